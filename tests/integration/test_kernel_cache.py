"""The CPU step kernels are cached on disk (geodem.backends.kernels): a second process loads
them instead of compiling, with bit-identical results; a stale generated module is rewritten;
an unwritable cache folder falls back to compiling in memory."""
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# steps a small 2-D specimen; prints the force kernel's cache statistics and a checksum
SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from tests.conftest import make_specimen
from geodem.core.engine import Simulation
st = make_specimen(n=200, dim=2)
st.gravity[1] = -9.81
Simulation(st, backend="numba", check_every=10**9, monitor_every=0).run(20)
print(json.dumps({"x": st.x.tolist()}))
"""
FORCE = "geodem_step_2d_rot0_damp0.cpu_force_owner"  # the pass a plain model runs


def _run(cache_dir):
    """Run SCRIPT; returns its JSON plus ``saved`` / ``loaded``: whether numba's cache debug
    output (NUMBA_DEBUG_CACHE) shows the force kernel written to or read from the disk."""
    env = dict(os.environ, GEODEM_CACHE_DIR=str(cache_dir), NUMBA_NUM_THREADS="1",
               NUMBA_DEBUG_CACHE="1")
    p = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT)], env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.strip().splitlines()
    out = json.loads(lines[-1])
    out["saved"] = any("data saved" in ln and FORCE in ln for ln in lines)
    out["loaded"] = any("data loaded" in ln and FORCE in ln for ln in lines)
    return out


def test_second_process_loads_the_cached_kernels(tmp_path):
    first = _run(tmp_path)
    assert first["saved"] and not first["loaded"]
    module = tmp_path / "kernels" / "geodem_step_2d_rot0_damp0.py"
    assert module.exists()
    assert list((tmp_path / "kernels" / "__pycache__").glob(FORCE + "-*.nbi"))
    second = _run(tmp_path)
    assert second["loaded"] and not second["saved"]
    assert second["x"] == first["x"]  # bit-identical

    # a module that no longer matches the law and the bodies is rewritten; numba keys its
    # cache on the module's content, so a changed law recompiles and this one loads again
    module.write_text("# out of date\n")
    third = _run(tmp_path)
    from geodem.backends.kernels import cpu_source

    assert module.read_text() == cpu_source(2, False, False)
    assert third["loaded"] and third["x"] == first["x"]


def test_unwritable_cache_folder_compiles_in_memory(tmp_path):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")  # the cache folder would have to be created inside a file
    out = _run(blocker)
    assert not out["saved"] and not out["loaded"] and len(out["x"]) > 0
