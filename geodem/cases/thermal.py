"""Thermal workflow pieces: the ``heat`` step and the rod check.

* step ``heat``: couples the thermal field (:class:`geodem.fields.thermal.ThermalField`, equations
  in its module docstring and docs/thermal.md) to the model, or, when an earlier ``heat`` step
  attached it, updates its parameters and fixed-temperature groups; then advances ``duration``
  seconds of *thermal* time. The thermal clock runs ``time_scale`` times faster than the
  mechanical one (heat diffuses over hours, elastic waves cross a specimen in microseconds): give
  ``nsteps`` (mechanical time steps; ``time_scale = duration / (nsteps dt)``) or ``time_scale``
  (``nsteps = duration / (time_scale dt)``, default ``time_scale = 1``). The step records every
  ``samples``-th of its time steps to ``<name>_temperature.csv``: step, mechanical time, thermal
  time, T min / max / mean [K], bonds broken since the step started, and the mean T of each
  probe group; it draws ``<name>_temperature.png`` (probe temperatures against thermal time; map
  of element temperatures with the cracks) and puts ``T_max``, ``T_min``, ``T_mean``,
  ``thermal_time`` and ``broken_bonds`` (bonds broken during the step) into summary.json. A run
  resumed from a checkpoint finds the field in the checkpoint and does not attach it twice.

* step ``thermal_rod``: the ``heat`` step on a 1-D bonded chain (``lattice_block`` with
  ``counts: [N, 1]``; groups ``hot`` and ``cold`` at its ends, fixed at ``T1`` and ``T2``, the
  rest starting at ``T0 = T_initial``), then a comparison with the Fourier series of the heat
  equation (:func:`geodem.fields.thermal.rod_solution`) at the thermal time reached. The chain is
  a rod of cross-section ``A`` (the contact face of the conductance formula), length ``L`` (the
  distance between the two fixed end elements) and bulk density ``rho_b = m / (A d)``, so its
  diffusivity is ``D = k / (rho_b c) = h d^2 / (m c)``. Result ``rel_error = max_i |T_i -
  T_exact(x_i, t)| / max(|T1 - T0|, |T2 - T0|, |T1 - T2|)`` over the free elements (also
  ``fourier_number = D t / L^2``); profile in ``thermal_rod_profile.csv`` and
  ``thermal_rod.png``.

The heated borehole (workflows/thermal_cracking.yaml) is a composition: model ``scene`` (the
rock's own specimen packing, an empty hole, groups by shape) + steps ``damping`` and ``heat``.
"""
from __future__ import annotations

import csv
import math
from typing import Annotated, Literal, Optional

import numpy as np
from pydantic import Field, model_validator

from geodem.cases.common import append_csv, write_csv
from geodem.workflow.animation import pyplot
from geodem.workflow.schema import (
    DOF_NAMES,
    F,
    Int,
    Name,
    StepBase,
    register_step,
    unknown_group,
)

Kelvin = Annotated[float, Field(gt=0)]
DEPOSIT_NAMES = ("viscous", "break_normal", "break_shear", "friction")
ROD_PROFILE = "thermal_rod_profile.csv"


def _csv_rows(path, step):
    with open(path) as f:
        rows = list(csv.reader(f))[1:]
    # values as they were written: whole numbers (step, broken bonds) stay whole, so the
    # kept rows of a resumed run are the same text
    return [[_number(v) for v in r] for r in rows if int(float(r[0])) <= step]


def _number(text: str):
    try:
        return int(text)
    except ValueError:
        return float(text)






def plane_axes(x) -> list:
    """The two axes of largest extent (2-D: x, y; 3-D: the widest pair), for maps."""
    if x.shape[1] == 2:
        return [0, 1]
    ext = np.ptp(x, axis=0)
    return sorted(np.argsort(-ext)[:2].tolist())


def crack_faces(x, r, i, j, axes=(0, 1)):
    """Crack faces of broken bonds ``(i, j)`` for a map: segments ``(k, 2, 2)`` across each bond
    at its contact point, as long as the smaller element's diameter, in the plane ``axes``."""
    i, j = np.asarray(i, int), np.asarray(j, int)
    if i.size == 0:
        return np.zeros((0, 2, 2))
    xi, xj = x[i][:, list(axes)], x[j][:, list(axes)]
    b = xj - xi
    n = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-300)
    ri, rj = r[i], r[j]
    c = xi + n * (ri / (ri + rj))[:, None] * np.linalg.norm(b, axis=1, keepdims=True)
    t = np.stack([-n[:, 1], n[:, 0]], axis=1) * np.minimum(ri, rj)[:, None]
    return np.stack([c - t, c + t], axis=1)


