"""Marching extraction of closed, oriented simplex meshes from 2D, 3D and 4D scalar grids.

The public wrappers (:func:`extract`, :func:`extract_field`) validate and normalise their input
and hand a slab reader to one vectorised core, :func:`_march`, which has no checks of its own.

How the core works (all numpy, no Python loop over cells):

1. Per slab of grid layers, classify every cell: bit v of its case is set iff corner v is
   positive (``f >= level``; DESIGN.md). The bits are combined axis by axis (d passes over the
   slab instead of 2^d).
2. Look up the simplices of the active cells (case neither 0 nor all ones) in a *cell table*:
   rows of d edge ids, each edge given by its lower corner ``a`` and direction mask ``m``
   (``a & m == 0``). The cube table comes straight from :func:`ao4d.lut.load`; the Kuhn table
   concatenates, per cube case, the simplex-table entries of the d! Kuhn cells (with the
   orientation reversed in odd cells), so both methods share the rest of the pipeline. Kuhn
   edges include cube diagonals (any non-zero ``m``).
3. Each crossed grid edge is one vertex, welded by its global key ``point * n_dirs + dir(m)``.
   Within a slab a dense key map replaces sorting; across slabs the vertices of the shared
   layer are carried over, so memory stays bounded by the slab size.
4. Every vertex is interpolated once, from its own edge, with ``t = (level - f0) / (f1 - f0)``
   where exactly one end is positive: ``t`` lies in [0, 1] in floating point too (the
   subtraction is monotonic), and every cell sees the same point.

The cell tables are expressed in user axes; a slab axis other than axis 0 (fields are evaluated
along the last axis, Fortran arrays are read transposed) only changes the strides used to turn
corners into memory offsets, so the mesh never depends on the memory layout.

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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import as_array, as_finite_float, check_choice, check_finite, check_memory, check_positive_int
from .mesh import SimplexMesh

__all__ = ["extract", "extract_field", "METHODS"]

METHODS = ("cubes", "simplices")
_INSIDE = ("below", "above")
_KIND = {"cubes": "cube", "simplices": "simplex"}

# Dense key-map entries per slab (points x directions). 2^23 keeps the per-slab working set
# (key map, mark array, case array, values) near 100 MB in 4D.
_KEYS_PER_SLAB = 1 << 23
# Show a progress bar by default from this many cells on (about a 40^4 grid).
_PROGRESS_CELLS = 1 << 21


# --------------------------------------------------------------------------------------------
# cell tables
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _CellTable:
    """Simplices of every cube case as rows of edge ids; edge e runs from corner ``corner[e]``
    to ``corner[e] | mask[e]``."""

    dim: int
    offsets: np.ndarray  # (2^(2^d) + 1,) int64
    counts: np.ndarray  # (2^(2^d),) int64
    simplices: np.ndarray  # (M, d) uint8 edge ids
    corner: np.ndarray  # (E,) int64
    mask: np.ndarray  # (E,) int64


def _load_table(dim: int, kind: str):
    from . import lut

    return lut.load(dim, kind)


@functools.lru_cache(maxsize=None)
def _cube_table(dim: int) -> _CellTable:
    table = _load_table(dim, "cube")
    u, v = table.edges[:, 0].astype(np.int64), table.edges[:, 1].astype(np.int64)
    offsets = table.offsets.astype(np.int64)
    return _CellTable(
        dim, offsets, np.diff(offsets), table.simplices.astype(np.uint8), u & v, u ^ v
    )


@functools.lru_cache(maxsize=None)
def _kuhn_table(dim: int) -> _CellTable:
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
    return _CellTable(dim, offsets, counts, simplices.astype(np.uint8), pairs_arr[:, 0], pairs_arr[:, 1])


def _cell_table(dim: int, method: str) -> _CellTable:
    return _cube_table(dim) if method == "cubes" else _kuhn_table(dim)


# --------------------------------------------------------------------------------------------
# the core
# --------------------------------------------------------------------------------------------


@dataclass
class _Geometry:
    """Engine layout: engine axis e holds user axis ``perm[e]``; slabs run along engine axis 0."""

    shape: tuple[int, ...]  # engine grid shape
    perm: tuple[int, ...]
    origin: np.ndarray  # (d,) user axes
    spacing: np.ndarray  # (d,) user axes

    @property
    def layer(self) -> int:
        """Points per layer (engine axis 0 stride)."""
        return math.prod(self.shape[1:])


def _corner_offsets(geom: _Geometry, d: int) -> np.ndarray:
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


@dataclass
class _Plan:
    """Per-grid constants of the core: table edges as key offsets, directions, shared layers."""

    table: _CellTable
    geom: _Geometry
    offs: np.ndarray  # (2^d,) engine offset of each user corner / mask
    dirs: np.ndarray  # (n_dirs,) edge direction masks used by the table
    key_off: np.ndarray  # (E,) key offset of each table edge from its cell's lowest corner
    in_plane: np.ndarray  # (n_dirs,) direction lies inside a layer (no slab-axis bit)
    mask_bits: np.ndarray  # (2^d, d) float: user bits of each mask

    @classmethod
    def make(cls, table: _CellTable, geom: _Geometry) -> _Plan:
        d = len(geom.shape)
        offs = _corner_offsets(geom, d)
        dirs = np.unique(table.mask)
        dir_of = np.zeros(1 << d, dtype=np.int64)
        dir_of[dirs] = np.arange(len(dirs))
        key_off = offs[table.corner] * len(dirs) + dir_of[table.mask]
        in_plane = (dirs & (1 << geom.perm[0])) == 0
        mask_bits = ((np.arange(1 << d)[:, None] >> np.arange(d)) & 1).astype(np.float64)
        return cls(table, geom, offs, dirs, key_off, in_plane, mask_bits)

    @property
    def n_dirs(self) -> int:
        return len(self.dirs)


def _slab_keys(case: np.ndarray, plan: _Plan, n_keys: int) -> np.ndarray | None:
    """(M, d) edge keys of the simplices of all active cells of one slab, or None if empty.

    ``case`` holds every cell's case at its lowest corner (flat slab index).
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
    return base[:, None] + plan.key_off.astype(kt)[table.simplices[rows]]


