"""Shapes: polygons, half-spaces, spheres and their unions, intersections and differences."""
import math

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.build.shapes import (
    Box,
    Cylinder,
    Difference,
    Disc,
    HalfSpace,
    Intersection,
    Polygon,
    Sphere,
    Union,
    cut,
    polygon_area,
    polygon_mask,
)
from geodem.geo import GeometryError

# an L-shaped polygon: the unit square [0,2]x[0,2] without its upper-right quarter [1,2]x[1,2]
L_SHAPE = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]


def test_polygon_2d_mask_area_bounds():
    pts = np.array([[0.5, 0.5],   # inside
                    [1.5, 0.5],   # inside (lower-right arm)
                    [1.5, 1.5],   # in the cut-away quarter: outside
                    [0.5, 1.5],   # inside (upper-left arm)
                    [2.5, 0.5],   # outside
                    [1.0, 1.5],   # on the inner vertical edge: inside (edges included)
                    [2.0, 0.0],   # a vertex: inside
                    [1.0 + 1e-6, 1.0 + 1e-6],  # just inside the cut-away corner: outside
                    [-1e-9, 1.0]])  # just outside the left edge, beyond the tolerance
    p = Polygon(L_SHAPE)
    assert p.mask(pts).tolist() == [True, True, False, True, False, True, True, False, False]
    assert p.area == pytest.approx(3.0, abs=1e-15)
    assert polygon_area(L_SHAPE) == pytest.approx(3.0)  # counter-clockwise: positive
    assert polygon_area(L_SHAPE[::-1]) == pytest.approx(-3.0)
    lo, hi = p.bounds
    assert lo.tolist() == [0, 0] and hi.tolist() == [2, 2]
    # orientation does not matter
    assert np.array_equal(Polygon(L_SHAPE[::-1]).mask(pts), p.mask(pts))


def test_polygon_mask_matches_area_by_sampling():
    # a triangle (0,0),(4,0),(0,3): area 6; a fine grid of cell centres counts it
    n = 400
    g = (np.arange(n) + 0.5) / n * 4.0
    X, Y = np.meshgrid(g, g)
    pts = np.c_[X.ravel(), Y.ravel()]
    m = polygon_mask(pts, [(0, 0), (4, 0), (0, 3)])
    area = m.sum() * (4.0 / n) ** 2
    assert area == pytest.approx(6.0, rel=2e-3)
    # exact check of the rule: y <= 3 - 0.75 x
    assert np.array_equal(m, pts[:, 1] <= 3.0 - 0.75 * pts[:, 0])


def test_polygon_prism_3d_axes():
    # prism along z: L-shape in (x, y), z in [0, 5]
    pz = Polygon(L_SHAPE, axis="z", z0=0.0, z1=5.0)
    pts = np.array([[0.5, 0.5, 2.0], [0.5, 0.5, 5.5], [1.5, 1.5, 2.0], [1.5, 0.5, 0.0]])
    assert pz.mask(pts).tolist() == [True, False, False, True]
    assert pz.volume == pytest.approx(15.0)
    # prism along y: the polygon is in (x, z)
    py = Polygon(L_SHAPE, axis="y", z0=-1.0, z1=1.0)
    pts = np.array([[1.5, 0.0, 0.5], [1.5, 0.0, 1.5], [0.5, 0.9, 1.5], [0.5, 1.1, 1.5]])
    assert py.mask(pts).tolist() == [True, False, True, False]
    lo, hi = py.bounds
    assert lo.tolist() == [0, -1, 0] and hi.tolist() == [2, 1, 2]
    # along x: (y, z)
    px = Polygon([(0, 0), (1, 0), (0, 1)], axis="x", z0=0.0, z1=1.0)
    assert px.mask(np.array([[0.5, 0.2, 0.2], [0.5, 0.8, 0.8]])).tolist() == [True, False]
    with pytest.raises(ValueError, match="3-D positions"):
        pz.mask(np.zeros((2, 2)))


def test_halfspace_and_sphere():
    h = HalfSpace((0, 0, 5), (0, 0, 2))  # z <= 5 (normal normalised)
    pts = np.array([[9, 9, 4.9], [0, 0, 5.0], [0, 0, 5.1]])
    assert h.mask(pts).tolist() == [True, True, False]
    lo, hi = h.bounds
    assert hi.tolist() == [np.inf, np.inf, 5.0] and lo.tolist() == [-np.inf] * 3
    # oblique 2-D half-space x + y <= 1 with normal (1, 1)
    h2 = HalfSpace((0.5, 0.5), (1, 1))
    assert h2.mask(np.array([[0.0, 0.9], [0.6, 0.6], [1.0, 0.0]])).tolist() == [True, False, True]
    assert np.all(np.isinf(h2.bounds[0])) and np.all(np.isinf(h2.bounds[1]))
    s = Sphere((1, 1, 1), 2.0)
    assert s.mask(np.array([[1, 1, 3.0], [1, 1, 3.01], [2, 2, 2]])).tolist() == [True, False, True]
    assert s.volume == pytest.approx(4 / 3 * math.pi * 8)
    assert Sphere((0, 0), 1.0).volume == pytest.approx(math.pi)


