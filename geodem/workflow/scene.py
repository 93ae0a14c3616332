"""Model ``scene``: a user's own bonded model composed from parts in YAML.

A scene is a **domain** (a box, a polygon or a disc in 2-D, or the ground under a terrain)
filled with a close-packed lattice of one element diameter (``fill: lattice``: triangular in 2-D, FCC in
3-D; the lattice starts half an element inside the lower corner, every element lies within the
bounding box, and in a polygon element centres lie inside it), a random packing deposited under
gravity (``random``) or the material's own specimen packing, cemented (``specimen``: a library
rock is then the calibrated rock; one material). Its elements take their material from
ordered **regions** (shapes or half-spaces; a later region overrides an earlier one; elements in
no region take the scene's ``material``); a region with ``empty: true`` removes its elements (a
hole). Bonds across two regions are kept (each bond as strong as the weaker element, as
everywhere in geodem) or, with ``interfaces: joint``, cut: the regions then touch without
cement, like the two sides of a joint. Named **groups** select elements by sides of the domain,
by region, by box or by any shape, for any step (fix, velocity, load, heat, ...).

Regions are shapes of one material each (a box, a polygon in 2-D or a prism in 3-D, a disc, a
half-space, a band, and their unions, intersections and differences; under a terrain also the
sides of surfaces and the cells of a raster mask), or the coloured regions of a **label image**
(colour -> region and material, with a pixel size and an origin; pixels of an ``empty`` colour
hold no element: a cavity drawn on the image).

The bonds across two regions are the **interface**: ``interface_strength`` scales their
strength (the breaking force and the shear strength), ``interface_stiffness`` their stiffness
(``Kn`` and ``Ks`` of the contact, through a per-contact stiffness factor:
:func:`geodem.core.state.scale_row_stiffness`), so a bedding plane or a cemented seam can be
weaker and softer than the rocks it joins without a region of its own.

Under a terrain domain a region or group may be a ``surface``: the side of a layer boundary
given as an elevation raster, or of a depth below the ground (a constant, or a raster of
depths, e.g. a sliding surface), rasters read onto the terrain raster's grid. A terrain
scene's random fill may be **graded** (``coarsen``): fine elements (diameter d) in a band along
the ground and below the surfaces of its surface regions (a sliding surface, a weak layer),
coarser ones (up to ``factor`` d) in the deep ground, each element with its material's
parameters at its own nominal diameter (docs/graded.md).

Not built yet: several materials in one specimen fill.
"""
from __future__ import annotations

import functools
import math
from typing import Literal, Optional, Union

import numpy as np
from pydantic import model_validator

from geodem.workflow.models import (SIDES, BuildError, BuiltModel, element_params,
                                    group_problems, state_bytes_per_element)
from geodem.workflow.schema import DOF_NAMES, F, Int, ModelBase, Name, Strict, register_model


class SceneBox(Strict):
    min: list[float] = F(..., unit="m", min_length=2, max_length=3, description="Lower corner")
    max: list[float] = F(..., unit="m", min_length=2, max_length=3, description="Upper corner")


class SceneDisc(Strict):
    center: list[float] = F(..., unit="m", min_length=2, max_length=3,
                            description="Centre (2-D: a disc; 3-D: a cylinder along y)")
    radius: float = F(..., unit="m", gt=0, description="Radius")


class SceneBand(Strict):
    point: list[float] = F(..., unit="m", min_length=2, max_length=3,
                           description="A point of the band's mid-plane")
    normal: list[float] = F(..., min_length=2, max_length=3,
                            description="Normal of the band (any length but zero)")
    thickness: float = F(..., unit="m", gt=0, description="Thickness across the band")


class SceneTerrain(Strict):
    """The ground under an elevation raster down to a base: a 2-D section along ``line`` or a
    3-D block over ``extent`` (local metres from the raster's lower-left corner)."""

    raster: str = F(..., description="Elevation raster (GeoTIFF or any format GDAL reads; "
                                     "projected in metres, or geographic: reprojected)")
    line: Optional[list[list[float]]] = F(None, unit="m", description="2-D: the section "
                                          "[[x0, y0], [x1, y1]] (default west to east "
                                          "through the middle)")
    extent: Optional[list[float]] = F(None, unit="m", min_length=4, max_length=4,
                                      description="3-D: [xmin, ymin, xmax, ymax] (default the "
                                                  "raster's)")
    base_depth: float = F(10.0, unit="m", gt=0, description="Depth of the base below the "
                                                            "lowest ground in the model")

    def read(self):
        from geodem.geo import read_elevation
        from geodem.workflow.models import resolve_path

        return read_elevation(str(resolve_path(self.raster)))


