"""Block-wise extraction of dask arrays and of fields: blocks as tasks on the active dask scheduler.

:func:`ao4d.extract` hands dask arrays here, and :func:`ao4d.extract_field` does when given
``blocks=``. Each block of the grid becomes one task that marches the block's cells with the
slab core of :mod:`ao4d.marching.cells` (the engine :mod:`ao4d.marching.march` uses) and returns a small *block mesh*: its vertices, its simplices
(indices into its own vertices), the **global edge key** of every vertex and the global index of
every active cell. The client welds the blocks by global edge key. Nothing else is shared
between tasks, so the blocks can run anywhere:

- on the scheduler that is active, as :func:`dask.compute` picks it: the threaded scheduler in
  this process by default (nothing to configure), or a ``distributed.Client`` when one exists
  (``Client(...)`` or ``with Client(...):``), or whatever ``dask.config.set(scheduler=...)``
  names. ao4d starts no scheduler of its own.
- A block of points ``[s_k, e_k)`` along each axis is read with one more point along every axis
  (``[s_k, e_k]``, the one-cell overlap) and marches exactly the cells whose lowest corner lies
  in the block, so every cell is marched once and every simplex comes from one block. A vertex
  on a block face is found by every block that touches its edge, always from the same two
  samples with the same arithmetic (the integer grid index is formed before it is scaled), so
  the copies are bitwise equal and are merged by their key.

The result is the mesh the one-process slab path gives for the same values, array for array:
vertices and simplices in the same order (vertices in the order the slab path numbers them,
simplices in cell order), so files written from it are byte-identical. The chunking of the dask
array is free: it need not align with anything.

Workers
-------
dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which makes numpy-heavy tasks
like these 2-3x slower: start workers inside :func:`ao4d.worker_environment` (ao4d warns once
per client otherwise: :class:`ao4d.WorkerEnvironmentWarning`). Workers need ao4d installed (the same
version as the client) and, for file-backed arrays, the same paths.

Memory
------
Worker
    One task holds its block with the overlap (``prod(c_k + 1)`` values), the slab working set of
    :func:`ao4d.extract` for the block (at most about 100 MB by default; ``chunk=`` makes it
    smaller) and the block's mesh (about 48 bytes per vertex and 24-32 bytes per simplex in 4D).
    A dask-array block is assembled from up to 2^d source chunks, so count about twice the block
    while it is assembled. A worker runs as many tasks at once as it has threads. Measured
    (``bench/scale.py``): a 192^4 field in 64^4-point blocks peaked at 0.37-0.55 GiB resident
    per one-thread worker process, about 0.12 GiB of it the imports.
Client
    Only the task graph (a few kB per block) and the block meshes, never the array: the welded
    mesh plus its keys, their sort and the cell order while welding. Measured: the same peak as
    the one-process slab path, 2.6 GiB for a mesh of 3.6 M vertices and 22 M simplices (0.78 GiB
    as arrays), i.e. about 3.4 times the output mesh; planning 512^4 in 64^4 blocks (4,096
    tasks) took 4 s on the client.

References
----------
Bhaniramka, Wenger & Crawfis (2000), doi:10.1109/VISUAL.2000.885693 (the tables);
M. Rocklin, "Dask: parallel computation with blocked algorithms and task scheduling", SciPy
2015, doi:10.25080/Majora-7b98e3ed-013.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._dask import block_sizes, check_workers
from .._optional import require
from .._validate import check_finite
from ..mesh import SimplexMesh
from . import cells_device
from .cells import (
    PROGRESS_CELLS,
    Geometry,
    Job,
    Plan,
    cell_table,
    check_slab_memory,
    layers_per_slab,
    march_slabs,
    outside_value,
)

__all__ = [
    "extract_blocks",
    "extract_field_blocks",
    "field_array",
    "MAX_BLOCKS",
]

# More tasks than this is a chunking mistake (the graph alone would not fit a client).
MAX_BLOCKS = 1 << 20


# --------------------------------------------------------------------------------------------
# one block (runs on a worker)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Spec:
    """What every block task of one extraction shares (small; pickled into each task)."""

    level: float
    method: str
    inside: str
    perm: tuple[int, ...]  # engine axis e holds user axis perm[e] (as in ao4d.marching.march)
    shape: tuple[int, ...]  # global grid, user axes
    origin: tuple[float, ...]
    spacing: tuple[float, ...]
    chunk: int | None  # cell layers per slab inside a block
    # closed=True: ``shape`` is the grid padded by one outside cell per side, whose grid index
    # is one more than the user's (block offsets are in the padded grid)
    padded: bool = False
    backend: str = "auto"  # where each task marches: ao4d.marching.cells_device.get_runtime(backend)


@dataclass
class _BlockMesh:
    """A block's mesh: simplices index ``vertices``; keys and cells are global (engine order)."""

    vertices: np.ndarray  # (K, d) float64
    simplices: np.ndarray  # (M, d) int32|int64, into this block's vertices
    keys: np.ndarray  # (K,) int64 global edge key: engine point index * n_dirs + direction
    cells: np.ndarray  # (A,) int64 global engine index of each active cell's lowest corner
    counts: np.ndarray  # (A,) int64 simplices per active cell (cell order)


