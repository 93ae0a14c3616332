"""Elevation rasters -> :class:`Terrain` (a regular grid of elevations in metres).

:func:`read_elevation` reads one band of any raster GDAL reads (GeoTIFF, ASCII grid, ...) through
rasterio and returns a :class:`Terrain` in a metric, north-up grid with a local origin. The rules:

CRS
    The raster's CRS, or ``crs=`` when the file has none (or a wrong one: ``crs`` overrides).
    Neither -> :class:`GeometryError`. The model's CRS is ``target_crs`` when given (it must be
    projected, in metres); otherwise a geographic raster (degrees) is reprojected to the UTM zone
    of its centre (:func:`utm_crs`: EPSG 326zz north, 327zz south, zone ``floor((lon + 180)/6) +
    1``; the Norway/Svalbard exceptions are ignored); a projected raster in metres keeps its CRS;
    one in other units (feet) needs ``target_crs`` (and ``z_scale`` for its elevations).
Nodata
    Cells equal to the nodata value (the file's, and ``nodata=``: an extra value, compared in the
    raster's own data type, e.g. float32), masked by the file, or not finite are filled before
    resampling by inverse-distance weighting of the ``k = 8`` nearest valid cells on the rim of
    the holes: ``z = sum(w_i z_i) / sum(w_i)``, ``w_i = 1 / d_i^2`` (``d`` in metres on the
    source grid; a geographic grid's degrees are converted at its central latitude with the
    Earth's mean radius). A single hole in a plane is filled exactly (the 8 neighbours pair
    up symmetrically). ``Terrain.nodata_filled`` counts the filled source cells (in the window
    read: the region plus a margin of a few cells). All-nodata, or more than
    ``max_nodata_fraction`` (default 0.5) nodata, -> :class:`GeometryError`.
Resampling
    When the model grid differs from the raster's (another CRS, another ``resolution``, a
    ``like`` grid), GDAL's warper resamples with ``resampling``: ``"auto"`` is ``"average"`` when
    the new cells are larger than the raster's (downsampling: the mean of the covered cells,
    weighted by overlap) and ``"bilinear"`` otherwise (upsampling: exact for a plane ``z = a x +
    b y + c`` between the outermost cell centres); any other name of
    :class:`rasterio.enums.Resampling` is passed through. The warper's coordinate transformer
    runs exactly (``tolerance = 0``). Same CRS, native resolution: cells are copied, no
    resampling (``Terrain.resampling == "none"``).
Clipping
    ``region = (xmin, ymin, xmax, ymax)`` in the model CRS (or in ``region_crs``, e.g.
    ``"EPSG:4326"`` for lon/lat, converted with densified edges). It must lie inside the raster's
    footprint (pixel edges), else :class:`GeometryError`. Without a region the whole raster is used
    (after reprojection, or for a raster not stored north-up (south-up, east-to-west, turned by
    90 or 180 degrees): the largest axis-aligned rectangle inside the footprint, found from its
    densified edges, told apart by their coordinates). Without resampling the cells whose
    centres span the region are kept (one cell beyond each side at most); with resampling the
    new grid starts at the region's west and north edges. With ``like=`` the region is that
    terrain's ``extent`` (not its grid, which may overhang it by under a cell: those cells
    are edge-filled), so a layer raster on the elevation raster's own grid, or on a larger
    one, is accepted in any CRS.
Local origin
    ``origin="auto"``: the region's (or grid's) lower-left corner ``(x0, y0)``, elevations kept
    (``z0 = 0``); ``None``: global coordinates; or ``(x0, y0[, z0])``. Local coordinates are
    ``x = X - x0``, ``y = Y - y0``, ``z = Z - z0``; :meth:`Terrain.to_global` inverts them.
Metadata
    ``Terrain.crs`` (WKT), ``epsg``, ``transform`` (the GDAL/rasterio affine ``(a, b, c, d, e, f)``
    of the grid in the CRS: ``X = a col + b row + c``, ``Y = d col + e row + f``, pixel corners),
    ``origin`` and ``source_crs``: :meth:`Terrain.metadata` returns them for output files;
    :meth:`Terrain.save` writes the grid back as a GeoTIFF.

Grid convention: ``Terrain.z[row, col]`` in raster order (row 0 = north edge), cell centres at
local ``x = west + (col + 1/2) dx``, ``y = north - (row + 1/2) dy``.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from geodem.geo.errors import GeometryError

__all__ = ["Terrain", "read_elevation", "utm_crs", "write_raster", "fill_nodata",
           "IDW_NEIGHBOURS", "MAX_NODATA_FRACTION"]

#: number of valid rim cells averaged by the inverse-distance nodata fill
IDW_NEIGHBOURS = 8
#: default largest nodata fraction of the cells read that is filled rather than refused
MAX_NODATA_FRACTION = 0.5


def _rasterio():
    from geodem.extras import needs_extra

    with needs_extra("reading elevation rasters"):
        import rasterio  # noqa: F401
        import rasterio.warp  # noqa: F401
    return rasterio


# ============================================================================ Terrain
@dataclass
class Terrain:
    """A north-up grid of elevations [m] in local coordinates (see the module docstring).

    ``z`` (ny, nx) local elevation ``Z - z0`` [m], row 0 at the north edge; ``transform`` the
    grid's affine in the CRS (6 floats, ``b = d = 0``, ``a = dx > 0``, ``e = -dy < 0``);
    ``crs`` WKT or None; ``origin = (x0, y0, z0)`` CRS coordinates of the local origin;
    ``extent = (xmin, ymin, xmax, ymax)`` local rectangle the terrain stands for (the clipping
    region; default the grid's pixel edges); ``nodata_filled`` source cells filled;
    ``edge_filled`` cells of the new grid outside the source footprint, filled the same way
    (slivers of under one cell at its edges); ``resampling`` the method used (``"none"``: cells
    copied); ``source``, ``source_crs`` (WKT), ``epsg``.
    """

    z: np.ndarray
    transform: tuple
    crs: str | None = None
    origin: tuple = (0.0, 0.0, 0.0)
    extent: tuple | None = None
    nodata_filled: int = 0
    edge_filled: int = 0
    resampling: str = "none"
    source: str = ""
    source_crs: str | None = None
    epsg: int | None = None
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        z = np.ascontiguousarray(self.z, dtype=np.float64)
        if z.ndim != 2 or min(z.shape) < 2:
            raise GeometryError(f"a terrain needs a 2-D grid of at least 2 x 2 cells, got shape "
                                f"{z.shape}")
        if not np.all(np.isfinite(z)):
            raise GeometryError(f"terrain elevations must be finite ({int((~np.isfinite(z)).sum())}"
                                " cells are not; fill nodata first)")
        self.z = z
        t = tuple(float(v) for v in self.transform)
        if len(t) != 6 or t[1] != 0.0 or t[3] != 0.0 or not t[0] > 0 or not t[4] < 0:
            raise GeometryError(f"terrain transform must be north-up (a > 0, b = d = 0, e < 0), "
                                f"got {t}")
        self.transform = t
        o = tuple(float(v) for v in self.origin)
        self.origin = o + (0.0,) * (3 - len(o))
        if self.extent is None:
            self.extent = self.grid_bounds
        self.extent = tuple(float(v) for v in self.extent)

    def __repr__(self) -> str:
        """One short line whatever the grid size (the generated dataclass repr printed every
        elevation): grid, cell size, CRS, local extent, elevation range, origin, source."""
        try:
            crs = f"EPSG:{self.epsg}" if self.epsg else _crs_label(self.crs)
            e = self.extent
            parts = [f"z {self.z.shape} {self.z.dtype.str.lstrip('<>|=')} "
                     f"{float(self.z.min()):.6g}..{float(self.z.max()):.6g} m",
                     f"cells {self.dx:.4g} x {self.dy:.4g} m", crs,
                     f"extent x {e[0]:.6g}..{e[2]:.6g}, y {e[1]:.6g}..{e[3]:.6g} m",
                     "origin (" + ", ".join(f"{v:.8g}" for v in self.origin) + ")",
                     f"resampling {self.resampling}"]
            if self.nodata_filled or self.edge_filled:
                parts.append(f"filled {self.nodata_filled} nodata + {self.edge_filled} edge")
            if self.source:
                parts.append(f"source {_clip_left(str(self.source), 60)!r}")
            return f"Terrain({', '.join(parts)})"
        except Exception as exc:  # noqa: BLE001 - a repr must not raise
            return f"Terrain(<unprintable: {type(exc).__name__}>)"

    # ---------------------------------------------------------------- grid geometry
    @property
    def dx(self) -> float:
        """Cell size along x (east) [m]."""
        return self.transform[0]

    @property
    def dy(self) -> float:
        """Cell size along y (north) [m]."""
        return -self.transform[4]

    @property
    def nx(self) -> int:
        return self.z.shape[1]

    @property
    def ny(self) -> int:
        return self.z.shape[0]

    @property
    def x0(self) -> float:
        return self.origin[0]

    @property
    def y0(self) -> float:
        return self.origin[1]

    @property
    def z0(self) -> float:
        return self.origin[2]

    @property
    def west(self) -> float:
        """Local x of the grid's west edge [m]."""
        return self.transform[2] - self.origin[0]

    @property
    def north(self) -> float:
        """Local y of the grid's north edge [m]."""
        return self.transform[5] - self.origin[1]

    @property
    def grid_bounds(self) -> tuple:
        """Local ``(west, south, east, north)`` pixel edges of the grid [m]."""
        return (self.west, self.north - self.ny * self.dy, self.west + self.nx * self.dx,
                self.north)

    @property
    def x_centres(self) -> np.ndarray:
        """Local x of the cell centres, west to east (nx,) [m]."""
        return self.west + (np.arange(self.nx) + 0.5) * self.dx

    @property
    def y_centres(self) -> np.ndarray:
        """Local y of the cell centres, NORTH to south (ny,) [m] (raster row order)."""
        return self.north - (np.arange(self.ny) + 0.5) * self.dy

    def centres(self) -> np.ndarray:
        """Local (x, y) of every cell centre, (ny, nx, 2), raster order."""
        X, Y = np.meshgrid(self.x_centres, self.y_centres)
        return np.stack([X, Y], axis=-1)

    # ---------------------------------------------------------------- sampling
    def elevation(self, xy) -> np.ndarray:
        """Local elevation [m] at local points ``xy`` (..., 2), bilinear between cell centres.

        With ``u = (x - x_c0)/dx`` and ``w = (y_c0 - y)/dy`` (cell coordinates from the NW
        centre), ``i = floor(u)``, ``s = u - i``, ``j = floor(w)``, ``t = w - j``:
        ``z = (1-s)(1-t) z[j,i] + s(1-t) z[j,i+1] + (1-s)t z[j+1,i] + s t z[j+1,i+1]``.
        Beyond the outermost centres (the outer half cells and outside) ``u, w`` are clamped:
        the edge values continue flat.
        """
        p = np.asarray(xy, dtype=np.float64)
        if p.shape[-1] != 2:
            raise ValueError(f"points must have shape (..., 2), got {p.shape}")
        u = np.clip((p[..., 0] - (self.west + 0.5 * self.dx)) / self.dx, 0.0, self.nx - 1)
        w = np.clip(((self.north - 0.5 * self.dy) - p[..., 1]) / self.dy, 0.0, self.ny - 1)
        i = np.minimum(np.floor(u).astype(np.int64), self.nx - 2)
        j = np.minimum(np.floor(w).astype(np.int64), self.ny - 2)
        s = u - i
        t = w - j
        z = self.z
        return ((1 - s) * (1 - t) * z[j, i] + s * (1 - t) * z[j, i + 1]
                + (1 - s) * t * z[j + 1, i] + s * t * z[j + 1, i + 1])

    def __call__(self, xy):
        return self.elevation(xy)

    def profile(self, p0, p1, n=None):
        """Section along the straight line from ``p0`` to ``p1`` (local (x, y) [m]).

        Returns ``(s, xy, z)``: distance along the line [m] (n,), the points (n, 2) and their
        elevation (n,). ``n`` defaults to one point per ``min(dx, dy)`` (at least 2).
        """
        a = np.asarray(p0, float)
        b = np.asarray(p1, float)
        if a.shape != (2,) or b.shape != (2,):
            raise GeometryError(f"profile end points need 2 coordinates, got {p0}, {p1}")
        length = float(np.linalg.norm(b - a))
        if not length > 0:
            raise GeometryError(f"profile line has zero length: {p0} -> {p1}")
        if n is None:
            n = max(2, int(math.ceil(length / min(self.dx, self.dy))) + 1)
        s = np.linspace(0.0, length, int(n))
        xy = a + np.outer(s / length, b - a)
        return s, xy, self.elevation(xy)

    # ---------------------------------------------------------------- coordinates
    def to_global(self, xyz) -> np.ndarray:
        """CRS coordinates of local points (..., 2 or 3)."""
        p = np.asarray(xyz, float)
        return p + np.asarray(self.origin[:p.shape[-1]])

    def to_local(self, XYZ) -> np.ndarray:
        """Local coordinates of CRS points (..., 2 or 3)."""
        p = np.asarray(XYZ, float)
        return p - np.asarray(self.origin[:p.shape[-1]])

    def metadata(self) -> dict:
        """Georeferencing for output files: plain numbers and strings (HDF5/JSON friendly)."""
        return {"crs": self.crs or "", "epsg": -1 if self.epsg is None else int(self.epsg),
                "transform": list(self.transform), "origin": list(self.origin),
                "extent": list(self.extent), "shape": [self.ny, self.nx],
                "dx": self.dx, "dy": self.dy, "nodata_filled": int(self.nodata_filled),
                "edge_filled": int(self.edge_filled), "resampling": self.resampling,
                "source": self.source, "source_crs": self.source_crs or ""}

    def save(self, path) -> None:
        """Write the grid (global elevations ``z + z0``) as a float64 GeoTIFF with CRS and
        transform."""
        write_raster(path, self.z + self.z0, self.transform, self.crs)

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_array(cls, z, dx, dy=None, *, west=0.0, south=0.0, crs=None, origin=None,
                   north_up=True):
        """A terrain from an elevation array [m] (raster order, row 0 north, unless
        ``north_up=False``: row 0 south) with cells ``dx`` x ``dy`` [m] whose SW corner is at
        CRS ``(west, south)``. ``origin`` defaults to ``(west, south, 0)``: local (0, 0) at the
        SW corner."""
        z = np.asarray(z, float)
        if not north_up:
            z = z[::-1]
        dy = dx if dy is None else dy
        if not (dx > 0 and dy > 0):
            raise GeometryError(f"cell sizes must be > 0, got dx={dx}, dy={dy}")
        if z.ndim != 2:
            raise GeometryError(f"elevations must be a 2-D array, got shape {z.shape}")
        t = (float(dx), 0.0, float(west), 0.0, -float(dy), float(south) + z.shape[0] * dy)
        return cls(z=z, transform=t, crs=_wkt(crs), origin=(west, south, 0.0) if origin is None
                   else origin, epsg=_epsg(crs))

    @classmethod
    def from_function(cls, f, extent, dx, dy=None, *, crs=None):
        """A terrain with elevations ``f(x, y)`` [m] (vectorised) at the cell centres of a grid
        covering the local ``extent = (xmin, ymin, xmax, ymax)`` exactly with cells ``dx`` x
        ``dy`` (rounded so that whole cells fit). Local = CRS coordinates."""
        xmin, ymin, xmax, ymax = map(float, extent)
        dy = dx if dy is None else dy
        nx = max(2, int(round((xmax - xmin) / dx)))
        ny = max(2, int(round((ymax - ymin) / dy)))
        dx, dy = (xmax - xmin) / nx, (ymax - ymin) / ny
        xc = xmin + (np.arange(nx) + 0.5) * dx
        yc = ymax - (np.arange(ny) + 0.5) * dy
        X, Y = np.meshgrid(xc, yc)
        z = np.broadcast_to(np.asarray(f(X, Y), float), X.shape)
        return cls.from_array(z, dx, dy, west=xmin, south=ymin, crs=crs, origin=(0.0, 0.0, 0.0))


def _crs_label(wkt) -> str:
    """A CRS's name from its WKT (``PROJCRS["WGS 84 / UTM zone 32N", ...``), at most 40
    characters; ``"no CRS"`` for None."""
    if not wkt:
        return "no CRS"
    import re

    m = re.search(r'^\s*[A-Z]+\["([^"]*)"', str(wkt))
    name = m.group(1) if m else str(wkt)
    return name if len(name) <= 40 else name[:37] + "..."


def _clip_left(text: str, n: int) -> str:
    """``text``, or its last ``n - 3`` characters after ``...`` (paths keep their file name)."""
    return text if len(text) <= n else "..." + text[-(n - 3):]


def _wkt(crs):
    if crs is None:
        return None
    if isinstance(crs, str) and crs.lstrip().upper().startswith(("PROJCRS", "GEOGCRS", "PROJCS",
                                                                  "GEOGCS", "COMPOUNDCRS")):
        return crs
    from rasterio.crs import CRS

    return CRS.from_user_input(crs).to_wkt()


def _epsg(crs):
    if crs is None:
        return None
    try:
        from rasterio.crs import CRS

        return CRS.from_user_input(crs).to_epsg()
    except Exception:  # noqa: BLE001 - EPSG lookup is informative only
        return None


def write_raster(path, z, transform, crs=None, nodata=None) -> None:
    """Write ``z`` (ny, nx) (raster order) as a single-band float64 GeoTIFF with ``transform``
    (6 floats or an :class:`affine.Affine`) and ``crs`` (anything rasterio accepts, or None)."""
    rasterio = _rasterio()
    from affine import Affine

    z = np.asarray(z)
    t = transform if isinstance(transform, Affine) else Affine(*transform)
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype=z.dtype if z.dtype != bool else "uint8", crs=crs, transform=t,
                       nodata=nodata) as dst:
        dst.write(z, 1)