class SceneSurface(Strict):
    """A surface under a terrain domain, and the side of it the shape takes: the elevation
    raster of a layer boundary, a constant depth below the ground, or a raster of depths below
    the ground (positive down, e.g. a sliding surface: 0 where there is none). A raster is read
    onto the terrain raster's grid (any CRS; the grids' footprints must agree)."""

    raster: Optional[str] = F(None, description="Raster of the surface's elevation [m]")
    depth: Optional[float] = F(None, unit="m", ge=0, description="Constant depth of the "
                                                                 "surface below the ground")
    depth_raster: Optional[str] = F(None, description="Raster of the surface's depth below "
                                                      "the ground [m], positive down")
    side: Literal["above", "below"] = F("above", description="Centres above (between the "
                                                             "surface and the ground) or "
                                                             "below the surface")

    @model_validator(mode="after")
    def _one(self):
        given = [k for k in ("raster", "depth", "depth_raster") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of raster, depth, depth_raster (got "
                             f"{', '.join(given) or 'none'})")
        return self

    def files(self):
        """``[(field, path)]`` of the rasters the surface reads."""
        return [(k, getattr(self, k)) for k in ("raster", "depth_raster")
                if getattr(self, k) is not None]

    def elevation(self, xy, frame) -> np.ndarray:
        """The surface's elevation [m] at local raster points ``xy`` (M, 2)."""
        if self.raster is not None:
            return frame.raster(self.raster).elevation(xy)
        if self.depth is not None:
            return frame.ground(xy) - self.depth
        return frame.ground(xy) - frame.raster(self.depth_raster).elevation(xy)

    def mask(self, x, frame) -> np.ndarray:
        """Centres ``x`` (model frame) on the surface's ``side``; ``frame``: the terrain domain's
        :class:`TerrainFrame`."""
        if frame is None:
            raise ValueError("a surface shape needs a terrain domain")
        z = self.elevation(frame.plan(x), frame)
        return x[:, -1] > z if self.side == "above" else x[:, -1] < z


class ScenePrism(Strict):
    polygon: list[list[float]] = F(..., unit="m", min_length=3,
                                   description="Polygon vertices [u, v] in the plane normal to "
                                               "axis (z: [x, y], y: [x, z], x: [y, z])")
    axis: Literal["x", "y", "z"] = F("z", description="Extrusion axis")
    range: list[float] = F(..., unit="m", min_length=2, max_length=2,
                           description="[from, to] along the axis (from < to)")

    @model_validator(mode="after")
    def _check(self):
        if any(len(v) != 2 for v in self.polygon):
            raise ValueError("prism polygon: vertices of 2 coordinates [u, v]")
        if not self.range[0] < self.range[1]:
            raise ValueError(f"prism range {self.range}: allowed [from, to] with from < to")
        return self

    def shape(self):
        """The prism as a :class:`geodem.build.shapes.Polygon` (3-D)."""
        from geodem.build.shapes import Polygon

        return Polygon(tuple(map(tuple, self.polygon)), axis=self.axis, z0=self.range[0],
                       z1=self.range[1])


class SceneHalfSpace(Strict):
    point: list[float] = F(..., unit="m", min_length=2, max_length=3,
                           description="A point of the bounding plane (a line in 2-D)")
    normal: list[float] = F(..., min_length=2, max_length=3,
                            description="Normal of the plane, pointing into the half-space")


class SceneRasterMask(Strict):
    raster: str = F(..., description="Raster read onto the terrain's grid (any CRS, as the "
                                     "surfaces' rasters)")
    above: float = F(0.5, description="Centres where the raster's value (bilinear between "
                                      "cell centres, as every raster here) is above this: "
                                      "0.5 puts a 0/1 mask's boundary on its cells' edges; "
                                      "nodata cells select nothing")


class TerrainFrame:
    """How a terrain scene's model coordinates meet its rasters: ``plan(x)`` the local raster
    (x, y) of model points (3-D: x[:, :2]; 2-D: along the section line), ``ground(xy)`` the
    terrain's elevation, ``raster(path)`` another raster read onto the terrain's grid."""

    def __init__(self, top_key, line):
        self.top_key, self.line = top_key, line
        self.top = _read_top(*top_key)

    def plan(self, x):
        from geodem.geo.terrain import plan_xy

        return plan_xy(x, self.line)

    def ground(self, xy):
        return self.top.elevation(xy)

    def raster(self, path):
        from geodem.workflow.models import resolve_path

        p = resolve_path(path)
        return _read_on_grid(str(p), p.stat().st_mtime, self.top_key)


class Shape(Strict):
    """One of: ``box``, ``polygon`` (2-D), ``prism`` (3-D: a polygon extruded along an axis),
    ``disc``, ``below`` or ``above`` (a horizontal plane: the last coordinate, y in 2-D and z
    in 3-D, below or above the value), ``half_space`` (the side of any plane the normal points
    to), ``band`` (a planar layer of a thickness: a dipping weak layer), ``surface`` (a side of
    a surface under a terrain domain: a layer boundary or a depth below the ground, from
    rasters), ``raster_mask`` (terrain domain: the centres over a raster's cells above a
    value), the combinations ``union``, ``intersection`` and ``difference`` (the first shape
    less the others) of shapes, or, for a domain only, ``terrain``."""

    box: Optional[SceneBox] = F(None, description="Box of element centres [m]")
    polygon: Optional[list[list[float]]] = F(None, unit="m", description="Polygon vertices "
                                             "(2-D, at least 3 [x, y] pairs)")
    prism: Optional[ScenePrism] = F(None, description="3-D: a polygon extruded along an axis")
    disc: Optional[SceneDisc] = F(None, description="Disc (2-D) or cylinder along y (3-D)")
    half_space: Optional[SceneHalfSpace] = F(None, description="Centres on the side of a plane "
                                                               "its normal points to")
    raster_mask: Optional[SceneRasterMask] = F(None, description="Terrain domain: centres over "
                                                                 "a raster's cells above a value")
    union: Optional[list["Shape"]] = F(None, min_length=1,
                                       description="Centres in any of these shapes")
    intersection: Optional[list["Shape"]] = F(None, min_length=1,
                                              description="Centres in all of these shapes")
    difference: Optional[list["Shape"]] = F(None, min_length=2,
                                            description="Centres in the first shape and in "
                                                        "none of the others")
    below: Optional[float] = F(None, unit="m", description="Centres with the last "
                                                           "coordinate below this")
    above: Optional[float] = F(None, unit="m", description="Centres with the last "
                                                           "coordinate above this")
    band: Optional[SceneBand] = F(None, description="Centres within thickness / 2 of a plane")
    surface: Optional[SceneSurface] = F(None, description="Terrain domain: centres above or "
                                                          "below a surface from a raster or a "
                                                          "depth below the ground")
    terrain: Optional[SceneTerrain] = F(None, description="Domain only: the ground under an "
                                                          "elevation raster")

    @model_validator(mode="after")
    def _one(self):
        names = SHAPE_KEYS
        given = [k for k in names if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(names)} (got "
                             f"{', '.join(given) or 'none'})")
        if self.polygon is not None and (len(self.polygon) < 3 or
                                         any(len(v) != 2 for v in self.polygon)):
            raise ValueError("polygon: at least 3 vertices of 2 coordinates [x, y]")
        return self

    def parts(self):
        """``(key, shapes)`` of a combination (``union``, ``intersection``, ``difference``),
        else None."""
        for key in COMBINATIONS:
            if getattr(self, key) is not None:
                return key, getattr(self, key)
        return None

    def leaves(self, path):
        """``[(path, shape)]`` of the shapes that are not combinations, nested ones included."""
        comb = self.parts()
        if comb is None:
            return [(path, self)]
        key, shapes = comb
        return [leaf for k, sh in enumerate(shapes) for leaf in sh.leaves(path + (key, k))]

    def problems(self, dim, path):
        out = []
        for where, sh in self.leaves(path):
            out += sh._own_problems(dim, where)
            if sh.terrain is not None and where != path:
                out.append((where + ("terrain",), "a terrain is a domain, not a part of a "
                                                  "combination"))
        return out

    def _own_problems(self, dim, path):
        out = []
        if self.polygon is not None and dim != 2:
            out.append((path + ("polygon",), "a polygon is 2-D only; in 3-D use a prism, a box "
                                             "or a disc"))
        if self.prism is not None and dim != 3:
            out.append((path + ("prism",), "a prism is 3-D only; in 2-D use a polygon"))
        for key, obj in (("box", self.box), ("disc", self.disc), ("band", self.band),
                         ("half_space", self.half_space)):
            if obj is None:
                continue
            for f in {"box": ("min", "max"), "disc": ("center",), "band": ("point", "normal"),
                      "half_space": ("point", "normal")}[key]:
                if len(getattr(obj, f)) != dim:
                    out.append((path + (key, f), f"{dim} coordinates needed"))
        if self.half_space is not None and not any(self.half_space.normal):
            out.append((path + ("half_space", "normal"), "the normal is zero; give a "
                                                         "direction"))
        return out

    def mask(self, x, frame=None) -> np.ndarray:
        """Elements (centres ``x``) in the shape; ``frame``: the :class:`TerrainFrame` of a
        terrain domain (a ``surface`` needs it)."""
        from geodem.build.shapes import box_mask, disc_mask, polygon_mask

        comb = self.parts()
        if comb is not None:
            key, shapes = comb
            out = shapes[0].mask(x, frame)
            for sh in shapes[1:]:
                m = sh.mask(x, frame)
                out = out | m if key == "union" else out & m if key == "intersection" else \
                    out & ~m
            return out
        if self.prism is not None:
            return self.prism.shape().mask(x)
        if self.half_space is not None:
            return (x - np.asarray(self.half_space.point, float)) @ \
                np.asarray(self.half_space.normal, float) > 0.0
        if self.raster_mask is not None:
            if frame is None:
                raise ValueError("a raster mask needs a terrain domain")
            value = frame.raster(self.raster_mask.raster).elevation(frame.plan(x))
            return np.isfinite(value) & (value > self.raster_mask.above)
        if self.box is not None:
            return box_mask(x, self.box.min, self.box.max)
        if self.polygon is not None:
            return polygon_mask(x, np.asarray(self.polygon, float))
        if self.disc is not None:
            if x.shape[1] == 2:
                return disc_mask(x, self.disc.center, self.disc.radius)
            return disc_mask(x, self.disc.center, self.disc.radius, axis="y",
                             thickness=math.inf)
        if self.below is not None:
            return x[:, -1] < self.below
        if self.band is not None:
            n = np.asarray(self.band.normal, float)
            dist = (x - np.asarray(self.band.point, float)) @ (n / np.linalg.norm(n))
            return np.abs(dist) <= 0.5 * self.band.thickness
        if self.surface is not None:
            return self.surface.mask(x, frame)
        if self.terrain is not None:
            raise ValueError("a terrain is a domain, not a region's shape")
        return x[:, -1] > self.above


class ImageColour(Strict):
    material: Name = F(..., description="Material of the elements on pixels of this colour")
    colour: Union[str, list[int], list[Union[str, list[int]]]] = F(
        ..., description="'#rrggbb', [r, g, b] (0-255), or a list of them")


class ImageRegions(Strict):
    """Regions from a label image: each named colour is a region of one material. The image's
    lower-left pixel corner sits at ``origin``; pixels are ``pixel_size`` square; in 3-D the
    image is a vertical section (``plane: xz``, extruded along y) or a plan (``xy``, extruded
    along z)."""

    file: str = F(..., description="Image file (PNG, BMP, TIFF, ...): absolute, or relative to "
                                   "the working directory or the geodem source tree")
    pixel_size: float = F(..., unit="m", gt=0, description="Pixel edge length")
    origin: list[float] = F([0.0, 0.0], unit="m", min_length=2, max_length=2,
                            description="Model coordinates of the image's lower-left corner")
    plane: Literal["xy", "xz", "yz"] = F("xy", description="Model plane of the image (2-D: "
                                                           "xy; 3-D section: xz)")
    colours: dict[Name, ImageColour] = F(..., min_length=1,
                                         description="Region name -> material and colour")
    empty: list[Union[str, list[int]]] = F([], description="Colours that mean no element (a "
                                                           "cavity, air): removed")
    tolerance: float = F(0.0, ge=0, le=255, description="Colour tolerance (Chebyshev, 0-255; "
                                                        "JPEG images need 20-40)")

    def read(self):
        from geodem.geo.image import read_labels
        from geodem.workflow.models import resolve_path

        colours = {name: c.colour for name, c in self.colours.items()}
        return read_labels(str(resolve_path(self.file)), colours=colours,
                           tolerance=self.tolerance, empty=self.empty or None)

    def extent(self, image):
        h, w = image.shape
        u0, v0 = self.origin
        return (u0, v0, u0 + w * self.pixel_size, v0 + h * self.pixel_size)


class Region(Strict):
    """A shape of one material, or the coloured regions of a label image."""

    name: Optional[Name] = F(None, description="Region name (for groups: {region: NAME})")
    material: Optional[Name] = F(None, description="Material of the elements in the shape")
    empty: bool = F(False, description="The shape holds no element (a hole, a cavity): its "
                                       "elements are removed (instead of a material)")
    shape: Optional[Shape] = F(None, description="Where the region is")
    image: Optional[ImageRegions] = F(None, description="Regions from a label image (instead "
                                                        "of name, material and shape)")

    @model_validator(mode="after")
    def _one(self):
        if (self.shape is None) == (self.image is None):
            raise ValueError("give exactly one of shape (with material) or image")
        if self.shape is not None and (self.material is None) != self.empty:
            raise ValueError("a shape region needs a material, or empty: true (a hole), "
                             "not both")
        if self.image is not None and self.empty:
            raise ValueError("an image region removes elements by its empty colours "
                             "(image.empty), not by empty: true")
        if self.image is not None and (self.material is not None or self.name is not None):
            raise ValueError("an image region takes its names and materials from image.colours")
        return self

    def slots(self) -> list:
        """``(name, material)`` of each region this entry makes (material None: empty)."""
        if self.image is None:
            return [(self.name, self.material)]
        return [(name, c.material) for name, c in self.image.colours.items()]


COMBINATIONS = ("union", "intersection", "difference")
#: shapes that select a part of a domain but do not make one
DOMAIN_REFUSED = ("below", "above", "half_space", "band", "surface", "raster_mask") + COMBINATIONS
SHAPE_KEYS = ("box", "polygon", "prism", "disc", "below", "above", "half_space", "band",
              "surface", "raster_mask", "terrain") + COMBINATIONS
Shape.model_rebuild()


class SceneGroup(Strict):
    """Elements of a group: a slab at one or more sides of the domain, a named region, a box
    or any shape. An element belongs to one group; the last group that selects it wins."""

    side: Optional[Union[Literal[SIDES], list[Literal[SIDES]]]] = F(  # type: ignore[valid-type]
        None, description="Side of the domain's bounding box (xmin, ..., zmax), or a list of "
                          "sides (their slabs together: e.g. the outer faces)")
    depth: float = F(0.5, gt=0, description="Slab depth from the side, in element diameters")
    region: Optional[Name] = F(None, description="A region's name")
    box: Optional[SceneBox] = F(None, description="Box selecting element centres [m]")
    shape: Optional[Shape] = F(None, description="A shape selecting element centres (box, "
                                                 "polygon, disc, below, above, band)")
    surface: Optional[Literal[SIDES]] = F(  # type: ignore[valid-type]
        None, description="The outermost element seen from this side in every d-wide strip "
                          "(2-D) or d x d column (3-D) across it: e.g. ymax, the ground line of "
                          "a section with its valleys and slopes")

    @model_validator(mode="after")
    def _one(self):
        if sum(v is not None for v in (self.side, self.region, self.box, self.shape,
                                       self.surface)) != 1:
            raise ValueError("give exactly one of side, region, box or shape (or surface: a "
                             "side)")
        if isinstance(self.side, list) and not self.side:
            raise ValueError("side: give a side or a non-empty list of sides")
        return self

    def sides(self) -> list:
        """The sides of a side group (one or several), else []."""
        if self.side is None:
            return []
        return [self.side] if isinstance(self.side, str) else list(self.side)


class CoarsenSpec(Strict):
    """Graded model (docs/graded.md): fine elements (diameter d) in a band along the ground
    surface and around the slide body, coarser ones (up to factor x d) in the deep ground,
    with a linear transition (:func:`geodem.geo.terrain.band_size_field`,
    :mod:`geodem.build.graded`)."""

    factor: float = F(2.0, ge=1.0, le=4.0,
                      description="Diameter of the coarsest elements / d (1: a uniform "
                                  "packing built the graded way)")
    band: float = F(9.0, unit="m", gt=0, le=1e4,
                    description="Fine elements down to this depth below the ground surface "
                                "and below the sliding surface (at least one d)")
    transition: float = F(15.0, unit="m", ge=0, le=1e4,
                          description="Depth over which the diameter grows linearly from d "
                                      "to factor x d below the fine band (0: a step)")


class SceneCoarsen(CoarsenSpec):
    """Graded random fill of a terrain scene (docs/graded.md): fine elements (diameter d) from
    2 d above the ground down to ``band`` below it and ``band`` below the surfaces of the
    surface regions named in ``around``, the diameter growing linearly to ``factor`` d over
    ``transition`` below that (:func:`geodem.geo.terrain.band_size_field`,
    :mod:`geodem.build.graded`)."""

    around: Optional[list[Name]] = F(None, description="Regions with a surface shape whose "
                                                       "surface gets a fine band below it "
                                                       "(default: every such region)")


@register_model("scene")
class Scene(ModelBase):
    """A domain filled with a lattice, a random packing or the material's specimen packing,
    materials (or holes) by ordered regions, joints between regions on request and named
    groups (module docstring)."""

    size_field = "d"
    example = {"type": "scene", "dim": 2, "d": 0.02,
               "domain": {"box": {"min": [0.0, 0.0], "max": [0.6, 0.3]}},
               "material": "rock",
               "regions": [{"name": "soft", "material": "clay", "shape": {"below": 0.1}}],
               "interfaces": "joint",
               "groups": {"base": {"side": "ymin"}, "soft": {"region": "soft"}}}
    dim: Literal[2, 3] = F(2, description="Dimension")
    d: float = F(..., unit="m", gt=0, description="Element diameter (lattice spacing; random "
                                                  "and specimen fills: the mean diameter)")
    domain: Shape = F(..., description="The domain: a box, or a polygon or a disc in 2-D")
    fill: Literal["lattice", "random", "specimen"] = F(
        "lattice", description="Fill: 'lattice' (close-packed, diameter d), 'random' (a "
                               "packing deposited under gravity, diameters d (1 +- "
                               "distri_rate), cut by the domain) or 'specimen' (the "
                               "material's own specimen packing, cemented, cut by the domain: "
                               "a library rock is then the calibrated rock; one material)")
    packing: Literal["deposit", "isotropic"] = F(
        "deposit", description="Random fill: 'deposit' (random placement settled under "
                               "gravity) or 'isotropic' (a dense, stress-free random packing "
                               "of the bounding box, geodem.build.isotropic: a periodic cell "
                               "repeated above 20,000 elements, so that 10^6 elements build "
                               "in minutes where a deposit takes hours)")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Random and specimen fills: radius "
                                                        "spread (d_max / d_min = (1 + r) / "
                                                        "(1 - r))")
    lattice_origin: Literal["inside", "corner"] = F(
        "inside", description="Lattice fill: 'inside' (the first centre half an element inside "
                              "the lower corner, whole elements inside the bounding box) or "
                              "'corner' (the first centre on the lower corner, centres up to "
                              "the upper faces: elements on the faces overhang by d/2)")
    elements: Literal["calibrated", "elastic"] = F(
        "calibrated", description="Element parameters: 'calibrated' (the material's element "
                                  "parameters) or 'elastic' (lattice fill: the material's "
                                  "rock properties E, nu, rho converted exactly onto the "
                                  "close-packed lattice, or its kn, ks kept; element mass one "
                                  "lattice cell, bonds "
                                  "that never break: an elastic medium for waves)")
    min_bonds: Int = F(0, ge=0, le=12, description="Lattice and random fills: elements left "
                                                   "with fewer contacts than this after the "
                                                   "cut are removed, again and again (0: none)")
    half_mass: list[Literal[SIDES]] = F(  # type: ignore[valid-type]
        [], description="Sides of the bounding box whose elements, centred on its face, own "
                        "half a lattice cell: half the mass (a symmetry plane; with "
                        "lattice_origin: corner)")
    material: Name = F(..., description="Material of elements in no region")
    regions: list[Region] = F([], description="Ordered regions; a later one overrides")
    interfaces: Literal["bonded", "joint"] = F(
        "bonded", description="Bonds across two regions: 'bonded' (kept) or 'joint' (cut)")
    interface_strength: float = F(
        1.0, gt=0, le=1, description="Bonded interfaces: the breaking displacement xb and shear "
                                     "strength fs0 of a bond across two regions times this "
                                     "(1: as strong as the weaker element)")
    interface_stiffness: float = F(
        1.0, gt=0, le=1, description="Bonded interfaces: the normal and shear stiffness (Kn, "
                                     "Ks) of a bond across two regions times this (1: the "
                                     "series stiffness of its two elements); its strength "
                                     "(breaking force) is interface_strength's")
    gravity: Optional[list[float]] = F(None, unit="m/s^2", min_length=2, max_length=3,
                                       description="Gravity vector (dim components)")
    groups: dict[Name, SceneGroup] = F({}, description="Named element groups")
    sort: bool = F(True, description="Reorder elements in Morton order (faster runs)")
    coarsen: Optional[SceneCoarsen] = F(None, description="Terrain domain, random fill: a "
                                                          "graded packing, coarser in the "
                                                          "deep ground (default off)")

    def _terrain(self):
        """The :class:`~geodem.geo.terrain.TerrainModel` of a terrain domain (cached)."""
        from geodem.workflow.models import resolve_path

        return _terrain_model(self._terrain_key())

    def _terrain_key(self):
        from geodem.workflow.models import resolve_path

        t = self.domain.terrain
        path = resolve_path(t.raster)
        return (str(path), path.stat().st_mtime if path.exists() else 0.0, float(self.d),
                int(self.dim), None if t.line is None else tuple(map(tuple, t.line)),
                None if t.extent is None else tuple(t.extent), float(t.base_depth))

    def frame(self):
        """The :class:`TerrainFrame` of a terrain domain (None for other domains)."""
        if self.domain.terrain is None:
            return None
        key = self._terrain_key()
        return TerrainFrame((key[0], key[1]), self._terrain().line)

    def _bounds(self):
        s = self.domain
        if s.terrain is not None:
            x = self._terrain().x
            return x.min(axis=0) - 0.5 * self.d, x.max(axis=0) + 0.5 * self.d
        if s.box is not None:
            return np.asarray(s.box.min, float), np.asarray(s.box.max, float)
        if s.polygon is not None:
            v = np.asarray(s.polygon, float)
            return v.min(axis=0), v.max(axis=0)
        if s.prism is not None:
            lo, hi = s.prism.shape().bounds
            return np.asarray(lo, float), np.asarray(hi, float)
        if s.disc is not None:
            c = np.asarray(s.disc.center, float)
            return c - s.disc.radius, c + s.disc.radius
        return None

    def _counts(self):
        """Lattice counts covering the bounding box with element centres from ``lo + d/2``
        to ``hi - d/2`` (``lattice_origin: corner``: from ``lo`` to ``hi``)."""
        lo, hi = self._bounds()
        ext = np.maximum(hi - lo - (self.d if self.lattice_origin == "inside" else 0.0), 0.0)
        spacing = [1.0, math.sqrt(3.0) / 2.0] + ([math.sqrt(2.0 / 3.0)] if self.dim == 3 else [])
        return [int(math.floor(e / (s * self.d) + 1e-9)) + 1 for e, s in zip(ext, spacing)]

    def n_elements(self):
        if self.domain.terrain is not None:
            try:
                x = self._terrain().x
                if self.coarsen is None or self.fill != "random":
                    return int(len(x))
                # each lattice site of size d stands for (d / d_nom)^dim elements of size
                # d_nom; a jammed packing holds 9-15 % fewer (the landslide model's estimate)
                size = self.diameter_field()(x)
                return max(1, int(0.86 * np.sum((self.d / size) ** self.dim)))
            except Exception:  # noqa: BLE001 - reported by check()
                return 0
        if self._bounds() is None or len(self._bounds()[0]) != self.dim:
            return 0
        return int(np.prod(self._counts(), dtype=np.float64))

    def bytes_per_element(self):
        width = 16 if self.dim == 3 else 8
        return state_bytes_per_element(self.dim, width) + 1000

    def material_refs(self):
        out = [(("material",), self.material)]
        for k, r in enumerate(self.regions):
            if r.image is None:
                if not r.empty:
                    out.append((("regions", k, "material"), r.material))
            else:
                out += [(("regions", k, "image", "colours", n, "material"), c.material)
                        for n, c in r.image.colours.items()]
        return out

    def slots(self) -> list:
        """``(name, material, path)`` of every region, in order (an image gives one per colour);
        element region ids index this list from 1 (0: no region)."""
        out = []
        for k, r in enumerate(self.regions):
            for name, mat in r.slots():
                path = (("regions", k, "material") if r.image is None else
                        ("regions", k, "image", "colours", name, "material"))
                out.append((name, mat, path))
        return out

    def group_names(self):
        return ["all"] + list(self.groups)

    def n_across(self):
        lo, hi = self._bounds()
        return float(max(hi - lo) / self.d)

    def check(self, cfg):
        out = []
        dom = self.domain
        if ((dom.disc is not None and self.dim != 2) or
                any(getattr(dom, k) is not None for k in DOMAIN_REFUSED)):
            out.append((("domain",), "the domain is a box, a polygon or a disc (2-D), a prism "
                                     "(3-D) or a terrain"))
        out += dom.problems(self.dim, ("domain",))
        if dom.terrain is not None:
            out += self._terrain_problems()
        elif not out:
            lo, hi = self._bounds()
            if np.any(hi - lo < self.d):
                out.append((("domain",), f"the domain is thinner than one element (d = "
                                         f"{self.d:g} m) along an axis"))
        for key in ("interface_strength", "interface_stiffness"):
            if getattr(self, key) != 1.0 and self.interfaces == "joint":
                out.append(((key,), f"a joint has no bonds to weaken or soften; allowed: "
                                    f"interfaces: bonded with {key} < 1, or a joint"))
        if self.gravity is not None and len(self.gravity) != self.dim:
            out.append((("gravity",), f"{len(self.gravity)} components for dim = {self.dim}"))
        names = [n for n, _, _ in self.slots() if n is not None]
        for k, r in enumerate(self.regions):
            if r.shape is not None and r.shape.terrain is not None:
                out.append((("regions", k, "shape", "terrain"), "a terrain is a domain, not a "
                                                                "region's shape"))
            elif r.shape is not None:
                out += r.shape.problems(self.dim, ("regions", k, "shape"))
                out += self._surface_problems(r.shape, ("regions", k, "shape"))
            else:
                out += self._image_problems(r.image, ("regions", k, "image"))
            for n, _ in r.slots():
                if n is not None and names.count(n) > 1:
                    out.append((("regions", k, "name" if r.image is None else "image"),
                                f"region name {n!r} is used twice"))
        empty = [n for n, m, _ in self.slots() if n is not None and m is None]
        for name, g in self.groups.items():
            if g.region is not None and g.region not in names:
                out.append((("groups", name, "region"), f"no region named {g.region!r}; "
                                                        f"allowed: {', '.join(names) or 'none'}"))
            elif g.region in empty:
                full = ", ".join(n for n in names if n not in empty) or "none"
                out.append((("groups", name, "region"), f"region {g.region!r} is empty (it "
                                                        f"holds no element); allowed: {full}"))
            if g.shape is not None and g.shape.terrain is not None:
                out.append((("groups", name, "shape", "terrain"), "a terrain is a domain, not "
                                                                  "a group's shape"))
            elif g.shape is not None:
                out += g.shape.problems(self.dim, ("groups", name, "shape"))
                out += self._surface_problems(g.shape, ("groups", name, "shape"))
        for name, g in self.groups.items():
            if g.surface is not None and DOF_NAMES.index(g.surface[0]) >= self.dim:
                out.append((("groups", name, "surface"), f"side {g.surface!r} does not exist "
                                                         f"in {self.dim}-D"))
        for k, side in enumerate(self.half_mass):
            if DOF_NAMES.index(side[0]) >= self.dim:
                out.append((("half_mass", k), f"side {side!r} does not exist in {self.dim}-D"))
        if self.packing != "deposit" and (self.fill != "random" or self.coarsen):
            out.append((("packing",), "packing applies to a random fill without coarsen; "
                                      "allowed here: 'deposit'"))
        if self.fill != "lattice":
            for key, default in (("lattice_origin", "inside"), ("elements", "calibrated"),
                                 ("half_mass", [])):
                if getattr(self, key) != default:
                    out.append(((key,), f"{key} applies to fill: lattice (the close-packed "
                                        f"lattice); allowed with fill: {self.fill}: "
                                        f"{default!r}"))
            if self.fill == "specimen" and self.min_bonds:
                out.append((("min_bonds",), "a specimen fill removes the elements left with "
                                            "fewer than 2 bonds itself; allowed: 0"))
        elif self.elements == "elastic":
            for name, mat, path in [(None, self.material, ("material",))] + self.slots():
                if mat is not None and mat in cfg.materials:
                    try:
                        self.medium(cfg, mat, path)
                    except BuildError as exc:
                        out.append((exc.path, str(exc)))
        if self.fill == "specimen":
            out += self._specimen_problems(cfg)
        if self.coarsen is not None:
            out += self._coarsen_problems()
        return out + group_problems(self.groups, self.dim)

    def _surface_regions(self) -> dict:
        """``{name: region}`` of the named regions with a surface shape."""
        return {r.name: r for r in self.regions
                if r.name and r.shape is not None and r.shape.surface is not None}

    def _coarsen_problems(self):
        """A graded fill: a random fill of a terrain domain, a band of at least one d, and
        surface regions to refine around."""
        c, out = self.coarsen, []
        if self.fill != "random" or self.domain.terrain is None:
            out.append((("coarsen",), f"a graded fill is a random fill of a terrain domain; "
                                      f"allowed here (fill: {self.fill}, "
                                      f"{'terrain' if self.domain.terrain else 'no terrain'}"
                                      f" domain): none"))
        if c.band < self.d:
            out.append((("coarsen", "band"), f"{c.band:g} m is thinner than one element "
                                             f"(d = {self.d:g} m); allowed: >= {self.d:g}"))
        known = self._surface_regions()
        for k, name in enumerate(c.around or []):
            if name not in known:
                out.append((("coarsen", "around", k), f"no region named {name!r} with a "
                                                      f"surface shape; allowed: "
                                                      f"{', '.join(known) or 'none'}"))
        return out

    def _specimen_problems(self, cfg):
        """A specimen fill packs and cements one material in a box, polygon or disc domain."""
        from geodem.workflow.material import material_problems

        if self.domain.terrain is not None:
            return [(("fill",), "a specimen fill packs a box, a polygon or a disc domain; "
                                "allowed for a terrain: lattice, random")]
        out = []
        for name, mat, path in self.slots():
            if mat is not None and mat != self.material:
                out.append((path, f"a specimen fill cements one material, the scene's "
                                  f"{self.material!r} (its packing recipe and bonds); this "
                                  f"region names {mat!r}: allowed: {self.material!r} or "
                                  f"empty: true, or fill: lattice or random for several "
                                  f"materials"))
        return out + material_problems(cfg, self.material, self.dim, self.d)

    def _terrain_problems(self):
        from geodem.geo.errors import GeometryError
        from geodem.workflow.models import resolve_path

        t, path = self.domain.terrain, ("domain", "terrain")
        if self.dim == 2 and t.extent is not None:
            return [(path + ("extent",), "a 2-D scene is a section: give line, not extent")]
        if self.dim == 3 and t.line is not None:
            return [(path + ("line",), "a 3-D scene is a block: give extent, not line")]
        if t.line is not None and (len(t.line) != 2 or any(len(v) != 2 for v in t.line)):
            return [(path + ("line",), "two points [[x0, y0], [x1, y1]] (local m)")]
        if not resolve_path(t.raster).exists():
            return [(path + ("raster",), f"raster not found: {t.raster} (looked in the working "
                                         f"directory and the geodem source tree)")]
        try:
            self._terrain()
        except GeometryError as exc:
            field = "raster" if "raster" in str(exc).lower() else (
                "line" if t.line is not None and "line" in str(exc) else "base_depth")
            return [(path + (field,), str(exc))]
        return []

    def _surface_problems(self, shape, path):
        """The surfaces and raster masks of a shape (nested ones too): a terrain domain that
        reads, and rasters that read onto its grid."""
        out = []
        for where, sh in shape.leaves(path):
            out += self._raster_problems(sh, where)
        return out

    def _raster_problems(self, shape, path):
        """One shape's surface or raster mask (:meth:`_surface_problems`)."""
        from geodem.geo.errors import GeometryError
        from geodem.workflow.models import resolve_path

        if shape.surface is not None:
            key, files = "surface", shape.surface.files()
        elif shape.raster_mask is not None:
            key, files = "raster_mask", [("raster", shape.raster_mask.raster)]
        else:
            return []
        path = path + (key,)
        if self.domain.terrain is None:
            return [(path, f"a {key.replace('_', ' ')} lies on a terrain: allowed with domain: "
                           "{terrain: ...} only (other domains: the shapes below, above, "
                           "half_space, band, polygon or prism)")]
        if self._terrain_problems():
            return []  # reported on the domain
        for field, file in files:
            if not resolve_path(file).exists():
                return [(path + (field,), f"raster not found: {file} (looked in the working "
                                          f"directory and the geodem source tree)")]
            try:
                self.frame().raster(file)
            except GeometryError as exc:
                return [(path + (field,), str(exc))]
        return []

    def _image_problems(self, im, path):
        from geodem.geo.errors import GeometryError
        from geodem.workflow.models import resolve_path

        if self.dim == 2 and im.plane != "xy":
            return [(path + ("plane",), "a 2-D scene lies in the xy plane")]
        if not resolve_path(im.file).exists():
            return [(path + ("file",), f"image not found: {im.file} (looked in the working "
                                       f"directory and the geodem source tree)")]
        try:
            im.read()
        except (GeometryError, ValueError, OSError) as exc:
            return [(path + ("file",), str(exc))]
        return []

    def build(self, cfg):
        from geodem.build.lattice import prune_loose
        from geodem.core.neighbors import spatial_sort

        d = self.d
        lo, hi = self._bounds()
        radius = 0.5 * d
        info = {"d": d, "diameter": d, "domain_min": [float(v) for v in lo],
                "domain_max": [float(v) for v in hi]}
        d_nom = None  # each element's nominal diameter: a graded fill's only
        if self.fill == "specimen":
            st, region, more = self._specimen_fill(cfg, lo, hi)
            info.update(more)
        else:
            if self.fill == "random":
                x, radius, d_nom, extra = self._random_fill(cfg, lo, hi)
                info.update(extra)
            elif self.domain.terrain is not None:
                x = np.array(self._terrain().x, float)  # local: (along the line, z) or (x, y, z)
            else:
                x = self._lattice(lo, hi)
            if len(x) == 0:
                raise BuildError(("domain",), "the domain holds no element")
            region = self.region_ids(x)
            info["elements_removed"] = int((region < 0).sum())
            keep = region >= 0  # empty regions: no element
            if self.min_bonds:
                r = np.broadcast_to(radius, (len(x),))
                keep[keep] = prune_loose(x[keep], r[keep], self.min_bonds, gap=1e-6 * d)
                info["loose_removed"] = int((region >= 0).sum() - keep.sum())
            x, region = x[keep], region[keep]
            if np.ndim(radius):
                radius = radius[keep]
            if d_nom is not None:
                d_nom = d_nom[keep]
            if len(x) == 0:
                raise BuildError(("regions",), "every element lies in an empty region")
            st = self._bond(cfg, x, radius, region, d_nom)
            if self.elements == "elastic":
                info["medium"] = {k: v for k, v in self.medium(cfg).items() if k != "element"}
            halve_side_masses(st, self.half_mass, d)
        slots = self.slots()
        if self.gravity is not None:
            st.gravity[:self.dim] = self.gravity
        info["joint_bonds_cut"] = cut_interfaces(st, region) if self.interfaces == "joint" else 0
        if self.interfaces == "bonded" and self.interface_strength != 1.0:
            info["interface_bonds_weakened"] = weaken_interfaces(st, region,
                                                                 self.interface_strength)
        if self.interfaces == "bonded" and self.interface_stiffness != 1.0:
            info["interface_bonds_softened"] = soften_interfaces(st, region,
                                                                 self.interface_stiffness)
        self._add_groups(st, region, d_nom)
        if self.sort:
            spatial_sort(st)
        labels = ["default"] + [n or f"region {k}" for k, (n, _, _) in enumerate(slots)]
        info["elements_by_region"] = {labels[k]: int((region == k).sum())
                                      for k in range(len(labels))
                                      if k == 0 or slots[k - 1][1] is not None}
        if self.domain.terrain is not None:
            info.update(self._terrain_info(st))
        return BuiltModel(st, st.x.copy(), self.n_across(), info)

    def _terrain_info(self, st) -> dict:
        """What a terrain scene's results and pictures need of the terrain: ``base_z`` [m],
        ``georef`` (the elevation raster's CRS and transform, the local origin; 2-D: the
        section line in local and CRS coordinates), ``solid_fraction`` (element volume over the
        ground's volume) and, in 2-D, ``profile`` (``s``, the ground ``top`` and each surface
        region's elevation under ``surfaces`` along the section)."""
        from geodem.geo.terrain import block_bulk_volume

        model, frame = self._terrain(), self.frame()
        top = frame.top
        zb = float(model.base_z)
        meta = top.metadata()
        if self.dim == 2:
            p0, p1 = (np.asarray(p, float) for p in model.line)
            meta["line_local"] = [p0.tolist(), p1.tolist()]
            meta["line_crs"] = [list(top.to_global(p0)), list(top.to_global(p1))]
            s_top = np.linspace(0.0, float(model.extent[1]), 400)
            xy = p0 + s_top[:, None] * (p1 - p0) / float(model.extent[1])
            ground = top.elevation(xy)
            surfaces = {}
            for k, reg in enumerate(self.regions):
                if reg.shape is not None and reg.shape.surface is not None:
                    surfaces[reg.name or f"region {k}"] = \
                        reg.shape.surface.elevation(xy, frame).tolist()
            profile = {"s": s_top.tolist(), "top": ground.tolist(), "surfaces": surfaces}
            bulk = float(np.trapezoid(np.maximum(ground - zb, 0.0), s_top))
            solid = float(np.sum(np.pi * st.r ** 2))
        else:
            profile = None
            bulk = block_bulk_volume(top, model.extent, zb)
            solid = float(np.sum(4.0 / 3.0 * np.pi * st.r ** 3))
        return {"base_z": zb, "georef": meta, "profile": profile,
                "solid_fraction": float(min(1.0, solid / bulk)) if bulk > 0 else None}

    def _lattice(self, lo, hi):
        """Centres of the close-packed lattice over the bounding box ``lo, hi``, cut by the
        domain (``lattice_origin``: whole elements inside the box, or centres from the lower
        corner up to the upper faces)."""
        from geodem.build.lattice import fcc_lattice, triangular_lattice

        d, c = self.d, self._counts()
        x = fcc_lattice(*c, d) if self.dim == 3 else triangular_lattice(*c, d)
        tol = 1e-9 * d
        if self.lattice_origin == "corner":
            x = x + lo
            keep = np.all((x >= lo - tol) & (x <= hi + tol), axis=1)
            return x[keep & (self.domain.mask(x) if self.domain.box is None else True)]
        x = x + lo + 0.5 * d
        # whole elements inside the bounding box; in a polygon, centres inside
        return x[self.domain.mask(x) & np.all(x <= hi - 0.5 * d + tol, axis=1)]

    def medium(self, cfg, name=None, path=("material",)) -> dict:
        """The elastic lattice medium of a material (``elements: elastic``;
        :func:`~geodem.workflow.material.elastic_medium`)."""
        from geodem.workflow.material import elastic_medium

        return elastic_medium(cfg, name or self.material, self.d, self.dim, path)

    def _bond(self, cfg, x, radius, region, d_nom=None):
        """The bonded state of element centres ``x`` (radius ``radius``), each with its region's
        element parameters (:func:`~geodem.build.lattice.bonded_state`), given for diameter d
        and, in a graded fill, taken to each element's nominal diameter ``d_nom``
        (:data:`geodem.build.graded.SIZE_LAW`: kn, ks, xb ~ d, fs0 ~ d^2, mass ~ d^3)."""
        from geodem.build.graded import SIZE_LAW
        from geodem.build.lattice import bonded_state

        d = self.d
        slots = self.slots()
        mats = [self.material] + [m for _, m, _ in slots]
        paths = [("material",)] + [p for _, _, p in slots]
        if self.elements == "elastic":
            params = {k: self.medium(cfg, name, paths[k])["element"]
                      for k, name in enumerate(mats) if name is not None}
        else:
            params = {k: element_params(cfg, name, d, self.dim, paths[k])
                      for k, name in enumerate(mats) if name is not None}
        per = {key: np.array([params[int(k)][key] for k in region], float)
               for key in ("kn", "ks", "xb", "fs0", "mu", "rho")}
        size = np.ones(len(x)) if d_nom is None else np.asarray(d_nom, float) / d
        for key in per:
            if key in SIZE_LAW:
                per[key] *= size ** SIZE_LAW[key]
        thick = d if self.elements == "elastic" and self.dim == 2 else None
        st = bonded_state(x, radius, density=per["rho"], kn=per["kn"], ks=per["ks"],
                          xb=per["xb"], fs0=per["fs0"], mu=per["mu"], gap=1e-6 * d,
                          thickness=thick)
        for k in params:
            if params[k]["mass"] is not None:
                at = region == k
                st.m[at] = params[k]["mass"] * size[at] ** SIZE_LAW["mass"]
        return st

    def _specimen_fill(self, cfg, lo, hi):
        """The material's own specimen (:func:`~geodem.build.specimen.make_specimen` box over
        the domain's bounding box: its packing recipe, cemented with its element parameters),
        cut by the domain and the empty regions; elements left with fewer than 2 bonds are
        removed and the model is balanced after a cut. Returns ``(state, region, info)``."""
        from geodem.build.shapes import subset_state
        from geodem.build.specimen import make_specimen, packing_notes, settle, well_bonded
        from geodem.workflow.material import specimen_material

        try:
            sm = specimen_material(cfg, self.material, self.dim, self.d)
        except ValueError as exc:
            raise BuildError(("material",), str(exc)) from None
        seed = int(cfg.metadata.seed or 0)
        try:
            st, rep = make_specimen("box", list(hi - lo), self.d, self.distri_rate,
                                    sm.material, self.dim, seed, element=sm.element)
        except ValueError as exc:
            raise BuildError(("domain",), str(exc)) from None
        st.x += lo
        st.x_ref += lo
        st.groups, st.group[:] = {"all": 0}, 0
        region = self.region_ids(st.x)
        keep = self.domain.mask(st.x) & (region >= 0)
        kept = well_bonded(st, keep, 2)
        info = {"material": sm.label, "material_warnings": list(sm.warnings) + packing_notes(rep),
                "elements_removed": int(st.n - keep.sum()),
                "loose_removed": int(keep.sum() - kept.sum()),
                "specimen_report": {k: v for k, v in rep.items() if k != "packing"}}
        if not kept.all():
            st, region = subset_state(st, kept), region[kept]
            if st.n == 0:
                raise BuildError(("regions",), "no bonded element is left after the cut")
            st = settle(st, self.n_across())
        st.v[:] = 0.0
        st.step, st.time = 0, 0.0
        return st, region, info

    def _random_fill(self, cfg, lo, hi):
        """A random packing of the domain's bounding box (random placement, then deposition
        under gravity: :mod:`geodem.build.packing`; with ``coarsen`` a graded packing:
        :meth:`_graded_fill`; with ``packing: isotropic`` a dense, stress-free random packing
        of the box: :func:`~geodem.build.isotropic.isotropic_packing`), cut by the domain (a
        terrain: by :func:`~geodem.geo.terrain.terrain_model` on the packing); returns ``(x,
        r, d_nom, info)``: centres, radii, each element's nominal diameter (a graded fill's,
        else None) and entries for the model's info (``graded``; ``packing`` and
        ``material_warnings`` of an isotropic packing)."""
        if self.coarsen is not None:
            return self._graded_fill(cfg, lo, hi)
        d = self.d
        lo = np.asarray(lo, float)
        seed = int(cfg.metadata.seed or 0)
        fill = self._isotropic_box if self.packing == "isotropic" else self._deposited_box
        px, pr, extra = fill(cfg, lo, np.asarray(hi, float), seed)
        if self.domain.terrain is not None:
            tm = _terrain_model(self._terrain_key(), packing=(px, pr))
            return np.array(tm.x, float), np.array(tm.r, float), None, extra
        lo0, hi0 = self._bounds()
        keep = self.domain.mask(px) & np.all((px - pr[:, None] >= lo0 - 1e-9 * d)
                                             & (px + pr[:, None] <= hi0 + 1e-9 * d), axis=1)
        return px[keep], pr[keep], None, extra

    def _isotropic_box(self, cfg, lo, hi, seed):
        """The dense, stress-free random packing of the box ``[lo, hi]`` (tiled above 20,000
        elements); returns ``(x, r, info)``, info with the packing's report and its warning."""
        from geodem.build.isotropic import isotropic_packing
        from geodem.build.specimen import packing_notes

        px, pr, rep = isotropic_packing(hi - lo, self.d, self.distri_rate, seed=seed)
        return px + lo, pr, {"packing": {k: v for k, v in rep.items()
                                         if not isinstance(v, list)},
                             "material_warnings": packing_notes({"packing": rep})}

    def _deposited_box(self, cfg, lo, hi, seed):
        """Elements placed at random in the box ``[lo, hi]`` (2 d taller: it settles lower)
        and deposited under gravity; returns ``(x, r, {})``."""
        from geodem.build import packing
        from geodem.core import groups as grp

        d, dim = self.d, self.dim
        hi = hi + np.r_[np.zeros(dim - 1), 2.0 * d]
        phi = 0.84 if dim == 2 else 0.63
        x, r = packing.random_placement((np.zeros(dim), hi - lo), porosity=1.0 - 1.1 * phi,
                                        d_mean=d, distri_rate=self.distri_rate, seed=seed)
        dep = packing.deposition_state(x, r, (np.zeros(dim), hi - lo),
                                       rho=element_params(cfg, self.material, d, dim)["rho"])
        packing.deposit(dep)
        s = grp.members(dep, "sample")
        return dep.x[s] + lo, dep.r[s].copy(), {}

    def _graded_fill(self, cfg, lo, hi):
        """The graded packing of a terrain scene's bounding box
        (:func:`~geodem.build.graded.graded_packing` on :meth:`diameter_field`),
        cut by the ground; returns ``(x, r, d_nom, {"graded": report})`` (the report: the
        counts of fine, transition and coarse elements, the largest nominal diameter and the
        packing's own)."""
        from geodem.build.graded import graded_packing

        c, d = self.coarsen, self.d
        seed = int(cfg.metadata.seed or 0)
        try:
            px, pr, dn, rep = graded_packing(np.asarray(lo, float), np.asarray(hi, float),
                                             self.diameter_field(), d, self.distri_rate, seed=seed)
        except ValueError as exc:
            raise BuildError(("coarsen",), str(exc)) from None
        tm = _terrain_model(self._terrain_key(), packing=(px, pr))
        dk = dn[tm.info["packing_index"]]
        fine = dk <= d * rep["scale"] * (1.0 + 1e-9)
        coarse = (dk >= c.factor * d * rep["scale"] * (1.0 - 1e-9)) & ~fine
        report = {"factor": c.factor, "band": c.band, "transition": c.transition,
                  "around": list(self._refined_surfaces()), "fine": int(fine.sum()),
                  "transition_elements": int((~fine & ~coarse).sum()),
                  "coarse": int(coarse.sum()), "d_nom_max": float(dk.max()),
                  **{f"packing_{k}": v for k, v in rep.items()}}
        return np.array(tm.x, float), np.array(tm.r, float), dk, {"graded": report}

    def _refined_surfaces(self) -> dict:
        """``{name: SceneSurface}`` of the surfaces a graded fill refines below."""
        regions = self._surface_regions()
        names = list(regions) if self.coarsen.around is None else self.coarsen.around
        return {n: regions[n].shape.surface for n in names}

    def diameter_field(self):
        """The graded fill's nominal diameter ``size(x (N, dim)) -> (N,)`` [m]: fine (d) from
        2 d above the ground to ``band`` below it and below the refined surfaces, then growing
        linearly to ``factor`` d over ``transition`` (:func:`geodem.geo.terrain.band_size_field`,
        its sliding surface the lowest of the refined surfaces)."""
        from geodem.geo.terrain import band_size_field

        c, frame = self.coarsen, self.frame()
        surfaces = list(self._refined_surfaces().values())
        lowest = None
        if surfaces:
            def lowest(xy):
                return np.min([sf.elevation(xy, frame) for sf in surfaces], axis=0)
        return band_size_field(frame.top, self.d, c.factor, c.band, c.transition,
                               sliding_surface=lowest, line=frame.line)

    def region_ids(self, x) -> np.ndarray:
        """Region index per element (the last region wins): 0 for none, k + 1 for
        ``slots()[k]``, -1 for an element in an empty region or on an image's empty pixel (it
        is removed). Elements outside an image keep what earlier regions gave them."""
        from geodem.geo.image import EMPTY, pixel_labels

        region = np.zeros(len(x), np.int64)
        first = 1
        frame = self.frame()
        for r in self.regions:
            if r.image is None:
                region[r.shape.mask(x, frame)] = -1 if r.empty else first
                first += 1
                continue
            im = r.image.read()
            lab = pixel_labels(x, im, r.image.extent(im), r.image.plane, outside="keep")
            slot = {name: first + k for k, name in enumerate(r.image.colours)}
            for k, name in enumerate(im.names):
                region[lab == k] = slot[name]
            region[lab == EMPTY] = -1
            first += len(r.image.colours)
        return region

    def _add_groups(self, st, region, d_nom=None):
        """The named groups; a side slab's depth counts in each element's own nominal diameter
        (``d_nom``, a graded fill; at least d), so a slab of coarse base elements is whole."""
        from geodem.core import groups as grp

        lo, hi = st.x.min(axis=0), st.x.max(axis=0)
        own = self.d if d_nom is None else np.maximum(np.asarray(d_nom, float), self.d)
        names = {n: k + 1 for k, (n, _, _) in enumerate(self.slots()) if n is not None}
        for name, g in self.groups.items():
            if g.side is not None:
                sel = np.zeros(st.n, bool)
                for side in g.sides():
                    ax = DOF_NAMES.index(side[0])
                    depth = g.depth * own
                    sel |= (st.x[:, ax] <= lo[ax] + depth - 1e-9 * self.d
                            if side.endswith("min") else
                            st.x[:, ax] >= hi[ax] - depth + 1e-9 * self.d)
            elif g.region is not None:
                sel = region == names[g.region]
            elif g.shape is not None:
                sel = g.shape.mask(st.x, self.frame())
            elif g.surface is not None:
                sel = surface_elements(st.x, self.d, g.surface)
            else:
                sel = np.all((st.x >= np.asarray(g.box.min)) & (st.x <= np.asarray(g.box.max)),
                             axis=1)
            if not sel.any():
                raise BuildError(("groups", name), f"group {name!r} selects no element")
            grp.add_group(st, name, sel)


