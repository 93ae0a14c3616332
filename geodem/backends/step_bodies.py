"""The time step's per-element bodies, written once for every target (a template).

``geodem.backends.kernels.make_kernels`` compiles this module's functions per dimension, option
set and target: the names ``DIM`` (2 or 3), ``ROT`` (rotating elements), ``DAMP`` (contact
dashpot), ``NR`` (rotational DOFs) and the contact law's functions (``contact``, ``rolling``,
``contact_energy``, ``series``) are bound to compile-time constants and to the law compiled for
that target. The placeholders below only make the module importable; nothing here runs as
plain Python.

The step is two passes over elements (velocity Verlet, PHYSICS.md section 3):

1. ``move_body``: ``dx = dt v + dt^2 a / 2`` on free DOFs, ``dx = dt v`` on fixed/kinematic
   ones; ``x += dx``; books the first half of the viscous heat and of the external work.
2. ``force_body``: the element walks its own row (no scatter, no atomics), evaluates every
   contact with :func:`geodem.core.law.contact`, sums the force, and updates its velocity with
   the damping treated by the trapezoidal rule (implicit, unconditionally stable for the
   damping term): ``v' = (v + dt/2 a + dt/(2m) F) / (1 + eta dt/(2m))``,
   ``a' = (F - eta v')/m``. Fixed and kinematic DOFs keep their velocity and store
   ``a = F_contact/m`` (the reaction).

   On the CPU the force pass is usually split in two instead (``owner_body`` +
   ``finish_body``, section "each contact once" below): each contact is evaluated once, by the
   lower index, which posts the partner's share into a buffer (the partner's row if it is in
   the owner's slab, else the contact's spill row); ``finish_body`` then
   ends every element's step exactly as ``force_body`` does (``finish_dofs``). The GPU and
   steps over a list of awake elements keep ``force_body``.

``KROW`` (compile-time): the contacts carry their own stiffness factor ``krate``
(``geodem.core.state.enable_row_stiffness``: a softer interface between two regions), read by
:func:`row_stiffness`; without it the factor is the literal 1.0 and the compiled code is the
plain one.

``ROT`` (compile-time): the elements also turn (``geodem.core.state.enable_rotation``); the
rotation arrays ``w, wa, dth, rfree, inertia, mr, rot_props`` are then read and written,
otherwise they are placeholders the compiled code never touches. ``DAMP`` (compile-time):
contacts in compression get the normal dashpot of
``geodem.core.state.enable_contact_damping`` (damping ratio in ``props`` column 7).

The CPU loops (``cpu_*``, numba ``prange``) live here too, so that the compiled CPU kernels can
be cached on disk (see ``make_kernels``); the CUDA launches are in ``geodem.backends.kernels``.
"""
import math

from numba import prange

from geodem.backends.prefetch import prefetch_line
from geodem.core.law import BONDED, contact, contact_energy, rolling, series

DIM = 3  # placeholders: bound per compiled variant
ROT = False
DAMP = False
KROW = False
NR = 3
# the passes cpu_steps calls: jitted under these names in the generated module
move = force_owner = finish = None


def dof_free(v, a, f, m, eta, dt, ddx):
    # implicit trapezoidal damping; returns new v, new a, viscous heat share
    vn = (v + 0.5 * dt * a + 0.5 * dt * f / m) / (1.0 + 0.5 * dt * eta / m)
    return vn, (f - eta * vn) / m, 0.5 * eta * vn * ddx


def dof_step(free, v, a, fc, m, eta, dt, ddx):
    # one rotational degree of freedom after the force pass: a free one turns under the
    # torque fc (returns w, w', viscous heat, 0); a fixed or prescribed one keeps w and
    # stores the reaction fc/I, whose work -fc ddx/2 it returns. (The translational loop
    # spells the same out inline: see geodem.core.law.tangent on why.)
    if free != 0.0:
        vn, an, dq = dof_free(v, a, fc, m, eta, dt, ddx)
        return vn, an, dq, 0.0
    return v, fc / m, 0.0, -0.5 * fc * ddx