# ============================================================================ CRS helpers
def utm_crs(lon: float, lat: float):
    """The WGS 84 / UTM zone CRS of a point (degrees): EPSG ``32600 + zone`` north of the
    equator, ``32700 + zone`` south, ``zone = floor((lon + 180) / 6) + 1`` (1..60)."""
    from rasterio.crs import CRS

    if not (math.isfinite(lon) and math.isfinite(lat) and -90 <= lat <= 90):
        raise GeometryError(f"not a longitude/latitude: ({lon}, {lat})")
    lon = (lon + 180.0) % 360.0 - 180.0
    zone = min(int(math.floor((lon + 180.0) / 6.0)) + 1, 60)
    return CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


def _is_metric(crs) -> bool:
    if not crs.is_projected:
        return False
    try:
        return abs(float(crs.linear_units_factor[1]) - 1.0) < 1e-12
    except Exception:  # noqa: BLE001
        return False


def _crs_name(crs) -> str:
    e = crs.to_epsg()
    return f"EPSG:{e}" if e else crs.to_string()[:80]


# ============================================================================ nodata
def fill_nodata(z, invalid, dx=1.0, dy=1.0, k=IDW_NEIGHBOURS):
    """Fill the cells ``invalid`` of ``z`` in place by inverse-distance weighting (power 2) of
    the ``k`` nearest valid cells on the rim of the holes (valid cells with an invalid one among
    their 8 neighbours); distances in metres with cells ``dx`` x ``dy``. Returns the number of
    cells filled and the largest distance [m] from a filled cell to its nearest valid cell."""
    from scipy.ndimage import binary_dilation
    from scipy.spatial import cKDTree

    invalid = np.asarray(invalid, bool)
    nh = int(invalid.sum())
    if nh == 0:
        return 0, 0.0
    rim = ~invalid & binary_dilation(invalid, structure=np.ones((3, 3), bool))
    rj, ri = np.nonzero(rim)
    hj, hi = np.nonzero(invalid)
    scale = np.array([dy, dx], float)
    tree = cKDTree(np.stack([rj, ri], axis=1) * scale)
    kk = min(int(k), len(rj))
    dist, idx = tree.query(np.stack([hj, hi], axis=1) * scale, k=kk)
    dist = dist.reshape(nh, kk)
    idx = idx.reshape(nh, kk)
    w = 1.0 / dist ** 2
    z[hj, hi] = (w * z[rj[idx], ri[idx]]).sum(axis=1) / w.sum(axis=1)
    return nh, float(dist[:, 0].max())


