"""TwoBalls (MatDEM's first example): two elements bonded in a row between two fixed walls.

``wall - ball - ball - wall`` along x, identical elements, bonds of stiffness ``K = kn/2``
(two half-springs in series). Both balls start displaced by the same ``amplitude``, which
excites only the symmetric mode: the middle bond stays unstretched and each ball is a damped
oscillator on one wall bond, ``m x'' + eta x' + K x = 0`` (PHYSICS.md section 3):

    T = 2 pi / sqrt(K/m - (eta/2m)^2),  amplitude ~ exp(-eta t / 2m),  eta_c = 2 sqrt(K m).
"""
from __future__ import annotations

import math
from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.core.neighbors import rows_from_pairs
from geodem.core.state import new_state
from geodem.workflow.models import (BuiltModel, concat_states, element_params,
                                    state_bytes_per_element)
from geodem.workflow.schema import F, ModelBase, Name, StepBase, register_model, register_step


def build(dim=2, d=1.0, rho=2650.0, kn=2.0e9, amplitude=0.01, damping_ratio=0.0, xb=None,
          fs0=1e12, mu=0.5):
    """Return the TwoBalls state. ``damping_ratio`` = eta / eta_c; ``amplitude`` in metres.

    ``xb`` (element breaking displacement) defaults to effectively unbreakable.
    """
    r = 0.5 * d
    m = rho * (4.0 / 3.0 * math.pi * r ** 3 if dim == 3 else math.pi * r * r * d)
    x = np.zeros((4, dim))
    x[:, 0] = np.arange(4) * d
    big = 1e6 * d if xb is None else xb
    st = new_state(x, r, m, kn=kn, ks=kn, xb=big, fs0=fs0, mu=mu, width=4)
    rows_from_pairs(st, np.array([0, 1, 2]), np.array([1, 2, 3]), bonded=True)
    st.free[[0, 3]] = 0.0
    st.groups = {"all": 0, "walls": 1, "balls": 2}
    st.group[[0, 3]] = 1
    st.group[[1, 2]] = 2
    st.x[[1, 2], 0] += amplitude
    K = 0.5 * kn
    st.eta[[1, 2]] = damping_ratio * 2.0 * math.sqrt(K * m)
    return st


def analytic(state):
    """Undamped period T0, damped period T and decay rate eta/2m of the symmetric mode."""
    m = state.m[1]
    K = 0.5 * state.kn[1]
    eta = state.eta[1]
    w0 = math.sqrt(K / m)
    gamma = eta / (2.0 * m)
    wd2 = w0 * w0 - gamma * gamma
    return {"T0": 2 * math.pi / w0, "T": 2 * math.pi / math.sqrt(wd2) if wd2 > 0 else math.inf,
            "decay_rate": gamma, "omega0": w0}


def analytic_curve(t, amp, omega0, gamma):
    """Free damped oscillator released from rest at ``amp``: displacement at times ``t``."""
    t = np.asarray(t, dtype=float)
    if gamma >= omega0:  # critical (or over-) damping: use the critical form at gamma == omega0
        if math.isclose(gamma, omega0, rel_tol=1e-9):
            return amp * (1.0 + omega0 * t) * np.exp(-omega0 * t)
        s = math.sqrt(gamma * gamma - omega0 * omega0)
        r1, r2 = -gamma + s, -gamma - s
        return amp * (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r2 - r1)
    wd = math.sqrt(omega0 * omega0 - gamma * gamma)
    return amp * np.exp(-gamma * t) * (np.cos(wd * t) + gamma / wd * np.sin(wd * t))


