"""Bad input is refused before any stepping; instabilities stop the run with a clear message."""
import math

import numpy as np
import pytest

from geodem.cases import two_balls as tb
from geodem.core.engine import InstabilityError, Simulation
from geodem.core.neighbors import rows_from_pairs
from geodem.core.state import new_state
from geodem.core.timestep import stable_dt_bound
from geodem.materials import macro_to_micro, micro_to_macro


@pytest.mark.parametrize("name,value,match", [
    ("kn", 0.0, r"kn of element 1 .* allowed range: finite and > 0"),
    ("kn", -1e9, r"kn of element 1 .* > 0"),
    ("ks", -1.0, r"ks of element 1 .* >= 0"),
    ("m", 0.0, r"m of element 1 .* > 0"),
    ("mu", np.nan, r"mu of element 1"),
])
def test_nonphysical_parameters(name, value, match):
    st = tb.build()
    getattr(st, name)[1] = value
    with pytest.raises(ValueError, match=match):
        Simulation(st, backend="numba")


def test_nan_position():
    st = tb.build()
    st.x[2, 0] = np.nan
    with pytest.raises(ValueError, match=r"x of element 2 is not finite"):
        Simulation(st, backend="numba")


def test_dt_above_stability_limit():
    st = tb.build()
    lim = stable_dt_bound(st)
    with pytest.raises(ValueError, match=r"above the stability limit .* allowed: 0 < dt <"):
        Simulation(st, backend="numba", dt=1.01 * lim)
    with pytest.raises(ValueError, match="positive"):
        Simulation(tb.build(), backend="numba", dt=-1.0)


def test_overlapping_fixed_elements():
    x = np.array([[0.0, 0.0], [0.4, 0.0], [2.0, 0.0]])
    st = new_state(x, 0.5, 1.0, kn=1e6, ks=1e6, width=4)
    st.free[:2] = 0.0
    with pytest.raises(ValueError, match=r"fixed elements 0 and 1 overlap"):
        Simulation(st, backend="numba")


def test_nu_and_friction_out_of_range():
    with pytest.raises(ValueError, match=r"nu = 0.3: .* -1 < nu <= 0.2"):
        macro_to_micro(E=3e10, nu=0.3, Tu=5e6, Cu=5e7, mu_i=1.0, rho=2650, d=0.01)
    with pytest.raises(ValueError, match=r"mu_i = 0.2: .* >= 0.3536"):
        macro_to_micro(E=3e10, nu=0.15, Tu=5e6, Cu=5e7, mu_i=0.2, rho=2650, d=0.01)
    with pytest.raises(ValueError, match=r"E = -1"):
        macro_to_micro(E=-1, nu=0.15, Tu=5e6, Cu=5e7, mu_i=1.0, rho=2650, d=0.01)


def test_macro_micro_round_trip():
    mic = macro_to_micro(E=3e10, nu=0.15, Tu=5e6, Cu=5e7, mu_i=1.0, rho=2650, d=0.01)
    mac = micro_to_macro(mic.Kn, mic.Ks, mic.Xb, mic.Fs0, mic.mu_p, 0.01)
    for k, v in dict(E=3e10, nu=0.15, Tu=5e6, Cu=5e7, mu_i=1.0).items():
        assert mac[k] == pytest.approx(v, rel=1e-12)
    assert mic.Xb == pytest.approx(5e6 * 0.01 * (2 - 0.15) / (3 * 3e10), rel=1e-12)
    assert mic.element["kn"] == 2 * mic.Kn and mic.mass == pytest.approx(2650 * 1e-6 / math.sqrt(2))


def test_instability_nan_stops_run():
    st = tb.build()
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.run(7)
    st.fload[2, 0] = np.inf  # a broken load reaches the loop: positions turn non-finite
    with pytest.raises(InstabilityError, match=r"unstable at step 10: .* elements \[1, 2\].*reduce dt"):
        sim.run(100)


def test_instability_nan_stops_run_between_neighbour_checks():
    # with a skin the check's displacement scan is also the finiteness test
    from geodem.bench import build_specimen

    st = build_specimen(200)
    assert st.skin > 0.0
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.run(3)
    st.fload[5, 0] = np.inf
    with pytest.raises(InstabilityError, match=r"non-finite positions/velocities of elements \[") \
            as err:
        sim.run(100)
    assert "5" in str(err.value).split("elements [")[1].split("]")[0].split(", ")