# ============================================================================ reading
def _resampling(name):
    from rasterio.enums import Resampling

    try:
        return Resampling[name]
    except KeyError:
        allowed = ["auto"] + [m.name for m in Resampling if m.value <= 13]
        raise GeometryError(f"unknown resampling {name!r}; allowed: {allowed}") from None


def _densified_ring(xmin, ymin, xmax, ymax, n=21):
    t = np.linspace(0.0, 1.0, n)[:-1]
    xs = np.concatenate([xmin + (xmax - xmin) * t, np.full_like(t, xmax),
                         xmax - (xmax - xmin) * t, np.full_like(t, xmin)])
    ys = np.concatenate([np.full_like(t, ymin), ymin + (ymax - ymin) * t,
                         np.full_like(t, ymax), ymax - (ymax - ymin) * t])
    return xs, ys


def _north_up(tr, width, height):
    """An axis-aligned raster's affine ``tr`` (``b = d = 0`` or ``a = e = 0``) turned north-up:
    ``(affine, width, height, f)`` with ``f`` mapping a full band array (height, width) to the
    north-up array (row 0 north, column 0 west)."""
    from affine import Affine

    a, b, c, d, e, f = tr.a, tr.b, tr.c, tr.d, tr.e, tr.f
    steps = []
    if a == 0 and e == 0:  # X = b row + c, Y = d col + f: rows run along x
        steps.append(np.transpose)
        a, b, d, e = b, 0.0, 0.0, d
        width, height = height, width
    if a < 0:  # columns run west
        c, a = c + a * width, -a
        steps.append(lambda z: z[:, ::-1])
    if e > 0:  # rows run north
        f, e = f + e * height, -e
        steps.append(lambda z: z[::-1])

    def turn(z):
        for step in steps:
            z = step(z)
        return np.ascontiguousarray(z)

    return Affine(a, 0.0, c, 0.0, e, f), width, height, turn


