"""Extraction throughput: ao4d against scikit-image's marching cubes in 3D, and ao4d in 4D.

The same sampled 3D grid (a ball's signed distance) goes to ``skimage.measure.marching_cubes``
(Lewiner, compiled Cython) and to ``ao4d.extract`` (vectorised numpy over the Bhaniramka
table, or Kuhn simplices). Throughput is grid cells per second; sampling the field is not
timed. In 4D there is no peer: ao4d's own cells per second for a 4-ball, as
``ao4d.extract`` on an array and as ``ao4d.extract_field`` (sampling included, slab by slab).
Times are the best of a few repeats, the run least disturbed by other load.
"""

from __future__ import annotations

from collections.abc import Sequence

from ._common import best_time, figure, finish_panel, machine, measured, parse_args, save_figure, write_results

NAME = "extract_throughput"


def measure(sizes3: Sequence[int], sizes4: Sequence[int], repeats: int) -> list[dict]:
    from skimage.measure import marching_cubes

    from ao4d import extract, extract_field, fields, sample

    rows = []
    for dim in (3, 4):  # load the tables and warm numpy's caches before anything is timed
        for method in ("cubes", "simplices"):
            extract(sample(fields.hypersphere(1.0, dim=dim), (6,) * dim, (-1.2, 1.2)), method=method, progress=False)

    def row(dim, n, tool, method, seconds, simplices):
        cells = (n - 1) ** dim
        rows.append(
            {
                "dim": dim,
                "n": n,
                "cells": cells,
                "tool": tool,
                "method": method,
                "seconds": seconds,
                "cells_per_second": cells / seconds,
                "simplices": simplices,
            }
        )

    for n in sizes3:
        values = sample(fields.hypersphere(1.0, dim=3), (n,) * 3, (-1.2, 1.2))
        seconds, (_, faces, _, _) = best_time(lambda: marching_cubes(values, 0.0), repeats)
        row(3, n, "scikit-image", "lewiner", seconds, len(faces))
        for method in ("cubes", "simplices"):
            seconds, mesh = best_time(lambda: extract(values, 0.0, method=method, progress=False), repeats)
            row(3, n, "ao4d", method, seconds, mesh.n_simplices)
    for n in sizes4:
        f = fields.hypersphere(1.0)
        values = sample(f, (n,) * 4, (-1.2, 1.2))
        for method in ("cubes", "simplices"):
            seconds, mesh = best_time(lambda: extract(values, 0.0, method=method, progress=False), repeats)
            row(4, n, "ao4d", method, seconds, mesh.n_simplices)
        seconds, mesh = best_time(lambda: extract_field(f, n, (-1.2, 1.2), progress=False), repeats)
        row(4, n, "ao4d extract_field", "cubes", seconds, mesh.n_simplices)
    return rows


def ratio_table(rows: list[dict]) -> list[dict]:
    """ao4d cubes time / scikit-image time per 3D grid size (> 1: scikit-image is faster)."""
    out = []
    for n in sorted({r["n"] for r in rows if r["dim"] == 3}):
        sk = next(r for r in rows if (r["dim"], r["n"], r["tool"]) == (3, n, "scikit-image"))
        ours = next(r for r in rows if (r["dim"], r["n"], r["method"]) == (3, n, "cubes"))
        out.append(
            {
                "n": n,
                "skimage_seconds": sk["seconds"],
                "ao4d_seconds": ours["seconds"],
                "ao4d_over_skimage": ours["seconds"] / sk["seconds"],
            }
        )
    return out


def plot(rows: list[dict], path) -> None:
    fig, (ax3, ax4) = figure(2)
    for ax, dim in ((ax3, 3), (ax4, 4)):
        keys = sorted({(r["tool"], r["method"]) for r in rows if r["dim"] == dim})
        for i, (tool, method) in enumerate(keys):
            sel = [r for r in rows if (r["dim"], r["tool"], r["method"]) == (dim, tool, method)]
            measured(ax, sel, "cells", "cells_per_second", "-o", color=f"C{i}", label=f"{tool} ({method})")
        finish_panel(ax, title=f"{dim}D ball", xlabel=f"{dim}D grid cells", ylabel="cells per second")
    fig.suptitle(f"Extraction throughput ({machine()})", fontsize=9)
    save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(NAME, __doc__.splitlines()[0], argv)
    if args.quick:
        rows = measure((16, 24), (8, 10), repeats=1)
    else:
        rows = measure((32, 64, 96, 128, 192), (12, 16, 24, 32, 48), repeats=3)
    write_results(args.out, NAME, rows, plot, {"ratio": ratio_table(rows)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
