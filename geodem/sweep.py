"""Parameter sweeps and Monte-Carlo ensembles of one workflow on Dask distributed.

``geodem sweep FILE.yaml --param a.b=1,2,3 [--param c.d=...] [--zip] [--seeds N]
[--scheduler ADDRESS | --workers N] -o DIR`` runs one workflow once per *member* (a combination
of parameter values) and gathers the results. See docs/sweeps.md.

Members
    ``--param KEY=V1,V2,...`` gives one parameter (``KEY`` is a ``--set`` path such as
    ``steps.oscillate.nsteps``; every value is YAML, parsed exactly as a ``--set`` value). Values
    are separated by commas outside brackets and quotes (``model.counts=[10,10],[20,20]``), or by
    ``;`` when the text holds one (``'model.counts=[10,10];[20,20]'``). The members are the
    Cartesian product of the parameters, or with ``zip_=True`` the n-th values of every parameter
    together (equal lengths). ``seeds=N`` crosses every member with ``metadata.seed = 0..N-1``.

Validation
    Every member is loaded and validated against the schema on the submitting machine before
    anything is written or submitted; an invalid member is a
    :class:`~geodem.workflow.errors.WorkflowError` (exit status 2) that names the member and
    the field. Problems that only show when the model is built (a time step above the stability
    limit, a packing that cannot be made) make that member fail in its worker.

Layout
    ::

        DIR/members.json           hash12 -> parameter values of every member
        DIR/members/<hash12>/      the member's run directory (geodem run's layout)
        DIR/results.csv            one row per member: hash, parameters, status, wall time,
                                   the scalars of its summary.json (results.<step>.<key> too)
        DIR/summary.json           members, completed, failed, skipped, wall_time_s, scheduler,
                                   parameters, failures, duplicates

    ``hash12`` is the first 12 hex digits of the runner's config hash of the member's resolved
    workflow (:func:`geodem.workflow.runner.config_hash`), so parameter combinations that give
    the same workflow share one directory (and run once).

Execution
    A ``LocalCluster`` of ``workers`` single-threaded worker processes, or the Dask scheduler at
    ``scheduler`` (any: ``dask-jobqueue``, Kubernetes, ``dask scheduler`` by hand). Workers need
    geodem importable and the same file system (workflow file, DIR). Each member runs in one
    task, with ``NUMBA_NUM_THREADS`` set to ``numba_threads`` (default 1) before numba is
    imported in the worker. A member that fails (exception, exit status != 0, worker lost) is
    recorded with its error; the others go on.
"""
from __future__ import annotations

import csv
import itertools
import json
import math
import os
import platform
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from geodem.workflow.errors import ErrorItem, WorkflowError

__all__ = [
    "Member",
    "Parameter",
    "SweepInterrupted",
    "expand",
    "flatten_summary",
    "parse_param",
    "plan_members",
    "run_member",
    "run_sweep",
    "split_values",
]

MEMBERS_DIR = "members"
MEMBERS_JSON = "members.json"
RESULTS_CSV = "results.csv"
SUMMARY_JSON = "summary.json"
HASH_LEN = 12
SEED_KEY = "metadata.seed"
#: seconds to wait for an external scheduler before giving up (exit status 2)
CONNECT_TIMEOUT_S = 30.0
#: result columns written before the member's summary scalars
FIXED_COLUMNS = ("hash", "status", "skipped", "resumed", "wall_s", "host", "numba_threads",
                 "error")


# ============================================================================ parameters
@dataclass
class Parameter:
    """One ``--param KEY=V1,V2,...``: the key, every value's text (as given) and YAML value."""

    key: str
    texts: list
    values: list
    origin: str = ""


def _perr(origin: str, path: str, msg: str) -> WorkflowError:
    return WorkflowError(ErrorItem(origin, None, path, msg))


