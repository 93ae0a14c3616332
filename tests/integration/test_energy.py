"""Energy books: conservation without damping, closure with damping, breakage and friction."""
import numpy as np

from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice
from geodem.cases import two_balls as tb
from geodem.core import groups
from geodem.core.engine import Simulation
from geodem.core.timestep import element_critical_damping


def period_mean_energy(sim, steps):
    vals = []

    def rec(s):
        e = s.energies()
        vals.append(e["kinetic"] + e["elastic"])

    sim.run(steps, callback=rec, every=1)
    return float(np.mean(vals))


def test_no_damping_no_breakage_drift_over_1e5_steps():
    st = tb.build(dim=3, damping_ratio=0.0)
    sim = Simulation(st, backend="numba", dt_fraction=0.02)
    e0 = sim.energies()["total"]
    per = 50  # one period at dt = 2 % of it
    first = period_mean_energy(sim, per)
    sim.run(100_000)
    last = period_mean_energy(sim, per)
    assert abs(last - first) / e0 < 1e-4
    assert sim.crack_log().size == 0


def platen_block(x, d, velocity, **params):
    """A bonded block on a fixed base with a kinematic top row moving at ``velocity``."""
    st = bonded_state(x, np.full(len(x), 0.5 * d), density=2650.0, gap=0.01 * d, **params)
    st.eta[:] = 0.05 * element_critical_damping(st)
    up = st.x[:, -1]
    groups.add_group(st, "base", up < 0.1 * d)
    groups.add_group(st, "top", up > up.max() - 0.1 * d)
    groups.fix(st, "base")
    groups.set_velocity(st, "top", velocity)
    return st


def test_closure_platen_compression_3d():
    """A 3-D lattice block crushed by a kinematic platen with damping: shear cracks, friction."""
    d = 0.01
    st = platen_block(fcc_lattice(8, 8, 10, d), d, [0.0, 0.0, -0.05], kn=1e7, ks=4e6,
                      xb=2e-4 * d, fs0=3.0, mu=0.4)
    sim = Simulation(st, backend="numba")
    sim.run(2500)
    e = sim.energies()
    log = sim.crack_log()
    assert (log["type"] == 2).sum() > 10
    assert e["work_external"] > 0 and e["heat_friction"] > 0 and e["heat_break_shear"] > 0
    assert e["closure_error"] < 0.005


def test_closure_platen_pull_2d():
    """A triangular-lattice block pulled apart by a kinematic top row: work, cracks, friction."""
    d = 0.01
    st = platen_block(triangular_lattice(12, 14, d), d, [0.01, 0.02], kn=1e7, ks=3e6,
                      xb=1e-4 * d, fs0=0.5, mu=0.5)
    sim = Simulation(st, backend="numba")
    sim.run(3000)
    e = sim.energies()
    assert e["work_external"] > 0
    assert sim.crack_log().size > 5
    assert e["closure_error"] < 0.005
