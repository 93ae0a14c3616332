"""``geodem study freeze``: what freezing elements at rest (geodem.fields.freeze) buys and costs.

Two scenes, each run with and without the ``freeze`` field:

* **grain pile**: a 2-D pile of cohesionless grains (triangular lattice, ``nx`` x ``ny``) at
  rest on a fixed base, light damping (2 % of the standard damping), a heavy ball dropped on
  its left end at 2 m/s. Most of the pile never feels the impact: the far field sleeps.
* **landslide**: ``workflows/landslide.yaml`` (ground damping 0.05 of critical) with
  ``steps.slide.freeze`` on and off, as shipped and on a ground 50 m deep (more far field).

Reported per scene: wall time of the stepping, skipped fraction of element-steps, speed-up,
and the accuracy cost (pile: largest position difference of any element and of the ball, in
grain diameters; landslide: the summary's runout, travel angle, max velocity, H_c/L_c, set
beside a run of the same scene at a 0.5 % smaller time step, which shows how much a granular
runout moves under any perturbation).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

D = 0.01  # grain diameter of the pile [m]


def pile(nx=80, ny=8):
    """Cohesionless grains on a triangular lattice with a fixed base row, gravity, and a ball
    of 4 grain masses held (fixed) three diameters above the left end."""
    from geodem.build.lattice import bonded_state, triangular_lattice
    from geodem.build.walls import append_elements
    from geodem.core import neighbors

    x = triangular_lattice(nx, ny, D)
    st = bonded_state(x, 0.5 * D, density=2650.0, kn=1e7, ks=4e6, xb=1e-4 * D, fs0=1.0, mu=0.5,
                      gap=1e-6 * D)
    st.cstate[:] = 0  # cohesionless grains
    st.free[x[:, 1] < 0.5 * D] = 0.0  # fixed base row
    st.gravity[:2] = [0.0, -9.81]
    top = x[:, 1].max()
    st = append_elements(st, np.array([[5 * D, top + 3 * D]]), 0.5 * D, 4 * st.m[0], kn=1e7,
                         mu=0.5, fixed=True)
    neighbors.build_rows(st)
    return st


def settled(backend="numba", nx=80, ny=8):
    """The pile balanced, light damping (2 % of the standard damping), the ball released
    downwards at 2 m/s; books reset. Returns the Simulation."""
    from geodem.core import timestep
    from geodem.core.engine import Simulation

    st = pile(nx, ny)
    ball = st.n - 1
    sim = Simulation(st, backend=backend)
    sim.balance(ny + 2)
    eta = 0.02 * timestep.standard_damping(st, 1)
    sim.change(lambda z: z.eta.__setitem__(slice(None), eta), book_energy=False)
    sim.change(lambda z: (z.free.__setitem__(ball, 1.0), z.v.__setitem__(ball, [0.0, -2.0])))
    sim.reset_energy()
    return sim


def pile_case(nx=300, ny=20, steps=20000, backend="numba", v_sleep=1e-3) -> dict:
    from geodem.fields.freeze import FreezeField

    out = {}
    for frz in (False, True):
        sim = settled(backend, nx, ny)
        if frz:
            sim.add_field(FreezeField(v_sleep=v_sleep, every=10))
        t = time.perf_counter()
        sim.run(steps)
        out[frz] = (sim, time.perf_counter() - t)
    (ref, w0), (fz, w1) = out[False], out[True]
    ball = ref.state.n - 1
    s = fz.field("freeze").summary()
    return {"scene": "grain pile", "elements": ref.state.n, "steps": steps,
            "wall_s_off": w0, "wall_s_on": w1, "speedup": w0 / w1,
            "skipped_fraction": s["skipped_fraction"], "fell_asleep": s["fell_asleep"],
            "woke": s["woke"],
            "max_position_error_d": float(np.abs(fz.state.x - ref.state.x).max() / D),
            "ball_position_error_d": float(np.abs(fz.state.x[ball] - ref.state.x[ball]).max()
                                           / D),
            "closure_error_on": fz.closure_error(), "closure_error_off": ref.closure_error()}


LANDSLIDE_KEYS = ("runout_m", "travel_angle_deg", "max_velocity", "com_ratio",
                  "deposit_volume_m3", "stopped_by")


LANDSLIDE_SCENES = {
    # the workflow as shipped: ground 10 m deep under the valley floor
    "landslide": {"sets": [], "freeze": "steps.slide.freeze={}"},
    # the same slope on a ground 50 m deep: more far field; sleepers at 0.01 m/s
    "landslide, deep ground": {"sets": ["model.base_depth=50"],
                               "freeze": "steps.slide.freeze={v_sleep: 0.01, patience: 5}"},
}


def landslide_case(out_dir, scene="landslide", workflow="workflows/landslide.yaml") -> dict:
    from geodem.workflow import run_workflow

    spec = LANDSLIDE_SCENES[scene]
    base = list(spec["sets"])
    runs = {"off": base, "on": base + [spec["freeze"]],
            "dt_0.995": base + ["simulation.dt_fraction=0.0199"]}
    res = {}
    tag = scene.replace(", ", "_").replace(" ", "_")
    for name, sets in runs.items():
        code, s = run_workflow(workflow, Path(out_dir) / f"{tag}_{name}", sets=sets,
                               echo=False, progress=False, overwrite=True)
        if code != 0:
            raise RuntimeError(f"{scene} run {name!r} failed: {s.get('error')}")
        r = s["results"]["slide"]
        res[name] = {k: s[k] for k in LANDSLIDE_KEYS}
        res[name]["runout_wall_s"] = r["runout_wall_s"]
        res[name]["elements"] = r["elements"]
        res[name]["skipped_fraction"] = (r.get("freeze") or {}).get("skipped_fraction", 0.0)
    res["speedup"] = res["off"]["runout_wall_s"] / res["on"]["runout_wall_s"]
    return {"scene": scene, "freeze": spec["freeze"], **res}


def freeze_study(out_dir, landslide=True, progress=None) -> dict:
    """Run the scenes, write ``freeze_study.json`` and ``freeze_study.md`` to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rec = {"pile": pile_case()}
    if progress:
        progress(rec["pile"])
    if landslide:
        for scene in LANDSLIDE_SCENES:
            rec[scene] = landslide_case(out, scene)
            if progress:
                progress(rec[scene])
    (out / "freeze_study.json").write_text(json.dumps(rec, indent=1))
    (out / "freeze_study.md").write_text(markdown(rec))
    return rec


