"""The run directory: what a run writes, and the rules for reusing a folder.

::

    DIR/config.resolved.yaml   the validated workflow with every default filled in
    DIR/manifest.json          versions, config hash, seed, backend, threads, sessions
    DIR/log.txt                progress and messages (appended on resume)
    DIR/output.h5              H5MD-like time series and frames (geodem.io.h5)
    DIR/summary.json           status and key results as numbers
    DIR/checkpoints/           step_<step>.npz + step_<step>.json (the .json, written last, marks
                               a complete checkpoint)
    DIR/vtk/                   .vtp frames + frames.pvd (when asked for)

An existing, non-empty folder is never overwritten unless ``--overwrite`` is given (and then only
a geodem run directory, one holding ``manifest.json``, and only the entries the run wrote: other
files stay), or continued with ``--resume``.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from pathlib import Path

from geodem.workflow.errors import ErrorItem, WorkflowError

CONFIG = "config.resolved.yaml"
MANIFEST = "manifest.json"
LOG = "log.txt"
OUTPUT = "output.h5"
SUMMARY = "summary.json"
CHECKPOINTS = "checkpoints"
VTK = "vtk"
_CKPT = re.compile(r"^step_(\d{12})\.json$")


def atomic_write(path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def finite_json(o):
    """``o`` with non-finite floats (NaN, inf) replaced by None (strict JSON has no NaN)."""
    import math

    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: finite_json(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite_json(v) for v in o]
    return o


def write_json(path, data) -> None:
    """Strict JSON (NaN/inf written as null), written atomically."""
    text = json.dumps(finite_json(json.loads(json.dumps(data, default=_jsonable))), indent=2,
                      allow_nan=False)
    atomic_write(path, text + "\n")


def _jsonable(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


#: what every checkpoint marker the runner writes holds (runner.Runner._marker)
_MARKER_KEYS = {"step", "config_hash", "step_index", "step_start"}


def _npz_damage(path: Path) -> str | None:
    """Why the checkpoint archive ``path`` cannot be read, or None when every member's CRC
    checks out (a truncated or overwritten file)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except (OSError, zipfile.BadZipFile, EOFError, ValueError) as exc:
        return f"not a readable archive ({type(exc).__name__}: {exc})"
    return f"member {bad} is corrupted (CRC mismatch)" if bad else None


