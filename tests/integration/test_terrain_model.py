"""A small terrain model from a GeoTIFF: the top follows the raster, the base is fixed, the slide
group is the set of elements above the sliding surface; 2-D sections; a short run under gravity."""
import math

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from geodem.core.state import BONDED  # noqa: E402
from geodem.geo import Depth, GeometryError, read_elevation, terrain_model  # noqa: E402
from geodem.geo.terrain import slip_surface_from_pair  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")

X0, Y0, DX = 600000.0, 5200000.0, 4.0  # NW corner (UTM 32N), cell size [m]
NX, NY = 20, 15  # 80 m x 60 m
D = 2.5  # element diameter [m]
ROCK = dict(kn=2e9, ks=8e8, xb=2e-3, fs0=4e6, mu=0.6, rho=2600.0)


def hill(x, y):
    """Local elevation [m]: a Gaussian hill on a gentle east-rising slope."""
    return 30.0 + 0.1 * x + 12.0 * np.exp(-((x - 40.0) ** 2 + (y - 30.0) ** 2) / 400.0)


def write(path, z):
    with rasterio.open(path, "w", driver="GTiff", width=NX, height=NY, count=1,
                       dtype="float64", crs="EPSG:32632",
                       transform=from_origin(X0, Y0, DX, DX)) as dst:
        dst.write(z, 1)
    return str(path)


