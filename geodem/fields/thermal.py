"""Thermal field: element temperatures, conduction over bonds and contacts, thermal expansion.

PHYSICS.md section 5. Every element ``i`` carries a temperature ``T_i`` [K] and a heat capacity
``C_i = m_i c`` [J/K] (``c`` specific heat [J/(kg K)], ``m_i`` the element mass). Heat flows over
the contacts the solid already stores (the rows ``nbr``/``cstate``, each contact in both rows, so
every element sums its own row: no atomics, no scatter)::

    C_i dT_i/dt = sum_j h_ij (T_j - T_i)                                    (1)

Conductance of a contact [W/K] (a bar of the material of cross-section ``A_ij`` between the two
centres, distance ``L_ij = |x_j - x_i|``)::

    h_ij = f_ij * k * A_ij / L_ij                                            (2)
    A_ij = (2/sqrt 3) r_ij * t_ij     (2-D: contact width x disc thickness)
    A_ij = sqrt(2) r_ij^2  (= pi r_c^2, r_c = (sqrt 2 / pi)^(1/2) r_ij)      (3-D)
    r_ij = 2 R_i R_j / (R_i + R_j)    (harmonic mean of the built radii R_i0)
    t_ij = state.thickness, or 2 r_ij when the model gives none (the 2-D mass convention t = d)

``f_ij`` = ``area_factor`` for an intact bond, ``unbonded_factor x area_factor`` for an unbonded
contact whose elements touch (``L_ij < R_i + R_j``, current radii), 0 otherwise (open cracks and
near neighbours do not conduct).

Calibration. ``A_ij`` is the face shared by two neighbouring cells of the close-packed lattice of
spacing ``d = 2r``: the hexagon side ``d/sqrt 3`` times ``t`` (2-D triangular lattice) and the
rhombic-dodecahedron face ``d^2/(2 sqrt 2)`` (3-D FCC). For cells of volume ``V`` whose faces
bisect the bonds, the flux of a linear field ``T = g.x`` is ``q = -(1/(2V)) sum_j h_ij (l_ij.g)
l_ij`` (``l_ij = x_j - x_i``), and the divergence theorem gives ``sum_j A_ij (L_ij/2) n n = V I``:
with (2) the lattice's conductivity tensor is exactly ``k I`` (tests/unit/test_thermal.py checks
it to 1e-12 for both lattices; a bar of equal elements, ``A = A_ij``, conducts ``k A/d``; the rod
workflow checks the transient against the Fourier series). Random packings have fewer bonds per
element than the lattice (2-D sandstone: ~3.8 against 6) and conduct less:
:func:`effective_conductivity` measures a model's value (a steady-state solve), and
``area_factor = k / k_eff`` compensates.

Heat capacity is ``m c``, so the model's diffusivity is ``k / (rho_b c)`` with ``rho_b`` the bulk
density the element masses give (mass / volume of the model).

Time stepping: explicit (forward Euler) sub-steps ``s`` of (1). With
``s <= min_i C_i / sum_j h_ij`` (:meth:`ThermalField.stable_dt`; fixed-temperature elements
excluded) every update is a convex combination of old temperatures: stable and free of new
extrema (maximum principle; Gershgorin bounds the largest eigenvalue of ``C^-1 H`` by
``2 max sum h / C``, and Euler needs ``s lambda <= 2``). The field uses ``safety`` (0.5) x that
bound.

Per coupling (every ``every`` mechanical steps, ``span = every dt`` of mechanical time; the
thermal clock advances ``time_scale x span``: ``time_scale`` > 1 accelerates heat flow against
the mechanics, valid while the mechanics stays quasi-static):

1. deposit mechanical heat (optional, ``deposit``: any of ``viscous``, ``break_normal``,
   ``break_shear``, ``friction``): ``dT_i = dQ_i / C_i`` with ``dQ_i`` the increase of the chosen
   accumulators (``q_visc``, ``q_break_n``, ``q_break_s``, ``q_fric``) since the last coupling
   (after ``Simulation.reset_energy`` zeroed them: the heat since the reset);
2. conductances (2) from the current geometry, then ``n`` Euler sub-steps of (1) in one
   compiled call; fixed-temperature elements (Dirichlet groups) keep their values (or follow a
   linear ramp from the temperature they had when fixed to their value over ``ramp`` seconds of
   thermal time: sudden heating shocks the solid); elements with
   no conducting contact are insulated (the default boundary: no flux leaves the model);
3. thermal expansion ``R_i = R_i0 (1 + alpha (T_i - T_ref))`` written to the ``r`` column of
   ``props``. The springs' elastic energy changes with the radii at fixed positions; the change
   ``E_el(R_new) - E_el(R_old)`` of each element's share is booked as external work ``w_ext``, so
   ``E_k + E_el + Q = E_0 + W`` still closes; the contact forces are then evaluated again at
   the same positions (``dt = 0``: velocities, springs and heat unchanged; a bond the expansion
   overstrains breaks now), so the next velocity-Verlet step starts from the new forces.

References: Incropera & DeWitt, *Fundamentals of Heat and Mass Transfer* (finite-volume
conduction, the explicit stability criterion); Carslaw & Jaeger, *Conduction of Heat in Solids*
(Fourier series); Liu et al. 2021 (MatDEM multi-field coupling).
"""
from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from geodem.fields import CoupledField, FieldStabilityError, check_substep, register_field

