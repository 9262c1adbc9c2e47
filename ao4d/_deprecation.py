"""Renamed parameters: the one way an old keyword spelling keeps working, with a warning.

A public function whose parameter was renamed keeps the old name as its last keyword-only
parameter, defaulting to :data:`DEPRECATED` and documented as the old spelling, and its first line
of work is ``new = renamed("func", "old", old, "new", new, default)``: a call that spells
``old=`` gets the value as ``new`` and a :class:`DeprecationWarning` that names the new
spelling, pointing at the caller's line; giving both is a :class:`TypeError`. (A wrapping
decorator would hide the old name from the signature, but it adds a frame that shifts every
other warning the function raises away from the caller's line.)
"""

from __future__ import annotations

import warnings
from typing import Any

__all__ = ["DEPRECATED", "renamed"]


class _Deprecated:
    """The default of an old parameter name: "not given"."""

    def __repr__(self) -> str:
        return "<deprecated>"


DEPRECATED: Any = _Deprecated()


def renamed(func: str, old: str, old_value: Any, new: str, new_value: Any, default: Any, *, stacklevel: int = 3) -> Any:
    """The value of parameter ``new``, taken from its old spelling ``old`` when that was given.

    Parameters
    ----------
    func : str
        The public function's name, for the messages.
    old, new : str
        The old and the new parameter name.
    old_value : object
        The old parameter's value (:data:`DEPRECATED` when not given).
    new_value : object
        The new parameter's value.
    default : object
        The new parameter's default: a ``new_value`` that is not it means both were given.
    stacklevel : int
        Frames above this call to point the warning at (3: the public function's caller).

    Returns
    -------
    object
        ``old_value`` when the old spelling was given, else ``new_value``.

    Raises
    ------
    TypeError
        Both spellings were given.
    """
    if old_value is DEPRECATED:
        return new_value
    if new_value is not default:
        raise TypeError(f"{func}() got both `{new}` and its old spelling `{old}`; give only `{new}`")
    warnings.warn(
        f"{func}(): the parameter `{old}` is now called `{new}`; `{old}=` will stop working in a future release",
        DeprecationWarning,
        stacklevel=stacklevel,
    )
    return old_value
