"""Read a dataset back: ``datasets_gen.load(path) -> Dataset`` (map-style, for training).

>>> ds = load("data/tori", split="train", normalize=True)     # doctest: +SKIP
>>> item = ds[0]          # vertices, simplices, ao, points, occupancy, sdf, ..., record, index
>>> fast = load("data/tori", keys=("points", "occupancy"), dtype="float32")  # doctest: +SKIP
>>> frames = ds.frames(0) # the item's sequence.npz as trimesh.Trimesh frames

``path`` is a dataset folder (``python -m datasets_gen CONFIG --out PATH``; or an fsspec URL) or
the folder of an export of one (``python -m datasets_gen export``, WebDataset or Parquet):
the same items, the same arrays byte for byte. A :class:`Dataset` holds only the address, the
item list and the manifest; each ``ds[i]`` reads the files of that item that its ``keys``
need. It pickles (what it opened is reopened from the address), so
``torch.utils.data.DataLoader(ds, num_workers=2)`` and process pools work.

Before an item is read, the index is checked against the manifest: a truncated, emptied or
duplicated ``items.csv`` is an error, never fewer or repeated items.
"""

from __future__ import annotations

import copy
import csv
import hashlib
import io
import json
import math
import os
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ao4d._npz import npz_member_problem
from ao4d._validate import regular_file

from ._files import sha256_file
from ._store import Store, is_url, open_store
from .items import item_folder
from .samples import SAMPLE_ARRAYS
from .shards import FORMATS, ParquetShard, TarShard

__all__ = ["load", "Dataset", "DatasetError", "POINT_ARRAYS", "KEYS"]

#: arrays holding 4D points (moved by ``normalize``); ``sdf`` is a length (scaled)
POINT_ARRAYS = ("vertices", "points", "surface_points")
#: the names ``keys`` may take: an item's arrays and its record
KEYS = ("vertices", "simplices", "ao", *SAMPLE_ARRAYS, "record")
# where each array of an item folder lives, and its name in that file
_FILE_OF = {
    "vertices": ("mesh.npz", "vertices"),
    "simplices": ("mesh.npz", "simplices"),
    "ao": ("ao.npz", "occlusion"),
    **{name: ("samples.npz", name) for name in SAMPLE_ARRAYS},
}


class DatasetError(ValueError):
    """A dataset folder is missing, incomplete, or a file fails its checksum (the message names
    the item and the file)."""


def load(
    path: str | os.PathLike | bytes,
    *,
    split: str | None = None,
    keys: Iterable[str] | None = None,
    dtype: Any = None,
    verify: bool = False,
    normalize: bool = False,
    transform: Callable[[dict], Any] | None = None,
) -> Dataset:
    """Open the dataset at ``path``: a datasets_gen output folder or URL, or an export's folder.

    Parameters
    ----------
    path : path, str or URL
        The run's output folder (``python -m datasets_gen CONFIG --out PATH``), an fsspec URL of
        one (``s3://bucket/run``, ``file:///...``), or the local folder of an export of one
        (``python -m datasets_gen export ... --out PATH``, either format).
    split : str, optional
        Only the items of this split (the config's ``split`` table). A split the config names
        exists even when no item fell into it (then ``len(ds) == 0``); ``None``: every item.
    keys : sequence of str, optional
        The arrays each item holds (of :data:`KEYS`: ``vertices``, ``simplices``, ``ao``,
        ``points``, ``occupancy``, ``sdf``, ``surface_points``, ``surface_normals``,
        ``surface_ao``, and ``record``); only the files they live in are opened, so
        ``keys=("points", "occupancy")`` never reads a mesh. Default: everything.
    dtype : numpy floating dtype, optional
        Cast every floating array to it (``"float32"`` for training); integer and boolean
        arrays keep theirs.
    verify : bool
        Check each file's sha256 (and ``items.csv``'s) against ``manifest.json`` before it is
        used (for an export: each shard's against the export's manifest); a mismatch raises
        :class:`DatasetError` naming the item and the file.
    normalize : bool
        Apply the item's ``record["normalization"]``: ``(x - loc) / scale`` on every point array
        (:data:`POINT_ARRAYS`) and ``sdf / scale``; normals and occupancy are unchanged. An
        export written with ``--normalize`` stores normalised points and must be loaded with
        ``normalize=True``.
    transform : callable, optional
        Called on each item's dict; ``ds[i]`` returns its result. When it has a ``set_epoch``
        method, :meth:`Dataset.set_epoch` calls it.

    Returns
    -------
    Dataset
        The items, read lazily: ``ds[i]`` is a dict of the arrays, ``record`` (when kept) and
        ``index`` (the item's index in the dataset).

    Raises
    ------
    DatasetError
        No dataset or export there, its index disagrees with its manifest, ``split`` names no
        split of the dataset, or ``keys`` asks for an array the dataset does not store.
    ValueError
        A ``keys`` name outside :data:`KEYS`, or a ``dtype`` that is not a floating type.
    """
    return Dataset(path, split=split, keys=keys, dtype=dtype, verify=verify, normalize=normalize, transform=transform)


