"""TwoBalls (MatDEM's first example): two elements bonded in a row between two fixed walls.

``wall - ball - ball - wall`` along x, identical elements, bonds of stiffness ``K = kn/2``
(two half-springs in series). Both balls start displaced by the same ``amplitude``, which
excites only the symmetric mode: the middle bond stays unstretched and each ball is a damped
oscillator on one wall bond, ``m x'' + eta x' + K x = 0`` (PHYSICS.md section 3):

    T = 2 pi / sqrt(K/m - (eta/2m)^2),  amplitude ~ exp(-eta t / 2m),  eta_c = 2 sqrt(K m).
"""
from __future__ import annotations

import math

import numpy as np

from geodem.core.neighbors import rows_from_pairs
from geodem.core.state import new_state


def build(dim=2, d=1.0, rho=2650.0, kn=2.0e9, amplitude=0.01, damping_ratio=0.0, xb=None,
          fs0=1e12, mu=0.5):
    """Return the TwoBalls state. ``damping_ratio`` = eta / eta_c; ``amplitude`` in metres.

    ``xb`` (element breaking displacement) defaults to effectively unbreakable.
    """
    r = 0.5 * d
    m = rho * (4.0 / 3.0 * math.pi * r ** 3 if dim == 3 else math.pi * r * r * d)
    x = np.zeros((4, dim))
    x[:, 0] = np.arange(4) * d
    big = 1e6 * d if xb is None else xb
    st = new_state(x, r, m, kn=kn, ks=kn, xb=big, fs0=fs0, mu=mu, width=4)
    rows_from_pairs(st, np.array([0, 1, 2]), np.array([1, 2, 3]), bonded=True)
    st.free[[0, 3]] = 0.0
    st.groups = {"all": 0, "walls": 1, "balls": 2}
    st.group[[0, 3]] = 1
    st.group[[1, 2]] = 2
    st.x[[1, 2], 0] += amplitude
    K = 0.5 * kn
    st.eta[[1, 2]] = damping_ratio * 2.0 * math.sqrt(K * m)
    return st


def analytic(state):
    """Undamped period T0, damped period T and decay rate eta/2m of the symmetric mode."""
    m = state.m[1]
    K = 0.5 * state.kn[1]
    eta = state.eta[1]
    w0 = math.sqrt(K / m)
    gamma = eta / (2.0 * m)
    wd2 = w0 * w0 - gamma * gamma
    return {"T0": 2 * math.pi / w0, "T": 2 * math.pi / math.sqrt(wd2) if wd2 > 0 else math.inf,
            "decay_rate": gamma, "omega0": w0}


def analytic_curve(t, amp, omega0, gamma):
    """Free damped oscillator released from rest at ``amp``: displacement at times ``t``."""
    t = np.asarray(t, dtype=float)
    if gamma >= omega0:  # critical (or over-) damping: use the critical form at gamma == omega0
        if math.isclose(gamma, omega0, rel_tol=1e-9):
            return amp * (1.0 + omega0 * t) * np.exp(-omega0 * t)
        s = math.sqrt(gamma * gamma - omega0 * omega0)
        r1, r2 = -gamma + s, -gamma - s
        return amp * (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r2 - r1)
    wd = math.sqrt(omega0 * omega0 - gamma * gamma)
    return amp * np.exp(-gamma * t) * (np.cos(wd * t) + gamma / wd * np.sin(wd * t))


def measure(times, u):
    """Period (mean spacing of successive maxima) and log decay rate of a displacement history."""
    u = np.asarray(u)
    t = np.asarray(times)
    k = np.flatnonzero((u[1:-1] > u[:-2]) & (u[1:-1] >= u[2:])) + 1
    if k.size < 2:
        return {"T": math.nan, "decay_rate": math.nan, "peaks": k.size}
    # parabolic refinement of each peak
    tp, up = [], []
    h = t[1] - t[0]
    for i in k:
        a, b, c = u[i - 1], u[i], u[i + 1]
        den = a - 2 * b + c
        off = 0.5 * (a - c) / den if den != 0 else 0.0
        tp.append(t[i] + off * h)
        up.append(b - 0.25 * (a - c) * off)
    tp, up = np.array(tp), np.array(up)
    period = float(np.mean(np.diff(tp)))
    pos = up > 0
    rate = float(-np.polyfit(tp[pos], np.log(up[pos]), 1)[0]) if pos.sum() >= 2 else math.nan
    return {"T": period, "decay_rate": rate, "peaks": int(k.size)}
