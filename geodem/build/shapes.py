"""Specimen and model shapes (boolean masks of element centres) and cutting a state to a shape.

Shapes select elements by their CENTRE (MatDEM's convention): an element is kept when its centre
lies inside the shape (boundary included), so boundary elements stick out by up to one radius.
Every shape has ``mask(x) -> bool (N,)`` for positions ``x`` (N, dim), vectorised over the
elements, and ``bounds -> (lo, hi)`` (``dim`` values each; ``+-inf`` where unbounded).

Primitives
* :class:`Box` ``(lo, hi)``: axis-aligned box, 2-D or 3-D.
* :class:`Cylinder` ``(center, radius, z0, z1)``: 3-D cylinder with its axis along z through the
  point ``center`` (x, y), from ``z0`` to ``z1``.
* :class:`Disc` ``(center, radius)``: 2-D disc; in 3-D a cylinder section (Brazilian disc) with its
  axis along ``axis`` (default ``"y"``) and thickness ``thickness`` centred on ``center`` (3 values).
* :class:`Sphere` ``(center, radius)``: ball ``|x - c| <= R`` (a disc in 2-D).
* :class:`Polygon` ``(vertices)``: 2-D simple polygon (even-odd rule, edges included); with
  ``axis, z0, z1`` a 3-D prism: the polygon in the plane of the two other axes (in x, y, z
  order: ``axis="z"`` -> (x, y), ``"y"`` -> (x, z), ``"x"`` -> (y, z)) extruded along ``axis``
  from ``z0`` to ``z1``.
* :class:`HalfSpace` ``(point, normal)``: ``(x - point) . n <= 0``, ``n`` the OUTWARD normal.

Combinations (also as operators)
* :class:`Union` ``a | b``: inside either; :class:`Intersection` ``a & b``: inside both;
  :class:`Difference` ``a - b``: inside ``a`` and not inside ``b``. Any depth of nesting.

``cut(obj, shape)`` returns the mask for positions, or a new :class:`State` holding only the
elements inside (see :func:`subset_state`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geodem.core.state import ELEMENT_SCALAR, ELEMENT_VEC, ACCUMULATORS, State
from geodem.geo.errors import GeometryError

__all__ = ["Shape", "Box", "Cylinder", "Disc", "Sphere", "Polygon", "HalfSpace", "Union",
           "Intersection", "Difference", "box_mask", "cylinder_mask", "disc_mask",
           "polygon_mask", "polygon_area", "cut", "subset_state"]

_AXES = "xyz"


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


def polygon_area(vertices) -> float:
    """Signed area of a polygon (shoelace formula), > 0 for counter-clockwise vertices:
    ``A = 1/2 sum_k (u_k v_{k+1} - u_{k+1} v_k)``."""
    v = np.asarray(vertices, float)
    u, w = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(u, np.roll(w, -1)) - np.dot(np.roll(u, -1), w))


def polygon_mask(p, vertices, tol=None) -> np.ndarray:
    """Points ``p`` (N, 2) inside the polygon ``vertices`` (M, 2; closed implicitly).

    Even-odd rule: a horizontal ray from the point to ``+u`` crosses the boundary an odd number
    of times. Edge ``(a, b)`` is crossed when ``(a_v > p_v) != (b_v > p_v)`` and
    ``p_u < a_u + (p_v - a_v)(b_u - a_u)/(b_v - a_v)``. Points within ``tol`` of an edge count
    as inside (default ``1e-12`` x the polygon's bounding-box diagonal), like the closed
    :class:`Box`. The loop runs over the M edges; every step is vectorised over the N points.
    Self-intersecting polygons follow the even-odd rule.
    """
    p = np.asarray(p, float)
    v = np.asarray(vertices, float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"points must have shape (N, 2), got {p.shape}")
    if tol is None:
        tol = 1e-12 * float(np.hypot(*(v.max(axis=0) - v.min(axis=0))))
    pu, pv = p[:, 0], p[:, 1]
    inside = np.zeros(len(p), bool)
    edge = np.zeros(len(p), bool)
    tol2 = tol * tol
    for k in range(len(v)):
        a, b = v[k], v[(k + 1) % len(v)]
        cross = (a[1] > pv) != (b[1] > pv)
        dv = b[1] - a[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            ui = a[0] + (pv - a[1]) * (b[0] - a[0]) / (dv if dv != 0.0 else 1.0)
        inside ^= cross & (pu < ui)
        e = b - a
        ee = float(e @ e)
        t = np.clip(((pu - a[0]) * e[0] + (pv - a[1]) * e[1]) / ee, 0.0, 1.0) if ee > 0 else 0.0
        edge |= (pu - a[0] - t * e[0]) ** 2 + (pv - a[1] - t * e[1]) ** 2 <= tol2
    return inside | edge


class Shape:
    """Base of all shapes: ``mask(x)``, ``bounds``, and the operators ``|`` (union),
    ``&`` (intersection) and ``-`` (difference)."""

    def mask(self, x) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def bounds(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def __or__(self, other):
        return Union(self, other)

    def __and__(self, other):
        return Intersection(self, other)

    def __sub__(self, other):
        return Difference(self, other)


@dataclass(frozen=True)
class Box(Shape):
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
class Cylinder(Shape):
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
class Disc(Shape):
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


@dataclass(frozen=True)
class Sphere(Shape):
    """Ball ``|x - center| <= radius`` (3-D), or a disc in 2-D (2 centre values)."""

    center: tuple
    radius: float

    def __post_init__(self):
        c = tuple(float(v) for v in self.center)
        if len(c) not in (2, 3) or not all(map(math.isfinite, c)):
            raise GeometryError(f"Sphere: center needs 2 or 3 finite values, got {self.center}")
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise GeometryError(f"Sphere: radius must be finite and > 0, got {self.radius!r}")
        object.__setattr__(self, "center", c)

    def mask(self, x):
        x = _pos(x)
        if x.shape[1] != len(self.center):
            raise ValueError(f"a {len(self.center)}-D sphere needs {len(self.center)}-D "
                             f"positions, got {x.shape[1]}-D")
        return ((x - np.asarray(self.center)) ** 2).sum(axis=1) <= self.radius ** 2

    @property
    def volume(self):
        """Volume (3-D) or area (2-D)."""
        return (4.0 / 3.0 * math.pi * self.radius ** 3 if len(self.center) == 3
                else math.pi * self.radius ** 2)

    @property
    def bounds(self):
        c = np.asarray(self.center)
        return c - self.radius, c + self.radius


@dataclass(frozen=True)
class Polygon(Shape):
    """A simple polygon (2-D) or a prism (3-D): the polygon extruded along ``axis``.

    ``vertices``: (M >= 3, 2) corner coordinates [m] in order (either orientation; the polygon
    closes itself). 2-D: ``axis``, ``z0``, ``z1`` left out; the polygon is in (x, y). 3-D: give
    ``z0 < z1`` (the extrusion range along ``axis``, default ``"z"``); the vertices are then in
    the plane of the two remaining axes in x, y, z order (``"z"`` -> (x, y), ``"y"`` -> (x, z),
    ``"x"`` -> (y, z)). Inside by the even-odd rule (:func:`polygon_mask`), edges included.
    """

    vertices: tuple
    axis: str = "z"
    z0: float | None = None
    z1: float | None = None

    def __post_init__(self):
        try:
            v = np.asarray(self.vertices, float)
        except (TypeError, ValueError):
            raise GeometryError(f"Polygon: vertices must be numbers, got {self.vertices!r}") \
                from None
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
            raise GeometryError(f"Polygon: vertices must be at least 3 points (u, v), got an "
                                f"array of shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise GeometryError("Polygon: vertices must be finite")
        if abs(polygon_area(v)) <= 1e-14 * float(np.ptp(v, axis=0).max()) ** 2:
            raise GeometryError(f"Polygon: the vertices enclose no area: {v.tolist()}")
        object.__setattr__(self, "vertices", tuple(map(tuple, v.tolist())))
        if (self.z0 is None) != (self.z1 is None):
            raise GeometryError("Polygon: give both z0 and z1 (3-D prism) or neither (2-D)")
        if self.axis not in _AXES:
            raise GeometryError(f"Polygon: axis must be 'x', 'y' or 'z', got {self.axis!r}")
        if self.z0 is not None and not (math.isfinite(self.z0) and math.isfinite(self.z1)
                                        and self.z1 > self.z0):
            raise GeometryError(f"Polygon: need finite z0 < z1, got z0={self.z0}, z1={self.z1}")

    @property
    def dim(self) -> int:
        return 2 if self.z0 is None else 3

    def _plane(self):
        k = _AXES.index(self.axis)
        return k, [a for a in range(3) if a != k]

    def mask(self, x):
        x = _pos(x)
        if x.shape[1] != self.dim:
            raise ValueError(f"a {self.dim}-D polygon needs {self.dim}-D positions, got "
                             f"{x.shape[1]}-D (give z0, z1 for a 3-D prism)")
        if self.dim == 2:
            return polygon_mask(x, self.vertices)
        k, other = self._plane()
        along = (x[:, k] >= self.z0) & (x[:, k] <= self.z1)
        out = np.zeros(len(x), bool)
        out[along] = polygon_mask(x[along][:, other], self.vertices)
        return out

    @property
    def area(self):
        """Area of the polygon [m^2]."""
        return abs(polygon_area(self.vertices))

    @property
    def volume(self):
        """Area (2-D) or area x (z1 - z0) (3-D)."""
        return self.area if self.dim == 2 else self.area * (self.z1 - self.z0)

    @property
    def bounds(self):
        v = np.asarray(self.vertices)
        if self.dim == 2:
            return v.min(axis=0), v.max(axis=0)
        k, other = self._plane()
        lo, hi = np.empty(3), np.empty(3)
        lo[other], hi[other] = v.min(axis=0), v.max(axis=0)
        lo[k], hi[k] = self.z0, self.z1
        return lo, hi


@dataclass(frozen=True)
class HalfSpace(Shape):
    """The half-space ``(x - point) . n <= 0``: ``normal`` points OUT of the shape (it is
    normalised). 2 or 3 components. E.g. ``HalfSpace((0, 0, 5), (0, 0, 1))`` is ``z <= 5``."""

    point: tuple
    normal: tuple

    def __post_init__(self):
        p = np.asarray(self.point, float)
        n = np.asarray(self.normal, float)
        if p.shape not in ((2,), (3,)) or n.shape != p.shape:
            raise GeometryError(f"HalfSpace: point and normal need 2 or 3 components each, got "
                                f"{self.point} and {self.normal}")
        nn = float(np.linalg.norm(n))
        if not (np.all(np.isfinite(p)) and math.isfinite(nn) and nn > 0):
            raise GeometryError(f"HalfSpace: need a finite point and a non-zero finite normal, "
                                f"got {self.point}, {self.normal}")
        object.__setattr__(self, "point", tuple(p.tolist()))
        object.__setattr__(self, "normal", tuple((n / nn).tolist()))

    def mask(self, x):
        x = _pos(x)
        if x.shape[1] != len(self.point):
            raise ValueError(f"a {len(self.point)}-D half-space needs {len(self.point)}-D "
                             f"positions, got {x.shape[1]}-D")
        return (x - np.asarray(self.point)) @ np.asarray(self.normal) <= 0.0

    @property
    def volume(self):
        return math.inf

    @property
    def bounds(self):
        """Unbounded (``+-inf``) except along an axis-aligned normal."""
        n = np.asarray(self.normal)
        p = np.asarray(self.point)
        lo, hi = np.full(n.size, -np.inf), np.full(n.size, np.inf)
        k = np.flatnonzero(n != 0.0)
        if k.size == 1:
            (hi if n[k[0]] > 0 else lo)[k[0]] = p[k[0]]
        return lo, hi


class _Combination(Shape):
    _symbol = "?"

    def __init__(self, *shapes):
        if len(shapes) < 2:
            raise GeometryError(f"{type(self).__name__} needs at least 2 shapes, got "
                                f"{len(shapes)}")
        for s in shapes:
            if not hasattr(s, "mask"):
                raise GeometryError(f"{type(self).__name__}: {s!r} is not a shape (no .mask)")
        self.shapes = tuple(shapes)

    def __repr__(self):
        return f"{type(self).__name__}({', '.join(map(repr, self.shapes))})"

    def __eq__(self, other):
        return type(self) is type(other) and self.shapes == other.shapes

    def __hash__(self):
        return hash((type(self).__name__, self.shapes))

    def _all_bounds(self):
        b = [s.bounds for s in self.shapes]
        return np.array([lo for lo, _ in b], float), np.array([hi for _, hi in b], float)


class Union(_Combination):
    """Inside at least one of the shapes (``a | b | ...``)."""

    def mask(self, x):
        out = self.shapes[0].mask(x)
        for s in self.shapes[1:]:
            out = out | s.mask(x)
        return out

    @property
    def bounds(self):
        lo, hi = self._all_bounds()
        return lo.min(axis=0), hi.max(axis=0)


class Intersection(_Combination):
    """Inside every shape (``a & b & ...``)."""

    def mask(self, x):
        out = self.shapes[0].mask(x)
        for s in self.shapes[1:]:
            out = out & s.mask(x)
        return out

    @property
    def bounds(self):
        lo, hi = self._all_bounds()
        return lo.max(axis=0), hi.min(axis=0)


class Difference(_Combination):
    """Inside the first shape and outside all the others (``a - b - ...``)."""

    def mask(self, x):
        out = self.shapes[0].mask(x)
        for s in self.shapes[1:]:
            out = out & ~s.mask(x)
        return out

    @property
    def bounds(self):
        return self.shapes[0].bounds


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
    if state.rotation or state.contact_damping:
        raise ValueError("this model already has rotating elements or contact damping; build the "
                         "model first and call enable_rotation / enable_contact_damping "
                         "(geodem.core.state) last")
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
    if state.row_stiffness:
        kr = np.take_along_axis(state.krate[idx], order, 1)
        kr[~np.take_along_axis(valid, order, 1)] = 1.0
        kw["krate"] = np.ascontiguousarray(kr)
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
