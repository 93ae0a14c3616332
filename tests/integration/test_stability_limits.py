"""Each method pushed past its limit (issue 7): geodem detects it and stops with a message that
says what to change -- too little damping for a quasi-static balance, a fluid or thermal
sub-step beyond the explicit limit, an extreme stiffness contrast, an overlapping start."""
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.core import timestep
from geodem.core.engine import InstabilityError, Simulation
from geodem.fields import FieldStabilityError
from geodem.fields.pore import OIL_CF, OIL_KF, PoreField
from geodem.fields.thermal import ThermalField
from geodem.studies import stability as S
from geodem.workflow import WorkflowError, prepare, run_workflow

pytestmark = pytest.mark.usefixtures("one_numba_thread")

D = 0.01


def lattice(n=6, kn=2e8, jitter=0.0, seed=3, gap=1e-9 * D):
    rng = np.random.default_rng(seed)
    x = triangular_lattice(n, n, D) + rng.uniform(-jitter, jitter, (n * n, 2)) * D
    return bonded_state(x, 0.5 * D, density=2500.0, kn=kn, ks=0.4 * kn, xb=1e-3 * D, fs0=1e4,
                        mu=0.5, gap=gap)


# ------------------------------------------------------------------ quasi-static balance
def _block_workflow(tmp_path, steps):
    wf = {"metadata": {"name": "limits"},
          "model": {"type": "lattice_block", "dim": 2, "counts": [6, 6], "diameter": D,
                    "material": "rock", "gravity": [0.0, -9.81],
                    "groups": {"base": {"side": "ymin"}}},
          "materials": {"rock": {"rho": 2650.0, "kn": 2.0e7, "ks": 6.0e6, "xb": 2.0e-6,
                                 "fs0": 20.0, "mu": 0.4}},
          "steps": [{"kind": "fix", "group": "base"}] + steps,
          "outputs": {"observables": {"every": 50}}}
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(wf))
    return p


@pytest.mark.parametrize("damping", [None, 1e-3, 1.0])
def test_balance_with_too_little_damping_is_flagged_and_the_standard_one_converges(tmp_path,
                                                                                   damping):
    # the same 50 N = 300 steps each time; only the damping differs (None: none at all)
    steps = [] if damping is None else [{"kind": "damping", "standard": 6.0}]
    if damping not in (None, 1.0):
        steps = [{"kind": "damping", "ratio": damping / 6.0}]  # eta_c / N x damping
    steps.append({"kind": "balance", "standard_damping": False, "unconverged": "fail"})
    code, s = run_workflow(_block_workflow(tmp_path, steps), tmp_path / "out", echo=False,
                           progress=False)
    assert s["steps"] == 300
    if damping == 1.0:
        assert code == 0 and s["status"] == "ok"
        assert s["results"]["balance"]["unbalanced_force_ratio"] < 1e-3
        assert s["results"]["balance"]["converged"] is True
    else:
        # still ringing: the run fails (exit 1) and the message says what to change
        assert code == 1 and s["status"] == "failed"
        assert "not in equilibrium after 300 time steps" in s["error"]
        assert "tolerance 0.01" in s["error"] and "standard_damping" in s["error"]


def test_balance_residual_grows_on_both_sides_of_the_standard_damping():
    recs = S.balance_damping_sweep(factors=(0.0, 0.1, 1.0, 10.0), n=6)
    u = {r["damping_over_standard"]: r["unbalanced_force_ratio"] for r in recs}
    assert u[1.0] < 1e-3  # standard damping: equilibrium within the standard 50 N steps
    assert u[0.0] > 1.0 and u[0.1] > 0.1 and u[10.0] > 1e-2  # all flagged at tolerance 1e-2
    assert u[0.0] > u[0.1] > u[1.0] < u[10.0]


# ------------------------------------------------------------------ coupled fields
def _pore(jitter=0.0):
    sim = Simulation(lattice(8, jitter=jitter, gap=0.2 * D), backend="numba")
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6, p_init=1e6, p_min=None, forces=False)
    sim.add_field(f)
    return sim, f


