"""Hydraulic fracturing (geodem/cases/hydrofrac.py, workflows/hydraulic_fracturing*.yaml).

Default suite: the analysis helpers on hand-made input, and a small uniform plate (0.1 m, ~400
elements, the fast 2e9 Pa/s ramp) run end to end (summary keys, mass balance, pictures). Slow
(``-m slow``): the two workflows at their default size (a graded 0.8 m plate, a borehole of
8 d_mean radius; ramp 5e8 Pa/s) against the targets of VALIDATION.md (measured values:
docs/hydraulic_fracturing.md):

Measured 2026-12-05 (commit d2faca0) on the library sandstone of commit 0010be8 (turning
elements: moment-resisting bonds, rolling stiffness 2; calibrated Tu 4.02 MPa):

* isotropic (four fixed boundaries), seeds 0-2: 3-5 crack arms round the hole, not all on one
  side (no preferred direction; measured 3, 3, 4; MatDEM shows 3); breakdown within 30 % of
  Hubbert-Willis ``P_b = T`` with T the calibrated Tu of materials/sandstone.yaml:
  measured 5.15, 3.90, 3.90 MPa (1.28, 0.97, 0.97 x), the mean of the three seeds is
  asserted; with T from direct tension of a strip of the plate's own packing
  (``tensile_strength_from: direct_tension``, 4.15 MPa) within 30 % too (1.24 x);
* confined (sigma_H = 6 MPa along x, sigma_h = 3 MPa), seeds 0-2: the dominant arm of seed 0
  within 15 deg of sigma_H (measured 5.7 deg); breakdown within 30 % of ``3 sigma_h - sigma_H
  + T`` = 7.02 MPa on the mean of the three seeds: measured 8.24, 9.83, 8.72 MPa (1.17, 1.40,
  1.24 x, mean 1.27 x); at a 16 d_mean hole 0.97 x (its own slow test);
* fluid mass balance < 1e-6 in all (measured 1.5e-14 or less).
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from geodem.workflow import run_workflow
from geodem.cases.hydrofrac import (
    axis_misfit_deg,
    boundary_tractions,
    burst_samples,
    connected_cracks,
    crack_arms,
    hubbert_willis,
    penetration_depth,
    view_half_width,
)
from geodem.workflow.schema import load_builtins

load_builtins()

ROOT = Path(__file__).resolve().parents[2]
HF = ROOT / "workflows" / "hydraulic_fracturing.yaml"
HFC = ROOT / "workflows" / "hydraulic_fracturing_confined.yaml"


pytestmark = pytest.mark.usefixtures("one_numba_thread")


# ------------------------------------------------------------------ helpers by hand
def test_hubbert_willis_formula():
    assert hubbert_willis(10e6, 5e6, 4e6, 1e6) == 3 * 5e6 - 10e6 + 4e6 - 1e6
    assert hubbert_willis(0.0, 0.0, 5.83e6) == 5.83e6


def test_crack_arms_finds_three_arms_at_120_degrees():
    rng = np.random.default_rng(0)
    pts = []
    for ang in (10.0, 130.0, 250.0):
        r = np.linspace(0.02, 0.08, 12)
        th = np.radians(ang + rng.normal(0, 3, r.size))
        pts.append(np.c_[r * np.cos(th), r * np.sin(th)])
    pts.append([[0.012, 0.0], [0.0, -0.011]])  # wall damage inside r_min: ignored
    xy = np.concatenate(pts) + [0.1, 0.1]
    arms = crack_arms(xy, [0.1, 0.1], 0.015, gap_deg=30, min_cracks=3)
    assert len(arms) == 3
    np.testing.assert_allclose([a["angle_deg"] for a in arms], [10, 130, 250], atol=3)
    assert all(a["count"] == 12 for a in arms)
    assert arms[0]["reach"] == pytest.approx(0.08, rel=1e-9)


def test_crack_arms_merges_across_zero_degrees_and_drops_small_clusters():
    xy = np.array([[math.cos(math.radians(a)), math.sin(math.radians(a))] for a in
                   (350, 355, 2, 8, 90)]) * 0.05
    arms = crack_arms(xy, [0, 0], 0.01, gap_deg=30, min_cracks=2)
    assert len(arms) == 1 and arms[0]["count"] == 4
    assert axis_misfit_deg(arms[0]["angle_deg"], 0.0) < 2.0


def test_connected_cracks_keeps_chains_reaching_the_borehole():
    chain = np.c_[np.linspace(0.012, 0.05, 9), np.zeros(9)]
    far = np.array([[0.0, 0.08], [0.004, 0.08]])
    idx = connected_cracks(np.concatenate([chain, far]), np.zeros(2), 0.01, 0.006)
    assert idx.tolist() == list(range(9))


def test_burst_is_the_first_window_with_enough_new_cracks():
    p = np.arange(10) * 0.1e6
    cracks = np.array([0, 0, 1, 1, 2, 3, 9, 12, 12, 12])
    b = burst_samples(p, cracks, 5, 0.25e6)
    assert b[0] == 6  # 9 cracks at 0.6 MPa, 3 at 0.35 MPa and below


def test_penetration_depth_counts_the_wetted_rings():
    # pores at r = 1.0..1.9 cm from the centre (wall at 1 cm), rings 0.25 cm wide
    r = np.repeat(0.01 + 0.0025 * np.arange(4) + 0.001, 3)
    P = np.repeat([0.9, 0.4, 0.15, 0.02], 3) * 2e6
    assert penetration_depth(r, P, 2e6, 0.01, 0.0025) == pytest.approx(0.0075)
    assert penetration_depth(r, P, 2e6, 0.01, 0.0025, frac=0.5) == pytest.approx(0.0025)
    assert penetration_depth(r, 0 * P, 2e6, 0.01, 0.0025) == 0.0
    assert penetration_depth(r, P, 0.0, 0.01, 0.0025) == 0.0
    # a wetted ring beyond a dry one does not count (the front is continuous from the wall)
    P2 = np.repeat([0.9, 0.0, 0.9, 0.9], 3) * 2e6
    assert penetration_depth(r, P2, 2e6, 0.01, 0.0025) == pytest.approx(0.0025)


def test_axis_misfit():
    assert axis_misfit_deg(175.0, 0.0) == pytest.approx(5.0)
    assert axis_misfit_deg(100.0, 10.0) == pytest.approx(90.0)
    assert axis_misfit_deg(30.0, 200.0) == pytest.approx(10.0)


@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_boundary_tractions_carry_the_far_field_stress(angle):
    # a ring of boundary points on the four faces of a unit square
    s = np.linspace(0.05, 0.95, 10)
    x = np.concatenate([np.c_[np.zeros(10), s], np.c_[np.ones(10), s],
                        np.c_[s, np.zeros(10)], np.c_[s, np.ones(10)]])
    F = boundary_tractions(x, np.arange(40), [0, 0], [1, 1], 6e6, 3e6, angle, 0.01)
    assert np.abs(F.sum(axis=0)).max() < 1e-6
    th = math.radians(angle)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    sig = R @ np.diag([6e6, 3e6]) @ R.T
    # the xmax face carries -sigma . (1, 0) x length 1 x thickness 0.01
    np.testing.assert_allclose(F[10:20].sum(axis=0), -sig @ [1.0, 0.0] * 0.01, rtol=1e-12)
    np.testing.assert_allclose(F[30:40].sum(axis=0), -sig @ [0.0, 1.0] * 0.01, rtol=1e-12)


# ------------------------------------------------------------------ a small plate end to end
# the small plate keeps the fast ramp that was the default before commit 65a0cde (2e9 Pa/s), to
# 20 MPa: a few seconds in CI. Its cracks grow stably between its close fixed edges (first crack
# 7.7 MPa, 15 cracks at the stop radius by 12.7 MPa), so a burst is 5 bonds within 1 MPa here
SMALL = ["model.coarsen=null", "model.size=0.1", "model.hole_radius=0.0075",
         "steps.injection.duration=0.01",
         "steps.injection.pressure_rate=2.0e9", "steps.injection.burst_window=1.0e6"]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("hf") / "run"
    code, s = run_workflow(HF, out, sets=SMALL, echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    return s, out


def test_small_plate_fractures_with_closed_books(small):
    s, out = small
    r = s["results"]["injection"]
    for key in ("breakdown_pressure", "hubbert_willis_pressure", "crack_branches",
                "crack_angles_deg", "dominant_crack_angle_deg", "sigma_H_angle_deg",
                "fluid_mass_balance_rel_error"):
        assert key in s, key
    assert s["fluid_mass_balance_rel_error"] < 1e-6
    assert s["energy_closure_rel_error"] < 1e-2
    assert s["sigma_H_angle_deg"] is None  # isotropic: no sigma_H
    # T from the calibration record of materials/sandstone.yaml (direct tension, 2-D)
    from geodem.materials_library import load_material

    tu = load_material("sandstone").calibrated["2d"]["measured"]["Tu"]
    assert 3e6 < tu < 1e7 and s["tensile_strength"] == pytest.approx(tu, rel=1e-12)
    assert "calibrated.2d.measured.Tu" in r["tensile_strength_source"]
    assert s["hubbert_willis_pressure"] == s["tensile_strength"]  # sigma = 0, p0 = 0
    # the burst: a pressure the ramp reached, after the first crack
    assert 0 < r["first_crack_pressure"] <= s["breakdown_pressure"] <= r["final_injection_pressure"]
    assert 2 <= s["crack_branches"] <= 4  # measured 2026-12-05: 2 arms (21, 237 deg)
    assert len(s["crack_angles_deg"]) == s["crack_branches"]
    assert r["injected_mass"] > 0 and s["cracks_tensile"] > 10
    for name in ("hf_pressure.png", "hf_history.png", "hf_animation.gif", "hydrofrac_curve.csv"):
        assert (out / name).stat().st_size > 1000, name
    a = np.loadtxt(out / "hydrofrac_curve.csv", delimiter=",", skiprows=1)
    assert np.all(np.diff(a[:, 2]) >= 0)  # the ramp
    assert a[:, 9].max() < 1e-6


# ------------------------------------------------------------------ the paper's size (slow)
@pytest.fixture(scope="module")
def isotropic(tmp_path_factory):
    out = tmp_path_factory.mktemp("hf_full") / "run"
    code, s = run_workflow(HF, out, echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    return s


@pytest.fixture(scope="module")
def confined(tmp_path_factory):
    out = tmp_path_factory.mktemp("hfc_full") / "run"
    code, s = run_workflow(HFC, out, echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    return s


def _seeds_1_and_2(workflow, first, tmp_path_factory, tag):
    """``first`` (seed 0's summary) and the summaries of ``workflow`` on seeds 1 and 2."""
    runs = [first]
    for seed in (1, 2):
        out = tmp_path_factory.mktemp(f"{tag}_seed{seed}") / "run"
        code, s = run_workflow(workflow, out, sets=[f"model.seed={seed}",
                                                    "steps.injection.gif=false"],
                               echo=False, progress=False)
        assert code == 0 and s["status"] == "ok", s.get("error")
        runs.append(s)
    return runs


@pytest.fixture(scope="module")
def isotropic_seeds(isotropic, tmp_path_factory):
    return _seeds_1_and_2(HF, isotropic, tmp_path_factory, "hf")


def test_maps_show_the_cracks_with_a_margin_and_never_more_than_the_plate():
    x = np.array([[0.0, 0.0], [1.0, 1.0], [0.5, 0.4], [0.5, 0.6], [0.5, 0.05], [0.5, 0.15]])
    centre, R, d = np.array([0.5, 0.5]), 0.04, 0.005
    frame = {"x": x, "ci": np.array([], int), "cj": np.array([], int)}
    assert view_half_width(frame, centre, R, d) == pytest.approx(4 * R)  # no crack yet
    frame.update(ci=np.array([2]), cj=np.array([3]))  # midpoint at the centre
    assert view_half_width(frame, centre, R, d) == pytest.approx(4 * R)
    frame.update(ci=np.array([2, 4]), cj=np.array([3, 4]))  # a crack 0.45 m out
    assert view_half_width(frame, centre, R, d) == pytest.approx(0.5 + d)  # the plate
    frame.update(ci=np.array([5]), cj=np.array([5]))  # 0.35 m out
    assert view_half_width(frame, centre, R, d) == pytest.approx(1.3 * 0.35 + 2 * d)


def _largest_gap_deg(angles):
    """Largest angle between neighbouring arms round the hole [deg]."""
    a = np.sort(np.asarray(angles, float) % 360.0)
    return float(np.max(np.diff(np.r_[a, a[0] + 360.0])))


def test_largest_gap_between_arms():
    assert _largest_gap_deg([10.0, 130.0, 250.0]) == pytest.approx(120.0)
    assert _largest_gap_deg([350.0, 170.0]) == pytest.approx(180.0)


@pytest.mark.slow
@pytest.mark.validation
def test_isotropic_plate_grows_arms_in_no_preferred_direction(isotropic_seeds):
    """Three packings (seeds 0-2). Measured 2026-12-05 (commit d2faca0) on the graded plate
    (8 d_mean hole, ramp 5e8 Pa/s, one thread): 3, 3, 4 arms (144, 302, 356 / 150, 231, 338 /
    58, 125, 204, 282 deg), the largest gap between neighbouring arms 158, 172, 136 deg. The
    bound on that gap was 150 deg while the library sandstone's elements translated (5, 5, 4
    arms, gaps 89-115 deg, commit 6d7aae0); the turning elements grow fewer arms: the same
    element parameters with ``rotation: false`` grow 5 arms on seeds 0 and 1 (largest gaps 115
    and 102 deg), and three arms at random angles leave wider gaps. The bound is now that no
    half of the plate is free of arms (< 180 deg): arms on both sides of the hole, no
    preferred direction. (The 2 d_mean hole of the 0.2 m plate grows 3, 2, 2 arms; MatDEM's
    picture shows 3.)"""
    for seed, s in enumerate(isotropic_seeds):
        assert 3 <= s["crack_branches"] <= 5, (seed, s["crack_angles_deg"])
        assert _largest_gap_deg(s["crack_angles_deg"]) < 180.0, (seed, s["crack_angles_deg"])
        assert s["fluid_mass_balance_rel_error"] < 1e-6


@pytest.mark.slow
@pytest.mark.validation
def test_isotropic_breakdown_within_30_percent_of_hubbert_willis(isotropic_seeds):
    """T = the calibrated Tu (direct tension of the 0.1 x 0.2 m calibration specimen, 4.02
    MPa). Measured 2026-12-05: 5.15, 3.90, 3.90 MPa (1.28, 0.97, 0.97 x; mean 1.07 x). The
    2 d_mean hole of the 0.2 m plate broke at 6.25, 7.50, 7.89 MPa (1.55-1.96 x): a hole of two
    elements puts the whole stress concentration into one element layer
    (docs/hydraulic_fracturing.md)."""
    ratios = [s["breakdown_pressure"] / s["hubbert_willis_pressure"] for s in isotropic_seeds]
    assert all(s["hubbert_willis_pressure"] == s["tensile_strength"] for s in isotropic_seeds)
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.30), ratios
    assert max(ratios) < 1.4, ratios  # no packing far off