DEPOSIT = {"viscous": "q_visc", "break_normal": "q_break_n", "break_shear": "q_break_s",
           "friction": "q_fric"}
FACE_2D = 2.0 / math.sqrt(3.0)  # hexagon side / r: d / sqrt 3 = (2 / sqrt 3) r
FACE_3D = math.sqrt(2.0)  # rhombic dodecahedron face / r^2: d^2 / (2 sqrt 2) = sqrt 2 r^2


# ============================================================================ kernels
# compiled on first use, cached on disk (__pycache__) for the next processes
_jit = numba.njit(parallel=True, fastmath=False, cache=True)
_seq = numba.njit(fastmath=False, cache=True)


@_jit
def conductances(x, r, r0, nbr, cstate, dim, thick, kfac, unb, hmat, hsum):
    # (2): h_ij of every row entry [W/K] and its row sums
    n, w = nbr.shape
    for i in prange(n):
        hs = 0.0
        for k in range(w):
            j = nbr[i, k]
            if j < 0:
                for kk in range(k, w):
                    hmat[i, kk] = 0.0
                break
            d2 = 0.0
            for a in range(dim):
                e = x[j, a] - x[i, a]
                d2 += e * e
            dist = math.sqrt(d2)
            h = 0.0
            if cstate[i, k] == 1:
                f = 1.0
            elif unb > 0.0 and dist < r[i] + r[j]:
                f = unb
            else:
                f = 0.0
            if f > 0.0 and dist > 0.0:
                rij = 2.0 * r0[i] * r0[j] / (r0[i] + r0[j])
                if dim == 2:
                    t = thick if thick > 0.0 else 2.0 * rij
                    area = FACE_2D * rij * t
                else:
                    area = FACE_3D * rij * rij
                h = f * kfac * area / dist
            hmat[i, k] = h
            hs += h
        hsum[i] = hs

@_seq
def stable(cap, hsum, fixed):
    # min C_i / sum_j h_ij over the free elements that conduct (inf if none)
    best = np.inf
    for i in range(cap.shape[0]):
        if fixed[i] == 0 and hsum[i] > 0.0:
            best = min(best, cap[i] / hsum[i])
    return best

@_seq
def hold(tt, t0, ramp, T, fixed, fstart, ftarget):
    # fixed temperatures at thermal time tt: linear ramp from fstart to ftarget
    frac = 1.0
    if ramp > 0.0:
        frac = min(1.0, max(0.0, (tt - t0) / ramp))
    for i in range(T.shape[0]):
        if fixed[i] != 0:
            T[i] = fstart[i] + (ftarget[i] - fstart[i]) * frac