def test_pore_sub_step_beyond_its_limit_is_refused_naming_h_and_the_range():
    sim, f = _pore()
    lim = f.stable_dt(sim)
    with pytest.raises(FieldStabilityError, match=r"'pore_fluid': sub-step h = .* allowed: "
                                                  r"0 < h <= stable_dt = "):
        f.substep(sim, 1.01 * lim)
    with pytest.raises(FieldStabilityError, match="allowed: 0 < h"):
        f.substep(sim, -1.0)
    m0 = f.M.copy()
    f.substep(sim, lim)  # at the bound: accepted
    assert np.abs(f.M - m0).max() < 1e-9 * m0.max()  # uniform pressure: nothing flows


def test_thermal_sub_step_beyond_its_limit_is_refused():
    sim = Simulation(lattice(6), backend="numba")
    f = ThermalField(k=3.0, c=800.0)
    sim.add_field(f)
    lim = f.stable_dt(sim)
    with pytest.raises(FieldStabilityError, match="'thermal': sub-step h = .* stable_dt"):
        f.substep(sim, 1.5 * lim)
    f.substep(sim, 0.5 * lim)
    assert f.time == pytest.approx(0.5 * lim)


@pytest.mark.parametrize("jitter", [0.0, 0.15])
def test_forced_pore_sub_steps_blow_up_at_two_over_lambda_max_and_advance_stays_below(jitter):
    sim, f = _pore(jitter)
    r = S.measure_field_critical_step(f, sim, steps=3000, rel_tol=0.004)
    # the explicit Euler limit measured by forcing sub-steps is 2 / lambda_max to 0.4 %
    assert r["measured"] == pytest.approx(r["predicted"], rel=0.005)
    # stable_dt (the largest sub-step the field accepts) never exceeds it: exact on the regular
    # lattice (near-bipartite pore graph), 0.6-0.8 x on an irregular one
    assert r["bound"] <= r["predicted"] * (1 + 1e-9)
    assert (0.95 if jitter == 0.0 else 0.5) < r["bound"] / r["predicted"]
    # what advance() takes: safety 0.5 x stable_dt, and it does take it
    span = 7.3 * r["bound"]
    assert f.advance(sim, span) == math.ceil(span / r["used"])
    assert r["used"] <= 0.5 * r["predicted"]


def test_two_pores_limit_is_exactly_stable_dt():
    """Two equal pores, one throat: lambda = 2 C / S, so 2 / lambda = S / C = stable_dt: the
    bound is the limit itself (not half of it)."""
    recs = [r for r in S.field_stability_study(steps=2000) if "two pores" in r["model"]]
    assert recs[0]["bound_over_predicted"] == pytest.approx(1.0, rel=1e-9)
    assert recs[0]["measured_over_predicted"] == pytest.approx(1.0, abs=0.003)


# ------------------------------------------------------------------ stiffness contrast
def contrast(ratio=1e4, n=8):
    """Left half soft (kn 1e6 N/m), right half ``ratio`` x stiffer, bonded together."""
    x = triangular_lattice(n, n, D)
    kn = np.where(x[:, 0] < x[:, 0].mean(), 1e6, 1e6 * ratio)
    return bonded_state(x, 0.5 * D, density=2500.0, kn=kn, ks=0.5 * kn, xb=1.0, fs0=1e9,
                        mu=0.5, gap=1e-9 * D)


