"""Steps ``excavate`` and ``weaken`` (geodem.workflow.excavation) and the engine's
``Simulation.remove_elements``, on a tiny lattice scene counted by hand.

The scene: d = 0.02 m in a 0.2 x 0.1 m box: rows every d sqrt(3)/2 from y = 0.01, floor(0.08 /
0.01732) + 1 = 5 rows; even rows 10 elements (x = 0.01 ... 0.19), odd rows 9 (x = 0.02 ... 0.18):
48 elements; 3 x 9 + 2 x 8 bonds along the rows and 4 x 18 between them: 115 bonds."""
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.core import groups
from geodem.core.engine import Simulation
from geodem.core.state import BONDED
from geodem.workflow.errors import WorkflowError
from geodem.workflow.schema import validate_document
from geodem.workflow.yamlio import load_document

ROCK = {"rho": 2650, "kn": 2.0e7, "ks": 6.0e6, "xb": 2.0e-6, "fs0": 20.0, "mu": 0.4}
D = 0.02
ROW = D * math.sqrt(3.0) / 2.0
CENTRE = (0.10, 0.01 + ROW)  # an element of row 1 (odd: x = 0.02 + 0.02 k)


def _cfg(steps=None, **model):
    doc = {"metadata": {"name": "exc"},
           "model": dict({"type": "scene", "dim": 2, "d": D, "material": "rock", "sort": False,
                          "domain": {"box": {"min": [0.0, 0.0], "max": [0.2, 0.1]}},
                          "groups": {"base": {"side": "ymin"},
                                     "plug": {"box": {"min": [0.09, 0.02],
                                                      "max": [0.11, 0.035]}}}}, **model),
           "materials": {"rock": ROCK},
           "steps": steps or [{"kind": "run", "nsteps": 1}]}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "exc.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return validate_document(load_document(path))


def _sim(gravity=False, steps=0):
    cfg = _cfg(**({"gravity": [0.0, -9.81]} if gravity else {}))
    st = cfg.model.build(cfg).state
    sim = Simulation(st, backend="numpy")
    if gravity:
        sim.change(lambda s: groups.fix(s, "base"))
    if steps:
        sim.run(steps)
    return sim


class Ctx:
    """What the two steps use of geodem.workflow.runner.StepContext, on a bare Simulation."""

    def __init__(self, sim):
        self.sim, self.resumed, self.summary = sim, False, {}
        self.runner = type("R", (), {"results": {}})()
        self.start = sim.state.step

    @property
    def state(self):
        return self.sim.sync()

    def log(self, msg):
        pass

    def remove_elements(self, mask):
        return self.sim.remove_elements(mask)

    def advance(self, n):
        self.sim.run(self.start + n - self.sim.state.step)


def _step(kind, **kw):
    from geodem.workflow.schema import STEPS

    return STEPS[kind].model_validate({"kind": kind, "name": kind, **kw})


def _bonds(st):
    i = np.repeat(np.arange(st.n), st.nbr.shape[1]).reshape(st.nbr.shape)
    ok = (st.nbr >= 0) & (st.cstate == BONDED)
    return i[ok], st.nbr[ok]


def test_the_tiny_scene_is_the_lattice_counted_by_hand():
    st = _sim().state
    assert st.n == 3 * 10 + 2 * 9 == 48
    # bonds: 9 along each even row, 8 along each odd row, 2 x 9 between each pair of rows
    assert len(_bonds(st)[0]) // 2 == 3 * 9 + 2 * 8 + 4 * 18 == 115
    assert groups.members(st, "base").size == 10 and groups.members(st, "plug").size == 1


