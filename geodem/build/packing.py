"""Random packings: element sizes, random placement, gravity deposition, platen compaction.

Size distribution (MatDEM's ``distriRate``)
    Diameters are uniform in ``[d_min, d_max]`` with ``d_max / d_min = (1 + r)^2`` (``r`` =
    ``distri_rate``) and ``(d_min + d_max) / 2 = d_mean``, i.e.
    ``d_min = 2 d_mean / (1 + (1+r)^2)``, ``d_max = (1+r)^2 d_min``. ``r = 0`` is monodisperse;
    MatDEM's default ``r = 0.2`` gives ``d_max / d_min = 1.44``.

Packing recipe (2-D and 3-D; gravity along the last axis, ``-y`` in 2-D, ``-z`` in 3-D)
    1. :func:`random_placement`: elements on a loose grid of cells of size ``1.02 d_max`` with a
       random jitter inside their cell and shuffled sizes: random, never overlapping; the grid is
       extended upwards when the box is too low for ``n`` elements.
    2. :func:`deposition_state`: the loose elements in a box of fixed wall elements (floor and
       sides; MatDEM walls are elements too) and a top platen of elements (group ``"platen"``),
       frictionless soft "packing material" (``kn`` proportional to ``d``, ``mu = 0``) so the
       packing gets dense.
    3. :func:`deposit`: gravity ``g = 2e-4 kn_mean / m_mean * d_mean`` (the weight of one element
       compresses a contact by ~0.02 % of ``d``), mass damping sized so that the terminal speed
       is ``0.05 d omega`` (omega = sqrt(kn_mean / m_mean)), time step 4 % of the smallest
       element period, until everything has landed; then standard balances until the
       unbalanced-force ratio is below ``tol``.
    4. :func:`compact`: the platen is brought down to just above the packing and lowered
       kinematically until its reaction reaches ``pressure`` [Pa] (default: half the deposit's
       weight per unit area) or it reaches ``height``; it is then held and the packing balanced.
    5. :func:`stiffen`: platen lifted, stiffness raised to the real material's, balanced: the
       overlaps locked into the packing shrink.
    6. :func:`relax`: gravity off, balanced until the largest overlap is a small fraction of the
       bonds' breaking displacement: the packing keeps its contacts (jammed, coordination about
       3.6 in 2-D) but holds almost no force, so bonds cemented now start stress-free and none
       break when the walls go (:func:`geodem.build.specimen.cement`).
"""
from __future__ import annotations

import math

import numpy as np

from geodem.build import progress
from geodem.core import groups, timestep
from geodem.core.state import new_state

__all__ = ["radii", "diameter_bounds", "random_placement", "deposition_state", "deposit",
           "compact", "stiffen", "relax", "packing_fraction", "element_volume"]

PACK_DT_FRACTION = 0.04
GRAVITY_OVERLAP = 2e-4  # weight of one element / kn: fraction of d_mean
TERMINAL_SPEED = 0.05  # terminal fall speed in units of d_mean * omega_0


def _rng(rng):
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def diameter_bounds(d_mean: float, distri_rate: float):
    """``(d_min, d_max)`` with ``d_max/d_min = (1+distri_rate)^2`` and mean ``d_mean``."""
    if not (math.isfinite(d_mean) and d_mean > 0):
        raise ValueError(f"d_mean must be finite and > 0, got {d_mean!r}")
    if not (math.isfinite(distri_rate) and distri_rate >= 0):
        raise ValueError(f"distri_rate must be finite and >= 0, got {distri_rate!r}")
    k = (1.0 + distri_rate) ** 2
    d_min = 2.0 * d_mean / (1.0 + k)
    return d_min, k * d_min


def radii(n: int, d_mean: float, distri_rate: float = 0.2, rng=None) -> np.ndarray:
    """``n`` radii, diameters uniform in ``[d_min, d_max]`` (see module docstring)."""
    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    d_min, d_max = diameter_bounds(d_mean, distri_rate)
    return 0.5 * _rng(rng).uniform(d_min, d_max, int(n))


