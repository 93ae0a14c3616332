"""TwoBalls against the damped harmonic oscillator (PHYSICS.md section 3, VALIDATION.md)."""
import numpy as np
import pytest

from geodem.cases import two_balls as tb
from geodem.core.engine import Simulation


def history(zeta, periods=12, backend="numba", dim=2):
    st = tb.build(dim=dim, damping_ratio=zeta)
    an = tb.analytic(st)
    sim = Simulation(st, backend=backend, dt=0.02 * an["T0"])  # dt = 2 % of the period
    x0 = 1.0  # rest position of ball 1
    ts, us = [0.0], [st.x[1, 0] - x0]

    def rec(s):
        s.backend.pull(("x",))  # inside a run: a device backend's positions of this step
        ts.append(s.state.time)
        us.append(s.state.x[1, 0] - x0)

    sim.run(int(periods / 0.02), callback=rec, every=1)
    return np.array(ts), np.array(us), sim, an


@pytest.mark.parametrize("dim", [2, 3])
def test_undamped_period(dim):
    t, u, sim, an = history(0.0, dim=dim)
    m = tb.measure(t, u)
    assert abs(m["T"] - an["T"]) / an["T"] < 0.005
    assert m["peaks"] >= 10


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_ten_percent_damping_period_and_decay(backend):
    t, u, sim, an = history(0.1, periods=8, backend=backend)
    m = tb.measure(t, u)
    assert abs(m["T"] - an["T"]) / an["T"] < 0.005
    assert abs(m["decay_rate"] - an["decay_rate"]) / an["decay_rate"] < 0.005
    assert sim.energies()["closure_error"] < 0.005


def test_critical_damping_returns_without_overshoot():
    t, u, sim, an = history(1.0, periods=4)
    amp = u[0]
    assert u.min() > -1e-9 * amp  # never crosses the rest position
    assert np.all(np.diff(u) <= 1e-15 * amp)  # monotone return
    # analytic critically damped curve u = A (1 + w t) exp(-w t)
    w = an["omega0"]
    ref = amp * (1 + w * t) * np.exp(-w * t)
    assert np.abs(u - ref).max() < 0.005 * amp
    assert u[-1] < 1e-3 * amp
