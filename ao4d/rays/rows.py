"""Rays as every traversal takes them: the caller's arrays checked, mapped into a tree's frame
(:class:`_Rays`, in float64 before the kernels round them), the answers' arrays filled launch by
launch (:class:`_Results`), a mesh's tree on a resolved backend (:class:`Tracer`) and the progress
bar (ray budgets: :mod:`ao4d._budget`).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from .. import _progress
from .. import bvh as _bvh
from .._validate import as_array, as_real
from ..bvh import get_bvh
from ..mesh import as_mesh

__all__ = ["check_distance", "mesh_arrays", "unit_rows", "progress_bar", "Tracer"]


_PROGRESS_MIN_RAYS = 1 << 22  # show a bar by default only for work this large


def _reach32(max_distance: float) -> np.float32:
    """A ray length for the float32 kernels: beyond float32's range it is infinite (the trees
    span about one unit), so the cast is not an overflow warning printed to the user."""
    return np.float32(max_distance) if max_distance <= float(np.finfo(np.float32).max) else np.float32(np.inf)


def check_distance(max_distance: Any) -> float:
    """``max_distance`` as a float > 0 (``inf`` allowed: unlimited), else an error naming it.

    Parameters
    ----------
    max_distance : float
        The longest ray, in world units.

    Returns
    -------
    float
        The value as a float.

    Raises
    ------
    ValueError
        If it is not a number > 0.
    """
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


def _pad4(a: np.ndarray) -> np.ndarray:
    out = np.zeros((len(a), 4), dtype=np.float32)
    out[:, : a.shape[1]] = a
    return out


def _row_types(origins: np.ndarray, directions: np.ndarray) -> tuple[type, str]:
    """The type the kernels read rays' rows in, as numpy and C name it: float32 when both arrays
    are float32, else float64 (exact for float32 values)."""
    return (np.float32, "float") if origins.dtype == directions.dtype == np.float32 else (np.float64, "double")


def _frame_values(frame) -> np.ndarray:
    """A tree frame as the kernels read it (``map_ray`` in kernels/rays/rows.h, kernels/rays/refine.cl):
    its centre's coordinates, then its scale, in float64."""
    return np.append(np.asarray(frame.centre, dtype=np.float64), np.float64(frame.scale))


def _tree_order(dev: dict, hit: np.ndarray) -> np.ndarray:
    """Tree-order simplices of kernel answers ``lanes * leaf block + lane`` (>= 0)."""
    lanes = dev["lanes"]
    return dev["block_first"][hit // lanes] + hit % lanes


class _NullBar:
    def update(self, n: int) -> None:
        pass


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
    (the order ``map_ray`` in kernels/rays/ao.cl follows); ``inf`` for a zero-length row."""
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


def _miss_values(n: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """``t`` and barycentrics of ``n`` rays that all missed: inf and zeros."""
    return np.full(n, np.inf), np.zeros((n, d))
