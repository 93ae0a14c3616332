"""Large random packings from a periodic cell (geodem.build.isotropic.tiled_packing).

The whole box jammed at once costs ~N^2.6 (docs/performance.md); above TILE_ABOVE elements the
packing is one periodic cell, jammed and made stress-free with its bonds across the cell's
boundaries, repeated over the box. The repeated packing must be stress-free everywhere (every
touching pair overlaps by the prestress, inside a cell and across two), the cells exact copies,
and its interior what the whole-box jamming gives: ~6.7 contacts per element, solid fraction
~0.65.
"""
import numpy as np
import pytest

from geodem.build import isotropic

pytestmark = pytest.mark.usefixtures("one_numba_thread")

CELLS = (2, 2, 1)
SIZE = np.array([9.0, 9.0, 4.5])  # d_mean = 1: cells 4.5 across


@pytest.fixture(scope="module")
def tiled():
    return isotropic.tiled_packing(SIZE, 1.0, 0.2, CELLS, 300, seed=4)


def test_every_touching_pair_is_stress_free_across_the_cells(tiled):
    x, r, rep = tiled
    pi, pj = isotropic._pairs(x, r, 0.05)
    gap = np.linalg.norm(x[pj] - x[pi], axis=1) - r[pi] - r[pj]
    touching = gap <= 0.0
    assert np.allclose(gap[touching], -isotropic.DEFAULT_PRESTRESS, atol=1e-10)
    assert rep["bonds"] == touching.sum()
    a, b = x[pi[touching]], x[pj[touching]]

    def crossing(axis, plane):
        return int(((a[:, axis] - plane) * (b[:, axis] - plane) < 0).sum())

    # as many bonds across the cells' boundary as across a plane through a cell's middle
    for axis in (0, 1):
        boundary, middle = crossing(axis, 4.5), crossing(axis, 2.25) + crossing(axis, 6.75)
        assert boundary > 40 and boundary == pytest.approx(0.5 * middle, rel=0.3)


def test_the_cells_are_copies_and_the_centres_lie_in_the_box(tiled):
    x, r, rep = tiled
    assert rep["tiles"] == list(CELLS) and rep["tile_elements"] == 300
    assert rep["n"] == 4 * 300 - rep["loose_removed"] and rep["loose_removed"] < 12
    assert np.all(x >= 0.0) and np.all(x < SIZE)
    side = SIZE / CELLS
    first = x[np.all(x < side, axis=1)]
    shifted = x[np.all((x >= [side[0], 0, 0]) & (x < [2 * side[0], side[1], side[2]]), axis=1)]
    a = first[np.lexsort(first.T)]
    b = shifted[np.lexsort(shifted.T)] - [side[0], 0.0, 0.0]
    assert a.shape == b.shape and np.allclose(a, b, atol=1e-12)


def test_the_periodic_cell_is_jammed_like_a_box():
    """Interior coordination and density of a periodic cell against the whole-box jamming of
    the same box (both ~1,000 elements; the box's interior 2 d_mean from its faces)."""
    z, phi = {}, {}
    side = 10.0
    for tile in (False, True):
        zs, ps = [], []
        for seed in (1,):
            x, r, rep = isotropic.isotropic_packing([side] * 3, 1.0, seed=seed, tile=tile)
            pi, pj = isotropic._pairs(x, r, 0.0)
            cnt = np.bincount(np.concatenate([pi, pj]), minlength=r.size)
            inner = np.all((x > 2.0) & (x < side - 2.0), axis=1)
            zs.append(cnt[inner].mean())
            ps.append(rep["packing_fraction"])
        z[tile], phi[tile] = np.mean(zs), np.mean(ps)
    assert 6.2 < z[True] < 7.2 and z[True] == pytest.approx(z[False], rel=0.05)
    assert 0.62 < phi[True] < 0.67


def test_tile_counts_keep_the_cells_near_the_requested_size():
    vmean = np.pi / 6.0  # d_mean 1
    side = (8000 * vmean / 0.635) ** (1 / 3)
    assert list(isotropic.tile_counts([side] * 3, vmean, 0.635)) == [1, 1, 1]
    assert list(isotropic.tile_counts([10 * side, 2.4 * side, 0.3 * side], vmean, 0.635)) == \
        [10, 2, 1]


def test_a_large_box_is_tiled_and_a_small_one_is_not(monkeypatch):
    calls = []
    monkeypatch.setattr(isotropic, "tiled_packing",
                        lambda *a, **k: calls.append((a, k)) or (None, None, {}))
    isotropic.isotropic_packing([40.0, 40.0, 40.0], 1.0)  # ~77,000 elements
    assert len(calls) == 1 and list(calls[0][0][3]) == [2, 2, 2]
    class Jammed(Exception):
        pass

    def whole_box(*a, **k):
        raise Jammed

    monkeypatch.setattr(isotropic, "jam", whole_box)
    with pytest.raises(Jammed):  # 2,000 elements: the whole box, as before
        isotropic.isotropic_packing([12.5] * 3, 1.0)
    assert len(calls) == 1