def translate_dofs(i, f0, f1, f2, v, a, dx, free, fload, mi, etai, g0, g1, g2, dt):
    # the translational DOFs of element i after the force pass, contact force (f0, f1, f2):
    # a free DOF takes gravity and its load too (dof_free); a fixed or prescribed one keeps
    # v and stores the reaction F/m, whose work over the step's second half it books.
    # Returns (viscous heat, external work) [J].
    qv = 0.0
    we = 0.0
    for d in range(DIM):
        if d == 0:
            fc = f0
            g = g0
        elif d == 1:
            fc = f1
            g = g1
        else:
            fc = f2
            g = g2
        if free[i, d] != 0.0:
            vn, an, dq = dof_free(v[i, d], a[i, d], fc + mi * g + fload[i, d], mi, etai, dt,
                                  dx[i, d])
            v[i, d] = vn
            a[i, d] = an
            qv += dq
        else:
            a[i, d] = fc / mi
            we -= 0.5 * fc * dx[i, d]
    return qv, we


def own_position(i, x, dx):
    # element i's position and step displacement (z = 0 in 2-D)
    if DIM == 3:
        return x[i, 0], x[i, 1], x[i, 2], dx[i, 0], dx[i, 1], dx[i, 2]
    return x[i, 0], x[i, 1], 0.0, dx[i, 0], dx[i, 1], 0.0


def branch(j, x, dx, xi0, xi1, xi2, di0, di1, di2):
    # branch vector x_j - x_i and relative displacement dx_j - dx_i of the step (z = 0 in 2-D)
    if DIM == 3:
        return (x[j, 0] - xi0, x[j, 1] - xi1, x[j, 2] - xi2,
                dx[j, 0] - di0, dx[j, 1] - di1, dx[j, 2] - di2)
    return x[j, 0] - xi0, x[j, 1] - xi1, 0.0, dx[j, 0] - di0, dx[j, 1] - di1, 0.0


def own_params(i, props):
    # props columns: r, kn, ks, xb, fs0, mu, mu_r, zeta (one cache line per element)
    return props[i, 0], props[i, 1], props[i, 2], props[i, 3], props[i, 4], props[i, 5]


def row_stiffness(kr, i, k):
    # KROW: the contact stiffness factor of entry k of row i; else exactly 1 (folded away)
    if KROW:
        return kr[i, k]
    return 1.0


def row_contact(i, k, j, bx, by, bz, rx, ry, rz, props, pi, fs, brate, kf, cs, code_t, code_s,
                hertz):
    # the law for entry k of row i (partner j, branch b, relative displacement r of the
    # step, i's parameters pi, stiffness factor kf); stores the new shear spring in the
    # entry, returns the law's tuple (geodem.core.law.contact)
    ri, kni, ksi, xbi, fs0i, mui = pi
    s2 = 0.0
    if DIM == 3:
        s2 = fs[i, k, 2]
    out = contact(bx, by, bz, rx, ry, rz, fs[i, k, 0], fs[i, k, 1], s2,
                  ri, props[j, 0], kni, props[j, 1], ksi, props[j, 2], xbi, props[j, 3],
                  fs0i, props[j, 4], mui, props[j, 5], brate[i, k], kf, cs, code_t, code_s,
                  hertz)
    fs[i, k, 0] = out[4]
    fs[i, k, 1] = out[5]
    if DIM == 3:
        fs[i, k, 2] = out[6]
    return out


def move_body(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
              w, wa, dth, rfree, inertia, fdash):
    qv = 0.0
    we = 0.0
    for d in range(DIM):
        if free[i, d] != 0.0:
            ddx = dt * v[i, d] + 0.5 * dt * dt * a[i, d]
            qv += 0.5 * eta[i] * v[i, d] * ddx
            we += fload[i, d] * ddx
        else:
            ddx = dt * v[i, d]
            we -= 0.5 * m[i] * a[i, d] * ddx
        dx[i, d] = ddx
        x[i, d] += ddx
        if DAMP:
            qv -= 0.5 * fdash[i, d] * ddx
    if ROT:
        # the same Verlet half step for the rotation; damping eta I/m (same decay time)
        ii = inertia[i]
        etar = eta[i] * ii / m[i]
        for d in range(NR):
            if rfree[i, d] != 0.0:
                ddt = dt * w[i, d] + 0.5 * dt * dt * wa[i, d]
                qv += 0.5 * etar * w[i, d] * ddt
            else:
                ddt = dt * w[i, d]
                we -= 0.5 * ii * wa[i, d] * ddt
            dth[i, d] = ddt
    q_visc[i] += qv
    w_ext[i] += we


