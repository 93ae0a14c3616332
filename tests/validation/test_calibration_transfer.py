"""Calibrated parameters transfer across resolutions (docs/calibration.md).

The library's sandstone carries a 2-D calibration made on the UCS specimen at d_mean = 5 mm
(20 elements across the width), its numbers the mean of ``packings`` packings (seeds 0, 1, ...).
Its per-size parameters (kn, ks, xb ∝ d, fs0 ∝ d^2) must reproduce the calibration at its own
resolution, and give the same E and UCS, within 10 %, on specimens with 2x finer elements
(d_mean = 2.5 mm, about 3,300 elements), on the mean of as many packings.
"""
from pathlib import Path

import numpy as np
import pytest

from geodem.materials_library import load_material
from geodem.workflow import run_workflow

pytestmark = pytest.mark.validation

ROOT = Path(__file__).resolve().parents[2]
UCS = ROOT / "workflows" / "ucs.yaml"


def ucs_mean(tmp_path, d_mean, packings):
    """E and UCS of workflows/ucs.yaml with the calibrated sandstone at ``d_mean``: the mean
    over seeds 0 .. packings - 1, as the calibration measures them."""
    runs = []
    for seed in range(packings):
        sets = ["materials.rock={library: sandstone, use: calibrated}",
                f"model.d_mean={d_mean}", f"metadata.seed={seed}"]
        code, s = run_workflow(UCS, tmp_path / f"d{d_mean}_s{seed}", sets=sets, echo=False,
                               progress=False)
        assert code == 0, s.get("error")
        runs.append(s)
    return {k: float(np.mean([s[k] for s in runs])) for k in ("E", "ucs", "n_elements")}


@pytest.fixture(scope="module")
def sandstone():
    mat = load_material("sandstone")
    if not (mat.calibrated or {}).get("2d"):
        pytest.fail("materials/sandstone.yaml has no 2-D calibration (geodem calibrate "
                    "sandstone --save)")
    return mat


@pytest.mark.slow  # three packings, about 45 s
def test_calibration_reproduces_at_its_resolution(sandstone, tmp_path):
    cal = sandstone.calibrated["2d"]
    spec = cal["specimen"]
    assert spec["seed"] == 0
    s = ucs_mean(tmp_path, spec["d_mean"], int(spec.get("packings") or 1))
    # the same specimens, seeds and parameters as the calibration's best iteration
    assert s["E"] == pytest.approx(cal["measured"]["E"], rel=1e-6)
    assert s["ucs"] == pytest.approx(cal["measured"]["Cu"], rel=1e-6)


@pytest.fixture(scope="module")
def finer(sandstone, tmp_path_factory):
    spec = sandstone.calibrated["2d"]["specimen"]
    return ucs_mean(tmp_path_factory.mktemp("finer"), spec["d_mean"] / 2,
                    int(spec.get("packings") or 1))


@pytest.mark.slow  # about 13 min on 1 core (three packings of 3,348 elements)
def test_twice_finer_elements_give_the_same_E(sandstone, finer):
    """Measured 2026-12-05 (the turning-element library of commit 0010be8, seeds 0-2, one
    core each): E 14.61 / 14.55 / 14.76 GPa (mean 14.64, -2.1 %) at d_mean 2.5 mm against the
    calibration's mean 14.95 GPa at 5 mm."""
    assert finer["n_elements"] > 3.5 * 830
    assert finer["E"] == pytest.approx(sandstone.calibrated["2d"]["measured"]["E"], rel=0.10)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "turning elements (rolling springs beta Ks R*^2) do not carry their UCS to 2x finer "
    "elements: 62.1 / 64.8 / 49.8 MPa (seeds 0-2, mean -20 %) against the calibration's "
    "73.8 MPa at 5 mm, while E transfers within 3 %; translating elements transferred within 4 % (commit "
    "6d7aae0). Calibrate at the resolution of the run (docs/calibration.md 'Resolution "
    "transfer')"))
def test_twice_finer_elements_give_the_same_UCS(sandstone, finer):
    assert finer["ucs"] == pytest.approx(sandstone.calibrated["2d"]["measured"]["Cu"], rel=0.10)
