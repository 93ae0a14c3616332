"""TBM disc cutter rolling over soft-strong interbedded rock (MatDEM's TBM case; PHYSICS.md
section 7).

* model ``tbm_rock``: a bonded block (:func:`geodem.build.specimen.make_specimen` box, the
  cutting direction x, the last axis vertical, 3-D: y across the cut) made of alternating
  layers of two materials, ``soft`` and ``strong``, whose interfaces dip at ``dip_deg`` in the
  x-vertical plane (positive: the layers go down towards +x). Layer of a point: its depth
  below the surface measured along the layer normal, ``u = (z_s - z) cos(dip) - x sin(dip) +
  layer_offset``, split into periods ``t_soft + t_strong`` (the ``first`` layer from u = 0).
  Every rock element gets the element parameters of its layer's material (kn, ks, xb, fs0,
  mu, mass; calibrated per-size parameters or the lattice conversion, scaled with the element
  diameter), then the block is balanced again. Groups: ``soft``, ``strong`` (the free rock of
  each material), ``base`` (fixed: the bottom layer, the far end, and the near end below the
  cut) and ``cutter``.

  The cutter is a rigid disc of radius ``cutter.radius`` made of fixed elements of diameter
  ``cutter.element_ratio x d_mean`` on its rim (2-D: one ring; 3-D: rings across the tip
  width ``cutter.tip_width``; their centres at ``R - r_c``, spaced ``1.001 x 2 r_c`` so they
  never touch one another: a contact between two cutter elements would rotate with the disc
  and wind up a shear spring). It starts left of the block, its lowest point
  ``cutter.penetration`` below the rock surface (``z_s``, the median of the highest element
  tops per d_mean-wide column), clear of the rock by at least d_mean / 4.

* step ``disc_cutter``: the disc translates along +x at ``speed`` V and rolls without slipping
  (angular velocity V / R) over ``distance``; the base is fixed and the rock damped at
  ``damping`` x MatDEM's standard damping. The kinematics live in the coupled field
  ``cutter_kinematics`` (every time step, numpy over the cutter elements only): the exact
  rigid-body pose ``X_i(t) = c0 + V t e_x + Rot(-V t / R) (x_i0 - c0)`` is tracked and each
  element's velocity is set to ``(X_i(t + dt) - x_i) / dt``, so the disc never drifts from a
  rigid rotation. The engine moves fixed elements by ``v dt`` and books their work
  ``-(F_old + F_new)/2 . dx`` (trapezoidal), so writing ``v`` of fixed elements (no kinetic
  energy in the books) keeps the energy books closed.

  Cutter force = sum over the cutter elements of ``m a`` (the contact reaction the engine
  stores for fixed DOFs): normal ``F_n`` = its vertical component (upwards), rolling
  ``F_r`` = minus its x component (resisting the motion), side ``F_s`` = its y component in
  3-D (across the cutting line; 0 in 2-D, where no force across the section exists).

  Results (summary.json): ``mean_normal_force``, ``peak_normal_force``,
  ``mean_rolling_force``, ``mean_side_force`` [N] (means over the full-engagement window:
  the samples whose whole contact chord is inside the block; peak: the largest sample mean,
  each averaged over every time step of ``distance / samples`` of travel), ``broken_bonds``
  (during the step; also by material: ``broken_bonds_soft``, ``_strong``, ``_interface``),
  ``specific_energy`` [MJ/m^3] = cutting work / removed volume, cutting work = the work of the
  cutter on the rock (its elements' booked external work), removed volume = the bulk volume
  (element volume / packing fraction) of the rock elements neither joined to the base by a
  chain of intact bonds nor part of the largest bonded cluster (chips and crushed grains); ``rolling_coefficient`` = F_r / F_n;
  ``csm_normal_force``, ``csm_rolling_force`` (CSM model, below) and ``normal_force_over_csm``;
  the layered fit ``normal_force_soft`` / ``normal_force_strong`` (least squares of the sample
  normal forces on the soft fraction of the contact chord); energy and heat (``cutting_work``,
  ``heat_total`` and its split). 2-D forces are those on the slice of thickness d_mean (the
  thickness of the 2-D calibration).

  CSM model (Rostami 1997): ``phi = acos((R - p)/R)``, ``P0 = C cbrt(sigma_c^2 sigma_t S /
  (phi sqrt(R T)))``, ``F_t = T R phi P0 / (1 + psi)``, ``F_n = F_t cos(phi/2)``, ``F_r = F_t
  sin(phi/2)`` (C = 2.12, psi = 0.2). sigma_c, sigma_t: the strengths of each layer's material
  as the DEM reproduces them (its calibration record's measured Cu, Tu; else the laboratory
  values). 2-D: T = the slice thickness, S = ``csm_spacing`` (a 2-D section has no
  neighbouring groove). See docs/tbm_cutter.md.

  Outputs: ``tbm_forces.csv`` (per sample), ``tbm_snapshots.png``, ``tbm_forces.png``,
  ``tbm_energy.png``, ``tbm_animation.gif``, ``tbm_vtk/*.vtp`` + ``tbm_vtk/tbm.pvd``.
"""
from __future__ import annotations

import csv
import math
from typing import Literal, Optional

import numpy as np

from geodem.cases.common import frames_gif, needs_model, read_rows, write_csv
from geodem.fields import CoupledField, register_field
from geodem.workflow.material import material_problems, specimen_material
from geodem.workflow.models import BuildError, BuiltModel, state_bytes_per_element
from geodem.workflow.schema import F, Int, ModelBase, Name, StepBase, Strict, register_model, \
    register_step
from geodem.workflow.animation import label_map, legend_outside, pick_frames, pyplot

CURVE = "tbm_forces.csv"
COLUMNS = ("step", "time", "travel", "normal_force", "rolling_force", "side_force",
           "soft_fraction", "cutting_work", "broken_bonds", "broken_soft", "broken_strong",
           "broken_interface", "heat_total", "closure_error")
FRAMES_DIR = "tbm_frames"
VTK_DIR = "tbm_vtk"
SOFT, STRONG = 0, 1
CSM_C, CSM_PSI = 2.12, 0.2