@_jit
def diffuse(nsub, h, T, cap, fixed, nbr, hmat, flux, tb, t0, ramp, fstart, ftarget):
    # nsub forward-Euler sub-steps of (1) from thermal time tb
    n, w = nbr.shape
    for s in range(nsub):
        if ramp > 0.0:
            hold(tb + s * h, t0, ramp, T, fixed, fstart, ftarget)
        for i in prange(n):
            acc = 0.0
            if fixed[i] == 0:
                ti = T[i]
                for k in range(w):
                    j = nbr[i, k]
                    if j < 0:
                        break
                    acc += hmat[i, k] * (T[j] - ti)
            flux[i] = acc
        for i in prange(n):
            if fixed[i] == 0:
                T[i] += h * flux[i] / cap[i]
    hold(tb + nsub * h, t0, ramp, T, fixed, fstart, ftarget)

@_jit
def expand(T, r0, alpha, tref, props):
    for i in prange(T.shape[0]):
        props[i, 0] = r0[i] * (1.0 + alpha * (T[i] - tref))

@_jit
def deposit(qsum, qlast, reset, T, cap, fixed):
    for i in prange(T.shape[0]):
        dq = qsum[i] if reset else qsum[i] - qlast[i]
        if fixed[i] == 0:
            T[i] += dq / cap[i]
        qlast[i] = qsum[i]

_K = (conductances, stable, diffuse, expand, deposit, hold)


def kernels():
    """The kernels ``(conductances, stable, diffuse, expand, deposit, hold)``."""
    return _K


# ============================================================================ the field
def _finite(v, name, *, lo=None, strict=False, unit=""):
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"thermal field: {name} must be a number, got {v!r}") from None
    bad = not math.isfinite(f) or (lo is not None and (f <= lo if strict else f < lo))
    if bad:
        rng = "finite" if lo is None else f"finite and {'>' if strict else '>='} {lo:g}"
        raise ValueError(f"thermal field: {name} = {v!r}{' ' + unit if unit else ''}; "
                         f"allowed: {rng}")
    return f


def _temps(d, name):
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ValueError(f"thermal field: {name} must map group names to temperatures [K]")
    return {str(g): _finite(t, f"{name}[{g!r}]", lo=0.0, strict=True, unit="K")
            for g, t in d.items()}


