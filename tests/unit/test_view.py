"""Frames as pictures and crack networks (geodem.io.view, geodem.io.vtk, `geodem view`):
cracks as VTK line cells read back, the frame and crack selection of a hand-made output.h5,
the rendered picture, and clear errors."""
import numpy as np
import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.core.engine import Simulation
from geodem.io.h5 import H5Writer
from geodem.io.view import ViewError, read_frame
from geodem.io.vtk import VtkWriter, crack_lines, read_vtp, rows_of, write_vtp
from tests.conftest import make_specimen


def test_crack_lines_are_vtk_line_cells(tmp_path):
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    write_vtp(tmp_path / "f.vtp", pts, {"radius": np.ones(3)}, lines=[[0, 1], [1, 2]],
              line_types=[1, 2])
    back = read_vtp(tmp_path / "f.vtp")
    assert back["lines"].tolist() == [[0, 1], [1, 2]]
    assert back["crack_type"].tolist() == [-1, -1, -1, 1, 2]  # vertex cells first
    assert back["radius"].tolist() == [1.0, 1.0, 1.0]
    pv = pytest.importorskip("pyvista")
    mesh = pv.read(tmp_path / "f.vtp")
    assert (mesh.n_points, mesh.n_verts, mesh.n_lines) == (3, 3, 2)


def test_rows_of_built_numbers_after_a_removal():
    ids = np.array([0, 2, 3, 7])  # elements 1, 4, 5, 6 were removed
    assert rows_of(ids, np.array([7, 0, 4, 3])).tolist() == [3, 0, -1, 2]
    log = {"i": np.array([0, 1, 2]), "j": np.array([2, 3, 7]), "type": np.array([1, 2, 1])}
    rows, types = crack_lines(ids, log)
    assert rows.tolist() == [[0, 1], [1, 3]] and types.tolist() == [1, 1]


def test_vtk_frames_carry_the_cracks_of_a_run(tmp_path):
    st = make_specimen(n=200, dim=2)
    sim = Simulation(st, backend="numba")
    sim.run(40)
    log = sim.crack_log()
    assert len(log) > 3
    VtkWriter(tmp_path).write(st, st.step, cracks=crack_lines(sim.ids, log))
    back = read_vtp(next(tmp_path.glob("frame_*.vtp")))
    assert back["lines"].tolist() == np.column_stack([log["i"], log["j"]]).tolist()
    assert back["crack_type"][st.n:].tolist() == log["type"].tolist()


def _fake_run(folder, dim=2):
    """A run directory with two frames of four elements and two cracks, one after each frame."""
    folder.mkdir()
    x0 = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.01], [0.01, 0.01]])
    if dim == 3:
        x0 = np.column_stack([x0, np.zeros(4)])
    h5 = H5Writer(folder / "output.h5")
    h5.static("particles/all/radius", np.full(4, 0.005))
    h5.static("particles/all/id", np.arange(4))
    h5.static("particles/all/reference_position", x0)
    h5.series("particles/all/position", shape=x0.shape)
    x1 = x0.copy()
    x1[3, 0] += 0.002  # element 3 moves 2 mm
    h5.append("particles/all/position", 0, 0.0, x0)
    h5.append("particles/all/position", 10, 1.0, x1)
    h5.static("cracks/i", np.array([0, 1]))
    h5.static("cracks/j", np.array([1, 3]))
    h5.static("cracks/time", np.array([0.5, 0.9]))
    h5.static("cracks/type", np.array([1, 2], np.int8))
    h5.close()
    return folder


def test_frame_selection_and_its_cracks(tmp_path):
    run = _fake_run(tmp_path / "run")
    first, last = read_frame(run, 0), read_frame(run, -1)
    assert (first.step, last.step, last.index, last.count) == (0, 10, 1, 2)
    assert first.crack_rows.shape == (0, 2)  # both cracks come after t = 0
    assert last.crack_rows.tolist() == [[0, 1], [1, 3]] and last.crack_types.tolist() == [1, 2]
    assert last.field == pytest.approx([0.0, 0.0, 0.0, 0.002])  # |x - reference| [m]
    assert read_frame(run, -1, color="radius").field.tolist() == [0.005] * 4


