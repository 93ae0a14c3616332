"""Named groups of elements and what is done to them: fixing, kinematic motion, loads.

A group is a name in ``state.groups`` mapped to an id stored per element in ``state.group``
(one group per element; ``"all"`` is id 0 and always means every element). Boundary conditions are
written into the per-element arrays the kernels read, so a new kind of boundary never touches the
time-step loop:

* fixed DOF: ``free[i, d] = 0`` and ``v[i, d] = 0``;
* kinematic (platens, walls): ``free[i, d] = 0`` and ``v[i, d]`` = the prescribed velocity, so the
  element moves at that velocity whatever the contact forces (their reaction is read from ``a``);
* loads: ``fload[i]`` [N] per element, booked as external work.
"""
from __future__ import annotations

import numpy as np


def add_group(state, name: str, mask) -> int:
    """Put the elements selected by ``mask`` (bool (N,) or indices) into a new group ``name``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"a group name is a non-empty string, got {name!r}")
    if name in state.groups:
        raise ValueError(f"group {name!r} already exists; groups: {sorted(state.groups)}")
    sel = np.zeros(state.n, bool)
    m = np.asarray(mask)
    if m.dtype != bool:
        if m.size and (m.dtype.kind not in "iu" or m.min() < -state.n or m.max() >= state.n):
            raise ValueError(f"group {name!r}: give a bool mask of {state.n} values or element "
                             f"indices in 0..{state.n - 1}")
        m = m.astype(np.int64)
    elif m.shape != (state.n,):
        raise ValueError(f"group {name!r}: a bool mask needs {state.n} values, got shape "
                         f"{m.shape}")
    sel[m] = True
    gid = max(state.groups.values(), default=0) + 1
    state.groups[name] = gid
    state.group[sel] = gid
    return gid


def members(state, name: str) -> np.ndarray:
    """Indices of the elements of group ``name``."""
    if name == "all":
        return np.arange(state.n)
    return np.flatnonzero(state.group_mask(name))


def _dofs(state, dofs):
    if dofs is None:
        return list(range(state.dim))
    names = "xyz"[:state.dim]
    if isinstance(dofs, str):
        dofs = list(dofs)  # "xy" names two degrees of freedom
    elif isinstance(dofs, (int, np.integer)):
        dofs = [dofs]
    else:
        dofs = list(dofs)
    if not dofs:
        raise ValueError(f"no degree of freedom given; allowed: names from {names!r} or indices "
                         f"0..{state.dim - 1}")
    out = []
    for d in dofs:
        k = names.index(d) if isinstance(d, str) and len(d) == 1 and d in names else d
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) \
                or not 0 <= k < state.dim:
            raise ValueError(f"degree of freedom {d!r} not in {list(names)} / 0..{state.dim - 1}")
        out.append(int(k))
    return out


def _hold_rotation(state, idx) -> None:
    # with rotation, an element whose translation is wholly fixed or prescribed does not turn
    # either (a platen or a wall, as enable_rotation sets them)
    if state.rotation:
        held = idx[(state.free[idx] == 0.0).all(axis=1)]
        state.rfree[held] = 0.0
        state.w[held] = 0.0


def fix(state, name: str, dofs=None) -> None:
    """Fix the degrees of freedom ``dofs`` (default all; names 'x','y','z' or indices). With
    rotation, an element left with no free translation stops turning too."""
    idx = members(state, name)
    for d in _dofs(state, dofs):
        state.free[idx, d] = 0.0
        state.v[idx, d] = 0.0
    _hold_rotation(state, idx)


def set_velocity(state, name: str, velocity) -> None:
    """Move group ``name`` kinematically at ``velocity`` [m/s] (``dim`` values; NaN = free).
    With rotation, an element left with no free translation stops turning too."""
    vel = np.asarray(velocity, float)
    if vel.shape != (state.dim,):
        raise ValueError(f"velocity must have {state.dim} components, got {vel.shape}")
    idx = members(state, name)
    for d in range(state.dim):
        if np.isnan(vel[d]):
            continue
        state.free[idx, d] = 0.0
        state.v[idx, d] = vel[d]
    _hold_rotation(state, idx)


def release(state, name: str, dofs=None) -> None:
    """Make the degrees of freedom free again (velocities are kept)."""
    idx = members(state, name)
    for d in _dofs(state, dofs):
        state.free[idx, d] = 1.0


def set_load(state, name: str, force, per: str = "group") -> None:
    """Apply ``force`` [N] to group ``name``: the group total split evenly (``per='group'``) or
    the same force on each element (``per='element'``)."""
    f = np.asarray(force, float)
    if f.shape != (state.dim,):
        raise ValueError(f"force must have {state.dim} components, got {f.shape}")
    idx = members(state, name)
    if per == "group":
        f = f / max(len(idx), 1)
    elif per != "element":
        raise ValueError(f"per must be 'group' or 'element', got {per!r}")
    state.fload[idx] = f


def reaction(state, name: str) -> np.ndarray:
    """Contact force on group ``name`` along its fixed/kinematic DOFs [N] (sum over elements)."""
    idx = members(state, name)
    fixed = state.free[idx] == 0.0
    return (state.m[idx, None] * state.a[idx] * fixed).sum(axis=0)