def contact_point(i, j, bx, by, bz, rx, ry, rz, ri, rj, dth):
    # ROT: the law sees the contact point's relative displacement: the rotations move it by
    # -(R_i dth_i + R_j dth_j) x n (symmetric in i, j: j's side gets exactly the opposite)
    inv = 1.0 / math.sqrt(bx * bx + by * by + bz * bz)
    cnx = bx * inv
    cny = by * inv
    cnz = bz * inv
    if DIM == 2:
        cz = ri * dth[i, 0] + rj * dth[j, 0]
        return rx + cz * cny, ry - cz * cnx, rz
    cx = ri * dth[i, 0] + rj * dth[j, 0]
    cy = ri * dth[i, 1] + rj * dth[j, 1]
    cz = ri * dth[i, 2] + rj * dth[j, 2]
    return rx - (cy * cnz - cz * cny), ry - (cz * cnx - cx * cnz), rz - (cx * cny - cy * cnx)


def entry_contact(i, k, j, x, dx, xi0, xi1, xi2, di0, di1, di2, props, pi, fs, brate, kf, cs,
                  dth, code_t, code_s, hertz):
    # entry k of row i (partner j) through the law: the law's tuple (the spring stored), then
    # the relative displacement the law saw (the contact point's with ROT) and R_j (ROT)
    bx, by, bz, rx, ry, rz = branch(j, x, dx, xi0, xi1, xi2, di0, di1, di2)
    rj = 0.0
    if ROT:
        rj = props[j, 0]
        rx, ry, rz = contact_point(i, j, bx, by, bz, rx, ry, rz, pi[0], rj, dth)
    (fn, nx, ny, nz, sx, sy, sz, csn, eqn, eqs, eqf) = row_contact(
        i, k, j, bx, by, bz, rx, ry, rz, props, pi, fs, brate, kf, cs, code_t, code_s, hertz)
    return fn, nx, ny, nz, sx, sy, sz, csn, eqn, eqs, eqf, rx, ry, rz, rj


def dashpot(i, j, fn, csn, nx, ny, nz, rx, ry, rz, kni, kf, props, m, dt):
    # DAMP: normal dashpot c (v_j - v_i).n on a contact in compression, force on i along n
    # [N]; an unbonded contact may resist separation but never pull
    zeta = min(props[i, 7], props[j, 7])
    fd = 0.0
    if fn < 0.0 and zeta > 0.0 and dt > 0.0:
        mj = m[j]
        c = 2.0 * zeta * math.sqrt(m[i] * mj / (m[i] + mj) * (series(kni, props[j, 1]) * kf))
        # the step's mean relative velocity du/dt (the end-of-step velocities are not known
        # yet): first-order accurate in dt
        fd = c * (nx * rx + ny * ry + nz * rz) / dt
        if csn != BONDED and fd > -fn:
            fd = -fn
    return fd


def roll(i, j, k, fn, csn, nx, ny, nz, ri, rj, ksi, kf, props, brate, dth, mr, rp):
    # ROT: the rolling resistance of entry k of row i; stores the new moment, returns it
    # (moment on i [N m]; 2-D: about z only) and its heat. Rolling spring K_r = beta Ks R*^2
    # (beta: rp column 1). A bond (state csn after this step's law) also holds
    # bond_moment R* F_b (rp column 0), F_b = rate min(kn xb) its tensile strength
    rs = series(ri, rj)
    kr = min(rp[i, 1], rp[j, 1]) * (series(ksi, props[j, 2]) * kf) * rs * rs
    lim = min(props[i, 6], props[j, 6]) * rs * max(-fn, 0.0)
    if csn == BONDED:
        mbij = min(rp[i, 0], rp[j, 0])
        if mbij > 0.0:
            lim += mbij * rs * brate[i, k] * min(props[i, 1] * props[i, 3],
                                                 props[j, 1] * props[j, 3])
    if DIM == 2:
        (mx, my, mz, eqr) = rolling(nx, ny, nz, 0.0, 0.0, dth[i, 0] - dth[j, 0],
                                    0.0, 0.0, mr[i, k, 0], kr, lim)
        mr[i, k, 0] = mz
        return mx, my, mz, eqr
    (mx, my, mz, eqr) = rolling(nx, ny, nz, dth[i, 0] - dth[j, 0], dth[i, 1] - dth[j, 1],
                                dth[i, 2] - dth[j, 2], mr[i, k, 0], mr[i, k, 1], mr[i, k, 2],
                                kr, lim)
    mr[i, k, 0] = mx
    mr[i, k, 1] = my
    mr[i, k, 2] = mz
    return mx, my, mz, eqr


