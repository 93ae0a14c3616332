"""``geodem validate / advise / run`` of the landslide workflow without the 'geo' extra: exit 2
and one line naming the pip install (rasterio absent: ``sys.modules['rasterio'] = None`` in a
fresh interpreter, so no raster read earlier in the test session is cached)."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LINE = ("Error: landslide needs the 'geo' extra (rasterio is not installed): "
        "pip install -e '.[geo]'")


def _geodem_without(modules, *args):
    code = ("import sys\n"
            f"for m in {list(modules)!r}:\n    sys.modules[m] = None\n"
            "from geodem.cli import app\n"
            f"app({list(args)!r}, prog_name='geodem')\n")
    env = dict(os.environ, NUMBA_NUM_THREADS="1", COLUMNS="200")
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("args", [("validate",), ("advise", "--no-calibrate"),
                                  ("run", "--dry-run")])
def test_landslide_without_the_geo_extra_is_a_user_error(args):
    res = _geodem_without(["rasterio"], args[0], "workflows/landslide.yaml", *args[1:])
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == LINE  # one line, no traceback
    assert res.stdout == ""


def test_a_workflow_without_rasters_does_not_need_the_extra():
    res = _geodem_without(["rasterio", "PIL"], "validate", "workflows/two_balls.yaml")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("workflows/two_balls.yaml: valid (8 elements")
