"""The shard formats of an export, written and read back: WebDataset tar and Parquet.

Both hold one record per item with the arrays of :func:`datasets_gen.load` (``ds[i]``) plus
the item's ``sequence.npz`` arrays as ``sequence.<name>``, and the item's split. A shard holds
the items of one split, and its name says which: ``train-000000.tar``, ``test-000003.parquet``
(``shard-000000.tar`` for a dataset without splits).

webdataset
    POSIX tar files (fixed dates, owners and modes, so the same data give the same bytes) with
    members ``<index>.<array>.npy.gz`` (each array as ``.npy``, gzip-compressed with no
    timestamp), ``<index>.record.json`` and ``<index>.split.txt``. The tar itself is not
    compressed, so one item can be read without reading the shard before it.
    ``webdataset.WebDataset(urls).decode()`` yields ``{"__key__": "00003", "points.npy.gz":
    array, ..., "record.json": dict, "split.txt": "train"}`` (its decoder unpacks ``.gz``).
parquet
    One row per item, each a row group of its own (zstd-compressed columns, no dictionaries): ``index``, ``split``, ``record`` (the JSON
    text) and one column per array: scalars as they are, 1D arrays as ``list<T>``, 2D arrays
    ``(n, k)`` as ``list<fixed_size_list<T, k>>`` (null where an item has no such array).
    With pyarrow, ``np.asarray(table["points"][i].values.to_tensor())`` is item ``i``'s
    ``(n, 4)`` array and ``table["sdf"][i].values.to_numpy()`` its 1D array.
"""

from __future__ import annotations

import gzip
import io
import json
import tarfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ._files import json_bytes

__all__ = [
    "FORMATS",
    "SUFFIX",
    "shard_name",
    "webdataset_members",
    "tar_bytes",
    "TarShard",
    "parquet_bytes",
    "ParquetShard",
]

FORMATS = ("webdataset", "parquet")
SUFFIX = {"webdataset": ".tar", "parquet": ".parquet"}
_NPY = ".npy.gz"


def shard_name(format: str, split: str | None, number: int) -> str:
    """``train-000000.tar``: the split (``shard`` without one), the shard's number in its split."""
    return f"{split or 'shard'}-{number:06d}{SUFFIX[format]}"


def _npy_gz(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asarray(array, order="C"), allow_pickle=False)
    return gzip.compress(buffer.getvalue(), compresslevel=6, mtime=0)


def webdataset_members(item: dict[str, Any]) -> list[tuple[str, bytes]]:
    """The tar members of one item (``item``: arrays plus ``record``)."""
    record = item["record"]
    key = f"{record['index']:05d}"
    members = [(f"{key}.{name}{_NPY}", _npy_gz(value)) for name, value in item.items() if name != "record"]
    members.append((f"{key}.record.json", json_bytes(record)))
    members.append((f"{key}.split.txt", (record.get("split") or "").encode("utf-8")))
    return members


