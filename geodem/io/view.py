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
#: crack types by name (``--cracks``)
CRACK_KINDS = {"tensile": 1, "shear": 2, "joint": 0}
#: above this many elements the spheres are drawn as screen-space points (fast) not meshes
GLYPH_LIMIT = 200_000


class ViewError(ValueError):
    """A run directory or frame that cannot be drawn (a user error: exit status 2)."""


def crack_kinds(text: str) -> tuple[str, ...]:
    """The crack types ``--cracks`` asks to draw: 'all', 'none' or names from
    :data:`CRACK_KINDS` separated by commas (a landslide's cut bonds are 'joint': its slide
    drags them into long lines)."""
    words = [w.strip() for w in text.lower().split(",") if w.strip()]
    if words == ["all"]:
        return tuple(CRACK_KINDS)
    if words == ["none"]:
        return ()
    bad = [w for w in words if w not in CRACK_KINDS]
    if bad or not words:
        raise ViewError(f"--cracks {text}: allowed: all, none, or a comma-separated list of "
                        f"{', '.join(CRACK_KINDS)}")
    return tuple(dict.fromkeys(words))


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


def _picture_path(out: Path, suffix: str) -> Path:
    """``out`` when it ends in ``suffix`` and its folder exists (else :class:`ViewError`)."""
    if out.suffix.lower() != suffix:
        raise ViewError(f"-o {out}: allowed: a .png file (one frame) or a .gif file (an "
                        "animation of the run's frames)")
    if not out.parent.is_dir():
        raise ViewError(f"-o {out}: the folder {out.parent} does not exist")
    return out


def _opacity(fr: Frame, opacity: float | None, cracks=tuple(CRACK_KINDS)) -> float:
    """The elements' opacity: ``opacity``, else 1 in 2-D and 0.2 in 3-D when cracks of the
    types ``cracks`` are drawn (so the cracks inside the body show)."""
    if opacity is None:
        drawn = np.isin(fr.crack_types, [CRACK_KINDS[k] for k in cracks]).any()
        opacity = 0.2 if (fr.dim == 3 and drawn) else 1.0
    if not 0.0 <= opacity <= 1.0:
        raise ViewError(f"--opacity {opacity}: allowed: 0 to 1")
    return opacity


def _draw(plotter, fr: Frame, opacity: float, size, clim=None,
          cracks=tuple(CRACK_KINDS)) -> dict:
    """Add frame ``fr`` to ``plotter``: the elements (spheres, or points above
    ``GLYPH_LIMIT``) coloured by the frame's field over ``clim`` (default: its own range),
    the cracks of the types ``cracks`` and a caption. Returns the frame's cracks by type."""
    import pyvista as pv

    elements, lines = frame_meshes(fr)
    scalar = "field" if fr.field is not None else None
    font = max(8, int(size[1] / 40))
    bar = ({"title": fr.label, "color": "black", "vertical": True, "position_x": 0.8,
            "position_y": 0.15, "height": 0.7, "width": 0.04, "fmt": "%.2g",
            "title_font_size": font, "label_font_size": font} if scalar else None)
    look = {"scalars": scalar, "cmap": "viridis", "opacity": opacity,
            "color": None if scalar else "tan", "scalar_bar_args": bar,
            "show_scalar_bar": bool(scalar)}
    if scalar and clim is not None:
        look["clim"] = clim
    if fr.x.shape[0] <= GLYPH_LIMIT and np.isfinite(fr.r).all():
        res = 12 if fr.x.shape[0] <= 20_000 else 6
        balls = elements.glyph(scale="radius", orient=False, factor=1.0,
                               geom=pv.Sphere(radius=1.0, theta_resolution=res,
                                              phi_resolution=res))
        plotter.add_mesh(balls, smooth_shading=True, render=False, **look)
    else:  # many elements: screen-space spheres of one size
        plotter.add_mesh(elements, render_points_as_spheres=True, point_size=3, render=False,
                         **look)
    counts = {}
    for name, code in CRACK_KINDS.items():
        sel = np.flatnonzero(fr.crack_types == code)
        counts[name] = int(sel.size)
        if sel.size and name in cracks:
            plotter.add_mesh(lines.extract_cells(sel), color=CRACK_COLORS[code], line_width=2,
                             render_lines_as_tubes=False, render=False)
    plotter.add_text(f"step {fr.step:,}   t = {fr.time:.4g} s   {fr.x.shape[0]:,} elements   "
                     f"cracks: {counts['tensile']} tensile, {counts['shear']} shear",
                     font_size=max(6, int(size[1] / 80)), color="black", render=False)
    return counts


def _plotter(size, show: bool = False):
    import pyvista as pv

    if not show:  # off-screen VTK first tries a display and warns when there is none
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    plotter = pv.Plotter(off_screen=not show, window_size=list(size))
    plotter.set_background("white")
    return plotter


def _aim(plotter, dim: int, bounds=None) -> None:
    """Seen from above in 2-D, isometric in 3-D; framing ``bounds`` (xmin, xmax, ymin, ymax,
    zmin, zmax) when given, else what is drawn."""
    if dim == 2:
        plotter.view_xy()
    else:
        plotter.view_isometric()
    if bounds is not None:
        plotter.reset_camera(bounds=bounds)


