"""Dense, isotropic, stress-free random packings in a box with flat faces (3-D specimens).

:func:`isotropic_packing` builds the packing of a random bonded specimen without gravity:

1. **Loose cloud.** ``n`` diameters from :func:`geodem.build.packing.radii` (uniform in
   ``[d_min, d_max]``, MatDEM's ``distri_rate``), centres uniformly random inside the box, all
   radii scaled down to a solid fraction of 0.3 (overlaps allowed: the first minimisation
   removes them).
2. **Isotropic compression by radius expansion.** Frictionless harmonic spheres (energy
   ``k/2 overlap^2`` per contact, the same ``k`` for every pair) inside the six *planar* faces
   of the fixed box (the same law against each face). All radii grow by a common factor; after
   each growth the energy is minimised with FIRE (Bitzek et al. 2006) until the largest net
   force is below ``0.01 overlap`` (``k = 1``, lengths in ``d_mean``). A state is *jammed*
   when its summed contact overlap per ``3 n`` stays above half the target after the
   minimisation. The radii grow in solid-fraction steps of 0.02 (0.01 above 0.55) until the
   first jammed state; then the packing is decompressed (or compressed) along that jammed
   branch, each time from the jammed state nearest the target, by the factor a linear fit of
   overlap against scale asks for, until the mean
   overlap lies within a factor 2 of ``overlap`` (default ``1e-4 d_mean``). That is the
   jamming point (O'Hern et al. 2003): random close packing, solid fraction ~0.64, every
   element that is not a rattler held by ``>= dim + 1`` contacts, about 6 per element in 3-D
   (isostatic). Frictionless compression gives the densest random packing; the friction of
   the rock acts only later, through the bonds.
3. **Bond network within a gap tolerance.** Every pair whose surface gap is below ``gap``
   (default ``0.01 d_mean``; overlapping contacts included) is a bond; every element face
   within ``gap`` of a box face touches it. An element left with fewer than ``dim + 1`` bonds
   and face contacts (a rattler, ~2-5 % of a jammed packing) is bonded to its nearest
   neighbours by gap (up to 0.25 d_mean) until it has ``dim + 1`` (PFC's floater elimination:
   the cement fills its cage).
4. **Stress-free bonds.** Bonds formed across a gap start in tension, contacts locked in with
   an overlap start in compression; both relax when the specimen leaves the box and break bonds
   when that strain exceeds the breaking displacement (``~Tu/E d``). So positions *and radii*
   are adjusted (Gauss-Newton, minimum-norm least squares, ``scipy.sparse.linalg.lsqr``) until
   every bonded pair touches with the overlap ``prestress`` (default ``1e-6 d_mean``: a small
   force scale, far below any breaking displacement) and every element at a face is tangent to
   it. The changes are of the order of ``gap`` (radii by < 1 %, a rattler's by up to ~10 %;
   reported), and the faces stay exactly flat. With ``4 N`` unknowns and about ``3.5 N`` bonds (7 per element) the
   system is under-determined and is met to round-off.

Returns positions and radii in metres and a report; :func:`geodem.build.specimen.cement` then
bonds the touching pairs and balances.

**Large boxes** (above :data:`TILE_ABOVE` elements): jamming the whole box costs ~N^2.6 (the
minimiser slows down near the jamming point, and more so for more elements), so a box that
large is filled by :func:`tiled_packing`: one periodic cell of about :data:`TILE_ELEMENTS`
elements (steps 1-2 without faces, the pairs by their nearest image; steps 3-4 with the bonds
across the cell's boundaries) repeated over the box. The cell's cost does not grow with the
box. The micro-structure repeats every cell side (~20 d_mean), and the box's faces cut the
cells instead of being flat and touched. A specimen whose faces along some axes must stay flat
(a 3-D Brazilian disc's sides and poles) is a strip instead (:func:`strip_packing`): one cell
periodic along the other axes and bounded by the box's faces along these, repeated.
"""
from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from geodem.build import progress
from geodem.threads import single_threaded_blas

__all__ = ["bond_network", "isotropic_packing", "jam", "strip_packing", "stress_free",
           "stress_free_network"]

PHI_START = 0.3
#: above this many elements :func:`isotropic_packing` repeats a periodic cell of about
#: TILE_ELEMENTS elements over the box (the whole box jammed at once costs ~N^2.6:
#: docs/performance.md, "Cost against model size"); below, the box is jammed whole, as the lab
#: specimens always were
TILE_ABOVE = 20_000
TILE_ELEMENTS = 8_000
#: the most elements a box jammed whole on request (``tile=False``) may hold: a 3-D box of
#: 42,282 elements took about 18 minutes to build on one core (2026-12-06), and the cost grows
#: ~N^2.6 (docs/performance.md, "A tiled lab specimen")
WHOLE_JAM_MAX = 60_000
#: the narrowest side [d_mean] of a strip's cell along its periodic axes (:func:`strip_counts`)
STRIP_MIN_SIDE = 6.0
#: FIRE iterations of one growth step of a periodic cell (:func:`jam`)
GROWTH_CAP = 30_000
PHI_BULK = 0.635  # random close packing of the default size spread (measured: 0.639)
PHI_BULK_2D = 0.84  # random close packing of discs of the default size spread
WALL_DEFICIT = 0.15
SKIN = 0.15  # pair-list skin, in d_mean
FTOL = 1e-2  # FIRE: largest net force / target overlap (k = 1, d_mean = 1)
DEFAULT_OVERLAP = 1e-4
DEFAULT_GAP = 1e-2
DEFAULT_PRESTRESS = 1e-6


