"""Benchmark: ambient occlusion rays per second, BVH build included, against Embree.

Run ``python -m bench.ao`` from the repository root (``--quick`` for small meshes, ``--help``
for sizes). Each of the ``--rounds`` rounds (5) takes every measurement once, in turn, so that
all see the same machine load; the tables show medians, and every ratio its median with the
minimum and maximum over the rounds (each round's ao4d figure against the same round's Open3D
figure). The machine line (CPU, SIMD width, L2, L3, OpenCL device and driver) comes first; a
round that starts on a busy machine is flagged loudly (``bench._protocol``).

* ao4d OpenCL, every vertex of a 4D mesh of about ``--tets`` tetrahedra, ``--samples`` rays per
  vertex (cosine-weighted, any hit), on six 4D shapes (``--shapes``): the spheritorus, the
  tiger, the ditorus, a CSG of tesseracts (a tesseract with four tesseract-shaped pockets,
  deep concavities), and two with dense mutual occlusion: three interlocked 4D tori around a
  ball (``tori``) and a cluster of 40 4D metaballs (``metaballs``), mean AO 0.17-0.18
  (``bench._shapes``). "first call" is a first ``ambient_occlusion(mesh, samples=64)`` on a
  fresh mesh (the device builder runs inside it: build + trace); "trace" is the second call on the
  same mesh, "build" the difference; "reach d/4" a call with ``max_distance`` a quarter of the
  bounding box's diagonal. Traced by the packet kernel (``ao_bvh``: a point's rays together) and,
  as "per-ray kernel", by the kernel it replaces (``ao_bvh_rays``, one ray at a time).
* Open3D's ``RaycastingScene.test_occlusions`` (Embree 4, all threads; in a process of its own,
  because its bundled TBB must not meet Intel's OpenCL runtime), per shape on a 3D torus with as
  many triangles as the shape has tetrahedra and as many AO rays of the same kind (64 per point,
  ao4d's directions, from as many points spread evenly over the torus), once with unlimited
  reach and once with ``tfar`` a quarter of the torus's bounding-box diagonal. Build is the scene
  construction and the first query. For the two dense shapes Open3D also traces their 3D
  analogues (``bench._embree.dense3d_trimesh``: three tori around a ball, 40 metaballs; as many triangles and
  rays per point; ``--no-dense-3d`` leaves them out), which says how Embree fares with dense
  mutual occlusion in its own dimension: context printed beside the ratios, whose peer stays
  the torus. The worker (``python -m bench._embree``) runs under ``AO4D_BENCH_OPEN3D_PYTHON``
  when set (a virtual environment with Open3D, made with ``--system-site-packages``), else this
  Python. ``--embreex`` adds trimesh's ``intersects_any`` (embreex: Embree from one Python
  thread) and ``--host-tree`` ao4d with the numpy-built tree.
* Traversal work per AO ray on ``--quality-points`` vertices (``ao4d.rays.api.traversal_counts``,
  deterministic, unlike the timings): wide nodes fetched and leaf blocks fetched, per-ray kernel
  (before) and packet kernel (after); SAH cost and the wide tree's nodes, slot use and depth.
* Bytes per tetrahedron of the traversed tree: wide nodes and leaf blocks, beside L2 and L3.
* What a tree that fits in cache would give (``--no-cache-ceiling`` leaves it out): each shape
  also extracted with ``--tets`` / 16 tetrahedra (its tree a sixteenth of the bytes, within L3),
  traced in the same rounds (the median of five traces a round: they are short). The full mesh's
  trace time per ray over the small one's, per round, estimates what a lever that cuts memory
  traffic (smaller nodes or leaves, another order) could gain at best; times the round's trace
  ratio against Open3D, the ratio such a lever could reach. It is an estimate, not a bound: the
  small tree's rays make fewer box and block tests (printed beside it, from
  ``traversal_counts``, with the time per test), but a coarser shape is not the same workload.
* The numpy backend on a smaller 4D mesh, and the BVH kernel against the brute-force kernel.

Rates count rays per wall-clock second; the machine's load average is printed before and after.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import statistics
import sys
import time

import numpy as np

from bench import _protocol as protocol
from bench._embree import Open3D, embree_run, have_open3d, torus_rays, torus_trimesh
from bench._shapes import DENSE, SHAPES, shape_mesh

CEILING_SHRINK = 16  # the cache ceiling's small meshes: --tets / 16 tetrahedra (a 1 M-tet tree's 114 MB -> 7 MB)


def ao4d_run(vertices, simplices, builder: str, runtime, samples: int, reach: float = 0.0, traces: int = 1) -> dict:
    """A fresh mesh: first call (build + trace), then a second call on it (trace); with
    reach > 0 both with ``max_distance`` = reach times the bounding box's diagonal. With
    ``traces`` > 1 the trace is the median of that many calls (short calls on small meshes)."""
    import ao4d
    from ao4d import bvh

    mesh = ao4d.SimplexMesh(vertices, simplices)
    mesh.vertex_normals  # noqa: B018 - computed (and cached) before the clock starts
    kwargs = {"samples": samples, "backend": "opencl", "progress": False}
    if reach:
        kwargs["max_distance"] = reach * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    clock = protocol.Clock()
    if builder == "host":  # the numpy tree, built and uploaded before the first call
        bvh.device_tree(mesh, bvh.get_bvh(mesh, builder="host"), runtime)
    occlusion = ao4d.ambient_occlusion(mesh, **kwargs)
    first = clock.lap()
    tree = bvh.get_bvh(mesh)
    assert (builder == "device") == (type(tree).__name__ == "DeviceBVH")
    laps = []
    for _ in range(traces):
        occlusion = ao4d.ambient_occlusion(mesh, **kwargs)
        laps.append(clock.lap())
    trace = tuple(statistics.median(lap[k] for lap in laps) for k in (0, 1))
    return {
        "first": first,
        "trace": trace,
        "build": tuple(f - t for f, t in zip(first, trace)),
        "hit": float(np.nanmean(occlusion)),
        "rays": int(np.isfinite(occlusion).sum()) * samples,
    }


@functools.lru_cache(maxsize=None)
def _reference_traversal():
    from ao4d.rays import launches

    return functools.partial(launches._ao_opencl, traversal="rays")


def per_ray_run(vertices, simplices, runtime, samples: int, reach: float = 0.0) -> dict:
    """The trace of ao4d_run with the per-ray kernel (``ao_bvh_rays``), the one before packets."""
    from ao4d.rays import launches

    packet = launches._ao_opencl
    launches._ao_opencl = _reference_traversal()
    try:
        return ao4d_run(vertices, simplices, "device", runtime, samples, reach)
    finally:
        launches._ao_opencl = packet


def quality(vertices, simplices, runtime, samples, n_points, rng) -> dict:
    import ao4d
    from ao4d import ao, bvh
    from ao4d.rays import api

    mesh = ao4d.SimplexMesh(vertices, simplices)
    tree = bvh.get_bvh(mesh, builder="device", runtime=runtime)
    normals = mesh.vertex_normals
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    idx = np.sort(rng.choice(ok, size=min(n_points, ok.size), replace=False))
    out = {}
    for reach in (0.0, 0.25):
        for traversal in ("rays", "packet"):
            out[traversal, reach] = api.traversal_counts(
                mesh,
                mesh.vertices[idx],
                normals[idx],
                samples=samples,
                runtime=runtime,
                offset=ao.ORIGIN_OFFSET * tree.world_diagonal,
                traversal=traversal,
                detail=True,
                max_distance=reach * tree.world_diagonal if reach else math.inf,
            )
    _, children, _, _, wide_depth = bvh.widen_topology(tree, bvh.block_lanes(runtime, 4), bvh.node_width(runtime))
    return {
        "counts": out,
        "sah": bvh.sah_cost(tree),
        "wide": len(children),
        "used": float((children != 0).mean()),
        "wide_depth": wide_depth,
    }


def med(runs, key, k=0):
    """Median over rounds of ``key`` (k = 0: wall seconds, 1: CPU seconds of all threads)."""
    return statistics.median(r[key][k] for r in runs)


def tree_bytes(vertices, simplices, runtime) -> dict:
    """Bytes of the traversed tree (the wide nodes and the leaf blocks the kernels fetch) of
    the mesh, in all and per tetrahedron, and the leaf blocks' lane occupancy."""
    import ao4d
    from ao4d import bvh

    mesh = ao4d.SimplexMesh(vertices, simplices)
    tree = bvh.get_bvh(mesh, builder="device", runtime=runtime)
    lanes, width = bvh.block_lanes(runtime, 4), bvh.node_width(runtime)
    d = tree.dim
    _, children, _, _, _ = bvh.widen_topology(tree, lanes, width)
    n_blocks = len(bvh.block_ranges(tree, lanes)[0])
    nodes = len(children) * (2 * d * width * 4 + width * 4)
    blocks = n_blocks * (d + 1) * d * lanes * 4
    tets = len(simplices)
    return {
        "tets": tets,
        "nodes": nodes,
        "blocks": blocks,
        "node_per_tet": nodes / tets,
        "block_per_tet": blocks / tets,
        "occupancy": tree.n_prims / (n_blocks * lanes),
    }


