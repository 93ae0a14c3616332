"""`geodem study speed-accuracy`: the Pareto front, the table, and the physical trends.

The --quick grid runs TwoBalls at dt = 0.005 and 0.02 T_min and the bonded chain at 50 and 200
elements: velocity Verlet is second order, so the TwoBalls trajectory error must shrink
~16-fold for a 4x smaller step, and the chain's long-wave speed error (dispersion of a front
5 elements long against 20) must shrink with resolution.
"""
import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.studies.speed_accuracy import COLUMNS, pareto_front

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_pareto_front_hand_made():
    wall = [1.0, 2.0, 3.0, 2.0, 4.0, 0.5, 5.0, np.nan, 3.0]
    err = [1e-1, 1e-2, 1e-3, 5e-2, 1e-3, 1.0, 1e-4, 1e-9, 1e-3]
    # 3 (2 s, 5e-2) is dominated by 1 (2 s, 1e-2); 4 (4 s, 1e-3) by 2 (3 s, 1e-3);
    # 2 and 8 are equal: neither dominates the other; 7 has no wall time
    assert pareto_front(wall, err).tolist() == [True, True, True, False, False, True, True,
                                                False, True]
    assert pareto_front([], []).tolist() == []


def test_quick_cli_run_table_and_trends(tmp_path):
    out = tmp_path / "sa"
    res = CliRunner().invoke(app, ["study", "speed-accuracy", "--quick", "--backend", "numba",
                                   "--cases", "two_balls,wave-speed", "-o", str(out)])
    assert res.exit_code == 0, res.output
    with open(out / "speed_accuracy.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == COLUMNS
    assert {r["precision"] for r in rows} == {"float64"}
    assert all(r["status"] == "ok" and float(r["wall_s"]) > 0 for r in rows), \
        [r["status"] for r in rows]
    tb = {float(r["dt_fraction"]): float(r["error"]) for r in rows if r["case"] == "two_balls"}
    assert set(tb) == {0.005, 0.02}
    assert 12.0 < tb[0.02] / tb[0.005] < 20.0  # second order: 16
    assert 0.03 < tb[0.02] < 0.05  # 10 periods x 2 pi x (omega dt)^2 / 24 = 0.041
    ws = {int(r["resolution"]): float(r["error"]) for r in rows if r["case"] == "wave_speed"}
    assert ws[200] < 0.25 * ws[50]
    assert ws[200] < 2e-3
    # the fastest point is always on the front, and so is the most accurate
    for case in ("two_balls", "wave_speed"):
        sel = [r for r in rows if r["case"] == case]
        assert min(sel, key=lambda r: float(r["wall_s"]))["pareto"] == "1"
        assert min(sel, key=lambda r: float(r["error"]))["pareto"] == "1"
    md = (out / "speed_accuracy.md").read_text()
    assert "## two_balls" in md and "## wave_speed" in md
    assert (out / "speed_accuracy_two_balls.png").stat().st_size > 1000


@pytest.mark.parametrize("args, words", [
    (["--cases", "two_balls,nope"], ["--cases", "'nope'", "allowed", "two_balls", "lattice"]),
    (["--cases", ","], ["--cases", "allowed", "thermal_rod"]),
])
def test_bad_cases_exit_2(tmp_path, args, words):
    res = CliRunner().invoke(app, ["study", "speed-accuracy", "-o", str(tmp_path / "x")] + args)
    assert res.exit_code == 2, res.output
    text = " ".join(res.output.split())
    for w in words:
        assert w in text
