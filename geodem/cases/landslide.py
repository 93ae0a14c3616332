"""Landslide from an elevation raster (MatDEM's landslide case, PHYSICS.md section 7).

* model ``landslide``: the ground under an elevation raster (:func:`geodem.geo.raster.
  read_elevation`: CRS, nodata, local origin) as a bonded random packing, cut by the terrain
  (:func:`geodem.geo.terrain.terrain_model` with ``packing=``): a 2-D section along ``line``
  (default) or a 3-D block. The slide body is every element above the sliding surface, given by
  a raster of its depth below the ground (``slip_depth``) or of its elevation (``slip_surface``,
  e.g. a post-event DEM: :func:`~geodem.geo.terrain.slip_surface_from_pair`). Groups ``slide``,
  ``ground``, ``base`` (fixed), ``side_x``/``side_y`` (rollers). Element diameter
  ``diameter / scale``.

  Packing: a random packing (sizes uniform in ``[d_min, d_max]``, ``distri_rate``) deposited
  under gravity in a box spanning the model (:mod:`geodem.build.packing`: random placement, then
  deposition), then cut by the terrain; every pair closer than ``bond_gap`` d is bonded. Not
  the close-packed lattice: a lattice cut by a curved sliding surface leaves a staircase that
  interlocks with the ground, and the lattice itself only shears by dilating a whole row (the
  elements do not rotate), so a lattice slide does not move even when every bond is cut.

* step ``landslide``: gravity settling (one standard balance, ``eta_c / N`` damping, all bonds
  intact), then the trigger (strength reduction, at one instant): the bonds across the sliding
  surface get bond rate ``slip_bond_rate`` (0: cut, logged as joints), the slide's elements get
  friction ``slide_friction`` and their bond strength (``xb``, ``fs0``) times
  ``strength_factor`` (0: the slide's own bonds are cut too: a cohesionless mass); damping is set
  to ``damping_ratio`` of critical (default 0: only friction and breakage dissipate). The slide
  then moves under gravity until it is at rest (mean speed of the slide's elements back below
  ``rest_speed`` after having exceeded it, and at least ``min_time``) or ``max_time``.

Results (summary.json):

* ``runout_m``: horizontal distance from the source's original toe (the down-slope-most point
  of the slide body before the trigger: max of ``h + r``) to the deposit front (max of ``h + r``
  over the *displaced* slide elements at the end), ``h`` the horizontal coordinate along the
  direction of motion (the horizontal displacement of the slide's mass centre; in 2-D the
  section's axis);
* ``travel_angle_deg`` = ``atan(H / L)``: from the crown top (the highest point of the source:
  max of ``z + r``) to the deposit tip (the front-most displaced element, its lowest point
  ``z - r``), ``H`` the drop and ``L`` the horizontal distance between them (Heim's
  Fahrboeschung);
* ``max_velocity`` [m/s]: the largest, over the samples, of the mean element speed of the
  slide body (``max_element_speed``: of the fastest slide element);
* ``deposit_volume_m3``: solid volume of the displaced slide elements (displacement above
  ``moved_threshold`` d): spheres ``4/3 pi r^3`` in 3-D; in 2-D discs ``pi r^2`` per metre of
  thickness (m^3 per metre of width). ``deposit_bulk_volume_m3`` divides it by the solid
  fraction of the packing (bulk volume, pores included);
* ``com_drop_m`` ``H_c``, ``com_travel_m`` ``L_c`` (mass centre of the slide body),
  ``com_ratio`` = ``H_c / L_c``; ``wall_s`` (wall time of the step), ``elements``.

Energy bound: once triggered the slide is driven by gravity alone and loses energy to
friction, breakage and damping. A mass sliding from rest to rest with Coulomb friction ``mu``
dissipates at least ``mu M g L_c`` on a concave path (the normal force is at least the weight's
normal component), so ``H_c / L_c >= mu``; the elements do not rotate, so they cannot roll
past the bound.

Outputs: ``landslide_history.csv``, ``landslide_velocity.png``, ``landslide_deposit.png``,
``landslide_snapshots.png``, ``landslide.gif``, ``landslide_vtk/*.vtp`` (+ ``frames.pvd``,
points in the raster's CRS coordinates), ``georef.json`` (CRS WKT, EPSG, transform, local
origin, section line) and the same as attributes of ``output.h5``.
"""
from __future__ import annotations

import csv
import functools
import json
import math
import os
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.workflow.models import ROOT, BuildError, BuiltModel, element_params, \
    resolve_path, state_bytes_per_element
from geodem.workflow.scene import CoarsenSpec  # noqa: F401 - the landslide model's field
from geodem.workflow.schema import F, Int, ModelBase, Name, StepBase, Strict, register_model, \
    register_step

HISTORY = "landslide_history.csv"
COLUMNS = ("step", "time", "mean_speed", "max_speed", "kinetic_energy", "com_h", "com_z",
           "front_h", "displaced")
FRAMES_DIR = "landslide_frames"
VTK_DIR = "landslide_vtk"
GEOREF = "georef.json"
START = "landslide_start.npz"


# ============================================================================ rasters
@functools.lru_cache(maxsize=8)
def _read(path: str, mtime: float, crs, like: tuple | None):
    from geodem.geo import read_elevation

    top = None
    if like is not None:
        top = _read(*like)
    return read_elevation(path, crs=crs, like=top)


