"""VTK ImageData (.vti) grids read without VTK: the XML header and the (compressed) array."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._optional import require

__all__ = []


def _vti_info(path: str) -> tuple[tuple[int, ...], np.ndarray, np.ndarray]:
    """Shape, spacing and origin from a .vti header (the data are not read)."""
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    if not reader.CanReadFile(path):
        raise ValueError(f"{path!r} is not a readable VTK image (.vti) file")
    reader.SetFileName(path)
    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    extent = info.Get(vtkStreamingDemandDrivenPipeline.WHOLE_EXTENT())
    if extent is None:
        raise ValueError(f"{path!r} is not a readable VTK image (.vti) file")
    shape = tuple(int(extent[2 * k + 1] - extent[2 * k] + 1) for k in range(3))
    from vtkmodules.vtkCommonDataModel import vtkDataObject

    spacing = np.array(info.Get(vtkDataObject.SPACING()) or (1.0, 1.0, 1.0), dtype=np.float64)
    origin = np.array(info.Get(vtkDataObject.ORIGIN()) or (0.0, 0.0, 0.0), dtype=np.float64)
    origin = origin + spacing * np.array([extent[0], extent[2], extent[4]])
    return shape, spacing, origin


def _vti_values(path: str) -> np.ndarray:
    pv = require("pyvista", "reading .vti frames")

    try:
        grid = pv.read(path)
    except Exception as exc:  # VTK reports broken files in several ways
        raise ValueError(f"{path!r} is not a readable VTK image (.vti): {exc}") from None
    names = [n for n in grid.point_data.keys() if np.asarray(grid.point_data[n]).ndim == 1]
    if not names or grid.n_points == 0:
        raise ValueError(f"{path!r} has no scalar point data (or is truncated)")
    name = grid.point_data.active_scalars_name if grid.point_data.active_scalars_name in names else names[0]
    data = np.asarray(grid.point_data[name])
    if data.size != math.prod(grid.dimensions):
        raise ValueError(
            f"{path!r}: point data {name!r} has {data.size} values for dimensions {grid.dimensions} (truncated?)"
        )
    return data.reshape(grid.dimensions, order="F")


def _read_vti(path: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    shape, step, start = _vti_info(path)
    values = _vti_values(path)
    if values.shape != shape:
        raise ValueError(f"{path!r}: data of shape {values.shape}, header says {shape}")
    return values, step, start, ["spacing and origin from the .vti header"]
