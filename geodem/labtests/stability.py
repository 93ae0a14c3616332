"""Where the explicit integration fails: the measured critical time step against theory.

Velocity Verlet (no damping) on a linear spring network is stable for ``dt < 2 / omega_max``,
``omega_max^2`` the largest eigenvalue of ``M^-1/2 K M^-1/2`` (K the stiffness matrix of the
free degrees of freedom). geodem refuses any ``dt`` above the cheaper *Gershgorin* bound
``omega_max^2 <= max_i sum_j K_ij (1/m_i + 1/sqrt(m_i m_j))`` (:mod:`geodem.core.timestep`),
which is never above the exact limit. This module

* assembles K of the linear contact law (bond/contact ``i-j`` with unit normal ``n``: block
  ``Kn n n^T + Ks (I - n n^T)``, ``Kn, Ks`` the series stiffnesses of the two elements' springs)
  and computes ``omega_max`` (:func:`omega_max_exact`, scipy ``eigsh``);
* measures the critical step of a model by bisection on ``dt``: every trial starts from the same
  small random velocities and runs ``steps`` undamped steps; the motion diverges when the
  largest speed grows 1000-fold (:func:`measure_critical_dt`, ``measured``). A second bisection
  finds where the engine's own monitor (energy books off by more than 50 %, NaN) stops the run
  (``engine_stops``): just *below* the limit, since near ``omega dt = 2`` the full-step kinetic
  energy of the highest mode swings far from the conserved (modified) energy;
* charts measured against predicted for a set of models (:func:`stability_study`).

Reference: Hairer, Lubich & Wanner, *Geometric Numerical Integration* (2006), the Stormer-Verlet
method on ``q'' = -omega^2 q`` is stable iff ``omega dt < 2``.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from geodem.core.state import BONDED


def stiffness_pairs(state):
    """Contacts that carry stiffness now: bonded pairs and touching unbonded pairs, each once.
    Returns ``(i, j, kn, ks, n)`` with ``n`` the unit normals from ``i`` to ``j``."""
    from geodem.core.law import series_array

    i = np.repeat(np.arange(state.n), state.width)
    j = state.nbr.ravel()
    c = state.cstate.ravel()
    ok = (j >= 0) & (i < j)
    i, j, c = i[ok], j[ok], c[ok]
    dx = state.x[j] - state.x[i]
    dist = np.linalg.norm(dx, axis=1)
    touch = dist < state.r[i] + state.r[j]
    keep = (c == BONDED) | touch
    i, j, dx, dist = i[keep], j[keep], dx[keep], dist[keep]
    kn = series_array(state.kn[i], state.kn[j])
    ks = series_array(state.ks[i], state.ks[j])
    return i, j, kn, ks, dx / dist[:, None]


def stiffness_matrix(state):
    """Sparse stiffness matrix of the free degrees of freedom of the linear law [N/m] and the
    masses of those DOFs [kg]: ``(K, m_dof)``."""
    from scipy import sparse

    dim = state.dim
    i, j, kn, ks, n = stiffness_pairs(state)
    eye = np.eye(dim)
    blocks = kn[:, None, None] * n[:, :, None] * n[:, None, :] + \
        ks[:, None, None] * (eye[None] - n[:, :, None] * n[:, None, :])
    a, b = np.meshgrid(np.arange(dim), np.arange(dim), indexing="ij")
    rows, cols, vals = [], [], []
    for p, q, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
        rows.append((p[:, None, None] * dim + a[None]).ravel())
        cols.append((q[:, None, None] * dim + b[None]).ravel())
        vals.append(sign * blocks.ravel())
    ndof = state.n * dim
    K = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(ndof, ndof)).tocsr()
    free = (state.free != 0.0).ravel()
    idx = np.flatnonzero(free)
    m_dof = np.repeat(state.m, dim)[idx]
    return K[idx][:, idx], m_dof


def omega_max_exact(state) -> float:
    """Largest angular frequency of the free DOFs of the linear law [rad/s]."""
    from scipy import sparse
    from scipy.sparse.linalg import eigsh

    K, m = stiffness_matrix(state)
    if K.shape[0] == 0:
        return 0.0
    s = sparse.diags(1.0 / np.sqrt(m))
    A = (s @ K @ s).tocsr()
    if A.shape[0] <= 400:
        w2 = float(np.linalg.eigvalsh(A.toarray()).max())
    else:
        w2 = float(eigsh(A, k=1, which="LA", return_eigenvectors=False, tol=1e-10)[0])
    return math.sqrt(max(w2, 0.0))


def _trial(state, dt, steps, seed, backend, engine_checks=True):
    """Whether ``steps`` undamped steps at ``dt`` stay stable, and the engine's message if not.

    ``engine_checks``: unstable = the engine stopped the run (energy books off by > 50 %,
    NaN). Otherwise the engine's energy monitor is off and unstable = the largest speed grew
    by more than 1e3 (or became non-finite): the true divergence of the integration."""
    from geodem.core.engine import InstabilityError, Simulation

    st = state.copy()
    st.eta[:] = 0.0
    st.step, st.time, st.dt = 0, 0.0, 0.0
    st.x_ref[:] = st.x
    rng = np.random.default_rng(seed)
    # velocities of about 1e-6 of a radius per period: tiny, linear, every mode excited
    scale = 1e-6 * float(st.r.mean()) * omega_max_exact(st) / (2 * math.pi)
    st.v[:] = rng.standard_normal(st.v.shape) * scale * (st.free != 0.0)
    v0 = float(np.abs(st.v).max())
    sim = Simulation(st, backend=backend, dt=dt, check_every=10,
                     monitor_every=100 if engine_checks else 0, allow_unstable_dt=True)
    try:
        sim.run(steps)
    except InstabilityError as exc:
        return False, str(exc)
    if not engine_checks:
        v = float(np.abs(sim.sync().v).max())
        if not (math.isfinite(v) and v < 1e3 * v0):
            return False, f"the largest speed grew from {v0:.3g} to {v:.3g} m/s"
    return True, ""


def _bisect(state, pred, steps, rel_tol, seed, backend, engine_checks):
    lo, hi = 0.8 * pred, 1.2 * pred
    ok_lo, _ = _trial(state, lo, steps, seed, backend, engine_checks)
    ok_hi, msg = _trial(state, hi, steps, seed, backend, engine_checks)
    trials = 2
    if not ok_lo or ok_hi:
        raise RuntimeError(f"the critical step is not within 0.8-1.2 x 2/omega_max = {pred:.4g} "
                           f"s (stable at 0.8: {ok_lo}, at 1.2: {ok_hi})")
    while hi - lo > rel_tol * pred:
        mid = 0.5 * (lo + hi)
        ok, m = _trial(state, mid, steps, seed, backend, engine_checks)
        trials += 1
        if ok:
            lo = mid
        else:
            hi, msg = mid, m
    return lo, hi, msg, trials


def measure_critical_dt(state, *, steps=3000, rel_tol=0.002, seed=0, backend="numba"):
    """Critical ``dt`` of ``state`` by bisection between 0.8 and 1.2 x ``2/omega_max``.

    Returns a dict [s]: ``predicted`` (2/omega_max exact), ``gershgorin`` (geodem's refusal
    bound), ``measured`` (largest ``dt`` whose motion does not diverge), ``engine_stops`` (the
    smallest ``dt`` at which the engine's own monitor stopped the run) with its ``message``,
    ``default`` (the default dt), ``trials``."""
    from geodem.core import timestep

    pred = 2.0 / omega_max_exact(state)
    lo, hi, _, n1 = _bisect(state, pred, steps, rel_tol, seed, backend, False)
    _, stop, msg, n2 = _bisect(state, pred, steps, rel_tol, seed, backend, True)
    return {"predicted": pred, "gershgorin": timestep.stable_dt_bound(state), "measured": lo,
            "diverges": hi, "engine_stops": stop, "message": msg, "trials": n1 + n2,
            "default": timestep.default_dt(state)}


# ---------------------------------------------------------------------------------- study
def _models():
    """Small models of different kinds: ``{label: state}``."""
    from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice

    out = {}
    d = 0.01
    x = triangular_lattice(8, 8, d)
    out["2-D triangular lattice, ks/kn 0.5"] = bonded_state(
        x, 0.5 * d, density=2500.0, kn=1e8, ks=5e7, xb=1.0, fs0=1e9, mu=0.5, gap=1e-9 * d)
    x = fcc_lattice(4, 4, 4, d)
    out["3-D FCC lattice, ks/kn 0.2"] = bonded_state(
        x, 0.5 * d, density=2500.0, kn=1e8, ks=2e7, xb=1.0, fs0=1e9, mu=0.5, gap=1e-9 * d)
    rng = np.random.default_rng(1)
    x = triangular_lattice(8, 8, d)
    st = bonded_state(x, 0.5 * d, density=2500.0, kn=1e8, ks=5e7, xb=1.0, fs0=1e9, mu=0.5,
                      gap=1e-9 * d)
    stiff = rng.random(st.n) < 0.1  # 10 % of the elements 100 x stiffer: a stiffness contrast
    st.kn[stiff] *= 100.0
    st.ks[stiff] *= 100.0
    out["2-D lattice, 10 % elements 100x stiffer"] = st
    return out


def stability_study(out_dir, *, steps=3000, backend="numba", progress=None) -> dict:
    """Measure the critical step of :func:`_models`; write ``stability.json`` and
    ``stability_limit.png`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    recs = []
    t0 = time.perf_counter()
    for label, st in _models().items():
        r = measure_critical_dt(st, steps=steps, backend=backend)
        r.update({"model": label, "n": int(st.n),
                  "measured_over_predicted": r["measured"] / r["predicted"],
                  "engine_stops_over_predicted": r["engine_stops"] / r["predicted"],
                  "gershgorin_over_predicted": r["gershgorin"] / r["predicted"],
                  "default_over_predicted": r["default"] / r["predicted"]})
        recs.append(r)
        if progress:
            progress(r)
    res = {"models": recs, "steps_per_trial": steps, "wall_time_s": time.perf_counter() - t0}
    (out / "stability.json").write_text(json.dumps(res, indent=2))
    try:
        _plot(out / "stability_limit.png", recs)
        res["plot"] = "stability_limit.png"
    except ImportError:
        res["plot"] = "skipped: matplotlib is not installed"
    return res


def _plot(path, recs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.0, 3.6))
    y = np.arange(len(recs))
    for k, (key, mk, lab) in enumerate((("measured_over_predicted", "o", "measured limit"),
                                        ("engine_stops_over_predicted", "x",
                                         "engine's monitor stops the run"),
                                        ("gershgorin_over_predicted", "s",
                                         "geodem's refusal bound (Gershgorin)"),
                                        ("default_over_predicted", "^", "default dt"))):
        ax.plot([r[key] for r in recs], y, mk, label=lab)
    ax.axvline(1.0, color="k", lw=0.8, ls="--", label="2 / omega_max (exact)")
    ax.set_yticks(y, [r["model"] for r in recs], fontsize="small")
    ax.set_xscale("log")
    ax.set_xlabel("time step / (2 / omega_max)")
    ax.legend(fontsize="x-small", loc="lower left")
    ax.set_title("velocity Verlet stability: measured against predicted", fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