def parse_args(argv=None) -> argparse.Namespace:
    """The options, with ``--quick``'s or the full run's sizes where none is given."""
    parser = argparse.ArgumentParser(prog="python -m bench.ao", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small sizes: --tets 1.5e5 --quality-points 3000 --numpy-tets 3e4 --rounds 2",
    )
    parser.add_argument("--tets", type=float, default=None, help="4D mesh size (1.05e6)")
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    protocol.add_rounds(parser, None, "rounds of measurements taken in turn (5; --quick: 2)", "--repeat")
    parser.add_argument("--shapes", default=",".join(SHAPES), help=f"4D shapes, of {', '.join(SHAPES)}")
    parser.add_argument("--quality-points", type=int, default=None, help="points for node-visit counts (20000)")
    parser.add_argument("--numpy-tets", type=float, default=None, help="mesh for the numpy rate (1.5e5)")
    parser.add_argument("--numpy-points", type=int, default=500)
    parser.add_argument(
        "--no-per-ray",
        dest="per_ray",
        action="store_false",
        help="leave out the per-ray kernel (the packets' reference)",
    )
    parser.add_argument("--host-tree", action="store_true", help="also ao4d with the numpy-built tree")
    parser.add_argument(
        "--no-dense-3d",
        dest="dense_3d",
        action="store_false",
        help="leave out Embree on the 3D analogues of the dense shapes (context for their ratios)",
    )
    parser.add_argument(
        "--no-cache-ceiling",
        dest="cache_ceiling",
        action="store_false",
        help="leave out the small meshes (--tets / 16) that estimate what memory levers can gain",
    )
    parser.add_argument("--embreex", action="store_true", help="also trimesh + embreex (one thread)")
    args = parser.parse_args(argv)
    quick = {"tets": 1.5e5, "quality_points": 3000, "numpy_tets": 3e4, "rounds": 2}
    full = {"tets": 1.05e6, "quality_points": 20000, "numpy_tets": 1.5e5, "rounds": 5}
    for key, value in (quick if args.quick else full).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    args.shapes = [s.strip() for s in args.shapes.split(",") if s.strip()]
    unknown = sorted(set(args.shapes) - set(SHAPES))
    if unknown:
        parser.error(f"--shapes: unknown {unknown}; choose from {', '.join(SHAPES)}")
    return args