@functools.lru_cache(maxsize=8)
def _read_on_grid(path, mtime, top_key):
    from geodem.geo import read_elevation

    return read_elevation(path, like=_read_top(*top_key))


@functools.lru_cache(maxsize=4)
def _read_top(path, mtime):
    from geodem.geo import read_elevation

    return read_elevation(path)


def _terrain_model(key, packing=None):
    """Element centres under a terrain: :func:`geodem.geo.terrain.terrain_model` (a close-packed
    lattice, or ``packing = (x, r)``, cut by the ground, down to ``base_depth`` below its lowest
    point). The lattice model is cached."""
    if packing is None:
        return _terrain_lattice(key)
    from geodem.geo import terrain_model

    path, mtime, d, dim, line, extent, base_depth = key
    base_z = _terrain_lattice(key).base_z
    return terrain_model(_read_top(path, mtime), d, base_z=base_z, dim=dim, body="ground",
                         line=None if line is None else [list(p) for p in line],
                         extent=extent, packing=packing)


@functools.lru_cache(maxsize=4)
def _terrain_lattice(key):
    from geodem.geo import terrain_model

    path, mtime, d, dim, line, extent, base_depth = key
    return terrain_model(_read_top(path, mtime), d, base_depth=base_depth, dim=dim,
                         body="ground", line=None if line is None else [list(p) for p in line],
                         extent=extent)