def split_values(text: str, origin: str = "--param", key: str = "(value)") -> list[str]:
    """Split the value list of a ``--param``: on ``;`` if the text holds one, else on commas
    outside ``[]``, ``{}`` and quotes. Items are stripped; an empty item is an error."""
    if ";" in text:
        items = text.split(";")
    else:
        items, cur, depth, quote = [], [], 0, None
        for ch in text:
            if quote:
                cur.append(ch)
                if ch == quote:
                    quote = None
                continue
            if ch in "'\"":
                quote = ch
            elif ch in "[{":
                depth += 1
            elif ch in "]}":
                depth -= 1
                if depth < 0:
                    raise _perr(origin, key, f"unbalanced {ch!r} in {text!r}")
            elif ch == "," and depth == 0:
                items.append("".join(cur))
                cur = []
                continue
            cur.append(ch)
        if depth or quote:
            raise _perr(origin, key, f"unclosed {'quote' if quote else 'bracket'} in {text!r}; "
                                     "a list value is written [a,b] (separate such values "
                                     "with ';', e.g. 'model.counts=[10,10];[20,20]')")
        items.append("".join(cur))
    items = [it.strip() for it in items]
    if any(not it for it in items):
        raise _perr(origin, key, f"empty value in {text!r}; give values separated by ',' "
                                 "(or by ';' when they contain commas), e.g. a.b=1,2,3")
    return items


def parse_param(expr: str) -> Parameter:
    """Parse one ``KEY=V1,V2,...`` (see :func:`split_values`); WorkflowError when malformed."""
    import yaml

    from geodem.workflow.yamlio import parse_scalar

    origin = f"--param {expr}"
    if "=" not in expr:
        raise _perr(origin, expr or "(empty)", "expected KEY=V1,V2,..., e.g. --param "
                                               "steps.oscillate.nsteps=100,200")
    key, text = expr.split("=", 1)
    key = key.strip()
    comps = key.split(".")
    if not key or any(not c.strip() for c in comps):
        raise _perr(origin, key or "(empty)", "the key is a dotted path such as "
                                              "simulation.dt_fraction (as for --set)")
    texts = split_values(text, origin, key)
    values = []
    for t in texts:
        try:
            values.append(parse_scalar(t))
        except yaml.YAMLError as exc:
            msg = " ".join(str(exc).split())
            raise _perr(origin, key, f"value {t!r} is not valid YAML: {msg}") from None
    return Parameter(key, texts, values, origin)


def expand(params: list, zip_: bool = False, seeds: int | None = None) -> list[list]:
    """The members as lists of ``(key, text, value)``: the Cartesian product of ``params`` (or
    their n-th values together with ``zip_``), each crossed with ``metadata.seed = 0..seeds-1``.
    """
    keys = [p.key for p in params]
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise _perr("--param", dup[0], "given twice; give every parameter once with all its "
                                       "values (--param KEY=V1,V2,...)")
    if seeds is not None:
        if seeds < 1:
            raise _perr("--seeds", "metadata.seed", f"allowed: an integer >= 1, got {seeds}")
        if SEED_KEY in keys:
            raise _perr("--seeds", SEED_KEY, "--seeds sets metadata.seed = 0..N-1; do not also "
                                             "give --param metadata.seed=...")
    if not params and seeds is None:
        raise _perr("--param", "(none)", "a sweep needs at least one --param KEY=V1,V2,... or "
                                         "--seeds N")
    cols = [[(p.key, t, v) for t, v in zip(p.texts, p.values)] for p in params]
    if zip_ and cols:
        lens = {p.key: len(p.values) for p in params}
        if len(set(lens.values())) > 1:
            shown = ", ".join(f"{k}: {n}" for k, n in lens.items())
            raise _perr("--zip", "(lengths)", f"--zip pairs the n-th values of every --param, "
                                              f"so they need equal numbers of values; got "
                                              f"{shown}")
        combos = [list(c) for c in zip(*cols)]
    else:
        combos = [list(c) for c in itertools.product(*cols)]
    if seeds is not None:
        combos = [c + [(SEED_KEY, str(s), s)] for c in combos for s in range(seeds)]
    return combos


# ============================================================================ members
@dataclass
class Member:
    """One distinct workflow of the sweep."""

    index: int
    key: str                   # hash12: the directory name under DIR/members/
    config_hash: str
    values: dict               # parameter key -> value (YAML-parsed)
    sets: list                 # the --set expressions that make it
    backend: str = ""          # resolved on the submitting machine, passed to the worker
    duplicates: list = field(default_factory=list)  # other combinations, same workflow


def _label(combo) -> str:
    return ", ".join(f"{k}={t}" for k, t, _ in combo) or "(no parameters)"


