"""Shards for streaming: ``python -m datasets_gen export DIR --format webdataset|parquet --out OUT``.

One record per item, items in index order, shards of at most ``--shard-size`` bytes (default
1 GB; an item larger than that alone gets a shard of its own, flagged ``oversize`` in the
manifest). The arrays are those of :func:`datasets_gen.load` (``dataset[i]`` without
normalisation) plus the item's ``sequence.npz`` arrays as ``sequence.<name>``:

webdataset
    ``shard-000000.tar`` ...: POSIX tar files (fixed dates, owners and modes, so the same data
    give the same bytes) with members ``<index>.<array>.npy`` and ``<index>.record.json``;
    ``webdataset.WebDataset(urls).decode()`` yields ``{"__key__": "00003", "points.npy":
    array, ..., "record.json": dict}``.
parquet
    ``shard-000000.parquet`` ...: one row per item, columns ``index``, ``split``, ``record``
    (the JSON text) and one per array: scalars as they are, 1D arrays as ``list<T>``, 2D arrays
    ``(n, k)`` as ``list<fixed_size_list<T, k>>`` (null where an item has no such array);
    ``pyarrow.parquet.read_table`` reads them.

``OUT/manifest.json`` (written last) lists every shard's name, sha256, size and items. Each
shard is written atomically, so an interrupted export leaves only whole shards and a marker
(``.export.json``); rerunning the same command resumes (shards are made again in the same
order, and only missing ones are written). Any other non-empty ``OUT`` is refused before work.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import sys
import tarfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ao4d._atomic import atomic_open

from ._files import json_bytes
from .loader import Dataset, load

__all__ = ["export", "FORMATS", "DEFAULT_SHARD_SIZE", "item_arrays", "main"]

FORMATS = ("webdataset", "parquet")
DEFAULT_SHARD_SIZE = 10**9
_MARKER = ".export.json"
_SUFFIX = {"webdataset": ".tar", "parquet": ".parquet"}


def item_arrays(ds: Dataset, i: int) -> dict[str, Any]:
    """Item ``i``'s arrays as exported: ``ds.raw(i)`` plus ``sequence.<name>`` arrays."""
    item = ds.raw(i)
    if "sequence.npz" in item["record"].get("files", {}):
        index = ds.indices[i]
        item.update({f"sequence.{k}": v for k, v in ds._npz(index, "sequence.npz").items()})
    return item


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asarray(array, order="C"), allow_pickle=False)
    return buffer.getvalue()


