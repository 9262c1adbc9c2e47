"""Marching extraction of closed, oriented simplex meshes from 2D, 3D and 4D scalar grids.

The public wrappers (:func:`extract`, :func:`extract_field`) validate and normalise their input
and hand a slab reader to one core with no checks of its own: :func:`ao4d.marching.cells_device.march`
on the OpenCL device where one works, else the vectorised numpy engine
:func:`ao4d.marching.cells.march`; both give the same arrays. Dask arrays and ``blocks=`` go to
:mod:`ao4d.marching.blockwise`, which runs the same cores on blocks as dask tasks.

How the core works, and the papers it follows, are described in :mod:`ao4d.marching.cells`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from .._dask import is_dask_array
from .._validate import (
    as_array,
    as_real,
    as_vector,
    check_bool,
    check_choice,
    check_finite,
    check_grid_lengths,
    check_positive_int,
)
from ..mesh import SimplexMesh
from ..opencl.cl import BACKENDS
from ..topology import GRID_EDGE_KEY
from . import cells_device
from .cells import PROGRESS_CELLS as _PROGRESS_CELLS
from .cells import Geometry as _Geometry
from .cells import Job as _Job
from .cells import cell_table as _cell_table
from .cells import check_slab_memory as _check_slab_memory
from .cells import layers_per_slab as _layers_per_slab
from .cells import march as _march
from .cells import outside_value

__all__ = ["extract", "extract_field", "METHODS"]

METHODS = ("cubes", "simplices")
_INSIDE = ("below", "above")
_KIND = {"cubes": "cube", "simplices": "simplex"}


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------


def _progress_bar(progress: bool | None, n_cells: int, n_layers: int) -> Any:
    if progress is None:
        progress = n_cells >= _PROGRESS_CELLS
    if not progress:
        return None
    from .. import _progress

    return _progress.bar(n_layers, "extract", unit="layer")


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
    backend: str = "auto",
    reread: bool = False,
    precheck: Callable[[], None] | None = None,
) -> SimplexMesh:
    """Check the slab memory, then march with a progress bar (on the OpenCL device when one
    works, :mod:`ao4d.marching.cells_device`; the same arrays as the numpy engine); wrap the result.

    ``precheck`` checks the whole input before any work, unless the device marches it as one
    slab: its first kernel reads every value and flags NaN and infinities (``check_values``)."""
    runtime = cells_device.get_runtime(backend)
    layers = _layers_per_slab(chunk, geom, method)
    _check_slab_memory(geom, min(layers, geom.shape[0] - 1), method, itemsize)
    table = _cell_table(len(geom.shape), method)
    engine: Callable[..., tuple[np.ndarray, np.ndarray]] = _march
    extra: dict[str, Any] = {}
    if runtime is not None and cells_device.fits(geom, layers, table):
        # device slabs grow past the numpy engine's unless the user chose them (chunk=)
        engine, extra = cells_device.march, {"runtime": runtime, "reread": reread, "grow": chunk is None}
        if precheck is not None and cells_device.in_one_slab(geom, layers, table, chunk is None):
            precheck, check_values = None, True
    else:  # slabs of fields sampled on the device, as host arrays (ao4d.marching.fields_device)
        read = getattr(read, "host", read)
    if precheck is not None:
        precheck()
    bar = _progress_bar(progress, math.prod(n - 1 for n in geom.shape), geom.shape[0] - 1)
    try:
        vertices, simplices = engine(_Job(read, geom, level, table, inside, layers, check_values, bar), **extra)
    finally:
        if bar is not None:
            bar.close()
    # the engines' own fresh arrays: taken without the constructor's copies and checks
    return SimplexMesh._adopt(
        np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(simplices, dtype=np.int64)
    )


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
    closed: bool = False,
    affine: Any = None,
    backend: str = "auto",
) -> SimplexMesh:
    """Extract the closed, outward-oriented level set of a 2D, 3D or 4D grid of values.

    Parameters
    ----------
    values : (n_0, ..., n_{d-1}) array_like, d in {2, 3, 4}
        Samples; ``values[i]`` sits at ``origin + spacing * i``. Any real dtype, C or Fortran
        order, or a ``np.memmap`` (``np.load(path, mmap_mode="r")``): large arrays are read slab
        by slab and never copied whole. A dask array (any chunking) is extracted block by block,
        each block a task on the active dask scheduler (threads by default, a
        ``distributed.Client`` when one exists), and gives the same mesh array for array; see
        :mod:`ao4d.marching.blockwise` for the memory a worker and the client need. Every axis needs at
        least 2 points.
    level : float
        Iso-value.
    spacing : float or (d,) array_like
        Grid step per axis (> 0); a ``None`` entry keeps that axis at the default step 1
        (``spacing=(None, None, None, 0.5)`` sets only w, as in :func:`ao4d.io.grids.read_grid`).
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
    closed : bool
        Close the mesh where the solid touches the grid's edge: the grid is taken as padded by
        one cell of an outside value on every side (nothing is copied), with the cap at the
        grid's boundary faces, so the result is the boundary of the solid clipped to the grid's
        box. Vertices inside the grid are those of ``closed=False``, bit for bit.
    affine : (d + 1, d + 1) or (d, d + 1) array_like, optional
        Place vertices at ``affine @ (i_0, ..., i_{d-1}, 1)`` (grid index to coordinates, e.g. a
        NIfTI affine: :attr:`ao4d.io.grids.Grid.affine`) instead of ``origin + spacing * i``
        (leave ``spacing`` and ``origin`` at their defaults). Its linear part must be invertible;
        an affine map keeps the mesh closed, and a negative determinant reverses the simplices
        so that the normals still point out of the solid.
    backend : {"auto", "opencl", "numpy"}
        Where the marching runs: ``"auto"`` on the OpenCL device :mod:`ao4d.opencl.cl` chooses
        (``AO4D_DEVICE``) and in numpy where none works; ``"opencl"`` requires a device.
        Every backend gives the same arrays (:mod:`ao4d.marching.cells_device`).

    Returns
    -------
    SimplexMesh
        Vertices (V, d) float64 on the crossed grid edges, one per edge, and simplices (S, d)
        int64 whose normals point to the positive side (out of the solid). The mesh is closed
        whenever the level set does not touch the grid border (always with ``closed=True``); a
        level outside the data range gives an empty mesh (0 vertices, 0 simplices). Simplices of
        zero measure occur where values equal the level exactly; they keep the mesh closed.
        When the solid touches the grid's edge (``closed=False``), ``mesh.check()`` says so and
        :func:`ao4d.ambient_occlusion` warns (:class:`ao4d.ao.OpenMeshWarning`).

    Raises
    ------
    ValueError
        ``values`` not 2D/3D/4D, an axis shorter than 2, NaN/inf values, bad ``level``,
        ``spacing``, ``origin``, ``method``, ``inside`` or ``affine``.
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
    closed = check_bool(closed, "closed")
    if isinstance(values, np.ma.MaskedArray):
        masked = int(np.ma.count_masked(values))
        if masked:
            raise ValueError(
                f"`values` is a masked array with {masked} masked entries; extraction "
                "needs a value at every grid point: fill them with a value on the "
                "side they belong to (values.filled(...))"
            )
        values = values.data  # nothing masked: the plain array (NaN in it is still refused)
    if isinstance(spacing, (list, tuple)) and any(step is None for step in spacing):
        spacing = [1.0 if step is None else step for step in spacing]  # None keeps the default
    if affine is not None:
        d = (
            getattr(values, "ndim", None)
            if is_dask_array(values) or isinstance(values, np.ndarray)
            else as_array(values, "values").ndim
        )
        matrix, shift = _affine(affine, d, spacing, origin)
        corners = np.abs(matrix) @ (np.asarray(values.shape, dtype=np.float64) + 1.0)  # padding included
        check_grid_lengths(np.abs(matrix).max(axis=0), np.abs(shift) + corners, "affine")
        mesh = extract(
            values, level, method=method, inside=inside, chunk=chunk, progress=progress, closed=closed, backend=backend
        )
        hint = mesh.cache.get(GRID_EDGE_KEY)
        mesh = mesh.transformed(matrix, shift)
        if hint is not None:
            mesh.cache[GRID_EDGE_KEY] = hint
        return mesh
    if is_dask_array(values):  # blocks as tasks on the active dask scheduler
        return _extract_dask(values, level, spacing, origin, method, inside, chunk, progress, closed, backend)
    arr = _check_grid(values if isinstance(values, np.ndarray) else as_array(values, "values"))
    d = arr.ndim
    level = as_real(level, "level")
    spacing = as_vector(spacing, "spacing", d, positive=True)
    origin = as_vector(origin, "origin", d)
    _check_lengths(spacing, origin, arr.shape, "spacing")
    check_choice(method, "method", METHODS)
    check_choice(inside, "inside", _INSIDE)
    check_choice(backend, "backend", BACKENDS)
    if progress is not None and not isinstance(progress, bool):
        raise TypeError(f"`progress` must be True, False or None, got {progress!r}")
    # read Fortran arrays transposed so that every slab is contiguous (integers: per slab)
    if arr.flags.f_contiguous and not arr.flags.c_contiguous:
        engine, perm = arr.T, tuple(range(d))[::-1]
    else:
        engine, perm = arr, tuple(range(d))
    geom = _Geometry(tuple(engine.shape), perm, origin, spacing)
    if closed:
        geom = _Geometry(tuple(n + 2 for n in engine.shape), perm, origin, spacing, np.full(d, -1, dtype=np.int64))
    layers = _layers_per_slab(chunk, geom, method)
    _check_slab_memory(geom, min(layers, geom.shape[0] - 1), method, 8 if closed else arr.dtype.itemsize)
    on_disk = isinstance(arr, np.memmap)
    # in memory: one pass before any work (on the device, when it marches the grid in one slab,
    # its first kernel's instead)
    precheck = None
    if not on_disk and closed:
        check_finite(arr, "values")  # the padding of closed=True holds infinities: check before it
    elif not on_disk:
        precheck = functools.partial(check_finite, arr, "values")

    def read(a: int, b: int) -> np.ndarray:
        slab = np.ascontiguousarray(engine[a:b])
        if on_disk and closed:
            check_finite(slab, "values")  # the padded slabs hold infinities: check before
        # integers stay as they are (compared exactly, widened where interpolated), except in
        # the padding of closed=True, which holds infinities
        native = "f" if closed else "fiu"
        return slab if slab.dtype.kind in native else slab.astype(np.float64)

    if closed:
        read = _padded_reader(read, engine.shape, outside_value(inside))
    mesh = _run(
        read,
        geom,
        level,
        method,
        inside,
        chunk,
        progress,
        on_disk and not closed,
        arr.dtype.itemsize,
        backend,
        reread=not on_disk,
        precheck=precheck,
    )
    if not closed:
        _mark_grid_edge(mesh, geom)
    return _checked(
        mesh,
        level,
        inside,
        lambda: (float(np.min(arr)), float(np.max(arr))),
        lambda: outside_value(inside) if closed else float(arr[(0,) * d]),
        _proved(mesh, geom, method),
    )


