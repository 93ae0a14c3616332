import numpy as np
import pytest

from geodem.build import packing
from geodem.build.lattice import bonded_state, fcc_lattice
from geodem.build.shapes import Box, Cylinder, Disc, cut, subset_state
from geodem.core.state import BONDED


@pytest.mark.parametrize("rate", [0.0, 0.2, 0.5])
def test_radii_bounds_and_mean(rate):
    d = 0.01
    r = packing.radii(20000, d, rate, np.random.default_rng(0))
    dmin, dmax = packing.diameter_bounds(d, rate)
    assert dmax / dmin == pytest.approx((1 + rate) ** 2, rel=1e-12)
    assert 0.5 * (dmin + dmax) == pytest.approx(d, rel=1e-12)
    assert np.all(2 * r >= dmin - 1e-15) and np.all(2 * r <= dmax + 1e-15)
    assert (2 * r).mean() == pytest.approx(d, rel=5e-3)
    if rate > 0:  # the extremes are reached
        assert (2 * r).max() / (2 * r).min() == pytest.approx((1 + rate) ** 2, rel=2e-3)


def test_radii_reject_bad_input():
    with pytest.raises(ValueError):
        packing.radii(10, -1.0, 0.2)
    with pytest.raises(ValueError):
        packing.radii(10, 1.0, -0.1)


@pytest.mark.parametrize("dim", [2, 3])
def test_random_placement_no_overlap_deterministic(dim):
    lo, hi = np.zeros(dim), np.full(dim, 0.1)
    x, r = packing.random_placement((lo, hi), n=300, d_mean=0.01, distri_rate=0.2, seed=3)
    x2, r2 = packing.random_placement((lo, hi), n=300, d_mean=0.01, distri_rate=0.2, seed=3)
    assert np.array_equal(x, x2) and np.array_equal(r, r2)
    assert x.shape == (300, dim)
    from scipy.spatial import cKDTree

    p = cKDTree(x).query_pairs(2 * r.max(), output_type="ndarray")
    gap = np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1) - r[p[:, 0]] - r[p[:, 1]]
    assert gap.min() > 0
    assert np.all(x[:, :-1] - r[:, None] >= lo[:-1]) and np.all(x[:, :-1] + r[:, None] <= hi[:-1])
    assert np.all(x[:, -1] - r >= lo[-1])


def test_random_placement_porosity_count():
    lo, hi = np.zeros(2), np.array([0.2, 0.2])
    x, r = packing.random_placement((lo, hi), porosity=0.5, d_mean=0.01, distri_rate=0.0, seed=0)
    assert (np.pi * r ** 2).sum() == pytest.approx(0.5 * 0.04, rel=0.01)


def test_shape_masks():
    x3 = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [0.95, 0.5, 0.2], [0.5, 0.5, 1.2]])
    assert Box((0, 0, 0), (1, 1, 1)).mask(x3).tolist() == [True, False, True, False]
    cyl = Cylinder((0.5, 0.5), 0.5, 0.0, 1.0)
    assert cyl.mask(x3).tolist() == [True, False, True, False]
    assert cyl.volume == pytest.approx(np.pi * 0.25)
    x2 = np.array([[0.5, 0.5], [0.9, 0.9], [0.0, 0.5]])
    disc = Disc((0.5, 0.5), 0.5)
    assert disc.mask(x2).tolist() == [True, False, True]
    assert cut(x2, disc).tolist() == [True, False, True]
    d3 = Disc((0.5, 0.1, 0.5), 0.5, "y", 0.2)
    x = np.array([[0.5, 0.15, 0.9], [0.5, 0.25, 0.5], [0.9, 0.1, 0.9]])
    assert d3.mask(x).tolist() == [True, False, False]
    with pytest.raises(ValueError):
        Cylinder((0, 0), 1, 0, 1).mask(x2)


def test_subset_state_copies_and_relabels():
    d = 0.01
    x = fcc_lattice(4, 4, 4, d)
    st = bonded_state(x, np.full(len(x), d / 2), density=2650.0, kn=1e7, ks=4e6, xb=1e-5,
                      fs0=10.0, mu=0.4, gap=1e-6 * d)
    st.kn[:] = np.arange(st.n) + 1.0
    st.v[:] = np.arange(st.n)[:, None]
    keep = st.x[:, 0] <= 0.5 * st.x[:, 0].max()
    sub = cut(st, Box((-1, -1, -1), (0.5 * st.x[:, 0].max(), 1, 1)))
    idx = np.flatnonzero(keep)
    assert sub.n == idx.size
    assert np.array_equal(sub.x, st.x[idx]) and np.array_equal(sub.kn, st.kn[idx])
    assert np.array_equal(sub.v, st.v[idx]) and np.array_equal(sub.m, st.m[idx])
    # bonds between kept elements survive, relabelled; nothing points outside
    inv = -np.ones(st.n, int)
    inv[idx] = np.arange(idx.size)
    want = set()
    for i in idx:
        for k in range(st.width):
            j = st.nbr[i, k]
            if j >= 0 and keep[j] and st.cstate[i, k] == BONDED:
                want.add((inv[i], inv[j]))
    got = {(i, int(sub.nbr[i, k])) for i in range(sub.n) for k in range(sub.width)
           if sub.nbr[i, k] >= 0 and sub.cstate[i, k] == BONDED}
    assert got == want and len(got) > 0
    assert sub.nbr.max() < sub.n
    # the original is untouched and the copy is independent
    sub.x[0, 0] = 99.0
    assert st.x[0, 0] != 99.0
    with pytest.raises(ValueError):
        subset_state(st, np.ones(3, bool))


def test_narrow_platen_elements_do_not_interpenetrate():
    # 5 elements across a 0.1 m box: the platen between the side walls holds 3 wall-size
    # elements 0.71 d_wall apart, which would overlap by more than half a radius (the fixed
    # elements' limit); they get elements of spacing / 0.85 instead, and the state is valid
    from geodem.build.packing import deposition_state
    from geodem.core.engine import validate_state
    from geodem.core import groups

    d = 0.02
    x = np.array([[0.05, 0.05], [0.03, 0.1], [0.07, 0.15]])
    r = np.full(3, 0.5 * d)
    st = deposition_state(x, r, ([0.0, 0.0], [0.1, 0.2]))
    validate_state(st)
    p = groups.members(st, "platen")
    xs = np.sort(st.x[p, 0])
    gap = np.diff(xs).min()
    assert gap < 0.75 * 2 * d  # the narrow case
    assert st.r[p] == pytest.approx(0.5 * gap / 0.85)
    assert st.r[groups.members(st, "wall")] == pytest.approx(d)  # walls keep d_wall = 2 d_mean
    # a wide platen keeps the wall element size
    wide = deposition_state(x * 4, r, ([0.0, 0.0], [0.4, 0.8]))
    assert wide.r[groups.members(wide, "platen")] == pytest.approx(d)
