"""Steps ``monitor`` and ``pressure`` (geodem.workflow.monitoring) on tiny models, by hand: the
sampling grid, the nearest element of a point, the CSV header and rows (and their truncation on
resume), the pressure force per element = p x its tributary area, the cavity's radial loads,
and bad inputs refused with the field named."""
import csv
import math
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from geodem.workflow import monitoring as mon
from geodem.workflow.errors import WorkflowError
from geodem.workflow.schema import validate_document
from geodem.workflow.yamlio import load_document

ROCK = {"rho": 2650, "kn": 2.0e7, "ks": 6.0e6, "xb": 2.0e-6, "fs0": 20.0, "mu": 0.4}


def _cfg(steps, **model):
    doc = {"metadata": {"name": "mon"},
           "model": dict({"type": "scene", "dim": 2, "d": 0.02, "material": "rock",
                          "domain": {"box": {"min": [0.0, 0.0], "max": [0.2, 0.1]}},
                          "groups": {"base": {"side": "ymin"}, "top": {"side": "ymax"},
                                     "mid": {"box": {"min": [0.0, 0.04], "max": [0.2, 0.06]}}}},
                         **model),
           "materials": {"rock": ROCK},
           "steps": steps}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mon.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return validate_document(load_document(path))


def test_samples_lie_on_multiples_of_every_plus_the_start_and_the_end():
    assert mon.sample_steps(150, 520, 100) == [150, 200, 300, 400, 500, 520]
    assert mon.sample_steps(0, 300, 100) == [0, 100, 200, 300]


def test_a_point_takes_the_nearest_element():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    idx, dist = mon.nearest_elements(x, [[0.9, 0.2], [0.1, 0.6]])
    assert idx.tolist() == [1, 2]
    assert dist == pytest.approx([math.hypot(0.1, 0.2), math.hypot(0.1, 0.4)])


def test_pressure_on_a_side_is_p_times_the_tributary_area_by_hand():
    cfg = _cfg([{"kind": "pressure", "group": "top", "pressure": 1000.0}])
    st = cfg.model.build(cfg).state
    step = cfg.steps[0]
    idx, unit, area = step.loads(cfg, st)
    # 10 per even row (x = 0.01 ... 0.19), rows every 0.0173 m: 5 rows, the top one (row 4) even:
    # 10 elements; the side is the model's width surface to surface, 0.2 m, times the 2-D
    # thickness 2 r = 0.02 m
    assert idx.size == 10 and area == pytest.approx(0.2 * 0.02)
    assert np.allclose(unit[:, 0], 0.0)
    assert np.allclose(1000.0 * unit[:, 1], -1000.0 * 0.2 * 0.02 / 10)  # pushes down
    base = cfg.model.groups["base"]
    assert base.side == "ymin"
    cfg2 = _cfg([{"kind": "pressure", "group": "base", "pressure": 1.0}])
    _, ub, _ = cfg2.steps[0].loads(cfg2, st)
    assert np.all(ub[:, 1] > 0)  # the base's outward normal is -y: pushed up
    # another group needs its side, and is loaded over its own width; area overrides
    cfg3 = _cfg([{"kind": "pressure", "group": "mid", "side": "ymax", "pressure": 1.0,
                  "area": 0.5}])
    i3, u3, a3 = cfg3.steps[0].loads(cfg3, st)
    assert a3 == 0.5 and np.allclose(u3[:, 1], -0.5 / i3.size)


def test_a_cavity_is_loaded_radially_over_its_wall():
    # eight elements on a ring of radius 0.05 around a hole of radius 0.04, one far away
    r = 0.01
    ang = np.arange(8) * np.pi / 4
    x = np.vstack([np.c_[0.05 * np.cos(ang), 0.05 * np.sin(ang)], [[0.5, 0.5]]]) + [1.0, 2.0]
    st = SimpleNamespace(x=x, r=np.full(9, r), dim=2, thickness=0.0)
    idx, unit, area = mon.cavity_load(st, [1.0, 2.0], 0.04)
    assert idx.tolist() == list(range(8))
    assert area == pytest.approx(2 * math.pi * 0.04 * 2 * r)
    mag = np.linalg.norm(unit, axis=1)
    assert mag == pytest.approx(np.full(8, area / 8))
    assert np.allclose(unit / mag[:, None], np.c_[np.cos(ang), np.sin(ang)])  # outwards
    # an uneven lining: each element takes half the angles to its neighbours round the centre
    # (0, 90 and 180 degrees: 135, 90 and 135 of the 360)
    st3 = SimpleNamespace(x=x[[0, 2, 4]], r=np.full(3, r), dim=2, thickness=0.0)
    _, u3, a3 = mon.cavity_load(st3, [1.0, 2.0], 0.04)
    assert np.linalg.norm(u3, axis=1) == pytest.approx(a3 * np.array([135, 90, 135]) / 360)