def _empty_block(d: int) -> _BlockMesh:
    z = np.zeros(0, dtype=np.int64)
    return _BlockMesh(np.zeros((0, d)), np.zeros((0, d), dtype=np.int64), z, z, z)


def _to_global(
    local: np.ndarray, block: tuple[int, ...], start: Sequence[int], grid: tuple[int, ...], n_dirs: int = 1
) -> np.ndarray:
    """Engine linear index (times ``n_dirs`` plus direction) in a block -> the same in the grid."""
    point, direction = np.divmod(local, n_dirs)
    index = np.unravel_index(point, block)
    flat = np.ravel_multi_index(tuple(i + s for i, s in zip(index, start)), grid)
    return flat.astype(np.int64) * n_dirs + direction


def _block_mesh(values: np.ndarray, offset: tuple[int, ...], spec: _Spec) -> _BlockMesh:
    """March one block (engine layout, with its overlap), grid index ``offset`` (user axes)."""
    d = len(spec.shape)
    values = np.ascontiguousarray(values)
    if any(n < 2 for n in values.shape):
        return _empty_block(d)
    if spec.padded:  # the data (not the infinite padding) must be finite
        inner = tuple(slice(max(1, o) - o, min(n - 1, o + m) - o) for o, m, n in zip(offset, values.shape, spec.shape))
        check_finite(values[inner], "values")
    shift = 1 if spec.padded else 0
    geom = Geometry(
        tuple(values.shape),
        spec.perm,
        np.asarray(spec.origin),
        np.asarray(spec.spacing),
        np.asarray(offset, dtype=np.int64) - shift,
    )
    table = cell_table(d, spec.method)

    def read(a: int, b: int) -> np.ndarray:  # as ao4d.extract reads its slabs
        slab = values[a:b]
        return slab if slab.dtype.kind == "f" else slab.astype(np.float64)

    layers = layers_per_slab(spec.chunk, geom, spec.method)
    runtime = cells_device.get_runtime(spec.backend)  # the worker's own device, if any
    job = Job(read, geom, spec.level, table, spec.inside, layers, check_values=not spec.padded)
    if runtime is not None and cells_device.fits(geom, layers, table):
        parts = list(cells_device.march_slabs(job, runtime=runtime))
    else:
        parts = list(march_slabs(job))
    if not parts:
        return _empty_block(d)
    n_dirs = table.n_dirs
    start = [int(offset[axis]) for axis in spec.perm]
    grid = tuple(spec.shape[axis] for axis in spec.perm)
    keys = _to_global(np.concatenate([p.keys for p in parts]), geom.shape, start, grid, n_dirs)
    cells = _to_global(np.concatenate([p.cells for p in parts]), geom.shape, start, grid)
    return _BlockMesh(
        np.concatenate([p.vertices for p in parts]),
        np.concatenate([p.simplices for p in parts]),
        keys,
        cells,
        np.concatenate([p.counts for p in parts]),
    )


