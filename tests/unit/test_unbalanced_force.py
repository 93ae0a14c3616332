"""The unbalanced-force ratio (geodem.core.checks): mean |m a + eta v| over free elements
divided by the mean |contact force| over the row entries, against a direct NumPy sum."""
import numpy as np

from geodem.core.checks import unbalanced_force_ratio
from tests.conftest import make_specimen


def direct_ratio(s):
    free = (s.free != 0.0).any(axis=1)
    net = s.m[:, None] * s.a + s.eta[:, None] * s.v
    net = np.where(s.free != 0.0, net, 0.0)
    fnet = np.linalg.norm(net, axis=1)[free].mean()
    rows = []
    for i in range(s.n):
        for k in range(s.nbr.shape[1]):
            j = s.nbr[i, k]
            if j < 0:
                break
            xn = np.linalg.norm(s.x[j] - s.x[i]) - s.r[i] - s.r[j]
            kn = s.kn[i] * s.kn[j] / (s.kn[i] + s.kn[j])
            fn = kn * xn if (s.cstate[i, k] == 1 or xn < 0.0) else 0.0
            rows.append(np.hypot(fn, np.linalg.norm(s.fs[i, k])))
    return fnet / np.mean(rows)


def test_ratio_matches_a_direct_sum_with_fixed_elements():
    s = make_specimen(n=150, dim=3)
    rng = np.random.default_rng(4)
    s.a[:] = rng.normal(0.0, 1.0, s.a.shape)
    s.v[:] = rng.normal(0.0, 1e-3, s.v.shape)
    s.fs[:] = rng.normal(0.0, 1.0, s.fs.shape) * (s.nbr >= 0)[..., None]
    s.free[:10] = 0.0  # fixed elements carry no unbalanced force
    s.free[10:20, 0] = 0.0  # rollers: only their free components count
    ratio = unbalanced_force_ratio(s)
    assert ratio > 0.0
    assert abs(ratio - direct_ratio(s)) <= 1e-12 * ratio


def test_ratio_is_zero_without_free_elements():
    s = make_specimen(n=60, dim=2)
    s.free[:] = 0.0
    assert unbalanced_force_ratio(s) == 0.0