def test_energy_growth_detected():
    st = tb.build(amplitude=0.001)
    sim = Simulation(st, backend="numba", monitor_every=10)
    sim.state.dt = 1.05 * 2.0 / math.sqrt(3 * 0.5 * st.kn[1] / st.m[1])  # just past 2/omega_max
    with pytest.raises(InstabilityError, match=r"energy grew .*fastest elements \[[12], [12]\]"):
        sim.run(20000)


def test_deep_overlap_detected():
    x = np.array([[0.0, 0.0], [1.0, 0.0]])
    st = new_state(x, 0.5, 1.0, kn=1e3, ks=1e3, mu=0.0, width=4)
    rows_from_pairs(st, np.array([0]), np.array([1]), bonded=False)
    st.free[0] = 0.0
    st.v[1, 0] = -20.0  # soft contact hit hard
    sim = Simulation(st, backend="numba", monitor_every=10)
    with pytest.raises(InstabilityError, match=r"elements 0 and 1 overlap .* reduce the loading"):
        sim.run(2000)


def test_energy_growth_message_quotes_the_bound_of_the_start():
    """The blown-up state has few contacts left, so its bound says little; the message quotes
    the bound of the model as it started."""
    st = tb.build(amplitude=0.001)
    b0 = stable_dt_bound(st)
    sim = Simulation(st, backend="numba", monitor_every=10, dt=1.3 * b0, allow_unstable_dt=True)
    with pytest.raises(InstabilityError) as err:
        sim.run(20000)
    assert f"stability bound at the start of the run {b0:.4g} s" in str(err.value)
    assert f"{1.3 * b0:.4g} s" in str(err.value)


def test_initial_overlap_refused_before_stepping():
    x = np.array([[0.0, 0.0], [0.6, 0.0], [3.0, 0.0]])  # 0 and 1 overlap by 0.4 = 0.8 R
    st = new_state(x, 0.5, 1.0, kn=1e6, ks=1e6, width=4)
    rows_from_pairs(st, np.array([0]), np.array([1]), bonded=False)
    before = st.x.copy()
    with pytest.raises(ValueError, match=r"elements [01] and [01] overlap by 0.8 x the smaller "
                                         r"radius before the first step; allowed: "
                                         r"overlap_limit = 0.5"):
        Simulation(st, backend="numba")
    assert np.array_equal(st.x, before) and st.step == 0
    Simulation(st, backend="numba", overlap_limit=0.9)  # a looser limit accepts it
    Simulation(st, backend="numba", monitor_every=0)  # so does a relaxation without monitor


@pytest.mark.parametrize("name,value,match", [
    ("fload", np.nan, r"fload of element 3 is not finite"),
    ("free", np.nan, r"free of element 3 .* allowed: 1.0 .* or 0.0"),
    ("free", 0.5, r"free of element 3"),
])
def test_nonfinite_loads_and_freedoms(name, value, match):
    st = tb.build()
    getattr(st, name)[3, 0] = value
    with pytest.raises(ValueError, match=match):
        Simulation(st, backend="numba")


def test_nonfinite_gravity():
    st = tb.build()
    st.gravity = np.array([0.0, np.inf, 0.0])[:st.dim]
    with pytest.raises(ValueError, match=r"gravity is not finite"):
        Simulation(st, backend="numba")


@pytest.mark.parametrize("kw,match", [
    ({"check_every": 0}, r"check_every must be an integer >= 1, got 0"),
    ({"check_every": 2.5}, r"check_every must be an integer >= 1"),
    ({"monitor_every": -10}, r"monitor_every must be an integer >= 0"),
    ({"overlap_limit": float("nan")}, r"0 < overlap_limit <= 1"),
    ({"overlap_limit": -1.0}, r"0 < overlap_limit <= 1"),
])
def test_engine_settings(kw, match):
    with pytest.raises(ValueError, match=match):
        Simulation(tb.build(), backend="numba", **kw)


def test_run_counts_steps_in_whole_numbers():
    sim = Simulation(tb.build(), backend="numba")
    for bad in (2.7, -5, "3", True):
        with pytest.raises(ValueError, match=r"nsteps must be an integer >= 0"):
            sim.run(bad)
    sim.run(3.0)
    sim.run(0)
    assert sim.state.step == 3


