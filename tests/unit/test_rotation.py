"""Rotational degrees of freedom (option): hand-computed rolling results, backend agreement,
energy books, rebuilds and checkpoints."""
import math

import numpy as np
import pytest

from geodem.core import neighbors
from geodem.core.engine import Simulation
from geodem.core.law import rolling
from geodem.core.state import enable_rotation, new_state
from tests.conftest import make_specimen, run_in_cuda_simulator, step_backends

pytestmark = pytest.mark.usefixtures("one_numba_thread")

R = 1e-3  # disc radius [m]
RF = 1.0  # floor: one fixed element this large, flat over the travel
M = 1e-3  # disc mass [kg]
G = 10.0


def disc_on_floor(dim, v0, w0=0.0, mu=0.5, mu_r=0.0, kn=1e5):
    """A free element resting on a huge fixed one, launched along +x at ``v0`` spinning at
    ``w0`` (about z)."""
    x = np.zeros((2, dim))
    x[0, 1] = R - M * G / kn  # resting overlap m g / kn
    x[1, 1] = -RF
    st = new_state(x, [R, RF], [M, 1e3], kn=kn, ks=0.5 * kn, mu=mu, width=4)
    st.free[1] = 0.0
    st.gravity[1] = -G
    neighbors.build_rows(st, skin=0.2 * R)
    enable_rotation(st, mu_r=mu_r)
    st.v[0, 0] = v0
    st.w[0, -1] = w0
    return st


@pytest.mark.parametrize("dim, k_inertia", [(2, 0.5), (3, 0.4)])
def test_sliding_element_ends_rolling_at_the_analytic_speed(dim, k_inertia):
    """A disc (sphere) launched sliding without spin: friction slows it and spins it up until it
    rolls at v0 / (1 + I/(m R^2)) = 2/3 v0 (5/7 v0), after t = v0 k/((1+k) mu g)."""
    v0, mu = 0.05, 0.5
    st = disc_on_floor(dim, v0, mu=mu)
    sim = Simulation(st, backend="numba")
    t_roll = v0 * k_inertia / ((1 + k_inertia) * mu * G)
    sim.run(int(3 * t_roll / st.dt))
    # the undamped shear spring rings (+-1 %) about the rolling state: average ~20 periods
    v, w = [], []
    for _ in range(200):
        sim.run(1)
        v.append(st.v[0, 0])
        w.append(st.w[0, -1])
    v_end = v0 / (1.0 + k_inertia)
    assert np.mean(v) == pytest.approx(v_end, rel=2e-3)
    # rolling without slip: v = -w R (spin about -z for travel along +x)
    assert -np.mean(w) * R == pytest.approx(v_end, rel=2e-3)
    # friction heat = the kinetic energy lost
    e = sim.energies()
    ke_lost = 0.5 * M * v0 ** 2 - e["kinetic"]
    assert e["heat_friction"] == pytest.approx(ke_lost, rel=0.02)
    assert e["closure_error"] < 1e-3


def test_rolling_resistance_stops_a_rolling_disc_at_the_analytic_distance():
    """A disc rolling at v0 under the moment mu_r R* m g decelerates at
    a = mu_r (R*/R) g / (1 + I/(m R^2)) and stops after v0^2 / (2 a)."""
    v0, mu_r = 0.02, 0.1
    st = disc_on_floor(2, v0, w0=-v0 / R, mu_r=mu_r)
    sim = Simulation(st, backend="numba")
    rs = R * RF / (R + RF)
    a = mu_r * (rs / R) * G / 1.5
    t_stop = v0 / a
    x0 = st.x[0, 0]
    sim.run(int(0.5 * t_stop / st.dt))
    assert st.v[0, 0] == pytest.approx(v0 - a * 0.5 * t_stop, rel=0.01)
    sim.run(int(1.0 * t_stop / st.dt))
    assert abs(st.v[0, 0]) < 0.02 * v0
    assert st.x[0, 0] - x0 == pytest.approx(v0 ** 2 / (2 * a), rel=0.02)
    assert sim.energies()["closure_error"] < 1e-3


def test_translation_only_is_unchanged_without_rotation():
    st = disc_on_floor(2, 0.05)
    st2 = st.copy()
    for k in ("w", "wa", "dth", "rfree", "inertia", "mr"):
        setattr(st2, k, None)
    assert not st2.rotation and st.rotation
    x0 = st2.x[0, 0]
    Simulation(st2, backend="numba").run(2000)
    # no rotation (MatDEM): the element slides until friction stops it, after v0^2/(2 mu g)
    assert abs(st2.v[0, 0]) < 0.02 * 0.05  # what is left is the ringing shear spring
    assert st2.x[0, 0] - x0 == pytest.approx(0.05 ** 2 / (2 * 0.5 * G), rel=0.02)


