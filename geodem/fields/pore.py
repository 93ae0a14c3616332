"""Pore-density fluid flow coupled to the bonded solid (MatDEM pore density flow; Liu et al. 2020).

The field ``"pore_fluid"`` (:class:`PoreField`) keeps a fluid mass in every pore of the packing
and exchanges it through the throats between pores; there is no global pressure solve
(PHYSICS.md section 6). Units SI.

Pore network
    Pores are the cells of a triangulation of the element centres (``scipy.spatial.Delaunay``):
    triangles in 2-D, tetrahedra in 3-D, built over the elements of ``group``. A cell is dropped
    (it is outside the packing: a sliver of the convex hull) when one of its edges is longer than
    ``edge_factor`` x the contact distance ``r_i + r_j`` of its two elements, unless it lies in a
    *cavity* (a boundary condition with ``cavity: true``, e.g. the borehole of a hydraulic
    fracturing model, whose cells are pores whatever their shape). Two pores sharing a face
    (2-D: an edge = one element pair; 3-D: a triangle = three pairs) are joined by a throat.

Pore volume [m^3]
    2-D (thickness ``t`` = ``thickness``, else ``state.thickness``, else the mean element
    diameter; the 2-D area convention of geodem)::

        V = t * ( max(A - sum_i theta_i r_i^2 / 2, floor * A) + aperture * sum_i theta_i r_i )

    ``A`` triangle area, ``theta_i`` its angle at element ``i``: the solid inside the cell is
    the three disc sectors; the *aperture allowance* is a film of thickness ``aperture`` on the
    solid surface inside the cell. 3-D::

        V = max(V_tet - sum_i Omega_i r_i^3 / 3, floor * V_tet) + aperture * sum_i Omega_i r_i^2

    ``Omega_i`` the solid angle of the tetrahedron at element ``i`` (Van Oosterom & Strackee
    1983). Both solid and film terms are sums over the angles at each element, so a flip of the
    triangulation inside a region keeps the region's total pore volume (the remap below relies
    on it). Overlap lenses of compressed pairs are not added back (< 1 % of the pore for
    overlaps below 1 % of the radius); ``floor`` (default 0.01) keeps a crushed cell's volume
    positive.

Equation of state
    ``rho = M / V``;  ``rho = k_f P + c_f``, so ``P = (M / V - c_f) / k_f`` [Pa], floored at
    ``p_min`` (default 0: a pore whose fluid no longer fills it - a freshly opened crack -
    holds ``p_min``, it does not pull the solid together; ``p_min: null`` disables the floor).
    ``k_f`` [kg m^-3 Pa^-1 = s^2/m^2] and ``c_f`` [kg/m^3]. Defaults: water,
    ``k_f = 1000 / 2.2e9 = 4.545e-7`` (bulk modulus ``K = c_f / k_f = 2.2 GPa``), ``c_f = 1000``.
    MatDEM's oil example: ``k_f = 4.615e-5``, ``c_f = 870`` (``K = 18.9 MPa``: a hundred times
    more compressible than water, which makes its pore pressures far less sensitive to volume
    changes).

Throat flow
    ``dM_a/dt = - sum_b C_ab (P_a - P_b)`` [kg/s] with the conductance [kg/(Pa s) = m s]::

        C_ab = k_t * max(g + aperture, 0) / L_path            (/ bond_factor if bonded)

    ``g = |x_j - x_i| - r_i - r_j`` the surface gap of the throat's element pair (3-D: the
    conductance is the mean over the face's three pairs, each with its own gap and bond),
    ``L_path`` the distance between the two pores' centroids (at least ``0.25 (r_i + r_j)``).
    An intact bond (``cstate == 1``) divides its pair's conductance by ``bond_factor`` (100):
    cracks become flow paths. Default ``k_t`` [kg/(Pa s)] is the cubic-law value at the
    aperture, ``k_t = c_f aperture^2 w / (12 viscosity)`` with ``w`` = ``t`` (2-D) or the mean
    element diameter (3-D), so an open pair of opening ``aperture`` conducts like a parallel-plate
    channel of that opening. Bonds are read from the contact rows at every coupling, so a bond
    that breaks opens its throat at once (no network update needed).

Forces on the solid
    The pressure of a pore acts on the elements bounding it. Element ``a`` of a cell owns the
    part of the cell boundary between the *contact points* ``q_ab`` of its two (2-D) edges,
    ``q_ab = x_a + (|x_b - x_a| + r_a - r_b) / 2 * e_ab`` (the middle of the gap, the contact
    point of touching discs). 2-D: ``F_a = P t R(q_ab - q_ca)``, ``R`` the rotation that gives the
    outward normal: a uniform pressure on the arc inside the cell gives ``P * chord * t`` normal
    to the chord (PHYSICS.md section 6). 3-D: each face (a, b, c) is split into three quads
    ``(x_a, q_ab, m, q_ca)`` (``m`` the mean of the face's three contact points) and
    ``F_a = P * sum of the vector areas of a's quads`` (outward). The parts close the cell, so
    the forces of one pore sum to zero exactly (no net force from the fluid, as it has no
    momentum), and equal pressures on all sides of an element cancel: the solid feels pressure
    *differences*. The forces are added to ``state.fload`` as a delta against this field's
    previous contribution (user loads are untouched) and booked by the kernels as external work
    ``w_ext``, so the energy books stay closed; ``state.a`` of free degrees of freedom is
    corrected by the same delta / m, as ``Simulation.change`` would (velocity Verlet starts the
    next step with the new load).

Boundary conditions (``bcs``, a list of mappings)
    ``{name, role: inject | drain, where, pressure [Pa] >= 0, rate [Pa/s] = 0, p_max [Pa],
    t_start [s] = 0, cavity = false}``: the pores selected by ``where`` are held at
    ``P_set(t) = min(pressure + rate * max(t - t_start, 0), p_max)``; the mass this takes is
    booked as injected (role inject) or drained (role drain: booked as the mass removed).
    ``where`` is one of ``{ball: [x, y(, z), R]}`` (cells whose centroid is within R),
    ``{box: [[lo...], [hi...]]}``, ``{group: NAME}`` (cells with an element of the group),
    ``{boundary: true}`` (the outer pores: cells with a face no other cell shares),
    ``{side: xmin|xmax|ymin|ymax|zmin|zmax}`` (cells whose centroid is within ``depth``
    (default half the mean element diameter) of the extreme pore centroid along that axis). A
    pore takes the first condition that selects it.

Explicit stability (``stable_dt``)
    With storage ``S_a = dM/dP = V_a k_f`` the explicit Euler update of pore ``a`` is
    ``P_a' = (1 - h sum_b C_ab / S_a) P_a + (h / S_a) sum_b C_ab P_b``: monotone (no overshoot,
    the discrete maximum principle) for ``h <= S_a / sum_b C_ab``. Gershgorin puts every
    eigenvalue of the update in ``[1 - 2 h max(sum C / S), 1]``, so it is also stable there, and
    not always further: two equal pores sharing one throat diverge just above ``S / C`` (the
    exact limit is ``2 / lambda_max`` of ``S^-1/2 L S^-1/2``, 1-1.4 x the bound; measured in
    docs/stability.md). So ``stable_dt = min over free pores of V_a k_f / sum_b C_ab``; the
    framework sub-steps at ``safety`` (0.5) of it, and :meth:`PoreField.substep` called directly
    refuses ``h > stable_dt``.

Network update (``remesh``), conserving fluid mass
    The triangulation is rebuilt when an element has moved more than ``remesh_disp`` x the mean
    diameter since the last build, when a cell has turned inside out (its signed volume below
    ``-INVERTED_REL d^dim``: a near-flat sliver flipped by less stays a pore of its absolute
    volume, closed by its faces as before), every ``remesh_every``
    couplings (0 = never), or on request. Cells whose vertex set survives keep their mass. The
    other old cells ("lost") and new cells are grouped into patches (a new cell is linked to the
    old cell containing its centroid, a lost cell to the new cell containing its centroid);
    each new cell gets the *density* of its parent, ``M* = V rho_parent``, and the patch's
    lost mass is shared among its new cells in proportion to ``M*`` (so the patch conserves
    mass exactly; a flip keeps the patch volume, so densities, hence pressures, barely change).
    A patch with no new cell hands its mass to the nearest surviving pore; a new cell in a
    region that held no pore shares the fluid of its nearest pore at equal density. Total
    mass is conserved to round-off. Contact-row rebuilds only re-map the rows' column of each
    throat pair (bonds are kept by the rows).

Mass books
    ``injected``, ``drained`` [kg]; ``fluid_mass_balance_rel_error = |M - M_0 - injected +
    drained| / max(M_0, |injected|)``.

References: Liu, C., Xu, Q., Shi, B., Gu, Y. (2017) Mechanical properties and energy conversion
of 3D close-packed lattice model for brittle rocks, Comput. Geosci. 103; Liu, C. et al. (2020)
MatDEM - fast matrix computing of the discrete element method (pore density flow: fluid mass
per pore, linear density-pressure relation); Van Oosterom, A., Strackee, J. (1983) The solid
angle of a plane triangle, IEEE Trans. Biomed. Eng. 30(2).
"""
from __future__ import annotations

