"""``geodem study scale``: what a model costs as its element count grows, as measured curves.

For each model family and size N (3-D):

* **build** [s]: from nothing to a bonded state with its neighbour rows (packing, bonding, rows);
* **memory** [B/element]: the state's arrays and the backend's own buffers (``geodem bench``);
* **element-steps/s**: ``geodem.bench.bench_one`` (a whole ``Simulation.run``, checks and
  rebuilds included) and the bare step;
* **checkpoint** [s]: ``geodem.core.checkpoint.save_state`` of the state;
* **output** [s]: one frame of positions and velocities appended to an HDF5 file and flushed
  (``geodem.io.h5``), and one ``.vtp`` frame (``geodem.io.vtk``);
* **the disk** [s]: a plain write of as many bytes as the checkpoint and the ``.vtp`` frame,
  the baseline their growth is judged against (:data:`DISK_BASELINE`); every write is timed
  :data:`IO_REPEAT` times and the best kept.

Families (``FAMILIES``):

* ``lattice``: the bench block (``geodem.bench.build_specimen``): a perturbed FCC lattice with
  random radii, bonded, ~12 contacts per element;
* ``isotropic``: the lab specimens' random packing (``geodem.build.isotropic.isotropic_packing``:
  random radii jammed by FIRE, then made stress-free), bonded, in a cube;
* ``granular``: the ``lattice`` block with every bond cut (unbonded frictional contacts), as a
  granular flow steps;
* ``thermal``: a block (equal spheres on an FCC lattice jittered by 1 % of d, bonded)
  with the thermal field (conduction and expansion, ``geodem.fields.thermal``);
* ``pore``: that block with the pore-fluid field (``geodem.fields.pore``; a fluid 1,000 times
  more compressible than water, so that the block's time step stays stable). Not the
  ``lattice`` block, whose vibration (up to ~70 m/s) makes the pore field rebuild its network
  at nearly every step (20 rebuilds in 22 couplings at 10⁴ elements); this one's jitter
  against bonds of rest length d sets it vibrating too (up to ~15 m/s; 4 rebuilds in 20
  couplings at 10⁴ elements, docs/performance.md).
* ``terrain``: the 3-D landslide's hill (``geodem.geo.synthetic``: 600 m x 300 m, 100 m of
  relief, 10 m of rock below its lowest point) built as a workflow builds it: a ``scene``
  model over the elevation raster (read with rasterio, the ground sampled at every element),
  filled with the close-packed lattice, the slide region under its sliding-surface raster,
  the base and sides as groups, bonded; d chosen for about N elements;
* ``pore_isotropic``: the ``isotropic`` packing (the lab specimens' rock: random, jammed,
  stress-free, so at rest) with that pore field: its network is the one a 3-D fluid scene in
  rock has, with few near-flat cells, so it measures the field's cost per coupling rather than
  the lattice's re-triangulations.
  A field's attach time (the pore network) counts in the build; ``FIELD_STEPS`` timed steps.
  The pore families step at ``FIT_DT`` of the fluid's stability bound where that is below
  the solid's time step (recorded as ``dt_s``, ``dt_fitted``).

Each measured curve is compared with the ideal linear cost: its local exponent between the two
largest sizes, ``log(c2 / c1) / log(N2 / N1)``, is reported, and a cost growing faster than
N log N (exponent above ``1 + 1 / ln N1 + SLACK``) is flagged. A family whose build at one size
took longer than ``max_build_s`` is not built at larger sizes; the projected build time there is
reported instead.
"""
from __future__ import annotations

import json
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

FAMILIES = ("lattice", "isotropic", "granular", "terrain", "thermal", "pore", "pore_isotropic")
FIELD_STEPS = 20  # timed steps of the families with a coupled field (the pore field is slow)
DEFAULT_SIZES = (1000, 10_000, 100_000, 1_000_000)
SLACK = 0.1  # exponent allowance over N log N (timer noise, cache effects)
D = 0.01  # element diameter of the isotropic and the at-rest blocks [m]


def _lattice(n):
    from geodem.bench import build_specimen

    return build_specimen(n, dim=3), {}