def surface_elements(x, d, side) -> np.ndarray:
    """Indices of the outermost element seen from ``side`` (xmin, ..., zmax) in every d-wide
    strip (2-D) or d x d column (3-D) across it (strips counted from the lowest centre)."""
    x = np.asarray(x, float)
    ax = DOF_NAMES.index(side[0])
    other = [k for k in range(x.shape[1]) if k != ax]
    cell = np.floor((x[:, other] - x[:, other].min(axis=0)) / d + 1e-6).astype(np.int64)
    key = cell[:, 0]
    for k in range(1, cell.shape[1]):
        key = key * (int(cell[:, k].max()) + 1) + cell[:, k]
    height = x[:, ax] if side.endswith("max") else -x[:, ax]
    order = np.lexsort((height, key))  # by strip, then height: the last of each is outermost
    s = key[order]
    last = np.r_[s[1:] != s[:-1], True]
    return np.sort(order[last])


def halve_side_masses(state, sides, d) -> None:
    """Halve the mass of the elements centred on the faces ``sides`` of the bounding box of the
    element centres (within 10^-6 d): they own half a lattice cell."""
    lo, hi = state.x.min(axis=0), state.x.max(axis=0)
    tol = 1e-6 * d
    on = np.zeros(state.n, bool)
    for side in sides:
        ax = DOF_NAMES.index(side[0])
        on |= np.abs(state.x[:, ax] - (lo[ax] if side.endswith("min") else hi[ax])) < tol
    state.m[on] *= 0.5


