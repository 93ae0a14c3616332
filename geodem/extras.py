"""Optional extras (``pyproject.toml``, ``[project.optional-dependencies]``): a missing one is a
user error that names the pip install to run.

:class:`MissingExtra` is an :class:`ImportError` (callers that catch ImportError still do) with
a one-line message, e.g. ``landslide needs the 'geo' extra (rasterio is not installed): pip
install -e '.[geo]'``. :func:`missing_extra` turns an ImportError of a known optional package
(:data:`EXTRAS`, looked up along the exception's cause chain) into one; :func:`needs_extra`
does so for a block of code. The command line (``geodem run``, ``validate``, ``advise``, ...)
exits with status 2 and that line.

The install command is ``pip install -e '<source tree>[extra]'`` when geodem runs from its
source tree (``.`` in the working directory), else ``pip install 'geodem[extra]'``.
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = ["EXTRAS", "MissingExtra", "install_command", "missing_extra", "needs_extra"]

#: top-level module -> the extra that installs it
EXTRAS = {
    "rasterio": "geo", "affine": "geo", "PIL": "geo",
    "matplotlib": "plot",
    "imageio": "vis", "pyvista": "vis",
    "dask": "dist", "distributed": "dist",
    "cupy": "gpu", "numba_cuda": "gpu",
}

#: the pip name of each module, when it differs
_PIP_NAME = {"PIL": "pillow", "cupy": "cupy-cuda12x", "numba_cuda": "numba-cuda"}

_ROOT = Path(__file__).resolve().parents[1]


def install_command(extra: str) -> str:
    """``pip install -e '.[extra]'`` (from the source tree; its path when the working directory
    is elsewhere), else ``pip install 'geodem[extra]'``."""
    if (_ROOT / "pyproject.toml").is_file() and (_ROOT / "geodem" / "__init__.py").is_file():
        try:
            here = Path.cwd().resolve() == _ROOT
        except OSError:
            here = False
        where = "." if here else os.fspath(_ROOT)
        return f"pip install -e '{where}[{extra}]'"
    return f"pip install 'geodem[{extra}]'"


class MissingExtra(ImportError):
    """``feature`` needs the optional ``module`` of the extra ``extra``: a user error."""

    def __init__(self, feature: str, module: str, extra: str | None = None):
        self.feature, self.module = feature, module
        self.extra = extra or EXTRAS.get(module.split(".")[0], "all")
        pip = _PIP_NAME.get(module, module)
        super().__init__(f"{feature} needs the '{self.extra}' extra ({pip} is not installed): "
                         f"{install_command(self.extra)}", name=module)


def _missing_module(exc: BaseException) -> str | None:
    """The known optional top-level module whose import failed along ``exc``'s chain."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, MissingExtra):
            return exc.module
        # ModuleNotFoundError: absent (an ImportError of an installed package that fails
        # to load, e.g. a missing shared library, is not a missing extra)
        if isinstance(exc, ModuleNotFoundError) and exc.name:
            top = exc.name.split(".")[0]
            if top in EXTRAS:
                return top
        exc = exc.__cause__ or exc.__context__
    return None


def missing_extra(exc: BaseException, feature: str) -> MissingExtra | None:
    """``exc`` as a :class:`MissingExtra` of ``feature`` when it is an ImportError of a known
    optional package (or a MissingExtra: relabelled with ``feature``), else None."""
    if not isinstance(exc, ImportError):
        return None
    module = _missing_module(exc)
    if module is None:
        return None
    return MissingExtra(feature, module)


@contextlib.contextmanager
def needs_extra(feature: str):
    """Raise :class:`MissingExtra` of ``feature`` for an ImportError of an optional package in
    the block; other ImportErrors pass unchanged."""
    try:
        yield
    except ImportError as exc:
        err = missing_extra(exc, feature)
        if err is None:
            raise
        raise err from exc
