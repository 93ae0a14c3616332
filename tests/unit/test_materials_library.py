"""Material library: every file loads, every value has a source, conversion round-trips."""
import copy

import pytest

from geodem.materials import STRUCTURE_KEYS
import yaml

from geodem.materials import MU_I_MIN, micro_to_macro
from geodem.materials_library import (
    LIBRARY_DIR,
    PROPERTY_NAMES,
    Material,
    MaterialError,
    list_materials,
    load_material,
    to_micro,
)

REQUIRED = {"granite", "sandstone", "marble", "limestone", "mudstone", "stiff_clay"}


def test_library_lists_required_materials():
    assert REQUIRED <= set(list_materials())


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_file_loads_with_sources(name):
    m = load_material(name)
    assert m.name == name
    # calibrated: null until 'geodem calibrate --save'; then per dimension with the element keys
    for dim, block in (m.calibrated or {}).items():
        assert dim in ("2d", "3d")
        keys = {"kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2", "mu"}
        assert keys | {"packing"} <= set(block["element"]) <= keys | set(STRUCTURE_KEYS)
        # the recipe the calibration was made on, stored with it (every test builds it)
        assert block["element"]["packing"] == block["specimen"]["packing"] == "isotropic"
        # a calibration with the friction test measured phi too (the 2-D library's)
        friction = block["specimen"].get("friction_test") is not None
        assert set(block["measured"]) == {"E", "nu", "Tu", "Cu"} | ({"phi"} if friction else set())
        if friction:
            assert abs(block["measured"]["phi"] - block["friction_test"]["target_phi"]) <= 2.0
    for k in PROPERTY_NAMES:
        s = getattr(m.properties, k).source
        assert s.author.strip() and s.title.strip() and s.what.strip()
        assert 1900 < s.year < 2030
    v = m.values()
    assert 0 < v["Tu"] < v["Cu"] and v["E"] > 0 and v["rho"] > 0 and v["mu_i"] > 0
    if v["nu"] > 0.2:  # the lattice limit must be said in the file
        assert any("0.2" in n and "lattice" in n for n in m.notes)
    assert load_material(LIBRARY_DIR / f"{name}.yaml") == m  # explicit path


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_to_micro_round_trip(name):
    d = 0.01
    r = to_micro(name, d)
    back = micro_to_macro(r.micro.Kn, r.micro.Ks, r.micro.Xb, r.micro.Fs0, r.micro.mu_p, d)
    for k in ("E", "nu", "Tu", "Cu", "mu_i"):
        assert back[k] == pytest.approx(r.used[k], rel=1e-9, abs=1e-12)
    for k in PROPERTY_NAMES:
        if k not in r.clamped:
            assert r.used[k] == r.target[k]
    assert ("nu" in r.clamped) == (r.target["nu"] > 0.2)
    assert len(r.warnings) == len(r.clamped)


def _doc(name="granite"):
    return yaml.safe_load((LIBRARY_DIR / f"{name}.yaml").read_text())


def _write(tmp_path, doc, fname="bad.yaml"):
    p = tmp_path / fname
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def test_clamping_recorded(tmp_path):
    doc = _doc()
    doc["name"] = "lowfric"
    doc["properties"]["mu_i"]["value"] = 0.2
    r = to_micro(load_material(_write(tmp_path, doc, "lowfric.yaml")), 0.02)
    assert r.clamped == ("nu", "mu_i")
    assert r.used["nu"] == 0.2 and r.used["mu_i"] == MU_I_MIN
    assert r.target["nu"] == 0.25 and r.target["mu_i"] == 0.2
    assert "nu = 0.25" in r.warnings[0] and "mu_i = 0.2" in r.warnings[1]
    assert r.micro.mu_p == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("field,value,match", [
    ("E", -1.0, r"properties\.E: value -1\.0 out of range; allowed: E > 0"),
    ("rho", 0.0, r"properties\.rho: .* allowed: rho > 0"),
    ("nu", 0.5, r"properties\.nu: .* allowed: -1 < nu < 0\.5"),
    ("nu", -1.0, r"properties\.nu: .* allowed: -1 < nu < 0\.5"),
    ("mu_i", 0.0, r"properties\.mu_i: .* allowed: mu_i = tan\(phi\) > 0"),
    ("Tu", 3e8, r"properties: .*Tu = 3e\+08 Pa must be below Cu .*allowed: 0 < Tu < Cu"),
    ("Cu", -5.0, r"properties\.Cu: .* allowed: Cu > 0"),
])
def test_errors_name_file_field_range(tmp_path, field, value, match):
    doc = _doc()
    doc["properties"][field]["value"] = value
    p = _write(tmp_path, doc)
    with pytest.raises(MaterialError, match=match) as ei:
        load_material(p)
    assert str(p) in str(ei.value)


