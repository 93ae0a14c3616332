"""Elevation rasters: CRS rules, reprojection, nodata, resampling, clipping, origin, errors.

Synthetic GeoTIFFs are written with rasterio into tmp_path; most carry the plane
``Z = A (X - X0) + B (Y - Y0) + C`` so that every expected value is known exactly.
"""
import math

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from rasterio.warp import transform as warp_points  # noqa: E402
from rasterio.warp import transform_bounds  # noqa: E402

from geodem.geo import GeometryError, Terrain, read_elevation, utm_crs  # noqa: E402
from geodem.geo.terrain import slip_surface_from_pair  # noqa: E402

# rasterio's own transform helpers still use Affine '*' (deprecated in affine 3)
pytestmark = pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")

X0, Y0 = 500000.0, 4100000.0  # NW corner of the projected test rasters (UTM 33N)
DX = 10.0
NY, NX = 12, 16
A, B, C = 0.3, -0.2, 800.0


def plane(X, Y):
    return A * (X - X0) + B * (Y - Y0) + C


def centres(ny=NY, nx=NX, dx=DX, x0=X0, y0=Y0):
    j, i = np.mgrid[0:ny, 0:nx]
    return x0 + (i + 0.5) * dx, y0 - (j + 0.5) * dx


def write(path, data, transform=None, crs="EPSG:32633", nodata=None):
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[None]
    profile = dict(driver="GTiff", width=data.shape[2], height=data.shape[1],
                   count=data.shape[0], dtype=data.dtype, crs=crs, nodata=nodata,
                   transform=from_origin(X0, Y0, DX, DX) if transform is None else transform)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data)
    return str(path)


@pytest.fixture
def plane_tif(tmp_path):
    X, Y = centres()
    return write(tmp_path / "plane.tif", plane(X, Y))


def test_projected_raster_copied_cell_by_cell(plane_tif):
    t = read_elevation(plane_tif)
    X, Y = centres()
    assert t.resampling == "none" and t.nodata_filled == 0
    assert t.epsg == 32633 and "UTM zone 33N" in t.crs
    assert t.z.shape == (NY, NX)
    assert np.array_equal(t.z, plane(X, Y))
    # local origin at the SW corner; the transform stays global
    assert t.origin == (X0, Y0 - NY * DX, 0.0)
    assert t.extent == (0.0, 0.0, NX * DX, NY * DX)
    assert t.transform == (DX, 0.0, X0, 0.0, -DX, Y0)
    assert t.dx == DX and t.dy == DX
    assert t.x_centres[0] == 5.0 and t.y_centres[0] == NY * DX - 5.0
    md = t.metadata()
    assert md["epsg"] == 32633 and md["transform"] == [DX, 0.0, X0, 0.0, -DX, Y0]
    assert md["origin"] == [X0, Y0 - NY * DX, 0.0] and md["resampling"] == "none"


def test_bilinear_sampling_exact_on_a_plane(plane_tif):
    t = read_elevation(plane_tif)
    rng = np.random.default_rng(0)
    # anywhere between the outermost cell centres: exact
    xy = np.c_[rng.uniform(5, NX * DX - 5, 200), rng.uniform(5, NY * DX - 5, 200)]
    G = t.to_global(xy)
    assert np.allclose(t.elevation(xy), plane(G[:, 0], G[:, 1]), rtol=0, atol=1e-9)
    # beyond them the edge values continue flat: at the SW corner, the SW centre's value
    sw = plane(X0 + 5.0, Y0 - NY * DX + 5.0)
    assert t.elevation([0.0, 0.0]) == pytest.approx(sw, abs=1e-12)
    assert t.elevation([-50.0, -50.0]) == pytest.approx(sw, abs=1e-12)
    # profile along x at y = 60: z = A x + const, s = distance
    s, xy, z = t.profile((5.0, 60.0), (145.0, 60.0), n=8)
    assert s[-1] == pytest.approx(140.0) and len(s) == 8
    assert np.allclose(np.diff(z), A * 20.0, atol=1e-9)