@register_field("thermal")
class ThermalField(CoupledField):
    """Element temperatures with conduction (1)-(2), Dirichlet groups, expansion and heat
    deposition (see the module docstring for the equations).

    Parameters (SI units)
    ---------------------
    k: conductivity [W/(m K)], >= 0.  c: specific heat [J/(kg K)], > 0.
    alpha: linear thermal expansion coefficient [1/K] (0: no expansion).
    T_ref: temperature at which the radii are the built radii [K], > 0.
    T0: initial temperature of every element [K] (default ``T_ref``).
    initial: ``{group: T}`` initial temperatures of groups [K] (after ``T0``).
    fixed: ``{group: T}`` fixed-temperature (Dirichlet) groups [K].
    ramp: thermal time [s] over which a fixed group goes linearly from the temperature it had
        when it was fixed to its value (0: at once).
    unbonded_factor: conductance of a touching unbonded contact / that of a bond, >= 0.
    area_factor: multiplies every conductance (calibration of random packings), > 0.
    deposit: mechanical heat deposited into T: subset of ``viscous, break_normal,
        break_shear, friction`` (a single name may be given as a string).
    time_scale: thermal seconds per mechanical second, > 0.
    every: couple every ``every`` mechanical steps.
    """

    reads = {"x": "m", "nbr": "1", "cstate": "1", "m": "kg", "props": "m (column r: radius)",
             "q_visc": "J", "q_break_n": "J", "q_break_s": "J", "q_fric": "J", "w_ext": "J"}
    writes = {"props": "m (column r: radius)", "w_ext": "J",
              "dx": "m (zeroed when the forces are re-evaluated after an expansion)"}
    safety = 0.5

    def __init__(self, k, c, alpha=0.0, T_ref=293.15, T0=None, initial=None, fixed=None,
                 unbonded_factor=0.0, area_factor=1.0, deposit=(), time_scale=1.0, ramp=0.0,
                 every=1):
        super().__init__(every)
        self.k = _finite(k, "conductivity k", lo=0.0, unit="W/(m K)")
        self.c = _finite(c, "specific heat c", lo=0.0, strict=True, unit="J/(kg K)")
        self.alpha = _finite(alpha, "expansion coefficient alpha", unit="1/K")
        if abs(self.alpha) >= 1e-2:
            raise ValueError(f"thermal field: expansion coefficient alpha = {alpha!r} 1/K; "
                             "allowed: |alpha| < 0.01 (rocks: about 5e-6 to 1.5e-5)")
        self.T_ref = _finite(T_ref, "reference temperature T_ref", lo=0.0, strict=True, unit="K")
        self.T0 = self.T_ref if T0 is None else _finite(T0, "initial temperature T0", lo=0.0,
                                                        strict=True, unit="K")
        self.initial = _temps(initial, "initial")
        self.fixed = _temps(fixed, "fixed")
        self.unbonded_factor = _finite(unbonded_factor, "unbonded_factor", lo=0.0)
        self.area_factor = _finite(area_factor, "area_factor", lo=0.0, strict=True)
        if isinstance(deposit, str):  # one name, not its letters
            deposit = (deposit,)
        bad = [d for d in deposit if d not in DEPOSIT]
        if bad:
            raise ValueError(f"thermal field: deposit {bad!r} unknown; allowed: "
                             f"{', '.join(DEPOSIT)}")
        self.deposit = tuple(dict.fromkeys(deposit))
        self.time_scale = _finite(time_scale, "time_scale", lo=0.0, strict=True)
        self.ramp = _finite(ramp, "ramp", lo=0.0, unit="s")
        self.ramp_t0 = 0.0
        self.time = 0.0  # thermal clock [s]
        self.sim = None

    # ------------------------------------------------------------------ contract
    def config(self) -> dict:
        return {"k": self.k, "c": self.c, "alpha": self.alpha, "T_ref": self.T_ref, "T0": self.T0,
                "initial": dict(self.initial), "fixed": dict(self.fixed),
                "unbonded_factor": self.unbonded_factor, "area_factor": self.area_factor,
                "deposit": list(self.deposit), "time_scale": self.time_scale,
                "ramp": self.ramp, "every": self.every}

    def attach(self, sim) -> None:
        """Size the arrays for ``sim.state``: ``T`` (``T0``, then ``initial`` groups, then the
        ``fixed`` values), the built radii ``r0``, capacities ``C = m c`` and the buffers."""
        from geodem.core import groups

        st = sim.state
        for g in list(self.initial) + list(self.fixed):
            if g not in st.groups:
                raise ValueError(f"thermal field: unknown group {g!r}; the model's groups: "
                                 f"{', '.join(st.groups)}")
        n = st.n
        self.sim = sim
        self.T = np.full(n, self.T0)
        for g, t in self.initial.items():
            self.T[groups.members(st, g)] = t
        self.fixed_mask = np.zeros(n, np.int8)
        self.fstart = np.zeros(n)
        self.ftarget = np.zeros(n)
        self._apply_fixed(st)
        self.r0 = st.r.copy()
        self.cap = np.ascontiguousarray(st.m * self.c)
        self.flux = np.zeros(n)
        self.hsum = np.zeros(n)
        self.hmat = np.zeros(st.nbr.shape)
        self.qlast = self._heat_sum(st) if self.deposit else np.zeros(n)
        self._qbuf = np.zeros(n)
        self._e0 = float(st.e0)
        self._ebuf = np.zeros(n)
        self._expanded = False

    def _apply_fixed(self, st):
        from geodem.core import groups

        self.fixed_mask[:] = 0
        self.ramp_t0 = self.time
        for g, t in self.fixed.items():
            idx = groups.members(st, g)
            self.fixed_mask[idx] = 1
            self.fstart[idx] = self.T[idx]
            self.ftarget[idx] = t
        kernels()[5](self.time, self.ramp_t0, self.ramp, self.T, self.fixed_mask, self.fstart,
                     self.ftarget)

    def set_fixed(self, fixed: dict, ramp: float | None = None) -> None:
        """Replace the fixed-temperature groups (``{group: T}``; the others become free); with
        ``ramp`` > 0 [s] each goes linearly from its present temperature to its value."""
        self.fixed = _temps(fixed, "fixed")
        if ramp is not None:
            self.ramp = _finite(ramp, "ramp", lo=0.0, unit="s")
        st = self.sim.state
        for g in self.fixed:
            if g not in st.groups:
                raise ValueError(f"thermal field: unknown group {g!r}; the model's groups: "
                                 f"{', '.join(st.groups)}")
        self._apply_fixed(st)

    def arrays(self) -> dict:
        return {"T": self.T, "r0": self.r0, "qlast": self.qlast, "fstart": self.fstart,
                "ftarget": self.ftarget,
                "clock": np.array([self.time, self._e0, float(self._expanded), self.ramp_t0])}

    def restore(self, arrays: dict) -> None:
        self.T[:] = arrays["T"]
        self.r0[:] = arrays["r0"]
        self.qlast[:] = arrays["qlast"]
        self.fstart[:] = arrays["fstart"]
        self.ftarget[:] = arrays["ftarget"]
        self.time, self._e0, exp, self.ramp_t0 = (float(v) for v in arrays["clock"])
        self._expanded = bool(exp)

    def _conductances(self, sim):
        st = sim.state
        if self.hmat.shape != st.nbr.shape:  # rows widened by a neighbour rebuild
            self.hmat = np.zeros(st.nbr.shape)
        cond = kernels()[0]
        cond(st.x, st.props[:, 0], self.r0, st.nbr, st.cstate, st.dim, float(st.thickness),
             self.k * self.area_factor, self.unbonded_factor, self.hmat, self.hsum)

    def stable_dt(self, sim) -> float:
        """``min_i C_i / sum_j h_ij`` over the free-temperature elements that conduct [s]
        (infinite when nothing conducts); also refreshes the conductances."""
        self._conductances(sim)
        return float(kernels()[1](self.cap, self.hsum, self.fixed_mask))

    def substep(self, sim, h: float, allow_unstable: bool = False) -> None:
        """One Euler step of (1) over ``h`` seconds of thermal time (conductances from the
        current geometry). ``h`` above :meth:`stable_dt` is refused (FieldStabilityError) unless
        ``allow_unstable`` (studies of where the scheme fails; :meth:`advance` sub-steps at
        ``safety`` x the limit and does not come here)."""
        if not allow_unstable:
            check_substep(self, sim, h)  # also refreshes the conductances
        else:
            self._conductances(sim)
        kernels()[2](1, float(h), self.T, self.cap, self.fixed_mask, sim.state.nbr, self.hmat,
                     self.flux, self.time, self.ramp_t0, self.ramp, self.fstart, self.ftarget)
        self.time += float(h)

    # ------------------------------------------------------------------ coupling
    def _heat_sum(self, st, out=None):
        out = np.zeros(st.n) if out is None else out
        out[:] = 0.0
        for name in self.deposit:
            out += getattr(st, DEPOSIT[name])
        return out

    def advance(self, sim, span: float) -> int:
        """One coupling over ``span`` seconds of mechanical time (module docstring, 1-3);
        returns the number of sub-steps."""
        st = sim.state
        if self.deposit:
            q = self._heat_sum(st, self._qbuf)
            # Simulation.reset_energy zeroed the books: E_0 changed, or the heat went down
            last = float(self.qlast.sum())
            reset = float(st.e0) != self._e0 or float(q.sum()) < last - 1e-9 * abs(last)
            kernels()[4](q, self.qlast, reset, self.T, self.cap, self.fixed_mask)
            self._e0 = float(st.e0)
        tspan = span * self.time_scale
        lim = self.stable_dt(sim)
        if not (lim > 0.0):
            raise FieldStabilityError(
                f"coupled field 'thermal': stable step is {lim!r} s at step {st.step}; check "
                f"the conductivity and the element masses")
        n = max(1, math.ceil(tspan / (self.safety * lim) - 1e-9))
        if n > self.max_substeps:
            raise FieldStabilityError(
                f"coupled field 'thermal' needs {n} sub-steps per coupling (stable step "
                f"{lim:.3g} s against {tspan:.3g} s of thermal time = time_scale "
                f"{self.time_scale:.3g} x {span:.3g} s): lower time_scale or couple more "
                f"often (every = {self.every})")
        kernels()[2](n, tspan / n, self.T, self.cap, self.fixed_mask, st.nbr, self.hmat,
                     self.flux, self.time, self.ramp_t0, self.ramp, self.fstart, self.ftarget)
        self.time += tspan
        self.substeps += n
        if self.alpha != 0.0 or self._expanded:
            self._expand(sim)
        return n

    def _expand(self, sim) -> float:
        """Radii from the temperatures; the elastic energy they add is booked as work [J]."""
        st, b = sim.state, sim.backend
        np.copyto(self._ebuf, b.elastic_energy())
        kernels()[3](self.T, self.r0, self.alpha, self.T_ref, st.props)
        b.push(("props",))
        e1 = b.elastic_energy()
        np.subtract(e1, self._ebuf, out=self._ebuf)
        st.w_ext += self._ebuf
        self._expanded = self.alpha != 0.0
        # the stored accelerations belong to the old radii: evaluate the forces again at the
        # same positions (dx = 0 and dt = 0: no velocity, spring or heat changes), so the next
        # velocity-Verlet step starts from F(x, R_new) (without it the books drift by ~1e-2)
        sim.refresh_forces(push=("w_ext",))  # the booked work too: a device must see it first
        return float(self._ebuf.sum())

    # ------------------------------------------------------------------ results
    def heat_content(self) -> float:
        """``sum_i C_i T_i`` [J] (relative to 0 K)."""
        return float(np.dot(self.cap, self.T))

    def summary(self) -> dict:
        free = self.fixed_mask == 0
        return {"T_min": float(self.T.min()), "T_max": float(self.T.max()),
                "T_mean": float(self.T.mean()),
                "T_mean_free": float(self.T[free].mean()) if free.any() else None,
                "thermal_time": self.time, "thermal_substeps": int(self.substeps),
                "heat_content_J": float(np.dot(self.cap, self.T - self.T_ref))}


