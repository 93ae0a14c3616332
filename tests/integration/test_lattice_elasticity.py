"""Close-packed lattice elasticity and chain wave speed against VALIDATION.md.

FCC and triangular lattices are Bravais lattices (every element is a centre of symmetry), so a
homogeneous strain is the exact equilibrium: imposing the affine displacement through one
force evaluation of the kernel and reading the interior stress (virial) measures the stiffness
tensor without relaxation error. E and nu follow from uniaxial stress (sigma_lateral = 0).
"""
import math

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, chain, fcc_lattice, triangular_lattice
from geodem.core.engine import Simulation
from geodem.core.neighbors import row_counts

D, KN, KS = 0.01, 2.0e7, 0.6e7


def lattice(dim):
    if dim == 3:
        x = fcc_lattice(8, 8, 8, D)
    else:
        x = triangular_lattice(12, 12, D)
    st = bonded_state(x, np.full(len(x), 0.5 * D), density=2650.0, kn=KN, ks=KS, xb=1.0, fs0=1e9,
                      mu=0.5, gap=1e-6 * D, thickness=D if dim == 2 else None)
    return st


def interior_stress(strain, dim, backend):
    st = lattice(dim)
    sim = Simulation(st, backend=backend, check_every=10**9)
    full = row_counts(st) == (12 if dim == 3 else 6)
    # impose the affine displacement and evaluate forces once (dt = 0 moves nothing else)
    st.dx[:] = st.x @ np.asarray(strain).T
    st.x += st.dx
    sim.backend.push(("x", "dx"))
    sim.backend.force(0.0, 2, 3)
    sim.sync()
    valid = st.nbr >= 0
    j = np.where(valid, st.nbr, 0)
    br = st.x[j] - st.x[:, None, :]
    dist = np.where(valid, np.linalg.norm(br, axis=-1), D)
    n = br / dist[..., None]
    fn = 0.5 * KN * (dist - D)  # bonded pairs, series stiffness KN/2
    f = fn[..., None] * n + st.fs
    sig = 0.5 * np.einsum("nwa,nwb->nab", np.where(valid[..., None], f, 0.0), br)
    vol = D ** 3 / math.sqrt(2) if dim == 3 else math.sqrt(3) / 2 * D * D * D
    return (sig[full] / vol).mean(axis=0)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_fcc_lattice_E_nu(backend):
    eps = 1e-6
    s_axial = interior_stress(np.diag([0.0, 0.0, eps]), 3, backend)
    s_lat = interior_stress(np.diag([eps, eps, 0.0]), 3, backend)
    c33, c13 = s_axial[2, 2] / eps, s_axial[0, 0] / eps
    c11_12 = s_lat[0, 0] / eps
    E = c33 - 2 * c13 * c13 / c11_12
    nu = c13 / c11_12
    Kn, Ks = KN / 2, KS / 2
    E_ref = 6 * math.sqrt(2) * Kn * (Kn + Ks) / (D * (5 * Kn + Ks))
    nu_ref = (Kn - Ks) / (5 * Kn + Ks)
    assert E == pytest.approx(E_ref, rel=0.01)
    assert nu == pytest.approx(nu_ref, rel=0.01)


def test_triangular_lattice_E_nu():
    eps = 1e-6
    s_y = interior_stress(np.diag([0.0, eps]), 2, "numba")
    c22, c12 = s_y[1, 1] / eps, s_y[0, 0] / eps
    s_x = interior_stress(np.diag([eps, 0.0]), 2, "numba")
    c11 = s_x[0, 0] / eps
    E = c22 - c12 * c12 / c11
    nu = c12 / c11
    Kn, Ks = KN / 2, KS / 2
    E_ref = 2 * math.sqrt(3) * Kn * (Kn + Ks) / (D * (3 * Kn + Ks))
    nu_ref = (Kn - Ks) / (3 * Kn + Ks)
    assert E == pytest.approx(E_ref, rel=0.01)
    assert nu == pytest.approx(nu_ref, rel=0.01)
    assert c11 == pytest.approx(c22, rel=0.01)  # the triangular lattice is isotropic


def test_chain_long_wave_speed():
    """A smooth velocity step at one end of a bonded chain travels at c = d sqrt(k/m)."""
    n = 700
    x = chain(n, D, dim=2)
    st = bonded_state(x, np.full(n, 0.5 * D), density=2650.0, kn=KN, ks=KS, xb=1.0, fs0=1e9,
                      mu=0.5, gap=1e-6 * D, thickness=D)
    st.free[0] = 0.0
    st.free[:, 1] = 0.0  # longitudinal motion only
    k, m = KN / 2, st.m[1]
    c = D * math.sqrt(k / m)
    sim = Simulation(st, backend="numba", check_every=10**9)
    tau = 40 * D / c  # rise time: the pulse spans ~40 elements, dispersion stays < 0.5 %
    vmax = 1e-3
    stations = (150, 550)
    cross = {}

    def drive(s):
        t = s.state.time
        s.backend.pull(("v",))  # inside a run: this step's velocities, and the drive's
        s.state.v[0, 0] = vmax * (0.5 - 0.5 * math.cos(math.pi * min(t / tau, 1.0)))
        s.backend.push(("v",))
        for i in stations:
            if i not in cross and s.state.v[i, 0] >= 0.5 * vmax:
                cross[i] = t

    steps = int((stations[1] * D / c + 2 * tau) / st.dt)
    sim.run(steps, callback=drive, every=1)
    speed = (stations[1] - stations[0]) * D / (cross[stations[1]] - cross[stations[0]])
    assert speed == pytest.approx(c, rel=0.02)
