"""Every ``geodem`` command printed in a ```bash block of README.md and docs/*.md runs as
printed.

CI tier (a few seconds in all):

* every command goes through the CLI's own parser: the subcommand and every option exist and
  every option value passes its checks (``--help`` alone would prove nothing);
* what it names is checked without building a model: a workflow with its ``--set`` values is
  validated as ``geodem validate`` does before the build (a wrong path, a wrong ``--set``
  field, a material without values for the model's dimension fail), a sweep expands and
  validates every member, library materials load, study kinds exist;
* synopsis lines (``[--option ...]``, ``FILE.yaml``) are checked for their subcommand and
  option names only;
* the two_balls commands (the README's quick start, docs/workflows.md), ``geodem schema``,
  ``geodem info`` and ``--help`` lines are run for real, output folders moved to a temporary
  one.

slow tier (``-m slow``): every other printed ``geodem run``, ``validate`` and ``advise`` runs
in a subprocess as printed (its environment prefix such as ``NUMBA_NUM_THREADS=1`` kept,
``-o`` moved to a temporary folder, a ``--resume`` after the command before it with the same
``-o``): a ``run`` to the end when its ``--dry-run`` estimate is below ``GEODEM_DOC_RUN_S``
seconds (default 300), else for ``GEODEM_DOC_STEPS`` time steps (default 500,
``--stop-after-steps``), and the two_balls sweeps. Studies, calibrations, benchmarks and sweeps
of other workflows (minutes to hours each) keep their CI checks only.
"""
from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC_FILES = ["README.md"] + sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))
#: values the docs leave to the reader, with the example they stand for (hydraulic_fracturing.md:
#: A the hole radius, L = 10 A, S the seed; sweeps.md: W the number of workers)
PLACEHOLDERS = {"$A": "0.02", "$L": "0.2", "S": "0", "W": "2"}
#: words of a synopsis line (the user puts a value there)
SYNOPSIS_WORDS = {"FILE.yaml", "DIR", "MATERIAL", "KIND", "FILE", "B", "N", "CSV"}
OUT_OPTIONS = ("-o", "--out", "--output")
CHEAP_WORKFLOWS = {"workflows/two_balls.yaml"}


@dataclass
class Command:
    file: str
    line: int
    text: str
    args: list
    env: dict = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}: geodem {' '.join(self.args)}"

    @property
    def synopsis(self) -> bool:
        return any(a.startswith("[") or a in SYNOPSIS_WORDS for a in self.args)

    @property
    def name(self) -> str:
        return next((a for a in self.args if not a.startswith("-")), "")

    def option(self, *names):
        """The value of the last of the options ``names``, or None."""
        value = None
        for k, a in enumerate(self.args[:-1]):
            if a in names:
                value = self.args[k + 1]
        return value

    @property
    def help(self) -> bool:
        return "--help" in self.args or "-h" in self.args

    @property
    def cheap(self) -> bool:
        """Run for real in CI: a two_balls run, validate or advise, schema, info, --help."""
        if self.synopsis:
            return False
        if self.help or self.name in ("schema", "info"):
            return True
        return self.name in ("run", "validate", "advise") and any(
            a in CHEAP_WORKFLOWS for a in self.args)


def parse_commands(text: str, file: str = "<text>") -> list[Command]:
    """The ``geodem`` commands of the ```bash blocks of a Markdown text: continuation lines
    joined, comments dropped, ``&&`` / ``;`` chains split, ``VAR=value`` prefixes kept as the
    environment, ``python -m geodem`` read as ``geodem``; placeholders substituted."""
    out = []
    lines = text.splitlines()
    k = 0
    block = False
    while k < len(lines):
        ln = lines[k]
        if ln.strip().startswith("```"):
            block = (not block) and ln.strip() == "```bash"
            k += 1
            continue
        if not block:
            k += 1
            continue
        start = k
        while ln.rstrip().endswith("\\") and k + 1 < len(lines):
            k += 1
            ln = ln.rstrip()[:-1] + " " + lines[k].strip()
        k += 1
        lex = shlex.shlex(ln, posix=True, punctuation_chars=True)
        lex.whitespace_split = True  # words end at blanks and at ; & | only
        try:
            tokens = list(lex)
        except ValueError:
            continue
        segment: list = []
        for tok in tokens + ["&&"]:
            if tok not in ("&&", ";", "||", "|"):
                segment.append(tok)
                continue
            cmd = _command(segment, file, start + 1, ln.strip())
            if cmd is not None:
                out.append(cmd)
            segment = []
    return out


