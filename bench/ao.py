"""Benchmark: ambient occlusion rays per second, BVH build included, against Embree.

Run ``python bench/ao.py`` (``--help`` for sizes). Each ``--repeat`` round takes every
measurement once, in turn, so that all see the same machine load; the table shows medians.

* ao4d OpenCL, every vertex of a 4D mesh of about ``--tets`` tetrahedra, ``--samples`` rays per
  vertex (cosine-weighted, any hit, unlimited distance), on the spheritorus and on a second 4D
  shape (``--shapes``), once with each BVH builder: ``host`` (numpy, :func:`ao4d.bvh.build`) and
  ``device`` (OpenCL kernels, :mod:`ao4d.bvh.device`, the default where OpenCL runs). End to end
  is a first ``ambient_occlusion(mesh, samples=64)`` on a fresh mesh (the device builder runs
  inside it; the host tree is built by ``get_bvh(mesh, builder="host")`` just before); trace is
  the second call on the same mesh, build the difference.
* The peers, on a 3D torus with as many triangles, as many AO rays of the same kind (64 per
  point, ao4d's directions, from as many points spread evenly over the torus): Open3D's
  ``RaycastingScene.test_occlusions`` (Embree 4, all threads; in a process of its own, because
  its bundled TBB must not meet Intel's OpenCL runtime) and trimesh's ``intersects_any``
  (embreex: Embree from one Python thread). Build is the scene construction and the first query.
  ao4d traces exactly these rays on the same torus too (row "ao4d ... 3D torus").
* Tree quality: SAH cost of each builder's binary tree, its 8-wide form (nodes, share of slots
  used, depth) and wide nodes visited / leaf blocks tested per AO ray
  (``ao4d.raycast.traversal_counts``, on ``--quality-points`` vertices).
* The numpy backend on a smaller 4D mesh, and the BVH kernel against the brute-force kernel.

Rates count rays per wall-clock second; the machine's load average is printed before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

SHAPES = ("spheritorus", "tiger", "ditorus")


def shape_mesh(name: str, tets: float):
    """A 4D shape extracted with about ``tets`` tetrahedra (grid spacing from a first estimate)."""
    import ao4d

    if name == "spheritorus":
        field = ao4d.fields.spheritorus(1.0, 0.4)
        # the tet count grows like n^3 (a 3-manifold); n = 48 gives about 1.1M
        n = max(8, round(48 * (tets / 1.1e6) ** (1 / 3)))
        shape = (n, n, n, max(6, n // 3))
        return ao4d.extract_field(field, shape, ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))
    field = {"tiger": ao4d.fields.tiger(), "ditorus": ao4d.fields.ditorus()}[name]
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


def open3d_worker(triangles: int, n_points: int, samples: int) -> int:
    """Serve Open3D measurements over stdin/stdout: a line ``run`` -> one JSON line."""
    import open3d as o3d  # first: its bundled TBB before anything else

    tm, _, _, o, w = torus_rays(triangles, n_points, samples)
    rays = o3d.core.Tensor(np.ascontiguousarray(np.concatenate([o, w], axis=1)))
    vertices = o3d.core.Tensor(np.asarray(tm.vertices, dtype=np.float32))
    faces = o3d.core.Tensor(np.asarray(tm.faces, dtype=np.uint32))
    print(json.dumps({"ready": True, "triangles": len(tm.faces), "rays": len(o)}), flush=True)
    for line in sys.stdin:
        if line.strip() != "run":
            break
        clock = Clock()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(vertices, faces)
        scene.test_occlusions(rays[:1])  # Embree builds its BVH at the first query
        build = clock.lap()
        hit = scene.test_occlusions(rays).numpy()
        print(json.dumps(dict(build=build, trace=clock.lap(), hit=float(hit.mean()))), flush=True)
    return 0


class Open3D:
    """The worker process, started once (its setup is not timed)."""

    def __init__(self, triangles: int, n_points: int, samples: int):
        env = dict(os.environ, AO4D_PRELOAD_TBB="0")  # the worker never uses OpenCL
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--open3d-worker", str(triangles), str(n_points), str(samples)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
        )
        self.info = json.loads(self.proc.stdout.readline())

    def run(self) -> dict:
        self.proc.stdin.write("run\n")
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
    return {"build": build, "trace": clock.lap(), "hit": float(hit.mean())}


# -- ao4d ---------------------------------------------------------------------------------------


def ao4d_run(vertices, simplices, builder: str, runtime, samples: int, points=None, normals=None) -> dict:
    """A fresh mesh: build = its tree and the tree's device copy (what the first AO call adds),
    trace = the AO call."""
    import ao4d
    from ao4d import bvh, raycast

    mesh = ao4d.SimplexMesh(vertices, simplices)
    if points is None:
        mesh.vertex_normals  # noqa: B018 - computed (and cached) before the clock starts
    kwargs = {"samples": samples, "backend": "opencl", "progress": False}
    if points is not None:
        kwargs.update(points=points, normals=normals)
    clock = Clock()
    tree = raycast.get_bvh(mesh, builder=builder, runtime=runtime)
    bvh.device_tree(mesh, tree, runtime)  # the host tree's upload; the device tree has it
    build = clock.lap()
    occlusion = ao4d.ambient_occlusion(mesh, **kwargs)
    trace = clock.lap()
    assert (builder == "device") == (type(tree).__name__ == "DeviceBVH")
    return {"build": build, "trace": trace, "hit": float(np.nanmean(occlusion)),
            "rays": int(np.isfinite(occlusion).sum()) * samples}


def quality(vertices, simplices, builder, runtime, samples, n_points, rng) -> dict:
    import ao4d
    from ao4d import ao, bvh, raycast

    mesh = ao4d.SimplexMesh(vertices, simplices)
    tree = raycast.get_bvh(mesh, builder=builder, runtime=runtime)
    normals = mesh.vertex_normals
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    idx = np.sort(rng.choice(ok, size=min(n_points, ok.size), replace=False))
    nodes, blocks = raycast.traversal_counts(
        mesh, mesh.vertices[idx], normals[idx], samples=samples, offset=ao.ORIGIN_OFFSET * tree.world_diagonal,
        runtime=runtime,
    )
    _, children, _, _, wide_depth = bvh.widen_topology(tree)
    return {"sah": bvh.sah_cost(tree), "nodes": nodes, "blocks": blocks, "depth": tree.depth,
            "n_nodes": tree.n_nodes, "wide": len(children), "used": float((children != 0).mean()),
            "wide_depth": wide_depth}


def timed(fn, repeat):
    walls, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - start)
    return statistics.median(walls), result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tets", type=float, default=1.05e6, help="4D mesh size (1.05e6)")
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    parser.add_argument("--repeat", type=int, default=3, help="rounds of measurements (3)")
    parser.add_argument("--shapes", default="spheritorus,tiger", help=f"4D shapes, of {', '.join(SHAPES)}")
    parser.add_argument("--quality-points", type=int, default=20000, help="points for node-visit counts")
    parser.add_argument("--numpy-tets", type=float, default=1.5e5, help="mesh for the numpy rate")
    parser.add_argument("--numpy-points", type=int, default=500)
    parser.add_argument("--open3d-worker", nargs=3, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.open3d_worker:
        return open3d_worker(*args.open3d_worker)
    shapes = [s.strip() for s in args.shapes.split(",") if s.strip()]
    unknown = sorted(set(shapes) - set(SHAPES))
    if unknown:
        parser.error(f"--shapes: unknown {unknown}; choose from {', '.join(SHAPES)}")

    import ao4d
    from ao4d import _progress, cl, raycast

    _progress.set_enabled(False)  # no progress lines from the host builder in the table
    rng = np.random.default_rng(0)
    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        print("no OpenCL device: nothing to benchmark", file=sys.stderr)
        return 1
    print(f"device: {cl.describe(runtime)}; load average before: {load()}")
    meshes = {}
    for name in shapes:
        mesh = shape_mesh(name, args.tets)
        meshes[name] = (np.asarray(mesh.vertices), np.asarray(mesh.simplices))
        print(f"{name}: {mesh.n_simplices:,} tetrahedra, {mesh.n_vertices:,} vertices")
    # warm up: kernels loaded (4D and 3D), sampling tables ready
    v0, s0 = meshes[shapes[0]]
    small = ao4d.SimplexMesh(v0, s0[:1000])
    ao4d.ambient_occlusion(small, points=v0[:10], normals=np.eye(4)[[0] * 10], samples=4, backend="opencl")
    tiny = torus_trimesh(2000)
    ao4d.ambient_occlusion(ao4d.SimplexMesh(tiny.vertices, tiny.faces), samples=4, backend="opencl")
    primary = ao4d.SimplexMesh(v0, s0)
    n_points = int((np.linalg.norm(primary.vertex_normals, axis=1) > 0.5).sum())

    peers: dict[str, list] = {}
    worker = None
    reason = have_open3d()
    if reason is None:
        worker = Open3D(len(s0), n_points, args.samples)
        peers["Open3D RaycastingScene (Embree 4, all threads)"] = []
    else:
        print(f"Open3D comparison skipped: {reason} (pip install 'ao4d[bench]')")
    try:
        import embreex  # noqa: F401

        tm, q, m, o, w = torus_rays(len(s0), n_points, args.samples)
        peers["trimesh + embreex (Embree, one thread)"] = []
    except ImportError as exc:
        tm = None
        print(f"trimesh+Embree comparison skipped: {exc}")
        if worker is not None:
            tm, q, m, o, w = torus_rays(len(s0), n_points, args.samples)
    ours: dict[tuple[str, str], list] = {(name, b): [] for name in shapes for b in ("host", "device")}
    torus_key = ("3D torus, the peers' rays", "device")
    if tm is not None:
        ours[torus_key] = []

    for _ in range(args.repeat):
        for (name, builder) in ours:
            if (name, builder) == torus_key:
                ours[torus_key].append(ao4d_run(np.asarray(tm.vertices), np.asarray(tm.faces), "device",
                                                runtime, args.samples, q, m))
            else:
                ours[(name, builder)].append(ao4d_run(*meshes[name], builder, runtime, args.samples))
        for label in peers:
            peers[label].append(worker.run() if label.startswith("Open3D") else embree_run(tm, o, w))
    if worker is not None:
        worker.close()

    def med(runs, key, k=0):  # k = 0: wall seconds, 1: CPU seconds
        return statistics.median(r[key][k] for r in runs)

    rows = {f"ao4d OpenCL, {name}, {builder}-built tree": (runs, runs[0]["rays"])
            for (name, builder), runs in ours.items()}
    rows.update({f"{label}, 3D torus": (runs, len(o)) for label, runs in peers.items()})
    rates = {}
    for k, title in ((0, "wall clock"), (1, "CPU time (all threads; rays per CPU-second)")):
        print(f"\n{title}, medians of {args.repeat} rounds; load average after: {load()}")
        print(f"{'':<58} {'rays':>11} {'build s':>8} {'trace Mrays/s':>14} {'end-to-end Mrays/s':>19} {'hit/AO':>7}")
        for label, (runs, rays) in rows.items():
            build, trace = med(runs, "build", k), med(runs, "trace", k)
            e2e = statistics.median(r["build"][k] + r["trace"][k] for r in runs)
            rates[label, k] = (rays / trace, rays / e2e, build)
            hit = statistics.median(r["hit"] for r in runs)
            print(f"{label:<58} {rays:>11,} {build:>8.2f} {rays / trace / 1e6:>14.2f} {rays / e2e / 1e6:>19.2f} {hit:>7.3f}")

    ours_labels = [label for label in rows if label.startswith("ao4d")]
    peer_labels = [label for label in rows if not label.startswith("ao4d")]
    for k, title in ((0, "wall clock"), (1, "CPU time")):
        print(f"\nratios, {title} (trace, end to end, build; > 1: ao4d faster):")
        for peer in peer_labels:
            for label in ours_labels:
                if "device" not in label:
                    continue
                (trace, e2e, build), (p_trace, p_e2e, p_build) = rates[label, k], rates[peer, k]
                print(f"  {label[13:].split(', device')[0]} / {peer.split(' (')[0]}: trace {trace / p_trace:.2f}x, "
                      f"end to end {e2e / p_e2e:.2f}x, build {p_build / build:.2f}x")
        for name in shapes:
            (ht, he, hb) = rates[f"ao4d OpenCL, {name}, host-built tree", k]
            (dt, de, db) = rates[f"ao4d OpenCL, {name}, device-built tree", k]
            print(f"  {name}: device tree / host tree: trace {dt / ht:.2f}x, build {hb / db:.1f}x faster, "
                  f"end to end {de / he:.2f}x")
    o3d_label = next((label for label in peer_labels if label.startswith("Open3D")), None)
    if o3d_label:
        trace, e2e, _ = rates[f"ao4d OpenCL, {shapes[0]}, device-built tree", 0]
        p_trace, p_e2e, _ = rates[o3d_label, 0]
        for what, ratio in (("end to end", e2e / p_e2e), ("trace", trace / p_trace)):
            print(f"target: {shapes[0]} {what} >= 1.0x Open3D (wall clock): {ratio:.2f}x, "
                  f"{'met' if ratio >= 1.0 else 'missed'}")

    print(f"\ntree quality (AO rays from {args.quality_points:,} random vertices):")
    print(f"{'':<30} {'SAH cost':>9} {'nodes/ray':>10} {'blocks/ray':>11} {'depth':>6} {'nodes':>9}"
          f" {'wide nodes':>11} {'slots used':>11} {'wide depth':>11}")
    for name in shapes:
        for builder in ("host", "device"):
            qd = quality(*meshes[name], builder, runtime, args.samples, args.quality_points, rng)
            print(f"{name + ', ' + builder:<30} {qd['sah']:>9.1f} {qd['nodes']:>10.2f} {qd['blocks']:>11.2f} "
                  f"{qd['depth']:>6} {qd['n_nodes']:>9,} {qd['wide']:>11,} {qd['used']:>11.0%} {qd['wide_depth']:>11}")

    # the numpy backend, and the BVH kernel against brute force, on a smaller 4D mesh
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
