"""The ``geodem`` command line (typer + rich).

::

    geodem [-v] info [--json]
    geodem [-v] bench [--sizes 10000,100000,1000000] [--backends numba,numpy] [--steps N] [--json]
    geodem run FILE.yaml -o DIR [--backend B] [--set a.b=c ...] [--dry-run] [--resume]
               [--stop-after-steps N] [--overwrite] [--no-progress] [-v]
    geodem validate FILE.yaml [--set a.b=c ...] [--backend B]
    geodem advise FILE.yaml [--set a.b=c ...] [--backend B] [--no-calibrate]
                  [--target-error E] [--speed-accuracy CSV] [--json]
    geodem sweep FILE.yaml --param a.b=1,2,3 [--param ...] [--zip] [--seeds N]
                 [--scheduler ADDRESS | --workers N] [--resume | --overwrite] -o DIR
    geodem calibrate MATERIAL -o DIR [--dim D] [--packing P] [--bond-gap G] [--bond-weibull M]
                     [--save]
    geodem rock MATERIAL -o DIR [--dim D] [--packing P] [--bond-gap G] [--bond-weibull M]
                [--bond-moment B] [--rolling-friction MU] [--friction] [--packings N] [--seed S]
    geodem schema [-o FILE]

Backend choice for a run: ``--backend`` > the workflow's ``backend:`` key (``geodem run``) >
environment variable ``GEODEM_BACKEND`` > ``auto`` (``cupy`` on a usable GPU, else ``numba``).
User errors (bad option values, unknown or unusable backend, non-empty output folder, invalid
workflow, a missing optional extra: the message names the pip install, see geodem.extras) print
a message on stderr and exit with status 2 -- an invalid workflow as one line per
problem, ``FILE.yaml:LINE: <field path>: <message>``; other failures exit with status 1.
``-v/--verbose`` shows the traceback. See docs/workflows.md.
"""
from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import platform
import sys
import traceback
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from geodem import __version__, threads

