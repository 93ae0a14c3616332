"""Triaxial lab test with servo-controlled walls, as workflow pieces: the ``triaxial_box`` model
and the ``triaxial`` step.

* model ``triaxial_box``: a bonded box specimen (:func:`box_specimen`: the packing recipe of
  the material, as the UCS specimen's; group ``specimen``) inside rigid walls of fixed
  elements (:func:`geodem.build.walls.add_walls`, gap 0: they just touch the outermost element
  surfaces): lateral walls frictionless by default (``wall_friction``, a membrane), platens
  as rough as the rock (``platen_friction`` 1; a contact takes the smaller of the two mu), so
  that at sigma3 = 0 the test is the UCS test (frictionless platens gave a 2-D sandstone
  10 % less: 69.9 against 78.0 MPa, docs/triaxial.md).
  2-D: lateral walls ``xmin``, ``xmax`` and platens ``bottom``, ``top`` along y; 3-D: lateral
  walls ``xmin``, ``xmax``, ``ymin``, ``ymax`` and platens along z. The loading axis is the last
  axis. With ``wall_margin`` = -0.5 (default) every wall spans exactly its face, so walls of
  neighbouring faces stay ``sqrt(2) d`` apart at the corners and never touch (wall-wall contact
  forces would corrupt the measured reactions). In 3-D the walls are head-on instead (one wall
  element per face element, :func:`face_walls` for ``packing: random``, :func:`lattice_walls`
  for ``packing: lattice``); ``wall_element`` and ``wall_margin`` then do not apply.

* step ``triaxial``: one test per confining stress ``sigma3`` of ``confining_pressures``, each on
  a fresh copy of the model as it was when the step started (the state is restored in place,
  the crack log and the energy books are restarted; time and step numbers keep counting):

  1. isotropic consolidation: every wall (platens included) is servo-controlled to ``sigma3``,
     with the standard damping ``eta_c / N`` on, until every wall stress is within
     ``tolerance x max(sigma3, sigma_ref)`` of ``sigma3`` (``sigma_ref`` = 5 % of the largest
     confining stress, for sigma3 = 0) and the unbalanced-force ratio is below
     ``balance_ratio``, or ``consolidation_balances`` standard balances (50 N steps each) have
     passed (then a warning; the result records ``consolidated: false``);
  2. axial loading: the bottom platen is fixed, the top platen moves down at
     ``strain_rate x h_c`` (``h_c`` = consolidated height); the specimen's elements within
     ``platen_layer`` d_mean of each platen move with it along the axis (free sideways, not
     turning: the UCS test's platens, which are the specimen's own end layers; before, a
     turning rock's peak at sigma3 = 0 was 4-22 % above its UCS, with walls alone); the lateral
     walls stay
     servo-controlled at ``sigma3``; it stops when the deviator has fallen below ``drop`` x its
     peak after the peak (and the strain is at least 1.5 x the strain at the peak: a crack burst
     in a small specimen can halve the stress for a moment), when the nominal strain reaches
     ``max_strain``, when a platen gets so close to a lateral wall that they would touch, or
     when two elements overlap by more than 0.35 x the smaller radius (``crushed``: an element
     squeezed into a corner between a platen and a lateral wall at high confinement).

  **Servo** (PFC style), every ``servo_interval`` = n time steps, for each servo-controlled wall
  ``w`` with area ``A_w``, measured stress ``sigma_w`` and target ``sigma_t``::

      v_w = clip(G_w (sigma_w - sigma_t), -v_max, v_max)      (outward positive)
      G_w = alpha A_w / (k_w n dt)
      v_max = servo_max_rate x (specimen extent along the wall normal)

  ``k_w`` [N/m] is the summed normal stiffness of the wall's contacts with the specimen (each the
  series ``kn_wall kn_i / (kn_wall + kn_i)``), at least that of one contact per ``d_mean`` of
  face (so ``G`` stays finite before the wall touches). Moving the wall by ``v n dt`` changes its
  contact force by at most ``k_w v n dt``, so one update corrects at most ``alpha`` (< 1) of the
  stress error: stable, and the specimen behind the contacts only makes the step smaller.

  **Measurements** (compression positive, :mod:`geodem.measure` convention), from the
  walls' inner surfaces (tangent planes of their elements) and contact reactions:

  - extents ``e_a`` = distance between the two walls normal to axis ``a`` (``h`` along the
    loading axis);
  - wall stress ``sigma_w = F_w / A_w``, ``F_w`` = the specimen's push on the wall along its
    normal [N], ``A_w`` = product of the extents along the other axes, times the thickness
    ``t`` (default ``d_mean``, as in ``uniaxial``) in 2-D;
  - axial stress ``sigma1`` = mean platen force / current lateral area ``A = w t`` (2-D) or
    ``w_x w_y`` (3-D); deviator ``q = sigma1 - sigma3``;
  - axial strain ``(L_c - L) / L_c`` between the centroids of the end layers glued to the
    platens (``platen_layer``, as the UCS test measures it), or ``(h_c - h) / h_c`` between
    the platens with ``platen_layer: 0``; lateral strain ``mean_a (w_c,a - w_a) / w_c,a`` (negative
    when the specimen bulges), volumetric strain ``1 - V / V_c`` with ``V = prod_a e_a``, all from
    the consolidated state ``c``; the consolidation's own volumetric strain is from the state
    before consolidation;
  - lateral stress = mean of the lateral wall stresses (shows that the servo holds sigma3).

  Per test: peak ``sigma1`` (the strength at this sigma3), the strain at the peak, the tangent
  modulus ``E`` of ``q`` vs axial strain between 10 and 50 % of the peak deviator, the lateral
  stress at the peak, the consolidation report, cracks. Then the Mohr-Coulomb envelope through the
  peaks, :func:`geodem.measure.mohr_coulomb_fit` (``sigma1 = C0 + q sigma3``, ``q =
  (1 + sin phi) / (1 - sin phi)``, ``c = C0 (1 - sin phi) / (2 cos phi)``).

  summary.json gets ``cohesion`` [Pa], ``friction_angle_deg``, ``ucs_fit`` [Pa] (None when no fit
  is possible: fewer than two distinct sigma3, or slope < 1), ``confining_pressures`` [Pa] and
  ``peak_strengths`` [Pa] (peak sigma1 per test; None for a test that has not peaked,
  :func:`has_peaked`: such a test is listed in ``no_peak`` and kept out of the fit). Files:
  ``triaxial_curves.csv`` (every sample of every test), ``triaxial.json`` (progress and results per test; finished tests are skipped
  on ``--resume``), ``triaxial_initial.npz`` (the state every test starts from), and the
  pictures ``triaxial_curves.png`` (deviator and volumetric strain vs axial strain),
  ``mohr_circles.png`` (circles at the peaks and the fitted envelope) and ``triaxial_cracks.png``
  (crack map of the last test).

  **Resume**: everything a test decides happens at absolute time steps on a grid (servo updates
  every n steps from the start of the phase; the phase starts are in ``triaxial.json``) and
  depends on the state only, so a run resumed from a checkpoint in the middle of a test continues
  that test exactly (bit-identical on CPU backends), finished tests are taken from
  ``triaxial.json``.

Only one ``triaxial`` step per workflow: the file names above are fixed.
"""
from __future__ import annotations

import csv
import json
import math
from typing import Literal, Optional

import numpy as np

