"""The growth verdicts of `geodem study scale` (geodem.studies.scale), by hand."""
import math

import pytest

from geodem.studies.scale import exponent, verdict


def pts(costs):
    return [{"n": n, "build_s": c} for n, c in costs]


def test_exponent_between_the_two_largest_sizes():
    # 10 -> 40 s from 1e5 to 1e6 elements: log(4) / log(10)
    assert exponent(pts([(1e3, 0.5), (1e5, 10.0), (1e6, 40.0)]), "build_s") == \
        pytest.approx(math.log(4) / math.log(10))
    assert exponent(pts([(1e3, 0.5)]), "build_s") is None


def test_n_log_n_is_not_flagged_and_n_to_the_1_5_is():
    n1, n2 = 1e5, 1e6
    nlogn = pts([(n1, n1 * math.log(n1) * 1e-6), (n2, n2 * math.log(n2) * 1e-6)])
    assert verdict(nlogn, "build_s")["faster_than_n_log_n"] is False
    power = pts([(n1, n1 ** 1.5 * 1e-6), (n2, n2 ** 1.5 * 1e-6)])
    v = verdict(power, "build_s")
    assert v["exponent"] == pytest.approx(1.5) and v["faster_than_n_log_n"] is True


def test_a_writer_is_judged_beyond_the_machines_own_write_of_its_bytes():
    # the checkpoint grows as N^1.25 from 1e5 to 1e6, and so does a plain write of its bytes
    # (the page cache filling): the writer adds nothing beyond the disk, not flagged
    n1, n2 = 1e5, 1e6
    same = [{"n": n1, "checkpoint_s": 0.1, "checkpoint_disk_s": 0.05},
            {"n": n2, "checkpoint_s": 0.1 * 10 ** 1.25, "checkpoint_disk_s": 0.05 * 10 ** 1.25}]
    v = verdict(same, "checkpoint_s")
    assert v["exponent"] == pytest.approx(1.25) and v["disk_exponent"] == pytest.approx(1.25)
    assert v["exponent_beyond_disk"] == pytest.approx(1.0)
    assert v["faster_than_n_log_n"] is False
    # ... while a writer at N^1.5 on a linear disk is flagged
    worse = [{"n": n1, "checkpoint_s": 0.1, "checkpoint_disk_s": 0.05},
             {"n": n2, "checkpoint_s": 0.1 * 10 ** 1.5, "checkpoint_disk_s": 0.5}]
    v = verdict(worse, "checkpoint_s")
    assert v["exponent_beyond_disk"] == pytest.approx(1.5) and v["faster_than_n_log_n"] is True
    # a cost without a baseline (the build) is judged on its own exponent
    assert "disk_exponent" not in verdict(pts([(n1, 1.0), (n2, 10.0)]), "build_s")


def test_a_tiled_random_packing_is_projected_with_its_cell_jammed_once():
    from geodem.studies.scale import projected_build

    # the 10^5 random packing with the pore field (2026-12-07): 659 s, 645 of them jamming
    # the periodic cell, which a 10^6 packing jams once as well (it took 553 s in all)
    tiled = [{"n": 100_000, "build_s": 659.0, "packing_s": 645.0}]
    assert projected_build(tiled, 1_000_000) == pytest.approx(645.0 + 14.0 * 10)
    # a box jammed whole (below TILE_ABOVE) and a lattice are scaled whole, at least linearly
    assert projected_build([{"n": 8_000, "build_s": 176.0, "packing_s": 170.0}], 16_000) == \
        pytest.approx(352.0)
    steep = [{"n": 1e4, "build_s": 1.0}, {"n": 1e5, "build_s": 100.0}]
    assert projected_build(steep, 1e6) == pytest.approx(10_000.0)
