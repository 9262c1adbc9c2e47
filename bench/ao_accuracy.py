"""Benchmark: AO accuracy against time, fixed samples against ``tolerance``.

Run ``python -m bench.ao_accuracy`` from the repository root (``--rounds 5`` for the log;
``--quick`` for a check). On each shape (``--shapes``: the dense ``tori`` of ``bench._shapes``,
three interlocked 4D tori around a
ball, and the ``spheritorus``) a reference AO is traced once with ``--reference`` fixed samples
(another seed). Then, for each target error ``e`` (``--targets``):

* fixed samples: the fewest samples among 8, 16, ..., 2048 whose error at the 95th percentile
  of the vertices is at most ``e`` (the first power of two that reaches it), with its rays and
  seconds (BVH built before the clock: a second call on the mesh);
* ``tolerance=e`` (confidence 0.95): the rays it traced, its seconds, the fraction of vertices
  within ``e`` of the reference and its error at the 95th percentile.

Each of the ``--rounds`` rounds takes every timing once, in turn; the table shows the median
seconds with their minimum and maximum. The machine line and the load come first, and a round
that starts on a busy machine is flagged (``bench._protocol``). ``--figure PATH`` writes the
error at the 95th percentile against seconds for both (matplotlib PNG).

The reference's own noise (its standard error, about ``0.5 / sqrt(reference)`` at worst) adds
to every error measured here: at 16384 rays it is below 0.004.
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np

from bench import _protocol as protocol
from bench._shapes import shape_mesh

FIXED = tuple(2**k for k in range(3, 12))  # 8 .. 2048


def q95(errors: np.ndarray) -> float:
    """The error at the 95th percentile of the finite ``errors``."""
    return float(np.quantile(errors[np.isfinite(errors)], 0.95))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options (``--quick``: small meshes, one round, a smaller reference)."""
    parser = argparse.ArgumentParser(prog="python -m bench.ao_accuracy", description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", default="tori,spheritorus")
    parser.add_argument("--tets", type=float, default=60000, help="tetrahedra per shape (60000)")
    parser.add_argument("--targets", default="0.02,0.01", help="target errors (0.02,0.01)")
    parser.add_argument("--reference", type=int, default=16384, help="reference samples (16384)")
    protocol.add_rounds(parser, 3, "rounds taken in turn (3)")
    parser.add_argument("--quick", action="store_true", help="small meshes, one round")
    parser.add_argument("--figure", default=None, help="write the figure here (PNG)")
    args = parser.parse_args(argv)
    if args.quick:
        args.tets, args.rounds, args.reference = 8000, 1, 4096
    return args


def measure_shape(name: str, args, targets: list[float]) -> tuple[list, tuple]:
    """One shape: its reference, the errors of fixed samples and of ``tolerance``, and their
    times over the rounds; returns the table's rows and the figure's two curves."""
    import ao4d

    mesh = shape_mesh(name, args.tets)
    ao4d.ambient_occlusion(mesh, samples=1)  # the BVH, before any clock
    ref_s, ref = protocol.timed(lambda: ao4d.ambient_occlusion(mesh, samples=args.reference, seed=999))
    n = int(np.isfinite(ref).sum())
    print(
        f"{name}: {mesh.n_vertices:,} vertices, {mesh.n_simplices:,} tetrahedra; reference "
        f"{args.reference} samples in {ref_s:.1f} s, mean AO {np.nanmean(ref):.3f}",
        flush=True,
    )
    fixed_err = {}
    for s in FIXED:  # errors are deterministic: one call each
        fixed_err[s] = q95(np.abs(ao4d.ambient_occlusion(mesh, samples=s) - ref))
    tol_res = {}
    for e in targets:
        res = ao4d.ambient_occlusion(mesh, tolerance=e, return_error=True)
        err = np.abs(res.occlusion - ref)
        tol_res[e] = (res, q95(err), float(np.mean(err[np.isfinite(err)] <= e)))
    times = {("fixed", s): [] for s in FIXED}
    times.update({("tol", e): [] for e in targets})
    for _ in protocol.Rounds(args.rounds):
        for s in FIXED:
            times["fixed", s].append(protocol.timed(lambda: ao4d.ambient_occlusion(mesh, samples=s))[0])
        for e in targets:
            times["tol", e].append(protocol.timed(lambda: ao4d.ambient_occlusion(mesh, tolerance=e))[0])
    curve = (
        [(statistics.median(times["fixed", s]), fixed_err[s]) for s in FIXED],
        [(statistics.median(times["tol", e]), tol_res[e][1]) for e in targets],
    )
    rows = []
    for e in targets:
        reach = [s for s in FIXED if fixed_err[s] <= e]
        res, err95, within = tol_res[e]
        fixed = (reach[0], reach[0] * n, times["fixed", reach[0]]) if reach else (None, None, None)
        rows.append((name, e, fixed, (int(res.rays.sum()), times["tol", e], within, err95)))
    return rows, curve


def print_table(rows: list) -> None:
    """Per shape and target: fixed samples against ``tolerance``, seconds as median (min-max)."""
    print()
    print("error at the 95th percentile of vertices reaching e; seconds: median (min-max) over rounds")
    print(
        f"{'shape':12} {'e':>5} | {'fixed samples':>13} {'rays':>11} {'seconds':>20} | "
        f"{'tolerance rays':>14} {'seconds':>20} {'within e':>8} {'err@95%':>8}"
    )
    for name, e, (s, rays, seconds), (trays, tseconds, within, err95) in rows:
        sec = protocol.format_spread(seconds, ".2f", "-") if s else ""
        fixed = f"{s:>13} {rays:>11,} {sec:>20}" if s else f"{'> 2048':>13} {'':>11} {'':>20}"
        tsec = protocol.format_spread(tseconds, ".2f", "-")
        print(f"{name:12} {e:>5} | {fixed} | {trays:>14,} {tsec:>20} {within:>8.3f} {err95:>8.4f}")


def figure(path: str, curves: dict, targets: list[float], label: str) -> None:
    """The error at the 95th percentile against seconds, fixed samples and ``tolerance``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
    for k, (name, (fixed, tol)) in enumerate(curves.items()):
        colour = f"C{k}"
        ax.loglog(*zip(*fixed), "o-", color=colour, label=f"{name}: fixed samples 8-2048")
        ax.loglog(*zip(*tol), "s--", color=colour, mfc="none", ms=9, label=f"{name}: tolerance {label}")
    for e in targets:
        ax.axhline(e, color="0.7", lw=0.8)
    ax.set_xlabel("seconds (BVH built before)")
    ax.set_ylabel("AO error at the 95th percentile of vertices")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    print(f"figure -> {path}")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``argv``: the options)."""
    args = parse_args(argv)
    print(protocol.machine_line(protocol.opencl_runtime()))
    print(f"load average before: {protocol.load_average()}")
    targets = [float(t) for t in args.targets.split(",")]
    rows, curves = [], {}
    for name in args.shapes.split(","):
        shape_rows, curves[name] = measure_shape(name, args, targets)
        rows += shape_rows
    print(f"load average after: {protocol.load_average()}")
    print_table(rows)
    if args.figure:
        figure(args.figure, curves, targets, args.targets)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
