"""What one packing decides (docs/calibration.md, "How much one packing decides"): the library
sandstone's element parameters (calibrated on seed 0) on another packing. E, nu, Cu and Tu move
by about the calibration's tolerance; the Brazilian disc agrees with direct tension on seed 0
only (seeds 1-4: 3.0-5.1 x). Slow: about 40 s a packing on one core."""
import pytest

from geodem.studies.calibrate import CalibrationSpec, brazilian_check, measure
from geodem.materials import STRUCTURE_KEYS
from geodem.materials_library import load_material

pytestmark = [pytest.mark.slow, pytest.mark.validation]


def _spec_and_element(seed):
    mat = load_material("sandstone")
    el = dict(mat.calibrated["2d"]["element"])
    structure = {k: el[k] for k in STRUCTURE_KEYS if k in el}
    return CalibrationSpec(targets=mat.values(), name=mat.name, seed=seed, iterations=1,
                           structure=structure), el


def test_another_packing_makes_the_same_rock_within_the_scatter(tmp_path):
    spec, el = _spec_and_element(1)
    m = measure(spec, el, tmp_path)
    # seed 1 measured 2026-12-04: E -2.5 %, nu 0.189, Cu +4.1 %, Tu -4.8 % against the lab values
    assert abs(m["E"] / 15e9 - 1) < 0.05 and abs(m["nu"] - 0.2) < 0.05
    assert abs(m["Cu"] / 75e6 - 1) < 0.10 and abs(m["Tu"] / 4e6 - 1) < 0.12


@pytest.mark.xfail(strict=True, reason="2-D discs 20 elements across carry load past their "
                                       "first crack: 3.0-5.1 x direct tension on seeds 1-4")
def test_the_brazilian_disc_agrees_with_direct_tension_on_another_packing(tmp_path):
    spec, el = _spec_and_element(1)
    tension = measure(spec, el, tmp_path / "specimen")["Tu"]
    disc = brazilian_check(spec, el, tmp_path / "disc")["tensile_strength"]
    assert abs(disc / tension - 1) < 0.15, (disc, tension)
