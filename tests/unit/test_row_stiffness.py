"""A contact's own stiffness factor (``krate``): a softer interface between two regions.

``Kn`` and ``Ks`` of a contact are the series stiffness of its two elements times the row's
factor (geodem.core.law); its strength (breaking force) is not scaled, so a softened bond
breaks at a larger displacement. The factor moves with its pair through rebuilds, sorting,
element removal and checkpoints, and every backend reads it the same.
"""
import numpy as np
import pytest

from geodem.core import law
from geodem.core.checkpoint import load_state, save_state
from geodem.core.engine import Simulation
from geodem.core.neighbors import build_rows, check_rows, rows_from_pairs, sort_rows
from geodem.core.state import (BONDED, enable_row_stiffness, new_state, scale_row_stiffness,
                               take)
from tests.conftest import make_specimen, run_in_cuda_simulator, step_backends
from tests.unit.test_backends import assert_same
from tests.unit.test_rotation import _rotating_specimen, numba_against_numpy

KN, KS, XB, FS0 = 2.0e6, 1.0e6, 1.0e-4, 50.0  # per element: the series values are half


def _law(xn, kf, rate=1.0, shear=0.0):
    # a bonded pair of unit radii along x, gap xn [m], tangential step displacement shear [m]
    return law.contact(2.0 + xn, 0.0, 0.0, 0.0, shear, 0.0, 0.0, 0.0, 0.0,
                       1.0, 1.0, KN, KN, KS, KS, XB, XB, FS0, FS0, 0.0, 0.0,
                       rate, kf, BONDED, 7, 9, 0)


def test_the_factor_scales_the_normal_and_shear_springs_not_the_strength():
    # Kn = kf kn/2 = 0.5e6 N/m at kf 0.5: 1e-5 m of tension holds 5 N
    fn = _law(1e-5, 0.5)[0]
    assert fn == pytest.approx(0.5 * KN / 2 * 1e-5, rel=1e-9)
    assert _law(1e-5, 1.0)[0] == pytest.approx(KN / 2 * 1e-5, rel=1e-9)
    # Ks = kf ks/2: a tangential step of 2e-5 m loads the spring by 0.25e6 * 2e-5 = 5 N
    assert _law(0.0, 0.5, shear=2e-5)[5] == pytest.approx(0.5 * KS / 2 * 2e-5, rel=1e-9)
    # the breaking force rate min(kn xb) = 200 N is the element's: reached at 4e-4 m of
    # tension at kf 0.5 (BF / (kf kn/2)), twice the 2e-4 m of the plain bond
    assert _law(3.9e-4, 0.5)[7] == BONDED
    assert _law(4.01e-4, 0.5)[7] == 7
    assert _law(2.01e-4, 1.0)[7] == 7


def test_the_elastic_energy_takes_the_factor():
    e = law.contact_energy(2.0 + 1e-5, 0.0, 0.0, 3.0, 0.0, 0.0, 1.0, 1.0, KN, KN, KS, KS,
                           BONDED, 0, 0.5)
    # Fn^2/(2 Kn) with Kn = 0.5e6 at 1e-5 m: Kn xn^2 / 2; |Fs|^2/(2 Ks), Ks = 0.25e6
    assert e == pytest.approx(0.5 * 0.5e6 * 1e-10 + 9.0 / (2 * 0.25e6), rel=1e-9)


def _soften(st, seed=2, lo=0.3):
    """Factors in [lo, 1) on every pair, the same on both sides of a pair."""
    enable_row_stiffness(st)
    rng = np.random.default_rng(seed)
    i, a = np.nonzero(st.nbr >= 0)
    j = st.nbr[i, a]
    f = rng.uniform(lo, 1.0, st.n * st.n)
    st.krate[i, a] = f[np.minimum(i, j) * st.n + np.maximum(i, j)]
    check_rows(st)
    return st


@pytest.mark.parametrize("dim", [2, 3])
def test_numba_matches_the_numpy_reference_with_softened_contacts(dim):
    base = _soften(make_specimen(n=300, dim=dim))
    runs = step_backends(base, ("numba", "numpy"), 12)
    assert_same(runs["numba"][0], runs["numpy"][0])
    assert len(runs["numba"][1]) > 3  # bonds break: the decisions are compared
    plain = step_backends(make_specimen(n=300, dim=dim), ("numba",), 12)["numba"][0]
    assert np.abs(plain.x - runs["numba"][0].x).max() > 0  # the factors change the motion


@pytest.mark.parametrize("dim", [2, 3])
def test_turning_elements_take_the_factor_on_every_backend(dim):
    st = _soften(_rotating_specimen(300, dim))
    st.bond_moment[:] = 1.0
    a = numba_against_numpy(st, ("x", "v", "a", "fs", "w", "wa", "mr", "q_visc", "q_fric",
                                 "w_ext"))
    assert np.abs(a.mr).max() > 0.0


