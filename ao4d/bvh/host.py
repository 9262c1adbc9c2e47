"""The reference BVH builder, on the host with numpy (the numpy backend's tree).

The binary tree is built top-down, one level at a time for all nodes at once (vectorised): a
node holding more than ``leaf_size`` simplices is split along the longest axis of its centroid
bounds where the binned surface-area heuristic (32 bins; the box's boundary (d-1)-measure as the
hit probability) is lowest; nodes of at most 16 simplices, nodes where SAH finds no split and
all nodes below level 40 split at the median instead, which bounds the depth. Nodes are numbered
breadth first and each covers a contiguous range of the reordered simplices, so a leaf is
``(start, count)``. The simplices' data stay in tree order in one float32 array that is sorted
once per level; a level costs a few passes over it (about 4 s for 1M tetrahedra). Where OpenCL
runs, :mod:`ao4d.bvh.device` builds the same kind of tree on the device.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .. import _progress
from .._validate import as_array, check_positive_int
from ..geometry import cross_components, edge_blocks
from .layout import _BOX_FMA_MARGIN, _BOX_MARGIN, BARY_EPS, BVH, box_area

__all__ = ["build", "check_mesh_arrays", "frames", "nondegenerate", "nondegenerate_given"]

_DEGENERATE_RTOL = 1e-12  # |n| below this times (longest edge)^(d-1): zero measure
_SAH_BINS = 32
_SAH_MIN_COUNT = 16  # smaller nodes split at the median: fewer levels, a faster build, rays as fast
_SAH_MAX_LEVEL = 40  # deeper levels split at the median: depth <= 40 + log2(P) < 64


def _keep(edges: list[np.ndarray], normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The degeneracy test: which simplices to keep, and ``|n|^2``, from the edge and normal
    components (component-major, float64).

    A simplex is kept when ``|n| > 1e-12 * L^(d-1)`` (L its longest edge from vertex 0) and
    ``|n| > 0``. ``kernels/bvh/bvh_build.cl`` repeats these operations in this order, the power as
    products left to right (``L * L * L`` in 4D): ``np.power`` rounds once where the products
    round twice, and a simplex in that gap would be kept by one side and skipped by the other.
    """
    d = len(edges) + 1
    longest = np.sqrt(np.max([(e * e).sum(0) for e in edges], axis=0))
    scale = longest
    for _ in range(d - 2):
        scale = scale * longest
    norm2 = (normals * normals).sum(0)
    norm = np.sqrt(norm2)
    return (norm > _DEGENERATE_RTOL * scale) & (norm > 0), norm2


def nondegenerate(vertices: np.ndarray, simplices: np.ndarray, *, chunk: int = 1 << 20) -> np.ndarray:
    """(S,) bool: the simplices :func:`frames` keeps (float64 vertices (V, d), simplices (S, d)),
    ``chunk`` simplices at a time. The device builder takes it from here on devices without
    double precision, so that both builders keep the same simplices."""
    keep = np.empty(len(simplices), dtype=bool)
    for rows, edges in edge_blocks(vertices, simplices, chunk):
        keep[rows] = _keep(edges, cross_components(edges))[0]
    return keep


