"""The shipped excavation workflow (workflows/scene_excavate.yaml) through the CLI: the hole's
elements counted independently, energy closed, removed elements NaN in the frames; and a run
stopped after the excavation and resumed ends in the same state as an uninterrupted one (from a
checkpoint between the two stages, and from one after them). Integration tier: a few seconds
each."""
import json
import math
from pathlib import Path

import h5py
import numpy as np
from typer.testing import CliRunner

from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]
WF = ROOT / "workflows" / "scene_excavate.yaml"
#: a shorter run of the same workflow: settle 300, stages at steps 300 and 500, relax to 900
SHORT = ["--set", "steps.settle.nsteps=300", "--set", "steps.hole.nsteps_per_stage=200",
         "--set", "steps.relax.nsteps=200", "--set", "checkpoints.every_steps=100",
         "--set", "checkpoints.keep=20"]


def _lattice():
    """The scene's element centres: d = 0.01 in 0.3 x 0.2 m, 30 / 29 per row, 22 rows."""
    d, h = 0.01, 0.01 * math.sqrt(3.0) / 2.0
    pts = [(0.005 + (0.005 if k % 2 else 0.0) + d * i, 0.005 + h * k)
           for k in range(22) for i in range(29 if k % 2 else 30)]
    return np.array(pts)


def _run(out, *extra):
    res = CliRunner().invoke(app, ["run", str(WF), "-o", str(out), "--no-progress", *extra])
    assert res.exit_code == 0, res.output
    return json.loads((out / "summary.json").read_text())


def test_the_excavation_workflow_removes_the_hole_and_keeps_the_books(tmp_path):
    x = _lattice()
    hole = np.hypot(x[:, 0] - 0.15, x[:, 1] - 0.1) <= 0.04
    s = _run(tmp_path / "run")
    assert s["status"] == "ok" and s["steps"] == 1500 + 2 * 1000 + 1000
    assert len(x) == 11 * 30 + 11 * 29 == 649 and int(hole.sum()) == 57
    r = s["results"]["hole"]
    assert r["removed_per_stage"] == [17, 40] and s["n_elements"] == 649 - 57
    assert r["energy_removed"] > 0 and r["empty_groups"] == []
    assert r["energy_removed"] == sum(r["energy_removed_per_stage"])
    assert r["gravity_removed"][0] > 1e3 * r["elastic_removed"][0] > 0  # at rest, mostly m g y
    # bonds across y = 0.142, between rows 15 (y 0.1349) and 16 (y 0.1436): 2 x 29, less the 6
    # of the 3 row-15 elements inside the hole (x 0.14, 0.15, 0.16)
    assert s["results"]["roof"]["bonds_weakened"] == 2 * 29 - 6
    assert s["energy_closure_rel_error"] < 1e-6
    with h5py.File(tmp_path / "run" / "output.h5", "r") as f:
        pos = f["particles/all/position/value"][()]
        removed = f["observables/energy/removed/value"][()]
    assert pos.shape[1:] == (649, 2)
    assert np.isnan(pos[-1]).all(axis=1).sum() == 57 and not np.isnan(pos[0]).any()
    assert removed[0] == 0.0 and abs(removed[-1] / r["energy_removed"] - 1.0) < 1e-12


def test_resume_across_the_excavation_gives_the_same_state(tmp_path):
    ref = _run(tmp_path / "ref", *SHORT)
    assert ref["steps"] == 900 and ref["results"]["hole"]["steps_at_stage"] == [300, 500]
    for name, stop, resume_from in (("between", 600, 500), ("after", 700, 700)):
        out = tmp_path / name
        part = _run(out, *SHORT, "--stop-after-steps", str(stop))
        assert part["status"] == "interrupted" and part["steps"] == stop
        # resume from the checkpoint at resume_from (500: written at the end of the first
        # stage's time steps, before the second stage removes its elements)
        for p in (out / "checkpoints").glob("step_*"):
            if int(p.stem.split("_")[1]) > resume_from:
                p.unlink()
        s = _run(out, *SHORT, "--resume")
        assert s["steps"] == 900 and s["n_elements"] == ref["n_elements"] == 592
        assert s["state_sha256"] == ref["state_sha256"], name
        assert s["results"]["hole"]["removed_per_stage"] == [17, 40]
        with h5py.File(out / "output.h5", "r") as fa, \
                h5py.File(tmp_path / "ref" / "output.h5", "r") as fb:
            for k in ("observables/energy/total", "observables/energy/removed",
                      "observables/energy/closure_error", "particles/all/position"):
                assert np.array_equal(fa[f"{k}/value"][()], fb[f"{k}/value"][()],
                                      equal_nan=True), k
