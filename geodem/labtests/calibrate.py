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

So ``ln E - ln kn`` and each ``ln strength - ln F_t`` are functions of the shape variables
``x = (s, ln rho_s)`` only, and so are nu and Cu / Tu. The solver (:func:`next_unknowns`) fits
each of them by a local weighted plane over every sample so far (:func:`local_plane`, a ridge
toward the prior slopes), solves ``nu(x) = nu_t`` and ``Cu/Tu(x) = ratio_t`` together for ``x``
(one step at most), and sets the two levels by the exact scalings. Iteration 1 runs the prior
guess (lattice conversion times rates measured on random packings). Every iteration builds the
same packing (same seed) with the spec's micro-structure (``structure``: packing recipe, bond
range, bond-strength scatter, stored with the result) and runs the UCS and the direct-tension
workflows on it (the same specimen pushed and pulled), whose files are kept under
``iterations/NN/``. Tu is the direct-tension strength: the one test that loads a whole
cross-section in uniform tension. The Brazilian disc is run once with the result, as a check
(:func:`brazilian_check`, stored with the calibration): calibrated on the Brazilian peak, the
bonded discs had a direct-tension strength of 0.24 x the Brazilian one (sandstone, 2-D), since
a disc of a rock that weak in tension crumbles under the platens and goes on carrying load.
It stops when every reachable target is met or after :data:`STALL` iterations without a
better one; the best iteration (smallest largest normalised error) is the result.

(An earlier Newton solver with a Broyden update of the four unknown slopes failed on granite:
steps of ``s`` below the measurement noise gave a near-zero secant of nu(s), and the next step
changed ``s`` by 0.4 and E by -58 %. A later one solved nu in ``s`` alone and Cu / Tu in
``rho_s`` alone; nu depends on ``rho_s`` too, and four rocks did not converge.)

