"""The MatDEM contact law, written once as small scalar functions.

These functions are plain Python on scalars. Each backend compiles them for its own loop:
``numba.njit`` for the CPU loop, ``numba.cuda.jit(device=True)`` for the GPU kernel (see
``geodem.backends.kernels``). The NumPy reference (``geodem.backends.numpy_ref``) restates the
same rules in whole-matrix form and the tests hold the two to 1e-12.

A contact ``ij`` is evaluated from element ``i``'s side with the branch vector
``d = x_j - x_i``. Every quantity below is either symmetric in ``(i, j)`` or changes sign exactly
with ``d``, so the row of ``j`` reaches the same decisions bit for bit and the forces are
exactly opposite (PHYSICS.md section 1; Liu et al. 2017, MatDEM).

Normal (tension positive): ``Xn = |d| - (R_i + R_j)``, ``Kn = kf kn_i kn_j / (kn_i + kn_j)``,
``kf`` the contact's stiffness factor (1 but for a softer interface between two regions:
``geodem.core.state.enable_row_stiffness``; it scales ``Kn``, ``Ks`` and the Hertz force alike,
not the strengths)

* bonded: ``Fn = Kn Xn`` in tension and compression; tensile break when
  ``Fn >= BF = rate * min(kn_i xb_i, kn_j xb_j)``;
* unbonded: ``Fn = Kn Xn`` if ``Xn < 0`` else 0; with ``hertz`` the compression of an unbonded
  contact is ``Fn = -(4/3) E* sqrt(R*) |Xn|^1.5`` with ``E_i = kn_i/(pi R_i)``.

Shear: the stored spring ``Fs`` (force on ``i``) is projected onto the current tangent plane,
then ``Fs_trial = Fs + Ks dXs`` with ``dXs`` the tangential relative displacement of the centres
in the step, ``Ks = kf ks_i ks_j/(ks_i + ks_j)``.

* bonded: ``|Fs| <= Fsmax = rate * min(fs0_i, fs0_j) - mu Fn`` (``mu = min(mu_i, mu_j)``);
  exceeding it breaks the bond in shear; a pair broken in tension keeps nothing, a pair broken
  in compression keeps friction ``-mu Fn`` (the excess is breaking heat, not sliding);
* unbonded in compression: Coulomb, ``|Fs| <= -mu Fn``, the excess slides (friction heat);
* unbonded and apart: ``Fs = 0``.

Heat [J] of the contact in this step (the caller books half on each side):

* ``qn`` normal breaking: the energy of a bond broken in tension, ``Fn^2/(2Kn) +
  |Fs_trial|^2/(2Ks)``, less half the work its trial forces would have done over the step,
  ``(Fn dXn + Fs_trial . dXs)/2``: velocity Verlet books the step's work with the force *after*
  the break (zero), so this is what the bond really held (exact for linear springs);
* ``qs`` shear breaking: likewise the drop of the spring energy from ``Fs_trial`` to what is kept,
  ``(|Fs_trial|^2 - |Fs_kept|^2)/(2Ks) - (Fs_trial - Fs_kept) . dXs / 2``, plus the normal energy
  when the pair was in tension; with ``hertz``, a pair broken in compression also releases
  ``Kn Xn^2/2 - (2/5) |Fn_Hertz| |Xn|`` (its normal energy changes law);
* ``qf`` friction: ``(Fs_1 + Fs_2)/2 . dS`` with ``dS = (Fs_trial - Fs_new)/Ks``, plus the energy
  lost by projecting the spring and by a contact opening (so the books close).
"""
from __future__ import annotations

import math

UNBONDED = 0
BONDED = 1
HELPERS = ("series", "spring_energy", "tangent", "slip")  # called by the law; compiled per target


def series(a, b):
    """Two springs in series: ``a b / (a + b)``; 0 when both are 0 [N/m]."""
    s = a + b
    if s > 0.0:
        return a * b / s
    return 0.0


def series_array(a, b):
    """:func:`series` for NumPy arrays (whole-matrix code: reference backend, stability bound)."""
    import numpy as np

    s = a + b
    return np.where(s > 0.0, a * b / np.where(s > 0.0, s, 1.0), 0.0)


def spring_energy(f2, k):
    """Energy ``f^2/(2k)`` of a linear spring holding force squared ``f2``; 0 if ``k == 0`` [J]."""
    if k > 0.0:
        return 0.5 * f2 / k
    return 0.0


def tangent(nx, ny, nz, ax, ay, az):
    """Split ``a`` along the unit normal ``n``: returns the tangential part ``a - (a.n) n`` and
    ``a.n``. (:func:`contact` spells the same steps out: restructuring it changes the order of
    floating-point operations the compiler picks under fastmath, and the translation-only
    results are kept bit for bit.)"""
    p = nx * ax + ny * ay + nz * az
    return ax - p * nx, ay - p * ny, az - p * nz, p


