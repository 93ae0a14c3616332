"""Hydraulic fracturing of a 2-D rock plate (MatDEM's case, Liu et al. 2020; PHYSICS.md section 7).

* model ``hydrofrac_plate``: a square bonded plate (``make_specimen`` box, side ``size``, group
  ``plate``) with an injection borehole of radius ``hole_radius`` cut at its centre (elements
  with centres inside removed, then elements left with fewer than two bonds, and balanced:
  :func:`geodem.cases.brazilian.prune_loose`). Groups: ``boundary`` (the elements within
  ``boundary_depth`` d_mean of the four outer faces) and ``wall`` (the elements within one
  d_mean of the borehole surface). 2-D thickness = ``d_mean`` (the 2-D area convention).
  ``coarsen: {factor, band, transition}`` (default off) builds a *graded* plate: fine elements
  (d_mean) within ``band`` of the borehole wall, growing to ``factor`` x d_mean over
  ``transition`` beyond it (:mod:`geodem.build.graded`; ``HydrofracPlate._graded``), so a
  hole many grains wide costs a fraction of the uniform plate's elements.

* step ``hydraulic_fracturing``: the pore-fluid field (:class:`geodem.fields.pore.PoreField`)
  is coupled to the plate; the borehole is a *cavity* whose pores are held at the injection
  pressure ``P_inj(t) = min(p0 + pressure_rate t, p_max)``; the fluid enters the rock through
  the throats, which an intact bond seals (conductance / ``bond_factor``) and a broken one
  opens: pressurised cracks grow (a hydraulic fracture). Boundary:

  - ``fixed`` (the paper's case: four fixed boundaries): the ``boundary`` elements are fixed;
    the plate is unstressed before injection (sigma_H = sigma_h = 0);
  - ``stress`` (confined): far-field stresses ``sigma_H`` along ``sigma_H_angle_deg`` (from x)
    and ``sigma_h`` across it (compression positive) are applied as boundary tractions
    ``F_i = -sigma n_i L_i t`` on the ``boundary`` elements (``n_i`` outward normal of the face
    the element is nearest to, ``L_i`` = face length / elements on it); they are ramped up over
    the first of ``confine_balances`` standard balances and held over the others, before the
    injection starts.

  Results (summary.json):

  - ``breakdown_pressure`` [Pa]: the injection pressure at the first *burst* of cracks: the
    first sample by which at least ``burst_cracks`` (5) bonds broke within the last
    ``burst_window`` (0.25 MPa) of injection pressure (isolated earlier breaks are damage; the
    first is reported as ``first_crack_pressure``). Samples are ``duration / samples`` apart
    (``pressure_rate x duration / samples`` Pa of injection pressure: 0.05 MPa by default);
  - ``hubbert_willis_pressure`` [Pa] = ``3 sigma_h - sigma_H + T - p_0`` (Hubbert & Willis
    1957; non-penetrating fluid, elastic plate, tension positive T), with ``T`` =
    ``tensile_strength`` if given, else the material's measured tensile strength from its
    library calibration record (``materials/NAME.yaml``, ``calibrated.2d.measured.Tu``: the
    direct-tension strength of the calibration specimen), else its laboratory ``Tu``; with
    ``tensile_strength_from: direct_tension``, the direct tension strength of a strip of the
    plate's own packing (:func:`strip_tensile_strength`); ``tensile_strength_source`` says
    which. ``fluid_penetration_at_breakdown`` [m] (:func:`penetration_depth`) tells whether
    the non-penetrating formula applies (docs/hydraulic_fracturing.md: it does);
  - ``crack_branches``, ``crack_angles_deg``: the crack arms from the borehole: the cracks
    (midpoints of broken bonds in the built plate) connected to the borehole (a chain of
    cracks less than 2.5 d_mean apart reaching within 2.5 d_mean of the wall), beyond
    ``hole_radius + 2 d_mean`` from the centre, clustered by their angle around the centre (a
    gap of more than ``arm_gap_deg`` between sorted angles separates arms; an arm needs
    ``arm_min_cracks`` cracks); the angle of an arm is the circular mean of its cracks' angles
    [deg, 0-360 from x];
  - ``dominant_crack_angle_deg``: the orientation (0-180 deg) of the arm reaching farthest from
    the borehole; with ``boundary: stress``, ``sigma_H_angle_deg`` and
    ``dominant_crack_misfit_deg`` (its angle to sigma_H, 0-90);
  - ``fluid_mass_balance_rel_error``, ``injected_mass`` [kg], ``cracks_tensile``,
    ``cracks_shear``, ``max_crack_radius`` [m], ``stopped_by``.

  Outputs: ``hydrofrac_curve.csv`` (per sample: injection pressure, cracks, injected mass,
  mass-balance error), ``hf_pressure.png`` (pore-pressure maps with cracks at ``frames``
  times), ``hf_history.png`` (injection pressure and cracks against time),
  ``hf_animation.gif`` (``gif_frames`` frames; Pillow, else imageio, else
  skipped with the reason in summary.json).

Fluid defaults: MatDEM's oil EOS (``k_f = 4.615e-5``, ``c_f = 870``): with water (bulk modulus
2.2 GPa) the tiny pores of a 2-D packing turn every elastic strain into large pore pressures
(the pore volume is a small difference of large areas), so the whole plate cracks under
undrained pore pressures before a fracture can run; the oil is a hundred times more
compressible. ``k_t = 3.6e-6`` kg/(Pa s) fills a freshly cracked pore in about a hundred time
steps of a d = 5 mm sandstone while bonded throats leak a hundred times slower.

Reference: Hubbert, M. K., Willis, D. G. (1957) Mechanics of hydraulic fracturing, Trans. AIME
210; Liu, C. et al. (2020) MatDEM - fast matrix computing of the discrete element method.
"""
from __future__ import annotations

import csv
import math
from typing import Literal, Optional

import numpy as np

from geodem.cases.common import frames_gif, needs_model, read_rows, write_csv
from geodem.workflow.material import material_problems
from geodem.cases.landslide import CoarsenSpec
from geodem.workflow.models import BuiltModel, state_bytes_per_element
from geodem.workflow.schema import F, Int, ModelBase, Name, Strict, StepBase, register_model, \
    register_step, time_steps
from geodem.workflow.animation import gif_writer_missing, label_map, legend_outside, pick_frames, \
    pyplot

CURVE = "hydrofrac_curve.csv"
COLUMNS = ("step", "time", "injection_pressure", "cracks_total", "cracks_tensile",
           "cracks_shear", "cracks_connected", "max_crack_radius", "injected_mass",
           "mass_balance_rel_error", "penetration_depth")
FRAMES_DIR = "hf_frames"
CRACK_LINK = 2.5  # x d_mean: cracks closer than this belong to one chain (an arm)


# ============================================================================ model
JAM_RETRIES = (1.0, 2.0, 4.0)  # relaxed graded plate: jamming overlaps tried, x RELAX_OVERLAP x xb


