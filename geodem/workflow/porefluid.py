"""Step ``pore_flow``: fluid flow through the pores of any model (geodem.fields.pore), linear
(Darcy) or radial (injection into a borehole: Thiem), with the permeability read from the flux
and from the steady pressure inside the rock (docs/pore_fluid.md)."""
from __future__ import annotations

import csv
import math
from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.workflow.errors import RunFailure
from geodem.workflow.schema import (F, Int, Name, Strict, StepBase, check_time_span,
                                    register_step, time_steps)

__all__ = ["PoreFluidSpec", "PoreFlow", "flow_geometry", "gradient_permeability"]


class PoreFluidSpec(Strict):
    """A pore fluid for ``pore_flow`` (geodem.fields.pore; defaults: water, cubic-law throats)."""

    k_f: float = F(1000.0 / 2.2e9, unit="kg m^-3 Pa^-1", gt=0,
                   description="EOS slope: rho = k_f P + c_f (water 4.545e-7; MatDEM's oil "
                               "4.615e-5)")
    c_f: float = F(1000.0, unit="kg/m^3", gt=0, description="EOS density at P = 0")
    k_t: Optional[float] = F(None, unit="kg/(Pa s)", gt=0,
                             description="Throat coefficient (default: cubic law at the "
                                         "aperture, c_f aperture^2 w / (12 viscosity))")
    aperture: Optional[float] = F(None, unit="m", ge=0,
                                  description="Residual aperture (default 0.002 d_mean)")
    viscosity: float = F(1.0e-3, unit="Pa s", gt=0,
                         description="Viscosity (default k_t and the permeability)")
    bond_factor: float = F(100.0, ge=1, description="An intact bond divides its throat's "
                                                    "conductance by this")
    p_min: Optional[float] = F(0.0, unit="Pa", description="Pressure floor (null: none)")
    every: Int = F(1, ge=1, le=100, description="Couple the fluid every N mechanical steps")


