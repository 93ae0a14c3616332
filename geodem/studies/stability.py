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
* charts measured against predicted for a set of models (:func:`stability_study`);
* does the same for the explicit Euler sub-steps of the coupled fields (pore fluid, thermal):
  the exact limit ``2 / lambda_max`` of ``cap^-1/2 L cap^-1/2`` (``L`` the conductance
  Laplacian, ``cap`` the storages/heat capacities) against a bisection on forced sub-steps,
  the field's ``stable_dt`` (the largest sub-step it accepts) and the sub-step it takes
  (:func:`measure_field_critical_step`);
* sweeps the damping of a quasi-static balance (:func:`balance_damping_sweep`): the
  unbalanced-force ratio after the standard ``50 N`` steps grows on both sides of the standard
  damping, and the balance step flags it above its tolerance.

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
    kf = state.krate.ravel() if state.row_stiffness else np.ones(j.size)
    ok = (j >= 0) & (i < j)
    i, j, c, kf = i[ok], j[ok], c[ok], kf[ok]
    dx = state.x[j] - state.x[i]
    dist = np.linalg.norm(dx, axis=1)
    touch = dist < state.r[i] + state.r[j]
    keep = (c == BONDED) | touch
    i, j, dx, dist, kf = i[keep], j[keep], dx[keep], dist[keep], kf[keep]
    kn = series_array(state.kn[i], state.kn[j]) * kf
    ks = series_array(state.ks[i], state.ks[j]) * kf
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


# ---------------------------------------------------------------- coupled fields (explicit Euler)
def field_operator(field, sim):
    """The linear operator of a coupled field's explicit update over its free unknowns:
    ``(L, cap, u, set_u)`` with ``cap du/dt = -L u`` (``L`` the sparse symmetric conductance
    Laplacian, ``cap`` the capacities), ``u()`` the current unknowns and ``set_u(v)`` to set them.

    * pore fluid (:class:`~geodem.fields.pore.PoreField`): pressures of the free pores
      (``held < 0``), capacities ``S = V k_f``, throat conductances ``C``;
    * thermal (:class:`~geodem.fields.thermal.ThermalField`): temperatures of the
      free-temperature elements, capacities ``m c``, contact conductances ``h_ij``.

    Held pores and fixed temperatures are Dirichlet values: their rows and columns are dropped,
    their conductances stay on the diagonal."""
    from scipy import sparse

    if field.kind == "pore_fluid":
        field.stable_dt(sim)  # geometry and conductances at the current positions
        a, b, c = field.tp[:, 0], field.tp[:, 1], field.C
        n = field.M.shape[0]
        free = field.held < 0
        cap_all = field.V * field.k_f

        def u():
            return (field.M / field.V - field.c_f) / field.k_f

        def set_u(v):
            field.M[:] = field.V * (field.k_f * v + field.c_f)
    elif field.kind == "thermal":
        field.stable_dt(sim)  # conductances
        st = sim.state
        i = np.repeat(np.arange(st.n), st.nbr.shape[1])
        j = st.nbr.ravel()
        h = field.hmat.ravel()
        ok = (j >= 0) & (i < j) & (h > 0)
        a, b, c = i[ok], j[ok], h[ok]
        n = st.n
        free = field.fixed_mask == 0
        cap_all = field.cap

        def u():
            return field.T

        def set_u(v):
            field.T[:] = v
    else:
        raise ValueError(f"field_operator: unsupported field {field.kind!r}; allowed: "
                         f"pore_fluid, thermal")
    rows = np.concatenate([a, b, a, b])
    cols = np.concatenate([a, b, b, a])
    vals = np.concatenate([c, c, -c, -c])
    L = sparse.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()
    idx = np.flatnonzero(free)
    return L[idx][:, idx], cap_all[idx], u, set_u


