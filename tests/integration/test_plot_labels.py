"""Every crack map and snapshot picture a workflow writes: both axes labelled with their units,
and no legend over the data of a map (elements, cracks) or outside the picture.

Each picture function is drawn on small synthetic data; ``Figure.savefig`` is wrapped to look
at the figure as saved (after its layout)."""

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402

RNG = np.random.default_rng(0)


@pytest.fixture
def saved(monkeypatch):
    """The figures saved while the test runs: one dict per figure (``axes``: a dict per
    visible axes, colour bars left out)."""
    out = []
    original = Figure.savefig

    def savefig(fig, *args, **kwargs):
        original(fig, *args, **kwargs)
        fig.canvas.draw()
        out.append(_describe(fig))

    monkeypatch.setattr(Figure, "savefig", savefig)
    return out


def _describe(fig):
    rend = fig.canvas.get_renderer()
    canvas = fig.bbox
    axes = []
    for ax in fig.axes:
        if not ax.axison or ax.get_label() == "<colorbar>":
            continue
        leg = ax.get_legend()
        axes.append({"xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(),
                     "map": ax.get_aspect() == 1.0, "legend": None if leg is None else
                     leg.get_window_extent(rend), "points": _points(ax), "ax": ax})
    shared = {id(a["ax"]): a for a in axes}
    for a in axes:  # a shared x axis is labelled once, on the lowest of the axes
        if not a["xlabel"]:
            a["xlabel"] = next((shared[id(o)]["xlabel"] for o in a["ax"].get_shared_x_axes()
                                .get_siblings(a["ax"]) if id(o) in shared
                                and shared[id(o)]["xlabel"]), "")
    return {"axes": axes, "canvas": canvas}


def _points(ax):
    """Display coordinates of the data drawn in ``ax``: collection offsets (elements,
    cracks as scatter), segment ends and polygon corners, line vertices."""
    pts = []
    for c in ax.collections:
        off = c.get_offsets()
        if len(off):
            pts.append(c.get_offset_transform().transform(off))
        segs = getattr(c, "get_segments", None)
        paths = c.get_paths()
        if segs is not None and segs():
            pts.append(c.get_transform().transform(np.concatenate(segs())))
        elif len(paths) > 1 and not len(off):
            pts.append(c.get_transform().transform(np.concatenate([p.vertices for p in paths])))
    for ln in ax.lines:
        xy = ln.get_xydata()
        if len(xy):
            pts.append(ln.get_transform().transform(xy))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def _check(figures, n_maps):
    assert figures, "no picture was saved"
    maps = 0
    for f in figures:
        for a in f["axes"]:
            for key in ("xlabel", "ylabel"):
                assert "[" in a[key] and a[key].rstrip().endswith("]"), (key, a[key])
            box = a["legend"]
            if box is not None:
                c = f["canvas"]
                assert (box.x0 >= c.x0 - 1 and box.y0 >= c.y0 - 1 and box.x1 <= c.x1 + 1
                        and box.y1 <= c.y1 + 1), f"legend {box} outside the picture {c}"
            if a["map"]:
                maps += 1
                p = a["points"]
                assert len(p), "a map with no data"
                if box is not None:
                    inside = ((p[:, 0] > box.x0 + 1) & (p[:, 0] < box.x1 - 1)
                              & (p[:, 1] > box.y0 + 1) & (p[:, 1] < box.y1 - 1))
                    assert not inside.any(), f"the legend covers {int(inside.sum())} points"
    assert maps >= n_maps


def _grid(nx, ny, d, lo=(0.0, 0.0)):
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    return np.c_[lo[0] + (i.ravel() + 0.5 * (j.ravel() % 2)) * d, lo[1] + j.ravel() * d * 0.87]


def _cracks(x, n):
    pos = x[RNG.choice(len(x), n, replace=False)] + 0.1
    return pos, RNG.choice([1, 2], n)


def test_uniaxial_and_brazilian_crack_maps(tmp_path, saved):
    from geodem.cases.brazilian import _plot as braz_plot
    from geodem.cases.uniaxial import _plot as ucs_plot

    x = _grid(20, 40, 0.0025)
    eps = np.linspace(0.0, 4e-3, 60)
    sig = 1e10 * eps * (1.0 - eps / 8e-3)
    ip = int(np.argmax(sig))
    pos, types = _cracks(x, 60)
    assert ucs_plot(tmp_path / "u.png", eps, sig, 1e10, sig[ip], eps[ip], pos, types, x,
                    np.full(len(x), 1.25e-3))
    disc = x[np.linalg.norm(x - x.mean(0), axis=1) < 0.024]
    assert braz_plot(tmp_path / "b.png", eps * 1e3, sig / 1e9, "platen displacement [mm]",
                     "load P [kN]", "Brazilian", *_cracks(disc, 30), disc, ("x", "z"))
    _check(saved, 2)
    assert saved[1]["axes"][1]["ylabel"] == "z [m]"


