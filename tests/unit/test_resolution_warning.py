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


# ---------------------------------------------------------------- the Brazilian disc's size
def _checked(ratio, across=40, d_mean=0.005):
    from geodem.workflow.material import SpecimenMaterial

    rec = {"element": {}, "specimen": {"d_mean": d_mean, "disc_diameter": across * d_mean},
           "brazilian": {"over_target": ratio}}
    return SpecimenMaterial(2650.0, element={}, name="sandstone", record=rec)


def test_a_disc_coarser_than_the_calibrations_check_is_warned_about():
    from geodem.workflow.material import disc_warnings

    (w,) = disc_warnings(_checked(0.99), 20)
    assert "split discs 40 d_mean across at 0.99 x" in w and "this disc is 20 across" in w
    assert "coarser: expect it to read higher" in w
    assert disc_warnings(_checked(0.99), 37) == []  # within 10 %: the checked size
    assert disc_warnings(_checked(0.99), 60) == []  # finer


def test_a_disc_the_size_of_a_check_that_missed_tu_says_so():
    from geodem.workflow.material import disc_warnings

    (w,) = disc_warnings(_checked(1.44), 40)  # the 3-D granite's record at 40 across
    assert "at 1.44 x" in w and "expect about the same ratio" in w
    assert disc_warnings(_checked(1.14), 40) == []  # within 15 % of Tu
    assert disc_warnings(_checked(1.44), 60) == []  # a finer disc: not known, not warned


def test_a_material_without_a_check_is_not_warned_about():
    from geodem.workflow.material import SpecimenMaterial, disc_warnings

    assert disc_warnings(SpecimenMaterial(2650.0, element={}), 10) == []
    bare = _checked(1.0)
    del bare.record["brazilian"]
    assert disc_warnings(bare, 10) == []
