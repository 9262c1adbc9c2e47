"""Benchmark: AO accuracy against time, fixed samples against ``tolerance``.

Run ``python bench/ao_accuracy.py`` (``--rounds 5`` for the log; ``--quick`` for a check). On each
shape (``--shapes``: the dense ``tori`` of ``bench/ao.py``, three interlocked 4D tori around a
ball, and the ``spheritorus``) a reference AO is traced once with ``--reference`` fixed samples
(another seed). Then, for each target error ``e`` (``--targets``):

* fixed samples: the fewest samples among 8, 16, ..., 2048 whose error at the 95th percentile
  of the vertices is at most ``e`` (the first power of two that reaches it), with its rays and
  seconds (BVH built before the clock: a second call on the mesh);
* ``tolerance=e`` (confidence 0.95): the rays it traced, its seconds, the fraction of vertices
  within ``e`` of the reference and its error at the 95th percentile.

Each of the ``--rounds`` rounds takes every timing once, in turn; the table shows the median
seconds with their minimum and maximum. The machine line and the load come first, and a round
that starts on a busy machine is flagged (``bench/_protocol.py``). ``--figure PATH`` writes the
error at the 95th percentile against seconds for both (matplotlib PNG).

The reference's own noise (its standard error, about ``0.5 / sqrt(reference)`` at worst) adds
to every error measured here: at 16384 rays it is below 0.004.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import _protocol as protocol  # bench/_protocol.py (bench/ is the script's folder)
import numpy as np

protocol.use_checkout(os.path.dirname(os.path.abspath(__file__)))

FIXED = tuple(2**k for k in range(3, 12))  # 8 .. 2048


def shape(name: str, tets: float):
    from ao import shape_mesh  # bench/ao.py's shapes

    return shape_mesh(name, tets)


def timed(fn):
    start = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - start


def q95(errors: np.ndarray) -> float:
    return float(np.quantile(errors[np.isfinite(errors)], 0.95))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", default="tori,spheritorus")
    parser.add_argument("--tets", type=float, default=60000, help="tetrahedra per shape (60000)")
    parser.add_argument("--targets", default="0.02,0.01", help="target errors (0.02,0.01)")
    parser.add_argument("--reference", type=int, default=16384, help="reference samples (16384)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small meshes, one round")
    parser.add_argument("--figure", default=None, help="write the figure here (PNG)")
    args = parser.parse_args(argv)
    if args.quick:
        args.tets, args.rounds, args.reference = 8000, 1, 4096
    import ao4d
    from ao4d.opencl import cl

    runtime = cl.get_runtime()
    print(protocol.machine_line(runtime))
    print(f"load average before: {protocol.load_average()}")
    targets = [float(t) for t in args.targets.split(",")]
    rows, curves = [], {}
    for name in args.shapes.split(","):
        mesh = shape(name, args.tets)
        ao4d.ambient_occlusion(mesh, samples=1)  # the BVH, before any clock
        ref, ref_s = timed(lambda: ao4d.ambient_occlusion(mesh, samples=args.reference, seed=999))
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
        for r in range(args.rounds):
            protocol.check_round(r, args.rounds)
            for s in FIXED:
                times["fixed", s].append(timed(lambda: ao4d.ambient_occlusion(mesh, samples=s))[1])
            for e in targets:
                times["tol", e].append(timed(lambda: ao4d.ambient_occlusion(mesh, tolerance=e))[1])
        curves[name] = (
            [(statistics.median(times["fixed", s]), fixed_err[s]) for s in FIXED],
            [(statistics.median(times["tol", e]), tol_res[e][1]) for e in targets],
        )
        for e in targets:
            reach = [s for s in FIXED if fixed_err[s] <= e]
            res, err95, within = tol_res[e]
            fixed = (reach[0], reach[0] * n, protocol.spread(times["fixed", reach[0]])) if reach else (None, None, None)
            rows.append((name, e, fixed, (int(res.rays.sum()), protocol.spread(times["tol", e]), within, err95)))
    print(f"load average after: {protocol.load_average()}")
    print()
    print("error at the 95th percentile of vertices reaching e; seconds: median (min-max) over rounds")
    print(
        f"{'shape':12} {'e':>5} | {'fixed samples':>13} {'rays':>11} {'seconds':>20} | "
        f"{'tolerance rays':>14} {'seconds':>20} {'within e':>8} {'err@95%':>8}"
    )

    def sec(spread):
        m, lo, hi = spread
        return f"{m:.2f} ({lo:.2f}-{hi:.2f})"

    for name, e, (s, rays, spread), (trays, tspread, within, err95) in rows:
        fixed = f"{s:>13} {rays:>11,} {sec(spread):>20}" if s else f"{'> 2048':>13} {'':>11} {'':>20}"
        print(f"{name:12} {e:>5} | {fixed} | {trays:>14,} {sec(tspread):>20} {within:>8.3f} {err95:>8.4f}")
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
        for k, (name, (fixed, tol)) in enumerate(curves.items()):
            colour = f"C{k}"
            ax.loglog(*zip(*fixed), "o-", color=colour, label=f"{name}: fixed samples 8-2048")
            ax.loglog(*zip(*tol), "s--", color=colour, mfc="none", ms=9, label=f"{name}: tolerance {args.targets}")
        for e in targets:
            ax.axhline(e, color="0.7", lw=0.8)
        ax.set_xlabel("seconds (BVH built before)")
        ax.set_ylabel("AO error at the 95th percentile of vertices")
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.figure)
        print(f"figure -> {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
