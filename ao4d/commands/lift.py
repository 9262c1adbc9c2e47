"""``ao4d lift``: make a closed 4D mesh from 3D solids (:mod:`ao4d.lift`).

One sub-subcommand so far, ``sweep``: frames of a moving, deforming solid (one triangle mesh,
moved: same faces, same vertex count) become the boundary of its space-time solid, time as w.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._options import add_pair

HELP = "make a 4D mesh from 3D solids: sweep frames of a moving solid through time (w = t)"
EXAMPLES = """  ao4d lift sweep ball_*.ply --out bounce.npz               # frames at t = 0, 1, 2, ...
  ao4d lift sweep f0.obj f1.obj f2.obj --times 0 0.25 1 --out motion.npz
  ao4d lift sweep walk_0*.stl --times-range 0 2 --out walk.npz   # evenly over [0, 2]
  ao4d view bounce.npz --out bounce.html                      # then look at it
"""

# library parameters under the names the user typed (ao4d.cli replaces them in error messages)
PARAMETERS = {"frames": "FRAMES", "times": "--times"}

_SWEEP_HELP = "the space-time solid of 3D frames of one moving mesh (vertices move linearly between frames)"
_SWEEP_EXAMPLES = """  ao4d lift sweep ball_*.ply --out bounce.npz
  ao4d lift sweep f0.obj f1.obj f2.obj --times 0 0.25 1 --out motion.npz
  ao4d lift sweep walk_0*.stl --times-range 0 2 --out walk.npz

Frames are used in the order given. A shell pattern expands in the shell's order (f10 before f2):
name frames with zero-padded numbers (a warning says when the order is not the names' numeric
order). The first and last frames must be star-shaped (e.g. convex): they become the caps.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="lift_kind", metavar="KIND", required=True)
    sweep = sub.add_parser(
        "sweep",
        help=_SWEEP_HELP,
        description=_SWEEP_HELP,
        epilog="examples:\n" + _SWEEP_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sweep.add_argument(
        "frames", nargs="+", type=Path, metavar="FRAMES", help="3D meshes (.ply, .obj, .stl, ...), at least 2"
    )
    when = sweep.add_mutually_exclusive_group()
    when.add_argument(
        "--times",
        type=float,
        nargs="+",
        metavar="T",
        help="one time per frame, strictly increasing (default 0 1 2 ...)",
    )
    add_pair(
        when,
        "--times-range",
        metavar=("START", "STOP"),
        help="frames evenly spaced in time from START to STOP (both included)",
    )
    sweep.add_argument("--out", required=True, type=Path, metavar="MESH.npz", help="output mesh (.npz, .vtu or .txt)")
    # accepted after the kind as well (``ao4d lift sweep ... --no-progress``); sweep shows no progress
    sweep.add_argument("--no-progress", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)


def run(args: argparse.Namespace) -> int:
    from .._atomic import check_output_file
    from ..io.mesh_files import SUFFIXES

    check_output_file(args.out, "--out", SUFFIXES)  # before any work
    return _sweep(args)


def _sweep(args: argparse.Namespace) -> int:
    import numpy as np

    from .. import lift
    from .._validate import as_real

    frames = list(args.frames)
    if frames != sorted(frames, key=_natural_key):
        print(
            "ao4d lift sweep: warning: FRAMES are not in the numeric order of their names "
            "(used as given; a shell pattern puts f10 before f2)",
            file=sys.stderr,
        )
    times = args.times
    if args.times_range is not None:
        start = as_real(args.times_range[0], "--times-range START")
        stop = as_real(args.times_range[1], "--times-range STOP")
        if not stop > start:
            raise ValueError(f"`--times-range` needs START < STOP, got {start:g} {stop:g}")
        times = np.linspace(start, stop, len(frames))
    mesh = lift.sweep(frames, times)
    mesh.save(args.out)  # atomic (ao4d.io.mesh_files)
    t = np.arange(len(frames), dtype=float) if times is None else np.asarray(times, dtype=float)
    report = mesh.check()
    print(
        f"sweep: {len(frames)} frames, t = {t[0]:g} .. {t[-1]:g}; {mesh.n_vertices:,} vertices, "
        f"{mesh.n_simplices:,} tetrahedra, closed={report.closed}, 4-volume {mesh.volume:.6g}; wrote {args.out}"
    )
    return 0


def _natural_key(path: Path) -> list:
    """Sort key of a file name with runs of digits compared as numbers: f2 before f10."""
    import re

    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", str(path))]
