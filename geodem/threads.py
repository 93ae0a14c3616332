"""Which threading layer numba's parallel loops run on, chosen by geodem.

numba picks its layer when the first parallel loop starts, in the order of
``NUMBA_THREADING_LAYER_PRIORITY`` (numba's default: ``tbb``, ``omp``, ``workqueue``). A TBB
runtime is on many machines (Debian's ``libtbb12``, which the ``yade`` package brings, or
conda's numba); with Debian's TBB 2021.8 the quick-start UCS test had not finished packing its
specimen after 60 s (it takes ~2 s on OpenMP) and ``geodem validate`` not after 120 s
(docs/performance.md, "Threading layer"). geodem's loops are many short parallel regions, which OpenMP serves best
(docs/performance.md, "Threading layer"). So, unless the user chose a layer
(``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY`` set), geodem asks for
``omp``, then ``workqueue``, then ``tbb``. This module imports nothing heavy: it runs when
``geodem`` is imported, before numba starts any thread.
"""
from __future__ import annotations

import functools
import os
import sys

PRIORITY = ("omp", "workqueue", "tbb")  # geodem's order (measured: docs/performance.md)
_ENV_LAYER = "NUMBA_THREADING_LAYER"
_ENV_PRIORITY = "NUMBA_THREADING_LAYER_PRIORITY"


def user_choice() -> str | None:
    """The layer setting the user made in the environment, as text, or None."""
    layer = os.environ.get(_ENV_LAYER, "").strip()
    if layer and layer.lower() != "default":
        return f"{_ENV_LAYER}={layer}"
    prio = os.environ.get(_ENV_PRIORITY, "").strip()
    if prio and prio != " ".join(PRIORITY):
        return f"{_ENV_PRIORITY}={prio}"
    return None


def choose() -> None:
    """Put geodem's priority in force (environment, and numba's config if numba is imported),
    unless the user made a choice. Idempotent; a no-op once numba's threads have started."""
    if user_choice() is not None:
        return
    os.environ[_ENV_PRIORITY] = " ".join(PRIORITY)  # numba re-reads it before each compile
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.THREADING_LAYER_PRIORITY = list(PRIORITY)


# ============================================================================ OpenMP waiting
#: how long (busy-wait iterations) an OpenMP thread of GNU libgomp spins at the end of a
#: parallel region before it sleeps; libgomp's own default is 300,000 (``OMP_WAIT_POLICY``
#: unset). See :func:`choose_wait` for the figures behind this value.
SPINCOUNT = "1000"
_ENV_WAIT = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
_ENV_MARK = "GEODEM_SET_GOMP_SPINCOUNT"  # tells a child process the value came from geodem


def user_wait_choice() -> str | None:
    """The OpenMP waiting setting the user made in the environment, as text, or None."""
    for name in _ENV_WAIT:
        value = os.environ.get(name, "").strip()
        if value and not (name == "GOMP_SPINCOUNT" and os.environ.get(_ENV_MARK) == value):
            return f"{name}={value}"
    return None


def _loaded_libraries() -> list[str]:
    """The paths of the shared libraries loaded in this process, from ``/proc/self/maps``
    (Linux; elsewhere none)."""
    try:
        with open("/proc/self/maps") as maps:
            return sorted({line.split()[-1] for line in maps if line.rstrip().endswith(".so")
                           or ".so." in line})
    except OSError:
        return []


def _libgomp_loaded() -> bool:
    """Whether GNU libgomp is already in this process (it reads its settings when it loads,
    so a setting made later has no effect)."""
    return any("libgomp" in os.path.basename(p) for p in _loaded_libraries())


def choose_wait() -> None:
    """Set ``GOMP_SPINCOUNT`` to :data:`SPINCOUNT` unless the user set ``OMP_WAIT_POLICY`` or
    ``GOMP_SPINCOUNT``.

    Why: geodem's step is many short parallel regions; with libgomp's default a thread spins
    300,000 iterations waiting for the next one. When another busy process shares the cores
    (a second run, a test suite, a compile), a spinning thread holds the core its partner
    needs, and every region waits for a time slice: two 2-thread runs side by side on 2 cores
    each ran at 4.6e4 element-steps/s (10^3 elements) against 1.34e7 alone. Measured on
    2 cores (docs/performance.md, "Waiting threads"): a spin of 1000 keeps them at 5.0e6 each
    and costs the quiet quick start ~7 %; ``OMP_WAIT_POLICY=passive`` (no spin) gives 8.1e6
    each but costs the quiet quick start ~60 %. The results do not change: waiting is not
    arithmetic."""
    if user_wait_choice() is not None or _libgomp_loaded():
        return
    os.environ["GOMP_SPINCOUNT"] = SPINCOUNT
    os.environ[_ENV_MARK] = SPINCOUNT