def force_body(i, x, v, a, dx, free, fload, props, m, eta,
               nbr, cstate, fs, brate, q_visc, q_bn, q_bs, q_f, w_ext,
               g0, g1, g2, dt, code_t, code_s, hertz, ext):
    # the options' arrays come as one tuple: seven more arguments of the inlined body made
    # the plain kernel 15-25 % slower (measured), one tuple costs nothing
    w, wa, dth, rfree, inertia, fdash, mr, rp, kr = ext
    xi0, xi1, xi2, di0, di1, di2 = own_position(i, x, dx)
    pi = own_params(i, props)
    ri, kni, ksi = pi[0], pi[1], pi[2]  # the rotation and the dashpot need these
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    qn = 0.0
    qs = 0.0
    qf = 0.0
    d0 = 0.0  # dashpot force (DAMP)
    d1 = 0.0
    d2 = 0.0
    t0 = 0.0  # torque [N m] (2-D: only t2, about z)
    t1 = 0.0
    t2 = 0.0
    for k in range(nbr.shape[1]):
        j = nbr[i, k]
        if j < 0:
            break
        cs = cstate[i, k]
        kf = row_stiffness(kr, i, k)
        (fn, nx, ny, nz, sx, sy, sz, csn, eqn, eqs, eqf, rx, ry, ez, rj) = entry_contact(
            i, k, j, x, dx, xi0, xi1, xi2, di0, di1, di2, props, pi, fs, brate, kf, cs, dth,
            code_t, code_s, hertz)
        if csn != cs:
            cstate[i, k] = csn
        f0 += fn * nx + sx
        f1 += fn * ny + sy
        f2 += fn * nz + sz
        qn += eqn
        qs += eqs
        qf += eqf
        if DAMP:
            fd = dashpot(i, j, fn, csn, nx, ny, nz, rx, ry, ez, kni, kf, props, m, dt)
            d0 += fd * nx
            d1 += fd * ny
            d2 += fd * nz
        if ROT:
            # the shear force acts at the contact point R_i n; rolling resistance on top
            mx, my, mz, eqr = roll(i, j, k, fn, csn, nx, ny, nz, ri, rj, ksi, kf, props,
                                   brate, dth, mr, rp)
            if DIM == 3:
                t0 += ri * (ny * sz - nz * sy) + mx
                t1 += ri * (nz * sx - nx * sz) + my
            t2 += ri * (nx * sy - ny * sx) + mz
            qf += eqr
    finish_dofs(i, f0, f1, f2, d0, d1, d2, t0, t1, t2, 0.5 * qn, 0.5 * qs, 0.5 * qf,
                v, a, dx, free, fload, m, eta, q_visc, q_bn, q_bs, q_f, w_ext,
                g0, g1, g2, dt, ext)


