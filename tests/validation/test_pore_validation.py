"""Pore-density flow against analytic references (VALIDATION.md): 1-D pressure diffusion
(Terzaghi's consolidation series), steady Darcy flow (flux linear in the pressure drop, network
conductivity of the honeycomb pore network), fluid mass conservation.

The discrete network of a triangular lattice of touching discs (spacing d) is a honeycomb of
pores: 4/(sqrt(3) d^2) pores per unit area, throats of conductance C between pore centroids
d/sqrt(3) apart. A uniform gradient G gives a linear pressure field that satisfies every pore's
balance exactly (its three throat vectors sum to zero), so the sheet conductivity follows from
the dissipation per area, sum C (G.delta)^2 = (2 sqrt(3)/d^2) C G^2 d^2/6 = C G^2 / sqrt(3):

    q = sigma G,  sigma = C / sqrt(3)                      [kg/(s Pa) per m of width x m/m]
    s = S * 4 / (sqrt(3) d^2)  (storage per area, S = V k_f per pore)
    D = sigma / s = C d^2 / (4 S)                          [m^2/s]

Terzaghi (drained at x = 0, impermeable at x = H, uniform initial excess pressure):
``U(T_v) = 1 - sum_m 2/M^2 exp(-M^2 T_v)``, ``M = pi (2m + 1)/2``, ``T_v = D t / H^2``.
"""
import math

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.core.engine import Simulation
from geodem.fields.pore import OIL_CF, OIL_KF, PoreField

pytestmark = pytest.mark.validation

D = 0.01


def terzaghi_U(tv, terms=200):
    m = np.arange(terms)
    M = np.pi * (2 * m + 1) / 2
    return 1.0 - np.sum(2.0 / M ** 2 * np.exp(-np.outer(np.atleast_1d(tv), M ** 2)), axis=1)


def _lattice(nx, ny, kn=2e8):
    x = triangular_lattice(nx, ny, D)
    return bonded_state(x, 0.5 * D, density=2500.0, kn=kn, ks=0.4 * kn, xb=1e-3 * D,
                        fs0=1e4, mu=0.5, gap=1e-6 * D)


def _columns(nx, ny):
    """x of the full columns of pores (ny - 1 cells each; spacing d/2) of the strip."""
    st = _lattice(nx, ny)
    st.free[:] = 0.0
    sim = Simulation(st, backend="numba")
    f = PoreField(forces=False)
    sim.add_field(f)
    xs, counts = np.unique(np.round(f.cen[:, 0] / (0.5 * D), 6), return_counts=True)
    return xs[counts == ny - 1] * 0.5 * D


def test_network_diffusivity_and_terzaghi_consolidation(nx=34, ny=4):
    """Strip of pores drained at its left end: the mean excess pressure decays as Terzaghi's
    U(T_v) with D = C d^2 / (4 S) from the network's own conductance and storage."""
    xs = _columns(nx, ny)
    x_cut = xs[0] + 0.25 * D  # the first full column of pores (and the end cells) drained
    st = _lattice(nx, ny)
    st.free[:] = 0.0  # a rigid skeleton: pure diffusion (any dt is stable for fixed elements)
    p0 = 1.0e6
    sim = Simulation(st, backend="numba", dt=0.05)
    f = PoreField(k_f=OIL_KF, c_f=OIL_CF, k_t=1e-6, p_init=p0, p_min=None, forces=False,
                  bcs=[{"name": "drain", "role": "drain", "pressure": 0.0,
                                  "where": {"box": [[-1.0, -1.0], [x_cut, 1.0]]}}])
    sim.add_field(f)
    free = f.held < 0
    # every pore alike (equal radii: V depends on the area and the angle sum only); every
    # throat between two lattice triangles alike (bonded touching pair, path d / sqrt(3)); the
    # obtuse cells closing the zig-zag ends of the strip differ
    assert np.ptp(f.V) < 1e-12 * f.V.max()
    C = float(np.median(f.C))
    assert C == pytest.approx(1e-6 * f.ap / (D / math.sqrt(3)) / f.bond_factor, rel=1e-9)
    S = f.V[0] * f.k_f
    Dh = C * D * D / (4.0 * S)
    H = (xs[-1] + 0.25 * D) - xs[0]  # drained column to the no-flow end (half a spacing on)
    t_end = 1.0 * H * H / Dh
    sim.state.dt = t_end / 400.0
    tv_meas, U_meas = [], []
    for _ in range(40):
        sim.run(10)
        P = f.update_pressure()
        tv_meas.append(Dh * (st.time) / H ** 2)
        U_meas.append(1.0 - (f.V[free] * P[free]).sum() / (f.V[free].sum() * p0))
    tv_meas, U_meas = np.array(tv_meas), np.array(U_meas)
    U_ref = terzaghi_U(tv_meas)
    sel = tv_meas >= 0.05
    err = np.abs(U_meas[sel] - U_ref[sel]) / U_ref[sel]
    assert err.max() < 0.05, (tv_meas[sel], U_meas[sel], U_ref[sel])
    # the drained mass is what left the pores
    assert f.mass_balance_error() < 1e-12
    assert f.drained > 0.5 * S * p0 * free.sum()


def _darcy(dp, nx=24, ny=8, p_out=1.0e6):
    st = _lattice(nx, ny)
    edge = (st.x[:, 0] < 0.1 * D) | (st.x[:, 0] > st.x[:, 0].max() - 0.6 * D) | \
        (st.x[:, 1] < 0.1 * D) | (st.x[:, 1] > st.x[:, 1].max() - 0.1 * D)
    st.free[edge] = 0.0  # a fixed frame holds the deforming specimen
    sim = Simulation(st, backend="numba")
    f = PoreField(k_t=2e-3, p_init=p_out, every=1,
                  bcs=[{"name": "in", "role": "inject", "where": {"side": "xmin"},
                        "pressure": p_out + dp},
                       {"name": "out", "role": "drain", "where": {"side": "xmax"},
                        "pressure": p_out}])
    sim.add_field(f)
    free = f.held < 0
    last = None
    for _ in range(200):
        i0, d0, t0 = f.injected, f.drained, st.time
        sim.run(200)
        q_in = (f.injected - i0) / (st.time - t0)
        q_out = (f.drained - d0) / (st.time - t0)
        if last is not None and abs(q_in - q_out) < 2e-4 * q_in and abs(q_in - last) < 2e-4 * q_in:
            break
        last = q_in
    else:
        pytest.fail("no steady state")
    P = f.update_pressure()
    x = f.cen[free, 0]
    mid = (x > x.min() + 2 * D) & (x < x.max() - 2 * D)
    G = -np.polyfit(x[mid], P[free][mid], 1)[0]
    width = (ny - 1) * math.sqrt(3) / 2 * D
    sigma = q_in / (G * width)
    return sigma, f, q_in, q_out


def test_steady_darcy_flow_conductivity_is_independent_of_the_drop_and_matches_the_network():
    s1, f1, qi1, _ = _darcy(2.0e5)
    s2, f2, qi2, _ = _darcy(4.0e5)
    assert abs(s2 - s1) / s1 < 0.05
    assert qi2 / qi1 == pytest.approx(2.0, rel=0.05)  # Darcy: flux linear in the drop
    # against the honeycomb value C / sqrt(3) with the mean bonded-throat conductance
    inner = f1.C[(f1.held[f1.tp[:, 0]] < 0) & (f1.held[f1.tp[:, 1]] < 0)]
    assert s1 == pytest.approx(np.median(inner) / math.sqrt(3), rel=0.05)
    assert f1.mass_balance_error() < 1e-10 and f2.mass_balance_error() < 1e-10
