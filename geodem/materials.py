"""Macro (rock) properties <-> micro (bond) parameters on the close-packed lattice.

PHYSICS.md section 2 (Liu et al. 2017, MatDEM). For element diameter ``d`` [m]::

    Kn   = sqrt(2) E d / (4 (1 - 2 nu))
    Ks   = sqrt(2) (1 - 5 nu) E d / (4 (1 + nu)(1 - 2 nu))
    Xb   = (3 Kn + Ks) Tu d^2 / (6 sqrt(2) Kn (Kn + Ks))
    mu_p = (3 mu_i - sqrt(1 + mu_i^2)) / (2 sqrt(2) sqrt(1 + mu_i^2))
    Fs0  = (1 - sqrt(2) mu_p) Cu d^2 / 6
    m    = rho d^3 / sqrt(2)

Bond values ``Kn, Ks, Xb, Fs0, mu_p``; each element stores ``kn = 2 Kn, ks = 2 Ks, xb = Xb/2,
fs0 = Fs0, mu = mu_p`` (two half-springs in series make the bond).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

SQ2 = math.sqrt(2.0)
MU_I_MIN = 1.0 / math.sqrt(8.0)  # mu_p = 0 at sin(phi) = 1/3, i.e. mu_i = tan(phi) = 0.354


@dataclass(frozen=True)
class Micro:
    Kn: float
    Ks: float
    Xb: float
    Fs0: float
    mu_p: float
    mass: float
    d: float

    @property
    def element(self) -> dict:
        """Per-element parameters for :func:`geodem.core.state.new_state`."""
        return {"kn": 2 * self.Kn, "ks": 2 * self.Ks, "xb": self.Xb / 2, "fs0": self.Fs0,
                "mu": self.mu_p}


def _positive(name, v, unit):
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise ValueError(f"{name} = {v!r}: must be a finite number > 0 [{unit}]")


def macro_to_micro(E, nu, Tu, Cu, mu_i, rho, d) -> Micro:
    """Bond parameters from Young's modulus E [Pa], Poisson's ratio nu, tensile strength Tu [Pa],
    UCS Cu [Pa], internal friction mu_i = tan(phi), density rho [kg/m^3], diameter d [m]."""
    for name, v, unit in (("E", E, "Pa"), ("Tu", Tu, "Pa"), ("Cu", Cu, "Pa"),
                          ("rho", rho, "kg/m^3"), ("d", d, "m")):
        _positive(name, v, unit)
    if not (math.isfinite(nu) and -1.0 < nu <= 0.2):
        raise ValueError(f"nu = {nu!r}: the close-packed lattice reaches only -1 < nu <= 0.2 "
                         "(above 0.2 the shear stiffness Ks would be negative)")
    if not (math.isfinite(mu_i) and mu_i >= MU_I_MIN):
        raise ValueError(f"mu_i = {mu_i!r}: the lattice needs mu_i = tan(phi) >= {MU_I_MIN:.4f} "
                         "(phi >= 19.47 deg); below it the bond friction mu_p would be negative")
    kn = SQ2 * E * d / (4 * (1 - 2 * nu))
    ks = SQ2 * (1 - 5 * nu) * E * d / (4 * (1 + nu) * (1 - 2 * nu))
    xb = (3 * kn + ks) * Tu * d * d / (6 * SQ2 * kn * (kn + ks))
    s = math.sqrt(1 + mu_i * mu_i)
    mu_p = (3 * mu_i - s) / (2 * SQ2 * s)
    fs0 = (1 - SQ2 * mu_p) * Cu * d * d / 6
    return Micro(kn, ks, xb, fs0, mu_p, rho * d ** 3 / SQ2, d)


def micro_to_macro(Kn, Ks, Xb, Fs0, mu_p, d) -> dict:
    """Inverse of :func:`macro_to_micro`: returns ``E, nu, Tu, Cu, mu_i``."""
    E = 6 * SQ2 * Kn * (Kn + Ks) / (d * (5 * Kn + Ks))
    nu = (Kn - Ks) / (5 * Kn + Ks)
    Tu = 3 * E * Xb / (d * (2 - nu))
    sphi = (1 + 2 * SQ2 * mu_p) / 3
    mu_i = sphi / math.sqrt(1 - sphi * sphi)
    Cu = 6 * Fs0 / (d * d * (1 - SQ2 * mu_p))
    return {"E": E, "nu": nu, "Tu": Tu, "Cu": Cu, "mu_i": mu_i}


PER_SIZE_KEYS = ("kn_per_d", "ks_per_d", "xb_per_d", "fs0_per_d2", "mu")


def per_size(element: dict, d: float) -> dict:
    """Per-element parameters given for diameter ``d`` (``kn, ks, xb, fs0, mu``, e.g.
    ``Micro.element``) as size-free values: ``kn_per_d = kn / d``, ``ks_per_d = ks / d``,
    ``xb_per_d = xb / d``, ``fs0_per_d2 = fs0 / d^2``, ``mu`` (PHYSICS.md section 2, mixed
    sizes: ``kn, ks, xb ∝ d``, ``fs0 ∝ d^2``)."""
    out = {"kn_per_d": element["kn"] / d, "ks_per_d": element["ks"] / d,
           "xb_per_d": element["xb"] / d, "fs0_per_d2": element["fs0"] / d ** 2,
           "mu": element["mu"]}
    return _with_structure(out, element)


def at_size(scaled: dict, d: float) -> dict:
    """Inverse of :func:`per_size`: ``kn, ks, xb, fs0, mu`` of an element of diameter ``d``."""
    out = {"kn": scaled["kn_per_d"] * d, "ks": scaled["ks_per_d"] * d,
           "xb": scaled["xb_per_d"] * d, "fs0": scaled["fs0_per_d2"] * d ** 2,
           "mu": scaled["mu"]}
    return _with_structure(out, scaled)


#: size-free micro-structure parameters carried with the element parameters (the specimen
#: builder reads them, :func:`geodem.build.specimen.make_specimen`): ``packing`` (the recipe:
#: ``isotropic`` or ``deposit``), ``bond_gap`` (bond range: pairs whose surface gap is below
#: ``bond_gap x d_mean`` are bonded, then made to touch) and ``bond_strength_weibull`` (the
#: Weibull modulus of the per-bond strength factors,
#: :func:`geodem.build.specimen.bond_strength_factors`), and ``rotation`` with
#: ``rolling_friction``, ``bond_moment`` and ``rolling_stiffness`` (turning elements with
#: rolling resistance, moment-resisting bonds and the rolling spring's factor,
#: :func:`geodem.core.state.enable_rotation`, switched on for the whole model by the workflow
#: runner). A calibration stores them with the element
#: parameters, so every test builds the rock the same way.
STRUCTURE_KEYS = ("packing", "bond_gap", "bond_strength_weibull", "rotation",
                  "rolling_friction", "bond_moment", "rolling_stiffness")
ROTATION_KEYS = ("rotation", "rolling_friction", "bond_moment", "rolling_stiffness")


def _with_structure(out: dict, source: dict) -> dict:
    for k in STRUCTURE_KEYS:
        if source.get(k) is not None:
            out[k] = source[k]
    return out


# ============================================================================ elastic lattice
SQRT3 = math.sqrt(3.0)


def elastic_lattice(E, nu, rho, d, dim=2) -> dict:
    """Element parameters that make the close-packed lattice of spacing ``d`` the elastic
    medium ``E, nu, rho`` exactly, and its wave speeds (docs/scene.md, ``elements: elastic``).

    2-D: the triangular lattice of thickness ``t = d`` (VALIDATION.md; -1 < nu <= 1/3)::

        Kn = E t / (sqrt3 (1 - nu)),   Ks = Kn (1 - 3 nu) / (1 + nu),   m = rho (sqrt3/2) d^2 t
        M = E / (1 - nu^2),   G = E / (2 (1 + nu)),   K0 = nu

    3-D: the FCC lattice (:func:`macro_to_micro` stiffnesses, ``m = rho d^3 / sqrt2``;
    -1 < nu <= 0.2), ``M = E (1 - nu) / ((1 + nu)(1 - 2 nu))``, ``K0 = nu / (1 - nu)``.

    Element values ``kn = 2 Kn``, ``ks = 2 Ks``; ``c_p = sqrt(M / rho)``, ``c_s = sqrt(G /
    rho)``; ``K0`` is the lateral stress ratio of a plane P wave (uniaxial strain);
    ``pitch``: the lattice's row spacing along each axis (``d``, ``d sqrt3/2``, ``d
    sqrt(2/3)``); ``thickness``: 2-D only (None in 3-D); ``element``: the element parameters
    (these stiffnesses and the cell's mass; bonds that never break: ``xb = 10^6 d``, ``fs0 =
    10^30``, ``mu = 0.5``)."""
    if dim == 2:
        if not -1.0 < nu <= 1.0 / 3.0:
            raise ValueError(f"nu = {nu:g}: the triangular lattice reaches -1 < nu <= 1/3")
        t = d
        Kn = E * t / (SQRT3 * (1.0 - nu))
        Ks = Kn * (1.0 - 3.0 * nu) / (1.0 + nu)
        m = rho * 0.5 * SQRT3 * d * d * t
        M = E / (1.0 - nu * nu)
        k0 = nu
        pitch = [d, 0.5 * SQRT3 * d]
    else:
        if not -1.0 < nu <= 0.2:
            raise ValueError(f"nu = {nu:g}: the close-packed (FCC) lattice reaches -1 < nu "
                             f"<= 0.2")
        t = None
        Kn = SQ2 * E * d / (4 * (1 - 2 * nu))
        Ks = SQ2 * (1 - 5 * nu) * E * d / (4 * (1 + nu) * (1 - 2 * nu))
        m = rho * d ** 3 / SQ2
        M = E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))
        k0 = nu / (1.0 - nu)
        pitch = [d, 0.5 * SQRT3 * d, math.sqrt(2.0 / 3.0) * d]
    G = E / (2.0 * (1.0 + nu))
    return {"E": E, "nu": nu, "rho": rho, "d": d, "dim": dim, "thickness": t, "Kn": Kn,
            "Ks": Ks, "kn": 2.0 * Kn, "ks": 2.0 * Ks, "mass": m, "M": M, "G": G, "k0": k0,
            "cp": math.sqrt(M / rho), "cs": math.sqrt(G / rho), "pitch": pitch,
            "element": {"kn": 2.0 * Kn, "ks": 2.0 * Ks, "xb": 1.0e6 * d, "fs0": 1.0e30,
                        "mu": 0.5, "rho": rho, "mass": m}}


def lattice_E_nu(Kn: float, Ks: float, t: float) -> tuple[float, float]:
    """``(E, nu)`` of the 2-D triangular lattice from its bond stiffnesses (VALIDATION.md)."""
    return (2.0 * SQRT3 * Kn * (Kn + Ks) / (t * (3.0 * Kn + Ks)),
            (Kn - Ks) / (3.0 * Kn + Ks))