Tolerances: E, Cu, Tu within 5 %, nu within 0.03 absolute. Targets outside the region charted
for the packing (:mod:`geodem.labtests.reach`: the (Cu / Tu, nu) measured over a grid of the
shape variables) are refused before the first iteration, with the measured bounds. A target
found out of reach on the way (nu beyond the nu(s) range of the packing, Cu/Tu beyond the ratio
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

__all__ = ["CalibrationSpec", "UnreachableTarget", "calibrate", "check_reachable",
           "brazilian_check", "save_calibration", "calibration_block", "to_unknowns",
           "from_unknowns", "TOLERANCES"]

TOLERANCES = {"E": 0.05, "nu": 0.03, "Cu": 0.05, "Tu": 0.05}  # nu absolute, others relative
KEYS = ("E", "nu", "Tu", "Cu")
S_RANGE = (0.0, 1.5)  # ks / kn searched
RHO_RANGE = (0.05, 50.0)  # fs0 / (kn xb) searched (per d^2)
MAX_S_STEP = 0.2  # largest change of ks / kn per iteration (nu moves ~0.1 with it)

# Prior rates per dimension: the lattice conversion of the targets is multiplied by these
# (like MatDEM's rate vector) for the first iteration, and the initial slopes of the unknown
# Jacobian entries. Measured on geodem's random packings (docs/materials.md, "calibration").
PRIOR = {
    # 2-D isotropic packings with Tu from direct tension (sandstone, granite, limestone
    # calibrations): nu(s) = 0.50, 0.25, 0.17, 0.15, 0.11 at s = 0.32, 0.46, 0.51, 0.52, 0.63;
    # the prior sets s from the line through the middle; Tu rate: F_t that meets Tu in direct
    # tension over the lattice conversion's
    2: {"E": 2.7, "Tu": 4.5, "Cu": 9.0, "s_of_nu": (0.45, 0.25, -1.0),
        "dlnE_ds": 0.5, "dnu_ds": -1.0, "dlnTu_dlnrho": 0.05, "dlnCu_dlnrho": 0.75},
    # 3-D (isotropic packings, d = 0.01 m specimens, sandstone): nu(s) = 0.37, 0.18, 0.14,
    # 0.11 at s = 0.33, 0.41, 0.46, 0.53
    3: {"E": 2.7, "Tu": 3.6, "Cu": 6.5, "s_of_nu": (0.41, 0.18, -0.8),
        "dlnE_ds": 0.5, "dnu_ds": -0.8, "dlnTu_dlnrho": 0.05, "dlnCu_dlnrho": 0.75},
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
    # micro-structure kept fixed while calibrating and stored with the element parameters
    # (geodem.materials.STRUCTURE_KEYS): packing recipe, bond range, bond-strength scatter
    structure: dict = field(default_factory=lambda: {"packing": "isotropic"})
    # refuse, before the first iteration, targets outside the charted reachable region
    # (geodem.labtests.reach); False runs them anyway and reports what is out of reach
    check_reach: bool = True

    def __post_init__(self):
        if self.dim not in (2, 3):
            raise ValueError(f"dim = {self.dim!r}: allowed 2 or 3")
        if not 1 <= int(self.iterations) <= 20:
            raise ValueError(f"iterations = {self.iterations!r}: allowed 1-20")
        if self.prefer not in ("Cu", "Tu"):
            raise ValueError(f"prefer = {self.prefer!r}: allowed 'Cu' or 'Tu'")
        if len(self.ucs_size) != self.dim:
            raise ValueError(f"ucs_size needs {self.dim} values for dim = {self.dim}")
        from geodem.build.specimen import packing_recipe
        from geodem.materials import STRUCTURE_KEYS

        unknown = sorted(set(self.structure) - set(STRUCTURE_KEYS))
        if unknown:
            raise ValueError(f"structure keys {unknown}: allowed {', '.join(STRUCTURE_KEYS)}")
        self.structure = {k: v for k, v in self.structure.items() if v is not None}
        packing_recipe(self.structure, self.dim)


class UnreachableTarget(ValueError):
    """The targets lie outside the charted reachable region (message: the measured bounds)."""


def check_reachable(spec: CalibrationSpec) -> None:
    """Raise :class:`UnreachableTarget` when ``spec.targets`` lie outside the region charted
    for ``spec.dim`` and its micro-structure (:func:`geodem.labtests.reach.outside_region`)."""
    from geodem.labtests.reach import outside_region

    why = outside_region(spec.targets, spec.dim, spec.structure, spec.tolerances)
    if why:
        raise UnreachableTarget(f"{spec.name}: {why}. Try a bond-strength scatter or a bond "
                                "range (docs/calibration.md), or calibrate anyway (--force) "
                                "to match E, nu and the preferred strength")


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


#: slope ranges of the four response functions (physical signs; measured on random packings)
SLOPES = {"nu_s": (-1.2, -0.2), "lnE_s": (-1.0, 3.0), "ratio_rho": (0.05, 1.5),
          "strength_rho": (-0.2, 1.5)}
#: smallest spread of ln rho_s over which a saturated strength ratio is believed: measurements
#: repeat to ~1e-3 (nu) and ~1 % (strengths) between packings of neighbouring parameters
MIN_SECANT_STEP = 0.05
#: iterations without a better score after which the calibration stops (measurement noise
#: of ~1 % in the strengths leaves a target at the edge of the reachable region unmet)
STALL = 3
#: d ln(Cu/Tu) / d ln rho_s below which the strength ratio counts as saturated: failure is by
#: tensile bond breakage and more shear strength no longer raises Cu (seen on granite with Tu
#: from the Brazilian disc: Cu/Tu = 8.4, 7.4, 8.5 for rho_s over a factor 9; with Tu from
#: direct tension the 2-D ratio rises on to 88 at rho_s 50, docs/calibration.md "Reachable
#: region")
RATIO_SATURATION = 0.1


#: the shape variables (ks/kn, ln rho_s) in units of their largest step per iteration: the
#: local model weighs samples by their distance from the latest in these units
SHAPE_SCALE = (MAX_S_STEP, math.log(3.0))
#: ridge weight pulling the local slopes toward the prior ones (per unit of SHAPE_SCALE): a
#: direction the samples have not explored keeps the prior slope
RIDGE = 0.05


def local_plane(X, y, prior, weights):
    """Plane ``y = y_last + g . (x - x_last)`` through the latest sample of ``X`` (rows) and
    ``y``, its slopes ``g`` fitted by weighted least squares over the other samples with a
    ridge pulling them toward ``prior`` (:data:`RIDGE`, in units of :data:`SHAPE_SCALE`).
    Returns ``(y_last, g)``. (The plane goes through the latest measurement: a free intercept
    let a far, curved sample hold the model's value 0.04 off the measured nu, and the next
    steps shrank to 0.008 in ks / kn.)"""
    X = np.asarray(X, float) / SHAPE_SCALE
    y = np.asarray(y, float)
    g0 = np.asarray(prior, float) * SHAPE_SCALE
    d = X - X[-1]
    w = np.asarray(weights, float)
    # unknowns g: sum w (y - y_last - g.d)^2 + RIDGE sum (g - g0)^2
    A = d * np.sqrt(w)[:, None]
    b = (y - y[-1]) * np.sqrt(w)
    R = np.sqrt(RIDGE) * np.eye(2)
    g = np.linalg.lstsq(np.vstack([A, R]), np.concatenate([b, np.sqrt(RIDGE) * g0]),
                        rcond=None)[0]
    return float(y[-1]), g / SHAPE_SCALE


def next_unknowns(history_u, history_y, y_target, dim, prefer="Cu"):
    """The next ``u`` from all iterations so far.

    The two exact scalings leave four functions of the two shape variables ``x = (s, ln
    rho_s)``: ``f_E = ln E - ln kn``, ``nu``, ``f_T = ln Tu - ln F_t``, ``f_C = ln Cu - ln F_t``.
    Each is modelled near the latest sample by a plane (:func:`local_plane`: weighted least
    squares over every sample, weights ``exp(-|x_i - x_last|^2 / 2)`` in units of
    :data:`SHAPE_SCALE`, slopes pulled toward the prior's). ``x`` solves the 2 x 2 linear system
    ``nu(x) = nu_t``, ``(f_C - f_T)(x) = ln(Cu_t / Tu_t)`` (nu depends on rho_s too: pre-peak
    cracking of a strong-shear, weak-tension rock widens it), within one step of the latest
    sample and the bounds; then the levels follow exactly: ``ln kn = ln E_t - f_E(x)``, ``ln F_t =
    ln S_t - f_S(x)`` (S the preferred strength). A target is flagged unreachable (``nu``, or
    the strength not preferred) when its variable sits at a bound and the model still points
    past it, or, for Cu / Tu, when the ratio has saturated (slope below
    :data:`RATIO_SATURATION` with the target above every sample). Returns ``(u, unreachable)``.
    (Earlier, nu was solved in ``s`` alone; on the isotropic 2-D packings nu at one ``s``
    moved from 0.29 to 0.15 as rho_s fell from 22 to 3.5, and four rocks did not converge.)"""
    U, Y = np.asarray(history_u, float), np.asarray(history_y, float)
    p = PRIOR[dim]
    X = U[:, [1, 3]]
    dist = (X - X[-1]) / SHAPE_SCALE
    w = np.exp(-0.5 * (dist ** 2).sum(axis=1))
    f_e = Y[:, 0] - U[:, 0]
    ratio = Y[:, 3] - Y[:, 2]
    k = 3 if prefer == "Cu" else 2
    f_s = Y[:, k] - U[:, 2]
    d_ratio = p["dlnCu_dlnrho"] - p["dlnTu_dlnrho"]
    nu0, g_nu = local_plane(X, Y[:, 1], (p["dnu_ds"], 0.0), w)
    r0, g_r = local_plane(X, ratio, (0.0, d_ratio), w)
    g_nu[0] = float(np.clip(g_nu[0], *SLOPES["nu_s"]))
    raw_ratio_slope = float(g_r[1])
    g_r[1] = float(np.clip(g_r[1], *SLOPES["ratio_rho"]))
    rhs = np.array([y_target[1] - nu0, (y_target[3] - y_target[2]) - r0])
    J = np.array([g_nu, g_r])
    try:
        step = np.linalg.solve(J, rhs)
    except np.linalg.LinAlgError:
        step = rhs / np.diag(J)
    step = np.clip(step, -np.asarray(SHAPE_SCALE), SHAPE_SCALE)
    bounds = (S_RANGE, tuple(np.log(RHO_RANGE)))
    x_new = X[-1] + step
    unreachable = set()
    for i, key in ((0, "nu"), (1, "Tu" if prefer == "Cu" else "Cu")):
        lo, hi = bounds[i]
        at_bound = (x_new[i] < lo and abs(X[-1, i] - lo) < 1e-9) or \
            (x_new[i] > hi and abs(X[-1, i] - hi) < 1e-9)
        if at_bound:
            unreachable.add(key)
        x_new[i] = float(np.clip(x_new[i], lo, hi))
    if x_new[0] != X[-1, 0] + step[0] and abs(J[1, 1]) > 1e-12:
        # ks / kn held at its bound: the strength ratio is met by rho_s alone, at that s
        d_rho = (rhs[1] - J[1, 0] * (x_new[0] - X[-1, 0])) / J[1, 1]
        d_rho = float(np.clip(d_rho, -SHAPE_SCALE[1], SHAPE_SCALE[1]))
        x_new[1] = float(np.clip(X[-1, 1] + d_rho, *bounds[1]))
    spread = np.ptp(X[:, 1]) if len(X) > 1 else 0.0
    if (len(X) >= 3 and spread >= MIN_SECANT_STEP and raw_ratio_slope < RATIO_SATURATION
            and y_target[3] - y_target[2] > ratio.max()):
        unreachable.add("Tu" if prefer == "Cu" else "Cu")
        x_new[1] = X[int(np.argmax(ratio)), 1]
    fe0, g_e = local_plane(X, f_e, (p["dlnE_ds"], 0.0), w)
    fs0, g_s = local_plane(X, f_s, (0.0, p["dlnCu_dlnrho"] if prefer == "Cu"
                                    else p["dlnTu_dlnrho"]), w)
    dx = x_new - X[-1]
    out = U[-1].copy()
    out[1], out[3] = x_new
    out[0] = y_target[0] - (fe0 + g_e @ dx)
    out[2] = y_target[k] - (fs0 + g_s @ dx)
    # at most a factor 3 per iteration in the level variables
    for i in (0, 2):
        out[i] = float(np.clip(out[i], U[-1, i] - math.log(3.0), U[-1, i] + math.log(3.0)))
    return out, unreachable


# ---------------------------------------------------------------------------------- runs
def _material_block(spec, el):
    return dict({"rho": float(spec.targets["rho"]), "dim": spec.dim},
                **{k: (v if isinstance(v, str) else float(v)) for k, v in el.items()})


def _specimen_workflow(spec, el, what, step):
    """The calibration specimen (``spec.ucs_size``, same packing every time) with one step."""
    return {"metadata": {"name": f"calibration_{step['name']}", "seed": spec.seed,
                         "description": f"calibration of {spec.name}: {what}"},
            "model": {"type": "specimen", "dim": spec.dim, "size": list(spec.ucs_size),
                      "d_mean": spec.d_mean, "distri_rate": spec.distri_rate,
                      "material": "rock"},
            "materials": {"rock": _material_block(spec, el)},
            "steps": [step],
            "outputs": {"observables": {"every": 1000}}}


def _ucs_workflow(spec, el):
    return _specimen_workflow(spec, el, "uniaxial compression", {
        "kind": "uniaxial", "name": "ucs", "strain_rate": spec.strain_rate,
        "max_strain": spec.max_strain, "drop": 0.7})


def _tension_workflow(spec, el):
    """Direct tension of the UCS specimen (same packing, pulled instead of pushed): the test
    that loads a whole cross-section in uniform tension, so its peak stress is the tensile
    strength the model has (the Brazilian disc's is checked against it afterwards)."""
    peak_strain = float(spec.targets["Tu"]) / float(spec.targets["E"])
    return _specimen_workflow(spec, el, "direct tension", {
        "kind": "direct_tension", "name": "tension", "strain_rate": 0.05,
        "max_strain": max(0.002, 20.0 * peak_strain), "drop": 0.5})


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
                       "max_strain": 0.01, "drop": 0.8}],  # as workflows/brazilian.yaml
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
    """Run the UCS and direct-tension workflows on the specimen with element parameters
    ``el``; returns E, nu, Cu (UCS), Tu (direct tension) and the wall time."""
    t0 = time.perf_counter()
    u = _run(_ucs_workflow(spec, el), folder / "ucs", spec.backend)
    d = _run(_tension_workflow(spec, el), folder / "tension", spec.backend)
    if u.get("E") is None or u.get("nu") is None:
        raise RuntimeError(f"the UCS run in {folder / 'ucs'} gave no E / nu fit "
                           f"({u['results']['ucs'].get('fit_error')})")
    return {"E": float(u["E"]), "nu": float(u["nu"]), "Cu": float(u["ucs"]),
            "Tu": float(d["tensile_strength"]), "wall_time_s": time.perf_counter() - t0}


