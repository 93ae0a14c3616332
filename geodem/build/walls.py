"""Rigid walls and platens made of elements, for lab tests (Brazilian platens, triaxial walls).

A wall is a flat layer of equal elements (diameter ``d_wall``, centre spacing ``0.85 d_wall``
so nothing slips between them) lying just outside one face of a box: the wall surface (the
element tangent plane on the inner side) is at ``face -/+ gap``, and the wall covers the face
(plus ``margin``) centred on it. Wall elements are unbonded;
they push on the specimen through the normal contact law (series of the wall's ``kn`` and the
element's ``kn``) and rub with friction ``mu``. Every wall is its own group (default name: the
side, e.g. ``"ymax"``) with all degrees of freedom fixed, ready to be moved kinematically
(:func:`geodem.core.groups.set_velocity`); its force on the specimen is minus
:func:`geodem.core.groups.reaction`.

Sides are named ``xmin, xmax, ymin, ymax`` (and ``zmin, zmax`` in 3-D).
"""
from __future__ import annotations

import math

import numpy as np

from geodem.core.state import ACCUMULATORS, ELEMENT_SCALAR, ELEMENT_VEC, State

__all__ = ["SIDES", "append_elements", "add_walls", "wall_surface"]

SIDES = ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")
SPACING = 0.85  # wall element spacing / d_wall: no slipping through, overlaps 0.3 r (< 0.5 r)


def _side(side: str, dim: int) -> tuple[int, int]:
    """(axis, sign) of a side name: sign -1 for min, +1 for max."""
    if side not in SIDES[:2 * dim]:
        raise ValueError(f"wall side {side!r}: allowed {', '.join(SIDES[:2 * dim])}")
    return "xyz".index(side[0]), (-1 if side.endswith("min") else 1)


def append_elements(state: State, x, r, m, *, kn, ks=None, mu=0.0, group: str | None = None,
                    fixed: bool = True) -> State:
    """A new state: ``state`` plus unbonded elements at ``x`` (M, dim) with radii ``r`` and
    masses ``m`` (scalars broadcast), stiffness ``kn, ks`` [N/m] (ks default kn), friction
    ``mu``, no bond strength. They join the new group ``group`` (if given) and are fixed in
    every degree of freedom when ``fixed``. Rows, time and books are carried over; the added
    elements have empty rows, so call :func:`geodem.core.neighbors.build_rows` afterwards."""
    if state.rotation or state.contact_damping:
        raise ValueError("this model already has rotating elements or contact damping; build the "
                         "model first and call enable_rotation / enable_contact_damping "
                         "(geodem.core.state) last")
    x = np.atleast_2d(np.asarray(x, float))
    if x.shape[1] != state.dim:
        raise ValueError(f"positions have {x.shape[1]} columns, the state is {state.dim}-D")
    k = len(x)
    b = lambda v: np.broadcast_to(np.asarray(v, float), (k,))  # noqa: E731
    props = np.zeros((k, state.props.shape[1]))
    props[:, 0], props[:, 1] = b(r), b(kn)
    props[:, 2] = b(kn if ks is None else ks)
    props[:, 5] = b(mu)
    extra = {"x": x, "v": np.zeros_like(x), "a": np.zeros_like(x), "dx": np.zeros_like(x),
             "x_ref": x.copy(), "free": np.ones_like(x) * (0.0 if fixed else 1.0),
             "fload": np.zeros_like(x), "m": b(m).copy(), "eta": np.zeros(k), "props": props,
             "group": np.zeros(k, np.int32)}
    for name in ACCUMULATORS:
        extra[name] = np.zeros(k)
    kw = {}
    for name in ELEMENT_VEC + ELEMENT_SCALAR + ACCUMULATORS + ("props", "group"):
        kw[name] = np.ascontiguousarray(np.concatenate([getattr(state, name), extra[name]]))
    w = state.width
    kw["nbr"] = np.concatenate([state.nbr, np.full((k, w), -1, np.int32)])
    kw["cstate"] = np.concatenate([state.cstate, np.zeros((k, w), np.int32)])
    kw["fs"] = np.concatenate([state.fs, np.zeros((k, w, state.dim))])
    kw["brate"] = np.concatenate([state.brate, np.ones((k, w), np.float32)])
    if state.row_stiffness:
        kw["krate"] = np.concatenate([state.krate, np.ones((k, w))])
    out = State(dim=state.dim, gravity=np.array(state.gravity, float).copy(),
                groups=dict(state.groups), thickness=state.thickness, hertz=state.hertz,
                dt=state.dt, step=state.step, time=state.time, skin=state.skin, e0=state.e0,
                **kw)
    if group is not None:
        from geodem.core import groups

        groups.add_group(out, group, np.arange(state.n, state.n + k))
    return out


