"""Long calibration checks go on where they stopped: a run that ended ok with the same
workflow is reused, an interrupted one goes on from its checkpoint to the same bits."""
import json

import pytest

from geodem.materials_library import load_material
from geodem.studies import calibrate as C


@pytest.fixture(scope="module")
def spec_el():
    mat = load_material("sandstone")
    el = dict(mat.calibrated["2d"]["element"])
    spec = C.CalibrationSpec(targets=mat.values(), name="sandstone", ucs_size=(0.03, 0.06),
                             structure={k: el[k] for k in ("packing", "rotation", "bond_moment",
                                                           "rolling_friction",
                                                           "rolling_stiffness")})
    return spec, el


def test_a_finished_run_is_reused_and_an_interrupted_one_goes_on(spec_el, tmp_path,
                                                                   monkeypatch, capsys):
    from geodem.workflow import run_workflow

    spec, el = spec_el
    doc = C._tension_workflow(spec, el)
    fresh = C._run(doc, tmp_path / "fresh", None)
    # interrupted after 300 steps (a checkpoint is written), then resumed by _run
    C._run(doc, tmp_path / "cut", None)  # writes workflow.yaml and a finished run ...
    wf = tmp_path / "cut" / "workflow.yaml"
    code, cut = run_workflow(wf, tmp_path / "cut" / "out", overwrite=True, echo=False,
                             progress=False, stop_after_steps=300)
    assert cut["status"] == "interrupted"
    resumed = C._run(doc, tmp_path / "cut", None, resume=True)
    assert resumed["status"] == "ok" and resumed["state_sha256"] == fresh["state_sha256"]
    assert resumed["tensile_strength"] == fresh["tensile_strength"]
    # ... and once finished it is read back without running
    import geodem.workflow as wfmod

    monkeypatch.setattr(wfmod, "run_workflow", lambda *a, **k: pytest.fail("ran again"))
    capsys.readouterr()
    with C.runs_told():  # and says so
        again = C._run(doc, tmp_path / "cut", None, resume=True)
    assert again["state_sha256"] == fresh["state_sha256"]
    told = capsys.readouterr().err
    assert "cut: finished before, reused" in told
    assert C.RUN_PROGRESS_ENV not in __import__("os").environ
    # a changed workflow is not passed off as finished: it runs
    monkeypatch.undo()
    changed = dict(doc, steps=[dict(doc["steps"][0], strain_rate=0.1)])
    with C.runs_told():
        other = C._run(changed, tmp_path / "cut", None, resume=True)
    told = capsys.readouterr().err
    assert "cut: building and running" in told and f"of {other['n_elements']:,} elements" in told
    assert other["status"] == "ok" and other["state_sha256"] != fresh["state_sha256"]
    assert json.loads((tmp_path / "cut" / "out" / "summary.json").read_text())[
        "state_sha256"] == other["state_sha256"]


def test_an_interrupted_run_says_how_to_go_on(spec_el, tmp_path, monkeypatch):
    import geodem.workflow as wfmod

    real = wfmod.run_workflow
    monkeypatch.setattr(wfmod, "run_workflow",
                        lambda *a, **k: real(*a, stop_after_steps=300, **k))
    spec, el = spec_el
    with pytest.raises(C.RunInterrupted, match="with --resume goes on") as info:
        C._run(C._tension_workflow(spec, el), tmp_path / "t", None)
    assert info.value.code == 130
    assert (tmp_path / "t" / "out" / "checkpoints").is_dir()


def test_the_friction_stages_run_apart_read_the_two_stage_test(spec_el, tmp_path):
    """measure_friction runs sigma3 = 0 and the confined stage as two workflows (so several
    packings' stages share the processes): each stage starts from the same state as in the
    one two-stage workflow, so both peaks are the same to the bit (each loaded at 4 x the
    unconfined stage's rate here, to keep the test short; the calibration loads its confined
    stage faster, C.friction_stage_rate)."""
    spec, el = spec_el
    rate = 4.0 * C.friction_stage_rate(spec, 0.0)

    def run(pressures, name):
        doc = C._triaxial_workflow(spec, el, pressures)
        doc["steps"][0]["strain_rate"] = rate
        return C._run(doc, tmp_path / name, None)["peak_strengths"]

    both = run(None, "both")
    s3 = C.friction_sigma3(spec)
    assert both[1] > both[0] > 0.0
    assert run([0.0], "unconfined") + run([s3], "confined") == both
