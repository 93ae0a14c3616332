"""Output pieces of the workflow layer: the H5MD-like writer, the run directory, progress."""
import hashlib
import io
import json

import h5py
import numpy as np
import pytest
from rich.console import Console

from geodem.io.h5 import H5Writer, read_series
from geodem.workflow.errors import WorkflowError
from geodem.workflow.progress import Reporter
from geodem.workflow.rundir import RunDir, write_json
from geodem.workflow.runner import state_sha256


def test_h5_series_static_truncate_and_reopen(tmp_path):
    p = tmp_path / "out.h5"
    w = H5Writer(p, attrs={"config": "a: 1"}, creator=("geodem", "test"))
    w.series("observables/energy/kinetic", unit="J")
    w.series("particles/all/position", (3, 2), unit="m", chunk_rows=1)
    w.static("particles/all/radius", np.ones(3), unit="m")
    for step in range(0, 50, 10):
        w.append("observables/energy/kinetic", step, step * 0.1, float(step))
        w.append("particles/all/position", step, step * 0.1, np.full((3, 2), step))
    w.flush()
    with h5py.File(p, "r") as f:  # readable while the writer is open
        assert f["observables/energy/kinetic/value"].shape == (5,)
    w.close()
    w = H5Writer(p, "a")
    w.truncate(25)
    w.append("observables/energy/kinetic", 30, 3.0, -1.0)
    w.close()
    step, t, v = read_series(p, "observables/energy/kinetic")
    assert step.tolist() == [0, 10, 20, 30] and v.tolist() == [0.0, 10.0, 20.0, -1.0]
    step, _, pos = read_series(p, "particles/all/position")
    assert step.tolist() == [0, 10, 20] and pos.shape == (3, 3, 2)
    with h5py.File(p, "r") as f:
        assert tuple(f["h5md"].attrs["version"]) == (1, 1)
        assert f["h5md/creator"].attrs["name"] == "geodem"
        assert f["observables/energy/kinetic/value"].attrs["unit"] == "J"
        assert f["observables/energy/kinetic/time"].attrs["unit"] == "s"
        assert f.attrs["config"] == "a: 1"


def test_state_sha256_is_positions_then_velocities():
    class S:
        x = np.arange(6.0).reshape(3, 2)
        v = np.asfortranarray(np.ones((3, 2)))  # any layout: hashed as contiguous float64

    ref = hashlib.sha256(S.x.tobytes() + np.ones((3, 2)).tobytes()).hexdigest()
    assert state_sha256(S) == ref


def test_run_directory_rules(tmp_path):
    d = RunDir(tmp_path / "run")
    d.prepare(overwrite=False, resume=False)
    (d / "manifest.json").write_text("{}")
    with pytest.raises(WorkflowError, match="already exists and is not empty"):
        d.prepare(overwrite=False, resume=False)
    with pytest.raises(WorkflowError, match="nothing to resume"):
        d.prepare(overwrite=False, resume=True)
    # --overwrite deletes what the run wrote (the fixed files, those summary.json and the
    # checkpoint markers list), and keeps the user's own files, naming them
    (d / "summary.json").write_text('{"files": ["plot.png", "frames/f0.npz", "../up.txt"]}')
    (d / "plot.png").write_text("x")
    (d / "frames").mkdir()
    (d / "frames" / "f0.npz").write_text("x")
    (d / "checkpoints").mkdir()
    (d / "checkpoints" / "step_000000000010.json").write_text('{"files": ["late.csv"]}')
    (d / "late.csv").write_text("x")
    (d / "notes.txt").write_text("mine")
    d.prepare(overwrite=True, resume=False)
    assert sorted(p.name for p in d.path.iterdir()) == ["notes.txt"]
    assert d.kept == ["notes.txt"] and (d / "notes.txt").read_text() == "mine"
    f = tmp_path / "afile"
    f.write_text("x")
    with pytest.raises(WorkflowError, match="not a folder"):
        RunDir(f).prepare(False, False)
    with pytest.raises(WorkflowError, match="cannot create the folder: Not a directory"):
        RunDir(f / "sub").prepare(False, False)


def test_summary_json_is_strict(tmp_path):
    write_json(tmp_path / "s.json", {"a": float("nan"), "b": [1.0, float("inf")],
                                     "c": np.float64(2.5), "d": np.arange(2)})
    text = (tmp_path / "s.json").read_text()
    assert "NaN" not in text and json.loads(text) == {"a": None, "b": [1.0, None], "c": 2.5,
                                                      "d": [0, 1]}


