"""Materials of a workflow as the model builders need them: the material a specimen (or any
model built at a mean element size) is made of, resolved from the workflow's ``materials:``
section (macro, micro, per-size and library materials), its problems, and the element rotation
a material asks for."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from geodem.workflow.models import BuildError, BuiltModel
from geodem.workflow.schema import MacroMaterial


# ============================================================================ materials
class SpecimenMaterial:
    """What a specimen builder needs from a material: ``rho``, and either ``macro`` (rock
    properties for ``macro_to_micro``) or ``element`` (size-free element parameters,
    :func:`geodem.materials.per_size` keys); ``label`` says which, ``warnings`` what was
    clamped."""

    def __init__(self, rho, macro=None, element=None, label="", warnings=(), name=None,
                 record=None):
        self.rho, self.macro, self.element = float(rho), macro, element
        self.label, self.warnings = label, tuple(warnings)
        # a library material: its name and the calibration record it was taken from
        self.name, self.record = name, record

    @property
    def material(self) -> dict:
        """The ``material`` argument of :func:`geodem.build.specimen.make_specimen`."""
        return dict(self.macro) if self.macro else {"rho": self.rho}


def specimen_material(cfg, name: str, dim: int, d_mean: float | None = None) -> SpecimenMaterial:
    """Resolve ``cfg.materials[name]`` for a bonded specimen of dimension ``dim``.

    * rock properties (``E, nu, ...``): lattice conversion (nu < 0.2 needed: at 0.2 the
      shear springs vanish and a random packing is a mechanism);
    * per-size element parameters (``kn_per_d, ...``, e.g. from ``geodem calibrate``);
    * ``{library: NAME}``: the library file's calibration for ``dim`` (``use: auto`` or
      ``calibrated``; an error where there is none), or with ``use: lattice`` its laboratory
      values on the lattice (clamped, with warnings);
    * element parameters (``kn, ks, xb, fs0, mu``) for an element of diameter ``d_mean`` (needs
      ``d_mean``; unset ``xb``/``fs0``: unbreakable), scaled to the other sizes by
      ``kn, ks, xb ∝ d``, ``fs0 ∝ d^2``.

    Raises ``ValueError`` with the reason (the callers turn it into a field error)."""
    from geodem.materials_library import load_material, to_micro
    from geodem.workflow.schema import LibraryMaterial, ScaledMicroMaterial

    from geodem.materials import STRUCTURE_KEYS, per_size
    from geodem.workflow.schema import MicroMaterial

    m = cfg.materials[name]
    if isinstance(m, MicroMaterial) and d_mean is not None:
        el = {"kn": m.kn, "ks": m.ks, "xb": m.xb if m.xb is not None else 1.0e6 * d_mean,
              "fs0": m.fs0 if m.fs0 is not None else 1.0e12, "mu": m.mu,
              **{k: getattr(m, k) for k in STRUCTURE_KEYS if getattr(m, k) is not None}}
        return SpecimenMaterial(m.rho, element=per_size(el, d_mean),
                                label=f"element parameters at d = {d_mean:g} m")
    if isinstance(m, MacroMaterial):
        if m.nu >= 0.2:
            raise ValueError(f"material {name!r} has nu = {m.nu:g}: macro_to_micro then gives "
                             "ks = 0, and a random packing without shear springs is a mechanism "
                             "(it never balances); allowed for a specimen: nu < 0.2, or "
                             "calibrated parameters")
        macro = {k: getattr(m, k) for k in ("E", "nu", "Tu", "Cu", "mu_i", "rho")}
        return SpecimenMaterial(m.rho, macro=macro, label="lattice conversion")
    if isinstance(m, ScaledMicroMaterial):
        if m.dim is not None and m.dim != dim:
            raise ValueError(f"material {name!r} was calibrated in {m.dim}-D; the model is "
                             f"{dim}-D: calibrate it for dim = {dim}, or, to take these element "
                             f"parameters in {dim}-D as they are (another rock: uncalibrated), "
                             f"set its dim: {dim}")
        el = {k: getattr(m, k) for k in ("kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2", "mu")
              + STRUCTURE_KEYS if getattr(m, k) is not None}
        return SpecimenMaterial(m.rho, element=el, label="per-size element parameters")
    if isinstance(m, LibraryMaterial):
        try:
            lib = load_material(m.library)
        except Exception as exc:  # noqa: BLE001 - MaterialError / FileNotFoundError: reported
            raise ValueError(str(exc)) from None
        cal = (lib.calibrated or {}).get(f"{dim}d") if m.use != "lattice" else None
        if cal is not None:
            return SpecimenMaterial(lib.values()["rho"], element=dict(cal["element"]),
                                    label=f"{lib.name}: calibrated ({dim}-D)",
                                    warnings=resolution_warnings(lib.name, cal, d_mean, dim),
                                    name=lib.name, record=cal)
        if m.use != "lattice":
            # no silent fallback: the lattice conversion is another rock (a 3-D sandstone on it
            # gave E 1.6 GPa for 15, nu 1.1), so it is taken only when asked for
            raise ValueError(f"library material {lib.name!r} has no {dim}-D calibration; "
                             f"calibrate it with 'geodem calibrate {m.library} --dim {dim} "
                             f"--save', or set use: lattice to take its laboratory values on "
                             f"the close-packed lattice (nu and mu_i clamped to the lattice's "
                             f"limits, with warnings in summary.json)")
        conv = to_micro(lib, 1.0)
        macro = dict(conv.used)
        warns = list(conv.warnings)
        if macro["nu"] >= 0.2:
            macro["nu"] = 0.19
            warns.append(f"{lib.name}: a random packing needs nu < 0.2 in the lattice conversion; "
                         "converted with nu = 0.19")
        return SpecimenMaterial(macro["rho"], macro=macro, label=f"{lib.name}: lattice conversion",
                                warnings=warns)
    raise ValueError(f"material {name!r} must give rock properties (E, nu, Tu, Cu, mu_i, rho), "
                     "per-size element parameters or {library: NAME}")


#: element sizes within this ratio of the calibration's count as its resolution
SAME_RESOLUTION = 0.1


def resolution_warnings(name: str, cal: dict, d_mean: float | None, dim: int) -> list:
    """A warning when turning elements (``rotation`` in the calibrated ``element``) serve at
    an element size more than :data:`SAME_RESOLUTION` away from the calibration's: their
    rolling springs make the strength depend on the resolution (the library sandstone's UCS
    measured 20 % lower at 2x finer elements while E moved 2 %, docs/calibration.md
    "Resolution transfer"), so the calibrated numbers hold at the calibration's size only."""
    cal_d = (cal.get("specimen") or {}).get("d_mean")
    if d_mean is None or not cal_d or not (cal.get("element") or {}).get("rotation"):
        return []
    if abs(float(d_mean) / float(cal_d) - 1.0) <= SAME_RESOLUTION:
        return []
    return [f"{name}: calibrated with turning elements at d_mean = {float(cal_d):g} m, used at "
            f"{float(d_mean):g} m: the strengths of turning elements depend on the resolution "
            f"(UCS 20 % lower at 2x finer elements for the library sandstone; "
            f"docs/calibration.md 'Resolution transfer'); for calibrated strengths calibrate at "
            f"this size: geodem calibrate {name} --dim {dim} --d-mean {float(d_mean):g} "
            f"-o DIR"]


