"""Ray casting on simplex meshes in 2D, 3D and 4D: every traversal of a mesh's tree.

=============================  ===================================================================
:mod:`~ao4d.rays.api`          the public traversals: :func:`cast_rays`, :func:`trace`,
                               :func:`count_occluded`, :func:`traversal_counts`, :class:`RayHits`
:mod:`~ao4d.rays.rows`         rays as every traversal takes them: checks, the mapping into a
                               tree's frame, the answers' arrays, :class:`Tracer`, the bar
:mod:`~ao4d.rays.launches`     the OpenCL kernels' builds and launches, packets, AO on the device
:mod:`~ao4d.rays.reference`    the numpy reference traversals (float64, binary tree)
:mod:`~ao4d.rays.refine`       hits' ``t`` and barycentrics refined in float64
=============================  ===================================================================

Data flow one way: rows <- launches, reference, refine <- api. The names below load on first
use: importing this package imports neither numpy nor pyopencl.
"""

from __future__ import annotations

from .._lazy import lazy_face

__all__ = [
    "ACCELS",
    "RAYS_PER_LAUNCH",
    "RayHits",
    "Tracer",
    "cast_rays",
    "count_occluded",
    "device_ray_mapping",
    "mesh_arrays",
    "progress_bar",
    "release_buffers",
    "sample_directions",
    "trace",
    "traversal_counts",
    "unit_rows",
]

__getattr__, __dir__ = lazy_face(
    __name__,
    {
        "ACCELS": "api:ACCELS",
        "RAYS_PER_LAUNCH": "launches:RAYS_PER_LAUNCH",
        "RayHits": "api:RayHits",
        "Tracer": "rows:Tracer",
        "cast_rays": "api:cast_rays",
        "count_occluded": "api:count_occluded",
        "device_ray_mapping": "launches:device_ray_mapping",
        "mesh_arrays": "rows:mesh_arrays",
        "progress_bar": "rows:progress_bar",
        "release_buffers": "launches:release_buffers",
        "sample_directions": "launches:sample_directions",
        "trace": "api:trace",
        "traversal_counts": "api:traversal_counts",
        "unit_rows": "rows:unit_rows",
    },
)
