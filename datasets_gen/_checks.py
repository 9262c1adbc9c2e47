"""Checks shared by the configuration reader and the settings it delegates (samples, sequence)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

__all__ = ["check_keys"]


def check_keys(table: dict[str, Any], allowed: Iterable[str], where: str) -> None:
    """Refuse keys of ``table`` outside ``allowed``.

    Parameters
    ----------
    table : dict
        The table read.
    allowed : iterable of str
        The keys it may hold.
    where : str
        How messages name the table (```samples```, ``[defaults]``...).

    Raises
    ------
    ValueError
        Naming ``where``, the unknown keys and the allowed ones.
    """
    allowed = set(allowed)
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(sorted(allowed))}"
        )
