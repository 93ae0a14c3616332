"""Registered step kinds (``steps: - kind: ...`` in a workflow).

=================  ===========================================================================
kind               what it does
=================  ===========================================================================
run                advance N time steps (or a duration), optionally with a damping setting
balance            MatDEM's standard balance: standard damping eta_c/N for 50 N steps
fix                fix degrees of freedom of a group
release            free degrees of freedom of a group again
velocity           move a group kinematically at a prescribed velocity
load               apply an external force to a group
damping            set the global damping of a group
two_balls_check    TwoBalls against the analytic damped oscillator (period, decay, overshoot)
monitor            record points, groups (displacement, velocity, stress) and broken bonds
                   while the later steps run: monitor.csv, monitor.png
                   (:mod:`geodem.workflow.monitoring`)
pressure           a normal pressure on a boundary group or a cavity's wall, optionally ramped
                   (:mod:`geodem.workflow.monitoring`)
excavate           remove a group or the elements in a shape, in stages (geodem.workflow.excavation)
weaken             lower the strength of a group's bonds or of those crossing a plane, or cut them
                   (geodem.workflow.excavation)
=================  ===========================================================================

A step kind is a :class:`~geodem.workflow.schema.StepBase` subclass registered with
``@register_step("kind")``; it works through the :class:`~geodem.workflow.runner.StepContext`
(``ctx.advance(n)`` is the only way time steps are run). Steps that change the model by decree
(fix, release, velocity) book the energy they add or remove as external work, so the energy
books stay closed.
"""
from __future__ import annotations

import math
from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.workflow.schema import (
    DOF_NAMES,
    F,
    Int,
    Name,
    STEPS,
    StepBase,
    check_time_span,
    register_step,
    time_steps,
    unknown_group,
)


def _group_problem(cfg, groups, name, path=("group",)):
    if name not in groups:
        return [(path, unknown_group(name, groups))]
    return []


def _dofs_problem(cfg, dofs, path=("dofs",)):
    out = []
    for k, d in enumerate(dofs or []):
        if DOF_NAMES.index(d) >= cfg.model.dim:
            out.append((path + (k,), f"degree of freedom {d!r} does not exist in "
                                     f"{cfg.model.dim}-D; allowed: "
                                     f"{', '.join(DOF_NAMES[:cfg.model.dim])}"))
    return out


def _vector_problem(cfg, vec, path, what):
    if len(vec) != cfg.model.dim:
        return [(path, f"{what} needs {cfg.model.dim} components (dim = {cfg.model.dim}), got "
                       f"{len(vec)}")]
    return []


# ============================================================================ run
@register_step("run")
class Run(StepBase):
    """Advance the model ``nsteps`` time steps, or for ``duration`` seconds of simulated time.
    Optionally set the damping of every element first: ``damping_ratio`` x the element critical
    damping, or MatDEM's standard damping eta_c / ``standard_damping``."""

    example = {"kind": "run", "nsteps": 20}
    nsteps: Optional[Int] = F(None, ge=1, description="Time steps to run")
    duration: Optional[float] = F(None, unit="s", gt=0,
                                  description="Simulated time to run (rounded up to whole steps)")
    damping_ratio: Optional[float] = F(None, ge=0, description="Set eta = ratio x the element "
                                                               "critical damping 2 sqrt(m kn/2)")
    standard_damping: Optional[float] = F(None, ge=1, description="Set MatDEM's standard damping "
                                                                  "eta_c / N, N elements across")

    @model_validator(mode="after")
    def _one(self):
        check_time_span(self.nsteps, self.duration)
        if self.damping_ratio is not None and self.standard_damping is not None:
            raise ValueError("give at most one of damping_ratio and standard_damping")
        return self

    def planned_steps(self, plan):
        return time_steps(plan.dt, self.nsteps, self.duration)

    def execute(self, ctx):
        from geodem.core import timestep

        if not ctx.resumed:
            st = ctx.state
            if self.damping_ratio is not None:
                ctx.set_eta(self.damping_ratio * timestep.element_critical_damping(st))
            elif self.standard_damping is not None:
                ctx.set_eta(timestep.standard_damping(st, self.standard_damping))
        ctx.advance(self.planned_steps(ctx.plan))
        return None


# ============================================================================ balance
@register_step("balance")
class Balance(StepBase):
    """MatDEM's standard balance: the standard damping eta_c / N on every element, then 50 N
    time steps (N elements across the model: ``n_across``, default from the model). Reports the
    unbalanced-force ratio at the end (small = equilibrium)."""

    example = {"kind": "balance", "n_across": 2}
    n_across: Optional[float] = F(None, ge=1, description="Elements across the model in the "
                                                          "loading direction (default: the "
                                                          "model's largest count)")
    nsteps: Optional[Int] = F(None, ge=1, description="Time steps (default 50 x n_across)")
    standard_damping: bool = F(True, description="Apply the standard damping first")
    tolerance: float = F(1e-2, gt=0, le=1, description="Unbalanced-force ratio that counts as "
                                                       "equilibrium")
    unconverged: Literal["warn", "fail"] = F(
        "warn", description="Above the tolerance at the end: warn (summary.json warnings) or "
                            "fail the run (exit 1, checkpoint kept)")

    def _n(self, plan):
        return float(self.n_across if self.n_across is not None else plan.n_across)

    def planned_steps(self, plan):
        from geodem.core import timestep

        if self.nsteps is not None:
            return int(self.nsteps)
        return timestep.standard_balance_steps(self._n(plan))

    def execute(self, ctx):
        from geodem.core import timestep

        if self.standard_damping and not ctx.resumed:
            ctx.set_eta(timestep.standard_damping(ctx.state, self._n(ctx.plan)))
        ctx.advance(self.planned_steps(ctx.plan))
        ratio = ctx.sim.unbalanced_force_ratio()
        ctx.log(f"unbalanced-force ratio after the balance: {ratio:.3e}")
        converged = bool(ratio <= self.tolerance)
        if not converged:
            eta = float(ctx.state.eta.mean())
            msg = (f"step {self.name!r}: not in equilibrium after {self.planned_steps(ctx.plan)} "
                   f"time steps: unbalanced-force ratio {ratio:.3g} > tolerance "
                   f"{self.tolerance:g} (mean damping {eta:.3g} kg/s); give more nsteps, or "
                   f"use the standard damping (standard_damping: true, n_across = the elements "
                   f"across the loading direction)")
            if self.unconverged == "fail":
                from geodem.workflow.errors import RunFailure

                raise RunFailure(msg)
            ctx.log("warning: " + msg)
            ctx.summary.setdefault("warnings", []).append(msg)
        return {"unbalanced_force_ratio": ratio, "n_across": self._n(ctx.plan),
                "converged": converged}


