"""A synthetic hill with a valley floor and a spoon-shaped sliding surface: the rasters of
``workflows/landslide.yaml`` (``workflows/data/hill.tif``, ``workflows/data/hill_slip_depth.tif``).

Regenerate them with::

    PYTHONPATH=. python -m geodem.geo.synthetic workflows/data

The recipe (local coordinates ``x`` east, ``y`` north [m] from the grid's SW corner; the grid is
600 m x 300 m in 10 m cells, 60 x 30, float32, projected CRS WGS 84 / UTM zone 32N (EPSG:32632)
with its SW corner at E 650000, N 5120000; elevations in metres above sea level):

* valley floor ``z_f = 400 + 0.02 (600 - x)`` (falls gently east, towards a stream at the
  east edge);
* hillside: a plateau ``R = 100`` m above the floor in the west, falling over the belt
  ``120 < x < 320`` m by a smoothstep ``S(t) = 3 t^2 - 2 t^3``, ``t = (x - 120) / 200``:
  ``z = z_f + R (1 - S(t))`` (alone its steepest slope would be ``1.5 R / 200 = 0.75``, 36.9
  deg, at ``x = 220`` m);
* a hollow in the hillside centred on ``y = 150`` m: ``- 8 exp(-((y - 150) / 60)^2) sin(pi t)``
  for ``0 < t < 1`` (the slope is concave across, as hillslope hollows are). With it the
  steepest slope along ``y = 150`` m is 38.05 deg at ``x = 207`` m (the recipe sampled every
  1 mm); the shipped raster's steepest cell-to-cell slope is 38.0 deg, between the centres
  ``x = 205`` and ``215`` m of the rows ``y = 145`` and ``155`` m. Measured with::

      python -c "import numpy as np; from geodem.geo.synthetic import hill_elevation as h
      x = np.linspace(100, 400, 300001); g = np.degrees(np.arctan(abs(np.gradient(
      h(x, 150 + 0 * x), x)))); print(x[g.argmax()], g.max())"

* sliding surface (``hill_slip_depth.tif``, depth below the ground, positive down): a spoon,
  ``D = D0 (27/4) u (1 - u)^2 sqrt(max(0, 1 - ((y - 150) / 60)^2))`` with ``u = (x - 130) /
  160`` for ``0 < u < 1`` (0 elsewhere), ``D0 = 20`` m: the source spans ``130 < x < 290`` m
  on the upper and middle slope, deepest (20 m) a third of the way down (``x = 183`` m), with a
  steep head scarp (the depth grows at ``(27/4) D0 / 160 = 0.84`` m/m below the crown) and a
  toe where the sliding surface runs out parallel to the ground (``dD/du = 0`` at ``u = 1``),
  so the slide can leave its bed over the lower slope.

Elevations are sampled at the cell centres. The files are small (under 10 KB each) and carry the
CRS and the geotransform, so they exercise the same reading path (:func:`~geodem.geo.raster.
read_elevation`) as a real DEM.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

#: the grid of the shipped rasters
NX, NY, DX = 60, 30, 10.0
WEST, SOUTH = 650000.0, 5120000.0
CRS = "EPSG:32632"
HILL = "hill.tif"
SLIP = "hill_slip_depth.tif"

FLOOR, FLOOR_SLOPE, RELIEF = 400.0, 0.02, 100.0
BELT = (120.0, 320.0)
HOLLOW = (8.0, 150.0, 60.0)  # depth, centre y, width [m]
SPOON = (20.0, 130.0, 160.0, 150.0, 60.0)  # depth, head x, length, centre y, half width


def _belt(x):
    return np.clip((np.asarray(x, float) - BELT[0]) / (BELT[1] - BELT[0]), 0.0, 1.0)


def hill_elevation(x, y):
    """Ground elevation [m a.s.l.] at local ``(x, y)`` [m] (the recipe above)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    t = _belt(x)
    s = 3 * t ** 2 - 2 * t ** 3
    floor = FLOOR + FLOOR_SLOPE * (NX * DX - x)
    hollow = HOLLOW[0] * np.exp(-((y - HOLLOW[1]) / HOLLOW[2]) ** 2) * np.sin(math.pi * t)
    return floor + RELIEF * (1.0 - s) - hollow


def slip_depth(x, y):
    """Depth of the sliding surface below the ground [m] (0 outside the source area)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    d0, xh, length, yc, b = SPOON
    u = np.clip((x - xh) / length, 0.0, 1.0)
    across = np.sqrt(np.clip(1.0 - ((y - yc) / b) ** 2, 0.0, None))
    return d0 * 6.75 * u * (1.0 - u) ** 2 * across


def grid():
    """Local cell-centre coordinates ``(x, y)`` (NY, NX) in raster order (row 0 north) and the
    geotransform (rasterio order)."""
    j, i = np.mgrid[0:NY, 0:NX]
    x, y = (i + 0.5) * DX, (NY - j - 0.5) * DX
    return x, y, (DX, 0.0, WEST, 0.0, -DX, SOUTH + NY * DX)


def write_hill(folder) -> tuple[Path, Path]:
    """Write ``hill.tif`` and ``hill_slip_depth.tif`` into ``folder``; returns their paths."""
    from geodem.geo.raster import write_raster

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    x, y, tr = grid()
    out = folder / HILL, folder / SLIP
    write_raster(out[0], hill_elevation(x, y).astype(np.float32), tr, CRS)
    write_raster(out[1], slip_depth(x, y).astype(np.float32), tr, CRS)
    return out


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    folder = args[0] if args else "workflows/data"
    for p in write_hill(folder):
        print(f"wrote {p} ({p.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
