"""The coupled-field framework: sub-stepping, coupling interval, checkpoints, the contract."""
import math

import numpy as np
import pytest

from geodem.core.engine import Simulation
from geodem.core.state import new_state
from geodem.fields import (FIELDS, CoupledField, FieldStabilityError, load_builtin,
                           register_field)


@register_field("_test_decay")
class Decay(CoupledField):
    """dq/dt = -k q per element, explicit Euler (stable for h < 2/k): a field with a known answer."""

    reads = {}
    writes = {}

    def __init__(self, k=1.0, every=1):
        super().__init__(every)
        self.k = float(k)

    def attach(self, sim):
        self.q = np.ones(sim.state.n)

    def stable_dt(self, sim):
        return 2.0 / self.k

    def substep(self, sim, h):
        self.q *= 1.0 - self.k * h

    def config(self):
        return {"k": self.k, "every": self.every}

    def arrays(self):
        return {"q": self.q}

    def restore(self, arrays):
        self.q[:] = arrays["q"]


def _sim():
    st = new_state(np.array([[0.0, 0.0], [1.0, 0.0]]), r=0.4, m=1.0, kn=1.0)
    return Simulation(st, backend="numpy", dt=1e-3)


def test_substeps_cover_the_mechanical_span_on_the_stable_step():
    sim = _sim()
    f = Decay(k=4000.0, every=5)  # safety 0.5 x 2/k = 2.5e-4 s; span 5e-3 s -> 20 sub-steps
    sim.add_field(f)
    sim.run(10)
    assert f.substeps == 2 * 20
    h = 5e-3 / 20
    assert f.q[0] == pytest.approx((1 - 4000.0 * h) ** 40, rel=1e-12)


def test_a_field_needing_too_many_substeps_stops_loudly():
    sim = _sim()
    sim.add_field(Decay(k=1e12))
    with pytest.raises(FieldStabilityError, match="sub-steps per coupling"):
        sim.run(1)


def test_every_must_be_positive():
    with pytest.raises(ValueError, match="every"):
        Decay(every=0)


@pytest.mark.parametrize("every", [1.5, float("nan"), True, "2"])
def test_every_must_be_a_whole_number(every):
    # 1.5 was truncated to 1, NaN gave "cannot convert float NaN to integer"
    with pytest.raises(ValueError, match=r"'_test_decay': every = .*allowed: a whole number >= 1"):
        Decay(every=every)
    assert Decay(every=np.int64(3)).every == 3 and Decay(every=4.0).every == 4


def test_checkpoint_restores_the_field_bit_identically(tmp_path):
    a = _sim()
    a.add_field(Decay(k=50.0, every=2))
    a.run(6)
    a.save(tmp_path / "c.npz")
    b = Simulation.load(tmp_path / "c.npz", backend="numpy")
    a.run(8)
    b.run(8)
    fa, fb = a.field("_test_decay"), b.field("_test_decay")
    assert fb.every == 2 and fb.k == 50.0
    assert np.array_equal(fa.q, fb.q)
    assert fa.substeps == fb.substeps
    with pytest.raises(KeyError, match="no coupled field"):
        a.field("nothing")


def test_every_registered_field_declares_its_contract():
    load_builtin()
    for kind, cls in FIELDS.items():
        assert issubclass(cls, CoupledField)
        assert cls.kind == kind
        for name, unit in {**cls.reads, **cls.writes}.items():
            assert isinstance(unit, str) and unit, f"{kind}: {name} has no unit"
        assert 0.0 < cls.safety <= 1.0
        for meth in ("attach", "stable_dt", "substep"):
            assert getattr(cls, meth) is not getattr(CoupledField, meth), \
                f"{kind} does not implement {meth}"
    assert math.isfinite(Decay().stable_dt(None))
