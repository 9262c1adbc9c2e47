"""Run every OpenCL kernel of ao4d on tiny scenes; tests/test_oclgrind.py runs this under Oclgrind.

Prints one line per check and ``kernels run: ...``; exits non-zero when an answer is wrong. The
device comes from ``AO4D_DEVICE`` (the test selects Oclgrind's simulator); answers are checked
against brute force on the same device and against the numpy backend.
"""

from __future__ import annotations

import sys

import numpy as np
import pyopencl as pcl

import ao4d
from ao4d import bvh
from ao4d.bvh import device
from ao4d.marching import fields_device
from ao4d.opencl import cl
from ao4d.rays import api, launches
from ao4d.rays import rows as ray_rows

ran: set[str] = set()


def _patch() -> None:
    """Side effects of the check, applied in main() only (pytest's doctest collection imports
    this file): only the device under test (Intel's CPU runtime, which ao4d would add, carries
    its own LLVM, and two LLVMs in one process crash Oclgrind's compiler), and a record of every
    kernel enqueued."""
    cl._icd_library_candidates = lambda: []
    call = pcl.Kernel.__call__

    def recording_call(self, *args, **kwargs):
        ran.add(self.function_name)
        return call(self, *args, **kwargs)

    pcl.Kernel.__call__ = recording_call


def soup(rng, d, n):
    centres = rng.uniform(-1, 1, size=(n, 1, d))
    vertices = (centres + 0.4 * rng.normal(size=(n, d, d))).reshape(-1, d)
    simplices = np.arange(n * d).reshape(n, d)
    simplices[:3, 1] = simplices[:3, 0]  # degenerate: skipped
    simplices[3:9] = simplices[9]  # duplicates: flat centroids, no SAH split
    return ao4d.SimplexMesh(vertices, simplices)


def check(name: str, ok: bool) -> None:
    print(f"{'ok ' if ok else 'BAD'} {name}", flush=True)
    if not ok:
        sys.exit(1)


