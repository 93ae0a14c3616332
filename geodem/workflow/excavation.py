"""Step kinds that change what the model is made of, on any model: ``excavate`` and ``weaken``.

=================  ===========================================================================
kind               what it does
=================  ===========================================================================
excavate           remove a group, or the elements inside a shape, optionally in stages with
                   time steps after each stage; the energy removed elements carry out is booked
weaken             scale the strength of the bonds of a group or of the bonds crossing a plane
                   (and the friction of a group), or cut those bonds outright
=================  ===========================================================================

Energy books (``Simulation.energies``, docs/excavation.md): an excavation books the kinetic and
gravity energy of the removed elements and the elastic energy of their bonds and contacts as
``removed`` (the heat and work they had booked stay in the totals), so the closure error after
an excavation is that of a model that lost nothing. Weakening changes no energy; bonds that the
lower strength can no longer hold break at once (``Simulation.refresh_forces``), and bonds cut
outright release their elastic energy as normal breaking heat (``Simulation.cut``), both booked
as any broken bond is.

Generic: nothing here knows a case (geodem.cases) or a study.
"""
from __future__ import annotations

from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.core.state import scale_bond_rate
from geodem.workflow.scene import Shape
from geodem.workflow.schema import (
    DOF_NAMES,
    F,
    Int,
    Name,
    StepBase,
    Strict,
    register_step,
    unknown_group,
)

ORDERS = ("outward", "inward", "x", "-x", "y", "-y", "z", "-z")


def _empty_groups(st) -> list:
    """Names of the groups (``all`` aside) that hold no element."""
    have = set(np.unique(st.group).tolist())
    return [g for g, gid in st.groups.items() if g != "all" and gid not in have]


