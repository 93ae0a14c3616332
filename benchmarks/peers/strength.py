"""A strength check in geodem and in Yade: the bonded block of ``elastic.py`` pulled apart, the
same bond strengths, the same peak stress? (issue: peers side by side.)

The block, the springs and the grips are those of ``elastic.py`` (equal spheres on geodem's
FCC lattice, close-packed layers normal to z, Yade's JCFpm springs given to geodem, rotation
blocked in Yade, the bottom layer held in z, the top layer moved). Here the top layer moves up
at a constant speed, undamped, slowly (the peak is reached after some 400 wave transits), until
the block breaks. Bond strengths, JCFpm's: a bond breaks in tension when its normal force
reaches ``FnMax = T pi R^2`` and in shear when its shear force exceeds ``FsMax + Fn tan(phi)``
(``FsMax = c pi R^2``, Fn compression positive), Scholtes & Donze 2012 (Int. J. Rock Mech.
Min. Sci. 52). geodem's law is the same criterion (docs/physics.md): ``xb = FnMax / Kn_i``
(``Kn_i = 2 kn``, the element's spring), ``Fs0 = FsMax``, ``mu = tan(phi)``.

Two cases: ``tension`` (c out of reach: the bonds fail in tension) and ``shear`` (T out of
reach: the bonds fail by Mohr-Coulomb shear). On the infinite lattice a uniform uniaxial
stress loads the six bonds that leave a close-packed layer alike, so the exact strength is the
stress at which they reach the criterion (:func:`exact_strength`); the finite block breaks
first where its surface concentrates the load.

    apt-get install -y yade
    python benchmarks/peers/strength.py --m 16              # 4,096 spheres, both cases

Prints the peak stress of each code per case, the exact lattice strength and the ratios.
docs/performance.md ("Peers side by side") holds measured figures.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from elastic import (D, POISSON, RHO, YADE_BLOCK, YADE_LAW, YOUNG, compliance,  # noqa: E402
                     gripped_block)

PHI = math.atan(0.5)  # friction angle of the bonds [rad]: mu = 0.5 in geodem
E_PEAK = 2.0e-4  # the axial strain at which the bonds of the lattice reach their strength
RAMP_TRANSITS = 400  # wave transits of the block until E_PEAK: quasi-static
SAMPLE = 20  # steps between two samples of the top reaction
CASES = ("tension", "shear")


# -------------------------------------------------------------------------------- exact
def bond_loads(kn: float, ks: float, d: float = D):
    """Normal (tension +) and shear force [N] of each of an element's 12 bonds per unit
    uniaxial stress along z [Pa] on the infinite lattice: ``(directions, fn, fs)``."""
    from geodem.build.lattice import fcc_lattice

    x = fcc_lattice(5, 5, 5, d)
    b = x - x[62]  # an interior sphere
    n = b[np.abs(np.linalg.norm(b, axis=1) - d) < 1e-9 * d] / d
    strain = compliance(kn, ks, d)  # per unit sigma_zz
    eps = np.array([[strain[0], strain[5], strain[4]],
                    [strain[5], strain[1], strain[3]],
                    [strain[4], strain[3], strain[2]]])
    u = d * n @ eps  # relative displacement of the partner per unit stress
    un = np.einsum("bi,bi->b", u, n)
    us = np.linalg.norm(u - un[:, None] * n, axis=1)
    return n, kn * un, ks * us


def bond_strengths(case: str, kn: float):
    """``(FnMax, FsMax)`` [N] of the case: the one that fails the bonds at ``E_PEAK`` on the
    lattice, the other out of reach (1e6 x)."""
    ks = POISSON * kn
    strain_z = compliance(kn, ks)[2]
    _, fn, fs = bond_loads(kn, ks)
    sigma = float(E_PEAK / strain_z)  # the stress at E_PEAK
    if case == "tension":
        fn_max = float(fn.max()) * sigma  # the most stretched bonds
        return fn_max, 1e6 * fn_max
    fs_max = float((fs + fn * math.tan(PHI)).max()) * sigma  # the nearest to Mohr-Coulomb
    return 1e6 * fs_max, fs_max


def exact_strength(kn: float, fn_max: float, fs_max: float) -> float:
    """The uniaxial tensile stress [Pa] at which the first bonds of the infinite lattice reach
    the tensile or the Mohr-Coulomb criterion."""
    _, fn, fs = bond_loads(kn, POISSON * kn)
    out = math.inf
    for a, s in zip(fn, fs):
        if a > 0:
            out = min(out, fn_max / a)
        if s + a * math.tan(PHI) > 0:
            out = min(out, fs_max / (s + a * math.tan(PHI)))
    return out


def _loading(height: float, kn: float) -> tuple[float, float]:
    """Speed of the top layer [m/s] and duration [s] of the pull: E_PEAK after
    RAMP_TRANSITS transits of a compression wave, 1.5 E_PEAK at the end."""
    c = math.sqrt(kn / (RHO * D)) * 2.0  # ~ the lattice's wave speed (order of magnitude)
    t_peak = RAMP_TRANSITS * height / c
    return E_PEAK * height / t_peak, 1.5 * t_peak


def _area(top) -> float:
    return int(np.count_nonzero(top)) * math.sqrt(3.0) / 2.0 * D * D


# ------------------------------------------------------------------------------- geodem
def run_geodem(x: np.ndarray, kn: float, ks: float, fn_max: float, fs_max: float) -> dict:
    """The peak stress [Pa] of the block pulled apart in geodem (numba) and its strain."""
    from geodem.core.engine import Simulation

    st, top, height = gripped_block(x, kn, ks, xb=fn_max / (2.0 * kn), fs0=fs_max,
                                    mu=math.tan(PHI))
    sim = Simulation(st, backend="numba", monitor_every=0)
    st = sim.sync()
    speed, duration = _loading(height, kn)
    st.v[top, 2] = speed
    samples = []

    def sample(s):
        t = s.sync()
        # the top layer's reaction: the block pulls it down (tension positive)
        samples.append((t.time, -float((t.m[top] * t.a[top, 2]).sum())))

    sim.run(int(math.ceil(duration / st.dt)), callback=sample, every=SAMPLE)
    return _peak(samples, speed, height, _area(top), st.dt)


def _peak(samples, speed, height, area, dt) -> dict:
    t, f = np.array(samples).T
    k = int(np.argmax(f))
    return {"peak_stress": float(f[k] / area), "peak_strain": float(speed * t[k] / height),
            "final_stress": float(f[-1] / area), "dt": float(dt), "samples": len(f)}


# --------------------------------------------------------------------------------- Yade
YADE = textwrap.dedent('''
    import json, sys
    import numpy as np
    x = np.load(sys.argv[1]); out = sys.argv[2]
    d, speed, duration, sample = {d!r}, float(sys.argv[3]), float(sys.argv[4]), {sample!r}
    O.materials.append(JCFpmMat(type=1, density={rho!r}, young={young!r}, poisson={poisson!r},
                                frictionAngle={phi!r}, tensileStrength=float(sys.argv[5]),
                                cohesion=float(sys.argv[6])))
    {block}
    rows = []
    def record():
        rows.append((O.time, -sum(O.forces.f(i)[2] for i in top)))
    O.engines = {law} + [NewtonIntegrator(damping=0.0),
                         PyRunner(command="record()", iterPeriod=sample)]
    O.dt = 0.5 * PWaveTimeStep()
    for i in top:
        O.bodies[i].state.vel = (0, 0, speed)
    O.run(int(duration / O.dt) + 1, True)
    np.savez(out, rows=np.array(rows), top=np.array(top), dt=O.dt,
             kn=np.array([i.phys.kn for i in O.interactions if i.isReal]))
''').format(d=D, sample=SAMPLE, rho=RHO, young=YOUNG, poisson=POISSON, phi=PHI,
         block=YADE_BLOCK.strip(), law=YADE_LAW)


def run_yade(x: np.ndarray, threads: int, tmp: Path, kn: float, fn_max: float,
             fs_max: float) -> dict | None:
    """The peak stress of the block pulled apart in Yade (JCFpm); None if Yade is missing."""
    exe = shutil.which("yade") or shutil.which("yade-batch")
    if exe is None:
        return None
    height = x[:, 2].max() - x[:, 2].min()
    speed, duration = _loading(height, kn)
    section = math.pi * (0.5 * D) ** 2  # JCFpm's bond cross-section, pi min(R)^2
    np.save(tmp / "x.npy", x)
    (tmp / "yade_strength.py").write_text(YADE)
    subprocess.run([exe, "-n", "-x", "-j", str(threads), str(tmp / "yade_strength.py"),
                    str(tmp / "x.npy"), str(tmp / "yade.npz"), *(repr(float(v)) for v in
                                             (speed, duration, fn_max / section,
                                              fs_max / section))],
                   check=True, cwd=tmp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    r = np.load(tmp / "yade.npz")
    top = np.zeros(len(x), bool)
    top[r["top"]] = True
    out = _peak([tuple(row) for row in r["rows"]], speed, height, _area(top), float(r["dt"]))
    out["kn"] = float(np.median(r["kn"]))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--m", type=int, default=16, help="spheres along each edge (m^3 spheres)")
    ap.add_argument("--cases", default=",".join(CASES), help="tension, shear or both")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", help="also write the results to this file")
    a = ap.parse_args(argv)
    from geodem.build.lattice import fcc_lattice

    cases = [c for c in a.cases.split(",") if c]
    bad = [c for c in cases if c not in CASES]
    if bad:
        ap.error(f"--cases {','.join(bad)}: allowed {', '.join(CASES)}")
    x = fcc_lattice(a.m, a.m, a.m, D)
    kn = YOUNG * 0.5 * D  # JCFpm's spring for equal spheres, kn = E R (elastic.py reads it)
    res = {"elements": len(x), "kn": kn, "ks": POISSON * kn, "cases": {}}
    print(f"{len(x):,} spheres, kn = {kn:.4g} N/m, ks = {POISSON * kn:.4g} N/m, "
          f"tan(phi) = {math.tan(PHI):.3g}")
    for case in cases:
        fn_max, fs_max = bond_strengths(case, kn)
        exact = exact_strength(kn, fn_max, fs_max)
        with tempfile.TemporaryDirectory() as tmp:
            yade = run_yade(x, a.threads, Path(tmp), kn, fn_max, fs_max)
        geo = run_geodem(x, kn, POISSON * kn, fn_max, fs_max)
        res["cases"][case] = {"FnMax": fn_max, "FsMax": fs_max, "exact": exact,
                              "geodem": geo, "yade": yade}
        print(f"{case}: FnMax = {fn_max:.4g} N, FsMax = {fs_max:.4g} N; exact lattice "
              f"strength {exact:.4g} Pa")
        for name, r in (("geodem", geo), ("Yade JCFpm", yade)):
            if r is not None:
                print(f"{name:>13}: peak {r['peak_stress']:.4g} Pa ({r['peak_stress'] / exact:.4f}"
                      f" x exact) at strain {r['peak_strain']:.4g}; after it "
                      f"{r['final_stress']:.3g} Pa")
        if yade is not None and abs(yade["kn"] / kn - 1.0) > 1e-9:
            print(f"   Yade's bonds have kn = {yade['kn']:.6g} N/m, not E R = {kn:.6g}: the "
                  "two codes do not run the same springs")
        if yade is None:
            print("   Yade JCFpm: not run (apt-get install -y yade)")
        else:
            print(f"geodem / Yade: peak stress {geo['peak_stress'] / yade['peak_stress']:.4f}, "
                  f"strain {geo['peak_strain'] / yade['peak_strain']:.4f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
