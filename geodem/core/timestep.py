"""Time step and damping helpers (PHYSICS.md section 3).

* element period ``T_i = 2 pi sqrt(m_i / (kn_i/2))``: one element bonded to a fixed wall, bond
  stiffness ``kn/2`` (MatDEM's definition); default ``dt = 0.02 min_i T_i``;
* stability: velocity Verlet is stable for ``dt < 2/omega_max``. ``omega_max_bound`` gives a
  Gershgorin bound over the actual rows, ``omega_max^2 <= max_i sum_j K_ij (1/m_i +
  1/sqrt(m_i m_j))`` with ``K_ij = max(Kn, Ks)`` of each contact, so ``dt < 2/omega_bound`` is
  guaranteed stable for the linear law;
* damping: critical ``eta_c = 2 sqrt(k m)``, standard (quasi-static) ``eta = eta_c / N`` with ``N``
  elements across the model in the loading direction; the standard balance runs ``50 N`` steps.
"""
from __future__ import annotations

import math

import numpy as np

DEFAULT_FRACTION = 0.02


def element_periods(state) -> np.ndarray:
    """``2 pi sqrt(2 m / kn)`` per element [s]; ``inf`` where ``kn == 0``."""
    with np.errstate(divide="ignore"):
        return 2.0 * np.pi * np.sqrt(np.where(state.kn > 0, 2.0 * state.m / state.kn, np.inf))


def default_dt(state, fraction: float = DEFAULT_FRACTION) -> float:
    """``fraction`` of the smallest element period (free elements; all if none is free) [s]."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"dt fraction must be in (0, 1], got {fraction}")
    per = element_periods(state)
    movable = (state.free != 0).any(axis=1)
    if movable.any():
        per = per[movable]
    t = float(per.min()) if per.size else math.inf
    if not math.isfinite(t):
        raise ValueError("no element has a positive normal stiffness kn: cannot choose a time step")
    return fraction * t


def omega_max_bound(state) -> float:
    """Gershgorin upper bound of the highest angular frequency of the current rows [rad/s]."""
    from geodem.core.law import series_array

    valid = state.nbr >= 0
    j = np.where(valid, state.nbr, 0)
    k = np.maximum(series_array(state.kn[:, None], state.kn[j]),
                   series_array(state.ks[:, None], state.ks[j]))
    mi = state.m[:, None]
    row = np.where(valid, k * (1.0 / mi + 1.0 / np.sqrt(mi * state.m[j])), 0.0).sum(axis=1)
    movable = (state.free != 0).any(axis=1)
    w2 = float(row[movable].max()) if movable.any() and row.size else 0.0
    return math.sqrt(w2)


def contact_omega_bound(state) -> float:
    """Highest angular frequency one new contact could give a movable element [rad/s]:
    ``max_i K_i (1/m_i + 1/sqrt(m_i m_min))`` under the square root, with ``K_i = max(Kn, Ks)``
    of ``i`` against the stiffest element (the row bound's term for a single contact, taken
    over every partner the model holds)."""
    from geodem.core.law import series_array

    movable = (state.free != 0).any(axis=1)
    if not movable.any():
        return 0.0
    kn, ks, m = state.kn[movable], state.ks[movable], state.m[movable]
    k = np.maximum(series_array(kn, state.kn.max()), series_array(ks, state.ks.max()))
    return math.sqrt(float((k * (1.0 / m + 1.0 / np.sqrt(m * state.m.min()))).max()))


def stable_dt_bound(state) -> float:
    """``2 / omega_max_bound``: any ``dt`` below it is stable for the linear law [s]."""
    w = omega_max_bound(state)
    return math.inf if w == 0.0 else 2.0 / w


def check_dt(state, dt: float) -> float:
    """Raise ValueError when ``dt`` is not positive or above the stability bound; returns the
    bound [s]."""
    if not (dt > 0.0 and math.isfinite(dt)):
        raise ValueError(f"time step dt must be a positive finite number [s], got {dt}")
    lim = stable_dt_bound(state)
    what = "Gershgorin bound over the current contacts"
    if not math.isfinite(lim):
        # no contacts yet: the first one must still be resolved
        w = contact_omega_bound(state)
        lim = math.inf if w == 0.0 else 2.0 / w
        what = "no contacts yet: the bound for the first contact of any element"
    if dt >= lim:
        raise ValueError(
            f"time step dt = {dt:.4g} s is above the stability limit 2/omega_max = {lim:.4g} s "
            f"({what}); allowed: 0 < dt < {lim:.4g} s, "
            f"default {DEFAULT_FRACTION} x the smallest element period = "
            f"{default_dt(state):.4g} s")
    return lim


def critical_damping(m, k):
    """Critical damping ``2 sqrt(k m)`` of a mass ``m`` [kg] on a spring ``k`` [N/m] -> [kg/s]."""
    return 2.0 * np.sqrt(np.asarray(k, float) * np.asarray(m, float))


def element_critical_damping(state) -> np.ndarray:
    """Per-element critical damping on the wall-bond stiffness ``kn/2`` [kg/s]."""
    return critical_damping(state.m, 0.5 * state.kn)


def standard_damping(state, n_across: float) -> np.ndarray:
    """MatDEM's standard (optimal) damping ``eta_c / N`` for quasi-static stages [kg/s]."""
    if n_across < 1:
        raise ValueError(f"n_across (elements across the model) must be >= 1, got {n_across}")
    return element_critical_damping(state) / float(n_across)


def standard_balance_steps(n_across: float) -> int:
    """Steps of MatDEM's standard balance, ``50 N``."""
    return int(round(50 * n_across))
