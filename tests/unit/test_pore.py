"""The pore-density fluid field (geodem.fields.pore) on models small enough to compute by hand."""
import math

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.core.engine import Simulation
from geodem.core.state import new_state
from geodem.fields import FieldStabilityError
from geodem.fields.pore import OIL_CF, OIL_KF, PoreField, PoreFluidError

D = 0.01
H = math.sqrt(3.0) / 2.0 * D


def _fixed_sim(x, r, backend="numpy", dt=1e-5):
    st = new_state(np.asarray(x, float), r=r, m=1.0, kn=1e6)
    st.free[:] = 0.0
    return Simulation(st, backend=backend, dt=dt)


def _rhombus():
    """Four touching discs: two equilateral triangles sharing the edge 0-1."""
    return [[0.0, 0.0], [D, 0.0], [0.5 * D, H], [0.5 * D, -H]]


def _tri_volume(t, ap):
    """Pore of an equilateral cell of side D between discs of radius D/2, thickness t:
    area minus three 60-degree sectors, plus the film ap x (three arcs of length pi/3 r)."""
    r = 0.5 * D
    return t * (math.sqrt(3) / 4 * D * D - 3 * (math.pi / 3) * r * r / 2 + ap * math.pi * r)


def test_two_pores_one_throat_network_and_hand_computed_geometry():
    sim = _fixed_sim(_rhombus(), 0.5 * D)
    f = PoreField(k_t=2e-6, aperture=1e-5, thickness=0.004, gap_reference="zero", p_min=None)
    sim.add_field(f)
    assert f.cells.shape == (2, 3) and f.tp.shape == (1, 2)
    assert sorted(f.te[0, 0].tolist()) == [0, 1]
    np.testing.assert_allclose(f.V, _tri_volume(0.004, 1e-5), rtol=1e-12)
    # throat: touching pair (gap 0), path = distance of the centroids = 2 H / 3
    C = 2e-6 * 1e-5 / (2 * H / 3)
    assert f.C[0] == pytest.approx(C, rel=1e-12)
    # stable step: V k_f / sum C (both pores alike)
    assert f.stable_dt(sim) == pytest.approx(f.V[0] * f.k_f / C, rel=1e-12)


def test_equation_of_state_and_pressure_floor():
    sim = _fixed_sim(_rhombus(), 0.5 * D)
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, p_init=3e6, p_min=0.0)
    sim.add_field(f)
    V = f.V[0]
    assert f.M[0] == pytest.approx(V * (OIL_KF * 3e6 + OIL_CF), rel=1e-14)
    f.M[:] = V * np.array([OIL_CF + OIL_KF * 7.5e6, OIL_CF - OIL_KF * 2e6])
    P = f.update_pressure()
    assert P[0] == pytest.approx(7.5e6, rel=1e-10)
    assert P[1] == 0.0  # below the floor: the pore is not full, it holds p_min
    f.p_min = None
    assert f.update_pressure()[1] == pytest.approx(-2e6, rel=1e-8)


def test_two_pores_equilibrate_exponentially_at_rate_from_conductance_and_storage():
    dt = 1e-5
    sim = _fixed_sim(_rhombus(), 0.5 * D, dt=dt)
    f = PoreField(k_t=2e-6, aperture=1e-5, gap_reference="zero", p_min=None)
    sim.add_field(f)
    S = f.V * f.k_f  # storage dM/dP [kg/Pa]
    lam = f.C[0] * (1.0 / S[0] + 1.0 / S[1])  # d(dP)/dt = -lam dP
    # choose the conductance so that lam dt = 0.01 (one sub-step per mechanical step)
    f.kt *= 0.01 / (lam * dt)
    f._geom_key = None
    lam = 0.01 / dt
    f.M[:] = f.V * (f.k_f * np.array([2.0e6, 0.0]) + f.c_f)
    m0 = f.mass
    sim.run(200)
    assert f.substeps == 200
    P = f.update_pressure()
    dp = P[0] - P[1]
    assert dp == pytest.approx(2.0e6 * (1.0 - lam * dt) ** 200, rel=1e-9)  # explicit Euler
    assert dp == pytest.approx(2.0e6 * math.exp(-lam * 200 * dt), rel=0.015)  # the ODE
    assert P.mean() == pytest.approx(1.0e6, rel=1e-9)  # equal storage: the mean is kept
    assert abs(f.mass - m0) <= 1e-14 * m0


