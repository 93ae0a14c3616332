"""Speed against accuracy: error against wall time for cases with an analytic or converged reference.

Each case is one small function ``case(dt_fraction, resolution, backend, damping)`` that builds a
model, runs it and returns :class:`Point` fields ``(error, wall_s, n_elements, steps)``. The sweep
driver (:func:`speed_accuracy_study`) crosses each case's axes, keeps the non-dominated points
in (wall time, error) (:func:`pareto_front`), and writes ``speed_accuracy.csv``,
``speed_accuracy.md`` and one log-log chart per case ``speed_accuracy_<case>.png``.

Cases (``error`` is always a relative error, >= 0):

* ``two_balls``: TwoBalls (:mod:`geodem.cases.two_balls`) released from rest; ``max |u -
  u_exact| / A`` over 10 undamped periods against the damped-oscillator solution. ``dt_fraction``
  of the element period ``T_min``; ``damping`` = eta / eta_c; no resolution (4 elements).
* ``wave_speed``: bonded chain of fixed length ``L`` with ``resolution`` elements (``kn`` scaled
  with ``d`` so ``c = d sqrt(K/m)`` is the same at every resolution); a smooth velocity step of
  rise length ``L/10`` at one end; ``|c_measured / c - 1|`` between stations at 0.2 L and 0.7 L
  (half-amplitude arrivals, interpolated between steps).
* ``lattice``: 2-D triangular lattice of discs, ``resolution`` rows across a fixed height,
  compressed to a strain of 1e-4 between frictionless platens and relaxed with ``damping`` x the
  standard damping ``eta_c / N``, for a fixed simulated time (two standard balances at
  ``dt = 0.02 T_min``: ``100 N 0.02 / dt_fraction`` steps); ``|E / E_lattice - 1|`` with ``E``
  from the interior virial stress and the fitted strain, ``E_lattice = 2 sqrt3 Kn (Kn + Ks) /
  (t (3 Kn + Ks))``.
* ``thermal_rod``: ``workflows/thermal_rod.yaml`` with ``resolution`` elements along the same
  rod, the thermal sub-step at ``dt_fraction`` x its explicit stability limit; ``max |T -
  T_exact| / dT`` against the Fourier series.
* ``consolidation``: pore-density flow (Darcy throat flow) in a rigid strip of a triangular
  lattice, ``resolution`` elements along the drainage path, the pore sub-step at ``dt_fraction``
  x its explicit stability limit; the largest relative error of the degree of consolidation
  ``U(T_v)``, ``0.05 <= T_v <= 1``, against Terzaghi's series with the network's own
  diffusivity ``C d^2 / (4 S)``.
* ``ucs``: ``workflows/ucs.yaml`` at ``resolution`` elements across the height; the reference is
  the calibration target of the material (calibrated at 40 across): ``max(|E / E_t - 1|, |UCS /
  Cu_t - 1|)``; three coarse resolutions only (seconds to tens of seconds per point).
* ``column_collapse``: hook for the granular column collapse workflow (runout against the law
  of Lube et al. 2005) once ``geodem/cases/collapse.py`` is part of geodem; not in the default
  set.

The engine is float64 only: every point is recorded with ``precision = float64``.
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["CASES", "DEFAULT_CASES", "Case", "CaseUnavailable", "pareto_front",
           "speed_accuracy_study"]

COLUMNS = ["case", "backend", "precision", "dt_fraction", "dt_of", "resolution",
           "resolution_of", "damping", "n_elements", "steps", "wall_s", "error", "pareto",
           "status"]
PRECISION = "float64"  # the engine's only precision


class CaseUnavailable(RuntimeError):
    """The case cannot run in this installation (its workflow module is missing)."""


@dataclass
class Point:
    error: float
    wall_s: float
    n_elements: int
    steps: int


class _Clock:
    """Wall time of the ``with`` block."""

    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.s = time.perf_counter() - self.t0
        return False


# ================================================================================== cases
def two_balls(dt_fraction, resolution, backend, damping) -> Point:
    """TwoBalls over 10 undamped periods: ``max |u - u_exact| / A`` (``resolution`` unused)."""
    from geodem.cases import two_balls as tb
    from geodem.core.engine import Simulation

    periods, amp = 10, 0.01
    with _Clock() as clock:
        st = tb.build(dim=2, damping_ratio=damping, amplitude=amp)
        an = tb.analytic(st)
        x_rest = st.x[1, 0] - amp
        sim = Simulation(st, backend=backend, dt=dt_fraction * an["T0"], monitor_every=0)
        steps = math.ceil(periods / dt_fraction)
        ts, us = np.empty(steps), np.empty(steps)

        def rec(s):
            k = s.state.step - 1
            ts[k] = s.state.time
            s.backend.pull(("x",))  # a device backend: the positions of this step
            us[k] = s.state.x[1, 0] - x_rest

        sim.run(steps, callback=rec, every=1)
    ref = tb.analytic_curve(ts, amp, an["omega0"], an["decay_rate"])
    return Point(float(np.abs(us - ref).max() / amp), clock.s, st.n, steps)


def wave_speed(dt_fraction, resolution, backend, damping) -> Point:
    """Bonded chain of ``resolution`` elements over ``L = 1 m``: long-wave speed error
    (``damping``: the elements' eta [kg/s]; the grid uses 0)."""
    from geodem.build.lattice import bonded_state, chain
    from geodem.core.engine import Simulation

    n = int(resolution)
    L, rho = 1.0, 2650.0
    d = L / n
    kn = 2.0e9 * d  # stiffness proportional to the size: the same wave speed at every n
    with _Clock() as clock:
        st = bonded_state(chain(n, d, dim=2), np.full(n, 0.5 * d), density=rho, kn=kn,
                          ks=0.3 * kn, xb=1.0, fs0=1e12, mu=0.5, gap=1e-6 * d, thickness=d,
                          eta=damping)
        st.free[0] = 0.0
        st.free[:, 1] = 0.0  # longitudinal motion only
        c = d * math.sqrt(0.5 * kn / st.m[1])
        sim = Simulation(st, backend=backend, dt_fraction=dt_fraction, monitor_every=0)
        tau = 0.1 * L / c  # rise time: the front spans n / 10 elements
        vmax = 1e-3
        stations = (int(0.2 * n), int(0.7 * n))
        cross, last = {}, {i: (0.0, 0.0) for i in stations}

        def drive(s):
            t = s.state.time
            s.backend.pull(("v",))  # a device backend: this step's velocities, and the drive's
            s.state.v[0, 0] = vmax * (0.5 - 0.5 * math.cos(math.pi * min(t / tau, 1.0)))
            s.backend.push(("v",))
            for i in stations:
                v = s.state.v[i, 0]
                if i not in cross and v >= 0.5 * vmax:
                    t0, v0 = last[i]
                    cross[i] = t0 + (t - t0) * (0.5 * vmax - v0) / (v - v0)
                last[i] = (t, v)

        steps = int((stations[1] * d / c + 2.0 * tau) / st.dt)
        sim.run(steps, callback=drive, every=1)
    if len(cross) < 2:
        return Point(math.nan, clock.s, n, steps)
    speed = (stations[1] - stations[0]) * d / (cross[stations[1]] - cross[stations[0]])
    return Point(abs(speed / c - 1.0), clock.s, n, steps)


def lattice(dt_fraction, resolution, backend, damping) -> Point:
    """Triangular lattice between frictionless platens: Young's modulus error."""
    from geodem.build.lattice import SQRT3_2, bonded_state, triangular_lattice
    from geodem.core import timestep
    from geodem.core.engine import Simulation
    from geodem.measure import contact_stress

    ny = int(resolution)
    H = 0.1
    d = H / ((ny - 1) * SQRT3_2)
    nx = ny // 2 + 4
    kn, ks = 2.0e9 * d, 0.6e9 * d
    eps = 1e-4
    with _Clock() as clock:
        x0 = triangular_lattice(nx, ny, d)
        st = bonded_state(x0, np.full(len(x0), 0.5 * d), density=2650.0, kn=kn, ks=ks, xb=1.0,
                          fs0=1e12, mu=0.5, gap=1e-6 * d, thickness=d)
        y = x0[:, 1]
        bottom, top = y < 0.1 * d, y > y.max() - 0.1 * d
        st.free[bottom, 1] = 0.0  # platens: y prescribed, x free
        st.free[top, 1] = 0.0
        st.free[np.flatnonzero(bottom)[nx // 2]] = 0.0  # no rigid drift
        st.eta[:] = damping * timestep.standard_damping(st, ny)
        sim = Simulation(st, backend=backend, dt_fraction=dt_fraction, monitor_every=0)
        half = round(timestep.standard_balance_steps(ny) * 0.02 / dt_fraction)
        st.v[top, 1] = -eps * y.max() / (half * st.dt)  # load over one balance, relax over one
        sim.run(half)
        st.v[top, 1] = 0.0
        sim.run(half)
        st = sim.sync()
    inner = (y > 2 * d) & (y < y.max() - 2 * d) & (x0[:, 0] > 1.5 * d) & \
        (x0[:, 0] < x0[:, 0].max() - 1.5 * d)
    u = st.x - x0
    A = np.c_[x0[inner], np.ones(inner.sum())]
    grad = np.linalg.lstsq(A, u[inner], rcond=None)[0][:2].T
    full = inner & ((st.nbr >= 0).sum(axis=1) == 6)
    s = contact_stress(st, np.flatnonzero(full), full.sum() * SQRT3_2 * d * d * d)
    Kn, Ks = kn / 2, ks / 2
    E_ref = 2 * math.sqrt(3) * Kn * (Kn + Ks) / (d * (3 * Kn + Ks))
    E = s[1, 1] / grad[1, 1]
    return Point(abs(E / E_ref - 1.0), clock.s, st.n, 2 * half)


class _Safety:
    """Temporarily set a coupled field's sub-step safety factor (fraction of its stable step)."""

    def __init__(self, cls, value):
        self.cls, self.value = cls, value

    def __enter__(self):
        self.old = self.cls.__dict__.get("safety")  # None: inherited
        self.cls.safety = float(self.value)

    def __exit__(self, *exc):
        if self.old is None:
            del self.cls.safety
        else:
            self.cls.safety = self.old
        return False


def _workflow(path, sets, backend, key):
    """Run a workflow into a temporary directory; returns (summary, wall)."""
    import tempfile

    from geodem.workflow import run_workflow

    with tempfile.TemporaryDirectory(prefix="geodem-sa-") as tmp, _Clock() as clock:
        code, s = run_workflow(path, Path(tmp) / "run", sets=list(sets) + ["outputs.plots=false"],
                               backend=backend, overwrite=True, echo=False, progress=False)
    if code != 0 or s.get(key) is None:
        raise RuntimeError(f"{path}: status {s.get('status')}: {s.get('error')}")
    return s, clock.s


def _repo_file(rel) -> Path:
    return Path(__file__).resolve().parents[2] / rel


def thermal_rod(dt_fraction, resolution, backend, damping) -> Point:
    """``workflows/thermal_rod.yaml`` with ``resolution`` elements along the 0.2 m rod."""
    from geodem.fields.thermal import ThermalField

    n = int(resolution)
    d = 0.2 / (n - 1)
    sets = [f"model.counts=[{n},1]", f"model.diameter={d!r}",
            "steps.0.nsteps=20"]  # 20 couplings: the sub-step is set by the fraction
    for k, g in ((1, "quarter"), (2, "middle")):  # the shipped rod's probes: elements 1, 2
        lo, hi = (k - 0.25) * d, (k + 0.25) * d
        sets += [f"model.groups.{g}.box.min=[{lo!r},-0.001]",
                 f"model.groups.{g}.box.max=[{hi!r},0.001]"]
    with _Safety(ThermalField, dt_fraction):
        s, wall = _workflow(_repo_file("workflows/thermal_rod.yaml"), sets, backend, "rel_error")
    sub = s.get("results", {}).get("rod", {}).get("thermal_substeps", 0)
    return Point(float(s["rel_error"]), wall, int(s.get("n_elements") or n), int(sub))


def consolidation(dt_fraction, resolution, backend, damping) -> Point:
    """Terzaghi consolidation of a rigid lattice strip drained at one end (pore-density flow)."""
    from geodem.build.lattice import bonded_state, triangular_lattice
    from geodem.core.engine import Simulation
    from geodem.fields.pore import OIL_CF, OIL_KF, PoreField

    nx, ny, D = int(resolution), 4, 0.01
    p0 = 1.0e6

    def strip(field):
        st = bonded_state(triangular_lattice(nx, ny, D), 0.5 * D, density=2500.0, kn=2e8,
                          ks=8e7, xb=1e-5, fs0=1e4, mu=0.5, gap=1e-6 * D)
        st.free[:] = 0.0  # a rigid skeleton: pure diffusion
        sim = Simulation(st, backend=backend, dt=0.05)
        sim.add_field(field)
        return st, sim

    with _Clock() as clock:
        probe = PoreField(forces=False)
        strip(probe)
        xs, counts = np.unique(np.round(probe.cen[:, 0] / (0.5 * D), 6), return_counts=True)
        xs = xs[counts == ny - 1] * 0.5 * D  # the full columns of pores
        x_cut = xs[0] + 0.25 * D  # the first full column of pores (and the end cells) drained
        f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6, p_init=p0, p_min=None, forces=False,
                      bcs=[{"name": "drain", "role": "drain", "pressure": 0.0,
                            "where": {"box": [[-1.0, -1.0], [x_cut, 1.0]]}}])
        f.safety = float(dt_fraction)
        st, sim = strip(f)
        free = f.held < 0
        C = float(np.median(f.C))
        S = f.V[0] * f.k_f
        Dh = C * D * D / (4.0 * S)
        H = (xs[-1] + 0.25 * D) - xs[0]
        t_end = H * H / Dh
        sim.state.dt = t_end / 400.0
        tv, U = [], []
        for _ in range(40):
            sim.run(10)
            P = f.update_pressure()
            tv.append(Dh * st.time / H ** 2)
            U.append(1.0 - (f.V[free] * P[free]).sum() / (f.V[free].sum() * p0))
    tv, U = np.array(tv), np.array(U)
    m = np.arange(200)
    M = np.pi * (2 * m + 1) / 2
    ref = 1.0 - np.sum(2.0 / M ** 2 * np.exp(-np.outer(tv, M ** 2)), axis=1)
    sel = tv >= 0.05
    err = float((np.abs(U[sel] - ref[sel]) / ref[sel]).max())
    return Point(err, clock.s, st.n, int(f.substeps))


def ucs(dt_fraction, resolution, backend, damping) -> Point:
    """``workflows/ucs.yaml`` at ``resolution`` elements across the height; the reference is
    the material's calibration target (E and UCS)."""
    from geodem.studies.study import _targets

    wf = _repo_file("workflows/ucs.yaml")
    E_t, Cu_t, height = _targets(wf, "rock")
    sets = [f"model.d_mean={height / float(resolution)!r}",
            f"simulation.dt_fraction={dt_fraction!r}"]
    s, wall = _workflow(wf, sets, backend, "ucs")
    err = max(abs(s["E"] / E_t - 1.0), abs(s["ucs"] / Cu_t - 1.0))
    return Point(err, wall, int(s.get("n_elements") or 0), int(s.get("steps") or 0))


def column_collapse(dt_fraction, resolution, backend, damping) -> Point:
    """Hook for the granular column collapse (``workflows/column_collapse.yaml``, one column of
    aspect ratio 1, ``resolution`` elements across it, ``damping`` the step's global damping):
    the relative runout error against the law of Lube et al. (2005) (an empirical reference,
    not a converged run). Not in the default set; unavailable until the collapse workflow is
    part of geodem."""
    import importlib.util

    wf = _repo_file("workflows/column_collapse.yaml")
    if importlib.util.find_spec("geodem.cases.collapse") is None or not wf.exists():
        raise CaseUnavailable("column_collapse: geodem/cases/collapse.py and "
                              "workflows/column_collapse.yaml are not in this version of geodem")
    sets = ["model.aspect_ratios=[1.0]", f"model.scale={float(resolution) / 10.0!r}",
            f"simulation.dt_fraction={dt_fraction!r}", f"steps.0.damping={damping!r}"]
    s, wall = _workflow(wf, sets, backend, "runout_rel_error")
    return Point(float(s["runout_rel_error"]), wall, int(s.get("n_elements") or 0),
                 int(s.get("steps") or 0))


# ================================================================================= grid
@dataclass
class Case:
    """A case and its grid: numba (and cupy where present) run every combination of
    ``dt_fraction x resolution x damping``; the slow numpy backend only ``numpy_dt x
    numpy_resolution x damping``. ``quick`` overrides axes for the tiny grid of ``--quick``."""

    run: object
    title: str
    error_of: str
    dt_fraction: tuple
    resolution: tuple = (None,)
    damping: tuple = (None,)
    dt_of: str = "T_min"
    resolution_of: str = "-"
    damping_of: str = "-"
    numpy_dt: tuple = ()
    numpy_resolution: tuple = ()
    gpu: bool = True  # cupy runs the grid when installed
    damping_is_problem: bool = False  # damping changes the reference: one front per value
    quick: dict = field(default_factory=dict)
    default: bool = True

    def axes(self, quick=False) -> dict:
        ax = {k: getattr(self, k) for k in ("dt_fraction", "resolution", "damping", "numpy_dt",
                                             "numpy_resolution")}
        if quick:
            ax.update(self.quick)
        return ax


CASES = {
    "two_balls": Case(
        two_balls, "TwoBalls (damped oscillator)", "max |u - u_exact| / A over 10 periods",
        (0.002, 0.005, 0.01, 0.02, 0.05, 0.1), damping=(0.0, 0.1), damping_of="eta / eta_c",
        damping_is_problem=True,
        numpy_dt=(0.02, 0.1), numpy_resolution=(None,),
        quick={"dt_fraction": (0.005, 0.02), "damping": (0.0,), "numpy_dt": ()}),
    "wave_speed": Case(
        wave_speed, "bonded chain: long-wave speed", "|c / (d sqrt(K/m)) - 1|",
        (0.02, 0.05, 0.1), (50, 100, 200, 400, 800, 1600),
        resolution_of="elements along the chain",
        numpy_dt=(0.1,), numpy_resolution=(50, 100),
        quick={"dt_fraction": (0.05,), "resolution": (50, 200), "numpy_resolution": ()}),
    "lattice": Case(
        lattice, "triangular lattice between platens: E", "|E / E_lattice - 1|",
        (0.01, 0.02, 0.05, 0.08), (8, 12, 16, 24, 32, 48), damping=(0.5, 1.0, 2.0),
        resolution_of="rows across the height", damping_of="x standard damping",
        numpy_dt=(0.05,), numpy_resolution=(8, 12),
        quick={"dt_fraction": (0.05,), "resolution": (8, 16), "damping": (1.0,),
               "numpy_resolution": ()}),
    "thermal_rod": Case(
        thermal_rod, "thermal rod (Fourier series)", "max |T - T_exact| / dT",
        (0.1, 0.25, 0.5), (11, 21, 41, 81, 161, 321), dt_of="thermal stable step",
        resolution_of="elements along the rod", gpu=False,
        quick={"dt_fraction": (0.5,), "resolution": (11, 21)}),
    "consolidation": Case(
        consolidation, "pore flow: Terzaghi consolidation", "max |U / U_Terzaghi - 1|",
        (0.1, 0.25, 0.5), (18, 34, 66, 130), dt_of="pore stable step",
        resolution_of="elements along the drainage path", gpu=False,
        quick={"dt_fraction": (0.5,), "resolution": (18, 34)}),
    "ucs": Case(
        ucs, "UCS specimen (calibration target)", "max(|E / E_t - 1|, |UCS / Cu_t - 1|)",
        (0.05, 0.1), (15, 20, 30), resolution_of="elements across the height",
        quick={"dt_fraction": (0.1,), "resolution": (15,)}),
    "column_collapse": Case(
        column_collapse, "granular column collapse, a = 1 (Lube et al. 2005)",
        "|runout / runout_law - 1|", (0.02, 0.04), (10, 20), damping=(0.0,),
        resolution_of="elements across the column", damping_of="eta tau / m", gpu=False,
        quick={"dt_fraction": (0.04,), "resolution": (10,)}, default=False),
}
DEFAULT_CASES = [k for k, c in CASES.items() if c.default]


def parse_cases(text) -> list:
    """``a,b,...`` or ``all`` or ``default``/None -> case names; ValueError naming ``--cases``."""
    if text is None or text.strip() in ("", "default"):
        return list(DEFAULT_CASES)
    names = [v.strip().lower().replace("-", "_") for v in text.split(",") if v.strip()]
    if names == ["all"]:
        return list(CASES)
    bad = [n for n in names if n not in CASES]
    if bad or not names:
        raise ValueError(f"--cases: unknown case {', '.join(map(repr, bad)) or repr(text)}; "
                         f"allowed: {', '.join(CASES)}, all, default "
                         f"(= {','.join(DEFAULT_CASES)})")
    return list(dict.fromkeys(names))


def _backends(case: Case, only=None) -> list:
    from geodem.backends import available

    have = available()
    out = ["numba", "numpy"] + (["cupy"] if case.gpu else [])
    out = [b for b in out if b in have]
    if only not in (None, "auto"):
        out = [b for b in out if b == only]
    return out


def points_of(name: str, quick=False, backend=None) -> list:
    """The grid of case ``name``: ``[(backend, dt_fraction, resolution, damping), ...]``."""
    case = CASES[name]
    ax = case.axes(quick)
    out = []
    for be in _backends(case, backend):
        dts, res = (ax["numpy_dt"], ax["numpy_resolution"]) if be == "numpy" else \
            (ax["dt_fraction"], ax["resolution"])
        out += [(be, f, r, dm) for r in res for dm in ax["damping"] for f in dts]
    return out


# =============================================================================== pareto
def pareto_front(wall, error) -> np.ndarray:
    """Mask of the non-dominated points of ``(wall, error)`` (both to be minimised): no other
    point is at least as fast *and* at least as accurate, and strictly better in one. Points
    with a non-finite value are never on the front."""
    w = np.asarray(wall, dtype=float)
    e = np.asarray(error, dtype=float)
    ok = np.isfinite(w) & np.isfinite(e)
    front = ok.copy()
    for i in np.flatnonzero(ok):
        better = ok & (w <= w[i]) & (e <= e[i]) & ((w < w[i]) | (e < e[i]))
        front[i] = not better.any()
    return front


# ================================================================================ sweep
REPEATS, REPEAT_BELOW_S = 3, 1.0


def run_point(name, backend, dt_fraction, resolution, damping) -> dict:
    """One point of case ``name`` as a table row (``status`` ok / refused / failed). A point
    whose runs take less than ``REPEAT_BELOW_S`` in all runs again, up to ``REPEATS`` times,
    and keeps the shortest wall time (the runs are deterministic: the error is the same)."""
    case = CASES[name]
    row = {"case": name, "backend": backend, "precision": PRECISION, "dt_fraction": dt_fraction,
           "dt_of": case.dt_of, "resolution": resolution, "resolution_of": case.resolution_of,
           "damping": damping, "n_elements": None, "steps": None, "wall_s": None,
           "error": None, "pareto": False, "status": "ok"}
    args = (dt_fraction, resolution, backend, 0.0 if damping is None else damping)
    try:
        p = case.run(*args)
        walls = [p.wall_s]
        while len(walls) < REPEATS and sum(walls) < REPEAT_BELOW_S:  # cheap: best of a few
            walls.append(case.run(*args).wall_s)
        p.wall_s = min(walls)
    except CaseUnavailable:
        raise
    except ValueError as exc:  # the engine refuses a step above the stability bound
        row["status"] = f"refused: {str(exc).split(';')[0]}"
        return row
    except Exception as exc:  # noqa: BLE001 - one lost point must not lose the study
        row["status"] = f"failed: {type(exc).__name__}: {exc}"
        return row
    row.update(error=float(p.error), wall_s=float(p.wall_s), n_elements=int(p.n_elements),
               steps=int(p.steps))
    if not math.isfinite(row["error"]):
        row["status"] = "failed: no measurement"
    return row


def speed_accuracy_study(out_dir, cases=None, quick=False, backend=None, progress=None) -> dict:
    """Sweep ``cases`` (default :data:`DEFAULT_CASES`); write ``speed_accuracy.csv``, ``.md``,
    ``.json`` and ``speed_accuracy_<case>.png`` into ``out_dir``. Before each case and backend
    one unrecorded warm-up run loads the compiled kernels, so the first point's wall time holds
    no compilation. Returns the record written to ``speed_accuracy.json``."""
    import numba

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(DEFAULT_CASES) if cases is None else list(cases)
    t0 = time.perf_counter()
    rows = []
    for name in names:
        grid = points_of(name, quick, backend)
        warmed = set()
        case_rows = []
        for be, f, r, dm in grid:
            if be not in warmed:
                warmed.add(be)
                run_point(name, be, max(x[1] for x in grid if x[0] == be), r, dm)
            row = run_point(name, be, f, r, dm)
            case_rows.append(row)
            if progress:
                progress(row)
        for prob in problems(case_rows, name):
            ok = [x for x in prob if x["status"] == "ok"]
            on = pareto_front([x["wall_s"] for x in ok], [x["error"] for x in ok])
            for x, o in zip(ok, on):
                x["pareto"] = bool(o)
        rows += case_rows
    rec = {"cases": names, "quick": bool(quick), "precision": PRECISION,
           "numba_threads": int(numba.get_num_threads()), "rows": rows,
           "wall_time_s": time.perf_counter() - t0, "charts": []}
    _write_csv(out / "speed_accuracy.csv", rows)
    rec["targets"] = {n: fastest_within(rows, n) for n in names}
    (out / "speed_accuracy.md").write_text(markdown(rows, names, rec["targets"]))
    try:
        for n in names:
            if any(x["case"] == n and x["status"] == "ok" for x in rows):
                fname = f"speed_accuracy_{n}.png"
                plot_case(out / fname, n, rows)
                rec["charts"].append(fname)
    except ImportError:
        rec["charts"] = "skipped: matplotlib is not installed"
    (out / "speed_accuracy.json").write_text(json.dumps(rec, indent=2))
    return rec


TARGETS = (1e-1, 1e-2, 1e-3, 1e-4)


def problems(rows, name) -> list:
    """The rows of case ``name`` split into problems, each with its own Pareto front: one
    per damping value where damping changes the reference (TwoBalls), else one."""
    sel = [x for x in rows if x["case"] == name]
    if not CASES[name].damping_is_problem:
        return [sel]
    return [[x for x in sel if x["damping"] == d] for d in dict.fromkeys(x["damping"]
                                                                        for x in sel)]


def fastest_within(rows, name) -> list:
    """Per problem of case ``name`` (:func:`problems`): ``{target: row}``, the fastest point
    with error <= target (None if none)."""
    out = []
    for prob in problems(rows, name):
        ok = [x for x in prob if x["status"] == "ok"]
        res = {}
        for t in TARGETS:
            sel = [x for x in ok if x["error"] <= t]
            res[f"{t:g}"] = min(sel, key=lambda x: x["wall_s"]) if sel else None
        out.append(res)
    return out


def _fmt(v, digits=4):
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _write_csv(path, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for x in rows:
            w.writerow([_fmt(x[c], 6) if c != "pareto" else int(x[c]) for c in COLUMNS])


def _label(x) -> str:
    parts = [f"dt {x['dt_fraction']:g}"]
    if x["resolution"] is not None:
        parts.append(f"res {x['resolution']}")
    if x["damping"] is not None:
        parts.append(f"damping {x['damping']:g}")
    return ", ".join(parts) + f" ({x['backend']})"


def markdown(rows, names, targets) -> str:
    """Per case: what is measured, the fastest point per target error, and every point."""
    lines = ["# Speed against accuracy", "",
             (f"precision: {PRECISION} (the engine's only precision); wall times on this "
              "machine; `*` = on the Pareto front (no point is both faster and more accurate)."),
             ""]
    for n in names:
        c = CASES[n]
        lines += [f"## {n}: {c.title}", "",
                  (f"error = {c.error_of}; dt fraction of the {c.dt_of}; resolution = "
                   f"{c.resolution_of}; damping = {c.damping_of}."), ""]
        for res in targets[n]:
            for t, x in res.items():
                lines.append(f"- error <= {t}: " + (f"{_label(x)}, {x['wall_s']:.3g} s, error "
                                                    f"{x['error']:.3g}" if x else "no point"))
        lines += ["", ("| backend | dt fraction | resolution | damping | elements | steps | "
                       "wall [s] | error | front |"), "|---|---|---|---|---|---|---|---|---|"]
        sel = sorted((x for x in rows if x["case"] == n),
                     key=lambda x: (x["status"] != "ok", x["wall_s"] or 0.0))
        for x in sel:
            err = _fmt(x["error"]) if x["status"] == "ok" else x["status"]
            lines.append(f"| {x['backend']} | {x['dt_fraction']:g} | {_fmt(x['resolution'])} | "
                         f"{_fmt(x['damping'])} | {_fmt(x['n_elements'])} | {_fmt(x['steps'])} "
                         f"| {_fmt(x['wall_s'])} | {err} | {'*' if x['pareto'] else ''} |")
        lines.append("")
    return "\n".join(lines)


def plot_case(path, name, rows):
    """Log-log error against wall time of one case: colour = (backend, damping), marker = dt
    fraction, label = resolution; the Pareto front as a black staircase."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = CASES[name]
    ok = [x for x in rows if x["case"] == name and x["status"] == "ok"]
    floor = 1e-16
    fig, ax = plt.subplots(figsize=(5.6, 4.1))
    series = sorted({(x["backend"], x["damping"] if x["damping"] is not None else -1.0)
                     for x in ok})
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    dts = sorted({x["dt_fraction"] for x in ok})
    marks = dict(zip(dts, "os^Dvp<>"))
    for k, (be, dm) in enumerate(series):
        lab = be + (f", damping {dm:g}" if dm >= 0 else "")
        for f in dts:
            sel = [x for x in ok if x["backend"] == be and x["dt_fraction"] == f and
                   (x["damping"] if x["damping"] is not None else -1.0) == dm]
            if not sel:
                continue
            ax.plot([x["wall_s"] for x in sel], [max(x["error"], floor) for x in sel],
                    marks[f], color=colours[k % len(colours)], ms=5, ls="none",
                    mfc="none" if be == "numpy" else colours[k % len(colours)],
                    label=lab)
            lab = None  # one legend entry per series
            if c.resolution_of != "-":
                for x in sel:
                    ax.annotate(str(x["resolution"]), (x["wall_s"], max(x["error"], floor)),
                                textcoords="offset points", xytext=(3, 2), fontsize=6)
    for k, prob in enumerate(problems(ok, name)):
        front = sorted((x for x in prob if x["pareto"]), key=lambda x: x["wall_s"])
        if front:
            ax.step([x["wall_s"] for x in front], [max(x["error"], floor) for x in front],
                    where="post", color="k", lw=0.9, ls="--" if k == 0 else ":",
                    label="Pareto front" + (f" (damping {front[0]['damping']:g})"
                                            if c.damping_is_problem else ""))
    for f in dts:  # marker key
        ax.plot([], [], marks[f], color="grey", mfc="none", ls="none", label=f"dt {f:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    import numba

    ax.set_xlabel(f"wall time [s] ({numba.get_num_threads()} numba thread(s); best of up to "
                  f"{REPEATS} runs)")
    ax.set_ylabel("relative error")
    res = "" if c.resolution_of == "-" else f"; labels: {c.resolution_of}"
    ax.set_title(f"{c.title}\nerror = {c.error_of}\ndt = fraction of the {c.dt_of}{res}",
                 fontsize=7)
    ax.legend(fontsize=6, loc="best", ncol=2)
    ax.grid(True, which="major", lw=0.3, alpha=0.5)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


# ================================================================================== CLI
def run_cli(out, cases, quick, backend, con, fail):
    """``geodem study speed-accuracy``: parse, sweep, print one line per point. ``fail(msg)``
    reports a user error (exit 2)."""
    try:
        names = parse_cases(cases)
    except ValueError as exc:
        fail(str(exc))
    if backend not in (None, "auto"):
        from geodem.backends import available

        if backend not in available():
            fail(f"--backend {backend}: not available on this machine; available: "
                 f"{', '.join(available())}")

    def said(x):
        what = f"error {x['error']:.3g}, {x['wall_s']:.3g} s" if x["status"] == "ok" else \
            x["status"]
        con.print(f"{x['case']}: {_label(x)}: {what}", highlight=False)

    try:
        rec = speed_accuracy_study(out, names, quick=quick, backend=backend, progress=said)
    except CaseUnavailable as exc:
        fail(f"--cases: {exc}")
    con.print(f"{len(rec['rows'])} points in {rec['wall_time_s']:.0f} s; wrote "
              f"speed_accuracy.csv, speed_accuracy.md, speed_accuracy.json and "
              f"{len(rec['charts'])} charts to {out}", highlight=False)
    return rec