app = typer.Typer(
    name="geodem",
    help="geodem: discrete-element (DEM) simulation of bonded rock, MatDEM style.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

_OPTS = {"verbose": False}
USER_ERROR = 2
FAILURE = 1
ENV_BACKEND = "GEODEM_BACKEND"


def _out() -> Console:
    return Console()


def _err() -> Console:
    return Console(stderr=True)


# ----------------------------------------------------------------------------- errors
def _user_error_types():
    from geodem.backends import BackendError
    from geodem.bench import BenchError
    from geodem.extras import MissingExtra
    from geodem.geo.errors import GeometryError
    from geodem.io.view import ViewError
    from geodem.materials_library import MaterialError
    from geodem.workflow.errors import WorkflowError

    # typer.BadParameter: an option checked inside a command's body
    return (BackendError, BenchError, WorkflowError, MaterialError, GeometryError,
            ViewError, MissingExtra, typer.BadParameter)


def _command_name() -> str:
    """``geodem <command>`` of the command running (for messages); typer keeps its own copy
    of click (typer._click) in recent versions."""
    ctx = None
    for mod in ("typer._click.globals", "click.globals"):
        try:
            ctx = __import__(mod, fromlist=["get_current_context"]).get_current_context(
                silent=True)
        except Exception:  # noqa: BLE001 - no such module, or no context
            ctx = None
        if ctx is not None:
            break
    name = getattr(ctx, "info_name", None)
    return f"geodem {name}" if name and name != "geodem" else "geodem"


def _fail(msg: str, code: int) -> None:
    err = _err()
    err.print(f"[bold red]Error:[/] {escape(msg)}", highlight=False, markup=True, soft_wrap=True)
    raise typer.Exit(code)


def _guard(fn):
    """Turn exceptions of a command into a message on stderr and an exit status.

    User errors exit with 2, anything else with 1; ``-v`` prints the traceback first.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (typer.Exit, typer.Abort, KeyboardInterrupt):
            raise
        except Exception as exc:  # noqa: BLE001 - the one place errors become exit codes
            from geodem.extras import MissingExtra, missing_extra
            from geodem.workflow.errors import WorkflowError

            if not isinstance(exc, MissingExtra):
                # an optional package absent (the import deep inside a command): the extra
                # that installs it, as a user error
                exc = missing_extra(exc, _command_name()) or exc
            user = isinstance(exc, _user_error_types())
            if _OPTS["verbose"]:
                traceback.print_exc(file=sys.stderr)
            if isinstance(exc, WorkflowError):
                # one plain line per problem (no wrapping): FILE.yaml:LINE: path: message
                for line in exc.lines():
                    sys.stderr.write(line + "\n")
                sys.stderr.flush()
                raise typer.Exit(USER_ERROR) from None
            msg = str(exc)  # _fail escapes the markup once
            if not user:
                msg = f"{type(exc).__name__}: {msg}"
                if not _OPTS["verbose"]:
                    msg += " (run 'geodem -v ...' for the traceback)"
            _fail(msg, USER_ERROR if user else FAILURE)

    return wrapper


# ----------------------------------------------------------------------------- option parsing
def _allowed_backends():
    from geodem.backends import ALLOWED

    return ALLOWED


def _parse_backend(value: Optional[str]) -> Optional[str]:
    if value is None:
        return None
    name = value.strip().lower()
    allowed = _allowed_backends()
    if name not in allowed:
        raise typer.BadParameter(f"{value!r} is not a known backend; allowed: "
                                 f"{', '.join(allowed)}")
    return name


def _parse_backends(value: Optional[str]) -> Optional[list]:
    if value is None:
        return None
    names = [v.strip().lower() for v in value.split(",") if v.strip()]
    if not names:
        raise typer.BadParameter(f"{value!r} names no backend; give a comma-separated list of: "
                                 f"{', '.join(_allowed_backends())}")
    return [_parse_backend(name) for name in names]


def _parse_sizes(value: Optional[str]) -> Optional[list]:
    from geodem.bench import MIN_SIZE

    if value is None:
        return None
    out = []
    parts = [p.strip().replace("_", "") for p in value.split(",")]
    for p in parts:
        try:
            f = float(p)
        except ValueError:
            f = None
        if f is None or f != f or f in (float("inf"), float("-inf")) or f != int(f) \
                or f < MIN_SIZE:
            raise typer.BadParameter(
                f"{p!r} is not a model size; allowed: comma-separated integers >= {MIN_SIZE}, "
                f"e.g. 10000,100000 or 1e4,1e5")
        out.append(int(f))
    return out


def _resolve_backend(option: Optional[str]) -> str:
    """``--backend`` > ``$GEODEM_BACKEND`` > ``auto``; BackendError names where it came from."""
    from geodem.backends import BackendError, resolve_name

    if option is not None:
        return resolve_name(option)
    env = os.environ.get(ENV_BACKEND)
    if env:
        try:
            return resolve_name(env)
        except BackendError as exc:
            raise BackendError(f"environment variable {ENV_BACKEND}={env!r}: {exc}") from None
    return resolve_name("auto")


# ----------------------------------------------------------------------------- main callback
def _version_callback(value: bool):
    if value:
        typer.echo(f"geodem {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    verbose: Annotated[bool, typer.Option("-v", "--verbose",
                                          help="Show full tracebacks on errors.")] = False,
    version: Annotated[Optional[bool], typer.Option(
        "--version", callback=_version_callback, is_eager=True,
        help="Print the version and exit.")] = None,
):
    """geodem: discrete-element (DEM) simulation of bonded rock, MatDEM style.

    Backends: auto (cupy on a usable GPU, else numba), numba, numpy, cupy. Choose one with
    --backend or the environment variable GEODEM_BACKEND (the option wins).
    """
    _OPTS["verbose"] = verbose


# ----------------------------------------------------------------------------- info
def _version_of(module: str) -> str:
    import importlib

    try:
        mod = importlib.import_module(module)
    except Exception as exc:  # noqa: BLE001
        return f"not installed ({type(exc).__name__})"
    ver = getattr(mod, "__version__", None)
    if ver is None:
        try:
            from importlib.metadata import version

            ver = version(module)
        except Exception:  # noqa: BLE001
            ver = "unknown"
    return str(ver)


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _gpu_info() -> list:
    """One dict per CUDA device (cupy), or [] when cupy is not usable."""
    try:
        import cupy

        out = []
        for k in range(cupy.cuda.runtime.getDeviceCount()):
            p = cupy.cuda.runtime.getDeviceProperties(k)
            name = p["name"].decode() if isinstance(p["name"], bytes) else str(p["name"])
            out.append({"index": k, "name": name,
                        "memory_gib": round(p["totalGlobalMem"] / 2**30, 1),
                        "compute_capability": f"{p['major']}.{p['minor']}"})
        return out
    except Exception:  # noqa: BLE001 - no GPU, no driver, no cupy
        return []


def collect_info() -> dict:
    """Everything ``geodem info`` prints, as a dict."""
    from geodem.backends import ALLOWED, BACKENDS, _load_all
    from geodem.bench import available_memory

    _load_all()
    backends = {}
    for name, cls in BACKENDS.items():
        ok = bool(cls.is_available())
        backends[name] = {"available": ok, "why_not": "" if ok else cls.why_not()}
    try:
        auto = _resolve_backend(None)
        default_err = ""
    except Exception as exc:  # noqa: BLE001
        auto, default_err = None, str(exc)
    try:
        affinity = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        affinity = None
    mem = available_memory()
    info = {
        "versions": {
            "geodem": __version__,
            "python": platform.python_version(),
            "numpy": _version_of("numpy"),
            "numba": _version_of("numba"),
            "scipy": _version_of("scipy"),
            "h5py": _version_of("h5py"),
            "typer": _version_of("typer"),
            "rich": _version_of("rich"),
        },
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": affinity,
        "memory_available_gib": None if mem is None else round(mem / 2**30, 1),
        "numba_threads": threads.numba_threads(),
        "numba_threading_layer": threads.describe(),
        "backends": backends,
        "allowed_backends": list(ALLOWED),
        "env_backend": os.environ.get(ENV_BACKEND),
        "default_backend": auto,
        "default_backend_error": default_err,
        "gpus": _gpu_info() if backends.get("cupy", {}).get("available") else [],
    }
    return info


@app.command()
@_guard
def info(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
):
    """Versions, CPU and threads, and which backends work on this machine (and why not)."""
    data = collect_info()
    if as_json:
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
        return
    con = _out()
    t = Table(title="geodem", show_header=False, title_justify="left")
    t.add_column("item", style="bold")
    t.add_column("value")
    for k, v in data["versions"].items():
        t.add_row(k, v)
    t.add_row("platform", data["platform"])
    t.add_row("cpu", data["cpu"])
    t.add_row("cpu count", f"{data['cpu_count']} (usable: {data['cpus_usable']})")
    if data["memory_available_gib"] is not None:
        t.add_row("memory available", f"{data['memory_available_gib']} GiB")
    layer = data["numba_threading_layer"]
    t.add_row("numba threads", f"{data['numba_threads']} (NUMBA_NUM_THREADS)")
    t.add_row("threading layer", f"{layer['layer']} (chosen by {layer['chosen_by']})")
    if "wait" in layer:
        t.add_row("OpenMP waiting", f"{layer['wait']['setting']} (chosen by "
                                    f"{layer['wait']['chosen_by']})")
    con.print(t)

    b = Table(title="backends", title_justify="left")
    b.add_column("backend", style="bold")
    b.add_column("usable")
    b.add_column("note")
    for name, row in data["backends"].items():
        b.add_row(name, "[green]yes[/]" if row["available"] else "[red]no[/]",
                  escape(row["why_not"]))
    con.print(b)
    env = data["env_backend"]
    src = f"{ENV_BACKEND}={env}" if env else "auto"
    if data["default_backend"]:
        con.print(f"default backend: [bold]{data['default_backend']}[/] (from {src}; "
                  f"override with --backend or {ENV_BACKEND})", highlight=False)
    else:
        con.print(f"default backend: [red]none[/] ({data['default_backend_error']})",
                  highlight=False)
    for g in data["gpus"]:
        con.print(f"GPU {g['index']}: {g['name']}, {g['memory_gib']} GiB, compute capability "
                  f"{g['compute_capability']}", highlight=False)


@app.command("library")
@_guard
def library_cmd(
    dim: Annotated[Optional[int], typer.Option(
        "--dim", min=2, max=3, help="Only this dimension (default: both).")] = None,
    markdown: Annotated[bool, typer.Option(
        "--markdown", help="Print markdown tables (as docs/calibration.md quotes them).")] = False,
):
    """The material library: each material's lab values and its stored calibrations (2-D and
    3-D), each measured value with its error against the lab value, the UCS fit, the
    iterations, the Brazilian check (strength / Tu) and when and how long it ran."""
    from geodem.materials_library import (CALIBRATION_COLUMNS, calibration_cells,
                                          calibration_markdown, calibration_rows)

    con = _out()
    for d in ([dim] if dim else [2, 3]):
        if markdown:
            sys.stdout.write(f"{d}-D:\n\n{calibration_markdown(d)}\n")
            continue
        t = Table(title=f"{d}-D calibrations (geodem calibrate NAME --dim {d} --save)",
                  title_justify="left")
        for col in CALIBRATION_COLUMNS:
            t.add_column(col)
        for r in calibration_rows(d):
            t.add_row(*(escape(c) for c in calibration_cells(r)))
        con.print(t)


# ----------------------------------------------------------------------------- bench
@app.command()
@_guard
def bench(
    sizes: Annotated[Optional[str], typer.Option(
        "--sizes", callback=_parse_sizes, metavar="N[,N...]",
        help="Comma-separated model sizes (elements), integers >= 100. "
             "\\[default: 10000,100000,1000000]")] = None,
    backends: Annotated[Optional[str], typer.Option(
        "--backends", callback=_parse_backends, metavar="NAME[,NAME...]",
        help="Comma-separated backends (auto, numba, numpy, cupy). \\[default: every usable one; "
             "numpy only up to --numpy-max elements]")] = None,
    steps: Annotated[Optional[int], typer.Option(
        "--steps", min=1,
        help="Timed steps per run. \\[default: about 3 s worth, at least 100]")] = None,
    dim: Annotated[int, typer.Option("--dim", min=2, max=3, help="Dimension (2 or 3).")] = 3,
    numpy_max: Annotated[int, typer.Option(
        "--numpy-max", min=1, help="Largest size the slow NumPy reference is run at.")] = 100_000,
    repeat: Annotated[int, typer.Option(
        "--repeat", min=1, max=100,
        help="Runs per size and backend, each on a fresh copy: the figures are then the "
             "median run's, with every run's and the best in the JSON (for a shared or noisy "
             "machine).")] = 1,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print only a JSON list of records on stdout (progress goes to stderr).")]
        = False,
):
    """Time full steps of bonded specimens: element-steps/s and bytes per element per backend."""
    from geodem.bench import DEFAULT_SIZES, run_bench

    err = _err()

    def progress(msg):
        err.print(msg, highlight=False, markup=False)

    records = run_bench(sizes=sizes or DEFAULT_SIZES, backends=backends, steps=steps, dim=dim,
                        progress=progress, numpy_max=numpy_max, repeat=repeat)
    if not records:
        # every size was skipped (memory, or the numpy limit): nothing was measured
        _fail("no run was made (see the messages above): choose --sizes this machine can "
              "hold, or raise --numpy-max", USER_ERROR)
    if as_json:
        sys.stdout.write(json.dumps(records, indent=2) + "\n")
        return
    con = _out()
    if not con.is_terminal:  # piped or captured: do not squeeze the table into 80 columns
        con = Console(width=120)
    t = Table(title=f"geodem bench ({dim}-D bonded specimen; {_cpu_model()}, "
                    f"{os.cpu_count()} cpus)", title_justify="left")
    cols = ["backend", "n", "el-steps/s", "kernels", "B/el", "contacts", "steps", "wall s",
            "threads", "rebuilds"]
    if repeat > 1:
        cols[2:4] = ["el-steps/s (best)", "kernels (best)"]
    for col in cols:
        t.add_column(col, justify="left" if col == "backend" else "right", no_wrap=True)

    def speeds(r, key):
        if repeat == 1 or f"{key}_runs" not in r:
            return f"{r[key]:.3g}"
        return f"{r[key]:.3g} ({r[f'{key}_best']:.3g})"

    for r in records:
        t.add_row(r["backend"], f"{r['n']:,}", speeds(r, "element_steps_per_s"),
                  speeds(r, "kernel_element_steps_per_s"),
                  f"{r['bytes_per_element']:.0f}", f"{r['contacts_per_element']:.1f}",
                  str(r["steps"]), f"{r['wall_s']:.2f}",
                  "-" if r["threads"] is None else str(r["threads"]),
                  "-" if r["rebuilds"] is None else str(r["rebuilds"]))
    con.print(t)
    con.print("el-steps/s: element-steps per second of Simulation.run (checks and neighbour "
              "rebuilds included); kernels: the bare move + force step; B/el: bytes per "
              "element (state and the backend's buffers); contacts: mean row entries per element"
              + (f"; with --repeat: the median of {repeat} runs, the best in brackets (every "
                 "run in --json)" if repeat > 1 else ""),
              highlight=False)


# ----------------------------------------------------------------------------- workflows
def _parse_sets(values: Optional[list]) -> list:
    return list(values or [])


@app.command("run", help=(
    "Run a workflow (YAML) into a run directory.\n\n"
    "Validates FILE.yaml, builds the model and runs its steps; writes summary.json, output.h5, "
    "log.txt, manifest.json, config.resolved.yaml and checkpoints/ into -o DIR.\n\n"
    "Exit status: 0 done (or stopped by --stop-after-steps), 1 run-time failure (instability, "
    "I/O), 2 invalid input, 128+N stopped by signal N (SIGINT 130, SIGTERM 143) after a "
    "checkpoint."))
@_guard
def run_workflow_cmd(
    file: Annotated[str, typer.Argument(metavar="FILE.yaml", help="Workflow file.")],
    out: Annotated[Optional[str], typer.Option(
        "-o", "--out", help="Run directory (created; required unless --dry-run).")] = None,
    backend: Annotated[Optional[str], typer.Option(
        "--backend", callback=_parse_backend,
        help="auto, numba, numpy or cupy. \\[default: the workflow's backend, else "
             "$GEODEM_BACKEND, else auto]")] = None,
    sets: Annotated[Optional[list[str]], typer.Option(
        "--set", metavar="KEY=VALUE",
        help="Override a value, e.g. --set model.counts=[20,20,20] --set steps.0.nsteps=1e4 "
             "(repeatable; VALUE is YAML).")] = None,
    dry_run: Annotated[bool, typer.Option(
        "--dry-run", help="Validate and build the model, print sizes and estimates; no "
                          "stepping, nothing written.")] = False,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue the run in -o DIR from its newest checkpoint (refused if "
                         "the workflow changed).")] = False,
    stop_after_steps: Annotated[Optional[int], typer.Option(
        "--stop-after-steps", min=1, metavar="N",
        help="Stop cleanly, as if interrupted, once the model has made N time steps in total "
             "(checkpoint written, status 'interrupted', exit 0).")] = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="Replace the run in an existing run directory.")] = False,
    no_progress: Annotated[bool, typer.Option(
        "--no-progress", help="No progress bar and no build progress (progress lines go to "
                              "log.txt).")] = False,
    verbose: Annotated[bool, typer.Option("-v", "--verbose",
                                          help="Show full tracebacks on errors.")] = False,
):
    """Run a workflow (YAML) into a run directory.

    Validates FILE.yaml, builds the model and runs its steps; writes summary.json, output.h5,
    log.txt, manifest.json, config.resolved.yaml and checkpoints/ into -o DIR.

    Exit status: 0 done (or stopped by --stop-after-steps), 1 run-time failure (instability,
    I/O), 2 invalid input, 128+N stopped by signal N (SIGINT 130, SIGTERM 143) after a checkpoint.
    """
    if verbose:
        _OPTS["verbose"] = True
    from geodem.workflow.runner import Runner, dry_run_report, prepare

    if out is None and not dry_run:
        _fail("option -o/--out (the run directory) is required unless --dry-run", USER_ERROR)
    err = _err()
    # the run directory is checked before the model is built (a bad -o fails at once)
    prep = prepare(file, sets=_parse_sets(sets), backend=backend,
                   run_dir=None if dry_run else out, overwrite=overwrite, resume=resume,
                   progress=None if no_progress else _build_progress(err))
    con = _out()
    if dry_run:
        for line in dry_run_report(prep):
            con.print(escape(line), highlight=False, soft_wrap=True)
        return
    runner = Runner(prep, out, resume=resume, overwrite=overwrite,
                    stop_after_steps=stop_after_steps,
                    progress=False if no_progress else err.is_terminal, console=err,
                    verbose=_OPTS["verbose"])
    code, summary = runner.run()
    _print_run_summary(con, summary, out)
    if code:
        raise typer.Exit(code)


def _build_progress(err: Console):
    """The model build's progress lines (geodem.workflow.runner.prepare), on ``err`` when it
    is a terminal, each with the seconds since the build started; None (silent) otherwise."""
    import time

    if not err.is_terminal:
        return None
    t0 = time.perf_counter()

    def show(text: str) -> None:
        err.print(f"[{time.perf_counter() - t0:6.1f} s] {escape(text)}", style="dim",
                  highlight=False, soft_wrap=True)

    return show


def _frames_drawn(err: Console):
    """``progress(i, n)`` of an animation's pictures, on one line of ``err`` when it is a
    terminal; None (silent) otherwise."""
    if not err.is_terminal:
        return None

    def tick(i: int, n: int) -> None:
        err.print(f"drawn {i} of {n} frames", end="\r" if i < n else "\n", highlight=False)

    return tick


def _print_run_summary(con, s: dict, out: str) -> None:
    if not con.is_terminal:
        con = Console(width=120)
    t = Table(title=f"{s.get('workflow', '')}: {s['status']}", title_justify="left",
              show_header=False)
    t.add_column("key", style="bold")
    t.add_column("value", justify="right")
    rows = [("time steps", f"{s['steps']:,}"), ("simulated time [s]", f"{s['sim_time']:.6g}"),
            ("elements", f"{s['n_elements']:,}"), ("wall time [s]", f"{s['wall_time_s']:.3g}"),
            ("element-steps/s", f"{s['element_steps_per_s']:.3g}"),
            ("energy closure error", f"{s['energy_closure_rel_error']:.2e}")]
    for key in ("period_rel_error", "decay_rel_error"):
        if key in s:
            v = s[key]
            rows.append((key.replace("_", " "),
                         f"{v:.2e}" if isinstance(v, (int, float)) else str(v)))
    for k, v in rows:
        t.add_row(escape(k), escape(v))
    con.print(t)
    if s.get("error"):
        con.print(f"error: {escape(s['error'])}", highlight=False)
    for w in s.get("warnings") or []:
        con.print(f"warning: {escape(str(w))}", highlight=False)
    for name, note in (s.get("plots") or {}).items():
        if note != name:
            con.print(f"{escape(name)}: {escape(note)}", highlight=False)
    if s.get("vtk", "").startswith("skipped"):
        con.print(f"vtk: {escape(s['vtk'])}", highlight=False)
    con.print(f"wrote {escape(', '.join(s.get('files', [])))} to {escape(out)}", highlight=False)


def _fresh_out_dir(out: str, overwrite: bool):
    """``-o DIR`` as a Path; refused (exit 2) when it holds files and ``--overwrite`` is off."""
    from pathlib import Path

    o = Path(out)
    if o.exists() and any(o.iterdir()) and not overwrite:
        _fail(f"{out} exists and is not empty; choose another -o or add --overwrite",
              USER_ERROR)
    return o


ResumeRunsOpt = Annotated[bool, typer.Option("--resume", help=(
    "Go on with an interrupted -o DIR: its runs that ended ok with the same workflow (and "
    "the packings of 'geodem rock' finished with the same inputs) are reused, an interrupted "
    "run goes on from its last checkpoint, the rest runs."))]
MaterialArg = Annotated[str, typer.Argument(
    metavar="MATERIAL", help="Library name (e.g. granite) or path of a material file.")]
OutDirOpt = Annotated[str, typer.Option("-o", "--out", help="Output directory (created).")]
def _float_option(flag: str, lo: float, hi: float, text: str):
    """An optional float option ``flag`` in ``[lo, hi]`` (None when not given)."""
    return Annotated[Optional[float], typer.Option(flag, min=lo, max=hi, help=text)]


BondGapOpt = _float_option(
    "--bond-gap", 1e-4, 0.3, "Bond range (isotropic packing): pairs whose surface gap is below "
                             "this x d_mean are bonded (default 0.01; in 2-D a larger range "
                             "lowers Cu / Tu).")
BondWeibullOpt = _float_option(
    "--bond-weibull", 0.5, 100, "Weibull modulus of the per-bond strength scatter (default: "
                                "none, or as stored).")
BondMomentOpt = _float_option(
    "--bond-moment", 0.0, 100, "Turning elements with moment-resisting bonds: a bond holds a "
                               "rolling moment up to this x R* F_b (switches rotation on; "
                               "docs/calibration.md, 'Rotation and moment-resisting bonds').")
RollingFrictionOpt = _float_option(
    "--rolling-friction", 0.0, 2.0, "Turning elements with rolling resistance mu_r of "
                                    "contacts in compression (switches rotation on).")
RollingStiffnessOpt = _float_option(
    "--rolling-stiffness", 0.0, 16.0, "Turning elements whose rolling spring is this factor "
                                      "beta x Ks R*^2 (default 1; switches rotation on; "
                                      "raises Cu / Tu).")
DiscDiameterOpt = _float_option(
    "--disc-diameter", 0.01, 10.0, "Diameter of the Brazilian check disc [m] (default 40 "
                                   "d_mean in 2-D, 10 in 3-D, or as stored).")
DiscThicknessOpt = _float_option(
    "--disc-thickness", 0.001, 10.0, "3-D: thickness of the Brazilian check disc [m] "
                                     "(default half its diameter, or as stored).")
DiscDropOpt = _float_option(
    "--disc-drop", 0.5, 0.99, "The Brazilian check stops when the load falls below this x "
                              "its peak with a crack near the centre (default 0.9 for "
                              "turning elements, else 0.8, or as stored).")


JobsOpt = Annotated[Optional[int], typer.Option(
    "--jobs", min=1, max=64, help="With --packings: processes that measure the packings side "
                                  "by side, one numba thread each (default: one per numba "
                                  "thread; 1: one after another). The results do not depend "
                                  "on it.")]
FitOpt = Annotated[Optional[str], typer.Option(
    "--fit", help="How the UCS test fits E and nu: 'elastic' (default: the part of "
                  "10-50 % of the peak below the crack-initiation stress; "
                  "docs/calibration.md, 'Elastic constants before the cracks') or 'window' "
                  "(all of 10-50 % of the peak, cracks and all).")]


def _rotation_structure(bond_moment, rolling_friction, rolling_stiffness=None,
                        stored: dict | None = None) -> dict:
    """The rotation keys of a micro-structure from --bond-moment / --rolling-friction /
    --rolling-stiffness (empty when none is given). A key not given keeps its ``stored``
    value where the stored micro-structure turns, else its default (0, 0, 1)."""
    given = {"bond_moment": bond_moment, "rolling_friction": rolling_friction,
             "rolling_stiffness": rolling_stiffness}
    if all(v is None for v in given.values()):
        return {}
    base = {"bond_moment": 0.0, "rolling_friction": 0.0, "rolling_stiffness": 1.0}
    if stored and stored.get("rotation"):
        base.update({k: stored[k] for k in base if stored.get(k) is not None})
    return {"rotation": True, **{k: base[k] if v is None else v for k, v in given.items()}}


DISC_KEYS = ("disc_diameter", "disc_drop", "disc_thickness")


def _stored_rate(specimen: dict) -> dict:
    """The UCS loading rate a stored record was calibrated at (its specimen's
    ``strain_rate``), as a :class:`CalibrationSpec` keyword: a check of the record loads as
    its calibration did."""
    rate = specimen.get("strain_rate")
    return {} if rate is None else {"strain_rate": float(rate)}


def _disc_options(diameter, drop, stored: dict | None = None, thickness=None) -> dict:
    """The Brazilian check's ``disc_diameter``, ``disc_drop`` and ``disc_thickness`` for a
    CalibrationSpec: the options given, else the stored specimen's, else the spec's defaults
    (absent). A diameter given without a thickness takes the default thickness."""
    out = {}
    if diameter is not None and thickness is None:
        stored = {k: v for k, v in (stored or {}).items() if k != "disc_thickness"}
    for key, value in zip(DISC_KEYS, (diameter, drop, thickness)):
        if value is None and stored:
            value = stored.get(key)
        if value is not None:
            out[key] = float(value)
    return out


def _phi_text(rec) -> str:
    """The friction angle of a calibration iteration, as the progress line prints it."""
    if "phi_abs_error" not in rec:
        return ""
    phi, mu = rec["measured"].get("phi"), rec["element"]["mu"]
    if phi is None:
        return f", phi not measured yet (mu {mu:.3g})"
    if not math.isfinite(phi):
        return f", phi: no confined peak (mu {mu:.3g})"
    return f", phi {phi:.1f} deg ({rec['phi_abs_error']:+.1f}, mu {mu:.3g})"


def _stored_recipe(mat, dim, *options):
    """The stored ``calibrated.<dim>d`` record's recipe ``(structure, friction, packings,
    disc options)`` when the material has one and none of the recipe ``options`` (packing,
    bond gap, Weibull modulus, bond moment, rolling friction, rolling stiffness, friction,
    packings) is given: ``geodem calibrate NAME`` repeats the library's calibration. Else
    None."""
    from geodem.materials import STRUCTURE_KEYS

    rec = (mat.calibrated or {}).get(f"{dim}d") or {}
    sp = rec.get("specimen")
    if not sp or any(v is not None for v in options):
        return None
    structure = {k: sp[k] for k in STRUCTURE_KEYS if sp.get(k) is not None}
    structure.setdefault("packing", "isotropic")
    disc = {k: float(sp[k]) for k in DISC_KEYS if sp.get(k) is not None}
    return structure, sp.get("friction_test") is not None, int(sp.get("packings", 1)), disc


def _run_time_text(rec) -> str:
    """`` (N s of runs side by side)`` where the iteration's runs, summed, took longer than
    the iteration (--jobs above 1), else nothing."""
    run = rec.get("run_time_s")
    return f" ({run:.0f} s of runs side by side)" if run and run > 1.05 * rec["wall_time_s"] \
        else ""


def _recipe_text(spec) -> str:
    """A calibration's recipe in words (the stored-recipe line of ``geodem calibrate``)."""
    st = spec.structure
    elements = ("turning elements (bond moment {:g}, rolling stiffness {:g})".format(
        st.get("bond_moment", 0.0), st.get("rolling_stiffness", 1.0)) if st.get("rotation")
        else "translating elements")
    return (f"{st.get('packing', 'isotropic')} packing, {elements}, "
            f"{'with' if spec.friction else 'without'} the friction angle, "
            f"{spec.packings} packing{'s' if spec.packings != 1 else ''}, check disc "
            f"{spec.disc_diameter:g} m")


