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
import time
from typing import Literal, Optional

import numpy as np

from geodem.cases.common import frames_gif, needs_model
from geodem.fields import CoupledField, register_field
from geodem.workflow.models import BuildError, BuiltModel, state_bytes_per_element
from geodem.workflow.schema import F, Int, ModelBase, Name, StepBase, register_model, \
    register_step
from geodem.workflow.animation import label_map, legend_outside, pick_frames, pyplot

SQRT3 = math.sqrt(3.0)
FRAMES_DIR = "seismic_frames"
VTK_DIR = "seismic_vtk"
RECORDS = "seismic_receivers.npz"
AMPLIFICATION_CSV = "seismic_amplification.csv"
#: accelerations are low-passed at this multiple of the pulse frequency before their peaks are
#: taken (:func:`lowpass`)
LOWPASS = 3.0
#: the amplification profile is averaged along the ground line over this fraction of the P
#: wavelength (the staircase of a slope makes neighbouring receivers differ by ~15 %)
SMOOTH = 0.5


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
    writes = {"fload": "N", "eta": "kg/s"}

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
        self.sets = {k: np.zeros(0, np.int64) for k in ("base", "left", "right", "receivers",
                                                        "patch_idx", "patch_ptr")}
        self.rec_t, self.rec_v, self.rec_a = [], [], []
        self.wall, self.calls = 0.0, 0  # its own cost (seconds, couplings)

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
    def set_sets(self, base, left, right, receivers, state) -> None:
        """The boundary sets and the receivers; a receiver records the mean motion of its
        element and the elements bonded to it (a patch about two spacings across: a single
        staircase corner of a slope rings on its own)."""
        from geodem.core.state import BONDED

        receivers = np.asarray(receivers, np.int64)
        patches = [np.concatenate([[r], state.nbr[r][state.cstate[r] == BONDED]])
                   for r in receivers]
        self.sets = {"base": np.asarray(base, np.int64), "left": np.asarray(left, np.int64),
                     "right": np.asarray(right, np.int64), "receivers": receivers,
                     "patch_idx": np.concatenate(patches).astype(np.int64) if patches else
                     np.zeros(0, np.int64),
                     "patch_ptr": np.cumsum([0] + [len(p) for p in patches]).astype(np.int64)}
        self._prepare(state)

    def _prepare(self, st) -> None:
        self._state = st
        ptr = self.sets["patch_ptr"]
        self._patch_start = ptr[:-1] if len(ptr) > 1 else np.zeros(0, np.int64)
        self._patch_cnt = np.diff(ptr)[:, None].astype(float) if len(ptr) > 1 else \
            np.ones((0, 1))
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
        # the normal (P) dashpots are the engine's own damping eta (implicit in the velocity
        # update, booked as viscous heat); fload carries the input, the free field and the
        # tangential difference rho (c_p - c_s) A v (the engine's eta is isotropic)
        eta = np.zeros(len(self._idx))
        eta[pos["base"]] += self._zb[0]
        eta[pos["left"]] += self._zs[0]
        eta[pos["right"]] += self._zs[0]
        st.eta[self._idx] = eta

    # -- the coupling, every mechanical step
    def advance(self, sim, span: float) -> int:
        c0 = time.perf_counter()
        st = sim.state
        t = st.time + st.dt - self.t_start  # time of the next force evaluation
        v = st.v
        f = self._force
        f[:] = 0.0
        p = self._pos
        vb = v[self.sets["base"]]
        zp, zs = self._zb
        f[p["base"], 0] += (zp - zs) * vb[:, 0]
        f[p["base"], 1] += 2.0 * zp * float(self.pulse(t))
        if self.sides != "roller" and len(self._nx):
            side = np.concatenate([p["left"], p["right"]])
            vs = v[self._idx[side]]
            zp, zs = self._zs
            f[side, 1] += (zp - zs) * vs[:, 1]
            if self.sides == "free_field":
                up, dn = self.pulse(t - self._tau_up), self.pulse(t - self._tau_dn)
                sxx = -self.nu * self.rho * self.cp * (up - dn)
                f[side, 0] += sxx * self._nx * self._area_side
                f[side, 1] += zs * (up + dn)
        st.fload[self._idx] = f
        if self.record_every and st.step % self.record_every == 0:
            idx, start, cnt = self.sets["patch_idx"], self._patch_start, self._patch_cnt
            self.rec_t.append(st.time - self.t_start)
            self.rec_v.append(np.add.reduceat(v[idx], start, axis=0) / cnt)
            self.rec_a.append(np.add.reduceat(st.a[idx], start, axis=0) / cnt)
        self.wall += time.perf_counter() - c0
        self.calls += 1
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
    field.set_sets(sets["base"], sets["left"], sets["right"], line, st)
    sim.add_field(field)
    H = info["y_top"] - info["y_base"]
    if duration is None:
        duration = pulse.t_c + 2.5 * H / medium["cp"] + 1.5 * pulse.half
    nsteps = int(math.ceil(duration / sim.state.dt))
    sim.run(nsteps)
    t, v, a_raw = field.records()
    a = lowpass(a_raw, t, LOWPASS * pulse.f)
    y = st.x_ref[line, 1] - info["y_base"]
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


