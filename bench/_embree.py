"""The peer: Embree 4 through Open3D's ``RaycastingScene`` in a process of its own, or trimesh.

Open3D's bundled TBB must not meet Intel's OpenCL runtime, so :class:`Open3D` serves its
measurements from a worker process (``python -m bench._embree``, run under
``AO4D_BENCH_OPEN3D_PYTHON`` when set, else this Python) over JSON lines. The workloads are a 3D
torus with as many triangles as a 4D shape has tetrahedra (:func:`torus_trimesh`), or the 3D
analogues of the dense 4D shapes (:func:`dense3d_trimesh`), and their AO rays
(:func:`torus_rays`: ao4d's directions, from points spread evenly over the surface).
:func:`embree_run` traces the same rays with trimesh's ``intersects_any`` (embreex: Embree from
one Python thread).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from bench._protocol import Clock

ROOT = Path(__file__).resolve().parent.parent  # the repository root: the worker runs from it


def torus_trimesh(triangles: int):
    """A 3D torus (R = 1, r = 0.4, the spheritorus's aspect) of about ``triangles`` triangles."""
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
    from ao4d import ao, sampling
    from ao4d.rays import rows

    tm = torus_trimesh(triangles) if kind == "torus" else dense3d_trimesh(kind, triangles)
    # as many points as the 4D mesh has, evenly spread over the vertex list (trimesh's torus
    # lists its vertices ring by ring, marching cubes slab by slab), in the Morton order ao4d
    # sorts its points by
    idx = np.linspace(0, len(tm.vertices) - 1, n_points).round().astype(np.int64)
    q, m = tm.vertices[idx], tm.vertex_normals[idx]
    order = rows._morton_order(q)
    q, m = q[order], m[order]
    diagonal = float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
    w = sampling.cosine_hemisphere(m, samples, seed=0).reshape(-1, 3)
    o = np.repeat(q + ao.ORIGIN_OFFSET * diagonal * m, samples, axis=0)
    return tm, q, m, o.astype(np.float32), w.astype(np.float32)


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
            [open3d_python(), "-m", "bench._embree"],
            cwd=ROOT,
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
        """One measurement (:func:`open3d_worker`'s job and answer)."""
        job = dict(triangles=triangles, points=points, samples=samples, reach=reach, kind=kind)
        self.proc.stdin.write(json.dumps(job) + "\n")
        self.proc.stdin.flush()
        return self._answer()

    def close(self) -> None:
        """End the worker (its input closed, its exit awaited, its output closed)."""
        self.proc.stdin.close()
        self.proc.wait(timeout=60)
        self.proc.stdout.close()


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
    """trimesh's ``intersects_any`` (embreex, one thread) on ``tm``'s rays ``o``, ``w``: build
    and trace times (wall, CPU), the share of rays that hit and the ray count."""
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


if __name__ == "__main__":
    sys.exit(open3d_worker())
