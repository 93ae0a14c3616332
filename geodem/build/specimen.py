"""Bonded specimens: cementing a packing and the whole chain packing -> cutting -> cementing.

``cement(state, gap, element_params, ...)``
    * element parameters from :func:`geodem.materials.macro_to_micro` (``Micro.element``, given
      for the reference diameter ``d_ref``) scaled per element by ``s = d_i / d_ref``
      (PHYSICS.md section 2, "Mixed sizes"): ``kn, ks, xb`` x ``s``, ``fs0`` x ``s^2``, ``mu``
      unchanged; mass ``rho * volume`` (sphere, or disc of thickness ``d_i`` in 2-D unless
      ``state.thickness`` is set);
    * every pair with surface gap ``<= gap`` is bonded (:func:`contact_pairs` +
      :func:`rows_from_pairs`), then the rows are completed with the unbonded neighbours within
      the skin (:func:`build_rows`);
    * gravity is switched off, every element freed, velocities and shear springs zeroed, time and
      energy books restarted; standard balances (damping ``eta_c / N``, ``50 N`` steps, ``N`` =
      elements across the largest extent) until the unbalanced-force ratio is below ``tol``.

    The default ``gap`` is the smallest element ``xb``: a bond formed across a gap starts in
    tension, and one formed across a gap larger than its breaking displacement would break at
    once. The locked-in overlaps of the packing relax during the balance; a few bonds may break
    then (reported).

``make_specimen(shape, size, d_mean, distri_rate, material, dim, seed)``
    The packing recipe is the element parameters' ``packing`` (a calibration stores it; default
    ``isotropic`` in 3-D, ``deposit`` in 2-D):

    * ``isotropic``: :func:`isotropic_specimen` (isotropic compression by radius expansion
      inside the shape's bounding box, :mod:`geodem.build.isotropic`; bonds stress-free, flat
      faces; every pair within ``bond_gap`` d_mean bonded, default 0.01);
    * ``deposit`` (2-D only): deposit (:mod:`geodem.build.packing`) in a box 1.5 ``d_mean``
      wider than the specimen on every side and about 2 ``d_mean`` taller, compact with the
      platen, lift the platen and stiffen the packing to the material's ``kn``
      (:func:`packing.stiffen`: the locked-in overlaps shrink below the bonds' breaking
      displacement), cut the shape (centres inside; specimen bounding box starting at the
      origin), cement, Morton-sort (:func:`spatial_sort`).

    The recipe is part of the rock: the library sandstone's 2-D element parameters make the lab's
    rock on ``isotropic`` (as calibrated; Brazilian 1.05 x direct tension) and one 20 % softer
    and weaker on ``deposit``, whose disc is 2.1 x its direct tension (docs/calibration.md,
    "Reaching real rocks").
    Every element is in group ``"specimen"``; platens are for the caller.
"""
from __future__ import annotations

import math

import numpy as np

from geodem.build import packing
from geodem.build.lattice import contact_pairs
from geodem.build.shapes import Box, Cylinder, Disc, subset_state
from geodem.core import groups, neighbors, timestep
from geodem.core.state import BONDED, State
from geodem.materials import Micro, at_size, macro_to_micro

__all__ = ["cement", "make_specimen", "isotropic_specimen", "specimen_params", "DEFAULT_MATERIAL",
           "coordination", "specimen_shape", "packing_recipe", "bond_strength_factors",
           "well_bonded", "settle"]

DEFAULT_MATERIAL = {"E": 10e9, "nu": 0.15, "Tu": 5e6, "Cu": 50e6, "mu_i": 0.8, "rho": 2500.0}
_ELEMENT_KEYS = ("kn", "ks", "xb", "fs0", "mu")
RELAX_OVERLAP = 0.1  # locked-in overlaps relaxed below this fraction of the smallest xb
CEMENT_GAP = 0.1  # make_specimen bonds pairs with gaps up to this fraction of the smallest xb


def coordination(state: State) -> float:
    """Mean number of intact bonds per element."""
    return float((state.cstate == BONDED).sum()) / max(state.n, 1)


def _element_dict(element_params) -> dict:
    return element_params.element if isinstance(element_params, Micro) else element_params