def _check_lengths(spacing: np.ndarray, origin: np.ndarray, shape: Any, name: str) -> None:
    """:func:`ao4d._validate.check_grid_lengths` for a grid ``origin + spacing * i`` of ``shape``
    (with one more cell on every side: ``closed=True`` pads the grid)."""
    n = np.asarray(shape, dtype=np.float64)
    extent = np.maximum(np.abs(origin - spacing), np.abs(origin + spacing * n))
    check_grid_lengths(spacing, extent, name)


def _check_grid(arr: np.ndarray) -> np.ndarray:
    """``arr`` if it is a 2D, 3D or 4D grid of real numbers with 2 points or more along every
    axis, else an error naming ``values``."""
    if arr.ndim not in (2, 3, 4):
        raise ValueError(f"`values` must be a 2D, 3D or 4D array, got shape {arr.shape}")
    if any(n < 2 for n in arr.shape):
        raise ValueError(f"`values` needs at least 2 points along every axis, got shape {arr.shape}")
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"`values` must hold real numbers, got dtype {arr.dtype}")
    return arr


def _field_axes(field: Any, shape: Any, bounds: Any) -> list[np.ndarray]:
    """The grid axes of ``field`` sampled on ``shape`` points in ``bounds`` (2D to 4D), else an
    error naming ``field`` or ``shape``."""
    from ..fields import grid_axes

    if not callable(field):
        raise TypeError(f"`field` must be callable on (..., d) points, got {type(field).__name__}")
    axes = grid_axes(shape, bounds, dim=getattr(field, "dim", None))
    if len(axes) not in (2, 3, 4):
        raise ValueError(f"`shape` must describe a 2D, 3D or 4D grid, got {len(axes)} axes")
    return axes