def finish_dofs(i, f0, f1, f2, d0, d1, d2, t0, t1, t2, qn, qs, qf,
                v, a, dx, free, fload, m, eta, q_visc, q_bn, q_bs, q_f, w_ext,
                g0, g1, g2, dt, ext):
    # element i's step after its contacts: contact force f, dashpot force d (DAMP), torque t
    # (ROT), and its shares of the contacts' heats qn, qs, qf [J] to book
    w, wa, dth, rfree, inertia, fdash, mr, rp, kr = ext
    q_bn[i] += qn
    q_bs[i] += qs
    q_f[i] += qf
    mi = m[i]
    etai = eta[i]
    qv = 0.0
    if DAMP:
        # the dashpot force acts over half of this step and half of the next (trapezoid, as
        # velocity Verlet integrates it): heat -F_d . dx / 2 now, the rest in move
        f0 += d0
        f1 += d1
        f2 += d2
        qv -= 0.5 * (d0 * dx[i, 0] + d1 * dx[i, 1])
        fdash[i, 0] = d0
        fdash[i, 1] = d1
        if DIM == 3:
            qv -= 0.5 * d2 * dx[i, 2]
            fdash[i, 2] = d2
    dq, we = translate_dofs(i, f0, f1, f2, v, a, dx, free, fload, mi, etai, g0, g1, g2, dt)
    qv += dq
    if ROT:
        ii = inertia[i]
        etar = etai * ii / mi
        for d in range(NR):
            if DIM == 2 or d == 2:
                tc = t2
            elif d == 0:
                tc = t0
            else:
                tc = t1
            wn, an, dq, dw = dof_step(rfree[i, d], w[i, d], wa[i, d], tc, ii, etar, dt,
                                      dth[i, d])
            w[i, d] = wn
            wa[i, d] = an
            qv += dq
            we += dw
    q_visc[i] += qv
    w_ext[i] += we


def energy_body(i, x, props, nbr, cstate, fs, hertz, e_el, mr, rp, kr):
    # half of each contact's elastic energy (the other half is booked by j's row)
    e = 0.0
    for k in range(nbr.shape[1]):
        j = nbr[i, k]
        if j < 0:
            break
        ex = 0.0
        s2 = 0.0
        kf = row_stiffness(kr, i, k)
        if DIM == 3:
            ex = x[j, 2] - x[i, 2]
            s2 = fs[i, k, 2]
        e += contact_energy(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], ex,
                            fs[i, k, 0], fs[i, k, 1], s2,
                            props[i, 0], props[j, 0], props[i, 1], props[j, 1],
                            props[i, 2], props[j, 2], cstate[i, k], hertz, kf)
        if ROT:
            rs = series(props[i, 0], props[j, 0])
            krl = min(rp[i, 1], rp[j, 1]) * (series(props[i, 2], props[j, 2]) * kf) * rs * rs
            m2 = 0.0
            for d in range(NR):
                m2 += mr[i, k, d] * mr[i, k, d]
            if krl > 0.0:
                e += 0.5 * m2 / krl
    e_el[i] = 0.5 * e