@app.command("calibrate", help=(
    "Calibrate a library material: find element parameters whose virtual UCS and direct "
    "tension tests give its E, nu, UCS (Cu) and tensile strength (Tu) (with --friction also "
    "the friction angle atan(mu_i), from a triaxial test); the Brazilian disc is run once "
    "with the result as a check.\n\n"
    "Each iteration builds the same specimen, runs the UCS and direct-tension workflows on it "
    "(and with --friction, once those four are close, a two-stage triaxial test at sigma3 = "
    "0 and 0.133 Cu), kept under DIR/iterations/NN/, and takes a step with the model's "
    "exact scalings. Writes "
    "summary.json (targets, measured, rel_errors, iterations, wall_time_s), history.csv, "
    "calibrated.yaml and convergence.png into -o DIR; --save also stores the result in the "
    "material file's 'calibrated' block.\n\n"
    "A material with a stored calibration for --dim is calibrated again with that one's "
    "recipe (micro-structure, --friction, --packings, check disc) unless a recipe option is "
    "given: 'geodem calibrate sandstone' repeats the library's.\n\n"
    "Exit status: 0 converged (or the unreachable targets reported), 1 not converged or a run "
    "failed, 2 invalid input."))
@_guard
def calibrate_cmd(
    material: MaterialArg,
    out: OutDirOpt,
    dim: Annotated[int, typer.Option("--dim", min=2, max=3, help="Dimension of the "
                                                                 "specimens.")] = 2,
    iterations: Annotated[int, typer.Option("--iterations", min=1, max=20,
                                            help="Largest number of iterations.")] = 8,
    d_mean: Annotated[Optional[float], typer.Option(
        "--d-mean", min=1e-6, help="Element diameter of the specimens [m] (default 0.005 in "
                                   "2-D, 0.01 in 3-D: about 800 and 2,200 elements).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Packing seed.")] = 0,
    prefer: Annotated[str, typer.Option("--prefer", help="Strength matched when the packing "
                                                         "cannot reach Cu / Tu: Cu or Tu.")] =
    "Cu",
    save: Annotated[bool, typer.Option("--save", help="Write the result into the material "
                                                      "file's 'calibrated' block.")] = False,
    packing: Annotated[Optional[str], typer.Option(
        "--packing", help="Specimen packing recipe, stored with the result: isotropic "
                          "(default) or deposit (2-D only).")] = None,
    bond_gap: BondGapOpt = None,
    bond_weibull: BondWeibullOpt = None,
    bond_moment: BondMomentOpt = None,
    rolling_friction: RollingFrictionOpt = None,
    rolling_stiffness: RollingStiffnessOpt = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace the contents of an "
                                                                "existing -o DIR.")] = False,
    resume: ResumeRunsOpt = False,
    force: Annotated[bool, typer.Option("--force", help="Calibrate even when the targets lie "
                                                        "outside the charted reachable "
                                                        "region (then E, nu and --prefer "
                                                        "are matched).")] = False,
    friction: Annotated[Optional[bool], typer.Option(
        "--friction/--no-friction", help="Also match the friction angle atan(mu_i) by the "
                                         "contact friction, with a two-stage triaxial test "
                                         "per iteration (without it mu stays at the lattice "
                                         "value from mu_i; docs/calibration.md, 'Friction "
                                         "angle').", show_default=False)] = None,
    packings: Annotated[Optional[int], typer.Option(
        "--packings", min=1, max=10, help="Measure every iteration on this many packings "
                                          "(seeds SEED, SEED+1, ...) and match their mean "
                                          "(that many times the cost; default 1).")] = None,
    jobs: JobsOpt = None,
    fit: FitOpt = None,
    disc_diameter: DiscDiameterOpt = None,
    disc_thickness: DiscThicknessOpt = None,
    disc_drop: DiscDropOpt = None,
    recipe: Annotated[Optional[str], typer.Option(
        "--recipe", help="'library': the library's recipe for this rock (2-D: turning "
                         "elements, bond moment 100, the rolling stiffness by its friction "
                         "angle, the friction angle matched on three packings; 3-D: turning "
                         "elements at rolling stiffness 4 for a friction angle of 37-44 deg, at "
                         "8 for 33-52 deg at nu <= 0.25, else translating ones), for a rock "
                         "of your own; the other recipe "
                         "options then change it (docs/calibration.md).")] = None,
    start: Annotated[Optional[str], typer.Option(
        "--start", help="Start from the element parameters (kn_per_d, ks_per_d, xb_per_d, "
                        "fs0_per_d2, mu) of this YAML file: an earlier run's calibrated.yaml "
                        "or a material file with a --dim record (edit mu there to start the "
                        "friction elsewhere); 'prior': the prior rates (lattice conversion); "
                        "default: the step from the nearest calibrated library rock of the same "
                        "recipe (never the rock's own record), else (and for 3-D turning "
                        "elements) the prior rates.")] = None,
    check: Annotated[bool, typer.Option(
        "--check/--no-check", help="Run the Brazilian check on the result (default); "
                                   "--no-check leaves it to 'geodem rock MATERIAL --dim D "
                                   "--save' (in 3-D a disc that splits at Tu, 60 d_mean "
                                   "across, takes about half an hour per packing on one "
                                   "core).")] = True,
    backend: Annotated[Optional[str], typer.Option(
        "--backend", callback=_parse_backend, help="auto, numba, numpy or cupy.")] = None,
):

    from geodem.studies.calibrate import (CalibrationSpec, UnreachableTarget, calibrate,
                                          check_reachable, library_friction_left_out,
                                          library_recipe, library_start,
                                          library_turning_left_out, runs_told,
                                          save_calibration)
    from geodem.materials_library import load_material, material_path

    if prefer not in ("Cu", "Tu"):
        _fail(f"--prefer {prefer!r}: allowed: Cu or Tu", USER_ERROR)
    if recipe not in (None, "library"):
        _fail(f"--recipe {recipe!r}: allowed: library", USER_ERROR)
    _check_fit(fit)
    mat = load_material(material)
    path = material_path(material)
    first = _start_element(start, dim) if start and start != "prior" else None
    from pathlib import Path

    o = Path(out) if resume else _fresh_out_dir(out, overwrite)
    if dim == 3:
        size = (0.1, 0.1, 0.2)
    else:
        size = (0.1, 0.2)
    if d_mean is None:
        d_mean = 0.01 if dim == 3 else 0.005
    if min(size) < 4 * d_mean:
        _fail(f"--d-mean {d_mean:g} m: allowed up to {min(size) / 4:g} m (the specimens are "
              f"{min(size):g} m across and need at least 4 elements)", USER_ERROR)
    stored = None if recipe else _stored_recipe(mat, dim, packing, bond_gap, bond_weibull,
                                                bond_moment, rolling_friction,
                                                rolling_stiffness, friction, packings)
    if recipe == "library":
        structure, lib_friction, lib_packings = library_recipe(dim, mat.values())
        given = _rotation_structure(bond_moment, rolling_friction, rolling_stiffness,
                                    stored=structure)
        structure = {**structure, **given, "packing": packing or structure["packing"],
                     "bond_gap": bond_gap, "bond_strength_weibull": bond_weibull}
        friction = lib_friction if friction is None else bool(friction)
        packings, disc = packings or lib_packings, {}
    elif stored is not None:
        structure, friction, packings, disc = stored
    else:
        structure = {"packing": packing or "isotropic", "bond_gap": bond_gap,
                     "bond_strength_weibull": bond_weibull,
                     **_rotation_structure(bond_moment, rolling_friction, rolling_stiffness)}
        friction, packings, disc = bool(friction), packings or 1, {}
    disc.update(_disc_options(disc_diameter, disc_drop, thickness=disc_thickness))
    try:
        spec = CalibrationSpec(targets=mat.values(), name=mat.name, dim=dim, d_mean=d_mean,
                               ucs_size=size, seed=seed, iterations=iterations,
                               backend=backend, prefer=prefer, structure=structure,
                               check_reach=not force, friction=friction,
                               packings=packings, fit=fit or "elastic", jobs=jobs,
                               resume=resume, check=check, **disc)
    except ValueError as exc:
        _fail(f"--packing / --bond-gap / --bond-weibull / --bond-moment: {exc}", USER_ERROR)
    if not force:
        try:
            check_reachable(spec)
        except UnreachableTarget as exc:
            _fail(f"{path}: {exc}", USER_ERROR)
    con = _out()
    con.print(f"calibrating {mat.name} ({dim}-D specimens, d = {d_mean:g} m) -> {out}",
              highlight=False)
    if recipe == "library":
        con.print(f"the library's {dim}-D recipe: {_recipe_text(spec)}", highlight=False)
        translating = library_turning_left_out(mat.values()) if dim == 3 else None
        if translating and not spec.structure.get("rotation"):
            con.print(f"translating elements: {translating}", highlight=False)
        left_out = library_friction_left_out(mat.values()) if dim == 3 and not friction \
            else None
        if left_out:
            con.print(f"the friction angle is not matched: {left_out}", highlight=False)
    elif stored is not None:
        con.print(f"the stored {dim}-D calibration's recipe: {_recipe_text(spec)} (give "
                  "--packing, --bond-*, --rolling-*, --friction/--no-friction or --packings "
                  "to choose another)", highlight=False)

    def report(i, rec):
        m, e = rec["measured"], rec["rel_errors"]
        con.print(f"iteration {i}: E {m['E']:.4g} Pa ({e['E']:+.1%}), nu {m['nu']:.3f} "
                  f"({rec['nu_abs_error']:+.3f}), Cu {m['Cu']:.4g} Pa ({e['Cu']:+.1%}), "
                  f"Tu {m['Tu']:.4g} Pa ({e['Tu']:+.1%}){_phi_text(rec)}; "
                  f"{rec['wall_time_s']:.0f} s{_run_time_text(rec)}", highlight=False)

    start_from = None  # calibrate() names a given start and the prior's itself
    if start is None:
        found = library_start(spec)
        if found:
            first, start_from = found[0], f"library {found[1]}"
            con.print(f"starting from the library's {found[1]} ({dim}-D record, the nearest "
                      "of the same recipe; --start prior for the prior rates)", highlight=False)
    with runs_told(), _interrupted_runs():
        summary = calibrate(spec, o, progress=report, start=first, start_from=start_from)
    b = summary["brazilian"]
    if b is None:
        con.print(f"check: not run (--no-check); 'geodem rock {material} --dim {dim} --packings "
                  f"{spec.packings} --save -o DIR' runs it on the saved calibration",
                  highlight=False)
    else:
        off = b["crack_start_offset"]
        con.print(f"check: Brazilian disc {b['tensile_strength']:.4g} Pa = "
                  f"{b['over_target']:.3g} x Tu (first cracks at "
                  f"{off if off is not None else math.nan:.2f} R from the centre); "
                  f"{b['wall_time_s']:.0f} s", highlight=False)
    con.print(f"best iteration {summary['best_iteration']} of {summary['iterations']}; "
              f"{'converged' if summary['converged'] else 'NOT converged'}; wall time "
              f"{summary['wall_time_s']:.0f} s", highlight=False)
    for note in summary["notes"]:
        con.print(f"note: {note}", highlight=False)
    if save:
        save_calibration(path, summary)
        con.print(f"saved the {dim}-D calibration into {path}", highlight=False)
    if not summary["converged"]:
        raise typer.Exit(FAILURE)