def read_terrains(model):
    """``(top Terrain, sliding-surface spec)``; GeometryError (with ``.field``) on bad input."""
    from geodem.geo import GeometryError
    from geodem.geo.terrain import Depth, slip_surface_from_pair

    def key(field, like=None):
        p = resolve_path(getattr(model, field))
        try:
            mt = os.path.getmtime(p)
        except OSError:
            err = GeometryError(f"{getattr(model, field)}: no such file (looked in the working "
                                f"directory {Path.cwd()} and in {ROOT})")
            err.field = field
            raise err from None
        return (str(p), mt, model.crs, like)

    if model.crs is not None:
        from rasterio.crs import CRS
        from rasterio.errors import CRSError

        try:
            CRS.from_user_input(model.crs)
        except CRSError as exc:
            err = GeometryError(f"{model.crs!r} is not a CRS ({exc}); allowed: an EPSG code "
                                "(e.g. EPSG:32632), a WKT or a PROJ string")
            err.field = "crs"
            raise err from None
    k = key("raster")
    try:
        top = _read(*k)
    except GeometryError as exc:
        raise _workflow_error(exc, "raster") from None
    field = "slip_depth" if model.slip_depth is not None else "slip_surface"
    ks = key(field, k)
    try:
        other = _read(*ks)
    except GeometryError as exc:
        raise _workflow_error(exc, field) from None
    if field == "slip_depth":
        return top, Depth(other)
    return top, slip_surface_from_pair(top, other)


#: hints of :func:`geodem.geo.read_elevation` naming its arguments (the workflow has no such
#: fields) -> what to do in a workflow
_HINTS = (
    ("pass band=k to choose one", "extract the elevation band first (e.g. gdal_translate -b 1 "
                                  "in.tif dem.tif)"),
    ("give target_crs= (a projected CRS in metres) and z_scale= for elevations not in metres",
     "convert it first to a projected CRS in metres, elevations in metres (e.g. gdalwarp "
     "-t_srs EPSG:32632 in.tif dem.tif; feet: gdal_calc.py --calc='A*0.3048')"),
    ("give it with crs=..., e.g. crs='EPSG:32633'", "give it with model.crs, e.g. EPSG:32632"),
    ("give transform=(dx, 0, west, 0, -dy, north)",
     "georeference it first (e.g. gdal_translate -a_srs EPSG:32632 -a_ullr west north east "
     "south in.tif dem.tif)"),
    ("; give region=", "; crop or convert it first (e.g. gdalwarp -t_srs EPSG:32632 -te xmin "
                       "ymin xmax ymax in.tif dem.tif)"),
    (" (max_nodata_fraction); choose a region inside the valid data",
     "; crop it to the valid data first (e.g. gdalwarp -te xmin ymin xmax ymax in.tif "
     "dem.tif)"),
    ("; choose a region inside it", "; this raster must cover the elevation raster (model."
                                    "raster)"),
)


def _workflow_error(exc, field):
    """A GeometryError of :func:`read_elevation` for the workflow field ``field``: its hints
    rewritten to say what to do in a workflow (:data:`_HINTS`)."""
    from geodem.geo import GeometryError

    msg = str(exc)
    for old, new in _HINTS:
        msg = msg.replace(old, new)
    if field != "raster" and "the requested region" in msg:
        msg = msg.replace("the requested region", "the elevation raster's area")
    err = GeometryError(msg)
    err.field = getattr(exc, "field", field) if field == "raster" else field
    return err


def _num(v) -> str:
    return f"{float(v):g}"


def _pt(p) -> str:
    return "[" + ", ".join(_num(v) for v in p) + "]"


def _box(b) -> str:
    return f"x {_num(b[0])} .. {_num(b[2])}, y {_num(b[1])} .. {_num(b[3])}"


