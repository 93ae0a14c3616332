"""Terrain models on synthetic terrains (no raster files): lattice layout, layers, precedence."""
import math

import numpy as np
import pytest

from geodem.build.shapes import Box
from geodem.geo import Below, Depth, GeometryError, Terrain, terrain_model

H = math.sqrt(2.0 / 3.0)  # FCC layer spacing / d


def flat(level, extent=(0, 0, 6, 6), dx=1.0):
    return Terrain.from_function(lambda x, y: np.full_like(x, level), extent, dx)


def test_flat_terrain_lattice_layers_exact():
    # top z = 10, base z = 0, d = 1: centres at 0.5 + k h <= 10 -> k = 0..11 (0.5 + 11 h = 9.48)
    m = terrain_model(flat(10.0), 1.0, base_z=0.0, side_width=0)
    z = np.unique(m.x[:, 2].round(12))
    assert np.allclose(z, 0.5 + H * np.arange(12))
    # every layer holds its ABC pattern's points inside [0.5, 5.5] in x and y: A and B rows at
    # y = 0.5 + j sqrt(3)/2 (+ sqrt(3)/6 for B), C rows start at 0.5 + sqrt(3)/3
    per_layer = np.array([(np.abs(m.x[:, 2] - zk) < 1e-9).sum() for zk in z])
    a, b, c = per_layer[0], per_layer[1], per_layer[2]
    assert a == 6 * 3 + 5 * 3  # rows 0, 2, 4 at x = 0.5..5.5 (6); rows 1, 3, 5 offset (5)
    assert np.array_equal(per_layer, np.tile([a, b, c], 4))
    assert m.n == 4 * (a + b + c)
    # base: the two lowest layers; no slide; one body group
    assert np.array_equal(m.masks["base"], m.x[:, 2] < 2.0)
    assert m.names == ["rock"] and "slide" not in m.masks and "side_x" not in m.masks


def test_layers_from_levels_callables_and_depths():
    top = Terrain.from_function(lambda x, y: 10.0 + 0.5 * x, (0, 0, 8, 6), 1.0)
    m = terrain_model(top, 1.0, base_z=0.0,
                      layers=[("cover", Depth(2.0)), ("upper", 6.0),
                              ("tilted", lambda xy: 3.0 + 0.25 * xy[:, 0])], body="deep")
    x, z = m.x[:, 0], m.x[:, 2]
    t = top.elevation(m.x[:, :2])
    expect = np.where(z >= t - 2.0, 0, np.where(z >= 6.0, 1, np.where(z >= 3.0 + 0.25 * x, 2, 3)))
    assert np.array_equal(m.layer, expect)
    assert m.names == ["cover", "upper", "tilted", "deep"]
    assert all(m.info["counts"][n] > 0 for n in m.names)
    gm = m.group_masks()  # exclusive, by precedence
    assert sum(v.astype(int) for v in gm.values()).max() == 1
    assert np.array_equal(gm["base"], m.masks["base"])
    assert np.array_equal(gm["cover"], (m.layer == 0) & ~m.masks["base"] & ~m.masks["side_x"]
                          & ~m.masks["side_y"])


def test_default_section_line_and_below_shape():
    top = Terrain.from_function(lambda x, y: 5.0 + 0.1 * x + 0.2 * y, (0, 0, 20, 10), 1.0)
    m = terrain_model(top, 0.5, base_depth=2.0, dim=2)
    assert m.line == ((0.0, 5.0), (20.0, 5.0)) and m.extent == (0.0, 20.0)
    inner = (m.x[:, 0] >= 0.5) & (m.x[:, 0] <= 19.5)  # between the outermost cell centres
    assert np.all(m.x[inner, 1] <= 5.0 + 0.1 * m.x[inner, 0] + 1.0 + 1e-9)
    assert np.all(m.x[:, 1] <= top.elevation(np.c_[m.x[:, 0], np.full(m.n, 5.0)]) + 1e-9)
    below = Below(top, line=m.line)
    assert below.mask(m.x).all()
    # 3-D: cut a box of points by the terrain, 1 m below it
    P = np.array([[2.0, 2.0, 5.0], [2.0, 2.0, 4.5], [10.0, 5.0, 6.9], [10.0, 5.0, 7.1]])
    cut = Box((0, 0, 0), (20, 10, 100)) & Below(top, offset=-1.0)
    # terrain there: 5.6 and 7.0 -> thresholds 4.6 and 6.0
    assert cut.mask(P).tolist() == [False, True, False, False]
    assert Below(top).mask(P).tolist() == [True, True, True, False]
    assert Below(top).bounds[1][2] == pytest.approx(top.z.max())


def test_bad_terrain_model_input():
    top = flat(10.0)
    with pytest.raises(GeometryError, match="d must be a finite diameter"):
        terrain_model(top, 0.0)
    with pytest.raises(GeometryError, match="not covered by the terrain grid"):
        terrain_model(top, 1.0, extent=(0, 0, 7, 6))
    with pytest.raises(GeometryError, match="base_z or base_depth, not both"):
        terrain_model(top, 1.0, base_z=0.0, base_depth=3.0)
    with pytest.raises(GeometryError, match="must be distinct and not base"):
        terrain_model(top, 1.0, layers=[("base", 5.0)])
    with pytest.raises(GeometryError, match="not a surface"):
        terrain_model(top, 1.0, layers=[("a", "deep")])
    with pytest.raises(GeometryError, match="narrower than one element"):
        terrain_model(top, 1.0, extent=(0, 0, 0.5, 6))
    with pytest.raises(GeometryError, match=r"2 x 2 cells"):
        Terrain.from_array(np.ones((1, 5)), 1.0)


def test_sliding_surface_from_a_depth_raster():
    top = flat(10.0, extent=(0, 0, 8, 6))
    # slide depth 0 at x <= 2, rising 1 m per metre to 6 m at x = 8 (cell centres, bilinear)
    depth = Terrain.from_function(lambda x, y: np.clip(x - 2.0, 0.0, None), (0, 0, 8, 6), 1.0)
    m = terrain_model(top, 1.0, base_z=0.0, sliding_surface=Depth(depth))
    d_at = depth.elevation(m.x[:, :2])
    assert np.array_equal(m.masks["slide"], m.x[:, 2] > 10.0 - d_at)
    xs = m.x[m.masks["slide"], 0]
    assert xs.min() > 2.0 and m.masks["slide"].sum() > 20


def test_steepest_slope_quoted_in_the_docs_is_measured():
    from pathlib import Path

    import geodem.geo.synthetic as syn

    x = np.linspace(100.0, 400.0, 300001)
    g = np.degrees(np.arctan(np.abs(np.gradient(syn.hill_elevation(x, 150.0 + 0 * x), x))))
    assert x[g.argmax()] == pytest.approx(207.1, abs=0.05)
    assert g.max() == pytest.approx(38.05, abs=0.005)
    doc = (Path(__file__).resolve().parents[2] / "docs" / "landslide.md").read_text()
    for text in (syn.__doc__, doc):
        flat = " ".join(text.split())
        assert "38.05 deg at ``x = 207`` m" in flat or "38.05 deg at `x = 207` m" in flat
