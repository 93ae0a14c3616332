"""Coupled field ``wave_boundary``: a plane P wave sent up through a viscous (Lysmer-Kuhlemeyer)
base, absorbing or free-field sides, and receivers that record the motion (2-D and 3-D); or,
with ``incidence="xmin"``, a plane P wave sent along +x through the xmin face (MatDEM's seismic
valley), the other faces absorbing (below).

The wave travels along the last axis (y in 2-D, z in 3-D) from the **base** (the bottom face)
to the top. Each boundary element stands for one lattice line normal to its face; its area
``A`` is the product of the lattice pitches along the face (2-D: times the thickness ``t``):
2-D base ``d t``, 2-D sides ``(sqrt3/2) d t``; 3-D base ``(sqrt3/2) d^2``, x faces
``(sqrt3/2) d sqrt(2/3) d``, y faces ``d sqrt(2/3) d``. With ``Z_p = rho c_p A``, ``Z_s = rho
c_s A``::

    base:   F_up = Z_p (2 v_in(t) - v_up),   F_tangential = -Z_s v
    sides:  F_n = -Z_p v_n + sigma_nn^ff n A,  F_up = Z_s (v_up^ff(z, t) - v_up),
            F_other tangential = -Z_s v

so the base injects an up-going plane P wave of particle velocity ``v_in`` and absorbs what
comes down, and the sides (``free_field``) absorb motion relative to the analytic free field of
a flat ground at ``z_top`` (incident plus surface-reflected wave): ``v_up^ff = v_in(t - z/c_p)
+ v_in(t - (2H - z)/c_p)``, ``sigma_zz^ff = -rho c_p (v_in(t - z/c_p) - v_in(t - (2H -
z)/c_p))``, ``sigma_nn^ff = K0 sigma_zz^ff`` (``z`` above the base, ``H`` the base to
``z_top``; ``K0`` the lateral stress ratio: ``nu`` in 2-D, ``nu / (1 - nu)`` in 3-D).
``absorbing`` drops the free field (plain dashpots); ``roller`` leaves the sides to the step
that made them (held along their normal: exact for a flat section, uniaxial strain).

Side incidence (``incidence="xmin"``): the elements of the xmin face take ``F_x = Z_p (2
v_in(t) - v_x)``, ``F_tangential = -Z_s v`` (their impedances those of an x face), and the xmax
face is a plain dashpot (exact for the plane wave leaving it). The faces along the wave's path
(the base and, in 3-D, the y faces) with ``sides="free_field"`` absorb motion relative to the
plane wave's free field, ``v_x^ff = v_in(t - (x - x_0)/c_p)``, ``sigma_nn^ff = K0 sigma_xx^ff``,
``sigma_xx^ff = -rho c_p v_x^ff`` (``x_0`` the source face): ``F_n = -Z_p v_n + sigma_nn^ff n
A``, ``F_x = Z_s (v_x^ff - v_x)``; with ``sides="absorbing"`` they are plain dashpots, whose
tangential part drains the passing wave (at mid-height of a 60 m block its peak kept 0.82 of
itself over 60 m, against 0.91 with the free field: tests/integration/test_wave_source.py).
The top stays free: a P wave running along a free surface is not a free field of it (the
surface holds ``sigma_nn = 0``, the plane wave ``K0 sigma_xx``), so the ground sees the wave's
own surface disturbance, in MatDEM's case as here.

The normal (P) dashpots ``Z_p`` are the engine's own damping ``eta`` (implicit in the velocity
update, booked as viscous heat); ``fload`` carries the input, the free field and the
tangential difference ``(Z_p - Z_s) v`` (the engine's ``eta`` is isotropic), so their work is
booked as external work. Receivers record, every ``record_every`` steps, the mean velocity
and acceleration (``State.a``) of their element and the elements bonded to it (a patch about
two spacings across: a single staircase corner of a slope rings on its own).

Reference: Lysmer, J., Kuhlemeyer, R. L. (1969) Finite dynamic model for infinite media,
J. Eng. Mech. Div. ASCE 95(EM4), 859-877.
"""
from __future__ import annotations

import math
import time

import numpy as np

from geodem.fields import CoupledField, register_field


#: the faces a plane P wave can enter through: the base (travelling up) or xmin (along +x)
INCIDENCE = ("base", "xmin")


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


def face_sets(x, d, sides=None, side_depth=0.6):
    """Boundary sets of a model from its element centres ``x``: ``base`` (the lowest layer
    along the last axis: centres within ``d / 2`` of the lowest), and the side elements (the
    slabs ``side_depth x d`` deep at the lateral faces ``sides``, default all: xmin, xmax and,
    in 3-D, ymin, ymax) with the axis and sign of their outward normal. An element on two faces
    (a corner) is on both; on two lateral faces it takes the first."""
    x = np.asarray(x, float)
    dim = x.shape[1]
    lo, hi = x.min(axis=0), x.max(axis=0)
    tol = 1e-9 * d
    base = np.flatnonzero(x[:, -1] <= lo[-1] + 0.5 * d - tol)
    names = "xyz"[:dim - 1]
    if sides is None:
        sides = [a + e for a in names for e in ("min", "max")]
    axis = np.full(len(x), -1, np.int64)
    sign = np.zeros(len(x))
    for s in sides:
        ax = "xyz".index(s[0])
        if ax >= dim - 1:
            raise ValueError(f"side {s!r}: the lateral faces are "
                             f"{', '.join(a + e for a in names for e in ('min', 'max'))}")
        on = (x[:, ax] <= lo[ax] + side_depth * d - tol) if s.endswith("min") else \
            (x[:, ax] >= hi[ax] - side_depth * d + tol)
        new = on & (axis < 0)
        axis[new] = ax
        sign[new] = -1.0 if s.endswith("min") else 1.0
    side = np.flatnonzero(axis >= 0)
    return {"base": base, "side": side, "side_axis": axis[side], "side_sign": sign[side]}


