"""Unit tests of geodem.core.neighbors (cell-list rows, carry-over, sorting)."""
import numpy as np
import pytest

from geodem.core import neighbors as nb
from geodem.core.state import new_state


# ----------------------------------------------------------------------------- helpers

def random_state(n, dim, seed=0, width=16, density=0.6, spread=(0.6, 1.0)):
    """Random loose packing: n elements, radius U(spread)*0.5, ~density per unit volume."""
    rng = np.random.default_rng(seed)
    side = (n / density) ** (1.0 / dim)
    x = rng.random((n, dim)) * side
    r = 0.5 * rng.uniform(*spread, n)
    return new_state(x, r, np.ones(n), width=width)


def brute_pairs(x, r, skin):
    """O(N^2) contact-range pairs (i < j), same arithmetic as the kernel."""
    diff = x[:, None, :] - x[None, :, :]
    d2 = np.zeros(diff.shape[:2])
    for d in range(x.shape[1]):
        d2 = d2 + diff[..., d] * diff[..., d]
    c = (r[:, None] + r[None, :]) + skin
    ok = d2 <= c * c
    i, j = np.nonzero(np.triu(ok, 1))
    return set(zip(i.tolist(), j.tolist()))


def row_pairs(st):
    i, j, _ = nb.pairs(st)
    return set(zip(i.tolist(), j.tolist()))


def directed_entries(st):
    """{(i, j): (cstate, fs bytes, brate bytes)} of every valid row entry."""
    out = {}
    ii, kk = np.nonzero(st.nbr >= 0)
    for i, k in zip(ii.tolist(), kk.tolist()):
        j = int(st.nbr[i, k])
        out[(i, j)] = (int(st.cstate[i, k]), st.fs[i, k].tobytes(), st.brate[i, k].tobytes())
    return out


def mirror_col(st, i, j):
    k = np.flatnonzero(st.nbr[j] == i)
    assert k.size == 1
    return int(k[0])


def randomize_pair_state(st, seed=1, p_bond=0.5):
    """Random but symmetric per-pair state (cstate, brate equal, fs opposite)."""
    rng = np.random.default_rng(seed)
    i, j, k = nb.pairs(st)
    codes = rng.choice([0, 1, 2, 7], size=i.size, p=[1 - p_bond, p_bond * 0.6,
                                                     p_bond * 0.2, p_bond * 0.2])
    fsv = rng.normal(size=(i.size, st.dim))
    brv = rng.uniform(0.1, 2.0, i.size).astype(np.float32)
    for p in range(i.size):
        a, b, ka = int(i[p]), int(j[p]), int(k[p])
        kb = mirror_col(st, a, b)
        st.cstate[a, ka] = st.cstate[b, kb] = codes[p]
        st.fs[a, ka] = fsv[p]
        st.fs[b, kb] = -fsv[p]
        st.brate[a, ka] = st.brate[b, kb] = brv[p]


def assert_rows_sorted_compact(st):
    nbr = st.nbr
    cnt = nb.row_counts(st)
    cols = np.arange(st.width)
    assert np.array_equal(nbr >= 0, cols[None, :] < cnt[:, None])  # compact
    valid = nbr[:, 1:] >= 0
    assert np.all(np.diff(nbr, axis=1)[valid] > 0)  # sorted, no duplicates
    # padding holds the defaults
    pad = nbr < 0
    assert np.all(st.cstate[pad] == 0) and np.all(st.brate[pad] == 1.0)
    assert np.all(st.fs[pad] == 0.0)


# ----------------------------------------------------------------------------- pair set

@pytest.mark.parametrize("dim", [2, 3])
def test_pairs_match_brute_force(dim):
    st = random_state(1500, dim, seed=dim)
    skin = 0.07
    nb.build_rows(st, skin=skin)
    assert row_pairs(st) == brute_pairs(st.x, st.r, skin)
    nb.check_rows(st)
    assert_rows_sorted_compact(st)
    assert st.skin == skin
    assert np.array_equal(st.x_ref, st.x)
    assert np.all(st.cstate == 0) and np.all(st.brate == 1.0) and np.all(st.fs == 0.0)


