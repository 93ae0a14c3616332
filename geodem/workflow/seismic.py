"""Seismic valley: a P wave from the base of a 2-D bonded rock section with a V-shaped valley,
absorbing (viscous) boundaries, surface receivers and the amplification of ground acceleration
(MatDEM's seismic case, Liu et al. 2020; PHYSICS.md section 7; docs/seismic_valley.md).

* model ``valley_section``: a regular triangular lattice (rows along x, spacing ``d / scale``)
  filling ``width x height`` (m), cut by a V-shaped valley (``valley_width`` at the ground line,
  ``valley_depth`` deep, centred at ``valley_x``; ``valley_depth: 0`` is a flat section); elements
  left with fewer than two bonds are dropped. The rock is an elastic medium of Young's modulus
  ``E``, Poisson's ratio ``nu`` and density ``rho`` (given, or a library / rock-property material):
  on the regular lattice these map exactly onto bonds (VALIDATION.md, 2-D triangular lattice of
  thickness ``t = d``)::

      Kn = E t / (sqrt3 (1 - nu)),   Ks = Kn (1 - 3 nu) / (1 + nu)    (-1 < nu <= 1/3)
      m  = rho (sqrt3 / 2) d^2 t                                     (the element's cell)

  element values ``kn = 2 Kn``, ``ks = 2 Ks``; bonds never break (an elastic wave problem).
  The 2-D medium's P-wave (constrained) modulus is ``M = lambda + 2 mu = E / (1 - nu^2)`` and
  its shear modulus ``G = E / (2 (1 + nu))``, so

      c_p = sqrt(M / rho) = sqrt(E / ((1 - nu^2) rho)),   c_s = sqrt(G / rho).

  Groups: ``base`` (bottom row), ``sides`` (left and right columns), ``surface`` (the ground
  line: the top element of every d-wide strip along x) and ``rock`` (the rest).

* coupled field ``seismic_boundary`` (:class:`SeismicBoundary`, every mechanical step): the
  Lysmer-Kuhlemeyer viscous boundary and the input. On each boundary element of tributary length
  ``L`` (base: ``d``; sides: the row spacing ``d sqrt3 / 2``), area ``A = L t``:

      base:  F_y = rho c_p A (2 v_in(t) - v_y),   F_x = -rho c_s A v_x
      sides (free_field): F_n = -rho c_p A v_n + sigma_xx^ff n_x A,
                          F_t = rho c_s A (v_y^ff(y, t) - v_y)

  so the base injects an up-going plane P wave of particle velocity ``v_in`` and absorbs what
  comes down; the sides absorb what leaves the section relative to the analytic free field of a
  flat ground (incident plus surface-reflected wave, ``v_y^ff = v_in(t - y/c_p) + v_in(t -
  (2H - y)/c_p)``, ``sigma_yy^ff = -rho c_p (v_in(t - y/c_p) - v_in(t - (2H - y)/c_p))``,
  ``sigma_xx^ff = nu sigma_yy^ff``). ``sides: absorbing`` drops the free field (plain dashpots),
  ``roller`` fixes the side elements horizontally (exact for a flat section: uniaxial strain).
  The forces go into ``fload`` (their work is booked as external work). The field also records
  the velocity and acceleration (``State.a``) of the receivers every ``record_every`` steps.

* step ``seismic_wave``: a flat reference column (``reference_width`` elements wide, roller
  sides, the section's far-field height, same lattice, pulse and base) is run first and measured
  (:func:`measure_column`), then the section itself (global damping off). Results (summary.json):

  - ``p_wave_speed_rel_error``: |c_measured - c_p| / c_p, ``c_measured`` the slope of the arrival
    time (energy centroid of v_y^2 in the up-going window) against height over the column's
    receivers that see the incident pulse separated from the base and surface ones;
  - ``free_surface_amplification``: the peak |a| of the column's surface element over the mean
    incident peak |a_y| of those receivers (2 for vertical incidence);
  - ``boundary_reflection``: at the column receivers far enough from both ends, the peak |a_y| in
    the window of a wave coming back up from the base after the surface round trip (arrival
    ``t_c + (2H + y)/c_p``) over the peak |a_y| of the down-going wave (``t_c + (2H - y)/c_p``),
    largest over those receivers;
  - ``amplification_max``, ``amplification_location_m``: along the ground line of the section,
    ``amplification(x) = max_t |a(x, t)| / A_flat``, ``A_flat`` the peak |a| at the flat
    reference column's surface; its largest value and the x [m] of that receiver
    (``amplification_offset_m``: from the valley axis; ``amplification_flat_ground``: the median
    over the ground more than one wavelength from the valley rims and the sides, ~1 when the
    sides are right).

  Outputs: ``seismic_receivers.npz`` (receiver positions, times, v and a histories),
  ``seismic_amplification.csv``, ``seismic_snapshots.png`` (particle speed maps),
  ``seismic_surface.png`` (ground-line acceleration record and amplification),
  ``seismic_reference.png`` (column: arrival times and traces), ``seismic_animation.gif`` and
  ``seismic_vtk/`` (.vtp frames and a .pvd collection, ParaView).

Reference: Lysmer, J., Kuhlemeyer, R. L. (1969) Finite dynamic model for infinite media, J. Eng.
Mech. Div. ASCE 95(EM4), 859-877; Liu, C. et al. (2020) MatDEM - fast matrix computing of the
discrete element method.
"""
from __future__ import annotations

