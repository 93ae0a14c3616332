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
import types

from geodem.core import law


def _bodies(DIM, jit_device):
    """Build the per-element bodies for dimension ``DIM`` with the device-function decorator."""
    # the law's helpers are plain Python; rebind them to compiled versions for this target
    glb = dict(vars(law))
    for name in law.HELPERS:
        glb[name] = jit_device(getattr(law, name))

    def retarget(f):
        return jit_device(types.FunctionType(f.__code__, glb, f.__name__, f.__defaults__))

    contact = retarget(law.contact)
    contact_energy = retarget(law.contact_energy)

    def dof_free(v, a, f, m, eta, dt, ddx):
        # implicit trapezoidal damping; returns new v, new a, viscous heat share
        vn = (v + 0.5 * dt * a + 0.5 * dt * f / m) / (1.0 + 0.5 * dt * eta / m)
        return vn, (f - eta * vn) / m, 0.5 * eta * vn * ddx

    dof_free = jit_device(dof_free)

    def move_body(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt):
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
        q_visc[i] += qv
        w_ext[i] += we

    def force_body(i, x, v, a, dx, free, fload, props, m, eta,
                   nbr, cstate, fs, brate, q_visc, q_bn, q_bs, q_f, w_ext,
                   g0, g1, g2, dt, code_t, code_s, hertz):
        xi0 = x[i, 0]
        xi1 = x[i, 1]
        di0 = dx[i, 0]
        di1 = dx[i, 1]
        xi2 = 0.0
        di2 = 0.0
        if DIM == 3:
            xi2 = x[i, 2]
            di2 = dx[i, 2]
        # props columns: r, kn, ks, xb, fs0, mu (one cache line per element)
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
            cs = cstate[i, k]
            (fn, nx, ny, nz, sx, sy, sz, csn, eqn, eqs, eqf) = contact(
                x[j, 0] - xi0, x[j, 1] - xi1, ex,
                dx[j, 0] - di0, dx[j, 1] - di1, ez,
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
        q_bn[i] += 0.5 * qn
        q_bs[i] += 0.5 * qs
        q_f[i] += 0.5 * qf
        mi = m[i]
        etai = eta[i]
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
        q_visc[i] += qv
        w_ext[i] += we

    def energy_body(i, x, props, nbr, cstate, fs, hertz, e_el):
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
        e_el[i] = 0.5 * e

    return move_body, force_body, energy_body


@functools.lru_cache(maxsize=None)
def make_kernels(dim: int, target: str):
    """Compile the kernels for ``dim`` in {2, 3} and ``target`` in {cpu, cuda}: a namespace with
    ``move, force, energy`` over every element and ``move_idx, force_idx`` over the elements of
    an index array (the first argument).

    CPU kernels take ``n`` implicitly and loop with ``prange``; CUDA kernels are launched as
    ``kernel[blocks, threads](...)`` with one thread per element.
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    if target == "cpu":
        import numba
        from numba import prange

        dev = functools.partial(numba.njit, fastmath=True, error_model="numpy", forceinline=True,
                                cache=False)
        move_b, force_b, energy_b = _bodies(dim, lambda f: dev(f))
        move_b = dev(move_b)
        force_b = dev(force_b)
        energy_b = dev(energy_b)
        par = numba.njit(parallel=True, fastmath=True, error_model="numpy", cache=False)

        @par
        def move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt):
            for i in prange(x.shape[0]):
                move_b(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt)

        @par
        def force(x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                  brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s, hertz):
            for i in prange(x.shape[0]):
                force_b(i, x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz)

        @par
        def energy(x, props, nbr, cstate, fs, hertz, e_el):
            for i in prange(x.shape[0]):
                energy_b(i, x, props, nbr, cstate, fs, hertz, e_el)

        # the same passes over a list of elements only (the others are asleep: see
        # geodem.fields.freeze)
        @par
        def move_idx(idx, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt):
            for k in prange(idx.shape[0]):
                move_b(idx[k], x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt)

        @par
        def force_idx(idx, x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                      brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s,
                      hertz):
            for k in prange(idx.shape[0]):
                force_b(idx[k], x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz)

        return types.SimpleNamespace(move=move, force=force, energy=energy,
                                     move_idx=move_idx, force_idx=force_idx)

    if target == "cuda":
        # ``cuda`` must be a module global: the CUDA simulator swaps it in the kernels' globals
        global cuda
        from numba import cuda

        dev = lambda f: cuda.jit(device=True)(f)  # noqa: E731
        move_b, force_b, energy_b = _bodies(dim, dev)
        move_b, force_b, energy_b = dev(move_b), dev(force_b), dev(energy_b)

        @cuda.jit
        def move(x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt):
            i = cuda.grid(1)
            if i < x.shape[0]:
                move_b(i, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt)

        @cuda.jit
        def force(x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                  brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s, hertz):
            i = cuda.grid(1)
            if i < x.shape[0]:
                force_b(i, x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz)

        @cuda.jit
        def energy(x, props, nbr, cstate, fs, hertz, e_el):
            i = cuda.grid(1)
            if i < x.shape[0]:
                energy_b(i, x, props, nbr, cstate, fs, hertz, e_el)

        @cuda.jit
        def move_idx(idx, x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt):
            k = cuda.grid(1)
            if k < idx.shape[0]:
                move_b(idx[k], x, v, a, dx, free, fload, m, eta, q_visc, w_ext, dt)

        @cuda.jit
        def force_idx(idx, x, v, a, dx, free, fload, props, m, eta, nbr, cstate, fs,
                      brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t, code_s,
                      hertz):
            k = cuda.grid(1)
            if k < idx.shape[0]:
                force_b(idx[k], x, v, a, dx, free, fload, props, m, eta, nbr, cstate,
                        fs, brate, q_visc, q_bn, q_bs, q_f, w_ext, g0, g1, g2, dt, code_t,
                        code_s, hertz)

        return types.SimpleNamespace(move=move, force=force, energy=energy,
                                     move_idx=move_idx, force_idx=force_idx)
    raise ValueError(f"unknown kernel target {target!r}; allowed: cpu, cuda")
