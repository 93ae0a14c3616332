"""Throughput benchmark: full time steps of a bonded 3-D specimen on each backend.

``run_bench`` builds, for every size, the same specimen
(:func:`geodem.build.lattice.random_specimen` bonded by :func:`geodem.build.lattice.bonded_state`,
Morton-sorted by :func:`geodem.core.neighbors.spatial_sort`) and times
:meth:`geodem.core.engine.Simulation.run` on each backend: the real step loop, checks and neighbour
rebuilds included. Benchmarks are commands, not tests: the numbers belong to the machine they were
taken on (``geodem info`` describes it).

The specimen is generated with overlapping elements, so it relaxes (expands) while it is stepped and
the neighbour rows are rebuilt now and then; the count is reported as ``rebuilds``. Its bonds are
made unbreakable (``xb`` = one diameter, ``fs0`` = 1000 kn d) so every contact stays bonded.
Besides the engine loop, the bare step kernels (``move`` + ``force``, no checks) are timed for about
a second: ``kernel_element_steps_per_s`` separates the kernels from the bookkeeping around them.
"""
from __future__ import annotations

import gc
import math
import os
import time
import inspect

import numpy as np

from geodem.machine import available_memory

DEFAULT_SIZES = (10_000, 100_000, 1_000_000)
#: the whole-array NumPy reference is slow by design: it is only run up to this size
NUMPY_MAX = 100_000
#: smallest model a bench accepts
MIN_SIZE = 100
#: estimated state size per element [bytes] (852 B in 3-D at row width 16; wider rows cost more)
STATE_BYTES_PER_ELEMENT = 1200
#: estimated peak memory per element [bytes]: state + builder and step temporaries (~1 KB)
BYTES_PER_ELEMENT_ESTIMATE = STATE_BYTES_PER_ELEMENT + 1000
#: wall time aimed at for the timed part of each run [s] (unless ``steps`` is given)
TARGET_SECONDS = 3.0
#: wall time of the extra timing of the bare step kernels [s] (see ``_time_kernels``)
KERNEL_SECONDS = 1.0
#: the timed part runs at least this many steps (unless ``steps`` is given): the bench specimen
#: rebuilds its rows about once per 100 steps, so a shorter window would count a whole rebuild
#: or none (at 1e6 elements one rebuild costs ~5 steps)
MIN_STEPS = 100
#: rock-like element parameters of the bench specimen (SI units; d = element spacing)
SPACING = 1.0e-3
SKIN = 0.3  # neighbour skin of the bench specimen, in lattice spacings (build_specimen)
DENSITY = 2650.0


class BenchError(ValueError):
    """Bad benchmark input (sizes, backends, steps); the message names the parameter."""


def estimated_memory(n: int, copies: int = 1) -> int:
    """Rough peak memory [bytes] of building and stepping an ``n``-element bench specimen with
    ``copies`` extra copies of the state alive (one when several backends share a specimen)."""
    return int(n) * (BYTES_PER_ELEMENT_ESTIMATE + copies * STATE_BYTES_PER_ELEMENT)


def mean_pair_gap(x, r, i, j, chunk: int = 1 << 20) -> float:
    """Mean surface gap ``|x_j - x_i| - (r_i + r_j)`` over the pairs ``(i, j)`` [m] (in chunks:
    no pair-sized temporary at 10^6 elements)."""
    total = 0.0
    for a in range(0, len(i), chunk):
        ii, jj = i[a:a + chunk], j[a:a + chunk]
        total += float((np.linalg.norm(x[jj] - x[ii], axis=1) - (r[ii] + r[jj])).sum())
    return total / max(len(i), 1)


