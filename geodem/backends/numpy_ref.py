"""Readable reference engine in MatDEM's whole-matrix style (NumPy, op by op).

Every neighbour quantity is an ``(N, W)`` matrix gathered through ``nbr``; the contact law of
``geodem.core.law`` is restated with masks instead of branches. It is slow by design (it moves
tens of kilobytes per element-step) and exists so the compiled kernels have something plain to be
checked against: the tests hold the backends to 1e-12 and identical bond decisions.
"""
from __future__ import annotations

import numpy as np

from geodem.backends import register
from geodem.backends.numba_backend import HostBackend
from geodem.core.law import series_array
from geodem.core.state import BONDED


def _spring(f2, k):
    return np.where(k > 0.0, 0.5 * f2 / np.where(k > 0.0, k, 1.0), 0.0)


def _stiffness_factor(s):
    """The rows' contact stiffness factor (``krate``; 1 without it)."""
    return s.krate if s.row_stiffness else 1.0


def _colsum(mat):
    """Sum over the neighbour columns in row order (the order the kernels use)."""
    out = np.zeros(mat.shape[0])
    for k in range(mat.shape[1]):
        out = out + mat[:, k]
    return out


@register("numpy")
class NumpyBackend(HostBackend):
    def move(self, dt):
        s = self.s
        fr = s.free != 0.0
        ddx = np.where(fr, dt * s.v + 0.5 * dt * dt * s.a, dt * s.v)
        s.q_visc += (np.where(fr, 0.5 * s.eta[:, None] * s.v * ddx, 0.0)).sum(axis=1)
        s.w_ext += np.where(fr, s.fload * ddx, -(0.5 * s.m[:, None] * s.a * ddx)).sum(axis=1)
        s.dx[:] = ddx
        s.x += ddx
        if s.contact_damping:  # second half of the last dashpot force's heat
            s.q_visc -= 0.5 * (s.fdash * ddx).sum(axis=1)
        if s.rotation:
            rf = s.rfree != 0.0
            ii = s.inertia[:, None]
            etar = (s.eta * s.inertia / s.m)[:, None]
            ddt = np.where(rf, dt * s.w + 0.5 * dt * dt * s.wa, dt * s.w)
            s.q_visc += np.where(rf, 0.5 * etar * s.w * ddt, 0.0).sum(axis=1)
            s.w_ext += np.where(rf, 0.0, -(0.5 * ii * s.wa * ddt)).sum(axis=1)
            s.dth[:] = ddt

    def _geometry(self):
        s = self.s
        valid = s.nbr >= 0
        j = np.where(valid, s.nbr, np.arange(s.n)[:, None])
        d = s.x[j] - s.x[:, None, :]
        dist2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
        if s.dim == 3:
            dist2 = dist2 + d[..., 2] * d[..., 2]
        dist = np.where(valid, np.sqrt(dist2), 1.0)
        return valid, j, d, dist

    def force(self, dt, code_t, code_s):
        s = self.s
        valid, j, d, dist = self._geometry()
        inv = 1.0 / dist
        n = d * inv[..., None]
        rel = s.dx[j] - s.dx[:, None, :]
        if s.rotation:
            # contact-point displacement: rel - (R_i dth_i + R_j dth_j) x n
            ri, rj = s.r[:, None], s.r[j]
            if s.dim == 2:
                cz = ri * s.dth[:, 0][:, None] + rj * s.dth[j, 0]
                rel[..., 0] = rel[..., 0] + cz * n[..., 1]
                rel[..., 1] = rel[..., 1] - cz * n[..., 0]
            else:
                c = ri[..., None] * s.dth[:, None, :] + rj[..., None] * s.dth[j]
                rel = rel - np.cross(c, n)
        xn = dist - (s.r[:, None] + s.r[j])
        kf = _stiffness_factor(s)
        kn = series_array(s.kn[:, None], s.kn[j]) * kf
        ks = series_array(s.ks[:, None], s.ks[j]) * kf
        mu = np.minimum(s.mu[:, None], s.mu[j])
        rate = s.brate.astype(np.float64)

        hks = np.where(ks > 0.0, 0.5 / np.where(ks > 0.0, ks, 1.0), 0.0)  # 1/(2 Ks)
        sh = s.fs
        p = (n * sh).sum(-1)
        rot = sh - p[..., None] * n
        rot2 = (rot * rot).sum(-1)
        qf = p * p * hks
        pr = (n * rel).sum(-1)
        u = rel - pr[..., None] * n
        trial = rot + ks[..., None] * u
        tr2 = (trial * trial).sum(-1)
        wt = (trial * u).sum(-1)

        bonded = valid & (s.cstate == BONDED)
        fn_b = kn * xn
        bf = rate * np.minimum(s.kn[:, None] * s.xb[:, None], s.kn[j] * s.xb[j])
        tens = bonded & (fn_b >= bf)
        fsmax = rate * np.minimum(s.fs0[:, None], s.fs0[j]) - mu * fn_b
        shr = bonded & ~tens & ((fsmax < 0.0) | (tr2 > fsmax * fsmax))
        shr_t = shr & (fn_b >= 0.0)
        shr_c = shr & (fn_b < 0.0)
        intact = bonded & ~tens & ~shr

        unb = valid & ~bonded
        apart = unb & (xn >= 0.0)
        comp = unb & (xn < 0.0)
        if s.hertz:
            e_i = s.kn[:, None] / (np.pi * s.r[:, None])
            e_j = s.kn[j] / (np.pi * s.r[j])
            ov = np.where(comp, -xn, 0.0)
            fn_u = -(4.0 / 3.0) * series_array(e_i, e_j) * np.sqrt(series_array(s.r[:, None], s.r[j])) \
                * ov * np.sqrt(ov) * kf
        else:
            fn_u = kn * xn
        lim_u = -mu * fn_u
        slide = comp & (tr2 > lim_u * lim_u)

        safe_tr = np.where(tr2 > 0.0, np.sqrt(np.where(tr2 > 0.0, tr2, 1.0)), 1.0)
        lim_b = -mu * fn_b
        scale = np.where(shr_c, lim_b / safe_tr, 1.0)
        scale = np.where(slide, np.where(tr2 > 0.0, lim_u / safe_tr, 0.0), scale)
        scale = np.where(tens | shr_t | apart | ~valid, 0.0, scale)
        new = trial * scale[..., None]

        fn = np.where(intact | shr_c, fn_b, 0.0) + np.where(comp, fn_u, 0.0)
        released = _spring(fn_b * fn_b, kn) + tr2 * hks - 0.5 * (fn_b * pr + wt)
        qn = np.where(tens, released, 0.0)
        qs = np.where(shr_t, released, 0.0)
        qs = qs + np.where(shr_c, (tr2 - lim_b * lim_b) * hks - 0.5 * (1.0 - scale) * wt, 0.0)
        if s.hertz:  # broken in compression: the normal energy changes to Hertz's (law.contact)
            ovc = np.where(shr_c, -xn, 0.0)
            fhc = (4.0 / 3.0) * series_array(e_i, e_j) \
                * np.sqrt(series_array(s.r[:, None], s.r[j])) * ovc * np.sqrt(ovc) * kf
            qs = qs + np.where(shr_c, 0.5 * kn * xn * xn - 0.4 * fhc * ovc, 0.0)
        qf = qf + np.where(apart, rot2 * hks, 0.0)
        qf = qf + np.where(slide, ((rot + new) * (trial - new)).sum(-1) * hks, 0.0)
        qf = np.where(valid, qf, 0.0)

        if s.rotation:
            torque, qr = self._rolling(valid, j, n, fn, new, intact, bf, kf)
            qf = qf + qr
        s.fs[:] = np.where(valid[..., None], new, s.fs)
        s.cstate[:] = np.where(tens, code_t, np.where(shr, code_s, s.cstate))
        fc = np.stack([_colsum(np.where(valid, fn * n[..., c] + new[..., c], 0.0))
                       for c in range(s.dim)], axis=1)
        if s.contact_damping:
            fd = self._dashpot(valid, j, n, rel, fn, kn, s.cstate, dt)
            fdn = np.stack([_colsum(fd * n[..., c]) for c in range(s.dim)], axis=1)
            fc = fc + fdn
            s.q_visc -= 0.5 * (fdn * s.dx).sum(axis=1)
            s.fdash[:] = fdn
        s.q_break_n += 0.5 * _colsum(qn)
        s.q_break_s += 0.5 * _colsum(qs)
        s.q_fric += 0.5 * _colsum(qf)

        fr = s.free != 0.0
        m = s.m[:, None]
        eta = s.eta[:, None]
        f = fc + m * s.gravity[None, :s.dim] + s.fload
        vn = (s.v + 0.5 * dt * s.a + 0.5 * dt * f / m) / (1.0 + 0.5 * dt * eta / m)
        s.q_visc += np.where(fr, 0.5 * eta * vn * s.dx, 0.0).sum(axis=1)
        s.w_ext -= np.where(fr, 0.0, 0.5 * fc * s.dx).sum(axis=1)
        s.a[:] = np.where(fr, (f - eta * vn) / m, fc / m)
        s.v[:] = np.where(fr, vn, s.v)
        if s.rotation:
            rf = s.rfree != 0.0
            ii = s.inertia[:, None]
            etar = (s.eta * s.inertia / s.m)[:, None]
            wn = (s.w + 0.5 * dt * s.wa + 0.5 * dt * torque / ii) / (1.0 + 0.5 * dt * etar / ii)
            s.q_visc += np.where(rf, 0.5 * etar * wn * s.dth, 0.0).sum(axis=1)
            s.w_ext -= np.where(rf, 0.0, 0.5 * torque * s.dth).sum(axis=1)
            s.wa[:] = np.where(rf, (torque - etar * wn) / ii, torque / ii)
            s.w[:] = np.where(rf, wn, s.w)

    def _dashpot(self, valid, j, n, rel, fn, kn, cstate_new, dt):
        """Normal dashpot force (tension +, (N, W)) of the contacts in compression
        (geodem.core.state.enable_contact_damping, whole-matrix form)."""
        s = self.s
        zeta = np.minimum(s.zeta_n[:, None], s.zeta_n[j])
        on = valid & (fn < 0.0) & (zeta > 0.0) & (dt > 0.0)
        mi, mj = s.m[:, None], s.m[j]
        c = 2.0 * zeta * np.sqrt(mi * mj / (mi + mj) * kn)
        pr = (n * rel).sum(-1)
        fd = c * pr / (dt if dt > 0.0 else 1.0)
        fd = np.where((cstate_new != BONDED) & (fd > -fn), -fn, fd)
        return np.where(on, fd, 0.0)

    def _rolling(self, valid, j, n, fn, shear, bonded, bf, kf):
        """Torques (N, nr) of the shear forces and the rolling moments, and the rolling heat
        (N, W); updates ``mr`` (geodem.core.law.rolling, whole-matrix form). ``bonded``: the
        contacts bonded after this step's law (they also hold ``bond_moment R* F_b``, ``bf`` =
        F_b). Rolling spring ``K_r = beta Ks R*^2``, ``beta`` the smaller rolling_stiffness,
        ``Ks`` with the contacts' stiffness factor ``kf``."""
        s = self.s
        ri = s.r[:, None]
        rs = series_array(ri, s.r[j])
        beta = np.minimum(s.rolling_stiffness[:, None], s.rolling_stiffness[j])
        kr = beta * (series_array(s.ks[:, None], s.ks[j]) * kf) * rs * rs
        lim = np.minimum(s.mu_r[:, None], s.mu_r[j]) * rs * np.maximum(-fn, 0.0)
        mb = np.minimum(s.bond_moment[:, None], s.bond_moment[j])
        lim = lim + np.where(bonded & (mb > 0.0), mb * rs * np.where(mb > 0.0, bf, 0.0), 0.0)
        hk = np.where(kr > 0.0, 0.5 / np.where(kr > 0.0, kr, 1.0), 0.0)
        t = s.dth[:, None, :] - s.dth[j]
        if s.dim == 2:
            mom = s.mr[..., 0]
            trial = mom - kr * t[..., 0]
            a2 = trial * trial
            slip = a2 > lim * lim
            nrm = np.sqrt(np.where(a2 > 0.0, a2, 1.0))
            new = trial * np.where(slip, np.where(lim > 0.0, lim / nrm, 0.0), 1.0)
            q = np.where(slip, (mom + new) * (trial - new) * hk, 0.0)
            new3 = new[..., None]
            arm = ri * (n[..., 0] * shear[..., 1] - n[..., 1] * shear[..., 0])
            tq = (arm + new)[..., None]
        else:
            mom = s.mr
            p = (n * mom).sum(-1)
            mom = mom - p[..., None] * n
            q = p * p * hk
            pt = (n * t).sum(-1)
            u = t - pt[..., None] * n
            trial = mom - kr[..., None] * u
            a2 = (trial * trial).sum(-1)
            nrm = np.sqrt(np.where(a2 > 0.0, a2, 1.0))
            slip = a2 > lim * lim
            scale = np.where(slip, np.where(lim > 0.0, lim / nrm, 0.0), 1.0)
            new3 = trial * scale[..., None]
            q = q + np.where(slip, ((mom + new3) * (trial - new3)).sum(-1) * hk, 0.0)
            tq = ri[..., None] * np.cross(n, shear) + new3
        s.mr[:] = np.where(valid[..., None], new3, s.mr)
        torque = np.stack([_colsum(np.where(valid, tq[..., c], 0.0)) for c in range(s.nrot)],
                          axis=1)
        return torque, np.where(valid, q, 0.0)

    def elastic_energy(self):
        s = self.s
        valid, j, d, dist = self._geometry()
        xn = dist - (s.r[:, None] + s.r[j])
        kf = _stiffness_factor(s)
        kn = series_array(s.kn[:, None], s.kn[j]) * kf
        ks = series_array(s.ks[:, None], s.ks[j]) * kf
        e = _spring((s.fs * s.fs).sum(-1), ks)
        bonded = s.cstate == BONDED
        comp = ~bonded & (xn < 0.0)
        if s.hertz:
            e_i = s.kn[:, None] / (np.pi * s.r[:, None])
            e_j = s.kn[j] / (np.pi * s.r[j])
            ov = np.where(comp, -xn, 0.0)
            fh = (4.0 / 3.0) * series_array(e_i, e_j) * np.sqrt(series_array(s.r[:, None], s.r[j])) \
                * ov * np.sqrt(ov) * kf
            en = np.where(bonded, 0.5 * kn * xn * xn, np.where(comp, 0.4 * fh * ov, 0.0))
        else:
            en = np.where(bonded | comp, 0.5 * kn * xn * xn, 0.0)
        if s.rotation:
            rs = series_array(s.r[:, None], s.r[j])
            beta = np.minimum(s.rolling_stiffness[:, None], s.rolling_stiffness[j])
            kr = beta * (series_array(s.ks[:, None], s.ks[j]) * kf) * rs * rs
            e = e + _spring((s.mr * s.mr).sum(-1), kr)
        self.e_el[:] = 0.5 * _colsum(np.where(valid, e + en, 0.0))
        return self.e_el
