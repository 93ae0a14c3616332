"""A missing optional extra is a user error that names the pip install (geodem.extras).

The absent package is simulated with ``sys.modules[name] = None`` (an import then raises
ModuleNotFoundError, as when it is not installed)."""
import os
import sys

import pytest
import typer
from typer.testing import CliRunner

from geodem import extras
from geodem.cli import _guard
from geodem.extras import MissingExtra, install_command, missing_extra, needs_extra

ROOT = os.fspath(extras._ROOT)


def test_install_command_from_the_source_tree_and_elsewhere(monkeypatch, tmp_path):
    monkeypatch.chdir(ROOT)
    assert install_command("geo") == "pip install -e '.[geo]'"
    monkeypatch.chdir(tmp_path)
    assert install_command("plot") == f"pip install -e '{ROOT}[plot]'"
    monkeypatch.setattr(extras, "_ROOT", tmp_path)  # an installed package: no source tree
    assert install_command("dist") == "pip install 'geodem[dist]'"


def test_missing_extra_names_the_extra(monkeypatch):
    monkeypatch.chdir(ROOT)
    err = missing_extra(ModuleNotFoundError("No module named 'rasterio'", name="rasterio.warp"),
                        "landslide")
    assert isinstance(err, MissingExtra) and isinstance(err, ImportError)
    assert str(err) == ("landslide needs the 'geo' extra (rasterio is not installed): "
                        "pip install -e '.[geo]'")
    assert (err.module, err.extra, err.feature) == ("rasterio", "geo", "landslide")
    pil = missing_extra(ModuleNotFoundError(name="PIL"), "reading images")
    assert "'geo' extra (pillow is not installed)" in str(pil)
    assert "'plot' extra" in str(missing_extra(ModuleNotFoundError(name="matplotlib"), "x"))
    # found along the cause chain (a wrapper's ImportError raised from the original)
    try:
        try:
            raise ModuleNotFoundError(name="distributed")
        except ImportError as exc:
            raise ImportError("sweeps need dask") from exc
    except ImportError as wrapped:
        assert missing_extra(wrapped, "geodem sweep").extra == "dist"
    # relabelled with the caller's feature
    assert str(missing_extra(err, "geodem advise")).startswith("geodem advise needs the 'geo'")
    # not a missing extra: a required or unknown package, an installed one that fails to load
    assert missing_extra(ModuleNotFoundError(name="numpy"), "x") is None
    assert missing_extra(ImportError("libgdal.so: cannot open", name="rasterio._base"),
                         "x") is None
    assert missing_extra(ValueError("rasterio"), "x") is None


def test_needs_extra_turns_the_import_into_a_missing_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(MissingExtra, match=r"^pictures needs the 'vis' extra \(pyvista is not "
                                           r"installed\): pip install -e '"):
        with needs_extra("pictures"):
            import pyvista  # noqa: F401
    monkeypatch.setitem(sys.modules, "not_an_extra_pkg", None)
    with pytest.raises(ModuleNotFoundError) as info:
        with needs_extra("pictures"):
            import not_an_extra_pkg  # noqa: F401
    assert not isinstance(info.value, MissingExtra)


def test_read_elevation_without_rasterio(monkeypatch, tmp_path):
    from geodem.geo import read_elevation

    monkeypatch.setitem(sys.modules, "rasterio", None)
    with pytest.raises(MissingExtra, match=r"^reading elevation rasters needs the 'geo' extra "
                                           r"\(rasterio is not installed\): pip install"):
        read_elevation(tmp_path / "dem.tif")


def test_read_labels_without_pillow(monkeypatch, tmp_path):
    from geodem.geo.image import read_labels

    monkeypatch.setitem(sys.modules, "PIL", None)
    with pytest.raises(MissingExtra, match=r"^reading images needs the 'geo' extra \(pillow is "
                                           r"not installed\)"):
        read_labels(tmp_path / "labels.png")


def _app():
    app = typer.Typer(add_completion=False)

    @app.command("plotme")
    @_guard
    def plotme(module: str):
        __import__(module)

    @app.command("other")  # a second command: the app takes command names
    def other():
        pass

    return app


def test_the_cli_guard_makes_a_missing_extra_exit_2(monkeypatch):
    monkeypatch.chdir(ROOT)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "not_an_extra_pkg", None)
    runner = CliRunner()
    res = runner.invoke(_app(), ["plotme", "matplotlib"], prog_name="geodem")
    assert res.exit_code == 2
    assert res.stderr.strip() == ("Error: geodem plotme needs the 'plot' extra (matplotlib is "
                                  "not installed): pip install -e '.[plot]'")
    # any other missing module stays a failure (exit 1) with its type named
    res = runner.invoke(_app(), ["plotme", "not_an_extra_pkg"], prog_name="geodem")
    assert res.exit_code == 1 and "ModuleNotFoundError" in res.stderr