def test_a_tiled_specimen_says_so_in_its_warnings():
    from geodem.build.specimen import packing_notes

    note, = packing_notes({"packing": {"n": 40_000, "tiles": [2, 2, 1], "tile_elements": 10_000}})
    assert "periodic cell of 10,000 repeated 2 x 2 x 1" in note and "20,000" in note
    assert packing_notes({"packing": {"n": 2_000, "bonds": 7_000}}) == []
    assert packing_notes({}) == []


def test_a_tiled_specimen_is_balanced_over_its_cell(monkeypatch):
    """A specimen from repeated cells (forced small here) is cemented and balanced with the
    standard balance's steps over one cell (50 x cell / d_mean per round), not over the box:
    it still ends in equilibrium (unbalanced ratio below the tolerance)."""
    from geodem.build.specimen import make_specimen

    monkeypatch.setattr(isotropic, "TILE_ABOVE", 0)
    monkeypatch.setattr(isotropic.tile_counts, "__defaults__", (300,))
    st, rep = make_specimen("box", [0.06, 0.06, 0.12], 0.01, 0.2, None, 3, 0)
    cell = max(rep["packing"]["tile_size"]) / 0.01
    assert rep["packing"]["tiles"] == [1, 1, 2]
    assert rep["balanced"] and rep["unbalanced_ratio"] < 1e-3
    assert rep["steps"] == rep["balance_rounds"] * round(50 * cell)
    assert rep["steps"] < rep["balance_rounds"] * 50 * 12  # the box is 12 d_mean tall


def _ucs_specimen(tmp_path):
    """The model of a small 3-D UCS workflow (library marble, 6 x 6 x 12 d_mean) and its
    platen test's area."""
    import types

    import yaml

    from geodem.workflow.schema import validate_document
    from geodem.workflow.yamlio import load_document

    doc = {"metadata": {"name": "ucs"},
           "model": {"type": "specimen", "dim": 3, "size": [0.06, 0.06, 0.12], "d_mean": 0.01,
                     "material": "rock"},
           "materials": {"rock": {"library": "marble"}},
           "steps": [{"kind": "uniaxial"}]}
    path = tmp_path / "ucs.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    cfg = validate_document(load_document(path))
    built = cfg.model.build(cfg)
    ctx = types.SimpleNamespace(state=built.state, model=built)
    return built, cfg.steps[0].platens(ctx)[-1]


def test_a_cut_face_specimen_is_measured_over_its_box(tmp_path, monkeypatch):
    """Faces cut from repeated cells: elements overhang the box, so the test takes the box's
    section (0.06 x 0.06 m), not the elements' (larger by up to a diameter per width); a box
    packed whole keeps the section over its elements, which is the box's (flat faces)."""
    whole, whole_area = _ucs_specimen(tmp_path)
    assert "cut_section" not in whole.info
    assert whole_area == pytest.approx(0.0036, rel=1e-3)  # flat faces on the box

    monkeypatch.setattr(isotropic, "TILE_ABOVE", 0)
    monkeypatch.setattr(isotropic.tile_counts, "__defaults__", (300,))
    cut, cut_area = _ucs_specimen(tmp_path)
    assert cut.info["cut_section"] == [0.06, 0.06]
    assert cut_area == pytest.approx(0.0036, rel=1e-12)
    st = cut.state
    over = (st.x + st.r[:, None]).max(axis=0) - (st.x - st.r[:, None]).min(axis=0)
    assert over[0] * over[1] > 1.05 * cut_area  # what the elements' extent would have read


def test_a_brazilian_disc_is_never_tiled_across_its_faces(monkeypatch):
    """A disc cut from cells periodic along its thickness splits early, and one whose poles
    are cut touches a platen with one or two elements, so the disc builder never tiles those
    axes: with tiling forced for every box (TILE_ABOVE = 0), a small 3-D disc comes from a
    strip periodic along x alone, its sides (y) and poles (z) flat and touched by elements as
    in a box jammed whole; below TILE_ABOVE, from its box jammed whole, as before."""
    from geodem.cases.brazilian import disc_with_platens
    from geodem.workflow.material import SpecimenMaterial

    mat = SpecimenMaterial(2600.0, macro={"E": 20e9, "nu": 0.15, "Tu": 5e6, "Cu": 60e6,
                                          "mu_i": 0.6, "rho": 2600.0})
    plain, rep_plain, _ = disc_with_platens(3, 0.08, 0.01, mat, thickness=0.03)
    assert "tiles" not in rep_plain["packing"] and rep_plain["packing"]["face_contacts"] > 0
    monkeypatch.setattr(isotropic, "TILE_ABOVE", 0)
    strip, rep, _ = disc_with_platens(3, 0.08, 0.01, mat, thickness=0.03)
    p = rep["packing"]  # one cell: at least STRIP_MIN_SIDE (6 d_mean) wide along x
    assert p["periodic_axes"] == [0] and p["tiles"] == [1, 1, 1]
    disc = strip.x[:rep["n_disc"]], strip.r[:rep["n_disc"]]
    # flat to the balance's settling (1e-8 m here; d_mean 1e-2 m): sides and poles
    for axis, top in ((1, 0.03), (2, 0.08)):
        low, high = disc[0][:, axis] - disc[1], disc[0][:, axis] + disc[1]
        assert low.min() == pytest.approx(0.0, abs=1e-6)
        assert high.max() == pytest.approx(top, abs=1e-6)
    # several elements at each pole, as in the box jammed whole
    for x, r in ((plain.x, plain.r), disc):
        assert ((x[:, 2] - r) < 1e-6).sum() >= 2
    assert not np.array_equal(strip.x[:10], plain.x[:10])


