"""UCS virtual lab test (workflows/ucs.yaml): the ``specimen`` model + ``uniaxial`` step run from
the CLI; the measured curve and summary keys are physically sensible.

The workflow's material is the library's calibrated sandstone, so E, nu and UCS match the lab
values within the calibration tolerances (docs/calibration.md)."""
import json
import math
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]
UCS = ROOT / "workflows" / "ucs.yaml"
E_TARGET = 15.0e9  # sandstone (materials/sandstone.yaml), the material of workflows/ucs.yaml
CU_TARGET = 75.0e6


@pytest.fixture(scope="module")
def ucs_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ucs") / "run"
    res = CliRunner().invoke(app, ["run", str(UCS), "-o", str(out), "--no-progress"])
    return res, out


def test_ucs_runs(ucs_run):
    res, out = ucs_run
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok"
    for k in ("E", "nu", "ucs", "peak_strain", "cracks_tensile", "cracks_shear"):
        assert k in s and math.isfinite(s[k]), k
    r = s["results"]["ucs"]
    assert 0 < s["E"] < 3 * E_TARGET          # softer than the lattice, never stiffer
    assert 0 < s["ucs"] < 3 * CU_TARGET
    assert 0 < s["peak_strain"] < r["final_strain"]
    assert r["final_stress"] < s["ucs"]        # the stress drops after the peak
    assert r["stopped_by"] == "drop" and r["final_stress"] <= 0.7 * s["ucs"] + 1e-9
    assert s["cracks_tensile"] + s["cracks_shear"] > 0
    # 2-D (plane) isotropic bound -1 < nu < 1; a bulging specimen has nu > 0
    assert 0 < s["nu"] < 1
    assert (out / "stress_strain.png").stat().st_size > 1000
    assert (out / "uniaxial_curve.csv").exists()


def test_ucs_matches_the_calibrated_material(ucs_run):
    """workflows/ucs.yaml uses {library: sandstone}, whose 2-D calibration was made on this
    very specimen: E, nu and UCS are the library's lab values within the calibration
    tolerances (a change to the specimen builder or the engine that moves them fails here:
    recalibrate with 'geodem calibrate sandstone --save')."""
    from geodem.materials_library import load_material

    t = load_material("sandstone").values()
    _, out = ucs_run
    s = json.loads((out / "summary.json").read_text())
    assert s["E"] == pytest.approx(t["E"], rel=0.05)
    assert abs(s["nu"] - t["nu"]) <= 0.03
    assert s["ucs"] == pytest.approx(t["Cu"], rel=0.05)


def test_ucs_reproduces_the_first_packing_of_the_calibration(ucs_run):
    """The shipped UCS workflow is the calibration's first specimen (seed 0, d_mean and
    loading of the record): the record keeps each packing's numbers (``measured_per_packing``,
    stored by ``geodem rock sandstone --packings 3 --save`` when their mean reproduces the
    record's), and this run gives seed 0's to the rounding. A change to the specimen builder
    or the engine that moves them fails here (docs/calibration.md)."""
    from geodem.materials_library import load_material

    cal = load_material("sandstone").calibrated["2d"]
    spec = cal["specimen"]
    assert spec["seed"] == 0 and spec["d_mean"] == 0.005 and spec["strain_rate"] == 0.2
    per = cal.get("measured_per_packing")
    if int(spec.get("packings") or 1) > 1 and not per:
        pytest.fail("the 2-D sandstone record has no measured_per_packing (geodem rock "
                    "sandstone --packings 3 --save)")
    want = per[0] if per else cal["measured"]
    _, out = ucs_run
    s = json.loads((out / "summary.json").read_text())
    assert s["E"] == pytest.approx(want["E"], rel=1e-6)
    assert s["ucs"] == pytest.approx(want["Cu"], rel=1e-6)


