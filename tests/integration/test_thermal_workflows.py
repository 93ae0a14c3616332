"""Thermal workflows (geodem/cases/thermal.py, workflows/thermal_rod.yaml,
workflows/thermal_cracking.yaml).

* the rod: a bonded chain with fixed end temperatures against the Fourier series of the heat
  equation, at the end (rel_error <= 0.02, measured 6.5e-5) and along the recorded history of
  its middle element; a run stopped and resumed from a checkpoint ends bit-identical (the field
  is restored, not attached twice);
* the heated borehole (a scene composition, at small size): the heater holds its temperature,
  thermal expansion breaks bonds in tension across radial cracks (none without expansion: slow
  control);
* bad input: exit status 2 with the field named.
"""
import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from geodem.cli import app
from geodem.fields.thermal import rod_solution
from geodem.workflow.schema import load_builtins

load_builtins()

ROOT = Path(__file__).resolve().parents[2]
ROD = ROOT / "workflows" / "thermal_rod.yaml"
CRACKING = ROOT / "workflows" / "thermal_cracking.yaml"


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def _run(path, out, *sets, extra=(), code=0):
    args = ["run", str(path), "-o", str(out), "--no-progress", *extra]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == code, res.output
    return json.loads((out / "summary.json").read_text()) if code == 0 else res.output


def _rows(path):
    with open(path) as f:
        r = list(csv.reader(f))
    return r[0], np.array(r[1:], float)


@pytest.fixture(scope="module")
def rod_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rod") / "run"
    return _run(ROD, out), out


def test_rod_matches_the_fourier_series(rod_run):
    s, out = rod_run
    assert s["status"] == "ok"
    assert s["rel_error"] <= 0.02
    assert s["rel_error"] < 1e-3  # measured 6.5e-5: spatial error of 41 elements
    res = s["results"]["rod"]
    assert res["passed"] and 0.09 < s["fourier_number"] < 0.11  # a developed transient
    assert res["thermal_time"] == pytest.approx(4500.0, rel=1e-12)
    assert s["energy_closure_rel_error"] < 1e-9  # alpha = 0: the solid stays at rest
    # the profile file holds the same comparison
    head, a = _rows(out / "thermal_rod_profile.csv")
    assert head == ["position", "T", "T_exact", "fixed"]
    free = a[:, 3] == 0
    assert np.abs(a[free, 1] - a[free, 2]).max() / 100.0 == pytest.approx(s["rel_error"],
                                                                          rel=1e-9)
    for name in ("thermal_rod.png", "rod_temperature.png"):
        assert (out / name).stat().st_size > 1000


def test_rod_history_of_the_middle_element(rod_run):
    """The middle element (x = L/2) against the series at every recorded time after
    Fo = 0.005 (before that, the discrete start from a step profile dominates)."""
    s, out = rod_run
    head, a = _rows(out / "rod_temperature.csv")
    res = s["results"]["rod"]
    L, D = res["length"], res["diffusivity"]
    t = a[:, head.index("thermal_time")]
    sel = D * t / L ** 2 > 0.005
    assert sel.sum() > 40
    exact = np.array([rod_solution([0.5 * L], tt, L, D, 293.15, 393.15, 293.15)[0]
                      for tt in t[sel]])
    mid = a[sel, head.index("T_middle")]
    assert np.abs(mid - exact).max() / 100.0 < 2e-3
    assert mid[-1] - 293.15 > 5.0  # the heat has reached the middle


def test_rod_resumed_from_a_checkpoint_ends_bit_identical(rod_run, tmp_path):
    s, out = rod_run
    part = tmp_path / "part"
    s1 = _run(ROD, part, extra=("--stop-after-steps", "1000"))
    assert s1["status"] == "interrupted" and s1["steps"] == 1000
    s2 = _run(ROD, part, extra=("--resume",))
    assert s2["state_sha256"] == s["state_sha256"]
    assert s2["rel_error"] == s["rel_error"]
    assert s2["results"]["rod"]["thermal_substeps"] == s["results"]["rod"]["thermal_substeps"]
    assert _rows(part / "rod_temperature.csv")[1].tolist() == \
        _rows(out / "rod_temperature.csv")[1].tolist()
    # the same text too: the kept rows' whole numbers were rewritten as floats ("40.0")
    assert (part / "rod_temperature.csv").read_text() == (out / "rod_temperature.csv").read_text()