import csv
import math
from typing import Literal, Optional

import numpy as np
from pydantic import PrivateAttr

from geodem.fields import CoupledField, register_field
from geodem.workflow.models import BuildError, BuiltModel, state_bytes_per_element
from geodem.workflow.schema import F, Int, ModelBase, Name, StepBase, register_model, \
    register_step

SQRT3 = math.sqrt(3.0)
FRAMES_DIR = "seismic_frames"
VTK_DIR = "seismic_vtk"
RECORDS = "seismic_receivers.npz"
AMPLIFICATION_CSV = "seismic_amplification.csv"


# ============================================================================ the medium
def lattice_medium(E: float, nu: float, rho: float, d: float) -> dict:
    """Bond and element parameters of a triangular lattice (spacing ``d``, thickness ``t = d``)
    that is the plane elastic medium ``E, nu, rho``, and its wave speeds (module docstring)."""
    if not -1.0 < nu <= 1.0 / 3.0:
        raise ValueError(f"nu = {nu:g}: the triangular lattice reaches -1 < nu <= 1/3")
    t = d
    Kn = E * t / (SQRT3 * (1.0 - nu))
    Ks = Kn * (1.0 - 3.0 * nu) / (1.0 + nu)
    m = rho * 0.5 * SQRT3 * d * d * t
    M = E / (1.0 - nu * nu)
    G = E / (2.0 * (1.0 + nu))
    return {"E": E, "nu": nu, "rho": rho, "d": d, "thickness": t, "Kn": Kn, "Ks": Ks,
            "kn": 2.0 * Kn, "ks": 2.0 * Ks, "mass": m, "M": M, "G": G,
            "cp": math.sqrt(M / rho), "cs": math.sqrt(G / rho)}


def lattice_E_nu(Kn: float, Ks: float, t: float) -> tuple[float, float]:
    """``(E, nu)`` of the triangular lattice from its bond stiffnesses (VALIDATION.md)."""
    return (2.0 * SQRT3 * Kn * (Kn + Ks) / (t * (3.0 * Kn + Ks)),
            (Kn - Ks) / (3.0 * Kn + Ks))


# ============================================================================ the pulse
class Pulse:
    """Particle-velocity time function of the incident wave: ``ricker`` (peak ``amplitude`` at
    ``t_c = 1.2 / frequency``, support ``[0, 2 t_c]``) or ``sine`` (``cycles`` periods of a sine
    under a Hann window, support ``[0, cycles / frequency]``)."""

    def __init__(self, kind: str, frequency: float, amplitude: float, cycles: float = 2.0):
        self.kind, self.f, self.amp, self.cycles = kind, float(frequency), float(amplitude), \
            float(cycles)
        if kind == "ricker":
            self.t_c = 1.2 / self.f
            self.duration = 2.0 * self.t_c
        elif kind == "sine":
            self.duration = self.cycles / self.f
            self.t_c = 0.5 * self.duration
        else:
            raise ValueError(f"pulse {kind!r}: allowed ricker, sine")
        self.half = 0.5 * self.duration  # half-width of its window around t_c

    def config(self) -> dict:
        return {"kind": self.kind, "frequency": self.f, "amplitude": self.amp,
                "cycles": self.cycles}

    def __call__(self, t):
        t = np.asarray(t, float)
        if self.kind == "ricker":
            u = (math.pi * self.f * (t - self.t_c)) ** 2
            out = self.amp * (1.0 - 2.0 * u) * np.exp(-u)
        else:
            on = (t > 0) & (t < self.duration)
            out = np.where(on, self.amp * np.sin(2 * math.pi * self.f * t)
                           * np.sin(math.pi * t / self.duration) ** 2, 0.0)
        return out


