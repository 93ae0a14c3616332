"""Lab-test measurements from recorded curves, and the contact stress of a state (pure numpy; no
engine).

Sign convention (lab, as in rock mechanics): **compression positive**. Axial stress and axial strain
of a compression test are positive (shortening); lateral strain of a specimen that bulges is
negative, so ``nu = -d(eps_lat)/d(eps_ax)`` is positive. Tensile strength and Brazilian strength are
returned as positive magnitudes. Triaxial principal stresses ``sigma1 >= sigma3`` are positive in
compression. Convert engine output (tension positive) by changing sign before calling these.

Functions (docs/materials.md, VALIDATION.md "uniaxial / triaxial", "Brazilian disc"):

* :func:`youngs_modulus` - slope of the linear part of the pre-peak stress-strain curve;
* :func:`poisson_ratio` - ``-slope`` of lateral vs axial strain over the same part;
* :func:`peak` - UCS (peak stress) and the strain at the peak;
* :func:`elastic_window` - the part of the 10-50 % window before the cracks begin (where E and nu
  are fitted);
* :func:`brazilian_tensile_strength` - ``2 P / (pi D t)``;
* :func:`crack_start_offset` - mean distance of the first cracks from the disc centre / radius;
* :func:`mohr_coulomb_fit` - cohesion, friction angle and UCS from triaxial peaks;
* :func:`contact_stress` - Love-Weber (virial) mean stress of a set of elements' contact forces
  from a model state (engine convention: **tension positive**).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

MIN_POINTS = 3


# ----------------------------------------------------------------------------- validation
def _curve(name_x, x, name_y, y, min_points=MIN_POINTS, increasing=True):
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    for nm, a in ((name_x, x), (name_y, y)):
        if a.ndim != 1:
            raise ValueError(f"{nm} must be a 1-D array, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{nm} has non-finite values at indices "
                             f"{np.flatnonzero(~np.isfinite(a))[:5].tolist()}")
    if len(x) != len(y):
        raise ValueError(f"{name_x} and {name_y} must have the same length, got {len(x)} and "
                         f"{len(y)}")
    if len(x) < min_points:
        raise ValueError(f"need at least {min_points} points, got {len(x)}")
    if increasing:
        bad = np.flatnonzero(np.diff(x) <= 0)
        if bad.size:
            raise ValueError(f"{name_x} must increase strictly (monotonic loading, compression "
                             f"positive); it does not at index {int(bad[0]) + 1} "
                             f"({x[bad[0]]:g} -> {x[bad[0] + 1]:g})")
    return x, y


def _window(window):
    try:
        lo, hi = (float(w) for w in window)
    except (TypeError, ValueError):
        raise ValueError(f"window must be a pair (lo, hi) of fractions, got {window!r}") from None
    if not (0.0 <= lo < hi <= 1.0):
        raise ValueError(f"window = ({lo:g}, {hi:g}): allowed 0 <= lo < hi <= 1 (fractions of "
                         "the peak stress)")
    return lo, hi


def _window_indices(stress, window):
    """Indices of the pre-peak points with lo * peak <= stress <= hi * peak."""
    lo, hi = _window(window)
    ipk = int(np.argmax(stress))
    pk = stress[ipk]
    if not pk > 0:
        raise ValueError(f"peak stress is {pk:g}: no compressive loading in the record "
                         "(compression positive)")
    pre = stress[: ipk + 1]
    idx = np.flatnonzero((pre >= lo * pk) & (pre <= hi * pk))
    if idx.size < MIN_POINTS:
        raise ValueError(f"only {idx.size} pre-peak points lie between {lo:g} and {hi:g} of the "
                         f"peak stress {pk:g}; need >= {MIN_POINTS} (record more points or widen "
                         "the window)")
    return idx


def _slope(x, y):
    xm = x - x.mean()
    den = float(xm @ xm)
    if den == 0.0:
        raise ValueError("all x values in the fitting window are equal: slope undefined")
    return float(xm @ (y - y.mean())) / den


# ----------------------------------------------------------------------- uniaxial / triaxial
def youngs_modulus(strain, stress, window=(0.1, 0.5)) -> float:
    """Young's modulus [Pa]: least-squares slope of stress vs strain over the pre-peak points
    whose stress lies between ``window[0]`` and ``window[1]`` times the peak stress."""
    strain, stress = _curve("strain", strain, "stress", stress)
    idx = _window_indices(stress, window)
    return _slope(strain[idx], stress[idx])


def poisson_ratio(axial_strain, lateral_strain, window=(0.1, 0.5), stress=None) -> float:
    """Poisson's ratio ``-d(eps_lat)/d(eps_ax)`` by least squares (compression positive, so a
    bulging specimen has negative lateral strain and nu > 0).

    With ``stress`` given, the fit uses the same points as :func:`youngs_modulus` (fractions of
    the peak stress, pre-peak); without it, ``window`` is in fractions of the largest axial
    strain of the record (use it for records that stop before the peak).
    """
    ax, lat = _curve("axial_strain", axial_strain, "lateral_strain", lateral_strain)
    if stress is not None:
        _, s = _curve("axial_strain", ax, "stress", stress)
        idx = _window_indices(s, window)
    else:
        lo, hi = _window(window)
        top = ax.max()
        if not top > 0:
            raise ValueError(f"largest axial strain is {top:g}: no compression in the record")
        idx = np.flatnonzero((ax >= lo * top) & (ax <= hi * top))
        if idx.size < MIN_POINTS:
            raise ValueError(f"only {idx.size} points lie between {lo:g} and {hi:g} of the "
                             f"largest axial strain; need >= {MIN_POINTS}")
    return -_slope(ax[idx], lat[idx])


def peak(strain, stress) -> tuple[float, float]:
    """``(ucs, peak_strain)``: the largest stress of the record and the strain where it occurs
    (first occurrence)."""
    strain, stress = _curve("strain", strain, "stress", stress, min_points=1)
    i = int(np.argmax(stress))
    return float(stress[i]), float(strain[i])


def elastic_window(stress, cracks, bonds, window=(0.1, 0.5), crack_fraction=0.005):
    """The linear (pre-damage) part of a compression record, where E and nu are fitted.

    ``window`` = (lo, hi) in fractions of the peak stress, its upper end lowered to the
    crack-initiation stress ``sigma_ci``: the largest pre-peak stress recorded before the broken
    bonds ``cracks`` (cumulative, per point) exceed ``crack_fraction x bonds`` (ISRM's "average
    modulus of the linear portion"; Martin & Chandler 1994, Int. J. Rock Mech. 31(6), for the
    crack-initiation threshold). A bonded packing whose bonds break diffusely from a third of
    its peak dilates strongly inside a fixed 10-50 % window; fitted there, nu measures that
    dilation, not the elastic ratio. ``crack_fraction`` None keeps ``window``.

    Returns ``(lo, hi, sigma_ci)``. A packing that cracks before ``2 lo`` of its peak is fitted
    from ``lo = hi / 2`` instead (the lower end skips the first points only to avoid seating
    effects); ``hi`` is never set so low that fewer than :data:`MIN_POINTS` points remain from
    ``lo`` (it is then the stress of the last of those points / peak); ``sigma_ci`` is None
    when the cracks stay below the threshold before the peak.
    """
    lo, hi = _window(window)
    stress = np.asarray(stress, float)
    cracks = np.asarray(cracks, float)
    if stress.shape != cracks.shape:
        raise ValueError(f"stress and cracks differ in length ({stress.size} and {cracks.size})")
    ipk = int(np.argmax(stress))
    pk = float(stress[ipk])
    if not pk > 0:
        raise ValueError(f"peak stress is {pk:g}: no compressive loading in the record "
                         "(compression positive)")
    if crack_fraction is None:
        return lo, hi, None
    if not (bonds > 0 and 0.0 < crack_fraction < 1.0):
        raise ValueError(f"bonds = {bonds!r}, crack_fraction = {crack_fraction!r}: allowed "
                         "bonds > 0 and 0 < crack_fraction < 1")
    over = np.flatnonzero(cracks[: ipk + 1] > crack_fraction * bonds)
    if over.size == 0:
        return lo, hi, None
    before = stress[: over[0]]
    sigma_ci = float(before.max()) if before.size else 0.0
    top = sigma_ci / pk
    lo = min(lo, 0.5 * top)
    pre = np.sort(stress[: ipk + 1][stress[: ipk + 1] >= lo * pk])
    if pre.size >= MIN_POINTS:
        top = max(top, float(pre[MIN_POINTS - 1]) / pk)
    return lo, float(min(hi, max(top, lo))), sigma_ci


# --------------------------------------------------------------------------------- Brazilian
def _pos(name, v, unit):
    if not (isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) and v > 0):
        raise ValueError(f"{name} = {v!r}: must be a finite number > 0 [{unit}]")
    return float(v)


def brazilian_tensile_strength(peak_load, diameter, thickness) -> float:
    """Indirect tensile strength of a Brazilian disc [Pa]: ``2 P / (pi D t)`` with peak load
    ``P`` [N] (compressive, positive), diameter ``D`` [m] and thickness ``t`` [m]."""
    P = _pos("peak_load", peak_load, "N")
    D = _pos("diameter", diameter, "m")
    t = _pos("thickness", thickness, "m")
    return 2.0 * P / (math.pi * D * t)


def crack_start_offset(crack_xy, centre, radius, k=10) -> float:
    """Mean distance of the first ``k`` cracks from the disc centre, divided by the radius.

    ``crack_xy``: crack (broken-bond) positions in the order they formed, shape ``(n, dim)`` with
    ``dim = len(centre)`` (project 3-D discs onto the disc plane first). 0 = at the centre,
    1 = at the rim; a valid Brazilian test starts cracking near the centre.
    """
    c = np.asarray(centre, dtype=float).ravel()
    xy = np.asarray(crack_xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != c.size or c.size not in (2, 3):
        raise ValueError(f"crack_xy must have shape (n, {c.size}) to match centre (2 or 3 "
                         f"coordinates), got {xy.shape}")
    if xy.shape[0] == 0:
        raise ValueError("no cracks given: crack_xy is empty")
    if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(c))):
        raise ValueError("crack_xy and centre must be finite")
    R = _pos("radius", radius, "m")
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"k = {k!r}: must be an integer >= 1")
    first = xy[: min(int(k), xy.shape[0])]
    return float(np.mean(np.linalg.norm(first - c, axis=1)) / R)


# ----------------------------------------------------------------------------- Mohr-Coulomb
class MohrCoulombFit(NamedTuple):
    cohesion: float  #: c [Pa]
    friction_angle_deg: float  #: phi [deg]
    ucs_fit: float  #: intercept Cu of sigma1 = Cu + tan^2(45 + phi/2) sigma3 [Pa]


def mohr_coulomb_fit(sigma3, sigma1) -> MohrCoulombFit:
    """Least-squares Mohr-Coulomb envelope through triaxial peaks (compression positive).

    Fits ``sigma1 = Cu + q sigma3`` with ``q = tan^2(45 + phi/2) = (1 + sin phi)/(1 - sin phi)``,
    so ``sin phi = (q - 1)/(q + 1)`` and ``c = Cu (1 - sin phi) / (2 cos phi)``.
    Needs at least two distinct confining stresses; returns ``(cohesion, friction_angle_deg,
    ucs_fit)``.
    """
    s3, s1 = _curve("sigma3", sigma3, "sigma1", sigma1, min_points=2, increasing=False)
    if np.unique(s3).size < 2:
        raise ValueError("need at least two different confining stresses sigma3 to fit an "
                         "envelope")
    if np.any(s1 < s3):
        i = int(np.flatnonzero(s1 < s3)[0])
        raise ValueError(f"sigma1 < sigma3 at index {i} ({s1[i]:g} < {s3[i]:g}): sigma1 is the "
                         "largest principal stress (compression positive)")
    q = _slope(s3, s1)
    cu = float(s1.mean() - q * s3.mean())
    if not q >= 1.0:
        raise ValueError(f"fitted slope d(sigma1)/d(sigma3) = {q:g} < 1 means a negative friction "
                         "angle; check the data (compression positive)")
    sphi = (q - 1.0) / (q + 1.0)
    phi = math.asin(sphi)
    c = cu * (1.0 - sphi) / (2.0 * math.cos(phi))
    return MohrCoulombFit(c, math.degrees(phi), cu)


# ----------------------------------------------------------------------------- contact stress
def contact_stress(state, idx, volume) -> np.ndarray:
    """Love-Weber (virial) mean stress of the elements ``idx`` over ``volume`` [Pa], tension
    positive, as a ``(dim, dim)`` array ``sigma[a, b]``::

        sigma = (1 / V) sum_{i in idx} sum_{contacts c of i} f_c (x) l_c
        f_c = Fn n + Fs   (force on i; n = (x_j - x_i) / |x_j - x_i|, Fn tension positive)
        l_c = (x_j - x_i) r_i / (r_i + r_j)   (centre of i to the contact point)

    with the contact law of :mod:`geodem.core.law` (bonded: ``Fn = Kn Xn``; unbonded: only in
    compression, Hertz if ``state.hertz``; ``Fs`` the stored shear spring). Summed over every
    element of a region, the contacts inside it count once as ``f (x) (x_j - x_i)``. ``volume``
    [m^3] is the region's volume (2-D: area x thickness). Without particle rotation (MatDEM's
    default) nothing balances the moments of the shear forces, so ``sigma`` can be asymmetric
    where the deformation rotates; it is returned as computed."""
    from geodem.core.law import series_array
    from geodem.core.state import BONDED

    idx = np.asarray(idx, dtype=np.int64)
    x, r = state.x, state.r
    nbr = state.nbr[idx]
    valid = nbr >= 0
    j = np.where(valid, nbr, idx[:, None])
    dvec = x[j] - x[idx][:, None, :]
    dist = np.where(valid, np.linalg.norm(dvec, axis=2), 1.0)
    n = dvec / dist[..., None]
    ri, rj = r[idx][:, None], r[j]
    xn = dist - ri - rj
    kn = series_array(state.kn[idx][:, None], state.kn[j])
    bonded = valid & (state.cstate[idx] == BONDED)
    comp = valid & ~bonded & (xn < 0.0)
    fn = np.where(bonded, kn * xn, 0.0)
    if state.hertz:
        e_i = state.kn[idx][:, None] / (np.pi * ri)
        e_j = state.kn[j] / (np.pi * rj)
        ov = np.where(comp, -xn, 0.0)
        fn = fn - (4.0 / 3.0) * series_array(e_i, e_j) * np.sqrt(series_array(ri, rj)) * ov * \
            np.sqrt(ov)
    else:
        fn = fn + np.where(comp, kn * xn, 0.0)
    f = fn[..., None] * n + np.where(valid[..., None], state.fs[idx], 0.0)
    lever = dvec * (ri / (ri + rj))[..., None]
    return np.einsum("ika,ikb->ab", f, lever) / float(volume)
