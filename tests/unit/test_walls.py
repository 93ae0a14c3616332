"""Walls of elements (geodem.build.walls): placement, groups and the force they transmit."""
import numpy as np
import pytest

from geodem.build.walls import add_walls, append_elements, wall_surface
from geodem.core import groups
from geodem.core.engine import Simulation
from geodem.core.state import new_state


def one_element():
    st = new_state(np.array([[0.0, 0.0]]), 0.5, 1.0, kn=100.0, ks=100.0, width=8)
    st.skin = 0.1
    groups.add_group(st, "specimen", [0])
    return st


def test_walls_touch_the_faces_and_are_fixed_groups():
    st = add_walls(one_element(), ["ymin", "ymax"], d_wall=1.0, margin=0.0)
    assert st.n == 7  # 1 + 3 + 3 (spacing 0.85 d_wall, covering a 1 m face)
    assert wall_surface(st, "ymax", "ymax") == pytest.approx(0.5)
    assert wall_surface(st, "ymin", "ymin") == pytest.approx(-0.5)
    top = groups.members(st, "ymax")
    assert np.all(st.free[top] == 0.0)
    assert np.all(st.kn[top] == 100.0)  # as stiff as the material per diameter
    assert np.all(st.xb[top] == 0.0) and np.all(st.fs0[top] == 0.0)  # unbonded
    assert set(st.nbr[0][st.nbr[0] >= 0]) == {2, 5}  # the element touches one of each wall


def test_pushed_wall_transmits_the_series_spring_force():
    st = add_walls(one_element(), ["ymin", "ymax"], d_wall=1.0, margin=0.0, kn=300.0)
    top = groups.members(st, "ymax")
    st.x[top, 1] -= 0.01  # 0.01 m overlap with the element
    st.dt = 1e-3
    Simulation(st, backend="numba")  # initial force evaluation
    k = 100.0 * 300.0 / 400.0
    assert groups.reaction(st, "ymax")[1] == pytest.approx(k * 0.01, rel=1e-12)
    assert st.a[0, 1] * st.m[0] == pytest.approx(-k * 0.01, rel=1e-12)
    assert groups.reaction(st, "ymin")[1] == pytest.approx(0.0, abs=1e-15)


def test_append_elements_keeps_rows_and_rejects_wrong_dim():
    st = one_element()
    out = append_elements(st, [[3.0, 0.0]], 0.5, 1.0, kn=10.0, group="extra", fixed=False)
    assert out.n == 2 and np.all(out.free[1] == 1.0) and groups.members(out, "extra").tolist() == [1]
    with pytest.raises(ValueError, match="columns"):
        append_elements(st, [[0.0, 0.0, 0.0]], 0.5, 1.0, kn=10.0)
    with pytest.raises(ValueError, match="allowed xmin"):
        add_walls(st, ["zmax"])
