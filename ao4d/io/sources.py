"""What the grid formats share: arrays read lazily, slab by slab (a memory-mapped view, or an
open NIfTI or HDF5 file), the warning for oblique grids, and the small helpers of the readers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._npz import npy_problem
from .._validate import as_vector, regular_file

__all__ = ["ObliqueAffineWarning"]


class ObliqueAffineWarning(UserWarning):
    """A NIfTI or MetaImage orientation is not axis-aligned: the voxel axes are used instead."""


def _suffix(name: str) -> str:
    lower = name.lower()
    return ".nii.gz" if lower.endswith(".nii.gz") else Path(lower).suffix


def _missing(path: str, what: str = "file") -> FileNotFoundError:
    return FileNotFoundError(f"{what} {path!r} does not exist")


def _view_source(values: np.memmap) -> _ViewSource:
    """The file-backed description of a memory map or of any view of one (reshaped, flipped):
    its first element's byte position in the file and its strides."""
    root = values
    while isinstance(root.base, np.memmap):
        root = root.base
    # a view's `offset` is its root's; the data pointers give the view's own start
    start = int(root.offset) + (values.__array_interface__["data"][0] - root.__array_interface__["data"][0])
    return _ViewSource(
        str(values.filename),
        tuple(int(n) for n in values.shape),
        values.dtype.str,
        start,
        tuple(int(s) for s in values.strides),
    )


class _ArraySource:
    """What dask reads of a lazy source besides ``__getitem__``: ``ndim`` and ``dtype``, from the
    subclass's ``shape`` and ``dtype_str`` fields."""

    shape: tuple[int, ...]
    dtype_str: str

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self.dtype_str)


@dataclass(frozen=True)
class _ViewSource(_ArraySource):
    """A strided view into a raw file (a memory map or a view of one: NIfTI reshaped to
    Fortran order, flipped axes), memory-mapped on first use in each process."""

    path: str
    shape: tuple[int, ...]
    dtype_str: str
    start: int  # byte position of element (0, ..., 0) in the file
    strides: tuple[int, ...]  # bytes, any sign

    def __getitem__(self, index: Any) -> np.ndarray:
        first = self.start + sum(s * (n - 1) for s, n in zip(self.strides, self.shape) if s < 0)
        last = self.start + sum(s * (n - 1) for s, n in zip(self.strides, self.shape) if s > 0)
        mm = np.memmap(self.path, dtype=np.uint8, mode="r", offset=first, shape=(last + self.dtype.itemsize - first,))
        view = np.ndarray(self.shape, self.dtype, buffer=mm, offset=self.start - first, strides=self.strides)
        return np.array(view[index])


def _open_npy(path: str) -> np.ndarray:
    regular_file(path, "path")  # frames of a glob too: a FIFO among them would block
    try:
        values = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        size = os.path.getsize(path)
        raise ValueError(f"{path!r} is not a valid .npy file ({size} bytes; {npy_problem(path, exc)})") from None
    if not isinstance(values, np.ndarray):
        raise ValueError(f"{path!r} holds no single array")
    return values


def _attrs_grid(attrs: Any, d: int, where: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Spacing/origin from ``spacing``/``origin`` attributes (zarr, HDF5), else 1 and 0."""
    notes = []
    step, start = np.ones(d), np.zeros(d)
    if "spacing" in attrs:
        step = as_vector(np.asarray(attrs["spacing"]), f"{where} attribute `spacing`", d, positive=True)
        notes.append("spacing from the `spacing` attribute")
    if "origin" in attrs:
        start = as_vector(np.asarray(attrs["origin"]), f"{where} attribute `origin`", d)
        notes.append("origin from the `origin` attribute")
    return step, start, notes


def _auto_multiple(shape: tuple[int, ...], stored: tuple[int, ...], itemsize: int) -> tuple:
    from dask.array.core import normalize_chunks

    return normalize_chunks("auto", shape, dtype=np.dtype(f"V{itemsize}"), previous_chunks=stored)