# ============================================================================ kernels (reduced)
@njit(cache=True, fastmath=True)
def _forces(x, r, pi, pj, lo, hi, f, period):
    """Harmonic repulsion (k = 1) between the candidate pairs and against the planar faces of
    ``[lo, hi]``; along an axis ``c`` with ``period[c] > 0`` the cell is periodic instead
    (``[0, period[c])``, pairs by their nearest image, no faces there); writes the net forces
    into ``f``, returns the energy."""
    n, dim = x.shape
    f[:] = 0.0
    e = 0.0
    t = np.empty(dim)
    for k in range(pi.size):
        i = pi[k]
        j = pj[k]
        d2 = 0.0
        for c in range(dim):
            t[c] = x[j, c] - x[i, c]
            if period[c] > 0.0:
                t[c] -= period[c] * np.floor(t[c] / period[c] + 0.5)
            d2 += t[c] * t[c]
        s = r[i] + r[j]
        if d2 < s * s:
            d = math.sqrt(d2)
            ov = s - d
            e += 0.5 * ov * ov
            for c in range(dim):
                fc = ov * t[c] / d
                f[i, c] -= fc
                f[j, c] += fc
    for i in range(n):
        for c in range(dim):
            if period[c] > 0.0:
                continue
            ov = r[i] - (x[i, c] - lo[c])
            if ov > 0.0:
                e += 0.5 * ov * ov
                f[i, c] += ov
            ov = r[i] - (hi[c] - x[i, c])
            if ov > 0.0:
                e += 0.5 * ov * ov
                f[i, c] -= ov
    return e


@njit(cache=True, fastmath=True)
def _fire(x, v, r, pi, pj, lo, hi, x0, half_skin, ftol, emin, max_iter, dt, dt_max, period):
    """FIRE minimisation (unit masses). Returns ``(status, iterations, dt, energy)``; status 0:
    largest net force below ``ftol``; 1: energy below ``emin`` (no contact left: unjammed);
    2: an element moved more than ``half_skin`` since the pair list was built (rebuild and
    call again); 3: ``max_iter`` reached. ``period``: the periodic cell's lengths per axis
    (no faces there), zero along an axis bounded by the faces of ``[lo, hi]``."""
    n, dim = x.shape
    f = np.zeros_like(x)
    e = _forces(x, r, pi, pj, lo, hi, f, period)
    alpha = 0.1
    npos = 0
    for it in range(max_iter):
        fmax2 = 0.0
        for i in range(n):
            s = 0.0
            for c in range(dim):
                s += f[i, c] * f[i, c]
            fmax2 = max(fmax2, s)
        if fmax2 < ftol * ftol:
            return 0, it, dt, e
        if e < emin:
            return 1, it, dt, e
        p = 0.0
        for i in range(n):
            for c in range(dim):
                p += f[i, c] * v[i, c]
        if p > 0.0:
            npos += 1
            if npos > 5:
                dt = min(dt * 1.1, dt_max)
                alpha *= 0.99
        else:
            npos = 0
            dt *= 0.5
            alpha = 0.1
            for i in range(n):
                for c in range(dim):
                    x[i, c] -= 0.5 * dt * v[i, c]
                    v[i, c] = 0.0
        vn = 0.0
        fn = 0.0
        for i in range(n):
            for c in range(dim):
                v[i, c] += dt * f[i, c]
                vn += v[i, c] * v[i, c]
                fn += f[i, c] * f[i, c]
        scale = alpha * math.sqrt(vn / fn) if fn > 0.0 else 0.0
        dmax2 = 0.0
        for i in range(n):
            d2 = 0.0
            for c in range(dim):
                v[i, c] = (1.0 - alpha) * v[i, c] + scale * f[i, c]
                x[i, c] += dt * v[i, c]
                t = x[i, c] - x0[i, c]
                d2 += t * t
            dmax2 = max(dmax2, d2)
        if dmax2 > half_skin * half_skin:
            return 2, it + 1, dt, e
        e = _forces(x, r, pi, pj, lo, hi, f, period)
    return 3, max_iter, dt, e


