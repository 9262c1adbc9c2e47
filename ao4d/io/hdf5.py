"""HDF5 datasets through h5py (``file.h5:dataset``): read lazily, the grid from the dataset's
attributes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._optional import require
from .._validate import regular_file
from .sources import _ArraySource, _attrs_grid, _auto_multiple, _missing

__all__ = []


_H5_SUFFIXES = (".h5", ".hdf5", ".hdf", ".he5")


@dataclass(frozen=True)
class _H5Source(_ArraySource):
    """An HDF5 dataset, opened by name (h5py objects do not pickle)."""

    path: str
    dataset: str
    shape: tuple[int, ...]
    dtype_str: str

    def __getitem__(self, index: Any) -> np.ndarray:
        import h5py

        try:
            with h5py.File(self.path, "r") as fh:
                return np.asarray(fh[self.dataset][index])
        except OSError as exc:
            raise ValueError(f"{self.path!r}:{self.dataset}: cannot read its data ({exc}); truncated?") from None


def _read_hdf5(file: str, dataset: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    h5py = require("h5py", "reading HDF5")
    da = require("dask.array", "reading HDF5", extra="io")

    if not Path(file).exists():
        raise _missing(file, "HDF5 file")
    regular_file(file, "path", what="HDF5 file")
    try:
        fh = h5py.File(file, "r")
    except OSError as exc:
        raise ValueError(f"{file!r} is not a readable HDF5 file (truncated?): {exc}") from None
    with fh:
        names: list[str] = []
        fh.visititems(lambda name, obj: names.append("/" + name) if isinstance(obj, h5py.Dataset) else None)
        if not dataset:
            if len(names) != 1:
                raise ValueError(
                    f"{file!r} holds {len(names)} datasets ({', '.join(names[:8])}); "
                    f"name one as {file}:/path/to/dataset"
                )
            dataset = names[0]
        if dataset not in fh or not isinstance(fh[dataset], h5py.Dataset):
            raise ValueError(f"{file!r} has no dataset {dataset!r}; datasets: {', '.join(names[:8]) or '(none)'}")
        dset = fh[dataset]
        shape, dtype = tuple(int(n) for n in dset.shape), dset.dtype
        if dtype.kind not in "fiub":
            raise ValueError(f"{file}:{dataset} holds {dtype}, not real numbers")
        step, start, notes = _attrs_grid(dset.attrs, len(shape), f"{file}:{dataset}")
        stored = dset.chunks
    source = _H5Source(file, dataset, shape, dtype.str)
    # whole storage chunks per block (dask "auto" rounds to multiples of them)
    chunks = "auto" if stored is None else _auto_multiple(shape, stored, dtype.itemsize)
    values = da.from_array(
        source, chunks=chunks, asarray=True, fancy=False, name=f"h5-{file}-{dataset}-{os.path.getmtime(file)}"
    )
    return values, step, start, notes
