"""numpy's BLAS on one thread where geodem's builds sum with it (geodem.threads.single_threaded_blas):
a long dot product then rounds as on a one-core machine, whatever this machine's core count."""
import os
import subprocess
import sys

import numpy as np
import pytest

from geodem.threads import _blas_libraries, single_threaded_blas

DOT = ("import numpy as np; rng = np.random.default_rng(7); a = rng.standard_normal(200_000); "
       "b = rng.standard_normal(200_000); print(float(np.dot(a, b)).hex())")

linux_wheel = pytest.mark.skipif(not _blas_libraries(), reason="no BLAS library found in "
                                 "/proc/self/maps (not Linux, or numpy without OpenBLAS/MKL)")


@linux_wheel
def test_a_long_dot_product_sums_as_on_one_thread():
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    one = subprocess.run([sys.executable, "-c", DOT], env=env, capture_output=True, text=True,
                         check=True).stdout.strip()
    rng = np.random.default_rng(7)
    a, b = rng.standard_normal(200_000), rng.standard_normal(200_000)
    with single_threaded_blas() as blas:
        assert blas.found >= 1
        inside = float(np.dot(a, b)).hex()
    assert inside == one


@linux_wheel
def test_the_thread_counts_are_restored():
    before = [int(get()) for get, _ in _blas_libraries()]
    with single_threaded_blas():
        assert all(int(get()) == 1 for get, _ in _blas_libraries())
    assert [int(get()) for get, _ in _blas_libraries()] == before