def member_hash(path, sets, backend=None) -> tuple[str, str]:
    """``(config hash, backend name)`` of ``path`` with ``sets`` applied, computed without
    building the model: the hash is the one :func:`geodem.workflow.runner.prepare` gives for
    that backend; WorkflowError when the workflow is invalid."""
    from geodem.workflow.runner import config_hash, validated

    _, _, name, resolved = validated(path, sets, backend)
    return config_hash(resolved), name


def plan_members(workflow, params: list, zip_: bool = False, seeds: int | None = None,
                 backend: str | None = None, base_sets=()) -> list:
    """Expand and validate every member; returns the distinct :class:`Member` list.

    Combinations with the same resolved workflow become one member (the others are listed in
    its ``duplicates``). Raises WorkflowError naming every invalid member and its field."""
    combos = expand(params, zip_, seeds)
    errors: list = []
    members: dict = {}
    for i, combo in enumerate(combos):
        sets = list(base_sets) + [f"{k}={t}" for k, t, _ in combo]
        try:
            h, name = member_hash(workflow, sets, backend)
        except WorkflowError as exc:
            who = f"member {i + 1} of {len(combos)} ({_label(combo)})"
            ours = {f"--set {k}={t}": f"--param {k}={t}" for k, t, _ in combo}
            errors += [ErrorItem(ours.get(it.file, it.file), it.line, it.path,
                                 f"{who}: {it.message}") for it in exc.items]
            continue
        values = {k: v for k, _, v in combo}
        if h in members:
            members[h].duplicates.append(values)
        else:
            members[h] = Member(len(members), h[:HASH_LEN], h, values, sets, backend=name)
    if errors:
        raise WorkflowError(errors)
    return list(members.values())


# ============================================================================ the task
def _set_threads(n: int) -> int:
    """Make numba use ``n`` threads in this process: through ``NUMBA_NUM_THREADS`` when numba is
    not imported yet, else ``numba.set_num_threads`` (capped at its pool). Returns the count."""
    if "numba" not in sys.modules:
        os.environ["NUMBA_NUM_THREADS"] = str(n)
    import numba

    n = max(1, min(int(n), int(numba.config.NUMBA_NUM_THREADS)))
    numba.set_num_threads(n)
    return int(numba.get_num_threads())


def _member_dir_state(path: Path) -> str:
    """``complete`` (summary.json with status ok), ``empty`` (missing or empty) or ``partial``."""
    if not path.is_dir() or not any(path.iterdir()):
        return "empty"
    try:
        if json.loads((path / "summary.json").read_text()).get("status") == "ok":
            return "complete"
    except (OSError, ValueError, AttributeError):
        pass
    return "partial"


def run_member(workflow: str, out_dir: str, sets: list, backend: str | None,
               expected_hash: str, numba_threads: int = 1, resume: bool = True) -> dict:
    """Run one member into ``out_dir`` (executed in a Dask worker); never raises.

    A ``partial`` member directory (an interrupted run) is continued from its newest checkpoint
    when ``resume`` and the checkpoint belongs to the same workflow; a failed run or one without
    a checkpoint is started again. Returns a record with
    ``status`` (the run's, or ``invalid`` / ``failed`` for errors), ``exit_code``, ``error``,
    ``wall_s``, ``host``, ``numba_threads``, ``resumed`` and the run's ``summary``."""
    t0 = time.perf_counter()
    rec: dict[str, Any] = {"host": platform.node(), "resumed": False, "summary": None,
                           "error": None}
    try:
        rec["numba_threads"] = _set_threads(numba_threads)
        from geodem.workflow import WorkflowError as WErr
        from geodem.workflow import run_workflow
        from geodem.workflow.rundir import RunDir

        out = Path(out_dir)
        state = _member_dir_state(out)
        go_on = False
        if state == "partial":
            before = _read_summary(out) or {}
            latest = RunDir(out).latest_checkpoint() if resume else None
            if latest is not None and latest[0].get("config_hash") == expected_hash and \
                    (out / "manifest.json").exists() and before.get("status") != "failed":
                go_on = True
            elif (out / "manifest.json").exists():
                pass  # started again below with overwrite=True
            else:
                shutil.rmtree(out)  # our own member folder without a run in it
        try:
            code, summary = run_workflow(workflow, out, sets=sets, backend=backend,
                                         resume=go_on, overwrite=not go_on and out.exists(),
                                         echo=False, progress=False)
        except WErr as exc:
            code, summary = 2, None
            rec["status"] = "invalid"
            rec["error"] = str(exc)
        rec["resumed"] = go_on
        rec["exit_code"] = code
        if summary is not None:
            rec["summary"] = summary
            rec["status"] = summary.get("status", "failed")
            if summary.get("error"):
                rec["error"] = str(summary["error"])
            got = summary.get("config_hash")
            if got and got != expected_hash:
                rec["status"] = "failed"
                rec["error"] = (f"config hash {got[:HASH_LEN]} in the worker differs from "
                                f"{expected_hash[:HASH_LEN]} on the submitting machine (a "
                                "different geodem version or backend on the worker?)")
            elif code != 0 and rec["status"] == "ok":
                rec["status"] = "failed"
                rec["error"] = rec["error"] or f"exit status {code}"
    except Exception as exc:  # noqa: BLE001 - a member's failure is data, not a crash
        rec["status"] = "failed"
        rec["exit_code"] = 1
        rec["error"] = f"{type(exc).__name__}: {exc}"
    rec["wall_s"] = time.perf_counter() - t0
    return rec


