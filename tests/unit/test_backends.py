"""All backends give the same forces and the same bond decisions on the same model."""

import numpy as np
import pytest

from geodem.backends import BackendError, available, resolve_name, select
from geodem.core.engine import Simulation
from tests.conftest import make_specimen, run_in_cuda_simulator, step_backends

FIELDS = ("x", "v", "a", "fs", "q_visc", "q_break_n", "q_break_s", "q_fric", "w_ext")


def assert_same(s1, s2, rtol=1e-12):
    assert np.array_equal(s1.cstate, s2.cstate), "bond decisions differ"
    assert np.array_equal(s1.nbr, s2.nbr)
    for k in FIELDS:
        a, b = getattr(s1, k), getattr(s2, k)
        scale = max(np.abs(a).max(), np.abs(b).max(), 1e-300)
        assert np.abs(a - b).max() <= rtol * scale, f"{k} differs"


@pytest.mark.parametrize("dim", [2, 3])
def test_numba_matches_numpy_reference(dim):
    runs = step_backends(make_specimen(n=400, dim=dim), ("numba", "numpy"), 12)
    assert_same(runs["numba"][0], runs["numpy"][0])
    log_a, log_b = runs["numba"][1], runs["numpy"][1]
    assert len(log_a) > 5, "the model must break bonds for the decision check to mean anything"
    assert set(np.unique(log_a["type"])) <= {1, 2}
    assert np.array_equal(np.sort(log_a, order=("i", "j")), np.sort(log_b, order=("i", "j")))


CUDA_SCRIPT = r"""
import json, sys, numpy as np
sys.path.insert(0, sys.argv[1])
from tests.conftest import make_specimen, step_backends
out = {}
for dim in (2, 3):
    res = step_backends(make_specimen(n=60, dim=dim, vscale=1.0), ("cupy", "numpy"), 4)
    res = {k: (st, len(log)) for k, (st, log) in res.items()}
    a, b = res["cupy"][0], res["numpy"][0]
    err = max(float(np.abs(getattr(a, k) - getattr(b, k)).max()
                    / max(np.abs(getattr(b, k)).max(), 1e-300)) for k in ("x", "v", "a", "fs"))
    out[dim] = {"err": err, "same_state": bool(np.array_equal(a.cstate, b.cstate)),
                "cracks": [res["cupy"][1], res["numpy"][1]]}
print(json.dumps(out))
"""


def test_cuda_kernels_in_simulator():
    """The GPU kernels (numba CUDA target) run in numba's CUDA simulator and match NumPy."""
    out = run_in_cuda_simulator(CUDA_SCRIPT, timeout=300)
    for dim, res in out.items():
        assert res["err"] < 1e-12, (dim, res)
        assert res["same_state"], (dim, res)
        assert res["cracks"][0] == res["cracks"][1]


CUDA_RUN_SCRIPT = r"""
import json, sys, numpy as np
sys.path.insert(0, sys.argv[1])
from geodem.core.engine import Simulation
from tests.conftest import make_specimen
runs = {}
for be in ("cupy", "numpy"):
    st = make_specimen(n=60, dim=3, seed=4)
    st.skin = 1e-4  # 1 % of the diameter: three rebuilds in 40 steps
    sim = Simulation(st, backend=be, check_every=5)
    sim.run(40)
    sim.sync()
    runs[be] = (st, sim)
(a, sa), (b, sb) = runs["cupy"], runs["numpy"]
print(json.dumps({"rebuilds": [sa.rebuilds, sb.rebuilds],
                  "cracks": [len(sa.crack_log()), len(sb.crack_log())],
                  "same": {k: bool(np.array_equal(getattr(a, k), getattr(b, k)))
                           for k in ("x", "v", "a", "fs", "cstate", "q_visc", "q_fric", "w_ext")},
                  "closure": [sa.closure_error(), sb.closure_error()]}))
"""


def test_cuda_run_with_rebuilds_in_simulator():
    """A whole ``Simulation.run`` on the GPU kernels (checks, rebuilds, crack harvest): the
    engine moves only the arrays a rebuild changes between device and host, so the run is the
    NumPy reference's bit for bit (pushing every array back after a rebuild once overwrote the
    device's accelerations and energy books with stale host copies: closure error 0.58)."""
    out = run_in_cuda_simulator(CUDA_RUN_SCRIPT, timeout=300)
    assert out["rebuilds"][0] == out["rebuilds"][1] >= 2, out
    assert out["cracks"][0] == out["cracks"][1] > 5, out
    assert all(out["same"].values()), out
    assert abs(out["closure"][0]) < 1e-3, out