def _across(state, region) -> np.ndarray:
    """Mask of the rows (both sides of each contact) bonding two elements of different
    regions."""
    from geodem.core.state import BONDED

    i = np.repeat(np.arange(state.n), state.nbr.shape[1]).reshape(state.nbr.shape)
    j = state.nbr
    across = (j >= 0) & (state.cstate == BONDED)
    return across & (region[i] != region[np.where(j >= 0, j, 0)])


def weaken_interfaces(state, region, factor: float) -> int:
    """Scale the bond rate (breaking force and Fs0, PHYSICS.md section 2) of every bond across
    two regions by ``factor``: a weaker interface (a bedding plane, a cemented contact);
    returns the number of bonds."""
    from geodem.core.state import scale_bond_rate

    across = _across(state, region)
    scale_bond_rate(state, across, factor)
    return int(across.sum()) // 2


def soften_interfaces(state, region, factor: float) -> int:
    """Scale the stiffness (``Kn`` and ``Ks``, PHYSICS.md section 1) of every bond across two
    regions by ``factor`` (0 < factor <= 1) through the rows' contact stiffness factor: a
    softer interface whose strength (breaking force) stays as it is, so it breaks at a
    displacement ``1/factor`` times larger; returns the number of bonds. A contact the
    interface's elements make anew later has the elements' own stiffness."""
    from geodem.core.state import scale_row_stiffness

    across = _across(state, region)
    scale_row_stiffness(state, across, factor)
    return int(across.sum()) // 2


def cut_interfaces(state, region) -> int:
    """Unbond every bonded contact whose two elements lie in different regions (a joint: the
    contact stays, frictional, without cement); returns the number of bonds cut."""
    from geodem.core.state import UNBONDED

    across = _across(state, region)
    state.cstate[across] = UNBONDED
    return int(across.sum()) // 2
