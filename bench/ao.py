"""Benchmark: ambient occlusion rays per second, BVH build included, against Embree.

Run ``python bench/ao.py`` (``--quick`` for small meshes, ``--help`` for sizes). Each
``--repeat`` round takes every measurement once, in turn, so that all see the same machine load;
the tables show medians.

* ao4d OpenCL, every vertex of a 4D mesh of about ``--tets`` tetrahedra, ``--samples`` rays per
  vertex (cosine-weighted, any hit), on four 4D shapes (``--shapes``): the spheritorus, the
  tiger, the ditorus and a CSG of tesseracts (a tesseract with four tesseract-shaped pockets,
  deep concavities). "first call" is a first ``ambient_occlusion(mesh, samples=64)`` on a fresh
  mesh (the device builder runs inside it: build + trace); "trace" is the second call on the
  same mesh, "build" the difference; "reach d/4" a call with ``max_distance`` a quarter of the
  bounding box's diagonal. Traced by the packet kernel (``ao_bvh``: a point's rays together) and,
  as "per-ray kernel", by the kernel it replaces (``ao_bvh_rays``, one ray at a time).
* Open3D's ``RaycastingScene.test_occlusions`` (Embree 4, all threads; in a process of its own,
  because its bundled TBB must not meet Intel's OpenCL runtime), per shape on a 3D torus with as
  many triangles as the shape has tetrahedra and as many AO rays of the same kind (64 per point,
  ao4d's directions, from as many points spread evenly over the torus), once with unlimited
  reach and once with ``tfar`` a quarter of the torus's bounding-box diagonal. Build is the scene
  construction and the first query. ``--embreex`` adds trimesh's ``intersects_any`` (embreex:
  Embree from one Python thread) and ``--host-tree`` ao4d with the numpy-built tree.
* Traversal work per AO ray on ``--quality-points`` vertices (``ao4d.raycast.traversal_counts``,
  deterministic, unlike the timings): wide nodes fetched and leaf blocks fetched, per-ray kernel
  (before) and packet kernel (after); SAH cost and the 8-wide tree's nodes, slot use and depth.
* The numpy backend on a smaller 4D mesh, and the BVH kernel against the brute-force kernel.

Rates count rays per wall-clock second; the machine's load average is printed before and after.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import statistics
import subprocess
import sys
import time

import numpy as np

SHAPES = ("spheritorus", "tiger", "ditorus", "csg")


def csg_field():
    """A tesseract of half side 1 with four pockets: tesseracts of half side 0.5 turned by 30
    degrees in four planes and sunk halfway into the facets +x, +y, +z and -w (deep concavities
    whose walls occlude each other)."""
    import ao4d

    fields = ao4d.fields
    pockets = []
    for axis, sign, plane in ((0, 1, (1, 2)), (1, 1, (2, 3)), (2, 1, (0, 3)), (3, -1, (0, 1))):
        centre = np.zeros(4)
        centre[axis] = sign * 1.0
        cube = fields.rotate(fields.tesseract(0.5, 0.05), plane, math.radians(30))
        pockets.append(fields.translate(cube, centre))
    return fields.difference(fields.tesseract(1.0, 0.05), fields.union(*pockets))


def shape_mesh(name: str, tets: float):
    """A 4D shape extracted with about ``tets`` tetrahedra (grid spacing from a first estimate)."""
    import ao4d

    if name == "spheritorus":
        field = ao4d.fields.spheritorus(1.0, 0.4)
        # the tet count grows like n^3 (a 3-manifold); n = 48 gives about 1.1M
        n = max(8, round(48 * (tets / 1.1e6) ** (1 / 3)))
        shape = (n, n, n, max(6, n // 3))
        return ao4d.extract_field(field, shape, ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))
    if name == "csg":
        field, lo, hi = csg_field(), np.full(4, -1.0), np.full(4, 1.0)
    else:
        field = {"tiger": ao4d.fields.tiger, "ditorus": ao4d.fields.ditorus}[name]()
        lo, hi = np.asarray(field.extent[0], float), np.asarray(field.extent[1], float)
    pad = 0.1 * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    spacing = 0.1
    probe = ao4d.extract_field(field, tuple(np.maximum(8, np.round((hi - lo) / spacing).astype(int))), (lo, hi))
    spacing *= (probe.n_simplices / tets) ** (1 / 3)
    shape = tuple(int(k) for k in np.maximum(8, np.round((hi - lo) / spacing)))
    return ao4d.extract_field(field, shape, (lo, hi))


def torus_trimesh(triangles: int):
    import trimesh

    # trimesh's torus has 2 * major * minor triangles; keep the 4D shape's aspect (R=1, r=0.4)
    minor = max(8, int(round((triangles / 2 / 2.5) ** 0.5)))
    major = max(8, int(round(triangles / 2 / minor)))
    return trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=major, minor_sections=minor)


def torus_rays(triangles: int, n_points: int, samples: int):
    """The torus, the AO points (Morton order) and their rays: (mesh, points, normals, o, w)."""
    from ao4d import ao, raycast, sampling

    tm = torus_trimesh(triangles)
    # as many points as the 4D mesh has, evenly spread over the vertex list (trimesh's torus
    # lists its vertices ring by ring), in the Morton order ao4d sorts its points by
    idx = np.linspace(0, len(tm.vertices) - 1, n_points).round().astype(np.int64)
    q, m = tm.vertices[idx], tm.vertex_normals[idx]
    order = raycast._morton_order(q)
    q, m = q[order], m[order]
    diagonal = float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
    w = sampling.cosine_hemisphere(m, samples, seed=0).reshape(-1, 3)
    o = np.repeat(q + ao.ORIGIN_OFFSET * diagonal * m, samples, axis=0)
    return tm, q, m, o.astype(np.float32), w.astype(np.float32)


class Clock:
    """Wall and process CPU time (all threads: OpenCL's and Embree's included) since the last lap."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def lap(self) -> tuple[float, float]:
        wall, cpu = time.perf_counter(), time.process_time()
        out = (wall - self.wall, cpu - self.cpu)
        self.wall, self.cpu = wall, cpu
        return out


