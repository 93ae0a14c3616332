"""Per-bond strength scatter (``bond_strength_weibull``): the factors' distribution, and bonds
that hold the same factor seen from either element."""
import math

import numpy as np
import pytest

from geodem.build.specimen import bond_strength_factors, cement
from geodem.core.state import BONDED, new_state
from geodem.materials import at_size, per_size


def _cov(m):
    g1, g2 = math.gamma(1 + 1 / m), math.gamma(1 + 2 / m)
    return math.sqrt(g2 / g1 ** 2 - 1)


@pytest.mark.parametrize("m", [1.5, 3.0, 10.0])
def test_factors_have_mean_one_and_the_weibull_scatter(m):
    w = bond_strength_factors(200_000, m, seed=1)
    assert w.mean() == pytest.approx(1.0, abs=0.01)
    assert w.std() / w.mean() == pytest.approx(_cov(m), rel=0.02)
    assert w.min() > 0.0


def test_hand_computed_cov_values():
    # the docstring's table: 0.52 at m = 2, 0.36 at 3, 0.23 at 5, 0.12 at 10
    assert [round(_cov(m), 2) for m in (2, 3, 5, 10)] == [0.52, 0.36, 0.23, 0.12]


def test_no_modulus_means_uniform_bonds_and_a_bad_one_is_refused():
    assert np.array_equal(bond_strength_factors(5, None), np.ones(5))
    with pytest.raises(ValueError, match="allowed > 0"):
        bond_strength_factors(5, 0.0)


def test_factors_repeat_with_the_seed_and_change_with_it():
    a, b = bond_strength_factors(50, 3.0, 7), bond_strength_factors(50, 3.0, 7)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, bond_strength_factors(50, 3.0, 8))


def _block(weibull):
    g = np.arange(6) * 0.01  # a 6 x 6 square grid of touching discs of diameter 0.01 m
    x = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    st = new_state(x, np.full(36, 0.005), 1.0, width=8)
    el = {"kn": 1e8, "ks": 5e7, "xb": 1e-5, "fs0": 1e3, "mu": 0.5}
    if weibull is not None:
        el["bond_strength_weibull"] = weibull
    cement(st, 1e-9, el, d_ref=0.01, rho=2500.0, seed=3)
    return st


def test_cement_gives_each_bond_one_factor_seen_from_both_elements():
    st = _block(2.0)
    bonded = st.cstate == BONDED
    i, k = np.nonzero(bonded)
    j = st.nbr[i, k]
    assert i.size == 2 * 60  # 6 x 6 square lattice: 2 x 6 x 5 bonds, each in two rows
    mirror = {(int(a), int(b)): float(st.brate[a, c]) for a, c, b in zip(i, k, j)}
    assert all(mirror[(a, b)] == mirror[(b, a)] for a, b in mirror)
    rates = np.array([mirror[(a, b)] for a, b in mirror if a < b])
    assert rates.std() > 0.2  # scattered (cov 0.52 at m = 2)
    assert np.all(_block(None).brate[bonded] == 1.0)


def test_the_modulus_travels_with_the_size_free_parameters():
    el = {"kn": 1e8, "ks": 5e7, "xb": 1e-5, "fs0": 1e3, "mu": 0.5, "bond_strength_weibull": 4.0}
    scaled = per_size(el, 0.01)
    assert scaled["bond_strength_weibull"] == 4.0
    assert at_size(scaled, 0.02)["bond_strength_weibull"] == 4.0
    assert "bond_strength_weibull" not in per_size(dict(el, bond_strength_weibull=None), 0.01)


def test_a_builder_without_per_bond_factors_refuses_a_scattered_material(tmp_path):
    # the lattice block bonds its own lattice: it would silently drop the scatter
    import yaml

    from geodem.workflow import run_workflow
    from geodem.workflow.errors import WorkflowError

    doc = {"metadata": {"name": "scatter", "seed": 0},
           "model": {"type": "lattice_block", "dim": 2, "counts": [4, 4], "diameter": 0.01,
                     "material": "rock"},
           "materials": {"rock": {"rho": 2500.0, "kn_per_d": 1e10, "ks_per_d": 5e9,
                                  "xb_per_d": 1e-4, "fs0_per_d2": 1e6, "mu": 0.5,
                                  "bond_strength_weibull": 3.0}},
           "steps": [{"kind": "run", "name": "run", "nsteps": 10}]}
    path = tmp_path / "w.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(WorkflowError, match="bond_strength_weibull = 3, which this model's "
                                            "builder does not apply"):
        run_workflow(path, tmp_path / "out", echo=False, progress=False)


def test_cement_reports_its_balance_rounds_and_whether_they_sufficed():
    """Balances run until the unbalanced-force ratio is below ``tol`` or ``max_rounds`` ran out,
    and the report says which. (A free block relaxed to no stress has a ratio of round-off
    over round-off, O(1): only a loose tolerance stops it after one round; a real specimen, the
    quick start's, balances in 2 rounds to 5.6e-4.)"""
    g = np.arange(4) * 0.00999  # slightly compressed: the bonds push the grid apart
    x = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    el = {"kn": 1e8, "ks": 5e7, "xb": 1e-5, "fs0": 1e3, "mu": 0.5}
    rep = cement(new_state(x, np.full(16, 0.005), 1.0, width=8), 1e-9, el, d_ref=0.01,
                 rho=2500.0, tol=10.0)
    assert rep["balanced"] and rep["balance_rounds"] == 1 and rep["unbalanced_ratio"] < 10.0
    rep = cement(new_state(x, np.full(16, 0.005), 1.0, width=8), 1e-9, el, d_ref=0.01,
                 rho=2500.0, tol=0.0, max_rounds=3)
    assert not rep["balanced"] and rep["balance_rounds"] == 3
