"""`geodem run`: the TwoBalls workflow's targets, the run directory, --dry-run, --overwrite,
--stop-after-steps + --resume bit-identity, exit codes."""
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from geodem.cli import app
from geodem.workflow.runner import prepare

ROOT = Path(__file__).resolve().parents[2]
TWO_BALLS = ROOT / "workflows" / "two_balls.yaml"
runner = CliRunner()

PLATEN = """\
metadata: {name: platen, description: a 2-D bonded block crushed by a platen}
model:
  type: lattice_block
  dim: 2
  counts: [10, 12]
  diameter: 0.01
  material: rock
  groups:
    base: {side: ymin}
    platen: {side: ymax}
materials:
  rock: {rho: 2650, kn: 2.0e7, ks: 6.0e6, xb: 2.0e-6, fs0: 20.0, mu: 0.4}
steps:
  - {kind: fix, group: base}
  - {kind: damping, standard: 12}
  - {kind: velocity, group: platen, velocity: [0.0, -0.5]}
  - {kind: run, name: load, nsteps: 1200}
  - {kind: velocity, group: platen, velocity: [0.0, 0.0]}
  - {kind: balance, nsteps: 300}
outputs:
  observables: {every: 50}
  frames: {every: 400, fields: [position, velocity, force, displacement, bonds]}
checkpoints: {every_steps: 300}
"""


def run(*args):
    return runner.invoke(app, ["run", *map(str, args), "--no-progress"])


def summary(d):
    return json.loads((Path(d) / "summary.json").read_text())


def h5_contents(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()]) if isinstance(o, h5py.Dataset)
                     else None)
    return out


@pytest.fixture(scope="module")
def two_balls_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tb") / "two_balls"
    res = run(TWO_BALLS, "-o", out)
    assert res.exit_code == 0, res.output
    return out, res


@pytest.fixture(scope="module")
def platen_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("platen") / "platen.yaml"
    p.write_text(PLATEN)
    return p


@pytest.fixture(scope="module")
def platen_run(platen_file):
    out = platen_file.parent / "full"
    res = run(platen_file, "-o", out)
    assert res.exit_code == 0, res.output
    return out


# ------------------------------------------------------------------ TwoBalls
def test_two_balls_targets(two_balls_run):
    out, res = two_balls_run
    s = summary(out)
    for key in ("status", "steps", "sim_time", "wall_time_s", "element_steps_per_s",
                "n_elements", "energy_closure_rel_error", "state_sha256"):
        assert key in s
    assert s["status"] == "ok" and s["steps"] == 500 and s["n_elements"] == 8
    assert s["period_rel_error"] < 0.005
    assert s["decay_rel_error"] < 0.005
    assert s["energy_closure_rel_error"] < 0.005
    chk = s["results"]["check"]
    assert chk["critical_overshoot"] < 1e-6 and chk["peaks"] >= 8 and chk["samples"] == 501
    assert max(chk["max_deviation_from_analytic"].values()) < 0.005
    assert s["bonds_broken"] == 0
    assert len(s["state_sha256"]) == 64
    try:
        import matplotlib  # noqa: F401
        assert (out / "two_balls.png").exists()
    except ImportError:
        assert s["plots"]["two_balls.png"].startswith("skipped: matplotlib is not installed")
        assert "skipped" in res.stdout
    assert "period rel error" in res.stdout


def test_two_balls_matches_a_direct_engine_run(two_balls_run):
    """The workflow's numbers are those of the engine driven directly from Python."""
    from geodem.cases import two_balls as tb
    from geodem.core.engine import Simulation

    st = tb.build(dim=2, damping_ratio=0.1)
    an = tb.analytic(st)
    sim = Simulation(st, backend="numba", dt=0.02 * an["T0"])
    t, u = [0.0], [st.x[1, 0] - 1.0]

    def rec(s):
        s.backend.pull(("x",))  # inside a run: a device backend's positions of this step
        t.append(s.state.time)
        u.append(s.state.x[1, 0] - 1.0)

    sim.run(500, callback=rec, every=1)
    m = tb.measure(t, u)
    s = summary(two_balls_run[0])
    assert s["period_rel_error"] == pytest.approx(abs(m["T"] - an["T"]) / an["T"], rel=1e-6)
    assert s["decay_rel_error"] == pytest.approx(
        abs(m["decay_rate"] - an["decay_rate"]) / an["decay_rate"], rel=1e-6)