def nondegenerate_given(vertices: np.ndarray, simplices: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """:func:`nondegenerate` for simplices whose normals are known, mostly without their edges.

    The test keeps a simplex when ``|n| > 1e-12 * L^(d-1)``, L its longest edge from vertex 0.
    No edge is longer than the diagonal D of the vertices' bounding box, so a simplex with
    ``|n|`` above ``1e-12 * D^(d-1)`` (plus a margin far above the tests' rounding) is kept
    whatever its edges; only the others, the slivers and the degenerate ones, gather their
    edges for the full test. The same answer as ``nondegenerate(vertices, simplices)``, at a
    fraction of its cost: the edges' gathers were most of it.

    Parameters
    ----------
    vertices : (V, d) numpy.ndarray of float64
        Vertex coordinates, d in {2, 3, 4}.
    simplices : (S, d) numpy.ndarray of int
        Vertex indices of each simplex.
    normals : (S, d) numpy.ndarray of float64
        ``ao4d.geometry.simplex_normals(vertices, simplices)``.

    Returns
    -------
    numpy.ndarray
        (S,) bool: the simplices :func:`frames` keeps.
    """
    d = vertices.shape[1]
    if len(simplices) == 0:
        return np.ones(0, dtype=bool)
    diagonal = float(np.sqrt((np.ptp(vertices, axis=0) ** 2).sum()))
    # a relative margin of 1e-9 covers the few roundings of L, L^(d-1) and |n| (about 1e-15 each)
    bound = _DEGENERATE_RTOL * (diagonal * (1.0 + 1e-9)) ** (d - 1) * (1.0 + 1e-9)
    keep = np.sqrt(np.einsum("ij,ij->i", normals, normals)) * (1.0 - 1e-9) > bound
    unsure = np.flatnonzero(~keep)
    if unsure.size:
        keep[unsure] = nondegenerate(vertices, simplices[unsure])
    return keep


def frames(vertices: np.ndarray, simplices: np.ndarray):
    """Per-simplex inverse matrices and corners (component-major); drop degenerate simplices.

    Returns the kept simplices' indices, their corners as d arrays (d, S) and the inverses
    (S, d, d). Works on contiguous per-coordinate arrays: gathers and products of (S, d)
    column views cost several times more.
    """
    d = vertices.shape[1]
    coords = np.ascontiguousarray(vertices.T)  # (d, V)
    ids = np.ascontiguousarray(simplices.T)  # (d, S)
    pts = [np.take(coords, ids[k], axis=1) for k in range(d)]  # d x (d, S)
    edges = [p - pts[0] for p in pts[1:]]
    normals = cross_components(edges)
    keep, norm2 = _keep(edges, normals)
    idx = np.flatnonzero(keep)
    if idx.size < len(keep):
        pts = [p[:, idx] for p in pts]
        edges = [e[:, idx] for e in edges]
        normals, norm2 = normals[:, idx], norm2[idx]
    # inverse of M = [e1 .. e_{d-1} | n] (columns) by Cramer's rule: det M = n . n, and row i
    # is (-1)^(d-1-i) X(columns but i) / det M; the last row is n / |n|^2
    columns = edges + [normals]
    inverse = np.empty((d, d, len(idx)))
    for i in range(d - 1):
        sign = 1.0 if (d - 1 - i) % 2 == 0 else -1.0
        inverse[i] = cross_components(columns[:i] + columns[i + 1 :]) * (sign / norm2)
    inverse[d - 1] = normals / norm2
    return idx, pts, inverse.transpose(2, 0, 1)


def _sah_bins(bins, n_bins, rank, seg_rows, n_seg, data, d):
    """Per (segment, bin) primitive count, bounds and centroid bounds of the considered segments.

    ``bins`` (N,) are the bin numbers of all primitives (sorted by segment, then bin), ``rank``
    (N,) their segment ranks, ``seg_rows`` the row of each segment rank among the ``n_seg``
    considered (-1: not considered), ``data`` (3d, N) the primitives' ``[lo | centroid | hi]`` (component-major).
    Returns counts (n_seg, B) and the bin minima of ``[lo | centroid]`` and maxima of
    ``[centroid | hi]``, (n_seg, B, 2d) each (empty bins: +inf / -inf).
    """
    flat = rank * n_bins + bins
    runs = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]])  # sorted: bins are runs
    row = seg_rows[rank[runs]]
    used = row >= 0
    run_min = np.minimum.reduceat(data[: 2 * d], runs, axis=1).T[used]
    run_max = np.maximum.reduceat(data[d:], runs, axis=1).T[used]
    run_n = np.diff(np.r_[runs, len(flat)])[used]
    cell = row[used] * n_bins + bins[runs[used]]
    b_min = np.full((n_seg * n_bins, 2 * d), np.inf, dtype=data.dtype)
    b_max = np.full((n_seg * n_bins, 2 * d), -np.inf, dtype=data.dtype)
    counts = np.zeros(n_seg * n_bins, dtype=np.int64)
    b_min[cell], b_max[cell], counts[cell] = run_min, run_max, run_n
    shape = (n_seg, n_bins, 2 * d)
    return counts.reshape(n_seg, n_bins), b_min.reshape(shape), b_max.reshape(shape)


