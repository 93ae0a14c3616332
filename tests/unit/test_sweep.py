"""``geodem sweep`` without a cluster: parameter parsing, member expansion, config-hash keying,
validation before anything is written, the sweep directory rules and the results table."""
import csv
import json
import math
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.sweep import (
    Member,
    _prepare_dir,
    expand,
    flatten_summary,
    parse_param,
    plan_members,
    run_member,
    run_sweep,
    split_values,
    write_results,
)
from geodem.workflow import WorkflowError

ROOT = Path(__file__).resolve().parents[2]
TWO_BALLS = ROOT / "workflows" / "two_balls.yaml"


# ----------------------------------------------------------------------------- parsing
@pytest.mark.parametrize("text, items", [
    ("1,2,3", ["1", "2", "3"]),
    (" 1 , 2 ", ["1", "2"]),
    ("[1,2],[3,4]", ["[1,2]", "[3,4]"]),
    ("[1,2];[3,4]", ["[1,2]", "[3,4]"]),
    ("0.1;0.2", ["0.1", "0.2"]),
    ("'a,b',c", ["'a,b'", "c"]),
    ("{a: 1, b: [2, 3]},{a: 4}", ["{a: 1, b: [2, 3]}", "{a: 4}"]),
    ("[[1,2],[3]],[4]", ["[[1,2],[3]]", "[4]"]),
])
def test_split_values(text, items):
    assert split_values(text) == items


def test_parse_param_values_are_yaml_like_set():
    p = parse_param("steps.oscillate.nsteps=100,2e2,3.5e2")
    assert p.key == "steps.oscillate.nsteps"
    assert p.values == [100, 200, 350] and all(isinstance(v, int) for v in p.values)
    assert p.texts == ["100", "2e2", "3.5e2"]
    q = parse_param("model.counts=[10,10];[20,20]")
    assert q.values == [[10, 10], [20, 20]]
    assert parse_param("model.counts=[10,10],[20,20]").values == q.values
    assert parse_param("model.material=paper,granite").values == ["paper", "granite"]
    assert parse_param("simulation.dt=null,1e-5").values == [None, 1e-5]


@pytest.mark.parametrize("expr, needle", [
    ("a.b", "expected KEY=V1,V2"),
    ("=1,2", "dotted path"),
    ("a..b=1", "dotted path"),
    ("a.b=", "empty value"),
    ("a.b=1,,2", "empty value"),
    ("a.b=1;", "empty value"),
    ("a.b=[1,2", "unclosed bracket"),
    ("a.b=1]", "unbalanced"),
    ("a.b='x,y", "unclosed quote"),
    ("a.b=[1;2]", "not valid YAML"),
])
def test_parse_param_bad_syntax(expr, needle):
    with pytest.raises(WorkflowError) as ei:
        parse_param(expr)
    text = str(ei.value)
    assert needle in text
    assert text.startswith(f"--param {expr}:")  # names the option as given


def test_expand_product_zip_seeds():
    a, b = parse_param("x.a=1,2"), parse_param("x.b=10,20,30")
    prod = expand([a, b])
    assert [[v for _, _, v in c] for c in prod] == [[1, 10], [1, 20], [1, 30], [2, 10],
                                                     [2, 20], [2, 30]]
    c = parse_param("x.c=5,6")
    zipped = expand([a, c], zip_=True)
    assert [[v for _, _, v in m] for m in zipped] == [[1, 5], [2, 6]]
    seeded = expand([a], seeds=3)
    assert [[(k, v) for k, _, v in m] for m in seeded] == [
        [("x.a", a), ("metadata.seed", s)] for a in (1, 2) for s in range(3)]
    only_seeds = expand([], seeds=2)
    assert [[(k, t) for k, t, _ in m] for m in only_seeds] == [[("metadata.seed", "0")],
                                                               [("metadata.seed", "1")]]
    assert len(expand([a, c], zip_=True, seeds=2)) == 4


@pytest.mark.parametrize("args, kwargs, needle", [
    (["x.a=1,2", "x.b=1,2,3"], {"zip_": True}, "equal numbers of values"),
    (["x.a=1", "x.a=2"], {}, "given twice"),
    ([], {}, "at least one --param"),
    (["metadata.seed=1,2"], {"seeds": 2}, "do not also give"),
    (["x.a=1"], {"seeds": 0}, ">= 1"),
])
def test_expand_errors(args, kwargs, needle):
    with pytest.raises(WorkflowError, match=needle):
        expand([parse_param(a) for a in args], **kwargs)


