"""Close-packed lattice under a platen-driven uniaxial test, relaxed dynamically (long).

Unlike the affine check in tests/integration, this one goes through the whole machinery: kinematic
platens, free lateral faces, the standard damping and balance, and reads E and nu from the
relaxed interior (virial stress, least-squares strain) as a lab test would.
"""
import math

import numpy as np
import pytest

from geodem.build.lattice import bonded_state, fcc_lattice
from geodem.core.engine import Simulation

pytestmark = pytest.mark.validation

D, KN, KS = 0.01, 2.0e7, 0.6e7


def test_fcc_uniaxial_platen_E_nu(shape=(7, 7, 12)):
    x = fcc_lattice(*shape, D)
    st = bonded_state(x, np.full(len(x), 0.5 * D), density=2650.0, kn=KN, ks=KS, xb=1.0,
                      fs0=1e9, mu=0.5, gap=1e-6 * D)
    z = st.x[:, 2]
    h = z.max()
    bottom, top = z < 0.1 * D, z > h - 0.1 * D
    st.free[bottom, 2] = 0.0  # frictionless platens: z prescribed, x/y free
    st.free[top, 2] = 0.0
    anchor = np.flatnonzero(bottom)[0]
    st.free[anchor] = 0.0  # no rigid drift
    eps = 1e-4
    n_across = shape[2]
    sim = Simulation(st, backend="numba", monitor_every=0)
    t_load = 2000 * st.dt
    st.v[top, 2] = -eps * h / t_load  # compress to eps over 2000 steps
    sim.backend.push(("v",))
    sim.run(2000)
    st.v[top, 2] = 0.0
    sim.backend.push(("v",))
    for _ in range(40):
        ratio = sim.balance(n_across)
        if ratio < 1e-6:
            break
    assert ratio < 1e-6
    # interior: away from the platens (two layers)
    inner = (z > 2 * D) & (z < h - 2 * D)
    x0 = fcc_lattice(*shape, D)
    u = st.x - x0
    A = np.c_[x0[inner], np.ones(inner.sum())]
    grad = np.linalg.lstsq(A, u[inner], rcond=None)[0][:3].T  # du_i/dx_j
    e_ax = grad[2, 2]
    e_lat = 0.5 * (grad[0, 0] + grad[1, 1])
    valid = st.nbr >= 0
    j = np.where(valid, st.nbr, 0)
    br = st.x[j] - st.x[:, None, :]
    dist = np.where(valid, np.linalg.norm(br, axis=-1), D)
    fn = 0.5 * KN * (dist - D)
    f = fn[..., None] * br / dist[..., None] + st.fs
    sig = 0.5 * np.einsum("nwa,nwb->nab", np.where(valid[..., None], f, 0.0), br)
    full = inner & ((st.nbr >= 0).sum(axis=1) == 12)
    s = (sig[full] / (D ** 3 / math.sqrt(2))).mean(axis=0)
    E = s[2, 2] / e_ax
    nu = -e_lat / e_ax
    Kn, Ks = KN / 2, KS / 2
    E_ref = 6 * math.sqrt(2) * Kn * (Kn + Ks) / (D * (5 * Kn + Ks))
    nu_ref = (Kn - Ks) / (5 * Kn + Ks)
    print(f"E = {E:.5g} (ref {E_ref:.5g}, {E / E_ref - 1:+.2%}); nu = {nu:.4f} "
          f"(ref {nu_ref:.4f}); lateral stress / axial = {s[0, 0] / s[2, 2]:.2e}")
    assert abs(s[0, 0]) < 0.02 * abs(s[2, 2])  # uniaxial stress state
    assert E == pytest.approx(E_ref, rel=0.01)
    assert nu == pytest.approx(nu_ref, rel=0.01)