def test_triaxial_crack_map(tmp_path, saved):
    from geodem.cases.triaxial import _plot_cracks

    x = _grid(24, 44, 0.0025)
    spec = (x[:, 0] > 0.004) & (x[:, 0] < 0.05) & (x[:, 1] > 0.004) & (x[:, 1] < 0.09)
    pos, types = _cracks(x[spec], 80)
    types[:5] = 0
    assert _plot_cracks(tmp_path / "t.png", x, spec, pos, types, 5e6)
    _check(saved, 1)


def test_thermal_temperature_map(tmp_path, saved):
    from geodem.cases.thermal import _plot_heat, crack_faces

    x = _grid(30, 34, 0.002)
    r = np.full(len(x), 1e-3)
    T = 300.0 + 100.0 * np.exp(-np.linalg.norm(x - x.mean(0), axis=1) / 0.01)
    t = np.linspace(0.0, 10.0, 20)
    a = np.zeros((20, 9))
    a[:, 2], a[:, 4], a[:, 5], a[:, 7], a[:, 8] = t, 300 + t, 300 + t / 2, 300 + t / 3, 300
    i = np.arange(0, 40)
    cxy = crack_faces(x, r, i, i + 1)
    assert _plot_heat(tmp_path / "h.png", a, None, ["hole", "edge"], x, r, T, cxy, ["x", "y"],
                      T.min(), T.max())
    _check(saved, 1)


def test_hydrofrac_pressure_maps(tmp_path, saved):
    from scipy.spatial import Delaunay

    from geodem.cases.hydrofrac import plot_pressure_maps

    x = _grid(24, 28, 0.005)
    cells = Delaunay(x).simplices
    frames = []
    for k in range(4):
        P = np.linspace(0, 1e6 * (k + 1), len(cells))
        f = tmp_path / f"frame_{k}.npz"
        np.savez(f, x=x.astype(np.float32), cells=cells.astype(np.int32),
                 P=P.astype(np.float32), ci=np.arange(k * 5), cj=np.arange(k * 5) + 1,
                 time=1e-3 * k, p_inj=1e6 * (k + 1))
        frames.append(f)
    assert plot_pressure_maps(tmp_path / "p.png", frames, 4, x.mean(0), 0.01, 0.005, None)
    _check(saved, 4)


def test_column_collapse_snapshots(tmp_path, saved):
    from geodem.cases.collapse import plot_snapshots

    x0 = _grid(10, 20, 0.005, lo=(0.0025, 0.0025))
    x1 = _grid(40, 5, 0.005, lo=(0.0025, 0.0025))
    r0, r1 = np.full(len(x0), 0.0025), np.full(len(x1), 0.0025)
    c = {"L0": 0.05, "H0": 0.1, "aspect_ratio": 2.0, "floor_y": 0.0}
    res = {"runout_length": 0.2, "reference": 2.5, "runout": 3.0, "rel_error": 0.2}
    assert plot_snapshots(tmp_path / "c.png", x0, r0, x1, r1, c, res, 0.005)
    _check(saved, 2)


def test_tbm_and_seismic_snapshots(tmp_path, saved):
    from geodem.cases.seismic import plot_snapshots as seismic_snapshots
    from geodem.cases.tbm import plot_snapshots as tbm_snapshots

    x = _grid(60, 15, 0.004)
    tbm, sei = [], []
    for k in range(3):
        f = tmp_path / f"tbm_{k}.npz"
        np.savez(f, x=x.astype(np.float32), r=np.full(len(x), 0.002, np.float32),
                 ci=np.arange(10 * k), cj=np.arange(10 * k) + 1, cut=np.arange(5),
                 time=0.01 * k, travel=0.01 * k, mat=np.arange(len(x)) % 2)
        tbm.append(f)
        g = tmp_path / f"sei_{k}.npz"
        np.savez(g, x=x.astype(np.float32), speed=RNG.random(len(x)), time=0.01 * k)
        sei.append(g)
    assert tbm_snapshots(tmp_path / "tbm.png", tbm, 3)
    assert seismic_snapshots(tmp_path / "sei.png", sei, 3, 0.004, 1.0)
    _check(saved, 6)