def _command(tokens, file, line, text):
    env = {}
    while tokens and re.match(r"^[A-Z_][A-Z0-9_]*=", tokens[0]):
        key, value = tokens[0].split("=", 1)
        env[key] = value
        tokens = tokens[1:]
    if tokens[:1] == ["geodem"]:
        args = tokens[1:]
    elif len(tokens) >= 3 and tokens[0] in ("python", "python3") and tokens[1:3] == ["-m",
                                                                                     "geodem"]:
        args = tokens[3:]
    else:
        return None
    return Command(file, line, text, [_substitute(a) for a in args], env)


def _substitute(arg: str) -> str:
    for key in ("$A", "$L"):
        arg = arg.replace(key, PLACEHOLDERS[key])
    if arg in PLACEHOLDERS:
        return PLACEHOLDERS[arg]
    if "=" in arg and arg.split("=", 1)[1] in PLACEHOLDERS:
        key, value = arg.split("=", 1)
        return f"{key}={PLACEHOLDERS[value]}"
    return arg


def doc_commands() -> list[Command]:
    out = []
    for f in DOC_FILES:
        out += parse_commands((ROOT / f).read_text(), f)
    return out


COMMANDS = doc_commands()


def _ids(cmds):
    return [f"{c.file}:{c.line}:{c.name or c.args[0]}" for c in cmds]


# ============================================================================ the CLI's parser
def _cli():
    import typer

    from geodem.cli import app

    return typer.main.get_command(app)


def parse(args):
    """``(subcommand name, its click command, its parameter values)`` as the CLI parses
    ``args``, without running anything; a click UsageError for an unknown subcommand or
    option, a missing argument or a value that fails its check."""
    cli = _cli()
    ctx = cli.make_context("geodem", list(args))
    rest = list(getattr(ctx, "protected_args", None) or ctx._protected_args) + list(ctx.args)
    name, cmd, rest = cli.resolve_command(ctx, rest)
    sub = cmd.make_context(name, list(rest), parent=ctx)
    return name, cmd, sub.params


def _option_names(cmd) -> set:
    names = set()
    for p in cmd.params:
        names.update(p.opts)
        names.update(p.secondary_opts)
    return names


def check_names(c: Command) -> None:
    """A synopsis or --help line: the subcommand and every option name it shows exist."""
    cli = _cli()
    cmd = cli.commands.get(c.name) if c.name else cli
    assert cmd is not None, f"{c.where}: no subcommand {c.name!r}"
    known = _option_names(cmd) | {"--help", "-h"}
    if cmd is cli:
        known |= _option_names(cli)
    for a in c.args:
        m = re.match(r"^\[?(--?[a-zA-Z][\w-]*)", a)
        if m and m.group(1) not in known:
            raise AssertionError(f"{c.where}: geodem {c.name} has no option {m.group(1)}; it "
                                 f"has {', '.join(sorted(known))}")


def _study_kinds(cmd) -> list:
    arg = next(p for p in cmd.params if p.name == "kind")
    return re.findall(r"[a-z][a-z-]+", arg.help.replace(" or ", ", "))


def check_cheaply(c: Command) -> None:
    """Parse ``c`` with the CLI's parser and check what it names (module doc), building
    nothing. AssertionError naming the file and line."""
    from geodem.workflow.errors import WorkflowError

    if c.synopsis or c.help:
        check_names(c)
        if c.synopsis:
            _check_material(c)
        return
    try:
        name, cmd, p = parse(c.args)
    except Exception as exc:  # noqa: BLE001 - click's UsageError and friends
        raise AssertionError(f"{c.where}: the CLI refuses it: {exc}") from None
    try:
        if name in ("run", "validate", "advise"):
            from geodem.workflow.runner import validated

            if name == "run" and p["out"] is None and not p["dry_run"]:
                raise AssertionError(f"{c.where}: geodem run needs -o DIR (or --dry-run)")
            validated(p["file"], p["sets"] or [], p["backend"])
        elif name == "sweep":
            from geodem.sweep import parse_param, plan_members

            plan_members(p["file"], [parse_param(e) for e in p["params"] or []], p["zip_"],
                         p["seeds"], p["backend"], base_sets=p["sets"] or [])
        elif name in ("calibrate", "rock"):
            _check_material(c, p["material"])
        elif name == "study":
            kinds = _study_kinds(cmd)
            assert p["kind"] in kinds, f"{c.where}: study kind {p['kind']!r}; allowed {kinds}"
            if p["kind"] == "friction":
                _check_material(c, "sandstone" if p["material"] == "rock" else p["material"])
    except WorkflowError as exc:
        raise AssertionError(f"{c.where}: invalid: " + "; ".join(exc.lines())) from None


