"""geodem chooses numba's threading layer itself (geodem.threads): with a TBB runtime on the
loader's path, which numba alone would pick, a run goes on OpenMP, says so in manifest.json,
and exits. On OpenMP, geodem shortens how long idle threads spin (GOMP_SPINCOUNT) unless the
user set it, and libgomp reads that value. The TBB runtime is the PyPI ``tbb`` package of the test extra, put on the loader's
path as Debian's ``libtbb12`` would be. Integration tier: two subprocesses of a few seconds."""
import json
import os
import subprocess
import sys
from pathlib import Path

import platform

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROBE = ("import numba, numpy as np\n"
         "@numba.njit(parallel=True)\n"
         "def f(a):\n"
         "    for i in numba.prange(a.shape[0]):\n"
         "        a[i] += 1.0\n"
         "f(np.zeros(8))\n"
         "print(numba.threading_layer())\n")


def _env_with_tbb():
    if sys.platform != "linux" or platform.machine() != "x86_64":
        pytest.skip("the PyPI tbb wheels of the test extra are for Linux x86_64")
    lib = Path(sys.prefix) / "lib"
    if not list(lib.glob("libtbb.so.12*")):
        pytest.fail(f"no libtbb.so.12 in {lib}: install the test extra (pip install -e '.[test]'"
                    f", which brings the PyPI tbb package)")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    env["LD_LIBRARY_PATH"] = os.pathsep.join(filter(None, [str(lib),
                                                           env.get("LD_LIBRARY_PATH")]))
    env["NUMBA_NUM_THREADS"] = "2"
    return env


def _run(args, env, timeout=300):
    return subprocess.run(args, env=env, cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def _run_two_balls(out, env) -> dict:
    """Run workflows/two_balls.yaml into ``out``; its manifest.json."""
    res = _run([sys.executable, "-m", "geodem", "run", "workflows/two_balls.yaml", "-o",
                str(out), "--no-progress"], env)
    assert res.returncode == 0, res.stdout + res.stderr
    return json.loads((out / "manifest.json").read_text())


def test_numba_alone_would_take_the_tbb_on_the_path():
    # the premise of the next test: without geodem, this environment runs numba on TBB
    res = _run([sys.executable, "-c", PROBE], _env_with_tbb())
    assert res.returncode == 0, res.stderr
    assert res.stdout.split()[-1] == "tbb"


def test_a_run_with_tbb_present_goes_on_openmp_and_exits(tmp_path):
    out = tmp_path / "tb"
    manifest = _run_two_balls(out, _env_with_tbb())
    assert manifest["threading_layer"] == "omp"
    assert manifest["sessions"][0]["threading_layer"] == "omp"
    summary = json.loads((out / "summary.json").read_text())
    assert not summary.get("warnings")


def test_a_layer_the_user_asks_for_is_kept_and_warned_about(tmp_path):
    out = tmp_path / "tb"
    env = _env_with_tbb()
    env["NUMBA_THREADING_LAYER"] = "workqueue"
    assert _run_two_balls(out, env)["threading_layer"] == "workqueue"
    warnings = json.loads((out / "summary.json").read_text())["warnings"]
    assert any("'workqueue' threading layer" in w for w in warnings)


def test_info_names_the_layer_and_who_chose_it():
    res = _run([sys.executable, "-m", "geodem", "info", "--json"], _env_with_tbb())
    assert res.returncode == 0, res.stderr
    layer = json.loads(res.stdout)["numba_threading_layer"]
    assert layer == {"layer": "omp", "chosen_by": "geodem (omp, workqueue, tbb)",
                     "wait": {"setting": "GOMP_SPINCOUNT=1000", "chosen_by": "geodem"}}


# ---------------------------------------------------------------- how idle OpenMP threads wait
WAIT_PROBE = ("import geodem\n"
              "from geodem import threads\n"
              "import json\n"
              "print(json.dumps(threads.describe()))\n")


def _plain_env():
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("NUMBA_THREADING_LAYER", "OMP_", "GOMP_", "GEODEM_SET_"))}
    env["NUMBA_NUM_THREADS"] = "2"
    env["OMP_DISPLAY_ENV"] = "verbose"  # libgomp prints the settings it read when it loaded
    return env


def _libgomp_setting(stderr, name):
    for line in stderr.splitlines():
        if line.strip().startswith(name + " ="):
            return line.split("=", 1)[1].strip().strip("'")
    raise AssertionError(f"libgomp printed no {name}: {stderr[-2000:]}")


def test_geodem_shortens_the_openmp_spin_and_libgomp_takes_it():
    res = _run([sys.executable, "-c", WAIT_PROBE], _plain_env())
    assert res.returncode == 0, res.stderr
    described = json.loads(res.stdout.splitlines()[-1])
    assert described["layer"] == "omp"
    assert described["wait"] == {"setting": "GOMP_SPINCOUNT=1000", "chosen_by": "geodem"}
    assert _libgomp_setting(res.stderr, "GOMP_SPINCOUNT") == "1000"  # not libgomp's 300000


def test_a_wait_policy_the_user_sets_is_kept():
    env = _plain_env()
    env["OMP_WAIT_POLICY"] = "active"
    res = _run([sys.executable, "-c", WAIT_PROBE], env)
    assert res.returncode == 0, res.stderr
    described = json.loads(res.stdout.splitlines()[-1])
    assert described["wait"] == {"setting": "OMP_WAIT_POLICY=active", "chosen_by": "user"}
    assert _libgomp_setting(res.stderr, "OMP_WAIT_POLICY") == "ACTIVE"
    assert _libgomp_setting(res.stderr, "GOMP_SPINCOUNT") != "1000"


def test_a_run_records_how_threads_wait(tmp_path):
    env = _plain_env()
    env["GOMP_SPINCOUNT"] = "20000"
    manifest = _run_two_balls(tmp_path / "tb", env)
    assert manifest["omp_wait"] == {"setting": "GOMP_SPINCOUNT=20000", "chosen_by": "user"}
    assert manifest["sessions"][0]["omp_wait"] == manifest["omp_wait"]
