"""Single-source element kernels: one loop body, compiled for the CPU (numba) and GPU (CUDA).

The time step is two passes over elements (velocity Verlet, PHYSICS.md section 3):

1. ``move``:  ``dx = dt v + dt^2 a / 2`` on free DOFs, ``dx = dt v`` on fixed/kinematic ones;
   ``x += dx``; books the first half of the viscous heat and of the external work.
2. ``force``: each element walks its own row (no scatter, no atomics), evaluates every contact
   with :func:`geodem.core.law.contact`, sums the force, and updates its velocity with the damping
   treated by the trapezoidal rule (implicit, unconditionally stable for the damping term):
   ``v' = (v + dt/2 a + dt/(2m) F) / (1 + eta dt/(2m))``, ``a' = (F - eta v')/m``.
   Fixed and kinematic DOFs keep their velocity and store ``a = F_contact/m`` (the reaction).

The bodies below are plain Python functions of scalars and arrays. ``make_kernels`` compiles them
with ``numba.njit`` + ``prange`` (target ``"cpu"``) or ``numba.cuda.jit`` (target ``"cuda"``; the
CUDA simulator runs the same code in CI without a GPU). ``DIM`` is a compile-time constant so the
2-D kernels carry no third component.
"""
from __future__ import annotations

import functools
import math
import types

from geodem.core import law


