"""Benchmark: 4D ambient occlusion rays per second (OpenCL) against trimesh + Embree in 3D.

Run ``python bench/ao.py`` (``--help`` for sizes). In one run it times, each ``--repeat`` times
(median, the three measurements taken in turn so that all see the same machine load):

* ao4d OpenCL: ``ambient_occlusion(mesh, samples=64)`` at every vertex of a 4D spheritorus mesh
  of about ``--tets`` tetrahedra (cosine-weighted, any-hit, unlimited distance; the call's
  whole time, BVH build excluded: it is built once per mesh and cached);
* trimesh + embreex: ``RayMeshIntersector.intersects_any`` for as many AO rays of the same kind
  (64 per point, ao4d's directions, from as many points spread evenly over the vertex list) on a
  3D torus mesh with the same number of triangles, with the points once in the mesh's vertex
  order and once sorted along the Morton curve that ao4d sorts its points by (coherent rays
  run faster in Embree too: the target is checked against the faster of the two);
* the numpy backend on a smaller 4D mesh, and the BVH kernel against the brute-force kernel.

Rates count rays traced per wall-clock second. Rays from a surface differ in difficulty between
shapes; the hit fractions are printed so the workloads can be compared.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np


def spheritorus_mesh(tets: int):
    import ao4d

    field = ao4d.fields.spheritorus(1.0, 0.4)
    # the tet count grows like n^3 (a 3-manifold); n = 48 gives about 1.1M
    n = max(8, round(48 * (tets / 1.1e6) ** (1 / 3)))
    shape = (n, n, n, max(6, n // 3))
    return ao4d.extract_field(field, shape, ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))


def torus_trimesh(triangles: int):
    import trimesh

    # trimesh's torus has 2 * major * minor triangles; keep the 4D shape's aspect (R=1, r=0.4)
    minor = max(8, int(round((triangles / 2 / 2.5) ** 0.5)))
    major = max(8, int(round(triangles / 2 / minor)))
    return trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=major, minor_sections=minor)


def ao_rays(points, normals, samples, diagonal, seed=0):
    from ao4d import ao, sampling

    w = sampling.cosine_hemisphere(normals, samples, seed=seed).reshape(-1, points.shape[1])
    o = np.repeat(points + ao.ORIGIN_OFFSET * diagonal * normals, samples, axis=0)
    return o, w


def pick(rng, vertices, normals, k):
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    idx = rng.choice(ok, size=min(k, ok.size), replace=False)
    return vertices[idx], normals[idx]


def timed(fn, repeat):
    """Median wall time and median process CPU time (all threads, OpenCL's included)."""
    import os

    walls, cpus, result = [], [], None
    for _ in range(repeat):
        c0, start = os.times(), time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - start)
        c1 = os.times()
        cpus.append((c1.user - c0.user) + (c1.system - c0.system))
    return statistics.median(walls), statistics.median(cpus), result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tets", type=float, default=1.0e6, help="4D mesh size (1e6)")
    parser.add_argument("--points", type=int, default=0, help="AO at this many random vertices (0: every vertex)")
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    parser.add_argument("--repeat", type=int, default=3, help="timings per measurement (3)")
    parser.add_argument("--numpy-tets", type=float, default=1.5e5, help="mesh for the numpy rate")
    parser.add_argument("--numpy-points", type=int, default=500)
    args = parser.parse_args(argv)

    from ao4d import ao, bvh, cl

    rng = np.random.default_rng(0)
    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        print("no OpenCL device: nothing to benchmark", file=sys.stderr)
        return 1
    rows = []

    mesh = spheritorus_mesh(int(args.tets))
    start = time.perf_counter()
    tree = bvh.get_bvh(mesh)
    build = time.perf_counter() - start
    normals = mesh.vertex_normals
    n_points = int((np.linalg.norm(normals, axis=1) > 0.5).sum())  # vertices with a normal
    if args.points:
        n_points = min(n_points, args.points)
    rays = n_points * args.samples
    ao.ambient_occlusion(mesh, points=mesh.vertices[:100], normals=normals[:100], samples=4, backend="opencl")
    print(f"device: {runtime.name}; BVH of {tree.n_prims:,} tets built in {build:.1f} s "
          f"({tree.n_nodes:,} nodes, depth {tree.depth})")

    if args.points:
        p, n = pick(rng, mesh.vertices, normals, n_points)

        def run_ours():
            return ao.ambient_occlusion(mesh, points=p, normals=n, samples=args.samples, backend="opencl", progress=False)
    else:

        def run_ours():
            return ao.ambient_occlusion(mesh, samples=args.samples, backend="opencl", progress=False)

    embree_runs, tm = {}, None
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        tm = torus_trimesh(tree.n_prims)
        # as many points as ours, evenly spread over the vertex list (trimesh's torus lists its
        # vertices ring by ring: neighbours in the list are neighbours on the surface)
        idx = np.linspace(0, len(tm.vertices) - 1, n_points).round().astype(np.int64)
        q, m = tm.vertices[idx], tm.vertex_normals[idx]
        diagonal = float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
        intersector = RayMeshIntersector(tm)
        for label, order in (("vertex order", np.arange(n_points)), ("Morton order", ao._morton_order(q))):
            o, w = ao_rays(q[order], m[order], args.samples, diagonal)
            o, w = o.astype(np.float32), w.astype(np.float32)  # trimesh converts to float32 anyway
            intersector.intersects_any(o[:100], w[:100])  # builds Embree's BVH

            def run_embree(o=o, w=w):
                return intersector.intersects_any(o, w)

            embree_runs[label] = run_embree
    except ImportError as exc:
        print(f"Embree comparison skipped: {exc}")

    # take the measurements in turn so that all see the same machine load
    results = {"ours": [], **{label: [] for label in embree_runs}}
    for _ in range(args.repeat):
        results["ours"].append(timed(run_ours, 1))
        for label, run in embree_runs.items():
            results[label].append(timed(run, 1))

    def medians(runs):
        return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs), runs[-1][2]

    t_cl, c_cl, a_cl = medians(results["ours"])
    rate_cl = rays / t_cl
    where = "random vertices" if args.points else "every vertex"
    rows.append((f"ao4d OpenCL, 4D, {tree.n_prims:,} tets, {where}", rays, rate_cl, rays / c_cl, np.nanmean(a_cl)))
    embree = {}
    for label in embree_runs:
        t_em, c_em, hit = medians(results[label])
        embree[label] = (rays / t_em, rays / c_em)
        rows.append((f"trimesh+Embree, 3D, {len(tm.faces):,} tris, {label}", rays, rays / t_em, rays / c_em, hit.mean()))

    small = spheritorus_mesh(int(args.numpy_tets))
    small_tree = bvh.get_bvh(small)
    p2, n2 = pick(rng, small.vertices, small.vertex_normals, args.numpy_points)
    samples2 = 16
    r2 = len(p2) * samples2
    t_np, c_np, a_np = timed(
        lambda: ao.ambient_occlusion(small, points=p2, normals=n2, samples=samples2, backend="numpy"), 1
    )
    rows.append((f"ao4d numpy, 4D, {small_tree.n_prims:,} tets", r2, r2 / t_np, r2 / c_np, a_np.mean()))
    # BVH against brute force on the same small mesh (few rays: brute force is slow)
    p3, n3 = p2[:40], n2[:40]
    r3 = len(p3) * samples2
    t_brute, c_brute, a_brute = timed(
        lambda: ao.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl", accel="brute"), 1
    )
    a_bvh = ao.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl")
    assert np.array_equal(a_brute, a_bvh), "BVH and brute force disagree"
    rows.append((f"ao4d OpenCL brute force, 4D, {small_tree.n_prims:,} tets", r3, r3 / t_brute, r3 / c_brute, a_brute.mean()))
    # the BVH's rate on the same mesh with enough rays that call overheads do not count
    p4, n4 = pick(rng, small.vertices, small.vertex_normals, 20000)
    r4 = len(p4) * samples2
    t_bvh, c_bvh, a_bvh = timed(
        lambda: ao.ambient_occlusion(small, points=p4, normals=n4, samples=samples2, backend="opencl"), args.repeat
    )
    rows.append((f"ao4d OpenCL BVH, 4D, {small_tree.n_prims:,} tets", r4, r4 / t_bvh, r4 / c_bvh, a_bvh.mean()))

    print(f"\n{'':<52} {'rays':>10} {'M rays/s':>9} {'M rays/CPU-s':>13} {'hit frac':>9}")
    for name, count, rate, cpu_rate, frac in rows:
        print(f"{name:<52} {count:>10,} {rate / 1e6:>9.3f} {cpu_rate / 1e6:>13.3f} {frac:>9.3f}")
    for label, (rate, cpu_rate) in embree.items():
        print(f"ratio ao4d / Embree ({label}): {rate_cl / rate:.2f} wall clock, "
              f"{(rays / c_cl) / cpu_rate:.2f} per CPU-second")
    if embree:
        best = max(rate for rate, _ in embree.values())
        verdict = "met" if rate_cl >= 2 * best else "missed"
        print(f"target: ao4d >= 2 x the faster Embree rate: {rate_cl / best:.2f}x, {verdict}")
    speedup = (t_brute / r3) / (t_bvh / r4)
    print(f"BVH speed-up over brute force ({small_tree.n_prims:,} tets, per ray): {speedup:.0f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