# ============================================================================ model
@register_model("landslide")
class Landslide(ModelBase):
    """The ground under an elevation raster as a bonded random packing (2-D section or 3-D
    block) with a slide body above a sliding surface (depth or elevation raster); groups
    slide, ground, base (fixed), side_x/side_y (rollers)."""

    size_field = "scale"
    example = {"type": "landslide", "raster": "workflows/data/hill.tif",
               "slip_depth": "workflows/data/hill_slip_depth.tif", "material": "rock",
               "line": [[100.0, 150.0], [400.0, 150.0]], "diameter": 8.0}
    raster: str = F(..., description="Elevation raster (GeoTIFF or any format GDAL reads) with "
                                     "a CRS; relative paths: the working directory, else the "
                                     "geodem source tree")
    slip_depth: Optional[str] = F(None, description="Raster of the sliding surface's depth "
                                                    "below the ground [m, positive down]")
    slip_surface: Optional[str] = F(None, description="Raster of the sliding surface's "
                                                      "elevation [m] (e.g. a post-event DEM)")
    crs: Optional[str] = F(None, description="CRS of the rasters when the files have none "
                                             "(e.g. EPSG:32632)")
    dim: Literal[2, 3] = F(2, description="2: a section along line; 3: a block")
    line: Optional[list[list[float]]] = F(
        None, unit="m", description="2-D section [[x0, y0], [x1, y1]] in local raster "
                                    "coordinates (from the raster's SW corner); default west "
                                    "to east through the middle")
    extent: Optional[list[float]] = F(None, unit="m", min_length=4, max_length=4,
                                      description="3-D: local [xmin, ymin, xmax, ymax] "
                                                  "(default the raster's)")
    diameter: float = F(3.0, unit="m", gt=0, description="Mean element diameter at scale 1")
    scale: float = F(1.0, ge=0.05, le=100.0,
                     description="Resolution knob: d = diameter / scale (elements ~ "
                                 "scale^dim)")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing "
                                                        "(d_max / d_min = (1 + r)^2)")
    base_depth: float = F(10.0, unit="m", gt=0,
                          description="Depth of the model's base below the lowest ground")
    bond_gap: float = F(1e-3, ge=0, le=0.1,
                        description="Pairs closer than this x d are bonded")
    material: Name = F(..., description="Material of the ground (element parameters)")
    slide_material: Optional[Name] = F(None, description="Material of the slide body "
                                                         "(default: material)")
    gravity: float = F(9.81, unit="m/s^2", gt=0, le=100, description="Gravity (down)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    coarsen: Optional[CoarsenSpec] = F(None, description="Graded model: coarser elements in "
                                                         "the deep ground (docs/graded.md); "
                                                         "default off (uniform d)")

    @model_validator(mode="after")
    def _one_surface(self):
        if (self.slip_depth is None) == (self.slip_surface is None):
            raise ValueError("give exactly one of slip_depth and slip_surface (the sliding "
                             "surface: its depth below the ground, or its elevation)")
        if self.line is not None and (len(self.line) != 2 or any(len(p) != 2 for p in self.line)):
            raise ValueError("line must be two points [[x0, y0], [x1, y1]] [m]")
        return self

    @property
    def d(self) -> float:
        return self.diameter / self.scale

    def _lattice(self):
        """The model's lattice version (fast): geometry, base level, element-count estimate.
        GeometryError with ``.field`` (a field of this model) on bad input."""
        from geodem.extras import needs_extra
        from geodem.geo import GeometryError, terrain_model

        with needs_extra("landslide"):  # rasterio: the 'geo' extra
            top, slip = read_terrains(self)
        self._check_geometry(top)
        try:
            return top, slip, terrain_model(
                top, self.d, base_depth=self.base_depth, dim=self.dim, body="ground",
                line=self.line, extent=self.extent, sliding_surface=slip)
        except GeometryError as exc:
            raise self._model_error(exc, top) from None

    def _check_geometry(self, top):
        """``extent`` and ``line`` against the raster (local m), before terrain_model."""
        from geodem.geo import GeometryError

        def fail(field, msg):
            err = GeometryError(msg)
            err.field = field
            return err

        gb = top.grid_bounds
        area = f"{_box(gb)} (local m from the raster's SW corner)"
        if self.extent is not None:
            e = [float(v) for v in self.extent]
            if not all(map(math.isfinite, e)) or not (e[2] > e[0] and e[3] > e[1]):
                raise fail("extent", f"{_pt(e)} is not [xmin, ymin, xmax, ymax] with xmax > "
                                     "xmin and ymax > ymin (finite, local m)")
            tol = 1e-9 * max(gb[2] - gb[0], gb[3] - gb[1])
            if (e[0] < gb[0] - tol or e[1] < gb[1] - tol or e[2] > gb[2] + tol
                    or e[3] > gb[3] + tol):
                raise fail("extent", f"{_pt(e)} is not covered by the raster; allowed: inside "
                                     f"{area}")
            ext = tuple(e)
        else:
            ext = tuple(top.extent)
        if self.dim == 2 and self.line is not None:
            p = np.asarray(self.line, float)
            if not np.all(np.isfinite(p)):
                raise fail("line", f"{[_pt(q) for q in p]} has coordinates that are not finite")
            length = float(np.linalg.norm(p[1] - p[0]))
            if not length > 0:
                raise fail("line", f"the two points are the same ({_pt(p[0])}): the section "
                                   "has zero length; allowed: two distinct points [[x0, y0], "
                                   "[x1, y1]] [m]")
            where = (area if self.extent is None
                     else f"the model's extent {_box(ext)} (local m)")
            for q in p:
                if not (ext[0] - 1e-9 * length <= q[0] <= ext[2] + 1e-9 * length
                        and ext[1] - 1e-9 * length <= q[1] <= ext[3] + 1e-9 * length):
                    raise fail("line", f"end {_pt(q)} lies outside {where}; allowed: points "
                                       "inside it")

    def _model_error(self, exc, top):
        """A GeometryError of terrain_model (whose messages name its own arguments) for the
        workflow field it is about."""
        from geodem.geo import GeometryError

        msg = str(exc)
        if "shorter than one element" in msg or "narrower than one element" in msg:
            field = "diameter"
            size = msg.split(" is ")[0].replace("the section (", "the section (line: ")
            msg = (f"d = diameter / scale = {self.d:g} m is larger than {size}; allowed: d "
                   "smaller than the model")
        elif "elements (> max_elements" in msg:
            n = msg.split("hold ")[1].split(" ")[0]
            limit = msg.split("max_elements = ")[1].split(")")[0]
            relief = float(top.z.max() - top.z.min())
            field = "base_depth" if self.base_depth > relief else "scale"
            msg = (f"the model would hold {n} elements (more than {limit}); use larger "
                   f"elements (diameter / scale: d = {self.d:g} m now; x2 in d divides the "
                   f"count by ~{2 ** self.dim}), a smaller base_depth ({self.base_depth:g} m "
                   f"now, the ground's relief is {relief:.4g} m) or a smaller model (line / "
                   "extent)")
        elif "base_depth" in msg:
            field = "base_depth"
        elif "has no element" in msg:
            field = "line" if self.dim == 2 else "extent"
            msg = "the model has no element: the line / extent holds no ground"
        elif "line" in msg:
            field = "line"
        elif "extent" in msg:
            field = "extent"
        else:
            field = getattr(exc, "field", "raster")
        err = GeometryError(msg)
        err.field = field
        return err

    def n_elements(self):
        try:
            top, slip, lat = self._lattice()
            if self.coarsen is None:
                return max(1, int(0.95 * lat.n))
            # each lattice site of size d stands for (d / d_nom)^dim elements of size d_nom; the
            # jammed packing holds 9-15 % fewer than that (measured at factors 1-3), 0.86
            size = self._size_field(top, slip, lat)
            return max(1, int(0.86 * np.sum((self.d / size(lat.x)) ** self.dim)))
        except Exception:  # noqa: BLE001 - check() reports bad input
            return 1

    def _size_field(self, top, slip, lat):
        from geodem.geo.terrain import band_size_field

        c = self.coarsen
        return band_size_field(top, self.d, c.factor, c.band, c.transition,
                               sliding_surface=slip, line=lat.line)

    def bytes_per_element(self):
        return state_bytes_per_element(self.dim, 8 if self.dim == 2 else 16) + 4000

    def material_refs(self):
        out = [(("material",), self.material)]
        if self.slide_material is not None:
            out.append((("slide_material",), self.slide_material))
        return out

    def group_names(self):
        return ["all", "ground", "slide", "side_x", "base"] + (["side_y"] if self.dim == 3
                                                              else [])

    def n_across(self):
        try:
            m = self._lattice()[2]
            return float((m.info["top_max"] - m.base_z) / self.d)
        except Exception:  # noqa: BLE001
            return 1.0

    def check(self, cfg):
        from geodem.geo import GeometryError

        try:
            m = self._lattice()[2]
        except GeometryError as exc:
            return [((getattr(exc, "field", "raster"),), str(exc))]
        out = []
        if self.coarsen is not None and self.coarsen.band < self.d:
            out.append((("coarsen", "band"), f"{self.coarsen.band:g} m is thinner than one "
                        f"element (d = {self.d:g} m); allowed: band >= d (the slide and the "
                        "ground it moves on need fine elements)"))
        if m.info["counts"].get("slide", 0) == 0:
            out.append(((("slip_depth" if self.slip_depth else "slip_surface"),),
                        "no element lies above the sliding surface along this model (line / "
                        "extent); allowed: a surface below the ground somewhere in the model"))
        return out

    def build(self, cfg):
        from geodem.build import packing
        from geodem.core import groups as grp
        from geodem.geo import GeometryError

        try:
            top, slip, lat = self._lattice()
        except GeometryError as exc:
            raise BuildError((getattr(exc, "field", "raster"),), str(exc)) from None
        d, dim = self.d, self.dim
        zb = float(lat.base_z)
        height = float(lat.info["top_max"]) - zb + 2.0 * d
        if dim == 2:
            lo = np.array([0.0, zb])
            hi = np.array([lat.extent[1], zb + height])
        else:
            e = lat.extent
            lo = np.array([e[0], e[1], zb])
            hi = np.array([e[2], e[3], zb + height])
        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        gm = element_params(cfg, self.material, d, dim)
        sm = element_params(cfg, self.slide_material or self.material, d, dim,
                            path=("slide_material",))
        graded = None
        if self.coarsen is None:
            phi = 0.84 if dim == 2 else 0.63
            x, r = packing.random_placement((np.zeros(dim), hi - lo),
                                            porosity=1.0 - 1.1 * phi, d_mean=d,
                                            distri_rate=self.distri_rate, seed=seed)
            dep = packing.deposition_state(x, r, (np.zeros(dim), hi - lo), rho=gm["rho"])
            rep = packing.deposit(dep)
            s = grp.members(dep, "sample")
            px, pr = dep.x[s] + lo, dep.r[s].copy()
            model = self._terrain_model(top, d, base_z=zb, dim=dim, body="ground",
                                        line=self.line, extent=self.extent,
                                        sliding_surface=slip, packing=(px, pr))
            mats = {"ground": gm, "slide": sm}
        else:
            model, mats, graded = self._graded(top, slip, lat, lo, hi, zb, seed, gm, sm)
            rep = {"steps": 0}
        st = model.to_state(mats, gravity=self.gravity, gap=self.bond_gap * d)
        solid = float(np.sum(st.m / np.where(st.group == st.groups["slide"], sm["rho"],
                                             gm["rho"])))
        meta = top.metadata()
        if dim == 2:
            (p0, p1) = model.line
            meta["line_local"] = [list(p0), list(p1)]
            meta["line_crs"] = [list(top.to_global(np.asarray(p0))),
                                list(top.to_global(np.asarray(p1)))]
            s_top = np.linspace(0.0, model.extent[1], 400)
            u = (np.asarray(p1) - np.asarray(p0)) / model.extent[1]
            xy = np.asarray(p0) + s_top[:, None] * u
            from geodem.geo.terrain import surface_function

            profile = {"s": s_top.tolist(), "top": top.elevation(xy).tolist(),
                       "slip": surface_function(slip, top.elevation)(xy).tolist()}
            bulk = float(np.trapezoid(np.maximum(np.array(profile["top"]) - zb, 0), s_top))
        else:
            from geodem.geo.terrain import block_bulk_volume

            profile = None
            bulk = block_bulk_volume(top, model.extent, zb)
        thickness = 2.0 * st.r if dim == 2 else None
        vol = math.pi * st.r ** 2 * thickness if dim == 2 else 4.0 / 3.0 * math.pi * st.r ** 3
        info = {"diameter": d, "dim": dim, "base_z": zb, "georef": meta, "profile": profile,
                "counts": {g: int((st.group == k).sum()) for g, k in st.groups.items()
                           if g != "all"},
                "solid_fraction": float(min(1.0, (vol / thickness).sum() / bulk)
                                        if dim == 2 else min(1.0, vol.sum() / bulk)),
                "solid_volume": solid, "deposition_steps": int(rep.get("steps", 0)),
                "materials": {"ground": self.material,
                              "slide": self.slide_material or self.material}}
        if graded is not None:
            info["graded"] = graded
        st.step, st.time = 0, 0.0
        return BuiltModel(st, st.x.copy(), float((model.info["top_max"] - zb) / d), info)


    def _terrain_model(self, top, d, **kw):
        """terrain_model; its GeometryError as a BuildError naming the workflow field."""
        from geodem.geo import GeometryError, terrain_model

        try:
            return terrain_model(top, d, **kw)
        except GeometryError as exc:
            err = self._model_error(exc, top)
            raise BuildError((err.field,), str(err)) from None

    def _graded(self, top, slip, lat, lo, hi, zb, seed, gm, sm):
        """The graded model (``coarsen``): a graded packing of the box (fine band along the
        ground and around the slide, coarser below), cut by the terrain; base and side groups
        two and one of each element's own nominal diameters thick; element parameters at each
        element's nominal diameter (:func:`geodem.build.graded.scale_params`)."""
        from geodem.build.graded import graded_packing, scale_params

        d, c = self.d, self.coarsen
        size = self._size_field(top, slip, lat)
        try:
            px, pr, dn, rep = graded_packing(lo, hi, size, d, self.distri_rate, seed=seed)
        except ValueError as exc:
            raise BuildError(("coarsen",), str(exc)) from None
        model = self._terrain_model(top, d, base_z=zb, dim=self.dim, body="ground",
                                    line=self.line, extent=self.extent, sliding_surface=slip,
                                    packing=(px, pr),
                                    base_thickness=np.maximum(2.0 * dn, 2.0 * d),
                                    side_width=np.maximum(dn, d))
        dk = dn[model.info["packing_index"]]
        mats = {"ground": scale_params(gm, d, dk), "slide": scale_params(sm, d, dk)}
        fine = dk <= d * rep["scale"] * (1.0 + 1e-9)
        coarse = (dk >= c.factor * d * rep["scale"] * (1.0 - 1e-9)) & ~fine
        info = {"factor": c.factor, "band": c.band, "transition": c.transition,
                "fine": int(fine.sum()), "transition_elements": int((~fine & ~coarse).sum()),
                "coarse": int(coarse.sum()), "d_nom_max": float(dk.max()),
                **{f"packing_{k}": v for k, v in rep.items()}}
        return model, mats, info


