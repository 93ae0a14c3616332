"""Images -> material groups: pixel colours or label values mapped to named materials.

:func:`read_labels` turns an image (a file Pillow reads: PNG, BMP, TIFF, JPEG, ...; or an array
(H, W) of label values or (H, W, 3|4) of RGB(A) colours) into a :class:`LabelImage`: one material
index per pixel.

* ``colours={name: colour}``: a colour is ``(r, g, b)`` (0-255) or ``"#rrggbb"``, or a list of
  them (several colours for one material). A pixel takes the material of the NEAREST configured
  colour in the Chebyshev distance ``max(|dr|, |dg|, |db|)`` if that distance is ``<=
  tolerance`` (default 0: exact colours; JPEG-compressed images need ~20-40). Alpha is ignored.
* ``values={name: value}`` (or a list of values): label images (one band); exact matches.
* ``empty=[...]``: colours (or values) that mean "no material" (air, water): label ``-1``.
* Colour values are whole numbers 0-255 (an integer array, or floats holding whole numbers);
  a float image in 0..1 (matplotlib's ``imread`` of a PNG) is refused, not truncated: pass
  ``np.round(image * 255)``. An empty image (no pixel) is refused.
* Any other pixel -> :class:`GeometryError` listing the unmapped colours found (the most
  frequent first, with pixel counts) and the ones configured.

:func:`assign_groups` maps element centres onto the image and puts the elements of each material
in the group of that name. The image covers ``extent = (u_min, v_min, u_max, v_max)`` of the
model's ``plane`` (pixel edges); columns run along u (left to right) and rows along v from the top
(row 0 at ``v_max``), so a picture looks the same as the model seen from +z (plan, ``"xy"``) or
from -y (section, ``"xz"``; ``"yz"`` from +x). Pixel of a centre:
``col = floor((u - u_min) / (u_max - u_min) * W)``,
``row = floor((v_max - v) / (v_max - v_min) * H)`` (clamped to the image on its far edges).
In 3-D a plan image is extruded along z and a section along the remaining axis.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from geodem.geo.errors import GeometryError

__all__ = ["LabelImage", "read_labels", "pixel_labels", "assign_groups", "EMPTY", "OUTSIDE"]

#: label of pixels whose colour is in ``empty``
EMPTY = -1
#: label returned by :func:`pixel_labels` for points outside the image (``outside="keep"``)
OUTSIDE = -2
_PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


@dataclass
class LabelImage:
    """``labels`` (H, W) int32: index into ``names``, or :data:`EMPTY` (-1); row 0 is the
    image's top. ``counts``: pixels per name (and ``"(empty)"``)."""

    labels: np.ndarray
    names: list
    counts: dict = field(default_factory=dict)
    source: str = ""

    @property
    def shape(self):
        return self.labels.shape


def _colour(c, where):
    if isinstance(c, str):
        h = c.strip().lstrip("#")
        if len(h) != 6:
            raise GeometryError(f"{where}: colour {c!r} is not '#rrggbb'")
        try:
            return tuple(int(h[i:i + 2], 16) for i in (0, 2, 4))
        except ValueError:
            raise GeometryError(f"{where}: colour {c!r} is not '#rrggbb'") from None
    try:
        t = tuple(int(v) for v in c)
    except (TypeError, ValueError):
        raise GeometryError(f"{where}: colour {c!r} is not (r, g, b) or '#rrggbb'") from None
    if len(t) not in (3, 4) or not all(0 <= v <= 255 for v in t):
        raise GeometryError(f"{where}: colour {c!r} must have 3 values in 0..255")
    return t[:3]


def _many(v, colour=False):
    """A single colour (or value), or a list of them -> list. For colours, a flat sequence of 3
    or 4 numbers is ONE colour (r, g, b[, a])."""
    if isinstance(v, str) or np.isscalar(v):
        return [v]
    v = list(v)
    if colour and len(v) in (3, 4) and all(np.isscalar(e) and not isinstance(e, str)
                                            for e in v):
        return [tuple(v)]
    return v