def _bodies(DIM, ROT, DAMP, jit_device):
    """Build the per-element bodies for dimension ``DIM`` with the device-function decorator.

    ``DAMP`` (compile-time): contacts in compression get the normal dashpot of
    ``geodem.core.state.enable_contact_damping`` (damping ratio in ``props`` column 7).

    ``ROT`` (compile-time): the elements also turn (``geodem.core.state.enable_rotation``); the
    rotation arrays ``w, wa, dth, rfree, inertia, mr`` are then read and written, otherwise
    they are placeholders the compiled code never touches.
    """
    # the law's helpers are plain Python; rebind them to compiled versions for this target
    glb = dict(vars(law))
    for name in law.HELPERS:
        glb[name] = jit_device(getattr(law, name))

    def retarget(f):
        return jit_device(types.FunctionType(f.__code__, glb, f.__name__, f.__defaults__))

    contact = retarget(law.contact)
    contact_energy = retarget(law.contact_energy)
    rolling = retarget(law.rolling)
    series = glb["series"]
    NR = 1 if DIM == 2 else 3  # rotational DOFs per element
    BONDED = law.BONDED

    def dof_free(v, a, f, m, eta, dt, ddx):
        # implicit trapezoidal damping; returns new v, new a, viscous heat share
        vn = (v + 0.5 * dt * a + 0.5 * dt * f / m) / (1.0 + 0.5 * dt * eta / m)
        return vn, (f - eta * vn) / m, 0.5 * eta * vn * ddx

    dof_free = jit_device(dof_free)

    def dof_step(free, v, a, fc, m, eta, dt, ddx):
        # one rotational degree of freedom after the force pass: a free one turns under the
        # torque fc (returns w, w', viscous heat, 0); a fixed or prescribed one keeps w and
        # stores the reaction fc/I, whose work -fc ddx/2 it returns. (The translational loop
        # spells the same out inline: see geodem.core.law.tangent on why.)
        if free != 0.0:
            vn, an, dq = dof_free(v, a, fc, m, eta, dt, ddx)
            return vn, an, dq, 0.0
        return v, fc / m, 0.0, -0.5 * fc * ddx

    dof_step = jit_device(dof_step)

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

    def force_body(i, x, v, a, dx, free, fload, props, m, eta,
                   nbr, cstate, fs, brate, q_visc, q_bn, q_bs, q_f, w_ext,
                   g0, g1, g2, dt, code_t, code_s, hertz, ext):
        # the options' arrays come as one tuple: seven more arguments of the inlined body made
        # the plain kernel 15-25 % slower (measured), one tuple costs nothing
        w, wa, dth, rfree, inertia, fdash, mr = ext
        xi0 = x[i, 0]
        xi1 = x[i, 1]
        di0 = dx[i, 0]
        di1 = dx[i, 1]
        xi2 = 0.0
        di2 = 0.0
        if DIM == 3:
            xi2 = x[i, 2]
            di2 = dx[i, 2]
        # props columns: r, kn, ks, xb, fs0, mu, mu_r (one cache line per element)
        ri = props[i, 0]
        kni = props[i, 1]
        ksi = props[i, 2]
        xbi = props[i, 3]
        fs0i = props[i, 4]
        mui = props[i, 5]
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
            ex = 0.0
            ez = 0.0
            s2 = 0.0
            if DIM == 3:
                ex = x[j, 2] - xi2
                ez = dx[j, 2] - di2
                s2 = fs[i, k, 2]
            bx = x[j, 0] - xi0
            by = x[j, 1] - xi1
            rx = dx[j, 0] - di0
            ry = dx[j, 1] - di1
            if ROT:
                # the law sees the contact point's relative displacement: the rotations
                # move it by -(R_i dth_i + R_j dth_j) x n (symmetric in i, j: j's row gets
                # exactly the opposite)
                inv = 1.0 / math.sqrt(bx * bx + by * by + ex * ex)
                cnx = bx * inv
                cny = by * inv
                cnz = ex * inv
                rj = props[j, 0]
                if DIM == 2:
                    cz = ri * dth[i, 0] + rj * dth[j, 0]
                    rx = rx + cz * cny
                    ry = ry - cz * cnx
                else:
                    cx = ri * dth[i, 0] + rj * dth[j, 0]
                    cy = ri * dth[i, 1] + rj * dth[j, 1]
                    cz = ri * dth[i, 2] + rj * dth[j, 2]
                    rx = rx - (cy * cnz - cz * cny)
                    ry = ry - (cz * cnx - cx * cnz)
                    ez = ez - (cx * cny - cy * cnx)
            cs = cstate[i, k]
            (fn, nx, ny, nz, sx, sy, sz, csn, eqn, eqs, eqf) = contact(
                bx, by, ex, rx, ry, ez,
                fs[i, k, 0], fs[i, k, 1], s2,
                ri, props[j, 0], kni, props[j, 1], ksi, props[j, 2], xbi, props[j, 3],
                fs0i, props[j, 4], mui, props[j, 5],
                brate[i, k], cs, code_t, code_s, hertz)
            fs[i, k, 0] = sx
            fs[i, k, 1] = sy
            if DIM == 3:
                fs[i, k, 2] = sz
            if csn != cs:
                cstate[i, k] = csn
            f0 += fn * nx + sx
            f1 += fn * ny + sy
            f2 += fn * nz + sz
            qn += eqn
            qs += eqs
            qf += eqf
            if DAMP:
                # normal dashpot c (v_j - v_i).n on a contact in compression; an unbonded
                # contact may resist separation but never pull
                zeta = min(props[i, 7], props[j, 7])
                if fn < 0.0 and zeta > 0.0 and dt > 0.0:
                    mj = m[j]
                    c = 2.0 * zeta * math.sqrt(m[i] * mj / (m[i] + mj) * series(kni, props[j, 1]))
                    # the step's mean relative velocity du/dt (the end-of-step velocities are
                    # not known yet): first-order accurate in dt
                    fd = c * (nx * rx + ny * ry + nz * ez) / dt
                    if csn != BONDED and fd > -fn:
                        fd = -fn
                    d0 += fd * nx
                    d1 += fd * ny
                    d2 += fd * nz
            if ROT:
                # the shear force acts at the contact point R_i n; rolling resistance on top
                rs = series(ri, rj)
                kr = series(ksi, props[j, 2]) * rs * rs
                lim = min(props[i, 6], props[j, 6]) * rs * max(-fn, 0.0)
                if DIM == 2:  # about z only
                    u0 = 0.0
                    u1 = 0.0
                    u2 = dth[i, 0] - dth[j, 0]
                    m0 = 0.0
                    m1 = 0.0
                    m2 = mr[i, k, 0]
                else:
                    u0 = dth[i, 0] - dth[j, 0]
                    u1 = dth[i, 1] - dth[j, 1]
                    u2 = dth[i, 2] - dth[j, 2]
                    m0 = mr[i, k, 0]
                    m1 = mr[i, k, 1]
                    m2 = mr[i, k, 2]
                (mx, my, mz, eqr) = rolling(nx, ny, nz, u0, u1, u2, m0, m1, m2, kr, lim)
                if DIM == 2:
                    mr[i, k, 0] = mz
                else:
                    mr[i, k, 0] = mx
                    mr[i, k, 1] = my
                    mr[i, k, 2] = mz
                    t0 += ri * (ny * sz - nz * sy) + mx
                    t1 += ri * (nz * sx - nx * sz) + my
                t2 += ri * (nx * sy - ny * sx) + mz
                qf += eqr
        q_bn[i] += 0.5 * qn
        q_bs[i] += 0.5 * qs
        q_f[i] += 0.5 * qf
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

    def energy_body(i, x, props, nbr, cstate, fs, hertz, e_el, mr):
        # half of each contact's elastic energy (the other half is booked by j's row)
        e = 0.0
        for k in range(nbr.shape[1]):
            j = nbr[i, k]
            if j < 0:
                break
            ex = 0.0
            s2 = 0.0
            if DIM == 3:
                ex = x[j, 2] - x[i, 2]
                s2 = fs[i, k, 2]
            e += contact_energy(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], ex,
                                fs[i, k, 0], fs[i, k, 1], s2,
                                props[i, 0], props[j, 0], props[i, 1], props[j, 1],
                                props[i, 2], props[j, 2], cstate[i, k], hertz)
            if ROT:
                rs = series(props[i, 0], props[j, 0])
                kr = series(props[i, 2], props[j, 2]) * rs * rs
                m2 = 0.0
                for d in range(NR):
                    m2 += mr[i, k, d] * mr[i, k, d]
                if kr > 0.0:
                    e += 0.5 * m2 / kr
        e_el[i] = 0.5 * e

    return move_body, force_body, energy_body