def field_limit_exact(field, sim) -> float:
    """Exact critical sub-step of the field's explicit Euler update, ``2 / lambda_max`` of
    ``cap^-1/2 L cap^-1/2`` [s] (forward Euler on ``u' = -A u`` is stable iff ``h lambda <= 2``)."""
    from scipy import sparse
    from scipy.sparse.linalg import eigsh

    L, cap, _, _ = field_operator(field, sim)
    if L.shape[0] == 0 or L.nnz == 0:
        return math.inf
    s = sparse.diags(1.0 / np.sqrt(cap))
    A = (s @ L @ s).tocsr()
    if A.shape[0] <= 600:
        lam = float(np.linalg.eigvalsh(A.toarray()).max())
    else:
        lam = float(eigsh(A, k=1, which="LA", return_eigenvectors=False, tol=1e-10)[0])
    return math.inf if lam <= 0.0 else 2.0 / lam


def _field_trial(field, sim, h, steps, seed):
    """Whether ``steps`` forced sub-steps of ``h`` keep a small random perturbation bounded
    (it must not grow 1000-fold); the field's unknowns are restored afterwards."""
    _, cap, u, set_u = field_operator(field, sim)
    free_idx = _free_index(field)
    base = u().copy()
    rng = np.random.default_rng(seed)
    v = base.copy()
    scale = 1e-3 * max(float(np.abs(base).max()), 1.0)
    v[free_idx] += scale * rng.standard_normal(free_idx.size)
    set_u(v)

    def dev():
        w = u()[free_idx]
        return float(np.abs(w - np.dot(cap, w) / cap.sum()).max())

    d0 = dev()
    ok = True
    for _ in range(int(steps)):
        field.substep(sim, h, allow_unstable=True)
    d = dev()
    ok = math.isfinite(d) and d < 1e3 * d0
    set_u(base)
    return ok


def _free_index(field):
    if field.kind == "pore_fluid":
        return np.flatnonzero(field.held < 0)
    return np.flatnonzero(field.fixed_mask == 0)


def measure_field_critical_step(field, sim, *, steps=4000, rel_tol=0.002, seed=0) -> dict:
    """Critical sub-step of a coupled field by bisection between 0.8 and 1.2 x the exact limit
    (:func:`field_limit_exact`), forcing sub-steps of a chosen length (``allow_unstable``).

    Returns [s]: ``predicted`` (exact), ``measured`` (largest stable sub-step found),
    ``diverges`` (smallest unstable one), ``bound`` (the field's ``stable_dt``: the largest
    sub-step it accepts), ``used`` (the sub-step :meth:`advance` takes: ``safety x stable_dt``),
    ``trials``."""
    pred = field_limit_exact(field, sim)
    lo, hi = 0.8 * pred, 1.2 * pred
    if not _field_trial(field, sim, lo, steps, seed) or _field_trial(field, sim, hi, steps, seed):
        raise RuntimeError(f"the critical sub-step of {field.kind!r} is not within 0.8-1.2 x "
                           f"the predicted {pred:.4g} s")
    trials = 2
    while hi - lo > rel_tol * pred:
        mid = 0.5 * (lo + hi)
        if _field_trial(field, sim, mid, steps, seed):
            lo = mid
        else:
            hi = mid
        trials += 1
    bound = float(field.stable_dt(sim))
    return {"predicted": pred, "measured": lo, "diverges": hi, "bound": bound,
            "used": field.safety * bound, "trials": trials}