def _hex(rgb):
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def _load(source):
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        from geodem.extras import needs_extra

        with needs_extra("reading images"):
            from PIL import Image
        if not os.path.exists(name):
            raise GeometryError(f"{name}: no such file")
        try:
            with Image.open(name) as im:
                if im.mode in ("P", "PA", "LA", "RGBA", "CMYK", "YCbCr", "1", "HSV", "LAB"):
                    im = im.convert("RGB") if im.mode != "1" else im.convert("L")
                arr = np.asarray(im)
        except OSError as exc:
            raise GeometryError(f"{name}: cannot be read as an image ({exc})") from None
        return arr, name
    return np.asarray(source), "<array>"


def read_labels(source, colours=None, values=None, *, tolerance=0.0, empty=None) -> LabelImage:
    """Label image from ``source`` (see the module docstring): a path or an array."""
    arr, name = _load(source)
    if arr.size == 0 or arr.ndim < 2 or min(arr.shape[:2]) < 1:
        raise GeometryError(f"{name}: the image is empty (shape {arr.shape}); an image needs at "
                            "least 1 x 1 pixels")
    if (colours is None) == (values is None):
        raise GeometryError("give exactly one of colours={name: (r, g, b)} or values={name: v}")
    table = colours if colours is not None else values
    if not isinstance(table, dict) or not table:
        raise GeometryError("colours/values must be a non-empty dict {material name: ...}")
    names = [str(k) for k in table]
    empty = [] if empty is None else _many(empty, colour=colours is not None)
    if colours is not None:
        if arr.ndim != 3 or arr.shape[2] not in (3, 4):
            raise GeometryError(f"{name}: a colour image needs shape (H, W, 3|4) (RGB), got "
                                f"{arr.shape}; use values= for a label image")
        tol = float(tolerance)
        if not (np.isfinite(tol) and tol >= 0):
            raise GeometryError(f"tolerance must be >= 0 (0-255 colour units), got {tolerance}")
        rgb = arr[..., :3]
        if rgb.dtype.kind == "f":
            whole = np.isfinite(rgb) & (rgb == np.round(rgb))
            if not whole.all():
                lo, hi = np.nanmin(rgb), np.nanmax(rgb)
                raise GeometryError(
                    f"{name}: colour values must be whole numbers in 0..255; this "
                    f"{arr.dtype} image has {int((~whole).sum())} values that are not (range "
                    f"{lo:g} .. {hi:g}{', NaN' if np.isnan(rgb).any() else ''}). Floats in "
                    "0..1 (e.g. from matplotlib's imread): pass np.round(image * 255)")
        elif rgb.dtype.kind not in "iub":
            raise GeometryError(f"{name}: colour values must be integers in 0..255, got an "
                                f"array of {arr.dtype}")
        rgb = rgb.astype(np.int64)
        if rgb.min() < 0 or rgb.max() > 255:
            raise GeometryError(f"{name}: colour values must lie in 0..255, got "
                                f"{int(rgb.min())} .. {int(rgb.max())}")
        key = (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]
        ukey, inv, cnt = np.unique(key.ravel(), return_inverse=True, return_counts=True)
        ucol = np.stack([(ukey >> 16) & 255, (ukey >> 8) & 255, ukey & 255], axis=1)
        conf, conf_lab = [], []
        for k, n in enumerate(names):
            for c in _many(table[n], True):
                conf.append(_colour(c, f"colours[{n!r}]"))
                conf_lab.append(k)
        for c in empty:
            conf.append(_colour(c, "empty"))
            conf_lab.append(EMPTY)
        conf = np.array(conf, np.int64)
        dist = np.abs(ucol[:, None, :] - conf[None, :, :]).max(axis=2)  # (U, K) Chebyshev
        best = np.argmin(dist, axis=1)
        ok = dist[np.arange(len(ucol)), best] <= tol
        ulab = np.where(ok, np.asarray(conf_lab)[best], -3)
        if not ok.all():
            bad = np.flatnonzero(~ok)
            bad = bad[np.argsort(-cnt[bad], kind="stable")]
            shown = ", ".join(f"{tuple(int(v) for v in ucol[i])} {_hex(ucol[i])} x {cnt[i]} px"
                              for i in bad[:5])
            more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
            cfg = ", ".join(f"{n}={[_hex(_colour(c, n)) for c in _many(table[n], True)]}"
                            for n in names)
            if empty:
                cfg += f", empty={[_hex(_colour(c, 'empty')) for c in empty]}"
            npx = int(cnt[bad].sum())
            raise GeometryError(
                f"{name}: {npx} of {key.size} pixels ({100.0 * npx / key.size:.1f} %) have "
                f"colours mapped to no material: {shown}{more}. Configured: {cfg} (tolerance "
                f"{tol:g}). Add the colours to colours= or empty=, or raise tolerance")
        labels = ulab[inv].reshape(key.shape)
    else:
        if arr.ndim == 3 and arr.shape[2] == 1:
            arr = arr[..., 0]
        if arr.ndim != 2:
            raise GeometryError(f"{name}: a label image needs one band, shape (H, W), got "
                                f"{arr.shape}; use colours= for an RGB image")
        uval, inv, cnt = np.unique(arr.ravel(), return_inverse=True, return_counts=True)
        ulab = np.full(len(uval), -3, np.int64)
        for k, n in enumerate(names):
            for v in _many(table[n]):
                ulab[uval == v] = k
        for v in empty:
            ulab[uval == v] = EMPTY
        bad = np.flatnonzero(ulab == -3)
        if bad.size:
            bad = bad[np.argsort(-cnt[bad], kind="stable")]
            shown = ", ".join(f"{uval[i].item()!r} x {cnt[i]} px" for i in bad[:5])
            more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
            cfg = ", ".join(f"{n}={_many(table[n])}" for n in names)
            npx = int(cnt[bad].sum())
            raise GeometryError(
                f"{name}: {npx} of {arr.size} pixels ({100.0 * npx / arr.size:.1f} %) have "
                f"values mapped to no material: {shown}{more}. Configured: {cfg}"
                + (f", empty={empty}" if empty else "")
                + ". Add the values to values= or empty=")
        labels = ulab[inv].reshape(arr.shape)
    if min(labels.shape) < 1:
        raise GeometryError(f"{name}: the image is empty (shape {labels.shape})")
    counts = {n: int((labels == k).sum()) for k, n in enumerate(names)}
    counts["(empty)"] = int((labels == EMPTY).sum())
    return LabelImage(labels=labels.astype(np.int32), names=names, counts=counts, source=name)


