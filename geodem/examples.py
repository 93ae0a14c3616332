"""Ready-to-run examples behind ``geodem example ...``.

``two_balls`` is MatDEM's first example (PHYSICS.md section 10): ``wall - ball - ball - wall``, all
bonded, both balls displaced by the same amplitude so that only the in-phase mode rings. It is run
twice, critically damped and at 10 % of critical damping, and compared with the analytic damped
oscillator (:mod:`geodem.cases.two_balls`).
"""
from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np

from geodem.cases.two_balls import analytic_curve

#: time step as a fraction of the undamped period, and number of undamped periods simulated
DT_FRACTION = 0.02
PERIODS = 10
#: damping ratios of the two runs (eta / eta_critical)
CRITICAL = 1.0
TEN_PERCENT = 0.1
#: energy terms recorded in the history (keys of ``Simulation.energies()``)
ENERGY_TERMS = ("kinetic", "elastic", "heat_viscous", "total", "closure_error")


class ExampleError(ValueError):
    """Bad example input (output folder, dimension); the message says what to change."""


def _prepare_out_dir(out_dir, overwrite: bool) -> Path:
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ExampleError(f"output path {str(out)!r} exists and is not a folder; "
                           "choose another output folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise ExampleError(f"output folder {str(out)!r} exists and is not empty; choose another "
                           "output folder, or allow writing into it (--overwrite on the "
                           "command line, overwrite=True in Python)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _run_case(damping_ratio, backend, dim, steps, dt_fraction):
    from geodem.cases import two_balls as tb
    from geodem.core.engine import Simulation

    d = 1.0
    st = tb.build(dim=dim, d=d, damping_ratio=damping_ratio)
    an = tb.analytic(st)
    sim = Simulation(st, backend=backend, dt=dt_fraction * an["T0"])
    x_rest = 1.0 * d  # rest position of ball 1 (wall at 0, spacing d)

    def u_of(s):
        return float(s.x[1, 0] - x_rest)

    times, u, energies = [], [], []

    def record(s):
        e = s.energies()  # syncs the state first (GPU backends)
        times.append(s.state.time)
        u.append(u_of(s.state))
        energies.append({k: e[k] for k in ENERGY_TERMS})

    record(sim)
    sim.run(steps, callback=record, every=1)
    return {"sim": sim, "state": st, "analytic": an, "t": np.array(times), "u": np.array(u),
            "energies": energies, "amplitude": u[0]}


def two_balls(out_dir, backend=None, dim=2, overwrite=False, periods=PERIODS,
              dt_fraction=DT_FRACTION, plot=True) -> dict:
    """Run TwoBalls critically damped and at 10 % of critical; write results to ``out_dir``.

    Each run covers ``periods`` undamped periods ``T0`` at ``dt = dt_fraction * T0``, recording
    the displacement of ball 1 and the energy terms every step. Writes ``summary.json`` (the key
    numbers, returned as a dict too), ``history.csv`` and, if matplotlib is importable,
    ``two_balls.png``.

    Raises :class:`ExampleError` if ``out_dir`` exists and is not empty (unless ``overwrite``).
    Backend: ``backend`` > ``$GEODEM_BACKEND`` > ``auto``.
    """
    from geodem.backends import resolve_name
    from geodem.cases import two_balls as tb

    if dim not in (2, 3):
        raise ExampleError(f"dim must be 2 or 3, got {dim!r}")
    if not (isinstance(periods, (int, float)) and periods > 1):
        raise ExampleError(f"periods must be a number > 1, got {periods!r}")
    if not (0.0 < dt_fraction <= 0.1):
        raise ExampleError(f"dt_fraction must be in (0, 0.1], got {dt_fraction!r}")
    name = resolve_name(backend)  # BackendError for an unknown/unusable backend, before any I/O
    out = _prepare_out_dir(out_dir, overwrite)
    steps = int(round(periods / dt_fraction))

    t0 = time.perf_counter()
    crit = _run_case(CRITICAL, name, dim, steps, dt_fraction)
    ten = _run_case(TEN_PERCENT, name, dim, steps, dt_fraction)
    wall = time.perf_counter() - t0

    an = ten["analytic"]
    meas = tb.measure(ten["t"], ten["u"])
    period_rel = abs(meas["T"] - an["T"]) / an["T"]
    decay_rel = abs(meas["decay_rate"] - an["decay_rate"]) / an["decay_rate"]
    amp_c = crit["amplitude"]
    overshoot = max(0.0, -float(crit["u"].min())) / amp_c
    closure = max(max(e["closure_error"] for e in run["energies"]) for run in (crit, ten))
    # deviation from the analytic curves, relative to the amplitude (information)
    dev = {}
    for key, run, zeta in (("critical", crit, CRITICAL), ("10pct", ten, TEN_PERCENT)):
        a = run["analytic"]
        ref = analytic_curve(run["t"], run["amplitude"], a["omega0"], a["decay_rate"])
        dev[key] = float(np.abs(run["u"] - ref).max() / run["amplitude"])

    st = ten["state"]
    summary = {
        "status": "ok",
        "case": "two_balls",
        "backend": name,
        "dim": dim,
        "n_elements": int(st.n),
        "runs": {"critical": CRITICAL, "10pct": TEN_PERCENT},
        "steps": steps,
        "dt": float(st.dt),
        "dt_over_T0": dt_fraction,
        "sim_time": float(steps * st.dt),
        "wall_time_s": wall,
        "amplitude": float(ten["amplitude"]),
        "period": meas["T"],
        "period_analytic": an["T"],
        "period_rel_error": period_rel,
        "period_undamped_analytic": an["T0"],
        "peaks": meas["peaks"],
        "decay_rate": meas["decay_rate"],
        "decay_rate_analytic": an["decay_rate"],
        "decay_rel_error": decay_rel,
        "critical_overshoot": overshoot,
        "energy_closure_rel_error": closure,
        "max_deviation_from_analytic": dev,
        "bonds_broken": int(crit["sim"].crack_log().size + ten["sim"].crack_log().size),
        "files": ["summary.json", "history.csv"],
    }

    # history: one row per recorded step (both runs share the time axis)
    with open(out / "history.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        cols = ["time", "u_critical", "u_10pct"]
        for tag in ("critical", "10pct"):
            cols += [f"{k}_{tag}" for k in ENERGY_TERMS]
        w.writerow(cols)
        for i in range(len(ten["t"])):
            row = [repr(float(ten["t"][i])), repr(float(crit["u"][i])), repr(float(ten["u"][i]))]
            for run in (crit, ten):
                row += [repr(float(run["energies"][i][k])) for k in ENERGY_TERMS]
            w.writerow(row)

    if plot:
        png = _plot(out / "two_balls.png", crit, ten)
        if png is None:
            summary["plot"] = "skipped: matplotlib is not installed (pip install 'geodem[vis]')"
        else:
            summary["files"].append("two_balls.png")
            summary["plot"] = "two_balls.png"

    with open(out / "summary.json", "w") as fh:
        json.dump(summary, fh, indent=2)
        fh.write("\n")
    summary["out_dir"] = str(out)
    return summary


def _plot(path, crit, ten):
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:  # matplotlib missing or unusable: the plot is optional
        return None
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for run, label, col in ((crit, "critical damping", "C0"), (ten, "10 % of critical", "C1")):
        a = run["analytic"]
        ref = analytic_curve(run["t"], run["amplitude"], a["omega0"], a["decay_rate"])
        ax1.plot(run["t"], run["u"], color=col, lw=1.5, label=f"{label} (geodem)")
        ax1.plot(run["t"], ref, color="k", lw=0.8, ls="--")
    ax1.plot([], [], color="k", lw=0.8, ls="--", label="analytic")
    ax1.axhline(0.0, color="0.6", lw=0.5)
    ax1.set_ylabel("ball 1 displacement [m]")
    ax1.legend(loc="upper right")
    ax1.set_title("TwoBalls: damped oscillation against the analytic oscillator")
    for key, label, col in (("kinetic", "kinetic", "C2"), ("elastic", "elastic", "C3"),
                            ("heat_viscous", "viscous heat", "C4"), ("total", "total", "k")):
        ax2.plot(ten["t"], [e[key] for e in ten["energies"]], color=col, lw=1.5,
                 label=f"{label}, 10 %")
        ax2.plot(crit["t"], [e[key] for e in crit["energies"]], color=col, lw=1.0, ls=":",
                 label=f"{label}, critical")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("energy [J]")
    ax2.legend(loc="center right", ncol=2, fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
