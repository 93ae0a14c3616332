"""3-D triaxial test on a close-packed (FCC) lattice specimen inside six servo-controlled walls.

The lattice is the one ``macro_to_micro`` is derived on, so the specimen's Young's modulus is
the material's E (tests/integration/test_lattice_elasticity.py). The axial strain of the
triaxial test is the platen approach over the height, which also counts the two wall contacts
at the platens (each as stiff as one bond, i.e. about half an inter-layer gap): over the ~9
layers of the tiny specimen below that makes the apparent modulus 10-25 % lower than E, never
higher unless the lateral walls hold the specimen back.
"""
import pytest
import yaml

from geodem.core import groups
from geodem.workflow import run_workflow
from geodem.workflow.runner import prepare

pytestmark = pytest.mark.usefixtures("one_numba_thread")

E = 20.0e9
# strengths far above what the test reaches: an elastic lattice
ROCK = {"E": E, "nu": 0.1, "Tu": 1.0e9, "Cu": 1.0e10, "mu_i": 0.8, "rho": 2600.0}
BOX = {"type": "triaxial_box", "dim": 3, "packing": "lattice", "size": [0.032, 0.032, 0.064],
       "d_mean": 0.008, "material": "rock"}


def write(tmp_path, step, model=None):
    wf = {"metadata": {"name": "tri3d", "seed": 0}, "model": dict(BOX, **(model or {})),
          "materials": {"rock": ROCK}, "steps": [dict({"kind": "triaxial"}, **step)],
          "outputs": {"observables": {"every": 2000}}}
    p = tmp_path / "wf.yaml"
    p.write_text(yaml.safe_dump(wf))
    return p


@pytest.fixture(scope="module")
def elastic_3d(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tri3d")
    # 0.2 /s: at 1 /s the lateral servo lags (0.45 MPa at sigma3 = 0) and stiffens the lattice
    p = write(tmp, {"confining_pressures": [0.0, 1.0e6], "strain_rate": 0.2,
                    "max_strain": 5.0e-4, "samples": 30})
    code, s = run_workflow(p, tmp / "out", echo=False, progress=False)
    assert code == 0 and s["status"] == "ok", s.get("error")
    return s


def test_six_walls_hold_the_consolidation_stress(elastic_3d):
    t = elastic_3d["results"]["triaxial"]["tests"][1]
    c = t["consolidation"]
    assert c["converged"]
    assert set(c["wall_stresses"]) == {"xmin", "xmax", "ymin", "ymax", "bottom", "top"}
    for name, sig in c["wall_stresses"].items():
        assert sig == pytest.approx(1.0e6, rel=0.02), name


def test_lattice_modulus_between_the_glued_end_layers(elastic_3d):
    """The strain is measured between the end layers glued to the platens (as in the UCS test),
    so no wall contact is in it: unconfined, the lattice's own E (measured 18.8 GPa, 2026-12-05).
    Confined at 1 MPa the tangent reads 26 GPa: the lateral walls move only sideways, so as the
    face elements slide down past their head-on wall elements the pressed contacts tilt and
    push back along the axis (with the platen contacts in the strain, before: 0.7-1.0 x E)."""
    unconfined, confined = elastic_3d["results"]["triaxial"]["tests"]
    for t in (unconfined, confined):
        assert t["cracks_tensile"] + t["cracks_shear"] == 0
    assert unconfined["E"] == pytest.approx(E, rel=0.10)
    assert 1.0 * E < confined["E"] < 1.5 * E


def test_prepared_model_has_a_lattice_inside_six_walls(tmp_path):
    p = write(tmp_path, {"confining_pressures": [1.0e6]})
    run = prepare(p)
    st = run.built.state
    spec = groups.members(st, "specimen")
    # every interior FCC element has 12 bonds: the mean is well above a random packing's ~4
    assert 2.0 * (st.cstate[spec] == 1).sum() / 2 / spec.size > 6.0
    for wall in ("xmin", "xmax", "ymin", "ymax", "bottom", "top"):
        assert groups.members(st, wall).size > 0
