"""The reachable region: targets outside the charted (Cu / Tu, nu) points are refused before
the first iteration, with the measured bounds; inside, or on another micro-structure, not."""
import math

import pytest

from geodem.studies.calibrate import (TOLERANCES, CalibrationSpec, UnreachableTarget,
                                       calibrate)
from geodem.studies.reach import _point_fits, outside_region, shipped_chart

# a hand-made chart: Cu / Tu 8-20 at nu 0.1-0.3 (a square in (ln ratio, nu))
CHART = {"dim": 2, "structure": {"packing": "isotropic"},
         "bounds": {"ratio": [8.0, 20.0], "nu": [0.1, 0.3]},
         "points": [{"ratio": r, "nu": n} for r in (8.0, 20.0) for n in (0.1, 0.3)]
         + [{"s": 0.0, "rho_s": 1.0, "error": "no E / nu fit"}]}
ROCK = {"E": 1.5e10, "nu": 0.2, "Tu": 4e6, "Cu": 6e7, "mu_i": 0.7, "rho": 2300.0}


def _why(nu, ratio, structure=None):
    t = dict(ROCK, nu=nu, Cu=ratio * ROCK["Tu"])
    return outside_region(t, 2, structure or {"packing": "isotropic"}, TOLERANCES, CHART)


def test_a_target_inside_the_chart_is_accepted():
    assert _why(0.2, 15.0) is None


@pytest.mark.parametrize("nu, ratio", [(0.2, 8.0 * 0.95), (0.2, 20 * 1.05), (0.1 - 0.029, 12.0),
                                       (0.3 + 0.029, 12.0)])
def test_a_target_within_tolerance_of_the_edge_is_accepted(nu, ratio):
    assert _why(nu, ratio) is None


@pytest.mark.parametrize("nu, ratio", [(0.2, 30.0), (0.2, 5.0), (0.4, 12.0), (0.0, 12.0)])
def test_a_target_outside_is_refused_with_the_measured_bounds(nu, ratio):
    why = _why(nu, ratio)
    assert why is not None
    assert "measured Cu / Tu 8-20, nu (window fit) 0.10-0.30" in why


def test_another_micro_structure_is_not_judged_by_the_chart():
    assert _why(0.2, 30.0, {"packing": "isotropic", "bond_strength_weibull": 3.0}) is None