def temperature_map(ax, x, r, T, crack_xy=None, vmin=None, vmax=None, title=""):
    """Elements coloured by temperature (discs to scale in data units) and cracks (segments
    ``(k, 2, 2)``, see :func:`crack_faces`), counted in the title (a legend inside would cover
    the map, one outside would sit on the colour bar)."""
    from matplotlib.collections import EllipseCollection

    coll = EllipseCollection(2 * r, 2 * r, np.zeros_like(r), units="xy", offsets=x,
                             offset_transform=ax.transData, cmap="inferno")
    coll.set_array(T)
    coll.set_clim(vmin if vmin is not None else T.min(), vmax if vmax is not None else T.max())
    ax.add_collection(coll)
    if crack_xy is not None and len(crack_xy):
        from matplotlib.collections import LineCollection

        # a broken bond is drawn as its crack face: a segment across the bond at the contact
        ax.add_collection(LineCollection(crack_xy, colors="cyan", linewidths=1.6,
                                         label=f"broken bonds ({len(crack_xy)})"))
        title = f"{title}\ncracks (cyan): {len(crack_xy)} broken bonds"
    pad = float(r.max())
    ax.set_xlim(x[:, 0].min() - pad, x[:, 0].max() + pad)
    ax.set_ylim(x[:, 1].min() - pad, x[:, 1].max() + pad)
    ax.set_aspect("equal")
    ax.set_title(title)
    return coll