def measure(times, u):
    """Period (mean spacing of successive maxima) and log decay rate of a displacement history."""
    u = np.asarray(u)
    t = np.asarray(times)
    k = np.flatnonzero((u[1:-1] > u[:-2]) & (u[1:-1] >= u[2:])) + 1
    if k.size < 2:
        return {"T": math.nan, "decay_rate": math.nan, "peaks": k.size}
    # parabolic refinement of each peak
    tp, up = [], []
    h = t[1] - t[0]
    for i in k:
        a, b, c = u[i - 1], u[i], u[i + 1]
        den = a - 2 * b + c
        off = 0.5 * (a - c) / den if den != 0 else 0.0
        tp.append(t[i] + off * h)
        up.append(b - 0.25 * (a - c) * off)
    tp, up = np.array(tp), np.array(up)
    period = float(np.mean(np.diff(tp)))
    pos = up > 0
    rate = float(-np.polyfit(tp[pos], np.log(up[pos]), 1)[0]) if pos.sum() >= 2 else math.nan
    return {"T": period, "decay_rate": rate, "peaks": int(k.size)}


# ==================================================================== workflow model and step
@register_model("two_balls")
class TwoBalls(ModelBase):
    """MatDEM's TwoBalls: ``wall - ball - ball - wall`` along x, bonded, both balls displaced by
    ``amplitude`` so only the in-phase mode rings (a damped oscillator on one wall bond). One
    independent copy per entry of ``damping_ratios``, side by side; copy ``LABEL`` has the groups
    ``LABEL_walls`` (fixed) and ``LABEL_balls``."""

    size_field = "damping_ratios"
    example = {"type": "two_balls", "material": "rock"}
    dim: Literal[2, 3] = F(2, description="Dimension")
    diameter: float = F(1.0, unit="m", gt=0, description="Element diameter (and spacing)")
    material: Name = F(..., description="Material name (a key of materials)")
    amplitude: float = F(0.01, unit="m", gt=0,
                         description="Initial displacement of both balls along x (< diameter/2)")
    damping_ratios: dict[Name, float] = F(
        {"critical": 1.0, "ten_percent": 0.1}, min_length=1, max_length=100,
        description="One copy per entry: label -> damping ratio eta / eta_critical (>= 0)")

    @model_validator(mode="after")
    def _ratios(self):
        for k, v in self.damping_ratios.items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"damping_ratios.{k} = {v!r}: allowed: a number >= 0 "
                                 f"(1 = critical damping)")
        return self

    def n_elements(self):
        return 4 * len(self.damping_ratios)

    def bytes_per_element(self):
        return 2 * state_bytes_per_element(self.dim, 4)

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        out = ["all"]
        for label in self.damping_ratios:
            out += [f"{label}_walls", f"{label}_balls"]
        return out

    def check(self, cfg):
        if self.amplitude >= 0.5 * self.diameter:
            return [(("amplitude",), f"amplitude {self.amplitude:g} m is not below half the "
                                     f"diameter ({0.5 * self.diameter:g} m); allowed: "
                                     f"0 < amplitude < diameter/2")]
        return []

    def build(self, cfg):
        d = self.diameter
        p = element_params(cfg, self.material, d, self.dim)
        parts, shifts, cases, groups = [], [], {}, {"all": 0}
        for k, (label, zeta) in enumerate(self.damping_ratios.items()):
            st = build(dim=self.dim, d=d, rho=p["rho"], kn=p["kn"], amplitude=self.amplitude,
                          damping_ratio=zeta, xb=p["xb"], fs0=p["fs0"], mu=p["mu"])
            st.ks[:] = p["ks"]
            if p["mass"] is not None:
                st.m[:] = p["mass"]
                st.eta[[1, 2]] = zeta * 2.0 * math.sqrt(0.5 * p["kn"] * p["mass"])
            gw, gb = 2 * k + 1, 2 * k + 2
            groups[f"{label}_walls"], groups[f"{label}_balls"] = gw, gb
            st.group[:] = np.array([gw, gb, gb, gw], np.int32)
            an = analytic(st)
            cases[label] = {"damping_ratio": zeta, "analytic": an, "amplitude": self.amplitude,
                            "walls": f"{label}_walls", "balls": f"{label}_balls"}
            shift = np.zeros(self.dim)
            shift[1] = 2.0 * d * k
            parts.append(st)
            shifts.append(shift)
        state = concat_states(parts, shifts)
        state.groups = groups
        ref = state.x.copy()
        balls = np.isin(state.group, [g for n, g in groups.items() if n.endswith("_balls")])
        ref[balls, 0] -= self.amplitude  # rest positions
        return BuiltModel(state, ref, 1.0, {"cases": cases, "diameter": d})


