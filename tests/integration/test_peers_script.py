"""benchmarks/peers/peers.py without the peers: the geodem side runs and reports a bonded FCC
cube (12 bonds inside), a peer that is not installed is reported as not run (CI does not install
them; the figures come from the command, docs/performance.md)."""
import importlib.util
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def peers():
    spec = importlib.util.spec_from_file_location("peers", ROOT / "benchmarks/peers/peers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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