# ============================================================================ model
@register_model("valley_section")
class ValleySection(ModelBase):
    """A 2-D section of bonded rock (regular triangular lattice, the elastic medium E, nu, rho)
    cut by a V-shaped valley; groups ``base``, ``sides``, ``surface`` (the ground line) and
    ``rock``. ``valley_depth: 0`` gives a flat section."""

    size_field = "scale"
    example = {"type": "valley_section", "width": 60.0, "height": 50.0, "valley_width": 24.0,
               "valley_depth": 10.0, "d": 2.0}
    dim: Literal[2] = F(2, description="Dimension (2-D sections only)")
    width: float = F(600.0, unit="m", gt=0, description="Width of the section")
    height: float = F(200.0, unit="m", gt=0, description="Height of the section (base to the "
                                                         "flat ground)")
    valley_width: float = F(240.0, unit="m", ge=0, description="Width of the V valley at the "
                                                               "ground line")
    valley_depth: float = F(80.0, unit="m", ge=0, description="Depth of the V valley (0: flat "
                                                              "ground)")
    valley_x: Optional[float] = F(None, unit="m", description="x of the valley axis (default: "
                                                              "the middle)")
    d: float = F(2.5, unit="m", gt=0, description="Element diameter (lattice spacing) at scale "
                                                  "1")
    scale: float = F(1.0, gt=0, le=20, description="Resolution knob: the spacing is d / scale "
                                                   "(elements ~ scale^2; the pulse and the "
                                                   "geometry stay)")
    material: Optional[Name] = F(None, description="A library or rock-property material whose "
                                                   "E, nu, rho are used (default: the E, nu, "
                                                   "rho below)")
    E: float = F(60.0e9, unit="Pa", gt=0, description="Young's modulus of the rock (2-D medium)")
    nu: float = F(0.25, gt=-1, le=1.0 / 3.0, description="Poisson's ratio of the rock; the "
                                                          "triangular lattice reaches -1 < nu "
                                                          "<= 1/3")
    rho: float = F(2650.0, unit="kg/m^3", gt=0, description="Density of the rock")

    def spacing(self) -> float:
        return self.d / self.scale

    def n_elements(self):
        d = self.spacing()
        area = self.width * self.height - 0.5 * self.valley_width * self.valley_depth
        return max(1, int(area / (0.5 * SQRT3 * d * d)))

    def bytes_per_element(self):
        return state_bytes_per_element(2, 8) + 1500

    def material_refs(self):
        return [(("material",), self.material)] if self.material is not None else []

    def group_names(self):
        return ["all", "rock", "surface", "sides", "base"]

    def n_across(self):
        return float(self.height / (0.5 * SQRT3 * self.spacing()))

    def check(self, cfg):
        out = []
        d = self.spacing()
        for key in ("width", "height"):
            if getattr(self, key) < 10 * d:
                out.append(((key,), f"{key} = {getattr(self, key):g} m is less than 10 element "
                                    f"spacings ({10 * d:g} m); allowed: >= 10 d / scale"))
        xc = 0.5 * self.width if self.valley_x is None else self.valley_x
        if self.valley_depth > 0:
            if self.valley_width <= 0:
                out.append((("valley_width",), "a valley (valley_depth > 0) needs "
                                               "valley_width > 0"))
            if xc - 0.5 * self.valley_width < 2 * d or xc + 0.5 * self.valley_width > \
                    self.width - 2 * d:
                out.append((("valley_width",), f"the valley ({xc - 0.5 * self.valley_width:g} "
                                               f"to {xc + 0.5 * self.valley_width:g} m) must "
                                               f"lie inside the section (2 d from its sides, "
                                               f"0 to {self.width:g} m)"))
            if self.valley_depth > self.height - 10 * d:
                out.append((("valley_depth",), f"valley_depth = {self.valley_depth:g} m leaves "
                                               f"less than 10 d of rock below the valley; "
                                               f"allowed: <= height - 10 d = "
                                               f"{self.height - 10 * d:g} m"))
        if self.material is not None and self.material in cfg.materials:
            try:
                self.rock(cfg)
            except BuildError as exc:
                out.append((exc.path, str(exc)))
        return out

    def rock(self, cfg) -> tuple[float, float, float, str]:
        """``(E, nu, rho, source)`` of the rock."""
        if self.material is None:
            return self.E, self.nu, self.rho, "model E, nu, rho"
        from geodem.workflow.schema import LibraryMaterial, MacroMaterial

        m = cfg.materials[self.material]
        if isinstance(m, LibraryMaterial):
            from geodem.materials_library import load_material

            try:
                v = load_material(m.library).values()
            except Exception as exc:  # noqa: BLE001 - reported as a build error
                raise BuildError(("material",), f"library material {m.library!r} not "
                                                f"readable: {exc}") from None
            E, nu, rho, src = v["E"], v["nu"], v["rho"], f"library {m.library!r} (laboratory)"
        elif isinstance(m, MacroMaterial):
            E, nu, rho, src = m.E, m.nu, m.rho, f"material {self.material!r}"
        else:
            raise BuildError(("material",), f"material {self.material!r} gives element "
                                            f"parameters; valley_section needs rock "
                                            f"properties (a library material or E, nu, ...)")
        if not -1.0 < nu <= 1.0 / 3.0:
            raise BuildError(("material",), f"material {self.material!r} has nu = {nu:g}; "
                                            f"the triangular lattice reaches -1 < nu <= 1/3")
        return float(E), float(nu), float(rho), src

    def build(self, cfg):
        E, nu, rho, src = self.rock(cfg)
        med = lattice_medium(E, nu, rho, self.spacing())
        st, info = build_section(med, self.width, self.height,
                                 self.valley_width if self.valley_depth > 0 else 0.0,
                                 self.valley_depth, self.valley_x)
        info.update({"rock_source": src, "d_base": self.d, "scale": self.scale,
                     "medium": {**info["medium"], "d": med["d"], "thickness": med["thickness"]}})
        return BuiltModel(st, st.x.copy(), self.n_across(), info)


