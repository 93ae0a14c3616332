"""Landslide from an elevation raster (geodem/cases/landslide.py, workflows/landslide.yaml).

* metrics by hand: runout, travel angle and the mass-centre path of a made-up slide;
* a tiny landslide (the shipped hill at scale 0.5: d = 6 m, ~840 elements, 56 slide
  elements, mass damping 0.2 % of critical, "rest" = mean speed below 0.5 m/s; at scale 0.4
  the 33 slide elements of one packing left 40 % of the slide in place): the slide
  moves down-slope and comes to rest; its mass centre obeys the energy
  bound of Coulomb sliding ``H_c / L_c >= mu`` (gravity is the only source once triggered:
  friction, breakage and damping only dissipate); the ground does not move; the outputs carry
  the raster's CRS and transform;
* bad input: a missing raster, a raster without CRS, two sliding surfaces -> exit 2 naming the
  field.

The default workflow (about 3,600 elements, a few minutes) is ``-m slow``.
"""
import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.cases.landslide import landslide_metrics, to_crs
from geodem.workflow.schema import load_builtins

load_builtins()

ROOT = Path(__file__).resolve().parents[2]
WF = ROOT / "workflows" / "landslide.yaml"
HILL = ROOT / "workflows" / "data" / "hill.tif"
TINY = ["model.scale=0.5", "steps.slide.max_time=40.0", "steps.slide.gif_frames=4",
        "steps.slide.snapshots=2", "steps.slide.vtk_frames=2", "steps.slide.slide_friction=0.1",
        "steps.slide.damping_ratio=0.002", "steps.slide.rest_speed=0.5",
        "steps.slide.ground_damping_ratio=0.002"]

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def _run(out, *sets, code=0):
    args = ["run", str(WF), "-o", str(out), "--no-progress"]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == code, res.output
    return json.loads((out / "summary.json").read_text()) if code == 0 else res.output


# ============================================================================ by hand
def test_metrics_of_a_block_moved_down_and_along():
    # two rows of two discs (r = 1) moved 10 m along +x and 4 m down
    x0 = np.array([[0.0, 10.0], [2.0, 10.0], [0.0, 12.0], [2.0, 12.0]])
    x = x0 + [10.0, -4.0]
    r = np.ones(4)
    m = np.ones(4)
    met = landslide_metrics(x0, x, r, m, 2, np.ones(4, bool))
    assert met["direction"] == [1.0]
    assert met["runout_m"] == pytest.approx(10.0)  # front edge 13 -> 3
    assert met["com_drop_m"] == pytest.approx(4.0) and met["com_travel_m"] == pytest.approx(10)
    # crown top: the first highest element, (0, 12) -> (0, 13); tip: the first front-most
    # element, (12, 6) -> front 13, bottom 5
    assert met["crown_h"] == 0.0 and met["crown_z"] == 13.0 and met["tip_z"] == 5.0
    H, L = 13.0 - 5.0, 13.0 - 0.0
    assert met["travel_angle_deg"] == pytest.approx(math.degrees(math.atan2(H, L)))
    # nothing displaced: no runout, no travel angle
    still = landslide_metrics(x0, x0, r, m, 2, np.zeros(4, bool))
    assert still["runout_m"] == 0.0 and still["travel_angle_deg"] is None


def test_section_points_go_back_to_the_crs():
    meta = {"origin": [650000.0, 5120000.0, 0.0], "line_local": [[0.0, 150.0], [600.0, 150.0]]}
    X = to_crs(np.array([[100.0, 450.0]]), meta)
    assert X.tolist() == [[650100.0, 5120150.0, 450.0]]


# ============================================================================ tiny run
@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("landslide") / "run"
    return _run(out, *TINY), out


def test_tiny_slide_moves_down_slope_and_stops(tiny):
    s, out = tiny
    r = s["results"]["slide"]
    d = 6.0  # 3 m / scale
    assert s["status"] == "ok" and r["stopped_by"] == "rest", r
    assert r["final_mean_speed"] < 1.0 and r["final_mean_speed"] < 0.2 * r["max_velocity"]
    assert r["com_travel_m"] > 2 * d and r["com_drop_m"] > d  # down-slope (east), downhill
    assert r["direction"] == [1.0]
    assert r["runout_m"] > 0 and 0 < r["travel_angle_deg"] < 45
    assert r["displaced_elements"] >= 0.8 * r["slide_elements"] and r["lost_elements"] == 0
    assert r["deposit_volume_m3"] == pytest.approx(
        r["slide_volume_m3"] * r["displaced_elements"] / r["slide_elements"], rel=0.3)
    assert r["ground_max_displacement"] < 0.5 * d
    for key in ("runout_m", "travel_angle_deg", "max_velocity", "deposit_volume_m3", "wall_s",
                "elements"):
        assert key in s
    assert s["elements"] == s["n_elements"]


def test_tiny_slide_obeys_the_coulomb_energy_bound(tiny):
    s, _ = tiny
    r = s["results"]["slide"]
    # H_c / L_c >= mu: friction dissipates at least mu M g L_c on the way from rest to rest
    assert r["slide_friction"] == 0.1
    assert r["com_ratio"] >= r["slide_friction"]
    assert r["energy_closure_rel_error"] < 0.05