# ============================================================================ results
def _scalar(v) -> bool:
    return v is None or isinstance(v, (bool, int, float, str))


def flatten_summary(summary: dict) -> dict:
    """The scalar top-level keys of a run's summary.json, plus ``results.<step>.<key>`` (deeper
    mappings joined with dots) for the scalars under ``results``. Lists are left out."""
    out: dict = {}
    for k, v in (summary or {}).items():
        if k != "results" and _scalar(v):
            out[k] = v

    def walk(prefix, node):
        for k, v in node.items():
            if isinstance(v, dict):
                walk(f"{prefix}.{k}", v)
            elif _scalar(v):
                out[f"{prefix}.{k}"] = v

    res = (summary or {}).get("results")
    if isinstance(res, dict):
        walk("results", res)
    return out


def _cell(v):
    if v is None:
        return ""
    if isinstance(v, float) and not math.isfinite(v):
        return ""
    if isinstance(v, (list, dict)):
        return json.dumps(v, default=str)
    return v


def _read_summary(path: Path) -> dict | None:
    try:
        data = json.loads((path / "summary.json").read_text())
        return data if isinstance(data, dict) else None
    except (OSError, ValueError):
        return None


def write_results(path: Path, members: list, records: dict, param_keys: list) -> None:
    """``results.csv``: one row per member (columns: FIXED_COLUMNS with the parameters after
    ``hash``, then every summary scalar seen, in order of first appearance)."""
    rows, extra = [], []
    for m in members:
        rec = records.get(m.key, {})
        flat = flatten_summary(rec.get("summary") or {})
        row = {"hash": m.key, **m.values, "status": rec.get("status", "pending"),
               "skipped": bool(rec.get("skipped", False)),
               "resumed": bool(rec.get("resumed", False)), "wall_s": rec.get("wall_s"),
               "host": rec.get("host"), "numba_threads": rec.get("numba_threads"),
               "error": rec.get("error")}
        for k, v in flat.items():
            if k in row:
                continue
            row[k] = v
            if k not in extra:
                extra.append(k)
        rows.append(row)
    cols = ["hash", *param_keys, *[c for c in FIXED_COLUMNS if c != "hash"], *extra]
    import io

    from geodem.workflow.rundir import atomic_write

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for row in rows:
        w.writerow({c: _cell(row.get(c)) for c in cols})
    atomic_write(path, buf.getvalue())