def _pairs(x, r, reach, period=None):
    """Candidate pairs with surface gap below ``reach`` (``i < j``, int64); in the periodic
    cell ``[0, period)`` by the nearest image."""
    from scipy.spatial import cKDTree

    tree = cKDTree(x) if period is None else cKDTree(_wrap(x, period), boxsize=period)
    p = tree.query_pairs(2.0 * float(r.max()) + reach, output_type="ndarray")
    if len(p) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = np.linalg.norm(_separation(x, p[:, 0], p[:, 1], period), axis=1)
    keep = d < r[p[:, 0]] + r[p[:, 1]] + reach
    return p[keep, 0].astype(np.int64), p[keep, 1].astype(np.int64)


def _wrap(x, period):
    """Centres moved into the periodic cell ``[0, period)`` (a round-off ``period`` -> 0) along
    the axes with ``period > 0``; the others as they are."""
    period = np.asarray(period, float)
    on = period > 0.0
    p = np.where(on, period, 1.0)
    w = np.mod(x, p)
    return np.where(on, np.where(w >= p, 0.0, w), x)


def _nearest_image(d, period):
    """Separations ``d`` as their nearest image in the periodic cell ``[0, period)`` (along
    the axes with ``period > 0``)."""
    period = np.asarray(period, float)
    p = np.where(period > 0.0, period, np.inf)
    return np.where(period > 0.0, d - period * np.floor(d / p + 0.5), d)


def _separation(x, i, j, period=None):
    """``x[j] - x[i]``; in the periodic cell ``[0, period)`` the nearest image's."""
    d = x[j] - x[i]
    return d if period is None else _nearest_image(d, period)


def _minimise(x, r, lo, hi, ftol, emin, max_iter=200000, period=None):
    """FIRE to ``ftol`` from rest (pair list rebuilt as needed); ``period``: a periodic cell
    instead of the box's faces. Returns ``(status, iters)``."""
    v = np.zeros_like(x)
    dt = 0.05
    total = 0
    cell = np.zeros(x.shape[1]) if period is None else np.asarray(period, float)
    while True:
        pi, pj = _pairs(x, r, SKIN, period)
        st, it, dt, _ = _fire(x, v, r, pi, pj, lo, hi, x.copy(), 0.5 * SKIN, ftol, emin,
                              max_iter - total, dt, 0.2, cell)
        total += it
        if st != 2:
            return st, total


def _contacts(x, r, lo, hi, period=None):
    """Overlaps of the touching pairs and element-face contacts (positive values); a periodic
    axis (``period`` > 0 there) has no faces."""
    pi, pj = _pairs(x, r, 0.0, period)
    ov = r[pi] + r[pj] - np.linalg.norm(_separation(x, pi, pj, period), axis=1)
    walls = _bounded_axes(x.shape[1], period)
    w = np.concatenate([r[:, None] - (x - lo)[:, walls], r[:, None] - (hi - x)[:, walls]],
                       axis=1).ravel()
    return np.concatenate([ov[ov > 0], w[w > 0]])


def _inside(x, r, lo, hi, period):
    """Centres wrapped into the cell along its periodic axes and moved inside the faces of
    ``[lo, hi]`` (by a radius) along the bounded ones; a copy."""
    xt = x.copy() if period is None else _wrap(x, period)
    b = _bounded_axes(x.shape[1], period)
    xt[:, b] = np.clip(xt[:, b], lo[b] + r[:, None], hi[b] - r[:, None])
    return xt


def _bounded_axes(dim, period):
    """The axes bounded by faces: all without a periodic cell, else those with period 0."""
    if period is None:
        return np.arange(dim)
    return np.flatnonzero(np.asarray(period, float) <= 0.0)


def _load(x, r, lo, hi, period=None):
    """Summed overlap of the contacts per ``3 n`` (the mean overlap of an isostatic packing,
    ~3 contacts per element in 3-D): 0 for an unjammed packing."""
    return float(_contacts(x, r, lo, hi, period).sum()) / (3.0 * r.size)


def jam(r0, lo, hi, *, overlap=DEFAULT_OVERLAP, seed=0, max_cycles=60, x0=None,
        periodic=False):
    """:func:`jam_fresh`, or its result kept from an earlier call with the same inputs
    (:mod:`geodem.build.jam_cache`: the same bits; ``info["cached"]`` says which)."""
    from geodem.build import jam_cache

    k = jam_cache.key(r0, lo, hi, overlap, seed, max_cycles, x0, periodic)
    hit = jam_cache.load(k)
    if hit is not None:
        x, r, info = hit
        progress.report(f"jamming: {r.size:,} elements taken from the packing cache (jammed "
                        f"before with the same inputs; GEODEM_PACKING_CACHE=0 jams anew)")
        return x, r, dict(info, cached=True)
    x, r, info = jam_fresh(r0, lo, hi, overlap=overlap, seed=seed, max_cycles=max_cycles,
                           x0=x0, periodic=periodic)
    jam_cache.store(k, x, r, info)
    return x, r, dict(info, cached=False)