def _granular(n):
    st, info = _lattice(n)
    st.cstate[st.cstate == 1] = 0  # cut every bond: contacts only (Coulomb friction)
    return st, info


def _isotropic(n):
    from geodem.build.isotropic import PHI_BULK, isotropic_packing
    from geodem.build.lattice import bonded_state
    from geodem.core.neighbors import build_rows, spatial_sort

    side = (n * math.pi / 6.0 * D ** 3 / PHI_BULK) ** (1.0 / 3.0)
    x, r, rep = isotropic_packing([side] * 3, D, n=n)
    kn = 1.0e9 * D
    st = bonded_state(x, r, density=2650.0, kn=kn, ks=kn / 3.0, xb=1.0 * D, fs0=1.0e3 * kn * D,
                      mu=0.5, gap=0.05 * D)
    st.skin = 0.3 * D
    build_rows(st)
    spatial_sort(st)
    # what the jamming took: compression cycles and minimiser (FIRE) iterations in all
    return st, {"jam_cycles": int(rep["jam_cycles"]),
                "fire_iterations": int(rep["fire_iterations"]), "packing_s": float(rep["time_s"])}


def _at_rest(n):
    """Equal spheres (diameter 1 cm) on an FCC lattice, jittered by up to 1 % of d (a regular
    lattice has no unique pore network), every pair within 3 % of d bonded."""
    from geodem.build.lattice import bonded_state, fcc_lattice, lattice_shape

    x = fcc_lattice(*lattice_shape(n, 3), D)
    x += np.random.default_rng(0).uniform(-0.01, 0.01, x.shape) * D
    kn = 1.0e9 * D
    st = bonded_state(x, 0.5 * D, density=2650.0, kn=kn, ks=kn / 3.0, xb=0.1 * D,
                      fs0=1.0e3 * kn * D, mu=0.5, gap=0.03 * D)
    return st, {}


def _terrain(n):
    from geodem.geo import synthetic as hill
    from geodem.workflow.runner import prepare

    x, y, _ = hill.grid()
    z = hill.hill_elevation(x, y)
    base = 10.0
    volume = float((z - z.min() + base).sum()) * hill.DX ** 2
    d = (volume * math.sqrt(2.0) / n) ** (1.0 / 3.0)  # FCC: sqrt(2) / d^3 elements per m^3
    with tempfile.TemporaryDirectory(prefix="geodem-scale-") as tmp:
        ground, slip = hill.write_hill(tmp)
        doc = {"metadata": {"name": "scale_terrain", "seed": 0},
               "model": {"type": "scene", "dim": 3, "d": d, "material": "rock",
                         "domain": {"terrain": {"raster": str(ground), "base_depth": base}},
                         "regions": [{"name": "slide", "material": "rock", "shape": {
                             "surface": {"depth_raster": str(slip), "side": "above"}}}],
                         "groups": {"sides": {"side": ["xmin", "xmax", "ymin", "ymax"]},
                                    "base": {"side": "zmin"}, "slide": {"region": "slide"}},
                         "gravity": [0.0, 0.0, -9.81]},
               "materials": {"rock": {"dim": 3, "rho": 2500.0, "kn_per_d": 6.667e8,
                                      "ks_per_d": 2.667e8, "xb_per_d": 0.01667,
                                      "fs0_per_d2": 3.333e7, "mu": 0.6}},
               "steps": [{"kind": "fix", "group": "base"}]}
        wf = Path(tmp) / "terrain.yaml"
        wf.write_text(json.dumps(doc))
        st = prepare(wf).built.state
    return st, {"d": d}


def _thermal_field():
    from geodem.fields.thermal import ThermalField

    return ThermalField(k=3.0, c=800.0, alpha=1.0e-5)


def _pore_field():
    from geodem.fields.pore import WATER_KF, PoreField

    return PoreField(k_f=1000.0 * WATER_KF)


BUILDERS = {"lattice": _lattice, "isotropic": _isotropic, "granular": _granular,
            "terrain": _terrain, "thermal": _at_rest, "pore": _at_rest,
            "pore_isotropic": _isotropic}
FIELDS = {"thermal": (_thermal_field,), "pore": (_pore_field,),
          "pore_isotropic": (_pore_field,)}