def extract_meshes(args) -> tuple[dict, dict, dict]:
    """Per shape: the mesh's (vertices, simplices), its AO points (vertices with a normal), and
    the cache ceiling's small mesh (with ``--no-cache-ceiling``, none)."""
    meshes, points, ceiling = {}, {}, {}
    for name in args.shapes:
        mesh = shape_mesh(name, args.tets)
        meshes[name] = (np.asarray(mesh.vertices), np.asarray(mesh.simplices))
        points[name] = int((np.linalg.norm(mesh.vertex_normals, axis=1) > 0.5).sum())
        print(f"{name}: {mesh.n_simplices:,} tetrahedra, {mesh.n_vertices:,} vertices", flush=True)
    if args.cache_ceiling:
        for name in args.shapes:
            mesh = shape_mesh(name, args.tets / CEILING_SHRINK)
            ceiling[name] = (np.asarray(mesh.vertices), np.asarray(mesh.simplices))
            print(f"{name}, small: {mesh.n_simplices:,} tetrahedra (the cache ceiling's mesh)", flush=True)
    return meshes, points, ceiling


def print_tree_bytes(meshes: dict, ceiling: dict, runtime, cpu: dict) -> None:
    """The bytes each traversed tree holds, against L2 and L3."""
    print(
        f"\nbytes the traversal reads (wide nodes and leaf blocks), against L2 {protocol.format_bytes(cpu['l2'])}"
        f" and L3 {protocol.format_bytes(cpu['l3'])}:"
    )
    for name, mesh in [*meshes.items(), *((n + ", small", m) for n, m in ceiling.items())]:
        b = tree_bytes(*mesh, runtime)
        print(
            f"  {name:<19} wide nodes {b['node_per_tet']:5.1f} B/tet ({protocol.format_bytes(b['nodes'])}), "
            f"leaf blocks {b['block_per_tet']:5.1f} B/tet ({protocol.format_bytes(b['blocks'])}, lanes "
            f"{b['occupancy']:.0%} used); {b['tets']:,} tets: {protocol.format_bytes(b['nodes'] + b['blocks'])}"
        )