# ============================================================================ heat
@register_step("heat")
class Heat(StepBase):
    """Couple the thermal field (conduction over bonds and touching contacts, fixed-temperature
    groups, thermal expansion of the radii, optional deposition of mechanical heat) and advance
    ``duration`` seconds of thermal time. Writes <name>_temperature.csv and .png; adds T_max,
    T_min, T_mean, thermal_time and broken_bonds to summary.json."""

    example = {"kind": "heat", "duration": 5.0, "nsteps": 20, "conductivity": 3.0,
               "specific_heat": 800.0, "alpha": 1e-5, "fixed": {"top": 350.0}}
    duration: float = F(..., unit="s", gt=0, description="Thermal time to advance")
    nsteps: Optional[Int] = F(None, ge=1,
                              description="Mechanical time steps over the duration (sets "
                                          "time_scale = duration / (nsteps dt))")
    time_scale: Optional[float] = F(None, gt=0,
                                    description="Thermal seconds per mechanical second (default "
                                                "1 when nsteps is not given)")
    conductivity: float = F(..., unit="W/(m K)", ge=0, description="Thermal conductivity k")
    specific_heat: float = F(..., unit="J/(kg K)", gt=0, description="Specific heat c")
    alpha: float = F(0.0, unit="1/K", ge=-1e-3, le=1e-3,
                     description="Linear thermal expansion coefficient (R = R0 (1 + alpha (T - "
                                 "T_ref)))")
    T_ref: Optional[float] = F(None, unit="K", gt=0,
                               description="Temperature at which the radii are the built radii "
                                           "(default T_initial, else 293.15)")
    T_initial: Optional[float] = F(None, unit="K", gt=0,
                                   description="Initial temperature of every element (default "
                                               "T_ref, else 293.15; ignored when an earlier heat "
                                               "step attached the field)")
    initial: dict[Name, Kelvin] = F({}, description="Initial temperatures of groups [K] (after "
                                                    "T_initial)")
    fixed: dict[Name, Kelvin] = F({}, description="Fixed-temperature groups [K]; the rest is "
                                                  "free, the model's surface insulated")
    ramp: float = F(0.0, unit="s", ge=0,
                    description="Thermal time over which each fixed group goes linearly from "
                                "its present temperature to its value (0: at once)")
    unbonded_factor: float = F(0.0, ge=0, le=1,
                               description="Conductance of a touching unbonded contact / that "
                                           "of a bond")
    area_factor: float = F(1.0, gt=0, le=100,
                           description="Multiplies every conductance (k_eff calibration of "
                                       "random packings)")
    deposit_heat: list[Literal[DEPOSIT_NAMES]] = F(  # type: ignore[valid-type]
        [], description="Mechanical heat deposited into the temperatures: viscous, "
                        "break_normal, break_shear, friction")
    every: Int = F(1, ge=1, le=100000, description="Couple every N mechanical time steps")
    probes: Optional[list[Name]] = F(None, description="Groups whose mean temperature is "
                                                       "recorded (default: every group but all)")
    samples: Int = F(50, ge=2, le=100000, description="Records over the step")
    plot: bool = F(True, description="Draw <name>_temperature.png (needs matplotlib)")

    @model_validator(mode="after")
    def _one(self):
        if self.nsteps is not None and self.time_scale is not None:
            raise ValueError("give at most one of nsteps and time_scale (the other follows "
                             "from duration)")
        return self

    def check(self, cfg, groups):
        out = []
        for key in ("initial", "fixed"):
            for g in getattr(self, key):
                if g not in groups:
                    out.append(((key, g), unknown_group(g, groups)))
        for k, g in enumerate(self.probes or []):
            if g not in groups:
                out.append((("probes", k), unknown_group(g, groups)))
        return out

    def planned_steps(self, plan):
        if self.nsteps is not None:
            return int(self.nsteps)
        ts = self.time_scale if self.time_scale is not None else 1.0
        return max(1, math.ceil(self.duration / (ts * plan.dt) - 1e-9))

    def _time_scale(self, dt):
        if self.nsteps is not None:
            return self.duration / (self.nsteps * dt)
        return self.time_scale if self.time_scale is not None else 1.0

    def field_kwargs(self, dt) -> dict:
        t_ref = self.T_ref if self.T_ref is not None else \
            (self.T_initial if self.T_initial is not None else 293.15)
        return dict(k=self.conductivity, c=self.specific_heat, alpha=self.alpha, T_ref=t_ref,
                    T0=self.T_initial, initial=dict(self.initial), fixed=dict(self.fixed),
                    unbonded_factor=self.unbonded_factor, area_factor=self.area_factor,
                    deposit=list(self.deposit_heat), time_scale=self._time_scale(dt),
                    ramp=self.ramp, every=self.every)

    def _attach(self, ctx):
        from geodem.fields.thermal import ThermalField

        sim = ctx.sim
        kw = self.field_kwargs(sim.state.dt)
        have = [f for f in sim.fields if f.kind == "thermal"]
        if not have:
            f = ThermalField(**kw)
            sim.add_field(f)
            return f
        f = have[0]
        new = ThermalField(**kw)  # validates
        keys = ["k", "c", "alpha", "unbonded_factor", "area_factor", "deposit", "time_scale"]
        if self.T_ref is not None:  # else the field keeps the radii's reference temperature
            keys.append("T_ref")
        for key in keys:
            setattr(f, key, getattr(new, key))
        f.cap[:] = sim.state.m * f.c
        if f.deposit:
            f.qlast[:] = f._heat_sum(sim.state)
            f._e0 = float(sim.state.e0)
        f.set_fixed(new.fixed, new.ramp)
        if new.every != f.every:
            ctx.log(f"the thermal field couples every {f.every} steps (set by the first heat "
                    f"step); every = {new.every} ignored")
        ctx.log("the thermal field was attached by an earlier heat step: its temperatures carry "
                "on (T_initial and initial ignored), parameters and fixed groups updated")
        return f

    def execute(self, ctx):
        from geodem.core import groups

        sim = ctx.sim
        st = ctx.state
        if ctx.resumed and any(f.kind == "thermal" for f in sim.fields):
            field = sim.field("thermal")
        else:
            field = self._attach(ctx)
        probes = self.probes if self.probes is not None else \
            [g for g in st.groups if g != "all"]
        idx = {g: groups.members(st, g) for g in probes}
        name = ctx.step.name
        path = ctx.out_dir / f"{name}_temperature.csv"
        header = ["step", "time", "thermal_time", "T_min", "T_max", "T_mean", "broken_bonds"] + \
            [f"T_{g}" for g in probes]
        rows = _csv_rows(path, st.step) if ctx.resumed and path.exists() else []
        write_csv(path, header, rows)
        if path.name not in ctx.runner.files:
            ctx.runner.files.append(path.name)
        t_start = (ctx.start_step + 0.5) * st.dt

        def broken():
            log = sim.crack_log()
            return log[log["time"] > t_start]

        def record():
            s = sim.state
            T = field.T
            row = [s.step, s.time, field.time, float(T.min()), float(T.max()), float(T.mean()),
                   len(broken())] + [float(T[i].mean()) if i.size else math.nan
                                     for i in idx.values()]
            rows.append(row)
            append_csv(path, row)

        if not rows:
            record()
        total = self.planned_steps(ctx.plan)
        chunk = max(1, total // self.samples)
        done = (st.step - ctx.start_step) // chunk * chunk
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(done)
            record()
        s = ctx.state
        log = broken()
        res = dict(field.summary())
        res.update({"broken_bonds": len(log), "cracks_tensile": int((log["type"] == 1).sum()),
                    "cracks_shear": int((log["type"] == 2).sum()), "time_scale": field.time_scale,
                    "probes": {g: float(field.T[i].mean()) for g, i in idx.items() if i.size}})
        ctx.summary.update({k: res[k] for k in ("T_max", "T_min", "T_mean", "thermal_time",
                                                 "broken_bonds")})
        ctx.log(f"heat: thermal time {field.time:.4g} s ({field.substeps} sub-steps in all), "
                f"T from {res['T_min']:.5g} to {res['T_max']:.5g} K, {len(log)} bonds broken "
                f"during the step")
        if self.plot and ctx.cfg.outputs.plots:
            a = np.array(rows, float)
            ax2 = plane_axes(s.x)
            xy = s.x[:, ax2]
            cxy = crack_faces(s.x, s.r, log["i"], log["j"], ax2) if len(log) else None
            res["plot"] = ctx.plot(f"{name}_temperature.png", lambda p: _plot_heat(
                p, a, header, probes, xy, s.r, field.T, cxy, [DOF_NAMES[k] for k in ax2],
                field.T.min(), field.T.max()))
        return res


def _plot_heat(path, a, header, probes, xy, r, T, cxy, names, vmin, vmax):
    plt = pyplot()
    if plt is None:
        return None
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1, 1.1]})
    t = a[:, 2]
    for k, g in enumerate(probes):
        a1.plot(t, a[:, 7 + k], label=g)
    a1.plot(t, a[:, 4], "k--", lw=0.8, label="max")
    a1.plot(t, a[:, 5], "k:", lw=0.8, label="mean")
    a1.set_xlabel("thermal time [s]")
    a1.set_ylabel("temperature [K]")
    a1.legend(fontsize="small")
    a1.grid(alpha=0.3)
    ext = np.ptp(xy, axis=0) + 2.0 * float(r.max())
    if ext.max() > 4.0 * ext.min():  # a bar or strip: the profile along it reads better
        k = int(np.argmax(ext))
        a2.plot(xy[:, k], T, "C3o", ms=3)
        a2.set_xlabel(f"{names[k]} [m]")
        a2.set_ylabel("temperature [K]")
        a2.set_title(f"temperature at t = {t[-1]:.4g} s")
        a2.grid(alpha=0.3)
    else:
        coll = temperature_map(a2, xy, r, T, cxy, vmin, vmax,
                               f"temperature at t = {t[-1]:.4g} s")
        a2.set_xlabel(f"{names[0]} [m]")
        a2.set_ylabel(f"{names[1]} [m]")
        fig.colorbar(coll, ax=a2, label="T [K]", shrink=0.85)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