import math
import numbers

import numpy as np
import numba
from numba import njit, prange

from geodem.fields import CoupledField, check_substep, register_field, whole_number

#: default fluid: water (K = 2.2 GPa, rho = 1000 kg/m^3 at P = 0)
WATER_KF = 1000.0 / 2.2e9
WATER_CF = 1000.0
#: MatDEM's oil example (Liu et al. 2020)
OIL_KF = 4.615e-5
OIL_CF = 870.0

ROLES = ("inject", "drain")
WHERE_KEYS = ("ball", "box", "group", "boundary", "side")
SIDES = ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")
L_PATH_MIN = 0.25  # x (r_i + r_j): shortest throat path
DEGENERATE_REL = 1e-9  # x d^dim: a cell of smaller area/volume is flat (refused as a pore)
#: x d^dim: a cell whose signed area/volume is below minus this is inside out (0.85 % of the
#: regular tetrahedron of edge d, 0.23 % of the equilateral triangle). A near-flat cell (a
#: sliver of a jittered lattice: 1e-6-1e-4 d^3) flips at the smallest motion; flipped by less
#: than this it stays a pore of its absolute volume, and its faces still close it, so equal
#: pressures still cancel on every element; counted as inside out, it rebuilt the network at
#: nearly every coupling (17 rebuilds in 20 couplings at 10^4 elements)
INVERTED_REL = 1e-3
# The pore kernels are compiled without fastmath: the threaded passes and the serial ones then
# give the same bits (fastmath lets the compiler reorder a sum differently in each)
#: a network of fewer cells runs its passes on one thread (measured on 2 cores: no gain at
#: 55,000 cells, 1.1-1.5 x at 580,000); the results are the same bits either way
PARALLEL_MIN = 65536


class PoreFluidError(ValueError):
    """Bad input of the pore-fluid field (the message names the field and the parameter)."""


def _err(msg: str) -> PoreFluidError:
    return PoreFluidError(f"coupled field 'pore_fluid': {msg}")


# ============================================================================ kernels
@njit(cache=True, inline="always")
def _geom2_cell(x, r, cells, t, ap, floor, V, cen, tol, c):
    """Volume ``V[c]`` [m^3] and vertex centroid ``cen[c]`` of 2-D cell ``c``; returns 1 when
    its area is below -tol (inside out), else 0."""
    bad = 0
    i0 = cells[c, 0]
    i1 = cells[c, 1]
    i2 = cells[c, 2]
    ax, ay = x[i0, 0], x[i0, 1]
    bx, by = x[i1, 0], x[i1, 1]
    cx, cy = x[i2, 0], x[i2, 1]
    area = 0.5 * ((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))
    if area < -tol:
        bad = 1
    # angles at the three vertices (the third from the angle sum pi)
    ux, uy, vx, vy = bx - ax, by - ay, cx - ax, cy - ay
    th0 = math.atan2(abs(ux * vy - uy * vx), ux * vx + uy * vy)
    ux, uy, vx, vy = cx - bx, cy - by, ax - bx, ay - by
    th1 = math.atan2(abs(ux * vy - uy * vx), ux * vx + uy * vy)
    th2 = math.pi - th0 - th1
    if th2 < 0.0:
        th2 = 0.0
    r0, r1, r2 = r[i0], r[i1], r[i2]
    solid = 0.5 * (th0 * r0 * r0 + th1 * r1 * r1 + th2 * r2 * r2)
    film = th0 * r0 + th1 * r1 + th2 * r2
    a = abs(area)
    free = a - solid
    if free < floor * a:
        free = floor * a
    V[c] = t * (free + ap * film)
    cen[c, 0] = (ax + bx + cx) / 3.0
    cen[c, 1] = (ay + by + cy) / 3.0
    return bad


@njit(cache=True)
def _geom2(x, r, cells, t, ap, floor, V, cen, tol):
    """2-D pore volumes ``V`` [m^3] and vertex centroids ``cen``; returns the number of cells
    with area < -tol (inside out)."""
    bad = 0
    for c in range(cells.shape[0]):
        bad += _geom2_cell(x, r, cells, t, ap, floor, V, cen, tol, c)
    return bad


@njit(cache=True, parallel=True)
def _geom2_par(x, r, cells, t, ap, floor, V, cen, tol):
    """:func:`_geom2` over the threads (each cell on its own: the same numbers)."""
    bad = 0
    for c in prange(cells.shape[0]):
        bad += _geom2_cell(x, r, cells, t, ap, floor, V, cen, tol, c)
    return bad


