"""Tensile lab tests as workflow pieces: the Brazilian disc (indirect tension) and direct tension.

* model ``brazilian_disc``: a packed, cut and cemented disc (:func:`geodem.build.specimen.
  make_specimen`, shape ``"disc"``; group ``specimen``) between two flat rigid platens of fixed
  elements (:func:`geodem.build.walls.add_walls`; groups ``bottom`` and ``top``) that touch the
  disc at its poles along the loading axis (the last axis: y in 2-D, z in 3-D; a 3-D disc has its
  axis along y, so it lies in the x-z plane). In 2-D the disc thickness is ``d_mean`` (the area
  convention of the ``specimen`` model); in 3-D it is ``thickness``. Elements left with fewer than
  two bonds by the cut are removed (:func:`prune_loose`), and each platen is moved until its
  closest element pair just touches (:func:`seat_platens`; a wall of discs is bumpy). The
  platens have friction (default 0.5): between frictionless flat platens a random disc, touched
  at two points that are not on one vertical line, rolls.

* step ``brazilian``: the bottom platen is fixed, the top platen moves down kinematically at
  ``v = loading_rate x D``, MatDEM's standard damping ``eta_c / N`` on (N = D / d_mean). Every
  sample records the load ``P`` (mean of the top and bottom platen reactions along the loading
  axis, compression positive) [N], the platen displacement ``delta = h0 - h`` (h = distance
  between the mean loading-axis coordinates of the platens) [m] and the crack counts. It stops
  when ``P < drop x P_peak`` after the peak and a crack lies within R/2 of the centre (the disc
  has split; a load drop without one is damage under a platen, and loading goes on), or when
  ``delta`` reaches ``max_strain x D``.
  Results (the first two also at the top of summary.json, with the crack counts):

  - ``tensile_strength`` = ``2 P_peak / (pi D t)`` [Pa] (Hertz / Timoshenko: the horizontal
    stress at the centre of a disc loaded by two opposite point loads ``P``; it is tensile and
    uniform along the loaded diameter), :func:`geodem.measure.brazilian_tensile_strength`;
  - ``peak_load`` = ``P_peak`` [N];
  - ``crack_start_offset`` = mean distance of the first ``crack_k`` cracks from the disc centre /
    radius (:func:`geodem.measure.crack_start_offset`; a crack sits at the midpoint of its
    two elements in the built, undeformed disc, projected onto the disc plane); 0 = at the
    centre, 1 = at the rim. A valid test splits from the centre; values near 1 mean the disc
    was crushed under the platens first;
  - ``diametral_fraction``: the fraction of the cracks within D/8 of the loaded diameter (in
    the built disc): near 1 for the diametral split of a valid test;
  - ``cracks_tensile``, ``cracks_shear``.

  The curve goes to ``brazilian_curve.csv``, the load-displacement curve and the crack map
  (cracks coloured by type) to ``brazilian.png``.

* step ``direct_tension`` on the ``specimen`` model (groups ``bottom`` and ``top``: the first and
  last element layers along the loading axis, bonded to the specimen): bottom fixed along the
  loading axis, top pulled kinematically at ``strain_rate x height``, standard damping on, until
  the force drops below ``drop x`` the peak or the strain reaches ``max_strain``. Tensile force
  ``F`` = mean of the bottom and top platen reactions (tension positive) [N]; strain
  ``(h - h0) / h0``; ``tensile_strength = F_peak / A`` with the uniaxial area convention
  ``A = width^(dim-1)`` (times ``thickness``, default d_mean, in 2-D). Results
  ``tensile_strength``, ``peak_strain``, ``E`` (tension slope, 10-50 % of the peak),
  ``cracks_tensile``, ``cracks_shear``; curve ``direct_tension_curve.csv``, picture
  ``direct_tension.png``.

Helpers: :func:`~geodem.measure.contact_stress` (Love-Weber stress of the contact forces of a set
of elements; in :mod:`geodem.measure`, for every model, and importable from here) and
:func:`disc_stress` (the Hertz / Timoshenko stress field of the diametrally loaded disc).

Caveat (tests/integration/test_brazilian.py): ``2P/(pi D t)`` is the centre stress of a
classical isotropic continuum. A disc of MatDEM's translation-only elements is one only without
shear springs (a central-force lattice matches the field within 1 % at 25 elements across);
with shear springs, which also resist the rigid rotation of element pairs, the horizontal
stress at the centre is only 0.16 x ``2P/(pi D t)`` at ks/kn = 0.45. ``tensile_strength`` is
therefore the conventional (nominal) Brazilian strength, not the tensile stress the centre
carried at the peak.
"""
from __future__ import annotations

