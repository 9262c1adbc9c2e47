"""``ao4d lut``: build, verify and describe the marching lookup tables in ``lut/``."""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

# the library's parameters that options become under another name (errors name the option)
PARAMETERS = {"folder": "--dir"}

HELP = "build, verify or describe the marching lookup tables (d-cubes and Kuhn simplices)"
EXAMPLES = """  ao4d lut verify                 checksums, then rebuild and compare every shipped table
  ao4d lut stats --dim 4          entries, symmetry classes, tets per entry, build time
  ao4d lut build --out /tmp/lut   regenerate all tables into a folder (atomic writes)
  ao4d lut build --dim 3 --kind cube
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..marching.lut import DIMS, KINDS

    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)

    def common(sub: argparse.ArgumentParser) -> None:
        sub.add_argument(
            "--dim",
            type=int,
            action="append",
            choices=DIMS,
            metavar="D",
            help="dimension 2, 3 or 4 (repeatable; default: all)",
        )
        sub.add_argument(
            "--kind",
            action="append",
            choices=KINDS,
            help="cell type (repeatable; default: both)",
        )

    build = actions.add_parser("build", help="generate tables and manifest.json (default folder: the shipped lut/)")
    common(build)
    build.add_argument("--out", metavar="DIR", help="output folder (default: the shipped lut/)")

    verify = actions.add_parser("verify", help="check checksums, rebuild and compare; exit code 1 on any mismatch")
    common(verify)
    verify.add_argument("--dir", metavar="DIR", help="table folder (default: the shipped lut/)")
    verify.add_argument("--no-rebuild", action="store_true", help="only check checksums (skip the rebuild)")

    stats = actions.add_parser("stats", help="print entries, classes and simplex counts")
    common(stats)
    stats.add_argument(
        "--repeat",
        type=int,
        default=1,
        metavar="N",
        help="time the build N times and report the median (default: 1)",
    )


def run(args: argparse.Namespace) -> int:
    from ..marching import lut

    dims = tuple(args.dim) if args.dim else lut.DIMS
    kinds = tuple(args.kind) if args.kind else lut.KINDS
    if args.action == "build":
        return _build(lut, dims, kinds, args.out)
    if args.action == "verify":
        return _verify(lut, dims, kinds, args.dir, rebuild=not args.no_rebuild)
    return _stats(lut, dims, kinds, repeat=args.repeat)


def _build(lut, dims, kinds, out) -> int:
    from .._resources import data_dir

    folder = out if out is not None else data_dir("lut")
    seconds = lut.write_tables(folder, dims, kinds)
    for name, took in seconds.items():
        print(f"wrote {folder}/{name}  ({took:.2f} s)")
    print(f"wrote {folder}/manifest.json")
    return 0


def _verify(lut, dims, kinds, folder, *, rebuild: bool) -> int:
    report = lut.verify(folder, dims, kinds, rebuild=rebuild)
    for line in report.lines:
        print(line)
    if report.ok:
        _stats(lut, dims, kinds, repeat=0, folder=folder)
    print("lookup tables: OK" if report.ok else "lookup tables: MISMATCH", file=sys.stderr)
    return 0 if report.ok else 1


def _stats(lut, dims, kinds, *, repeat: int, folder=None) -> int:
    if repeat < 0:
        raise ValueError(f"`--repeat` must be >= 0, got {repeat}")
    header = (
        f"{'dim':>3} {'kind':<7} {'entries':>7} {'group':>5} {'classes':>7} {'+compl':>6} "
        f"{'simplices':>9} {'max':>4} {'mean':>7}" + ("  build (s)" if repeat else "")
    )
    print(header)
    for dim in dims:
        for kind in kinds:
            if folder is None:
                table = lut.load(dim, kind)
            else:
                table = lut.read(Path(folder) / lut.table_filename(dim, kind))
            s = lut.stats(table)
            line = (
                f"{s.dim:>3} {s.kind:<7} {s.entries:>7} {s.group_order:>5} {s.classes:>7} "
                f"{s.classes_with_complement:>6} {s.simplices:>9} {s.max_per_entry:>4} "
                f"{s.mean_per_entry:>7.3f}"
            )
            if repeat:
                line += f"  {_median_build_time(lut, dim, kind, repeat):9.3f}"
            print(line)
    sys.stdout.flush()
    return 0


def _median_build_time(lut, dim: int, kind: str, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        lut.build(dim, kind, progress=False)
        times.append(time.perf_counter() - start)
    return statistics.median(times)