class PlateCoarsenSpec(CoarsenSpec):
    """Graded plate (docs/graded.md, docs/hydraulic_fracturing.md): fine elements (d_mean) in
    a band around the borehole, where the fracture starts, coarser ones (up to factor x
    d_mean) further out, with a linear transition (:mod:`geodem.build.graded`)."""

    band: float = F(0.03, unit="m", gt=0, le=1e4,
                    description="Fine elements (d_mean) up to this distance from the borehole "
                                "wall (at least one d_mean)")
    transition: float = F(0.02, unit="m", ge=0, le=1e4,
                          description="Distance beyond the fine band over which the diameter "
                                      "grows linearly from d_mean to factor x d_mean (0: a step)")
    bonds: Optional[Literal["relaxed", "stress_free"]] = F(
        None, description="relaxed: jammed to 0.1 xb and bonded within 0.1 xb, as "
                          "make_specimen's deposited packing (packing: deposit); "
                          "stress_free: jammed to 1e-4 d and made stress-free within the "
                          "material's bond_gap, as make_specimen's packing: isotropic; "
                          "default: the recipe the material was calibrated on")


@register_model("hydrofrac_plate")
class HydrofracPlate(ModelBase):
    """A square 2-D bonded plate with an injection borehole cut at its centre (groups
    ``plate``, ``boundary``: the outer layer, ``wall``: the borehole surface layer)."""

    size_field = "size"
    example = {"type": "hydrofrac_plate", "size": 0.06, "d_mean": 0.005, "hole_radius": 0.006,
               "material": "rock"}
    dim: Literal[2] = F(2, description="Dimension (2-D plates only)")
    size: float = F(0.2, unit="m", gt=0, description="Side of the square plate")
    d_mean: float = F(0.005, unit="m", gt=0,
                      description="Mean element diameter (the resolution knob: elements "
                                  "~ 1.07 (size / d_mean)^2)")
    hole_radius: float = F(0.01, unit="m", gt=0, description="Radius of the borehole")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing "
                                                        "(make_specimen distri_rate)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    material: Name = F(..., description="Material name (rock properties, per-size or direct "
                                        "element parameters, or a library material)")
    boundary_depth: float = F(1.0, gt=0, le=5,
                              description="Depth of the boundary group in d_mean (graded "
                                          "plate: in each element's nominal diameter)")
    coarsen: Optional[PlateCoarsenSpec] = F(None, description="Graded plate: coarser elements "
                                                              "away from the borehole "
                                                              "(docs/hydraulic_fracturing.md); "
                                                              "default off (uniform d_mean)")

    @property
    def centre(self):
        return np.full(2, 0.5 * self.size)

    def local_d(self, x):
        """Nominal element diameter [m] at the points ``x`` (N, 2): ``d_mean``, or with
        ``coarsen`` the graded size field (:func:`geodem.build.graded.ramp` of the distance
        beyond ``hole_radius + band`` from the borehole centre)."""
        x = np.asarray(x, float).reshape(-1, 2)
        if self.coarsen is None:
            return np.full(len(x), float(self.d_mean))
        from geodem.build.graded import ramp

        c = self.coarsen
        excess = np.linalg.norm(x - self.centre, axis=1) - (self.hole_radius + c.band)
        return ramp(excess, self.d_mean, c.factor, c.transition)

    def n_elements(self):
        hole = math.pi * self.hole_radius ** 2
        fill = 0.84 / (math.pi / 4 * self.d_mean ** 2)
        if self.coarsen is None:
            return max(1, int(fill * (self.size ** 2 - hole)))
        from geodem.build.graded import expected_count

        n = expected_count(np.zeros(2), np.full(2, self.size), self.local_d, self.d_mean,
                           self.distri_rate)[0]
        return max(1, int(n - fill * hole))

    def bytes_per_element(self):
        return state_bytes_per_element(2, 8) + 4000

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        return ["all", "plate", "boundary", "wall"]

    def n_across(self):
        return float(self.size / self.d_mean)

    def check(self, cfg):
        out = []
        if self.size < 10 * self.d_mean:
            out.append((("size",), f"the plate must be at least 10 d_mean = "
                                   f"{10 * self.d_mean:g} m across (got {self.size:g} m)"))
        if self.hole_radius < 0.5 * self.d_mean:
            out.append((("hole_radius",), f"the borehole must be at least d_mean / 2 = "
                                          f"{0.5 * self.d_mean:g} m in radius (one element "
                                          f"removed), got {self.hole_radius:g} m"))
        if self.hole_radius > self.size / 6:
            out.append((("hole_radius",), f"the borehole radius must be at most size / 6 = "
                                          f"{self.size / 6:g} m (a plate, not a ring), got "
                                          f"{self.hole_radius:g} m"))
        if self.coarsen is not None and self.coarsen.band < self.d_mean:
            out.append((("coarsen", "band"), f"{self.coarsen.band:g} m is thinner than one "
                        f"element (d_mean = {self.d_mean:g} m); allowed: band >= d_mean (the "
                        "fracture starts at the borehole wall: it needs fine elements)"))
        return out + material_problems(cfg, self.material, 2, self.d_mean)

    def build(self, cfg):
        from geodem.core import groups as grp
        from geodem.cases.brazilian import plate_with_hole

        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        graded = None
        if self.coarsen is None:
            st, removed, sm, rep, centre = plate_with_hole(
                cfg, self.material, (self.size, self.size), self.d_mean, self.distri_rate,
                seed, self.hole_radius, self.n_across())
        else:
            st, removed, sm, rep, centre, graded = self._graded(cfg, seed)
        st.groups = {"all": 0}
        st.group[:] = 0
        grp.add_group(st, "plate", np.arange(st.n))
        d = self.d_mean
        lo, hi = st.x.min(axis=0), st.x.max(axis=0)
        depth = self.boundary_depth * (d if graded is None else self.local_d(st.x)[:, None])
        wall = np.linalg.norm(st.x - centre, axis=1) <= self.hole_radius + d
        edge = np.any((st.x <= lo + depth) | (st.x >= hi - depth), axis=1)
        st.group[:] = 0
        st.groups = {"all": 0}
        grp.add_group(st, "plate", ~edge & ~wall)
        grp.add_group(st, "boundary", edge)
        grp.add_group(st, "wall", wall & ~edge)
        st.step, st.time = 0, 0.0
        T, src = material_tensile_strength(cfg, self.material)
        info = {"diameter": d, "size": self.size, "hole_radius": self.hole_radius,
                "centre": centre.tolist(), "thickness": d, "material": sm.label,
                "material_warnings": list(sm.warnings), "loose_removed": removed,
                "material_tensile_strength": T, "material_tensile_strength_source": src,
                "specimen_report": {k: v for k, v in rep.items() if k != "packing"}}
        if graded is not None:
            info["graded"] = graded
        return BuiltModel(st, st.x.copy(), self.n_across(), info)

    def _graded(self, cfg, seed):
        """The graded plate (``coarsen``): a graded packing of the square
        (:func:`geodem.build.graded.graded_packing`, size field :meth:`local_d`), cemented with
        the plate's element parameters at d_mean scaled to each element's diameter by the
        size law (``kn, ks, xb ~ d``, ``fs0 ~ d^2``, mass ``rho x volume``: what the uniform
        plate's :func:`~geodem.build.specimen.cement` does, so ``factor`` 1 gives the uniform
        plate's parameters), then made a plate of one thickness, d_mean: ``kn``, ``ks``,
        ``fs0`` and the mass times ``d_mean / d_nom`` (the size law's discs as thick as wide
        would make the coarse rings ``d_nom / d_mean`` times stiffer and stronger per unit
        length, and the stiff ring would shield the borehole wall: :func:`wall_hoop_stress`;
        docs/hydraulic_fracturing.md), and balanced; the borehole cut and the loose elements
        pruned as in :func:`geodem.cases.brazilian.plate_with_hole`. The bonds follow the
        recipe the material was calibrated on unless ``bonds`` says otherwise
        (:func:`plate_bonds`; another recipe is reported as a material warning).
        ``bonds: relaxed`` (``packing: deposit``): the packing is jammed to a mean contact
        overlap of ``RELAX_OVERLAP`` (0.1) x xb and pairs within ``CEMENT_GAP`` (0.1) x xb
        are bonded, as ``make_specimen`` relaxes and bonds a deposited packing (a bonded
        packing released from overlaps larger than xb springs apart and breaks its bonds:
        at the jamming default of 1e-4 d, 2.5 xb of the sandstone, 40 % broke); when the
        jamming finds no state so near its jamming point it is tried at 2 and 4 times that.
        ``bonds: stress_free`` (``packing: isotropic``, the 2-D library): jammed to the
        default 1e-4 d and made stress-free within the material's ``bond_gap``
        (:func:`geodem.build.isotropic.stress_free_network`), as ``isotropic_specimen``;
        only the start positions differ (placed by the size field). Bonds unstrained, and
        the jamming near 0.1 xb, 87 % of the relaxed build (332 of 382 s at a 16 d hole),
        is skipped.
        Returns ``(state, removed, specimen_material, report, centre, graded_info)``."""
        from geodem.build.graded import graded_packing
        from geodem.build.isotropic import stress_free_network
        from geodem.build.shapes import subset_state
        from geodem.build.specimen import CEMENT_GAP, RELAX_OVERLAP, cement, specimen_params
        from geodem.core.engine import Simulation
        from geodem.core.neighbors import spatial_sort
        from geodem.core.state import new_state
        from geodem.cases.brazilian import prune_loose
        from geodem.workflow.material import SpecimenMaterial, specimen_material
        from geodem.workflow.models import BuildError

        d, c, centre = self.d_mean, self.coarsen, self.centre
        sm = specimen_material(cfg, self.material, 2, d)
        recipe = (sm.element or {}).get("packing") or "deposit"  # make_specimen's 2-D default
        bonds = plate_bonds(c.bonds, recipe)
        if sm.element and (bonds == "stress_free") != (recipe == "isotropic"):
            # said, not silent: the plate is bonded by another recipe than the calibration's
            sm = SpecimenMaterial(sm.rho, sm.macro, sm.element, sm.label, sm.warnings + (
                f"the graded plate is bonded '{bonds}' but the material was calibrated on "
                f"packing: {recipe}: the rock is not exactly the calibrated one",))
        mat = sm.material
        params = specimen_params(mat, sm.element, d)
        lo, hi = np.zeros(2), np.full(2, self.size)
        if bonds == "stress_free":
            try:
                x, r, dn, prep = graded_packing(lo, hi, self.local_d, d, self.distri_rate,
                                                seed=seed)
            except (RuntimeError, ValueError) as exc:
                raise BuildError(("coarsen",), str(exc)) from None
            # stress-free bonds, as the 3-D specimens: touching pairs within a gap, positions
            # and radii adjusted until each bonded pair touches (lengths in d)
            gap = params.get("bond_gap")
            xs, rs, bi, _, _, added, res = stress_free_network(
                x / d, r / d, lo / d, hi / d,
                **({} if gap is None else {"gap": float(gap)}))
            prep.update({"bonds": int(bi.size), "rattler_bonds": int(added),
                         "max_radius_change": float(np.abs(rs * d / r - 1.0).max()),
                         "stress_free_residual": float(res)})
            x, r = xs * d, rs * d
            gap = 0.0
        else:
            for k, mult in enumerate(JAM_RETRIES):
                try:
                    x, r, dn, prep = graded_packing(
                        lo, hi, self.local_d, d, self.distri_rate, seed=seed,
                        overlap=mult * RELAX_OVERLAP * params["xb"] / d)
                    break
                except RuntimeError as exc:  # no jammed state near so small an overlap
                    if k == len(JAM_RETRIES) - 1:
                        raise BuildError(("coarsen",), str(exc)) from None
                except ValueError as exc:
                    raise BuildError(("coarsen",), str(exc)) from None
            prep["overlap_over_xb"] = mult * RELAX_OVERLAP
            gap = CEMENT_GAP * params["xb"]
        st = new_state(x, r, 1.0, width=16)
        rep = cement(st, gap, params, d_ref=d, rho=mat["rho"], n_across=self.n_across(),
                     seed=seed)
        # a plate of one thickness (d_mean): cement made each element a disc as thick as wide
        thick = d * prep["scale"] / dn  # 1 for the fine elements (their d_nom is d x scale)
        if np.any(thick != 1.0):
            for key in ("kn", "ks", "fs0", "m"):
                getattr(st, key)[:] *= thick
            sim = Simulation(st, monitor_every=0)
            for _ in range(10):
                if sim.balance(self.n_across()) < 1e-3:
                    break
            st = sim.sync()
        spatial_sort(st)
        st = subset_state(st, np.linalg.norm(st.x - centre, axis=1) > self.hole_radius)
        st, removed = prune_loose(st, 2, n_across=self.n_across())
        dl = self.local_d(st.x)
        fine = dl <= d * (1.0 + 1e-9)
        coarse = (dl >= c.factor * d * (1.0 - 1e-9)) & ~fine
        info = {"factor": c.factor, "band": c.band, "transition": c.transition, "bonds": bonds,
                "fine": int(fine.sum()), "transition_elements": int((~fine & ~coarse).sum()),
                "coarse": int(coarse.sum()), "d_max": float(2.0 * st.r.max()),
                "cement_bonds_broken": int(rep["bonds_broken"]),
                **{f"packing_{k}": v for k, v in prep.items()}}
        return st, removed, sm, rep, centre, info