import math
from typing import Literal, Optional

import numpy as np

from geodem.cases.common import PlatenTest, append_csv, needs_model, read_rows, write_csv
from geodem.measure import contact_stress  # noqa: F401 - written in geodem.measure, used here
from geodem.workflow.material import (SpecimenMaterial, disc_warnings, material_problems,
                                      specimen_material)
from geodem.workflow.models import BuildError, BuiltModel, state_bytes_per_element
from geodem.workflow.schema import (
    F,
    ModelBase,
    Name,
    StepBase,
    register_model,
    register_step,
)

BRAZILIAN_CURVE = "brazilian_curve.csv"
BRAZILIAN_COLUMNS = ("step", "time", "displacement", "load", "nominal_stress", "cracks_tensile",
                     "cracks_shear", "cracks_total")
TENSION_CURVE = "direct_tension_curve.csv"
TENSION_COLUMNS = ("step", "time", "strain", "stress", "force", "cracks_tensile", "cracks_shear",
                   "cracks_total")
MIN_ACROSS = 6  # the packer cannot fill a disc fewer element diameters across


def plate_with_hole(cfg, material: str, size, d_mean: float, distri_rate: float, seed: int,
                    hole_radius: float, n_across: float):
    """A 2-D bonded plate ``size = (Lx, Ly)`` [m] with a circular hole of ``hole_radius`` [m]
    at its centre: a :func:`~geodem.build.specimen.make_specimen` box, the hole cut out, loose
    elements pruned (:func:`prune_loose`). Shared by the borehole models (heated borehole,
    hydraulic fracturing). Returns ``(state, removed, specimen_material, report, centre)``;
    raises :class:`BuildError` on ``size`` when the plate cannot be built."""
    from geodem.build.shapes import subset_state
    from geodem.build.specimen import make_specimen

    sm = specimen_material(cfg, material, 2, d_mean)
    try:
        st, rep = make_specimen("box", list(size), d_mean, distri_rate, sm.material, 2, seed,
                                element=sm.element)
    except ValueError as exc:
        raise BuildError(("size",), str(exc)) from None
    centre = 0.5 * np.asarray(size, float)
    st = subset_state(st, np.linalg.norm(st.x - centre, axis=1) > hole_radius)
    st, removed = prune_loose(st, 2, n_across=n_across)
    return st, removed, sm, rep, centre


def prune_loose(state, min_bonds: int = 2, n_across: float | None = None, tol: float = 1e-3):
    """Remove the elements with fewer than ``min_bonds`` intact bonds, repeatedly (a removal
    can leave a neighbour short), and balance again (standard balances until the
    unbalanced-force ratio is below ``tol``, 10 at most) if any went.

    Cutting a random packing leaves a few loose or dangling elements at the surface (bonds lost
    while cementing); under a flat platen such an element is pushed into the disc at a small,
    friction-limited load and the contact never seats. Returns ``(state, removed)``."""
    from geodem.build.shapes import subset_state
    from geodem.build.specimen import settle, well_bonded

    keep = well_bonded(state, min_bonds=min_bonds)
    removed = int(state.n - keep.sum())
    if removed:
        state = subset_state(state, keep)
    if removed and state.n:
        state = settle(state, n_across, tol)
    return state, removed


