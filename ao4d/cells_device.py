"""The marching engine of :mod:`ao4d.cells` on the OpenCL device (``kernels/march.cl``).

Same slabs, same welding, same arrays: for every slab it yields the :class:`ao4d.cells._SlabMesh`
the numpy engine yields, vertex for vertex and simplex for simplex, so :mod:`ao4d.march` and
:mod:`ao4d.blockwise` take either engine. The numpy engine stays the reference and the backend
where no OpenCL device works.

Per slab, the host compares the values with the level (``f >= level``, the exact comparison of
the reference, in the values' own precision) and sends one byte per point; the device then

1. classifies every cell (its case) and finds the crossed edges starting at every point that
   are new in this slab (an edge of the layer shared with the slab below keeps the vertex that
   slab gave it: the *carry*, kept on the device);
2. counts simplices, new vertices and active cells per chunk of 256 points and scans the
   counts (chunks, then blocks of chunks);
3. numbers the new vertices in (point, direction) order — the order of the numpy engine's
   sorted unique edge keys —, compacts their keys, remembers the top layer's in-plane vertices
   for the next slab, and compacts the active cells with their first simplex;
4. emits each active cell's simplices (one work-item per active cell), table row by table row.

Only the totals, the simplices and the new vertices' keys come back (and, for block-wise
welding, the active cells); the host interpolates
the new vertices in float64 from its own copy of the slab (:func:`ao4d.cells._interpolate`), so
the positions are the reference's bit for bit. Why reading "used" off the signs is exact: every
table case uses each of its crossed edges (tests/test_cells_device.py checks every case of every
table), and every crossed edge of the slab lies in one of its cells; so the shared layer's
crossed in-plane edges are exactly the carried ones.

Kernels are int only, with no local memory and runtime-chosen work-group sizes (classification
one work-item per point, the chunk passes one per 256 points, emission one per active cell), so
the same code suits CPUs and GPUs. Slabs are the numpy engine's (``cells._layers_per_slab``):
the vertex order depends on where slabs meet, so the same slabs give the same order.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from . import cl
from ._validate import check_finite
from .cells import _CellTable, _corner_offsets, _Geometry, _Plan, _SlabMesh

__all__ = ["fits", "get_runtime", "march", "march_slabs", "release_buffers"]

_CHUNK = 256  # points per work-item of the passes after classification (a multiple of 16)
_SCAN_BLOCK = 256  # chunks per block of the two-level scan
_INT_MAX = 2**31 - 1
_lock = threading.Lock()  # pyopencl kernels hold their arguments: one slab at a time per process

#: Seconds per stage, summed over slabs, while :data:`PROFILE` is true (bench/extract.py sets
#: it; the device queue is then drained after every stage, which costs a little).
PROFILE = False
profile: dict[str, float] = {}


def _stage(name: str, queue: Any, since: float) -> float:
    """Add the time since ``since`` to stage ``name`` (after draining the queue); return now."""
    if not PROFILE:
        return since
    queue.finish()
    now = time.perf_counter()
    profile[name] = profile.get(name, 0.0) + now - since
    return now


def get_runtime(backend: str = "auto") -> cl.Runtime | None:
    """The OpenCL runtime extraction runs on, or ``None`` for the numpy engine.

    Parameters
    ----------
    backend : {"auto", "opencl", "numpy"}
        ``"auto"``: the device :func:`ao4d.cl.get_runtime` chooses (``AO4D_DEVICE``), numpy
        when none works (no warning: the mesh is the same); ``"opencl"`` requires a device.
    """
    return cl.resolve_backend(backend, warn=False)


def fits(geom: _Geometry, layers: int, table: _CellTable) -> bool:
    """Whether one slab's 32-bit indices (points times directions) fit the kernels."""
    n_dirs = len(np.unique(table.mask))
    points = (min(layers, geom.shape[0] - 1) + 1) * geom.layer
    return points * n_dirs < _INT_MAX