def plate_bonds(bonds: Optional[str], recipe: str) -> str:
    """How the graded plate bonds its packing: ``bonds`` when given, else the recipe the
    material was calibrated on (``packing: isotropic`` -> ``stress_free``, the same jamming
    to 1e-4 d and stress-free bonds within ``bond_gap`` as
    :func:`geodem.build.specimen.isotropic_specimen`; ``deposit`` -> ``relaxed``)."""
    return bonds or ("stress_free" if recipe == "isotropic" else "relaxed")


def material_tensile_strength(cfg, name: str, dim: int = 2):
    """``(T [Pa], source)`` of material ``name``: the measured Tu of a library material's
    calibration record for ``dim`` (the calibration's direct-tension strength), else its
    laboratory Tu, else the rock properties' Tu; ``(None, reason)`` when none is known."""
    from geodem.workflow.schema import LibraryMaterial, MacroMaterial

    m = cfg.materials.get(name)
    if isinstance(m, LibraryMaterial):
        from geodem.materials_library import load_material

        try:
            lib = load_material(m.library)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            return None, f"library material {m.library!r} not readable: {exc}"
        cal = (lib.calibrated or {}).get(f"{dim}d")
        if m.use != "lattice" and cal and "Tu" in (cal.get("measured") or {}):
            sp = cal.get("specimen", {})
            test = sp.get("tensile_test", "brazilian").replace("_", " ")
            return float(cal["measured"]["Tu"]), (
                f"materials/{lib.name}.yaml calibrated.{dim}d.measured.Tu ({test} test of "
                f"the calibration, d_mean = {sp.get('d_mean')} m)")
        return float(lib.values()["Tu"]), f"materials/{lib.name}.yaml laboratory Tu"
    if isinstance(m, MacroMaterial):
        return float(m.Tu), f"material {name!r} Tu"
    return None, f"material {name!r} gives no tensile strength: set tensile_strength"