def _start_element(path: str, dim: int) -> dict:
    """The element parameters to start a calibration from: ``<dim>d.element`` of a
    calibrated.yaml or ``calibrated.<dim>d.element`` of a material file; exit 2 with the file
    and field when missing or not positive."""
    from pathlib import Path

    import yaml

    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        _fail(f"--start {path}: cannot read it: {exc}", USER_ERROR)
    key = f"{dim}d"
    rec = (doc or {}).get(key) or ((doc or {}).get("calibrated") or {}).get(key)
    if not isinstance(rec, dict) or not isinstance(rec.get("element"), dict):
        _fail(f"--start {path}: no '{key}.element' (calibrated.yaml) or "
              f"'calibrated.{key}.element' (material file) for --dim {dim}", USER_ERROR)
    el, values = rec["element"], {}
    for name in ("kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2", "mu"):
        v = el.get(name)
        try:  # YAML reads 1.0e11 (no sign in the exponent) as a string
            values[name] = float(v) if not isinstance(v, bool) else math.nan
        except (TypeError, ValueError):
            values[name] = math.nan
        if not values[name] > 0 or math.isinf(values[name]):
            _fail(f"{path}: field '{key}.element.{name}' = {v!r}: allowed: a number > 0",
                  USER_ERROR)
    return values