def slip(sx, sy, sz, tx, ty, tz, scale, hk):
    """A spring of compliance ``2 hk`` capped from its trial value ``t`` to ``t * scale``,
    having held ``s`` at the start of the step: returns the capped value and the heat of the
    slip, mean force x slip = ``(s + t_new) . (t - t_new) hk``."""
    bx = tx * scale
    by = ty * scale
    bz = tz * scale
    return bx, by, bz, ((sx + bx) * (tx - bx) + (sy + by) * (ty - by) + (sz + bz) * (tz - bz)) * hk


def contact(dx, dy, dz, rx, ry, rz, sx, sy, sz,
            ri, rj, kni, knj, ksi, ksj, xbi, xbj, fs0i, fs0j, mui, muj,
            rate, kf, cs, broken_t, broken_s, hertz):
    """Evaluate one contact from element i's side.

    Parameters: branch vector ``d = x_j - x_i`` [m]; relative displacement of the step
    ``dx_j - dx_i`` [m]; stored shear spring ``Fs`` [N]; element parameters of i and j; bond rate;
    contact stiffness factor ``kf`` (0 < kf <= 1); contact state ``cs`` (1 bonded, anything
    else unbonded); the state codes to store for a tensile / shear break in this step;
    ``hertz`` flag (0/1).

    Returns ``(Fn, nx, ny, nz, sx, sy, sz, cs_new, qn, qs, qf)``: normal force (tension +) along
    the unit normal ``n = d/|d|``, the new shear spring, the new state and the step's heats.
    The force on ``i`` is ``Fn n + Fs``.
    """
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    inv = 1.0 / dist
    nx = dx * inv
    ny = dy * inv
    nz = dz * inv
    xn = dist - (ri + rj)
    kn = series(kni, knj) * kf
    ks = series(ksi, ksj) * kf

    # 1/(2 Ks) once: every shear energy below is |F|^2 * hks
    hks = 0.5 / ks if ks > 0.0 else 0.0

    # rotate the stored spring onto the current tangent plane; the projection's energy loss
    # (|Fs|^2 - |Fs_rot|^2)/(2Ks) = p^2/(2Ks) is booked as friction heat
    p = nx * sx + ny * sy + nz * sz
    sx = sx - p * nx
    sy = sy - p * ny
    sz = sz - p * nz
    qf = p * p * hks
    # trial shear force from the tangential relative displacement u of the step
    pr = nx * rx + ny * ry + nz * rz
    ux = rx - pr * nx
    uy = ry - pr * ny
    uz = rz - pr * nz
    tx = sx + ks * ux
    ty = sy + ks * uy
    tz = sz + ks * uz
    tr2 = tx * tx + ty * ty + tz * tz

    qn = 0.0
    qs = 0.0
    mu = min(mui, muj)
    if cs == BONDED:
        fn = kn * xn
        bf = rate * min(kni * xbi, knj * xbj)
        if fn >= bf:
            # tensile break: both springs release what they held (see module doc)
            qn = spring_energy(fn * fn, kn) + tr2 * hks \
                - 0.5 * (fn * pr + tx * ux + ty * uy + tz * uz)
            return 0.0, nx, ny, nz, 0.0, 0.0, 0.0, broken_t, qn, qs, qf
        fsmax = rate * min(fs0i, fs0j) - mu * fn
        if fsmax < 0.0 or tr2 > fsmax * fsmax:
            if fn >= 0.0:
                # shear break in tension: tension vanishes with the bond
                qs = spring_energy(fn * fn, kn) + tr2 * hks \
                    - 0.5 * (fn * pr + tx * ux + ty * uy + tz * uz)
                return 0.0, nx, ny, nz, 0.0, 0.0, 0.0, broken_s, qn, qs, qf
            # shear break in compression: keep the friction limit, the drop is heat
            lim = -mu * fn
            scale = lim / math.sqrt(tr2)
            qs = (tr2 - lim * lim) * hks - 0.5 * (1.0 - scale) * (tx * ux + ty * uy + tz * uz)
            if hertz:
                # the pair goes on as an unbonded Hertz contact: its normal energy at this Xn
                # changes from the bond's Kn Xn^2/2 to (2/5) |Fn_Hertz| |Xn|; the drop is heat
                ei = kni / (math.pi * ri)
                ej = knj / (math.pi * rj)
                fh = (4.0 / 3.0) * series(ei, ej) * math.sqrt(series(ri, rj)) * (-xn) \
                    * math.sqrt(-xn) * kf
                qs += 0.5 * kn * xn * xn - 0.4 * fh * (-xn)
            return fn, nx, ny, nz, tx * scale, ty * scale, tz * scale, broken_s, qn, qs, qf
        return fn, nx, ny, nz, tx, ty, tz, cs, qn, qs, qf

    if xn >= 0.0:
        # unbonded and apart: the spring empties
        qf += (sx * sx + sy * sy + sz * sz) * hks
        return 0.0, nx, ny, nz, 0.0, 0.0, 0.0, cs, qn, qs, qf
    if hertz:
        ei = kni / (math.pi * ri)
        ej = knj / (math.pi * rj)
        fn = -(4.0 / 3.0) * series(ei, ej) * math.sqrt(series(ri, rj)) * (-xn) * math.sqrt(-xn) \
            * kf
    else:
        fn = kn * xn
    lim = -mu * fn
    if tr2 > lim * lim:
        # Coulomb sliding: heat = mean force x slip, (Fs_rot + Fs_new)/2 . (Fs_trial - Fs_new)/Ks
        scale = lim / math.sqrt(tr2)
        nxs = tx * scale
        nys = ty * scale
        nzs = tz * scale
        qf += ((sx + nxs) * (tx - nxs) + (sy + nys) * (ty - nys) + (sz + nzs) * (tz - nzs)) * hks
        return fn, nx, ny, nz, nxs, nys, nzs, cs, qn, qs, qf
    return fn, nx, ny, nz, tx, ty, tz, cs, qn, qs, qf


