"""``geodem advise FILE.yaml``: what a workflow will cost, and how it could cost less.

Everything comes from :func:`geodem.workflow.runner.prepare` (the path of ``geodem validate`` and
``--dry-run``: validated, model built, time step checked, steps planned; nothing is stepped or
written) plus, unless told not to, a short timing of the built model on this machine:

* size: elements, dimension, estimated memory (the model's state bytes per element, as the
  memory check uses) and the built state's actual bytes;
* time: planned time steps, element-steps, and the wall time at a throughput that is either
  *measured* (``calibrate``: a copy of the built model steps for about ``CALIBRATE_SECONDS`` on
  the chosen backend after a warm-up that loads the compiled kernels) or *documented* (the
  backend's figure in ``geodem.workflow.runner.EST_RATE``, from docs/performance.md). The
  calibration times the bare mechanical step: coupled fields and step logic come on top, and
  steps that stop on a criterion (uniaxial: the peak drop) may end earlier than planned;
* suggestions: whether a 2-D model would do (the built model's thinnest extent in element
  layers), the time-step fraction against the stability bound (docs/stability.md), and the
  resolution for a target error from a ``geodem study speed-accuracy`` CSV when one is found
  (docs/speed_accuracy.md).
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np

#: seconds of stepping the calibration aims at (after its warm-up)
CALIBRATE_SECONDS = 0.5
#: where ``geodem study speed-accuracy -o out/speed_accuracy`` (the documented command) writes
DEFAULT_SPEED_CSV = Path("out/speed_accuracy/speed_accuracy.csv")
#: a 3-D model at most this many element layers thick along one axis counts as plane
PLANE_LAYERS = 4.0
#: the stability study's measured ratios (docs/stability.md): refusal bound / exact limit
BOUND_OVER_LIMIT = (0.58, 0.76)


def measure_throughput(state, backend: str, dt: float,
                       seconds: float = CALIBRATE_SECONDS) -> dict:
    """Element-steps per second of ``Simulation.run`` at ``dt`` on a copy of ``state`` (the
    original is not touched): a warm-up of 2 steps (kernels loaded or compiled), then doubling
    chunks until ``seconds`` of stepping. Returns ``rate``, ``steps``, ``wall_s``,
    ``warmup_s``."""
    from geodem.core.engine import Simulation

    st = state.copy()
    t0 = time.perf_counter()
    sim = Simulation(st, backend=backend, dt=dt, monitor_every=0)
    sim.run(2)
    sim.sync()
    warm = time.perf_counter() - t0
    steps, wall, chunk = 0, 0.0, 4
    while wall < seconds and steps < 100_000:
        t1 = time.perf_counter()
        sim.run(chunk)
        sim.sync()
        wall += time.perf_counter() - t1
        steps += chunk
        # next chunk: double, but not past the time left at the rate so far
        chunk = max(1, min(2 * chunk, int((seconds - wall) * steps / max(wall, 1e-9))))
    return {"rate": st.n * steps / wall if wall > 0 else math.inf, "steps": steps,
            "wall_s": wall, "warmup_s": warm}


# ------------------------------------------------------------------ suggestions
def _plane(state) -> dict:
    """Extents of the built model and its element layers along each axis."""
    d = 2.0 * float(state.r.mean())
    ext = state.x.max(axis=0) - state.x.min(axis=0) + d
    layers = ext / d
    k = int(np.argmin(ext))
    return {"extent_m": ext.tolist(), "layers": layers.tolist(), "thin_axis": "xyz"[k],
            "thin_layers": float(layers[k])}


def _dim_suggestion(prep) -> dict:
    st, m = prep.built.state, prep.cfg.model
    if st.dim == 2:
        return {"topic": "dimension", "two_d_possible": True,
                "text": "already 2-D (a disc model: the cheapest; 3-D multiplies elements by "
                        "the layers across the thickness)"}
    geo = _plane(st)
    field = type(m).model_fields.get("dim")
    has_2d = field is not None and "2" in str(field.annotation)
    plane = geo["thin_layers"] <= PLANE_LAYERS
    n2 = st.n / max(geo["thin_layers"], 1.0)
    if plane:
        text = (f"the model is {geo['thin_layers']:.1f} element layers thick along "
                f"{geo['thin_axis']}: nearly plane; a 2-D model would have about {n2:,.0f} "
                f"elements (1/{geo['thin_layers']:.1f} of the memory and time per step)")
        text += ("; set model.dim: 2 (with 2-component sizes/counts)" if has_2d else
                 f"; model type {m.type!r} has no 2-D variant")
    else:
        text = (f"3-D needed as built: the thinnest extent is {geo['thin_layers']:.1f} element "
                f"layers ({geo['thin_axis']}); a 2-D section would have about {n2:,.0f} "
                f"elements but not the 3-D response"
                + ("" if has_2d else f" (model type {m.type!r} has no 2-D variant)"))
    return {"topic": "dimension", "two_d_possible": bool(plane and has_2d),
            "two_d_elements": int(round(n2)), **geo, "text": text}


def _dt_suggestion(prep) -> dict:
    from geodem.core import timestep

    st, plan = prep.built.state, prep.plan
    t_min = timestep.default_dt(st, 1.0)  # the smallest element period
    frac = plan.dt / t_min
    f_max = min(0.2, plan.stable_dt / t_min)  # the schema allows dt_fraction <= 0.2
    lo, hi = (plan.stable_dt / b for b in reversed(BOUND_OVER_LIMIT))
    text = (f"dt = {frac:.3g} x the smallest element period T_min"
            + (" (simulation.dt)" if plan.dt_source == "simulation.dt" else "") + "; the "
            f"engine refuses above {plan.stable_dt / t_min:.3g} x T_min (its stability bound, "
            f"{plan.dt / plan.stable_dt:.2f} of it used; the true limit 2/omega_max lies about "
            f"{lo / t_min:.2g}-{hi / t_min:.2g} x T_min, docs/stability.md)")
    if f_max > 1.05 * frac:
        text += (f"; quasi-static stages (balance, platen loading) barely change up to the "
                 f"bound (docs/speed_accuracy.md): dt_fraction {0.8 * f_max:.3g} (0.8 of it, a "
                 f"margin for contacts that form during the run) would need "
                 f"{frac / (0.8 * f_max):.2f} x the steps; keep 0.02 or less for undamped "
                 f"dynamics (phase error (omega dt)^2/24 per period)")
    return {"topic": "time_step", "dt_fraction": frac, "refusal_fraction": plan.stable_dt / t_min,
            "suggested_quasi_static_fraction": 0.8 * f_max, "text": text}


#: speed_accuracy cases and what in a workflow they stand for (model types, step kinds)
CASE_OF = (("two_balls", {"two_balls"}), ("ucs", {"uniaxial", "specimen"}),
           ("thermal_rod", {"heat", "thermal_bar"}),
           ("consolidation", {"flow", "darcy", "consolidation", "hydrofrac_plate"}),
           ("column_collapse", {"granular_column", "collapse"}),
           ("wave_speed", {"wave_source", "valley_amplification"}),
           ("lattice", {"lattice_block"}))


def _case(prep) -> str | None:
    kinds = {s.kind for s in prep.cfg.steps} | {prep.cfg.model.type}
    for case, keys in CASE_OF:
        if kinds & keys:
            return case
    return None


def _resolution_suggestion(prep, csv_path, target) -> dict | None:
    path = Path(csv_path) if csv_path else DEFAULT_SPEED_CSV
    case = _case(prep)
    base = {"topic": "resolution", "csv": str(path), "case": case, "target_error": target}
    if not path.is_file():
        if csv_path:  # asked for by name: say it is missing
            return {**base, "text": f"no speed-accuracy results at {path}"}
        return None
    if case is None:
        return {**base, "text": "no speed-accuracy case stands for this workflow "
                                f"(cases: {', '.join(c for c, _ in CASE_OF)})"}
    with path.open(newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("case") == case
                and r.get("status") == "ok"]
    pts = []
    for r in rows:
        p = {k: _number(r.get(k)) for k in ("error", "wall_s", "dt_fraction", "resolution",
                                             "n_elements", "damping")}
        if p["error"] is None or p["wall_s"] is None:
            continue
        pts.append(p | {k: r.get(k, "") for k in ("resolution_of", "dt_of", "backend")})
    if not pts:
        return {**base, "text": f"no successful {case!r} points in {path}"}
    ok = [p for p in pts if p["error"] <= target]
    b = min(ok, key=lambda p: p["wall_s"]) if ok else min(pts, key=lambda p: p["error"])
    where = (f"resolution {b['resolution']:g} ({b['resolution_of']}), " if b["resolution"]
             is not None else "") + f"dt fraction {b['dt_fraction']:g} of {b['dt_of']}" + (
        f", damping {b['damping']:g}" if b["damping"] is not None else "")
    if ok:
        text = (f"speed-accuracy case {case!r}: the fastest point under {target:.3g} error is "
                f"{where} (error {b['error']:.2g}, {b['wall_s']:.2g} s on {b['backend']}, "
                f"{b['n_elements']:.0f} elements)")
    else:
        text = (f"speed-accuracy case {case!r}: no point reached {target:.3g}; the best is "
                f"{b['error']:.2g} at {where}")
    return {**base, "best": b, "reached": bool(ok), "text": text}


def _number(v):
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


# ------------------------------------------------------------------ the report
def advise(path, sets=(), backend: str | None = None, *, calibrate: bool = True,
           target_error: float = 0.01, speed_csv=None, progress=None) -> dict:
    """The advice for a workflow as a dict (WorkflowError on bad input, as ``prepare``);
    ``progress`` gets the build's progress lines (``prepare``'s)."""
    from geodem.workflow.runner import _estimate, prepare

    if not (0.0 < target_error < 1.0):
        raise ValueError(f"target error {target_error!r}: allowed 0 < target < 1 (relative)")
    prep = prepare(path, sets=sets, backend=backend, progress=progress)
    cfg, plan, st = prep.cfg, prep.plan, prep.built.state
    if calibrate:
        cal = measure_throughput(st, prep.backend, plan.dt)
        rate, source = cal["rate"], (f"measured here: {cal['steps']} steps of the built model "
                                     f"in {cal['wall_s']:.2f} s on {prep.backend}")
    else:
        from geodem.workflow.runner import EST_RATE

        cal = None
        rate = EST_RATE.get(prep.backend, 4.0e6)
        source = f"documented figure for {prep.backend} (docs/performance.md)"
    _, runtime, compile_s = _estimate(cfg, prep.backend, prep.built, plan.total_steps, st.n,
                                      st.dim, rate=rate)
    out = {
        "workflow": cfg.metadata.name, "file": str(prep.doc.file), "model": cfg.model.type,
        "dim": int(st.dim), "n_elements": int(st.n), "backend": prep.backend,
        "memory_bytes": int(plan.memory_bytes),
        "bytes_per_element": int(plan.memory_bytes // max(st.n, 1)),
        "state_bytes": int(st.nbytes()), "memory_available": plan.memory_available,
        "output_bytes": int(plan.output_bytes), "checkpoint_bytes": int(plan.checkpoint_bytes),
        "dt": plan.dt, "dt_source": plan.dt_source, "stable_dt": plan.stable_dt,
        "steps": [{"name": s.name, "kind": s.kind, "time_steps": int(n)}
                  for s, n in zip(cfg.steps, plan.steps)],
        "total_steps": int(plan.total_steps), "simulated_time_s": plan.total_steps * plan.dt,
        "element_steps": int(plan.total_steps) * int(st.n),
        "throughput": {"element_steps_per_s": rate, "source": source,
                       "calibration": cal},
        "wall_time_s": runtime, "wall_time_note": (
            "stepping at the throughput plus observations and frames; coupled fields and "
            "step logic come on top, steps that stop on a criterion may end earlier"),
        "compile_s": compile_s if not calibrate else 0.0,
        "initial_overlap": plan.initial_overlap,
    }
    sugg = [_dim_suggestion(prep), _dt_suggestion(prep)]
    res = _resolution_suggestion(prep, speed_csv, target_error)
    if res is not None:
        sugg.append(res)
    out["suggestions"] = sugg
    return out


def report_lines(a: dict) -> list[str]:
    """What ``geodem advise`` prints."""
    from geodem.workflow.runner import human_bytes

    avail = a["memory_available"]
    lines = [
        f"workflow {a['workflow']!r} ({a['file']}): {a['model']}, {a['dim']}-D, "
        f"{a['n_elements']:,} elements, backend {a['backend']}",
        f"memory: about {human_bytes(a['memory_bytes'])} ({a['bytes_per_element']} bytes per "
        f"element; the built state holds {human_bytes(a['state_bytes'])})"
        + (f", {human_bytes(avail)} available" if avail else ""),
        f"time step: {a['dt']:.4g} s ({a['dt_source']}); stability bound {a['stable_dt']:.4g} s",
        "steps: " + ", ".join(f"{s['name']} ({s['kind']}) {s['time_steps']:,}"
                              for s in a["steps"]),
        f"total: {a['total_steps']:,} time steps, {a['simulated_time_s']:.4g} s simulated, "
        f"{a['element_steps']:.3g} element-steps",
        f"throughput: {a['throughput']['element_steps_per_s']:.3g} element-steps/s "
        f"({a['throughput']['source']})",
        f"estimated wall time: about {a['wall_time_s']:.3g} s"
        + (f" (plus about {a['compile_s']:.0f} s compiling on first use)"
           if a["compile_s"] else "") + f"; {a['wall_time_note']}",
        f"output: output.h5 about {human_bytes(a['output_bytes'])}, checkpoints about "
        f"{human_bytes(a['checkpoint_bytes'])} each",
        f"largest initial overlap (a free element): {a['initial_overlap']:.3g} x the smaller "
        f"radius",
        "suggestions:",
    ]
    lines += [f"  - {s['topic']}: {s['text']}" for s in a["suggestions"]]
    return lines