@njit(cache=True, inline="always")
def _solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Solid angle [sr] of the triangle (a, b, c) seen from the origin (Van Oosterom-Strackee)."""
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    trip = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb
           + (bx * cx + by * cy + bz * cz) * la)
    om = 2.0 * math.atan2(abs(trip), den)
    if om < 0.0:
        om += 2.0 * math.pi
    return om


@njit(cache=True, inline="always")
def _geom3_cell(x, r, cells, ap, floor, V, cen, tol, c):
    """Volume and centroid of tetrahedron ``c``; returns 1 when its volume is below -tol
    (inside out), else 0."""
    bad = 0
    i0 = cells[c, 0]
    i1 = cells[c, 1]
    i2 = cells[c, 2]
    i3 = cells[c, 3]
    e1x, e1y, e1z = x[i1, 0] - x[i0, 0], x[i1, 1] - x[i0, 1], x[i1, 2] - x[i0, 2]
    e2x, e2y, e2z = x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2]
    e3x, e3y, e3z = x[i3, 0] - x[i0, 0], x[i3, 1] - x[i0, 1], x[i3, 2] - x[i0, 2]
    vol6 = e1x * (e2y * e3z - e2z * e3y) - e1y * (e2x * e3z - e2z * e3x) + \
        e1z * (e2x * e3y - e2y * e3x)
    if vol6 < -6.0 * tol:
        bad = 1
    solid = 0.0
    film = 0.0
    for k in range(4):
        p = cells[c, k]
        q1 = cells[c, (k + 1) % 4]
        q2 = cells[c, (k + 2) % 4]
        q3 = cells[c, (k + 3) % 4]
        om = _solid_angle(x[q1, 0] - x[p, 0], x[q1, 1] - x[p, 1], x[q1, 2] - x[p, 2],
                          x[q2, 0] - x[p, 0], x[q2, 1] - x[p, 1], x[q2, 2] - x[p, 2],
                          x[q3, 0] - x[p, 0], x[q3, 1] - x[p, 1], x[q3, 2] - x[p, 2])
        rr = r[p]
        solid += om * rr * rr * rr / 3.0
        film += om * rr * rr
    vt = abs(vol6) / 6.0
    free = vt - solid
    if free < floor * vt:
        free = floor * vt
    V[c] = free + ap * film
    for d in range(3):
        cen[c, d] = 0.25 * (x[i0, d] + x[i1, d] + x[i2, d] + x[i3, d])
    return bad


@njit(cache=True)
def _geom3(x, r, cells, ap, floor, V, cen, tol):
    """3-D pore volumes and centroids; returns the number of tetrahedra with volume < -tol
    (inside out)."""
    bad = 0
    for c in range(cells.shape[0]):
        bad += _geom3_cell(x, r, cells, ap, floor, V, cen, tol, c)
    return bad


@njit(cache=True, parallel=True)
def _geom3_par(x, r, cells, ap, floor, V, cen, tol):
    """:func:`_geom3` over the threads (each cell on its own: the same numbers)."""
    bad = 0
    for c in prange(cells.shape[0]):
        bad += _geom3_cell(x, r, cells, ap, floor, V, cen, tol, c)
    return bad


@njit(cache=True, inline="always")
def _distance(p, a, b):
    """``|p[b] - p[a]|`` [m]."""
    l2 = 0.0
    for d in range(p.shape[1]):
        dd = p[b, d] - p[a, d]
        l2 += dd * dd
    return math.sqrt(l2)


@njit(cache=True, inline="always")
def _throat_conductance(x, r, g0, tp, te, slots, cstate, cen, kt, ap, bond_factor, t):
    """Conductance [kg/(Pa s)] of throat ``t``: the mean over its pairs (module docstring)."""
    ne = te.shape[1]
    lp = _distance(cen, tp[t, 0], tp[t, 1])
    acc = 0.0
    rsum = 0.0
    for e in range(ne):
        i = te[t, e, 0]
        j = te[t, e, 1]
        op = _distance(x, i, j) - r[i] - r[j] - g0[t, e] + ap
        if op < 0.0:
            op = 0.0
        s = slots[t, e]
        if s >= 0:
            if cstate[i, s] == 1:
                op /= bond_factor
        acc += op
        rsum += r[i] + r[j]
    rsum /= ne
    if lp < L_PATH_MIN * rsum:
        lp = L_PATH_MIN * rsum
    return kt * (acc / ne) / lp


@njit(cache=True)
def _conductance(x, r, g0, tp, te, slots, cstate, cen, kt, ap, bond_factor, C, csum):
    """Throat conductances ``C`` [kg/(Pa s)] (mean over the throat's pairs) and their sums per
    pore ``csum``; ``g0`` the reference gap of each pair (subtracted when positive)."""
    for a in range(csum.shape[0]):
        csum[a] = 0.0
    for t in range(tp.shape[0]):
        c = _throat_conductance(x, r, g0, tp, te, slots, cstate, cen, kt, ap, bond_factor, t)
        C[t] = c
        csum[tp[t, 0]] += c
        csum[tp[t, 1]] += c


@njit(cache=True, parallel=True)
def _conductance_par(x, r, g0, tp, te, slots, cstate, cen, kt, ap, bond_factor, C):
    """The conductances of :func:`_conductance` over the threads (their sums per pore:
    :func:`_pore_sums`)."""
    for t in prange(tp.shape[0]):
        C[t] = _throat_conductance(x, r, g0, tp, te, slots, cstate, cen, kt, ap, bond_factor, t)


@njit(cache=True, parallel=True)
def _pore_sums(v, ptr, items, out):
    """``out[a]`` = the sum of ``v[t]`` over the throats ``t`` of pore ``a`` in ascending ``t``
    (``items`` = 2 t + side: :func:`_owner_index` of the throats' pores), the order of the
    serial scatter: the same bits at any thread count."""
    for a in prange(out.shape[0]):
        acc = 0.0
        for k in range(ptr[a], ptr[a + 1]):
            acc += v[items[k] >> 1]
        out[a] = acc


@njit(cache=True)
def _substep(M, V, C, tp, held, pset, booked, kf, cf, pmin, use_pmin, h, P):
    """One explicit Euler step of length ``h`` [s]: pressures from the EOS, throat fluxes,
    held pores reset (the mass this takes is added to ``booked`` of their condition)."""
    for a in range(M.shape[0]):
        p = (M[a] / V[a] - cf) / kf
        if use_pmin and p < pmin:
            p = pmin
        P[a] = p
    for t in range(tp.shape[0]):
        a = tp[t, 0]
        b = tp[t, 1]
        q = h * C[t] * (P[a] - P[b])
        M[a] -= q
        M[b] += q
    for a in range(M.shape[0]):
        k = held[a]
        if k >= 0:
            target = V[a] * (kf * pset[k] + cf)
            booked[k] += target - M[a]
            M[a] = target


@njit(cache=True)
def _pressure(M, V, kf, cf, pmin, use_pmin, P):
    for a in range(M.shape[0]):
        p = (M[a] / V[a] - cf) / kf
        if use_pmin and p < pmin:
            p = pmin
        P[a] = p


@njit(cache=True)
def _hold(M, V, held, pset, booked, kf, cf):
    for a in range(M.shape[0]):
        k = held[a]
        if k >= 0:
            target = V[a] * (kf * pset[k] + cf)
            booked[k] += target - M[a]
            M[a] = target


@njit(cache=True, inline="always")
def _cscale(x, r, a, b):
    """Where the contact point of pair (a, b), the middle of their gap, lies along the branch
    from a to b (0 at a, 1 at b)."""
    L = _distance(x, a, b)
    return 0.5 * (L + r[a] - r[b]) / L if L > 0.0 else 0.5


@njit(cache=True, fastmath=True)
def _forces2(x, r, cells, P, t, F):
    """2-D pressure forces: ``F_a += P t R(q_ab - q_ca)`` for each cell (a, b, c) (ccw)."""
    for i in range(F.shape[0]):
        F[i, 0] = 0.0
        F[i, 1] = 0.0
    qx = np.empty(3)
    qy = np.empty(3)
    for c in range(cells.shape[0]):
        pt = P[c] * t
        if pt == 0.0:
            continue
        for k in range(3):  # q[k]: contact point of edge (k, k+1)
            a = cells[c, k]
            b = cells[c, (k + 1) % 3]
            ex = x[b, 0] - x[a, 0]
            ey = x[b, 1] - x[a, 1]
            L = math.sqrt(ex * ex + ey * ey)
            s = 0.5 * (L + r[a] - r[b]) / L if L > 0.0 else 0.5
            qx[k] = x[a, 0] + s * ex
            qy[k] = x[a, 1] + s * ey
        for k in range(3):
            a = cells[c, k]
            o = (k + 2) % 3  # edge (o, a) precedes a; edge (a, b) is k
            dx = qx[k] - qx[o]
            dy = qy[k] - qy[o]
            F[a, 0] += pt * dy  # outward normal of the chord (dy, -dx)
            F[a, 1] -= pt * dx


_FACES3 = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], np.int64)


@njit(cache=True, inline="always")
def _cpoint(x, r, a, b):
    """Contact point ``q_ab`` of pair (a, b): the middle of their gap on the branch [m]."""
    s = _cscale(x, r, a, b)
    return (x[a, 0] + s * (x[b, 0] - x[a, 0]), x[a, 1] + s * (x[b, 1] - x[a, 1]),
            x[a, 2] + s * (x[b, 2] - x[a, 2]))


@njit(cache=True, inline="always")
def _quad(p, x, v, m, w0, w1, w2):
    """``P/2 (m - x_v) x w``: the force of vertex v's quad (x_v, q_ab, m, q_ca), ``w = q_ca -
    q_ab`` [N]."""
    ux = m[0] - x[v, 0]
    uy = m[1] - x[v, 1]
    uz = m[2] - x[v, 2]
    return (0.5 * p * (uy * w2 - uz * w1), 0.5 * p * (uz * w0 - ux * w2),
            0.5 * p * (ux * w1 - uy * w0))


@njit(cache=True, inline="always")
def _face_forces(p, x, a, b, c, qab, qbc, qca):
    """Forces on a, b, c of the outward face (a, b, c) split into their three quads."""
    m = ((qab[0] + qbc[0] + qca[0]) / 3.0, (qab[1] + qbc[1] + qca[1]) / 3.0,
         (qab[2] + qbc[2] + qca[2]) / 3.0)
    fa = _quad(p, x, a, m, qca[0] - qab[0], qca[1] - qab[1], qca[2] - qab[2])
    fb = _quad(p, x, b, m, qab[0] - qbc[0], qab[1] - qbc[1], qab[2] - qbc[2])
    fc = _quad(p, x, c, m, qbc[0] - qca[0], qbc[1] - qca[1], qbc[2] - qca[2])
    return fa, fb, fc


@njit(cache=True)
def _cell_forces3(x, r, cells, P, c, out, o):
    """Forces [N] of tetrahedron ``c``'s pressure on its four vertices into ``out[o + k]``:
    each outward face (a, b, c) split into the quads ``(x_a, q_ab, m, q_ca)``, ``F = P *
    vector area``; a vertex's three quads summed in face order. The six contact points are
    computed once, so the two faces on an edge share its point exactly."""
    p = P[c]
    i0 = cells[c, 0]
    i1 = cells[c, 1]
    i2 = cells[c, 2]
    i3 = cells[c, 3]
    q01 = _cpoint(x, r, i0, i1)
    q02 = _cpoint(x, r, i0, i2)
    q03 = _cpoint(x, r, i0, i3)
    q12 = _cpoint(x, r, i1, i2)
    q13 = _cpoint(x, r, i1, i3)
    q23 = _cpoint(x, r, i2, i3)
    # the outward faces (1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1) of a right-handed cell
    f1a, f2a, f3a = _face_forces(p, x, i1, i2, i3, q12, q23, q13)
    f0b, f3b, f2b = _face_forces(p, x, i0, i3, i2, q03, q23, q02)
    f0c, f1c, f3c = _face_forces(p, x, i0, i1, i3, q01, q13, q03)
    f0d, f2d, f1d = _face_forces(p, x, i0, i2, i1, q02, q12, q01)
    for d in range(3):
        out[o, d] = f0b[d] + f0c[d] + f0d[d]
        out[o + 1, d] = f1a[d] + f1c[d] + f1d[d]
        out[o + 2, d] = f2a[d] + f2b[d] + f2d[d]
        out[o + 3, d] = f3a[d] + f3b[d] + f3c[d]


@njit(cache=True)
def _forces3(x, r, cells, P, F, buf):
    """3-D pressure forces (:func:`_cell_forces3`), each element's sum over its cells in
    ascending order (``buf``: (4, 3) scratch)."""
    for i in range(F.shape[0]):
        F[i, 0] = 0.0
        F[i, 1] = 0.0
        F[i, 2] = 0.0
    for c in range(cells.shape[0]):
        if P[c] == 0.0:
            continue
        _cell_forces3(x, r, cells, P, c, buf, 0)
        for k in range(4):
            a = cells[c, k]
            F[a, 0] += buf[k, 0]
            F[a, 1] += buf[k, 1]
            F[a, 2] += buf[k, 2]


@njit(cache=True, parallel=True)
def _forces3_par(x, r, cells, P, F, buf, ptr, items):
    """:func:`_forces3` over the threads: every cell's vertex forces on their own (``buf``
    (4 P, 3)), then every element's sum over its cells in ascending order (``ptr``, ``items``:
    :func:`_owner_index` of ``cells``), the serial order: the same bits at any thread count."""
    for c in prange(cells.shape[0]):
        if P[c] == 0.0:
            for k in range(4):
                buf[4 * c + k, 0] = 0.0
                buf[4 * c + k, 1] = 0.0
                buf[4 * c + k, 2] = 0.0
        else:
            _cell_forces3(x, r, cells, P, c, buf, 4 * c)
    for i in prange(F.shape[0]):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            o = items[k]
            f0 += buf[o, 0]
            f1 += buf[o, 1]
            f2 += buf[o, 2]
        F[i, 0] = f0
        F[i, 1] = f1
        F[i, 2] = f2


@njit(cache=True)
def _apply_delta(F, f_prev, fload, a, free, m):
    """``fload += F - f_prev``; free degrees of freedom's ``a`` by the same delta / m."""
    for i in range(F.shape[0]):
        for d in range(F.shape[1]):
            dl = F[i, d] - f_prev[i, d]
            fload[i, d] += dl
            a[i, d] += dl / m[i] if free[i, d] != 0.0 else 0.0


