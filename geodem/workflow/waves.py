"""Generic step kind ``wave_source``: a plane P wave sent up through the base of an elastic
lattice model (or along +x through its xmin face: ``incidence: xmin``), with absorbing or
free-field sides and receivers, in 2-D and 3-D. In 3-D the
close-packed layers are stacked along z, and the FCC lattice's P modulus along z is exactly
the medium's ``M`` (three of each element's six bonds at ``n_z^2 = 2/3``: ``M_z = (sqrt2 / d)
(4/3 Kn + 2/3 Ks)``); measured on a column 8.5 spacings wide (tests/integration/
test_wave_source.py), the pulse travels at c_p within 1 %. Its lateral faces are not planes
(the stacking shifts every other layer), so half masses there are approximate: on narrow
columns with ``sides: roller`` the wave is slower (-5.9 % at 4.5 spacings wide, -2.6 % at 8.5,
-1.2 % at 16.5), while ``free_field`` sides keep it within 1 % at every width.

The model is a ``scene`` with ``elements: elastic`` (its rock's E, nu, rho converted exactly
onto the close-packed lattice; docs/scene.md), whose medium (``rho``, ``c_p``, ``c_s``, the
lateral stress ratio and the lattice pitches) sets the boundary's impedances. The wave travels
along the last axis (y in 2-D, z in 3-D). The step

* finds the boundary: the **base** (the lowest layer of element centres) and the **sides**
  (slabs ``side_depth`` element diameters deep at the lateral faces ``side_faces``: one element
  per lattice row, so 0.6 for the close-packed lattices); a corner element is on both;
* switches the global damping off and attaches the coupled field ``wave_boundary``
  (:mod:`geodem.fields.wave`: Lysmer-Kuhlemeyer dashpots, the input ``2 Z_p v_in(t)`` at the
  base, the analytic free field of a flat ground on the sides; ``sides: roller`` holds the
  side elements along their normal instead);
* records the group ``receivers`` (the mean velocity and acceleration of each receiver and
  the elements bonded to it, every ``record_every`` steps) and runs ``duration`` seconds,
  writing ``frames`` particle-speed frames (``<name>_frames/frame_*.npz``: positions, speed,
  time since the wave started) and ``vtk_frames`` ParaView frames (``<name>_vtk/<name>.pvd``).

The receivers' records are written to ``<name>_receivers.npz`` (``receiver_x``, ``t``, ``v``,
``a``); a case step after it reads them from the field (e.g. ``valley_amplification``,
geodem.cases.seismic). The pulse is a Ricker wavelet or a Hann-windowed sine of particle
velocity ``amplitude`` (frequency given, or ``c_p / wavelength``).
"""
from __future__ import annotations

import math
import time
from typing import Literal, Optional

import numpy as np
from pydantic import model_validator

from geodem.workflow.models import SIDES
from geodem.workflow.schema import F, Int, Name, StepBase, register_step, time_steps, \
    unknown_group


def wave_field(sim):
    """The ``wave_boundary`` field attached to ``sim`` (None if there is none)."""
    return next((f for f in sim.fields if f.kind == "wave_boundary"), None)


def model_medium(cfg) -> tuple[Optional[dict], list]:
    """The elastic medium of the workflow's model (``scene`` with ``elements: elastic``) and
    the problems found: ``(medium or None, [(path, message)])``."""
    from geodem.workflow.models import BuildError

    m = cfg.model
    if getattr(m, "type", None) != "scene" or m.elements != "elastic" or m.fill != "lattice":
        return None, [(("kind",), "a wave needs an elastic lattice: use model type scene with "
                                  "fill: lattice and elements: elastic")]
    if m.material not in cfg.materials:
        return None, []
    try:
        return m.medium(cfg), []
    except BuildError:
        return None, []  # the model reports it