@app.command("rock", help=(
    "Measure the rock a material's calibrated element parameters make: run the calibration's "
    "UCS, direct-tension and Brazilian workflows once (specimens as geodem calibrate builds "
    "them) and print E, nu, Cu, Tu (direct tension), Cu / Tu and the Brazilian strength "
    "against the lab values; --friction also runs the calibration's two-stage triaxial test "
    "and prints the friction angle against atan(mu_i). --packing, --bond-gap, "
    "--bond-weibull, --bond-moment and --rolling-friction replace the stored "
    "micro-structure, to see what each does; --packings N measures on N packings and prints "
    "the scatter.\n\n"
    "Writes summary.json (measured, targets, element, structure; with --packings, each "
    "packing's and their mean and standard deviation) and the runs into -o DIR. Exit "
    "status: 0 done, 1 a run failed, 2 invalid input."))
@_guard
def rock_cmd(
    material: MaterialArg,
    out: OutDirOpt,
    dim: Annotated[int, typer.Option("--dim", min=2, max=3, help="Dimension.")] = 2,
    packing: Annotated[Optional[str], typer.Option(
        "--packing", help="Packing recipe: isotropic or deposit (2-D only).")] = None,
    bond_gap: BondGapOpt = None,
    bond_weibull: BondWeibullOpt = None,
    bond_moment: BondMomentOpt = None,
    rolling_friction: RollingFrictionOpt = None,
    rolling_stiffness: RollingStiffnessOpt = None,
    friction: Annotated[bool, typer.Option("--friction", help="Also run the triaxial friction "
                                                              "test (two stages).")] = False,
    packings: Annotated[int, typer.Option("--packings", min=1, max=20, help=(
        "Measure on this many packings (seeds SEED, SEED+1, ...) and print each and their "
        "mean and standard deviation."))] = 1,
    seed: Annotated[Optional[int], typer.Option("--seed", min=0, help=(
        "Packing seed of the first specimen (default: the calibration's)."))] = None,
    jobs: JobsOpt = None,
    fit: FitOpt = None,
    disc_diameter: DiscDiameterOpt = None,
    disc_thickness: DiscThicknessOpt = None,
    disc_drop: DiscDropOpt = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace the contents of an "
                                                                "existing -o DIR.")] = False,
    save: Annotated[bool, typer.Option("--save", help=(
        "Store this Brazilian check (the mean over the packings, and its disc) in the "
        "material file's calibration record, in place of the calibration's own; only for "
        "the stored element parameters and micro-structure. With the calibration's packings "
        "it also stores each packing's E, nu, Cu and Tu, if their mean reproduces the "
        "record's."))] = False,
    resume: ResumeRunsOpt = False,
):
    import json

    from geodem.studies.calibrate import (CalibrationSpec, jobs_for, rock_packings,
                                          runs_told)
    from geodem.materials import STRUCTURE_KEYS
    from geodem.materials_library import load_material

    _check_fit(fit)
    mat = load_material(material)
    cal = (mat.calibrated or {}).get(f"{dim}d")
    if cal is None:
        _fail(f"{mat.name} has no {dim}-D calibration; run 'geodem calibrate {material} --dim "
              f"{dim} --save' first", USER_ERROR)
    overrides = [name for name, v in (("--packing", packing), ("--bond-gap", bond_gap),
                                      ("--bond-weibull", bond_weibull),
                                      ("--bond-moment", bond_moment),
                                      ("--rolling-friction", rolling_friction),
                                      ("--rolling-stiffness", rolling_stiffness),
                                      ("--fit", fit), ("--seed", seed)) if v is not None]
    if save and overrides:
        _fail(f"--save stores a check of the stored calibration: drop {', '.join(overrides)}",
              USER_ERROR)
    from pathlib import Path

    o = Path(out) if resume else _fresh_out_dir(out, overwrite)
    el = dict(cal["element"])
    for key, value in (("packing", packing), ("bond_gap", bond_gap),
                       ("bond_strength_weibull", bond_weibull)):
        if value is not None:
            el[key] = value
    if packing == "deposit" and bond_gap is None:
        el.pop("bond_gap", None)  # a bond range belongs to the isotropic recipe
    el.update(_rotation_structure(bond_moment, rolling_friction, rolling_stiffness, stored=el))
    sp = cal.get("specimen", {})
    size = tuple(sp.get("ucs_size") or ((0.1, 0.1, 0.2) if dim == 3 else (0.1, 0.2)))
    structure = {k: el[k] for k in STRUCTURE_KEYS if k in el}
    first = int(sp.get("seed", 0)) if seed is None else seed
    try:
        specs = [CalibrationSpec(targets=mat.values(), name=mat.name, dim=dim,
                                 d_mean=float(sp.get("d_mean", 0.01 if dim == 3 else 0.005)),
                                 ucs_size=size, seed=first + k, iterations=1,
                                 structure=structure, fit=fit or sp.get("fit", "window"),
                                 resume=resume, **_stored_rate(sp),
                                 **_disc_options(disc_diameter, disc_drop, sp,
                                                 disc_thickness))
                 for k in range(packings)]
    except ValueError as exc:
        _fail(f"--packing / --bond-gap / --bond-weibull / --bond-moment: {exc}", USER_ERROR)
    con = _out()
    con.print(f"measuring {mat.name} ({dim}-D, {structure}) -> {out}", highlight=False)
    folders = [o if packings == 1 else o / f"packing_{spec.seed}" for spec in specs]
    if resume:
        _refuse_another_check(o, mat.name, dim)
    with runs_told(), _interrupted_runs():
        runs = rock_packings(specs, el, folders, friction, jobs_for(packings, jobs))
    for spec, run in zip(specs, runs):
        prefix = "" if packings == 1 else f"seed {spec.seed}: "
        reused = " (finished before, reused)" if run.pop("resumed", False) else ""
        con.print(prefix + _rock_line(run) + reused, highlight=False)
    if packings > 1:
        spread = _rock_spread(runs)
        (o / "summary.json").write_text(json.dumps(
            {"material": mat.name, "dim": dim, "structure": structure, "element": el,
             "seeds": [r["seed"] for r in runs], "targets": runs[0]["targets"],
             "target_phi": runs[0].get("target_phi"), "mean": spread["mean"],
             "std": spread["std"], "packings": runs}, indent=2))
        con.print("mean +- std over the packings: " + ", ".join(
            f"{key} {spread['mean'][key]:.4g} +- {spread['std'][key]:.2g}"
            for key in spread["mean"]), highlight=False)
    if save:
        from geodem.materials_library import material_path
        from geodem.studies.calibrate import save_brazilian_check

        path = material_path(material)
        check = save_brazilian_check(path, dim, [r["brazilian"] for r in runs],
                                     specs[0].disc_diameter, specs[0].disc_drop,
                                     specs[0].disc_thickness)
        con.print(f"saved the Brazilian check ({check['over_target']:.3g} x Tu, disc "
                  f"{specs[0].disc_diameter:g} m) into {path}", highlight=False)
        if packings == int(sp.get("packings") or 1) > 1 and first == int(sp.get("seed", 0)):
            from geodem.studies.calibrate import save_packing_measurements

            miss = save_packing_measurements(path, dim, runs)
            con.print(f"each packing's E, nu, Cu and Tu not stored: {miss}" if miss else
                      f"saved each packing's E, nu, Cu and Tu (their mean reproduces the "
                      f"record's) into {path}", highlight=False)


