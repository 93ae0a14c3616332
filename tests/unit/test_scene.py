"""Model ``scene``: a domain filled with a close-packed lattice, materials by ordered regions,
joints across regions and groups; counts checked by hand on tiny scenes."""
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from geodem.core.state import BONDED
from geodem.workflow.errors import WorkflowError
from geodem.workflow.schema import validate_document
from geodem.workflow.yamlio import load_document

ROCK = {"rho": 2650, "kn": 2.0e7, "ks": 6.0e6, "xb": 2.0e-6, "fs0": 20.0, "mu": 0.4}
CLAY = {"rho": 2000, "kn": 1.0e7, "ks": 3.0e6, "xb": 1.0e-6, "fs0": 10.0, "mu": 0.3}


def _cfg(**model):
    doc = {"metadata": {"name": "scene"},
           "model": dict({"type": "scene", "dim": 2, "d": 0.02, "material": "rock",
                          "domain": {"box": {"min": [0.0, 0.0], "max": [0.6, 0.3]}}}, **model),
           "materials": {"rock": ROCK, "clay": CLAY},
           "steps": [{"kind": "run", "nsteps": 1}]}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return validate_document(load_document(path))


def _build(**model):
    cfg = _cfg(**model)
    return cfg.model.build(cfg)


def test_a_box_holds_the_lattice_counted_by_hand():
    # centres from d/2 to 0.6 - d/2: 30 per even row, 29 per odd row (offset d/2); rows
    # every d sqrt(3)/2 from d/2 to 0.3 - d/2: floor(0.28 / 0.01732) + 1 = 17 rows
    st = _build().state
    assert st.n == 9 * 30 + 8 * 29
    r = 0.01
    assert st.x[:, 0].min() == pytest.approx(r) and st.x[:, 1].min() == pytest.approx(r)
    assert st.x[:, 0].max() <= 0.6 - r + 1e-12 and st.x[:, 1].max() <= 0.3 - r + 1e-12


def test_later_regions_override_earlier_ones_and_carry_their_material():
    built = _build(regions=[
        {"name": "low", "material": "clay", "shape": {"below": 0.1}},
        {"name": "plug", "material": "rock", "shape": {"disc": {"center": [0.3, 0.05],
                                                                "radius": 0.05}}}])
    st = built.state
    kn = st.kn
    clay = (st.x[:, 1] < 0.1) & (np.hypot(st.x[:, 0] - 0.3, st.x[:, 1] - 0.05) > 0.05)
    assert np.allclose(kn[clay], CLAY["kn"]) and np.allclose(kn[~clay], ROCK["kn"])
    assert built.info["elements_by_region"]["low"] == int(clay.sum())


def _bonds(st):
    i = np.repeat(np.arange(st.n), st.nbr.shape[1]).reshape(st.nbr.shape)
    ok = (st.nbr >= 0) & (st.cstate == BONDED)
    return i[ok], st.nbr[ok]


def test_a_joint_cuts_exactly_the_bonds_across_two_regions():
    regions = [{"name": "low", "material": "clay", "shape": {"below": 0.1}}]
    whole = _build(regions=regions).state
    joint = _build(regions=regions, interfaces="joint")
    i, j = _bonds(whole)
    low = whole.x[:, 1] < 0.1
    across = int((low[i] != low[j]).sum()) // 2
    assert across > 0 and joint.info["joint_bonds_cut"] == across
    i2, j2 = _bonds(joint.state)
    low2 = joint.state.x[:, 1] < 0.1
    assert not np.any(low2[i2] != low2[j2])
    assert len(i2) // 2 == len(i) // 2 - across


def test_groups_by_side_region_and_box():
    from geodem.core.groups import members

    built = _build(regions=[{"name": "low", "material": "clay", "shape": {"below": 0.1}}],
                   groups={"low": {"region": "low"}, "base": {"side": "ymin"},
                           "corner": {"box": {"min": [0.0, 0.2], "max": [0.1, 0.3]}}})
    st = built.state
    base = members(st, "base")
    assert len(base) == 30 and np.allclose(st.x[base, 1], 0.01)
    # the last group that selects an element wins: the base row left 'low' for 'base'
    low = members(st, "low")
    assert np.all(st.x[low, 1] < 0.1) and np.all(st.x[low, 1] > 0.011)
    corner = members(st, "corner")
    assert np.all(st.x[corner, 0] <= 0.1) and np.all(st.x[corner, 1] >= 0.2)


def test_a_polygon_domain_keeps_the_centres_inside():
    tri = [[0.0, 0.0], [0.6, 0.0], [0.0, 0.3]]
    st = _build(domain={"polygon": tri}).state
    x, y = st.x[:, 0], st.x[:, 1]
    assert np.all(x / 0.6 + y / 0.3 <= 1.0 + 1e-9)
    assert 0.4 * 252 < st.n < 0.6 * 502  # about half the box's 502


def test_a_3d_box_is_an_fcc_block():
    st = _build(dim=3, d=0.05, domain={"box": {"min": [0, 0, 0], "max": [0.3, 0.3, 0.3]}}).state
    # interior elements touch 12 others: the most bonds any element has
    i, _ = _bonds(st)
    assert np.bincount(i, minlength=st.n).max() == 12


@pytest.mark.parametrize("model, where", [
    ({"domain": {"below": 0.1}}, "domain"),
    ({"regions": [{"material": "nope", "shape": {"below": 0.1}}]}, "nope"),
    ({"groups": {"g": {"region": "missing"}}}, "missing"),
    ({"domain": {"box": {"min": [0, 0], "max": [0.01, 0.3]}}}, "thinner"),
    ({"regions": [{"material": "clay", "shape": {"polygon": [[0, 0], [1, 1]]}}]}, "polygon"),
])
def test_bad_scenes_are_refused_with_the_field(model, where):
    with pytest.raises(WorkflowError) as exc:
        _cfg(**model)
    assert where in str(exc.value)