@functools.lru_cache(maxsize=None)
def make_kernels(dim: int, target: str, rotation: bool = False, damping: bool = False):
    """Compile the kernels for ``dim`` in {2, 3}, ``target`` in {cpu, cuda}, translation-only
    or rotating elements, without or with the contact dashpot: a namespace with ``move, force,
    energy`` over every element and ``move_idx, force_idx`` over the elements of an index array
    (the first argument).

    Argument order: ``move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt, *EXTRA_MOVE)``,
    ``force(x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs, brate, q_visc, q_bn,
    q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s, hertz, *EXTRA_FORCE)``,
    ``energy(x, props, nbr, cstate, fs, hertz, e_el, mr)`` with ``EXTRA_MOVE = (w, wa, dth,
    rfree, inertia, fdash)`` and ``EXTRA_FORCE = EXTRA_MOVE + (mr,)``: the arrays of the
    options (placeholders for an option that is off: :func:`placeholders`).

    CPU kernels take ``n`` implicitly and loop with ``prange``; CUDA kernels are launched as
    ``kernel[blocks, threads](...)`` with one thread per element.
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    rot = bool(rotation)
    damp = bool(damping)
    if target == "cpu":
        import numba
        from numba import prange

        dev = functools.partial(numba.njit, fastmath=True, error_model="numpy", forceinline=True,
                                cache=False)
        move_b, force_b, energy_b = _bodies(dim, rot, damp, lambda f: dev(f))
        move_b = dev(move_b)
        force_b = dev(force_b)
        energy_b = dev(energy_b)
        par = numba.njit(parallel=True, fastmath=True, error_model="numpy", cache=False)

        @par
        def move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                 w, wa, dth, rfree, inertia, fdash):
            for i in prange(x.shape[0]):
                move_b(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                       w, wa, dth, rfree, inertia, fdash)

        @par
        def force(x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                  brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s, hertz,
                  w, wa, dth, rfree, inertia, fdash, mr):
            for i in prange(x.shape[0]):
                force_b(i, x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz, (w, wa, dth, rfree, inertia, fdash, mr))

        @par
        def energy(x, props, nbr, cstate, fs, hertz, e_el, mr):
            for i in prange(x.shape[0]):
                energy_b(i, x, props, nbr, cstate, fs, hertz, e_el, mr)

        # the same passes over a list of elements only (the others are asleep: see
        # geodem.fields.freeze)
        @par
        def move_idx(idx, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                     w, wa, dth, rfree, inertia, fdash):
            for k in prange(idx.shape[0]):
                move_b(idx[k], x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                       w, wa, dth, rfree, inertia, fdash)

        @par
        def force_idx(idx, x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                      brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s,
                      hertz, w, wa, dth, rfree, inertia, fdash, mr):
            for k in prange(idx.shape[0]):
                force_b(idx[k], x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz, (w, wa, dth, rfree, inertia, fdash, mr))

        return types.SimpleNamespace(move=move, force=force, energy=energy,
                                     move_idx=move_idx, force_idx=force_idx)

    if target == "cuda":
        # ``cuda`` must be a module global: the CUDA simulator swaps it in the kernels' globals
        global cuda
        from numba import cuda

        dev = lambda f: cuda.jit(device=True)(f)  # noqa: E731
        move_b, force_b, energy_b = _bodies(dim, rot, damp, dev)
        move_b, force_b, energy_b = dev(move_b), dev(force_b), dev(energy_b)

        @cuda.jit
        def move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                 w, wa, dth, rfree, inertia, fdash):
            i = cuda.grid(1)
            if i < x.shape[0]:
                move_b(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                       w, wa, dth, rfree, inertia, fdash)

        @cuda.jit
        def force(x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                  brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s, hertz,
                  w, wa, dth, rfree, inertia, fdash, mr):
            i = cuda.grid(1)
            if i < x.shape[0]:
                force_b(i, x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz, (w, wa, dth, rfree, inertia, fdash, mr))

        @cuda.jit
        def energy(x, props, nbr, cstate, fs, hertz, e_el, mr):
            i = cuda.grid(1)
            if i < x.shape[0]:
                energy_b(i, x, props, nbr, cstate, fs, hertz, e_el, mr)

        @cuda.jit
        def move_idx(idx, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                     w, wa, dth, rfree, inertia, fdash):
            k = cuda.grid(1)
            if k < idx.shape[0]:
                move_b(idx[k], x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt,
                       w, wa, dth, rfree, inertia, fdash)

        @cuda.jit
        def force_idx(idx, x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                      brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s,
                      hertz, w, wa, dth, rfree, inertia, fdash, mr):
            k = cuda.grid(1)
            if k < idx.shape[0]:
                force_b(idx[k], x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz, (w, wa, dth, rfree, inertia, fdash, mr))

        return types.SimpleNamespace(move=move, force=force, energy=energy,
                                     move_idx=move_idx, force_idx=force_idx)
    raise ValueError(f"unknown kernel target {target!r}; allowed: cpu, cuda")


EXTRA_MOVE = ("w", "wa", "dth", "rfree", "inertia", "fdash")  # the options' arrays
EXTRA_FORCE = EXTRA_MOVE + ("mr",)


def placeholders(xp=None):
    """Stand-ins for the arrays of options that are off (never read): one tiny allocation per
    backend, not per step. Returns a dict name -> array."""
    import numpy as np

    xp = np if xp is None else xp
    z2 = xp.zeros((1, 1))
    return {"w": z2, "wa": z2, "dth": z2, "rfree": z2, "inertia": xp.zeros(1), "fdash": z2,
            "mr": xp.zeros((1, 1, 1))}