def jam_fresh(r0, lo, hi, *, overlap=DEFAULT_OVERLAP, seed=0, max_cycles=60, x0=None,
              periodic=False):
    """Compress the spheres of radii ``r0`` (reduced units, ``d_mean`` ~ 1) isotropically
    inside the box ``[lo, hi]`` by radius expansion until the mean overlap of the contacts is
    within a factor 2 of ``overlap`` (module docstring, step 2). Returns ``(x, r, info)``.

    Growth: solid-fraction steps of 0.02 (0.01 above 0.55) from 0.3, each minimised from the
    last unjammed state, until a state is jammed (mean overlap above half the target). Then
    along that jammed branch: the radii shrink (or grow) by the factor a linear fit of
    overlap against scale asks for, each minimised from the nearest jammed state above the
    target (a jammed packing decompresses along its own branch down to its jamming point).
    ``x0``: starting centres (reduced units; default uniformly random in the box), e.g. placed
    with a density that follows a graded size field (:mod:`geodem.build.graded`).
    ``periodic``: the box is a periodic cell (no faces; centres returned inside it); or one
    flag per axis (a strip: periodic along some axes, bounded by faces along the others)."""
    rng = np.random.default_rng(seed)
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    dim = lo.size
    axes = np.broadcast_to(np.asarray(periodic, bool), (dim,))
    if np.any(lo[axes] != 0.0):
        raise ValueError("a periodic cell starts at the origin: lo = 0 along its periodic axes")
    period = np.where(axes, hi - lo, 0.0) if axes.any() else None
    vol = float(np.prod(hi - lo))
    unit = (4.0 / 3.0 * np.pi * (r0 ** 3).sum()) if dim == 3 else np.pi * (r0 ** 2).sum()
    lam = (PHI_START * vol / unit) ** (1.0 / dim)
    x = lo + rng.uniform(0.0, 1.0, (r0.size, dim)) * (hi - lo) if x0 is None else \
        np.array(x0, float)
    ftol = FTOL * overlap
    emin = 0.5 * r0.size * (0.01 * overlap) ** 2
    lam_lo = None  # largest unjammed scale seen on the branch
    hi_pts = []  # (scale, overlap, x) of jammed states above the target
    iters = cycles = 0
    ov = 0.0
    progress.report(f"jamming: {r0.size:,} elements compressed to a mean overlap of "
                    f"{overlap:.3g} d")
    tick = progress.Every()
    for cycles in range(1, max_cycles + 1):
        if tick.due():
            progress.report(f"jamming: compression cycle {cycles} (at most {max_cycles}), mean "
                            f"overlap {ov:.3g} d")
        r = lam * r0
        xt = _inside(x, r, lo, hi, period)
        # a periodic cell's growth minimised at most GROWTH_CAP iterations: a state that
        # needs more sits at the jamming point itself (critical slowing down: ~70 % of the
        # whole jamming's iterations in one such step) and is passed as unjammed
        capped = period is not None and not hi_pts
        st, it = _minimise(xt, r, lo, hi, ftol, emin, GROWTH_CAP if capped else 200000,
                           period=period)
        iters += it
        unjammed = st == 1 or (capped and st == 3)
        ov = 0.0 if unjammed else _load(xt, r, lo, hi, period)
        if 0.5 * overlap <= ov <= 2.0 * overlap:
            if period is not None:
                xt = _wrap(xt, period)
            progress.report(f"jamming: jammed after {cycles} compression cycles ({iters:,} "
                            f"minimiser iterations), mean overlap {ov:.3g} d")
            return xt, r, {"cycles": cycles, "fire_iterations": iters, "scale": float(lam),
                           "mean_overlap": ov, "status": int(st)}
        if ov > 2.0 * overlap:
            hi_pts.append((lam, ov, xt))
            hi_pts.sort(key=lambda p: p[0])
        if not hi_pts:  # still growing
            x = xt
            phi = float(unit) * lam ** dim / vol
            lam *= (1.0 + (0.02 if phi < 0.55 else 0.01) / phi) ** (1.0 / dim)
            continue
        if ov <= 2.0 * overlap:
            lam_lo = lam if lam_lo is None else max(lam_lo, lam)
        l1, o1, x = hi_pts[0]  # the jammed state nearest to the target: start from it
        if len(hi_pts) > 1:
            l2, o2, _ = hi_pts[1]
            slope = (o2 - o1) / (l2 - l1)
        else:
            slope = 1.0  # rigid network: the overlaps grow with the diameters
        if lam_lo is not None and ov < 0.5 * overlap:
            # between an unjammed (or too loose) state and the branch: interpolate
            slope = max(slope, (o1 - ov) / (l1 - lam))
        lam_new = l1 - (o1 - overlap) / slope
        if lam_lo is not None and lam_new <= lam_lo:
            lam_new = 0.5 * (lam_lo + l1)
        lam = lam_new
    raise RuntimeError(f"isotropic packing: no jammed state with mean overlap near {overlap:g} "
                       f"d_mean after {max_cycles} compression cycles (last {ov:.3g}); report "
                       "this with the arguments used")