@pytest.mark.parametrize("dim", [2, 3])
def test_pairs_wide_radius_range(dim):
    # radii over a factor 10: cell size is driven by the largest
    st = random_state(800, dim, seed=11, density=0.3, spread=(0.15, 1.5))
    nb.build_rows(st, skin=0.05, width=4)
    assert row_pairs(st) == brute_pairs(st.x, st.r, 0.05)
    nb.check_rows(st)


@pytest.mark.parametrize("kind", ["line", "plane", "point"])
def test_degenerate_boxes(kind):
    rng = np.random.default_rng(5)
    n = 400
    x = np.zeros((n, 3))
    if kind == "line":
        x[:, 0] = rng.random(n) * 150
    elif kind == "plane":
        x[:, :2] = rng.random((n, 2)) * 20
    else:
        x[:] = 1.0  # all coincident: everybody touches everybody
    r = 0.5 * rng.uniform(0.8, 1.0, n)
    st = new_state(x, r, np.ones(n), width=8)
    nb.build_rows(st, skin=0.1)
    assert row_pairs(st) == brute_pairs(x, r, 0.1)
    nb.check_rows(st)
    assert_rows_sorted_compact(st)


def test_sparse_model_caps_grid():
    # two tiny clusters 1e12 apart: the grid must not follow the box size
    rng = np.random.default_rng(3)
    a = rng.random((100, 3)) * 4
    b = a + 1e12
    x = np.vstack([a, b])
    r = np.full(200, 0.5)
    lo, h, nc = nb.cell_grid(x, 0.5, 0.1)
    assert nc[0] * nc[1] * nc[2] <= 400
    assert h >= 1.1
    st = new_state(x, r, np.ones(200))
    nb.build_rows(st, skin=0.1)
    assert row_pairs(st) == brute_pairs(x, r, 0.1)


def test_pair_at_exact_cut_distance():
    # distance == r_i + r_j + skin exactly (representable numbers): included
    x = np.array([[0.0, 0.0, 0.0], [2.25, 0.0, 0.0], [4.75, 0.0, 0.0]])
    r = np.array([1.0, 1.0, 1.0])
    st = new_state(x, r, np.ones(3), width=4)
    nb.build_rows(st, skin=0.25)
    assert row_pairs(st) == {(0, 1)}


# ----------------------------------------------------------------------------- carry-over

@pytest.mark.parametrize("dim", [2, 3])
def test_carry_over_is_exact(dim):
    rng = np.random.default_rng(10 + dim)
    st = random_state(1200, dim, seed=20 + dim)
    skin = 0.1
    nb.build_rows(st, skin=skin)
    randomize_pair_state(st, seed=dim)
    before = directed_entries(st)

    # small moves (< skin/2) everywhere, plus a few bonded partners torn far apart
    st.x += rng.uniform(-0.2, 0.2, st.x.shape) * skin
    i, j, k = nb.pairs(st)
    bonded = np.flatnonzero(st.cstate[i, k] != 0)
    torn = set()
    for p in bonded[:5]:
        a = int(j[p])
        st.x[a] += 25.0  # far beyond any contact range
        torn.add(a)
    nb.build_rows(st, skin=skin)
    after = directed_entries(st)
    nb.check_rows(st)
    assert_rows_sorted_compact(st)

    geo = brute_pairs(st.x, st.r, skin)
    for (a, b), val in after.items():
        if (a, b) in before:
            assert val == before[(a, b)], (a, b)  # bitwise
        else:  # a new pair: defaults
            assert val[0] == 0
            assert val[1] == np.zeros(dim).tobytes()
            assert val[2] == np.float32(1.0).tobytes()
            assert (min(a, b), max(a, b)) in geo
    for (a, b), val in before.items():
        if val[0] != 0:
            assert (a, b) in after  # never dropped
        else:  # unbonded kept iff in contact range
            assert ((a, b) in after) == ((min(a, b), max(a, b)) in geo)
    # the torn-apart bonded pairs are still there
    for a in torn:
        assert any(st.cstate[a, :nb.row_counts(st)[a]] != 0)
    # exact pair set: contact range union non-zero-state pairs
    keep = {(min(a, b), max(a, b)) for (a, b), v in before.items() if v[0] != 0}
    assert row_pairs(st) == geo | keep