@register_step("wave_source")
class WaveSource(StepBase):
    """A plane P pulse (Ricker or Hann-windowed sine) sent up through the absorbing base of an
    elastic lattice scene, the sides absorbing against the flat free field (or plain dashpots,
    or rollers), the group ``receivers`` recorded (geodem.workflow.waves)."""

    example = {"kind": "wave_source", "duration": 0.0025, "wavelength": 0.5,
               "receivers": "ground"}
    example_model = {"type": "scene", "dim": 2, "d": 0.01, "elements": "elastic",
                     "lattice_origin": "corner", "half_mass": ["xmin", "xmax"],
                     "domain": {"box": {"min": [0.0, 0.0], "max": [0.1, 0.3]}},
                     "material": "rock", "groups": {"ground": {"surface": "ymax"}}}
    pulse: Literal["ricker", "sine"] = F("ricker", description="Incident particle-velocity "
                                                               "pulse")
    frequency: Optional[float] = F(None, unit="Hz", gt=0, description="Ricker peak / sine "
                                                                      "frequency")
    wavelength: Optional[float] = F(None, unit="m", gt=0,
                                    description="P wavelength: frequency c_p / wavelength "
                                                "(default 20 d when no frequency is given)")
    cycles: float = F(2.0, gt=0, le=20, description="Sine cycles under the Hann window")
    amplitude: float = F(0.01, unit="m/s", gt=0, description="Peak particle velocity of the "
                                                             "incident wave")
    duration: float = F(..., unit="s", gt=0, description="Simulated time (at least the pulse "
                                                         "plus one crossing of the model)")
    sides: Literal["free_field", "absorbing", "roller"] = F(
        "free_field", description="Side boundaries: dashpots against the flat free field "
                                  "(free_field), plain dashpots (absorbing) or held along "
                                  "their normal (roller)")
    side_faces: Optional[list[Literal[SIDES]]] = F(  # type: ignore[valid-type]
        None, min_length=1, description="Lateral faces that are boundaries (default all: xmin, "
                                        "xmax and, in 3-D, ymin, ymax)")
    side_depth: float = F(0.6, gt=0, le=2, description="Side slabs: depth in element "
                                                       "diameters (one element per lattice row)")
    incidence: Literal["base", "xmin"] = F(
        "base", description="Face the plane P wave enters through: base (travelling up, "
                            "vertical incidence) or xmin (travelling along +x, MatDEM's seismic "
                            "valley; the free-field faces are then the base and the y faces, "
                            "the xmax face a plain dashpot)")
    receivers: Optional[Name] = F(None, description="Group whose elements record velocity and "
                                                    "acceleration")
    record_every: Int = F(2, ge=1, le=1000, description="Receiver sampling interval [steps]")
    frames: Int = F(0, ge=0, le=1000, description="Particle-speed frames written to "
                                                  "<name>_frames/ (for pictures)")
    vtk_frames: Int = F(0, ge=0, le=100, description="Frames written to <name>_vtk/ (.vtp)")

    @model_validator(mode="after")
    def _freq(self):
        if self.frequency is not None and self.wavelength is not None:
            raise ValueError("give at most one of frequency and wavelength")
        return self

    def check(self, cfg, groups):
        med, out = model_medium(cfg)
        if self.receivers is not None and self.receivers not in groups:
            out.append((("receivers",), unknown_group(self.receivers, groups)))
        for k, side in enumerate(self.side_faces or []):
            if "xyz".index(side[0]) >= cfg.model.dim - 1:
                out.append((("side_faces", k), f"{side!r} is not a lateral face in "
                                               f"{cfg.model.dim}-D (the wave runs along the "
                                               f"last axis)"))
        if self.incidence != "base" and self.sides == "roller":
            out.append((("sides",), f"sides: roller with incidence: {self.incidence}: rollers "
                                    "are the flat section's under a wave from the base; allowed "
                                    "with a wave from a side: free_field, absorbing"))
        if self.incidence != "base" and self.side_faces is not None \
                and self.incidence not in self.side_faces:
            out.append((("side_faces",), f"the wave enters through {self.incidence}, which is "
                                         f"not among side_faces {list(self.side_faces)}; add "
                                         "it"))
        if med is None:
            return out
        lo, hi = cfg.model._bounds()
        axis = -1 if self.incidence == "base" else 0
        length = float(hi[axis] - lo[axis])
        pulse = self.make_pulse(med["cp"], cfg.model.d)
        need = pulse.duration + length / med["cp"]
        if self.duration < need:
            out.append((("duration",), f"duration = {self.duration:g} s ends before the pulse "
                                       f"({pulse.duration:.4g} s) has crossed the model "
                                       f"({length:g} m at c_p = {med['cp']:.0f} m/s); allowed: "
                                       f">= {need:.4g} s (2 crossings recommended: "
                                       f"{pulse.duration + 2 * length / med['cp']:.4g} s)"))
        return out

    def make_pulse(self, cp: float, d: float):
        from geodem.fields.wave import Pulse

        if self.frequency is not None:
            f = self.frequency
        else:
            f = cp / (self.wavelength if self.wavelength is not None else 20.0 * d)
        return Pulse(self.pulse, f, self.amplitude, self.cycles)

    def planned_steps(self, plan):
        return time_steps(plan.dt, duration=self.duration)

    def execute(self, ctx):
        from geodem.core import groups as grp
        from geodem.fields.wave import WaveBoundary, face_sets
        from geodem.io.vtk import VtkWriter

        info = ctx.model.info
        med, d = info["medium"], float(info["d"])
        pulse = self.make_pulse(med["cp"], d)
        total = self.planned_steps(ctx.plan)
        sim = ctx.sim
        field = wave_field(sim)
        ref_x = ctx.model.reference
        if field is None:
            st = ctx.state
            sets = face_sets(ref_x, d, self.side_faces, self.side_depth)
            if self.sides == "roller":
                side, axis = sets["side"], sets["side_axis"]

                def roll(s):
                    s.free[side, axis] = 0.0
                    s.v[side, axis] = 0.0

                ctx.decree(roll)
            ctx.set_eta(0.0)
            field = WaveBoundary(med["rho"], med["cp"], med["cs"], med["k0"], med["pitch"],
                                 med["thickness"], float(ref_x[:, -1].min()),
                                 float(ref_x[:, -1].max()), pulse.config(), sides=self.sides,
                                 record_every=self.record_every, t_start=st.time,
                                 incidence=self.incidence)
            rec = grp.members(st, self.receivers) if self.receivers else np.zeros(0, np.int64)
            field.set_sets(sets, rec, st)
            sim.add_field(field)
        n_frames = max(self.frames, self.vtk_frames, 1)
        chunk = max(1, total // n_frames)
        n_last = int(math.ceil(total / chunk))
        vtk_at = set(np.unique(np.linspace(1, n_last, self.vtk_frames).round().astype(int))
                     .tolist()) if self.vtk_frames else set()
        fdir = ctx.out_dir / f"{self.name}_frames"
        if self.frames:
            fdir.mkdir(exist_ok=True)
        vtk = VtkWriter(ctx.out_dir / f"{self.name}_vtk", f"{self.name}.pvd") if vtk_at \
            else None
        done = ctx.state.step - ctx.start_step
        t_wall = time.perf_counter()
        while done < total:
            done = min(total, (done // chunk + 1) * chunk)
            ctx.advance(done)
            s = ctx.state
            k = int(math.ceil(done / chunk))
            if self.frames:
                np.savez_compressed(fdir / f"frame_{k:05d}.npz", x=s.x.astype(np.float32),
                                    speed=np.linalg.norm(s.v, axis=1).astype(np.float32),
                                    time=s.time - field.t_start)
            if vtk is not None and k in vtk_at:
                vtk.write(s, s.step, ref_x)
        wall = time.perf_counter() - t_wall
        t, v, a = field.records()
        rec = field.sets["receivers"]
        np.savez_compressed(ctx.out_dir / f"{self.name}_receivers.npz",
                            receiver_x=ref_x[rec], t=t, v=v, a=a)
        res = {"pulse": pulse.config(), "wavelength_m": med["cp"] / pulse.f,
               "p_wave_speed": med["cp"], "s_wave_speed": med["cs"],
               "base_elements": int(len(field.sets["base"])),
               "side_elements": int(len(field.sets["side"])), "receivers": int(len(rec)),
               "records": int(len(t)), "run_wall_s": wall,
               "boundary_field_wall_s": field.wall,
               "boundary_field_us_per_step": 1e6 * field.wall / max(field.calls, 1)}
        if len(t) and len(rec):
            res["receiver_peak_velocity_max"] = float(np.linalg.norm(v, axis=2).max())
        res["incidence"] = self.incidence
        ctx.log(f"{self.name}: {pulse.kind} pulse {pulse.f:.4g} Hz from {self.incidence}, "
                f"{res['base_elements']} base "
                f"and {res['side_elements']} side elements ({self.sides}), {len(rec)} "
                f"receivers, {total} steps in {wall:.3g} s")
        return res
