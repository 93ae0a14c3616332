"""The Python examples in docs/ run as written."""
import pathlib
import re

import pytest

DOCS = pathlib.Path(__file__).resolve().parents[2] / "docs"


@pytest.mark.parametrize("page", ["engine.md"])
def test_doc_examples_run(page, tmp_path, monkeypatch, capsys):
    text = (DOCS / page).read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks
    monkeypatch.chdir(tmp_path)
    scope = {}
    for code in blocks:
        exec(compile(code.replace("/tmp/", f"{tmp_path}/"), f"{page}", "exec"), scope)
    out = capsys.readouterr().out
    assert "closure error" in out