def test_new_state_names_a_parameter_of_the_wrong_length():
    with pytest.raises(ValueError, match=r"r must be one number or one per element \(3 values"):
        new_state(np.zeros((3, 2)), [0.5, 0.5], 1.0)
    with pytest.raises(ValueError, match=r"kn must be one number or one per element"):
        new_state(np.zeros((3, 2)), 0.5, 1.0, kn=[1.0, 2.0])


def _head_on(v0):
    # three unbonded discs in a row, the first thrown at the second
    from geodem.core import neighbors

    st = new_state(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]), 0.5, 1.0, width=4,
                   kn=1e6, ks=1e6, mu=0.5)
    neighbors.build_rows(st, skin=0.1)
    st.v[0, 0] = v0
    return st


def test_fast_element_overlap_is_caught_at_once():
    # 2000 m/s moves the disc ~0.36 m per step (0.7 of its radius): the pair overlaps beyond
    # the limit in the first step. The monitor would look only at step 1000; the fast-element
    # check looks every step (and from the first one), so the run stops at step 1.
    sim = Simulation(_head_on(2000.0), backend="numba", monitor_every=1000)
    assert sim.state.dt * 2000.0 > 0.5 * 0.5
    with pytest.raises(InstabilityError, match=r"elements 0 and 1 overlap by .* at step 1"):
        sim.run(50)


def test_slow_collision_is_not_stopped():
    # the same collision at 20 m/s stays far inside the overlap limit
    sim = Simulation(_head_on(20.0), backend="numba", monitor_every=1000)
    sim.run(200)
    assert sim.state.x[0, 0] < sim.state.x[1, 0]


def test_fast_start_is_checked_before_check_every():
    # a model at rest keeps the regular schedule; a fast one is checked as the skin asks
    assert Simulation(_head_on(0.0), backend="numba", monitor_every=0)._next_check == 10
    fast = Simulation(_head_on(30.0), backend="numba", monitor_every=0)
    u = fast.state.dt * 30.0
    assert fast._next_check == max(1, int(0.5 * 0.1 / u)) < 10


def test_check_finite_names_the_elements():
    sim = Simulation(tb.build(), backend="numba")
    sim.check_finite()
    sim.state.v[1, 0] = np.nan
    with pytest.raises(InstabilityError, match=r"non-finite positions/velocities of elements \[1\]"):
        sim.check_finite()


def test_overlap_limit_survives_a_checkpoint(tmp_path):
    sim = Simulation(tb.build(), backend="numba", overlap_limit=0.8)
    sim.save(tmp_path / "c.npz")
    assert Simulation.load(tmp_path / "c.npz", backend="numba").overlap_limit == 0.8


def _pair(gap, v=0.0, **kw):
    """Two discs of radius 5 mm, 1 g, ``gap`` apart, approaching at ``v`` each."""
    x = np.array([[0.0, 0.0], [0.01 + gap, 0.0]])
    st = new_state(x, 0.005, 1e-3, kn=1e5, ks=3e4, mu=0.5, **kw)
    st.v[0, 0], st.v[1, 0] = v, -v
    return st


def test_dt_is_bounded_before_the_first_contact():
    # no contacts yet: the bound over the current rows is infinite, so any dt passed and the
    # two discs went through each other; the first contact's bound (2 sqrt(m / Kn (1 + 1)))
    # with Kn = kn/2: omega^2 = kn/2 (1/m + 1/m) = kn/m -> dt < 2 sqrt(m/kn) = 2e-4 s
    from geodem.core.neighbors import build_rows

    st = _pair(0.04, v=5.0)
    build_rows(st, skin=0.001)
    with pytest.raises(ValueError, match=r"above the stability limit .* = 0.0002 s \(no contacts"):
        Simulation(st, backend="numba", dt=4e-3)
    Simulation(st, backend="numba", dt=1.9e-4)  # below it: accepted