def rolling(nx, ny, nz, tx, ty, tz, mx, my, mz, kr, lim):
    """Rolling resistance of one contact from element i's side (rotation option only).

    An elastic-plastic rolling spring (Iwashita & Oda 1998, J. Eng. Mech. 124(3); model C of
    Ai et al. 2011, Powder Technol. 206, without its dashpot): the stored moment on ``i``
    ``M`` [N m] loses its twisting part (along ``n``), then ``M_trial = M - Kr t_r`` with
    ``t_r`` the rolling part (normal to ``n``) of the step's relative rotation
    ``t = dtheta_i - dtheta_j`` [rad], and is capped at ``|M| <= lim``.

    The caller gives ``Kr = Ks R*^2`` [N m/rad] and ``lim = mu_r R* max(-Fn, 0)`` [N m]
    (``R* = R_i R_j/(R_i + R_j)``), so a contact in tension or apart holds no moment; a bond
    with moment-resisting bonds (``bond_moment`` b) has ``b R* F_b`` more, ``F_b`` its tensile
    strength (Potyondy & Cundall 2004, Int. J. Rock Mech. 41(8), the parallel bond). Like the
    shear spring, every quantity changes sign exactly with the side, so ``j`` gets ``-M``.

    Returns ``(mx, my, mz, q)``: the new moment and the heat [J] of the step, the twist
    removed, ``p^2/(2Kr)``, plus the rolling slip ``(M_rot + M_new)/2 . (M_trial - M_new)/Kr``
    (for ``lim = 0`` the whole stored energy less the work the elements receive this step).
    """
    hk = 0.5 / kr if kr > 0.0 else 0.0
    mx, my, mz, p = tangent(nx, ny, nz, mx, my, mz)
    ux, uy, uz, pt = tangent(nx, ny, nz, tx, ty, tz)
    ax = mx - kr * ux
    ay = my - kr * uy
    az = mz - kr * uz
    a2 = ax * ax + ay * ay + az * az
    if a2 > lim * lim:
        bx, by, bz, q = slip(mx, my, mz, ax, ay, az, lim / math.sqrt(a2) if lim > 0.0 else 0.0, hk)
        return bx, by, bz, p * p * hk + q
    return ax, ay, az, p * p * hk


def contact_energy(dx, dy, dz, sx, sy, sz, ri, rj, kni, knj, ksi, ksj, cs, hertz, kf=1.0):
    """Elastic energy of one contact from its current geometry and stored spring [J].

    ``Fn^2/(2Kn) + |Fs|^2/(2Ks)``; a Hertz contact stores ``(2/5) |Fn| |Xn|``; ``kf`` the
    contact's stiffness factor (:func:`contact`).
    """
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    xn = dist - (ri + rj)
    kn = series(kni, knj) * kf
    ks = series(ksi, ksj) * kf
    e = spring_energy(sx * sx + sy * sy + sz * sz, ks)
    if cs == BONDED:
        return e + 0.5 * kn * xn * xn
    if xn < 0.0:
        if hertz:
            ei = kni / (math.pi * ri)
            ej = knj / (math.pi * rj)
            fn = (4.0 / 3.0) * series(ei, ej) * math.sqrt(series(ri, rj)) * (-xn) \
                * math.sqrt(-xn) * kf
            return e + 0.4 * fn * (-xn)
        return e + 0.5 * kn * xn * xn
    return e
