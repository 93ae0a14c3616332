"""Unit tests of geodem.build.lattice (lattices, contact pairs, specimens, bonded state)."""
import math
import sys
import types

import numpy as np
import pytest
from scipy.spatial import cKDTree

from geodem.build.lattice import (
    bonded_state,
    chain,
    contact_pairs,
    fcc_lattice,
    lattice_shape,
    random_specimen,
    triangular_lattice,
)


def _brute_pairs(x, r, gap):
    n = len(x)
    i, j = np.triu_indices(n, k=1)
    dist = np.linalg.norm(x[j] - x[i], axis=1)
    keep = dist - r[i] - r[j] <= gap
    return i[keep], j[keep]


def _degree(i, j, n):
    return np.bincount(i, minlength=n) + np.bincount(j, minlength=n)


# ------------------------------------------------------------------------ FCC
def test_fcc_shape_origin_and_layers():
    d = 0.7
    nx, ny, nz = 5, 4, 7
    x = fcc_lattice(nx, ny, nz, d)
    assert x.shape == (nx * ny * nz, 3)
    assert x.dtype == np.float64
    assert np.all(x >= 0.0)
    assert np.allclose(x.min(axis=0), 0.0, atol=0.0)
    z = np.unique(np.round(x[:, 2], 12))
    assert len(z) == nz
    np.testing.assert_allclose(np.diff(z), d * math.sqrt(2.0 / 3.0), rtol=0, atol=1e-12)
    # rows of a layer at d*sqrt(3)/2, nx elements per row at spacing d
    lay0 = x[: nx * ny]
    y = np.unique(np.round(lay0[:, 1], 12))
    np.testing.assert_allclose(np.diff(y), d * math.sqrt(3.0) / 2.0, atol=1e-12)
    row0 = lay0[:nx]
    np.testing.assert_allclose(np.diff(row0[:, 0]), d, atol=1e-12)
    # ABC: layers 0, 1, 2 distinct in-plane, layer 3 repeats layer 0
    m = nx * ny
    xy = [x[k * m:(k + 1) * m, :2] for k in range(4)]
    np.testing.assert_allclose(xy[3], xy[0], atol=1e-12)
    assert not np.allclose(xy[1], xy[0])
    assert not np.allclose(xy[2], xy[0])
    assert not np.allclose(xy[2], xy[1])


def test_fcc_interior_coordination_and_distances():
    d = 1.3
    nx, ny, nz = 6, 6, 6
    x = fcc_lattice(nx, ny, nz, d)
    tree = cKDTree(x)
    # nearest distance of every element is exactly d; nothing closer
    dist, _ = tree.query(x, k=2)
    np.testing.assert_allclose(dist[:, 1], d, rtol=0, atol=1e-12)
    # pairs within 1.01 d all at d (to 1e-12)
    p = tree.query_pairs(1.01 * d, output_type="ndarray")
    pd = np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1)
    np.testing.assert_allclose(pd, d, rtol=0, atol=1e-12)
    deg = _degree(p[:, 0], p[:, 1], len(x))
    k, j, i = np.unravel_index(np.arange(len(x)), (nz, ny, nx))
    interior = (i > 0) & (i < nx - 1) & (j > 0) & (j < ny - 1) & (k > 0) & (k < nz - 1)
    assert interior.sum() > 0
    assert np.all(deg[interior] == 12)
    assert deg.max() == 12
    # FCC (not HCP): neighbour vectors of an interior element are centrosymmetric
    for e in np.flatnonzero(interior)[:5]:
        nb = tree.query_ball_point(x[e], 1.01 * d)
        v = x[[q for q in nb if q != e]] - x[e]
        assert len(v) == 12
        # for each v there is a -v
        dd = np.linalg.norm(v[:, None, :] + v[None, :, :], axis=2)
        assert np.all(dd.min(axis=1) < 1e-12)


def test_fcc_contact_pairs_at_zero_gap():
    d = 2e-3
    x = fcc_lattice(5, 5, 5, d)
    i, j = contact_pairs(x, d / 2, gap=0.0)
    p = cKDTree(x).query_pairs(1.001 * d, output_type="ndarray")
    assert len(i) == len(p)


def test_lattice_bad_counts():
    with pytest.raises(ValueError, match="nx"):
        fcc_lattice(0, 2, 2, 1.0)
    with pytest.raises(ValueError, match="d"):
        fcc_lattice(2, 2, 2, -1.0)
    with pytest.raises(ValueError, match="ny"):
        triangular_lattice(2, 1.5, 1.0)