def _padded_reader(
    read: Callable[[int, int], np.ndarray], shape: tuple[int, ...], fill: float
) -> Callable[[int, int], np.ndarray]:
    """Serve slabs of the grid padded by one layer of ``fill`` on every side (engine axes)."""
    n0 = shape[0]

    def padded(a: int, b: int) -> np.ndarray:
        lo, hi = max(a - 1, 0), min(b - 1, n0)  # rows of the unpadded grid
        core = read(lo, hi) if hi > lo else None
        dtype = np.float64 if core is None else core.dtype
        out = np.full((b - a, *(n + 2 for n in shape[1:])), fill, dtype=dtype)
        if core is not None:
            out[(slice(lo + 1 - a, hi + 1 - a),) + (slice(1, -1),) * (len(shape) - 1)] = core
        return out

    return padded


def _mark_grid_edge(mesh: SimplexMesh, geom: _Geometry) -> None:
    """Record on ``mesh`` (its cache: dropped when the mesh changes) that the level set reaches
    the grid's boundary, where the mesh is cut open, and what closes it.

    A vertex on an edge inside a boundary face of the grid has that coordinate exactly equal to
    the face's (the integer index is formed before scaling), so comparing is exact and cheap.
    """
    if mesh.n_simplices == 0 or _clear_of_grid_edge(mesh, geom):
        return
    first, last = _grid_box(geom)
    v = mesh.vertices
    on_edge = ((v == first) | (v == last)).any(axis=1)
    if on_edge.any():
        mesh.cache[GRID_EDGE_KEY] = (
            f"{int(on_edge.sum()):,} vertices lie on the grid's boundary, where the solid touches "
            "the grid's edge and the mesh is cut open; extract with closed=True (command line: "
            "--closed) to close it there"
        )