def test_progress_bar_on_a_terminal(tmp_path):
    buf = io.StringIO()
    con = Console(file=buf, force_terminal=True, width=160)
    rep = Reporter(tmp_path / "log.txt", total_steps=1000, n_elements=10, bar=True,
                   console=con, log_every_s=0.0)
    rep.start(0)
    rep.start_step(0, 2, "load", "run", 1000)
    rep.update(400, ke=1.25e-3, broken=7, rate=2.5e4)
    rep.close()
    out = buf.getvalue()
    for words in ("1/2 load", "400/1000", "2.5e+04 steps/s", "KE 1.250e-03 J", "broken 7",
                  "ETA"):
        assert words in out, words
    log = (tmp_path / "log.txt").read_text()
    assert "step 1/2 load (run): 1000 time steps" in log
    assert "400/1000 time steps (40 %)" in log and "broken bonds 7" in log


def test_progress_lines_without_a_terminal(tmp_path):
    buf = io.StringIO()
    con = Console(file=buf, force_terminal=False, width=200)
    rep = Reporter(None, total_steps=100, n_elements=4, bar=False, console=con, log_every_s=0.0)
    rep.start(0)
    rep.start_step(0, 1, "run", "run", 100)
    rep.update(50, ke=2.0, broken=0, rate=100.0)
    rep.close()
    out = buf.getvalue()
    assert "50/100 time steps (50 %), 100 steps/s, 400 element-steps/s, ETA 0:00:00" in out
    assert "\x1b[" not in out  # plain lines


def test_vtk_writer_round_trip(tmp_path):
    """The .vtp files are VTK XML written directly: read them back and check every array."""
    from geodem.io.vtk import VtkWriter, read_vtp

    class St:
        x = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.8]])
        v = np.array([[1.0, 2.0], [0.0, 0.0], [-1.0, 0.5]])
        r = np.array([0.5, 0.5, 0.4])
        group = np.array([0, 1, 1], np.int32)
        cstate = np.array([[1, 1], [1, 0], [1, 0]], np.int32)
        time = 0.0

    w = VtkWriter(tmp_path / "vtk")
    w.write(St, 0)
    St.time = 0.5
    w.write(St, 10, reference=St.x - 0.1)
    files = sorted(p.name for p in (tmp_path / "vtk").iterdir())
    assert files == ["frame_000000000000.vtp", "frame_000000000010.vtp", "frames.pvd"]
    pvd = (tmp_path / "vtk" / "frames.pvd").read_text()
    assert pvd.count("<DataSet") == 2 and 'timestep="0.5"' in pvd
    got = read_vtp(tmp_path / "vtk" / "frame_000000000010.vtp")
    assert got["Points"].shape == (3, 3) and np.all(got["Points"][:, 2] == 0)  # 2-D: z = 0
    assert np.array_equal(got["Points"][:, :2], St.x)
    assert np.array_equal(got["velocity"][:, :2], St.v)
    assert np.allclose(got["displacement"][:, :2], 0.1)
    assert np.array_equal(got["radius"], St.r)
    assert np.array_equal(got["group"], [0, 1, 1]) and np.array_equal(got["bonds"], [2, 1, 1])
    assert np.array_equal(got["offsets"], [1, 2, 3])
    again = VtkWriter(tmp_path / "vtk")  # a resumed run keeps the listed frames
    assert len(again.frames) == 2




@pytest.mark.parametrize("write_s, interval", [(0.0, 2.0), (0.05, 5.0), (0.5, 30.0)])
def test_output_writes_take_a_bounded_share_of_the_run(monkeypatch, write_s, interval):
    """The next write of output.h5 waits max(FLUSH_SECONDS, its time / FLUSH_SHARE), at most
    FLUSH_MAX_SECONDS: 2 s after an instant write, 5 s after one of 50 ms, 30 s after 0.5 s."""
    from types import SimpleNamespace

    from geodem.workflow import runner as rn

    clock = [100.0]
    monkeypatch.setattr(rn.time, "perf_counter", lambda: clock[0])
    h5 = SimpleNamespace(flush=lambda: clock.__setitem__(0, clock[0] + write_s))
    fake = SimpleNamespace(h5=h5, _last_flush=0.0, _flush_interval=rn.FLUSH_SECONDS)
    rn.Runner._flush_output(fake, 100.0)
    assert fake._last_flush == pytest.approx(100.0 + write_s)
    assert fake._flush_interval == pytest.approx(interval)


def test_series_written_in_several_flushes_keep_every_sample(tmp_path):
    """The writer keeps each series' datasets open between writes: samples appended over
    three writes read back in order, none lost or repeated."""
    w = H5Writer(tmp_path / "o.h5")
    w.series("observables/a", shape=(2,))
    for k in range(6):
        w.append("observables/a", 10 * k, 0.1 * k, [k, -k])
        if k % 2:
            w.flush()
    w.close()
    step, time_, value = read_series(tmp_path / "o.h5", "observables/a")
    assert list(step) == [0, 10, 20, 30, 40, 50]
    assert np.allclose(time_, [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    assert value[:, 0].tolist() == [0, 1, 2, 3, 4, 5]
    assert value[:, 1].tolist() == [0, -1, -2, -3, -4, -5]
