"""Pictures of the ``landslide`` step (matplotlib, off-screen): velocity history, deposit map,
snapshots and the GIF animation. Each function returns the path, or None when matplotlib is not
usable (the step then says "skipped" in summary.json)."""
from __future__ import annotations

import math

import numpy as np

from geodem.workflow.animation import figure_rgb, label_map, legend_outside, pick_frames, \
    pyplot, save_gif


def velocity_history(path, a, res):
    """Mean and largest element speed of the slide body, and its mass centre's horizontal
    travel, against the time since the trigger."""
    plt = pyplot()
    if plt is None or len(a) == 0:
        return None
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True)
    t = a[:, 1]
    a1.plot(t, a[:, 2], "C0-", label=f"mean speed (max {res['max_velocity']:.3g} m/s)")
    a1.plot(t, a[:, 3], "C1-", lw=0.8, label="fastest element")
    a1.set_ylabel("speed [m/s]")
    a1.set_title(f"slide body: {res['slide_elements']} elements, stopped by "
                 f"{res['stopped_by']}")
    a1.legend(fontsize="small")
    a1.grid(alpha=0.3)
    a2.plot(t, a[:, 5] - a[0, 5], "C2-", label="mass centre: horizontal travel")
    a2.plot(t, a[0, 6] - a[:, 6], "C3-", label="mass centre: drop")
    a2.set_xlabel("time since the trigger [s]")
    a2.set_ylabel("[m]")
    a2.legend(fontsize="small")
    a2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _discs(ax, xy, r, colours, **kw):
    from matplotlib.collections import EllipseCollection

    coll = EllipseCollection(2 * r, 2 * r, np.zeros_like(r), units="xy", offsets=xy,
                             offset_transform=ax.transData, **kw)
    if colours is not None and np.ndim(colours) == 1 and np.asarray(colours).dtype.kind == "f":
        coll.set_array(np.asarray(colours))
    elif colours is not None:
        coll.set_facecolor(colours)
    ax.add_collection(coll)
    return coll


def _section_view(ax, ref, r, slide, xs, speed, info, vmax, title):
    """A 2-D section: ground grey, slide elements coloured by speed, terrain and sliding
    surface lines."""
    ground = np.setdiff1d(np.arange(len(r)), slide)
    _discs(ax, ref[ground], r[ground], "0.8", edgecolors="none")
    coll = _discs(ax, xs, r[slide], speed, cmap="plasma", edgecolors="none")
    coll.set_clim(0.0, vmax)
    _profile_lines(ax, info.get("profile"), 0.7, labels=False)
    ax.set_xlim(ref[:, 0].min() - r.max(), ref[:, 0].max() + r.max())
    ax.set_ylim(info["base_z"], max(ref[:, 1].max(), xs[:, 1].max()) + 3 * r.max())
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=8)
    label_map(ax, ("distance along the section", "elevation"), fontsize=7)
    return coll


def _plan_view(ax, ref, r, slide, xs, speed, vmax, title):
    """A 3-D model in plan: the ground's top layer grey, slide elements by speed."""
    ground = np.setdiff1d(np.arange(len(r)), slide)
    ax.scatter(ref[ground, 0], ref[ground, 1], s=1, c="0.85", lw=0)
    sc = ax.scatter(xs[:, 0], xs[:, 1], s=3, c=speed, cmap="plasma", vmin=0, vmax=vmax, lw=0)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=8)
    label_map(ax, fontsize=7)
    return sc


def _view(ax, dim, ref, r, slide, xs, speed, info, vmax, title):
    if dim == 2:
        return _section_view(ax, ref, r, slide, xs, speed, info, vmax, title)
    return _plan_view(ax, ref, r, slide, xs, speed, vmax, title)


