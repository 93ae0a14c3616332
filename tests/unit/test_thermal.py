"""The thermal field (geodem/fields/thermal.py) against hand-computed answers.

* conductance formula and the close-packed lattices' conductivity tensor (exactly k I);
* two elements: explicit-Euler decay of the temperature difference, rate h (1/C1 + 1/C2);
* the stability bound min C / sum h is the true limit of a symmetric pair;
* heat conserved in an insulated body (1e-12), maximum principle, fixed temperatures and ramps;
* unbonded contacts, open cracks; deposition of mechanical heat;
* thermal expansion R = R0 (1 + alpha (T - T_ref)) and the energy books of a heated block;
* checkpoint / resume bit-identical.
"""
import math

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice
from geodem.core import groups
from geodem.core.engine import Simulation
from geodem.fields import FIELDS, load_builtin
from geodem.fields.thermal import (
    ThermalField,
    conductance_pairs,
    contact_area,
    effective_conductivity,
    rod_solution,
)

K, C = 2.5, 900.0  # W/(m K), J/(kg K)


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def _pair(r1=0.005, r2=0.004, rho=2000.0):
    x = np.array([[0.0, 0.0], [r1 + r2, 0.0]])
    st = bonded_state(x, np.array([r1, r2]), density=rho, kn=1e6, ks=3e5, xb=1.0, fs0=1e6,
                      mu=0.3, gap=1e-9)
    return Simulation(st, backend="numba")


def _lattice2d(nx=8, ny=8, d=0.01, unbreakable=True):
    st = bonded_state(triangular_lattice(nx, ny, d), 0.5 * d, density=2600.0, kn=2e7, ks=6e6,
                      xb=1.0 if unbreakable else 2e-6, fs0=1e9 if unbreakable else 20.0,
                      mu=0.4, gap=1e-6 * d)
    return st


def test_registered_with_its_contract():
    load_builtin()
    assert FIELDS["thermal"] is ThermalField
    assert ThermalField.kind == "thermal"


def test_conductance_of_a_pair_by_hand():
    """2-D, no thickness given: A = (2/sqrt 3) r12 * 2 r12, r12 = 2 r1 r2/(r1 + r2),
    h = k A / L with L = r1 + r2."""
    sim = _pair()
    f = ThermalField(k=K, c=C)
    sim.add_field(f)
    r12 = 2 * 0.005 * 0.004 / 0.009
    h = K * (2 / math.sqrt(3)) * r12 * 2 * r12 / 0.009
    i, j, hh = conductance_pairs(sim, f)
    assert (i.tolist(), j.tolist()) == ([0], [1])
    assert hh[0] == pytest.approx(h, rel=1e-14)
    # the same from both rows, bit for bit (conservation needs it)
    assert f.hmat[0, 0] == f.hmat[1, 0]
    # 3-D face: sqrt(2) r^2 (the FCC rhombic-dodecahedron face d^2 / (2 sqrt 2))
    assert contact_area(0.5, 0.5, 3) == pytest.approx(0.5 ** 2 / (2 * math.sqrt(2)) * 4,
                                                      rel=1e-15)


@pytest.mark.parametrize("dim", [2, 3])
def test_close_packed_lattice_conducts_exactly_k(dim):
    """The conductivity tensor of an interior element, (1/(2V)) sum_j h_ij l_ij (x) l_ij, with V
    the Voronoi cell (2-D: sqrt(3)/2 d^2 t, t = d; 3-D: d^3/sqrt 2) is k I (module docstring)."""
    d = 0.01
    x = triangular_lattice(9, 9, d) if dim == 2 else fcc_lattice(6, 6, 6, d)
    st = bonded_state(x, 0.5 * d, density=2600.0, kn=2e7, ks=6e6, xb=1.0, fs0=1e9, mu=0.4,
                      gap=1e-6 * d)
    sim = Simulation(st, backend="numpy")  # the field's kernels are the same for every backend
    f = ThermalField(k=K, c=C)
    sim.add_field(f)
    f.stable_dt(sim)  # fills the conductances
    per = (st.cstate == 1).sum(axis=1)
    z = 6 if dim == 2 else 12
    interior = np.flatnonzero(per == z)
    assert interior.size > 5
    V = math.sqrt(3) / 2 * d * d * d if dim == 2 else d ** 3 / math.sqrt(2)
    for i in interior[:5]:
        js = st.nbr[i, :z]
        lvec = st.x[js] - st.x[i]
        kt = np.einsum("k,ka,kb->ab", f.hmat[i, :z], lvec, lvec) / (2 * V)
        assert np.allclose(kt, K * np.eye(dim), rtol=0, atol=1e-12 * K)