@register_step("pore_flow")
class PoreFlow(StepBase):
    """Fluid flow through the pores of the model (geodem.fields.pore): the pores touching the
    group ``inlet`` are held at ``p_in``, those touching ``outlet`` at ``p_out`` (drained),
    for ``nsteps`` or ``duration``, stopping early at steady state (``steady_tol``). The
    first pore_flow step couples the fluid (``fluid``, ``group``, ``p_init``); later ones keep
    it and change only the two pressures. Adds mass_flux_in, mass_flux_out [kg/s],
    hydraulic_conductance (flux / (p_in - p_out)) [kg/(s Pa)], permeability [m^2] and
    fluid_mass_balance_rel_error to summary.json; writes pore_flow_<name>.csv."""

    example = {"kind": "pore_flow", "inlet": "base", "outlet": "top", "p_in": 2e5,
               "p_out": 1e5, "nsteps": 20, "fluid": {"k_f": 4.615e-5, "c_f": 870.0}}
    inlet: Name = F(..., description="Group whose pores are held at p_in")
    outlet: Name = F(..., description="Group whose pores are held at p_out (drained)")
    p_in: float = F(..., unit="Pa", ge=0, description="Inlet pressure")
    p_out: float = F(0.0, unit="Pa", ge=0, description="Outlet pressure")
    p_init: Optional[float] = F(None, unit="Pa", ge=0,
                                description="Initial pore pressure (first pore_flow step; "
                                            "default p_out)")
    nsteps: Optional[Int] = F(None, ge=1, description="Time steps to run (at most)")
    duration: Optional[float] = F(None, unit="s", gt=0, description="Simulated time (at most)")
    steady_tol: Optional[float] = F(1e-4, gt=0, lt=1,
                                    description="Stop when the inflow and outflow agree, and "
                                                "the inflow has not changed over the last "
                                                "sample, within this fraction (null: never)")
    samples: Int = F(50, ge=2, le=100000, description="Samples over the step")
    group: Name = F("all", description="Elements forming the pore network")
    fluid: PoreFluidSpec = F(default_factory=PoreFluidSpec, description="The fluid (first "
                                                                          "pore_flow step)")
    flow: Literal["linear", "radial"] = F(
        "linear", description="How the permeability is read from the flux: linear (from the "
                              "inlet across the model to the outlet: Darcy over the distance "
                              "between the groups' centroids) or radial (injection into a "
                              "borehole, the outlet around it: Thiem's solution)")

    @model_validator(mode="after")
    def _one(self):
        check_time_span(self.nsteps, self.duration)
        return self

    def check(self, cfg, groups):
        out = []
        for key in ("inlet", "outlet", "group"):
            name = getattr(self, key)
            if name != "all" and name not in groups:
                out.append(((key,), f"coupled field 'pore_fluid': unknown group {name!r}; the "
                                    f"model's groups: {', '.join(groups)}"))
        if self.inlet == self.outlet:
            out.append((("outlet",), "inlet and outlet must be different groups"))
        first = next((s for s in cfg.steps if getattr(s, "kind", None) == "pore_flow"), None)
        if first is not None and first is not self and (first.inlet, first.outlet) != \
                (self.inlet, self.outlet):
            out.append((("inlet",), f"a later pore_flow step keeps the pores of the first one: "
                                    f"inlet/outlet must be {first.inlet}/{first.outlet}"))
        return out

    def planned_steps(self, plan):
        return time_steps(plan.dt, self.nsteps, self.duration)

    def execute(self, ctx):
        from geodem.fields.pore import PoreField

        sim = ctx.sim
        st = ctx.state
        field = next((f for f in sim.fields if f.kind == "pore_fluid"), None)
        if field is None:
            fl = self.fluid
            p_init = self.p_out if self.p_init is None else self.p_init
            field = PoreField(k_f=fl.k_f, c_f=fl.c_f, k_t=fl.k_t, aperture=fl.aperture,
                              viscosity=fl.viscosity, bond_factor=fl.bond_factor,
                              p_init=p_init, p_min=fl.p_min, group=self.group, every=fl.every,
                              bcs=[{"name": "inlet", "role": "inject", "pressure": self.p_in,
                                    "where": {"group": self.inlet}},
                                   {"name": "outlet", "role": "drain", "pressure": self.p_out,
                                    "where": {"group": self.outlet}}])
            sim.add_field(field)
        elif not ctx.resumed:
            field.set_bc("inlet", pressure=self.p_in)
            field.set_bc("outlet", pressure=self.p_out)
        flow_geometry(st, self.inlet, self.outlet, self.flow, field.t)  # refuses before running
        total = self.planned_steps(ctx.plan)
        chunk = max(1, total // self.samples)
        path = ctx.out_dir / f"pore_flow_{ctx.step.name}.csv"
        cols = ("step", "time", "mass_flux_in", "mass_flux_out", "injected_mass",
                "drained_mass", "mass_balance_rel_error")
        rows = []
        if ctx.resumed and path.exists():
            with open(path) as fh:
                rows = [[float(v) for v in r] for r in list(csv.reader(fh))[1:]
                        if int(float(r[0])) <= st.step]
        with open(path, "w", newline="") as fh:
            csv.writer(fh).writerow(cols)
            csv.writer(fh).writerows(rows)
        done = (st.step - ctx.start_step) // chunk * chunk
        last = (st.time, field.injected, field.drained)
        reason = "steps"
        prev_q = rows[-1][2] if rows else None
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(done)
            s = ctx.state
            span = s.time - last[0]
            q_in = (field.injected - last[1]) / span if span > 0 else 0.0
            q_out = (field.drained - last[2]) / span if span > 0 else 0.0
            last = (s.time, field.injected, field.drained)
            row = [s.step, s.time, q_in, q_out, field.injected, field.drained,
                   field.mass_balance_error()]
            rows.append(row)
            with open(path, "a", newline="") as fh:
                csv.writer(fh).writerow(row)
            tol = self.steady_tol
            if tol is not None and prev_q is not None and q_in > 0 and \
                    abs(q_in - q_out) <= tol * q_in and abs(q_in - prev_q) <= tol * q_in:
                reason = "steady"
                break
            prev_q = q_in
        q_in, q_out = rows[-1][2], rows[-1][3]
        dp = self.p_in - self.p_out
        K = 0.5 * (q_in + q_out) / dp if dp != 0 else None
        rho = field.c_f + field.k_f * 0.5 * (self.p_in + self.p_out)
        geo = flow_geometry(ctx.state, self.inlet, self.outlet, self.flow, field.t)
        perm = K * field.viscosity * geo["length"] / (rho * geo["area"]) \
            if K is not None and geo["area"] > 0 else None
        grad = gradient_permeability(ctx.state, field, self.flow, geo, 0.5 * (q_in + q_out),
                                     rho)
        res = {"mass_flux_in": q_in, "mass_flux_out": q_out,
               "flux_mismatch": abs(q_in - q_out) / max(abs(q_in), 1e-300),
               "hydraulic_conductance": K, "permeability": perm, "flow": self.flow,
               "flow_length": geo["length"], "flow_area": geo["area"], **grad,
               **{k: geo[k] for k in ("inlet_radius", "outlet_radius") if k in geo},
               "pressure_drop": dp, "stopped_by": reason,
               "fluid_mass_balance_rel_error": field.mass_balance_error(),
               "fluid": field.summary()}
        ctx.summary.update({k: res[k] for k in ("mass_flux_in", "mass_flux_out",
                                                 "hydraulic_conductance", "permeability",
                                                 "fluid_mass_balance_rel_error")})
        ctx.log(f"pore flow: q_in = {q_in:.4g} kg/s, q_out = {q_out:.4g} kg/s, "
                f"K = {K if K is None else f'{K:.4g}'} kg/(s Pa), permeability "
                f"{perm if perm is None else f'{perm:.4g}'} m^2; stopped by {reason}")
        return res


def flow_geometry(st, inlet: str, outlet: str, flow: str, thickness: float) -> dict:
    """The lengths that turn a hydraulic conductance ``K = q / dP`` [kg/(s Pa)] into a
    permeability ``k = K mu length / (rho area)`` [m^2].

    * ``linear``: ``length`` = the distance between the inlet's and the outlet's centroids,
      ``area`` = the model's cross-section normal to that direction (2-D: width x
      ``thickness``). Refused (RunFailure) when the centroids lie within two mean diameters:
      then the outlet surrounds the inlet and the flow is radial.
    * ``radial`` (Thiem 1906; Bear 1972, section 7.2): the inlet's centroid is the centre,
      ``r_in`` and ``r_out`` the mean distances of the inlet's and the outlet's elements from
      it; 2-D ``q = 2 pi k t rho dP / (mu ln(r_out / r_in))``, so ``length = ln(r_out /
      r_in)``, ``area = 2 pi t``; 3-D (spherical) ``q = 4 pi k rho dP / (mu (1/r_in -
      1/r_out))``, so ``length = 1/r_in - 1/r_out``, ``area = 4 pi``.

    Also ``centre`` (the inlet's centroid) and, for ``linear``, ``axis`` (the unit vector to
    the outlet's centroid): the frame :func:`gradient_permeability` fits the pressures in."""
    from geodem.core import groups as grp

    a, b = st.x[grp.members(st, inlet)], st.x[grp.members(st, outlet)]
    d_mean = 2.0 * float(st.r.mean())
    axis = b.mean(axis=0) - a.mean(axis=0)
    L = float(np.linalg.norm(axis))
    if flow == "radial":
        c = a.mean(axis=0)
        r_in = float(np.linalg.norm(a - c, axis=1).mean())
        r_out = float(np.linalg.norm(b - c, axis=1).mean())
        if not r_out > r_in > 0:
            raise RunFailure(f"pore_flow flow: radial needs the outlet {outlet!r} around the "
                             f"inlet {inlet!r}: their mean distances from the inlet's centre "
                             f"are {r_out:.4g} and {r_in:.4g} m")
        radii = {"inlet_radius": r_in, "outlet_radius": r_out, "centre": c}
        if st.dim == 2:
            return {"length": math.log(r_out / r_in), "area": 2.0 * math.pi * thickness, **radii}
        return {"length": 1.0 / r_in - 1.0 / r_out, "area": 4.0 * math.pi, **radii}
    if L < 2.0 * d_mean:
        raise RunFailure(f"pore_flow flow: linear needs the outlet {outlet!r} across the "
                         f"model from the inlet {inlet!r}, but their centroids are {L:.3g} m "
                         f"apart (< 2 d_mean): the outlet surrounds the inlet; allowed: "
                         f"flow: radial")
    u = axis / L
    ext = st.x.max(axis=0) - st.x.min(axis=0) + 2.0 * float(st.r.mean())
    if st.dim == 2:
        area = float(abs(np.array([-u[1], u[0]]) @ ext)) * thickness
    else:
        area = float(np.prod(ext)) / max(float(abs(u @ ext)), 1e-300)
    return {"length": L, "area": area, "axis": u, "centre": a.mean(axis=0)}


def gradient_permeability(st, field, flow: str, geo: dict, q: float, rho: float) -> dict:
    """Permeability from the steady pressure inside the rock, as from pressure taps: the free
    pores' pressures fitted by least squares to the steady solution of the flow, then
    ``k = q mu / (rho area |slope|)`` with ``q`` the mass flux [kg/s]. Linear: ``P = A + B s``
    (``s`` along the inlet-outlet axis; ``area`` the cross-section); radial 2-D (Thiem):
    ``P = A + B ln r``, ``area = 2 pi t``; radial 3-D: ``P = A + B / r``, ``area = 4 pi``
    (``r`` from the inlet's centroid); ``geo`` is :func:`flow_geometry`'s. Independent of
    where the held pores end, which the flux-based ``permeability`` must assume. Returns
    ``permeability_gradient`` [m^2] and ``pressure_fit_r2`` (both None without enough free
    pores)."""
    P = np.asarray(field.P, float)
    free = np.asarray(field.held) < 0
    if free.sum() < 3 or q <= 0:
        return {"permeability_gradient": None, "pressure_fit_r2": None}
    cen = st.x[field.cells].mean(axis=1)[free] - geo["centre"]
    if flow == "radial":
        r = np.linalg.norm(cen, axis=1)
        s = np.log(r) if st.dim == 2 else -1.0 / r  # dP/ds = -q mu / (rho area k)
    else:
        s = cen @ geo["axis"]
    A = np.column_stack([np.ones_like(s), s])
    coef, *_ = np.linalg.lstsq(A, P[free], rcond=None)
    res = P[free] - A @ coef
    r2 = 1.0 - float(res @ res) / max(float(((P[free] - P[free].mean()) ** 2).sum()), 1e-300)
    slope = -float(coef[1])
    k = q * field.viscosity / (rho * geo["area"] * slope) if slope > 0 else None
    return {"permeability_gradient": k, "pressure_fit_r2": r2}