@pytest.mark.parametrize("dim", [2, 3])
def test_held_rotation_is_translation(dim):
    """Elements given rotational freedom and then held from turning (a translating material
    beside turning ones, geodem.workflow.material.apply_material_rotation) move as
    translating elements: the same bonds break and the positions agree to rounding, with
    moment-resisting bonds and a stiff rolling spring switched on."""
    base = make_specimen(n=200, dim=dim)
    held = base.copy()
    enable_rotation(held, mu_r=0.1, bond_moment=100.0, rolling_stiffness=8.0)
    held.rfree[:] = 0.0
    sims = [Simulation(s, backend="numba") for s in (base, held)]
    for sim in sims:
        sim.run(60)
    assert np.array_equal(base.cstate, held.cstate)
    assert int((base.cstate == 0).sum()) > int((make_specimen(n=200, dim=dim).cstate
                                                == 0).sum())  # bonds broke on the way
    assert np.all(held.w == 0.0)
    assert rel_diff(base, held, "x") < 1e-12 and rel_diff(base, held, "v") < 1e-9
    turning = make_specimen(n=200, dim=dim)  # the same elements free to turn move otherwise
    enable_rotation(turning, mu_r=0.1, bond_moment=100.0, rolling_stiffness=8.0)
    Simulation(turning, backend="numba").run(60)
    assert rel_diff(base, turning, "v") > 0.1


def test_rolling_law_by_hand():
    # 2-D (about z): elastic, then capped at lim with the slip heat
    mx, my, mz, q = rolling(1.0, 0.0, 0.0, 0.0, 0.0, 2e-3, 0.0, 0.0, 0.1, 100.0, 1.0)
    assert (mx, my) == (0.0, 0.0) and mz == pytest.approx(0.1 - 0.2) and q == 0.0
    mx, my, mz, q = rolling(1.0, 0.0, 0.0, 0.0, 0.0, 2e-2, 0.0, 0.0, 0.5, 100.0, 1.0)
    # trial 0.5 - 2 = -1.5 -> capped at -1; heat (0.5 - 1) (-1.5 + 1) / (2 x 100)
    assert mz == pytest.approx(-1.0) and q == pytest.approx((0.5 - 1.0) * (-0.5) / 200.0)
    # 3-D: twist (along n) is dropped and its energy booked; apart (lim 0) holds nothing
    mx, my, mz, q = rolling(0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 100.0, 1.0)
    assert (mx, my, mz) == (0.0, 0.0, 0.0) and q == pytest.approx(0.09 / 200.0)
    mx, my, mz, q = rolling(0.0, 0.0, 1.0, 1e-3, 0.0, 0.0, 0.2, 0.0, 0.0, 100.0, 0.0)
    assert (mx, my, mz) == (0.0, 0.0, 0.0)
    assert q == pytest.approx(0.2 * (0.2 - 0.1) / 200.0)


def rel_diff(a, b, name):
    """Largest difference of array ``name`` of two states, relative to its largest value."""
    x, y = getattr(a, name), getattr(b, name)
    return float(np.abs(x - y).max() / max(np.abs(x).max(), np.abs(y).max(), 1e-300))


def _rotating_specimen(n, dim, seed=1):
    st = make_specimen(n=n, dim=dim)
    enable_rotation(st, mu_r=0.05)
    rng = np.random.default_rng(seed)
    st.w[:] = rng.normal(0.0, 50.0, st.w.shape)
    st.gravity[1] = -9.81
    return st


def numba_against_numpy(base, fields, steps=8):
    """Step ``base`` on numba and on the NumPy reference: the same bond decisions (more than
    five bonds broken) and every array of ``fields`` within 1e-12. Returns numba's state."""
    out = step_backends(base, ("numba", "numpy"), steps)
    a, b = out["numba"][0], out["numpy"][0]
    assert np.array_equal(a.cstate, b.cstate)
    assert len(out["numba"][1]) == len(out["numpy"][1]) > 5
    for k in fields:
        assert rel_diff(a, b, k) <= 1e-12, k
    return a


@pytest.mark.parametrize("dim", [2, 3])
def test_numba_matches_numpy_with_rotation(dim):
    a = numba_against_numpy(_rotating_specimen(300, dim),
                            ("x", "v", "a", "fs", "w", "wa", "mr", "q_visc", "q_fric", "w_ext"))
    assert np.abs(a.mr).max() > 0.0 and np.abs(a.w).max() > 0.0


