"""``geodem study freeze``: what freezing elements at rest (geodem.fields.freeze) buys and costs;
``geodem study graded``: the same for coarser elements in the deep ground (``model.coarsen``,
docs/graded.md), at the bottom of this module.

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


# ============================================================================ graded models
#: ``geodem study graded``: the landslide as shipped (uniform d, gravity deposition) and graded
#: (``model.coarsen``: fine band 9 m under the ground and the sliding surface, 15 m transition)
#: with the coarsest elements 1, 2 and 3 times d (factor 1: the graded builder, no coarsening)
GRADED_RUNS = {
    "uniform": [],
    "graded x1": ["model.coarsen.factor=1"],
    "graded x2": ["model.coarsen.factor=2"],
    "graded x3": ["model.coarsen.factor=3"],
}
GRADED_KEYS = ("runout_m", "travel_angle_deg", "max_velocity", "deposit_volume_m3", "com_ratio")


def graded_run(out_dir, name, seed, workflow="workflows/landslide.yaml") -> dict:
    """One landslide run of :data:`GRADED_RUNS` ``name`` with packing seed ``seed``."""
    from geodem.workflow import run_workflow

    sets = GRADED_RUNS[name] + [f"model.seed={seed}", "steps.slide.gif=false"]
    tag = name.replace(" ", "_")
    t0 = time.perf_counter()
    code, s = run_workflow(workflow, Path(out_dir) / f"{tag}_seed{seed}", sets=sets,
                           echo=False, progress=False, overwrite=True)
    total = time.perf_counter() - t0
    if code != 0:
        raise RuntimeError(f"graded study run {name!r} seed {seed} failed: {s.get('error')}")
    r = s["results"]["slide"]
    out = {"run": name, "seed": seed, "total_wall_s": total, "step_wall_s": r["wall_s"],
           "runout_wall_s": r["runout_wall_s"], "elements": r["elements"],
           "element_steps": r["element_steps"], "steps": r["settle_steps"] + r["runout_steps"],
           "slide_elements": r["slide_elements"], "stopped_by": r["stopped_by"],
           **{k: r[k] for k in GRADED_KEYS}}
    g = r.get("graded")
    if g:
        out.update(fine=g["fine"], transition_elements=g["transition_elements"],
                   coarse=g["coarse"], packing_s=g["packing_time_s"])
    return out


def graded_summary(runs) -> dict:
    """Per configuration: means (and sample standard deviations over the seeds) of the results,
    mean element count, element-steps and wall times; speed-ups against ``uniform``."""
    out = {}
    for name in GRADED_RUNS:
        rs = [r for r in runs if r["run"] == name]
        if not rs:
            continue
        row = {"seeds": [r["seed"] for r in rs]}
        for k in GRADED_KEYS + ("elements", "element_steps", "step_wall_s", "runout_wall_s",
                                "total_wall_s"):
            v = np.array([r[k] for r in rs], float)
            row[k] = float(v.mean())
            row[k + "_std"] = float(v.std(ddof=1)) if v.size > 1 else 0.0
        out[name] = row
    if "uniform" in out:
        u = out["uniform"]
        for row in out.values():
            row["element_steps_ratio"] = u["element_steps"] / row["element_steps"]
            row["step_speedup"] = u["step_wall_s"] / row["step_wall_s"]
            row["total_speedup"] = u["total_wall_s"] / row["total_wall_s"]
    return out


def graded_study(out_dir, seeds=(0, 1, 2), names=None, progress=None) -> dict:
    """Run :data:`GRADED_RUNS` (or ``names``) for each packing seed; write
    ``graded_study.json`` and ``graded_study.md`` to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = []
    for seed in seeds:
        for name in (names or GRADED_RUNS):
            runs.append(graded_run(out, name, seed))
            if progress:
                progress(runs[-1])
    rec = {"runs": runs, "summary": graded_summary(runs)}
    (out / "graded_study.json").write_text(json.dumps(rec, indent=1))
    (out / "graded_study.md").write_text(graded_markdown(rec))
    return rec


def graded_markdown(rec) -> str:
    lines = ["| model | elements | element-steps | step wall [s] | speed-up (element-steps / "
             "wall) | runout_m | travel_angle_deg | max_velocity | deposit_volume_m3 | "
             "com_ratio |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, row in rec["summary"].items():
        acc = " | ".join(f"{row[k]:.4g} ± {row[k + '_std']:.2g}" for k in GRADED_KEYS)
        sp = (f"{row['element_steps_ratio']:.2f} / {row['step_speedup']:.2f}"
              if "step_speedup" in row else "")
        lines.append(f"| {name} | {row['elements']:,.0f} | {row['element_steps']:.3g} | "
                     f"{row['step_wall_s']:.1f} | {sp} | {acc} |")
    lines += ["", "| model | seed | elements | step wall [s] | total wall [s] | "
              + " | ".join(GRADED_KEYS) + " |", "|---|---:|---:|---:|---:|"
              + "---:|" * len(GRADED_KEYS)]
    for r in rec["runs"]:
        lines.append(f"| {r['run']} | {r['seed']} | {r['elements']:,} | {r['step_wall_s']:.1f} | "
                     f"{r['total_wall_s']:.1f} | "
                     + " | ".join(f"{r[k]:.4g}" for k in GRADED_KEYS) + " |")
    return "\n".join(lines) + "\n"


def describe_graded(r) -> str:
    return (f"{r['run']} seed {r['seed']}: {r['elements']:,} elements, step "
            f"{r['step_wall_s']:.1f} s (total {r['total_wall_s']:.1f} s), runout "
            f"{r['runout_m']:.4g} m, travel angle {r['travel_angle_deg']:.3g} deg")
