"""Run a workflow: validate, build, plan, then execute its steps with outputs and checkpoints.

:func:`prepare` does everything that needs no time stepping (and is what ``geodem validate`` and
``--dry-run`` run): load the YAML, validate it, resolve the backend, check the memory the model
needs, build the model, check the time step, and plan the steps. Every problem there is a
:class:`~geodem.workflow.errors.WorkflowError` (exit status 2) located in the YAML file.

:class:`Runner` then executes the steps in a run directory (:mod:`geodem.workflow.rundir`).
Time steps are only ever run by :meth:`StepContext.advance`, which calls ``Simulation.run`` in
chunks that end at every scheduled event: observables, frames, checkpoints, ``--stop-after-steps``
and the end of the step. Between chunks it records, checkpoints, reports progress and reacts to
SIGINT/SIGTERM (checkpoint, then stop with status ``interrupted``). The schedule depends on the
absolute step number only, so a run resumed from a checkpoint records the same samples and ends in
the same state (bit-identical on CPU backends) as an uninterrupted one.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import signal
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from geodem import __version__
from geodem.core.checks import initial_overlap
from geodem.workflow import rundir as rd
from geodem.workflow.errors import (
    EXIT_FAILURE,
    EXIT_OK,
    ErrorItem,
    Interrupted,
    RunFailure,
    WorkflowError,
)
from geodem.workflow.yamlio import load_document

#: energy terms recorded under /observables/energy (keys of Simulation.energies())
ENERGY_TERMS = ("kinetic", "gravity", "elastic", "heat_viscous", "heat_break_normal",
                "heat_break_shear", "heat_friction", "heat_total", "work_external", "removed",
                "total", "closure_error")
#: per-group energy terms (/observables/groups/<group>/energy/<term>)
GROUP_ENERGY_TERMS = ("kinetic", "gravity", "elastic", "heat_viscous", "heat_break_normal",
                      "heat_break_shear", "heat_friction", "work_external")
CRACK_TYPES = {"joint": 0, "tensile": 1, "shear": 2}
#: rough throughput used by the --dry-run estimate [element-steps/s] (docs/performance.md)
EST_RATE = {"numba": 4.0e6, "numpy": 1.3e5, "cupy": 5.0e7}
EST_COMPILE_S = {"numba": 10.0, "numpy": 0.0, "cupy": 30.0}
#: wall-clock time one chunk of time steps aims at (reaction time to signals, progress) [s]
CHUNK_SECONDS = 0.25
#: buffered observables are written to output.h5 at most this often [s]...
FLUSH_SECONDS = 2.0
#: ... and less often when a write takes longer than this share of the interval: a small
#: specimen's ~50 series took 65-150 ms to write, 5-7 % of its run at one write per 2 s
FLUSH_SHARE = 0.01
#: ... but at least once in this interval [s]
FLUSH_MAX_SECONDS = 30.0
REQUIRED_SUMMARY = ("status", "steps", "sim_time", "wall_time_s", "element_steps_per_s",
                    "n_elements", "energy_closure_rel_error", "state_sha256")


# ============================================================================ preparation
@dataclass
class Plan:
    dt: float
    dt_source: str
    stable_dt: float
    n_across: float
    steps: list
    total_steps: int
    n_elements: int
    memory_bytes: int
    memory_available: int | None
    output_bytes: int
    checkpoint_bytes: int
    runtime_s: float
    compile_s: float
    initial_overlap: float = 0.0


@dataclass
class Prepared:
    """A validated workflow with its model built and its steps planned (no stepping yet)."""

    path: Path
    doc: object
    cfg: object
    backend: str
    built: object
    plan: Plan
    resolved: dict
    config_hash: str
    sets: tuple = ()


def human_bytes(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1024 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1024.0
    return f"{n:.3g} PB"


def _is_lock_error(exc: OSError) -> bool:
    """Whether h5py refused a file because another process holds it open (HDF5's lock)."""
    import errno

    return getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK) or \
        "unable to lock file" in str(exc)


def _check_unlocked(path: Path) -> None:
    """WorkflowError (exit 2, nothing changed) when another process holds ``path`` open."""
    if not path.exists():
        return
    import h5py

    try:
        h5py.File(path, "a").close()
    except OSError as exc:
        if _is_lock_error(exc):
            raise WorkflowError(ErrorItem(
                str(path), None, "(file)",
                f"is open in another program (HDF5 file lock); close it and run --resume again "
                f"(nothing was changed)")) from None


def _free_name(path: Path) -> Path:
    """``path``, or ``NAME.1.EXT``, ``NAME.2.EXT``, ... when it exists (never overwrite)."""
    k = 0
    out = path
    while out.exists():
        k += 1
        out = path.with_name(f"{path.stem}.{k}{path.suffix}")
    return out