def test_heated_borehole_cracks(tmp_path):
    """The composition (scene: specimen fill, empty hole, groups by shape; damping; heat) at
    d = 6 mm (268 elements) and 6000 steps: the heater ring holds its fixed temperature, heat
    flows outwards, bonds break in tension across radial cracks, and the energy books close."""
    import h5py

    out = tmp_path / "crack"
    s = _run(CRACKING, out, "model.d=0.006", "model.groups.heater.shape.disc.radius=0.018",
             "steps.heat.nsteps=6000")
    assert s["status"] == "ok" and s["n_elements"] == 268  # measured 2026-12-05, seed 0
    assert s["T_max"] == pytest.approx(473.15, rel=1e-12)
    res = s["results"]["heat"]
    assert res["probes"]["heater"] == pytest.approx(473.15, rel=1e-12)
    assert 293.15 < res["probes"]["edge"] < res["probes"]["specimen"] < 473.15
    # measured 6 with the turning library sandstone (2026-12-05; 17 with the translating one
    # of 6d7aae0): a turning rock splits in a few clean radial cracks (the default plate: 21
    # bonds against 35, docs/thermal.md); seeds 1, 2 break 9 and 9, and the same element
    # parameters without rotation 17, 10 and 30 in about four cracks: the rotation, not the
    # recalibration, lowers the count
    assert 3 <= s["broken_bonds"] <= 40
    assert res["cracks_tensile"] == s["broken_bonds"] and res["cracks_shear"] == 0
    assert s["energy_closure_rel_error"] < 1e-3  # measured 3.3e-5
    # radial cracks: a broken bond runs round the hole (hoop tension), |cos| of its angle with
    # the radius 0.2-0.45 (random bonds: 2/pi = 0.64); all outside the heater ring
    ckpt = sorted((out / "checkpoints").glob("*.npz"))[-1]
    x = np.load(ckpt)["x"]
    with h5py.File(out / "output.h5") as f:
        i, j = f["cracks/i"][:], f["cracks/j"][:]
    b = x[j] - x[i]
    b /= np.linalg.norm(b, axis=1)[:, None]
    m = 0.5 * (x[i] + x[j]) - 0.05
    dist = np.linalg.norm(m, axis=1)
    cos = np.abs((b * m).sum(axis=1)) / dist
    assert cos.mean() < 0.5 and dist.min() > 0.012
    assert (out / "heat_temperature.png").stat().st_size > 1000


def test_the_cracking_workflow_area_factor_restores_k():
    """The workflow's area_factor is k / k_eff of its rock's packing: the library sandstone's
    2-D calibration packed in a 0.1 m box at the workflow's d_mean conducts 0.60 / 0.59 k along
    x / y with the lattice formula (measured 2026-12-05, docs/thermal.md)."""
    from geodem.build.specimen import make_specimen
    from geodem.core.engine import Simulation
    from geodem.fields.thermal import ThermalField, effective_conductivity
    from geodem.materials_library import load_material

    doc = yaml.safe_load(CRACKING.read_text())
    heat = next(st for st in doc["steps"] if st.get("kind") == "heat")
    mat = load_material("sandstone")
    st, _ = make_specimen("box", (0.1, 0.1), doc["model"]["d"], 0.2, mat.values(), 2,
                          seed=0, element=dict(mat.calibrated["2d"]["element"]))
    sim = Simulation(st, backend="numba")
    f = ThermalField(k=heat["conductivity"], c=heat["specific_heat"])
    sim.add_field(f)
    ratio = np.mean([effective_conductivity(sim, f, axis=a)["ratio"] for a in (0, 1)])
    assert heat["area_factor"] * ratio == pytest.approx(1.0, abs=0.05)


@pytest.mark.slow
@pytest.mark.validation
def test_no_expansion_no_cracks(tmp_path):
    """The control: the same heating without thermal expansion breaks nothing."""
    s = _run(CRACKING, tmp_path / "crack0", "steps.heat.alpha=0")
    assert s["broken_bonds"] == 0


# ============================================================================ bad input
@pytest.mark.parametrize("setting, path, words", [
    ("steps.rod.conductivity=-1", "steps[0].conductivity", ">= 0"),
    ("steps.rod.specific_heat=0", "steps[0].specific_heat", "> 0"),
    ("steps.rod.fixed={hot: -3.0, cold: 300.0}", "steps[0].fixed.hot", "> 0"),
    ("steps.rod.fixed={hot: 400.0, nowhere: 300.0}", "steps[0].fixed.nowhere", "unknown group"),
    ("steps.rod.fixed={hot: 400.0}", "steps[0].fixed", "needs a fixed temperature"),
    ("steps.rod.alpha=0.5", "steps[0].alpha", "<= 0.001"),
    ("steps.rod.time_scale=10.0", "steps[0]", "at most one of nsteps and time_scale"),
])
def test_bad_thermal_input_exits_2_naming_the_field(tmp_path, setting, path, words):
    res = CliRunner().invoke(app, ["run", str(ROD), "-o", str(tmp_path / "x"), "--no-progress",
                                   "--set", setting])
    assert res.exit_code == 2, res.output
    assert path in res.output and words in res.output, res.output
    assert "thermal_rod.yaml:" in res.output or "--set" in res.output


@pytest.mark.parametrize("setting, path, words", [
    ("model.regions=[{name: hole, material: granite, shape: {disc: {center: [0.05, 0.05], "
     "radius: 0.012}}}]", "model.regions[0].material", "a specimen fill cements one material"),
    ("model.groups.heater={region: hole}", "model.groups.heater.region",
     "region 'hole' is empty"),
    ("model.fill=packed", "model.fill", "'lattice', 'random' or 'specimen'"),
])
def test_bad_borehole_scene_exits_2_naming_the_field(tmp_path, setting, path, words):
    res = CliRunner().invoke(app, ["run", str(CRACKING), "-o", str(tmp_path / "x"),
                                   "--no-progress", "--set", "materials.granite={library: "
                                   "granite}", "--set", setting])
    assert res.exit_code == 2, res.output
    assert path in res.output and words in res.output, res.output
