"""Lab tests (uniaxial, triaxial, Brazilian): measurement of E, nu, UCS, tensile strength and the
Mohr-Coulomb envelope from recorded curves. Compression positive (see :mod:`.measure`)."""
from geodem.labtests.measure import (
                                     MohrCoulombFit,
                                     brazilian_tensile_strength,
                                     crack_start_offset,
                                     mohr_coulomb_fit,
                                     peak,
                                     poisson_ratio,
                                     youngs_modulus,
)

__all__ = ["MohrCoulombFit", "brazilian_tensile_strength", "crack_start_offset",
           "mohr_coulomb_fit", "peak", "poisson_ratio", "youngs_modulus"]