def test_two_elements_equilibrate_at_the_rate_h_times_sum_of_inverse_capacities():
    """C1 dT1/dt = h (T2 - T1), C2 dT2/dt = h (T1 - T2): the difference decays as
    exp(-h (1/C1 + 1/C2) t); forward Euler with sub-step s multiplies it by exactly
    1 - s h (1/C1 + 1/C2) per sub-step; the heat C1 T1 + C2 T2 is kept."""
    sim = _pair()
    st = sim.state
    f = ThermalField(k=K, c=C, T0=300.0, time_scale=1.0)
    sim.add_field(f)
    f.T[:] = [400.0, 300.0]
    c1, c2 = st.m * C
    h = conductance_pairs(sim, f)[2][0]
    rate = h * (1 / c1 + 1 / c2)
    lim = f.stable_dt(sim)
    assert lim == pytest.approx(min(c1, c2) / h, rel=1e-14)
    q0 = f.heat_content()
    span = 1.9 * lim  # 4 sub-steps of 0.475 lim
    n = f.advance(sim, span)
    assert n == 4
    assert f.T[0] - f.T[1] == pytest.approx(100.0 * (1 - span / n * rate) ** n, rel=1e-12)
    d1 = f.T[0] - f.T[1]
    span = 1e-3 / rate
    for _ in range(2000):
        f.advance(sim, span)
    assert f.time == pytest.approx(1.9 * lim + 2000 * span, rel=1e-12)
    # small sub-steps: the continuous answer, to the Euler error (a relative (rate s)^2 / 2 per
    # sub-step s: 1e-3 over these 2000)
    assert f.T[0] - f.T[1] == pytest.approx(d1 * math.exp(-rate * 2000 * span), rel=2e-3)
    assert f.T[0] - f.T[1] != pytest.approx(d1 * math.exp(-1.01 * rate * 2000 * span),
                                            rel=2e-3)
    assert f.heat_content() == pytest.approx(q0, rel=1e-14)


def test_stable_dt_is_the_stability_limit_of_a_symmetric_pair():
    """Equal elements: the difference is multiplied by 1 - 2 s h / C per step; the bound C/h
    is the step where this factor reaches -1: just below it decays, just above it grows."""
    sim = _pair(0.005, 0.005)
    f = ThermalField(k=K, c=C)
    sim.add_field(f)
    lim = f.stable_dt(sim)
    for factor, grows in ((0.99, False), (1.01, True)):
        f.T[:] = [301.0, 300.0]
        for _ in range(300):
            f.substep(sim, factor * lim, allow_unstable=True)
        assert (abs(f.T[0] - f.T[1]) > 1.0) == grows


def test_heat_is_conserved_in_an_insulated_body_and_no_new_extremes():
    st = _lattice2d()
    # an unbonded touching contact conducts with the factor, an open one not at all
    sim = Simulation(st, backend="numba")
    f = ThermalField(k=K, c=C, unbonded_factor=0.3, time_scale=1e7, every=1)
    sim.add_field(f)
    rng = np.random.default_rng(1)
    f.T[:] = 300.0 + 100.0 * rng.random(st.n)
    lo, hi = f.T.min(), f.T.max()
    q0 = f.heat_content()
    sim.run(300)
    assert f.substeps > 300
    assert abs(f.heat_content() - q0) <= 1e-12 * q0
    assert f.T.min() >= lo and f.T.max() <= hi
    assert np.ptp(f.T) < 0.5 * (hi - lo)  # it did conduct


