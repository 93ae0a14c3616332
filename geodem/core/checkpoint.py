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

_SCALARS = ("dim", "thickness", "hertz", "contact_damping", "dt", "step", "time", "skin", "e0")
_DEFAULTS = {"contact_damping": False}  # scalars added after the first checkpoints


def save_state(state: State, path, extra: dict | None = None,
               extra_arrays: dict | None = None) -> None:
    """Write ``state`` (and JSON-able ``extra``, and the arrays ``extra_arrays`` under their own
    keys) to ``path`` atomically (temp file + rename)."""
    path = os.fspath(path)
    arrays = {k: v for k, v in state.arrays().items()}
    for k, v in (extra_arrays or {}).items():
        if k in arrays or k in ("gravity", "__meta__"):
            raise ValueError(f"extra array {k!r} would overwrite a state array")
        arrays[k] = v
    arrays["gravity"] = state.gravity
    meta = {k: getattr(state, k) for k in _SCALARS}
    meta["hertz"] = bool(meta["hertz"])
    meta["contact_damping"] = bool(meta["contact_damping"])
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


def load_state(path, with_arrays: bool = False):
    """Read a checkpoint; returns ``(state, extra)``, or ``(state, extra, extra_arrays)`` with
    ``with_arrays``."""
    names = {f.name for f in fields(State)}
    with np.load(os.fspath(path)) as z:
        meta = json.loads(bytes(z["__meta__"]).decode())
        kw = {k: z[k].copy() for k in z.files if k in names}
        more = {k: z[k].copy() for k in z.files if k not in names and k != "__meta__"}
    kw.update({k: meta.get(k, _DEFAULTS.get(k)) for k in _SCALARS})
    kw["groups"] = meta["groups"]
    if kw.get("w") is not None and kw.get("rot_props") is None:
        # checkpoints written before the rolling parameters were one array: their bond moment
        # (none before moment-resisting bonds) and the default rolling stiffness 1
        n = kw["w"].shape[0]
        mb = more.pop("bond_moment", np.zeros(n))
        kw["rot_props"] = np.stack([mb, np.ones(n)], axis=1)
    if with_arrays:
        return State(**kw), meta["extra"], more
    return State(**kw), meta["extra"]