# ============================================================================ the section
def section_points(width, height, d, valley_width=0.0, valley_depth=0.0, valley_x=None):
    """Centres of the triangular lattice filling ``[0, width] x [0, height]`` minus the V valley
    (a :class:`geodem.build.shapes.Polygon` cut from the box), elements with fewer than two
    contacts dropped repeatedly. Returns ``(x, y_top)``, ``y_top`` the ground line of the flat
    part (the top row)."""
    from geodem.build.lattice import contact_pairs, triangular_lattice
    from geodem.build.shapes import Box, Polygon

    h = 0.5 * SQRT3 * d
    nx = int(math.floor(width / d + 1e-9)) + 1
    ny = int(math.floor(height / h + 1e-9)) + 1
    x = triangular_lattice(nx, ny, d)
    x = x[x[:, 0] <= width + 1e-9 * d]
    y_top = float(x[:, 1].max())
    shape = Box((-d, -d), (width + d, y_top + d))
    if valley_depth > 0:
        xc = 0.5 * width if valley_x is None else valley_x
        over = 2.0 * d  # the V's sides carried on above the ground line
        s = 0.5 * valley_width / valley_depth
        bottom = y_top - valley_depth
        top = y_top + over
        shape = shape - Polygon(((xc - s * (top - bottom), top), (xc + s * (top - bottom), top),
                                 (xc, bottom)))
    x = x[shape.mask(x)]
    while True:
        i, j = contact_pairs(x, 0.5 * d, gap=1e-6 * d)
        count = np.bincount(np.concatenate([i, j]), minlength=len(x))
        short = count < 2
        if not short.any():
            break
        x = x[~short]
    return x, y_top


def boundary_sets(x, d):
    """Index sets of a section: ``base`` (bottom row), ``left``, ``right`` (the outer columns:
    both row parities) and ``surface`` (the top element of every d-wide strip along x)."""
    lo, hi = x.min(axis=0), x.max(axis=0)
    tol = 1e-6 * d
    base = np.flatnonzero(x[:, 1] <= lo[1] + tol)
    left = np.flatnonzero(x[:, 0] <= lo[0] + 0.5 * d + tol)
    right = np.flatnonzero(x[:, 0] >= hi[0] - 0.5 * d - tol)
    strip = np.floor((x[:, 0] - lo[0]) / d + 1e-6).astype(np.int64)
    order = np.lexsort((x[:, 1], strip))  # by strip, then height: the last of each strip is top
    s = strip[order]
    last = np.r_[s[1:] != s[:-1], True]
    surface = np.sort(order[last])
    return {"base": base, "left": left, "right": right, "surface": surface}


def build_section(medium: dict, width, height, valley_width=0.0, valley_depth=0.0,
                  valley_x=None):
    """The bonded section (a :class:`State`, elements in Morton order) and its geometry:
    ``(state, info)``; groups ``rock``, ``surface``, ``sides``, ``base``."""
    from geodem.build.lattice import bonded_state
    from geodem.core import groups as grp
    from geodem.core.neighbors import spatial_sort

    d = medium["d"]
    x, y_top = section_points(width, height, d, valley_width, valley_depth, valley_x)
    st = bonded_state(x, 0.5 * d, density=medium["rho"], kn=medium["kn"], ks=medium["ks"],
                      xb=1.0e6 * d, fs0=1.0e30, mu=0.5, gap=1e-6 * d,
                      thickness=medium["thickness"])
    st.m[:] = medium["mass"]
    lo, hi = st.x.min(axis=0), st.x.max(axis=0)
    tol = 1e-6 * d
    # elements centred on the side planes own half a lattice cell (they miss the two diagonal
    # bonds beyond the plane): half the mass keeps their vertical frequency that of the
    # interior, as if the model were mirrored there (a full mass slows a narrow column's wave
    # by ~5 %). The base row keeps its full mass (halving it changed the base reflection
    # little and halves the time step).
    on_plane = (np.abs(st.x[:, 0] - lo[0]) < tol) | (np.abs(st.x[:, 0] - hi[0]) < tol)
    st.m[on_plane] *= 0.5
    spatial_sort(st)
    sets = boundary_sets(st.x, d)
    st.groups = {"all": 0}
    st.group[:] = 0
    grp.add_group(st, "rock", np.arange(st.n))
    st.group[:] = 0
    grp.add_group(st, "surface", sets["surface"])
    sides = np.zeros(st.n, bool)
    sides[sets["left"]] = sides[sets["right"]] = True
    sides[sets["base"]] = False
    st.group[sides] = 0
    grp.add_group(st, "sides", sides)
    st.group[sets["base"]] = 0
    grp.add_group(st, "base", sets["base"])
    st.group[st.group == 0] = st.groups["rock"]
    xc = 0.5 * width if valley_x is None else float(valley_x)
    info = {"diameter": d, "thickness": medium["thickness"], "width": float(width),
            "height": float(height), "y_base": float(st.x[:, 1].min()), "y_top": y_top,
            "x_min": float(st.x[:, 0].min()), "x_max": float(st.x[:, 0].max()),
            "valley_width": float(valley_width), "valley_depth": float(valley_depth),
            "valley_x": xc,
            "medium": {k: medium[k] for k in ("E", "nu", "rho", "Kn", "Ks", "kn", "ks",
                                              "mass", "M", "G", "cp", "cs")}}
    return st, info


