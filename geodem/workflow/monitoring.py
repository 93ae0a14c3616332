"""Generic step kinds that work on any model: ``monitor`` (time series) and ``pressure``.

* ``monitor``: from where it stands in the workflow on, records every ``every`` time steps
  (and once when it starts and once at the end of the workflow), through all later steps
  (run, balance, pressure, the cases' steps), a row of ``monitor.csv``: ``step``, ``time [s]``,
  then per named **point** the displacement and velocity of the element nearest to it (in the
  built model), per **group** its mean displacement and velocity and the Love-Weber (virial)
  mean stress of its elements' contact forces (:func:`geodem.measure.contact_stress`, tension
  positive, over the group's volume: given in ``volumes``, else the sum of the elements'
  close-packed cells, ``2 sqrt(3) r^2 t`` in 2-D with the element thickness ``t`` (the model's
  2-D thickness, else ``2 r``) and ``4 sqrt(2) r^3`` in 3-D), and the number of **broken bonds**
  (tensile and shear cracks; joints cut at the build are not counted). Displacements are from
  the built positions (as ``observables``). ``monitor.png`` plots the columns against time.
  The samples lie on multiples of ``every`` (absolute step numbers), so a run resumed from a
  checkpoint keeps the rows up to the checkpoint and records the same rows after it.
* ``pressure``: a normal pressure ``p`` [Pa] (compression positive: it pushes on the surface)
  on a boundary group, or on the wall of a cavity (``shape: {disc: ...}``). Each surface
  element carries ``p x A / n`` along the inward normal (``A``: the loaded area, ``n``: the
  elements carrying it), a dead load (fixed direction and size) added to the other loads of
  those elements. Area convention (the ``specimen`` model's): for a ``side`` group of the model
  (``scene``, ``lattice_block``) the side's outward normal and the model's extent across it,
  from element surface to surface, per transverse axis; 2-D times the thickness ``t`` (the
  model's 2-D thickness, else the mean element diameter of the group); another group needs
  ``side`` and uses its own extent across. ``area`` overrides the loaded area. For a cavity
  (a disc in 2-D, a cylinder along y in 3-D) the elements within one diameter of its wall
  (centre distance from ``radius`` to ``radius + 2 r``) carry ``p 2 pi R t`` (3-D: ``t`` =
  the model's extent along y) along the direction from the centre to them, shared by the
  angle each covers around the centre (3-D: evenly).
  With ``ramp`` (seconds) or ``ramp_steps`` the step itself runs the ramp's time steps: the
  pressure rises linearly from its current value (the last ``pressure`` step on the same
  surface, else 0) to ``pressure`` in equal increments every ``update_every`` steps (each
  increment lands at the start of its interval), and stays constant afterwards. The work of the
  pressure is booked as external work by the time-step loop (force x displacement), so the
  energy books stay closed.
"""
from __future__ import annotations

import csv
import math
from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.workflow.models import SIDES
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

COMPONENTS = "xyz"


