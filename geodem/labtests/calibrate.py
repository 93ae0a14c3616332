"""Calibration: find the element parameters whose virtual lab tests give a rock's E, nu, UCS and
tensile strength.

MatDEM's trainer multiplies the four targets by a ``rate`` vector, converts them on the lattice
and updates ``rate *= target / measured`` (PHYSICS.md section 2). That treats the four
properties as independent, which they are not: nu moves E, and the tensile and compressive
strengths move together. geodem uses what is exact about the bonded-particle model instead.

Unknowns (size-free, :func:`geodem.materials.per_size`), in the log / ratio variables::

    u = (ln kn_per_d, s = ks / kn, ln F_t, ln rho_s)   with F_t = kn_per_d xb_per_d  [Pa]
                                                            rho_s = fs0_per_d2 / F_t  [-]

(``F_t d^2`` is a bond's tensile breaking force, ``rho_s`` the ratio of its shear to its tensile
strength; ``mu`` stays at the lattice value from ``mu_i``). Measurements
``y = (ln E, nu, ln Tu, ln Cu)``. In quasi-static small-strain loading:

* scaling both spring stiffnesses by ``a`` at fixed breaking *forces* scales E by ``a`` and
  leaves nu and both strengths unchanged (the forces for a given stress do not change);
* scaling both breaking forces by ``b`` scales both strengths by ``b`` and changes nothing else.

So the Jacobian ``dy/du`` has known entries (1 and 0) and four unknown ones: ``d ln E / ds``,
``d nu / ds`` and ``d ln Tu, d ln Cu / d ln rho_s`` (plus small ``s``-couplings of the
strengths). The solver is Newton with a Broyden update restricted to the unknown entries
(the exact ones stay exact), started from slopes measured on random packings; iteration 1
runs the prior guess (lattice conversion times default rates). Every iteration builds the
same packing (same seed) and runs the UCS and Brazilian workflows, whose files are kept under
``iterations/NN/``. The best iteration (smallest largest normalised error) is the result.

Tolerances (issue targets): E, Cu, Tu within 5 %, nu within 0.03 absolute. A target outside
what the packing can reach (nu beyond the nu(s) range of the packing, Cu/Tu beyond the ratio
the bond law allows) is reported as unreachable with the reason.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from geodem.materials import macro_to_micro, per_size

__all__ = ["CalibrationSpec", "calibrate", "save_calibration", "calibration_block",
           "to_unknowns", "from_unknowns", "TOLERANCES"]

TOLERANCES = {"E": 0.05, "nu": 0.03, "Cu": 0.05, "Tu": 0.05}  # nu absolute, others relative
KEYS = ("E", "nu", "Tu", "Cu")
S_RANGE = (0.0, 1.5)  # ks / kn searched
RHO_RANGE = (0.05, 50.0)  # fs0 / (kn xb) searched (per d^2)
MAX_S_STEP = 0.2  # largest change of ks / kn per iteration (nu moves ~0.1 with it)

# Prior rates per dimension: the lattice conversion of the targets is multiplied by these
# (like MatDEM's rate vector) for the first iteration, and the initial slopes of the unknown
# Jacobian entries. Measured on geodem's random packings (docs/materials.md, "calibration").
PRIOR = {
    # 2-D: nu(s) of the random disc packings is about 0.26 - 0.49 (s - 0.5) near s = 0.5
    # (measured: s = 0.5 -> 0.26, s = 1 -> 0.015); their nu is far above the lattice's at
    # small s, so the prior sets s from this line instead of the lattice formula
    2: {"E": 2.7, "Tu": 1.35, "Cu": 9.0, "s_of_nu": (0.5, 0.26, -0.49),
        "dlnE_ds": 0.5, "dnu_ds": -0.5, "dlnTu_dlnrho": 0.15, "dlnCu_dlnrho": 0.75},
    3: {"E": 2.7, "Tu": 6.0, "Cu": 6.5, "s_of_nu": None,
        "dlnE_ds": 0.5, "dnu_ds": -0.25, "dlnTu_dlnrho": 0.15, "dlnCu_dlnrho": 0.75},
}


def to_unknowns(el: dict) -> np.ndarray:
    """``u = (ln kn_per_d, ks/kn, ln(kn_per_d xb_per_d), ln(fs0_per_d2 / (kn_per_d xb_per_d)))``
    of size-free element parameters."""
    ft = el["kn_per_d"] * el["xb_per_d"]
    return np.array([math.log(el["kn_per_d"]), el["ks_per_d"] / el["kn_per_d"], math.log(ft),
                     math.log(el["fs0_per_d2"] / ft)])


def from_unknowns(u, mu: float) -> dict:
    """Inverse of :func:`to_unknowns` (``mu`` carried through)."""
    kn = math.exp(u[0])
    ft = math.exp(u[2])
    return {"kn_per_d": kn, "ks_per_d": float(u[1]) * kn, "xb_per_d": ft / kn,
            "fs0_per_d2": math.exp(u[3]) * ft, "mu": float(mu)}


def _outputs(m: dict) -> np.ndarray:
    return np.array([math.log(m["E"]), m["nu"], math.log(m["Tu"]), math.log(m["Cu"])])


@dataclass
class CalibrationSpec:
    """What to calibrate against and on which specimens (defaults: the 2-D lab workflows)."""

    targets: dict  # E, nu, Tu, Cu, mu_i, rho
    name: str = "material"
    dim: int = 2
    d_mean: float = 0.005
    ucs_size: tuple = (0.1, 0.2)
    disc_diameter: float = 0.1
    distri_rate: float = 0.2
    seed: int = 0
    strain_rate: float = 0.2
    max_strain: float = 0.02  # the same sample grid as workflows/ucs.yaml
    iterations: int = 6
    tolerances: dict = field(default_factory=lambda: dict(TOLERANCES))
    backend: str | None = None
    prefer: str = "Cu"  # strength matched when Cu / Tu is out of reach


    def __post_init__(self):
        if self.dim not in (2, 3):
            raise ValueError(f"dim = {self.dim!r}: allowed 2 or 3")
        if not 1 <= int(self.iterations) <= 20:
            raise ValueError(f"iterations = {self.iterations!r}: allowed 1-20")
        if self.prefer not in ("Cu", "Tu"):
            raise ValueError(f"prefer = {self.prefer!r}: allowed 'Cu' or 'Tu'")
        if len(self.ucs_size) != self.dim:
            raise ValueError(f"ucs_size needs {self.dim} values for dim = {self.dim}")


def prior_guess(spec: CalibrationSpec) -> dict:
    """Iteration 1: lattice conversion of the targets times the prior rates (per-size values)."""
    t = spec.targets
    p = PRIOR[spec.dim]
    nu = min(max(t["nu"], -0.5), 0.19)
    mi = max(t["mu_i"], 1.0 / math.sqrt(8.0))
    mic = macro_to_micro(t["E"] * p["E"], nu, t["Tu"] * p["Tu"], t["Cu"] * p["Cu"], mi,
                         t["rho"], 1.0)
    el = per_size(mic.element, 1.0)
    if p["s_of_nu"] is not None:
        s0, nu0, slope = p["s_of_nu"]
        s = float(np.clip(s0 + (t["nu"] - nu0) / slope, *S_RANGE))
        el["ks_per_d"] = s * el["kn_per_d"]
    return el


def initial_jacobian(dim: int) -> tuple[np.ndarray, np.ndarray]:
    """(J, unknown mask) in the variables of the module docstring."""
    p = PRIOR[dim]
    J = np.array([[1.0, p["dlnE_ds"], 0.0, 0.0],
                  [0.0, p["dnu_ds"], 0.0, 0.0],
                  [0.0, 0.0, 1.0, p["dlnTu_dlnrho"]],
                  [0.0, 0.0, 1.0, p["dlnCu_dlnrho"]]])
    free = np.array([[0, 1, 0, 0],
                     [0, 1, 0, 0],
                     [0, 1, 0, 1],
                     [0, 1, 0, 1]], bool)
    return J, free


#: smallest change of a free unknown (s, or ln rho_s) that a secant may learn from: the
#: measurements repeat to ~1e-3 (nu) / ~1 % (strengths) between packings of neighbouring
#: parameters, so a smaller step's secant is mostly noise
MIN_SECANT_STEP = 0.05


def broyden(J, free, du, dy, min_step=MIN_SECANT_STEP):
    """Broyden's update restricted to the unknown entries: each row ``k`` gets
    ``J[k] += (dy_k - J[k] du) du_free / |du_free|^2`` over its free columns, when the free
    part of the step is at least ``min_step`` (smaller steps teach noise)."""
    J = J.copy()
    for k in range(J.shape[0]):
        cols = free[k]
        n2 = float((du[cols] ** 2).sum())
        if n2 >= min_step ** 2:
            J[k, cols] += (dy[k] - J[k] @ du) * du[cols] / n2
    return J


def sane(J):
    """Keep the slopes within their physical range so one noisy secant cannot send the Newton
    step astray. Measured on random 2-D packings (docs/calibration.md): d nu/ds about -0.5
    (kept in [-1.2, -0.2]: a near-zero slope asks for a huge change of s), d ln E/ds in
    [-1, 3]; d ln Cu/d ln rho > d ln Tu/d ln rho."""
    J = J.copy()
    J[1, 1] = float(np.clip(J[1, 1], -1.2, -0.2))
    J[0, 1] = float(np.clip(J[0, 1], -1.0, 3.0))
    J[2, 3] = float(np.clip(J[2, 3], -0.2, 0.9))
    J[3, 3] = float(np.clip(J[3, 3], J[2, 3] + 0.1, 1.5))
    return J


def newton_step(J, u, y, y_target, pinned=None, prefer="Cu"):
    """Next ``u``: ``J du = y_target - y``, bounded (s in S_RANGE, rho_s in RHO_RANGE, at most a
    factor 3 per step in the log variables). ``pinned`` maps unknown index -> value held
    (a target found unreachable): those columns are fixed and the rest solved without the row
    of the unreachable target (s pinned: the nu row; rho_s pinned: the row of the strength
    not in ``prefer``, so the preferred one is matched and the other is as close as the
    packing gets)."""
    r = y_target - y
    if pinned:
        du = np.zeros(4)
        cols = [c for c in range(4) if c not in pinned]
        for c, v in pinned.items():
            du[c] = v - u[c]
        rows = [k for k in range(4) if not (k == 1 and 1 in pinned)
                and not (k == (2 if prefer == "Cu" else 3) and 3 in pinned)]
        rhs = r[rows] - J[np.ix_(rows, list(pinned))] @ du[list(pinned)]
        du[cols] = np.linalg.lstsq(J[np.ix_(rows, cols)], rhs, rcond=None)[0]
    else:
        du = np.linalg.solve(J, r)
    du[[0, 2, 3]] = np.clip(du[[0, 2, 3]], -math.log(3.0), math.log(3.0))
    du[1] = float(np.clip(du[1], -MAX_S_STEP, MAX_S_STEP))
    un = u + du
    un[1] = float(np.clip(un[1], *S_RANGE))
    un[3] = float(np.clip(un[3], *np.log(RHO_RANGE)))
    return un


# ---------------------------------------------------------------------------------- runs
def _material_block(spec, el):
    return dict({"rho": float(spec.targets["rho"]), "dim": spec.dim}, **{k: float(v) for k, v in
                                                                         el.items()})


def _ucs_workflow(spec, el):
    return {"metadata": {"name": "calibration_ucs", "seed": spec.seed,
                         "description": f"calibration of {spec.name}: uniaxial compression"},
            "model": {"type": "specimen", "dim": spec.dim, "size": list(spec.ucs_size),
                      "d_mean": spec.d_mean, "distri_rate": spec.distri_rate,
                      "material": "rock"},
            "materials": {"rock": _material_block(spec, el)},
            "steps": [{"kind": "uniaxial", "name": "ucs", "strain_rate": spec.strain_rate,
                       "max_strain": spec.max_strain, "drop": 0.7}],
            "outputs": {"observables": {"every": 1000}}}


def _brazilian_workflow(spec, el):
    model = {"type": "brazilian_disc", "dim": spec.dim, "diameter": spec.disc_diameter,
             "d_mean": spec.d_mean, "distri_rate": spec.distri_rate, "material": "rock"}
    if spec.dim == 3:
        model["thickness"] = 0.5 * spec.disc_diameter
    return {"metadata": {"name": "calibration_brazilian", "seed": spec.seed,
                         "description": f"calibration of {spec.name}: Brazilian test"},
            "model": model,
            "materials": {"rock": _material_block(spec, el)},
            "steps": [{"kind": "brazilian", "name": "brazilian", "loading_rate": 0.1,
                       "max_strain": 0.01, "drop": 0.5}],  # as workflows/brazilian.yaml
            "outputs": {"observables": {"every": 1000}}}


def _run(doc, folder: Path, backend):
    from geodem.workflow import run_workflow

    folder.mkdir(parents=True, exist_ok=True)
    wf = folder / "workflow.yaml"
    wf.write_text("# written by geodem calibrate; rerun with: geodem run workflow.yaml -o out\n"
                  + yaml.safe_dump(doc, sort_keys=False))
    code, summary = run_workflow(wf, folder / "out", backend=backend, overwrite=True,
                                 echo=False, progress=False)
    if code != 0 or summary.get("status") != "ok":
        raise RuntimeError(f"calibration run {wf} failed ({summary.get('status')}): "
                           f"{summary.get('error')}")
    return summary


def measure(spec: CalibrationSpec, el: dict, folder: Path) -> dict:
    """Run the UCS and Brazilian workflows with element parameters ``el``; returns E, nu, Cu
    (UCS), Tu (Brazilian tensile strength) and the wall time."""
    t0 = time.perf_counter()
    u = _run(_ucs_workflow(spec, el), folder / "ucs", spec.backend)
    b = _run(_brazilian_workflow(spec, el), folder / "brazilian", spec.backend)
    if u.get("E") is None or u.get("nu") is None:
        raise RuntimeError(f"the UCS run in {folder / 'ucs'} gave no E / nu fit "
                           f"({u['results']['ucs'].get('fit_error')})")
    return {"E": float(u["E"]), "nu": float(u["nu"]), "Cu": float(u["ucs"]),
            "Tu": float(b["tensile_strength"]), "wall_time_s": time.perf_counter() - t0}


def _score(measured, targets, tol, reachable):
    worst = 0.0
    for k in KEYS:
        if not reachable.get(k, True):
            continue
        e = abs(measured[k] - targets[k]) if k == "nu" else abs(measured[k] / targets[k] - 1)
        worst = max(worst, e / tol[k])
    return worst


def calibrate(spec: CalibrationSpec, out_dir, progress=None, start: dict | None = None,
              measure_fn=None) -> dict:
    """Calibrate (see module docstring); writes ``summary.json``, ``calibrated.yaml``
    (the material block), ``history.csv``, ``convergence.png`` and ``iterations/NN/`` into
    ``out_dir``. ``progress(i, record)`` is called after each iteration; ``measure_fn(spec,
    element, folder)`` replaces :func:`measure` (tests use a synthetic response). Returns the
    summary."""
    measure_fn = measure if measure_fn is None else measure_fn
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    tg = {k: float(spec.targets[k]) for k in ("E", "nu", "Tu", "Cu", "mu_i", "rho")}
    y_t = _outputs(tg)
    tol = spec.tolerances
    el = dict(start) if start else prior_guess(spec)
    mu = el["mu"]
    u = to_unknowns(el)
    u[1] = float(np.clip(u[1], *S_RANGE))
    u[3] = float(np.clip(u[3], *np.log(RHO_RANGE)))
    J, free = initial_jacobian(spec.dim)
    history = []
    reachable = {k: True for k in KEYS}
    pinned = {}
    notes = []
    prev = None
    best_pt = None  # (u, y, score, iteration) of the best iteration so far
    for it in range(1, int(spec.iterations) + 1):
        el = from_unknowns(u, mu)
        m = measure_fn(spec, el, out / "iterations" / f"{it:02d}")
        y = _outputs(m)
        rel = {k: (m[k] - tg[k]) / tg[k] for k in KEYS}
        rec = {"iteration": it, "element": el, "measured": {k: m[k] for k in KEYS},
               "rel_errors": rel, "nu_abs_error": m["nu"] - tg["nu"],
               "wall_time_s": m["wall_time_s"]}
        if prev is not None:
            J = broyden(J, free, u - prev[0], y - prev[1])
        J = sane(J)
        rec["score"] = _score(m, tg, tol, reachable)
        history.append(rec)
        if progress:
            progress(it, rec)
        if rec["score"] <= 1.0:
            break
        if best_pt is not None and rec["score"] > best_pt[2]:
            # a step that made things worse still taught the secant; the next step starts
            # again from the best point (a trust-region fallback: no iteration is wasted
            # drifting from a bad point)
            rec["restart_from"] = best_pt[3]
            u, y = best_pt[0].copy(), best_pt[1].copy()
        else:
            best_pt = (u.copy(), y.copy(), rec["score"], it)
        prev = (u.copy(), y.copy())
        # reachability: the Newton step wants s or rho_s beyond the searched range while
        # already at its bound -> pin it there and match the others
        want = u + np.linalg.solve(J, y_t - y)
        other = "Tu" if spec.prefer == "Cu" else "Cu"
        for idx, key, (lo, hi) in ((1, "nu", S_RANGE), (3, other, tuple(np.log(RHO_RANGE)))):
            for bound, beyond in ((lo, want[idx] < lo - 1e-9), (hi, want[idx] > hi + 1e-9)):
                if beyond and abs(u[idx] - bound) < 1e-9:
                    reachable[key] = False
                    pinned[idx] = bound
        u = newton_step(J, u, y, y_t, pinned, spec.prefer)
    for rec in history:  # judged on what is reachable
        rec["score"] = _score(rec["measured"], tg, tol, reachable)
    best = min(history, key=lambda r: r["score"])
    if not reachable["nu"]:
        notes.append(f"nu = {tg['nu']:g} is beyond this packing: with ks / kn at its bound "
                     f"({pinned[1]:g}) it measures nu = "
                     f"{best['measured']['nu']:.3g}; E, Tu and Cu are matched")
    if 3 in pinned:
        other = "Tu" if spec.prefer == "Cu" else "Cu"
        notes.append(f"Cu / Tu = {tg['Cu'] / tg['Tu']:.3g} is beyond what the bond law gives "
                     f"this packing: with the bonds' shear strength at its bound "
                     f"({math.exp(pinned[3]):.3g} x the tensile) it measures Cu / Tu = "
                     f"{best['measured']['Cu'] / best['measured']['Tu']:.3g}. {spec.prefer} is "
                     f"matched (prefer = {spec.prefer}), {other} is what the packing gives with "
                     "it; more shear strength does not help: failure is by tensile bond "
                     "breakage (PHYSICS.md section 2, 'random packings')")
    wall = time.perf_counter() - t0
    summary = {
        "material": spec.name, "dim": spec.dim,
        "targets": {k: tg[k] for k in KEYS},
        "measured": best["measured"],
        "rel_errors": best["rel_errors"],
        "abs_errors": {k: best["measured"][k] - tg[k] for k in KEYS},
        "tolerances": tol,
        "converged": best["score"] <= 1.0,
        "best_iteration": best["iteration"],
        "iterations": len(history),
        "wall_time_s": wall,
        "element": best["element"],
        "reachable": reachable,
        "notes": notes,
        "specimen": {"d_mean": spec.d_mean, "ucs_size": list(spec.ucs_size),
                     "disc_diameter": spec.disc_diameter, "distri_rate": spec.distri_rate,
                     "seed": spec.seed, "strain_rate": spec.strain_rate,
                     "max_strain": spec.max_strain},
        "history": history,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    _write_history_csv(out / "history.csv", history)
    (out / "calibrated.yaml").write_text(yaml.safe_dump(calibration_block(summary),
                                                        sort_keys=False))
    try:
        _plot(out / "convergence.png", history, tol, spec.name)
        summary["plot"] = "convergence.png"
    except ImportError:  # matplotlib is optional
        pass
    return summary


def calibration_block(summary: dict) -> dict:
    """The ``calibrated: {<dim>d: ...}`` entry of a material file."""
    return {f"{summary['dim']}d": {
        "element": {k: float(v) for k, v in summary["element"].items()},
        "measured": {k: float(v) for k, v in summary["measured"].items()},
        "rel_errors": {k: round(float(v), 5) for k, v in summary["rel_errors"].items()},
        "converged": bool(summary["converged"]),
        "iterations": int(summary["iterations"]),
        "notes": list(summary["notes"]),
        "specimen": summary["specimen"],
    }}


def save_calibration(path, summary: dict) -> None:
    """Store :func:`calibration_block` in the material file ``path`` under ``calibrated``
    (other dimensions' entries kept; the rest of the file, comments included, untouched).
    The file is replaced atomically."""
    import os

    p = Path(path)
    text = p.read_text()
    lines = text.splitlines()
    start = next((k for k, ln in enumerate(lines) if ln.startswith("calibrated:")), None)
    old = {}
    if start is not None:
        old = (yaml.safe_load("\n".join(lines[start:])) or {}).get("calibrated") or {}
        end = next((k for k in range(start + 1, len(lines))
                    if lines[k] and not lines[k][0].isspace() and not lines[k].startswith("#")),
                   len(lines))
        head, tail = lines[:start], lines[end:]
    else:
        head, tail = lines, []
    old.update(calibration_block(summary))
    block = yaml.safe_dump({"calibrated": old}, sort_keys=False).rstrip("\n").splitlines()
    new = "\n".join(head + block + tail) + "\n"
    tmp = p.with_suffix(p.suffix + ".tmp")
    tmp.write_text(new)
    os.replace(tmp, p)


def _write_history_csv(path, history):
    cols = ["iteration", "score"] + [f"{k}_measured" for k in KEYS] + \
        [f"{k}_rel_error" for k in KEYS] + ["kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2",
                                             "mu", "wall_time_s"]
    lines = [",".join(cols)]
    for r in history:
        row = [r["iteration"], r["score"]] + [r["measured"][k] for k in KEYS] + \
            [r["rel_errors"][k] for k in KEYS] + [r["element"][k] for k in
                                                  ("kn_per_d", "ks_per_d", "xb_per_d",
                                                   "fs0_per_d2", "mu")] + [r["wall_time_s"]]
        lines.append(",".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in row))
    Path(path).write_text("\n".join(lines) + "\n")


def _plot(path, history, tol, name):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [r["iteration"] for r in history]
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for k, c in zip(KEYS, ("C0", "C1", "C2", "C3")):
        if k == "nu":
            e = [abs(r["nu_abs_error"]) / tol["nu"] for r in history]
            lab = f"|nu - target| / {tol['nu']}"
        else:
            e = [abs(r["rel_errors"][k]) / tol[k] for r in history]
            lab = f"|{k} error| / {tol[k]:.0%}"
        ax.semilogy(it, np.maximum(e, 1e-3), "o-", color=c, label=lab)
    ax.axhline(1.0, color="k", ls="--", lw=0.8, label="tolerance")
    ax.set_xlabel("iteration")
    ax.set_ylabel("error / tolerance")
    ax.set_xticks(it)
    ax.set_title(f"calibration of {name}")
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
