"""Freezing elements at rest (geodem.fields.freeze): a pile of grains at rest on a fixed base,
a ball dropped on its left end. The far field falls asleep and is skipped; the grains the ball
hits wake up; the books stay closed and the answer matches the run without freezing."""
import os

import numpy as np
import pytest

from geodem.core.engine import Simulation
from geodem.fields.freeze import FreezeField
from geodem.studies.freeze_study import D, settled
from tests.conftest import run_in_cuda_simulator

pytestmark = pytest.mark.usefixtures("one_numba_thread")



def field():
    return FreezeField(v_sleep=1e-3, a_wake=0.5, every=10)


@pytest.fixture(scope="module")
def pair():
    ref = settled()
    ref.run(6000)
    frz = settled()
    f = field()
    frz.add_field(f)
    frz.run(6000)
    return ref, frz, f


def test_far_field_sleeps_and_is_skipped(pair):
    _, frz, f = pair
    s = f.summary()
    assert s["fell_asleep"] > 0.5 * frz.state.n
    assert s["skipped_fraction"] > 0.5  # most element-steps were skipped
    assert s["woke"] > 0  # the ball's impact woke grains


def test_books_stay_closed_and_the_answer_matches(pair):
    ref, frz, _ = pair
    assert frz.closure_error() < 1e-4
    ball = frz.state.n - 1
    # the ball lands where it lands without freezing (to 1e-3 of a grain)
    assert np.abs(frz.state.x[ball] - ref.state.x[ball]).max() < 1e-3 * D
    # every grain within 1e-2 of a grain of the reference (sleepers stop at v < v_sleep)
    assert np.abs(frz.state.x - ref.state.x).max() < 1e-2 * D


def test_a_sleeper_pushed_wakes_up():
    sim = settled()
    f = field()
    sim.add_field(f)
    sim.run(3000)
    st = sim.state
    asleep = np.flatnonzero(f.asleep)
    assert asleep.size > 0
    k = asleep[np.argmax(st.x[asleep, 0])]  # a sleeper at the right end of the pile
    sim.change(lambda z: z.fload.__setitem__(k, [0.0, 50.0 * z.m[k] * 9.81]))
    sim.run(20)
    assert not f.asleep[k]
    assert st.free[k].all() and st.v[k, 1] > 0.0


def test_checkpoint_continues_bit_identically(tmp_path):
    a = settled()
    a.add_field(field())
    a.run(2000)
    a.save(tmp_path / "c.npz")
    b = Simulation.load(tmp_path / "c.npz", backend="numba")
    a.run(1000)
    b.run(1000)
    assert np.array_equal(a.state.x, b.state.x) and np.array_equal(a.state.v, b.state.v)
    assert np.array_equal(a.field("freeze").asleep, b.field("freeze").asleep)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="v_sleep"):
        FreezeField(v_sleep=0.0, a_wake=1.0)
    with pytest.raises(ValueError, match="a_sleep"):
        FreezeField(v_sleep=1e-3, a_wake=1.0, a_sleep=2.0)


CUDA_SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[2])
import numpy as np
from geodem.core.engine import Simulation
from geodem.studies.freeze_study import pile
out = {}
for backend in ("cupy", "numba"):
    st = pile(nx=12, ny=4)
    right = st.x[:, 0] > 6e-2
    st.free[right] = 0.0  # the right part asleep (fixed, at rest)
    sim = Simulation(st, backend=backend)
    sim.backend.set_active(np.flatnonzero(~right | (st.x[:, 0] < 8e-2)))
    sim.run(30)
    st = sim.sync()
    out[backend] = {"x": st.x.tolist(), "a": st.a.tolist()}
err = float(np.abs(np.array(out["cupy"]["x"]) - np.array(out["numba"]["x"])).max())
a_c, a_n = np.array(out["cupy"]["a"]), np.array(out["numba"]["a"])
print(json.dumps({"err": err, "a_err": float(np.abs(a_c - a_n).max() / np.abs(a_n).max())}))
"""


def test_gpu_kernels_step_the_same_subset_in_the_simulator():
    """The CUDA kernels' index-list variants (numba's CUDA simulator) step the same elements
    as the CPU ones: same positions and forces after 30 steps."""
    here = os.path.dirname(os.path.abspath(__file__))
    out = run_in_cuda_simulator(CUDA_SCRIPT, here)
    assert out["err"] < 1e-12 * D
    assert out["a_err"] < 1e-8  # net forces near equilibrium: sums of cancelling terms