def load() -> str:
    try:
        return ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


# -- peers --------------------------------------------------------------------------------------


def open3d_worker() -> int:
    """Serve Open3D measurements over stdin/stdout: a JSON line ``{"triangles", "points",
    "samples", "reach"}`` (reach: tfar as a fraction of the torus's diagonal, 0 for unlimited)
    -> one JSON line. The torus and its rays are made once per size (not timed)."""
    import open3d as o3d  # first: its bundled TBB before anything else

    workloads = {}
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        job = json.loads(line)
        size = (job["triangles"], job["points"], job["samples"])
        if size not in workloads:
            tm, _, _, o, w = torus_rays(*size)
            workloads[size] = (
                o3d.core.Tensor(np.ascontiguousarray(np.concatenate([o, w], axis=1))),
                o3d.core.Tensor(np.asarray(tm.vertices, dtype=np.float32)),
                o3d.core.Tensor(np.asarray(tm.faces, dtype=np.uint32)),
                float(np.linalg.norm(np.ptp(tm.vertices, axis=0))),
            )
        rays, vertices, faces, diagonal = workloads[size]
        tfar = job["reach"] * diagonal if job["reach"] else math.inf
        clock = Clock()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(vertices, faces)
        scene.test_occlusions(rays[:1])  # Embree builds its BVH at the first query
        build = clock.lap()
        hit = scene.test_occlusions(rays, tfar=tfar).numpy()
        trace = clock.lap()
        first = [b + t for b, t in zip(build, trace)]
        print(json.dumps(dict(build=build, trace=trace, first=first, hit=float(hit.mean()),
                              rays=int(len(hit)))), flush=True)
    return 0


