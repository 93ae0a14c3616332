"""Brazilian (indirect tension) and direct tension lab tests (geodem/cases/brazilian.py,
workflows/brazilian.yaml, workflows/direct_tension.yaml).

Physics checked:

* the Love-Weber stress of the contact forces (``contact_stress``) against an exact two-element
  case;
* the stress at the centre of an elastic disc squeezed by two point loads against Hertz /
  Timoshenko (``sigma_xx = 2P/(pi D t)``, ``sigma_yy = -6P/(pi D t)``), on a triangular-lattice
  disc with central springs (a classical isotropic continuum: the stress field does not depend
  on the elastic constants). Measured: within 0.8 % at D/d = 25 (4.7 % at D/d = 18, 1.3 % at
  D/d = 39; the error comes from the disc radius being defined only to about half an element
  and from the stepped lattice boundary), so 3 % is asserted;
* the same disc *with* shear springs (MatDEM's translation-only elements) does not follow the
  classical field: the shear springs also resist rigid rotation of neighbour pairs, and the
  horizontal stress at the centre is 0.16 x 2P/(pi D t) at ks/kn = 0.45 (0.6 x at 0.1); kept as
  a strict xfail; with rotating elements (``enable_rotation``) the same disc matches the
  classical field within 1 %;
* the workflow: the summary's tensile strength is exactly 2 P_peak / (pi D t) of the recorded
  curve, the disc splits along the loaded diameter; direct tension gives a positive strength
  of the same order (Brazilian / direct ~ 1.5 for this 12-d_mean disc).

The crack-start position is *not* asserted: at 12-20 elements across, the first cracks form
under the platens (offset 0.68-0.89 R over 8 packings measured), where a single element carries
the platen load and wedges its neighbours apart; the split then runs through the centre.
"""
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from geodem.build.lattice import bonded_state, triangular_lattice
from geodem.cli import app
from geodem.core import groups
from geodem.core.engine import Simulation
from geodem.core.state import enable_rotation
from geodem.workflow import WorkflowError, prepare
from geodem.workflow.schema import load_builtins

load_builtins()  # the built-in kinds first, in their usual order (the JSON schema lists them so)
from geodem.cases.brazilian import contact_stress, disc_stress  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BRAZILIAN = ROOT / "workflows" / "brazilian.yaml"
TENSION = ROOT / "workflows" / "direct_tension.yaml"


pytestmark = pytest.mark.usefixtures("one_numba_thread")


# ============================================================================ stress
def test_contact_stress_of_a_stretched_pair():
    """Two bonded elements pulled apart by delta: Fn = Kn delta (Kn = kn/2), stress
    sigma_xx = Fn L / V (tension positive), nothing else."""
    d, kn, delta = 0.01, 1.0e7, 1.0e-5
    st = bonded_state(np.array([[0.0, 0.0], [d, 0.0]]), 0.5 * d, density=2600.0, kn=kn, ks=0.4 * kn,
                      xb=1.0, fs0=1e9, mu=0.3, gap=1e-6)
    st.x[1, 0] += delta
    V = 2.0e-6
    sig = contact_stress(st, [0, 1], V)
    assert sig[0, 0] == pytest.approx(0.5 * kn * delta * (d + delta) / V, rel=1e-12)
    assert np.abs(sig).ravel()[1:].max() < 1e-12 * sig[0, 0]
    # one element alone: its half of the branch vector
    assert contact_stress(st, [0], V)[0, 0] == pytest.approx(0.5 * sig[0, 0], rel=1e-12)


