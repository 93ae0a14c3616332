"""Cheap whole-model checks run between steps (never inside one): finiteness and overlaps."""
from __future__ import annotations

import numba
import numpy as np
from numba import prange


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