def test_run_directory(two_balls_run):
    out, _ = two_balls_run
    for name in ("config.resolved.yaml", "manifest.json", "log.txt", "output.h5",
                 "summary.json"):
        assert (out / name).exists(), name
    man = json.loads((out / "manifest.json").read_text())
    for key in ("geodem_version", "versions", "config_hash", "seed", "backend", "threads"):
        assert key in man
    assert man["versions"]["numpy"] and man["backend"] == "numba" and man["seed"] == 0
    assert "oscillate" in (out / "log.txt").read_text()
    ckpts = sorted((out / "checkpoints").glob("step_*.npz"))
    assert [c.name for c in ckpts] == ["step_000000000250.npz", "step_000000000500.npz"]
    # the resolved config runs as it is and has the same hash
    prep = prepare(out / "config.resolved.yaml")
    assert prep.config_hash == man["config_hash"] == summary(out)["config_hash"]
    cfg = yaml.safe_load((out / "config.resolved.yaml").read_text())
    assert cfg["backend"] == "numba" and cfg["steps"][0]["name"] == "oscillate"


def test_output_h5_layout(two_balls_run):
    out, _ = two_balls_run
    with h5py.File(out / "output.h5", "r") as f:
        assert tuple(f["h5md"].attrs["version"]) == (1, 1)
        assert "TwoBalls" in f.attrs["config"] or "two_balls" in f.attrs["config"]
        assert f.attrs["status"] == "ok"
        pos = f["particles/all/position"]
        assert pos["value"].shape == (11, 8, 2)  # frames every 50 steps, 0..500
        assert list(pos["step"][()]) == list(range(0, 501, 50))
        assert pos["value"].attrs["unit"] == "m"
        assert f["particles/all/radius"].shape == (8,)  # static: written once
        ke = f["observables/energy/kinetic"]
        assert ke["value"].shape == (501,) and ke["time"][-1] == pytest.approx(
            summary(out)["sim_time"])
        disp = f["observables/groups/ten_percent_balls/displacement/value"][()]
        assert disp.shape == (501, 2) and disp[0, 0] == pytest.approx(0.01)
        walls = f["observables/groups/critical_walls/reaction/value"][()]
        assert np.abs(walls[:, 0]).max() > 0  # the walls hold the oscillators
        assert f["observables/cracks/total/value"][-1] == 0
        assert f["observables/bonds/intact/value"][0] == 6


def test_existing_directory_is_not_overwritten(two_balls_run, tmp_path):
    out, _ = two_balls_run
    res = run(TWO_BALLS, "-o", out)
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "already exists and is not empty" in res.stderr and "--overwrite" in res.stderr
    # a folder that is not a run directory is never deleted, even with --overwrite
    other = tmp_path / "precious"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    res = run(TWO_BALLS, "-o", other, "--overwrite")
    assert res.exit_code == 2 and "not a geodem run directory" in res.stderr
    assert (other / "thesis.tex").exists()


def test_overwrite(tmp_path):
    out = tmp_path / "tb"
    assert run(TWO_BALLS, "-o", out, "--set", "steps.oscillate.nsteps=20").exit_code == 0
    (out / "stale.txt").write_text("old")
    res = run(TWO_BALLS, "-o", out, "--overwrite", "--set", "steps.oscillate.nsteps=30",
              "--set", "steps.check.critical=null")
    assert res.exit_code == 0, res.output
    assert summary(out)["steps"] == 30
    # the user's own file stays, and the run says so
    assert (out / "stale.txt").read_text() == "old"
    said = " ".join(res.output.split())
    assert "--overwrite kept 1 entry" in said and "stale.txt" in said