# ============================================================================ bonds
def _face_contacts(x, r, lo, hi, gap, period=None):
    """``(elem, axis, side)`` of every element surface within ``gap`` of a face of the box
    (none along a periodic axis of ``period``)."""
    faces = [np.zeros((0, 3), np.int64)]
    for a in _bounded_axes(x.shape[1], period):
        for side in (0, 1):
            dist = x[:, a] - lo[a] if side == 0 else hi[a] - x[:, a]
            e = np.flatnonzero(dist - r <= gap)
            faces.append(np.stack([e, np.full(e.size, a), np.full(e.size, side)], axis=1))
    return np.concatenate(faces).astype(np.int64)


def bond_network(x, r, lo, hi, gap, min_bonds=None, max_gap=0.25, period=None):
    """Bonded pairs (``i < j``): every pair with surface gap ``<= gap`` plus, for an element
    with fewer than ``min_bonds`` (default ``dim + 1``) bonds and face contacts, its nearest
    neighbours by gap (up to ``max_gap``) until it has ``min_bonds``; and the element-face
    contacts within ``gap``: ``(elem, axis, side)`` (none in a periodic cell, ``period``).
    Returns ``(i, j, faces, added)`` (``added``: the pairs the rattler rule added)."""
    n, dim = x.shape
    min_bonds = dim + 1 if min_bonds is None else int(min_bonds)
    pi, pj = _pairs(x, r, max_gap, period)
    g = np.linalg.norm(_separation(x, pi, pj, period), axis=1) - r[pi] - r[pj]
    bond = g <= gap
    faces = _face_contacts(x, r, lo, hi, gap, period)
    cnt = (np.bincount(pi[bond], minlength=n) + np.bincount(pj[bond], minlength=n)
           + np.bincount(faces[:, 0], minlength=n))
    added = 0
    for e in np.flatnonzero(cnt < min_bonds):
        if cnt[e] >= min_bonds:
            continue
        cand = np.flatnonzero(((pi == e) | (pj == e)) & ~bond)
        for k in cand[np.argsort(g[cand])][:min_bonds - cnt[e]]:
            bond[k] = True
            cnt[pi[k]] += 1
            cnt[pj[k]] += 1
            added += 1
    return pi[bond], pj[bond], faces, added


def stress_free_network(xj, rj, lo, hi, gap=DEFAULT_GAP, prestress=DEFAULT_PRESTRESS,
                        period=None):
    """Steps 3 and 4 of the module docstring on a jammed packing (reduced units): the bond
    network within ``gap`` (:func:`bond_network`), then positions and radii made stress-free
    (:func:`stress_free`); pairs or faces the adjustment brings into contact are bonded too and
    the adjustment redone (up to 5 times). ``period``: a periodic cell ``[0, period)``
    instead of the box's faces. Returns ``(x, r, i, j, faces, added, residual)``."""
    i, j, faces, added = bond_network(xj, rj, lo, hi, gap, period=period)
    for _ in range(5):
        xs, rs, res = stress_free(xj, rj, i, j, faces, lo, hi, prestress=prestress,
                                  period=period)
        # pairs or faces the adjustment brought into contact: bond them too and redo
        pi, pj = _pairs(xs, rs, 0.0, period)
        new = set(zip(pi.tolist(), pj.tolist())) - set(zip(i.tolist(), j.tolist()))
        fnew = {tuple(f) for f in _face_contacts(xs, rs, lo, hi, 0.0, period).tolist()} - \
            {tuple(f) for f in faces.tolist()}
        if not new and not fnew:
            break
        if new:
            add = np.array(sorted(new), dtype=np.int64)
            i, j = np.concatenate([i, add[:, 0]]), np.concatenate([j, add[:, 1]])
        if fnew:
            faces = np.concatenate([faces, np.array(sorted(fnew), dtype=np.int64)])
    return xs, rs, i, j, faces, added, res


