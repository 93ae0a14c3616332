"""Seismic valley: ground amplification of a V-shaped valley under a vertically incident P
wave (MatDEM's seismic case, Liu et al. 2020; PHYSICS.md section 7; docs/seismic_valley.md).

The case is a composition (workflows/seismic_valley.yaml): a ``scene`` (a box with an empty V
region, ``fill: lattice`` from the corner, ``elements: elastic``: the rock's E, nu, rho on the
triangular lattice; the ground line as a ``surface`` group), the generic step ``wave_source``
(geodem.workflow.waves: the pulse through the Lysmer-Kuhlemeyer base, free-field sides, the
ground line recorded) and the step here, ``valley_amplification``, which turns the records
into the case's results:

* a flat reference column (``reference_width`` elements wide, the section's height, the same
  scene's lattice and rock, roller sides, the same pulse, base and time step) is run and
  measured (:func:`measure_column`):

  - ``p_wave_speed_rel_error``: |c_measured - c_p| / c_p, ``c_measured`` the slope of the
    arrival time (energy centroid of v_y^2 in the up-going window) against height over the
    column's receivers that see the incident pulse separated from the base and surface ones;
  - ``free_surface_amplification``: the peak |a| of the column's surface element over the mean
    incident peak |a_y| of those receivers (2 for vertical incidence);
  - ``boundary_reflection``: at the column receivers far enough from both ends, the peak |a_y|
    in the window of a wave coming back up from the base after the surface round trip
    (arrival ``t_c + (2H + y)/c_p``) over the peak |a_y| of the down-going wave (``t_c + (2H -
    y)/c_p``), largest over those receivers;

* along the ground line (the wave step's receivers), ``amplification(x) = max_t |a(x, t)| /
  A_flat``, ``A_flat`` the peak |a| at the reference column's surface, accelerations low-passed
  at 3 f and the profile averaged along the ground over half a wavelength:
  ``amplification_max`` and ``amplification_location_m`` (more than ``edge_exclusion``
  wavelengths from the sides), ``amplification_offset_m`` (from the valley axis),
  ``amplification_flat_ground`` (the median over the ground more than one wavelength from the
  valley rims and the sides, ~1 when the sides are right).

Outputs: ``seismic_receivers.npz`` (receiver positions, times, v and a histories, the column's
records), ``seismic_amplification.csv``, ``seismic_snapshots.png`` (particle speed maps from the
wave step's frames), ``seismic_surface.png`` (ground-line acceleration record and
amplification), ``seismic_reference.png`` (column: arrival times and traces) and
``seismic_animation.gif``.

Reference: Liu, C. et al. (2020) MatDEM - fast matrix computing of the discrete element method.
"""
from __future__ import annotations

import csv
import math
import time
from typing import ClassVar, Optional

import numpy as np

from geodem.cases.common import frames_gif
from geodem.fields.wave import Pulse, WaveBoundary, face_sets
from geodem.workflow.schema import F, Int, Name, StepBase, register_step
from geodem.workflow.animation import label_map, legend_outside, pick_frames, pyplot
from geodem.workflow.waves import WaveSource, wave_field

RECORDS = "seismic_receivers.npz"
AMPLIFICATION_CSV = "seismic_amplification.csv"
#: accelerations are low-passed at this multiple of the pulse frequency before their peaks are
#: taken (:func:`lowpass`)
LOWPASS = 3.0
#: the amplification profile is averaged along the ground line over this fraction of the P
#: wavelength (the staircase of a slope makes neighbouring receivers differ by ~15 %)
SMOOTH = 0.5


# ============================================================================ the column
def column_state(cfg, model, width_elements: int = 8):
    """The flat reference column of a 2-D ``scene`` ``model``: the same scene (lattice, rock,
    origin, half masses) over a box ``width_elements - 1/2`` spacings wide and as tall as the
    model's domain, without regions and groups. Returns its built state."""
    from geodem.workflow.scene import SceneBox, Shape

    lo, hi = model._bounds()
    box = SceneBox(min=[0.0, 0.0], max=[(width_elements - 0.5) * model.d,
                                        float(hi[-1] - lo[-1])])
    col = model.model_copy(update={"domain": Shape(box=box), "regions": [], "groups": {},
                                   "interfaces": "bonded"})
    return col.build(cfg).state