def _check_material(c: Command, name=None) -> None:
    from geodem.materials_library import load_material

    if name is None:
        if c.name not in ("calibrate", "rock") or len(c.args) < 2 or \
                c.args[1].startswith(("-", "[")) or c.args[1] in SYNOPSIS_WORDS:
            return
        name = c.args[1]
    try:
        load_material(name)
    except Exception as exc:  # noqa: BLE001 - MaterialError, FileNotFoundError
        raise AssertionError(f"{c.where}: material {name!r}: {exc}") from None


def _redirect(args, tmp: Path, outs: dict) -> list:
    """``args`` with the value of every -o/--out/--output moved under ``tmp`` (the same
    folder for the same printed path: ``--resume`` finds its run)."""
    args = list(args)
    for k, a in enumerate(args[:-1]):
        if a in OUT_OPTIONS:
            orig = args[k + 1]
            if orig not in outs:
                outs[orig] = str(tmp / f"{len(outs)}_{re.sub(r'[^A-Za-z0-9_.-]', '_', orig)}")
            args[k + 1] = outs[orig]
    return args


# ============================================================================ CI tier
def test_the_collector_reads_blocks_chains_prefixes_and_continuations():
    text = "\n".join([
        "text `geodem run not/in/a/block.yaml`", "```bash",
        "NUMBA_NUM_THREADS=1 geodem run workflows/ucs.yaml -o out/u   # a comment",
        "geodem run workflows/ucs.yaml \\", "    --set model.seed=S -o out/u_S",
        "pip install -e . && PYTHONPATH=. python -m geodem validate workflows/ucs.yaml; ls",
        "# geodem run commented/out.yaml", "```", "```python", "geodem = 1", "```",
        "```bash", "geodem sweep workflows/two_balls.yaml --workers W -o out/s", "```"])
    cmds = parse_commands(text, "x.md")
    assert [(c.line, c.env, c.args) for c in cmds] == [
        (3, {"NUMBA_NUM_THREADS": "1"}, ["run", "workflows/ucs.yaml", "-o", "out/u"]),
        (4, {}, ["run", "workflows/ucs.yaml", "--set", "model.seed=0", "-o", "out/u_S"]),
        (6, {"PYTHONPATH": "."}, ["validate", "workflows/ucs.yaml"]),
        (13, {}, ["sweep", "workflows/two_balls.yaml", "--workers", "2", "-o", "out/s"])]


def test_the_docs_print_commands_of_every_kind():
    names = {c.name for c in COMMANDS}
    assert len(COMMANDS) > 80 and {"run", "validate", "advise", "sweep", "calibrate", "study",
                                   "schema", "info", "bench"} <= names
    assert any(c.file == "docs/landslide.md" and "model.dim=3" in c.args for c in COMMANDS)
    assert sum(c.synopsis for c in COMMANDS) >= 3


@pytest.mark.parametrize("args, what", [
    (["run", "workflows/no_such.yaml", "-o", "out/x"], "no_such.yaml"),
    (["run", "workflows/two_balls.yaml", "-o", "out/x", "--set", "model.no_such_field=1"],
     "no_such_field"),
    (["run", "workflows/two_balls.yaml", "-o", "out/x", "--no-such-option"], "--no-such-option"),
    (["run", "workflows/two_balls.yaml"], "needs -o"),
    (["validate", "workflows/landslide.yaml", "--set", "model.dim=3"], "calibrated in 2-D"),
    (["run", "workflows/two_balls.yaml", "--stop-after-steps", "0", "-o", "x"],
     "stop-after-steps"),
    (["sweep", "workflows/two_balls.yaml", "--param", "model.nope=1,2", "-o", "x"], "nope"),
    (["calibrate", "no_such_rock", "-o", "x"], "no_such_rock"),
    (["study", "no-such-study", "-o", "x"], "no-such-study"),
    (["bench", "--sizes", "ten"], "--sizes"),
    (["no-such-command"], "no-such-command"),
])
def test_a_wrong_command_fails_the_check(args, what, monkeypatch):
    monkeypatch.chdir(ROOT)
    with pytest.raises(AssertionError, match=re.escape(what)):
        check_cheaply(Command("x.md", 1, "", args))