# ============================================================================ the boundary
@register_field("seismic_boundary")
class SeismicBoundary(CoupledField):
    """Lysmer-Kuhlemeyer viscous boundary with the base input and the receivers (module
    docstring). Index sets are set with :meth:`set_sets` (fresh) or :meth:`restore`."""

    reads = {"v": "m/s", "a": "m/s^2", "x_ref": "m"}
    writes = {"fload": "N"}

    def __init__(self, rho, cp, cs, nu, thickness, d, y_base, y_top, pulse: dict,
                 sides="free_field", record_every=2, t_start=0.0, every=1):
        super().__init__(every)
        if sides not in ("free_field", "absorbing", "roller"):
            raise ValueError(f"sides {sides!r}: allowed free_field, absorbing, roller")
        self.rho, self.cp, self.cs, self.nu = float(rho), float(cp), float(cs), float(nu)
        self.t, self.d = float(thickness), float(d)
        self.y_base, self.y_top = float(y_base), float(y_top)
        self.pulse_cfg = dict(pulse)
        self.pulse = Pulse(**pulse)
        self.sides = sides
        self.record_every = int(record_every)
        self.t_start = float(t_start)
        self.sets = {k: np.zeros(0, np.int64) for k in ("base", "left", "right", "receivers")}
        self.rec_t, self.rec_v, self.rec_a = [], [], []

    # -- contract
    def attach(self, sim) -> None:
        self._prepare(sim.state)

    def stable_dt(self, sim) -> float:
        return math.inf

    def substep(self, sim, h) -> None:  # pragma: no cover - advance is overridden
        pass

    def config(self) -> dict:
        return {"rho": self.rho, "cp": self.cp, "cs": self.cs, "nu": self.nu,
                "thickness": self.t, "d": self.d, "y_base": self.y_base, "y_top": self.y_top,
                "pulse": self.pulse_cfg, "sides": self.sides, "record_every": self.record_every,
                "t_start": self.t_start, "every": self.every}

    def arrays(self) -> dict:
        out = {f"set_{k}": v for k, v in self.sets.items()}
        n = len(self.sets["receivers"])
        out["rec_t"] = np.asarray(self.rec_t, float)
        out["rec_v"] = np.asarray(self.rec_v, float).reshape(-1, n, 2)
        out["rec_a"] = np.asarray(self.rec_a, float).reshape(-1, n, 2)
        return out

    def restore(self, arrays: dict) -> None:
        self.sets = {k: np.asarray(arrays[f"set_{k}"], np.int64) for k in self.sets}
        self.rec_t = [float(v) for v in arrays["rec_t"]]
        self.rec_v = list(np.asarray(arrays["rec_v"]))
        self.rec_a = list(np.asarray(arrays["rec_a"]))
        if getattr(self, "_state", None) is not None:
            self._prepare(self._state)

    def summary(self) -> dict:
        return {"boundary_elements": int(len(self._idx)) if hasattr(self, "_idx") else 0,
                "sides": self.sides, "records": len(self.rec_t)}

    # -- set-up
    def set_sets(self, base, left, right, receivers, state=None) -> None:
        self.sets = {"base": np.asarray(base, np.int64), "left": np.asarray(left, np.int64),
                     "right": np.asarray(right, np.int64),
                     "receivers": np.asarray(receivers, np.int64)}
        if state is not None:
            self._prepare(state)

    def _prepare(self, st) -> None:
        self._state = st
        base, left, right = self.sets["base"], self.sets["left"], self.sets["right"]
        if self.sides == "roller":
            left = right = np.zeros(0, np.int64)
        self._idx = np.unique(np.concatenate([base, left, right]))
        pos = {k: np.searchsorted(self._idx, v) for k, v in
               (("base", base), ("left", left), ("right", right))}
        self._pos = pos
        self._force = np.zeros((len(self._idx), 2))
        zt = self.rho * self.t
        self._zb = (zt * self.d * self.cp, zt * self.d * self.cs)           # base: L = d
        h = 0.5 * SQRT3 * self.d
        self._zs = (zt * h * self.cp, zt * h * self.cs)                      # sides: L = row
        self._area_side = h * self.t
        y = st.x_ref[np.concatenate([left, right]), 1] - self.y_base
        H = self.y_top - self.y_base
        self._tau_up = y / self.cp                      # incident arrival delay
        self._tau_dn = (2.0 * H - y) / self.cp          # surface-reflected arrival delay
        self._nx = np.concatenate([-np.ones(len(left)), np.ones(len(right))])

    # -- the coupling, every mechanical step
    def advance(self, sim, span: float) -> int:
        st = sim.state
        t = st.time + st.dt - self.t_start  # time of the next force evaluation
        v = st.v
        f = self._force
        f[:] = 0.0
        p = self._pos
        vb = v[self.sets["base"]]
        zp, zs = self._zb
        f[p["base"], 0] -= zs * vb[:, 0]
        f[p["base"], 1] += zp * (2.0 * float(self.pulse(t)) - vb[:, 1])
        if self.sides != "roller" and len(self._nx):
            side = np.concatenate([p["left"], p["right"]])
            vs = v[self._idx[side]]
            zp, zs = self._zs
            if self.sides == "free_field":
                up, dn = self.pulse(t - self._tau_up), self.pulse(t - self._tau_dn)
                vff = up + dn
                sxx = -self.nu * self.rho * self.cp * (up - dn)
                f[side, 0] += -zp * vs[:, 0] + sxx * self._nx * self._area_side
                f[side, 1] += zs * (vff - vs[:, 1])
            else:
                f[side, 0] -= zp * vs[:, 0]
                f[side, 1] -= zs * vs[:, 1]
        st.fload[self._idx] = f
        if self.record_every and st.step % self.record_every == 0:
            r = self.sets["receivers"]
            self.rec_t.append(st.time - self.t_start)
            self.rec_v.append(v[r].copy())
            self.rec_a.append(st.a[r].copy())
        return 1

    def records(self):
        """``(t (K,), v (K, R, 2), a (K, R, 2))`` of the receivers."""
        a = self.arrays()
        return a["rec_t"], a["rec_v"], a["rec_a"]