# ============================================================================ layers, CSM
def layer_of(x, surface: float, dip_deg: float, t_soft: float, t_strong: float,
             first: str = "soft", offset: float = 0.0):
    """``(material, layer)`` of points ``x`` (N, dim): material 0 soft / 1 strong, layer the
    running layer number from the surface pattern (0 = ``first``). The layer coordinate is the
    depth along the layer normal ``u = (surface - z) cos(dip) - x sin(dip) + offset`` (dip > 0:
    the interfaces go down towards +x)."""
    x = np.asarray(x, float)
    th = math.radians(dip_deg)
    u = (surface - x[:, -1]) * math.cos(th) - x[:, 0] * math.sin(th) + offset
    t1, t2 = (t_soft, t_strong) if first == "soft" else (t_strong, t_soft)
    period = t1 + t2
    k = np.floor(u / period)
    second = (u - k * period) >= t1
    layer = (2 * k + second).astype(np.int64)
    first_code = SOFT if first == "soft" else STRONG
    mat = np.where(second, 1 - first_code, first_code).astype(np.int8)
    return mat, layer


def csm_forces(sigma_c: float, sigma_t: float, R: float, T: float, p: float, S: float,
               C: float = CSM_C, psi: float = CSM_PSI) -> dict:
    """Forces on a disc cutter by the CSM model (Rostami 1997): contact angle ``phi``, base
    pressure ``P0`` [Pa], total ``F_t``, normal ``F_n`` and rolling ``F_r`` forces [N] for
    strengths ``sigma_c, sigma_t`` [Pa], radius ``R``, tip width ``T``, penetration ``p`` and
    spacing ``S`` [m]."""
    if not 0 < p < R:
        raise ValueError(f"penetration {p!r} must be between 0 and the radius {R!r}")
    phi = math.acos((R - p) / R)
    P0 = C * (sigma_c ** 2 * sigma_t * S / (phi * math.sqrt(R * T))) ** (1.0 / 3.0)
    Ft = T * R * phi * P0 / (1.0 + psi)
    return {"phi": phi, "P0": P0, "F_t": Ft, "F_n": Ft * math.cos(0.5 * phi),
            "F_r": Ft * math.sin(0.5 * phi), "T": T, "S": S, "R": R, "p": p,
            "sigma_c": sigma_c, "sigma_t": sigma_t}


def material_strengths(cfg, name: str, dim: int):
    """``(Cu, Tu, source)`` [Pa] of material ``name`` as the DEM reproduces it: the measured
    values of a library material's calibration record for ``dim``, else its laboratory values,
    else the rock properties; ``(None, None, reason)`` when unknown."""
    from geodem.cases.hydrofrac import material_tensile_strength
    from geodem.workflow.schema import LibraryMaterial, MacroMaterial

    Tu, src = material_tensile_strength(cfg, name, dim)
    m = cfg.materials.get(name)
    if isinstance(m, LibraryMaterial):
        from geodem.materials_library import load_material

        lib = load_material(m.library)
        cal = (lib.calibrated or {}).get(f"{dim}d")
        if m.use != "lattice" and cal and "Cu" in (cal.get("measured") or {}):
            return float(cal["measured"]["Cu"]), Tu, src.replace(".Tu", ".Cu/.Tu")
        return float(lib.values()["Cu"]), Tu, src
    if isinstance(m, MacroMaterial):
        return float(m.Cu), Tu, src
    return None, None, f"material {name!r} gives no strengths (element parameters)"


def _element_arrays(sm, d, d_mean: float, dim: int, thickness=None):
    """Element parameters ``kn, ks, xb, fs0, mu`` and mass for diameters ``d`` of the
    specimen material ``sm`` (per-size parameters, or the lattice conversion at d_mean scaled
    by ``d / d_mean``: PHYSICS.md section 2, mixed sizes)."""
    from geodem.build.packing import element_volume
    from geodem.materials import at_size, macro_to_micro

    if sm.element is not None:
        el = at_size(sm.element, d)
    else:
        m = sm.macro
        base = macro_to_micro(m["E"], m["nu"], m["Tu"], m["Cu"], m["mu_i"], m["rho"],
                              d_mean).element
        s = d / d_mean
        el = {"kn": base["kn"] * s, "ks": base["ks"] * s, "xb": base["xb"] * s,
              "fs0": base["fs0"] * s * s, "mu": base["mu"]}
    r = 0.5 * d
    vol = element_volume(r, 3) if dim == 3 else element_volume(r, 2, d if thickness is None
                                                                else thickness)
    el["mass"] = sm.rho * vol
    return el


#: unbalanced-force ratio the layered block is balanced to (geodem.core.engine.Simulation.balance)
LAYER_BALANCE_TOL = 1e-3
#: fewest elements across of that balance: over 2.5 (layers of 2.5 elements) ten rounds stopped
#: at a ratio of 1.8e-3
LAYER_BALANCE_MIN_ACROSS = 10.0


# ============================================================================ model
class CutterSpec(Strict):
    """The rigid disc cutter of ``tbm_rock``."""

    radius: float = F(0.03, unit="m", gt=0, description="Disc radius R")
    penetration: float = F(0.004, unit="m", gt=0, description="Penetration p below the rock "
                                                               "surface (0 < p < R)")
    tip_width: float = F(0.01, unit="m", gt=0, description="Tip width T (3-D: the rim's "
                                                            "width; 2-D: unused)")
    element_ratio: float = F(0.5, ge=0.2, le=1.0,
                             description="Cutter element diameter / d_mean")
    stiffness_factor: float = F(4.0, ge=1.0, le=100.0,
                                description="Cutter element kn / d = this x the stiffest rock "
                                            "kn / d")
    friction: float = F(0.2, ge=0, le=1, description="Cutter element friction (a contact "
                                                     "takes the smaller of its two elements)")