def _triangle_sim():
    x = [[0.0, 0.0], [1.05 * D, 0.001 * D], [0.4 * D, 0.92 * D]]
    r = np.array([0.5, 0.45, 0.55]) * D
    return _fixed_sim(x, r), np.asarray(x), r


def test_pressure_forces_on_one_cell_close_and_equal_p_chord_t():
    sim, x, r = _triangle_sim()
    f = PoreField(thickness=0.003)
    sim.add_field(f)
    assert f.cells.shape == (1, 3)
    f.P[:] = 4.0e6
    F = f.pressure_forces(sim)
    scale = 4e6 * 0.003 * D
    assert np.abs(F.sum(axis=0)).max() < 1e-12 * scale

    def q(a, b):  # contact point: the middle of the gap between a and b
        e = x[b] - x[a]
        L = np.linalg.norm(e)
        return x[a] + (L + r[a] - r[b]) / (2 * L) * e

    c = x.mean(axis=0)
    for a in range(3):
        b, o = [k for k in range(3) if k != a]
        chord = q(a, b) - q(a, o)
        assert np.linalg.norm(F[a]) == pytest.approx(4e6 * 0.003 * np.linalg.norm(chord),
                                                     rel=1e-12)
        assert abs(F[a] @ chord) < 1e-12 * scale  # normal to the chord
        assert F[a] @ (x[a] - c) > 0  # pushes the element away from the pore


def test_tetrahedron_pore_volume_and_closed_forces():
    a = D
    x = np.array([[0, 0, 0], [a, 0, 0], [a / 2, a * math.sqrt(3) / 2, 0],
                  [a / 2, a * math.sqrt(3) / 6, a * math.sqrt(2.0 / 3.0)]])
    sim = _fixed_sim(x, 0.5 * a)
    f = PoreField(aperture=0.0, k_t=1e-6)  # no throat: k_t unused, but required
    sim.add_field(f)
    assert f.cells.shape == (1, 4)
    omega = 3 * math.acos(1.0 / 3.0) - math.pi  # solid angle at a vertex of a regular tet
    v_tet = a ** 3 / (6 * math.sqrt(2))
    assert f.V[0] == pytest.approx(v_tet - 4 * omega * (a / 2) ** 3 / 3, rel=1e-12)
    f.P[:] = 1e6
    F = f.pressure_forces(sim)
    assert np.abs(F.sum(axis=0)).max() < 1e-12 * 1e6 * a * a
    # by symmetry each force points from the centre to its vertex, magnitude P x (area of the
    # three quads of the vertex) = P x (1/3 of the opposite face's area) (closure + symmetry)
    c = x.mean(axis=0)
    for i in range(4):
        u = (x[i] - c) / np.linalg.norm(x[i] - c)
        np.testing.assert_allclose(F[i], 1e6 * math.sqrt(3) / 4 * a * a / 3 * u, rtol=1e-10,
                                   atol=1e-12 * 1e6 * a * a)


def test_a_sliver_flipped_by_a_hair_is_no_inside_out_cell():
    """A near-flat tetrahedron (a sliver of a jittered lattice) whose apex crosses its base by
    less than INVERTED_REL d^3 of volume stays a pore of its absolute volume; crossed further,
    the cell is inside out (and the field rebuilds its network)."""
    from geodem.fields.pore import INVERTED_REL, _geom3

    a = D
    x = np.array([[0, 0, 0], [a, 0, 0], [0, a, 0], [0.3 * a, 0.3 * a, 0.0]])
    cells = np.array([[0, 1, 2, 3]])
    r = np.full(4, 0.5 * a)
    V, cen = np.zeros(1), np.zeros((1, 3))
    tol = INVERTED_REL * a ** 3
    for h, inverted in ((1e-4, False), (-1e-4, False), (-5.0 * INVERTED_REL, False),
                        (-7.0 * INVERTED_REL, True), (-0.3, True)):
        x[3, 2] = h * a  # signed volume a^3 h / 6: the apex below the base turns it inside out
        assert _geom3(x, r, cells, 0.0, 0.01, V, cen, tol) == int(inverted), h
        assert V[0] == pytest.approx(0.01 * a ** 3 * abs(h) / 6.0, rel=1e-9)  # floor x |vol|


