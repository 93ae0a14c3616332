"""docs/workflows.md stays true: its complete workflows validate, its Python blocks run."""
import re
from pathlib import Path

import pytest

from geodem.workflow import STEPS, prepare, workflow_model

ROOT = Path(__file__).resolve().parents[2]
PAGE = (ROOT / "docs" / "workflows.md").read_text()
WORKFLOWS = [b for b in re.findall(r"```yaml\n(.*?)```", PAGE, flags=re.S) if "metadata:" in b]


def test_the_page_has_examples():
    assert len(WORKFLOWS) >= 3


@pytest.mark.parametrize("k", range(len(WORKFLOWS)))
def test_workflows_on_the_page_validate(k, tmp_path):
    text = WORKFLOWS[k]
    assert text.startswith("# yaml-language-server: $schema=../docs/geodem.schema.json")
    p = tmp_path / "wf.yaml"
    p.write_text(text)
    prep = prepare(p)
    assert prep.plan.n_elements > 0


def test_python_blocks_run(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", PAGE, flags=re.S)
    assert len(blocks) >= 3
    monkeypatch.chdir(ROOT)
    try:
        for code in blocks:
            exec(compile(code.replace("/tmp/", f"{tmp_path}/"), "workflows.md", "exec"), {})
    finally:
        STEPS.pop("kick", None)
        workflow_model.cache_clear()
    out = capsys.readouterr().out
    assert "101 samples" in out and "frames of 8 elements" in out
    assert "0 ok 50" in out