@register_model("tbm_rock")
class TbmRock(ModelBase):
    """A bonded block of soft-strong interbedded rock (layers of two materials whose interfaces
    dip at dip_deg) with a rigid disc cutter of fixed elements at its near end; groups soft,
    strong, base (fixed boundary) and cutter."""

    size_field = "size"
    example = {"type": "tbm_rock", "size": [0.12, 0.05], "d_mean": 0.005, "soft": "rock",
               "strong": "rock"}
    dim: Literal[2, 3] = F(2, description="Dimension (2-D: a vertical section along the cut)")
    size: list[float] = F([0.16, 0.05], unit="m", min_length=2, max_length=3,
                          description="Block length along the cut (x), [width across it (y, "
                                      "3-D)], height")
    d_mean: float = F(0.0025, unit="m", gt=0,
                      description="Mean element diameter (the resolution knob: elements ~ "
                                  "0.84 L H / (pi d^2 / 4) in 2-D)")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing "
                                                        "(make_specimen distri_rate)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    soft: Name = F(..., description="Material of the soft layers (a library material, rock "
                                    "properties or element parameters)")
    strong: Name = F(..., description="Material of the strong layers")
    layer_thickness: list[float] = F([0.012, 0.012], unit="m", min_length=2, max_length=2,
                                     description="Thickness of the soft and of the strong "
                                                 "layers (normal to the layers)")
    dip_deg: float = F(30.0, unit="deg", ge=-90, le=90,
                       description="Dip of the layer interfaces in the cutting plane "
                                   "(positive: going down towards +x)")
    first: Literal["soft", "strong"] = F("soft", description="Layer at the surface at x = 0")
    layer_offset: float = F(0.0, unit="m", ge=0,
                            description="Shift of the layer pattern along the layer normal")
    base_depth: float = F(1.0, gt=0, le=5, description="Fixed boundary depth in d_mean")
    cutter: CutterSpec = F(default_factory=CutterSpec, description="The disc cutter")

    def n_elements(self):
        vol = float(np.prod(self.size))
        el = math.pi / 4 * self.d_mean ** 2 if self.dim == 2 else math.pi / 6 * self.d_mean ** 3
        rock = (0.84 if self.dim == 2 else 0.63) * vol / el
        return max(1, int(rock + self._n_cutter()))

    def _r_cutter(self):
        return 0.5 * self.cutter.element_ratio * self.d_mean

    def _n_cutter(self):
        rc = self._r_cutter()
        ring = max(8, int(2 * math.pi * (self.cutter.radius - rc) / (2.002 * rc)))
        rows = 1 if self.dim == 2 else max(1, int(round(self.cutter.tip_width / (2.002 * rc))))
        return ring * rows

    def bytes_per_element(self):
        return state_bytes_per_element(self.dim, 16 if self.dim == 3 else 8) + 3000

    def material_refs(self):
        return [(("soft",), self.soft), (("strong",), self.strong)]

    def group_names(self):
        return ["all", "soft", "strong", "base", "cutter"]

    def n_across(self):
        return float(self.size[-1] / self.d_mean) if self.size else 1.0

    def check(self, cfg):
        from geodem.workflow.material import box_size_problems

        out = box_size_problems(self.size, self.dim, self.d_mean)
        c = self.cutter
        if not out:
            if self.size[-1] < c.penetration + (self.base_depth + 3) * self.d_mean:
                out.append((("size",), f"the block must be at least penetration + (base_depth "
                                       f"+ 3) d_mean = "
                                       f"{c.penetration + (self.base_depth + 3) * self.d_mean:g}"
                                       f" m high"))
            if self.dim == 3 and self.size[1] < c.tip_width + 4 * self.d_mean:
                out.append((("size",), f"the block must be at least tip_width + 4 d_mean = "
                                       f"{c.tip_width + 4 * self.d_mean:g} m wide (y)"))
        if c.penetration >= 0.5 * c.radius:
            out.append((("cutter", "penetration"), f"penetration {c.penetration:g} m: allowed "
                                                   f"0 < p < R/2 = {0.5 * c.radius:g} m"))
        if c.radius < 3 * self.d_mean:
            out.append((("cutter", "radius"), f"the disc radius must be at least 3 d_mean = "
                                              f"{3 * self.d_mean:g} m"))
        if c.penetration < 0.5 * self.d_mean:
            out.append((("cutter", "penetration"), f"penetration {c.penetration:g} m is below "
                                                   f"half an element (d_mean / 2 = "
                                                   f"{0.5 * self.d_mean:g} m)"))
        for k, t in enumerate(self.layer_thickness):
            if not t >= self.d_mean:
                out.append((("layer_thickness", k), f"{t:g} m: allowed >= d_mean = "
                                                    f"{self.d_mean:g} m"))
        for key in ("soft", "strong"):
            for path, msg in material_problems(cfg, getattr(self, key), self.dim, self.d_mean):
                out.append(((key,), msg))
        return out

    def _balance_layers(self, sim, tol: float = LAYER_BALANCE_TOL, rounds: int = 10) -> dict:
        """Standard balances after the layers took their rocks, until the unbalanced-force
        ratio is below ``tol``. The new stiffnesses unbalance the packing only across the layer
        interfaces, so the balance is over the thinner layer's thickness in elements (at least
        ``LAYER_BALANCE_MIN_ACROSS``, at most the block's height), not the block's height: its
        steps (50 per element across) and damping (eta_c / n) do not grow with the block, nor
        its cost faster than the element count."""
        across = min(max(min(self.layer_thickness) / self.d_mean, LAYER_BALANCE_MIN_ACROSS),
                     self.n_across())
        ratio, done = math.inf, 0
        while done < rounds and not ratio < tol:
            ratio = sim.balance(across)
            done += 1
        return {"sim": sim, "n_across": across, "rounds": done, "unbalanced_ratio": ratio}

    def layers(self, x, surface):
        """``(material, layer)`` of points ``x`` (see :func:`layer_of`)."""
        return layer_of(x, surface, self.dip_deg, self.layer_thickness[0],
                        self.layer_thickness[1], self.first, self.layer_offset)

    def build(self, cfg):
        from geodem.build.specimen import make_specimen, packing_notes
        from geodem.build.walls import append_elements
        from geodem.core import groups as grp
        from geodem.core.engine import Simulation
        from geodem.core.neighbors import build_rows

        dim, d = self.dim, self.d_mean
        sms = {}
        for key in ("soft", "strong"):
            try:
                sms[key] = specimen_material(cfg, getattr(self, key), dim, d)
            except ValueError as exc:
                raise BuildError((key,), str(exc)) from None
        kn_d = {k: _element_arrays(sm, np.array([d]), d, dim)["kn"][0] / d
                for k, sm in sms.items()}
        stiff = max(kn_d, key=kn_d.get)  # pack with the stiffer one: smaller locked overlaps
        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        try:
            st, rep = make_specimen("box", list(self.size), d, self.distri_rate,
                                    sms[stiff].material, dim, seed, element=sms[stiff].element)
        except ValueError as exc:
            raise BuildError(("size",), str(exc)) from None
        # ---- per-element parameters by layer
        surface = rock_surface(st.x, st.r, d)
        mat, layer = self.layers(st.x, surface)
        dd = 2.0 * st.r
        for code, key in ((SOFT, "soft"), (STRONG, "strong")):
            sel = mat == code
            el = _element_arrays(sms[key], dd[sel], d, dim)
            for name in ("kn", "ks", "xb", "fs0", "mu"):
                getattr(st, name)[sel] = el[name]
            st.m[sel] = el["mass"]
        balance = self._balance_layers(Simulation(st, monitor_every=0))
        st = balance.pop("sim").sync()
        st.v[:] = 0.0
        st.eta[:] = 0.0
        lo, hi = st.x.min(axis=0), st.x.max(axis=0)
        depth = self.base_depth * d
        base = (st.x[:, -1] <= lo[-1] + depth) | (st.x[:, 0] >= hi[0] - depth) | \
            ((st.x[:, 0] <= lo[0] + depth) &
             (st.x[:, -1] < surface - self.cutter.penetration - 3 * d))
        st.group[:] = 0
        st.groups = {"all": 0}
        grp.add_group(st, "soft", (mat == SOFT) & ~base)
        grp.add_group(st, "strong", (mat == STRONG) & ~base)
        grp.add_group(st, "base", base)
        n_rock = st.n
        # ---- the cutter
        c = self.cutter
        R, p, rc = c.radius, c.penetration, self._r_cutter()
        a = math.sqrt(R * R - (R - p) ** 2)
        face = float((st.x[:, 0] - st.r).min())
        centre = np.zeros(dim)
        centre[0] = face - a - 0.25 * d
        centre[-1] = surface - p + R
        if dim == 3:
            centre[1] = 0.5 * self.size[1]
        pts = disc_rim(centre, R, rc, dim, c.tip_width)
        # clear of the rock by d_mean / 4 at least (elements stick out of the surface)
        from scipy.spatial import cKDTree

        dist, idx = cKDTree(st.x).query(pts)
        gap = float((dist - st.r[idx] - rc).min())
        if gap < 0.25 * d:
            shift = 0.25 * d - gap + 1e-9
            pts[:, 0] -= 2.0 * shift
            centre[0] -= 2.0 * shift
        rho_c = 7800.0
        vol = math.pi / 6 * (2 * rc) ** 3 if dim == 3 else math.pi * rc * rc * 2 * rc
        kn_c = c.stiffness_factor * float((st.kn / (2.0 * st.r)).max()) * 2.0 * rc
        st = append_elements(st, pts, rc, rho_c * vol, kn=kn_c, ks=kn_c, mu=c.friction,
                             group="cutter")
        build_rows(st)
        st.step, st.time, st.dt = 0, 0.0, 0.0
        volume_el = float(rep["volume"]) * float(rep["shape_packing_fraction"])
        info = {"diameter": d, "size": list(self.size), "surface": surface,
                "cutter_centre": centre.tolist(), "cutter_radius": R, "penetration": p,
                "cutter_element_radius": rc, "contact_half_chord": a, "rock_face": face,
                "n_rock": n_rock, "far_end": float(hi[0] - depth),
                "n_cutter": int(st.n - n_rock),
                "packing_fraction": volume_el / float(rep["volume"]),
                "thickness": d if dim == 2 else None,
                "materials": {k: sms[k].label for k in sms},
                "material_warnings": [w for sm in sms.values() for w in sm.warnings]
                + packing_notes(rep) + ([] if balance["unbalanced_ratio"] < LAYER_BALANCE_TOL
                                        else [f"the layered block balanced to an unbalanced-"
                                              f"force ratio of {balance['unbalanced_ratio']:.2g}"
                                              f" in {balance['rounds']} rounds (target "
                                              f"{LAYER_BALANCE_TOL:g})"]),
                "packed_with": stiff,
                "layers": {"dip_deg": self.dip_deg, "thickness": list(self.layer_thickness),
                           "first": self.first, "offset": self.layer_offset},
                "n_soft": int((mat == SOFT).sum()), "n_strong": int((mat == STRONG).sum()),
                "layer_balance": balance,
                "specimen_report": {k: v for k, v in rep.items() if k != "packing"}}
        return BuiltModel(st, st.x.copy(), self.n_across(), info)


