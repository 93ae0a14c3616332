"""Layer rasters (slip depth, post-event DEM) read onto an elevation raster's grid with
``read_elevation(..., like=top)``: a pair on one geographic grid, a window clipped from a
larger geographic tile, nodata voids, and the UTM pair.

The geographic rasters are square in degrees (1 arc-second, like SRTM tiles): a grid resampled
to UTM overhangs its region by under one cell, which is what the layer once had to cover."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from rasterio.warp import transform as warp_points  # noqa: E402
from rasterio.windows import Window  # noqa: E402
from rasterio.windows import transform as window_transform  # noqa: E402

from geodem.geo import read_elevation  # noqa: E402
from geodem.geo.raster import EARTH_RADIUS, _cell_metres, fill_nodata  # noqa: E402
from geodem.geo.terrain import Depth, slip_surface_from_pair  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")

RES = 1.0 / 3600.0  # 1 arc-second


def write(path, data, transform, crs="EPSG:4326", nodata=None, dtype="float32"):
    data = np.asarray(data)
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=dtype, crs=crs, transform=transform,
                       nodata=nodata) as dst:
        dst.write(data.astype(dtype), 1)
    return str(path)


def elev(i, j):
    return 1500.0 + 3.0 * i - 2.0 * j


def depth(i, j):
    return 4.0 + 0.05 * i + 0.02 * j


def cell_coords(t, west, north, res=RES):
    """Source column and row (cell centre = integer) of every cell centre of terrain ``t``."""
    g = t.to_global(t.centres().reshape(-1, 2))
    lon, lat = warp_points(t.crs, "EPSG:4326", g[:, 0], g[:, 1])
    i = (np.asarray(lon) - west) / res - 0.5
    j = (north - np.asarray(lat)) / res - 0.5
    return i.reshape(t.z.shape), j.reshape(t.z.shape)


def test_layer_on_the_same_geographic_grid(tmp_path):
    west, north, ny, nx = 10.0, 46.0, 30, 40
    tr = from_origin(west, north, RES, RES)
    j, i = np.mgrid[0:ny, 0:nx]
    zp = write(tmp_path / "z.tif", elev(i, j), tr)
    sp = write(tmp_path / "s.tif", depth(i, j), tr)
    top = read_elevation(zp)
    assert top.epsg == 32632 and top.resampling == "bilinear"
    gb, ext = top.grid_bounds, top.extent
    assert gb[1] < ext[1] - 0.1 * top.dy  # the UTM grid overhangs its region (south edge)
    s = read_elevation(sp, like=top)
    assert s.z.shape == top.z.shape and s.transform == top.transform
    assert s.origin == top.origin and s.extent == pytest.approx(ext, abs=1e-9)
    # the same raster on its own grid goes through the same resampling: identical cells
    assert np.array_equal(read_elevation(zp, like=top).z, top.z)
    ci, rj = cell_coords(top, west, north)
    inner = (ci >= 0) & (ci <= nx - 1) & (rj >= 0) & (rj <= ny - 1)
    assert inner.sum() > 0.9 * inner.size
    # GDAL's bilinear kernel is widened along the 21 m longitude cells: within 0.2 cells
    assert np.abs(s.z - depth(ci, rj))[inner].max() < 0.2 * 0.05
    assert np.abs(top.z - elev(ci, rj))[inner].max() < 0.2 * 3.0
    assert 4.0 < s.z.min() < 4.1 and 6.4 < s.z.max() < 6.53  # depth(0, 0) .. depth(39, 29)
    pair = slip_surface_from_pair(top, read_elevation(zp, like=top))
    assert pair.info["depleted_cells"] == 0


def test_workflow_reads_a_geographic_pair(tmp_path):
    from geodem.cases.landslide import read_terrains

    j, i = np.mgrid[0:24, 0:32]
    tr = from_origin(-122.3, 47.6, RES, RES)
    model = SimpleNamespace(raster=write(tmp_path / "z.tif", elev(i, j), tr), crs=None,
                            slip_depth=write(tmp_path / "d.tif", depth(i, j), tr),
                            slip_surface=None)
    top, slip = read_terrains(model)
    assert top.epsg == 32610  # floor((180 - 122.3) / 6) + 1 = 10, north
    assert isinstance(slip, Depth) and slip.value.z.shape == top.z.shape
    ci, rj = cell_coords(top, -122.3, 47.6)
    inner = (ci >= 0) & (ci <= 31) & (rj >= 0) & (rj <= 23)
    assert np.abs(slip.value.z - depth(ci, rj))[inner].max() < 0.01


def test_layer_clipped_from_a_larger_geographic_tile(tmp_path):
    # a 150 x 150 tile whose cell centres sit on whole arc-seconds (SRTM: pixel is area, the
    # corner half a cell off); the model's rasters are a window clipped from it
    west, north, n = 7.5 - 0.5 * RES, 46.0 + 0.5 * RES, 150
    tile = from_origin(west, north, RES, RES)
    j, i = np.mgrid[0:n, 0:n]
    write(tmp_path / "tile_z.tif", elev(i, j), tile)
    tile_s = write(tmp_path / "tile_s.tif", depth(i, j), tile)
    win = Window(40, 30, 60, 50)
    wtr = window_transform(win, tile)
    sl = win.toslices()
    top = read_elevation(write(tmp_path / "z.tif", elev(i, j)[sl], wtr))
    s_win = read_elevation(write(tmp_path / "s.tif", depth(i, j)[sl], wtr), like=top)
    s_tile = read_elevation(tile_s, like=top)  # a layer covering more than the model
    ci, rj = cell_coords(top, west, north)
    assert ci.min() > 39.4 and ci.max() < 99.6 and rj.min() > 29.4 and rj.max() < 79.6
    inner = (ci >= 40) & (ci <= 99) & (rj >= 30) & (rj <= 79)
    for s in (s_win, s_tile):
        assert s.z.shape == top.z.shape and s.transform == top.transform
        assert np.abs(s.z - depth(ci, rj))[inner].max() < 0.01
    # the tile has data beyond the window: right to the last cells of the grid
    assert np.abs(s_tile.z - depth(ci, rj)).max() < 0.01
    assert s_tile.edge_filled == 0 and s_tile.nodata_filled == 0


def test_nodata_voids_in_a_geographic_pair(tmp_path):
    # at 60 N a cell of 1 x 1 arc-second is 15.4 m east-west and 30.9 m north-south
    west, north, ny, nx = 25.0, 60.0, 30, 30
    tr = from_origin(west, north, RES, RES)
    j, i = np.mgrid[0:ny, 0:nx]
    z = elev(i, j)
    z[12, 14] = -9999.0  # a void in the elevation raster
    s = depth(i, j)
    s[8, 9] = -9999.0  # a single void in a plane: filled exactly
    s[20:22, 18:20] = -9999.0  # a 2 x 2 void
    top = read_elevation(write(tmp_path / "z.tif", z, tr, nodata=-9999.0))
    lay = read_elevation(write(tmp_path / "s.tif", s, tr, nodata=-9999.0), like=top)
    assert top.nodata_filled == 1 and lay.nodata_filled == 5
    assert np.all(np.isfinite(lay.z)) and np.all(np.isfinite(top.z))
    # distances of the fill are metres on the ground, not degrees: the nearest valid cell of
    # each void is one east-west cell away
    k = EARTH_RADIUS * math.pi / 180.0 * RES
    lat_c = north - 0.5 * ny * RES
    assert top.info["fill_distance"] == pytest.approx(k * math.cos(math.radians(lat_c)),
                                                      rel=1e-3)
    assert lay.info["fill_distance"] == pytest.approx(15.45, abs=0.01)
    ci, rj = cell_coords(top, west, north)
    near = (np.abs(ci - 9) < 1.5) & (np.abs(rj - 8) < 1.5)
    assert near.any() and np.abs(lay.z - depth(ci, rj))[near].max() < 0.01
    near2 = (np.abs(ci - 18.5) < 1.0) & (np.abs(rj - 20.5) < 1.0)
    assert near2.any() and np.abs(lay.z - depth(ci, rj))[near2].max() < 0.02
    near3 = (np.abs(ci - 14) < 1.5) & (np.abs(rj - 12) < 1.5)
    assert np.abs(top.z - elev(ci, rj))[near3].max() < 0.6


def test_cell_metres_and_the_anisotropic_fill():
    from affine import Affine
    from rasterio.crs import CRS

    geo = Affine(RES, 0.0, 25.0, 0.0, -RES, 60.0 + 0.5 * 10 * RES)  # centre row at 60 N
    dx, dy = _cell_metres(geo, CRS.from_epsg(4326), (10, 10))
    assert dy == pytest.approx(30.887, abs=1e-3)
    assert dx == pytest.approx(0.5 * dy, rel=1e-9)  # cos 60 deg
    utm = Affine(10.0, 0.0, 5e5, 0.0, -10.0, 4.1e6)
    assert _cell_metres(utm, CRS.from_epsg(32633), (10, 10)) == (10.0, 10.0)
    feet = _cell_metres(utm, CRS.from_epsg(2229), (10, 10))  # California zone 5, US feet
    assert feet == pytest.approx((3.048006, 3.048006), rel=1e-6)
    # a hole between a row of 0 (west/east, 1 m away) and 10 (north/south, 2 m away): the
    # 8 nearest rim cells are the 4 neighbours and the 4 diagonals (the diagonals hold 0)
    z = np.array([[0.0, 10.0, 0.0], [0.0, 0.0, 0.0], [0.0, 10.0, 0.0]])
    w_ew, w_ns, w_d = 1.0, 1.0 / 4.0, 1.0 / 5.0
    ok = fill_nodata(z, np.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]], bool), dx=1.0, dy=2.0)
    assert ok == (1, 1.0)
    assert z[1, 1] == pytest.approx(2 * w_ns * 10 / (2 * w_ew + 2 * w_ns + 4 * w_d))


def test_utm_pair_on_the_same_grid(tmp_path):
    tr = from_origin(650000.0, 5120300.0, 10.0, 10.0)
    j, i = np.mgrid[0:30, 0:60]
    top = read_elevation(write(tmp_path / "z.tif", elev(i, j), tr, crs="EPSG:32632"))
    s = read_elevation(write(tmp_path / "s.tif", depth(i, j), tr, crs="EPSG:32632"), like=top)
    assert top.resampling == "none" and top.grid_bounds == top.extent
    assert s.transform == top.transform and s.extent == top.extent
    assert np.allclose(s.z, depth(i, j).astype("float32"), atol=1e-9)


def test_workflow_refuses_a_layer_smaller_than_the_elevation_raster(tmp_path):
    from geodem.geo import GeometryError
    from geodem.cases.landslide import read_terrains

    j, i = np.mgrid[0:24, 0:32]
    tr = from_origin(-122.3, 47.6, RES, RES)
    small = from_origin(-122.3 + 4 * RES, 47.6, RES, RES)  # 4 columns short in the west
    model = SimpleNamespace(raster=write(tmp_path / "z.tif", elev(i, j), tr), crs=None,
                            slip_depth=write(tmp_path / "d.tif", depth(i, j)[:, 4:], small),
                            slip_surface=None)
    with pytest.raises(GeometryError, match=r"the elevation raster's area \(x .* in "
                                            r"EPSG:32610\) is not covered by the raster.*this "
                                            r"raster must cover the elevation raster") as e:
        read_terrains(model)
    assert e.value.field == "slip_depth"