#: a Brazilian check within this fraction of Tu reads the rock's tensile strength (the
#: consistency tests/integration/test_one_rock.py asserts: Brazilian and direct tension
#: within 15 %)
BRAZILIAN_AGREES = 0.15


def disc_warnings(sm: SpecimenMaterial, n_across: float) -> list:
    """A warning for a Brazilian disc of a calibrated library material whose record's
    Brazilian check (``brazilian.over_target`` on discs ``specimen.disc_diameter / d_mean``
    across) says the disc will not read the rock's tensile strength: the disc is coarser than
    the checked one (a coarse disc is crushed under its platens before it splits and reads
    higher), or the check itself, on discs of this size, read more than
    :data:`BRAZILIAN_AGREES` off Tu. A finer disc is not warned about."""
    rec = sm.record or {}
    check, spec = rec.get("brazilian") or {}, rec.get("specimen") or {}
    ratio, disc, d = check.get("over_target"), spec.get("disc_diameter"), spec.get("d_mean")
    if ratio is None or not disc or not d:
        return []
    checked = float(disc) / float(d)
    coarser = n_across < (1.0 - SAME_RESOLUTION) * checked
    same = abs(n_across / checked - 1.0) <= SAME_RESOLUTION
    if not (coarser or (same and abs(float(ratio) - 1.0) > BRAZILIAN_AGREES)):
        return []
    text = (f"{sm.name}: the calibration's Brazilian check split discs {checked:.0f} d_mean "
            f"across at {float(ratio):.2f} x its direct-tension strength Tu; this disc is "
            f"{n_across:.0f} across")
    if coarser:
        text += (", coarser: expect it to read higher (a coarse disc is crushed under its "
                 "platens before it splits")
    else:
        text += (": expect about the same ratio (the Brazilian strength is Tu only on discs "
                 "fine enough")
    return [text + "; docs/calibration.md, 'Friction angle in 3-D' and 'Rolling stiffness')"]


