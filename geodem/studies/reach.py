"""The reachable region of a packing: which (Cu / Tu, nu) a calibration can meet.

The calibration's two exact scalings (module :mod:`geodem.studies.calibrate`) leave nu and
Cu / Tu functions of the shape variables only: ``s = ks / kn`` and ``rho_s = fs0 / (kn xb)``
(per size), at a fixed micro-structure and friction ``mu`` (the charts use
:data:`CHARTED_MU`, 0.25; more friction raises Cu, so for another mu the bounds are
approximate).
So the region is a map of that
plane: :func:`reach_study` measures nu and Cu / Tu (UCS and direct tension of the calibration
specimen, as :func:`geodem.studies.calibrate.measure`) on a grid of ``(s, rho_s)`` and writes
``reach.json`` and ``reach.png``. The shipped charts (``geodem/studies/reach_2d.json``,
``reach_3d.json``, regenerated with ``geodem study reach --dim D -o DIR --save``) let
``geodem calibrate`` refuse a target outside the region before the first iteration
(:func:`outside_region`), with the measured bound.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

__all__ = ["reach_study", "outside_region", "shipped_chart", "save_chart", "plot_chart",
           "DEFAULT_GRID"]

DEFAULT_S = (0.15, 0.25, 0.35, 0.45, 0.6, 0.8, 1.2)
DEFAULT_RHO = (0.1, 0.3, 1.0, 3.0, 10.0, 50.0)
#: the 3-D grid (a 3-D point costs about 4 x a 2-D one; below ks / kn 0.25 the 3-D packing is
#: near its mechanism)
DEFAULT_GRID = {2: (DEFAULT_S, DEFAULT_RHO),
                3: ((0.25, 0.33, 0.41, 0.53, 0.8, 1.2), (0.5, 2.0, 8.0, 50.0))}
#: a fitted nu at or above this (2-D, 3-D) is no elastic solid: the packing is a mechanism
#: there (isotropic elasticity needs nu < 1 in 2-D and nu < 1/2 in 3-D)
NU_LIMIT = {2: 1.0, 3: 0.5}
#: the charted micro-structure: the calibration's default (isotropic packing, bond gap 0.01,
#: no strength scatter); other structures are not refused up front
CHARTED_STRUCTURE = {"packing": "isotropic"}


#: the UCS loading rate of the charted grid [1/s]: its elements span strengths and stiffnesses
#: far from the sandstone's targets, so the grid keeps the slowest calibration rate (the one
#: the stored charts were measured at) rather than one from the targets
REACH_STRAIN_RATE = 0.2


def _base_element(dim: int) -> dict:
    """Levels (kn, F_t) of the library sandstone's calibration: the region does not depend
    on them (exact scalings), only on the shape variables."""
    from geodem.materials_library import load_material

    return dict(load_material("sandstone").calibrated[f"{dim}d"]["element"])


#: element friction the charts are measured at: the lattice conversion of the sandstone's
#: mu_i 0.7 (calibrations with the friction angle reach 0.26-0.46 in the library)
CHARTED_MU = 0.25481189610327715


def reach_study(dim: int, out_dir, s_values=None, rho_values=None, backend=None,
                progress=None, mu: float = CHARTED_MU) -> dict:
    """Measure nu and Cu / Tu over the ``(s, rho_s)`` grid on the calibration specimen of
    ``dim`` (isotropic packing, seed 0). A point whose specimen cannot be measured (a
    mechanism near ``s = 0``: no E / nu fit, or a fitted nu beyond :data:`NU_LIMIT`) is kept
    with its error and left out of the region. The grid defaults to :data:`DEFAULT_GRID`.
    Returns the record written to ``reach.json``."""
    from geodem.studies.calibrate import CalibrationSpec, measure
    from geodem.materials_library import load_material

    s_values = DEFAULT_GRID[dim][0] if s_values is None else s_values
    rho_values = DEFAULT_GRID[dim][1] if rho_values is None else rho_values
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    base = dict(_base_element(dim), mu=float(mu))
    targets = load_material("sandstone").values()
    size = (0.1, 0.1, 0.2) if dim == 3 else (0.1, 0.2)
    spec = CalibrationSpec(targets=targets, name="reach", dim=dim,
                           d_mean=0.01 if dim == 3 else 0.005, ucs_size=size, iterations=1,
                           backend=backend, structure=dict(CHARTED_STRUCTURE),
                           strain_rate=REACH_STRAIN_RATE)
    ft = base["kn_per_d"] * base["xb_per_d"]
    points = []
    t0 = time.perf_counter()
    for s in s_values:
        for rho in rho_values:
            el = dict(base, ks_per_d=float(s) * base["kn_per_d"], fs0_per_d2=float(rho) * ft,
                      **CHARTED_STRUCTURE)
            p = {"s": float(s), "rho_s": float(rho)}
            try:
                m = measure(spec, el, out / f"s{s:g}_rho{rho:g}")
            except RuntimeError as exc:
                p["error"] = str(exc).splitlines()[0][:300]
            else:
                p.update(_point_fits(m, NU_LIMIT[dim]))
            points.append(p)
            if progress:
                progress(p)
    ok = [p for p in points if "ratio" in p]
    rec = {"dim": dim, "structure": dict(CHARTED_STRUCTURE), "mu": base["mu"],
           "specimen": {"ucs_size": list(size), "d_mean": spec.d_mean, "seed": spec.seed},
           "points": points, "wall_time_s": time.perf_counter() - t0,
           "bounds": _bounds(ok)}
    (out / "reach.json").write_text(json.dumps(rec, indent=2))
    try:
        _plot(out / "reach.png", rec)
        rec["plot"] = "reach.png"
    except ImportError:
        pass
    return rec


def _point_fits(m: dict, nu_limit: float) -> dict:
    """What one measured point contributes: the window fit's ``nu`` and the elastic fit's
    ``nu_elastic`` (the same UCS run below its crack-initiation stress), Cu / Tu, and
    ``crack_initiation`` (that stress / Cu). A fit whose nu reaches ``nu_limit`` is no elastic
    solid and is left out with the reason: ``error`` when the elastic fit says so too (a
    mechanism), ``window_error`` when only the window does (cracks opening from early in the
    loading dilate the specimen; below them it is an elastic solid and counts for
    ``--fit elastic``)."""
    el = m.get("fits", {}).get("elastic") or {}
    if m["nu"] < nu_limit:
        out = {"nu": m["nu"], "E": m["E"]}
    elif el and el["nu"] < nu_limit:
        out = {"window_error": f"window fit nu {m['nu']:.3g} >= {nu_limit:g}: dilated by "
                               f"cracks (E {m['E']:.3g} Pa)"}
    else:
        return {"error": f"mechanism: fitted nu {m['nu']:.3g} >= {nu_limit:g} "
                         f"(E {m['E']:.3g} Pa)"}
    out.update(Cu=m["Cu"], Tu=m["Tu"], ratio=m["Cu"] / m["Tu"], wall_time_s=m["wall_time_s"])
    if el:
        out.update(nu_elastic=el["nu"], E_elastic=el["E"])
        if el.get("crack_initiation_stress"):
            out["crack_initiation"] = el["crack_initiation_stress"] / m["Cu"]
    return out


def _bounds(points) -> dict:
    if not points:
        return {}
    r = [p["ratio"] for p in points]
    out = {"ratio": [min(r), max(r)]}
    for key in ("nu", "nu_elastic"):
        n = [p[key] for p in points if key in p]
        if n:
            out[key] = [min(n), max(n)]
    return out


#: what the shipped chart keeps of each point (nu and Cu / Tu do not depend on the levels);
#: ``nu`` is the UCS test's 10-50 % window fit, ``nu_elastic`` its fit below the
#: crack-initiation stress (the uniaxial step's two fits)
CHART_KEYS = ("s", "rho_s", "nu", "nu_elastic", "ratio", "crack_initiation", "error",
              "window_error")
#: crack initiation below this fraction of Cu is flagged in the chart's picture (rocks crack
#: from about 30-50 % of their peak in the laboratory)
EARLY_CRACKS = 0.3
#: the chart key of each UCS fit
NU_KEY = {"window": "nu", "elastic": "nu_elastic"}


def save_chart(rec: dict, merge: bool = False) -> Path:
    """Store the study record ``rec`` as the shipped chart of its dimension (points trimmed to
    :data:`CHART_KEYS`); with ``merge``, add its points to the shipped chart instead (a point
    of the same ``(s, rho_s)`` replaced; the structure, friction and specimen must be the
    same). Returns the path."""
    chart = {k: rec[k] for k in ("dim", "structure", "mu", "specimen", "bounds")}
    chart["command"] = f"geodem study reach --dim {rec['dim']} -o DIR --save"
    chart["points"] = [{k: p[k] for k in CHART_KEYS if k in p} for p in rec["points"]]
    old = shipped_chart(rec["dim"]) if merge else None
    if old is not None:
        same = ("structure", "mu", "specimen")
        if any(old[k] != chart[k] for k in same):
            raise ValueError(f"cannot merge: the stored chart was measured with another "
                             f"{', '.join(k for k in same if old[k] != chart[k])}")
        new = {(p["s"], p["rho_s"]) for p in chart["points"]}
        chart["points"] = sorted([p for p in old["points"] if (p["s"], p["rho_s"]) not in new]
                                 + chart["points"], key=lambda p: (p["s"], p["rho_s"]))
        chart["bounds"] = _bounds([p for p in chart["points"] if "ratio" in p])
        s_v = ",".join(f"{v:g}" for v in sorted({p["s"] for p in rec["points"]}))
        r_v = ",".join(f"{v:g}" for v in sorted({p["rho_s"] for p in rec["points"]}))
        chart["command"] = (old["command"] + f"; geodem study reach --dim {rec['dim']} --s "
                            f"{s_v} --rho {r_v} -o DIR --save --merge")
    dest = Path(__file__).with_name(f"reach_{rec['dim']}d.json")
    dest.write_text(json.dumps(chart, indent=1) + "\n")
    return dest


def shipped_chart(dim: int) -> dict | None:
    """The committed chart for ``dim`` (None if absent)."""
    path = Path(__file__).with_name(f"reach_{dim}d.json")
    if not path.exists():
        return None
    return json.loads(path.read_text())


def _hull_points(chart: dict, tol_nu: float, tol_ratio: float, key: str = "nu") -> np.ndarray:
    """Measured points in ``(ln ratio, nu)`` (``key``: the fit's nu), each widened by the
    tolerances (a box around every point), so that a target the calibration could still meet
    within tolerance is in."""
    pts = []
    for p in chart["points"]:
        if "ratio" not in p or key not in p:
            continue
        x, y = math.log(p["ratio"]), p[key]
        for dx in (-tol_ratio, tol_ratio):
            for dy in (-tol_nu, tol_nu):
                pts.append((x + dx, y + dy))
    return np.array(pts)


def same_structure(structure: dict, charted: dict) -> bool:
    """Whether the micro-structure ``structure`` (keys set to None: not given) is the one a
    chart was measured on."""
    return {k: v for k, v in structure.items() if v is not None} == charted


def outside_region(targets: dict, dim: int, structure: dict, tolerances: dict,
                   chart: dict | None = None, fit: str = "window") -> str | None:
    """Why ``targets`` (``nu``, ``Cu``, ``Tu``) lie outside the charted region of ``dim``, with
    the measured bounds; None when inside, or when no chart applies (another micro-structure,
    no chart shipped, no points of the UCS ``fit``'s nu). Inside means: within the convex hull
    of the measured ``(ln Cu/Tu, nu)`` points widened by the tolerances."""
    from scipy.spatial import Delaunay

    chart = shipped_chart(dim) if chart is None else chart
    if chart is None or not same_structure(structure, chart["structure"]):
        return None
    tol_r = math.log1p(tolerances["Cu"] + tolerances["Tu"])
    key = NU_KEY[fit]
    hull = _hull_points(chart, tolerances["nu"], tol_r, key)
    if len(hull) < 4:
        return None
    ratio = float(targets["Cu"]) / float(targets["Tu"])
    nu = float(targets["nu"])
    tri = Delaunay(hull)
    if tri.find_simplex(np.array([[math.log(ratio), nu]]))[0] >= 0:
        return None
    b = chart["bounds"]
    # the hull's extent in Cu / Tu at the target's nu (and in nu at its Cu / Tu)
    xs = np.linspace(hull[:, 0].min(), hull[:, 0].max(), 400)
    at_nu = xs[tri.find_simplex(np.column_stack([xs, np.full_like(xs, nu)])) >= 0]
    ys = np.linspace(hull[:, 1].min(), hull[:, 1].max(), 400)
    at_r = ys[tri.find_simplex(np.column_stack([np.full_like(ys, math.log(ratio)), ys])) >= 0]
    span = []
    if at_nu.size:
        span.append(f"at nu {nu:.2f} it reaches Cu / Tu {math.exp(at_nu.min()):.3g}-"
                    f"{math.exp(at_nu.max()):.3g}")
    if at_r.size:
        span.append(f"at Cu / Tu {ratio:.3g} nu {at_r.min():.2f}-{at_r.max():.2f}")
    span = ("; " + ", ".join(span) + " (within tolerance)") if span else ""
    return (f"Cu / Tu = {ratio:.3g} with nu = {nu:.3g} is outside what the "
            f"{dim}-D {chart['structure']['packing']} packing reaches: measured Cu / Tu "
            f"{b['ratio'][0]:.3g}-{b['ratio'][1]:.3g}, nu ({fit} fit) {b[key][0]:.2f}-"
            f"{b[key][1]:.2f}{span} (geodem study reach; docs/calibration.md, 'Reachable "
            f"region')")


def plot_chart(path, rec):
    """The (Cu / Tu, nu) chart of a study record or a stored chart as a PNG at ``path``."""
    _plot(path, rec)
    return path


def _plot(path, rec):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [p for p in rec["points"] if "nu" in p]
    fig, ax = plt.subplots(figsize=(8.6, 4.6))
    rhos = sorted({p["rho_s"] for p in ok})
    for s in sorted({p["s"] for p in ok}):
        sel = sorted((p for p in ok if p["s"] == s), key=lambda p: p["rho_s"])
        ax.plot([p["ratio"] for p in sel], [p["nu"] for p in sel], "o-", ms=4,
                label=f"ks/kn = {s:g}")
    for rho in rhos:
        sel = sorted((p for p in ok if p["rho_s"] == rho), key=lambda p: p["s"])
        ax.plot([p["ratio"] for p in sel], [p["nu"] for p in sel], ":", color="0.6", lw=0.8)
        if sel:
            ax.annotate(f"rho_s {rho:g}", (sel[-1]["ratio"], sel[-1]["nu"]), fontsize=7,
                        textcoords="offset points", xytext=(3, -9), color="0.4")
    el = [p for p in rec["points"] if "nu_elastic" in p]
    early = [p for p in el if p.get("crack_initiation", 1.0) < EARLY_CRACKS]
    late = [p for p in el if p not in early]
    for sel, colour, label in ((late, "k", "elastic fit (below crack initiation)"),
                               (early, "C3", f"elastic fit, cracks before "
                                             f"{100 * EARLY_CRACKS:.0f} % of Cu")):
        if sel:
            ax.scatter([p["ratio"] for p in sel], [p["nu_elastic"] for p in sel], s=22,
                       facecolors="none", edgecolors=colour, lw=0.7, label=label)
    ax.add_patch(plt.Rectangle((5, 0.05), 25, 0.30, fill=False, ls="--", color="k", lw=0.8))
    ax.text(5.2, 0.355, "goal: Cu/Tu 5-30, nu 0.05-0.35", fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("Cu / Tu (UCS / direct tension)")
    ax.set_ylabel("nu: 10-50 % window (dots), elastic fit (circles)")
    ax.set_title(f"reachable region, {rec['dim']}-D isotropic packing (mu {rec['mu']:.2f})")
    ax.legend(fontsize="x-small", loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


#: The friction angle of 3-D translating elements on the charted packing (isotropic, bond gap
#: 0.01, no strength scatter): ``(ks / kn, mu, phi [deg], packings, rock)``, each the
#: calibration's two-stage triaxial test (sigma_3 = 0 and 0.133 Cu, d = 0.01 m) on a library
#: record's element parameters with its ``mu`` replaced: ``geodem rock FILE --dim 3 --friction
#: -o DIR`` (one packing, seed 0), or an iteration of ``geodem calibrate FILE --dim 3 --friction
#: --packings 3`` (three). Measured 2026-12-05, docs/calibration.md "Friction angle in 3-D".
#: phi follows mu steeply on stiff shear springs and hardly on soft ones (the nu 0.3 rocks):
#: there the bonds' tensile failure, suppressed by confinement, sets phi, not sliding. At the
#: top of the range no angle is measured: the 3-D granite's elements (ks / kn 0.182) at mu 1.0
#: made Cu +66 % and a confined stage that hardened to the strain limit without a peak, and so
#: did the limestone's (about 0.17) at mu 0.60.
FRICTION_POINTS = {3: (
    (0.095, 0.05, 28.8, 1, "stiff clay"),
    (0.102, 0.05, 28.3, 1, "mudstone"),
    (0.103, 0.143, 32.6, 3, "mudstone"),
    (0.103, 0.217, 33.2, 3, "mudstone"),
    (0.325, 0.05, 16.0, 1, "sandstone"),
    (0.325, 0.255, 30.0, 1, "sandstone"),
    (0.302, 0.343, 35.5, 3, "sandstone"),
    (0.172, 0.430, 41.0, 3, "limestone"),
    (0.174, 0.384, 39.8, 3, "limestone"),
)}
# Not in the points, so that the prior stays the one the stored 3-D calibrations started from
# (a point added moves every calibration's first mu; tests/validation/
# test_library_calibration.py finds the marble's record again): the marble's calibration,
# ks / kn 0.169, 38.7 deg at mu 0.389 (three packings), 1.3 deg below the fit there.

#: the structure the friction points were measured on
FRICTION_STRUCTURE = {"packing": "isotropic"}


class FrictionModel:
    """``phi(s, mu) = a + b ln mu + c s + d s ln mu + e s^2`` [deg] (s = ks / kn): its slope in
    ln mu, ``b + d s``, grows with the shear springs, and at a fixed mu phi peaks at middling
    springs (the limestone's 41 deg at mu 0.43, ks / kn 0.17, above both the mudstone's and
    the sandstone's)."""

    def __init__(self, a, b, c, d, e):
        self.a, self.b, self.c, self.d, self.e = (float(v) for v in (a, b, c, d, e))

    def phi(self, s: float, mu: float) -> float:
        return self.a + self.c * s + self.e * s * s + self.slope(s) * math.log(mu)

    def slope(self, s: float) -> float:
        """d phi / d ln mu [deg] at ``s``."""
        return self.b + self.d * s

    def mu_for(self, s: float, phi: float) -> float:
        """The contact friction that gives ``phi`` at ``s`` (unclipped)."""
        return math.exp((phi - self.a - self.c * s - self.e * s * s) / self.slope(s))


def _friction_points(dim: int, structure: dict):
    pts = FRICTION_POINTS.get(dim)
    if not pts or not same_structure(structure, FRICTION_STRUCTURE):
        return None
    return [np.array([p[k] for p in pts], float) for k in range(3)]


def friction_model(dim: int, structure: dict) -> FrictionModel | None:
    """:class:`FrictionModel` fitted to :data:`FRICTION_POINTS` by least squares, or None when
    no points apply to ``dim`` and ``structure``. A prior for the calibration, not a bound."""
    pts = _friction_points(dim, structure)
    if pts is None:
        return None
    s, mu, phi = pts
    A = np.column_stack([np.ones_like(s), np.log(mu), s, s * np.log(mu), s * s])
    return FrictionModel(*np.linalg.lstsq(A, phi, rcond=None)[0])


def friction_floor(s: float, dim: int, structure: dict, mu_min: float) -> float | None:
    """The friction angle [deg] measured at the lowest contact friction ``mu_min``,
    interpolated linearly in ``s`` between the points measured there (clamped at the ends), or
    None when none was."""
    pts = _friction_points(dim, structure)
    if pts is None:
        return None
    at = np.isclose(pts[1], mu_min)
    if not at.any():
        return None
    order = np.argsort(pts[0][at])
    return float(np.interp(s, pts[0][at][order], pts[2][at][order]))


def s_for_nu(nu: float, dim: int, structure: dict, fit: str = "elastic",
             chart: dict | None = None) -> float | None:
    """The spring ratio ``ks / kn`` at which the charted packing gives ``nu`` (the mean nu of
    the ``fit`` over each charted ks / kn, interpolated; clamped to the chart), or None when no
    chart applies."""
    chart = shipped_chart(dim) if chart is None else chart
    if chart is None or not same_structure(structure, chart["structure"]):
        return None
    key = NU_KEY[fit]
    by_s = {}
    for p in chart["points"]:
        if p.get(key) is not None and math.isfinite(p[key]):
            by_s.setdefault(p["s"], []).append(p[key])
    ss = np.array(sorted(by_s))
    nus = np.array([np.mean(by_s[s]) for s in ss])  # falls with s
    return float(np.interp(-nu, -nus, ss))


def friction_out_of_reach(targets: dict, dim: int, structure: dict, tolerances: dict,
                          mu_range: tuple, fit: str = "elastic") -> str | None:
    """Why the friction angle ``atan(mu_i)`` lies below what the lowest contact friction
    ``mu_range[0]`` gives elements whose spring ratio meets the target nu (:func:`s_for_nu`,
    :func:`friction_floor`, less the phi tolerance); None when above, or not measured. No upper
    bound: at the top no angle was measured (a 3-D granite at mu 1.0 and a limestone at 0.6
    hardened in their confined stages instead of peaking), and the calibration finds a target
    beyond it out by itself."""
    s = s_for_nu(float(targets["nu"]), dim, structure, fit)
    lo = None if s is None else friction_floor(s, dim, structure, mu_range[0])
    if lo is None:
        return None
    phi = math.degrees(math.atan(float(targets["mu_i"])))
    if phi >= lo - float(tolerances["phi"]):
        return None
    return (f"phi = {phi:.1f} deg (mu_i {float(targets['mu_i']):g}) is below what {dim}-D "
            f"translating elements with nu {float(targets['nu']):.2f} (ks / kn {s:.2f}) give "
            f"at the lowest contact friction, mu {mu_range[0]:g}: about {lo:.1f} deg, "
            f"interpolated between the measured points (geodem.studies.reach.FRICTION_POINTS; "
            f"docs/calibration.md, 'Friction angle in 3-D')")