def _mean_dpow(d_mean, distri_rate, k):
    """E[d^k] of the uniform diameter distribution."""
    a, b = diameter_bounds(d_mean, distri_rate)
    if b - a < 1e-15 * b:
        return a ** k
    return (b ** (k + 1) - a ** (k + 1)) / ((k + 1) * (b - a))


def element_volume(r, dim, thickness=None):
    """Sphere volume (3-D) or disc area (2-D; times ``thickness`` if given)."""
    r = np.asarray(r, float)
    if dim == 3:
        return 4.0 / 3.0 * np.pi * r ** 3
    a = np.pi * r ** 2
    return a if thickness is None else a * thickness


def random_placement(box, n=None, porosity=None, radii_=None, d_mean=None, distri_rate=0.2,
                     dim=None, seed=0):
    """Random, non-overlapping positions in ``box = (lo, hi)``: returns ``(x, r)``.

    Give the radii (``radii_``), or ``n`` elements, or a target ``porosity`` of the box (then
    ``n = (1 - porosity) V_box / E[element volume]``), with ``d_mean`` and ``distri_rate``.
    Elements sit in cells of size ``1.02 d_max`` of a grid filling the box from the bottom (last
    axis) in random order, each with a random offset inside its cell; the grid grows above the
    box top when the box holds fewer cells than elements (deposition lets them fall). Vectorised;
    deterministic for ``seed``.
    """
    lo = np.asarray(box[0], float)
    hi = np.asarray(box[1], float)
    if lo.shape != hi.shape or lo.size not in (2, 3) or not np.all(hi > lo):
        raise ValueError(f"box must be (lo, hi) with 2 or 3 components and hi > lo, got {box}")
    dim = lo.size if dim is None else dim
    if dim != lo.size:
        raise ValueError(f"dim={dim} but the box has {lo.size} components")
    rng = np.random.default_rng(seed)
    if radii_ is None:
        if d_mean is None:
            raise ValueError("give radii_ or d_mean (with n or porosity)")
        if n is None:
            if porosity is None or not 0.0 <= porosity < 1.0:
                raise ValueError("give n or a porosity in [0, 1)")
            vmean = (np.pi / 6.0 * _mean_dpow(d_mean, distri_rate, 3) if dim == 3
                     else np.pi / 4.0 * _mean_dpow(d_mean, distri_rate, 2))
            n = int(round((1.0 - porosity) * np.prod(hi - lo) / vmean))
        r = radii(n, d_mean, distri_rate, rng)
    else:
        r = np.asarray(radii_, float).copy()
        if r.ndim != 1 or not np.all(r > 0):
            raise ValueError("radii_ must be a 1-D array of positive radii")
    n = r.size
    if n == 0:
        return np.zeros((0, dim)), r
    s = 2.0 * float(r.max()) * 1.02
    ncell = np.floor((hi - lo) / s).astype(int)
    if np.any(ncell[:-1] < 1):
        raise ValueError(f"the box is narrower than one cell (1.02 d_max = {s:.4g})")
    per_layer = int(np.prod(ncell[:-1]))
    layers = max(int(ncell[-1]), -(-n // per_layer))
    # all cells, bottom layers first; take the n lowest cells in random order inside a layer
    grids = np.meshgrid(*[np.arange(c) for c in ncell[:-1]], np.arange(layers), indexing="ij")
    cells = np.stack([g.ravel() for g in grids], axis=1)
    key = cells[:, -1] + rng.uniform(0.0, 0.5, len(cells))
    cells = cells[np.argsort(key, kind="stable")[:n]]
    r = r[rng.permutation(n)]
    room = 0.5 * s - r  # >= 0.01 d_max
    jitter = rng.uniform(-1.0, 1.0, (n, dim)) * room[:, None]
    x = lo + (cells + 0.5) * s + jitter
    return x, r


def _plane_points(lo, hi, spacing):
    """Grid points covering the (possibly degenerate) box [lo, hi] with spacing <= ``spacing``."""
    axes = []
    for a, b in zip(lo, hi):
        k = max(int(math.ceil((b - a) / spacing - 1e-9)), 0) + 1
        axes.append(np.linspace(a, b, k) if b > a else np.array([a]))
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([v.ravel() for v in g], axis=1)


def _dedupe(p, tol):
    from scipy.spatial import cKDTree

    pairs = cKDTree(p).query_pairs(tol, output_type="ndarray")
    keep = np.ones(len(p), bool)
    if len(pairs):
        keep[pairs.max(axis=1)] = False
    return p[keep]


def deposition_state(x, r, box, *, rho=2650.0, kn_per_d=None, d_wall=None, top=None,
                     platen=True, skin=None, thickness=None):
    """A state for deposition: loose elements ``(x, r)`` (group ``"sample"``), fixed wall
    elements on the floor and the sides of ``box`` (group ``"wall"``; wall surfaces on the box
    faces) up to ``top`` (default: above the highest element), and a top platen of elements
    between the side walls at ``top`` (group ``"platen"``, fixed until :func:`compact`).

    Packing material: ``kn = ks = kn_per_d * d`` (default ``1e6 N/m per d_mean`` scaled),
    ``mu = 0`` (frictionless: dense packing), no bonds. Wall/platen elements have diameter
    ``d_wall`` (default ``2 d_mean``), spacing at most ``0.95 d_wall`` (walls and platen wider
    than ``4 d_wall``). 2-D masses use ``thickness``
    (default: per element ``t = d``).
    """
    x = np.asarray(x, float)
    r = np.asarray(r, float)
    n, dim = x.shape
    lo = np.asarray(box[0], float)
    hi = np.asarray(box[1], float)
    d_mean = 2.0 * float(r.mean())
    if kn_per_d is None:
        kn_per_d = 1e6 / d_mean
    d_wall = 2.0 * d_mean if d_wall is None else float(d_wall)
    rw = 0.5 * d_wall
    sp = 0.95 * d_wall  # spacing in (0.76, 0.95] d_wall: no gap, fixed overlaps < r/2
    if top is None:
        top = max(float(hi[-1]), float((x[:, -1] + r).max()) + 0.5 * d_mean)
    # floor and side walls (centres one wall radius outside the faces)
    parts = []
    flo = np.append(lo[:-1] - rw, lo[-1] - rw)
    fhi = np.append(hi[:-1] + rw, lo[-1] - rw)
    parts.append(_plane_points(flo, fhi, sp))
    for a in range(dim - 1):
        for side, c in ((0, lo[a] - rw), (1, hi[a] + rw)):
            wlo = np.append(lo[:-1] - rw, lo[-1] - rw)
            whi = np.append(hi[:-1] + rw, top + rw)
            wlo[a] = whi[a] = c
            parts.append(_plane_points(wlo, whi, sp))
    walls = _dedupe(np.concatenate(parts), 0.5 * sp)
    eps = 0.05 * 2.0 * float(r.min())
    if platen:
        plo = np.append(lo[:-1] + rw + eps, top + rw)
        phi = np.append(hi[:-1] - rw - eps, top + rw)
        plat = _plane_points(plo, phi, sp)
    else:
        plat = np.zeros((0, dim))
    # a platen only a few wall elements wide gets a spacing below 0.75 d_wall (3 points over
    # 1.4 d_wall: 0.71 d_wall), and its fixed elements would overlap by more than half a
    # radius: such a platen gets elements of spacing / 0.85 instead (the walls' overlap)
    r_plat = rw
    if len(plat) > 1:
        gaps = [np.diff(np.unique(plat[:, a])) for a in range(dim - 1)]
        gaps = [g.min() for g in gaps if g.size]
        if gaps and min(gaps) < 0.75 * d_wall:
            r_plat = 0.5 * min(gaps) / 0.85
    xa = np.concatenate([x, walls, plat])
    ra = np.concatenate([r, np.full(len(walls), rw), np.full(len(plat), r_plat)])
    t = None if thickness is None else thickness
    vol = element_volume(ra, dim, t) if (dim == 3 or t is not None) else \
        element_volume(ra, dim) * 2.0 * ra
    m = rho * vol
    kn = kn_per_d * 2.0 * ra
    st = new_state(xa, ra, m, kn=kn, ks=kn, xb=0.0, fs0=0.0, mu=0.0,
                   width=16 if dim == 3 else 8)
    if thickness is not None:
        st.thickness = float(thickness)
    nw = len(walls)
    groups.add_group(st, "sample", np.arange(n))
    groups.add_group(st, "wall", np.arange(n, n + nw))
    groups.fix(st, "wall")
    if platen:
        groups.add_group(st, "platen", np.arange(n + nw, n + nw + len(plat)))
        groups.fix(st, "platen")
    st.skin = 0.5 * d_mean if skin is None else float(skin)
    from geodem.core.neighbors import build_rows

    build_rows(st)
    return st


def _stats(st):
    s = groups.members(st, "sample")
    return s, 2.0 * float(st.r[s].mean()), float(st.m[s].mean()), float(st.kn[s].mean())


def _simulation(st, backend):
    from geodem.core.engine import Simulation

    if st.dt <= 0.0:
        s = groups.members(st, "sample")
        per = timestep.element_periods(st)[s]
        st.dt = PACK_DT_FRACTION * float(per.min())
    try:
        return Simulation(st, backend=backend, monitor_every=0)
    except ValueError:
        st.dt = 0.5 * timestep.stable_dt_bound(st)
        return Simulation(st, backend=backend, monitor_every=0)


def _n_across(st):
    s, d, _, _ = _stats(st)
    ext = st.x[s].max(axis=0) - st.x[s].min(axis=0)
    return max(float(ext.max()) / d, 1.0)


def deposit(st, *, gravity=None, tol=1e-2, max_steps=40000, chunk=500, backend=None):
    """Let the ``"sample"`` elements of a :func:`deposition_state` settle under gravity.

    ``gravity`` [m/s^2] (default ``GRAVITY_OVERLAP d_mean kn_mean / m_mean``) acts along the last
    axis. Mass damping ``eta = m g / v_t`` with terminal speed ``v_t = 0.05 d_mean omega_0``.
    Runs in chunks until nothing moves faster than ``0.3 v_t`` (or the mean speed is below
    ``0.02 v_t``), then standard balances until the
    unbalanced-force ratio is below ``tol``. Returns a dict with ``steps``,
    ``unbalanced_ratio``, ``gravity``, ``dt``.
    """
    s, d, m, kn = _stats(st)
    w0 = math.sqrt(kn / m)
    g = GRAVITY_OVERLAP * d * w0 * w0 if gravity is None else float(gravity)
    vt = TERMINAL_SPEED * d * w0
    st.gravity = np.zeros(st.dim)
    st.gravity[-1] = -g
    st.eta[:] = 0.0
    st.eta[s] = st.m[s] * g / vt
    sim = _simulation(st, backend)
    progress.report(f"deposition: {s.size:,} elements settling under gravity")
    tick = progress.Every()
    steps = 0
    while steps < max_steps:
        sim.run(chunk)
        steps += chunk
        sp = np.sqrt((st.v[s] ** 2).sum(axis=1))
        if float(sp.max()) < 0.3 * vt or float(sp.mean()) < 0.02 * vt:
            break
        if tick.due():
            progress.report(f"deposition: {steps:,} time steps, fastest element at "
                            f"{float(sp.max()) / vt:.2g} x the terminal speed (landed below 0.3)")
    n = _n_across(st)
    ratio = math.inf
    while steps < max_steps:
        ratio = sim.balance(n)
        steps += timestep.standard_balance_steps(n)
        progress.report(f"deposition: balance, unbalanced-force ratio {ratio:.2g} (target "
                        f"{tol:g}), {steps:,} time steps")
        if ratio < tol:
            break
    return {"steps": steps, "unbalanced_ratio": ratio, "gravity": g, "dt": st.dt, "sim": sim}


def _move_platen_to_surface(st, gap):
    s = groups.members(st, "sample")
    p = groups.members(st, "platen")
    surface = float((st.x[s, -1] + st.r[s]).max())
    target = surface + gap + float(st.r[p].max())
    st.x[p, -1] = target
    st.x_ref[p, -1] = target


def compact(st, *, pressure=None, height=None, speed=None, tol=1e-2, max_steps=40000,
            chunk=100, backend=None):
    """Lower the ``"platen"`` group kinematically onto the packing.

    The platen is first placed just above the highest element, then moves down at ``speed``
    [m/s] (default ``2e-3 d_mean`` per time step) until its reaction (along the last axis)
    reaches ``pressure * A`` (``A`` = the platen's cross-section between the walls; default
    pressure: half the weight of the sample per unit area) or its lower surface reaches ``height``.
    The platen is then held fixed and the packing balanced until the unbalanced-force ratio is
    below ``tol``. Returns ``steps``, ``pressure`` (reached), ``height`` (platen's lower surface),
    ``unbalanced_ratio``.
    """
    from geodem.core import neighbors

    s, d, m, kn = _stats(st)
    p = groups.members(st, "platen")
    if p.size == 0:
        raise ValueError("the state has no 'platen' group (deposition_state(platen=True))")
    xp = st.x[p, :-1]
    area = float(np.prod(xp.max(axis=0) - xp.min(axis=0) + 2.0 * st.r[p].max()))
    if st.dim == 2:
        area *= st.thickness if st.thickness > 0 else d
    g = abs(float(st.gravity[-1]))
    if pressure is None and height is None:
        pressure = 0.5 * float(st.m[s].sum()) * g / area if g > 0 else None
        if pressure is None:
            raise ValueError("give pressure or height (no gravity to derive a default)")
    if st.dt <= 0.0:
        _simulation(st, backend)
    if speed is None:
        speed = 2e-3 * d / st.dt
    _move_platen_to_surface(st, 0.01 * d)
    neighbors.build_rows(st)
    sim = _simulation(st, backend)
    sim.change(lambda z: groups.set_velocity(z, "platen", [0.0] * (z.dim - 1) + [-speed]),
               book_energy=False)
    steps = 0
    reached = 0.0
    progress.report("compaction: platen lowered onto the packing")
    tick = progress.Every()
    while steps < max_steps:
        sim.run(chunk)
        steps += chunk
        reached = float(groups.reaction(st, "platen")[-1]) / area
        bottom = float((st.x[p, -1] - st.r[p]).min())
        if (pressure is not None and reached >= pressure) or \
                (height is not None and bottom <= height):
            break
        if tick.due():
            progress.report(f"compaction: {steps:,} time steps, platen pressure {reached:.3g} Pa"
                            + (f" of {pressure:.3g}" if pressure is not None else ""))
    sim.change(lambda z: groups.fix(z, "platen"), book_energy=False)
    n = _n_across(st)
    ratio = math.inf
    for _ in range(10):
        ratio = sim.balance(n)
        steps += timestep.standard_balance_steps(n)
        progress.report(f"compaction: balance, unbalanced-force ratio {ratio:.2g} (target "
                        f"{tol:g})")
        if ratio < tol:
            break
    reached = float(groups.reaction(st, "platen")[-1]) / area
    return {"steps": steps, "pressure": reached, "target_pressure": pressure,
            "height": float((st.x[p, -1] - st.r[p]).min()), "unbalanced_ratio": ratio,
            "sim": sim}


def sample_overlap(st) -> float:
    """Largest overlap [m] between two ``"sample"`` elements (0 when none touch)."""
    s = groups.members(st, "sample")
    ins = np.zeros(st.n, bool)
    ins[s] = True
    i = np.repeat(np.arange(st.n), st.width)
    j = st.nbr.ravel()
    m = (j >= 0) & ins[i] & ins[np.maximum(j, 0)]
    i, j = i[m], j[m]
    gap = np.linalg.norm(st.x[j] - st.x[i], axis=1) - st.r[i] - st.r[j]
    return float(max(0.0, -gap.min())) if gap.size else 0.0


def _platen_touches_sample(st) -> bool:
    """Whether any ``"platen"`` element overlaps a ``"sample"`` element (walls ignored)."""
    p = groups.members(st, "platen")
    ins = np.zeros(st.n, bool)
    ins[groups.members(st, "sample")] = True
    nb = st.nbr[p]
    j = np.where(nb >= 0, nb, 0)
    dist = np.linalg.norm(st.x[j] - st.x[p][:, None, :], axis=-1)
    return bool(((nb >= 0) & ins[j] & (dist < st.r[p][:, None] + st.r[j])).any())


def relax(st, overlap, *, max_rounds=30, sim=None, backend=None):
    """Switch gravity off and balance (platen lifted, walls kept) until the largest overlap
    between sample elements is below ``overlap`` [m]. Returns ``steps``, ``rounds``,
    ``max_overlap`` [m], ``unbalanced_ratio``."""
    from geodem.core import neighbors

    if not (math.isfinite(overlap) and overlap > 0):
        raise ValueError(f"overlap must be finite and > 0 [m], got {overlap!r}")
    if "platen" in st.groups:
        groups.fix(st, "platen")
    if sim is None:
        neighbors.build_rows(st)
        sim = _simulation(st, backend)
    # gravity off for the jamming stage, set directly rather than through sim.change (which
    # also refreshes the accelerations for it): the first step keeps the accelerations under
    # gravity, as every packing and calibration so far was made (the stage's energy books are
    # not used, and a refresh moves every packing, chaotically, to another one)
    sim.sync().gravity[:] = 0.0
    sim.backend.push()
    n = _n_across(st)
    d = _stats(st)[1]
    steps = rounds = lifts = 0
    ratio = math.inf
    worst = sample_overlap(st)
    while worst > overlap and rounds < max_rounds:
        ratio = sim.balance(n)
        steps += timestep.standard_balance_steps(n)
        rounds += 1
        sim.sync()
        worst = sample_overlap(st)
        progress.report(f"relaxation: balance {rounds}, largest overlap {worst:.3g} m (target "
                        f"{overlap:.3g})")
        # the released packing grows by its compaction strain (the lower the deposition
        # stiffness, the more): a platen it reaches would hold the overlaps in, so lift it again
        if "platen" in st.groups and _platen_touches_sample(st):
            _move_platen_to_surface(st, 2.0 * d)
            neighbors.build_rows(st)
            sim.backend.push()
            lifts += 1
            worst = max(worst, overlap * (1.0 + 1e-9))  # balance once more without it
    return {"steps": steps, "rounds": rounds, "max_overlap": worst, "unbalanced_ratio": ratio,
            "platen_lifts": lifts}


def packing_fraction(x, r, lo, hi, n_samples=20000, seed=0):
    """Solid fraction of the region ``[lo, hi]`` by Monte Carlo: the share of ``n_samples``
    uniform points covered by at least one element (overlaps counted once). 2-D: area fraction
    of discs; 3-D: volume fraction of spheres."""
    from scipy.spatial import cKDTree

    x = np.asarray(x, float)
    r = np.asarray(r, float)
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    pts = np.random.default_rng(seed).uniform(lo, hi, (n_samples, x.shape[1]))
    k = min(16, len(x))
    dist, idx = cKDTree(x).query(pts, k=k)
    dist = dist.reshape(n_samples, k)
    idx = idx.reshape(n_samples, k)
    return float((dist <= r[idx]).any(axis=1).mean())


def stiffen(st, factor, *, tol=1e-3, max_rounds=10, backend=None):
    """Lift the platen clear of the packing, multiply ``kn, ks`` of every element by ``factor``
    and balance under the deposition gravity: the packing's overlaps shrink by ``factor``.

    Run before cementing: overlaps locked into a bonded specimen are released when the walls go,
    and a release strain larger than the bonds' breaking strain (``~Tu/E``) would break them.
    With the stiffness of the real material the overlaps drop to the scale of that material's own
    weight. Returns ``steps``, ``unbalanced_ratio``, ``dt``.
    """
    from geodem.core import neighbors

    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"factor must be finite and > 0, got {factor!r}")
    s, d, _, _ = _stats(st)
    if "platen" in st.groups:
        groups.fix(st, "platen")
        _move_platen_to_surface(st, 2.0 * d)
    st.kn[:] *= factor
    st.ks[:] *= factor
    st.v[:] = 0.0
    neighbors.build_rows(st)
    st.dt = 0.0
    sim = _simulation(st, backend)
    n = _n_across(st)
    ratio = math.inf
    steps = 0
    for k in range(max_rounds):
        ratio = sim.balance(n)
        steps += timestep.standard_balance_steps(n)
        progress.report(f"stiffening x{factor:.3g}: balance {k + 1}, unbalanced-force ratio "
                        f"{ratio:.2g} (target {tol:g})")
        if ratio < tol:
            break
    return {"steps": steps, "unbalanced_ratio": ratio, "dt": st.dt, "sim": sim}