# ------------------------------------------------ each contact once (CPU)
# The force pass above evaluates every contact twice, once from each row. These bodies
# evaluate it once, from the row of its owner i < j (the tail of i's sorted row, from
# ``ostart[i]``), and post what j receives into ``buf``. The elements are cut into slabs of
# consecutive indices, one per thread of the pool, run in parallel; ``buf`` has a row per
# element and a spill row per contact that crosses a slab boundary:
# * a partner in the owner's slab (``j < hi``) gets the post added to its own row: no other
#   slab writes there;
# * a partner in a later slab gets it in the contact's spill row: the row's crossing
#   contacts are ``c = cstart[i]`` onwards, contact ``c`` posts into row ``n + spill[c]``,
#   and the spill rows are grouped by partner, so that ``finish_body`` adds element j's as
#   one run, ``n + inc_start[j]`` to ``n + inc_start[j + 1]`` (``neighbors.cross_tables``).
# A post holds the force (columns 0-2), the half heats q_f, q_bn, q_bs (3-5), and with the
# options the dashpot force (6-8) and the torque (9-11). ``finish_body`` then sums them in
# a fixed order, empties the rows and ends the step exactly as ``force_body`` does
# (``finish_dofs``). One buffer whatever the number of threads (48 B per element plus ~4 B
# of spill rows at two slabs, docs/performance.md).
# Only the owner's slot of a contact is stepped: its state code is copied to the partner's
# slot (``mirror``) when it changes, its shear spring and rolling moment by ``mirror_body``
# when the partner slots are wanted (``geodem.backends.numba_backend``).
def owner_body(i, hi, x, dx, props, m, nbr, ostart, mirror, cstate, fs, brate, buf,
               spill, c, dt, code_t, code_s, hertz, dth, mr, rp, kr):
    n = x.shape[0]
    xi0, xi1, xi2, di0, di1, di2 = own_position(i, x, dx)
    pi = own_params(i, props)
    ri, kni, ksi = pi[0], pi[1], pi[2]
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    qn = 0.0
    qs = 0.0
    qf = 0.0
    d0 = 0.0
    d1 = 0.0
    d2 = 0.0
    t0 = 0.0
    t1 = 0.0
    t2 = 0.0
    for k in range(ostart[i], nbr.shape[1]):
        j = nbr[i, k]
        if j < 0:
            break
        cs = cstate[i, k]
        kf = row_stiffness(kr, i, k)
        (fn, nx, ny, nz, sx, sy, sz, csn, eqn, eqs, eqf, rx, ry, ez, rj) = entry_contact(
            i, k, j, x, dx, xi0, xi1, xi2, di0, di1, di2, props, pi, fs, brate, kf, cs, dth,
            code_t, code_s, hertz)
        if csn != cs:
            cstate[i, k] = csn
            cstate[j, mirror[i, k]] = csn
        a0 = fn * nx + sx
        a1 = fn * ny + sy
        a2 = 0.0
        f0 += a0
        f1 += a1
        if DIM == 3:
            a2 = fn * nz + sz
            f2 += a2
        qn += eqn
        qs += eqs
        fd = 0.0
        if DAMP:
            fd = dashpot(i, j, fn, csn, nx, ny, nz, rx, ry, ez, kni, kf, props, m, dt)
            d0 += fd * nx
            d1 += fd * ny
            if DIM == 3:
                d2 += fd * nz
        u0 = 0.0
        u1 = 0.0
        u2 = 0.0
        if ROT:
            # j receives -Fs at -R_j n: torque R_j n x Fs, like i's with R_j; moment -M
            mx, my, mz, eqr = roll(i, j, k, fn, csn, nx, ny, nz, ri, rj, ksi, kf, props,
                                   brate, dth, mr, rp)
            cz = nx * sy - ny * sx
            if DIM == 3:
                cx = ny * sz - nz * sy
                cy = nz * sx - nx * sz
                t0 += ri * cx + mx
                t1 += ri * cy + my
                u0 = rj * cx - mx
                u1 = rj * cy - my
            t2 += ri * cz + mz
            u2 = rj * cz - mz
            eqf += eqr
        qf += eqf
        # the post's row: j's own row in the owner's slab, else the contact's spill row
        r = j
        if j >= hi:
            r = n + spill[c]
            c += 1
        buf[r, 0] -= a0
        buf[r, 1] -= a1
        if DIM == 3:
            buf[r, 2] -= a2
        if eqn != 0.0 or eqs != 0.0:  # breaks are rare: skip the scatter otherwise
            buf[r, 4] += 0.5 * eqn
            buf[r, 5] += 0.5 * eqs
        if DAMP and fd != 0.0:
            buf[r, 6] -= fd * nx
            buf[r, 7] -= fd * ny
            if DIM == 3:
                buf[r, 8] -= fd * nz
        if ROT:
            if DIM == 3:
                buf[r, 9] += u0
                buf[r, 10] += u1
            buf[r, 11] += u2
        buf[r, 3] += 0.5 * eqf
    buf[i, 0] += f0
    buf[i, 1] += f1
    buf[i, 2] += f2
    buf[i, 3] += 0.5 * qf
    buf[i, 4] += 0.5 * qn
    buf[i, 5] += 0.5 * qs
    if DAMP:
        buf[i, 6] += d0
        buf[i, 7] += d1
        buf[i, 8] += d2
    if ROT:
        buf[i, 9] += t0
        buf[i, 10] += t1
        buf[i, 11] += t2


def take_post(buf, r, f0, f1, f2, qf, qn, qs, d0, d1, d2, t0, t1, t2):
    # add row r of the posts' buffer to the sums and empty it
    f0 += buf[r, 0]
    f1 += buf[r, 1]
    f2 += buf[r, 2]
    qf += buf[r, 3]
    qn += buf[r, 4]
    qs += buf[r, 5]
    if DAMP:
        d0 += buf[r, 6]
        d1 += buf[r, 7]
        d2 += buf[r, 8]
    if ROT:
        t0 += buf[r, 9]
        t1 += buf[r, 10]
        t2 += buf[r, 11]
    for c in range(buf.shape[1]):
        buf[r, c] = 0.0
    return f0, f1, f2, qf, qn, qs, d0, d1, d2, t0, t1, t2