def brazilian_check(spec: CalibrationSpec, el: dict, folder: Path) -> dict:
    """The Brazilian disc test with element parameters ``el`` (disc of ``spec.disc_diameter``,
    as workflows/brazilian.yaml): its tensile strength, that over the direct-tension Tu
    target, where its first cracks formed (0 centre, 1 rim) and the wall time."""
    t0 = time.perf_counter()
    b = _run(_brazilian_workflow(spec, el), folder, spec.backend)
    r = b["results"]["brazilian"]
    T = float(r["tensile_strength"])
    return {"tensile_strength": T, "over_target": T / float(spec.targets["Tu"]),
            "crack_start_offset": r.get("crack_start_offset"),
            "stopped_by": r.get("stopped_by"), "wall_time_s": time.perf_counter() - t0}


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
    (the material block), ``history.csv``, ``convergence.png``, ``iterations/NN/`` and
    ``brazilian/`` (the check of the result, summary key ``brazilian``) into ``out_dir``.
    ``progress(i, record)`` is called after each iteration; ``measure_fn(spec, element,
    folder)`` replaces :func:`measure` (tests use a synthetic response, and then the Brazilian
    check and the reachable-region check are skipped). Raises :class:`UnreachableTarget`
    before the first run when the targets lie outside the charted region and
    ``spec.check_reach`` is on. Returns the summary."""
    if measure_fn is None and spec.check_reach:
        check_reachable(spec)  # before any folder is written
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
    history = []
    reachable = {k: True for k in KEYS}
    notes = []
    us, ys = [], []
    for it in range(1, int(spec.iterations) + 1):
        el = dict(from_unknowns(u, mu), **spec.structure)
        m = measure_fn(spec, el, out / "iterations" / f"{it:02d}")
        y = _outputs(m)
        rel = {k: (m[k] - tg[k]) / tg[k] for k in KEYS}
        rec = {"iteration": it, "element": el, "measured": {k: m[k] for k in KEYS},
               "rel_errors": rel, "nu_abs_error": m["nu"] - tg["nu"],
               "wall_time_s": m["wall_time_s"]}
        us.append(u.copy())
        ys.append(y)
        rec["score"] = _score(m, tg, tol, reachable)
        history.append(rec)
        if progress:
            progress(it, rec)
        if rec["score"] <= 1.0:
            break
        u, unreachable = next_unknowns(us, ys, y_t, spec.dim, spec.prefer)
        for key in unreachable:
            reachable[key] = False
        if _score(m, tg, tol, reachable) <= 1.0:  # what is left to match already is
            break
        scores = [_score(r["measured"], tg, tol, reachable) for r in history]
        if it - int(np.argmin(scores)) - 1 >= STALL:
            notes.append(f"stopped at iteration {it}: no better than iteration "
                         f"{int(np.argmin(scores)) + 1} for {STALL} iterations")
            break
    for rec in history:  # judged on what is reachable
        rec["score"] = _score(rec["measured"], tg, tol, reachable)
    best = min(history, key=lambda r: r["score"])
    # a target flagged out of reach on the way but met by the best iteration is reachable
    met = {k for k in KEYS if not reachable[k] and _score(best["measured"], tg, tol,
                                                        {j: j == k for j in KEYS}) <= 1.0}
    if met:
        for k in met:
            reachable[k] = True
        for rec in history:
            rec["score"] = _score(rec["measured"], tg, tol, reachable)
        best = min(history, key=lambda r: r["score"])
    if not reachable["nu"]:
        notes.append(f"nu = {tg['nu']:g} is beyond this packing: with ks / kn at its bound "
                     f"({best['element']['ks_per_d'] / best['element']['kn_per_d']:.3g}) it "
                     f"measures nu = {best['measured']['nu']:.3g}; E, Tu and Cu are matched")
    if not (reachable["Tu"] and reachable["Cu"]):
        other = "Tu" if spec.prefer == "Cu" else "Cu"
        el_b = best["element"]
        rho_b = el_b["fs0_per_d2"] / (el_b["kn_per_d"] * el_b["xb_per_d"])
        notes.append(f"Cu / Tu = {tg['Cu'] / tg['Tu']:.3g} is beyond what the bond law gives "
                     f"this packing: with the bonds' shear strength at "
                     f"{rho_b:.3g} x the tensile (search bound {RHO_RANGE[1]:g}) it measures "
                     f"Cu / Tu = {best['measured']['Cu'] / best['measured']['Tu']:.3g}. "
                     f"{spec.prefer} is matched (prefer = {spec.prefer}), {other} is what the "
                     "packing gives with it; more shear strength does not help: failure is by "
                     "tensile bond breakage (PHYSICS.md section 2, 'random packings')")
    brazilian = None
    if measure_fn is measure:  # the synthetic responses of the tests have no disc
        brazilian = brazilian_check(spec, best["element"], out / "brazilian")
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
        "brazilian": brazilian,
        "notes": notes,
        "specimen": {"d_mean": spec.d_mean, "ucs_size": list(spec.ucs_size),
                     **spec.structure,
                     "disc_diameter": spec.disc_diameter, "distri_rate": spec.distri_rate,
                     "seed": spec.seed, "strain_rate": spec.strain_rate,
                     "max_strain": spec.max_strain, "tensile_test": "direct_tension"},
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
    block = {
        "element": {k: (v if isinstance(v, str) else float(v))
                    for k, v in summary["element"].items()},
        "measured": {k: float(v) for k, v in summary["measured"].items()},
        "rel_errors": {k: round(float(v), 5) for k, v in summary["rel_errors"].items()},
        "converged": bool(summary["converged"]),
        "iterations": int(summary["iterations"]),
        "notes": list(summary["notes"]),
        "specimen": summary["specimen"],
    }
    b = summary.get("brazilian")
    if b:
        block["brazilian"] = {"tensile_strength": float(b["tensile_strength"]),
                              "over_target": round(float(b["over_target"]), 4),
                              "crack_start_offset": (None if b["crack_start_offset"] is None
                                                     else round(float(b["crack_start_offset"]),
                                                                3))}
    return {f"{summary['dim']}d": block}


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
