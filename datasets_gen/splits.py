"""Fixed train/val/test splits: ``split = { train = 0.8, val = 0.1, test = 0.1 }`` in a config.

Item ``i`` of a run with seed ``s`` gets the split whose cumulative interval holds
``u_i = frac(x_s + (i + 1) * g)``, with ``g = (sqrt(5) - 1) / 2`` and ``x_s`` uniform in [0, 1)
drawn from ``SeedSequence([s, SPLIT_TAG])``. So a split depends only on the seed and the index
(never on the worker count or the order items are made in), and the golden-ratio sequence is
equidistributed on every run of consecutive indices: each family (a block of consecutive
indices) gets its fractions to within one or two items, where independent draws would often
leave a small split empty.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["check_split", "split_of", "split_counts", "empty_splits", "SPLIT_TAG"]

SPLIT_TAG = 0x5911  # keeps the split's draw apart from the items' own seed sequences
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def check_split(value: Any) -> dict[str, float]:
    """The validated split table (name -> fraction, in the order given).

    Raises ``ValueError`` naming the bad entry: not a table, a name that is not an identifier,
    a fraction that is not a number in [0, 1], or fractions that do not sum to 1 (within 1e-9).
    """
    if not isinstance(value, dict) or not value:
        raise ValueError(
            f"`split` must be a table of name = fraction, e.g. {{ train = 0.8, val = 0.1, test = 0.1 }}, got {value!r}"
        )
    out: dict[str, float] = {}
    for name, frac in value.items():
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"`split` names must be identifiers, got {name!r}")
        if isinstance(frac, bool) or not isinstance(frac, (int, float)) or not 0 <= frac <= 1:
            raise ValueError(f"`split.{name}` must be a number in [0, 1], got {frac!r}")
        out[name] = float(frac)
    total = math.fsum(out.values())
    if abs(total - 1.0) > 1e-9:
        raise ValueError(
            f"`split` fractions must sum to 1, got {total!r} ({' + '.join(f'{k} = {v:g}' for k, v in out.items())})"
        )
    return out


def _start(seed: int) -> float:
    """``x_s``: the run's offset of the golden-ratio sequence."""
    return float(np.random.default_rng(np.random.SeedSequence([int(seed), SPLIT_TAG])).random())


def split_of(split: dict[str, float] | None, seed: int, index: int) -> str | None:
    """The split of item ``index`` of a run with ``seed`` (``None`` without a split table)."""
    if not split:
        return None
    u = math.fmod(_start(seed) + (int(index) + 1) * _GOLDEN, 1.0)
    edge = 0.0
    names = list(split)
    for name in names:
        edge += split[name]
        if u < edge:
            return name
    return [n for n in names if split[n] > 0][-1]  # u within rounding of 1


def split_counts(split: dict[str, float], seed: int, n_items: int) -> dict[str, int]:
    """How many of the items ``0 .. n_items - 1`` of a run with ``seed`` each split gets.

    Every name of ``split`` is a key, in the table's order, a split that gets no item with 0.
    The same assignment as :func:`split_of` (the same float64 arithmetic, element by element),
    without a generator per item: a million items take a fraction of a second.

    Parameters
    ----------
    split : dict of str to float
        The validated split table (:func:`check_split`).
    seed : int
        The run's seed.
    n_items : int
        The run's item count.

    Returns
    -------
    dict of str to int
        Split name -> item count.
    """
    names = list(split)
    if not names:
        return {}
    u = np.fmod(_start(seed) + (np.arange(int(n_items), dtype=np.float64) + 1.0) * _GOLDEN, 1.0)
    edges, edge = [], 0.0
    for name in names:  # summed in the table's order, as split_of sums them
        edge += split[name]
        edges.append(edge)
    slot = np.searchsorted(np.asarray(edges), u, side="right")  # first edge > u
    last = max(i for i, name in enumerate(names) if split[name] > 0)  # u within rounding of 1
    slot = np.where(slot >= len(names), last, slot)
    counts = np.bincount(slot, minlength=len(names))
    return {name: int(counts[i]) for i, name in enumerate(names)}


def empty_splits(counts: dict[str, int]) -> list[str]:
    """The names that get no item, in the table's order (``counts``: :func:`split_counts`; a
    fraction of 0, or one too small for so few items)."""
    return [name for name, count in counts.items() if count == 0]
