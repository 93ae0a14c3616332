"""Geometry from geodata: elevation rasters, label images and terrain models.

* :mod:`geodem.geo.raster`: :func:`read_elevation` -> :class:`Terrain` (GeoTIFF and every format
  rasterio/GDAL reads; CRS, reprojection to metres, nodata filling, resampling, clipping, local
  origin);
* :mod:`geodem.geo.terrain`: :func:`terrain_model` -> :class:`TerrainModel` (a lattice of
  elements under the terrain with a fixed base, layers and a sliding body; ``to_state``);
* :mod:`geodem.geo.image`: :func:`read_labels` and :func:`assign_groups` (pixel colours or label
  values -> material groups, in 2-D or in plan/section of 3-D models);
* :class:`GeometryError`: bad input (a ``ValueError``; exit status 2 on the command line).

Names are imported lazily (PEP 562): ``import geodem.geo`` needs neither rasterio nor Pillow.
"""
from __future__ import annotations

import importlib

from geodem.geo.errors import GeometryError

_EXPORTS = {
    "Terrain": "raster", "read_elevation": "raster", "utm_crs": "raster",
    "write_raster": "raster",
    "TerrainModel": "terrain", "terrain_model": "terrain", "Depth": "terrain",
    "Below": "terrain", "slip_surface_from_pair": "terrain", "surface_function": "terrain",
    "LabelImage": "image", "read_labels": "image", "assign_groups": "image",
    "pixel_labels": "image",
}

__all__ = ["GeometryError", *_EXPORTS]


def __getattr__(name):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'geodem.geo' has no attribute {name!r}")
    return getattr(importlib.import_module(f"geodem.geo.{mod}"), name)


def __dir__():
    return sorted(__all__)
