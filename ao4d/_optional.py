"""Optional packages: imported where a feature needs them, with an error that names the extra.

``import ao4d`` and the core (extraction, ambient occlusion, rendering, the demo) need only the
required dependencies. A feature that needs an extra imports it through :func:`require`, which
turns a missing package into::

    ModuleNotFoundError: reading NIfTI needs nibabel: pip install "ao4d[io]"
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["require", "EXTRAS"]

# top-level package -> the extra of ao4d that installs it
EXTRAS = {
    "nibabel": "io",
    "zarr": "io",
    "h5py": "io",
    "dask": "dask",
    "distributed": "dask",
    "pyvista": "vtk",
    "vtk": "vtk",
    "igl": "datasets",
    "threadpoolctl": "datasets",
}


def require(module: str, what: str, *, extra: str | None = None) -> ModuleType:
    """Import ``module`` for a feature, or say which extra of ao4d installs it.

    Parameters
    ----------
    module : str
        The module to import (``"dask.array"``); its top-level package is a key of :data:`EXTRAS`.
    what : str
        The feature that needs it, the start of the error's sentence (``"reading NIfTI"``).
    extra : str, optional
        The extra to name, where the feature's own extra holds ``module`` too (reading zarr
        needs dask, which ``ao4d[io]`` installs); default: ``EXTRAS`` of its package.

    Returns
    -------
    module
        The imported module.

    Raises
    ------
    ModuleNotFoundError
        ``module`` or a package it needs is not installed; the message names the extra.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        top = module.partition(".")[0]
        extra = extra or EXTRAS[top]
        missing = exc.name or top
        detail = "" if missing.partition(".")[0] == top else f" (it lacks {missing})"
        raise ModuleNotFoundError(f'{what} needs {top}{detail}: pip install "ao4d[{extra}]"', name=missing) from None