from geodem.cases.common import needs_model, read_rows
from geodem.core.checks import max_overlap
from geodem.workflow.animation import label_map, legend_outside, pyplot
from geodem.workflow.material import (SpecimenMaterial, box_size_problems, material_problems,
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

CURVES = "triaxial_curves.csv"
PROGRESS = "triaxial.json"
INITIAL = "triaxial_initial.npz"
COLUMNS = ("test", "sigma3", "step", "time", "axial_strain", "axial_stress", "deviator",
           "lateral_strain", "volumetric_strain", "lateral_stress", "lateral_stress_error",
           "cracks_tensile", "cracks_shear")
INT_COLUMNS = (0, 2, 11, 12)
COMPACTION = 10.0  # box_specimen: compaction pressure / half the deposit's weight per area
SIGMA_REF = 0.05  # sigma3 = 0: tolerance relative to 5 % of the largest confining stress
PA_FLOOR = 1.0e3  # ... and at least 1 kPa when every sigma3 is 0


# ============================================================================ geometry
def wall_layout(dim: int):
    """``[(group, axis, sign)]`` of the walls: lateral walls first, then the platens
    ``bottom`` and ``top`` along the last axis (sign -1: the wall on the low side)."""
    lat = [("xmin", 0, -1), ("xmax", 0, 1)]
    if dim == 3:
        lat += [("ymin", 1, -1), ("ymax", 1, 1)]
    ax = dim - 1
    return lat + [("bottom", ax, -1), ("top", ax, 1)]


def _sides(dim):
    return [("xyz"[a] + ("min" if s < 0 else "max")) for _, a, s in wall_layout(dim)]


def wall_clearance(st, names) -> tuple[float, str, str]:
    """Smallest surface gap between elements of two different walls [m] (negative: they
    overlap) and the two walls."""
    from geodem.core import groups

    best, pair = math.inf, ("", "")
    idx = {n: groups.members(st, n) for n in names}
    for k, a in enumerate(names):
        for b in names[k + 1:]:
            ia, ib = idx[a], idx[b]
            d = np.linalg.norm(st.x[ia][:, None, :] - st.x[ib][None, :, :], axis=2)
            gap = d - st.r[ia][:, None] - st.r[ib][None, :]
            g = float(gap.min())
            if g < best:
                best, pair = g, (a, b)
    return best, pair[0], pair[1]


# ============================================================================ specimen
def _stiffen_under_platen(st, factor, d_mean, n_across, f0, backend=None, alpha=0.5, n=10,
                          max_updates=3000):
    """Multiply ``kn, ks`` of every element by ``factor`` with gravity off while the
    ``"platen"`` of a compacted :func:`~geodem.build.packing.deposition_state` is
    servo-controlled to the force ``f0`` [N] (platen speed ``alpha (F - f0) / (k n dt)``
    upwards, ``k`` the summed stiffness of its contacts, updated every ``n`` steps; standard
    damping on) until ``F <= 2 f0`` and the unbalanced-force ratio is below 1e-2: the overlaps
    shrink by ``factor`` while the top face stays against the platen. Returns the time steps
    run."""
    from geodem.core import groups, neighbors, timestep
    from geodem.core.engine import Simulation

    s = groups.members(st, "sample")
    p = groups.members(st, "platen")
    st.kn[:] *= factor
    st.ks[:] *= factor
    st.v[:] = 0.0
    st.gravity[:] = 0.0
    neighbors.build_rows(st)
    st.dt = 0.0
    sim = Simulation(st, backend=backend, monitor_every=0)
    eta = timestep.standard_damping(st, n_across)
    sim.change(lambda z: z.eta.__setitem__(slice(None), eta), book_energy=False)
    ins = np.zeros(st.n, bool)
    ins[s] = True
    k_floor = 0.1 * float(st.kn[s].mean())
    vmax = 1e-3 * d_mean / st.dt
    steps = 0
    for it in range(max_updates):
        st = sim.sync()
        f = float(groups.reaction(st, "platen")[-1])
        if it > 20 and f <= 2.0 * f0 and sim.unbalanced_force_ratio() < 1e-2:
            break
        nb = st.nbr[p]
        valid = nb >= 0
        j = np.where(valid, nb, 0)
        dist = np.linalg.norm(st.x[j] - st.x[p][:, None, :], axis=2)
        touch = valid & ins[j] & (dist < st.r[p][:, None] + st.r[j])
        ki, kj = st.kn[p][:, None], st.kn[j]
        k = max(float((ki * kj / (ki + kj) * touch).sum()), k_floor)
        v = float(np.clip(alpha * (f - f0) / (k * n * st.dt), -vmax, vmax))
        vel = [0.0] * (st.dim - 1) + [v]
        sim.change(lambda z: groups.set_velocity(z, "platen", vel), book_energy=False)
        sim.run(n)
        steps += n
    sim.sync()
    return steps


def box_specimen(size, d_mean, distri_rate, material: SpecimenMaterial, dim, seed, d_wall,
                 backend=None):
    """A bonded random box specimen with flat faces, packed inside the box itself (MatDEM's
    box models) rather than cut from a larger packing (a cut face is rough by up to one element
    diameter, and rigid walls then touch a few protruding elements first: bedding strains of
    ~1 % and local crushing before the specimen carries the load).

    1. :func:`geodem.build.packing.random_placement` of enough elements to fill ``size`` at a
       packing fraction of 0.84 (2-D) / 0.63 (3-D), :func:`~geodem.build.packing.
       deposition_state` in the box ``[0, size]`` with floor and side walls of elements of
       diameter ``d_wall`` (small: the walls are flat to about ``0.01 d_mean``), ``deposit``,
       ``compact`` at 10 x half the deposit's weight per area (the soft, frictionless packing
       material rearranges and the top layer is pressed flat);
    2. stiffen to the material's ``kn`` under the compaction platen, gravity off, with the
       platen servo-controlled to half the weight (:func:`_stiffen_under_platen`): the
       overlaps shrink by the stiffening factor and the top face stays flat against the platen
       (:func:`geodem.build.packing.stiffen` lifts the platen instead, and the soft packing's
       column then springs back unevenly: a top face rough by 0.1-0.2 d_mean);
    3. keep the packed elements, cement them (:func:`geodem.build.specimen.cement`, every pair
       within the smallest ``xb`` bonded, at most ``2e-4 d_mean`` for unbreakable materials;
       balanced), Morton-sort.

    3-D, and a material whose ``packing`` is ``isotropic`` (:func:`geodem.build.specimen.
    packing_recipe`): :func:`geodem.build.specimen.isotropic_specimen` instead (isotropic
    compression by radius expansion inside the box itself, every face flat at the box, bonds
    stress-free; :mod:`geodem.build.isotropic`), the same recipe as the UCS specimen's; the
    steps above are the 2-D ``deposit`` recipe.

    The height is the packing's: close to ``size[-1]`` (within about one ``d_mean``). Returns
    ``(state, report)`` like ``make_specimen`` (``report["packing"]`` holds the packing
    steps)."""
    from geodem.build import packing
    from geodem.build.shapes import subset_state
    from geodem.build.specimen import cement, packing_recipe
    from geodem.core import groups, neighbors
    from geodem.materials import at_size, macro_to_micro

    size = np.asarray(size, float)
    if packing_recipe(material.element, dim) == "isotropic":
        # isotropic compression by radius expansion inside the box itself (flat faces): the
        # recipe of every 3-D specimen, and of a 2-D rock calibrated on it
        from geodem.build.shapes import Box
        from geodem.build.specimen import isotropic_specimen, specimen_params

        params = specimen_params(material.material, material.element, d_mean)
        return isotropic_specimen(Box((0.0,) * dim, tuple(size)), d_mean, distri_rate, params,
                                  material.rho, seed=seed, backend=backend)
    lo = np.zeros(dim)
    phi = 0.84 if dim == 2 else 0.63
    x, r = packing.random_placement((lo, size), porosity=1.0 - phi, d_mean=d_mean,
                                    distri_rate=distri_rate, seed=seed)
    st = packing.deposition_state(x, r, (lo, size), rho=material.rho, d_wall=d_wall)
    dep = packing.deposit(st, backend=backend)
    # half the deposit's weight per area (compact's default), and 10 x that to press the top
    # layer flat (a partly filled top layer otherwise leaves a few elements standing proud)
    p_half = 0.5 * float(st.m[groups.members(st, "sample")].sum()) * \
        abs(float(st.gravity[-1])) / float(np.prod(size[:-1]) * (d_mean if dim == 2 else 1.0))
    com = packing.compact(st, pressure=COMPACTION * p_half, backend=backend)
    if material.element is None:
        m = material.macro
        params = macro_to_micro(m["E"], m["nu"], m["Tu"], m["Cu"], m["mu_i"], m["rho"],
                                d_mean).element
    else:
        params = at_size(material.element, d_mean)
    s = groups.members(st, "sample")
    factor = max(1.0, params["kn"] / float(st.kn[s].mean()))
    area = float(np.prod(size[:-1]) * (d_mean if dim == 2 else 1.0))
    stiffen_steps = _stiffen_under_platen(st, factor, d_mean, float(size.max()) / d_mean,
                                          p_half * area, backend)
    sp = subset_state(st, st.group_mask("sample"), rebuild=False)
    sp.x_ref[:] = sp.x
    sp.groups = {"all": 0}
    sp.group[:] = 0
    groups.add_group(sp, "specimen", np.arange(sp.n))
    # cement bonds the pairs within the smallest xb; "unbreakable" materials (huge xb) would
    # bond every pair in reach: bond those within 2e-4 d_mean (a rock's xb is ~1e-4 d) instead
    gap = None if params["xb"] <= 1e-3 * d_mean else 2e-4 * d_mean
    rep = cement(sp, gap, params, d_ref=d_mean, rho=material.rho, backend=backend, seed=seed)
    neighbors.spatial_sort(sp)
    rep["packing"] = {"deposit_steps": dep["steps"], "compact_steps": com["steps"],
                      "stiffen_steps": stiffen_steps, "stiffen_factor": factor,
                      "compaction_pressure": com["pressure"], "n_packed": int(s.size)}
    return sp, rep


def lattice_box_specimen(size, d_mean, material: SpecimenMaterial, dim):
    """A bonded close-packed box specimen: the largest FCC (3-D, close-packed layers normal to
    the loading axis z) or triangular (2-D) block of element diameter ``d_mean`` that fits in
    ``size``, every touching pair bonded (12 bonds per interior element in 3-D, 6 in 2-D), in
    Morton order. It is the lattice on which :func:`geodem.materials.macro_to_micro` is
    derived (PHYSICS.md section 2), so rock properties give E and nu of the lattice directly;
    it is anisotropic (cubic symmetry) and its faces across the rows are stepped by d/2 (only
    every other row touches a lateral wall). Returns ``(state, report)``."""
    from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice
    from geodem.core import groups, neighbors
    from geodem.materials import at_size, macro_to_micro

    size = np.asarray(size, float)
    spacing = [d_mean, d_mean * math.sqrt(3) / 2] + ([d_mean * math.sqrt(2 / 3)] if dim == 3
                                                     else [])
    # x rows span (nx - 1) d + d/2 (odd rows shifted) plus one diameter of element
    counts = [int((size[0] - 1.5 * d_mean) / d_mean) + 1] + \
        [int((size[a] - d_mean) / spacing[a]) + 1 for a in range(1, dim)]
    if min(counts) < 3:
        raise ValueError(f"size {size.tolist()} m holds only {counts} lattice elements of "
                         f"d_mean {d_mean:g} m along the axes; allowed: at least 3 along each")
    x = fcc_lattice(*counts, d_mean) if dim == 3 else triangular_lattice(*counts, d_mean)
    x = x + 0.5 * d_mean
    mass = None
    if material.element is None:
        m = material.macro
        mic = macro_to_micro(m["E"], m["nu"], m["Tu"], m["Cu"], m["mu_i"], m["rho"], d_mean)
        params, mass = mic.element, mic.mass
    else:
        params = at_size(material.element, d_mean)
    st = bonded_state(x, 0.5 * d_mean, density=material.rho, kn=params["kn"], ks=params["ks"],
                      xb=params["xb"], fs0=params["fs0"], mu=params["mu"], gap=1e-6 * d_mean)
    if mass is not None:
        st.m[:] = mass
    st.groups = {"all": 0}
    st.group[:] = 0
    groups.add_group(st, "specimen", np.arange(st.n))
    neighbors.spatial_sort(st)
    bonds = int((st.cstate == 1).sum() // 2)
    return st, {"n_elements": st.n, "bonds": bonds, "coordination": 2.0 * bonds / st.n,
                "packing": {"lattice": "fcc" if dim == 3 else "triangular",
                            "counts": counts}}


def lattice_walls(st, layout, mu: float):
    """A new state with the walls of a :func:`lattice_box_specimen`: one wall element (the
    specimen's diameter and ``kn``) head-on against each face element, one diameter out along
    the wall's axis, where no specimen element is nearer than 0.99 diameters. Every face
    element then touches its wall through one contact as stiff as a bond (a flat wall of
    smaller elements lets the lattice's spheres sink into the gaps between wall elements: a
    seating strain of about 0.5 % and a wall contact several times softer than the rock).
    The walls follow the lattice's stepped faces; ``layout`` is :func:`wall_layout`."""
    from scipy.spatial import cKDTree

    from geodem.build.walls import append_elements
    from geodem.core.neighbors import build_rows

    d = float(2.0 * st.r.mean())
    tree = cKDTree(st.x)
    out = st
    for name, ax, sign in layout:
        pts = st.x.copy()
        pts[:, ax] += sign * d
        free = np.array([len(h) == 0 for h in tree.query_ball_point(pts, 0.99 * d)])
        out = append_elements(out, pts[free], 0.5 * d, float(st.m.mean()),
                              kn=float(st.kn.mean()), ks=float(st.ks.mean()), mu=mu, group=name)
    if out.skin <= 0:
        out.skin = 0.1 * d
    build_rows(out)
    return out


def face_walls(st, layout, mu: float, stiffness: float = 1.0, tol: float = 1e-3):
    """A new state with head-on walls for a flat-faced random box specimen
    (:func:`geodem.build.specimen.isotropic_specimen`): for every face of the specimen's
    bounding box (surfaces included), one wall element per specimen element whose surface lies
    within ``tol`` d_mean of that face, of the same radius and ``stiffness`` x its ``kn``,
    tangent to the face from outside on the element's axis (the element's mirror image). Every
    face element then touches its wall through one contact as stiff as a bond; a flat wall of
    smaller elements lets the spheres sink into the hollows between its elements (seating
    strains of several 0.1 %, far above the elastic strains). Mirror images of non-overlapping
    elements do not overlap, and walls of neighbouring faces stay at least
    ``(sqrt 2 - 1) (r_i + r_j)`` apart. ``layout`` is :func:`wall_layout`."""
    from geodem.build.walls import append_elements
    from geodem.core.neighbors import build_rows

    d = float(2.0 * st.r.mean())
    lo = (st.x - st.r[:, None]).min(axis=0)
    hi = (st.x + st.r[:, None]).max(axis=0)
    out = st
    for name, ax, sign in layout:
        plane = hi[ax] if sign > 0 else lo[ax]
        on = np.flatnonzero(np.abs(st.x[:, ax] + sign * st.r - plane) <= tol * d)
        pts = st.x[on].copy()
        pts[:, ax] = plane + sign * st.r[on]
        out = append_elements(out, pts, st.r[on], st.m[on], kn=stiffness * st.kn[on],
                              ks=stiffness * st.ks[on], mu=mu, group=name)
    if out.skin <= 0:
        out.skin = 0.1 * d
    build_rows(out)
    return out


# ============================================================================ model
@register_model("triaxial_box")
class TriaxialBox(ModelBase):
    """A bonded random box specimen with flat faces (packed inside the box, :func:`box_specimen`;
    group ``specimen``) inside rigid walls of fixed elements for the triaxial test: lateral
    walls ``xmin``, ``xmax`` (and ``ymin``, ``ymax`` in 3-D) and platens ``bottom``, ``top``
    along the last axis (the loading axis), frictionless by default. Every wall is its own
    group, ready to be servo-controlled."""

    size_field = "size"
    example = {"type": "triaxial_box", "dim": 2, "size": [0.05, 0.1], "d_mean": 0.005,
               "material": "rock"}
    dim: Literal[2, 3] = F(2, description="Dimension")
    size: list[float] = F(..., unit="m", min_length=2, max_length=3,
                          description="Box edge lengths (dim values; the last is the height, "
                                      "the loading axis; the packed height comes within about "
                                      "one d_mean of it)")
    d_mean: float = F(..., unit="m", gt=0, description="Mean element diameter")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing "
                                                        "(MatDEM distriRate)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    packing: Literal["random", "lattice"] = F(
        "random", description="random: packed in the box (deposited in 2-D, isotropic "
                              "radius expansion in 3-D); lattice: the largest close-packed "
                              "block (FCC in 3-D) that fits the box, all touching pairs bonded")
    material: Name = F(..., description="Material name (rock properties, per-size or direct "
                                        "element parameters, or a library material)")
    wall_element: Optional[float] = F(None, gt=0, le=2,
                                      description="Wall element diameter / d_mean (default "
                                                  "0.25 in 2-D, 0.5 in 3-D): small elements "
                                                  "make flat walls (bumps of about 0.01 d_mean "
                                                  "at 0.25) but many of them")
    wall_friction: float = F(0.0, ge=0, description="Friction coefficient between the lateral "
                                                    "walls and the specimen (0: frictionless, "
                                                    "like a membrane)")
    platen_friction: float = F(1.0, ge=0, description="Friction coefficient of the platens "
                                                      "(bottom, top); a contact takes the "
                                                      "smaller of it and the rock's mu, so the "
                                                      "default 1 makes them as rough as the "
                                                      "rock: the UCS test's platens, bonded to "
                                                      "the specimen, hold it the same way")
    wall_stiffness: float = F(1.0, gt=0, le=100,
                              description="Wall element kn / d over the specimen's stiffest "
                                          "kn / d (1: as stiff as the rock)")
    wall_margin: float = F(-0.5, ge=-3, le=3,
                           description="How far each wall's element centres reach past the "
                                       "edges of its face, in d_mean (negative: shorter than "
                                       "the face, so walls of neighbouring faces stay clear of "
                                       "each other; they must never touch)")

    def d_wall(self) -> float:
        """Wall element diameter [m]."""
        ratio = self.wall_element if self.wall_element is not None else \
            (0.25 if self.dim == 2 else 0.5)
        return ratio * self.d_mean

    def n_elements(self):
        vol = float(np.prod(self.size))
        el = math.pi / 4 * self.d_mean ** 2 if self.dim == 2 else math.pi / 6 * self.d_mean ** 3
        phi = {"random": (0.84, 0.63), "lattice": (0.907, 0.74)}[self.packing]
        spec = (phi[0] if self.dim == 2 else phi[1]) * vol / el
        dw = self.d_wall()
        per = [s / (0.85 * dw) + 1 for s in self.size]
        wall = 0.0
        for a in range(self.dim):
            wall += 2 * float(np.prod([per[b] for b in range(self.dim) if b != a]))
        return max(1, int(spec + wall))

    def bytes_per_element(self):
        return state_bytes_per_element(self.dim, 16 if self.dim == 3 else 8) + 3000

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        return ["all", "specimen"] + [g for g, _, _ in wall_layout(self.dim)]

    def n_across(self):
        return float(self.size[-1] / self.d_mean) if self.size else 1.0

    def check(self, cfg):
        out = box_size_problems(self.size, self.dim, self.d_mean)
        return out + material_problems(cfg, self.material, self.dim, self.d_mean)

    def build(self, cfg):
        from geodem.build.specimen import packing_notes
        from geodem.build.walls import add_walls
        from geodem.core import groups

        sm = specimen_material(cfg, self.material, self.dim, self.d_mean)
        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        dw = self.d_wall()
        try:
            if self.packing == "lattice":
                st, rep = lattice_box_specimen(self.size, self.d_mean, sm, self.dim)
            else:
                st, rep = box_specimen(self.size, self.d_mean, self.distri_rate, sm, self.dim,
                                       seed, dw)
        except ValueError as exc:
            raise BuildError(("size",), str(exc)) from None
        kn = self.wall_stiffness * float((st.kn / (2.0 * st.r)).max()) * dw
        names = [g for g, _, _ in wall_layout(self.dim)]
        if self.packing == "lattice":
            st = lattice_walls(st, wall_layout(self.dim), self.wall_friction)
            dw, kn = self.d_mean, float(st.kn[groups.members(st, "specimen")].mean())
        elif self.dim == 3:
            st = face_walls(st, wall_layout(self.dim), self.wall_friction, self.wall_stiffness)
            dw, kn = self.d_mean, float(st.kn[groups.members(st, "specimen")].mean())
        else:
            st = add_walls(st, _sides(self.dim), names=names, d_wall=dw, gap=0.0,
                           margin=self.wall_margin * self.d_mean / dw, kn=kn,
                           mu=self.wall_friction)
        for g in ("bottom", "top"):
            st.mu[groups.members(st, g)] = self.platen_friction
        gap, a, b = wall_clearance(st, names)
        if gap < 0.05 * self.d_mean:
            raise BuildError(("wall_margin",), f"walls {a!r} and {b!r} come within "
                                               f"{gap / self.d_mean:.3g} d_mean of each other at "
                                               f"a corner with wall_margin = "
                                               f"{self.wall_margin:g}; walls must stay clear of "
                                               "each other (at least 0.05 d_mean; wall-wall "
                                               "forces would corrupt the measured stresses): "
                                               "make wall_margin more negative (default -0.5)")
        # a fresh model for the workflow: its time steps count from 0
        st.step, st.time = 0, 0.0
        info = {"diameter": self.d_mean, "size": list(self.size), "material": sm.label,
                "material_warnings": list(sm.warnings) + packing_notes(rep),
                "walls": {"names": names, "d_wall": dw, "kn": kn,
                          "friction": self.wall_friction,
                          "platen_friction": self.platen_friction, "margin": self.wall_margin,
                          "clearance": gap},
                "specimen_report": {k: v for k, v in rep.items()}}
        return BuiltModel(st, st.x.copy(), self.n_across(), info)


# ============================================================================ walls at run time
class Walls:
    """The walls of a ``triaxial_box`` state: measurements and servo velocities (NumPy over
    the wall elements only; nothing here loops over elements in Python)."""

    def __init__(self, st, thickness: float, d_mean: float):
        from geodem.core import groups

        self.dim = st.dim
        self.ax = st.dim - 1
        self.layout = wall_layout(st.dim)
        self.names = [g for g, _, _ in self.layout]
        self.lateral = self.names[:-2]
        self.axis = {g: a for g, a, _ in self.layout}
        self.sign = {g: s for g, _, s in self.layout}
        self.idx = {g: groups.members(st, g) for g in self.names}
        self.spec = np.zeros(st.n, bool)
        self.spec[groups.members(st, "specimen")] = True
        self.t = float(thickness)
        self.d = float(d_mean)
        kn_w = float(np.mean(np.concatenate([st.kn[i] for i in self.idx.values()])))
        kn_s = float(st.kn[self.spec].mean())
        self.kn_contact = kn_w * kn_s / (kn_w + kn_s)
        self.rbar = {g: float(st.r[i].mean()) for g, i in self.idx.items()}
        # platen -> specimen elements glued to it along the loading axis (``platen_layer``)
        self.layers: dict = {}

    def layer_distance(self, st) -> float:
        """Distance between the glued end layers' centroids along the loading axis [m]."""
        return float(st.x[self.layers["top"], self.ax].mean()
                     - st.x[self.layers["bottom"], self.ax].mean())

    def layer(self, st, g: str, depth: float) -> np.ndarray:
        """Specimen elements whose centres lie within ``depth`` [m] of platen ``g``'s inner
        surface: the end layer that ``platen_layer`` moves with the platen."""
        s = self.surfaces(st)[g]
        return np.flatnonzero(self.spec & (self.sign[g] * (s - st.x[:, self.ax]) < depth))

    def surfaces(self, st) -> dict:
        """Inner surface coordinate of every wall [m]."""
        return {g: float(st.x[i, self.axis[g]].mean()) - self.sign[g] * self.rbar[g]
                for g, i in self.idx.items()}

    def extents(self, st) -> np.ndarray:
        """Distance between the two walls normal to each axis [m] (last: the height h)."""
        s = self.surfaces(st)
        e = np.zeros(self.dim)
        for g, a, sg in self.layout:
            e[a] += sg * s[g]
        return e

    def interior_set(self, st, inset: float) -> np.ndarray:
        """Specimen elements whose centres lie at least ``inset`` [m] inside every wall."""
        s = self.surfaces(st)
        ok = self.spec.copy()
        for g, a, sg in self.layout:
            ok &= sg * (s[g] - st.x[:, a]) >= inset
        return np.flatnonzero(ok)

    @staticmethod
    def interior_extents(st, idx) -> np.ndarray:
        """Twice the mean distance of the elements ``idx`` from their centre, per axis [m]: a
        uniform strain scales it by 1 + strain (an interior strain gauge, free of the
        wall-contact seating that the wall positions include)."""
        x = st.x[idx]
        return 2.0 * np.abs(x - x.mean(axis=0)).mean(axis=0)

    def area(self, e, g) -> float:
        """Contact area of wall ``g`` for extents ``e`` [m^2] (2-D: times the thickness)."""
        a = self.axis[g]
        other = float(np.prod([e[b] for b in range(self.dim) if b != a]))
        return other * (self.t if self.dim == 2 else 1.0)

    def forces(self, st) -> dict:
        """The specimen's push on each wall along its outward normal [N] (>= 0 in compression):
        ``sign x`` the wall's reaction (contact force on its fixed DOFs) along its axis."""
        f = {g: self.sign[g] * float((st.m[i] * st.a[i, self.axis[g]]).sum())
             for g, i in self.idx.items()}
        for g, i in self.layers.items():  # the glued end layer pushes through the platen too
            f[g] += self.sign[g] * float((st.m[i] * st.a[i, self.ax]).sum())
        return f

    def stresses(self, st, e=None) -> dict:
        e = self.extents(st) if e is None else e
        f = self.forces(st)
        return {g: f[g] / self.area(e, g) for g in self.names}

    def contacts(self, st, g, e=None) -> tuple[float, float]:
        """``(k_w, v_s)`` of wall ``g``: summed normal stiffness of its contacts with the
        specimen [N/m] (at least one contact per d_mean of face), and the mean outward velocity
        of the specimen elements it touches [m/s] (0 when it touches none)."""
        i = self.idx[g]
        nb = st.nbr[i]
        valid = nb >= 0
        j = np.where(valid, nb, 0)
        dist = np.linalg.norm(st.x[j] - st.x[i][:, None, :], axis=2)
        touch = valid & self.spec[j] & (dist < st.r[i][:, None] + st.r[j])
        ki, kj = st.kn[i][:, None], st.kn[j]
        k = float((ki * kj / (ki + kj) * touch).sum())
        nt = int(touch.sum())
        v_s = self.sign[g] * float(st.v[j[touch], self.axis[g]].sum()) / nt if nt else 0.0
        e = self.extents(st) if e is None else e
        faces = self.area(e, g) / ((self.t * self.d) if self.dim == 2 else self.d ** 2)
        return max(k, faces * self.kn_contact), v_s

    def servo(self, st, targets: dict, alpha: float, n: int, max_rate: float) -> dict:
        """Velocity vectors of the walls in ``targets`` (name -> target stress [Pa]):
        ``v = clip(v_s + alpha A / (k_w n dt) (sigma - sigma_t), -v_max, v_max)`` outward."""
        e = self.extents(st)
        sig = self.stresses(st, e)
        out = {}
        for g, target in targets.items():
            a = self.axis[g]
            k, v_s = self.contacts(st, g, e)
            gain = alpha * self.area(e, g) / (k * n * st.dt)
            vmax = max_rate * e[a]
            v_out = float(np.clip(v_s + gain * (sig[g] - target), -vmax, vmax))
            vel = np.zeros(self.dim)
            vel[a] = self.sign[g] * v_out
            out[g] = vel
        return out

    def set_velocities(self, ctx, vel: dict) -> None:
        """Move the walls kinematically at ``vel`` (their DOFs stay fixed: no energy is
        booked, the contact work of the walls is booked by the kernels as external work).
        Walls already fixed take the light path (``Simulation.set_fixed_velocity``: the same
        numbers, without a full ``decree`` every servo update)."""
        if ctx.sim.set_fixed_velocity([(self.idx[g], v) for g, v in vel.items()]):
            return

        def put(s):
            for g, v in vel.items():
                i = self.idx[g]
                s.free[i] = 0.0
                s.v[i] = v
                if s.rotation:
                    s.rfree[i] = 0.0
                    s.w[i] = 0.0

        ctx.decree(put, book_energy=False)

    def clearance(self, st) -> float:
        """Smallest surface gap between a platen element and a lateral wall element [m]."""
        best = math.inf
        for p in ("bottom", "top"):
            ip = self.idx[p]
            for g in self.lateral:
                ig = self.idx[g]
                dd = np.linalg.norm(st.x[ip][:, None, :] - st.x[ig][None, :, :], axis=2)
                best = min(best, float((dd - st.r[ip][:, None] - st.r[ig][None, :]).min()))
        return best


# ============================================================================ step
@register_step("triaxial")
class Triaxial(StepBase):
    """Triaxial compression on a ``triaxial_box``, one test per confining stress, each on a
    fresh copy of the model: isotropic consolidation with every wall servo-controlled to sigma3,
    then axial loading (bottom platen fixed, top platen at ``strain_rate``, lateral walls
    servo-controlled at sigma3) until the deviator falls below ``drop`` x peak after the peak or
    the strain reaches ``max_strain``. Servo: ``v = G (sigma - sigma3)``, ``G = alpha A / (k n
    dt)``. Fits the Mohr-Coulomb envelope through the peaks; adds cohesion,
    friction_angle_deg, ucs_fit, confining_pressures and peak_strengths to summary.json; writes
    triaxial_curves.csv, triaxial.json and triaxial_curves.png, mohr_circles.png,
    triaxial_cracks.png."""

    example = {"kind": "triaxial", "confining_pressures": [1.0e5, 2.0e5], "max_strain": 5.0e-5,
               "consolidation_balances": 0.5, "tolerance": 1.0e-6}
    example_model = {"type": "triaxial_box", "dim": 2, "size": [0.03, 0.03], "d_mean": 0.005,
                     "material": "rock"}
    confining_pressures: list[float] = F(..., unit="Pa", min_length=1, max_length=100,
                                         description="Confining stresses sigma3 (>= 0, "
                                                     "compression positive): one test each, on "
                                                     "a fresh copy of the model")
    strain_rate: float = F(0.2, unit="1/s", gt=0, le=100,
                           description="Axial strain rate of the top platen (quasi-static when "
                                       "the time to the peak is many wave transit times)")
    max_strain: float = F(0.01, gt=0, le=0.2, description="Stop a test at this axial strain")
    drop: float = F(0.5, gt=0, lt=1,
                    description="Stop a test when the deviator sigma1 - sigma3 falls below drop "
                                "x its peak after the peak, at drop_strain x the peak strain or "
                                "more (small specimens lose 20-30 % in one crack burst and "
                                "recover: keep it well below 0.8)")
    drop_strain: float = F(1.5, ge=1, le=10,
                           description="The drop stops a test only at this many times the "
                                       "axial strain of its peak or more (a burst right after "
                                       "the peak may recover)")
    samples: int = F(200, ge=20, le=100000, description="Samples per test over max_strain")
    tolerance: float = F(0.02, gt=0, le=0.5,
                         description="Consolidation ends when every wall stress is within "
                                     "tolerance x max(sigma3, 5 % of the largest confining "
                                     "stress) of sigma3 (and the specimen is balanced)")
    balance_ratio: float = F(0.01, gt=0, le=1,
                             description="Consolidation ends only when the unbalanced-force "
                                         "ratio (mean net force / mean contact force) is below "
                                         "this")
    consolidation_balances: float = F(4.0, gt=0, le=100,
                                      description="Longest consolidation, in standard balances "
                                                  "of 50 N time steps (N = elements across the "
                                                  "height); a warning if it ends unconverged")
    servo_gain: float = F(0.5, gt=0, le=1,
                          description="Safety factor alpha of the servo gain G = alpha A / "
                                      "(k n dt): the fraction of the stress error one update "
                                      "may correct")
    servo_interval: int = F(10, ge=1, le=1000,
                            description="Time steps n between servo updates of the wall "
                                        "velocities")
    servo_max_rate: Optional[float] = F(None, unit="1/s", gt=0, le=1000,
                                        description="Largest servo wall speed / specimen extent "
                                                    "(default 5 x strain_rate)")
    standard_damping: bool = F(True, description="MatDEM's standard damping eta_c / N on (N = "
                                                 "elements across the height)")
    platen_layer: float = F(1.0, ge=0, le=5,
                            description="During loading, the specimen's elements within this "
                                        "many d_mean of each platen move with it along the "
                                        "loading axis (free sideways, not turning): the UCS "
                                        "test's platens, so that at sigma3 = 0 both tests load "
                                        "the rock alike; 0: the platens push through their "
                                        "contacts alone (friction: the model's platen_friction)")
    thickness: Optional[float] = F(None, unit="m", gt=0,
                                   description="2-D: thickness for the areas (default d_mean)")
    plot: bool = F(True, description="Draw triaxial_curves.png, mohr_circles.png and "
                                     "triaxial_cracks.png (needs matplotlib)")

    def check(self, cfg, groups):
        out = needs_model(cfg, "triaxial_box", "triaxial needs the walls of model type triaxial_box"
                                               " (groups xmin, xmax, [ymin, ymax,] bottom, top "
                                               "around a specimen)")
        for k, p in enumerate(self.confining_pressures):
            if not (math.isfinite(p) and p >= 0):
                out.append((("confining_pressures", k),
                            f"sigma3 = {p!r} Pa: allowed finite values >= 0 (confining "
                            "stresses are compressive, compression positive)"))
        return out

    # ------------------------------------------------------------------ plan
    def consolidation_steps(self, n_across: float) -> int:
        return max(1, int(round(self.consolidation_balances * 50.0 * n_across)))

    def loading_steps(self, dt: float) -> int:
        return max(1, int(math.ceil(self.max_strain / (self.strain_rate * dt))))

    def planned_steps(self, plan):
        per = self.consolidation_steps(plan.n_across) + self.loading_steps(plan.dt)
        return len(self.confining_pressures) * per

    def max_rate(self) -> float:
        return self.servo_max_rate if self.servo_max_rate is not None else 5.0 * self.strain_rate

    def stress_tolerance(self, sigma3: float) -> float:
        """Allowed |sigma_wall - sigma3| [Pa] at the end of the consolidation."""
        ref = max(SIGMA_REF * max(self.confining_pressures), PA_FLOOR)
        return self.tolerance * max(sigma3, ref)

    def execute(self, ctx):
        return _Run(self, ctx).execute()


# ============================================================================ the run
def _save_initial(path, st, cracks):
    from geodem.core.checkpoint import save_state

    save_state(st, path, extra={"cracks": cracks})


def _load_initial(path):
    from geodem.core.checkpoint import load_state

    st, extra = load_state(path)
    return st, extra["cracks"]


def _write_json(path, data):
    from geodem.workflow.rundir import write_json

    write_json(path, data)


class _Run:
    """One execution of a ``triaxial`` step (state kept between its phases)."""

    def __init__(self, step: Triaxial, ctx):
        self.p, self.ctx = step, ctx
        st = ctx.state
        self.dim = st.dim
        self.ax = st.dim - 1
        self.d = float(ctx.model.info["diameter"])
        self.t = float(step.thickness or self.d)
        self.walls = Walls(st, self.t, self.d)
        self.n_across = float(ctx.model.n_across)
        self.n = int(step.servo_interval)
        self.c_steps = step.consolidation_steps(self.n_across)
        self.l_steps = step.loading_steps(st.dt)
        per = max(1, int(round(self.l_steps / (step.samples * self.n))))
        self.sample_every = per * self.n  # time steps between samples (a multiple of n)
        out = ctx.out_dir
        self.f_curves, self.f_prog, self.f_init = out / CURVES, out / PROGRESS, out / INITIAL

    # ------------------------------------------------------------------ helpers
    def _target(self, s):
        """Advance to absolute time step ``s``."""
        self.ctx.advance(s - self.ctx.start_step)

    def _save_progress(self):
        _write_json(self.f_prog, self.prog)

    def _restore(self):
        """Reset the model in place to the state the step started from (time goes on)."""
        sim = self.ctx.sim
        st = sim.sync()
        step, time_, dt = st.step, st.time, st.dt
        for name in st.array_names():
            setattr(st, name, getattr(self.init, name).copy())
        st.groups = dict(self.init.groups)
        st.skin = self.init.skin
        st.step, st.time, st.dt = step, time_, dt
        sim.cracks = {k: list(v) for k, v in self.init_cracks.items()}
        sim.backend.attach(st)
        sim.reset_energy()

    def _setup_damping(self):
        from geodem.core import timestep

        if self.p.standard_damping:
            eta = timestep.standard_damping(self.ctx.state, self.n_across)
            self.ctx.set_eta(eta)

    def _cracks(self):
        log = self.ctx.sim.crack_log()
        return int((log["type"] == 1).sum()), int((log["type"] == 2).sum())

    # ------------------------------------------------------------------ main
    def execute(self):
        ctx, p = self.ctx, self.p
        st = ctx.state
        if not ctx.resumed:
            ctx.sim.crack_log()  # harvest: cstate holds no pending break codes
            _save_initial(self.f_init, st, ctx.sim.cracks)
            self.prog = {"start_step": ctx.start_step, "tests": []}
            self._save_progress()
            self.rows = []
        else:
            if not (self.f_prog.exists() and self.f_init.exists()):
                from geodem.workflow.errors import RunFailure

                raise RunFailure(f"cannot resume the triaxial step: {PROGRESS} or {INITIAL} is "
                                 f"missing in {ctx.out_dir}; start a new run")
            self.prog = json.loads(self.f_prog.read_text())
            self._forget_after(st.step)
            self.rows = self._read_rows(st.step)
        for name in (CURVES, PROGRESS, INITIAL):
            if name not in ctx.runner.files:
                ctx.runner.files.append(name)
        with open(self.f_curves, "w", newline="") as f:
            csv.writer(f).writerow(COLUMNS)
            csv.writer(f).writerows(self.rows)
        self.init, self.init_cracks = _load_initial(self.f_init)
        # interior strain gauge: the elements 1.5 d_mean or more inside every wall at the start
        self.inner = self.walls.interior_set(self.init, 1.5 * self.d)
        results = []
        for k, s3 in enumerate(p.confining_pressures):
            tests = self.prog["tests"]
            rec = tests[k] if k < len(tests) else None
            if rec is not None and "result" in rec:
                results.append(rec["result"])
                continue
            results.append(self._test(k, float(s3), rec))
        return self._finish(results)

    def _forget_after(self, step):
        """Resume: drop what happened after the checkpoint's time step."""
        keep = []
        for rec in self.prog["tests"]:
            if rec["start"] > step:
                break
            if rec.get("end", -1) > step:
                rec.pop("end", None)
                rec.pop("result", None)
            if rec.get("load_start", -1) > step:
                for key in ("load_start", "consolidation", "h_c", "e_c", "platen_layers",
                            "gauge_length"):
                    rec.pop(key, None)
            keep.append(rec)
        self.prog["tests"] = keep

    def _read_rows(self, step):
        if not self.f_curves.exists():
            return []
        return read_rows(self.f_curves, step, INT_COLUMNS, step_column=2)

    # ------------------------------------------------------------------ one test
    def _test(self, k, s3, rec):
        ctx = self.ctx
        st = ctx.state
        if rec is None or rec["start"] == st.step:
            # a new test (or one that had not made a time step: restoring again is the same)
            if rec is None:
                rec = {"sigma3": s3, "start": int(st.step)}
                self.prog["tests"].append(rec)
            self._restore()
            self._setup_damping()
            self.rows = [r for r in self.rows if r[0] != k]
            e0 = self.walls.extents(ctx.state)
            rec["e_0"] = e0.tolist()
            rec["g_0"] = self.walls.interior_extents(ctx.state, self.inner).tolist()
            self._save_progress()
            ctx.log(f"test {k + 1}/{len(self.p.confining_pressures)}: sigma3 = {s3:.4g} Pa")
        if "load_start" not in rec:
            self._consolidate(k, s3, rec)
        return self._load(k, s3, rec)

    def _consolidate(self, k, s3, rec):
        ctx, p, w = self.ctx, self.p, self.walls
        c0, cmax = rec["start"], rec["start"] + self.c_steps
        tol = p.stress_tolerance(s3)
        targets = {g: s3 for g in w.names}
        w.layers = {}  # consolidation: the walls alone
        ratio = math.inf
        while True:
            st = ctx.state
            s = st.step
            if (s - c0) % self.n and s < cmax:  # resumed between two servo updates
                self._target(min(cmax, c0 + ((s - c0) // self.n + 1) * self.n))
                continue
            sig = w.stresses(st)
            err = max(abs(sig[g] - s3) for g in w.names)
            converged = False
            if err <= tol:
                ratio = ctx.sim.unbalanced_force_ratio()
                converged = ratio <= p.balance_ratio
            if converged or s >= cmax:
                break
            w.set_velocities(ctx, w.servo(ctx.state, targets, p.servo_gain, self.n,
                                          p.max_rate()))
            self._target(min(cmax, s + self.n))
        st = ctx.state
        if not math.isfinite(ratio):
            ratio = ctx.sim.unbalanced_force_ratio()
        e = w.extents(st)
        e0 = np.asarray(rec["e_0"])
        g0 = np.asarray(rec["g_0"])
        g = w.interior_extents(st, self.inner)
        cons = {"steps": int(st.step - c0), "converged": bool(converged),
                "wall_stresses": {g: float(v) for g, v in sig.items()},
                "max_stress_error": float(err), "tolerance": float(tol),
                "unbalanced_ratio": float(ratio),
                "volumetric_strain": float(1.0 - np.prod(e) / np.prod(e0)),
                "axial_strain": float((e0[-1] - e[-1]) / e0[-1]),
                "lateral_strains": [float((e0[a] - e[a]) / e0[a]) for a in range(self.ax)],
                "interior_strains": [float((g0[a] - g[a]) / g0[a]) for a in range(self.dim)],
                "interior_volumetric_strain": float(1.0 - np.prod(g) / np.prod(g0))}
        if not converged:
            ctx.log(f"warning: sigma3 = {s3:.4g} Pa: consolidation did not converge in "
                    f"{self.c_steps} steps ({p.consolidation_balances:g} balances): wall stress "
                    f"error {err:.4g} Pa (allowed {tol:.4g}), unbalanced ratio {ratio:.3g} "
                    f"(allowed {p.balance_ratio:g}); loading anyway")
        rec.update({"consolidation": cons, "load_start": int(st.step), "h_c": float(e[-1]),
                    "e_c": e.tolist()})
        self._save_progress()

    def _load(self, k, s3, rec):
        from geodem import measure

        ctx, p, w = self.ctx, self.p, self.walls
        l0 = rec["load_start"]
        lmax = l0 + self.l_steps
        e_c = np.asarray(rec["e_c"])
        h_c = float(rec["h_c"])
        lat_targets = {g: s3 for g in w.lateral}
        st = ctx.state
        if st.step == l0:  # set up the loading (again, on a resume at this very step)
            vel = w.servo(st, lat_targets, p.servo_gain, self.n, p.max_rate())
            vel["bottom"] = np.zeros(self.dim)
            v_top = np.zeros(self.dim)
            v_top[self.ax] = -p.strain_rate * h_c
            vel["top"] = v_top
            w.set_velocities(ctx, vel)
            self._glue_layers(rec, vel)
        else:
            w.layers = {g: np.asarray(i, dtype=np.int64)
                        for g, i in rec.get("platen_layers", {}).items()}
        rows = [r for r in self.rows if r[0] == k]
        q = [r[6] for r in rows]
        ipeak = int(np.argmax(q)) if q else 0
        peak = max(q) if q else -math.inf
        reason = "max_strain"
        while True:
            st = ctx.state
            s = st.step
            if (s - l0) % self.n and s < lmax:  # resumed between two servo updates
                self._target(min(lmax, l0 + ((s - l0) // self.n + 1) * self.n))
                continue
            due = (s - l0) % self.sample_every == 0 or s >= lmax
            if due and not (rows and rows[-1][2] == s):
                row = self._sample(k, s3, st, e_c, h_c, rec.get("gauge_length"))
                rows.append(row)
                self.rows.append(row)
                with open(self.f_curves, "a", newline="") as fh:
                    csv.writer(fh).writerow(row)
                if row[6] > peak:
                    peak, ipeak = row[6], len(rows) - 1
            if due and past_peak(rows, ipeak, p.drop, p.drop_strain):
                reason = "drop"
                break
            if s >= lmax:
                break
            if due and w.clearance(st) < 0.05 * self.d:
                reason = "walls_touch"
                ctx.log(f"warning: sigma3 = {s3:.4g} Pa: a platen came within 0.05 d_mean of a "
                        "lateral wall; test stopped (lower max_strain)")
                break
            if due:
                worst, a, b = max_overlap(st.x, st.r, st.nbr)
                if worst > CRUSHED_OVERLAP:
                    # an element squeezed into a corner between a platen and a lateral wall
                    # (or crushed in a band) long after the peak: stop the stage before the
                    # engine's overlap limit (0.5) fails the whole run
                    reason = "crushed"
                    ctx.log(f"warning: sigma3 = {s3:.4g} Pa: elements {a} and {b} overlap by "
                            f"{worst:.2f} x the smaller radius (> {CRUSHED_OVERLAP}); test "
                            "stopped (lower max_strain or the strain rate)")
                    break
            vel = w.servo(st, lat_targets, p.servo_gain, self.n, p.max_rate())
            w.set_velocities(ctx, vel)
            self._target(min(lmax, s + self.n))
        a = np.array(rows, float)
        eps, sig1, dev, lat_sig = a[:, 4], a[:, 5], a[:, 6], a[:, 9]
        i = int(np.argmax(dev))
        run = np.maximum.accumulate(eps)
        keep = np.concatenate([[True], eps[1:] > run[:-1]])
        E = None
        try:
            E = measure.youngs_modulus(eps[keep], dev[keep])
        except ValueError as exc:
            ctx.log(f"sigma3 = {s3:.4g} Pa: modulus not fitted: {exc}")
        ct, cs = self._cracks()
        peaked = has_peaked(reason, dev, i)
        res = {"sigma3": s3, "peaked": peaked,
               "peak_strength": float(sig1[i]) if peaked else None,
               "max_strength": float(sig1[i]), "peak_deviator": float(dev[i]),
               "peak_strain": float(eps[i]), "lateral_stress_at_peak": float(lat_sig[i]),
               "E": E, "final_strain": float(eps[-1]), "final_deviator": float(dev[-1]),
               "stopped_by": reason, "samples": len(rows), "cracks_tensile": ct,
               "cracks_shear": cs, "consolidation": rec["consolidation"],
               "steps": int(ctx.state.step - rec["start"])}
        what = (f"peak sigma1 = {sig1[i]:.4g} Pa" if peaked else
                f"no peak (sigma1 still {sig1[i]:.4g} Pa and not fallen by "
                f"{100 * (1 - SOFTENED):.0f} % when stopped by {reason}; raise max_strain)")
        ctx.log(f"sigma3 = {s3:.4g} Pa: {what} at strain "
                f"{res['peak_strain']:.4g} (lateral stress {res['lateral_stress_at_peak']:.4g} "
                f"Pa), E = {E or math.nan:.4g} Pa; cracks {ct} tensile, {cs} shear; stopped by "
                f"{reason}")
        rec.update({"end": int(ctx.state.step), "result": res})
        self._save_progress()
        return res

    def _glue_layers(self, rec, vel):
        """Glue the specimen's end layers (``platen_layer`` d_mean deep) to the platens along
        the loading axis: they move at the platens' speed, free sideways, and do not turn; the
        indices go to the progress record so that a resumed run measures the same forces."""
        ctx, w, ax = self.ctx, self.walls, self.ax
        depth = self.p.platen_layer * self.d
        w.layers = {g: w.layer(ctx.state, g, depth) for g in ("bottom", "top")} if depth else {}
        rec["platen_layers"] = {g: i.tolist() for g, i in w.layers.items()}
        rec["gauge_length"] = w.layer_distance(ctx.state) if w.layers else None
        self._save_progress()
        if not w.layers:
            return

        def glue(s):
            for g, i in w.layers.items():
                s.free[i, ax] = 0.0
                s.v[i, ax] = vel[g][ax]
                if s.rotation:
                    s.rfree[i] = 0.0
                    s.w[i] = 0.0

        ctx.decree(glue)  # the layers' kinetic energy change is booked as work

    def _sample(self, k, s3, st, e_c, h_c, gauge=None):
        w = self.walls
        e = w.extents(st)
        sig = w.stresses(st, e)
        s1 = 0.5 * (sig["bottom"] + sig["top"])
        lat = [sig[g] for g in w.lateral]
        if gauge:  # between the glued end layers' centres, as the UCS test measures it
            eps_ax = (gauge - w.layer_distance(st)) / gauge
        else:
            eps_ax = (h_c - e[-1]) / h_c
        eps_lat = float(np.mean((e_c[:-1] - e[:-1]) / e_c[:-1]))
        eps_v = 1.0 - float(np.prod(e) / np.prod(e_c))
        ct, cs = self._cracks()
        return [k, s3, int(st.step), float(st.time), float(eps_ax), float(s1), float(s1 - s3),
                eps_lat, eps_v, float(np.mean(lat)), float(max(abs(v - s3) for v in lat)), ct, cs]

    # ------------------------------------------------------------------ results
    def _finish(self, results):
        from geodem import measure

        ctx, p = self.ctx, self.p
        s3_all = [r["sigma3"] for r in results]
        # a stage that has not peaked has no strength to fit: it is kept out of the envelope
        peaks = [(r["sigma3"], r["peak_strength"]) for r in results
                 if r["peak_strength"] is not None]
        s3 = [a for a, _ in peaks]
        s1 = [b for _, b in peaks]
        fit = {"cohesion": None, "friction_angle_deg": None, "ucs_fit": None}
        fit_error = None
        try:
            mc = measure.mohr_coulomb_fit(s3, s1)
            fit = {"cohesion": mc.cohesion, "friction_angle_deg": mc.friction_angle_deg,
                   "ucs_fit": mc.ucs_fit}
        except ValueError as exc:
            fit_error = str(exc)
            ctx.log(f"Mohr-Coulomb envelope not fitted: {exc}")
        out = dict(fit)
        out.update({"confining_pressures": s3_all,
                    "peak_strengths": [r["peak_strength"] for r in results],
                    "no_peak": [r["sigma3"] for r in results if r["peak_strength"] is None]})
        ctx.summary.update(out)
        res = dict(out, tests=results, strain_rate=p.strain_rate,
                   thickness=self.t if self.dim == 2 else None)
        if fit_error:
            res["fit_error"] = fit_error
        else:
            q = (1.0 + math.sin(math.radians(fit["friction_angle_deg"]))) / \
                (1.0 - math.sin(math.radians(fit["friction_angle_deg"])))
            pred = [fit["ucs_fit"] + q * v for v in s3]
            res["fit_residuals"] = [float(a - b) for a, b in zip(s1, pred)]
            ctx.log(f"Mohr-Coulomb: c = {fit['cohesion']:.4g} Pa, phi = "
                    f"{fit['friction_angle_deg']:.3g} deg, C0 = {fit['ucs_fit']:.4g} Pa")
        if p.plot and ctx.cfg.outputs.plots:
            rows = np.array(self.rows, float)
            res["plots"] = [
                ctx.plot("triaxial_curves.png", lambda path: _plot_curves(path, rows)),
                ctx.plot("mohr_circles.png", lambda path: _plot_mohr(path, s3, s1, fit)),
            ]
            st = ctx.state
            log = ctx.sim.crack_log()
            pos = 0.5 * (st.x[log["i"]] + st.x[log["j"]]) if len(log) else np.zeros((0, self.dim))
            spec = self.walls.spec
            res["plots"].append(ctx.plot("triaxial_cracks.png", lambda path: _plot_cracks(
                path, st.x, spec, pos, log["type"], s3_all[-1] if s3_all else 0.0)))
        return res


SOFTENED = 0.95  # a stage stopped by max_strain has peaked if q fell below this x its maximum
#: overlap (x the smaller radius) at which a stage stops as crushed; the engine fails at 0.5
CRUSHED_OVERLAP = 0.35


def past_peak(rows, ipeak: int, drop: float, drop_strain: float) -> bool:
    """Whether a stage's samples ``rows`` (curve columns: axial strain at 4, deviator at 6)
    stop it: its last deviator below ``drop`` x the peak at ``rows[ipeak]``, at least two
    samples and ``drop_strain`` x the peak's axial strain after it (a burst right after the
    peak of a small specimen can recover past it), and ten samples in all."""
    if len(rows) - ipeak < 3 or len(rows) < 10:
        return False
    peak, last = rows[ipeak], rows[-1]
    return peak[6] > 0 and last[6] < drop * peak[6] and last[4] >= drop_strain * peak[4]


def has_peaked(reason: str, dev, i: int) -> bool:
    """Whether a triaxial stage reached its peak: stopped by the post-peak ``drop``, or, when
    stopped otherwise (``max_strain``, walls), its deviator ``dev`` has fallen below
    ``SOFTENED`` x its maximum ``dev[i]`` after it. A curve still hardening at the stop has
    no peak: its largest stress is a lower bound of the strength, not the strength."""
    if reason == "drop":
        return True
    return bool(i < len(dev) - 1 and dev[-1] < SOFTENED * dev[i])


# ============================================================================ pictures


def _plot_curves(path, rows):
    plt = pyplot()
    if plt is None:
        return None
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for k in np.unique(rows[:, 0]).astype(int) if rows.size else []:
        r = rows[rows[:, 0] == k]
        lab = f"sigma3 = {r[0, 1] / 1e6:.3g} MPa"
        a1.plot(r[:, 4], r[:, 6] / 1e6, "-", lw=1.2, label=lab)
        a2.plot(r[:, 4], r[:, 8], "-", lw=1.2, label=lab)
    a1.set_xlabel("axial strain [-]")
    a1.set_ylabel("deviator sigma1 - sigma3 [MPa]")
    a1.set_title("triaxial compression")
    a1.legend(fontsize="small")
    a2.set_xlabel("axial strain [-]")
    a2.set_ylabel("volumetric strain [-] (compaction +)")
    a2.axhline(0.0, color="0.7", lw=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_mohr(path, s3, s1, fit):
    plt = pyplot()
    if plt is None:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.5))
    th = np.linspace(0.0, math.pi, 200)
    top = max(s1) / 1e6 if s1 else 1.0
    for a, b in zip(s3, s1):
        c, r = 0.5 * (a + b) / 1e6, 0.5 * (b - a) / 1e6
        ax.plot(c + r * np.cos(th), r * np.sin(th), "-", lw=1.2,
                label=f"sigma3 = {a / 1e6:.3g}, sigma1 = {b / 1e6:.3g} MPa")
    if fit["cohesion"] is not None:
        phi = math.radians(fit["friction_angle_deg"])
        sg = np.linspace(min(0.0, -fit["cohesion"] / 1e6 / max(math.tan(phi), 1e-9)), top, 50)
        tau = fit["cohesion"] / 1e6 + sg * math.tan(phi)
        ax.plot(sg, tau, "k--", lw=1.0, label=f"c = {fit['cohesion'] / 1e6:.3g} MPa, phi = "
                                              f"{fit['friction_angle_deg']:.3g} deg")
    ax.set_xlim(min(0.0, ax.get_xlim()[0]), top * 1.05)
    ax.set_ylim(0.0, None)
    ax.set_aspect("equal")
    ax.set_xlabel("normal stress [MPa]")
    ax.set_ylabel("shear stress [MPa]")
    ax.set_title("Mohr circles at the peaks")
    ax.legend(fontsize="small", loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_cracks(path, x, spec, pos, types, s3):
    plt = pyplot()
    if plt is None:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 6))
    ax.scatter(x[spec, 0], x[spec, -1], s=3, c="0.8")
    ax.scatter(x[~spec, 0], x[~spec, -1], s=3, c="0.3")
    for code, col, name in ((1, "C0", "tensile"), (2, "C3", "shear"), (0, "C2", "joint")):
        sel = types == code
        if sel.any():
            ax.scatter(pos[sel, 0], pos[sel, -1], s=8, c=col, label=f"{name} ({sel.sum()})")
    ax.set_aspect("equal")
    ax.set_title(f"cracks, last test (sigma3 = {s3 / 1e6:.3g} MPa)")
    label_map(ax, ("x", "z" if x.shape[1] == 3 else "y"), fontsize=8)
    legend_outside(ax)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