def stress_free(x, r, i, j, faces, lo, hi, *, prestress=DEFAULT_PRESTRESS, iterations=6,
                tol=1e-10, period=None):
    """Adjust positions and radii (minimum-norm Gauss-Newton) so that every pair ``(i, j)``
    overlaps by ``prestress`` and every face contact ``(elem, axis, side)`` is tangent to its
    face of ``[lo, hi]`` (pairs by their nearest image in a periodic cell ``[0, period)``).
    Returns ``(x, r, residual)`` (largest remaining error)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import lsqr

    x = x.copy()
    r = r.copy()
    n, dim = x.shape
    nb, nf = i.size, len(faces)
    fe, fa, fs = faces[:, 0], faces[:, 1], faces[:, 2]
    res = math.inf
    # one BLAS thread: lsqr's dot products then sum in the same order on every machine
    blas = single_threaded_blas()
    for _ in range(iterations):
        dvec = _separation(x, i, j, period)
        dist = np.linalg.norm(dvec, axis=1)
        nrm = dvec / dist[:, None]
        # residuals: gap + prestress (pairs), surface - plane (faces)
        rb = dist - r[i] - r[j] + prestress
        sign = np.where(fs == 0, 1.0, -1.0)
        plane = np.where(fs == 0, lo[fa], hi[fa])
        rf = sign * (x[fe, fa] - plane) - r[fe]
        res = float(max(np.abs(rb).max(initial=0.0), np.abs(rf).max(initial=0.0)))
        if res < tol:
            break
        rows, cols, vals = [], [], []
        k = np.arange(nb)
        for c in range(dim):
            rows += [k, k]
            cols += [j * (dim + 1) + c, i * (dim + 1) + c]
            vals += [nrm[:, c], -nrm[:, c]]
        rows += [k, k]
        cols += [i * (dim + 1) + dim, j * (dim + 1) + dim]
        vals += [-np.ones(nb), -np.ones(nb)]
        kf = nb + np.arange(nf)
        rows += [kf, kf]
        cols += [fe * (dim + 1) + fa, fe * (dim + 1) + dim]
        vals += [sign, -np.ones(nf)]
        a = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(nb + nf, n * (dim + 1))).tocsr()
        with blas:
            sol = lsqr(a, -np.concatenate([rb, rf]), atol=1e-14, btol=1e-14,
                       iter_lim=20000)[0]
        sol = sol.reshape(n, dim + 1)
        x += sol[:, :dim]
        r += sol[:, dim]
    return x, r, res


# ============================================================================ driver
def isotropic_packing(size, d_mean, distri_rate=0.2, *, seed=0, n=None, phi=None,
                      overlap=DEFAULT_OVERLAP, gap=DEFAULT_GAP, prestress=DEFAULT_PRESTRESS,
                      tile=None, periodic_axes=None):
    """A dense, isotropic, stress-free random packing filling the box ``[0, size]`` (module
    docstring). ``n`` elements (default: ``phi`` x box volume / mean element volume, so that
    the jammed diameters come out close to ``d_mean``; ``phi`` default: 0.635 in 3-D, 0.84 in
    2-D); ``overlap``, ``gap`` and ``prestress``
    in units of ``d_mean``. Above :data:`TILE_ABOVE` elements (``tile`` None; True: always,
    False: never) the packing is a periodic cell repeated over the box
    (:func:`tiled_packing`). ``periodic_axes``: above :data:`TILE_ABOVE` elements, a strip
    periodic along these axes and bounded by the box's flat faces along the others, repeated
    along them (:func:`strip_packing`; ``tile`` is then not read): for a specimen whose faces
    on the other axes must be whole, such as a 3-D Brazilian disc's (its flat sides and its
    poles under the platens), that would take an hour to jam whole. Returns ``(x, r,
    report)`` in metres; the report has ``n``,
    ``d_mean`` (of the result), ``scale`` (jammed / requested diameters), ``jam_overlap``,
    ``bonds`` (pairs to bond), ``face_contacts``, ``rattler_bonds``, ``max_radius_change``
    (relative), ``residual`` (in d_mean), ``packing_fraction`` (whole box), ``time_s``."""
    from geodem.build import packing

    t0 = time.perf_counter()
    size = np.asarray(size, float)
    dim = size.size
    if dim not in (2, 3) or not np.all(size > 0):
        raise ValueError(f"size must hold 2 or 3 positive lengths [m], got {size.tolist()}")
    if phi is None:
        phi = PHI_BULK if dim == 3 else PHI_BULK_2D
    vmean = (math.pi / 6.0 * packing._mean_dpow(d_mean, distri_rate, 3) if dim == 3
             else math.pi / 4.0 * packing._mean_dpow(d_mean, distri_rate, 2))
    whole = n is None
    if n is None:
        # a wall leaves a looser layer: about WALL_DEFICIT d_mean of each face counts as empty
        n = round(phi * float(np.prod(size - 2.0 * WALL_DEFICIT * d_mean)) / vmean)
    if periodic_axes is not None and n > TILE_ABOVE:
        cells = strip_counts(size, vmean, phi, periodic_axes,
                             min_side=STRIP_MIN_SIDE * d_mean)
        cell = _less_walls(size / cells, d_mean, [a for a in range(dim)
                                                  if a not in set(periodic_axes)])
        n_cell = round(phi * float(np.prod(cell)) / vmean) if whole else \
            max(1, round(n / int(np.prod(cells))))
        return strip_packing(size, d_mean, distri_rate, periodic_axes, cells, n_cell,
                             seed=seed, overlap=overlap, gap=gap, prestress=prestress)
    if tile is False and n > WHOLE_JAM_MAX:
        raise ValueError(f"a random packing of {n:,} elements jammed whole (not tiled: a disc "
                         f"or another lab specimen whose faces must be whole); allowed: up to "
                         f"{WHOLE_JAM_MAX:,} (a box of 42,282 elements took about 18 minutes "
                         f"to build on one core, and the cost grows ~N^2.6): make d_mean larger "
                         f"or the specimen smaller")
    if tile or (tile is None and n > TILE_ABOVE):
        cells = tile_counts(size, vmean, phi)
        n_cell = round(phi * float(np.prod(size / cells)) / vmean) if whole else \
            max(1, round(n / int(np.prod(cells))))
        return tiled_packing(size, d_mean, distri_rate, cells, n_cell, seed=seed,
                             overlap=overlap, gap=gap, prestress=prestress)
    rng = np.random.default_rng(seed)
    r0 = packing.radii(n, d_mean, distri_rate, rng) / d_mean
    lo, hi = np.zeros(dim), size / d_mean
    xj, rj, info = jam(r0, lo, hi, overlap=overlap, seed=rng.integers(2 ** 31))
    xs, rs, i, j, faces, added, res = stress_free_network(xj, rj, lo, hi, gap, prestress)
    vol = packing.element_volume(rs, dim).sum() / np.prod(hi)
    rep = {"n": int(n), "d_mean": 2.0 * float(rs.mean()) * d_mean, "scale": info["scale"],
           "jam_overlap": info["mean_overlap"], "jam_cycles": info["cycles"],
           "fire_iterations": info["fire_iterations"], "jam_cached": info["cached"],
           "bonds": int(i.size),
           "face_contacts": len(faces), "rattler_bonds": int(added),
           "max_radius_change": float(np.abs(rs / rj - 1.0).max()),
           "max_shift": float(np.abs(xs - xj).max()), "residual": res,
           "packing_fraction": float(vol), "time_s": time.perf_counter() - t0}
    return xs * d_mean, rs * d_mean, rep


def _less_walls(extent, d_mean, axes):
    """``extent`` less the looser layer of :data:`WALL_DEFICIT` at both faces along ``axes``."""
    e = np.array(extent, float)
    e[list(axes)] -= 2.0 * WALL_DEFICIT * d_mean
    return e


def strip_counts(size, vmean, phi, periodic_axes, elements=TILE_ELEMENTS,
                 min_side=0.0) -> np.ndarray:
    """Cells along each axis of the box ``size`` [m] for a strip (:func:`strip_packing`) of
    about ``elements`` elements a cell: one cell along every bounded axis (the box's whole
    extent), the cell's side along the ``periodic_axes`` closest to that of a square (a
    segment, a cube) of that volume, and at least ``min_side`` [m] (a cell a few elements
    wide does not jam: its elements meet their own images)."""
    size = np.asarray(size, float)
    along = np.asarray(periodic_axes, np.int64)
    bounded = np.delete(np.arange(size.size), along)
    side = (elements * vmean / phi / float(np.prod(size[bounded]))) ** (1.0 / along.size)
    cells = np.ones(size.size, np.int64)
    cells[along] = np.maximum(1, np.minimum(np.round(size[along] / side),
                                            np.floor(size[along] / max(min_side, 1e-300))))
    return cells


def strip_packing(size, d_mean, distri_rate, periodic_axes, cells, n_cell, *, seed=0,
                  overlap=DEFAULT_OVERLAP, gap=DEFAULT_GAP, prestress=DEFAULT_PRESTRESS):
    """A random packing of the box ``[0, size]`` [m] made of one cell ``size / cells`` of
    ``n_cell`` elements, periodic along ``periodic_axes`` and bounded by the box's flat faces
    along the others (``cells`` = 1 there: the box's whole extent), repeated ``cells`` times
    along the periodic axes: the cell jammed (:func:`jam`, periodic along those axes) and
    made stress-free (:func:`stress_free_network`: the bonds across the cell's periodic
    boundaries, and the elements at the faces tangent to them). The bounded faces are flat
    and touched as in a box jammed whole, while the cost is the cell's: a 3-D Brazilian
    disc's box of 42,282 elements jammed whole took 55-80 CPU-minutes. The micro-structure
    repeats every cell side along the periodic axes; the box's faces there cut the cells (an
    element left without a bond is dropped). Returns ``(x, r, report)`` as
    :func:`tiled_packing`, with ``periodic_axes`` and the face contacts."""
    cells = np.asarray(cells, np.int64)
    along = {int(a) for a in periodic_axes}
    flags = tuple(a in along for a in range(cells.size))
    if not any(flags) or all(flags) or np.any(cells[~np.array(flags)] != 1):
        raise ValueError(f"a strip is periodic along some axes, not all, and has one cell "
                         f"along the others: periodic axes {sorted(along)}, cells "
                         f"{cells.tolist()}")
    return _repeated_cell(size, d_mean, distri_rate, cells, n_cell, flags, seed=seed,
                          overlap=overlap, gap=gap, prestress=prestress)


def tile_counts(size, vmean, phi, elements=TILE_ELEMENTS) -> np.ndarray:
    """Cells along each axis of the box ``size`` [m] for cells of about ``elements`` elements
    of mean volume ``vmean`` [m^dim] at solid fraction ``phi``: the cell's side closest to
    that cube's, and a whole number of cells along every axis."""
    return strip_counts(size, vmean, phi, range(len(size)), elements)