def _running(ufunc, a: np.ndarray, reverse: bool = False) -> np.ndarray:
    """``ufunc.accumulate`` along axis 1 of (N, B, k) (or from the end): a loop over the B
    bins of whole (N, k) slices runs several times faster than numpy's strided accumulate."""
    out = np.empty_like(a)
    cols = range(a.shape[1] - 1, -1, -1) if reverse else range(a.shape[1])
    prev = None
    for k in cols:
        prev = a[:, k] if prev is None else ufunc(prev, a[:, k])
        out[:, k] = prev
    return out


def _sah_split_counts(counts, box_lo, box_hi, s_count):
    """Binned SAH: how many of each segment's sorted primitives go left (0 = no good split)."""
    n_seg = len(counts)
    left_n = np.cumsum(counts, axis=1)[:, :-1]
    right_n = s_count[:, None] - left_n
    left_a = box_area(_running(np.minimum, box_lo), _running(np.maximum, box_hi))[:, :-1]
    right_a = box_area(_running(np.minimum, box_lo, True), _running(np.maximum, box_hi, True))[:, 1:]
    with np.errstate(invalid="ignore"):
        cost = np.where((left_n > 0) & (right_n > 0), left_a * left_n + right_a * right_n, np.inf)
    best = np.argmin(cost, axis=1)
    rows = np.arange(n_seg)
    return np.where(np.isfinite(cost[rows, best]), left_n[rows, best], 0)


def _split_levels(centroids: np.ndarray, p_lo: np.ndarray, p_hi: np.ndarray, leaf_size: int, bar=None):
    """Top-down binned-SAH splits along the longest centroid axis, all nodes of a level at once.

    The primitives' data stay in tree order, one array sorted once per level (by node, then by
    centroid along the node's axis; finished leaves keep their place): every node is a
    contiguous range, marked by ``is_start``. The bins that choose a split also give the
    children's centroid bounds (a superset: the bins on each side of the split). Falls back to
    the median where SAH finds no split and below ``_SAH_MAX_LEVEL`` levels, which bounds the
    depth by ``_SAH_MAX_LEVEL + log2(P)``. Returns the primitive order, the primitive bounds in
    that order, per node ``start``, ``count``, ``left``, ``right`` (-1 for leaves) and the node
    ids per level.
    """
    work = _Splits(centroids, p_lo, p_hi)
    while (work.count[work.levels[-1]] > leaf_size).any():
        work.split_level(leaf_size)
        if bar is not None:
            if bar.total is not None and bar.n + 1 > bar.total:
                bar.total = bar.n + 1  # deeper than estimated: keep the bar honest
            bar.update(1)
    sl = slice(0, work.n_nodes)
    d = work.d
    return (
        work.order,
        work.data[:d].T,
        work.data[2 * d :].T,
        work.start[sl],
        work.count[sl],
        work.left[sl],
        work.right[sl],
        work.levels,
    )


class _Level:
    """The current level's segments (one per node, leaves included) and the nodes to split."""

    def __init__(self, work: "_Splits", leaf_size: int) -> None:
        self.seg_start = np.flatnonzero(work.is_start)
        self.seg_node = work.node_at[self.seg_start]
        self.seg_count = work.count[self.seg_node]
        self.active = self.seg_count > leaf_size
        self.ids = self.seg_node[self.active]
        self.s_start, self.s_count = self.seg_start[self.active], self.seg_count[self.active]
        self.rows = np.arange(self.seg_start.size)
        self.rank = np.repeat(self.rows, self.seg_count)  # segment of every primitive


