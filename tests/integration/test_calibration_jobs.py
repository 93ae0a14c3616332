"""Packings measured side by side (``geodem calibrate --packings N --jobs J``): fresh
processes of one numba thread each give the numbers the packings give one after another in
this process (a run's numbers do not depend on its thread count). Integration tier: two tiny
specimens, each measured both ways (about half a minute, most of it the processes' start)."""
from pathlib import Path

import pytest

from geodem.materials_library import load_material
from geodem.studies import calibrate as cal


@pytest.fixture(scope="module")
def spec():
    return cal.CalibrationSpec(targets=load_material("sandstone").values(), name="sandstone",
                               ucs_size=(0.03, 0.06), packings=2, max_strain=0.01)


def test_packings_side_by_side_give_the_numbers_one_after_another(spec, tmp_path,
                                                                  one_numba_thread):
    el = cal.prior_guess(spec)
    here = cal.over_packings(cal.measure, cal.replace(spec, jobs=1), el, Path(tmp_path / "one"))
    apart = cal.over_packings(cal.measure, cal.replace(spec, jobs=2), el, Path(tmp_path / "two"))
    for a, b in zip(here["per_packing"], apart["per_packing"]):
        for key in ("E", "nu", "Cu", "Tu"):
            assert a[key] == b[key], key  # bit for bit
    assert here["E"] == apart["E"] and here["scatter"] == apart["scatter"]
    assert (tmp_path / "two" / "packing_1" / "ucs" / "out" / "summary.json").exists()


def test_jobs_default_to_the_numba_threads_and_never_exceed_the_packings(spec, monkeypatch):
    monkeypatch.setattr(cal.threads, "numba_threads", lambda: 2)
    assert cal.packing_jobs(spec) == 2
    assert cal.packing_jobs(cal.replace(spec, packings=1)) == 1
    assert cal.packing_jobs(cal.replace(spec, jobs=8)) == 2  # at most one per packing
    monkeypatch.setattr(cal.threads, "numba_threads", lambda: 1)
    assert cal.packing_jobs(spec) == 1
    with pytest.raises(ValueError, match="jobs"):
        cal.replace(spec, jobs=0)
