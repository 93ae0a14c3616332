"""Studies that drive workflows: calibration of element parameters to lab properties, the
reachable region of a packing, friction, freezing, speed against accuracy and stability limits.
The measurements they use (E, nu, UCS, Brazilian, Mohr-Coulomb) are in :mod:`geodem.measure`."""