def test_view_draws_the_frame_with_its_cracks(tmp_path):
    pytest.importorskip("pyvista")
    iio = pytest.importorskip("imageio.v3")
    run = _fake_run(tmp_path / "run")
    res = CliRunner().invoke(app, ["view", str(run), "--size", "320x240"])
    assert res.exit_code == 0, res.output
    assert "1 tensile / 1 shear / 0 joint cracks" in res.output
    img = iio.imread(run / "view_frame_1.png")
    assert img.shape[:2] == (240, 320)
    rgb = img[..., :3].astype(int)
    red = (rgb[..., 0] > 200) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)
    blue = (rgb[..., 2] > 200) & (rgb[..., 0] < 60) & (rgb[..., 1] < 60)
    assert red.sum() > 10 and blue.sum() > 10  # the tensile and the shear crack are drawn


@pytest.mark.parametrize("args, expected", [
    (["--frame", "2"], "--frame 2: "),
    (["--frame", "-3"], "allowed: -2 to 1"),
    (["--color", "stress"], "allowed: displacement, velocity, radius, none"),
    (["--color", "velocity"], "has no velocities"),
    (["--size", "big"], "allowed: WIDTHxHEIGHT"),
    (["-o", "picture.jpg"], "allowed: a .png file"),
])
def test_view_refuses_bad_options_with_exit_2(tmp_path, args, expected):
    pytest.importorskip("pyvista")
    run = _fake_run(tmp_path / "run")
    res = CliRunner().invoke(app, ["view", str(run), *args])
    assert res.exit_code == 2, res.output
    assert expected in res.output
    assert not list(run.glob("*.png"))


def test_view_of_a_folder_without_output_exits_2(tmp_path):
    res = CliRunner().invoke(app, ["view", str(tmp_path)])
    assert res.exit_code == 2 and "no output.h5" in res.output
    with pytest.raises(ViewError, match="no such run directory"):
        read_frame(tmp_path / "missing")


@pytest.mark.parametrize("glyph_limit", [10**6, 0])  # spheres as meshes / as screen points
def test_view_draws_a_3d_frame(tmp_path, monkeypatch, glyph_limit):
    pytest.importorskip("pyvista")
    iio = pytest.importorskip("imageio.v3")
    import geodem.io.view as view

    monkeypatch.setattr(view, "GLYPH_LIMIT", glyph_limit)
    run = _fake_run(tmp_path / "run", dim=3)
    out = tmp_path / "v.png"
    r = view.render_frame(run, output=out, size=(200, 160))
    assert r["cracks"] == {"tensile": 1, "shear": 1, "joint": 0} and r["elements"] == 4
    img = iio.imread(out)[..., :3].astype(int)
    assert img.shape[:2] == (160, 200)
    assert (img.sum(axis=2) < 600).sum() > 50  # something other than the white background


def _red_blue(rgb):
    red = (rgb[..., 0] > 200) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)
    blue = (rgb[..., 2] > 200) & (rgb[..., 0] < 60) & (rgb[..., 1] < 60)
    return int(red.sum()), int(blue.sum())


@pytest.mark.parametrize("dim", [2, 3])
def test_view_draws_the_frames_into_a_gif(tmp_path, dim):
    pytest.importorskip("pyvista")
    iio = pytest.importorskip("imageio.v3")
    run = _fake_run(tmp_path / "run", dim=dim)
    out = tmp_path / "anim.gif"
    res = CliRunner().invoke(app, ["view", str(run), "-o", str(out), "--size", "240x180"])
    assert res.exit_code == 0, res.output
    assert "2 of the run's 2 frames (steps 0 to 10)" in res.output
    pics = iio.imread(out, index=None)
    assert pics.shape[:3] == (2, 180, 240)
    first, last = (_red_blue(p[..., :3].astype(int)) for p in pics)
    assert first == (0, 0)  # both cracks come after the first frame
    assert min(last) > 5    # the tensile (red) and the shear (blue) crack at the last


