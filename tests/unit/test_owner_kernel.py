"""Each contact evaluated once, by its owner i < j (geodem.backends.numba_backend)."""
import numpy as np
import pytest

from geodem.core import neighbors as nb
from geodem.core.engine import Simulation
from geodem.core.state import new_state

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def chain_rows():
    """Four elements: 0-1, 0-2, 1-3, 2-3 (a square), rows sorted."""
    st = new_state(np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float), 0.5, 1.0, width=4)
    nb.rows_from_pairs(st, np.array([0, 0, 1, 2]), np.array([1, 2, 3, 3]), bonded=True)
    return st


def test_owner_tables_by_hand():
    st = chain_rows()
    # rows: 0: [1, 2]; 1: [0, 3]; 2: [0, 3]; 3: [1, 2]
    assert st.nbr[:, :2].tolist() == [[1, 2], [0, 3], [0, 3], [1, 2]]
    ostart, mirror = nb.owner_tables(st.nbr)
    assert ostart.tolist() == [0, 1, 1, 2]  # 3 owns nothing: its row ends at column 2
    # owned entries only: 0 is column 0 of rows 1 and 2; 1 and 2 are columns 0 and 1 of row 3
    assert mirror[:, :2].tolist() == [[0, 0], [-1, 0], [-1, 1], [-1, -1]]
    assert mirror.dtype == np.int8


def test_owner_tables_refuse_unsorted_or_one_sided_rows_and_sort_rows_mends_order():
    st = chain_rows()
    st.nbr[1, :2] = [3, 0]
    st.fs[1, 0] = [5.0, 6.0]  # the pair 1-3's spring moves with it
    assert nb.owner_tables(st.nbr) is None
    assert nb.sort_rows(st) == 1
    assert st.nbr[1, :2].tolist() == [0, 3] and st.fs[1, 1].tolist() == [5.0, 6.0]
    assert nb.owner_tables(st.nbr) is not None
    st.nbr[3, 1] = -1  # 2 lists 3, 3 no longer lists 2: an owned entry without its mirror
    assert nb.owner_tables(st.nbr) is None
    st.nbr[3, 1] = 2
    st.nbr[2, 1] = -1  # 3 lists 2, 2 no longer lists 3: every owned entry has its mirror
    assert nb.owner_tables(st.nbr) is None


def breaking_block(n=1500):
    from geodem.bench import SPACING, build_specimen

    st = build_specimen(n)
    st.xb[:] = 0.004 * SPACING  # the misfits' vibration breaks a share of the bonds
    st.fs0[:] = 2.0e-3 * st.kn * SPACING
    return st


VARIANTS = [(False, False), (True, False), (False, True), (True, True)]