def tar_bytes(samples: Iterable[list[tuple[str, bytes]]]) -> bytes:
    """A reproducible POSIX tar of the members of ``samples`` (no dates, owners or modes)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for members in samples:
            for name, data in members:
                info = tarfile.TarInfo(name)
                info.size, info.mtime, info.mode = len(data), 0, 0o644
                info.uid = info.gid = 0
                info.uname = info.gname = ""
                tar.addfile(info, io.BytesIO(data))
    return buffer.getvalue()


class TarShard:
    """Random access to the items of a WebDataset shard: the member table is read once, each
    item's members are read (and decompressed) only when asked."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.members: dict[int, dict[str, tuple[int, int]]] = {}
        with tarfile.open(self.path, mode="r:") as tar:
            for info in tar:
                if not info.isfile():
                    continue
                key, _, name = info.name.partition(".")
                self.members.setdefault(int(key), {})[name] = (info.offset_data, info.size)

    def _bytes(self, fh, where: tuple[int, int]) -> bytes:
        fh.seek(where[0])
        return fh.read(where[1])

    def record(self, index: int) -> dict:
        with open(self.path, "rb") as fh:
            return json.loads(self._bytes(fh, self.members[index]["record.json"]))

    def arrays(self, index: int, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """Item ``index``'s arrays (all, or those of ``names`` that it has)."""
        stored = {m[: -len(_NPY)]: where for m, where in self.members[index].items() if m.endswith(_NPY)}
        wanted = stored if names is None else [n for n in names if n in stored]
        out = {}
        with open(self.path, "rb") as fh:
            for name in wanted:
                out[name] = np.load(io.BytesIO(gzip.decompress(self._bytes(fh, stored[name]))), allow_pickle=False)
        return out


def _arrow_column(values: list[Any]):
    """A pyarrow array of one column: each entry a numpy array (or None)."""
    import pyarrow as pa

    sample = next(v for v in values if v is not None)
    if sample.ndim == 0:
        return pa.array([None if v is None else v.item() for v in values], type=pa.from_numpy_dtype(sample.dtype))
    if sample.ndim == 1:
        typ = pa.list_(pa.from_numpy_dtype(sample.dtype))
        return pa.array([None if v is None else v for v in values], type=typ)
    k = sample.shape[1]
    inner = pa.from_numpy_dtype(sample.dtype)
    offsets, flat, valid = [0], [], []
    for v in values:
        valid.append(v is not None)
        if v is not None:
            flat.append(np.ascontiguousarray(v).reshape(-1))
        offsets.append(offsets[-1] + (0 if v is None else len(v)))
    data = pa.array(np.concatenate(flat) if flat else np.zeros(0, sample.dtype), type=inner)
    rows = pa.FixedSizeListArray.from_arrays(data, k)
    mask = pa.array([not ok for ok in valid])
    return pa.ListArray.from_arrays(pa.array(offsets, pa.int32()), rows, mask=mask)


def parquet_bytes(items: list[dict[str, Any]]) -> bytes:
    """One Parquet file of ``items`` (arrays plus ``record``), a row each."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = sorted({n for it in items for n in it if n != "record"})
    columns = {
        "index": pa.array([it["record"]["index"] for it in items], pa.int64()),
        "split": pa.array([it["record"].get("split") for it in items], pa.string()),
        "record": pa.array([json_bytes(it["record"]).decode() for it in items], pa.string()),
    }
    for name in names:
        columns[name] = _arrow_column([it.get(name) for it in items])
    buffer = io.BytesIO()
    # a row group an item: a reader of one item decompresses that item's columns only; no
    # dictionaries (float arrays hardly repeat: a dictionary made the shards 1.4x the dataset)
    pq.write_table(
        pa.table(columns),
        buffer,
        compression="zstd",
        compression_level=9,
        use_dictionary=False,
        write_statistics=False,
        row_group_size=1,
    )
    return buffer.getvalue()


def _cell_array(cell: Any) -> np.ndarray:
    """A Parquet cell back as the numpy array it was written from (dtype and shape kept)."""
    import pyarrow as pa

    if not isinstance(cell, pa.ListScalar):
        return np.asarray(cell.as_py(), dtype=cell.type.to_pandas_dtype())
    values = cell.values
    if isinstance(values, pa.FixedSizeListArray):
        k = values.type.list_size
        flat = values.flatten().to_numpy(zero_copy_only=False)
        return np.ascontiguousarray(flat.reshape(-1, k))
    return np.ascontiguousarray(values.to_numpy(zero_copy_only=False))


class ParquetShard:
    """Random access to the items of a Parquet shard: each item is a row group of its own, of
    which only the columns asked for are read."""

    def __init__(self, path: Path):
        import pyarrow.parquet as pq

        self.path = Path(path)
        self.file = pq.ParquetFile(self.path, memory_map=True)
        indices = self.file.read(columns=["index"]).column("index").to_pylist()
        self.rows = {int(i): row for row, i in enumerate(indices)}
        self.groups = self.file.metadata.num_row_groups == len(indices)
        self.stored = [c for c in self.file.schema_arrow.names if c not in ("index", "split", "record")]

    def _row(self, index: int, columns: list[str]):
        row = self.rows[index]
        if self.groups:
            return self.file.read_row_group(row, columns=columns), 0
        return self.file.read(columns=columns), row

    def record(self, index: int) -> dict:
        table, row = self._row(index, ["record"])
        return json.loads(table.column("record")[row].as_py())

    def arrays(self, index: int, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """Item ``index``'s arrays (all, or those of ``names`` that it has)."""
        wanted = self.stored if names is None else [n for n in names if n in self.stored]
        table, row = self._row(index, wanted)
        out = {}
        for name in wanted:
            cell = table.column(name)[row]
            if cell.is_valid:
                out[name] = _cell_array(cell)
        return out