@pytest.fixture(scope="module")
def rasters(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("terrain")
    j, i = np.mgrid[0:NY, 0:NX]
    x = (i + 0.5) * DX  # local: origin at the SW corner
    y = NY * DX - (j + 0.5) * DX
    pre = hill(x, y)
    post = pre.copy()
    scar = (x > 25) & (x < 55) & (y > 20) & (y < 40)
    post[scar] -= 6.0 * np.exp(-((x[scar] - 40.0) ** 2 + (y[scar] - 30.0) ** 2) / 150.0)
    return write(tmp / "pre.tif", pre), write(tmp / "post.tif", post)


@pytest.fixture(scope="module")
def model3d(rasters):
    top = read_elevation(rasters[0])
    post = read_elevation(rasters[1], like=top)
    slip = slip_surface_from_pair(top, post, min_depth=0.5)
    m = terrain_model(top, D, base_depth=4 * D, layers=[("soil", Depth(3.0))],
                      sliding_surface=slip)
    return top, slip, m


def test_top_follows_the_raster(model3d):
    top, _, m = model3d
    xy, z = m.x[:, :2], m.x[:, 2]
    assert m.info["packing"] == "lattice" and m.n == m.info["n_elements"]
    # every centre at or below the terrain (centre-inside rule), every element inside the extent
    assert np.all(z <= top.elevation(xy) + 1e-9)
    assert np.all(xy - m.r[:, None] >= -1e-9) and np.all(xy[:, 0] + m.r <= 80 + 1e-9)
    # and the highest centre within one diameter (horizontally) of any surface point lies less
    # than one diameter below the terrain there (measured: at most 2.02 m = 0.81 d, median
    # 0.61 m; a neighbour up-slope may stand higher than the point: deficit < 0)
    g = np.linspace(D, 80 - D, 40), np.linspace(D, 60 - D, 30)
    P = np.stack(np.meshgrid(*g), axis=-1).reshape(-1, 2)
    near = cKDTree(xy).query_ball_point(P, D)
    highest = np.array([z[k].max() for k in near])
    deficit = top.elevation(P) - highest
    assert deficit.max() < D
    assert np.median(deficit) < 0.5 * D
    # element count = volume under the terrain / FCC volume per element (d^3 / sqrt(2)),
    # within the half-element shells lost at the faces
    cells = top.centres().reshape(-1, 2)
    vol = float(((top.elevation(cells) - m.base_z).sum()) * DX * DX)
    assert m.n == pytest.approx(vol / (D ** 3 / math.sqrt(2)), rel=0.15)
    assert m.base_z == pytest.approx(m.info["top_min"] - 4 * D)
    assert m.metadata["epsg"] == 32632 and m.metadata["origin"][0] == X0


def test_groups_base_layers_slide(model3d):
    top, slip, m = model3d
    z = m.x[:, 2]
    h = D * math.sqrt(2 / 3)
    # base: the two lowest lattice layers
    assert np.array_equal(m.masks["base"], z < m.base_z + 2 * D)
    assert np.allclose(np.unique(z[m.masks["base"]].round(9)),
                       [m.base_z + D / 2, m.base_z + D / 2 + h])
    # slide: exactly the centres above the sliding surface (post-event ground in the scar)
    above = z > slip.elevation(m.x[:, :2])
    assert np.array_equal(m.masks["slide"], above)
    assert 50 < above.sum() < m.n // 4
    # soil: within 3 m of the terrain
    assert m.names == ["soil", "rock"]
    assert np.array_equal(m.layer == 0, z >= top.elevation(m.x[:, :2]) - 3.0)
    # to State: one group per element by precedence, base fixed, rollers on the sides
    st = m.to_state(ROCK, slide_bond_rate=0.0, sort=False)
    base, sx, sy = (st.group_mask(g) for g in ("base", "side_x", "side_y"))
    assert np.array_equal(base, m.masks["base"])
    assert np.array_equal(st.group_mask("slide"), above & ~m.masks["base"] & ~m.masks["side_x"]
                          & ~m.masks["side_y"])
    assert np.all(st.free[base] == 0.0)
    assert np.all(st.free[sx, 0] == 0.0) and np.all(st.free[sx, 1:] == 1.0)
    assert np.all(st.free[sy, 1] == 0.0) and np.all(st.free[sy, 2] == 1.0)
    rest = ~(base | sx | sy)
    assert np.all(st.free[rest] == 1.0)
    assert st.gravity.tolist() == [0.0, 0.0, -9.81]
    # lattice bonds: 12 per interior element; none across the sliding surface (rate 0)
    nb = st.nbr
    bonded = (st.cstate == BONDED) & (nb >= 0)
    assert bonded.sum(axis=1).max() == 12
    sl = m.masks["slide"]
    cross = (nb >= 0) & (sl[:, None] != sl[np.maximum(nb, 0)])
    assert cross.any() and not np.any(bonded & cross)


def test_short_run_under_gravity(model3d):
    from geodem.core.engine import Simulation

    _, _, m = model3d
    st = m.to_state(ROCK, slide_bond_rate=0.5)
    base = st.group_mask("base")
    x0 = st.x.copy()
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.run(200)
    e = sim.energies()
    assert e["closure_error"] < 1e-3
    assert np.array_equal(st.x[base], x0[base])
    sag = x0[:, 2] - st.x[:, 2]
    assert sag.max() > 0 and sag.max() < 0.01 * D  # elastic settling only
    assert len(sim.crack_log()) == 0


def test_section_along_a_line(rasters):
    top = read_elevation(rasters[0])
    line = ((5.0, 30.0), (75.0, 30.0))
    m = terrain_model(top, 1.0, base_z=20.0, dim=2, line=line,
                      sliding_surface=Depth(2.0))
    s, y = m.x[:, 0], m.x[:, 1]
    xy = np.c_[5.0 + s, np.full_like(s, 30.0)]
    assert m.dim == 2 and m.extent == (0.0, 70.0) and m.line == line
    assert np.all(y <= top.elevation(xy) + 1e-9)
    assert np.all(s >= 0.5 - 1e-9) and np.all(s <= 69.5 + 1e-9)
    assert np.array_equal(m.masks["slide"], y > top.elevation(xy) - 2.0)
    rows = np.unique(((y - 20.5) / (math.sqrt(3) / 2)).round(9))
    assert np.allclose(rows, np.round(rows))  # triangular rows from the base up
    st = m.to_state({"rock": ROCK})
    assert st.dim == 2 and st.gravity.tolist() == [0.0, -9.81]
    assert "side_y" not in st.groups
    # the line must lie in the extent; base_z must be below the ground
    with pytest.raises(GeometryError, match="outside the extent"):
        terrain_model(top, 1.0, dim=2, line=((5.0, 30.0), (95.0, 30.0)))
    with pytest.raises(GeometryError, match="below the lowest point"):
        terrain_model(top, 1.0, base_z=35.0, dim=2, line=line)


def test_size_guard_and_given_packing(rasters):
    top = read_elevation(rasters[0])
    with pytest.raises(GeometryError, match=r"would hold \d+ elements \(> max_elements = 1000\)"):
        terrain_model(top, 1.0, max_elements=1000)
    # cutting a given (random) packing by the same rules
    rng = np.random.default_rng(0)
    x = np.c_[rng.uniform(0, 80, 3000), rng.uniform(0, 60, 3000), rng.uniform(0, 45, 3000)]
    r = np.full(3000, 0.5)
    m = terrain_model(top, 1.0, base_z=5.0, packing=(x, r))
    keep = (x[:, 2] <= top.elevation(x[:, :2])) & (x[:, 2] - 0.5 >= 5.0)
    assert m.info["packing"] == "given" and m.n == int(keep.sum())
    with pytest.raises(GeometryError, match="materials lacks"):
        terrain_model(top, 4.0, layers=[("soil", Depth(2.0))]).to_state({"rock": ROCK})