def _assign(state, element_params, d_ref, rho):
    if isinstance(element_params, Micro):
        d_ref = element_params.d if d_ref is None else d_ref
        if rho is None:
            rho = element_params.mass * math.sqrt(2.0) / element_params.d ** 3
        element_params = element_params.element
    missing = [k for k in _ELEMENT_KEYS if k not in element_params]
    if missing:
        raise ValueError(f"element_params lacks {missing} (expected Micro.element keys)")
    if d_ref is None or rho is None:
        raise ValueError("give d_ref and rho (or a Micro from macro_to_micro)")
    s = 2.0 * state.r / float(d_ref)
    state.kn[:] = element_params["kn"] * s
    state.ks[:] = element_params["ks"] * s
    state.xb[:] = element_params["xb"] * s
    state.fs0[:] = element_params["fs0"] * s * s
    state.mu[:] = element_params["mu"]
    if state.dim == 3:
        vol = packing.element_volume(state.r, 3)
    else:
        t = state.thickness if state.thickness > 0 else 2.0 * state.r
        vol = packing.element_volume(state.r, 2) * t
    state.m[:] = float(rho) * vol


def bond_strength_factors(n_bonds: int, weibull_m, seed: int = 0) -> np.ndarray:
    """Per-bond strength factors (``brate``) of a heterogeneous rock: Weibull distributed with
    modulus ``weibull_m`` (RFPA's homogeneity index: larger is more uniform) and mean 1::

        w = (-ln U)^(1/m) / Gamma(1 + 1/m),   U uniform in (0, 1)

    (coefficient of variation ``sqrt(Gamma(1 + 2/m) / Gamma(1 + 1/m)^2 - 1)``: 0.52 at m = 2,
    0.36 at 3, 0.23 at 5, 0.12 at 10). Both the tensile (``kn xb``) and the shear (``fs0``)
    strength of the bond are multiplied by ``w`` (the law's ``rate``). ``weibull_m`` None: every
    factor is 1 (uniform bonds). Tang et al. 2000 (RFPA); Potyondy & Cundall 2004, section 3.2
    (strength scatter of parallel bonds)."""
    if weibull_m is None:
        return np.ones(n_bonds)
    m = float(weibull_m)
    if not m > 0.0:
        raise ValueError(f"bond_strength_weibull = {weibull_m!r}: allowed > 0")
    u = np.random.default_rng(seed).random(n_bonds)
    return (-np.log1p(-u)) ** (1.0 / m) / math.gamma(1.0 + 1.0 / m)


