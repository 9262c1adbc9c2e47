"""Benchmark: 4D ambient occlusion rays per second (OpenCL) against trimesh + Embree in 3D.

Run ``python bench/ao.py`` (``--help`` for sizes). In one run it times, each ``--repeat`` times
(median):

* ao4d OpenCL: AO rays (``--samples`` per point, cosine-weighted, any-hit, unlimited distance)
  from ``--points`` vertices of a 4D spheritorus mesh of about ``--tets`` tetrahedra;
* trimesh + embreex: ``RayMeshIntersector.intersects_any`` for the same number of AO rays of the
  same kind on a 3D torus mesh with the same number of triangles;
* the numpy backend on a smaller 4D mesh, and the BVH kernel against the brute-force kernel.

Rates count rays traced per wall-clock second, BVH build excluded (it is built once per mesh
and cached). Rays from a surface differ in difficulty between shapes; the hit fractions are
printed so the workloads can be compared.
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
    parser.add_argument("--points", type=int, default=20000, help="AO points (20000)")
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
    p, n = pick(rng, mesh.vertices, mesh.vertex_normals, args.points)
    rays = len(p) * args.samples
    ao.ambient_occlusion(mesh, points=p[:100], normals=n[:100], samples=4, backend="opencl")  # upload, compile
    print(f"device: {runtime.name}; BVH of {tree.n_prims:,} tets built in {build:.1f} s "
          f"({tree.n_nodes:,} nodes, depth {tree.depth})")

    def run_ours():
        return ao.ambient_occlusion(mesh, points=p, normals=n, samples=args.samples, backend="opencl")

    run_embree, tm = None, None
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        tm = torus_trimesh(tree.n_prims)
        q, m = pick(rng, tm.vertices, tm.vertex_normals, args.points)
        diagonal = float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
        o, w = ao_rays(q, m, args.samples, diagonal)
        intersector = RayMeshIntersector(tm)
        intersector.intersects_any(o[:100], w[:100])  # builds Embree's BVH

        def run_embree():
            return intersector.intersects_any(o, w)
    except ImportError as exc:
        print(f"Embree comparison skipped: {exc}")

    # alternate the two so that both see the same machine load
    ours, theirs = [], []
    for _ in range(args.repeat):
        ours.append(timed(run_ours, 1))
        if run_embree is not None:
            theirs.append(timed(run_embree, 1))
    t_cl, c_cl = statistics.median(r[0] for r in ours), statistics.median(r[1] for r in ours)
    rate_cl = rays / t_cl
    rows.append((f"ao4d OpenCL, 4D, {tree.n_prims:,} tets", rays, rate_cl, rays / c_cl, ours[-1][2].mean()))
    rate_embree = None
    if theirs:
        t_em, c_em = statistics.median(r[0] for r in theirs), statistics.median(r[1] for r in theirs)
        rate_embree = rays / t_em
        rows.append((f"trimesh+Embree any-hit, 3D, {len(tm.faces):,} triangles", rays, rate_embree, rays / c_em, theirs[-1][2].mean()))

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
    if rate_embree:
        print(f"\nratio 4D OpenCL / 3D Embree (wall clock): {rate_cl / rate_embree:.2f}  (target >= 2)")
        print(f"ratio per CPU-second (both threads of ours vs Embree's one): {c_em / c_cl:.2f}")
    speedup = (t_brute / r3) / (t_bvh / r4)
    print(f"BVH speed-up over brute force ({small_tree.n_prims:,} tets, per ray): {speedup:.0f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
