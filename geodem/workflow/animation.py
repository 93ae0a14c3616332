"""Pictures of workflow results shared by every workflow: matplotlib on the Agg backend (None
when it is missing: pictures are optional), the frames to show, GIF animations (imageio if
installed, else Pillow; skipped with the reason when neither is), and the habits of every map
(crack maps, snapshots): axes labelled with their units (:func:`label_map`) and legends beside
the data, never over it (:func:`legend_outside`)."""
from __future__ import annotations


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend, or None when not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:  # noqa: BLE001 - pictures are optional
        return None
    return plt


def label_map(ax, names=("x", "y"), unit="m", fontsize=7) -> None:
    """Label a map's axes ``"x [m]"``, ``"y [m]"`` (or ``names``), with small tick labels."""
    ax.set_xlabel(f"{names[0]} [{unit}]", fontsize=fontsize)
    ax.set_ylabel(f"{names[1]} [{unit}]", fontsize=fontsize)
    ax.tick_params(labelsize=fontsize - 1)


def legend_outside(ax, handles=None, labels=None, fontsize="small", side="right", **kw):
    """A legend outside the data area of ``ax``: to its right (``side="right"``: a map's data
    fills the axes, any corner inside would cover elements or cracks) or above it
    (``side="top"``, in two columns: for twin axes, whose right side holds the second y
    axis and whose data ``loc="best"`` cannot see); None when there is nothing to list."""
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return None
    if side == "top":
        kw.setdefault("ncol", 2)
        return ax.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.0, 1.02),
                         borderaxespad=0.0, fontsize=fontsize, **kw)
    return ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                     borderaxespad=0.0, fontsize=fontsize, **kw)


def pick_frames(frames, n: int):
    """Indices of ``n`` frames spread evenly over ``frames`` (first and last included)."""
    import numpy as np

    return np.unique(np.linspace(0, len(frames) - 1, n).round().astype(int))


def gif_writer_missing() -> str | None:
    """Why no GIF can be written (None when imageio or Pillow is installed)."""
    for mod in ("imageio", "PIL"):
        try:
            __import__(mod)
            return None
        except ImportError:
            continue
    return "neither imageio nor Pillow is installed (pip install imageio)"


def figure_rgb(fig):
    """The drawn matplotlib figure as an (H, W, 3) uint8 array (one animation frame)."""
    import numpy as np

    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def save_gif(path, images, fps: float = 8.0):
    """Write the RGB frames ``images`` as a looping GIF at ``fps`` frames per second; returns
    ``path``, or None when no GIF writer is installed (:func:`gif_writer_missing`)."""
    images = list(images)
    if not images:
        return None
    try:
        import imageio.v2 as imageio

        imageio.mimsave(path, images, duration=1.0 / fps, loop=0)
        return path
    except ImportError:
        pass
    try:
        from PIL import Image
    except ImportError:
        return None
    pics = [Image.fromarray(im) for im in images]
    pics[0].save(path, save_all=True, append_images=pics[1:], duration=int(1000 / fps), loop=0)
    return path
