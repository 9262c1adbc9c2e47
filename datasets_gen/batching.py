"""Batches of dataset items: ``collate`` for ``DataLoader(..., collate_fn=datasets_gen.collate)``.

PyTorch's default collate stacks every entry and so fails on what differs in size between
items (meshes, per-vertex AO, the records). :func:`collate` stacks what can be stacked and
lists the rest, with numpy only (torch is never needed).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["collate"]


def collate(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One batch from a list of items (dicts, as :func:`datasets_gen.load` gives them).

    Parameters
    ----------
    batch : sequence of dict
        Items with the same keys.

    Returns
    -------
    dict
        For each key: a stacked array of shape ``(len(batch), ...)`` where every item's value
        is an array (or number) of one shape and dtype, else the list of the items' values
        (meshes of different sizes, records). ``torch.as_tensor`` turns a stacked array into a
        tensor without a copy.

    Raises
    ------
    ValueError
        An empty batch, or items with different keys.
    """
    if not batch:
        raise ValueError("`batch` is empty")
    if not isinstance(batch[0], dict):
        raise TypeError(
            f"`batch` holds items as dicts (as datasets_gen.load gives them), got {type(batch[0]).__name__}"
        )
    keys = list(batch[0])
    for n, item in enumerate(batch):
        if not isinstance(item, dict) or set(item) != set(keys):
            got = sorted(item) if isinstance(item, dict) else type(item).__name__
            raise ValueError(f"`batch` item {n} has keys {got}, item 0 {sorted(keys)}")
    out: dict[str, Any] = {}
    for key in keys:
        values = [item[key] for item in batch]
        arrays = [v for v in values if isinstance(v, (np.ndarray, np.generic, int, float, bool))]
        if len(arrays) == len(values):
            arrays = [np.asarray(v) for v in values]
            if all(a.shape == arrays[0].shape and a.dtype == arrays[0].dtype for a in arrays):
                out[key] = np.stack(arrays)
                continue
        out[key] = values
    return out
