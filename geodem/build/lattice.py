"""Regular packings, contact detection and bonded specimens.

All builders are vectorised numpy/scipy (no Python loop over elements), so that a
specimen of 10^6 elements is built in a few seconds.

Public functions
    fcc_lattice(nx, ny, nz, d)            -> (N, 3) close-packed (FCC, ABC along z)
    triangular_lattice(nx, ny, d)         -> (N, 2) triangular (hexagonal) disc packing
    chain(n, d, dim=3)                    -> (n, dim) straight chain along x
    contact_pairs(x, r, gap=0.0)          -> (i, j) pairs with surface gap <= gap
    random_specimen(n, dim=3, seed=0, size_ratio=1.2, d=1.0) -> (x, r)
    bonded_state(x, r, *, density, kn, ks, xb, fs0, mu, gap, ...) -> State
"""
from __future__ import annotations

import math
import numbers

import numpy as np
from scipy.spatial import cKDTree

from geodem.core.state import State, new_state

__all__ = [
    "fcc_lattice",
    "triangular_lattice",
    "chain",
    "contact_pairs",
    "random_specimen",
    "bonded_state",
    "lattice_shape",
]

SQRT3_2 = math.sqrt(3.0) / 2.0  # row spacing of a triangular layer / d
SQRT2_3 = math.sqrt(2.0 / 3.0)  # FCC close-packed layer spacing / d

#: relative tolerance of the contact test in :func:`contact_pairs` (exactly touching
#: lattice spheres must be found despite round-off in the distance)
CONTACT_RTOL = 1e-9

#: random_specimen: jitter amplitude and detection gap, in units of the spacing d
JITTER = 0.02
SPECIMEN_GAP = 0.05


# --------------------------------------------------------------------------- helpers
def _count(v, name):
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (numbers.Integral, np.integer)):
        raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    if v < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {v}")
    return int(v)