def _grid_box(geom: _Geometry) -> tuple[np.ndarray, np.ndarray]:
    """The first and last grid points' coordinates (user axes)."""
    shape = np.empty(len(geom.shape), dtype=np.int64)
    shape[list(geom.perm)] = geom.shape  # user axes
    first = geom.origin + geom.spacing * np.zeros(len(shape))
    last = geom.origin + geom.spacing * (shape - 1).astype(np.float64)
    return first, last


def _clear_of_grid_edge(mesh: SimplexMesh, geom: _Geometry) -> bool:
    """Whether no vertex of ``mesh`` (marched on ``geom``) lies on the grid's boundary.

    Every vertex lies in [first, last] and one on the boundary has that coordinate exactly
    equal to the boundary's (the integer index is formed before scaling): one lies there only
    where a coordinate's extreme reaches it (a column's min and max: 1 ms at 200,000 vertices,
    where testing every vertex takes 9, as does min(axis=0) across the rows).
    """
    first, last = _grid_box(geom)
    v = mesh.vertices
    return all(v[:, j].min() > first[j] and v[:, j].max() < last[j] for j in range(v.shape[1]))


def _proved(mesh: SimplexMesh, geom: _Geometry, method: str) -> tuple[str, ...]:
    """What the table guarantees for ``mesh``, marched by ``method`` on the one grid ``geom``:
    closed and oriented as well (topology.MARCHING_CLOSED_PROVED) for cubes clear of the grid's
    edge, where no face can be left open; otherwise the vertex stars only."""
    from ..topology import MARCHING_CLOSED_PROVED, MARCHING_PROVED

    if method == "cubes" and mesh.n_simplices and _clear_of_grid_edge(mesh, geom):
        return MARCHING_CLOSED_PROVED
    return MARCHING_PROVED


def _affine(affine: Any, d: int, spacing: Any, origin: Any) -> tuple[np.ndarray, np.ndarray]:
    """(linear part (d, d), translation (d,)) of a grid-index-to-coordinates affine."""
    m = as_array(affine, "affine", ndim=2, dtype=np.float64, finite=True)
    if m.shape not in ((d + 1, d + 1), (d, d + 1)):
        raise ValueError(
            f"`affine` must have shape ({d + 1}, {d + 1}) or ({d}, {d + 1}) for {d}D values, got {m.shape}"
        )
    if m.shape[0] == d + 1 and not np.array_equal(m[d], np.eye(d + 1)[d]):
        raise ValueError(f"`affine`'s last row must be (0, ..., 0, 1), got {m[d].tolist()}")
    if np.any(np.asarray(spacing, dtype=float) != 1.0) or np.any(np.asarray(origin, dtype=float) != 0.0):
        raise ValueError(
            "give either `affine` or `spacing`/`origin`, not both (the affine holds the spacing and origin)"
        )
    # relative, not an absolute determinant: data stored in metres (steps of 1e-3) is fine
    # the columns (the grid's axes) scaled to unit size first: different steps per axis, however
    # small or large, are fine; axes (nearly) parallel are not
    linear = m[:d, :d]
    top = np.abs(linear).max(axis=0)
    cond = math.inf
    if (top > 0).all():
        axes = linear / top
        cond = float(np.linalg.cond(axes / np.linalg.norm(axes, axis=0)))
    if not cond < 1e12:
        raise ValueError(
            f"`affine`'s linear part must be invertible (condition number below 1e12, "
            f"got {cond:.3g}), got {linear.tolist()}"
        )
    return m[:d, :d], m[:d, d]


