"""Workflow validation: schema staleness, `geodem validate` output format, and one test per kind of
bad input (exit status 2 with FILE:LINE, the field path and what is allowed)."""
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.workflow import schema as wschema
from geodem.workflow.errors import ErrorItem, WorkflowError, format_path
from geodem.workflow.yamlio import load_document

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()
# FILE.yaml:LINE: path: message (values set on the command line: "--set KEY=VALUE: path: message")
LINE = re.compile(r"^(?P<file>--set [^:]+|[^:]+:(?P<line>\d+)): (?P<path>[^:]+): (?P<msg>.+)$")

# a small valid workflow; line numbers below refer to this text
BLOCK = """\
metadata:
  name: block
model:
  type: lattice_block
  dim: 2
  counts: [6, 6]
  diameter: 0.01
  material: rock
  groups:
    base: {side: ymin}
    top: {side: ymax}
materials:
  rock:
    rho: 2650.0
    kn: 2.0e7
    ks: 6.0e6
    xb: 2.0e-6
    fs0: 20.0
    mu: 0.4
simulation:
  dt_fraction: 0.02
steps:
  - kind: fix
    group: base
  - kind: run
    nsteps: 100
"""


def write(tmp_path, text, name="wf.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def validate(path, *extra):
    return runner.invoke(app, ["validate", str(path), *extra])


def error_lines(res):
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert lines, res.output
    parsed = []
    for ln in lines:
        m = LINE.match(ln)
        assert m, f"not FILE:LINE: path: message: {ln!r}"
        d = m.groupdict()
        d["file"] = d["file"].rsplit(":", 1)[0] if d["line"] else d["file"]
        parsed.append(d)
    return parsed


def one_error(res, path=None):
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    errs = error_lines(res)
    if path is not None:
        errs = [e for e in errs if e["path"] == path]
        assert errs, f"no error at {path}: {res.stderr}"
    return errs[0]


# ------------------------------------------------------------------ schema and files
def test_committed_schema_is_current():
    committed = json.loads((ROOT / "docs" / "geodem.schema.json").read_text())
    assert committed == wschema.json_schema(), \
        "docs/geodem.schema.json is stale: run `geodem schema -o docs/geodem.schema.json`"


def test_schema_command_prints_the_schema():
    res = runner.invoke(app, ["schema"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["additionalProperties"] is False
    kinds = data["properties"]["steps"]["items"]["discriminator"]["mapping"]
    assert {"run", "balance", "two_balls_check"} <= set(kinds)
    assert data["$defs"]["TwoBalls"]["properties"]["diameter"]["unit"] == "m"


@pytest.mark.parametrize("wf", sorted((ROOT / "workflows").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_workflows_pass_the_json_schema(wf):
    """What an editor sees: the committed JSON schema accepts the shipped workflows."""
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((ROOT / "docs" / "geodem.schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    data = load_document(wf).data
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(data)) == []
    data["model"]["colour"] = "red"
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(data))


def test_valid_block(tmp_path):
    res = validate(write(tmp_path, BLOCK))
    assert res.exit_code == 0, res.output
    assert "36 elements" in res.stdout and "101 time steps" not in res.stdout


# ------------------------------------------------------------------ bad input, one per kind
def test_unknown_key(tmp_path):
    p = write(tmp_path, BLOCK.replace("  diameter: 0.01", "  diameter: 0.01\n  diamter: 0.02"))
    e = one_error(validate(p))
    assert e["file"] == str(p) and e["line"] == "8" and e["path"] == "model.diamter"
    assert "unknown key 'diamter'" in e["msg"] and "allowed keys: type, dim, counts" in e["msg"]


def test_unknown_key_in_a_step_and_at_the_top(tmp_path):
    p = write(tmp_path, BLOCK.replace("    nsteps: 100", "    nsteps: 100\n    speed: 3")
              + "colour: red\n")
    res = validate(p)
    e = one_error(res, "steps[1].speed")
    assert e["line"] == "27" and "allowed keys: kind, name, nsteps, duration" in e["msg"]
    e = one_error(res, "colour")
    assert e["line"] == "28" and "allowed keys: version, metadata" in e["msg"]


@pytest.mark.parametrize("text,line,path,words", [
    ("    nsteps: many", "26", "steps[1].nsteps", ["valid integer", "got 'many'",
                                                  "allowed: a whole number >= 1"]),
    ("    nsteps: 2.5", "26", "steps[1].nsteps", ["valid integer", "got 2.5"]),
    ("    nsteps: true", "26", "steps[1].nsteps", ["valid integer", "got True"]),
])
def test_wrong_types(tmp_path, text, line, path, words):
    e = one_error(validate(write(tmp_path, BLOCK.replace("    nsteps: 100", text))))
    assert (e["line"], e["path"]) == (line, path)
    for w in words:
        assert w in e["msg"]


def test_wrong_type_of_a_float(tmp_path):
    e = one_error(validate(write(tmp_path, BLOCK.replace("kn: 2.0e7", "kn: stiff"))))
    assert (e["line"], e["path"]) == ("15", "materials.rock.kn")
    assert "valid number" in e["msg"] and "allowed: a number > 0 [N/m]" in e["msg"]


def test_numbers_in_exponent_form_are_numbers(tmp_path):
    p = write(tmp_path, BLOCK.replace("kn: 2.0e7", "kn: 2e7").replace("nsteps: 100",
                                                                      "nsteps: 1e2"))
    res = validate(p)
    assert res.exit_code == 0, res.output
    assert "100 time steps" in res.stdout


def test_missing_workflow_file(tmp_path):
    res = validate(tmp_path / "nothere.yaml")
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "file not found" in res.stderr and "nothere.yaml" in res.stderr


def test_missing_material_file(tmp_path):
    text = BLOCK.replace("""  rock:
    rho: 2650.0""", """  rock:
    file: granite.yaml
  other:
    rho: 2650.0""")
    e = one_error(validate(write(tmp_path, text)))
    assert (e["line"], e["path"]) == ("14", "materials.rock.file")
    assert "file not found" in e["msg"] and str(tmp_path / "granite.yaml") in e["msg"]


def test_material_file_included_and_its_errors_point_into_it(tmp_path):
    (tmp_path / "granite.yaml").write_text("rho: 2650.0\nkn: 2.0e7\nks: -6.0e6\n")
    text = BLOCK.replace("""  rock:
    rho: 2650.0
    kn: 2.0e7
    ks: 6.0e6
    xb: 2.0e-6
    fs0: 20.0
    mu: 0.4
""", "  rock: {file: granite.yaml}\n")
    e = one_error(validate(write(tmp_path, text)))
    assert e["file"] == str(tmp_path / "granite.yaml") and e["line"] == "3"
    assert e["path"] == "materials.rock.ks" and ">= 0 [N/m]" in e["msg"]
    (tmp_path / "granite.yaml").write_text("rho: 2650.0\nkn: 2.0e7\nks: 6.0e6\n")
    assert validate(tmp_path / "wf.yaml").exit_code == 0


@pytest.mark.parametrize("old,new,line,path,allowed", [
    ("diameter: 0.01", "diameter: 0", "7", "model.diameter", "a number > 0 [m]"),
    ("diameter: 0.01", "diameter: -0.01", "7", "model.diameter", "a number > 0 [m]"),
    ("counts: [6, 6]", "counts: [6, 0]", "6", "model.counts[1]", "a whole number >= 1"),
    ("nsteps: 100", "nsteps: 0", "26", "steps[1].nsteps", "a whole number >= 1"),
    ("dt_fraction: 0.02", "dt_fraction: -1", "21", "simulation.dt_fraction",
     "a number > 0 and <= 0.2"),
])
def test_zero_or_negative_sizes(tmp_path, old, new, line, path, allowed):
    e = one_error(validate(write(tmp_path, BLOCK.replace(old, new))))
    assert (e["line"], e["path"]) == (line, path)
    assert f"allowed: {allowed}" in e["msg"]


MACRO = """\
  rock:
    E: 5.0e10
    nu: 0.2
    Tu: 5.0e6
    Cu: 5.0e7
    mu_i: 0.6
    rho: 2650.0
"""


def macro_block(**change):
    text = MACRO
    for k, v in change.items():
        text = re.sub(rf"    {k}: .*", f"    {k}: {v}", text)
    block = BLOCK.replace("dim: 2", "dim: 3").replace("counts: [6, 6]", "counts: [4, 4, 4]")
    start = block.index("  rock:\n")
    end = block.index("simulation:")
    return block[:start] + text + block[end:]


@pytest.mark.parametrize("change,line,path,words", [
    ({"nu": 0.3}, "15", "materials.rock.nu", ["<= 0.2", "got 0.3", "-1 < nu <= 0.2"]),
    ({"mu_i": 0.2}, "18", "materials.rock.mu_i", [">= 0.353553", "19.47 deg"]),
    ({"E": -5.0e10}, "14", "materials.rock.E", ["a number > 0 [Pa]"]),
    ({"rho": 0}, "19", "materials.rock.rho", ["a number > 0 [kg/m^3]"]),
    ({"Cu": 1.0e6}, "13", "materials.rock", ["Cu = 1e+06 Pa must exceed", "Tu = 5e+06 Pa"]),
])
def test_non_physical_materials(tmp_path, change, line, path, words):
    p = write(tmp_path, macro_block(**change))
    e = one_error(validate(p))
    assert (e["line"], e["path"]) == (line, path), e
    for w in words:
        assert w in e["msg"]


def test_macro_material_valid_in_3d_refused_in_2d(tmp_path):
    p = write(tmp_path, macro_block())
    assert validate(p).exit_code == 0
    p.write_text(macro_block().replace("dim: 3", "dim: 2").replace("[4, 4, 4]", "[4, 4]"))
    e = one_error(validate(p))
    assert (e["line"], e["path"]) == ("8", "model.material")
    assert "3-D close-packed lattice only" in e["msg"]


def test_dt_above_the_stability_limit(tmp_path):
    p = write(tmp_path, BLOCK.replace("dt_fraction: 0.02", "dt: 1.0e-3"))
    e = one_error(validate(p))
    assert (e["line"], e["path"]) == ("21", "simulation.dt")
    assert "above the stability limit" in e["msg"] and "allowed: 0 < dt <" in e["msg"]


def test_model_too_large_for_memory(tmp_path):
    big = BLOCK.replace("dim: 2", "dim: 3").replace("counts: [6, 6]",
                                                    "counts: [1000, 1000, 1000]")
    big = big.replace(MACRO.split("\n")[0], MACRO.split("\n")[0])
    e = one_error(validate(write(tmp_path, big)))
    assert (e["line"], e["path"]) == ("6", "model.counts")
    assert "1,000,000,000 elements" in e["msg"] and "MemAvailable" in e["msg"]
    assert "allowed here: at most about" in e["msg"]


def test_unknown_and_missing_step_kind(tmp_path):
    p = write(tmp_path, BLOCK.replace("kind: run", "kind: runn").replace("  - kind: fix\n",
                                                                        "  - kid: fix\n"))
    res = validate(p)
    e = one_error(res, "steps[1]")
    assert e["line"] == "25" and "unknown kind 'runn'; allowed: balance, brazilian" in e["msg"]
    e = one_error(res, "steps[0]")
    assert e["line"] == "23" and "missing 'kind'" in e["msg"]


def test_cross_field_errors(tmp_path):
    text = BLOCK.replace("material: rock", "material: granite").replace(
        "group: base", "group: bottom")
    res = validate(write(tmp_path, text))
    assert one_error(res, "model.material")["msg"].startswith(
        "unknown material 'granite'; defined materials: rock")
    assert "the model's groups: all, base, top" in one_error(res, "steps[0].group")["msg"]


def test_duplicate_key_and_yaml_syntax(tmp_path):
    e = one_error(validate(write(tmp_path, BLOCK.replace("  dim: 2", "  dim: 2\n  dim: 3"))))
    assert (e["line"], e["path"]) == ("6", "model.dim") and "given twice" in e["msg"]
    e = one_error(validate(write(tmp_path, BLOCK.replace("counts: [6, 6]", "counts: [6, 6"))))
    assert e["line"] == "7" and e["path"] == "(YAML syntax)"


def test_several_errors_one_line_each_sorted(tmp_path):
    text = BLOCK.replace("diameter: 0.01", "diameter: zero").replace("nsteps: 100", "nsteps: -4")
    res = validate(write(tmp_path, text))
    errs = error_lines(res)
    assert [e["path"] for e in errs] == ["model.diameter", "steps[1].nsteps"]
    assert len(res.stderr.strip().splitlines()) == 2


# ------------------------------------------------------------------ --set
def test_set_overrides(tmp_path):
    p = write(tmp_path, BLOCK)
    res = validate(p, "--set", "steps.1.nsteps=250", "--set", "model.counts=[8, 8]")
    assert res.exit_code == 0, res.output
    assert "64 elements" in res.stdout and "250 time steps" in res.stdout
    res = validate(p, "--set", "steps.fix.group=top")  # a step addressed by its name
    assert res.exit_code == 0, res.output
    res = validate(p, "--set", "steps.1.nsteps=-3")
    e = one_error(res)
    assert e["file"].startswith("--set steps.1.nsteps=-3") and e["path"] == "steps[1].nsteps"
    res = validate(p, "--set", "steps.7.nsteps=3")
    assert res.exit_code == 2 and "no list item '7'" in res.stderr
    res = validate(p, "--set", "nokeyvalue")
    assert res.exit_code == 2 and "expected KEY=VALUE" in res.stderr


def test_verbose_shows_traceback(tmp_path):
    p = write(tmp_path, BLOCK.replace("diameter: 0.01", "diameter: 0"))
    res = runner.invoke(app, ["validate", str(p), "-v"])
    assert res.exit_code == 2 and "Traceback" in res.stderr


# ------------------------------------------------------------------ pieces
def test_error_item_format_and_paths():
    assert format_path(("steps", 0, "nsteps")) == "steps[0].nsteps"
    assert format_path(()) == "(top level)"
    assert ErrorItem("a.yaml", 3, "x.y", "bad").format() == "a.yaml:3: x.y: bad"
    err = WorkflowError([ErrorItem("a.yaml", 3, "x", "m1"), ErrorItem("a.yaml", None, "y", "m2")])
    assert err.lines() == ["a.yaml:3: x: m1", "a.yaml: y: m2"]


def test_document_locates_union_tags(tmp_path):
    doc = load_document(write(tmp_path, BLOCK))
    assert doc.locate(("steps", 1, "run", "nsteps"))[1:] == (26, ("steps", 1, "nsteps"))
    assert doc.locate(("model", "lattice_block", "sort"))[1:] == (3, ("model", "sort"))
    assert doc.locate(("materials", "rock", "micro"), keep_last=False)[1:] == \
        (13, ("materials", "rock"))


def test_a_union_tag_named_like_a_key_is_not_taken_for_it(tmp_path):
    # a library material's tag is "library", also a key of its mapping: pydantic's location of a
    # bad "use" is (materials, rock, library, use), which must point at "use", not "library"
    text = BLOCK.split("materials:")[0] + "materials:\n  rock: {library: sandstone, use: foo}\n" \
        + "simulation:" + BLOCK.split("simulation:")[1]
    p = write(tmp_path, text)
    e = one_error(validate(p))
    assert (e["line"], e["path"]) == ("13", "materials.rock.use") and "'lattice'" in e["msg"]
    e = one_error(validate(write(tmp_path, text.replace(", use: foo", "")), "--set",
                           "materials.rock.use=foo"))
    assert e["file"] == "--set materials.rock.use=foo" and e["path"] == "materials.rock.use"


@pytest.mark.parametrize("line, value, field", [("nsteps: 100", "nsteps: 1e15", "nsteps"),
                                                ("nsteps: 100", "duration: 1.0e+9", "duration")])
def test_a_step_too_long_to_run_is_refused(tmp_path, line, value, field):
    p = write(tmp_path, BLOCK.replace(line, value))
    e = one_error(validate(p))
    assert (e["line"], e["path"]) == ("26", f"steps[1].{field}")
    assert "allowed: at most 1e+12 per step" in e["msg"]
    assert one_error(validate(write(tmp_path, BLOCK), "--set", "steps.1.nsteps=1e13"))["file"] \
        == "--set steps.1.nsteps=1e13"


def test_time_steps_of_a_count_or_a_duration():
    from geodem.workflow.schema import time_steps

    assert time_steps(1e-3, nsteps=7) == 7
    assert time_steps(1e-3, duration=0.0105) == 11  # a partial step counts
    assert time_steps(0.1, duration=0.3) == 3  # 0.3 / 0.1 = 2.9999999999999996: not 4
    assert time_steps(1.0, duration=1e-9) == 1
