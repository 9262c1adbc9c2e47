"""Extraction error versus grid size against analytic 4-volumes and boundary 3-measures.

Shapes with closed-form volume and boundary measure (:mod:`ao4d.fields`) are extracted on grids of
n^4 points spanning a fixed box, with both methods (marching cubes with the Bhaniramka table, and
Kuhn simplices). A piecewise-linear interpolant of a smooth surface is off by O(h^2) (h = grid
spacing), so the relative errors should fall like n^-2: the figure shows that slope for reference.
Interpolated vertices lie on the true surface while the linear pieces cut inside a convex
surface, so the volume comes out slightly too small.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from ._common import figure, machine, parse_args, save_figure, write_results

NAME = "extraction_error"
SHAPES = {
    "hypersphere(r=1)": ("hypersphere", {"radius": 1.0}),
    "spheritorus(R=1, r=0.4)": ("spheritorus", {"R": 1.0, "r": 0.4}),
    "duocylinder(1, 1)": ("duocylinder", {"r1": 1.0, "r2": 1.0}),
}


def measure(sizes: Sequence[int]) -> list[dict]:
    """One row per (shape, method, n): errors of volume and boundary measure, time, size."""
    from ao4d import extract_field, fields

    rows = []
    for label, (kind, params) in SHAPES.items():
        f = getattr(fields, kind)(**params)
        half = 1.1 * float(np.max(np.abs(f.extent)))  # the same box for every n
        for method in ("cubes", "simplices"):
            for n in sizes:
                t0 = time.perf_counter()
                mesh = extract_field(f, n, (-half, half), method=method, progress=False)
                seconds = time.perf_counter() - t0
                rows.append(
                    {
                        "shape": label,
                        "method": method,
                        "n": n,
                        "spacing": 2 * half / (n - 1),
                        "simplices": mesh.n_simplices,
                        "closed": mesh.check().ok,
                        "volume": mesh.volume,
                        "volume_exact": f.volume,
                        "volume_rel_error": mesh.volume / f.volume - 1,
                        "measure": mesh.measure,
                        "measure_exact": f.boundary_measure,
                        "measure_rel_error": mesh.measure / f.boundary_measure - 1,
                        "seconds": seconds,
                    }
                )
    return rows


def plot(rows: list[dict], path) -> None:
    fig, (ax_v, ax_m) = figure(2)
    colours = dict(zip(SHAPES, ("C0", "C1", "C2")))
    for label in SHAPES:
        for method, style in (("cubes", "-o"), ("simplices", "--s")):
            sel = [r for r in rows if r["shape"] == label and r["method"] == method]
            n = np.array([r["n"] for r in sel])
            for ax, key in ((ax_v, "volume_rel_error"), (ax_m, "measure_rel_error")):
                ax.loglog(
                    n, np.abs([r[key] for r in sel]), style, color=colours[label], ms=4, label=f"{label}, {method}"
                )
    n_all = np.array(sorted({r["n"] for r in rows}), dtype=float)
    for ax, what, key in ((ax_v, "4-volume", "volume_rel_error"), (ax_m, "boundary 3-measure", "measure_rel_error")):
        first = np.median([abs(r[key]) for r in rows if r["n"] == n_all[0]])
        ax.loglog(n_all, first * (n_all / n_all[0]) ** -2, ":", color="0.3", lw=2, label="slope n^-2")
        ax.set_xticks(n_all, [f"{n:g}" for n in n_all], minor=False)
        ax.set_xticks([], minor=True)
        ax.set_xlabel("grid points per axis n")
        ax.set_ylabel(f"|relative error| of the {what}")
        ax.grid(True, which="both", alpha=0.3)
    ax_v.legend(fontsize=6.5, loc="lower left")
    fig.suptitle(f"Extraction error vs grid size ({machine()})", fontsize=9)
    save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(NAME, __doc__.splitlines()[0], argv)
    sizes = (6, 8, 11) if args.quick else (8, 12, 16, 24, 32, 40)
    rows = measure(sizes)
    write_results(args.out, NAME, rows, plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
