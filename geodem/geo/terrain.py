"""Terrain models: a lattice of elements under a terrain surface, with layers, a sliding body and a
fixed base (3-D block models, or 2-D sections along a line).

Surfaces
    A *surface* gives an elevation [m] at local horizontal points ``xy`` (N, 2). Accepted specs
    (:func:`surface_function`): a number (a level ``z = const``), a :class:`~geodem.geo.raster.
    Terrain` (bilinear in its grid), :class:`Depth` (``value`` metres, or a depth raster, below the
    TOP surface), or any callable ``f(xy) -> z``. :func:`slip_surface_from_pair` turns a pre/post
    event raster pair into the sliding surface.

Packing: a regular close-packed lattice (FCC in 3-D, triangular in 2-D), not a deposited packing
    A hill of 1e5-1e6 elements packed by gravity deposition (:mod:`geodem.build.packing`) needs
    tens of thousands of time steps over the whole box; the lattice is built directly, in
    O(elements), with no overlap and no locked-in force, so the model starts exactly at rest and
    gravity loading begins from zero stress. Its price is the lattice's regularity (anisotropic
    strength along its close-packed planes; monodisperse elements). To model with a random
    packing instead, pass ``packing=(x, r)`` (e.g. from :func:`geodem.build.specimen.
    make_specimen` or a deposition): it is cut by the same surfaces.

    3-D: close-packed layers normal to z at spacing ``h = d sqrt(2/3)`` (:func:`~geodem.build.
    lattice.fcc_lattice`, ABC stacking), the lowest centres at ``base_z + d/2``; the element at
    horizontal point ``p`` and layer ``k`` is kept when ``z_k = base_z + d/2 + k h <= top(p)``
    (centre inside, MatDEM's convention) and ``p`` lies inside the extent inset by ``d/2`` (whole
    elements inside the lateral faces). The layers kept above each point are counted
    arithmetically, so only kept elements are ever generated. 2-D: the same with rows along the
    section at spacing ``h = d sqrt(3)/2``, odd rows offset by ``d/2``.

    Hence the top of the model follows the terrain: every centre lies at or below it, and the
    highest centre above any point lies less than ``h`` (about one diameter on a slope) below it.

Groups (:class:`TerrainModel` keeps them as overlapping masks; a :class:`State` holds one group per
element, taken in this order of precedence)
    ``base`` centres less than ``base_thickness`` (default ``2 d``: two lattice layers) above
    ``base_z``, fixed; ``side_x`` / ``side_y`` centres within ``side_width`` (default ``d``) of the
    lateral faces (rollers: the normal degree of freedom fixed; ``sides="fixed"``: all; ``None``:
    free); ``slide`` centres above the sliding surface; the layers (first whose bottom surface lies
    below the centre, top down) and ``body`` (default ``"rock"``) below the last layer.

Coordinates are the terrain's local ones (see :mod:`geodem.geo.raster`); in 2-D the model's x is
the distance along the section line from its first point and y the elevation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from geodem.build.shapes import Shape
from geodem.geo.errors import GeometryError
from geodem.geo.raster import Terrain

__all__ = ["Depth", "Below", "TerrainModel", "terrain_model", "surface_function",
           "block_bulk_volume",
           "slip_surface_from_pair", "band_size_field", "ELEMENT_KEYS"]

SQRT2_3 = math.sqrt(2.0 / 3.0)
SQRT3_2 = math.sqrt(3.0) / 2.0
#: element parameters a material dict must give to :meth:`TerrainModel.to_state`
ELEMENT_KEYS = ("kn", "ks", "xb", "fs0", "mu", "rho")


@dataclass(frozen=True)
class Depth:
    """A surface ``value`` metres (a number, or a :class:`Terrain` of depths, positive down)
    below the top surface: ``z(p) = top(p) - depth(p)``."""

    value: object


def surface_function(spec, top=None):
    """A callable ``f(xy (N, 2)) -> z (N,)`` for a surface spec (see the module docstring);
    ``top`` (a callable) is needed for :class:`Depth`."""
    if spec is None:
        return None
    if isinstance(spec, Depth):
        if top is None:
            raise GeometryError("a Depth surface needs the top surface")
        dep = spec.value
        if isinstance(dep, Terrain):
            return lambda xy: top(xy) - dep.elevation(xy)
        try:
            dv = float(dep)
        except (TypeError, ValueError):
            raise GeometryError(f"Depth needs a number [m] or a depth Terrain, got {dep!r}") \
                from None
        if not (math.isfinite(dv) and dv >= 0):
            raise GeometryError(f"Depth must be finite and >= 0 [m], got {dv}")
        return lambda xy: top(xy) - dv
    if isinstance(spec, Terrain):
        return spec.elevation
    if isinstance(spec, (int, float, np.integer, np.floating)) and not isinstance(spec, bool):
        if not math.isfinite(float(spec)):
            raise GeometryError(f"a level surface must be finite, got {spec}")
        level = float(spec)
        return lambda xy: np.full(np.shape(xy)[:-1], level)
    if callable(spec):
        return spec
    raise GeometryError(f"not a surface: {spec!r}; give a level [m], a Terrain, Depth(...) or a "
                        "callable f(xy) -> z")


def slip_surface_from_pair(pre: Terrain, post: Terrain, min_depth: float = 0.0) -> Terrain:
    """The sliding surface from pre- and post-event terrains on the same grid.

    Where the ground went down by at least ``min_depth`` [m] (the depletion zone,
    ``pre - post >= min_depth`` and ``> 0``) the sliding surface is the post-event surface;
    elsewhere it is the pre-event surface, so no element lies above it there:
    ``z_s = post if pre - post >= max(min_depth, 0+) else pre``. The slide body is then everything
    between ``z_s`` and ``pre`` (read ``post`` with ``read_elevation(..., like=pre)``)."""
    if pre.z.shape != post.z.shape or not np.allclose(pre.transform, post.transform) \
            or not np.allclose(pre.origin, post.origin):
        raise GeometryError(f"pre/post terrains must share their grid (shapes {pre.z.shape} and "
                            f"{post.z.shape}); read the second with read_elevation(..., like=pre)")
    drop = pre.z - post.z
    zs = np.where((drop > 0) & (drop >= min_depth), post.z, pre.z)
    return Terrain(z=zs, transform=pre.transform, crs=pre.crs, origin=pre.origin,
                   extent=pre.extent, source=f"slip({pre.source}, {post.source})",
                   source_crs=pre.source_crs, epsg=pre.epsg,
                   info={"depleted_cells": int(((drop > 0) & (drop >= min_depth)).sum())})


def _line(line):
    try:
        p = np.asarray(line, float)
    except (TypeError, ValueError):
        p = np.zeros(0)
    if p.shape != (2, 2) or not np.all(np.isfinite(p)):
        raise GeometryError(f"line must be two local points ((x0, y0), (x1, y1)), got {line!r}")
    length = float(np.linalg.norm(p[1] - p[0]))
    if not length > 0:
        raise GeometryError(f"line has zero length: {line!r}")
    return p[0], (p[1] - p[0]) / length, length


def plan_xy(x, line):
    """Local horizontal (x, y) of model points: x[:, :2] in 3-D; p0 + s u in 2-D."""
    x = np.asarray(x, float)
    if x.shape[-1] == 3:
        return x[..., :2]
    if line is None:
        raise GeometryError("a 2-D (section) model needs its line to reach the terrain")
    p0, u, _ = _line(line)
    return p0 + x[..., :1] * u


def band_size_field(top, d, factor, band, transition, *, sliding_surface=None, line=None,
                    above=None):
    """Size field of a graded terrain model (:mod:`geodem.build.graded`): fine elements
    (diameter ``d``) in a band along the ground, coarser ones (up to ``factor d``) below it.

    The fine region holds every point from ``above`` (default ``2 d``) above the top surface
    down to ``band`` metres below the top surface and ``band`` below the sliding surface
    (when given: the slide body and a band of ground under it). Below (and above) it the
    diameter grows linearly with the vertical distance ``e`` to the fine region,
    ``d (1 + (factor - 1) min(e / transition, 1))`` (:func:`geodem.build.graded.ramp`).
    ``top`` and ``sliding_surface`` are surface specs (:func:`surface_function`), ``line`` the
    section line of a 2-D model. Returns ``size(x (N, dim)) -> (N,)`` [m]."""
    from geodem.build.graded import ramp

    for name, v in (("d", d), ("band", band)):
        if not (math.isfinite(float(v)) and float(v) > 0):
            raise GeometryError(f"{name} must be finite and > 0 [m], got {v!r}")
    if not (math.isfinite(float(factor)) and float(factor) >= 1):
        raise GeometryError(f"factor must be finite and >= 1, got {factor!r}")
    if not (math.isfinite(float(transition)) and float(transition) >= 0):
        raise GeometryError(f"transition must be finite and >= 0 [m], got {transition!r}")
    ftop = surface_function(top)
    fslip = surface_function(sliding_surface, ftop)
    up = 2.0 * float(d) if above is None else float(above)

    def size(x):
        x = np.asarray(x, float)
        h = plan_xy(x, line)
        zt = ftop(h)
        floor = zt - band
        if fslip is not None:
            floor = np.minimum(floor, fslip(h) - band)
        z = x[:, -1]
        return ramp(np.maximum(floor - z, z - zt - up), d, factor, transition)

    return size


class Below(Shape):
    """Centres at or below a surface (plus ``offset`` [m]): ``z <= f(x, y) + offset`` in 3-D;
    in 2-D (a section along ``line``) ``y <= f(p0 + x u) + offset``. Combine with other shapes to
    cut any packing by a terrain, e.g. ``Box(lo, hi) & Below(terrain)``."""

    def __init__(self, surface, offset=0.0, line=None):
        self.surface = surface
        self.f = surface_function(surface)
        self.offset = float(offset)
        self.line = line

    def __repr__(self):
        return f"Below({self.surface!r}, offset={self.offset})"

    def mask(self, x):
        x = np.asarray(x, float)
        if x.ndim != 2 or x.shape[1] not in (2, 3):
            raise ValueError(f"positions must have shape (N, 2) or (N, 3), got {x.shape}")
        return x[:, -1] <= self.f(plan_xy(x, self.line)) + self.offset

    @property
    def bounds(self):
        dim = 2 if self.line is not None else 3
        lo, hi = np.full(dim, -np.inf), np.full(dim, np.inf)
        if isinstance(self.surface, Terrain):
            hi[-1] = float(self.surface.z.max()) + self.offset
        return lo, hi


@dataclass
class TerrainModel:
    """Elements of a terrain model (see the module docstring) before they become a State.

    ``x`` (N, dim) centres [m] (local; 2-D: distance along the line, elevation), ``r`` (N,)
    radii [m]; ``layer`` (N,) index into ``names`` (the layers top down, then the body);
    ``masks`` overlapping bool (N,) masks ``base``, ``side_x``, ``side_y`` (3-D), ``slide``;
    ``top_z`` (N,) the top surface above each element; ``base_z`` [m]; ``extent`` local
    ``(xmin, ymin, xmax, ymax)`` (3-D) or ``(0, length)`` (2-D); ``line``; ``d`` [m];
    ``metadata`` the terrain's georeferencing (:meth:`Terrain.metadata`); ``info`` counts.
    """

    x: np.ndarray
    r: np.ndarray
    dim: int
    d: float
    layer: np.ndarray
    names: list
    masks: dict
    top_z: np.ndarray
    base_z: float
    extent: tuple
    line: tuple | None = None
    metadata: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.r)

    def __repr__(self) -> str:
        """One short line whatever the size (the generated dataclass repr printed every
        array): size, element diameter, layers and masks with their counts, extent, base and
        top, CRS, arrays."""
        from geodem.core.state import _clip, array_summary
        from geodem.geo.raster import _crs_label

        try:
            layer = np.asarray(self.layer)
            layers = ", ".join(f"{nm} {int((layer == k).sum())}"
                               for k, nm in enumerate(self.names))
            masks = ", ".join(f"{nm} {int(np.count_nonzero(m))}" for nm, m in self.masks.items())
            e = tuple(float(v) for v in self.extent)
            if self.dim == 2:
                where = f"section 0..{e[-1]:.6g} m"
                if self.line is not None:
                    (a, b), (c, d) = self.line
                    where += f" along ({a:.6g}, {b:.6g})-({c:.6g}, {d:.6g})"
            else:
                where = f"extent x {e[0]:.6g}..{e[2]:.6g}, y {e[1]:.6g}..{e[3]:.6g} m"
            parts = [f"dim={self.dim}", f"n={self.n}", f"d={self.d:.4g} m",
                     _clip(f"layers [{layers}]", 120), _clip(f"masks [{masks}]", 120), where,
                     f"base_z {float(self.base_z):.6g} m"]
            if len(self.top_z):
                lo, hi = float(np.min(self.top_z)), float(np.max(self.top_z))
                parts.append(f"top {lo:.6g}..{hi:.6g} m")
            md = self.metadata or {}
            if md:
                epsg = md.get("epsg", -1)
                parts.append(f"EPSG:{epsg}" if epsg not in (None, -1)
                             else _crs_label(md.get("crs")))
            parts.append(array_summary({"x": self.x, "r": self.r, "layer": self.layer,
                                        "top_z": self.top_z}, limit=120))
            return f"TerrainModel({', '.join(parts)})"
        except Exception as exc:  # noqa: BLE001 - a repr must not raise
            return f"TerrainModel(<unprintable: {type(exc).__name__}>)"

    def group_order(self):
        """Group names from the lowest to the highest precedence (a State keeps the last)."""
        out = list(reversed(self.names)) + ["slide", "side_y", "side_x", "base"]
        return [g for g in out if g in self.names or g in self.masks]

    def group_masks(self) -> dict:
        """Exclusive masks, one group per element, by precedence (base > side_x > side_y >
        slide > layers top down > body)."""
        owner = np.full(self.n, -1, np.int64)
        order = self.group_order()
        for k, g in enumerate(order):
            sel = self.masks[g] if g in self.masks else self.layer == self.names.index(g)
            owner[sel] = k
        return {g: owner == k for k, g in enumerate(order)}

    def to_state(self, materials, *, gravity=9.81, sides="roller", slide_bond_rate=None,
                 gap=None, thickness=None, sort=True):
        """A bonded :class:`~geodem.core.state.State` of the model.

        ``materials``: one dict of element parameters (``kn, ks`` [N/m], ``xb`` [m], ``fs0``
        [N], ``mu`` [-], ``rho`` [kg/m^3], optional ``mass`` [kg]) for every element, or a dict
        ``{group name: dict}`` covering every layer and the body; a ``"slide"`` entry overrides
        the slide body's. A value may also be an array with one entry per element (e.g. the
        per-size parameters of a graded packing, :func:`geodem.build.graded.scale_params`).
        Every touching pair is bonded (surface gap ``<= gap``, default
        ``1e-6 d``: the lattice's neighbours). ``gravity`` [m/s^2] along -z (-y in 2-D).
        ``sides``: ``"roller"`` (side groups' normal DOF fixed), ``"fixed"``, or None (free).
        ``slide_bond_rate``: bonds between the slide body and the ground below get this bond
        rate (scales their breaking force and Fs0; ``0`` removes them: contacts without bonds).
        Groups as :meth:`group_masks`; the base is fixed. ``sort``: Morton order.
        """
        from geodem.build.lattice import bonded_state
        from geodem.core import groups as grp
        from geodem.core.state import BONDED, UNBONDED

        if self.n == 0:
            raise GeometryError("the terrain model has no element")
        per = self._element_params(materials, thickness)
        g = 1e-6 * self.d if gap is None else float(gap)
        st = bonded_state(self.x, self.r, density=per["rho"], kn=per["kn"], ks=per["ks"],
                          xb=per["xb"], fs0=per["fs0"], mu=per["mu"], gap=g, thickness=thickness)
        if per.get("mass") is not None:
            st.m[:] = per["mass"]
        st.gravity = np.zeros(self.dim)
        st.gravity[-1] = -float(gravity)
        gm = self.group_masks()
        for name in self.group_order():
            grp.add_group(st, name, gm[name])
        grp.fix(st, "base")
        if sides not in ("roller", "fixed", None):
            raise GeometryError(f"sides must be 'roller', 'fixed' or None, got {sides!r}")
        for k, name in enumerate(("side_x", "side_y")[:self.dim - 1]):
            if sides is not None and name in st.groups:
                grp.fix(st, name, None if sides == "fixed" else k)
        if slide_bond_rate is not None and "slide" in self.masks:
            rate = float(slide_bond_rate)
            if not (math.isfinite(rate) and rate >= 0):
                raise GeometryError(f"slide_bond_rate must be finite and >= 0, got {rate}")
            sl = self.masks["slide"]
            nb = st.nbr
            cross = (nb >= 0) & (st.cstate == BONDED) & (sl[:, None] != sl[np.maximum(nb, 0)])
            if rate == 0.0:
                st.cstate[cross] = UNBONDED
            else:
                st.brate[cross] = rate
        if sort:
            from geodem.core.neighbors import spatial_sort

            spatial_sort(st)
        return st

    def _element_params(self, materials, thickness=None):
        if not isinstance(materials, dict) or not materials:
            raise GeometryError("materials must be a dict of element parameters, or a dict "
                                "{group: parameters}")
        single = all(k in materials for k in ELEMENT_KEYS)
        table = {n: materials for n in self.names} if single else dict(materials)
        missing = [n for n in self.names if n not in table and (self.layer == self.names.index(n))
                   .any()]
        if missing:
            raise GeometryError(f"materials lacks {missing}; it covers {sorted(table)} (give one "
                                f"for every layer and the body: {self.names})")
        owner = [(self.layer == self.names.index(n)) for n in self.names]
        if "slide" in table and not single and "slide" in self.masks:
            owner_names = self.names + ["slide"]
            owner = [o & ~self.masks["slide"] for o in owner] + [self.masks["slide"]]
        else:
            owner_names = self.names
        out = {}
        for key in ELEMENT_KEYS + ("mass",):
            arr = np.zeros(self.n)
            any_mass = False
            for name, sel in zip(owner_names, owner):
                if not sel.any():
                    continue
                mat = table[name]
                if key == "mass":
                    if mat.get("mass") is not None:
                        mv = mat["mass"]
                        arr[sel] = np.asarray(mv, float)[sel] if np.ndim(mv) == 1 else float(mv)
                        any_mass = True
                    continue
                if key not in mat:
                    raise GeometryError(f"material of {name!r} lacks {key!r}; needed: "
                                        f"{list(ELEMENT_KEYS)}")
                val = mat[key]
                arr[sel] = np.asarray(val, float)[sel] if np.ndim(val) == 1 else float(val)
            out[key] = arr if (key != "mass" or any_mass) else None
        if out["mass"] is not None and np.any(out["mass"] <= 0):
            # some materials give masses and some do not: fill the rest from rho
            from geodem.build.packing import element_volume

            t = 2.0 * self.r if thickness is None else float(thickness)
            m = out["rho"] * (element_volume(self.r, 3) if self.dim == 3 else
                              element_volume(self.r, 2) * t)
            out["mass"] = np.where(out["mass"] > 0, out["mass"], m)
        return out


# ============================================================================ builder
def _lattice_columns(extent, d, dim):
    """Horizontal lattice points per stacking pattern: list of (M_p, dim-1) arrays, the period
    and layer spacing."""
    r = 0.5 * d
    if dim == 3:
        from geodem.build.lattice import fcc_lattice

        xmin, ymin, xmax, ymax = extent
        lx, ly = xmax - xmin, ymax - ymin
        nxl = int(math.floor((lx - d) / d)) + 2
        nyl = int(math.floor((ly - d) / (d * SQRT3_2))) + 2
        if lx < d or ly < d:
            raise GeometryError(f"the extent {extent} is narrower than one element (d = {d})")
        pat = fcc_lattice(nxl, nyl, 3, d).reshape(3, -1, 3)[:, :, :2] + [xmin + r, ymin + r]
        eps = 1e-9 * d
        keep = [(p[:, 0] <= xmax - r + eps) & (p[:, 1] <= ymax - r + eps) for p in pat]
        return [p[k] for p, k in zip(pat, keep)], 3, d * SQRT2_3
    (s0, s1) = extent
    if s1 - s0 < d:
        raise GeometryError(f"the section ({s1 - s0:.4g} m) is shorter than one element (d = {d})")
    out = []
    for off in (0.0, 0.5 * d):
        s = s0 + r + off + d * np.arange(int(math.floor((s1 - s0 - d - off) / d + 1e-9)) + 1)
        out.append(s[:, None])
    return out, 2, d * SQRT3_2


def terrain_model(top, d, *, base_z=None, base_depth=None, layers=(), body="rock",
                  sliding_surface=None, dim=3, line=None, extent=None, base_thickness=None,
                  side_width=None, packing=None, max_elements=2_000_000) -> TerrainModel:
    """Elements under the terrain ``top`` (see the module docstring).

    Parameters
    ----------
    top : :class:`Terrain` (or a surface callable, then ``extent`` is required): the ground.
    d : element diameter [m] (lattice spacing).
    base_z / base_depth : the model's bottom [m]: a level, or a depth below the lowest point of
        the top surface inside the model (default ``base_depth = 5 d``).
    layers : ``[(name, bottom surface), ...]`` top down; elements above a layer's bottom (and
        below the previous one's) belong to it; below the last: ``body``.
    sliding_surface : surface spec; elements above it form the ``slide`` mask.
    dim : 3 (block under the terrain) or 2 (section along ``line``).
    line : 2-D: ``((x0, y0), (x1, y1))`` local; default west to east through the extent's middle.
    extent : local ``(xmin, ymin, xmax, ymax)``; default the terrain's extent.
    base_thickness : thickness of the fixed base [m] (default ``2 d``); with ``packing``, also
        one value per packing element (e.g. two of its own diameters: a graded packing).
    side_width : thickness of the side groups [m] (default ``d``; 0 for none); per packing
        element as ``base_thickness``.
    packing : ``(x, r)`` to cut instead of the lattice (centres in the local model frame).
    max_elements : refuse models larger than this (the count is known before generating).
    """
    d = float(d)
    if not (math.isfinite(d) and d > 0):
        raise GeometryError(f"d must be a finite diameter > 0 [m], got {d!r}")
    if dim not in (2, 3):
        raise GeometryError(f"dim must be 2 or 3, got {dim!r}")
    ftop = surface_function(top)
    if isinstance(top, Terrain):
        ext = top.extent if extent is None else tuple(map(float, extent))
        gb = top.grid_bounds
        tol = 1e-9 * max(gb[2] - gb[0], gb[3] - gb[1])
        if (ext[0] < gb[0] - tol or ext[1] < gb[1] - tol or ext[2] > gb[2] + tol
                or ext[3] > gb[3] + tol):
            raise GeometryError(f"extent {ext} is not covered by the terrain grid {gb} (local m)")
    else:
        if extent is None:
            raise GeometryError("give extent= (local xmin, ymin, xmax, ymax) for a top surface "
                                "that is not a Terrain")
        ext = tuple(map(float, extent))
    if len(ext) != 4 or not (ext[2] > ext[0] and ext[3] > ext[1]):
        raise GeometryError(f"extent must be (xmin, ymin, xmax, ymax), got {ext}")
    r = 0.5 * d
    if dim == 2:
        if line is None:
            yc = 0.5 * (ext[1] + ext[3])
            line = ((ext[0], yc), (ext[2], yc))
        p0, u, length = _line(line)
        for p in (p0, p0 + length * u):
            if not (ext[0] - 1e-9 * length <= p[0] <= ext[2] + 1e-9 * length
                    and ext[1] - 1e-9 * length <= p[1] <= ext[3] + 1e-9 * length):
                raise GeometryError(f"line end {tuple(p)} lies outside the extent {ext}")
        line = (tuple(map(float, p0)), tuple(map(float, p0 + length * u)))
        lat_extent = (0.0, length)
    else:
        line = None
        lat_extent = ext

    def horiz(h):
        """Local (x, y) of horizontal model coordinates ((M, 2) in 3-D, (M, 1) in 2-D)."""
        return h if dim == 3 else p0 + h[:, :1] * u

    bt = 2.0 * d if base_thickness is None else base_thickness
    sw = d if side_width is None else side_width
    per_element = [np.ndim(v) == 1 for v in (bt, sw)]
    if any(per_element) and packing is None:
        raise GeometryError("per-element base_thickness / side_width need packing=(x, r)")
    bt, sw = (np.asarray(v, float) if pe else float(v) for v, pe in zip((bt, sw), per_element))
    if packing is None:
        pats, period, h = _lattice_columns(lat_extent, d, dim)
        tops = [ftop(horiz(p)) for p in pats]
        zmin = min(float(t.min()) for t in tops if t.size)
    else:
        px, pr = (np.asarray(a, float) for a in packing)
        if px.ndim != 2 or px.shape[1] != dim or pr.shape != (len(px),):
            raise GeometryError(f"packing must be (x (N, {dim}), r (N,)), got shapes {px.shape}, "
                                f"{pr.shape}")
        lo = np.array(lat_extent[:dim - 1])
        hi = np.array(lat_extent[dim - 1:])
        inside = np.all((px[:, :-1] >= lo) & (px[:, :-1] <= hi), axis=1)
        px, pr = px[inside], pr[inside]
        ptop = ftop(horiz(px[:, :-1]))
        zmin = float(ptop.min()) if len(ptop) else 0.0
    if base_z is not None and base_depth is not None:
        raise GeometryError("give base_z or base_depth, not both")
    if base_z is None:
        bd = 5.0 * d if base_depth is None else float(base_depth)
        if not (math.isfinite(bd) and bd > 0):
            raise GeometryError(f"base_depth must be finite and > 0 [m], got {base_depth!r}")
        zb = zmin - bd
    else:
        zb = float(base_z)
        if not zb <= zmin - d:
            raise GeometryError(f"base_z = {zb:.6g} m must lie at least one element diameter "
                                f"({d:.4g} m) below the lowest point of the top surface "
                                f"({zmin:.6g} m)")
    # ---- elements
    if packing is None:
        counts = []
        for p, t in zip(range(period), tops):
            kmax = np.floor((t - zb - r) / h + 1e-9).astype(np.int64)
            counts.append(np.where(kmax >= p, (kmax - p) // period + 1, 0))
        total = int(sum(int(c.sum()) for c in counts))
        if total > max_elements:
            raise GeometryError(f"the model would hold {total} elements (> max_elements = "
                                f"{max_elements}); use larger elements (d = {d:.4g} m now: "
                                f"x2 in d divides the count by ~{2 ** dim}) or raise max_elements")
        xs, tz = [], []
        for p, (pts, t, c) in enumerate(zip(pats, tops, counts)):
            idx = np.repeat(np.arange(len(pts)), c)
            start = np.repeat(np.cumsum(c) - c, c)
            k = p + period * (np.arange(idx.size) - start)
            xs.append(np.c_[pts[idx], zb + r + k * h])
            tz.append(t[idx])
        x = np.concatenate(xs) if xs else np.zeros((0, dim))
        top_z = np.concatenate(tz)
        rr = np.full(len(x), r)
    else:
        keep = (px[:, -1] <= ptop) & (px[:, -1] - pr >= zb - 1e-9 * d)
        x, rr, top_z = px[keep], pr[keep], ptop[keep]
        kept = np.flatnonzero(inside)[keep]
        if per_element[0]:
            bt = bt[kept]
        if per_element[1]:
            sw = sw[kept]
        if len(x) > max_elements:
            raise GeometryError(f"the model would hold {len(x)} elements (> max_elements = "
                                f"{max_elements})")
    hz = horiz(x[:, :-1])
    zc = x[:, -1]
    # ---- masks
    masks = {"base": zc < zb + bt - 1e-9 * d}
    if np.any(sw > 0):
        tol = 1e-9 * d
        masks["side_x"] = (x[:, 0] <= lat_extent[0] + sw + tol) | \
            (x[:, 0] >= lat_extent[dim - 1] - sw - tol)
        if dim == 3:
            masks["side_y"] = (x[:, 1] <= ext[1] + sw + tol) | (x[:, 1] >= ext[3] - sw - tol)
    fslip = surface_function(sliding_surface, ftop)
    if fslip is not None:
        masks["slide"] = zc > fslip(hz)
    names = []
    bottoms = []
    for item in layers:
        try:
            lname, spec = item
        except (TypeError, ValueError):
            raise GeometryError(f"layers must be (name, bottom surface) pairs, got {item!r}") \
                from None
        names.append(str(lname))
        bottoms.append(surface_function(spec, ftop))
    names.append(str(body))
    if len(set(names)) != len(names) or set(names) & {"base", "side_x", "side_y", "slide", "all"}:
        raise GeometryError(f"layer and body names must be distinct and not base, side_x, "
                            f"side_y, slide or all; got {names}")
    layer = np.full(len(x), len(names) - 1, np.int16)
    for k in range(len(bottoms) - 1, -1, -1):  # the first (top-most) match wins
        layer[zc >= bottoms[k](hz)] = k
    meta = top.metadata() if isinstance(top, Terrain) else {}
    info = {"n_elements": int(len(x)), "base_z": zb, "top_min": zmin,
            "top_max": float(top_z.max()) if len(top_z) else zmin,
            "packing": "lattice" if packing is None else "given",
            # packing=(x, r): the index of each kept element in the given packing
            "packing_index": None if packing is None else kept,
            "counts": {**{n: int((layer == i).sum()) for i, n in enumerate(names)},
                       **{k: int(v.sum()) for k, v in masks.items()}}}
    return TerrainModel(x=x, r=rr, dim=dim, d=d, layer=layer, names=names, masks=masks,
                        top_z=top_z, base_z=zb, extent=ext if dim == 3 else lat_extent,
                        line=line, metadata=meta, info=info)


def block_bulk_volume(top, extent, base_z: float) -> float:
    """Volume [m^3] between the base ``base_z`` and the ground of elevation raster ``top`` over
    the local ``extent`` ``(xmin, ymin, xmax, ymax)`` of a 3-D terrain block (the cells whose
    centres lie inside it)."""
    c = top.centres().reshape(-1, 2)
    e = extent
    inside = (c[:, 0] >= e[0]) & (c[:, 0] <= e[2]) & (c[:, 1] >= e[1]) & (c[:, 1] <= e[3])
    return float(np.sum(top.z.reshape(-1)[inside] - base_z) * top.dx * top.dy)
