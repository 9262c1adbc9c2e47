"""MetaImage grids (.mhd with its raw file, or .mha): the header parsed, the data read."""

from __future__ import annotations

import math
import os
import warnings
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import check_memory, regular_file
from .sources import ObliqueAffineWarning

__all__ = []


_MET_TYPES = {
    "MET_CHAR": "i1",
    "MET_UCHAR": "u1",
    "MET_SHORT": "i2",
    "MET_USHORT": "u2",
    "MET_INT": "i4",
    "MET_UINT": "u4",
    "MET_LONG": "i4",
    "MET_ULONG": "u4",
    "MET_LONG_LONG": "i8",
    "MET_ULONG_LONG": "u8",
    "MET_FLOAT": "f4",
    "MET_DOUBLE": "f8",
}


def _parse_metaimage_header(path: str) -> tuple[dict[str, str], int]:
    """Header fields and, for ``ElementDataFile = LOCAL``, the byte offset of the data."""
    fields: dict[str, str] = {}
    with open(path, "rb") as fh:
        offset = 0
        for raw in fh:
            offset += len(raw)
            try:  # file names in headers written today are UTF-8; older tools wrote latin-1
                line = raw.decode("utf-8").strip()
            except UnicodeDecodeError:
                line = raw.decode("latin-1").strip()
            if not line:
                continue
            if "=" not in line:
                raise ValueError(f"{path!r} is not a MetaImage header (line {line[:40]!r})")
            key, _, value = line.partition("=")
            fields[key.strip()] = value.strip()
            if key.strip() == "ElementDataFile":
                break
            if offset > 1 << 16:
                raise ValueError(f"{path!r} is not a MetaImage header (no ElementDataFile)")
    if "ElementDataFile" not in fields:
        raise ValueError(f"{path!r} is not a MetaImage header (no ElementDataFile)")
    return fields, offset


def _floats(fields: dict, key: str, d: int, default: float, path: str) -> np.ndarray:
    if key not in fields:
        return np.full(d, default)
    try:
        values = np.array([float(x) for x in fields[key].split()])
    except ValueError:
        raise ValueError(f"{path!r}: {key} = {fields[key]!r} is not a list of numbers") from None
    if len(values) < d:
        raise ValueError(f"{path!r}: {key} has {len(values)} entries, NDims is {d}")
    return values[:d]


def _header_int(fields: dict, key: str, default: int, path: str) -> int:
    try:
        return int(fields.get(key, str(default)))
    except ValueError:
        raise ValueError(f"{path!r}: {key} = {fields[key]!r} is not an integer") from None


def _read_metaimage(path: str, *, data: bool = True) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    """Values (a memory map; decompressed when compressed, unless ``data`` is false: then a
    read-only stand-in of the right shape and dtype), spacing, origin, notes."""
    fields, header_end = _parse_metaimage_header(path)
    try:
        d = int(fields["NDims"])
        shape = tuple(int(n) for n in fields["DimSize"].split())
    except (KeyError, ValueError):
        raise ValueError(f"{path!r}: NDims and DimSize are missing or not integers") from None
    if len(shape) != d:
        raise ValueError(f"{path!r}: DimSize has {len(shape)} entries, NDims is {d}")
    if any(n < 1 for n in shape):
        raise ValueError(f"{path!r}: DimSize = {fields['DimSize']} must be positive integers")
    met = fields.get("ElementType", "")
    if met not in _MET_TYPES:
        raise ValueError(f"{path!r}: ElementType {met!r} is not one of {', '.join(_MET_TYPES)}")
    if _header_int(fields, "ElementNumberOfChannels", 1, path) != 1:
        raise ValueError(f"{path!r}: only single-channel (scalar) images are read")
    msb = fields.get("BinaryDataByteOrderMSB", fields.get("ElementByteOrderMSB", "False"))
    dtype = np.dtype(_MET_TYPES[met]).newbyteorder(">" if msb.lower() == "true" else "<")
    data_file = fields["ElementDataFile"]
    if data_file.upper() == "LIST" or data_file.split()[0].lower().find("%") >= 0:
        raise ValueError(
            f"{path!r}: ElementDataFile = {data_file} (file lists) is not supported; give the frames as a glob instead"
        )
    if data_file.upper() == "LOCAL":
        raw, offset = path, header_end
    else:
        raw, offset = str(Path(path).parent / data_file), 0
        if not Path(raw).exists():
            raise FileNotFoundError(f"{path!r} names the data file {data_file!r}, which does not exist")
        if Path(raw).is_dir():
            raise ValueError(f"{path!r} names the data file {data_file!r}, which is a folder, not a file")
        regular_file(raw, "path", what=f"data file of {path!r}")  # a FIFO would block the reader
    header_size = _header_int(fields, "HeaderSize", 0, path)
    if header_size > 0:
        offset += header_size
    need = math.prod(shape) * dtype.itemsize
    have = os.path.getsize(raw) - offset
    # MetaImage stores x fastest: a Fortran-ordered array of shape (n_x, n_y, ...)
    if fields.get("CompressedData", "False").lower() == "true" and not data:
        values = np.broadcast_to(np.zeros((), dtype=dtype), shape)
    elif fields.get("CompressedData", "False").lower() == "true":
        check_memory(need, f"decompressing {raw!r}", hint="store the data uncompressed")
        with open(raw, "rb") as fh:
            fh.seek(offset)
            try:
                payload = zlib.decompress(fh.read())
            except zlib.error as exc:
                raise ValueError(f"{raw!r}: compressed data is corrupt or truncated ({exc})") from None
        if len(payload) != need:
            raise ValueError(f"{raw!r}: decompressed {len(payload)} bytes, DimSize needs {need}")
        values = np.frombuffer(payload, dtype=dtype).reshape(shape, order="F")
    else:
        if header_size == -1:
            offset = os.path.getsize(raw) - need
            have = need
        if have < need:
            raise ValueError(
                f"{raw!r} is truncated: DimSize {shape} of {met} needs {need} bytes "
                f"of data, the file has {max(have, 0)}"
            )
        values = np.memmap(raw, dtype=dtype, mode="r", offset=offset, shape=shape, order="F")
    step = _floats(fields, "ElementSpacing", d, 1.0, path)
    if (step <= 0).any():
        raise ValueError(f"{path!r}: ElementSpacing must be > 0, got {step.tolist()}")
    key = next((k for k in ("Offset", "Origin", "Position") if k in fields), "Offset")
    start = _floats(fields, key, d, 0.0, path)
    notes = [
        "spacing from ElementSpacing" if "ElementSpacing" in fields else "no ElementSpacing: 1",
        f"origin from {key}" if key in fields else "no Offset: 0",
    ]
    matrix_key = next((k for k in ("TransformMatrix", "Rotation", "Orientation") if k in fields), None)
    if matrix_key is not None:
        matrix = _floats(fields, matrix_key, d * d, 0.0, path).reshape(d, d)
        if np.abs(matrix - np.eye(d)).max() > 1e-6:
            warnings.warn(
                f"{path!r}: {matrix_key} is not the identity; using the voxel axes "
                "(the mesh is not in the rotated frame)",
                ObliqueAffineWarning,
                stacklevel=4,
            )
            notes.append(f"{matrix_key} ignored")
    return values, step, start, notes