def markdown(rec) -> str:
    p = rec["pile"]
    lines = ["| scene | elements | wall off [s] | wall on [s] | speed-up | skipped | accuracy |",
             "|---|---:|---:|---:|---:|---:|---|",
             f"| grain pile | {p['elements']} | {p['wall_s_off']:.2f} | {p['wall_s_on']:.2f} | "
             f"{p['speedup']:.2f} | {p['skipped_fraction']:.1%} | largest position error "
             f"{p['max_position_error_d']:.2g} d, ball {p['ball_position_error_d']:.2g} d |"]
    for scene in LANDSLIDE_SCENES:
        if scene not in rec:
            continue
        ls = rec[scene]
        acc = ", ".join(f"{k} {ls['on'][k]:.4g} / {ls['off'][k]:.4g} / {ls['dt_0.995'][k]:.4g}"
                        for k in LANDSLIDE_KEYS[:4])
        lines.append(f"| {scene} | {ls['off']['elements']:,} | {ls['off']['runout_wall_s']:.2f} | "
                     f"{ls['on']['runout_wall_s']:.2f} | {ls['speedup']:.2f} | "
                     f"{ls['on']['skipped_fraction']:.1%} | on / off / off at 0.995 dt: {acc} |")
    return "\n".join(lines) + "\n"


def describe(rec) -> str:
    if rec["scene"] == "grain pile":
        return (f"grain pile, {rec['elements']} elements: {rec['wall_s_off']:.2f} s -> "
                f"{rec['wall_s_on']:.2f} s (x{rec['speedup']:.2f}), "
                f"{rec['skipped_fraction']:.0%} of element-steps skipped, largest position "
                f"error {rec['max_position_error_d']:.2g} grain diameters")
    return (f"{rec['scene']}: {rec['off']['runout_wall_s']:.1f} s -> "
            f"{rec['on']['runout_wall_s']:.1f} s (x{rec['speedup']:.2f}), "
            f"{rec['on']['skipped_fraction']:.0%} skipped; runout "
            f"{rec['on']['runout_m']:.4g} m with freezing, {rec['off']['runout_m']:.4g} m "
            f"without, {rec['dt_0.995']['runout_m']:.4g} m without at a 0.5 % smaller step")
