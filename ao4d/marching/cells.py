"""The marching engine shared by :mod:`ao4d.marching.march` (slabs in one process) and
:mod:`ao4d.marching.blockwise` (dask blocks): cell tables, classification, emission and welding by global
edge id. Vectorised numpy with no checks of its own: the callers validate.

How the core works (all numpy, no Python loop over cells):

1. Per slab of grid layers, classify every cell: bit v of its case is set iff corner v is
   positive (``f >= level``; DESIGN.md), compared as the user means it: the level in float64
   against the value widened. :func:`threshold` turns that into one comparison in the data's
   own dtype (``f >= thr``, thr the smallest value of the dtype that is >= level), so float16,
   float32 and integer data are neither widened nor compared with a rounded level. The bits are
   combined axis by axis (d passes over the slab instead of 2^d).
2. Look up the simplices of the active cells (case neither 0 nor all ones) in a *cell table*:
   rows of d edge ids, each edge given by its lower corner ``a`` and direction mask ``m``
   (``a & m == 0``). The cube table comes straight from :func:`ao4d.marching.lut.load`; the Kuhn table
   concatenates, per cube case, the simplex-table entries of the d! Kuhn cells (with the
   orientation reversed in odd cells), so both methods share the rest of the pipeline. Kuhn
   edges include cube diagonals (any non-zero ``m``).
3. Each crossed grid edge is one vertex, welded by its global key ``point * n_dirs + dir(m)``.
   Within a slab a dense key map replaces sorting; across slabs the vertices of the shared
   layer are carried over, so memory stays bounded by the slab size.
4. Every vertex is interpolated once, from its own edge, with ``t = (level - f0) / (f1 - f0)``
   in float64 (both ends widened) where exactly one end is positive: ``t`` lies in [0, 1] in
   floating point too (the subtraction is monotonic), and every cell sees the same point.

The cell tables are expressed in user axes; a slab axis other than axis 0 (fields are evaluated
along the last axis, Fortran arrays are read transposed) only changes the strides used to turn
corners into memory offsets, so the mesh never depends on the memory layout.

The engine marches any grid that a ``read(a, b)`` callable serves slab by slab (a :class:`Job`,
whose :meth:`Job.slabs` is the slab loop of both engines); a grid that is a block of a larger
one carries its index ``offset`` (:class:`Geometry`), and :func:`march_slabs` reports each
slab's vertices with their edge keys and active cells, which is what block-wise welding needs.
The device engine (:mod:`ao4d.marching.cells_device`) takes the same :class:`Job` and gives the same
arrays. The names without an underscore are shared inside the package (march, cells_device and
blockwise import them); none is part of the public API.

References
----------
.. [1] P. Bhaniramka, R. Wenger, R. Crawfis, "Isosurfacing in higher dimensions", IEEE
   Visualization 2000, doi:10.1109/VISUAL.2000.885693; "Isosurface construction in any dimension
   using convex hulls", IEEE TVCG 10(2) (2004), doi:10.1109/TVCG.2004.1260762.
.. [2] W. E. Lorensen, H. E. Cline, "Marching cubes: a high resolution 3D surface construction
   algorithm", SIGGRAPH 1987, doi:10.1145/37402.37422.
.. [3] H. Freudenthal, "Simplizialzerlegungen von beschränkter Flachheit", Annals of Mathematics
   43(3) (1942), doi:10.2307/1968813 (the Kuhn split).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import check_finite, check_memory, check_positive_int

# Dense key-map entries per slab (points x directions). 2^23 keeps the per-slab working set
# (key map, mark array, case array, values) near 100 MB in 4D.
_KEYS_PER_SLAB = 1 << 23
# Show a progress bar by default from this many cells on (about a 40^4 grid).
PROGRESS_CELLS = 1 << 21


# --------------------------------------------------------------------------------------------
# cell tables
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CellTable:
    """Simplices of every cube case as rows of edge ids; edge e runs from corner ``corner[e]``
    to ``corner[e] | mask[e]``."""

    dim: int
    offsets: np.ndarray  # (2^(2^d) + 1,) int64
    counts: np.ndarray  # (2^(2^d),) int64
    simplices: np.ndarray  # (M, d) uint8 edge ids
    corner: np.ndarray  # (E,) int64
    mask: np.ndarray  # (E,) int64

    @property
    def n_dirs(self) -> int:
        """How many edge directions the table uses (d for cubes, 2^d - 1 for the Kuhn split)."""
        return len(np.unique(self.mask))


def _load_table(dim: int, kind: str):
    from . import lut

    return lut.load(dim, kind)


@functools.lru_cache(maxsize=None)
def cube_table(dim: int) -> CellTable:
    table = _load_table(dim, "cube")
    u, v = table.edges[:, 0].astype(np.int64), table.edges[:, 1].astype(np.int64)
    offsets = table.offsets.astype(np.int64)
    return CellTable(dim, offsets, np.diff(offsets), table.simplices.astype(np.uint8), u & v, u ^ v)


@functools.lru_cache(maxsize=None)
def kuhn_table(dim: int) -> CellTable:
    """Cube-level table of the Kuhn split: per cube case, the simplices of all d! cells."""
    table = _load_table(dim, "simplex")
    n = 1 << dim
    cells = table.cells.astype(np.int64)  # (J, d+1) cube corners
    parity = table.cell_parity
    # every cube edge or diagonal (a, m) with a & m == 0, m != 0, numbered densely
    pairs = [(a, m) for m in range(1, n) for a in range(n) if a & m == 0]
    pair_id = np.full((n, n), -1, dtype=np.int64)
    for e, (a, m) in enumerate(pairs):
        pair_id[a, m] = e
    lo_c, hi_c = cells[:, table.edges[:, 0]], cells[:, table.edges[:, 1]]  # (J, Es)
    edge_map = pair_id[lo_c & hi_c, lo_c ^ hi_c]  # (J, Es): simplex-table edge -> pair id

    cases = np.arange(1 << n, dtype=np.int64)
    bits = (cases[:, None, None] >> cells[None, :, :]) & 1  # (C, J, d+1)
    sub_case = (bits << np.arange(dim + 1)).sum(axis=2)  # (C, J)
    sub_counts = np.diff(table.offsets)[sub_case].ravel()
    sub_start = table.offsets[:-1][sub_case].ravel()
    total = int(sub_counts.sum())
    first = np.cumsum(sub_counts) - sub_counts
    rows = np.repeat(sub_start - first, sub_counts) + np.arange(total)
    cell_of_row = np.repeat(np.tile(np.arange(len(cells)), len(cases)), sub_counts)
    n_edges = edge_map.shape[1]  # flat gather: much faster than 2D broadcast indexing
    simplices = edge_map.ravel()[(cell_of_row * n_edges)[:, None] + table.simplices[rows]]
    odd = parity[cell_of_row] < 0
    simplices[odd, 0], simplices[odd, 1] = simplices[odd, 1], simplices[odd, 0].copy()
    counts = sub_counts.reshape(len(cases), len(cells)).sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    pairs_arr = np.array(pairs, dtype=np.int64)
    return CellTable(dim, offsets, counts, simplices.astype(np.uint8), pairs_arr[:, 0], pairs_arr[:, 1])


def cell_table(dim: int, method: str) -> CellTable:
    return cube_table(dim) if method == "cubes" else kuhn_table(dim)


# --------------------------------------------------------------------------------------------
# the core
# --------------------------------------------------------------------------------------------


@dataclass
class Geometry:
    """Engine layout: engine axis e holds user axis ``perm[e]``; slabs run along engine axis 0."""

    shape: tuple[int, ...]  # engine grid shape
    perm: tuple[int, ...]
    origin: np.ndarray  # (d,) user axes
    spacing: np.ndarray  # (d,) user axes
    # (d,) int64 user-axis grid index of this grid's first point inside a larger grid (a dask
    # block); vertices sit at origin + spacing * (offset + local index + t * mask)
    offset: np.ndarray | None = None

    @property
    def layer(self) -> int:
        """Points per layer (engine axis 0 stride)."""
        return math.prod(self.shape[1:])

    def frame(self, z0: int) -> tuple[list[int], list[float], list[float]]:
        """Per engine axis, for the slab starting at layer ``z0``: the grid index of the slab's
        first point (in the larger grid, with :attr:`offset`), the origin and the spacing. The
        vertex of slab point ``i`` (engine index), ``t`` along direction ``m`` lies at
        ``origin + spacing * ((i + index) + t * m)`` on each axis, integers added first: the
        same float in every slab and block, and on the device (kernels/marching/march.cl)."""
        start = [0] * len(self.shape) if self.offset is None else [int(k) for k in self.offset]
        index = [(z0 if e == 0 else 0) + start[axis] for e, axis in enumerate(self.perm)]
        return (
            index,
            [float(self.origin[axis]) for axis in self.perm],
            [float(self.spacing[axis]) for axis in self.perm],
        )


def corner_offsets(geom: Geometry, d: int) -> np.ndarray:
    """(2^d,) engine linear offset of the corner (or mask) with user bits v."""
    strides = np.cumprod((1,) + geom.shape[:0:-1])[::-1]  # engine C-order strides
    user_stride = np.empty(d, dtype=np.int64)
    user_stride[list(geom.perm)] = strides
    v = np.arange(1 << d)
    return (((v[:, None] >> np.arange(d)) & 1) * user_stride).sum(axis=1)


def _cases(positive: np.ndarray, perm: tuple[int, ...]) -> np.ndarray:
    """Case index of every cell, stored at its lowest corner (last layers along each axis: 0)."""
    d = positive.ndim
    c = positive.astype(np.uint16 if d == 4 else np.uint8)
    for k in range(d):  # user axis k carries corner bits 2^k .. 2^(k+1)-1
        e = perm.index(k)
        lo = (slice(None),) * e + (slice(None, -1),)
        hi = (slice(None),) * e + (slice(1, None),)
        c[lo] |= c[hi] << (1 << k)
    for e in range(d):
        c[(slice(None),) * e + (-1,)] = 0
    return c


@dataclass(frozen=True)
class Threshold:
    """The level as one comparison in the data's dtype: a value ``v`` is positive iff
    ``v >= value`` (``op == ">="``; ``inside="below"``) or ``v <= value`` (``"<="``; ``"above"``),
    which equals ``float64(v) >= level`` (``<=``) exactly. ``value`` is ``None`` when no value
    of the dtype is positive (an integer dtype whose range the level misses)."""

    value: Any  # numpy scalar of the data's dtype, or None
    op: str  # ">=" or "<="


@functools.lru_cache(maxsize=256)
def threshold(level: float, dtype: np.dtype, inside: str) -> Threshold:
    """The comparison in ``dtype`` that equals comparing the widened values with ``level``.

    Floats: the level rounded into the dtype, moved one step up (``inside="below"``: the
    smallest value >= level) or down (``"above"``: the largest value <= level) when rounding
    went the wrong way; a level beyond the dtype's range becomes an infinity, which only an
    infinite value reaches. Integers: ``ceil(level)`` (``floor``); a level above (below) the
    dtype's range makes no value positive (``value=None``), one below (above) every value.
    64-bit integers beyond 2^53, which float64 cannot hold, are compared exactly.
    """
    dtype = np.dtype(dtype)
    below = inside == "below"
    op = ">=" if below else "<="
    if dtype.kind == "f":
        with np.errstate(over="ignore"):
            x = dtype.type(level)
        if (float(x) < level) if below else (float(x) > level):
            x = np.nextafter(x, dtype.type(np.inf if below else -np.inf))
        return Threshold(x, op)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        c = math.ceil(level) if below else math.floor(level)
        if (c > info.max) if below else (c < info.min):
            return Threshold(None, op)
        return Threshold(dtype.type(min(max(c, info.min), info.max)), op)
    return threshold(level, np.dtype(np.float64), inside)  # bool and others: as float64


def _positive(values: np.ndarray, level: float, inside: str, out: np.ndarray | None = None) -> np.ndarray:
    """Bool array: which ``values`` are positive (:func:`threshold`'s exact comparison)."""
    thr = threshold(level, values.dtype, inside)
    if thr.value is None:
        if out is None:
            return np.zeros(values.shape, dtype=bool)
        out.fill(False)
        return out
    return (np.greater_equal if thr.op == ">=" else np.less_equal)(values, thr.value, out=out)


@dataclass
class Plan:
    """Per-grid constants of the core: table edges as key offsets, directions, shared layers."""

    table: CellTable
    geom: Geometry
    offs: np.ndarray  # (2^d,) engine offset of each user corner / mask
    dirs: np.ndarray  # (n_dirs,) edge direction masks used by the table
    dir_of: np.ndarray  # (2^d,) direction number of each mask the table uses
    key_off: np.ndarray  # (E,) key offset of each table edge from its cell's lowest corner
    in_plane: np.ndarray  # (n_dirs,) direction lies inside a layer (no slab-axis bit)
    mask_bits: np.ndarray  # (2^d, d) float: user bits of each mask

    @classmethod
    def make(cls, table: CellTable, geom: Geometry) -> Plan:
        d = len(geom.shape)
        offs = corner_offsets(geom, d)
        dirs = np.unique(table.mask)
        dir_of = np.zeros(1 << d, dtype=np.int64)
        dir_of[dirs] = np.arange(len(dirs))
        key_off = offs[table.corner] * len(dirs) + dir_of[table.mask]
        in_plane = (dirs & (1 << geom.perm[0])) == 0
        mask_bits = ((np.arange(1 << d)[:, None] >> np.arange(d)) & 1).astype(np.float64)
        return cls(table, geom, offs, dirs, dir_of, key_off, in_plane, mask_bits)

    @property
    def n_dirs(self) -> int:
        return len(self.dirs)


def _slab_keys(case: np.ndarray, plan: Plan, n_keys: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Edge keys of the simplices of all active cells of one slab, or None if empty.

    ``case`` holds every cell's case at its lowest corner (flat slab index). Returns (keys
    (M, d), active (A,) flat slab index of each active cell, counts (A,) its simplices); the
    simplices of active cell ``j`` are ``counts[j]`` consecutive rows, in cell order.
    """
    table, n_dirs = plan.table, plan.n_dirs
    full = (1 << (1 << table.dim)) - 1
    active = np.flatnonzero((case != 0) & (case != full))
    case = case[active].astype(np.int64)
    counts = table.counts[case]
    n_simp = int(counts.sum())
    if n_simp == 0:
        return None
    first = np.cumsum(counts) - counts
    rows = np.repeat(table.offsets[case] - first, counts) + np.arange(n_simp)
    # int32 keys halve the memory traffic of the hottest lines when the slab allows
    kt = np.int32 if n_keys < 2**31 else np.int64
    base = np.repeat((active * n_dirs).astype(kt), counts)
    return base[:, None] + plan.key_off.astype(kt)[table.simplices[rows]], active, counts


class _Welder:
    """Numbers the crossed edges (vertices) of successive slabs, sharing the layer between two
    slabs: keys of the top layer are remembered (``carry``) and reused by the next slab."""

    def __init__(self, plan: Plan) -> None:
        self.plan = plan
        self.carry = np.full(plan.geom.layer * plan.n_dirs, -1, dtype=np.int64)
        self.n_vertices = 0

    def number(self, keys: np.ndarray | None, n_keys: int, n_layers: int):
        """Vertex index of every key. Returns (simplices (M, d), new_keys (K,)): ``new_keys``
        are the sorted keys of the vertices first seen in this slab, in index order."""
        plan, carry = self.plan, self.carry
        layer_keys = plan.geom.layer * plan.n_dirs
        if keys is None:
            carry.fill(-1)
            return None, None
        mark = np.zeros(n_keys, dtype=bool)  # sorted unique keys without sorting
        mark[keys] = True
        used = np.flatnonzero(mark)
        del mark
        in_plane = plan.in_plane[used % plan.n_dirs]
        shared = np.zeros(len(used), dtype=bool)
        bottom = (used < layer_keys) & in_plane
        shared[bottom] = carry[used[bottom]] >= 0
        index = np.empty(len(used), dtype=np.int64)
        index[shared] = carry[used[shared]]
        new = ~shared
        n_new = int(np.count_nonzero(new))
        index[new] = self.n_vertices + np.arange(n_new)
        self.n_vertices += n_new
        carry.fill(-1)
        top = (used >= n_layers * layer_keys) & in_plane
        carry[used[top] - n_layers * layer_keys] = index[top]
        # key -> index through a dense map (np.empty: only the used keys are touched);
        # int32 halves the memory the slabs hold until the final concatenation
        key_map = np.empty(n_keys, dtype=np.int32 if self.n_vertices < 2**31 else np.int64)
        key_map[used] = index
        return key_map[keys], used[new]


@dataclass
class SlabMesh:
    """What one slab adds: its new vertices, its simplices (indices into all vertices so far)
    and, for block-wise welding (:mod:`ao4d.marching.blockwise`), the engine keys of those vertices
    (``point * n_dirs + dir``, point = engine linear index in this grid) and the engine linear
    index of each active cell's lowest corner with its simplex count."""

    vertices: np.ndarray  # (K, d) float64
    simplices: np.ndarray  # (M, d) int32|int64
    keys: np.ndarray  # (K,) int64, increasing
    cells: np.ndarray  # (A,) int64, increasing
    counts: np.ndarray  # (A,) int64, sum M


@dataclass(frozen=True)
class Job:
    """One extraction as both engines take it (validated by the callers): the slab reader,
    the grid, the level and how to march it.

    ``read(a, b)`` returns the values of engine layers ``a`` to ``b - 1`` (engine layout,
    C order); ``layers_per_slab`` is the numpy engine's slab, whose vertex order the device
    engine keeps too; ``progress`` is a bar (``update(n)``) or None.
    """

    read: Callable[[int, int], np.ndarray]
    geom: Geometry
    level: float
    table: CellTable
    inside: str
    layers_per_slab: int
    check_values: bool
    progress: Any = None

    def slabs(
        self, layers: int | None = None, *, report: bool = True, check: bool = True
    ) -> Iterator[tuple[int, int, np.ndarray]]:
        """The slab loop of both engines: ``(z0, z1, values of layers z0..z1)`` for slabs of
        ``layers`` cell layers (default :attr:`layers_per_slab`) that share their boundary
        layer, read and checked when asked for (:attr:`check_values`; ``check=False``: the
        caller checks them itself, as the device engine does in its first pass). ``report``:
        advance :attr:`progress` by each slab's layers once the caller is done with it."""
        layers = self.layers_per_slab if layers is None else layers
        n0 = self.geom.shape[0]
        z0 = 0
        while z0 < n0 - 1:
            z1 = min(z0 + layers, n0 - 1)
            yield z0, z1, self._read(z0, z1 + 1, check)  # no reference kept here while the caller works
            if report and self.progress is not None:
                self.progress.update(z1 - z0)
            z0 = z1

    def _read(self, a: int, b: int, check: bool = True) -> np.ndarray:
        slab = self.read(a, b)
        if check and self.check_values:
            check_finite(slab, "values")
        return slab


def march_slabs(job: Job) -> Iterator[SlabMesh]:
    """March slab by slab, yielding each non-empty slab's :class:`SlabMesh`."""
    geom, level = job.geom, job.level
    plan = Plan.make(job.table, geom)
    welder = _Welder(plan)
    for z0, z1, slab in job.slabs():
        case = _cases(_positive(slab, level, job.inside), geom.perm).ravel()
        n_keys = slab.size * plan.n_dirs
        found = _slab_keys(case, plan, n_keys)
        simplices, new_keys = welder.number(None if found is None else found[0], n_keys, z1 - z0)
        if simplices is not None:
            lin, dir_ = np.divmod(new_keys, plan.n_dirs)
            shift = z0 * geom.layer  # slab -> grid linear index
            yield SlabMesh(
                interpolate(slab, lin, plan.dirs[dir_], z0, level, plan),
                simplices,
                new_keys + shift * plan.n_dirs,
                found[1] + shift,
                found[2],
            )


def march(job: Job) -> tuple[np.ndarray, np.ndarray]:
    """Extract the mesh slab by slab: (vertices (V, d) float64, simplices (S, d) int32|int64)."""
    # kept int32 when it fits: SimplexMesh converts to int64 in its own (unavoidable) copy
    return join(march_slabs(job), len(job.geom.shape))


def join(parts: Iterable[SlabMesh], d: int, *, widen: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The vertices and simplices of slab ``parts``, concatenated: (V, d) float64 and (S, d)
    in the parts' index type, or int64 with ``widen`` (then a single part is returned as it
    is, without a copy)."""
    verts: list[np.ndarray] = []
    simps: list[np.ndarray] = []
    for part in parts:
        verts.append(part.vertices)
        simps.append(part.simplices)
    if not simps:
        return np.zeros((0, d)), np.zeros((0, d), dtype=np.int64)
    if widen and len(simps) == 1:
        return verts[0], simps[0]
    vertices = np.concatenate(verts)
    del verts
    if not widen:
        return vertices, np.concatenate(simps)
    simplices = np.empty((sum(len(x) for x in simps), d), dtype=np.int64)
    np.concatenate(simps, out=simplices)  # widened while concatenated
    return vertices, simplices


def interpolate(slab: np.ndarray, lin: np.ndarray, masks: np.ndarray, z0: int, level: float, plan: Plan) -> np.ndarray:
    """Positions (K, d) of the crossings on edges (slab point ``lin``, direction ``masks``):
    the reference whose float64 operations the device's ``interpolate`` kernel repeats."""
    geom = plan.geom
    flat = slab.reshape(-1)
    f0 = flat[lin].astype(np.float64)
    f1 = flat[lin + plan.offs[masks]].astype(np.float64)
    # exactly one end is positive, so f1 != f0 and fl(level - f0) lies between 0 and fl(f1 - f0)
    with np.errstate(invalid="ignore"):
        t = np.clip((level - f0) / (f1 - f0), 0.0, 1.0)
    # an infinite lower end (the outside padding of ``closed=True``) gives inf / inf: the limit
    # of ever larger outside values is 1, the vertex at the grid's end of the edge
    t[np.isnan(t)] = 1.0
    eidx = np.unravel_index(lin, slab.shape)
    idx = np.empty((len(lin), len(geom.shape)))
    index = geom.frame(z0)[0]
    for e, axis in enumerate(geom.perm):  # integer index first: the same float in every block
        idx[:, axis] = eidx[e] + index[e]
    idx += t[:, None] * plan.mask_bits[masks]
    return geom.origin + geom.spacing * idx


def outside_value(inside: str) -> float:
    """The value of the cells ``closed=True`` pads the grid with: positive, on the outside.

    Infinite, so that a vertex on an edge that leaves the grid sits on the grid's boundary
    face (the limit of ever larger outside values: ``t`` is 0 at the grid end, and the
    undefined ``inf / inf`` at the far end is taken as that limit, 1; see
    :func:`interpolate`).
    """
    return math.inf if inside == "below" else -math.inf


def layers_per_slab(chunk: Any, geom: Geometry, method: str) -> int:
    """The numpy engine's cell layers per slab: ``chunk`` when given, else as many as keep a
    slab's dense key map near :data:`_KEYS_PER_SLAB` entries."""
    n_dirs = cell_table(len(geom.shape), method).n_dirs
    if chunk is None:
        return max(1, _KEYS_PER_SLAB // max(1, geom.layer * n_dirs) - 1)
    return check_positive_int(chunk, "chunk")


def check_slab_memory(geom: Geometry, layers: int, method: str, itemsize: int) -> None:
    d = len(geom.shape)
    n_dirs = d if method == "cubes" else (1 << d) - 1
    points = (layers + 1) * geom.layer
    # values + float64 copy, sign and case arrays, mark (bool) and key map (int32) per key,
    # plus the shared-layer map (int64)
    per_point = itemsize + 8 + 1 + 2 + 5 * n_dirs
    check_memory(
        points * per_point + geom.layer * n_dirs * 8,
        f"extracting a grid of shape {geom.shape}",
        hint="use thinner slabs (`chunk=`) or a coarser grid",
    )