#: the pore families step at most this fraction of the fluid's stability bound: the bound is
#: set by the smallest pore, which shrinks as the network grows (the at-rest block at 10^6:
#: 1.82e-6 s, below its solid's 2.09e-6 s), so a fixed time step fails at some size
FIT_DT = {"pore": 0.8, "pore_isotropic": 0.8}


def _timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


#: each writer (and the plain write of its bytes) is timed this many times, the best kept: a
#: single write of a 10^6-element frame read 0.40-0.72 s in one process, the first to a new
#: file the slowest (the page cache growing), and one-shot exponents between 10^5 and 10^6
#: scattered from 0.8 to 1.8
IO_REPEAT = 3


def _best(fn, *args) -> float:
    """The shortest of :data:`IO_REPEAT` timings of ``fn(*args)`` [s]."""
    return min(_timed(fn, *args)[1] for _ in range(IO_REPEAT))


def _io_costs(state, folder) -> dict:
    """Seconds to write a checkpoint, an HDF5 frame (positions, velocities) and a .vtp frame,
    and a plain write of as many bytes as the checkpoint and the frame (the best of
    :data:`IO_REPEAT` each)."""
    from geodem.core.checkpoint import save_state
    from geodem.io.h5 import H5Writer
    from geodem.io.vtk import write_vtp

    def h5_frame():
        h5 = H5Writer(folder / "out.h5")
        for name in ("position", "velocity"):
            h5.series(f"particles/all/{name}", shape=state.x.shape)
            h5.append(f"particles/all/{name}", state.step, state.time,
                      state.x if name == "position" else state.v)
        h5.close()
        (folder / "out.h5").unlink()

    ckpt = _best(save_state, state, folder / "ckpt.npz")
    size = os.path.getsize(folder / "ckpt.npz")
    h5_s = _best(h5_frame)
    vtk_s = _best(write_vtp, folder / "frame.vtp", state.x, {"radius": state.r,
                                                             "velocity": state.v})
    vtk_size = os.path.getsize(folder / "frame.vtp")
    for f in ("ckpt.npz", "frame.vtp"):
        (folder / f).unlink(missing_ok=True)
    return {"checkpoint_s": ckpt, "checkpoint_bytes_per_element": size / state.n,
            "h5_frame_s": h5_s, "vtk_frame_s": vtk_s,
            "checkpoint_disk_s": _best(_raw_write, folder / "raw.bin", size),
            "vtk_disk_s": _best(_raw_write, folder / "raw.bin", vtk_size)}


