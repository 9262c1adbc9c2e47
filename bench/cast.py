"""Benchmark: ``ao4d.rays.api.cast_rays`` (render's primary and shadow rays) against Embree.

Run ``python -m bench.cast`` from the repository root (``--help`` for sizes; ``--quick`` for a
small run). Each of the
``--rounds`` rounds (5) takes every measurement once, in turn; the table shows medians, the
ratio its median and min–max over the rounds. The machine line comes first, and a round that
starts on a busy machine is flagged loudly (``bench._protocol``).

* 3D: any-hit rays against a torus of ``--triangles`` triangles: the AO rays of ``bench.ao``
  (64 cosine-weighted directions per point, from points spread over the torus), identical on both
  sides. Open3D's ``RaycastingScene.test_occlusions`` (Embree 4, all threads, in a process of its
  own) against ``cast_rays(mesh, o, w, closest=False)``, the tree already built (the build is
  ``bench.ao``'s subject). Closest hits (``closest=True``, reading ``t`` and the barycentrics)
  are timed too.
* 4D: the same kind of rays from the vertices of a spheritorus, through ``cast_rays``.
* Host share: the part of a ``cast_rays`` call's wall time when no kernel launch runs (input
  checks, the float64 mapping into the tree's frame, float32 copies, the result arrays, hit
  refinement where the host does it), from each launch's enqueue and completion times (an
  OpenCL event callback); on fp64 devices the closest hits' refinement is a launch too.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from bench import _protocol as protocol
from bench._embree import Open3D, have_open3d, torus_rays
from bench._shapes import shape_mesh


class KernelClock:
    """Wall seconds the device spends on ``cast_rays``' launches, from the moment each launch
    can start (enqueued, and the previous one complete) to its completion, which the OpenCL
    runtime reports through an event callback: the launches are left to overlap with the
    host's work as they do in ``cast_rays``; the rest of the call's wall time is host time."""

    def __init__(self):
        from ao4d.rays import launches, refine

        self._launching, self._refining = launches, refine  # the modules whose kernels are timed
        self._original = launches._traversal_kernel
        self._original_refine = refine._refine_kernel
        self._launches: list[list[float]] = []  # [enqueued, completed]

    @property
    def seconds(self) -> float:
        busy, previous = 0.0, -float("inf")
        for enqueued, completed in sorted(self._launches):
            begin = max(enqueued, previous)
            busy += max(0.0, completed - begin)
            previous = completed
        return busy

    def __enter__(self):
        import pyopencl as pcl

        clock = self

        class Timed:
            def __init__(self, kernel):
                self.kernel = kernel

            def __call__(self, *args, **kwargs):
                times = [time.perf_counter(), float("nan")]
                event = self.kernel(*args, **kwargs)

                def done(status, times=times):
                    times[1] = time.perf_counter()

                event.set_callback(pcl.command_execution_status.COMPLETE, done)
                clock._launches.append(times)
                return event

        def wrapped(*args, **kwargs):
            kernel, head = self._original(*args, **kwargs)
            return Timed(kernel), head

        self._launching._traversal_kernel = wrapped
        # the closest hits' refinement runs on fp64 devices as a kernel too
        self._refining._refine_kernel = lambda *args, **kwargs: Timed(self._original_refine(*args, **kwargs))
        return self

    def __exit__(self, *exc):
        self._launching._traversal_kernel = self._original
        self._refining._refine_kernel = self._original_refine
        # the runtime reports completions from its own thread, possibly after cast_rays has
        # returned (it waited on the answers, not on the callbacks): a launch still without its
        # time would count as no kernel time at all
        deadline = time.perf_counter() + 5.0
        while any(completed != completed for _, completed in self._launches):  # NaN: not yet
            if time.perf_counter() > deadline:
                raise RuntimeError("an OpenCL launch never reported its completion to the kernel clock")
            time.sleep(0.001)


def ao4d_cast(mesh, o, w, closest: bool) -> dict:
    from ao4d.rays import api

    with KernelClock() as kc:
        start = time.perf_counter()
        hits = api.cast_rays(mesh, o, w, closest=closest, backend="opencl")
        if closest:
            hits.t, hits.barycentric  # what render reads
        wall = time.perf_counter() - start
    return {"trace": wall, "kernel": kc.seconds, "hit": float(hits.hit.mean())}


def rays_4d(tets: float, samples: int):
    """AO rays of a 4D spheritorus (every vertex, ``samples`` each): mesh, origins, directions."""
    import ao4d
    from ao4d import ao, sampling
    from ao4d.rays import rows

    mesh = shape_mesh("spheritorus", tets)
    p, n = mesh.vertices, mesh.vertex_normals
    order = rows._morton_order(p)
    p, n = p[order], n[order]
    w = sampling.cosine_hemisphere(n, samples, seed=0).reshape(-1, 4)
    diagonal = float(np.linalg.norm(np.ptp(p, axis=0)))
    o = np.repeat(p + ao.ORIGIN_OFFSET * diagonal * n, samples, axis=0)
    return ao4d.SimplexMesh(mesh.vertices, mesh.simplices), o.astype(np.float32), w.astype(np.float32)


def parse_args(argv=None) -> argparse.Namespace:
    """The options (``--quick``: small sizes, two rounds)."""
    parser = argparse.ArgumentParser(
        prog="python -m bench.cast",
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: python -m bench.cast --rounds 5",
    )
    parser.add_argument("--triangles", type=float, default=1e6, help="3D torus size (default 1e6)")
    parser.add_argument("--tets", type=float, default=1.1e6, help="4D spheritorus size (default 1.1e6)")
    parser.add_argument("--points", type=int, default=160_000, help="AO points (default 160000: 10.2 M rays)")
    parser.add_argument("--samples", type=int, default=64)
    protocol.add_rounds(parser, 5, "rounds taken in turn (default 5)", "--repeat")
    parser.add_argument("--quick", action="store_true", help="small sizes, two rounds (seconds)")
    args = parser.parse_args(argv)
    if args.quick:
        args.triangles, args.tets, args.points, args.rounds = 5e4, 5e4, 8000, 2
    return args


def workloads(args, runtime) -> dict:
    """The 3D torus and the 4D spheritorus with their rays, trees built and kernels loaded:
    name -> (mesh, origins, directions)."""
    import ao4d
    from ao4d import bvh
    from ao4d.rays import api

    tm, _, _, o3, w3 = torus_rays(int(args.triangles), args.points, args.samples)
    torus = ao4d.SimplexMesh(tm.vertices, tm.faces)
    mesh4, o4, w4 = rays_4d(args.tets, args.samples)
    out = {"3D": (torus, o3, w3), "4D": (mesh4, o4, w4)}
    for mesh, o, w in out.values():
        bvh.get_bvh(mesh, runtime=runtime)
        api.cast_rays(mesh, o[:1], w[:1], backend="opencl")  # device copies and kernels
    return out


def measure(args, work: dict, peer, rounds: protocol.Rounds) -> dict[str, list[dict]]:
    """Every measurement once a round, in turn: name -> the rounds' figures."""
    runs: dict[str, list[dict]] = {}
    for _ in rounds:
        if peer is not None:
            runs.setdefault("Open3D test_occlusions (3D)", []).append(
                peer.run(int(args.triangles), args.points, args.samples)
            )
        for dim in ("3D", "4D"):
            runs.setdefault(f"ao4d cast_rays any hit ({dim})", []).append(ao4d_cast(*work[dim], False))
            runs.setdefault(f"ao4d cast_rays closest ({dim})", []).append(ao4d_cast(*work[dim], True))
    return runs


