"""The BVH built by OpenCL kernels on the device that traces it (``kernels/bvh/bvh_build.cl``).

It builds the kind of tree :func:`ao4d.bvh.host.build` builds (binned SAH along the longest
centroid axis, 32 bins, 16 for nodes of at most 256 simplices; median splits for nodes of at
most 16 and halves below level 40; leaves are ranges of the reordered simplices) and returns the
same :class:`ao4d.bvh.BVH`, so :func:`ao4d.bvh.blocks.widen` and both traversals apply unchanged. One
difference: splits follow the SAH bins exactly, where the host builder rounds a left side to
whole leaves of 16; not rounding costs more, partly filled leaf blocks but gives a much better
tree: lower SAH cost, fewer leaf blocks tested per AO ray, faster AO (figures: the benchmarks
log).

Work is split so that the device does every pass over the simplices and the host only
bookkeeping per node:

1. per chunk of simplices: the degeneracy test and the scene bounds (the box margin depends on
   them), then the records (box with margin rounded outwards, centroid) compacted in order;
2. nodes larger than ``subtree`` simplices, one level at a time: per chunk of a node's
   primitives partial bins, per node the reduction and the SAH choice, per chunk a stable
   partition (two buffers, ping-pong);
3. every smaller node: one work-item builds its whole subtree (bins and partitions in its own
   range), taking node ids from one atomic counter.

   Bins hold counts and boxes only: the partitions read every centroid anyway and give the
   children's centroid bounds (per chunk in step 2, reduced on the host), the same min / max
   as bins of centroids at half the bins' updates (the whole build on one core: 0.77 of its
   time on a 3.7 M-tet tiger, the trees bit for bit the same);
4. the host renumbers the nodes breadth first (deterministic ids) and widens the tree
   (:func:`ao4d.bvh.blocks.widen`'s topology); the leaf blocks are filled on the device from the
   vertices, never copied through the host.

On devices with double precision every per-simplex value (keep/skip, box, centroid, the leaf
blocks' inverse matrices) equals the host builder's bit for bit: the kernels repeat its float64
operations in order. Devices without it compute in float, except the keep/skip test, which the
host does in float64 (:func:`ao4d.bvh.host.nondegenerate`): both trees hold the same simplices. The float64 ``inverse`` and ``origin`` of the tree, which only the numpy
traversal and the refinement of hits need, are computed on the host on first use.

Work-group sizes are left to the runtime (NULL local size), bins are per-work-item partials
(no float atomics, no local memory), so the same kernels run on CPUs and GPUs; ``chunk`` and
``subtree`` follow the device's compute units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import check_positive_int
from ..opencl import cl
from ..opencl.pool import TREES, BufferPool
from . import host
from .blocks import device_wide_tree, give_source_when, release_source
from .layout import _BOX_FMA_MARGIN, _BOX_MARGIN, BARY_EPS, BVH, WIDTH

__all__ = ["build", "DeviceBVH", "release_buffers"]

_SCAN_CHUNK = 4096  # simplices per work-item of the per-simplex passes
_BINS = 32  # kernels' MAX_BINS
_SUBTREE_MAX = 1 << 15  # largest subtree one work-item builds (its stack holds 40 + 16 levels)

# The build's scratch (records, node arrays, bins: about 190 bytes per simplex), kept for the
# next build on the context: a 1.2 M-tetrahedron build faulted in 330 MB of fresh pages and spent
# 0.7 s of system time on it, as much as its own work (ao4d.opencl.pool). Up to 1 GiB (builds
# of up to about 5 M simplices): a 55 M-tet build's 10 GB are not held while its AO is traced.
_scratch = BufferPool(max_bytes=1 << 30)


def release_buffers() -> None:
    """Drop the scratch buffers :func:`build` keeps between builds and the trees' buffers held
    for the next tree (:data:`ao4d.opencl.pool.TREES`; device memory).

    Examples
    --------
    >>> from ao4d.bvh import device
    >>> device.release_buffers()
    """
    _scratch.clear()
    TREES.clear()


class _LazyFrames:
    """A :class:`DeviceBVH`'s ``inverse`` or ``origin``: both computed for every simplex on the
    first read; assigning ``None`` (as the dataclass constructor does) leaves them to be computed."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = f"_{name}"

    def __get__(self, tree: Any, owner: type | None = None) -> Any:
        if tree is None:
            return self
        if getattr(tree, self.slot) is None:
            tree._inverse, tree._origin = tree.frames(np.arange(tree.n_prims))
        return getattr(tree, self.slot)

    def __set__(self, tree: Any, value: Any) -> None:
        if value is not None:
            setattr(tree, self.slot, value)


