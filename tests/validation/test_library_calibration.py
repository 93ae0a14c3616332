"""The long calibrations (slow): `geodem calibrate` of library rocks on real specimens meets E,
Cu, Tu within 5 % and nu within 0.03 (and, with the 2-D recipe, phi within 2 deg) in at most 8
iterations, and the stored calibration is what it finds again (`geodem calibrate NAME` repeats
the stored recipe). The cheap slice in CI is tests/unit/test_calibrate.py (synthetic packings).
Measured: granite 2-D (turning elements, friction angle, three packings; 2026-12-05) converged
at iteration 4 in 1,354 s with its packings side by side on a busy 2-core machine; marble 3-D
(turning elements at rolling stiffness 4, friction angle, three packings, discs 20 across;
2026-12-06, commit a8d1890) at iteration 1 in 2,248 s on one core beside another calibration.
The 3-D turning recipe starts from its prior (geodem.studies.calibrate.PRIOR_ROTATION_3D_BETA):
a change there moves the first iteration, so the record is found again only with the prior it
was calibrated from."""
import json

import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.materials_library import load_material

pytestmark = [pytest.mark.slow, pytest.mark.validation]


@pytest.mark.parametrize("name, dim", [("granite", 2), ("marble", 3)])
def test_a_library_rock_calibrates_to_its_lab_values(tmp_path, name, dim):
    out = tmp_path / "cal"
    res = CliRunner().invoke(app, ["calibrate", name, "--dim", str(dim), "-o", str(out),
                                   "--iterations", "8"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] and s["iterations"] <= 8 and all(s["reachable"].values())
    for k in ("E", "Cu", "Tu"):
        assert abs(s["rel_errors"][k]) <= 0.05, (k, s["rel_errors"])
    assert abs(s["abs_errors"]["nu"]) <= 0.03
    if "phi" in s["targets"]:  # the 2-D library recipe matches the friction angle too
        assert abs(s["abs_errors"]["phi"]) <= 2.0
    # the same seed on any thread count gives the same packing: the stored record is found again
    stored = load_material(name).calibrated[f"{dim}d"]
    assert s["measured"] == pytest.approx(stored["measured"], rel=1e-9)


def _user_rock(tmp_path, name, values):
    """A material file outside the library: the sandstone file's sources with other values."""
    import yaml

    from geodem.materials_library import material_path

    base = yaml.safe_load(material_path("sandstone").read_text())
    base.update(name=name, description=f"{name}: a rock outside the library", calibrated=None)
    base["properties"] = {k: dict(base["properties"][k], value=v) for k, v in values.items()}
    base.pop("notes", None)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(base, sort_keys=False))
    return path


@pytest.mark.parametrize("name, values", [
    # measured 2026-12-04 (2-D, elastic fit): iteration 2, 39 s (window fit, 2026-12-02: iteration
    # 2, 46 s; 3-D: iteration 3, 231 s)
    ("hard_granite", {"E": 70e9, "nu": 0.22, "Cu": 250e6, "Tu": 12e6, "mu_i": 1.0, "rho": 2700.0}),
    # measured 2026-12-04 (2-D, elastic fit): iteration 4, 47 s (window fit: iteration 4, 57 s;
    # 3-D: iteration 5, 237 s)
    ("weak_sandstone", {"E": 8e9, "nu": 0.25, "Cu": 30e6, "Tu": 2.5e6, "mu_i": 0.6,
                        "rho": 2200.0}),
])
def test_a_rock_outside_the_library_calibrates_the_same_way(tmp_path, name, values):
    path = _user_rock(tmp_path, name, values)
    out = tmp_path / "cal"
    res = CliRunner().invoke(app, ["calibrate", str(path), "-o", str(out), "--iterations", "8",
                                   "--save"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] and all(s["reachable"].values())
    for k in ("E", "Cu", "Tu"):
        assert abs(s["rel_errors"][k]) <= 0.05, (k, s["rel_errors"])
    assert abs(s["abs_errors"]["nu"]) <= 0.03
    assert s["brazilian"]["tensile_strength"] > 0  # the check ran and is stored
    assert load_material(path).calibrated["2d"]["brazilian"]["over_target"] == pytest.approx(
        s["brazilian"]["over_target"], abs=1e-4)


def test_a_turning_rock_meets_all_five_targets_on_three_packings(tmp_path):
    """Turning elements, moment-resisting bonds and a rolling stiffness of 2: the sandstone's
    E, Cu, Tu within 5 %, nu within 0.03 and its friction angle atan(mu_i) = 35 deg within
    2 deg, on the mean of three packings (docs/calibration.md, "Rolling stiffness"). Measured
    2026-12-05: converged at iteration 4 in 813 s on one core, phi 36.1 deg (+1.1)."""
    out = tmp_path / "cal"
    res = CliRunner().invoke(app, ["calibrate", "sandstone", "--dim", "2", "-o", str(out),
                                   "--bond-moment", "100", "--rolling-stiffness", "2",
                                   "--friction", "--packings", "3", "--iterations", "10"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"]
    for k in ("E", "Cu", "Tu"):
        assert abs(s["rel_errors"][k]) <= 0.05, (k, s["rel_errors"])
    assert abs(s["abs_errors"]["nu"]) <= 0.03
    assert abs(s["measured"]["phi"] - 35.0) <= 2.0
    assert s["specimen"]["rotation"] and s["specimen"]["rolling_stiffness"] == 2.0
