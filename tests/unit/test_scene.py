"""Model ``scene``: a domain filled with a close-packed lattice, materials by ordered regions,
joints across regions and groups; counts checked by hand on tiny scenes."""
import math
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
           "materials": {"rock": ROCK, "clay": CLAY, "sand": {"library": "sandstone"}},
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


def test_a_disc_domain_keeps_the_centres_inside():
    st = _build(domain={"disc": {"center": [0.3, 0.3], "radius": 0.15}}).state
    r = np.linalg.norm(st.x - [0.3, 0.3], axis=1)
    assert r.max() <= 0.15 + 1e-9 and r.max() > 0.15 - 0.02  # filled to its rim
    # the lattice's areal density 2 / (sqrt 3 d^2) over pi R^2: 204 elements
    assert st.n == pytest.approx(math.pi * 0.15 ** 2 * 2 / (math.sqrt(3) * 0.02 ** 2), rel=0.05)


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
    ({"regions": [{"material": "clay", "empty": True, "shape": {"below": 0.1}}]},
     "needs a material, or empty: true"),
    ({"regions": [{"name": "cave", "empty": True, "shape": {"below": 0.1}}],
      "groups": {"g": {"region": "cave"}}}, "groups.g.region: region 'cave' is empty"),
    ({"groups": {"g": {"side": ["xmin", "zmax"]}}}, "groups.g.side: side 'zmax' does not exist"),
    ({"groups": {"g": {"shape": {"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}}}},
     "groups.g.shape.box.min: 2 coordinates needed"),
    ({"groups": {"g": {"side": "xmin", "shape": {"below": 0.1}}}},
     "exactly one of side, region, box or shape"),
    ({"fill": "specimen", "material": "sand",
      "regions": [{"name": "soft", "material": "clay", "shape": {"below": 0.1}}]},
     "regions[0].material: a specimen fill cements one material"),
    ({"fill": "specimen", "d": 10.0, "material": "sand",
      "domain": {"terrain": {"raster": "workflows/data/hill.tif"}}},
     "fill: a specimen fill packs a box, a polygon or a disc domain; allowed for a terrain"),
    ({"dim": 3, "domain": {"disc": {"center": [0.3, 0.3, 0.3], "radius": 0.1}}},
     "domain: the domain is a box, a polygon or a disc (2-D), a prism (3-D) or a terrain"),
    ({"domain": {"union": [{"box": {"min": [0, 0], "max": [0.3, 0.3]}}]}},
     "domain: the domain is a box"),
    ({"regions": [{"material": "clay", "shape": {"prism": {
        "polygon": [[0, 0], [1, 0], [0, 1]], "range": [0, 1]}}}]},
     "regions[0].shape.prism: a prism is 3-D only"),
    ({"regions": [{"material": "clay", "shape": {"half_space": {
        "point": [0, 0], "normal": [0, 0]}}}]}, "half_space.normal: the normal is zero"),
    ({"regions": [{"material": "clay", "shape": {"difference": [{"below": 0.1}]}}]},
     "difference"),
    ({"regions": [{"material": "clay", "shape": {"union": [
        {"below": 0.1}, {"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}]}}]},
     "regions[0].shape.union[1].box.min: 2 coordinates needed"),
    ({"regions": [{"material": "clay", "shape": {"union": [
        {"below": 0.1}, {"terrain": {"raster": "workflows/data/hill.tif"}}]}}]},
     "a terrain is a domain, not a part of a combination"),
    ({"regions": [{"material": "clay", "shape": {"raster_mask": {
        "raster": "workflows/data/hill.tif"}}}]}, "a raster mask lies on a terrain"),
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


SLIP = str(Path(HILL).with_name("hill_slip_depth.tif"))
LINE = [[0.0, 150.0], [600.0, 150.0]]


def _terrain_scene(d, regions, **more):
    cfg = _cfg(d=d, domain={"terrain": {"raster": HILL, "line": LINE, "base_depth": 10.0}},
               regions=regions, **more)
    return cfg.model.build(cfg)


def test_a_depth_raster_region_is_the_slide_above_the_sliding_surface():
    """The region above a raster of depths below the ground is the terrain model's slide mask
    (geodem.geo.terrain_model with that sliding surface), element for element."""
    from geodem.geo import read_elevation, terrain_model
    from geodem.geo.terrain import Depth

    built = _terrain_scene(6.0, [{"name": "slide", "material": "clay",
                                  "shape": {"surface": {"depth_raster": SLIP}}}])
    st = built.state
    top = read_elevation(HILL)
    tm = terrain_model(top, 6.0, base_depth=10.0, dim=2, body="ground", line=LINE,
                       sliding_surface=Depth(read_elevation(SLIP, like=top)))
    want = {tuple(np.round(v, 6)) for v in tm.x[tm.masks["slide"]]}
    got = {tuple(np.round(v, 6)) for v in st.x[np.isclose(st.kn, CLAY["kn"])]}
    assert got == want and len(want) == 59
    assert built.info["elements_by_region"]["slide"] == 59


def test_a_constant_depth_and_an_elevation_raster_split_the_ground_into_layers(tmp_path):
    """``depth: 7``: centres less than 7 m below the ground above the hill's profile; an
    elevation raster 20 m under the ground (written here on the hill's grid): centres below
    it; counted by hand from the ground's elevation along the section."""
    import rasterio

    from geodem.geo import read_elevation
    from geodem.geo.terrain import plan_xy

    lower = tmp_path / "lower.tif"
    with rasterio.open(HILL) as src:
        prof = src.profile
        lower_z = src.read(1) - 20.0
    with rasterio.open(lower, "w", **prof) as dst:
        dst.write(lower_z, 1)
    built = _terrain_scene(10.0, [
        {"name": "deep", "material": "clay", "shape": {"surface": {"raster": str(lower),
                                                                    "side": "below"}}},
        {"name": "soil", "material": "sand", "shape": {"surface": {"depth": 7.0}}}])
    st = built.state
    ground = read_elevation(HILL).elevation(plan_xy(st.x, LINE))
    soil = st.x[:, 1] > ground - 7.0
    deep = (st.x[:, 1] < ground - 20.0) & ~soil
    counts = built.info["elements_by_region"]
    assert counts["soil"] == int(soil.sum()) > 20
    assert counts["deep"] == int(deep.sum()) > 100
    assert counts["default"] == st.n - counts["soil"] - counts["deep"] > 20


def test_surface_shapes_are_checked():
    with pytest.raises(WorkflowError) as e:
        _cfg(regions=[{"name": "a", "material": "clay", "shape": {"surface": {"depth": 1.0}}}])
    assert "model.regions[0].shape.surface" in str(e.value) and "terrain" in str(e.value)
    with pytest.raises(WorkflowError) as e:
        _cfg(d=10.0, domain={"terrain": {"raster": HILL, "line": LINE}},
             groups={"g": {"shape": {"surface": {"depth_raster": "none.tif"}}}})
    assert "model.groups.g.shape.surface.depth_raster" in str(e.value)
    assert "raster not found: none.tif" in str(e.value)
    with pytest.raises(WorkflowError) as e:
        _cfg(regions=[{"name": "a", "material": "clay",
                       "shape": {"surface": {"depth": 1.0, "raster": HILL}}}])
    assert "exactly one of raster, depth, depth_raster" in str(e.value)


# ============================================================================ specimen fill, holes
SAND = {"fill": "specimen", "material": "sand", "d": 0.004,
        "domain": {"box": {"min": [0.1, 0.2], "max": [0.16, 0.26]}}}


def _bond_counts(st):
    return ((st.nbr >= 0) & (st.cstate == BONDED)).sum(axis=1)


def test_a_specimen_fill_is_the_materials_own_packing_cut_by_the_domain():
    """The library sandstone's 2-D calibration (isotropic packing) in a 6 x 6 cm box at
    d = 4 mm: about 0.84 x 36 cm^2 / (pi 4 mm^2) = 240 elements, 4 bonds per interior element
    (docs/thermal.md: 4.02), each with the calibrated element parameters at its size."""
    from geodem.materials_library import load_material

    built = _build(**SAND)
    st = built.state
    lo, hi = np.array([0.1, 0.2]), np.array([0.16, 0.26])
    tol = 1e-4 * 0.004  # the packing's flat faces move by ~1e-5 d as the cement balances
    assert np.all(st.x - st.r[:, None] >= lo - tol) and np.all(st.x + st.r[:, None] <= hi + tol)
    fraction = float(np.pi * (st.r ** 2).sum()) / 0.06 ** 2
    assert 0.78 < fraction < 0.9 and 200 < st.n < 280
    assert built.info["specimen_report"]["interior_coordination"] == pytest.approx(4.0, abs=0.3)
    assert 3.3 < 2.0 * _bond_counts(st).sum() / 2 / st.n < 4.2
    el = load_material("sandstone").calibrated["2d"]["element"]
    assert np.allclose(st.kn, el["kn_per_d"] * 2 * st.r, rtol=1e-12)
    assert np.allclose(st.mu, el["mu"])
    assert 0.8 <= st.r.min() / 0.002 and st.r.max() / 0.002 <= 1.2 + 1e-9  # distri_rate 0.2
    again = _build(**SAND).state
    assert np.array_equal(again.x, st.x)                      # the seed repeats it


def test_a_specimen_fill_of_a_polygon_keeps_the_centres_inside():
    tri = [[0.1, 0.2], [0.16, 0.2], [0.1, 0.26]]
    built = _build(**dict(SAND, domain={"polygon": tri}))
    st = built.state
    assert np.all((st.x[:, 0] - 0.1) + (st.x[:, 1] - 0.2) <= 0.06 + 1e-9)
    assert built.info["elements_removed"] > 80 and 80 < st.n < 150   # about half of 229
    assert _bond_counts(st).min() >= 2


def test_a_specimen_fill_follows_the_seed():
    a = _build(**SAND).state
    cfg = _cfg(**SAND)
    cfg.metadata.seed = 7
    b = cfg.model.build(cfg).state
    assert a.n != b.n or not np.allclose(a.x, b.x)


def test_an_empty_region_is_a_hole_without_loose_elements():
    """A 12 mm hole in the specimen fill: the same packing as without it, the elements with
    centres in the hole removed (counted), then the ones left with fewer than 2 bonds."""
    hole = {"name": "hole", "empty": True,
            "shape": {"disc": {"center": [0.13, 0.23], "radius": 0.012}}}
    full = _build(**SAND)
    built = _build(**SAND, regions=[hole])
    st, info = built.state, built.info
    c = np.array([0.13, 0.23])
    inside = np.linalg.norm(full.state.x - c, axis=1) <= 0.012
    assert info["elements_removed"] == int(inside.sum()) > 20   # pi 12^2 / (pi 2^2) x 0.84 = 30
    packed = full.state.n + full.info["loose_removed"]  # the packing before any removal
    assert st.n == packed - info["elements_removed"] - info["loose_removed"]
    assert full.info["elements_removed"] == 0 and _bond_counts(full.state).min() >= 2
    assert np.linalg.norm(st.x - c, axis=1).min() > 0.012       # no centre in the hole
    assert _bond_counts(st).min() >= 2
    assert "hole" not in info["elements_by_region"]


def test_an_empty_region_on_the_lattice_removes_the_centres_inside():
    hole = {"name": "hole", "empty": True,
            "shape": {"box": {"min": [0.2, 0.0], "max": [0.4, 0.1]}}}
    full = _build().state
    built = _build(regions=[hole])
    cut = (full.x[:, 0] >= 0.2) & (full.x[:, 0] <= 0.4) & (full.x[:, 1] <= 0.1)
    assert built.state.n == full.n - int(cut.sum()) and built.info["elements_removed"] == cut.sum()
    # a later region overrides an empty one: a plug refills part of the hole
    plug = {"name": "plug", "material": "clay",
            "shape": {"box": {"min": [0.2, 0.0], "max": [0.3, 0.1]}}}
    refilled = _build(regions=[hole, plug])
    assert refilled.info["elements_by_region"]["plug"] > 0
    assert refilled.state.n == full.n - refilled.info["elements_removed"] > built.state.n


def test_groups_by_shape_and_by_a_list_of_sides_last_one_wins():
    """The heated borehole's groups on a lattice: everything, then the outer faces (1.2 d
    deep), then a disc that reaches the top and bottom rows; an element goes to the last group
    that selects it."""
    from geodem.core.groups import members

    ring = {"center": [0.3, 0.15], "radius": 0.14}
    built = _build(groups={"rock": {"shape": {"box": {"min": [0, 0], "max": [0.6, 0.3]}}},
                           "edge": {"side": ["xmin", "xmax", "ymin", "ymax"], "depth": 1.2},
                           "heater": {"shape": {"disc": ring}}})
    st = built.state
    x, y = st.x[:, 0], st.x[:, 1]
    in_ring = np.hypot(x - 0.3, y - 0.15) <= 0.14
    on_edge = (x <= 0.034) | (x >= 0.566) | (y <= 0.034) | (y >= 0.2631)
    # by hand: two rows at the bottom and two at the top (59 each), and in the 13 rows between
    # two columns at each side in the 7 even rows (x = 0.01, 0.03 / 0.57, 0.59), one in the 6
    # odd ones (0.02 / 0.58): 59 + 59 + 7 x 4 + 6 x 2 = 158
    assert int(on_edge.sum()) == 158
    heater, edge, rock = (set(members(st, g).tolist()) for g in ("heater", "edge", "rock"))
    assert heater == set(np.flatnonzero(in_ring).tolist()) and len(heater) > 100
    assert edge == set(np.flatnonzero(on_edge & ~in_ring).tolist())
    assert 0 < int((on_edge & in_ring).sum()) == 158 - len(edge)   # the disc won those
    assert rock == set(np.flatnonzero(~on_edge & ~in_ring).tolist())
    assert len(heater) + len(edge) + len(rock) == st.n


# ------------------------------------------------------------------ lattice origin, elastic
def _small(**model):
    """0.1 x 0.05 m, d = 0.02, lattice from the corner: rows at y = 0, 0.0173, 0.0346 (3);
    even rows x = 0 ... 0.1 (6), the odd row x = 0.01 ... 0.09 (5; 0.11 is outside)."""
    return _build(domain={"box": {"min": [0.0, 0.0], "max": [0.1, 0.05]}},
                  lattice_origin="corner", **model)


def test_a_lattice_from_the_corner_counted_by_hand():
    b = _small(half_mass=["xmin", "xmax"])
    st = b.state
    assert st.n == 6 + 5 + 6
    x = np.round(st.x / 0.01, 6)
    assert x[:, 0].min() == 0.0 and x[:, 0].max() == 10.0 and x[:, 1].min() == 0.0
    assert np.unique(x[:, 1]).tolist() == pytest.approx([0.0, 1.732051, 3.464102])
    # the four elements centred on x = 0 and x = 0.1 own half a cell
    full = 2650 * np.pi * 0.01 ** 2 * 0.02
    on = (x[:, 0] == 0.0) | (x[:, 0] == 10.0)
    assert on.sum() == 4
    assert st.m[on] == pytest.approx(0.5 * full) and st.m[~on] == pytest.approx(full)


def test_min_bonds_removes_the_elements_left_loose():
    # an empty box takes the odd row and the top row but its element at x = 0, which is left
    # without a contact: min_bonds 1 removes it; the base row (6) stays
    hole = [{"name": "cut", "empty": True,
             "shape": {"box": {"min": [0.005, 0.01], "max": [0.2, 0.2]}}}]
    assert _small(regions=hole).state.n == 7
    b = _small(regions=hole, min_bonds=1)
    assert b.state.n == 6 and b.info["loose_removed"] == 1
    assert np.all(b.state.x[:, 1] == 0.0)


def test_surface_groups_take_the_outermost_element_of_every_strip():
    st = _small(groups={"left": {"surface": "xmin"}, "ground": {"surface": "ymax"}}).state
    g = st.x[st.group_mask("ground")]
    # 6 strips of d along x (x = 0 ... 0.1); the top row holds one element in each
    assert len(g) == 6 and np.allclose(g[:, 1], 2 * 0.02 * np.sqrt(3) / 2)
    left = st.x[st.group_mask("left")]
    # along y, strips of d from y = 0: [0, 0.02) holds rows 0 and 1 (x = 0 and 0.01), [0.02,
    # 0.04) row 2: (0, 0) and (0, 0.0346); the corner (0, 0.0346) went to the later group
    assert left.tolist() == [[0.0, 0.0]]


def test_elastic_elements_are_the_rock_on_the_lattice():
    d = 0.02
    cfg = _cfg(domain={"box": {"min": [0.0, 0.0], "max": [0.1, 0.05]}}, lattice_origin="corner",
               elements="elastic", material="sand")
    b = cfg.model.build(cfg)
    from geodem.materials_library import load_material

    v = load_material("sandstone").values()
    E, nu, rho = v["E"], v["nu"], v["rho"]
    st, med = b.state, b.info["medium"]
    kn = 2 * E * d / (np.sqrt(3) * (1 - nu))                    # 2 Kn, thickness t = d
    assert st.kn == pytest.approx(kn, rel=1e-12)
    assert st.ks == pytest.approx(kn * (1 - 3 * nu) / (1 + nu), rel=1e-12)
    assert st.m == pytest.approx(rho * np.sqrt(3) / 2 * d ** 3, rel=1e-12)
    assert st.xb == pytest.approx(1e6 * d) and st.thickness == d
    assert med["cp"] == pytest.approx(np.sqrt(E / ((1 - nu ** 2) * rho)), rel=1e-12)
    assert med["k0"] == nu and med["source"].startswith("library 'sandstone'")
    # element parameters: the medium they make (their kn, ks kept, cell mass, unbreakable)
    b = _small(elements="elastic")
    assert b.state.kn == pytest.approx(ROCK["kn"], rel=1e-12)
    assert b.state.ks == pytest.approx(ROCK["ks"], rel=1e-12)
    assert b.state.m == pytest.approx(ROCK["rho"] * np.sqrt(3) / 2 * d ** 3, rel=1e-12)
    # another fill refused
    with pytest.raises(WorkflowError, match="elements applies to fill: lattice"):
        _cfg(fill="random", elements="elastic", material="sand")


def _interface(**model):
    """A lattice box split at y = 0.1 m into two regions of one rock, with ``model``'s
    interface options: ``(built, bond rows i, j, across)`` (``across``: the bond crosses
    the split)."""
    built = _build(regions=[{"name": "low", "material": "rock", "shape": {"below": 0.1}}],
                   **model)
    i, j = _bonds(built.state)
    low = built.state.x[:, 1] < 0.1
    return built, i, j, low[i] != low[j]


def test_a_weak_interface_scales_the_bonds_across_and_breaks_first():
    """interface_strength 0.5: the bonds across the two regions (and only they) carry half the
    breaking force. A bond of two equal elements breaks at Fn = kn xb with Fn = (kn / 2) x
    stretch (springs in series), i.e. at a stretch of 2 xb (1 xb at half strength). Stretched
    by eps = 2 xb / d along y, every inclined lattice bond opens by d eps sin^2(60 deg) =
    1.5 xb, so exactly the inclined bonds across the interface break, in tension, at once."""
    from geodem.core.engine import Simulation

    whole = _interface()[0].state
    built, i, j, across = _interface(interface_strength=0.5)
    st = built.state
    assert built.info["interface_bonds_weakened"] == int(across.sum()) // 2 > 0
    ok = (st.nbr >= 0) & (st.cstate == BONDED)
    assert np.all(st.brate[ok][across] == np.float32(0.5))
    assert np.all(st.brate[ok][~across] == 1.0) and np.array_equal(st.x, whole.x)
    eps = 2.0 * ROCK["xb"] / 0.02
    st.x[:, 1] *= 1.0 + eps
    sim = Simulation(st, backend="numpy")
    sim.run(1)
    log = sim.crack_log()
    assert len(log) == int(across.sum()) // 2 and np.all(log["type"] == 1)
    y = 0.5 * (st.x[log["i"], 1] + st.x[log["j"], 1])
    assert np.all(np.abs(y - 0.1) < 0.02)


def test_a_joint_has_no_interface_strength():
    with pytest.raises(WorkflowError, match="interface_strength"):
        _cfg(regions=[{"name": "low", "material": "clay", "shape": {"below": 0.1}}],
             interfaces="joint", interface_strength=0.5)


def test_a_soft_interface_holds_where_the_rock_breaks():
    """interface_stiffness 0.5: the bonds across the two regions (and only they) have half the
    stiffness and the same breaking force, so they break at twice the stretch: 4 xb instead of
    2 xb (two equal elements in series, Fn = kf kn/2 x stretch against kn xb). Stretched by
    eps = 3 xb / d along y, every inclined lattice bond opens by d eps sin^2(60 deg) =
    2.25 xb: all of them break but the softened ones across the interface."""
    from geodem.core.engine import Simulation

    built, i, j, across = _interface(interface_stiffness=0.5)
    st = built.state
    assert built.info["interface_bonds_softened"] == int(across.sum()) // 2 > 0
    ok = (st.nbr >= 0) & (st.cstate == BONDED)
    assert np.all(st.krate[ok][across] == 0.5) and np.all(st.krate[ok][~across] == 1.0)
    inclined = np.abs(st.x[i, 1] - st.x[j, 1]) > 1e-6
    st.x[:, 1] *= 1.0 + 3.0 * ROCK["xb"] / 0.02
    sim = Simulation(st, backend="numba")
    sim.run(1)
    log = sim.crack_log()
    assert len(log) == int((inclined & ~across).sum()) // 2 and np.all(log["type"] == 1)
    broken = {(min(a, b), max(a, b)) for a, b in zip(log["i"], log["j"])}
    assert not broken & {(min(a, b), max(a, b)) for a, b in zip(i[across], j[across])}


def test_a_joint_has_no_interface_stiffness():
    with pytest.raises(WorkflowError, match="interface_stiffness"):
        _cfg(regions=[{"name": "low", "material": "clay", "shape": {"below": 0.1}}],
             interfaces="joint", interface_stiffness=0.5)


def test_a_prism_domain_holds_the_box_lattice_inside_its_triangle():
    """A 3-D prism domain, the triangle x >= 0, z >= 0, x + z <= 0.2 (in the x-z plane)
    extruded along y over 0-0.1 m: exactly the centres of the box lattice over its bounds that
    lie in the triangle (edges included)."""
    tri = {"polygon": [[0.0, 0.0], [0.2, 0.0], [0.0, 0.2]], "axis": "y", "range": [0.0, 0.1]}
    st = _build(dim=3, domain={"prism": tri}).state
    box = _build(dim=3, domain={"box": {"min": [0, 0, 0], "max": [0.2, 0.1, 0.2]}}).state
    inside = box.x[box.x[:, 0] + box.x[:, 2] <= 0.2 + 1e-12]
    assert st.n == len(inside) > 20
    assert {tuple(np.round(v, 9)) for v in st.x} == {tuple(np.round(v, 9)) for v in inside}


def test_half_spaces_unions_and_differences_select_the_centres_counted_by_hand():
    """Regions (later overriding earlier): clay in the half-space x + y > 0.45 (point
    (0.3, 0.15), normal (1, 1)); sand in the union of two boxes less a disc. Each element's
    material is checked against the predicates evaluated on its centre."""
    regions = [
        {"name": "upper", "material": "clay",
         "shape": {"half_space": {"point": [0.3, 0.15], "normal": [1.0, 1.0]}}},
        {"name": "blocks", "material": "rock", "shape": {"difference": [
            {"union": [{"box": {"min": [0.0, 0.0], "max": [0.2, 0.1]}},
                       {"box": {"min": [0.4, 0.2], "max": [0.6, 0.3]}}]},
            {"disc": {"center": [0.5, 0.25], "radius": 0.04}}]}}]
    built = _build(material="sand", regions=regions)
    x = built.state.x
    upper = x[:, 0] + x[:, 1] > 0.45
    boxes = ((x[:, 0] >= 0) & (x[:, 0] <= 0.2) & (x[:, 1] >= 0) & (x[:, 1] <= 0.1)) | \
        ((x[:, 0] >= 0.4) & (x[:, 0] <= 0.6) & (x[:, 1] >= 0.2) & (x[:, 1] <= 0.3))
    blocks = boxes & (np.hypot(x[:, 0] - 0.5, x[:, 1] - 0.25) > 0.04)
    counts = built.info["elements_by_region"]
    assert counts["blocks"] == int(blocks.sum()) > 50
    assert counts["upper"] == int((upper & ~blocks).sum()) > 100
    assert counts["default"] == int((~upper & ~blocks).sum()) > 100
    assert np.array_equal(np.isclose(built.state.kn, ROCK["kn"]), blocks)


def test_a_raster_mask_selects_the_centres_over_its_cells(tmp_path):
    """A mask raster on the hill's grid (10 m cells), 1 on the cells west of local x = 300 m
    and 0 east of them: read bilinearly between cell centres, it is 0.5 on that cell edge, so
    the region (above 0.5, the default) is the centres whose section position lies west of
    300 m (the line runs west-east from local x = 0)."""
    import rasterio

    mask = tmp_path / "mask.tif"
    with rasterio.open(HILL) as src:
        prof = src.profile
        west = (np.arange(src.width) + 0.5) * src.res[0] < 300  # cell centres, local x
        grid = np.repeat(west[None, :].astype("float32"), src.height, axis=0)
    with rasterio.open(mask, "w", **prof) as dst:
        dst.write(grid.astype(prof["dtype"]), 1)
    built = _terrain_scene(10.0, [{"name": "west", "material": "clay",
                                   "shape": {"raster_mask": {"raster": str(mask)}}}])
    x = built.state.x
    assert built.info["elements_by_region"]["west"] == int((x[:, 0] < 300).sum()) > 20
    assert np.array_equal(np.isclose(built.state.kn, CLAY["kn"]), x[:, 0] < 300)
