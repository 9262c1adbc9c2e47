"""The OpenCL side of ray casting: kernel builds (``kernels/rays/ao.cl`` with ``kernels/bvh/bvh.h``;
``kernels/rays/cast_packets.cl``), launches of at most ``RAYS_PER_LAUNCH`` rays in two sets of buffers
that take turns, shared-origin packets, and the AO kernels (cosine rays generated on the device).

On CPUs the AO kernel traces the rays of a point together as one packet from their shared origin
(``trace_packet`` in ``kernels/bvh/bvh.h``): every wide node is fetched and walked once per packet, and
each ray still meets exactly the boxes and leaf blocks the one-ray traversal tests, so the counts
are the same bits. Work is split into launches with a tqdm bar; Ctrl-C stops between launches.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import bvh as _bvh
from .._validate import check_choice
from ..opencl import cl
from ..opencl.pool import BufferPool
from ..sampling import sobol_table
from .rows import _frame_values, _morton_order, _pad4, _reach32, _row_types

__all__ = [
    "AO_PACKET",
    "AO_PACKET_CPU",
    "AO_TRAVERSALS",
    "RAYS_PER_LAUNCH",
    "ao_packet",
    "MAP_ON_DEVICE",
    "release_buffers",
    "CAST_PACKETS",
    "shared_origin_packets",
    "sample_directions",
    "device_ray_mapping",
]


AO_PACKET = 32  # rays of a point traced together by the AO kernel on GPUs (kernels/bvh/bvh.h trace_packet)


AO_PACKET_CPU = 64  # on CPUs: a node fetched once serves twice the rays (5-6 % less trace time, measured)


AO_TRAVERSALS = ("packet", "rays")  # kernels ao_bvh and ao_bvh_rays; same counts


RAYS_PER_LAUNCH = 1 << 21  # ~0.5-2 s per launch on a 2-core CPU: responsive bar and Ctrl-C


def _kernels(
    runtime,
    dim: int,
    lanes: int,
    count_visits: bool = False,
    ray_type: str | None = None,
    width: int | None = None,
    source: str = "rays/ao.cl",
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
        32 or 64 (``PACKET`` of kernels/bvh/bvh.h).
    """
    import pyopencl as pcl

    return AO_PACKET_CPU if runtime.device.type & pcl.device_type.CPU else AO_PACKET


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
    host's operations (the same float32 bits: ``map_ray`` in kernels/rays/ao.cl); a zero-length
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
    >>> from ao4d.rays import launches
    >>> launches.release_buffers()
    """
    _launch_pool.clear()


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
    ``cast_packets`` kernel comes from kernels/rays/cast_packets.cl, the others from ao.cl)."""
    source = {"ao": "rays/ao.cl", "cast_packets": "rays/cast_packets.cl"}.get(name, "rays/cast.cl")
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


#: cast_rays' any-hit rays that share an origin go as packets (kernels/rays/cast_packets.cl):
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
    _kernels(runtime, d, _bvh.block_lanes(runtime, d), source="testing/directions.cl")[
        "sample_directions8" if eight else "sample_directions"
    ](
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
    _kernels(runtime, d, _bvh.block_lanes(runtime, d), ray_type=ray_type, source="rays/cast.cl")["map_rays"](
        queue, (n,), None, *ins, frame_buf, *bufs
    )
    for a, b in zip(out, bufs):
        pcl.enqueue_copy(queue, a, b)
    queue.finish()
    return out[0], out[1]
