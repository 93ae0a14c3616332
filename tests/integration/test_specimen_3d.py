"""3-D random bonded specimens: isotropic compression by radius expansion in a box with flat
faces, bonds within a gap tolerance made stress-free (geodem.build.isotropic), cemented.

A frictionless jammed random sphere packing has about 6 contacts per element (isostatic) and a
solid fraction of ~0.64; bonding the pairs within 0.01 d_mean adds about half a bond per
element. Because the bonded pairs are adjusted to touch, cementing starts stress-free: no bond
breaks and the specimen is in equilibrium at once.
"""
import numpy as np
import pytest
import yaml

from geodem.build import isotropic
from geodem.build.specimen import make_specimen
from geodem.core import groups
from geodem.core.state import BONDED
from geodem.workflow import run_workflow
from geodem.workflow.runner import prepare

pytestmark = pytest.mark.usefixtures("one_numba_thread")

D = 0.01
SIZE = [0.07, 0.07, 0.07]
ROCK = {"E": 15e9, "nu": 0.15, "Tu": 4e6, "Cu": 75e6, "mu_i": 0.7, "rho": 2400.0}


@pytest.fixture(scope="module")
def small():
    return make_specimen("box", SIZE, D, 0.2, ROCK, 3, seed=0)


def test_coordination_density_balance(small):
    st, rep = small
    assert 250 < rep["n_elements"] < 500
    # isostatic (6) plus the pairs bonded within the gap tolerance, in the interior
    assert rep["interior_coordination"] >= 6.0
    # random close packing ~0.64; the interior region of a small box is close to the walls
    assert 0.60 <= rep["packing_fraction"] <= 0.66
    assert rep["unbalanced_ratio"] < 1e-2
    assert rep["bonds_broken"] == 0
    assert rep["bonds"] == rep["bonds_formed"]
    # every element that is not on a face is bonded (rattlers bonded into their cages)
    per = (st.cstate == BONDED).sum(axis=1)
    assert per.min() >= 1


def test_faces_are_flat_and_touched_by_many_elements(small):
    st, _ = small
    lo = (st.x - st.r[:, None]).min(axis=0)
    hi = (st.x + st.r[:, None]).max(axis=0)
    assert np.allclose(lo, 0.0, atol=1e-5 * D)
    assert np.allclose(hi, SIZE, atol=1e-5 * D)
    face_area = SIZE[0] * SIZE[1] / D ** 2  # in d_mean^2
    for a in range(3):
        for touching in (np.abs(st.x[:, a] - st.r - lo[a]) < 1e-4 * D,
                         np.abs(st.x[:, a] + st.r - hi[a]) < 1e-4 * D):
            # a flat face: ~0.6-0.9 touching elements per d_mean^2
            assert touching.sum() > 0.4 * face_area


def test_bond_network_is_isotropic(small):
    st, _ = small
    i = np.repeat(np.arange(st.n), st.width)
    j = st.nbr.ravel()
    b = (st.cstate.ravel() == BONDED) & (j > i)
    n = st.x[j[b]] - st.x[i[b]]
    n /= np.linalg.norm(n, axis=1)[:, None]
    fabric = np.linalg.eigvalsh(n.T @ n / len(n))
    assert np.all(np.abs(fabric - 1.0 / 3.0) < 0.04), fabric


def test_stress_free_adjustment_closes_the_bonds():
    # a tiny jammed packing: every bonded pair ends touching, every face element tangent
    rng = np.random.default_rng(3)
    r0 = 0.5 * rng.uniform(0.82, 1.18, 60)
    lo, hi = np.zeros(3), np.full(3, 3.6)
    x, r, info = isotropic.jam(r0, lo, hi, seed=1)
    assert info["mean_overlap"] == pytest.approx(isotropic.DEFAULT_OVERLAP, rel=1.0)
    i, j, faces, _ = isotropic.bond_network(x, r, lo, hi, 0.01)
    xs, rs, res = isotropic.stress_free(x, r, i, j, faces, lo, hi, prestress=1e-6)
    assert res < 1e-10
    gap = np.linalg.norm(xs[j] - xs[i], axis=1) - rs[i] - rs[j]
    assert np.allclose(gap, -1e-6, atol=1e-10)
    assert np.abs(rs / r - 1.0).max() < 0.2


def _triaxial_workflow(tmp_path):
    wf = {"metadata": {"name": "tri3d_random", "seed": 0},
          "model": {"type": "triaxial_box", "dim": 3, "packing": "random",
                    "size": [0.04, 0.04, 0.08], "d_mean": 0.008, "material": "rock"},
          "materials": {"rock": dict(ROCK, Tu=1e9, Cu=1e10)},  # elastic: no bond breaks
          "steps": [{"kind": "triaxial", "confining_pressures": [1.0e6], "strain_rate": 1.0,
                     "max_strain": 5.0e-4, "samples": 20}],
          "outputs": {"observables": {"every": 2000}}}
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(wf))
    return p


def test_random_3d_triaxial_box_has_head_on_walls(tmp_path):
    run = prepare(_triaxial_workflow(tmp_path))
    st = run.built.state
    spec = groups.members(st, "specimen")
    bonds = (st.cstate[spec] == BONDED).sum() / spec.size
    assert bonds > 4.5
    for wall, area in (("xmin", 50), ("xmax", 50), ("ymin", 50), ("ymax", 50), ("bottom", 25),
                       ("top", 25)):  # face areas in d_mean^2
        w = groups.members(st, wall)
        assert w.size > 0.5 * area, wall
        # each wall element touches its face element head-on (gap 0)
        nb = st.nbr[w]
        jj = np.where(nb >= 0, nb, 0)
        gap = np.linalg.norm(st.x[jj] - st.x[w][:, None, :], axis=2) - st.r[w][:, None] - st.r[jj]
        touch = (nb >= 0) & np.isin(jj, spec) & (np.abs(gap) < 1e-4 * 0.008)
        assert touch.any(axis=1).mean() > 0.99, wall


def test_random_3d_triaxial_consolidates_and_loads(tmp_path):
    code, s = run_workflow(_triaxial_workflow(tmp_path), tmp_path / "out", echo=False,
                           progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    t = s["results"]["triaxial"]["tests"][0]
    assert t["consolidation"]["converged"]
    for name, sig in t["consolidation"]["wall_stresses"].items():
        assert sig == pytest.approx(1.0e6, rel=0.02), name
    assert t["cracks_tensile"] + t["cracks_shear"] == 0
    # a random packing is softer than the lattice the conversion assumes (E = 15 GPa)
    assert 0.1 * ROCK["E"] < t["E"] < 0.6 * ROCK["E"], t["E"]
