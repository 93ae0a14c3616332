"""What this machine offers the run: the memory available for new allocations, and the
folder geodem keeps its caches in."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path


@contextlib.contextmanager
def env_set(name: str, value: str):
    """Within this block the environment variable ``name`` is ``value`` (for this process and
    the processes it starts); afterwards it is what it was, or absent again."""
    saved = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = saved


def cache_root() -> Path:
    """geodem's cache folder: ``$GEODEM_CACHE_DIR``, else ``$XDG_CACHE_HOME/geodem`` or
    ``~/.cache/geodem`` (generated kernels, jammed packings)."""
    base = os.environ.get("GEODEM_CACHE_DIR")
    if not base:
        base = os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"),
                            "geodem")
    return Path(base)


def available_memory() -> int | None:
    """Bytes of memory available for new allocations (``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None
