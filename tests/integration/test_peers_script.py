"""benchmarks/peers/peers.py without the peers: the geodem side runs and reports a bonded FCC
cube (12 bonds inside), a peer that is not installed is reported as not run (CI does not install
them; the figures come from the command, docs/performance.md)."""
import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _script(name):
    """benchmarks/peers/NAME.py as a module."""
    spec = importlib.util.spec_from_file_location(name, ROOT / f"benchmarks/peers/{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def peers():
    return _script("peers")


def test_cube_edge_holds_n_touching_spheres(peers):
    # FCC of touching spheres: 4 per cubic cell of edge d sqrt(2)
    n = 10_000
    assert 4 * (peers.side(n) / (peers.D * math.sqrt(2))) ** 3 == pytest.approx(n)


def test_geodem_side_and_missing_peers(peers, monkeypatch):
    monkeypatch.setattr(peers.shutil, "which",
                        lambda name: None if name in ("yade", "liggghts") else "/usr/bin/time")
    lines = []
    rows = peers.measure(["bonded", "granular"], n=4000, steps=20, threads=1,
                         progress=lines.append)
    assert [r["program"] for r in rows] == ["geodem", "geodem"]
    bonded, granular = rows
    assert bonded["n"] == 16 ** 3 and 10.0 < bonded["bonds_per_element"] < 12.0
    assert granular["bonds_per_element"] == 0.0
    assert bonded["element_steps_per_s"] > 0 and bonded["bytes_per_element"] > 0
    assert any("Yade (JCFpm)" in ln and "not run: yade is not installed" in ln for ln in lines)
    assert any("LIGGGHTS" in ln and "not run" in ln for ln in lines)


@pytest.fixture(scope="module")
def elastic():
    return _script("elastic")


def test_exact_fcc_modulus_with_equal_springs(elastic):
    """ks = kn: every bond is an isotropic spring, f = k u, so sigma = (d^2 / V) (1/2) k
    sum n n . eps = 2 k d^2 / V eps (sum over the 12 bonds of n n = 4 I) with V = d^3 / sqrt2:
    E = 2 sqrt2 k / d, nu = 0."""
    k = 2.5e6
    e, nu = elastic.exact(k, k)
    assert e == pytest.approx(2.0 * math.sqrt(2.0) * k / elastic.D, rel=1e-12)
    assert abs(nu) < 1e-12


def test_geodem_block_is_the_lattice_less_its_surface(elastic, one_numba_thread):
    """The finite block (8 spheres along an edge) in uniaxial stress: softer than the infinite
    lattice by its surface bonds, its Poisson ratio the lattice's."""
    from geodem.build.lattice import fcc_lattice

    kn = 2.5e6
    e, nu = elastic.exact(kn, 0.25 * kn)
    r = elastic.run_geodem(fcc_lattice(8, 8, 8, elastic.D), kn, 0.25 * kn)
    assert r["strain"] == pytest.approx(elastic.EPS, rel=1e-6)
    assert 0.8 < r["E"] / e < 0.95
    assert r["nu"] == pytest.approx(nu, abs=0.01)


@pytest.fixture(scope="module")
def strength():
    return _script("strength")


def test_bond_loads_of_the_lattice_by_hand(strength):
    """ks = kn: nu = 0, so a uniaxial stress sigma strains only z, by sigma / E with E = 2 sqrt2
    k / d. A bond leaving its close-packed layer (n_z^2 = 2/3) is stretched by d (2/3) sigma / E
    and sheared by d sqrt(2/3) sqrt(1/3) sigma / E: per unit stress Fn = d^2 / (3 sqrt2) and
    Fs = d^2 / 6; the six bonds within a layer carry nothing."""
    k, d = 2.5e6, strength.D
    n, fn, fs = strength.bond_loads(k, k)
    leaving = np.abs(n[:, 2]) > 0.5
    assert leaving.sum() == 6
    assert fn[leaving] == pytest.approx(d * d / (3.0 * math.sqrt(2.0)), rel=1e-9)
    assert fs[leaving] == pytest.approx(d * d / 6.0, rel=1e-9)
    assert np.abs(fn[~leaving]).max() < 1e-9 * d * d and fs[~leaving].max() < 1e-9 * d * d


def test_the_lattice_breaks_at_the_strain_the_strengths_are_set_for(strength, elastic):
    kn = 2.5e6
    e, _ = elastic.exact(kn, 0.25 * kn)
    for case in strength.CASES:
        fn_max, fs_max = strength.bond_strengths(case, kn)
        assert strength.exact_strength(kn, fn_max, fs_max) == pytest.approx(
            e * strength.E_PEAK, rel=1e-9)


@pytest.mark.parametrize("case", ["tension", "shear"])
def test_geodem_block_breaks_below_the_lattice_strength(strength, case, one_numba_thread):
    """The finite block (6 spheres an edge, 216) pulled apart: its surface bonds carry more
    than the lattice's, so it breaks first there, below the lattice strength, and completely
    (measured 0.679 x in tension, 0.591 x in shear, the same as Yade's JCFpm to 3e-4)."""
    from geodem.build.lattice import fcc_lattice

    kn = 2.5e6
    fn_max, fs_max = strength.bond_strengths(case, kn)
    exact = strength.exact_strength(kn, fn_max, fs_max)
    r = strength.run_geodem(fcc_lattice(6, 6, 6, strength.D), kn, 0.25 * kn, fn_max, fs_max)
    assert 0.5 < r["peak_stress"] / exact < 0.8
    assert abs(r["final_stress"]) < 0.05 * r["peak_stress"]