def _equal_in_dtype(raw, nodata):
    """Cells of ``raw`` equal to ``nodata`` compared in the raster's own dtype: ``-9999.9`` in
    a float32 raster is ``float32(-9999.9)``, not the float64 ``-9999.9``. A NaN nodata
    matches the NaN cells; a value an integer raster cannot hold (a fraction, out of range)
    matches no cell."""
    try:
        v = float(nodata)
    except (TypeError, ValueError):
        raise GeometryError(f"nodata must be a number, got {nodata!r}") from None
    if math.isnan(v):
        return np.isnan(raw) if raw.dtype.kind == "f" else np.zeros(raw.shape, bool)
    if raw.dtype.kind in "iu":
        info = np.iinfo(raw.dtype)
        if v != math.floor(v) or not info.min <= v <= info.max:
            return np.zeros(raw.shape, bool)
        return raw == raw.dtype.type(int(v))
    with np.errstate(over="ignore"):
        return raw == raw.dtype.type(v)


def _inner_box(foot, n):
    """``(xmin, ymin, xmax, ymax)`` of the axis-aligned rectangle inside a footprint ring
    ``foot`` (4 n, 2) made of the raster's 4 edges (row 0, last column, last row, column 0; n
    points each, in model coordinates [m]).

    The edges are told apart by their coordinates, not by the raster's orientation (south-up,
    east-to-west, rotated by 90 or 180 degrees all occur): the edge whose mean point lies
    farthest north of the footprint's centre is the north edge, and so on. The rectangle spans
    from the west edge's easternmost point to the east edge's westernmost, and from the south
    edge's northernmost point to the north edge's southernmost. An empty box (``xmax <= xmin``
    or ``ymax <= ymin``) when the edges cannot be told apart (a footprint turned by about 45
    degrees)."""
    edges = [foot[k * n:(k + 1) * n] for k in range(4)]
    mid = np.array([e.mean(axis=0) for e in edges]) - foot.mean(axis=0)
    north, south = int(np.argmax(mid[:, 1])), int(np.argmin(mid[:, 1]))
    east, west = int(np.argmax(mid[:, 0])), int(np.argmin(mid[:, 0]))
    if len({north, south, east, west}) != 4:
        return (0.0, 0.0, 0.0, 0.0)
    return (float(edges[west][:, 0].max()), float(edges[south][:, 1].max()),
            float(edges[east][:, 0].min()), float(edges[north][:, 1].min()))