@pytest.mark.parametrize("dim", [2, 3])
def test_landslide_snapshots_and_deposit(tmp_path, saved, dim):
    from geodem.cases.landslide_plots import deposit_map, snapshots

    s = np.linspace(0.0, 300.0, 400)
    top = 100.0 - 60.0 / (1.0 + np.exp(-(s - 150.0) / 30.0))
    if dim == 2:
        ref = _grid(100, 30, 3.0)
        ref = ref[ref[:, 1] < np.interp(ref[:, 0], s, top)]
    else:
        ref = np.c_[_grid(140, 116, 3.0), np.zeros(16240)]  # the ground fills the plan
    r = np.full(len(ref), 1.5)
    if dim == 2:
        slide = np.flatnonzero(ref[:, -1] > np.interp(ref[:, 0], s, top) - 9.0)[:200]
    else:  # a patch in the middle of the plan, moving inside it
        slide = np.flatnonzero(np.abs(ref[:, :2] - 150.0).max(axis=1) < 21.0)
    x0 = ref[slide]
    shift = np.zeros(dim)
    shift[0], shift[-1] = 60.0, -20.0
    x = x0 + shift
    frames = []
    for k in range(3):
        f = tmp_path / f"ls_{k}.npz"
        np.savez(f, x=x0 + (x - x0) * k / 2, v=RNG.random((len(slide), dim)), time=5.0 * k)
        frames.append(f)
    info = {"base_z": -5.0, "profile": {"s": s, "top": top, "slip": top - 9.0}}
    res = {"direction": [1.0, 0.0][:dim - 1], "crown_h": 60.0, "front_h": 260.0,
           "crown_z": 100.0, "tip_z": 40.0, "travel_angle_deg": 16.7, "source_toe_h": 200.0,
           "runout_m": 60.0, "deposit_volume_m3": 1500.0, "max_velocity": 9.0,
           "com_ratio": 0.4}
    assert snapshots(tmp_path / "s.png", dim, ref, r, slide, frames, 3, info)
    moved = np.ones(len(slide), bool)
    assert deposit_map(tmp_path / "d.png", dim, ref, r, slide, x0, x, moved, info, res)
    _check(saved, 4)
    if dim == 2:
        labels = {a["ylabel"] for f in saved for a in f["axes"]}
        assert labels == {"elevation [m]"}


def test_legends_of_twin_axis_histories_sit_above_the_curves(tmp_path, saved):
    """Twin axes: loc="best" sees only one axes' curves; the legend goes above both."""
    from geodem.cases.hydrofrac import plot_history
    from geodem.cases.tbm import plot_energy

    t = np.linspace(0.0, 1e-3, 50)
    a = np.zeros((50, 13))
    a[:, 1], a[:, 2] = t, 1e6 * np.sin(3e3 * t) ** 2
    a[:, 3], a[:, 6] = np.arange(50), np.arange(50) // 2
    assert plot_history(tmp_path / "h.png", a, 0.0, 9e5, 8e5)
    a[:, 2] = np.linspace(0.0, 0.02, 50)
    a[:, 7], a[:, 12] = np.linspace(0, 5, 50), np.linspace(0, 4, 50)
    a[:, 9], a[:, 10], a[:, 11] = np.arange(50), np.arange(50) // 2, np.arange(50) // 3
    assert plot_energy(tmp_path / "e.png", a, {"energy_closure_rel_error": 1e-3})
    assert len(saved) == 2
    for f in saved:
        boxes = [a["legend"] for a in f["axes"] if a["legend"] is not None]
        assert len(boxes) == 1
        box, c = boxes[0], f["canvas"]
        assert box.y1 <= c.y1 + 1 and box.x0 >= c.x0 - 1 and box.x1 <= c.x1 + 1
        for ax in f["axes"]:
            p = ax["points"]
            inside = ((p[:, 0] > box.x0 + 1) & (p[:, 0] < box.x1 - 1)
                      & (p[:, 1] > box.y0 + 1) & (p[:, 1] < box.y1 - 1))
            assert not inside.any()


def test_monitor_picture(tmp_path, saved):
    """monitor.png: every panel labelled with its unit, the legends beside the data."""
    from geodem.workflow.monitoring import plot_monitor

    cols = ["step", "time [s]", "p.ux [m]", "p.uy [m]", "p.vx [m/s]", "p.vy [m/s]",
            "g.ux [m]", "g.uy [m]", "g.vx [m/s]", "g.vy [m/s]", "g.sxx [Pa]", "g.sxy [Pa]",
            "g.syy [Pa]", "broken_bonds [1]"]
    t = np.linspace(0.0, 1e-3, 30)
    rows = [[k, tk] + list(RNG.normal(size=11)) + [k] for k, tk in enumerate(t)]
    assert plot_monitor(tmp_path / "m.png", cols, rows)
    _check(saved, 0)
    axes = saved[0]["axes"]
    assert [a["ylabel"] for a in axes] == ["displacement [m]", "velocity [m/s]",
                                           "stress (tension +) [Pa]", "broken bonds [1]"]
    for a in axes:  # the legend lies beside the panel, not over its data
        box, panel = a["legend"], a["ax"].get_window_extent()
        assert box.x0 >= panel.x1 - 1
