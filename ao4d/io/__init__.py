"""Files in and out: grids of values read from data files, mesh files, 3D image volumes and
pictures.

==========================  ======================================================================
:mod:`~ao4d.io.grids`       :func:`read_grid`: one reader for 2D/3D/4D grids in files (the format
                            modules below, by suffix), lazily or as dask arrays
:mod:`~ao4d.io.sources`     what the formats share: arrays read lazily, slab by slab
:mod:`~ao4d.io.nifti`       NIfTI-1/2 (.nii, .nii.gz) through nibabel
:mod:`~ao4d.io.hdf5`        HDF5 datasets through h5py
:mod:`~ao4d.io.zarr_files`  zarr arrays
:mod:`~ao4d.io.metaimage`   MetaImage (.mhd/.mha) headers and data
:mod:`~ao4d.io.vti`         VTK ImageData (.vti) read without VTK
:mod:`~ao4d.io.frames`      a 4D grid from a sorted glob of 3D frame files
:mod:`~ao4d.io.mesh_files`  mesh files by suffix (.npz, .vtu, text) and 3D slice meshes
:mod:`~ao4d.io.volumes`     3D image files: MetaImage and VTK ImageData written and read
:mod:`~ao4d.io.pictures`    PNG pictures without a display
==========================  ======================================================================

The names below load on first use: importing this package imports neither numpy nor pyopencl.
"""

from __future__ import annotations

from .._lazy import lazy_face

__all__ = [
    "Grid",
    "read_grid",
]

__getattr__, __dir__ = lazy_face(
    __name__,
    {
        "Grid": "grids:Grid",
        "read_grid": "grids:read_grid",
    },
)
