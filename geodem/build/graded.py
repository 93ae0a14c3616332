"""Graded random packings: fine elements in a region of interest, coarser ones away from it.

A scene such as a landslide needs its fine resolution only where things happen (the sliding
mass, the ground it slides on); the deep ground and the far field only carry the weight and the
boundary. A graded packing spends its elements accordingly:

1. **Size field.** ``size(x) -> d_nom`` [m], the nominal (mean) diameter wanted at each point:
   ``d`` in the region of interest, growing to ``factor d`` away from it. :func:`ramp` gives the
   usual law: ``d_nom = d (1 + (factor - 1) min(e / transition, 1))`` for an *excess distance*
   ``e`` (0 inside the region of interest, the distance beyond it outside), so the diameter
   grows linearly over ``transition`` metres (neighbouring elements differ by about
   ``(factor - 1) d / transition`` of ``d``: a gradual change, no step).
   :func:`geodem.geo.terrain.band_size_field` is the terrain version (fine within a band below
   the ground surface and below a sliding surface).
2. **Placement.** The expected count is ``sum phi V_cell / v(d_nom)`` over a grid of cells of
   ``d/2`` (``phi`` the random close packing fraction: 0.84 in 2-D, 0.635 in 3-D; ``v`` the
   mean element area (2-D) or volume (3-D) of the size distribution at ``d_nom``). Centres are
   drawn by systematic sampling of those expected counts along the cells (each zone gets its
   share to about one element, without the density fluctuations of independent random
   points, which make the packing flow by several diameters while it jams), each
   element's diameter uniform in ``[d_min, d_max]`` of its own ``d_nom``
   (:func:`geodem.build.packing.radii`, MatDEM's ``distri_rate``).
3. **Jamming.** Isotropic compression by radius expansion from those centres (frictionless
   harmonic discs or spheres, FIRE, planar box faces: :func:`geodem.build.isotropic.jam`), to
   a mean contact overlap of ``overlap`` d (default 1e-4). There is no gravity, so the elements
   move only by a fraction of their size (``max_drift`` in the report) and each stays in the
   zone it was drawn for; all radii are scaled by one common factor (``scale``, ~1).

Each element keeps its nominal diameter ``d_nom`` (times ``scale``): its element parameters
follow it by the size law of the macro -> micro conversion (:mod:`geodem.materials`,
PHYSICS.md section 2): ``kn, ks, xb ~ d``, ``fs0 ~ d^2`` and a given ``mass ~ d^3``
(:func:`scale_params`). Within one zone that is exactly what the uniform builders do (the
parameters of the nominal diameter for the whole size spread), so with ``factor = 1`` every
element gets the uniform model's parameters. Across the transition the pair law
(series springs ``kn_i kn_j / (kn_i + kn_j)``, the smaller breaking force) mixes them.
"""
from __future__ import annotations

import math
import time

import numpy as np

from geodem.build import packing

__all__ = ["ramp", "graded_packing", "scale_params", "expected_count", "overlap_ratio",
           "PHI_RANDOM"]

#: random close packing fraction of the default size spread (2-D discs, 3-D spheres)
PHI_RANDOM = {2: 0.84, 3: 0.635}
#: exponents of the size law: parameter ~ d^k (PHYSICS.md section 2, mixed sizes)
SIZE_LAW = {"kn": 1, "ks": 1, "xb": 1, "fs0": 2, "mass": 3}


def ramp(excess, d, factor, transition):
    """Nominal diameter ``d (1 + (factor - 1) min(max(e, 0) / transition, 1))`` for excess
    distances ``e`` [m] beyond the region of interest (``transition = 0``: a step)."""
    e = np.maximum(np.asarray(excess, float), 0.0)
    if transition > 0:
        t = np.minimum(e / float(transition), 1.0)
    else:
        t = (e > 0).astype(float)
    return float(d) * (1.0 + (float(factor) - 1.0) * t)


def _check(d, factor, distri_rate):
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"d must be finite and > 0 [m], got {d!r}")
    if not (math.isfinite(factor) and factor >= 1):
        raise ValueError(f"factor must be finite and >= 1, got {factor!r}")
    if not (math.isfinite(distri_rate) and 0 <= distri_rate < 1):
        raise ValueError(f"distri_rate must be in [0, 1), got {distri_rate!r}")


