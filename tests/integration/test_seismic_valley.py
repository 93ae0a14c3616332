"""Seismic valley: the flat column against the analytic P wave (speed, free-surface doubling,
absorbing base) and the workflow on a small valley section."""
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.workflow import run_workflow
from geodem.cases.seismic import column_state, run_column
from geodem.fields.wave import Pulse

pytestmark = pytest.mark.usefixtures("one_numba_thread")
ROOT = Path(__file__).resolve().parents[2]


def _column(d, height, width_elements):
    """The workflow's scene (granite, elastic lattice from the corner) as a flat column."""
    import tempfile

    from geodem.workflow.schema import validate_document
    from geodem.workflow.yamlio import load_document

    wf = yaml.safe_load(open(ROOT / "workflows" / "seismic_valley.yaml"))
    wf["model"].update({"d": d, "regions": [], "groups": {},
                        "domain": {"box": {"min": [0.0, 0.0], "max": [40 * d, height]}}})
    wf["steps"] = [{"kind": "run", "nsteps": 1}]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "col.yaml"
        path.write_text(yaml.safe_dump(wf))
        cfg = validate_document(load_document(path))
    return column_state(cfg, cfg.model, width_elements), cfg.model.medium(cfg)


def test_flat_column_p_wave_speed_free_surface_and_absorbing_base():
    """A column 6 elements wide, 80 spacings tall, granite, Ricker pulse of 20 spacings: the
    arrival-time slope gives c_p = sqrt(E / ((1 - nu^2) rho)) within 3 %, the surface doubles
    the incident acceleration (1.85-2.15), the viscous base reflects less than 10 %."""
    d = 2.5
    st, med = _column(d, 80 * d, 6)
    assert (med["E"], med["nu"], med["rho"]) == (60e9, 0.25, 2650.0)  # granite, laboratory
    pulse = Pulse("ricker", med["cp"] / (20 * d), 0.01)
    r = run_column(st, med, pulse, dt_fraction=0.05)
    assert r["arrival_receivers"] >= 8 and r["reflection_receivers"] >= 8
    assert r["p_wave_speed_rel_error"] <= 0.03
    assert 1.85 <= r["free_surface_amplification"] <= 2.15
    assert 1.85 <= r["free_surface_amplification_velocity"] <= 2.15
    assert r["boundary_reflection"] < 0.10
    # the incident particle velocity is the one injected at the base
    assert r["incident_peak_velocity"] == pytest.approx(0.01, rel=0.05)
    assert r["energy_closure_error"] < 0.05


def test_column_too_short_for_the_pulse_is_refused():
    d = 2.5
    st, med = _column(d, 20 * d, 4)
    pulse = Pulse("ricker", med["cp"] / (20 * d), 0.01)
    with pytest.raises(ValueError, match="too short"):
        run_column(st, med, pulse, dt_fraction=0.05)


def test_valley_workflow_small(tmp_path):
    wf = yaml.safe_load(open(ROOT / "workflows" / "seismic_valley.yaml"))
    # 150 x 100 m, a V 60 m wide and 20 m deep on the axis x = 75 m
    wf["model"].update({"d": 2.5, "domain": {"box": {"min": [0.0, 0.0], "max": [150.0, 100.0]}},
                        "regions": [{"name": "valley", "empty": True, "shape": {"polygon": [
                            [37.5, 105.0], [112.5, 105.0], [75.0, 80.0]]}}]})
    wf["steps"][0].update({"duration": 0.05, "wavelength": 30.0, "frames": 6, "vtk_frames": 2})
    wf["steps"][1].update({"valley_x": 75.0, "valley_width": 60.0, "snapshots": 2})
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(wf))
    code, s = run_workflow(p, tmp_path / "out", echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    for key in ("amplification_max", "amplification_location_m", "p_wave_speed_rel_error",
                "free_surface_amplification", "boundary_reflection"):
        assert s[key] is not None, key
    assert s["p_wave_speed_rel_error"] < 0.05  # 12 spacings per wavelength: more dispersion
    assert 1.8 <= s["free_surface_amplification"] <= 2.2
    assert 0.0 <= s["amplification_location_m"] <= 150.0
    # the ground line moves about as much as the flat reference's surface
    assert 0.8 <= s["amplification_max"] <= 1.6
    out = tmp_path / "out"
    for f in ("seismic_snapshots.png", "seismic_surface.png", "seismic_reference.png",
              "seismic_animation.gif", "seismic_amplification.csv", "seismic_receivers.npz",
              "seismic_vtk/seismic.pvd"):
        assert (out / f).exists(), f
    assert len(list((out / "seismic_vtk").glob("*.vtp"))) == 2
    z = np.load(out / "seismic_receivers.npz")
    assert z["a"].shape[1] == len(z["receiver_x"]) and z["a"].shape[2] == 2
    summ = json.loads((out / "summary.json").read_text())
    assert summ["amplification_max"] == s["amplification_max"]
