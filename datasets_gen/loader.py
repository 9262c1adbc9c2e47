"""Read a dataset back: ``datasets_gen.load(path_or_url) -> Dataset`` (map-style, for training).

>>> ds = load("data/tori", split="train", normalize=True)     # doctest: +SKIP
>>> item = ds[0]          # vertices, simplices, ao, points, occupancy, sdf, ..., record
>>> frames = ds.frames(0) # the item's sequence.npz as trimesh.Trimesh frames
>>> ds.frame_samples(0)[3]["occupancy"]  # frame 3's labelled 3D points   # doctest: +SKIP

A :class:`Dataset` holds only the folder's address, the item list (from ``items.csv``) and the
manifest; each ``ds[i]`` reads that item's files when asked (a local folder or any fsspec URL,
through :mod:`datasets_gen._store`). It pickles (its store is rebuilt from the address), so
``torch.utils.data.DataLoader(ds, num_workers=2)`` and process pools work.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import zipfile
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np

from ._store import Store, open_store
from .items import item_folder

__all__ = ["load", "Dataset", "DatasetError", "POINT_ARRAYS"]

#: arrays holding 4D points (moved by ``normalize``); ``sdf`` is a length (scaled)
POINT_ARRAYS = ("vertices", "points", "surface_points")
_ITEM_FILES = ("mesh.npz", "ao.npz", "samples.npz")


class DatasetError(ValueError):
    """A dataset folder is missing, incomplete, or a file fails its checksum (the message names
    the item and the file)."""


def load(
    path_or_url: str | os.PathLike,
    *,
    split: str | None = None,
    verify: bool = False,
    normalize: bool = False,
    transform: Callable[[dict], Any] | None = None,
) -> Dataset:
    """Open the dataset made by ``python -m datasets_gen CONFIG --out PATH`` at ``path_or_url``.

    Parameters
    ----------
    path_or_url : path or str
        The run's output folder, or an fsspec URL (``s3://bucket/run``, ``file:///...``).
    split : str, optional
        Only the items of this split (the config's ``split`` table); ``None``: every item.
    verify : bool
        Check each file's sha256 against ``manifest.json`` before it is used; a mismatch raises
        :class:`DatasetError` naming the item and the file.
    normalize : bool
        Apply the item's ``record["normalization"]``: ``(x - loc) / scale`` on every point array
        (:data:`POINT_ARRAYS`) and ``sdf / scale``; normals and occupancy are unchanged.
    transform : callable, optional
        Called on each item's dict; ``ds[i]`` returns its result.

    Returns
    -------
    Dataset
        The items, read lazily.

    Raises
    ------
    DatasetError
        No ``manifest.json``/``items.csv`` there, or ``split`` names no split of the dataset.
    """
    return Dataset(path_or_url, split=split, verify=verify, normalize=normalize, transform=transform)


class Dataset:
    """The items of a dataset folder, read lazily; see :func:`load`.

    ``len(ds)`` items; ``ds[i]`` a dict of numpy arrays (``vertices``, ``simplices``, ``ao`` when
    present, the ``samples.npz`` arrays when present) plus ``record`` (the item's JSON record);
    ``ds.records`` every record; ``ds.frames(i)`` the item's sequence frames and
    ``ds.frame_samples(i)`` their 3D samples; ``ds.indices`` the
    dataset indices of the items (``ds[i]`` is item ``ds.indices[i]``).

    Parameters
    ----------
    path_or_url : path or str
        The run's output folder or URL (:func:`load`).
    split : str, optional
        Only the items of this split.
    verify : bool
        Check each file's sha256 against the manifest before use.
    normalize : bool
        Apply each item's ``record["normalization"]``.
    transform : callable, optional
        Called on each item's dict.
    """

    def __init__(
        self,
        path_or_url: str | os.PathLike,
        *,
        split: str | None = None,
        verify: bool = False,
        normalize: bool = False,
        transform: Callable[[dict], Any] | None = None,
    ) -> None:
        if transform is not None and not callable(transform):
            raise TypeError(f"`transform` must be callable, got {type(transform).__name__}")
        self.location = str(path_or_url) if isinstance(path_or_url, str) else os.fspath(path_or_url)
        self.verify, self.normalize, self.transform, self.split = bool(verify), bool(normalize), transform, split
        store = self._store
        try:
            self._manifest = json.loads(store.read_text("manifest.json"))
            rows = list(csv.DictReader(io.StringIO(store.read_text("items.csv"))))
        except (OSError, ValueError) as exc:
            raise DatasetError(
                f"`path_or_url` {self.location!r} holds no readable dataset "
                f"(manifest.json and items.csv of a datasets_gen run): {exc}"
            ) from None
        splits = sorted({r.get("split") or "" for r in rows} - {""})
        if split is not None and split not in splits:
            raise DatasetError(
                f"`split` {split!r} is not a split of {self.location!r}; it has "
                f"{', '.join(map(repr, splits)) or 'no splits'}"
            )
        self.indices = [int(r["index"]) for r in rows if split is None or r.get("split") == split]
        self._records: dict[int, dict] = {}

    # the store is rebuilt after unpickling (fsspec filesystems and open files stay local)
    @property
    def _store(self) -> Store:
        store = self.__dict__.get("_store_obj")
        if store is None:
            store = self.__dict__["_store_obj"] = open_store(self.location, "path_or_url")
        return store

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_store_obj", None)
        return state

    def __len__(self) -> int:
        return len(self.indices)

    def __repr__(self) -> str:
        which = "" if self.split is None else f", split={self.split!r}"
        return f"<Dataset {self.location!r}: {len(self)} items{which}>"

    def _index(self, i: int) -> int:
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
            raise TypeError(f"dataset indices are integers, got {type(i).__name__}")
        n = len(self.indices)
        if not -n <= i < n:
            raise IndexError(f"item {i} out of range for a dataset of {n} items")
        return self.indices[int(i)]

    def _read(self, index: int, name: str) -> bytes:
        rel = f"{item_folder(index)}/{name}"
        try:
            data = self._store.read_bytes(rel)
        except OSError as exc:
            raise DatasetError(f"item {index}: cannot read {name} ({rel}): {exc}") from None
        if self.verify:
            entry = self._manifest.get("files", {}).get(rel)
            if entry is None:
                raise DatasetError(f"item {index}: {name} ({rel}) is not in manifest.json")
            if hashlib.sha256(data).hexdigest() != entry["sha256"]:
                raise DatasetError(
                    f"item {index}: {name} ({rel}) fails its checksum: sha256 "
                    f"{hashlib.sha256(data).hexdigest()} != manifest "
                    f"{entry['sha256']}"
                )
        return data

    def _npz(self, index: int, name: str) -> dict[str, np.ndarray]:
        data = self._read(index, name)
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (zipfile.BadZipFile, zlib.error, ValueError, EOFError, OSError, KeyError) as exc:
            raise DatasetError(f"item {index}: {name} is damaged: {type(exc).__name__}: {exc}") from None

    def record(self, i: int) -> dict:
        """The JSON record of ``ds[i]``.

        Parameters
        ----------
        i : int
            Position in the dataset (``ds.indices[i]`` is the item's index).

        Returns
        -------
        dict
            The item's ``record.json``.
        """
        index = self._index(i)
        if index not in self._records:
            try:
                self._records[index] = json.loads(self._read(index, "record.json"))
            except ValueError as exc:
                raise DatasetError(f"item {index}: record.json is not valid JSON: {exc}") from None
        return self._records[index]

    @property
    def records(self) -> list[dict]:
        """Every item's record, in order (read on first use)."""
        return [self.record(i) for i in range(len(self))]

    def raw(self, i: int) -> dict[str, Any]:
        """``ds[i]`` before ``normalize`` and ``transform``: the files' arrays, as stored.

        Parameters
        ----------
        i : int
            Position in the dataset; negative positions count from the end.

        Returns
        -------
        dict
            ``vertices``, ``simplices``, ``ao`` and the ``samples.npz`` arrays when present,
            and ``record``.
        """
        index = self._index(i)
        record = self.record(i)
        listed = record.get("files", {})
        item: dict[str, Any] = {}
        mesh = self._npz(index, "mesh.npz")
        item["vertices"], item["simplices"] = mesh["vertices"], mesh["simplices"]
        if "ao.npz" in listed:
            item["ao"] = self._npz(index, "ao.npz")["occlusion"]
        if "samples.npz" in listed:
            item.update(self._npz(index, "samples.npz"))
        item["record"] = record
        return item

    def __getitem__(self, i: int) -> Any:
        item = self.raw(i)
        if self.normalize:
            item = normalized(item)
        return self.transform(item) if self.transform is not None else item

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
            The item has no sequence.
        """
        from .sequence import frames_of

        return frames_of(self._sequence(i))

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

        out = frame_samples_of(self._sequence(i))
        if not out:
            raise DatasetError(
                f"item {self._index(i)}: its sequence.npz has no frame samples (the config sets no `samples`)"
            )
        return out

    def _sequence(self, i: int) -> dict[str, np.ndarray]:
        """The arrays of ``ds[i]``'s ``sequence.npz``, normalised when asked."""
        index = self._index(i)
        record = self.record(i)
        if "sequence.npz" not in record.get("files", {}):
            raise DatasetError(f"item {index} has no sequence.npz (the config sets no `sequence`)")
        arrays = self._npz(index, "sequence.npz")
        if self.normalize:  # a frame's point y is x = x0 + y @ basis with x0 along the axis
            loc, scale = np.asarray(record["normalization"]["loc"]), float(record["normalization"]["scale"])
            shift = arrays["basis"] @ loc
            for name in ("vertices", "frame_points", "frame_surface_points"):
                if name in arrays:
                    a = arrays[name]
                    arrays[name] = ((a - shift) / scale).astype(a.dtype)
            if "frame_sdf" in arrays:
                arrays["frame_sdf"] = (arrays["frame_sdf"] / scale).astype(np.float32)
        return arrays


def normalized(item: dict[str, Any]) -> dict[str, Any]:
    """``item`` with its record's normalisation applied (see :func:`load`'s ``normalize``)."""
    norm = item["record"]["normalization"]
    loc, scale = np.asarray(norm["loc"], np.float64), float(norm["scale"])
    out = dict(item)
    for name in POINT_ARRAYS:
        if name in out:
            a = out[name]
            out[name] = ((a - loc) / scale).astype(a.dtype)
    if "sdf" in out:
        out["sdf"] = (out["sdf"] / scale).astype(out["sdf"].dtype)
    return out
