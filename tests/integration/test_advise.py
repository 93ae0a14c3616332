"""geodem advise: sizes and estimates from the validated, built workflow, and its suggestions."""
import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from geodem.advise import advise, report_lines
from geodem.cli import app
from geodem.workflow import prepare
from geodem.workflow.runner import EST_RATE

pytestmark = pytest.mark.usefixtures("one_numba_thread")

WF = Path(__file__).resolve().parents[2] / "workflows"
KEYS = {"workflow", "model", "dim", "n_elements", "backend", "memory_bytes",
        "bytes_per_element", "state_bytes", "dt", "stable_dt", "steps", "total_steps",
        "element_steps", "throughput", "wall_time_s", "initial_overlap", "suggestions"}


def test_two_balls_sizes_equal_what_prepare_builds_and_the_estimate_is_consistent():
    a = advise(WF / "two_balls.yaml", backend="numba")
    prep = prepare(WF / "two_balls.yaml", backend="numba")
    assert a["n_elements"] == prep.built.state.n == prep.plan.n_elements == 8
    assert a["dim"] == 2 and a["total_steps"] == prep.plan.total_steps == 500
    assert a["memory_bytes"] == prep.plan.memory_bytes > 0
    assert a["memory_bytes"] == a["n_elements"] * a["bytes_per_element"]
    assert 0 < a["state_bytes"] <= a["memory_bytes"]
    assert a["element_steps"] == 500 * 8
    thr = a["throughput"]
    assert thr["source"].startswith("measured here") and thr["calibration"]["steps"] > 0
    # the wall time is at least the stepping at the measured throughput
    assert a["wall_time_s"] >= a["element_steps"] / thr["element_steps_per_s"] > 0
    assert a["dt"] == prep.plan.dt and a["dt"] < a["stable_dt"]
    topics = [s["topic"] for s in a["suggestions"]]
    assert topics[:2] == ["dimension", "time_step"]
    ts = a["suggestions"][1]
    assert ts["dt_fraction"] == pytest.approx(0.02, rel=1e-9)
    assert ts["dt_fraction"] < ts["suggested_quasi_static_fraction"] < ts["refusal_fraction"]
    assert a["initial_overlap"] == pytest.approx(0.02, rel=1e-9)


def test_documented_throughput_without_calibration_and_ucs_at_a_small_size():
    sets = ["model.size=[0.04,0.08]"]
    a = advise(WF / "ucs.yaml", sets=sets, backend="numba", calibrate=False)
    prep = prepare(WF / "ucs.yaml", sets=sets, backend="numba")
    assert a["n_elements"] == prep.built.state.n > 50
    assert a["model"] == "specimen" and a["steps"][0]["kind"] == "uniaxial"
    assert a["throughput"]["element_steps_per_s"] == EST_RATE["numba"]
    assert "docs/performance.md" in a["throughput"]["source"]
    assert a["wall_time_s"] == pytest.approx(prep.plan.runtime_s, rel=1e-12)  # the same rate


def test_a_thin_3d_block_is_advised_to_go_2d(tmp_path):
    wf = {"metadata": {"name": "slab"},
          "model": {"type": "lattice_block", "dim": 3, "counts": [12, 10, 2], "diameter": 0.01,
                    "material": "rock"},
          "materials": {"rock": {"rho": 2650.0, "kn": 2.0e7, "ks": 6.0e6}},
          "steps": [{"kind": "run", "nsteps": 10}]}
    p = tmp_path / "slab.yaml"
    p.write_text(yaml.safe_dump(wf))
    a = advise(p, calibrate=False)
    dim = a["suggestions"][0]
    assert a["dim"] == 3 and dim["two_d_possible"] is True
    assert dim["thin_axis"] == "z" and dim["thin_layers"] <= 4
    assert dim["two_d_elements"] == pytest.approx(a["n_elements"] / dim["thin_layers"], abs=1)
    assert "model.dim: 2" in dim["text"]
    # a thick block is not
    wf["model"]["counts"] = [8, 8, 8]
    p.write_text(yaml.safe_dump(wf))
    dim = advise(p, calibrate=False)["suggestions"][0]
    assert dim["two_d_possible"] is False and "3-D needed" in dim["text"]


def test_resolution_for_a_target_error_from_a_speed_accuracy_csv(tmp_path):
    csv = tmp_path / "speed_accuracy.csv"
    head = ("case,backend,precision,dt_fraction,dt_of,resolution,resolution_of,damping,"
            "n_elements,steps,wall_s,error,pareto,status\n")
    rows = ["two_balls,numba,float64,0.02,T_min,,-,0,4,500,0.009,0.04,1,ok",
            "two_balls,numba,float64,0.005,T_min,,-,0,4,2000,0.037,0.0025,1,ok",
            "two_balls,numba,float64,0.002,T_min,,-,0,4,5000,0.10,0.0004,1,ok",
            "two_balls,numba,float64,0.2,T_min,,-,0,4,50,0.001,0.0,0,failed: x",
            "ucs,numba,float64,0.1,T_min,30,elements across,-,465,9,10.4,0.013,1,ok"]
    csv.write_text(head + "\n".join(rows) + "\n")
    a = advise(WF / "two_balls.yaml", calibrate=False, target_error=0.01, speed_csv=csv)
    res = a["suggestions"][-1]
    assert res["topic"] == "resolution" and res["case"] == "two_balls" and res["reached"]
    assert res["best"]["dt_fraction"] == 0.005  # the fastest under 1 % (the failed row ignored)
    a = advise(WF / "two_balls.yaml", calibrate=False, target_error=1e-4, speed_csv=csv)
    res = a["suggestions"][-1]
    assert res["reached"] is False and res["best"]["error"] == 0.0004
    assert "no point reached" in res["text"]
    # no CSV given and none at the default place: no resolution suggestion, no error
    a = advise(WF / "two_balls.yaml", calibrate=False, speed_csv=tmp_path / "none.csv")
    assert "no speed-accuracy results" in a["suggestions"][-1]["text"]


def test_cli_json_text_and_bad_input_exit_2(tmp_path):
    r = CliRunner()
    res = r.invoke(app, ["advise", str(WF / "two_balls.yaml"), "--json", "--no-calibrate"])
    assert res.exit_code == 0, res.output
    a = json.loads(res.stdout)
    assert KEYS <= set(a) and a["n_elements"] == 8
    res = r.invoke(app, ["advise", str(WF / "two_balls.yaml"), "--no-calibrate"])
    assert res.exit_code == 0
    assert "8 elements" in res.stdout and "estimated wall time" in res.stdout
    assert "suggestions:" in res.stdout
    assert report_lines(a)[0] in res.stdout.replace("\n", "")  # same lines as report_lines
    bad = tmp_path / "bad.yaml"
    bad.write_text((WF / "two_balls.yaml").read_text().replace("amplitude: 0.01",
                                                               "amplitude: -1"))
    res = r.invoke(app, ["advise", str(bad)])
    assert res.exit_code == 2 and "bad.yaml:" in res.output and "amplitude" in res.output
    res = r.invoke(app, ["advise", str(WF / "two_balls.yaml"), "--target-error", "2"])
    assert res.exit_code == 2