def render_frame(run_dir, frame: int = -1, output=None, color: str = "displacement",
                 size=(1200, 900), opacity: float | None = None, show: bool = False,
                 cracks=tuple(CRACK_KINDS)) -> dict:
    """Draw frame ``frame`` of ``run_dir`` to ``output`` (PNG; default
    ``RUN_DIR/view_frame_<index>.png``). Returns what was drawn: path, step, time, elements,
    cracks by type.

    ``opacity`` of the elements: default 1 in 2-D, and 0.2 in 3-D when cracks are drawn (so the
    cracks inside the body show); ``cracks``: the crack types drawn (:func:`crack_kinds`)."""
    from geodem.extras import needs_extra

    fr = read_frame(run_dir, frame, color)  # the run and the frame first: clear errors
    out = _picture_path(Path(output) if output else
                        Path(run_dir) / f"view_frame_{fr.index}.png", ".png")
    with needs_extra("geodem view"):
        plotter = _plotter(size, show)
    counts = _draw(plotter, fr, _opacity(fr, opacity, cracks), size, cracks=cracks)
    _aim(plotter, fr.dim)
    if show:
        plotter.show(screenshot=os.fspath(out))
    else:
        plotter.screenshot(os.fspath(out))
    plotter.close()
    return {"path": os.fspath(out), "frame": fr.index, "frames": fr.count, "step": fr.step,
            "time": fr.time, "elements": int(fr.x.shape[0]), "cracks": counts}


#: the most frames an animation draws (spread evenly over the run's frames)
MAX_ANIMATION_FRAMES = 120


def render_animation(run_dir, output, color: str = "displacement", size=(800, 600),
                     opacity: float | None = None, fps: float = 4.0,
                     max_frames: int = MAX_ANIMATION_FRAMES, progress=None,
                     cracks=tuple(CRACK_KINDS)) -> dict:
    """Draw the frames of ``run_dir`` (at most ``max_frames``, spread evenly, the first and
    last among them) into the looping GIF ``output``, at ``fps`` frames per second. Every
    picture keeps one camera (framing every drawn frame's elements) and one colour scale
    (0 to the largest value of the field over the drawn frames), so motion and growth show.
    ``progress(i, n)`` is called after each picture. Returns path, frames drawn, steps,
    elements and the last frame's cracks by type."""
    from geodem.extras import needs_extra
    from geodem.io.gif import gif_writer_missing, pick_frames, save_gif

    first = read_frame(run_dir, 0, color)
    out = _picture_path(Path(output), ".gif")
    # one opacity for every picture: the last frame's (see through when it has cracks)
    opacity = _opacity(read_frame(run_dir, -1, color), opacity, cracks)
    if first.count < 2:
        raise ViewError(f"{run_dir}: the run holds {first.count} frame; an animation needs 2 or "
                        "more (outputs.frames.every: N writes a frame every N steps)")
    if not 2 <= max_frames <= 10_000:
        raise ViewError(f"--max-frames {max_frames}: allowed: 2 to 10000")
    if not 0.1 <= fps <= 60:
        raise ViewError(f"--fps {fps}: allowed: 0.1 to 60")
    if (why := gif_writer_missing()) is not None:
        raise ViewError(f"-o {out}: cannot write a GIF: {why}")
    with needs_extra("geodem view"):
        plotter = _plotter(size)
    picks = [int(k) for k in pick_frames(range(first.count), min(max_frames, first.count))]
    lo, hi, top = np.full(3, np.inf), np.full(3, -np.inf), 0.0
    for k in picks:  # one camera and one colour scale for the whole animation
        fr = read_frame(run_dir, k, color)
        xyz = np.asarray(fr.x, float)
        pad = float(np.nanmax(fr.r)) if len(fr.r) and np.isfinite(fr.r).any() else 0.0
        lo[:fr.dim] = np.minimum(lo[:fr.dim], xyz.min(axis=0) - pad)
        hi[:fr.dim] = np.maximum(hi[:fr.dim], xyz.max(axis=0) + pad)
        if fr.field is not None and fr.field.size:
            top = max(top, float(np.nanmax(fr.field)))
    if first.dim == 2:
        lo[2], hi[2] = 0.0, 0.0
    bounds = [v for pair in zip(lo, hi) for v in pair]
    clim = (0.0, top if top > 0 else 1.0)
    images, steps, counts = [], [], {}
    for i, k in enumerate(picks):
        fr = read_frame(run_dir, k, color)
        # drawing renders nothing (render=False): a render of 10^4 spheres in software takes
        # seconds, and one is enough, the screenshot's
        for name in list(plotter.actors):
            plotter.remove_actor(name, render=False)
        for title in list(plotter.scalar_bars.keys()):  # drawn again with the new elements
            plotter.remove_scalar_bar(title, render=False)
        counts = _draw(plotter, fr, opacity, size, clim, cracks)
        if i == 0:
            _aim(plotter, fr.dim, bounds)
        plotter.render()
        images.append(plotter.screenshot(return_img=True))
        steps.append(fr.step)
        if progress is not None:
            progress(i + 1, len(picks))
    plotter.close()
    save_gif(os.fspath(out), images, fps)
    return {"path": os.fspath(out), "frames": len(picks), "frames_in_run": first.count,
            "steps": [steps[0], steps[-1]], "elements": int(first.x.shape[0]),
            "cracks": counts}