def test_dry_run(tmp_path):
    out = tmp_path / "dry"
    res = run(TWO_BALLS, "-o", out, "--dry-run")
    assert res.exit_code == 0, res.output
    text = res.stdout
    for words in ("8 elements", "dt = 0.0001813 s", "500 time steps", "estimated memory",
                  "estimated run time", "estimated output size", "oscillate (run)"):
        assert words in text, words
    assert not out.exists()
    res = runner.invoke(app, ["run", str(TWO_BALLS), "--dry-run"])  # -o optional here
    assert res.exit_code == 0
    res = runner.invoke(app, ["run", str(TWO_BALLS)])
    assert res.exit_code == 2 and "-o/--out" in res.stderr


def test_stop_after_steps_and_resume_is_bit_identical(two_balls_run, tmp_path):
    out = tmp_path / "tb"
    res = run(TWO_BALLS, "-o", out, "--stop-after-steps", 180)
    assert res.exit_code == 0, res.output
    s = summary(out)
    assert s["status"] == "interrupted" and s["steps"] == 180
    assert s["interrupted_by"] == "--stop-after-steps 180"
    assert s["checkpoint"] == "checkpoints/step_000000000180.npz"
    with h5py.File(out / "output.h5", "r") as f:  # readable, holds what was done
        assert f["observables/energy/kinetic/step"][-1] == 180
    res = run(TWO_BALLS, "-o", out, "--resume")
    assert res.exit_code == 0, res.output
    r, full = summary(out), summary(two_balls_run[0])
    assert r["status"] == "ok" and r["steps"] == 500
    assert r["state_sha256"] == full["state_sha256"]
    assert r["period_rel_error"] == full["period_rel_error"]
    a, b = h5_contents(out / "output.h5"), h5_contents(two_balls_run[0] / "output.h5")
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    man = json.loads((out / "manifest.json").read_text())
    assert [x["resumed_from_step"] for x in man["sessions"]] == [None, 180]
    # resuming a finished run changes nothing
    res = run(TWO_BALLS, "-o", out, "--resume")
    assert res.exit_code == 0 and "already complete" in res.stderr


def test_resume_with_cracks_rebuilds_and_several_steps(platen_file, platen_run, tmp_path):
    out = tmp_path / "platen"
    assert run(platen_file, "-o", out, "--stop-after-steps", 777).exit_code == 0
    assert summary(out)["steps"] == 777
    assert run(platen_file, "-o", out, "--resume", "--stop-after-steps", 1350).exit_code == 0
    assert summary(out)["steps"] == 1350  # stopped inside the balance step
    res = run(platen_file, "-o", out, "--resume")
    assert res.exit_code == 0, res.output
    r, full = summary(out), summary(platen_run)
    assert full["bonds_broken"] > 50 and r["bonds_broken"] == full["bonds_broken"]
    assert r["state_sha256"] == full["state_sha256"]
    assert r["results"] == full["results"]
    assert r["energy_closure_rel_error"] == full["energy_closure_rel_error"] < 5e-3
    a, b = h5_contents(out / "output.h5"), h5_contents(platen_run / "output.h5")
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_resume_refusals(platen_file, platen_run, tmp_path):
    res = run(platen_file, "-o", platen_run, "--resume", "--set", "steps.load.nsteps=1300")
    assert res.exit_code == 2 and "workflow changed since the run" in res.stderr
    res = run(platen_file, "-o", tmp_path / "none", "--resume")
    assert res.exit_code == 2 and "nothing to resume" in res.stderr
    res = run(platen_file, "-o", platen_run, "--resume", "--overwrite")
    assert res.exit_code == 2 and "exclude each other" in res.stderr


