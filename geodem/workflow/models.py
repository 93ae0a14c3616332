"""Registered model builders (``model: {type: ...}`` in a workflow).

* ``two_balls``: MatDEM's TwoBalls, ``wall - ball - ball - wall`` bonded in a row
  (:mod:`geodem.cases.two_balls`), one independent copy per damping case, all in one model;
* ``lattice_block``: a bonded close-packed block (FCC in 3-D, triangular in 2-D) with named
  boundary groups.

A builder is a :class:`~geodem.workflow.schema.ModelBase` subclass registered with
``@register_model("name")``; it returns a :class:`BuiltModel`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal, Optional

import numpy as np
from pydantic import Field, model_validator

from geodem.workflow.schema import (
    DOF_NAMES,
    F,
    Int,
    MacroMaterial,
    MicroMaterial,
    ModelBase,
    Name,
    Strict,
    register_model,
)


#: the source tree's root: data files named in workflows (``workflows/data/...``) are found
#: from any working directory
ROOT = Path(__file__).resolve().parents[2]


def resolve_path(path: str) -> Path:
    """A data file named in a workflow (raster, image): absolute, or relative to the working
    directory, else to the geodem source tree (so ``workflows/data/hill.tif`` is found from
    anywhere)."""
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists():
        return p
    q = ROOT / p
    return q if q.exists() else p


def state_bytes_per_element(dim: int, width: int) -> int:
    """State bytes per element at row width ``width``: 7 (N, dim) float64 arrays, props (8
    float64), m, eta, group, the rows (nbr int32, cstate int32, fs dim float64, brate float32)
    and 5 energy accumulators."""
    return 7 * dim * 8 + 8 * 8 + 2 * 8 + 4 + width * (4 + 4 + 8 * dim + 4) + 5 * 8


class BuildError(ValueError):
    """A model cannot be built from its parameters; ``path`` names the field (inside ``model``
    or from the top, when it starts with ``'materials'``)."""

    def __init__(self, path, message):
        super().__init__(message)
        self.path = tuple(path)


@dataclass
class BuiltModel:
    """A model ready to run: its state, the reference positions displacements are measured
    from, the elements across the model (standard damping/balance) and builder information."""

    state: object
    reference: np.ndarray
    n_across: float
    info: dict = field(default_factory=dict)


def element_params(cfg, name: str, d: float, dim: int, path=("material",)) -> dict:
    """Element parameters of material ``name`` for diameter ``d``:
    ``kn, ks, xb, fs0, mu, rho`` and ``mass`` (None: from rho and the element volume)."""
    from geodem.materials import macro_to_micro

    mat = cfg.materials[name]
    if isinstance(mat, MacroMaterial):
        if dim != 3:
            raise BuildError(path, f"material {name!r} gives rock properties (E, nu, ...), which "
                                   "convert to element parameters on the 3-D close-packed "
                                   "lattice only; use dim: 3, or give element parameters "
                                   "(rho, kn, ks, xb, fs0, mu) for a 2-D model")
        try:
            mic = macro_to_micro(mat.E, mat.nu, mat.Tu, mat.Cu, mat.mu_i, mat.rho, d)
        except ValueError as exc:
            key = str(exc).split(" ", 1)[0]
            where = ("materials", name, key) if key in type(mat).model_fields else \
                ("materials", name)
            raise BuildError(where, str(exc)) from None
        el = mic.element
        return dict(el, rho=mat.rho, mass=mic.mass)
    if not isinstance(mat, MicroMaterial):
        from geodem.materials import at_size
        from geodem.workflow.material import specimen_material

        try:
            sm = specimen_material(cfg, name, dim)
        except ValueError as exc:
            raise BuildError(("materials", name), str(exc)) from None
        if sm.element is None:
            raise BuildError(path, f"material {name!r} has no calibrated {dim}-D element "
                                   "parameters; a lattice model needs element parameters "
                                   "(or rock properties in 3-D)")
        if sm.element.get("bond_strength_weibull") is not None:
            # the lattice and granular builders bond without per-bond factors: taking the
            # material would silently drop its strength scatter
            raise BuildError(("materials", name), f"material {name!r} has "
                             f"bond_strength_weibull = {sm.element['bond_strength_weibull']:g}, "
                             "which this model's builder does not apply; allowed: a material "
                             "without it here, or a specimen-type model (specimen, "
                             "triaxial_box, brazilian_disc, hydrofrac_plate)")
        return dict(at_size(sm.element, d), rho=sm.rho, mass=None)
    xb = mat.xb if mat.xb is not None else 1.0e6 * d
    fs0 = mat.fs0 if mat.fs0 is not None else 1.0e12
    return dict(kn=mat.kn, ks=mat.ks, xb=xb, fs0=fs0, mu=mat.mu, rho=mat.rho, mass=None)


def concat_states(parts, shifts):
    """One state holding independent copies ``parts`` (same dim and row width), each moved by
    its ``shifts`` row; neighbour indices are offset, groups are taken from the first part."""
    base = parts[0]
    offs = np.cumsum([0] + [p.n for p in parts[:-1]])
    arrays = {}
    for name in base.array_names():
        arrays[name] = np.concatenate([getattr(p, name) for p in parts])
    nbr = [np.where(p.nbr >= 0, p.nbr + o, -1) for p, o in zip(parts, offs)]
    arrays["nbr"] = np.ascontiguousarray(np.concatenate(nbr).astype(np.int32))
    shift = np.concatenate([np.broadcast_to(np.asarray(s, float), p.x.shape)
                            for p, s in zip(parts, shifts)])
    arrays["x"] = arrays["x"] + shift
    arrays["x_ref"] = arrays["x_ref"] + shift
    return dataclasses.replace(base, **arrays, gravity=base.gravity.copy(),
                               groups=dict(base.groups))


# ============================================================================ lattice_block
SIDES = ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")


def group_problems(groups: dict, dim: int) -> list:
    """Problems of named groups with an optional ``side`` and ``box`` (lattice_block, scene):
    the reserved name 'all', a side the dimension lacks, a box of the wrong size."""
    out = []
    for name, g in groups.items():
        if name == "all":
            out.append((("groups", name), "'all' always means every element; choose "
                                           "another name"))
        for side in [g.side] if isinstance(g.side, str) else (g.side or []):
            if DOF_NAMES.index(side[0]) >= dim:
                out.append((("groups", name, "side"), f"side {side!r} does not exist in "
                                                      f"{dim}-D"))
        if g.box is not None:
            for key in ("min", "max"):
                if len(getattr(g.box, key)) != dim:
                    out.append((("groups", name, "box", key), f"{dim} coordinates needed"))
    return out


class Box(Strict):
    min: list[float] = F(..., unit="m", min_length=2, max_length=3, description="Lower corner")
    max: list[float] = F(..., unit="m", min_length=2, max_length=3, description="Upper corner")


class GroupSelect(Strict):
    """Elements of a group: a slab at one side of the block, or a box. An element belongs to one
    group; the last group that selects it wins."""

    side: Optional[Literal[SIDES]] = F(  # type: ignore[valid-type]
        None, description="Side of the block (xmin, xmax, ymin, ymax, zmin, zmax)")
    depth: float = F(0.5, gt=0, description="Slab depth from the side, in element diameters "
                                            "(0.5 = the outer layer)")
    box: Optional[Box] = F(None, description="Box selecting element centres [m]")

    @model_validator(mode="after")
    def _one(self):
        if (self.side is None) == (self.box is None):
            raise ValueError("give exactly one of side or box")
        return self


@register_model("lattice_block")
class LatticeBlock(ModelBase):
    """A bonded close-packed block: FCC (3-D, layers normal to z) or triangular (2-D) lattice of
    ``counts`` elements of one ``diameter``, every touching pair bonded, elements in Morton
    order."""

    size_field = "counts"
    example = {"type": "lattice_block", "dim": 2, "counts": [6, 6], "diameter": 0.01,
               "material": "rock", "groups": {"base": {"side": "ymin"}, "top": {"side": "ymax"}}}
    dim: Literal[2, 3] = F(3, description="Dimension")
    counts: list[Annotated[Int, Field(ge=1)]] = F(..., min_length=2, max_length=3,
                          description="Elements along x, rows along y (and layers along z in "
                                      "3-D); each >= 1")
    diameter: float = F(..., unit="m", gt=0, description="Element diameter (lattice spacing)")
    material: Name = F(..., description="Material name (a key of materials)")
    gravity: Optional[list[float]] = F(None, unit="m/s^2", min_length=2, max_length=3,
                                       description="Gravity vector (dim components)")
    groups: dict[Name, GroupSelect] = F({}, description="Named element groups")
    sort: bool = F(True, description="Reorder elements in Morton order (faster runs)")

    def n_elements(self):
        return int(np.prod([max(int(c), 0) for c in self.counts], dtype=np.float64))

    def bytes_per_element(self):
        # state at the default row width, plus the builder's temporaries (pairs, tree) and the
        # engine's copies (checkpoint writing, energy arrays)
        width = 16 if self.dim == 3 else 8
        return state_bytes_per_element(self.dim, width) + 1000

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        return ["all"] + list(self.groups)

    def n_across(self):
        return float(max(self.counts))

    def check(self, cfg):
        out = []
        if len(self.counts) != self.dim:
            out.append((("counts",), f"{len(self.counts)} counts for dim = {self.dim}; allowed: "
                                     f"{self.dim} whole numbers >= 1"))
        if self.gravity is not None and len(self.gravity) != self.dim:
            out.append((("gravity",), f"{len(self.gravity)} components for dim = {self.dim}"))
        return out + group_problems(self.groups, self.dim)

    def build(self, cfg):
        from geodem.build.lattice import bonded_state, fcc_lattice, triangular_lattice
        from geodem.core import groups as grp
        from geodem.core.neighbors import spatial_sort

        d = self.diameter
        p = element_params(cfg, self.material, d, self.dim)
        c = [int(v) for v in self.counts]
        x = fcc_lattice(*c, d) if self.dim == 3 else triangular_lattice(*c, d)
        st = bonded_state(x, 0.5 * d, density=p["rho"], kn=p["kn"], ks=p["ks"], xb=p["xb"],
                          fs0=p["fs0"], mu=p["mu"], gap=1e-6 * d)
        if p["mass"] is not None:
            st.m[:] = p["mass"]
        if self.gravity is not None:
            st.gravity[:self.dim] = self.gravity
        lo, hi = st.x.min(axis=0), st.x.max(axis=0)
        for name, g in self.groups.items():
            if g.side is not None:
                ax = DOF_NAMES.index(g.side[0])
                depth = g.depth * d
                if g.side.endswith("min"):
                    sel = st.x[:, ax] <= lo[ax] + depth - 1e-9 * d
                else:
                    sel = st.x[:, ax] >= hi[ax] - depth + 1e-9 * d
            else:
                bmin, bmax = np.asarray(g.box.min), np.asarray(g.box.max)
                sel = np.all((st.x >= bmin) & (st.x <= bmax), axis=1)
            if not sel.any():
                raise BuildError(("groups", name), f"group {name!r} selects no element (block "
                                                   f"from {lo.round(12).tolist()} to "
                                                   f"{hi.round(12).tolist()} m)")
            grp.add_group(st, name, sel)
        if self.sort:
            spatial_sort(st)
        return BuiltModel(st, st.x.copy(), self.n_across(), {"diameter": d})
