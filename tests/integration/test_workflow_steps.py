"""Step kinds as registered components: one contract test runs every registered kind, and a new
kind plugs in without touching the runner."""
import json
from typing import Literal

import numpy as np
import pytest
import yaml

from geodem.workflow import STEPS, StepBase, register_step, run_workflow, workflow_model
from geodem.workflow.schema import F, load_builtins

load_builtins()
# the examples' models have tens to a few hundred elements (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_numba_thread")

LATTICE = {"type": "lattice_block", "dim": 2, "counts": [6, 6], "diameter": 0.01,
           "material": "rock", "groups": {"base": {"side": "ymin"}, "top": {"side": "ymax"}}}
ROCK = {"rho": 2650.0, "kn": 2.0e7, "ks": 6.0e6, "xb": 2.0e-6, "fs0": 20.0, "mu": 0.4}


def workflow(tmp_path, steps, model=None, **extra):
    wf = {"metadata": {"name": "contract"}, "model": model or LATTICE,
          "materials": {"rock": ROCK}, "steps": steps,
          "outputs": {"observables": {"every": 5}}, **extra}
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(wf))
    return p


def example_workflow(tmp_path, kind):
    """The workflow file of step ``kind``'s example: 10 steps, the example, 10 steps, on the
    step's example model or else a loaded lattice block (a load keeps energy flowing: the
    closure error of a model at rest is round-off / round-off)."""
    cls = STEPS[kind]
    pre = [] if cls.example_model else [{"kind": "load", "group": "top", "force": [0.0, -1.0]}]
    pre += list(getattr(cls, "example_before", []))  # steps the example needs before it
    return workflow(tmp_path, pre + [{"kind": "run", "nsteps": 10}, dict(cls.example),
                                     {"kind": "run", "nsteps": 10}], model=cls.example_model)


@pytest.mark.parametrize("kind", list(STEPS))
def test_every_step_kind_runs(kind, step_example_run):
    cls = STEPS[kind]
    assert cls.__doc__ and cls.example["kind"] == kind
    for name, f in cls.model_fields.items():  # every field documented
        assert f.description, f"{kind}.{name} has no description"
    ex = dict(cls.example)
    code, s = step_example_run(kind)  # the run test_separate_memory compares with
    assert code == 0 and s["status"] == "ok", s.get("error")
    if cls.example_model is None:
        assert s["steps"] == 20 + cls.model_validate(ex).planned_steps(
            type("P", (), {"dt": s["dt"], "n_across": 6.0})())
    else:  # scene steps on their own model may end early (at rest), never past the plan
        assert 20 <= s["steps"] <= s["planned_steps"]
    # a load suddenly applied to a block at rest: Verlet's start-up error is ~1 % of the tiny
    # energies of the first steps, then falls below 1e-3
    assert s["energy_closure_rel_error"] < 2e-2


def test_decrees_keep_the_energy_books_closed(tmp_path):
    steps = [{"kind": "velocity", "group": "top", "velocity": [0.0, -0.2]},
             {"kind": "run", "nsteps": 200},
             {"kind": "fix", "group": "top"},  # removes the kinetic energy it had
             {"kind": "load", "group": "top", "force": [0.0, -5.0]},
             {"kind": "release", "group": "top", "dofs": ["y"]},
             {"kind": "run", "nsteps": 200}]
    code, s = run_workflow(workflow(tmp_path, steps), tmp_path / "out", echo=False,
                           progress=False)
    assert code == 0, s.get("error")
    assert s["energy_closure_rel_error"] < 5e-3  # the largest: Verlet's start-up at step 5
    import h5py

    with h5py.File(tmp_path / "out" / "output.h5", "r") as f:
        step = f["observables/energy/closure_error/step"][()]
        err = f["observables/energy/closure_error/value"][()]
        ke = f["observables/energy/kinetic/value"][()]
    assert ke[step == 200][0] > 1e-3  # the top group was moving when it was fixed
    assert err[step > 200].max() < 1e-3


