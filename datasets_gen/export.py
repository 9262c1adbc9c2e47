"""Shards for streaming: ``python -m datasets_gen export DIR --format webdataset|parquet --out OUT``.

One record per item, shards of one split each named for it (``train-000000.tar``; formats in
:mod:`datasets_gen.shards`), items in index order within a split, splits in the config's order;
shards of at most ``--shard-size`` bytes (default 1 GB; an item larger than that alone gets a
shard of its own, flagged ``oversize`` in the manifest). The arrays are those of
:func:`datasets_gen.load` (``dataset[i]``; normalised with ``--normalize``, the record keeping
``loc`` and ``scale``) plus the item's ``sequence.npz`` arrays as ``sequence.<name>``.
``datasets_gen.load(OUT)`` reads an export back as the same :class:`~datasets_gen.Dataset`.

``OUT/manifest.json`` (written last) lists every shard's name, split, sha256, size and items,
the dataset's split names (empty ones too) and whether points are normalised. Each shard is
written atomically, so an interrupted export leaves only whole shards and a marker
(``.export.json``); rerunning the same command resumes (shards are made again in the same
order, and only missing ones are written). Any other non-empty ``OUT`` is refused before work.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import tarfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ao4d._atomic import atomic_open

from ._files import json_bytes, sha256_file
from ._store import is_url
from .loader import Dataset, load, normalized
from .shards import FORMATS, parquet_bytes, shard_name, tar_bytes, webdataset_members

__all__ = ["export", "FORMATS", "DEFAULT_SHARD_SIZE", "item_arrays", "main", "parse_size"]

DEFAULT_SHARD_SIZE = 10**9
_MARKER = ".export.json"


def item_arrays(ds: Dataset, i: int) -> dict[str, Any]:
    """Item ``i``'s arrays as exported: ``ds.raw(i)`` (normalised when ``ds.normalize``) plus
    ``sequence.<name>`` arrays."""
    item = ds.raw(i)
    index = ds.indices[i]
    if ds.normalize and not ds._manifest.get("normalized"):
        item = normalized(item, ds._normalization(index))
    if "sequence.npz" in item["record"]["files"]:
        item.update({f"sequence.{k}": v for k, v in ds._sequence(i).items()})
    return item


def _tar_member_bytes(size: int) -> int:
    return 512 + -(-size // 512) * 512


def _local_out(out: str | os.PathLike | bytes) -> Path:
    """``out`` as an absolute local folder; ``file://`` URLs are local folders, other URLs are
    refused (shards are written here, then copied where they go)."""
    text = os.fsdecode(out) if isinstance(out, (bytes, os.PathLike)) else out
    if not isinstance(text, str):
        raise TypeError(f"`out` must be a folder path, got {type(out).__name__}")
    if not text.strip():
        raise ValueError("`out` is empty; give a new or empty folder for the shards")
    if is_url(text):
        protocol, _, rest = text.partition("://")
        if protocol != "file" or not rest.strip("/"):
            raise ValueError(
                f"`out` {text!r} is a URL; export writes its shards into a local folder: give one, "
                "then copy the folder there (such as with fsspec's put or the storage's own tool)"
            )
        text = rest
    return Path(os.path.abspath(text))


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


def export(
    dataset: str | os.PathLike,
    out: str | os.PathLike,
    *,
    format: str = "webdataset",
    shard_size: int = DEFAULT_SHARD_SIZE,
    split: str | None = None,
    normalize: bool = False,
    verify: bool = True,
    progress: bool | None = None,
) -> dict[str, Any]:
    """Write the items of ``dataset`` as shards into the folder ``out``; return the manifest.

    Parameters
    ----------
    dataset : path or URL
        A datasets_gen output folder (anything :func:`datasets_gen.load` opens).
    out : path
        A new or empty local folder (or ``file://`` URL; or the folder of an interrupted export
        of the same dataset, format, shard size, split and normalisation: the export resumes).
    format : {"webdataset", "parquet"}
    shard_size : int
        Largest shard in bytes (default 1 GB).
    split : str, optional
        Only this split's items.
    normalize : bool
        Store the normalised points (:func:`datasets_gen.load`'s ``normalize``); each record
        keeps ``normalization`` (``loc``, ``scale``), and ``load(out)`` needs ``normalize=True``.
    verify : bool
        Check every item file against the dataset's manifest while reading (default).
    progress : bool, optional
        A bar over items (default: when stderr is a terminal).

    Returns
    -------
    dict
        The export's manifest (also written to ``out/manifest.json``).

    Raises
    ------
    ValueError
        A bad ``format``, ``shard_size`` or ``out`` (empty, a file, a URL other than
        ``file://``); a damaged dataset (:class:`~datasets_gen.DatasetError`).
    FileExistsError
        ``out`` is not empty (and not an interrupted export of the same thing).
    OSError
        A shard cannot be written (a read-only folder, a full disk): whole shards are kept.
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
    out = _local_out(out)
    ds = load(dataset, split=split, verify=verify, normalize=normalize)
    marker = {
        "dataset": ds.location,
        "manifest_sha256": hashlib.sha256(json_bytes(ds._manifest)).hexdigest(),
        "format": format,
        "shard_size": shard_size,
        "split": split,
        "normalized": bool(normalize),
    }
    _check_out(out, marker)
    with atomic_open(out / _MARKER, "wb") as fh:
        fh.write(json_bytes(marker))

    from ao4d import _progress

    bar = _progress.bar(
        len(ds), f"export {format}", unit="item", show=sys.stderr.isatty() if progress is None else bool(progress)
    )
    shards: list[dict[str, Any]] = []
    for name_of_split, positions in _by_split(ds):
        for number, batch in enumerate(_batches(ds, positions, format, shard_size, bar)):
            name = shard_name(format, name_of_split, number)
            data = batch["bytes"]
            digest = hashlib.sha256(data).hexdigest()
            path = out / name
            if not (path.is_file() and path.stat().st_size == len(data) and sha256_file(path) == digest):
                with atomic_open(path, "wb") as fh:
                    fh.write(data)
            shards.append(
                {
                    "name": name,
                    "split": name_of_split,
                    "sha256": digest,
                    "bytes": len(data),
                    "items": batch["items"],
                    "oversize": len(data) > shard_size,
                }
            )
    bar.close()
    manifest = {
        "format": format,
        "dataset": ds.location,
        "dataset_manifest_sha256": marker["manifest_sha256"],
        "split": split,
        "splits": ds.splits,
        "normalized": bool(normalize),
        "shard_size": shard_size,
        "n_items": len(ds),
        "shards": shards,
    }
    with atomic_open(out / "manifest.json", "wb") as fh:
        fh.write(json_bytes(manifest))
    (out / _MARKER).unlink()
    return manifest


def _by_split(ds: Dataset) -> list[tuple[str | None, list[int]]]:
    """The dataset's positions grouped by split, splits in the config's order (items without
    a split last, under ``None``)."""
    groups: dict[str | None, list[int]] = {}
    for position, index in enumerate(ds.indices):
        groups.setdefault(ds._record(index).get("split") or None, []).append(position)
    order = [s for s in ds.splits if s in groups] + [s for s in groups if s not in ds.splits]
    return [(s, groups[s]) for s in order]


def _batches(ds: Dataset, positions: list[int], format: str, shard_size: int, bar) -> Iterator[dict[str, Any]]:
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
                data = tar_bytes(parts[:keep]) if format == "webdataset" else parquet_bytes(parts[:keep])
                if len(data) <= shard_size or keep == 1:
                    break
                keep -= 1
            yield {"bytes": data, "items": [index(p) for p in parts[:keep]]}
            parts = parts[keep:]

    for i in positions:
        item = item_arrays(ds, i)
        if format == "webdataset":
            part = webdataset_members(item)
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
    parser.add_argument(
        "--normalize", action="store_true", help="store normalised points (each record keeps loc and scale)"
    )
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
            normalize=args.normalize,
            verify=not args.no_verify,
            progress=False if args.no_progress else None,
        )
    except (FileExistsError, ValueError, ImportError, TypeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a read-only folder, a full disk: whole shards are kept
        where = f" {exc.filename}" if exc.filename else ""
        print(f"error: cannot write the shards{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted: whole shards are kept; rerun the same command to resume", file=sys.stderr)
        return 130
    total = sum(s["bytes"] for s in manifest["shards"])
    try:
        print(
            f"{args.out}: {manifest['n_items']} items in {len(manifest['shards'])} {args.format} "
            f"shards, {total / 2**20:.2f} MiB"
        )
        sys.stdout.flush()
    except BrokenPipeError:  # `... | head -0`: the shards are written; nobody reads the line
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
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
    if not math.isfinite(value):
        raise ValueError(f"`--shard-size` must be a finite size like 1GB, got {text!r}")
    if not value >= 1024:  # NaN fails this too
        raise ValueError(f"`--shard-size` must be at least 1024 bytes, got {text!r}")
    return int(value)
