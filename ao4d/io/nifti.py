"""NIfTI-1/2 grids (.nii, .nii.gz) through nibabel: the data read lazily, the grid from the
header's affine and units (spacing in the file's units; a time axis in seconds).
"""

from __future__ import annotations

import math
import os
import warnings
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._optional import require
from .._validate import check_memory
from .sources import ObliqueAffineWarning, _ArraySource

__all__ = []


@dataclass(frozen=True)
class _NiftiSource(_ArraySource):
    """A NIfTI image read (with its scaling) through nibabel's array proxy."""

    path: str
    shape: tuple[int, ...]
    dtype_str: str

    def __getitem__(self, index: Any) -> np.ndarray:
        import nibabel as nib

        try:
            values = np.asarray(nib.load(self.path).dataobj[index], dtype=self.dtype)
        except (OSError, EOFError, ValueError, zlib.error) as exc:
            raise ValueError(f"{self.path!r}: cannot read its data ({exc}); truncated?") from None
        # a 3D image stored with a time axis of one: drop it (see _nifti_open)
        return values.reshape(values.shape[: len(self.shape)]) if values.ndim > len(self.shape) else values


def _nifti_open(path: str) -> tuple[Any, tuple[int, ...], np.dtype, bool]:
    """(image, shape, value dtype, scaled) from the header alone."""
    nib = require("nibabel", "reading NIfTI")

    try:
        img = nib.load(path, mmap=True)
    except Exception as exc:  # nibabel raises ImageFileError, EOFError, OSError, ValueError...
        raise ValueError(f"{path!r} is not a readable NIfTI file: {exc}") from None
    shape = tuple(int(n) for n in img.shape)
    while len(shape) > 3 and shape[-1] == 1:  # a 3D image stored with a time axis of one
        shape = shape[:-1]
    if len(shape) not in (2, 3, 4):
        raise ValueError(f"{path!r} holds a {len(shape)}D image of shape {shape}; a 2D, 3D or 4D grid is needed")
    proxy = img.dataobj
    slope, inter = getattr(proxy, "slope", 1.0), getattr(proxy, "inter", 0.0)
    scaled = not (slope is None or math.isnan(slope) or slope == 1.0) or not (
        inter is None or math.isnan(inter) or inter == 0.0
    )
    dtype = np.dtype(np.float64) if scaled else np.dtype(img.header.get_data_dtype())
    return img, shape, dtype, scaled


def _read_nifti(
    path: str, *, warn: bool = True, lazy: bool = True, scale: dict | None = None
) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    img, shape, dtype, scaled = _nifti_open(path)
    stored = np.dtype(img.header.get_data_dtype())
    if not path.lower().endswith(".gz"):
        need = int(img.dataobj.offset) + math.prod(img.shape) * stored.itemsize
        have = os.path.getsize(path)
        if have < need:
            raise ValueError(f"{path!r} is truncated: its header needs {need} bytes, the file has {have}")
        if not scaled:
            values = img.dataobj.get_unscaled().reshape(shape, order="F")  # memory map
        elif lazy:
            da = require("dask.array", "reading a scaled NIfTI lazily", extra="io")
            values = da.from_array(_NiftiSource(path, shape, dtype.str), chunks="auto", asarray=True, fancy=False)
        else:
            values = _NiftiSource(path, shape, dtype.str)[...]
    else:  # gzip cannot be sliced cheaply: decompress once
        check_memory(
            math.prod(shape) * dtype.itemsize,
            f"decompressing {path!r}",
            hint="gunzip it to .nii, which is memory-mapped",
        )
        values = _NiftiSource(path, shape, dtype.str)[...]
    scale = {} if scale is None else scale
    step, start, flips, notes = _nifti_grid(img, shape, path, warn and not scale.get("affine"), scale)
    if scale.get("affine"):
        flips = [False] * len(shape)  # the affine keeps the file's axes as they are
    if any(flips):
        values = values[tuple(slice(None, None, -1) if f else slice(None) for f in flips)]
    return values, step, start, notes


# NIfTI xyzt_units names (nibabel) -> short unit names; time units scale a w axis
_NIFTI_UNITS = {
    "mm": "mm",
    "micron": "um",
    "meter": "m",
    "sec": "s",
    "msec": "ms",
    "usec": "us",
    "hz": "Hz",
    "ppm": "ppm",
    "rads": "rad/s",
    "unknown": "unknown",
}


