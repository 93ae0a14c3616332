"""A turning-element calibration used at another element size is said, not silent
(geodem.workflow.material.resolution_warnings; docs/calibration.md "Resolution transfer")."""
from geodem.workflow.material import resolution_warnings

TURNING = {"element": {"rotation": True, "rolling_stiffness": 2.0}, "specimen": {"d_mean": 0.005}}
TRANSLATING = {"element": {"mu": 0.2}, "specimen": {"d_mean": 0.005}}


def test_turning_elements_at_half_the_size_are_warned_about():
    (w,) = resolution_warnings("sandstone", TURNING, 0.0025, 2)
    assert "d_mean = 0.005 m" in w and "0.0025 m" in w
    assert "geodem calibrate sandstone --dim 2 --d-mean 0.0025" in w


def test_within_ten_percent_of_the_calibration_size_is_its_resolution():
    assert resolution_warnings("sandstone", TURNING, 0.0054, 2) == []
    assert resolution_warnings("sandstone", TURNING, 0.0046, 2) == []
    assert len(resolution_warnings("sandstone", TURNING, 0.0056, 2)) == 1


def test_translating_elements_and_unknown_sizes_are_not_warned_about():
    # translating elements carried E and UCS to 2x finer elements within 4 %
    assert resolution_warnings("sandstone", TRANSLATING, 0.0025, 2) == []
    assert resolution_warnings("sandstone", TURNING, None, 2) == []
    assert resolution_warnings("sandstone", {"element": {"rotation": True}}, 0.0025, 2) == []
