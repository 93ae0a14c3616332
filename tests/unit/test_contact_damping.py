"""Normal contact damping (option): restitution of a binary collision against the analytic
spring-dashpot solution, energy books, backend agreement."""
import math

import numpy as np
import pytest

from geodem.core import neighbors
from geodem.core.engine import Simulation
from geodem.core.state import damping_ratio, enable_contact_damping, enable_rotation, new_state
from tests.conftest import make_specimen, run_in_cuda_simulator
from tests.unit.test_rotation import numba_against_numpy

pytestmark = pytest.mark.usefixtures("one_numba_thread")

R, M, KN, V0 = 1e-3, 1e-3, 1e5, 0.1


def capped_restitution(e):
    """Rebound of a linear spring-dashpot contact whose force may not pull: the pair separates
    when ``k x + c x' = 0``, i.e. at ``tan(wd t) = -2 zeta sqrt(1 - zeta^2)/(1 - 2 zeta^2)``;
    the restitution is ``|x'(t)| / v0`` there (x: overlap, x(0) = 0, x'(0) = v0)."""
    z = damping_ratio(e)
    wd = math.sqrt(1.0 - z * z)  # omega = 1
    t = (math.pi + math.atan(-2.0 * z * wd / (1.0 - 2.0 * z * z))) / wd
    return math.exp(-z * t) * abs(wd * math.cos(wd * t) - z * math.sin(wd * t)) / wd


def collide(e, backend="numba", dt_fraction=0.02):
    x = np.array([[0.0, 0.0], [2.05 * R, 0.0]])
    st = new_state(x, R, M, kn=KN, ks=0.5 * KN, mu=0.5, width=4)
    neighbors.build_rows(st, skin=R)
    if e is not None:
        enable_contact_damping(st, restitution=e)
    st.v[0, 0], st.v[1, 0] = V0, -V0
    sim = Simulation(st, backend=backend, dt_fraction=dt_fraction)
    sim.run(int(3000 * 0.02 / dt_fraction))
    return (st.v[1, 0] - st.v[0, 0]) / (2 * V0), sim.energies()


def test_damping_ratio_by_hand():
    assert damping_ratio(1.0) == 0.0
    assert damping_ratio(math.exp(-math.pi)) == pytest.approx(1.0 / math.sqrt(2.0), rel=1e-14)
    with pytest.raises(ValueError, match="allowed 0 < e <= 1"):
        damping_ratio(1.5)


@pytest.mark.parametrize("e, err_default", [(0.9, 0.008), (0.5, 0.028), (0.2, 0.042)])
def test_binary_collision_rebounds_at_the_analytic_restitution(e, err_default):
    """The rebound against the analytic capped spring-dashpot value. The dashpot sees the
    step's mean relative velocity (half a step late): 0.7-4 % lively at the default step (2 % of
    the period), 0.03-0.2 % at a quarter of it. The heat is the kinetic energy lost."""
    e_ref = capped_restitution(e)
    assert e_ref > e  # the cap makes the rebound livelier than the uncapped formula
    errs = []
    for frac in (0.02, 0.005):
        e_num, en = collide(e, dt_fraction=frac)
        errs.append(e_num / e_ref - 1.0)
        ke0 = 0.5 * 2 * M * V0 ** 2
        # heat = kinetic energy lost, to the collision's integration error (0.44 % of the
        # energy for an undamped one at the default step)
        assert abs(en["heat_viscous"] - ke0 * (1.0 - e_num ** 2)) < 0.006 * ke0
    assert 0.0 < errs[0] < err_default
    assert abs(errs[1]) < 0.1 * errs[0]


def test_no_damping_is_elastic_and_books_close():
    e_num, en = collide(None)
    assert e_num == pytest.approx(1.0, abs=0.003) and en["heat_viscous"] == 0.0


def _damped_specimen(n, dim, seed=1):
    st = make_specimen(n=n, dim=dim, seed=seed)
    enable_rotation(st, mu_r=0.05)
    enable_contact_damping(st, restitution=0.5)
    st.gravity[1] = -9.81
    return st


@pytest.mark.parametrize("dim", [2, 3])
def test_numba_matches_numpy_with_contact_damping(dim):
    a = numba_against_numpy(_damped_specimen(300, dim),
                            ("x", "v", "a", "fs", "w", "mr", "fdash", "q_visc", "q_fric", "w_ext"))
    assert np.abs(a.fdash).max() > 0.0


CUDA_SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from tests.unit.test_contact_damping import _damped_specimen
from tests.unit.test_rotation import rel_diff
from tests.conftest import step_backends
out = {}
for dim in (2, 3):
    res = step_backends(_damped_specimen(60, dim), ("cupy", "numpy"), 4)
    out[dim] = max(rel_diff(res["cupy"][0], res["numpy"][0], k)
                   for k in ("x", "v", "fs", "w", "fdash", "q_visc"))
print(json.dumps(out))
"""


def test_cuda_kernels_with_contact_damping_in_simulator():
    for dim, err in run_in_cuda_simulator(CUDA_SCRIPT, timeout=300).items():
        assert err < 1e-12, (dim, err)


def test_energy_books_close_in_a_damped_collapse(tmp_path):
    st = _damped_specimen(300, 2)
    st.cstate[:] = 0
    sim = Simulation(st, backend="numba")
    sim.run(2000)
    e = sim.energies()
    assert e["heat_viscous"] > 0.0 and e["closure_error"] < 2e-3
    sim.save(tmp_path / "d.npz")  # the dashpot forces are part of the checkpoint
    sim.run(30)
    again = Simulation.load(tmp_path / "d.npz", backend="numba")
    assert again.state.contact_damping
    again.run(30)
    for k in ("x", "v", "fdash", "q_visc"):
        assert np.array_equal(getattr(again.state, k), getattr(st, k)), k


def test_contact_damping_needs_its_arrays():
    x = np.array([[0.0, 0.0], [2.05 * R, 0.0]])
    st = new_state(x, R, M, kn=KN, width=4)
    st.contact_damping = True  # switched on by hand, without enable_contact_damping
    with pytest.raises(ValueError, match="enable_contact_damping"):
        Simulation(st, backend="numba")
    with pytest.raises(ValueError, match="exactly one of restitution and zeta_n"):
        enable_contact_damping(new_state(x, R, M, kn=KN), restitution=0.5, zeta_n=0.2)
