"""The ``geodem`` command line: info, bench --json, user errors (exit 2)."""
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[2]


def flat(text: str) -> str:
    """Rich boxes and line wrapping removed: words separated by single spaces."""
    return re.sub(r"[\s│╭╮╰╯─┃━]+", " ", text)


def invoke(*args, env=None):
    return runner.invoke(app, list(args), env=env)


def test_info_lists_numba():
    res = invoke("info")
    assert res.exit_code == 0, res.output
    assert "numba" in res.stdout
    assert "backends" in res.stdout


def test_info_json():
    res = invoke("info", "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["backends"]["numba"]["available"] is True
    assert data["versions"]["geodem"]


def test_library_prints_every_rock_and_both_dimensions():
    from geodem.materials_library import list_materials

    res = invoke("library", "--markdown")
    assert res.exit_code == 0, res.output
    assert "2-D:" in res.stdout and "3-D:" in res.stdout
    for name in list_materials():
        assert res.stdout.count(f"| {name} (") == 2, name
    assert invoke("library", "--dim", "4").exit_code == 2


def test_bench_json():
    res = invoke("bench", "--sizes", "2000", "--backends", "numba", "--steps", "20", "--json")
    assert res.exit_code == 0, res.output
    recs = json.loads(res.stdout)  # stdout holds only the JSON list
    assert isinstance(recs, list) and len(recs) == 1
    r = recs[0]
    for key in ("backend", "dim", "n", "element_steps_per_s", "bytes_per_element",
                "contacts_per_element", "steps", "wall_s", "threads"):
        assert key in r
    assert r["backend"] == "numba" and r["dim"] == 3 and r["steps"] == 20
    assert r["n"] > 1000
    assert r["element_steps_per_s"] > 0 and r["bytes_per_element"] > 0
    assert 6 < r["contacts_per_element"] <= 12
    assert r["bonds_broken"] == 0


def test_bench_repeat_reports_every_run_and_the_median_one():
    res = invoke("bench", "--sizes", "2000", "--backends", "numba", "--steps", "5",
                 "--repeat", "3", "--json")
    assert res.exit_code == 0, res.output
    (r,) = json.loads(res.stdout)
    assert r["repeats"] == 3 and r["steps"] == 5
    runs = r["element_steps_per_s_runs"]
    assert len(runs) == 3 and len(r["kernel_element_steps_per_s_runs"]) == 3
    assert r["element_steps_per_s"] == sorted(runs)[1]  # the median run's record
    assert r["element_steps_per_s_best"] == max(runs)
    assert r["kernel_element_steps_per_s"] == sorted(r["kernel_element_steps_per_s_runs"])[1]
    assert len(r["load_average_runs"]) == 3
    # every run stepped its own copy of the same specimen
    assert r["bonds_broken"] == 0 and r["rebuilds"] is not None
    assert flat(res.stderr).count("run 3 of 3") == 1


def test_bench_merge_repeats_picks_the_median_run():
    from geodem.bench import _merge_repeats

    recs = [{"element_steps_per_s": v, "kernel_element_steps_per_s": k, "load_average": l,
             "wall_s": w} for v, k, l, w in ((3.0, 9.0, 0.5, 1.0), (1.0, 7.0, 1.5, 3.0),
                                             (2.0, 8.0, 1.0, 2.0), (5.0, 4.0, 0.1, 0.5))]
    r = _merge_repeats(recs)
    # even count: the lower of the two middle runs (speeds 2 and 3 -> 2), its own wall time
    assert r["element_steps_per_s"] == 2.0 and r["wall_s"] == 2.0
    assert r["element_steps_per_s_runs"] == [3.0, 1.0, 2.0, 5.0]
    assert r["element_steps_per_s_best"] == 5.0
    assert r["kernel_element_steps_per_s"] == 7.5  # median of 9, 7, 8, 4
    assert r["kernel_element_steps_per_s_best"] == 9.0
    assert r["load_average_runs"] == [0.5, 1.5, 1.0, 0.1] and r["repeats"] == 4


def test_bench_bad_repeat():
    import geodem.bench

    with pytest.raises(geodem.bench.BenchError, match="repeat must be an integer from 1 to 100"):
        geodem.bench.run_bench(sizes=[2000], backends=["numba"], repeat=0)
    res = invoke("bench", "--sizes", "2000", "--repeat", "0")
    assert res.exit_code == 2
    assert "--repeat" in flat(res.output)


def test_bench_numpy_limited_and_memory_skip(monkeypatch):
    res = invoke("bench", "--sizes", "2000", "--backends", "numba,numpy", "--steps", "3",
                 "--numpy-max", "1000", "--json")
    assert res.exit_code == 0, res.output
    assert [r["backend"] for r in json.loads(res.stdout)] == ["numba"]
    assert "numpy skipped" in flat(res.stderr)

    import geodem.bench

    monkeypatch.setattr(geodem.bench, "available_memory", lambda: 1000)
    notes = []
    assert geodem.bench.run_bench(sizes=[2000], backends=["numba"], progress=notes.append) == []
    assert any("skipped" in m and "available" in m for m in notes)


@pytest.mark.parametrize("value", ["abc", "10,x", "50", "1.5e3.2", ""])
def test_bench_bad_sizes_exit_2(value):
    res = invoke("bench", "--sizes", value, "--json")
    assert res.exit_code == 2
    msg = flat(res.stderr)
    assert "--sizes" in msg and "integers >= 100" in msg
    assert "Traceback" not in res.output
    assert res.stdout == ""


def test_bench_unknown_backend_exit_2():
    res = invoke("bench", "--sizes", "2000", "--backends", "numba,fortran")
    assert res.exit_code == 2
    msg = flat(res.stderr)
    assert "--backends" in msg and "fortran" in msg
    assert "auto, numba, numpy, cupy" in msg
    assert "Traceback" not in res.output


def test_error_text_keeps_its_brackets():
    """A user error naming an install extra prints it as written (the markup escaped once)."""
    from geodem.backends import BACKENDS, _load_all

    _load_all()
    if BACKENDS["cupy"].is_available():
        pytest.skip("a usable GPU: the cupy backend is no error here")
    res = invoke("bench", "--sizes", "2000", "--backends", "cupy")
    assert res.exit_code == 2
    msg = flat(res.stderr)
    assert "backend 'cupy' is not usable here" in msg
    assert "geodem[gpu]" in msg and "\\[" not in msg


def test_python_dash_m():
    res = subprocess.run([sys.executable, "-m", "geodem", "--version"], capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert res.returncode == 0 and "geodem" in res.stdout
    res = subprocess.run([sys.executable, "-m", "geodem", "bench", "--sizes", "abc"],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert res.returncode == 2 and "--sizes" in res.stderr and "Traceback" not in res.stderr


TWO_BALLS = str(ROOT / "workflows" / "two_balls.yaml")


@pytest.mark.parametrize("setting,field", [
    ("materials.paper.rho=.inf", "materials.paper.rho"),
    ("materials.paper.kn=.nan", "materials.paper.kn"),
    ("steps.oscillate.nsteps=null", None),  # with the next one: duration = inf
])
def test_non_finite_numbers_are_refused(setting, field):
    args = ["validate", TWO_BALLS, "--set", setting]
    if field is None:
        args += ["--set", "steps.oscillate.duration=.inf"]
        field = "steps[0].duration"
    res = invoke(*args)
    assert res.exit_code == 2, res.output
    assert f"{field}: Input should be a finite number" in flat(res.output)
    assert "Traceback" not in res.output


def test_a_model_whose_numbers_overflow_is_a_user_error():
    res = invoke("validate", TWO_BALLS, "--set", "model.diameter=1e308")
    assert res.exit_code == 2, res.output
    out = flat(res.output)
    assert "model: cannot build the model: ZeroDivisionError" in out
    assert "allowed: lengths, densities and stiffnesses of a physical magnitude" in out


def test_run_into_an_impossible_folder(tmp_path):
    (tmp_path / "afile").write_text("x")
    res = invoke("run", TWO_BALLS, "-o", str(tmp_path / "afile" / "sub"), "--no-progress")
    assert res.exit_code == 2, res.output
    assert "(run directory): cannot create the folder: Not a directory" in flat(res.output)


def test_schema_into_a_folder_is_a_user_error(tmp_path):
    res = invoke("schema", "-o", str(tmp_path))
    assert res.exit_code == 2, res.output
    assert "cannot write the schema there (Is a directory)" in flat(res.output)


def test_study_refuses_bad_lists_and_foreign_folders(tmp_path):
    for opt, value in (("--across", "abc"), ("--across", "0"), ("--dt-fractions", "-1")):
        res = invoke("study", "ucs", "-o", str(tmp_path / "s"), opt, value)
        assert res.exit_code == 2, res.output
        assert opt in flat(res.output) and "BadParameter" not in res.output
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("x")
    res = invoke("study", "ucs", "-o", str(tmp_path / "mine"), "--across", "10")
    assert res.exit_code == 2 and "no study.json" in flat(res.output)
    res = invoke("study", "ucs", "-o", str(tmp_path / "new"), "--workflow",
                 str(tmp_path / "nothere.yaml"))
    assert res.exit_code == 2 and not (tmp_path / "new").exists()


def test_calibrate_bad_prefer(tmp_path):
    res = invoke("calibrate", "granite", "-o", str(tmp_path / "c"), "--prefer", "xx")
    assert res.exit_code == 2, res.output
    assert "--prefer 'xx': allowed: Cu or Tu" in flat(res.output)


def test_calibrate_bad_recipe_writes_nothing(tmp_path):
    res = invoke("calibrate", "granite", "-o", str(tmp_path / "c"), "--recipe", "mine")
    assert res.exit_code == 2, res.output
    assert "--recipe 'mine': allowed: library" in flat(res.output)
    assert not (tmp_path / "c").exists()


def test_calibrate_refuses_a_rock_outside_the_charted_region(tmp_path):
    import yaml

    from geodem.studies.reach import shipped_chart

    doc = yaml.safe_load((ROOT / "materials" / "sandstone.yaml").read_text())
    doc.pop("calibrated", None)
    doc["name"] = "too_strong_in_compression"
    top = shipped_chart(2)["bounds"]["ratio"][1]
    doc["properties"]["Cu"]["value"] = 2.0 * top * doc["properties"]["Tu"]["value"]
    path = tmp_path / "odd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    before = path.read_text()
    res = invoke("calibrate", str(path), "-o", str(tmp_path / "c"))
    assert res.exit_code == 2, res.output
    out = flat(res.output)
    assert str(path) in out and "is outside what the 2-D isotropic packing reaches" in out
    assert f"{top:.3g}" in out and "--force" in out
    assert not (tmp_path / "c").exists() and path.read_text() == before


def test_rock_save_refuses_a_changed_micro_structure(tmp_path):
    """``geodem rock --save`` stores a check of the stored calibration only: with a
    micro-structure override it exits 2 before anything is written."""
    path = tmp_path / "sandstone.yaml"
    path.write_text((ROOT / "materials" / "sandstone.yaml").read_text())
    before = path.read_text()
    res = invoke("rock", str(path), "-o", str(tmp_path / "r"), "--bond-moment", "10",
                 "--save")
    assert res.exit_code == 2, res.output
    assert "--save stores a check of the stored calibration: drop --bond-moment" in \
        flat(res.output)
    assert not (tmp_path / "r").exists() and path.read_text() == before


def test_bench_with_nothing_run_exits_2(monkeypatch):
    import geodem.bench

    monkeypatch.setattr(geodem.bench, "available_memory", lambda: 1000)
    res = invoke("bench", "--sizes", "2000", "--backends", "numba", "--json")
    assert res.exit_code == 2
    assert "no run was made" in flat(res.stderr)


def test_two_balls_too_short_to_measure_warns_and_resumes(tmp_path):
    out = tmp_path / "tb"
    res = invoke("run", TWO_BALLS, "-o", str(out), "--set", "steps.oscillate.nsteps=50",
                 "--no-progress")
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["period_rel_error"] is None  # NaN in JSON: nothing was measured
    assert any("shows 0 displacement peak(s)" in w and "at least 2.5 periods" in w
               for w in s["warnings"])
    assert "warning: two_balls_check" in flat(res.output)
    res = invoke("run", TWO_BALLS, "-o", str(out), "--set", "steps.oscillate.nsteps=50",
                 "--resume", "--no-progress")
    assert res.exit_code == 0, res.output
    assert "already complete" in flat(res.output)


@pytest.mark.parametrize("cmd", ["rock", "calibrate"])
def test_an_unknown_fit_is_a_user_error(tmp_path, cmd):
    res = CliRunner().invoke(app, [cmd, "sandstone", "-o", str(tmp_path / "o"), "--fit", "x"])
    assert res.exit_code == 2
    assert "--fit 'x': allowed: window or elastic" in res.output
    assert not (tmp_path / "o").exists()


def test_calibrate_start_file_errors_name_the_field_and_write_nothing(tmp_path):
    bad = tmp_path / "start.yaml"
    bad.write_text("3d:\n  element:\n    kn_per_d: 1.0e11\n    mu: -0.2\n")
    res = invoke("calibrate", "marble", "--dim", "3", "--start", str(bad),
                 "-o", str(tmp_path / "c"))
    assert res.exit_code == 2, res.output
    assert "'3d.element.ks_per_d' = None: allowed: a number > 0" in flat(res.output)
    res = invoke("calibrate", "marble", "--start", str(bad), "-o", str(tmp_path / "c"))
    assert res.exit_code == 2 and "no '2d.element'" in flat(res.output)
    assert not (tmp_path / "c").exists()


def test_calibrate_starts_from_a_stored_record(tmp_path):
    """--start with a material file: the first iteration runs the record's elements."""
    import yaml

    path = ROOT / "materials" / "sandstone.yaml"
    el = yaml.safe_load(path.read_text())["calibrated"]["2d"]["element"]
    res = invoke("calibrate", "sandstone", "--start", str(path), "--iterations", "1",
                 "--d-mean", "0.02", "--no-friction", "--packings", "1",
                 "-o", str(tmp_path / "c"))
    assert res.exit_code in (0, 1), res.output
    first = json.loads((tmp_path / "c" / "summary.json").read_text())["history"][0]["element"]
    for key in ("kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2", "mu"):
        assert first[key] == pytest.approx(el[key], rel=1e-12)


def test_calibrate_starts_from_the_nearest_library_rock_of_its_recipe(tmp_path, monkeypatch):
    """``geodem calibrate marble`` (the stored 2-D recipe: turning elements, BETA 2) starts
    from the step off the limestone's record (the nearest other rock of that recipe: nu 0.25
    both, Cu / Tu 13.3 against the granite's 20), says so,
    and ``--start prior`` takes the prior rates; the calibration itself is not run here."""
    from geodem.studies import calibrate as C

    seen = []

    def capture(spec, out, progress=None, start=None, start_from=None, **kw):
        seen.append((spec, start, start_from))
        raise KeyboardInterrupt  # stop before any run

    monkeypatch.setattr(C, "calibrate", capture)
    res = invoke("calibrate", "marble", "-o", str(tmp_path / "c"))
    assert "starting from the library's limestone (2-D record" in flat(res.output)
    spec, start, start_from = seen[-1]
    assert start_from == "library limestone"
    assert start == C.library_start(spec)[0]
    res = invoke("calibrate", "marble", "--start", "prior", "-o", str(tmp_path / "d"))
    assert "starting from" not in flat(res.output)
    assert seen[-1][1] is None and seen[-1][2] is None
    assert seen[-1][0].check  # the Brazilian check runs unless told
    invoke("calibrate", "marble", "--no-check", "-o", str(tmp_path / "e"))
    assert seen[-1][0].check is False