def rock_surface(x, r, d) -> float:
    """Level of the rock surface [m]: the median over d-wide columns of the highest element
    top (elements stick out of the cut plane by up to a radius)."""
    top = x[:, -1] + r
    cols = np.floor((x[:, 0] - x[:, 0].min()) / d).astype(np.int64)
    if x.shape[1] == 3:
        cols = cols * 100003 + np.floor((x[:, 1] - x[:, 1].min()) / d).astype(np.int64)
    order = np.lexsort((top, cols))
    last = np.r_[cols[order][1:] != cols[order][:-1], True]
    return float(np.median(top[order][last]))


def disc_rim(centre, R, rc, dim, tip_width) -> np.ndarray:
    """Centres of the rim elements of radius ``rc`` of a disc of radius ``R`` (outer surface at
    R) rolling in the x-vertical plane: a ring (2-D), rings across ``tip_width`` along y
    (3-D); neighbours are ``1.001 x 2 rc`` apart (they never touch)."""
    rr = R - rc
    n = max(8, int(2 * math.pi * rr / (2.002 * rc)))
    th = 2 * math.pi * np.arange(n) / n
    ring = np.stack([rr * np.cos(th), rr * np.sin(th)], axis=1)
    if dim == 2:
        return ring + np.asarray(centre, float)
    rows = max(1, int(round(tip_width / (2.002 * rc))))
    ys = 2.002 * rc * (np.arange(rows) - 0.5 * (rows - 1))
    pts = [np.column_stack([ring[:, 0], np.full(n, y), ring[:, 1]]) for y in ys]
    return np.concatenate(pts) + np.asarray(centre, float)