class DeviceBVH(BVH):
    """A :class:`ao4d.bvh.BVH` built on an OpenCL device.

    ``inverse`` and ``origin`` (float64, tree order) are computed from the mesh on first access:
    the OpenCL traversal never needs them (its leaf blocks are filled on the device).
    :meth:`frames` gives them for a few simplices without computing all.
    """

    # the dataclass fields `inverse` and `origin` become lazy here
    inverse = _LazyFrames()
    origin = _LazyFrames()

    def __init__(self, *, vertices: np.ndarray, simplices: np.ndarray, **fields: Any) -> None:
        self._source = (vertices, simplices)
        self._inverse = self._origin = None
        self.device_source: dict[str, Any] | None = None  # the build's device buffers
        self.device_wide: dict[tuple[int, int], dict[str, Any]] = {}  # (lanes, width) -> device_wide_tree(...)
        super().__init__(inverse=None, origin=None, **fields)

    @property
    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The vertices (V, d) float64, in the tree's frame, and the simplices (S, d) it was built
        from (the closest hits' refinement on the device reads them)."""
        return self._source

    def frames(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse matrices (k, d, d) and vertex 0 (k, d), float64, of tree-order simplices ``p``."""
        if self._inverse is not None:
            return self._inverse[p], self._origin[p]
        vertices, simplices = self._source
        chosen = simplices[self.prim[p]]
        idx, pts, inverse = host.frames(vertices, chosen)
        if idx.size != len(chosen):  # the device kept a simplex the float64 test skips
            inverse = _frames_unfiltered(vertices, chosen)
            return inverse, vertices[chosen[:, 0]].astype(np.float64)
        # contiguous like the host tree's arrays: einsum then sums in the same order
        return np.ascontiguousarray(inverse), pts[0].T.copy()

    def __repr__(self) -> str:
        return (
            f"DeviceBVH(dim={self.dim}, n_prims={self.n_prims}, n_nodes={self.n_nodes}, "
            f"depth={self.depth}, n_skipped={self.n_skipped})"
        )


def _frames_unfiltered(vertices: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Inverses of simplices that may include near-degenerate ones (huge but finite entries)."""
    from ..geometry import simplex_normals

    corners = vertices[simplices].astype(np.float64)
    edges = corners[:, 1:] - corners[:, :1]
    normals = simplex_normals(vertices, simplices)
    matrix = np.concatenate([edges, normals[:, None]], axis=1).transpose(0, 2, 1)
    return np.linalg.pinv(matrix)


def _kernels(runtime, dim: int, use_double: bool) -> dict[str, Any]:
    defines: dict[str, Any] = {"DIM": dim, "SUBTREE_STACK": 64}
    if use_double:
        defines["USE_DOUBLE"] = 1
    else:  # the float64 degeneracy test comes from the host
        defines["KEEP_GIVEN"] = 1
    return cl.build_kernels(runtime, "bvh/bvh_build.cl", defines)


def _has_double(device) -> bool:
    import pyopencl as cl

    try:
        return "cl_khr_fp64" in device.extensions and device.double_fp_config != 0
    except cl.Error:  # pragma: no cover - a driver without the query
        return False


def _check_inputs(vertices: Any, simplices: Any, leaf_size: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`ao4d.bvh.host.build`'s checks, plus the device builder's 32-bit and leaf limits."""
    vertices, simplices, leaf_size = host.check_mesh_arrays(vertices, simplices, leaf_size)
    if len(simplices) >= 2**30 or len(vertices) >= 2**31:
        raise ValueError(
            f"the device builder indexes with 32-bit integers: at most 2^30 simplices, got {len(simplices):,}"
        )
    if leaf_size > 64:
        raise ValueError(f"`leaf_size` must be at most 64 for the device builder, got {leaf_size}")
    return vertices, simplices, leaf_size


def _sizes(n_prims: int, compute_units: int, subtree: int | None, chunk: int | None) -> tuple[int, int]:
    """Subtree size for one work-item and chunk size of the level passes.

    About 32 subtrees and 16 chunks per compute unit keep every unit busy; a CPU runtime
    (few units) gets subtrees of thousands of simplices, whose working set stays in cache.
    """
    if subtree is None:
        subtree = 1 << max(8, min(15, int(math.log2(max(n_prims, 1) / (32 * compute_units) + 1))))
    if chunk is None:
        chunk = 1 << max(8, min(13, int(math.log2(max(n_prims, 1) / (16 * compute_units) + 1))))
    return int(min(subtree, _SUBTREE_MAX)), int(chunk)


def build(
    vertices: Any,
    simplices: Any,
    *,
    leaf_size: int = 16,
    runtime: Any = None,
    subtree: int | None = None,
    chunk: int | None = None,
    lanes: int | None = None,
    width: int = WIDTH,
) -> DeviceBVH:
    """Build the BVH of a simplex mesh with OpenCL kernels.

    Parameters
    ----------
    vertices : (V, d) array_like of float
        The mesh's vertices, d in {2, 3, 4} (the same arguments as :func:`ao4d.bvh.host.build`).
    simplices : (S, d) array_like of int
        Vertex indices per simplex.
    leaf_size : int
        Most simplices per leaf (1 to 64; the kernels' leaf blocks need at most 16 per block).
    runtime : ao4d.opencl.cl.Runtime, optional
        The device to build on (default: the one :func:`ao4d.opencl.cl.get_runtime` chooses).
    subtree, chunk : int, optional
        Nodes of at most ``subtree`` simplices are built by one work-item each; the level
        passes over larger nodes give each work-item ``chunk`` simplices. Defaults follow the
        device's compute units; the tree does not depend on them.
    lanes : {4, 8, 16}, optional
        Also fill the wide form with leaf blocks of ``lanes`` simplices on the device (see
        :func:`device_wide_tree`; the ray-casting module asks for the one it traverses), then
        free the build's device copies of the mesh (:func:`release_source`).
    width : {8, 16}, optional
        Children per wide node of that form (:func:`ao4d.bvh.node_width`).

    Returns
    -------
    DeviceBVH
        A :class:`ao4d.bvh.BVH`; its nodes are numbered breadth first, like the host's.

    Raises
    ------
    ValueError
        Bad input (as :func:`ao4d.bvh.host.build`), or every simplex degenerate.
    RuntimeError
        If no OpenCL device works.

    Examples
    --------
    >>> from ao4d.bvh import device as bb
    >>> tree = bb.build([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])  # doctest: +SKIP
    >>> tree.n_prims, tree.n_nodes  # doctest: +SKIP
    (1, 1)
    """
    vertices, simplices, leaf_size = _check_inputs(vertices, simplices, leaf_size)
    subtree, chunk, runtime = _check_build_options(subtree, chunk, runtime, leaf_size)
    d, n = vertices.shape[1], len(simplices)
    # records (two buffers), node arrays (at most 2 n nodes), the mesh and the leaf blocks
    cl.check_device_memory(
        runtime,
        fallback="the host builder",
        task="the BVH build",
        nbytes={
            "the BVH build's node bounds": 32 * n,
            "the BVH build": n * (2 * 52 + 2 * 40 + 6 + 4 * (d + 1) * d + 8 * d * d) + vertices.nbytes,
        },
    )
    with _scratch.take(runtime.context) as pooled:
        job = _Job(runtime, vertices, simplices, pooled)
        scan = _scan(job)
        nodes = _Nodes(job, scan.n_prims)
        c_lo, c_hi = _records(job, scan, nodes)
        subtree_size, chunk_size = _sizes(scan.n_prims, int(runtime.device.max_compute_units), subtree, chunk)
        subtree_size = max(subtree_size, 2 * leaf_size)
        big, tasks = _split_large_nodes(job, nodes, scan.n_prims, c_lo, c_hi, subtree_size, chunk_size)
        meta, lo, hi, order = _build_subtrees(job, nodes, tasks, big, leaf_size, scan.n_prims)
        job.queue.finish()  # no kernel uses the scratch any more
    meta, lo, hi, depth = _breadth_first(meta, lo, hi)
    lo[:, d:] = 0.0
    hi[:, d:] = 0.0
    tree = DeviceBVH(
        vertices=vertices,
        simplices=simplices,
        dim=d,
        lo=lo,
        hi=hi,
        meta=meta,
        prim=order.astype(np.int64),
        n_skipped=n - scan.n_prims,
        depth=depth,
        diagonal=scan.diagonal,
    )
    tree.device_source = {
        "context": job.ctx,
        "vertices": job.vertices,
        "simplices": job.simplices,
        "order": nodes.order,
        "kernels": job.k,
    }
    give_source_when(tree)
    if lanes is not None:
        device_wide_tree(tree, runtime, lanes, width)  # the form the device traverses
        release_source(tree)
    return tree


def _check_build_options(subtree, chunk, runtime, leaf_size: int):
    """``subtree``, ``chunk`` and the runtime of :func:`build`, checked (the default device)."""
    if subtree is not None:
        subtree = check_positive_int(subtree, "subtree", minimum=2 * leaf_size)
        if subtree > _SUBTREE_MAX:
            raise ValueError(f"`subtree` must be at most {_SUBTREE_MAX}, got {subtree}")
    if chunk is not None:
        chunk = check_positive_int(chunk, "chunk")
    if runtime is None:
        runtime = cl.get_runtime(warn=False)
        if runtime is None:
            raise RuntimeError("the device BVH builder needs an OpenCL device; none works (see `ao4d info`)")
    return subtree, chunk, runtime


class _Job:
    """One build's device, kernels and mesh buffers (float64 where the device has doubles)."""

    def __init__(self, runtime, vertices: np.ndarray, simplices: np.ndarray, pooled) -> None:
        import pyopencl as cl_

        self.cl = cl_
        self.pooled = pooled  # the kept scratch (ao4d.opencl.pool.Taken)
        self.d, self.n = vertices.shape[1], len(simplices)
        use_double = _has_double(runtime.device)
        self.real = np.float64 if use_double else np.float32
        self.k = _kernels(runtime, self.d, use_double)
        self.ctx, self.queue = runtime.context, runtime.queue
        self.mf = cl_.mem_flags
        # the mesh's copies outlive the build (the tree's device_source): recycled, not fresh
        self.vertices = TREES.upload(self.queue, np.ascontiguousarray(vertices, dtype=self.real))
        self.simplices = TREES.upload(self.queue, np.ascontiguousarray(simplices, dtype=np.int32))
        # without doubles a float test would keep other simplices than the host's float64 one
        # (slivers): the host decides, one byte per simplex
        self.keep = None if use_double else host.nondegenerate(vertices, simplices).view(np.uint8)

    def input(self, array: np.ndarray):
        """A read-only device copy of ``array``."""
        return self.cl.Buffer(self.ctx, self.mf.READ_ONLY | self.mf.COPY_HOST_PTR, hostbuf=array)

    def scratch(self, nbytes: int, flags=None, *, kept: str | None = None):
        """A device buffer of ``nbytes`` (read-write unless ``flags`` say otherwise); with a
        name ``kept``, the build's kept scratch of that name (read-write, old contents: the
        kernels write it before they read it)."""
        if kept is not None:
            return self.pooled.get(kept, nbytes)
        return self.cl.Buffer(self.ctx, self.mf.READ_WRITE if flags is None else flags, max(int(nbytes), 1))

    def read(self, *pairs) -> None:
        """Copy each (host array, device buffer) pair to the host."""
        for array, dev in pairs:
            self.cl.enqueue_copy(self.queue, array, dev)


@dataclass
class _Scan:
    """Pass 1's answer: which simplices are kept, the scene's diagonal and margin extent."""

    keep: Any  # device buffer, one byte per simplex
    used: np.ndarray  # chunks that kept a simplex
    offsets: np.ndarray  # kept simplices before each chunk
    n_chunks: int
    n_prims: int
    diagonal: float
    extent: float


def _scan(job: _Job) -> _Scan:
    """1. keep/skip and the scene bounds, per chunk of simplices (the box margin depends on them)."""
    d, n, real = job.d, job.n, job.real
    n_chunks = -(-n // _SCAN_CHUNK)
    kept = np.empty(n_chunks, dtype=np.int32)
    part_lo = np.empty((n_chunks, d), dtype=real)
    part_hi = np.empty((n_chunks, d), dtype=real)
    part_abs = np.empty(n_chunks, dtype=real)
    host = (kept, part_lo, part_hi, part_abs)
    bufs = [job.scratch(a.nbytes, job.mf.WRITE_ONLY) for a in host]
    keep = job.scratch(n, kept="keep") if job.keep is None else job.input(job.keep)
    job.k["scan_simplices"](
        job.queue, (n_chunks,), None, job.vertices, job.simplices, np.int32(n), np.int32(_SCAN_CHUNK), keep, *bufs
    )
    job.read(*zip(host, bufs))
    n_prims = int(kept.sum())
    if n_prims == 0:
        raise ValueError(f"all {n} simplices are degenerate (zero measure)")
    used = kept > 0
    p_lo = part_lo[used].min(0).astype(np.float64)
    p_hi = part_hi[used].max(0).astype(np.float64)
    diagonal = float(np.linalg.norm(p_hi - p_lo))
    extent = max(diagonal, _BOX_FMA_MARGIN * float(part_abs[used].max()), 1e-30)
    offsets = (np.cumsum(kept) - kept).astype(np.int32)
    return _Scan(keep, used, offsets, n_chunks, n_prims, diagonal, extent)


class _Nodes:
    """The records (two buffers, ping-pong), node arrays (at most 2 P nodes) and the order."""

    def __init__(self, job: _Job, n_prims: int) -> None:
        self.rec = [job.scratch(48 * n_prims, kept=f"records {k}") for k in range(2)]
        self.ids = [job.scratch(4 * n_prims, kept=f"ids {k}") for k in range(2)]
        self.bin_of = job.scratch(n_prims, kept="bin of")
        cap = 2 * n_prims
        self.meta = job.scratch(8 * cap, kept="meta")
        self.lo, self.hi = job.scratch(16 * cap, kept="lo"), job.scratch(16 * cap, kept="hi")
        self.order = TREES.get(job.ctx, 4 * n_prims)  # the tree's device_source holds it


def _records(job: _Job, scan: _Scan, nodes: _Nodes) -> tuple[np.ndarray, np.ndarray]:
    """2. records (boxes with margins, centroids) of the kept simplices, compacted in order into
    the first record buffer; returns the centroid bounds, (4,) float32 each."""
    part_c = np.empty((scan.n_chunks, 2, 4), dtype=np.float32)
    buf_pc = job.scratch(part_c.nbytes, job.mf.WRITE_ONLY)
    job.k["make_records"](
        job.queue,
        (scan.n_chunks,),
        None,
        job.vertices,
        job.simplices,
        np.int32(job.n),
        np.int32(_SCAN_CHUNK),
        scan.keep,
        job.input(scan.offsets),
        job.real(2 * BARY_EPS),
        job.real(_BOX_MARGIN * scan.extent),
        nodes.rec[0],
        nodes.ids[0],
        buf_pc,
    )
    job.read((part_c, buf_pc))
    return part_c[scan.used, 0].min(0), part_c[scan.used, 1].max(0)


def _split_large_nodes(job: _Job, nodes: _Nodes, n_prims: int, c_lo, c_hi, subtree_size: int, chunk_size: int):
    """3. nodes larger than ``subtree_size``, one level at a time (the host keeps only node
    bookkeeping). Returns the split nodes as (ids with first child ids, boxes) per level and the
    subtree tasks: (id, start, count, level + 256 parity) rows and their centroid bounds."""
    big: list[tuple[np.ndarray, np.ndarray]] = []
    tasks: list[tuple[np.ndarray, np.ndarray]] = []
    level_nodes = np.array([[0, 0, n_prims]], dtype=np.int64)  # id, start, count
    level_c = np.stack([c_lo, c_hi])[None].astype(np.float32)  # (m, 2, 4)
    next_id, level = 1, 0
    if n_prims <= subtree_size:
        tasks.append((np.array([[0, 0, n_prims, 0]], dtype=np.int32), level_c.reshape(-1, 4)))
        return big, tasks
    while len(level_nodes):
        left, boxes, kids_c = _split_level(job, nodes, level_nodes, level_c, level, chunk_size)
        m = len(level_nodes)
        starts, counts = level_nodes[:, 1], level_nodes[:, 2]
        child = next_id + 2 * np.arange(m)
        next_id += 2 * m
        big.append((np.column_stack([level_nodes[:, 0], child]), boxes))
        kids = np.empty((2 * m, 3), dtype=np.int64)
        kids[0::2, 0], kids[1::2, 0] = child, child + 1
        kids[0::2, 1], kids[1::2, 1] = starts, starts + left
        kids[0::2, 2], kids[1::2, 2] = left, counts - left
        level += 1
        small = kids[:, 2] <= subtree_size
        if small.any():
            t = np.zeros((int(small.sum()), 4), dtype=np.int32)
            t[:, :3] = kids[small]
            t[:, 3] = level + 256 * (level % 2)
            tasks.append((t, kids_c[small].reshape(-1, 4)))
        level_nodes, level_c = kids[~small], np.ascontiguousarray(kids_c[~small])
    return big, tasks


def _split_level(job: _Job, nodes: _Nodes, level_nodes: np.ndarray, level_c: np.ndarray, level: int, chunk_size: int):
    """One level of large nodes: per chunk of a node's records partial bins, per node the
    reduction and the SAH choice, per chunk a stable partition into the other record buffer.
    Returns per node the left child's record count, the children's boxes (m, 8) and their
    centroid bounds (2 m, 2, 4)."""
    d, k = job.d, job.k
    m = len(level_nodes)
    starts, counts = level_nodes[:, 1], level_nodes[:, 2]
    per = -(-counts // chunk_size)
    first = np.concatenate([[0], np.cumsum(per)]).astype(np.int32)
    chunk_node = np.repeat(np.arange(m), per)
    chunk_begin = starts[chunk_node] + (np.arange(first[-1]) - first[chunk_node]) * chunk_size
    chunk_end = np.minimum(chunk_begin + chunk_size, (starts + counts)[chunk_node])
    chunk_i = np.zeros((first[-1], 4), dtype=np.int32)
    chunk_i[:, 0], chunk_i[:, 1], chunk_i[:, 2] = chunk_node, chunk_begin, chunk_end
    ext = (level_c[:, 1] - level_c[:, 0])[:, :d]
    axis = np.argmax(ext, axis=1)
    width = ext[np.arange(m), axis]
    node_i = np.zeros((m, 4), dtype=np.int32)
    node_i[:, 0], node_i[:, 1] = axis, np.where(counts > 8 * _BINS, _BINS, _BINS // 2)
    node_i[:, 2], node_i[:, 3] = starts, counts
    node_f = np.zeros((m, 4), dtype=np.float32)
    node_f[:, 0] = level_c[np.arange(m), 0, axis]
    node_f[:, 1] = np.where(width > 0, width, np.inf)
    n_ch = int(first[-1])
    b_chunk, b_node_i, b_node_f = job.input(chunk_i), job.input(node_i), job.input(node_f)
    b_node_c, b_first = job.input(np.ascontiguousarray(level_c)), job.input(first)
    b_pn, b_pb = job.scratch(4 * _BINS * n_ch, kept="bin counts"), job.scratch(32 * _BINS * n_ch, kept="bin boxes")
    b_off = job.scratch(8 * n_ch, kept="chunk offsets")
    part_c = np.empty((n_ch, 4, 4), dtype=np.float32)  # per chunk: its sides' centroid bounds
    b_pc = job.scratch(part_c.nbytes, kept="chunk centroids")
    res_i = np.empty((m, 4), dtype=np.int32)
    res_f = np.empty((m, 6, 4), dtype=np.float32)
    b_ri, b_rf = job.scratch(res_i.nbytes), job.scratch(res_f.nbytes, job.mf.WRITE_ONLY)
    src, dst = level % 2, (level + 1) % 2
    rec, ids = nodes.rec, nodes.ids
    k["bin_chunks"](job.queue, (n_ch,), None, rec[src], b_chunk, b_node_i, b_node_f, nodes.bin_of, b_pn, b_pb)
    k["split_nodes"](
        job.queue, (m,), None, b_node_i, b_node_c, b_first, b_chunk, b_pn, b_pb, np.int32(level), b_ri, b_rf, b_off
    )
    k["scatter_chunks"](
        job.queue, (n_ch,), None, rec[src], ids[src], rec[dst], ids[dst], b_chunk, b_ri, nodes.bin_of, b_off, b_pc
    )
    job.read((res_i, b_ri), (res_f, b_rf), (part_c, b_pc))
    # after an SAH split the children's centroid bounds are the union of their chunks' (exact
    # min / max: the bits bins of centroids gave); halves keep the parent's (split_nodes)
    sah = res_i[:, 0] > 0
    if sah.any():
        lows = np.minimum.reduceat(part_c[:, 0::2], first[:-1], axis=0)
        highs = np.maximum.reduceat(part_c[:, 1::2], first[:-1], axis=0)
        res_f[sah, 2::2] = lows[sah]
        res_f[sah, 3::2] = highs[sah]
    return res_i[:, 1].astype(np.int64), res_f[:, :2].reshape(m, 8), res_f[:, 2:].reshape(2 * m, 2, 4)


def _build_subtrees(job: _Job, nodes: _Nodes, tasks, big, leaf_size: int, n_prims: int):
    """4. every smaller node: one work-item builds its whole subtree, the largest first, taking
    node ids from one atomic counter; then the large nodes' links and boxes are filled in.
    Returns the node arrays meta (K, 2) int32, lo, hi (K, 4) float32 and the simplex order."""
    next_id = 1 + sum(2 * len(ids) for ids, _ in big)
    t_all = np.concatenate([t for t, _ in tasks])
    c_all = np.concatenate([c for _, c in tasks]).reshape(-1, 2, 4)
    by_size = np.argsort(-t_all[:, 2], kind="stable")
    t_all, c_all = np.ascontiguousarray(t_all[by_size]), np.ascontiguousarray(c_all[by_size])
    counter = np.array([next_id, 0], dtype=np.int32)
    b_counter = job.cl.Buffer(job.ctx, job.mf.READ_WRITE | job.mf.COPY_HOST_PTR, hostbuf=counter)
    job.k["build_subtrees"](
        job.queue,
        (len(t_all),),
        None,
        nodes.rec[0],
        nodes.ids[0],
        nodes.rec[1],
        nodes.ids[1],
        nodes.bin_of,
        job.input(t_all),
        job.input(c_all.reshape(-1, 4)),
        np.int32(leaf_size),
        b_counter,
        nodes.meta,
        nodes.lo,
        nodes.hi,
        nodes.order,
    )
    job.read((counter, b_counter))
    n_nodes = int(counter[0])
    meta = np.empty((n_nodes, 2), dtype=np.int32)
    lo = np.empty((n_nodes, 4), dtype=np.float32)
    hi = np.empty((n_nodes, 4), dtype=np.float32)
    order = np.empty(n_prims, dtype=np.int32)
    job.read((meta, nodes.meta), (lo, nodes.lo), (hi, nodes.hi), (order, nodes.order))
    job.queue.finish()
    if counter[1]:
        raise RuntimeError("device BVH build: a subtree outgrew its work-item's stack")
    for ids, boxes in big:
        node, first_child = ids[:, 0], ids[:, 1]
        meta[node, 0], meta[node, 1] = first_child, first_child + 1
        lo[node], hi[node] = boxes[:, :4], boxes[:, 4:]
    return meta, lo, hi, order


def _breadth_first(meta: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Renumber nodes breadth first (children of a level in order, left before right)."""
    levels = [np.array([0])]
    while True:
        ids = levels[-1]
        inner = ids[meta[ids, 0] >= 0]
        if inner.size == 0:
            break
        levels.append(np.stack([meta[inner, 0], meta[inner, 1]], 1).ravel())
    old = np.concatenate(levels)
    new_of = np.empty(len(meta), dtype=np.int64)
    new_of[old] = np.arange(len(old))
    out = meta[old].copy()
    inner = out[:, 0] >= 0
    out[inner, 0] = new_of[out[inner, 0]]
    out[inner, 1] = new_of[out[inner, 1]]
    return out.astype(np.int32), lo[old], hi[old], len(levels)
