"""Neighbour rows: cell-list build with exact per-pair state carry-over.

Every element ``i`` owns a row ``nbr[i, :W]`` of neighbour indices, valid entries first
(compact), padded with ``-1``. Each contact is stored in both rows (``j`` in row ``i`` iff
``i`` in row ``j``); its state (``cstate``, ``fs``, ``brate``) sits beside it in the same
column. See :mod:`geodem.core.state` for the meaning of the codes.

Criteria used by :func:`build_rows` (the "contact range")
    * unbonded entry ``(i, j)`` (``cstate == 0``) is present iff
      ``|x_i - x_j|^2 <= (r_i + r_j + skin)^2`` (computed bit-identically from both sides,
      so the rows stay symmetric);
    * an entry with ``cstate != 0`` (bonded, or broken but not yet harvested) is NEVER
      dropped, however far the partners drift;
    * per-pair state is carried over bitwise by pair identity: for a new entry ``(i, j)``
      the old row of ``i`` is searched for ``j``; new pairs get ``cstate 0, fs 0, brate 1``;
    * rows come out sorted by neighbour index (deterministic whatever the thread count
      or the old column order) and compact;
    * a row never loses entries for lack of room: the width grows instead (to the next
      multiple of 4 at or above the largest row count, never below the current width).

The rows stay valid until some element has moved more than ``skin / 2`` from its
position at the last build (``x_ref``): two elements approaching each other then close at
most ``skin``. :func:`needs_rebuild` implements that test (with an optional look-ahead);
:func:`check_plan` is the engine's schedule built on it (rebuild now? next check when?).
Radii must not grow between builds (or the skin must cover the growth).

All heavy work is in numba kernels (``cache=True``, ``parallel=True`` where useful).
Build cost is O(N) with a cell list whose cell size is at least ``2*max(r) + skin``; the
number of cells is capped at ~2N by enlarging cells so sparse or degenerate (line,
plane) models never allocate a huge grid.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from geodem.core.state import State

__all__ = [
    "build_rows",
    "needs_rebuild",
    "check_plan",
    "rows_from_pairs",
    "spatial_sort",
    "row_counts",
    "pairs",
    "check_rows",
    "cell_grid",
    "owner_tables",
    "sort_rows",
]

_BLOCK = 256  # elements per parallel chunk (thread-local scratch is allocated per chunk)
_CELL_SAFETY = 1.0 + 1e-9  # cell size margin against rounding in floor((x - lo) / h)
_INT_OF_SIZE = {1: np.int8, 2: np.int16, 4: np.int32, 8: np.int64}
_ONE_F32_BITS = int(np.array(1.0, np.float32).view(np.int32))  # brate default, as bits
_ONE_F64_BITS = int(np.array(1.0, np.float64).view(np.int64))  # krate default, as bits


def _ceil4(n: int) -> int:
    return int(-(-int(n) // 4) * 4)


# ----------------------------------------------------------------------------- cell list

@njit(cache=True)
def _bbox(x):
    # one sequential pass (~4 ms at 1e6); numpy's axis-0 min/max on (N, 3) is ~10x slower
    n, dim = x.shape
    lo = x[0].copy()
    hi = x[0].copy()
    for i in range(1, n):
        for d in range(dim):
            v = x[i, d]
            if v < lo[d]:
                lo[d] = v
            if v > hi[d]:
                hi[d] = v
    return lo, hi


def cell_grid(x: np.ndarray, rmax: float, skin: float, cap: int | None = None):
    """Uniform cell grid over the bounding box of ``x``.

    Cell size ``h >= (2*rmax + skin)`` so every pair in contact range lies in the same or an
    adjacent cell (9 cells in 2-D, 27 in 3-D). The number of cells is kept ``<= cap``
    (default ``max(2N, 1)``) by enlarging ``h``: sparse models or huge boxes never allocate
    a big grid, and a flat extent (all elements on a line or plane) gets one cell layer.

    Returns ``(lo, h, nc)`` with ``lo`` (dim,) the box corner, ``h`` the cell size and
    ``nc`` a 3-tuple of cell counts (``nc[2] == 1`` in 2-D).
    """
    n, dim = x.shape
    if cap is None:
        cap = max(2 * n, 1)
    lo, hi = _bbox(x) if n else (np.zeros(dim), np.zeros(dim))
    ext = hi - lo
    h = (2.0 * float(rmax) + float(skin)) * _CELL_SAFETY
    if not h > 0.0:
        h = 1.0
    # counts in floating point first: L/h may be astronomically large for sparse models
    while True:
        ncf = np.floor(ext / h) + 1.0
        tot = float(np.prod(ncf))
        if tot <= cap:
            break
        h *= max(1.01, (tot / cap) ** (1.0 / dim))
    nc = [int(c) for c in ncf] + [1] * (3 - dim)
    return np.ascontiguousarray(lo, dtype=np.float64), float(h), (nc[0], nc[1], nc[2])


@njit(cache=True, parallel=True)
def _cell_ids(x, lo, h, nc0, nc1, nc2):
    n, dim = x.shape
    cell = np.empty(n, np.int64)
    ncs = (nc0, nc1, nc2)
    for i in prange(n):
        c = np.int64(0)
        stride = np.int64(1)
        for d in range(dim):
            q = np.int64(math.floor((x[i, d] - lo[d]) / h))
            if q < 0:
                q = 0
            elif q >= ncs[d]:
                q = ncs[d] - 1
            c += q * stride
            stride *= ncs[d]
        cell[i] = c
    return cell


@njit(cache=True)
def _counting_sort(cell, ncell):
    # sequential and stable: element order inside a cell is by index (deterministic)
    n = cell.shape[0]
    start = np.zeros(ncell + 1, np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        c = cell[i]
        order[fill[c]] = i
        fill[c] += 1
    return order, start


@njit(cache=True, parallel=True)
def _gather(x, r, order):
    # cell-ordered packed copy [x, y, z (0 in 2-D), r]: candidate loops read one
    # contiguous stream, and the fixed 3 components let the distance be unrolled
    n, dim = x.shape
    xr = np.zeros((n, 4))
    for p in prange(n):
        i = order[p]
        for d in range(dim):
            xr[p, d] = x[i, d]
        xr[p, 3] = r[i]
    return xr


def _cell_list(x, r, skin):
    n, dim = x.shape
    rmax = float(r.max()) if n else 0.0
    lo, h, nc = cell_grid(x, rmax, skin)
    cell = _cell_ids(x, lo, h, nc[0], nc[1], nc[2])
    order, start = _counting_sort(cell, nc[0] * nc[1] * nc[2])
    xr = _gather(x, r, order)
    return nc, cell, order, start, xr


# ----------------------------------------------------------------------------- build


@njit(cache=True, inline="always")
def _in_range(x, r, skin, i, j):
    # the contact-range predicate, same arithmetic as the candidate loop of the kernel
    # (there the 2-D third term is 0*0, and a + 0.0 == a exactly); symmetric in (i, j)
    t0 = x[i, 0] - x[j, 0]
    t1 = x[i, 1] - x[j, 1]
    d2 = t0 * t0 + t1 * t1
    if x.shape[1] == 3:
        t2 = x[i, 2] - x[j, 2]
        d2 = d2 + t2 * t2
    c = r[i] + r[j] + skin
    return d2 <= c * c


@njit(cache=True, parallel=True)
def _rebuild_kernel(x, r, skin, nc0, nc1, nc2, cell, order, start, xr,
                    nbr, cst, fs, br, mr, kr):
    """Rebuild every row in place; returns the wanted entry count of each row.

    ``fs``, ``mr``, ``kr`` (int64) and ``br`` (int32) are bit views of the float arrays;
    ``mr`` (the rolling moments, rotation only) has zero columns for a translation-only model,
    ``kr`` (the contact stiffness factors, one column) none without them.

    Row ``i`` reads only its own old row (copied to scratch first), so the update is in
    place and race free. A row whose count exceeds the width is left untouched (the caller
    grows the width and calls again; rebuilding already rebuilt rows is idempotent).
    """
    n, dim = x.shape
    w = nbr.shape[1]
    counts = np.zeros(n, np.int32)
    nblk = (n + _BLOCK - 1) // _BLOCK
    one = np.int32(_ONE_F32_BITS)
    one64 = np.int64(_ONE_F64_BITS)
    nkr = kr.shape[2]
    for b in prange(nblk):
        onb = np.empty(w, np.int32)
        ocs = np.empty(w, np.int32)
        ofs = np.empty((w, dim), np.int64)
        nmr = mr.shape[2]
        omr = np.empty((w, nmr), np.int64)
        okr = np.empty((w, nkr), np.int64)
        obr = np.empty(w, np.int32)
        new = np.empty(w, np.int32)
        p1 = min(n, (b + 1) * _BLOCK)
        for pp in range(b * _BLOCK, p1):
            # visit elements in cell order: neighbouring cells stay in cache
            i = order[pp]
            # old row -> scratch (tolerates holes, result is compact anyway)
            m = 0
            for k in range(w):
                j = nbr[i, k]
                if j >= 0:
                    onb[m] = j
                    ocs[m] = cst[i, k]
                    for d in range(dim):
                        ofs[m, d] = fs[i, k, d]
                    for d in range(nmr):
                        omr[m, d] = mr[i, k, d]
                    for d in range(nkr):
                        okr[m, d] = kr[i, k, d]
                    obr[m] = br[i, k]
                    m += 1
            # geometric neighbours from the 9 / 27 surrounding cells
            c = cell[i]
            cx = c % nc0
            cy = (c // nc0) % nc1
            cz = c // (nc0 * nc1)
            xi0 = xr[pp, 0]
            xi1 = xr[pp, 1]
            xi2 = xr[pp, 2]
            ri = xr[pp, 3]
            cnt = 0
            x0 = max(cx - 1, 0)
            x1 = min(cx + 1, nc0 - 1)
            for zz in range(max(cz - 1, 0), min(cz + 2, nc2)):
                for yy in range(max(cy - 1, 0), min(cy + 2, nc1)):
                    # cells x0..x1 of this (y, z) line are consecutive: one element range
                    base = nc0 * (yy + nc1 * zz)
                    for p in range(start[base + x0], start[base + x1 + 1]):
                        t0 = xi0 - xr[p, 0]
                        t1 = xi1 - xr[p, 1]
                        t2 = xi2 - xr[p, 2]
                        d2 = t0 * t0 + t1 * t1 + t2 * t2
                        cut = ri + xr[p, 3] + skin
                        if d2 <= cut * cut and p != pp:
                            if cnt < w:
                                new[cnt] = order[p]
                            cnt += 1
            # bonded / broken-not-harvested entries are never dropped
            for q in range(m):
                if ocs[q] != 0:
                    j = onb[q]
                    if not _in_range(x, r, skin, i, j):
                        if cnt < w:
                            new[cnt] = j
                        cnt += 1
            counts[i] = cnt
            if cnt > w:
                continue
            # sort by neighbour index (deterministic), drop duplicates of a corrupt old row
            for a in range(1, cnt):
                v = new[a]
                bb = a - 1
                while bb >= 0 and new[bb] > v:
                    new[bb + 1] = new[bb]
                    bb -= 1
                new[bb + 1] = v
            k = 0
            for a in range(cnt):
                if k > 0 and new[a] == new[k - 1]:
                    continue
                new[k] = new[a]
                k += 1
            cnt = k
            counts[i] = cnt
            # write the row, carrying the state over by pair identity. fs / brate arrive as
            # integer views of their bits: copies and compares are bitwise exact. Writes
            # are skipped where memory already holds the value (rows mostly unchanged:
            # less memory traffic, and untouched calloc pages of a fresh state stay
            # unmapped).
            for a in range(cnt):
                j = new[a]
                found = -1
                for q in range(m):
                    if onb[q] == j:
                        found = q
                        break
                if nbr[i, a] != j:
                    nbr[i, a] = j
                if found >= 0:
                    vc = ocs[found]
                    vb = obr[found]
                else:
                    vc = 0
                    vb = one
                if cst[i, a] != vc:
                    cst[i, a] = vc
                if br[i, a] != vb:
                    br[i, a] = vb
                for d in range(dim):
                    vf = ofs[found, d] if found >= 0 else 0
                    if fs[i, a, d] != vf:
                        fs[i, a, d] = vf
                for d in range(nmr):
                    vm = omr[found, d] if found >= 0 else 0
                    if mr[i, a, d] != vm:
                        mr[i, a, d] = vm
                for d in range(nkr):
                    vk = okr[found, d] if found >= 0 else one64
                    if kr[i, a, d] != vk:
                        kr[i, a, d] = vk
            for a in range(cnt, w):
                if nbr[i, a] != -1:
                    nbr[i, a] = -1
                if cst[i, a] != 0:
                    cst[i, a] = 0
                if br[i, a] != one:
                    br[i, a] = one
                for d in range(dim):
                    if fs[i, a, d] != 0:
                        fs[i, a, d] = 0
                for d in range(nmr):
                    if mr[i, a, d] != 0:
                        mr[i, a, d] = 0
                for d in range(nkr):
                    if kr[i, a, d] != one64:
                        kr[i, a, d] = one64
    return counts


def _empty_rows(n, w, dim):
    return (np.full((n, w), -1, np.int32), np.zeros((n, w), np.int32),
            np.zeros((n, w, dim)), np.ones((n, w), np.float32))


def _set_width(state: State, w: int) -> None:
    """Replace the row arrays by width-``w`` copies (pads or truncates columns)."""
    if w == state.width:
        return
    n, dim = state.n, state.dim
    nbr, cst, fs, br = _empty_rows(n, w, dim)
    c = min(w, state.width)
    nbr[:, :c] = state.nbr[:, :c]
    cst[:, :c] = state.cstate[:, :c]
    fs[:, :c] = state.fs[:, :c]
    br[:, :c] = state.brate[:, :c]
    state.nbr, state.cstate, state.fs, state.brate = nbr, cst, fs, br
    if state.rotation:
        mr = np.zeros((n, w, state.nrot))
        mr[:, :c] = state.mr[:, :c]
        state.mr = mr
    if state.row_stiffness:
        kr = np.ones((n, w))
        kr[:, :c] = state.krate[:, :c]
        state.krate = kr


def _normalize_rows(state: State) -> None:
    # kernels are compiled for these exact dtypes / layouts
    n, dim = state.n, state.dim
    specs = (("nbr", np.int32, (n, -1)), ("cstate", np.int32, (n, -1)),
             ("fs", np.float64, (n, -1, dim)), ("brate", np.float32, (n, -1)))
    if state.rotation:
        specs = specs + (("mr", np.float64, (n, -1, state.nrot)),)
    if state.row_stiffness:
        specs = specs + (("krate", np.float64, (n, -1)),)
    w = state.nbr.shape[1] if state.nbr.ndim == 2 else -1
    for name, dt, shape in specs:
        a = getattr(state, name)
        want = tuple(w if s == -1 else s for s in shape)
        if a.shape != want:
            raise ValueError(f"state.{name} has shape {a.shape}, expected {want}")
        if a.dtype != dt or not a.flags.c_contiguous:
            setattr(state, name, np.ascontiguousarray(a, dtype=dt))


def _row_bits(state: State):
    # same memory, integer dtypes: the kernel moves per-pair state bit for bit
    mr = state.mr.view(np.int64) if state.rotation else np.zeros((state.n, 0, 0), np.int64)
    kr = state.krate.view(np.int64).reshape(state.n, -1, 1) if state.row_stiffness else \
        np.zeros((state.n, 0, 0), np.int64)
    return (state.nbr, state.cstate, state.fs.view(np.int64), state.brate.view(np.int32), mr,
            kr)


def _check_skin(skin) -> float:
    try:
        s = float(skin)
    except (TypeError, ValueError):
        raise ValueError(f"skin must be a finite number in (0, inf), got {skin!r}") from None
    if not (s > 0.0 and math.isfinite(s)):
        raise ValueError(f"skin must be a finite number in (0, inf), got {skin!r}")
    return s


def _check_positions(x: np.ndarray) -> None:
    if x.size and not np.isfinite(x).all():
        bad = int(np.flatnonzero(~np.isfinite(x).all(axis=1))[0])
        raise ValueError(f"position of element {bad} is not finite: x[{bad}] = {x[bad]}")


def build_rows(state: State, skin: float | None = None, width: int | None = None) -> None:
    """Rebuild the contact rows of ``state`` from a cell list, carrying per-pair state.

    New row of ``i`` = {j != i : |x_i - x_j| <= r_i + r_j + skin}
    union {old entries of row i with cstate != 0}, sorted by ``j``. For each entry the
    old row of ``i`` is searched for ``j``: ``cstate``, ``fs`` and ``brate`` are copied
    bitwise; new pairs get ``cstate 0``, ``fs 0``, ``brate 1``. Old rows are assumed
    symmetric (as all functions here produce them); the result is then symmetric too.

    ``skin`` (default ``state.skin``) must be finite and > 0. ``width`` (default: the
    current width) is the wanted row width; it grows to the next multiple of 4 at or
    above the largest row count when a row would not fit - entries are never dropped.
    The row arrays are updated in place when the width does not change, otherwise new
    arrays are assigned to ``state``. Sets ``state.x_ref[:] = state.x`` and
    ``state.skin = skin``.

    Raises ValueError for a bad ``skin`` or ``width`` or a non-finite position (naming the
    first bad element).
    """
    skin = _check_skin(state.skin if skin is None else skin)
    if width is not None:
        if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width < 1:
            raise ValueError(f"width must be an integer >= 1, got {width!r}")
        width = int(width)
    x = np.ascontiguousarray(state.x, dtype=np.float64)
    r = np.ascontiguousarray(state.r, dtype=np.float64)
    _check_positions(x)
    _normalize_rows(state)
    n = state.n
    w_cur = state.width
    w_target = w_cur if width is None else width
    w_build = max(w_cur, w_target)
    _set_width(state, w_build)
    if n:
        nc, cell, order, start, xr = _cell_list(x, r, skin)
        args = (x, r, skin, nc[0], nc[1], nc[2], cell, order, start, xr)
        counts = _rebuild_kernel(*args, *_row_bits(state))
        mx = int(counts.max())
        while mx > state.width:
            # overflowing rows were left untouched; the others are rebuilt idempotently
            _set_width(state, max(state.width, _ceil4(mx)))
            counts = _rebuild_kernel(*args, *_row_bits(state))
            mx = int(counts.max())
        if state.width > w_target:  # a smaller width was asked for: shrink if it fits
            _set_width(state, max(w_target, _ceil4(mx)))
    state.x_ref[...] = state.x
    state.skin = skin
    rows_touched(state)


def rows_touched(state: State) -> None:
    """Mark the rows of ``state`` as rewritten in place (by :func:`build_rows`,
    :func:`sort_rows`, :func:`spatial_sort`): a backend that keeps tables derived from the
    rows (the numba backend's owner tables) then rebuilds them at its next step, pushed or
    not. A runtime counter, ``state.rows_version``; not part of a checkpoint."""
    state.rows_version = rows_version(state) + 1


def rows_version(state: State) -> int:
    """How many times the rows of ``state`` were rewritten in place (see :func:`rows_touched`)."""
    return getattr(state, "rows_version", 0)


# ----------------------------------------------------------------------------- rebuild test


@njit(cache=True, parallel=True)
def _max_disp_speed(x, x_ref, v):
    n, dim = x.shape
    md = 0.0
    mv = 0.0
    for i in prange(n):
        d2 = 0.0
        v2 = 0.0
        for d in range(dim):
            t = x[i, d] - x_ref[i, d]
            d2 += t * t
            v2 += v[i, d] * v[i, d]
        if d2 != d2:  # NaN: force a rebuild (which then reports the bad element)
            d2 = np.inf
        if v2 != v2:
            v2 = np.inf
        md = max(md, d2)
        mv = max(mv, v2)
    return md, mv


def needs_rebuild(state: State, steps_ahead: int = 0) -> bool:
    """True when the rows may miss a contact within the next ``steps_ahead`` steps.

    Criterion: ``max_i |x_i - x_ref_i| + steps_ahead * dt * max_i |v_i| > skin / 2``.
    (Two elements each within ``skin/2`` of their reference positions cannot have closed
    more than ``skin``.) The look-ahead lets the engine test only every few steps. Always
    True when the state has never been built (``skin <= 0``) or holds NaN.
    """
    if state.n == 0:
        return False
    skin = float(state.skin)
    if not (skin > 0.0 and math.isfinite(skin)):
        return True
    md2, mv2 = _max_disp_speed(state.x, state.x_ref, state.v)
    reach = math.sqrt(md2) + max(int(steps_ahead), 0) * abs(float(state.dt)) * math.sqrt(mv2)
    return not (reach <= 0.5 * skin)


def check_plan(disp: float, u: float, skin: float, max_interval: int) -> tuple[bool, int]:
    """The engine's neighbour-check schedule: ``(rebuild, interval)``.

    ``disp`` [m]: largest displacement since the last build; ``u = dt v_max`` [m]: the farthest
    an element goes in one step at the current top speed. Rebuild now when the next step could
    take an element past ``skin/2`` (``disp + u > skin/2``, :func:`needs_rebuild` with a
    one-step look-ahead); then check again after ``floor((skin/2 - disp)/u)`` steps (``disp``
    = 0 after a rebuild), between 1 and ``max_interval``. A fixed interval lets fast elements
    cross the skin between two checks and touch unseen (docs/landslide.md).
    """
    half = 0.5 * skin
    rebuild = disp + u > half
    if rebuild:
        disp = 0.0
    if u <= 0.0:
        return rebuild, max_interval
    return rebuild, max(1, min(max_interval, int((half - disp) / u)))


# ----------------------------------------------------------------------------- explicit pairs


@njit(cache=True)
def _fill_pairs(pi, pj, code, pbr, start, nbr, cst, br):
    # sequential scatter of both directions (deterministic); rows sorted afterwards
    fill = start[:-1].copy()
    for p in range(pi.shape[0]):
        a = pi[p]
        b = pj[p]
        k = fill[a]
        nbr[a, k - start[a]] = b
        cst[a, k - start[a]] = code
        br[a, k - start[a]] = pbr[p]
        fill[a] += 1
        k = fill[b]
        nbr[b, k - start[b]] = a
        cst[b, k - start[b]] = code
        br[b, k - start[b]] = pbr[p]
        fill[b] += 1


@njit(cache=True, parallel=True)
def _sort_rows(nbr, cst, br, counts):
    """Sort each row by neighbour index (carrying cstate, brate). Returns, per row, the
    column of the first duplicate neighbour or -1."""
    n = nbr.shape[0]
    dup = np.full(n, -1, np.int64)
    for i in prange(n):
        c = counts[i]
        for a in range(1, c):
            v = nbr[i, a]
            s = cst[i, a]
            t = br[i, a]
            b = a - 1
            while b >= 0 and nbr[i, b] > v:
                nbr[i, b + 1] = nbr[i, b]
                cst[i, b + 1] = cst[i, b]
                br[i, b + 1] = br[i, b]
                b -= 1
            nbr[i, b + 1] = v
            cst[i, b + 1] = s
            br[i, b + 1] = t
        for a in range(1, c):
            if nbr[i, a] == nbr[i, a - 1]:
                dup[i] = a
                break
    return dup


def rows_from_pairs(state: State, i, j, bonded: bool = True, brate=None) -> None:
    """Replace all rows by an explicit list of unordered pairs ``(i[p], j[p])``.

    Both directions are inserted; ``cstate`` is 1 if ``bonded`` else 0, ``brate`` per pair
    (scalar or (P,) array, default 1.0), ``fs`` zero. Rows come out sorted by neighbour
    index. The width becomes ``max(current, next multiple of 4 >= largest row count)``;
    new row arrays are assigned to ``state``. ``x_ref`` and ``skin`` are not touched.

    Raises ValueError for mismatched shapes, non-integer or out-of-range indices, self
    pairs and pairs given more than once (in either orientation); ``state`` is unchanged
    then.
    """
    n, dim = state.n, state.dim
    pi = np.asarray(i)
    pj = np.asarray(j)
    if pi.ndim != 1 or pj.shape != pi.shape:
        raise ValueError(f"i and j must be 1-D arrays of equal length, got {pi.shape}, {pj.shape}")
    npair = pi.shape[0]
    for name, a in (("i", pi), ("j", pj)):
        if npair and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{name} must hold integer element indices, got dtype {a.dtype}")
    pi = pi.astype(np.int64)
    pj = pj.astype(np.int64)
    bad = np.flatnonzero((pi < 0) | (pi >= n) | (pj < 0) | (pj >= n))
    if bad.size:
        p = int(bad[0])
        raise ValueError(f"pair {p} = ({pi[p]}, {pj[p]}) has an index out of range [0, {n})")
    bad = np.flatnonzero(pi == pj)
    if bad.size:
        p = int(bad[0])
        raise ValueError(f"pair {p} = ({pi[p]}, {pj[p]}) is a self pair")
    if brate is None:
        pbr = np.ones(npair, np.float32)
    else:
        pbr = np.asarray(brate, dtype=np.float32)
        if pbr.ndim == 0:
            pbr = np.full(npair, pbr, np.float32)
        elif pbr.shape != (npair,):
            raise ValueError(f"brate must be a scalar or have shape ({npair},), got {pbr.shape}")
        pbr = np.ascontiguousarray(pbr)
    counts = (np.bincount(pi, minlength=n) + np.bincount(pj, minlength=n)).astype(np.int64)
    mx = int(counts.max()) if n else 0
    w = max(state.width, _ceil4(mx))
    start = np.zeros(n + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    nbr, cst, fs, br = _empty_rows(n, w, dim)
    if npair:
        _fill_pairs(pi, pj, np.int32(1 if bonded else 0), pbr, start, nbr, cst, br)
        dup = _sort_rows(nbr, cst, br, counts)
        rows = np.flatnonzero(dup >= 0)
        if rows.size:
            a = int(rows[0])
            b = int(nbr[a, dup[a]])
            raise ValueError(f"pair ({a}, {b}) is given more than once")
    state.nbr, state.cstate, state.fs, state.brate = nbr, cst, fs, br
    if state.rotation:
        state.mr = np.zeros((n, w, state.nrot))
    if state.row_stiffness:
        state.krate = np.ones((n, w))


# ----------------------------------------------------------------------------- spatial sort

@njit(cache=True, inline="always")
def _spread2(v):
    # 32-bit -> even bits of 64
    v &= np.uint64(0xFFFFFFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x0000FFFF0000FFFF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x00FF00FF00FF00FF)
    v = (v | (v << np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    v = (v | (v << np.uint64(2))) & np.uint64(0x3333333333333333)
    v = (v | (v << np.uint64(1))) & np.uint64(0x5555555555555555)
    return v


@njit(cache=True, inline="always")
def _spread3(v):
    # 21-bit -> every third bit of 63
    v &= np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


@njit(cache=True, parallel=True)
def _morton_keys(x, lo, scale):
    n, dim = x.shape
    keys = np.empty(n, np.uint64)
    qmax = 2097151.0 if dim == 3 else 4294967295.0
    for i in prange(n):
        key = np.uint64(0)
        for d in range(dim):
            q = (x[i, d] - lo[d]) * scale[d]
            if q < 0.0:
                q = 0.0
            elif q > qmax:
                q = qmax
            u = np.uint64(q)
            if dim == 3:
                key |= _spread3(u) << np.uint64(d)
            else:
                key |= _spread2(u) << np.uint64(d)
        keys[i] = key
    return keys


@njit(cache=True, parallel=True)
def _permute_nbr(nbr, perm, inv):
    n, w = nbr.shape
    out = np.empty_like(nbr)
    for k in prange(n):
        src = perm[k]
        for a in range(w):
            j = nbr[src, a]
            out[k, a] = inv[j] if j >= 0 else -1
    return out


@njit(cache=True, parallel=True)
def _take_rows(src, perm, dst):
    n, w = src.shape
    for k in prange(n):
        s = perm[k]
        for a in range(w):
            dst[k, a] = src[s, a]


@njit(cache=True, parallel=True)
def _copy_rows(src, dst):
    n, w = src.shape
    for k in prange(n):
        for a in range(w):
            dst[k, a] = src[k, a]


@njit(cache=True, parallel=True)
def _sort_row_arrays(nbr, cst, fs, br, mr, kr):
    # insertion sort of each row by neighbour index, moving the pair state (bit views) along
    n, w = nbr.shape
    dim = fs.shape[2]
    nmr = mr.shape[2]
    nkr = kr.shape[2]
    moved = 0
    for i in prange(n):
        for a in range(1, w):
            v = nbr[i, a]
            if v < 0:
                break
            if nbr[i, a - 1] <= v:
                continue
            moved += 1
            c = cst[i, a]
            b = br[i, a]
            f = np.empty(dim, np.int64)
            g = np.empty(nmr, np.int64)
            h = np.empty(nkr, np.int64)
            for d in range(dim):
                f[d] = fs[i, a, d]
            for d in range(nmr):
                g[d] = mr[i, a, d]
            for d in range(nkr):
                h[d] = kr[i, a, d]
            q = a - 1
            while q >= 0 and nbr[i, q] > v:
                nbr[i, q + 1] = nbr[i, q]
                cst[i, q + 1] = cst[i, q]
                br[i, q + 1] = br[i, q]
                for d in range(dim):
                    fs[i, q + 1, d] = fs[i, q, d]
                for d in range(nmr):
                    mr[i, q + 1, d] = mr[i, q, d]
                for d in range(nkr):
                    kr[i, q + 1, d] = kr[i, q, d]
                q -= 1
            nbr[i, q + 1] = v
            cst[i, q + 1] = c
            br[i, q + 1] = b
            for d in range(dim):
                fs[i, q + 1, d] = f[d]
            for d in range(nmr):
                mr[i, q + 1, d] = g[d]
            for d in range(nkr):
                kr[i, q + 1, d] = h[d]
    return moved


def sort_rows(state: State) -> int:
    """Sort every row by neighbour index in place, moving each entry's state (``cstate``,
    ``fs``, ``brate``, ``mr``) bit for bit with it (the order :func:`build_rows` leaves).
    A row is a set: the order changes no contact, only the order forces are summed in.
    Returns the number of entries moved."""
    _normalize_rows(state)
    if state.n == 0:
        return 0
    moved = int(_sort_row_arrays(*_row_bits(state)))
    if moved:
        rows_touched(state)
    return moved


def spatial_sort(state: State) -> np.ndarray:
    """Reorder all elements in Morton (Z-) order of their positions.

    Positions are quantised over the bounding box (21 bits per axis in 3-D, 32 in 2-D) and
    sorted stably by the interleaved key (ties by old index: deterministic). Every
    per-element array (``state.array_names()``: element vectors and scalars, group, rows,
    accumulators) is permuted in place; neighbour indices are relabelled through the
    inverse permutation, so contacts and their state are preserved exactly; rows stay
    compact and are sorted again by the new indices (:func:`sort_rows`). Returns ``perm``: new element ``k`` is
    old element ``perm[k]``.
    """
    n, dim = state.n, state.dim
    if n == 0:
        return np.zeros(0, np.int64)
    x = np.ascontiguousarray(state.x, dtype=np.float64)
    _check_positions(x)
    _normalize_rows(state)
    lo, hi = _bbox(x)
    ext = hi - lo
    qmax = 2097151.0 if dim == 3 else 4294967295.0
    scale = np.where(ext > 0, qmax / np.where(ext > 0, ext, 1.0), 0.0)
    keys = _morton_keys(x, lo, np.ascontiguousarray(scale))
    perm = np.argsort(keys, kind="stable").astype(np.int64)
    inv = np.empty(n, np.int32)
    inv[perm] = np.arange(n, dtype=np.int32)
    state.nbr[...] = _permute_nbr(state.nbr, perm, inv)
    names = tuple(k for k in state.array_names() if k != "nbr")
    # one scratch buffer for all arrays (a[perm] would allocate, and page-fault, each time);
    # parallel row gather (numpy's take is single threaded and slow on (N, W, dim))
    scratch = np.empty(max(getattr(state, k).nbytes for k in names), np.uint8)
    for name in names:
        a = getattr(state, name)
        if not a.flags.c_contiguous:
            raise ValueError(f"state.{name} must be C-contiguous")
        # integer views: moves are bitwise whatever the payload (NaNs included)
        a2 = a.reshape(n, -1).view(_INT_OF_SIZE[a.dtype.itemsize])
        tmp = scratch[:a.nbytes].view(a2.dtype).reshape(a2.shape)
        _take_rows(a2, perm, tmp)
        _copy_rows(tmp, a2)
    sort_rows(state)  # relabelled rows: sorted again, as build_rows leaves them
    rows_touched(state)
    return perm


# ----------------------------------------------------------------------------- queries


@njit(cache=True, parallel=True)
def _row_counts(nbr):
    n, w = nbr.shape
    out = np.zeros(n, np.int32)
    for i in prange(n):
        c = 0
        for a in range(w):
            if nbr[i, a] >= 0:
                c += 1
        out[i] = c
    return out


def row_counts(state: State) -> np.ndarray:
    """Number of valid entries (``nbr >= 0``) of each row, int32 (N,)."""
    return _row_counts(state.nbr)


@njit(cache=True, parallel=True)
def _pairs(nbr):
    n, w = nbr.shape
    cnt = np.zeros(n + 1, np.int64)
    for i in prange(n):
        c = 0
        for a in range(w):
            if nbr[i, a] > i:
                c += 1
        cnt[i + 1] = c
    for i in range(n):
        cnt[i + 1] += cnt[i]
    m = cnt[n]
    pi = np.empty(m, np.int32)
    pj = np.empty(m, np.int32)
    pk = np.empty(m, np.int32)
    for i in prange(n):
        p = cnt[i]
        for a in range(w):
            j = nbr[i, a]
            if j > i:
                pi[p] = i
                pj[p] = j
                pk[p] = a
                p += 1
    return pi, pj, pk


def pairs(state: State):
    """Each contact once: ``(i, j, k)`` int32 arrays with ``i < j`` and ``nbr[i, k] == j``.

    Ordered by ``i`` then column ``k`` (deterministic). Per-pair state is
    ``state.cstate[i, k]``, ``state.fs[i, k]``, ``state.brate[i, k]``.
    """
    return _pairs(state.nbr)


@njit(cache=True, parallel=True)
def _owner_tables(nbr, ostart, mirror):
    # per row: first column with j > i, and each owned entry's column in its partner's row.
    # Returns (rows unsorted / self / without a mirror entry, owned - other entries): rows
    # are symmetric iff both are 0 (each owned entry has its mirror, distinct entries have
    # distinct mirrors, and the counts agree, so the mirrors are all the other entries)
    n, w = nbr.shape
    bad = 0
    balance = 0
    for i in prange(n):
        ok = True
        start = w
        prev = -1
        owned = 0
        valid = 0
        for a in range(w):
            j = nbr[i, a]
            if j < 0:
                break
            valid += 1
            if j <= prev or j == i:
                ok = False
            prev = j
            if j < i:
                continue
            if start == w:
                start = a
            owned += 1
            # the mirror entry: binary search in the partner's sorted row
            lo = 0
            hi = w
            while lo < hi:
                mid = (lo + hi) // 2
                v = nbr[j, mid]
                if v >= 0 and v < i:
                    lo = mid + 1
                else:
                    hi = mid
            if lo < w and nbr[j, lo] == i:
                mirror[i, a] = lo
            else:
                ok = False
        ostart[i] = start if start < w else valid
        balance += 2 * owned - valid
        if not ok:
            bad += 1
    return bad, balance


def owner_tables(nbr: np.ndarray):
    """The tables that let each contact be evaluated once, by its owner ``i < j``.

    Returns ``(ostart, mirror)`` or ``None``: ``ostart[i]`` (int32) is the first column of
    row ``i`` whose neighbour is above ``i`` (rows are sorted, so the owned entries are the
    tail of the valid part); ``mirror[i, k]`` (int8 for rows up to 127 wide, else int16)
    is the column of ``i`` in the row of ``nbr[i, k]`` for the owned entries (-1 elsewhere).
    ``None`` when some row is not sorted, holds a duplicate or itself, or the rows are not
    symmetric: such rows are only stepped by the kernels that walk every row entry.
    """
    n, w = nbr.shape
    mirror = np.full((n, w), -1, np.int8 if w <= 127 else np.int16)
    ostart = np.zeros(n, np.int32)
    if n:
        bad, balance = _owner_tables(nbr, ostart, mirror)
        if bad or balance:
            return None
    return ostart, mirror


@njit(cache=True)
def _cross_tables(nbr, ostart, nslab, cstart, inc_start):
    # the owned contacts whose partner is in a later slab, in (owner, column) order: the
    # first sweep counts them per owner and per partner, the second gives each its spill
    # row, grouped by partner in that order (a stable counting sort), so that the finish
    # pass reads each element's spill rows as one run
    n, w = nbr.shape
    spill = np.zeros(1, np.int32)
    fill = np.zeros(0, np.int32)
    for sweep in range(2):
        c = 0
        for t in range(nslab):
            hi = (t + 1) * n // nslab
            for i in range(t * n // nslab, hi):
                if sweep == 0:
                    cstart[i] = c
                for k in range(ostart[i], w):
                    j = nbr[i, k]
                    if j < 0:
                        break
                    if j >= hi:
                        if sweep == 0:
                            inc_start[j + 1] += 1
                        else:
                            spill[c] = fill[j]
                            fill[j] += 1
                        c += 1
        if sweep == 0:
            cstart[n] = c
            for j in range(n):
                inc_start[j + 1] += inc_start[j]
            spill = np.zeros(c + 1, np.int32)  # one spare entry
            fill = inc_start[:-1].copy()
    return spill


def cross_tables(nbr: np.ndarray, ostart: np.ndarray, nslab: int):
    """Where the owner pass posts the contacts that cross a slab boundary.

    The ``n`` elements are cut into ``nslab`` slabs of consecutive indices, slab ``t`` from
    ``t n // nslab`` up to ``hi = (t + 1) n // nslab``; ``ostart`` from :func:`owner_tables`.
    Returns ``(cstart, spill, inc_start)`` (int32). The owned contacts of row ``i`` whose
    partner ``j`` lies in a later slab (``j >= hi`` of ``i``'s slab) are the crossing
    contacts ``cstart[i]`` onwards, in column order (``cstart[n]`` of them in all); crossing
    contact ``c`` posts into spill row ``spill[c]`` (``spill`` has one spare entry at the
    end); element ``j``'s spill rows are ``inc_start[j]`` to ``inc_start[j + 1] - 1``, its
    crossing contacts in (owner, column) order.
    """
    n = nbr.shape[0]
    nslab = max(1, min(int(nslab), n))
    cstart = np.zeros(n + 1, np.int32)
    inc_start = np.zeros(n + 1, np.int32)
    spill = _cross_tables(nbr, ostart, nslab, cstart, inc_start)
    return cstart, spill, inc_start


@njit(cache=True, parallel=True)
def _check_rows(nbr, cst, br):
    # per row: 0 ok, 1 hole (not compact), 2 out of range, 3 self, 4 duplicate,
    # 5 missing mirror entry, 6 mirror cstate differs, 7 mirror brate differs
    n, w = nbr.shape
    err = np.zeros(n, np.int32)
    col = np.zeros(n, np.int32)
    for i in prange(n):
        seen_empty = False
        for a in range(w):
            j = nbr[i, a]
            e = 0
            if j < 0:
                seen_empty = True
                continue
            if seen_empty:
                e = 1
            elif j >= n:
                e = 2
            elif j == i:
                e = 3
            else:
                for b in range(a):
                    if nbr[i, b] == j:
                        e = 4
                if e == 0:
                    q = -1
                    for b in range(w):
                        if nbr[j, b] == i:
                            q = b
                            break
                    if q < 0:
                        e = 5
                    elif cst[j, q] != cst[i, a]:
                        e = 6
                    elif br[j, q] != br[i, a]:
                        e = 7
            if e != 0:
                err[i] = e
                col[i] = a
                break
    return err, col


_CHECK_MSG = {1: "row is not compact (entry after a -1)", 2: "neighbour index out of range",
              3: "self contact", 4: "duplicate neighbour", 5: "mirror entry missing",
              6: "cstate differs from the mirror entry", 7: "brate differs from the mirror entry"}


def check_rows(state: State) -> None:
    """Validate the row invariants; raise ValueError naming the first bad row/column.

    Checks: compact rows, indices in range, no self contacts, no duplicates, every entry
    mirrored (``j`` in row ``i`` iff ``i`` in row ``j``) with equal ``cstate``,
    ``brate`` and ``krate`` (with it) on both sides. (``fs`` is not compared: its sign
    convention belongs to the force law.)
    """
    err, col = _check_rows(state.nbr, state.cstate, state.brate)
    bad = np.flatnonzero(err)
    if bad.size:
        i = int(bad[0])
        k = int(col[i])
        raise ValueError(f"row {i}, column {k} (nbr={int(state.nbr[i, k])}): "
                         f"{_CHECK_MSG[int(err[i])]}")
    if state.row_stiffness:
        _check_mirrored(state, state.krate, "krate")


def _check_mirrored(state: State, rows: np.ndarray, name: str) -> None:
    """ValueError unless the per-row values ``rows`` of every pair are equal on both sides
    (the rows themselves already mirrored)."""
    i, a = np.nonzero(state.nbr >= 0)
    j = state.nbr[i, a].astype(np.int64)
    n = state.n
    there = np.argsort(j * n + i, kind="stable")  # (j, i) keys in the order of (i, j) keys
    here = np.argsort(i.astype(np.int64) * n + j, kind="stable")
    differ = np.flatnonzero(rows[i[here], a[here]] != rows[i[there], a[there]])
    if differ.size:
        p = here[differ[0]]
        raise ValueError(f"row {int(i[p])}, column {int(a[p])} (nbr={int(j[p])}): {name} "
                         "differs from the mirror entry")