def test_platen_outputs(platen_run):
    s = summary(platen_run)
    assert s["status"] == "ok" and s["steps"] == 1500 and s["n_elements"] == 120
    assert s["results"]["balance"]["unbalanced_force_ratio"] < 0.05
    with h5py.File(platen_run / "output.h5", "r") as f:
        bonds = f["particles/all/bonds/value"][()]
        assert bonds.shape == (5, 120) and bonds[0].sum() > bonds[-1].sum()
        react = f["observables/groups/platen/reaction/value"][()]
        assert react[1:, 1].max() > 0  # the block pushes the platen back up
        cracks = f["cracks/type"][()]
        assert cracks.size == s["bonds_broken"]
        assert f["observables/cracks/total/value"][-1] == s["bonds_broken"]


def test_runtime_failure_exit_1(platen_file, tmp_path):
    out = tmp_path / "unstable"
    res = run(platen_file, "-o", out, "--set", "steps.velocity_1.velocity=[0, -2000]",
              "--set", "simulation.monitor_every=20")
    assert res.exit_code == 1, res.output
    s = summary(out)
    assert s["status"] == "failed" and ("overlap" in s["error"] or "reduce dt" in s["error"])
    assert s["steps"] < 1500 and "state_sha256" in s
    assert "Traceback" not in res.output


def test_unknown_backend_exit_2(tmp_path):
    res = run(TWO_BALLS, "-o", tmp_path / "x", "--backend", "fortran")
    assert res.exit_code == 2 and "auto, numba, numpy, cupy" in res.stderr
    assert not (tmp_path / "x").exists()


def test_vtk_output(tmp_path):
    from geodem.io.vtk import read_vtp

    out = tmp_path / "vtk"
    res = run(TWO_BALLS, "-o", out, "--set", "outputs.vtk.every=100",
              "--set", "steps.oscillate.nsteps=100", "--set", "steps.check.critical=null")
    assert res.exit_code == 0, res.output
    pvd = (out / "vtk" / "frames.pvd").read_text()
    frames = sorted((out / "vtk").glob("frame_*.vtp"))
    assert len(frames) >= 2 and pvd.count("<DataSet") == len(frames)
    last = read_vtp(frames[-1])
    assert last["Points"].shape == (summary(out)["n_elements"], 3)


def test_checkpoints_by_wall_clock_and_keep(tmp_path):
    """every_seconds writes checkpoints as wall-clock time passes; only the newest `keep` stay."""
    out = tmp_path / "clock"
    res = run(TWO_BALLS, "-o", out, "--set", "checkpoints.every_seconds=1e-6",
              "--set", "checkpoints.keep=3", "--set", "checkpoints.final=false",
              "--set", "steps.oscillate.nsteps=20", "--set", "steps.check.critical=null")
    assert res.exit_code == 0, res.output
    files = sorted((out / "checkpoints").glob("*.npz"))
    assert len(files) == 3  # many were written (one per chunk), the newest three kept
    log = (out / "log.txt").read_text().lower()
    assert log.count("checkpoint") >= 3


def test_a_damaged_newest_checkpoint_is_passed_over(two_balls_run, tmp_path):
    out = tmp_path / "tb"
    assert run(TWO_BALLS, "-o", out, "--stop-after-steps", 300).exit_code == 0
    ck = out / "checkpoints"
    assert sorted(p.name for p in ck.glob("*.npz")) == ["step_000000000250.npz",
                                                         "step_000000000300.npz"]
    newest = ck / "step_000000000300.npz"
    newest.write_bytes(newest.read_bytes()[:3000])  # truncated (a full disk, a killed copy)
    res = run(TWO_BALLS, "-o", out, "--resume")
    assert res.exit_code == 0, res.output
    assert "checkpoint step_000000000300.npz is damaged" in res.stderr
    r, full = summary(out), summary(two_balls_run[0])
    assert r["status"] == "ok" and r["state_sha256"] == full["state_sha256"]
    assert any("step_000000000300.npz" in w for w in r["warnings"])
    a, b = h5_contents(out / "output.h5"), h5_contents(two_balls_run[0] / "output.h5")
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_a_marker_that_is_not_a_checkpoint_is_passed_over(tmp_path):
    out = tmp_path / "tb"
    assert run(TWO_BALLS, "-o", out, "--stop-after-steps", 300).exit_code == 0
    (out / "checkpoints" / "step_000000000300.json").write_text("[]")
    res = run(TWO_BALLS, "-o", out, "--resume")
    assert res.exit_code == 0 and "step_000000000300.json is damaged" in res.stderr
    for f in (out / "checkpoints").glob("*.json"):
        f.write_text("{}")
    res = run(TWO_BALLS, "-o", out, "--resume")
    assert res.exit_code == 2 and "no complete checkpoint" in res.stderr, res.output