# ----------------------------------------------------------------------------- members
def test_member_hash_is_the_runners_config_hash():
    from geodem.workflow.runner import prepare

    (m,) = plan_members(TWO_BALLS, [parse_param("steps.oscillate.nsteps=30")], backend="numpy")
    prep = prepare(TWO_BALLS, sets=m.sets, backend="numpy")
    assert m.config_hash == prep.config_hash
    assert m.key == prep.config_hash[:12] and m.backend == "numpy"


def test_identical_configs_share_one_member():
    # 0.02, 2e-2 and 0.020 are the same workflow (and 0.02 is the file's own value)
    ms = plan_members(TWO_BALLS, [parse_param("simulation.dt_fraction=0.02,2e-2,0.020,0.05")],
                      backend="numpy")
    assert len(ms) == 2
    assert [m.values for m in ms] == [{"simulation.dt_fraction": 0.02},
                                      {"simulation.dt_fraction": 0.05}]
    assert len(ms[0].duplicates) == 2 and not ms[1].duplicates
    assert ms[0].key != ms[1].key
    # the seed is part of the workflow: every seed is its own member
    seeded = plan_members(TWO_BALLS, [], seeds=3, backend="numpy")
    assert len({m.key for m in seeded}) == 3


def test_invalid_member_names_member_and_field(tmp_path):
    out = tmp_path / "sweep"
    with pytest.raises(WorkflowError) as ei:
        run_sweep(TWO_BALLS, out, ["steps.oscillate.nsteps=10,-5,20"], backend="numpy")
    lines = ei.value.lines()
    assert len(lines) == 1, lines  # only the bad member
    line = lines[0]
    assert line.startswith("--param steps.oscillate.nsteps=-5: steps[0].nsteps: ")
    assert "member 2 of 3 (steps.oscillate.nsteps=-5)" in line
    assert ">= 1" in line
    assert not out.exists()  # nothing written


def test_unknown_parameter_path_rejected_before_anything_is_written(tmp_path):
    out = tmp_path / "sweep"
    with pytest.raises(WorkflowError) as ei:
        run_sweep(TWO_BALLS, out, ["model.diametre=1,2"])
    assert "unknown key 'diametre'" in str(ei.value)
    assert "member 1 of 2" in str(ei.value) and "member 2 of 2" in str(ei.value)
    assert not out.exists()


def test_run_member_records_a_build_time_failure(tmp_path):
    """dt = 1 s passes the schema but not the stability check of the built model: the member
    is 'invalid' with the message, and nothing raises."""
    import numba

    (m,) = plan_members(TWO_BALLS, [parse_param("simulation.dt=1.0")], backend="numpy")
    threads = numba.get_num_threads()
    try:
        rec = run_member(str(TWO_BALLS), str(tmp_path / m.key), m.sets, m.backend,
                         m.config_hash)
    finally:
        numba.set_num_threads(threads)  # run_member set this process's numba threads to 1
    assert rec["status"] == "invalid" and rec["exit_code"] == 2
    assert "stability limit" in rec["error"]
    assert rec["numba_threads"] == 1 and rec["wall_s"] > 0


