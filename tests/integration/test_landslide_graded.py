"""The landslide on a graded model (``model.coarsen``; docs/graded.md).

* the built model (the shipped hill at scale 0.6, d = 5 m, factor 2): fewer elements than the
  uniform model, the slide and the ground surface fine, the deep ground coarse, every
  element's parameters at its own nominal size (kn, ks, xb ~ d, fs0 ~ d^2, mass rho pi r^2 2r),
  the base fixed along the whole section, initial overlaps far below the overlap limit;
* a short run (seconds): the slide moves down-slope and obeys H_c / L_c >= mu;
* bad input: exit 2 naming the field and the allowed range.

The default-size comparison with and without coarsening is ``-m slow``.
"""
import numpy as np
import pytest

from tests.integration.test_landslide import WF, _run

SMALL = ["model.scale=0.6", "model.coarsen.factor=2", "model.coarsen.band=10",
         "model.coarsen.transition=15"]

pytestmark = pytest.mark.usefixtures("one_numba_thread")


@pytest.fixture(scope="module")
def built():
    from geodem.workflow import prepare
    from geodem.workflow.runner import validated

    prep = prepare(WF, sets=SMALL)
    uni = validated(WF, ["model.scale=0.6"], None)[1]
    return prep, uni


def test_graded_model_is_fine_near_the_surface_and_coarse_below(built):
    prep, uni = built
    st, info = prep.built.state, prep.built.info
    g = info["graded"]
    d = 5.0
    assert g["factor"] == 2.0 and g["fine"] + g["transition_elements"] + g["coarse"] == st.n
    assert g["coarse"] > 0.15 * st.n and g["fine"] > 0.4 * st.n
    # the uniform model of the same d would hold ~1,300 elements (the lattice estimate)
    assert st.n < 0.75 * uni.model.n_elements()
    # the estimate the planner uses (advise, memory) is within 15 % of the built count
    assert prep.cfg.model.n_elements() == pytest.approx(st.n, rel=0.15)
    kn_f = float(np.min(st.kn))
    size = st.kn / kn_f  # nominal diameter / the finest (kn ~ d)
    assert size.max() == pytest.approx(2.0, rel=0.02)
    # the slide is all fine
    sl = st.group == st.groups["slide"]
    assert np.allclose(size[sl], 1.0)
    # depth below the ground surface of each element (the profile along the section)
    prof = info["profile"]
    top = np.interp(st.x[:, 0], prof["s"], prof["top"])
    depth = top - st.x[:, 1]
    slip = np.interp(st.x[:, 0], prof["s"], prof["slip"])
    below_band = np.minimum(top - 10.0, slip - 10.0) - st.x[:, 1]  # depth below the band
    near = depth < 10.0 - d  # inside the fine band by one d
    assert np.mean(np.isclose(size[near], 1.0, rtol=1e-6)) > 0.97 and size[near].max() < 1.3
    deep = below_band > 15.0 + d  # past the transition by one d
    assert deep.sum() > 50 and np.mean(np.isclose(size[deep], 2.0, rtol=1e-6)) > 0.97


def test_graded_parameters_follow_each_elements_size(built):
    prep, _ = built
    st = prep.built.state
    s = st.kn / st.kn.min()
    # rock: kn_per_d 6.667e8, ks_per_d 2.667e8, xb_per_d 0.01667, fs0_per_d2 3.333e7 at d = 5 m
    # (x the packing's common scale ~1)
    assert st.kn.min() == pytest.approx(6.667e8 * 5.0, rel=0.03)
    assert np.allclose(st.ks / st.ks.min(), s) and np.allclose(st.xb / st.xb.min(), s)
    assert np.allclose(st.fs0 / st.fs0.min(), s ** 2)
    assert np.allclose(st.kn / st.ks, 6.667 / 2.667, rtol=1e-3)
    # 2-D discs as thick as wide: m = rho pi r^2 2r
    assert np.allclose(st.m, 2500.0 * np.pi * st.r ** 2 * 2 * st.r)
    # each element's radius lies in its own size distribution (d_max / d_min = 1.44)
    dn = 5.0 * s * st.kn.min() / (6.667e8 * 5.0)
    a = 2.0 / 2.44
    assert np.all(2 * st.r > 0.99 * a * dn) and np.all(2 * st.r < 1.01 * 1.44 * a * dn)


