"""Where the integration fails (issue 7): the measured critical time step against 2/omega_max,
and the engine stopping a run that blows up with a message that says what to change."""
import numpy as np
import pytest

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.core import timestep
from geodem.core.engine import InstabilityError, Simulation
from geodem.studies import stability as S

D = 0.01


def lattice(n=6):
    return bonded_state(triangular_lattice(n, n, D), 0.5 * D, density=2500.0, kn=1e8, ks=5e7,
                        xb=1.0, fs0=1e9, mu=0.5, gap=1e-9 * D)


def test_omega_max_of_two_bonded_elements_is_the_hand_value():
    # two free discs, one bond: the axial mode omega^2 = K (1/m + 1/m), K = kn/2 in series
    st = bonded_state(np.array([[0.0, 0.0], [D, 0.0]]), 0.5 * D, density=2500.0, kn=1e8,
                      ks=2e7, xb=1.0, fs0=1e9, mu=0.5, gap=1e-9 * D)
    m = st.m[0]
    assert S.omega_max_exact(st) == pytest.approx(np.sqrt(0.5e8 * 2 / m), rel=1e-12)


def test_refusal_bound_is_below_the_exact_limit():
    st = lattice()
    assert timestep.stable_dt_bound(st) < 2.0 / S.omega_max_exact(st)


def test_measured_critical_step_is_two_over_omega_max():
    r = S.measure_critical_dt(lattice(), steps=1000, rel_tol=0.004)
    assert r["measured"] == pytest.approx(r["predicted"], rel=0.01)
    # the engine's monitor stops runs at or just below the limit, never far below it
    assert 0.95 * r["predicted"] <= r["engine_stops"] <= r["diverges"]
    assert "energy grew without a source" in r["message"] and "reduce dt" in r["message"]


def test_a_run_blowing_up_is_stopped_even_when_every_check_rebuilds_the_rows():
    # regression: a neighbour rebuild used to skip the energy monitor, and a diverging run
    # rebuilds at every check; here the elements fly apart and nothing would be NaN
    st = lattice()
    st.v[:] = np.random.default_rng(0).standard_normal(st.v.shape) * 1e-4
    dt = 1.5 * 2.0 / S.omega_max_exact(st)
    sim = Simulation(st, backend="numba", dt=dt, monitor_every=100, allow_unstable_dt=True)
    with pytest.raises(InstabilityError, match="energy grew without a source"):
        sim.run(2000)
    assert sim.state.step <= 200


def test_unstable_dt_is_refused_without_the_study_flag():
    st = lattice()
    with pytest.raises(ValueError, match="above the stability limit"):
        Simulation(st, backend="numba", dt=1.01 * timestep.stable_dt_bound(st))
