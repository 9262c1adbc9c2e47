"""ao4d: true 4D surfaces, 4D ambient occlusion in OpenCL, and renders into 3D image volumes.

The package's names (``__all__``) are its functions and classes; the stages' modules and
subpackages are reachable as attributes (``ao4d.fields``, ``ao4d.marching``, ...). Everything
loads lazily on first use, so that ``import ao4d`` is cheap and never touches OpenCL.

Modules that moved into a subpackage keep their old import paths (``ao4d.cl``, ``from ao4d.cl
import ...``): ``_MOVED`` maps them, and the old name is the same module object as the new one.

Example
-------
>>> import ao4d
>>> mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (24,) * 4, (-1.3, 1.3))
>>> mesh.check().closed
True
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
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
    "read_grid": "readers:read_grid",
    "SimplexMesh": "mesh:SimplexMesh",
    "ambient_occlusion": "ao:ambient_occlusion",
    "cast_rays": "raycast:cast_rays",
    "Camera4D": "camera:Camera4D",
    "Light": "lighting:Light",
    "render": "rendering:render",
    "RenderResult": "rendering:RenderResult",
    "view": "browser.pages:view",
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
    "mesh_files",
    "readers",
    "bvh",
    "raycast",
    "sampling",
    "ao",
    "camera",
    "lighting",
    "rendering",
    "screen_ao",
    "compositing",
    "volumes",
    "pictures",
    "lift",
    "scenes",
)

# modules that moved into a subpackage: old name -> new name (relative to this package). The
# old paths are permanent, silent aliases (no DeprecationWarning: docs/ARCHITECTURE.md says why)
_MOVED = {
    "lut": "marching.lut",
    "cells": "marching.cells",
    "cells_device": "marching.cells_device",
    "fields_device": "marching.fields_device",
    "march": "marching.march",
    "blockwise": "marching.blockwise",
    "cl": "opencl.cl",
    "_kernel_binaries": "opencl.binaries",
    "_tbb": "opencl.tbb",
    "pages": "browser.pages",
    "viewer": "browser.viewer",
    "image_viewer": "browser.image_viewer",
    "_page": "browser._page",
}

__all__ = sorted(_EXPORTS)


class _MovedModule(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """``import ao4d.<old>`` for a moved module: the module at its new path, also registered in
    ``sys.modules`` under the old name (the same object, so state and monkeypatches are shared)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        package, _, old = fullname.partition(".")
        if package != __name__ or old not in _MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: Any) -> Any:
        module = importlib.import_module(f"{__name__}.{_MOVED[spec.name.partition('.')[2]]}")
        spec.loader_state = module.__spec__  # the import system sets the alias' spec on the module
        return module

    def exec_module(self, module: Any) -> None:
        module.__spec__ = module.__spec__.loader_state  # its own spec again: the new name


if not any(type(finder).__qualname__ == "_MovedModule" for finder in sys.meta_path):  # once, reloads too
    sys.meta_path.append(_MovedModule())


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        module_name, _, attr = _EXPORTS[name].partition(":")
        value = getattr(importlib.import_module(f".{module_name}", __name__), attr)
    elif name in _MODULES or name in _MOVED:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'ao4d' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return [*__all__, "__version__"]