class _Splits:
    """The state of :func:`_split_levels`: primitive data in tree order and the node arrays."""

    def __init__(self, centroids: np.ndarray, p_lo: np.ndarray, p_hi: np.ndarray) -> None:
        n, d = centroids.shape
        self.n, self.d = n, d
        # float32 working copy [lo | centroid | hi] (bounds rounded outwards), component-major:
        # half the memory traffic of float64, and contiguous rows gather and reduce fastest
        self.data = np.empty((3 * d, n), dtype=np.float32)
        self.data[:d] = np.nextafter(p_lo.T.astype(np.float32), np.float32(-np.inf))
        self.data[d : 2 * d] = centroids.T
        self.data[2 * d :] = np.nextafter(p_hi.T.astype(np.float32), np.float32(np.inf))
        self.spare = np.empty_like(self.data)
        self.order = np.arange(n)
        cap = 2 * n + 1  # a binary tree with non-empty leaves has fewer than 2n nodes
        self.start = np.zeros(cap, dtype=np.int64)
        self.count = np.zeros(cap, dtype=np.int64)
        self.left = np.full(cap, -1, dtype=np.int64)
        self.right = np.full(cap, -1, dtype=np.int64)
        self.c_lo = np.zeros((cap, d), dtype=np.float32)  # centroid bounds of nodes still to split
        self.c_hi = np.zeros((cap, d), dtype=np.float32)
        self.c_known = np.zeros(cap, dtype=bool)
        self.count[0] = n
        self.is_start = np.zeros(n, dtype=bool)  # first primitive of a current node (leaf or not)
        self.is_start[0] = True
        self.node_at = np.zeros(n, dtype=np.int64)  # node id by its first primitive
        self.levels = [np.array([0])]
        self.n_nodes = 1
        self.index = np.arange(n)

    def split_level(self, leaf_size: int) -> None:
        """Split every node of the current level that holds more than ``leaf_size`` primitives."""
        level = _Level(self, leaf_size)
        self._reduce_unknown_bounds(level)
        frac = self._sort(level)
        half = level.s_count // 2
        big = level.s_count > _SAH_MIN_COUNT
        sah = None
        if len(self.levels) <= _SAH_MAX_LEVEL and big.any():
            sah = self._sah_bins(level, frac, big)
            chosen = _sah_split_counts(sah[1], sah[2][..., : self.d], sah[3][..., self.d :], level.s_count[big])
            half[big] = np.where(chosen > 0, chosen, half[big])
        # left sides of whole leaves: leaf blocks of the kernels run with all lanes full
        half = np.clip(leaf_size * np.round(half / leaf_size).astype(np.int64), leaf_size, level.s_count - 1)
        ids_l, ids_r = self._children(level, half)
        if sah is not None:
            self._child_bounds(level, half, big, sah, ids_l, ids_r)
        self.levels.append(np.stack([ids_l, ids_r], 1).ravel())

    def _reduce_unknown_bounds(self, level: _Level) -> None:
        """Centroid bounds of the root and of median-split children, reduced over their ranges."""
        d = self.d
        unknown = ~self.c_known[level.ids]
        if not unknown.any():
            return
        s_start, s_count = level.s_start[unknown], level.s_count[unknown]
        edges = np.stack([s_start, s_start + s_count], 1).ravel()
        cent = np.concatenate([self.data[d : 2 * d], self.data[d : 2 * d, -1:]], axis=1)  # edges may be n
        self.c_lo[level.ids[unknown]] = np.minimum.reduceat(cent, edges, axis=1).T[::2]
        self.c_hi[level.ids[unknown]] = np.maximum.reduceat(cent, edges, axis=1).T[::2]

    def _sort(self, level: _Level) -> np.ndarray:
        """Sort each segment by centroid along its node's longest axis (finished leaves and flat
        nodes keep their order); returns every primitive's place in its node's range, [0, 1]."""
        d, seg_count, rows = self.d, level.seg_count, level.rows
        node_lo, node_hi = self.c_lo[level.seg_node], self.c_hi[level.seg_node]
        axis = np.argmax(node_hi - node_lo, axis=1)
        ext = (node_hi - node_lo)[rows, axis]
        ext = np.where(level.active & (ext > 0), ext, np.inf)
        # per-segment values spread to the primitives with repeat (contiguous writes: several
        # times faster than gathers by segment rank)
        value = np.choose(np.repeat(axis, seg_count), self.data[d : 2 * d])
        frac = np.clip((value - np.repeat(node_lo[rows, axis], seg_count)) / np.repeat(ext, seg_count), 0.0, 1.0)
        done = np.repeat(~level.active, seg_count)
        place = (self.index - np.repeat(level.seg_start, seg_count)) / np.repeat(seg_count + 1.0, seg_count)
        frac[done] = place[done]
        sort = np.argsort(level.rank + 0.75 * frac)  # keys stay below rank + 1
        self.data, self.spare = np.take(self.data, sort, axis=1, out=self.spare), self.data  # no page faults
        self.order = np.take(self.order, sort)
        return np.take(frac, sort)

    def _sah_bins(self, level: _Level, frac: np.ndarray, big: np.ndarray):
        """Bins of the nodes large enough for SAH: (bins, counts, bin minima, bin maxima)."""
        # fewer bins for small nodes: 32 bins pay off at the top (4% fewer node visits)
        # but would double the cost of the many small nodes at the bottom
        n_bins = _SAH_BINS if level.s_count[big].mean() > 8 * _SAH_BINS else _SAH_BINS // 2
        bins = np.minimum((frac * n_bins).astype(np.int64), n_bins - 1)
        seg_rows = np.full(level.seg_start.size, -1, dtype=np.int64)
        big_ranks = np.flatnonzero(level.active)[big]
        seg_rows[big_ranks] = np.arange(big_ranks.size)
        counts, b_min, b_max = _sah_bins(bins, n_bins, level.rank, seg_rows, big_ranks.size, self.data, self.d)
        return bins, counts, b_min, b_max

    def _children(self, level: _Level, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Two children per split node: the first ``half`` primitives and the rest."""
        ids, s_start, s_count = level.ids, level.s_start, level.s_count
        ids_l = self.n_nodes + 2 * np.arange(ids.size)
        ids_r = ids_l + 1
        self.n_nodes += 2 * ids.size
        self.left[ids], self.right[ids] = ids_l, ids_r
        self.start[ids_l], self.count[ids_l] = s_start, half
        self.start[ids_r], self.count[ids_r] = s_start + half, s_count - half
        self.is_start[s_start + half] = True
        self.node_at[s_start], self.node_at[s_start + half] = ids_l, ids_r
        return ids_l, ids_r

    def _child_bounds(self, level: _Level, half, big, sah, ids_l, ids_r) -> None:
        """Children's centroid bounds from the SAH bins: the bins from the first to the one
        holding the last left primitive, and from the one holding the first right primitive on."""
        d = self.d
        bins, _, b_min, b_max = sah
        split = (level.s_start + half)[big]
        r = np.arange(big.sum())
        bl, br = bins[split - 1], bins[split]
        cent_min, cent_max = b_min[..., d:], b_max[..., :d]
        self.c_lo[ids_l[big]] = _running(np.minimum, cent_min)[r, bl]
        self.c_hi[ids_l[big]] = _running(np.maximum, cent_max)[r, bl]
        self.c_lo[ids_r[big]] = _running(np.minimum, cent_min, True)[r, br]
        self.c_hi[ids_r[big]] = _running(np.maximum, cent_max, True)[r, br]
        self.c_known[ids_l[big]] = self.c_known[ids_r[big]] = True


def _node_bounds(prim_lo, prim_hi, start, count, left, right, levels):
    """Bounds of every node: leaves reduce their ranges, parents merge children bottom-up."""
    n_nodes, d = len(start), prim_lo.shape[1]
    lo = np.empty((n_nodes, d), dtype=prim_lo.dtype)
    hi = np.empty((n_nodes, d), dtype=prim_hi.dtype)
    leaves = np.flatnonzero(left < 0)
    leaves = leaves[np.argsort(start[leaves])]  # leaves partition the primitive range in order
    lo[leaves] = np.minimum.reduceat(prim_lo, start[leaves], axis=0)
    hi[leaves] = np.maximum.reduceat(prim_hi, start[leaves], axis=0)
    for ids in reversed(levels):
        ids = ids[left[ids] >= 0]
        lo[ids] = np.minimum(lo[left[ids]], lo[right[ids]])
        hi[ids] = np.maximum(hi[left[ids]], hi[right[ids]])
    return lo, hi


def _pad4(a: np.ndarray) -> np.ndarray:
    out = np.zeros((len(a), 4), dtype=a.dtype)
    out[:, : a.shape[1]] = a
    return out


def check_mesh_arrays(vertices: Any, simplices: Any, leaf_size: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """The input checks of both builders: (V, d) finite floats, (S, d) in-range integers, S > 0.

    Parameters
    ----------
    vertices, simplices : array_like
        As for :func:`build`.
    leaf_size : int
        As for :func:`build`.

    Returns
    -------
    vertices : (V, d) float64
        The checked vertices.
    simplices : (S, d) int array
        The checked simplices.
    leaf_size : int
        The checked leaf size.

    Raises
    ------
    ValueError
        If a shape, a value or an index is out of range.
    TypeError
        If ``simplices`` does not hold integers or ``leaf_size`` is not an integer.
    """
    vertices = as_array(vertices, "vertices", ndim=2, dtype=np.float64, finite=True)
    d = vertices.shape[1]
    if d not in (2, 3, 4):
        raise ValueError(f"`vertices` must have 2, 3 or 4 columns, got shape {vertices.shape}")
    simplices = as_array(simplices, "simplices", ndim=2, shape_tail=(d,))
    if simplices.shape[0] == 0:
        raise ValueError("`simplices` is empty: a mesh without simplices has nothing to hit")
    if simplices.dtype.kind not in "iu":
        raise TypeError(f"`simplices` must hold integers, got dtype {simplices.dtype}")
    if simplices.min() < 0 or simplices.max() >= len(vertices):
        raise ValueError(
            f"`simplices` indices must be in [0, {len(vertices)}), got range [{simplices.min()}, {simplices.max()}]"
        )
    return vertices, simplices, check_positive_int(leaf_size, "leaf_size")


def build(vertices: Any, simplices: Any, *, leaf_size: int = 16, progress: bool | None = None) -> BVH:
    """Build the BVH of a simplex mesh.

    Parameters
    ----------
    vertices : (V, d) array_like of float
        d in {2, 3, 4}.
    simplices : (S, d) array_like of int
        Vertex indices per simplex.
    leaf_size : int
        Most simplices per leaf (the OpenCL kernels need at most ``LANES`` = 16).
    progress : bool, optional
        Show a tqdm bar (default: from 2^19 simplices on).

    Returns
    -------
    BVH
        The tree, in the identity frame.

    Raises
    ------
    ValueError
        If the mesh is empty, has non-finite vertices or out-of-range indices, or every simplex
        is degenerate.

    Examples
    --------
    >>> tree = build([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> tree.n_prims, tree.n_nodes
    (1, 1)
    """
    vertices, simplices, leaf_size = check_mesh_arrays(vertices, simplices, leaf_size)
    d = vertices.shape[1]
    idx, pts, inverse = frames(vertices, simplices.astype(np.int64))
    if idx.size == 0:
        raise ValueError(f"all {len(simplices)} simplices are degenerate (zero measure)")
    p_lo, p_hi = np.minimum.reduce(pts), np.maximum.reduce(pts)  # (d, S)
    diagonal = float(np.linalg.norm(p_hi.max(1) - p_lo.min(1)))
    # an accepted hit lies within BARY_EPS (barycentric) of the simplex: grow boxes to match
    # (plus float32 slab-test error: fma(box, 1/w, -o/w) errs by ~|o| 2^-24 in coordinates, so
    # a scene far from the coordinate origin needs a margin that grows with its distance)
    extent = max(diagonal, _BOX_FMA_MARGIN * float(np.abs(pts).max()), 1e-30)
    margin = 2 * BARY_EPS * (p_hi - p_lo).max(0) + _BOX_MARGIN * extent
    p_lo, p_hi = (p_lo - margin).T, (p_hi + margin).T
    centroids = (np.add.reduce(pts) / d).T
    show = idx.size >= (1 << 19) if progress is None else bool(progress)
    # SAH trees run about 1.6 times deeper than balanced ones
    levels_estimate = math.ceil(1.6 * math.log2(max(idx.size / leaf_size, 1))) + 2
    bar = _progress.bar(levels_estimate, "BVH levels", unit="level", show=show)
    with bar:
        order, s_lo, s_hi, start, count, left, right, levels = _split_levels(centroids, p_lo, p_hi, leaf_size, bar)
    lo, hi = _node_bounds(s_lo, s_hi, start, count, left, right, levels)
    meta = np.where((left >= 0)[:, None], np.stack([left, right], 1), np.stack([-(start + 1), count], 1))
    return BVH(
        dim=d,
        lo=_pad4(lo),  # float32, rounded outwards per simplex in _split_levels
        hi=_pad4(hi),
        meta=meta.astype(np.int32),
        inverse=np.take(inverse, order, axis=0),
        origin=np.take(pts[0], order, axis=1).T.copy(),
        prim=idx[order].astype(np.int64),
        n_skipped=len(simplices) - idx.size,
        depth=len(levels),
        diagonal=diagonal,
    )