def _extract_dask(values, level, spacing, origin, method, inside, chunk, progress, closed, backend) -> SimplexMesh:
    """Validate the options as :func:`extract` does, then run the blocks (ao4d.marching.blockwise)."""
    from .blockwise import extract_blocks

    d = values.ndim if values.ndim in (2, 3, 4) else 1  # the shape error comes from blockwise
    if progress is not None and not isinstance(progress, bool):
        raise TypeError(f"`progress` must be True, False or None, got {progress!r}")
    level = as_real(level, "level")
    spacing = as_vector(spacing, "spacing", d, positive=True)
    origin = as_vector(origin, "origin", d)
    if d == values.ndim:
        _check_lengths(spacing, origin, values.shape, "spacing")
    inside = check_choice(inside, "inside", _INSIDE)
    backend = check_choice(backend, "backend", BACKENDS)
    mesh = extract_blocks(
        values,
        level,
        spacing=spacing,
        origin=origin,
        method=check_choice(method, "method", METHODS),
        inside=inside,
        chunk=None if chunk is None else check_positive_int(chunk, "chunk"),
        progress=progress,
        closed=closed,
        backend=backend,
    )
    if not closed:
        _mark_grid_edge(mesh, _Geometry(tuple(int(n) for n in values.shape), tuple(range(d)), origin, spacing))
    return _checked(mesh, level, inside, None, (lambda: outside_value(inside)) if closed else None)


