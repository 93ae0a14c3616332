"""Calibrated parameters transfer across resolutions (docs/calibration.md).

The library's sandstone carries a 2-D calibration made on the UCS specimen at d_mean = 5 mm
(20 elements across the width). Its per-size parameters (kn, ks, xb ∝ d, fs0 ∝ d^2) must give
the same E and UCS, within 10 %, on a specimen with 2x finer elements (d_mean = 2.5 mm, about
3,300 elements), and reproduce the calibration at its own resolution.
"""
import json
from pathlib import Path

import pytest

from geodem.materials_library import load_material
from geodem.workflow import run_workflow

pytestmark = pytest.mark.validation

ROOT = Path(__file__).resolve().parents[2]
UCS = ROOT / "workflows" / "ucs.yaml"


def ucs(tmp_path, d_mean):
    sets = ["materials.rock={library: sandstone, use: calibrated}", f"model.d_mean={d_mean}"]
    code, s = run_workflow(UCS, tmp_path / f"d{d_mean}", sets=sets, echo=False, progress=False)
    assert code == 0, s.get("error")
    return s


@pytest.fixture(scope="module")
def sandstone():
    mat = load_material("sandstone")
    if not (mat.calibrated or {}).get("2d"):
        pytest.fail("materials/sandstone.yaml has no 2-D calibration (geodem calibrate "
                    "sandstone --save)")
    return mat


def test_calibration_reproduces_at_its_resolution(sandstone, tmp_path):
    cal = sandstone.calibrated["2d"]
    s = ucs(tmp_path, cal["specimen"]["d_mean"])
    # the same specimen, seed and parameters as the calibration's best iteration. Not bit for
    # bit: the record was measured before the engine's adaptive neighbour checks,
    # whose other rebuild steps change the round-off (E then moved by 1.5e-5 relative)
    assert s["E"] == pytest.approx(cal["measured"]["E"], rel=1e-4)
    assert s["ucs"] == pytest.approx(cal["measured"]["Cu"], rel=1e-4)


@pytest.mark.slow  # about 1.5 min on 1 core (3,348 elements)
def test_twice_finer_elements_give_the_same_E_and_UCS(sandstone, tmp_path):
    """Measured 2026-12-04 (commit 6d7aae0, the library on the elastic fit): d_mean 2.5 mm gives
    E 14.39 GPa (-3.9 %) and UCS 73.4 MPa (-3.1 %) against the calibration's 14.97 GPa and 75.8
    MPa at 5 mm (the window-fit library of commit 5a24c31: -3.9 % and -10.2 %, a strict xfail).
    One packing per resolution: the UCS of one packing scatters by ~9 % between seeds at 5 mm
    (docs/performance.md)."""
def test_twice_finer_elements_give_the_same_E_and_UCS(sandstone, tmp_path):
    cal = sandstone.calibrated["2d"]
    d = cal["specimen"]["d_mean"]
    fine = ucs(tmp_path, d / 2)
    assert fine["n_elements"] > 3.5 * 830
    E_t, Cu_t = cal["measured"]["E"], cal["measured"]["Cu"]
    assert fine["E"] == pytest.approx(E_t, rel=0.10)
    assert fine["ucs"] == pytest.approx(Cu_t, rel=0.10)