def test_ucs_stopped_signalled_and_resumed_is_bit_identical(ucs_run, tmp_path, monkeypatch):
    """One run interrupted twice, each time resumed: first stopped mid-loading
    (``--stop-after-steps``), then, resumed, a SIGTERM arriving in the chunk of steps that
    reaches a sample of the curve. The sample is recorded before the checkpoint (the
    checkpoint used to be taken first, and the resumed curve lacked that row), and the run
    resumed again ends with the same samples, results and final state as the run never
    interrupted (the two interruptions share one run's worth of steps)."""
    import signal

    from geodem.core.engine import Simulation
    from geodem.workflow import runner as wr

    _, full = ucs_run
    out = tmp_path / "res"
    r1 = CliRunner().invoke(app, ["run", str(UCS), "-o", str(out), "--no-progress",
                                  "--stop-after-steps", "8000"])
    assert r1.exit_code == 0, r1.output

    seen = {"n": 0}
    advance_to, sim_run = wr.Runner.advance_to, Simulation.run

    def spy_advance_to(self, target, ctx):
        seen["runner"], seen["target"] = self, target
        seen["n"] += ctx.step.kind == "uniaxial"
        return advance_to(self, target, ctx)

    def signal_on_sample(self, nsteps, *args, **kw):
        out = sim_run(self, nsteps, *args, **kw)
        if seen["n"] == 40 and self.state.step == seen["target"] and "sent" not in seen:
            seen["sent"] = self.state.step
            seen["runner"]._on_signal(signal.SIGTERM, None)
        return out

    monkeypatch.setattr(wr.Runner, "advance_to", spy_advance_to)
    monkeypatch.setattr(Simulation, "run", signal_on_sample)
    r2 = CliRunner().invoke(app, ["run", str(UCS), "-o", str(out), "--no-progress", "--resume"])
    assert r2.exit_code == 143, r2.output
    monkeypatch.undo()
    assert seen["sent"] > 8000
    rows = (out / "uniaxial_curve.csv").read_text().splitlines()
    assert rows[-1].split(",")[0] == str(seen["sent"])  # the sample at the signal's step
    r3 = CliRunner().invoke(app, ["run", str(UCS), "-o", str(out), "--no-progress", "--resume"])
    assert r3.exit_code == 0, r3.output
    a = json.loads((out / "summary.json").read_text())
    b = json.loads((full / "summary.json").read_text())
    assert a["state_sha256"] == b["state_sha256"]
    for k in ("E", "nu", "ucs", "peak_strain", "cracks_tensile", "cracks_shear"):
        assert a[k] == b[k], k
    assert (out / "uniaxial_curve.csv").read_text() == (full / "uniaxial_curve.csv").read_text()


def test_ucs_reports_the_elastic_fit_below_the_crack_initiation_stress(ucs_run):
    """Both fits are in the results: the elastic one (the default, E and nu of the summary),
    which ends where 0.5 % of the bonds have broken, re-fitted here by hand from
    uniaxial_curve.csv, and the whole 10-50 % window. The library sandstone cracks well below
    half its peak, so the window's nu carries crack dilation the elastic fit does not."""
    import csv

    import numpy as np

    from geodem import measure

    _, out = ucs_run
    s = json.loads((out / "summary.json").read_text())
    r = s["results"]["ucs"]
    assert r["fit"] == "elastic" and s["nu"] == r["elastic"]["nu"] and s["E"] == r["elastic"]["E"]
    rows = list(csv.DictReader(open(out / "uniaxial_curve.csv")))
    col = {k: np.array([float(x[k]) for x in rows]) for k in rows[0]}
    sig, cracks = col["axial_stress"], col["cracks_total"]
    ipk = int(np.argmax(sig))
    el = r["elastic"]
    lo, hi = el["fit_window"]
    assert lo == 0.1 and 0.1 < hi < 0.5
    # the crack-initiation stress: the last stress before 0.5 % of the bonds broke
    first = int(np.flatnonzero(cracks[:ipk + 1] > 0.005 * r["bonds"])[0])
    assert el["crack_initiation_stress"] == pytest.approx(sig[:first].max(), rel=1e-12)
    assert hi == pytest.approx(el["crack_initiation_stress"] / sig[ipk], rel=1e-12)
    assert el["nu"] == pytest.approx(measure.poisson_ratio(
        col["axial_strain"], col["lateral_strain"], (lo, hi), stress=sig), rel=1e-9)
    assert el["nu"] < r["window"]["nu"] - 0.01  # dilation of the cracks left out
    # E moves less than nu: the window's cracks soften it by a few per cent (the turning
    # library sandstone, 2026-12-05: window 14.07 GPa against 15.22 below the crack
    # initiation at 0.26 of the peak, 0.925; the translating one of commit 6d7aae0: within 3 %)
    assert 0.85 < r["window"]["E"] / el["E"] <= 1.0


def test_a_bad_fit_window_names_the_field(tmp_path):
    res = CliRunner().invoke(app, ["validate", str(UCS), "--set", "steps.0.fit_window=[0.5,0.2]"])
    assert res.exit_code == 2
    assert "fit_window" in res.output and "allowed 0 <= lo < hi <= 1" in res.output