# ----------------------------------------------------------------------------- directory
def test_existing_directory_refused(tmp_path):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    res = CliRunner().invoke(app, ["sweep", str(TWO_BALLS), "--param",
                                   "steps.oscillate.nsteps=20,40", "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert "already exists and is not empty" in res.output
    assert "--resume" in res.output and "--overwrite" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    # --overwrite deletes only a sweep directory, --resume continues only one
    for flag in ("--overwrite", "--resume"):
        res = CliRunner().invoke(app, ["sweep", str(TWO_BALLS), "--param",
                                       "steps.oscillate.nsteps=20", "-o", str(out), flag])
        assert res.exit_code == 2, res.output
        assert "not a geodem sweep directory" in res.output
    assert (out / "keep.txt").read_text() == "mine"


def test_prepare_dir_rules(tmp_path):
    out = tmp_path / "s"
    _prepare_dir(out, resume=False, overwrite=False)  # new: fine
    _prepare_dir(out, resume=True, overwrite=False)   # nothing to skip yet: fine
    with pytest.raises(WorkflowError, match="exclude each other"):
        _prepare_dir(out, resume=True, overwrite=True)
    out.mkdir()
    (out / "members.json").write_text("{}")
    _prepare_dir(out, resume=True, overwrite=False)
    _prepare_dir(out, resume=False, overwrite=True)
    with pytest.raises(WorkflowError, match="already exists"):
        _prepare_dir(out, resume=False, overwrite=False)
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(WorkflowError, match="not a folder"):
        _prepare_dir(f, resume=False, overwrite=False)


def test_cli_bad_param_exit_2(tmp_path):
    res = CliRunner().invoke(app, ["sweep", str(TWO_BALLS), "--param", "a.b=[1,2",
                                   "-o", str(tmp_path / "s")])
    assert res.exit_code == 2
    assert "--param a.b=[1,2: a.b: unclosed bracket" in res.output
    res = CliRunner().invoke(app, ["sweep", str(TWO_BALLS), "--param", "model.diameter=1",
                                   "--scheduler", "tcp://127.0.0.1:1", "--workers", "2",
                                   "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and "--workers sizes the local cluster" in res.output
    res = CliRunner().invoke(app, ["sweep", str(tmp_path / "missing.yaml"), "--param",
                                   "a.b=1", "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and "file not found" in res.output
    assert not (tmp_path / "s").exists()


# ----------------------------------------------------------------------------- results
def test_flatten_summary():
    s = {"status": "ok", "steps": 10, "sim_time": 0.5, "workflow": "w", "bonds_broken": None,
         "files": ["a", "b"], "plots": {"p.png": "p.png"},
         "results": {"check": {"period": 1.5, "peaks": 3, "curve": [1, 2],
                               "dev": {"a": 0.1, "b": 0.2}},
                     "other": {"ok": True}}}
    flat = flatten_summary(s)
    assert flat == {"status": "ok", "steps": 10, "sim_time": 0.5, "workflow": "w",
                    "bonds_broken": None, "results.check.period": 1.5,
                    "results.check.peaks": 3, "results.check.dev.a": 0.1,
                    "results.check.dev.b": 0.2, "results.other.ok": True}


def test_write_results_columns_and_cells(tmp_path):
    ms = [Member(0, "aaaaaaaaaaaa", "a" * 64, {"x.a": 1, "x.l": [1, 2]}, []),
          Member(1, "bbbbbbbbbbbb", "b" * 64, {"x.a": 2, "x.l": [3, 4]}, [])]
    recs = {"aaaaaaaaaaaa": {"status": "ok", "wall_s": 1.5, "host": "h", "numba_threads": 1,
                             "summary": {"status": "ok", "steps": 7, "energy": math.nan,
                                         "results": {"c": {"v": 2.5}}}},
            "bbbbbbbbbbbb": {"status": "failed", "error": "boom", "summary": None}}
    path = tmp_path / "results.csv"
    write_results(path, ms, recs, ["x.a", "x.l"])
    rows = list(csv.DictReader(path.open()))
    assert list(rows[0])[:10] == ["hash", "x.a", "x.l", "status", "skipped", "resumed",
                                  "wall_s", "host", "numba_threads", "error"]
    assert list(rows[0])[10:] == ["steps", "energy", "results.c.v"]
    assert rows[0]["x.l"] == "[1, 2]" and rows[0]["steps"] == "7"
    assert rows[0]["energy"] == ""  # NaN -> empty cell
    assert rows[0]["results.c.v"] == "2.5"
    assert rows[1]["status"] == "failed" and rows[1]["error"] == "boom"
    assert rows[1]["steps"] == ""
    json.dumps(rows)  # plain strings


# ----------------------------------------------------------------------------- docs
def _doc_commands():
    import re
    import shlex

    text = (ROOT / "docs" / "sweeps.md").read_text()
    cmds = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("geodem sweep"):
                cmds.append(shlex.split(line)[2:])
    return cmds


def test_doc_commands_are_valid_sweeps():
    """Every ``geodem sweep`` command of docs/sweeps.md expands into valid members (parsed as
    the command line parses them; nothing is run)."""
    from typer.main import get_command

    cmds = _doc_commands()
    assert len(cmds) >= 7
    sweep_cmd = get_command(app).commands["sweep"]
    for args in cmds:
        args = ["2" if a == "W" else a for a in args]  # the measured commands' --workers W
        p = sweep_cmd.make_context("sweep", args).params
        members = plan_members(ROOT / p["file"], [parse_param(x) for x in p["params"] or []],
                               zip_=p["zip_"], seeds=p["seeds"], backend=p["backend"],
                               base_sets=p["sets"] or [])
        assert members, args