def cement(state: State, gap=None, element_params=None, *, d_ref=None, rho=None, n_across=None,
           tol=1e-3, max_rounds=20, backend=None, skin=None, seed=0):
    """Give ``state`` its material and bond every contact within ``gap``; balance (see module
    docstring). Modifies ``state`` in place. Returns a report dict: ``n_elements``, ``bonds``
    (intact after the balance), ``bonds_formed``, ``bonds_broken``, ``coordination`` (bonds per
    element, 2 x bonds / n), ``interior_coordination`` (the same over the elements inside the
    bounding box inset by one ``d_max``: free of the surface deficit), ``porosity`` (Monte-Carlo estimate inside the bounding box inset by
    one ``d_max``), ``packing_fraction``, ``max_overlap`` (fraction of the smaller radius),
    ``unbalanced_ratio``, ``balance_rounds`` (standard balances run, at most ``max_rounds``),
    ``balanced`` (``unbalanced_ratio < tol``: False when ``max_rounds`` ran out first),
    ``steps``, ``dt``."""
    from geodem.core.engine import Simulation

    if element_params is None:
        raise ValueError("element_params is required (macro_to_micro(...) or its .element)")
    _assign(state, element_params, d_ref, rho)
    if gap is None:
        gap = float(state.xb.min())
    st = state
    st.gravity = np.zeros(st.dim)
    st.free[:] = 1.0
    st.v[:] = 0.0
    st.a[:] = 0.0
    st.fload[:] = 0.0
    st.fs[:] = 0.0
    for k in ("q_visc", "q_break_n", "q_break_s", "q_fric", "w_ext"):
        getattr(st, k)[:] = 0.0
    st.step, st.time, st.dt = 0, 0.0, 0.0
    d_mean = 2.0 * float(st.r.mean())
    st.skin = 0.1 * d_mean if skin is None else float(skin)
    i, j = contact_pairs(st.x, st.r, gap)
    st.nbr[:] = -1
    st.cstate[:] = 0
    st.brate[:] = 1.0
    weibull = _element_dict(element_params).get("bond_strength_weibull")
    rate = bond_strength_factors(len(i), weibull, seed)
    out = neighbors.rows_from_pairs(st, i, j, bonded=True, brate=rate)
    if isinstance(out, State):  # pragma: no cover - rows_from_pairs assigns in place
        st = out
    neighbors.build_rows(st)
    formed = int((st.cstate == BONDED).sum() // 2)
    if n_across is None:
        ext = st.x.max(axis=0) - st.x.min(axis=0)
        n_across = max(float(ext.max()) / d_mean, 1.0)
    sim = Simulation(st, backend=backend, monitor_every=0)
    ratio = math.inf
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        ratio = sim.balance(n_across)
        if ratio < tol:
            break
    sim.sync()
    from geodem.core.checks import max_overlap

    bonds = sim.bonded_count()
    lo, hi = st.x.min(axis=0), st.x.max(axis=0)
    inset = 2.0 * float(st.r.max())
    if np.all(hi - lo > 2.0 * inset + d_mean):
        lo, hi = lo + inset, hi - inset
    pf = packing.packing_fraction(st.x, st.r, lo, hi)
    per = (st.cstate == BONDED).sum(axis=1)
    inner = np.all((st.x > lo) & (st.x < hi), axis=1)
    interior = float(per[inner].mean()) if inner.any() else float("nan")
    return {"n_elements": int(st.n), "bonds": bonds, "bonds_formed": formed,
            "bonds_broken": len(sim.crack_log()), "coordination": 2.0 * bonds / max(st.n, 1),
            "interior_coordination": interior,
            "porosity": 1.0 - pf, "packing_fraction": pf,
            "max_overlap": float(max_overlap(st.x, st.r, st.nbr)[0]),
            "unbalanced_ratio": float(ratio), "balance_rounds": rounds,
            "balanced": bool(ratio < tol),
            "steps": rounds * timestep.standard_balance_steps(n_across), "dt": st.dt,
            "gap": gap}


def specimen_shape(shape: str, size, dim: int, origin=0.0):
    """The :mod:`geodem.build.shapes` object for ``shape`` with its bounding box starting at
    ``origin``: box ``size = (Lx, Ly[, Lz])``; cylinder (3-D) ``(diameter, height)``; disc
    ``(diameter,)`` in 2-D or ``(diameter, thickness)`` in 3-D (axis y)."""
    size = [float(v) for v in np.atleast_1d(size)]
    o = np.zeros(dim) + origin
    if shape == "box":
        if len(size) != dim:
            raise ValueError(f"box size needs {dim} values, got {size}")
        return Box(tuple(o), tuple(o + np.array(size)))
    if shape == "cylinder":
        if dim != 3 or len(size) != 2:
            raise ValueError("cylinder: 3-D only, size = (diameter, height)")
        R = 0.5 * size[0]
        return Cylinder((o[0] + R, o[1] + R), R, o[2], o[2] + size[1])
    if shape == "disc":
        R = 0.5 * size[0]
        if dim == 2:
            if len(size) != 1:
                raise ValueError("2-D disc: size = (diameter,)")
            return Disc((o[0] + R, o[1] + R), R)
        if len(size) != 2:
            raise ValueError("3-D disc: size = (diameter, thickness)")
        return Disc((o[0] + R, o[1] + 0.5 * size[1], o[2] + R), R, "y", size[1])
    raise ValueError(f"shape must be 'box', 'cylinder' or 'disc', got {shape!r}")


def specimen_params(mat, element, d_mean):
    """Element parameters at ``d_mean``: ``macro_to_micro`` of the rock properties ``mat``, or
    the size-free ``element`` parameters at that size."""
    if element is None:
        return macro_to_micro(mat["E"], mat["nu"], mat["Tu"], mat["Cu"], mat["mu_i"],
                              mat["rho"], d_mean).element
    return at_size(element, d_mean)


def isotropic_specimen(shp, d_mean, distri_rate, params, rho, *, seed=0, backend=None,
                       tol=1e-3, **packing_kw):
    """A bonded random specimen of shape ``shp`` (:func:`specimen_shape`) from
    :func:`geodem.build.isotropic.isotropic_packing`: a box is packed in itself (flat faces,
    the box of the packing; above ``TILE_ABOVE`` elements a repeated periodic cell, its faces
    cut), other shapes in their bounding box (and cut: centres inside).
    The bond range is ``params["bond_gap"]`` (d_mean; default the packing's 0.01).
    The packing's bonded pairs touch, stress-free; :func:`cement` bonds them (gap 0) with the
    element parameters ``params`` (at ``d_mean``) and balances; Morton-sorted. Every element is
    in group ``"specimen"``. Returns ``(state, report)``: the :func:`cement` keys plus
    ``volume``, ``shape_packing_fraction`` and ``packing`` (the packing's report)."""
    from geodem.build.isotropic import isotropic_packing
    from geodem.core.state import new_state

    lo, hi = shp.bounds
    if params.get("bond_gap") is not None:
        packing_kw.setdefault("gap", float(params["bond_gap"]))
    x, r, prep = isotropic_packing(hi - lo, d_mean, distri_rate, seed=seed, **packing_kw)
    x = x + lo
    if not isinstance(shp, Box):
        keep = shp.mask(x)
        x, r = x[keep], r[keep]
    st = new_state(x, r, 1.0, width=16)
    groups.add_group(st, "specimen", np.arange(st.n))
    # a repeated periodic cell: its small unbalance (the bonds' prestress) repeats with the
    # cell and relaxes over a cell, not over the box (the standard balance's 50 n_across
    # steps per round would grow as N^(4/3))
    across = max(prep["tile_size"]) / d_mean if "tiles" in prep else None
    rep = cement(st, 0.0, params, d_ref=d_mean, rho=rho, backend=backend, tol=tol, seed=seed,
                 n_across=across)
    neighbors.spatial_sort(st)
    vol_el = float(packing.element_volume(st.r, st.dim).sum())
    rep.update({"volume": shp.volume, "shape_packing_fraction": vol_el / shp.volume,
                "packing": prep})
    return st, rep


def packing_notes(report) -> list[str]:
    """What a specimen's build report ``report`` (:func:`isotropic_specimen`'s) says the user
    should know: a packing built from a repeated periodic cell (above
    ``geodem.build.isotropic.TILE_ABOVE`` elements)."""
    prep = (report or {}).get("packing") or {}
    if "tiles" not in prep:
        return []
    from geodem.build.isotropic import TILE_ABOVE

    if "periodic_axes" in prep:
        along = prep["periodic_axes"]
        side = min(prep["tile_size"][a] for a in along)
        names = " and ".join("xyz"[a] for a in along)
        return [f"the random packing's {prep['n']:,} elements are a strip cell of "
                f"{prep['tile_elements']:,} repeated {' x '.join(map(str, prep['tiles']))} "
                f"(more than {TILE_ABOVE:,} elements): periodic along {names}, its other "
                f"faces flat as jammed whole; the micro-structure repeats every {side:.3g} m "
                f"along {names} (docs/brazilian.md, 'Large 3-D discs')"]
    return [f"the random packing's {prep['n']:,} elements are a periodic cell of "
            f"{prep['tile_elements']:,} repeated {' x '.join(map(str, prep['tiles']))} (a box "
            f"of more than {TILE_ABOVE:,} elements: docs/performance.md, 'Cost against "
            "model size'); the micro-structure repeats every cell and the box's faces cut the "
            "cells instead of being flat: elements overhang them by up to a radius (a lab "
            "test takes the box's section, not the elements'), and a disc cut from such a box "
            "splits early (docs/performance.md, 'A tiled lab specimen')"]


def cut_section(report, size) -> list[float] | None:
    """The lateral widths [m] of a box specimen whose faces were cut from a repeated periodic
    cell (:func:`isotropic_specimen` above ``TILE_ABOVE`` elements): the box's, ``size[:-1]``;
    None for a box packed whole (flat faces: its section is measured over the elements).

    Why: elements overhang a cut face by up to a radius, so the section measured over the
    elements is larger than the box's (23 % at 10 d_mean across) while the load is carried by
    the box's worth of packing: the library marble's 3-D UCS specimen cut from one cell read E
    39.0 GPa and UCS 70.1 MPa over the elements' section, 50.0 and 90.1 packed whole
    (docs/performance.md, "A tiled lab specimen")."""
    prep = (report or {}).get("packing") or {}
    if "tiles" not in prep or size is None:
        return None
    return [float(w) for w in list(size)[:-1]]


PACKINGS = ("isotropic", "deposit")


def packing_recipe(element, dim: int) -> str:
    """The packing recipe of element parameters ``element`` (their ``packing``; default
    ``isotropic`` in 3-D, ``deposit`` in 2-D). ``deposit`` is 2-D only."""
    recipe = (element or {}).get("packing") or ("isotropic" if dim == 3 else "deposit")
    if recipe not in PACKINGS:
        raise ValueError(f"packing = {recipe!r}: allowed {', '.join(PACKINGS)}")
    if recipe == "deposit" and dim == 3:
        raise ValueError("packing = 'deposit' is 2-D only; 3-D specimens are packed "
                         "isotropically (packing: isotropic)")
    if recipe == "deposit" and (element or {}).get("bond_gap") is not None:
        raise ValueError("bond_gap needs packing: isotropic (the deposited packing bonds the "
                         "pairs within a tenth of the breaking displacement)")
    return recipe


def make_specimen(shape="box", size=None, d_mean=0.01, distri_rate=0.2, material=None, dim=3,
                  seed=0, gap=None, backend=None, tol=1e-3, element=None, tile=None,
                  periodic_axes=None):
    """Pack, cut and cement a specimen. ``material``: rock properties (``E, nu, Tu, Cu, mu_i,
    rho``) converted by ``macro_to_micro`` at ``d_mean``; or, with ``element`` (size-free
    element parameters, :func:`geodem.materials.per_size` keys, e.g. calibrated ones), only
    ``rho`` is read from ``material``. Returns ``(state, report)``; the report holds the
    :func:`cement` keys plus ``packing`` (deposition/compaction summaries) and ``volume``
    (shape volume, area in 2-D) and ``shape_packing_fraction`` (element volume / shape volume).
    ``tile``: an isotropic packing's tiling (:func:`geodem.build.isotropic.isotropic_packing`;
    None: above ``TILE_ABOVE`` elements, False: never); ``periodic_axes``: above
    ``TILE_ABOVE`` elements a strip periodic along these axes instead, with flat faces along
    the others (a 3-D disc's sides and poles)."""
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    mat = dict(DEFAULT_MATERIAL if material is None else material)
    shp = specimen_shape(shape, size if size is not None else [10 * d_mean] * dim, dim)
    recipe = packing_recipe(element, dim)
    if recipe == "isotropic":
        return isotropic_specimen(shp, d_mean, distri_rate,
                                  specimen_params(mat, element, d_mean), mat["rho"], seed=seed,
                                  backend=backend, tol=tol, tile=tile,
                                  periodic_axes=periodic_axes)
    blo, bhi = shp.bounds
    ext = bhi - blo
    margin = 1.5 * d_mean
    box_lo = np.zeros(dim)
    # a shape lower than wide is packed and relaxed in a box as high as wide, then cut: in a
    # low box the relaxation unloads the packing completely, its contacts open wider than the
    # cementing gap and only ~1.4 bonds per element form instead of ~3.7 (docs/tbm_cutter.md,
    # "The block's bonds")
    height = max(float(ext[-1]), float(ext[:-1].max()))
    box_hi = np.append(ext[:-1] + 2 * margin, height + 2 * margin + 1.0 * d_mean)
    phi = 0.84 if dim == 2 else 0.63
    x, r = packing.random_placement((box_lo, box_hi), porosity=1.0 - phi * 1.1, d_mean=d_mean,
                                    distri_rate=distri_rate, seed=seed)
    st = packing.deposition_state(x, r, (box_lo, box_hi), rho=mat["rho"])
    dep = packing.deposit(st, backend=backend)
    com = packing.compact(st, backend=backend)
    params = specimen_params(mat, element, d_mean)
    s = groups.members(st, "sample")
    factor = max(1.0, params["kn"] / float(st.kn[s].mean()))
    stf = packing.stiffen(st, factor, backend=backend)
    xb_min = float(params["xb"]) * float(st.r[groups.members(st, "sample")].min()) * 2 / d_mean
    rel = packing.relax(st, RELAX_OVERLAP * xb_min, sim=stf["sim"])
    if rel["max_overlap"] > RELAX_OVERLAP * xb_min:
        # cementing now would lock in overlaps that break the bonds as soon as the walls go
        raise RuntimeError(
            f"the packing did not relax: largest overlap {rel['max_overlap']:.3g} m = "
            f"{rel['max_overlap'] / xb_min:.3g} x the smallest breaking displacement after "
            f"{rel['rounds']} balance rounds (needed < {RELAX_OVERLAP}); report this with the "
            "arguments used")
    s = groups.members(st, "sample")
    top = float(st.x[s, -1].max())
    off = np.append(np.full(dim - 1, margin), margin)
    if top < off[-1] + ext[-1] + 0.5 * d_mean:
        raise RuntimeError(f"the packing ({top:.4g} m high) is too low for the specimen; "
                           "report this with the arguments used")
    keep = np.zeros(st.n, bool)
    keep[s] = shp.mask(st.x[s] - off)
    sp = subset_state(st, keep, rebuild=False)
    sp.x -= off
    sp.x_ref[:] = sp.x
    sp.groups = {"all": 0}
    sp.group[:] = 0
    groups.add_group(sp, "specimen", np.arange(sp.n))
    if gap is None:
        gap = CEMENT_GAP * xb_min
    rep = cement(sp, gap, params, d_ref=d_mean, rho=mat["rho"], backend=backend, tol=tol,
                 seed=seed)
    neighbors.spatial_sort(sp)
    vol_el = float(packing.element_volume(sp.r, dim).sum())
    rep.update({"volume": shp.volume, "shape_packing_fraction": vol_el / shp.volume,
                "packing": {"deposit_steps": dep["steps"], "compact_steps": com["steps"],
                            "stiffen_steps": stf["steps"], "stiffen_factor": factor,
                            "relax_steps": rel["steps"],
                            "relax_platen_lifts": rel["platen_lifts"],
                            "relax_max_overlap_over_xb": rel["max_overlap"] / xb_min,
                            "compaction_pressure": com["pressure"],
                            "n_deposited": int(s.size)}})
    return sp, rep


def well_bonded(state: State, keep=None, min_bonds: int = 2) -> np.ndarray:
    """The elements of ``keep`` (bool (N,), default every element) left when those with fewer
    than ``min_bonds`` intact bonds to other kept elements are dropped, repeatedly (a drop can
    leave a neighbour short): a bool (N,) mask. Cutting a bonded packing leaves a few loose or
    dangling elements at the cut."""
    keep = np.ones(state.n, bool) if keep is None else np.array(keep, bool)
    bonded = (state.cstate == BONDED) & (state.nbr >= 0)
    while keep.any():
        count = (bonded & keep[np.maximum(state.nbr, 0)]).sum(axis=1)
        short = keep & (count < min_bonds)
        if not short.any():
            break
        keep &= ~short
    return keep


def settle(state: State, n_across: float | None = None, tol: float = 1e-3,
           rounds: int = 10) -> State:
    """Standard balances (:meth:`Simulation.balance`) until the unbalanced-force ratio is below
    ``tol``, ``rounds`` at most: a bonded model after a cut. ``n_across`` defaults to the largest
    extent over the mean diameter. Returns the synced state."""
    from geodem.core.engine import Simulation

    if n_across is None:
        ext = state.x.max(axis=0) - state.x.min(axis=0)
        n_across = max(float(ext.max()) / (2.0 * float(state.r.mean())), 1.0)
    sim = Simulation(state, monitor_every=0)
    for _ in range(rounds):
        if sim.balance(n_across) < tol:
            break
    return sim.sync()
