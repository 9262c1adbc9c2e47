"""Benchmark: ambient occlusion rays per second, BVH build included, against Embree.

Run ``python bench/ao.py`` (``--quick`` for small meshes, ``--help`` for sizes). Each of the
``--rounds`` rounds (5) takes every measurement once, in turn, so that all see the same machine
load; the tables show medians, and every ratio its median with the minimum and maximum over the
rounds (each round's ao4d figure against the same round's Open3D figure). The machine line (CPU,
SIMD width, L2, L3, OpenCL device and driver) comes first; a round that starts on a busy machine
is flagged loudly (``bench/_protocol.py``).

* ao4d OpenCL, every vertex of a 4D mesh of about ``--tets`` tetrahedra, ``--samples`` rays per
  vertex (cosine-weighted, any hit), on six 4D shapes (``--shapes``): the spheritorus, the
  tiger, the ditorus, a CSG of tesseracts (a tesseract with four tesseract-shaped pockets,
  deep concavities), and two with dense mutual occlusion: three interlocked 4D tori around a
  ball (``tori``) and a cluster of 40 4D metaballs (``metaballs``), mean AO 0.17-0.18. "first call" is a first ``ambient_occlusion(mesh, samples=64)`` on a fresh
  mesh (the device builder runs inside it: build + trace); "trace" is the second call on the
  same mesh, "build" the difference; "reach d/4" a call with ``max_distance`` a quarter of the
  bounding box's diagonal. Traced by the packet kernel (``ao_bvh``: a point's rays together) and,
  as "per-ray kernel", by the kernel it replaces (``ao_bvh_rays``, one ray at a time).
* Open3D's ``RaycastingScene.test_occlusions`` (Embree 4, all threads; in a process of its own,
  because its bundled TBB must not meet Intel's OpenCL runtime), per shape on a 3D torus with as
  many triangles as the shape has tetrahedra and as many AO rays of the same kind (64 per point,
  ao4d's directions, from as many points spread evenly over the torus), once with unlimited
  reach and once with ``tfar`` a quarter of the torus's bounding-box diagonal. Build is the scene
  construction and the first query. For the two dense shapes Open3D also traces their 3D
  analogues (``dense3d_trimesh``: three tori around a ball, 40 metaballs; as many triangles and
  rays per point; ``--no-dense-3d`` leaves them out), which says how Embree fares with dense
  mutual occlusion in its own dimension: context printed beside the ratios, whose peer stays
  the torus. The worker runs under ``AO4D_BENCH_OPEN3D_PYTHON`` when set
  (a virtual environment with Open3D, made with ``--system-site-packages``), else this Python. ``--embreex`` adds trimesh's ``intersects_any`` (embreex:
  Embree from one Python thread) and ``--host-tree`` ao4d with the numpy-built tree.
* Traversal work per AO ray on ``--quality-points`` vertices (``ao4d.raycast.traversal_counts``,
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
import json
import math
import os
import statistics
import subprocess
import sys
import time

import numpy as np

_BENCH = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, _BENCH)
import _protocol as protocol  # noqa: E402  (bench/_protocol.py)

protocol.use_checkout(_BENCH)  # the ao4d of this checkout, not another one installed

SHAPES = ("spheritorus", "tiger", "ditorus", "csg", "tori", "metaballs")
CEILING_SHRINK = 16  # the cache ceiling's small meshes: --tets / 16 tetrahedra (a 1 M-tet tree's 114 MB -> 7 MB)
DENSE = ("tori", "metaballs")  # dense mutual occlusion: Embree also traces their 3D analogues


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


def tori_field():
    """Three interlocked 4D tori around a ball: torispheres (a circle of radius 0.9 swept by a
    3-ball of radius 0.28) whose core circles lie in the xy plane, the zw plane and a plane
    turned between them, united with a hypersphere of radius 0.6 at their common centre."""
    import ao4d

    fields = ao4d.fields

    def torus():
        return fields.torisphere(0.9, 0.28)

    second = fields.rotate(fields.rotate(torus(), (0, 2), math.pi / 2), (1, 3), math.pi / 2)
    third = fields.rotate(fields.rotate(torus(), (1, 2), math.pi / 2), (0, 3), math.pi / 4)
    return fields.union(fields.hypersphere(0.6), torus(), second, third)


def metaballs_field():
    """A cluster of 40 4D metaballs of radius 0.3 (sharpness 8) at random centres in
    [-0.8, 0.8]^4 (seed 3): narrow crevices between the balls."""
    import ao4d

    centres = np.random.default_rng(3).uniform(-0.8, 0.8, size=(40, 4))
    return ao4d.fields.metaballs(centres, 0.3, sharpness=8.0)


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
        field = {
            "tiger": ao4d.fields.tiger,
            "ditorus": ao4d.fields.ditorus,
            "tori": tori_field,
            "metaballs": metaballs_field,
        }[name]()
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


def dense3d_field(kind: str):
    """A 3D analogue of a dense 4D shape, negative inside, on (N, 3) points: ``"tori"``, three
    tori (core circles of radius 0.9 in the xy plane, the yz plane and the xz plane turned by 45
    degrees about z; tubes of radius 0.28) around a ball of radius 0.6; ``"metaballs"``, 40
    metaballs of radius 0.3 and sharpness 8 (:func:`ao4d.fields.metaballs`' formula) at random
    centres in [-0.8, 0.8]^3 (seed 3)."""
    if kind == "tori":

        def torus(p):  # core circle in the plane of the first two columns
            return np.hypot(np.hypot(p[:, 0], p[:, 1]) - 0.9, p[:, 2]) - 0.28

        c = math.sqrt(0.5)
        turn = np.array([[c, -c, 0.0], [c, c, 0.0], [0.0, 0.0, 1.0]])
        return lambda p: np.minimum.reduce(
            [np.linalg.norm(p, axis=1) - 0.6, torus(p), torus(p[:, [1, 2, 0]]), torus((p @ turn)[:, [0, 2, 1]])]
        )
    if kind == "metaballs":
        centres = np.random.default_rng(3).uniform(-0.8, 0.8, size=(40, 3))

        def blobs(p):
            total = np.zeros(len(p))
            for c in centres:
                total += np.exp(-8.0 * (((p - c) ** 2).sum(axis=1) / 0.09 - 1.0))
            return 1.0 - total

        return blobs
    raise ValueError(f"no dense 3D analogue of {kind!r}")


def dense3d_trimesh(kind: str, triangles: int):
    """:func:`dense3d_field`'s surface with about ``triangles`` triangles (scikit-image's
    marching cubes on [-1.5, 1.5]^3, evaluated a slab at a time), facing outwards."""
    import trimesh
    from skimage.measure import marching_cubes

    field = dense3d_field(kind)

    def extract(n: int):
        axis = np.linspace(-1.5, 1.5, n)
        yz = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
        values = np.empty((n, n, n))
        for i, x in enumerate(axis):
            values[i] = field(np.column_stack([np.full(len(yz), x), yz])).reshape(n, n)
        v, f, _, _ = marching_cubes(values, 0.0, spacing=(axis[1] - axis[0],) * 3)
        return trimesh.Trimesh(v - 1.5, f, process=False)

    probe = extract(48)  # the triangle count grows like n^2 (a surface)
    tm = extract(max(16, round(48 * math.sqrt(triangles / len(probe.faces)))))
    if tm.volume < 0:
        tm.invert()
    return tm


def torus_rays(triangles: int, n_points: int, samples: int, kind: str = "torus"):
    """The torus (or the :func:`dense3d_trimesh` of ``kind``), the AO points (Morton order) and
    their rays: (mesh, points, normals, o, w)."""
    from ao4d import ao, raycast, sampling

    tm = torus_trimesh(triangles) if kind == "torus" else dense3d_trimesh(kind, triangles)
    # as many points as the 4D mesh has, evenly spread over the vertex list (trimesh's torus
    # lists its vertices ring by ring, marching cubes slab by slab), in the Morton order ao4d
    # sorts its points by
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
    """The load averages (``bench/_protocol.py``)."""
    return protocol.load_average()


# -- peers --------------------------------------------------------------------------------------


def open3d_worker() -> int:
    """Serve Open3D measurements over stdin/stdout: a JSON line ``{"triangles", "points",
    "samples", "reach", "kind"}`` (reach: tfar as a fraction of the mesh's diagonal, 0 for
    unlimited; kind: the torus, or a :func:`dense3d_trimesh`) -> one JSON line. The mesh and
    its rays are made once per kind and size (not timed)."""
    import open3d as o3d  # first: its bundled TBB before anything else

    workloads = {}
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        job = json.loads(line)
        size = (job["triangles"], job["points"], job["samples"], job.get("kind", "torus"))
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
        # the last scene goes before the clock starts: its teardown is not in this build's time
        # (nor beside the other side's runs), and its memory is free just before the build, as
        # when a new scene replaces it (on the project's VM, memory freed before ao4d's runs
        # came back as fresh pages that made Embree's builds 0.2-0.35 s slower)
        scene = hit = None
        clock = Clock()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(vertices, faces)
        scene.test_occlusions(rays[:1])  # Embree builds its BVH at the first query
        build = clock.lap()
        hit = scene.test_occlusions(rays, tfar=tfar).numpy()
        trace = clock.lap()
        first = [b + t for b, t in zip(build, trace)]
        print(
            json.dumps(dict(build=build, trace=trace, first=first, hit=float(hit.mean()), rays=int(len(hit)))),
            flush=True,
        )
    return 0


def open3d_python() -> str:
    """The Python that runs the Open3D worker: ``AO4D_BENCH_OPEN3D_PYTHON`` (an environment
    holding Open3D beside this one's packages), else this one."""
    return os.environ.get("AO4D_BENCH_OPEN3D_PYTHON") or sys.executable


class Open3D:
    """The worker process, started once (its setup is not timed)."""

    def __init__(self):
        env = dict(os.environ, AO4D_PRELOAD_TBB="0")  # the worker never uses OpenCL
        self.proc = subprocess.Popen(
            [open3d_python(), os.path.abspath(__file__), "--open3d-worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        self.info = self._answer()

    def _answer(self) -> dict:
        """The worker's next line as JSON; a worker that died says so (its traceback is above,
        on the shared stderr) instead of a JSON error on an empty line."""
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(
                f"the Open3D worker ({open3d_python()}) exited with {self.proc.wait()}: see its "
                "error above (its Python needs open3d and trimesh: AO4D_BENCH_OPEN3D_PYTHON)"
            )
        return json.loads(line)

    def run(self, triangles: int, points: int, samples: int, reach: float = 0.0, kind: str = "torus") -> dict:
        job = dict(triangles=triangles, points=points, samples=samples, reach=reach, kind=kind)
        self.proc.stdin.write(json.dumps(job) + "\n")
        self.proc.stdin.flush()
        return self._answer()

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def have_open3d() -> str | None:
    """None when Open3D imports in a fresh process, else why not."""
    run = subprocess.run(
        [open3d_python(), "-c", "import open3d"],
        capture_output=True,
        text=True,
        env=dict(os.environ, AO4D_PRELOAD_TBB="0"),
        check=False,
    )
    return None if run.returncode == 0 else (run.stderr.strip().splitlines() or ["import failed"])[-1]


def embree_run(tm, o, w) -> dict:
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    clock = Clock()
    intersector = RayMeshIntersector(tm)
    intersector.intersects_any(o[:1], w[:1])  # builds Embree's BVH
    build = clock.lap()
    hit = intersector.intersects_any(o, w)
    trace = clock.lap()
    return {
        "build": build,
        "trace": trace,
        "first": [b + t for b, t in zip(build, trace)],
        "hit": float(hit.mean()),
        "rays": len(o),
    }


# -- ao4d ---------------------------------------------------------------------------------------


def ao4d_run(vertices, simplices, builder: str, runtime, samples: int, reach: float = 0.0, traces: int = 1) -> dict:
    """A fresh mesh: first call (build + trace), then a second call on it (trace); with
    reach > 0 both with ``max_distance`` = reach times the bounding box's diagonal. With
    ``traces`` > 1 the trace is the median of that many calls (short calls on small meshes)."""
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


def tree_bytes(vertices, simplices, runtime) -> dict:
    """Bytes of the traversed tree (the wide nodes and the leaf blocks the kernels fetch) of
    the mesh, in all and per tetrahedron, and the leaf blocks' lane occupancy."""
    import ao4d
    from ao4d import bvh, raycast

    mesh = ao4d.SimplexMesh(vertices, simplices)
    tree = raycast.get_bvh(mesh, builder="device", runtime=runtime)
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small sizes: --tets 1.5e5 --quality-points 3000 --numpy-tets 3e4 --rounds 2",
    )
    parser.add_argument("--tets", type=float, default=None, help="4D mesh size (1.05e6)")
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    parser.add_argument(
        "--rounds",
        "--repeat",
        dest="rounds",
        type=int,
        default=None,
        help="rounds of measurements taken in turn (5; --quick: 2)",
    )
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
    parser.add_argument("--open3d-worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.open3d_worker:
        return open3d_worker()
    quick = {"tets": 1.5e5, "quality_points": 3000, "numpy_tets": 3e4, "rounds": 2}
    full = {"tets": 1.05e6, "quality_points": 20000, "numpy_tets": 1.5e5, "rounds": 5}
    for key, value in (quick if args.quick else full).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    shapes = [s.strip() for s in args.shapes.split(",") if s.strip()]
    unknown = sorted(set(shapes) - set(SHAPES))
    if unknown:
        parser.error(f"--shapes: unknown {unknown}; choose from {', '.join(SHAPES)}")

    import ao4d
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
    meshes, points = {}, {}
    for name in shapes:
        mesh = shape_mesh(name, args.tets)
        meshes[name] = (np.asarray(mesh.vertices), np.asarray(mesh.simplices))
        points[name] = int((np.linalg.norm(mesh.vertex_normals, axis=1) > 0.5).sum())
        print(f"{name}: {mesh.n_simplices:,} tetrahedra, {mesh.n_vertices:,} vertices", flush=True)
    ceiling = {}  # the cache ceiling's small meshes
    if args.cache_ceiling:
        for name in shapes:
            mesh = shape_mesh(name, args.tets / CEILING_SHRINK)
            ceiling[name] = (np.asarray(mesh.vertices), np.asarray(mesh.simplices))
            print(f"{name}, small: {mesh.n_simplices:,} tetrahedra (the cache ceiling's mesh)", flush=True)
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
    quiet = []
    for index in range(args.rounds):
        quiet.append(protocol.check_round(index, args.rounds))
        for name in shapes:
            v, s = meshes[name]
            todo = {
                "ao4d": lambda: ao4d_run(v, s, "device", runtime, args.samples),
                "ao4d d/4": lambda: ao4d_run(v, s, "device", runtime, args.samples, 0.25),
            }
            if args.per_ray:
                todo["per-ray"] = lambda: per_ray_run(v, s, runtime, args.samples)
                todo["per-ray d/4"] = lambda: per_ray_run(v, s, runtime, args.samples, 0.25)
            if name in ceiling:
                todo["ao4d small"] = lambda: ao4d_run(*ceiling[name], "device", runtime, args.samples, traces=5)
            if args.host_tree:
                todo["ao4d host tree"] = lambda: ao4d_run(v, s, "host", runtime, args.samples)
            if worker is not None:
                todo["Open3D"] = lambda: worker.run(len(s), points[name], args.samples)
                todo["Open3D d/4"] = lambda: worker.run(len(s), points[name], args.samples, 0.25)
                if name in DENSE and args.dense_3d:
                    todo["Open3D dense 3D"] = lambda: worker.run(len(s), points[name], args.samples, 0.0, name)
                    todo["Open3D dense 3D d/4"] = lambda: worker.run(len(s), points[name], args.samples, 0.25, name)
            if embree is not None:
                todo["embreex"] = lambda: embree_run(embree[name][0], *embree[name][3:])
            for label, fn in todo.items():
                runs.setdefault((name, label), []).append(fn())
    if worker is not None:
        worker.close()
    report(runs, shapes, args.rounds, quiet)

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
    tests = {}  # box and block tests per ray, packet kernel, unlimited reach
    for name in shapes:
        qd = quality(*meshes[name], runtime, args.samples, args.quality_points, rng)
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
        # tests a ray makes before its first hit (tests/test_raycast.py bounds the difference)
    small_tests = {
        name: tests_per_ray(*mesh, runtime, args.samples, args.quality_points, rng) for name, mesh in ceiling.items()
    }
    ceiling_report(runs, shapes, {name: (tests[name], small_tests[name]) for name in ceiling})
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


def report(runs, shapes, rounds, quiet=None) -> None:
    """The speed table (medians) and, per shape, every ratio against Open3D as its median and
    min–max over the rounds."""
    quiet = [True] * rounds if quiet is None else quiet
    noisy = [i + 1 for i, q in enumerate(quiet) if not q]
    print(
        f"\nmedians of {rounds} rounds taken in turn (wall clock; CPU time of all threads in brackets); "
        f"load average after: {protocol.load_average()}"
    )
    if noisy:
        print(f"!!! WARNING: rounds {noisy} started on a busy machine: these are not quiet figures !!!")
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
        f"\nratios, median (min–max) over {rounds} rounds, each round's ao4d against the same round's "
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
        lambda: ao4d.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl", accel="brute"),
        1,
    )
    a_bvh = ao4d.ambient_occlusion(small, points=p3, normals=n3, samples=samples2, backend="opencl")
    assert np.array_equal(a_brute, a_bvh), "BVH and brute force disagree"
    pick4 = rng.choice(ok, size=min(20000, ok.size), replace=False)
    t_bvh, _ = timed(
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
