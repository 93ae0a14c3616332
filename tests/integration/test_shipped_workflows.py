"""Every shipped workflow validates as shipped (schema, names, memory, model build, time step,
step counts: what a run checks before its first step) and names the committed schema for editors.
Integration tier: validating builds each model (up to ~40 s for the largest).

column_collapse_mean.yaml builds 64 packed columns (~29,000 elements, about a minute): CI checks
the file as shipped up to the build (schema, names, memory) and validates it in full, build
included, with two packings of every column (the same recipe and channel stacking; its one-packing
twin, column_collapse.yaml, validates as shipped here too). The build as shipped runs in the slow
tier, here and in tests/integration/test_column_collapse.py's validation run. The same for the
two landslides (a gravity deposition of ~3,500 elements: 50-90 s) and the two hydraulic
fracturing plates (about a minute): in CI as shipped up to the build, and built smaller."""
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app

ROOT = Path(__file__).resolve().parents[2]
#: shipped workflows whose build takes about a minute: the --set values of their CI validation
#: (the landslides at d = 6 m, ~900 elements, as tests/integration/test_landslide.py's; the
#: fracturing plates at 0.2 m with the coarse borehole their files' comments give)
SMALLER_IN_CI = {"column_collapse_mean.yaml": ["model.packings=2"],
                 "landslide.yaml": ["model.scale=0.5"],
                 "landslide_scene.yaml": ["model.d=6.0", "steps.2.n_across=20.3"],
                 "hydraulic_fracturing.yaml": ["model.size=0.2", "model.hole_radius=0.01"],
                 "hydraulic_fracturing_confined.yaml": ["model.size=0.2",
                                                        "model.hole_radius=0.01"]}


def _workflows():
    for wf in sorted((ROOT / "workflows").glob("*.yaml")):
        if wf.name in SMALLER_IN_CI:
            yield pytest.param(wf, [], id=wf.name, marks=pytest.mark.slow)
            yield pytest.param(wf, SMALLER_IN_CI[wf.name], id=f"{wf.name}-ci")
        else:
            yield pytest.param(wf, [], id=wf.name)


@pytest.mark.parametrize("wf,sets", list(_workflows()))
def test_shipped_workflows_validate_and_reference_the_schema(wf, sets):
    first = wf.read_text().splitlines()[0]
    assert first == "# yaml-language-server: $schema=../docs/geodem.schema.json"
    if sets:  # the file as shipped, up to the build: schema, names, backend, memory
        from geodem.workflow.runner import _check_memory, validated

        doc, cfg, _, _ = validated(wf)
        _check_memory(cfg, doc)
    res = CliRunner().invoke(app, ["validate", str(wf), *(a for s in sets for a in ("--set", s))])
    assert res.exit_code == 0, res.output
    assert "valid" in res.stdout