# ============================================================================ rod
@register_step("thermal_rod")
class ThermalRod(Heat):
    """The heat step on a 1-D bonded chain (lattice_block counts [N, 1]; groups hot and cold at
    its ends, held at T1 and T2 by fixed), then a comparison with the Fourier series of the
    heat equation at the thermal time reached. Adds rel_error (max |T - T_exact| / max
    temperature step) and fourier_number to summary.json; writes thermal_rod_profile.csv and
    thermal_rod.png besides the heat step's files."""

    kind: Literal["thermal_rod"] = F(..., description="kind: thermal_rod")
    example = {"kind": "thermal_rod", "duration": 2000.0, "nsteps": 20, "conductivity": 2.5,
               "specific_heat": 900.0, "T_initial": 300.0,
               "fixed": {"hot": 400.0, "cold": 300.0}}
    example_model = {"type": "lattice_block", "dim": 2, "counts": [12, 1], "diameter": 0.01,
                     "material": "rock", "groups": {"hot": {"side": "xmin"},
                                                    "cold": {"side": "xmax"}}}
    hot: Name = F("hot", description="Group held at T1 (x = 0 of the rod)")
    cold: Name = F("cold", description="Group held at T2 (x = L)")
    tolerance: float = F(0.02, gt=0, description="rel_error above this is reported as failed "
                                                 "(passed: false in the results)")
    terms: Int = F(400, ge=10, le=100000, description="Terms of the Fourier series")

    def check(self, cfg, groups):
        out = super().check(cfg, groups)
        for key in ("hot", "cold"):
            g = getattr(self, key)
            if g not in groups:
                out.append(((key,), unknown_group(g, groups)))
            elif g not in self.fixed:
                out.append((("fixed",), (f"the rod's {key} end {g!r} needs a fixed "
                                         f"temperature (fixed: {{{g}: T}})")))
        if self.hot == self.cold:
            out.append((("cold",), "hot and cold must be different groups"))
        return out

    def execute(self, ctx):
        res = super().execute(ctx)
        res.update(self.compare(ctx))
        return res

    def compare(self, ctx) -> dict:
        """rel_error of the chain against :func:`geodem.fields.thermal.rod_solution`."""
        from geodem.core import groups
        from geodem.fields.thermal import conductance_pairs, contact_area, rod_solution
        from geodem.workflow.errors import RunFailure

        sim = ctx.sim
        st = ctx.state
        f = sim.field("thermal")
        i, j, h = conductance_pairs(sim, f)
        deg = np.bincount(i, minlength=st.n) + np.bincount(j, minlength=st.n)
        if deg.max() > 2 or i.size != st.n - 1:
            raise RunFailure("thermal_rod needs a 1-D chain (each element conducting to at "
                             "most two neighbours, e.g. lattice_block counts: [N, 1]); this "
                             f"model has {i.size} conducting pairs for {st.n} elements")
        hot, cold = groups.members(st, self.hot), groups.members(st, self.cold)
        x0, x1 = st.x[hot].mean(axis=0), st.x[cold].mean(axis=0)
        L = float(np.linalg.norm(x1 - x0))
        s = (st.x - x0) @ ((x1 - x0) / L)
        d = float(np.linalg.norm(st.x[j] - st.x[i], axis=1).mean())
        m = float(st.m.mean())
        D = float(h.mean()) * d * d / (m * f.c)  # = k / (rho_b c), rho_b = m / (A d)
        A = float(contact_area(f.r0[i], f.r0[j], st.dim, st.thickness).mean()) * f.area_factor
        T0, T1, T2 = f.T0, f.fixed[self.hot], f.fixed[self.cold]
        t = f.time
        if f.ramp > 0:
            raise RunFailure("thermal_rod compares with ends held from t = 0: ramp must be 0")
        scale = max(abs(T1 - T0), abs(T2 - T0), abs(T1 - T2))
        if scale == 0:
            raise RunFailure("thermal_rod: T_initial and the two end temperatures are equal; "
                             "nothing to compare")
        exact = rod_solution(s, t, L, D, T0, T1, T2, self.terms)
        free = f.fixed_mask == 0
        rel = float(np.abs(f.T - exact)[free].max() / scale)
        res = {"rel_error": rel, "fourier_number": D * t / (L * L), "diffusivity": D,
               "length": L, "bulk_density": m / (A * d), "conductance": float(h.mean()),
               "T0": T0, "T1": T1, "T2": T2, "passed": bool(rel <= self.tolerance),
               "tolerance": self.tolerance}
        ctx.summary.update({"rel_error": rel, "fourier_number": res["fourier_number"]})
        ctx.log(f"rod: Fo = D t / L^2 = {res['fourier_number']:.4g} (D = {D:.4g} m^2/s, "
                f"L = {L:.4g} m, t = {t:.4g} s): max |T - T_exact| = {rel:.3e} x "
                f"{scale:.4g} K ({'within' if res['passed'] else 'ABOVE'} {self.tolerance})")
        order = np.argsort(s)
        write_csv(ctx.out_dir / ROD_PROFILE, ["position", "T", "T_exact", "fixed"],
                   [[float(s[k]), float(f.T[k]), float(exact[k]), int(f.fixed_mask[k])]
                    for k in order])
        ctx.runner.files.append(ROD_PROFILE)
        if self.plot and ctx.cfg.outputs.plots:
            xs = np.linspace(0.0, L, 400)
            curves = [(tt, rod_solution(xs, tt, L, D, T0, T1, T2, self.terms))
                      for tt in (0.25 * t, 0.5 * t)]
            res["rod_plot"] = ctx.plot("thermal_rod.png", lambda p: _plot_rod(
                p, s[order], f.T[order], xs, rod_solution(xs, t, L, D, T0, T1, T2, self.terms),
                curves, t, rel, res["fourier_number"]))
        return res


def _plot_rod(path, s, T, xs, exact, curves, t, rel, fo):
    plt = pyplot()
    if plt is None:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for tt, c in curves:
        ax.plot(xs, c, color="0.7", lw=1, label=f"Fourier, t = {tt:.3g} s")
    ax.plot(xs, exact, "C0-", lw=1.5, label=f"Fourier, t = {t:.3g} s (Fo = {fo:.3g})")
    ax.plot(s, T, "C3o", ms=3.5, label=f"elements (max error {rel:.2%})")
    ax.set_xlabel("position along the rod [m]")
    ax.set_ylabel("temperature [K]")
    ax.set_title("1-D conduction rod: DEM chain against the Fourier series")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