def warm_up(mesh: tuple, runtime) -> None:
    """Kernels loaded (4D and 3D, both traversals) and sampling tables ready, on a small piece of
    ``mesh`` (vertices, simplices) and a small torus."""
    import ao4d

    small = ao4d.SimplexMesh(mesh[0], mesh[1][:1000])
    ao4d_run(small.vertices, small.simplices, "device", runtime, 4)
    per_ray_run(small.vertices, small.simplices, runtime, 4)
    tiny = torus_trimesh(2000)
    ao4d.ambient_occlusion(ao4d.SimplexMesh(tiny.vertices, tiny.faces), samples=4, backend="opencl")


def start_peers(args, meshes: dict, points: dict):
    """The Open3D worker (None without Open3D, saying why) and, with ``--embreex``, trimesh's
    workloads per shape (None without embreex)."""
    reason = have_open3d()
    worker = Open3D() if reason is None else None
    if worker is None:
        print(f"Open3D comparison skipped: {reason} (pip install 'ao4d[bench]')")
    embree = None
    if args.embreex:
        try:
            import embreex  # noqa: F401

            embree = {name: torus_rays(len(meshes[name][1]), points[name], args.samples) for name in args.shapes}
        except ImportError as exc:
            print(f"trimesh+Embree comparison skipped: {exc}")
    return worker, embree


def round_cases(name: str, args, runtime, work: dict, worker, embree) -> dict:
    """One round's measurements of shape ``name`` by label, each a call that returns its figures
    (``work``: :func:`extract_meshes`' meshes, points and ceiling by those names)."""
    v, s = work["meshes"][name]
    points, samples = work["points"][name], args.samples
    todo = {
        "ao4d": lambda: ao4d_run(v, s, "device", runtime, samples),
        "ao4d d/4": lambda: ao4d_run(v, s, "device", runtime, samples, 0.25),
    }
    if args.per_ray:
        todo["per-ray"] = lambda: per_ray_run(v, s, runtime, samples)
        todo["per-ray d/4"] = lambda: per_ray_run(v, s, runtime, samples, 0.25)
    if name in work["ceiling"]:
        todo["ao4d small"] = lambda: ao4d_run(*work["ceiling"][name], "device", runtime, samples, traces=5)
    if args.host_tree:
        todo["ao4d host tree"] = lambda: ao4d_run(v, s, "host", runtime, samples)
    if worker is not None:
        todo["Open3D"] = lambda: worker.run(len(s), points, samples)
        todo["Open3D d/4"] = lambda: worker.run(len(s), points, samples, 0.25)
        if name in DENSE and args.dense_3d:
            todo["Open3D dense 3D"] = lambda: worker.run(len(s), points, samples, 0.0, name)
            todo["Open3D dense 3D d/4"] = lambda: worker.run(len(s), points, samples, 0.25, name)
    if embree is not None:
        todo["embreex"] = lambda: embree_run(embree[name][0], *embree[name][3:])
    return todo


def measure(args, runtime, work: dict, rounds: protocol.Rounds) -> dict:
    """Every measurement once a round, in turn: (shape, label) -> the rounds' figures."""
    worker, embree = start_peers(args, work["meshes"], work["points"])
    runs: dict[tuple[str, str], list] = {}
    for _ in rounds:
        for name in args.shapes:
            for label, fn in round_cases(name, args, runtime, work, worker, embree).items():
                runs.setdefault((name, label), []).append(fn())
    if worker is not None:
        worker.close()
    return runs