CUDA_FIELDS_SCRIPT = r"""
import json, sys, numpy as np
sys.path.insert(0, sys.argv[1])
from geodem.core import groups
from geodem.core.engine import Simulation
from geodem.fields.pore import OIL_CF, OIL_KF, PoreField
from geodem.fields.thermal import ThermalField
from tests.unit.test_pore import D, _bonded_lattice
from tests.unit.test_thermal import _lattice2d
out = {}
def thermal(be):
    st = _lattice2d(8, 8, unbreakable=False)
    groups.add_group(st, "hot", st.x[:, 0] < 0.005)
    sim = Simulation(st, backend=be)
    f = ThermalField(k=3.0, c=800.0, alpha=3e-5, fixed={"hot": 700.0}, ramp=500.0,
                     deposit=["break_normal", "break_shear", "friction"], time_scale=1e5, every=3)
    sim.add_field(f)
    sim.run(60)
    sim.sync()
    return st, sim, f.T.copy()
def pore(be):
    st = _bonded_lattice(8, 6, jitter=0.15, seed=3)
    st.v[:] = np.random.default_rng(1).normal(0.0, 0.05, st.v.shape)
    sim = Simulation(st, backend=be)
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, p_init=1e5, k_t=1e-6, remesh_every=7, every=2,
                  bcs=[{"name": "inj", "where": {"ball": [0.04, 0.025, 0.012]}, "pressure": 5e5}])
    sim.add_field(f)
    sim.run(40)
    sim.sync()
    return st, sim, f.update_pressure().copy()
for name, fn in (("thermal", thermal), ("pore", pore)):
    (a, sa, fa), (b, sb, fb) = fn("cupy"), fn("numpy")
    out[name] = {"same": {k: bool(np.array_equal(getattr(a, k), getattr(b, k)))
                          for k in ("x", "v", "a", "fs", "props", "fload", "q_visc", "w_ext")},
                 "field": bool(np.array_equal(fa, fb)),
                 "closure": [sa.closure_error(), sb.closure_error()],
                 "moved": float(np.abs(fb).max())}
print(json.dumps(out))
"""


def test_cuda_coupled_fields_in_simulator():
    """The thermal field (expansion, deposition, fixed temperatures) and the pore fluid
    (injection, network updates, pressure forces) coupled to the GPU kernels: the engine moves
    each field's declared reads and writes between device and host, and the runs are the
    NumPy reference's bit for bit."""
    out = run_in_cuda_simulator(CUDA_FIELDS_SCRIPT, timeout=300)
    for name, res in out.items():
        assert all(res["same"].values()) and res["field"], (name, res)
        assert res["closure"][0] == res["closure"][1] < 1e-2, (name, res)
        assert res["moved"] > 0.0, (name, res)


def test_backend_selection(monkeypatch):
    assert "numba" in available() and "numpy" in available()
    monkeypatch.setenv("GEODEM_BACKEND", "numpy")
    assert resolve_name() == "numpy"
    assert resolve_name("numba") == "numba"
    monkeypatch.delenv("GEODEM_BACKEND")
    assert resolve_name("auto") in ("numba", "cupy")
    with pytest.raises(BackendError, match="allowed: auto, numba, numpy, cupy"):
        select("fortran")


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_both_rows_decide_alike(backend):
    """Each contact is evaluated in both rows: the two sides must agree bit for bit."""
    from geodem.core.neighbors import pairs

    st = make_specimen(n=500, dim=3, seed=5)
    sim = Simulation(st, backend=backend, check_every=10**9)
    sim.run(15)
    assert len(sim.crack_log()) > 5
    i, j, k = pairs(st)
    back = np.array([np.flatnonzero(st.nbr[b] == a)[0] for a, b in zip(i, j)])
    assert np.array_equal(st.cstate[i, k], st.cstate[j, back])
    assert np.array_equal(st.fs[i, k], -st.fs[j, back])  # exactly opposite shear springs


def test_numpy_alias_for_numba_cuda_is_added_only_where_missing():
    """numba-cuda registers an overload of ``np.row_stack`` when it compiles a kernel; NumPy 2.5
    removed that alias, so it is put back (as ``vstack``) only where it is missing."""
    import types

    from geodem.backends.kernels import _numpy_aliases_for_numba_cuda

    fake = types.SimpleNamespace(vstack=np.vstack)
    assert _numpy_aliases_for_numba_cuda(fake) is True
    assert fake.row_stack is np.vstack
    assert _numpy_aliases_for_numba_cuda(fake) is False