# ============================================================================ metrics
def horizontal(x, dim, direction):
    """Horizontal coordinate of points along ``direction`` (2-D: +-1 along x; 3-D: unit
    (2,) vector)."""
    if dim == 2:
        return x[:, 0] * direction
    return x[:, :2] @ direction


def motion_direction(x0, x, m, dim):
    """Unit horizontal direction of the mass centre's displacement (2-D: +1 or -1)."""
    dc = (m[:, None] * (x - x0)).sum(axis=0) / m.sum()
    if dim == 2:
        return 1.0 if dc[0] >= 0 else -1.0
    h = dc[:2]
    n = float(np.linalg.norm(h))
    return h / n if n > 0 else np.array([1.0, 0.0])


def landslide_metrics(x0, x, r, m, dim, moved, direction=None) -> dict:
    """Runout, travel angle and mass-centre path of a slide body: initial positions ``x0``,
    final ``x``, radii ``r``, masses ``m``; ``moved`` (bool) the displaced elements (module
    docstring for the definitions)."""
    if direction is None:
        direction = motion_direction(x0, x, m, dim)
    h0, h = horizontal(x0, dim, direction), horizontal(x, dim, direction)
    z0, z = x0[:, -1], x[:, -1]
    toe0 = float((h0 + r).max())
    crown = int(np.argmax(z0 + r))
    M = m.sum()
    c0, c1 = (m[:, None] * x0).sum(0) / M, (m[:, None] * x).sum(0) / M
    hc0 = float(horizontal(c0[None], dim, direction)[0])
    hc1 = float(horizontal(c1[None], dim, direction)[0])
    out = {"com_drop_m": float(c0[-1] - c1[-1]), "com_travel_m": hc1 - hc0,
           "source_toe_h": toe0, "crown_h": float(h0[crown]),
           "crown_z": float(z0[crown] + r[crown]),
           "direction": [float(v) for v in np.atleast_1d(direction)]}
    out["com_ratio"] = out["com_drop_m"] / out["com_travel_m"] if out["com_travel_m"] > 0 \
        else math.inf
    if not np.any(moved):
        out.update(runout_m=0.0, travel_angle_deg=None, front_h=toe0, tip_z=None)
        return out
    idx = np.flatnonzero(moved)
    tip = idx[np.argmax(h[idx] + r[idx])]
    front = float(h[tip] + r[tip])
    H = out["crown_z"] - float(z[tip] - r[tip])
    L = front - out["crown_h"]
    out.update(runout_m=front - toe0, front_h=front, tip_z=float(z[tip] - r[tip]),
               travel_H_m=H, travel_L_m=L,
               travel_angle_deg=float(math.degrees(math.atan2(H, L))))
    return out