def _location(path: Any) -> str:
    """The dataset's address: an absolute local path (so a later ``os.chdir`` changes nothing)
    or a URL."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"`path` must be a folder path or URL (str or os.PathLike), got {type(path).__name__}")
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not text.strip():
        raise ValueError("`path` is empty; give the dataset's folder")
    return text if is_url(text) else os.path.abspath(text)


def _check_keys(keys: Any) -> tuple[str, ...] | None:
    if keys is None:
        return None
    if isinstance(keys, (str, bytes)) or not isinstance(keys, Iterable):
        raise TypeError(f"`keys` must be a sequence of names such as ('points', 'occupancy'), got {keys!r}")
    keys = tuple(keys)
    unknown = [k for k in keys if k not in KEYS]
    if unknown or not keys:
        raise ValueError(
            f"`keys` names {', '.join(map(repr, unknown)) or 'nothing'}; an item's keys are {', '.join(KEYS)}"
        )
    return tuple(dict.fromkeys(keys))


def _check_dtype(dtype: Any) -> np.dtype | None:
    if dtype is None:
        return None
    try:
        out = np.dtype(dtype)
    except TypeError:
        out = None
    if out is None or out.kind != "f":
        raise ValueError(f"`dtype` must be a floating type such as 'float32', got {dtype!r}")
    return out


def _few(values: list[int], n: int = 5) -> str:
    """``[1, 2, 3]`` or ``[1, 2, 3, 4, 5, ...] (12)`` for a message."""
    return str(values) if len(values) <= n else f"{str(values[:n])[:-1]}, ...] ({len(values)})"


def _json(data: bytes, what: str) -> Any:
    try:
        return json.loads(data)
    except ValueError as exc:  # not UTF-8 or not JSON
        raise DatasetError(f"{what} is not valid JSON: {exc}") from None


class _Folder:
    """A dataset folder (local or a URL): items.csv, manifest.json, items/NNNNN/ files."""

    def __init__(self, location: str, verify: bool):
        self.location, self.verify = location, verify
        self.store: Store = open_store(location, "path")
        if not is_url(location) and not os.path.isdir(location):
            raise DatasetError(f"`path` {location!r} is not a folder (a datasets_gen output or export)")
        if not self.store.is_file("manifest.json"):
            raise DatasetError(
                f"`path` {location!r} holds no readable dataset: no manifest.json (a datasets_gen run's "
                "folder holds manifest.json and items.csv; an export's, manifest.json and shards)"
            )
        manifest = _json(self.read("manifest.json"), f"{location}/manifest.json")
        if not isinstance(manifest, dict) or not isinstance(manifest.get("files"), dict):
            raise DatasetError(f"{location}/manifest.json is damaged: no table of files (a datasets_gen manifest)")
        self.manifest = manifest
        self.rows = self._rows(self.read("items.csv"))
        self.splits = self._split_names()

    def read(self, rel: str) -> bytes:
        where = f"{self.location.rstrip('/')}/{rel}"
        parts = rel.split("/")
        if len(parts) == 3 and parts[0] == "items" and parts[1].isdigit():  # name the item and file first
            where = f"item {int(parts[1])}: {parts[2]} ({where})"
        try:
            data = self.store.read_bytes(rel)
        except OSError as exc:
            raise DatasetError(f"cannot read {where}: {exc.strerror or exc}") from None
        if self.verify and rel != "manifest.json":
            entry = self.manifest["files"].get(rel) if hasattr(self, "manifest") else None
            if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str):
                raise DatasetError(f"{where} has no sha256 in manifest.json, so it cannot be verified")
            digest = hashlib.sha256(data).hexdigest()
            if digest != entry["sha256"]:
                raise DatasetError(f"{where} fails its checksum: sha256 {digest} != manifest {entry['sha256']}")
        return data

    def _rows(self, data: bytes) -> list[tuple[int, str]]:
        where = f"{self.location}/items.csv"
        try:
            reader = csv.DictReader(io.StringIO(data.decode("utf-8")))
            rows = list(reader)
        except (UnicodeDecodeError, csv.Error) as exc:
            raise DatasetError(f"{where} is damaged: {exc}") from None
        if "index" not in (reader.fieldnames or []):
            raise DatasetError(f"{where} is damaged: it has no `index` column")
        out = []
        for n, row in enumerate(rows, 2):
            text = row.get("index") or ""
            if not (text.isascii() and text.isdigit()):
                raise DatasetError(f"{where} is damaged: line {n} has index {text!r}, not an item number")
            out.append((int(text), row.get("split") or ""))
        indices = [i for i, _ in out]
        listed = sorted(
            int(rel.split("/")[1])
            for rel in self.manifest["files"]
            if rel.startswith("items/") and rel.endswith("/record.json") and rel.split("/")[1].isdigit()
        )
        if sorted(indices) != listed:
            repeated = sorted(i for i, n in Counter(indices).items() if n > 1)
            extra, missing = sorted(set(indices) - set(listed)), sorted(set(listed) - set(indices))
            said = [f"item(s) {_few(repeated)} more than once"] if repeated else []
            said += [f"item(s) {_few(extra)} the manifest has not"] if extra else []
            said += [f"not item(s) {_few(missing)} of the manifest"] if missing else []
            raise DatasetError(
                f"{where} does not match manifest.json: it lists {len(indices)} rows, the manifest "
                f"{len(listed)} complete items ({'; '.join(said)}); the index is truncated or damaged "
                "(rerun the same command to rewrite it)"
            )
        return out

    def _split_names(self) -> list[str]:
        """The config's split names (``run.json``), so a split that received no item exists."""
        names = sorted({s for _, s in self.rows} - {""})
        try:
            info = json.loads(self.store.read_bytes("run.json"))
            from .config import tomllib

            table = tomllib.loads(info["config_text"]).get("split")
        except (OSError, ValueError, KeyError, TypeError, AttributeError):  # no run.json of ours: the items' splits
            return names
        if isinstance(table, dict):  # the config's order, then any the items carry besides
            return list(table) + [n for n in names if n not in table]
        return names

    def record(self, index: int) -> dict:
        return _json(self.read(f"{item_folder(index)}/record.json"), f"item {index}: record.json")

    def _npz(self, index: int, name: str) -> dict[str, np.ndarray]:
        data = self.read(f"{item_folder(index)}/{name}")
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (zipfile.BadZipFile, zlib.error, ValueError, EOFError, OSError, KeyError, AttributeError) as exc:
            # numpy's allow_pickle hint replaced (object arrays are never loaded)
            why = npz_member_problem(exc) if "pickle" in str(exc) else f"{type(exc).__name__}: {exc}"
            raise DatasetError(f"item {index}: {name} is damaged: {why}") from None

    def arrays(self, index: int, record: dict, keys: tuple[str, ...] | None) -> dict[str, np.ndarray]:
        files = record["files"]
        wanted = [k for k in (keys or _FILE_OF) if k in _FILE_OF]
        out: dict[str, np.ndarray] = {}
        for name in dict.fromkeys(_FILE_OF[k][0] for k in wanted):
            if name not in files:
                continue
            stored = self._npz(index, name)
            if keys is None and name == "samples.npz":
                out.update(stored)
                continue
            for key in wanted:
                file, member = _FILE_OF[key]
                if file != name:
                    continue
                if member not in stored:
                    raise DatasetError(f"item {index}: {name} has no array {member!r}")
                out[key] = stored[member]
        return out

    def sequence(self, index: int, record: dict) -> dict[str, np.ndarray]:
        return self._npz(index, "sequence.npz")


