"""Byte-reproducible ``.npz`` archives, and what to say when a user's ``.npy``/``.npz`` will not load.

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

__all__ = ["write_npz", "npz_bytes", "npy_problem", "npz_member_problem"]

NPY_MAGIC = b"\x93NUMPY"

# what a file that is no .npy often is instead (its first bytes), for the message
_SIGNATURES = (
    (b"\x89PNG", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF8", "a GIF image"),
    (b"PK\x03\x04", "a zip archive (an .npz?)"),
    (b"\x1f\x8b", "gzip data"),
    (b"\x89HDF", "an HDF5 file"),
    (b"%PDF", "a PDF document"),
)

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


def npy_problem(path: str | os.PathLike, exc: BaseException) -> str:
    """Why ``np.load(path, allow_pickle=False)`` refused a ``.npy`` file, in words.

    numpy says of any file without the ``.npy`` header that it "contains pickled (object) data"
    and suggests ``allow_pickle=True``: wrong for random bytes or a renamed picture, and an
    invitation to an unsafe load. This looks at the file's first bytes instead.

    Parameters
    ----------
    path : str or path-like
        The file that failed to load.
    exc : BaseException
        numpy's exception.

    Returns
    -------
    str
        The reason, for a message such as ``f"{path!r} is not a valid .npy file ({reason})"``.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as err:
        return f"cannot be read: {err.strerror or err}"
    if not head:
        return "it is empty"
    if not head.startswith(NPY_MAGIC):
        kind = next((f"; it looks like {name}" for magic, name in _SIGNATURES if head.startswith(magic)), "")
        return f"no .npy header{kind}; it starts with {head[:8]!r}"
    if "pickle" in str(exc) or "Python objects" in str(exc):
        return "it holds Python objects (dtype object), which ao4d never loads: unpickling can run code"
    return f"truncated or damaged: {exc}"


def npz_member_problem(exc: BaseException) -> str:
    """Why reading a member of a ``.npz`` archive failed, in words (without numpy's
    ``allow_pickle=`` hint): see :func:`npy_problem`."""
    if "pickle" in str(exc):
        return (
            "a member holds Python objects (dtype object) or is no .npy array; ao4d never loads "
            "those: unpickling can run code"
        )
    return f"damaged: {exc}"
