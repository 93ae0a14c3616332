"""Virtual lab tests as workflow pieces: the ``specimen`` model and the ``uniaxial`` step.

* model ``specimen``: a packed, cut and cemented specimen (:func:`geodem.build.specimen.
  make_specimen`, rock properties converted by ``macro_to_micro`` at ``d_mean``) with platen
  groups ``bottom`` and ``top``: the elements within ``platen_depth`` x ``d_mean`` of the lower
  and upper faces along the loading axis (the last axis: y in 2-D, z in 3-D); the rest is
  ``specimen``.
* step ``uniaxial``: UCS test. Bottom platen fixed along the loading axis, top platen moved
  kinematically down at ``strain_rate`` x height, MatDEM's standard damping eta_c / N on (N =
  elements along the height), until the axial stress has dropped below ``drop`` x the peak after
  the peak, or the axial strain reaches ``max_strain``. Recorded every sample (compression
  positive, :mod:`geodem.measure` convention):

  - axial stress = mean of the top and bottom platen reactions / area; area = width^(dim-1),
    times a thickness in 2-D: ``thickness`` (default d_mean, the thickness the 2-D element
    masses use); width = the specimen's extent across the loading axis from surface to surface
    (outermost element surfaces; the widths between the outermost centres are smaller by
    about one diameter and made every stress 4 % (2-D, 20 across) to 19 % (3-D, 10 across)
    too high);
  - axial strain = (h0 - h) / h0, h = distance between the mean loading-axis coordinates of the
    platens (h0 from the built positions);
  - lateral strain = -(w - w0) / w0 (negative when bulging, compression positive) with w the
    mean lateral extent of the middle third of the height: twice the mean distance of its
    elements from their centre, per lateral axis, averaged over the lateral axes;
  - crack counts by type.

  Results: ``E`` (:func:`~geodem.measure.youngs_modulus`, 10-50 % of the peak), ``nu``
  (same window); with ``fit: elastic`` both over the part of that window below the
  crack-initiation stress (:func:`~geodem.measure.elastic_window`: where 0.5 % of the bonds
  have broken); both fits are in ``window`` and ``elastic``; ``ucs``, ``peak_strain``, ``cracks_tensile``, ``cracks_shear`` (also at the top
  of summary.json); the curve goes to ``uniaxial_curve.csv`` and the picture to
  ``stress_strain.png``.
"""
from __future__ import annotations

import csv
import math
from typing import Literal, Optional

import numpy as np

from geodem.cases.common import PlatenTest
from geodem.workflow.material import box_size_problems, material_problems, specimen_material
from geodem.workflow.models import BuildError, BuiltModel, state_bytes_per_element
from geodem.workflow.schema import (
    F,
    Int,
    ModelBase,
    Name,
    register_model,
    register_step,
)

CURVE = "uniaxial_curve.csv"
#: how the UCS test fits E and nu (the step's ``fit``; calibrate and rock take the same)
FITS = ("window", "elastic")
COLUMNS = ("step", "time", "axial_strain", "axial_stress", "lateral_strain", "cracks_tensile",
           "cracks_shear", "cracks_total")


