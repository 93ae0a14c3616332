"""Jammed packings kept on disk, so that a specimen built again is not jammed again.

Jamming (:func:`geodem.build.isotropic.jam`) is most of a random specimen's build: 15 of the
18 s of the 2,177-element 3-D calibration specimen, and most of a large Brazilian disc's (a
box of 42,282 elements jammed whole takes tens of minutes). A calibration builds the same
specimen for every iteration and test, and ``geodem rock`` the same discs on every check. The
jam is deterministic: its result depends only on its inputs (radii, box, overlap, seed, start
positions, periodic or not) and on the code that jams. Both are hashed into the file's name,
so a hit returns the very bits a fresh jam would give (a changed input, a changed
``isotropic.py``, another numba or another processor misses), and results do not depend on
whether the cache was used.

Files: ``$GEODEM_CACHE_DIR/packings/<sha256>.npz`` (:func:`geodem.machine.cache_root`), at
most :data:`MAX_FILES` (the oldest used are removed). ``GEODEM_PACKING_CACHE=0`` turns the
cache off."""
from __future__ import annotations

import functools
import hashlib
import inspect
import os
import platform
from pathlib import Path

import numpy as np

#: packings kept; a 3-D calibration specimen's file is ~70 kB, a 42,282-element disc box ~1.4 MB
MAX_FILES = 200


def enabled() -> bool:
    """Whether jammed packings are read from and written to the cache
    (``GEODEM_PACKING_CACHE`` not ``0``)."""
    return os.environ.get("GEODEM_PACKING_CACHE", "1").strip() not in ("0", "false", "no", "off")


def off():
    """A block within which jams are neither read from nor written to the cache (a build that
    is timed, e.g. ``geodem study scale``, must jam)."""
    from geodem.machine import env_set

    return env_set("GEODEM_PACKING_CACHE", "0")


def folder() -> Path:
    from geodem.machine import cache_root

    return cache_root() / "packings"


@functools.lru_cache(maxsize=1)
def _code_hash() -> str:
    """The jamming code and what compiles it: isotropic.py's source, numba and numpy, and the
    processor numba compiles for (its name and features: the machine code of the minimiser,
    hence its last bits, may differ between processors)."""
    import llvmlite.binding as ll
    import numba

    from geodem.build import isotropic

    text = "\n".join([inspect.getsource(isotropic), numba.__version__, np.__version__,
                      platform.machine(), ll.get_host_cpu_name(),
                      ll.get_host_cpu_features().flatten()])
    return hashlib.sha256(text.encode()).hexdigest()


def key(r0, lo, hi, overlap, seed, max_cycles, x0, periodic) -> str:
    """The cache key of one :func:`geodem.build.isotropic.jam` call: a sha256 of its inputs
    (arrays by their float64 bytes) and of the jamming code."""
    h = hashlib.sha256(_code_hash().encode())
    for a in (r0, lo, hi) + (() if x0 is None else (x0,)):
        arr = np.ascontiguousarray(a, dtype=np.float64)
        h.update(repr(arr.shape).encode())
        h.update(arr.tobytes())
    # one flag (a periodic cell or none) keeps the keys it always had; a strip's per-axis flags
    per_axis = periodic if isinstance(periodic, bool) else tuple(bool(p) for p in periodic)
    h.update(repr((float(overlap), int(seed), int(max_cycles), x0 is None,
                   per_axis)).encode())
    return h.hexdigest()


def load(k: str):
    """``(x, r, info)`` stored under key ``k``, or None (absent, unreadable, cache off)."""
    if not enabled():
        return None
    path = folder() / f"{k}.npz"
    try:
        with np.load(path) as f:
            x, r = f["x"].copy(), f["r"].copy()
            info = {name[5:]: f[name].item() for name in f.files if name.startswith("info_")}
        os.utime(path)  # recently used: kept longest
    except Exception:  # noqa: BLE001 - absent, truncated, foreign: jam anew
        return None
    return x, r, info


def store(k: str, x, r, info: dict) -> None:
    """Keep ``(x, r, info)`` under key ``k`` (written to a temporary file and renamed, so a
    process reading it side by side never sees half a file); a cache that cannot be written
    is skipped silently: it only saves time."""
    if not enabled():
        return
    d = folder()
    try:
        d.mkdir(parents=True, exist_ok=True)
        tmp = d / f".{k}.{os.getpid()}.tmp.npz"
        np.savez(tmp, x=x, r=r, **{f"info_{n}": np.asarray(v) for n, v in info.items()})
        os.replace(tmp, d / f"{k}.npz")
        _prune(d)
    except OSError:
        return


def _prune(d: Path) -> None:
    files = sorted(d.glob("*.npz"), key=lambda p: p.stat().st_mtime)
    for p in files[:max(0, len(files) - MAX_FILES)]:
        try:
            p.unlink()
        except OSError:
            pass
