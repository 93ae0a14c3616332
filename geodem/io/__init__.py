"""Output writers: H5MD-like HDF5 (:mod:`geodem.io.h5`), ParaView files (:mod:`geodem.io.vtk`)."""
