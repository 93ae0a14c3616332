"""Time the numba step against the same step compiled by gcc (tests/perf/owner_step.c).

Usage (from the repository root, with gcc on the PATH)::

    NUMBA_NUM_THREADS=2 OMP_NUM_THREADS=2 python tests/perf/compare_c_step.py --n 100000

Builds the bench specimen (``geodem.bench.build_specimen``), runs the numba backend's stretch
of steps (``backend.steps``) and the C step from the same state, checks that they agree after
20 steps (round-off only: the C compiler orders the floating-point operations differently),
then alternates timed rounds of ``--steps`` steps (restoring the state before each), so that a
noisy machine slows both alike. Prints ms per step (best and median) and, per round, the
numba time over each C build's time. A measurement, not a test: pytest does not collect it.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FLAGS = {
    "gcc -O3": ["-O3"],
    "gcc -O3 -ffast-math": ["-O3", "-ffast-math"],
    "gcc -O3 -ffast-math, SIMD rows": ["-O3", "-ffast-math", "-DOWNER_SIMD"],
    "gcc -O3 -ffast-math, SIMD rows, 4 lanes": ["-O3", "-ffast-math", "-DOWNER_SIMD",
                                                "-mprefer-vector-width=256"],
}
CHANGED = ["x", "v", "a", "dx", "cstate", "fs", "q_visc", "q_break_n", "q_break_s", "q_fric",
           "w_ext"]


def build(folder: Path) -> dict:
    libs = {}
    for k, (name, flags) in enumerate(FLAGS.items()):
        so = folder / f"owner_step_{k}.so"
        subprocess.run(["gcc", *flags, "-march=native", "-fopenmp", "-fPIC", "-shared",
                        str(HERE / "owner_step.c"), "-o", str(so)], check=True)
        libs[name] = ctypes.CDLL(str(so))
    return libs


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000, help="elements (default 1e5)")
    ap.add_argument("--steps", type=int, default=10, help="steps per timed round")
    ap.add_argument("--rounds", type=int, default=8, help="timed rounds per kernel")
    args = ap.parse_args()

    from geodem.bench import build_specimen
    from geodem.core.engine import Simulation
    from geodem.core.state import broken_code

    sim = Simulation(build_specimen(args.n), backend="numba", monitor_every=0)
    sim.run(2)
    s, b = sim.state, sim.backend
    if not b.steps(s.dt, 1, s.step):  # compiles, and makes the owner and crossing tables
        raise SystemExit("the numba backend does not take the owner pass on this model")
    if s.hertz or s.nbr.dtype != np.int32 or s.cstate.dtype != np.int32 \
            or s.brate.dtype != np.float32 or b.buf.shape[1] != 6:
        raise SystemExit("owner_step.c expects the plain 3-D layout of the bench specimen")
    ostart, mirror = b.tables
    cstart, spill, inc_start = b.cross
    g = b._gravity()
    ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)  # noqa: E731

    def run_c(lib, nsteps):
        lib.steps(ctypes.c_int(nsteps), ctypes.c_int64(broken_code(s.step + 1, 1)),
                  ctypes.c_int64(broken_code(s.step + 1, 2)), ctypes.c_int(s.n),
                  ctypes.c_int(s.nbr.shape[1]), ptr(s.x), ptr(s.v), ptr(s.a), ptr(s.dx),
                  ptr(s.free), ptr(s.fload), ptr(s.props), ptr(s.m), ptr(s.eta), ptr(s.nbr),
                  ptr(ostart), ptr(mirror), ptr(s.cstate), ptr(s.fs), ptr(s.brate), ptr(b.buf),
                  ptr(cstart), ptr(spill), ptr(inc_start), ctypes.c_int(b.slabs),
                  ptr(s.q_visc), ptr(s.q_break_n), ptr(s.q_break_s), ptr(s.q_fric),
                  ptr(s.w_ext), *(ctypes.c_double(v) for v in g), ctypes.c_double(s.dt),
                  ctypes.c_int(int(s.hertz)), ctypes.c_int(b.ahead))

    saved = {k: getattr(s, k).copy() for k in CHANGED}
    buf0 = b.buf.copy()

    def restore():
        for k in CHANGED:
            getattr(s, k)[...] = saved[k]
        b.buf[...] = buf0

    with tempfile.TemporaryDirectory() as tmp:
        libs = build(Path(tmp))
        kernels = {"numba": lambda k: b.steps(s.dt, k, s.step)}
        kernels.update({name: (lambda k, lib=lib: run_c(lib, k)) for name, lib in libs.items()})
        restore()
        kernels["numba"](20)
        ref = {k: getattr(s, k).copy() for k in CHANGED}
        for name in libs:
            restore()
            kernels[name](20)
            worst = max(float(np.abs(getattr(s, k) - ref[k]).max() / (np.abs(ref[k]).max() or 1))
                        for k in ("x", "v", "fs"))
            same = np.array_equal(s.cstate, ref["cstate"])
            print(f"{name}: after 20 steps, largest difference from numba (x, v, fs) "
                  f"{worst:.1e} of the largest value; contact states {'equal' if same else 'DIFFER'}")
        times = {name: [] for name in kernels}
        for _ in range(args.rounds):
            for name, kern in kernels.items():
                restore()
                t0 = time.perf_counter()
                kern(args.steps)
                times[name].append((time.perf_counter() - t0) / args.steps * 1e3)
    base = np.array(times["numba"])
    threads = os.environ.get("NUMBA_NUM_THREADS", "numba's default")
    print(f"{s.n} elements, {threads} threads, {args.rounds} rounds of {args.steps} steps:")
    for name, t in times.items():
        t = np.array(t)
        print(f"  {name:>20}: best {t.min():6.2f} ms, median {np.median(t):6.2f} ms per step "
              f"({s.n / t.min() * 1e3:.3g} element-steps/s); numba / this per round, "
              f"median {np.median(base / t):.2f}")


if __name__ == "__main__":
    main()