def _lattice_disc(ks_over_kn, rows=50, cut=13.0, d=0.0025, P=100.0, rotation=False):
    """A triangular-lattice disc (element centres within ``cut`` d of a lattice site), squeezed
    by two opposite point loads P on its pole elements and balanced; returns the state, the
    centre, the diameter D (pole surface to pole surface) and P. ``rotation``: the elements
    turn freely (shear springs at the contact points, no rolling resistance)."""
    x = triangular_lattice(rows, rows, d)
    c = x[np.argmin(np.linalg.norm(x - x.mean(axis=0), axis=1))]
    x = x[np.linalg.norm(x - c, axis=1) <= cut * d + 1e-9 * d]
    kn = 1.0e8
    st = bonded_state(x, 0.5 * d, density=2600.0, kn=kn, ks=ks_over_kn * kn, xb=1.0, fs0=1e12,
                      mu=0.3, gap=1e-3 * d, thickness=d)
    if rotation:
        enable_rotation(st, mu_r=0.0)
    rel = st.x - c
    axis = np.flatnonzero(np.abs(rel[:, 0]) < 1e-6 * d)
    top, bot = axis[np.argmax(rel[axis, 1])], axis[np.argmin(rel[axis, 1])]
    assert rel[top, 1] == pytest.approx(-rel[bot, 1])
    groups.add_group(st, "top_pole", [top])
    groups.add_group(st, "bottom_pole", [bot])
    D = 2.0 * rel[top, 1] + d
    sim = Simulation(st, monitor_every=0)

    def load(s):
        groups.set_load(s, "top_pole", [0.0, -P])
        groups.set_load(s, "bottom_pole", [0.0, P])

    sim.change(load)
    for _ in range(20):
        if sim.balance(D / d) < 1e-7:
            break
    assert sim.unbalanced_force_ratio() < 1e-7
    return sim.sync(), c, D, P


def _centre_stress(st, c, D, d, P, a=0.2):
    """(measured, analytic) stress over the elements within a x R of the centre, over the
    region's lattice cells (sqrt(3)/2 d^2 each, thickness d), divided by 2P/(pi D t)."""
    sel = np.flatnonzero(np.linalg.norm(st.x - c, axis=1) < a * 0.5 * D)
    area = len(sel) * math.sqrt(3.0) / 2.0 * d * d
    s0 = 2.0 * P / (math.pi * D * d)
    sig = contact_stress(st, sel, area * d) / s0
    sxx, syy, _ = disc_stress(st.x[sel, 0] - c[0], st.x[sel, 1] - c[1], P, D, d)
    return sig, np.array([sxx.mean(), syy.mean()]) / s0


def test_disc_centre_stress_matches_hertz_timoshenko():
    d = 0.0025
    st, c, D, P = _lattice_disc(0.0, d=d)
    assert 24 < D / d < 27
    sig, an = _centre_stress(st, c, D, d, P)
    # the closed form at the centre itself
    sxx0, syy0, sxy0 = disc_stress(0.0, 0.0, P, D, d)
    assert sxx0 == pytest.approx(2 * P / (math.pi * D * d), rel=1e-12)
    assert syy0 == pytest.approx(-6 * P / (math.pi * D * d), rel=1e-12) and sxy0 == 0.0
    # region average (r < 0.2 R): sigma_xx is 0.968, sigma_yy -2.968 x 2P/(pi D t)
    assert sig[0, 0] == pytest.approx(an[0], rel=0.03)
    assert sig[1, 1] == pytest.approx(an[1], rel=0.03)
    assert sig[0, 0] == pytest.approx(1.0, rel=0.06)  # the Brazilian value 2P/(pi D t)
    assert abs(sig[0, 1]) < 0.02 and abs(sig[1, 0]) < 0.02  # symmetric problem


@pytest.mark.xfail(strict=True, reason="translation-only elements (MatDEM's default): shear "
                                       "springs resist rigid rotation of element pairs, so the "
                                       "disc is not a classical continuum; sigma_xx at the "
                                       "centre is ~0.16 x 2P/(pi D t) at ks/kn = 0.45")
def test_disc_centre_stress_with_shear_springs():
    d = 0.0025
    st, c, D, P = _lattice_disc(0.45, d=d)
    sig, an = _centre_stress(st, c, D, d, P)
    assert sig[0, 0] == pytest.approx(an[0], rel=0.15)


