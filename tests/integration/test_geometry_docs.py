"""The Python examples of docs/geometry.md run as written (in order, one namespace)."""
import pathlib
import re

import pytest

pytest.importorskip("rasterio")

DOCS = pathlib.Path(__file__).resolve().parents[2] / "docs"


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")
def test_geometry_doc_examples_run(capsys):
    text = (DOCS / "geometry.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 5
    scope = {}
    for code in blocks:
        exec(compile(code, "geometry.md", "exec"), scope)
    out = capsys.readouterr().out
    assert "has no CRS" in out and "32633" in out