# ============================================================================ excavate
@register_step("excavate")
class Excavate(StepBase):
    """Remove elements from the model: the members of ``group``, or the elements whose centres
    lie inside ``shape`` (box, polygon in 2-D, disc, below, above: as scene regions). With
    ``stages`` = n the removal is split in n stages, each followed by ``nsteps_per_stage`` time
    steps so the model relaxes.

    Stages follow ``order``: ``outward`` (default) by the distance of the element centres from
    the centre (the disc's or box's centre, else the centroid of the elements selected at the
    start; in 3-D a disc is a cylinder along y and the distance is from its axis), innermost
    first; ``inward`` outermost first; ``x``, ``y``, ``z`` by that coordinate,
    lowest first, ``-x``, ``-y``, ``-z`` highest first (``-y`` in 2-D: a pit dug from the top).
    The range of that key over the elements selected when the step starts, ``[lo, hi]``, is cut
    in n bands of equal width; stage k removes the selected elements (their positions then)
    whose key is at most ``lo + k (hi - lo) / n``, the last stage every selected element left.

    Books: the kinetic [J] and gravity [J] energy of the removed elements and the elastic energy
    [J] of their bonds and contacts leave the model as the energy term ``removed``; their heat
    and external work stay booked. Removed elements leave every group; a group left empty is
    listed in the results (``empty_groups``) and in the summary's warnings. Results per stage:
    ``removed_per_stage`` (elements), ``energy_removed_per_stage`` [J] and its parts
    (``kinetic_removed``, ``gravity_removed``, ``elastic_removed`` [J]), ``energy_removed`` [J]
    in all and ``n_elements_left``. Not with coupled fields (thermal, pore fluid)."""

    example = {"kind": "excavate", "group": "base", "stages": 2, "nsteps_per_stage": 5}
    group: Optional[Name] = F(None, description="Remove this group's elements")
    shape: Optional[Shape] = F(None, description="Remove the elements whose centres lie "
                                                 "inside this shape (as scene regions) [m]")
    stages: Int = F(1, ge=1, description="Number of stages the removal is split into (>= 1)")
    nsteps_per_stage: Int = F(0, ge=0, description="Time steps run after each stage (the "
                                                   "model relaxes)")
    order: Literal[ORDERS] = F(  # type: ignore[valid-type]
        "outward", description="Stage order: outward / inward from the centre, or along an "
                               "axis (x, y, z lowest first; -x, -y, -z highest first)")

    @model_validator(mode="after")
    def _one(self):
        if (self.group is None) == (self.shape is None):
            raise ValueError("give exactly one of group (a group's elements) or shape (the "
                             "elements inside a shape)")
        return self

    def planned_steps(self, plan):
        return int(self.stages) * int(self.nsteps_per_stage)

    def check(self, cfg, groups):
        dim = cfg.model.dim
        out = []
        if self.group is not None:
            if self.group not in groups:
                out.append((("group",), unknown_group(self.group, groups)))
            elif self.group == "all":
                out.append((("group",), "group 'all' is every element: excavating it would "
                                        "leave no model; name a group or give a shape"))
        if self.shape is not None:
            out += self.shape.problems(dim, ("shape",))
        axis = self.order.lstrip("-")
        if axis in DOF_NAMES and DOF_NAMES.index(axis) >= dim:
            out.append((("order",), f"axis {axis!r} does not exist in {dim}-D; allowed: "
                                    f"outward, inward, "
                                    f"{', '.join(a + ', -' + a for a in DOF_NAMES[:dim])}"))
        return out

    # -- selection ---------------------------------------------------------------------
    def _selected(self, st) -> np.ndarray:
        if self.group is not None:
            return st.group_mask(self.group)
        return self.shape.mask(st.x)

    def _centre(self, st, sel) -> list:
        s = self.shape
        if s is not None and s.disc is not None:
            return [float(v) for v in s.disc.center]
        if s is not None and s.box is not None:
            return [0.5 * (a + b) for a, b in zip(s.box.min, s.box.max)]
        return st.x[sel].mean(axis=0).tolist() if sel.any() else [0.0] * st.dim

    def _key(self, st, centre) -> np.ndarray:
        o = self.order
        if o in ("outward", "inward"):
            diff = st.x - np.asarray(centre)[None, :]
            if st.dim == 3 and self.shape is not None and self.shape.disc is not None:
                diff[:, 1] = 0.0  # a cylinder along y: the distance from its axis
            d = np.sqrt((diff ** 2).sum(axis=1))
            return d if o == "outward" else -d
        k = DOF_NAMES.index(o.lstrip("-"))
        return -st.x[:, k] if o.startswith("-") else st.x[:, k].copy()

    def execute(self, ctx):
        rec = ctx.runner.results.get(self.name) if ctx.resumed else None
        if rec is None:
            st = ctx.state
            sel = self._selected(st)
            centre = self._centre(st, sel)
            key = self._key(st, centre)
            lo, hi = (float(key[sel].min()), float(key[sel].max())) if sel.any() else (0.0, 0.0)
            rec = {"selected": int(sel.sum()), "order": self.order, "centre": centre,
                   "key_range": [lo, hi], "removed_per_stage": [],
                   "energy_removed_per_stage": [], "kinetic_removed": [], "gravity_removed": [],
                   "elastic_removed": [], "steps_at_stage": []}
            if not sel.any():
                msg = (f"step {self.name!r}: the {'group' if self.group else 'shape'} selects no "
                       f"element; nothing is removed")
                ctx.log("warning: " + msg)
                ctx.summary.setdefault("warnings", []).append(msg)
        n = int(self.stages)
        lo, hi = rec["key_range"]
        for k in range(n):
            if k >= len(rec["removed_per_stage"]):
                st = ctx.state
                sel = self._selected(st)
                if k < n - 1:
                    edge = lo + (hi - lo) * (k + 1) / n
                    sel &= self._key(st, rec["centre"]) <= edge + 1e-9 * max(hi - lo, 0.0)
                out = ctx.remove_elements(sel)
                rec["removed_per_stage"].append(out["n_removed"])
                rec["energy_removed_per_stage"].append(out["removed"])
                for part in ("kinetic", "gravity", "elastic"):
                    rec[f"{part}_removed"].append(out[part])
                rec["steps_at_stage"].append(int(ctx.sim.state.step))
                ctx.log(f"stage {k + 1}/{n}: removed {out['n_removed']} elements "
                        f"({out['n_left']} left), energy carried out {out['removed']:.4g} J")
                self._report(ctx, rec)
            ctx.advance((k + 1) * int(self.nsteps_per_stage))
        return self._report(ctx, rec)

    def _report(self, ctx, rec) -> dict:
        st = ctx.sim.state
        rec["n_removed"] = int(sum(rec["removed_per_stage"]))
        rec["energy_removed"] = float(sum(rec["energy_removed_per_stage"]))
        rec["n_elements_left"] = int(st.n)
        empty = _empty_groups(st)
        new = [g for g in empty if g not in rec.get("empty_groups", [])]
        rec["empty_groups"] = empty
        for g in new:
            msg = f"step {self.name!r}: group {g!r} has no element left after the excavation"
            ctx.log("warning: " + msg)
            ctx.summary.setdefault("warnings", []).append(msg)
        # kept in the run's results at once, so a checkpoint between stages knows them
        ctx.runner.results[self.name] = rec
        return rec


# ============================================================================ weaken
class Plane(Strict):
    point: list[float] = F(..., unit="m", min_length=2, max_length=3,
                           description="A point of the plane (a line in 2-D)")
    normal: list[float] = F(..., min_length=2, max_length=3,
                            description="Normal of the plane (any length but zero)")


