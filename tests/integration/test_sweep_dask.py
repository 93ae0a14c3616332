"""``geodem sweep`` on Dask local clusters: results, counts, per-member values, resume (completed
members not rerun, interrupted ones continued), a failing member, an external scheduler.

Members are workflows/two_balls.yaml (8 elements) with a few tens of time steps on the numpy
backend (no kernel compilation in fresh worker processes): about 1 s each once a worker has
imported geodem.
"""
import csv
import json
import logging
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.sweep import parse_param, plan_members

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]
TWO_BALLS = str(ROOT / "workflows" / "two_balls.yaml")
NSTEPS = "steps.oscillate.nsteps"


def sweep(*args):
    return CliRunner().invoke(app, ["sweep", TWO_BALLS, "--backend", "numpy", "--no-progress",
                                    *args])


def rows(out: Path) -> list:
    with (out / "results.csv").open() as fh:
        return list(csv.DictReader(fh))


def summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def cluster():
    """A 2-worker local cluster standing in for an external scheduler."""
    c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 dashboard_address=None, silence_logs=logging.ERROR,
                                 env={"NUMBA_NUM_THREADS": "1"})
    yield c
    c.close()


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    """A 3-member sweep on the default local cluster (2 workers). The parent process has
    NUMBA_NUM_THREADS=2: the members must still run with 1 numba thread."""
    out = tmp_path_factory.mktemp("sweep") / "three"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NUMBA_NUM_THREADS", "2")
        res = sweep("--param", f"{NSTEPS}=20,40,60", "--workers", "2", "-o", str(out))
    return out, res


def test_sweep_results(three):
    out, res = three
    assert res.exit_code == 0, res.output
    s = summary(out)
    assert (s["members"], s["completed"], s["failed"], s["skipped"]) == (3, 3, 0, 0)
    assert s["status"] == "ok" and s["scheduler"].startswith("local (2 worker")
    assert s["parameters"] == {NSTEPS: [20, 40, 60]} and s["backend"] == "numpy"
    members = json.loads((out / "members.json").read_text())
    assert sorted(members) == sorted(p.name for p in (out / "members").iterdir())
    r = rows(out)
    assert [row[NSTEPS] for row in r] == ["20", "40", "60"]
    for row in r:
        assert row["status"] == "ok" and row["skipped"] == "False"
        # the run did what its parameter says
        assert int(row["steps"]) == int(row[NSTEPS]) == int(row["planned_steps"])
        assert members[row["hash"]] == {NSTEPS: int(row[NSTEPS])}
        # keyed by the runner's config hash of the resolved workflow
        man = json.loads((out / "members" / row["hash"] / "manifest.json").read_text())
        assert man["config_hash"][:12] == row["hash"] == row["config_hash"][:12]
        assert row["numba_threads"] == "1"  # set in the worker despite the parent's 2
        assert float(row["wall_s"]) > 0
        assert float(row["results.check.samples"]) == int(row[NSTEPS]) + 1
    assert len({row["state_sha256"] for row in r}) == 3


def test_resume_skips_completed_members(three, cluster, tmp_path):
    src, res = three
    assert res.exit_code == 0, res.output
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    before = {p.name: (p / "summary.json").stat().st_mtime_ns
              for p in (out / "members").iterdir()}
    res = sweep("--param", f"{NSTEPS}=20,40,60,80", "--resume", "--scheduler",
                cluster.scheduler_address, "-o", str(out))
    assert res.exit_code == 0, res.output
    after = {p.name: (p / "summary.json").stat().st_mtime_ns
             for p in (out / "members").iterdir()}
    assert len(after) == 4
    assert {k: after[k] for k in before} == before  # the three completed ones were not rerun
    s = summary(out)
    assert (s["members"], s["completed"], s["failed"], s["skipped"]) == (4, 4, 0, 3)
    r = {row[NSTEPS]: row for row in rows(out)}
    assert [r[n]["skipped"] for n in ("20", "40", "60", "80")] == ["True"] * 3 + ["False"]
    assert r["80"]["steps"] == "80" and r["20"]["steps"] == "20"


def test_failed_member_on_an_external_scheduler(cluster, tmp_path):
    """dt = 1 s passes validation but fails the stability check when the model is built in the
    worker: counted as failed, the other member completes, exit status 1."""
    out = tmp_path / "s"
    res = sweep("--param", "simulation.dt=1e-5,1.0", "--set", f"{NSTEPS}=20",
                "--scheduler", cluster.scheduler_address, "-o", str(out))
    assert res.exit_code == 1, res.output
    s = summary(out)
    assert (s["members"], s["completed"], s["failed"]) == (2, 1, 1)
    assert s["scheduler"] == cluster.scheduler_address and s["status"] == "failed"
    (f,) = s["failures"]
    assert f["parameters"] == {"simulation.dt": 1} and "stability limit" in f["error"]
    r = {row["simulation.dt"]: row for row in rows(out)}
    assert r["1e-05"]["status"] == "ok" and r["1e-05"]["steps"] == "20"
    assert float(r["1e-05"]["dt"]) == pytest.approx(1e-5)
    assert r["1"]["status"] == "invalid" and "stability limit" in r["1"]["error"]
    assert "1 failed" in res.output


def test_resume_continues_an_interrupted_member(cluster, tmp_path):
    from geodem.workflow import run_workflow

    out = tmp_path / "s"
    (m,) = plan_members(TWO_BALLS, [parse_param(f"{NSTEPS}=60")], backend="numpy")
    code, s0 = run_workflow(TWO_BALLS, out / "members" / m.key, sets=m.sets, backend="numpy",
                            stop_after_steps=25, echo=False, progress=False)
    assert code == 0 and s0["status"] == "interrupted" and s0["steps"] == 25
    (out / "members.json").write_text(json.dumps({m.key: m.values}))
    res = sweep("--param", f"{NSTEPS}=60", "--resume", "--scheduler",
                cluster.scheduler_address, "-o", str(out))
    assert res.exit_code == 0, res.output
    (row,) = rows(out)
    assert row["status"] == "ok" and row["resumed"] == "True" and row["skipped"] == "False"
    assert row["steps"] == "60"
    log = (out / "members" / m.key / "log.txt").read_text()
    assert "resuming from checkpoint" in log
