"""The slope case: strength reduction of a weak layer until the slope fails.

workflows/slope_weak_layer.yaml composes the slope from parts: a ``scene`` on the terrain of an
elevation raster with a weak ``band``, gravity, a fixed base and roller sides, a balance under
gravity. Only what is special to the slope is here:

* step ``slope_stability`` (the strength reduction method, Dawson, Roth & Drescher 1999, in its
  DEM form): for each trial factor ``F`` of ``factors`` (ascending), the bonds touching
  ``group`` get ``1 / F`` of their strength (``xb`` and ``fs0`` through each bond's rate) and the
  group's elements ``1 / F`` of their friction coefficient (``tan phi / F``), both relative to
  the values when the step started; then ``nsteps`` time steps run. The slope has *failed* at
  ``F`` when the mean displacement of ``watch`` during those steps exceeds
  ``failure_displacement``: it is still moving instead of settling. The factor of safety is the
  last factor at which it did not fail (reported as ``factor_of_safety``; ``null`` if it fails at
  the first factor; at least the last factor if it never fails, ``failed: false``).

  Results: ``stages`` (per factor: ``factor``, ``displacement`` during the stage and
  ``total_displacement`` since the step started, mean over ``watch`` [m], ``max_displacement``
  [m], ``bonds_broken`` during the stage, ``kinetic`` at its end [J]), ``factor_of_safety``,
  ``failed_at``, ``failed``; the picture ``<name>.png`` (displacement against F; the elements
  coloured by their displacement at the end).

  Checkpoint and resume: the strengths and friction at the start and the positions are kept in
  ``<name>_start.npz``; the stages done are in the run's results.
"""
from __future__ import annotations

import numpy as np

from geodem.workflow.schema import F, Int, Name, StepBase, register_step, unknown_group

START = "{name}_start.npz"