def _plane_axes(dim, plane):
    if dim == 2:
        if plane not in ("xy", None):
            raise GeometryError(f"a 2-D model has only the plane 'xy', got {plane!r}")
        return 0, 1
    if plane not in _PLANES:
        raise GeometryError(f"plane must be one of {sorted(_PLANES)}, got {plane!r}")
    return _PLANES[plane]


def pixel_labels(x, image: LabelImage, extent, plane="xy", outside="error") -> np.ndarray:
    """Label of each point ``x`` (N, dim) [m] (module docstring for the mapping).

    Points outside ``extent`` (beyond a tolerance of ``1e-9`` x its size) or not finite (NaN,
    inf): ``outside="error"`` -> :class:`GeometryError`; ``"keep"`` -> :data:`OUTSIDE` (-2);
    ``"clamp"`` -> the nearest edge pixel (a point that is not finite has none: error)."""
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise GeometryError(f"positions must have shape (N, 2) or (N, 3), got {x.shape}")
    a, b = _plane_axes(x.shape[1], plane)
    try:
        umin, vmin, umax, vmax = (float(v) for v in extent)
    except (TypeError, ValueError):
        raise GeometryError(f"extent must be (u_min, v_min, u_max, v_max), got {extent!r}") \
            from None
    if not (umax > umin and vmax > vmin):
        raise GeometryError(f"extent must have u_max > u_min and v_max > v_min, got {extent}")
    H, W = image.labels.shape
    fu = (x[:, a] - umin) / (umax - umin) * W
    fv = (vmax - x[:, b]) / (vmax - vmin) * H
    eps = 1e-9
    bad = ~(np.isfinite(fu) & np.isfinite(fv))  # NaN / inf positions: outside any image
    out = bad | (fu < -eps * W) | (fu > W * (1 + eps)) | (fv < -eps * H) | (fv > H * (1 + eps))
    if outside not in ("error", "keep", "clamp"):
        raise GeometryError(f"outside must be 'error', 'keep' or 'clamp', got {outside!r}")
    if out.any() and (outside == "error" or (outside == "clamp" and bad.any())):
        why = []
        if bad.any():
            why.append(f"{int(bad.sum())} not finite (NaN or inf)")
        if (out & ~bad).any():
            lo, hi = x[out & ~bad].min(axis=0), x[out & ~bad].max(axis=0)
            why.append(f"they span {lo.round(6).tolist()} .. {hi.round(6).tolist()}")
        hint = ("a position that is not finite has no nearest pixel; outside='keep' leaves them"
                if outside == "clamp" else
                "give an extent covering the model or outside='keep'/'clamp'")
        raise GeometryError(f"{int(out.sum())} of {len(x)} element centres lie outside the "
                            f"image extent {tuple(extent)} in plane {plane!r} "
                            f"({'; '.join(why)}); {hint}")
    fu, fv = np.where(bad, 0.0, fu), np.where(bad, 0.0, fv)
    col = np.clip(np.floor(fu).astype(np.int64), 0, W - 1)
    row = np.clip(np.floor(fv).astype(np.int64), 0, H - 1)
    lab = image.labels[row, col].astype(np.int64)
    if outside == "keep":
        lab[out] = OUTSIDE
    return lab