def test_unbonded_contacts_and_open_cracks():
    """A touching unbonded contact conducts factor x the bond value, a broken bond that has
    opened does not conduct at all."""
    sim = _pair(0.005, 0.005)
    st = sim.state
    f = ThermalField(k=K, c=C, unbonded_factor=0.25)
    sim.add_field(f)
    h_bond = conductance_pairs(sim, f)[2][0]
    st.cstate[:, 0] = 0  # unbonded (the pair was built exactly touching)
    st.x[1, 0] -= 1e-7  # touching
    assert conductance_pairs(sim, f)[2][0] == pytest.approx(0.25 * h_bond, rel=1e-4)
    st.x[1, 0] += 2e-7  # apart: an open crack
    assert conductance_pairs(sim, f)[2].size == 0
    assert f.stable_dt(sim) == math.inf  # nothing conducts: any step is stable


def test_fixed_temperatures_are_held_and_ramped():
    st = _lattice2d(6, 6)
    groups.add_group(st, "hot", st.x[:, 0] < 0.005)
    sim = Simulation(st, backend="numba")
    f = ThermalField(k=K, c=C, T0=300.0, fixed={"hot": 500.0}, time_scale=1e6)
    sim.add_field(f)
    hot = groups.members(st, "hot")
    sim.run(100)
    assert np.all(f.T[hot] == 500.0)
    assert f.T.max() == 500.0 and f.T[f.fixed_mask == 0].max() > 300.0
    # replace by a ramp back down: linear in thermal time from 500 to 400 over `ramp` seconds
    span = 100 * sim.state.dt * 1e6
    f.set_fixed({"hot": 400.0}, ramp=2 * span)
    sim.run(100)
    assert np.allclose(f.T[hot], 450.0, rtol=0, atol=1e-9)
    sim.run(150)
    assert np.all(f.T[hot] == 400.0)


def test_expansion_changes_the_radius_by_alpha_dT():
    st = _lattice2d(5, 5)
    r0 = st.r.copy()
    sim = Simulation(st, backend="numba")
    alpha, tref = 1.2e-5, 293.15
    f = ThermalField(k=K, c=C, alpha=alpha, T_ref=tref, T0=tref, time_scale=1e5)
    sim.add_field(f)
    f.T[:] = tref + np.linspace(0.0, 200.0, st.n)
    sim.run(1)
    assert np.allclose(st.r, r0 * (1 + alpha * (f.T - tref)), rtol=1e-15, atol=0)
    k = np.argmax(f.T)
    assert st.r[k] / r0[k] - 1 == pytest.approx(alpha * (f.T[k] - tref), rel=1e-9)


def test_heated_bonded_block_keeps_the_energy_books_closed():
    """One side of a bonded block heated (ramp), expansion on, no damping: the elastic energy
    the expansion adds is booked as external work; the books close to < 1e-4 while that work
    is a large part of the energy in play."""
    st = _lattice2d(10, 10)
    groups.add_group(st, "hot", st.x[:, 0] < 0.005)
    sim = Simulation(st, backend="numba")
    f = ThermalField(k=3.0, c=800.0, alpha=1e-4, fixed={"hot": 600.0}, ramp=2000.0,
                     time_scale=1e5)
    sim.add_field(f)
    worst = 0.0
    for _ in range(4):
        sim.run(500)
        e = sim.energies()
        worst = max(worst, e["closure_error"])
    scale = e["kinetic"] + e["elastic"] + e["heat_total"]
    assert e["work_external"] > 0.5 * scale  # the booking matters
    assert worst < 1e-4
    assert f.T[groups.members(st, "hot")].min() > 340.0


def test_mechanical_heat_is_deposited_into_the_temperature():
    sim = _pair(0.005, 0.005)
    st = sim.state
    f = ThermalField(k=0.0, c=C, T0=300.0, deposit=["friction", "break_normal"])
    sim.add_field(f)
    st.q_fric[0] += 2.0
    st.q_break_n[1] += 0.5
    st.q_visc[1] += 7.0  # not deposited
    f.advance(sim, 1e-3)
    assert f.T[0] == pytest.approx(300.0 + 2.0 / (st.m[0] * C), rel=1e-15)
    assert f.T[1] == pytest.approx(300.0 + 0.5 / (st.m[1] * C), rel=1e-15)
    f.advance(sim, 1e-3)  # nothing new: nothing deposited
    assert f.T[0] == pytest.approx(300.0 + 2.0 / (st.m[0] * C), rel=1e-15)
    sim.reset_energy()  # books zeroed: only the heat after the reset counts
    st.q_fric[0] += 1.0
    f.advance(sim, 1e-3)
    assert f.T[0] == pytest.approx(300.0 + 3.0 / (st.m[0] * C), rel=1e-14)


