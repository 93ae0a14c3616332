"""Cheap whole-model checks run between steps (never inside one): finiteness and overlaps."""
from __future__ import annotations

import numba
import numpy as np
from numba import prange

from geodem.core.state import BONDED


@numba.njit(parallel=True, cache=True)
def _row_overlap(x, r, nbr, out_ratio, out_col):
    n, w = nbr.shape
    dim = x.shape[1]
    for i in prange(n):
        best = -np.inf
        col = -1
        for k in range(w):
            j = nbr[i, k]
            if j < 0:
                break
            d2 = 0.0
            for c in range(dim):
                e = x[j, c] - x[i, c]
                d2 += e * e
            ov = (r[i] + r[j] - np.sqrt(d2)) / min(r[i], r[j])
            if ov > best:
                best = ov
                col = k
        out_ratio[i] = best
        out_col[i] = col


def max_overlap(x, r, nbr):
    """Largest overlap of any row contact as a fraction of the smaller radius: ``(ratio, i, j)``."""
    n = x.shape[0]
    ratio = np.empty(n)
    col = np.empty(n, np.int64)
    _row_overlap(x, r, nbr, ratio, col)
    i = int(np.argmax(ratio))
    if col[i] < 0:
        return -np.inf, -1, -1
    return float(ratio[i]), i, int(nbr[i, col[i]])


@numba.njit(parallel=True, cache=True)
def _count_at_least(a, value):
    n = 0
    for i in prange(a.shape[0]):
        for k in range(a.shape[1]):
            if a[i, k] >= value:
                n += 1
    return n


def any_at_least(a, value) -> bool:
    """``(a >= value).any()`` for a 2-D integer array without a temporary array."""
    return _count_at_least(a, value) > 0


@numba.njit(parallel=True, cache=True)
def _unbalance_rows(x, r, kn, nbr, cstate, fs, a, m, v, eta, free, fnet, fcon, ncon):
    """Per element: |net force| (-1 for an element with no free component), the sum of
    |contact force| over its row entries, and their count. Written per element (no parallel
    reduction) so that the sums do not depend on the thread count, and because numba 0.68.0 on
    Python 3.12 fails to compile reductions inside this loop ("unexpected cycle in lookup")."""
    n, w = nbr.shape
    dim = x.shape[1]
    for i in prange(n):
        isfree = False
        f2 = 0.0
        for c in range(dim):
            if free[i, c] != 0.0:
                isfree = True
                t = m[i] * a[i, c] + eta[i] * v[i, c]
                f2 += t * t
        fnet[i] = np.sqrt(f2) if isfree else -1.0
        row = 0.0
        count = 0
        for k in range(w):
            j = nbr[i, k]
            if j < 0:
                break
            d2 = 0.0
            s2 = 0.0
            for c in range(dim):
                e = x[j, c] - x[i, c]
                d2 += e * e
                s2 += fs[i, k, c] * fs[i, k, c]
            xn = np.sqrt(d2) - r[i] - r[j]
            knij = kn[i] * kn[j] / (kn[i] + kn[j])
            fn = knij * xn if (cstate[i, k] == 1 or xn < 0.0) else 0.0
            row += np.sqrt(fn * fn + s2)
            count += 1
        fcon[i] = row
        ncon[i] = count


def unbalanced_force_ratio(state) -> float:
    """Mean |net force| on free elements / mean |contact force| (0 = perfect equilibrium).

    The net force of a free element is ``m a + eta v`` (the damping force is not a load), so the
    ratio measures the contact and body forces left unbalanced (PFC's mean unbalanced ratio).
    """
    s = state
    fnet = np.empty(s.n)
    fcon = np.empty(s.n)
    ncon = np.empty(s.n, dtype=np.int64)
    _unbalance_rows(s.x, s.r, s.kn, s.nbr, s.cstate, s.fs, s.a, s.m, s.v, s.eta, s.free,
                    fnet, fcon, ncon)
    freed = fnet >= 0.0
    nfree, ncon = int(freed.sum()), int(ncon.sum())
    fnet, fcon = float(fnet[freed].sum()), float(fcon.sum())
    if nfree == 0 or ncon == 0 or fcon == 0.0:
        return 0.0
    return (fnet / nfree) / (fcon / ncon)


def initial_overlap(state, bonded: bool = True, chunk: int = 200_000) -> tuple[float, int, int]:
    """Largest overlap of a contact in the rows with at least one free element, as a fraction
    of the smaller radius: ``(ratio, i, j)``; ``(0.0, -1, -1)`` when nothing overlaps. With
    ``bonded=False`` bonded pairs are left out (a lattice may be built in compression). (Overlaps
    between fixed elements are :func:`geodem.core.engine.validate_state`'s business.)"""
    best, bi, bj = 0.0, -1, -1
    movable = (state.free != 0).any(axis=1)
    for lo in range(0, state.n, chunk):
        hi = min(state.n, lo + chunk)
        nb = state.nbr[lo:hi]
        i = np.broadcast_to(np.arange(lo, hi)[:, None], nb.shape)
        ok = (nb >= 0) & (movable[i] | movable[np.maximum(nb, 0)])
        if not bonded:
            ok &= state.cstate[lo:hi] != BONDED
        if not ok.any():
            continue
        i, j = i[ok], nb[ok]
        dist = np.linalg.norm(state.x[j] - state.x[i], axis=1)
        ri, rj = state.r[i], state.r[j]
        ratio = (ri + rj - dist) / np.minimum(ri, rj)
        k = int(np.argmax(ratio))
        if ratio[k] > best:
            best, bi, bj = float(ratio[k]), int(min(i[k], j[k])), int(max(i[k], j[k]))
    return best, bi, bj
