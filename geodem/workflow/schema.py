"""The workflow schema: Pydantic v2 models, the step-kind and model registries, validation.

A workflow is::

    version, metadata, backend, model, materials, simulation, steps, outputs, checkpoints

``model`` is a discriminated union on ``type`` over the registered model builders, ``steps`` a
list of a discriminated union on ``kind`` over the registered step kinds. Both unions are built
from the registries when :func:`workflow_model` is called, so a new step kind is one class plus
``@register_step("name")`` (see :mod:`geodem.workflow.steps`) and a new model is one class plus
``@register_model("name")`` (:mod:`geodem.workflow.models`); the runner does not change.

Every model forbids unknown keys (``extra="forbid"``) and is strict about types (a count is an
integer, ``2.5`` or ``"3"`` is not; ``1e3`` is read as 1000). Units are in each field's
description (``[m]``) and in the JSON schema as ``unit``.

:func:`validate_document` turns a loaded YAML document into a validated workflow or raises
:class:`~geodem.workflow.errors.WorkflowError` with one ``FILE:LINE: path: message`` item per
problem, the message saying what is wrong and what is allowed.
"""
from __future__ import annotations

import math
import types
import typing
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    create_model,
    model_validator,
)

from geodem.registry import Registry
from geodem.workflow.errors import ErrorItem, WorkflowError

SCHEMA_VERSION = 1
SCHEMA_ID = "https://geodem.dev/schema/workflow-1.json"
#: names of groups, materials, steps, model cases: identifiers
NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"
BACKENDS = ("auto", "numba", "numpy", "cupy")
DOF_NAMES = ("x", "y", "z")


# ============================================================================ helpers
#: whole numbers; the YAML loader turns integral floats (``1e3``, ``500.0``) into ints, so these
#: accept them, while strict mode refuses ``2.5``, ``"3"`` and ``true``
Int = int


def F(default: Any = ..., *, unit: str | None = None, description: str = "", **kw) -> Any:
    """``Field`` with the unit in the description (``[m]``) and in the JSON schema (``unit``)."""
    desc = description
    if unit:
        desc = f"{desc} [{unit}]" if desc else f"[{unit}]"
    extra = {"unit": unit} if unit else None
    return Field(default, description=desc or None, json_schema_extra=extra, **kw)


class Strict(BaseModel):
    """Base of every workflow model: unknown keys are errors, types are strict, numbers finite
    (``.inf`` and ``.nan`` are errors in every field)."""

    model_config = ConfigDict(extra="forbid", strict=True, populate_by_name=True,
                              allow_inf_nan=False)


Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]