def test_a_disc_is_excavated_in_two_stages_counted_by_hand():
    sim = _sim()
    ctx = Ctx(sim)
    # the element at CENTRE and its 6 neighbours at d: 7 (the next ring is at sqrt(3) d)
    step = _step("excavate", shape={"disc": {"center": list(CENTRE), "radius": 0.021}},
                 stages=2, nsteps_per_stage=3)
    res = step.execute(ctx)
    # outward: keys 0 (the centre) and d (6); bands [0, d/2], (d/2, d]
    assert res["removed_per_stage"] == [1, 6] and res["n_removed"] == 7
    assert res["n_elements_left"] == sim.state.n == 41
    assert res["steps_at_stage"] == [0, 3] and sim.state.step == 6
    st = sim.state
    assert not (np.hypot(st.x[:, 0] - CENTRE[0], st.x[:, 1] - CENTRE[1]) < 0.021).any()
    # groups: the base row lost its two elements under the hole, the plug (the centre) is empty
    assert groups.members(st, "base").size == 8
    assert groups.members(st, "plug").size == 0 and res["empty_groups"] == ["plug"]
    assert any("plug" in w for w in ctx.summary["warnings"])
    # ids: the built model's numbering of the elements left; the rows point inside the model
    assert sim.ids.size == 41 and np.all(np.diff(sim.ids) > 0)
    assert st.nbr.max() < 41
    # bonds left: 115 less the hexagon's 6 spokes and 6 rim bonds and the rim's bonds outward,
    # 3 per rim element but 1 for the two in the base row (nothing below): 6 + 6 + 14 = 26
    assert len(_bonds(st)[0]) // 2 == 115 - 26


def test_a_group_is_excavated_along_an_axis():
    sim = _sim()
    step = _step("excavate", group="base", stages=2, order="-x")
    res = step.execute(Ctx(sim))
    # base row x = 0.01 ... 0.19, highest first: keys -0.19 ... -0.01, edge -0.1: 5 then 5
    assert res["removed_per_stage"] == [5, 5] and sim.state.n == 38
    assert res["empty_groups"] == ["base"]


def test_removal_books_what_leaves_and_keeps_the_books_closed():
    from geodem.core.law import contact_energy

    sim = _sim(gravity=True, steps=200)
    st = sim.state
    x, r, kn, ks, fs = st.x.copy(), st.r.copy(), st.kn.copy(), st.ks.copy(), st.fs.copy()
    gone = np.hypot(x[:, 0] - CENTRE[0], x[:, 1] - CENTRE[1]) < 0.021
    ke = 0.5 * (st.m[:, None] * st.v ** 2 * st.free)[gone].sum()
    eg = (st.m * 9.81 * x[:, 1] * (st.free[:, 1] != 0))[gone].sum()
    el = 0.0  # the contacts of a removed element, each once, with the law's energy
    for i in range(st.n):
        for k, j in enumerate(st.nbr[i]):
            if j > i and (gone[i] or gone[j]):
                d = x[j] - x[i]
                el += contact_energy(d[0], d[1], 0.0, fs[i, k, 0], fs[i, k, 1], 0.0, r[i], r[j],
                                     kn[i], kn[j], ks[i], ks[j], st.cstate[i, k], False)
    e0 = sim.energies()
    out = sim.remove_elements(gone)
    e1 = sim.energies()
    assert out["n_removed"] == 7 and sim.state.n == 41
    assert out["kinetic"] == pytest.approx(ke, rel=1e-12, abs=1e-30)
    assert out["gravity"] == pytest.approx(eg, rel=1e-12) and eg > 0
    assert out["elastic"] == pytest.approx(el, rel=1e-9) and el > 0
    assert e1["removed"] == pytest.approx(ke + eg + el, rel=1e-12)
    # what stays is what it was: totals of heat and work, the residual of the balance
    assert e1["total"] == pytest.approx(e0["total"], rel=1e-13)
    assert e1["closure_residual"] == pytest.approx(e0["closure_residual"], abs=1e-12 * eg)
    assert e1["gravity"] == pytest.approx(e0["gravity"] - eg, rel=1e-12)
    sim.run(300)
    e2 = sim.energies()
    assert e2["closure_error"] < 1e-3 and e2["removed"] == e1["removed"]


def test_a_checkpoint_after_a_removal_resumes_bit_identically(tmp_path):
    sim = _sim(gravity=True, steps=50)
    gone = np.hypot(sim.state.x[:, 0] - CENTRE[0], sim.state.x[:, 1] - CENTRE[1]) < 0.021
    sim.remove_elements(gone)
    sim.run(20)
    sim.save(tmp_path / "ck.npz")
    back = Simulation.load(tmp_path / "ck.npz", backend="numpy")
    assert np.array_equal(back.ids, sim.ids) and back.gone == sim.gone
    sim.run(40)
    back.run(40)
    assert np.array_equal(back.state.x, sim.state.x) and np.array_equal(back.state.v, sim.state.v)
    assert back.energies()["closure_error"] == sim.energies()["closure_error"]