class Open3D:
    """The worker process, started once (its setup is not timed)."""

    def __init__(self):
        env = dict(os.environ, AO4D_PRELOAD_TBB="0")  # the worker never uses OpenCL
        self.proc = subprocess.Popen([sys.executable, __file__, "--open3d-worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        self.info = json.loads(self.proc.stdout.readline())

    def run(self, triangles: int, points: int, samples: int, reach: float = 0.0) -> dict:
        job = dict(triangles=triangles, points=points, samples=samples, reach=reach)
        self.proc.stdin.write(json.dumps(job) + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def have_open3d() -> str | None:
    """None when Open3D imports in a fresh process, else why not."""
    run = subprocess.run([sys.executable, "-c", "import open3d"], capture_output=True, text=True,
                         env=dict(os.environ, AO4D_PRELOAD_TBB="0"), check=False)
    return None if run.returncode == 0 else (run.stderr.strip().splitlines() or ["import failed"])[-1]


def embree_run(tm, o, w) -> dict:
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    clock = Clock()
    intersector = RayMeshIntersector(tm)
    intersector.intersects_any(o[:1], w[:1])  # builds Embree's BVH
    build = clock.lap()
    hit = intersector.intersects_any(o, w)
    trace = clock.lap()
    return {"build": build, "trace": trace, "first": [b + t for b, t in zip(build, trace)],
            "hit": float(hit.mean()), "rays": len(o)}


# -- ao4d ---------------------------------------------------------------------------------------


def ao4d_run(vertices, simplices, builder: str, runtime, samples: int, reach: float = 0.0) -> dict:
    """A fresh mesh: first call (build + trace), then a second call on it (trace); with
    reach > 0 both with ``max_distance`` = reach times the bounding box's diagonal."""
    import ao4d
    from ao4d import bvh, raycast

    mesh = ao4d.SimplexMesh(vertices, simplices)
    mesh.vertex_normals  # noqa: B018 - computed (and cached) before the clock starts
    kwargs = {"samples": samples, "backend": "opencl", "progress": False}
    if reach:
        kwargs["max_distance"] = reach * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    clock = Clock()
    if builder == "host":  # the numpy tree, built and uploaded before the first call
        bvh.device_tree(mesh, raycast.get_bvh(mesh, builder="host"), runtime)
    occlusion = ao4d.ambient_occlusion(mesh, **kwargs)
    first = clock.lap()
    tree = raycast.get_bvh(mesh)
    assert (builder == "device") == (type(tree).__name__ == "DeviceBVH")
    occlusion = ao4d.ambient_occlusion(mesh, **kwargs)
    trace = clock.lap()
    return {"first": first, "trace": trace, "build": tuple(f - t for f, t in zip(first, trace)),
            "hit": float(np.nanmean(occlusion)), "rays": int(np.isfinite(occlusion).sum()) * samples}


@functools.lru_cache(maxsize=None)
def _reference_traversal():
    from ao4d import raycast

    return functools.partial(raycast._ao_opencl, traversal="rays")


def per_ray_run(vertices, simplices, runtime, samples: int, reach: float = 0.0) -> dict:
    """The trace of ao4d_run with the per-ray kernel (``ao_bvh_rays``), the one before packets."""
    from ao4d import raycast

    packet = raycast._ao_opencl
    raycast._ao_opencl = _reference_traversal()
    try:
        return ao4d_run(vertices, simplices, "device", runtime, samples, reach)
    finally:
        raycast._ao_opencl = packet


def quality(vertices, simplices, runtime, samples, n_points, rng) -> dict:
    import ao4d
    from ao4d import ao, bvh, raycast

    mesh = ao4d.SimplexMesh(vertices, simplices)
    tree = raycast.get_bvh(mesh, builder="device", runtime=runtime)
    normals = mesh.vertex_normals
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    idx = np.sort(rng.choice(ok, size=min(n_points, ok.size), replace=False))
    out = {}
    for reach in (0.0, 0.25):
        for traversal in ("rays", "packet"):
            out[traversal, reach] = raycast.traversal_counts(
                mesh, mesh.vertices[idx], normals[idx], samples=samples, runtime=runtime,
                offset=ao.ORIGIN_OFFSET * tree.world_diagonal, traversal=traversal, detail=True,
                max_distance=reach * tree.world_diagonal if reach else math.inf,
            )
    _, children, _, _, wide_depth = bvh.widen_topology(tree)
    return {"counts": out, "sah": bvh.sah_cost(tree), "wide": len(children),
            "used": float((children != 0).mean()), "wide_depth": wide_depth}


def timed(fn, repeat):
    walls, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - start)
    return statistics.median(walls), result


def med(runs, key, k=0):
    """Median over rounds of ``key`` (k = 0: wall seconds, 1: CPU seconds of all threads)."""
    return statistics.median(r[key][k] for r in runs)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="small sizes: --tets 1.5e5 --quality-points 3000 --numpy-tets 3e4")
    parser.add_argument("--tets", type=float, default=None, help="4D mesh size (1.05e6)")
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    parser.add_argument("--repeat", type=int, default=3, help="rounds of measurements (3)")
    parser.add_argument("--shapes", default=",".join(SHAPES), help=f"4D shapes, of {', '.join(SHAPES)}")
    parser.add_argument("--quality-points", type=int, default=None, help="points for node-visit counts (20000)")
    parser.add_argument("--numpy-tets", type=float, default=None, help="mesh for the numpy rate (1.5e5)")
    parser.add_argument("--numpy-points", type=int, default=500)
    parser.add_argument("--host-tree", action="store_true", help="also ao4d with the numpy-built tree")
    parser.add_argument("--embreex", action="store_true", help="also trimesh + embreex (one thread)")
    parser.add_argument("--open3d-worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.open3d_worker:
        return open3d_worker()
    quick = {"tets": 1.5e5, "quality_points": 3000, "numpy_tets": 3e4}
    full = {"tets": 1.05e6, "quality_points": 20000, "numpy_tets": 1.5e5}
    for key, value in (quick if args.quick else full).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    shapes = [s.strip() for s in args.shapes.split(",") if s.strip()]
    unknown = sorted(set(shapes) - set(SHAPES))
    if unknown:
        parser.error(f"--shapes: unknown {unknown}; choose from {', '.join(SHAPES)}")

    import ao4d
    from ao4d import _progress, cl

    _progress.set_enabled(False)  # no progress lines from the host builder in the table
    rng = np.random.default_rng(0)
    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        print("no OpenCL device: nothing to benchmark", file=sys.stderr)
        return 1
    print(f"device: {cl.describe(runtime)}; load average before: {load()}")
    meshes, points = {}, {}
    for name in shapes:
        mesh = shape_mesh(name, args.tets)
        meshes[name] = (np.asarray(mesh.vertices), np.asarray(mesh.simplices))
        points[name] = int((np.linalg.norm(mesh.vertex_normals, axis=1) > 0.5).sum())
        print(f"{name}: {mesh.n_simplices:,} tetrahedra, {mesh.n_vertices:,} vertices")
    # warm up: kernels loaded (4D and 3D, both traversals), sampling tables ready
    v0, s0 = meshes[shapes[0]]
    small = ao4d.SimplexMesh(v0, s0[:1000])
    for run in (ao4d_run, per_ray_run):
        run(small.vertices, small.simplices, *(("device",) if run is ao4d_run else ()), runtime, 4)
    tiny = torus_trimesh(2000)
    ao4d.ambient_occlusion(ao4d.SimplexMesh(tiny.vertices, tiny.faces), samples=4, backend="opencl")

    reason = have_open3d()
    worker = Open3D() if reason is None else None
    if worker is None:
        print(f"Open3D comparison skipped: {reason} (pip install 'ao4d[bench]')")
    embree = None
    if args.embreex:
        try:
            import embreex  # noqa: F401

            embree = {name: torus_rays(len(meshes[name][1]), points[name], args.samples) for name in shapes}
        except ImportError as exc:
            print(f"trimesh+Embree comparison skipped: {exc}")
    runs: dict[tuple[str, str], list] = {}
    for _ in range(args.repeat):
        for name in shapes:
            v, s = meshes[name]
            todo = {
                "ao4d": lambda: ao4d_run(v, s, "device", runtime, args.samples),
                "ao4d d/4": lambda: ao4d_run(v, s, "device", runtime, args.samples, 0.25),
                "per-ray": lambda: per_ray_run(v, s, runtime, args.samples),
                "per-ray d/4": lambda: per_ray_run(v, s, runtime, args.samples, 0.25),
            }
            if args.host_tree:
                todo["ao4d host tree"] = lambda: ao4d_run(v, s, "host", runtime, args.samples)
            if worker is not None:
                todo["Open3D"] = lambda: worker.run(len(s), points[name], args.samples)
                todo["Open3D d/4"] = lambda: worker.run(len(s), points[name], args.samples, 0.25)
            if embree is not None:
                todo["embreex"] = lambda: embree_run(embree[name][0], *embree[name][3:])
            for label, fn in todo.items():
                runs.setdefault((name, label), []).append(fn())
    if worker is not None:
        worker.close()
    report(runs, shapes, args.repeat)

    print(f"\ntraversal work per AO ray ({args.quality_points:,} random vertices, deterministic): "
          "wide nodes fetched, leaf blocks fetched; before = per-ray kernel, after = packet kernel")
    print(f"{'':<22} {'nodes before':>12} {'after':>7} {'ratio':>6} {'blocks before':>14} {'after':>7} {'ratio':>6}"
          f" {'SAH':>6} {'wide nodes':>11} {'slots used':>11} {'wide depth':>11}")
    for name in shapes:
        qd = quality(*meshes[name], runtime, args.samples, args.quality_points, rng)
        for reach in (0.0, 0.25):
            before, after = qd["counts"]["rays", reach], qd["counts"]["packet", reach]
            label = name + (", reach d/4" if reach else "")
            tail = (f" {qd['sah']:>6.1f} {qd['wide']:>11,} {qd['used']:>11.0%} {qd['wide_depth']:>11}"
                    if not reach else "")
            print(f"{label:<22} {before[0]:>12.2f} {after[0]:>7.2f} {before[0] / after[0]:>5.1f}x"
                  f" {before[1]:>14.2f} {after[1]:>7.2f} {before[1] / after[1]:>5.1f}x{tail}")
        assert qd["counts"]["packet", 0.0][2:] == qd["counts"]["rays", 0.0][2:]  # same tests per ray
    numpy_and_brute(args, runtime, rng)
    return 0


def report(runs, shapes, repeat) -> None:
    """The speed table and the ratios against Open3D."""
    print(f"\nmedians of {repeat} rounds taken in turn (wall clock; CPU time of all threads in brackets); "
          f"load average after: {load()}")
    print(f"{'':<34} {'rays':>11} {'build s':>8} {'trace Mrays/s':>14} {'first call Mrays/s':>19} {'hit/AO':>7}")
    rate = {}
    for (name, label), rs in runs.items():
        rays = rs[0]["rays"]
        row = [rays / med(rs, "trace", k) for k in (0, 1)]
        first = [rays / med(rs, "first", k) for k in (0, 1)]
        rate[name, label] = row, first
        build = med(rs, "build")
        hit = statistics.median(r["hit"] for r in rs)
        print(f"{name + ', ' + label:<34} {rays:>11,} {build:>8.2f} {row[0] / 1e6:>6.2f} ({row[1] / 1e6:>5.2f})"
              f" {first[0] / 1e6:>10.2f} ({first[1] / 1e6:>5.2f}) {hit:>7.3f}")
    if not any(label == "Open3D" for _, label in runs):
        return
    print("\nratios (> 1: ao4d faster; wall clock, CPU time in brackets); targets: trace and first call >= 1.0x Open3D")
    for name in shapes:
        for reach in ("", " d/4"):
            (t, f), (pt, pf) = rate[name, "ao4d" + reach], rate[name, "Open3D" + reach]
            (bt, _) = rate[name, "per-ray" + reach]
            verdict = "met" if min(t[0] / pt[0], f[0] / pf[0]) >= 1.0 else "missed"
            print(f"  {name + reach + ':':<18} trace {t[0] / pt[0]:.2f}x ({t[1] / pt[1]:.2f}x), first call "
                  f"{f[0] / pf[0]:.2f}x ({f[1] / pf[1]:.2f}x); packets / per-ray kernel {t[0] / bt[0]:.2f}x "
                  f"({t[1] / bt[1]:.2f}x): {verdict}")


def numpy_and_brute(args, runtime, rng) -> None:
    """The numpy backend, and the BVH kernel against brute force, on a smaller 4D mesh."""
    import ao4d
    from ao4d import raycast

    small = shape_mesh("spheritorus", args.numpy_tets)
    small_tree = raycast.get_bvh(small, runtime=runtime)
    ok = np.flatnonzero(np.linalg.norm(small.vertex_normals, axis=1) > 0.5)
    pick = rng.choice(ok, size=min(args.numpy_points, ok.size), replace=False)
    p2, n2 = small.vertices[pick], small.vertex_normals[pick]
    samples2 = 16
    t_np, _ = timed(lambda: ao4d.ambient_occlusion(small, points=p2, normals=n2, samples=samples2, backend="numpy"), 1)
    p3, n3 = p2[:40], n2[:40]
    t_brute, a_brute = timed(
        lambda: ao4d.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl", accel="brute"), 1
    )
    a_bvh = ao4d.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl")
    assert np.array_equal(a_brute, a_bvh), "BVH and brute force disagree"
    pick4 = rng.choice(ok, size=min(20000, ok.size), replace=False)
    t_bvh, _ = timed(lambda: ao4d.ambient_occlusion(small, points=small.vertices[pick4],
                                                    normals=small.vertex_normals[pick4], samples=samples2,
                                                    backend="opencl"), args.repeat)
    per_ray_bvh = t_bvh / (len(pick4) * samples2)
    print(f"\nao4d numpy backend, 4D, {small_tree.n_prims:,} tets: {len(p2) * samples2 / t_np / 1e6:.3f} M rays/s")
    print(f"BVH speed-up over brute force ({small_tree.n_prims:,} tets, per ray): "
          f"{(t_brute / (len(p3) * samples2)) / per_ray_bvh:.0f}x")


if __name__ == "__main__":
    sys.exit(main())
