"""Model builders: regular lattices, contact detection, bonded specimens."""
from geodem.build.lattice import (
    bonded_state,
    chain,
    contact_pairs,
    fcc_lattice,
    lattice_shape,
    random_specimen,
    triangular_lattice,
)

__all__ = [
    "bonded_state",
    "chain",
    "contact_pairs",
    "fcc_lattice",
    "lattice_shape",
    "random_specimen",
    "triangular_lattice",
]
