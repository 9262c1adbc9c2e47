"""Benchmark: ao4d extraction (4D, both methods) against scikit-image's 3D marching cubes.

Same cell count on both sides: a 64^4 grid has 63^4 = 15.8 M cells, a 256^3 grid 255^3 = 16.6 M.
The grids are sampled once up front; the runs are interleaved and repeated, and the table shows
the median time, cells per second and output simplices (tets / triangles) per second, and the
ratio of ao4d's simplices per second to scikit-image's triangles per second.

    python bench/extract.py                 # 64^4 vs 256^3, 5 repeats
    python bench/extract.py --grid4 48 --grid3 200 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def _cases(n4: int, n3: int):
    import ao4d
    from ao4d import fields
    from skimage import measure

    ball = ao4d.sample(fields.hypersphere(1.0), n4, (-1.2, 1.2))
    torus_f = fields.spheritorus(1.0, 0.4)
    torus = ao4d.sample(torus_f, n4, (torus_f.extent[0] - 0.1, torus_f.extent[1] + 0.1))
    sphere3 = ao4d.sample(fields.hypersphere(1.0, dim=3), n3, (-1.2, 1.2))

    def ao4d_run(values, method):
        return lambda: ao4d.extract(values, 0.0, method=method, progress=False).n_simplices

    def skimage_run():
        return len(measure.marching_cubes(sphere3, 0.0, method="lorensen")[1])

    return [
        (f"ao4d cubes      hypersphere {n4}^4", ball, ao4d_run(ball, "cubes")),
        (f"ao4d simplices  hypersphere {n4}^4", ball, ao4d_run(ball, "simplices")),
        (f"ao4d cubes      spheritorus {n4}^4", torus, ao4d_run(torus, "cubes")),
        (f"ao4d simplices  spheritorus {n4}^4", torus, ao4d_run(torus, "simplices")),
        (f"ao4d cubes      sphere      {n3}^3", sphere3, ao4d_run(sphere3, "cubes")),
        (f"skimage lorensen sphere     {n3}^3", sphere3, skimage_run),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid4", type=int, default=64, help="points per axis of the 4D grids")
    parser.add_argument("--grid3", type=int, default=256, help="points per axis of the 3D grid")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per case (median)")
    args = parser.parse_args(argv)

    cases = _cases(args.grid4, args.grid3)
    times: dict[str, list[float]] = {name: [] for name, _, _ in cases}
    outputs: dict[str, int] = {}
    for _, _, run in cases:  # warm-up: table loading, first-touch allocations
        run()
    for _ in range(args.repeats):  # interleaved, so machine load affects all cases alike
        for name, _, run in cases:
            t0 = time.perf_counter()
            outputs[name] = run()
            times[name].append(time.perf_counter() - t0)

    ref_name = cases[-1][0]
    ref_rate = outputs[ref_name] / statistics.median(times[ref_name])
    print(f"median of {args.repeats} runs; ratio = simplices/s over scikit-image's triangles/s")
    print(f"{'case':36s} {'cells':>10s} {'time s':>8s} {'Mcells/s':>9s} {'simplices':>10s} "
          f"{'Msimp/s':>8s} {'ratio':>6s}")
    for name, values, _ in cases:
        med = statistics.median(times[name])
        cells = int(np.prod(np.array(values.shape) - 1))
        rate = outputs[name] / med
        print(f"{name:36s} {cells:10d} {med:8.3f} {cells / med / 1e6:9.2f} {outputs[name]:10d} "
              f"{rate / 1e6:8.2f} {rate / ref_rate:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
