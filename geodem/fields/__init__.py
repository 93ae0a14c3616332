"""Coupled fields: physics that lives beside the bonded solid and sub-steps against it.

A coupled field (temperature, pore fluid, ...) is a :class:`CoupledField` subclass registered with
``@register_field("kind")``. The time-step loop knows nothing about any particular field: every
``every`` mechanical steps ``Simulation`` calls :meth:`CoupledField.advance` with the span of
mechanical time to cover, and the field sub-steps on its own stable step (DESIGN.md: "coupled
fields advance on their own stable time step and sub-step against the mechanical step").

Contract of a field (one contract test runs over every registered kind):

* ``reads`` / ``writes``: names of :class:`~geodem.core.state.State` arrays it reads and writes,
  with units. On a device backend those arrays are pulled before and pushed after each coupling
  (CPU backends share the arrays; nothing is copied).
* ``attach(sim)``: size its own arrays for ``sim.state``; called once by ``Simulation.add_field``.
* ``stable_dt(sim)``: its explicit stability limit [s].
* ``substep(sim, h)``: advance its own state by ``h`` seconds (``h <= safety * stable_dt``).
  Fields whose ``substep`` may be called directly refuse ``h > stable_dt`` with
  :func:`check_substep` (the thermal and pore fields; ``allow_unstable=True`` is for studies of
  where the explicit scheme fails, :mod:`geodem.studies.stability`).
* ``config()``: JSON-able constructor keywords; ``arrays()`` / ``restore(arrays)``: its state for
  checkpoints (a run resumed from a checkpoint continues bit-identically on CPU).
* ``summary()``: key results as numbers (merged into a workflow's summary by the steps that use it).
"""
from __future__ import annotations

import math
import numbers
from typing import ClassVar

import numpy as np

from geodem.registry import Registry


def _kinded(cls, kind):
    cls.kind = kind
    return cls


FIELDS: Registry = Registry("coupled field", builtins="fields", prepare=_kinded,
                            decorator="register_field")  # base set below CoupledField


def register_field(kind: str):
    """Class decorator: register a coupled field (a :class:`CoupledField` subclass) as ``kind``."""
    return FIELDS.register(kind)


def whole_number(name, v, lo, prefix="", why="", err=ValueError) -> int:
    """``v`` as an int >= ``lo``: whole numbers only (an int, or a float/NumPy number with no
    fraction; not a bool, NaN or 1.5), else ``err`` naming ``name`` and the allowed range."""
    ok = isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))
    if ok:
        f = float(v)
        ok = math.isfinite(f) and f == math.floor(f) and f >= lo
    if not ok:
        raise err(f"{prefix}{name} = {v!r}; allowed: a whole number >= {lo}"
                  f"{f' ({why})' if why else ''}")
    return int(v)


class FieldStabilityError(RuntimeError):
    """A coupled field cannot advance stably (its own step would be needlessly tiny or invalid)."""


def check_substep(field, sim, h: float) -> float:
    """Refuse a sub-step ``h`` [s] of ``field`` that is not positive or above its explicit
    stability limit ``field.stable_dt(sim)`` (FieldStabilityError naming the field, ``h`` and the
    allowed range). Returns the limit [s]."""
    lim = float(field.stable_dt(sim))
    if not (h > 0.0 and math.isfinite(h)) or h > lim * (1.0 + 1e-12):
        raise FieldStabilityError(
            f"coupled field {field.kind!r}: sub-step h = {h!r} s is above its explicit stability "
            f"limit; allowed: 0 < h <= stable_dt = {lim:.4g} s (beyond it the explicit update "
            f"overshoots and, a little further, blows up); advance() sub-steps automatically at "
            f"safety = {field.safety:g} x stable_dt")
    return lim


class CoupledField:
    """Base class of coupled fields (see the module docstring for the contract)."""

    kind: ClassVar[str] = ""
    #: state arrays read, name -> unit
    reads: ClassVar[dict] = {}
    #: state arrays written, name -> unit
    writes: ClassVar[dict] = {}
    #: fraction of the stable step actually used
    safety: ClassVar[float] = 0.5
    #: most sub-steps per coupling before the run is stopped as hopeless
    max_substeps: ClassVar[int] = 100_000

    def __init__(self, every: int = 1):
        self.every = whole_number("every", every, 1, f"coupled field {self.kind!r}: ",
                                  "a field couples every >= 1 mechanical steps")
        self.substeps = 0  # sub-steps taken so far (for reports)

    # -- to implement -------------------------------------------------------------------
    def attach(self, sim) -> None:
        raise NotImplementedError

    def stable_dt(self, sim) -> float:
        raise NotImplementedError

    def substep(self, sim, h: float) -> None:
        raise NotImplementedError

    def config(self) -> dict:
        return {"every": self.every}

    def arrays(self) -> dict:
        return {}

    def restore(self, arrays: dict) -> None:
        pass

    def summary(self) -> dict:
        return {}

    # -- provided -------------------------------------------------------------------------
    def advance(self, sim, span: float) -> int:
        """Cover ``span`` seconds of mechanical time in ``n`` equal sub-steps of at most
        ``safety * stable_dt``; returns ``n``."""
        lim = self.stable_dt(sim)
        if not (lim > 0.0):
            raise FieldStabilityError(
                f"coupled field {self.kind!r}: stable step is {lim!r} s at step "
                f"{sim.state.step}; check its conductances and capacities")
        n = max(1, math.ceil(span / (self.safety * lim) - 1e-9))
        if n > self.max_substeps:
            raise FieldStabilityError(
                f"coupled field {self.kind!r} needs {n} sub-steps per coupling (stable step "
                f"{lim:.3g} s against {span:.3g} s of mechanical time): the field is far stiffer "
                f"than the solid; lower its conductivity/compressibility or couple more often "
                f"(every = {self.every})")
        h = span / n
        for _ in range(n):
            self.substep(sim, h)
        self.substeps += n
        return n


FIELDS.base = CoupledField


def field_from_config(kind: str, config: dict) -> CoupledField:
    """Re-create a registered field from its :meth:`CoupledField.config` (checkpoints)."""
    return FIELDS.lookup(kind)(**config)


def load_builtin() -> None:
    """Import the built-in fields (they register themselves; list: :data:`geodem.registry.BUILTINS`)."""
    FIELDS.load_builtins()


def pack_arrays(fields_list) -> dict:
    """Arrays of every field for a checkpoint, keyed ``field{k}:{name}``."""
    out = {}
    for k, f in enumerate(fields_list):
        for name, arr in f.arrays().items():
            out[f"field{k}:{name}"] = np.asarray(arr)
    return out


def unpack_arrays(k: int, arrays: dict) -> dict:
    pre = f"field{k}:"
    return {name[len(pre):]: a for name, a in arrays.items() if name.startswith(pre)}
