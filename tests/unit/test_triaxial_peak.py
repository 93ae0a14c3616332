"""A triaxial stage has a peak only if its deviator came down after it (geodem.cases.triaxial
.has_peaked); a curve still hardening at max_strain has none."""
import numpy as np

from geodem.cases.triaxial import SOFTENED, has_peaked


def test_a_curve_still_hardening_at_max_strain_has_no_peak():
    q = np.array([0.0, 10.0, 20.0, 29.0, 30.0])
    assert not has_peaked("max_strain", q, int(np.argmax(q)))


def test_a_maximum_then_a_small_dip_is_not_yet_a_peak():
    q = np.array([0.0, 10.0, 30.0, 29.0])  # 3 % below: within the curve's own wobble
    assert 29.0 > SOFTENED * 30.0
    assert not has_peaked("max_strain", q, 2)


def test_softening_after_the_maximum_is_a_peak():
    q = np.array([0.0, 10.0, 30.0, 27.0])  # 10 % below the maximum
    assert has_peaked("max_strain", q, 2)
    assert has_peaked("walls", q, 2)


def test_a_stage_stopped_by_the_post_peak_drop_has_peaked():
    q = np.array([0.0, 30.0, 12.0])
    assert has_peaked("drop", q, 1)
