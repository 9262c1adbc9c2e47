"""A 4D grid from a glob of 3D frame files (.vti, .mhd, .mha, .npy, .nii), in natural order,
the frames checked to share one grid.
"""

from __future__ import annotations

import glob as globmod
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .._optional import require
from .._validate import regular_file
from .metaimage import _read_metaimage
from .nifti import _nifti_grid, _nifti_open, _read_nifti
from .sources import ObliqueAffineWarning, _open_npy, _suffix
from .vti import _vti_info, _vti_values

__all__ = ["FRAME_SUFFIXES", "natural_key"]


FRAME_SUFFIXES = (".vti", ".mhd", ".mha", ".npy", ".nii", ".nii.gz")


def natural_key(text: str) -> list:
    """Sort key that orders digit runs by value: ``f2`` before ``f10``.

    Parameters
    ----------
    text : str
        A file name.

    Returns
    -------
    list of str and int
        The key: text in lower case, digit runs as numbers.
    """
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", text)]


def _read_frame(path: str, kind: str, shape: tuple[int, ...], dtype: str) -> np.ndarray:
    """One 3D frame as a C-ordered array (runs inside a dask task)."""
    if kind == ".vti":
        values = _vti_values(path)
    elif kind in (".mhd", ".mha"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ObliqueAffineWarning)
            values = np.asarray(_read_metaimage(path)[0])
    elif kind == ".npy":
        values = np.asarray(_open_npy(path))
    else:
        values = np.asarray(_read_nifti(path, warn=False, lazy=False)[0])
    if values.shape != shape:
        raise ValueError(f"frame {path!r} has shape {values.shape}, expected {shape} (it changed?)")
    return np.ascontiguousarray(values, dtype=np.dtype(dtype))


def _frame_header(path: str, kind: str, warn: bool = False) -> tuple[tuple[int, ...], np.dtype, np.ndarray, np.ndarray]:
    """Shape, dtype, spacing and origin of one frame, reading as little as the format allows."""
    regular_file(path, "path", what="frame")  # a glob may match a folder or a FIFO
    if kind == ".vti":
        shape, step, start = _vti_info(path)
        return shape, np.dtype(np.float64), step, start  # dtype: from the first frame's data
    if kind in (".mhd", ".mha"):
        with warnings.catch_warnings():
            if not warn:  # said once, for the first frame
                warnings.simplefilter("ignore", ObliqueAffineWarning)
            values, step, start, _ = _read_metaimage(path, data=False)
    elif kind == ".npy":
        values = _open_npy(path)
        step, start = np.ones(values.ndim), np.zeros(values.ndim)
    else:
        img, shape, dtype, _ = _nifti_open(path)
        step, start, _, _ = _nifti_grid(img, shape, path, warn)
        return shape, dtype, step, start
    return tuple(int(n) for n in values.shape), np.dtype(values.dtype), step, start


def _read_frames(pattern: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    da = require("dask.array", "reading a glob of frames", extra="io")
    import dask

    paths = sorted(globmod.glob(pattern), key=natural_key)
    if not paths:
        raise FileNotFoundError(f"no files match {pattern!r}")
    kinds = {_suffix(p) for p in paths}
    if len(kinds) > 1:
        raise ValueError(f"{pattern!r} matches frames of different kinds: {sorted(kinds)}")
    kind = kinds.pop()
    if kind not in FRAME_SUFFIXES:
        raise ValueError(f"{pattern!r} matches {kind!r} files; frames must be one of {', '.join(FRAME_SUFFIXES)}")
    if len(paths) < 2:
        raise ValueError(f"{pattern!r} matches one frame ({paths[0]!r}); a series needs >= 2")
    shape, dtype, step, start = _frame_header(paths[0], kind, warn=True)
    if len(shape) != 3:
        raise ValueError(f"frame {paths[0]!r} is {len(shape)}D (shape {shape}); frames must be 3D")
    if kind == ".vti":
        dtype = _vti_values(paths[0]).dtype
    for path in paths[1:]:
        other = _frame_header(path, kind)[0]
        if other != shape:
            raise ValueError(f"frames of different shapes: {paths[0]!r} is {shape}, {path!r} is {other}")
    read = dask.delayed(_read_frame, pure=True)
    frames = [da.from_delayed(read(p, kind, shape, dtype.str), shape, dtype=dtype) for p in paths]
    values = da.stack(frames, axis=-1)
    notes = [
        f"{len(paths)} frames {Path(paths[0]).name} .. {Path(paths[-1]).name} stacked along w",
        "x, y, z spacing and origin from the first frame; w: 1, 0",
    ]
    return values, np.append(step, 1.0), np.append(start, 0.0), notes