class _Welder:
    """Numbers the crossed edges (vertices) of successive slabs, sharing the layer between two
    slabs: keys of the top layer are remembered (``carry``) and reused by the next slab."""

    def __init__(self, plan: _Plan) -> None:
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


def _march(
    read: Callable[[int, int], np.ndarray],
    geom: _Geometry,
    level: float,
    *,
    table: _CellTable,
    inside: str,
    layers_per_slab: int,
    check_values: bool,
    progress: Any,
) -> tuple[np.ndarray, np.ndarray]:
    """Extract the mesh slab by slab: (vertices (V, d) float64, simplices (S, d) int32|int64)."""
    d = len(geom.shape)
    plan = _Plan.make(table, geom)
    welder = _Welder(plan)
    verts: list[np.ndarray] = []
    simps: list[np.ndarray] = []
    n0 = geom.shape[0]
    z0 = 0
    while z0 < n0 - 1:
        z1 = min(z0 + layers_per_slab, n0 - 1)
        slab = read(z0, z1 + 1)
        if check_values:
            check_finite(slab, "values")
        case = _cases(slab >= level if inside == "below" else slab <= level, geom.perm).ravel()
        n_keys = slab.size * plan.n_dirs
        simplices, new_keys = welder.number(_slab_keys(case, plan, n_keys), n_keys, z1 - z0)
        if simplices is not None:
            simps.append(simplices)
            lin, dir_ = np.divmod(new_keys, plan.n_dirs)
            verts.append(_interpolate(slab, lin, plan.dirs[dir_], z0, level, plan))
        if progress is not None:
            progress.update(z1 - z0)
        z0 = z1
    if not simps:
        return np.zeros((0, d)), np.zeros((0, d), dtype=np.int64)
    vertices = np.concatenate(verts)
    del verts
    # kept int32 when it fits: SimplexMesh converts to int64 in its own (unavoidable) copy
    return vertices, np.concatenate(simps)


def _interpolate(
    slab: np.ndarray, lin: np.ndarray, masks: np.ndarray, z0: int, level: float, plan: _Plan
) -> np.ndarray:
    """Positions (K, d) of the crossings on edges (slab point ``lin``, direction ``masks``)."""
    geom = plan.geom
    flat = slab.reshape(-1)
    f0 = flat[lin].astype(np.float64)
    f1 = flat[lin + plan.offs[masks]].astype(np.float64)
    # exactly one end is positive, so f1 != f0 and fl(level - f0) lies between 0 and fl(f1 - f0)
    t = np.clip((level - f0) / (f1 - f0), 0.0, 1.0)
    eidx = np.unravel_index(lin, slab.shape)
    idx = np.empty((len(lin), len(geom.shape)))
    for e, axis in enumerate(geom.perm):
        idx[:, axis] = eidx[e] + (z0 if e == 0 else 0)
    idx += t[:, None] * plan.mask_bits[masks]
    return geom.origin + geom.spacing * idx


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------


