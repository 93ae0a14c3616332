"""geodem: discrete-element (DEM) framework for bonded rock, MatDEM style (numba / CuPy / NumPy)."""

from geodem import threads as _threads

_threads.choose()  # before numba starts a thread: see geodem.threads
_threads.choose_wait()  # before libgomp loads: see geodem.threads

__version__ = "0.1.0"
