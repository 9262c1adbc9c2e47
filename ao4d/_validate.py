"""Shared input validation: every public function checks its inputs here, naming the parameter."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

__all__ = ["as_array", "as_finite_float", "check_choice", "check_positive_int", "check_finite", "check_memory"]

# Refuse allocations above this many bytes before starting work (overridable per call).
DEFAULT_MEMORY_LIMIT = 16 * 2**30


def as_array(
    value: Any,
    name: str,
    *,
    ndim: int | Iterable[int] | None = None,
    shape_tail: tuple[int | None, ...] | None = None,
    dtype: Any = None,
    finite: bool = False,
    min_size: int = 0,
) -> np.ndarray:
    """Convert an array-like to ndarray and check its dimensions, trailing shape and values.

    Parameters
    ----------
    value : array_like
        The input.
    name : str
        Parameter name used in error messages.
    ndim : int or iterable of int, optional
        Allowed numbers of dimensions.
    shape_tail : tuple of (int or None), optional
        Required trailing shape; ``None`` entries match anything.
    dtype : dtype, optional
        Convert to this dtype.
    finite : bool
        Require every value to be finite.
    min_size : int
        Minimum number of elements.
    """
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"`{name}` must be array-like of numbers: {exc}") from None
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            words = " or ".join(f"{k}D" for k in allowed)
            raise ValueError(f"`{name}` must be a {words} array, got shape {arr.shape}")
    if shape_tail is not None:
        tail = arr.shape[arr.ndim - len(shape_tail):] if arr.ndim >= len(shape_tail) else None
        if tail is None or any(want is not None and got != want for got, want in zip(tail, shape_tail)):
            want_s = "(..., " + ", ".join("*" if w is None else str(w) for w in shape_tail) + ")"
            raise ValueError(f"`{name}` must have shape {want_s}, got {arr.shape}")
    if arr.size < min_size:
        raise ValueError(f"`{name}` must have at least {min_size} elements, got {arr.size}")
    if finite:
        check_finite(arr, name)
    return arr


def check_finite(arr: np.ndarray, name: str) -> None:
    """Raise ``ValueError`` naming ``name`` if ``arr`` holds NaN or infinity."""
    if arr.dtype.kind in "fc" and not np.isfinite(arr).all():
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"`{name}` contains {bad} non-finite value(s) (NaN or inf)")


def as_finite_float(value: Any, name: str) -> float:
    """Return ``value`` as a finite float, else raise naming ``name`` (TypeError / ValueError)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"`{name}` must be a real number, got {type(value).__name__}") from None
    if not math.isfinite(number):
        raise ValueError(f"`{name}` must be finite, got {value!r}")
    return number


def check_choice(value: Any, name: str, choices: Iterable[Any]) -> Any:
    """Return ``value`` if it is one of ``choices``, else raise ``ValueError`` listing them."""
    choices = tuple(choices)
    if value not in choices:
        raise ValueError(f"`{name}` must be one of {', '.join(map(repr, choices))}; got {value!r}")
    return value


def check_positive_int(value: Any, name: str, *, minimum: int = 1) -> int:
    """Return ``value`` as int if it is an integer >= ``minimum``, else raise naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"`{name}` must be an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"`{name}` must be >= {minimum}, got {value}")
    return int(value)


def check_memory(
    nbytes: float, what: str, *, limit: float = DEFAULT_MEMORY_LIMIT, hint: str = "use a smaller size"
) -> None:
    """Refuse work needing more than ``limit`` bytes, saying how much it would need and what to do."""
    if nbytes > limit:
        raise MemoryError(
            f"{what} would need about {nbytes / 2**30:.1f} GiB, above the limit of "
            f"{limit / 2**30:.1f} GiB; {hint}"
        )