def report(runs: dict, work: dict, rounds: protocol.Rounds, why_not: str | None) -> None:
    """The rates and host shares (medians, min–max) and ao4d's ratio against Open3D."""
    if rounds.warning():
        print(rounds.warning())
    print(
        f"\nmedians of {len(rounds)} rounds (wall clock); host share: the part of the call outside "
        "its kernel launches, median (min–max)"
    )
    print("\n| | M rays/s | host share of the call | hits |\n|---|---|---|---|")
    rates = {}
    for name, rs in runs.items():
        n = len(work["4D"][1]) if "(4D)" in name else len(work["3D"][1])
        # the Open3D worker reports (wall, CPU) seconds
        rates[name] = [n / (r["trace"][0] if isinstance(r["trace"], list) else r["trace"]) / 1e6 for r in rs]
        if "kernel" in rs[0]:
            m, lo, hi = protocol.spread(100 * (1 - r["kernel"] / r["trace"]) for r in rs)
            host_s = f"{m:.0f} % ({lo:.0f}–{hi:.0f})"
        else:
            host_s = "–"
        print(f"| {name} | {statistics.median(rates[name]):.2f} | {host_s} | {rs[0]['hit']:.3f} |")
    if why_not is None:
        base = rates["Open3D test_occlusions (3D)"]
        ours = rates["ao4d cast_rays any hit (3D)"]
        print(
            f"\nao4d any-hit cast_rays / Open3D test_occlusions (identical rays), median (min–max) over "
            f"{len(rounds)} rounds: {protocol.format_ratio(a / b for a, b in zip(ours, base))}"
        )
    else:
        print(f"\nOpen3D not measured: {why_not}")


def main(argv=None) -> int:
    """Run the benchmark (``argv``: the options); 1 without an OpenCL device."""
    args = parse_args(argv)
    from ao4d import _progress
    from ao4d.opencl import cl

    _progress.set_enabled(False)  # no progress lines in the table
    began = time.perf_counter()
    runtime = cl.get_runtime()
    if runtime is None:
        print("no OpenCL device: nothing to measure")
        return 1
    print(protocol.machine_line(runtime))
    print(f"device: {runtime.name}; load average {protocol.load_average()}")
    print(f"before the rounds, {protocol.memory_line(runtime)}", flush=True)
    work = workloads(args, runtime)
    why_not = have_open3d()
    peer = None if why_not else Open3D()
    (torus, o3, _), (mesh4, o4, _) = work["3D"], work["4D"]
    print(
        f"3D torus: {len(torus.simplices):,} triangles, {len(o3):,} rays; 4D spheritorus: "
        f"{len(mesh4.simplices):,} tets, {len(o4):,} rays"
    )
    rounds = protocol.Rounds(args.rounds)
    runs = measure(args, work, peer, rounds)
    if peer is not None:
        peer.close()
    print(f"load average after: {protocol.load_average()}")
    print(f"after the rounds, {protocol.memory_line(runtime)}")
    report(runs, work, rounds, why_not)
    print(f"\n{protocol.machine_line(runtime)}")
    print(f"bench run time {time.perf_counter() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
