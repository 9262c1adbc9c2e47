"""Ray casting on simplex meshes in 2D, 3D and 4D: every traversal of a mesh's tree.

Both backends trace the same rays through the same BVH (:mod:`ao4d.bvh`) with the same
ray-simplex test and barycentric tolerance ``ao4d.bvh.BARY_EPS``. The OpenCL kernels
(``kernels/ao.cl`` with ``kernels/bvh.h``) compute in float32 and traverse the tree's 8-wide form;
the numpy traversal walks the binary tree in float64. They differ only on rays that graze an edge
or the ``max_distance`` sphere.

Three traversals: :func:`cast_rays` (closest or any hit of given rays; it validates, then calls
:func:`trace`, which :func:`ao4d.render` calls directly with its :class:`Tracer`: the mesh's tree
and device copies fetched once on a resolved backend),
:func:`count_occluded` (any-hit counts of cosine-distributed rays generated on the device:
ambient occlusion), and :func:`sample_directions` (the directions that kernel traces, for tests).
On CPUs the AO kernel traces the rays of a point together as one packet from their shared origin
(``trace_packet`` in ``kernels/bvh.h``): every wide node is fetched and walked once per packet, and
each ray still meets exactly the boxes and leaf blocks the one-ray traversal tests, so the counts
are the same bits.
The trees and their device copies come from :func:`ao4d.bvh.get_bvh` and
:func:`ao4d.bvh.device_tree` (cached on the mesh); rays are mapped into a tree's frame in float64
before they are rounded for the kernels.

Work is split into launches of at most ``RAYS_PER_LAUNCH`` rays with a tqdm bar; Ctrl-C stops
between launches.

Why this stays one module: the traversals share the ray mapping into the tree's frame, the
kernels' scene arguments and the numpy reference traversal; split, each part would need the
others' private helpers.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from . import _progress
from . import bvh as _bvh
from ._validate import as_array, as_real, check_bool, check_choice, check_memory
from .bvh import BUILDERS, get_bvh
from .mesh import as_mesh
from .opencl import cl
from .opencl.pool import BufferPool
from .sampling import cosine_hemisphere, sobol_table

__all__ = [
    "cast_rays",
    "trace",
    "Tracer",
    "count_occluded",
    "sample_directions",
    "device_ray_mapping",
    "traversal_counts",
    "get_bvh",
    "RayHits",
    "mesh_arrays",
    "unit_rows",
    "progress_bar",
    "RAYS_PER_LAUNCH",
    "release_buffers",
    "ACCELS",
    "BUILDERS",
]

AO_PACKET = 32  # rays of a point traced together by the AO kernel on GPUs (kernels/bvh.h trace_packet)
AO_PACKET_CPU = 64  # on CPUs: a node fetched once serves twice the rays (5-6 % less trace time, measured)
AO_TRAVERSALS = ("packet", "rays")  # kernels ao_bvh and ao_bvh_rays; same counts
RAYS_PER_LAUNCH = 1 << 21  # ~0.5-2 s per launch on a 2-core CPU: responsive bar and Ctrl-C
ACCELS = ("bvh", "brute")
_NUMPY_RAYS_PER_STEP = 1 << 14  # bounds the (ray, node) frontier of the numpy traversal
_PROGRESS_MIN_RAYS = 1 << 22  # show a bar by default only for work this large


class RayHits:
    """Result of :func:`cast_rays`.

    Attributes
    ----------
    t : (N,) float64
        Distance along the (normalised) direction to the hit; ``inf`` on a miss.
    simplex : (N,) int64
        Index of the hit simplex in ``mesh.simplices``; -1 on a miss.
    barycentric : (N, d) float64
        Weights of the hit simplex's d vertices (in ``mesh.simplices`` order) at the hit point,
        summing to 1; zeros on a miss.

    ``t`` and ``barycentric`` are recomputed in float64 on the hit simplices when first read:
    callers that only ask whether rays hit (shadow and occlusion rays) never pay for them. For
    closest hits their arrays are made during the trace, with the misses' values, while the
    device works; any-hit calls make them only when they are read.
    """

    __slots__ = ("simplex", "_t", "_barycentric", "_pending")

    def __init__(
        self, t: np.ndarray | None, simplex: np.ndarray, barycentric: np.ndarray | None, *, pending: Any = None
    ) -> None:
        self.simplex = simplex
        self._t, self._barycentric, self._pending = t, barycentric, pending

    def _resolve(self) -> None:
        if self._pending is not None:
            self._t, self._barycentric = self._pending()
            self._pending = None

    @property
    def t(self) -> np.ndarray:
        self._resolve()
        return self._t

    @property
    def barycentric(self) -> np.ndarray:
        self._resolve()
        return self._barycentric

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: rays that hit."""
        return self.simplex >= 0

    def __repr__(self) -> str:
        return f"RayHits({len(self.simplex)} rays, {int(self.hit.sum())} hits)"


# -- input handling ---------------------------------------------------------------------------


def _reach32(max_distance: float) -> np.float32:
    """A ray length for the float32 kernels: beyond float32's range it is infinite (the trees
    span about one unit), so the cast is not an overflow warning printed to the user."""
    return np.float32(max_distance) if max_distance <= float(np.finfo(np.float32).max) else np.float32(np.inf)


def check_distance(max_distance: Any) -> float:
    """``max_distance`` as a float > 0 (``inf`` allowed: unlimited), else an error naming it."""
    return as_real(max_distance, "max_distance", finite=False, gt=0, unit=" (inf for unlimited)")