@pytest.fixture
def plugin_step():
    @register_step("shake")
    class Shake(StepBase):
        """Test plug-in: give a group a velocity kick, then run."""

        example = {"kind": "shake", "group": "top", "speed": 0.01}
        group: str = F(..., description="Group")
        speed: float = F(..., unit="m/s", gt=0, description="Kick")
        nsteps: int = F(50, ge=1, description="Steps after the kick")
        direction: Literal["x", "y"] = F("x", description="Direction")

        def planned_steps(self, plan):
            return self.nsteps

        def execute(self, ctx):
            from geodem.core import groups

            if not ctx.resumed:
                k = "xy".index(self.direction)

                def kick(st):
                    st.v[groups.members(st, self.group), k] += self.speed

                ctx.decree(kick, self.group)
            ctx.advance(self.nsteps)
            return {"kinetic": ctx.sim.energies()["kinetic"]}

    yield Shake
    STEPS.pop("shake")
    workflow_model.cache_clear()


def test_a_new_step_kind_plugs_in(plugin_step, tmp_path):
    sch = workflow_model().model_json_schema()
    assert "shake" in sch["properties"]["steps"]["items"]["discriminator"]["mapping"]
    p = workflow(tmp_path, [{"kind": "shake", "group": "top", "speed": 0.01, "nsteps": 40}])
    code, s = run_workflow(p, tmp_path / "out", echo=False, progress=False)
    assert code == 0 and s["steps"] == 40 and s["results"]["shake"]["kinetic"] > 0
    assert s["energy_closure_rel_error"] < 5e-3
    bad = workflow(tmp_path, [{"kind": "shake", "group": "top", "speed": -1}])
    from geodem.workflow import WorkflowError, prepare

    with pytest.raises(WorkflowError) as err:
        prepare(bad)
    assert "steps[0].speed" in str(err.value) and "> 0 [m/s]" in str(err.value)


@pytest.mark.parametrize("mode", ["warn", "fail"])
def test_balance_without_enough_damping_is_flagged(tmp_path, mode):
    # no damping and 20 steps: the block dropped under gravity is nowhere near equilibrium
    model = dict(LATTICE, gravity=[0.0, -9.81])
    steps = [{"kind": "fix", "group": "base"},
             {"kind": "balance", "standard_damping": False, "nsteps": 20, "unconverged": mode}]
    code, s = run_workflow(workflow(tmp_path, steps, model=model), tmp_path / "out",
                           echo=False, progress=False)
    if mode == "warn":
        assert code == 0
        assert s["results"]["balance"]["converged"] is False
        assert s["results"]["balance"]["unbalanced_force_ratio"] > 1e-2
        assert any("not in equilibrium" in w for w in s["warnings"])
    else:
        assert code == 1 and s["status"] == "failed"
        assert "not in equilibrium" in s["error"] and "nsteps" in s["error"]


def test_balance_reaches_equilibrium_under_gravity(tmp_path):
    model = dict(LATTICE, gravity=[0.0, -9.81])
    steps = [{"kind": "fix", "group": "base"}, {"kind": "balance"}]
    code, s = run_workflow(workflow(tmp_path, steps, model=model), tmp_path / "out",
                           echo=False, progress=False)
    assert code == 0
    assert s["steps"] == 300  # 50 x 6 elements across
    assert s["results"]["balance"]["unbalanced_force_ratio"] < 1e-2
    assert s["results"]["balance"]["converged"] is True
    # the base carries the weight of the block
    import h5py

    with h5py.File(tmp_path / "out" / "output.h5", "r") as f:
        fy = f["observables/groups/base/reaction/value"][-1, 1]
        mass = f["particles/all/mass"][()].sum()
    assert fy == pytest.approx(-9.81 * mass * 30 / 36, rel=0.05)  # 30 free of 36 elements
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["status"] == "ok"
    assert np.isfinite(s["energy_closure_rel_error"])
