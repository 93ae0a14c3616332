"""A physics check in geodem and in Yade: the same bonded block, the same contact springs, the
same loading, the same Young's modulus and Poisson ratio? (issue: peers side by side.)

The block: equal spheres (d = 5 mm) on geodem's FCC lattice (close-packed layers normal to z,
``geodem.build.lattice.fcc_lattice``), every touching pair bonded, bonds that never break, no
rotation (geodem's elements translate; Yade's spheres are blocked in rotation), no gravity.
Yade's JCFpm springs come from its material (``young``, ``poisson``): ``kn = E R``, ``ks = nu
kn`` for equal spheres. They are read from Yade's interactions and given to geodem as element
springs (``Kn = kn_i kn_j / (kn_i + kn_j)``, so ``kn_i = 2 kn``). The bottom layer is held in
z (one sphere in x, y, z), the top layer moved down in z (free in x, y), so the block is in
uniaxial stress: a ramp to the strain ``EPS``, then a hold with damping until it is at rest.
E = (top reaction / top area) / strain (the area: the top layer's close-packed cells, sqrt3/2
d^2 each; the strain over the centres of the top and bottom layers); nu from the side faces'
mean displacement.

The same springs on the infinite lattice give the exact answer (the FCC lattice is a Bravais
lattice: a uniform strain is exact, no internal relaxation): ``exact()`` sums the 12 bonds of
an element, ``C_ijkl = (d^2 / V) sum (1/2) [(kn - ks) n_i n_j n_k n_l + ks d_ik n_j n_l]`` with
``V = d^3 / sqrt 2``, and inverts it for uniaxial stress along z. The finite block is softer
than that by its surface (its outer spheres have fewer bonds).

    apt-get install -y yade
    python benchmarks/peers/elastic.py --m 16        # 4,096 spheres

Prints E and nu of each code, the exact values and the ratios. docs/performance.md ("Peers side
by side") holds measured figures.
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

D = 0.005  # sphere diameter [m]
YOUNG = 1.0e9  # Yade's material modulus [Pa]: kn = E R
POISSON = 0.25  # Yade's ks / kn
RHO = 2650.0
EPS = 1.0e-4  # axial strain of the test
RAMP, HOLD = 4000, 6000  # steps


# -------------------------------------------------------------------------------- exact
def exact(kn: float, ks: float, d: float = D) -> tuple[float, float]:
    """``(E_z, nu_zx)`` of the infinite FCC lattice of ``geodem.build.lattice.fcc_lattice``
    with contact springs ``kn``, ``ks`` [N/m] (see the module docstring)."""
    e = compliance(kn, ks, d)
    return 1.0 / e[2], -0.5 * (e[0] + e[1]) / e[2]


def compliance(kn: float, ks: float, d: float = D) -> np.ndarray:
    """The strain of the infinite lattice under a unit uniaxial stress along z [1/Pa]:
    ``(e_xx, e_yy, e_zz, e_yz, e_xz, e_xy)``, tensor components (not doubled)."""
    from geodem.build.lattice import fcc_lattice

    x = fcc_lattice(5, 5, 5, d)
    c = x[62]  # an interior sphere
    b = x - c
    dist = np.linalg.norm(b, axis=1)
    n = b[np.abs(dist - d) < 1e-9 * d] / d
    assert len(n) == 12, len(n)
    vol = d ** 3 / math.sqrt(2.0)
    eye = np.eye(3)
    cijkl = 0.5 * d * d / vol * (
        (kn - ks) * np.einsum("bi,bj,bk,bl->ijkl", n, n, n, n)
        + ks * np.einsum("ik,bj,bl->ijkl", eye, n, n))
    # the six stresses (symmetrised) of the six unit strains (a shear strain sets eps_kl and
    # eps_lk); uniaxial stress: the strain whose only stress is sigma_zz = 1
    pairs = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
    m = np.zeros((6, 6))
    for b, (k, l) in enumerate(pairs):
        eps = np.zeros((3, 3))
        eps[k, l] = eps[l, k] = 1.0
        sig = np.einsum("ijkl,kl->ij", cijkl, eps)
        sig = 0.5 * (sig + sig.T)
        m[:, b] = [sig[i, j] for i, j in pairs]
    return np.linalg.solve(m, np.eye(6)[2])


# ------------------------------------------------------------------------------- geodem
def gripped_block(x: np.ndarray, kn: float, ks: float, xb: float = 1.0, fs0: float = 1.0e12,
                  mu: float = 0.5):
    """The bonded block in geodem, springs ``kn``, ``ks`` of the contact (the elements' twice
    that), bond strengths ``xb`` [m], ``fs0`` [N]: its bottom layer held in z (one sphere in
    x, y, z), its top layer in z. Returns ``(state, top mask, height)``."""
    from geodem.build.lattice import bonded_state

    st = bonded_state(x, 0.5 * D, density=RHO, kn=2.0 * kn, ks=2.0 * ks, xb=xb, fs0=fs0,
                      mu=mu, gap=0.01 * D)
    z = x[:, 2]
    bottom, top = z < z.min() + 0.1 * D, z > z.max() - 0.1 * D
    st.free[bottom, 2] = 0.0
    st.free[np.flatnonzero(bottom)[0]] = 0.0
    st.free[top, 2] = 0.0
    return st, top, z.max() - z.min()


def run_geodem(x: np.ndarray, kn: float, ks: float) -> dict:
    """E and nu of the block in geodem (numba), springs ``kn``, ``ks`` of the contact."""
    from geodem.core import timestep
    from geodem.core.engine import Simulation

    st, top, height = gripped_block(x, kn, ks)
    sim = Simulation(st, backend="numba", monitor_every=0)
    n_across = height / D
    st = sim.sync()
    st.v[top, 2] = -EPS * height / (RAMP * st.dt)
    sim.run(RAMP)
    eta = timestep.standard_damping(sim.sync(), n_across)
    sim.change(lambda s: (s.v.__setitem__((top, 2), 0.0), s.eta.__setitem__(slice(None), eta)),
               book_energy=False)
    sim.run(HOLD)
    st = sim.sync()
    return _moduli(st.x, x, st.m[:, None] * st.a, top, height)


def _moduli(x, x0, force, top, height) -> dict:
    """E and nu from the final positions ``x`` against the start ``x0`` and the force on the
    top layer (the reaction, compression positive)."""
    lo, hi = x0.min(axis=0), x0.max(axis=0)
    area = int(top.sum()) * math.sqrt(3.0) / 2.0 * D * D  # a close-packed layer's cells
    stress = float(force[top, 2].sum()) / area  # the block pushes the top layer up
    strain = -float((x[top, 2] - x0[top, 2]).mean()) / height
    lat = []
    for ax in (0, 1):
        lo_f, hi_f = x0[:, ax] < lo[ax] + 0.1 * D, x0[:, ax] > hi[ax] - 0.1 * D
        grow = (x[hi_f, ax] - x0[hi_f, ax]).mean() - (x[lo_f, ax] - x0[lo_f, ax]).mean()
        lat.append(grow / (hi[ax] - lo[ax]))
    return {"E": stress / strain, "nu": float(np.mean(lat)) / strain, "strain": strain,
            "n": int(len(x))}


# --------------------------------------------------------------------------------- Yade
#: Yade: the spheres at ``x`` (diameter ``d``) and the grips of :func:`gripped_block`
YADE_BLOCK = textwrap.dedent('''
    for p in x:
        O.bodies.append(sphere(tuple(p), d / 2))
    z = x[:, 2]
    height = z.max() - z.min()
    bottom = [i for i in range(len(x)) if z[i] < z.min() + 0.1 * d]
    top = [i for i in range(len(x)) if z[i] > z.max() - 0.1 * d]
    for b in O.bodies:
        b.state.blockedDOFs = "XYZ"
    for i in bottom:
        O.bodies[i].state.blockedDOFs = "zXYZ"
    O.bodies[bottom[0]].state.blockedDOFs = "xyzXYZ"
    for i in top:
        O.bodies[i].state.blockedDOFs = "zXYZ"
    ''')
#: Yade: JCFpm's contact detection, bonding (first step) and law
YADE_LAW = ("[ForceResetter(), InsertionSortCollider([Bo1_Sphere_Aabb(aabbEnlargeFactor=1.05)]), "
            "InteractionLoop([Ig2_Sphere_Sphere_ScGeom(interactionDetectionFactor=1.05)], "
            "[Ip2_JCFpmMat_JCFpmMat_JCFpmPhys(cohesiveTresholdIteration=1)], "
            "[Law2_ScGeom_JCFpmPhys_JointedCohesiveFrictionalPM()])]")

YADE = textwrap.dedent('''
    import json, sys
    import numpy as np
    x = np.load(sys.argv[1]); out = sys.argv[2]
    eps, ramp, hold, d = {eps!r}, {ramp!r}, {hold!r}, {d!r}
    O.materials.append(JCFpmMat(type=1, density={rho!r}, young={young!r}, poisson={poisson!r},
                                frictionAngle=radians(26.6), tensileStrength=1e15,
                                cohesion=1e15))
    {block}
    newton = NewtonIntegrator(damping=0.0)
    O.engines = {law} + [newton]
    O.dt = 0.5 * PWaveTimeStep()
    O.step()
    kn = [i.phys.kn for i in O.interactions if i.isReal]
    ks = [i.phys.ks for i in O.interactions if i.isReal]
    for i in top:
        O.bodies[i].state.vel = (0, 0, -eps * height / (ramp * O.dt))
    O.run(ramp - 1, True)
    for i in top:
        O.bodies[i].state.vel = (0, 0, 0)
    newton.damping = 0.2
    O.run(hold, True)
    pos = np.array([b.state.pos for b in O.bodies])
    f = np.array([O.forces.f(b.id) for b in O.bodies])
    np.savez(out, x=pos, f=f, top=np.array(top), kn=np.array(kn), ks=np.array(ks),
             bonds=sum(1 for i in O.interactions if i.isReal and i.phys.isCohesive))
''').format(eps=EPS, ramp=RAMP, hold=HOLD, d=D, rho=RHO, young=YOUNG, poisson=POISSON,
         block=YADE_BLOCK.strip(), law=YADE_LAW)


def run_yade(x: np.ndarray, threads: int, tmp: Path) -> dict:
    """E, nu and the contact springs of the block in Yade (JCFpm); None if Yade is missing."""
    exe = shutil.which("yade") or shutil.which("yade-batch")
    if exe is None:
        return None
    np.save(tmp / "x.npy", x)
    (tmp / "yade_elastic.py").write_text(YADE)
    subprocess.run([exe, "-n", "-x", "-j", str(threads), str(tmp / "yade_elastic.py"),
                    str(tmp / "x.npy"), str(tmp / "yade.npz")], check=True, cwd=tmp,
                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    r = np.load(tmp / "yade.npz")
    top = np.zeros(len(x), bool)
    top[r["top"]] = True
    height = x[:, 2].max() - x[:, 2].min()
    out = _moduli(r["x"], x, r["f"], top, height)
    out.update(kn=float(np.median(r["kn"])), ks=float(np.median(r["ks"])),
               kn_spread=float(np.ptp(r["kn"])), bonds_per_element=2.0 * int(r["bonds"]) / len(x))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--m", type=int, default=16, help="spheres along each edge (m^3 spheres)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", help="also write the results to this file")
    a = ap.parse_args(argv)
    from geodem.build.lattice import fcc_lattice

    x = fcc_lattice(a.m, a.m, a.m, D)
    with tempfile.TemporaryDirectory() as tmp:
        yade = run_yade(x, a.threads, Path(tmp))
    if yade is None:
        kn, ks = YOUNG * 0.5 * D, POISSON * YOUNG * 0.5 * D  # JCFpm's springs, equal spheres
        print("Yade: not run (apt-get install -y yade)")
    else:
        kn, ks = yade["kn"], yade["ks"]
    e_exact, nu_exact = exact(kn, ks)
    geo = run_geodem(x, kn, ks)
    res = {"elements": len(x), "kn": kn, "ks": ks, "exact": {"E": e_exact, "nu": nu_exact},
           "geodem": geo, "yade": yade}
    print(f"{len(x):,} spheres, kn = {kn:.4g} N/m, ks = {ks:.4g} N/m; exact (infinite lattice): "
          f"E = {e_exact:.4g} Pa, nu = {nu_exact:.4f}")
    for name, r in (("geodem", geo), ("Yade JCFpm", yade)):
        if r is not None:
            print(f"{name:>11}: E = {r['E']:.4g} Pa ({r['E'] / e_exact:.4f} x exact), "
                  f"nu = {r['nu']:.4f}")
    if yade is not None:
        print(f"geodem / Yade: E {geo['E'] / yade['E']:.4f}, nu {geo['nu'] / yade['nu']:.4f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