def _refuse_another_check(o, name: str, dim: int) -> None:
    """``geodem rock --resume -o DIR`` where DIR holds another rock's or dimension's check:
    refused before anything runs (its runs would be overwritten)."""
    for f in [o / "summary.json", *sorted(o.glob("packing_*/summary.json"))]:
        try:
            old = json.loads(f.read_text())
        except (OSError, ValueError):
            continue
        meta = (old.get("inputs") or old) if isinstance(old, dict) else {}
        if "material" in meta and (meta.get("material"), meta.get("dim")) != (name, dim):
            _fail(f"{o} holds a check of {meta.get('material')} in {meta.get('dim')}-D ({f}); "
                  f"--resume goes on only with the same rock and dimension: choose another -o",
                  USER_ERROR)


@contextlib.contextmanager
def _interrupted_runs():
    """A calibration run stopped by a signal: say how to go on, exit 128 + the signal."""
    from geodem.studies.calibrate import RunInterrupted

    try:
        yield
    except RunInterrupted as exc:
        _fail(f"interrupted: {exc}", exc.code)


def _check_fit(fit) -> None:
    """Refuse an unknown --fit before anything is written (the CalibrationSpec would too, but
    after the output folder exists)."""
    from geodem.cases.uniaxial import FITS

    if fit is not None and fit not in FITS:
        _fail(f"--fit {fit!r}: allowed: {' or '.join(FITS)}", USER_ERROR)


def _rock_line(r: dict) -> str:
    """The line ``geodem rock`` prints for one packing: each value against the lab's."""
    m, t, b = r["measured"], r["targets"], r["brazilian"]["tensile_strength"]
    text = (f"E {m['E']:.4g} Pa ({m['E'] / t['E'] - 1:+.1%}), nu {m['nu']:.3f} "
            f"({m['nu'] - t['nu']:+.3f}), Cu {m['Cu']:.4g} Pa ({m['Cu'] / t['Cu'] - 1:+.1%}), "
            f"Tu {m['Tu']:.4g} Pa ({m['Tu'] / t['Tu'] - 1:+.1%}), Cu / Tu {r['ratio']:.3g} "
            f"(lab {r['target_ratio']:.3g}); Brazilian {b:.4g} Pa ({b / t['Tu'] - 1:+.1%})")
    other = "elastic" if r.get("fit", "window") == "window" else "window"
    o = r.get("fits", {}).get(other)
    if o:
        w = o["fit_window"]
        text += (f"; {other} fit ({100 * w[0]:.0f}-{100 * w[1]:.0f} % of the peak): "
                 f"E {o['E']:.4g} Pa, nu {o['nu']:.3f}")
    if "friction_test" in r:
        phi = r["friction_test"]["phi"]
        text += (f"; phi {phi:.1f} deg ({phi - r['target_phi']:+.1f})" if phi is not None
                 else "; phi: no confined peak")
    return text + f"; {r['wall_time_s']:.0f} s"


def _rock_spread(runs: list) -> dict:
    """Mean and sample standard deviation over the packings of E, nu, Cu, Tu, Cu / Tu, the
    Brazilian strength and (where every packing has one) phi."""
    import numpy as np

    cols = {k: [r["measured"][k] for r in runs] for k in ("E", "nu", "Cu", "Tu")}
    cols["Cu/Tu"] = [r["ratio"] for r in runs]
    cols["Brazilian"] = [r["brazilian"]["tensile_strength"] for r in runs]
    phis = [r.get("friction_test", {}).get("phi") for r in runs]
    if all(p is not None for p in phis):
        cols["phi"] = phis
    return {"mean": {k: float(np.mean(v)) for k, v in cols.items()},
            "std": {k: float(np.std(v, ddof=1)) for k, v in cols.items()}}

def _float_list(value: Optional[str], name: str, integer=False):
    if value is None:
        return None
    try:
        vals = [int(v) if integer else float(v) for v in value.split(",") if v.strip()]
    except ValueError:
        raise typer.BadParameter(f"{name}: comma-separated {'integers' if integer else 'numbers'}"
                                 f", got {value!r}") from None
    if not vals or any(v <= 0 for v in vals):
        raise typer.BadParameter(f"{name}: allowed values > 0, got {value!r}")
    return vals


@app.command("study", help=(
    "Speed against accuracy of a lab test over resolution and time-step fraction.\n\n"
    "KIND is 'ucs': runs WORKFLOW (default workflows/ucs.yaml) for every number of elements "
    "across the height (--across) and time-step fraction (--dt-fractions); writes study.json "
    "(wall time, E and UCS errors against the material's targets per point) and "
    "speed_accuracy.png into -o DIR, and names the fastest point within --tolerance.\n\n"
    "KIND 'stability': measures the critical time step of small lattice models (undamped "
    "velocity Verlet) against 2/omega_max and geodem's refusal bound, the critical sub-step of "
    "the pore-fluid and thermal fields against 2/lambda_max, and a balance's unbalanced force "
    "against its damping; writes stability.json and stability_*.png into -o DIR.\n\n"
    "KIND 'speed-accuracy': error against wall time of the "
    "cases with a reference (--cases; --quick: a tiny grid); docs/speed_accuracy.md.\n\n"
    "KIND 'graded': the landslide uniform and graded (model.coarsen factor 1, 2, 3) over "
    "three packing seeds; writes graded_study.json and graded_study.md; docs/graded.md.\n\n"
    "KIND 'reach': the (Cu / Tu, nu) a calibration can reach on the --dim packing: UCS and "
    "direct tension over a grid of ks / kn (--s) and bond shear / tensile strength (--rho); "
    "writes reach.json and reach.png; --save stores it as the chart geodem calibrate refuses "
    "targets by (docs/calibration.md, 'Reachable region').\n\n"
    "KIND 'friction': the triaxial workflow's friction angle with the library --material's "
    "2-D element parameters, one micro-parameter changed at a time (friction, bond range, "
    "strength scatter); writes friction.json and friction.md; docs/triaxial.md.\n\n"
    "KIND 'scale': build time, memory per element, element-steps/s, checkpoint and output time "
    "of 3-D models against their size (--sizes) for each family (--families: lattice, "
    "isotropic, granular, terrain, thermal, pore, pore_isotropic); writes scale.json, "
    "scale.csv and scale.png (log-log, with the linear cost) and flags a cost growing faster "
    "than N log N; docs/performance.md."))