@pytest.mark.parametrize("rotation,damping", VARIANTS)
def test_each_contact_once_matches_both_rows_and_leaves_the_state_complete(rotation, damping):
    from geodem.core.state import enable_contact_damping, enable_rotation

    a = breaking_block()
    if rotation:
        enable_rotation(a, mu_r=0.2)
    if damping:
        enable_contact_damping(a, restitution=0.5)
    b = a.copy()
    sa = Simulation(a, backend="numba", monitor_every=0)
    sb = Simulation(b, backend="numba", monitor_every=0)
    sb.backend.once = False
    assert sa.backend.tables is not None
    sa.run(300)
    sb.run(300)
    ca, cb = sa.crack_log(), sb.crack_log()
    assert ca.size > 20  # the test must see bonds break, in tension and in shear
    assert set(np.unique(ca["type"]).tolist()) == {1, 2}
    # same contacts break at the same steps; forces agree to round-off (summation order)
    assert np.array_equal(np.sort(ca, order=["i", "j"]), np.sort(cb, order=["i", "j"]))
    assert np.array_equal(a.cstate, b.cstate)
    scale = np.abs(b.v).max()
    assert np.abs(a.v - b.v).max() < 1e-9 * scale
    assert np.abs(a.fs - b.fs).max() < 1e-9 * np.abs(b.fs).max()
    # after run every partner slot holds exactly the opposite of its owner's spring
    i, j, k = nb.pairs(a)
    kj = np.array([np.flatnonzero(a.nbr[q] == p)[0] for p, q in zip(i, j)])
    assert np.array_equal(a.fs[j, kj], -a.fs[i, k])
    assert np.array_equal(a.cstate[j, kj], a.cstate[i, k])
    if rotation:
        assert np.abs(a.w - b.w).max() < 1e-9 * np.abs(b.w).max()
        assert np.abs(b.mr).max() > 0 and np.array_equal(a.mr[j, kj], -a.mr[i, k])
        assert np.abs(a.mr - b.mr).max() < 1e-9 * np.abs(b.mr).max()
    if damping:
        assert np.abs(b.fdash).max() > 0
        assert np.abs(a.fdash - b.fdash).max() < 1e-9 * np.abs(b.fdash).max()
    # energy books agree (heat of the breaks booked half on each side)
    ea, eb = sa.energies(), sb.energies()
    assert eb["heat_break_normal"] > 0 and eb["heat_break_shear"] > 0
    for key in ("kinetic", "elastic", "heat_break_normal", "heat_break_shear", "heat_friction",
                "heat_viscous", "total", "closure_error"):
        assert ea[key] == pytest.approx(eb[key], rel=1e-8, abs=1e-12 * abs(eb["total"])), key
    assert not sa.backend.buf.any()  # the posts' buffer is emptied every step


def test_rows_changed_by_a_rebuild_get_new_tables():
    a = breaking_block(600)
    sim = Simulation(a, backend="numba", monitor_every=0)
    sim.run(5)
    old = sim.backend.tables
    a.x[:] += 0.0  # same geometry, narrower rows: a rebuild with a new width
    nb.build_rows(a, width=a.width + 4)
    sim.backend.push()
    ostart, mirror = sim.backend.tables
    assert mirror.shape == a.nbr.shape and mirror is not old[1]
    assert np.array_equal((ostart, mirror)[0], nb.owner_tables(a.nbr)[0])
    sim.run(5)  # and stepping goes on (the monitor would stop a corrupted run)
    assert np.isfinite(a.v).all()


def test_results_do_not_depend_on_how_many_threads_run_the_buffers():
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs a numba pool of 2 threads or more")
    out = []
    for threads in (1, 2):
        st = breaking_block(800)
        numba.set_num_threads(threads)
        try:
            sim = Simulation(st, backend="numba", monitor_every=0)
            sim.run(60)
        finally:
            numba.set_num_threads(1)
        out.append((st.x.copy(), st.v.copy(), st.fs.copy(), sim.crack_log()))
    for a, b in zip(out[0], out[1]):
        assert np.array_equal(a, b)


def test_an_option_switched_on_after_attach_gets_its_buffer_columns():
    from geodem.core.state import enable_rotation

    a = breaking_block(600)
    b = a.copy()
    sims = [Simulation(st, backend="numba", monitor_every=0) for st in (a, b)]
    sims[1].backend.once = False
    for sim in sims:
        sim.run(5)
        enable_rotation(sim.state, mu_r=0.2)  # no push: the backend notices the new variant
        sim.run(40)
    assert sims[0].backend.buf.shape[1] == 12
    assert np.abs(b.w).max() > 0 and np.abs(a.w - b.w).max() < 1e-9 * np.abs(b.w).max()
    assert np.abs(a.v - b.v).max() < 1e-9 * np.abs(b.v).max()


