"""Benchmark: ``ao4d.raycast.cast_rays`` (render's primary and shadow rays) against Embree.

Run ``python bench/cast.py`` (``--help`` for sizes; ``--quick`` for a small run). Each
``--repeat`` round takes every measurement once, in turn; the table shows medians.

* 3D: any-hit rays against a torus of ``--triangles`` triangles: the AO rays of ``bench/ao.py``
  (64 cosine-weighted directions per point, from points spread over the torus), identical on both
  sides. Open3D's ``RaycastingScene.test_occlusions`` (Embree 4, all threads, in a process of its
  own) against ``cast_rays(mesh, o, w, closest=False)``, the tree already built (the build is
  ``bench/ao.py``'s subject). Closest hits (``closest=True``, reading ``t`` and the barycentrics)
  are timed too.
* 4D: the same kind of rays from the vertices of a spheritorus, through ``cast_rays``.
* Host share: the part of a ``cast_rays`` call outside its kernel launches (input checks, the
  float64 mapping into the tree's frame, float32 copies, hit refinement), measured by timing
  each launch's wait.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ao as ao_bench  # noqa: E402  (bench/ao.py: the torus, its rays and the Open3D worker)


class KernelClock:
    """Wall seconds spent waiting for cast kernels, by wrapping the kernels ``cast_rays`` gets."""

    def __init__(self, raycast):
        self.seconds = 0.0
        self._raycast = raycast
        self._original = raycast._traversal_kernel

    def __enter__(self):
        clock = self

        class Timed:
            def __init__(self, kernel):
                self.kernel = kernel

            def __call__(self, *args, **kwargs):
                event = self.kernel(*args, **kwargs)
                start = time.perf_counter()
                event.wait()
                clock.seconds += time.perf_counter() - start
                return event

        def wrapped(*args, **kwargs):
            kernel, head = self._original(*args, **kwargs)
            return Timed(kernel), head

        self._raycast._traversal_kernel = wrapped
        return self

    def __exit__(self, *exc):
        self._raycast._traversal_kernel = self._original


def ao4d_cast(mesh, o, w, closest: bool) -> dict:
    from ao4d import raycast

    with KernelClock(raycast) as kc:
        start = time.perf_counter()
        hits = raycast.cast_rays(mesh, o, w, closest=closest, backend="opencl")
        if closest:
            hits.t, hits.barycentric  # what render reads
        wall = time.perf_counter() - start
    return {"trace": wall, "kernel": kc.seconds, "hit": float(hits.hit.mean())}


def rays_4d(tets: float, samples: int):
    """AO rays of a 4D spheritorus (every vertex, ``samples`` each): mesh, origins, directions."""
    import ao4d
    from ao4d import ao, raycast, sampling

    mesh = ao_bench.shape_mesh("spheritorus", tets)
    p, n = mesh.vertices, mesh.vertex_normals
    order = raycast._morton_order(p)
    p, n = p[order], n[order]
    w = sampling.cosine_hemisphere(n, samples, seed=0).reshape(-1, 4)
    diagonal = float(np.linalg.norm(np.ptp(p, axis=0)))
    o = np.repeat(p + ao.ORIGIN_OFFSET * diagonal * n, samples, axis=0)
    return ao4d.SimplexMesh(mesh.vertices, mesh.simplices), o.astype(np.float32), w.astype(np.float32)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="example: python bench/cast.py --repeat 3")
    parser.add_argument("--triangles", type=float, default=1e6, help="3D torus size (default 1e6)")
    parser.add_argument("--tets", type=float, default=1.1e6, help="4D spheritorus size (default 1.1e6)")
    parser.add_argument("--points", type=int, default=160_000, help="AO points (default 160000: 10.2 M rays)")
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small sizes, one round (seconds)")
    args = parser.parse_args(argv)
    if args.quick:
        args.triangles, args.tets, args.points, args.repeat = 5e4, 5e4, 8000, 1
    import ao4d
    from ao4d import cl, raycast

    runtime = cl.get_runtime()
    if runtime is None:
        print("no OpenCL device: nothing to measure")
        return 1
    print(f"device: {runtime.name}; load average {ao_bench.load()}")
    tm, _, _, o3, w3 = ao_bench.torus_rays(int(args.triangles), args.points, args.samples)
    torus = ao4d.SimplexMesh(tm.vertices, tm.faces)
    raycast.get_bvh(torus, runtime=runtime)
    raycast.cast_rays(torus, o3[:1], w3[:1], backend="opencl")  # device copies and kernels
    mesh4, o4, w4 = rays_4d(args.tets, args.samples)
    raycast.get_bvh(mesh4, runtime=runtime)
    raycast.cast_rays(mesh4, o4[:1], w4[:1], backend="opencl")
    why_not = ao_bench.have_open3d()
    peer = None if why_not else ao_bench.Open3D()
    print(f"3D torus: {len(tm.faces):,} triangles, {len(o3):,} rays; 4D spheritorus: "
          f"{len(mesh4.simplices):,} tets, {len(o4):,} rays")
    runs: dict[str, list[dict]] = {}
    for _ in range(args.repeat):
        if peer is not None:
            runs.setdefault("Open3D test_occlusions (3D)", []).append(peer.run(int(args.triangles), args.points, args.samples))
        runs.setdefault("ao4d cast_rays any hit (3D)", []).append(ao4d_cast(torus, o3, w3, False))
        runs.setdefault("ao4d cast_rays closest (3D)", []).append(ao4d_cast(torus, o3, w3, True))
        runs.setdefault("ao4d cast_rays any hit (4D)", []).append(ao4d_cast(mesh4, o4, w4, False))
        runs.setdefault("ao4d cast_rays closest (4D)", []).append(ao4d_cast(mesh4, o4, w4, True))
    if peer is not None:
        peer.close()
    print(f"load average after: {ao_bench.load()}")
    print("\n| | M rays/s | host share of the call | hits |\n|---|---|---|---|")
    rates = {}
    for name, rs in runs.items():
        n = len(o4) if "(4D)" in name else len(o3)
        # the Open3D worker reports (wall, CPU) seconds
        trace = statistics.median(r["trace"][0] if isinstance(r["trace"], list) else r["trace"] for r in rs)
        rates[name] = n / trace / 1e6
        host = statistics.median(1 - r["kernel"] / r["trace"] for r in rs) if "kernel" in rs[0] else None
        host_s = "–" if host is None else f"{100 * host:.0f} %"
        print(f"| {name} | {rates[name]:.2f} | {host_s} | {rs[0]['hit']:.3f} |")
    if peer is not None:
        base = rates["Open3D test_occlusions (3D)"]
        print(f"\nao4d any-hit cast_rays / Open3D test_occlusions (identical rays): "
              f"{rates['ao4d cast_rays any hit (3D)'] / base:.2f}x")
    else:
        print(f"\nOpen3D not measured: {why_not}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