def test_stiffness_contrast_default_dt_follows_the_stiffest_and_runs_stable():
    st = contrast()
    stiff = st.kn > 1e9
    per = timestep.element_periods(st)
    assert timestep.default_dt(st) == pytest.approx(0.02 * per[stiff].min(), rel=1e-12)
    assert timestep.default_dt(st) < timestep.stable_dt_bound(st) < 2.0 / S.omega_max_exact(st)
    st.v[:] = np.random.default_rng(0).standard_normal(st.v.shape) * 1e-4
    sim = Simulation(st, backend="numba", monitor_every=100)
    v0 = float(np.abs(st.v).max())
    e0 = sim.energies()
    sim.run(2000)
    e = sim.energies()
    assert e["closure_error"] < 1e-4
    # no growth: the energy only moves between kinetic and elastic (to the Verlet full-step
    # swing, well under 1 % at 0.02 of the stiffest period)
    assert e["kinetic"] + e["elastic"] == pytest.approx(e0["kinetic"] + e0["elastic"], rel=1e-2)
    assert float(np.abs(sim.sync().v).max()) < 3 * v0


def test_stiffness_contrast_dt_of_the_soft_material_is_refused_and_blows_up_if_forced():
    st = contrast()
    soft = st.kn < 1e9
    dt_soft = 0.02 * timestep.element_periods(st)[soft].min()  # the soft half's default
    bound = timestep.stable_dt_bound(st)
    assert dt_soft > 20 * bound
    with pytest.raises(ValueError, match=r"time step dt = .* above the stability limit .* "
                                         r"allowed: 0 < dt < "):
        Simulation(st.copy(), backend="numba", dt=dt_soft)
    s2 = st.copy()
    s2.v[:] = np.random.default_rng(0).standard_normal(s2.v.shape) * 1e-4
    sim = Simulation(s2, backend="numba", dt=dt_soft, monitor_every=100, allow_unstable_dt=True)
    with pytest.raises(InstabilityError, match=r"fastest elements \[") as err:
        sim.run(2000)
    assert sim.state.step <= 200  # caught at the first energy check, before garbage piles up
    named = [int(v) for v in str(err.value).split("fastest elements [")[1].split("]")[0]
             .split(",")]
    assert named and all(st.kn[i] > 1e9 for i in named)  # the stiff elements fly first


# ------------------------------------------------------------------ overlapping start
TWO_BALLS = Path(__file__).resolve().parents[2] / "workflows" / "two_balls.yaml"


def test_deep_initial_overlap_of_free_elements_is_refused_before_any_step():
    # both balls displaced by 0.3 d: the right ball overlaps its wall by 0.6 x its radius
    src, sets = TWO_BALLS, ["model.amplitude=0.3"]
    with pytest.raises(WorkflowError) as err:
        prepare(src, sets=sets)
    msg = str(err.value)
    assert "model" in msg and "overlap by 0.6 x the smaller radius at the start" in msg
    assert "simulation.overlap_limit = 0.5" in msg and "allowed" in msg
    # the limit is the run's own overlap limit: raised, the model is accepted
    prep = prepare(src, sets=sets + ["simulation.overlap_limit=0.7"])
    assert prep.plan.initial_overlap == pytest.approx(0.6, rel=1e-9)
    # the shipped case starts with 2 x amplitude / d = 0.02
    assert prepare(src).plan.initial_overlap == pytest.approx(0.02, rel=1e-9)


def test_deep_initial_overlap_exits_2_from_the_command_line():
    from typer.testing import CliRunner

    from geodem.cli import app

    src, sets = TWO_BALLS, ["model.amplitude=0.3"]
    res = CliRunner().invoke(app, ["validate", str(src), "--set", sets[0]])
    assert res.exit_code == 2
    assert "two_balls.yaml:" in res.output and "overlap by 0.6 x" in res.output


def test_initial_overlap_ignores_fixed_pairs_and_finds_the_free_one():
    from geodem.core.checks import initial_overlap

    st = lattice(4)
    st.free[:2] = 0.0
    st.x[1] = st.x[0] + [0.3 * D, 0.0]  # two fixed elements overlapping: not this check's job
    st.x[2] = st.x[3] + [0.4 * D, 0.0]  # free 2 against free 3: 0.6 x the radius
    ratio, i, j = initial_overlap(st)
    assert (i, j) == (2, 3) and ratio == pytest.approx(1.2, rel=1e-9)