# ============================================================================ analysis
def hubbert_willis(sigma_H: float, sigma_h: float, T: float, p0: float = 0.0) -> float:
    """Breakdown pressure of a borehole, ``3 sigma_h - sigma_H + T - p0`` [Pa] (Hubbert &
    Willis 1957; stresses compression positive, non-penetrating fluid)."""
    return 3.0 * sigma_h - sigma_H + T - p0


def wall_hoop_stress(P, a, b, nu, stiffness=None, rings=400):
    """Hoop stress [Pa, tension positive] at the wall of a borehole of radius ``a`` [m] under
    the pressure ``P`` [Pa] in a 2-D plate (plane stress, Poisson ratio ``nu``) held at
    ``u = 0`` on the circle ``r = b`` (the fixed boundary; b = size / 2 for the square
    plate). ``stiffness(r)``: the in-plane stiffness (modulus x thickness) at radius ``r``
    relative to the wall's (None: uniform, ``P (1 - k x) / (1 + k x)``, ``x = a^2/b^2``,
    ``k = (1 + nu) / (1 - nu)``; e.g. ``local_d(r) / d_mean`` for a graded plate whose
    elements were discs as thick as wide, as the size law makes them: the graded plate is
    built with one thickness instead, stiffness 1). Lame's ``u = A r + B / r`` in ``rings``
    rings of constant stiffness, with ``u`` and the radial force per unit length continuous
    between them."""
    if stiffness is None:
        x = (a / b) ** 2
        k = (1.0 + nu) / (1.0 - nu)
        return P * (1.0 - k * x) / (1.0 + k * x)
    edges = np.linspace(a, b, int(rings) + 1)
    s = np.asarray(stiffness(0.5 * (edges[1:] + edges[:-1])), float)
    n = s.size
    M = np.zeros((2 * n, 2 * n))
    rhs = np.zeros(2 * n)

    def sig_r(k, r):  # radial stress (x (1 - nu^2) / E_wall) of ring k at r, coefficients
        return s[k] * np.array([1.0 + nu, -(1.0 - nu) / r ** 2])

    M[0, 0:2] = sig_r(0, a)
    rhs[0] = -P
    for k in range(n - 1):
        r = edges[k + 1]
        M[2 * k + 1, 2 * k:2 * k + 2] = [r, 1.0 / r]
        M[2 * k + 1, 2 * k + 2:2 * k + 4] = [-r, -1.0 / r]
        M[2 * k + 2, 2 * k:2 * k + 2] = sig_r(k, r)
        M[2 * k + 2, 2 * k + 2:2 * k + 4] = -sig_r(k + 1, r)
    M[2 * n - 1, 2 * n - 2:] = [b, 1.0 / b]
    A, B = np.linalg.solve(M, rhs)[:2]
    return float(s[0] * ((1.0 + nu) * A + (1.0 - nu) * B / a ** 2))