@register_field("wave_boundary")
class WaveBoundary(CoupledField):
    """Lysmer-Kuhlemeyer viscous boundary with a plane-wave input at the base and receivers
    (module docstring). Index sets are set with :meth:`set_sets` (fresh) or :meth:`restore`.
    ``pitch``: the lattice pitch along each axis, ``thickness``: 2-D only."""

    reads = {"v": "m/s", "a": "m/s^2", "x_ref": "m"}
    writes = {"fload": "N", "eta": "kg/s"}
    SETS = ("base", "side", "side_axis", "side_sign", "receivers", "patch_idx", "patch_ptr")

    def __init__(self, rho, cp, cs, k0, pitch, thickness, z_base, z_top, pulse: dict,
                 sides="free_field", record_every=2, t_start=0.0, every=1, incidence="base"):
        super().__init__(every)
        if sides not in ("free_field", "absorbing", "roller"):
            raise ValueError(f"sides {sides!r}: allowed free_field, absorbing, roller")
        if incidence not in INCIDENCE:
            raise ValueError(f"incidence {incidence!r}: allowed {', '.join(INCIDENCE)}")
        if incidence != "base" and sides == "roller":
            raise ValueError(f"incidence {incidence!r} with sides {sides!r}: rollers are the "
                             "flat section's under vertical incidence; allowed: free_field, "
                             "absorbing")
        self.incidence = incidence
        self.rho, self.cp, self.cs, self.k0 = float(rho), float(cp), float(cs), float(k0)
        self.pitch = [float(p) for p in pitch]
        self.dim = len(self.pitch)
        if (thickness is None) != (self.dim == 3):
            raise ValueError("thickness: give it in 2-D (the discs' thickness), None in 3-D")
        self.t = None if thickness is None else float(thickness)
        self.z_base, self.z_top = float(z_base), float(z_top)
        self.pulse_cfg = dict(pulse)
        self.pulse = Pulse(**pulse)
        self.sides = sides
        self.record_every = int(record_every)
        self.t_start = float(t_start)
        self.sets = {k: np.zeros(0, float if k == "side_sign" else np.int64) for k in self.SETS}
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
        return {"rho": self.rho, "cp": self.cp, "cs": self.cs, "k0": self.k0,
                "pitch": self.pitch, "thickness": self.t, "z_base": self.z_base,
                "z_top": self.z_top, "pulse": self.pulse_cfg, "sides": self.sides,
                "record_every": self.record_every, "t_start": self.t_start,
                "every": self.every, "incidence": self.incidence}

    def arrays(self) -> dict:
        out = {f"set_{k}": v for k, v in self.sets.items()}
        n = len(self.sets["receivers"])
        out["rec_t"] = np.asarray(self.rec_t, float)
        out["rec_v"] = np.asarray(self.rec_v, float).reshape(-1, n, self.dim)
        out["rec_a"] = np.asarray(self.rec_a, float).reshape(-1, n, self.dim)
        return out

    def restore(self, arrays: dict) -> None:
        self.sets = {k: np.asarray(arrays[f"set_{k}"], float if k == "side_sign" else np.int64)
                     for k in self.SETS}
        self.rec_t = [float(v) for v in arrays["rec_t"]]
        self.rec_v = list(np.asarray(arrays["rec_v"]))
        self.rec_a = list(np.asarray(arrays["rec_a"]))
        if getattr(self, "_state", None) is not None:
            self._prepare(self._state)

    def summary(self) -> dict:
        return {"boundary_elements": int(len(self._idx)) if hasattr(self, "_idx") else 0,
                "sides": self.sides, "records": len(self.rec_t)}

    # -- set-up
    def set_sets(self, sets: dict, receivers, state) -> None:
        """The boundary sets (:func:`face_sets`) and the receivers; a receiver records the mean
        motion of its element and the elements bonded to it."""
        from geodem.core.state import BONDED

        receivers = np.asarray(receivers, np.int64)
        patches = [np.concatenate([[r], state.nbr[r][state.cstate[r] == BONDED]])
                   for r in receivers]
        self.sets = {k: np.asarray(sets[k], float if k == "side_sign" else np.int64)
                     for k in ("base", "side", "side_axis", "side_sign")}
        self.sets.update({
            "receivers": receivers,
            "patch_idx": np.concatenate(patches).astype(np.int64) if patches else
            np.zeros(0, np.int64),
            "patch_ptr": np.cumsum([0] + [len(p) for p in patches]).astype(np.int64)})
        self._prepare(state)

    def _impedance(self, axis):
        """``(rho A c_p, rho A c_s, A)`` of a boundary element on a face normal to ``axis``."""
        tang = [self.pitch[k] for k in range(self.dim) if k != axis]
        a, b = (self.t, tang[0]) if self.dim == 2 else tang
        z = self.rho * a * b
        return z * self.cp, z * self.cs, b * a

    def _prepare(self, st) -> None:
        self._state = st
        ptr = self.sets["patch_ptr"]
        self._patch_start = ptr[:-1] if len(ptr) > 1 else np.zeros(0, np.int64)
        self._patch_cnt = np.diff(ptr)[:, None].astype(float) if len(ptr) > 1 else \
            np.ones((0, 1))
        up = self.dim - 1
        base, side = self.sets["base"], self.sets["side"]
        axis, sign = self.sets["side_axis"], self.sets["side_sign"]
        if self.sides == "roller":
            side, axis, sign = side[:0], axis[:0], sign[:0]
        self._idx = np.unique(np.concatenate([base, side]))
        self._pb = np.searchsorted(self._idx, base)
        self._ps = np.searchsorted(self._idx, side)
        self._force = np.zeros((len(self._idx), self.dim))
        self._zb = self._impedance(up)[:2]
        imp = np.array([self._impedance(a) for a in range(self.dim)])
        self._zps, self._zss, self._area = (imp[axis, k] for k in range(3))
        self._axis, self._sign = axis, sign
        # side incidence: the positions (among the sides) of the source face's elements, and
        # the faces along the wave's path (base, y faces) that take its free field
        self._src = np.flatnonzero((axis == 0) & (sign < 0)) if self.incidence == "xmin" \
            else np.zeros(0, np.int64)
        if self.incidence == "xmin" and self.sides == "free_field":
            along = np.flatnonzero(axis != 0)
            self._ff_pos = np.concatenate([self._pb, self._ps[along]])
            self._ff_axis = np.concatenate([np.full(len(base), up), axis[along]])
            self._ff_sign = np.concatenate([-np.ones(len(base)), sign[along]])
            self._ff_zs = np.concatenate([np.full(len(base), self._zb[1]), self._zss[along]])
            self._ff_area = np.concatenate([np.full(len(base), self._impedance(up)[2]),
                                            self._area[along]])
            x_el = st.x_ref[self._idx[self._ff_pos], 0]
            self._ff_tau = (x_el - float(st.x_ref[:, 0].min())) / self.cp
        else:
            self._ff_pos = np.zeros(0, np.int64)
        # tangential axes of the side elements: (axis, their positions among the sides)
        self._tang = [(j, np.flatnonzero(axis != j)) for j in range(self.dim)]
        z = st.x_ref[side, up] - self.z_base
        H = self.z_top - self.z_base
        self._tau_up = z / self.cp                      # incident arrival delay
        self._tau_dn = (2.0 * H - z) / self.cp          # surface-reflected arrival delay
        eta = np.zeros(len(self._idx))
        eta[self._pb] += self._zb[0]
        eta[self._ps] += self._zps
        st.eta[self._idx] = eta

    # -- the coupling, every mechanical step
    def advance(self, sim, span: float) -> int:
        c0 = time.perf_counter()
        st = sim.state
        t = st.time + st.dt - self.t_start  # time of the next force evaluation
        v = st.v
        f = self._force
        f[:] = 0.0
        up = self.dim - 1
        pb = self._pb
        vb = v[self.sets["base"]]
        zp, zs = self._zb
        for j in range(up):
            f[pb, j] += (zp - zs) * vb[:, j]
        v_in = float(self.pulse(t))
        if self.incidence == "base":
            f[pb, up] += 2.0 * zp * v_in
        if len(self._ps):
            ps = self._ps
            vs = v[self._idx[ps]]
            for j, k in self._tang:
                if len(k):
                    f[ps[k], j] += (self._zps[k] - self._zss[k]) * vs[k, j]
            if self.sides == "free_field" and self.incidence == "base":
                u, dn = self.pulse(t - self._tau_up), self.pulse(t - self._tau_dn)
                snn = -self.k0 * self.rho * self.cp * (u - dn)
                f[ps, self._axis] += snn * self._sign * self._area
                f[ps, up] += self._zss * (u + dn)
            if len(self._src):
                f[ps[self._src], 0] += 2.0 * self._zps[self._src] * v_in
        if len(self._ff_pos):
            u = self.pulse(t - self._ff_tau)
            snn = -self.k0 * self.rho * self.cp * u
            f[self._ff_pos, self._ff_axis] += snn * self._ff_sign * self._ff_area
            f[self._ff_pos, 0] += self._ff_zs * u
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
        """``(t (K,), v (K, R, dim), a (K, R, dim))`` of the receivers."""
        a = self.arrays()
        return a["rec_t"], a["rec_v"], a["rec_a"]


__all__ = ["Pulse", "WaveBoundary", "face_sets"]