def test_uniform_pressure_gives_no_net_force_on_an_interior_element():
    x = triangular_lattice(7, 7, D)
    sim = _fixed_sim(x, 0.5 * D)
    f = PoreField()
    sim.add_field(f)
    f.P[:] = 2e6
    F = f.pressure_forces(sim)
    inner = 3 * 7 + 3  # element in the middle: surrounded by six pores
    assert np.abs(F[inner]).max() < 1e-9 * 2e6 * D * D
    assert np.abs(F.sum(axis=0)).max() < 1e-9 * 2e6 * D * D * 10


def _bonded_lattice(nx=12, ny=10, jitter=0.0, seed=0, kn=2e8):
    rng = np.random.default_rng(seed)
    x = triangular_lattice(nx, ny, D) + rng.uniform(-jitter, jitter, (nx * ny, 2)) * D
    return bonded_state(x, 0.5 * D, density=2500.0, kn=kn, ks=0.4 * kn, xb=1e-3 * D,
                        fs0=1e4, mu=0.5, gap=0.2 * D)


def test_closed_system_conserves_fluid_mass_across_network_updates():
    st = _bonded_lattice(jitter=0.15, seed=3)
    rng = np.random.default_rng(1)
    st.v[:] = rng.normal(0.0, 0.05, st.v.shape)
    sim = Simulation(st, backend="numba")
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, p_init=1e5, k_t=1e-7, remesh_every=7, every=2)
    sim.add_field(f)
    m0 = f.mass
    sim.run(60)
    assert f.remeshes >= 4
    assert abs(f.mass - m0) <= 1e-10 * m0
    # a large, uneven deformation: the triangulation flips; the remap keeps every kilogram
    st.x += rng.uniform(-0.2, 0.2, st.x.shape) * D
    rep = f.remesh(sim)
    assert rep["lost"] > 0 and rep["new"] > 0
    assert abs(f.mass - m0) <= 1e-10 * m0
    assert f.mass_balance_error() <= 1e-10
    assert np.all(f.M > 0)


def test_injection_and_drain_books_close():
    st = _bonded_lattice(16, 6)
    st.free[:] = 0.0
    sim = Simulation(st, backend="numba")
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-4, bond_factor=1.0, every=10,
                  bcs=[{"name": "in", "role": "inject", "where": {"side": "xmin"},
                        "pressure": 2e6},
                       {"name": "out", "role": "drain", "where": {"side": "xmax"},
                        "pressure": 0.0}])
    sim.add_field(f)
    assert f.bc_pores("in").size > 0 and f.bc_pores("out").size > 0
    sim.run(3000)
    assert f.injected > 0 and f.drained > 0
    assert f.mass_balance_error() < 1e-12
    assert f.update_pressure()[f.bc_pores("in")].min() == pytest.approx(2e6, rel=1e-12)


def test_pressure_ramp_schedule():
    sim = _fixed_sim(_rhombus(), 0.5 * D)
    f = PoreField(bcs=[{"name": "inj", "where": {"ball": [0.5 * D, 0.3 * D, 0.2 * D]},
                        "pressure": 1e6, "rate": 1e9, "p_max": 3e6, "t_start": 1e-3}])
    sim.add_field(f)
    assert f.bc_pressure("inj", 0.0) == 1e6
    assert f.bc_pressure("inj", 1.5e-3) == pytest.approx(1.5e6)
    assert f.bc_pressure("inj", 1.0) == 3e6
    f.set_bc("inj", rate=0.0)
    assert f.config()["bcs"][0]["rate"] == 0.0


def test_forces_go_into_fload_as_a_delta_and_energy_books_stay_closed():
    def run(frac):
        st = _bonded_lattice(10, 8)
        st.fload[5] = [3.0, -2.0]  # a user load must survive
        sim = Simulation(st, backend="numba")
        sim = Simulation(st, backend="numba", dt=st.dt * frac)
        f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6,
                      bcs=[{"name": "inj", "where": {"ball": [0.05, 0.04, 0.012]},
                            "pressure": 5e5}])
        sim.add_field(f)
        sim.run(int(round(400 / frac)))
        user = np.zeros_like(st.fload)
        user[5] = [3.0, -2.0]
        np.testing.assert_allclose(st.fload - f.f_prev, user, atol=1e-9)
        assert np.abs(f.f_prev).max() > 0
        e = sim.energies()
        assert e["work_external"] > 0.5 * (e["kinetic"] + e["elastic"])  # the fluid did it
        return e["closure_error"]

    # the pressure is switched on at once (a step load): the books close to the O(dt^2) of
    # velocity Verlet, and halving dt divides the residual by ~4
    e1, e2 = run(1.0), run(0.5)
    assert e1 < 5e-3
    assert e1 / e2 > 3.5


