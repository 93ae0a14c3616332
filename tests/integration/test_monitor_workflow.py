"""The example workflow workflows/scene_pressure.yaml through the CLI: a 2-D lattice block on a
roller base under a ramped top pressure p, monitored. Against the analytic answer: the base
reaction is p x the loaded area, the Love-Weber stress of a band across the block is -p (the
lattice's rows alternate 20 and 19 elements: the cells' volume is that of a block 19.5
diameters wide, so the band reads p x 20 / 19.5; within 4 %), and the top settles by p H / E of
the triangular lattice (docs/physics.md section 11) within 10 %; the energy books stay closed.
Stopped mid-ramp and resumed: the same monitor.csv, byte for byte, and the same final state.
A pressure in the borehole of the hydraulic-fracturing plate (a random packing): no net force,
the wall pushed outwards by about Lame's ring displacement, the energy books closed."""
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from geodem.cli import app
from geodem.workflow import run_workflow

ROOT = Path(__file__).resolve().parents[2]
WF = ROOT / "workflows" / "scene_pressure.yaml"
P, D, KN, KS = 1.0e5, 0.01, 2.0e7, 6.0e6


def _run(out, *extra):
    res = CliRunner().invoke(app, ["run", str(WF), "-o", str(out), "--no-progress", *extra])
    assert res.exit_code == 0, res.output
    return json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() \
        else None


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene_pressure")
    return out, _run(out)


def test_pressure_and_monitor_against_the_analytic_block(full):
    import h5py

    out, s = full
    assert s["status"] == "ok" and s["n_elements"] == 11 * 20 + 11 * 19
    assert s["energy_closure_rel_error"] < 1e-4
    assert (out / "monitor.png").stat().st_size > 0 and "monitor.csv" in s["files"]
    with open(out / "monitor.csv") as f:
        rows = list(csv.reader(f))
    assert len(rows) == 1 + 31  # header, steps 0, 100, ..., 3000
    assert [int(r[0]) for r in rows[1:]] == list(range(0, 3001, 100))
    last = s["results"]["monitor"]["last"]
    area = 0.2 * D  # the block's width surface to surface x the 2-D thickness d
    pr = s["results"]["pressure"]
    assert pr["area"] == pytest.approx(area) and pr["elements"] == 19
    assert pr["total_force"][1] == pytest.approx(-P * area)
    with h5py.File(out / "output.h5") as h:
        base = h["observables/groups/base/reaction/value"][-1]
    assert -base[1] / area == pytest.approx(P, rel=0.01)  # equilibrium: the base carries p
    sig = -last["band.syy [Pa]"]
    assert sig == pytest.approx(P, rel=0.04)
    assert sig == pytest.approx(P * 20 / 19.5, rel=0.01)
    assert abs(last["band.sxx [Pa]"]) < 0.01 * P  # uniaxial stress: the sides are free
    kn, ks = KN / 2, KS / 2
    e_lattice = 2 * math.sqrt(3) * kn * (kn + ks) / (D * (3 * kn + ks))
    h = 21 * D * math.sqrt(3) / 2  # base row to top row
    assert -last["top_centre.uy [m]"] == pytest.approx(P * h / e_lattice, rel=0.10)


def test_stopped_mid_ramp_and_resumed_gives_the_same_rows_and_state(full, tmp_path):
    out, s = full
    part = tmp_path / "part"
    _run(part, "--stop-after-steps", "1234")
    with open(part / "monitor.csv") as f:
        assert int(list(csv.reader(f))[-1][0]) == 1200
    b = _run(part, "--resume")
    assert (part / "monitor.csv").read_bytes() == (out / "monitor.csv").read_bytes()
    assert b["state_sha256"] == s["state_sha256"]
    assert b["results"] == s["results"]
    assert np.isfinite(b["energy_closure_rel_error"])


def test_a_pressure_in_a_cavity_pushes_its_wall_outwards(tmp_path):
    c, a, g = 0.03, 0.006, 0.0035  # centre, hole radius, points just beyond the wall
    pts = {"east": [c + a + g, c], "west": [c - a - g, c], "north": [c, c + a + g],
           "south": [c, c - a - g]}
    wf = {"metadata": {"name": "cavity", "seed": 0},
          "model": {"type": "hydrofrac_plate", "size": 0.06, "d_mean": 0.005, "hole_radius": a,
                    "material": "rock"},
          "materials": {"rock": {"rho": 2650, "kn": KN, "ks": KS, "xb": 2.0e-5, "fs0": 200.0,
                                 "mu": 0.4}},
          "steps": [{"kind": "fix", "group": "boundary"},
                    {"kind": "monitor", "every": 100, "points": pts, "groups": [],
                     "plot": False},
                    {"kind": "pressure", "shape": {"disc": {"center": [c, c], "radius": a}},
                     "pressure": P, "ramp_steps": 600},
                    {"kind": "balance", "nsteps": 600}],
          "outputs": {"observables": {"every": 100}}}
    path = tmp_path / "cavity.yaml"
    path.write_text(yaml.safe_dump(wf))
    code, s = run_workflow(path, tmp_path / "out", echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    pr = s["results"]["pressure"]
    assert pr["area"] == pytest.approx(2 * math.pi * a * 0.005, rel=0.1)  # t: about d_mean
    assert np.linalg.norm(pr["total_force"]) < 0.01 * P * pr["area"]  # balanced round the hole
    assert s["energy_closure_rel_error"] < 1e-4
    last = s["results"]["monitor"]["last"]
    outward = [last["east.ux [m]"], -last["west.ux [m]"], last["north.uy [m]"],
               -last["south.uy [m]"]]
    assert min(outward) > 0
    # the order of Lame's thick ring (inner radius a under p, outer radius 0.03 m fixed, plane
    # stress, the triangular lattice's E and nu) at r = a + g: a random packing is softer and
    # less regular than the lattice, so within a factor of 2 only
    kn, ks = KN / 2, KS / 2
    e = 2 * math.sqrt(3) * kn * (kn + ks) / (D * (3 * kn + ks))
    nu = (kn - ks) / (3 * kn + ks)
    b, r = 0.03, a + g
    B = P * (1 - nu * nu) / (e * ((1 + nu) / b ** 2 + (1 - nu) / a ** 2))
    lame = B / r - B * r / b ** 2
    assert 0.5 < np.mean(outward) / lame < 2.0