def _cells(lo, hi, spacing):
    """Centres and volume of a grid of cells of at most ``spacing`` covering ``[lo, hi]``."""
    k = np.maximum(np.ceil((hi - lo) / spacing).astype(int), 1)
    h = (hi - lo) / k
    axes = [lo[a] + (np.arange(k[a]) + 0.5) * h[a] for a in range(lo.size)]
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([v.ravel() for v in g], axis=1), float(np.prod(h))


def _mean_size(dn, distri_rate, dim):
    """Mean element area (2-D) or volume (3-D) of the size distribution at nominal ``dn``."""
    if dim == 3:
        return math.pi / 6.0 * packing._mean_dpow(1.0, distri_rate, 3) * dn ** 3
    return math.pi / 4.0 * packing._mean_dpow(1.0, distri_rate, 2) * dn ** 2


def expected_count(lo, hi, size, d, distri_rate=0.2, phi=None):
    """Elements a graded packing of the box ``[lo, hi]`` holds: ``sum phi V_cell / v(d_nom)``
    over cells of ``d/2`` (module docstring); the wall layers count as empty (``0.15 d_nom`` of
    each face, as :func:`geodem.build.isotropic.isotropic_packing`)."""
    from geodem.build.isotropic import WALL_DEFICIT

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dim = lo.size
    phi = PHI_RANDOM[dim] if phi is None else float(phi)
    c, vc = _cells(lo, hi, 0.5 * d)
    dn = np.asarray(size(c), float)
    n = float(np.sum(phi * vc / _mean_size(dn, distri_rate, dim)))
    # wall deficit: a strip of 0.15 d_nom along each face holds no solid
    dface = float(np.mean(dn))
    inner = np.prod(np.maximum(hi - lo - 2.0 * WALL_DEFICIT * dface, 0.0)) / np.prod(hi - lo)
    return int(round(n * inner)), c, dn


def _systematic(lo, hi, size, d, distri_rate, dim, phi, n, rng):
    """``n`` centres with a density ``phi / v(d_nom)``: systematic sampling along the cells of
    ``d/2`` in boustrophedon order (an element wherever the running sum of the expected counts
    crosses an integer, from a random start; uniform inside its cell). Counts in any region
    match the expected ones to about one element, so jamming has no density fluctuations to
    even out (random Poisson centres make the packing flow by several diameters)."""
    phi = PHI_RANDOM[dim] if phi is None else float(phi)
    k = np.maximum(np.ceil((hi - lo) / (0.5 * d)).astype(int), 1)
    h = (hi - lo) / k
    idx = np.indices(k[::-1]).reshape(dim, -1)[::-1].T  # x fastest, then y (then z)
    # boustrophedon: reverse the fastest axis on every other row (and the next on every other
    # layer in 3-D), so consecutive cells are neighbours
    if dim == 3:
        flip_y = idx[:, 2] % 2 == 1
        idx[flip_y, 1] = k[1] - 1 - idx[flip_y, 1]
    row = idx[:, 1] + (idx[:, 2] * k[1] if dim == 3 else 0)
    flip_x = row % 2 == 1
    idx[flip_x, 0] = k[0] - 1 - idx[flip_x, 0]
    c = lo + (idx + 0.5) * h
    lam = phi * float(np.prod(h)) / _mean_size(np.asarray(size(c), float), distri_rate, dim)
    lam *= n / lam.sum()
    cum = np.cumsum(lam)
    marks = rng.uniform() + np.arange(n)
    cell = np.minimum(np.searchsorted(cum, marks), len(c) - 1)
    return c[cell] + rng.uniform(-0.5, 0.5, (n, dim)) * h