def test_checkpoint_resume_is_bit_identical(tmp_path):
    def make():
        st = _bonded_lattice(10, 8, jitter=0.05)
        sim = Simulation(st, backend="numba")
        sim.add_field(PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6, remesh_every=9,
                                bcs=[{"name": "inj", "where": {"ball": [0.05, 0.04, 0.012]},
                                      "pressure": 1e5, "rate": 1e9, "t_start": 0.0}]))
        return sim

    a = make()
    a.run(25)
    a.save(tmp_path / "c.npz")
    b = Simulation.load(tmp_path / "c.npz", backend="numba")
    a.run(40)
    b.run(40)
    fa, fb = a.field("pore_fluid"), b.field("pore_fluid")
    assert np.array_equal(fa.M, fb.M) and np.array_equal(fa.cells, fb.cells)
    assert np.array_equal(a.state.x, b.state.x) and np.array_equal(a.state.fload, b.state.fload)
    assert fa.injected == fb.injected and fa.substeps == fb.substeps


def test_stiff_fluid_in_a_soft_solid_is_refused_with_the_bound():
    st = _bonded_lattice(8, 6, kn=1e6)
    sim = Simulation(st, backend="numpy")
    with pytest.raises(FieldStabilityError, match="pore_fluid.*stability bound"):
        sim.add_field(PoreField())  # water: K = 2.2 GPa
    sim2 = Simulation(_bonded_lattice(8, 6, kn=1e6), backend="numpy")
    sim2.add_field(PoreField(k_f=OIL_KF, c_f=OIL_CF))  # MatDEM's oil is soft enough


@pytest.mark.parametrize("kw, what", [
    ({"k_f": 0.0}, "k_f"), ({"k_f": -1.0}, "k_f"), ({"c_f": 0.0}, "c_f"),
    ({"bcs": [{"where": {"boundary": True}, "pressure": -5.0}]}, "pressure"),
    ({"bcs": [{"where": {"nowhere": 1}}]}, "where"),
    ({"bcs": [{"where": {"boundary": True}, "role": "suck"}]}, "role"),
    ({"bond_factor": 0.5}, "bond_factor"), ({"p_init": -1.0}, "p_init"),
])
def test_bad_parameters_are_refused_naming_the_field(kw, what):
    with pytest.raises(PoreFluidError, match=f"pore_fluid.*{what}"):
        PoreField(**kw)


def test_unknown_group_is_refused_naming_the_field():
    sim = _fixed_sim(_rhombus(), 0.5 * D)
    with pytest.raises(PoreFluidError, match="pore_fluid.*group 'rock'"):
        sim.add_field(PoreField(group="rock"))
    with pytest.raises(PoreFluidError, match="pore_fluid.*group 'wall'"):
        sim.add_field(PoreField(bcs=[{"where": {"group": "wall"}}]))


def test_three_d_network_conserves_mass_and_closes_forces():
    from geodem.build.lattice import fcc_lattice

    rng = np.random.default_rng(0)
    x = fcc_lattice(4, 4, 4, D) + rng.uniform(-0.1, 0.1, (64, 3)) * D
    st = bonded_state(x, 0.5 * D, density=2500.0, kn=2e8, ks=8e7, xb=1e-3 * D, fs0=1e4,
                      mu=0.5, gap=0.2 * D)
    st.v[:] = rng.normal(0.0, 0.05, st.v.shape)
    sim = Simulation(st, backend="numba")
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, p_init=1e5, k_t=1e-7, remesh_every=4,
                  bcs=[{"name": "inj", "where": {"ball": [0.015, 0.015, 0.015, 0.006]},
                        "pressure": 3e5}])
    sim.add_field(f)
    assert f.cells.shape[1] == 4 and f.te.shape[1:] == (3, 2) and np.all(f.V > 0)
    sim.run(20)
    assert f.remeshes >= 4
    assert f.mass_balance_error() < 1e-12 and f.injected != 0.0
    F = f.pressure_forces(sim)
    assert np.abs(F.sum(axis=0)).max() < 1e-10 * np.abs(F).max()
    st.x += rng.uniform(-0.15, 0.15, st.x.shape) * D
    rep = f.remesh(sim)
    assert rep["lost"] > 0 and f.mass_balance_error() < 1e-12