# ============================================================================ the column
def run_column(medium: dict, height: float, pulse: Pulse, *, width_elements: int = 8,
               dt=None, dt_fraction: float = 0.05, backend=None, record_every: int = 1,
               duration=None) -> dict:
    """The flat reference: a column ``width_elements`` wide and ``height`` tall of the lattice
    ``medium``, roller sides, the LK base with the input ``pulse``; run until the wave has come
    back up from the base after the surface round trip. Returns the records of its receivers
    (the centre column's elements of even rows, bottom to top; the last is the surface) and
    the measurements of :func:`measure_column`."""
    from geodem.core.engine import Simulation

    d = medium["d"]
    st, info = build_section(medium, (width_elements - 0.5) * d, height)
    sets = boundary_sets(st.x, d)
    xc = st.x[sets["base"], 0][len(sets["base"]) // 2]
    line = np.flatnonzero(np.abs(st.x[:, 0] - xc) < 0.25 * d)
    line = line[np.argsort(st.x[line, 1])]
    st.free[np.concatenate([sets["left"], sets["right"]]), 0] = 0.0
    sim = Simulation(st, backend=backend, dt=dt, dt_fraction=dt_fraction, monitor_every=0)
    field = SeismicBoundary(medium["rho"], medium["cp"], medium["cs"], medium["nu"],
                            medium["thickness"], d, info["y_base"], info["y_top"],
                            pulse.config(), sides="roller", record_every=record_every)
    field.set_sets(sets["base"], sets["left"], sets["right"], line)
    sim.add_field(field)
    H = info["y_top"] - info["y_base"]
    if duration is None:
        duration = pulse.t_c + 2.5 * H / medium["cp"] + 1.5 * pulse.half
    nsteps = int(math.ceil(duration / sim.state.dt))
    sim.run(nsteps)
    t, v, a = field.records()
    y = st.x_ref[line, 1] - info["y_base"]
    out = measure_column(t, y, v, a, H, medium["cp"], pulse)
    out.update({"t": t, "y": y, "v": v, "a": a, "height": H, "elements": int(st.n),
                "steps": nsteps, "dt": sim.state.dt,
                "energy_closure_error": sim.energies()["closure_error"]})
    return out


def _window(t, centre, half):
    return (t >= centre - half) & (t <= centre + half)


def measure_column(t, y, v, a, H, cp, pulse: Pulse) -> dict:
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