def tiled_packing(size, d_mean, distri_rate, cells, n_cell, *, seed=0,
                  overlap=DEFAULT_OVERLAP, gap=DEFAULT_GAP, prestress=DEFAULT_PRESTRESS):
    """A random packing of the box ``[0, size]`` [m] made of one periodic cell
    (``size / cells``, ``n_cell`` elements) repeated ``cells`` times along the axes: the cell
    jammed (:func:`jam`, periodic) and made stress-free (:func:`stress_free_network`,
    periodic), so that every bond across a cell boundary is a bond of the cell itself and the
    repeated packing is stress-free everywhere. Its cost is the cell's plus a copy: about
    linear in the box. The micro-structure repeats every cell side (about 20 d_mean for
    :data:`TILE_ELEMENTS`); the box's faces cut the repeated cells (centres inside, elements
    across a face overhang it, no face contacts; an element left without a bond there is
    dropped). Returns ``(x, r, report)`` as :func:`isotropic_packing`, the report with
    ``tiles`` (cells per axis), ``tile_elements``, ``tile_size`` [m] and ``loose_removed``."""
    return _repeated_cell(size, d_mean, distri_rate, cells, n_cell, True, seed=seed,
                          overlap=overlap, gap=gap, prestress=prestress)


def _repeated_cell(size, d_mean, distri_rate, cells, n_cell, periodic, *, seed, overlap, gap,
                   prestress):
    """:func:`tiled_packing` (``periodic`` True) and :func:`strip_packing` (one flag per axis):
    the cell jammed with its periodicity, made stress-free, repeated ``cells`` times; the
    touching pairs of the copies are the bonds; an element the box's faces cut from all its
    bonds is dropped."""
    from geodem.build import packing

    t0 = time.perf_counter()
    size = np.asarray(size, float)
    cells = np.asarray(cells, np.int64)
    dim = size.size
    rng = np.random.default_rng(seed)
    r0 = packing.radii(int(n_cell), d_mean, distri_rate, rng) / d_mean
    cell = size / d_mean / cells
    flags = np.broadcast_to(np.asarray(periodic, bool), (dim,))
    period = np.where(flags, cell, 0.0)
    strip = None if flags.all() else [int(a) for a in np.flatnonzero(flags)]
    kind = "a periodic cell" if strip is None else \
        f"a strip cell (periodic along axes {strip}, flat faces along the others)"
    progress.report(f"isotropic packing: {kind} of {int(n_cell):,} elements, repeated "
                    f"{' x '.join(str(int(c)) for c in cells)}")
    xj, rj, info = jam(r0, np.zeros(dim), cell, overlap=overlap, seed=rng.integers(2 ** 31),
                       periodic=periodic)
    xs, rs, i, j, faces, added, res = stress_free_network(xj, rj, np.zeros(dim), cell, gap,
                                                          prestress, period=period)
    shift = float(np.abs(_nearest_image(xs - xj, period)).max())
    xs = _wrap(xs, period)
    grid = np.stack(np.meshgrid(*[np.arange(c) for c in cells], indexing="ij"), axis=-1)
    x = (xs[None, :, :] + (grid.reshape(-1, dim) * cell)[:, None, :]).reshape(-1, dim)
    r = np.tile(rs, int(np.prod(cells)))
    pi, pj = _pairs(x, r, 0.0)  # the touching pairs: the bonds inside the box
    keep = np.bincount(np.concatenate([pi, pj]), minlength=r.size) > 0
    if not keep.all():  # elements the box's faces cut from all their bonds
        x, r = x[keep], r[keep]
        pi, pj = _pairs(x, r, 0.0)
    hi = size / d_mean
    vol = packing.element_volume(r, dim).sum() / np.prod(hi)
    copies = int(np.prod(cells))
    rep = {"n": int(r.size), "d_mean": 2.0 * float(r.mean()) * d_mean, "scale": info["scale"],
           "jam_overlap": info["mean_overlap"], "jam_cycles": info["cycles"],
           "fire_iterations": info["fire_iterations"], "jam_cached": info["cached"],
           "bonds": int(pi.size), "face_contacts": len(faces) * copies,
           "rattler_bonds": int(added) * copies,
           "max_radius_change": float(np.abs(rs / rj - 1.0).max()), "max_shift": shift,
           "residual": res, "packing_fraction": float(vol),
           "tiles": [int(c) for c in cells], "tile_elements": int(n_cell),
           "tile_size": [float(c) * d_mean for c in cell]}
    if strip is not None:
        rep["periodic_axes"] = strip
    rep.update(loose_removed=int((~keep).sum()), time_s=time.perf_counter() - t0)
    progress.report(f"isotropic packing: {rep['n']:,} elements, {rep['bonds']:,} bonds in "
                    f"{rep['time_s']:.1f} s")
    return x * d_mean, r * d_mean, rep