def traversal_report(args, runtime, work: dict, rng) -> dict:
    """The traversal work per AO ray, before and after packets, and the trees' shapes; returns
    the box and block tests per ray (packet kernel, unlimited reach) of each shape."""
    from ao4d import bvh

    lanes, width = bvh.block_lanes(runtime, 4), bvh.node_width(runtime)
    node_bytes, block_bytes = 2 * 4 * width * 4 + width * 4, 5 * 4 * lanes * 4  # 4D
    print(
        f"\ntraversal work per AO ray ({args.quality_points:,} random vertices, deterministic): "
        "wide nodes fetched, leaf blocks fetched, and the bytes they hold "
        f"({node_bytes} B a node, {block_bytes} B a block); before = per-ray kernel, after = packet kernel"
    )
    print(
        f"{'':<22} {'nodes before':>12} {'after':>7} {'ratio':>6} {'blocks before':>14} {'after':>7} {'ratio':>6}"
        f" {'B/ray after':>11} {'SAH':>6} {'wide nodes':>11} {'slots used':>11} {'wide depth':>11}"
    )
    tests = {}
    for name in args.shapes:
        qd = quality(*work["meshes"][name], runtime, args.samples, args.quality_points, rng)
        for reach in (0.0, 0.25):
            before, after = qd["counts"]["rays", reach], qd["counts"]["packet", reach]
            label = name + (", reach d/4" if reach else "")
            tail = (
                f" {qd['sah']:>6.1f} {qd['wide']:>11,} {qd['used']:>11.0%} {qd['wide_depth']:>11}" if not reach else ""
            )
            moved = after[0] * node_bytes + after[1] * block_bytes
            print(
                f"{label:<22} {before[0]:>12.2f} {after[0]:>7.2f} {before[0] / after[0]:>5.1f}x"
                f" {before[1]:>14.2f} {after[1]:>7.2f} {before[1] / after[1]:>5.1f}x {moved:>11.0f}{tail}"
            )
        tests[name] = sum(qd["counts"]["packet", 0.0][2:])
        # box and block tests per ray differ a little: the packets' nearest-first order changes which
        # tests a ray makes before its first hit (tests/test_rays.py bounds the difference)
    return tests


def main(argv=None) -> int:
    """Run the benchmark (``argv``: the options); 1 without an OpenCL device."""
    args = parse_args(argv)
    from ao4d import _progress
    from ao4d.opencl import cl

    _progress.set_enabled(False)  # no progress lines from the host builder in the table
    began = time.perf_counter()
    rng = np.random.default_rng(0)
    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        print("no OpenCL device: nothing to benchmark", file=sys.stderr)
        return 1
    cpu = protocol.cpu_info()
    print(protocol.machine_line(runtime, cpu))
    print(f"device: {cl.describe(runtime)}; load average before: {protocol.load_average()}")
    print(f"before the rounds, {protocol.memory_line(runtime)}", flush=True)
    meshes, points, ceiling = extract_meshes(args)
    work = {"meshes": meshes, "points": points, "ceiling": ceiling}
    print_tree_bytes(meshes, ceiling, runtime, cpu)
    warm_up(meshes[args.shapes[0]], runtime)
    rounds = protocol.Rounds(args.rounds)
    runs = measure(args, runtime, work, rounds)
    report(runs, args.shapes, rounds)
    tests = traversal_report(args, runtime, work, rng)
    small_tests = {
        name: tests_per_ray(*mesh, runtime, args.samples, args.quality_points, rng) for name, mesh in ceiling.items()
    }
    ceiling_report(runs, args.shapes, {name: (tests[name], small_tests[name]) for name in ceiling})
    numpy_and_brute(args, runtime, rng)
    print(f"\n{protocol.machine_line(runtime, cpu)}")
    print(f"after the rounds, {protocol.memory_line(runtime)}")
    print(f"bench run time {time.perf_counter() - began:.0f} s; load average after: {protocol.load_average()}")
    return 0


def _rates(run: dict, rays: int) -> dict:
    """Trace and first-call rates (rays per wall second, per CPU second) of one round's run."""
    return {key: (rays / run[key][0], rays / run[key][1]) for key in ("trace", "first")}


def _ratios(ours: list, peer: list, part: str, k: int = 0) -> list[float]:
    """Per round, ao4d's rate over the peer's for ``part`` ("trace" or "first"; ``k``: 0 wall
    clock, 1 CPU time)."""
    return [_rates(a, a["rays"])[part][k] / _rates(b, b["rays"])[part][k] for a, b in zip(ours, peer)]