#: the Earth's mean radius [m] (IUGG): metres per radian on a geographic grid
EARTH_RADIUS = 6371008.8


def _cell_metres(tr, crs, shape):
    """The source cells' ground size ``(dx, dy)`` [m] for the nodata fill: a geographic grid's
    degrees are ``R pi/180`` m of latitude and ``R pi/180 cos(lat)`` m of longitude at the
    window's central latitude (``R`` = :data:`EARTH_RADIUS`); a projected grid's units times
    their length in metres (feet: 0.3048)."""
    sdx, sdy = math.hypot(tr.a, tr.d), math.hypot(tr.b, tr.e)
    if crs.is_geographic:
        ny, nx = shape
        lat = (tr @ (0.5 * nx, 0.5 * ny))[1]
        k = EARTH_RADIUS * math.pi / 180.0
        return sdx * k * max(math.cos(math.radians(lat)), 1e-6), sdy * k
    try:
        f = float(crs.linear_units_factor[1])
    except Exception:  # noqa: BLE001 - no linear unit known: take the units as metres
        f = 1.0
    return sdx * f, sdy * f


def _fmt_box(b):
    return "x {:.10g} .. {:.10g}, y {:.10g} .. {:.10g}".format(
        *(round(float(v), 6) for v in (b[0], b[2], b[1], b[3])))