def main() -> int:
    _patch()
    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        print("no OpenCL device", file=sys.stderr)
        return 2
    print(f"device: {runtime.name}", flush=True)
    rng = np.random.default_rng(0)
    x = np.arange(8, dtype=np.float32)
    buf = pcl.Buffer(runtime.context, pcl.mem_flags.READ_WRITE | pcl.mem_flags.COPY_HOST_PTR, hostbuf=x)
    cl.build_kernels(runtime, "testing/selftest.cl", {"SCALE": 3})["scale_add"](
        runtime.queue, (8,), None, buf, np.float32(1)
    )
    out = np.empty_like(x)
    pcl.enqueue_copy(runtime.queue, out, buf)
    check("selftest scale_add", np.array_equal(out, 3 * x + 1))
    for d in (2, 3, 4):
        mesh = soup(rng, d, 60)
        host = bvh.build(mesh.vertices, mesh.simplices)
        # small subtrees and chunks: the level passes and the per-work-item subtrees both run
        tree = device.build(mesh.vertices, mesh.simplices, runtime=runtime, subtree=32, chunk=16)
        check(
            f"{d}D device tree holds every kept simplex",
            sorted(tree.prim.tolist()) == sorted(host.prim.tolist()) and tree.n_skipped == 3,
        )
        mesh.cache[f"ao4d.bvh/device/leaf={16}"] = tree
        o = rng.uniform(-1.2, 1.2, size=(48, d))
        w = rng.normal(size=(48, d))
        w[::3, 0] = 0.0  # exact zero components
        for closest in (True, False):
            fast = api.cast_rays(mesh, o, w, closest=closest, backend="opencl")
            slow = api.cast_rays(mesh, o, w, closest=closest, backend="opencl", accel="brute")
            ref = api.cast_rays(mesh, o, w, closest=closest, backend="numpy")
            check(
                f"{d}D cast closest={closest}: BVH equals brute force",
                np.array_equal(fast.hit, slow.hit) and (not closest or np.array_equal(fast.t, slow.t)),
            )
            check(f"{d}D cast closest={closest}: near numpy", np.mean(fast.hit == ref.hit) >= 0.95)
            # the other ray mapping (cast_rows_* map on fp64 devices, cast_* take the host's rays)
            launches.MAP_ON_DEVICE = not launches.MAP_ON_DEVICE
            for accel, want in (("bvh", fast), ("brute", slow)):
                other = api.cast_rays(mesh, o, w, closest=closest, backend="opencl", accel=accel)
                check(
                    f"{d}D cast closest={closest} {accel}: both ray mappings hit alike",
                    np.array_equal(other.simplex, want.simplex),
                )
            launches.MAP_ON_DEVICE = not launches.MAP_ON_DEVICE
        if "cl_khr_fp64" in runtime.device.extensions:  # any-hit rays sharing origins as packets
            shared = np.repeat(o[:6], 8, axis=0)  # runs of 8 rows, a zero component among them
            launches.CAST_PACKETS = True
            packets = api.cast_rays(mesh, shared, w, closest=False, backend="opencl")
            launches.CAST_PACKETS = "auto"
            slow = api.cast_rays(mesh, shared, w, closest=False, backend="opencl", accel="brute")
            check(f"{d}D cast packets: brute force's hits", np.array_equal(packets.hit, slow.hit))
        if "cl_khr_fp64" in runtime.device.extensions:  # the device's ray mapping: the host's bits
            frame = bvh.Frame.fit(mesh.vertices)
            got = launches.device_ray_mapping(runtime, frame, o, w, "double")
            want = ray_rows._Rays(frame, o, w).chunk(0, len(o), np.float32, 4)
            check(
                f"{d}D map_rays: the host's bits",
                all(np.array_equal(a.view(np.uint32), b.view(np.uint32)) for a, b in zip(got, want)),
            )
        p, n = o[:6], w[:6] / np.linalg.norm(w[:6], axis=1, keepdims=True)
        a = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=8, backend="opencl")
        b = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=8, backend="opencl", accel="brute")
        check(f"{d}D AO: BVH equals brute force", np.array_equal(a, b))
        # both AO kernels (packets of a point's rays, one ray at a time), 37 samples: a cut packet
        counts = {
            t: launches._ao_opencl(
                mesh, tree, runtime, p, n, 37, 0, 0.0, np.inf, "bvh", ray_rows._NullBar(), traversal=t
            )
            for t in launches.AO_TRAVERSALS
        }
        check(f"{d}D AO: packet kernel equals per-ray kernel", np.array_equal(*counts.values()))
        for traversal in launches.AO_TRAVERSALS:
            nodes, blocks = api.traversal_counts(
                mesh, p, n, samples=8, offset=0.0, runtime=runtime, traversal=traversal
            )
            check(f"{d}D traversal counts ({traversal})", nodes > 0.0 and 0.0 <= blocks)
        dirs = launches.sample_directions(runtime, n, 8, 0)
        check(f"{d}D sample directions are unit", np.allclose(np.linalg.norm(dirs, axis=2), 1, atol=1e-5))
        eight = launches.sample_directions(runtime, n, 11, 0, eight=True)
        check(f"{d}D directions eight at a time", np.array_equal(eight, launches.sample_directions(runtime, n, 11, 0)))
        # extraction (kernels/marching/march.cl): both methods, thin slabs, the numpy engine's arrays
        values = rng.standard_normal((5, 4, 6, 3)[:d])
        # rows of 35 points: classify's 16-point vectors (the last reading past the slab's
        # last point) and its scalar row ends
        wide = rng.standard_normal(((3, 35), (3, 2, 35), (2, 2, 2, 35))[d - 2])
        for method in ("cubes", "simplices"):
            for grid, chunk in ((values, 2), (wide, None)):
                ref = ao4d.extract(grid, 0.1, method=method, chunk=chunk, backend="numpy")
                got = ao4d.extract(grid, 0.1, method=method, chunk=chunk, backend="opencl")
                check(
                    f"{d}D extraction ({method}, rows of {grid.shape[-1]}) equals the numpy engine",
                    np.array_equal(ref.vertices, got.vertices) and np.array_equal(ref.simplices, got.simplices),
                )
        # a grid in one device slab: its NaNs found by the sign kernel (work-items writing one flag)
        damaged = values.copy()
        damaged.flat[[3, -1]] = np.nan
        try:
            ao4d.extract(damaged, 0.1, backend="opencl")
            found = False
        except ValueError as error:
            found = "contains 2 non-finite" in str(error)
        check(f"{d}D extraction finds NaN on the device", found)
        # the shape library's fields sampled on the device (kernels/marching/fields.cl): numpy's values
        field = ao4d.fields.spheritorus() if d == 4 else ao4d.fields.hypersphere(0.7, [0.1] * d)
        axes = ao4d.fields.grid_axes((5, 4, 6, 3)[:d], (-1.2, 1.1))
        check(
            f"{d}D field sampled on the device equals numpy",
            np.array_equal(
                fields_device.sample_layers(field, axes, 0, len(axes[-1]), runtime),
                ao4d.fields.evaluate_layers(field, axes, 0, len(axes[-1])),
            ),
        )
    # screen-space AO and its filter on a tiny image (9 directions: a cut group of eight)
    from ao4d.rendering.screen_ao import DepthVolume, denoise, screen_space_occlusion

    pair = ao4d.extract_field(
        ao4d.fields.union(ao4d.fields.hypersphere(0.5, [-0.5, 0, 0, 0]), ao4d.fields.hypersphere(0.5, [0.5, 0, 0, 0])),
        (8, 5, 5, 5),
        ([-1.1, -0.6, -0.6, -0.6], [1.1, 0.6, 0.6, 0.6]),
    )
    cam = ao4d.Camera4D([0.2, 0.3, 0, -3], [0, 0, 0, 0], fov=50)
    volume = DepthVolume.trace(pair, cam, (6, 4, 4), backend="numpy")
    hit = volume.hit.reshape(-1)
    origins, directions = (a.reshape(-1, 4) for a in cam.rays((6, 4, 4)))
    pts = origins[hit] + volume.depth.reshape(-1)[hit][:, None] * directions[hit]
    nrm = volume.normals.reshape(-1, 4)[hit]
    occ = {
        b: screen_space_occlusion(volume, pts, nrm, samples=9, max_distance=0.8, backend=b) for b in ("opencl", "numpy")
    }
    check("screen-space AO near numpy", np.mean(occ["opencl"] == occ["numpy"]) >= 0.9)
    image = np.full(hit.size, np.nan)
    image[hit] = occ["numpy"]
    smooth = {b: denoise(image.reshape(volume.shape), volume, backend=b) for b in ("opencl", "numpy")}
    check("denoise equals numpy", np.allclose(smooth["opencl"], smooth["numpy"], atol=1e-5, equal_nan=True))
    print("kernels run: " + " ".join(sorted(ran)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