def test_checkpoint_resume_is_bit_identical(tmp_path):
    st = _lattice2d(8, 8, unbreakable=False)
    groups.add_group(st, "hot", st.x[:, 0] < 0.005)
    a = Simulation(st, backend="numba")
    a.add_field(ThermalField(k=3.0, c=800.0, alpha=3e-5, fixed={"hot": 700.0}, ramp=500.0,
                             deposit=["break_normal", "break_shear", "friction"],
                             time_scale=1e5, every=3))
    a.run(301)
    a.save(tmp_path / "c.npz")
    b = Simulation.load(tmp_path / "c.npz", backend="numba")
    a.run(400)
    b.run(400)
    fa, fb = a.field("thermal"), b.field("thermal")
    assert fb.config() == fa.config()
    for name in ("T", "r0", "qlast", "fstart", "ftarget"):
        assert np.array_equal(getattr(fa, name), getattr(fb, name)), name
    assert fa.time == fb.time and fa.substeps == fb.substeps
    assert np.array_equal(a.state.x, b.state.x) and np.array_equal(a.state.props, b.state.props)
    assert np.array_equal(a.state.w_ext, b.state.w_ext)


def test_bad_parameters_name_the_parameter():
    for kw, word in (({"k": -1.0}, "conductivity"), ({"c": 0.0}, "specific heat"),
                     ({"T_ref": -5.0}, "T_ref"), ({"fixed": {"a": -1.0}}, "fixed"),
                     ({"deposit": ["magic"]}, "deposit"), ({"alpha": 0.5}, "alpha"),
                     ({"time_scale": 0.0}, "time_scale"), ({"k": float("nan")}, "conductivity")):
        args = {"k": K, "c": C, **kw}
        with pytest.raises(ValueError, match=word):
            ThermalField(**args)
    sim = _pair()
    with pytest.raises(ValueError, match="unknown group 'nowhere'"):
        sim.add_field(ThermalField(k=K, c=C, fixed={"nowhere": 400.0}))


def test_rod_series_limits():
    """t = 0: the initial temperature inside; t -> inf: the linear steady profile."""
    x = np.linspace(0.05, 0.95, 7)
    assert np.allclose(rod_solution(x, 0.0, 1.0, 1.0, 300.0, 400.0, 350.0, 20000), 300.0,
                       atol=0.2)
    assert np.allclose(rod_solution(x, 100.0, 1.0, 1.0, 300.0, 400.0, 350.0),
                       400.0 - 50.0 * x, atol=1e-9)


def test_effective_conductivity_of_a_lattice_strip():
    """A triangular-lattice block along x: steady flux between the end layers. The lattice
    conducts k in the bulk; the two surface rows conduct less (each has 4 bonds instead of 6),
    a deficit of 1/(3 n_rows) for heat along the rows: k_eff / k = (3n - 1)/(3n) over the
    cross-section n_rows x sqrt(3)/2 d (here measured over the centres' extent + d)."""
    d = 0.01
    nrow = 6
    st = bonded_state(triangular_lattice(30, nrow, d), 0.5 * d, density=2600.0, kn=2e7, ks=6e6,
                      xb=1.0, fs0=1e9, mu=0.4, gap=1e-6 * d)
    sim = Simulation(st, backend="numba")
    f = ThermalField(k=K, c=C)
    sim.add_field(f)
    out = effective_conductivity(sim, f, axis=0, layer=0.6 * d)
    height = (nrow - 1) * math.sqrt(3) / 2 * d + d
    expect = (3 * nrow - 1) / (3 * nrow) * nrow * math.sqrt(3) / 2 * d / height
    assert out["ratio"] == pytest.approx(expect, rel=0.02)


def test_deposit_given_as_one_string_is_one_name():
    from geodem.fields.thermal import ThermalField

    # before: iterated letter by letter ("deposit ['v', 'i', ...] unknown")
    assert ThermalField(k=3.0, c=800.0, deposit="viscous").deposit == ("viscous",)
    with pytest.raises(ValueError, match=r"deposit \['heat'\] unknown"):
        ThermalField(k=3.0, c=800.0, deposit="heat")