def test_carry_over_special_values_bitwise():
    # -0.0, NaN payloads, denormals survive a rebuild bit for bit
    st = random_state(300, 3, seed=14)
    nb.build_rows(st, skin=0.1)
    i, j, k = nb.pairs(st)
    special = np.array([-0.0, np.nan, 5e-324]).view(np.int64)
    special[1] |= 0x1234  # NaN with a payload
    st.fs[i[:5], k[:5]] = special.view(np.float64)
    st.brate[i[:5], k[:5]] = np.array(-0.0, np.float32)
    st.cstate[i[:5], k[:5]] = 3
    before = directed_entries(st)
    st.x[i[0]] += 30.0  # one of them torn apart as well
    nb.build_rows(st)
    after = directed_entries(st)
    for p in range(5):
        key = (int(i[p]), int(j[p]))
        assert after[key] == before[key]


def test_carry_over_independent_of_old_column_order():
    st = random_state(600, 3, seed=4)
    nb.build_rows(st, skin=0.1)
    randomize_pair_state(st, seed=4)
    st.x += 0.01
    a = st.copy()
    b = st.copy()
    # shuffle b's rows column-wise (rows stay compact)
    rng = np.random.default_rng(0)
    cnt = nb.row_counts(b)
    for i in range(b.n):
        c = int(cnt[i])
        p = rng.permutation(c)
        for name in ("nbr", "cstate", "fs", "brate"):
            arr = getattr(b, name)
            arr[i, :c] = arr[i, :c][p]
    nb.build_rows(a)
    nb.build_rows(b)
    for name in ("nbr", "cstate", "fs", "brate"):
        assert np.array_equal(getattr(a, name), getattr(b, name))


def test_rebuild_is_idempotent_and_deterministic():
    st = random_state(1000, 2, seed=8)
    nb.build_rows(st, skin=0.08)
    randomize_pair_state(st, seed=8)
    c1 = st.copy()
    c2 = st.copy()
    nb.build_rows(c1)
    nb.build_rows(c2)
    for name in ("nbr", "cstate", "fs", "brate", "x_ref"):
        assert np.array_equal(getattr(c1, name), getattr(c2, name))
        assert np.array_equal(getattr(c1, name), getattr(st, name))  # nothing moved


# ----------------------------------------------------------------------------- symmetry

@pytest.mark.parametrize("dim", [2, 3])
def test_symmetry(dim):
    st = random_state(700, dim, seed=30 + dim)
    nb.build_rows(st, skin=0.1)
    randomize_pair_state(st, seed=1)
    st.x += np.random.default_rng(2).normal(0, 0.02, st.x.shape)
    nb.build_rows(st)
    ent = directed_entries(st)
    for (a, b), (c, f, br) in ent.items():
        assert (b, a) in ent
        c2, f2, br2 = ent[(b, a)]
        assert c == c2 and br == br2
        assert np.array_equal(np.frombuffer(f), -np.frombuffer(f2))
    nb.check_rows(st)


def test_check_rows_detects_asymmetry():
    st = random_state(300, 2, seed=2)
    nb.build_rows(st, skin=0.1)
    i, j, k = nb.pairs(st)
    st.cstate[i[0], k[0]] = 1
    with pytest.raises(ValueError, match="cstate"):
        nb.check_rows(st)


# ----------------------------------------------------------------------------- width

