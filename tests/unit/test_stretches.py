"""The engine runs the steps between two events in one backend call (``NumbaBackend.steps``):
the same steps, bit for bit, as one call per pass and step."""
import numpy as np
import pytest

from geodem.core.engine import Simulation

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def _run(stretches, nsteps=230, every=7):
    from tests.unit.test_owner_kernel import breaking_block

    st = breaking_block(600)
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.stretches = stretches
    seen = []
    calls = []
    real = sim.backend.steps

    def spy(dt, k, step0):
        calls.append(k)
        return real(dt, k, step0)

    sim.backend.steps = spy
    sim.run(nsteps, callback=lambda s: seen.append((s.state.step, s.state.time)), every=every)
    sim.run(13)  # no callback: stretches up to the checks
    return st, sim, seen, calls


def test_stretches_repeat_single_steps_bit_for_bit():
    a, sa, seen_a, calls_a = _run(False)
    b, sb, seen_b, calls_b = _run(True)
    assert calls_a == [] and max(calls_b) > 1  # the stretches were taken
    assert sum(calls_b) < a.step  # not every step: the checks' steps go one by one too
    assert a.step == b.step == 243 and a.time == b.time
    assert seen_a == seen_b and [s for s, _ in seen_b] == list(range(7, 231, 7))
    assert len(sa.crack_log()) > 0  # bonds broke inside stretches: the codes were exercised
    assert np.array_equal(sa.crack_log(), sb.crack_log())
    for name in ("x", "v", "a", "dx", "fs", "cstate", "q_break_n", "q_break_s", "q_fric",
                 "q_visc", "w_ext"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert sa.rebuilds == sb.rebuilds


def test_awake_elements_only_take_the_step_by_step_path():
    from tests.unit.test_owner_kernel import breaking_block

    st = breaking_block(300)
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.backend.set_active(np.arange(st.n // 2))
    assert sim.backend.steps(st.dt, 5, st.step) is False  # nothing done: the engine steps
    x0 = st.x.copy()
    sim.run(5)
    assert st.step == 5 and not np.array_equal(st.x, x0)