def test_disc_centre_stress_with_shear_springs_and_rotating_elements():
    """With rotating elements the shear springs act at the contact points and no longer resist
    a rigid rotation of a pair, so the lattice is a classical continuum again (the stress field
    does not depend on ks/kn). Measured: sigma_xx 0.958, sigma_yy -2.945 x 2P/(pi D t) at
    ks/kn = 0.45 against 0.968, -2.968 (1 %)."""
    d = 0.0025
    st, c, D, P = _lattice_disc(0.45, d=d, rotation=True)
    sig, an = _centre_stress(st, c, D, d, P)
    assert sig[0, 0] == pytest.approx(an[0], rel=0.03)
    assert sig[1, 1] == pytest.approx(an[1], rel=0.03)
    assert abs(sig[0, 1]) < 0.02 and abs(sig[1, 0]) < 0.02


# ============================================================================ workflows
def _run(path, out, *sets, extra=()):
    args = ["run", str(path), "-o", str(out), "--no-progress", *extra]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    return json.loads((out / "summary.json").read_text())


# the tests' own rock (lattice conversion; the shipped workflows use the calibrated sandstone):
# the crack-pattern bounds below were measured with it
ROCK = "materials.rock={E: 20.0e9, nu: 0.1, Tu: 5.0e6, Cu: 50.0e6, mu_i: 0.8, rho: 2600.0}"
# 12 d_mean across, ~130 elements, stopped at a 20 % drop (the shipped disc: 40 across, 10 %)
SMALL_DISC = ("model.diameter=0.06", "steps.brazilian.drop=0.8", ROCK)


@pytest.fixture(scope="module")
def brazilian_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("braz") / "run"
    return _run(BRAZILIAN, out, *SMALL_DISC), out


def _curve(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], float)


def test_brazilian_workflow(brazilian_run):
    s, out = brazilian_run
    assert s["status"] == "ok"
    r = s["results"]["brazilian"]
    cols, a = _curve(out / "brazilian_curve.csv")
    P = a[:, cols.index("load")]
    D, t = r["disc_diameter"], r["thickness"]
    assert D == 0.06 and t == 0.005  # 2-D: t = d_mean
    # the summary is the formula on the recorded peak
    assert s["peak_load"] == P.max() > 0
    assert s["tensile_strength"] == pytest.approx(2 * P.max() / (math.pi * D * t), rel=1e-12)
    assert np.allclose(a[:, cols.index("nominal_stress")], 2 * P / (math.pi * D * t),
                       rtol=1e-12)
    # loaded to failure: the load fell after the peak, with the disc split through its centre
    assert r["stopped_by"] == "drop" and P[-1] < 0.8 * P.max()
    assert r["displacement_at_peak"] > 0
    assert s["cracks_tensile"] > s["cracks_shear"] > 0
    # the split follows the loaded diameter: measured 0.6-0.95 of the cracks within D/8 of it
    # over 8 packings, 0.60 for this one (0.31 if the cracks were spread evenly over the disc)
    assert r["diametral_fraction"] > 0.45
    assert 0.0 <= s["crack_start_offset"] <= 1.05  # reported, not asserted near 0 (docstring)
    assert (out / "brazilian.png").stat().st_size > 1000
    # strength of the same order as the 2-D specimen's (UCS ~1.6 MPa, docs/workflows.md)
    assert 1e5 < s["tensile_strength"] < 5e6


def test_brazilian_resume_is_bit_identical(brazilian_run, tmp_path):
    full = brazilian_run[1]
    out = tmp_path / "res"
    _run(BRAZILIAN, out, *SMALL_DISC, extra=["--stop-after-steps", "15000"])
    b = _run(BRAZILIAN, out, *SMALL_DISC, extra=["--resume"])
    a = json.loads((full / "summary.json").read_text())
    assert a["state_sha256"] == b["state_sha256"]
    for k in ("tensile_strength", "peak_load", "crack_start_offset", "cracks_tensile"):
        assert a[k] == b[k], k
    assert (out / "brazilian_curve.csv").read_text() == \
        (full / "brazilian_curve.csv").read_text()