# ============================================================================ two_balls_check
@register_step("two_balls_check")
class TwoBallsCheck(StepBase):
    """TwoBalls against the analytic damped oscillator, from the recorded displacements of the
    balls (``/observables/groups/LABEL_balls/displacement``, best recorded every step): period
    and decay rate of the ``oscillating`` case, overshoot of the ``critical`` case, largest
    deviation of each case from its analytic curve. Adds ``period_rel_error`` and
    ``decay_rel_error`` to summary.json and draws ``two_balls.png`` (with matplotlib)."""

    example = {"kind": "two_balls_check"}
    example_model = {"type": "two_balls", "material": "rock"}
    oscillating: Name = F("ten_percent", description="Case (damping_ratios label) whose period "
                                                     "and decay rate are measured")
    critical: Optional[Name] = F("critical", description="Critically damped case checked for "
                                                         "overshoot (null: none)")
    plot: bool = F(True, description="Draw two_balls.png (needs matplotlib)")

    def check(self, cfg, groups):
        if cfg.model.type != "two_balls":
            return [(("kind",), f"two_balls_check needs model type two_balls, not "
                                f"{cfg.model.type!r}")]
        out = []
        labels = list(cfg.model.damping_ratios)
        for key in ("oscillating", "critical"):
            v = getattr(self, key)
            if v is not None and v not in labels:
                out.append(((key,), f"unknown case {v!r}; the model's damping_ratios: "
                                    f"{', '.join(labels)}"))
        if not out and not 0 < cfg.model.damping_ratios[self.oscillating] < 1:
            out.append((("oscillating",), f"case {self.oscillating!r} has damping ratio "
                                          f"{cfg.model.damping_ratios[self.oscillating]:g}; it "
                                          f"must oscillate: allowed 0 < ratio < 1"))
        for key in ("groups", "energy_groups"):
            lst = getattr(cfg.outputs.observables, key)
            for label in {self.oscillating, self.critical} - {None}:
                g = f"{label}_balls"
                if lst is not None and g not in lst:
                    out.append(((), f"outputs.observables.{key} must include {g!r}"))
        return out

    def _case(self, ctx, label):
        info = ctx.model.info["cases"][label]
        step, t, disp = ctx.series(f"observables/groups/{info['balls']}/displacement")
        u = disp[:, 0]
        terms = ("kinetic", "gravity", "elastic", "heat_viscous", "heat_break_normal",
                 "heat_break_shear", "heat_friction")
        e = {}
        for term in terms:
            e[term] = sum(ctx.series(f"observables/groups/{g}/energy/{term}")[2]
                          for g in (info["balls"], info["walls"]))
        total = sum(e[k] for k in terms)
        energies = [{"kinetic": e["kinetic"][i], "elastic": e["elastic"][i],
                     "heat_viscous": e["heat_viscous"][i], "total": total[i]}
                    for i in range(len(t))]
        an = info["analytic"]
        amp = float(u[0]) if step[0] == 0 else float(info["amplitude"])
        ref = analytic_curve(t, amp, an["omega0"], an["decay_rate"])
        dev = float(np.abs(u - ref).max() / amp)
        return {"t": t, "u": u, "analytic": an, "amplitude": amp, "energies": energies,
                "deviation": dev}

    def execute(self, ctx):
        osc = self._case(ctx, self.oscillating)
        an = osc["analytic"]
        meas = measure(osc["t"], osc["u"])
        if meas["peaks"] < 2:
            # the run is fine, the check has nothing to measure: say so (the errors stay NaN)
            dt = float(ctx.sim.state.dt)
            msg = (f"two_balls_check: the {self.oscillating!r} case shows {meas['peaks']} "
                   f"displacement peak(s) in {osc['t'][-1]:.4g} s; the period and decay rate "
                   f"need at least 2: run it for at least 2.5 periods (the analytic period is "
                   f"{an['T']:.4g} s, {an['T'] / dt:.0f} time steps), with "
                   f"outputs.observables.every small enough to resolve them")
            ctx.log("warning: " + msg)
            ctx.summary.setdefault("warnings", []).append(msg)
        per_rel = abs(meas["T"] - an["T"]) / an["T"]
        dec_rel = abs(meas["decay_rate"] - an["decay_rate"]) / an["decay_rate"] \
            if an["decay_rate"] > 0 else abs(meas["decay_rate"])
        res = {
            "period": meas["T"], "period_analytic": an["T"], "period_rel_error": per_rel,
            "period_undamped_analytic": an["T0"], "peaks": meas["peaks"],
            "decay_rate": meas["decay_rate"], "decay_rate_analytic": an["decay_rate"],
            "decay_rel_error": dec_rel,
            "max_deviation_from_analytic": {self.oscillating: osc["deviation"]},
            "samples": int(len(osc["t"])),
        }
        crit = None
        if self.critical is not None:
            crit = self._case(ctx, self.critical)
            res["critical_overshoot"] = max(0.0, -float(crit["u"].min())) / crit["amplitude"]
            res["max_deviation_from_analytic"][self.critical] = crit["deviation"]
        ctx.summary["period_rel_error"] = per_rel
        ctx.summary["decay_rel_error"] = dec_rel
        ctx.log(f"TwoBalls: period {meas['T']:.6g} s (analytic {an['T']:.6g} s, rel. error "
                f"{per_rel:.2e}); decay rate {meas['decay_rate']:.6g} 1/s (analytic "
                f"{an['decay_rate']:.6g} 1/s, rel. error {dec_rel:.2e})")
        if self.plot and ctx.cfg.outputs.plots:
            ratios = ctx.cfg.model.damping_ratios
            labels = [f"{c}, {ratios[c]:g} x critical" if c else "" for c in
                      (self.critical, self.oscillating)]
            res["plot"] = ctx.plot("two_balls.png",
                                   lambda path: _plot(path, crit, osc, labels))
        return res


