"""Speed against accuracy of the UCS lab test: resolution (elements across the specimen height)
and time-step fraction.

Every point runs ``workflows/ucs.yaml`` (or any UCS workflow) with ``model.d_mean = height /
n_across`` and ``simulation.dt_fraction = f``, and records the wall time and the relative
errors of E and UCS against the material's targets (a calibrated material: the targets are what
the calibration matched at its own resolution; the errors show how well the per-size scaling
transfers and what a coarser / faster run costs in accuracy). Writes ``study.json`` and
``speed_accuracy.png``; the fastest point with both errors <= ``tolerance`` is reported.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

__all__ = ["ucs_study"]


def _targets(workflow: Path, material: str):
    from geodem.materials_library import load_material
    from geodem.workflow.yamlio import load_document

    doc = load_document(workflow)
    spec = doc.data["materials"][material]
    if "library" in spec:
        v = load_material(spec["library"]).values()
    else:
        v = spec
    return float(v["E"]), float(v["Cu"]), doc.data["model"]["size"][-1]


def ucs_study(workflow, out_dir, across=(10, 15, 20, 30, 40), fractions=(0.02, 0.05, 0.1),
              material: str = "rock", tolerance: float = 0.05, backend=None, progress=None):
    """Run the grid; returns the study record (also written to ``study.json``)."""
    from geodem.workflow import WorkflowError, run_workflow

    wf = Path(workflow)
    out = Path(out_dir)
    E_t, Cu_t, height = _targets(wf, material)  # first: a bad workflow leaves no folder
    out.mkdir(parents=True, exist_ok=True)
    points = []
    for n in across:
        for f in fractions:
            d = height / float(n)
            run = out / f"across{n}_dt{f:g}"
            t0 = time.perf_counter()
            try:
                code, s = run_workflow(wf, run, sets=[f"model.d_mean={d!r}",
                                                      f"simulation.dt_fraction={f!r}"],
                                       backend=backend, overwrite=True, echo=False,
                                       progress=False)
            except WorkflowError as exc:  # e.g. a specimen too coarse to build: a point lost
                code, s = 2, {"status": "invalid", "error": str(exc)}
            wall = time.perf_counter() - t0
            p = {"n_across": n, "dt_fraction": f, "d_mean": d, "status": s.get("status"),
                 "wall_time_s": wall, "n_elements": s.get("n_elements"),
                 "steps": s.get("steps")}
            if code == 0 and s.get("E") and s.get("ucs"):
                p.update(E=s["E"], ucs=s["ucs"], nu=s.get("nu"),
                         E_rel_error=s["E"] / E_t - 1.0, ucs_rel_error=s["ucs"] / Cu_t - 1.0)
            else:
                p["error"] = s.get("error")
            points.append(p)
            if progress:
                progress(p)
    ok = [p for p in points if "E_rel_error" in p and abs(p["E_rel_error"]) <= tolerance
          and abs(p["ucs_rel_error"]) <= tolerance]
    best = min(ok, key=lambda p: p["wall_time_s"]) if ok else None
    rec = {"workflow": str(wf), "targets": {"E": E_t, "Cu": Cu_t}, "tolerance": tolerance,
           "points": points, "fastest_within_tolerance": best}
    (out / "study.json").write_text(json.dumps(rec, indent=2))
    try:
        _plot(out / "speed_accuracy.png", points, tolerance, best)
        rec["plot"] = "speed_accuracy.png"
    except ImportError:
        pass
    return rec


def _plot(path, points, tol, best):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    good = [p for p in points if "E_rel_error" in p]
    fr = sorted({p["dt_fraction"] for p in good})
    marks = dict(zip(fr, "os^Dv"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.3), sharex=True)
    for ax, key, name in ((axes[0], "E_rel_error", "E"), (axes[1], "ucs_rel_error", "UCS")):
        for f in fr:
            sel = sorted((p for p in good if p["dt_fraction"] == f), key=lambda p: p["n_across"])
            ax.plot([p["wall_time_s"] for p in sel], [100 * abs(p[key]) for p in sel],
                    marker=marks[f], ls="-", label=f"dt = {f:g} T_min")
            for p in sel:
                ax.annotate(str(p["n_across"]), (p["wall_time_s"], 100 * abs(p[key])),
                            textcoords="offset points", xytext=(4, 3), fontsize=7)
        ax.axhline(100 * tol, color="k", ls="--", lw=0.8, label=f"{tol:.0%}")
        if best is not None:
            ax.plot([best["wall_time_s"]], [100 * abs(best[key])], "r*", ms=14,
                    label="fastest within tolerance")
        ax.set_xscale("log")
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_xlabel("wall time [s] (2 cores)")
        ax.set_ylabel(f"|{name} error| [%]")
        ax.set_title(f"{name}: labels = elements across the height")
    axes[0].legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
