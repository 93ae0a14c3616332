"""Backend registry: compute engines chosen by name (Devito/HOOMD style).

``select(name)`` resolves ``name`` (or ``$GEODEM_BACKEND``, or ``auto``) to a backend instance:
``auto`` = ``cupy`` when a GPU is usable, else ``numba``. A backend is a class registered with
:func:`register`; adding one never touches the time-step loop in ``geodem.core.engine``.

Every backend implements::

    attach(state)            take the model (copy it to the device if needed)
    move(dt)                 first half of velocity Verlet (positions)
    force(dt, code_t, code_s) contact forces, velocity update, heat accounting
    elastic_energy()         per-element elastic energy (host array)
    pull(names) / push(names) copy named arrays device -> state / state -> device
"""
from __future__ import annotations

import os

from geodem.registry import Registry


def _named(cls, name):
    cls.name = name
    return cls


BACKENDS: Registry = Registry("backend", builtins="backends", prepare=_named)
ALLOWED = ("auto", "numba", "numpy", "cupy")


class BackendError(ValueError):
    """Unknown or unusable backend."""


register = BACKENDS.register
_load_all = BACKENDS.load_builtins


def available() -> list[str]:
    """Names of the backends usable on this machine."""
    _load_all()
    return [n for n, cls in BACKENDS.items() if cls.is_available()]


def resolve_name(name: str | None = None) -> str:
    name = name or os.environ.get("GEODEM_BACKEND") or "auto"
    if not isinstance(name, str):
        raise BackendError(f"backend {name!r} is not a name; allowed: {', '.join(ALLOWED)}")
    name = name.strip().lower()
    if name not in ALLOWED:
        raise BackendError(f"backend {name!r} is not known; allowed: {', '.join(ALLOWED)}")
    _load_all()
    if name == "auto":
        return "cupy" if BACKENDS["cupy"].is_available() else "numba"
    if not BACKENDS[name].is_available():
        raise BackendError(f"backend {name!r} is not usable here: {BACKENDS[name].why_not()}; "
                           f"usable: {', '.join(available())}")
    return name


def select(name: str | None = None):
    """Instantiate the backend called ``name`` (see module doc for the resolution order)."""
    return BACKENDS[resolve_name(name)]()