def test_resuming_a_final_checkpoint_records_no_sample_twice(two_balls_run, tmp_path):
    import shutil

    out = tmp_path / "tb"
    shutil.copytree(two_balls_run[0], out)
    (out / "summary.json").unlink()  # a run stopped while writing its summary
    res = run(TWO_BALLS, "-o", out, "--resume")
    assert res.exit_code == 0, res.output
    a, b = h5_contents(out / "output.h5"), h5_contents(two_balls_run[0] / "output.h5")
    for k in b:
        assert np.array_equal(a[k], b[k]), k  # was: every series' last sample twice


def test_files_a_step_writes_are_listed_and_overwrite_removes_them(tmp_path, monkeypatch):
    # a step's own file (a curve CSV) that the step did not list: every entry the run created
    # in its folder goes into summary.json's files, so --overwrite knows it as the run's
    from geodem.workflow import runner as wr

    out = tmp_path / "p"
    finish = wr.Runner._finish

    def finish_after_a_csv(self, *a, **k):
        (self.dir.path / "step_curve.csv").write_text("step\n1\n")
        return finish(self, *a, **k)

    monkeypatch.setattr(wr.Runner, "_finish", finish_after_a_csv)
    assert run(TWO_BALLS, "-o", out, "--set", "steps.oscillate.nsteps=20").exit_code == 0
    monkeypatch.undo()
    assert "step_curve.csv" in summary(out)["files"]
    res = run(TWO_BALLS, "-o", out, "--overwrite", "--set", "steps.oscillate.nsteps=20")
    assert res.exit_code == 0 and not (out / "step_curve.csv").exists()
    assert "kept" not in res.output


def test_resume_refuses_a_locked_output_and_changes_nothing(tmp_path):
    out = tmp_path / "tb"
    assert run(TWO_BALLS, "-o", out, "--stop-after-steps", 300).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    import subprocess
    import sys

    holder = subprocess.Popen([sys.executable, "-c", (
        "import h5py, sys, time; f = h5py.File(sys.argv[1], 'r'); print('open', flush=True); "
        "time.sleep(60)"), str(out / "output.h5")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        res = run(TWO_BALLS, "-o", out, "--resume")
    finally:
        holder.kill()
        holder.wait()
    assert res.exit_code == 2 and "is open in another program" in res.stderr, res.output
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert not (out / "output.damaged.h5").exists()
    assert run(TWO_BALLS, "-o", out, "--resume").exit_code == 0  # closed: resumes


def test_a_folder_the_run_cannot_write_into_is_refused(tmp_path, monkeypatch):
    import tempfile

    def read_only(*a, **k):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
    res = run(TWO_BALLS, "-o", tmp_path / "ro")
    assert res.exit_code == 2 and "cannot write into the folder: Read-only" in res.stderr


def test_a_disk_without_room_for_the_run_is_refused_before_it_starts(tmp_path, monkeypatch):
    # a full disk mid-run crashes the HDF5 library itself (a bus error, no summary)
    import collections
    import shutil

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(2 << 20, 1 << 20, 1 << 20))
    res = run(TWO_BALLS, "-o", tmp_path / "full")
    assert res.exit_code == 2 and "only 1 MB is free there" in " ".join(res.stderr.split())
    assert not (tmp_path / "full").exists()