def mesh_arrays(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    """``mesh``'s vertex and simplex arrays, else an error naming ``mesh``.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        The mesh, in any form :func:`ao4d.mesh.as_mesh` takes.

    Returns
    -------
    vertices : (V, d) float64 numpy.ndarray
        The vertices.
    simplices : (S, d) int64 numpy.ndarray
        The simplices, as vertex indices.

    Raises
    ------
    TypeError
        If ``mesh`` is not a mesh.
    ValueError
        If it does not live in 2D, 3D or 4D, or has no simplices.
    """
    mesh = as_mesh(mesh)
    vertices, simplices = np.asarray(mesh.vertices), np.asarray(mesh.simplices)
    if vertices.ndim != 2 or vertices.shape[1] not in (2, 3, 4):
        raise ValueError(f"`mesh` must live in 2D, 3D or 4D, got vertices of shape {vertices.shape}")
    if simplices.ndim != 2 or simplices.shape[0] == 0:
        raise ValueError("`mesh` has no simplices: nothing can occlude or be hit")
    return vertices, simplices


def unit_rows(values: np.ndarray, name: str) -> np.ndarray:
    """Rows of ``values`` scaled to unit length; zero-length rows are an error naming ``name``.

    Parameters
    ----------
    values : (N, d) ndarray
        Vectors, one per row.
    name : str
        The parameter they came from, named in the error.

    Returns
    -------
    (N, d) ndarray
        The rows divided by their lengths.

    Raises
    ------
    ValueError
        If a row has zero (or non-finite) length.
    """
    length = np.linalg.norm(values, axis=1)
    bad = np.flatnonzero(~(length > 0))
    if bad.size:
        raise ValueError(f"`{name}` has {bad.size} zero-length row(s), first at index {bad[0]}")
    return values / length[:, None]


def progress_bar(progress: bool | None, total: int, desc: str):
    """Progress over ``total`` rays (:mod:`ao4d._progress`), shown by default only for large work.

    Parameters
    ----------
    progress : bool or None
        Show the bar; ``None`` shows it for large work only.
    total : int
        Number of rays.
    desc : str
        The bar's label.

    Returns
    -------
    context manager
        The bar: enter it, then ``update(n)`` after each batch.
    """
    show = total >= _PROGRESS_MIN_RAYS if progress is None else bool(progress)
    return _progress.bar(total, desc, unit="ray", unit_scale=True, show=show)


def _morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """Order of points along a d-dimensional Z curve (neighbouring rays trace similar nodes)."""
    lo, hi = points.min(0), points.max(0)
    q = ((points - lo) / np.where(hi > lo, hi - lo, 1.0) * ((1 << bits) - 1)).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    d = points.shape[1]
    for b in range(bits):
        for k in range(d):
            code |= ((q[:, k] >> np.uint64(b)) & np.uint64(1)) << np.uint64(b * d + k)
    return np.argsort(code, kind="stable")


def _kernels(
    runtime,
    dim: int,
    lanes: int,
    count_visits: bool = False,
    ray_type: str | None = None,
    width: int | None = None,
    source: str = "ao.cl",
) -> dict[str, Any]:
    defines = {
        "DIM": dim,
        "BARY_EPS": f"{_bvh.BARY_EPS:.9g}f",
        "WIDTH": _bvh.node_width(runtime) if width is None else width,  # the trees' (bvh.device_tree)
        "LANES": lanes,
        "STACK_SIZE": _bvh.layout.STACK_SIZE,
        "PACKET": ao_packet(runtime),
    }
    if count_visits:  # the debug variant of traversal_counts
        defines["COUNT_VISITS"] = 1
    if ray_type is not None:  # the cast_rows_* kernels, which map the caller's rows themselves
        defines["RAY_T"] = ray_type
    return cl.build_kernels(runtime, source, defines)


def ao_packet(runtime) -> int:
    """Rays of a point traced together by the AO kernel on ``runtime``'s device.

    64 on CPUs, whose large stacks hold the packet's rays (80 bytes each in 4D) in cache; 32
    on GPUs, where private memory is scarce per work-item.

    Parameters
    ----------
    runtime : ao4d.opencl.cl.Runtime
        The device that traces.

    Returns
    -------
    int
        32 or 64 (``PACKET`` of kernels/bvh.h).
    """
    import pyopencl as pcl

    return AO_PACKET_CPU if runtime.device.type & pcl.device_type.CPU else AO_PACKET


def _pad4(a: np.ndarray) -> np.ndarray:
    out = np.zeros((len(a), 4), dtype=np.float32)
    out[:, : a.shape[1]] = a
    return out


#: Let fp64 devices map cast_rays' rays into the tree's frame themselves (the ``cast_rows_*``
#: kernels), reading the caller's rows as they are; tests clear it to take the host's mapping,
#: the path of devices without ``cl_khr_fp64``. Read when a trace starts.
MAP_ON_DEVICE = True


def _trace_opencl(dev, tree, runtime, rays, max_distance, any_hit, accel, bar, results):
    """The kernels' answers for ``rays`` (:class:`_Rays`), launch by launch, into ``results``
    (:class:`_Results`; see :func:`_launches`): each launch's (count,) int32 answers are
    ``lanes * leaf block + lane`` or -1 (:func:`_tree_order` maps them to tree-order simplices).

    On a device with ``cl_khr_fp64`` each launch's rows are copied as they are into device
    buffers and the ``cast_rows_*`` kernels map them into the tree's frame in double, with the
    host's operations (the same float32 bits: ``map_ray`` in kernels/ao.cl); a zero-length
    direction comes back as -2 and is named here. That costs the host a copy of the rows
    (17 GB/s) instead of the float64 mapping (13 ns a ray: 0.135 s of a 0.92 s 3D any-hit call
    of 10 M rays, cProfile).
    Elsewhere the host maps and rounds each launch's rays straight into mapped device buffers.
    """
    import pyopencl as pcl

    queue = runtime.queue
    if not (MAP_ON_DEVICE and "cl_khr_fp64" in runtime.device.extensions):
        kernel, head = _traversal_kernel(runtime, tree.dim, dev, "cast", accel)
        write = pcl.map_flags.WRITE_INVALIDATE_REGION
        rays.check()  # before any launch

        def fill(feed, bufs, start, stop, wait):
            o, _ = pcl.enqueue_map_buffer(feed, bufs[0], write, 0, (stop - start, 4), np.float32, wait_for=wait)
            w, _ = pcl.enqueue_map_buffer(feed, bufs[1], write, 0, (stop - start, 4), np.float32)
            rays.chunk(start, stop, np.float32, 4, out=(o, w))
            return [o.base.release(feed), w.base.release(feed)]

        def launch(bufs, count, written):
            args = head + [bufs[0], bufs[1], _reach32(max_distance), np.int32(any_hit), bufs[2], bufs[3]]
            return kernel(queue, (count,), None, *args, wait_for=written)

        return _launches(runtime, rays.n, (16, 16, 4, 4), fill, launch, bar, results)

    # float32 rows are read as float32; any float64 makes both double (exact for float32 values,
    # and the same bits: _Rays.chunk promotes them alike)
    real, ray_type = _row_types(rays.origins, rays.directions)
    origins, directions = (np.ascontiguousarray(a, dtype=real) for a in (rays.origins, rays.directions))
    kernel, head = _traversal_kernel(runtime, tree.dim, dev, "cast_rows", accel, ray_type=ray_type)
    ro = pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR
    buf_frame = pcl.Buffer(runtime.context, ro, hostbuf=_frame_values(rays.frame))
    row = rays.d * np.dtype(real).itemsize
    packed = any_hit and accel == "bvh" and _casts_packets(runtime)
    if packed:
        packet_kernel, _ = _traversal_kernel(runtime, tree.dim, dev, "cast_packets", accel, ray_type=ray_type)
    packets: dict[int, np.ndarray | None] = {}  # per buffer set: the launch's packets, if any

    def fill(feed, bufs, start, stop, wait):
        if packed:
            packets[id(bufs)] = shared_origin_packets(origins[start:stop], ao_packet(runtime))
        return [
            pcl.enqueue_copy(feed, buf, rows[start:stop], is_blocking=False, wait_for=wait)
            for buf, rows in ((bufs[0], origins), (bufs[1], directions))
        ]

    def launch(bufs, count, written):
        found = packets.pop(id(bufs), None)
        if found is not None:
            args = head + [bufs[0], bufs[1], buf_frame, pcl.Buffer(runtime.context, ro, hostbuf=found)]
            args += [_reach32(max_distance), bufs[2]]
            return packet_kernel(queue, (len(found),), None, *args, wait_for=written)
        args = head + [bufs[0], bufs[1], buf_frame, _reach32(max_distance), np.int32(any_hit), bufs[2]]
        return kernel(queue, (count,), None, *args, wait_for=written)

    def check(answers):
        if answers.min() == -2:  # a zero-length direction
            rays.check()
            raise RuntimeError("the ray kernel flagged a zero-length direction the host does not see")

    return _launches(runtime, rays.n, (row, row, 4), fill, launch, bar, results, check)


def _row_types(origins: np.ndarray, directions: np.ndarray) -> tuple[type, str]:
    """The type the kernels read rays' rows in, as numpy and C name it: float32 when both arrays
    are float32, else float64 (exact for float32 values)."""
    return (np.float32, "float") if origins.dtype == directions.dtype == np.float32 else (np.float64, "double")


def _frame_values(frame) -> np.ndarray:
    """A tree frame as the kernels read it (``map_ray`` in kernels/rows.h, kernels/refine.cl):
    its centre's coordinates, then its scale, in float64."""
    return np.append(np.asarray(frame.centre, dtype=np.float64), np.float64(frame.scale))


def _launches(runtime, n: int, widths: tuple[int, ...], fill, launch, bar, results, check=None) -> None:
    """Trace ``n`` rays in launches of at most ``RAYS_PER_LAUNCH``.

    A launch uses one set of buffers of ``widths`` bytes per ray (the rays in the first two, the
    answers in the last; kept between calls in ``_launch_pool``). Two sets take turns when
    there is more than one launch: ``fill(feed, buffers, start, stop, wait)`` enqueues a
    launch's rays on a second queue (after the ``wait`` events: the set's last launch) while the
    device traces the previous launch, and returns the events that complete them;
    ``launch(buffers, count, written)`` enqueues the kernel after those; then
    ``results.launched(start, stop)`` runs while the device traces. Each launch's int32 answers
    are mapped for reading (no copy on CPUs) and handed, while the device traces the next
    launch, to ``check(answers)`` when given and then to ``results.answered(start, answers)``,
    which must copy what it keeps: the mapping ends when it returns."""
    import pyopencl as pcl

    size = min(n, RAYS_PER_LAUNCH)
    sets = 1 if n <= RAYS_PER_LAUNCH else 2
    cl.check_device_memory(
        runtime,
        {"the rays": sets * size * sum(widths[:2]), "the ray results": sets * size * sum(widths[2:])},
        task="ray tracing",
    )
    ctx, queue = runtime.context, runtime.queue
    feed = pcl.CommandQueue(ctx, runtime.device) if sets > 1 else queue  # fills while a launch runs
    with _launch_pool.take(ctx) as pooled:
        buffers = [[pooled.get(f"set {i} buffer {k}", size * w) for k, w in enumerate(widths)] for i in range(sets)]
        free: list[Any] = [None] * sets  # per set: the event after which its last launch is done with it
        traced: list[tuple[Any, np.ndarray, int, int, int]] = []  # (mapping, answers, start, stop, set) a launch
        try:
            for index, start in enumerate(range(0, n, RAYS_PER_LAUNCH)):
                stop = min(n, start + RAYS_PER_LAUNCH)
                bufs = buffers[index % sets]
                wait = None if free[index % sets] is None else [free[index % sets]]
                written = fill(feed, bufs, start, stop, wait)
                feed.flush()
                launch(bufs, stop - start, written)
                answers, mapped = pcl.enqueue_map_buffer(
                    queue, bufs[-1], pcl.map_flags.READ, 0, (stop - start,), np.int32, is_blocking=False
                )
                queue.flush()
                results.launched(start, stop)
                traced.append((mapped, answers, start, stop, index % sets))
                while len(traced) > 1 or (traced and stop == n):  # the bar follows the finished launches
                    event, answers, a, b, used = traced[0]
                    event.wait()
                    if check is not None:
                        check(answers)
                    results.answered(a, answers)
                    traced.pop(0)
                    free[used] = answers.base.release(queue)
                    bar.update(b - a)
        finally:
            for _, answers, *_ in traced:  # an error or an interrupt left them mapped
                answers.base.release(queue)
            queue.finish()
            if feed is not queue:
                feed.finish()


# One call's launch buffers (up to two sets of rays in and answers out, 20-68 bytes per ray of a
# launch), kept for the next call on the same context (ao4d.opencl.pool: a fresh buffer costs a
# page fault per page on its first write, about 65 ms of a 1 s call of 10 M rays, estimated
# from 13 ms per fresh 32 MiB buffer on a 2-core VM); release_buffers() drops them.
_launch_pool = BufferPool()


def release_buffers() -> None:
    """Drop the ray buffers :func:`cast_rays` keeps between calls (device memory).

    Examples
    --------
    >>> from ao4d import raycast
    >>> raycast.release_buffers()
    """
    _launch_pool.clear()


def _tree_order(dev: dict, hit: np.ndarray) -> np.ndarray:
    """Tree-order simplices of kernel answers ``lanes * leaf block + lane`` (>= 0)."""
    lanes = dev["lanes"]
    return dev["block_first"][hit // lanes] + hit % lanes


def _traversal_kernel(
    runtime,
    dim: int,
    dev: dict,
    name: str,
    accel: str,
    count_visits: bool = False,
    suffix: str = "",
    ray_type: str | None = None,
):
    """The ``{name}_bvh{suffix}`` or ``{name}_brute`` kernel and its leading scene arguments
    (``ray_type``: the build of the ``cast_rows_*`` kernels for rows of that C type; the
    ``cast_packets`` kernel comes from kernels/cast_packets.cl, the others from ao.cl)."""
    source = "cast_packets.cl" if name == "cast_packets" else "ao.cl"
    kernels = _kernels(runtime, dim, dev["lanes"], count_visits, ray_type, dev["width"], source)
    if accel == "bvh":
        return kernels[f"{name}_bvh{suffix}"], [dev["boxes"], dev["children"], dev["blocks"]]
    return kernels[f"{name}_brute"], [dev["blocks"], dev["n_blocks"]]


def _ao_traversal(runtime) -> str:
    """The AO kernel for this device: packets on CPUs, where one work-item runs on one core and
    a packet shares its node fetches and child loops among :func:`ao_packet` rays (64 on CPUs;
    1.1-1.45x the per-ray kernel at 32, measured); one ray per work-item elsewhere: GPUs run
    neighbouring rays on SIMT lanes already and the packet's 5.5-11 KiB of private memory per
    work-item would spill (not measured: no GPU lent)."""
    import pyopencl as pcl

    return "packet" if runtime.device.type & pcl.device_type.CPU else "rays"


#: cast_rays' any-hit rays that share an origin go as packets (kernels/cast_packets.cl):
#: "auto" on CPUs, like the AO kernel (:func:`_ao_traversal`); True or False always or never
#: (tests). Read when a trace starts.
CAST_PACKETS: bool | str = "auto"
_PACKET_MIN_RUN = 4  # rows per origin, on average, below which a launch keeps one ray per work-item


def _casts_packets(runtime) -> bool:
    """Whether :data:`CAST_PACKETS` sends shared-origin any-hit rays on ``runtime`` as packets."""
    return _ao_traversal(runtime) == "packet" if CAST_PACKETS == "auto" else bool(CAST_PACKETS)


def shared_origin_packets(origins: np.ndarray, size: int) -> np.ndarray | None:
    """Packets of rows with bit-identical origins, for ``cast_packets_bvh``.

    Parameters
    ----------
    origins : (N, d) float32 or float64 numpy.ndarray
        Contiguous rows, as a launch copies them to the device.
    size : int
        Most rays per packet (:func:`ao_packet`).

    Returns
    -------
    (P, 2) int32 numpy.ndarray or None
        Per packet its first row and its number of rows: the runs of consecutive rows whose
        origins have the same bits, cut into pieces of at most ``size``. None when the runs
        average fewer than 4 rows, where a work-item per ray pays better.

    Examples
    --------
    >>> o = np.array([[0.0, 1.0]] * 5 + [[2.0, 0.0]] * 4)
    >>> shared_origin_packets(o, 4).tolist()
    [[0, 4], [4, 1], [5, 4]]
    """
    n = len(origins)
    if n == 0:
        return None
    bits = origins.view(np.uint32 if origins.dtype == np.float32 else np.uint64)
    new = np.empty(n, dtype=bool)
    new[0] = True
    np.not_equal(bits[1:, 0], bits[:-1, 0], out=new[1:])
    for j in range(1, bits.shape[1]):  # column by column: 5x faster than any() over rows of 3 or 4
        new[1:] |= bits[1:, j] != bits[:-1, j]
    first = np.flatnonzero(new)
    if n < _PACKET_MIN_RUN * len(first):
        return None
    length = np.diff(np.append(first, n))
    pieces = -(-length // size)
    run = np.repeat(np.arange(len(first)), pieces)
    k = np.arange(len(run)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    out = np.empty((len(run), 2), dtype=np.int32)
    out[:, 0] = first[run] + k * size
    out[:, 1] = np.minimum(size, length[run] - k * size)
    return out


def _ao_opencl(
    mesh,
    tree,
    runtime,
    points,
    normals,
    samples,
    seed,
    offset,
    max_distance,
    accel,
    bar,
    index=None,
    first=0,
    visits=None,
    traversal=None,
):
    """Occluded-ray counts per point on the device (points Morton-sorted for coherence); with
    ``visits`` ((N, 4) int64), the counting kernels fill it (see :func:`traversal_counts`).
    ``traversal``: ``"packet"`` (``ao_bvh``, the rays of a point together) or ``"rays"``
    (``ao_bvh_rays``, one ray at a time: the reference); same counts. Default:
    :func:`_ao_traversal`."""
    import pyopencl as pcl

    n = len(points)
    cl.check_device_memory(runtime, {"the AO points": n * 36, "the AO results": n * 4}, task="ray tracing")
    order = _morton_order(points)
    ctx, queue = runtime.context, runtime.queue
    mf = pcl.mem_flags
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR
    table = sobol_table(first + samples, tree.dim - 1, seed=seed)[first:]
    buffers = [
        pcl.Buffer(ctx, ro, hostbuf=_pad4(points[order])),
        pcl.Buffer(ctx, ro, hostbuf=_pad4(normals[order])),
        # global index: same directions
        pcl.Buffer(ctx, ro, hostbuf=(order if index is None else np.asarray(index)[order]).astype(np.uint32)),
        pcl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(table)),
    ]
    counts = np.empty(n, dtype=np.int32)
    buf_counts = pcl.Buffer(ctx, mf.WRITE_ONLY, counts.nbytes)
    dev = _bvh.device_tree(mesh, tree, runtime)
    traversal = _ao_traversal(runtime) if traversal is None else check_choice(traversal, "traversal", AO_TRAVERSALS)
    suffix = "_rays" if traversal == "rays" else ""
    kernel, head = _traversal_kernel(runtime, tree.dim, dev, "ao", accel, visits is not None, suffix)
    args = (
        head
        + buffers
        + [
            np.int32(samples),
            np.uint32(seed & 0xFFFFFFFF),
            np.float32(offset),
            _reach32(max_distance),
            buf_counts,
        ]
    )
    if visits is not None:
        counted = np.empty((n, 4), dtype=np.int32)
        buf_visits = pcl.Buffer(ctx, mf.WRITE_ONLY, counted.nbytes)
        args.append(buf_visits)
    per_launch = max(1, RAYS_PER_LAUNCH // samples)
    for start in range(0, n, per_launch):
        count = min(per_launch, n - start)
        kernel(queue, (count,), None, *args, global_offset=(start,)).wait()
        bar.update(count * samples)
    pcl.enqueue_copy(queue, counts, buf_counts)
    if visits is not None:
        pcl.enqueue_copy(queue, counted, buf_visits)
        visits[order] = counted
    queue.finish()
    out = np.empty(n, dtype=np.int64)
    out[order] = counts
    return out


def sample_directions(runtime, normals: np.ndarray, samples: int, seed: int, *, eight: bool = False) -> np.ndarray:
    """The directions the AO kernel traces, computed on the device.

    For tests: they must equal :func:`ao4d.sampling.cosine_hemisphere` on the host. With
    ``eight``, generated eight at a time on vector lanes as the packet AO kernel does
    (``cosine_directions8``); they must be the same bits as one at a time.

    Parameters
    ----------
    runtime : ao4d.opencl.cl.Runtime
        The OpenCL device.
    normals : (N, d) float64
        Unit normals.
    samples, seed : int
        Directions per normal, and the seed of their random shifts.
    eight : bool
        Generate them eight at a time.

    Returns
    -------
    (N, samples, d) float64 numpy.ndarray
        The directions.
    """
    import pyopencl as pcl

    n, d = normals.shape
    ctx, queue = runtime.context, runtime.queue
    ro = pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR
    out = np.empty((n * samples, 4), dtype=np.float32)
    buf = pcl.Buffer(ctx, pcl.mem_flags.WRITE_ONLY, out.nbytes)
    _kernels(runtime, d, _bvh.block_lanes(runtime, d))["sample_directions8" if eight else "sample_directions"](
        queue,
        (n,),
        None,
        pcl.Buffer(ctx, ro, hostbuf=_pad4(normals)),
        pcl.Buffer(ctx, ro, hostbuf=np.arange(n, dtype=np.uint32)),
        pcl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(sobol_table(samples, d - 1, seed=seed))),
        np.int32(samples),
        np.uint32(seed & 0xFFFFFFFF),
        buf,
    )
    pcl.enqueue_copy(queue, out, buf)
    queue.finish()
    return out[:, :d].reshape(n, samples, d).astype(np.float64)


def device_ray_mapping(runtime, frame, origins: np.ndarray, directions: np.ndarray, ray_type: str):
    """The float4 rays the ``cast_rows_*`` kernels trace for these rows (the ``map_rays`` kernel).

    For tests: they must be the bits of the host's mapping (``_Rays.chunk``). Needs ``cl_khr_fp64``.

    Parameters
    ----------
    runtime : ao4d.opencl.cl.Runtime
        The OpenCL device.
    frame : ao4d.bvh.Frame
        The tree's frame the rays are mapped into.
    origins, directions : (N, d) float32 or float64
        The rows, as the caller gives them to :func:`cast_rays`.
    ray_type : {"float", "double"}
        The C type the kernels read the rows as.

    Returns
    -------
    origins, directions : (N, 4) float32 numpy.ndarray
        The mapped rays (directions of zero-length rows are zeros).
    """
    import pyopencl as pcl

    n, d = origins.shape
    ctx, queue = runtime.context, runtime.queue
    ro = pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR
    real = np.float32 if ray_type == "float" else np.float64
    ins = [pcl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(a, dtype=real)) for a in (origins, directions)]
    frame_buf = pcl.Buffer(ctx, ro, hostbuf=_frame_values(frame))
    out = [np.empty((n, 4), dtype=np.float32) for _ in range(2)]
    bufs = [pcl.Buffer(ctx, pcl.mem_flags.WRITE_ONLY, a.nbytes) for a in out]
    _kernels(runtime, d, _bvh.block_lanes(runtime, d), ray_type=ray_type)["map_rays"](
        queue, (n,), None, *ins, frame_buf, *bufs
    )
    for a, b in zip(out, bufs):
        pcl.enqueue_copy(queue, a, b)
    queue.finish()
    return out[0], out[1]


# -- numpy side -------------------------------------------------------------------------------


def _box_hits(lo, hi, o, inv_w, t_max):
    """Slab test in float64 like ``hit_boxes`` in kernels/geometry.h (which keeps the inverse
    direction finite instead; both are conservative for rays parallel to a slab)."""
    with np.errstate(invalid="ignore"):
        t0, t1 = (lo - o) * inv_w, (hi - o) * inv_w
    # fmin/fmax skip the NaN of 0 * inf: the slab of a parallel ray counts as hit
    t_near = np.fmax(np.fmax.reduce(np.fmin(t0, t1), axis=1), 0.0)
    t_far = np.fmin(np.fmin.reduce(np.fmax(t0, t1), axis=1), t_max)
    return t_near <= t_far


def _leaf_pairs(rays: np.ndarray, meta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    first, count = -meta[:, 0] - 1, meta[:, 1]
    ray = np.repeat(rays, count)
    start = np.cumsum(count) - count
    prim = np.repeat(first, count) + (np.arange(ray.size) - np.repeat(start, count))
    return ray, prim


def _record_hits(best, best_t, ray, prim, t, any_hit):
    if any_hit:
        best[ray], best_t[ray] = prim, t
        return
    order = np.lexsort((t, ray))
    ray, prim, t = ray[order], prim[order], t[order]
    first = np.ones(ray.size, dtype=bool)
    first[1:] = ray[1:] != ray[:-1]
    ray, prim, t = ray[first], prim[first], t[first]
    closer = t <= best_t[ray]
    best[ray[closer]], best_t[ray[closer]] = prim[closer], t[closer]


def _trace_numpy_bvh(tree, o, w, max_distance, any_hit):
    """Breadth-first traversal of (ray, node) pairs, vectorised over the whole frontier."""
    d = tree.dim
    n = len(o)
    lo, hi = tree.lo[:, :d].astype(np.float64), tree.hi[:, :d].astype(np.float64)
    with np.errstate(divide="ignore"):
        inv_w = 1.0 / w
    best = np.full(n, -1, dtype=np.int64)
    best_t = np.full(n, max_distance)
    ray, node = np.arange(n), np.zeros(n, dtype=np.int64)
    while ray.size:
        meta = tree.meta[node].astype(np.int64)
        leaf = meta[:, 0] < 0
        if leaf.any():
            r, p = _leaf_pairs(ray[leaf], meta[leaf])
            ok, t = _bvh.intersect(tree.inverse[p], tree.origin[p], o[r], w[r], best_t[r])
            _record_hits(best, best_t, r[ok], p[ok], t[ok], any_hit)
        r, m = ray[~leaf], meta[~leaf]
        if any_hit:
            live = best[r] < 0
            r, m = r[live], m[live]
        r = np.concatenate([r, r])
        c = np.concatenate([m[:, 0], m[:, 1]])
        keep = _box_hits(lo[c], hi[c], o[r], inv_w[r], best_t[r])
        ray, node = r[keep], c[keep]
    return best_t, best


def _trace_numpy_brute(tree, o, w, max_distance, any_hit, block=64):
    n = len(o)
    best = np.full(n, -1, dtype=np.int64)
    best_t = np.full(n, max_distance)
    for start in range(0, tree.n_prims, block):
        prims = np.arange(start, min(start + block, tree.n_prims))
        r = np.repeat(np.arange(n), prims.size)
        p = np.tile(prims, n)
        ok, t = _bvh.intersect(tree.inverse[p], tree.origin[p], o[r], w[r], best_t[r])
        _record_hits(best, best_t, r[ok], p[ok], t[ok], any_hit)
    return best_t, best


def _trace_numpy(tree, rays, max_distance, any_hit, accel, bar):
    """Tree-order simplex or -1 per ray of ``rays`` (:class:`_Rays`), in float64."""
    hit = np.empty(rays.n, dtype=np.int64)
    trace = _trace_numpy_bvh if accel == "bvh" else _trace_numpy_brute
    for start in range(0, rays.n, _NUMPY_RAYS_PER_STEP):
        stop = min(rays.n, start + _NUMPY_RAYS_PER_STEP)
        o, w = rays.chunk(start, stop, np.float64)
        hit[start:stop] = trace(tree, o, w, max_distance, any_hit)[1]
        bar.update(stop - start)
    return hit


def _ao_numpy(tree, points, normals, samples, seed, offset, max_distance, accel, bar, index=None, first=0):
    n = len(points)
    counts = np.empty(n, dtype=np.int64)
    per_step = max(1, _NUMPY_RAYS_PER_STEP // samples)
    for start in range(0, n, per_step):
        sl = slice(start, min(n, start + per_step))
        w = cosine_hemisphere(
            normals[sl], samples, seed=seed, index_offset=start, index=None if index is None else index[sl], first=first
        )
        o = points[sl] + offset * normals[sl]
        o = np.repeat(o, samples, axis=0)
        trace = _trace_numpy_bvh if accel == "bvh" else _trace_numpy_brute
        hit = trace(tree, o, w.reshape(-1, tree.dim), max_distance, True)[1]
        counts[sl] = (hit.reshape(-1, samples) >= 0).sum(1)
        bar.update((sl.stop - sl.start) * samples)
    return counts


class _NullBar:
    def update(self, n: int) -> None:
        pass


# -- public API -------------------------------------------------------------------------------


def cast_rays(
    mesh: Any,
    origins: Any,
    directions: Any,
    *,
    max_distance: float = math.inf,
    closest: bool = True,
    backend: str = "auto",
    accel: str = "bvh",
    progress: bool | None = None,
) -> RayHits:
    """Intersect rays with a simplex mesh: closest hit, or any hit.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        A mesh in R^d, d in {2, 3, 4}, in any form :func:`ao4d.mesh.as_mesh` takes. A
        ``SimplexMesh`` builds its BVH on first use and keeps it; the other forms are converted,
        and their tree built, on every call.
    origins : (N, d) array_like of float
        Where the rays start.
    directions : (N, d) array_like of float
        Normalised here; zero-length directions are an error.
    max_distance : float
        Hits count for ``0 < t <= max_distance``.
    closest : bool
        ``True``: the nearest hit. ``False``: any hit within ``max_distance`` (faster, for
        shadow/occlusion rays; ``t`` and ``simplex`` belong to some hit, not the nearest).
    backend : {"auto", "opencl", "numpy"}
        ``"auto"`` uses OpenCL when a device works, else numpy.
    accel : {"bvh", "brute"}
        ``"brute"`` tests every simplex (for checks and benchmarks; gives the same answer).
    progress : bool, optional
        Show a tqdm bar (default: only for more than ~4M rays).

    Returns
    -------
    RayHits
        ``t`` (N,) float64, ``simplex`` (N,) int64 (-1 on a miss), ``barycentric`` (N, d) float64.
        Distances and weights of hits are recomputed in float64 on the hit simplex.

    Notes
    -----
    On CPUs, any-hit rays in consecutive rows with the same origin (shadow and AO rays from
    shared points, a pinhole camera's rays) are traced together, up to 64 at a time, as the AO
    kernel traces a point's rays: put such rays next to each other.

    Examples
    --------
    >>> import ao4d
    >>> tri = ao4d.SimplexMesh([[0, 0, 1], [1, 0, 1], [0, 1, 1]], [[0, 1, 2]])
    >>> hits = cast_rays(tri, [[0.2, 0.2, 0]], [[0, 0, 1]], backend="numpy")
    >>> float(hits.t[0]), int(hits.simplex[0])
    (1.0, 0)
    """
    mesh = as_mesh(mesh)
    vertices, _ = mesh_arrays(mesh)
    d = vertices.shape[1]
    # float32 or float64 inputs are kept as they are: each launch converts its own rays
    origins = _float_rows(origins, "origins", d)
    directions = _float_rows(directions, "directions", d)
    if len(origins) != len(directions):
        raise ValueError(
            f"`origins` and `directions` must have the same length, got {len(origins)} and {len(directions)}"
        )
    max_distance = check_distance(max_distance)
    closest = check_bool(closest, "closest")
    check_choice(accel, "accel", ACCELS)
    runtime = cl.resolve_backend(backend)
    if len(origins) == 0:  # no tree is needed to miss
        return trace(None, origins, directions)
    with progress_bar(progress, len(origins), "rays") as bar:
        return trace(
            Tracer.of(mesh, runtime),
            origins,
            directions,
            max_distance=max_distance,
            closest=closest,
            accel=accel,
            bar=bar,
        )


class Tracer:
    """A mesh's tree on a resolved backend: what every trace of the mesh needs, fetched once.

    Attributes
    ----------
    tree : ao4d.bvh.BVH
        The mesh's tree (:func:`ao4d.bvh.get_bvh`).
    runtime : ao4d.opencl.cl.Runtime or None
        The OpenCL device, or None for the numpy traversal.
    device : dict or None
        The tree's device copies (:func:`ao4d.bvh.device_tree`) on ``runtime``.
    """

    __slots__ = ("tree", "runtime", "device")

    def __init__(self, tree: Any, runtime: Any, device: dict | None) -> None:
        self.tree, self.runtime, self.device = tree, runtime, device

    @classmethod
    def of(cls, mesh: Any, runtime: Any) -> Tracer:
        """The tracer of ``mesh`` on ``runtime`` (:func:`ao4d.opencl.cl.resolve_backend`'s answer).

        Parameters
        ----------
        mesh : SimplexMesh
            A mesh with at least one simplex.
        runtime : ao4d.opencl.cl.Runtime or None
            The OpenCL device, or None for numpy.

        Returns
        -------
        Tracer
            Its tree, and the device copies when ``runtime`` is a device.
        """
        tree = get_bvh(mesh, runtime=runtime)
        return cls(tree, runtime, None if runtime is None else _bvh.device_tree(mesh, tree, runtime))


def trace(
    tracer: Tracer | None,
    origins: np.ndarray,
    directions: np.ndarray,
    *,
    max_distance: float = math.inf,
    closest: bool = True,
    accel: str = "bvh",
    bar: Any = None,
) -> RayHits:
    """:func:`cast_rays` on trusted inputs: one batch of rays, no validation.

    Parameters
    ----------
    tracer : Tracer
        The mesh's tree on its backend (None only when there are no rays).
    origins, directions : (N, d) float32 or float64 numpy.ndarray
        Finite rows; directions non-zero (normalised here).
    max_distance : float
        Hits count for ``0 < t <= max_distance`` (> 0, inf allowed).
    closest : bool
        The nearest hit, or any hit.
    accel : {"bvh", "brute"}
        As for :func:`cast_rays`.
    bar : tqdm-like, optional
        Counts the rays as they are traced.

    Returns
    -------
    RayHits
        As :func:`cast_rays` returns.
    """
    n, d = origins.shape
    if n == 0:  # OpenCL refuses buffers of zero bytes
        return RayHits(t=np.zeros(0), simplex=np.zeros(0, dtype=np.int64), barycentric=np.zeros((0, d)))
    bar = _NullBar() if bar is None else bar
    tree, runtime = tracer.tree, tracer.runtime
    rays = _Rays(tree.frame, origins, directions)
    reach = tree.frame.length(max_distance)
    results = _Results(tree, tracer.device if runtime is not None else None, n, closest)
    if runtime is not None:
        _trace_opencl(tracer.device, tree, runtime, rays, reach, not closest, accel, bar, results)
    else:
        check_memory(min(n, _NUMPY_RAYS_PER_STEP) * 64.0 + n * 8.0, "the numpy ray arrays")
        results.launched(0, n)
        results.answered(0, _trace_numpy(tree, rays, reach, not closest, accel, bar))
    rows, p = results.hits()
    simplex = results.simplex
    hit_simplex = simplex[rows]
    # the hit rays as they are now (the caller may change the arrays); refined when t is read
    o, w = np.take(rays.origins, rows, axis=0), np.take(rays.directions, rows, axis=0)  # faster than [rows]
    refined = results.refined
    if _refines_on_device(tree, runtime):
        pending = lambda: _refine_on_device(tracer, n, rows, hit_simplex, o, w, refined)  # noqa: E731
    else:
        inv_length = rays.inv_length_of(rows, w)
        pending = lambda: _refine_hits(tree, n, rows, p, o, w, inv_length(), refined)  # noqa: E731
    return RayHits(None, simplex, None, pending=pending)


class _Results:
    """A trace's result arrays, written launch by launch while the device works.

    ``launched(start, stop)`` fills the rows of a launch just enqueued with the misses' values
    (simplex -1; for closest hits also ``t`` = inf and zero barycentrics, which the refinement
    completes), ``answered(start, answers)`` the hits among a finished launch's answers, while
    the device traces the next launch. The arrays' fresh pages are then touched while the device
    traces, not after the last launch: on the project's VM filling a fresh 82 MB array took
    14 ms, and 130-190 ms right after another process's large run (3D closest hits of 10 M rays:
    a third of a GB of results).
    """

    def __init__(self, tree, device: dict | None, n: int, closest: bool) -> None:
        self._tree, self._device = tree, device  # device: answers are kernel answers (lanes * block + lane)
        self.simplex = np.empty(n, dtype=np.int64)
        self.refined = (np.empty(n), np.empty((n, tree.dim))) if closest else None
        self._found: list[tuple[np.ndarray, np.ndarray]] = []  # per launch: hit rows, tree-order simplices

    def launched(self, start: int, stop: int) -> None:
        self.simplex[start:stop] = -1
        if self.refined is not None:
            self.refined[0][start:stop] = np.inf
            self.refined[1][start:stop] = 0.0

    def answered(self, start: int, answers: np.ndarray) -> None:
        at = np.flatnonzero(answers >= 0)
        p = answers[at].astype(np.int64)
        if self._device is not None:
            p = _tree_order(self._device, p)
        self.simplex[start + at] = self._tree.prim[p]
        self._found.append((at + start, p))

    def hits(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows that hit, in order, and their tree-order simplices (after at least one answer)."""
        return np.concatenate([at for at, _ in self._found]), np.concatenate([p for _, p in self._found])


def _float_rows(value: Any, name: str, d: int) -> np.ndarray:
    """(N, d) finite float32 or float64 rows (other types become float64), else an error naming `name`."""
    kept = isinstance(value, np.ndarray) and value.dtype in (np.float32, np.float64)
    dtype = value.dtype if kept else np.float64
    return as_array(value, name, ndim=2, shape_tail=(d,), dtype=dtype, finite=True)


_ROW_BLOCK = 1 << 14  # rows per step of the host's ray mapping: its float64 temporaries stay in L2


def _inverse_lengths(directions: np.ndarray) -> np.ndarray:
    """``1 / sqrt(w0^2 + w1^2 + ...)`` per row in float64, the squares summed in column order
    (the order ``map_ray`` in kernels/ao.cl follows); ``inf`` for a zero-length row."""
    square = directions.astype(np.float64)
    square *= square
    length2 = square[:, 0].copy()
    for k in range(1, square.shape[1]):  # column by column: the same bits as one column at a time
        length2 += square[:, k]
    np.sqrt(length2, out=length2)
    with np.errstate(divide="ignore"):
        return np.divide(1.0, length2, out=length2)


class _Rays:
    """The rays of one :func:`cast_rays` call, handed out launch by launch in the tree's frame.

    Directions are normalised and origins mapped into the frame (``tree.frame``) in float64,
    block by block of ``_ROW_BLOCK`` rows (the temporaries stay in cache), then rounded to the
    kernels' float32: the whole call never holds more than one launch's float32 copies besides
    the inputs. Every value is the same bits as the plain formulas over all rays give: origins
    ``float32((o - centre) * scale)``, directions ``w * float32(1 / sqrt(sum of float64 squares))``.
    """

    def __init__(self, frame, origins: np.ndarray, directions: np.ndarray) -> None:
        self.frame, self.origins, self.directions = frame, origins, directions
        self.n, self.d = origins.shape
        self._inv_length: np.ndarray | None = None

    @property
    def inv_length(self) -> np.ndarray:
        """(N,) float64 ``1 / |w|`` of every ray, computed on first use (:meth:`check`)."""
        if self._inv_length is None:
            inv_length = np.empty(self.n)
            for start in range(0, self.n, _ROW_BLOCK):
                stop = min(self.n, start + _ROW_BLOCK)
                inv_length[start:stop] = _inverse_lengths(self.directions[start:stop])
            bad = np.flatnonzero(~(inv_length < np.inf))
            if bad.size:
                raise ValueError(f"`directions` has {bad.size} zero-length row(s), first at index {bad[0]}")
            self._inv_length = inv_length
        return self._inv_length

    def check(self) -> None:
        """Raise ``ValueError`` naming ``directions`` if a row has zero length."""
        self.inv_length  # noqa: B018 (computed for its check)

    def inv_length_of(self, rows: np.ndarray, directions: np.ndarray) -> Callable[[], np.ndarray]:
        """A function giving ``inv_length[rows]`` (``directions``: those rows, as they were when
        the call began), the same bits: taken now when the whole array is known, else computed
        from those rows when called (for the kernels that map rays themselves: only when a hit's
        ``t`` is read)."""
        if self._inv_length is not None:
            known = self._inv_length[rows]
            return lambda: known
        return lambda: _inverse_lengths(directions)

    def chunk(
        self,
        start: int,
        stop: int,
        dtype,
        width: int | None = None,
        *,
        out: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions of rays ``start:stop`` in ``dtype``, zero-padded to
        ``width`` columns (the kernels' float4); written into ``out`` (two arrays of that
        shape and type, such as mapped device buffers) when given."""
        width = self.d if width is None else width
        if out is None:
            out = (np.empty((stop - start, width), dtype=dtype), np.empty((stop - start, width), dtype=dtype))
        o, w = out
        o[:, self.d :] = w[:, self.d :] = 0
        centre, scale = self.frame.centre, self.frame.scale
        column = np.empty(min(_ROW_BLOCK, stop - start))
        for a in range(start, stop, _ROW_BLOCK):
            b = min(stop, a + _ROW_BLOCK)
            col, rows = column[: b - a], slice(a - start, b - start)
            inv_length = self.inv_length[a:b].astype(dtype)
            # column by column (numpy's loops over rows of 3 or 4 values run several times
            # slower), origins mapped in float64
            for k in range(self.d):
                np.subtract(self.origins[a:b, k], centre[k], out=col)
                np.multiply(col, scale, out=o[rows, k])
                np.multiply(self.directions[a:b, k], inv_length, out=w[rows, k])
        return o, w


#: Let fp64 devices refine the hits of a device-built tree themselves (kernels/refine.cl); tests
#: clear it to take the host's refinement, which gives the same bits. Read when a trace starts.
REFINE_ON_DEVICE = True


def _refines_on_device(tree, runtime) -> bool:
    """Whether the hits of a trace of ``tree`` on ``runtime`` are refined by the device: an fp64
    device and a tree it built (whose float64 vertices in the tree's frame it keeps)."""
    return (
        REFINE_ON_DEVICE
        and runtime is not None
        and "cl_khr_fp64" in runtime.device.extensions
        and hasattr(tree, "mesh_arrays")
    )


def _refine_kernel(runtime, dim: int, ray_type: str):
    """The ``refine_hits`` kernel (kernels/refine.cl) for rows of C type ``ray_type``."""
    return cl.build_kernels(runtime, "refine.cl", {"DIM": dim, "RAY_T": ray_type})["refine_hits"]


def _refine_block(inv: np.ndarray, origin: np.ndarray, o: np.ndarray, w: np.ndarray):
    """Ray parameters (tree units) and barycentrics of rays ``o + t w`` (float64, tree frame)
    hitting simplices of inverse frames ``inv`` (k, d, d) and vertex 0 ``origin`` (k, d).

    Products and sums one column at a time, left to right: ``kernels/refine.cl`` repeats these
    operations in this order, so the device's refinement gives the same bits (numpy's
    ``einsum`` chooses its own summation order).
    """
    d = inv.shape[-1]
    rel = o - origin
    num, den = inv[:, -1, 0] * rel[:, 0], inv[:, -1, 0] * w[:, 0]
    for j in range(1, d):
        num = num + inv[:, -1, j] * rel[:, j]
        den = den + inv[:, -1, j] * w[:, j]
    t = -num / den
    x = (o + t[:, None] * w) - origin
    bary = np.empty((len(t), d))
    for i in range(d - 1):
        beta = inv[:, i, 0] * x[:, 0]
        for j in range(1, d):
            beta = beta + inv[:, i, j] * x[:, j]
        bary[:, i + 1] = beta
    total = bary[:, 1].copy()
    for i in range(2, d):
        total = total + bary[:, i]
    bary[:, 0] = 1.0 - total
    return t, bary


def _miss_values(n: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """``t`` and barycentrics of ``n`` rays that all missed: inf and zeros."""
    return np.full(n, np.inf), np.zeros((n, d))


def _refine_hits(
    tree,
    n: int,
    rows: np.ndarray,
    p: np.ndarray,
    o: np.ndarray,
    w: np.ndarray,
    inv_length: np.ndarray,
    out: tuple[np.ndarray, np.ndarray] | None = None,
):
    """``t`` (world units) and barycentrics of the hits, recomputed in float64 on the host on the
    hit simplices (tree-order ``p``) of rays ``rows`` (world origins ``o``, directions ``w`` and
    their ``1 / |w|``), written into ``out`` (``t`` and barycentrics holding the misses' inf and
    zeros) when given.

    Block by block of ``_ROW_BLOCK`` hits: every step is per row, so the blocks give the bits
    the whole arrays give, while the frames' float64 temporaries (about 40 d^2 bytes a hit)
    stay in cache instead of faulting in fresh pages (0.3-0.7 s for 0.9 M hits, all at once).
    """
    t, bary = _miss_values(n, tree.dim) if out is None else out
    for a in range(0, len(rows), _ROW_BLOCK):
        b = min(len(rows), a + _ROW_BLOCK)
        inv, origin = tree.frames(p[a:b])
        w_k = w[a:b].astype(np.float64) * inv_length[a:b, None]
        t_hit, bary[rows[a:b]] = _refine_block(inv, origin, tree.frame.points(o[a:b]), w_k)
        t[rows[a:b]] = tree.frame.world_length(t_hit)
    return t, bary


def _refine_on_device(
    tracer: Tracer,
    n: int,
    rows: np.ndarray,
    simplex: np.ndarray,
    o: np.ndarray,
    w: np.ndarray,
    out: tuple[np.ndarray, np.ndarray] | None = None,
):
    """:func:`_refine_hits`' answer (the same bits) from ``kernels/refine.cl``: one work-item per
    hit (mesh simplex ``simplex``, ray rows ``o``, ``w`` as the caller gave them) writes its row
    of ``t`` and the barycentrics (into ``out`` when given, as :func:`_refine_hits`), in place
    where the device shares the host's memory (CPUs). The tree's float64 vertices and the
    simplices go to the device once per tree."""
    import pyopencl as pcl

    tree, runtime, dev = tracer.tree, tracer.runtime, tracer.device
    d = tree.dim
    t, bary = _miss_values(n, d) if out is None else out
    if not len(rows):
        return t, bary
    ctx, queue = runtime.context, runtime.queue
    mf = pcl.mem_flags
    cl.check_device_memory(runtime, {"the refined hits": t.nbytes + bary.nbytes}, task="the hits' refinement")
    mesh = dev.get("refine mesh")
    if mesh is None:
        vertices, simplices = tree.mesh_arrays
        mesh = dev["refine mesh"] = tuple(
            pcl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a, dtype=dtype))
            for a, dtype in ((vertices, np.float64), (simplices, np.int32))
        )
    real, ray_type = _row_types(o, w)  # float32 rows stay float32
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR
    inputs = [
        pcl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(a, dtype=dtype))
        for a, dtype in (
            (o, real),
            (w, real),
            (_frame_values(tree.frame), np.float64),
            (simplex, np.int32),
            (rows, np.int64),
        )
    ]
    outputs = [pcl.Buffer(ctx, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=a) for a in (t, bary)]
    kernel = _refine_kernel(runtime, d, ray_type)
    kernel(queue, (len(rows),), None, *inputs, *mesh, *outputs)
    for buf, a in zip(outputs, (t, bary)):  # the device's writes, seen by the host (no copy on CPUs)
        mapped, _ = pcl.enqueue_map_buffer(queue, buf, pcl.map_flags.READ, 0, a.shape, a.dtype)
        mapped.base.release(queue)
    queue.finish()
    return t, bary


def count_occluded(
    mesh: Any,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    samples: int,
    seed: int,
    offset: float,
    max_distance: float,
    runtime: Any,
    accel: str = "bvh",
    bar: Any = None,
    index: np.ndarray | None = None,
    first: int = 0,
) -> np.ndarray:
    """Per point, how many of ``samples`` cosine-weighted rays hit ``mesh`` (any hit).

    The rays start at ``point + offset * normal``; their directions come from
    :func:`ao4d.sampling.cosine_hemisphere` (on the device the same ones are generated in the
    kernel). Points, ``offset`` and ``max_distance`` are in world units and are mapped into the
    tree's frame here. No validation: :func:`ao4d.ao.ambient_occlusion` checks the inputs.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        The occluding geometry, in any form :func:`ao4d.mesh.as_mesh` takes.
    points, normals : (N, d) float64
        Query points and their unit normals.
    samples, seed : int
        Rays per point, and the seed of the directions' random shifts.
    offset, max_distance : float
        How far above the point the rays start, and their reach (world units).
    runtime : ao4d.opencl.cl.Runtime or None
        The OpenCL device, or None for the numpy traversal.
    accel : {"bvh", "brute"}
        Traverse the BVH, or test every simplex.
    bar : tqdm-like, optional
        Updated with the number of rays traced.
    index : (N,) int, optional
        The points' global indices, which seed their directions' shifts (default: their
        positions in ``points``): a point keeps its rays whichever points are traced with it.
    first : int
        Trace directions ``first`` to ``first + samples - 1`` of each point's sequence (the
        rows of the Sobol table of ``seed``): a later call continues an earlier one's rays.

    Returns
    -------
    counts : (N,) int64
        Rays of each point that hit.
    """
    mesh = as_mesh(mesh)
    tree = get_bvh(mesh, runtime=runtime)
    bar = _NullBar() if bar is None else bar
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    frame = tree.frame
    args = (frame.points(points), normals, samples, seed, frame.length(offset), frame.length(max_distance), accel, bar)
    if runtime is not None:
        return _ao_opencl(mesh, tree, runtime, *args, index=index, first=first)
    return _ao_numpy(tree, *args, index=index, first=first)


def traversal_counts(
    mesh: Any,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    samples: int,
    offset: float,
    runtime: Any,
    seed: int = 0,
    max_distance: float = math.inf,
    traversal: str = "rays",
    detail: bool = False,
) -> tuple[float, ...]:
    """Wide nodes visited and leaf blocks tested per AO ray, on average (tree quality).

    Traces the rays of :func:`count_occluded` with a debug build of the kernels
    (``-D COUNT_VISITS``), which also counts, and returns ``(nodes per ray, blocks per ray)``.

    Parameters
    ----------
    mesh, points, normals, samples, offset, runtime, seed, max_distance : see count_occluded
        As in :func:`count_occluded`.
    traversal : {"rays", "packet"}
        ``"rays"``: one ray at a time (every visit is one ray's); ``"packet"``: the rays of a
        point together, where a node fetched once serves every ray of the packet.
    detail : bool
        Also return the box tests (ray, wide node) and block tests (ray, block) per ray:
        ``(nodes, blocks, node tests, block tests)``; for ``"rays"`` these equal the first two.

    Returns
    -------
    tuple of float
        ``(nodes per ray, blocks per ray)``, or the four figures with ``detail``.
    """
    mesh = as_mesh(mesh)
    check_choice(traversal, "traversal", AO_TRAVERSALS)
    detail = check_bool(detail, "detail")
    tree = get_bvh(mesh, runtime=runtime)
    if len(points) == 0:
        return (math.nan,) * (4 if detail else 2)
    visits = np.zeros((len(points), 4), dtype=np.int64)
    frame = tree.frame
    _ao_opencl(
        mesh,
        tree,
        runtime,
        frame.points(points),
        normals,
        samples,
        seed,
        frame.length(offset),
        frame.length(max_distance),
        "bvh",
        _NullBar(),
        visits=visits,
        traversal=traversal,
    )
    per_ray = visits.sum(0) / (len(points) * samples)
    return tuple(float(x) for x in per_ray[: 4 if detail else 2])
