"""One rock, one answer: the calibrated library sandstone (2-D) gives the same strength in the
UCS test, the triaxial test at sigma3 = 0, and its tensile strength in the Brazilian and the
direct-tension tests. Integration tier: about a minute on one core (the three-disc Brazilian
mean: slow tier)."""
from pathlib import Path

import pytest
import yaml

from geodem.materials_library import load_material
from geodem.workflow import run_workflow

ROOT = Path(__file__).resolve().parents[2]
SANDSTONE = load_material("sandstone").values()
# the triaxial workflow's specimen (the calibration's UCS specimen) and rate, in both tests
SPECIMEN = {"dim": 2, "size": [0.1, 0.2], "d_mean": 0.005, "distri_rate": 0.2,
            "material": "rock"}
ROCK = {"rock": {"library": "sandstone"}}


def _run(tmp_path, name, doc):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    code, summary = run_workflow(path, tmp_path / name, overwrite=True, echo=False,
                                 progress=False)
    assert code == 0 and summary["status"] == "ok", summary.get("error")
    return summary


def _shipped(tmp_path, name):
    code, summary = run_workflow(ROOT / "workflows" / f"{name}.yaml", tmp_path / name,
                                 echo=False, progress=False)
    assert code == 0 and summary["status"] == "ok", summary.get("error")
    return summary


def _ucs_and_triaxial(tmp_path, spec, rate):
    """UCS strength and triaxial strength at sigma3 = 0 of one specimen, at one strain rate."""
    ucs = _run(tmp_path, "ucs", {
        "metadata": {"name": "ucs", "seed": 0},
        "model": dict(spec, type="specimen"), "materials": ROCK,
        "steps": [{"kind": "uniaxial", "name": "ucs", "strain_rate": rate, "max_strain": 0.02,
                   "drop": 0.7}]})
    tri = _run(tmp_path, "triaxial", {
        "metadata": {"name": "triaxial", "seed": 0},
        "model": dict(spec, type="triaxial_box"), "materials": ROCK,
        "steps": [{"kind": "triaxial", "name": "triaxial", "confining_pressures": [0.0],
                   "strain_rate": rate, "max_strain": 0.02, "drop": 0.5}]})
    assert tri["peak_strengths"][0] is not None, "the sigma3 = 0 stage has not peaked"
    return ucs["ucs"], tri["peak_strengths"][0]


def test_the_triaxial_test_at_zero_confinement_is_the_ucs_test(tmp_path):
    # measured 2026-12-05 (turning library sandstone): 73.1 MPa (UCS) and 76.4 MPa (triaxial,
    # end layers glued to the platens), +4.5 % (five packings: test below)
    ucs, tri = _ucs_and_triaxial(tmp_path, SPECIMEN, 1.0)
    assert tri / ucs == pytest.approx(1.0, abs=0.05), (tri, ucs)


@pytest.mark.slow
@pytest.mark.validation
def test_over_five_packings_the_triaxial_at_zero_confinement_is_the_ucs_test(tmp_path):
    """One packing's peak moves by a few per cent with a 1 % change of the loading rate (the
    crack cascade after the first cracks is chaotic: the seed-3 UCS reads 74.6 / 72.4 / 76.9 /
    70.0 / 70.0 MPa at 0.98 / 0.99 / 1 / 1.01 / 1.02 /s), so the two tests are compared over
    five packings. Measured 2026-12-05 (turning library sandstone): triaxial / UCS 1.045,
    0.903, 1.034, 1.052, 1.049 (mean 1.017); about 5 minutes on one core."""
    ratios = []
    for seed in range(5):
        (tmp_path / f"seed{seed}").mkdir()
        ucs, tri = _ucs_and_triaxial(tmp_path / f"seed{seed}", dict(SPECIMEN, seed=seed), 1.0)
        ratios.append(tri / ucs)
    assert sum(ratios) / 5 == pytest.approx(1.0, abs=0.03), ratios
    assert all(abs(r - 1.0) < 0.12 for r in ratios), ratios