# ------------------------------------------------------------------------ triangular
def test_triangular_coordination():
    d = 0.4
    nx, ny = 9, 8
    x = triangular_lattice(nx, ny, d)
    assert x.shape == (nx * ny, 2)
    assert np.all(x >= 0.0)
    y = np.unique(np.round(x[:, 1], 12))
    np.testing.assert_allclose(np.diff(y), d * math.sqrt(3) / 2, atol=1e-12)
    np.testing.assert_allclose(x[nx, 0] - x[0, 0], d / 2, atol=1e-12)  # odd row offset
    tree = cKDTree(x)
    dist, _ = tree.query(x, k=2)
    np.testing.assert_allclose(dist[:, 1], d, atol=1e-12)
    p = tree.query_pairs(1.01 * d, output_type="ndarray")
    pd = np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1)
    np.testing.assert_allclose(pd, d, atol=1e-12)
    deg = _degree(p[:, 0], p[:, 1], len(x))
    j, i = np.unravel_index(np.arange(len(x)), (ny, nx))
    interior = (i > 0) & (i < nx - 1) & (j > 0) & (j < ny - 1)
    assert np.all(deg[interior] == 6)
    assert deg.max() == 6


# ------------------------------------------------------------------------ chain
@pytest.mark.parametrize("dim", [1, 2, 3])
def test_chain(dim):
    x = chain(7, 0.25, dim=dim)
    assert x.shape == (7, dim)
    np.testing.assert_allclose(np.diff(x[:, 0]), 0.25)
    assert x[0, 0] == 0.0
    assert np.all(x[:, 1:] == 0.0)


def test_chain_bad_dim():
    with pytest.raises(ValueError, match="dim"):
        chain(3, 1.0, dim=4)


# ------------------------------------------------------------------------ contact_pairs
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("gap", [0.0, 0.03, 0.2])
def test_contact_pairs_vs_brute_force(dim, gap):
    rng = np.random.default_rng(42 + dim)
    n = 300
    x = rng.uniform(0, 3.0, size=(n, dim))
    r = rng.uniform(0.05, 0.25, size=n)
    i, j = contact_pairs(x, r, gap)
    bi, bj = _brute_pairs(x, r, gap)
    assert len(bi) > 0
    np.testing.assert_array_equal(i, bi)  # brute force is in (i, j) order too
    np.testing.assert_array_equal(j, bj)
    assert np.all(i < j)
    assert np.issubdtype(i.dtype, np.integer)


def test_contact_pairs_scalar_radius_and_edge_cases():
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 2.0, size=(100, 3))
    i, j = contact_pairs(x, 0.15)
    bi, bj = _brute_pairs(x, np.full(100, 0.15), 0.0)
    np.testing.assert_array_equal(i, bi)
    np.testing.assert_array_equal(j, bj)
    i, j = contact_pairs(x[:1], 0.1)
    assert len(i) == 0 and len(j) == 0
    i, j = contact_pairs(np.array([[0.0, 0.0], [5.0, 0.0]]), 1.0)
    assert len(i) == 0
    with pytest.raises(ValueError, match="r must"):
        contact_pairs(x, np.ones(3))


# ------------------------------------------------------------------------ specimen
def test_lattice_shape_close_to_n():
    for n in (1, 5, 37, 500, 2000, 12345, 10**6):
        for dim in (2, 3):
            s = lattice_shape(n, dim)
            assert len(s) == dim
            assert abs(np.prod(s) - n) <= 0.05 * n


def test_random_specimen_3d():
    n = 2000
    d = 0.01
    x, r = random_specimen(n, dim=3, seed=3, d=d)
    assert x.shape[1] == 3 and r.shape == (x.shape[0],)
    assert abs(len(x) - n) <= 0.05 * n
    assert r.max() / r.min() <= 1.2 + 1e-12
    i, j = contact_pairs(x, r, gap=0.05 * d)
    mean = 2 * len(i) / len(x)
    assert 10.0 <= mean <= 13.0
    # exactly the lattice-neighbour pairs: every one found, no other
    lat = fcc_lattice(*lattice_shape(n, 3), d)
    li, lj = contact_pairs(lat, d / 2, gap=0.0)
    np.testing.assert_array_equal(i, li)
    np.testing.assert_array_equal(j, lj)
    # jitter bound
    assert np.abs(x - lat).max() <= 0.02 * d


def test_random_specimen_2d():
    n = 2000
    x, r = random_specimen(n, dim=2, seed=5)
    assert x.shape[1] == 2
    assert abs(len(x) - n) <= 0.05 * n
    i, j = contact_pairs(x, r, gap=0.05)
    mean = 2 * len(i) / len(x)
    assert 5.0 <= mean <= 6.0
    lat = triangular_lattice(*lattice_shape(n, 2), 1.0)
    li, lj = contact_pairs(lat, 0.5, gap=0.0)
    np.testing.assert_array_equal(i, li)
    np.testing.assert_array_equal(j, lj)


def test_random_specimen_deterministic():
    a = random_specimen(500, seed=7)
    b = random_specimen(500, seed=7)
    c = random_specimen(500, seed=8)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    assert not np.array_equal(a[1], c[1])


def test_random_specimen_bad_args():
    with pytest.raises(ValueError, match="dim"):
        random_specimen(100, dim=1)
    with pytest.raises(ValueError, match="size_ratio"):
        random_specimen(100, size_ratio=0.9)
    with pytest.raises(ValueError, match="n"):
        random_specimen(0)