def read_elevation(path, *, crs=None, target_crs=None, resolution=None, region=None,
                   region_crs=None, band=None, resampling="auto", origin="auto", nodata=None,
                   z_scale=1.0, like=None, transform=None,
                   max_nodata_fraction=MAX_NODATA_FRACTION) -> Terrain:
    """Read an elevation raster into a :class:`Terrain` (rules in the module docstring).

    Parameters
    ----------
    path : raster file (anything GDAL opens).
    crs : the raster's CRS when the file has none, or to override it (e.g. ``"EPSG:32633"``).
    target_crs : the model's CRS (projected, metres). Default: the raster's CRS, or the UTM zone
        of its centre when it is geographic.
    resolution : model cell size [m] (one value or ``(dx, dy)``); default the raster's.
    region : ``(xmin, ymin, xmax, ymax)`` to clip to, in ``target_crs`` (or ``region_crs``).
    band : the band to read (1-based); required when the raster has several.
    resampling : ``"auto"`` (average when downsampling, else bilinear) or a rasterio name.
    origin : ``"auto"`` (lower-left corner of the region), ``None`` (global coordinates) or
        ``(x0, y0[, z0])`` [m].
    nodata : a further nodata value (compared in the raster's data type); the cells at the
        file's own nodata value (or masked by it) stay nodata.
    z_scale : factor applied to the elevations (e.g. 0.3048 for feet).
    like : a :class:`Terrain`: resample onto exactly its grid, CRS and origin (for layer
        rasters and pre/post-event pairs).
    transform : the raster's affine (6 floats, rasterio order) when the file has none.
    max_nodata_fraction : refuse rasters whose cells read are more nodata than this.
    """
    rasterio = _rasterio()
    from affine import Affine
    from rasterio.crs import CRS
    from rasterio.errors import CRSError, NotGeoreferencedWarning, RasterioIOError
    from rasterio.transform import array_bounds
    from rasterio.warp import calculate_default_transform, reproject, transform_bounds
    from rasterio.warp import transform as warp_points
    from rasterio.windows import Window

    name = os.fspath(path)
    if not os.path.exists(name):
        raise GeometryError(f"{name}: no such file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            src = rasterio.open(name)
    except RasterioIOError as exc:
        raise GeometryError(f"{name}: cannot be read as a raster ({exc}); an elevation raster "
                            "is a single-band grid in a format GDAL reads (GeoTIFF, ...)") from None
    with src:
        width, height, count = src.width, src.height, src.count
        # ---- dimensionality
        if band is None:
            if count != 1:
                raise GeometryError(f"{name}: the raster has {count} bands "
                                    f"({', '.join(src.dtypes)}); an elevation raster needs one "
                                    "band: pass band=k to choose one")
            band = 1
        if not (isinstance(band, (int, np.integer)) and 1 <= band <= count):
            raise GeometryError(f"{name}: band={band!r} does not exist; the raster has {count} "
                                f"band(s), numbered 1..{count}")
        if width < 2 or height < 2:
            raise GeometryError(f"{name}: the raster is {width} x {height} cells (columns x "
                                "rows); an elevation raster needs at least 2 x 2 cells "
                                "(bilinear sampling)")
        # ---- source CRS and transform
        try:
            s_crs = CRS.from_user_input(crs) if crs is not None else src.crs
        except CRSError as exc:
            raise GeometryError(f"crs={crs!r} is not a CRS: {exc}") from None
        if s_crs is None:
            raise GeometryError(f"{name}: the raster has no CRS (coordinate reference system); "
                                "give it with crs=..., e.g. crs='EPSG:32633'")
        if transform is not None:
            s_tr = transform if isinstance(transform, Affine) else Affine(*transform)
        else:
            s_tr = src.transform
            if s_tr.is_identity and src.crs is None:
                raise GeometryError(f"{name}: the raster has no georeferencing (pixel size and "
                                    "position); give transform=(dx, 0, west, 0, -dy, north)")
        # ---- target CRS
        if like is not None:
            if like.crs is None:
                raise GeometryError("like= terrain has no CRS")
            t_crs = CRS.from_wkt(like.crs)
        elif target_crs is not None:
            try:
                t_crs = CRS.from_user_input(target_crs)
            except CRSError as exc:
                raise GeometryError(f"target_crs={target_crs!r} is not a CRS: {exc}") from None
            if not _is_metric(t_crs):
                raise GeometryError(f"target_crs {_crs_name(t_crs)} is not a projected CRS in "
                                    "metres; a model needs metric coordinates (e.g. a UTM zone)")
        elif s_crs.is_geographic:
            sb = array_bounds(height, width, s_tr)
            cx, cy = 0.5 * (sb[0] + sb[2]), 0.5 * (sb[1] + sb[3])
            lon, lat = warp_points(s_crs, CRS.from_epsg(4326), [cx], [cy])
            t_crs = utm_crs(lon[0], lat[0])
        elif _is_metric(s_crs):
            t_crs = s_crs
        else:
            units = s_crs.linear_units_factor[0] if s_crs.is_projected else "unknown units"
            raise GeometryError(f"{name}: the raster's CRS {_crs_name(s_crs)} is in {units}; "
                                "give target_crs= (a projected CRS in metres) and z_scale= for "
                                "elevations not in metres")
        same_crs = t_crs == s_crs
        north_up = s_tr.b == 0 and s_tr.d == 0 and s_tr.a > 0 and s_tr.e < 0
        axis_aligned = (s_tr.b == 0 and s_tr.d == 0) or (s_tr.a == 0 and s_tr.e == 0)
        reorient = None
        if same_crs and axis_aligned and not north_up:
            # south-up, east-to-west or turned by 90/180 degrees: the cells, turned north-up
            # in memory, are copied like those of a north-up raster (no resampling)
            s_tr, width, height, reorient = _north_up(s_tr, width, height)
            north_up = True
        # ---- native resolution in the target CRS, footprint
        sb = array_bounds(height, width, s_tr)  # (west, south, east, north)
        if same_crs and north_up:
            native = (s_tr.a, -s_tr.e)
        else:
            dtr, _, _ = calculate_default_transform(s_crs, t_crs, width, height, *sb)
            native = (abs(dtr.a), abs(dtr.e))
        cols = np.concatenate([np.linspace(0, width, 41), np.full(41, width),
                               np.linspace(width, 0, 41), np.zeros(41)])
        rows = np.concatenate([np.zeros(41), np.linspace(0, height, 41), np.full(41, height),
                               np.linspace(height, 0, 41)])
        fx, fy = s_tr @ (cols, rows)
        if not same_crs:
            fx, fy = warp_points(s_crs, t_crs, list(fx), list(fy))
        foot = np.stack([np.asarray(fx, float), np.asarray(fy, float)], axis=1)
        fbox = (foot[:, 0].min(), foot[:, 1].min(), foot[:, 0].max(), foot[:, 1].max())
        # ---- region in the target CRS
        if like is not None:
            # the region the terrain stands for, not its grid: a grid resampled from another
            # CRS overhangs its region (and its raster's footprint) by under one cell, whose
            # outer cells are edge-filled; a raster on the same grid covers just the region
            lb = like.extent
            reg = (lb[0] + like.x0, lb[1] + like.y0, lb[2] + like.x0, lb[3] + like.y0)
            given = True
        elif region is not None:
            try:
                reg = tuple(float(v) for v in region)
            except (TypeError, ValueError):
                reg = ()
            if len(reg) != 4 or not all(map(math.isfinite, reg)) or not (
                    reg[2] > reg[0] and reg[3] > reg[1]):
                raise GeometryError(f"region must be (xmin, ymin, xmax, ymax) with xmax > xmin "
                                    f"and ymax > ymin, got {region!r}")
            if region_crs is not None:
                r_crs = CRS.from_user_input(region_crs)
                if r_crs != t_crs:
                    reg = tuple(transform_bounds(r_crs, t_crs, *reg, densify_pts=21))
            given = True
        else:
            given = False
            if same_crs and north_up:
                reg = tuple(sb)
            else:  # largest axis-aligned rectangle inside the reprojected footprint
                reg = _inner_box(foot, 41)
                if not (reg[2] > reg[0] and reg[3] > reg[1]):
                    raise GeometryError(f"{name}: cannot find a rectangle inside the raster's "
                                        f"footprint in {_crs_name(t_crs)}; give region=")
        # ---- coverage
        size = max(fbox[2] - fbox[0], fbox[3] - fbox[1])
        rx, ry = _densified_ring(*reg)
        from geodem.build.shapes import polygon_mask

        inside = polygon_mask(np.stack([rx, ry], axis=1), foot, tol=1e-7 * size)
        if not inside.all():
            what = "the requested region" if given else "the default region"
            raise GeometryError(
                f"{name}: {what} ({_fmt_box(reg)} in {_crs_name(t_crs)}) is not covered by the "
                f"raster, which covers {_fmt_box(fbox)} (pixel edges); choose a region inside it")
        # ---- resolution and method
        if resolution is None:
            res = (like.dx, like.dy) if like is not None else native
        else:
            r_ = np.atleast_1d(np.asarray(resolution, float))
            if r_.size == 1:
                r_ = np.repeat(r_, 2)
            if r_.size != 2 or not np.all(np.isfinite(r_)) or not np.all(r_ > 0):
                raise GeometryError(f"resolution must be one or two cell sizes > 0 [m], got "
                                    f"{resolution!r}")
            if like is not None:
                raise GeometryError("give like= or resolution=, not both")
            res = (float(r_[0]), float(r_[1]))
        same_res = all(abs(a - b) <= 1e-9 * b for a, b in zip(res, native))
        copy_cells = same_crs and north_up and same_res and like is None
        if resampling == "auto":
            down = any(a > b * (1 + 1e-9) for a, b in zip(res, native))
            method = "average" if down else "bilinear"
        else:
            method = str(resampling)
        if method != "none":
            rs = _resampling(method)
        elif not copy_cells:
            raise GeometryError("resampling='none' keeps the raster's cells: it needs the same "
                                "CRS and resolution (and no like=); choose a method, e.g. "
                                "'auto'")
        # ---- source window
        if copy_cells:
            a, e = s_tr.a, -s_tr.e
            c0 = int(math.floor((reg[0] - s_tr.c) / a - 0.5 + 1e-9))
            c1 = int(math.ceil((reg[2] - s_tr.c) / a - 0.5 - 1e-9))
            r0 = int(math.floor((s_tr.f - reg[3]) / e - 0.5 + 1e-9))
            r1 = int(math.ceil((s_tr.f - reg[1]) / e - 0.5 - 1e-9))
            c0, r0 = max(c0, 0), max(r0, 0)
            c1, r1 = min(max(c1, c0 + 1), width - 1), min(max(r1, r0 + 1), height - 1)
            c0, r0 = min(c0, c1 - 1), min(r0, r1 - 1)
            win = Window(c0, r0, c1 - c0 + 1, r1 - r0 + 1)
        else:
            if like is not None:
                nxd, nyd = like.nx, like.ny
                d_tr = Affine(*like.transform)
            else:
                nxd = max(2, int(math.ceil((reg[2] - reg[0]) / res[0] - 1e-9)))
                nyd = max(2, int(math.ceil((reg[3] - reg[1]) / res[1] - 1e-9)))
                d_tr = Affine(res[0], 0.0, reg[0], 0.0, -res[1], reg[3])
            db = array_bounds(nyd, nxd, d_tr)
            wb = db if same_crs else transform_bounds(t_crs, s_crs, *db, densify_pts=21)
            inv = ~s_tr
            cx_, ry_ = inv @ (np.array([wb[0], wb[2], wb[0], wb[2]]),
                              np.array([wb[1], wb[1], wb[3], wb[3]]))
            pad = 2 + int(math.ceil(max(res[0] / native[0], res[1] / native[1])))
            c0 = max(int(math.floor(cx_.min())) - pad, 0)
            c1 = min(int(math.ceil(cx_.max())) + pad, width)
            r0 = max(int(math.floor(ry_.min())) - pad, 0)
            r1 = min(int(math.ceil(ry_.max())) + pad, height)
            win = Window(c0, r0, max(c1 - c0, 1), max(r1 - r0, 1))
        if reorient is None:
            raw = src.read(band, window=win)
            invalid = src.read_masks(band, window=win) == 0
        else:
            rs_, cs_ = win.toslices()
            raw = reorient(src.read(band))[rs_, cs_]
            invalid = reorient(src.read_masks(band))[rs_, cs_] == 0
        nd_txt = ("nodata value " + repr(src.nodata)) if src.nodata is not None \
            else "masked cells"
        if nodata is not None:
            invalid |= _equal_in_dtype(raw, nodata)
            same = src.nodata is None or float(src.nodata) == float(nodata)
            nd_txt = f"nodata value {nodata}" + ("" if same else
                                                 f" or the file's {src.nodata!r}")
        data = raw.astype(np.float64)
        invalid |= ~np.isfinite(data)
        w_tr = src.window_transform(win) if transform is None and reorient is None else \
            s_tr @ Affine.translation(win.col_off, win.row_off)
    # ---- nodata
    nbad = int(invalid.sum())
    if nbad == data.size:
        raise GeometryError(f"{name}: all {data.size} cells read (band {band}, around "
                            f"{_fmt_box(reg)}) are nodata ({nd_txt}); an elevation raster "
                            "needs valid elevations there")
    if nbad > max_nodata_fraction * data.size:
        raise GeometryError(f"{name}: {nbad} of {data.size} cells read "
                            f"({100.0 * nbad / data.size:.1f} %) are nodata ({nd_txt}); at most "
                            f"{100 * max_nodata_fraction:.0f} % are filled (max_nodata_fraction)"
                            "; choose a region inside the valid data")
    sdx, sdy = _cell_metres(w_tr, s_crs, data.shape)
    filled, fill_dist = fill_nodata(data, invalid, sdx, sdy)
    # ---- resample
    edge = 0
    if copy_cells:
        out = data
        o_tr = w_tr
        method = "none"
    else:
        out = np.full((nyd, nxd), np.nan)
        reproject(data, out, src_transform=w_tr, src_crs=s_crs, dst_transform=d_tr,
                  dst_crs=t_crs, resampling=rs, src_nodata=None, dst_nodata=np.nan,
                  tolerance=0.0, num_threads=1)
        bad = ~np.isfinite(out)
        edge = int(bad.sum())
        if edge == out.size:  # pragma: no cover - excluded by the coverage check
            raise GeometryError(f"{name}: resampling produced no valid cell")
        fill_nodata(out, bad, res[0], res[1])
        o_tr = d_tr
    out = out * float(z_scale)
    # ---- origin
    if like is not None:
        org = like.origin
    elif origin is None or (isinstance(origin, str) and origin in ("none", "global")):
        org = (0.0, 0.0, 0.0)
    elif isinstance(origin, str):
        if origin != "auto":
            raise GeometryError(f"origin must be 'auto', None or (x0, y0[, z0]), got {origin!r}")
        org = (reg[0], reg[1], 0.0)
    else:
        o = tuple(float(v) for v in origin)
        if len(o) not in (2, 3):
            raise GeometryError(f"origin must be (x0, y0) or (x0, y0, z0), got {origin!r}")
        org = o + (0.0,) * (3 - len(o))
    ext = (reg[0] - org[0], reg[1] - org[1], reg[2] - org[0], reg[3] - org[1])
    return Terrain(z=out - org[2], transform=tuple(o_tr)[:6], crs=t_crs.to_wkt(), origin=org,
                   extent=ext, nodata_filled=filled, edge_filled=edge, resampling=method,
                   source=name, source_crs=s_crs.to_wkt(), epsg=t_crs.to_epsg(),
                   info={"native_resolution": tuple(map(float, native)),
                         "fill_distance": fill_dist, "band": int(band)})
