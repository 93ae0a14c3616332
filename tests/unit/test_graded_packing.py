"""Graded packings (geodem/build/graded.py) and the terrain size field (band_size_field).

Hand-checked: the ramp law, the size law of the element parameters, the expected count of a
box, the band size field at chosen points; on a small box (fine above y = 16 d, twice as coarse
from 6 d lower down): the count per area in each zone, the nominal size of the elements in
each zone, the gradation across the transition (against a step), the radii inside each
element's size distribution, the overlaps far below the workflows' overlap limit.
"""
import math

import numpy as np
import pytest

from geodem.build.graded import (PHI_RANDOM, expected_count, graded_packing, overlap_ratio,
                                 ramp, scale_params)
from geodem.geo.terrain import band_size_field

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_ramp_grows_linearly_over_the_transition():
    e = np.array([-1.0, 0.0, 2.5, 5.0, 10.0])
    assert ramp(e, 1.0, 3.0, 5.0).tolist() == [1.0, 1.0, 2.0, 3.0, 3.0]
    assert ramp(e, 2.0, 2.0, 5.0).tolist() == [2.0, 2.0, 3.0, 4.0, 4.0]
    # transition 0: a step
    assert ramp(e, 1.0, 3.0, 0.0).tolist() == [1.0, 1.0, 3.0, 3.0, 3.0]


def test_parameters_follow_the_size_law():
    p = {"kn": 10.0, "ks": 4.0, "xb": 0.1, "fs0": 7.0, "mu": 0.6, "rho": 2500.0, "mass": 3.0}
    out = scale_params(p, 2.0, np.array([2.0, 4.0, 6.0]))
    assert out["kn"].tolist() == [10.0, 20.0, 30.0]  # ~ d
    assert out["ks"].tolist() == [4.0, 8.0, 12.0]
    assert out["xb"] == pytest.approx([0.1, 0.2, 0.3])
    assert out["fs0"].tolist() == [7.0, 28.0, 63.0]  # ~ d^2
    assert out["mass"].tolist() == [3.0, 24.0, 81.0]  # ~ d^3
    assert out["mu"].tolist() == [0.6] * 3 and out["rho"].tolist() == [2500.0] * 3
    assert scale_params({**p, "mass": None}, 2.0, np.array([4.0]))["mass"] is None
    # the macro -> micro conversion has the same law
    from geodem.materials import macro_to_micro

    a, b = (macro_to_micro(10e9, 0.15, 5e6, 50e6, 0.8, 2500.0, d) for d in (1.0, 3.0))
    el = dict(a.element, rho=2500.0, mass=a.mass)
    s = scale_params(el, 1.0, np.array([3.0]))
    for k, v in b.element.items():
        assert s[k][0] == pytest.approx(v, rel=1e-12), k
    assert s["mass"][0] == pytest.approx(b.mass, rel=1e-12)


def test_expected_count_of_a_box_by_hand():
    # d = 1, distri_rate 0.2: diameters uniform in [a, b], a = 2 / (1 + 1.44), b = 1.44 a
    a = 2.0 / 2.44
    b = 1.44 * a
    ed2 = (b ** 3 - a ** 3) / (3.0 * (b - a))  # E[d^2] = 1.01082
    n_hand = 0.84 * 20 * 10 / (math.pi / 4 * ed2) * (19.7 * 9.7) / 200.0  # wall strips 0.15 d
    n, _, _ = expected_count([0, 0], [20, 10], lambda x: np.ones(len(x)), 1.0)
    assert n == round(n_hand) == 202
    # all twice as coarse: a quarter as many (the wall strips scale with d too)
    n2, _, _ = expected_count([0, 0], [20, 10], lambda x: np.full(len(x), 2.0), 1.0)
    n2_hand = 0.84 * 200 / (math.pi / 4 * ed2 * 4) * (19.4 * 9.4) / 200.0
    assert n2 == round(n2_hand) == 48
    assert PHI_RANDOM == {2: 0.84, 3: 0.635}