def build_specimen(n: int, dim: int = 3, seed: int = 0):
    """The bench specimen: about ``n`` bonded elements (~12 contacts each in 3-D), Morton-sorted.

    ``random_specimen``'s radii overlap their lattice neighbours by 0.12 d on average. Bonded as
    they are, the block would be prestressed and breathe by 1-2 d at its faces, so the engine
    would rebuild the rows at nearly every step. The radii are therefore shifted by half that
    mean overlap, so the bonded network starts at zero mean strain; the sizes stay random and the
    pairs' own misfits (0.045 d) keep the elements vibrating at up to ~70 m/s. The skin is
    ``SKIN`` d: wide enough for that vibration, and still short of the lattice's second shell
    (1.34 d), so the rows keep the same ~12 contacts.
    """
    from geodem.build.lattice import bonded_state, contact_pairs, random_specimen
    from geodem.core.neighbors import build_rows, spatial_sort

    d = SPACING
    gap = 0.05 * d
    x, r = random_specimen(n, dim=dim, seed=seed, d=d)
    i, j = contact_pairs(x, r, gap)
    shift = 0.5 * mean_pair_gap(x, r, i, j)  # < 0: the radii shrink
    del i, j
    kn = 1.0e9 * d
    state = bonded_state(x, r + shift, density=DENSITY, kn=kn, ks=kn / 3.0, xb=1.0 * d,
                         fs0=1.0e3 * kn * d, mu=0.5, gap=gap - 2.0 * shift)  # the same pairs
    del x, r
    state.skin = SKIN * d
    build_rows(state)
    spatial_sort(state)
    return state


def _check_sizes(sizes) -> list[int]:
    out = []
    for s in sizes:
        if isinstance(s, (bool, np.bool_)):
            raise BenchError(f"sizes must be integers >= {MIN_SIZE}, got {s!r}")
        try:
            f = float(s)
        except (TypeError, ValueError):
            raise BenchError(f"sizes must be integers >= {MIN_SIZE}, got {s!r}") from None
        if not (math.isfinite(f) and f == int(f) and f >= MIN_SIZE):
            raise BenchError(f"sizes must be integers >= {MIN_SIZE}, got {s!r}")
        out.append(int(f))
    if not out:
        raise BenchError("sizes must name at least one model size")
    return out


def _check_backends(backends) -> list[str]:
    from geodem.backends import ALLOWED, BACKENDS, _load_all, available

    _load_all()
    if backends is None:
        return available()
    if isinstance(backends, str):
        backends = [backends]
    out = []
    for b in backends:
        name = str(b).strip().lower()
        if name not in ALLOWED:
            raise BenchError(f"backend {b!r} is not known; allowed: {', '.join(ALLOWED)}")
        if name == "auto":
            from geodem.backends import resolve_name

            name = resolve_name("auto")
        elif not BACKENDS[name].is_available():
            raise BenchError(f"backend {name!r} is not usable here: {BACKENDS[name].why_not()}; "
                             f"usable: {', '.join(available())}")
        if name not in out:
            out.append(name)
    if not out:
        raise BenchError("backends must name at least one backend")
    return out


def _threads(backend: str):
    if backend == "numba":
        from geodem.threads import numba_threads

        return numba_threads()
    if backend == "numpy":
        return 1
    return None  # GPU: not a thread count


def _device_sync(sim) -> None:
    """Wait for queued GPU work so that timings are honest (no-op on the CPU backends)."""
    xp = getattr(sim.backend, "xp", np)
    if xp is not np:  # pragma: no cover - needs a GPU
        xp.cuda.Device().synchronize()


def _say(progress, msg):
    if progress is not None:
        progress(msg)


def _time_kernels(sim, max_steps: int, seconds: float = KERNEL_SECONDS):
    """Element-steps/s of the bare step (the backend's ``move`` + ``force``, nothing else).

    Runs on the simulation's state after the timed run, for about ``seconds`` (at most
    ``max_steps`` steps); neighbour checks are skipped, so it is only a timing, not a valid
    continuation of the run (the bench throws the state away afterwards).
    """
    from geodem.core.state import broken_code

    s, b = sim.state, sim.backend
    dt = s.dt
    k = 0
    t0 = time.perf_counter()
    while k < max(1, max_steps):
        nxt = s.step + 1 + k
        b.move(dt)
        b.force(dt, broken_code(nxt, 1), broken_code(nxt, 2))
        k += 1
        if k >= 2 and time.perf_counter() - t0 > seconds:
            break
    _device_sync(sim)
    wall = time.perf_counter() - t0
    return s.n * k / wall, k