def _layers_per_slab(chunk: Any, geom: _Geometry, method: str) -> int:
    n_dirs = len(np.unique(_cell_table(len(geom.shape), method).mask))
    if chunk is None:
        return max(1, _KEYS_PER_SLAB // max(1, geom.layer * n_dirs) - 1)
    return check_positive_int(chunk, "chunk")


def _check_slab_memory(geom: _Geometry, layers: int, method: str, itemsize: int) -> None:
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


def _progress_bar(progress: bool | None, n_cells: int, n_layers: int) -> Any:
    if progress is None:
        progress = n_cells >= _PROGRESS_CELLS
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=n_layers, desc="extract", unit="layer", leave=False)


def _per_axis(value: Any, name: str, d: int, *, positive: bool) -> np.ndarray:
    arr = as_array(value, name, ndim=(0, 1), dtype=np.float64, finite=True)
    if arr.ndim == 1 and arr.shape[0] != d:
        raise ValueError(f"`{name}` must be a scalar or have {d} entries, got {arr.shape[0]}")
    if positive and (arr <= 0).any():
        raise ValueError(f"`{name}` must be > 0, got {value!r}")
    return np.broadcast_to(arr, (d,)).astype(np.float64)


def _run(
    read: Callable[[int, int], np.ndarray],
    geom: _Geometry,
    level: float,
    method: str,
    inside: str,
    chunk: int | None,
    progress: bool | None,
    check_values: bool,
    itemsize: int,
) -> SimplexMesh:
    """Check the slab memory, then march with a progress bar; wrap the result in a mesh."""
    layers = _layers_per_slab(chunk, geom, method)
    _check_slab_memory(geom, min(layers, geom.shape[0] - 1), method, itemsize)
    table = _cell_table(len(geom.shape), method)
    bar = _progress_bar(progress, math.prod(n - 1 for n in geom.shape), geom.shape[0] - 1)
    try:
        vertices, simplices = _march(
            read,
            geom,
            level,
            table=table,
            inside=inside,
            layers_per_slab=layers,
            check_values=check_values,
            progress=bar,
        )
    finally:
        if bar is not None:
            bar.close()
    return SimplexMesh(vertices, simplices)


def extract(
    values: Any,
    level: float = 0.0,
    *,
    spacing: Any = 1.0,
    origin: Any = 0.0,
    method: str = "cubes",
    inside: str = "below",
    chunk: int | None = None,
    progress: bool | None = None,
) -> SimplexMesh:
    """Extract the closed, outward-oriented level set of a 2D, 3D or 4D grid of values.

    Parameters
    ----------
    values : (n_0, ..., n_{d-1}) array_like, d in {2, 3, 4}
        Samples; ``values[i]`` sits at ``origin + spacing * i``. Any real dtype, C or Fortran
        order, or a ``np.memmap`` (``np.load(path, mmap_mode="r")``): large arrays are read slab
        by slab and never copied whole. Every axis needs at least 2 points.
    level : float
        Iso-value.
    spacing : float or (d,) array_like
        Grid step per axis (> 0).
    origin : float or (d,) array_like
        Position of ``values[0, ..., 0]``.
    method : {"cubes", "simplices"}
        ``"cubes"``: the Bhaniramka d-cube table (fewest simplices). ``"simplices"``: split each
        cube into d! Kuhn simplices and use the simplex table (more, better-shaped simplices).
    inside : {"below", "above"}
        Which side is the solid: ``"below"`` means ``{f < level}`` (signed distances);
        ``"above"`` means ``{f > level}`` (bright objects, CT data).
    chunk : int, optional
        Cell layers per slab along the slab axis; by default sized to bound memory near 100 MB.
    progress : bool, optional
        Show a tqdm bar; by default only for grids of 2^21 cells or more.

    Returns
    -------
    SimplexMesh
        Vertices (V, d) float64 on the crossed grid edges, one per edge, and simplices (S, d)
        int64 whose normals point to the positive side (out of the solid). The mesh is closed
        whenever the level set does not touch the grid border; a level outside the data range
        gives an empty mesh (0 vertices, 0 simplices). Simplices of zero measure occur where
        values equal the level exactly; they keep the mesh closed.

    Raises
    ------
    ValueError
        ``values`` not 2D/3D/4D, an axis shorter than 2, NaN/inf values, bad ``level``,
        ``spacing``, ``origin``, ``method`` or ``inside``.
    MemoryError
        When even one slab would not fit (absurd shapes).

    References
    ----------
    Bhaniramka, Wenger & Crawfis (2000), doi:10.1109/VISUAL.2000.885693; Lorensen & Cline (1987),
    doi:10.1145/37402.37422.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(-1.2, 1.2, 13)
    >>> r = np.sqrt(sum(np.square(g) for g in np.meshgrid(x, x, x, x, indexing="ij")))
    >>> mesh = extract(r, 1.0, spacing=x[1] - x[0], origin=x[0])
    >>> mesh.check().ok, mesh.dim
    (True, 4)
    """
    arr = values if isinstance(values, np.ndarray) else as_array(values, "values")
    if arr.ndim not in (2, 3, 4):
        raise ValueError(f"`values` must be a 2D, 3D or 4D array, got shape {arr.shape}")
    if any(n < 2 for n in arr.shape):
        raise ValueError(f"`values` needs at least 2 points along every axis, got shape {arr.shape}")
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"`values` must hold real numbers, got dtype {arr.dtype}")
    d = arr.ndim
    level = as_finite_float(level, "level")
    spacing = _per_axis(spacing, "spacing", d, positive=True)
    origin = _per_axis(origin, "origin", d, positive=False)
    check_choice(method, "method", METHODS)
    check_choice(inside, "inside", _INSIDE)
    if progress is not None and not isinstance(progress, bool):
        raise TypeError(f"`progress` must be True, False or None, got {progress!r}")
    # read Fortran arrays transposed so that every slab is contiguous (integers: per slab)
    if arr.flags.f_contiguous and not arr.flags.c_contiguous:
        engine, perm = arr.T, tuple(range(d))[::-1]
    else:
        engine, perm = arr, tuple(range(d))
    geom = _Geometry(tuple(engine.shape), perm, origin, spacing)
    layers = _layers_per_slab(chunk, geom, method)
    _check_slab_memory(geom, min(layers, geom.shape[0] - 1), method, arr.dtype.itemsize)
    on_disk = isinstance(arr, np.memmap)
    if not on_disk:
        check_finite(arr, "values")  # in memory: one cheap pass before any work

    def read(a: int, b: int) -> np.ndarray:
        slab = np.ascontiguousarray(engine[a:b])
        return slab if slab.dtype.kind == "f" else slab.astype(np.float64)

    return _run(read, geom, level, method, inside, chunk, progress, on_disk, arr.dtype.itemsize)