def _field_block_mesh(field: Callable, axes: list[np.ndarray], offset: tuple[int, ...], spec: _Spec) -> _BlockMesh:
    """Sample ``field`` on one block's points (with overlap) and march it."""
    from ..fields import evaluate_layers

    values = evaluate_layers(field, axes, 0, len(axes[-1]))
    bad = ~np.isfinite(values)
    if bad.any():  # as ao4d.extract_field says it: name `field` and a point
        k, *rest = np.unravel_index(int(np.argmax(bad)), values.shape)  # engine axis 0 = last
        point = [float(axes[i][j]) for i, j in enumerate(rest)] + [float(axes[-1][k])]
        raise ValueError(
            f"`field` returned {int(bad.sum())} non-finite value(s) (NaN or inf) in "
            f"the block at grid index {offset}, e.g. at point "
            f"{tuple(round(x, 6) for x in point)}"
        )
    return _block_mesh(values, offset, spec)


# --------------------------------------------------------------------------------------------
# the client: plan blocks, run them, weld
# --------------------------------------------------------------------------------------------


def _block_ranges(chunks: tuple[tuple[int, ...], ...]) -> list[tuple[tuple[int, int], ...]]:
    """Per block, the point range ``[s, e]`` (overlap included) per axis; blocks without cells
    (a last chunk of one point) are left out."""
    axes = []
    for sizes in chunks:
        n = sum(sizes)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
        axes.append(
            [
                (int(s), min(int(s) + int(c) + 1, n))
                for s, c in zip(starts, sizes)
                if min(int(s) + int(c) + 1, n) - int(s) >= 2
            ]
        )
    return list(itertools.product(*axes))


def _check_blocks(ranges: list, spec: _Spec, itemsize: int, what: str) -> None:
    if len(ranges) > MAX_BLOCKS:
        raise ValueError(f"{what} would make {len(ranges):,} blocks (at most {MAX_BLOCKS:,}); use larger chunks")
    # the largest block must fit one worker's slab working set (checked before any work)
    biggest = tuple(max(r[k][1] - r[k][0] for r in ranges) for k in range(len(spec.shape)))
    engine = tuple(biggest[axis] for axis in spec.perm)
    geom = Geometry(engine, spec.perm, np.zeros(len(engine)), np.ones(len(engine)))
    layers = layers_per_slab(spec.chunk, geom, spec.method)
    check_slab_memory(geom, min(layers, engine[0] - 1), spec.method, itemsize)


def _distributed_client(tasks: list) -> Any:
    """The ``distributed.Client`` that :func:`dask.compute` would use now, or None."""
    import dask.base

    get = dask.base.get_scheduler(collections=tasks)
    client = getattr(get, "__self__", None)
    return client if type(client).__module__.startswith("distributed") else None


def _compute(tasks: list, prefix: str, bar: Any) -> list[_BlockMesh]:
    """Run the block tasks on the active scheduler; results in task order."""
    import dask

    client = _distributed_client(tasks)
    if client is not None:
        from distributed import as_completed

        check_workers(client)
        futures = client.compute(tasks)
        where = {f.key: i for i, f in enumerate(futures)}
        out: list[Any] = [None] * len(futures)
        try:
            for future, result in as_completed(futures, with_results=True):
                out[where[future.key]] = result
                future.release()  # the workers may drop their copy now
                if bar is not None:
                    bar.update()
        except BaseException:
            client.cancel(futures)
            raise
        return out

    from dask.callbacks import Callback

    def done(key, *_):
        if bar is not None and isinstance(key, str) and key.startswith(prefix):
            bar.update()

    with Callback(posttask=done):
        return list(dask.compute(*tasks))


