"""Every shipped workflow validates as shipped (schema, names, memory, model build, time step,
step counts: what a run checks before its first step) and names the committed schema for editors.
Integration tier: validating builds each model (up to ~40 s for the largest)."""
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("wf", sorted((ROOT / "workflows").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_workflows_validate_and_reference_the_schema(wf):
    first = wf.read_text().splitlines()[0]
    assert first == "# yaml-language-server: $schema=../docs/geodem.schema.json"
    res = CliRunner().invoke(app, ["validate", str(wf)])
    assert res.exit_code == 0, res.output
    assert "valid" in res.stdout