# ============================================================================ helpers
def contact_area(r_i, r_j, dim: int, thickness: float = 0.0):
    """``A_ij`` of (2) [m^2] for radii ``r_i, r_j`` [m] (arrays allowed)."""
    r_i, r_j = np.asarray(r_i, float), np.asarray(r_j, float)
    rij = 2.0 * r_i * r_j / (r_i + r_j)
    if dim == 2:
        t = thickness if thickness > 0 else 2.0 * rij
        return FACE_2D * rij * t
    return FACE_3D * rij * rij


def conductance_pairs(sim, field):
    """``(i, j, h_ij)`` of every conducting pair once (``i < j``) at the current geometry."""
    field._conductances(sim)
    st = sim.state
    i, k = np.nonzero((st.nbr >= 0) & (field.hmat > 0.0))
    j = st.nbr[i, k]
    once = i < j
    return i[once], j[once], field.hmat[i, k][once]


def effective_conductivity(sim, field, axis: int = 0, layer: float | None = None,
                           thickness: float | None = None) -> dict:
    """Measured conductivity of a box-shaped model along ``axis`` [W/(m K)].

    Steady state of (1) with ``T = 1`` on the elements within ``layer`` (default one mean
    diameter) of the low face and ``T = 0`` within ``layer`` of the high face (the rest
    insulated), solved directly (sparse LU). The heat flow ``P`` [W] leaving the hot layer gives
    ``k_eff = P L / (A dT)``: ``L`` the distance between the mean coordinates of the two layers,
    ``A`` the cross-section (extent of the centres plus one mean diameter across the other
    axes, times the thickness in 2-D: ``state.thickness`` or the mean diameter). Returns
    ``{"k_eff", "ratio" (k_eff / (k area_factor)), "L", "A", "P"}``."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    st = sim.state
    i, j, h = conductance_pairs(sim, field)
    n = st.n
    d = 2.0 * float(st.r.mean())
    layer = d if layer is None else float(layer)
    xa = st.x[:, axis]
    hot = xa <= xa.min() + layer
    cold = xa >= xa.max() - layer
    known = hot | cold
    tk = np.where(hot, 1.0, 0.0)
    lap = sp.coo_matrix((np.concatenate([-h, -h]), (np.concatenate([i, j]),
                                                    np.concatenate([j, i]))), shape=(n, n))
    lap = (lap + sp.diags(np.bincount(i, h, n) + np.bincount(j, h, n))).tocsr()
    # clusters that touch neither layer (cut off by cracks, loose elements) carry no flux and
    # would make the system singular: solve only for the elements connected to a layer
    from scipy.sparse.csgraph import connected_components

    _, comp = connected_components(lap, directed=False)
    linked = np.isin(comp, np.unique(comp[known]))
    un = np.flatnonzero(~known & linked)
    T = tk.copy()
    if un.size:
        rhs = -lap[un][:, np.flatnonzero(known)] @ tk[known]
        T[un] = spsolve(lap[un][:, un].tocsc(), rhs)
    P = float((lap @ T)[hot].sum())
    L = float(xa[cold].mean() - xa[hot].mean())
    other = [a for a in range(st.dim) if a != axis]
    A = 1.0
    for a in other:
        A *= float(np.ptp(st.x[:, a])) + d
    if st.dim == 2:
        A *= thickness if thickness is not None else (st.thickness if st.thickness > 0 else d)
    k_eff = P * L / A
    return {"k_eff": k_eff, "ratio": k_eff / (field.k * field.area_factor), "L": L, "A": A,
            "P": P}


def rod_solution(x, t, L, D, T0, T1, T2, terms: int = 400):
    """Temperature [K] of a rod ``0 <= x <= L`` [m] at time ``t`` [s], initially at ``T0``, ends
    held at ``T1`` (x = 0) and ``T2`` (x = L) from ``t = 0``, diffusivity ``D`` [m^2/s]::

        T = T1 + (T2 - T1) x/L + sum_n B_n sin(n pi x / L) exp(-D (n pi / L)^2 t)
        B_n = (2 / (n pi)) [(T0 - T1)(1 - (-1)^n) + (T2 - T1)(-1)^n]

    (Carslaw & Jaeger, section 3.3). ``terms`` terms of the series."""
    x = np.asarray(x, float)
    nn = np.arange(1, terms + 1)[:, None]
    sgn = np.where(nn % 2 == 0, 1.0, -1.0)
    B = 2.0 / (nn * math.pi) * ((T0 - T1) * (1.0 - sgn) + (T2 - T1) * sgn)
    s = (B * np.sin(nn * math.pi * x[None, :] / L)
         * np.exp(-D * (nn * math.pi / L) ** 2 * t)).sum(axis=0)
    return T1 + (T2 - T1) * x / L + s