def _field_updates(sim) -> int | None:
    """Network updates of the simulation's coupled fields so far (``remeshes``), or None."""
    counts = [f.remeshes for f in getattr(sim, "fields", ()) if hasattr(f, "remeshes")]
    return int(sum(counts)) if counts else None


def _fit_dt(sim, dt: float, fraction: float, bound: float | None) -> None:
    """The time step becomes ``dt`` [s], or ``fraction`` x the fields' smallest
    ``mechanical_dt_bound`` ``bound`` where that is smaller; each field then checks it
    (FieldStabilityError if above)."""
    sim.state.dt = dt if bound is None else min(dt, fraction * bound)
    for f in sim.fields:
        if hasattr(f, "check_mechanical_dt"):
            f.check_mechanical_dt(sim)


def _field_steps(sim) -> dict:
    """At the start of the timed run: the coupled fields' own stable step (the smallest
    ``stable_dt`` [s], which sets their sub-steps per coupling) and the smallest bound they put
    on the mechanical step (``mechanical_dt_bound`` [s]); {} without fields."""
    if not sim.fields:
        return {}
    own = [f.stable_dt(sim) for f in sim.fields]
    bounds = [f.mechanical_dt_bound(sim) for f in sim.fields if hasattr(f, "mechanical_dt_bound")]
    return {"field_stable_dt_s": min(own),
            "field_mechanical_dt_bound_s": min(bounds) if bounds else None}


def bench_one(state, backend: str, steps: int | None = None, copy: bool = True,
              fields=(), fit_dt: float | None = None) -> dict:
    """Time ``Simulation.run`` of ``state`` on ``backend``; one record.

    ``copy=True`` steps a copy (so the next backend starts from the same state); ``False`` steps
    ``state`` itself (saves the memory of a copy; the state is changed). ``fields``: factories
    of coupled fields to attach first (their attach time is ``field_attach_s``). ``fit_dt``:
    the time step becomes at most this fraction of each field's ``mechanical_dt_bound`` (a
    stiff fluid in the smallest pore of a large network), recorded as ``dt_s`` and
    ``dt_fitted``; None keeps the state's time step (a field then refuses one above its bound).
    """
    from geodem.core.engine import Simulation
    from geodem.core.neighbors import row_counts

    st = state.copy() if copy else state
    n = st.n
    bytes_per_element = st.nbytes() / n
    contacts = float(row_counts(st).mean())
    kw = {}
    if "monitor_every" in inspect.signature(Simulation).parameters:
        # the periodic energy/overlap monitors are not part of the step being timed (and the
        # generated specimen starts with overlaps near the monitor's limit)
        kw["monitor_every"] = 0
    sim = Simulation(st, backend=backend, **kw)
    t0 = time.perf_counter()
    dt0 = st.dt
    if fit_dt:
        st.dt = 0.0  # the fields check their bound against a set time step only
    for make in fields:
        sim.add_field(make())
    steps_at_start = _field_steps(sim)
    if fit_dt:
        _fit_dt(sim, dt0, fit_dt, steps_at_start.get("field_mechanical_dt_bound_s"))
    attach = time.perf_counter() - t0
    # the backend's own buffers and tables count too (numba: the threads' force buffers)
    scratch = getattr(sim.backend, "scratch_nbytes", lambda: 0)()
    # warm-up: compiles the kernels on first use; not timed
    t0 = time.perf_counter()
    sim.run(2)
    _device_sync(sim)
    warm = time.perf_counter() - t0
    if steps is None:
        # calibration (not timed in the result): step time without compilation, checks and
        # rebuilds included when they come within about a second, to aim at TARGET_SECONDS
        t0 = time.perf_counter()
        k = 0
        while k < 2 * sim.check_every and (k < 2 or time.perf_counter() - t0 < 1.0):
            sim.run(1)
            k += 1
        _device_sync(sim)
        per_step = max((time.perf_counter() - t0) / k, 1e-9)
        steps = max(MIN_STEPS, int(math.ceil(TARGET_SECONDS / per_step)))
    rebuilds0 = getattr(sim, "rebuilds", None)
    updates0 = _field_updates(sim)
    t0 = time.perf_counter()
    sim.run(steps)
    _device_sync(sim)
    wall = time.perf_counter() - t0
    rebuilds = None if rebuilds0 is None else int(sim.rebuilds - rebuilds0)
    updates = None if updates0 is None else _field_updates(sim) - updates0
    broken = int(sim.crack_log().size)
    kernel_rate, kernel_steps = _time_kernels(sim, max_steps=steps)
    rec = {
        "backend": backend,
        "dim": st.dim,
        "dt_s": st.dt,
        "dt_fitted": st.dt < dt0,
        **steps_at_start,
        "n": int(n),
        "element_steps_per_s": n * steps / wall,
        "bytes_per_element": bytes_per_element + scratch / n,
        "state_bytes_per_element": bytes_per_element,
        "contacts_per_element": contacts,
        "steps": int(steps),
        "wall_s": wall,
        "threads": _threads(backend),
        "rebuilds": rebuilds,
        "kernel_element_steps_per_s": kernel_rate,
        "kernel_steps": kernel_steps,
        "bonds_broken": broken,
        "warmup_s": warm,
        "field_attach_s": attach,
        # network updates of the coupled fields in the timed steps (the pore field's
        # re-triangulations), None without such a field
        "field_network_updates": updates,
    }
    del sim, st
    gc.collect()
    return rec


