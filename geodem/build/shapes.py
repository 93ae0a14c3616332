"""Specimen shapes (boolean masks of element centres) and cutting a state to a shape.

Shapes select elements by their CENTRE (MatDEM's convention): an element is kept when its centre
lies inside the shape, so boundary elements stick out by up to one radius.

* :class:`Box` ``(lo, hi)``: axis-aligned box, 2-D or 3-D.
* :class:`Cylinder` ``(center, radius, z0, z1)``: 3-D cylinder with its axis along z through the
  point ``center`` (x, y), from ``z0`` to ``z1``.
* :class:`Disc` ``(center, radius)``: 2-D disc; in 3-D a cylinder section (Brazilian disc) with its
  axis along ``axis`` (default ``"y"``) and thickness ``thickness`` centred on ``center`` (3 values).

``cut(obj, shape)`` returns the mask for positions, or a new :class:`State` holding only the
elements inside (see :func:`subset_state`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geodem.core.state import ELEMENT_SCALAR, ELEMENT_VEC, ACCUMULATORS, State

__all__ = ["Box", "Cylinder", "Disc", "box_mask", "cylinder_mask", "disc_mask", "cut",
           "subset_state"]


def _pos(x):
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise ValueError(f"positions must have shape (N, 2) or (N, 3), got {x.shape}")
    return x


def box_mask(x, lo, hi) -> np.ndarray:
    """Centres with ``lo <= x <= hi`` on every axis."""
    x = _pos(x)
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    if lo.shape != (x.shape[1],) or hi.shape != (x.shape[1],):
        raise ValueError(f"lo/hi must have {x.shape[1]} components")
    return np.all((x >= lo) & (x <= hi), axis=1)


def cylinder_mask(x, center, radius, z0, z1) -> np.ndarray:
    """3-D: centres within ``radius`` of the z-axis through ``center`` (x, y), ``z0 <= z <= z1``."""
    x = _pos(x)
    if x.shape[1] != 3:
        raise ValueError("a cylinder (axis z) needs 3-D positions; use a disc in 2-D")
    c = np.asarray(center, float)[:2]
    rr = (x[:, 0] - c[0]) ** 2 + (x[:, 1] - c[1]) ** 2
    return (rr <= radius * radius) & (x[:, 2] >= z0) & (x[:, 2] <= z1)


def disc_mask(x, center, radius, axis="y", thickness=None) -> np.ndarray:
    """2-D: centres within ``radius`` of ``center``. 3-D: a cylinder section with its axis along
    ``axis`` ('x', 'y' or 'z') through ``center`` (3 values), ``|offset along axis| <= thickness/2``."""
    x = _pos(x)
    c = np.asarray(center, float)
    if x.shape[1] == 2:
        return ((x - c[:2]) ** 2).sum(axis=1) <= radius * radius
    if thickness is None:
        raise ValueError("a 3-D disc needs a thickness")
    k = "xyz".index(axis)
    other = [a for a in range(3) if a != k]
    rr = ((x[:, other] - c[other]) ** 2).sum(axis=1)
    return (rr <= radius * radius) & (np.abs(x[:, k] - c[k]) <= 0.5 * thickness)


@dataclass(frozen=True)
class Box:
    lo: tuple
    hi: tuple

    def mask(self, x):
        return box_mask(x, self.lo, self.hi)

    @property
    def volume(self):
        """Volume (3-D) or area (2-D)."""
        return float(np.prod(np.asarray(self.hi, float) - np.asarray(self.lo, float)))

    @property
    def bounds(self):
        return np.asarray(self.lo, float), np.asarray(self.hi, float)


@dataclass(frozen=True)
class Cylinder:
    center: tuple
    radius: float
    z0: float
    z1: float

    def mask(self, x):
        return cylinder_mask(x, self.center, self.radius, self.z0, self.z1)

    @property
    def volume(self):
        return math.pi * self.radius ** 2 * (self.z1 - self.z0)

    @property
    def bounds(self):
        c = np.asarray(self.center, float)[:2]
        return (np.array([c[0] - self.radius, c[1] - self.radius, self.z0]),
                np.array([c[0] + self.radius, c[1] + self.radius, self.z1]))


@dataclass(frozen=True)
class Disc:
    center: tuple
    radius: float
    axis: str = "y"
    thickness: float | None = None

    def mask(self, x):
        return disc_mask(x, self.center, self.radius, self.axis, self.thickness)

    @property
    def volume(self):
        a = math.pi * self.radius ** 2
        return a if len(self.center) == 2 else a * float(self.thickness)

    @property
    def bounds(self):
        c = np.asarray(self.center, float)
        half = np.full(c.shape, float(self.radius))
        if c.size == 3:
            half["xyz".index(self.axis)] = 0.5 * float(self.thickness)
        return c - half, c + half


def subset_state(state: State, keep, rebuild: bool = True) -> State:
    """A new state holding only the elements selected by ``keep`` (bool (N,) or indices).

    Every per-element array is copied for the kept elements (order kept); groups (names and
    ids) are carried over. Row entries whose neighbour is kept are carried over with their state
    (``cstate``, ``fs``, ``brate``) and relabelled; entries to removed elements are dropped. With
    ``rebuild`` (and ``state.skin > 0``) the rows are then rebuilt by
    :func:`geodem.core.neighbors.build_rows` (unbonded neighbours within the skin added). Time,
    step, energy books and ``dt`` are copied as they are (``dt`` may need a new choice).
    """
    idx = np.asarray(keep)
    if idx.dtype == bool:
        if idx.shape != (state.n,):
            raise ValueError(f"mask must have shape ({state.n},), got {idx.shape}")
        idx = np.flatnonzero(idx)
    idx = np.asarray(idx, dtype=np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= state.n):
        raise ValueError("subset indices out of range")
    if np.unique(idx).size != idx.size:
        raise ValueError("subset indices must be unique")
    n = idx.size
    inv = np.full(state.n, -1, np.int64)
    inv[idx] = np.arange(n)
    kw = {}
    for name in ELEMENT_VEC + ELEMENT_SCALAR + ACCUMULATORS + ("props", "group"):
        kw[name] = np.ascontiguousarray(getattr(state, name)[idx])
    # rows: relabel, drop entries to removed elements, compact (stable: order kept)
    nbr = state.nbr[idx]
    new = np.where(nbr >= 0, inv[np.maximum(nbr, 0)], -1)
    valid = new >= 0
    order = np.argsort(~valid, axis=1, kind="stable")
    kw["nbr"] = np.ascontiguousarray(np.take_along_axis(new, order, axis=1).astype(np.int32))
    kw["cstate"] = np.ascontiguousarray(
        np.where(np.take_along_axis(valid, order, 1), np.take_along_axis(state.cstate[idx], order, 1), 0)
        .astype(np.int32))
    fs = np.take_along_axis(state.fs[idx], order[:, :, None], axis=1)
    fs[~np.take_along_axis(valid, order, 1)] = 0.0
    kw["fs"] = np.ascontiguousarray(fs)
    br = np.take_along_axis(state.brate[idx], order, 1)
    br[~np.take_along_axis(valid, order, 1)] = 1.0
    kw["brate"] = np.ascontiguousarray(br.astype(np.float32))
    out = State(dim=state.dim, gravity=np.array(state.gravity, float).copy(),
                groups=dict(state.groups), thickness=state.thickness, hertz=state.hertz,
                dt=state.dt, step=state.step, time=state.time, skin=state.skin, e0=state.e0,
                **kw)
    if rebuild and out.skin > 0 and n:
        from geodem.core.neighbors import build_rows

        build_rows(out)
    return out


def cut(obj, shape, rebuild: bool = True):
    """Mask of the positions inside ``shape`` (``obj`` an (N, dim) array), or, for a
    :class:`State`, a new state with only the elements whose centres are inside."""
    if isinstance(obj, State):
        return subset_state(obj, shape.mask(obj.x), rebuild=rebuild)
    return shape.mask(obj)
