"""Seismic valley: the elastic lattice medium, the pulse, the section geometry and bad
input."""
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.cases.seismic import ground_smooth
from geodem.fields.wave import Pulse
from geodem.materials import elastic_lattice, lattice_E_nu


def lattice_medium(E, nu, rho, d):
    return elastic_lattice(E, nu, rho, d, 2)

pytestmark = pytest.mark.usefixtures("one_numba_thread")
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("nu", [-0.2, 0.0, 0.25, 1.0 / 3.0])
def test_lattice_medium_round_trip_and_wave_speeds(nu):
    E, rho, d = 3.0e10, 2500.0, 0.7
    m = lattice_medium(E, nu, rho, d)
    E2, nu2 = lattice_E_nu(m["Kn"], m["Ks"], m["thickness"])  # VALIDATION.md formulas
    assert E2 == pytest.approx(E, rel=1e-12) and nu2 == pytest.approx(nu, abs=1e-12)
    # constrained modulus of the triangular lattice from its bonds (uniaxial strain along y:
    # two diagonal bonds per cell, cell area sqrt3/2 d^2, thickness t)
    M = 1.5 * (0.75 * m["Kn"] + 0.25 * m["Ks"]) * d * d / (0.5 * math.sqrt(3) * d * d * d)
    assert m["M"] == pytest.approx(M, rel=1e-12)
    rho_cell = m["mass"] / (0.5 * math.sqrt(3) * d * d * m["thickness"])
    assert rho_cell == pytest.approx(rho, rel=1e-12)
    assert m["cp"] == pytest.approx(math.sqrt(E / ((1 - nu * nu) * rho)), rel=1e-12)
    assert m["cs"] == pytest.approx(math.sqrt(E / (2 * (1 + nu) * rho)), rel=1e-12)


def test_lattice_medium_refuses_nu_above_one_third():
    with pytest.raises(ValueError, match="1/3"):
        lattice_medium(1e10, 0.35, 2000.0, 1.0)


def test_pulses_peak_and_support():
    r = Pulse("ricker", 50.0, 0.02)
    t = np.linspace(0, r.duration, 20001)
    v = r(t)
    assert v.max() == pytest.approx(0.02, rel=1e-6)
    assert t[np.argmax(v)] == pytest.approx(1.2 / 50.0, abs=2 * (t[1] - t[0]))
    assert abs(v[0]) < 1e-4 * 0.02 and abs(v[-1]) < 1e-4 * 0.02
    s = Pulse("sine", 40.0, 0.01, cycles=3)
    assert s.duration == pytest.approx(3 / 40.0)
    assert s(np.array([-1e-3, s.duration + 1e-3])).tolist() == [0.0, 0.0]
    with pytest.raises(ValueError):
        Pulse("step", 1.0, 1.0)


def _valley_scene(**model):
    import tempfile

    from geodem.workflow.schema import validate_document
    from geodem.workflow.yamlio import load_document

    wf = yaml.safe_load(open(ROOT / "workflows" / "seismic_valley.yaml"))
    wf["model"].update(model)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "wf.yaml"
        path.write_text(yaml.safe_dump(wf))
        cfg = validate_document(load_document(path))
    return cfg.model.build(cfg)


def test_valley_section_points_and_ground_line():
    d = 1.0
    # 40 x 20 m, a V 20 m wide and 8 m deep at x = 20 (slope 0.8)
    b = _valley_scene(d=d, domain={"box": {"min": [0.0, 0.0], "max": [40.0, 20.0]}},
                      regions=[{"name": "valley", "empty": True, "shape": {"polygon": [
                          [8.75, 21.0], [31.25, 21.0], [20.0, 12.0]]}}])
    x = b.reference
    h = 0.5 * math.sqrt(3.0)
    assert x[:, 1].max() == pytest.approx(23 * h)  # rows from y = 0: floor(20 / h) + 1 = 24
    # no centre strictly inside the V: y > 12 + 0.8 |x - 20| (+ round-off)
    inside = x[:, 1] > 12.0 + 0.8 * np.abs(x[:, 0] - 20.0) + 1e-9
    assert not inside.any()
    st = b.state
    g = st.x[st.group_mask("ground")]
    # the ground line: one element per d-wide strip along x (x = 0 ... 40: 41 strips)
    assert len(g) == len(np.unique(np.floor(x[:, 0] / d + 1e-6))) == 41
    centre = np.argmin(np.abs(g[:, 0] - 20.0))
    assert g[centre, 1] == pytest.approx(12.0, abs=d)            # valley bottom
    assert g[np.argmin(g[:, 0]), 1] == pytest.approx(23 * h)       # flat ground
    # the elastic medium: the granite's cell mass, halved on the side planes
    med = b.info["medium"]
    on_side = (np.abs(st.x[:, 0]) < 1e-9) | (np.abs(st.x[:, 0] - 40.0) < 1e-9)
    assert on_side.sum() == 12 * 2  # even rows (12 of 24) start at x = 0 and end at x = 40
    assert np.all(st.m[on_side] == 0.5 * med["mass"])
    assert np.all(st.m[~on_side] == med["mass"])
    assert med["mass"] == pytest.approx(2650.0 * h * d ** 3)
    assert st.thickness == d


def test_ground_smooth_is_a_running_mean_along_the_line():
    xr = np.column_stack([np.arange(10.0), np.zeros(10)])[::-1]  # any order
    vals = np.arange(10.0)[::-1]
    out = ground_smooth(xr, vals, 2.0)  # window: the point and its two neighbours
    assert out[::-1][1:-1] == pytest.approx(np.arange(1.0, 9.0))
    assert out[::-1][0] == pytest.approx(0.5)


def test_bad_input_names_the_field(tmp_path):
    from typer.testing import CliRunner

    from geodem.cli import app

    wf = yaml.safe_load(open(ROOT / "workflows" / "seismic_valley.yaml"))
    wf["materials"]["rock"] = {"library": "granite"}
    wf["model"].update({"dim": 3, "regions": [], "half_mass": [],
                        "domain": {"box": {"min": [0.0, 0.0, 0.0], "max": [60, 20, 40]}}})
    wf["model"]["groups"] = {}
    wf["steps"] = [{"kind": "run", "nsteps": 1}]
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(wf))
    res = CliRunner().invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "model.material" in text and "0.2" in text  # granite nu = 0.25 on the FCC lattice
    wf = yaml.safe_load(open(ROOT / "workflows" / "seismic_valley.yaml"))
    wf["steps"][0]["duration"] = 0.01
    p.write_text(yaml.safe_dump(wf))
    res = CliRunner().invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "steps[0].duration" in text and "crossed the model" in text
    wf = yaml.safe_load(open(ROOT / "workflows" / "seismic_valley.yaml"))
    wf["model"]["elements"] = "calibrated"
    p.write_text(yaml.safe_dump(wf))
    res = CliRunner().invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    assert "elements: elastic" in " ".join(res.output.split())