def _load_average():
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):  # not on every platform
        return None


def _merge_repeats(recs: list[dict]) -> dict:
    """One record from the repeated runs of a (size, backend): the run of median speed, with
    every run's two speeds, their best and the load average before each run."""
    speeds = [r["element_steps_per_s"] for r in recs]
    rec = dict(recs[int(np.argsort(speeds)[(len(recs) - 1) // 2])])
    rec["repeats"] = len(recs)
    rec["element_steps_per_s_runs"] = speeds
    rec["element_steps_per_s_best"] = max(speeds)
    kernel = [r["kernel_element_steps_per_s"] for r in recs]
    rec["kernel_element_steps_per_s"] = float(np.median(kernel))
    rec["kernel_element_steps_per_s_runs"] = kernel
    rec["kernel_element_steps_per_s_best"] = max(kernel)
    rec["load_average_runs"] = [r["load_average"] for r in recs]
    return rec


def run_bench(sizes=DEFAULT_SIZES, backends=None, steps=None, dim=3, seed=0, progress=None,
              numpy_max=NUMPY_MAX, repeat=1) -> list[dict]:
    """Time full steps of bonded specimens of each size on each backend.

    Parameters
    ----------
    sizes: element counts (about; the lattice count is used), integers >= 100.
    backends: names (``numba``, ``numpy``, ``cupy``, ``auto``); default: every backend usable here.
        ``numpy`` is only run up to ``numpy_max`` elements (the reference is slow by design).
    steps: timed steps per run; default: as many as take about 3 s (at least 100).
    dim: 2 or 3. seed: specimen seed.
    progress: ``callable(str)`` receiving progress and skip messages, or None.
    repeat: runs per (size, backend), each on a fresh copy of the specimen, for a shared or
        noisy machine: the record is then the run of median speed, with every run's speeds
        (``element_steps_per_s_runs``, ``kernel_element_steps_per_s_runs``), their best
        (``..._best``), the median kernel speed, ``repeats`` and ``load_average_runs``.

    Returns one record per (size, backend) that was run, with the keys ``backend, dim, n,
    element_steps_per_s, bytes_per_element, state_bytes_per_element, contacts_per_element, steps,
    wall_s, threads, rebuilds, kernel_element_steps_per_s, kernel_steps, bonds_broken,
    warmup_s, load_average`` (the 1-minute load average before the run: another busy
    process on the cores slows every figure).
    ``element_steps_per_s`` is ``n * steps / wall_s`` of ``Simulation.run`` (checks and neighbour
    rebuilds included); ``kernel_element_steps_per_s`` times the bare step kernels alone.
    ``bytes_per_element`` is the memory of the model per element: ``state.nbytes() / n`` (all
    state arrays, also ``state_bytes_per_element``) plus the backend's own buffers and tables
    (``scratch_nbytes``); ``contacts_per_element`` the mean number of valid row entries.
    """
    sizes = _check_sizes(sizes)
    names = _check_backends(backends)
    if steps is not None:
        if isinstance(steps, bool) or int(steps) != steps or int(steps) < 1:
            raise BenchError(f"steps must be an integer >= 1, got {steps!r}")
        steps = int(steps)
    if dim not in (2, 3):
        raise BenchError(f"dim must be 2 or 3, got {dim!r}")
    if isinstance(repeat, bool) or int(repeat) != repeat or not 1 <= int(repeat) <= 100:
        raise BenchError(f"repeat must be an integer from 1 to 100, got {repeat!r}")
    repeat = int(repeat)
    records = []
    for n in sizes:
        todo = list(names)
        if "numpy" in todo and n > numpy_max:
            todo.remove("numpy")
            _say(progress, f"numpy skipped at n={n:,}: the op-by-op NumPy reference is slow by "
                           f"design and is only benchmarked up to {numpy_max:,} elements")
        if not todo:
            continue
        copies = 1 if len(todo) > 1 or repeat > 1 else 0
        need, have = estimated_memory(n, copies), available_memory()
        if have is not None and need > have:
            _say(progress, f"size n={n:,} skipped: needs about {need / 2**30:.1f} GiB "
                           f"(~{need / n / 1000:.1f} KB per element), only "
                           f"{have / 2**30:.1f} GiB available")
            continue
        _say(progress, f"building a {dim}-D bonded specimen of about {n:,} elements ...")
        t0 = time.perf_counter()
        try:
            state = build_specimen(n, dim=dim, seed=seed)
        except MemoryError:
            gc.collect()
            _say(progress, f"size n={n:,} skipped: out of memory while building the specimen")
            continue
        _say(progress, f"  built {state.n:,} elements in {time.perf_counter() - t0:.1f} s")
        for k, b in enumerate(todo):
            runs = []
            for rep in range(repeat):
                tag = f" (run {rep + 1} of {repeat})" if repeat > 1 else ""
                _say(progress, f"  {b}: warm-up and timing{tag} ...")
                load = _load_average()
                try:
                    # the last run of a size steps the specimen itself (no copy)
                    last = k == len(todo) - 1 and rep == repeat - 1
                    rec = bench_one(state, b, steps=steps, copy=not last)
                except MemoryError:
                    gc.collect()
                    _say(progress, f"  {b} skipped at n={n:,}: out of memory")
                    break
                rec["load_average"] = load
                _say(progress, f"  {b}: {rec['element_steps_per_s']:.3g} element-steps/s "
                               f"({rec['steps']} steps in {rec['wall_s']:.2f} s)")
                runs.append(rec)
            if runs and repeat > 1:
                if len(runs) < repeat:
                    _say(progress, f"  {b}: only {len(runs)} of {repeat} runs at n={n:,}")
                records.append(_merge_repeats(runs))
            elif runs:
                records.append(runs[0])
        del state
        gc.collect()
    return records
