"""Simulation.set_fixed_velocity: the light velocity update of fixed elements (a servo's walls)
gives the bits of the full Simulation.change."""
import numpy as np
import pytest

from geodem.core.engine import Simulation
from geodem.workflow.runner import state_sha256
from tests.conftest import make_specimen

pytestmark = pytest.mark.usefixtures("one_numba_thread")

WALL = np.arange(3)  # make_specimen's fixed elements


def servo_run(light: bool) -> str:
    """Every 5 steps, the fixed elements get a new velocity (as a servo's walls do)."""
    sim = Simulation(make_specimen(n=200, dim=2, seed=3), backend="numba")
    for k in range(6):
        v = np.array([1e-3 * (k + 1), -2e-3 * k])
        if light:
            assert sim.set_fixed_velocity([(WALL, v)])
        else:
            def put(st, v=v):
                st.free[WALL] = 0.0
                st.v[WALL] = v
            sim.change(put, book_energy=False)
        sim.run(5)
    return state_sha256(sim.sync())


def test_the_light_update_gives_the_bits_of_a_full_change():
    assert servo_run(light=True) == servo_run(light=False)


def test_a_free_element_is_left_to_change_and_nothing_is_touched():
    sim = Simulation(make_specimen(n=200, dim=2, seed=3), backend="numba")
    st = sim.sync()
    before = st.v.copy(), st.a.copy()
    assert not sim.set_fixed_velocity([(WALL, np.zeros(2)), (np.arange(3, 6), np.ones(2))])
    assert np.array_equal(st.v, before[0]) and np.array_equal(st.a, before[1])
    with pytest.raises(ValueError, match="finite"):
        sim.set_fixed_velocity([(WALL, np.array([np.nan, 0.0]))])