class MaterialRolling(NamedTuple):
    """One material's rotation option in a model (:func:`material_rotation`)."""
    rolling_friction: float
    bond_moment: float
    rolling_stiffness: float
    mu: float       # its element friction: how its elements are told apart
    turns: bool     # False: a translating material, its elements held from turning


def material_rotation(cfg, model) -> dict | None:
    """The rotation option of the materials ``model`` uses (``rotation``, ``rolling_friction``,
    ``bond_moment``, ``rolling_stiffness`` of their element parameters): None when none asks
    for it, else ``{"rolling_friction": mu_r, "bond_moment": b, "rolling_stiffness": beta}``
    (the largest of each over the turning materials), and, where the materials differ in those
    values or some translate, ``"per_material"``: material name -> :class:`MaterialRolling`
    (``mu`` its element friction: how :func:`apply_material_rotation` tells the elements
    apart). The engine gives every element of such a model rotational degrees of
    freedom; the elements of a translating material (``rotation`` false) are held from turning,
    which leaves their own contacts exactly as on translating elements (a contact's rolling
    moment comes from the elements' rotations only), and take the largest values as walls do,
    so that a contact with a turning element takes that element's."""
    dim = getattr(model, "dim", None)
    if dim not in (2, 3):
        return None
    seen, friction = {}, {}
    for _, name in model.material_refs():
        if name in seen or name not in cfg.materials:
            continue
        try:
            # (any size serves: the options read are the same at every size)
            el = specimen_material(cfg, name, dim, d_mean=1.0).element or {}
        except ValueError:
            continue  # the build reports it
        beta = el.get("rolling_stiffness")
        seen[name] = ((float(el.get("rolling_friction") or 0.0),
                       float(el.get("bond_moment") or 0.0),
                       1.0 if beta is None else float(beta)) if el.get("rotation") else None)
        friction[name] = el.get("mu")
    wanted = {v for v in seen.values()}
    if wanted <= {None}:
        return None
    turning = wanted - {None}
    mu_r, mb, beta = (max(v[k] for v in turning) for k in range(3))
    out = {"rolling_friction": mu_r, "bond_moment": mb, "rolling_stiffness": beta}
    if len(wanted) > 1:
        mus = [friction[n] for n in seen]
        if None in mus or len(set(mus)) < len(mus):
            raise BuildError(("materials",), "the model's materials differ in rotation, "
                             "rolling_friction, bond_moment or rolling_stiffness, and their "
                             "elements are told apart by their element friction mu, which "
                             f"{'is unknown for one' if None in mus else 'two share'}; allowed: "
                             "one set of those values, or a different mu for each material")
        out["per_material"] = {
            n: MaterialRolling(*(v if v is not None else (mu_r, mb, beta)),
                               float(friction[n]), v is not None) for n, v in seen.items()}
    return out


def rotation_arrays(rot: dict, mu) -> tuple:
    """Per-element ``(mu_r, bond_moment, rolling_stiffness)`` for a model whose turning
    materials differ (:func:`material_rotation`'s ``per_material``): an element whose friction
    ``mu`` equals a material's takes that material's values; the others (walls, platens, a
    cutter) take the largest of each, so that their contacts take the rock's (a contact
    takes the smaller of its two elements' values). Scalars when the materials agree."""
    if "per_material" not in rot:
        return rot["rolling_friction"], rot["bond_moment"], rot["rolling_stiffness"]
    mu = np.asarray(mu, dtype=np.float64)
    out = [np.full(mu.shape, rot[k]) for k in ("rolling_friction", "bond_moment",
                                                "rolling_stiffness")]
    for m in rot["per_material"].values():
        mine = mu == m.mu
        for a, v in zip(out, (m.rolling_friction, m.bond_moment, m.rolling_stiffness)):
            a[mine] = v
    return tuple(out)


def translating_elements(rot: dict, mu) -> np.ndarray:
    """Mask of the elements of the translating materials of a model that mixes them with
    turning ones (:func:`material_rotation`), told apart by their element friction ``mu``."""
    mu = np.asarray(mu, dtype=np.float64)
    held = np.zeros(mu.shape, dtype=bool)
    for m in (rot.get("per_material") or {}).values():
        if not m.turns:
            held |= mu == m.mu
    return held


