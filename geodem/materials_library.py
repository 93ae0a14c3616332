"""Material library: laboratory (macro) properties of rocks and soils with their sources.

Each file ``materials/NAME.yaml`` (repository root) holds ``E, nu, Tu, Cu, mu_i, rho``, every value
with a literature source, plus ``notes`` and a ``calibrated`` placeholder (``null`` until the
calibration writes the micro parameters and its record). See docs/materials.md.

* :func:`load_material` reads and validates a file by name (``"granite"``) or path;
* :func:`list_materials` names the files of the library;
* :func:`to_micro` converts a material to bond parameters with
  :func:`geodem.materials.macro_to_micro`.

Clamping in :func:`to_micro`: the ideal close-packed lattice reaches only ``nu <= 0.2`` (above it
``Ks < 0``) and ``mu_i >= 1/sqrt(8) = 0.3536`` (below it the bond friction ``mu_p < 0``). The
material file keeps the true laboratory values as targets; ``to_micro`` converts with
``nu_used = min(nu, 0.2)`` and ``mu_i_used = max(mu_i, 0.3536)`` and records one warning per
clamped value in :attr:`MicroConversion.warnings` (nothing is clamped silently).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from geodem.materials import MU_I_MIN, Micro, macro_to_micro

#: folder of the library files (repository root / materials)
LIBRARY_DIR = Path(__file__).resolve().parent.parent / "materials"
#: largest Poisson's ratio the close-packed lattice reaches (Ks = 0 at nu = 0.2)
NU_MAX_LATTICE = 0.2
#: smallest internal friction tan(phi) the lattice reaches (mu_p = 0), = 1/sqrt(8)
MU_I_MIN_LATTICE = MU_I_MIN

PROPERTY_NAMES = ("E", "nu", "Tu", "Cu", "mu_i", "rho")
UNITS = {"E": "Pa", "nu": "-", "Tu": "Pa", "Cu": "Pa", "mu_i": "-", "rho": "kg/m^3"}
RANGES = {
    "E": "E > 0 [Pa]",
    "nu": "-1 < nu < 0.5",
    "Tu": "Tu > 0 [Pa] and Tu < Cu",
    "Cu": "Cu > 0 [Pa] and Cu > Tu",
    "mu_i": "mu_i = tan(phi) > 0",
    "rho": "rho > 0 [kg/m^3]",
}


class MaterialError(ValueError):
    """A material file is missing, unreadable or invalid; the message names file and field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Source(_Strict):
    """Where one value comes from."""

    author: str = Field(..., min_length=1, description="Author(s), 'Surname, I.; Surname, I.'")
    year: int = Field(..., ge=1800, le=2100, description="Publication year")
    title: str = Field(..., min_length=1, description="Book or paper (journal, volume, pages)")
    what: str = Field(..., min_length=1,
                      description="What the value is: 'typical value', 'range midpoint', a table "
                                  "entry, or a modelling assumption")


class Quantity(_Strict):
    value: float = Field(..., description="The value in SI units")
    unit: str = Field(..., description="Pa, kg/m^3 or '-' (dimensionless)")
    source: Source

    @field_validator("value")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError(f"{v!r} is not a finite number")
        return v


class Properties(_Strict):
    """Laboratory properties (targets). Compression positive; strengths are magnitudes."""

    E: Quantity = Field(..., description="Young's modulus [Pa]")
    nu: Quantity = Field(..., description="Poisson's ratio [-]")
    Tu: Quantity = Field(..., description="Tensile strength [Pa]")
    Cu: Quantity = Field(..., description="Uniaxial compressive strength (UCS) [Pa]")
    mu_i: Quantity = Field(..., description="Internal friction coefficient tan(phi) [-]")
    rho: Quantity = Field(..., description="Density [kg/m^3]")

    @field_validator("E", "Tu", "Cu", "rho")
    @classmethod
    def _positive(cls, q: Quantity, info) -> Quantity:
        if not q.value > 0:
            raise ValueError(f"value {q.value!r} out of range; allowed: {RANGES[info.field_name]}")
        return q

    @field_validator("nu")
    @classmethod
    def _nu(cls, q: Quantity) -> Quantity:
        if not -1.0 < q.value < 0.5:
            raise ValueError(f"value {q.value!r} out of range; allowed: {RANGES['nu']}")
        return q

    @field_validator("mu_i")
    @classmethod
    def _mu(cls, q: Quantity) -> Quantity:
        if not q.value > 0:
            raise ValueError(f"value {q.value!r} out of range; allowed: {RANGES['mu_i']}")
        return q

    @model_validator(mode="after")
    def _units_and_strengths(self):
        for name in PROPERTY_NAMES:
            unit = getattr(self, name).unit
            if unit != UNITS[name]:
                raise ValueError(f"{name}.unit = {unit!r}; allowed: {UNITS[name]!r} "
                                 "(values are in SI units)")
        if not self.Tu.value < self.Cu.value:
            raise ValueError(f"Tu = {self.Tu.value:g} Pa must be below Cu = {self.Cu.value:g} Pa "
                             "(allowed: 0 < Tu < Cu; rocks have Cu of about 5-20 x Tu)")
        return self


