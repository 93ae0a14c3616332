"""`geodem study scale` end to end on tiny sizes: every family measured, the files written, the
numbers consistent with the built models; bad input exits 2."""
import json

from typer.testing import CliRunner

from geodem.cli import app


def test_scale_study_on_tiny_models(tmp_path):
    out = tmp_path / "scale"
    res = CliRunner().invoke(app, ["study", "scale", "-o", str(out), "--sizes", "300,600",
                                   "--families",
                                   "lattice,granular,isotropic,terrain,thermal,pore,"
                                   "pore_isotropic"])
    assert res.exit_code == 0, res.output
    r = json.loads((out / "scale.json").read_text())
    families = {"lattice", "granular", "isotropic", "terrain", "thermal", "pore",
                "pore_isotropic"}
    assert {p["family"] for p in r["points"]} == families
    for p in r["points"]:
        assert 0.5 * p["n_requested"] <= p["n"] <= 1.5 * p["n_requested"]
        # the state alone is ~870 B per element at ~12 contacts (docs/performance.md)
        assert 700 < p["bytes_per_element"] < 1500
        assert p["element_steps_per_s"] > 0 and p["build_s"] > 0 and p["checkpoint_s"] > 0
        assert p["checkpoint_bytes_per_element"] > 500
        assert p["checkpoint_disk_s"] > 0 and p["vtk_disk_s"] > 0  # the disk's baseline
    lattice = [p for p in r["points"] if p["family"] == "lattice"]
    granular = [p for p in r["points"] if p["family"] == "granular"]
    assert [p["n"] for p in lattice] == [p["n"] for p in granular]  # the same block, cut
    assert set(r["growth"]) == families
    for g in r["growth"].values():  # the writers are judged beyond a plain write of their bytes
        assert "exponent_beyond_disk" in g["checkpoint_s"] and "disk_exponent" in g["vtk_frame_s"]
        assert "disk_exponent" not in g["build_s"]
    for p in r["points"]:  # a field's set-up counts in the build, and its steps are timed
        if p["family"] in ("thermal", "pore", "pore_isotropic"):
            assert 0.0 <= p["field_attach_s"] <= p["build_s"] and p["steps"] == 20
        # the pore field counts its network updates; the thermal field has no network
        assert (p.get("field_network_updates") is not None) == p["family"].startswith("pore")
    iso = [p for p in r["points"] if p["family"] == "isotropic"]
    assert [p["n"] for p in iso] == [p["n"] for p in r["points"]
                                     if p["family"] == "pore_isotropic"]  # the same packing
    assert (out / "scale.png").stat().st_size > 1000
    assert len((out / "scale.csv").read_text().splitlines()) == 1 + len(r["points"])


def test_unknown_family_exits_2(tmp_path):
    res = CliRunner().invoke(app, ["study", "scale", "-o", str(tmp_path / "s"),
                                   "--families", "lattice,foam"])
    assert res.exit_code == 2
    assert ("foam unknown; allowed: lattice, isotropic, granular, terrain, thermal, pore, "
            "pore_isotropic") in res.output


def test_the_terrain_family_is_the_hill_built_as_a_workflow_builds_it():
    """About N elements of the landslide's hill: the FCC lattice's sqrt(2) / d^3 elements per
    m^3 over the ground's volume, less the partial cells at its faces; bonded like rock."""
    from geodem.studies.scale import measure

    r = measure("terrain", 3000, steps=5)
    assert 0.8 * 3000 < r["n"] < 1.05 * 3000
    assert r["d"] > 10.0  # m: 600 m x 300 m of hill in a few thousand elements
    assert 6.0 < r["contacts_per_element"] < 12.5


def test_a_failing_point_is_reported_and_the_others_kept(tmp_path, monkeypatch):
    """A point that fails (here: a made-up stability error of the lattice at 900 elements)
    is said and kept in scale.json; the family's larger sizes are skipped, the other
    families measured, and the study exits 1."""
    from geodem.studies import scale

    real = scale.measure

    def measure(family, n, backend="numba", steps=None):
        if family == "lattice" and n == 900:
            raise RuntimeError("dt above the field's stability bound")
        return real(family, n, backend, steps)

    monkeypatch.setattr(scale, "measure", measure)
    out = tmp_path / "scale"
    res = CliRunner().invoke(app, ["study", "scale", "-o", str(out), "--sizes", "300,900,2000",
                                   "--families", "lattice,granular"])
    assert res.exit_code == 1
    assert "lattice at 900 elements failed: RuntimeError: dt above" in res.output
    r = json.loads((out / "scale.json").read_text())
    assert r["failed"] == [{"family": "lattice", "n": 900,
                            "error": "RuntimeError: dt above the field's stability bound"}]
    assert {(s["family"], s["n"]) for s in r["skipped"]} == {("lattice", 2000)}
    assert sorted((p["family"], p["n_requested"]) for p in r["points"]) == [
        ("granular", 300), ("granular", 900), ("granular", 2000), ("lattice", 300)]


def test_a_pore_block_steps_within_the_fluids_bound():
    """Water in the at-rest block's pores needs a smaller step than the solid (bound 3.9e-7 s
    against 2.1e-6 s at 300 elements): without ``fit_dt`` the field refuses the solid's step;
    with it the run steps at that fraction of the field's own bound, and says so."""
    import pytest

    from geodem.bench import bench_one
    from geodem.core.engine import Simulation
    from geodem.fields import FieldStabilityError
    from geodem.fields.pore import WATER_KF, PoreField
    from geodem.studies.scale import _at_rest

    state, _ = _at_rest(300)
    with pytest.raises(FieldStabilityError, match="above the stability bound"):
        bench_one(state, "numba", steps=2, fields=(lambda: PoreField(k_f=WATER_KF),))
    b = bench_one(state, "numba", steps=2, fields=(lambda: PoreField(k_f=WATER_KF),),
                  fit_dt=0.8)
    probe = Simulation(state.copy(), backend="numba", monitor_every=0)
    solid_dt = probe.state.dt
    probe.state.dt = 0.0
    field = PoreField(k_f=WATER_KF)
    probe.add_field(field)
    bound = field.mechanical_dt_bound(probe)
    assert bound < solid_dt
    assert b["dt_fitted"] and b["dt_s"] == pytest.approx(0.8 * bound, rel=1e-9)
    assert b["field_mechanical_dt_bound_s"] == pytest.approx(bound, rel=1e-9)
    assert b["field_stable_dt_s"] == pytest.approx(field.stable_dt(probe), rel=1e-9)
    dry = bench_one(state, "numba", steps=2, fields=(lambda: PoreField(k_f=100 * WATER_KF),),
                    fit_dt=0.8)  # a compressible fluid: the solid's step stands
    assert not dry["dt_fitted"] and dry["dt_s"] == pytest.approx(solid_dt, rel=1e-12)
