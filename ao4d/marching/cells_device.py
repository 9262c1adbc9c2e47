"""The marching engine of :mod:`ao4d.marching.cells` on the OpenCL device (``kernels/marching/march.cl``): the
whole march, from the values as stored to the final arrays.

It gives the arrays the numpy engine gives, vertex for vertex and simplex for simplex, so
:mod:`ao4d.marching.march` and :mod:`ao4d.marching.blockwise` take either engine. The numpy engine stays the
reference and the backend where no OpenCL device works. It stays one module: the slab loop,
the engine's buffers and the carry between slabs are one state that every step reads and writes.

Per slab, the host uploads the values as they are stored (float16, float32, float64, 8- to
64-bit integers; anything else as float64; a CPU device reads an array aligned to 128 bytes in
place, :mod:`ao4d._pages`) and the device

1. compares every value with the level once (``sign``: one comparison in the values' own type
   against :func:`ao4d.marching.cells.threshold`, which makes it equal to ``float64(v) >= level``)
   and flags NaN and infinities, so that the host need not read the values to check them,
2. classifies every cell (its case) and finds the crossed edges starting at every point that
   are new in this slab (an edge of the layer shared with the slab below keeps the vertex that
   slab gave it: the *carry*, kept on the device);
3. counts simplices, active cells and new vertices per chunk of 256 points and scans the counts
   (chunks, then blocks of chunks);
4. numbers the new vertices in the numpy engine's order, compacts their keys, remembers the top
   layer's in-plane vertices for the next slab, and compacts the active cells with their first
   simplex;
5. emits each active cell's simplices (one work-item per active cell), table row by table row,
   as int32 or int64 (the type of the final array);
6. interpolates every new vertex with the numpy engine's float64 operations in the same order
   (``#pragma OPENCL FP_CONTRACT OFF``: no fused multiply-add), so the positions are the
   reference's bit for bit.

Then the totals come back, and the simplices and vertices are read once, straight into the
final arrays; a CPU device writes them there in place (``CL_MEM_USE_HOST_PTR`` on page-aligned
rows, no copy at all). For arrays in memory the slabs are counted first, so the final arrays
are allocated once at their size; a grid in one device slab needs no count. The host touches
neither the values (beyond the upload, none for an aligned array on a CPU device) nor the
output. Memory: a device slab holds up to
:data:`_SLAB_POINTS` points (2^26; :data:`_FIELD_SLAB_POINTS` for fields), with about 13 bytes
of scratch per point besides the values' copy.

Device slabs are as large as memory allows, not the numpy engine's: the numpy engine's vertex
order depends on where its slabs of ``layers_per_slab`` (the *period*) meet (the in-plane
vertices of a layer two slabs share belong to the lower one and come first), and the kernels
number vertices with that rule at every multiple of the period inside a device slab, so a
device slab of any multiple of the period gives the same arrays. A ``chunk=`` the user chose
fixes the device's slabs too.

Devices without ``cl_khr_fp64`` compare exactly all the same (doubles as ordered integers) and
interpolate in float32: the simplices are the same, and each vertex coordinate is within
``2^-21 * (|origin| + spacing * (i + 1)) + spacing * dt`` of the float64 one, where ``dt``, the
error of ``t``, is at most ``2^-22 * (|level| + |f0| + |f1|) / |f1 - f0| + 2^-23`` (float64
values are truncated to float32 first; ``i`` the grid index). :data:`FLOAT32` forces that path.

Why reading "used" off the signs is exact: every table case uses each of its crossed edges
(tests/test_cells_device.py checks every case of every table), and every crossed edge of the
slab lies in one of its cells; so the shared layer's crossed in-plane edges are exactly the
carried ones.

Kernels are int only apart from ``sign`` and ``interpolate``, with no local memory and
runtime-chosen work-group sizes, so the same code suits CPUs and GPUs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from .._pages import PAGE, aligned_empty, readable_in_place
from .._validate import check_finite
from ..opencl import cl
from .cells import CellTable, Geometry, Job, Plan, SlabMesh, join, threshold

__all__ = ["FLOAT32", "IN_PLACE", "device_layers", "fits", "get_runtime", "march", "march_slabs", "release_buffers"]

_CHUNK = 256  # points per work-item of the passes after classification (a multiple of 16)
_SCAN_BLOCK = 256  # chunks per block of the two-level scan
_INT_MAX = 2**31 - 1
# Grid points per device slab: arrays in memory (up to a 400^3 or 90^4 grid in one slab, which
# needs neither a counting pass nor a host check of the values: 384^3 in two slabs took 1.8x as
# long as in one; at most 0.9 GB of scratch), and fields sampled slab by slab on the host (whose
# evaluation holds several float64 temporaries per point). About 13 bytes per point of device
# scratch plus the values.
_SLAB_POINTS = 1 << 26
_FIELD_SLAB_POINTS = 1 << 23
_lock = threading.Lock()  # pyopencl kernels hold their arguments: one slab at a time per process

#: Interpolate in float32 even where the device has ``cl_khr_fp64`` (the path of devices without
#: it; tests set it). Read when an extraction starts.
FLOAT32 = False

#: On a CPU device, let the kernels write the final arrays in place (``CL_MEM_USE_HOST_PTR``)
#: instead of device buffers read back (what other devices do; tests clear it).
IN_PLACE = True

#: Seconds per stage, summed over slabs, while :data:`PROFILE` is true (bench/extract.py sets
#: it; the device queue is then drained after every stage, which costs a little).
PROFILE = False
profile: dict[str, float] = {}

# value dtype -> (OpenCL type as stored, VKIND of kernels/marching/march.cl)
_NATIVE = {
    "f2": ("half", 1),
    "f4": ("float", 0),
    "i1": ("char", 0),
    "u1": ("uchar", 0),
    "i2": ("short", 0),
    "u2": ("ushort", 0),
    "i4": ("int", 0),
    "u4": ("uint", 0),
    "i8": ("long", 0),
    "u8": ("ulong", 0),
}


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
        ``"auto"``: the device :func:`ao4d.opencl.cl.get_runtime` chooses (``AO4D_DEVICE``), numpy
        when none works (no warning: the mesh is the same); ``"opencl"`` requires a device.
    """
    return cl.resolve_backend(backend, warn=False)