def test_band_size_field_at_chosen_points():
    # level ground at 100 m, sliding surface at 95 m, d = 1, fine band 2 m, factor 3 over 4 m
    size = band_size_field(100.0, 1.0, 3.0, 2.0, 4.0, sliding_surface=95.0,
                           line=((0.0, 0.0), (10.0, 0.0)))
    z = np.array([101.0, 103.0, 106.0, 99.0, 93.0, 92.0, 85.0])
    x = np.column_stack([np.full(z.size, 5.0), z])
    # above the ground: fine up to 2 d above it, then growing; below: fine down to 2 m under
    # the sliding surface (93 m), 1.5 at 1 m deeper, 3 from 4 m deeper
    assert size(x).tolist() == [1.0, 1.5, 3.0, 1.0, 1.0, 1.5, 3.0]
    # without a sliding surface the band ends 2 m below the ground
    plain = band_size_field(100.0, 1.0, 3.0, 2.0, 4.0, line=((0.0, 0.0), (10.0, 0.0)))
    z2 = np.array([99.0, 97.0, 96.0, 93.0])
    assert plain(np.column_stack([np.full(4, 5.0), z2])).tolist() == [1.0, 1.5, 2.0, 3.0]


def test_band_size_field_refuses_bad_values():
    from geodem.geo import GeometryError

    with pytest.raises(GeometryError, match="factor must be finite and >= 1"):
        band_size_field(100.0, 1.0, 0.5, 2.0, 4.0, line=((0, 0), (1, 0)))
    with pytest.raises(GeometryError, match="band must be finite and > 0"):
        band_size_field(100.0, 1.0, 2.0, 0.0, 4.0, line=((0, 0), (1, 0)))
    with pytest.raises(GeometryError, match="transition must be finite and >= 0"):
        band_size_field(100.0, 1.0, 2.0, 1.0, -1.0, line=((0, 0), (1, 0)))


# ============================================================================ small box
LO, HI = np.array([0.0, 0.0]), np.array([24.0, 28.0])


def two_zones(transition):
    """Fine (d = 1) above y = 16, twice as coarse from y = 16 - transition down."""
    return lambda x: ramp(16.0 - np.asarray(x)[:, 1], 1.0, 2.0, transition)


@pytest.fixture(scope="module")
def box():
    x, r, dn, rep = graded_packing(LO, HI, two_zones(6.0), 1.0, seed=3)
    return x, r, dn, rep


def test_each_zone_holds_its_sizes(box):
    x, r, dn, rep = box
    s = rep["scale"]
    assert 0.97 < s < 1.03  # the count was right: jammed near the requested sizes
    y = x[:, 1]
    fine = y > 17.0  # the fine zone inset by one d
    coarse = y < 9.0  # the coarse zone inset by one d
    assert np.mean(np.isclose(dn[fine], s)) > 0.95 and dn[fine].max() < 1.25 * s
    assert np.mean(np.isclose(dn[coarse], 2.0 * s)) > 0.95 and dn[coarse].min() > 1.75 * s
    # jamming moved the elements by a fraction of a diameter (median), a few at most
    assert rep["median_drift"] < 1.0 and rep["max_drift"] < 5.0
    # radii inside each element's own size distribution (distri_rate 0.2: d_max/d_min = 1.44)
    a = 2.0 / 2.44
    assert np.all(2 * r >= a * dn * (1 - 1e-9)) and np.all(2 * r <= 1.44 * a * dn * (1 + 1e-9))


def test_counts_per_area_follow_the_size(box):
    x, r, dn, rep = box
    y = x[:, 1]
    n_fine = np.sum((y > 17.0) & (y < 27.0))  # 24 x 10 m, away from the faces
    n_coarse = np.sum((y > 2.0) & (y < 9.0))  # 24 x 7 m
    dens_f, dens_c = n_fine / (24 * 10.0), n_coarse / (24 * 7.0)
    # 0.84 / (pi/4 E[d^2]) = 1.058 per d^2 fine, a quarter of it (0.265) coarse
    assert dens_f == pytest.approx(1.058, rel=0.1)
    assert dens_c == pytest.approx(0.265, rel=0.2)
    # solid fraction of each zone: a dense random packing
    from geodem.build.packing import packing_fraction

    assert packing_fraction(x, r, [2.0, 17.0], [22.0, 27.0]) == pytest.approx(0.84, abs=0.03)
    assert packing_fraction(x, r, [2.0, 2.0], [22.0, 9.0]) == pytest.approx(0.84, abs=0.04)