@register_model("specimen")
class Specimen(ModelBase):
    """A bonded random specimen (box) from rock properties: packed, cut, cemented and balanced
    (``geodem.build.specimen.make_specimen``), with platen groups ``bottom`` and ``top`` (the
    elements within ``platen_depth`` d_mean of the faces along the last axis)."""

    size_field = "size"
    example = {"type": "specimen", "dim": 2, "size": [0.06, 0.12], "d_mean": 0.006,
               "material": "rock"}
    dim: Literal[2, 3] = F(2, description="Dimension")
    shape: Literal["box"] = F("box", description="Specimen shape (box)")
    size: list[float] = F(..., unit="m", min_length=2, max_length=3,
                          description="Box edge lengths (dim values; the last is the height, "
                                      "the loading axis)")
    d_mean: float = F(..., unit="m", gt=0, description="Mean element diameter")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing (make_specimen "
                                                        "distri_rate)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    material: Name = F(..., description="Material name (rock properties E, nu, Tu, Cu, mu_i, "
                                        "rho)")
    platen_depth: float = F(1.0, gt=0, le=5, description="Platen layer depth in d_mean")
    min_bonds: Int = F(0, ge=0, le=6, description="Remove the elements left with fewer intact "
                                                   "bonds than this, and balance again "
                                                   "(0: keep every element)")

    def n_elements(self):
        vol = float(np.prod(self.size))
        el = math.pi / 4 * self.d_mean ** 2 if self.dim == 2 else math.pi / 6 * self.d_mean ** 3
        return max(1, int((0.84 if self.dim == 2 else 0.63) * vol / el))

    def bytes_per_element(self):
        return state_bytes_per_element(self.dim, 16 if self.dim == 3 else 8) + 3000

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        return ["all", "specimen", "bottom", "top"]

    def n_across(self):
        return float(self.size[-1] / self.d_mean) if self.size else 1.0

    def check(self, cfg):
        out = box_size_problems(self.size, self.dim, self.d_mean)
        return out + material_problems(cfg, self.material, self.dim)

    def build(self, cfg):
        from geodem.build.specimen import cut_section, make_specimen, packing_notes
        from geodem.core import groups as grp

        sm = specimen_material(cfg, self.material, self.dim, self.d_mean)
        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        try:
            st, rep = make_specimen(self.shape, self.size, self.d_mean, self.distri_rate,
                                    sm.material, self.dim, seed, element=sm.element)
        except ValueError as exc:
            raise BuildError(("size",), str(exc)) from None
        removed = 0
        if self.min_bonds:
            # a loose element (a rattler of the packing, or one that lost its bonds while
            # cementing) is held by nothing: pore pressure, for one, pushes it out of the box
            from geodem.cases.brazilian import prune_loose

            st, removed = prune_loose(st, self.min_bonds, n_across=self.n_across())
            if st.n == 0:
                raise BuildError(("min_bonds",), f"no element has {self.min_bonds} intact bonds; "
                                                 f"allowed: a lower min_bonds")
        ax = self.dim - 1
        lo, hi = st.x[:, ax].min(), st.x[:, ax].max()
        depth = self.platen_depth * self.d_mean
        grp.add_group(st, "bottom", st.x[:, ax] <= lo + depth)
        grp.add_group(st, "top", st.x[:, ax] >= hi - depth)
        info = {"diameter": self.d_mean, "size": list(self.size), "material": sm.label,
                "material_warnings": list(sm.warnings) + packing_notes(rep),
                "specimen_report": {k: v for k, v in rep.items() if k != "packing"}}
        cut = cut_section(rep, self.size)
        if cut is not None:
            info["cut_section"] = cut
        if self.min_bonds:
            info["loose_removed"] = removed
        return BuiltModel(st, st.x.copy(), self.n_across(), info)


# ============================================================================ uniaxial
def _lateral_sets(x, ax, d):
    """Indices of the elements in the middle third of the height (loading axis ``ax``)."""
    lo, hi = x[:, ax].min(), x[:, ax].max()
    h = hi - lo
    return np.flatnonzero((x[:, ax] > lo + h / 3) & (x[:, ax] < hi - h / 3))


def _extent(x, mid):
    """Mean lateral extent of the elements ``mid`` per lateral axis: twice their mean distance
    from their centre (a uniform lateral strain scales it by 1 + strain; averaged over every
    element of the band, so it is far less noisy than the outermost elements)."""
    lat = x[mid, :-1]
    return 2.0 * np.abs(lat - lat.mean(axis=0)).mean(axis=0)


@register_step("uniaxial")
class Uniaxial(PlatenTest):
    """Uniaxial compression (UCS): bottom platen fixed along the loading axis, top platen
    moved at ``strain_rate`` with the standard damping on, until the stress falls below
    ``drop`` x peak after the peak or the strain reaches ``max_strain``. Needs the groups
    ``bottom`` and ``top`` (model ``specimen``; a ``lattice_block`` with them works too). Adds E, nu, ucs,
    peak_strain, cracks_tensile and cracks_shear to summary.json; writes uniaxial_curve.csv and
    stress_strain.png."""

    example = {"kind": "uniaxial", "max_strain": 0.0001}
    strain_rate: float = F(0.2, unit="1/s", gt=0, le=100,
                           description="Axial strain rate of the top platen (quasi-static "
                                       "when the time to the peak is many wave transit times)")
    max_strain: float = F(0.01, gt=0, le=0.5, description="Stop at this axial strain")
    drop: float = F(0.7, gt=0, lt=1, description="Stop when the stress falls below drop x "
                                                 "peak after the peak")
    fit_window: list[float] = F([0.1, 0.5], min_length=2, max_length=2,
                                description="E and nu are fitted between these fractions of "
                                            "the peak stress (pre-peak)")
    fit: Literal[FITS] = F(
        "elastic", description="'elastic': E and nu over the part of fit_window below the "
                               "crack-initiation stress (the last stress before "
                               "crack_fraction of the bonds has broken), the constants of "
                               "the intact rock; 'window': over the whole fit_window, cracks "
                               "and all. Both are in the results ('window', 'elastic')")
    crack_fraction: float = F(0.005, gt=0, lt=1,
                              description="Fraction of the bonds broken that marks crack "
                                          "initiation")
    plot: bool = F(True, description="Draw stress_strain.png (needs matplotlib)")

    def check(self, cfg, groups):
        out = super().check(cfg, groups)
        lo, hi = self.fit_window
        if not 0.0 <= lo < hi <= 1.0:
            out.append((("fit_window",), f"[{lo:g}, {hi:g}]: allowed 0 <= lo < hi <= 1 "
                                         "(fractions of the peak stress)"))
        return out

    def execute(self, ctx):
        from geodem.core import groups
        from geodem import measure

        st, ax, d, ref, top, bot, h0, height, area = self.platens(ctx)
        dim = st.dim
        sets = _lateral_sets(ref, ax, d)
        w0 = _extent(ref, sets)
        path = ctx.out_dir / CURVE
        rows = []
        if ctx.resumed and path.exists():
            with open(path) as f:
                rows = [[int(v) if k in (0, 5, 6, 7) else float(v) for k, v in enumerate(r)]
                        for r in list(csv.reader(f))[1:] if int(r[0]) <= st.step]
        if not ctx.resumed:
            self.start_loading(ctx, -1.0, height, d)
        with open(path, "w", newline="") as f:
            csv.writer(f).writerow(COLUMNS)
            csv.writer(f).writerows(rows)
        total = self.planned_steps(ctx.plan)
        chunk = max(1, total // self.samples)
        done = (st.step - ctx.start_step) // chunk * chunk  # same sample grid on resume
        peak = max((r[3] for r in rows), default=0.0)
        ipeak = int(np.argmax([r[3] for r in rows])) if rows else 0
        reason = "max_strain"
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(done)
            s = ctx.state
            f_ax = 0.5 * (groups.reaction(s, "top")[ax] - groups.reaction(s, "bottom")[ax])
            h = s.x[top, ax].mean() - s.x[bot, ax].mean()
            lat = -float(np.mean((_extent(s.x, sets) - w0) / w0))  # compression +, bulging -
            log = ctx.sim.crack_log()
            ct, cs = int((log["type"] == 1).sum()), int((log["type"] == 2).sum())
            row = [s.step, s.time, (h0 - h) / h0, f_ax / area, lat, ct, cs, len(log)]
            rows.append(row)
            with open(path, "a", newline="") as fh:
                csv.writer(fh).writerow(row)
            if row[3] > peak:
                peak, ipeak = row[3], len(rows) - 1
            if len(rows) - ipeak >= 3 and len(rows) >= 10 and row[3] < self.drop * peak:
                reason = "drop"
                break
        a = np.array(rows, float)
        eps, sig, lat = a[:, 2], a[:, 3], a[:, 4]
        run = np.maximum.accumulate(eps)  # the fits need strictly increasing strain
        keep = np.concatenate([[True], eps[1:] > run[:-1]])
        e_, s_, l_ = eps[keep], sig[keep], lat[keep]
        ucs, peak_strain = measure.peak(e_, s_)
        fits, fit_error = {}, None
        bonds = ctx.sim.bonded_count() + len(ctx.sim.crack_log())  # every bond the test had
        try:
            lo, hi, sigma_ci = measure.elastic_window(s_, a[keep, 7], bonds, self.fit_window,
                                                      self.crack_fraction)
            for name, window in (("window", tuple(self.fit_window)), ("elastic", (lo, hi))):
                fits[name] = {"E": measure.youngs_modulus(e_, s_, window),
                              "nu": measure.poisson_ratio(e_, l_, window, stress=s_),
                              "fit_window": [float(w) for w in window]}
            fits["elastic"]["crack_initiation_stress"] = sigma_ci
        except ValueError as exc:  # too few points before the peak: reported, not fatal
            fit_error = str(exc)
            ctx.log(f"E / nu not fitted: {exc}")
        used = fits.get(self.fit, {})
        E, nu = used.get("E"), used.get("nu")
        window = used.get("fit_window", self.fit_window)
        ct, cs = int(a[-1, 5]), int(a[-1, 6])
        res = {"E": E, "nu": nu, "fit": self.fit, "fit_window": window, **fits,
               "bonds": int(bonds), "ucs": ucs, "peak_strain": peak_strain,
               "cracks_tensile": ct, "cracks_shear": cs, "final_strain": float(eps[-1]),
               "final_stress": float(sig[-1]), "stopped_by": reason, "samples": len(rows),
               "area": area, "height": float(h0), "strain_rate": self.strain_rate}
        if fit_error:
            res["fit_error"] = fit_error
        ctx.summary.update({k: res[k] for k in ("E", "nu", "ucs", "peak_strain",
                                                 "cracks_tensile", "cracks_shear")})
        ctx.log(f"UCS test: E = {E or math.nan:.4g} Pa, nu = {nu or math.nan:.3g}, UCS = {ucs:.4g} Pa at strain "
                f"{peak_strain:.4g}; cracks {ct} tensile, {cs} shear; stopped by {reason}")
        if self.plot and ctx.cfg.outputs.plots and E is not None:
            st = ctx.state
            log = ctx.sim.crack_log()
            pos = 0.5 * (st.x[log["i"]] + st.x[log["j"]]) if len(log) else np.zeros((0, dim))
            res["plot"] = ctx.plot("stress_strain.png", lambda p: _plot(
                p, e_, s_, E, ucs, peak_strain, pos, log["type"], st.x, st.r, window))
        return res


def _plot(path, eps, sig, E, ucs, peak_strain, pos, types, x, r, window=(0.1, 0.5)):
    from geodem.workflow.animation import label_map, legend_outside

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:  # noqa: BLE001 - the plot is optional
        return None
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 5), gridspec_kw={"width_ratios": [3, 2]})
    a1.plot(eps, sig / 1e6, "C0-", lw=1.2, label="geodem")
    ip = int(np.argmax(sig))
    lo, hi = window
    win = np.flatnonzero((sig[:ip + 1] >= lo * ucs) & (sig[:ip + 1] <= hi * ucs))
    b = float(np.mean(sig[win] - E * eps[win])) if win.size else 0.0
    e_fit = np.linspace(max(0.0, -b / E), peak_strain, 10)
    a1.plot(e_fit, (E * e_fit + b) / 1e6, "k--", lw=0.8,
            label=f"E = {E / 1e9:.3g} GPa (fit, {100 * lo:.0f}-{100 * hi:.0f} % of the peak)")
    a1.plot([peak_strain], [ucs / 1e6], "r*", ms=12, label=f"UCS = {ucs / 1e6:.3g} MPa")
    a1.set_ylim(min(0.0, sig.min() / 1e6), 1.15 * ucs / 1e6)
    a1.set_xlabel("axial strain [-]")
    a1.set_ylabel("axial stress [MPa]")
    a1.legend(loc="best")
    a1.set_title("uniaxial compression")
    a2.scatter(x[:, 0], x[:, -1], s=2, c="0.8")
    for code, col, name in ((1, "C0", "tensile"), (2, "C3", "shear"), (0, "C2", "joint")):
        sel = types == code
        if sel.any():
            a2.scatter(pos[sel, 0], pos[sel, -1], s=6, c=col, label=f"{name} ({sel.sum()})")
    a2.set_aspect("equal")
    a2.set_title("cracks")
    label_map(a2, ("x", "z" if x.shape[1] == 3 else "y"), fontsize=8)
    legend_outside(a2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
