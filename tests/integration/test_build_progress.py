"""First contact with a run: the run directory is checked before the model is built (a bad -o
fails at once, exit 2), and the build tells a terminal what it is doing (geodem.build.progress),
without changing the build or anything written when the output is not a terminal."""
import json
import os
import pty
import select
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geodem.build import packing
from geodem.build import progress as build_progress
from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]
TB = str(ROOT / "workflows" / "two_balls.yaml")

pytestmark = pytest.mark.usefixtures("one_numba_thread")


@pytest.fixture
def no_build(monkeypatch):
    """Any model build fails the test: the refusals must come before it."""
    import geodem.workflow.runner as runner

    def build(cfg, doc):
        raise AssertionError("the model was built")

    monkeypatch.setattr(runner, "_build", build)


def _run(*args):
    return CliRunner().invoke(app, list(args))


@pytest.mark.parametrize("case, extra, message", [
    ("file", [], "exists and is not a folder"),
    ("under_file", [], "cannot create the folder: Not a directory"),
    ("not_empty", [], "already exists and is not empty; use --overwrite"),
    ("not_empty", ["--overwrite"], "is not a geodem run directory (no manifest.json)"),
    ("empty", ["--resume"], "nothing to resume"),
    ("manifest_only", ["--resume"], "nothing to resume: no complete checkpoint"),
    ("empty", ["--resume", "--overwrite"], "exclude each other"),
])
def test_a_bad_run_directory_fails_before_the_build(tmp_path, no_build, case, extra, message):
    out = tmp_path / "run"
    if case == "file":
        out.write_text("x")
    elif case == "under_file":
        (tmp_path / "f").write_text("x")
        out = tmp_path / "f" / "run"
    elif case in ("not_empty", "manifest_only"):
        out.mkdir()
        (out / ("manifest.json" if case == "manifest_only" else "notes.txt")).write_text("{}")
    elif case == "empty":
        out.mkdir()
    res = _run("run", TB, "-o", str(out), *extra)
    assert res.exit_code == 2, res.output
    assert message in res.output and str(out) in res.output and "(run directory)" in res.output


def test_missing_out_fails_before_the_build(no_build):
    res = _run("run", TB)
    assert res.exit_code == 2 and "-o/--out (the run directory) is required" in res.output


def test_resuming_another_workflow_fails_before_the_build(tmp_path, monkeypatch):
    out = tmp_path / "run"
    assert _run("run", TB, "-o", str(out), "--stop-after-steps", "100").exit_code == 0
    import geodem.workflow.runner as runner

    monkeypatch.setattr(runner, "_build", lambda cfg, doc: (_ for _ in ()).throw(
        AssertionError("the model was built")))
    res = _run("run", TB, "-o", str(out), "--resume", "--set", "steps.oscillate.nsteps=900")
    assert res.exit_code == 2, res.output
    assert "the workflow changed since the run" in res.output and "config hash" in res.output


def test_prepare_reports_the_build_and_its_stages(monkeypatch):
    from geodem.workflow.runner import prepare

    monkeypatch.chdir(ROOT)
    lines = []
    prep = prepare("workflows/ucs.yaml", sets=["model.size=[0.03,0.06]"], progress=lines.append)
    n = prep.built.state.n
    assert lines[0].startswith("building model specimen: ~") and lines[0].endswith(
        "elements, 2-D ...")
    assert lines[-1].startswith(f"built model specimen: {n:,} elements in ")
    assert any(line.startswith("jamming: ") for line in lines[1:-1])
    quiet = prepare("workflows/ucs.yaml", sets=["model.size=[0.03,0.06]"])
    # telling changes nothing: the same model, bit for bit
    assert np.array_equal(quiet.built.state.x, prep.built.state.x)


def _deposit(listen):
    x, r = packing.random_placement((np.zeros(2), np.array([0.1, 0.15])), n=150,
                                    d_mean=0.008, seed=1)
    st = packing.deposition_state(x, r, (np.zeros(2), np.array([0.1, 0.15])))
    lines = []
    with build_progress.listening(lines.append if listen else None):
        rep = packing.deposit(st, tol=0.05)
    return st, rep, lines


def test_deposition_reports_and_stays_the_same(monkeypatch):
    monkeypatch.setattr(build_progress, "INTERVAL_S", 0.0)
    st, rep, lines = _deposit(True)
    assert lines[0] == "deposition: 150 elements settling under gravity"
    assert any("time steps, fastest element at" in line for line in lines)  # every chunk
    assert lines[-1].startswith("deposition: balance, unbalanced-force ratio")
    st2, rep2, quiet = _deposit(False)
    assert quiet == [] and rep2["steps"] == rep["steps"]
    assert np.array_equal(st2.x, st.x) and np.array_equal(st2.v, st.v)


def test_no_listener_no_report():
    assert not build_progress.active()
    build_progress.report("nobody hears this")  # no error, nothing
    with build_progress.listening(None):
        assert not build_progress.active() and not build_progress.Every(0.0).due()
    seen = []
    with build_progress.listening(seen.append):
        assert build_progress.active()
        build_progress.report("a")
        with build_progress.listening(None):
            build_progress.report("b")
        build_progress.report("c")
    assert seen == ["a", "c"] and not build_progress.active()


def test_validate_without_a_terminal_prints_one_line():
    res = subprocess.run([sys.executable, "-m", "geodem", "validate", TB], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stderr == ""
    assert res.stdout.count("\n") == 1 and ": valid (" in res.stdout


def _on_a_terminal(args, timeout=120):
    """Run geodem with stderr on a pseudo-terminal: (exit status, stdout, terminal text)."""
    master, slave = pty.openpty()
    env = dict(os.environ, COLUMNS="200", TERM="xterm")
    p = subprocess.Popen([sys.executable, "-m", "geodem", *args], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    chunks = []
    while True:
        ready, _, _ = select.select([master], [], [], timeout)
        if not ready:
            p.kill()
            raise AssertionError("no output from the terminal")
        try:
            data = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    out = p.stdout.read().decode()
    p.wait(timeout)
    os.close(master)
    return p.returncode, out, b"".join(chunks).decode(errors="replace")


def test_validate_and_dry_run_show_the_build_on_a_terminal(tmp_path):
    code, out, term = _on_a_terminal(["validate", TB])
    assert code == 0 and ": valid (" in out
    assert "building model two_balls: ~" in term and "built model two_balls: " in term
    code, out, term = _on_a_terminal(["run", TB, "--dry-run"])
    assert code == 0 and "estimated run time" in out and "built model two_balls" in term
    code, out, term = _on_a_terminal(["advise", TB, "--no-calibrate"])
    assert code == 0 and "built model two_balls: " in term and "built model" not in out
    run = tmp_path / "run"
    code, out, term = _on_a_terminal(["run", TB, "-o", str(run), "--no-progress"])
    assert code == 0 and "building model" not in term
    s = json.loads((run / "summary.json").read_text())
    assert s["status"] == "ok" and "building model" not in (run / "log.txt").read_text()