def extract_field(
    field: Callable,
    shape: Any,
    bounds: Any,
    level: float = 0.0,
    *,
    method: str = "cubes",
    inside: str = "below",
    chunk: int | None = None,
    progress: bool | None = None,
) -> SimplexMesh:
    """Sample ``field`` and extract its level set slab by slab, never holding the whole grid.

    Parameters
    ----------
    field : callable
        Maps (..., d) points to (...) values (see :mod:`ao4d.fields`).
    shape : int or sequence of int
        Grid points per axis (>= 2 each); an int needs a field of known ``dim``.
    bounds : (lo, hi)
        Grid box, scalars or (d,) sequences; point i at ``lo + (hi - lo) * i / (n - 1)``.
    level : float
        Iso-value.
    method : {"cubes", "simplices"}
        As in :func:`extract`.
    inside : {"below", "above"}
        As in :func:`extract`.
    chunk : int, optional
        Cell layers per slab along the last axis (slabs share one layer of grid points, whose
        vertices are welded by global edge key). By default about 100 MB of working memory.
    progress : bool, optional
        tqdm bar; by default from 2^21 cells on.

    Returns
    -------
    SimplexMesh
        The same mesh as ``extract(sample(field, shape, bounds), level, ...)`` up to vertex
        and simplex order.

    Examples
    --------
    >>> from ao4d import fields
    >>> mesh = extract_field(fields.hypersphere(1.0), 16, (-1.25, 1.25))
    >>> mesh.check().ok
    True
    """
    from .fields import evaluate_layers, grid_axes

    if not callable(field):
        raise TypeError(f"`field` must be callable on (..., d) points, got {type(field).__name__}")
    axes = grid_axes(shape, bounds, dim=getattr(field, "dim", None))
    d = len(axes)
    if d not in (2, 3, 4):
        raise ValueError(f"`shape` must describe a 2D, 3D or 4D grid, got {len(axes)} axes")
    level = as_finite_float(level, "level")
    check_choice(method, "method", METHODS)
    check_choice(inside, "inside", _INSIDE)
    n = [len(a) for a in axes]
    lo = np.array([a[0] for a in axes])
    spacing = np.array([(a[-1] - a[0]) / (len(a) - 1) for a in axes])
    # engine axis 0 is the user's last axis, so each evaluated layer is one engine layer
    geom = _Geometry((n[-1], *n[:-1]), (d - 1, *range(d - 1)), lo, spacing)
    last: dict[int, np.ndarray] = {}

    def read(a: int, b: int) -> np.ndarray:
        # reuse the previous slab's top layer instead of evaluating it twice
        if a in last:
            slab = np.concatenate([last.pop(a)[None], evaluate_layers(field, axes, a + 1, b)])
        else:
            slab = evaluate_layers(field, axes, a, b)
        last.clear()
        last[b - 1] = slab[-1].copy()
        return slab

    return _run(read, geom, level, method, inside, chunk, progress, True, 8)