class RunDir:
    def __init__(self, path):
        self.path = Path(path)
        self.kept: list = []  # entries --overwrite left in place (prepare)

    def __truediv__(self, name) -> Path:
        return self.path / name

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    def _err(self, msg) -> WorkflowError:
        return WorkflowError(ErrorItem(str(self.path), None, "(run directory)", msg))

    def check(self, overwrite: bool, resume: bool) -> None:
        """The refusals of :meth:`prepare`, changing nothing (WorkflowError, exit 2): run
        before the model is built, so a bad ``-o`` fails at once. Reading every checkpoint's
        CRC, and the actual write into the folder, are left to :meth:`prepare`."""
        p = self.path
        if overwrite and resume:
            raise self._err("--overwrite and --resume exclude each other: --resume continues the "
                            "run in this folder, --overwrite deletes it and starts again")
        if p.exists() and not p.is_dir():
            raise self._err("exists and is not a folder; choose another -o")
        empty = not p.exists() or not any(p.iterdir())
        if resume:
            if empty:
                raise self._err("nothing to resume: the folder does not exist or is empty "
                                "(run without --resume to start)")
            if not (p / MANIFEST).exists():
                raise self._err("is not a geodem run directory (no manifest.json): nothing to "
                                "resume; choose another -o to start a run")
            if not self.checkpoint_markers():
                raise self._no_checkpoint()
        elif not empty:
            if not overwrite:
                raise self._err("already exists and is not empty; use --overwrite to replace "
                                "the run in it, --resume to continue it, or choose another -o")
            if not (p / MANIFEST).exists():
                raise self._err("is not a geodem run directory (no manifest.json); refusing to "
                                "delete its contents with --overwrite: choose another -o")
        if p.exists():
            if not os.access(p, os.W_OK | os.X_OK):
                raise self._err("cannot write into the folder: permission denied; choose "
                                "another -o")
            return
        # the folder is created by prepare: its nearest existing parent must be a writable folder
        parent = next((q for q in p.absolute().parents if q.exists()), None)
        if parent is not None and not parent.is_dir():
            raise self._err(f"cannot create the folder: Not a directory ({parent} is a "
                            "file); choose another -o")
        if parent is not None and not os.access(parent, os.W_OK | os.X_OK):
            raise self._err(f"cannot create the folder: Permission denied ({parent} cannot be "
                            "written); choose another -o")

    def _no_checkpoint(self) -> WorkflowError:
        return self._err(f"nothing to resume: no complete checkpoint in {self.checkpoints} (run "
                         "with --overwrite to start again)")

    def prepare(self, overwrite: bool, resume: bool) -> None:
        """Create the folder, or check that it may be reused (WorkflowError, exit 2, if not:
        :meth:`check`). ``--overwrite`` deletes only what the run wrote
        (:meth:`written_entries`); the names of the other entries are left in ``self.kept``."""
        p = self.path
        self.kept = []
        self.resume_from, self.damaged = None, []
        self.check(overwrite, resume)
        if resume:
            self.resume_from = self.latest_checkpoint()  # every CRC read once, here
            if self.resume_from is None:
                raise self._no_checkpoint()
            return
        if p.exists() and any(p.iterdir()):
            # --overwrite (check refused it otherwise): only what the run wrote goes, the
            # user's own files in the folder stay
            ours = self.written_entries()
            for child in p.iterdir():
                if child.name not in ours:
                    self.kept.append(child.name)
                elif child.is_dir() and not child.is_symlink():
                    shutil.rmtree(child)
                else:
                    child.unlink()
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise self._err(f"cannot create the folder: {exc.strerror or exc}; choose another "
                            "-o") from None
        try:  # a folder the run cannot write into (read-only file system, permissions)
            tempfile.TemporaryFile(dir=p).close()
        except OSError as exc:
            raise self._err(f"cannot write into the folder: {exc.strerror or exc}; choose "
                            "another -o") from None

    def written_entries(self) -> set:
        """Names of the folder's entries that a geodem run writes: the fixed ones, and the
        first part of every file the run listed (summary.json ``files``, the checkpoints'
        markers)."""
        names = {CONFIG, MANIFEST, LOG, OUTPUT, SUMMARY, CHECKPOINTS, VTK}
        listed = []
        sources = [self.path / SUMMARY] + self.checkpoint_markers()
        for f in sources:
            try:
                listed += list(json.loads(f.read_text()).get("files") or [])
            except (OSError, ValueError, AttributeError, TypeError):
                continue
        for f in listed:
            parts = Path(str(f)).parts
            if parts and not Path(str(f)).is_absolute() and ".." not in parts:
                names.add(parts[0])
        return names

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_markers(self) -> list[Path]:
        d = self.checkpoints
        if not d.is_dir():
            return []
        return sorted(f for f in d.iterdir() if _CKPT.match(f.name))

    def latest_checkpoint(self):
        """``(marker dict, npz path)`` of the newest complete and readable checkpoint, or None.

        A damaged one (a marker that is not the runner's mapping, a truncated or corrupted
        .npz: every member's CRC is checked) is passed over for the one before it; the names
        and reasons of those passed over are left in ``self.damaged``."""
        self.damaged = []
        for marker in reversed(self.checkpoint_markers()):
            npz = marker.with_suffix(".npz")
            try:
                data = json.loads(marker.read_text())
            except (OSError, ValueError) as exc:
                self.damaged.append((marker.name, f"unreadable marker ({exc})"))
                continue
            if not isinstance(data, dict) or not _MARKER_KEYS <= set(data):
                self.damaged.append((marker.name, "not a checkpoint marker (missing "
                                                  f"{sorted(_MARKER_KEYS - set(data or ()))})"
                                     if isinstance(data, dict) else "not a checkpoint marker"))
                continue
            if not npz.exists():
                continue  # the marker is written after its .npz: an old, deleted one
            reason = _npz_damage(npz)
            if reason:
                self.damaged.append((npz.name, reason))
                continue
            return data, npz
        return None

    def write_checkpoint(self, sim, marker: dict, keep: int) -> Path:
        """Save ``sim`` (atomic .npz) and then its marker (atomic .json); keep the newest
        ``keep`` checkpoints."""
        d = self.checkpoints
        d.mkdir(exist_ok=True)
        step = int(sim.state.step)
        npz = d / f"step_{step:012d}.npz"
        sim.save(npz)
        write_json(npz.with_suffix(".json"), dict(marker, npz=npz.name))
        markers = self.checkpoint_markers()
        for old in markers[:-keep] if keep > 0 else []:
            for f in (old.with_suffix(".npz"), old):
                try:
                    f.unlink()
                except FileNotFoundError:
                    pass
        return npz