def test_prefetching_changes_no_result_and_is_on_for_large_models_only():
    from geodem.backends.numba_backend import NumbaBackend

    out = []
    for ahead in (0, 2, 5):
        st = breaking_block(800)
        sim = Simulation(st, backend="numba", monitor_every=0)
        assert sim.backend.ahead == 0  # 800 elements: below PREFETCH_MIN
        sim.backend.ahead = ahead
        sim.run(40)
        out.append((st.x.copy(), st.v.copy(), st.fs.copy(), sim.crack_log()))
    assert len(out[0][3]) > 0  # bonds broke, so the state codes were exercised too
    for other in out[1:]:
        for a, b in zip(out[0], other):
            assert np.array_equal(a, b)
    side = int(np.ceil(np.sqrt(NumbaBackend.PREFETCH_MIN)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
    big = new_state(grid.astype(float), 0.5, 1.0, kn=1.0, ks=0.5)  # touching discs, a grid
    big.x[:, 0] += 0.01 * np.sin(grid[:, 1])  # some motion, so the rows are read and written
    nb.build_rows(big, skin=0.1)
    runs = []
    for ahead in (NumbaBackend.PREFETCH_AHEAD, 0):  # the 2-D kernel, prefetching or not
        st = big.copy()
        sim = Simulation(st, backend="numba", monitor_every=0)
        assert sim.backend.ahead == NumbaBackend.PREFETCH_AHEAD  # 33,124 elements: on
        sim.backend.ahead = ahead
        sim.run(3)
        runs.append((st.x, st.v, st.fs))
    assert np.abs(runs[0][1]).max() > 0.0
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_cross_tables_by_hand():
    # chain_rows: owned contacts 0-1, 0-2, 1-3, 2-3; slabs of 2 elements: {0, 1}, {2, 3}
    st = chain_rows()
    ostart, _ = nb.owner_tables(st.nbr)
    cstart, spill, inc_start = nb.cross_tables(st.nbr, ostart, 2)  # two slabs
    # crossing contacts in owner order: c=0 is 0-2 (row 0, column 1), c=1 is 1-3
    assert cstart.tolist() == [0, 1, 2, 2, 2]
    # element 2 receives spill row 0, element 3 spill row 1
    assert inc_start.tolist() == [0, 0, 0, 1, 2]
    assert spill[:2].tolist() == [0, 1] and spill.size == 3  # one spare entry
    # one slab: nothing crosses; four slabs of one element: every owned contact crosses
    cstart, spill, inc_start = nb.cross_tables(st.nbr, ostart, 1)
    assert cstart[-1] == 0 and not inc_start.any()
    cstart, spill, inc_start = nb.cross_tables(st.nbr, ostart, 4)
    assert cstart.tolist() == [0, 2, 3, 4, 4] and inc_start.tolist() == [0, 0, 1, 2, 4]
    # element 3's rows hold 1-3 (owner 1: c=2) before 2-3 (owner 2: c=3)
    assert spill[:4].tolist() == [0, 1, 2, 3]


def test_spill_rows_are_grouped_by_partner_in_owner_order():
    st = breaking_block(1500)
    ostart, _ = nb.owner_tables(st.nbr)
    cstart, spill, inc_start = nb.cross_tables(st.nbr, ostart, 5)
    ends = [(t + 1) * st.n // 5 for t in range(5)]  # slab t: from t n // 5 to its end
    owners, partners = [], []
    for i in range(st.n):
        hi = next(e for e in ends if i < e)
        row = st.nbr[i, ostart[i]:]
        cross = row[(row >= hi)]
        assert cstart[i + 1] - cstart[i] == cross.size
        owners += [i] * cross.size
        partners += cross.tolist()
    nc = len(owners)
    assert nc > 100 and cstart[-1] == nc
    target = np.empty(nc, int)
    target[spill[:nc]] = np.arange(nc)  # crossing contact posted into each spill row
    assert sorted(spill[:nc].tolist()) == list(range(nc))  # one row per contact
    p = np.asarray(partners)[target]
    o = np.asarray(owners)[target]
    # rows of element j are inc_start[j]..inc_start[j+1]-1, its contacts by ascending owner
    assert np.array_equal(p, np.repeat(np.arange(st.n), np.diff(inc_start)))
    assert all(np.all(np.diff(o[inc_start[j]:inc_start[j + 1]]) > 0) for j in range(st.n))


def test_the_slab_count_is_the_models_own():
    from geodem.backends.numba_backend import SLAB_ELEMENTS, SLAB_MAX, slab_count

    assert [slab_count(n) for n in (1, 2, SLAB_ELEMENTS, SLAB_ELEMENTS + 1)] == [1, 1, 1, 2]
    assert slab_count(10 * SLAB_ELEMENTS) == 10
    assert slab_count(10**9) == SLAB_MAX


@pytest.mark.parametrize("slabs", [1, 3, 8])
def test_any_number_of_slabs_gives_the_both_rows_result_and_one_buffer(slabs, monkeypatch):
    # more slabs than threads run one after another
    from geodem.backends import numba_backend

    monkeypatch.setattr(numba_backend, "SLAB_ELEMENTS", 1)
    monkeypatch.setattr(numba_backend, "SLAB_MAX", slabs)
    a = breaking_block(1200)
    b = a.copy()
    sa = Simulation(a, backend="numba", monitor_every=0)
    sb = Simulation(b, backend="numba", monitor_every=0)
    sb.backend.once = False
    assert sa.backend.slabs == slabs
    ncross = int(sa.backend.cross[0][-1])
    assert (ncross > 0) == (slabs > 1)
    # one row per element plus one per crossing contact, whatever the slab count
    assert sa.backend.buf.shape == (a.n + max(1, ncross), 6)
    sa.run(200)
    sb.run(200)
    assert sa.crack_log().size > 20
    assert np.array_equal(np.sort(sa.crack_log(), order=["i", "j"]),
                          np.sort(sb.crack_log(), order=["i", "j"]))
    assert np.abs(a.v - b.v).max() < 1e-9 * np.abs(b.v).max()
    assert np.abs(a.fs - b.fs).max() < 1e-9 * np.abs(b.fs).max()
    assert not sa.backend.buf.any()  # every row emptied by the finish pass


def test_rows_rebuilt_in_place_between_runs_need_no_push():
    # build_rows writes the rows in place at the same width: the numba backend's owner tables
    # used to stay those of the old rows (only a new array object was noticed)
    x = np.array([[0.0, 0, 0], [0.0099, 0, 0], [0.1, 0, 0], [0.2, 0, 0]])
    out = {}
    for be in ("numba", "numpy"):
        st = new_state(x, 0.005, 1e-3, kn=1e5, ks=3e4, mu=0.5)
        nb.build_rows(st, skin=0.001)
        sim = Simulation(st, backend=be, check_every=50)
        sim.run(5)
        st.x[3] = [0.1099, 0, 0]  # element 3 moved next to element 2, then new rows
        v = nb.rows_version(st)
        nb.build_rows(st)
        assert nb.rows_version(st) == v + 1
        sim.run(5)
        out[be] = st.v.copy()
    assert out["numba"][3, 0] > 0.3
    assert np.allclose(out["numba"], out["numpy"], rtol=1e-12, atol=0)


def test_the_crack_log_does_not_depend_on_how_a_run_is_cut_into_calls():
    # a harvest of the contact states (at each check and at the end of each run call) may span
    # several steps; the log is ordered by step, then pair, so the calls do not show in it
    logs = []
    for calls in ((60,), (7,) * 8 + (4,)):
        st = breaking_block(600)
        sim = Simulation(st, backend="numba", monitor_every=0)
        for n in calls:
            sim.run(n)
        logs.append(sim.crack_log())
    a, b = logs
    assert len(a) > 20 and np.unique(a["time"]).size > 3
    assert np.array_equal(a, b)
    assert np.all(np.diff(a["time"]) >= 0)