def _plot(path, crit, osc, labels):
    """Displacements against the analytic curves, and the energy terms, of both cases."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:  # noqa: BLE001 - matplotlib missing or unusable: the plot is optional
        return None
    runs = [(r, lab) for r, lab in zip((crit, osc), labels) if r is not None]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for k, (run, label) in enumerate(runs):
        a = run["analytic"]
        ref = analytic_curve(run["t"], run["amplitude"], a["omega0"], a["decay_rate"])
        ax1.plot(run["t"], run["u"], color=f"C{k}", lw=1.5, label=f"{label} (geodem)")
        ax1.plot(run["t"], ref, color="k", lw=0.8, ls="--")
        for key, col, name in (("kinetic", "C2", "kinetic"), ("elastic", "C3", "elastic"),
                               ("heat_viscous", "C4", "viscous heat"), ("total", "k", "total")):
            ax2.plot(run["t"], [e[key] for e in run["energies"]], color=col,
                     lw=1.5 if k else 1.0, ls="-" if k else ":", label=f"{name}, {label}")
    ax1.plot([], [], color="k", lw=0.8, ls="--", label="analytic")
    ax1.axhline(0.0, color="0.6", lw=0.5)
    ax1.set_ylabel("ball displacement [m]")
    ax1.legend(loc="best")
    ax1.set_title("TwoBalls: damped oscillation against the analytic oscillator")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("energy [J]")
    ax2.legend(loc="best", ncol=2, fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
