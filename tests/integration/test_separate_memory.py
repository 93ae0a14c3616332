"""Host and device in step: every step kind's example, run with the numba kernels on arrays
kept apart from the state as the GPU backend keeps them (tests/separate_memory.py), is the
plain numba run bit for bit, and no code reads or writes a state array behind the backend's
``pull`` / ``push``. The CPU backends share their arrays with the state, so only this (or a
GPU) shows such a slip: before the host/device fix the cupy backend ended ``Simulation.run`` without
bringing the state back, and the packing of every specimen read stale velocities."""
import pytest

import geodem.backends as backends
from geodem.workflow import STEPS, run_workflow
from tests.integration.test_workflow_steps import example_workflow
from tests.separate_memory import SeparateMemory

backends._load_all()
# the examples' models have tens to a few hundred elements (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_numba_thread")


@pytest.mark.parametrize("kind", list(STEPS))
def test_step_kind_keeps_host_and_device_in_step(kind, tmp_path, monkeypatch,
                                                 step_example_run):
    # the plain numba run is the one test_workflow_steps checks (run once per session)
    code, plain = step_example_run(kind, "numba")
    assert code == 0, plain.get("error")
    monkeypatch.setenv("GEODEM_BACKEND", "numba")
    p = example_workflow(tmp_path, kind)
    monkeypatch.setitem(backends.BACKENDS, "numba", SeparateMemory)
    code, apart = run_workflow(p, tmp_path / "apart", echo=False, progress=False)
    assert code == 0, apart.get("error")
    assert apart["state_sha256"] == plain["state_sha256"]
    assert apart["energy_closure_rel_error"] == plain["energy_closure_rel_error"]


def test_speed_accuracy_study_keeps_host_and_device_in_step(tmp_path, monkeypatch):
    """The study's cases step the engine themselves and read (TwoBalls) or drive (the chain's
    first element) the state from a callback every step."""
    import csv

    from typer.testing import CliRunner

    from geodem.cli import app

    def errors(out):
        res = CliRunner().invoke(app, ["study", "speed-accuracy", "--quick", "--backend",
                                       "numba", "--cases", "two_balls,wave-speed", "-o",
                                       str(out)])
        assert res.exit_code == 0, res.output
        with open(out / "speed_accuracy.csv") as fh:
            rows = list(csv.DictReader(fh))
        assert all(r["status"] == "ok" for r in rows), [r["status"] for r in rows]
        return [(r["case"], r["dt_fraction"], r["resolution"], r["error"]) for r in rows]

    plain = errors(tmp_path / "shared")
    monkeypatch.setitem(backends.BACKENDS, "numba", SeparateMemory)
    assert errors(tmp_path / "apart") == plain
