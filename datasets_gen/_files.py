"""Byte-reproducible file output: npz archives without timestamps, canonical JSON, hashes.

The npz writer is ``ao4d._npz.write_npz`` (fixed zip dates, so equal arrays give equal bytes);
all writes are atomic (``ao4d._atomic``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ao4d._atomic import atomic_open
from ao4d._npz import write_npz

__all__ = ["write_npz", "write_json", "json_bytes", "sha256_file", "to_jsonable", "written_bytes"]


def written_bytes(name: str, write: Callable[[Path], Any]) -> bytes:
    """The bytes that ``write(path)`` puts in a file called ``name``.

    For writers that take only a path (``SimplexMesh.save``, ``ao4d.io.pictures.save_montage``):
    they write into a private scratch folder, so that the caller can hand the bytes to a
    :class:`~datasets_gen._store.Store`. The name keeps the suffix that chooses the format.
    """
    with tempfile.TemporaryDirectory(prefix="datasets_gen-") as scratch:
        path = Path(scratch) / name
        write(path)
        return path.read_bytes()


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


def json_bytes(data: Any) -> bytes:
    """``data`` as canonical JSON (sorted keys, 2-space indent, trailing newline), UTF-8."""
    return (json.dumps(to_jsonable(data), indent=2, sort_keys=True, allow_nan=False) + "\n").encode("utf-8")


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write ``data`` as canonical JSON (:func:`json_bytes`), atomically."""
    with atomic_open(path, "wb") as fh:
        fh.write(json_bytes(data))
    return Path(path)


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