def _field_models():
    """Small fields on fixed solids: ``{label: (sim, field)}``."""
    from geodem.build.lattice import bonded_state, triangular_lattice
    from geodem.core.engine import Simulation
    from geodem.fields.pore import OIL_CF, OIL_KF, PoreField
    from geodem.fields.thermal import ThermalField

    d = 0.01

    def solid(nx, ny, jitter, seed=0):
        rng = np.random.default_rng(seed)
        x = triangular_lattice(nx, ny, d) + rng.uniform(-jitter, jitter, (nx * ny, 2)) * d
        st = bonded_state(x, 0.5 * d, density=2500.0, kn=2e8, ks=8e7, xb=1e-3 * d, fs0=1e4,
                          mu=0.5, gap=0.2 * d)
        return Simulation(st, backend="numba")  # never stepped: only the field sub-steps

    out = {}
    h = math.sqrt(3.0) / 2.0 * d
    x = np.array([[0.0, 0.0], [d, 0.0], [0.5 * d, h], [0.5 * d, -h]])
    st = bonded_state(x, 0.5 * d, density=2500.0, kn=2e8, ks=8e7, xb=1e-3 * d, fs0=1e4,
                      mu=0.5, gap=0.2 * d)
    st.free[:] = 0.0
    sim = Simulation(st, backend="numba")
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6, p_init=1e6, p_min=None, forces=False)
    sim.add_field(f)
    out["pore fluid: two pores, one throat"] = (sim, f)
    for label, jit in (("pore fluid: 2-D lattice, 10 x 10", 0.0),
                       ("pore fluid: 2-D jittered lattice, 10 x 10", 0.15)):
        sim = solid(10, 10, jit, seed=3)
        f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6, p_init=1e6, p_min=None, forces=False)
        sim.add_field(f)
        out[label] = (sim, f)
    for label, jit in (("thermal: 2-D lattice, 10 x 10", 0.0),
                       ("thermal: 2-D jittered lattice, 10 x 10", 0.15)):
        sim = solid(10, 10, jit, seed=3)
        f = ThermalField(k=3.0, c=800.0)
        sim.add_field(f)
        out[label] = (sim, f)
    return out


def field_stability_study(*, steps=4000, progress=None) -> list:
    """:func:`measure_field_critical_step` over :func:`_field_models`; one dict per model."""
    recs = []
    for label, (sim, f) in _field_models().items():
        r = measure_field_critical_step(f, sim, steps=steps)
        r.update({"model": label, "field": f.kind, "unknowns": int(_free_index(f).size),
                  "measured_over_predicted": r["measured"] / r["predicted"],
                  "bound_over_predicted": r["bound"] / r["predicted"],
                  "used_over_predicted": r["used"] / r["predicted"]})
        recs.append(r)
        if progress:
            progress(r)
    return recs


# ---------------------------------------------------------------- quasi-static balance
def balance_damping_sweep(factors=(0.0, 1e-3, 1e-2, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0), *,
                          n=8, backend="numba") -> list:
    """Unbalanced-force ratio after a standard balance (``50 N`` steps) of a bonded 2-D block
    (``n x n`` triangular lattice, base fixed, dropped under gravity) for each damping
    ``factor x`` the standard damping ``eta_c / N``: too little damping leaves it ringing, too
    much leaves it creeping; the step's ``tolerance`` (1e-2) flags both."""
    from geodem.build.lattice import bonded_state, triangular_lattice
    from geodem.core import timestep
    from geodem.core.engine import Simulation

    d = 0.01
    recs = []
    for f in factors:
        x = triangular_lattice(n, n, d)
        st = bonded_state(x, 0.5 * d, density=2650.0, kn=2e7, ks=6e6, xb=2e-6, fs0=20.0,
                          mu=0.4, gap=1e-9 * d)
        st.gravity[:] = 0.0
        st.gravity[1] = -9.81
        st.free[x[:, 1] < x[:, 1].min() + 0.25 * d] = 0.0
        sim = Simulation(st, backend=backend, monitor_every=0)
        eta = float(f) * timestep.standard_damping(st, n)
        sim.change(lambda s, e=eta: s.eta.__setitem__(slice(None), e), book_energy=False)
        sim.run(timestep.standard_balance_steps(n))
        recs.append({"damping_over_standard": float(f),
                     "unbalanced_force_ratio": float(sim.unbalanced_force_ratio())})
    return recs


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


