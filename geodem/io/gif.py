"""GIF animations from RGB frames: Pillow if installed, else imageio; None with the reason
when neither is (:func:`gif_writer_missing`). Used by the workflows' animations and by
``geodem view RUN_DIR -o FILE.gif``."""
from __future__ import annotations


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


def save_gif(path, images, fps: float = 8.0):
    """Write the RGB frames ``images`` as a looping GIF at ``fps`` frames per second; returns
    ``path``, or None when no GIF writer is installed (:func:`gif_writer_missing`). Pillow
    first: its frame duration is in milliseconds in every version, where imageio's ``duration``
    changed from seconds to milliseconds (2.28) and a 1/fps there played at full speed."""
    images = list(images)
    if not images:
        return None
    ms = int(round(1000.0 / fps))
    try:
        from PIL import Image
    except ImportError:
        try:
            import imageio.v3 as iio
        except ImportError:
            return None
        iio.imwrite(path, images, duration=ms, loop=0)
        return path
    pics = [Image.fromarray(im) for im in images]
    pics[0].save(path, save_all=True, append_images=pics[1:], duration=ms, loop=0)
    return path