def test_state_arrays_of_the_wrong_layout_are_refused():
    st = tb.build()
    sim = Simulation(st, backend="numba")
    for name, value, match in (
            ("gravity", np.array([-9.81]), r"gravity is .* allowed: a float NumPy array of 2"),
            ("gravity", [0.0, 0.0, -9.81], r"gravity is .* allowed"),
            ("m", np.ones(st.n + 1), r"m has shape \(%d,\); allowed: \(%d,\)" % (st.n + 1, st.n)),
            ("x", st.x.astype(np.float32), r"x has dtype float32; allowed: float64"),
            ("v", np.asfortranarray(np.zeros((st.n, st.dim))),
             r"v is not a writeable C-contiguous array")):
        old = getattr(st, name)
        setattr(st, name, value)
        with pytest.raises(ValueError, match=match):
            sim.run(1)  # checked at every run, before any step
        setattr(st, name, old)
    ro = st.x.copy()
    ro.setflags(write=False)
    st.x = ro
    with pytest.raises(ValueError, match=r"x is not a writeable"):
        Simulation(st, backend="numba")


def test_coincident_elements_are_refused_before_stepping():
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0099, 0.0, 0.0]])
    st = new_state(x, 0.005, 1e-3, kn=1e5, ks=3e4, xb=1e-3, fs0=10.0, mu=0.5)
    rows_from_pairs(st, [0, 1], [1, 2], bonded=True)
    for backend in ("numba", "numpy"):
        with pytest.raises(ValueError, match=r"elements 0 and 1 are at the same position"):
            Simulation(st, backend=backend)


def test_a_change_that_breaks_the_model_is_refused():
    st = tb.build()
    sim = Simulation(st, backend="numba")
    sim.run(10)
    v = st.v.copy()
    with pytest.raises(KeyError, match="unknown group 'nope'"):
        sim.change(lambda s: s.v.__setitem__((1, 0), 1.0), group="nope")
    assert np.array_equal(st.v, v)  # fn not applied
    with pytest.raises(ValueError, match=r"parameter m of element 1 .* > 0"):
        sim.change(lambda s: s.m.__setitem__(1, 0.0))


def test_non_finite_books_stop_the_monitor():
    # finite positions and velocities but a NaN in the books: the closure error is NaN, and
    # NaN > limit is False, so the monitor used to pass it
    st = tb.build()
    sim = Simulation(st, backend="numba")
    sim.run(10)
    st.w_ext[1] = np.nan
    with pytest.raises(InstabilityError, match=r"non-finite accelerations or energy books of "
                                               r"elements \[1\]"):
        sim.check_energy()


def test_run_checks_its_callback_interval():
    sim = Simulation(tb.build(), backend="numba")
    for every in (-1, 0, 2.5, "a"):
        with pytest.raises(ValueError, match="every must be an integer >= 1"):
            sim.run(5, callback=lambda s: None, every=every)


def test_small_api_mistakes_get_clear_errors(tmp_path):
    from geodem.backends import BackendError
    from geodem.core import groups
    from geodem.core.checkpoint import save_state

    st = tb.build()
    with pytest.raises(BackendError, match="is not a name"):
        Simulation(st, backend=5)
    Simulation(st, backend="numba", overlap_limit=np.float32(0.5))  # a NumPy float is a number
    for width in (-1, 2.5, True):
        with pytest.raises(ValueError, match="width .* integer >= 1"):
            new_state(np.zeros((2, 2)) + [[0, 0], [1, 0]], 0.1, 1.0, width=width)
    with pytest.raises(ValueError, match="complex"):
        new_state(np.array([[0, 0], [1, 0]], complex), 0.1, 1.0)
    assert groups.add_group(st, "none", []) > 0 and groups.members(st, "none").size == 0
    for name, mask, match in ((7, [0], "non-empty string"), ("far", [10**6], "indices in"),
                              ("half", np.ones(2, bool), "needs %d values" % st.n)):
        with pytest.raises(ValueError, match=match):
            groups.add_group(st, name, mask)
    save_state(st, tmp_path / "plain.npz")
    with pytest.raises(ValueError, match="holds a state .* but no simulation"):
        Simulation.load(tmp_path / "plain.npz")


def test_a_change_of_gravity_refreshes_the_accelerations():
    st = tb.build()
    sim = Simulation(st, backend="numba")
    sim.run(5)
    free = st.free[:, 1] != 0
    a0 = st.a[free, 1].copy()
    sim.change(lambda s: s.gravity.__setitem__(1, -9.81), book_energy=False)
    assert np.allclose(st.a[free, 1], a0 - 9.81, rtol=0, atol=1e-9)