def _raw_write(path, nbytes: int) -> None:
    """Write ``nbytes`` bytes as the writers do (a new file, renamed into place) with nothing
    to compute: the baseline of the writers' cost at that size (page cache and disk, which
    slow down per byte as files grow past caches; the buffer's own pages are touched too, as
    a writer's are)."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(memoryview(np.ones(int(nbytes), np.uint8)))
    os.replace(tmp, path)
    path.unlink()


def measure(family: str, n: int, backend: str = "numba", steps: int | None = None) -> dict:
    """One point: build, memory, throughput and I/O of ``family`` at about ``n`` elements."""
    from geodem.bench import bench_one
    from geodem.build import jam_cache

    if family not in BUILDERS:
        raise ValueError(f"family {family!r}: allowed: {', '.join(FAMILIES)}")
    with jam_cache.off():  # the build is measured: jammed anew, never read back
        (state, info), build = _timed(BUILDERS[family], int(n))
    rec = {"family": family, "n_requested": int(n), "n": int(state.n), "build_s": build, **info}
    with tempfile.TemporaryDirectory(prefix="geodem-scale-") as tmp:
        rec.update(_io_costs(state, Path(tmp)))
    fields = FIELDS.get(family, ())
    if fields and steps is None:
        steps = FIELD_STEPS
    b = bench_one(state, backend, steps=steps, copy=False, fields=fields,
                  fit_dt=FIT_DT.get(family))
    rec.update({k: b[k] for k in ("element_steps_per_s", "kernel_element_steps_per_s",
                                  "bytes_per_element", "contacts_per_element", "steps",
                                  "rebuilds", "threads", "backend", "dt_s", "dt_fitted")})
    if fields:  # the field's set-up is part of building the model
        rec["field_attach_s"] = b["field_attach_s"]
        rec["field_network_updates"] = b.get("field_network_updates")
        rec["field_stable_dt_s"] = b.get("field_stable_dt_s")
        rec["field_mechanical_dt_bound_s"] = b.get("field_mechanical_dt_bound_s")
        rec["build_s"] += b["field_attach_s"]
    return rec


def exponent(points, key) -> float | None:
    """Local exponent of ``key`` against N between the two largest sizes of ``points``."""
    pts = sorted((p for p in points if p.get(key) and p[key] > 0), key=lambda p: p["n"])
    if len(pts) < 2:
        return None
    a, b = pts[-2], pts[-1]
    return math.log(b[key] / a[key]) / math.log(b["n"] / a["n"])


#: the writers' costs and the machine's own write of the same bytes (:func:`_raw_write`)
DISK_BASELINE = {"checkpoint_s": "checkpoint_disk_s", "vtk_frame_s": "vtk_disk_s"}


def projected_build(done, n) -> float:
    """The build time [s] projected at ``n`` elements from the points ``done`` of one family:
    the largest point's, at least linear in N (its exponent from the two largest points where
    that is steeper). A random packing above ``TILE_ABOVE`` elements is one periodic cell
    repeated (:func:`geodem.build.isotropic.tiled_packing`), whose jamming (``packing_s``)
    does not grow with N: only the rest of that build is scaled (the 10^5 and 10^6 random
    packings were jammed in 645 and 377 s)."""
    from geodem.build.isotropic import TILE_ABOVE

    last = done[-1]
    e = max(exponent(done, "build_s") or 1.0, 1.0)
    fixed = 0.0
    if last.get("packing_s") is not None and last["n"] > TILE_ABOVE:
        fixed = float(last["packing_s"])
        e = 1.0
    return fixed + (last["build_s"] - fixed) * (n / last["n"]) ** e


def verdict(points, key) -> dict:
    """Exponent of a cost against N and whether it grows faster than N log N. A writer's cost
    is judged beyond the machine's own write of its bytes (:data:`DISK_BASELINE`): with
    ``e_disk`` the baseline's exponent, ``exponent_beyond_disk = e - e_disk + 1`` is the
    exponent the writer would have on a disk as fast per byte at every size, and the flag
    reads it (``disk_exponent`` is reported beside)."""
    e = exponent(points, key)
    if e is None:
        return {"exponent": None, "faster_than_n_log_n": None}
    n1 = sorted(p["n"] for p in points if p.get(key))[-2]
    out = {"exponent": e}
    judged = e
    base = DISK_BASELINE.get(key)
    e_disk = exponent(points, base) if base else None
    if e_disk is not None:
        judged = e - e_disk + 1.0
        out.update(disk_exponent=e_disk, exponent_beyond_disk=judged)
    out["faster_than_n_log_n"] = bool(judged > 1.0 + 1.0 / math.log(n1) + SLACK)
    return out


def scale_study(out, families=FAMILIES, sizes=DEFAULT_SIZES, backend="numba",
                max_build_s: float = 600.0, progress=None) -> dict:
    """Measure every family at every size (skipping larger sizes after a build over
    ``max_build_s``); writes scale.json, scale.csv and scale.png into ``out``. A point that
    fails (a field's stability bound, memory) is kept in ``failed`` with its error, the
    family's larger sizes are skipped, and the other families go on."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for f in families:
        if f not in BUILDERS:
            raise ValueError(f"--families: {f!r} unknown; allowed: {', '.join(FAMILIES)}")
    points, skipped, failed = [], [], []
    for fam in families:
        BUILDERS[fam](200)  # compile the builder's kernels first: not part of the curve
        done = []
        for n in sorted(sizes):
            if failed and failed[-1]["family"] == fam:  # larger sizes fail as well, or worse
                skipped.append({"family": fam, "n": int(n), "after_failure": True})
                continue
            proj = projected_build(done, n) if done else 0.0
            if done and done[-1]["build_s"] > max_build_s and proj > max_build_s:
                skipped.append({"family": fam, "n": int(n), "projected_build_s": proj})
                if progress:
                    progress(f"{fam:9s} {n:>9,}: skipped (build projected at {proj:,.0f} s)")
                continue
            try:
                rec = measure(fam, n, backend)
            except Exception as exc:  # noqa: BLE001 - one point failed: say it, keep the rest
                failed.append({"family": fam, "n": int(n),
                               "error": f"{type(exc).__name__}: {exc}"})
                if progress:
                    progress(f"{fam:9s} {n:>9,}: FAILED: {failed[-1]['error']}")
                continue
            done.append(rec)
            points.append(rec)
            if progress:
                progress(describe(rec))
    summary = {fam: {k: verdict([p for p in points if p["family"] == fam], k)
                     for k in ("build_s", "checkpoint_s", "h5_frame_s", "vtk_frame_s")}
               for fam in families}
    res = {"backend": backend, "points": points, "skipped": skipped, "failed": failed,
           "growth": summary, "machine": _machine()}
    (out / "scale.json").write_text(json.dumps(res, indent=2))
    _csv(out / "scale.csv", points)
    plot(res, out / "scale.png")
    return res


def _machine() -> dict:
    import platform

    from geodem.threads import numba_threads

    return {"cpu_count": os.cpu_count(), "numba_threads": numba_threads(),
            "platform": platform.platform()}


def _csv(path, points):
    keys = ["family", "n", "build_s", "bytes_per_element", "element_steps_per_s",
            "kernel_element_steps_per_s", "checkpoint_s", "h5_frame_s", "vtk_frame_s",
            "checkpoint_disk_s", "vtk_disk_s", "rebuilds", "steps", "contacts_per_element", "field_network_updates"]
    rows = [",".join(keys)] + [",".join(str(p.get(k, "")) for k in keys) for p in points]
    Path(path).write_text("\n".join(rows) + "\n")


def describe(rec) -> str:
    jam = (f" (jamming: {rec['jam_cycles']} cycles, {rec['fire_iterations']:,} FIRE "
           "iterations)" if "fire_iterations" in rec else "")
    return (f"{rec['family']:9s} {rec['n']:>9,}: build {rec['build_s']:8.2f} s{jam}, "
            f"{rec['bytes_per_element']:6.0f} B/element, {rec['element_steps_per_s']:.3g} "
            f"element-steps/s (kernels {rec['kernel_element_steps_per_s']:.3g}), checkpoint "
            f"{rec['checkpoint_s']:.3f} s, h5 frame {rec['h5_frame_s']:.3f} s, vtk frame "
            f"{rec['vtk_frame_s']:.3f} s"
            + (f", {rec['field_network_updates']} network updates in {rec['steps']} steps"
               if rec.get("field_network_updates") is not None else "")
            + (f", dt {rec['dt_s']:.3g} s (the fluid's bound)" if rec.get("dt_fitted") else ""))


def plot(res, path) -> None:
    """Log-log charts of the costs against N, each family with the ideal linear line through
    its smallest point."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    panels = [("build_s", "build [s]"), ("element_steps_per_s", "element-steps/s"),
              ("bytes_per_element", "memory [B/element]"), ("checkpoint_s", "checkpoint [s]"),
              ("h5_frame_s", "HDF5 frame [s]"), ("vtk_frame_s", ".vtp frame [s]")]
    fig, axes = plt.subplots(2, 3, figsize=(12, 7))
    for ax, (key, label) in zip(axes.ravel(), panels):
        for fam in dict.fromkeys(p["family"] for p in res["points"]):
            pts = sorted((p for p in res["points"] if p["family"] == fam), key=lambda p: p["n"])
            n = np.array([p["n"] for p in pts], float)
            y = np.array([p[key] for p in pts], float)
            line, = ax.loglog(n, y, "o-", label=fam)
            if key in ("build_s", "checkpoint_s", "h5_frame_s", "vtk_frame_s") and len(n):
                ax.loglog(n, y[0] * n / n[0], ":", color=line.get_color(), lw=1)
        ax.set_xlabel("elements N")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(title="dotted: linear in N", fontsize=8)
    fig.suptitle(f"cost against model size (3-D, {res['backend']}, "
                 f"{res['machine']['numba_threads']} threads)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