# ------------------------------------------------------------------------ bonded_state
PARAMS = dict(density=2600.0, kn=1e7, ks=5e6, xb=1e-5, fs0=10.0, mu=0.5)


@pytest.fixture
def stub_rows(monkeypatch):
    """Replace geodem.core.neighbors by a stub recording the pairs it is given."""
    calls = []
    mod = types.ModuleType("geodem.core.neighbors")

    def rows_from_pairs(state, i, j, bonded=True, brate=None):
        calls.append((np.asarray(i).copy(), np.asarray(j).copy(), bonded))

    mod.rows_from_pairs = rows_from_pairs
    monkeypatch.setitem(sys.modules, "geodem.core.neighbors", mod)
    return calls


def test_bonded_state_masses_3d(stub_rows):
    x, r = random_specimen(300, dim=3, seed=1, d=0.01)
    st = bonded_state(x, r, gap=5e-4, **PARAMS)
    np.testing.assert_allclose(st.m, 2600.0 * 4.0 / 3.0 * np.pi * r ** 3, rtol=1e-14)
    assert st.dim == 3 and st.width == 16
    assert np.all(st.kn == 1e7) and np.all(st.mu == 0.5) and np.all(st.eta == 0.0)
    assert st.skin == pytest.approx(max(5e-4, 0.1 * r.min()))
    (i, j, bonded), = stub_rows
    assert bonded is True
    ci, cj = contact_pairs(x, r, 5e-4)
    np.testing.assert_array_equal(i, ci)
    np.testing.assert_array_equal(j, cj)


def test_bonded_state_masses_2d(stub_rows):
    x, r = random_specimen(200, dim=2, seed=1)
    st = bonded_state(x, r, gap=0.05, **PARAMS)
    np.testing.assert_allclose(st.m, 2600.0 * np.pi * r ** 2 * 2 * r, rtol=1e-14)
    assert st.width == 8 and st.thickness == 0.0
    rho = np.full(len(r), 1000.0)
    kn = np.linspace(1.0, 2.0, len(r))
    st = bonded_state(x, r, gap=0.0, thickness=0.1, width=4,
                      **{**PARAMS, "density": rho, "kn": kn})
    np.testing.assert_allclose(st.m, 1000.0 * np.pi * r ** 2 * 0.1, rtol=1e-14)
    np.testing.assert_array_equal(st.kn, kn)
    assert st.thickness == 0.1 and st.width == 4
    assert st.skin == pytest.approx(0.1 * r.min())


@pytest.mark.parametrize("name,value,match", [
    ("density", 0.0, "density"),
    ("density", -1.0, "density"),
    ("kn", -1.0, "kn"),
    ("ks", np.nan, "ks"),
    ("xb", np.inf, "xb"),
    ("fs0", np.ones(3), "fs0"),
    ("mu", -0.1, "mu"),
    ("eta", -1.0, "eta"),
    ("gap", -1e-3, "gap"),
    ("gap", np.nan, "gap"),
    ("width", 0, "width"),
    ("thickness", 0.1, "thickness"),  # 3-D
])
def test_bonded_state_errors(stub_rows, name, value, match):
    x, r = random_specimen(50, dim=3, seed=0)
    kw = dict(PARAMS, gap=0.05)
    kw[name] = value
    with pytest.raises(ValueError, match=match):
        bonded_state(x, r, **kw)


def test_bonded_state_bad_geometry(stub_rows):
    x, r = random_specimen(50, dim=3, seed=0)
    with pytest.raises(ValueError, match="r must"):
        bonded_state(x, r[:-1], gap=0.05, **PARAMS)
    with pytest.raises(ValueError, match="r must"):
        bonded_state(x, -r, gap=0.05, **PARAMS)
    with pytest.raises(ValueError, match="x"):
        bonded_state(x[:, :1], r, gap=0.05, **PARAMS)
    x2, r2 = random_specimen(50, dim=2, seed=0)
    with pytest.raises(ValueError, match="thickness"):
        bonded_state(x2, r2, gap=0.05, thickness=-1.0, **PARAMS)


def _real_rows_from_pairs():
    mod = pytest.importorskip("geodem.core.neighbors")
    if not hasattr(mod, "rows_from_pairs"):
        pytest.skip("geodem.core.neighbors.rows_from_pairs not available")
    return mod


@pytest.mark.parametrize("dim", [2, 3])
def test_bonded_state_rows(dim):
    _real_rows_from_pairs()
    x, r = random_specimen(400, dim=dim, seed=2)
    st = bonded_state(x, r, gap=0.05, **PARAMS)
    i, j = contact_pairs(x, r, 0.05)
    deg = _degree(i, j, len(x))
    valid = st.nbr >= 0
    np.testing.assert_array_equal(valid.sum(axis=1), deg)
    assert np.all(st.cstate[valid] == 1)
    rows = {(a, b) for a in range(st.n) for b in st.nbr[a][valid[a]]}
    for a, b in zip(i.tolist(), j.tolist()):
        assert (a, b) in rows and (b, a) in rows