def report(runs, shapes, rounds: protocol.Rounds) -> None:
    """The speed table (medians) and, per shape, every ratio against Open3D as its median and
    min–max over the rounds."""
    print(
        f"\nmedians of {len(rounds)} rounds taken in turn (wall clock; CPU time of all threads in brackets); "
        f"load average after: {protocol.load_average()}"
    )
    if rounds.warning():
        print(rounds.warning())
    print(f"{'':<34} {'rays':>11} {'build s':>8} {'trace Mrays/s':>14} {'first call Mrays/s':>19} {'hit/AO':>7}")
    for (name, label), rs in runs.items():
        rays = rs[0]["rays"]
        row = [rays / med(rs, "trace", k) for k in (0, 1)]
        first = [rays / med(rs, "first", k) for k in (0, 1)]
        build = med(rs, "build")
        hit = statistics.median(r["hit"] for r in rs)
        print(
            f"{name + ', ' + label:<34} {rays:>11,} {build:>8.2f} {row[0] / 1e6:>6.2f} ({row[1] / 1e6:>5.2f})"
            f" {first[0] / 1e6:>10.2f} ({first[1] / 1e6:>5.2f}) {hit:>7.3f}"
        )
    if not any(label == "Open3D" for _, label in runs):
        return
    print(
        f"\nratios, median (min–max) over {len(rounds)} rounds, each round's ao4d against the same round's "
        "Open3D (> 1: ao4d faster; wall clock); targets: trace and first call >= 1.0x Open3D"
    )
    print(f"  {'shape':<18} {'trace':>20} {'trace (CPU time)':>20} {'first call':>20} {'packets / per-ray':>20}")
    for name in shapes:
        for reach in ("", " d/4"):
            ours, peer = runs[name, "ao4d" + reach], runs[name, "Open3D" + reach]
            per_ray = runs.get((name, "per-ray" + reach))
            ratio = {
                key: _ratios(ours, peer, key.split()[0], k) for key, k in (("trace", 0), ("trace cpu", 1), ("first", 0))
            }
            packets = "–" if per_ray is None else protocol.format_ratio(_ratios(ours, per_ray, "trace"))
            verdict = (
                "met" if min(statistics.median(ratio["trace"]), statistics.median(ratio["first"])) >= 1.0 else "missed"
            )
            print(
                f"  {name + reach + ':':<18} {protocol.format_ratio(ratio['trace']):>20} "
                f"{protocol.format_ratio(ratio['trace cpu']):>20} {protocol.format_ratio(ratio['first']):>20} "
                f"{packets:>20}  {verdict}"
            )
    dense_report(runs, shapes)


def dense_report(runs, shapes) -> None:
    """The dense shapes' ratios against Embree on their 3D analogues (context: the targets'
    peer is the torus), with the share of rays that hit on each side."""
    dense = [name for name in shapes if (name, "Open3D dense 3D") in runs]
    if not dense:
        return
    print(
        "\nthe dense shapes against Embree on their dense 3D analogues (as many triangles and rays per "
        "point; context for the ratios above, whose peer is the torus), median (min–max):"
    )
    for name in dense:
        for reach in ("", " d/4"):
            ours, peer = runs[name, "ao4d" + reach], runs[name, "Open3D dense 3D" + reach]
            ratio = {part: _ratios(ours, peer, part) for part in ("trace", "first")}
            hits = {label: runs[name, label + reach][0]["hit"] for label in ("ao4d", "Open3D dense 3D", "Open3D")}
            print(
                f"  {name + reach + ':':<18} trace {protocol.format_ratio(ratio['trace'])}, first call "
                f"{protocol.format_ratio(ratio['first'])}; rays that hit: ao4d {hits['ao4d']:.3f}, the 3D analogue "
                f"{hits['Open3D dense 3D']:.3f}, the torus {hits['Open3D']:.3f}"
            )


def cache_gains(full: list, small: list) -> list[float]:
    """Per round, the full mesh's trace time per ray over the small mesh's: about how much faster
    a ray would be traced if the tree fitted in cache as the small one's does (the small tree is
    also shallower, so its rays make fewer tests)."""
    return [(f["trace"][0] / f["rays"]) / (s["trace"][0] / s["rays"]) for f, s in zip(full, small)]


