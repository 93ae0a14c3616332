"""Errors of the geometry layer (rasters, images, shapes, terrain models)."""
from __future__ import annotations

__all__ = ["GeometryError"]


class GeometryError(ValueError):
    """Bad geometry input: a raster without CRS, all nodata, of the wrong dimensionality or not
    covering the requested region; an image whose colours map to no material; an impossible
    shape. The message says what was found and what is needed. A subclass of ``ValueError``:
    the command line reports it as invalid input (exit status 2)."""