def test_a_synopsis_with_an_unknown_option_fails_the_check():
    check_names(Command("x.md", 1, "", ["run", "FILE.yaml", "-o", "DIR", "[--dry-run]"]))
    with pytest.raises(AssertionError, match="no option --dry-walk"):
        check_names(Command("x.md", 1, "", ["run", "FILE.yaml", "[--dry-walk]"]))


@pytest.mark.parametrize("cmd", COMMANDS, ids=_ids(COMMANDS))
def test_every_printed_command_parses_and_names_what_exists(cmd, monkeypatch):
    monkeypatch.chdir(ROOT)
    check_cheaply(cmd)


CHEAP_FILES = sorted({c.file for c in COMMANDS if c.cheap})


@pytest.mark.parametrize("file", CHEAP_FILES)
def test_cheap_commands_run_as_printed(file, tmp_path, monkeypatch):
    """The two_balls commands, schema, info and --help lines of ``file``, in order (a
    ``--resume`` continues the run before it), in this process: exit status 0."""
    from typer.testing import CliRunner

    from geodem.cli import app

    monkeypatch.chdir(ROOT)
    outs: dict = {}
    ran = []
    for c in (c for c in COMMANDS if c.file == file and c.cheap):
        args = _redirect(c.args, tmp_path, outs)
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, f"{c.where}: exit {res.exit_code}\n{res.output[-2000:]}"
        ran.append(c)
        if c.name == "run" and not c.help and "--dry-run" not in args:
            s = json.loads((Path(outs[c.option(*OUT_OPTIONS)]) / "summary.json").read_text())
            want = "interrupted" if "--stop-after-steps" in args else "ok"
            assert s["status"] == want, (c.where, s["status"])
        if c.name == "schema" and c.option(*OUT_OPTIONS):
            assert "properties" in json.loads(Path(outs[c.option(*OUT_OPTIONS)]).read_text())
    assert ran


# ============================================================================ slow tier
def _sequences():
    """Slow-tier commands, each alone, except that a ``--resume`` follows the command before
    it with the same printed -o (in order); a command printed twice runs once."""
    seqs: list = []
    last: dict = {}
    seen: set = set()
    for c in COMMANDS:
        if c.synopsis or c.help or c.cheap:
            continue
        runs = c.name in ("run", "validate", "advise")
        sweep = c.name == "sweep" and c.option("--scheduler") is None and any(
            a in CHEAP_WORKFLOWS for a in c.args)
        if not (runs or sweep):
            continue
        out = (c.file, c.option(*OUT_OPTIONS))
        if "--resume" in c.args and out in last:
            last[out].append(c)
            continue
        key = tuple(c.args)
        if key in seen:
            continue
        seen.add(key)
        seqs.append([c])
        last[out] = seqs[-1]
    return seqs


SEQUENCES = _sequences()


def _subprocess(c: Command, args, timeout):
    env = dict(os.environ, **c.env)
    env.pop("PYTHONPATH", None)
    return subprocess.run([sys.executable, "-m", "geodem", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
@pytest.mark.parametrize("seq", SEQUENCES, ids=[f"{s[0].file}:{s[0].line}" for s in SEQUENCES])
def test_printed_commands_run_as_printed(seq, tmp_path):
    limit = float(os.environ.get("GEODEM_DOC_RUN_S", "300"))
    steps = os.environ.get("GEODEM_DOC_STEPS", "500")
    outs: dict = {}
    for c in seq:
        args = _redirect(c.args, tmp_path, outs)
        if c.name == "run" and "--dry-run" not in args and "--resume" not in args \
                and "--stop-after-steps" not in args:
            dry = [a for k, a in enumerate(args)
                   if a not in OUT_OPTIONS and (k == 0 or args[k - 1] not in OUT_OPTIONS)]
            p = _subprocess(c, dry + ["--dry-run"], timeout=3600)
            assert p.returncode == 0, f"{c.where}: --dry-run exit {p.returncode}\n{p.stderr}"
            est = re.search(r"estimated run time: about ([0-9.e+]+) s", p.stdout)
            if est and float(est.group(1)) > limit:
                args += ["--stop-after-steps", steps]
        p = _subprocess(c, args, timeout=max(3600, 3 * limit))
        assert p.returncode == 0, f"{c.where}: exit {p.returncode}\n{p.stderr[-3000:]}"