def test_graded_model_is_held_and_starts_without_overlaps(built):
    prep, _ = built
    st = prep.built.state
    from geodem.core.checks import initial_overlap

    ratio, _, _ = initial_overlap(st)
    assert ratio < 0.01 < prep.cfg.simulation.overlap_limit
    base = st.group == st.groups["base"]
    assert np.all(st.free[base] == 0)
    # the base spans the whole section (no 50 m stretch without a fixed element)
    xb = np.sort(st.x[base, 0])
    assert xb[0] < 25 and xb[-1] > 575 and np.diff(xb).max() < 50
    # every element resting on the base level is in it
    zb = prep.built.info["base_z"]
    low = st.x[:, 1] - st.r < zb + 0.01
    assert np.all(base[low])
    side = st.group == st.groups["side_x"]
    assert side.sum() >= 4 and np.all(st.free[side, 0] == 0)


def test_graded_landslide_runs_down_slope(tmp_path):
    s = _run(tmp_path / "run", *SMALL, "steps.slide.max_time=8.0", "steps.slide.min_time=1.0",
             "steps.slide.gif=false", "steps.slide.vtk_frames=0", "steps.slide.snapshots=1",
             "steps.slide.plot=false")
    r = s["results"]["slide"]
    assert s["status"] == "ok" and r["graded"]["factor"] == 2.0
    assert r["elements"] == s["elements"] and r["element_steps"] == (
        r["settle_steps"] + r["runout_steps"]) * r["elements"]
    assert r["com_travel_m"] > 5.0 and r["com_drop_m"] > 2.0 and r["direction"] == [1.0]
    assert r["com_ratio"] >= r["slide_friction"] == 0.1
    assert r["max_velocity"] > 1.0 and r["lost_elements"] == 0
    assert r["ground_max_displacement"] < 2.5  # half a fine diameter
    assert r["energy_closure_rel_error"] < 0.05


@pytest.mark.parametrize("setting, words", [
    ("model.coarsen.factor=5", ["model.coarsen.factor", "4"]),
    ("model.coarsen.factor=0.5", ["model.coarsen.factor", "1"]),
    ("model.coarsen.transition=-1", ["model.coarsen.transition", "0"]),
    ("model.coarsen.band=1", ["model.coarsen.band", "thinner than one element"]),
    ("model.coarsen.depth=5", ["model.coarsen.depth", "unknown key", "factor, band, transition"]),
])
def test_bad_coarsen_exits_2(tmp_path, setting, words):
    out = _run(tmp_path / "x", "model.coarsen.factor=2", setting, code=2)
    for w in words:
        assert w in out, out


# ============================================================================ slow
@pytest.mark.slow
def test_default_landslide_graded(tmp_path):
    """The default workflow with ``model.coarsen.factor=2`` (docs/graded.md; a minute):
    ``NUMBA_NUM_THREADS=1 geodem run workflows/landslide.yaml -o out/ls_x2
    --set model.coarsen.factor=2``."""
    s = _run(tmp_path / "run", "model.coarsen.factor=2", "steps.slide.gif=false")
    r = s["results"]["slide"]
    # measured: 1,575 elements (uniform 3,541); as many time steps as the uniform model
    assert r["elements"] < 0.5 * 3541 and r["settle_steps"] == 2030
    assert r["stopped_by"] == "rest" and r["lost_elements"] == 0
    assert r["com_ratio"] >= r["slide_friction"]
    # inside the spread of the uniform and factor-1 runs over three packing seeds
    assert 100 < r["runout_m"] < 260 and 15 < r["travel_angle_deg"] < 23
    assert r["deposit_volume_m3"] > 1300
