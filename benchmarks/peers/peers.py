"""geodem beside the programs users would otherwise pick, on the same work (issue: peers side by
side). Each program runs in its own process under ``/usr/bin/time`` (peak memory); the rate is
element-steps per second of the timed steps only (set-up and warm-up excluded).

* **bonded**: a cube of equal spheres (d = 5 mm) on a face-centred cubic lattice, every
  touching pair bonded (12 bonds inside), gravity, the bottom layer fixed. geodem (numba,
  ``NUMBA_NUM_THREADS``) against Yade's JCFpm (``yade -j THREADS``; JCFpmMat,
  Ip2_JCFpmMat_JCFpmMat_JCFpmPhys bonding every pair found at the first step,
  Law2_ScGeom_JCFpmPhys_JointedCohesiveFrictionalPM, NewtonIntegrator).
* **granular**: the same cube with no bonds (frictional spheres settling on the floor): geodem's
  unbonded contacts (linear springs, Coulomb friction, history) against LIGGGHTS
  (``mpirun -np THREADS``; pair gran hooke with tangential history, a wall/gran floor).

Memory per element: (peak RSS at N - peak RSS of the same program at a small N) / (N - n_small),
so the interpreter and libraries are left out.

    apt-get install -y yade liggghts       # Debian / Ubuntu: the peers
    python benchmarks/peers/peers.py --n 100000 --threads 2 --steps 200
    python benchmarks/peers/peers.py --n 30000 --cases bonded --json out/peers.json

Prints one line per program and the ratios geodem / peer. docs/performance.md ("Peers side by
side") holds measured figures.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

D = 0.005  # sphere diameter [m]
A = D * math.sqrt(2.0)  # FCC cubic cell of touching spheres
ROOT = Path(__file__).resolve().parents[2]
SMALL = 2000  # the small model whose peak memory is subtracted


def side(n: int) -> float:
    """Edge [m] of a cube holding about ``n`` touching spheres on an FCC lattice."""
    return A * (n / 4.0) ** (1.0 / 3.0)


# ------------------------------------------------------------------------------------ geodem
GEODEM = textwrap.dedent('''
    import json, sys, time
    import numpy as np
    from geodem.build.lattice import bonded_state, fcc_lattice
    from geodem.core.engine import Simulation
    case, n, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    d = {d!r}
    m = max(2, round((n / 1.0) ** (1 / 3)))
    x = fcc_lattice(m, m, m, d)
    kn = 1.0e9 * d
    st = bonded_state(x, 0.5 * d, density=2650.0, kn=kn, ks=kn / 3.0, xb=0.1 * d,
                      fs0=1.0e3 * kn * d, mu=0.5, gap=0.01 * d)
    if case == "granular":
        st.cstate[st.cstate == 1] = 0
    st.gravity[2] = -9.81
    st.free[x[:, 2] < 0.5 * d] = 0.0
    sim = Simulation(st, backend="numba", monitor_every=0)
    sim.run(20)
    t0 = time.perf_counter()
    sim.run(steps)
    wall = time.perf_counter() - t0
    bonds = int((st.cstate == 1).sum())
    print("RESULT " + json.dumps({{"n": int(st.n), "steps": steps, "wall_s": wall,
                                  "bonds_per_element": bonds / st.n}}))
''').format(d=D)


# -------------------------------------------------------------------------------------- Yade
YADE = textwrap.dedent('''
    import json, sys, time
    from yade import pack
    n, steps, L, d = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), {d!r}
    O.materials.append(JCFpmMat(type=1, density=2650, young=1e9, poisson=0.25,
                                frictionAngle=radians(26.6), tensileStrength=1e12,
                                cohesion=1e12))
    O.bodies.append(pack.regularHexa(pack.inAlignedBox((0, 0, 0), (L, L, L)), radius=d / 2,
                                     gap=0))
    for b in O.bodies:
        if b.state.pos[2] < d / 2:
            b.state.blockedDOFs = "xyzXYZ"
    O.engines = [ForceResetter(),
                 InsertionSortCollider([Bo1_Sphere_Aabb(aabbEnlargeFactor=1.05)]),
                 InteractionLoop([Ig2_Sphere_Sphere_ScGeom(interactionDetectionFactor=1.05)],
                                 [Ip2_JCFpmMat_JCFpmMat_JCFpmPhys(cohesiveTresholdIteration=1)],
                                 [Law2_ScGeom_JCFpmPhys_JointedCohesiveFrictionalPM()]),
                 NewtonIntegrator(damping=0.0, gravity=(0, 0, -9.81))]
    O.dt = 0.5 * PWaveTimeStep()
    O.run(20, True)
    bonds = sum(1 for i in O.interactions if i.isReal and i.phys.isCohesive)
    t0 = time.time()
    O.run(steps, True)
    wall = time.time() - t0
    print("RESULT " + json.dumps({{"n": len(O.bodies), "steps": steps, "wall_s": wall,
                                  "bonds_per_element": 2.0 * bonds / len(O.bodies)}}))
''').format(d=D)


# --------------------------------------------------------------------------------- LIGGGHTS
LIGGGHTS = textwrap.dedent('''
    atom_style granular
    atom_modify map array
    boundary f f f
    newton off
    communicate single vel yes
    units si
    region reg block -0.01 {big} -0.01 {big} -0.01 {top} units box
    create_box 1 reg
    region inner block 0.0 {L} 0.0 {L} 0.0 {L} units box
    neighbor {skin} bin
    neigh_modify delay 0
    fix m1 all property/global youngsModulus peratomtype 1e9
    fix m2 all property/global poissonsRatio peratomtype 0.25
    fix m3 all property/global coefficientRestitution peratomtypepair 1 0.5
    fix m4 all property/global coefficientFriction peratomtypepair 1 0.5
    fix m5 all property/global characteristicVelocity scalar 1.0
    pair_style gran model hooke tangential history
    pair_coeff * *
    timestep {dt}
    fix gravi all gravity 9.81 vector 0.0 0.0 -1.0
    fix floor all wall/gran model hooke tangential history primitive type 1 zplane {floor}
    thermo_modify lost ignore norm no
    lattice fcc {a}
    create_atoms 1 region inner
    set group all diameter {d} density 2650
    fix integr all nve/sphere
    run 20
    run {steps}
''')


def _time_run(cmd, env=None, cwd=None):
    """Run ``cmd`` under /usr/bin/time; returns (stdout + stderr, peak RSS [bytes])."""
    timer = shutil.which("time") or "/usr/bin/time"
    p = subprocess.run([timer, "-f", "PEAKRSS %M"] + cmd, capture_output=True, text=True,
                       env=env, cwd=cwd, timeout=7200)
    out = p.stdout + p.stderr
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])} ... failed ({p.returncode}):\n{out[-3000:]}")
    rss = int(re.findall(r"PEAKRSS (\d+)", out)[-1]) * 1024
    return out, rss


def _result(out):
    return json.loads(re.findall(r"RESULT (\{.*\})", out)[-1])


def run_geodem(case, n, steps, threads, tmp):
    script = tmp / "geodem_case.py"
    script.write_text(GEODEM)
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads),
               PYTHONPATH=f"{ROOT}:{os.environ.get('PYTHONPATH', '')}")
    out, rss = _time_run([sys.executable, str(script), case, str(n), str(steps)], env=env)
    return dict(_result(out), peak_rss=rss)


def run_yade(n, steps, threads, tmp):
    script = tmp / "yade_case.py"
    script.write_text(YADE)
    exe = shutil.which("yade")
    if exe is None:
        raise FileNotFoundError("yade is not installed (apt-get install yade)")
    out, rss = _time_run([exe, "-n", "-x", "-j", str(threads), str(script), str(n), str(steps),
                          repr(side(n))])
    return dict(_result(out), peak_rss=rss)


def run_liggghts(n, steps, threads, tmp):
    exe = shutil.which("liggghts")
    if exe is None:
        raise FileNotFoundError("liggghts is not installed (apt-get install liggghts)")
    L = side(n) - 0.5 * D
    m = 1.0  # the floor sits below the lowest layer, which rests on it
    text = LIGGGHTS.format(big=L + 0.01, top=1.5 * L + 0.01, L=L, skin=0.2 * D, a=A, d=D,
                           floor=-0.5 * D * m, dt=_hooke_dt(), steps=steps)
    (tmp / "granular.in").write_text(text)
    cmd = [exe, "-in", "granular.in", "-log", "none"]
    if threads > 1:
        cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(threads)] + cmd
    out, rss = _time_run(cmd, cwd=tmp)
    loops = re.findall(r"Loop time of ([0-9.eE+-]+) on \d+ procs for (\d+) steps with (\d+) "
                       r"atoms", out)
    wall, nsteps, natoms = loops[-1]
    return {"n": int(natoms), "steps": int(nsteps), "wall_s": float(wall), "peak_rss": rss,
            "bonds_per_element": 0.0}


def _hooke_dt():
    """A step of about a tenth of the contact period sqrt(m / k) of two spheres, for LIGGGHTS'
    hooke model with Y = 1 GPa (k ~ Y d)."""
    m = 2650.0 * math.pi / 6.0 * D ** 3
    return 0.1 * math.sqrt(m / (1.0e9 * D))


RUNNERS = {
    "bonded": {"geodem": lambda n, s, t, tmp: run_geodem("bonded", n, s, t, tmp),
               "Yade (JCFpm)": run_yade},
    "granular": {"geodem": lambda n, s, t, tmp: run_geodem("granular", n, s, t, tmp),
                 "LIGGGHTS": run_liggghts},
}


def measure(cases, n, steps, threads, progress=print):
    rows = []
    with tempfile.TemporaryDirectory(prefix="geodem-peers-") as t:
        tmp = Path(t)
        for case in cases:
            for name, fn in RUNNERS[case].items():
                try:
                    big = fn(n, steps, threads, tmp)
                    small = fn(SMALL, max(2, steps // 10), threads, tmp)
                except (FileNotFoundError, RuntimeError) as exc:
                    progress(f"{case:9s} {name:14s} not run: {str(exc).splitlines()[0]}")
                    continue
                rate = big["n"] * big["steps"] / big["wall_s"]
                mem = (big["peak_rss"] - small["peak_rss"]) / max(1, big["n"] - small["n"])
                row = {"case": case, "program": name, "threads": threads, **big,
                       "element_steps_per_s": rate, "bytes_per_element": mem}
                rows.append(row)
                progress(f"{case:9s} {name:14s} {big['n']:>8,} elements, "
                         f"{big['bonds_per_element']:4.1f} bonds/element: {rate:9.3g} "
                         f"element-steps/s, {mem:6.0f} B/element")
    for case in cases:
        ours = [r for r in rows if r["case"] == case and r["program"] == "geodem"]
        for r in rows:
            if r["case"] == case and r["program"] != "geodem" and ours:
                progress(f"{case}: geodem / {r['program']}: "
                         f"{ours[0]['element_steps_per_s'] / r['element_steps_per_s']:.1f} x "
                         f"the speed, {ours[0]['bytes_per_element'] / r['bytes_per_element']:.2f}"
                         " x the memory per element")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100_000, help="elements (about)")
    ap.add_argument("--steps", type=int, default=200, help="timed steps")
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="threads / ranks")
    ap.add_argument("--cases", default="bonded,granular", help="bonded, granular")
    ap.add_argument("--json", help="write the rows to this file")
    a = ap.parse_args(argv)
    cases = [c.strip() for c in a.cases.split(",")]
    bad = [c for c in cases if c not in RUNNERS]
    if bad or a.n < 2 * SMALL or a.steps < 20 or a.threads < 1:
        ap.error(f"allowed: --cases from {', '.join(RUNNERS)}, --n >= {2 * SMALL}, "
                 "--steps >= 20, --threads >= 1")
    rows = measure(cases, a.n, a.steps, a.threads)
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