def _ctx(tmp_path, st, results):
    sim = SimpleNamespace(state=st, sync=lambda: st, cracks={"type": [0, 1, 2, 1]})
    runner = SimpleNamespace(results=results, files=[], cfg=None)
    return SimpleNamespace(runner=runner, sim=sim, out_dir=tmp_path, state=st,
                           model=SimpleNamespace(reference=st.x.copy()))


def test_monitor_csv_header_rows_and_resume_by_hand(tmp_path):
    cfg = _cfg([{"kind": "monitor", "every": 10, "points": {"p": [0.1, 0.05]},
                 "groups": ["top"]}])
    st = cfg.model.build(cfg).state
    step = cfg.steps[0]
    results = {}
    ctx = _ctx(tmp_path, st, results)
    rec = mon.MonitorRecorder(step, ctx)
    rec.start()
    for k in (10, 20):
        st.step, st.time = k, k * 1e-6
        st.x[:, 1] -= 1e-6  # everything moves down 1 um per sample
        rec.sample()
    with open(tmp_path / "monitor.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["step", "time [s]", "p.ux [m]", "p.uy [m]", "p.vx [m/s]", "p.vy [m/s]",
                       "top.ux [m]", "top.uy [m]", "top.vx [m/s]", "top.vy [m/s]",
                       "top.sxx [Pa]", "top.sxy [Pa]", "top.syy [Pa]", "broken_bonds [1]"]
    assert [int(r[0]) for r in rows[1:]] == [0, 10, 20]
    assert float(rows[3][3]) == pytest.approx(-2e-6) and float(rows[3][7]) == pytest.approx(-2e-6)
    assert rows[3][-1] == "3"  # tensile and shear cracks; the joint (type 0) is not counted
    last = results[step.name]["last"]
    assert results[step.name]["samples"] == 3 and last["p.uy [m]"] == pytest.approx(-2e-6)
    # resumed from a checkpoint at step 10: the row of step 20 goes, the others stay as written
    st.step = 10
    again = mon.MonitorRecorder(step, ctx)
    again.resume()
    with open(tmp_path / "monitor.csv") as f:
        kept = list(csv.reader(f))
    assert kept == rows[:3] and again.last_step == 10 and again.samples == 2


@pytest.mark.parametrize("step, where", [
    ({"kind": "monitor", "groups": ["nope"]}, "nope"),
    ({"kind": "monitor", "every": -5, "groups": ["top"]}, "every"),
    ({"kind": "monitor", "points": {"tip": [0.1, 0.1, 0.1]}}, "tip"),
    ({"kind": "monitor", "groups": ["top"], "volumes": {"base": 1.0}}, "volumes"),
    ({"kind": "pressure", "group": "nope", "pressure": 1.0}, "nope"),
    ({"kind": "pressure", "group": "mid", "pressure": 1.0}, "side"),
    ({"kind": "pressure", "group": "top", "pressure": 1.0, "ramp": 1.0, "ramp_steps": 5},
     "ramp"),
    ({"kind": "pressure", "shape": {"disc": {"center": [0.1], "radius": 0.02}},
      "pressure": 1.0}, "center"),
])
def test_bad_inputs_are_refused_with_the_field(step, where):
    with pytest.raises(WorkflowError) as exc:
        _cfg([step])
    assert where in str(exc.value)


def test_two_monitors_need_two_files():
    with pytest.raises(WorkflowError) as exc:
        _cfg([{"kind": "monitor", "groups": ["top"]}, {"kind": "monitor", "groups": ["base"]}])
    assert "file" in str(exc.value)


def test_contact_stress_lives_in_measure_and_the_cases_still_offer_it():
    from geodem import measure
    from geodem.cases import brazilian

    assert brazilian.contact_stress is measure.contact_stress