# ============================================================================ CSV helpers
def write_csv(path, header, rows=()) -> None:
    """A new CSV file: ``header`` then ``rows``."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


def append_csv(path, row) -> None:
    with open(path, "a", newline="") as f:
        csv.writer(f).writerow(row)


def read_csv(path, text=False):
    """``(header, rows)`` of a CSV file of numbers (rows as lists of floats, the step as int;
    ``text``: the rows as written, strings)."""
    with open(path, newline="") as f:
        lines = list(csv.reader(f))
    if not lines:
        return [], []
    rows = [r for r in lines[1:] if r]
    if text:
        return lines[0], rows
    return lines[0], [[int(float(r[0]))] + [float(v) for v in r[1:]] for r in rows]


def sample_steps(start: int, end: int, every: int) -> list:
    """The steps a monitor started at ``start`` records up to ``end``: ``start``, the multiples
    of ``every`` after it, and ``end`` when it is not one of those."""
    out = [int(start)] + list(range((start // every + 1) * every, end + 1, every))
    if out[-1] != end:
        out.append(int(end))
    return out


# ============================================================================ geometry
def nearest_elements(x, points) -> tuple[np.ndarray, np.ndarray]:
    """Index of the element of ``x`` (N, dim) nearest to each of ``points`` (P, dim), and its
    distance [m]."""
    x = np.asarray(x, float)
    idx, dist = [], []
    for p in np.atleast_2d(np.asarray(points, float)):
        d2 = ((x - p) ** 2).sum(axis=1)
        k = int(np.argmin(d2))
        idx.append(k)
        dist.append(math.sqrt(float(d2[k])))
    return np.asarray(idx, np.int64), np.asarray(dist)


def cell_volume(state, idx) -> float:
    """Sum of the close-packed cells of elements ``idx`` [m^3]: ``2 sqrt(3) r^2 t`` in 2-D
    (``t``: the state's 2-D thickness, else ``2 r``), ``4 sqrt(2) r^3`` in 3-D."""
    r = state.r[idx]
    if state.dim == 3:
        return float((4.0 * math.sqrt(2.0) * r ** 3).sum())
    t = float(getattr(state, "thickness", 0.0) or 0.0)
    t = t if t > 0 else 2.0 * r
    return float((2.0 * math.sqrt(3.0) * r * r * t).sum())


def _thickness(state, idx) -> float:
    t = float(getattr(state, "thickness", 0.0) or 0.0)
    return t if t > 0 else float(2.0 * state.r[idx].mean())


def side_load(state, idx, side: str, extent_of=None, area: float | None = None, x=None):
    """Force per pascal on each element ``idx`` of a side ``side`` (xmin, ..., zmax): ``(unit
    forces (n, dim) [N/Pa], loaded area [m^2])``. The area is ``area`` if given, else the extent
    across the side's normal of the elements ``extent_of`` (default ``idx``; the whole model
    for a side group), from element surface to surface, per transverse axis, at positions ``x``
    (default the state's; the workflow step takes the built ones), times the 2-D thickness;
    split evenly, along the inward normal (a pressure pushes on the surface)."""
    dim = state.dim
    ax = DOF_NAMES.index(side[0])
    sign = 1.0 if side.endswith("max") else -1.0
    if area is None:
        sel = idx if extent_of is None else extent_of
        x, r = (state.x if x is None else x)[sel], state.r[sel]
        area = 1.0
        for k in range(dim):
            if k != ax:
                area *= float((x[:, k] + r).max() - (x[:, k] - r).min())
        if dim == 2:
            area *= _thickness(state, idx)
    unit = np.zeros((len(idx), dim))
    unit[:, ax] = -sign * area / len(idx)
    return unit, float(area)


def cavity_load(state, center, radius, area: float | None = None, x=None):
    """Elements lining a cavity (disc in 2-D, cylinder along y in 3-D) of ``radius`` at
    ``center``: those whose centre lies from ``radius`` to ``radius + 2 r`` from its axis (at
    positions ``x``, default the state's). Returns ``(idx, unit forces (n, dim) [N/Pa], area
    [m^2])`` (default ``2 pi R t``; 3-D: ``t`` the model's extent along y), from the centre
    outwards. In 2-D each element carries the share of the wall its angle covers (half the
    angles to its neighbours around the centre), so the forces on an uneven lining add up to
    no net force; in 3-D ``area / n`` each."""
    c = np.asarray(center, float)
    x = state.x if x is None else x
    rel = x - c
    if state.dim == 3:
        rel[:, 1] = 0.0  # cylinder along y
    dist = np.linalg.norm(rel, axis=1)
    idx = np.flatnonzero((dist >= radius) & (dist < radius + 2.0 * state.r))
    if idx.size == 0:
        return idx, np.zeros((0, state.dim)), 0.0
    if area is None:
        if state.dim == 2:
            t = _thickness(state, idx)
        else:
            t = float((x[:, 1] + state.r).max() - (x[:, 1] - state.r).min())
        area = 2.0 * math.pi * radius * t
    share = np.full(idx.size, 1.0 / idx.size)
    if state.dim == 2 and idx.size > 1:
        ang = np.arctan2(rel[idx, 1], rel[idx, 0])
        order = np.argsort(ang, kind="stable")
        a = ang[order]
        gap = np.diff(np.concatenate([a, a[:1] + 2.0 * math.pi]))  # to the next one round
        share[order] = 0.5 * (gap + np.roll(gap, 1)) / (2.0 * math.pi)
    unit = rel[idx] / dist[idx, None] * (area * share)[:, None]
    return idx, unit, float(area)


def add_load(sim, idx, df) -> None:
    """Add ``df`` (n, dim) [N] to the loads of elements ``idx`` between time steps, with the
    stored acceleration of their free degrees of freedom made consistent (``a += df / m``):
    vector operations only, no validation pass over the model (``Simulation.change`` does the
    same for any change, with one)."""
    b = sim.backend
    b.pull(("fload", "a"))
    st = sim.state
    st.fload[idx] += df
    st.a[idx] += df * (st.free[idx] != 0.0) / st.m[idx, None]
    b.push(("fload", "a"))


# ============================================================================ monitor
def current_rows(sim, built) -> tuple[np.ndarray, np.ndarray]:
    """Element numbers of the model as built -> ``(indices in the current state, present)``:
    they differ after an excavation (``Simulation.ids``, ascending: a removal keeps the order);
    an excavated element is not present."""
    built = np.asarray(built, np.int64)
    ids = getattr(sim, "ids", None)
    if ids is None:
        return built, np.ones(len(built), bool)
    ids = np.asarray(ids, np.int64)
    if len(ids) == 0:
        return np.zeros(len(built), np.int64), np.zeros(len(built), bool)
    pos = np.clip(np.searchsorted(ids, built), 0, len(ids) - 1)
    return pos, ids[pos] == built


class MonitorRecorder:
    """The per-sample recorder of a ``monitor`` step (see the module doc); registered with
    :meth:`~geodem.workflow.runner.StepContext.add_sampler`."""

    def __init__(self, step, ctx):
        from geodem.core import groups as grp

        self.step, self.runner = step, ctx.runner
        self.sim = ctx.sim
        self.every = int(step.every)
        self.path = ctx.out_dir / step.file
        st = ctx.state
        self.dim = dim = st.dim
        self.model = ctx.model  # its reference positions follow an excavation
        self.ref = ctx.model.reference
        comp = COMPONENTS[:dim]
        cols = ["step", "time [s]"]
        names = list(step.points)
        self.points = {}
        if names:
            idx, dist = nearest_elements(self.ref, [step.points[n] for n in names])
            self.points = {n: (int(i), float(dd)) for n, i, dd in zip(names, idx, dist)}
            self.point_idx = self._built(idx)
        for n in names:
            cols += [f"{n}.u{c} [m]" for c in comp] + [f"{n}.v{c} [m/s]" for c in comp]
        self.groups = {}
        pairs = [(a, b) for k, a in enumerate(comp) for b in comp[k:]]
        self.pairs = [(COMPONENTS.index(a), COMPONENTS.index(b)) for a, b in pairs]
        for g in step.groups:
            idx = grp.members(st, g)
            vol = step.volumes.get(g) if step.volumes else None
            self.groups[g] = (self._built(idx),
                              float(vol) if vol is not None else cell_volume(st, idx))
            cols += [f"{g}.u{c} [m]" for c in comp] + [f"{g}.v{c} [m/s]" for c in comp]
            if step.stress:
                cols += [f"{g}.s{a}{b} [Pa]" for a, b in pairs]
        if step.broken_bonds:
            cols.append("broken_bonds [1]")
        self.columns = cols
        self.last_step = None
        self.samples = 0

    # -------------------------------------------------------------- numbering
    def _built(self, idx) -> np.ndarray:
        """Element indices of the current state -> their numbers in the model as built (they
        differ after an excavation: ``Simulation.ids``)."""
        ids = getattr(self.sim, "ids", None)
        idx = np.asarray(idx, np.int64)
        return idx if ids is None else np.asarray(ids, np.int64)[idx]

    def _current(self, built) -> tuple[np.ndarray, np.ndarray]:
        return current_rows(self.sim, built)

    # -------------------------------------------------------------- rows
    def row(self) -> list:
        from geodem.measure import contact_stress

        sim = self.sim
        st = sim.sync()
        ref = self.model.reference
        out = [int(st.step), float(st.time)]
        if self.points:
            idx, present = self._current(self.point_idx)
            u, v = st.x[idx] - ref[idx], st.v[idx].copy()
            u[~present] = np.nan
            v[~present] = np.nan
            for k in range(len(idx)):
                out += u[k].tolist() + v[k].tolist()
        for built, vol in self.groups.values():
            idx, present = self._current(built)
            idx = idx[present]
            if len(idx) == 0:
                out += [math.nan] * (2 * self.dim + (len(self.pairs) if self.step.stress else 0))
                continue
            out += (st.x[idx] - ref[idx]).mean(axis=0).tolist()
            out += st.v[idx].mean(axis=0).tolist()
            if self.step.stress:
                sig = contact_stress(st, idx, vol)
                out += [float(sig[a, b]) for a, b in self.pairs]
        if self.step.broken_bonds:
            out.append(int(np.count_nonzero(np.asarray(sim.cracks["type"], np.int64))))
        return out

    def sample(self) -> None:
        row = self.row()
        append_csv(self.path, row)
        self.last_step = row[0]
        self.samples += 1
        self._results(row)

    def _results(self, row) -> None:
        res = {"file": self.step.file, "samples": self.samples, "every": self.every,
               "last": {c: v for c, v in zip(self.columns, row)}}
        if self.points:
            res["points"] = {n: {"element": i, "distance": d} for n, (i, d) in
                             self.points.items()}
        if self.groups:
            res["volumes"] = {g: vol for g, (_, vol) in self.groups.items()}
        self.runner.results[self.step.name] = res

    # -------------------------------------------------------------- start, resume, end
    def start(self) -> None:
        write_csv(self.path, self.columns)
        if self.step.file not in self.runner.files:
            self.runner.files.append(self.step.file)
        self.sample()

    def resume(self) -> None:
        """Keep the rows the checkpoint covers (step <= the step now), drop any after it."""
        step = int(self.sim.state.step)
        rows = []
        if self.path.exists():
            _, rows = read_csv(self.path, text=True)  # rewritten as they were: same bytes
            rows = [r for r in rows if int(r[0]) <= step]
        write_csv(self.path, self.columns, rows)
        self.samples = len(rows)
        self.last_step = int(rows[-1][0]) if rows else None
        if rows:
            self._results([int(rows[-1][0])] + [float(v) for v in rows[-1][1:]])

    def finish(self) -> None:
        step = self.step
        if not (step.plot and self.runner.cfg.outputs.plots):
            return
        ctx = _PlotContext(self.runner)
        png = self.path.with_suffix(".png").name
        _, rows = read_csv(self.path)
        ctx.plot(png, lambda path: plot_monitor(path, self.columns, rows))


class _PlotContext:
    """What :meth:`StepContext.plot` needs, at the end of the workflow (no step running)."""

    def __init__(self, runner):
        from geodem.workflow.runner import StepContext

        self.plot = lambda name, draw: StepContext.plot(self, name, draw)
        self.runner, self.out_dir = runner, runner.dir.path

    def log(self, msg):
        self.runner.reporter.message(msg)


def plot_monitor(path, columns, rows):
    """monitor.png: one panel per quantity (displacement [m], velocity [m/s], stress [Pa],
    broken bonds [1]) against time [s]; legends beside the panels. None without matplotlib."""
    from geodem.workflow.animation import pyplot

    plt = pyplot()
    if plt is None:
        return None
    a = np.asarray(rows, float).reshape(len(rows), len(columns))
    t = a[:, 1]
    panels = [("displacement", "m", lambda c: ".u" in c and c.endswith("[m]")),
              ("velocity", "m/s", lambda c: ".v" in c and c.endswith("[m/s]")),
              ("stress (tension +)", "Pa", lambda c: c.endswith("[Pa]")),
              ("broken bonds", "1", lambda c: c.startswith("broken_bonds"))]
    used = [(title, unit, [k for k, c in enumerate(columns) if k > 1 and want(c)])
            for title, unit, want in panels]
    used = [u for u in used if u[2]]
    fig, axes = plt.subplots(len(used), 1, figsize=(7.5, 2.2 * len(used) + 0.6), squeeze=False,
                             sharex=True)
    for ax, (title, unit, ks) in zip(axes[:, 0], used):
        for k in ks:
            ax.plot(t, a[:, k], label=columns[k].rsplit(" [", 1)[0], lw=1.2)
        ax.set_ylabel(f"{title} [{unit}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, borderaxespad=0.0)
    axes[-1, 0].set_xlabel("time [s]", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


@register_step("monitor")
class Monitor(StepBase):
    """Record time series while the later steps run (monitor.csv, monitor.png): the
    displacement and velocity of the elements nearest to named points, the mean displacement,
    velocity and contact stress of groups, the number of broken bonds
    (geodem.workflow.monitoring)."""

    example = {"kind": "monitor", "every": 5, "points": {"tip": [0.02, 0.02]},
               "groups": ["top"]}
    every: Int = F(100, ge=1, description="Time steps between samples (on multiples of it)")
    points: dict[Name, list[float]] = F({}, unit="m", description="Named points: the element "
                                        "nearest to each (built positions) is recorded")
    groups: list[Name] = F([], description="Groups: mean displacement, velocity and stress")
    stress: bool = F(True, description="Record the groups' Love-Weber contact stress")
    volumes: dict[Name, float] = F({}, unit="m^3", description="Volume of a group for its "
                                   "stress (2-D: area x thickness); default: the sum of its "
                                   "elements' close-packed cells")
    broken_bonds: bool = F(True, description="Record the number of broken bonds")
    file: str = F("monitor.csv", pattern=r"^[A-Za-z0-9_.-]+\.csv$",
                  description="CSV file in the run directory (the picture: same name, .png)")
    plot: bool = F(True, description="Draw the picture (needs matplotlib)")

    def check(self, cfg, groups):
        out = []
        dim = cfg.model.dim if getattr(cfg.model, "dim", None) in (2, 3) else None
        for name, p in self.points.items():
            if dim is not None and len(p) != dim:
                out.append((("points", name), f"point {name!r} needs {dim} coordinates "
                                              f"(dim = {dim}), got {len(p)}"))
            if name in self.groups:
                out.append((("points", name), f"{name!r} names a point and a group; the "
                                              f"columns need distinct names"))
        for k, g in enumerate(self.groups):
            if g not in groups:
                out.append((("groups", k), unknown_group(g, groups)))
        for g, v in self.volumes.items():
            if g not in self.groups:
                out.append((("volumes", g), f"{g!r} is not one of this monitor's groups "
                                            f"({', '.join(self.groups) or 'none'})"))
            elif not v > 0:
                out.append((("volumes", g), f"volume {v!r}; allowed: > 0 [m^3]"))
        if not (self.points or self.groups or self.broken_bonds):
            out.append(((), "nothing to record: give points, groups or broken_bonds: true"))
        files = [s.file for s in cfg.steps if isinstance(s, Monitor)]
        if files.count(self.file) > 1:
            out.append((("file",), f"{self.file!r} is written by another monitor step too; "
                                   f"give each monitor its own file"))
        return out

    def execute(self, ctx):
        rec = MonitorRecorder(self, ctx)
        if ctx.resumed:
            rec.resume()
        else:
            rec.start()
        ctx.add_sampler(rec)
        where = ", ".join(f"{n} -> element {i} ({d:.3g} m away)" for n, (i, d) in
                          rec.points.items())
        ctx.log(f"recording {len(rec.columns) - 2} columns every {self.every} steps to "
                f"{self.file}" + (f"; points: {where}" if where else ""))
        far = [n for n, (i, d) in rec.points.items() if d > 2.0 * float(ctx.state.r[i])]
        if far:
            msg = (f"step {self.name!r}: point(s) {', '.join(far)} lie more than an element "
                   f"diameter from the nearest element (outside the model?)")
            ctx.log("warning: " + msg)
            ctx.summary.setdefault("warnings", []).append(msg)
        return ctx.runner.results.get(self.name)

    def restore(self, ctx):
        """On --resume after this step: the recorder again, with the rows up to the checkpoint."""
        rec = MonitorRecorder(self, ctx)
        rec.resume()
        ctx.add_sampler(rec)


# ============================================================================ pressure
# ============================================================================ snapshot
SNAPSHOT = "{name}_snapshot.npz"


@register_step("snapshot")
class Snapshot(StepBase):
    """Keep the element positions of this moment in ``<name>_snapshot.npz`` (``x`` [m],
    ``ids``: each element's number in the model as built, ``step``, ``time`` [s]), for a later
    step that measures displacements since then (e.g. ``tunnel_check``). A resumed run keeps the
    file it wrote."""

    example = {"kind": "snapshot", "name": "before"}

    def execute(self, ctx):
        path = ctx.out_dir / SNAPSHOT.format(name=self.name)
        if not (ctx.resumed and path.exists()):
            st = ctx.sim.sync()
            ids = getattr(ctx.sim, "ids", None)
            np.savez(path, x=st.x, ids=np.arange(st.n) if ids is None else np.asarray(ids),
                     step=int(st.step), time=float(st.time))
        if path.name not in ctx.runner.files:
            ctx.runner.files.append(path.name)
        return {"file": path.name, "elements": int(ctx.state.n)}


def read_snapshot(out_dir, name: str, sim) -> tuple[np.ndarray, np.ndarray, dict]:
    """Positions of a :class:`Snapshot` for the elements present now: ``(x_then (n, dim) with
    NaN rows for elements that were not there, present (n,) bool, {"step", "time"})``."""
    z = np.load(out_dir / SNAPSHOT.format(name=name))
    ids = getattr(sim, "ids", None)
    now = np.arange(sim.state.n) if ids is None else np.asarray(ids, np.int64)
    then = np.asarray(z["ids"], np.int64)  # ascending: a removal keeps the order
    pos = np.clip(np.searchsorted(then, now), 0, len(then) - 1)
    present = then[pos] == now
    x = np.full((len(now), sim.state.dim), np.nan)
    x[present] = z["x"][pos[present]]
    return x, present, {"step": int(z["step"]), "time": float(z["time"])}


class CavityDisc(Strict):
    center: list[float] = F(..., unit="m", min_length=2, max_length=3,
                            description="Centre (2-D: a disc; 3-D: a cylinder along y)")
    radius: float = F(..., unit="m", gt=0, description="Radius of the cavity's wall")


class CavityShape(Strict):
    disc: CavityDisc = F(..., description="The cavity: a disc (2-D) or cylinder along y (3-D)")


@register_step("pressure")
class Pressure(StepBase):
    """A normal pressure on a boundary group or a cavity's wall (compression positive), its
    work booked; optionally ramped linearly from its current value over ``ramp`` seconds or
    ``ramp_steps`` time steps (the step runs them), constant afterwards
    (geodem.workflow.monitoring)."""

    example = {"kind": "pressure", "group": "top", "pressure": 1.0e4, "ramp_steps": 20}
    group: Optional[Name] = F(None, description="A boundary group (a side of the model, or "
                                                "give side)")
    shape: Optional[CavityShape] = F(None, description="A cavity's wall instead of a group")
    side: Optional[Literal[SIDES]] = F(  # type: ignore[valid-type]
        None, description="Side the group lies on (xmin, ..., zmax); default: the group's own "
                           "side in the model")
    pressure: float = F(..., unit="Pa", description="Pressure (positive: pushes on the surface)")
    area: Optional[float] = F(None, unit="m^2", gt=0, description="Loaded area (default: the "
                                                                  "area convention)")
    ramp: Optional[float] = F(None, unit="s", gt=0, description="Ramp duration")
    ramp_steps: Optional[Int] = F(None, ge=1, description="Ramp duration in time steps")
    update_every: Optional[Int] = F(None, ge=1, description="Time steps between the ramp's "
                                                            "increments (default: 1/100 of "
                                                            "the ramp)")

    @model_validator(mode="after")
    def _one(self):
        if (self.group is None) == (self.shape is None):
            raise ValueError("give exactly one of group or shape")
        if self.ramp is not None and self.ramp_steps is not None:
            raise ValueError("give at most one of ramp (seconds) and ramp_steps")
        if self.shape is not None and self.side is not None:
            raise ValueError("side applies to a group, not to a cavity's shape")
        return self

    def _model_side(self, cfg):
        spec = (getattr(cfg.model, "groups", None) or {}).get(self.group)
        return getattr(spec, "side", None)

    def check(self, cfg, groups):
        out = []
        dim = getattr(cfg.model, "dim", None)
        if self.group is not None:
            if self.group not in groups:
                return [(("group",), unknown_group(self.group, groups))]
            own = self._model_side(cfg)
            side = self.side or own
            if side is None:
                out.append((("side",), f"group {self.group!r} is not a side of the model: give "
                                       f"side (xmin, ..., zmax), the face it lies on"))
            elif dim in (2, 3) and DOF_NAMES.index(side[0]) >= dim:
                out.append((("side",), f"side {side!r} does not exist in {dim}-D"))
        elif dim in (2, 3) and len(self.shape.disc.center) != dim:
            out.append((("shape", "disc", "center"), f"{dim} coordinates needed (dim = {dim})"))
        return out

    def planned_steps(self, plan):
        if self.ramp_steps is not None:
            return int(self.ramp_steps)
        if self.ramp is not None:
            return max(1, int(math.ceil(self.ramp / plan.dt - 1e-9)))
        return 0

    def _key(self):
        if self.group is not None:
            return ("group", self.group, self.side)
        d = self.shape.disc
        return ("disc", tuple(d.center), d.radius)

    def _start_value(self, ctx) -> float:
        """The pressure on this surface before the step: the last earlier pressure step's."""
        p = 0.0
        for s in ctx.cfg.steps[:ctx.index]:
            if isinstance(s, Pressure) and s._key() == self._key():
                p = float(s.pressure)
        return p

    def loads(self, cfg, state, x=None):
        """``(idx, unit forces (n, dim) [N/Pa], area [m^2])`` of this step's surface, from the
        positions ``x`` (default the state's; the step takes the built ones: the same loads
        however far the model has moved, and on --resume)."""
        from geodem.core import groups as grp

        if self.shape is not None:
            d = self.shape.disc
            return cavity_load(state, d.center, d.radius, self.area, x=x)
        idx = grp.members(state, self.group)
        own = self._model_side(cfg)
        side = self.side or own
        whole = np.arange(state.n) if own is not None and side == own else None
        unit, area = side_load(state, idx, side, extent_of=whole, area=self.area, x=x)
        return idx, unit, area

    def execute(self, ctx):
        from geodem.workflow.errors import RunFailure

        sim = ctx.sim
        st = ctx.state
        idx, unit, area = self.loads(ctx.cfg, st, x=ctx.model.reference)
        if idx.size == 0:
            raise RunFailure(f"step {self.name!r}: no element lines the cavity (centre "
                             f"{self.shape.disc.center}, radius {self.shape.disc.radius} m)")
        p0, p1 = self._start_value(ctx), float(self.pressure)
        total = self.planned_steps(ctx.plan)
        k = int(self.update_every or max(1, math.ceil(total / 100))) if total else 0
        res = {"pressure": p1, "pressure_start": p0, "area": area, "elements": int(idx.size),
               "mean_force_per_element": float(p1 * area / idx.size),
               "total_force": (p1 * unit.sum(axis=0)).tolist(), "ramp_steps": total,
               "update_every": k}
        prev = ctx.runner.results.get(self.name) if ctx.resumed else None
        applied = float(prev["applied"]) if prev else p0
        at = int(prev["applied_at"]) if prev else -1  # the ramp offset its value landed at

        def apply(value, offset):
            nonlocal applied
            add_load(sim, idx, (value - applied) * unit)
            applied = value
            ctx.runner.results[self.name] = dict(res, applied=applied, applied_at=offset)

        if not total:
            if not ctx.resumed:
                apply(p1, 0)
            return ctx.runner.results.get(self.name, dict(res, applied=p1, applied_at=0))
        if at < 0:
            ctx.log(f"ramp {p0:.4g} -> {p1:.4g} Pa over {total} steps on {idx.size} elements "
                    f"(area {area:.4g} m^2), an increment every {k} steps")
        else:
            ctx.advance(min(total, at + k))  # the interval the checkpoint fell in
        b = at + k if at >= 0 else 0
        while b < total:
            end = min(total, b + k)
            apply(p0 + (p1 - p0) * end / total, b)
            ctx.advance(end)
            b = end
        return ctx.runner.results[self.name]
