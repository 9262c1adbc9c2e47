"""The orientation convention of DESIGN.md, written once: the generalised cross product.

Simplex (p0, ..., p_{d-1}) in R^d has normal n with ``n . x = det[p1 - p0; ...; p_{d-1} - p0; x]``
(rows, x last). n is the cross product of the d-1 edge vectors: component k is the cofactor of
entry (d-1, k). In 3D it is the usual cross product ``(p1 - p0) x (p2 - p0)``; in 2D it is
``(p1 - p0)`` turned clockwise. ``|n| = (d-1)! * measure``. The mesh, the BVH, the lookup-table
builder and the camera all use these functions.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

__all__ = ["cross", "cross_components", "edge_blocks", "signed_volumes", "simplex_normals", "vertex_sums"]

# Simplices per block when gathering corners: the block's temporaries (about 30 arrays) stay in
# a core's L2 cache, which larger blocks overflow (figures in the benchmarks log)
_BLOCK = 1 << 14


def cross_components(rows: Sequence[Any]) -> np.ndarray:
    """Generalised cross product X of d-1 vectors stored component-major.

    ``X . x = det[v_1; ...; v_{d-1}; x]``. Each of the d-1 entries of ``rows`` is indexable by
    component first (shape (d, ...)): contiguous per-component arrays make the closed-form
    cofactors fast (a batched ``np.linalg.det`` costs ten times more). Exact for integer input.
    No validation.

    Parameters
    ----------
    rows : sequence of d-1 arrays of shape (d, ...)
        The vectors, component-major.

    Returns
    -------
    X : (d, ...) array, dtype of the inputs' products
        The generalised cross product, component-major.
    """
    d = len(rows) + 1
    if d == 2:
        (a,) = rows
        return np.stack([-a[1], a[0]])
    if d == 3:
        a, b = rows
        return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
    a, b, c = rows
    # 2x2 minors of the last two rows, then expansion along the first row of each 3x3 minor
    m = {(p, q): b[p] * c[q] - b[q] * c[p] for p in range(4) for q in range(p + 1, 4)}
    out = []
    for j in range(4):
        p, q, r = (k for k in range(4) if k != j)
        det = a[p] * m[q, r] - a[q] * m[p, r] + a[r] * m[p, q]
        out.append(det if j % 2 else -det)  # sign (-1)^(d-1+j)
    return np.stack(out)


def cross(*vectors: Any) -> np.ndarray:
    """Generalised cross product of ``d - 1`` vectors in R^d (DESIGN.md orientation).

    Returns ``n`` with ``n . x = det[v_1; ...; v_{d-1}; x]`` for every ``x`` (cofactors of the
    last row); in 3D this is the usual cross product.

    Parameters
    ----------
    *vectors : (..., d) array_like
        ``d - 1`` vectors (broadcast together), d in {2, 3, 4}.

    Returns
    -------
    n : (..., d) ndarray
        Orthogonal to every input; its length is the (d-1)-volume of their parallelotope.
        Integer input gives an exact integer result; otherwise float64.

    Examples
    --------
    >>> cross([1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0])
    array([0, 0, 0, 1])
    >>> cross([1.0, 0, 0], [0, 1.0, 0])
    array([0., 0., 1.])
    """
    arrays = [np.asarray(v) for v in vectors]
    if not arrays:
        raise ValueError("`vectors` must be d - 1 vectors of length d, got none")
    if any(a.dtype.kind not in "biuf" for a in arrays):
        raise TypeError("`vectors` must be real numbers")
    if not all(a.dtype.kind in "biu" for a in arrays):
        arrays = [a.astype(np.float64) for a in arrays]
    arrays = np.broadcast_arrays(*arrays)
    d = arrays[0].shape[-1] if arrays[0].ndim else 0
    if d not in (2, 3, 4) or len(arrays) != d - 1:
        raise ValueError(f"`vectors` must be d - 1 vectors of length d (d in 2, 3, 4), got {len(arrays)} of length {d}")
    out = np.moveaxis(cross_components([np.moveaxis(a, -1, 0) for a in arrays]), 0, -1)
    return out + 0 if out.dtype.kind != "f" else out + 0.0  # -0.0 -> 0.0 for readable output


def simplex_normals(vertices: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Unnormalised simplex normals ``n`` with ``n·x = det[p1 - p0; ...; p_{d-1} - p0; x]``.

    Parameters
    ----------
    vertices : (V, d) float64
        Vertex coordinates, d in {2, 3, 4}.
    simplices : (S, d) int
        Vertex indices of each simplex.

    Returns
    -------
    normals : (S, d) float64
        ``|normals| = (d-1)! * measure``; zero for degenerate simplices. No input validation.

    Examples
    --------
    >>> simplex_normals(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    array([[0., 0., 1.]])
    """
    out = np.empty((len(simplices), vertices.shape[1]), dtype=np.float64)
    for rows, edges in edge_blocks(vertices, simplices):
        out[rows] = cross_components(edges).T
    return out