@register_step("slope_stability")
class SlopeStability(StepBase):
    """Strength reduction of a group's bonds and friction by trial factors until the slope moves
    on: the factor of safety (geodem.cases.slope)."""

    example = {"kind": "slope_stability", "group": "top", "factors": [1.0, 2.0],
               "nsteps": 100}
    group: Name = F(..., description="Group whose bonds (touching it) and friction are reduced")
    watch: Name = F("all", description="Group whose mean displacement decides failure")
    factors: list[float] = F(..., min_length=1, description="Trial factors of safety, "
                                                            "ascending, each >= 1")
    nsteps: Int = F(..., ge=1, description="Time steps at each factor")
    failure_displacement: float = F(0.5, unit="m", gt=0,
                                    description="Mean displacement of watch during a stage "
                                                "above which the slope has failed")
    stop_at_failure: bool = F(True, description="Stop after the first factor that fails")
    plot: bool = F(True, description="Draw <name>.png (needs matplotlib)")

    def check(self, cfg, groups):
        out = []
        for key in ("group", "watch"):
            g = getattr(self, key)
            if g not in groups:
                out.append(((key,), unknown_group(g, groups)))
        f = list(self.factors)
        if any(v < 1.0 for v in f):
            out.append((("factors",), f"factors must be >= 1 (strength / F), got {f}"))
        if any(b <= a for a, b in zip(f, f[1:])):
            out.append((("factors",), f"factors must be ascending, got {f}"))
        return out

    def planned_steps(self, plan):
        return int(self.nsteps) * len(self.factors)

    # ------------------------------------------------------------------ start
    def _start(self, ctx):
        """The selection, strengths, friction and positions at the start (kept in a file)."""
        from geodem.core.state import BONDED

        path = ctx.out_dir / START.format(name=self.name)
        if ctx.resumed and path.exists():
            z = np.load(path)
            return {k: z[k] for k in z.files}
        st = ctx.sim.sync()
        g = st.group_mask(self.group) if self.group != "all" else np.ones(st.n, bool)
        rows, cols = np.nonzero((st.nbr >= 0) & (st.cstate == BONDED))
        j = st.nbr[rows, cols]
        sel = g[rows] | g[j]
        rec = {"rows": rows[sel], "cols": cols[sel], "brate": st.brate[rows[sel], cols[sel]],
               "elements": np.flatnonzero(g), "mu": st.mu[np.flatnonzero(g)].copy(),
               "x": st.x.copy()}
        np.savez(path, **rec)
        if path.name not in ctx.runner.files:
            ctx.runner.files.append(path.name)
        return rec

    def _reduce(self, ctx, start, factor):
        st = ctx.sim.state
        st.brate[start["rows"], start["cols"]] = (start["brate"].astype(np.float64)
                                                  / factor).astype(st.brate.dtype)
        st.mu[start["elements"]] = start["mu"] / factor
        ctx.sim.backend.push(("brate", "props"))
        ctx.sim.refresh_forces()  # bonds beyond their new strength break now
        ctx.sim.sync()  # the forces it computed, back on the host before the next run

    # ------------------------------------------------------------------ run
    def execute(self, ctx):
        sim = ctx.sim
        start = self._start(ctx)
        rec = ctx.runner.results.get(self.name) if ctx.resumed else None
        rec = rec or {"stages": [], "factor_of_safety": None, "failed_at": None,
                      "failed": False}
        watch = (np.ones(sim.state.n, bool) if self.watch == "all"
                 else sim.state.group_mask(self.watch))
        for k, factor in enumerate(self.factors):
            if k < len(rec["stages"]):
                continue
            if rec["failed"] and self.stop_at_failure:
                break
            st = sim.sync()
            x_stage = st.x.copy()
            cracks0 = len(sim.crack_log())
            self._reduce(ctx, start, factor)
            ctx.advance((k + 1) * int(self.nsteps))
            st = sim.sync()
            step_u = np.linalg.norm(st.x - x_stage, axis=1)
            total_u = np.linalg.norm(st.x - start["x"], axis=1)
            stage = {"factor": float(factor),
                     "displacement": float(step_u[watch].mean()),
                     "total_displacement": float(total_u[watch].mean()),
                     "max_displacement": float(total_u[watch].max()),
                     "bonds_broken": len(sim.crack_log()) - cracks0,
                     "kinetic": float(sim.energies()["kinetic"])}
            rec["stages"].append(stage)
            failed = stage["displacement"] > self.failure_displacement
            ctx.log(f"F = {factor:g}: {self.watch} moved {stage['displacement']:.4g} m during "
                    f"the stage (mean), {stage['bonds_broken']} "
                    f"bond{'' if stage['bonds_broken'] == 1 else 's'} broke"
                    + (": failed" if failed else ""))
            if failed and not rec["failed"]:
                rec["failed"], rec["failed_at"] = True, float(factor)
            if not rec["failed"]:
                rec["factor_of_safety"] = float(factor)
            ctx.runner.results[self.name] = rec  # a checkpoint between stages knows them
        if self.plot and ctx.cfg.outputs.plots:
            st = sim.sync()
            u = np.linalg.norm(st.x - start["x"], axis=1)
            rec["plot"] = ctx.plot(f"{self.name}.png", lambda path: _plot(
                path, rec, st.x, u, self.failure_displacement, self.name))
        ctx.runner.results[self.name] = rec
        return rec


def _plot(path, rec, x, u, limit, title):
    from geodem.workflow.animation import pyplot

    plt = pyplot()
    if plt is None:
        return None
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8), gridspec_kw={"width_ratios": [1, 2]})
    f = [s["factor"] for s in rec["stages"]]
    a.semilogy(f, [max(s["displacement"], 1e-12) for s in rec["stages"]], "o-",
               label="during the stage")
    a.axhline(limit, color="r", ls="--", lw=0.8, label="failure displacement")
    a.set_xlabel("trial factor of safety F [-]")
    a.set_ylabel("mean displacement [m]")
    a.legend(loc="upper left", fontsize=8)
    fos = rec["factor_of_safety"]
    a.set_title(f"factor of safety {fos:g}" if fos is not None else "fails at the first factor")
    sc = b.scatter(x[:, 0], x[:, -1], c=u, s=3, cmap="magma", linewidths=0)
    fig.colorbar(sc, ax=b, label="displacement since the start [m]")
    b.set_xlabel("distance along the section [m]")
    b.set_ylabel("elevation [m]")
    b.set_aspect("equal")
    b.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)
    return path
