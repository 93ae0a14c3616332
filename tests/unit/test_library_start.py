"""A calibration's first guess from the nearest calibrated library rock of the same recipe
(geodem.studies.calibrate.library_start)."""
import math

import numpy as np
import pytest
import yaml

from geodem.materials_library import material_path
from geodem.studies import calibrate as C

from tests.unit.test_calibrate import TARGETS, synthetic

ELEMENT_KEYS = ("kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2", "mu")


def spec(name="new_rock", **kw):
    return C.CalibrationSpec(targets=dict(TARGETS, **{k: v for k, v in kw.items()
                                                        if k in TARGETS}),
                             name=name, **{k: v for k, v in kw.items() if k not in TARGETS})


def record_file(tmp_path, name, element, measured, **specimen):
    """A material file named ``name`` with a converged 2-D record: ``element`` measured
    ``measured`` on the default calibration specimen (``specimen`` overrides its keys)."""
    s = spec()
    block = {"element": dict(element, packing="isotropic"), "measured": measured,
             "converged": True,
             "specimen": dict({"d_mean": s.d_mean, "ucs_size": list(s.ucs_size),
                               "packing": "isotropic", "fit": s.fit,
                               "strain_rate": s.strain_rate, "max_strain": s.max_strain,
                               "packings": 3}, **specimen)}
    doc = yaml.safe_load(material_path("sandstone").read_text())  # its sources
    for k, v in TARGETS.items():
        doc["properties"][k]["value"] = float(v)
    doc.update(name=name, calibrated={"2d": block})
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def element_at(u):
    return C.from_unknowns(np.asarray(u, float))


def test_a_record_at_the_targets_shape_is_scaled_exactly_to_them(tmp_path):
    """A record whose measured nu and Cu / Tu are the new rock's, at the prior's contact
    friction, with E 10 x and both strengths 2 x the targets: the start is the record with kn
    / 10 and the breaking forces / 2 (the model's exact scalings), its shape unchanged."""
    s = spec()
    mu = C.prior_guess(s)["mu"]
    rec = element_at([math.log(3e11), 0.4, math.log(2e7), math.log(6.0), math.log(mu)])
    measured = {"E": 10 * TARGETS["E"], "nu": TARGETS["nu"], "Tu": 2 * TARGETS["Tu"],
                "Cu": 2 * TARGETS["Cu"]}
    path = record_file(tmp_path, "rock_a", rec, measured)
    el, name = C.library_start(s, names=[path])
    assert name == path
    assert el["kn_per_d"] == pytest.approx(rec["kn_per_d"] / 10, rel=1e-12)
    assert el["ks_per_d"] / el["kn_per_d"] == pytest.approx(0.4, rel=1e-12)
    assert el["kn_per_d"] * el["xb_per_d"] == pytest.approx(1e7, rel=1e-12)
    assert el["fs0_per_d2"] / (el["kn_per_d"] * el["xb_per_d"]) == pytest.approx(6.0, rel=1e-12)
    assert el["mu"] == pytest.approx(mu, rel=1e-12)


def test_the_rocks_own_record_another_recipe_or_a_far_one_is_not_taken(tmp_path):
    s = spec(name="rock_a")
    mu = C.prior_guess(s)["mu"]
    rec = element_at([math.log(3e11), 0.4, math.log(2e7), math.log(6.0), math.log(mu)])
    at_target = {k: TARGETS[k] for k in C.KEYS}
    own = record_file(tmp_path, "rock_a", rec, at_target)
    assert C.library_start(s, names=[own]) is None  # its own record: checked, not read back
    other = spec()
    turning = record_file(tmp_path, "turning", rec, at_target, rotation=True, bond_moment=100.0,
                          rolling_friction=0.0, rolling_stiffness=2.0)
    coarser = record_file(tmp_path, "coarser", rec, at_target, d_mean=0.01)
    assert C.library_start(other, names=[turning, coarser]) is None
    far_nu = record_file(tmp_path, "far_nu", rec, dict(at_target, nu=TARGETS["nu"] + 0.15))
    far_ratio = record_file(tmp_path, "far_ratio", rec, dict(at_target, Cu=3 * TARGETS["Cu"]))
    assert C.library_start(other, names=[far_nu, far_ratio]) is None
    near = record_file(tmp_path, "near", rec, dict(at_target, nu=TARGETS["nu"] + 0.02))
    nearer = record_file(tmp_path, "nearer", rec, dict(at_target, nu=TARGETS["nu"] - 0.01))
    assert C.library_start(other, names=[far_nu, near, nearer, turning])[1] == nearer


def test_a_start_from_a_neighbouring_rock_converges_sooner(tmp_path):
    """On the synthetic packing: rock A calibrated, stored as a record; rock B (nu 0.23, Cu /
    Tu 21) started from A's record needs fewer iterations than from the prior rates."""
    a = C.calibrate(spec(name="rock_a"), tmp_path / "a", measure_fn=synthetic)
    assert a["converged"]
    path = record_file(tmp_path, "rock_a", {k: a["element"][k] for k in ELEMENT_KEYS},
                       {k: a["measured"][k] for k in C.KEYS})
    b = spec(name="rock_b", nu=0.23, Cu=84e6)
    el, _ = C.library_start(b, names=[path])
    from_prior = C.calibrate(b, tmp_path / "b0", measure_fn=synthetic)
    from_a = C.calibrate(b, tmp_path / "b1", measure_fn=synthetic, start=el,
                         start_from="library rock_a")
    assert from_prior["converged"] and from_a["converged"]
    assert from_a["iterations"] < from_prior["iterations"]
    assert from_a["start"] == "library rock_a" and from_prior["start"] == "prior table"
