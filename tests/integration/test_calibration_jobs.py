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


def test_an_interrupted_job_stops_the_others_and_drops_the_queued_ones():
    """When one packing's job is interrupted or fails, the parent tells the running jobs to
    stop (SIGTERM: a run checkpoints and stops) and a queued job that reaches a process ends
    at once, instead of every queued packing running to its end first (a Ctrl-C of `geodem
    rock --jobs 2` went on to the third packing). Here the jobs are plain sleeps, which
    SIGTERM ends."""
    import multiprocessing
    import time
    from concurrent.futures import ProcessPoolExecutor

    spawn = multiprocessing.get_context("spawn")
    stop = spawn.Event()
    ex = ProcessPoolExecutor(2, mp_context=spawn, initializer=cal._init_job, initargs=(stop,))
    futures = [ex.submit(cal._call, (time.sleep, (60.0,))) for _ in range(3)]
    while not all(f.running() for f in futures[:2]):
        time.sleep(0.05)
    t0 = time.perf_counter()
    cal._stop_jobs(ex, futures, stop)
    ex.shutdown(wait=True, cancel_futures=True)
    assert time.perf_counter() - t0 < 20.0  # not the 60 s sleeps, nor a third one
    assert stop.is_set() and all(f.cancelled() or f.exception() is not None for f in futures)


def test_a_job_queued_after_the_stop_does_not_start(monkeypatch):
    """In a job's process, once the stop is set, the next job raises at once."""
    import multiprocessing

    ran = []
    stop = multiprocessing.get_context("spawn").Event()
    monkeypatch.setattr(cal, "_STOP_JOBS", None)
    cal._init_job(stop)
    assert cal._call((ran.append, (1,))) is None and ran == [1]
    stop.set()
    with pytest.raises(cal.RunInterrupted, match="not started"):
        cal._call((ran.append, (2,)))
    assert ran == [1]