def deposit_map(path, dim, ref, r, slide, x0, x, moved, info, res):
    """Before and after: 2-D, the section with the source (light) and the deposit (red), the
    travel-angle line from the crown top to the deposit tip and the runout; 3-D, the plan view
    of the source and the deposit coloured by the elevation change."""
    plt = pyplot()
    if plt is None:
        return None
    if dim == 2:
        fig, ax = plt.subplots(figsize=(10, 4.2))
        ground = np.setdiff1d(np.arange(len(r)), slide)
        _discs(ax, ref[ground], r[ground], "0.82", edgecolors="none")
        _discs(ax, x0, r[slide], "#9ecae1", edgecolors="none", alpha=0.6)
        cols = np.where(moved[:, None], np.array([[0.84, 0.15, 0.16, 1.0]]),
                        np.array([[0.4, 0.4, 0.4, 1.0]]))
        _discs(ax, x, r[slide], cols, edgecolors="none")
        _profile_lines(ax, info.get("profile"), 0.8, labels=True)
        sgn = res["direction"][0]
        if res.get("travel_angle_deg") is not None:
            xc, xt = sgn * res["crown_h"], sgn * res["front_h"]
            ax.plot([xc, xt], [res["crown_z"], res["tip_z"]], "g-", lw=1.2,
                    label=f"travel angle {res['travel_angle_deg']:.1f} deg")
            xtoe = sgn * res["source_toe_h"]
            y = info["base_z"] + 2 * r.max()
            ax.annotate("", xy=(xt, y), xytext=(xtoe, y),
                        arrowprops=dict(arrowstyle="<->", color="C3"))
            ax.text(0.5 * (xt + xtoe), y + r.max(), f"runout {res['runout_m']:.0f} m",
                    color="C3", ha="center", fontsize=8)
        ax.plot([], [], "o", color="#9ecae1", label="source (before)")
        ax.plot([], [], "o", color="C3", label=f"deposit ({res['deposit_volume_m3']:.0f} m^3/m)")
        ax.set_xlim(ref[:, 0].min(), ref[:, 0].max())
        ax.set_ylim(info["base_z"], max(ref[:, 1].max(), x[:, 1].max()) + 3 * r.max())
        ax.set_aspect("equal")
        ax.set_xlabel("distance along the section [m]")
        ax.set_ylabel("elevation [m]")
        ax.legend(fontsize=7, loc="best")
    else:
        fig, ax = plt.subplots(figsize=(8, 5))
        ground = np.setdiff1d(np.arange(len(r)), slide)
        ax.scatter(ref[ground, 0], ref[ground, 1], s=1, c="0.85", lw=0)
        ax.scatter(x0[:, 0], x0[:, 1], s=3, c="#9ecae1", lw=0, label="source")
        sc = ax.scatter(x[moved, 0], x[moved, 1], s=4, c=x[moved, 2] - x0[moved, 2],
                        cmap="RdBu", lw=0, label="deposit")
        fig.colorbar(sc, ax=ax, label="elevation change [m]")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        # the ground fills the plan: the legend goes above it (the colour bar is on the right)
        legend_outside(ax, fontsize=7, side="top", markerscale=3)
    ta = res.get("travel_angle_deg")
    title = (f"runout {res['runout_m']:.1f} m, travel angle "
             f"{'n/a' if ta is None else f'{ta:.1f}'} deg, max mean speed "
             f"{res['max_velocity']:.2g} m/s, H_c/L_c = {res['com_ratio']:.3g}")
    if dim == 2:
        ax.set_title(title, fontsize=9)
    else:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _load(frames, n):
    pick = pick_frames(frames, n)
    return [np.load(frames[k]) for k in pick]


def _speed(z):
    return np.linalg.norm(z["v"].astype(float), axis=1)


def snapshots(path, dim, ref, r, slide, frames, n, info):
    """``n`` panels of the slide body spread over the runout (colour: element speed)."""
    plt = pyplot()
    if plt is None or not frames:
        return None
    data = _load(frames, n)
    vmax = max(float(np.percentile(_speed(z), 99)) for z in data) or 1.0
    cols = 1 if dim == 2 else min(3, len(data))
    rows = int(math.ceil(len(data) / cols))
    size = (9, 1.9 * rows + 0.6) if dim == 2 else (3.4 * cols + 1, 3 * rows)
    fig, axes = plt.subplots(rows, cols, figsize=size, squeeze=False, layout="constrained")
    coll = None
    for ax, z in zip(axes.ravel(), data):
        coll = _view(ax, dim, ref, r, slide, z["x"].astype(float), _speed(z), info, vmax,
                     f"t = {float(z['time']):.1f} s")
    for ax in axes.ravel()[len(data):]:
        ax.axis("off")
    fig.colorbar(coll, ax=axes.ravel().tolist(), label="speed [m/s]", shrink=0.8)
    fig.savefig(path, dpi=70)
    plt.close(fig)
    return path


def animation(path, dim, ref, r, slide, frames, n, info):
    """GIF of the runout (Pillow if installed, else imageio)."""
    plt = pyplot()
    if plt is None or not frames:
        return None
    data = _load(frames, n)
    vmax = max(float(np.percentile(_speed(z), 99)) for z in data) or 1.0
    fig, ax = plt.subplots(figsize=(8, 3.2) if dim == 2 else (5, 4))
    images = []
    for z in data:
        ax.clear()
        _view(ax, dim, ref, r, slide, z["x"].astype(float), _speed(z), info, vmax,
              f"t = {float(z['time']):.1f} s")
        images.append(figure_rgb(fig))
    plt.close(fig)
    return save_gif(path, images, fps=8)


def _profile_lines(ax, prof, lw, labels):
    """The ground before (solid) and the sliding surface (dashed) along a 2-D section: the
    landslide model's ``slip``, or a terrain scene's surface regions (``surfaces``)."""
    if not prof:
        return
    ax.plot(prof["s"], prof["top"], "k-", lw=lw, label="ground before" if labels else None)
    if "slip" in prof:
        lines = {"sliding surface": prof["slip"]}
    else:  # a scene's surface regions: one is the sliding surface
        found = prof.get("surfaces") or {}
        lines = ({"sliding surface": z for z in found.values()} if len(found) == 1
                 else {f"surface of {name}": z for name, z in found.items()})
    for name, z in lines.items():
        ax.plot(prof["s"], z, "k--", lw=lw - 0.1, label=name if labels else None)
