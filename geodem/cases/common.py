"""Helpers shared by the cases, written once: the platen-driven test step (uniaxial, direct
tension), the "this step needs model type X" check, the curve CSV files a resumed run reads back,
and the GIF of a run's snapshots."""
from __future__ import annotations

import csv
import math
from typing import Optional

import numpy as np

from geodem.workflow.animation import figure_rgb, pyplot, save_gif
from geodem.workflow.monitoring import append_csv, write_csv  # noqa: F401 (the cases' CSV helpers)
from geodem.workflow.schema import F, StepBase


# ============================================================================ checks
def needs_model(cfg, model_type: str, message: str) -> list:
    """``[(("kind",), message)]`` when the workflow's model is not of type ``model_type``, else
    ``[]`` (a step's :meth:`~geodem.workflow.schema.StepBase.check`)."""
    if getattr(cfg.model, "type", None) != model_type:
        return [(("kind",), message)]
    return []


# ============================================================================ curve CSV files
def read_rows(path, step, ints=(), step_column: int = 0) -> list:
    """Rows of a curve CSV (header skipped) whose column ``step_column`` is at most ``step``
    (a resumed run keeps what its checkpoint covers); columns ``ints`` as int, the rest float."""
    with open(path) as f:
        return [[int(v) if k in ints else float(v) for k, v in enumerate(r)]
                for r in list(csv.reader(f))[1:] if int(float(r[step_column])) <= step]


# ============================================================================ pictures
def frames_gif(path, items, figsize, draw, fps: float):
    """GIF of ``items`` (one frame each, drawn by ``draw(ax, item)`` on one figure of size
    ``figsize``): Pillow, else imageio; None when there is nothing to draw or
    nothing can draw it."""
    plt = pyplot()
    if plt is None or not items:
        return None
    fig, ax = plt.subplots(figsize=figsize)

    def render(z):
        ax.clear()
        draw(ax, z)
        return figure_rgb(fig)

    images = [render(z) for z in items]
    plt.close(fig)
    return save_gif(path, images, fps=fps)


# ============================================================================ platen tests
class PlatenTest(StepBase):
    """Shared part of the platen-driven tests (``uniaxial``, ``direct_tension``): the bottom
    platen fixed along the loading axis (the last), the top one moved at ``strain_rate`` x
    height, ``samples`` records over ``max_strain``. Subclasses declare ``strain_rate``,
    ``max_strain``, ``drop`` and ``plot`` (their defaults differ)."""

    example_model = {"type": "lattice_block", "dim": 2, "counts": [6, 6], "diameter": 0.01,
                     "material": "rock", "groups": {"bottom": {"side": "ymin"},
                                                    "top": {"side": "ymax"}}}
    samples: int = F(400, ge=20, le=100000, description="Samples over max_strain")
    standard_damping: bool = F(True, description="MatDEM's standard damping eta_c / N on")
    thickness: Optional[float] = F(None, unit="m", gt=0,
                                   description="2-D: thickness for the area (default d_mean)")

    def check(self, cfg, groups):
        missing = [g for g in ("bottom", "top") if g not in groups]
        if missing:
            return [(("kind",), f"{self.kind} needs the platen groups 'bottom' and 'top' (model "
                                f"type specimen has them); missing: {', '.join(missing)}")]
        return []

    def planned_steps(self, plan):
        return max(1, int(math.ceil(self.max_strain / (self.strain_rate * plan.dt))))

    def platens(self, ctx):
        """Geometry of the test from the model's reference positions: ``(st, ax, d, ref, top,
        bot, h0, height, area)`` (h0: platen-to-platen distance; area: cross-section, times
        the thickness in 2-D: surface to surface over the elements, or the box's where the
        specimen's faces were cut, ``info["cut_section"]``)."""
        from geodem.core import groups

        st = ctx.state
        ax = st.dim - 1
        d = float(ctx.model.info["diameter"])
        ref = ctx.model.reference
        top, bot = groups.members(st, "top"), groups.members(st, "bottom")
        h0 = ref[top, ax].mean() - ref[bot, ax].mean()
        height = ref[:, ax].max() - ref[:, ax].min()
        cut = ctx.model.info.get("cut_section")
        if cut is not None:
            # faces cut from a repeated periodic cell: elements overhang them, the section is
            # the box's (geodem.build.specimen.cut_section)
            widths = np.asarray(cut, dtype=float)
        else:
            r = st.r[:, None]
            widths = (ref + r).max(axis=0)[:ax] - (ref - r).min(axis=0)[:ax]  # surface to surface
        area = float(np.prod(widths)) * ((self.thickness or d) if st.dim == 2 else 1.0)
        return st, ax, d, ref, top, bot, h0, height, area

    def start_loading(self, ctx, sign: float, height: float, d: float) -> None:
        """Standard damping on (``eta_c / N``, N = height / d), bottom fixed along the loading
        axis, top moving at ``sign x strain_rate x height`` (sign -1: compression); with
        rotation, the platens' elements do not turn."""
        from geodem.core import groups, timestep

        st = ctx.state
        ax = st.dim - 1
        v = [math.nan] * st.dim
        v[ax] = sign * self.strain_rate * height

        def setup(s):
            if self.standard_damping:
                s.eta[:] = timestep.standard_damping(s, height / d)
            groups.fix(s, "bottom", [ax])
            groups.set_velocity(s, "top", v)
            if s.rotation:
                # the platens are rigid: their elements neither tilt nor roll
                for g in ("bottom", "top"):
                    i = groups.members(s, g)
                    s.rfree[i] = 0.0
                    s.w[i] = 0.0

        ctx.decree(setup, "top")