def test_width_grows_never_drops():
    st = random_state(1000, 3, seed=9, density=1.2)  # dense: ~20 neighbours
    nb.build_rows(st, skin=0.2, width=4)
    cnt = nb.row_counts(st)
    assert cnt.max() > 4
    assert st.width == -(-int(cnt.max()) // 4) * 4
    assert row_pairs(st) == brute_pairs(st.x, st.r, 0.2)
    nb.check_rows(st)
    # width=None keeps a larger current width
    w = st.width
    nb.build_rows(st, width=w + 8)
    assert st.width == w + 8
    nb.build_rows(st)
    assert st.width == w + 8
    # asking for less shrinks only as far as the rows allow
    nb.build_rows(st, width=4)
    assert st.width == w
    assert row_pairs(st) == brute_pairs(st.x, st.r, 0.2)


def test_width_growth_keeps_state_of_bonds():
    # bonds given in a narrow width, then geometric neighbours force growth
    st = random_state(500, 2, seed=12, density=1.0, width=4)
    geo = sorted(brute_pairs(st.x, st.r, 0.05))
    i = np.array([p[0] for p in geo])
    j = np.array([p[1] for p in geo])
    sel = np.random.default_rng(0).random(i.size) < 0.3
    br = np.linspace(0.5, 1.5, int(sel.sum()))
    nb.rows_from_pairs(st, i[sel], j[sel], bonded=True, brate=br)
    before = directed_entries(st)
    w0 = st.width
    nb.build_rows(st, skin=0.3)
    assert st.width > w0  # the growth path (rows rebuilt twice) was taken
    after = directed_entries(st)
    for key, val in before.items():
        assert after[key] == val
    assert row_pairs(st) == brute_pairs(st.x, st.r, 0.3) | {(a, b) for a, b in zip(i[sel], j[sel])}
    assert st.width % 4 == 0 and st.width >= nb.row_counts(st).max()


# ----------------------------------------------------------------------------- needs_rebuild

def test_needs_rebuild():
    st = random_state(300, 3, seed=1)
    assert nb.needs_rebuild(st)  # never built (skin 0)
    nb.build_rows(st, skin=0.2)
    assert not nb.needs_rebuild(st)
    st.x[17, 1] += 0.099
    assert not nb.needs_rebuild(st)
    st.x[17, 1] += 0.002
    assert nb.needs_rebuild(st)
    nb.build_rows(st)
    assert not nb.needs_rebuild(st)
    # look-ahead: 10 steps of 0.01 s at 0.5 m/s = 0.05 m
    st.dt = 0.01
    st.v[3] = [0.0, 0.3, 0.4]
    st.x[5, 0] += 0.06
    assert not nb.needs_rebuild(st, steps_ahead=0)
    assert not nb.needs_rebuild(st, steps_ahead=7)  # 0.06 + 0.035 < 0.1
    assert nb.needs_rebuild(st, steps_ahead=10)  # 0.06 + 0.05 > 0.1
    st.x[2, 2] = np.nan
    assert nb.needs_rebuild(st)


# ----------------------------------------------------------------------------- validation

@pytest.mark.parametrize("skin", [0.0, -1.0, np.nan, np.inf, "a"])
def test_bad_skin(skin):
    st = random_state(50, 2)
    with pytest.raises(ValueError, match="skin"):
        nb.build_rows(st, skin=skin)


def test_default_skin_must_be_set():
    st = random_state(50, 2)
    with pytest.raises(ValueError, match=r"skin.*\(0, inf\)"):
        nb.build_rows(st)  # state.skin is 0


def test_nan_position_named():
    st = random_state(50, 3)
    st.x[13, 2] = np.nan
    st.x[40, 0] = np.inf
    with pytest.raises(ValueError, match="element 13"):
        nb.build_rows(st, skin=0.1)


# ----------------------------------------------------------------------------- rows_from_pairs

def test_rows_from_pairs_fills_both_directions():
    st = new_state(np.random.default_rng(0).random((6, 2)), 0.1, 1.0, width=2)
    i = np.array([0, 0, 0, 4, 2])
    j = np.array([1, 2, 3, 0, 5])
    br = np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    nb.rows_from_pairs(st, i, j, bonded=True, brate=br)
    assert st.width == 4  # 0 has 4 partners
    assert list(st.nbr[0]) == [1, 2, 3, 4]
    assert np.allclose(st.brate[0], np.float32([0.5, 0.6, 0.7, 0.8]))
    assert list(st.nbr[2][:2]) == [0, 5] and st.brate[2, 1] == np.float32(0.9)
    assert np.all(st.cstate[st.nbr >= 0] == 1)
    assert np.all(st.fs == 0.0)
    nb.check_rows(st)
    assert_rows_sorted_compact(st)
    nb.rows_from_pairs(st, [1], [2], bonded=False)
    assert st.width == 4  # never below the current width
    assert row_pairs(st) == {(1, 2)} and st.cstate[1, 0] == 0 and st.brate[1, 0] == 1.0


@pytest.mark.parametrize("i,j,msg", [
    ([0, 1], [1, 0], "more than once"),
    ([0, 2, 0], [1, 3, 1], "more than once"),
    ([0, 3], [1, 3], "self pair"),
    ([0, 5], [1, 9], "out of range"),
    ([-1], [2], "out of range"),
    ([0, 1], [1], "equal length"),
    ([0.0], [1.0], "integer"),
])
def test_rows_from_pairs_errors(i, j, msg):
    st = new_state(np.zeros((6, 3)), 0.1, 1.0, width=4)
    nb.rows_from_pairs(st, [2], [4])
    ref = st.copy()
    with pytest.raises(ValueError, match=msg):
        nb.rows_from_pairs(st, i, j)
    for name in ("nbr", "cstate", "fs", "brate"):
        assert np.array_equal(getattr(st, name), getattr(ref, name))


def test_rows_from_pairs_then_build_keeps_bonds():
    st = random_state(400, 3, seed=6)
    nb.build_rows(st, skin=0.1)
    i, j, _ = nb.pairs(st)
    nb.rows_from_pairs(st, i, j, bonded=True, brate=0.75)
    st.x[i[0]] += 50.0
    nb.build_rows(st)
    assert (int(i[0]), int(j[0])) in row_pairs(st)
    assert st.brate[i[0], 0] == np.float32(0.75)
    nb.check_rows(st)


# ----------------------------------------------------------------------------- spatial sort

@pytest.mark.parametrize("dim", [2, 3])
def test_spatial_sort_preserves_pairs_and_state(dim):
    st = random_state(900, dim, seed=40 + dim)
    nb.build_rows(st, skin=0.1)
    randomize_pair_state(st, seed=3)
    rng = np.random.default_rng(1)
    for name in st.array_names():
        a = getattr(st, name)
        if name == "props":  # keep column 0, the radii
            a[:, 1:] = rng.random(a[:, 1:].shape)
        elif name not in ("nbr", "cstate", "fs", "brate", "x") and a.dtype.kind == "f":
            a[...] = rng.random(a.shape)
    st.group[:] = rng.integers(0, 5, st.n)
    old = st.copy()
    before = directed_entries(st)
    perm = nb.spatial_sort(st)
    assert np.array_equal(np.sort(perm), np.arange(st.n))
    after = directed_entries(st)
    relabelled = {(int(perm[a]), int(perm[b])): v for (a, b), v in after.items()}
    assert relabelled == before
    # the pair state moved with its pair (above); every other array is permuted
    for name in st.array_names():
        if name in st.row_array_names():
            continue
        assert np.array_equal(getattr(st, name), getattr(old, name)[perm]), name
    nb.check_rows(st)
    # rows come out sorted by the new indices, as build_rows leaves them
    valid = st.nbr >= 0
    steps = np.diff(st.nbr, axis=1)
    assert (steps[valid[:, 1:]] > 0).all() and valid.sum() == before.__len__()
    # Morton order is spatially coherent: consecutive elements are close on average
    step = np.linalg.norm(np.diff(st.x, axis=0), axis=1).mean()
    step_old = np.linalg.norm(np.diff(old.x, axis=0), axis=1).mean()
    assert step < 0.5 * step_old
    # and rebuilding after the sort gives the relabelled rows
    nb.build_rows(st)
    assert {tuple(sorted((int(perm[a]), int(perm[b])))) for a, b in row_pairs(st)} == \
        row_pairs(old)


def test_spatial_sort_deterministic():
    st = random_state(500, 3, seed=2)
    nb.build_rows(st, skin=0.1)
    a, b = st.copy(), st.copy()
    pa, pb = nb.spatial_sort(a), nb.spatial_sort(b)
    assert np.array_equal(pa, pb)
    assert np.array_equal(a.nbr, b.nbr)
    # sorting a sorted state is the identity
    assert np.array_equal(nb.spatial_sort(a), np.arange(a.n))


# ----------------------------------------------------------------------------- queries

def test_pairs_and_row_counts():
    st = random_state(500, 2, seed=7)
    nb.build_rows(st, skin=0.1)
    i, j, k = nb.pairs(st)
    assert np.all(i < j)
    assert np.array_equal(st.nbr[i, k], j)
    assert 2 * i.size == int(nb.row_counts(st).sum())
    order = np.lexsort((k, i))
    assert np.array_equal(order, np.arange(i.size))


def test_empty_and_isolated():
    st = new_state(np.array([[0.0, 0.0], [100.0, 0.0]]), 0.5, 1.0, width=4)
    nb.build_rows(st, skin=0.1)
    assert np.all(st.nbr == -1)
    assert nb.pairs(st)[0].size == 0
    assert not nb.needs_rebuild(st)
    st0 = new_state(np.zeros((0, 3)), 0.5, 1.0, width=4)
    nb.build_rows(st0, skin=0.1)
    assert nb.spatial_sort(st0).size == 0
    assert not nb.needs_rebuild(st0)


def test_check_plan_by_hand():
    skin = 0.1  # half skin 0.05
    # slow: no rebuild, the longest interval
    assert nb.check_plan(0.01, 0.001, skin, 10) == (False, 10)
    # (0.05 - 0.03) / 0.004 = 5 steps of room left
    assert nb.check_plan(0.03, 0.004, skin, 10) == (False, 5)
    # the next step could pass half the skin: rebuild, then 0.05 / 0.02 = 2.5 -> 2 steps
    assert nb.check_plan(0.04, 0.02, skin, 10) == (True, 2)
    # faster than half a skin per step: rebuild, and check at every step
    assert nb.check_plan(0.0, 0.2, skin, 10) == (True, 1)
    # at rest
    assert nb.check_plan(0.0, 0.0, skin, 10) == (False, 10)


def test_fast_elements_are_checked_before_they_can_cross_the_skin():
    """Two unbonded discs fly at each other, each moving 0.3 of the half skin per step: with a
    fixed 10-step check interval they would touch unseen (overlapping deeper at every step until the
    next check). The engine checks sooner while elements are fast (geodem.core.engine), so the
    pair is in the rows before it touches, and the collision is resolved from its first step.
    (With the fixed interval: touching at step 17, first seen at step 20.)"""
    from geodem.build.lattice import bonded_state
    from geodem.core.engine import Simulation

    st = bonded_state(np.array([[0.0, 0.0], [1.25, 0.0]]), 0.5, density=1000.0, kn=1e6,
                      ks=0.0, xb=0.0, fs0=0.0, mu=0.0, gap=1e-6, thickness=1.0)
    assert (st.cstate == 0).all() and st.skin == pytest.approx(0.05)
    sim = Simulation(st, check_every=10, monitor_every=0)
    v = 0.3 * 0.5 * st.skin / st.dt  # 0.3 half skins per step
    st.v[0, 0], st.v[1, 0] = v, -v
    sim.backend.push(("v",))
    touched = False
    for _ in range(30):
        sim.run(1)
        s = sim.sync()
        gap = abs(s.x[1, 0] - s.x[0, 0]) - 1.0
        if gap < 0.0:
            touched = True
            assert 1 in s.nbr[0].tolist(), f"touching at step {s.step} but not in the rows"
    assert touched and sim.rebuilds >= 1