# ============================================================================ common sections
class Metadata(Strict):
    """What the workflow is; recorded in manifest.json and output.h5."""

    name: str = F(..., description="Workflow name (letters, digits, _ . -)",
                  pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$", max_length=64)
    description: str = F("", description="What the workflow does")
    author: Optional[str] = F(None, description="Who wrote it")
    seed: Int = F(0, ge=0, le=2**63 - 1,
                  description="Seed of every random choice of the model builders")
    tags: list[str] = F([], description="Free keywords")


class SimulationSpec(Strict):
    """Time step and engine checks (``geodem.core.engine.Simulation``)."""

    dt: Optional[float] = F(None, unit="s", gt=0,
                            description="Time step; must be below the stability limit "
                                        "2/omega_max. Default: dt_fraction x the smallest "
                                        "element period")
    dt_fraction: float = F(0.02, gt=0, le=0.2,
                           description="Time step as a fraction of the smallest element period "
                                       "2 pi sqrt(2 m / kn) (used when dt is not given)")
    check_every: Int = F(10, ge=1, le=100_000,
                         description="Most steps between neighbour/crack/finiteness checks "
                                     "(sooner while elements move fast)")
    monitor_every: Int = F(1000, ge=0,
                           description="Steps between energy-growth and overlap checks "
                                       "(0 = never); a multiple of check_every")
    overlap_limit: float = F(0.5, gt=0, le=1.0,
                             description="Largest allowed overlap as a fraction of the smaller "
                                         "radius before the run stops as unstable")


class CheckpointSpec(Strict):
    """When complete, atomic checkpoints are written to ``checkpoints/`` (also on SIGINT/SIGTERM
    and ``--stop-after-steps``)."""

    every_steps: Optional[Int] = F(None, ge=1, description="Checkpoint every N time steps "
                                                           "(counted from the start)")
    every_seconds: Optional[float] = F(600.0, unit="s", gt=0,
                                       description="Checkpoint when this much wall-clock time "
                                                   "has passed since the last one")
    keep: Int = F(2, ge=1, le=1000, description="Number of newest checkpoints kept")
    final: bool = F(True, description="Write a checkpoint of the final state")


class ObservablesSpec(Strict):
    """Time series written to ``output.h5`` under ``/observables``."""

    every: Int = F(100, ge=1, description="Record every N time steps (and at the start and "
                                          "the end)")
    energy_groups: Optional[list[Name]] = F(
        None, description="Groups whose energy terms are recorded separately "
                          "(default: every group of the model)")
    groups: Optional[list[Name]] = F(
        None, description="Groups whose reaction force and mean displacement are recorded "
                          "(default: every group of the model)")


FRAME_FIELDS = ("position", "velocity", "force", "displacement", "bonds")


class FramesSpec(Strict):
    """Per-element snapshots written to ``output.h5`` under ``/particles/<group>/<field>``."""

    every: Optional[Int] = F(None, ge=1, description="Write a frame every N time steps "
                                                     "(default: only the first and the last)")
    groups: list[Name] = F(["all"], min_length=1, description="Groups written")
    fields: list[Literal[FRAME_FIELDS]] = F(  # type: ignore[valid-type]
        ["position", "velocity"], min_length=1,
        description="Fields written per frame: position [m], velocity [m/s], force [N], "
                    "displacement [m] (from the reference positions), bonds (intact bonds per "
                    "element)")


class VtkSpec(Strict):
    """ParaView output (``vtk/*.vtp`` + ``vtk/frames.pvd``, VTK XML written directly)."""

    every: Optional[Int] = F(None, ge=1, description="Write a .vtp frame every N time steps "
                                                     "(default: no VTK output)")


class Outputs(Strict):
    observables: ObservablesSpec = F(default_factory=ObservablesSpec)
    frames: FramesSpec = F(default_factory=FramesSpec)
    vtk: VtkSpec = F(default_factory=VtkSpec)
    plots: bool = F(True, description="Draw the workflow's plots (needs matplotlib)")
    log_every_seconds: float = F(10.0, unit="s", gt=0,
                                 description="Wall-clock time between progress lines in log.txt")


# ============================================================================ materials
class _MaterialInfo(Strict):
    description: str = F("", description="What the material is")
    source: str = F("", description="Where the values come from")


class MacroMaterial(_MaterialInfo):
    """Rock properties, converted to element parameters on the close-packed lattice
    (``geodem.materials.macro_to_micro``; 3-D only)."""

    __tag__: ClassVar[str] = "macro"
    E: float = F(..., unit="Pa", gt=0, description="Young's modulus")
    nu: float = F(..., gt=-1.0, le=0.2,
                  description="Poisson's ratio; the close-packed lattice reaches -1 < nu <= 0.2")
    Tu: float = F(..., unit="Pa", gt=0, description="Tensile strength")
    Cu: float = F(..., unit="Pa", gt=0, description="Uniaxial compressive strength (> Tu)")
    mu_i: float = F(..., ge=1.0 / math.sqrt(8.0),
                    description="Internal friction coefficient tan(phi); the lattice needs "
                                ">= 0.3536 (phi >= 19.47 deg)")
    rho: float = F(..., unit="kg/m^3", gt=0, description="Density")

    @model_validator(mode="after")
    def _strengths(self):
        if self.Cu <= self.Tu:
            raise ValueError(f"compressive strength Cu = {self.Cu:g} Pa must exceed the tensile "
                             f"strength Tu = {self.Tu:g} Pa (rocks: Cu is about 5-20 x Tu)")
        return self


class _Structure(_MaterialInfo):
    """Micro-structure of a bonded rock (``geodem.materials.STRUCTURE_KEYS``), read by the
    specimen builders and stored by a calibration with the element parameters."""

    bond_strength_weibull: Optional[float] = F(
        None, gt=0, le=100, description="Weibull modulus of the per-bond strength factors "
                                        "(heterogeneity: 2 very scattered, 10 nearly uniform; "
                                        "unset: every bond as strong)")
    packing: Optional[Literal["isotropic", "deposit"]] = F(
        None, description="Specimen packing recipe (part of the rock: a calibration stores "
                          "it): isotropic (radius expansion, stress-free bonds, flat faces) or "
                          "deposit (2-D: gravity deposit, compaction, cut); unset: isotropic "
                          "in 3-D, deposit in 2-D")
    bond_gap: Optional[float] = F(
        None, gt=0, le=0.3, description="Bond range with packing: isotropic: pairs whose "
                                        "surface gap is below bond_gap x d_mean are bonded "
                                        "(default 0.01; larger: more bonds per element)")
    rotation: Optional[bool] = F(
        None, description="Elements turn (rotational degrees of freedom); unset or false: "
                          "MatDEM's translation-only elements (beside a turning material "
                          "they are held from turning, their contacts unchanged)")
    rolling_friction: Optional[float] = F(
        None, ge=0, le=2, description="With rotation: rolling-resistance coefficient mu_r of "
                                      "contacts in compression (moment up to mu_r R* |Fn|, "
                                      "R* = R_i R_j / (R_i + R_j)); default 0")
    bond_moment: Optional[float] = F(
        None, ge=0, le=100, description="With rotation: moment-resisting bonds; a bond holds "
                                        "a rolling moment up to bond_moment R* F_b (F_b its "
                                        "tensile strength; about 0.67 for a 2-D parallel "
                                        "bond as wide as the elements, 0.5 in 3-D); default "
                                        "0: a bond turns freely")
    rolling_stiffness: Optional[float] = F(
        None, ge=0, le=16, description="With rotation: factor beta of the rolling spring, "
                                       "K_r = beta K_s R*^2 (default 1; a stiffer rolling "
                                       "spring raises the compressive strength far more "
                                       "than the tensile; up to 16 the default time step "
                                       "stays stable for the turning modes)")

    @model_validator(mode="after")
    def _rotation_options(self):
        for key in ("rolling_friction", "bond_moment", "rolling_stiffness"):
            if getattr(self, key) is not None and not self.rotation:
                raise ValueError(f"{key} = {getattr(self, key):g} needs rotation: true (the "
                                 "elements must turn to roll)")
        return self


class MicroMaterial(_Structure):
    """Element parameters given directly (as stored per element; a bond between two equal
    elements has half these stiffnesses, two springs in series)."""

    __tag__: ClassVar[str] = "micro"
    rho: float = F(..., unit="kg/m^3", gt=0, description="Density")
    kn: float = F(..., unit="N/m", gt=0, description="Element normal spring stiffness")
    ks: float = F(..., unit="N/m", ge=0, description="Element shear spring stiffness")
    xb: Optional[float] = F(None, unit="m", ge=0,
                            description="Element breaking displacement (default: unbreakable)")
    fs0: Optional[float] = F(None, unit="N", ge=0,
                             description="Element initial shear resistance (default: "
                                         "unbreakable)")
    mu: float = F(0.5, ge=0, description="Element friction coefficient")


class ScaledMicroMaterial(_Structure):
    """Element parameters per element size (what ``geodem calibrate`` writes): an element of
    diameter d gets ``kn = kn_per_d d``, ``ks = ks_per_d d``, ``xb = xb_per_d d``,
    ``fs0 = fs0_per_d2 d^2`` and ``mu`` (PHYSICS.md section 2, mixed sizes), so the same
    values serve every resolution."""

    __tag__: ClassVar[str] = "scaled"
    rho: float = F(..., unit="kg/m^3", gt=0, description="Density")
    kn_per_d: float = F(..., unit="Pa", gt=0, description="Element normal stiffness / diameter")
    ks_per_d: float = F(..., unit="Pa", ge=0, description="Element shear stiffness / diameter")
    xb_per_d: float = F(..., ge=0, description="Element breaking displacement / diameter")
    fs0_per_d2: float = F(..., unit="Pa", ge=0,
                          description="Element initial shear resistance / diameter^2")
    mu: float = F(..., ge=0, description="Element friction coefficient")
    dim: Optional[Literal[2, 3]] = F(None, description="Dimension the values were calibrated "
                                                      "for (checked against the model)")


class LibraryMaterial(Strict):
    """A material of the library (``materials/NAME.yaml`` or a path): its calibrated element
    parameters for the model's dimension (``use: auto`` or ``calibrated``; a file without a
    calibration for that dimension is an error that says how to calibrate it), or, only when
    asked for with ``use: lattice``, its laboratory values converted on the close-packed
    lattice (nu above 0.2 and mu_i below 0.354 clamped, each clamp a warning in
    summary.json)."""

    __tag__: ClassVar[str] = "library"
    library: str = F(..., min_length=1, description="Library material name or file path")
    use: Literal["auto", "calibrated", "lattice"] = F(
        "auto", description="calibrated parameters for the model's dimension (auto and "
                            "calibrated: an error without them) or, explicitly, the lattice "
                            "conversion (clamped, with warnings)")


class MaterialFile(Strict):
    """A material kept in its own YAML file (path relative to the workflow file)."""

    __tag__: ClassVar[str] = "file"
    file: str = F(..., min_length=1, description="YAML file holding the material mapping")


MACRO_KEYS = ("E", "nu", "Tu", "Cu", "mu_i")


def _material_tag(v):
    if isinstance(v, dict):
        if "file" in v:
            return "file"
        if "library" in v:
            return "library"
        if "kn_per_d" in v:
            return "scaled"
        return "macro" if any(k in v for k in MACRO_KEYS) else "micro"
    if isinstance(v, BaseModel):
        return type(v).__tag__
    return None


Material = Annotated[
    Union[Annotated[MacroMaterial, Tag("macro")], Annotated[MicroMaterial, Tag("micro")],
          Annotated[MaterialFile, Tag("file")], Annotated[ScaledMicroMaterial, Tag("scaled")],
          Annotated[LibraryMaterial, Tag("library")]],
    Discriminator(_material_tag, custom_error_type="material",
                  custom_error_message="a material is a mapping: rock properties (E, nu, Tu, "
                                       "Cu, mu_i, rho), element parameters (rho, kn, ks, xb, "
                                       "fs0, mu), per-size element parameters (rho, kn_per_d, ks_per_d, "
                                       "xb_per_d, fs0_per_d2, mu), {library: NAME} or "
                                       "{file: PATH}"),
]


# ============================================================================ registries
def _workflow_changed():
    workflow_model.cache_clear()


# base classes are set below, once defined; the built-in modules: geodem.registry.BUILTINS
STEPS: Registry = Registry("step kind", builtins="workflow", decorator="register_step",
                           prepare=lambda cls, kind: _with_tag(cls, "kind", kind),
                           on_change=_workflow_changed)
MODELS: Registry = Registry("model type", builtins="workflow", decorator="register_model",
                            prepare=lambda cls, name: _with_tag(cls, "type", name),
                            on_change=_workflow_changed)


def check_time_span(nsteps, duration) -> None:
    """A step's length is given as exactly one of ``nsteps`` or ``duration`` (ValueError)."""
    if (nsteps is None) == (duration is None):
        raise ValueError("give exactly one of nsteps (time steps) or duration (seconds)")


def time_steps(dt: float, nsteps=None, duration=None) -> int:
    """Time steps of a step given as ``nsteps`` or as a simulated ``duration`` [s] at the time
    step ``dt`` (at least 1; a duration a round-off short of a whole step count is that count)."""
    if nsteps is not None:
        return int(nsteps)
    return max(1, int(math.ceil(duration / dt - 1e-9)))


class StepBase(Strict):
    """Base of every step kind.

    Contract (one contract test runs it over every registered kind):

    * ``example``: a minimal valid mapping of the kind's fields (``kind`` included), used by the
      contract test and the docs; ``example_model``: the model section it is tested on (None:
      a small 2-D ``lattice_block`` with groups ``base`` and ``top``);
    * ``planned_steps(plan)``: time steps the step will run (0 for instantaneous steps);
    * ``check(cfg, groups)``: semantic problems as ``[(path inside the step, message)]``;
    * ``execute(ctx)``: do the work through :class:`geodem.workflow.runner.StepContext`
      (``ctx.advance(n)`` runs time steps in chunks, with observables, checkpoints and
      interruption between chunks); return a dict of results (numbers) or None. Work done
      before the first ``ctx.advance`` must be skipped when ``ctx.resumed`` (the checkpoint
      holds its effect);
    * optional ``restore(ctx)``: on ``--resume``, called for each step done before the
      checkpoint, to set up again what it left running that the checkpoint does not hold (a
      ``monitor``'s recorder, :meth:`~geodem.workflow.runner.StepContext.add_sampler`).
    """

    __tag__: ClassVar[str] = ""
    example: ClassVar[dict] = {}
    example_model: ClassVar[Optional[dict]] = None
    name: Optional[Name] = F(None, description="Step name (results, logs, --set steps.NAME...); "
                                               "default: the kind, numbered if repeated")

    def planned_steps(self, plan) -> int:
        return 0

    def check(self, cfg, groups) -> list:
        return []

    def execute(self, ctx):  # pragma: no cover - abstract
        raise NotImplementedError


class ModelBase(Strict):
    """Base of every model builder.

    * ``size_field``: the field that sets the element count (memory errors point at it);
    * ``n_elements()``: element count, computed without building;
    * ``bytes_per_element()``: memory estimate per element (state + build temporaries);
    * ``material_refs()``: ``[(path, material name)]`` of the materials it uses;
    * ``group_names()``: groups the built model will have (without building);
    * ``check(cfg)``: semantic problems ``[(path inside the model, message)]``;
    * ``build(cfg)``: the :class:`geodem.workflow.models.BuiltModel`; raise
      :class:`geodem.workflow.models.BuildError` naming the field for bad values.
    """

    __tag__: ClassVar[str] = ""
    size_field: ClassVar[str] = ""
    example: ClassVar[dict] = {}

    def n_elements(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def bytes_per_element(self) -> int:
        return 1800

    def material_refs(self) -> list:
        return []

    def group_names(self) -> list[str]:
        return ["all"]

    def check(self, cfg) -> list:
        return []

    def n_across(self) -> float:
        return 1.0

    def build(self, cfg):  # pragma: no cover - abstract
        raise NotImplementedError


def _with_tag(cls, field_name: str, tag: str):
    if field_name in cls.model_fields:
        ann = cls.model_fields[field_name].annotation
        args = typing.get_args(ann)
        if typing.get_origin(ann) is not Literal or args != (tag,):
            raise TypeError(f"{cls.__name__}.{field_name} must be Literal[{tag!r}]")
        cls.__tag__ = tag
        return cls
    new = create_model(cls.__name__, __base__=cls, __module__=cls.__module__,
                       __doc__=cls.__doc__,
                       **{field_name: (Literal[tag], F(..., description=f"{field_name}: {tag}"))})
    new.__tag__ = tag
    return new


STEPS.base = StepBase
MODELS.base = ModelBase


def register_step(kind: str):
    """Class decorator: register a step kind (a :class:`StepBase` subclass) under ``kind``."""
    return STEPS.register(kind)


def register_model(type_name: str):
    """Class decorator: register a model builder (a :class:`ModelBase` subclass)."""
    return MODELS.register(type_name)


def load_builtins() -> None:
    """Import the built-in model builders and step kinds (they register themselves; the list:
    :data:`geodem.registry.BUILTINS`)."""
    STEPS.load_builtins()


def _union(classes, field_name):
    if len(classes) == 1:
        return classes[0]
    return Annotated[Union[tuple(classes)], Field(discriminator=field_name)]


def _cache(fn):
    import functools

    return functools.lru_cache(maxsize=1)(fn)


@_cache
def workflow_model():
    """The Workflow model class over the currently registered models and step kinds."""
    load_builtins()
    Model = _union([MODELS[k] for k in sorted(MODELS)], "type")  # sorted: import order free
    Step = _union([STEPS[k] for k in sorted(STEPS)], "kind")

    class WorkflowBase(Strict):
        """A geodem workflow: a model, its materials and an ordered list of steps."""

        model_config = ConfigDict(extra="forbid", strict=True, title="geodem workflow",
                                  populate_by_name=True, allow_inf_nan=False)

    fields = dict(
        version=(Literal[SCHEMA_VERSION], F(SCHEMA_VERSION, description="Schema version")),
        metadata=(Metadata, F(...)),
        backend=(Optional[Literal[BACKENDS]],  # type: ignore[valid-type]
                 F(None, description="Compute backend (auto = cupy on a usable GPU, else "
                                     "numba). Order: --backend, this key, $GEODEM_BACKEND, "
                                     "auto")),
        model=(Model, F(..., description="The model builder (type) and its parameters")),
        materials=(dict[Name, Material], F({}, description="Materials by name")),
        simulation=(SimulationSpec, F(default_factory=SimulationSpec)),
        steps=(list[Step], F(..., min_length=1, description="What is done, in order")),
        outputs=(Outputs, F(default_factory=Outputs)),
        checkpoints=(CheckpointSpec, F(default_factory=CheckpointSpec)),
    )
    return create_model("Workflow", __base__=WorkflowBase, **fields)


def json_schema() -> dict:
    """The JSON schema of a workflow file (``geodem schema``, ``docs/geodem.schema.json``)."""
    sch = workflow_model().model_json_schema(by_alias=True)
    out = {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": SCHEMA_ID}
    out.update(sch)
    out["description"] = ("geodem workflow file (YAML). Generated by `geodem schema`; "
                          "see docs/workflows.md.")
    return out


# ============================================================================ error messages
def _unwrap(tp, meta: list):
    while True:
        origin = typing.get_origin(tp)
        if origin is Annotated:
            args = typing.get_args(tp)
            for m in args[1:]:
                meta.extend(getattr(m, "metadata", None) or [m])
            tp = args[0]
            continue
        if origin in (Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) == 1:
                tp = args[0]
                continue
        return tp


def _walk_type(root, loc):
    """Follow ``loc`` through the model classes: ``(parent model, field info, type, meta)``."""
    tp, finfo, parent, meta = root, None, None, []
    for comp in loc:
        meta = []
        tp = _unwrap(tp, meta)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            f = tp.model_fields.get(comp)
            if f is None:
                return tp, None, None, []
            parent, finfo, tp = tp, f, f.annotation
            meta = list(f.metadata)
            continue
        origin = typing.get_origin(tp)
        if origin in (list, tuple) and isinstance(comp, int):
            tp, finfo = typing.get_args(tp)[0], None
            continue
        if origin is dict:
            tp, finfo = typing.get_args(tp)[1], None
            continue
        if origin in (Union, types.UnionType):
            for member in typing.get_args(tp):
                inner = _unwrap(member, [])
                if getattr(inner, "__tag__", None) == comp:
                    tp = inner
                    break
            else:
                return parent, finfo, None, []
            continue
        return parent, finfo, None, []
    last_meta: list = []
    tp = _unwrap(tp, last_meta)
    return parent, finfo, tp, meta + last_meta


def _kind_text(tp) -> str:
    if tp is None:
        return ""
    if typing.get_origin(tp) is Literal:
        return "one of " + ", ".join(repr(a) if isinstance(a, str) else str(a)
                                     for a in typing.get_args(tp))
    if tp is bool:
        return "true or false"
    if tp is int:
        return "a whole number"
    if tp is float:
        return "a number"
    if tp is str:
        return "a string"
    origin = typing.get_origin(tp)
    if origin in (list, tuple):
        inner = _kind_text(_unwrap(typing.get_args(tp)[0], []))
        return f"a list of {inner.removeprefix('a ').removeprefix('an ')}s" if inner else "a list"
    if origin is dict or (isinstance(tp, type) and issubclass(tp, BaseModel)):
        return "a mapping"
    return ""


def allowed_text(finfo, tp, meta) -> str:
    """``'a number > 0 [m]'`` from a field's type, bounds and unit."""
    bounds, extras = [], []
    for m in meta:
        for attr, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            v = getattr(m, attr, None)
            if v is not None and not isinstance(v, bool):
                bounds.append(f"{sym} {v:.6g}" if isinstance(v, float) else f"{sym} {v}")
        lo, hi = getattr(m, "min_length", None), getattr(m, "max_length", None)
        unit = "characters" if tp is str else "items"
        if lo is not None and hi is not None:
            extras.append(f"with {lo} to {hi} {unit}" if lo != hi else f"with {lo} {unit}")
        elif lo is not None:
            extras.append(f"with at least {lo} {unit if lo != 1 else unit[:-1]}")
        elif hi is not None:
            extras.append(f"with at most {hi} {unit}")
        pat = getattr(m, "pattern", None)
        if pat == NAME_PATTERN:
            extras.append("(letters, digits and _, not starting with a digit)")
        elif pat:
            extras.append(f"matching the pattern {pat}")
    kind = _kind_text(tp)
    text = " ".join(p for p in (kind, " and ".join(bounds), " ".join(extras)) if p)
    extra = getattr(finfo, "json_schema_extra", None) or {}
    if isinstance(extra, dict) and extra.get("unit"):
        text += f" [{extra['unit']}]"
    return text.strip()


def _short(v) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def error_message(err: dict, root) -> str:
    """A pydantic error as 'what is wrong; what is allowed'."""
    typ, loc, ctx = err["type"], tuple(err["loc"]), err.get("ctx") or {}
    msg = err["msg"]
    if typ == "extra_forbidden":
        parent, _, target, _ = _walk_type(root, loc[:-1])
        cls = target if isinstance(target, type) and issubclass(target, BaseModel) else parent
        order = {"kind": 0, "type": 0, "description": 2, "source": 2}
        allowed = sorted(cls.model_fields, key=lambda k: order.get(k, 1)) \
            if cls is not None else []
        hint = f"; allowed keys: {', '.join(allowed)}" if allowed else ""
        return f"unknown key {loc[-1]!r}{hint}"
    if typ in ("union_tag_invalid", "union_tag_not_found"):
        disc = str(ctx.get("discriminator", "")).strip("'")
        tags = str(ctx.get("expected_tags", "")).replace("'", "")
        if typ == "union_tag_invalid":
            return f"unknown {disc} {ctx.get('tag')!r}; allowed: {tags}"
        if not isinstance(err.get("input"), dict):
            return f"expected a mapping with a {disc!r} key, got {_short(err.get('input'))}"
        return f"missing {disc!r}; allowed: {_registry_tags(disc)}"
    if typ == "material":
        return msg
    parent, finfo, tp, meta = _walk_type(root, loc)
    allowed = allowed_text(finfo, tp, meta)
    desc = (finfo.description or "") if finfo is not None else ""
    if typ == "missing":
        what = f" ({desc})" if desc else ""
        return f"required field missing{what}" + (f"; allowed: {allowed}" if allowed else "")
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
        return msg
    out = f"{msg} (got {_short(err.get('input'))})"
    if allowed:
        out += f"; allowed: {allowed}"
    if desc and typ in _BOUND_ERRORS:
        out += f" ({desc.rsplit(' [', 1)[0]})"
    return out


_BOUND_ERRORS = ("greater_than", "greater_than_equal", "less_than", "less_than_equal",
                 "too_short", "too_long")


def _registry_tags(disc: str) -> str:
    if disc == "kind":
        return ", ".join(STEPS)
    if disc == "type":
        return ", ".join(MODELS)
    return ""


# ============================================================================ validation
def schema_errors(exc: ValidationError, doc, root) -> list[ErrorItem]:
    items, seen = [], set()
    for err in exc.errors(include_url=False):
        item = doc.error(err["loc"], error_message(err, root), keep_last=err["type"] == "missing")
        key = (item.path, item.message)
        if key not in seen:
            seen.add(key)
            items.append(item)
    items.sort(key=lambda i: (i.file != doc.file, i.line or 0))
    return items


def semantic_errors(cfg) -> list[tuple[tuple, str]]:
    """Cross-field problems of a schema-valid workflow: ``[(path, message)]``."""
    out = []
    mats = cfg.materials
    for path, name in cfg.model.material_refs():
        if name not in mats:
            defined = ", ".join(mats) or "none (add a materials: section)"
            out.append((("model",) + tuple(path),
                        f"unknown material {name!r}; defined materials: {defined}"))
    out += [(("model",) + tuple(p), m) for p, m in cfg.model.check(cfg)]
    out += [p for p in _material_dim_problems(cfg) if p[1] not in {m for _, m in out}]
    sim = cfg.simulation
    if sim.monitor_every and sim.monitor_every % sim.check_every:
        out.append((("simulation", "monitor_every"),
                    f"{sim.monitor_every} is not a multiple of check_every = {sim.check_every}; "
                    f"allowed: 0 or a multiple of check_every"))
    groups = cfg.model.group_names()
    names: dict = {}
    for i, step in enumerate(cfg.steps):
        if step.name is not None:
            if step.name in names:
                out.append((("steps", i, "name"),
                            f"step name {step.name!r} is already used by steps[{names[step.name]}]"
                            f"; step names must be unique"))
            names.setdefault(step.name, i)
        out += [(("steps", i) + tuple(p), m) for p, m in step.check(cfg, groups)]
    obs, frames = cfg.outputs.observables, cfg.outputs.frames
    for key, lst in (("energy_groups", obs.energy_groups), ("groups", obs.groups)):
        for k, g in enumerate(lst or []):
            if g not in groups:
                out.append((("outputs", "observables", key, k), unknown_group(g, groups)))
    for k, g in enumerate(frames.groups):
        if g not in groups:
            out.append((("outputs", "frames", "groups", k), unknown_group(g, groups)))
    return out


def _material_dim_problems(cfg) -> list:
    """Per-size and library materials the model uses that have no values for the model's
    dimension (``dim``): found here, before the model is built, rather than by the build."""
    from geodem.workflow.material import specimen_material

    dim = getattr(cfg.model, "dim", None)
    if dim not in (2, 3):
        return []
    out = []
    for _, name in cfg.model.material_refs():
        mat = cfg.materials.get(name)
        if not isinstance(mat, (ScaledMicroMaterial, LibraryMaterial)):
            continue
        try:
            specimen_material(cfg, name, dim)
        except ValueError as exc:
            problem = (("materials", name), str(exc))
            if problem not in out:
                out.append(problem)
    return out


def unknown_group(name, groups) -> str:
    return f"unknown group {name!r}; the model's groups: {', '.join(groups)}"


def default_names(items) -> list:
    """Names of steps given as ``(kind, name or None)``: the given name, else the kind, numbered
    (``run_1``, ``run_2``) when the kind repeats."""
    items = list(items)
    used = {n for _, n in items if n}
    counts: dict = {}
    for kind, _ in items:
        counts[kind] = counts.get(kind, 0) + 1
    seen: dict = {}
    out = []
    for kind, name in items:
        if name:
            out.append(name)
            continue
        seen[kind] = seen.get(kind, 0) + 1
        base = kind if counts[kind] == 1 else f"{kind}_{seen[kind]}"
        new, k = base, 1
        while new in used:
            k += 1
            new = f"{base}_{k}"
        used.add(new)
        out.append(new)
    return out


def assign_step_names(cfg) -> None:
    """Give every unnamed step a name (see :func:`default_names`)."""
    for s, name in zip(cfg.steps, default_names((s.kind, s.name) for s in cfg.steps)):
        s.name = name


def validate_document(doc):
    """Validate a loaded document: the workflow model instance, or WorkflowError (exit 2)."""
    root = workflow_model()
    try:
        cfg = root.model_validate(doc.data)
    except ValidationError as exc:
        raise WorkflowError(schema_errors(exc, doc, root)) from None
    problems = semantic_errors(cfg)
    if problems:
        items = [doc.error(p, m) for p, m in problems]
        items.sort(key=lambda i: (i.file != doc.file, i.line or 0))
        raise WorkflowError(items)
    assign_step_names(cfg)
    return cfg