@pytest.mark.parametrize("dim", [2, 3])
def test_resume_with_thermal_expansion_is_bit_identical(tmp_path, dim):
    """Thermal expansion changes the radii before the checkpoint: on resume the pore field
    keeps the mean diameter, thickness, aperture and k_t of its first attach."""
    from geodem.build.lattice import fcc_lattice
    from geodem.core import groups
    from geodem.fields.thermal import ThermalField

    def make():
        rng = np.random.default_rng(0)
        x = triangular_lattice(10, 8, D) if dim == 2 else fcc_lattice(4, 3, 3, D)
        x = x + rng.uniform(-0.05, 0.05, x.shape) * D
        st = bonded_state(x, 0.5 * D, density=2500.0, kn=2e8, ks=8e7, xb=1e-4 * D, fs0=1e2,
                          mu=0.5, gap=0.2 * D)
        groups.add_group(st, "hot", st.x[:, 0] < st.x[:, 0].min() + 0.5 * D)
        sim = Simulation(st, backend="numba")
        sim.add_field(ThermalField(k=3.0, c=800.0, alpha=2e-4, fixed={"hot": 700.0}, ramp=5.0,
                                   unbonded_factor=0.3, time_scale=1e4))
        sim.add_field(PoreField(k_f=OIL_KF, c_f=OIL_CF, remesh_every=7,
                                bcs=[{"name": "inj", "where": {"group": "hot"},
                                      "pressure": 1e5, "rate": 1e9}]))
        return sim

    a = make()
    a.run(100)
    assert a.state.r.mean() > 0.5 * D * (1 + 1e-4)  # expanded before the checkpoint
    a.save(tmp_path / "c.npz")
    b = Simulation.load(tmp_path / "c.npz", backend="numba")
    fa, fb = a.field("pore_fluid"), b.field("pore_fluid")
    assert (fb.d_mean, fb.t, fb.ap, fb.kt) == (fa.d_mean, fa.t, fa.ap, fa.kt)
    assert fb.d_mean == pytest.approx(D, rel=1e-12)
    assert fb.ap == pytest.approx(0.002 * D, rel=1e-12)
    a.run(200)
    b.run(200)
    assert np.array_equal(a.state.x, b.state.x) and np.array_equal(a.state.v, b.state.v)
    assert np.array_equal(fa.M, fb.M) and np.array_equal(fa.cells, fb.cells)
    assert np.array_equal(a.field("thermal").T, b.field("thermal").T)
    assert len(a.cracks["i"]) == len(b.cracks["i"])


def _fcc_state(jitter=0.0):
    from geodem.build.lattice import fcc_lattice

    x = fcc_lattice(4, 3, 3, D)
    x = x + np.random.default_rng(0).uniform(-jitter, jitter, x.shape) * D
    return bonded_state(x, 0.5 * D, density=2500.0, kn=2e8, ks=8e7, xb=1e-3 * D, fs0=1e4,
                        mu=0.5, gap=0.2 * D)


def test_flat_cells_of_a_regular_lattice_are_refused_as_a_degenerate_network():
    # cospherical FCC centres: qhull leaves zero-volume tetrahedra inside the packing (before:
    # a stability bound of 4.8e-14 s, or a ZeroDivisionError with aperture = 0)
    with pytest.raises(PoreFluidError, match="pore_fluid.*degenerate: 2 cells inside the "
                                             "packing are flat.*jitter"):
        Simulation(_fcc_state()).add_field(PoreField(k_f=OIL_KF, c_f=OIL_CF))
    sim = Simulation(_fcc_state(jitter=0.01))  # a jittered lattice: every pore has volume
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF)
    sim.add_field(f)
    assert f.V.min() > 0.0 and f.mechanical_dt_bound(sim) > sim.state.dt


def test_aperture_zero_needs_an_explicit_k_t():
    with pytest.raises(PoreFluidError, match="aperture = 0 without k_t.*give k_t > 0"):
        PoreField(aperture=0.0)
    assert PoreField(aperture=0.0, k_t=1e-6).k_t == 1e-6


@pytest.mark.parametrize("where, what", [
    ({"ball": [0.0, 0.0, float("nan")]}, r"ball = \[0.0, 0.0, nan\]; allowed: finite"),
    ({"ball": [0.0, 0.0, -1.0]}, "ball radius = -1.0; allowed: > 0"),
    ({"box": [[0.0, 0.0], [float("inf"), 1.0]]}, "box = .*allowed: finite"),
    ({"box": [[0.0, 1.0], [1.0, 0.0]]}, "box = .*lo <= hi"),
])
def test_bad_ball_and_box_numbers_are_refused(where, what):
    with pytest.raises(PoreFluidError, match=f"pore_fluid.*bcs\\[0\\] \\(out\\): {what}"):
        PoreField(bcs=[{"name": "out", "role": "drain", "where": where}])