class _Export:
    """The folder of an export (WebDataset or Parquet shards and their manifest)."""

    def __init__(self, location: str, manifest: dict, verify: bool):
        self.location, self.manifest, self.verify = location, manifest, verify
        fmt = manifest.get("format")
        if fmt not in FORMATS:
            raise DatasetError(
                f"`path` {location!r}: its manifest.json is of format {fmt!r}, neither a datasets_gen run "
                f"nor an export of one ({', '.join(FORMATS)})"
            )
        shards = manifest.get("shards")
        if not isinstance(shards, list) or not all(
            isinstance(s, dict) and isinstance(s.get("name"), str) and isinstance(s.get("items"), list) for s in shards
        ):
            raise DatasetError(
                f"{location}/manifest.json is damaged: `shards` is not a list of shards with their items"
            )
        self.format = fmt
        self.rows, self._shard_of = [], {}
        for shard in manifest["shards"]:
            for index in shard["items"]:
                self.rows.append((int(index), shard.get("split") or ""))
                self._shard_of[int(index)] = shard
        self.rows.sort()
        self.splits = list(manifest.get("splits") or sorted({s for _, s in self.rows} - {""}))
        self._open: dict[str, Any] = {}

    def _shard(self, index: int):
        shard = self._shard_of[index]
        name = shard["name"]
        if name not in self._open:
            path = Path(self.location) / name
            try:
                regular_file(path, "path", what="shard")  # never a FIFO, which would block
                if self.verify:
                    digest = sha256_file(path)  # in blocks: a shard may be 1 GB
                    if digest != shard.get("sha256"):
                        raise DatasetError(
                            f"{path} fails its checksum: sha256 {digest} != manifest {shard.get('sha256')}"
                        )
                opened = TarShard(path) if self.format == "webdataset" else ParquetShard(path)
            except DatasetError:
                raise
            except Exception as exc:  # missing, unreadable or not a shard of this format
                raise DatasetError(f"cannot read the shard {path}: {type(exc).__name__}: {exc}") from None
            if len(self._open) >= 16:  # a few shards open: items are mostly read shard by shard
                self._open.pop(next(iter(self._open)))
            self._open[name] = opened
        return self._open[name]

    def record(self, index: int) -> dict:
        return self._shard(index).record(index)

    def arrays(self, index: int, record: dict, keys: tuple[str, ...] | None) -> dict[str, np.ndarray]:
        names = [k for k in keys if k != "record"] if keys is not None else None
        out = self._shard(index).arrays(index, names)
        if names is None:
            out = {k: v for k, v in out.items() if not k.startswith("sequence.")}
        else:
            missing = [k for k in names if k not in out]
            if missing:
                raise DatasetError(f"item {index} of {self.location!r} has no {', '.join(map(repr, missing))}")
        return out

    def sequence(self, index: int, record: dict) -> dict[str, np.ndarray]:
        arrays = self._shard(index).arrays(index)
        return {k[len("sequence.") :]: v for k, v in arrays.items() if k.startswith("sequence.")}