def seat_platens(state, names, ax: int, against: str = "specimen") -> list:
    """Move each platen group of ``names`` (the first below, the second above along axis
    ``ax``) towards the ``against`` elements until its closest element pair just touches.

    ``add_walls`` puts a wall's tangent plane on the outermost element surface, but a wall of
    discs / spheres spaced 0.85 d is bumpy: the element at the pole usually sits between two
    wall elements, up to ~0.1 d away, and the platen would travel that far unloaded. Returns
    the distances moved [m]; rows are rebuilt."""
    from geodem.core import groups
    from geodem.core.neighbors import build_rows

    sp = groups.members(state, against)
    moved = []
    for name, sign in zip(names, (1.0, -1.0)):
        w = groups.members(state, name)
        face = state.x[w, ax].mean()
        near = sp[np.abs(state.x[sp, ax] - face) < 4.0 * float(state.r.max()) + np.abs(
            state.x[w, ax] - face).max() + float(state.r[w].max())]
        if near.size == 0:
            moved.append(0.0)
            continue
        gap = (np.linalg.norm(state.x[w][:, None] - state.x[near][None], axis=2)
               - state.r[w][:, None] - state.r[near][None]).min()
        state.x[w, ax] += sign * gap
        state.x_ref[w, ax] += sign * gap
        moved.append(float(gap))
    build_rows(state)
    return moved


MAX_BOND_GAP = 0.01  # x d_mean: the widest gap cemented (matters for near-unbreakable bonds)


def _bond_gap(material: SpecimenMaterial, d_mean: float):
    """The cementing gap: ``make_specimen``'s default (the smallest element ``xb``) unless the
    material's ``xb`` at ``d_mean`` exceeds ``MAX_BOND_GAP x d_mean`` (unbreakable or nearly
    unbreakable bonds): then ``MAX_BOND_GAP x d_mean``, since a gap of many diameters would
    bond every pair within it."""
    from geodem.materials import macro_to_micro

    if material.element is not None:
        xb = material.element["xb_per_d"] * d_mean
    else:
        m = material.macro
        xb = macro_to_micro(m["E"], m["nu"], m["Tu"], m["Cu"], m["mu_i"], m["rho"],
                            d_mean).element["xb"]
    return MAX_BOND_GAP * d_mean if xb > MAX_BOND_GAP * d_mean else None


def disc_with_platens(dim, diameter, d_mean, material: SpecimenMaterial, *, thickness=None,
                      distri_rate=0.2, seed=0, platen_friction=0.5, platen_stiffness=1.0):
    """A bonded disc between two flat platens touching its poles.

    The disc (group ``specimen``) comes from ``make_specimen("disc", ...)``: diameter ``D``
    [m], in 3-D thickness ``t`` [m] along y; its centre is ``(D/2, D/2)`` in 2-D and
    ``(D/2, t/2, D/2)`` in 3-D. Elements left with fewer than 2 bonds are removed
    (:func:`prune_loose`). The platens (groups ``bottom`` and ``top``, every DOF fixed) are
    layers of elements of diameter ``d_mean`` below and above the disc along the last axis,
    reaching one ``d_mean`` past it on every side, each moved until it just touches the disc
    (:func:`seat_platens`); their element ``kn`` is ``platen_stiffness`` x the stiffest
    ``kn / d`` of the disc x ``d_mean`` and their friction ``platen_friction`` (a contact takes
    the smaller friction of its two elements).

    Returns ``(state, report, centre)``; raises ``ValueError`` for unbuildable parameters."""
    from geodem.build.specimen import make_specimen
    from geodem.build.walls import add_walls
    from geodem.core import groups

    size = (float(diameter),) if dim == 2 else (float(diameter), float(thickness))
    # never tiled in all axes: a disc cut from cells periodic along its thickness splits
    # early (0.55-5.62 MPa against 8.3 jammed whole: docs/performance.md, "A tiled lab
    # specimen"), and one whose poles are cut touches a platen with an element or two; a
    # large 3-D disc's box is a strip periodic along x alone, its sides (y) and poles (z)
    # flat as jammed whole (docs/brazilian.md, "Large 3-D discs")
    st, rep = make_specimen("disc", size, d_mean, distri_rate, material.material, dim, seed,
                            element=material.element, gap=_bond_gap(material, d_mean),
                            tile=False, periodic_axes=(0,) if dim == 3 else None)
    st, removed = prune_loose(st, 2, n_across=float(diameter) / d_mean)
    if st.n < 10:
        raise ValueError(f"only {st.n} elements of the disc have 2 bonds or more: make the "
                         "disc larger or d_mean smaller")
    R = 0.5 * float(diameter)
    centre = [R, R] if dim == 2 else [R, 0.5 * float(thickness), R]
    kn = platen_stiffness * float((st.kn / (2.0 * st.r)).max()) * d_mean
    sides = ["ymin", "ymax"] if dim == 2 else ["zmin", "zmax"]
    st = add_walls(st, sides, names=["bottom", "top"], d_wall=d_mean, gap=0.0, margin=1.0,
                   kn=kn, mu=platen_friction)
    seated = seat_platens(st, ["bottom", "top"], dim - 1)
    st.step, st.time = 0, 0.0  # a fresh model: its time steps count from 0
    rep = dict(rep, loose_removed=removed, platen_seating=seated, platen_kn=kn,
               n_disc=int(groups.members(st, "specimen").size))
    return st, rep, centre


