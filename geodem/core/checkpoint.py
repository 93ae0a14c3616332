"""Complete, atomic checkpoints of a state (and a simulation's books) as ``.npz`` files.

Everything the next step depends on is saved: element arrays, rows with their per-contact
history, the energy books, ``dt``, ``step``, ``time``, ``skin`` and the crack log. A run resumed
from a checkpoint continues bit-identically on CPU backends.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import fields

import numpy as np

from geodem.core.state import State

_SCALARS = ("dim", "thickness", "hertz", "dt", "step", "time", "skin", "e0")


def save_state(state: State, path, extra: dict | None = None) -> None:
    """Write ``state`` (and JSON-able ``extra``) to ``path`` atomically (temp file + rename)."""
    path = os.fspath(path)
    arrays = {k: v for k, v in state.arrays().items()}
    arrays["gravity"] = state.gravity
    meta = {k: getattr(state, k) for k in _SCALARS}
    meta["hertz"] = bool(meta["hertz"])
    meta["groups"] = state.groups
    meta["extra"] = extra or {}
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".ckpt-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, __meta__=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a checkpoint is an ordinary file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_state(path):
    """Read a checkpoint; returns ``(state, extra)``."""
    with np.load(os.fspath(path)) as z:
        meta = json.loads(bytes(z["__meta__"]).decode())
        kw = {f.name: z[f.name].copy() for f in fields(State) if f.name in z.files}
    kw.update({k: meta[k] for k in _SCALARS})
    kw["groups"] = meta["groups"]
    return State(**kw), meta["extra"]