def tests_per_ray(vertices, simplices, runtime, samples, n_points, rng) -> float:
    """Box tests plus block tests per AO ray of the packet kernel (unlimited reach) on
    ``n_points`` random vertices (:func:`quality`'s counts)."""
    return sum(quality(vertices, simplices, runtime, samples, n_points, rng)["counts"]["packet", 0.0][2:])


def ceiling_report(runs, shapes, tests) -> None:
    """Per shape, the trace time per ray of the full and the small mesh and per box or block
    test (``tests``: name -> (tests per ray of the full mesh, of the small one)), the gain a
    tree that fits in cache would give, and the trace ratio against Open3D that gain would reach."""
    have = [name for name in shapes if (name, "ao4d small") in runs]
    if not have:
        return
    print(
        "\nthe cache ceiling: trace time per ray (one core's share: wall time x cores / rays) of the mesh "
        f"and of the same shape with 1/{CEILING_SHRINK} of the tetrahedra, whose tree fits in L3, and per "
        "box or block test; the ratio of the times per ray estimates what a lever that cuts memory "
        "traffic could gain at best (the small tree's rays make fewer tests); median (min–max) over rounds"
    )
    cores = os.cpu_count() or 1
    print(
        f"  {'shape':<18} {'ns/ray':>7} {'small':>6} {'tests/ray':>10} {'small':>6} {'ns/test':>8} {'small':>6}"
        f" {'gain in L3':>20} {'trace ratio in L3':>22}"
    )
    for name in have:
        full, small = runs[name, "ao4d"], runs[name, "ao4d small"]
        gains = cache_gains(full, small)
        per_ray = [statistics.median(x["trace"][0] / x["rays"] for x in rs) * cores * 1e9 for rs in (full, small)]
        counts = tests[name]
        peer = runs.get((name, "Open3D"))
        reach = "–"
        if peer is not None:
            reach = protocol.format_ratio([g * r for g, r in zip(gains, _ratios(full, peer, "trace"))])
        print(
            f"  {name + ':':<18} {per_ray[0]:>7.0f} {per_ray[1]:>6.0f} {counts[0]:>10.1f} {counts[1]:>6.1f}"
            f" {per_ray[0] / counts[0]:>8.1f} {per_ray[1] / counts[1]:>6.1f}"
            f" {protocol.format_ratio(gains):>20} {reach:>22}"
        )


def numpy_and_brute(args, runtime, rng) -> None:
    """The numpy backend, and the BVH kernel against brute force, on a smaller 4D mesh."""
    import ao4d
    from ao4d import bvh

    small = shape_mesh("spheritorus", args.numpy_tets)
    small_tree = bvh.get_bvh(small, runtime=runtime)
    ok = np.flatnonzero(np.linalg.norm(small.vertex_normals, axis=1) > 0.5)
    pick = rng.choice(ok, size=min(args.numpy_points, ok.size), replace=False)
    p2, n2 = small.vertices[pick], small.vertex_normals[pick]
    samples2 = 16
    t_np, _ = protocol.timed(
        lambda: ao4d.ambient_occlusion(small, points=p2, normals=n2, samples=samples2, backend="numpy"), 1
    )
    p3, n3 = p2[:40], n2[:40]
    t_brute, a_brute = protocol.timed(
        lambda: ao4d.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl", accel="brute"),
        1,
    )
    a_bvh = ao4d.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl")
    assert np.array_equal(a_brute, a_bvh), "BVH and brute force disagree"
    pick4 = rng.choice(ok, size=min(20000, ok.size), replace=False)
    t_bvh, _ = protocol.timed(
        lambda: ao4d.ambient_occlusion(
            small, points=small.vertices[pick4], normals=small.vertex_normals[pick4], samples=samples2, backend="opencl"
        ),
        args.rounds,
    )
    per_ray_bvh = t_bvh / (len(pick4) * samples2)
    print(f"\nao4d numpy backend, 4D, {small_tree.n_prims:,} tets: {len(p2) * samples2 / t_np / 1e6:.3f} M rays/s")
    print(
        f"BVH speed-up over brute force ({small_tree.n_prims:,} tets, per ray): "
        f"{(t_brute / (len(p3) * samples2)) / per_ray_bvh:.0f}x"
    )


if __name__ == "__main__":
    sys.exit(main())