# ============================================================================ stress
def disc_stress(x, y, P, D, t):
    """Stress [Pa] of an isotropic elastic disc (plane stress or strain alike) of diameter ``D``
    and thickness ``t`` squeezed by two opposite point loads ``P`` [N] at ``(0, +-D/2)``
    (Hertz 1883, Timoshenko & Goodier section 41: two Flamant fields plus a uniform tension
    ``P / (pi R t)``), at ``(x, y)`` [m] from the centre, tension positive; returns
    ``(sigma_xx, sigma_yy, sigma_xy)``::

        sigma_xx = -(2P/(pi t)) [x^2 (R - y)/r1^4 + x^2 (R + y)/r2^4 - 1/D]
        sigma_yy = -(2P/(pi t)) [(R - y)^3/r1^4 + (R + y)^3/r2^4 - 1/D]
        sigma_xy =  (2P/(pi t)) [x (R - y)^2/r1^4 - x (R + y)^2/r2^4]
        r1^2 = x^2 + (R - y)^2,  r2^2 = x^2 + (R + y)^2,  R = D/2

    At the centre ``sigma_xx = 2P/(pi D t)`` (the Brazilian tensile stress, uniform along the
    loaded diameter) and ``sigma_yy = -6P/(pi D t)``."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    R = 0.5 * D
    r1 = (x * x + (R - y) ** 2) ** 2
    r2 = (x * x + (R + y) ** 2) ** 2
    k = 2.0 * P / (math.pi * t)
    sxx = -k * (x * x * (R - y) / r1 + x * x * (R + y) / r2 - 1.0 / D)
    syy = -k * ((R - y) ** 3 / r1 + (R + y) ** 3 / r2 - 1.0 / D)
    sxy = k * (x * (R - y) ** 2 / r1 - x * (R + y) ** 2 / r2)
    return sxx, syy, sxy


# ============================================================================ model
@register_model("brazilian_disc")
class BrazilianDisc(ModelBase):
    """A bonded random disc between two flat rigid platens for the Brazilian test: packed, cut
    and cemented (``make_specimen`` shape disc; group ``specimen``), platens ``bottom`` and
    ``top`` (fixed elements) touching it at its poles along the loading axis (y in 2-D, z in
    3-D; a 3-D disc has its axis along y)."""

    size_field = "diameter"
    example = {"type": "brazilian_disc", "dim": 2, "diameter": 0.04, "d_mean": 0.005,
               "material": "rock"}
    dim: Literal[2, 3] = F(2, description="Dimension")
    diameter: float = F(0.1, unit="m", gt=0, description="Disc diameter D")
    thickness: Optional[float] = F(None, unit="m", gt=0,
                                   description="3-D only: disc thickness t along y (default "
                                               "D/2); in 2-D t = d_mean")
    d_mean: float = F(0.005, unit="m", gt=0, description="Mean element diameter")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing "
                                                        "(make_specimen distri_rate)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    material: Name = F(..., description="Material name (rock properties, per-size or direct "
                                        "element parameters, or a library material)")
    platen_friction: float = F(0.5, ge=0,
                               description="Platen element friction coefficient (a contact "
                                           "takes the smaller of its two elements'); > 0 keeps "
                                           "the disc from rolling between the platens")
    platen_stiffness: float = F(1.0, gt=0, le=100,
                                description="Platen element kn / d over the disc's stiffest "
                                            "kn / d (1: as stiff as the rock)")

    def disc_thickness(self) -> float:
        """t [m]: ``thickness`` in 3-D (default D/2), ``d_mean`` in 2-D."""
        if self.dim == 2:
            return self.d_mean
        return self.thickness if self.thickness is not None else 0.5 * self.diameter

    def n_elements(self):
        area = math.pi / 4 * self.diameter ** 2
        if self.dim == 2:
            disc = 0.84 * area / (math.pi / 4 * self.d_mean ** 2)
            wall = 2 * ((self.diameter + 3 * self.d_mean) / (0.85 * self.d_mean) + 1)
        else:
            t = self.disc_thickness()
            disc = 0.63 * area * t / (math.pi / 6 * self.d_mean ** 3)
            wall = 2 * ((self.diameter + 3 * self.d_mean) / (0.85 * self.d_mean) + 1) * \
                ((t + 3 * self.d_mean) / (0.85 * self.d_mean) + 1)
        return max(1, int(disc + wall))

    def bytes_per_element(self):
        return state_bytes_per_element(self.dim, 16 if self.dim == 3 else 8) + 3000

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        return ["all", "specimen", "bottom", "top"]

    def n_across(self):
        return float(self.diameter / self.d_mean)

    def check(self, cfg):
        out = []
        if self.dim == 2 and self.thickness is not None:
            out.append((("thickness",), "a 2-D disc has thickness d_mean (the area convention "
                                        "of the 2-D models); thickness is for dim: 3 only"))
        if self.diameter < MIN_ACROSS * self.d_mean:
            out.append((("diameter",), f"the disc must be at least {MIN_ACROSS} d_mean = "
                                       f"{MIN_ACROSS * self.d_mean:g} m across (got "
                                       f"{self.diameter:g} m = {self.diameter / self.d_mean:.3g} "
                                       f"d_mean); 20 or more give a useful test"))
        if self.dim == 3 and self.disc_thickness() < 2 * self.d_mean:
            out.append((("thickness",), f"a 3-D disc must be at least 2 d_mean = "
                                        f"{2 * self.d_mean:g} m thick (got "
                                        f"{self.disc_thickness():g} m)"))
        return out + material_problems(cfg, self.material, self.dim, self.d_mean)

    def build(self, cfg):
        from geodem.build.specimen import packing_notes

        sm = specimen_material(cfg, self.material, self.dim, self.d_mean)
        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        t = self.disc_thickness()
        try:
            st, rep, centre = disc_with_platens(
                self.dim, self.diameter, self.d_mean, sm, thickness=t,
                distri_rate=self.distri_rate, seed=seed, platen_friction=self.platen_friction,
                platen_stiffness=self.platen_stiffness)
        except ValueError as exc:
            raise BuildError(("diameter",), f"building the disc failed: {exc}") from None
        info = {"diameter": self.d_mean, "disc_diameter": self.diameter, "thickness": t,
                "centre": centre, "material": sm.label,
                "material_warnings": list(sm.warnings) + packing_notes(rep)
                + disc_warnings(sm, self.n_across()),
                "specimen_report": {k: v for k, v in rep.items() if k != "packing"}}
        return BuiltModel(st, st.x.copy(), self.n_across(), info)


# ============================================================================ helpers
def _crack_counts(log):
    return int((log["type"] == 1).sum()), int((log["type"] == 2).sum()), len(log)


def _should_stop(rows, col, ipeak, peak, drop):
    """After the peak (3 samples past it, 10 samples at least), the value fell below drop x
    peak."""
    return len(rows) - ipeak >= 3 and len(rows) >= 10 and peak > 0 and rows[-1][col] < drop * peak


# ============================================================================ brazilian
@register_step("brazilian")
class Brazilian(StepBase):
    """Brazilian (indirect tension) test on a ``brazilian_disc``: bottom platen fixed, top
    platen moved down at ``loading_rate`` x D with the standard damping on, until the load
    falls below ``drop`` x peak after the peak or the displacement reaches ``max_strain`` x D.
    Adds tensile_strength (2 P_peak / (pi D t)), peak_load, crack_start_offset, cracks_tensile
    and cracks_shear to summary.json; writes brazilian_curve.csv and brazilian.png."""

    example = {"kind": "brazilian", "max_strain": 0.0001}
    example_model = {"type": "brazilian_disc", "dim": 2, "diameter": 0.04, "d_mean": 0.005,
                     "material": "rock"}
    loading_rate: float = F(0.1, unit="1/s", gt=0, le=100,
                            description="Platen speed / D (quasi-static when the time to the "
                                        "peak is many wave transit times across the disc)")
    max_strain: float = F(0.02, gt=0, le=0.5,
                          description="Stop when the platen displacement reaches this "
                                      "fraction of D")
    drop: float = F(0.8, gt=0, lt=1, description="Stop when the load falls below drop x peak "
                                                 "after the peak and a crack lies within R/2 "
                                                 "of the centre (the disc has split: its "
                                                 "halves, held by the platens, carry load "
                                                 "again, which is not the disc's strength)")
    samples: int = F(400, ge=20, le=100000, description="Samples over max_strain")
    crack_k: int = F(10, ge=1, le=10000,
                     description="How many of the first cracks crack_start_offset averages")
    standard_damping: bool = F(True, description="MatDEM's standard damping eta_c / N on")
    plot: bool = F(True, description="Draw brazilian.png (needs matplotlib)")

    def check(self, cfg, groups):
        return needs_model(cfg, "brazilian_disc",
                           "brazilian needs the disc geometry: use model type brazilian_disc")

    def planned_steps(self, plan):
        return max(1, int(math.ceil(self.max_strain / (self.loading_rate * plan.dt))))

    def execute(self, ctx):
        from geodem.core import groups, timestep
        from geodem import measure

        st = ctx.state
        dim = st.dim
        ax = dim - 1
        info = ctx.model.info
        D, t = float(info["disc_diameter"]), float(info["thickness"])
        d = float(info["diameter"])
        centre = np.asarray(info["centre"], float)
        plane = [0, 1] if dim == 2 else [0, 2]
        ref = ctx.model.reference
        top, bot = groups.members(st, "top"), groups.members(st, "bottom")
        h0 = ref[top, ax].mean() - ref[bot, ax].mean()
        path = ctx.out_dir / BRAZILIAN_CURVE
        rows = []
        if ctx.resumed and path.exists():
            rows = read_rows(path, st.step, (0, 5, 6, 7))
        if not ctx.resumed:
            v = [0.0] * dim
            v[ax] = -self.loading_rate * D

            def setup(s):
                if self.standard_damping:
                    s.eta[:] = timestep.standard_damping(s, D / d)
                groups.fix(s, "bottom")
                groups.set_velocity(s, "top", v)

            ctx.decree(setup, "top")
        write_csv(path, BRAZILIAN_COLUMNS, rows)

        def _split(log):
            """A crack within R/2 of the centre: the disc has split (a load drop without one
            is damage under a platen)."""
            if not len(log):
                return False
            xy = 0.5 * (ref[log["i"]] + ref[log["j"]])[:, plane]
            return bool((np.linalg.norm(xy - centre[plane], axis=1) < 0.25 * D).any())

        total = self.planned_steps(ctx.plan)
        chunk = max(1, total // self.samples)
        done = (st.step - ctx.start_step) // chunk * chunk  # same sample grid on resume
        peak = max((r[3] for r in rows), default=0.0)
        ipeak = int(np.argmax([r[3] for r in rows])) if rows else 0
        reason = "max_strain"
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(done)
            s = ctx.state
            P = 0.5 * (groups.reaction(s, "top")[ax] - groups.reaction(s, "bottom")[ax])
            h = s.x[top, ax].mean() - s.x[bot, ax].mean()
            log = ctx.sim.crack_log()
            ct, cs, n = _crack_counts(log)
            row = [s.step, s.time, h0 - h, P, 2.0 * P / (math.pi * D * t), ct, cs, n]
            rows.append(row)
            append_csv(path, row)
            if row[3] > peak:
                peak, ipeak = row[3], len(rows) - 1
            if _should_stop(rows, 3, ipeak, peak, self.drop) and _split(log):
                reason = "drop"
                break
        a = np.array(rows, float)
        ip = int(np.argmax(a[:, 3]))
        P_peak = float(a[ip, 3])
        log = ctx.sim.crack_log()
        ct, cs, _ = _crack_counts(log)
        res = {"peak_load": P_peak, "tensile_strength": None, "crack_start_offset": None,
               "displacement_at_peak": float(a[ip, 2]), "cracks_tensile": ct,
               "cracks_shear": cs, "cracks_at_peak": int(a[ip, 7]),
               "final_load": float(a[-1, 3]), "stopped_by": reason, "samples": len(rows),
               "disc_diameter": D, "thickness": t, "loading_rate": self.loading_rate}
        if P_peak > 0:
            res["tensile_strength"] = measure.brazilian_tensile_strength(P_peak, D, t)
        else:
            ctx.log("no compressive load on the platens: tensile strength undefined")
        crack_xy = 0.5 * (ref[log["i"]] + ref[log["j"]])[:, plane] if len(log) else None
        if crack_xy is not None:
            res["crack_start_offset"] = measure.crack_start_offset(
                crack_xy, centre[plane], 0.5 * D, k=self.crack_k)
            res["diametral_fraction"] = float(np.mean(
                np.abs(crack_xy[:, 0] - centre[0]) < 0.125 * D))
        ctx.summary.update({k: res[k] for k in ("tensile_strength", "peak_load",
                                                 "crack_start_offset", "cracks_tensile",
                                                 "cracks_shear")})
        off = res["crack_start_offset"]
        ctx.log(f"Brazilian test: P_peak = {P_peak:.4g} N, sigma_t = 2P/(pi D t) = "
                f"{res['tensile_strength'] or math.nan:.4g} Pa; first cracks at "
                f"{off if off is not None else math.nan:.3g} R from the centre; cracks {ct} "
                f"tensile, {cs} shear; stopped by {reason}")
        if self.plot and ctx.cfg.outputs.plots and P_peak > 0:
            s = ctx.state
            pos = 0.5 * (s.x[log["i"]] + s.x[log["j"]]) if len(log) else np.zeros((0, dim))
            disc = groups.members(s, "specimen")
            res["plot"] = ctx.plot("brazilian.png", lambda p: _plot(
                p, a[:, 2] * 1e3, a[:, 3] / 1e3, "platen displacement [mm]", "load P [kN]",
                f"Brazilian test: sigma_t = 2P/(pi D t) = {res['tensile_strength'] / 1e6:.3g} "
                f"MPa", pos[:, plane], log["type"], s.x[disc][:, plane],
                ("x", "y" if dim == 2 else "z")))
        return res


# ============================================================================ direct tension
@register_step("direct_tension")
class DirectTension(PlatenTest):
    """Direct tension: bottom platen fixed along the loading axis, top platen pulled at
    ``strain_rate`` with the standard damping on, until the force falls below ``drop`` x peak
    after the peak or the strain reaches ``max_strain``. Needs the groups ``bottom`` and
    ``top`` bonded to the specimen (model ``specimen``). Adds tensile_strength (peak force /
    area), peak_strain, E, cracks_tensile and cracks_shear to summary.json; writes
    direct_tension_curve.csv and direct_tension.png."""

    example = {"kind": "direct_tension", "max_strain": 0.0001}
    strain_rate: float = F(0.05, unit="1/s", gt=0, le=100,
                           description="Axial strain rate of the top platen (quasi-static "
                                       "when the time to the peak is many wave transit times)")
    max_strain: float = F(0.001, gt=0, le=0.5, description="Stop at this axial strain")
    drop: float = F(0.5, gt=0, lt=1, description="Stop when the force falls below drop x "
                                                 "peak after the peak")
    plot: bool = F(True, description="Draw direct_tension.png (needs matplotlib)")

    def execute(self, ctx):
        from geodem.core import groups
        from geodem import measure

        st, ax, d, ref, top, bot, h0, height, area = self.platens(ctx)
        dim = st.dim
        path = ctx.out_dir / TENSION_CURVE
        rows = []
        if ctx.resumed and path.exists():
            rows = read_rows(path, st.step, (0, 5, 6, 7))
        if not ctx.resumed:
            self.start_loading(ctx, 1.0, height, d)
        write_csv(path, TENSION_COLUMNS, rows)
        total = self.planned_steps(ctx.plan)
        chunk = max(1, total // self.samples)
        done = (st.step - ctx.start_step) // chunk * chunk
        peak = max((r[3] for r in rows), default=0.0)
        ipeak = int(np.argmax([r[3] for r in rows])) if rows else 0
        reason = "max_strain"
        while done < total:
            done = min(total, done + chunk)
            ctx.advance(done)
            s = ctx.state
            f = 0.5 * (groups.reaction(s, "bottom")[ax] - groups.reaction(s, "top")[ax])
            h = s.x[top, ax].mean() - s.x[bot, ax].mean()
            ct, cs, n = _crack_counts(ctx.sim.crack_log())
            row = [s.step, s.time, (h - h0) / h0, f / area, f, ct, cs, n]
            rows.append(row)
            append_csv(path, row)
            if row[3] > peak:
                peak, ipeak = row[3], len(rows) - 1
            if _should_stop(rows, 3, ipeak, peak, self.drop):
                reason = "drop"
                break
        a = np.array(rows, float)
        eps, sig = a[:, 2], a[:, 3]
        strength, peak_strain = measure.peak(eps, sig)
        E = None
        run = np.maximum.accumulate(eps)
        keep = np.concatenate([[True], eps[1:] > run[:-1]])
        try:
            E = measure.youngs_modulus(eps[keep], sig[keep])
        except ValueError as exc:  # too few points before the peak: reported, not fatal
            ctx.log(f"E not fitted: {exc}")
        log = ctx.sim.crack_log()
        ct, cs, _ = _crack_counts(log)
        res = {"tensile_strength": strength, "peak_strain": peak_strain, "E": E,
               "peak_force": float(a[int(np.argmax(sig)), 4]), "cracks_tensile": ct,
               "cracks_shear": cs, "final_strain": float(eps[-1]),
               "final_stress": float(sig[-1]), "stopped_by": reason, "samples": len(rows),
               "area": area, "height": float(h0), "strain_rate": self.strain_rate}
        ctx.summary.update({k: res[k] for k in ("tensile_strength", "peak_strain",
                                                 "cracks_tensile", "cracks_shear")})
        ctx.log(f"direct tension: tensile strength = {strength:.4g} Pa at strain "
                f"{peak_strain:.4g}; cracks {ct} tensile, {cs} shear; stopped by {reason}")
        if self.plot and ctx.cfg.outputs.plots and strength > 0:
            s = ctx.state
            pos = 0.5 * (s.x[log["i"]] + s.x[log["j"]]) if len(log) else np.zeros((0, dim))
            xz = [0, ax]
            res["plot"] = ctx.plot("direct_tension.png", lambda p: _plot(
                p, eps, sig / 1e6, "axial strain [-]", "tensile stress [MPa]",
                f"direct tension: strength = {strength / 1e6:.3g} MPa", pos[:, xz],
                log["type"], s.x[:, xz], ("x", "xyz"[ax])))
        return res


def _plot(path, xs, ys, xlabel, ylabel, title, pos, types, x, map_axes=("x", "y")):
    """Curve (left) and crack map (right; cracks by type over the element centres)."""
    from geodem.workflow.animation import label_map, legend_outside

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:  # noqa: BLE001 - the plot is optional
        return None
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 5), gridspec_kw={"width_ratios": [3, 2]})
    a1.plot(xs, ys, "C0-", lw=1.2)
    ip = int(np.argmax(ys))
    a1.plot([xs[ip]], [ys[ip]], "r*", ms=12, label=f"peak {ys[ip]:.4g}")
    a1.set_xlabel(xlabel)
    a1.set_ylabel(ylabel)
    a1.set_title(title)
    a1.legend(loc="best")
    a2.scatter(x[:, 0], x[:, 1], s=2, c="0.8")
    for code, col, name in ((1, "C0", "tensile"), (2, "C3", "shear"), (0, "C2", "joint")):
        sel = types == code
        if sel.any():
            a2.scatter(pos[sel, 0], pos[sel, 1], s=6, c=col, label=f"{name} ({sel.sum()})")
    a2.set_aspect("equal")
    a2.set_title("cracks")
    label_map(a2, map_axes, fontsize=8)
    legend_outside(a2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