def test_sizes_change_gradually_across_the_transition(box):
    x, r, dn, rep = box
    xs, rs, dns, _ = graded_packing(LO, HI, two_zones(0.0), 1.0, seed=3)  # a step

    def worst_pair_ratio(x, r, dn):
        from scipy.spatial import cKDTree

        p = cKDTree(x).query_pairs(2.0 * r.max() + 0.01, output_type="ndarray")
        gap = np.linalg.norm(x[p[:, 1]] - x[p[:, 0]], axis=1) - r[p[:, 0]] - r[p[:, 1]]
        p = p[gap < 0.01]  # touching pairs
        q = dn[p[:, 0]] / dn[p[:, 1]]
        return float(np.maximum(q, 1 / q).max())

    # across the step, touching neighbours differ by the full factor 2; over 6 d by much less
    # (1 + 1/6 per d of distance: ~1.25 between touching centres, plus the jamming drift)
    assert worst_pair_ratio(xs, rs, dns) == pytest.approx(2.0)
    assert worst_pair_ratio(x, r, dn) < 1.45


def test_overlaps_far_below_the_workflow_limit(box):
    x, r, dn, rep = box
    assert rep["max_overlap_ratio"] == overlap_ratio(x, r)
    assert 0 < rep["max_overlap_ratio"] < 0.01  # simulation.overlap_limit is 0.5
    assert rep["jam_overlap"] == pytest.approx(1e-4, rel=1.0)  # within a factor 2
    # every element inside the box (the faces are soft like the contacts: < 0.5 % d in)
    assert np.all(x - r[:, None] >= LO - 5e-3) and np.all(x + r[:, None] <= HI + 5e-3)


def test_uniform_field_gives_uniform_nominal_size():
    x, r, dn, rep = graded_packing([0, 0], [12, 8], lambda p: np.ones(len(p)), 1.0, seed=0)
    assert np.all(dn == rep["scale"]) and rep["n"] == len(x)
    with pytest.raises(ValueError, match="max_elements"):
        graded_packing([0, 0], [12, 8], lambda p: np.ones(len(p)), 1.0, max_elements=10)


def test_graded_study_summary_by_hand():
    from geodem.studies.freeze_study import graded_markdown, graded_summary

    def run(name, seed, n, steps, wall, runout):
        return {"run": name, "seed": seed, "elements": n, "element_steps": steps,
                "step_wall_s": wall, "runout_wall_s": wall - 1, "total_wall_s": wall + 10,
                "runout_m": runout, "travel_angle_deg": 20.0, "max_velocity": 8.0,
                "deposit_volume_m3": 1400.0, "com_ratio": 0.44}

    runs = [run("uniform", 0, 3500, 4e8, 50.0, 200.0), run("uniform", 1, 3500, 4e8, 70.0, 150.0),
            run("graded x2", 0, 1500, 2e8, 25.0, 140.0), run("graded x2", 1, 1700, 2e8, 35.0,
                                                            160.0)]
    s = graded_summary(runs)
    u, g = s["uniform"], s["graded x2"]
    assert u["runout_m"] == 175.0 and u["runout_m_std"] == pytest.approx(35.355, rel=1e-4)
    assert g["elements"] == 1600.0 and g["runout_m_std"] == pytest.approx(14.142, rel=1e-4)
    assert g["element_steps_ratio"] == 2.0 and g["step_speedup"] == 2.0
    assert g["total_speedup"] == pytest.approx(70.0 / 40.0)
    md = graded_markdown({"runs": runs, "summary": s})
    assert "| graded x2 | 1,600 | 2e+08 | 30.0 | 2.00 / 2.00 | 150 ± 14 |" in md
