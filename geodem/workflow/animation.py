"""Pictures of workflow results shared by every workflow: matplotlib on the Agg backend (None
when it is missing: pictures are optional), the frames to show, and GIF animations (imageio if
installed, else Pillow; skipped with the reason when neither is)."""
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