# ============================================================================ kinematics
@register_field("cutter_kinematics")
class CutterKinematics(CoupledField):
    """A rigid disc of fixed elements translating along +x at ``speed`` and rolling without
    slipping (angular velocity speed / radius, in the x-vertical plane) from ``t_start`` for
    ``duration``; at rest afterwards. Every coupling sets each element's velocity to carry it
    to its exact rigid-body position one time step later, and sums the contact reaction on the
    disc (``m a`` of its elements) for the force records."""

    reads = {"x": "m", "a": "m/s^2", "m": "kg"}
    writes = {"v": "m/s"}
    safety = 1.0

    def __init__(self, speed=1.0, radius=1.0, t_start=0.0, duration=0.0, centre0=(0.0, 0.0),
                 every=1):
        super().__init__(every)
        self.speed, self.radius = float(speed), float(radius)
        self.t_start, self.duration = float(t_start), float(duration)
        self.centre0 = np.asarray(centre0, float)
        self.idx = np.zeros(0, np.int64)
        self.rel0 = np.zeros((0, len(self.centre0)))
        self.fsum = np.zeros(len(self.centre0))
        self.nsum = 0

    def bind(self, idx, x):
        """The cutter elements ``idx`` at positions ``x`` (their pose at ``t_start``)."""
        self.idx = np.asarray(idx, np.int64)
        self.rel0 = np.asarray(x, float)[self.idx] - self.centre0
        self._index()

    def _index(self):
        # the cutter elements are appended last by the model: a slice is a view, no gather
        i = self.idx
        contiguous = i.size and np.array_equal(i, np.arange(i[0], i[0] + i.size))
        self.sel = slice(int(i[0]), int(i[0]) + i.size) if contiguous else i

    def attach(self, sim):
        self.fsum = np.zeros(sim.state.dim)
        self.nsum = 0

    def stable_dt(self, sim):
        return math.inf  # no dynamics of its own

    def pose(self, t):
        """Rigid-body positions of the cutter elements at time ``t`` [m]."""
        tau = min(max(t - self.t_start, 0.0), self.duration)
        c = self.centre0.copy()
        c[0] += self.speed * tau
        ang = -self.speed * tau / self.radius  # clockwise in the x-vertical plane: rolls to +x
        rot = np.eye(len(c))
        rot[0, 0] = rot[-1, -1] = math.cos(ang)
        rot[-1, 0] = math.sin(ang)
        rot[0, -1] = -rot[-1, 0]
        return self.rel0 @ rot.T + c

    def centre(self, t):
        tau = min(max(t - self.t_start, 0.0), self.duration)
        c = self.centre0.copy()
        c[0] += self.speed * tau
        return c

    def apply(self, sim):
        """Set the velocities that carry the disc to its pose one step later."""
        st = sim.state
        st.v[self.sel] = (self.pose(st.time + st.dt) - st.x[self.sel]) / st.dt

    def advance(self, sim, span):
        st = sim.state
        self.fsum += st.m[self.sel] @ st.a[self.sel]
        self.nsum += 1
        self.apply(sim)
        self.substeps += 1
        return 1

    def substep(self, sim, h):
        self.apply(sim)

    def take_force(self):
        """Mean contact force on the disc since the last call [N] (and the count)."""
        n = self.nsum
        f = self.fsum / n if n else np.zeros_like(self.fsum)
        self.fsum = np.zeros_like(self.fsum)
        self.nsum = 0
        return f, n

    def config(self):
        return {"speed": self.speed, "radius": self.radius, "t_start": self.t_start,
                "duration": self.duration, "centre0": self.centre0.tolist(),
                "every": self.every}

    def arrays(self):
        return {"idx": self.idx, "rel0": self.rel0, "fsum": self.fsum,
                "nsum": np.array([self.nsum])}

    def restore(self, arrays):
        self.idx = np.asarray(arrays["idx"], np.int64)
        self.rel0 = np.asarray(arrays["rel0"], float)
        self.fsum = np.asarray(arrays["fsum"], float).copy()
        self.nsum = int(np.asarray(arrays["nsum"])[0])
        self._index()

    def summary(self):
        return {"speed": self.speed, "angular_velocity": self.speed / self.radius,
                "couplings": self.substeps}


