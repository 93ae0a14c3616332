"""`geodem rock --packings N`: one measurement per packing seed, and their mean and sample
standard deviation (the runs are replaced by responses made up per seed)."""
import json
import math

import pytest
from typer.testing import CliRunner

import geodem.studies.calibrate as C
from geodem.cli import app
from geodem.materials_library import load_material


@pytest.fixture
def fake_runs(monkeypatch):
    def measure(spec, el, folder):
        folder.mkdir(parents=True, exist_ok=True)
        k = spec.seed
        return {"E": 10e9 + 1e9 * k, "nu": 0.2 + 0.01 * k, "Cu": 60e6 + 2e6 * k,
                "Tu": 4e6, "wall_time_s": 1.0}

    def brazilian(spec, el, folder):
        return {"tensile_strength": 4e6 * (1 + spec.seed), "over_target": 1.0 + spec.seed,
                "crack_start_offset": 0.1, "stopped_by": "drop", "wall_time_s": 1.0}

    def friction(spec, el, folder):
        phi = math.inf if spec.seed == 99 else 30.0 + 2.0 * spec.seed
        return {"phi": phi, "peak_0": 1.0, "peak_c": 2.0, "sigma3": 1.0, "wall_time_s": 1.0}

    # made-up responses live in this process: no packing measured in a process of its own
    monkeypatch.setattr(C, "jobs_for", lambda packings, jobs: 1)
    monkeypatch.setattr(C, "measure", measure)
    monkeypatch.setattr(C, "brazilian_check", brazilian)
    monkeypatch.setattr(C, "measure_friction", friction)


def test_three_packings_give_each_seed_and_the_spread(tmp_path, fake_runs):
    out = tmp_path / "r"
    res = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(out), "--packings", "3",
                                   "--seed", "2", "--friction"])
    assert res.exit_code == 0, res.output
    for seed in (2, 3, 4):
        assert f"seed {seed}:" in res.output
        one = json.loads((out / f"packing_{seed}" / "summary.json").read_text())
        assert one["seed"] == seed and one["friction_test"]["phi"] == 30.0 + 2.0 * seed
    s = json.loads((out / "summary.json").read_text())
    assert s["seeds"] == [2, 3, 4]
    # E 12, 13, 14 GPa: mean 13, sample std 1; phi 34, 36, 38: mean 36, std 2
    assert s["mean"]["E"] == pytest.approx(13e9) and s["std"]["E"] == pytest.approx(1e9)
    assert s["mean"]["phi"] == pytest.approx(36.0) and s["std"]["phi"] == pytest.approx(2.0)
    assert s["mean"]["Brazilian"] == pytest.approx(16e6)
    assert s["mean"]["Cu/Tu"] == pytest.approx(16.5)  # Cu 64, 66, 68 MPa over 4 MPa
    assert "mean +- std over the packings" in res.output


def test_one_packing_keeps_the_single_summary(tmp_path, fake_runs):
    out = tmp_path / "r"
    res = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(out)])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["measured"]["E"] == pytest.approx(10e9) and "mean" not in s
    assert not list(out.glob("packing_*"))


def test_a_packing_without_a_confined_peak_leaves_phi_out_of_the_spread(tmp_path, fake_runs):
    out = tmp_path / "r"
    res = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(out), "--packings", "2",
                                   "--seed", "98", "--friction"])
    assert res.exit_code == 0, res.output
    assert "phi: no confined peak" in res.output
    s = json.loads((out / "summary.json").read_text())
    assert "phi" not in s["mean"] and s["packings"][1]["friction_test"]["phi"] is None


@pytest.mark.parametrize("bad", [["--packings", "0"], ["--packings", "21"], ["--seed", "-1"]])
def test_bad_packing_options_are_refused(tmp_path, bad):
    res = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(tmp_path / "x"), *bad])
    assert res.exit_code == 2, res.output