def test_weaken_a_group_scales_exactly_the_bonds_touching_it():
    sim = _sim()
    st = sim.state
    res = _step("weaken", group="base", factor=0.7).execute(Ctx(sim))
    i, j = _bonds(st)
    base = st.group_mask("base")
    touch = base[i] | base[j]
    # 9 bonds along the base row, 18 up to row 1
    assert res["bonds_weakened"] == int(touch.sum()) // 2 == 27
    ok = (st.nbr >= 0) & (st.cstate == BONDED)
    br = st.brate[ok]
    assert np.all(br[touch] == np.float32(0.7)) and np.all(br[~touch] == 1.0)
    assert np.all(st.brate[~ok] == 1.0)
    assert res["bonds_broken"] == 0 and res["bonds_left"] == 115
    # a second step multiplies: 0.7 x 0.5, bonds 'inside' the base only: its 9
    res = _step("weaken", group="base", factor=0.5, bonds="inside").execute(Ctx(sim))
    assert res["bonds_weakened"] == 9
    inside = base[i] & base[j]
    assert np.all(st.brate[ok][inside] == np.float32(np.float32(0.7) * 0.5))


def test_weaken_the_bonds_crossing_a_plane_counted_with_numpy():
    sim = _sim()
    st = sim.state
    # horizontal, between rows 1 and 2: 2 x 9 bonds by hand
    res = _step("weaken", plane={"point": [0.0, 0.036], "normal": [0.0, 1.0]},
                factor=0.25).execute(Ctx(sim))
    assert res["bonds_weakened"] == 18
    assert int((st.brate == np.float32(0.25)).sum()) == 2 * 18
    # slanted: counted independently from every pair of lattice neighbours
    sim = _sim()
    st = sim.state
    p, n = np.array([0.1, 0.05]), np.array([1.0, 0.6])
    a, b = np.triu_indices(st.n, 1)
    near = np.abs(np.hypot(*(st.x[a] - st.x[b]).T) - D) < 1e-6 * D
    s = (st.x - p) @ n > 0
    want = int((near & (s[a] != s[b])).sum())
    res = _step("weaken", plane={"point": p.tolist(), "normal": n.tolist()},
                factor=0.5).execute(Ctx(sim))
    assert want > 5 and res["bonds_weakened"] == want
    assert int((st.brate == np.float32(0.5)).sum()) == 2 * want


def test_cut_breaks_the_bonds_and_books_their_energy_as_heat():
    sim = _sim(gravity=True, steps=200)
    e0 = sim.energies()
    el0 = e0["elastic"]
    res = _step("weaken", plane={"point": [0.0, 0.036], "normal": [0.0, 1.0]},
                cut=True).execute(Ctx(sim))
    assert res["bonds_cut"] == 18 and res["bonds_weakened"] == 0
    assert sim.bonded_count() == 115 - 18 == res["bonds_left"]
    log = sim.crack_log()
    assert int((log["type"] == 0).sum()) == 18
    e1 = sim.energies()
    assert res["heat_booked"] == pytest.approx(e1["heat_break_normal"] - e0["heat_break_normal"])
    assert res["heat_booked"] >= 0.0 and e1["elastic"] <= el0
    assert e1["closure_residual"] == pytest.approx(e0["closure_residual"], abs=1e-9 * el0)


def test_friction_factor_scales_the_group_elements_only():
    sim = _sim()
    st = sim.state
    base = st.group_mask("base")
    res = _step("weaken", group="base", friction_factor=0.5).execute(Ctx(sim))
    assert res["elements_friction_reduced"] == 10 and res["bonds_weakened"] == 0
    assert np.all(st.mu[base] == 0.4 * 0.5) and np.all(st.mu[~base] == 0.4)
    assert np.all(st.brate == 1.0)