@pytest.mark.parametrize("dim", [2, 3])
def test_numba_matches_numpy_with_moment_bonds(dim):
    st = _rotating_specimen(300, dim)
    st.bond_moment[:] = np.linspace(0.2, 0.8, st.n)  # the pair's smaller value counts
    a = numba_against_numpy(st, ("x", "v", "a", "fs", "w", "wa", "mr", "q_visc", "q_fric",
                                 "w_ext"))
    assert np.abs(a.mr).max() > 0.0


@pytest.mark.parametrize("dim", [2, 3])
def test_numba_matches_numpy_with_rolling_stiffness(dim):
    st = _rotating_specimen(300, dim)
    st.bond_moment[:] = 100.0
    st.rolling_stiffness[:] = np.linspace(0.5, 4.0, st.n)  # the pair's smaller value counts
    a = numba_against_numpy(st, ("x", "v", "a", "fs", "w", "wa", "mr", "q_visc", "q_fric",
                                 "w_ext"))
    assert np.abs(a.mr).max() > 0.0


def turned_bond(bond_moment, steps, kn=1e5, xb=1e-5, beta=1.0):
    """Two touching bonded discs, both held in place; the second turns at a prescribed rate
    (mu_r = 0, no normal force): returns the rolling moment on the first, the rolling
    stiffness (``beta`` x two shear springs in series x R*^2), the bond's moment limit, the
    angle turned and the friction heat."""
    x = np.array([[0.0, 0.0], [2.0 * R, 0.0]])
    ks = 0.5 * kn
    st = new_state(x, [R, R], [M, M], kn=kn, ks=ks, xb=xb, fs0=1e12, mu=0.5, width=4)
    st.free[:] = 0.0
    neighbors.rows_from_pairs(st, np.array([0]), np.array([1]), bonded=True)
    enable_rotation(st, mu_r=0.0, bond_moment=bond_moment, rolling_stiffness=beta)
    st.w[1, 0] = 10.0
    sim = Simulation(st, backend="numba")
    sim.run(steps)
    rs = 0.5 * R  # R* of two equal discs
    kr = beta * 0.5 * ks * rs * rs  # two shear springs in series, times R*^2
    k = int(np.flatnonzero(st.nbr[0] == 1)[0])
    assert st.cstate[0, k] == 1  # still bonded: the moment does not break it
    return (float(st.mr[0, k, 0]), kr, bond_moment * rs * kn * xb, steps * st.dt * 10.0,
            float(st.q_fric.sum()))


def test_moment_bond_holds_the_rolling_moment_elastically_up_to_its_strength():
    # 0.5 of the limit after the first run: elastic, M = kr theta (the turned disc drags the
    # other one's moment along: relative rotation dth_0 - dth_1 < 0)
    m, kr, lim, theta, q = turned_bond(1.0, 50)
    assert kr * theta < lim
    assert m == pytest.approx(kr * theta, rel=1e-9) and q == pytest.approx(0.0, abs=1e-18)
    # turned further: capped at bond_moment R* F_b, the slip is heat
    m, kr, lim, theta, q = turned_bond(1.0, 2000)
    assert kr * theta > 1.5 * lim
    assert m == pytest.approx(lim, rel=1e-12) and q > 0.0
    # without moment bonds (bond_moment 0) a bond in no compression holds no moment
    m, *_ = turned_bond(0.0, 50)
    assert m == 0.0


def test_rolling_stiffness_scales_the_rolling_spring():
    """K_r = beta Ks R*^2: at the same turned angle the elastic moment is beta times the
    default's, and its stored energy M^2 / (2 K_r) beta times too (M = beta K theta)."""
    m1, kr1, lim, theta, _ = turned_bond(100.0, 50)
    m4, kr4, _, theta4, q = turned_bond(100.0, 50, beta=4.0)
    assert theta4 == theta and kr4 == pytest.approx(4.0 * kr1, rel=1e-15)
    assert m4 == pytest.approx(4.0 * m1, rel=1e-9) and m4 == pytest.approx(kr4 * theta, rel=1e-9)
    assert kr4 * theta < lim and q == pytest.approx(0.0, abs=1e-18)
    # beta 0: no rolling spring at all
    m0, *_ = turned_bond(100.0, 50, beta=0.0)
    assert m0 == 0.0