def stability_study(out_dir, *, steps=3000, backend="numba", progress=None,
                    fields=True, balance=True) -> dict:
    """Measure the critical step of :func:`_models` (and, with ``fields``, the critical sub-step
    of :func:`_field_models`; with ``balance``, :func:`balance_damping_sweep`); write
    ``stability.json``, ``stability_limit.png``, ``stability_limit_fields.png`` and
    ``stability_balance.png`` into ``out_dir``. ``progress(kind, record)`` reports each point."""
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
            progress("mechanics", r)
    res = {"models": recs, "steps_per_trial": steps}
    if fields:
        res["fields"] = field_stability_study(progress=(lambda r: progress("field", r))
                                              if progress else None)
    if balance:
        res["balance"] = balance_damping_sweep(backend=backend)
        if progress:
            for r in res["balance"]:
                progress("balance", r)
    res["wall_time_s"] = time.perf_counter() - t0
    res["plots"] = []
    try:
        _plot(out / "stability_limit.png", recs, (
            ("measured_over_predicted", "o", "measured limit"),
            ("engine_stops_over_predicted", "x", "engine's monitor stops the run"),
            ("gershgorin_over_predicted", "s", "geodem's refusal bound (Gershgorin)"),
            ("default_over_predicted", "^", "default dt")),
            "velocity Verlet stability: measured against predicted", "2 / omega_max (exact)",
            "time step / (2 / omega_max)")
        res["plots"].append("stability_limit.png")
        if fields:
            _plot(out / "stability_limit_fields.png", res["fields"], (
                ("measured_over_predicted", "o", "measured limit"),
                ("bound_over_predicted", "s", "stable_dt: the largest sub-step accepted"),
                ("used_over_predicted", "^", "sub-step advance() takes (safety 0.5)")),
                "coupled fields, explicit Euler: measured against predicted",
                "2 / lambda_max (exact)", "sub-step / (2 / lambda_max)")
            res["plots"].append("stability_limit_fields.png")
        if balance:
            _plot_balance(out / "stability_balance.png", res["balance"])
            res["plots"].append("stability_balance.png")
    except ImportError:
        res["plots"] = []
        res["plot_note"] = "skipped: matplotlib is not installed"
    (out / "stability.json").write_text(json.dumps(res, indent=2))
    return res


def describe(kind, r) -> str:
    """One line for a point of :func:`stability_study` (its ``progress(kind, record)``)."""
    if kind == "mechanics":
        p = r["predicted"]
        return (f"{r['model']}: 2/omega_max {p:.4g} s; diverges above {r['measured'] / p:.4f} x; "
                f"engine stops at {r['engine_stops'] / p:.4f} x; refusal bound "
                f"{r['gershgorin'] / p:.3f} x; default {r['default'] / p:.3f} x")
    if kind == "field":
        return (f"{r['model']}: 2/lambda_max {r['predicted']:.4g} s; diverges above "
                f"{r['measured_over_predicted']:.4f} x; stable_dt (largest accepted) "
                f"{r['bound_over_predicted']:.3f} x; sub-step taken "
                f"{r['used_over_predicted']:.3f} x")
    return (f"balance, damping {r['damping_over_standard']:g} x standard: unbalanced-force "
            f"ratio {r['unbalanced_force_ratio']:.3g}")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot(path, recs, series, title, exact_label, xlabel):
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 0.45 * len(recs) + 1.5))
    y = np.arange(len(recs))
    for key, mk, lab in series:
        ax.plot([r[key] for r in recs], y, mk, label=lab)
    ax.axvline(1.0, color="k", lw=0.8, ls="--", label=exact_label)
    ax.set_yticks(y, [r["model"] for r in recs], fontsize="small")
    ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.legend(fontsize="x-small", loc="center left", bbox_to_anchor=(1.02, 0.5))
    ax.set_title(title, fontsize="medium")
    fig.subplots_adjust(left=0.34, right=0.70, bottom=0.2, top=0.9)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def _plot_balance(path, recs, tolerance=1e-2):
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    f = np.array([r["damping_over_standard"] for r in recs])
    u = np.array([r["unbalanced_force_ratio"] for r in recs])
    zero = f == 0.0
    ax.loglog(f[~zero], u[~zero], "o-", label="after 50 N steps (standard balance)")
    if zero.any():
        ax.axhline(float(u[zero][0]), color="C3", lw=0.8, ls=":", label="no damping")
    ax.axhline(tolerance, color="k", lw=0.8, ls="--", label="balance tolerance (flagged above)")
    ax.axvline(1.0, color="0.6", lw=0.8)
    ax.set_xlabel("damping / standard damping eta_c / N")
    ax.set_ylabel("unbalanced-force ratio")
    ax.set_title("quasi-static balance: too little or too much damping", fontsize="medium")
    ax.legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
