"""Images -> material groups: colour and label images, tolerance, errors, pixel mapping."""
import numpy as np
import pytest

from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice
from geodem.geo import GeometryError, assign_groups, pixel_labels, read_labels
from geodem.geo.image import EMPTY, OUTSIDE

RED, BLUE, WHITE = (200, 0, 0), (0, 0, 200), (255, 255, 255)


def two_band_image():
    """4 x 6 RGB: rows 0-1 red (soil), rows 2-3 blue (rock), the top-left pixel white (air)."""
    img = np.zeros((4, 6, 3), np.uint8)
    img[:2] = RED
    img[2:] = BLUE
    img[0, 0] = WHITE
    return img


def test_colours_from_a_png_file(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    path = tmp_path / "layers.png"
    Image.fromarray(two_band_image()).save(path)
    li = read_labels(path, colours={"soil": RED, "rock": "#0000c8"}, empty=WHITE)
    assert li.names == ["soil", "rock"]
    expected = np.array([[EMPTY] + [0] * 5, [0] * 6, [1] * 6, [1] * 6])
    assert np.array_equal(li.labels, expected)
    assert li.counts == {"soil": 11, "rock": 12, "(empty)": 1}
    # a palette image reads the same
    Image.fromarray(two_band_image()).convert("P", palette=Image.Palette.ADAPTIVE).save(
        tmp_path / "pal.png")
    li2 = read_labels(tmp_path / "pal.png", colours={"soil": RED, "rock": BLUE}, empty=[WHITE])
    assert np.array_equal(li2.labels, expected)


def test_colour_tolerance_and_several_colours_per_material():
    img = two_band_image()
    noisy = img.astype(int) + np.random.default_rng(0).integers(-3, 4, img.shape)
    noisy = np.clip(noisy, 0, 255)
    li = read_labels(noisy, colours={"soil": RED, "rock": BLUE}, empty=WHITE, tolerance=3)
    assert li.counts == {"soil": 11, "rock": 12, "(empty)": 1}
    with pytest.raises(GeometryError, match="tolerance 2"):
        read_labels(noisy, colours={"soil": RED, "rock": BLUE}, empty=WHITE, tolerance=2)
    # the nearest configured colour wins (Chebyshev distance)
    px = np.array([[[100, 0, 0], [60, 0, 0]]], np.uint8)
    li = read_labels(px, colours={"a": (0, 0, 0), "b": (120, 0, 0)}, tolerance=100)
    assert li.labels.tolist() == [[1, 0]]
    li = read_labels(two_band_image(), colours={"ground": [RED, BLUE], "air": WHITE})
    assert li.counts == {"ground": 23, "air": 1, "(empty)": 0}


def test_unmapped_colours_are_listed_with_counts():
    img = two_band_image()
    img[3, :4] = (0, 255, 0)
    with pytest.raises(GeometryError) as e:
        read_labels(img, colours={"soil": RED}, empty=WHITE)
    msg = str(e.value)
    # most frequent first: blue 8 px, green 4 px
    assert ("<array>: 12 of 24 pixels (50.0 %) have colours mapped to no material: "
            "(0, 0, 200) #0000c8 x 8 px, (0, 255, 0) #00ff00 x 4 px.") in msg
    assert "Configured: soil=['#c80000'], empty=['#ffffff'] (tolerance 0)" in msg


def test_label_values():
    lab = np.array([[1, 1, 2], [3, 0, 0]])
    li = read_labels(lab, values={"sand": 1, "clay": [2, 3]}, empty=0)
    assert li.labels.tolist() == [[0, 0, 1], [1, EMPTY, EMPTY]]
    with pytest.raises(GeometryError, match=r"values mapped to no material: 0 x 2 px, 3 x 1 px"):
        read_labels(lab, values={"sand": 1, "clay": 2})


def test_wrong_image_kinds():
    with pytest.raises(GeometryError, match=r"colour image needs shape \(H, W, 3\|4\)"):
        read_labels(np.zeros((3, 3)), colours={"a": RED})
    with pytest.raises(GeometryError, match="label image needs one band"):
        read_labels(np.zeros((3, 3, 3)), values={"a": 0})
    with pytest.raises(GeometryError, match="exactly one of"):
        read_labels(np.zeros((3, 3)))
    with pytest.raises(GeometryError, match="not '#rrggbb'"):
        read_labels(np.zeros((3, 3, 3)), colours={"a": "#12"})


def test_pixel_mapping_2d_and_sections():
    li = read_labels(np.array([[0, 1, 2], [3, 4, 5]]), values={str(k): k for k in range(6)})
    # extent 0..3 x 0..2: pixel (row, col) covers x in [col, col+1], y in [1-row, 2-row]
    pts = np.array([[0.5, 1.5], [2.5, 1.5], [0.5, 0.5], [2.9, 0.1], [3.0, 0.0], [1.0, 1.0]])
    assert pixel_labels(pts, li, (0, 0, 3, 2)).tolist() == [0, 2, 3, 5, 5, 4]
    with pytest.raises(GeometryError, match="1 of 2 element centres lie outside"):
        pixel_labels(np.array([[0.5, 0.5], [3.5, 0.5]]), li, (0, 0, 3, 2))
    assert pixel_labels(np.array([[3.5, 0.5]]), li, (0, 0, 3, 2), outside="keep").tolist() == \
        [OUTSIDE]
    assert pixel_labels(np.array([[3.5, 0.5]]), li, (0, 0, 3, 2), outside="clamp").tolist() == [5]
    # 3-D section "xz": row 0 is the top (z max), y is ignored
    p3 = np.array([[0.5, 99.0, 1.5], [2.5, -5.0, 0.5]])
    assert pixel_labels(p3, li, (0, 0, 3, 2), plane="xz").tolist() == [0, 5]
    assert pixel_labels(p3[:, [1, 0, 2]], li, (0, 0, 3, 2), plane="yz").tolist() == [0, 5]
    with pytest.raises(GeometryError, match="plane must be one of"):
        pixel_labels(p3, li, (0, 0, 3, 2), plane="zx")


def test_assign_groups_2d_removes_empty_pixels():
    d = 1.0
    x = triangular_lattice(6, 4, d) + 0.5  # x in 0.5..6.0, y in 0.5..3.1
    st = bonded_state(x, 0.5 * d, density=1000.0, kn=1e6, ks=4e5, xb=1e-3, fs0=1.0, mu=0.5,
                      gap=1e-6)
    img = two_band_image()
    img[0, 0], img[0, 5] = RED, WHITE
    li = read_labels(img, colours={"soil": RED, "rock": BLUE}, empty=WHITE)
    # one pixel per metre; the white pixel covers 5 <= x <= 6, 3 <= y <= 4: the top row (y =
    # 3.098, x = 1, 2, ..., 6) has two elements there (x = 6 is on the far edge: last column)
    extent = (0.0, 0.0, 6.0, 4.0)
    out = assign_groups(st, li, extent)
    lab = pixel_labels(st.x, li, extent)
    assert out.n == st.n - int((lab == EMPTY).sum()) == st.n - 2
    assert not np.any((out.x[:, 0] >= 5.0) & (out.x[:, 1] > 3.0))
    assert set(out.groups) == {"all", "soil", "rock"}
    assert np.array_equal(out.group_mask("soil"), out.x[:, 1] >= 2.0)
    assert np.array_equal(out.group_mask("rock"), out.x[:, 1] < 2.0)


def test_assign_groups_3d_plan_with_only():
    d = 1.0
    x = fcc_lattice(4, 4, 3, d)
    st = bonded_state(x, 0.5 * d, density=1000.0, kn=1e6, ks=4e5, xb=1e-3, fs0=1.0, mu=0.5,
                      gap=1e-6)
    from geodem.core import groups as grp

    grp.add_group(st, "base", st.x[:, 2] < 0.1)
    plan = read_labels(np.array([[1, 2], [1, 2]]), values={"west": 1, "east": 2})
    out = assign_groups(st, plan, (0, 0, 4, 4), plane="xy", only=~st.group_mask("base"))
    assert out is st
    upper = st.x[:, 2] > 0.1
    assert np.array_equal(st.group_mask("west"), upper & (st.x[:, 0] < 2.0))
    assert np.array_equal(st.group_mask("east"), upper & (st.x[:, 0] >= 2.0))
    assert int(st.group_mask("base").sum()) == 16


def test_float_colour_arrays_and_empty_images():
    img = two_band_image()
    cols = {"soil": RED, "rock": BLUE, "air": WHITE}
    # floats holding whole numbers read like the integer image
    assert read_labels(img.astype(float), colours=cols).counts == \
        read_labels(img, colours=cols).counts == {"soil": 11, "rock": 12, "air": 1,
                                                 "(empty)": 0}
    # floats in 0..1 (matplotlib's imread) are refused, not truncated to black
    with pytest.raises(GeometryError, match=r"<array>: colour values must be whole numbers in "
                                            r"0\.\.255; this float64 image has 23 values that "
                                            r"are not \(range 0 \.\. 1\)\. Floats in 0\.\.1"):
        read_labels(img / 255.0, colours={"black": (0, 0, 0), **cols})
    nan = img.astype(float)
    nan[1, 1, 0] = np.nan
    with pytest.raises(GeometryError, match=r"has 1 values that are not \(range 0 \.\. 255, "
                                            r"NaN\)"):
        read_labels(nan, colours=cols)
    with pytest.raises(GeometryError, match=r"colour values must lie in 0\.\.255, got -1 \.\. "
                                            r"255"):
        read_labels(img.astype(int) - (img == 0), colours=cols)
    for shape in ((0, 5, 3), (4, 0), (0,)):
        with pytest.raises(GeometryError, match=r"the image is empty \(shape \(" + str(shape[0])):
            read_labels(np.zeros(shape, np.uint8), colours=cols)
        with pytest.raises(GeometryError, match="the image is empty"):
            read_labels(np.zeros(shape, np.uint8), values={"a": 0})


def test_positions_that_are_not_finite_lie_outside():
    li = read_labels(np.array([[0, 1, 2], [3, 4, 5]]), values={str(k): k for k in range(6)})
    pts = np.array([[0.5, 0.5], [np.nan, 0.5], [4.0, 1.0]])
    with pytest.raises(GeometryError, match=r"2 of 3 element centres lie outside the image "
                                            r"extent \(0, 0, 3, 2\) in plane 'xy' \(1 not finite "
                                            r"\(NaN or inf\); they span \[4\.0, 1\.0\] \.\. "
                                            r"\[4\.0, 1\.0\]\)"):
        pixel_labels(pts, li, (0, 0, 3, 2))
    assert pixel_labels(pts, li, (0, 0, 3, 2), outside="keep").tolist() == [3, OUTSIDE, OUTSIDE]
    with pytest.raises(GeometryError, match="not finite has no nearest pixel"):
        pixel_labels(pts, li, (0, 0, 3, 2), outside="clamp")
    assert pixel_labels(pts[[0, 2]], li, (0, 0, 3, 2), outside="clamp").tolist() == [3, 5]