def _owner_index(owner, n):
    """CSR of the entries of ``owner`` (flat, values in [0, n)) by value, each value's entries in
    ascending position: ``(ptr (n + 1,), items)``."""
    owner = np.ascontiguousarray(owner, dtype=np.int64).ravel()
    items = np.argsort(owner, kind="stable").astype(np.int64)
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(owner, minlength=n), out=ptr[1:])
    return ptr, items


@njit(cache=True)
def _find_slots(nbr, te, slots):
    """Column of pair (i, j) in row i for each throat pair (-1: not in the rows)."""
    for t in range(te.shape[0]):
        for e in range(te.shape[1]):
            i = te[t, e, 0]
            j = te[t, e, 1]
            s = -1
            for k in range(nbr.shape[1]):
                v = nbr[i, k]
                if v < 0:
                    break
                if v == j:
                    s = k
                    break
            slots[t, e] = s


@njit(cache=True)
def _slots_valid(nbr, te, slots):
    for t in range(te.shape[0]):
        for e in range(te.shape[1]):
            s = slots[t, e]
            i = te[t, e, 0]
            j = te[t, e, 1]
            if s >= 0:
                if s >= nbr.shape[1] or nbr[i, s] != j:
                    return False
            else:
                for k in range(nbr.shape[1]):
                    v = nbr[i, k]
                    if v < 0:
                        break
                    if v == j:
                        return False
    return True


# ============================================================================ network
def _cell_edges(dim):
    if dim == 2:
        return np.array([[0, 1], [1, 2], [2, 0]])
    return np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


def _orient(x, cells):
    """Reorder cells so their signed area/volume is positive (ccw / right-handed)."""
    cells = np.array(cells, dtype=np.int64)
    p = x[cells]
    if cells.shape[1] == 3:
        s = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - \
            (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])
        neg = s < 0
        cells[neg, 1], cells[neg, 2] = cells[neg, 2].copy(), cells[neg, 1].copy()
    else:
        e = p[:, 1:] - p[:, :1]
        s = np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2]))
        neg = s < 0
        cells[neg, 2], cells[neg, 3] = cells[neg, 3].copy(), cells[neg, 2].copy()
    return cells


def _throats(cells, dim):
    """Throats (pairs of cells sharing a face) and boundary flags.

    Returns ``tp (T, 2)`` cell indices, ``te (T, ne, 2)`` element pairs of the shared face
    (ne = 1 in 2-D, 3 in 3-D) and ``boundary (P,)`` (cells with an unshared face)."""
    P = cells.shape[0]
    k = dim  # vertices per face
    faces_local = [np.delete(np.arange(dim + 1), f) for f in range(dim + 1)]
    fv = np.concatenate([cells[:, fl] for fl in faces_local], axis=0)  # (P*(dim+1), k)
    owner = np.tile(np.arange(P), dim + 1)
    fv = np.sort(fv, axis=1)
    if P == 0:
        return (np.zeros((0, 2), np.int64), np.zeros((0, 1 if dim == 2 else 3, 2), np.int64),
                np.zeros(0, bool))
    order = np.lexsort(fv.T[::-1])
    fs, os_ = fv[order], owner[order]
    same = np.all(fs[1:] == fs[:-1], axis=1)
    first = np.flatnonzero(same)
    tp = np.stack([os_[first], os_[first + 1]], axis=1).astype(np.int64)
    shared_face = fs[first]
    if k == 2:
        te = shared_face[:, None, :].astype(np.int64)
    else:
        te = np.stack([shared_face[:, [0, 1]], shared_face[:, [0, 2]], shared_face[:, [1, 2]]],
                      axis=1).astype(np.int64)
    count = np.zeros(P, np.int64)
    np.add.at(count, tp.ravel(), 1)
    boundary = count < dim + 1
    return tp, te, boundary


def _peel(neighbors, bad):
    """Cells outside the packing: the ``bad`` cells reachable from the convex hull through
    ``bad`` cells (``neighbors``: Delaunay neighbours, -1 = hull). Bad cells enclosed by good
    ones (voids of the packing, a borehole) stay."""
    out = np.zeros(bad.shape[0], bool)
    nb = np.asarray(neighbors)
    open_ = nb < 0
    front = bad & open_.any(axis=1)
    while front.any():
        out |= front
        touch = np.zeros(bad.shape[0], bool)
        nbf = nb[front]
        touch[nbf[nbf >= 0]] = True
        front = touch & bad & ~out
    return out


def _cell_measure(x, cells):
    """Signed area (2-D) or volume (3-D) of each cell [m^2 or m^3]."""
    p = x[cells]
    e = p[:, 1:] - p[:, :1]
    if cells.shape[1] == 3:
        return 0.5 * (e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])
    return np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0


def _edge_ratio_max(x, r, cells, dim):
    ed = _cell_edges(dim)
    a, b = cells[:, ed[:, 0]], cells[:, ed[:, 1]]
    L = np.linalg.norm(x[b] - x[a], axis=2)
    return (L / (r[a] + r[b])).max(axis=1)


def _nearest(pts, query, k):
    """Indices ``(n, k)`` of the ``k`` nearest of ``pts`` to each query point (k <= len(pts))."""
    from scipy.spatial import cKDTree

    k = max(1, min(int(k), len(pts)))
    if len(query) == 0:
        return np.zeros((0, k), np.int64)
    return np.asarray(cKDTree(pts).query(query, k=k)[1], np.int64).reshape(len(query), k)


def _point_in_cells(x, cells, pts, cand):
    """For each point, the first of its candidate cells ``cand (n, k)`` containing it (-1)."""
    n, kk = cand.shape
    out = np.full(n, -1, np.int64)
    if n == 0:
        return out
    dim = x.shape[1]
    for j in range(kk):
        c = cand[:, j]
        v = x[cells[c]]  # (n, dim+1, dim)
        T = np.transpose(v[:, 1:] - v[:, :1], (0, 2, 1))  # (n, dim, dim)
        rhs = pts - v[:, 0]
        with np.errstate(all="ignore"):
            try:
                lam = np.linalg.solve(T, rhs[..., None])[..., 0]
            except np.linalg.LinAlgError:
                lam = np.full((n, dim), np.nan)
                for i in range(n):
                    try:
                        lam[i] = np.linalg.solve(T[i], rhs[i])
                    except np.linalg.LinAlgError:
                        pass
        inside = np.all(lam >= -1e-9, axis=1) & (lam.sum(axis=1) <= 1.0 + 1e-9)
        hit = inside & (out < 0)
        out[hit] = c[hit]
    return out


# ============================================================================ the field
def _check_bc(k, bc):
    if not isinstance(bc, dict):
        raise _err(f"bcs[{k}] must be a mapping, got {bc!r}")
    allowed = {"name", "role", "where", "pressure", "rate", "p_max", "t_start", "cavity"}
    extra = set(bc) - allowed
    if extra:
        raise _err(f"bcs[{k}] has unknown keys {sorted(extra)}; allowed: {sorted(allowed)}")
    name = bc.get("name", f"bc{k}")
    role = bc.get("role", "inject")
    if role not in ROLES:
        raise _err(f"bcs[{k}] ({name}): role {role!r}; allowed: {', '.join(ROLES)}")
    where = bc.get("where")
    if not isinstance(where, dict) or len(where) != 1 or next(iter(where)) not in WHERE_KEYS:
        raise _err(f"bcs[{k}] ({name}): where must be one of {{ball: [centre..., R]}}, "
                   f"{{box: [lo, hi]}}, {{group: NAME}}, {{boundary: true}}, {{side: xmin..}}; "
                   f"got {where!r}")
    key, val = next(iter(where.items()))
    if key in ("ball", "box"):
        if key == "ball":
            nums = list(val) if isinstance(val, (list, tuple, np.ndarray)) else [val]
        else:
            ok = isinstance(val, (list, tuple, np.ndarray)) and len(val) == 2 and all(
                isinstance(v, (list, tuple, np.ndarray)) for v in val)
            nums = [u for v in val for u in v] if ok else [val]
        if not all(_real(u) and math.isfinite(u) for u in nums):
            raise _err(f"bcs[{k}] ({name}): {key} = {val!r}; allowed: finite numbers [m]")
        if key == "ball" and not nums[-1] > 0:
            raise _err(f"bcs[{k}] ({name}): ball radius = {nums[-1]!r}; allowed: > 0 [m]")
        if key == "box" and not all(lo <= hi for lo, hi in zip(val[0], val[1])):
            raise _err(f"bcs[{k}] ({name}): box = {val!r}; allowed: lo <= hi on every axis [m]")
    for key in ("pressure", "rate", "t_start"):
        v = bc.get(key, 0.0)
        if not (_real(v) and math.isfinite(v) and v >= 0):
            raise _err(f"bcs[{k}] ({name}): {key} = {v!r}; allowed: a finite number >= 0 "
                       f"[{'Pa' if key == 'pressure' else 'Pa/s' if key == 'rate' else 's'}]")
    pm = bc.get("p_max")
    if pm is not None and not (_real(pm) and math.isfinite(pm) and pm >= 0):
        raise _err(f"bcs[{k}] ({name}): p_max = {pm!r}; allowed: a finite number >= 0 [Pa]")
    return {"name": str(name), "role": role, "where": dict(where),
            "pressure": float(bc.get("pressure", 0.0)), "rate": float(bc.get("rate", 0.0)),
            "p_max": None if pm is None else float(pm), "t_start": float(bc.get("t_start", 0.0)),
            "cavity": bool(bc.get("cavity", False))}