def extract_field(
    field: Callable,
    shape: Any,
    bounds: Any,
    level: float = 0.0,
    *,
    method: str = "cubes",
    inside: str = "below",
    chunk: int | None = None,
    blocks: Any = None,
    progress: bool | None = None,
    backend: str = "auto",
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
    blocks : int, sequence of int, dask chunk sizes or "auto", optional
        Sample and extract block by block instead, each block (this many grid points per axis,
        dask's ``chunks`` rules) a task on the active dask scheduler (threads, or a
        ``distributed.Client`` when one exists; see :mod:`ao4d.marching.blockwise` for worker and client
        memory). Same result.
    progress : bool, optional
        tqdm bar; by default from 2^21 cells on.
    backend : {"auto", "opencl", "numpy"}
        As in :func:`extract`.

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
    from ..fields import evaluate_layers

    axes = _field_axes(field, shape, bounds)
    d = len(axes)
    level = as_real(level, "level")
    check_choice(method, "method", METHODS)
    check_choice(inside, "inside", _INSIDE)
    check_choice(backend, "backend", BACKENDS)
    n = [len(a) for a in axes]
    lo = np.array([a[0] for a in axes])
    spacing = np.array([(a[-1] - a[0]) / (len(a) - 1) for a in axes])
    _check_lengths(spacing, lo, n, "bounds")
    if blocks is not None:
        from .blockwise import extract_field_blocks

        if progress is not None and not isinstance(progress, bool):
            raise TypeError(f"`progress` must be True, False or None, got {progress!r}")
        return _checked(
            extract_field_blocks(
                field,
                axes,
                level,
                origin=lo,
                spacing=spacing,
                method=method,
                inside=inside,
                chunk=None if chunk is None else check_positive_int(chunk, "chunk"),
                chunks=blocks,
                progress=progress,
                backend=backend,
            ),
            level,
            inside,
            None,
            None,
        )
    # engine axis 0 is the user's last axis, so each evaluated layer is one engine layer
    geom = _Geometry((n[-1], *n[:-1]), (d - 1, *range(d - 1)), lo, spacing)
    last: dict[int, np.ndarray] = {}
    first: list[float] = []

    def read(a: int, b: int) -> np.ndarray:
        # reuse the previous slab's top layer instead of evaluating it twice
        if a in last:
            slab = np.concatenate([last.pop(a)[None], evaluate_layers(field, axes, a + 1, b)])
        else:
            slab = evaluate_layers(field, axes, a, b)
        last.clear()
        last[b - 1] = slab[-1].copy()
        _check_field_values(slab, field, axes, a)
        if a == 0:
            first.append(float(slab[(0,) * slab.ndim]))  # the value at the grid's first corner
        return slab

    from . import fields_device  # the shape library's fields: sampled on the device

    read = fields_device.reader(
        field, axes, backend, read, first=first, check=lambda slab, a: _check_field_values(slab, field, axes, a)
    )
    mesh = _run(read, geom, level, method, inside, chunk, progress, False, 8, backend)
    return _checked(mesh, level, inside, None, lambda: first[0], _proved(mesh, geom, method))


def _check_field_values(slab: np.ndarray, field: Callable, axes: list, first: int) -> None:
    """The field's own values must be finite: name `field` and a point where they are not."""
    bad = ~np.isfinite(slab)
    if bad.any():
        k, *rest = np.unravel_index(int(np.argmax(bad)), slab.shape)  # engine axis 0 = last axis
        point = [float(axes[i][j]) for i, j in enumerate(rest)] + [float(axes[-1][first + k])]
        raise ValueError(
            f"`field` returned {int(bad.sum())} non-finite value(s) (NaN or inf) in grid layers "
            f"{first}..{first + slab.shape[0] - 1}, e.g. at point {tuple(round(x, 6) for x in point)}"
        )


def _in_solid(value: float, level: float, inside: str) -> bool:
    return value < level if inside == "below" else value > level


def _empty_reason(level: float, inside: str, lo: float, hi: float) -> str:
    """Why a grid with values in [lo, hi] gives no surface at ``level``."""
    if lo == hi:
        return f"the grid is constant (every value is {lo:g}): no level crosses it"
    if level < lo or level > hi:
        return f"`level` {level:g} is outside the data range [{lo:g}, {hi:g}]"
    # the level is the range's end on the solid's side: the solid (strict inequality) is empty
    end, side, sign = ("minimum", "below", "<") if inside == "below" else ("maximum", "above", ">")
    return (
        f"`level` {level:g} equals the data's {end}: the solid is f {sign} level and no value "
        f"lies {side} it (values equal to the level count as outside); choose a level strictly "
        f"between {lo:g} and {hi:g}, e.g. {(lo + hi) / 2:g}"
    )


class EmptyMeshWarning(UserWarning):
    """The extracted level set is empty (the level misses the data)."""


def _checked(
    mesh: SimplexMesh,
    level: float,
    inside: str,
    value_range: Callable | None,
    corner: Callable[[], float] | None,
    proved: tuple[str, ...] | None = None,
) -> SimplexMesh:
    """Warn about results that are almost always mistakes: empty, or closed and inside out.

    Cheap in the usual case: a closed result leaves the whole (connected) grid boundary on one
    side, so it is inside out exactly when the grid's first corner lies in the solid; only then
    are the volume and the closedness computed (``corner=None``: always).
    """
    import warnings

    from ..mesh import InsideOutWarning
    from ..topology import MARCHING_PROVED

    # what the table guarantees (``proved``, else the vertex stars): check() need not test it
    mesh._mark_constructed(MARCHING_PROVED if proved is None else proved)
    if mesh.n_simplices == 0:
        if value_range is not None:
            why = _empty_reason(level, inside, *value_range())
        else:
            why = f"no grid cell crosses `level` {level:g} (check `level` and the grid's bounds)"
        warnings.warn(f"the extracted mesh is empty: {why}", EmptyMeshWarning, stacklevel=3)
    elif (corner is None or _in_solid(corner(), level, inside)) and mesh.volume < 0 and mesh.check().closed:
        other = "below" if inside == "above" else "above"
        warnings.warn(
            f"the extracted mesh is closed but encloses a negative volume ({mesh.volume:.4g}): "
            f"the solid is the unbounded side of the level set, so `inside={inside!r}` is "
            f"probably wrong for this data (try inside={other!r})",
            InsideOutWarning,
            stacklevel=3,
        )
    return mesh