def _open_source(location: str, verify: bool) -> _Folder | _Export:
    if not is_url(location):
        manifest_path = Path(location) / "manifest.json"
        if manifest_path.is_file() and not (Path(location) / "items.csv").exists():
            manifest = _json(manifest_path.read_bytes(), f"{manifest_path}")
            if not isinstance(manifest, dict):
                raise DatasetError(f"{manifest_path} is damaged: not a table")
            return _Export(location, manifest, verify)
    return _Folder(location, verify)


class Dataset:
    """The items of a dataset (or of an export of one), read lazily; see :func:`load`.

    ``len(ds)`` items; ``ds[i]`` a dict of numpy arrays (``vertices``, ``simplices``, ``ao`` when
    present, the ``samples.npz`` arrays when present; only ``keys`` when given) plus ``record``
    (the item's JSON record, a copy) and ``index``; ``ds.records`` every record;
    ``ds.frames(i)`` the item's sequence frames and ``ds.frame_samples(i)`` their 3D samples;
    ``ds.indices`` the dataset indices of the items (``ds[i]`` is item ``ds.indices[i]``);
    ``ds.splits`` the dataset's split names; ``ds.set_epoch(k)`` tells the transform the epoch.

    Parameters
    ----------
    path : path, str or URL
        The dataset's folder, URL or export folder (:func:`load`).
    split : str, optional
        Only the items of this split.
    keys : sequence of str, optional
        The arrays each item holds (:data:`KEYS`); only their files are opened.
    dtype : numpy floating dtype, optional
        Cast every floating array to it.
    verify : bool
        Check each file against the manifest before use.
    normalize : bool
        Apply each item's ``record["normalization"]``.
    transform : callable, optional
        Called on each item's dict.
    """

    def __init__(
        self,
        path: str | os.PathLike | bytes,
        *,
        split: str | None = None,
        keys: Iterable[str] | None = None,
        dtype: Any = None,
        verify: bool = False,
        normalize: bool = False,
        transform: Callable[[dict], Any] | None = None,
    ) -> None:
        if transform is not None and not callable(transform):
            raise TypeError(f"`transform` must be callable, got {type(transform).__name__}")
        if split is not None and not isinstance(split, str):
            raise TypeError(f"`split` must be a split's name (str), got {type(split).__name__}")
        self.location = _location(path)
        self.keys, self.dtype = _check_keys(keys), _check_dtype(dtype)
        self.verify, self.normalize, self.transform, self.split = bool(verify), bool(normalize), transform, split
        self.epoch = 0
        source = self._source
        if isinstance(source, _Export) and source.manifest.get("normalized") and not self.normalize:
            raise DatasetError(
                f"`path` {self.location!r} is an export with normalised points (export --normalize); "
                "load it with normalize=True"
            )
        self.splits = source.splits
        if split is not None and split not in self.splits:
            raise DatasetError(
                f"`split` {split!r} is not a split of {self.location!r}; it has "
                f"{', '.join(map(repr, self.splits)) or 'no splits'}"
            )
        self.indices = [i for i, s in source.rows if split is None or s == split]
        self._records: dict[int, dict] = {}
        if self.keys is not None and self.indices:
            self._check_stored(0)  # a key the dataset does not store: said now, not at item 0

    # what was opened is reopened after unpickling (fsspec filesystems and open files stay local)
    @property
    def _source(self) -> _Folder | _Export:
        source = self.__dict__.get("_source_obj")
        if source is None:
            source = self.__dict__["_source_obj"] = _open_source(self.location, self.verify)
        return source

    @property
    def _manifest(self) -> dict:
        return self._source.manifest

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_source_obj", None)
        return state

    def __len__(self) -> int:
        return len(self.indices)

    def __repr__(self) -> str:
        which = "" if self.split is None else f", split={self.split!r}"
        return f"<Dataset {self.location!r}: {len(self)} items{which}>"

    def set_epoch(self, epoch: int) -> None:
        """Set the epoch that transforms see (``transform.set_epoch(epoch)`` when it has one).

        With ``DataLoader(..., persistent_workers=False)`` (the default) call it before each
        epoch's loop: the workers take a copy of the dataset as it is then.

        Parameters
        ----------
        epoch : int
            A non-negative integer.
        """
        if isinstance(epoch, (bool, np.bool_)) or not isinstance(epoch, (int, np.integer)) or epoch < 0:
            raise ValueError(f"`epoch` must be a non-negative integer, got {epoch!r}")
        self.epoch = int(epoch)
        if hasattr(self.transform, "set_epoch"):
            self.transform.set_epoch(self.epoch)

    def _index(self, i: int) -> int:
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
            raise TypeError(f"a dataset's items are indexed by integers (`ds[i]`), got {type(i).__name__}")
        n = len(self.indices)
        if not -n <= i < n:
            raise IndexError(f"item {i} out of range for a dataset of {n} items")
        return self.indices[int(i)]

    def _record(self, index: int) -> dict:
        """The cached record of item ``index``, checked (never handed out: see :meth:`record`)."""
        if index not in self._records:
            record = self._source.record(index)
            if not isinstance(record, dict) or record.get("index") != index:
                raise DatasetError(f"item {index}: record.json is damaged: not the record of item {index}")
            if not isinstance(record.get("files"), dict):
                raise DatasetError(
                    f"item {index}: record.json is damaged: it has no `files` table (the item's files and hashes)"
                )
            self._records[index] = record
        return self._records[index]

    def record(self, i: int) -> dict:
        """The JSON record of ``ds[i]`` (a copy: changing it changes nothing here).

        Parameters
        ----------
        i : int
            Position in the dataset (``ds.indices[i]`` is the item's index).

        Returns
        -------
        dict
            The item's ``record.json``.
        """
        return copy.deepcopy(self._record(self._index(i)))

    @property
    def records(self) -> list[dict]:
        """Every item's record, in order (read on first use)."""
        return [self.record(i) for i in range(len(self))]

    def _check_stored(self, i: int) -> None:
        index = self._index(i)
        record = self._record(index)
        if isinstance(self._source, _Export):
            self._source.arrays(index, record, self.keys)  # raises naming what the export lacks
        else:
            missing = [k for k in self.keys if k in _FILE_OF and _FILE_OF[k][0] not in record["files"]]
            if missing:
                files = sorted({_FILE_OF[k][0] for k in missing})
                raise DatasetError(
                    f"`keys` {', '.join(map(repr, missing))}: item {index} of {self.location!r} has no "
                    f"{', '.join(files)} (its config makes no {'samples' if 'samples.npz' in files else 'AO'})"
                )

    def raw(self, i: int) -> dict[str, Any]:
        """``ds[i]`` before ``normalize``, ``dtype`` and ``transform``: the arrays as stored.

        Parameters
        ----------
        i : int
            Position in the dataset; negative positions count from the end.

        Returns
        -------
        dict
            The arrays of ``keys`` (default: ``vertices``, ``simplices``, ``ao`` and the
            ``samples.npz`` arrays when present), and ``record`` (unless ``keys`` leaves it out).
        """
        index = self._index(i)
        record = self._record(index)
        if self.keys is not None:
            self._check_stored(i)
        item: dict[str, Any] = self._source.arrays(index, record, self.keys)
        if self.keys is None or "record" in self.keys:
            item["record"] = copy.deepcopy(record)
        return item

    def __getitem__(self, i: int) -> Any:
        item = self.raw(i)
        index = self._index(i)
        if self.normalize and not self._manifest.get("normalized"):
            item = normalized(item, self._normalization(index))
        if self.dtype is not None:
            item = {
                k: v.astype(self.dtype) if isinstance(v, np.ndarray) and v.dtype.kind == "f" else v
                for k, v in item.items()
            }
        item["index"] = index
        return self.transform(item) if self.transform is not None else item

    def _normalization(self, index: int) -> tuple[np.ndarray, float]:
        norm = self._record(index).get("normalization")
        try:
            loc, scale = np.asarray(norm["loc"], np.float64), float(norm["scale"])
            ok = loc.shape == (4,) and np.isfinite(loc).all() and math.isfinite(scale) and scale > 0
        except (TypeError, KeyError, ValueError):
            ok = False
        if not ok:
            raise DatasetError(
                f"item {index}: record.json has no valid `normalization` (loc: 4 finite numbers, scale > 0), "
                "which `normalize=True` needs"
            )
        return loc, scale

    def frames(self, i: int) -> list[Any]:
        """The frames of item ``ds[i]``'s ``sequence.npz``.

        Parameters
        ----------
        i : int
            Position in the dataset of an item made with a ``sequence`` setting.

        Returns
        -------
        list of trimesh.Trimesh
            One per frame (``metadata["time"]`` in [0, 1]; with ``normalize``, in the
            normalised coordinates).

        Raises
        ------
        DatasetError
            The item has no sequence, or its sequence.npz lacks an array.
        """
        from .sequence import frames_of

        arrays = self._sequence(i)
        try:
            return frames_of(arrays)
        except KeyError as exc:
            raise DatasetError(f"item {self._index(i)}: sequence.npz is damaged: no array {exc}") from None

    def frame_samples(self, i: int) -> list[dict[str, Any]]:
        """The per-frame 3D learning samples of item ``ds[i]``'s ``sequence.npz``.

        Parameters
        ----------
        i : int
            Position in the dataset of an item made with ``sequence`` and ``samples`` settings.

        Returns
        -------
        list of dict
            One per frame, in the order of :meth:`frames`: ``points`` (K, 3) float32,
            ``occupancy`` (K,) bool, ``sdf`` (K,) float32, ``surface_points`` and
            ``surface_normals`` (M, 3) float32, ``surface_ao`` (M,) when the item has AO, and
            ``time``; in the frame's 3D coordinates (with ``normalize``, normalised as the
            frames' vertices, ``sdf`` divided by the scale).

        Raises
        ------
        DatasetError
            The item has no sequence, or its sequence has no samples (the config sets no
            ``samples``).
        """
        from .sequence import frame_samples_of

        try:
            out = frame_samples_of(self._sequence(i))
        except KeyError as exc:
            raise DatasetError(f"item {self._index(i)}: sequence.npz is damaged: no array {exc}") from None
        if not out:
            raise DatasetError(
                f"item {self._index(i)}: its sequence.npz has no frame samples (the config sets no `samples`)"
            )
        return out

    def _sequence(self, i: int) -> dict[str, np.ndarray]:
        """The arrays of ``ds[i]``'s ``sequence.npz``, normalised when asked."""
        index = self._index(i)
        record = self._record(index)
        if "sequence.npz" not in record["files"]:
            raise DatasetError(f"item {index} has no sequence.npz (the config sets no `sequence`)")
        arrays = self._source.sequence(index, record)
        if self.normalize and not self._manifest.get("normalized"):
            arrays = normalized_sequence(arrays, *self._normalization(index), index)
        return arrays


