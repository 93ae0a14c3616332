"""A run stopped by SIGTERM writes a checkpoint and exits 143; a run killed with SIGKILL leaves a
readable output.h5 and a checkpoint that --resume continues bit-identically.

The runs are subprocesses on the numpy backend (no kernel compilation in the child)."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest
from typer.testing import CliRunner

from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]
LONG = """\
metadata: {name: long}
model:
  type: lattice_block
  dim: 2
  counts: [8, 8]
  diameter: 0.01
  material: rock
  groups: {base: {side: ymin}, top: {side: ymax}}
materials:
  rock: {rho: 2650, kn: 2.0e7, ks: 6.0e6, xb: 2.0e-6, fs0: 20.0, mu: 0.4}
steps:
  - {kind: fix, group: base}
  - {kind: velocity, group: top, velocity: [0.0, -0.05]}
  - {kind: run, name: load, nsteps: 10000000}
outputs:
  observables: {every: 20}
  frames: {every: 200}
checkpoints: {every_steps: 200}
"""

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def start(wf, out, *extra):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen([sys.executable, "-m", "geodem", "run", str(wf), "-o", str(out),
                             "--backend", "numpy", "--no-progress", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=ROOT)


def wait_for_checkpoints(proc, out, count, timeout=60.0):
    t0 = time.time()
    while time.time() - t0 < timeout:
        found = list((out / "checkpoints").glob("step_*.json")) if (out / "checkpoints").is_dir() \
            else []
        if len(found) >= count:
            return
        if proc.poll() is not None:
            raise AssertionError(f"run ended early: {proc.communicate()}")
        time.sleep(0.02)
    proc.kill()
    raise AssertionError("no checkpoint in time")


def test_sigterm_checkpoints_and_exits_143(tmp_path):
    wf = tmp_path / "long.yaml"
    wf.write_text(LONG)
    out = tmp_path / "run"
    proc = start(wf, out)
    wait_for_checkpoints(proc, out, 1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["interrupted_by"] == "SIGTERM"
    assert (out / s["checkpoint"]).exists() and s["steps"] > 0
    assert f"step_{s['steps']:012d}.npz" in s["checkpoint"]
    assert "--resume" in err and "Traceback" not in err
    with h5py.File(out / "output.h5", "r") as f:
        assert f.attrs["status"] == "interrupted"
        assert f["observables/energy/kinetic/step"][-1] <= s["steps"]


def test_sigkill_leaves_readable_output_and_resume_is_bit_identical(tmp_path):
    wf = tmp_path / "long.yaml"
    wf.write_text(LONG)
    out = tmp_path / "run"
    proc = start(wf, out)
    wait_for_checkpoints(proc, out, 2)
    proc.kill()  # SIGKILL: no handler, no clean-up (while stepping, between flushes)
    proc.communicate(timeout=30)
    with h5py.File(out / "output.h5", "r") as f:  # readable
        n = f["observables/energy/kinetic/value"].shape[0]
        assert n >= 2 and f["particles/all/position/value"].shape[1:] == (64, 2)
    last = sorted((out / "checkpoints").glob("step_*.json"))[-1]
    ck = json.loads(last.read_text())["step"]
    stop = ck + 150
    runner = CliRunner()
    res = runner.invoke(app, ["run", str(wf), "-o", str(out), "--backend", "numpy", "--resume",
                              "--no-progress", "--stop-after-steps", str(stop)])
    assert res.exit_code == 0, res.output
    ref = tmp_path / "ref"
    res = runner.invoke(app, ["run", str(wf), "-o", str(ref), "--backend", "numpy",
                              "--no-progress", "--stop-after-steps", str(stop)])
    assert res.exit_code == 0, res.output
    a = json.loads((out / "summary.json").read_text())
    b = json.loads((ref / "summary.json").read_text())
    assert a["steps"] == b["steps"] == stop
    assert a["state_sha256"] == b["state_sha256"]
    with h5py.File(out / "output.h5", "r") as fa, h5py.File(ref / "output.h5", "r") as fb:
        for name in ("observables/energy/total", "particles/all/position"):
            for k in ("value", "step", "time"):
                assert (fa[f"{name}/{k}"][()] == fb[f"{name}/{k}"][()]).all()