class Material(_Strict):
    """One material file."""

    name: str = Field(..., pattern=r"^[A-Za-z_][A-Za-z0-9_\-]*$", description="Identifier")
    category: Literal["rock", "soil"] = Field(..., description="rock or soil")
    description: str = Field("", description="What the material is")
    properties: Properties
    notes: list[str] = Field(default_factory=list,
                             description="Caveats, e.g. values the lattice cannot reach")
    calibrated: dict[str, Any] | None = Field(
        None, description="Calibrated micro parameters and calibration record; null until "
                          "the calibration fills it in")

    def values(self) -> dict[str, float]:
        """``{E, nu, Tu, Cu, mu_i, rho}`` as plain floats (the laboratory targets)."""
        return {k: getattr(self.properties, k).value for k in PROPERTY_NAMES}


# ---------------------------------------------------------------------------------- loading
def list_materials(directory: str | Path | None = None) -> list[str]:
    """Names (file stems) of the material files in ``directory`` (default: the library)."""
    d = Path(directory) if directory is not None else LIBRARY_DIR
    return sorted(p.stem for p in d.glob("*.yaml")) if d.is_dir() else []


def _resolve(name_or_path: str | Path) -> Path:
    s = str(name_or_path)
    p = Path(s).expanduser()
    looks_like_path = isinstance(name_or_path, Path) or p.suffix in (".yaml", ".yml") or \
        "/" in s or "\\" in s
    if looks_like_path:
        if p.is_file():
            return p
        raise MaterialError(f"{p}: material file not found")
    cand = LIBRARY_DIR / f"{s}.yaml"
    if cand.is_file():
        return cand
    raise MaterialError(f"material {s!r} not found in {LIBRARY_DIR}; available: "
                        f"{', '.join(list_materials()) or '(none)'} (or give a path to a .yaml file)")


