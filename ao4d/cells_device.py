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
2. scans per-row counts of simplices and new vertices (rows of the last engine axis, then
   blocks of rows);
3. numbers the new vertices in (point, direction) order — the order of the numpy engine's
   sorted unique edge keys — and compacts their keys;
4. emits each active cell's simplices in cell order, table row by table row.

Only the two totals, the simplices and the new vertices' keys come back; the host interpolates
the new vertices in float64 from its own copy of the slab (:func:`ao4d.cells._interpolate`), so
the positions are the reference's bit for bit. Why reading "used" off the signs is exact: every
table case uses each of its crossed edges (tests/test_cells_device.py checks every case of every
table), and every crossed edge of the slab lies in one of its cells.

Kernels are int only, with no local memory and runtime-chosen work-group sizes; one work-item
walks one row, so a slab of P points in rows of n gives P / n work-items.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from . import cl
from ._validate import check_finite
from .cells import _CellTable, _corner_offsets, _Geometry, _interpolate, _Plan, _SlabMesh

__all__ = ["fits", "get_runtime", "march", "march_slabs"]

_CHUNK = 256  # points per work-item of the passes after classification (a multiple of 16)
_SCAN_BLOCK = 256  # chunks per block of the two-level scan
_INT_MAX = 2**31 - 1
_lock = threading.Lock()  # pyopencl kernels hold their arguments: one slab at a time per process


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
        blocks = -(-chunks // _SCAN_BLOCK)
        case_size = 2 if d == 4 else 1
        mask_size = 2 if plan.n_dirs > 8 else 1
        carry = geom.layer * plan.n_dirs * 4
        cl.check_device_memory(runtime, {
            "the slab's signs, cases, edge masks and first vertices": padded * (1 + case_size + mask_size + 4),
            "the shared layer's vertices (twice)": 2 * carry,
        }, task=f"extracting a grid of shape {geom.shape} on the device", fallback="thinner slabs (`chunk=`)")
        self.sign = self._buf(points)
        self.cases = self._buf(padded * case_size)
        self.vmask = self._buf(padded * mask_size)
        self.vfirst = self._buf(points * 4)
        self.chunk_v, self.chunk_s, self.chunk_a = (self._buf(chunks * 4) for _ in range(3))
        self.blk_v, self.blk_s, self.blk_a = (self._buf(blocks * 4) for _ in range(3))
        self.totals = self._buf(12)
        self.case_size, self.mask_size = case_size, mask_size
        self.carry = [self._buf(carry), self._buf(carry)]
        self._fill(self.carry[0], carry)
        self.out = self.keys = self.act_p = self.act_s = None
        self.out_size = self.keys_size = self.act_size = 0
        self.host_sign = np.empty(points, dtype=np.uint8)
        self.n_vertices = 0

    def _const(self, array: np.ndarray):
        return self.cl.Buffer(self.ctx, self.mf.READ_ONLY | self.mf.COPY_HOST_PTR,
                              hostbuf=np.ascontiguousarray(array))

    def _buf(self, nbytes: int):
        return self.cl.Buffer(self.ctx, self.mf.READ_WRITE, max(int(nbytes), 4))

    def _fill(self, buf, nbytes: int) -> None:
        self.cl.enqueue_fill_buffer(self.queue, buf, np.int32(-1), 0, max(int(nbytes), 4) // 4 * 4)

    def slab(self, slab: np.ndarray, level: float, inside: str, want_cells: bool):
        """March one slab: (simplices (S, d) int32, new keys (K,) int64, cells, counts) or None."""
        cl_, q, k = self.cl, self.queue, self.kernels
        d, n_dirs = self.d, self.n_dirs
        n = slab.size
        sign = self.host_sign[:n].view(bool).reshape(slab.shape)
        (np.greater_equal if inside == "below" else np.less_equal)(slab, level, out=sign)
        cl_.enqueue_copy(q, self.sign, self.host_sign[:n], is_blocking=False)
        chunks = -(-n // _CHUNK)
        blocks = -(-chunks // _SCAN_BLOCK)
        top_start = (slab.shape[0] - 1) * self.layer
        cur, nxt = self.carry
        self._fill(nxt, self.layer * n_dirs * 4)
        if chunks * _CHUNK > n:  # zero the last chunk's padding
            zero = np.uint8(0)
            cl_.enqueue_fill_buffer(q, self.cases, zero, n * self.case_size,
                                    (chunks * _CHUNK - n) * self.case_size)
            cl_.enqueue_fill_buffer(q, self.vmask, zero, n * self.mask_size,
                                    (chunks * _CHUNK - n) * self.mask_size)
        i32 = np.int32
        e = slab.shape
        grid = (e[-1], e[-2], n // (e[-1] * e[-2]))
        k["classify"](q, grid, None, self.sign, self.cases, self.vmask, cur, self.tables["counts"],
                      i32(self.in_plane), *self.strides, *self.user_bits, i32(e[0]),
                      i32(e[1] if d == 4 else 1))
        k["count"](q, (chunks,), None, self.cases, self.vmask, self.tables["counts"], self.chunk_v,
                   self.chunk_s, self.chunk_a)
        k["scan_chunks"](q, (blocks,), None, self.chunk_v, self.chunk_s, self.chunk_a, self.blk_v,
                         self.blk_s, self.blk_a, i32(chunks))
        k["scan_blocks"](q, (1,), None, self.blk_v, self.blk_s, self.blk_a, i32(blocks), self.totals)
        totals = np.empty(3, dtype=np.int32)
        cl_.enqueue_copy(q, totals, self.totals)
        n_new, n_simp, n_active = (int(t) for t in totals)
        if n_simp == 0:  # as the numpy engine: nothing to carry over an empty slab
            self._fill(cur, self.layer * n_dirs * 4)
            return None
        if self.n_vertices + n_new > _INT_MAX:
            raise MemoryError(f"the mesh would have more than {_INT_MAX:,} vertices, more than the "
                              "device engine indexes; use AO4D_DEVICE=none (the numpy engine)")
        if n_simp * d > self.out_size:
            self.out_size = int(n_simp * d * 1.25) + 16
            self.out = self._buf(self.out_size * 4)
        if n_new > self.keys_size:
            self.keys_size = int(n_new * 1.25) + 16
            self.keys = self._buf(self.keys_size * 4)
        if n_active > self.act_size:
            self.act_size = int(n_active * 1.25) + 16
            self.act_p, self.act_s = self._buf(self.act_size * 4), self._buf(self.act_size * 4)
        k["number"](q, (chunks,), None, self.cases, self.vmask, self.tables["counts"],
                    self.chunk_v, self.blk_v, self.chunk_s, self.blk_s, self.chunk_a, self.blk_a,
                    self.vfirst, self.keys, nxt, self.act_p, self.act_s, i32(self.n_vertices),
                    i32(self.in_plane), i32(top_start))
        k["emit"](q, (n_active,), None, self.cases, self.vmask, self.vfirst, cur, self.act_p,
                  self.act_s, self.tables["offsets"], self.tables["table"], self.edge_off,
                  self.edge_dir, self.out)
        simplices = np.empty((n_simp, d), dtype=np.int32)
        keys = np.empty(n_new, dtype=np.int32)
        cl_.enqueue_copy(q, simplices, self.out, is_blocking=False)
        cl_.enqueue_copy(q, keys, self.keys, is_blocking=False)
        cells = counts = None
        if want_cells:
            cells = np.empty(n_active, dtype=np.int32)
            first = np.empty(n_active + 1, dtype=np.int32)
            first[n_active] = n_simp
            cl_.enqueue_copy(q, cells, self.act_p, is_blocking=False)
            cl_.enqueue_copy(q, first[:n_active], self.act_s, is_blocking=False)
        q.finish()
        if want_cells:
            cells, counts = cells.astype(np.int64), np.diff(first).astype(np.int64)
        self.carry = [nxt, cur]
        self.n_vertices += n_new
        return simplices, keys.astype(np.int64), cells, counts

    def release(self) -> None:
        for name in ("sign", "cases", "vmask", "vfirst", "chunk_v", "chunk_s", "chunk_a", "blk_v",
                     "blk_s", "blk_a", "totals", "out", "keys", "act_p", "act_s"):
            buf = getattr(self, name, None)
            if buf is not None:
                buf.release()
                setattr(self, name, None)
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
    """
    with _lock:
        engine = _Engine(runtime, table, geom, layers_per_slab)
    plan = engine.plan
    empty = np.zeros(0, dtype=np.int64)
    try:
        n0 = geom.shape[0]
        z0 = 0
        while z0 < n0 - 1:
            z1 = min(z0 + layers_per_slab, n0 - 1)
            slab = read(z0, z1 + 1)
            if check_values:
                check_finite(slab, "values")
            with _lock:
                found = engine.slab(slab, level, inside, cells)
            if found is not None:
                simplices, new_keys, active, counts = found
                lin, dir_ = np.divmod(new_keys, plan.n_dirs)
                shift = z0 * geom.layer
                yield _SlabMesh(_interpolate(slab, lin, plan.dirs[dir_], z0, level, plan), simplices,
                                new_keys + shift * plan.n_dirs,
                                empty if active is None else active + shift,
                                empty if counts is None else counts)
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
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ao4d.cells._march` on the device: (vertices (V, d) float64, simplices (S, d) int32)."""
    d = len(geom.shape)
    verts: list[np.ndarray] = []
    simps: list[np.ndarray] = []
    for part in march_slabs(read, geom, level, table=table, inside=inside,
                            layers_per_slab=layers_per_slab, check_values=check_values,
                            progress=progress, runtime=runtime, cells=False):
        verts.append(part.vertices)
        simps.append(part.simplices)
    if not simps:
        return np.zeros((0, d)), np.zeros((0, d), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(simps)