@pytest.fixture(scope="module")
def isotropic_direct(tmp_path_factory):
    out = tmp_path_factory.mktemp("hf_dt") / "run"
    code, s = run_workflow(HF, out, sets=["steps.injection.tensile_strength_from=direct_tension",
                                          "steps.injection.gif=false"],
                           echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    return s, out


@pytest.mark.slow
def test_direct_tension_strength_of_the_plate_packing(isotropic_direct):
    s, out = isotropic_direct
    r = s["results"]["injection"]
    sub = json.loads((out / "tensile_test" / "out" / "summary.json").read_text())
    # T is the strip's F_peak / A (A = width x thickness = 10 d_mean x d_mean, the width from
    # surface to surface: the isotropic packing's faces are flat)
    res = sub["results"]["tension"]
    assert res["area"] == pytest.approx(10 * 0.005 * 0.005, rel=1e-4)
    assert s["tensile_strength"] == pytest.approx(res["peak_force"] / res["area"], rel=1e-12)
    # measured 4.15 MPa on the isotropic packing of the 2-D sandstone (its calibrated Tu, direct
    # tension of the twice larger calibration specimen: 4.02); strips scatter ~12 % (docs)
    assert 3.5e6 < s["tensile_strength"] < 5.0e6
    assert "direct tension" in r["tensile_strength_source"]
    assert s["hubbert_willis_pressure"] == s["tensile_strength"]  # sigma = 0, p0 = 0
    # how far the fluid had entered the rock at the breakdown: measured 0.010 m, 2 d_mean
    # (a quarter of the hole radius)
    assert r["fluid_penetration_at_breakdown"] < 0.02


@pytest.mark.slow
@pytest.mark.validation
def test_isotropic_breakdown_within_30_percent_of_direct_tension_hubbert_willis(
        isotropic_direct):
    # measured 5.15 MPa against T = 4.15 MPa: 1.24 x
    s, _ = isotropic_direct
    assert s["breakdown_pressure"] == pytest.approx(s["hubbert_willis_pressure"], rel=0.30)


@pytest.mark.slow
@pytest.mark.validation
def test_confined_fracture_follows_sigma_H(confined):
    # measured: dominant arm at 174.3 deg (5.7 deg from sigma_H), 2 branches (seeds 1, 2: 16.1,
    # 13.1 deg; docs/hydraulic_fracturing.md)
    assert confined["sigma_H_angle_deg"] == 0.0
    assert axis_misfit_deg(confined["dominant_crack_angle_deg"],
                           confined["sigma_H_angle_deg"]) < 15.0
    assert confined["hubbert_willis_pressure"] == pytest.approx(
        3 * 3e6 - 6e6 + confined["tensile_strength"], rel=1e-12)
    assert confined["fluid_mass_balance_rel_error"] < 1e-6
    assert json.loads(json.dumps(confined))["crack_branches"] >= 1


@pytest.fixture(scope="module")
def confined_seeds(confined, tmp_path_factory):
    return _seeds_1_and_2(HFC, confined, tmp_path_factory, "hfc")


@pytest.mark.slow
@pytest.mark.validation
def test_confined_breakdown_within_30_percent_of_hubbert_willis(confined_seeds):
    """Three packings (seeds 0-2), T = the calibrated Tu (4.02 MPa): ``3 sigma_h - sigma_H + T``
    = 7.02 MPa. Measured 2026-12-05 (commit d2faca0, turning library sandstone of 0010be8):
    8.24, 9.83, 8.72 MPa (1.17, 1.40, 1.24 x; mean 1.27 x). The translating library of commit
    6d7aae0 broke seed 0 at 10.47 MPa (1.48 x; this test was then a strict xfail on seed 0
    alone); the turning library's element parameters without rotation break seeds 0 and 1 at
    10.63 MPa (1.51 x): the turning elements lower the confined breakdown. The
    confinement adds 3.09, 5.94, 4.82 MPa to the isotropic breakdown of the same packings
    (mean 4.61 MPa, against 4.74 MPa for Kirsch's hoop stress one element into the rock and
    3 MPa at the wall; docs/hydraulic_fracturing.md, "Why the confined case is high"), and the
    isotropic breakdown is 1.07 T on the mean: together 1.27 x, so the mean is asserted, as for
    the isotropic plate; no packing beyond 1.5 x (seed 1: 1.40 x)."""
    ratios = [s["breakdown_pressure"] / s["hubbert_willis_pressure"] for s in confined_seeds]
    assert all(s["hubbert_willis_pressure"] == pytest.approx(3 * 3e6 - 6e6 + s["tensile_strength"],
                                                             rel=1e-12) for s in confined_seeds)
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.30), ratios
    assert max(ratios) < 1.5, ratios
    assert all(s["fluid_mass_balance_rel_error"] < 1e-6 for s in confined_seeds)