def _table_arrays(table: _CellTable) -> dict[str, np.ndarray]:
    return {
        "offsets": table.offsets.astype(np.int32),
        "counts": table.counts.astype(np.int32),
        "table": np.ascontiguousarray(table.simplices, dtype=np.uint8),
    }


# Scratch buffers that live for one slab, kept from slab to slab and from one extraction to the
# next (fresh buffers cost a page fault per page on first touch): (context id, name) -> buffer,
# and the host's sign bytes. At most a few bytes per point of the largest slab so far;
# release_buffers() drops them.
_pool: dict[Any, Any] = {}


def release_buffers() -> None:
    """Drop the scratch buffers kept between extractions (device and host memory)."""
    with _lock:
        _pool.clear()


# the cell tables on each device, by (context, table): the tables are built once per process
_device_tables: dict[tuple[int, int, int], dict[str, Any]] = {}


class _Engine:
    """Kernels and buffers of one extraction on one device, reused slab after slab."""

    def __init__(self, runtime: cl.Runtime, table: _CellTable, geom: _Geometry, layers: int) -> None:
        import pyopencl

        self.cl = pyopencl
        self.runtime = runtime
        self.ctx, self.queue = runtime.context, runtime.queue
        self.mf = pyopencl.mem_flags
        d = len(geom.shape)
        self.d = d
        self.plan = plan = _Plan.make(table, geom)
        self.n_dirs = plan.n_dirs
        self.kernels = cl.build_kernels(runtime, "march.cl",
                                        {"DIM": d, "NDIRS": plan.n_dirs, "CHUNK": _CHUNK,
                                         "SCAN_BLOCK": _SCAN_BLOCK})
        key = (id(self.ctx), id(table), d)
        if key not in _device_tables:
            arrays = _table_arrays(table)
            _device_tables[key] = {k: self._const(v) for k, v in arrays.items()}
        self.tables = _device_tables[key]
        offs = _corner_offsets(geom, d)
        dir_of = np.zeros(1 << d, dtype=np.int64)
        dir_of[plan.dirs] = np.arange(plan.n_dirs)
        masks = np.arange(1 << d)
        expect = 1 << np.arange(d) if plan.n_dirs == d else masks[1:]
        if not np.array_equal(plan.dirs, expect):  # the kernels' DIR_MASK
            raise AssertionError(f"unexpected table directions {plan.dirs.tolist()}")
        self.strides = [np.int32(offs[1 << k]) for k in range(d)] + [np.int32(0)] * (4 - d)
        self.user_bits = [np.int32(1 << axis) for axis in geom.perm] + [np.int32(0)] * (4 - d)
        self.edge_off = self._const(offs[table.corner].astype(np.int32))
        self.edge_dir = self._const(dir_of[table.mask].astype(np.int32))
        self.in_plane = int(sum(1 << j for j in range(plan.n_dirs) if plan.in_plane[j]))
        self.layer = geom.layer
        points = (min(layers, geom.shape[0] - 1) + 1) * geom.layer
        chunks = -(-points // _CHUNK)
        padded = chunks * _CHUNK
        case_size = 2 if d == 4 else 1
        mask_size = 2 if plan.n_dirs > 8 else 1
        carry = geom.layer * plan.n_dirs * 4
        cl.check_device_memory(runtime, {
            "the slab's signs, cases, edge masks and first vertices": padded * (1 + case_size + mask_size + 4),
            "the shared layer's vertices (twice)": 2 * carry,
        }, task=f"extracting a grid of shape {geom.shape} on the device", fallback="thinner slabs (`chunk=`)")
        self.case_size, self.mask_size = case_size, mask_size
        # carry[key]: the vertex of a crossed in-plane edge of the shared layer (only those are
        # read, and each is written by the slab below: no fill needed)
        self.carry = [self._buf(carry), self._buf(carry)]
        self.has_below = False
        self.n_vertices = 0

    def _const(self, array: np.ndarray):
        return self.cl.Buffer(self.ctx, self.mf.READ_ONLY | self.mf.COPY_HOST_PTR,
                              hostbuf=np.ascontiguousarray(array))

    def _buf(self, nbytes: int):
        return self.cl.Buffer(self.ctx, self.mf.READ_WRITE, max(int(nbytes), 4))

    def _scratch(self, name: str, nbytes: int):
        """A device buffer of at least ``nbytes`` that lives for one slab (from the pool)."""
        key = (id(self.ctx), name)
        buf = _pool.get(key)
        if buf is None or buf.size < nbytes:
            buf = _pool[key] = self._buf(int(nbytes * 1.25) + 64)
        return buf

    def _host_rows(self, n: int) -> np.ndarray:
        buf = _pool.get("host rows")
        if buf is None or buf.size < n:
            buf = _pool["host rows"] = np.empty(int(n * 1.25) + 64, dtype=np.int32)
        return buf[:n]

    def _host_sign(self, n: int) -> np.ndarray:
        buf = _pool.get("host sign")
        if buf is None or buf.size < n:
            buf = _pool["host sign"] = np.empty(int(n * 1.25) + 64, dtype=np.uint8)
        return buf[:n]

    def slab(self, slab: np.ndarray, level: float, inside: str, want_cells: bool,
             take: Callable[[int, int], tuple[np.ndarray, np.ndarray]] | None,
             below: bool | None = None):
        """March one slab, or None when it has no simplex.

        With ``take=None`` only count: (new vertices, simplices) of the slab, ``below`` saying
        whether a slab lies below it (the engine's own state is left alone).

        ``take(S, K)`` gives the (S, d) int32 or int64 rows the simplices are read into and the (K, d)
        float64 rows for the new vertices (filled by the caller). Returns (those two arrays, the
        new vertices' keys (K,) int64, the active cells and their simplex counts, or None).
        """
        cl_, q, k = self.cl, self.queue, self.kernels
        d = self.d
        n = slab.size
        chunks = -(-n // _CHUNK)
        blocks = -(-chunks // _SCAN_BLOCK)
        scratch = self._scratch
        self.sign = scratch("sign", n)
        self.cases = scratch("cases", chunks * _CHUNK * self.case_size)
        self.vmask = scratch("vmask", chunks * _CHUNK * self.mask_size)
        self.vfirst = scratch("vfirst", n * 4)
        self.chunk_v, self.chunk_s, self.chunk_a = (scratch(f"chunk {x}", chunks * 4) for x in "vsa")
        self.blk_v, self.blk_s, self.blk_a = (scratch(f"block {x}", blocks * 4) for x in "vsa")
        self.totals = scratch("totals", 12)
        t = time.perf_counter()
        host_sign = self._host_sign(n)
        sign = host_sign.view(bool).reshape(slab.shape)
        (np.greater_equal if inside == "below" else np.less_equal)(slab, level, out=sign)
        t = _stage("signs (host)", q, t)
        cl_.enqueue_copy(q, self.sign, host_sign, is_blocking=False)
        t = _stage("upload", q, t)
        top_start = (slab.shape[0] - 1) * self.layer
        cur, nxt = self.carry
        if chunks * _CHUNK > n:  # zero the last chunk's padding
            zero = np.uint8(0)
            cl_.enqueue_fill_buffer(q, self.cases, zero, n * self.case_size,
                                    (chunks * _CHUNK - n) * self.case_size)
            cl_.enqueue_fill_buffer(q, self.vmask, zero, n * self.mask_size,
                                    (chunks * _CHUNK - n) * self.mask_size)
        i32 = np.int32
        e = slab.shape
        grid = (e[-1], e[-2], n // (e[-1] * e[-2]))
        shared = self.in_plane if (self.has_below if below is None else below) else 0
        k["classify"](q, grid, None, self.sign, self.cases, self.vmask, self.tables["counts"],
                      i32(shared), *self.strides, *self.user_bits, i32(e[0]),
                      i32(e[1] if d == 4 else 1))
        t = _stage("classify", q, t)
        k["count"](q, (chunks,), None, self.cases, self.vmask, self.tables["counts"], self.chunk_v,
                   self.chunk_s, self.chunk_a)
        k["scan_chunks"](q, (blocks,), None, self.chunk_v, self.chunk_s, self.chunk_a, self.blk_v,
                         self.blk_s, self.blk_a, i32(chunks))
        k["scan_blocks"](q, (1,), None, self.blk_v, self.blk_s, self.blk_a, i32(blocks), self.totals)
        totals = np.empty(3, dtype=np.int32)
        cl_.enqueue_copy(q, totals, self.totals)
        t = _stage("count and scan", q, t)
        n_new, n_simp, n_active = (int(t) for t in totals)
        if take is None:
            return n_new, n_simp
        self.has_below = True
        if n_simp == 0:  # an empty slab shares no crossed edge with the next one
            return None
        if self.n_vertices + n_new > _INT_MAX:
            raise MemoryError(f"the mesh would have more than {_INT_MAX:,} vertices, more than the "
                              "device engine indexes; use backend='numpy' (AO4D_DEVICE=none)")
        if n_simp * d > _INT_MAX:
            raise MemoryError(f"one slab makes {n_simp:,} simplices, more than the device engine "
                              "indexes in one slab; use thinner slabs (`chunk=`)")
        self.out = scratch("simplices", n_simp * d * 4)
        self.keys = scratch("keys", n_new * 4)
        self.act_p, self.act_s = scratch("active points", n_active * 4), scratch("active first", n_active * 4)
        k["number"](q, (chunks,), None, self.cases, self.vmask, self.tables["counts"],
                    self.chunk_v, self.blk_v, self.chunk_s, self.blk_s, self.chunk_a, self.blk_a,
                    self.vfirst, self.keys, nxt, self.act_p, self.act_s, i32(self.n_vertices),
                    i32(self.in_plane), i32(top_start))
        t = _stage("number", q, t)
        k["emit"](q, (n_active,), None, self.cases, self.vmask, self.vfirst, cur, self.act_p,
                  self.act_s, self.tables["offsets"], self.tables["table"], self.edge_off,
                  self.edge_dir, self.out)
        t = _stage("emit", q, t)
        simplices, vertices = take(n_simp, n_new)
        keys = np.empty(n_new, dtype=np.int32)
        staged = simplices  # int32 rows are read as they are; wider ones through a staging copy
        if simplices.dtype != np.int32:
            staged = self._host_rows(n_simp * d).reshape(n_simp, d)
        cl_.enqueue_copy(q, staged, self.out, is_blocking=False)
        if n_new:
            cl_.enqueue_copy(q, keys, self.keys, is_blocking=False)
        cells = counts = None
        if want_cells:
            cells = np.empty(n_active, dtype=np.int32)
            first = np.empty(n_active + 1, dtype=np.int32)
            first[n_active] = n_simp
            cl_.enqueue_copy(q, cells, self.act_p, is_blocking=False)
            cl_.enqueue_copy(q, first[:n_active], self.act_s, is_blocking=False)
        q.finish()
        if staged is not simplices:
            simplices[...] = staged
        t = _stage("download", q, t)
        if want_cells:
            cells, counts = cells.astype(np.int64), np.diff(first).astype(np.int64)
        self.carry = [nxt, cur]
        self.n_vertices += n_new
        return simplices, vertices, keys.astype(np.int64), cells, counts

    def release(self) -> None:
        for buf in self.carry:
            buf.release()
        self.carry = []


def march_slabs(
    read: Callable[[int, int], np.ndarray],
    geom: _Geometry,
    level: float,
    *,
    table: _CellTable,
    inside: str,
    layers_per_slab: int,
    check_values: bool,
    progress: Any,
    runtime: cl.Runtime,
    cells: bool = True,
    take: Callable[[int, int, float], tuple[np.ndarray, np.ndarray]] | None = None,
    count_first: Callable[[int, int], None] | None = None,
) -> Iterator[_SlabMesh]:
    """:func:`ao4d.cells._march_slabs` on the device: the same :class:`_SlabMesh` per slab.

    Parameters
    ----------
    read, geom, level, table, inside, layers_per_slab, check_values, progress
        As for :func:`ao4d.cells._march_slabs` (the callers validate).
    runtime : ao4d.cl.Runtime
        The device.
    cells : bool
        Also report each slab's active cells and their simplex counts (block-wise welding needs
        them; they cost one read of the slab's cases). When False, ``cells`` and ``counts`` of
        the yielded meshes are empty.
    take : callable, optional
        ``take(S, K, done)``: where the next slab's S simplices and K vertices go ((S, d) int32
        or int64 and (K, d) float64 rows; ``done`` is the fraction of the grid's layers marched
        after this slab). By default new arrays per slab, int32 like the numpy engine's.
    count_first : callable, optional
        Count every slab's simplices and new vertices first (reading each slab twice: for
        arrays in memory) and call ``count_first(S, K)`` with the totals before marching, so
        that the output can be allocated once, at its size.
    """
    if take is None:
        def take(n_simp: int, n_new: int, done: float) -> tuple[np.ndarray, np.ndarray]:
            return np.empty((n_simp, d), dtype=np.int32), np.empty((n_new, d))
    d = len(geom.shape)
    with _lock:
        engine = _Engine(runtime, table, geom, layers_per_slab)
    plan = engine.plan
    empty = np.zeros(0, dtype=np.int64)
    try:
        n0 = geom.shape[0]
        if count_first is not None:
            total_simp = total_new = 0
            z0 = 0
            while z0 < n0 - 1:
                z1 = min(z0 + layers_per_slab, n0 - 1)
                slab = read(z0, z1 + 1)
                if check_values:
                    check_finite(slab, "values")
                with _lock:
                    n_new, n_simp = engine.slab(slab, level, inside, False, None, below=z0 > 0)
                total_simp += n_simp
                total_new += n_new if n_simp else 0
                z0 = z1
            count_first(total_simp, total_new)
        z0 = 0
        while z0 < n0 - 1:
            z1 = min(z0 + layers_per_slab, n0 - 1)
            slab = read(z0, z1 + 1)
            if check_values:
                check_finite(slab, "values")
            done = z1 / (n0 - 1)
            with _lock:
                found = engine.slab(slab, level, inside, cells,
                                    lambda n_simp, n_new, done=done: take(n_simp, n_new, done))
            if found is not None:
                simplices, vertices, new_keys, active, counts = found
                t = time.perf_counter()
                _interpolate_into(vertices, slab, new_keys, z0, level, plan)
                shift = z0 * geom.layer
                part = _SlabMesh(vertices, simplices, new_keys + shift * plan.n_dirs,
                                 empty if active is None else active + shift,
                                 empty if counts is None else counts)
                _stage("interpolate (host)", engine.queue, t)
                yield part
            if progress is not None:
                progress.update(z1 - z0)
            z0 = z1
    finally:
        with _lock:
            engine.release()


def march(
    read: Callable[[int, int], np.ndarray],
    geom: _Geometry,
    level: float,
    *,
    table: _CellTable,
    inside: str,
    layers_per_slab: int,
    check_values: bool,
    progress: Any,
    runtime: cl.Runtime,
    reread: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ao4d.cells._march` on the device: (vertices (V, d) float64, simplices (S, d) int64;
    the numpy engine's are int32 while they fit, the same values).

    ``reread``: ``read`` is cheap (an array in memory), so the slabs are counted first and the
    output is allocated once at its size and filled in place (no slab parts, no concatenation:
    large fresh allocations are slow to fault in here); otherwise (a field sampled slab by slab)
    the slab parts are concatenated at the end, as the numpy engine does.
    """
    d = len(geom.shape)
    kwargs = dict(table=table, inside=inside, layers_per_slab=layers_per_slab,
                  check_values=check_values, progress=progress, runtime=runtime, cells=False)
    if not reread:  # slab parts (int32, as the numpy engine keeps them), then one concatenation
        verts, simps = [], []
        for part in march_slabs(read, geom, level, **kwargs):
            verts.append(part.vertices)
            simps.append(part.simplices)
        if not simps:
            return np.zeros((0, d)), np.zeros((0, d), dtype=np.int64)
        vertices = np.concatenate(verts)
        del verts
        simplices = np.empty((sum(len(x) for x in simps), d), dtype=np.int64)
        np.concatenate(simps, out=simplices)  # widened while concatenated
        return vertices, simplices
    rows_s, rows_v = _Rows(d, np.int64), _Rows(d, np.float64)

    def take(n_simp: int, n_new: int, done: float) -> tuple[np.ndarray, np.ndarray]:
        return rows_s.take(n_simp), rows_v.take(n_new)

    def count_first(n_simp: int, n_new: int) -> None:
        rows_s.reserve(n_simp)
        rows_v.reserve(n_new)

    for part in march_slabs(read, geom, level, take=take, count_first=count_first, **kwargs):
        del part  # views into the rows
    return rows_v.array, rows_s.array


class _Rows:
    """A (n, d) array allocated once at its counted size and filled slab by slab in place."""

    def __init__(self, d: int, dtype: Any) -> None:
        self.array = np.empty((0, d), dtype=dtype)
        self.n = 0

    def reserve(self, n: int) -> None:
        """Room for ``n`` rows in all (before any row is taken)."""
        self.array = np.empty((n, self.array.shape[1]), dtype=self.array.dtype)

    def take(self, k: int) -> np.ndarray:
        """The next ``k`` rows (a view)."""
        rows = self.array[self.n : self.n + k]
        if len(rows) != k:
            raise RuntimeError("the slabs made more rows than they were counted to make")
        self.n += k
        return rows


def _interpolate_into(out: np.ndarray, slab: np.ndarray, keys: np.ndarray, z0: int, level: float,
                      plan: _Plan) -> None:
    """:func:`ao4d.cells._interpolate` of the vertices with edge ``keys``, written into ``out``.

    The same float64 operations on every element (so the same bits), column by column without
    the (K, d) temporaries.
    """
    if len(keys) == 0:
        return
    geom = plan.geom
    lin, dir_ = np.divmod(keys, plan.n_dirs)
    masks = plan.dirs[dir_]
    flat = slab.reshape(-1)
    f0 = flat[lin].astype(np.float64, copy=False)
    f1 = flat[lin + plan.offs[plan.dirs][dir_]].astype(np.float64, copy=False)
    with np.errstate(invalid="ignore"):
        t = np.subtract(level, f0)
        t /= f1 - f0
    np.clip(t, 0.0, 1.0, out=t)
    t[np.isnan(t)] = 1.0  # the infinite padding of closed=True (see cells._interpolate)
    eidx = np.unravel_index(lin, slab.shape)
    start = [0] * len(geom.shape) if geom.offset is None else [int(k) for k in geom.offset]
    col = np.empty(len(keys))
    for e, axis in enumerate(geom.perm):
        col[:] = eidx[e] + ((z0 if e == 0 else 0) + start[axis])
        bit = (masks >> axis) & 1
        col += t * bit  # as the reference's idx += t * mask_bits: t or 0.0, added
        np.multiply(geom.spacing[axis], col, out=col)
        np.add(geom.origin[axis], col, out=out[:, axis])

