"""Registries of things chosen by name: backends, coupled fields, workflow models and step kinds.

One helper, :class:`Registry`, does the work for all four: a dict from name to class with a
``register(name)`` class decorator (base-class and duplicate-name checks), ``lookup(name)`` with an
error that lists the allowed names, and ``load_builtins()``, which imports the built-in modules
(they register themselves when imported). The built-in modules of every registry are listed in one
place, :data:`BUILTINS`, by module name only: this module imports nothing of geodem, so any layer
may use it, and the modules named are imported on first need.

A new backend, field, model or step kind is one class plus its registry's decorator; a new
built-in module is one line in :data:`BUILTINS`.
"""
from __future__ import annotations

import importlib
from typing import Callable, Optional

#: the built-in modules of each registry, in load order (the order names are listed in messages
#: and in the JSON schema)
BUILTINS: dict[str, tuple[str, ...]] = {
    "backends": ("geodem.backends.cupy_backend",
                 "geodem.backends.numba_backend",
                 "geodem.backends.numpy_ref"),
    # coupled fields, then the cases that define their own (a checkpoint holding one restores
    # whatever was imported before)
    "fields": ("geodem.fields.thermal",
               "geodem.fields.pore",
               "geodem.fields.freeze",
               "geodem.fields.wave",      # wave_boundary
               "geodem.cases.tbm"),       # cutter_kinematics
    # workflow models and step kinds: the generic ones, then one module per case
    "workflow": ("geodem.cases.two_balls",     # two_balls, two_balls_check
                 "geodem.workflow.models",
                 "geodem.workflow.steps",
                 "geodem.workflow.scene",   # scene: a model composed from parts
                 "geodem.workflow.monitoring",  # monitor, pressure: generic, any model
                 "geodem.workflow.excavation",  # excavate, weaken
                 "geodem.workflow.waves",   # wave_source: a plane wave through an absorbing base
                 "geodem.workflow.porefluid",  # pore_flow: linear or radial, any model
                 "geodem.cases.uniaxial",   # specimen, uniaxial
                 "geodem.cases.brazilian",  # brazilian_disc, brazilian, direct_tension
                 "geodem.cases.triaxial",   # triaxial_box, triaxial
                 "geodem.cases.thermal",    # thermal models and steps
                 "geodem.cases.hydrofrac",  # hydrofrac_plate, hydraulic_fracturing
                 "geodem.cases.collapse",   # granular column collapse
                 "geodem.cases.seismic",    # valley_amplification (on a scene + wave_source)
                 "geodem.cases.landslide",  # landslide from an elevation raster
                 "geodem.cases.tbm",        # TBM disc cutter
                 "geodem.cases.tunnel",     # tunnel_check (on a scene + generic steps)
                 "geodem.cases.slope"),     # slope_stability (strength reduction)
}


def import_builtins(group: str) -> None:
    """Import the built-in modules of ``group`` (a key of :data:`BUILTINS`). A module that is not
    there is skipped; a missing dependency inside a module is a real error and is raised."""
    for mod in BUILTINS[group]:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise


class Registry(dict):
    """Name -> class, filled by the :meth:`register` decorator.

    ``what`` names an entry in messages ("step kind", "coupled field"); ``base``: the class every
    entry must subclass (None: any class); ``builtins``: the key of :data:`BUILTINS` holding its
    built-in modules; ``prepare(cls, name)``: returns the class to store (it may set the name on
    the class or derive a tagged subclass); ``on_change()``: called after each registration.
    """

    def __init__(self, what: str, *, base: Optional[type] = None, builtins: str = "",
                 prepare: Optional[Callable] = None, on_change: Optional[Callable] = None,
                 decorator: str = "register"):
        super().__init__()
        self.what = what
        self.base = base
        self.builtins = builtins
        self.prepare = prepare
        self.on_change = on_change
        self.decorator = decorator

    def register(self, name: str):
        """Class decorator: register the class under ``name``."""

        def deco(cls):
            base = self.base
            if base is not None and not (isinstance(cls, type) and issubclass(cls, base)):
                raise TypeError(f"{self.decorator} decorates {base.__name__} subclasses")
            if name in self and self[name].__qualname__ != cls.__qualname__:
                raise ValueError(f"{self.what} {name!r} is already registered")
            new = self.prepare(cls, name) if self.prepare is not None else cls
            self[name] = new
            if self.on_change is not None:
                self.on_change()
            return new

        return deco

    def load_builtins(self) -> None:
        """Import the built-in modules (they register themselves)."""
        if self.builtins:
            import_builtins(self.builtins)

    def lookup(self, name: str) -> type:
        """The class registered as ``name`` (built-ins loaded first); KeyError listing the
        registered names otherwise."""
        self.load_builtins()
        if name not in self:
            raise KeyError(f"unknown {self.what} {name!r}; registered: {sorted(self)}")
        return self[name]