def _weld(blocks: list[_BlockMesh], spec: _Spec, d: int) -> SimplexMesh:
    """Merge the block meshes by global edge key, in the slab path's vertex and cell order."""
    blocks = [b for b in blocks if len(b.simplices)]
    if not blocks:
        return SimplexMesh(np.zeros((0, d)), np.zeros((0, d), dtype=np.int64))
    keys = np.concatenate([b.keys for b in blocks])
    unique, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    del keys
    # The slab path numbers vertices slab by slab, in key order within a slab; an edge lying in
    # a slab-boundary layer is numbered by the slab below. Reproduce that order.
    engine = tuple(spec.shape[axis] for axis in spec.perm)
    geom = Geometry(engine, spec.perm, np.zeros(d), np.ones(d))
    table = cell_table(d, spec.method)
    plan = Plan.make(table, geom)
    layers = layers_per_slab(spec.chunk, geom, spec.method)
    point, direction = np.divmod(unique, plan.n_dirs)
    z = point // geom.layer
    slab = np.where(plan.in_plane[direction] & (z > 0), (z - 1) // layers, z // layers)
    del point, direction, z, unique
    order = np.argsort(slab, kind="stable")  # unique keys are sorted: (slab, key) order
    del slab
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    vertices = np.concatenate([b.vertices for b in blocks])[first[order]]
    del first, order
    ids = rank[inverse]  # block vertex -> output vertex
    del rank, inverse
    starts = np.cumsum([0] + [len(b.keys) for b in blocks])
    simplices = np.concatenate([ids[s + b.simplices] for s, b in zip(starts, blocks)])
    del ids
    cells = np.concatenate([np.repeat(b.cells, b.counts) for b in blocks])
    simplices = simplices[np.argsort(cells, kind="stable")]  # cell order, table rows kept
    return SimplexMesh(vertices, simplices)


def _run(func: Callable, block_args: list[tuple], spec: _Spec, progress: bool | None, token: str) -> SimplexMesh:
    """Run ``func(*args)`` for every block as a named task on the active scheduler, then weld."""
    import dask

    prefix = f"ao4d-block-{token}-"
    tasks = [dask.delayed(func)(*args, dask_key_name=f"{prefix}{n}") for n, args in enumerate(block_args)]
    n_cells = math.prod(n - 1 for n in spec.shape)
    bar = None
    if (n_cells >= PROGRESS_CELLS) if progress is None else progress:
        from .. import _progress

        bar = _progress.bar(len(tasks), "extract", unit="block")
    try:
        blocks = _compute(tasks, prefix, bar)
    finally:
        if bar is not None:
            bar.close()
    return _weld(blocks, spec, len(spec.shape))


# --------------------------------------------------------------------------------------------
# entry points
# --------------------------------------------------------------------------------------------


def extract_blocks(
    values: Any,
    level: float,
    *,
    spacing: np.ndarray,
    origin: np.ndarray,
    method: str,
    inside: str,
    chunk: int | None,
    progress: bool | None,
    closed: bool = False,
    backend: str = "auto",
) -> SimplexMesh:
    """Extract a dask array block by block on the active scheduler (see the module docstring).

    Called by :func:`ao4d.extract` with validated options; the values themselves are checked
    (finite) inside the tasks, on the workers: the client never reads them.

    Parameters
    ----------
    values : dask.array.Array, (n_0, ..., n_{d-1}), d in {2, 3, 4}
        Any chunking with known chunk sizes; real dtype.
    level : float
        Iso-value.
    spacing, origin : (d,) float64 ndarray
        As in :func:`ao4d.extract`, already per axis.
    method : {"cubes", "simplices"}
    inside : {"below", "above"}
    chunk : int or None
        Cell layers per slab inside each block (also fixes the vertex order, as in
        :func:`ao4d.extract`).
    progress : bool or None
        tqdm bar over finished blocks; by default from 2^21 cells on.
    closed : bool
        As in :func:`ao4d.extract`: the array is padded (lazily) by one infinite outside cell
        per side.
    backend : {"auto", "opencl", "numpy"}
        Where each task marches (on its worker; the same arrays everywhere).

    Returns
    -------
    SimplexMesh
        Equal, array for array, to ``ao4d.extract(values.compute(), level, ...)``.
    """
    import dask
    import dask.array as da

    if values.ndim not in (2, 3, 4):
        raise ValueError(f"`values` must be a 2D, 3D or 4D array, got shape {values.shape}")
    if any(math.isnan(c) for sizes in values.chunks for c in sizes):
        raise ValueError("`values` has unknown chunk sizes; call `values.compute_chunk_sizes()` first")
    if any(n < 2 for n in values.shape):
        raise ValueError(f"`values` needs at least 2 points along every axis, got shape {values.shape}")
    if values.dtype.kind not in "fiub":
        raise TypeError(f"`values` must hold real numbers, got dtype {values.dtype}")
    d = values.ndim
    if any(c == 0 for sizes in values.chunks for c in sizes):  # empty chunks: nothing to march
        values = values.rechunk(tuple(tuple(c for c in sizes if c) for sizes in values.chunks))
    if closed:  # as ao4d.extract reads integers: float64, here before the infinite padding
        if values.dtype.kind != "f":
            values = values.astype(np.float64)
        values = da.pad(values, 1, mode="constant", constant_values=outside_value(inside))
    spec = _Spec(
        float(level),
        method,
        inside,
        tuple(range(d)),
        tuple(int(n) for n in values.shape),
        tuple(map(float, origin)),
        tuple(map(float, spacing)),
        chunk,
        closed,
        backend,
    )
    ranges = _block_ranges(values.chunks)
    _check_blocks(ranges, spec, values.dtype.itemsize, f"`values` in chunks of {values.chunksize}")
    # one more point along every axis from the next blocks (thin slices move, not whole chunks)
    grown = da.overlap.overlap(values, depth={k: (0, 1) for k in range(d)}, boundary="none")
    pieces = grown.to_delayed(optimize_graph=False)
    args = []
    for index in np.ndindex(*pieces.shape):
        box = tuple(
            (int(sum(sizes[:i])), int(sum(sizes[:i])) + grown.chunks[k][i])
            for k, (sizes, i) in enumerate(zip(values.chunks, index))
        )
        if all(hi - lo >= 2 for lo, hi in box):
            args.append((pieces[index], tuple(lo for lo, _ in box), spec))
    return _run(_block_mesh, args, spec, progress, dask.base.tokenize(values.name, spec))


def extract_field_blocks(
    field: Callable,
    axes: list[np.ndarray],
    level: float,
    *,
    origin: np.ndarray,
    spacing: np.ndarray,
    method: str,
    inside: str,
    chunk: int | None,
    chunks: Any,
    progress: bool | None,
    backend: str = "auto",
) -> SimplexMesh:
    """Sample and extract ``field`` block by block on the active scheduler.

    Called by :func:`ao4d.extract_field` when it is given ``blocks``. Each task samples its own
    block (with the one-point overlap: the shared layers are sampled twice, about
    ``prod((c + 1) / c)`` of the points) and marches it, so no values travel between tasks and
    no process ever holds more than one block per thread. The field is pickled into every task
    (``cloudpickle``: lambdas and closures work); it must be deterministic.

    Parameters
    ----------
    field : callable
        (..., d) points -> (...) values.
    axes : list of (n_k,) float64 ndarray
        Grid coordinates per axis (:func:`ao4d.fields.grid_axes`).
    level : float
        The isovalue.
    origin, spacing : (d,) float64 ndarray
        First grid point and step per axis, as :func:`ao4d.extract_field` derives them.
    method, inside : str
        As in :func:`ao4d.extract_field`.
    chunk : int or None
        As in :func:`ao4d.extract_field`.
    chunks : int, sequence of int, dask block sizes or "auto"
        The ``blocks`` of :func:`ao4d.extract_field`: grid points per block along each axis
        (dask's ``normalize_chunks`` rules).
    progress : bool or None
        As in :func:`ao4d.extract_field`.
    backend : str
        As in :func:`ao4d.extract_field`.

    Returns
    -------
    SimplexMesh
        Equal, array for array, to ``ao4d.extract_field(field, ...)`` without ``blocks``.
    """
    dask = require("dask", "`blocks` (blocks as dask tasks)")

    d = len(axes)
    shape = tuple(len(a) for a in axes)
    spec = _Spec(
        float(level),
        method,
        inside,
        (d - 1, *range(d - 1)),
        shape,
        tuple(map(float, origin)),
        tuple(map(float, spacing)),
        chunk,
        backend=backend,
    )
    ranges = _block_ranges(block_sizes(chunks, shape, name="blocks"))
    _check_blocks(ranges, spec, 8, f"`blocks={chunks!r}` on a grid of shape {shape}")
    args = [(field, [a[lo:hi] for a, (lo, hi) in zip(axes, box)], tuple(lo for lo, _ in box), spec) for box in ranges]
    token = dask.base.tokenize(dask.base.tokenize(field), [a.tobytes() for a in axes], spec)
    return _run(_field_block_mesh, args, spec, progress, token)


def _sample_block(field: Callable, axes: list[np.ndarray], block_info: Any = None) -> np.ndarray:
    from ..fields import evaluate_layers

    (lo_hi) = block_info[None]["array-location"]
    sub = [a[lo:hi] for a, (lo, hi) in zip(axes, lo_hi)]
    return np.ascontiguousarray(np.moveaxis(evaluate_layers(field, sub, 0, len(sub[-1])), 0, -1))


def field_array(field: Callable, shape: Any, bounds: Any, *, chunks: Any = "auto") -> Any:
    """A lazy dask array of ``field`` sampled on a grid (:func:`ao4d.sample`, block by block).

    Parameters
    ----------
    field : callable
        (..., d) points -> (...) values.
    shape : int or sequence of int
        Grid points per axis (>= 2); an int needs a field of known ``dim``.
    bounds : (lo, hi)
        Grid box; point i at ``lo + (hi - lo) * i / (n - 1)``.
    chunks : int, sequence of int, dask block sizes or "auto"
        Points per block along each axis.

    Returns
    -------
    dask.array.Array
        (n_0, ..., n_{d-1}) float64; block values equal ``ao4d.sample(field, shape, bounds)``'s.
        Save it (``to_zarr``) or pass it to :func:`ao4d.extract`; for extraction alone,
        ``ao4d.extract_field(..., blocks=)`` is cheaper (no values move between tasks).

    Examples
    --------
    >>> from ao4d import fields
    >>> x = field_array(fields.hypersphere(1.0), 9, (-1.5, 1.5), chunks=4)
    >>> x.chunks[0], float(x[4, 4, 4, 4].compute())
    ((4, 4, 1), -1.0)
    """
    from ..fields import grid_axes

    da = require("dask.array", "field_array")
    if not callable(field):
        raise TypeError(f"`field` must be callable on (..., d) points, got {type(field).__name__}")
    axes = grid_axes(shape, bounds, dim=getattr(field, "dim", None))
    n = tuple(len(a) for a in axes)
    return da.map_blocks(
        _sample_block, field, axes, chunks=block_sizes(chunks, n), dtype=np.float64, meta=np.empty((0,) * len(n))
    )