def signed_volumes(vertices: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Signed d-volumes ``det[p1 - p0; ...; pd - p0] / d!`` of d-simplices (d + 1 corners in R^d).

    Parameters
    ----------
    vertices : (n, d) float numpy.ndarray
        Points.
    simplices : (m, d + 1) int numpy.ndarray
        Corner indices per simplex.

    Returns
    -------
    (m,) float64 numpy.ndarray
        Positive for positively oriented simplices; the corners are measured from each
        simplex's centroid (less cancellation far from the origin). Exactly 0 for a simplex
        with two equal corners (LAPACK's LU leaves about 1e-16 of the scale, either sign).
    """
    d = vertices.shape[1]
    if len(simplices) == 0:
        return np.zeros(0)
    p = vertices[simplices]
    p = p - p.mean(axis=1, keepdims=True)
    volume = np.linalg.det(p[:, 1:] - p[:, :1]) / math.factorial(d)
    k = simplices.shape[1]
    repeated = np.zeros(len(simplices), dtype=bool)
    for i in range(k):
        for j in range(i + 1, k):
            repeated |= (p[:, i] == p[:, j]).all(axis=1)
    volume[repeated] = 0.0
    return volume


def vertex_sums(values: np.ndarray, simplices: np.ndarray, n: int) -> np.ndarray:
    """Per vertex, the sum of the rows of ``values`` over the simplices around it.

    One bincount per (coordinate, corner), the corners in order: every caller gets the same
    bits (the vertex normals and AO's query normals start from these sums). Contiguous columns
    spare the copy of the weights per corner that one bincount over the raveled simplices needs.

    Parameters
    ----------
    values : (S, k) float64
        One row per simplex (for normals: the raw normals, whose length weights by measure).
    simplices : (S, d) int
        Vertex indices of each simplex.
    n : int
        Number of vertices.

    Returns
    -------
    (n, k) float64
        The sums; zero rows for vertices in no simplex.

    Examples
    --------
    >>> vertex_sums(np.array([[1.0], [2.0]]), np.array([[0, 1], [1, 2]]), 3)
    array([[1.],
           [3.],
           [2.]])
    """
    total = np.zeros((n, values.shape[1]))
    corners = [np.ascontiguousarray(simplices[:, i]) for i in range(simplices.shape[1])]
    for j in range(values.shape[1]):
        weights = np.ascontiguousarray(values[:, j])
        for ids in corners:
            total[:, j] += np.bincount(ids, weights, n)
    return total


def edge_blocks(vertices: np.ndarray, simplices: np.ndarray, block: int = _BLOCK) -> Iterator[tuple[slice, list]]:
    """The simplices' edges from their first vertex, ``block`` simplices at a time.

    Parameters
    ----------
    vertices : (V, d) float64
        Vertex coordinates.
    simplices : (S, d) int
        Vertex indices of each simplex.
    block : int
        Simplices per step (the default keeps the temporaries in a core's L2 cache).

    Yields
    ------
    rows : slice
        The block's simplices.
    edges : list of d-1 (d, B) float64 arrays
        ``p_k - p_0`` for k = 1 .. d-1, component-major (as :func:`cross_components` takes them).
    """
    d = vertices.shape[1]
    coords = np.ascontiguousarray(vertices.T, dtype=np.float64)  # (d, V): contiguous gathers
    for start in range(0, len(simplices), block):
        ids = np.ascontiguousarray(simplices[start : start + block].T)  # (d, B)
        p0 = np.take(coords, ids[0], axis=1)
        yield slice(start, start + ids.shape[1]), [np.take(coords, ids[k], axis=1) - p0 for k in range(1, d)]