@pytest.mark.parametrize("kf", [1.0, 0.25])
def test_a_bonded_pair_rings_at_the_softened_springs_frequency(kf):
    """Two bonded balls of mass m pulled apart ring at w = sqrt(2 Kn / m), Kn = kf kn / 2:
    a quarter of the stiffness doubles the period; the books close (no heat: no break)."""
    m, kn, r = 1.0, 4.0e6, 0.01
    st = new_state(np.array([[0.0, 0.0], [2 * r, 0.0]]), r, m, kn=kn, ks=kn, xb=1.0,
                   fs0=1e9, width=4)
    rows_from_pairs(st, [0], [1])
    scale_row_stiffness(st, st.nbr >= 0, kf)
    st.v[0, 0], st.v[1, 0] = -0.01, 0.01
    period = 2 * np.pi / np.sqrt(2 * kf * kn / 2 / m)
    sim = Simulation(st, backend="numba", dt=period / 400)
    gap, t = [], []
    for _ in range(1000):
        sim.run(1)
        gap.append(st.x[1, 0] - st.x[0, 0] - 2 * r)
        t.append(st.time)
    gap = np.array(gap)
    up = np.flatnonzero((gap[:-1] < 0) & (gap[1:] >= 0))  # upward zero crossings
    measured = (t[up[-1]] - t[up[0]]) / (len(up) - 1)
    assert measured == pytest.approx(period, rel=2e-3)
    # amplitude v_rel / w: the same energy in a softer spring stretches it further
    assert np.abs(gap).max() == pytest.approx(0.02 / np.sqrt(2 * kf * kn / 2 / m), rel=2e-3)
    assert sim.energies()["closure_error"] < 1e-6


def test_a_plain_model_is_stepped_bit_for_bit_as_before():
    # factors of exactly 1 on the per-row variant give the plain kernels' bits
    a = step_backends(make_specimen(n=200, dim=3), ("numba",), 20)["numba"][0]
    b = step_backends(enable_row_stiffness(make_specimen(n=200, dim=3)), ("numba",), 20)
    assert np.array_equal(a.x, b["numba"][0].x) and np.array_equal(a.fs, b["numba"][0].fs)


def test_the_factor_moves_with_its_pair_through_rebuilds_sorting_and_removal():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.5, 0.8]])
    st = new_state(x, 0.5, 1.0, kn=1e6, ks=1e6, width=4)
    rows_from_pairs(st, [0, 1, 0], [1, 2, 3])
    enable_row_stiffness(st)
    pair = lambda s, i, j: s.krate[i, list(s.nbr[i]).index(j)]  # noqa: E731
    scale_row_stiffness(st, (st.nbr == 1) & (np.arange(4)[:, None] == 0), 0.5)
    scale_row_stiffness(st, (st.nbr == 0) & (np.arange(4)[:, None] == 1), 0.5)
    check_rows(st)
    build_rows(st, skin=0.05, width=8)  # a wider row: new arrays, the same pairs
    assert pair(st, 0, 1) == pair(st, 1, 0) == 0.5 and pair(st, 1, 2) == 1.0
    st.x[2] = [1.5, 0.0]  # 2 now touches 1 closer; no new pair for 0
    build_rows(st, skin=0.05)
    assert pair(st, 0, 1) == 0.5 and (st.krate[st.nbr < 0] == 1.0).all()
    st.nbr[0, :2] = st.nbr[0, 1::-1].copy()  # renumbered by hand: sort carries the factor
    st.krate[0, :2] = st.krate[0, 1::-1].copy()
    sort_rows(st)
    assert pair(st, 0, 1) == 0.5
    sub = take(st, np.array([0, 1, 3]))
    assert pair(sub, 0, 1) == 0.5 and pair(sub, 0, 2) == 1.0
    check_rows(sub)


def test_a_checkpoint_keeps_the_factors(tmp_path):
    st = _soften(make_specimen(n=100, dim=2))
    save_state(st, tmp_path / "c.npz")
    back, _ = load_state(tmp_path / "c.npz")
    assert back.row_stiffness and np.array_equal(back.krate, st.krate)


def test_bad_factors_are_refused():
    st = make_specimen(n=50, dim=2)
    with pytest.raises(ValueError, match="allowed: 0 < factor <= 1"):
        scale_row_stiffness(st, st.nbr >= 0, 1.5)
    enable_row_stiffness(st)
    st.krate[0, 0] = 0.0
    with pytest.raises(ValueError, match=r"krate\[0, 0\] is 0.0; allowed: 0 < krate <= 1"):
        Simulation(st)
    st.krate[0, 0] = 0.5  # one side only
    with pytest.raises(ValueError, match="krate differs from the mirror entry"):
        check_rows(st)


CUDA_SCRIPT = r"""
import json, sys, numpy as np
sys.path.insert(0, sys.argv[1])
from tests.conftest import make_specimen, step_backends
from tests.unit.test_row_stiffness import _soften
out = {}
for dim in (2, 3):
    res = step_backends(_soften(make_specimen(n=60, dim=dim)), ("cupy", "numpy"), 4)
    a, b = res["cupy"][0], res["numpy"][0]
    out[dim] = max(float(np.abs(getattr(a, k) - getattr(b, k)).max()
                         / max(np.abs(getattr(b, k)).max(), 1e-300)) for k in ("x", "v", "fs"))
    out[f"{dim}_same"] = bool(np.array_equal(a.cstate, b.cstate))
print(json.dumps(out))
"""


def test_the_gpu_kernels_take_the_factor_in_the_cuda_simulator():
    out = run_in_cuda_simulator(CUDA_SCRIPT, timeout=300)
    assert out["2"] < 1e-12 and out["3"] < 1e-12 and out["2_same"] and out["3_same"]
