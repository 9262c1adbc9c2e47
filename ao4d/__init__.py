"""ao4d: true 4D surfaces, 4D ambient occlusion in OpenCL, and renders into 3D image volumes.

Submodules are loaded lazily so that ``import ao4d`` is cheap and never touches OpenCL.

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

from ._tbb import preload_runtime_tbb as _preload_runtime_tbb

# before any other library can load an older libtbb.so.12 (Open3D): see ao4d/_tbb.py
_preload_runtime_tbb()

__version__ = "0.1.0"

# public name -> "module:attribute" (module relative to this package)
_LAZY = {
    "lut": "lut:",
    "fields": "fields:",
    "cl": "cl:",
    "geometry": "geometry:",
    "topology": "topology:",
    "slicing": "slicing:",
    "mesh": "mesh:",
    "mesh_files": "mesh_files:",
    "march": "march:",
    "blockwise": "blockwise:",
    "readers": "readers:",
    "bvh": "bvh:",
    "raycast": "raycast:",
    "sampling": "sampling:",
    "ao": "ao:",
    "camera": "camera:",
    "lighting": "lighting:",
    "rendering": "rendering:",
    "screen_ao": "screen_ao:",
    "volumes": "volumes:",
    "pictures": "pictures:",
    "lift": "lift:",
    "scenes": "scenes:",
    "SimplexMesh": "mesh:SimplexMesh",
    "sample": "fields:sample",
    "extract": "march:extract",
    "extract_field": "march:extract_field",
    "read_grid": "readers:read_grid",
    "ambient_occlusion": "ao:ambient_occlusion",
    "cast_rays": "raycast:cast_rays",
    "render": "rendering:render",
    "RenderResult": "rendering:RenderResult",
    "Camera4D": "camera:Camera4D",
    "Light": "lighting:Light",
    "viewer": "viewer:",
    "image_viewer": "image_viewer:",
    "pages": "pages:",
    "view": "pages:view",
}

__all__ = sorted(_LAZY) + ["__version__"]


def __getattr__(name: str) -> Any:
    try:
        target = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'ao4d' has no attribute {name!r}") from None
    module_name, _, attr = target.partition(":")
    module = importlib.import_module(f".{module_name}", __name__)
    value = getattr(module, attr) if attr else module
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