def finish_body(i, v, a, dx, free, fload, m, eta, buf, inc_start,
                q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, ext):
    # the element's spill rows (the posts from earlier slabs, in owner order), then its own
    # row (its slab's posts and its own contacts), each emptied for the next step. With up
    # to two slabs this is, bit for bit, the order of the one-buffer-per-thread sums before
    # (the earlier slab's sum first)
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    qf = 0.0
    qn = 0.0
    qs = 0.0
    d0 = 0.0
    d1 = 0.0
    d2 = 0.0
    t0 = 0.0
    t1 = 0.0
    t2 = 0.0
    n = v.shape[0]
    for r in range(n + inc_start[i], n + inc_start[i + 1]):
        f0, f1, f2, qf, qn, qs, d0, d1, d2, t0, t1, t2 = take_post(
            buf, r, f0, f1, f2, qf, qn, qs, d0, d1, d2, t0, t1, t2)
    f0, f1, f2, qf, qn, qs, d0, d1, d2, t0, t1, t2 = take_post(
        buf, i, f0, f1, f2, qf, qn, qs, d0, d1, d2, t0, t1, t2)
    finish_dofs(i, f0, f1, f2, d0, d1, d2, t0, t1, t2, qn, qs, qf,
                v, a, dx, free, fload, m, eta, q_visc, q_bn, q_bs, q_f, w_ext,
                g0, g1, g2, dt, ext)


def mirror_body(i, nbr, ostart, mirror, cstate, fs, mr):
    # the partner's slot of each contact i owns gets its state: same code, opposite spring
    # and rolling moment
    for k in range(ostart[i], nbr.shape[1]):
        j = nbr[i, k]
        if j < 0:
            break
        c = mirror[i, k]
        # guarded: tables older than the rows never write into a wrong slot
        if c >= 0 and nbr[j, c] == i:
            cstate[j, c] = cstate[i, k]
            for d in range(DIM):
                fs[j, c, d] = -fs[i, k, d]
            if ROT:
                for d in range(NR):
                    mr[j, c, d] = -mr[i, k, d]


def prefetch_partners(i, hi, x, dx, props, nbr, ostart, buf, spill, c):
    # ask for the cache lines of the partners of owner i a few elements ahead: in a model
    # larger than the caches the partners' rows are the pass's scattered reads, and waiting
    # for them cost ~20 % of the pass at 1e6 elements (docs/performance.md); and for the
    # row of buf each post goes to (owner_body); a hint only
    n = x.shape[0]
    for k in range(ostart[i], nbr.shape[1]):
        j = nbr[i, k]
        if j < 0:
            break
        prefetch_line(x, j, 0)
        prefetch_line(dx, j, 0)
        prefetch_line(props, j, 0)
        if j < hi:
            prefetch_line(buf, j, 0)
        else:
            prefetch_line(buf, n + spill[c], 0)
            c += 1


def prefetch_rows(i, nbr, cstate, brate, fs):
    # the owner's own rows (neighbours, states, bond rates, shear springs: 9 cache lines in
    # 3-D at width 16) are read in order, but the processor's own prefetcher left the pass
    # waiting on them at 1e5-1e6 elements (x1.09-1.12 with this, docs/performance.md)
    prefetch_line(nbr, i, 0)
    prefetch_line(cstate, i, 0)
    prefetch_line(brate, i, 0)
    for off in range(0, fs.strides[0], 64):
        prefetch_line(fs, i, off)


# ------------------------------------------------------------------ CPU loops (numba prange)
def cpu_move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
             w, wa, dth, rfree, inertia, fdash):
    for i in prange(x.shape[0]):
        move_body(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                  w, wa, dth, rfree, inertia, fdash)


def cpu_force(x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
              brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s, hertz,
              w, wa, dth, rfree, inertia, fdash, mr, rp, kr):
    for i in prange(x.shape[0]):
        force_body(i, x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                   fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                   code_s, hertz, (w, wa, dth, rfree, inertia, fdash, mr, rp, kr))


