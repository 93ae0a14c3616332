"""What sets the friction angle of a calibrated rock: the triaxial workflow's specimen with the
library material's element parameters, one micro-parameter changed at a time.

Each variant runs ``workflows/triaxial.yaml`` at ``sigma3 = 0`` and one confining stress,
and gives the two-point friction angle ``sin phi = (K - 1) / (K + 1)`` with ``K = (sigma1(s3) -
sigma1(0)) / s3`` (Jaeger et al. 2007, the Mohr-Coulomb criterion in principal stresses) when
both stages peaked; a stage with no peak is reported as such and gives no angle. Writes
``friction.json`` and ``friction.md``.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import yaml

__all__ = ["friction_study", "DEFAULT_VARIANTS"]

#: (label, element-parameter changes) run by default
DEFAULT_VARIANTS = (("as calibrated", {}), ("mu 0.35", {"mu": 0.35}), ("mu 0.5", {"mu": 0.5}),
                    ("bond gap 0.1", {"bond_gap": 0.1}),
                    ("bond strength Weibull m 3", {"bond_strength_weibull": 3.0}),
                    ("mu 0.4", {"mu": 0.4}), ("mu 0.45", {"mu": 0.45}),
                    ("mu 0.35, bond gap 0.1", {"mu": 0.35, "bond_gap": 0.1}))


def two_point_angle(s1_0: float, s1_c: float, s3: float) -> float:
    """Friction angle [deg] of the Mohr-Coulomb line through two peaks (sigma3 = 0 and s3)."""
    k = (s1_c - s1_0) / s3
    if k <= 1.0:
        return 0.0
    return math.degrees(math.asin((k - 1.0) / (k + 1.0)))


def friction_study(out_dir, material: str = "sandstone", sigma3: float = 10e6,
                   variants=DEFAULT_VARIANTS, max_strain: float = 0.03, backend=None,
                   progress=None) -> dict:
    """Run every variant (2-D, the triaxial workflow's specimen); returns the record."""
    from geodem.materials_library import load_material
    from geodem.workflow import run_workflow

    out = Path(out_dir)
    mat = load_material(material)
    el = (mat.calibrated or {}).get("2d")
    if el is None:
        raise ValueError(f"{material} has no 2-D calibration")
    base = dict(el["element"])
    rho = float(mat.values()["rho"])
    root = Path(__file__).resolve().parents[2]
    doc = yaml.safe_load((root / "workflows" / "triaxial.yaml").read_text())
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for label, change in variants:
        w = dict(doc)
        w["materials"] = {"rock": {"rho": rho, "dim": 2, **base, **change}}
        step = dict(doc["steps"][0], confining_pressures=[0.0, float(sigma3)],
                    max_strain=float(max_strain))
        w["steps"] = [step]
        folder = out / label.replace(" ", "_")
        folder.mkdir(parents=True, exist_ok=True)
        wf = folder / "workflow.yaml"
        wf.write_text(yaml.safe_dump(w, sort_keys=False))
        t0 = time.perf_counter()
        code, s = run_workflow(wf, folder / "out", backend=backend, overwrite=True, echo=False,
                               progress=False)
        peaks = s.get("peak_strengths") or [None, None]
        row = {"variant": label, "change": change, "status": s.get("status"),
               "peak_0": peaks[0], "peak_c": peaks[1] if len(peaks) > 1 else None,
               "wall_time_s": time.perf_counter() - t0}
        if s.get("status") != "ok":
            row["error"] = s.get("error")
        if row["peak_0"] and row["peak_c"]:
            row["phi_deg"] = two_point_angle(row["peak_0"], row["peak_c"], sigma3)
        rows.append(row)
        if progress:
            progress(row)
    rec = {"material": material, "sigma3": sigma3, "max_strain": max_strain,
           "target_phi_deg": math.degrees(math.atan(float(mat.values()["mu_i"]))),
           "rows": rows}
    (out / "friction.json").write_text(json.dumps(rec, indent=2))
    (out / "friction.md").write_text(table(rec))
    return rec


def describe(row: dict) -> str:
    def mpa(v):
        return "no peak" if v is None else f"{v / 1e6:.1f} MPa"

    phi = f"phi {row['phi_deg']:.1f} deg" if "phi_deg" in row else "no angle"
    err = f" ({row['error']})" if row.get("error") else ""
    return (f"{row['variant']}: sigma1 {mpa(row['peak_0'])} at sigma3 0, {mpa(row['peak_c'])} "
            f"confined; {phi}; {row['status']}{err}; {row['wall_time_s']:.0f} s")


def table(rec: dict) -> str:
    lines = [f"| variant | peak sigma1 at 0 [MPa] | at {rec['sigma3'] / 1e6:g} MPa [MPa] | "
             "phi [deg] |", "|---|---|---|---|"]
    for r in rec["rows"]:
        a = "no peak" if r["peak_0"] is None else f"{r['peak_0'] / 1e6:.1f}"
        b = "no peak" if r["peak_c"] is None else f"{r['peak_c'] / 1e6:.1f}"
        if r.get("status") != "ok":
            b += f" ({r['status']})"
        phi = f"{r['phi_deg']:.1f}" if "phi_deg" in r else "-"
        lines.append(f"| {r['variant']} | {a} | {b} | {phi} |")
    lines.append(f"\ntarget (mu_i {math.tan(math.radians(rec['target_phi_deg'])):.3g}): phi "
                 f"{rec['target_phi_deg']:.1f} deg")
    return "\n".join(lines) + "\n"
