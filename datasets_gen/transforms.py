"""Transforms for :func:`datasets_gen.load`'s ``transform=``: fixed-size items for batching.

>>> from datasets_gen.transforms import SubsamplePoints
>>> ds = load("data/occ", split="train", dtype="float32",
...           transform=SubsamplePoints(points=2048, surface=512))   # doctest: +SKIP
>>> loader = torch.utils.data.DataLoader(ds, batch_size=4, shuffle=True, num_workers=2)  # doctest: +SKIP
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

__all__ = ["SubsamplePoints", "POINT_ROWS", "SURFACE_ROWS"]

#: the arrays with one row per labelled point (subsampled together)
POINT_ROWS = ("points", "occupancy", "sdf")
#: the arrays with one row per surface sample (subsampled together)
SURFACE_ROWS = ("surface_points", "surface_normals", "surface_ao")
_TAG = 0x5B5A  # keeps the subsampling's draws apart from the items' own seed sequences


def _count(value: Any, name: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise ValueError(f"`{name}` must be a positive integer (rows per item) or None, got {value!r}")
    return int(value)


class SubsamplePoints:
    """Pick a fixed number of rows of an item's samples, so that items batch by stacking.

    The rows are drawn without replacement from ``np.random.SeedSequence([seed, TAG, index,
    epoch])``: the same for a given seed, item and epoch (whatever the worker or the order),
    different across epochs (:meth:`datasets_gen.Dataset.set_epoch` sets it). An item with
    fewer rows than asked is sampled with replacement (a warning says so, once per transform).

    The result holds the subsampled arrays (:data:`POINT_ROWS` and :data:`SURFACE_ROWS` that the
    item has), ``index``, and ``loc`` (4,) and ``scale`` () from the record's normalisation
    when the item has its record; the mesh, per-vertex AO and the record, whose sizes differ
    between items, are left out, so PyTorch's default collate stacks a batch
    (:func:`datasets_gen.collate` keeps them, as lists).

    Parameters
    ----------
    points : int, optional
        Rows of ``points``, ``occupancy``, ``sdf`` per item; ``None`` leaves them out.
    surface : int, optional
        Rows of ``surface_points``, ``surface_normals``, ``surface_ao``; ``None`` leaves
        them out.
    seed : int
        Seed of the draws (non-negative).

    Raises
    ------
    ValueError
        A count that is not a positive integer or None (both None is refused too), a negative
        seed; when called, an item that has none of the arrays asked for.
    """

    def __init__(self, points: int | None = 2048, surface: int | None = None, seed: int = 0):
        self.points, self.surface = _count(points, "points"), _count(surface, "surface")
        if self.points is None and self.surface is None:
            raise ValueError("`points` and `surface` are both None: ask for rows of at least one")
        if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"`seed` must be a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self.epoch = 0
        self._warned = False

    def __repr__(self) -> str:
        return f"SubsamplePoints(points={self.points}, surface={self.surface}, seed={self.seed})"

    def set_epoch(self, epoch: int) -> None:
        """Draw the rows of epoch ``epoch`` from now on (:meth:`datasets_gen.Dataset.set_epoch`).

        Parameters
        ----------
        epoch : int
            The epoch (a non-negative integer).
        """
        self.epoch = int(epoch)

    def _rows(self, rng: np.random.Generator, n: int, k: int, index: int, group: str) -> np.ndarray:
        if n == 0:
            raise ValueError(f"item {index} has no {group} rows to subsample")
        if n >= k:
            return np.sort(rng.choice(n, k, replace=False))
        if not self._warned:
            self._warned = True
            warnings.warn(
                f"SubsamplePoints: item {index} has {n} {group} rows, fewer than the {k} asked; such items "
                "are sampled with replacement (said once)",
                stacklevel=3,
            )
        return np.sort(rng.choice(n, k, replace=True))

    def __call__(self, item: dict[str, Any]) -> dict[str, Any]:
        """The fixed-size item of ``item``.

        Parameters
        ----------
        item : dict
            An item as :func:`datasets_gen.load` gives it (with ``index``, or its ``record``).

        Returns
        -------
        dict
            The subsampled arrays, ``index``, and ``loc`` and ``scale`` when the item has its
            record.
        """
        if "index" in item:
            index = int(item["index"])
        elif "record" in item:
            index = int(item["record"]["index"])
        else:
            raise ValueError("SubsamplePoints needs the item's `index` (as datasets_gen.load gives it)")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, _TAG, index, self.epoch]))
        out: dict[str, Any] = {}
        for k, names, group in ((self.points, POINT_ROWS, "point"), (self.surface, SURFACE_ROWS, "surface")):
            if k is None:
                continue
            present = [n for n in names if n in item]
            if not present:
                raise ValueError(
                    f"item {index} has none of {', '.join(names)}: load it with those keys (its config needs samples)"
                )
            rows = self._rows(rng, len(item[present[0]]), k, index, group)
            for name in present:
                out[name] = item[name][rows]
        out["index"] = index
        norm = item.get("record", {}).get("normalization") if isinstance(item.get("record"), dict) else None
        if norm is not None:  # in the points' precision, as load(dtype=) cast them
            first = next((v for v in out.values() if isinstance(v, np.ndarray) and v.dtype.kind == "f"), None)
            dtype = first.dtype if first is not None else np.dtype(np.float64)
            out["loc"] = np.asarray(norm["loc"], dtype)
            out["scale"] = np.asarray(norm["scale"], dtype)
        return out
