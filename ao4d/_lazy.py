"""A subpackage's public face, loaded lazily (PEP 562): its names come from its modules on first use.

``import ao4d.<subpackage>`` then stays as cheap as ``import ao4d``: no numpy, no pyopencl until a
name is used.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_face"]


def lazy_face(package: str, exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``, whose names are ``exports``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : dict of str to str
        Public name -> ``"module:attribute"``, the module relative to ``package``.

    Returns
    -------
    getattr : callable
        Loads a public name from its module on first use and keeps it in the package.
    dir : callable
        The public names and the module's dunder names (``__all__``, ``__doc__``, ...), sorted.
    """

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module_name, _, attr = exports[name].partition(":")
        value = getattr(importlib.import_module(f".{module_name}", package), attr)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        dunders = (name for name in vars(sys.modules[package]) if name.startswith("__"))
        return sorted({*exports, *dunders})

    return __getattr__, __dir__