def _format_errors(path: Path, err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown field (allowed: name, category, description, properties, notes, " \
                  "calibrated; properties: E, nu, Tu, Cu, mu_i, rho, each with value, unit, source)"
        lines.append(f"{path}: {loc}: {msg}")
    return "invalid material file\n  " + "\n  ".join(lines)


def material_path(name_or_path: str | Path) -> Path:
    """The file of a library material (name) or a material file (path)."""
    return _resolve(name_or_path)


def load_material(name_or_path: str | Path) -> Material:
    """Load and validate a material by library name (``"granite"`` -> ``materials/granite.yaml``)
    or by path. Raises :class:`MaterialError` naming the file, the field and the allowed range."""
    path = _resolve(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise MaterialError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise MaterialError(f"{path}: a material file holds a mapping (name, category, properties, "
                            "...), got " + type(data).__name__)
    try:
        return Material.model_validate(data)
    except ValidationError as exc:
        raise MaterialError(_format_errors(path, exc)) from None


#: the columns of :func:`calibration_cells` (``geodem library``, docs/calibration.md)
CALIBRATION_COLUMNS = ("material (lab E, nu, Cu, Tu, phi)", "elements", "best iteration", "E",
                       "nu", "Cu (UCS)", "Tu (direct tension)", "phi (triaxial)",
                       "Brazilian / Tu (disc)", "run")


def calibration_rows(dim: int, names: list[str] | None = None) -> list[dict]:
    """One row per library material (``names``, default all) for its stored ``calibrated.<dim>d``
    record: lab ``targets``, the ``record`` (None where the material has no calibration for
    ``dim``) and its ``errors`` against the lab values (relative; absolute for nu)."""
    rows = []
    for name in names or list_materials():
        m = load_material(name)
        rec = (m.calibrated or {}).get(f"{dim}d")
        row = {"name": m.name, "dim": dim, "targets": m.values(), "record": rec}
        if rec:
            meas = rec["measured"]
            row["errors"] = {k: (meas[k] - row["targets"][k] if k == "nu" else
                                 meas[k] / row["targets"][k] - 1) for k in ("E", "nu", "Cu", "Tu")}
        rows.append(row)
    return rows


def _elements_cell(spec: dict) -> str:
    """The micro-structure of a calibration record in a few words."""
    if not spec.get("rotation"):
        return "translating"
    return (f"turning (bond moment {_g(spec.get('bond_moment', 0.0))}, rolling stiffness "
            f"{_g(spec.get('rolling_stiffness', 1.0))})")


def calibration_cells(row: dict) -> list[str]:
    """The :data:`CALIBRATION_COLUMNS` of one :func:`calibration_rows` row as text: each value
    with its error against the lab value, the micro-structure, the iterations, the friction
    angle (where the calibration matched it; ``± s`` the standard error of its mean over the
    packings, where the record has it), the Brazilian check and its disc (elements across),
    and the run (date, wall time, threads)."""
    import math

    t, rec = row["targets"], row["record"]
    phi_lab = math.degrees(math.atan(t["mu_i"]))
    lab = (f"{row['name']} ({_g(t['E'] / 1e9)} GPa, {t['nu']:g}, {_g(t['Cu'] / 1e6)} MPa, "
           f"{_g(t['Tu'] / 1e6)} MPa, {phi_lab:.0f} deg)")
    if not rec:
        return [lab, f"no {row['dim']}-D calibration"] + [""] * (len(CALIBRATION_COLUMNS) - 2)
    m, e, spec = rec["measured"], row["errors"], rec.get("specimen", {})
    state = "converged" if rec["converged"] else "not converged"
    run = rec.get("run") or {}
    when = (f"{run['date']}, {run['wall_time_s']:.0f} s on {run['threads']} thread"
            f"{'s' if run.get('threads') != 1 else ''}" if run else "")
    if run.get("check_wall_time_s") is not None:
        when += f" (disc check {run['check_wall_time_s']:.0f} s)"
    phi = m.get("phi")
    phi_se = (rec.get("friction_test") or {}).get("phi_standard_error")
    phi_cell = (f"{phi:.1f} deg ({phi - phi_lab:+.1f})"
                + (f" ± {phi_se:.1f}" if phi_se is not None else "") if phi is not None
                else "not matched")
    braz = rec.get("brazilian") or {}
    across = (f", {spec['disc_diameter'] / spec['d_mean']:.0f} across"
              if spec.get("disc_diameter") and spec.get("d_mean") else "")
    cells = [lab, _elements_cell(spec),
             f"{rec.get('best_iteration', rec['iterations'])} of {rec['iterations']} ({state})",
             f"{_g(m['E'] / 1e9)} GPa ({e['E']:+.1%})", f"{m['nu']:.3f} ({e['nu']:+.3f})",
             f"{_g(m['Cu'] / 1e6)} MPa ({e['Cu']:+.1%})", f"{_g(m['Tu'] / 1e6)} MPa ({e['Tu']:+.1%})",
             phi_cell, (f"{braz['over_target']:.2f}{across}" if braz else "not checked"),
             when]
    return [c.replace("%)", " %)") for c in cells]


def calibration_markdown(dim: int, names: list[str] | None = None) -> str:
    """The stored calibrations of ``dim`` as a markdown table (docs/calibration.md, "Measured:
    the library")."""
    lines = ["| " + " | ".join(CALIBRATION_COLUMNS) + " |", "|" + "---|" * len(CALIBRATION_COLUMNS)]
    lines += ["| " + " | ".join(calibration_cells(r)) + " |"
              for r in calibration_rows(dim, names)]
    return "\n".join(lines) + "\n"


def _g(x: float) -> str:
    """Three significant digits, no exponent for the magnitudes the tables hold."""
    return f"{x:.3g}" if x >= 0.01 else f"{x:.2e}"


# ------------------------------------------------------------------------------ conversion
@dataclass(frozen=True)
class MicroConversion:
    """Result of :func:`to_micro`.

    ``target``: the laboratory values of the file; ``used``: the values given to
    ``macro_to_micro`` (equal to ``target`` except where clamped); ``clamped``: names of the
    clamped properties; ``warnings``: one sentence per clamped value.
    """

    micro: Micro
    target: dict[str, float]
    used: dict[str, float]
    clamped: tuple[str, ...] = ()
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def element(self) -> dict:
        return self.micro.element


def to_micro(material: Material | str | Path, d: float) -> MicroConversion:
    """Bond parameters of ``material`` for element diameter ``d`` [m] on the close-packed lattice.

    ``nu`` above 0.2 is converted as 0.2 and ``mu_i`` below 1/sqrt(8) as 1/sqrt(8) (the lattice
    limits); each clamp is recorded in the result's ``warnings``. Other values pass unchanged.
    """
    mat = material if isinstance(material, Material) else load_material(material)
    target = mat.values()
    used = dict(target)
    clamped, warns = [], []
    if used["nu"] > NU_MAX_LATTICE:
        used["nu"] = NU_MAX_LATTICE
        clamped.append("nu")
        warns.append(f"{mat.name}: nu = {target['nu']:g} is above the lattice limit 0.2 (Ks would "
                     "be negative); converted with nu = 0.2, the target nu is not reachable")
    if used["mu_i"] < MU_I_MIN_LATTICE:
        used["mu_i"] = MU_I_MIN_LATTICE
        clamped.append("mu_i")
        warns.append(f"{mat.name}: mu_i = {target['mu_i']:g} is below the lattice limit "
                     f"{MU_I_MIN_LATTICE:.4f} (phi < 19.47 deg, bond friction would be negative); "
                     f"converted with mu_i = {MU_I_MIN_LATTICE:.4f}")
    micro = macro_to_micro(E=used["E"], nu=used["nu"], Tu=used["Tu"], Cu=used["Cu"],
                           mu_i=used["mu_i"], rho=used["rho"], d=d)
    return MicroConversion(micro, target, used, tuple(clamped), tuple(warns))
