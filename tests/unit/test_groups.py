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
