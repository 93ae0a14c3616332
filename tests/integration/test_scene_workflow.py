"""The shipped scene workflow (workflows/scene_layers.yaml) runs end to end through the CLI:
2,023 elements (17 rows of 60 and 17 of 59, counted by hand in docs/scene.md), energy closed,
the jointed layers cracking under the platen. Integration tier: a few seconds."""
import json
from pathlib import Path

from typer.testing import CliRunner

from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]


def test_the_layered_scene_runs_and_closes_its_energy(tmp_path):
    out = tmp_path / "scene"
    res = CliRunner().invoke(app, ["run", str(ROOT / "workflows" / "scene_layers.yaml"), "-o",
                                   str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["n_elements"] == 17 * 60 + 17 * 59
    assert s["energy_closure_rel_error"] < 1e-4
    assert s["bonds_broken"] > 0
