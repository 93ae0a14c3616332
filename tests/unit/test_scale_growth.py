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
