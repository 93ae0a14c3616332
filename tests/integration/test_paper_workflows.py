"""The paper's cases (workflows/paper/, docs/paper.md) at reduced size: they run, and hold the
loading the paper describes."""
from pathlib import Path

import numpy as np
import pytest

from geodem.workflow import run_workflow

ROOT = Path(__file__).resolve().parents[2]
PAPER_HF = ROOT / "workflows" / "paper" / "hydraulic_fracturing.yaml"

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_paper_hydraulic_fracturing_holds_100_mpa_on_a_small_plate(tmp_path):
    """A 0.1 m plate (about 400 elements) for 0.2 ms: the borehole pressure reaches the
    paper's 100 MPa after 10 microseconds and stays there; the plate cracks; the fluid's
    books close."""
    out = tmp_path / "run"
    code, s = run_workflow(PAPER_HF, out, echo=False, progress=False,
                           sets=["model.coarsen=null", "model.size=0.1",
                                 "model.hole_radius=0.0075", "steps.injection.duration=2.0e-4",
                                 "steps.injection.gif=false"])
    assert code == 0 and s["status"] == "ok", s.get("error")
    r = s["results"]["injection"]
    assert r["stopped_by"] == "duration"
    assert r["final_injection_pressure"] == pytest.approx(1.0e8, rel=1e-12)
    a = np.genfromtxt(out / "hydrofrac_curve.csv", delimiter=",", names=True)
    held = a["time"] >= 1.0e-5 + 2.0e-7
    assert held.any() and np.allclose(a["injection_pressure"][held], 1.0e8, rtol=1e-12)
    assert s["cracks_tensile"] > 10
    assert s["fluid_mass_balance_rel_error"] < 1e-6
