"""Page-aligned numpy arrays: what a CPU OpenCL device reads and writes in place.

A buffer made with ``CL_MEM_USE_HOST_PTR`` over an array aligned so is used without a copy
(Intel's CPU runtime: from 128 bytes, measured; numpy's own large arrays start 16 bytes past a
page, and each such buffer costs a copy of the whole array).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: the alignment :func:`aligned_empty` gives (a page)
PAGE = 4096
#: the alignment from which a CPU device reads an array in place (Intel's runtime, measured)
HOST_PTR_ALIGN = 128


def aligned_empty(shape: int | tuple[int, ...], dtype: Any) -> np.ndarray:
    """``np.empty`` whose data starts on a 4096-byte page.

    Parameters
    ----------
    shape : int or tuple of int
        Shape of the array.
    dtype : data-type
        Its element type.

    Returns
    -------
    numpy.ndarray
        A C-contiguous array, a view into a slightly larger buffer.
    """
    dtype = np.dtype(dtype)
    shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = np.empty(nbytes + PAGE, dtype=np.uint8)
    start = (-raw.ctypes.data) % PAGE
    return raw[start : start + nbytes].view(dtype).reshape(shape)


def readable_in_place(arr: np.ndarray) -> bool:
    """Whether a CPU device can read ``arr`` in place: C-contiguous and aligned to
    :data:`HOST_PTR_ALIGN` bytes.

    Parameters
    ----------
    arr : numpy.ndarray
        The array.

    Returns
    -------
    bool
        True when a ``CL_MEM_USE_HOST_PTR`` buffer over it needs no copy.
    """
    return bool(arr.flags.c_contiguous and arr.nbytes and arr.ctypes.data % HOST_PTR_ALIGN == 0)
