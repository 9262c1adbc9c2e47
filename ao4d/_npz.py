"""Byte-reproducible ``.npz`` archives.

``np.savez`` stamps every zip member with the current time, so writing the same arrays twice
gives different bytes (and different checksums in manifests). Here every member gets the fixed
date 1980-01-01 (the earliest a zip header holds), fixed permissions and a fixed compression
level: equal arrays give equal bytes for the same numpy and zlib. ``np.load`` reads the result.
"""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import atomic_open

__all__ = ["write_npz", "npz_bytes"]

_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def npz_bytes(arrays: Mapping[str, Any], *, compress: bool = True) -> bytes:
    """The ``.npz`` archive of ``arrays`` (member name -> array) as bytes, deterministically.

    Object arrays are refused: they would need pickling, which ``np.load`` rejects by default.
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=method) as archive:
        for name, value in arrays.items():
            arr = np.asarray(value)
            if arr.dtype == object:
                raise TypeError(f"`arrays[{name!r}]` has dtype object, which .npz cannot store safely")
            npy = io.BytesIO()
            np.lib.format.write_array(npy, np.asarray(arr, order="C"), allow_pickle=False)  # keeps 0-d
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            # level 1: a demo scene's arrays 9 % larger than at level 6, deflated 4x faster
            archive.writestr(info, npy.getvalue(), compresslevel=1 if compress else None)
    return buffer.getvalue()


def write_npz(path: str | os.PathLike, arrays: Mapping[str, Any], *, compress: bool = True) -> Path:
    """Write ``arrays`` atomically to the ``.npz`` file ``path``; equal arrays give equal bytes.

    Parameters
    ----------
    path : path-like
        Destination (``.npz`` is not appended).
    arrays : mapping of str to array_like
        Member names (without ``.npy``) and arrays.
    compress : bool
        Deflate the members (level 1).

    Returns
    -------
    Path
    """
    data = npz_bytes(arrays, compress=compress)
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)