def normalized(item: dict[str, Any], normalization: tuple[np.ndarray, float] | None = None) -> dict[str, Any]:
    """``item`` with its normalisation applied (see :func:`load`'s ``normalize``).

    ``normalization`` is ``(loc, scale)``; default the item's ``record["normalization"]``.
    """
    if normalization is None:
        norm = item["record"]["normalization"]
        normalization = np.asarray(norm["loc"], np.float64), float(norm["scale"])
    loc, scale = normalization
    out = dict(item)
    for name in POINT_ARRAYS:
        if name in out:
            a = out[name]
            out[name] = ((a - loc) / scale).astype(a.dtype)
    if "sdf" in out:
        out["sdf"] = (out["sdf"] / scale).astype(out["sdf"].dtype)
    return out


def normalized_sequence(arrays: dict[str, np.ndarray], loc: np.ndarray, scale: float, index: int) -> dict:
    """A ``sequence.npz``'s arrays normalised as their item (a frame's point ``y`` is
    ``x = x0 + y @ basis`` with ``x0`` along the axis, so ``loc`` moves it by ``basis @ loc``)."""
    if "basis" not in arrays:
        raise DatasetError(f"item {index}: sequence.npz is damaged: no array 'basis'")
    out = dict(arrays)
    shift = arrays["basis"] @ loc
    for name in ("vertices", "frame_points", "frame_surface_points"):
        if name in out:
            a = out[name]
            out[name] = ((a - shift) / scale).astype(a.dtype)
    if "frame_sdf" in out:
        out["frame_sdf"] = (out["frame_sdf"] / scale).astype(np.float32)
    return out
