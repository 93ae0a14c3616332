"""One rock, one answer: the calibrated library sandstone (2-D) gives the same strength in the
UCS test, the triaxial test at sigma3 = 0, and its tensile strength in the Brazilian and the
direct-tension tests. Integration tier: about a minute on 2 cores."""
import json
from pathlib import Path

import pytest
import yaml

from geodem.materials_library import load_material
from geodem.workflow import run_workflow

ROOT = Path(__file__).resolve().parents[2]
SANDSTONE = load_material("sandstone").values()
# the triaxial workflow's specimen and rate, in both tests
SPECIMEN = {"dim": 2, "size": [0.05, 0.1], "d_mean": 0.005, "distri_rate": 0.2,
            "material": "rock"}
ROCK = {"rock": {"library": "sandstone"}}


def _run(tmp_path, name, doc):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    code, summary = run_workflow(path, tmp_path / name, overwrite=True, echo=False,
                                 progress=False)
    assert code == 0 and summary["status"] == "ok", summary.get("error")
    return summary


def _shipped(tmp_path, name):
    code, summary = run_workflow(ROOT / "workflows" / f"{name}.yaml", tmp_path / name,
                                 echo=False, progress=False)
    assert code == 0 and summary["status"] == "ok", summary.get("error")
    return summary


def test_the_triaxial_test_at_zero_confinement_is_the_ucs_test(tmp_path):
    ucs = _run(tmp_path, "ucs", {
        "metadata": {"name": "ucs", "seed": 0},
        "model": dict(SPECIMEN, type="specimen"), "materials": ROCK,
        "steps": [{"kind": "uniaxial", "name": "ucs", "strain_rate": 1.0, "max_strain": 0.02,
                   "drop": 0.7}]})
    tri = _run(tmp_path, "triaxial", {
        "metadata": {"name": "triaxial", "seed": 0},
        "model": dict(SPECIMEN, type="triaxial_box"), "materials": ROCK,
        "steps": [{"kind": "triaxial", "name": "triaxial", "confining_pressures": [0.0],
                   "strain_rate": 1.0, "max_strain": 0.02, "drop": 0.5}]})
    strength = tri["peak_strengths"][0]
    assert strength is not None, "the sigma3 = 0 stage has not peaked"
    assert strength / ucs["ucs"] == pytest.approx(1.0, abs=0.05), (strength, ucs["ucs"])


def test_the_brazilian_test_gives_the_lab_tensile_strength(tmp_path):
    s = _shipped(tmp_path, "brazilian")
    assert s["tensile_strength"] / SANDSTONE["Tu"] == pytest.approx(1.0, abs=0.15)


@pytest.mark.xfail(strict=True, reason=(
    "direct tension of the 2-D isotropic sandstone gives 1.04 MPa against the Brazilian 4.2 "
    "(deposit packing: 0.91 against 9.5): the bonded-disc model's Brazilian/direct ratio is "
    "about 4, the lab's about 1; Tu is calibrated on the Brazilian test"))
def test_the_direct_tension_test_gives_the_lab_tensile_strength(tmp_path):
    s = _shipped(tmp_path, "direct_tension")
    assert s["tensile_strength"] / SANDSTONE["Tu"] == pytest.approx(1.0, abs=0.15)