def run_column(st, medium: dict, pulse: Pulse, *, dt=None, dt_fraction: float = 0.05,
               backend=None, record_every: int = 1, duration=None) -> dict:
    """Run the flat reference column ``st`` (:func:`column_state`) of the lattice ``medium``:
    roller sides, the Lysmer-Kuhlemeyer base with the input ``pulse``, until the wave has come
    back up from the base after the surface round trip. Returns the records of its receivers
    (the centre column's elements of even rows, bottom to top; the last is the surface) and
    the measurements of :func:`measure_column`."""
    from geodem.core.engine import Simulation

    d = medium["d"]
    sets = face_sets(st.x, d)
    xc = st.x[sets["base"], 0][len(sets["base"]) // 2]
    line = np.flatnonzero(np.abs(st.x[:, 0] - xc) < 0.25 * d)
    line = line[np.argsort(st.x[line, 1])]
    st.free[sets["side"], sets["side_axis"]] = 0.0
    z_base, z_top = float(st.x_ref[:, 1].min()), float(st.x_ref[:, 1].max())
    sim = Simulation(st, backend=backend, dt=dt, dt_fraction=dt_fraction, monitor_every=0)
    field = WaveBoundary(medium["rho"], medium["cp"], medium["cs"], medium["k0"],
                         medium["pitch"], medium["thickness"], z_base, z_top, pulse.config(),
                         sides="roller", record_every=record_every)
    field.set_sets(sets, line, st)
    sim.add_field(field)
    H = z_top - z_base
    if duration is None:
        duration = pulse.t_c + 2.5 * H / medium["cp"] + 1.5 * pulse.half
    nsteps = int(math.ceil(duration / sim.state.dt))
    sim.run(nsteps)
    t, v, a_raw = field.records()
    a = lowpass(a_raw, t, LOWPASS * pulse.f)
    y = st.x_ref[line, 1] - z_base
    out = measure_column(t, y, v, a, H, medium["cp"], pulse)
    out.update({"t": t, "y": y, "v": v, "a": a, "height": H, "elements": int(st.n),
                "steps": nsteps, "dt": sim.state.dt,
                "energy_closure_error": sim.energies()["closure_error"]})
    return out


def lowpass(a, t, fc: float, order: int = 4):
    """Zero-phase Butterworth low-pass (``order``, cut-off ``fc`` [Hz]) of records ``a`` (time
    along axis 0, samples ``t`` equally spaced): removes the lattice's own high-frequency ringing
    (staircase corners of the slopes ring at ~ c / d) from the peak accelerations."""
    from scipy.signal import butter, sosfiltfilt

    if len(t) < 4 * order + 4:
        return np.asarray(a, float)
    fs = 1.0 / float(t[1] - t[0])
    if fc >= 0.45 * fs:
        return np.asarray(a, float)
    sos = butter(order, fc, fs=fs, output="sos")
    return sosfiltfilt(sos, np.asarray(a, float), axis=0)


def ground_smooth(xr, values, width: float):
    """Running mean of ``values`` at the ground-line points ``xr`` over ``width`` [m] of arc
    length along the line (points ordered by x)."""
    order = np.argsort(xr[:, 0], kind="stable")
    p = xr[order]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    lo = np.searchsorted(s, s - 0.5 * width, side="left")
    hi = np.searchsorted(s, s + 0.5 * width, side="right")
    c = np.concatenate([[0.0], np.cumsum(np.asarray(values, float)[order])])
    out = np.empty(len(values))
    out[order] = (c[hi] - c[lo]) / (hi - lo)
    return out


def _window(t, centre, half):
    return (t >= centre - half) & (t <= centre + half)


def measure_column(t, y, v, a, H, cp, pulse) -> dict:
    """Wave speed, free-surface amplification and base reflection of a flat column's records
    (``t (K,)``, receiver heights ``y (R,)`` above the base row, ``v``, ``a`` ``(K, R, 2)``;
    the last receiver is the surface). Definitions in the module docstring."""
    w = pulse.half * 1.05 + 2.0 * (t[1] - t[0] if len(t) > 1 else 0.0)
    tc = pulse.t_c
    # receivers whose incident window is clear of the base start and of the surface reflection
    sep_in = (y / cp >= w) & ((2.0 * H - 2.0 * y) / cp >= 2.0 * w)
    arrival, inc = [], []
    for k in np.flatnonzero(sep_in):
        win = _window(t, tc + y[k] / cp, w)
        e = v[win, k, 1] ** 2
        arrival.append(float((t[win] * e).sum() / e.sum()))
        inc.append(float(np.abs(a[win, k, 1]).max()))
    sel = np.flatnonzero(sep_in)
    if len(sel) < 3:
        raise ValueError("the column is too short for this pulse: fewer than 3 receivers see "
                         "the incident wave apart from the base and the surface (make it "
                         "taller than about 2.5 wavelengths)")
    slope, icpt = np.polyfit(y[sel], arrival, 1)
    c_meas = 1.0 / slope
    a_inc = float(np.mean(inc))
    top = len(y) - 1
    win = _window(t, tc + y[top] / cp, 2.0 * w)
    a_surf = float(np.linalg.norm(a[win, top], axis=1).max())
    v_surf = float(np.abs(v[win, top, 1]).max())
    v_inc = float(np.mean([np.abs(v[_window(t, tc + y[k] / cp, w), k, 1]).max() for k in sel]))
    # base reflection: the down-going wave and what comes back up
    sep_r = (2.0 * y / cp >= 2.0 * w) & ((2.0 * H - 2.0 * y) / cp >= 2.0 * w) & \
        (tc + (2.0 * H + y) / cp + w <= t[-1])
    refl = []
    for k in np.flatnonzero(sep_r):
        down = np.abs(a[_window(t, tc + (2.0 * H - y[k]) / cp, w), k, 1]).max()
        back = np.abs(a[_window(t, tc + (2.0 * H + y[k]) / cp, w), k, 1]).max()
        refl.append(float(back / down))
    return {"p_wave_speed_analytic": cp, "p_wave_speed_measured": float(c_meas),
            "p_wave_speed_rel_error": float(abs(c_meas - cp) / cp),
            "arrival_receivers": int(len(sel)), "arrival_heights": y[sel].tolist(),
            "arrival_times": arrival, "arrival_intercept": float(icpt),
            "incident_peak_acceleration": a_inc, "surface_peak_acceleration": a_surf,
            "free_surface_amplification": a_surf / a_inc,
            "free_surface_amplification_velocity": v_surf / v_inc,
            "incident_peak_velocity": v_inc,
            "boundary_reflection": float(max(refl)) if refl else None,
            "reflection_receivers": int(len(refl))}


# ============================================================================ step
@register_step("valley_amplification")
class ValleyAmplification(StepBase):
    """The seismic valley's results from a ``wave_source`` step's ground-line records: a flat
    reference column of the same scene measures the P-wave speed, the free-surface
    amplification and the base reflection, then the amplification along the ground (module
    docstring). Adds amplification_max, amplification_location_m, p_wave_speed_rel_error,
    free_surface_amplification, boundary_reflection and amplification_flat_ground to
    summary.json; writes seismic_receivers.npz, seismic_amplification.csv,
    seismic_snapshots.png, seismic_surface.png, seismic_reference.png and
    seismic_animation.gif."""

    example = {"kind": "valley_amplification", "reference": False, "gif": False,
               "snapshots": 2}
    example_model = WaveSource.example_model
    #: the steps its example needs before it (the contract test puts them first)
    example_before: ClassVar[list] = [dict(WaveSource.example, frames=2)]
    wave: Optional[Name] = F(None, description="The wave_source step whose records are used "
                                               "(default: the last one before this step)")
    valley_x: Optional[float] = F(None, unit="m", description="x of the valley axis (default: "
                                                              "the middle of the section)")
    valley_width: float = F(0.0, unit="m", ge=0, description="Width of the valley at the "
                                                             "ground line (0: flat ground)")
    reference: bool = F(True, description="Run the flat reference column (wave speed, "
                                          "free-surface amplification, base reflection and the "
                                          "flat-ground peak acceleration)")
    reference_width: Int = F(8, ge=3, le=200, description="Width of the reference column "
                                                          "[elements]")
    snapshots: Int = F(6, ge=1, le=12, description="Particle-speed maps in "
                                                   "seismic_snapshots.png")
    gif: bool = F(True, description="Write seismic_animation.gif (from the wave step's frames)")
    edge_exclusion: float = F(1.5, ge=0, le=10,
                              description="amplification_max is searched on the ground more "
                                          "than this many P wavelengths from the sides")
    plot: bool = F(True, description="Draw the pictures (needs matplotlib)")

    def _wave_step(self, cfg):
        k = next((i for i, s in enumerate(cfg.steps) if s is self), len(cfg.steps))
        waves = [s for s in cfg.steps[:k] if s.kind == "wave_source"]
        if self.wave is not None:
            waves = [s for s in waves if s.name == self.wave]
        return waves[-1] if waves else None

    def check(self, cfg, groups):
        out = []
        if cfg.model.dim != 2:
            out.append((("kind",), "valley_amplification reads a 2-D section's ground line"))
        w = self._wave_step(cfg)
        if w is None:
            out.append((("wave",) if self.wave else ("kind",),
                        f"no wave_source step{' named ' + repr(self.wave) if self.wave else ''}"
                        f" before this step; add one (with receivers: the ground line)"))
        elif w.receivers is None:
            out.append((("wave",), f"the wave_source step {w.name!r} records no receivers; give "
                                   f"it receivers: a surface group (e.g. {{surface: ymax}})"))
        return out

    def planned_steps(self, plan):
        return 0

    def execute(self, ctx):
        field = wave_field(ctx.sim)
        if field is None:
            raise ValueError(f"step {self.name!r}: no wave boundary is attached (run a "
                             f"wave_source step first)")
        wave = self._wave_step(ctx.cfg)
        info = ctx.model.info
        med = info["medium"]
        pulse = Pulse(**field.pulse_cfg)
        ref, ref_note = None, None
        if field.incidence != "base":
            ref_note = (f"no reference column: the wave enters through {field.incidence} (the "
                        "column is the flat ground under a wave from the base); the flat "
                        "ground before the valley is the reference")
        elif self.reference:
            t0 = time.perf_counter()
            try:
                st = column_state(ctx.cfg, ctx.cfg.model, self.reference_width)
                ref = run_column(st, med, pulse, dt=ctx.state.dt,
                                 backend=ctx.runner.prep.backend,
                                 record_every=field.record_every)
                ref["wall_s"] = time.perf_counter() - t0
            except ValueError as exc:
                ref_note = f"reference column not measured: {exc}"
                ctx.log(ref_note)
        return self._results(ctx, field, ref, ref_note, pulse, float(info["d"]),
                             ctx.out_dir / f"{wave.name}_frames")

    def _results(self, ctx, field, ref, ref_note, pulse, d, fdir):
        med = ctx.model.info["medium"]
        t, v, a_raw = field.records()
        a = lowpass(a_raw, t, LOWPASS * pulse.f)
        rec = field.sets["receivers"]
        ref_x = ctx.model.reference
        x_min, x_max = float(ref_x[:, 0].min()), float(ref_x[:, 0].max())
        xr = ref_x[rec]
        peak_a = np.linalg.norm(a, axis=2).max(axis=0) if len(t) else np.zeros(len(rec))
        peak_v = np.linalg.norm(v, axis=2).max(axis=0) if len(t) else np.zeros(len(rec))
        lam = med["cp"] / pulse.f
        xc = 0.5 * (x_min + x_max) if self.valley_x is None else float(self.valley_x)
        hw = 0.5 * self.valley_width
        tt = np.linspace(0.0, pulse.duration, 4001)
        a_inc = float(np.abs(np.gradient(pulse(tt), tt)).max())
        front = (xr[:, 0] >= x_min + self.edge_exclusion * lam) & (xr[:, 0] < xc - hw - lam)
        if ref is not None:
            a_flat, flat_src = ref["surface_peak_acceleration"], "flat reference column"
        elif field.incidence != "base" and front.any():
            a_flat = float(np.median(peak_a[front]))
            flat_src = (f"flat ground before the valley (median of {int(front.sum())} "
                        "receivers)")
        elif field.incidence != "base":
            a_flat, flat_src = a_inc, "analytic (the incident peak acceleration)"
        else:  # analytic: twice the incident peak acceleration
            a_flat, flat_src = 2.0 * a_inc, "analytic (2 x incident peak acceleration)"
        amp_raw = peak_a / a_flat
        amp = ground_smooth(xr, amp_raw, SMOOTH * lam)
        edge = self.edge_exclusion * lam
        inner = (xr[:, 0] >= x_min + edge) & (xr[:, 0] <= x_max - edge)
        if not inner.any():
            inner[:] = True
        k = int(np.flatnonzero(inner)[np.argmax(amp[inner])])
        far = (np.abs(xr[:, 0] - xc) > hw + lam) & (xr[:, 0] > x_min + lam) & \
            (xr[:, 0] < x_max - lam)
        with open(ctx.out_dir / AMPLIFICATION_CSV, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(("x", "y", "peak_acceleration", "peak_velocity", "amplification_receiver",
                        "amplification"))
            w.writerows(np.column_stack([xr, peak_a, peak_v, amp_raw, amp]).tolist())
        rx = {"receiver_x": xr, "t": t, "v": v, "a": a_raw, "a_lowpass": a}
        if ref is not None:
            rx.update({"column_y": ref["y"], "column_t": ref["t"], "column_v": ref["v"],
                       "column_a": ref["a"]})
        np.savez_compressed(ctx.out_dir / RECORDS, **rx)
        ref_keys = ("p_wave_speed_rel_error", "free_surface_amplification",
                    "boundary_reflection")
        res = {
            "amplification_max": float(amp[k]),
            "amplification_location_m": float(xr[k, 0]),
            "amplification_location_y_m": float(xr[k, 1]),
            "amplification_offset_m": float(xr[k, 0] - xc),
            "amplification_max_receiver": float(amp_raw[inner].max()),
            "amplification_max_whole_line": float(amp.max()),
            "amplification_whole_line_location_m": float(xr[int(np.argmax(amp)), 0]),
            "edge_exclusion_m": edge,
            "amplification_smoothing_m": SMOOTH * lam,
            "amplification_flat_ground": float(np.median(amp[far])) if far.any() else None,
            "flat_peak_acceleration": float(a_flat), "flat_peak_acceleration_source": flat_src,
            "p_wave_speed_analytic": med["cp"], "s_wave_speed_analytic": med["cs"],
            "pulse": pulse.config(), "wavelength_m": lam, "receivers": int(len(rec)),
            "incidence": field.incidence,
        }
        res.update(slope_maxima(xr, amp, xc, hw))
        for key in ref_keys:
            res[key] = ref[key] if ref is not None else None
        if ref is not None:
            res["reference"] = {k: v for k, v in ref.items() if not isinstance(v, np.ndarray)}
        else:
            res["reference_note"] = ref_note or "reference: false"
        ctx.summary.update({key: res[key] for key in
                            ("amplification_max", "amplification_location_m") + ref_keys})
        ctx.summary["amplification_flat_ground"] = res["amplification_flat_ground"]
        for side in ("left", "right"):
            key = f"amplification_{side}_slope_max"
            if key in res:
                ctx.summary[key] = res[key]

        def fmt(v, f=".3g"):
            return "n/a" if v is None else format(v, f)

        ctx.log(f"seismic valley: amplification max {amp[k]:.3g} at x = {xr[k, 0]:.1f} m "
                f"(flat ground {fmt(res['amplification_flat_ground'])}); reference: c_p error "
                f"{fmt(res['p_wave_speed_rel_error'])}, free-surface amplification "
                f"{fmt(res['free_surface_amplification'])}, base reflection "
                f"{fmt(res['boundary_reflection'])}")
        if self.plot and ctx.cfg.outputs.plots:
            frames = sorted(fdir.glob("frame_*.npz"))
            vmax = 2.0 * pulse.amp
            res["plot_snapshots"] = ctx.plot("seismic_snapshots.png", lambda p: plot_snapshots(
                p, frames, self.snapshots, d, vmax))
            res["plot_surface"] = ctx.plot("seismic_surface.png", lambda p: plot_surface(
                p, t, a, xr, amp, amp_raw))
            if ref is not None:
                res["plot_reference"] = ctx.plot("seismic_reference.png",
                                                 lambda p: plot_reference(p, ref, pulse))
            if self.gif:
                from geodem.workflow.animation import gif_writer_missing

                why = gif_writer_missing()
                if why:
                    res["animation"] = f"skipped: {why}"
                    ctx.runner.plots["seismic_animation.gif"] = res["animation"]
                else:
                    res["animation"] = ctx.plot("seismic_animation.gif", lambda p: write_gif(
                        p, frames, d, vmax))
        return res


def slope_maxima(xr, amp, xc: float, half_width: float) -> dict:
    """The largest (smoothed) amplification on each slope of the valley (receivers within
    ``half_width`` of the axis ``xc``, left and right of it), where it is, and how deep:
    ``depth_fraction`` = (ground - y) / (ground - valley bottom), 0 at the rim, 1 at the
    bottom. Empty for a flat ground (``half_width`` 0)."""
    if half_width <= 0.0:
        return {}
    ground, bottom = float(xr[:, 1].max()), float(xr[:, 1].min())
    depth = max(ground - bottom, 1e-300)
    out = {}
    for side, on in (("left", (xr[:, 0] > xc - half_width) & (xr[:, 0] < xc)),
                     ("right", (xr[:, 0] >= xc) & (xr[:, 0] < xc + half_width))):
        if not on.any():
            continue
        k = int(np.flatnonzero(on)[np.argmax(amp[on])])
        out[f"amplification_{side}_slope_max"] = float(amp[k])
        out[f"amplification_{side}_slope_location_m"] = float(xr[k, 0])
        out[f"amplification_{side}_slope_depth_fraction"] = float((ground - xr[k, 1]) / depth)
    return out


# ============================================================================ pictures

def _speed_map(ax, z, d, vmax, title=True):
    x = z["x"].astype(float)
    lo, hi = x.min(axis=0) - d, x.max(axis=0) + d
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    fig = ax.figure
    bbox = ax.get_window_extent().transformed(fig.dpi_scale_trans.inverted())
    pts = bbox.width * 72.0 / (hi[0] - lo[0]) * d  # one spacing in points
    sc = ax.scatter(x[:, 0], x[:, 1], c=z["speed"], s=(1.05 * pts) ** 2, marker="h",
                    linewidths=0, cmap="magma", vmin=0.0, vmax=vmax)
    label_map(ax, fontsize=7)
    if title:
        ax.set_title(f"t = {float(z['time']) * 1e3:.1f} ms", fontsize=8)
    return sc


def plot_snapshots(path, frames, n, d, vmax):
    """Maps of the particle speed |v| at ``n`` times spread over the run."""
    plt = pyplot()
    if plt is None:
        return None
    if not frames:
        return None
    pick = pick_frames(frames, n)
    data = [np.load(frames[k]) for k in pick]
    x = data[0]["x"]
    aspect = float(np.ptp(x[:, 1]) / max(np.ptp(x[:, 0]), 1e-300))
    cols = 2 if len(data) > 1 else 1
    rws = int(math.ceil(len(data) / cols))
    fig, axes = plt.subplots(rws, cols, figsize=(3.6 * cols + 0.8, 3.6 * aspect * rws + 0.5),
                             squeeze=False, layout="constrained")
    sc = None
    for ax, z in zip(axes.ravel(), data):
        sc = _speed_map(ax, z, d, vmax)
    for ax in axes.ravel()[len(data):]:
        ax.axis("off")
    fig.colorbar(sc, ax=axes.ravel().tolist(), label="particle speed |v| [m/s]", shrink=0.8)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_surface(path, t, a, xr, amp, amp_raw=None):
    """Ground-line record (|a| against x and time) and the amplification along the ground."""
    plt = pyplot()
    if plt is None:
        return None
    if len(t) == 0:
        return None
    order = np.argsort(xr[:, 0])
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, layout="constrained")
    mag = np.linalg.norm(a, axis=2)[:, order]
    im = ax1.pcolormesh(xr[order, 0], t * 1e3, mag, cmap="viridis", shading="nearest")
    fig.colorbar(im, ax=ax1, label="|a| [m/s$^2$]")
    ax1.set_ylabel("time [ms]")
    ax1.set_title("ground-line acceleration")
    if amp_raw is not None:
        ax2.plot(xr[order, 0], amp_raw[order], "-", color="C3", alpha=0.3, lw=0.7,
                 label="single receivers")
    ax2.plot(xr[order, 0], amp[order], "C3-", lw=1.4, label="amplification (smoothed)")
    ax2.axhline(1.0, color="k", lw=0.8, ls=":")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("peak |a| / flat free surface")
    ax3 = ax2.twinx()
    ax3.plot(xr[order, 0], xr[order, 1], color="0.6", lw=1, label="ground line")
    ax3.set_ylabel("ground elevation [m]", color="0.5")
    k = int(np.argmax(amp))
    ax2.plot([xr[k, 0]], [amp[k]], "k^", label=f"max {amp[k]:.2f} at x = {xr[k, 0]:.0f} m")
    h1, l1 = ax2.get_legend_handles_labels()
    h2, l2 = ax3.get_legend_handles_labels()
    legend_outside(ax2, h1 + h2, l1 + l2, fontsize=8, side="top")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_reference(path, ref, pulse):
    """The flat column: vertical velocity traces against height and the arrival-time fit."""
    plt = pyplot()
    if plt is None:
        return None
    t, y, v = ref["t"], ref["y"], ref["v"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 4.2), layout="constrained")
    step = max(1, len(y) // 12)
    gain = 0.8 * step * float(np.diff(y).mean()) / max(pulse.amp, 1e-300)
    for k in range(0, len(y), step):
        ax1.plot(t * 1e3, y[k] + gain * v[:, k, 1], "k-", lw=0.7)
    ax1.set_xlabel("time [ms]")
    ax1.set_ylabel("height above the base [m] (trace: v$_y$)")
    ax1.set_title(f"flat column: A$_{{surface}}$/A$_{{inc}}$ = "
                  f"{ref['free_surface_amplification']:.3f}, reflection "
                  f"{ref['boundary_reflection'] if ref['boundary_reflection'] is not None else float('nan'):.3f}",
                  fontsize=9)
    hy, ht = np.asarray(ref["arrival_heights"]), np.asarray(ref["arrival_times"])
    ax2.plot(hy, ht * 1e3, "o", ms=4, label="arrival (energy centroid)")
    c = ref["p_wave_speed_analytic"]
    ax2.plot(hy, (ref["arrival_intercept"] + hy / ref["p_wave_speed_measured"]) * 1e3, "C0-",
             label=f"fit: c = {ref['p_wave_speed_measured']:.0f} m/s")
    ax2.plot(hy, (pulse.t_c + hy / c) * 1e3, "k--", lw=1, label=f"c_p = {c:.0f} m/s")
    ax2.set_xlabel("height above the base [m]")
    ax2.set_ylabel("arrival time [ms]")
    ax2.legend(fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write_gif(path, frames, d, vmax):
    """Animation of the particle-speed maps (Pillow, else imageio; None when
    neither can write a GIF)."""
    if pyplot() is None or not frames:
        return None
    x = np.load(frames[0])["x"]
    aspect = float(np.ptp(x[:, 1]) / max(np.ptp(x[:, 0]), 1e-300))
    return frames_gif(path, frames, (6.0, 6.0 * aspect + 0.4),
                      lambda ax, f: _speed_map(ax, np.load(f), d, vmax), fps=8)


__all__ = ["ValleyAmplification", "column_state", "run_column", "measure_column", "lowpass",
           "ground_smooth", "slope_maxima"]