def state_sha256(state) -> str:
    """sha256 of the positions followed by the velocities, as contiguous float64 bytes."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(state.x, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(state.v, dtype=np.float64).tobytes())
    return h.hexdigest()


def config_hash(resolved: dict) -> str:
    text = json.dumps(resolved, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _resolve_backend(cfg, doc) -> str:
    from geodem.backends import BackendError, resolve_name

    env = os.environ.get("GEODEM_BACKEND")
    try:
        if cfg.backend:
            return resolve_name(cfg.backend)
        if env:
            try:
                return resolve_name(env)
            except BackendError as exc:
                raise WorkflowError(ErrorItem("GEODEM_BACKEND", None, "backend",
                                              f"environment variable GEODEM_BACKEND={env!r}: "
                                              f"{exc}")) from None
        return resolve_name("auto")
    except BackendError as exc:
        raise WorkflowError(doc.error(("backend",), str(exc))) from None


def _check_memory(cfg, doc) -> tuple[int, int | None, int]:
    """``(bytes needed, bytes available or None, estimated elements)``; WorkflowError when the
    model would not fit."""
    from geodem.machine import available_memory

    m = cfg.model
    n = int(m.n_elements())
    per = int(m.bytes_per_element())
    need = n * per
    avail = available_memory()
    where = ("model", m.size_field) if m.size_field else ("model",)
    if n >= 2**31 - 1:
        raise WorkflowError(doc.error(where, f"the model would have {n:,} elements; allowed: "
                                             f"fewer than 2^31 - 1 = {2**31 - 1:,}"))
    if avail is not None and need > avail:
        raise WorkflowError(doc.error(where, (
            f"the model would have {n:,} elements and need about {human_bytes(need)} of memory "
            f"({per} bytes per element), more than the {human_bytes(avail)} available "
            f"(MemAvailable); allowed here: at most about {avail // per:,} elements")))
    return need, avail, n


#: disk room a run keeps beyond its estimates [bytes] (see Runner._check_disk_space)
DISK_HEADROOM = 4 << 20

#: most time steps one workflow step may plan: 1e12 steps take 12 days even at a microsecond each
MAX_STEPS = 10**12


def _check_step_counts(doc, steps, dt) -> None:
    for k, n in enumerate(steps):
        if n <= MAX_STEPS:
            continue
        item = doc.get(("steps", k))
        keys = [f for f in ("nsteps", "duration") if isinstance(item, dict) and f in item]
        raise WorkflowError(doc.error(("steps", k, *keys[:1]), (
            f"this step would make {n:.3g} time steps (dt = {dt:.3g} s); allowed: at most "
            f"{MAX_STEPS:.0e} per step (12 days even at a microsecond per step): lower nsteps "
            f"or duration")))


def _build(cfg, doc):
    from geodem.core.engine import validate_state
    from geodem.workflow.material import apply_material_rotation
    from geodem.workflow.models import BuildError

    try:
        with warnings.catch_warnings(record=True) as caught:
            # numbers of unphysical magnitude (1e308 m) overflow inside the builders: a build
            # that fails says so as the model's error below, without the NumPy warnings on
            # the way; a build that succeeds passes its warnings on
            warnings.simplefilter("always")
            built = cfg.model.build(cfg)
            apply_material_rotation(cfg, built)
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    except ArithmeticError as exc:
        raise WorkflowError(doc.error(("model",), (
            f"cannot build the model: {type(exc).__name__}: {exc}; the model's and the "
            f"materials' numbers overflow or divide by zero: allowed: lengths, densities and "
            f"stiffnesses of a physical magnitude"))) from None
    except BuildError as exc:
        path = exc.path if exc.path[:1] == ("materials",) else ("model",) + exc.path
        raise WorkflowError(doc.error(path, str(exc))) from None
    except MemoryError:
        raise WorkflowError(doc.error(("model", cfg.model.size_field),
                                      "out of memory while building the model; make it "
                                      "smaller")) from None
    except ValueError as exc:
        raise WorkflowError(doc.error(("model",), f"cannot build the model: {exc}")) from None
    try:
        validate_state(built.state)
    except ValueError as exc:
        raise WorkflowError(doc.error(("model",), f"the built model is not valid: {exc}")) \
            from None
    return built


def _check_initial_overlap(cfg, doc, state) -> float:
    """Refuse a model that starts with a free element overlapping another by more than
    ``simulation.overlap_limit`` x the smaller radius: the contact force throws the pair apart
    at once, and the run would only stop at its first overlap check, on a wrecked packing."""
    ratio, i, j = initial_overlap(state)
    lim = cfg.simulation.overlap_limit
    if ratio > lim:
        raise WorkflowError(doc.error(("model",), (
            f"elements {i} and {j} overlap by {ratio:.3g} x the smaller radius at the start, "
            f"more than simulation.overlap_limit = {lim:g} (at least one of them is free: the "
            f"contact force would throw them apart in the first steps); allowed: initial "
            f"overlaps up to simulation.overlap_limit x the smaller radius: build a looser "
            f"packing, or raise simulation.overlap_limit (at most 1)")))
    return ratio


def _time_step(cfg, doc, state) -> tuple[float, str, float]:
    from geodem.core import timestep

    sim = cfg.simulation
    try:
        if sim.dt is not None:
            dt, source = float(sim.dt), "simulation.dt"
        else:
            dt = timestep.default_dt(state, sim.dt_fraction)
            source = f"{sim.dt_fraction:g} x the smallest element period"
        timestep.check_dt(state, dt)
    except ValueError as exc:
        path = ("simulation", "dt") if sim.dt is not None else ("simulation", "dt_fraction")
        raise WorkflowError(doc.error(path, str(exc))) from None
    return dt, source, timestep.stable_dt_bound(state)


class _PlanInfo:
    def __init__(self, dt, n_across):
        self.dt, self.n_across = dt, n_across


def _default_groups(state, chosen):
    if chosen is not None:
        return list(chosen)
    return [g for g in state.groups if g != "all"]


def _estimate(cfg, backend, built, total_steps, n, dim, rate=None):
    """``(output bytes, run time [s], compile time [s])``; ``rate``: element-steps/s of the
    stepping (default: the backend's figure in EST_RATE, from docs/performance.md)."""
    st = built.state
    obs = cfg.outputs.observables
    samples = total_steps // obs.every + 2
    eg = len(_default_groups(st, obs.energy_groups))
    gg = len(_default_groups(st, obs.groups))
    series_bytes = (len(ENERGY_TERMS) + 4 + 1 + eg * len(GROUP_ENERGY_TERMS)) * 24 \
        + gg * 2 * (8 * dim + 16)
    fr = cfg.outputs.frames
    frames = (total_steps // fr.every if fr.every else 0) + 2
    per_el = sum(4 if f == "bonds" else 8 * dim for f in fr.fields)
    members = sum(st.n if g == "all" else int((st.group == st.groups[g]).sum())
                  for g in fr.groups)
    output = samples * series_bytes + frames * members * per_el + 64 * 1024
    rate = rate or EST_RATE.get(backend, 4.0e6)
    # measured on the 2-core machine of docs/performance.md: ~1.2 ms per observation (energies
    # by group, reactions, crack counts) plus the passes over the elements, ~5 ms per frame
    runtime = 0.2 + total_steps * (n / rate + 5e-6) + samples * (1.2e-3 + 5e-7 * n) \
        + frames * (5e-3 + members * 5e-8)
    return int(output), float(runtime), EST_COMPILE_S.get(backend, 0.0)


def validated(path, sets=(), backend: str | None = None):
    """Load and validate a workflow with its ``--set`` overrides and backend, without building
    anything: ``(doc, cfg, backend_name, resolved)`` (``resolved``: the resolved config whose
    :func:`config_hash` names the run). WorkflowError on bad input."""
    from geodem.workflow.schema import validate_document

    doc = load_document(path, sets)
    if backend is not None:
        doc.data["backend"] = backend
        doc._replace_lines(("backend",), {("backend",): (f"--backend {backend}", None)})
    cfg = validate_document(doc)
    name = _resolve_backend(cfg, doc)
    resolved = _tags_first(cfg.model_dump(mode="json", by_alias=True))
    resolved["backend"] = name
    return doc, cfg, name, resolved


def prepare(path, sets=(), backend: str | None = None, *, run_dir=None, overwrite=False,
            resume=False, progress=None) -> Prepared:
    """Validate, build and plan a workflow without stepping (WorkflowError on bad input).

    ``run_dir``: the run directory the workflow will run in, checked (with ``overwrite`` and
    ``resume``: :meth:`~geodem.workflow.rundir.RunDir.check`, and for ``resume`` the config
    hash of its newest checkpoint) before the model is built, so a bad ``-o`` fails at once.
    ``progress``: a callable taking one line of text, told when the build starts and ends and
    of the builders' stages (:mod:`geodem.build.progress`); None: silent."""
    from geodem.build import progress as build_progress

    doc, cfg, name, resolved = validated(path, sets, backend)
    chash = config_hash(resolved)
    if run_dir is not None:
        rdir = rd.RunDir(run_dir)
        rdir.check(overwrite, resume)
        if resume:
            _check_resume_hash(rdir, doc.file, chash)
    need, avail, n_est = _check_memory(cfg, doc)
    m = cfg.model
    if progress is not None:
        dim = getattr(m, "dim", None)
        progress(f"building model {m.type}: ~{n_est:,} elements"
                 + (f", {dim}-D" if dim in (2, 3) else "") + " ...")
    t0 = time.perf_counter()
    with build_progress.listening(progress):
        built = _build(cfg, doc)
    if progress is not None:
        progress(f"built model {m.type}: {built.state.n:,} elements in "
                 f"{time.perf_counter() - t0:.1f} s")
    overlap = _check_initial_overlap(cfg, doc, built.state)
    dt, source, stable = _time_step(cfg, doc, built.state)
    info = _PlanInfo(dt, built.n_across)
    steps = [int(s.planned_steps(info)) for s in cfg.steps]
    _check_step_counts(doc, steps, dt)
    total = int(sum(steps))
    st = built.state
    output, runtime, compile_s = _estimate(cfg, name, built, total, st.n, st.dim)
    plan = Plan(dt=dt, dt_source=source, stable_dt=stable, n_across=built.n_across, steps=steps,
                total_steps=total, n_elements=st.n, memory_bytes=need, memory_available=avail,
                output_bytes=output, checkpoint_bytes=int(st.nbytes()) + 4096,
                runtime_s=runtime, compile_s=compile_s, initial_overlap=overlap)
    return Prepared(Path(path), doc, cfg, name, built, plan, resolved, chash, tuple(sets))


def _changed_workflow(file, run_dir, new_hash, old_hash) -> WorkflowError:
    return WorkflowError(ErrorItem(
        file, None, "(config)",
        f"the workflow changed since the run in {run_dir} started (config hash "
        f"{new_hash[:12]} != {str(old_hash)[:12]}, compare with {Path(run_dir) / rd.CONFIG}); "
        f"--resume continues only the same workflow, backend and --set values: start a new run "
        f"(another -o, or --overwrite)"))


def _check_resume_hash(rdir, file, chash) -> None:
    """Refuse to resume a run of another workflow (before the build): the config hash of the
    newest checkpoint marker that reads (Runner.run checks the one it resumes from again)."""
    for marker in reversed(rdir.checkpoint_markers()):
        try:
            old = json.loads(marker.read_text()).get("config_hash")
        except (OSError, ValueError, AttributeError):
            continue
        if old is not None and old != chash:
            raise _changed_workflow(file, rdir.path, chash, old)
        return


def _quote(text: str) -> str:
    import shlex

    return shlex.quote(text)


def _tags_first(obj):
    """Dump order: a mapping's ``kind``/``type`` key first (readable config.resolved.yaml)."""
    if isinstance(obj, dict):
        keys = sorted(obj, key=lambda k: k not in ("kind", "type"))
        return {k: _tags_first(obj[k]) for k in keys}
    if isinstance(obj, list):
        return [_tags_first(v) for v in obj]
    return obj


def dry_run_report(prep: Prepared) -> list[str]:
    """What --dry-run prints: sizes, time step, steps, estimates."""
    cfg, plan, st = prep.cfg, prep.plan, prep.built.state
    m = cfg.model
    lines = [
        f"workflow {cfg.metadata.name!r} ({prep.doc.file}): valid",
        f"model: {m.type}, {st.dim}-D, {st.n:,} elements, groups: "
        f"{', '.join(g for g in st.groups)}",
        f"backend: {prep.backend}",
        f"time step: dt = {plan.dt:.4g} s ({plan.dt_source}); stability limit "
        f"{plan.stable_dt:.4g} s",
        "steps:",
    ]
    for i, (s, n) in enumerate(zip(cfg.steps, plan.steps)):
        lines.append(f"  {i + 1}. {s.name} ({s.kind}): "
                     + (f"{n:,} time steps" if n else "no time steps"))
    lines += [
        f"total: {plan.total_steps:,} time steps, {plan.total_steps * plan.dt:.4g} s simulated, "
        f"{plan.total_steps * st.n:.3g} element-steps",
        f"estimated memory: {human_bytes(plan.memory_bytes)}"
        + (f" (available: {human_bytes(plan.memory_available)})"
           if plan.memory_available else ""),
        f"estimated run time: about {plan.runtime_s:.3g} s"
        + (f" (plus about {plan.compile_s:.0f} s compiling the {prep.backend} kernels on "
           f"first use)" if plan.compile_s else ""),
        f"estimated output size: output.h5 about {human_bytes(plan.output_bytes)}, "
        f"checkpoints about {human_bytes(plan.checkpoint_bytes)} each "
        f"(keeping {cfg.checkpoints.keep})",
    ]
    return lines


# ============================================================================ observables
class Observer:
    """Records observables (energies, group reactions and displacements, cracks) and frames.

    Frames hold the members a group had in the model as built (``particles/<group>/id``, in that
    numbering); an element removed since (``Simulation.remove_elements``) is written as NaN
    (0 bonds). ``original``: the state as built, when the simulation's elements differ from it
    (a run resumed after an excavation)."""

    def __init__(self, sim, built, cfg, h5, original=None):
        self.sim, self.built, self.cfg, self.h5 = sim, built, cfg, h5
        st = sim.state
        self.dim = st.dim
        obs = cfg.outputs.observables
        self.energy_groups = _default_groups(st, obs.energy_groups)
        self.groups = _default_groups(st, obs.groups)
        from geodem.core import groups

        base = st if original is None else original
        self.idx = {g: groups.members(base, g)
                    for g in set(self.groups) | set(cfg.outputs.frames.groups)}
        self._now, self._now_for = {}, None
        self.last = {}
        self.last_obs_step = None
        self.last_frame_step = None
        for t in ENERGY_TERMS:
            h5.series(f"observables/energy/{t}", unit="1" if t == "closure_error" else "J")
        for g in self.energy_groups:
            for t in GROUP_ENERGY_TERMS:
                h5.series(f"observables/groups/{g}/energy/{t}", unit="J")
        for g in self.groups:
            h5.series(f"observables/groups/{g}/reaction", (self.dim,), unit="N")
            h5.series(f"observables/groups/{g}/displacement", (self.dim,), unit="m")
        for c in (*CRACK_TYPES, "total"):
            h5.series(f"observables/cracks/{c}", dtype="i8", unit="1")
        h5.series("observables/bonds/intact", dtype="i8", unit="1")
        fr = cfg.outputs.frames
        for g in fr.groups:
            n = self.idx[g].size
            h5.box(g, self.dim)
            for f in fr.fields:
                shape = (n,) if f == "bonds" else (n, self.dim)
                unit = {"position": "m", "velocity": "m/s", "force": "N", "displacement": "m",
                        "bonds": "1"}[f]
                h5.series(f"particles/{g}/{f}", shape, dtype="i4" if f == "bonds" else "f8",
                          unit=unit, chunk_rows=1)

    def current(self, g):
        """``(indices now, which of idx[g] remain)`` of group ``g``'s members as built
        (``None`` for the second while no element was removed)."""
        ids = self.sim.ids
        if ids is None:
            return self.idx[g], None
        if self._now_for is not ids:
            self._now, self._now_for = {}, ids
        if g not in self._now:
            orig = self.idx[g]
            k = np.minimum(np.searchsorted(ids, orig), max(ids.size - 1, 0))
            ok = ids[k] == orig
            self._now[g] = (k[ok], ok)
        return self._now[g]

    def write_static(self):
        st = self.sim.sync()
        for g in self.cfg.outputs.frames.groups:
            idx = self.idx[g]
            self.h5.static(f"particles/{g}/id", idx.astype(np.int64))
            self.h5.static(f"particles/{g}/radius", st.r[idx], unit="m")
            self.h5.static(f"particles/{g}/mass", st.m[idx], unit="kg")
            self.h5.static(f"particles/{g}/reference_position", self.built.reference[idx],
                           unit="m")

    def record(self):
        from geodem.core import groups

        sim, h5 = self.sim, self.h5
        e = sim.energies(by_group=bool(self.energy_groups))  # syncs the state
        st = sim.state
        step, t = st.step, st.time
        for k in ENERGY_TERMS:
            h5.append(f"observables/energy/{k}", step, t, e[k])
        for g in self.energy_groups:
            eg = e["groups"][g]
            for k in GROUP_ENERGY_TERMS:
                h5.append(f"observables/groups/{g}/energy/{k}", step, t, eg[k])
        ref = self.built.reference
        for g in self.groups:
            idx = self.current(g)[0]
            h5.append(f"observables/groups/{g}/reaction", step, t, groups.reaction(st, g))
            disp = (st.x[idx] - ref[idx]).mean(axis=0) if idx.size else np.zeros(self.dim)
            h5.append(f"observables/groups/{g}/displacement", step, t, disp)
        log = sim.crack_log()
        total = 0
        for name, code in CRACK_TYPES.items():
            c = int((log["type"] == code).sum())
            total += c
            h5.append(f"observables/cracks/{name}", step, t, c)
        h5.append("observables/cracks/total", step, t, total)
        bonds = sim.bonded_count()
        h5.append("observables/bonds/intact", step, t, bonds)
        self.last = {"kinetic": e["kinetic"], "closure_error": e["closure_error"],
                     "broken": total, "bonds": bonds}
        self.last_obs_step = step

    def frame(self):
        st = self.sim.sync()
        ref = self.built.reference
        step, t = st.step, st.time
        for g in self.cfg.outputs.frames.groups:
            idx, ok = self.current(g)
            for f in self.cfg.outputs.frames.fields:
                if f == "position":
                    val = st.x[idx]
                elif f == "velocity":
                    val = st.v[idx]
                elif f == "force":
                    val = st.m[idx, None] * st.a[idx]
                elif f == "displacement":
                    val = st.x[idx] - ref[idx]
                else:
                    val = (st.cstate[idx] == 1).sum(axis=1).astype(np.int32)
                if ok is not None:  # removed members: NaN (0 bonds)
                    full = np.zeros((ok.size,) + val.shape[1:], val.dtype) if f == "bonds" \
                        else np.full((ok.size,) + val.shape[1:], np.nan)
                    full[ok] = val
                    val = full
                self.h5.append(f"particles/{g}/{f}", step, t, val)
        self.last_frame_step = step
        self.h5.flush()


# ============================================================================ step context
class StepContext:
    """What a step kind works with (see :class:`geodem.workflow.schema.StepBase`)."""

    def __init__(self, runner, index: int, start_step: int, resumed: bool):
        self.runner = runner
        self.index = index
        self.start_step = int(start_step)
        self.resumed = resumed
        self.step = runner.cfg.steps[index]
        self.cfg = runner.cfg
        self.model = runner.built
        self.sim = runner.sim
        self.plan = _PlanInfo(runner.sim.state.dt, runner.built.n_across)
        self.summary = runner.summary_extra
        self.out_dir = runner.dir.path

    @property
    def state(self):
        """The model state, synchronised from the backend."""
        return self.sim.sync()

    def log(self, msg: str) -> None:
        self.runner.reporter.message(f"[{self.step.name}] {msg}")

    def advance(self, nsteps: int) -> None:
        """Run until this step has made ``nsteps`` time steps since it started (chunked)."""
        self.runner.advance_to(self.start_step + int(nsteps), self)

    def set_eta(self, eta) -> None:
        """Set the global damping ``eta`` [kg/s] (scalar or per element)."""

        def put(st):
            st.eta[:] = np.broadcast_to(np.asarray(eta, dtype=np.float64), st.eta.shape)

        self.decree(put, book_energy=False)

    def decree(self, fn, group: str | None = None, book_energy: bool = True) -> float:
        """Change the model between time steps (see ``Simulation.change``): ``a`` is made
        consistent with the new conditions and the energy the change adds is booked as work."""
        return self.sim.change(fn, book_energy=book_energy, group=group)

    def add_sampler(self, sampler) -> None:
        """Record with ``sampler`` while the later steps run: ``sampler.sample()`` after every
        chunk of time steps that ends on a multiple of ``sampler.every`` (the chunks end there),
        and once more at the end of the workflow unless ``sampler.last_step`` is the last step;
        then ``sampler.finish()``. A step that adds one sets it up again on ``--resume`` in its
        ``restore(ctx)`` (called for the steps done before the checkpoint)."""
        self.runner.samplers.append(sampler)

    def remove_elements(self, mask) -> dict:
        """Remove the elements selected by ``mask`` (bool (N,) or indices of the current
        state) between time steps: ``Simulation.remove_elements`` (the energy they carry out is
        booked as ``removed``), and the run's reference positions and frames follow. Returns
        its dict (``n_removed``, ``n_left``, ``kinetic``, ``gravity``, ``elastic``,
        ``removed`` [J])."""
        return self.runner.remove_elements(mask)

    def series(self, path: str):
        """``(step, time, value)`` of a recorded series (e.g. observables/energy/kinetic)."""
        return self.runner.h5.read(path)

    def plot(self, filename: str, draw) -> str:
        """Draw a picture with ``draw(path)`` (which returns None when matplotlib is missing);
        returns the file name or the reason it was skipped (also put in summary.json)."""
        path = self.out_dir / filename
        try:
            import matplotlib  # noqa: F401
        except Exception:  # noqa: BLE001
            note = "skipped: matplotlib is not installed (pip install 'geodem[vis]')"
            self.runner.plots[filename] = note
            self.log(f"{filename} {note}")
            return note
        out = draw(path)
        if out is None:
            note = "skipped: matplotlib is not usable"
            self.runner.plots[filename] = note
            return note
        self.runner.plots[filename] = filename
        self.runner.files.append(filename)
        return filename


# ============================================================================ runner
class Runner:
    """Executes a prepared workflow in a run directory (see the module doc)."""

    def __init__(self, prep: Prepared, out_dir, *, resume=False, overwrite=False,
                 stop_after_steps=None, progress=None, console=None, echo=True, argv=None,
                 verbose=False):
        from rich.console import Console

        self.prep, self.cfg, self.built = prep, prep.cfg, prep.built
        self.dir = rd.RunDir(out_dir)
        self.resume, self.overwrite = resume, overwrite
        self.stop_after = stop_after_steps
        self.console = console or Console(stderr=True)
        self.progress = self.console.is_terminal if progress is None else progress
        self.echo = echo
        self.verbose = verbose
        self.argv = list(sys.argv if argv is None else argv)
        self.summary_extra: dict = {}
        self.results: dict = {}
        self.plots: dict = {}
        self.files: list = []
        self.notes: list = []
        self._stop_signal = None
        self._finishing = False
        self._entries_before = set()
        self.sim = None
        self.h5 = None
        self.reporter = None
        self.vtk = None
        #: per-sample recorders that steps register (StepContext.add_sampler): each has
        #: ``every`` (time steps between samples), ``last_step``, ``sample()`` and ``finish()``
        self.samplers: list = []

    # ------------------------------------------------------------------ signals
    def _on_signal(self, signum, frame):
        if self._finishing:
            self._stop_signal = signum
            return
        if self._stop_signal is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt  # second Ctrl-C: stop at once
        self._stop_signal = signum

    def _install_signals(self):
        self._old = {}
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, self._on_signal)
            except (ValueError, OSError):  # pragma: no cover
                pass

    def _restore_signals(self):
        for sig, old in self._old.items():
            try:
                signal.signal(sig, old)
            except (ValueError, OSError):  # pragma: no cover
                pass

    # ------------------------------------------------------------------ stepping
    def _next_event(self, s: int, target: int) -> int:
        nxt = target
        cfg = self.cfg
        for every in (cfg.outputs.observables.every, cfg.outputs.frames.every,
                      cfg.outputs.vtk.every if self.vtk is not None else None,
                      cfg.checkpoints.every_steps, *(smp.every for smp in self.samplers)):
            if every:
                nxt = min(nxt, (s // every + 1) * every)
        if self.stop_after is not None and self.stop_after > s:
            nxt = min(nxt, int(self.stop_after))
        chunk = max(1, int(self._rate * CHUNK_SECONDS)) if self._rate > 0 else 10
        return min(nxt, s + chunk)

    def advance_to(self, target: int, ctx: StepContext) -> None:
        st = self.sim.state
        self._ctx = ctx
        cfg = self.cfg
        while st.step < target:
            self._check_stop(ctx)
            if self.stop_after is not None and st.step >= self.stop_after:
                self.checkpoint(ctx)
                raise Interrupted(f"--stop-after-steps {self.stop_after}")
            s = st.step
            n = self._next_event(s, target) - s
            t0 = time.perf_counter()
            self.sim.run(n)
            dt_wall = time.perf_counter() - t0
            self.stepping_wall += dt_wall
            self.stepped += n
            if dt_wall > 0:  # smoothed stepping rate (time steps per second of Simulation.run)
                r = n / dt_wall
                self._rate = r if self._rate <= 0 else 0.7 * self._rate + 0.3 * r
            s = st.step
            if s % cfg.outputs.observables.every == 0:
                self.observer.record()
            for smp in self.samplers:
                if s % smp.every == 0:
                    smp.sample()
            if cfg.outputs.frames.every and s % cfg.outputs.frames.every == 0:
                self.observer.frame()
            if self.vtk is not None and cfg.outputs.vtk.every and s % cfg.outputs.vtk.every == 0:
                self._vtk_frame()
            now = time.perf_counter()
            if now - self._last_flush > self._flush_interval:
                self._flush_output(now)
            ck = cfg.checkpoints
            # a stop landing exactly on this advance's target is left to the next advance (its
            # first check): the step records its sample at the target before the checkpoint
            stop = self.stop_after is not None and s >= self.stop_after and s < target
            if stop or (ck.every_steps and s % ck.every_steps == 0) or \
                    (ck.every_seconds and now - self._last_ckpt > ck.every_seconds):
                self.checkpoint(ctx)
            self.reporter.update(s, ke=self.observer.last.get("kinetic"),
                                 broken=len(self.sim.cracks["i"]), rate=self._rate)
            if stop:
                raise Interrupted(f"--stop-after-steps {self.stop_after}")
        # a signal that arrived in the last chunk is left to the next advance's first check,
        # as a stop at the target is: the step records its sample at the target first (a
        # checkpoint here, before it, lost that sample on resume)

    def remove_elements(self, mask) -> dict:
        """See :meth:`StepContext.remove_elements`."""
        m = np.asarray(mask)
        if m.dtype != bool:  # indices
            sel = np.zeros(self.sim.state.n, bool)
            sel[m.astype(np.int64)] = True
            m = sel
        keep = ~m
        out = self.sim.remove_elements(m)
        if out["n_removed"]:
            self.built.state = self.sim.state
            self.built.reference = np.ascontiguousarray(self.built.reference[keep])
        return out

    def _check_stop(self, ctx):
        if self._stop_signal is not None:
            signum = self._stop_signal
            self.checkpoint(ctx)
            raise Interrupted(signal.Signals(signum).name, signum)

    def _marker(self, ctx, complete=False) -> dict:
        st = self.sim.state
        return {
            "format": 1, "step": int(st.step), "time": float(st.time),
            "config_hash": self.prep.config_hash, "step_index": ctx.index if ctx else None,
            "step_start": ctx.start_step if ctx else None, "complete": complete,
            "results": self.results, "summary_extra": self.summary_extra, "plots": self.plots,
            "files": self._written_files(), "wall_time_s": self.wall_before + self._wall(),
            "stepping_wall_s": self.stepping_wall, "stepped": self.stepped,
            "written": _now(),
        }

    def _written_files(self) -> list:
        """The files the steps listed, and every other entry this run created in its folder
        (a step's CSV, a moved output.damaged.h5): ``--overwrite`` deletes what is listed."""
        try:
            now = set(os.listdir(self.dir.path))
        except OSError:
            now = set()
        fixed = {rd.CONFIG, rd.MANIFEST, rd.LOG, rd.OUTPUT, rd.SUMMARY, rd.CHECKPOINTS, rd.VTK}
        new = sorted(n for n in now - self._entries_before - fixed
                     if not n.startswith("."))  # atomic writes' temporary files
        return list(self.files) + [n for n in new if n not in self.files]

    def _flush_output(self, now: float) -> None:
        """Write the buffered samples to output.h5; the next write waits the longer of
        :data:`FLUSH_SECONDS` and this one's time over :data:`FLUSH_SHARE` (at most
        :data:`FLUSH_MAX_SECONDS`), so writing costs a bounded share of the run."""
        self.h5.flush()
        self._last_flush = time.perf_counter()
        self._flush_interval = min(FLUSH_MAX_SECONDS, max(
            FLUSH_SECONDS, (self._last_flush - now) / FLUSH_SHARE))

    def checkpoint(self, ctx, complete=False) -> None:
        # a broken state stops the run here, before it can replace a good checkpoint
        self.sim.check_finite()
        self.h5.flush()
        path = self.dir.write_checkpoint(self.sim, self._marker(ctx, complete),
                                         self.cfg.checkpoints.keep)
        self._last_ckpt = time.perf_counter()
        self.last_checkpoint = str(path.relative_to(self.dir.path))
        self.reporter.message(f"checkpoint at step {self.sim.state.step}: {self.last_checkpoint}",
                              echo=False)

    def _vtk_frame(self):
        from geodem.io.vtk import crack_lines

        st = self.sim.sync()
        self.vtk.write(st, st.step, self.built.reference,
                       cracks=crack_lines(self.sim.ids, self.sim.crack_log()))

    def _wall(self) -> float:
        return time.perf_counter() - self._t_start

    # ------------------------------------------------------------------ the run
    def run(self) -> tuple[int, dict]:
        """Execute the workflow; returns ``(exit status, summary)``. Raises WorkflowError for
        a run directory that may not be used (exit status 2)."""
        prep = self.prep
        self._t_start = time.perf_counter()
        self.wall_before = 0.0
        self.stepping_wall = 0.0
        self.stepped = 0
        self._rate = 0.0
        self._flush_interval = FLUSH_SECONDS
        self.last_checkpoint = None
        created = not self.dir.path.exists()
        self.dir.prepare(self.overwrite, self.resume)
        try:
            self._check_disk_space()
        except WorkflowError:
            if created and not any(self.dir.path.iterdir()):
                self.dir.path.rmdir()  # leave nothing behind
            raise
        self._entries_before = set(os.listdir(self.dir.path))
        if self.dir.kept:
            self.console.print(
                f"--overwrite kept {len(self.dir.kept)} entr{'y' if len(self.dir.kept) == 1 else 'ies'}"
                f" of {self.dir.path} that the run did not write: "
                f"{', '.join(sorted(self.dir.kept))}", highlight=False, markup=False)
        marker, npz = None, None
        if self.resume:
            marker, npz = self.dir.resume_from
            for name, why in self.dir.damaged:
                self.console.print(f"checkpoint {name} is damaged ({why}); passed over for the "
                                   f"one before it", highlight=False, markup=False)
            if self.dir.damaged:
                self.notes.append(f"resumed from {npz.name}: newer checkpoint(s) damaged: "
                                  + "; ".join(f"{n} ({w})" for n, w in self.dir.damaged))
            if marker.get("config_hash") != prep.config_hash:
                raise _changed_workflow(prep.doc.file, self.dir.path, prep.config_hash,
                                        marker.get("config_hash"))
            _check_unlocked(self.dir / rd.OUTPUT)
            if marker.get("complete"):
                summary = self._read_summary()
                if summary.get("status") == "ok":
                    self.console.print(f"the run in {self.dir.path} is already complete; "
                                       "nothing to resume", highlight=False, markup=False)
                    return EXIT_OK, summary
        self._write_config_manifest(marker)
        self.reporter = _make_reporter(self, marker)
        try:
            code = self._execute(marker, npz)
        finally:
            self.reporter.close()
        return code, self.summary

    def _execute(self, marker, npz) -> int:
        from geodem.core.engine import InstabilityError, Simulation

        prep, cfg = self.prep, self.cfg
        rep = self.reporter
        status, error, code, interrupted_by = "running", None, EXIT_OK, None
        original = None
        self._install_signals()
        try:
            sim_cfg = cfg.simulation
            if marker is None:
                rep.message(f"geodem {__version__}: workflow {cfg.metadata.name!r} "
                            f"({prep.doc.file}), {self.built.state.n:,} elements, backend "
                            f"{prep.backend}, dt = {prep.plan.dt:.4g} s, "
                            f"{prep.plan.total_steps:,} time steps -> {self.dir.path}")
                for note in (getattr(self.built, "info", None) or {}).get(
                        "material_warnings") or []:
                    rep.message(f"warning: {note}")
                    self.summary_extra.setdefault("warnings", []).append(note)
                slow = _slow_layer_note(prep.backend)
                if slow:
                    rep.message(slow)
                    self.summary_extra.setdefault("warnings", []).append(slow)
                self.sim = Simulation(self.built.state, backend=prep.backend, dt=prep.plan.dt,
                                      check_every=sim_cfg.check_every,
                                      overlap_limit=sim_cfg.overlap_limit,
                                      monitor_every=sim_cfg.monitor_every)
                start_index, start_step = 0, 0
            else:
                rep.message(f"resuming from checkpoint {npz.name} (step {marker['step']}) with "
                            f"backend {prep.backend}")
                self.sim = Simulation.load(npz, backend=prep.backend)
                self.sim.overlap_limit = sim_cfg.overlap_limit
                original = self.built.state
                self.built.state = self.sim.state  # the rebuilt one only gave the reference
                if self.sim.ids is not None:  # elements were removed before the checkpoint
                    self.built.reference = np.ascontiguousarray(
                        self.built.reference[self.sim.ids])
                self.results = dict(marker.get("results") or {})
                self.summary_extra.update(marker.get("summary_extra") or {})
                if self.notes:  # what the resume itself found (damaged newer checkpoints)
                    self.summary_extra["warnings"] = \
                        list(self.summary_extra.get("warnings") or []) + self.notes
                self.plots.update(marker.get("plots") or {})
                self.files = list(marker.get("files") or [])
                self.wall_before = float(marker.get("wall_time_s", 0.0))
                self.stepping_wall = float(marker.get("stepping_wall_s", 0.0))
                self.stepped = int(marker.get("stepped", 0))
                start_index = int(marker["step_index"]) if marker["step_index"] is not None \
                    else len(cfg.steps)
                start_step = int(marker["step_start"] or 0)
            self._open_outputs(marker)
            self.observer = Observer(self.sim, self.built, cfg, self.h5,
                                     original if marker is not None else None)
            if marker is not None:
                # samples the kept output already holds at the checkpoint's step (a resumed
                # final checkpoint used to record its last sample and frame twice)
                self.observer.last_obs_step = self.h5.last_step_of("observables/energy/total")
                self.observer.last_frame_step = self.h5.last_step_of(
                    f"particles/{cfg.outputs.frames.groups[0]}/{cfg.outputs.frames.fields[0]}"
                    if cfg.outputs.frames.groups and cfg.outputs.frames.fields else "")
            if marker is None:
                self.observer.write_static()
                self.observer.record()
                self.observer.frame()
                if self.vtk is not None:
                    self._vtk_frame()
                self.h5.flush()
            self._last_flush = self._last_ckpt = time.perf_counter()
            rep.start(self.sim.state.step)
            for i in range(min(start_index, len(cfg.steps))):
                # steps done before the checkpoint whose effect outlives them and is not in the
                # state (a monitor's recorder) set it up again
                restore = getattr(cfg.steps[i], "restore", None)
                if restore is not None:
                    restore(StepContext(self, i, self.sim.state.step, True))
            for i in range(start_index, len(cfg.steps)):
                step = cfg.steps[i]
                resumed = marker is not None and i == start_index
                ctx = StepContext(self, i, start_step if resumed else self.sim.state.step,
                                  resumed)
                self._ctx = ctx
                rep.start_step(i, len(cfg.steps), step.name, step.kind, prep.plan.steps[i])
                res = step.execute(ctx)
                if res:
                    self.results[step.name] = res
            self._ctx = None
            st = self.sim.state
            if self.observer.last_obs_step != st.step:
                self.observer.record()
            if self.observer.last_frame_step != st.step:
                self.observer.frame()
            for smp in self.samplers:
                if smp.last_step != st.step:
                    smp.sample()
                smp.finish()
            if self.vtk is not None and cfg.outputs.vtk.every and st.step % cfg.outputs.vtk.every:
                self._vtk_frame()
            rep.update(st.step, ke=self.observer.last.get("kinetic"),
                       broken=len(self.sim.cracks["i"]), rate=self._rate, force=True)
            status = "ok"
            if cfg.checkpoints.final:
                self.checkpoint(None, complete=True)
        except Interrupted as exc:
            status, interrupted_by, code = "interrupted", exc.reason, exc.exit_code
            again = " ".join([f"geodem run {_quote(str(prep.doc.file))}"] + [
                f"--set {_quote(x)}" for x in prep.sets] + [
                f"--backend {prep.backend} -o {_quote(str(self.dir.path))} --resume"])
            rep.message(f"interrupted ({exc.reason}) at step {self.sim.state.step}; checkpoint "
                        f"{self.last_checkpoint}; continue with: {again}")
        except KeyboardInterrupt:
            status, interrupted_by, code = "interrupted", "SIGINT (twice)", 130
            error = "stopped at once by a second Ctrl-C (no checkpoint of this point)"
            rep.message(error)
        except InstabilityError as exc:
            status, error, code = "failed", str(exc), EXIT_FAILURE
            rep.message(f"run failed: {exc}")
            self._traceback()
        except (OSError, RunFailure) as exc:
            status, error, code = "failed", f"{type(exc).__name__}: {exc}", EXIT_FAILURE
            rep.message(f"run failed: {error}")
            self._traceback()
        except WorkflowError as exc:
            status, error = "failed", str(exc)
            raise
        except Exception as exc:  # noqa: BLE001 - reported in summary.json, exit 1
            status, error, code = "failed", f"{type(exc).__name__}: {exc}", EXIT_FAILURE
            rep.message(f"run failed: {error}" + ("" if self.verbose else
                                                  " (run with -v for the traceback)"))
            if self.verbose:
                import traceback

                traceback.print_exc(file=sys.stderr)
        finally:
            # a signal while the summary is written is noted, not raised: the summary and the
            # output's closing status are written in any case (a KeyboardInterrupt here used
            # to leave no summary.json)
            self._finishing = True
            try:
                self.summary = self._finish(status, error, interrupted_by)
            finally:
                self._restore_signals()
        return code

    def _traceback(self):
        if self.verbose:
            import traceback

            traceback.print_exc(file=sys.stderr)

    # ------------------------------------------------------------------ files
    def _check_disk_space(self) -> None:
        """WorkflowError (exit 2) when the folder's file system lacks the room the plan
        estimates: output.h5, and ``keep + 1`` checkpoints (one is written before the oldest
        goes). A full disk mid-run crashes the HDF5 library itself (a bus error), so this is
        checked before the first step."""
        import shutil

        plan, keep = self.prep.plan, self.cfg.checkpoints.keep
        out = self.dir / rd.OUTPUT
        have = out.stat().st_size if self.resume and out.exists() else 0
        # with room to spare: the output estimate leaves out HDF5's chunk and metadata
        # overhead (two_balls: 0.76 MB estimated, 2 MB written)
        need = 2 * max(plan.output_bytes - have, 0) + (keep + 1) * plan.checkpoint_bytes \
            + DISK_HEADROOM
        free = shutil.disk_usage(self.dir.path).free
        if free < need:
            raise WorkflowError(ErrorItem(
                str(self.dir.path), None, "-o",
                f"the run needs about {human_bytes(need)} (twice the estimated output.h5 of "
                f"{human_bytes(plan.output_bytes)}, {keep + 1} checkpoints of about "
                f"{human_bytes(plan.checkpoint_bytes)}, {human_bytes(DISK_HEADROOM)} to "
                f"spare), and only {human_bytes(free)} is free "
                f"there; free some space, choose another -o, or write less (outputs.*.every, "
                f"checkpoints.keep)"))

    def _write_config_manifest(self, marker):
        prep, cfg = self.prep, self.cfg
        threads = _threads(prep.backend)
        layer = _threading_layer(prep.backend)
        session = {"started": _now(), "backend": prep.backend, "threads": threads,
                   "threading_layer": layer, "omp_wait": _omp_wait(layer), "command": self.argv,
                   "resumed_from_step": None if marker is None else marker["step"]}
        if marker is None:
            header = ("# geodem: resolved workflow (every default filled in); rerun with\n"
                      f"#   geodem run {self.dir / rd.CONFIG} -o OTHER_DIR\n")
            rd.atomic_write(self.dir / rd.CONFIG,
                            header + yaml.safe_dump(prep.resolved, sort_keys=False))
            manifest = {
                "geodem_version": __version__,
                "created": _now(),
                "workflow": cfg.metadata.name,
                "workflow_file": str(prep.path.resolve()),
                "config_hash": prep.config_hash,
                "seed": cfg.metadata.seed,
                "backend": prep.backend,
                "threads": threads,
                "threading_layer": session["threading_layer"],
                "omp_wait": session["omp_wait"],
                "n_elements": int(self.built.state.n),
                "dim": int(self.built.state.dim),
                "dt": prep.plan.dt,
                "versions": _versions(prep.backend),
                "platform": platform.platform(),
                "cpu_count": os.cpu_count(),
                "hostname": platform.node(),
                "sessions": [session],
            }
        else:
            try:
                manifest = json.loads((self.dir / rd.MANIFEST).read_text())
            except (OSError, ValueError):
                manifest = {"config_hash": prep.config_hash, "sessions": []}
            manifest.setdefault("sessions", []).append(session)
        rd.write_json(self.dir / rd.MANIFEST, manifest)

    def _open_outputs(self, marker):
        from geodem.io.h5 import H5Writer

        path = self.dir / rd.OUTPUT
        attrs = {"config": yaml.safe_dump(self.prep.resolved, sort_keys=False),
                 "config_hash": self.prep.config_hash, "workflow": self.cfg.metadata.name,
                 "geodem_version": __version__, "backend": self.prep.backend,
                 "dim": int(self.built.state.dim), "dt": float(self.prep.plan.dt),
                 "status": "running"}
        if marker is not None and path.exists():
            try:
                self.h5 = H5Writer(path, "a", attrs=attrs, creator=("geodem", __version__))
                self.h5.truncate(int(marker["step"]))
            except OSError as exc:
                if _is_lock_error(exc):
                    raise RunFailure(
                        f"{path} is open in another program (HDF5 file lock: {exc}); close it "
                        f"and resume again (nothing was changed)") from None
                bad = _free_name(path.with_name("output.damaged.h5"))
                os.replace(path, bad)
                note = (f"output.h5 could not be reopened ({exc}); moved it to {bad.name} and "
                        f"started a new one at step {marker['step']}: the series before that "
                        f"step are in {bad.name} only, and results measured from the series "
                        f"see only the steps since")
                self.reporter.message(note)
                self.summary_extra.setdefault("warnings", []).append(note)
                self.h5 = H5Writer(path, "w", attrs=attrs, creator=("geodem", __version__))
        else:
            if marker is not None:
                note = (f"output.h5 was missing when the run resumed at step {marker['step']}: "
                        f"a new one holds the series from that step on only, and results "
                        f"measured from the series see only those steps")
                self.reporter.message(note)
                self.summary_extra.setdefault("warnings", []).append(note)
            self.h5 = H5Writer(path, "w", attrs=attrs, creator=("geodem", __version__))
        vtk = self.cfg.outputs.vtk
        if vtk.every:
            from geodem.io.vtk import VtkWriter

            self.vtk = VtkWriter(self.dir / rd.VTK)
            self.vtk_note = "vtk/frames.pvd"

    def _read_summary(self) -> dict:
        try:
            return json.loads((self.dir / rd.SUMMARY).read_text())
        except (OSError, ValueError):
            return {}

    def _finish(self, status, error, interrupted_by) -> dict:
        sim, st = self.sim, self.built.state
        if sim is not None:
            st = sim.state
            try:
                sim.sync()
            except Exception:  # noqa: BLE001
                pass
        closure = math.nan
        bonds_broken = None
        if sim is not None and status != "failed":
            try:
                closure = float(sim.energies()["closure_error"])
                if self.h5 is not None:
                    _, _, c = self.h5.read("observables/energy/closure_error")
                    if c.size:
                        closure = max(closure, float(np.nanmax(c)))
                bonds_broken = int(len(sim.cracks["i"]))
            except Exception:  # noqa: BLE001
                pass
        wall = self.wall_before + self._wall()
        total_steps = int(st.step)
        summary = {
            "status": status,
            "steps": total_steps,
            "sim_time": float(st.time),
            "wall_time_s": wall,
            "element_steps_per_s": (st.n * self.stepped / self.stepping_wall
                                    if self.stepping_wall > 0 else 0.0),
            "n_elements": int(st.n),
            "energy_closure_rel_error": closure,
            "state_sha256": state_sha256(st),
            "workflow": self.cfg.metadata.name,
            "backend": self.prep.backend,
            "dim": int(st.dim),
            "dt": float(st.dt) if st.dt else self.prep.plan.dt,
            "planned_steps": self.prep.plan.total_steps,
            "stepping_wall_s": self.stepping_wall,
            "bonds_broken": bonds_broken,
            "config_hash": self.prep.config_hash,
        }
        summary.update(self.summary_extra)
        summary["results"] = self.results
        if self.plots:
            summary["plots"] = self.plots
        if self.cfg.outputs.vtk.every:
            summary["vtk"] = getattr(self, "vtk_note", "")
        if interrupted_by:
            summary["interrupted_by"] = interrupted_by
        if self.last_checkpoint:
            summary["checkpoint"] = self.last_checkpoint
        if error:
            summary["error"] = error
        files = ["config.resolved.yaml", "manifest.json", "log.txt", "summary.json"]
        if (self.dir / rd.OUTPUT).exists():
            files.append("output.h5")
        if self.vtk is not None:
            files.append("vtk/frames.pvd")
        summary["files"] = files + [f for f in self._written_files() if f not in files]
        if self.h5 is not None:
            try:
                if sim is not None:
                    log = sim.crack_log()
                    for k in ("i", "j", "time", "type"):
                        self.h5.static(f"cracks/{k}", log[k], unit="s" if k == "time" else None)
                self.h5.set_attrs(status=status)
                self.h5.close()
            except Exception as exc:  # noqa: BLE001
                self.reporter.message(f"could not finish output.h5: {exc}")
        rd.write_json(self.dir / rd.SUMMARY, summary)
        self.reporter.message(
            f"{status}: {total_steps:,} time steps, {st.time:.4g} s simulated, wall "
            f"{wall:.3g} s, {summary['element_steps_per_s']:.3g} element-steps/s, energy "
            f"closure error {closure:.2e}; summary in {self.dir / rd.SUMMARY}", echo=False)
        return summary


def _make_reporter(runner, marker):
    from geodem.workflow.progress import Reporter

    return Reporter(runner.dir / rd.LOG, total_steps=runner.prep.plan.total_steps,
                    n_elements=runner.built.state.n, bar=bool(runner.progress),
                    console=runner.console, echo=runner.echo,
                    log_every_s=runner.cfg.outputs.log_every_seconds)


def _now() -> str:
    from geodem.workflow.progress import now_iso

    return now_iso()


def _threads(backend: str) -> int:
    if backend == "numba":
        from geodem.threads import numba_threads

        return numba_threads()
    if backend == "numpy":
        return 1
    return 0


def _threading_layer(backend: str) -> str | None:
    """numba's threading layer for the numba backend (geodem.threads), else None."""
    if backend != "numba":
        return None
    from geodem import threads

    return threads.layer()


def _omp_wait(layer: str | None) -> dict | None:
    """How idle OpenMP threads wait (geodem.threads.choose_wait) on the omp layer, else None."""
    if layer != "omp":
        return None
    from geodem import threads

    return threads.describe_wait()


def _slow_layer_note(backend: str) -> str | None:
    from geodem import threads

    layer = _threading_layer(backend)
    return None if layer is None else threads.slow_layer_note(layer)


def _versions(backend: str) -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {"geodem": __version__, "python": platform.python_version()}
    pkgs = ["numpy", "numba", "scipy", "h5py", "pydantic", "pyyaml", "typer", "rich"]
    if backend == "cupy":
        pkgs.append("cupy")
    for p in pkgs:
        try:
            out[p] = version(p)
        except PackageNotFoundError:
            out[p] = None
    return out


# ============================================================================ entry point
def run_workflow(path, out_dir, *, sets=(), backend=None, resume=False, overwrite=False,
                 stop_after_steps=None, progress=None, console=None, echo=True):
    """Validate, build and run the workflow in ``path`` into ``out_dir``.

    Returns ``(exit status, summary dict)``; raises WorkflowError for invalid input (exit 2).
    """
    prep = prepare(path, sets=sets, backend=backend, run_dir=out_dir, overwrite=overwrite,
                   resume=resume)
    runner = Runner(prep, out_dir, resume=resume, overwrite=overwrite,
                    stop_after_steps=stop_after_steps, progress=progress, console=console,
                    echo=echo)
    return runner.run()