def test_upsampling_is_bilinear_and_exact_on_a_plane(plane_tif):
    t = read_elevation(plane_tif, resolution=2.5)
    assert t.resampling == "bilinear"
    assert t.z.shape == (NY * 4, NX * 4) and t.dx == 2.5
    X, Y = np.meshgrid(t.x_centres + t.x0, t.y_centres + t.y0)
    inner = (X > X0 + 5) & (X < X0 + NX * DX - 5) & (Y < Y0 - 5) & (Y > Y0 - NY * DX + 5)
    assert inner.sum() == (NX * 4 - 4) * (NY * 4 - 4)
    assert np.max(np.abs(t.z - plane(X, Y))[inner]) < 1e-9
    assert t.edge_filled == 0


def test_downsampling_averages_blocks(tmp_path):
    z = np.random.default_rng(1).normal(500.0, 20.0, (NY, NX))
    path = write(tmp_path / "rand.tif", z)
    t = read_elevation(path, resolution=20.0)
    assert t.resampling == "average"
    blocks = z.reshape(NY // 2, 2, NX // 2, 2).mean(axis=(1, 3))
    assert np.max(np.abs(t.z - blocks)) < 1e-9
    # 4 x 4 blocks, explicit method name
    t4 = read_elevation(path, resolution=40.0, resampling="average")
    assert np.max(np.abs(t4.z - z.reshape(NY // 4, 4, NX // 4, 4).mean(axis=(1, 3)))) < 1e-9
    tn = read_elevation(path, resolution=20.0, resampling="nearest")
    assert tn.resampling == "nearest" and tn.z.shape == (NY // 2, NX // 2)
    with pytest.raises(GeometryError, match="unknown resampling 'spline'.*bilinear"):
        read_elevation(path, resolution=20.0, resampling="spline")


def test_clipping_to_a_region(plane_tif):
    reg = (X0 + 22.0, Y0 - 95.0, X0 + 71.0, Y0 - 31.0)
    t = read_elevation(plane_tif, region=reg)
    # cells whose centres span the region: columns 1..7 (centres 15..75), rows 2..9 (25..95)
    assert t.z.shape == (8, 7)
    X, Y = centres()
    assert np.array_equal(t.z, plane(X, Y)[2:10, 1:8])
    assert t.origin == (reg[0], reg[1], 0.0)
    assert t.extent == pytest.approx((0.0, 0.0, 49.0, 64.0))
    assert t.grid_bounds == pytest.approx((-12.0, -5.0, 58.0, 75.0))
    # resampled clip: the new grid starts at the region's west and north edges
    t2 = read_elevation(plane_tif, region=reg, resolution=7.0)
    assert t2.transform[2] == reg[0] and t2.transform[5] == reg[3]
    assert t2.z.shape == (math.ceil(64 / 7), 7)
    # origin choices
    tg = read_elevation(plane_tif, region=reg, origin=None)
    assert tg.origin == (0.0, 0.0, 0.0) and tg.extent == pytest.approx(reg)
    to = read_elevation(plane_tif, origin=(X0, Y0 - 200.0, 700.0))
    assert np.array_equal(to.z, plane(X, Y) - 700.0)
    assert to.to_global([[0.0, 0.0, 0.0]]).tolist() == [[X0, Y0 - 200.0, 700.0]]


def test_region_not_covered(plane_tif):
    with pytest.raises(GeometryError, match=r"requested region .* not covered by the raster, "
                                            r"which covers x 500000 \.\. 500160"):
        read_elevation(plane_tif, region=(X0 - 50.0, Y0 - 100.0, X0 + 50.0, Y0 - 10.0))


def test_missing_crs_needs_crs_argument(tmp_path):
    X, Y = centres()
    path = write(tmp_path / "nocrs.tif", plane(X, Y), crs=None)
    with pytest.raises(GeometryError, match="has no CRS.*crs='EPSG:32633'"):
        read_elevation(path)
    t = read_elevation(path, crs="EPSG:32633")
    assert t.epsg == 32633 and np.array_equal(t.z, plane(X, Y))


def test_geographic_raster_goes_to_utm(tmp_path):
    # 30 x 30 cells of 1e-4 deg latitude (and the same ground length in longitude) at 14E 46N
    lon0, lat0, n, dla = 14.0, 46.0, 30, 1e-4
    dlo = dla / math.cos(math.radians(lat0 + 0.5 * n * dla))
    j, i = np.mgrid[0:n, 0:n]
    lon = lon0 + (i + 0.5) * dlo
    lat = lat0 + n * dla - (j + 0.5) * dla
    f = lambda lo, la: 1000.0 + 2000.0 * (lo - lon0) + 3000.0 * (la - lat0)  # noqa: E731
    path = write(tmp_path / "geo.tif", f(lon, lat), from_origin(lon0, lat0 + n * dla, dlo, dla),
                 crs="EPSG:4326")
    t = read_elevation(path)
    assert t.epsg == 32633  # zone floor((14 + 180) / 6) + 1 = 33, north
    assert "WGS 84" in t.source_crs and t.resampling == "bilinear"
    assert t.dx == pytest.approx(11.13, abs=0.01)  # 1e-4 deg of latitude ~ 11.13 m
    # the default region is inside the footprint: values match the lon/lat function
    G = t.to_global(t.centres()[2:-2, 2:-2].reshape(-1, 2))
    lo, la = warp_points("EPSG:32633", "EPSG:4326", G[:, 0], G[:, 1])
    err = np.abs(t.z[2:-2, 2:-2].ravel() - f(np.array(lo), np.array(la)))
    assert err.max() < 1e-3  # 0.3 m per cell; the UTM grid is rotated ~1.4 deg to the meridians
    # a region in lon/lat, and an explicit target CRS
    tr = read_elevation(path, region=(14.001, 46.001, 14.003, 46.002), region_crs="EPSG:4326",
                        target_crs="EPSG:32633", resolution=5.0)
    b = transform_bounds("EPSG:4326", "EPSG:32633", 14.001, 46.001, 14.003, 46.002,
                         densify_pts=21)  # the bounding box of the rotated lon/lat rectangle
    assert tr.origin[:2] == pytest.approx(b[:2], abs=1e-6)
    assert tr.extent == pytest.approx((0, 0, b[2] - b[0], b[3] - b[1]), abs=1e-6)
    assert 154.0 < tr.extent[2] < 158.0 and 111.0 < tr.extent[3] < 115.0  # 0.002 x 0.001 deg
    with pytest.raises(GeometryError, match="not a projected CRS in metres"):
        read_elevation(path, target_crs="EPSG:4326")


def test_utm_zone_choice():
    assert utm_crs(14.0, 46.0).to_epsg() == 32633
    assert utm_crs(-70.6, -33.4).to_epsg() == 32719  # Santiago: floor(109.4 / 6) + 1 = 19, S
    assert utm_crs(179.99, 10.0).to_epsg() == 32660
    assert utm_crs(-180.0, 10.0).to_epsg() == 32601


def test_nodata_holes_filled_by_inverse_distance(tmp_path):
    X, Y = centres()
    z = plane(X, Y)
    z[5, 7] = -9999.0  # one hole in a plane: its 8 neighbours pair up, the fill is exact
    z[2, 2:4] = -9999.0  # a two-cell hole: filled between the neighbours' extremes
    path = write(tmp_path / "holes.tif", z, nodata=-9999.0)
    t = read_elevation(path)
    exact = plane(X, Y)
    assert t.nodata_filled == 3
    assert t.z[5, 7] == pytest.approx(exact[5, 7], abs=1e-9)
    for c in (2, 3):
        nb = exact[1:4, c - 1:c + 2]
        assert nb.min() <= t.z[2, c] <= nb.max()
    assert abs(t.z[2, 2] - exact[2, 2]) < 0.5 and abs(t.z[2, 3] - exact[2, 3]) < 0.5
    # NaN cells count as nodata too; nodata= overrides the file's value
    z2 = plane(X, Y)
    z2[0, 0] = np.nan
    z2[4, 4] = 123.0
    t2 = read_elevation(write(tmp_path / "nan.tif", z2), nodata=123.0)
    assert t2.nodata_filled == 2 and np.all(np.isfinite(t2.z))
    assert t2.z[4, 4] == pytest.approx(exact[4, 4], abs=1e-9)


def test_all_nodata_and_mostly_nodata_are_refused(tmp_path):
    path = write(tmp_path / "empty.tif", np.full((NY, NX), -9999.0), nodata=-9999.0)
    with pytest.raises(GeometryError, match=r"all 192 cells read .* are nodata \(nodata value "
                                            r"-9999.0\)"):
        read_elevation(path)
    z = np.full((NY, NX), -9999.0)
    z[:3] = 100.0
    path = write(tmp_path / "mostly.tif", z, nodata=-9999.0)
    with pytest.raises(GeometryError, match=r"144 of 192 cells read \(75.0 %\) are nodata"):
        read_elevation(path)
    assert read_elevation(path, max_nodata_fraction=0.8).nodata_filled == 144


def test_wrong_dimensionality_is_refused(tmp_path):
    X, Y = centres()
    rgb = np.stack([plane(X, Y)] * 3)
    path = write(tmp_path / "rgb.tif", rgb)
    with pytest.raises(GeometryError, match="has 3 bands.*needs one band: pass band=k"):
        read_elevation(path)
    assert np.array_equal(read_elevation(path, band=2).z, plane(X, Y))
    with pytest.raises(GeometryError, match="band=4 does not exist"):
        read_elevation(path, band=4)
    thin = write(tmp_path / "thin.tif", np.ones((NY, 1)))
    with pytest.raises(GeometryError,
                       match=r"is 1 x 12 cells \(columns x rows\); .* at least 2 x 2"):
        read_elevation(thin)
    with pytest.raises(GeometryError, match="no such file"):
        read_elevation(tmp_path / "missing.tif")
    (tmp_path / "junk.tif").write_text("not a raster")
    with pytest.raises(GeometryError, match="cannot be read as a raster"):
        read_elevation(tmp_path / "junk.tif")


def test_like_grid_and_slip_surface_from_pair(tmp_path, plane_tif):
    pre = read_elevation(plane_tif, resolution=5.0)
    X, Y = centres()
    post = plane(X, Y)
    post[4:8, 4:10] -= 6.0  # depletion zone, 6 m deep
    post[9:11, 2:5] += 3.0  # deposit
    post_t = read_elevation(write(tmp_path / "post.tif", post), like=pre)
    assert post_t.z.shape == pre.z.shape and post_t.transform == pre.transform
    assert post_t.origin == pre.origin
    slip = slip_surface_from_pair(pre, post_t, min_depth=1.0)
    drop = pre.z - post_t.z
    assert np.array_equal(slip.z, np.where(drop >= 1.0, post_t.z, pre.z))
    assert slip.info["depleted_cells"] == int((drop >= 1.0).sum()) > 0
    with pytest.raises(GeometryError, match="share their grid"):
        slip_surface_from_pair(pre, read_elevation(plane_tif), 1.0)


def test_save_roundtrip_and_from_function(tmp_path):
    t = Terrain.from_function(lambda x, y: 3.0 * x - y, (0, 0, 40, 30), dx=10.0,
                              crs="EPSG:32633")
    assert t.z.shape == (3, 4) and t.z[0, 0] == 3 * 5 - 25
    t.save(tmp_path / "t.tif")
    back = read_elevation(tmp_path / "t.tif", origin=None)
    assert np.array_equal(back.z, t.z) and back.transform == t.transform and back.epsg == 32633


@pytest.mark.parametrize("name, tr, flip", [
    # south-up (e > 0): row 0 is the south edge
    ("south_up", (DX, 0.0, X0, 0.0, DX, Y0 - NY * DX), lambda z: z[::-1]),
    # east-to-west (a < 0): column 0 is the east edge
    ("east_to_west", (-DX, 0.0, X0 + NX * DX, 0.0, -DX, Y0), lambda z: z[:, ::-1]),
    # turned by 180 degrees
    ("rot180", (-DX, 0.0, X0 + NX * DX, 0.0, DX, Y0 - NY * DX), lambda z: z[::-1, ::-1]),
    # turned by 90 degrees: X = dx row + west, Y = north - dx col (the array is transposed)
    ("rot90", (0.0, DX, X0, -DX, 0.0, Y0), lambda z: z.T),
])
def test_default_region_of_rasters_not_stored_north_up(tmp_path, name, tr, flip):
    X, Y = centres()
    z = plane(X, Y)
    path = write(tmp_path / f"{name}.tif", flip(z), transform=rasterio.Affine(*tr))
    t = read_elevation(path)
    # the whole raster, on the north-up grid, the plane reproduced at every cell
    assert t.z.shape == (NY, NX) and t.dx == DX and t.dy == DX
    assert t.transform == pytest.approx((DX, 0.0, X0, 0.0, -DX, Y0), abs=1e-6)
    assert t.extent == pytest.approx((0.0, 0.0, NX * DX, NY * DX), abs=1e-6)
    assert t.edge_filled == 0 and t.nodata_filled == 0
    # the cells are copied, not resampled: the plane reproduced exactly
    assert t.resampling == "none" and np.array_equal(t.z, z)
    # an explicit region clips the same cells as in the north-up raster
    reg = (X0 + 22.0, Y0 - 95.0, X0 + 71.0, Y0 - 31.0)
    assert np.array_equal(read_elevation(path, region=reg).z, z[2:10, 1:8])


def test_default_region_of_a_south_up_geographic_raster(tmp_path):
    lon0, lat0, n, dla = 14.0, 46.0, 30, 1e-4
    dlo = dla / math.cos(math.radians(lat0 + 0.5 * n * dla))
    j, i = np.mgrid[0:n, 0:n]
    z = 1000.0 + 20.0 * i - 30.0 * j
    north = read_elevation(write(tmp_path / "n.tif", z, from_origin(lon0, lat0 + n * dla, dlo,
                                                                    dla), crs="EPSG:4326"))
    south = read_elevation(write(tmp_path / "s.tif", z[::-1],
                                 rasterio.Affine(dlo, 0.0, lon0, 0.0, dla, lat0),
                                 crs="EPSG:4326"))
    assert south.epsg == north.epsg == 32633
    assert south.z.shape == north.z.shape and south.extent == pytest.approx(north.extent)
    assert np.max(np.abs(south.z - north.z)) < 1e-6


def test_nodata_override_compared_in_the_rasters_dtype(tmp_path):
    X, Y = centres()
    z = plane(X, Y).astype(np.float32)
    z[3, 4] = -9999.9  # float32(-9999.9) != -9999.9 in float64
    z[6, 6] = -32768.0  # the file's own nodata value
    path = write(tmp_path / "f32.tif", z, nodata=-32768.0)
    t = read_elevation(path, nodata=-9999.9)
    exact = plane(X, Y)
    # both the override and the file's own nodata cells are filled (single holes in a plane)
    assert t.nodata_filled == 2
    assert t.z[3, 4] == pytest.approx(exact[3, 4], abs=1e-3)
    assert t.z[6, 6] == pytest.approx(exact[6, 6], abs=1e-3)
    # an integer raster: a value it cannot hold matches no cell, an integral one matches
    zi = np.round(plane(X, Y)).astype(np.int16)
    zi[2, 2] = -500
    pi = write(tmp_path / "i16.tif", zi)
    assert read_elevation(pi, nodata=-500.5).nodata_filled == 0
    assert read_elevation(pi, nodata=-500).nodata_filled == 1
    with pytest.raises(GeometryError, match="nodata must be a number, got 'x'"):
        read_elevation(pi, nodata="x")
