"""Same seed, same result, on any thread count: the owner pass's slabs, and so the order of
every force sum, are fixed by the model (``geodem.backends.numba_backend.slab_count``), not by
numba's pool. Each case runs in fresh processes at NUMBA_NUM_THREADS = 1, 2, 3 and 8 (a pool
larger than the machine included; one process per thread count runs both blocks) and compares
the final states bit for bit. Integration tier:
about 45 s in all on 2 cores (the 8-thread runs wait on each other's threads)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
THREADS = (1, 2, 3, 8)

# a 3-D bench block whose bonds break, with rotation and the contact dashpot: every column of
# the posts' buffer is summed; 3,000 elements make 12 slabs
BLOCK = """
import hashlib, sys
from geodem.bench import SPACING, build_specimen
from geodem.core.engine import Simulation
from geodem.core.state import enable_contact_damping, enable_rotation
for dim in sys.argv[1:]:
    st = build_specimen(3000, dim=int(dim))
    st.xb[:] = 0.004 * SPACING
    st.fs0[:] = 2.0e-3 * st.kn * SPACING
    enable_rotation(st, mu_r=0.2)
    enable_contact_damping(st, restitution=0.5)
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.run(100)
    h = hashlib.sha256(st.x.tobytes() + st.v.tobytes() + st.fs.tobytes() + st.w.tobytes())
    print(dim, sim.backend.slabs, sim.crack_log().size, h.hexdigest())
"""


def _env(threads):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_WAIT_POLICY="PASSIVE")
    env.pop("NUMBA_THREADING_LAYER", None)
    return env


def _python(code, threads, *args):
    res = subprocess.run([sys.executable, "-c", code, *args], env=_env(threads), cwd=ROOT,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    return res.stdout.split()


@pytest.fixture(scope="module")
def block_runs():
    """``{threads: {dim: [slabs, cracks, sha256]}}``: one fresh process per thread count runs
    the 2-D and then the 3-D block (separate models, one interpreter start and kernel load)."""
    out = {}
    for t in THREADS:
        words = _python(BLOCK, t, "2", "3")
        out[t] = {int(words[k]): words[k + 1:k + 4] for k in range(0, len(words), 4)}
    return out


@pytest.mark.parametrize("dim", [2, 3])
def test_a_breaking_block_is_the_same_on_any_thread_count(dim, block_runs):
    runs = {t: block_runs[t][dim] for t in THREADS}
    slabs, cracks, _ = runs[1]
    assert int(slabs) == 12 and int(cracks) > 100  # many slabs, many broken bonds
    assert all(r == runs[1] for r in runs.values()), runs


def test_a_packed_and_broken_ucs_specimen_is_the_same_on_any_thread_count(tmp_path):
    # the packing is chaotic: before, 1 and 2 threads packed 128 and 131 elements here
    hashes = {}
    for t in THREADS:
        out = tmp_path / f"t{t}"
        res = subprocess.run(
            [sys.executable, "-m", "geodem", "run", "workflows/ucs.yaml", "-o", str(out),
             "--no-progress", "--set", "model.size=[0.04,0.08]",
             "--set", "steps.ucs.max_strain=0.006", "--set", "steps.ucs.strain_rate=1.0"],
            env=_env(t), cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stdout + res.stderr
        summary = json.loads((out / "summary.json").read_text())
        assert summary["results"]["ucs"]["cracks_tensile"] > 0
        hashes[t] = (summary["state_sha256"], summary["results"]["ucs"]["ucs"])
    assert len(set(hashes.values())) == 1, hashes
