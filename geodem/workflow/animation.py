"""Pictures of workflow results shared by every workflow: matplotlib on the Agg backend (None
when it is missing: pictures are optional), the frames to show, GIF animations (Pillow if
installed, else imageio; skipped with the reason when neither is), and the habits of every map
(crack maps, snapshots): axes labelled with their units (:func:`label_map`) and legends beside
the data, never over it (:func:`legend_outside`)."""
from __future__ import annotations

# the GIF writer lives with the other file writers (geodem.io), where `geodem view` uses it too
from geodem.io.gif import gif_writer_missing, pick_frames, save_gif

__all__ = ["pyplot", "label_map", "legend_outside", "figure_rgb", "gif_writer_missing",
           "pick_frames", "save_gif"]


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


def figure_rgb(fig):
    """The drawn matplotlib figure as an (H, W, 3) uint8 array (one animation frame)."""
    import numpy as np

    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
