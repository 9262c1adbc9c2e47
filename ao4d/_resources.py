"""Locate the shipped data folders (``lut/`` and ``kernels/``).

A wheel carries them inside the package as ``ao4d/_data/<name>``; a source checkout or an
editable install keeps them at the top of the repository. Both are looked up here, once.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

__all__ = ["data_dir"]

_PACKAGE_DIR = Path(__file__).resolve().parent


@cache
def data_dir(name: str) -> Path:
    """Return the folder holding the shipped data ``name`` (``"lut"`` or ``"kernels"``).

    Raises
    ------
    FileNotFoundError
        If neither the wheel location nor the source-tree location exists.
    """
    candidates = (_PACKAGE_DIR / "_data" / name, _PACKAGE_DIR.parent / name)
    for folder in candidates:
        if folder.is_dir():
            return folder
    raise FileNotFoundError(f"ao4d data folder {name!r} not found; looked in " + ", ".join(map(str, candidates)))