# the borehole of 16 d_mean (a 1.6 m graded plate, 7,903 elements, ~7 min on one core)
HOLE_16 = ["model.hole_radius=0.08", "model.size=1.6", "model.coarsen.band=0.04",
           "model.coarsen.transition=0.04", "steps.injection.gif=false"]


@pytest.mark.slow
@pytest.mark.validation
def test_confined_breakdown_within_30_percent_of_hubbert_willis_at_a_16_d_mean_hole(tmp_path):
    """The confined case with the borehole resolved twice as finely as the workflow's default
    (docs/hydraulic_fracturing.md, "Why the confined case is high"): measured 2026-12-05
    (commit d2faca0, seed 0) 6.79 MPa against 3 sigma_h - sigma_H + T = 7.02 MPa, 0.97 x (the
    8 d_mean default: 1.17 x on seed 0, 1.27 x on the mean of three seeds); 2 arms, the
    dominant 13.1 deg from sigma_H. (Translating library, commit 6d7aae0: 8.96 MPa, 1.27 x.)"""
    code, s = run_workflow(HFC, tmp_path / "run", sets=HOLE_16, echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    assert s["n_elements"] > 7000
    assert s["breakdown_pressure"] == pytest.approx(s["hubbert_willis_pressure"], rel=0.30)
    assert s["fluid_mass_balance_rel_error"] < 1e-6