def cpu_energy(x, props, nbr, cstate, fs, hertz, e_el, mr, rp, kr):
    for i in prange(x.shape[0]):
        energy_body(i, x, props, nbr, cstate, fs, hertz, e_el, mr, rp, kr)


# the same passes over a list of elements only (the others are asleep: geodem.fields.freeze)
def cpu_move_idx(idx, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                 w, wa, dth, rfree, inertia, fdash):
    for k in prange(idx.shape[0]):
        move_body(idx[k], x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                  w, wa, dth, rfree, inertia, fdash)


def cpu_force_idx(idx, x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                  brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s,
                  hertz, w, wa, dth, rfree, inertia, fdash, mr, rp, kr):
    for k in prange(idx.shape[0]):
        force_body(idx[k], x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                   fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                   code_s, hertz, (w, wa, dth, rfree, inertia, fdash, mr, rp, kr))


# each contact once: slabs of ``slab`` consecutive elements in parallel (owner_body). The
# slabs and every sum's order are fixed by the model, not by the threads' number or schedule.
# ``ahead`` > 0: prefetch the partners of element i + ahead (prefetch_partners) and the rows
# of element i + 4 ahead (prefetch_rows); 0: none.
def cpu_force_owner(x, dx, props, m, nbr, ostart, mirror, cstate, fs, brate, buf,
                    cstart, spill, nslab, dt, code_t, code_s, hertz, dth, mr, rp, kr, ahead):
    n = x.shape[0]
    for t in prange(nslab):
        hi = (t + 1) * n // nslab
        for i in range(t * n // nslab, hi):
            if ahead > 0 and i + ahead < hi:
                prefetch_partners(i + ahead, hi, x, dx, props, nbr, ostart, buf, spill,
                                  cstart[i + ahead])
            if ahead > 0 and i + 4 * ahead < hi:
                prefetch_rows(i + 4 * ahead, nbr, cstate, brate, fs)
            owner_body(i, hi, x, dx, props, m, nbr, ostart, mirror, cstate, fs, brate, buf,
                       spill, cstart[i], dt, code_t, code_s, hertz, dth, mr, rp, kr)


def cpu_finish(v, a, dx, free, fload, m, eta, buf, inc_start, q_visc, q_bn,
               q_bs, q_f, w_ext, g0, g1, g2, dt, w, wa, dth, rfree, inertia, fdash, mr, rp,
               kr):
    for i in prange(v.shape[0]):
        finish_body(i, v, a, dx, free, fload, m, eta, buf, inc_start,
                    q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt,
                    (w, wa, dth, rfree, inertia, fdash, mr, rp, kr))


def cpu_mirror(nbr, ostart, mirror, cstate, fs, mr):
    for i in prange(nbr.shape[0]):
        mirror_body(i, nbr, ostart, mirror, cstate, fs, mr)


# several whole steps in one call: the engine's stretch of steps between two events (a check,
# a coupled field, a callback), so that Python, numba's dispatch and the unboxing of the
# arrays are paid once per stretch instead of three times per step (1.35x at 200 elements,
# 1.11x at 1,500, 1.06x at 1e4: docs/performance.md). The step k of the stretch (0-based)
# is step step0 + 1 + k; its broken-bond codes are code_t0 + 2k, code_s0 + 2k
# (geodem.core.state.broken_code grows by 2 per step).
def cpu_steps(nsteps, code_t0, code_s0, x, v, a, dx, free, fload, props, m, eta, nbr, ostart,
              mirror, cstate, fs, brate, buf, cstart, spill, inc_start, nslab, q_visc,
              q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, hertz, ahead, w, wa, dth, rfree, inertia,
              fdash, mr, rp, kr):
    for k in range(nsteps):
        move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt, w, wa, dth, rfree, inertia,
             fdash)
        force_owner(x, dx, props, m, nbr, ostart, mirror, cstate, fs, brate, buf,
                    cstart, spill, nslab, dt, code_t0 + 2 * k, code_s0 + 2 * k, hertz, dth, mr, rp,
                    kr, ahead)
        finish(v, a, dx, free, fload, m, eta, buf, inc_start, q_visc, q_bn,
               q_bs, q_f, w_ext, g0, g1, g2, dt, w, wa, dth, rfree, inertia, fdash, mr, rp, kr)