# ============================================================================ boundary decrees
class _GroupStep(StepBase):
    group: Name = F(..., description="Group name")

    def check(self, cfg, groups):
        return _group_problem(cfg, groups, self.group)


@register_step("fix")
class Fix(_GroupStep):
    """Fix degrees of freedom of a group (velocity set to zero; the reaction force is recorded)."""

    example = {"kind": "fix", "group": "base"}
    dofs: Optional[list[Literal[DOF_NAMES]]] = F(  # type: ignore[valid-type]
        None, min_length=1, description="Degrees of freedom (x, y, z; default all)")

    def check(self, cfg, groups):
        return super().check(cfg, groups) + _dofs_problem(cfg, self.dofs)

    def execute(self, ctx):
        from geodem.core import groups

        ctx.decree(lambda st: groups.fix(st, self.group, self.dofs), self.group)


@register_step("release")
class Release(_GroupStep):
    """Free degrees of freedom of a group again (velocities kept)."""

    example = {"kind": "release", "group": "top"}
    dofs: Optional[list[Literal[DOF_NAMES]]] = F(  # type: ignore[valid-type]
        None, min_length=1, description="Degrees of freedom (x, y, z; default all)")

    def check(self, cfg, groups):
        return super().check(cfg, groups) + _dofs_problem(cfg, self.dofs)

    def execute(self, ctx):
        from geodem.core import groups

        ctx.decree(lambda st: groups.release(st, self.group, self.dofs), self.group)


@register_step("velocity")
class Velocity(_GroupStep):
    """Move a group kinematically at ``velocity`` (platens, walls); a null component leaves that
    degree of freedom as it is."""

    example = {"kind": "velocity", "group": "top", "velocity": [0.0, -0.01]}
    velocity: list[Optional[float]] = F(..., unit="m/s", min_length=2, max_length=3,
                                        description="Velocity (dim components; null = free)")

    def check(self, cfg, groups):
        return super().check(cfg, groups) + _vector_problem(cfg, self.velocity, ("velocity",),
                                                            "velocity")

    def execute(self, ctx):
        from geodem.core import groups

        vel = [math.nan if v is None else v for v in self.velocity]
        ctx.decree(lambda st: groups.set_velocity(st, self.group, vel), self.group)


@register_step("load")
class Load(_GroupStep):
    """Apply an external force to a group (its work is booked as external work)."""

    example = {"kind": "load", "group": "top", "force": [0.0, -1.0]}
    force: list[float] = F(..., unit="N", min_length=2, max_length=3,
                           description="Force (dim components)")
    per: Literal["group", "element"] = F("group", description="The force is the group total "
                                                              "(split evenly) or per element")

    def check(self, cfg, groups):
        return super().check(cfg, groups) + _vector_problem(cfg, self.force, ("force",), "force")

    def execute(self, ctx):
        from geodem.core import groups

        ctx.decree(lambda st: groups.set_load(st, self.group, self.force, per=self.per),
                   book_energy=False)


@register_step("damping")
class Damping(StepBase):
    """Set the global (mass) damping of a group: a ratio of the element critical damping, the
    standard damping eta_c / N, or eta directly."""

    example = {"kind": "damping", "ratio": 0.1}
    group: Name = F("all", description="Group name")
    ratio: Optional[float] = F(None, ge=0, description="eta / element critical damping")
    standard: Optional[float] = F(None, ge=1, description="N for eta = eta_c / N")
    eta: Optional[float] = F(None, unit="kg/s", ge=0, description="Damping coefficient")

    @model_validator(mode="after")
    def _one(self):
        if sum(v is not None for v in (self.ratio, self.standard, self.eta)) != 1:
            raise ValueError("give exactly one of ratio, standard or eta")
        return self

    def check(self, cfg, groups):
        return _group_problem(cfg, groups, self.group)

    def execute(self, ctx):
        from geodem.core import groups, timestep

        st = ctx.state
        if self.ratio is not None:
            new = self.ratio * timestep.element_critical_damping(st)
        elif self.standard is not None:
            new = timestep.standard_damping(st, self.standard)
        else:
            new = np.full(st.n, float(self.eta))
        idx = groups.members(st, self.group)
        eta = st.eta.copy()
        eta[idx] = new[idx]
        ctx.set_eta(eta)


# the case modules register more models and step kinds (list: geodem.registry.BUILTINS)
STEPS.load_builtins()