def test_an_interrupted_check_exits_with_the_signal_and_says_resume(tmp_path, monkeypatch):
    def stopped(*args, **kwargs):
        raise C.RunInterrupted(130, "R/brazilian was interrupted; the same command with "
                                    "--resume goes on from it")

    monkeypatch.setattr(C, "rock_packings", stopped)
    res = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(tmp_path / "r")])
    assert res.exit_code == 130
    assert "interrupted" in res.output and "--resume" in res.output


def test_resume_refuses_a_folder_of_another_rock_and_keeps_it(tmp_path, fake_runs):
    out = tmp_path / "r"
    assert CliRunner().invoke(app, ["rock", "sandstone", "-o", str(out), "--packings",
                                    "2"]).exit_code == 0
    before = (out / "packing_0" / "summary.json").read_text()
    res = CliRunner().invoke(app, ["rock", "granite", "-o", str(out), "--packings", "2",
                                   "--resume"])
    assert res.exit_code == 2 and "holds a check of sandstone in 2-D" in res.output
    assert (out / "packing_0" / "summary.json").read_text() == before
    again = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(out), "--packings", "2",
                                     "--resume"])
    assert again.exit_code == 0
    assert " ".join(again.output.split()).count("(finished before, reused)") == 2


def test_the_friction_stages_of_several_packings_share_the_processes(monkeypatch, tmp_path):
    """With two processes, the friction tests of three packings run as six stage jobs, the
    confined (longer) ones first, and each packing's phi comes from its own two peaks."""
    from geodem.studies.friction import two_point_angle

    order = []

    def stage(spec, el, folder, k):
        order.append((folder.name, k))
        return (100.0e6 + spec.seed * 1e6 + (50.0e6 if k else 0.0)), 2.0 + k

    def serial(fn, calls, jobs):
        assert fn is stage and jobs == 2
        return [fn(*a) for a in calls]

    monkeypatch.setattr(C, "_friction_stage", stage)
    monkeypatch.setattr(C, "_side_by_side", serial)
    mat = load_material("sandstone")
    spec = C.CalibrationSpec(targets=mat.values(), name="sandstone", packings=3, jobs=2)
    out = C.over_packings(C.measure_friction, spec, {}, tmp_path)
    assert order == [(f"packing_{s}", 1) for s in range(3)] + [(f"packing_{s}", 0)
                                                                for s in range(3)]
    s3 = C.friction_sigma3(spec)
    for s, run in enumerate(out["per_packing"]):
        assert run["peak_0"] == 100.0e6 + s * 1e6 and run["peak_c"] == 150.0e6 + s * 1e6
        assert run["phi"] == two_point_angle(run["peak_0"], run["peak_c"], s3)
        assert run["wall_time_s"] == 5.0
    assert out["wall_time_s"] == 15.0
    # one packing: its two stages one after the other, the same numbers
    order.clear()
    one = C.measure_friction(spec, {}, tmp_path / "packing_0")
    assert order == [("packing_0", 0), ("packing_0", 1)]
    assert one == out["per_packing"][0]


def test_a_check_loads_the_record_at_its_calibration_rate(tmp_path, monkeypatch, fake_runs):
    """`geodem rock` measures a stored record with the UCS loading rate it was calibrated at
    (the library's 0.2 /s), not the default of new calibrations (0.5 /s), and a finished
    packing measured at another rate is not passed off as this one on --resume."""
    seen = []
    measure = C.measure  # the made-up one

    def spy(spec, el, folder):
        seen.append(spec.strain_rate)
        return measure(spec, el, folder)

    monkeypatch.setattr(C, "measure", spy)
    mat = load_material("sandstone")
    stored = mat.calibrated["2d"]["specimen"]["strain_rate"]
    res = CliRunner().invoke(app, ["rock", "sandstone", "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    new = C.CalibrationSpec(targets=mat.values())
    assert seen == [stored] and stored != C.ucs_strain_rate(new)
    old = C.CalibrationSpec(targets=mat.values(), strain_rate=stored)
    assert C.rock_inputs(old, {}, False) != C.rock_inputs(new, {}, False)
