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


def test_3d_column_travels_at_cp_with_free_field_sides(tmp_path):
    """3-D: an FCC column 8.5 spacings wide and 100 m tall (close-packed layers stacked along
    z, half masses on the lateral faces, free-field sides), a sandstone-like medium (E 15 GPa,
    nu 0.2, rho 2400: c_p = sqrt(E (1 - nu) / ((1 + nu)(1 - 2 nu) rho)) = 2635 m/s), Ricker
    0.01 m/s of 40 m wavelength: the arrival times of the incident peak at the 32 receivers
    between 15 and 65 m fit a speed within 2 % of c_p (measured -0.1 %), and the peak is the
    pulse within 8 % (measured -5 %; -0.6 % on a column 16.5 wide: the lattice's faces are not
    planes). Frames and ParaView frames are written in 3-D too."""
    d, H, w = 2.5, 100.0, 8.5 * 2.5
    model = {"type": "scene", "dim": 3, "d": d, "lattice_origin": "corner",
             "elements": "elastic", "half_mass": ["xmin", "xmax", "ymin", "ymax"],
             "material": "rock", "domain": {"box": {"min": [0.0, 0.0, 0.0], "max": [w, w, H]}},
             "groups": {"probe": {"box": {"min": [w / 2 - 1.5, w / 2 - 1.5, 15.0],
                                          "max": [w / 2 + 1.5, w / 2 + 1.5, 65.0]}}}}
    rock = {"E": 15e9, "nu": 0.2, "rho": 2400.0, "Tu": 4e6, "Cu": 75e6, "mu_i": 0.7}
    s, r = _run(tmp_path, model, {"wavelength": 40.0, "duration": 0.075, "sides": "free_field",
                                  "frames": 2, "vtk_frames": 2}, {"rock": rock})
    cp = math.sqrt(15e9 * 0.8 / (1.2 * 0.6 * 2400.0))
    assert s["results"]["wave"]["p_wave_speed"] == pytest.approx(cp, rel=1e-12)
    z = r["receiver_x"][:, 2]
    assert len(z) == 32 and z.min() > 15.0 and z.max() < 65.0
    t_c = 1.2 / (cp / 40.0)
    arrivals, peaks = [], []
    for k in range(len(z)):
        vz = np.where(r["t"] < t_c + (2 * H - z[k]) / cp - 0.01, r["v"][:, k, 2], 0.0)
        i = int(np.argmax(vz))  # the incident peak (the surface reflection masked)
        a, b, c = vz[i - 1], vz[i], vz[i + 1]
        arrivals.append(r["t"][i] + 0.5 * (a - c) / (a - 2 * b + c) * (r["t"][i + 1] - r["t"][i]))
        peaks.append(b)
    speed = np.polyfit(arrivals, z, 1)[0]
    assert speed == pytest.approx(cp, rel=0.02)
    assert np.mean(peaks) == pytest.approx(0.01, rel=0.08)
    assert s["energy_closure_rel_error"] < 0.02
    out = tmp_path / "out"
    assert len(list((out / "wave_frames").glob("frame_*.npz"))) >= 2
    assert (out / "wave_vtk" / "wave.pvd").exists()