def test_direct_tension_and_brazilian_same_order(brazilian_run, tmp_path):
    s = _run(TENSION, tmp_path / "dt", ROCK)
    r = s["results"]["tension"]
    assert s["status"] == "ok" and r["stopped_by"] == "drop"
    cols, a = _curve(tmp_path / "dt" / "direct_tension_curve.csv")
    assert s["tensile_strength"] == a[:, cols.index("stress")].max() > 0
    assert s["tensile_strength"] == pytest.approx(r["peak_force"] / r["area"], rel=1e-12)
    assert r["area"] == pytest.approx(0.1 * 0.005, rel=0.1)  # width x d_mean (2-D)
    assert 0 < s["peak_strain"] < r["final_strain"]
    assert s["cracks_tensile"] > 0 and s["cracks_shear"] <= s["cracks_tensile"]
    assert r["E"] > 0
    ratio = brazilian_run[0]["tensile_strength"] / s["tensile_strength"]
    assert 1 / 3 < ratio < 3, ratio  # measured 1.46 (0.86 / 0.59 MPa)
    assert (tmp_path / "dt" / "direct_tension.png").stat().st_size > 1000


# ============================================================================ bad input
def _prepare(tmp_path, model, steps):
    wf = {"metadata": {"name": "bad"}, "model": model,
          "materials": {"rock": {"E": 20e9, "nu": 0.1, "Tu": 5e6, "Cu": 50e6, "mu_i": 0.8,
                                 "rho": 2600.0}},
          "steps": steps}
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(wf))
    with pytest.raises(WorkflowError) as err:
        prepare(p)
    return str(err.value)


DISC = {"type": "brazilian_disc", "dim": 2, "diameter": 0.1, "d_mean": 0.005, "material": "rock"}


@pytest.mark.parametrize("change, path, words", [
    ({"thickness": 0.01}, "model.thickness", "thickness is for dim: 3 only"),
    ({"diameter": 0.015}, "model.diameter", "at least 6 d_mean"),
    ({"dim": 3, "thickness": 0.004}, "model.thickness", "at least 2 d_mean"),
    ({"diameter": -0.1}, "model.diameter", "> 0"),
])
def test_bad_disc(tmp_path, change, path, words):
    msg = _prepare(tmp_path, dict(DISC, **change), [{"kind": "brazilian"}])
    assert path in msg and words in msg, msg


def test_steps_need_their_models(tmp_path):
    box = {"type": "specimen", "dim": 2, "size": [0.05, 0.1], "d_mean": 0.005, "material": "rock"}
    msg = _prepare(tmp_path, box, [{"kind": "brazilian"}])
    assert "steps[0].kind" in msg and "brazilian_disc" in msg, msg
    lat = {"type": "lattice_block", "dim": 3, "counts": [4, 4, 4], "diameter": 0.01,
           "material": "rock"}
    msg = _prepare(tmp_path, lat, [{"kind": "direct_tension"}])
    assert "'bottom' and 'top'" in msg, msg
    msg = _prepare(tmp_path, DISC, [{"kind": "brazilian", "loading_rate": 0}])
    assert "steps[0].loading_rate" in msg, msg


def test_a_disc_coarser_than_the_calibrations_check_says_so():
    """The library stiff clay's 2-D record checks its Brazilian strength on discs 120 across
    (0.94 x Tu); the shipped 40-across disc of it is warned about, the sandstone's (checked on
    the shipped disc, 40 across, 0.99 x) is not."""
    shipped = ROOT / "workflows" / "brazilian.yaml"
    clay = prepare(shipped, ["materials.rock={library: stiff_clay}"]).built.info
    (w,) = [w for w in clay["material_warnings"] if "Brazilian check" in w]
    assert "stiff_clay: the calibration's Brazilian check split discs 120 d_mean across" in w
    assert "this disc is 40 across, coarser" in w
    sand = prepare(shipped).built.info
    assert not any("Brazilian check" in w for w in sand["material_warnings"])
