"""The bench specimen (geodem.bench.build_specimen): bonded at zero mean strain, every lattice
neighbour bonded, few other row entries, and the skin the docstring states."""
import numpy as np
import pytest

from geodem.bench import SKIN, SPACING, build_specimen, mean_pair_gap
from geodem.build.lattice import contact_pairs, random_specimen

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_mean_pair_gap_by_hand():
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    r = np.array([0.4, 0.5, 0.5])
    i, j = np.array([0, 0]), np.array([1, 2])
    # gaps 1 - 0.9 = 0.1 and 2 - 0.9 = 1.1; chunks of one pair give the same mean
    assert mean_pair_gap(x, r, i, j) == pytest.approx(0.6, rel=1e-15)
    assert mean_pair_gap(x, r, i, j, chunk=1) == pytest.approx(0.6, rel=1e-15)


def test_bench_specimen_starts_at_zero_mean_strain():
    st = build_specimen(2000)
    nbr, cs = st.nbr.ravel(), st.cstate.ravel()
    bonded = (nbr >= 0) & (cs == 1)
    i = np.repeat(np.arange(st.n), st.nbr.shape[1])[bonded]
    j = nbr[bonded]
    # the skin adds a few second-shell pairs of the largest elements (18 entries of 21,056)
    assert ((nbr >= 0) & (cs != 1)).sum() < 0.002 * (nbr >= 0).sum()
    # same pairs as random_specimen's lattice neighbours (its radii overlap them by ~0.12 d)
    x, r = random_specimen(2000, seed=0, d=SPACING)
    p, q = contact_pairs(x, r, 0.05 * SPACING)
    assert len(i) == 2 * len(p)
    assert mean_pair_gap(x, r, p, q) < -0.1 * SPACING
    # bonded now at zero mean strain (to round-off)
    assert abs(mean_pair_gap(st.x, st.r, i, j)) < 1e-12 * SPACING
    assert st.skin == SKIN * SPACING
