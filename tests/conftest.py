import numpy as np
import pytest

from geodem.build.lattice import bonded_state, random_specimen


def make_specimen(n=300, dim=3, seed=1, xb=2e-3, fs0=2e4, mu=0.4, vscale=0.5):
    """A small bonded specimen with random velocities: some bonds break within a few steps."""
    x, r = random_specimen(n, dim=dim, seed=seed, d=0.01)
    st = bonded_state(x, r, density=2650.0, kn=1e7, ks=4e6, xb=xb * 0.01, fs0=fs0 * 1e-4,
                      mu=mu, gap=0.05 * 0.01, eta=1e-3)
    rng = np.random.default_rng(seed)
    st.v[:] = rng.normal(0.0, vscale, st.v.shape)
    st.free[:3] = 0.0  # a few fixed elements: reactions and external work
    st.v[:3] = 0.0
    st.groups = {"all": 0, "fixed": 1}
    st.group[:3] = 1
    return st


@pytest.fixture
def specimen():
    return make_specimen
