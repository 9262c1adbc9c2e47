"""ao4d: true 4D surfaces, 4D ambient occlusion in OpenCL, and renders into 3D image volumes.

The package's names (``__all__``) are its functions and classes; the stages' modules and
subpackages are reachable as attributes (``ao4d.fields``, ``ao4d.marching``, ...). Everything
loads lazily on first use, so that ``import ao4d`` is cheap and never touches OpenCL.

Modules live at one path each: ``ao4d.marching.lut``, ``ao4d.opencl.cl``, ``ao4d.browser.viewer``
(the package has no released users, so modules that moved keep no aliases at their old paths).

Example
-------
>>> import ao4d
>>> mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (24,) * 4, (-1.3, 1.3))
>>> mesh.check().closed
True
"""

from __future__ import annotations

import importlib
from typing import Any

from .opencl.tbb import preload_runtime_tbb as _preload_runtime_tbb

# before any other library can load an older libtbb.so.12 (Open3D): see ao4d/opencl/tbb.py
_preload_runtime_tbb()

__version__ = "0.1.0"

# the functions and classes: ``__all__``, ``from ao4d import *`` and ``dir(ao4d)``
# (public name -> "module:attribute", the module relative to this package)
_EXPORTS = {
    "sample": "fields:sample",
    "extract": "marching.march:extract",
    "extract_field": "marching.march:extract_field",
    "extract_solid": "marching.solid:extract_solid",
    "extract_solid_field": "marching.solid:extract_solid_field",
    "SolidMesh": "solid_mesh:SolidMesh",
    "load": "solid_mesh:load",
    "read_grid": "io.grids:read_grid",
    "SimplexMesh": "mesh:SimplexMesh",
    "ambient_occlusion": "ao:ambient_occlusion",
    "cast_rays": "rays.api:cast_rays",
    "Camera4D": "rendering.camera:Camera4D",
    "Light": "rendering.lighting:Light",
    "render": "rendering.pipeline:render",
    "RenderResult": "rendering.pipeline:RenderResult",
    "view": "browser.pages:view",
    "worker_environment": "_dask:worker_environment",
    "WorkerEnvironmentWarning": "_dask:WorkerEnvironmentWarning",
}

# the stages' modules: reachable as ``ao4d.<name>`` (loaded on first use), kept out of
# ``__all__`` and ``dir`` so that ``ao`` stands apart from ``ambient_occlusion``, ``sampling``
# from ``sample``
_MODULES = (
    "marching",
    "browser",
    "opencl",
    "fields",
    "geometry",
    "topology",
    "slicing",
    "mesh",
    "solid_mesh",
    "io",
    "bvh",
    "rays",
    "sampling",
    "ao",
    "rendering",
    "lift",
    "scenes",
    "data",
)

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        module_name, _, attr = _EXPORTS[name].partition(":")
        value = getattr(importlib.import_module(f".{module_name}", __name__), attr)
    elif name in _MODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'ao4d' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return [*__all__, "__version__"]