def assign_groups(state, image: LabelImage, extent=None, plane="xy", *, only=None,
                  empty="remove", outside="error"):
    """Put the elements of ``state`` into the groups named by ``image`` (see the module
    docstring); returns the state (a new one when elements were removed).

    ``extent`` defaults to the bounding box of the element centres in ``plane``. ``only``: a
    group name or bool mask restricting the elements assigned (e.g. not the fixed base).
    Existing groups of the same names are reused (their other members stay). ``empty``: what to do
    with elements on :data:`EMPTY` pixels: ``"remove"`` them (:func:`geodem.build.shapes.
    subset_state`), ``"keep"`` them unchanged, or ``"error"``. ``outside``: see
    :func:`pixel_labels` (``"keep"`` leaves those elements unchanged).
    """
    from geodem.core import groups as grp

    if not isinstance(image, LabelImage):
        raise GeometryError("image must be a LabelImage (from read_labels)")
    a, b = _plane_axes(state.dim, plane)
    if extent is None:
        lo, hi = state.x.min(axis=0), state.x.max(axis=0)
        extent = (lo[a], lo[b], hi[a], hi[b])
    sel = np.ones(state.n, bool)
    if only is not None:
        sel = state.group_mask(only) if isinstance(only, str) else np.asarray(only, bool)
        if sel.shape != (state.n,):
            raise GeometryError(f"only must be a group name or a bool mask of shape "
                                f"({state.n},)")
    lab = np.full(state.n, OUTSIDE, np.int64)
    lab[sel] = pixel_labels(state.x[sel], image, extent, plane, outside)
    for k, name in enumerate(image.names):
        members = lab == k
        if name in state.groups:
            state.group[members] = state.groups[name]
        else:
            grp.add_group(state, name, members)
    gone = lab == EMPTY
    if gone.any():
        if empty == "error":
            raise GeometryError(f"{int(gone.sum())} elements lie on empty pixels")
        if empty == "remove":
            from geodem.build.shapes import subset_state

            return subset_state(state, ~gone)
        if empty != "keep":
            raise GeometryError(f"empty must be 'remove', 'keep' or 'error', got {empty!r}")
    return state