def test_calibrate_refuses_before_writing_anything(tmp_path, monkeypatch):
    import geodem.studies.reach as reach

    monkeypatch.setattr(reach, "shipped_chart", lambda dim: CHART)
    # the hand-made chart holds window-fit points only
    spec = CalibrationSpec(targets=dict(ROCK, Cu=30 * ROCK["Tu"]), name="odd", fit="window")
    with pytest.raises(UnreachableTarget, match="Cu / Tu = 30 with nu = 0.2 is outside"):
        calibrate(spec, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_an_elastic_fit_is_judged_by_the_elastic_points_only(monkeypatch):
    """A calibration on the elastic fit is judged by the points' ``nu_elastic`` (the same UCS
    runs below their crack-initiation stress), never by the window's nu; a chart without
    elastic points judges nothing."""
    import geodem.studies.reach as reach
    from geodem.studies.calibrate import check_reachable

    # the same runs with the cracks' dilation left out: nu -0.05-0.15
    elastic = dict(CHART, bounds=dict(CHART["bounds"], nu_elastic=[-0.05, 0.15]),
                   points=[dict(p, nu_elastic=p["nu"] - 0.15) if "nu" in p else p
                           for p in CHART["points"]])
    t = dict(ROCK, nu=0.25, Cu=12 * ROCK["Tu"])  # inside the window's square, above elastic
    assert outside_region(t, 2, {"packing": "isotropic"}, TOLERANCES, elastic) is None
    why = outside_region(t, 2, {"packing": "isotropic"}, TOLERANCES, elastic, fit="elastic")
    assert "nu (elastic fit) -0.05-0.15" in why and "at Cu / Tu 12 nu -0.08-0.18" in why
    assert outside_region(t, 2, {"packing": "isotropic"}, TOLERANCES, CHART,
                          fit="elastic") is None  # no elastic points: not judged
    monkeypatch.setattr(reach, "shipped_chart", lambda dim: elastic)
    with pytest.raises(UnreachableTarget, match="nu = 0.25 is outside"):
        check_reachable(CalibrationSpec(targets=t, name="odd", fit="elastic"))
    check_reachable(CalibrationSpec(targets=t, name="odd", fit="window"))  # the window fit reaches it
    with pytest.raises(ValueError, match="fit = 'tangent': allowed 'window' or 'elastic'"):
        CalibrationSpec(targets=t, fit="tangent")


@pytest.mark.parametrize("fit", ["window", "elastic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_the_shipped_charts_hold_every_library_rock(dim, fit):
    """Every library rock lies inside the charted region of both fits; in 3-D the elastic
    fit's nu 0.25-0.30 needs the ks / kn 0.1-0.15 rows of the chart."""
    from geodem.materials_library import list_materials, load_material

    chart = shipped_chart(dim)
    assert chart is not None and chart["dim"] == dim
    for name in list_materials():
        t = load_material(name).values()
        assert outside_region(t, dim, {"packing": "isotropic"}, TOLERANCES, chart,
                              fit=fit) is None, name


def test_two_point_friction_angle_by_hand():
    from geodem.studies.friction import two_point_angle

    # K = (1 + sin 35) / (1 - sin 35) = 3.690: sigma1 rises by 36.90 MPa over 10 MPa
    k = (1 + math.sin(math.radians(35))) / (1 - math.sin(math.radians(35)))
    assert two_point_angle(75e6, 75e6 + k * 10e6, 10e6) == pytest.approx(35.0, abs=1e-9)
    assert two_point_angle(75e6, 80e6, 10e6) == 0.0  # K < 1: no frictional strengthening


def test_the_friction_study_changes_one_parameter_per_variant(tmp_path, monkeypatch):
    import yaml

    import geodem.workflow as wf
    from geodem.studies.friction import friction_study
    from geodem.materials_library import load_material

    seen = []

    def fake_run(path, out, **kw):
        doc = yaml.safe_load(open(path))
        seen.append(doc)
        return 0, {"status": "ok", "peak_strengths": [75e6, 110e6]}

    monkeypatch.setattr(wf, "run_workflow", fake_run)
    rec = friction_study(tmp_path, variants=(("base", {}), ("mu 0.5", {"mu": 0.5})))
    base = load_material("sandstone").calibrated["2d"]["element"]
    assert seen[0]["materials"]["rock"]["mu"] == base["mu"]
    assert seen[1]["materials"]["rock"]["mu"] == 0.5
    assert seen[1]["materials"]["rock"]["kn_per_d"] == base["kn_per_d"]
    assert seen[1]["steps"][0]["confining_pressures"] == [0.0, 10e6]
    # K = 3.5: sin phi = 2.5 / 4.5
    assert rec["rows"][1]["phi_deg"] == pytest.approx(math.degrees(math.asin(2.5 / 4.5)))
    assert (tmp_path / "friction.md").exists()


@pytest.mark.parametrize("dim, top", [(2, 0.45), (3, 0.35)])
def test_the_shipped_charts_hold_the_elastic_fit_of_every_point(dim, top):
    """Every measured point of the shipped charts has its elastic nu too, never above the
    window's by more than round-off (cracks only add lateral strain), and below ``top``. In 3-D
    the elastic nu reaches 0.30 only at ks / kn 0.1, where the window fit of the strong points
    is dilated past 0.5 by early cracks (docs/calibration.md, "Reachable region")."""
    chart = shipped_chart(dim)
    ok = [p for p in chart["points"] if "ratio" in p]
    assert ok and all("nu_elastic" in p for p in ok)
    assert all(p["nu_elastic"] <= p["nu"] + 0.01 for p in ok if "nu" in p)
    assert all("window_error" in p for p in ok if "nu" not in p)
    assert max(p["nu_elastic"] for p in ok) < top


def _measured(nu, nu_el, ci=None):
    el = {"nu": nu_el, "E": 9e9}
    if ci is not None:
        el["crack_initiation_stress"] = ci
    return {"nu": nu, "E": 5e9, "Cu": 60e6, "Tu": 3e6, "wall_time_s": 1.0,
            "fits": {"elastic": el} if nu_el is not None else {}}


def test_a_point_dilated_by_cracks_counts_for_the_elastic_fit_only():
    p = _point_fits(_measured(0.94, 0.31, ci=6e6), 0.5)
    assert "nu" not in p and "error" not in p and "0.94" in p["window_error"]
    assert p["nu_elastic"] == 0.31 and p["ratio"] == 20.0
    assert p["crack_initiation"] == pytest.approx(0.1)
    # both fits at or past the limit, or no elastic fit: a mechanism, no values
    for m in (_measured(0.94, 0.6), _measured(0.94, None)):
        p = _point_fits(m, 0.5)
        assert p.keys() == {"error"} and "mechanism" in p["error"]
    p = _point_fits(_measured(0.3, 0.25), 0.5)
    assert p["nu"] == 0.3 and p["nu_elastic"] == 0.25 and "window_error" not in p


def test_merge_adds_points_and_replaces_the_same_grid_point(tmp_path, monkeypatch):
    import geodem.studies.reach as reach

    monkeypatch.setattr(reach, "__file__", str(tmp_path / "reach.py"))
    base = {"dim": 3, "structure": {"packing": "isotropic"}, "mu": 0.25,
            "specimen": {"d_mean": 0.01}, "bounds": {}}
    reach.save_chart(dict(base, points=[
        {"s": 0.25, "rho_s": 2.0, "nu": 0.2, "nu_elastic": 0.2, "ratio": 6.0},
        {"s": 0.1, "rho_s": 8.0, "error": "mechanism"}]))
    dest = reach.save_chart(dict(base, points=[
        {"s": 0.1, "rho_s": 8.0, "window_error": "dilated", "nu_elastic": 0.31,
         "ratio": 21.6}]), merge=True)
    chart = reach.shipped_chart(3)
    assert dest == tmp_path / "reach_3d.json"
    assert [(p["s"], p["rho_s"]) for p in chart["points"]] == [(0.1, 8.0), (0.25, 2.0)]
    assert chart["points"][0]["nu_elastic"] == 0.31 and "error" not in chart["points"][0]
    assert chart["bounds"] == {"ratio": [6.0, 21.6], "nu": [0.2, 0.2],
                               "nu_elastic": [0.2, 0.31]}
    assert "--merge" in chart["command"]
    with pytest.raises(ValueError, match="mu"):
        reach.save_chart(dict(base, mu=0.5, points=[]), merge=True)


# --- the friction angle of 3-D translating elements (reach.FRICTION_POINTS) ---------------
from geodem.studies import reach as R  # noqa: E402
from geodem.studies import calibrate as C  # noqa: E402

ISO = {"packing": "isotropic"}


def test_the_friction_model_follows_its_points():
    """Least squares through the measured points: within 1 deg of each, and phi follows mu
    about three times more steeply on the sandstone's springs (ks / kn 0.30) than on the
    mudstone's (0.10): 35.5 - 16.0 deg over ln(0.343 / 0.05) against 33.2 - 28.3 over
    ln(0.217 / 0.05)."""
    m = R.friction_model(3, ISO)
    for s, mu, phi, _, _ in R.FRICTION_POINTS[3]:
        assert m.phi(s, mu) == pytest.approx(phi, abs=1.0)
    # the floor is the measurements at the lowest mu, interpolated in s
    assert R.friction_floor(0.10, 3, ISO, 0.05) == pytest.approx(28.3 + (0.10 - 0.102) / (
        0.095 - 0.102) * (28.8 - 28.3))
    assert R.friction_floor(0.20, 3, ISO, 0.05) == pytest.approx(
        28.3 + (0.20 - 0.102) / (0.325 - 0.102) * (16.0 - 28.3))
    assert R.friction_floor(0.2, 3, ISO, 0.07) is None
    assert m.slope(0.30) / m.slope(0.10) > 2.0
    assert m.phi(0.2, m.mu_for(0.2, 31.0)) == pytest.approx(31.0, abs=1e-9)
    assert R.friction_model(3, {"packing": "isotropic", "rotation": True}) is None
    assert R.friction_model(2, ISO) is None


def test_the_spring_ratio_for_a_poisson_ratio_comes_from_the_chart():
    """The 3-D chart's elastic nu: 0.29-0.31 at ks / kn 0.1, 0.25-0.27 at 0.15, 0.20-0.21 at
    0.25 (docs/calibration.md); the library's 3-D records sit at 0.10 (nu 0.3), 0.165 (0.25)
    and 0.30 (0.2)."""
    assert R.s_for_nu(0.30, 3, ISO) == pytest.approx(0.10, abs=0.01)
    assert R.s_for_nu(0.25, 3, ISO) == pytest.approx(0.165, abs=0.015)
    assert R.s_for_nu(0.20, 3, ISO) == pytest.approx(0.26, abs=0.02)
    assert R.s_for_nu(0.9, 3, ISO) == pytest.approx(0.1)  # clamped to the chart
    assert R.s_for_nu(0.3, 3, dict(ISO, bond_gap=0.05)) is None


def _clay(phi, nu=0.3):
    return {"E": 5e7, "nu": nu, "Tu": 2e4, "Cu": 2e5, "mu_i": math.tan(math.radians(phi)),
            "rho": 2000.0}


def test_a_friction_angle_below_the_3d_floor_is_refused_up_front(tmp_path):
    """A stiff clay (nu 0.3, phi 25 deg): 3-D elements at nu 0.3 measure 28.8 deg at the lowest
    contact friction, so 25 deg is refused before any folder is made; 28 deg (the mudstone,
    28.3 measured at mu 0.05) is not."""
    why = R.friction_out_of_reach(_clay(25.0), 3, ISO, TOLERANCES, C.MU_RANGE)
    assert why and "phi = 25.0 deg" in why and "ks / kn 0.10" in why
    low = float(why.split("about ")[1].split(" deg")[0])
    assert 27.5 < low < 29.5
    # no upper refusal: the model is not trusted above the measured friction (granite, 50 deg)
    assert R.friction_out_of_reach(_clay(50.0, nu=0.25), 3, ISO, TOLERANCES,
                                   C.MU_RANGE) is None
    assert R.friction_out_of_reach(_clay(28.0), 3, ISO, TOLERANCES, C.MU_RANGE) is None
    assert R.friction_out_of_reach(_clay(25.0, nu=0.2), 3, ISO, TOLERANCES, C.MU_RANGE) is None
    spec = CalibrationSpec(targets=_clay(25.0), name="clay", dim=3, friction=True,
                           fit="elastic", ucs_size=(0.1, 0.1, 0.2))
    with pytest.raises(UnreachableTarget, match="without --friction"):
        calibrate(spec, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    C.check_reachable(CalibrationSpec(targets=_clay(25.0), name="clay", dim=3, fit="elastic",
                                     ucs_size=(0.1, 0.1, 0.2)))


def test_the_3d_prior_takes_the_springs_and_friction_from_the_measurements():
    """A mudstone (nu 0.3, phi 28 deg) starts at ks / kn 0.10 and mu at the lower bound (the
    slope table of 2-D put 0.26 and 0.22); a sandstone (nu 0.2, 35 deg) between the
    measured 30.0 deg at mu 0.255 and 35.5 at 0.343 (ks / kn 0.30-0.33) and the limestone's
    41.0 at 0.43 (0.17): the chart gives nu 0.2 at ks / kn 0.26."""
    mud = C.prior_guess(CalibrationSpec(targets=_clay(28.0), dim=3, friction=True,
                                        fit="elastic", ucs_size=(0.1, 0.1, 0.2)))
    assert mud["ks_per_d"] / mud["kn_per_d"] == pytest.approx(0.10, abs=0.01)
    assert mud["mu"] == pytest.approx(C.MU_RANGE[0])
    sand = dict(_clay(35.0, nu=0.2), E=1.5e10, Tu=4e6, Cu=7.5e7)
    el = C.prior_guess(CalibrationSpec(targets=sand, dim=3, friction=True, fit="elastic",
                                        ucs_size=(0.1, 0.1, 0.2)))
    assert 0.15 < el["mu"] < 0.40