@_guard
def study_cmd(
    kind: Annotated[str, typer.Argument(metavar="KIND", help="ucs, stability, "
                                                             "speed-accuracy, freeze, graded, "
                                                             "reach, friction or scale")],
    out: Annotated[str, typer.Option("-o", "--out", help="Output directory.")],
    workflow: Annotated[str, typer.Option("--workflow", help="UCS workflow file.")] =
    "workflows/ucs.yaml",
    across: Annotated[str, typer.Option("--across", help="Elements across the height, "
                                                         "comma-separated.")] = "10,15,20,30,40",
    fractions: Annotated[str, typer.Option("--dt-fractions", help="Time-step fractions, "
                                                                  "comma-separated.")] =
    "0.02,0.05,0.1",
    material: Annotated[str, typer.Option("--material", help="ucs: material name in the "
                                                             "workflow; friction: library "
                                                             "material (default sandstone)."
                                          )] = "rock",
    tolerance: Annotated[float, typer.Option("--tolerance", min=1e-6, max=1.0,
                                             help="Error bound for 'fastest within'.")] = 0.05,
    backend: Annotated[Optional[str], typer.Option(
        "--backend", callback=_parse_backend, help="auto, numba, numpy or cupy.")] = None,
    cases: Annotated[Optional[str], typer.Option("--cases", help="speed-accuracy: cases, "
                                                 "comma-separated, or all.")] = None,
    quick: Annotated[bool, typer.Option("--quick", help="speed-accuracy: tiny grid.")] = False,
    dim: Annotated[int, typer.Option("--dim", min=2, max=3, help="reach: dimension.")] = 2,
    s_values: Annotated[Optional[str], typer.Option(
        "--s", help="reach: ks / kn values, comma-separated.")] = None,
    rho_values: Annotated[Optional[str], typer.Option(
        "--rho", help="reach: bond shear / tensile strength ratios, comma-separated.")] = None,
    save: Annotated[bool, typer.Option("--save", help="reach: store the chart in the "
                                                      "package.")] = False,
    merge: Annotated[bool, typer.Option("--merge", help="reach: with --save, add the points "
                                        "to the stored chart (a point of the same ks / kn "
                                        "and rho_s is replaced) instead of replacing it.")]
    = False,
    sizes: Annotated[Optional[str], typer.Option(
        "--sizes", callback=_parse_sizes, help="scale: element counts, comma-separated "
        "\\[default: 1000,10000,100000,1000000]")] = None,
    families: Annotated[Optional[str], typer.Option(
        "--families", help="scale: model families, comma-separated (lattice, isotropic, "
                           "granular, terrain, thermal, pore, pore_isotropic) "
                           "\\[default: all]")] = None,
    max_build: Annotated[float, typer.Option(
        "--max-build", min=1.0, help="scale: seconds of build after which a family's larger "
                                     "sizes are skipped (their build time projected)")] = 600.0,
):
    from geodem.studies.study import ucs_study

    if kind == "reach":
        _reach(out, dim, s_values, rho_values, save, backend, merge)
        return
    if kind == "scale":
        _scale(out, sizes, families, max_build, backend)
        return
    if kind == "friction":
        from geodem.studies.friction import describe, friction_study

        con = _out()
        lib = "sandstone" if material == "rock" else material
        friction_study(_fresh_out_dir(out, overwrite=False), lib, backend=backend,
                       progress=lambda r: con.print(escape(describe(r)), highlight=False))
        con.print(f"wrote friction.json, friction.md to {out}", highlight=False)
        return

    if kind == "speed-accuracy":
        from geodem.studies.speed_accuracy import run_cli

        run_cli(out, cases, quick, backend, _out(), lambda msg: _fail(msg, USER_ERROR))
        return

    if kind == "freeze":
        from geodem.studies.freeze_study import describe, freeze_study

        con = _out()
        freeze_study(out, progress=lambda r: con.print(escape(describe(r)), highlight=False))
        con.print(f"wrote freeze_study.json, freeze_study.md to {out}", highlight=False)
        return

    if kind == "graded":
        from geodem.studies.freeze_study import describe_graded, graded_study

        con = _out()
        graded_study(out, progress=lambda r: con.print(escape(describe_graded(r)),
                                                          highlight=False))
        con.print(f"wrote graded_study.json, graded_study.md to {out}", highlight=False)
        return

    if kind == "stability":
        from geodem.studies.stability import describe, stability_study

        con = _out()
        res = stability_study(out, backend=backend or "numba",
                              progress=lambda k, r: con.print(escape(describe(k, r)),
                                                              highlight=False))
        con.print(f"wrote {', '.join(['stability.json'] + res['plots'])} to {out}",
                  highlight=False)
        return
    if kind != "ucs":
        _fail(f"study KIND {kind!r}: allowed: ucs, stability, speed-accuracy, freeze, graded, "
              "reach, friction, scale",
              USER_ERROR)
    n = _float_list(across, "--across", integer=True)
    f = _float_list(fractions, "--dt-fractions")
    if any(v > 0.2 for v in f):
        _fail("--dt-fractions: allowed 0 < fraction <= 0.2 (simulation.dt_fraction)", USER_ERROR)
    from pathlib import Path

    o = Path(out)
    if o.exists() and (not o.is_dir() or (any(o.iterdir()) and not (o / "study.json").exists())):
        _fail(f"-o {out}: exists and is not an empty folder or a previous UCS study (no "
              f"study.json); choose another -o", USER_ERROR)
    con = _out()

    def report(p):
        if "E_rel_error" in p:
            con.print(f"{p['n_across']:>4} across, dt {p['dt_fraction']:g}: {p['n_elements']} "
                      f"elements, {p['wall_time_s']:.1f} s, E error {p['E_rel_error']:+.1%}, "
                      f"UCS error {p['ucs_rel_error']:+.1%}", highlight=False)
        else:
            con.print(f"{p['n_across']:>4} across, dt {p['dt_fraction']:g}: {p['status']}: "
                      f"{p.get('error')}", highlight=False)

    rec = ucs_study(workflow, out, across=n, fractions=f, material=material,
                    tolerance=tolerance, backend=backend, progress=report)
    b = rec["fastest_within_tolerance"]
    if b:
        con.print(f"fastest within {tolerance:.0%}: {b['n_across']} across, dt fraction "
                  f"{b['dt_fraction']:g} ({b['wall_time_s']:.1f} s)", highlight=False)
    else:
        con.print(f"no point within {tolerance:.0%}", highlight=False)
    con.print(f"wrote study.json, speed_accuracy.png to {out}", highlight=False)
    if not any("E_rel_error" in p for p in rec["points"]):
        _fail("no point of the study gave a result (see the errors above)", FAILURE)


def _scale(out, sizes, families, max_build, backend):
    from geodem.studies.scale import DEFAULT_SIZES, FAMILIES, scale_study

    fams = [f.strip() for f in families.split(",")] if families else list(FAMILIES)
    bad = [f for f in fams if f not in FAMILIES]
    if bad:
        _fail(f"--families {families}: {', '.join(bad)} unknown; allowed: "
              f"{', '.join(FAMILIES)}", USER_ERROR)
    con = _out()
    res = scale_study(_fresh_out_dir(out, overwrite=False), fams, sizes or DEFAULT_SIZES,
                      backend=backend or "numba", max_build_s=max_build,
                      progress=lambda msg: con.print(escape(msg), highlight=False))
    for fam, g in res["growth"].items():
        worst = [k for k, v in g.items() if v["faster_than_n_log_n"]]
        e = g["build_s"]["exponent"]
        con.print(f"{fam}: build time grows as N^{e:.2f}" if e is not None else
                  f"{fam}: one size only", highlight=False)
        for key, v in g.items():
            if v.get("disk_exponent") is not None:
                con.print(f"{fam}: {key} grows as N^{v['exponent']:.2f}, a plain write of its "
                          f"bytes as N^{v['disk_exponent']:.2f}", highlight=False)
        if worst:
            con.print(f"[bold red]{fam}: faster than N log N: {', '.join(worst)}[/]")
    con.print(f"wrote scale.json, scale.csv, scale.png to {out}", highlight=False)
    if res["failed"]:
        _fail("; ".join(f"{f['family']} at {f['n']:,} elements failed: {f['error']}"
                        for f in res["failed"]) + f" (the other points are in {out})", 1)


def _reach(out, dim, s_values, rho_values, save, backend, merge=False):
    from pathlib import Path

    from geodem.studies import reach

    s_v = _float_list(s_values, "--s") if s_values else reach.DEFAULT_GRID[dim][0]
    r_v = _float_list(rho_values, "--rho") if rho_values else reach.DEFAULT_GRID[dim][1]
    o = _fresh_out_dir(out, overwrite=(Path(out) / "reach.json").exists())
    con = _out()
    con.print(f"reachable region, {dim}-D: {len(s_v)} x {len(r_v)} points -> {out}",
              highlight=False)

    def report(p):
        if "ratio" in p:
            win = f"nu {p['nu']:.3f}" if "nu" in p else escape(p["window_error"])
            el = (f", elastic nu {p['nu_elastic']:.3f} (cracks from "
                  f"{100 * p.get('crack_initiation', float('nan')):.0f} % of Cu)"
                  if "nu_elastic" in p else "")
            con.print(f"ks/kn {p['s']:g}, rho_s {p['rho_s']:g}: {win}{el}, Cu / Tu "
                      f"{p['ratio']:.3g}; {p['wall_time_s']:.0f} s", highlight=False)
        else:
            con.print(f"ks/kn {p['s']:g}, rho_s {p['rho_s']:g}: {escape(p['error'])}",
                      highlight=False)

    rec = reach.reach_study(dim, o, s_v, r_v, backend=backend, progress=report)
    b = rec["bounds"]
    if not b:
        _fail("no point of the study gave a result (see the errors above)", FAILURE)
    nus = "".join(f", {name} {b[k][0]:.3g}-{b[k][1]:.3g}" for k, name in
                  (("nu", "nu"), ("nu_elastic", "elastic nu")) if k in b)
    con.print(f"Cu / Tu {b['ratio'][0]:.3g}-{b['ratio'][1]:.3g}{nus}; "
              f"{rec['wall_time_s']:.0f} s; wrote reach.json, reach.png to {out}",
              highlight=False)
    if save:
        dest = reach.save_chart(rec, merge=merge)
        con.print(f"{'added the points to' if merge else 'saved'} the chart {dest}",
                  highlight=False)
        if merge:  # the whole chart, as calibrate now judges by it
            reach.plot_chart(o / "reach_chart.png", reach.shipped_chart(dim))
            con.print(f"wrote reach_chart.png (every point of the chart) to {out}",
                      highlight=False)


@app.command("sweep", help=(
    "Run a workflow once per combination of parameter values, on Dask.\n\n"
    "Every --param KEY=V1,V2,... (a --set path and YAML values, separated by ',' outside "
    "brackets, or by ';' when the values contain commas: 'model.counts=[10,10];[20,20]') is "
    "one axis; the members are their Cartesian product (--zip: the n-th values together), "
    "crossed with metadata.seed = 0..N-1 by --seeds N. Every member is validated first. Each "
    "runs in DIR/members/<hash12>/ (its config hash; identical workflows share one); writes "
    "DIR/members.json, DIR/results.csv and DIR/summary.json. Runs on a local cluster of "
    "--workers processes, or on the Dask scheduler at --scheduler ADDRESS.\n\n"
    "Exit status: 0 every member completed, 1 a member failed, 2 invalid input (nothing "
    "written), 130 interrupted (results so far written; continue with --resume)."))
