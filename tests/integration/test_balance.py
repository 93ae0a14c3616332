"""Standard damping and the standard balance: a block settles under gravity to equilibrium."""
import numpy as np
import pytest

from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice
from geodem.core.engine import Simulation
from geodem.core.timestep import standard_balance_steps, standard_damping


@pytest.mark.parametrize("dim", [2, 3])
def test_block_under_gravity_reaches_equilibrium(dim):
    d = 0.01
    x = fcc_lattice(5, 5, 8, d) if dim == 3 else triangular_lattice(8, 10, d)
    st = bonded_state(x, np.full(len(x), 0.5 * d), density=2650.0, kn=1e6, ks=4e5, xb=1.0,
                      fs0=1e9, mu=0.5, gap=1e-6 * d, thickness=d if dim == 2 else None)
    up = dim - 1
    bottom = st.x[:, up] < 0.1 * d
    st.free[bottom] = 0.0
    st.gravity[up] = -9.81
    st.groups = {"all": 0, "base": 1, "block": 2}
    st.group[:] = np.where(bottom, 1, 2)
    n_across = int(round(st.x[:, up].max() / (d * (np.sqrt(2 / 3) if dim == 3 else np.sqrt(3) / 2)))) + 1
    sim = Simulation(st, backend="numba")
    ratio0 = sim.unbalanced_force_ratio()
    ratio = sim.balance(n_across)
    assert st.step == standard_balance_steps(n_across) == 50 * n_across
    assert np.allclose(st.eta, standard_damping(st, n_across))
    sim.run(3 * standard_balance_steps(n_across))  # a few more standard balances
    ratio = sim.unbalanced_force_ratio()
    assert ratio < 1e-3 < ratio0
    # the base carries the weight of the block: sum of reactions = total weight
    weight = st.m[~bottom].sum() * 9.81
    reaction = (st.a[bottom, up] * st.m[bottom]).sum()
    assert -reaction == pytest.approx(weight, rel=1e-3)
    e = sim.energies(by_group=True)
    assert e["closure_error"] < 0.005
    groups = e["groups"]
    for key in ("kinetic", "elastic", "gravity", "heat_viscous"):
        assert groups["base"][key] + groups["block"][key] == pytest.approx(e[key], rel=1e-9, abs=1e-15)
        assert groups["all"][key] == pytest.approx(e[key], rel=1e-12, abs=1e-15)
    assert groups["base"]["kinetic"] == 0.0 and groups["block"]["heat_viscous"] > 0