# ============================================================================ the sweep
class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C during a sweep: results so far were written; ``summary`` holds them."""

    def __init__(self, summary):
        super().__init__("sweep interrupted")
        self.summary = summary


def _prepare_dir(out: Path, resume: bool, overwrite: bool) -> None:
    """Check that DIR may be used (WorkflowError, exit 2, nothing touched when not)."""
    def err(msg):
        return WorkflowError(ErrorItem(str(out), None, "(sweep directory)", msg))

    if resume and overwrite:
        raise err("--resume and --overwrite exclude each other: --resume keeps completed "
                  "members, --overwrite deletes them all")
    if out.exists() and not out.is_dir():
        raise err("exists and is not a folder; choose another -o")
    empty = not out.exists() or not any(out.iterdir())
    if empty:
        return
    is_sweep = (out / MEMBERS_JSON).exists()
    if resume:
        if not is_sweep:
            raise err(f"is not a geodem sweep directory (no {MEMBERS_JSON}); --resume continues "
                      "a sweep: choose another -o")
        return
    if not overwrite:
        raise err("already exists and is not empty; add --resume to run only the members not "
                  "completed yet, --overwrite to delete it and start again, or choose another -o")
    if not is_sweep:
        raise err(f"is not a geodem sweep directory (no {MEMBERS_JSON}); refusing to delete its "
                  "contents with --overwrite: choose another -o")


def _clear(out: Path) -> None:
    for child in out.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child)
        else:
            child.unlink()


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _import_distributed():
    try:
        import distributed  # noqa: F401
    except ImportError as exc:
        raise WorkflowError(ErrorItem("geodem sweep", None, "(dependencies)",
                                      f"needs dask.distributed ({exc}); install it with "
                                      "pip install 'dask[distributed]' (or geodem[dist])")) \
            from None


def _connect(scheduler, n_workers, numba_threads, timeout):
    """``(client, cluster or None, description)``; WorkflowError when the scheduler cannot be
    reached."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=timeout)
        except (OSError, TimeoutError, ValueError) as exc:
            raise WorkflowError(ErrorItem(f"--scheduler {scheduler}", None, "(scheduler)",
                                          f"cannot reach a Dask scheduler there within "
                                          f"{timeout:g} s: {type(exc).__name__}: {exc}")) \
                from None
        return client, None, scheduler
    env = {"NUMBA_NUM_THREADS": str(numba_threads), "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, env=env,
                           dashboard_address=None, silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
    except BaseException:
        cluster.close()
        raise
    return client, cluster, f"local ({n_workers} worker process{'es' * (n_workers != 1)})"


def _write_json(path: Path, data) -> None:
    from geodem.workflow.rundir import write_json

    write_json(path, json.loads(json.dumps(data, default=str)))


def run_sweep(workflow, out_dir, params: list, *, zip_: bool = False, seeds: int | None = None,
              backend: str | None = None, scheduler: str | None = None,
              workers: int | None = None, numba_threads: int = 1, resume: bool = False,
              overwrite: bool = False, sets=(), on_member: Callable | None = None,
              bar: bool = False, console=None,
              connect_timeout: float = CONNECT_TIMEOUT_S) -> tuple[int, dict]:
    """Run a sweep (see the module doc); returns ``(exit status, summary)``.

    ``params`` are :class:`Parameter` objects or ``KEY=V1,V2`` strings; ``sets`` are ``--set``
    overrides applied to every member. Exit status 0 when every member completed, 1 when any
    failed. Raises WorkflowError (exit 2) for invalid input -- a malformed parameter, an invalid
    member, an unusable DIR, an unreachable scheduler -- before anything is written, and
    :class:`SweepInterrupted` on Ctrl-C (after writing the results so far). ``on_member(member,
    record)`` is called as each member finishes (and for skipped ones)."""
    t0 = time.perf_counter()
    params = [p if isinstance(p, Parameter) else parse_param(p) for p in params]
    wf = Path(workflow)
    if not wf.is_file():
        raise WorkflowError(ErrorItem(str(wf), None, "(file)", f"file not found: {wf}"))
    if workers is not None and scheduler:
        raise _perr("--workers", "(workers)", "--workers sizes the local cluster; with "
                                              "--scheduler the cluster's own workers are used")
    if workers is not None and workers < 1:
        raise _perr("--workers", "(workers)", f"allowed: an integer >= 1, got {workers}")
    if numba_threads < 1:
        raise _perr("--numba-threads", "(threads)", f"allowed: an integer >= 1, got "
                                                    f"{numba_threads}")
    if backend is not None:
        from geodem.backends import BackendError, resolve_name

        try:
            backend = resolve_name(backend)
        except BackendError as exc:
            raise _perr(f"--backend {backend}", "backend", str(exc)) from None
    members = plan_members(wf, params, zip_, seeds, backend, base_sets=sets)
    out = Path(out_dir)
    _prepare_dir(out, resume, overwrite)
    param_keys = [p.key for p in params] + ([SEED_KEY] if seeds is not None else [])

    mdir = out / MEMBERS_DIR
    records: dict = {}
    todo = []
    for m in members:
        d = mdir / m.key
        if resume and _member_dir_state(d) == "complete":
            records[m.key] = {"status": "ok", "skipped": True, "summary": _read_summary(d),
                              "error": None}
        else:
            todo.append(m)

    client = cluster = None
    where = "none (every member already complete)"
    if todo:
        _import_distributed()
        n = workers or max(1, min(_cpus(), len(todo)))
        client, cluster, where = _connect(scheduler, n, numba_threads, connect_timeout)
    try:
        if overwrite and out.exists():
            _clear(out)
        mdir.mkdir(parents=True, exist_ok=True)
        _write_json(out / MEMBERS_JSON, {m.key: m.values for m in members})
        for m in members:
            if m.key in records and on_member:
                on_member(m, records[m.key])
        interrupted = False
        if todo:
            interrupted = _execute(client, wf, mdir, todo, records, numba_threads,
                                   resume, on_member, bar, console)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()

    for m in members:  # the member's own summary.json is the reference (shared file system)
        rec = records.setdefault(m.key, {"status": "pending", "error": "not run (interrupted)"})
        disk = _read_summary(mdir / m.key)
        if disk is not None and rec.get("status") != "pending":
            rec["summary"] = disk
    write_results(out / RESULTS_CSV, members, records, param_keys)
    summary = _sweep_summary(wf, members, records, params, zip_, seeds, where,
                             time.perf_counter() - t0, interrupted)
    _write_json(out / SUMMARY_JSON, summary)
    if interrupted:
        raise SweepInterrupted(summary)
    return (0 if summary["failed"] == 0 else 1), summary


def _execute(client, wf, mdir, todo, records, numba_threads, resume, on_member, bar,
             console) -> bool:
    """Submit ``todo`` and collect the records as they finish; True when interrupted."""
    import uuid

    from distributed import as_completed

    tag = uuid.uuid4().hex[:8]
    futures = {}
    for m in todo:
        fut = client.submit(run_member, str(wf.resolve()), str((mdir / m.key).resolve()),
                            m.sets, m.backend, m.config_hash, numba_threads, resume,
                            key=f"geodem-member-{m.key}-{tag}", pure=False, retries=0)
        futures[fut] = m
    progress = task = None
    if bar:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        progress = Progress(TextColumn("[bold]sweep"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("failed {task.fields[failed]}"), TimeElapsedColumn(),
                            TextColumn("ETA"), TimeRemainingColumn(), console=console,
                            transient=False)
        progress.start()
        task = progress.add_task("sweep", total=len(todo), failed=0)
    failed = 0
    try:
        for fut in as_completed(list(futures)):
            m = futures[fut]
            try:
                rec = fut.result()
            except Exception as exc:  # noqa: BLE001 - worker lost, unpicklable result, ...
                rec = {"status": "failed", "exit_code": 1, "summary": None,
                       "error": f"{type(exc).__name__}: {exc}"}
            rec["skipped"] = False
            records[m.key] = rec
            failed += rec.get("status") != "ok"
            if progress is not None:
                progress.update(task, advance=1, failed=failed)
            if on_member:
                on_member(m, rec)
    except KeyboardInterrupt:
        for fut in futures:
            fut.cancel()
        return True
    finally:
        if progress is not None:
            progress.stop()
    return False


def _sweep_summary(wf, members, records, params, zip_, seeds, where, wall,
                   interrupted) -> dict:
    from geodem import __version__
    from geodem.workflow.progress import now_iso

    status = {m.key: records.get(m.key, {}).get("status") for m in members}
    completed = sum(s == "ok" for s in status.values())
    pending = sum(s == "pending" for s in status.values())
    failures = [{"hash": m.key, "parameters": m.values, "status": status[m.key],
                 "error": records[m.key].get("error")}
                for m in members if status[m.key] not in ("ok", "pending")]
    out = {
        "workflow": str(wf),
        "status": "interrupted" if interrupted else ("ok" if not failures else "failed"),
        "members": len(members),
        "completed": completed,
        "failed": len(failures),
        "skipped": sum(bool(records.get(m.key, {}).get("skipped")) for m in members),
        "wall_time_s": wall,
        "scheduler": where,
        "backend": ", ".join(sorted({m.backend for m in members})),
        "parameters": {p.key: p.values for p in params},
        "zip": bool(zip_),
        "seeds": seeds,
        "failures": failures,
        "duplicates": [{"hash": m.key, "parameters": d} for m in members for d in m.duplicates],
        "results": RESULTS_CSV,
        "geodem_version": __version__,
        "finished": now_iso(),
    }
    if pending:
        out["pending"] = pending
    return out
