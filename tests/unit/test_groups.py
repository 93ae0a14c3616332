"""Groups: fixing, kinematic platens, loads, reactions, and pre-cut joints."""
import numpy as np
import pytest

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.core import groups
from geodem.core.engine import Simulation


def block():
    d = 0.01
    x = triangular_lattice(6, 6, d)
    st = bonded_state(x, np.full(len(x), 0.5 * d), density=2650.0, kn=1e6, ks=4e5, xb=1.0,
                      fs0=1e9, mu=0.5, gap=1e-6 * d, thickness=d)
    y = st.x[:, 1]
    groups.add_group(st, "base", y < 0.1 * d)
    groups.add_group(st, "top", y > y.max() - 0.1 * d)
    return st


def test_fix_velocity_load_and_reaction():
    st = block()
    groups.fix(st, "base")
    groups.set_velocity(st, "top", [np.nan, -1e-3])  # y prescribed, x free
    top = groups.members(st, "top")
    assert np.all(st.free[top, 1] == 0) and np.all(st.free[top, 0] == 1)
    sim = Simulation(st, backend="numba")
    y0 = st.x[top, 1].copy()
    sim.run(100)
    assert np.allclose(st.x[top, 1], y0 - 1e-3 * st.time, rtol=0, atol=1e-15)
    # compressed block: the base pushes back up, the top platen down
    assert groups.reaction(st, "base")[1] < 0 < groups.reaction(st, "top")[1]
    groups.set_load(st, "top", [5.0, 0.0])
    assert st.fload[top, 0].sum() == pytest.approx(5.0)
    with pytest.raises(ValueError, match="already exists"):
        groups.add_group(st, "top", [0])
    with pytest.raises(ValueError, match=r"degree of freedom 'w'"):
        groups.fix(st, "base", "w")


def test_precut_joint_logged_and_unbonded():
    st = block()
    sim = Simulation(st, backend="numba")
    j0 = st.nbr[0, 0]
    assert sim.cut([0], [j0]) == 1
    log = sim.crack_log()
    assert len(log) == 1 and log["type"][0] == 0 and (log["i"][0], log["j"][0]) == (0, j0)
    assert sim.bonded_count() == (st.cstate == 1).sum() // 2
    assert sim.cut([0], [j0]) == 0  # already cut


def test_degrees_of_freedom_by_name():
    st = block()
    base = groups.members(st, "base")
    groups.fix(st, "base", "y")
    assert np.all(st.free[base] == [1.0, 0.0])
    groups.release(st, "base", "y")
    groups.fix(st, "base", "xy")  # two names in one string: both fixed (was x only)
    assert np.all(st.free[base] == 0.0)
    for bad in ("", "xw", True, [0, 5]):
        with pytest.raises(ValueError, match="degree of freedom"):
            groups.fix(st, "base", bad)


def test_cutting_a_loaded_bond_books_its_energy_and_refreshes_the_forces():
    from geodem.core.neighbors import build_rows, rows_from_pairs
    from geodem.core.state import new_state

    r = 0.005
    st = new_state(np.array([[0.0, 0.0, 0.0], [2 * r + 0.001 * r, 0.0, 0.0]]), r, 1e-3,
                   kn=1e6, ks=3e5, xb=1e-3, fs0=50.0, mu=0.3)
    rows_from_pairs(st, [0], [1], bonded=True)
    build_rows(st, skin=0.1 * r)
    sim = Simulation(st, backend="numba")
    e0 = sim.energies()["elastic"]
    kn = 0.5e6  # series of the two kn
    assert e0 == pytest.approx(0.5 * kn * (0.001 * r) ** 2, rel=1e-9)
    assert st.a[1, 0] < 0.0  # the stretched bond pulls element 1 back
    assert sim.cut(0, 1) == 1
    e = sim.energies()
    assert e["elastic"] == 0.0 and e["heat_break_normal"] == pytest.approx(e0, rel=1e-12)
    assert e["closure_error"] < 1e-12
    assert np.all(st.a == 0.0)  # apart and unbonded: no force from the next step on
    sim.run(10)
    assert sim.closure_error() < 1e-12 and np.all(st.v == 0.0)


def test_crack_times_follow_the_time_step_of_each_stage():
    st = block()
    st.xb[:] = 1e-6  # weak bonds
    groups.fix(st, "base")
    s1 = Simulation(st, backend="numba")
    dt = st.dt
    s1.run(200)  # at rest: no crack
    t1 = st.time
    groups.set_velocity(st, "top", [0.0, 0.5])  # then pulled apart, at a finer step
    s2 = Simulation(st, backend="numba", dt=dt / 4)
    s2.run(800)
    t = s2.crack_log()["time"]
    assert len(t) > 0 and len(s1.crack_log()) == 0
    # (step * dt, the old time, put them between 50 dt and 250 dt: before the stage began)
    assert t.min() > t1 and t.max() <= st.time + 1e-15


def test_a_force_refresh_of_turning_elements_adds_no_rotation():
    """``refresh_forces`` evaluates the forces at the current state: for turning elements the
    last step's rotation increment must not load the rolling springs again (it did, and a
    heated plate of turning elements, refreshed at every expansion, gained energy)."""
    from geodem.core.state import enable_rotation

    st = block()
    enable_rotation(st, bond_moment=100.0, rolling_stiffness=2.0)
    groups.fix(st, "base")
    groups.set_velocity(st, "top", [1e-3, 0.0])  # shear the block: the elements turn
    sim = Simulation(st, backend="numba")
    sim.run(200)
    sim.sync()
    assert np.abs(st.dth).max() > 0.0 and np.abs(st.mr).max() > 0.0
    mr, a = st.mr.copy(), st.a.copy()
    sim.refresh_forces()
    sim.refresh_forces()
    sim.sync()
    assert np.all(st.dth == 0.0)
    np.testing.assert_array_equal(st.mr, mr)
    np.testing.assert_allclose(st.a, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