@register_step("weaken")
class Weaken(StepBase):
    """Lower the strength of bonds: those of ``group`` (``bonds: touching``, default: at least
    one end in the group; ``inside``: both ends), or those crossing ``plane`` (the two centres on
    opposite sides; a centre on the plane counts on the side the normal points away from).

    ``factor`` (0 < factor <= 1) multiplies the bonds' strength, the tensile breaking force
    (``xb``) and the shear strength (``fs0``) alike, through each bond's ``bond_rate``; it applies
    to the strength as it is, so two steps of 0.8 leave 0.64. ``friction_factor`` (group only:
    friction is a property of the elements) multiplies the friction coefficient ``mu`` of the
    group's elements. ``cut: true`` breaks the selected bonds instead (logged as joint cracks,
    type 0): the elastic energy a loaded bond held is booked as normal breaking heat [J].
    Bonds the lower strength can no longer hold break at once, booked like any broken bond.
    A strength-reduction series is several ``weaken`` + ``run`` steps.

    Results: ``bonds_weakened``, ``bonds_cut``, ``bonds_broken`` (broken at once by the lower
    strength), ``elements_friction_reduced``, ``heat_booked`` [J] (breaking heat of the cut and
    broken bonds) and ``bonds_left`` (intact bonds after the step)."""

    example = {"kind": "weaken", "group": "top", "factor": 0.5}
    group: Optional[Name] = F(None, description="Weaken the bonds of this group")
    plane: Optional[Plane] = F(None, description="Weaken the bonds crossing this plane")
    bonds: Literal["touching", "inside"] = F(
        "touching", description="With group: bonds with at least one end in it (touching) or "
                                "both ends (inside)")
    factor: Optional[float] = F(None, gt=0, le=1, description="Strength factor, 0 < factor "
                                                               "<= 1 (xb and fs0 of each bond)")
    friction_factor: Optional[float] = F(None, gt=0, le=1,
                                         description="Friction factor of the group's elements, "
                                                     "0 < friction_factor <= 1")
    cut: bool = F(False, description="Break the selected bonds outright (their elastic energy "
                                     "is booked as breaking heat)")

    @model_validator(mode="after")
    def _one(self):
        if (self.group is None) == (self.plane is None):
            raise ValueError("give exactly one of group (its bonds) or plane (the bonds "
                             "crossing it)")
        if self.cut and self.factor is not None:
            raise ValueError("give factor (weaken) or cut: true (break), not both")
        if not self.cut and self.factor is None and self.friction_factor is None:
            raise ValueError("give factor, friction_factor or cut: true")
        if self.plane is not None and self.friction_factor is not None:
            raise ValueError("friction_factor needs a group: friction is a property of the "
                             "elements, not of the bonds crossing a plane")
        return self

    def check(self, cfg, groups):
        dim = cfg.model.dim
        out = []
        if self.group is not None and self.group not in groups:
            out.append((("group",), unknown_group(self.group, groups)))
        if self.plane is not None:
            for f in ("point", "normal"):
                if len(getattr(self.plane, f)) != dim:
                    out.append((("plane", f), f"{dim} components needed (dim = {dim}), got "
                                              f"{len(getattr(self.plane, f))}"))
            if not any(self.plane.normal):
                out.append((("plane", "normal"), "the normal is zero; give a direction"))
        return out

    def selected_bonds(self, st):
        """``(rows, cols)`` of the selected bonds' slots (both slots of each bond)."""
        from geodem.core.state import BONDED

        rows, cols = np.nonzero((st.nbr >= 0) & (st.cstate == BONDED))
        j = st.nbr[rows, cols]
        if self.plane is not None:
            side = (st.x - np.asarray(self.plane.point)) @ np.asarray(self.plane.normal) > 0.0
            sel = side[rows] != side[j]
        else:
            g = np.ones(st.n, bool) if self.group == "all" else st.group_mask(self.group)
            sel = (g[rows] & g[j]) if self.bonds == "inside" else (g[rows] | g[j])
        return rows[sel], cols[sel]

    def execute(self, ctx):
        sim = ctx.sim
        st = ctx.state
        rows, cols = self.selected_bonds(st)
        j = st.nbr[rows, cols]
        pair = rows < j
        e = sim.energies()
        heat0 = e["heat_break_normal"] + e["heat_break_shear"]
        cracks0 = len(sim.crack_log())
        res = {"bonds_weakened": 0, "bonds_cut": 0, "elements_friction_reduced": 0}
        if self.cut:
            res["bonds_cut"] = int(sim.cut(rows[pair], j[pair]))
        elif self.factor is not None:
            scale_bond_rate(st, (rows, cols), self.factor)
            res["bonds_weakened"] = int(pair.sum())
        if self.friction_factor is not None:
            idx = np.arange(st.n) if self.group == "all" else np.flatnonzero(
                st.group_mask(self.group))
            st.mu[idx] = st.mu[idx] * self.friction_factor
            res["elements_friction_reduced"] = int(idx.size)
        sim.backend.push(("brate", "props"))
        # at the same positions: bonds beyond their new strength break now, contacts beyond
        # their new friction slide now, booked as in any step
        sim.refresh_forces()
        e = sim.energies()
        res["bonds_broken"] = len(sim.crack_log()) - cracks0 - res["bonds_cut"]
        res["heat_booked"] = e["heat_break_normal"] + e["heat_break_shear"] - heat0
        res["bonds_left"] = sim.bonded_count()
        ctx.log(f"{res['bonds_weakened']} bonds weakened, {res['bonds_cut']} cut, "
                f"{res['bonds_broken']} broke at once; {res['bonds_left']} bonds left")
        return res