# ============================================================================ step
class FreezeSpec(Strict):
    """Freezing of elements at rest (:mod:`geodem.fields.freeze`): calm elements fall asleep
    and the kernels skip those with no moving neighbour; a push wakes them."""

    v_sleep: float = F(1e-3, unit="m/s", gt=0, description="Speed below which an element is "
                                                           "calm")
    a_wake: Optional[float] = F(None, unit="m/s^2", gt=0,
                                description="Unbalanced acceleration that wakes a sleeper (calm "
                                            "below half of it); default per element "
                                            "2 v_sleep sqrt(kn / 2m)")
    patience: Int = F(3, ge=1, le=1000, description="Calm couplings in a row before sleeping")
    every: Int = F(10, ge=1, le=10000, description="Time steps between couplings")
    group: Optional[Name] = F("ground", description="Only elements of this group may sleep "
                                                    "(ground: the slide never sleeps; null: "
                                                    "any free element)")


class RunoutBase(StepBase):
    """The runout of a slide body under gravity until it is at rest: the thin case step of a
    landslide composed from parts (a terrain ``scene`` with the slide as a region, then the
    generic ``fix``, ``balance``, ``weaken`` and ``damping`` steps; workflows/
    landslide_scene.yaml). Samples the group's motion, stops when its mean speed is back below
    ``rest_speed`` after having exceeded it (and ``min_time`` has passed) or at ``max_time``.
    Adds runout_m, travel_angle_deg, max_velocity, deposit_volume_m3, wall_s and elements to
    summary.json (definitions: module docstring); writes landslide_history.csv,
    landslide_velocity.png, landslide_deposit.png, landslide_snapshots.png, landslide.gif,
    landslide_vtk/ and georef.json."""

    example = {"kind": "runout", "max_time": 1.0, "min_time": 0.5, "snapshots": 2,
               "gif": False, "vtk_frames": 2}
    example_model = {"type": "lattice_block", "dim": 2, "counts": [6, 4], "diameter": 1.0,
                     "material": "rock", "gravity": [0.0, -9.81],
                     "groups": {"slide": {"side": "ymax"}}}
    group: Name = F("slide", description="The slide body (a group of the model)")
    freeze: Optional[FreezeSpec] = F(None, description="Put elements at rest to sleep during "
                                                       "the runout (docs/freezing.md)")
    max_time: float = F(60.0, unit="s", gt=0, description="Longest runout time")
    min_time: float = F(2.0, unit="s", ge=0, description="Runout time before the rest test")
    rest_speed: float = F(0.05, unit="m/s", gt=0,
                          description="At rest: mean speed of the slide elements below this")
    sample_time: float = F(0.1, unit="s", gt=0, description="Time between samples")
    moved_threshold: float = F(1.0, gt=0, le=100,
                               description="A slide element displaced by more than this x d "
                                           "belongs to the deposit")
    snapshots: Int = F(6, ge=1, le=24, description="Panels of landslide_snapshots.png")
    gif: bool = F(True, description="Write landslide.gif")
    gif_frames: Int = F(40, ge=2, le=300, description="Frames of the animation")
    vtk_frames: Int = F(8, ge=0, le=1000, description="ParaView frames (landslide_vtk/)")
    plot: bool = F(True, description="Draw the PNGs (needs matplotlib)")

    def check(self, cfg, groups):
        if self.group not in groups:
            return [(("group",), f"no group '{self.group}' in the model; allowed: "
                                 f"{', '.join(sorted(groups))}")]
        if self.min_time >= self.max_time:
            return [(("min_time",), f"must be below max_time = {self.max_time:g} s")]
        return []

    def _settle_steps(self, plan):
        return 0

    def planned_steps(self, plan):
        return self._settle_steps(plan) + max(1, int(math.ceil(self.max_time / plan.dt)))

    def _before(self, ctx, slide):
        """What happens at the start of the runout (the landslide step: its trigger)."""
        return None

    # ------------------------------------------------------------------ execution
    def execute(self, ctx):
        from geodem.core import groups, timestep

        wall0 = time.perf_counter()
        st = ctx.state
        info = ctx.model.info
        d = float(info["diameter"])
        self._georef(ctx)
        settle = self._settle_steps(ctx.plan)
        slide = groups.members(st, self.group)
        if not ctx.resumed or st.step < ctx.start_step + settle:
            if settle:
                ctx.set_eta(timestep.standard_damping(st, ctx.plan.n_across))
                ctx.advance(settle)
        start = ctx.out_dir / START
        if ctx.resumed and start.exists():
            z = np.load(start)
            x0, t0 = z["x0"], float(z["t0"])
        else:
            st = ctx.state
            x0, t0 = st.x[slide].copy(), float(st.time)
            np.savez(start, x0=x0, t0=t0)
            self._before(ctx, slide)
            if self.freeze is not None:  # (a resumed run gets it back from its checkpoint)
                from geodem.fields.freeze import FreezeField

                fz = self.freeze
                ctx.sim.add_field(FreezeField(v_sleep=fz.v_sleep, a_wake=fz.a_wake,
                                              patience=fz.patience, every=fz.every,
                                              group=fz.group))
        runout_wall0 = time.perf_counter()
        total = max(1, int(math.ceil(self.max_time / ctx.plan.dt)))
        chunk = max(1, int(round(self.sample_time / ctx.plan.dt)))
        path = ctx.out_dir / HISTORY
        rows = []
        if ctx.resumed and path.exists():
            with open(path) as f:
                rows = [[float(v) for v in r] for r in list(csv.reader(f))[1:]
                        if int(float(r[0])) <= ctx.state.step]
        with open(path, "w", newline="") as f:
            csv.writer(f).writerows([COLUMNS] + rows)
        if path.name not in ctx.runner.files:
            ctx.runner.files.append(path.name)
        fdir = ctx.out_dir / FRAMES_DIR
        fdir.mkdir(exist_ok=True)
        n_frames = max(self.gif_frames if self.gif else 0, self.snapshots, self.vtk_frames, 2)
        frame_every = max(1, int(round(total / chunk / n_frames)))
        done = max(0, ctx.state.step - ctx.start_step - settle) // chunk * chunk
        k = len(rows)
        if not rows:
            rows.append(self._sample(ctx, slide, x0, t0, d, path))
            self._frame(fdir, ctx, slide, t0, 0)
        reason = "max_time"
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(settle + done)
            row = self._sample(ctx, slide, x0, t0, d, path)
            rows.append(row)
            k += 1
            # at rest: slow again after having moved (faster than rest_speed), past min_time
            moving = max(rw[2] for rw in rows) >= self.rest_speed
            rest = row[1] >= self.min_time and moving and row[2] < self.rest_speed
            if k % frame_every == 0 or rest or done == total:
                self._frame(fdir, ctx, slide, t0, k)
            if rest:
                reason = "rest"
                break
        runout_wall = time.perf_counter() - runout_wall0
        return self._results(ctx, slide, x0, rows, reason, fdir, d, wall0, runout_wall,
                             settle)

    def _georef(self, ctx):
        meta = dict(ctx.model.info.get("georef") or {})
        (ctx.out_dir / GEOREF).write_text(json.dumps(meta, indent=1))
        if GEOREF not in ctx.runner.files:
            ctx.runner.files.append(GEOREF)
        attrs = {"crs_wkt": meta.get("crs", ""), "crs_epsg": int(meta.get("epsg", -1)),
                 "geotransform": np.asarray(meta.get("transform", []), float),
                 "local_origin": np.asarray(meta.get("origin", []), float)}
        if "line_crs" in meta:
            attrs["section_line_crs"] = np.asarray(meta["line_crs"], float)
            attrs["section_line_local"] = np.asarray(meta["line_local"], float)
        ctx.runner.h5.set_attrs(**attrs)
        ctx.summary["crs_epsg"] = attrs["crs_epsg"]

    def _sample(self, ctx, slide, x0, t0, d, path):
        s = ctx.state
        x, v, m = s.x[slide], s.v[slide], s.m[slide]
        sp = np.linalg.norm(v, axis=1)
        M = m.sum()
        c = (m[:, None] * x).sum(0) / M
        moved = np.linalg.norm(x - x0, axis=1) > self.moved_threshold * d
        direction = motion_direction(x0, x, m, s.dim)
        h = horizontal(x, s.dim, direction)
        front = float((h + s.r[slide])[moved].max()) if moved.any() else math.nan
        row = [int(s.step), float(s.time - t0), float(sp.mean()), float(sp.max()),
               float(0.5 * (m * sp * sp).sum()),
               float(horizontal(c[None], s.dim, direction)[0]), float(c[-1]), front,
               int(moved.sum())]
        with open(path, "a", newline="") as f:
            csv.writer(f).writerow(row)
        return row

    def _frame(self, fdir, ctx, slide, t0, k):
        s = ctx.state
        np.savez_compressed(fdir / f"frame_{int(k):06d}.npz",
                            x=s.x[slide].astype(np.float32),
                            v=s.v[slide].astype(np.float32),
                            time=float(s.time - t0), step=int(s.step))

    # ------------------------------------------------------------------ results
    def _results(self, ctx, slide, x0, rows, reason, fdir, d, wall0, runout_wall, settle):
        s = ctx.state
        ref = ctx.model.reference
        info = dict(ctx.model.info)
        # a model that is not a terrain (a block, a scene without a raster): its bottom
        info.setdefault("base_z", float((ref[:, -1] - s.r).min()))
        x, r, m = s.x[slide], s.r[slide], s.m[slide]
        moved = np.linalg.norm(x - x0, axis=1) > self.moved_threshold * d
        lo, hi = ref.min(axis=0) - r.max(), ref.max(axis=0) + r.max()
        lost = (x[:, -1] < info["base_z"]) | np.any((x[:, :-1] < lo[:-1]) | (x[:, :-1] > hi[:-1]),
                                                    axis=1)
        moved &= ~lost
        met = landslide_metrics(x0, x, r, m, s.dim, moved)
        a = np.array(rows, float)
        vol = math.pi * r ** 2 if s.dim == 2 else 4.0 / 3.0 * math.pi * r ** 3
        ground = np.setdiff1d(np.arange(s.n), slide)
        gdisp = np.linalg.norm(s.x[ground] - ctx.model.reference[ground], axis=1)
        mu = float(np.min(s.mu[slide]))
        res = {
            "runout_m": met["runout_m"], "travel_angle_deg": met["travel_angle_deg"],
            "max_velocity": float(a[:, 2].max()), "max_element_speed": float(a[:, 3].max()),
            "deposit_volume_m3": float(vol[moved].sum()),
            "deposit_bulk_volume_m3": (float(vol[moved].sum() / info["solid_fraction"])
                                       if info.get("solid_fraction") else None),
            "slide_volume_m3": float(vol.sum()), "displaced_elements": int(moved.sum()),
            "slide_elements": int(slide.size), "slide_friction": mu,
            "lost_elements": int(lost.sum()),
            "runout_time": float(a[-1, 1]), "stopped_by": reason,
            "final_mean_speed": float(a[-1, 2]),
            "ground_max_displacement": float(gdisp.max()) if gdisp.size else 0.0,
            "energy_closure_rel_error": float(ctx.sim.energies()["closure_error"]),
            "solid_fraction": info.get("solid_fraction"),
            "volume_note": "2-D: m^3 per metre of width (discs pi r^2 x 1 m)"
            if s.dim == 2 else "3-D: spheres",
            "elements": int(s.n), "wall_s": time.perf_counter() - wall0,
            "runout_wall_s": runout_wall, "settle_steps": settle,
            "runout_steps": int(a[-1, 0] - a[0, 0]),
        }
        res.update({k: v for k, v in met.items() if k not in res})
        res["runout_element_steps_per_s"] = res["runout_steps"] * s.n / max(runout_wall, 1e-9)
        res["element_steps"] = int((settle + res["runout_steps"]) * s.n)
        if info.get("graded") is not None:
            res["graded"] = info["graded"]
        if self.freeze is not None:
            res["freeze"] = ctx.sim.field("freeze").summary()
        ctx.summary.update({k: res[k] for k in ("runout_m", "travel_angle_deg", "max_velocity",
                                                 "deposit_volume_m3", "wall_s", "elements",
                                                 "com_ratio", "stopped_by")})
        ta = res["travel_angle_deg"]
        ctx.log(f"landslide: runout {res['runout_m']:.4g} m, travel angle "
                f"{'n/a' if ta is None else f'{ta:.3g}'} deg, max mean speed "
                f"{res['max_velocity']:.3g} m/s, deposit {res['deposit_volume_m3']:.4g} m^3, "
                f"H_c/L_c = {res['com_ratio']:.3g} (friction {mu:.3g}); stopped by {reason} "
                f"after {res['runout_time']:.3g} s")
        frames = sorted(fdir.glob("frame_*.npz"))
        self._vtk(ctx, slide, frames, x0)
        if self.plot and ctx.cfg.outputs.plots:
            from geodem.cases.landslide_plots import deposit_map, snapshots, velocity_history

            res["plot_velocity"] = ctx.plot("landslide_velocity.png", lambda p: velocity_history(
                p, a, res))
            res["plot_deposit"] = ctx.plot("landslide_deposit.png", lambda p: deposit_map(
                p, s.dim, ref, s.r, slide, x0, x, moved, info, res))
            res["plot_snapshots"] = ctx.plot("landslide_snapshots.png", lambda p: snapshots(
                p, s.dim, ref, s.r, slide, frames, self.snapshots, info))
            if self.gif:
                from geodem.workflow.animation import gif_writer_missing
                from geodem.cases.landslide_plots import animation

                why = gif_writer_missing()
                if why:
                    res["animation"] = f"skipped: {why}"
                    ctx.runner.plots["landslide.gif"] = res["animation"]
                else:
                    res["animation"] = ctx.plot("landslide.gif", lambda p: animation(
                        p, s.dim, ref, s.r, slide, frames, self.gif_frames, info))
        return res

    def _vtk(self, ctx, slide, frames, x0):
        """ParaView frames of every element in the raster's CRS coordinates (ground at its
        final position, the slide at each frame's)."""
        from geodem.io.vtk import VtkWriter, to_xyz

        if not self.vtk_frames or not frames:
            return
        s = ctx.state
        meta = ctx.model.info.get("georef")  # None: the model's own coordinates
        pick = np.unique(np.linspace(0, len(frames) - 1, self.vtk_frames).round().astype(int))
        w = VtkWriter(ctx.out_dir / VTK_DIR)
        x = s.x.copy()
        v = np.zeros_like(s.v)
        for k in pick:
            z = np.load(frames[k])
            x[slide] = z["x"]
            v[slide] = z["v"]
            pseudo = SimpleNamespace(x=to_crs(x, meta) if meta else to_xyz(x), r=s.r, v=to_xyz(v), group=s.group,
                                     cstate=s.cstate, time=float(z["time"]))
            w.write(pseudo, int(z["step"]))
        if VTK_DIR not in ctx.runner.files:
            ctx.runner.files.append(VTK_DIR)


