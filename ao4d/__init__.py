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

__version__ = "0.1.0"

# public name -> "module:attribute" (module relative to this package)
_LAZY = {
    "lut": "lut:",
    "fields": "fields:",
    "cl": "cl:",
    "mesh": "mesh:",
    "meshio": "meshio:",
    "march": "march:",
    "bvh": "bvh:",
    "ao": "ao:",
    "render": "render:render",
    "io": "io:",
    "camera": "camera:",
    "lift": "lift:",
    "sampling": "sampling:",
    "scenes": "scenes:",
    "SimplexMesh": "mesh:SimplexMesh",
    "sample": "fields:sample",
    "extract": "march:extract",
    "extract_field": "march:extract_field",
    "ambient_occlusion": "ao:ambient_occlusion",
    "Camera4D": "camera:Camera4D",
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