def _real(v):
    """A real number (Python or NumPy, any width), not a bool."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _positive(name, v, unit, allow_zero=False, allow_none=False):
    if v is None and allow_none:
        return None
    ok = _real(v) and math.isfinite(v) and \
        (v >= 0 if allow_zero else v > 0)
    if not ok:
        rng = ">= 0" if allow_zero else "> 0"
        raise _err(f"{name} = {v!r}; allowed: a finite number {rng} [{unit}]")
    return float(v)


@register_field("pore_fluid")
class PoreField(CoupledField):
    """Pore-density fluid flow with pressure forces on the solid (see the module docstring).

    Parameters (SI): ``k_f`` [s^2/m^2] and ``c_f`` [kg/m^3] of the EOS ``rho = k_f P + c_f``;
    ``k_t`` [kg/(Pa s)] throat coefficient (default: cubic law at the aperture);
    ``aperture`` [m] (default 0.002 x mean diameter); ``viscosity`` [Pa s] (only for the
    default ``k_t``); ``bond_factor`` (100); ``p_init`` [Pa] initial pore pressure; ``p_min``
    [Pa] pressure floor (None: none); ``bcs`` boundary conditions; ``group`` elements forming
    the network; ``thickness`` [m] (2-D); ``edge_factor`` (2.0) sliver filter; ``floor``
    (0.01) smallest free-volume fraction; ``remesh_disp`` (0.25) and ``remesh_every`` (0)
    network-update triggers; ``forces`` (True) apply the pressure forces; ``every`` coupling
    interval in mechanical steps."""

    reads = {"x": "m", "props": "m (column r: radius)", "nbr": "- (contact rows)",
             "cstate": "- (bond flags)", "free": "- (free DOF flags)", "m": "kg"}
    writes = {"fload": "N", "a": "m/s^2"}
    safety = 0.5

    def __init__(self, k_f=WATER_KF, c_f=WATER_CF, k_t=None, aperture=None, viscosity=1.0e-3,
                 bond_factor=100.0, p_init=0.0, p_min=0.0, bcs=(), group="all", thickness=None,
                 edge_factor=2.0, floor=0.01, remesh_disp=0.25, remesh_every=0, forces=True,
                 gap_reference="initial", every=1):
        super().__init__(every)
        self.k_f = _positive("k_f", k_f, "kg m^-3 Pa^-1")
        self.c_f = _positive("c_f", c_f, "kg/m^3")
        self.k_t = _positive("k_t", k_t, "kg/(Pa s)", allow_none=True)
        self.aperture = _positive("aperture", aperture, "m", allow_zero=True, allow_none=True)
        self.viscosity = _positive("viscosity", viscosity, "Pa s")
        if self.aperture == 0.0 and self.k_t is None:
            raise _err("aperture = 0 without k_t: the default k_t = c_f aperture^2 w / "
                       "(12 viscosity) would be 0 and no fluid would flow; give k_t > 0 "
                       "[kg/(Pa s)] or aperture > 0 [m]")
        self.bond_factor = _positive("bond_factor", bond_factor, "-")
        if self.bond_factor < 1.0:
            raise _err(f"bond_factor = {bond_factor!r}; allowed: >= 1 (an intact bond "
                       "divides the throat conductance by it)")
        self.p_init = _positive("p_init", p_init, "Pa", allow_zero=True)
        if p_min is not None:
            if not (_real(p_min) and math.isfinite(p_min)):
                raise _err(f"p_min = {p_min!r}; allowed: a finite number [Pa] or null")
            if p_min > self.p_init:
                raise _err(f"p_min = {p_min!r} exceeds p_init = {self.p_init!r}; allowed: "
                           "p_min <= p_init")
        self.p_min = None if p_min is None else float(p_min)
        self.bcs = [_check_bc(k, bc) for k, bc in enumerate(bcs or ())]
        names = [b["name"] for b in self.bcs]
        if len(set(names)) != len(names):
            raise _err(f"boundary condition names must be unique, got {names}")
        if not isinstance(group, str) or not group:
            raise _err(f"group = {group!r}; allowed: a group name")
        self.group = group
        self.thickness = _positive("thickness", thickness, "m", allow_none=True)
        self.edge_factor = _positive("edge_factor", edge_factor, "-")
        if self.edge_factor <= 1.0:
            raise _err(f"edge_factor = {edge_factor!r}; allowed: > 1 (x the contact distance)")
        self.floor = _positive("floor", floor, "-")
        if self.floor >= 1.0:
            raise _err(f"floor = {floor!r}; allowed: 0 < floor < 1")
        self.remesh_disp = _positive("remesh_disp", remesh_disp, "-")
        self.remesh_every = whole_number("remesh_every", remesh_every, 0, "", "0 = never",
                                         _err)
        self.forces = bool(forces)
        if gap_reference not in ("initial", "zero"):
            raise _err(f"gap_reference = {gap_reference!r}; allowed: initial, zero")
        self.gap_reference = gap_reference
        self.sim = None
        self._advancing = False
        self._t_sub = 0.0

    # ------------------------------------------------------------------ config
    def config(self) -> dict:
        return {"k_f": self.k_f, "c_f": self.c_f, "k_t": self.k_t, "aperture": self.aperture,
                "viscosity": self.viscosity, "bond_factor": self.bond_factor,
                "p_init": self.p_init, "p_min": self.p_min,
                "bcs": [dict(b, where=dict(b["where"])) for b in self.bcs],
                "group": self.group, "thickness": self.thickness,
                "edge_factor": self.edge_factor, "floor": self.floor,
                "remesh_disp": self.remesh_disp, "remesh_every": self.remesh_every,
                "forces": self.forces, "gap_reference": self.gap_reference,
                "every": self.every}

    # ------------------------------------------------------------------ attach
    def attach(self, sim) -> None:
        st = sim.state
        self.sim = sim
        self.dim = st.dim
        if self.group != "all" and self.group not in st.groups:
            raise _err(f"group {self.group!r} is unknown; groups: {sorted(st.groups)}")
        for b in self.bcs:
            w = b["where"]
            if "group" in w and w["group"] != "all" and w["group"] not in st.groups:
                raise _err(f"boundary condition {b['name']!r}: group {w['group']!r} is "
                           f"unknown; groups: {sorted(st.groups)}")
            if "side" in w and (w["side"] not in SIDES or SIDES.index(w["side"]) // 2 >= st.dim):
                raise _err(f"boundary condition {b['name']!r}: side {w['side']!r}; allowed: "
                           f"{', '.join(SIDES[:2 * st.dim])}")
            if "ball" in w and len(w["ball"]) != st.dim + 1:
                raise _err(f"boundary condition {b['name']!r}: ball needs {st.dim + 1} numbers "
                           f"(centre and radius), got {w['ball']!r}")
            if "box" in w and (len(w["box"]) != 2 or any(len(v) != st.dim for v in w["box"])):
                raise _err(f"boundary condition {b['name']!r}: box needs [[lo x {st.dim}], "
                           f"[hi x {st.dim}]], got {w['box']!r}")
        idx = np.arange(st.n) if self.group == "all" else \
            np.flatnonzero(st.group == st.groups[self.group])
        if idx.size < st.dim + 1:
            raise _err(f"group {self.group!r} has {idx.size} elements; a pore network needs "
                       f"at least {st.dim + 1}")
        self.members = idx
        d_mean = 2.0 * float(st.r[idx].mean())
        self.d_mean = d_mean
        self._inverted = INVERTED_REL * d_mean ** st.dim
        if st.dim == 2:
            self.t = self.thickness or (st.thickness if st.thickness > 0 else d_mean)
        else:
            self.t = d_mean
        self.ap = self.aperture if self.aperture is not None else 0.002 * d_mean
        self.kt = self.k_t if self.k_t is not None else \
            self.c_f * self.ap ** 2 * self.t / (12.0 * self.viscosity)
        self.booked = np.zeros(len(self.bcs))
        self.couplings = 0
        self.remeshes = 0
        self._geom_key = None
        self.x0 = st.x.copy()
        self.r0 = st.r.copy()
        cells = self._triangulate(st.x, None)
        self._set_network(st, cells)
        for k, b in enumerate(self.bcs):
            if not (self.held == k).any():
                raise _err(f"boundary condition {b['name']!r}: where = {b['where']!r} selects "
                           "no pore (or only pores an earlier condition took); widen it")
        self._geometry(st)
        self.M = self.V * (self.k_f * self.p_init + self.c_f)
        self._hold_now(st.time)
        self.M0 = float(self.M.sum())
        self.booked[:] = 0.0
        self.f_prev = np.zeros((st.n, st.dim))
        self._f_spare = None  # the other force buffer of apply_forces
        self.x_mesh = st.x.copy()
        if self.forces and st.dt > 0:
            self.check_mechanical_dt(sim)

    def check_mechanical_dt(self, sim) -> float:
        """Raise :class:`~geodem.fields.FieldStabilityError` when the mechanical time step is
        above :meth:`mechanical_dt_bound` (or, coupling every ``every`` > 1 steps, when
        ``every x dt`` is: the fluid force is then held for ``every`` steps). Returns the
        bound [s]."""
        from geodem.fields import FieldStabilityError

        st = sim.state
        lim = self.mechanical_dt_bound(sim)
        if st.dt * self.every >= lim:
            raise FieldStabilityError(
                f"coupled field 'pore_fluid': the pore fluid stiffens the solid: the mechanical "
                f"time step {st.dt:.4g} s{f' x every = {self.every}' if self.every > 1 else ''} "
                f"is above the stability bound {lim:.4g} s with the fluid's stiffness (bulk "
                f"modulus c_f / k_f = {self.c_f / self.k_f:.3g} Pa in pores of "
                f"{float(np.median(self.V)):.3g} m^3); use a smaller dt (simulation.dt or "
                f"dt_fraction), couple every step, or a more compressible fluid (larger k_f)")
        return lim

    # ------------------------------------------------------------------ network
    def _triangulate(self, x, old):
        """Cells of a new triangulation (oriented), filtered (see the module doc). Flat cells
        (area/volume <= DEGENERATE_REL d^dim) reachable from the hull through dropped cells
        are dropped like the slivers there; a flat cell inside the packing is refused
        (PoreFluidError): it would be a pore of no volume, with no stable step."""
        from scipy.spatial import Delaunay

        st = self.sim.state
        idx = self.members
        try:
            tri = Delaunay(x[idx])
        except Exception as exc:  # noqa: BLE001 - qhull errors: degenerate input
            raise _err(f"the element centres cannot be triangulated ({exc}); the network needs "
                       f"a {st.dim}-D cloud of elements") from None
        cells = idx[tri.simplices]
        cells = _orient(x, cells)
        cen = x[cells].mean(axis=1)
        rel = np.abs(_cell_measure(x, cells)) / self.d_mean ** st.dim
        flat = rel <= DEGENERATE_REL
        bad = (_edge_ratio_max(x, st.r, cells, st.dim) > self.edge_factor) & \
            ~self._cavity_mask(cen)
        keep = ~_peel(tri.neighbors, bad | flat)
        if old is not None and old.shape[0]:
            # cells whose vertex set existed, or whose centroid lies in an old cell, stay pores
            keep |= self._match(old, cells)[0] >= 0
            cand = _nearest(x[old].mean(axis=1), cen[~keep], 4)
            inside = _point_in_cells(x, old, cen[~keep], cand) >= 0
            k2 = np.flatnonzero(~keep)
            keep[k2[inside]] = True
        if (flat & keep).any():
            raise _err(f"the pore network is degenerate: {int((flat & keep).sum())} cells inside "
                       f"the packing are flat (volume {float(rel[flat & keep].min()):.3g} x "
                       f"d^{self.dim} <= {DEGENERATE_REL:g} x d^{self.dim}, d = {self.d_mean:.4g} "
                       "m the mean diameter): the element centres of a regular lattice lie on "
                       "common spheres and the triangulation is not unique; jitter the positions "
                       "(e.g. by 1 % of d)")
        cells = cells[keep]
        if cells.shape[0] == 0:
            raise _err("no pore is left after dropping the cells outside the packing "
                       f"(edge_factor = {self.edge_factor}); is the packing dense?")
        return cells

    def _cavity_mask(self, cen):
        m = np.zeros(cen.shape[0], bool)
        for b in self.bcs:
            if b["cavity"]:
                m |= self._where(b["where"], cen, None, None)
        return m

    @staticmethod
    def _keys(cells):
        return np.sort(cells, axis=1)

    def _match(self, old, new):
        """``(old_of_new, new_of_old)``: index of the cell with the same vertex set (-1).
        Within one triangulation the vertex sets are unique, so after a lexicographic sort of
        both sets' rows an equal neighbour is the other set's cell (stable: old first)."""
        ko, kn = self._keys(old), self._keys(new)
        allk = np.concatenate([ko, kn])
        order = np.lexsort(allk.T[::-1])
        srt = allk[order]
        same = np.flatnonzero(np.all(srt[1:] == srt[:-1], axis=1))
        a, b = order[same], order[same + 1] - len(ko)
        ok = (a < len(ko)) & (b >= 0)
        old_of_new = np.full(len(kn), -1, np.int64)
        new_of_old = np.full(len(ko), -1, np.int64)
        old_of_new[b[ok]] = a[ok]
        new_of_old[a[ok]] = b[ok]
        return old_of_new, new_of_old

    def _where(self, w, cen, boundary, cells):
        key, val = next(iter(w.items()))
        if key == "ball":
            c = np.asarray(val[:-1], float)
            return np.linalg.norm(cen - c, axis=1) <= float(val[-1])
        if key == "box":
            lo, hi = np.asarray(val[0], float), np.asarray(val[1], float)
            return np.all((cen >= lo) & (cen <= hi), axis=1)
        if key == "boundary":
            if boundary is None:
                return np.zeros(cen.shape[0], bool)
            return boundary.copy() if val else ~boundary
        if key == "group":
            if cells is None:
                return np.zeros(cen.shape[0], bool)
            st = self.sim.state
            inside = np.ones(st.n, bool) if val == "all" else st.group == st.groups[val]
            return inside[cells].any(axis=1)
        if key == "side":
            ax = SIDES.index(val) // 2
            depth = 0.5 * self.d_mean
            if val.endswith("min"):
                return cen[:, ax] <= cen[:, ax].min() + depth
            return cen[:, ax] >= cen[:, ax].max() - depth
        raise _err(f"unknown where {w!r}")  # pragma: no cover - checked in _check_bc

    def _set_network(self, st, cells):
        """Install ``cells``: throats, boundary flags, held pores, slots, buffers."""
        self.cells = np.ascontiguousarray(cells, dtype=np.int64)
        P = self.cells.shape[0]
        tp, te, boundary = _throats(self.cells, st.dim)
        self.tp = np.ascontiguousarray(tp)
        self.te = np.ascontiguousarray(te)
        self.boundary = boundary
        cen = st.x[self.cells].mean(axis=1)
        held = np.full(P, -1, np.int64)
        for k, b in enumerate(self.bcs):
            sel = self._where(b["where"], cen, boundary, self.cells) & (held < 0)
            held[sel] = k
        self.held = held
        self.slots = np.full(self.te.shape[:2], -1, np.int64)
        _find_slots(st.nbr, self.te, self.slots)
        # reference gap of each throat pair (gap_reference: initial), from the attach positions
        if self.gap_reference == "initial":
            i, j = self.te[..., 0], self.te[..., 1]
            g0 = np.linalg.norm(self.x0[j] - self.x0[i], axis=-1) - self.r0[i] - self.r0[j]
            self.g0 = np.ascontiguousarray(np.maximum(g0, 0.0))
        else:
            self.g0 = np.zeros(self.te.shape[:2])
        self.V = np.zeros(P)
        self.cen = np.zeros((P, st.dim))
        self.C = np.zeros(self.tp.shape[0])
        self._cell_forces = np.empty((4, 3))  # the serial 3-D force pass's scratch
        if P >= PARALLEL_MIN:  # the gathers of the threaded passes (same order as the serial ones)
            self._pore_ptr, self._pore_items = _owner_index(self.tp, P)
            if st.dim == 3:
                self._el_ptr, self._el_items = _owner_index(self.cells, st.n)
                self._vertex_forces = np.zeros((4 * P, 3))
        self.csum = np.zeros(P)
        self.P = np.zeros(P)
        self._geom_key = None

    def _geometry(self, st):
        """Volumes, centroids and conductances at the current positions; returns the number of
        inside-out cells."""
        bad = self._volumes(st, self.cells, self.V, self.cen)
        args = (st.x, st.r, self.g0, self.tp, self.te, self.slots, st.cstate, self.cen,
                self.kt, self.ap, self.bond_factor, self.C)
        if self._threaded():
            _conductance_par(*args)
            _pore_sums(self.C, self._pore_ptr, self._pore_items, self.csum)
        else:
            _conductance(*args, self.csum)
        self._geom_key = (st.step, st.time)
        return bad

    def _threaded(self, cells=None) -> bool:
        """Whether the passes over ``cells`` (default the network's) run over the threads."""
        n = (self.cells if cells is None else cells).shape[0]
        return n >= PARALLEL_MIN and numba.get_num_threads() > 1

    def _volumes(self, st, cells, V, cen):
        """Pore volumes ``V`` and centroids ``cen`` of ``cells``; returns the number of cells
        inside out."""
        par = self._threaded(cells)
        if self.dim == 2:
            fn = _geom2_par if par else _geom2
            return fn(st.x, st.r, cells, self.t, self.ap, self.floor, V, cen, self._inverted)
        fn = _geom3_par if par else _geom3
        return fn(st.x, st.r, cells, self.ap, self.floor, V, cen, self._inverted)

    def remesh(self, sim=None) -> dict:
        """Rebuild the pore network at the current positions, conserving the fluid mass (see
        the module docstring). Returns counts of kept, lost and new pores."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        sim = sim or self.sim
        st = sim.state
        x = st.x
        old_cells, old_M = self.cells, self.M
        total = float(old_M.sum())
        # old densities at the current positions
        Vo = np.zeros(old_cells.shape[0])
        co = np.zeros((old_cells.shape[0], self.dim))
        self._volumes(st, old_cells, Vo, co)
        rho_old = old_M / Vo
        new_cells = self._triangulate(x, old_cells)
        old_of_new, new_of_old = self._match(old_cells, new_cells)
        self._set_network(st, new_cells)
        self._geometry(st)
        Vn, cn = self.V, self.cen
        Pn = new_cells.shape[0]
        M = np.zeros(Pn)
        kept = old_of_new >= 0
        M[kept] = old_M[old_of_new[kept]]
        lost = np.flatnonzero(new_of_old < 0)
        new = np.flatnonzero(~kept)
        nO = old_cells.shape[0]
        if lost.size or new.size:
            # parent (old cell containing the centroid, else nearest) of every new cell
            cand = _nearest(co, cn[new], 4)
            parent = _point_in_cells(x, old_cells, cn[new], cand)
            parent = np.where(parent >= 0, parent, cand[:, 0])
            # child (new cell containing the centroid, else nearest) of every lost cell
            cand = _nearest(cn, co[lost], 4)
            child = _point_in_cells(x, new_cells, co[lost], cand)
            child = np.where(child >= 0, child, cand[:, 0])
            # graph over nodes: old cells [0, nO) and new cells [nO, nO + Pn)
            rows = np.concatenate([new + nO, lost])
            cols = np.concatenate([parent, child + nO])
            g = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(nO + Pn, nO + Pn))
            _, lab = connected_components(g, directed=False)
            target = Vn[new] * rho_old[parent]
            lost_lab = lab[lost]
            new_lab = lab[new + nO]
            nl = lab.max() + 1
            lost_mass = np.bincount(lost_lab, weights=old_M[lost], minlength=nl)
            tgt_sum = np.bincount(new_lab, weights=target, minlength=nl)
            has_lost = np.bincount(lost_lab, minlength=nl) > 0
            has_new = np.bincount(new_lab, minlength=nl) > 0
            # patches with lost and new cells: the lost mass shared by density targets
            both = has_lost & has_new
            sel = both[new_lab]
            with np.errstate(invalid="ignore", divide="ignore"):
                M[new[sel]] = lost_mass[new_lab[sel]] * target[sel] / tgt_sum[new_lab[sel]]
            # new cells in formerly dry space: share their parent's (kept) pore at equal density
            dry = np.flatnonzero(~sel)
            if dry.size:
                par_new = new_of_old[parent[dry]]
                host = np.where(par_new >= 0, par_new, -1)
                if (host < 0).any():  # parent lost in a patch without ... : nearest kept cell
                    kc = np.flatnonzero(kept)
                    if kc.size:
                        near = kc[_nearest(cn[kc], cn[new[dry[host < 0]]], 1)[:, 0]]
                        host[host < 0] = near
                for h in np.unique(host):
                    if h < 0:
                        continue
                    members = new[dry[host == h]]
                    vol = Vn[h] + Vn[members].sum()
                    mh = M[h]
                    M[members] = mh * Vn[members] / vol
                    M[h] = mh - M[members].sum()
            # patches with lost cells only: their mass to the nearest pore of the new network
            only = np.flatnonzero(has_lost & ~has_new)
            if only.size:
                lsel = np.isin(lost_lab, only)
                np.add.at(M, child[lsel], old_M[lost[lsel]])
        # round-off: put the last bits where the most fluid is
        M[np.argmax(M)] += total - float(M.sum())
        self.M = M
        self.x_mesh = x.copy()
        self.remeshes += 1
        return {"kept": int(kept.sum()), "lost": int(lost.size), "new": int(new.size)}

    # ------------------------------------------------------------------ stepping
    def _pset(self, time):
        out = np.zeros(len(self.bcs))
        for k, b in enumerate(self.bcs):
            p = b["pressure"] + b["rate"] * max(time - b["t_start"], 0.0)
            if b["p_max"] is not None:
                p = min(p, b["p_max"])
            out[k] = p
        return out

    def _hold_now(self, time):
        if len(self.bcs):
            _hold(self.M, self.V, self.held, self._pset(time), self.booked, self.k_f, self.c_f)

    def _prepare(self, sim):
        """Network checks and geometry at the current positions (once per coupling)."""
        st = sim.state
        if not _slots_valid(st.nbr, self.te, self.slots):
            _find_slots(st.nbr, self.te, self.slots)
        disp2 = float(((st.x - self.x_mesh) ** 2).sum(axis=1).max())
        due = self.remesh_every and self.couplings % self.remesh_every == 0 and self.couplings
        if due or disp2 > (self.remesh_disp * self.d_mean) ** 2:
            self.remesh(sim)
        bad = self._geometry(st)
        if bad:
            self.remesh(sim)
            bad = self._geometry(st)
            if bad:
                raise _err(f"{bad} pores are inside out even after a network update at step "
                           f"{st.step}: elements crossed each other; reduce the time step")

    def stable_dt(self, sim) -> float:
        """``min over free pores of V k_f / sum C`` [s] (see the module docstring)."""
        st = sim.state
        if self._geom_key != (st.step, st.time):
            self._geometry(st)
        free = (self.held < 0) & (self.csum > 0)
        if not free.any():
            return math.inf
        return float((self.V[free] * self.k_f / self.csum[free]).min())

    def substep(self, sim, h: float, allow_unstable: bool = False) -> None:
        """One explicit Euler sub-step of ``h`` seconds. Called directly (not from
        :meth:`advance`, which sub-steps at ``safety`` x :meth:`stable_dt`), ``h`` above
        :meth:`stable_dt` is refused (FieldStabilityError) unless ``allow_unstable`` (studies of
        where the scheme fails, :mod:`geodem.studies.stability`)."""
        if not (allow_unstable or self._advancing):
            check_substep(self, sim, h)
        t = self._t_sub + h
        self._t_sub = t
        pset = self._pset(t)
        use = self.p_min is not None
        _substep(self.M, self.V, self.C, self.tp, self.held, pset, self.booked, self.k_f,
                 self.c_f, self.p_min if use else 0.0, use, h, self.P)

    def advance(self, sim, span: float) -> int:
        """Geometry at the current positions, held pores reset, ``n`` sub-steps over ``span``,
        then the pressure forces on the solid."""
        st = sim.state
        self._prepare(sim)
        self._t_sub = st.time - span
        self._hold_now(self._t_sub)
        self._advancing = True
        try:
            n = super().advance(sim, span)
        finally:
            self._advancing = False
        self.couplings += 1
        self.update_pressure()
        if self.forces:
            self.apply_forces(sim)
        return n

    def update_pressure(self) -> np.ndarray:
        use = self.p_min is not None
        _pressure(self.M, self.V, self.k_f, self.c_f, self.p_min if use else 0.0, use, self.P)
        return self.P

    def pressure_forces(self, sim=None, out=None) -> np.ndarray:
        """Forces [N] of the current pore pressures on every element, ``(N, dim)`` (into
        ``out`` when given)."""
        st = (sim or self.sim).state
        F = np.zeros((st.n, st.dim)) if out is None else out
        if self.dim == 2:
            _forces2(st.x, st.r, self.cells, self.P, self.t, F)
        elif self._threaded():
            _forces3_par(st.x, st.r, self.cells, self.P, F, self._vertex_forces, self._el_ptr,
                         self._el_items)
        else:
            _forces3(st.x, st.r, self.cells, self.P, F, self._cell_forces)
        return F

    def apply_forces(self, sim) -> None:
        """Replace this field's previous contribution to ``fload`` by the current one; free
        DOFs' ``a`` change by the same delta / m (see the module docstring)."""
        st = sim.state
        spare = self._f_spare
        if spare is None or spare.shape != self.f_prev.shape:
            spare = np.zeros_like(self.f_prev)
        F = self.pressure_forces(sim, out=spare)
        _apply_delta(F, self.f_prev, st.fload, st.a, st.free, st.m)
        self._f_spare, self.f_prev = self.f_prev, F  # two buffers, no allocation per coupling

    def mechanical_dt_bound(self, sim=None) -> float:
        """Stability bound [s] of the mechanical step with the fluid's stiffness added.

        A saturated pore is a spring: ``dP = -(rho / (k_f V)) dV`` and ``dV = a_i . dx_i`` with
        ``a_i`` the force per unit pressure on element ``i`` (``F_i = P a_i``), so the pore adds
        the stiffness ``(rho / (k_f V)) a a^T`` to its elements. With the contact rows'
        Gershgorin row sums (``geodem.core.timestep.omega_max_bound``) this gives
        ``omega_max^2 <= max_i [sum_contacts + sum_pores (rho/(k_f V)) |a_i| sum_j |a_j| /
        sqrt(m_i m_j)]`` and the bound ``2 / omega_max``. A stiff fluid (water) in small pores of
        a soft solid can need a smaller time step than the solid alone."""
        from geodem.core.law import series_array

        st = (sim or self.sim).state
        if self._geom_key != (st.step, st.time):
            self._geometry(st)
        valid = st.nbr >= 0
        j = np.where(valid, st.nbr, 0)
        k = np.maximum(series_array(st.kn[:, None], st.kn[j]),
                       series_array(st.ks[:, None], st.ks[j]))
        mi = st.m[:, None]
        row = np.where(valid, k * (1.0 / mi + 1.0 / np.sqrt(mi * st.m[j])), 0.0).sum(axis=1)
        amag = self._unit_force_magnitudes(st)
        rho = np.maximum(self.M / self.V, self.c_f)
        kc = rho / (self.k_f * self.V)  # (P,)
        sm = np.sqrt(st.m[self.cells])  # (P, k)
        s = (amag / sm).sum(axis=1)  # sum_j |a_j| / sqrt(m_j)
        contrib = kc[:, None] * amag / sm * s[:, None]  # per (cell, vertex): / sqrt(m_i)
        fl = np.zeros(st.n)
        np.add.at(fl, self.cells.ravel(), contrib.ravel())
        movable = (st.free != 0).any(axis=1)
        w2 = float((row + fl)[movable].max()) if movable.any() else 0.0
        return math.inf if w2 == 0.0 else 2.0 / math.sqrt(w2)

    def _unit_force_magnitudes(self, st) -> np.ndarray:
        """``|a_i|`` (force per unit pressure) of each cell's vertices, ``(P, dim + 1)``."""
        x, r, cells = st.x, st.r, self.cells
        k = cells.shape[1]
        out = np.zeros(cells.shape)
        if self.dim == 2:
            def cp(a, b):
                e = x[b] - x[a]
                L = np.linalg.norm(e, axis=1)[:, None]
                return x[a] + 0.5 * (L + r[a][:, None] - r[b][:, None]) / L * e
            for v in range(3):
                a, b, o = cells[:, v], cells[:, (v + 1) % 3], cells[:, (v + 2) % 3]
                out[:, v] = self.t * np.linalg.norm(cp(a, b) - cp(o, a), axis=1)
            return out
        Fu = np.zeros((cells.shape[0], k, 3))
        for c0 in range(0, cells.shape[0], 4096):
            sl = slice(c0, min(cells.shape[0], c0 + 4096))
            for f in _FACES3:
                v0, v1, v2 = cells[sl, f[0]], cells[sl, f[1]], cells[sl, f[2]]

                def cp(a, b):
                    e = x[b] - x[a]
                    L = np.linalg.norm(e, axis=1)[:, None]
                    return x[a] + 0.5 * (L + r[a][:, None] - r[b][:, None]) / L * e
                q01, q12, q20 = cp(v0, v1), cp(v1, v2), cp(v2, v0)
                m = (q01 + q12 + q20) / 3.0
                for slot, a, qin, qout in ((f[0], v0, q20, q01), (f[1], v1, q01, q12),
                                           (f[2], v2, q12, q20)):
                    Fu[sl, slot] += 0.5 * np.cross(m - x[a], qin - qout)
        return np.linalg.norm(Fu, axis=2)

    def remove_forces(self, sim=None) -> None:
        """Take this field's loads off the solid (before removing the field)."""
        st = (sim or self.sim).state
        st.fload -= self.f_prev
        st.a -= np.where(st.free != 0.0, self.f_prev / st.m[:, None], 0.0)
        self.f_prev = np.zeros_like(self.f_prev)

    # ------------------------------------------------------------------ bcs at run time
    def set_bc(self, name: str, **changes) -> None:
        """Change a boundary condition's schedule (``pressure``, ``rate``, ``p_max``,
        ``t_start``); the change is part of :meth:`config`, so checkpoints keep it."""
        k = self.bc_index(name)
        bad = set(changes) - {"pressure", "rate", "p_max", "t_start"}
        if bad:
            raise _err(f"set_bc({name!r}): cannot change {sorted(bad)}")
        self.bcs[k] = _check_bc(k, dict(self.bcs[k], **changes))

    def bc_index(self, name: str) -> int:
        for k, b in enumerate(self.bcs):
            if b["name"] == name:
                return k
        raise _err(f"no boundary condition named {name!r}; have {[b['name'] for b in self.bcs]}")

    def bc_pressure(self, name: str, time: float | None = None) -> float:
        """Set pressure [Pa] of condition ``name`` at ``time`` (default: now)."""
        t = self.sim.state.time if time is None else time
        return float(self._pset(t)[self.bc_index(name)])

    def bc_pores(self, name: str) -> np.ndarray:
        return np.flatnonzero(self.held == self.bc_index(name))

    # ------------------------------------------------------------------ books
    @property
    def mass(self) -> float:
        return float(self.M.sum())

    @property
    def injected(self) -> float:
        return float(sum(self.booked[k] for k, b in enumerate(self.bcs) if b["role"] == "inject"))

    @property
    def drained(self) -> float:
        return float(-sum(self.booked[k] for k, b in enumerate(self.bcs) if b["role"] == "drain"))

    def mass_balance_error(self) -> float:
        """``|M - M_0 - injected + drained| / max(M_0, |injected|)``."""
        resid = self.mass - self.M0 - self.injected + self.drained
        return abs(resid) / max(self.M0, abs(self.injected), 1e-300)

    def storage(self) -> np.ndarray:
        """Pore storage ``dM/dP = V k_f`` [kg/Pa]."""
        return self.V * self.k_f

    # ------------------------------------------------------------------ checkpoints
    def arrays(self) -> dict:
        return {"cells": self.cells, "M": self.M, "booked": self.booked,
                "f_prev": self.f_prev.copy(), "x_mesh": self.x_mesh, "x0": self.x0, "r0": self.r0,
                "held": self.held,
                "books": np.array([self.M0, self.couplings, self.remeshes], float),
                "scales": np.array([self.d_mean, self.t, self.ap, self.kt], float)}

    def restore(self, arrays: dict) -> None:
        st = self.sim.state
        if "scales" in arrays:
            # the mean diameter, thickness, aperture and k_t chosen when the field was first
            # attached: ``attach`` on resume sees the radii of now (a thermal field may have
            # expanded them), which would shift all four (checkpoints before this: as attached)
            sc = np.asarray(arrays["scales"], float)
            self.d_mean, self.t, self.ap, self.kt = (float(v) for v in sc)
        self.x0 = np.array(arrays["x0"], float)
        self.r0 = np.array(arrays["r0"], float)
        self._set_network(st, arrays["cells"])
        self.held = np.array(arrays["held"], np.int64)  # chosen when the network was built
        self.M = np.array(arrays["M"], float)
        self.booked = np.array(arrays["booked"], float)
        self.f_prev = np.array(arrays["f_prev"], float)
        self.x_mesh = np.array(arrays["x_mesh"], float)
        b = arrays["books"]
        self.M0, self.couplings, self.remeshes = float(b[0]), int(b[1]), int(b[2])
        self._geometry(st)
        self.update_pressure()

    # ------------------------------------------------------------------ report
    def summary(self) -> dict:
        P = self.P
        free = self.held < 0
        out = {"pores": int(self.cells.shape[0]), "throats": int(self.tp.shape[0]),
               "fluid_mass": self.mass, "fluid_mass_initial": self.M0,
               "injected_mass": self.injected, "drained_mass": self.drained,
               "fluid_mass_balance_rel_error": self.mass_balance_error(),
               "pressure_max": float(P.max()) if P.size else 0.0,
               "pressure_mean_free": float(P[free].mean()) if free.any() else 0.0,
               "substeps": int(self.substeps), "couplings": int(self.couplings),
               "network_updates": int(self.remeshes), "k_t": self.kt, "aperture": self.ap,
               "thickness": self.t if self.dim == 2 else None}
        return out