def wall_surface(state: State, group: str, side: str) -> float:
    """Coordinate of the inner surface of wall ``group`` on ``side`` (its elements' tangent
    plane towards the specimen) [m]."""
    from geodem.core import groups

    ax, sign = _side(side, state.dim)
    idx = groups.members(state, group)
    return float(np.mean(state.x[idx, ax] - sign * state.r[idx]))


def add_walls(state: State, sides, *, d_wall=None, gap=0.0, margin=1.0, kn=None, mu=0.0,
              rho=None, lo=None, hi=None, names=None) -> State:
    """A new state with a flat wall of elements outside each face in ``sides`` of the box
    ``[lo, hi]`` (default: the elements' bounding box, surfaces included).

    ``d_wall`` [m] wall element diameter (default the mean element diameter); ``gap`` [m]
    distance from the face to the wall surface; ``margin`` how far the wall reaches past the
    box edges, in ``d_wall``; ``kn`` [N/m] wall element stiffness (default: the largest element
    ``kn`` scaled to ``d_wall`` by ``kn / d``: the wall is as stiff as the material);
    ``mu`` wall friction; ``rho`` wall density (default: that of the elements; masses only
    matter for the time step). ``names``: group names per side (default the side names).
    Rows are rebuilt."""
    from geodem.core.neighbors import build_rows

    dim = state.dim
    sides = [sides] if isinstance(sides, str) else list(sides)
    names = list(sides) if names is None else list(names)
    if len(names) != len(sides):
        raise ValueError("give one group name per side")
    d_el = 2.0 * state.r
    if lo is None:
        lo = (state.x - state.r[:, None]).min(axis=0)
    if hi is None:
        hi = (state.x + state.r[:, None]).max(axis=0)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    d_wall = float(d_el.mean()) if d_wall is None else float(d_wall)
    if not (d_wall > 0 and math.isfinite(d_wall)):
        raise ValueError(f"d_wall = {d_wall!r}: must be > 0 [m]")
    if kn is None:
        kn = float((state.kn / np.maximum(d_el, 1e-300)).max()) * d_wall
    if rho is None:
        vol = (math.pi / 6 * d_el ** 3) if dim == 3 else (math.pi / 4 * d_el ** 2 * d_el)
        rho = float(state.m.sum() / vol.sum())
    rw = 0.5 * d_wall
    m_wall = rho * (math.pi / 6 * d_wall ** 3 if dim == 3 else math.pi / 4 * d_wall ** 3)
    out = state
    for side, name in zip(sides, names):
        ax, sign = _side(side, dim)
        face = hi[ax] if sign > 0 else lo[ax]
        c = face + sign * (gap + rw)
        others = [a for a in range(dim) if a != ax]
        grids = []
        for a in others:
            a0, a1 = lo[a] - margin * d_wall, hi[a] + margin * d_wall
            k = max(int(math.ceil((a1 - a0) / SPACING / d_wall - 1e-9)), 0) + 1
            grids.append(0.5 * (a0 + a1) + SPACING * d_wall * (np.arange(k) - 0.5 * (k - 1)))
        mesh = np.meshgrid(*grids, indexing="ij")
        pts = np.zeros((mesh[0].size, dim))
        for a, g in zip(others, mesh):
            pts[:, a] = g.ravel()
        pts[:, ax] = c
        out = append_elements(out, pts, rw, m_wall, kn=kn, mu=mu, group=name)
    if out.skin <= 0:
        out.skin = 0.1 * float(d_el.mean())
    build_rows(out)
    return out
