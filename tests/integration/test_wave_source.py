"""Generic step ``wave_source`` on a tiny elastic scene: the incident wave is the pulse sent in
at the base and it travels at c_p."""
import math

import numpy as np
import pytest
import yaml

from geodem.workflow import run_workflow

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def _run(tmp_path, model, step, materials):
    doc = {"metadata": {"name": "wave"}, "model": model, "materials": materials,
           "simulation": {"dt_fraction": 0.05},
           "steps": [dict({"kind": "wave_source", "name": "wave", "sides": "roller",
                           "receivers": "probe", "record_every": 1}, **step)]}
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(doc))
    code, s = run_workflow(p, tmp_path / "out", echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    return s, np.load(tmp_path / "out" / "wave_receivers.npz")


def test_2d_column_incident_velocity_and_travel_time(tmp_path):
    """A granite column 6 spacings wide, 120 m tall, roller sides, Ricker 0.01 m/s of 50 m
    wavelength: at the probe 60 m up the incident v_y peaks at 0.01 m/s (within 3 %) at
    t_c + 60 m / c_p, c_p = sqrt(E / ((1 - nu^2) rho)) = 4914 m/s (within 2 %; the wave
    reflected at the surface comes back after 36 ms)."""
    d = 2.5
    model = {"type": "scene", "dim": 2, "d": d, "lattice_origin": "corner",
             "elements": "elastic", "half_mass": ["xmin", "xmax"], "material": "rock",
             "domain": {"box": {"min": [0.0, 0.0], "max": [5.5 * d, 120.0]}},
             "groups": {"probe": {"box": {"min": [6.0, 59.0], "max": [8.0, 62.0]}}}}
    s, r = _run(tmp_path, model, {"wavelength": 50.0, "duration": 0.05},
                {"rock": {"library": "granite"}})
    cp = math.sqrt(60e9 / ((1 - 0.25 ** 2) * 2650.0))
    assert s["results"]["wave"]["p_wave_speed"] == pytest.approx(cp, rel=1e-12)
    assert r["receiver_x"].shape == (1, 2)
    y = r["receiver_x"][0, 1]
    vy = np.where(r["t"] < 0.036, r["v"][:, 0, 1], 0.0)  # the incident pulse only
    k = int(np.argmax(vy))
    assert vy[k] == pytest.approx(0.01, rel=0.03)
    t_c = 1.2 / (cp / 50.0)
    assert r["t"][k] - t_c == pytest.approx(y / cp, rel=0.02)
    assert s["energy_closure_rel_error"] < 0.02