def test_union_intersection_difference_masks():
    a = Box((0, 0), (2, 2))
    b = Disc((2, 2), 1.0)
    pts = np.array([[1.0, 1.0],    # a only
                    [2.5, 2.5],    # b only
                    [1.8, 1.8],    # both
                    [3.5, 3.5],    # neither
                    [2.0, 1.0]])   # a's edge and b's rim: both
    ma = [True, False, True, False, True]
    mb = [False, True, True, False, True]
    assert (a | b).mask(pts).tolist() == [x or y for x, y in zip(ma, mb)]
    assert (a & b).mask(pts).tolist() == [x and y for x, y in zip(ma, mb)]
    assert (a - b).mask(pts).tolist() == [x and not y for x, y in zip(ma, mb)]
    assert (b - a).mask(pts).tolist() == [y and not x for x, y in zip(ma, mb)]
    assert isinstance(a | b, Union) and isinstance(a & b, Intersection)
    assert isinstance(a - b, Difference)
    lo, hi = (a | b).bounds
    assert lo.tolist() == [0, 0] and hi.tolist() == [3, 3]
    lo, hi = (a & b).bounds
    assert lo.tolist() == [1, 1] and hi.tolist() == [2, 2]
    lo, hi = (a - b).bounds
    assert lo.tolist() == [0, 0] and hi.tolist() == [2, 2]
    # nesting and n-ary forms
    hole = Box((0.5, 0.5), (1.2, 1.2))
    upper = HalfSpace((0, 0.9), (0, -1))  # outward normal -y: y >= 0.9
    nested = (a | b) - hole & upper  # '-' binds tighter than '&': ((a | b) - hole) & upper
    assert nested.mask(pts).tolist() == [False, True, True, False, True]
    assert Union(a, b, hole).mask(pts).tolist() == (a | b | hole).mask(pts).tolist()
    assert Difference(a, b, hole).mask(pts).tolist() == ((a - b) - hole).mask(pts).tolist()


def test_difference_of_3d_shapes_cuts_a_hole():
    # a cylinder with a spherical hole: the centre point is outside, a point in the wall inside
    cyl = Cylinder((0, 0), 2.0, 0.0, 4.0)
    shape = cyl - Sphere((0, 0, 2), 1.0)
    pts = np.array([[0, 0, 2.0], [1.5, 0, 2.0], [0, 0, 3.5], [0, 2.5, 2.0]])
    assert shape.mask(pts).tolist() == [False, True, True, False]
    assert cut(pts, shape).tolist() == [False, True, True, False]


def test_cut_state_by_polygon_difference():
    d = 1.0
    x = triangular_lattice(10, 10, d)
    st = bonded_state(x, 0.5 * d, density=1000.0, kn=1e6, ks=4e5, xb=1e-3, fs0=1.0, mu=0.5,
                      gap=1e-6)
    shape = Polygon([(0, 0), (9, 0), (9, 8), (0, 8)]) - HalfSpace((4.5, 4.0), (-1, 0))
    sub = cut(st, shape)  # the rectangle minus {x >= 4.5}: 0 <= x < 4.5, y <= 8
    keep = (st.x[:, 0] < 4.5) & (st.x[:, 1] <= 8)
    assert sub.n == int(keep.sum())
    assert np.array_equal(sub.x, st.x[keep])


def test_bad_shapes_raise_geometry_errors():
    with pytest.raises(GeometryError, match="at least 3 points"):
        Polygon([(0, 0), (1, 1)])
    with pytest.raises(GeometryError, match="no area"):
        Polygon([(0, 0), (1, 1), (2, 2)])
    with pytest.raises(GeometryError, match="z0 and z1"):
        Polygon(L_SHAPE, z0=0.0)
    with pytest.raises(GeometryError, match="z0 < z1"):
        Polygon(L_SHAPE, z0=1.0, z1=0.0)
    with pytest.raises(GeometryError, match="non-zero"):
        HalfSpace((0, 0, 0), (0, 0, 0))
    with pytest.raises(GeometryError, match="at least 2"):
        Union(Box((0, 0), (1, 1)))
    with pytest.raises(GeometryError, match="not a shape"):
        Union(Box((0, 0), (1, 1)), 3)
    with pytest.raises(ValueError, match="2-D half-space"):
        HalfSpace((0, 0), (1, 0)).mask(np.zeros((1, 3)))
    assert issubclass(GeometryError, ValueError)
