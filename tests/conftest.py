import os

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, fcc_lattice, lattice_shape, triangular_lattice


def pytest_configure(config):
    # pytest -n N (pytest-xdist): N workers share the machine's cores, so each steps its models
    # on its share of numba's threads (a run's numbers do not depend on the count; the tests
    # that compare thread counts set theirs), as two busy threads per core cost more than one
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    if workers > 1:
        import numba

        numba.set_num_threads(max(1, numba.config.NUMBA_NUM_THREADS // workers))
    # GEODEM_TEST_SEPARATE_MEMORY=1: every test's numba backend keeps its arrays apart from
    # the state, as the GPU does, and any unsynchronised access fails (tests/separate_memory.py)
    if os.environ.get("GEODEM_TEST_SEPARATE_MEMORY") == "1":
        import geodem.backends as backends
        from tests.separate_memory import SeparateMemory

        backends._load_all()
        backends.BACKENDS["numba"] = SeparateMemory


#: the longest test files (seconds of the CI tier, 2026-12-08, two workers): run first, so
#: that with ``--dist loadfile`` (each file whole to the next free worker, in collection order)
#: no long file starts last while the other worker has nothing left to do
LONGEST_FIRST = ("tests/integration/test_rock_structure.py", "tests/integration/test_ucs.py",
                 "tests/integration/test_one_rock.py", "tests/integration/test_separate_memory.py",
                 "tests/integration/test_scale_study.py", "tests/integration/test_thread_count.py",
                 "tests/integration/test_calibration_jobs.py", "tests/unit/test_backends.py",
                 "tests/integration/test_slope_stability.py", "tests/integration/test_pore_flow.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {f: k for k, f in enumerate(LONGEST_FIRST)}
    order = {id(it): k for k, it in enumerate(items)}
    items.sort(key=lambda it: (rank.get(it.nodeid.split("::")[0], len(rank)), order[id(it)]))


def make_specimen(n=300, dim=3, seed=1, xb=5e-4, fs0=60.0, mu=0.4, vscale=1.0):
    """A small bonded lattice with scattered element parameters and random velocities.

    Elements touch (no prestress) and the random motion breaks some bonds within a few tens of
    steps, in tension and in shear, so forces, decisions and heat books are all exercised.
    """
    d = 0.01
    rng = np.random.default_rng(seed)
    shape = lattice_shape(n, dim)
    x = fcc_lattice(*shape, d) if dim == 3 else triangular_lattice(*shape, d)
    x = x + rng.uniform(-1e-4, 1e-4, x.shape) * d
    nel = len(x)
    r = np.full(nel, 0.5 * d)
    scatter = lambda v: v * rng.uniform(0.8, 1.2, nel)  # noqa: E731
    st = bonded_state(x, r, density=2650.0, kn=scatter(1e7), ks=scatter(4e6),
                      xb=scatter(xb * d), fs0=scatter(fs0), mu=mu, gap=0.01 * d,
                      eta=1e-3)
    st.v[:] = rng.normal(0.0, vscale, st.v.shape)
    st.free[:3] = 0.0  # a few fixed elements: reactions and external work
    st.v[:3] = 0.0
    st.groups = {"all": 0, "fixed": 1}
    st.group[:3] = 1
    return st


@pytest.fixture
def specimen():
    return make_specimen


@pytest.fixture(scope="module")
def one_numba_thread():
    """Models of a few hundred elements run faster on one numba thread than on two busy ones
    (and a machine shared with other jobs makes two threads far slower). Use with
    ``pytestmark = pytest.mark.usefixtures("one_numba_thread")``."""
    import numba

    n = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(n)


def run_in_cuda_simulator(script: str, *args: str, timeout: int = 600):
    """Run ``script`` in a fresh Python with numba's CUDA simulator on (the GPU kernels on
    NumPy arrays), the repository root as ``sys.argv[1]`` and ``args`` after it; returns the
    JSON its last printed line holds."""
    import json
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", GEODEM_CUDA_SIM="1")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.run([sys.executable, "-c", script, root, *args], env=env,
                       capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def step_backends(base, backends, steps):
    """Step a copy of ``base`` ``steps`` times on each backend (no rebuilds): returns
    ``{backend: (state, crack log)}`` with the states synchronised to the host."""
    from geodem.core.engine import Simulation

    out = {}
    for be in backends:
        st = base.copy()
        sim = Simulation(st, backend=be, check_every=10**9)
        sim.run(steps)
        sim.sync()
        out[be] = (st, sim.crack_log())
    return out


@pytest.fixture(scope="session")
def step_example_run(tmp_path_factory):
    """``run(kind, backend=None) -> (exit status, summary)``: step ``kind``'s example workflow
    (tests/integration/test_workflow_steps.example_workflow) run once per session and backend
    (None: the one a plain run resolves, ``$GEODEM_BACKEND`` or auto). The contract test
    (test_workflow_steps) and the host/device test (test_separate_memory) check the same plain
    run; the column_collapse example alone takes ~45 s on 2 cores. Each caller gets its own
    copy of the summary."""
    import copy

    from geodem.backends import resolve_name
    from geodem.workflow import run_workflow

    done = {}

    def run(kind, backend=None):
        from tests.integration.test_workflow_steps import example_workflow

        name = resolve_name(backend)
        if (kind, name) not in done:
            folder = tmp_path_factory.mktemp(f"example_{kind}_{name}")
            p = example_workflow(folder, kind)
            done[kind, name] = run_workflow(p, folder / "out", backend=backend, echo=False,
                                            progress=False)
        code, summary = done[kind, name]
        return code, copy.deepcopy(summary)

    return run
