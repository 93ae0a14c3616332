"""geodem: discrete-element (DEM) framework for bonded rock, MatDEM style (numba / CuPy / NumPy)."""

__version__ = "0.1.0"