def fits(geom: Geometry, layers: int, table: CellTable) -> bool:
    """Whether one slab's 32-bit indices (points times directions) fit the kernels."""
    points = (min(layers, geom.shape[0] - 1) + 1) * geom.layer
    return points * table.n_dirs < _INT_MAX


def device_layers(geom: Geometry, period: int, table: CellTable, points: int | None = None) -> int:
    """Cell layers per device slab: the largest multiple of the numpy engine's ``period`` whose
    slab holds about ``points`` grid points (default :data:`_SLAB_POINTS`; at least ``period``
    layers) and fits 32-bit indices."""
    points = _SLAB_POINTS if points is None else points
    n_cells = geom.shape[0] - 1
    n_dirs = table.n_dirs
    per = max(1, period) * geom.layer  # points of ``period`` layers
    mult = max(1, points // per)
    mult = min(mult, -(-n_cells // max(1, period)))  # no more than the grid
    while mult > 1 and (mult * period + 1) * geom.layer * n_dirs >= _INT_MAX:
        mult -= 1
    return mult * period


def _table_arrays(table: CellTable) -> dict[str, np.ndarray]:
    return {
        "offsets": table.offsets.astype(np.int32),
        "counts": table.counts.astype(np.int32),
        "table": np.ascontiguousarray(table.simplices, dtype=np.uint8),
    }


# Scratch buffers that live for one slab, kept from slab to slab and from one extraction to the
# next (fresh buffers cost a page fault per page on first touch): (context id, name) -> buffer.
# At most a few bytes per point of the largest slab so far; release_buffers() drops them.
_pool: dict[Any, Any] = {}


def release_buffers() -> None:
    """Drop the scratch buffers kept between extractions (device memory)."""
    with _lock:
        _pool.clear()


# the cell tables on each device, by (context, table): the tables are built once per process
_device_tables: dict[tuple[int, int, int], dict[str, Any]] = {}


def _kernel_value(dtype: np.dtype, fp64: bool) -> tuple[str, int] | None:
    """(stored OpenCL type, VKIND) for values of ``dtype``, or None: widen to float64 first."""
    code = f"{dtype.kind}{dtype.itemsize}"
    if code == "f8":
        return ("double", 0) if fp64 else ("ulong", 2)
    return _NATIVE.get(code)


class _Engine:
    """Kernels and buffers of one extraction on one device, reused slab after slab."""

    def __init__(self, runtime: cl.Runtime, table: CellTable, geom: Geometry, layers: int, period: int) -> None:
        import pyopencl

        self.cl = pyopencl
        self.runtime = runtime
        self.ctx, self.queue = runtime.context, runtime.queue
        self.mf = pyopencl.mem_flags
        d = len(geom.shape)
        self.d = d
        self.geom = geom
        self.plan = plan = Plan.make(table, geom)
        self.n_dirs = plan.n_dirs
        self.period = period
        self.fp64 = not FLOAT32 and "cl_khr_fp64" in runtime.device.extensions
        self.real = np.float64 if self.fp64 else np.float32
        # a CPU device shares the host's memory: the kernels write the final arrays in place
        self.in_place = IN_PLACE and bool(runtime.device.type & pyopencl.device_type.CPU)
        self._built: dict[str, dict[str, Any]] = {}
        key = (id(self.ctx), id(table), d)
        if key not in _device_tables:
            arrays = _table_arrays(table)
            _device_tables[key] = {k: self._const(v) for k, v in arrays.items()}
        self.tables = _device_tables[key]
        offs, dir_of = plan.offs, plan.dir_of
        masks = np.arange(1 << d)
        expect = 1 << np.arange(d) if plan.n_dirs == d else masks[1:]
        if not np.array_equal(plan.dirs, expect):  # the kernels' DIR_MASK
            raise AssertionError(f"unexpected table directions {plan.dirs.tolist()}")
        self.strides = [np.int32(offs[1 << k]) for k in range(d)] + [np.int32(0)] * (4 - d)
        self.user_bits = [np.int32(1 << axis) for axis in geom.perm] + [np.int32(0)] * (4 - d)
        self.edge_off = self._const(offs[table.corner].astype(np.int32))
        step = (table.corner >> geom.perm[0]) & 1  # the edge's lower corner is one layer up
        self.edge_dir = self._const((dir_of[table.mask] | (step << 8) | (table.corner << 16)).astype(np.int32))
        self.in_plane = int(sum(1 << j for j in range(plan.n_dirs) if plan.in_plane[j]))
        self.layer = geom.layer
        points = (min(layers, geom.shape[0] - 1) + 1) * geom.layer
        chunks = -(-points // _CHUNK)
        padded = chunks * _CHUNK
        case_size = 2 if d == 4 else 1
        mask_size = 2 if plan.n_dirs > 8 else 1
        carry = geom.layer * plan.n_dirs * 4
        # new vertices found from per-block bases in 2D and 3D (half a byte a point), from
        # per-point first indices in 4D (8 bytes a point; kernels/marching/march.cl's new_vertex says why)
        self.vertex_blocks = d < 4
        cl.check_device_memory(
            runtime,
            {
                "the slab's values": points * 8,
                "the slab's values, signs, cases, edge masks and vertex numbers": padded
                * (8 + 1 + case_size + mask_size + (1 if self.vertex_blocks else 8)),
                "the shared layer's vertices (twice)": 2 * carry,
            },
            task=f"extracting a grid of shape {geom.shape} on the device",
            fallback="thinner slabs (`chunk=`)",
        )
        self.case_size, self.mask_size = case_size, mask_size
        # carry[key]: the vertex of a crossed in-plane edge of the shared layer (only those are
        # read, and each is written by the slab below: no fill needed)
        self.carry = [self._buf(carry), self._buf(carry)]
        self.has_below = False
        self.n_vertices = 0

    def kernels(self, vtype: str, vkind: int) -> dict[str, Any]:
        if vtype not in self._built:
            self._built[vtype] = cl.build_kernels(
                self.runtime,
                "marching/march.cl",
                {
                    "DIM": self.d,
                    "NDIRS": self.n_dirs,
                    "CHUNK": _CHUNK,
                    "SCAN_BLOCK": _SCAN_BLOCK,
                    "VTYPE": vtype,
                    "VKIND": vkind,
                    "VFLOAT": int(vtype in ("float", "double")),
                    "FP64": int(self.fp64),
                    "VERTEX_BLOCKS": int(self.vertex_blocks),
                },
            )
        return self._built[vtype]

    def _const(self, array: np.ndarray):
        return self.cl.Buffer(self.ctx, self.mf.READ_ONLY | self.mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(array))

    def _buf(self, nbytes: int):
        return self.cl.Buffer(self.ctx, self.mf.READ_WRITE, max(int(nbytes), 4))

    def _scratch(self, name: str, nbytes: int):
        """A device buffer of at least ``nbytes`` that lives for one slab (from the pool)."""
        key = (id(self.ctx), name)
        buf = _pool.get(key)
        if buf is None or buf.size < nbytes:
            buf = _pool[key] = None  # drop the old one before allocating
            buf = _pool[key] = self._buf(int(nbytes * 1.25) + 64)
        return buf

    def _threshold_arg(self, level: float, dtype: np.dtype, inside: str, vkind: int):
        """(thr, mode) kernel arguments of ``sign``."""
        thr = threshold(level, dtype, inside)
        if thr.value is None:
            mode, value = 2, dtype.type(0)
        else:
            mode, value = (0 if thr.op == ">=" else 1), thr.value
        if vkind == 1:
            return np.float32(value), np.int32(mode)
        if vkind == 2:  # ordered-integer key of the double; -0.0 so that both zeros pass >= 0
            x = np.float64(value)
            if x == 0 and mode == 0:
                x = np.float64(-0.0)
            bits = int(x.view(np.int64))
            return np.int64(bits if bits >= 0 else bits ^ 0x7FFFFFFFFFFFFFFF), np.int32(mode)
        return dtype.type(value), np.int32(mode)

    def slab(
        self,
        slab: np.ndarray,
        z0: int,
        level: float,
        inside: str,
        want_cells: bool,
        take: Callable[[int, int], tuple[np.ndarray, np.ndarray]] | None,
        below: bool | None = None,
        check: bool = False,
    ):
        """March one slab (its first layer ``z0`` in the grid), or None when it has no simplex.

        ``check``: raise ``ValueError`` naming ``values`` when the slab holds NaN or infinities
        (found by the first kernel, which reads every value anyway).

        With ``take=None`` only count: (new vertices, simplices) of the slab, ``below`` saying
        whether a slab lies below it (the engine's own state is left alone).

        ``take(S, K)`` gives the (S, d) int32 or int64 rows the simplices are read into and the
        (K, d) float64 rows the new vertices are read into. Returns (those two arrays, the new
        vertices' keys (K,) int64, the active cells and their simplex counts; the last three
        only with ``want_cells``, else None).
        """
        run = _SlabMarch(self, slab)
        run.upload()
        run.sign(level, inside)
        run.classify(self.in_plane if (self.has_below if below is None else below) else 0)
        n_new, n_simp, n_active = run.count(check)
        if take is None:
            return n_new, n_simp
        self.has_below = True
        if n_simp == 0:  # an empty slab shares no crossed edge with the next one
            return None
        if self.n_vertices + n_new > _INT_MAX:
            raise MemoryError(
                f"the mesh would have more than {_INT_MAX:,} vertices, more than the "
                "device engine indexes; use backend='numpy' (AO4D_DEVICE=none)"
            )
        if n_simp * self.d > _INT_MAX:
            raise MemoryError(
                f"one slab makes {n_simp:,} simplices, more than the device engine "
                "indexes in one slab; use thinner slabs (`chunk=`)"
            )
        simplices, vertices = take(n_simp, n_new)
        run.outputs(simplices, vertices, n_new)
        run.number(z0, n_new, n_active)
        run.emit(n_active)
        run.interpolate(z0, level, n_new)
        found = run.read_back(simplices, vertices, n_new, n_active, want_cells)
        self.carry = [run.nxt, run.cur]  # the top layer's vertices: the next slab's shared layer
        self.n_vertices += n_new
        return found

    def release(self) -> None:
        for buf in self.carry:
            buf.release()
        self.carry = []


class _SlabMarch:
    """One slab's march on an :class:`_Engine`: its buffers and kernel launches, step by step.

    The steps run in order: :meth:`upload`, :meth:`sign`, :meth:`classify`, :meth:`count`; then,
    with a place for the rows, :meth:`outputs`, :meth:`number`, :meth:`emit`,
    :meth:`interpolate` and :meth:`read_back`.
    """

    def __init__(self, engine: _Engine, slab: np.ndarray) -> None:
        kv = _kernel_value(slab.dtype, engine.fp64)
        if kv is None:
            slab, kv = slab.astype(np.float64), _kernel_value(np.dtype(np.float64), engine.fp64)
        self.engine, self.slab, self.vkind = engine, slab, kv[1]
        self.cl, self.q = engine.cl, engine.queue
        self.fill = getattr(slab, "fill_device", None)  # a field sampled on the device: ao4d.marching.fields_device
        self.k = engine.kernels(*kv)
        self.n = n = slab.size
        self.chunks = chunks = -(-n // _CHUNK)
        self.blocks = blocks = -(-chunks // _SCAN_BLOCK)
        self.n0 = slab.shape[0]
        scratch = self.scratch = engine._scratch
        # an aligned array in memory is read in place by a CPU device (no upload: a copy of the
        # whole slab, a sixth of a 256^3 march); others are copied into the scratch buffer
        self.host_values = self.fill is None and engine.in_place and readable_in_place(slab)
        if self.host_values:
            self.values = self.cl.Buffer(engine.ctx, engine.mf.READ_ONLY | engine.mf.USE_HOST_PTR, hostbuf=slab)
        else:
            self.values = scratch("values", slab.nbytes)
        self.sign_buf = scratch("sign", n + 16)  # classify reads 16 bytes past the last point
        self.cases = scratch("cases", chunks * _CHUNK * engine.case_size)
        self.vmask = scratch("vmask", chunks * _CHUNK * engine.mask_size)
        self.chunk_vi, self.chunk_va, self.chunk_s, self.chunk_a = (
            scratch(f"chunk {x}", chunks * 4) for x in ("vi", "va", "s", "a")
        )
        self.blk = scratch("blocks", 4 * blocks * 4)
        self.totals_buf = scratch("totals", 16)
        self.bad_buf = scratch("bad", 4)
        self.cur, self.nxt = engine.carry
        self.t = time.perf_counter()

    def _stage(self, name: str) -> None:
        self.t = _stage(name, self.q, self.t)

    def upload(self) -> None:
        """The slab's values into the device buffer (sampled there, copied, or read in place)."""
        if self.fill is not None:
            self.fill(self.engine.runtime, self.values)
        elif not self.host_values:
            self.cl.enqueue_copy(self.q, self.values, np.ascontiguousarray(self.slab), is_blocking=False)
        self._stage("upload")

    def sign(self, level: float, inside: str) -> None:
        """Each value's side of the level; NaN and infinities flagged in the ``bad`` buffer."""
        thr, mode = self.engine._threshold_arg(level, self.slab.dtype, inside, self.vkind)
        self.cl.enqueue_fill_buffer(self.q, self.bad_buf, np.int32(0), 0, 4)
        self.k["sign"](
            self.q, (-(-self.n // 16),), None, self.values, self.sign_buf, thr, mode, self.bad_buf, np.int32(self.n)
        )
        self._stage("sign")

    def classify(self, shared: int) -> None:
        """Each cell's case and each point's new crossed edges (``shared``: the in-plane
        directions whose edges the slab below gave vertices, or 0)."""
        engine, q, n = self.engine, self.q, self.n
        padded = self.chunks * _CHUNK
        if padded > n:  # zero the last chunk's padding
            zero = np.uint8(0)
            self.cl.enqueue_fill_buffer(q, self.cases, zero, n * engine.case_size, (padded - n) * engine.case_size)
            self.cl.enqueue_fill_buffer(q, self.vmask, zero, n * engine.mask_size, (padded - n) * engine.mask_size)
        e = self.slab.shape
        grid = (-(-e[-1] // 16), e[-2], n // (e[-1] * e[-2]))
        self.k["classify"](
            q,
            grid,
            None,
            self.sign_buf,
            self.cases,
            self.vmask,
            engine.tables["counts"],
            np.int32(shared),
            *engine.strides,
            *engine.user_bits,
            np.int32(e[0]),
            np.int32(e[1] if engine.d == 4 else 1),
            np.int32(e[-1]),
        )
        self._stage("classify")

    def count(self, check: bool) -> tuple[int, int, int]:
        """(new vertices, simplices, active cells) of the slab: counted per chunk and scanned.

        ``check``: raise ``ValueError`` naming ``values`` when the slab holds NaN or infinities.
        """
        k, q, cl_ = self.k, self.q, self.cl
        chunks, blocks = self.chunks, self.blocks
        counts = (self.chunk_vi, self.chunk_va, self.chunk_s, self.chunk_a)
        tables = self.engine.tables
        k["count"](
            q, (chunks,), None, self.cases, self.vmask, tables["counts"], *counts, np.int32(self.engine.in_plane)
        )
        k["scan_chunks"](q, (blocks,), None, *counts, self.blk, np.int32(chunks), np.int32(blocks))
        k["scan_blocks"](q, (1,), None, self.blk, np.int32(blocks), self.totals_buf)
        totals = np.empty(4, dtype=np.int32)
        bad = np.zeros(1, dtype=np.int32)
        if check:
            cl_.enqueue_copy(q, bad, self.bad_buf, is_blocking=False)
        cl_.enqueue_copy(q, totals, self.totals_buf)
        if self.host_values:  # no kernel keeps the caller's array past this call
            k["sign"].set_arg(0, self.scratch("placeholder", 64))
        if bad[0]:
            check_finite(self.slab, "values")  # counts them and raises
        self._stage("count and scan")
        n_in, n_ax, n_simp, n_active = (int(x) for x in totals)
        return n_in + n_ax, n_simp, n_active

    def outputs(self, simplices: np.ndarray, vertices: np.ndarray, n_new: int) -> None:
        """The device buffers the simplices and new vertices are written to: the final rows
        themselves where the device can write them in place (a CPU device and rows that start on
        a page: the first slab's; other slabs' would be copied), else scratch buffers."""
        engine = self.engine
        self.wide = simplices.dtype == np.int64
        self.in_place = (
            engine.in_place and simplices.ctypes.data % PAGE == 0 and (n_new == 0 or vertices.ctypes.data % PAGE == 0)
        )
        if self.in_place:
            flags = engine.mf.WRITE_ONLY | engine.mf.USE_HOST_PTR
            self.out = self.cl.Buffer(engine.ctx, flags, hostbuf=simplices)
            self.verts = self.cl.Buffer(engine.ctx, flags, hostbuf=vertices) if n_new else None
        else:
            self.out = self.scratch("simplices", len(simplices) * engine.d * (8 if self.wide else 4))
            self.verts = self.scratch("vertices", n_new * engine.d * 8)

    def number(self, z0: int, n_new: int, n_active: int) -> None:
        """Number the new vertices in the numpy engine's order (keeping the top layer's in-plane
        ones for the next slab) and compact the active cells with their first simplex."""
        engine, scratch, n, n0 = self.engine, self.scratch, self.n, self.n0
        self.keys_buf = scratch("keys", n_new * 4)
        if engine.vertex_blocks:  # (ki, ka) per block of 16 points
            self.vblock = scratch("vertex blocks", self.chunks * _CHUNK // 16 * 8)
            self.vfirst = self.vax = scratch("placeholder", 64)
        else:
            self.vblock = scratch("placeholder", 64)
            self.vfirst, self.vax = scratch("vfirst", n * 4), scratch("vax", n * 4)
        self.layer_in, self.layer_ax = scratch("layer in", (n0 + 1) * 4), scratch("layer ax", (n0 + 1) * 4)
        self.act_p, self.act_s = scratch("active points", n_active * 4), scratch("active first", n_active * 4)
        self.act_b = scratch("active flags", n_active)
        in_plane, layer = np.int32(engine.in_plane), np.int32(engine.layer)
        chunk_counts = (self.chunk_vi, self.chunk_va)
        self.k["layer_prefix"](
            self.q,
            (n0 + 1,),
            None,
            self.vmask,
            *chunk_counts,
            self.blk,
            self.totals_buf,
            self.layer_in,
            self.layer_ax,
            layer,
            np.int32(n),
            np.int32(self.blocks),
            in_plane,
        )
        self.k["number"](
            self.q,
            (self.chunks,),
            None,
            self.cases,
            self.vmask,
            engine.tables["counts"],
            *chunk_counts,
            self.chunk_s,
            self.chunk_a,
            self.blk,
            self.layer_in,
            self.layer_ax,
            self.vblock,
            self.vfirst,
            self.vax,
            self.keys_buf,
            self.nxt,
            self.act_p,
            self.act_s,
            self.act_b,
            np.int32(self.blocks),
            np.int32(engine.n_vertices),
            in_plane,
            np.int32((n0 - 1) * engine.layer),  # the top layer's first point
            layer,
            np.int32(z0),
            np.int32(engine.period),
        )
        self._stage("number")

    def emit(self, n_active: int) -> None:
        """Each active cell's simplices, table row by table row, into the output buffer."""
        engine = self.engine
        self.k["emit64" if self.wide else "emit32"](
            self.q,
            (n_active,),
            None,
            self.cases,
            self.vmask,
            self.vblock,
            self.vfirst,
            self.vax,
            self.layer_in,
            self.layer_ax,
            self.cur,
            self.act_p,
            self.act_s,
            self.act_b,
            engine.tables["offsets"],
            engine.tables["table"],
            engine.edge_off,
            engine.edge_dir,
            np.int32(engine.in_plane),
            np.int32(engine.layer),
            np.int32(engine.n_vertices),
            self.out,
        )
        self._stage("emit")

    def interpolate(self, z0: int, level: float, n_new: int) -> None:
        """Every new vertex's position, with :func:`ao4d.marching.cells.interpolate`'s operations."""
        engine = self.engine
        if n_new:
            d = engine.d
            real, pad = engine.real, [0] * (4 - d)
            index, origin, spacing = engine.geom.frame(z0)  # what cells.interpolate adds and scales
            shape = list(self.slab.shape[1:]) + [1] * (4 - d)
            perm = list(engine.geom.perm) + pad
            base = index + pad
            origin = [real(x) for x in origin + pad]
            spacing = [real(x) for x in spacing + pad]
            self.k["interpolate"](
                self.q,
                (n_new,),
                None,
                self.values,
                self.keys_buf,
                self.verts,
                real(level),
                *(np.int32(x) for x in shape[:3]),
                *engine.strides,
                *(np.int32(x) for x in perm),
                *(np.int32(x) for x in base),
                *origin,
                *spacing,
            )
        self._stage("interpolate")

    def read_back(
        self, simplices: np.ndarray, vertices: np.ndarray, n_new: int, n_active: int, want_cells: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """The rows read (or mapped) back, and with ``want_cells`` the new vertices' keys, the
        active cells and their simplex counts (int64); the kernels let go of the caller's arrays."""
        cl_, q, k = self.cl, self.q, self.k
        mapped = []
        if self.in_place:
            for buf, rows in ((self.out, simplices), (self.verts, vertices)):
                if buf is not None:
                    view, _ = cl_.enqueue_map_buffer(
                        q, buf, cl_.map_flags.READ, 0, rows.shape, rows.dtype, is_blocking=False
                    )
                    mapped.append((buf, view))
        else:
            cl_.enqueue_copy(q, simplices, self.out, is_blocking=False)
            if n_new:
                cl_.enqueue_copy(q, vertices, self.verts, is_blocking=False)
        keys = cells = counts = None
        if want_cells:
            keys = np.empty(n_new, dtype=np.int32)
            cells = np.empty(n_active, dtype=np.int32)
            first = np.empty(n_active + 1, dtype=np.int32)
            first[n_active] = len(simplices)
            if n_new:
                cl_.enqueue_copy(q, keys, self.keys_buf, is_blocking=False)
            cl_.enqueue_copy(q, cells, self.act_p, is_blocking=False)
            cl_.enqueue_copy(q, first[:n_active], self.act_s, is_blocking=False)
        q.finish()
        # no kernel keeps the caller's rows (written in place) or values (read in place)
        placeholder = self.scratch("placeholder", 64)
        if self.in_place:
            k["emit64" if self.wide else "emit32"].set_arg(18, placeholder)
            k["interpolate"].set_arg(2, placeholder)
        if self.host_values:
            k["interpolate"].set_arg(0, placeholder)
        for buf, view in mapped:
            view.base.release()
            buf.release()
        self._stage("download")
        if want_cells:
            keys, cells, counts = keys.astype(np.int64), cells.astype(np.int64), np.diff(first).astype(np.int64)
        return simplices, vertices, keys, cells, counts


def march_slabs(
    job: Job,
    *,
    runtime: cl.Runtime,
    cells: bool = True,
    take: Callable[[int, int, float], tuple[np.ndarray, np.ndarray]] | None = None,
    count_first: Callable[[int, int], None] | None = None,
    slab_points: int | None = None,
    grow: bool = True,
) -> Iterator[SlabMesh]:
    """:func:`ao4d.marching.cells.march_slabs` on the device: the same arrays, in device slabs.

    The yielded :class:`SlabMesh` parts cover device slabs (multiples of ``layers_per_slab``,
    :func:`device_layers`); concatenated, their arrays are those of the numpy engine's parts.

    Parameters
    ----------
    job : ao4d.marching.cells.Job
        The extraction, as for :func:`ao4d.marching.cells.march_slabs` (the callers validate); its
        ``layers_per_slab`` is the numpy engine's slab, whose vertex order the device keeps.
    runtime : ao4d.opencl.cl.Runtime
        The device.
    cells : bool
        Also report each slab's new vertices' keys, active cells and their simplex counts
        (block-wise welding needs them). When False, ``keys``, ``cells`` and ``counts`` of the
        yielded meshes are empty.
    take : callable, optional
        ``take(S, K, done)``: where the next slab's S simplices and K vertices go ((S, d) int32
        or int64 and (K, d) float64 rows, read from the device straight into them; ``done`` is
        the fraction of the grid's layers marched after this slab). By default new arrays per
        slab, int32 like the numpy engine's.
    count_first : callable, optional
        Count every slab's simplices and new vertices first (reading each slab twice: for
        arrays in memory) and call ``count_first(S, K)`` with the totals before marching, so
        that the output can be allocated once, at its size.
    slab_points : int, optional
        About how many grid points a device slab holds (default :data:`_SLAB_POINTS`).
    grow : bool
        Whether device slabs may be larger than ``layers_per_slab`` (False: the user chose the
        slab size, ``chunk=``, to bound memory).
    """
    geom, level, inside, layers_per_slab = job.geom, job.level, job.inside, job.layers_per_slab
    if take is None:

        def take(n_simp: int, n_new: int, done: float) -> tuple[np.ndarray, np.ndarray]:
            return aligned_empty((n_simp, d), np.int32), aligned_empty((n_new, d), np.float64)

    d = len(geom.shape)
    layers = device_layers(geom, layers_per_slab, job.table, slab_points) if grow else layers_per_slab
    with _lock:
        engine = _Engine(runtime, job.table, geom, layers, layers_per_slab)
    plan = engine.plan
    empty = np.zeros(0, dtype=np.int64)
    try:
        n0 = geom.shape[0]
        if count_first is not None:
            total_simp = total_new = 0
            for z0, _, slab in job.slabs(layers, report=False, check=False):
                with _lock:
                    n_new, n_simp = engine.slab(
                        slab, z0, level, inside, False, None, below=z0 > 0, check=job.check_values
                    )
                total_simp += n_simp
                total_new += n_new if n_simp else 0
            count_first(total_simp, total_new)
        for z0, z1, slab in job.slabs(layers, check=False):
            done = z1 / (n0 - 1)
            with _lock:
                found = engine.slab(
                    slab,
                    z0,
                    level,
                    inside,
                    cells,
                    lambda n_simp, n_new, done=done: take(n_simp, n_new, done),
                    check=job.check_values,
                )
            del slab
            if found is not None:
                simplices, vertices, new_keys, active, counts = found
                shift = z0 * geom.layer
                yield SlabMesh(
                    vertices,
                    simplices,
                    empty if new_keys is None else new_keys + shift * plan.n_dirs,
                    empty if active is None else active + shift,
                    empty if counts is None else counts,
                )
    finally:
        with _lock:
            engine.release()


def in_one_slab(geom: Geometry, layers_per_slab: int, table: CellTable, grow: bool = True) -> bool:
    """Whether :func:`march` marches the whole grid as one device slab (arguments as for
    :func:`march_slabs`)."""
    layers = device_layers(geom, layers_per_slab, table) if grow else layers_per_slab
    return layers >= geom.shape[0] - 1


def march(
    job: Job,
    *,
    runtime: cl.Runtime,
    reread: bool = False,
    grow: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ao4d.marching.cells.march` on the device: (vertices (V, d) float64, simplices (S, d) int64;
    the numpy engine's are int32 while they fit, the same values).

    ``reread``: ``read`` is cheap (an array in memory): the output is allocated once at its size
    and each device slab is read straight into it (a grid in one device slab is counted by its
    own march; more slabs are counted first); otherwise (a field sampled slab by slab, in
    smaller device slabs) the slab parts are concatenated at the end, as the numpy engine does.
    ``grow``: as for :func:`march_slabs`.
    """
    geom, table = job.geom, job.table
    d = len(geom.shape)
    kwargs = dict(runtime=runtime, cells=False, grow=grow)
    one_slab = in_one_slab(geom, job.layers_per_slab, table, grow)
    # several device slabs of an array in memory: count them all first and fill the output in
    # place where the output outweighs the input (4D Kuhn simplices: counting again costs less
    # than copying the output), else slab parts and one concatenation (measured: 384^3 and 96^4
    # cubes 1.3-1.4x faster so, 96^4 simplices 1.2-1.3x slower)
    count_first = d == 4 and table.n_dirs == 15
    if not reread or (not one_slab and not count_first):
        # slab parts (int32, as the numpy engine keeps them), then one concatenation, widened
        # to int64 while concatenated (one part is returned as it is: SimplexMesh widens it in
        # its own copy)
        points = _SLAB_POINTS if reread else min(_SLAB_POINTS, _FIELD_SLAB_POINTS)
        return join(march_slabs(job, slab_points=points, **kwargs), d, widen=True)
    rows_s, rows_v = _Rows(d, np.int64), _Rows(d, np.float64)

    def take(n_simp: int, n_new: int, done: float) -> tuple[np.ndarray, np.ndarray]:
        if one_slab:
            rows_s.reserve(n_simp)
            rows_v.reserve(n_new)
        return rows_s.take(n_simp), rows_v.take(n_new)

    def count_first(n_simp: int, n_new: int) -> None:
        rows_s.reserve(n_simp)
        rows_v.reserve(n_new)

    for part in march_slabs(job, take=take, count_first=None if one_slab else count_first, **kwargs):
        del part  # views into the rows
    return rows_v.array, rows_s.array


class _Rows:
    """A (n, d) array allocated once at its counted size and filled slab by slab in place."""

    def __init__(self, d: int, dtype: Any) -> None:
        self.array = np.empty((0, d), dtype=dtype)
        self.n = 0

    def reserve(self, n: int) -> None:
        """Room for ``n`` rows in all (before any row is taken)."""
        self.array = aligned_empty((n, self.array.shape[1]), self.array.dtype)

    def take(self, k: int) -> np.ndarray:
        """The next ``k`` rows (a view)."""
        rows = self.array[self.n : self.n + k]
        if len(rows) != k:
            raise RuntimeError("the slabs made more rows than they were counted to make")
        self.n += k
        return rows