_TIME_UNITS = ("s", "ms", "us")


def _nifti_grid(
    img: Any, shape: tuple[int, ...], path: str, warn: bool, scale: dict | None = None
) -> tuple[np.ndarray, np.ndarray, list[bool], list[str]]:
    """(spacing, origin, flipped axes, notes) of a NIfTI image. ``scale`` (optional) passes
    ``w_scale``, ``w_step`` and ``affine`` in, and gets ``units``, ``w_scaled`` (the length per
    time unit used) and ``affine_matrix`` (index to coordinates, (d+1, d+1)) back."""
    scale = {} if scale is None else scale
    d = len(shape)
    k = min(d, 3)
    affine = np.asarray(img.affine, dtype=np.float64)
    rot = affine[:k, :k]
    zooms = np.array(img.header.get_zooms()[:d], dtype=np.float64)
    step, start = np.ones(d), np.zeros(d)
    flips = [False] * d
    notes = []
    off_diagonal = np.abs(rot - np.diag(np.diag(rot))).max()
    if off_diagonal <= 1e-6 * np.abs(rot).max() and (np.diag(rot) != 0).all():
        diag = np.diag(rot)
        for axis in range(k):
            step[axis] = abs(diag[axis])
            start[axis] = affine[axis, 3]
            if diag[axis] < 0:  # flip: the array then runs along +axis in scanner space
                flips[axis] = True
                start[axis] = affine[axis, 3] + diag[axis] * (shape[axis] - 1)
        flipped = [a for a in range(k) if flips[a]]
        notes.append(
            "spacing and origin from the axis-aligned affine"
            + (f" (axes {flipped} flipped to run along +x, +y, +z)" if flipped else "")
        )
    else:
        step[:k] = np.where(zooms[:k] > 0, zooms[:k], 1.0)
        start[:k] = affine[:k, 3]
        notes.append("oblique affine: voxel axes with the header's zooms")
        if warn:
            warnings.warn(
                f"{path!r}: the affine is oblique (not axis-aligned):\n{affine[:3, :3]}\n"
                "using the voxel axes with the header's zooms as spacing and the "
                "affine's translation as origin; the mesh is not in scanner coordinates (read "
                "it with keep_affine=True, command line --affine, to place it there)",
                ObliqueAffineWarning,
                stacklevel=5,
            )
    try:
        space_unit, time_unit = (_NIFTI_UNITS.get(u, "unknown") for u in img.header.get_xyzt_units())
    except (AttributeError, KeyError, ValueError):
        space_unit, time_unit = "unknown", "unknown"
    scale["units"] = (space_unit,) * k + ((time_unit,) if d == 4 else ())
    if d == 4:
        pixdim = float(zooms[3]) if zooms[3] > 0 else 1.0
        toffset = float(img.header.get("toffset", 0.0) or 0.0)
        if time_unit in _TIME_UNITS or time_unit in ("Hz", "ppm", "rad/s"):
            w_scale = scale.get("w_scale")
            length = space_unit if space_unit != "unknown" else "length units"
            if scale.get("w_step") is not None:
                per = scale["w_step"] / pixdim
                how = f"scaled by the w step given: {per:.6g} {length} per {time_unit}"
            elif w_scale is not None:
                per = w_scale
                how = f"scaled by w_scale: {per:.6g} {length} per {time_unit}"
            else:
                per = float(np.mean(step[:3])) / pixdim
                how = (
                    f"not taken as a length: one frame is one mean x/y/z step, "
                    f"{per * pixdim:.6g} {length} (w_scale= or --w-scale sets {length} per "
                    f"{time_unit})"
                )
            scale["w_scaled"] = per
            step[3], start[3] = pixdim * per, toffset * per
            notes.append(f"w is time: pixdim[4] = {pixdim:g} {time_unit}, toffset {toffset:g}; {how}")
        else:
            step[3], start[3] = pixdim, toffset
            notes.append(
                "w spacing from pixdim[4], origin from toffset" + (f" ({time_unit})" if time_unit != "unknown" else "")
            )
    matrix = np.eye(d + 1)
    matrix[:k, :k] = rot
    matrix[:k, d] = affine[:k, 3]
    if d == 4:
        matrix[3, 3], matrix[3, 4] = step[3], start[3]
    scale["affine_matrix"] = matrix
    if scale.get("affine"):
        notes.append("vertices placed by the file's affine (scanner coordinates)")
    return step, start, flips, notes
