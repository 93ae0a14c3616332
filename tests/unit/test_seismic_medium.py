"""Seismic valley: the lattice medium, the pulse, the section geometry and bad input."""
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.cases.seismic import (Pulse, boundary_sets, ground_smooth, lattice_E_nu,
                                     lattice_medium, section_points)

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


def test_valley_section_points_and_ground_line():
    d = 1.0
    x, y_top = section_points(40.0, 20.0, d, valley_width=20.0, valley_depth=8.0)
    # no centre strictly inside the V: y > y_top - 8 + 0.8 |x - 20| (+ round-off)
    inside = x[:, 1] > y_top - 8.0 + 0.8 * np.abs(x[:, 0] - 20.0) + 1e-9
    assert not inside.any()
    sets = boundary_sets(x, d)
    g = x[sets["surface"]]
    assert len(sets["surface"]) == len(np.unique(np.floor(x[:, 0] / d + 1e-6)))
    centre = np.argmin(np.abs(g[:, 0] - 20.0))
    assert g[centre, 1] == pytest.approx(y_top - 8.0, abs=d)   # valley bottom
    assert g[np.argmin(g[:, 0]), 1] == pytest.approx(y_top)      # flat ground
    assert np.all(x[sets["base"], 1] == x[:, 1].min())


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
    wf["model"].pop("material")
    wf["model"]["nu"] = 0.4
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(wf))
    res = CliRunner().invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "model.nu" in text and "0.3333" in text
    wf["model"]["nu"] = 0.25
    wf["steps"][0]["duration"] = 0.01
    p.write_text(yaml.safe_dump(wf))
    res = CliRunner().invoke(app, ["validate", str(p)])
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "steps[0].duration" in text and "crossed the section" in text