@pytest.mark.parametrize("step, where, says", [
    ({"kind": "excavate", "group": "nope"}, "steps[0].group", "unknown group 'nope'"),
    ({"kind": "excavate", "group": "all"}, "steps[0].group", "leave no model"),
    ({"kind": "excavate", "shape": {"disc": {"center": [0.1, 0.0, 0.0], "radius": 0.01}}},
     "steps[0].shape.disc.center", "2 coordinates needed"),
    ({"kind": "excavate", "shape": {"polygon": [[0, 0], [1, 0]]}}, "steps[0].shape",
     "at least 3 vertices"),
    ({"kind": "excavate", "group": "base", "stages": 0}, "steps[0].stages", ">= 1"),
    ({"kind": "excavate", "group": "base", "order": "z"}, "steps[0].order", "in 2-D"),
    ({"kind": "excavate", "group": "base", "nsteps_per_stage": -1},
     "steps[0].nsteps_per_stage", ">= 0"),
    ({"kind": "excavate"}, "steps[0]", "exactly one of group"),
    ({"kind": "weaken", "group": "base", "factor": 0.0}, "steps[0].factor", "> 0 and <= 1"),
    ({"kind": "weaken", "group": "base", "factor": 1.5}, "steps[0].factor", "> 0 and <= 1"),
    ({"kind": "weaken", "group": "nope", "factor": 0.5}, "steps[0].group", "unknown group"),
    ({"kind": "weaken", "plane": {"point": [0, 0, 0], "normal": [0, 1, 0]}, "factor": 0.5},
     "steps[0].plane.point", "2 components needed"),
    ({"kind": "weaken", "plane": {"point": [0, 0], "normal": [0, 0]}, "factor": 0.5},
     "steps[0].plane.normal", "the normal is zero"),
    ({"kind": "weaken", "plane": {"point": [0, 0], "normal": [0, 1]},
      "friction_factor": 0.5}, "steps[0]", "friction_factor needs a group"),
    ({"kind": "weaken", "group": "base", "factor": 0.5, "cut": True}, "steps[0]", "not both"),
    ({"kind": "weaken", "group": "base"}, "steps[0]", "give factor, friction_factor or cut"),
])
def test_bad_inputs_are_refused_naming_the_field(step, where, says):
    with pytest.raises(WorkflowError) as exc:
        _cfg(steps=[step])
    text = str(exc.value)
    assert f": {where}: " in text and says in text, text


def test_take_carries_every_array_rotation_included():
    from geodem.core.state import enable_rotation, take

    st = _sim().state
    enable_rotation(st)
    st.mr[:, :, 0] = np.where(st.nbr >= 0, st.nbr + 0.5, 0.0)  # the partner's index, per slot
    st.w[:, 0] = np.arange(st.n)
    keep = np.ones(st.n, bool)
    keep[[0, 5, 17]] = False
    new = take(st, keep)
    old = np.flatnonzero(keep)
    assert new.n == 45 and np.array_equal(new.w[:, 0], old) and new.mr.shape == (45, st.width, 1)
    valid = new.nbr >= 0
    # each slot's history moved with its pair: the old partner's index, relabelled
    assert np.array_equal(new.mr[:, :, 0][valid], old[new.nbr[valid]] + 0.5)
    assert np.all(new.mr[~valid] == 0.0) and np.all(new.brate[~valid] == 1.0)
    assert not np.isin(new.nbr[valid], -1).any() and new.groups == st.groups


def test_removal_refuses_coupled_fields_and_removing_everything():
    sim = _sim()
    with pytest.raises(ValueError, match="no model"):
        sim.remove_elements(np.ones(sim.state.n, bool))
    sim.fields.append(type("Field", (), {"kind": "thermal"})())
    with pytest.raises(ValueError, match="coupled fields \\(thermal\\)"):
        sim.remove_elements([0])
    assert sim.state.n == 48


def test_a_cylinder_in_3d_is_staged_by_the_distance_from_its_axis():
    cfg = _cfg(dim=3, domain={"box": {"min": [0.0, 0.0, 0.0], "max": [0.12, 0.06, 0.12]}},
               groups={"base": {"side": "zmin"}})
    st = cfg.model.build(cfg).state
    sim = Simulation(st, backend="numpy")
    x0 = st.x.copy()
    radial = np.hypot(x0[:, 0] - 0.06, x0[:, 2] - 0.06)
    inside = radial <= 0.035
    res = _step("excavate", shape={"disc": {"center": [0.06, 0.03, 0.06], "radius": 0.035}},
                stages=2).execute(Ctx(sim))
    lo, hi = radial[inside].min(), radial[inside].max()
    first = inside & (radial <= lo + 0.5 * (hi - lo) + 1e-12)
    assert res["key_range"] == pytest.approx([lo, hi])
    assert res["removed_per_stage"] == [int(first.sum()), int((inside & ~first).sum())]
    assert 0 < first.sum() < inside.sum() and sim.state.n == len(x0) - int(inside.sum())