def _positive(v, name):
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0, got {v!r}") from None
    if not (math.isfinite(f) and f > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    return f


def _nonneg(v, name):
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number >= 0, got {v!r}") from None
    if not (math.isfinite(f) and f >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
    return f


def _index_dtype(n):
    return np.int32 if n < 2**31 - 1 else np.int64


# --------------------------------------------------------------------------- lattices
def fcc_lattice(nx, ny, nz, d):
    """Face-centred cubic close packing of spheres of diameter ``d``.

    Close-packed (triangular) layers lie in the x-y plane and are stacked ABC along z,
    layer spacing ``d*sqrt(2/3)``. Within a layer there are ``ny`` rows along x at row
    spacing ``d*sqrt(3)/2`` with ``nx`` spheres each (spacing ``d``); odd rows are
    offset by ``d/2``. Layer ``k`` is shifted in-plane by ``(k mod 3)`` times the
    vector from a sphere to the centroid of a triangle of the layer below
    (``(d/2, d*sqrt(3)/6)``; the C shift is reduced modulo ``d`` in x).

    Every interior sphere touches exactly 12 others at distance ``d``. Element order is
    x fastest, then row (y), then layer (z); element ``i + nx*(j + ny*k)``. Coordinates
    start at 0 and are all ``>= 0``.

    Returns ``(nx*ny*nz, 3)`` float64.
    """
    nx, ny, nz = _count(nx, "nx"), _count(ny, "ny"), _count(nz, "nz")
    d = _positive(d, "d")
    h = d * SQRT3_2
    i = np.arange(nx, dtype=np.float64)
    j = np.arange(ny)
    k = np.arange(nz)
    km = k % 3
    # in-plane x offset per (layer, row): row offset d/2 on odd rows, B layer +d/2
    xoff = ((j[None, :] % 2) + (km[:, None] == 1)) * (0.5 * d)          # (nz, ny)
    yrow = j[None, :] * h + km[:, None] * (h / 3.0)                      # (nz, ny)
    x = np.empty((nz, ny, nx, 3))
    x[..., 0] = i[None, None, :] * d + xoff[:, :, None]
    x[..., 1] = yrow[:, :, None]
    x[..., 2] = (k * (d * SQRT2_3))[:, None, None]
    return x.reshape(-1, 3)


def triangular_lattice(nx, ny, d):
    """Triangular (hexagonal) packing of discs of diameter ``d`` in the x-y plane.

    ``ny`` rows along x at spacing ``d*sqrt(3)/2``, ``nx`` discs per row at spacing
    ``d``; odd rows are offset by ``d/2``. Interior discs touch exactly 6 others.
    Element ``i + nx*j``; coordinates ``>= 0``. Returns ``(nx*ny, 2)`` float64.
    """
    nx, ny = _count(nx, "nx"), _count(ny, "ny")
    d = _positive(d, "d")
    i = np.arange(nx, dtype=np.float64)
    j = np.arange(ny)
    x = np.empty((ny, nx, 2))
    x[..., 0] = i[None, :] * d + ((j % 2) * (0.5 * d))[:, None]
    x[..., 1] = (j * (d * SQRT3_2))[:, None]
    return x.reshape(-1, 2)


def chain(n, d, dim=3):
    """``n`` elements on the x axis at spacing ``d`` starting at 0: shape ``(n, dim)``.

    ``dim`` may be 1, 2 or 3 (a :class:`State` needs 2 or 3).
    """
    n = _count(n, "n")
    d = _positive(d, "d")
    if dim not in (1, 2, 3):
        raise ValueError(f"dim must be 1, 2 or 3, got {dim!r}")
    x = np.zeros((n, dim))
    x[:, 0] = np.arange(n) * d
    return x


def lattice_shape(n, dim=3):
    """Lattice counts giving a nearly cubic (square) block of about ``n`` elements.

    Returns ``(nx, ny, nz)`` for ``dim=3`` (FCC, see :func:`fcc_lattice`) or
    ``(nx, ny)`` for ``dim=2`` (see :func:`triangular_lattice`). The physical extents
    are ``nx*d``, ``ny*d*sqrt(3)/2`` and ``nz*d*sqrt(2/3)``. Candidates whose count is
    within 5 % of ``n`` are scored by ``relative count error + 0.02*(aspect - 1)``
    (aspect = longest / shortest extent), so the count is as close to ``n`` as a
    reasonably cubic block allows.
    """
    n = _count(n, "n")
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    sp = np.array([1.0, SQRT3_2, SQRT2_3][:dim])  # spacing per axis / d
    edge = (n * np.prod(sp)) ** (1.0 / dim)  # cube edge / d
    ideal = edge / sp
    rng_ = [np.arange(1, min(n, int(math.ceil(3 * f)) + 3) + 1) for f in ideal[:-1]]
    grids = np.meshgrid(*rng_, indexing="ij")
    head = [g.ravel().astype(np.int64) for g in grids]
    base = np.prod(np.stack(head), axis=0)
    last0 = np.rint(n / base).astype(np.int64)
    best = None
    for delta in (-1, 0, 1):
        last = np.maximum(last0 + delta, 1)
        counts = base * last
        err = np.abs(counts - n) / n
        ext = np.stack([*head, last]) * sp[:, None]
        aspect = ext.max(axis=0) / ext.min(axis=0)
        score = np.where(err <= 0.05, err + 0.02 * (aspect - 1.0), np.inf)
        k = int(np.argmin(score))
        if np.isfinite(score[k]) and (best is None or score[k] < best[0]):
            best = (score[k], tuple(int(h[k]) for h in head) + (int(last[k]),))
    if best is None:  # cannot happen for n >= 1 (1 x .. x n is exact), kept as a guard
        return (n,) + (1,) * (dim - 1)
    return best[1]


# --------------------------------------------------------------------------- contacts
def contact_pairs(x, r, gap=0.0):
    """All pairs ``(i, j)``, ``i < j``, whose surface gap ``|x_i-x_j| - r_i - r_j <= gap``.

    ``x`` is ``(N, dim)``, ``r`` is ``(N,)`` or a scalar. Candidates come from
    ``scipy.spatial.cKDTree.query_pairs`` with radius ``2*max(r) + gap`` and are then
    filtered exactly. A relative tolerance ``CONTACT_RTOL*(r_i + r_j)`` is added to
    ``gap`` so that exactly touching lattice spheres (``gap=0``) are found despite
    round-off. Output is sorted by ``(i, j)``; dtype int32 (int64 above 2^31 elements).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (1, 2, 3):
        raise ValueError(f"x must have shape (N, 1|2|3), got {x.shape}")
    n = x.shape[0]
    r = np.asarray(r, dtype=np.float64)
    if r.ndim == 0:
        r = np.full(n, float(r))
    if r.shape != (n,):
        raise ValueError(f"r must be a scalar or have shape ({n},), got {r.shape}")
    gap = float(gap)
    if not math.isfinite(gap):
        raise ValueError(f"gap must be finite, got {gap}")
    idt = _index_dtype(n)
    if n < 2:
        return np.zeros(0, idt), np.zeros(0, idt)
    if not np.all(np.isfinite(x)):
        raise ValueError("x must be finite")
    if not (np.all(np.isfinite(r)) and np.all(r >= 0.0)):
        raise ValueError("r must be finite and >= 0")
    rmax = float(r.max())
    reach = 2.0 * rmax * (1.0 + 2 * CONTACT_RTOL) + gap
    if reach < 0.0:
        return np.zeros(0, idt), np.zeros(0, idt)
    tree = cKDTree(x, balanced_tree=False, compact_nodes=False)
    p = tree.query_pairs(reach, output_type="ndarray")
    del tree
    if p.shape[0] == 0:
        return np.zeros(0, idt), np.zeros(0, idt)
    i = p[:, 0].astype(idt)
    j = p[:, 1].astype(idt)
    del p
    # query_pairs promises i < j; enforce it anyway (cheap)
    sw = i > j
    if sw.any():
        i[sw], j[sw] = j[sw], i[sw].copy()
    # exact filter, column by column (contiguous gathers), in chunks to bound temporaries
    xt = np.ascontiguousarray(x.T)
    keep = np.empty(i.shape[0], bool)
    chunk = 1 << 22
    for s in range(0, i.shape[0], chunk):
        ii, jj = i[s:s + chunk], j[s:s + chunk]
        d2 = np.zeros(ii.shape[0])
        for col in xt:
            e = col[jj]
            e -= col[ii]
            e *= e
            d2 += e
        rs = r[ii] + r[jj]
        keep[s:s + chunk] = np.sqrt(d2) - rs <= gap + CONTACT_RTOL * rs
    i, j = i[keep], j[keep]
    order = np.argsort(i.astype(np.int64) * n + j, kind="stable")
    return i[order], j[order]


# --------------------------------------------------------------------------- specimen
def prune_loose(x, r, min_contacts, gap=0.0):
    """Keep of the centres ``x`` (radii ``r``) those with at least ``min_contacts`` contacts
    (:func:`contact_pairs` with ``gap``), removing the others again and again (a removal can
    leave a neighbour short). Returns the bool mask of the kept centres."""
    x = np.asarray(x, dtype=np.float64)
    r = np.broadcast_to(np.asarray(r, dtype=np.float64), (len(x),))
    keep = np.ones(len(x), bool)
    while keep.any() and min_contacts > 0:
        idx = np.flatnonzero(keep)
        i, j = contact_pairs(x[idx], r[idx], gap=gap)
        count = np.bincount(np.concatenate([i, j]), minlength=len(idx))
        short = count < min_contacts
        if not short.any():
            break
        keep[idx[short]] = False
    return keep


def random_specimen(n, dim=3, seed=0, size_ratio=1.2, d=1.0):
    """Dense, polydisperse bonded-specimen stand-in of about ``n`` elements: ``(x, r)``.

    Recipe (deterministic for ``seed``, ``numpy.random.default_rng(seed)``):

    1. Lattice: FCC (``dim=3``, :func:`fcc_lattice`) or triangular (``dim=2``,
       :func:`triangular_lattice`) of spacing ``d``; counts from :func:`lattice_shape`
       (nearly cubic block, count within 5 % of ``n``; the exact lattice count is
       returned).
    2. Jitter: every coordinate gets ``U(-0.02, 0.02)*d`` (first draw, shape (N, dim)).
       A neighbour distance then lies in ``d +/- J*d`` with ``J = 0.04*sqrt(dim)``.
    3. Radii: ``r_i = 0.5*d*s_i`` with ``s_i = c*u_i``, ``u_i ~ U(1/size_ratio, 1)``
       (second draw) and ``c = size_ratio*(1 + J - 0.05 + 1e-6)``, i.e. the smallest
       possible ``s`` is ``1 + J - 0.05`` (1.019 in 3-D, 1.007 in 2-D). Hence every
       lattice-neighbour pair has surface gap ``<= 0.05*d``, and
       ``contact_pairs(x, r, gap=0.05*d)`` finds all of them (12 per interior element
       in 3-D, 6 in 2-D). Most pairs overlap (mean overlap about ``0.1*d`` for
       ``size_ratio=1.2``), the largest about ``0.27*d``.
    4. Non-lattice pairs: the second-neighbour distance is ``d*sqrt(2)`` (3-D) or
       ``d*sqrt(3)`` (2-D), at least ``(sqrt(2) - J)*d`` resp. ``(sqrt(3) - J)*d``
       after jitter, while ``r_i + r_j + 0.05*d <= (c + 0.05)*d``. So there are none
       for ``size_ratio <= 1.27`` (3-D) or ``<= 1.61`` (2-D); larger ratios add a few
       between the largest elements.

    Returns ``x`` (N, dim) float64 and ``r`` (N,) float64.
    """
    n = _count(n, "n")
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    size_ratio = _positive(size_ratio, "size_ratio")
    if size_ratio < 1.0:
        raise ValueError(f"size_ratio must be >= 1, got {size_ratio}")
    d = _positive(d, "d")
    shape = lattice_shape(n, dim)
    x = fcc_lattice(*shape, d) if dim == 3 else triangular_lattice(*shape, d)
    rng = np.random.default_rng(seed)
    x += rng.uniform(-JITTER, JITTER, size=x.shape) * d
    jmax = 2.0 * JITTER * math.sqrt(dim)
    c = size_ratio * (1.0 + jmax - SPECIMEN_GAP + 1e-6)
    r = (0.5 * d * c) * rng.uniform(1.0 / size_ratio, 1.0, size=x.shape[0])
    return x, r


# --------------------------------------------------------------------------- state
def _elem_param(v, n, name, *, positive=False):
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or an array of shape ({n},)") from None
    if a.ndim != 0 and a.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {a.shape}")
    rng_txt = "> 0" if positive else ">= 0"
    ok = np.isfinite(a) & ((a > 0.0) if positive else (a >= 0.0))
    if not np.all(ok):
        raise ValueError(f"{name} must be finite and {rng_txt}")
    return np.broadcast_to(a, (n,))


def bonded_state(x, r, *, density, kn, ks, xb, fs0, mu, gap, eta=0.0, width=None,
                 thickness=None):
    """Allocate a :class:`State` and bond every pair in contact.

    Parameters
    ----------
    x : (N, 2|3) positions [m];  r : (N,) or scalar radii [m], > 0.
    density : scalar or (N,), > 0 [kg/m^3]. Mass ``m = density * volume`` with the
        sphere volume ``4/3 pi r^3`` (3-D) or the disc volume ``pi r^2 t`` (2-D), where
        ``t = thickness`` if given, else ``2 r`` per element (disc as thick as wide).
    kn, ks, xb, fs0, mu, eta : scalar or (N,), finite and >= 0 (element parameters,
        see :mod:`geodem.core.state`).
    gap : finite, >= 0 [m]; every pair with surface gap ``<= gap``
        (:func:`contact_pairs`) gets a bonded contact (``cstate = 1``) in both rows via
        :func:`geodem.core.neighbors.rows_from_pairs`.
    width : starting row width (int >= 1); default 16 (3-D) or 8 (2-D).
        ``rows_from_pairs`` grows it when an element has more contacts.
    thickness : 2-D disc thickness [m], > 0, or None (``2 r``); stored in
        ``state.thickness`` (0.0 when None). Not allowed in 3-D.

    ``state.skin`` (neighbour-search margin) is set to ``max(gap, 0.1*min(r))``: at
    least ``gap`` so that the rows already hold every pair the skin would catch, and
    never vanishing when ``gap = 0``.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise ValueError(f"x must have shape (N, 2) or (N, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x must be finite")
    n, dim = x.shape
    r = _elem_param(r, n, "r", positive=True)
    rho = _elem_param(density, n, "density", positive=True)
    params = {k: _elem_param(v, n, k) for k, v in
              (("kn", kn), ("ks", ks), ("xb", xb), ("fs0", fs0), ("mu", mu), ("eta", eta))}
    gap = _nonneg(gap, "gap")
    if width is None:
        width = 16 if dim == 3 else 8
    else:
        width = _count(width, "width")
    if thickness is not None:
        if dim == 3:
            raise ValueError("thickness applies to 2-D (discs) only; got 3-D positions")
        thickness = _positive(thickness, "thickness")

    if dim == 3:
        vol = (4.0 / 3.0) * np.pi * r ** 3
    else:
        t = thickness if thickness is not None else 2.0 * r
        vol = np.pi * r ** 2 * t
    m = rho * vol

    state = new_state(x, r, m, dim=dim, width=width, **params)
    if thickness is not None:
        state.thickness = thickness
    state.skin = max(gap, 0.1 * float(r.min())) if n else gap

    i, j = contact_pairs(x, r, gap)
    from geodem.core.neighbors import rows_from_pairs  # lazy: sibling module

    out = rows_from_pairs(state, i, j, bonded=True)
    if isinstance(out, State):
        state = out
    return state
