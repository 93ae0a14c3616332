"""Pictures of a run's frames (``geodem view``): the elements of one frame of ``output.h5`` as
spheres (3-D) or discs seen from above (2-D), coloured by a field, and the bonds broken up to
that frame's time drawn as line cells between the two elements' positions (red: tensile, blue:
shear, grey: joint). Rendered off-screen with pyvista (the ``vis`` extra); ``show=True`` opens
a window where a display is available.

The frame is read with h5py (:func:`read_frame`); :func:`frame_meshes` turns it into pyvista
meshes, so the same meshes can be saved for ParaView (``.vtp``) or drawn.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from geodem.io.vtk import crack_lines, to_xyz

COLOR_FIELDS = ("displacement", "velocity", "radius", "none")
#: crack colours by type (geodem.core.engine.Simulation.crack_log: 1 tensile, 2 shear, 0 joint)
CRACK_COLORS = {1: "red", 2: "blue", 0: "grey"}
#: above this many elements the spheres are drawn as screen-space points (fast) not meshes
GLYPH_LIMIT = 200_000


class ViewError(ValueError):
    """A run directory or frame that cannot be drawn (a user error: exit status 2)."""


@dataclasses.dataclass
class Frame:
    """One frame of a run: element centres ``x`` (n, dim) [m], radii ``r`` [m], the colour
    ``field`` (n,) with its ``label``, and the cracks up to ``time`` as row pairs with types."""

    step: int
    time: float
    index: int
    count: int
    dim: int
    x: np.ndarray
    r: np.ndarray
    field: np.ndarray | None
    label: str
    crack_rows: np.ndarray  # (m, 2) rows of the two elements of each broken bond
    crack_types: np.ndarray  # (m,)


def _output_file(run_dir) -> Path:
    run = Path(run_dir)
    if not run.is_dir():
        raise ViewError(f"{run_dir}: no such run directory; allowed: a folder written by "
                        "'geodem run -o DIR'")
    out = run / "output.h5"
    if not out.is_file():
        raise ViewError(f"{out}: no output.h5 in the run directory (outputs.frames writes it); "
                        "allowed: a folder written by 'geodem run -o DIR'")
    return out


def read_frame(run_dir, frame: int = -1, color: str = "displacement") -> Frame:
    """Frame ``frame`` (Python indexing: -1 is the last) of ``RUN_DIR/output.h5``."""
    import h5py

    if color not in COLOR_FIELDS:
        raise ViewError(f"--color {color}: unknown field; allowed: {', '.join(COLOR_FIELDS)}")
    path = _output_file(run_dir)
    with h5py.File(path, "r") as f:
        if "particles/all/position/value" not in f:
            raise ViewError(f"{path}: no element positions (outputs.frames.fields must hold "
                            "'position' for the group 'all')")
        g = f["particles/all"]
        steps = g["position/step"][()]
        count = len(steps)
        if not -count <= frame < count:
            raise ViewError(f"--frame {frame}: {path} holds {count} frames (steps "
                            f"{', '.join(str(int(s)) for s in steps[:6])}"
                            f"{', ...' if count > 6 else ''}); allowed: {-count} to {count - 1}")
        k = frame % count
        x = g["position/value"][k]
        n, dim = x.shape
        r = g["radius"][()] if "radius" in g else np.full(n, np.nan)
        ids = g["id"][()] if "id" in g else np.arange(n)
        if len(r) != n or len(ids) != n:
            raise ViewError(f"{path}: frame {k} holds {n} elements but the model's static "
                            f"arrays {len(r)} (elements were removed during the run); "
                            "allowed: a frame before the first removal")
        field, label = None, ""
        if color == "displacement" and "reference_position" in g:
            field = np.linalg.norm(x - g["reference_position"][()], axis=1)
            label = "displacement [m]"
        elif color == "displacement":
            first = g["position/value"][0]
            field, label = np.linalg.norm(x - first, axis=1), "displacement from frame 0 [m]"
        elif color == "velocity":
            if "velocity/value" not in g:
                raise ViewError(f"--color velocity: {path} has no velocities (add 'velocity' "
                                "to outputs.frames.fields)")
            field, label = np.linalg.norm(g["velocity/value"][k], axis=1), "speed [m/s]"
        elif color == "radius":
            field, label = r, "radius [m]"
        time = float(g["position/time"][k])
        pairs = np.zeros((0, 2), np.int64)
        types = np.zeros(0, np.int8)
        if "cracks/i" in f:
            sel = f["cracks/time"][()] <= time * (1 + 1e-12)
            log = {k: f[f"cracks/{k}"][()][sel] for k in ("i", "j", "type")}
            pairs, types = crack_lines(ids, log)
    return Frame(int(steps[k]), time, k, count, dim, x, r, field, label, pairs, types)


def frame_meshes(fr: Frame):
    """``(elements, cracks)`` pyvista PolyData: the element centres with their radius and colour
    field as point data; the cracks as line cells (cell data ``crack_type``)."""
    import pyvista as pv

    pts = to_xyz(fr.x)
    elements = pv.PolyData(pts)
    elements["radius"] = fr.r
    if fr.field is not None:
        elements["field"] = fr.field
    lines = np.column_stack([np.full(len(fr.crack_rows), 2), fr.crack_rows]).ravel()
    lifted = pts.copy()
    if fr.dim == 2:  # above the discs, so that the picture (seen from +z) shows them
        lifted[:, 2] = 1.01 * float(np.nanmax(fr.r)) if len(fr.r) else 0.0
    cracks = pv.PolyData(lifted, lines=lines) if len(fr.crack_rows) else pv.PolyData()
    if len(fr.crack_rows):
        cracks.cell_data["crack_type"] = fr.crack_types.astype(np.int32)
    return elements, cracks


def render_frame(run_dir, frame: int = -1, output=None, color: str = "displacement",
                 size=(1200, 900), opacity: float | None = None, show: bool = False) -> dict:
    """Draw frame ``frame`` of ``run_dir`` to ``output`` (PNG; default
    ``RUN_DIR/view_frame_<index>.png``). Returns what was drawn: path, step, time, elements,
    cracks by type.

    ``opacity`` of the elements: default 1 in 2-D, and 0.2 in 3-D when cracks are drawn (so the
    cracks inside the body show)."""
    from geodem.extras import needs_extra

    fr = read_frame(run_dir, frame, color)  # the run and the frame first: clear errors
    with needs_extra("geodem view"):
        import pyvista as pv
    out = Path(output) if output else Path(run_dir) / f"view_frame_{fr.index}.png"
    if out.suffix.lower() != ".png":
        raise ViewError(f"-o {out}: allowed: a .png file")
    if not out.parent.is_dir():
        raise ViewError(f"-o {out}: the folder {out.parent} does not exist")
    if opacity is None:
        opacity = 0.2 if (fr.dim == 3 and len(fr.crack_rows)) else 1.0
    if not 0.0 <= opacity <= 1.0:
        raise ViewError(f"--opacity {opacity}: allowed: 0 to 1")
    elements, cracks = frame_meshes(fr)
    plotter = pv.Plotter(off_screen=not show, window_size=list(size))
    plotter.set_background("white")
    scalar = "field" if fr.field is not None else None
    font = max(8, int(size[1] / 40))
    bar = ({"title": fr.label, "color": "black", "vertical": True, "position_x": 0.8,
            "position_y": 0.15, "height": 0.7, "width": 0.04, "fmt": "%.2g",
            "title_font_size": font, "label_font_size": font} if scalar else None)
    if fr.x.shape[0] <= GLYPH_LIMIT and np.isfinite(fr.r).all():
        res = 12 if fr.x.shape[0] <= 20_000 else 6
        balls = elements.glyph(scale="radius", orient=False, factor=1.0,
                               geom=pv.Sphere(radius=1.0, theta_resolution=res,
                                              phi_resolution=res))
        plotter.add_mesh(balls, scalars=scalar, cmap="viridis", opacity=opacity,
                         color=None if scalar else "tan", scalar_bar_args=bar,
                         show_scalar_bar=bool(scalar), smooth_shading=True)
    else:  # many elements: screen-space spheres of one size
        plotter.add_mesh(elements, scalars=scalar, cmap="viridis", opacity=opacity,
                         render_points_as_spheres=True, point_size=3,
                         color=None if scalar else "tan", scalar_bar_args=bar,
                         show_scalar_bar=bool(scalar))
    counts = {}
    for code, name in ((1, "tensile"), (2, "shear"), (0, "joint")):
        sel = np.flatnonzero(fr.crack_types == code)
        counts[name] = int(sel.size)
        if sel.size:
            plotter.add_mesh(cracks.extract_cells(sel), color=CRACK_COLORS[code], line_width=2,
                             render_lines_as_tubes=False)
    if fr.dim == 2:
        plotter.view_xy()
    else:
        plotter.view_isometric()
    plotter.add_text(f"step {fr.step:,}   t = {fr.time:.4g} s   {fr.x.shape[0]:,} elements   "
                     f"cracks: {counts['tensile']} tensile, {counts['shear']} shear",
                     font_size=max(6, int(size[1] / 80)), color="black")
    if show:
        plotter.show(screenshot=os.fspath(out))
    else:
        plotter.screenshot(os.fspath(out))
    plotter.close()
    return {"path": os.fspath(out), "frame": fr.index, "frames": fr.count, "step": fr.step,
            "time": fr.time, "elements": int(fr.x.shape[0]), "cracks": counts}
