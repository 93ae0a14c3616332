"""Rotation as a material option (``rotation``, ``rolling_friction``, ``bond_moment``): the
runner turns every element of a model whose material asks for it, walls and platens held; the
options are refused without rotation, and materials of one model must agree."""
import json
import types
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.workflow import WorkflowError, prepare
from geodem.workflow.material import material_rotation
from geodem.workflow.models import BuildError
from geodem.workflow.schema import ScaledMicroMaterial

pytestmark = pytest.mark.usefixtures("one_numba_thread")

# the library sandstone's 2-D element parameters, per size
ROCK = {"rho": 2400.0, "dim": 2, "kn_per_d": 3.34e10, "ks_per_d": 1.68e10,
        "xb_per_d": 2.16e-4, "fs0_per_d2": 6.05e7, "mu": 0.255, "packing": "isotropic"}


def _ucs(tmp_path, **structure):
    wf = {"metadata": {"name": "ucs_rot", "seed": 0},
          "model": {"type": "specimen", "dim": 2, "size": [0.04, 0.08], "d_mean": 0.005,
                    "material": "rock"},
          "materials": {"rock": dict(ROCK, **structure)},
          "steps": [{"kind": "uniaxial", "strain_rate": 0.2, "max_strain": 0.002}]}
    p = tmp_path / "ucs_rot.yaml"
    p.write_text(yaml.safe_dump(wf, sort_keys=False))
    return p


def test_a_rotating_material_turns_the_specimen_and_holds_the_platens(tmp_path):
    prep = prepare(_ucs(tmp_path, rotation=True, bond_moment=0.5, rolling_friction=0.1,
                        rolling_stiffness=2.0), backend="numba")
    st = prep.built.state
    assert st.rotation
    assert np.all(st.bond_moment == 0.5) and np.all(st.mu_r == 0.1)
    assert np.all(st.rolling_stiffness == 2.0)
    assert np.all(st.rfree == 1.0)  # the platens are held when the loading starts
    assert prep.built.info["rotation"] == {"rolling_friction": 0.1, "bond_moment": 0.5,
                                           "rolling_stiffness": 2.0}


def test_held_translation_holds_the_rotation_too(tmp_path):
    from geodem.core import groups

    st = prepare(_ucs(tmp_path, rotation=True), backend="numba").built.state
    st.w[:] = 1.0
    top, bot = groups.members(st, "top"), groups.members(st, "bottom")
    groups.fix(st, "bottom", [1])  # x still free: it may turn
    assert np.all(st.rfree[bot] == 1.0)
    groups.set_velocity(st, "top", [0.0, -0.01])  # wholly prescribed: it stops turning
    assert np.all(st.rfree[top] == 0.0) and np.all(st.w[top] == 0.0)
    others = np.setdiff1d(np.arange(st.n), top)
    assert np.all(st.rfree[others] == 1.0) and np.all(st.w[others] == 1.0)


def test_without_the_option_the_specimen_translates_only(tmp_path):
    assert not prepare(_ucs(tmp_path), backend="numba").built.state.rotation


@pytest.mark.parametrize("key", ["bond_moment", "rolling_friction", "rolling_stiffness"])
def test_rolling_options_need_rotation(tmp_path, key):
    with pytest.raises(WorkflowError, match=f"{key} = 0.5 needs rotation: true"):
        prepare(_ucs(tmp_path, **{key: 0.5}), backend="numba")


def test_materials_of_one_model_are_told_apart_by_their_friction():
    """Turning materials may differ in their rolling options and sit beside translating
    ones, told apart per element by their element friction (rotation_arrays)."""
    from geodem.workflow.material import rotation_arrays

    mats = {"a": ScaledMicroMaterial(**ROCK, rotation=True, bond_moment=0.5),
            "b": ScaledMicroMaterial(**ROCK)}
    cfg = types.SimpleNamespace(materials=mats)
    model = types.SimpleNamespace(dim=2, material_refs=lambda: [(("m",), "a"), (("n",), "b")])
    # a translating material beside a turning one needs its own friction to be told apart
    with pytest.raises(BuildError, match="two share"):
        material_rotation(cfg, model)
    mats["b"] = ScaledMicroMaterial(**dict(ROCK, mu=0.2))
    rot = material_rotation(cfg, model)
    assert rot["per_material"]["b"] == (0.0, 0.5, 1.0, 0.2, False)
    mats["b"] = ScaledMicroMaterial(**ROCK, rotation=True, bond_moment=0.5)
    assert material_rotation(cfg, model) == {"rolling_friction": 0.0, "bond_moment": 0.5,
                                             "rolling_stiffness": 1.0}
    # the same element friction: the elements cannot be told apart
    mats["b"] = ScaledMicroMaterial(**ROCK, rotation=True, bond_moment=0.5, rolling_stiffness=3)
    with pytest.raises(BuildError, match="two share"):
        material_rotation(cfg, model)
    # another friction: per-element values; an element of neither (a wall) takes the largest
    mats["b"] = ScaledMicroMaterial(**dict(ROCK, mu=0.123), rotation=True, bond_moment=2.0,
                                    rolling_stiffness=3)
    rot = material_rotation(cfg, model)
    assert rot["rolling_stiffness"] == 3.0 and rot["bond_moment"] == 2.0
    mu_a = float(mats["a"].mu)
    mu_r, mb, beta = rotation_arrays(rot, [mu_a, 0.123, 0.9])
    assert list(beta) == [1.0, 3.0, 3.0] and list(mb) == [0.5, 2.0, 2.0]
    assert list(mu_r) == [0.0, 0.0, 0.0]


def _layers(tmp_path):
    """workflows/scene_layers.yaml with its rock turning, its clay translating and the two
    bonded across their interface, loaded for 600 steps."""
    root = Path(__file__).resolve().parents[2]
    wf = yaml.safe_load((root / "workflows" / "scene_layers.yaml").read_text())
    wf["materials"]["rock"].update(rotation=True, bond_moment=1.0, rolling_stiffness=4.0)
    wf["model"].pop("interfaces")
    wf["steps"][-1]["nsteps"] = 600
    p = tmp_path / "mixed.yaml"
    p.write_text(yaml.safe_dump(wf, sort_keys=False))
    return p


def test_a_translating_material_beside_a_turning_one_is_held_from_turning(tmp_path):
    from geodem.workflow.runner import Runner

    out = tmp_path / "run"
    prep = prepare(_layers(tmp_path), backend="numba", run_dir=out)
    info, st = prep.built.info["rotation"], prep.built.state
    assert info["per_material"]["clay"]["turns"] is False
    assert info["per_material"]["rock"]["rolling_stiffness"] == 4.0
    clay = st.mu == 0.3
    assert info["per_material"]["clay"]["elements"] == int(clay.sum()) > 100
    assert np.all(st.rfree[clay] == 0.0) and np.all(st.rfree[st.mu == 0.4] == 1.0)
    status, summary = Runner(prep, out, progress=False, echo=False).run()
    assert summary["status"] == "ok" and summary["energy_closure_rel_error"] < 1e-4
    end = prep.built.state  # stepped in place: the rock's elements turned, the clay's did not
    assert np.all(end.w[end.mu == 0.3] == 0.0)
    assert np.abs(end.w[end.mu == 0.4]).max() > 0.0