def _tar_member_bytes(size: int) -> int:
    return 512 + -(-size // 512) * 512


def _webdataset_members(item: dict[str, Any]) -> list[tuple[str, bytes]]:
    key = f"{item['record']['index']:05d}"
    members = [(f"{key}.{name}.npy", _npy(value)) for name, value in item.items() if name != "record"]
    members.append((f"{key}.record.json", json_bytes(item["record"])))
    return members


def _tar_bytes(samples: list[list[tuple[str, bytes]]]) -> bytes:
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


def _parquet_bytes(items: list[dict[str, Any]]) -> bytes:
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
    pq.write_table(pa.table(columns), buffer, compression="zstd", write_statistics=False)
    return buffer.getvalue()


def _check_out(out: Path, marker: dict) -> None:
    if out.exists() and not out.is_dir():
        raise ValueError(f"`out` {str(out)!r} is a file; it must be a new or empty folder")
    if out.is_dir() and any(out.iterdir()):
        previous = None
        try:
            previous = json.loads((out / _MARKER).read_text())
        except (OSError, ValueError):
            pass
        if previous != marker:
            raise FileExistsError(
                f"`out` {str(out)!r} is not empty; shards go into a new or empty "
                "folder (or the folder of an interrupted export of the same "
                "dataset, format and shard size, to resume it)"
            )
        for stray in out.iterdir():  # temporary files of a killed write
            if stray.name.startswith(".") and ".tmp" in stray.name:
                stray.unlink()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create the folder `out` {str(out)!r}: {exc.strerror or exc}") from None


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def export(
    dataset: str | os.PathLike,
    out: str | os.PathLike,
    *,
    format: str = "webdataset",
    shard_size: int = DEFAULT_SHARD_SIZE,
    split: str | None = None,
    verify: bool = True,
    progress: bool | None = None,
) -> dict[str, Any]:
    """Write the items of ``dataset`` as shards into the folder ``out``; return the manifest.

    Parameters
    ----------
    dataset : path or URL
        A datasets_gen output folder (anything :func:`datasets_gen.load` opens).
    out : path
        A new or empty folder (or the folder of an interrupted export of the same dataset,
        format and shard size: the export resumes).
    format : {"webdataset", "parquet"}
    shard_size : int
        Largest shard in bytes (default 1 GB).
    split : str, optional
        Only this split's items.
    verify : bool
        Check every item file against the dataset's manifest while reading (default).
    progress : bool, optional
        A bar over items (default: when stderr is a terminal).

    Raises
    ------
    ValueError
        A bad ``format`` or ``shard_size``; ``out`` is a file.
    FileExistsError
        ``out`` is not empty (and not an interrupted export of the same thing).
    """
    if format not in FORMATS:
        raise ValueError(f"`format` must be one of {', '.join(map(repr, FORMATS))}, got {format!r}")
    if isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1024:
        raise ValueError(f"`shard_size` must be an integer >= 1024 bytes, got {shard_size!r}")
    if format == "parquet":
        try:
            import pyarrow  # noqa: F401 - fail before any work when it is missing
        except ImportError:
            raise ImportError("`format` 'parquet' needs pyarrow: pip install pyarrow") from None
    ds = load(dataset, split=split, verify=verify)
    out = Path(out)
    marker = {
        "dataset": str(dataset),
        "manifest_sha256": hashlib.sha256(json_bytes(ds._manifest)).hexdigest(),
        "format": format,
        "shard_size": shard_size,
        "split": split,
    }
    _check_out(out, marker)
    with atomic_open(out / _MARKER, "wb") as fh:
        fh.write(json_bytes(marker))

    from ao4d import _progress

    bar = _progress.bar(
        len(ds), f"export {format}", unit="item", show=sys.stderr.isatty() if progress is None else bool(progress)
    )
    shards: list[dict[str, Any]] = []
    for batch in _batches(ds, format, shard_size, bar):
        name = f"shard-{len(shards):06d}{_SUFFIX[format]}"
        data = batch["bytes"]
        path = out / name
        if not (
            path.is_file() and path.stat().st_size == len(data) and _sha256(path) == hashlib.sha256(data).hexdigest()
        ):
            with atomic_open(path, "wb") as fh:
                fh.write(data)
        shards.append(
            {
                "name": name,
                "sha256": hashlib.sha256(data).hexdigest(),
                "bytes": len(data),
                "items": batch["items"],
                "oversize": len(data) > shard_size,
            }
        )
    bar.close()
    manifest = {
        "format": format,
        "dataset": str(dataset),
        "dataset_manifest_sha256": marker["manifest_sha256"],
        "split": split,
        "shard_size": shard_size,
        "n_items": len(ds),
        "shards": shards,
    }
    with atomic_open(out / "manifest.json", "wb") as fh:
        fh.write(json_bytes(manifest))
    (out / _MARKER).unlink()
    return manifest


def _batches(ds: Dataset, format: str, shard_size: int, bar) -> Iterator[dict[str, Any]]:
    """Greedy shards in index order: an item joins the current shard while it stays within
    ``shard_size``. Tar sizes are exact; a Parquet shard is closed when the items' raw bytes
    would pass the limit, and if the written shard is still over, its last items move on."""
    pending: list[Any] = []
    size = 1024  # tar: two zero blocks at the end (the record padding is added below)

    def index(part: Any) -> int:
        return int(part[0][0].partition(".")[0]) if format == "webdataset" else part["record"]["index"]

    def flush(parts: list[Any]) -> Iterator[dict[str, Any]]:
        while parts:
            keep = len(parts)
            while True:
                data = _tar_bytes(parts[:keep]) if format == "webdataset" else _parquet_bytes(parts[:keep])
                if len(data) <= shard_size or keep == 1:
                    break
                keep -= 1
            yield {"bytes": data, "items": [index(p) for p in parts[:keep]]}
            parts = parts[keep:]

    for i in range(len(ds)):
        item = item_arrays(ds, i)
        if format == "webdataset":
            part = _webdataset_members(item)
            cost = sum(_tar_member_bytes(len(d)) for _, d in part)
            total = -(-(size + cost) // tarfile.RECORDSIZE) * tarfile.RECORDSIZE
        else:
            part = item
            cost = 4096 + len(json_bytes(item["record"])) + sum(v.nbytes for k, v in item.items() if k != "record")
            total = size + cost
        if pending and total > shard_size:
            yield from flush(pending)
            pending, size = [], 1024
        pending.append(part)
        size += cost
        bar.update()
    yield from flush(pending)


def main(argv: list[str] | None = None) -> int:
    """``python -m datasets_gen export DIR --format webdataset|parquet --out OUT``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m datasets_gen export",
        description="Write a dataset's items as WebDataset tar or Parquet shards, with a manifest of their hashes.",
    )
    parser.add_argument("dataset", help="a datasets_gen output folder or fsspec URL")
    parser.add_argument("--format", required=True, choices=FORMATS)
    parser.add_argument("--out", required=True, help="a new or empty folder for the shards")
    parser.add_argument(
        "--shard-size",
        default=str(DEFAULT_SHARD_SIZE),
        help="largest shard: bytes, or with a suffix kB, MB, GB (default 1GB)",
    )
    parser.add_argument("--split", default=None, help="only this split's items")
    parser.add_argument("--no-verify", action="store_true", help="skip the item checksums")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        manifest = export(
            args.dataset,
            args.out,
            format=args.format,
            shard_size=parse_size(args.shard_size),
            split=args.split,
            verify=not args.no_verify,
            progress=False if args.no_progress else None,
        )
    except (FileExistsError, ValueError, ImportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted: whole shards are kept; rerun the same command to resume", file=sys.stderr)
        return 130
    total = sum(s["bytes"] for s in manifest["shards"])
    print(
        f"{args.out}: {manifest['n_items']} items in {len(manifest['shards'])} {args.format} "
        f"shards, {total / 2**20:.2f} MiB"
    )
    return 0


def parse_size(text: str) -> int:
    """``"1GB"``, ``"250MB"``, ``"64kB"`` or a plain byte count -> bytes (decimal units)."""
    units = {"kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12, "b": 1}
    t = str(text).strip().lower()
    for suffix, factor in units.items():  # noqa: B007 (factor is used after the break)
        if t.endswith(suffix) and t[: -len(suffix)].strip():
            number = t[: -len(suffix)].strip()
            break
    else:
        number, factor = t, 1
    try:
        value = float(number) * factor
    except ValueError:
        raise ValueError(f"`--shard-size` must be bytes or a size like 1GB, got {text!r}") from None
    if not value >= 1024:  # NaN fails this too
        raise ValueError(f"`--shard-size` must be at least 1024 bytes, got {text!r}")
    return int(value)