@_guard
def sweep_cmd(
    file: Annotated[str, typer.Argument(metavar="FILE.yaml", help="Workflow file.")],
    out: Annotated[str, typer.Option("-o", "--out", help="Sweep directory (created).")],
    params: Annotated[Optional[list[str]], typer.Option(
        "--param", metavar="KEY=V1,V2,...",
        help="A parameter and its values, e.g. --param steps.oscillate.nsteps=100,200 "
             "(repeatable; VALUE is YAML as for --set; separate values with ';' when they "
             "contain commas).")] = None,
    zip_: Annotated[bool, typer.Option(
        "--zip", help="Pair the n-th values of every --param instead of the Cartesian "
                      "product (equal numbers of values).")] = False,
    seeds: Annotated[Optional[int], typer.Option(
        "--seeds", min=1, metavar="N",
        help="Monte-Carlo ensemble: every member once per metadata.seed = 0..N-1.")] = None,
    sets: Annotated[Optional[list[str]], typer.Option(
        "--set", metavar="KEY=VALUE", help="Override a value in every member (as for "
                                           "geodem run).")] = None,
    scheduler: Annotated[Optional[str], typer.Option(
        "--scheduler", metavar="ADDRESS",
        help="Address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786. \\[default: a "
             "local cluster]")] = None,
    workers: Annotated[Optional[int], typer.Option(
        "--workers", min=1, metavar="N",
        help="Worker processes of the local cluster. \\[default: usable cores, at most the "
             "number of members to run]")] = None,
    numba_threads: Annotated[int, typer.Option(
        "--numba-threads", min=1, metavar="N",
        help="NUMBA_NUM_THREADS of every member.")] = 1,
    backend: Annotated[Optional[str], typer.Option(
        "--backend", callback=_parse_backend,
        help="auto, numba, numpy or cupy. \\[default: the workflow's backend, else "
             "$GEODEM_BACKEND, else auto; resolved on this machine]")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue the sweep in -o DIR: completed members are skipped, "
                         "interrupted ones continue from their checkpoint, failed ones run "
                         "again.")] = False,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="Delete the sweep in -o DIR and start again.")] = False,
    no_progress: Annotated[bool, typer.Option(
        "--no-progress", help="No progress bar (one line per finished member).")] = False,
):
    from geodem.sweep import SweepInterrupted, run_sweep

    con = _out()
    err = _err()
    bar = not no_progress and err.is_terminal

    def report(m, rec):
        vals = ", ".join(f"{k}={v}" for k, v in m.values.items())
        what = "skipped (complete)" if rec.get("skipped") else rec.get("status", "?")
        wall = rec.get("wall_s")
        line = f"{m.key} {vals}: {what}" + (f", {wall:.1f} s" if wall is not None else "")
        if rec.get("error") and rec.get("status") != "ok":
            line += f": {str(rec['error']).splitlines()[0]}"
        (err if bar else con).print(escape(line), highlight=False, soft_wrap=True)  # above a bar

    try:
        code, s = run_sweep(file, out, params or [], zip_=zip_, seeds=seeds, backend=backend,
                            scheduler=scheduler, workers=workers, numba_threads=numba_threads,
                            resume=resume, overwrite=overwrite, sets=_parse_sets(sets),
                            on_member=report, bar=bar, console=err)
    except SweepInterrupted as exc:
        s = exc.summary
        err.print(f"interrupted: {s['completed']} of {s['members']} members complete; results "
                  f"so far in {escape(out)}; continue with --resume", highlight=False)
        raise typer.Exit(130) from None
    con.print(f"{s['members']} members: {s['completed']} completed ({s['skipped']} skipped), "
              f"{s['failed']} failed; wall time {s['wall_time_s']:.1f} s on "
              f"{escape(s['scheduler'])}; wrote results.csv, summary.json to {escape(out)}",
              highlight=False)
    if code:
        raise typer.Exit(code)


@app.command("validate", help=(
    "Check a workflow without running it.\n\n"
    "Checks the schema, names, sizes and memory, the model build and the time step. Exit 0 if "
    "valid; else exit 2 and one line per problem: FILE.yaml:LINE: <field path>: <message>."))
@_guard
def validate_cmd(
    file: Annotated[str, typer.Argument(metavar="FILE.yaml", help="Workflow file.")],
    sets: Annotated[Optional[list[str]], typer.Option(
        "--set", metavar="KEY=VALUE", help="Override a value (as for geodem run).")] = None,
    backend: Annotated[Optional[str], typer.Option(
        "--backend", callback=_parse_backend, help="Backend to check.")] = None,
    verbose: Annotated[bool, typer.Option("-v", "--verbose",
                                          help="Show full tracebacks on errors.")] = False,
):
    """Check a workflow without running it.

    Checks the schema, names, sizes and memory, the model build and the time step. Exit 0 if
    valid; else exit 2 and one line per problem: FILE.yaml:LINE: <field path>: <message>."""
    if verbose:
        _OPTS["verbose"] = True
    from geodem.workflow.runner import prepare

    prep = prepare(file, sets=_parse_sets(sets), backend=backend,
                   progress=_build_progress(_err()))
    p = prep.plan
    sys.stdout.write(f"{file}: valid ({p.n_elements:,} elements, dt = {p.dt:.4g} s, "
                     f"{p.total_steps:,} time steps, backend {prep.backend})\n")


@app.command("advise", help=(
    "What a workflow will cost and how it could cost less, without running it.\n\n"
    "Validates and builds FILE.yaml as 'geodem validate' does, times the built model on this "
    "machine for about half a second (--no-calibrate: the documented throughput instead), and "
    "prints elements, dimension, memory, planned time steps, the estimated wall time and "
    "suggestions: 2-D or not, the time-step fraction against the stability bound, and the "
    "resolution for --target-error from a 'geodem study speed-accuracy' CSV when one is found. "
    "Exit 0, or 2 and one line per problem for an invalid workflow. See docs/advise.md."))
@_guard
def advise_cmd(
    file: Annotated[str, typer.Argument(metavar="FILE.yaml", help="Workflow file.")],
    sets: Annotated[Optional[list[str]], typer.Option(
        "--set", metavar="KEY=VALUE", help="Override a value (as for geodem run).")] = None,
    backend: Annotated[Optional[str], typer.Option(
        "--backend", callback=_parse_backend, help="Backend to estimate for.")] = None,
    no_calibrate: Annotated[bool, typer.Option(
        "--no-calibrate", help="Use the documented throughput (docs/performance.md) instead "
                               "of timing the model here.")] = False,
    target_error: Annotated[float, typer.Option(
        "--target-error", min=1e-9, max=0.999, help="Relative error the resolution "
                                                     "suggestion aims at.")] = 0.01,
    speed_csv: Annotated[Optional[str], typer.Option(
        "--speed-accuracy", metavar="CSV", help="speed_accuracy.csv of 'geodem study "
        "speed-accuracy'. \\[default: out/speed_accuracy/speed_accuracy.csv if present]")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON object.")] = False,
):
    from geodem.advise import advise, report_lines

    a = advise(file, sets=_parse_sets(sets), backend=backend, calibrate=not no_calibrate,
               target_error=target_error, speed_csv=speed_csv,
               progress=_build_progress(_err()))
    if as_json:
        sys.stdout.write(json.dumps(a, indent=2) + "\n")
        return
    con = _out()
    for line in report_lines(a):
        con.print(escape(line), highlight=False, soft_wrap=True)


@app.command("view", help=(
    "Draw one frame of a run to a PNG, or its frames to a GIF (pyvista, off-screen).\n\n"
    "Reads RUN_DIR/output.h5: the elements of frame K (spheres in 3-D, discs seen from above in "
    "2-D) coloured by --color, and the bonds broken up to that frame as lines (red tensile, blue "
    "shear, grey joint). Writes RUN_DIR/view_frame_K.png unless -o names another file; -o "
    "FILE.gif draws the run's frames (at most --max-frames) into an animation with one camera "
    "and one colour scale. Needs the 'vis' extra. Exit 0, or 2 for a missing run, an unknown "
    "frame or a bad option. See docs/view.md."))
@_guard
def view_cmd(
    run_dir: Annotated[str, typer.Argument(metavar="RUN_DIR", help="Run directory.")],
    frame: Annotated[int, typer.Option(
        "--frame", "-f", help="Frame index (0 the first, -1 the last).")] = -1,
    output: Annotated[Optional[str], typer.Option(
        "-o", "--output", metavar="FILE.png|FILE.gif", help="Picture to write; a .gif is an "
        "animation of the run's frames. \\[default: RUN_DIR/view_frame_K.png]")] = None,
    color: Annotated[str, typer.Option(
        "--color", help="Colour the elements by displacement, velocity, radius or none.")] =
        "displacement",
    size: Annotated[str, typer.Option(
        "--size", metavar="WxH", help="Picture size in pixels.")] = "1200x900",
    opacity: Annotated[Optional[float], typer.Option(
        "--opacity", help="Element opacity 0-1. \\[default: 1; 0.2 in 3-D with cracks]")] = None,
    show: Annotated[bool, typer.Option(
        "--show", help="Open an interactive window (needs a display) and save on close.")] =
        False,
    cracks: Annotated[str, typer.Option(
        "--cracks", help="Crack types drawn: all, none, or a list of tensile,shear,joint.")] =
        "all",
    fps: Annotated[float, typer.Option(
        "--fps", help="Animation: frames per second (0.1-60).")] = 4.0,
    max_frames: Annotated[int, typer.Option(
        "--max-frames", help="Animation: the most frames drawn, spread evenly over the run's "
        "(2-10000).")] = 120,
):
    from geodem.io.view import ViewError, crack_kinds, render_animation, render_frame

    try:
        w, h = (int(v) for v in size.lower().split("x"))
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise ValueError
    except ValueError:
        raise ViewError(f"--size {size}: allowed: WIDTHxHEIGHT in pixels, 16 to 8192 each "
                        "(e.g. 1200x900)") from None
    kinds = crack_kinds(cracks)
    if output and output.lower().endswith(".gif"):
        if show:
            raise ViewError("--show: allowed with a .png picture only, not with an animation")
        r = render_animation(run_dir, output, color=color, size=(w, h), opacity=opacity,
                             fps=fps, max_frames=max_frames, progress=_frames_drawn(_err()),
                             cracks=kinds)
        c = r["cracks"]
        sys.stdout.write(f"wrote {r['path']}: {r['frames']} of the run's {r['frames_in_run']} "
                         f"frames (steps {r['steps'][0]:,} to {r['steps'][1]:,}), "
                         f"{r['elements']:,} elements; at the last {c['tensile']} tensile / "
                         f"{c['shear']} shear / {c['joint']} joint cracks\n")
        return
    r = render_frame(run_dir, frame=frame, output=output, color=color, size=(w, h),
                     opacity=opacity, show=show, cracks=kinds)
    c = r["cracks"]
    sys.stdout.write(f"wrote {r['path']}: frame {r['frame']} of {r['frames']} (step "
                     f"{r['step']:,}, t = {r['time']:.4g} s), {r['elements']:,} elements, "
                     f"{c['tensile']} tensile / {c['shear']} shear / {c['joint']} joint "
                     "cracks\n")


@app.command("schema")
@_guard
def schema_cmd(
    output: Annotated[Optional[str], typer.Option(
        "-o", "--output", help="Write to this file instead of stdout.")] = None,
):
    """Print the JSON schema of workflow files (committed as docs/geodem.schema.json)."""
    from geodem.workflow.schema import json_schema

    text = json.dumps(json_schema(), indent=2) + "\n"
    if output:
        try:
            with open(output, "w") as fh:
                fh.write(text)
        except OSError as exc:
            _fail(f"-o {output}: cannot write the schema there ({exc.strerror or exc}); "
                  f"allowed: a file path in a folder that exists and can be written", USER_ERROR)
    else:
        sys.stdout.write(text)


def run():  # pragma: no cover - entry point for python -m geodem
    app(prog_name="geodem")


if __name__ == "__main__":  # pragma: no cover
    run()