# ============================================================================ label images
RED, BLUE, WHITE = (200, 30, 30), (30, 30, 200), (255, 255, 255)


def _section_png(folder: Path) -> Path:
    """6 x 3 pixels of 0.1 m over the 0.6 x 0.3 m box: a red upper layer (rows 0-1 from the top)
    with a white (empty) window at columns 2-3 of row 1, on a blue lower layer (row 2)."""
    from PIL import Image

    px = np.zeros((3, 6, 3), np.uint8)
    px[:2] = RED
    px[1, 2:4] = WHITE
    px[2] = BLUE
    path = folder / "section.png"
    Image.fromarray(px).save(path)
    return path


def test_an_image_gives_regions_by_colour_and_empty_pixels_hold_no_element(tmp_path):
    png = _section_png(tmp_path)
    image = {"file": str(png), "pixel_size": 0.1, "origin": [0.0, 0.0],
             "colours": {"upper": {"material": "rock", "colour": list(RED)},
                         "lower": {"material": "clay", "colour": "#1e1ec8"}},
             "empty": ["#ffffff"]}
    full = _build().state
    built = _build(regions=[{"image": image}], groups={"low": {"region": "lower"}})
    st = built.state
    x = full.x
    window = (x[:, 1] >= 0.1) & (x[:, 1] < 0.2) & (x[:, 0] >= 0.2) & (x[:, 0] < 0.4)
    lower = x[:, 1] < 0.1
    assert st.n == full.n - int(window.sum()) and window.sum() > 0
    assert built.info["elements_by_region"] == {"default": 0, "upper": int((~window & ~lower).sum()),
                                                 "lower": int(lower.sum())}
    low = st.x[:, 1] < 0.1
    assert np.allclose(st.kn[low], CLAY["kn"]) and np.allclose(st.kn[~low], ROCK["kn"])
    from geodem.core import groups
    assert len(groups.members(st, "low")) == lower.sum()


def test_an_image_with_an_unmapped_colour_or_missing_file_is_refused(tmp_path):
    png = _section_png(tmp_path)
    image = {"file": str(png), "pixel_size": 0.1,
             "colours": {"upper": {"material": "rock", "colour": list(RED)}}}
    with pytest.raises(WorkflowError) as e:
        _cfg(regions=[{"image": image}])
    assert "regions[0].image.file" in str(e.value) and "#1e1ec8" in str(e.value)
    with pytest.raises(WorkflowError) as e:
        _cfg(regions=[{"image": dict(image, file=str(tmp_path / "none.png"))}])
    assert "regions[0].image.file" in str(e.value) and "image not found" in str(e.value)
    with pytest.raises(WorkflowError) as e:
        _cfg(regions=[{"image": image, "material": "rock"}])
    assert "image.colours" in str(e.value)


# ============================================================================ terrain, band, random
HILL = str(Path(__file__).resolve().parents[2] / "workflows" / "data" / "hill.tif")


def test_a_terrain_domain_is_the_ground_under_the_raster():
    from geodem.geo import read_elevation
    from geodem.geo.terrain import surface_function

    line = [[0.0, 150.0], [600.0, 150.0]]
    cfg = _cfg(d=10.0, domain={"terrain": {"raster": HILL, "line": line, "base_depth": 20.0}},
               groups={"base": {"side": "ymin"}})
    st = cfg.model.build(cfg).state
    ground = surface_function(read_elevation(HILL))
    s, z = st.x[:, 0], st.x[:, 1]
    top = ground(np.c_[s, np.full(len(s), 150.0)])
    assert st.n == cfg.model.n_elements() > 0
    assert np.all(z <= top + 1e-6)                     # under the ground
    assert z.min() == pytest.approx(400.1 - 20.0 + 5.0, abs=5.0)  # the base: 20 m below the valley
    assert s.min() >= 0.0 and s.max() <= 600.0


def test_a_band_selects_centres_within_half_its_thickness_of_a_plane():
    n = np.array([0.6, 0.8])
    built = _build(regions=[{"name": "weak", "material": "clay",
                             "shape": {"band": {"point": [0.3, 0.15], "normal": n.tolist(),
                                                "thickness": 0.05}}}])
    st = built.state
    inside = np.abs((st.x - [0.3, 0.15]) @ n) <= 0.025
    assert np.allclose(st.kn[inside], CLAY["kn"]) and np.allclose(st.kn[~inside], ROCK["kn"])
    assert built.info["elements_by_region"]["weak"] == int(inside.sum()) > 10


def test_a_random_fill_lies_inside_the_box_and_repeats_for_its_seed():
    a = _build(fill="random").state
    b = _build(fill="random").state
    r = a.r
    assert np.array_equal(a.x, b.x)
    assert np.all(a.x - r[:, None] >= -1e-9) and np.all(a.x + r[:, None] <= [0.6 + 1e-9, 0.3 + 1e-9])
    assert r.max() / r.min() <= 1.2 / 0.8 + 1e-9     # distri_rate 0.2
    assert 0.7 * 9 * 30 + 8 * 29 * 0.7 < a.n          # most of the lattice's count


def test_terrain_inputs_are_checked():
    with pytest.raises(WorkflowError) as e:
        _cfg(d=10.0, domain={"terrain": {"raster": "nothing.tif"}})
    assert "raster not found" in str(e.value) and "domain.terrain.raster" in str(e.value)
    with pytest.raises(WorkflowError) as e:
        _cfg(d=10.0, domain={"terrain": {"raster": HILL, "extent": [0, 0, 100, 100]}})
    assert "give line, not extent" in str(e.value)