def test_a_boundary_condition_selecting_no_pore_is_refused():
    from geodem.core import groups

    st = _bonded_lattice(8, 6)
    groups.add_group(st, "empty", np.zeros(st.n, bool))
    for where in ({"group": "empty"}, {"ball": [5.0, 5.0, 0.001]}):
        with pytest.raises(PoreFluidError, match="pore_fluid.*condition 'd'.*selects no pore"):
            Simulation(st).add_field(PoreField(k_f=OIL_KF, c_f=OIL_CF, bcs=[
                {"name": "d", "role": "drain", "where": where}]))


def test_number_types_booleans_and_whole_numbers():
    f = PoreField(k_f=np.float32(OIL_KF), c_f=np.float32(870.0), remesh_every=np.int64(3),
                  bcs=[{"where": {"boundary": True}, "pressure": np.float32(2.0)}])
    assert f.k_f == float(np.float32(OIL_KF)) and f.remesh_every == 3
    assert f.bcs[0]["pressure"] == 2.0
    with pytest.raises(PoreFluidError, match=r"bcs\[0\] \(bc0\): pressure = True; allowed"):
        PoreField(bcs=[{"where": {"boundary": True}, "pressure": True}])
    for v in (1.5, float("nan"), -1):
        with pytest.raises(PoreFluidError, match="remesh_every = .*allowed: a whole number >= 0"):
            PoreField(remesh_every=v)


def _network_run(dim, parallel_min, threads, monkeypatch):
    """A jittered bonded lattice with injection, stepped 12 times with remeshes; the arrays a
    threaded pass writes, afterwards."""
    import numba

    from geodem.build.lattice import fcc_lattice
    from geodem.fields import pore

    monkeypatch.setattr(pore, "PARALLEL_MIN", parallel_min)
    rng = np.random.default_rng(3)
    x = triangular_lattice(12, 10, D) if dim == 2 else fcc_lattice(5, 4, 4, D)
    x = x + rng.uniform(-0.1, 0.1, x.shape) * D
    st = bonded_state(x, 0.5 * D, density=2500.0, kn=2e8, ks=8e7, xb=1e-3 * D, fs0=1e4,
                      mu=0.5, gap=0.2 * D)
    st.v[:] = rng.normal(0.0, 0.05, st.v.shape)
    sim = Simulation(st, backend="numba")
    centre = [float(v) for v in st.x.mean(axis=0)]
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, p_init=1e5, k_t=1e-7, remesh_every=5,
                  bcs=[{"name": "inj", "where": {"ball": centre + [0.8 * D]},
                        "pressure": 3e5}])
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        sim.add_field(f)
        sim.run(12)
        threaded = f._threaded()
    finally:
        numba.set_num_threads(before)
    assert threaded == (parallel_min == 0) and f.remeshes >= 2
    s = sim.sync()
    return [np.array(a) for a in (s.x, s.v, s.a, s.fload, f.M, f.P, f.V, f.cen, f.C, f.csum)]


@pytest.mark.parametrize("dim", [2, 3])
def test_threaded_pore_passes_give_the_serial_bits_at_any_thread_count(dim, monkeypatch):
    """Volumes, conductances and (3-D) pressure forces over the threads sum in the serial
    order: the same bits as one thread, whatever the thread count."""
    import numba

    most = min(3, numba.config.NUMBA_NUM_THREADS)
    if most < 2:
        pytest.skip("one numba thread: nothing runs over threads")
    serial = _network_run(dim, 10 ** 12, 1, monkeypatch)
    for threads in range(2, most + 1):
        threaded = _network_run(dim, 0, threads, monkeypatch)
        for a, b in zip(serial, threaded):
            assert a.tobytes() == b.tobytes()


def test_cells_of_two_networks_are_matched_by_their_vertex_sets():
    f = PoreField.__new__(PoreField)
    old = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 5]])
    new = np.array([[3, 2, 1], [0, 1, 4], [5, 2, 3], [0, 2, 1]])
    old_of_new, new_of_old = f._match(old, new)
    assert old_of_new.tolist() == [1, -1, 2, 0]
    assert new_of_old.tolist() == [3, 0, 2]