CUDA_SCRIPT = r"""
import json, sys, numpy as np
sys.path.insert(0, sys.argv[1])
from tests.unit.test_rotation import _rotating_specimen, rel_diff
from tests.conftest import step_backends
out = {}
for dim in (2, 3):
    base = _rotating_specimen(60, dim)
    base.bond_moment[:] = 0.5
    res = {k: st for k, (st, _) in step_backends(base, ("cupy", "numpy"), 4).items()}
    out[dim] = max(rel_diff(res["cupy"], res["numpy"], k)
                   for k in ("x", "v", "fs", "w", "wa", "mr"))
print(json.dumps(out))
"""


def test_cuda_kernels_with_rotation_in_simulator():
    for dim, err in run_in_cuda_simulator(CUDA_SCRIPT, timeout=300).items():
        assert err < 1e-12, (dim, err)


def test_energy_books_close_in_a_rotating_collapse():
    """Unbonded rotating grains falling and colliding with friction and rolling resistance,
    undamped: every joule is kinetic (translation + rotation), potential, elastic or heat."""
    st = _rotating_specimen(300, 2)
    st.cstate[:] = 0
    st.mu_r = 0.2
    sim = Simulation(st, backend="numba")
    sim.run(3000)
    e = sim.energies()
    assert e["heat_friction"] > 0.05 * abs(e["gravity"] - sim._eg0) > 0.0
    assert e["closure_error"] < 2e-3


def test_rebuild_and_checkpoint_carry_the_rolling_moments(tmp_path):
    st = _rotating_specimen(200, 3)
    st.cstate[:] = 0
    sim = Simulation(st, backend="numba")
    sim.run(200)
    pairs_before = {(i, j): st.mr[i, k].copy() for i in range(st.n) for k, j in
                    enumerate(st.nbr[i]) if j >= 0}
    neighbors.build_rows(st, width=st.width + 4)
    assert st.mr.shape == (st.n, st.width, 3)
    for i in range(st.n):
        for k, j in enumerate(st.nbr[i]):
            if (i, j) in pairs_before:
                assert np.array_equal(st.mr[i, k], pairs_before[(i, j)])
    sim.backend.push()
    path = tmp_path / "rot.npz"
    sim.save(path)
    sim.run(50)
    sim2 = Simulation.load(path, backend="numba")
    assert sim2.state.rotation
    sim2.run(50)
    for k in ("x", "w", "mr", "fs"):
        assert np.array_equal(getattr(sim2.state, k), getattr(st, k)), k


def test_a_checkpoint_from_before_the_rolling_stiffness_loads_with_beta_one(tmp_path):
    """Checkpoints written before ``rot_props`` stored ``bond_moment`` alone (and before that
    nothing): they load with their bond moment and the default rolling stiffness 1."""
    from geodem.core.checkpoint import load_state

    st = _rotating_specimen(50, 2)
    st.bond_moment[:] = 0.7
    path = tmp_path / "new.npz"
    Simulation(st, backend="numpy").save(path)
    with np.load(path) as z:
        old = {k: z[k] for k in z.files if k != "rot_props"}
    old["bond_moment"] = np.full(st.n, 0.7)
    np.savez(tmp_path / "old.npz", **old)
    back, _ = load_state(tmp_path / "old.npz")
    assert np.all(back.bond_moment == 0.7) and np.all(back.rolling_stiffness == 1.0)
    del old["bond_moment"]
    np.savez(tmp_path / "older.npz", **old)
    back, _ = load_state(tmp_path / "older.npz")
    assert np.all(back.bond_moment == 0.0) and np.all(back.rolling_stiffness == 1.0)


def test_bad_rotation_input_is_refused():
    st = disc_on_floor(2, 0.0)
    st.inertia[0] = 0.0
    with pytest.raises(ValueError, match="inertia of element 0"):
        Simulation(st, backend="numba")
    st = disc_on_floor(2, 0.0, mu_r=-0.1)
    with pytest.raises(ValueError, match="mu_r of element 0.*>= 0"):
        Simulation(st, backend="numba")
    with pytest.raises(ValueError, match="bond_moment = -1.*>= 0"):
        enable_rotation(disc_on_floor(2, 0.0), bond_moment=-1.0)
    with pytest.raises(ValueError, match="rolling_stiffness = nan.*finite values >= 0"):
        enable_rotation(disc_on_floor(2, 0.0), rolling_stiffness=float("nan"))
    st = disc_on_floor(2, 0.0)
    st.rolling_stiffness[0] = -2.0
    with pytest.raises(ValueError, match="rolling_stiffness of element 0.*>= 0"):
        Simulation(st, backend="numba")
    from geodem.build.walls import append_elements
    with pytest.raises(ValueError, match="enable_rotation / enable_contact_damping"):
        append_elements(disc_on_floor(2, 0.0), np.zeros((1, 2)), r=R, m=M, kn=1.0)
    assert math.isfinite(R)