def describe_wait() -> dict:
    """The OpenMP waiting setting in force and who made it (``geodem info``, manifest.json)."""
    user = user_wait_choice()
    if user is not None:
        return {"setting": user, "chosen_by": "user"}
    value = os.environ.get("GOMP_SPINCOUNT")
    if value is None:
        return {"setting": "libgomp default (GOMP_SPINCOUNT 300000)",
                "chosen_by": "nobody: libgomp was loaded before geodem was imported"}
    return {"setting": f"GOMP_SPINCOUNT={value}", "chosen_by": "geodem"}


def layer() -> str:
    """The layer numba's parallel loops run on in this process (starting numba's threads if
    they have not started yet), e.g. ``omp``."""
    import numba
    from numba.np.ufunc import parallel

    choose()
    parallel._launch_threads()  # what the first parallel loop does; returns at once after it
    return str(numba.threading_layer())


def numba_threads() -> int:
    """The number of threads numba's parallel loops run on (``NUMBA_NUM_THREADS`` or
    ``numba.set_num_threads``); imports numba, so call it after :func:`choose`."""
    import numba

    return int(numba.get_num_threads())


def describe() -> dict:
    """The layer in use and where the choice came from, and on ``omp`` how idle threads wait
    (``geodem info``, manifest.json)."""
    chosen_by = user_choice()
    out = {"layer": layer(), "chosen_by": chosen_by or "geodem (" + ", ".join(PRIORITY) + ")"}
    if out["layer"] == "omp":
        out["wait"] = describe_wait()
    return out


def slow_layer_note(name: str) -> str | None:
    """A warning for a layer that runs geodem's loops much slower than ``omp``, else None."""
    if name == "omp":
        return None
    return (f"numba's parallel loops run on the {name!r} threading layer (OpenMP was not "
            f"available or another layer was asked for); geodem measured its UCS workflow 10x "
            f"slower on 'workqueue' and its step 7x slower on Debian's TBB 2021.8 than on 'omp' "
            f"(docs/performance.md, \"Threading layer\")")


# ============================================================================ BLAS threads
#: (getter, setter) symbol names of the BLAS libraries numpy and scipy load: OpenBLAS as
#: PyPI's numpy / scipy wheels bundle it, a system OpenBLAS, Intel MKL
_BLAS_SYMBOLS = (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
                 ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
                 ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
                 ("openblas_get_num_threads", "openblas_set_num_threads"),
                 ("MKL_Get_Max_Threads", "MKL_Set_Num_Threads"))


def _blas_libraries() -> list:
    """``(get_threads, set_threads)`` of every BLAS library loaded in this process, found in
    ``/proc/self/maps`` (Linux; elsewhere none is found)."""
    import ctypes

    out = []
    for path in _loaded_libraries():
        name = os.path.basename(path).lower()
        if not path.startswith("/") or not ("openblas" in name or "mkl_rt" in name):
            continue
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get, put in _BLAS_SYMBOLS:
            if hasattr(lib, get) and hasattr(lib, put):
                out.append((getattr(lib, get), getattr(lib, put)))
                break
    return out


@functools.lru_cache(maxsize=1)
def _blas_libraries_cached() -> tuple:
    """:func:`_blas_libraries`, looked up once per process (numpy's and scipy's BLAS stay
    loaded once imported)."""
    return tuple(_blas_libraries())


class single_threaded_blas:
    """Context: numpy's and scipy's BLAS on one thread, restored after.

    OpenBLAS splits a dot product of more than ~1e4 entries between its threads (one per core
    by default), and the partial sums round differently: the least-squares solve of the
    stress-free packing (:func:`geodem.build.isotropic.stress_free`) then gave another
    specimen on a machine with another core count (a 12,000-element 2-D packing: different
    positions with 1 and 2 BLAS threads). On one thread it is the same everywhere, and faster
    (0.28 s against 0.97 s for that solve; a thread hand-off per dot costs more than the dot).
    ``.found``: how many BLAS libraries were set (0: none found, nothing changed)."""

    def __enter__(self):
        import numpy  # noqa: F401 - load numpy's BLAS before looking for it

        self._libs = _blas_libraries_cached()
        self._old = [int(get()) for get, _ in self._libs]
        for _, put in self._libs:
            put(1)
        self.found = len(self._libs)
        return self

    def __exit__(self, *exc):
        for (_, put), n in zip(self._libs, self._old):
            put(max(1, n))
        return False