def test_a_whole_jam_beyond_its_limit_is_refused_before_any_work():
    with pytest.raises(ValueError, match=r"113,\d{3} elements jammed whole.*allowed: up to "
                                         r"60,000.*make d_mean larger"):
        isotropic.isotropic_packing([1.0, 1.0, 0.1], 0.01, tile=False)


STRIP = np.array([12.0, 6.0, 8.0])  # d_mean = 1: periodic along x, cells 6 x 6 x 8


@pytest.fixture(scope="module")
def strip():
    return isotropic.strip_packing(STRIP, 1.0, 0.2, (0,), (2, 1, 1), 220, seed=3)


def test_a_strip_is_stress_free_across_its_cells_and_flat_along_its_bounded_axes(strip):
    """Periodic along x, bounded by flat faces along y and z: every touching pair overlaps by
    the prestress (inside a cell and across two), every element at a face is tangent to it,
    and the faces are touched about as densely as those of a box jammed whole."""
    x, r, rep = strip
    pi, pj = isotropic._pairs(x, r, 0.05)
    gap = np.linalg.norm(x[pj] - x[pi], axis=1) - r[pi] - r[pj]
    touching = gap <= 0.0
    assert np.allclose(gap[touching], -isotropic.DEFAULT_PRESTRESS, atol=1e-10)
    assert rep["bonds"] == touching.sum() and rep["periodic_axes"] == [0]
    at_faces = 0
    for axis in (1, 2):
        low, high = x[:, axis] - r, x[:, axis] + r
        assert low.min() == pytest.approx(0.0, abs=1e-12)
        assert high.max() == pytest.approx(STRIP[axis])
        at_faces += np.isclose(low, 0.0, atol=1e-9).sum()
        at_faces += np.isclose(high, STRIP[axis], atol=1e-9).sum()
    assert at_faces == rep["face_contacts"]
    # per unit of face area, as in a box jammed whole
    _, _, whole = isotropic.isotropic_packing(STRIP, 1.0, seed=3)
    per_area = at_faces / (2 * 12.0 * (6.0 + 8.0))
    whole_per_area = whole["face_contacts"] / (2 * (12 * 6 + 12 * 8 + 6 * 8))
    assert per_area == pytest.approx(whole_per_area, rel=0.25)
    # bonds cross the cells' boundary as often as a plane through a cell's middle
    a, b = x[pi[touching]], x[pj[touching]]

    def crossing(plane):
        return int(((a[:, 0] - plane) * (b[:, 0] - plane) < 0).sum())

    assert crossing(6.0) == pytest.approx(0.5 * (crossing(3.0) + crossing(9.0)), rel=0.3)


def test_strip_counts_keep_one_cell_along_the_bounded_axes():
    vmean = np.pi / 6.0
    # the 3-D disc 60 across and 10 thick: cells of ~8,000 elements 11.4 d wide along x
    assert list(isotropic.strip_counts([60.0, 10.0, 60.0], vmean, 0.635, (0,))) == [5, 1, 1]
    assert list(isotropic.strip_counts([60.0, 10.0, 60.0], vmean, 0.635, (0, 2))) == [2, 1, 2]
    # a disc 300 across: cells of 8,000 would be 2.2 d wide; at least 6 wide, 50 of them
    assert list(isotropic.strip_counts([300.0, 10.0, 300.0], vmean, 0.635, (0,),
                                       min_side=6.0)) == [50, 1, 1]
    with pytest.raises(ValueError, match="periodic along some axes, not all"):
        isotropic.strip_packing(STRIP, 1.0, 0.2, (0, 1, 2), (2, 1, 1), 10)
    with pytest.raises(ValueError, match="one cell"):
        isotropic.strip_packing(STRIP, 1.0, 0.2, (0,), (2, 2, 1), 10)


def test_a_strip_jam_is_cached_apart_from_a_periodic_cell():
    from geodem.build import jam_cache

    args = (np.ones(10), np.zeros(3), np.full(3, 3.0), 1e-4, 0, 60, None)
    keys = {jam_cache.key(*args, p) for p in (True, False, (True, False, False))}
    assert len(keys) == 3


def test_a_strip_says_so_in_its_warnings():
    from geodem.build.specimen import packing_notes

    note, = packing_notes({"packing": {"n": 41_000, "tiles": [5, 1, 1], "tile_elements": 8_200,
                                       "tile_size": [0.12, 0.1, 0.6], "periodic_axes": [0]}})
    assert "strip cell of 8,200 repeated 5 x 1 x 1" in note and "periodic along x" in note
    assert "every 0.12 m along x" in note