def graded_packing(lo, hi, size, d, distri_rate=0.2, *, seed=0, overlap=1e-4, phi=None,
                   max_elements=2_000_000):
    """A dense random packing of the box ``[lo, hi]`` [m] whose element sizes follow the size
    field ``size(x (N, dim)) -> d_nom (N,)`` [m] (module docstring); ``d`` is the finest
    nominal diameter (the length unit of the jamming). Returns ``(x, r, d_nom, report)``:
    centres, radii, each element's nominal diameter [m] (its parameters' size), and a report
    (``n``, ``scale``, ``jam_overlap``, ``fire_iterations``, ``max_drift`` [d],
    ``max_overlap_ratio``, ``d_nom_min``, ``d_nom_max``, ``time_s``)."""
    from geodem.build.isotropic import jam

    t0 = time.perf_counter()
    d = float(d)
    _check(d, 1.0, distri_rate)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dim = lo.size
    if dim not in (2, 3) or hi.shape != lo.shape or not np.all(hi > lo):
        raise ValueError(f"box must be two 2-D or 3-D corners with hi > lo, got {lo}, {hi}")
    n, _, dn_cells = expected_count(lo, hi, size, d, distri_rate, phi)
    if n > max_elements:
        raise ValueError(f"the graded packing would hold {n} elements (> max_elements = "
                         f"{max_elements})")
    if n < 1:
        raise ValueError("the box holds no element")
    dmin = float(dn_cells.min())
    if not (dmin > 0 and np.all(np.isfinite(dn_cells))):
        raise ValueError("the size field must give finite diameters > 0")
    rng = np.random.default_rng(seed)
    x = _systematic(lo, hi, size, d, distri_rate, dim, phi, n, rng)
    dn = np.asarray(size(x), float)
    r0 = packing.radii(n, 1.0, distri_rate, rng) * dn  # radii in m, mean diameter d_nom
    xj, rj, info = jam(r0 / d, lo / d, hi / d, overlap=overlap, x0=x / d,
                       seed=int(rng.integers(2 ** 31)))
    # jam scales every radius by one factor: the nominal diameters with them
    scale = float(info["scale"])
    xs, rs = xj * d, rj * d
    drift = np.linalg.norm(xs - x, axis=1) / d
    rep = {"n": int(n), "scale": scale, "jam_overlap": float(info["mean_overlap"]),
           "jam_cycles": int(info["cycles"]), "fire_iterations": int(info["fire_iterations"]),
           "jam_cached": info["cached"],
           "max_drift": float(drift.max()), "median_drift": float(np.median(drift)),
           "max_overlap_ratio": overlap_ratio(xs, rs),
           "d_nom_min": float(dn.min() * scale), "d_nom_max": float(dn.max() * scale),
           "time_s": time.perf_counter() - t0}
    return xs, rs, dn * scale, rep


def overlap_ratio(x, r) -> float:
    """Largest overlap of two elements as a fraction of the smaller radius (0: none touch);
    the quantity workflows hold below ``simulation.overlap_limit``."""
    from scipy.spatial import cKDTree

    x, r = np.asarray(x, float), np.asarray(r, float)
    if len(r) < 2:
        return 0.0
    p = cKDTree(x).query_pairs(2.0 * float(r.max()), output_type="ndarray")
    if len(p) == 0:
        return 0.0
    i, j = p[:, 0], p[:, 1]
    ov = r[i] + r[j] - np.linalg.norm(x[j] - x[i], axis=1)
    return float(max(0.0, (ov / np.minimum(r[i], r[j])).max()))


def scale_params(params: dict, d_ref: float, d_nom) -> dict:
    """Element parameters given for diameter ``d_ref`` (``kn, ks, xb, fs0, mu, rho`` and an
    optional ``mass``, e.g. :func:`geodem.workflow.models.element_params`) for elements of
    nominal diameters ``d_nom`` (array): ``kn, ks, xb ~ d``, ``fs0 ~ d^2``, ``mass ~ d^3``
    (the macro -> micro size law, :func:`geodem.materials.at_size`); ``mu`` and ``rho`` do
    not depend on size. Returns a dict of arrays (``mass`` None when not given)."""
    s = np.asarray(d_nom, float) / float(d_ref)
    out = {}
    for key, val in params.items():
        if key in SIZE_LAW:
            out[key] = None if val is None else float(val) * s ** SIZE_LAW[key]
        elif key in ("mu", "rho"):
            out[key] = np.full(s.shape, float(val))
        else:
            out[key] = val
    return out