def test_an_animation_draws_at_most_max_frames_spread_over_the_run(tmp_path):
    pytest.importorskip("pyvista")
    pytest.importorskip("imageio")
    from geodem.io.view import render_animation

    run = _fake_run(tmp_path / "run")
    calls: list = []
    r = render_animation(run, tmp_path / "a.gif", size=(64, 48), max_frames=2,
                         progress=lambda i, n: calls.append((i, n)))
    assert (r["frames"], r["frames_in_run"], r["steps"]) == (2, 2, [0, 10])
    assert calls == [(1, 2), (2, 2)]


@pytest.mark.parametrize("args, expected", [
    (["--fps", "0"], "--fps 0.0: allowed: 0.1 to 60"),
    (["--max-frames", "1"], "--max-frames 1: allowed: 2 to 10000"),
    (["--show"], "--show: allowed with a .png picture only"),
    (["--opacity", "2"], "--opacity 2.0: allowed: 0 to 1"),
])
def test_an_animation_refuses_bad_options_with_exit_2(tmp_path, args, expected):
    pytest.importorskip("pyvista")
    run = _fake_run(tmp_path / "run")
    out = tmp_path / "a.gif"
    res = CliRunner().invoke(app, ["view", str(run), "-o", str(out), *args])
    assert res.exit_code == 2, res.output
    assert expected in res.output
    assert not out.exists()


def test_an_animation_of_a_single_frame_run_exits_2(tmp_path):
    pytest.importorskip("pyvista")
    run = tmp_path / "run"
    run.mkdir()
    h5 = H5Writer(run / "output.h5")
    h5.static("particles/all/radius", np.full(2, 0.005))
    h5.series("particles/all/position", shape=(2, 2))
    h5.append("particles/all/position", 0, 0.0, np.array([[0.0, 0.0], [0.01, 0.0]]))
    h5.close()
    res = CliRunner().invoke(app, ["view", str(run), "-o", str(tmp_path / "a.gif")])
    assert res.exit_code == 2 and "an animation needs 2 or more" in res.output


def test_a_gif_plays_at_its_frames_per_second(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    from geodem.io.gif import save_gif

    frames = [np.full((8, 8, 3), 60 * k, np.uint8) for k in range(3)]
    save_gif(tmp_path / "a.gif", frames, fps=4.0)
    im = Image.open(tmp_path / "a.gif")
    shown = []
    for k in range(im.n_frames):
        im.seek(k)
        shown.append(im.info["duration"])
    assert shown == [250, 250, 250]  # milliseconds: 1000 / fps


def test_crack_kinds_chooses_the_types_drawn():
    from geodem.io.view import crack_kinds

    assert crack_kinds("all") == ("tensile", "shear", "joint")
    assert crack_kinds("none") == ()
    assert crack_kinds("Shear, tensile,shear") == ("shear", "tensile")
    for bad in ("cuts", "", "all,none", "tensile,cuts"):
        with pytest.raises(ViewError, match="allowed: all, none, or a comma-separated list"):
            crack_kinds(bad)


@pytest.mark.parametrize("kinds, expected", [("none", (False, False)),
                                             ("tensile", (True, False)),
                                             ("shear,tensile", (True, True))])
def test_view_draws_the_crack_types_asked_for(tmp_path, kinds, expected):
    pytest.importorskip("pyvista")
    iio = pytest.importorskip("imageio.v3")
    run = _fake_run(tmp_path / "run")
    out = tmp_path / "v.png"
    res = CliRunner().invoke(app, ["view", str(run), "-o", str(out), "--size", "320x240",
                                   "--cracks", kinds])
    assert res.exit_code == 0, res.output
    assert "1 tensile / 1 shear / 0 joint cracks" in res.output  # counted, drawn or not
    red, blue = _red_blue(iio.imread(out)[..., :3].astype(int))
    assert (red > 10, blue > 10) == expected


def test_view_refuses_unknown_crack_types_with_exit_2(tmp_path):
    run = _fake_run(tmp_path / "run")
    res = CliRunner().invoke(app, ["view", str(run), "--cracks", "cuts"])
    assert res.exit_code == 2 and "--cracks cuts: allowed: all, none" in res.output
    assert not list(run.glob("*.png"))