def test_outputs_carry_the_crs_and_the_pictures(tiny):
    s, out = tiny
    geo = json.loads((out / "georef.json").read_text())
    assert geo["epsg"] == 32632 and "UTM zone 32N" in geo["crs"]
    assert geo["transform"] == [10.0, 0.0, 650000.0, 0.0, -10.0, 5120300.0]
    assert geo["line_crs"][0][:2] == [650000.0, 5120150.0]
    with h5py.File(out / "output.h5", "r") as f:
        assert int(f.attrs["crs_epsg"]) == 32632
        assert "UTM zone 32N" in f.attrs["crs_wkt"]
        assert f.attrs["local_origin"].tolist() == [650000.0, 5120000.0, 0.0]
    for name in ("landslide_velocity.png", "landslide_deposit.png", "landslide_snapshots.png",
                 "landslide.gif", "landslide_history.csv"):
        assert (out / name).stat().st_size > 0, name
    vtp = sorted((out / "landslide_vtk").glob("*.vtp"))
    assert len(vtp) == 2
    from geodem.io.vtk import read_vtp

    pts = read_vtp(vtp[0])["Points"]
    assert 650000 <= pts[:, 0].min() and pts[:, 0].max() <= 650600  # CRS eastings
    assert np.allclose(pts[:, 1], 5120150.0)


# ============================================================================ bad input
def test_missing_raster_exits_2_naming_the_field(tmp_path):
    out = _run(tmp_path / "x", "model.raster=nowhere/dem.tif", code=2)
    assert "model.raster" in out and "no such file" in out


def test_raster_without_crs_exits_2_naming_the_field(tmp_path):
    from geodem.geo.raster import read_elevation, write_raster

    t = read_elevation(HILL)
    p = tmp_path / "nocrs.tif"
    write_raster(p, t.z, t.transform, None)
    out = _run(tmp_path / "x", f"model.raster={p}", code=2)
    assert "model.raster" in out and "CRS" in out
    # the crs field supplies it
    from geodem.workflow import prepare

    prep = prepare(WF, sets=[f"model.raster={p}", "model.crs=EPSG:32632", "model.scale=0.3"])
    assert prep.built.info["georef"]["epsg"] == 32632


def test_two_sliding_surfaces_exit_2(tmp_path):
    out = _run(tmp_path / "x", "model.slip_surface=workflows/data/hill.tif", code=2)
    assert "model" in out and "exactly one of slip_depth and slip_surface" in out


# ============================================================================ slow
@pytest.mark.slow
def test_default_landslide(tmp_path):
    """The default workflow (docs/landslide.md):
    ``NUMBA_NUM_THREADS=1 geodem run workflows/landslide.yaml -o out/landslide``."""
    s = _run(tmp_path / "run")
    r = s["results"]["slide"]
    # measured: max_time, mean speed 0.17 m/s after 60 s (undamped bouncing; docs/landslide.md)
    assert r["final_mean_speed"] < 0.05 * r["max_velocity"] and r["lost_elements"] == 0
    assert r["com_ratio"] >= r["slide_friction"]
    assert r["runout_m"] > 50 and r["displaced_elements"] >= 0.9 * r["slide_elements"]


@pytest.mark.parametrize("sets, expected", [
    (["model.line=[[0,150],[700,150]]"],
     "model.line: end [700, 150] lies outside x 0 .. 600, y 0 .. 300 (local m from the "
     "raster's SW corner); allowed: points inside it"),
    (["model.line=[[10,150],[10,150]]"],
     "model.line: the two points are the same ([10, 150]): the section has zero length"),
    (["model.crs=NOTACRS"], "model.crs: 'NOTACRS' is not a CRS"),
    (["model.dim=3", "model.extent=[0,0,900,300]"],
     "model.extent: [0, 0, 900, 300] is not covered by the raster; allowed: inside x 0 .. 600, "
     "y 0 .. 300"),
    (["model.diameter=5000"],
     "model.diameter: d = diameter / scale = 5000 m is larger than the section (line: 600 m)"),
    (["model.base_depth=100000"],
     "model.base_depth: the model would hold 7681882 elements (more than 2000000); use larger "
     "elements (diameter / scale: d = 3 m now"),
])
def test_geometry_errors_name_the_workflow_field(sets, expected):
    args = ["validate", str(WF)]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    out = " ".join(res.output.split())
    assert expected in out
    assert "model.raster" not in out and "np.float64" not in out and "max_elements" not in out


def test_raster_hints_name_what_to_do_in_the_workflow(tmp_path):
    import rasterio

    from geodem.geo.raster import read_elevation

    t = read_elevation(HILL)
    p = tmp_path / "three.tif"
    with rasterio.open(p, "w", driver="GTiff", width=t.nx, height=t.ny, count=3,
                       dtype="float64", crs="EPSG:32632", transform=t.transform) as dst:
        for k in (1, 2, 3):
            dst.write(t.z, k)
    res = CliRunner().invoke(app, ["validate", str(WF), "--set", f"model.raster={p}"])
    assert res.exit_code == 2
    out = " ".join(res.output.split())
    assert "model.raster:" in out and "extract the elevation band first (e.g. gdal_translate " \
        "-b 1 in.tif dem.tif)" in out and "band=" not in out