def _brazilian_over_tu(tmp_path, seed):
    code, s = run_workflow(ROOT / "workflows" / "brazilian.yaml", tmp_path / f"s{seed}",
                           sets=[f"metadata.seed={seed}"], echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    assert s["results"]["brazilian"]["stopped_by"] == "drop"  # it split
    return s["tensile_strength"] / SANDSTONE["Tu"]


def test_the_shipped_brazilian_disc_splits_near_the_lab_tensile_strength(tmp_path):
    """The CI slice of the test below: the shipped disc (seed 0) splits within one disc's
    measured scatter around Tu (0.75 x; seeds 0-2 read 0.75-1.30 x), far below where a disc
    too coarse for its elements or a translating rock's disc of that size peaks (2.7-3.4 x,
    docs/calibration.md)."""
    assert 0.6 < _brazilian_over_tu(tmp_path, 0) < 1.4


@pytest.mark.slow
@pytest.mark.validation
def test_the_brazilian_test_gives_the_lab_tensile_strength(tmp_path):
    """The shipped disc (40 elements across, split at a 10 % drop) on the three packings the
    sandstone was calibrated on: their mean within 15 % of the lab Tu. One disc splits from
    one flaw: measured 2026-12-05, 0.75, 1.30 and 0.92 x Tu on seeds 0-2 (mean 0.99); a
    translating rock's discs of that size peaked at 2.7-3.4 x (docs/calibration.md). About
    two minutes on one core."""
    ratios = [_brazilian_over_tu(tmp_path, seed) for seed in range(3)]
    assert sum(ratios) / 3 == pytest.approx(1.0, abs=0.15), ratios


@pytest.mark.slow
@pytest.mark.validation
def test_the_stiff_clays_brazilian_test_gives_its_tensile_strength_on_a_fine_disc(tmp_path):
    """The stiff clay's turning elements have the stiffest rolling spring of the 2-D library
    (BETA 5) and need a finer disc than the other rocks: on discs 40 / 60 / 80 / 120 elements
    across, seeds 0-4 read 1.31 / 1.27 / 1.19 / 0.96 x Tu on average (measured 2026-12-06;
    docs/calibration.md, "The Brazilian check"). On 120 across (D = 0.6 m, about 12,000
    elements; about 2 minutes per disc on one core, most of it packing) seeds 0-2 read 0.98,
    0.96 and 0.89 x Tu."""
    tu = load_material("stiff_clay").values()["Tu"]
    ratios = []
    for seed in range(3):
        code, s = run_workflow(ROOT / "workflows" / "brazilian.yaml", tmp_path / f"s{seed}",
                               sets=[f"metadata.seed={seed}", "model.diameter=0.6",
                                     "materials.rock={library: stiff_clay}"],
                               echo=False, progress=False)
        assert code == 0 and s["status"] == "ok", s.get("error")
        assert s["results"]["brazilian"]["stopped_by"] == "drop"  # it split
        ratios.append(s["tensile_strength"] / tu)
    assert sum(ratios) / 3 == pytest.approx(1.0, abs=0.15), ratios


@pytest.mark.slow
@pytest.mark.validation
def test_the_3d_brazilian_test_gives_the_lab_tensile_strength_on_a_fine_disc(tmp_path):
    """The library's 3-D sandstone (turning elements, rolling stiffness 8) on a disc 60 d_mean
    across and 10 thick (0.6 x 0.1 m, about 34,600 elements; the disc's box a strip of 5 cells
    periodic along x, flat along y and z: docs/brazilian.md, "Large 3-D discs"): seed 0 split
    at 4.16 MPa, 1.04 x the lab Tu, its first cracks 0.93 R from the centre (measured
    2026-12-07; its box jammed whole read 0.94 x on 2026-12-06). On discs 40 across the same
    rock reads 1.09-1.47 x, on 10 across about 3 x: the coarse 3-D disc is crushed under its
    platens before it splits. About 30 minutes on one core (6.5 of them the packing; a second
    run takes the jam from the packing cache)."""
    s = _run(tmp_path, "brazilian3d", {
        "metadata": {"name": "brazilian3d", "seed": 0},
        "model": {"type": "brazilian_disc", "dim": 3, "diameter": 0.6, "thickness": 0.1,
                  "d_mean": 0.01, "distri_rate": 0.2, "material": "rock",
                  "platen_friction": 0.5},
        "materials": ROCK,
        "steps": [{"kind": "brazilian", "name": "brazilian", "loading_rate": 0.1,
                   "max_strain": 0.01, "drop": 0.9}]})
    assert s["results"]["brazilian"]["stopped_by"] == "drop"  # it split
    tu = load_material("sandstone").values()["Tu"]
    assert s["tensile_strength"] / tu == pytest.approx(1.0, abs=0.15), s["tensile_strength"]


def test_the_direct_tension_test_gives_the_lab_tensile_strength(tmp_path):
    s = _shipped(tmp_path, "direct_tension")
    assert s["tensile_strength"] / SANDSTONE["Tu"] == pytest.approx(1.0, abs=0.15)
    # the stress is over the specimen's section from surface to surface (0.1 m x d_mean): the
    # width between the outermost element centres, 0.0958 m, made it 4 % too high
    assert s["results"]["tension"]["area"] == pytest.approx(0.1 * 0.005, rel=1e-4)


@pytest.mark.slow
@pytest.mark.validation
def test_the_3d_triaxial_test_at_zero_confinement_is_the_ucs_test(tmp_path):
    """3-D sandstone, 0.1 x 0.1 x 0.2 m at d_mean 10 mm (10 elements across), 0.2 /s; measured
    2026-12-06 with the library's turning 3-D sandstone: UCS 77.6 MPa, triaxial 74.8 MPa
    (-3.6 %; seed 1: 78.7 / 74.4 MPa, -5.4 %). The translating record before it: 71.3 / 69.4
    MPa (-2.6 %). With the platens' friction alone (platen_layer 0) the box was +8.7 %."""
    spec = dict(SPECIMEN, dim=3, size=[0.1, 0.1, 0.2], d_mean=0.01)
    ucs, tri = _ucs_and_triaxial(tmp_path, spec, 0.2)
    assert tri / ucs == pytest.approx(1.0, abs=0.05), (tri, ucs)
