"""Options that several ``ao4d`` commands take, declared once (each command gives its own help)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..opencl.cl import BACKENDS


def add_meshes(parser: argparse.ArgumentParser, *, metavar: str, help: str) -> None:
    """The positional input files, one or more, as ``args.meshes`` (a list of paths)."""
    parser.add_argument("meshes", nargs="+", type=Path, metavar=metavar, help=help)


def add_backend(parser: argparse.ArgumentParser, *, help: str | None = None) -> None:
    """``--backend {auto, opencl, numpy}`` (default auto), as ``args.backend``."""
    parser.add_argument("--backend", choices=BACKENDS, default="auto", help=help)


def add_force(parser: argparse.ArgumentParser, *, help: str) -> None:
    """``--force``: go on although the estimate is above the command's time limit."""
    parser.add_argument("--force", action="store_true", help=help)


def add_pair(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, flag: str, *, metavar: tuple[str, str], help: str
) -> None:
    """An option of two numbers (a range, or a box's two bounds), as a list of two floats."""
    parser.add_argument(flag, type=float, nargs=2, metavar=metavar, help=help)
