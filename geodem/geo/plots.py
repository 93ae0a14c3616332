"""The terrain-model picture of docs/geometry.md (matplotlib, off-screen).

Regenerate with::

    PYTHONPATH=. python -m geodem.geo.plots docs/img/terrain_model.png

It writes a synthetic pre/post-event raster pair (a hill with a scar) as GeoTIFFs in a temporary
folder, reads them (:func:`~geodem.geo.raster.read_elevation`), builds the 3-D model and a 2-D
section through the scar (:func:`~geodem.geo.terrain.terrain_model`) and draws: the terrain with
the depletion zone, the 3-D model's elements by group, and the section with the top and sliding
surfaces.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

GROUP_COLOURS = {"base": "#555555", "side_x": "#999999", "side_y": "#bbbbbb",
                 "slide": "#d62728", "soil": "#bcbd22", "rock": "#8c6d31"}


def example_rasters(folder, nx=40, ny=30, dx=5.0, crs="EPSG:32632"):
    """Write ``pre.tif`` and ``post.tif`` (a hill on a slope; a 7 m deep scar on its east flank)
    into ``folder``; returns their paths."""
    from geodem.geo.raster import write_raster

    j, i = np.mgrid[0:ny, 0:nx]
    x, y = (i + 0.5) * dx, (ny - j - 0.5) * dx
    pre = 100.0 + 0.15 * x + 25.0 * np.exp(-((x - 90) ** 2 + (y - 75) ** 2) / 1500.0)
    scar = 7.0 * np.exp(-((x - 125) ** 2 + (y - 75) ** 2) / 300.0)
    post = pre - np.where(scar > 0.5, scar, 0.0)
    tr = (dx, 0.0, 650000.0, 0.0, -dx, 5120000.0 + ny * dx)
    folder = Path(folder)
    write_raster(folder / "pre.tif", pre, tr, crs)
    write_raster(folder / "post.tif", post, tr, crs)
    return folder / "pre.tif", folder / "post.tif"


def example_models(folder, d3=4.0, d2=1.5):
    """The terrain, sliding surface, 3-D model and 2-D section of the picture."""
    from geodem.geo import Depth, read_elevation, terrain_model
    from geodem.geo.terrain import slip_surface_from_pair

    pre_p, post_p = example_rasters(folder)
    top = read_elevation(pre_p)
    slip = slip_surface_from_pair(top, read_elevation(post_p, like=top), min_depth=0.5)
    m3 = terrain_model(top, d3, base_depth=15.0, layers=[("soil", Depth(4.0))],
                       sliding_surface=slip)
    line = ((60.0, 75.0), (190.0, 75.0))
    m2 = terrain_model(top, d2, base_depth=15.0, layers=[("soil", Depth(4.0))],
                       sliding_surface=slip, dim=2, line=line)
    return top, slip, m3, m2


def _groups(model):
    """(name, exclusive mask) in drawing order: the slide last (on top)."""
    gm = model.group_masks()
    order = [g for g in model.group_order() if g != "slide"] + ["slide"]
    return [(g, gm[g]) for g in order if g in gm]


def plot(path, folder=None):
    """Draw the picture into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import EllipseCollection

    with tempfile.TemporaryDirectory() as tmp:
        top, slip, m3, m2 = example_models(folder or tmp)
    fig = plt.figure(figsize=(15, 4.6))
    # (a) terrain and depletion zone
    ax = fig.add_subplot(1, 3, 1)
    w, s, e, n = top.grid_bounds
    im = ax.imshow(top.z, extent=(w, e, s, n), cmap="terrain", vmin=80, vmax=140)
    X, Y = np.meshgrid(top.x_centres, top.y_centres)
    ax.contour(X, Y, top.z - slip.z, levels=[0.5], colors="#d62728")
    ax.plot(*np.array(m2.line).T, "k--", lw=1)
    ax.set_title("(a) terrain [m]; scar (red); section line")
    ax.set_xlabel("x [m] (local)")
    ax.set_ylabel("y [m]")
    fig.colorbar(im, ax=ax, shrink=0.8)
    # (b) 3-D model
    ax = fig.add_subplot(1, 3, 2, projection="3d")
    # the outer shell only: within 1.5 d of the terrain, or on the faces
    shell = (m3.x[:, 2] > m3.top_z - 1.5 * m3.d) | m3.masks["side_x"] | m3.masks["side_y"]
    for g, sel in _groups(m3):
        sel = sel & shell
        if sel.any():
            p = m3.x[sel]
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=2, c=GROUP_COLOURS.get(g, "k"), label=g,
                       depthshade=False)
    ax.view_init(elev=28, azim=-120)
    ax.set_box_aspect((np.ptp(m3.x[:, 0]), np.ptp(m3.x[:, 1]), 2 * np.ptp(m3.x[:, 2])))
    ax.set_title(f"(b) 3-D model: {m3.n} elements, d = {m3.d:g} m")
    ax.legend(loc="upper left", fontsize=7, markerscale=4)
    # (c) section
    ax = fig.add_subplot(1, 3, 3)
    for g, sel in _groups(m2):
        if sel.any():
            p = m2.x[sel]
            ax.add_collection(EllipseCollection(2 * m2.r[sel], 2 * m2.r[sel], 0.0, units="xy",
                                                offsets=p, transOffset=ax.transData,
                                                facecolors=GROUP_COLOURS.get(g, "k"),
                                                edgecolors="none"))
    sv, xy, zt = top.profile(*m2.line, n=400)
    ax.plot(sv, zt, "k-", lw=1, label="terrain")
    ax.plot(sv, slip.elevation(xy), "r--", lw=1, label="sliding surface")
    ax.set_xlim(0, sv[-1])
    ax.set_ylim(m2.base_z - 2, zt.max() + 22)
    ax.set_aspect("equal")
    ax.set_title(f"(c) 2-D section along the dashed line: {m2.n} elements")
    ax.set_xlabel("distance along the line [m]")
    ax.set_ylabel("z [m]")
    from matplotlib.patches import Patch

    handles = [Patch(color=GROUP_COLOURS.get(g, "k"), label=g) for g, sel in _groups(m2)
               if sel.any()]
    ax.legend(handles=handles + ax.get_legend_handles_labels()[0], loc="upper right",
              fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"n3": m3.n, "n2": m2.n, "slide3": int(m3.masks["slide"].sum())}


if __name__ == "__main__":  # pragma: no cover - command
    out = sys.argv[1] if len(sys.argv) > 1 else "docs/img/terrain_model.png"
    print(plot(out), "->", out)
