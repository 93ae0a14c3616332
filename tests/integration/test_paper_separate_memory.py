"""The paper's workflows (workflows/paper/) at reduced size on arrays kept apart from the state,
as the GPU backend keeps them (tests/separate_memory.py): the first steps of each are the plain
numba run bit for bit, builds included (the terrain's settling, the cutter's block, the
plate's pore field), so the device path of every paper case is exercised without a GPU."""
from pathlib import Path

import pytest

import geodem.backends as backends
from geodem.workflow import run_workflow
from tests.separate_memory import SeparateMemory

backends._load_all()
ROOT = Path(__file__).resolve().parents[2] / "workflows" / "paper"
pytestmark = pytest.mark.usefixtures("one_numba_thread")

# the reduced sizes of tests/integration/test_paper_workflows.py
SMALL = {
    "hydraulic_fracturing.yaml": ["model.coarsen=null", "model.size=0.1",
                                  "model.hole_radius=0.0075", "steps.injection.gif=false"],
    "landslide_3d.yaml": ["model.d=20", "model.domain.terrain.base_depth=25",
                          "steps.settle.n_across=20", "steps.runout.gif=false"],
    "seismic_valley.yaml": ["model.d=10.0", "steps.seismic.frames=2",
                            "steps.seismic.vtk_frames=0", "steps.valley.gif=false"],
    "tbm_cutter_3d.yaml": ["model.d_mean=0.005", "model.size=[0.1,0.03,0.04]",
                           "steps.cut.distance=0.005",
                           "steps.cut.gif_frames=2", "steps.cut.frames=1"],
}


def test_every_paper_workflow_is_listed():
    assert sorted(p.name for p in ROOT.glob("*.yaml")) == sorted(SMALL)


@pytest.mark.parametrize("name", sorted(SMALL))
def test_paper_workflow_keeps_host_and_device_in_step(name, tmp_path, monkeypatch):
    monkeypatch.setenv("GEODEM_BACKEND", "numba")

    def first_steps(out):
        code, s = run_workflow(ROOT / name, out, sets=SMALL[name], echo=False, progress=False,
                               stop_after_steps=400)
        assert code == 0 and s["status"] in ("ok", "interrupted"), s.get("error")
        return s

    plain = first_steps(tmp_path / "plain")
    monkeypatch.setitem(backends.BACKENDS, "numba", SeparateMemory)
    apart = first_steps(tmp_path / "apart")
    assert apart["steps"] == plain["steps"] > 0
    assert apart["state_sha256"] == plain["state_sha256"]
