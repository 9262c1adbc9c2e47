"""Marching: 2D-4D scalar grids to simplex meshes (isolines, isosurfaces, 4D hypersurfaces).

:mod:`ao4d.marching.lut` generates, ships and verifies the marching tables;
:mod:`ao4d.marching.cells` is the numpy engine (the reference) and
:mod:`ao4d.marching.cells_device` the same engine on the OpenCL device;
:mod:`ao4d.marching.fields_device` samples the shape library's fields on the device;
:mod:`ao4d.marching.march` holds the public API (:func:`extract`, :func:`extract_field`) and
:mod:`ao4d.marching.blockwise` extracts dask arrays block by block;
:mod:`ao4d.marching.solid` cuts the solid inside a level set into simplices. The names below load on
first use: importing this package imports neither numpy nor pyopencl.
"""

from __future__ import annotations

from .._lazy import lazy_face

__all__ = ["build_table", "extract", "extract_field", "extract_solid", "extract_solid_field"]

__getattr__, __dir__ = lazy_face(
    __name__,
    {
        "build_table": "lut:build",
        "extract": "march:extract",
        "extract_field": "march:extract_field",
        "extract_solid": "solid:extract_solid",
        "extract_solid_field": "solid:extract_solid_field",
    },
)
