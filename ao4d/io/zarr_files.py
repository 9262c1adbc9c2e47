"""Zarr arrays (``store.zarr`` or ``store.zarr:array``), the grid from the array's attributes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .._optional import require
from .sources import _attrs_grid, _missing

__all__ = []


def _read_zarr(store: str, inner: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    zarr = require("zarr", "reading zarr")
    da = require("dask.array", "reading zarr", extra="io")

    if not Path(store).exists():
        raise _missing(store, "zarr store")
    try:
        node = zarr.open(store, mode="r")
        if inner:
            node = node[inner.strip("/")]
    except KeyError:
        raise ValueError(f"{store!r} has no array {inner!r}") from None
    except Exception as exc:  # zarr raises various errors for broken stores
        raise ValueError(f"{store!r} is not a readable zarr store: {exc}") from None
    if not hasattr(node, "shape") or not hasattr(node, "dtype"):
        arrays = sorted(name for name, _ in node.arrays()) if hasattr(node, "arrays") else []
        if len(arrays) == 1:
            node = node[arrays[0]]
        else:
            raise ValueError(
                f"{store}{':' + inner if inner else ''} is a group with arrays "
                f"{arrays or '(none)'}; name one as {store}:/array"
            )
    if np.dtype(node.dtype).kind not in "fiub":
        raise ValueError(f"{store!r} holds {node.dtype}, not real numbers")
    step, start, notes = _attrs_grid(node.attrs, len(node.shape), store)
    return da.from_zarr(node), step, start, notes
