"""Byte-reproducible file output: npz archives without timestamps, canonical JSON, hashes.

``np.savez`` stamps each zip member with the current time, so two identical runs would differ;
here every member gets the fixed date 1980-01-01 and the same compression, so equal arrays give
equal bytes (for the same numpy and zlib). All writes are atomic (``ao4d._atomic``).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ao4d._atomic import atomic_open

__all__ = ["write_npz", "write_json", "sha256_file", "to_jsonable", "save_mesh_npz"]

_EPOCH = (1980, 1, 1, 0, 0, 0)  # the earliest date a zip header can hold


def write_npz(path: str | os.PathLike, arrays: Mapping[str, Any], *, compress: bool = True) -> Path:
    """Write ``arrays`` to an ``.npz`` file (readable by ``np.load``) with fixed metadata.

    Parameters
    ----------
    path : path-like
        Destination; written atomically.
    arrays : mapping of str to array_like
        Member names (without ``.npy``) and arrays; object arrays are refused.
    compress : bool
        Deflate the members (level 6).

    Returns
    -------
    Path
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_open(path, "wb") as fh, zipfile.ZipFile(fh, "w", compression=method,
                                                       compresslevel=6 if compress else None) as zf:
        for name, value in arrays.items():
            arr = np.asarray(value)
            if arr.dtype == object:
                raise TypeError(f"`arrays[{name!r}]` has dtype object, which .npz cannot store safely")
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.asarray(arr, order="C"), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            zf.writestr(info, buffer.getvalue())
    return Path(path)


def save_mesh_npz(path: str | os.PathLike, mesh: Any) -> Path:
    """Write a SimplexMesh in ``ao4d.meshio``'s npz layout (``SimplexMesh.load`` reads it)."""
    from ao4d.meshio import NPZ_FORMAT

    arrays: dict[str, Any] = {"format": np.array(NPZ_FORMAT), "vertices": mesh.vertices,
                              "simplices": mesh.simplices}
    for kind in ("point_data", "cell_data"):
        for name, value in sorted(getattr(mesh, kind).items()):
            arrays[f"{kind}/{name}"] = value
    return write_npz(path, arrays)


def to_jsonable(value: Any) -> Any:
    """Convert numpy scalars/arrays, tuples and paths into plain JSON types.

    Non-finite floats become the strings ``"inf"``, ``"-inf"``, ``"nan"`` (strict JSON has none).
    """
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        f = float(value)
        return f if math.isfinite(f) else str(f)
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write ``data`` as canonical JSON (sorted keys, 2-space indent, trailing newline), atomically."""
    text = json.dumps(to_jsonable(data), indent=2, sort_keys=True, allow_nan=False) + "\n"
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    return Path(path)


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
