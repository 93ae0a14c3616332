"""The command line's rotation options (--bond-moment, --rolling-friction, --rolling-stiffness)
as micro-structure keys (``geodem rock`` and ``geodem calibrate``)."""
from geodem.cli import _rotation_structure


def test_no_option_leaves_the_micro_structure_alone():
    assert _rotation_structure(None, None, None) == {}
    assert _rotation_structure(None, None, None, stored={"rotation": True}) == {}


def test_an_option_alone_takes_the_defaults_for_the_others():
    assert _rotation_structure(None, None, 2.0) == {
        "rotation": True, "bond_moment": 0.0, "rolling_friction": 0.0, "rolling_stiffness": 2.0}
    assert _rotation_structure(100.0, None) == {
        "rotation": True, "bond_moment": 100.0, "rolling_friction": 0.0, "rolling_stiffness": 1.0}


def test_an_option_keeps_the_stored_values_of_a_turning_rock():
    stored = {"rotation": True, "bond_moment": 100.0, "rolling_friction": 0.1,
              "rolling_stiffness": 1.5, "packing": "isotropic"}
    assert _rotation_structure(None, None, 2.0, stored=stored) == {
        "rotation": True, "bond_moment": 100.0, "rolling_friction": 0.1, "rolling_stiffness": 2.0}
    # a translating rock's stored keys are not rotation values: defaults
    assert _rotation_structure(None, 0.3, None, stored={"rotation": False, "bond_moment": 5.0}) \
        == {"rotation": True, "bond_moment": 0.0, "rolling_friction": 0.3,
            "rolling_stiffness": 1.0}