# ============================================================================ step
@register_step("disc_cutter")
class DiscCutter(StepBase):
    """Roll the tbm_rock model's disc cutter along +x at speed (rolling without slipping) over
    distance, at the model's penetration, the base fixed and the rock damped. Adds
    mean_normal_force, peak_normal_force, mean_rolling_force, mean_side_force, broken_bonds,
    specific_energy, rolling_coefficient, csm_normal_force, csm_rolling_force and
    normal_force_over_csm to summary.json; writes tbm_forces.csv, tbm_snapshots.png,
    tbm_forces.png, tbm_energy.png, tbm_animation.gif and tbm_vtk/*.vtp."""

    example = {"kind": "disc_cutter", "speed": 10.0, "distance": 0.01, "samples": 5,
               "frames": 2, "gif": False}
    example_model = {"type": "tbm_rock", "size": [0.1, 0.05], "d_mean": 0.008,
                     "soft": "rock", "strong": "rock",
                     "cutter": {"radius": 0.03, "penetration": 0.006}}
    speed: float = F(5.0, unit="m/s", gt=0, le=100,
                     description="Translation speed V of the disc (it rolls at V / R)")
    distance: float = F(0.12, unit="m", gt=0, description="Travel of the disc centre")
    damping: float = F(1.0, ge=0, le=100, description="Rock damping as a multiple of "
                                                       "MatDEM's standard damping eta_c / N")
    csm_spacing: Optional[float] = F(None, unit="m", gt=0,
                                     description="Cut spacing S of the CSM comparison "
                                                 "(default 10 x penetration)")
    csm_tip_width: Optional[float] = F(None, unit="m", gt=0,
                                       description="Tip width T of the CSM comparison "
                                                   "(default: 2-D the slice thickness d_mean,"
                                                   " 3-D the cutter's tip_width)")
    samples: Int = F(200, ge=4, le=100000, description="Force samples over the travel (each "
                                                       "the mean over its time steps)")
    frames: Int = F(4, ge=1, le=12, description="Snapshots in tbm_snapshots.png")
    gif: bool = F(True, description="Write tbm_animation.gif")
    gif_frames: Int = F(30, ge=2, le=300, description="Frames of the animation (and .vtp "
                                                      "files)")
    plot: bool = F(True, description="Draw the pictures (needs matplotlib)")

    def check(self, cfg, groups):
        m = cfg.model
        wrong = needs_model(cfg, "tbm_rock",
                            "disc_cutter needs the rock and its cutter: use model type tbm_rock")
        if wrong:
            return wrong
        reach = m.size[0] - (m.base_depth + 2.0) * m.d_mean
        if self.distance > reach:
            return [(("distance",), f"distance {self.distance:g} m would drive the disc into "
                                    f"the fixed far end; allowed: at most size[0] - "
                                    f"(base_depth + 2) d_mean = {reach:.4g} m for this block")]
        return []

    def planned_steps(self, plan):
        return max(1, int(math.ceil(self.distance / (self.speed * plan.dt) - 1e-9)))

    # ------------------------------------------------------------------ execution
    def execute(self, ctx):
        from geodem.core import groups, timestep

        st = ctx.state
        info = ctx.model.info
        model = ctx.cfg.model
        cut = groups.members(st, "cutter")
        rock = np.setdiff1d(np.arange(st.n), cut)
        total = self.planned_steps(ctx.plan)
        sim = ctx.sim
        field = next((f for f in sim.fields if f.kind == "cutter_kinematics"), None)
        if field is None:
            eta = np.zeros(st.n)
            eta[rock] = self.damping * timestep.standard_damping(st, ctx.plan.n_across)[rock]
            ctx.set_eta(eta)
            ctx.decree(lambda s: groups.fix(s, "base"), "base")
            field = CutterKinematics(self.speed, info["cutter_radius"], st.time,
                                     total * st.dt, info["cutter_centre"])
            field.bind(cut, st.x)
            sim.add_field(field)
            ctx.decree(lambda s: field.apply(sim), book_energy=False)
        ref = ctx.model.reference
        mat, _ = model.layers(ref, info["surface"])
        bonded0 = _bond_count(st, mat)
        w0 = 0.0  # the cutter is at rest before this step: its booked work starts at 0
        # ---------------------------------------------------------------- sampling
        path = ctx.out_dir / CURVE
        rows = read_rows(path, st.step) if ctx.resumed and path.exists() else []
        write_csv(path, COLUMNS, rows)
        fdir = ctx.out_dir / FRAMES_DIR
        fdir.mkdir(exist_ok=True)
        chunk = max(1, total // self.samples)
        n_frames = max(self.gif_frames if self.gif else 0, 2 * self.frames)
        frame_every = max(chunk, total // (n_frames * chunk) * chunk)
        t_start = field.t_start
        done = (st.step - ctx.start_step) // chunk * chunk
        if not rows and st.step == ctx.start_step:
            self._frame(fdir, ctx, field, mat, t_start, 0)
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(done)
            row = self._sample(ctx, field, mat, t_start, w0, info)
            rows.append(row)
            with open(path, "a", newline="") as fh:
                csv.writer(fh).writerow(row)
            if done % frame_every == 0 or done == total:
                self._frame(fdir, ctx, field, mat, t_start, done)
        return self._results(ctx, field, rows, mat, rock, cut, bonded0, w0, fdir)

    def _cracks(self, ctx, mat, t_start):
        log = ctx.sim.crack_log()
        log = log[log["time"] > t_start - 0.5 * ctx.state.dt]
        mi, mj = mat[log["i"]], mat[log["j"]]
        return log, int(((mi == SOFT) & (mj == SOFT)).sum()), \
            int(((mi == STRONG) & (mj == STRONG)).sum()), int((mi != mj).sum())

    def _sample(self, ctx, field, mat, t_start, w0, info):
        s = ctx.state
        f, _ = field.take_force()
        e = ctx.sim.energies()
        cut = field.idx
        log, ns, nh, ni = self._cracks(ctx, mat, t_start)
        travel = float(field.centre(s.time)[0] - field.centre0[0])
        return [int(s.step), float(s.time), travel, float(f[-1]), float(-f[0]),
                float(f[1]) if s.dim == 3 else 0.0,
                soft_fraction(ctx.cfg.model, field.centre(s.time), info),
                float(s.w_ext[cut].sum()) - w0, len(log), ns, nh, ni, e["heat_total"],
                e["closure_error"]]

    def _frame(self, fdir, ctx, field, mat, t_start, k):
        s = ctx.state
        log = ctx.sim.crack_log()
        log = log[log["time"] > t_start - 0.5 * s.dt]
        np.savez_compressed(fdir / f"frame_{int(k):09d}.npz", x=s.x.astype(np.float32),
                            r=s.r.astype(np.float32), ci=log["i"], cj=log["j"],
                            cut=field.idx, time=s.time - t_start,
                            travel=field.centre(s.time)[0] - field.centre0[0],
                            centre=field.centre(s.time), mat=mat)
        from geodem.io.vtk import VtkWriter

        VtkWriter(ctx.out_dir / VTK_DIR, "tbm.pvd").write(s, s.step, ctx.model.reference)

    def _results(self, ctx, field, rows, mat, rock, cut, bonded0, w0, fdir):
        st = ctx.state
        info = ctx.model.info
        model = ctx.cfg.model
        dim = st.dim
        a = np.array(rows, float) if rows else np.zeros((0, len(COLUMNS)))
        half = float(info["contact_half_chord"])
        start_gap = float(info["rock_face"]) - (float(info["cutter_centre"][0]) + half)
        # full engagement: the whole contact chord inside the block, its front at least R / 2
        # (and 3 d_mean) short of the fixed far end (the rock ahead is squeezed against it)
        far = float(info["far_end"]) - max(0.5 * float(info["cutter_radius"]),
                                           3.0 * float(info["diameter"]))
        front = float(info["cutter_centre"][0]) + half + a[:, 2] if len(a) else np.zeros(0)
        full = (a[:, 2] >= start_gap + 2.0 * half) & (front <= far) if len(a) else \
            np.zeros(0, bool)
        win = a[full] if full.any() else a
        Fn, Fr, Fs = win[:, 3], win[:, 4], win[:, 5]
        mean_n, mean_r = float(Fn.mean()), float(Fr.mean())
        log, ns, nh, ni = self._cracks(ctx, mat, field.t_start)
        # removed rock: elements no longer joined to the base by intact bonds
        det = detached(st, groups_members(st, "base"), rock)
        vol_el = _element_volume(st, det, float(info["diameter"]))
        removed = vol_el / float(info["packing_fraction"])
        work = float(st.w_ext[cut].sum()) - w0
        se = work / removed / 1e6 if removed > 0 else None
        e = ctx.sim.energies()
        # ---- layered fit: F_n = F_soft f + F_strong (1 - f)
        fsoft = win[:, 6]
        fit = None
        if len(win) >= 4 and np.ptp(fsoft) > 0.2:
            A = np.column_stack([fsoft, 1.0 - fsoft])
            fit = np.linalg.lstsq(A, Fn, rcond=None)[0]
        # ---- CSM
        thick = float(info["diameter"]) if dim == 2 else None
        T = self.csm_tip_width or (thick if dim == 2 else model.cutter.tip_width)
        S = self.csm_spacing or 10.0 * float(info["penetration"])
        csm = {}
        for key in ("soft", "strong"):
            Cu, Tu, src = material_strengths(ctx.cfg, getattr(model, key), dim)
            if Cu is not None and Tu is not None:
                csm[key] = dict(csm_forces(Cu, Tu, float(info["cutter_radius"]), T,
                                           float(info["penetration"]), S), source=src)
        frac = float(fsoft.mean()) if len(fsoft) else 0.5
        csm_n = csm_r = None
        if len(csm) == 2:
            csm_n = frac * csm["soft"]["F_n"] + (1 - frac) * csm["strong"]["F_n"]
            csm_r = frac * csm["soft"]["F_r"] + (1 - frac) * csm["strong"]["F_r"]
        phi = math.acos(1.0 - float(info["penetration"]) / float(info["cutter_radius"]))
        res = {
            "mean_normal_force": mean_n,
            "peak_normal_force": float(a[:, 3].max()) if len(a) else None,
            "mean_rolling_force": mean_r,
            "mean_side_force": float(Fs.mean()) if dim == 3 else 0.0,
            "mean_abs_side_force": float(np.abs(Fs).mean()) if dim == 3 else 0.0,
            "rolling_coefficient": mean_r / mean_n if mean_n else None,
            "tan_half_contact_angle": math.tan(0.5 * phi), "contact_angle": phi,
            "broken_bonds": len(log), "broken_bonds_soft": ns, "broken_bonds_strong": nh,
            "broken_bonds_interface": ni, "bonds_at_start": bonded0,
            "broken_fraction_soft": ns / bonded0["soft"] if bonded0["soft"] else None,
            "broken_fraction_strong": nh / bonded0["strong"] if bonded0["strong"] else None,
            "cracks_tensile": int((log["type"] == 1).sum()),
            "cracks_shear": int((log["type"] == 2).sum()),
            "cutting_work": work, "removed_elements": int(det.size),
            "removed_volume": removed,
            "removed_volume_note": "bulk volume of the rock elements off the bonded block "
                                   "(element volume / packing fraction"
                                   + (", slice thickness d_mean" if dim == 2 else "") + ")",
            "specific_energy": se,
            "heat_total": e["heat_total"], "heat_viscous": e["heat_viscous"],
            "heat_break_normal": e["heat_break_normal"],
            "heat_break_shear": e["heat_break_shear"], "heat_friction": e["heat_friction"],
            "elastic_energy": e["elastic"], "kinetic_energy": e["kinetic"],
            "work_external": e["work_external"],
            "energy_closure_rel_error": e["closure_error"],
            "full_engagement_samples": int(full.sum()), "samples": len(rows),
            "soft_fraction_mean": frac,
            "normal_force_soft": float(fit[0]) if fit is not None else None,
            "normal_force_strong": float(fit[1]) if fit is not None else None,
            "csm": csm, "csm_tip_width": T, "csm_spacing": S,
            "csm_normal_force": csm_n, "csm_rolling_force": csm_r,
            "normal_force_over_csm": mean_n / csm_n if csm_n else None,
            "rolling_force_over_csm": mean_r / csm_r if csm_r else None,
            "slice_thickness": thick, "speed": self.speed,
            "angular_velocity": self.speed / float(info["cutter_radius"]),
            "penetration": float(info["penetration"]),
            "cutter_radius": float(info["cutter_radius"]),
            "kinematics": field.summary(),
            "layer_balance": info.get("layer_balance"),
        }
        if dim == 2:
            res["side_force_note"] = "2-D section: no force across the cutting line exists"
        keys = ("mean_normal_force", "peak_normal_force", "mean_rolling_force",
                "mean_side_force", "broken_bonds", "specific_energy", "rolling_coefficient",
                "cutting_work", "heat_total", "csm_normal_force", "csm_rolling_force",
                "normal_force_over_csm", "normal_force_soft", "normal_force_strong",
                "broken_fraction_soft", "broken_fraction_strong")
        ctx.summary.update({k: res[k] for k in keys})
        def g(v):
            return "n/a" if v is None else f"{v:.4g}"

        ctx.log(f"disc cutter: F_n = {mean_n:.4g} N (peak {g(res['peak_normal_force'])} N), "
                f"F_r = {mean_r:.4g} N, F_r/F_n = {g(res['rolling_coefficient'])} "
                f"(tan(phi/2) = {res['tan_half_contact_angle']:.3g}); {len(log)} bonds broken "
                f"({ns} soft, {nh} strong, {ni} across); specific energy "
                f"{se if se is None else f'{se:.4g}'} MJ/m^3; CSM F_n = "
                f"{csm_n if csm_n is None else f'{csm_n:.4g}'} N")
        if self.plot and ctx.cfg.outputs.plots:
            frames = sorted(fdir.glob("frame_*.npz"))
            res["plot_snapshots"] = ctx.plot("tbm_snapshots.png", lambda p: plot_snapshots(
                p, frames, self.frames))
            window = (start_gap + 2.0 * half, far - half - float(info["cutter_centre"][0]))
            res["plot_forces"] = ctx.plot("tbm_forces.png", lambda p: plot_forces(
                p, a, res, window))
            res["plot_energy"] = ctx.plot("tbm_energy.png", lambda p: plot_energy(p, a, res))
            if self.gif:
                from geodem.workflow.animation import gif_writer_missing

                why = gif_writer_missing()
                if why:
                    res["animation"] = f"skipped: {why}"
                    ctx.runner.plots["tbm_animation.gif"] = res["animation"]
                else:
                    res["animation"] = ctx.plot("tbm_animation.gif", lambda p: write_gif(
                        p, frames))
        if f"{VTK_DIR}/tbm.pvd" not in ctx.runner.files:
            ctx.runner.files.append(f"{VTK_DIR}/tbm.pvd")
        if CURVE not in ctx.runner.files:
            ctx.runner.files.append(CURVE)
        return res


# ============================================================================ analysis
def soft_fraction(model, centre, info, n=41) -> float:
    """Fraction of the contact chord (the disc's cross-section below the surface, sampled on
    ``n`` points along the chord at mid depth) lying in soft rock."""
    surface = float(info["surface"])
    R, p = float(info["cutter_radius"]), float(info["penetration"])
    half = float(info["contact_half_chord"])
    xs = centre[0] + np.linspace(-half, half, n)
    depth = np.clip(surface - (centre[-1] - np.sqrt(np.maximum(R * R - (xs - centre[0]) ** 2,
                                                               0.0))), 0.0, p)
    pts = np.zeros((n, len(centre)))
    pts[:, 0] = xs
    pts[:, -1] = surface - 0.5 * depth
    mat, _ = model.layers(pts, surface)
    w = np.maximum(depth, 1e-30)
    return float((w * (mat == SOFT)).sum() / w.sum())


def groups_members(st, name):
    from geodem.core import groups

    return groups.members(st, name)


def _bond_count(st, mat) -> dict:
    """Intact bonds: ``total``, ``soft`` (both elements soft), ``strong``, ``interface``."""
    from geodem.core.state import BONDED

    i, k = np.nonzero(st.cstate == BONDED)
    j = st.nbr[i, k]
    once = i < j
    mi, mj = mat[i[once]], mat[j[once]]
    return {"total": int(once.sum()), "soft": int(((mi == SOFT) & (mj == SOFT)).sum()),
            "strong": int(((mi == STRONG) & (mj == STRONG)).sum()),
            "interface": int((mi != mj).sum())}


def detached(st, anchor, candidates) -> np.ndarray:
    """Elements of ``candidates`` neither joined to an ``anchor`` element by a chain of intact
    bonds nor part of the largest bonded cluster (the block, should a crack along the fixed
    base have cut it off): connected components of the bond graph."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from geodem.core.state import BONDED

    i, k = np.nonzero(st.cstate == BONDED)
    j = st.nbr[i, k]
    g = coo_matrix((np.ones(i.size), (i, j)), shape=(st.n, st.n))
    _, lab = connected_components(g, directed=False)
    cand = np.asarray(candidates)
    big = np.argmax(np.bincount(lab[cand])) if cand.size else -1
    keep = np.isin(lab, np.append(np.unique(lab[anchor]), big))
    return cand[~keep[cand]]


def _element_volume(st, idx, d_mean) -> float:
    from geodem.build.packing import element_volume

    if st.dim == 3:
        return float(element_volume(st.r[idx], 3).sum())
    return float(element_volume(st.r[idx], 2).sum()) * d_mean


# ============================================================================ io helpers
# ============================================================================ pictures

def _draw(ax, z):
    from matplotlib.collections import EllipseCollection, LineCollection

    from geodem.cases.thermal import crack_faces

    x, r = z["x"].astype(float), z["r"].astype(float)
    axes = [0, x.shape[1] - 1]
    xy = x[:, axes]
    cut = np.zeros(len(x), bool)
    cut[z["cut"]] = True
    mat = np.asarray(z["mat"])
    col = np.where(mat == SOFT, 0.0, 1.0)
    rock = ~cut
    coll = EllipseCollection(2 * r[rock], 2 * r[rock], np.zeros(rock.sum()), units="xy",
                             offsets=xy[rock], offset_transform=ax.transData, cmap="Pastel1")
    coll.set_array(col[rock])
    coll.set_clim(0, 8)
    ax.add_collection(coll)
    ax.add_collection(EllipseCollection(2 * r[cut], 2 * r[cut], np.zeros(cut.sum()), units="xy",
                                        offsets=xy[cut], offset_transform=ax.transData,
                                        facecolors="0.25"))
    if len(z["ci"]):
        segs = crack_faces(x, r, z["ci"], z["cj"], axes)
        ax.add_collection(LineCollection(segs, colors="red", linewidths=0.8))
    pad = float(r.max())
    lo, hi = xy.min(axis=0) - pad, xy.max(axis=0) + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    label_map(ax, ("x", "y" if x.shape[1] == 2 else "z"), fontsize=7)
    ax.set_title(f"travel {float(z['travel']) * 1e3:.1f} mm, {len(z['ci'])} broken bonds",
                 fontsize=8)


def plot_snapshots(path, frames, n):
    """``n`` snapshots over the run: rock coloured by layer (pink soft, grey-blue strong), the
    cutter's rim elements (dark), broken bonds (red, drawn across each bond)."""
    plt = pyplot()
    if plt is None:
        return None
    if not frames:
        return None
    pick = pick_frames(frames, n)
    fig, axes = plt.subplots(len(pick), 1, figsize=(7.0, 1.9 * len(pick) + 0.3), squeeze=False)
    for ax, k in zip(axes[:, 0], pick):
        _draw(ax, np.load(frames[k]))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_forces(path, a, res, window):
    """Normal, rolling (and side) forces against the travel, with the CSM estimates and the
    full-engagement window (dotted lines)."""
    plt = pyplot()
    if plt is None:
        return None
    if len(a) == 0:
        return None
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.0, 5.6), sharex=True,
                                 gridspec_kw={"height_ratios": [3, 1]})
    t = a[:, 2] * 1e3
    a1.plot(t, a[:, 3], "C0-", lw=1, label=f"normal (mean {res['mean_normal_force']:.3g} N)")
    a1.plot(t, a[:, 4], "C1-", lw=1, label=f"rolling (mean {res['mean_rolling_force']:.3g} N)")
    if np.any(a[:, 5]):
        a1.plot(t, a[:, 5], "C2-", lw=1, label="side")
    if res.get("csm_normal_force"):
        a1.axhline(res["csm_normal_force"], color="C0", ls="--", lw=1, label="CSM normal")
        a1.axhline(res["csm_rolling_force"], color="C1", ls="--", lw=1, label="CSM rolling")
    for w in window:
        a1.axvline(w * 1e3, color="k", ls=":", lw=0.8)
    a1.set_ylabel("force on the cutter [N]")
    a1.legend(fontsize=7, loc="best")
    a1.grid(alpha=0.3)
    a2.plot(t, a[:, 6], "C4-", lw=1)
    a2.set_ylabel("soft fraction")
    a2.set_xlabel("travel of the disc centre [mm]")
    a2.set_ylim(-0.05, 1.05)
    a2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_energy(path, a, res):
    """Cutting work, heat and broken bonds (by material) against the travel."""
    plt = pyplot()
    if plt is None:
        return None
    if len(a) == 0:
        return None
    fig, ax = plt.subplots(figsize=(7.0, 4.0))
    t = a[:, 2] * 1e3
    ax.plot(t, a[:, 7], "k-", label="cutting work")
    ax.plot(t, a[:, 12], "C3-", label="heat (all)")
    ax.set_xlabel("travel of the disc centre [mm]")
    ax.set_ylabel("energy [J]")
    ax2 = ax.twinx()
    ax2.plot(t, a[:, 9], "C6--", lw=1, label="broken bonds, soft")
    ax2.plot(t, a[:, 10], "C9--", lw=1, label="broken bonds, strong")
    ax2.plot(t, a[:, 11], "C7:", lw=1, label="broken bonds, interface")
    ax2.set_ylabel("broken bonds")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    # above the axes (twin axes: loc="best" would not see ax2's curves), with the closure error
    legend_outside(ax, h1 + h2, l1 + l2, fontsize=7, side="top", ncol=3, title_fontsize=8,
                   title=f"energy closure error {res['energy_closure_rel_error']:.2e}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write_gif(path, frames):
    """Animation of the snapshots (Pillow, else imageio)."""
    return frames_gif(path, frames, (6.0, 2.4), lambda ax, f: _draw(ax, np.load(f)), fps=7)


__all__ = ["TbmRock", "DiscCutter", "CutterKinematics", "CutterSpec", "layer_of", "csm_forces",
           "material_strengths", "rock_surface", "disc_rim", "soft_fraction", "detached"]