def test_other_errors(tmp_path):
    doc = _doc()
    doc["colour"] = "grey"
    with pytest.raises(MaterialError, match=r"bad\.yaml: colour: unknown field"):
        load_material(_write(tmp_path, doc))
    doc = _doc()
    del doc["properties"]["Tu"]["source"]
    with pytest.raises(MaterialError, match=r"properties\.Tu\.source: Field required"):
        load_material(_write(tmp_path, doc))
    doc = _doc()
    doc["properties"]["E"]["unit"] = "GPa"
    with pytest.raises(MaterialError, match=r"E\.unit = 'GPa'; allowed: 'Pa'"):
        load_material(_write(tmp_path, doc))
    with pytest.raises(MaterialError, match=r"'basalt' not found .* available: .*granite"):
        load_material("basalt")
    with pytest.raises(MaterialError, match=r"nope\.yaml: material file not found"):
        load_material(tmp_path / "nope.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(MaterialError, match=r"list\.yaml: a material file holds a mapping"):
        load_material(tmp_path / "list.yaml")
    with pytest.raises(ValueError, match=r"d = 0"):
        to_micro("granite", 0.0)


def test_model_forbids_extra_in_nested():
    doc = _doc()
    bad = copy.deepcopy(doc)
    bad["properties"]["E"]["source"]["doi"] = "x"
    with pytest.raises(Exception, match="doi"):
        Material.model_validate(bad)
    assert Material.model_validate(doc).name == "granite"


def test_calibration_table_by_hand(tmp_path):
    """`geodem library --markdown`: each stored value beside its error against the lab value,
    relative for E, Cu, Tu and absolute for nu; a material without a record says so."""
    from geodem.materials_library import calibration_markdown, calibration_rows

    doc = _doc("sandstone")
    rec = doc["calibrated"]["2d"]
    rec.update(measured={"E": 15.3e9, "nu": 0.185, "Cu": 72.0e6, "Tu": 4.2e6},
               converged=True, iterations=4, best_iteration=3,
               brazilian={"tensile_strength": 4.4e6, "over_target": 1.1,
                          "crack_start_offset": 0.8},
               run={"date": "2026-12-04", "wall_time_s": 45.0, "threads": 1})
    rec["specimen"]["fit"] = "elastic"
    for k in ("rotation", "bond_moment", "rolling_friction", "rolling_stiffness",
              "disc_diameter"):  # a translating record without its disc
        rec["specimen"].pop(k, None)
    done = _write(tmp_path, doc, "done.yaml")
    bare = copy.deepcopy(doc)
    bare["name"], bare["calibrated"] = "bare", None
    bare = _write(tmp_path, bare, "bare.yaml")
    rows = calibration_rows(2, [done, bare])
    e = rows[0]["errors"]
    assert e["E"] == pytest.approx(0.02) and e["Cu"] == pytest.approx(-0.04)
    assert e["Tu"] == pytest.approx(0.05) and e["nu"] == pytest.approx(-0.015)
    assert rows[1]["record"] is None
    text = calibration_markdown(2, [done, bare])
    assert ("| sandstone (15 GPa, 0.2, 75 MPa, 4 MPa, 35 deg) | translating | 3 of 4 "
            "(converged) | 15.3 GPa (+2.0 %) | 0.185 (-0.015) | 72 MPa (-4.0 %) | 4.2 MPa "
            "(+5.0 %) | not matched | 1.10") in text
    assert "2026-12-04, 45 s on 1 thread |" in text
    rec["run"].update(check_wall_time_s=20.0, jobs=1)  # a record that times its disc check
    assert "2026-12-04, 45 s on 1 thread (disc check 20 s) |" in calibration_markdown(
        2, [_write(tmp_path, doc, "timed.yaml")])
    assert "| bare (15 GPa, 0.2, 75 MPa, 4 MPa, 35 deg) | no 2-D calibration |" in text
    # a turning rock that matched its friction angle, checked on a disc 40 elements across
    rec["measured"]["phi"] = 36.2
    rec["specimen"].update(rotation=True, bond_moment=100.0, rolling_stiffness=2.0,
                           d_mean=0.005, disc_diameter=0.2)
    done = _write(tmp_path, doc, "done.yaml")
    text = calibration_markdown(2, [done])
    assert ("| turning (bond moment 100, rolling stiffness 2) | 3 of 4 (converged) |" in text)
    assert "| 36.2 deg (+1.2) | 1.10, 40 across |" in text
    del rec["brazilian"]  # calibrated with --no-check
    text = calibration_markdown(2, [_write(tmp_path, doc, "unchecked.yaml")])
    assert "| 36.2 deg (+1.2) | not checked |" in text