# ============================================================================ step
@register_step("seismic_wave")
class SeismicWave(StepBase):
    """A vertically propagating P pulse (Ricker or Hann-windowed sine) injected at the base of a
    ``valley_section`` through a Lysmer-Kuhlemeyer viscous boundary (base and sides absorb),
    after a flat reference column of the same rock measured the P-wave speed, the free-surface
    amplification and the base reflection. Adds amplification_max, amplification_location_m,
    p_wave_speed_rel_error, free_surface_amplification and boundary_reflection to summary.json;
    writes seismic_receivers.npz, seismic_amplification.csv, seismic_snapshots.png,
    seismic_surface.png, seismic_reference.png, seismic_animation.gif and seismic_vtk/."""

    example = {"kind": "seismic_wave", "duration": 0.02, "wavelength_elements": 8,
               "gif": False, "snapshots": 2, "vtk_frames": 1}
    example_model = ValleySection.example
    pulse: Literal["ricker", "sine"] = F("ricker", description="Incident particle-velocity "
                                                               "pulse")
    frequency: Optional[float] = F(None, unit="Hz", gt=0,
                                   description="Ricker peak / sine frequency (default: the P "
                                               "wavelength is wavelength_elements x the model's "
                                               "d at scale 1)")
    wavelength_elements: float = F(20.0, ge=4, le=1000,
                                   description="Default frequency: c_p / (this x d)")
    cycles: float = F(2.0, gt=0, le=20, description="Sine cycles under the Hann window")
    amplitude: float = F(0.01, unit="m/s", gt=0, description="Peak particle velocity of the "
                                                             "incident wave")
    duration: float = F(..., unit="s", gt=0, description="Simulated time of the section run "
                                                         "(at least the pulse plus the "
                                                         "crossing of the section)")
    sides: Literal["free_field", "absorbing", "roller"] = F(
        "free_field", description="Side boundaries: dashpots against the flat free field "
                                  "(free_field), plain dashpots (absorbing) or horizontally "
                                  "fixed (roller)")
    record_every: Int = F(2, ge=1, le=1000, description="Receiver sampling interval [steps]")
    reference: bool = F(True, description="Run the flat reference column first (wave speed, "
                                          "free-surface amplification, base reflection and the "
                                          "flat-ground peak acceleration)")
    reference_width: Int = F(8, ge=3, le=200, description="Width of the reference column "
                                                          "[elements]")
    snapshots: Int = F(6, ge=1, le=12, description="Particle-speed maps in "
                                                   "seismic_snapshots.png")
    vtk_frames: Int = F(6, ge=0, le=100, description="Frames written to seismic_vtk/ (.vtp)")
    gif: bool = F(True, description="Write seismic_animation.gif")
    gif_frames: Int = F(40, ge=2, le=300, description="Frames of the animation")
    edge_exclusion: float = F(1.5, ge=0, le=10,
                              description="amplification_max is searched on the ground more "
                                          "than this many P wavelengths from the sides")
    plot: bool = F(True, description="Draw the pictures (needs matplotlib)")

    def check(self, cfg, groups):
        out = needs_model(cfg, "valley_section",
                          "seismic_wave needs the rock section: use model type valley_section")
        if out:
            return out
        m = cfg.model
        try:
            E, nu, rho, _ = m.rock(cfg) if (m.material is None or m.material in
                                            cfg.materials) else (m.E, m.nu, m.rho, "")
        except BuildError:
            return out
        cp = math.sqrt(E / ((1 - nu * nu) * rho))
        pulse = self.make_pulse(cp, m.d)
        need = pulse.duration + m.height / cp
        if self.duration < need:
            out.append((("duration",), f"duration = {self.duration:g} s ends before the pulse "
                                       f"({pulse.duration:.4g} s) has crossed the section "
                                       f"({m.height:g} m at c_p = {cp:.0f} m/s); allowed: "
                                       f">= {need:.4g} s (2 crossings recommended: "
                                       f"{pulse.duration + 2 * m.height / cp:.4g} s)"))
        return out

    def make_pulse(self, cp: float, d_base: float) -> Pulse:
        f = self.frequency if self.frequency is not None else \
            cp / (self.wavelength_elements * d_base)
        return Pulse(self.pulse, f, self.amplitude, self.cycles)

    def planned_steps(self, plan):
        return max(1, int(math.ceil(self.duration / plan.dt - 1e-9)))

    # ------------------------------------------------------------------ execution
    def execute(self, ctx):
        from geodem.io.vtk import VtkWriter

        info = ctx.model.info
        med = info["medium"]
        d = float(info["diameter"])
        pulse = self.make_pulse(med["cp"], float(info["d_base"]))
        total = self.planned_steps(ctx.plan)
        H = info["y_top"] - info["y_base"]
        # ------------------------------------------------------------ flat reference
        ref, ref_note = None, None
        if self.reference:
            t0 = time.perf_counter()
            try:
                ref = run_column(med, info["height"], pulse, width_elements=self.reference_width,
                                 dt=ctx.state.dt, backend=ctx.runner.prep.backend,
                                 record_every=self.record_every)
                ref["wall_s"] = time.perf_counter() - t0
            except ValueError as exc:
                ref_note = f"reference column not measured: {exc}"
                ctx.log(ref_note)
        # ------------------------------------------------------------ the section
        sim = ctx.sim
        field = next((f for f in sim.fields if f.kind == "seismic_boundary"), None)
        ref_x = ctx.model.reference
        if field is None:
            sets = boundary_sets(ref_x, d)
            st = ctx.state
            if self.sides == "roller":
                side = np.concatenate([sets["left"], sets["right"]])

                def roll(s):
                    s.free[side, 0] = 0.0
                    s.v[side, 0] = 0.0

                ctx.decree(roll, "sides")
            ctx.set_eta(0.0)
            field = SeismicBoundary(med["rho"], med["cp"], med["cs"], med["nu"],
                                    med["thickness"], d, info["y_base"], info["y_top"],
                                    pulse.config(), sides=self.sides,
                                    record_every=self.record_every, t_start=st.time)
            field.set_sets(sets["base"], sets["left"], sets["right"], sets["surface"], st)
            sim.add_field(field)
        n_frames = max(self.gif_frames if self.gif else 0, self.snapshots, self.vtk_frames, 1)
        chunk = max(1, total // n_frames)
        n_last = int(math.ceil(total / chunk))
        vtk_at = set(np.unique(np.linspace(1, n_last, self.vtk_frames).round().astype(int))
                     .tolist()) if self.vtk_frames else set()
        fdir = ctx.out_dir / FRAMES_DIR
        fdir.mkdir(exist_ok=True)
        vtk = VtkWriter(ctx.out_dir / VTK_DIR, "seismic.pvd") if vtk_at else None
        done = ctx.state.step - ctx.start_step
        t_wall = time.perf_counter()
        while done < total:
            done = min(total, (done // chunk + 1) * chunk)
            ctx.advance(done)
            s = ctx.state
            k = int(math.ceil(done / chunk))
            np.savez_compressed(fdir / f"frame_{k:05d}.npz", x=s.x.astype(np.float32),
                                speed=np.linalg.norm(s.v, axis=1).astype(np.float32),
                                time=s.time - field.t_start)
            if vtk is not None and k in vtk_at:
                vtk.write(s, s.step, ref_x)
        wall = time.perf_counter() - t_wall
        return self._results(ctx, field, ref, ref_note, pulse, H, d, fdir, wall)

    def _results(self, ctx, field, ref, ref_note, pulse, H, d, fdir, wall):
        info = ctx.model.info
        med = info["medium"]
        t, v, a_raw = field.records()
        a = lowpass(a_raw, t, LOWPASS * pulse.f)
        rec = field.sets["receivers"]
        xr = ctx.model.reference[rec]
        peak_a = np.linalg.norm(a, axis=2).max(axis=0) if len(t) else np.zeros(len(rec))
        peak_v = np.linalg.norm(v, axis=2).max(axis=0) if len(t) else np.zeros(len(rec))
        if ref is not None:
            a_flat, flat_src = ref["surface_peak_acceleration"], "flat reference column"
        else:  # analytic: twice the incident peak acceleration
            tt = np.linspace(0.0, pulse.duration, 4001)
            a_flat = 2.0 * float(np.abs(np.gradient(pulse(tt), tt)).max())
            flat_src = "analytic (2 x incident peak acceleration)"
        lam = med["cp"] / pulse.f
        amp_raw = peak_a / a_flat
        amp = ground_smooth(xr, amp_raw, SMOOTH * lam)
        edge = self.edge_exclusion * lam
        inner = (xr[:, 0] >= info["x_min"] + edge) & (xr[:, 0] <= info["x_max"] - edge)
        if not inner.any():
            inner[:] = True
        k = int(np.flatnonzero(inner)[np.argmax(amp[inner])])
        xc, hw = info["valley_x"], 0.5 * info["valley_width"]
        far = (np.abs(xr[:, 0] - xc) > hw + lam) & (xr[:, 0] > info["x_min"] + lam) & \
            (xr[:, 0] < info["x_max"] - lam)
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
            "section_wall_s": wall, "boundary_field_wall_s": field.wall,
            "boundary_field_us_per_step": 1e6 * field.wall / max(field.calls, 1),
        }
        for key in ref_keys:
            res[key] = ref[key] if ref is not None else None
        if ref is not None:
            res["reference"] = {k: v for k, v in ref.items() if not isinstance(v, np.ndarray)}
        else:
            res["reference_note"] = ref_note or "reference: false"
        ctx.summary.update({key: res[key] for key in
                            ("amplification_max", "amplification_location_m") + ref_keys})
        ctx.summary["amplification_flat_ground"] = res["amplification_flat_ground"]

        def fmt(v, f=".3g"):
            return "n/a" if v is None else format(v, f)

        ctx.log(f"seismic wave: amplification max {amp[k]:.3g} at x = {xr[k, 0]:.1f} m "
                f"(flat ground {fmt(res['amplification_flat_ground'])}); reference: c_p error "
                f"{fmt(res['p_wave_speed_rel_error'])}, free-surface amplification "
                f"{fmt(res['free_surface_amplification'])}, base reflection "
                f"{fmt(res['boundary_reflection'])}")
        if self.plot and ctx.cfg.outputs.plots:
            frames = sorted(fdir.glob("frame_*.npz"))
            vmax = 2.0 * self.amplitude
            res["plot_snapshots"] = ctx.plot("seismic_snapshots.png", lambda p: plot_snapshots(
                p, frames, self.snapshots, d, vmax))
            res["plot_surface"] = ctx.plot("seismic_surface.png", lambda p: plot_surface(
                p, t, a, xr, amp, info, amp_raw))
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


def plot_surface(path, t, a, xr, amp, info, amp_raw=None):
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
    """Animation of the particle-speed maps (imageio, else matplotlib's PillowWriter; None when
    neither can write a GIF)."""
    if pyplot() is None or not frames:
        return None
    x = np.load(frames[0])["x"]
    aspect = float(np.ptp(x[:, 1]) / max(np.ptp(x[:, 0]), 1e-300))
    return frames_gif(path, frames, (6.0, 6.0 * aspect + 0.4),
                      lambda ax, f: _speed_map(ax, np.load(f), d, vmax), fps=8)


__all__ = ["ValleySection", "SeismicWave", "SeismicBoundary", "Pulse", "lattice_medium",
           "lattice_E_nu", "section_points", "boundary_sets", "build_section", "run_column",
           "measure_column"]