def apply_material_rotation(cfg, built: BuiltModel) -> None:
    """Switch on the materials' rotation (:func:`material_rotation`) for the built model:
    every element turns (walls and platens, being fixed or prescribed, do not; nor do the
    elements of a translating material beside turning ones), with the materials' rolling
    friction, moment-resisting bonds and rolling stiffness (per element,
    :func:`rotation_arrays`, where the materials differ); recorded in ``built.info``."""
    rot = material_rotation(cfg, cfg.model)
    if rot is None:
        return
    from geodem.core.state import enable_rotation

    if built.state.rotation:
        raise BuildError(("model",), "the model turns its elements already (its own rotation "
                                     "option) and its material asks for rotation too; allowed: "
                                     "one of the two")
    mu_r, mb, beta = rotation_arrays(rot, built.state.mu)
    enable_rotation(built.state, mu_r=mu_r, bond_moment=mb, rolling_stiffness=beta)
    held = translating_elements(rot, built.state.mu)
    built.state.rfree[held] = 0.0
    built.info["rotation"] = {k: v for k, v in rot.items() if k != "per_material"}
    if "per_material" in rot:
        mu = np.asarray(built.state.mu)
        built.info["rotation"]["per_material"] = {
            n: ({"rolling_friction": m.rolling_friction, "bond_moment": m.bond_moment,
                 "rolling_stiffness": m.rolling_stiffness} if m.turns else {"turns": False})
            | {"mu": m.mu, "elements": int(np.sum(mu == m.mu))}
            for n, m in rot["per_material"].items()}


# ============================================================================ specimen
def material_problems(cfg, name: str, dim: int, d_mean: float | None = None) -> list:
    """``[(("material",), message)]`` when material ``name`` cannot serve a specimen of
    dimension ``dim`` (:func:`specimen_material` refuses it); ``[]`` otherwise, also when the
    name is unknown (the schema reports that)."""
    if name not in cfg.materials:
        return []
    try:
        specimen_material(cfg, name, dim, d_mean)
    except ValueError as exc:
        return [(("material",), str(exc))]
    return []


def box_size_problems(size, dim: int, d_mean: float) -> list:
    """Field problems of a box specimen's ``size`` (``dim`` lengths > 0, at least 4 d_mean)."""
    if len(size) != dim:
        return [(("size",), f"{len(size)} values for dim = {dim}; allowed: {dim} lengths > 0 "
                            "[m]")]
    if any(not s > 0 for s in size):
        return [(("size",), "allowed: lengths > 0 [m]")]
    if min(size) < 4 * d_mean:
        return [(("size",), f"the specimen must be at least 4 d_mean = {4 * d_mean:g} m "
                            "across")]
    return []




# ============================================================================ elastic lattice
def rock_properties(cfg, name: str, path=("material",), d=None,
                    dim=None) -> tuple[float, float, float, str]:
    """``(E, nu, rho, source)`` of material ``name``: a library rock's laboratory values, a
    rock-property material's, or the medium that element parameters (kn, ks) make on the
    close-packed lattice of spacing ``d`` in ``dim`` (the lattice's E, nu); others are refused
    (BuildError at ``path``)."""
    from geodem.workflow.schema import LibraryMaterial, MicroMaterial

    m = cfg.materials[name]
    if isinstance(m, LibraryMaterial):
        from geodem.materials_library import load_material

        try:
            v = load_material(m.library).values()
        except Exception as exc:  # noqa: BLE001 - reported as a build error
            raise BuildError(path, f"library material {m.library!r} not readable: "
                                   f"{exc}") from None
        return float(v["E"]), float(v["nu"]), float(v["rho"]), \
            f"library {m.library!r} (laboratory)"
    if isinstance(m, MacroMaterial):
        return float(m.E), float(m.nu), float(m.rho), f"material {name!r}"
    if isinstance(m, MicroMaterial) and dim in (2, 3):
        # element parameters on the lattice: the medium they make (their own E, nu)
        from geodem.materials import lattice_E_nu, micro_to_macro

        Kn, Ks = 0.5 * m.kn, 0.5 * m.ks
        E, nu = lattice_E_nu(Kn, Ks, d) if dim == 2 else \
            [micro_to_macro(Kn, Ks, 1.0, 1.0, 0.5, d)[k] for k in ("E", "nu")]
        return float(E), float(nu), float(m.rho), f"element parameters of {name!r} (kn, ks)"
    raise BuildError(path, f"material {name!r} gives per-size element parameters; elements: "
                           f"elastic needs rock properties (a library material or E, nu, rho, "
                           f"...) or element parameters (kn, ks)")


def elastic_medium(cfg, name: str, d: float, dim: int, path=("material",)) -> dict:
    """The elastic lattice medium (:func:`geodem.materials.elastic_lattice`) of material
    ``name``'s rock properties at spacing ``d``, with ``source`` (where E, nu, rho came
    from)."""
    from geodem.materials import elastic_lattice

    E, nu, rho, src = rock_properties(cfg, name, path, d, dim)
    try:
        med = elastic_lattice(E, nu, rho, d, dim)
    except ValueError as exc:
        raise BuildError(path, f"material {name!r}: {exc}") from None
    med["source"] = src
    return med