@register_step("runout")
class Runout(RunoutBase):
    __doc__ = RunoutBase.__doc__


@register_step("landslide")
class LandslideStep(RunoutBase):
    """Gravity settling, then a strength-reduction trigger (bonds across the sliding surface
    cut or weakened, reduced friction and bond strength of the slide body), then the runout
    under gravity until the slide is at rest (:class:`Runout`). Adds runout_m,
    travel_angle_deg, max_velocity, deposit_volume_m3, wall_s and elements to summary.json;
    writes landslide_history.csv, landslide_velocity.png, landslide_deposit.png,
    landslide_snapshots.png, landslide.gif, landslide_vtk/ and georef.json."""

    example = {"kind": "landslide", "max_time": 1.0, "min_time": 0.5, "settle": False,
               "snapshots": 2, "gif": False, "vtk_frames": 2}
    example_model = Landslide.example
    settle: bool = F(True, description="One standard balance under gravity (damping eta_c / "
                                       "N) before the trigger")
    slip_bond_rate: float = F(0.0, ge=0, le=1,
                              description="Bond rate of the bonds across the sliding surface "
                                          "after the trigger (0: cut)")
    slide_friction: Optional[float] = F(None, ge=0, le=5,
                                        description="Friction coefficient of the slide "
                                                    "elements after the trigger (default: "
                                                    "unchanged)")
    strength_factor: float = F(0.0, ge=0, le=1,
                               description="Factor on the slide elements' bond strength (xb, "
                                           "fs0) at the trigger (0: their bonds are cut)")
    damping_ratio: float = F(0.0, ge=0, le=1,
                             description="Mass damping of the slide during the runout, "
                                         "fraction of critical (0: none)")
    ground_damping_ratio: float = F(0.0, ge=0, le=1,
                                    description="Mass damping of the ground (every free element "
                                                "outside the slide) during the runout, fraction "
                                                "of critical: stands in for the waves a bounded "
                                                "model cannot radiate away (0: none)")

    def check(self, cfg, groups):
        if "slide" not in groups:
            return [((), "the landslide step needs a model with a 'slide' group (model type "
                         "landslide)")]
        if self.min_time >= self.max_time:
            return [(("min_time",), f"must be below max_time = {self.max_time:g} s")]
        return []

    def _settle_steps(self, plan):
        from geodem.core import timestep

        return timestep.standard_balance_steps(plan.n_across) if self.settle else 0

    def _before(self, ctx, slide):
        self._trigger(ctx, slide)

    def _trigger(self, ctx, slide):
        from geodem.core import timestep
        from geodem.core.state import BONDED

        st = ctx.state
        sl = np.zeros(st.n, bool)
        sl[slide] = True
        nb = st.nbr
        cross = (nb >= 0) & (st.cstate == BONDED) & (sl[:, None] != sl[np.maximum(nb, 0)])
        i, j = np.nonzero(cross)
        pairs = [(a, b) for a, b in zip(i.tolist(), nb[i, j].tolist()) if a < b]
        if self.slip_bond_rate == 0.0:
            cut = ctx.sim.cut([p[0] for p in pairs], [p[1] for p in pairs]) if pairs else 0
        else:
            cut = 0
        inner = (nb >= 0) & (st.cstate == BONDED) & sl[:, None] & sl[np.maximum(nb, 0)]
        ii, jj = np.nonzero(inner)
        inner_pairs = [(a, b) for a, b in zip(ii.tolist(), nb[ii, jj].tolist()) if a < b]
        if self.strength_factor == 0.0 and inner_pairs:
            cut += ctx.sim.cut([p[0] for p in inner_pairs], [p[1] for p in inner_pairs])
        crit = timestep.element_critical_damping(ctx.state)
        eta = np.where(sl, self.damping_ratio, self.ground_damping_ratio) * crit

        def trigger(s):
            if self.slip_bond_rate > 0.0:
                s.brate[cross] = self.slip_bond_rate
            if self.slide_friction is not None:
                s.mu[slide] = self.slide_friction
            if self.strength_factor > 0.0:
                s.xb[slide] *= self.strength_factor
                s.fs0[slide] *= self.strength_factor
            s.eta[:] = eta

        ctx.decree(trigger, "slide")
        across = "cut" if self.slip_bond_rate == 0 else f"at rate {self.slip_bond_rate:g}"
        in_slide = "cut" if self.strength_factor == 0 else f"x {self.strength_factor:g}"
        fric = self.slide_friction if self.slide_friction is not None else "kept"
        ctx.log(f"trigger at t = {ctx.state.time:.4g} s: {len(pairs)} bonds across the sliding "
                f"surface {across}, {len(inner_pairs)} slide bonds {in_slide}, "
                f"slide friction {fric} ({cut} bonds cut in all)")


def to_crs(x, meta) -> np.ndarray:
    """Model coordinates -> the raster CRS (X, Y, Z) [m]: 3-D: plus the local origin; 2-D: the
    section point ``p0 + s u`` of the line, plus the origin, and the elevation."""
    o = np.asarray(meta.get("origin", [0.0, 0.0, 0.0]), float)
    x = np.asarray(x, float)
    if x.shape[1] == 3:
        return x + o
    p0, p1 = (np.asarray(p, float) for p in meta["line_local"])
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    xy = p0 + x[:, :1] * u
    return np.column_stack([xy + o[:2], x[:, 1] + o[2]])


__all__ = ["Landslide", "LandslideStep", "landslide_metrics", "resolve_path", "to_crs",
           "motion_direction", "horizontal"]