def connected_cracks(xy, centre, r_wall, link):
    """Indices of the crack points ``xy`` connected to the borehole: chains of points less
    than ``link`` apart that reach within ``r_wall + link`` of ``centre``. ``link`` may be one
    value per point (a graded plate: two points are linked within the larger of theirs)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(xy)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(xy).query_pairs(float(np.max(link)), output_type="ndarray")
    if np.ndim(link) and len(pairs):
        lk = np.asarray(link, float)
        dist = np.linalg.norm(xy[pairs[:, 0]] - xy[pairs[:, 1]], axis=1)
        pairs = pairs[dist <= np.maximum(lk[pairs[:, 0]], lk[pairs[:, 1]])]
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) \
        if len(pairs) else coo_matrix((n, n))
    _, lab = connected_components(g, directed=False)
    near = np.linalg.norm(xy - centre, axis=1) <= r_wall + link
    return np.flatnonzero(np.isin(lab, np.unique(lab[near])))


def crack_arms(xy, centre, r_min, gap_deg=30.0, min_cracks=3):
    """Crack arms around ``centre``: the points beyond ``r_min`` clustered by angle (a gap of
    more than ``gap_deg`` between sorted angles separates two arms; an arm has at least
    ``min_cracks`` points). Returns a list of dicts ``angle_deg`` (circular mean, 0-360),
    ``count``, ``reach`` (largest distance from the centre) [m], sorted by angle."""
    rel = np.asarray(xy, float) - np.asarray(centre, float)
    r = np.hypot(rel[:, 0], rel[:, 1]) if len(rel) else np.zeros(0)
    sel = r >= r_min
    rel, r = rel[sel], r[sel]
    if len(r) == 0:
        return []
    ang = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
    order = np.argsort(ang)
    a = ang[order]
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    cut = np.flatnonzero(gaps > gap_deg)
    arms = []
    if cut.size == 0:  # one ring of cracks all around: a single cluster
        groups = [order]
    else:
        groups = []
        for k in range(cut.size):
            lo, hi = cut[k - 1] + 1 if k > 0 else cut[-1] + 1, cut[k] + 1
            if k == 0:  # wraps around 360
                idx = np.concatenate([np.arange(lo, len(a)), np.arange(0, hi)])
            else:
                idx = np.arange(lo, hi)
            groups.append(order[idx])
    for g in groups:
        if len(g) < min_cracks:
            continue
        th = np.radians(ang[g])
        mean = math.degrees(math.atan2(np.sin(th).mean(), np.cos(th).mean())) % 360.0
        arms.append({"angle_deg": mean, "count": int(len(g)), "reach": float(r[g].max())})
    return sorted(arms, key=lambda d: d["angle_deg"])


def penetration_depth(r, P, p_inj, r_wall, width, frac=0.1):
    """How far the injected fluid has entered the rock [m]: the outer edge, measured from
    ``r_wall``, of the last of the consecutive rings (``width`` wide, from ``r_wall`` out) whose
    pores (distances ``r`` of their centroids from the borehole centre, pressures ``P``) hold a
    mean pressure of at least ``frac`` x ``p_inj``; 0 when the first ring holds less (or
    ``p_inj`` <= 0)."""
    r = np.asarray(r, float)
    P = np.asarray(P, float)
    if p_inj <= 0 or width <= 0:
        return 0.0
    k = 0
    while True:
        sel = (r >= r_wall + k * width) & (r < r_wall + (k + 1) * width)
        if not sel.any() or P[sel].mean() < frac * p_inj:
            return k * width
        k += 1


def strip_tensile_strength(ctx):
    """``(T [Pa], source)``: the direct tension strength of a strip of the plate's packing,
    ``10 x 20 d_mean``, built like the plate (same material, d_mean, distri_rate and seed)
    and pulled by the ``direct_tension`` step
    (strain rate 0.05 1/s, to 0.5 x the peak force); the run lies in ``tensile_test/`` of the
    run folder and is reused when its summary is there (a resumed run)."""
    import json
    from pathlib import Path

    import yaml

    from geodem.workflow import run_workflow

    cfg = ctx.cfg
    m = cfg.model
    d = float(m.d_mean)
    seed = m.seed if m.seed is not None else int(cfg.metadata.seed or 0)
    folder = ctx.out_dir / "tensile_test"
    done = folder / "out" / "summary.json"
    src = (f"direct tension of a {10 * d:g} x {20 * d:g} m strip of the plate's packing "
           f"(d_mean {d:g} m, distri_rate {m.distri_rate:g}, seed {seed}): tensile_test/")
    if not done.exists():
        mat = cfg.materials[m.material].model_dump(mode="json", exclude_none=True)
        base = Path(ctx.runner.prep.path).resolve().parent
        for key in ("file", "library"):
            v = mat.get(key)
            if isinstance(v, str) and v.endswith((".yaml", ".yml")) and \
                    not Path(v).is_absolute():
                mat[key] = str(base / v)
        doc = {"metadata": {"name": "hydrofrac_tensile_test", "seed": seed,
                            "description": "direct tension of a strip of the plate's packing"},
               "model": {"type": "specimen", "dim": 2, "size": [10 * d, 20 * d], "d_mean": d,
                         "distri_rate": float(m.distri_rate), "material": "rock"},
               "materials": {"rock": mat},
               "steps": [{"kind": "direct_tension", "name": "tension", "strain_rate": 0.05,
                          "max_strain": 0.0005, "drop": 0.5}],
               "outputs": {"observables": {"every": 1000}}}
        folder.mkdir(parents=True, exist_ok=True)
        wf = folder / "workflow.yaml"
        wf.write_text(yaml.safe_dump(doc, sort_keys=False))
        ctx.log("tensile strength: direct tension of a strip of the plate's packing "
                f"({wf.relative_to(ctx.out_dir)})")
        code, summ = run_workflow(wf, folder / "out", overwrite=True, echo=False,
                                  progress=False)
        if code != 0 or summ.get("status") != "ok":
            return None, f"{src} failed ({summ.get('status')}: {summ.get('error')})"
    T = json.loads(done.read_text()).get("tensile_strength")
    return (float(T) if T else None), src


def burst_samples(p, cracks, n, window):
    """Samples ending a burst: at least ``n`` more cracks than at the last sample whose
    pressure is ``window`` [Pa] or more below (the start counts as 0 cracks at p[0])."""
    p = np.asarray(p, float)
    c = np.asarray(cracks, float)
    # index of the last sample with p <= p_k - window (-1: before the first sample)
    j = np.searchsorted(np.maximum.accumulate(p), p - window, side="right") - 1
    before = np.where(j >= 0, c[np.maximum(j, 0)], 0.0)
    return np.flatnonzero(c - before >= n)


def axis_misfit_deg(a: float, b: float) -> float:
    """Angle between two orientations (axes, mod 180) [deg], 0-90."""
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


def boundary_tractions(x, idx, size_lo, size_hi, sigma_H, sigma_h, angle_deg, thickness):
    """Forces ``(len(idx), 2)`` [N] of the far-field stress (compression positive,
    ``sigma_H`` along ``angle_deg`` from x) on the boundary elements ``idx``: ``-sigma n L t``,
    ``n`` the outward normal of the nearest face, ``L`` the face length over the elements on
    that face."""
    th = math.radians(angle_deg)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    sig = R @ np.diag([sigma_H, sigma_h]) @ R.T
    p = x[idx]
    lo, hi = np.asarray(size_lo, float), np.asarray(size_hi, float)
    dist = np.stack([p[:, 0] - lo[0], hi[0] - p[:, 0], p[:, 1] - lo[1], hi[1] - p[:, 1]], 1)
    face = np.argmin(dist, axis=1)
    normals = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
    length = np.array([hi[1] - lo[1], hi[1] - lo[1], hi[0] - lo[0], hi[0] - lo[0]])
    out = np.zeros((len(idx), 2))
    for k in range(4):
        on = face == k
        if on.any():
            out[on] = -(sig @ normals[k]) * length[k] / on.sum() * thickness
    return out


# ============================================================================ step
class FluidSpec(Strict):
    """The pore fluid of the hydraulic fracturing step (geodem.fields.pore; see
    docs/pore_fluid.md)."""

    k_f: float = F(4.615e-5, unit="kg m^-3 Pa^-1", gt=0,
                   description="EOS slope: rho = k_f P + c_f (default MatDEM's oil; water "
                               "4.545e-7)")
    c_f: float = F(870.0, unit="kg/m^3", gt=0, description="EOS density at P = 0 (water 1000)")
    k_t: float = F(3.6e-6, unit="kg/(Pa s)", gt=0,
                   description="Throat coefficient: C = k_t max(opening + aperture, 0) / L")
    aperture: float = F(1.0e-5, unit="m", ge=0, description="Residual hydraulic aperture of a "
                                                            "closed contact")
    bond_factor: float = F(100.0, ge=1, description="An intact bond divides its throat's "
                                                    "conductance by this")
    p_min: Optional[float] = F(0.0, unit="Pa", description="Pressure floor of a pore the fluid "
                                                           "no longer fills (null: none)")
    drained_boundary: bool = F(False, description="Hold the outer pores at p0 (drained); "
                                                  "default: no flow across the outer boundary")
    every: Int = F(2, ge=1, le=100, description="Couple the fluid every N mechanical steps")


@register_step("hydraulic_fracturing")
class HydraulicFracturing(StepBase):
    """Hydraulic fracturing of a ``hydrofrac_plate``: the borehole pressure ramps at
    ``pressure_rate`` (up to ``p_max``) for ``duration`` seconds with the pore-fluid field on;
    the plate is fixed at its boundary (``boundary: fixed``, the paper's case) or loaded by the
    far-field stresses sigma_H, sigma_h (``boundary: stress``). Adds breakdown_pressure,
    hubbert_willis_pressure, crack_branches, crack_angles_deg, dominant_crack_angle_deg
    (sigma_H_angle_deg when confined) and fluid_mass_balance_rel_error to summary.json; writes
    hydrofrac_curve.csv, hf_pressure.png, hf_history.png and hf_animation.gif."""

    example = {"kind": "hydraulic_fracturing", "duration": 2e-5, "samples": 4, "frames": 2,
               "gif": False}
    example_model = HydrofracPlate.example
    boundary: Literal["fixed", "stress"] = F(
        "fixed", description="fixed: the boundary elements are fixed (unstressed plate); "
                             "stress: far-field stresses on the boundary elements")
    sigma_H: float = F(0.0, unit="Pa", ge=0, description="Largest horizontal far-field stress "
                                                         "(compression positive; stress "
                                                         "boundary)")
    sigma_h: float = F(0.0, unit="Pa", ge=0, description="Smallest horizontal far-field stress "
                                                         "(compression positive; stress "
                                                         "boundary)")
    sigma_H_angle_deg: float = F(0.0, unit="deg", ge=-180, le=180,
                                 description="Direction of sigma_H from the x axis")
    confine_balances: Int = F(3, ge=1, le=50,
                              description="Standard balances (50 N steps each) applying the "
                                          "far-field stress: ramped over the first, held over "
                                          "the others (stress boundary)")
    p0: float = F(0.0, unit="Pa", ge=0, description="Initial pore pressure (also the drained "
                                                    "boundary pressure)")
    pressure_rate: float = F(5.0e8, unit="Pa/s", gt=0,
                             description="Ramp rate of the borehole pressure (faster ramps "
                                         "branch into more arms)")
    p_max: float = F(1.0e8, unit="Pa", gt=0, description="Largest borehole pressure (the "
                                                         "paper's 100 MPa)")
    duration: float = F(2.0e-2, unit="s", gt=0, description="Injection time")
    stop_radius: Optional[float] = F(0.85, gt=0, le=1,
                                     description="Stop when a borehole-connected crack reaches "
                                                 "this fraction of size/2 from the centre "
                                                 "(null: run the whole duration)")
    damping: float = F(1.0, ge=0, description="Global damping as a multiple of MatDEM's "
                                              "standard damping eta_c / N (0: none)")
    fluid: FluidSpec = F(default_factory=FluidSpec, description="The pore fluid")
    tensile_strength: Optional[float] = F(
        None, unit="Pa", gt=0, description="T of Hubbert-Willis (default: see "
                                           "tensile_strength_from)")
    tensile_strength_from: Literal["calibration", "direct_tension"] = F(
        "calibration", description="Where T comes from when tensile_strength is not given: "
                                   "calibration (the material's calibration record: the "
                                   "direct-tension strength of the calibration specimen) or "
                                   "direct_tension (a direct tension "
                                   "test of a 10 x 20 d_mean strip of the plate's packing: same "
                                   "material, d_mean, distri_rate and seed, run in "
                                   "tensile_test/)")
    samples: Int = F(200, ge=2, le=100000, description="Samples over the duration")
    burst_cracks: Int = F(5, ge=1, description="Bonds broken within burst_window of "
                                               "injection pressure that make the breakdown "
                                               "burst")
    burst_window: float = F(2.5e5, unit="Pa", gt=0,
                            description="Injection-pressure window of the burst")
    arm_gap_deg: float = F(30.0, unit="deg", gt=0, lt=180,
                           description="Angular gap separating two crack arms")
    arm_min_cracks: Int = F(3, ge=1, description="Cracks an arm needs")
    frames: Int = F(4, ge=1, le=12, description="Pore-pressure maps in hf_pressure.png")
    gif: bool = F(True, description="Write hf_animation.gif")
    gif_frames: Int = F(30, ge=2, le=300, description="Frames of the animation")
    plot: bool = F(True, description="Draw the pictures (needs matplotlib)")

    def check(self, cfg, groups):
        out = needs_model(cfg, "hydrofrac_plate", "hydraulic_fracturing needs the plate with a "
                                                  "borehole: use model type hydrofrac_plate")
        if self.boundary == "fixed" and (self.sigma_H or self.sigma_h):
            out.append((("sigma_H",), "far-field stresses need boundary: stress (a fixed "
                                      "boundary leaves the plate unstressed)"))
        if self.sigma_h > self.sigma_H:
            out.append((("sigma_h",), f"sigma_h = {self.sigma_h:g} Pa exceeds sigma_H = "
                                      f"{self.sigma_H:g} Pa; allowed: sigma_h <= sigma_H"))
        if self.p_max <= self.p0:
            out.append((("p_max",), f"p_max = {self.p_max:g} Pa must exceed p0 = "
                                    f"{self.p0:g} Pa"))
        if self.fluid.p_min is not None and self.fluid.p_min > self.p0:
            out.append((("fluid", "p_min"), f"p_min = {self.fluid.p_min:g} Pa must not exceed "
                                            f"p0 = {self.p0:g} Pa"))
        return out

    def _confine_steps(self, n_across):
        from geodem.core import timestep

        if self.boundary != "stress":
            return 0
        return self.confine_balances * timestep.standard_balance_steps(n_across)

    def planned_steps(self, plan):
        return self._confine_steps(plan.n_across) + time_steps(plan.dt, duration=self.duration)

    # ------------------------------------------------------------------ execution
    def execute(self, ctx):
        from geodem.core import groups, timestep
        from geodem.fields.pore import PoreField

        st = ctx.state
        info = ctx.model.info
        d = float(info["diameter"])
        size = float(info["size"])
        R = float(info["hole_radius"])
        centre = np.asarray(info["centre"], float)
        ref = ctx.model.reference
        n_across = ctx.plan.n_across
        confine = self._confine_steps(n_across)
        # ---------------------------------------------------------------- set-up
        if not ctx.resumed:
            eta = self.damping * timestep.standard_damping(st, n_across)
            ctx.set_eta(eta)
            if self.boundary == "fixed":
                ctx.decree(lambda s: groups.fix(s, "boundary"), "boundary")
        if confine:
            bidx = groups.members(st, "boundary")
            lo = (ref - st.r[:, None]).min(axis=0)
            hi = (ref + st.r[:, None]).max(axis=0)
            full = boundary_tractions(ref, bidx, lo, hi, self.sigma_H, self.sigma_h,
                                      self.sigma_H_angle_deg, d)
            per = timestep.standard_balance_steps(n_across)
            n_inc = 20
            inc = max(1, per // n_inc)
            for k in range(n_inc):
                s0 = ctx.start_step + k * inc
                if st.step == s0:
                    frac = (k + 1) / n_inc

                    def put(s, frac=frac):
                        s.fload[bidx] = frac * full

                    ctx.decree(put, "boundary")
                if st.step < s0 + inc:
                    ctx.advance((k + 1) * inc)
                st = ctx.state
            ctx.advance(confine)
            st = ctx.state
        # ---------------------------------------------------------------- the fluid
        sim = ctx.sim
        field = next((f for f in sim.fields if f.kind == "pore_fluid"), None)
        if field is None:
            t0 = st.time
            bcs = [{"name": "injection", "role": "inject", "cavity": True,
                    "where": {"ball": [float(centre[0]), float(centre[1]), R]},
                    "pressure": self.p0, "rate": self.pressure_rate, "p_max": self.p_max,
                    "t_start": t0}]
            if self.fluid.drained_boundary:
                bcs.append({"name": "drain", "role": "drain", "where": {"boundary": True},
                            "pressure": self.p0})
            fl = self.fluid
            field = PoreField(k_f=fl.k_f, c_f=fl.c_f, k_t=fl.k_t, aperture=fl.aperture,
                              bond_factor=fl.bond_factor, p_init=self.p0, p_min=fl.p_min,
                              bcs=bcs, thickness=d, every=fl.every)
            sim.add_field(field)
        t_inj0 = field.bcs[0]["t_start"]
        inj_start = ctx.start_step + confine
        total = confine + max(1, int(math.ceil(self.duration / st.dt - 1e-9)))
        # ---------------------------------------------------------------- sampling
        path = ctx.out_dir / CURVE
        rows = []
        if ctx.resumed and path.exists():
            rows = read_rows(path, st.step, (0, 3, 4, 5, 6))
        write_csv(path, COLUMNS, rows)
        fdir = ctx.out_dir / FRAMES_DIR
        fdir.mkdir(exist_ok=True)
        n_inj = total - confine
        chunk = max(1, n_inj // self.samples)
        n_frames = max(self.gif_frames if self.gif else 0, 2 * self.frames)
        frame_every = max(chunk, n_inj // (n_frames * chunk) * chunk)
        reason = "duration"
        done = max(0, st.step - inj_start) // chunk * chunk
        if not rows and st.step == inj_start:
            self._frame(fdir, ctx, field, ref, 0)
        while done < n_inj:
            done = min(n_inj, done + chunk)
            ctx.advance(confine + done)
            s = ctx.state
            row = self._sample(ctx, field, ref, centre, R, d, t_inj0)
            rows.append(row)
            with open(path, "a", newline="") as fh:
                csv.writer(fh).writerow(row)
            if done % frame_every == 0 or done == n_inj:
                self._frame(fdir, ctx, field, ref, s.step - inj_start)
            if self.stop_radius is not None and row[7] >= self.stop_radius * 0.5 * size:
                reason = "stop_radius"
                self._frame(fdir, ctx, field, ref, s.step - inj_start)
                break
        return self._results(ctx, field, rows, ref, centre, R, d, size, reason, fdir)

    def _crack_xy(self, ctx, ref):
        log = ctx.sim.crack_log()
        return log, 0.5 * (ref[log["i"]] + ref[log["j"]]) if len(log) else np.zeros((0, 2))

    def _sample(self, ctx, field, ref, centre, R, d, t_inj0):
        s = ctx.state
        log, xy = self._crack_xy(ctx, ref)
        conn = connected_cracks(xy, centre, R, CRACK_LINK * ctx.cfg.model.local_d(xy))
        reach = float(np.linalg.norm(xy[conn] - centre, axis=1).max()) if conn.size else 0.0
        p_inj = field.bc_pressure("injection")
        cent = s.x[field.cells].mean(axis=1)
        pen = penetration_depth(np.linalg.norm(cent - centre, axis=1), field.update_pressure(),
                                p_inj, R, 0.5 * d)
        return [int(s.step), float(s.time), p_inj, len(log),
                int((log["type"] == 1).sum()), int((log["type"] == 2).sum()), int(conn.size),
                reach, field.injected, field.mass_balance_error(), pen]

    def _frame(self, fdir, ctx, field, ref, k):
        s = ctx.state
        log = ctx.sim.crack_log()
        P = field.update_pressure()
        np.savez_compressed(fdir / f"frame_{int(k):09d}.npz", x=s.x.astype(np.float32),
                            cells=field.cells.astype(np.int32), P=P.astype(np.float32),
                            ci=log["i"], cj=log["j"], time=s.time - field.bcs[0]["t_start"],
                            p_inj=field.bc_pressure("injection"))

    def _results(self, ctx, field, rows, ref, centre, R, d, size, reason, fdir):
        a = np.array(rows, float) if rows else np.zeros((0, len(COLUMNS)))
        burst = burst_samples(a[:, 2], a[:, 3], self.burst_cracks, self.burst_window) \
            if len(a) else np.zeros(0, int)
        first = np.flatnonzero(a[:, 3] > 0) if len(a) else np.zeros(0, int)
        breakdown = float(a[burst[0], 2]) if burst.size else None
        if self.tensile_strength is not None:
            T, src = self.tensile_strength, "tensile_strength of the step"
        elif self.tensile_strength_from == "direct_tension":
            T, src = strip_tensile_strength(ctx)
        else:
            T, src = (ctx.model.info.get("material_tensile_strength"),
                      ctx.model.info.get("material_tensile_strength_source"))
        sH, sh = (self.sigma_H, self.sigma_h) if self.boundary == "stress" else (0.0, 0.0)
        hw = hubbert_willis(sH, sh, T, self.p0) if T is not None else None
        log, xy = self._crack_xy(ctx, ref)
        conn = connected_cracks(xy, centre, R, CRACK_LINK * ctx.cfg.model.local_d(xy))
        arms = crack_arms(xy[conn], centre, R + 2.0 * d, self.arm_gap_deg, self.arm_min_cracks)
        dom = max(arms, key=lambda v: (v["reach"], v["count"])) if arms else None
        res = {
            "breakdown_pressure": breakdown,
            "breakdown_time": float(a[burst[0], 1] - field.bcs[0]["t_start"])
            if burst.size else None,
            "first_crack_pressure": float(a[first[0], 2]) if first.size else None,
            "hubbert_willis_pressure": hw,
            "fluid_penetration_at_breakdown": float(a[burst[0], 10]) if burst.size else None,
            "breakdown_over_hubbert_willis": breakdown / hw if breakdown and hw else None,
            "tensile_strength": T, "tensile_strength_source": src,
            "sigma_H": sH, "sigma_h": sh, "p0": self.p0, "boundary": self.boundary,
            "crack_branches": len(arms),
            "crack_angles_deg": [round(v["angle_deg"], 2) for v in arms],
            "crack_arm_counts": [v["count"] for v in arms],
            "crack_arm_reach": [v["reach"] for v in arms],
            "dominant_crack_angle_deg": dom["angle_deg"] % 180.0 if dom else None,
            "sigma_H_angle_deg": self.sigma_H_angle_deg % 180.0
            if self.boundary == "stress" else None,
            "fluid_mass_balance_rel_error": field.mass_balance_error(),
            "injected_mass": field.injected,
            "cracks_tensile": int((log["type"] == 1).sum()),
            "cracks_shear": int((log["type"] == 2).sum()),
            "cracks_connected": int(conn.size),
            "max_crack_radius": float(a[-1, 7]) if len(a) else 0.0,
            "final_injection_pressure": float(a[-1, 2]) if len(a) else None,
            "stopped_by": reason, "samples": len(rows),
            "fluid": field.summary(),
        }
        if "graded" in ctx.model.info:
            res["graded"] = ctx.model.info["graded"]
        if dom is not None and self.boundary == "stress":
            res["dominant_crack_misfit_deg"] = axis_misfit_deg(res["dominant_crack_angle_deg"],
                                                               res["sigma_H_angle_deg"])
        keys = ("breakdown_pressure", "hubbert_willis_pressure", "tensile_strength",
                "crack_branches", "crack_angles_deg", "dominant_crack_angle_deg",
                "sigma_H_angle_deg", "fluid_mass_balance_rel_error", "cracks_tensile",
                "cracks_shear")
        ctx.summary.update({k: res[k] for k in keys})
        if "dominant_crack_misfit_deg" in res:
            ctx.summary["dominant_crack_misfit_deg"] = res["dominant_crack_misfit_deg"]

        def mpa(v):
            return f"{v / 1e6:.3g} MPa" if v is not None else "n/a"

        ctx.log(f"hydraulic fracturing: breakdown {mpa(breakdown)} (Hubbert-Willis "
                f"{mpa(hw)}, T = {mpa(T)}); {len(arms)} crack arms at "
                f"{res['crack_angles_deg']} deg; mass balance "
                f"{res['fluid_mass_balance_rel_error']:.2e}; stopped by {reason}")
        if self.plot and ctx.cfg.outputs.plots:
            frames = sorted(fdir.glob("frame_*.npz"))
            res["plot_pressure"] = ctx.plot("hf_pressure.png", lambda p: plot_pressure_maps(
                p, frames, self.frames, centre, R, d, ref))
            res["plot_history"] = ctx.plot("hf_history.png", lambda p: plot_history(
                p, a, field.bcs[0]["t_start"], breakdown, hw))
            if self.gif:
                why = gif_writer_missing()
                if why:
                    res["animation"] = f"skipped: {why}"
                    ctx.runner.plots["hf_animation.gif"] = res["animation"]
                    ctx.log(f"hf_animation.gif {res['animation']}")
                else:
                    res["animation"] = ctx.plot("hf_animation.gif", lambda p: write_gif(
                        p, frames, centre, R, d, ref))
        return res


# ============================================================================ io helpers
# ============================================================================ pictures
def view_half_width(last, centre, R, d) -> float:
    """Half-width [m] of the square the maps show around the borehole: the cracks of the last
    frame ``last`` with a margin (at least 4 hole radii), at most the whole plate."""
    x = last["x"].astype(float)
    plate = float(np.max(np.abs(x - centre))) + d
    ci, cj = last["ci"], last["cj"]
    reach = (float(np.max(np.abs(0.5 * (x[ci] + x[cj]) - centre))) if len(ci) else 0.0)
    return min(plate, max(4.0 * R, 1.3 * reach + 2.0 * d))


def _draw_frame(ax, z, centre, R, d, ref, vmax, half=None, cmap="viridis"):
    from matplotlib.collections import LineCollection, PolyCollection

    x, cells, P = z["x"].astype(float), z["cells"], z["P"].astype(float) / 1e6
    pc = PolyCollection(x[cells], array=P, cmap=cmap, edgecolors="none", antialiased=False)
    pc.set_clim(0.0, vmax)
    ax.add_collection(pc)
    ci, cj = z["ci"], z["cj"]
    if len(ci):
        mid = 0.5 * (x[ci] + x[cj])
        e = x[cj] - x[ci]
        t = np.stack([-e[:, 1], e[:, 0]], 1)
        t /= np.maximum(np.linalg.norm(t, axis=1), 1e-300)[:, None]
        segs = np.stack([mid - 0.5 * d * t, mid + 0.5 * d * t], 1)
        ax.add_collection(LineCollection(segs, colors="red", linewidths=1.2))
    if half is None:
        ax.set_xlim(x[:, 0].min() - d, x[:, 0].max() + d)
        ax.set_ylim(x[:, 1].min() - d, x[:, 1].max() + d)
    else:
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    label_map(ax, fontsize=6)
    ax.set_title(f"t = {float(z['time']) * 1e3:.3g} ms, P = {float(z['p_inj']) / 1e6:.3g} MPa\n"
                 f"{len(ci)} cracks", fontsize=7)
    return pc



def plot_pressure_maps(path, frames, n, centre, R, d, ref):
    """Pore-pressure maps (colour: P [MPa]) with the cracks (red, across the broken bonds) at
    ``n`` times spread over the run, around the borehole (:func:`view_half_width`)."""
    plt = pyplot()
    if plt is None:
        return None
    if not frames:
        return None
    pick = pick_frames(frames, n)
    data = [np.load(frames[k]) for k in pick]
    vmax = max(float(z["p_inj"]) for z in data) / 1e6 or 1.0
    cols = len(data) if len(data) <= 4 else 3
    rws = int(math.ceil(len(data) / cols))
    fig, axes = plt.subplots(rws, cols, figsize=(2.4 * cols + 0.9, 2.6 * rws), squeeze=False,
                             layout="constrained")
    pc = None
    half = view_half_width(np.load(frames[-1]), centre, R, d)
    for ax, z in zip(axes.ravel(), data):
        pc = _draw_frame(ax, z, centre, R, d, ref, vmax, half)
    for ax in axes.ravel()[len(data):]:
        ax.axis("off")
    fig.colorbar(pc, ax=axes.ravel().tolist(), label="pore pressure [MPa]", shrink=0.9)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_history(path, a, t0, breakdown, hw):
    """Injection pressure and crack count against injection time."""
    plt = pyplot()
    if plt is None:
        return None
    if len(a) == 0:
        return None
    fig, ax = plt.subplots(figsize=(6.5, 4))
    t = (a[:, 1] - t0) * 1e3
    ax.plot(t, a[:, 2] / 1e6, "C0-", label="borehole pressure")
    if breakdown is not None:
        ax.axhline(breakdown / 1e6, color="C0", ls=":", lw=1,
                   label=f"breakdown {breakdown / 1e6:.3g} MPa")
    if hw is not None:
        ax.axhline(hw / 1e6, color="k", ls="--", lw=1, label=f"Hubbert-Willis {hw / 1e6:.3g} MPa")
    ax.set_xlabel("injection time [ms]")
    ax.set_ylabel("pressure [MPa]")
    ax2 = ax.twinx()
    ax2.plot(t, a[:, 3], "C3-", label="broken bonds")
    ax2.plot(t, a[:, 6], "C3--", label="connected to the borehole")
    ax2.set_ylabel("cracks", color="C3")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    legend_outside(ax, h1 + h2, l1 + l2, fontsize=8, side="top")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_gif(path, frames, centre, R, d, ref):
    """Animation of the pore-pressure maps: Pillow if installed, else imageio; returns None
    (skipped) when neither can write a GIF."""
    if pyplot() is None or not frames:
        return None
    data = [np.load(f) for f in frames]
    vmax = max(float(z["p_inj"]) for z in data) / 1e6 or 1.0
    half = view_half_width(data[-1], centre, R, d)
    return frames_gif(path, data, (4.2, 4.2),
                      lambda ax, z: _draw_frame(ax, z, centre, R, d, ref, vmax, half), fps=7)


__all__ = ["HydrofracPlate", "HydraulicFracturing", "FluidSpec",
           "hubbert_willis", "burst_samples", "penetration_depth", "strip_tensile_strength",
           "crack_arms", "connected_cracks", "wall_hoop_stress", "axis_misfit_deg",
           "boundary_tractions", "material_tensile_strength", "plate_bonds", "view_half_width"]
