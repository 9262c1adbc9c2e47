"""The numpy reference traversals: the binary tree walked in float64, ray frontier by frontier
(and brute force over all simplices), for closest hits, any hits and AO counts. The OpenCL
kernels answer the same rays; they differ only on rays that graze an edge or the
``max_distance`` sphere.
"""

from __future__ import annotations

import numpy as np

from .. import bvh as _bvh
from ..sampling import cosine_hemisphere

__all__ = []


_NUMPY_RAYS_PER_STEP = 1 << 14  # bounds the (ray, node) frontier of the numpy traversal


def _box_hits(lo, hi, o, inv_w, t_max):
    """Slab test in float64 like ``hit_boxes`` in kernels/common/geometry.h (which keeps the inverse
    direction finite instead; both are conservative for rays parallel to a slab)."""
    with np.errstate(invalid="ignore"):
        t0, t1 = (lo - o) * inv_w, (hi - o) * inv_w
    # fmin/fmax skip the NaN of 0 * inf: the slab of a parallel ray counts as hit
    t_near = np.fmax(np.fmax.reduce(np.fmin(t0, t1), axis=1), 0.0)
    t_far = np.fmin(np.fmin.reduce(np.fmax(t0, t1), axis=1), t_max)
    return t_near <= t_far


def _leaf_pairs(rays: np.ndarray, meta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    first, count = -meta[:, 0] - 1, meta[:, 1]
    ray = np.repeat(rays, count)
    start = np.cumsum(count) - count
    prim = np.repeat(first, count) + (np.arange(ray.size) - np.repeat(start, count))
    return ray, prim


def _record_hits(best, best_t, ray, prim, t, any_hit):
    if any_hit:
        best[ray], best_t[ray] = prim, t
        return
    order = np.lexsort((t, ray))
    ray, prim, t = ray[order], prim[order], t[order]
    first = np.ones(ray.size, dtype=bool)
    first[1:] = ray[1:] != ray[:-1]
    ray, prim, t = ray[first], prim[first], t[first]
    closer = t <= best_t[ray]
    best[ray[closer]], best_t[ray[closer]] = prim[closer], t[closer]


def _trace_numpy_bvh(tree, o, w, max_distance, any_hit):
    """Breadth-first traversal of (ray, node) pairs, vectorised over the whole frontier."""
    d = tree.dim
    n = len(o)
    lo, hi = tree.lo[:, :d].astype(np.float64), tree.hi[:, :d].astype(np.float64)
    with np.errstate(divide="ignore"):
        inv_w = 1.0 / w
    best = np.full(n, -1, dtype=np.int64)
    best_t = np.full(n, max_distance)
    ray, node = np.arange(n), np.zeros(n, dtype=np.int64)
    while ray.size:
        meta = tree.meta[node].astype(np.int64)
        leaf = meta[:, 0] < 0
        if leaf.any():
            r, p = _leaf_pairs(ray[leaf], meta[leaf])
            ok, t = _bvh.intersect(tree.inverse[p], tree.origin[p], o[r], w[r], best_t[r])
            _record_hits(best, best_t, r[ok], p[ok], t[ok], any_hit)
        r, m = ray[~leaf], meta[~leaf]
        if any_hit:
            live = best[r] < 0
            r, m = r[live], m[live]
        r = np.concatenate([r, r])
        c = np.concatenate([m[:, 0], m[:, 1]])
        keep = _box_hits(lo[c], hi[c], o[r], inv_w[r], best_t[r])
        ray, node = r[keep], c[keep]
    return best_t, best


def _trace_numpy_brute(tree, o, w, max_distance, any_hit, block=64):
    n = len(o)
    best = np.full(n, -1, dtype=np.int64)
    best_t = np.full(n, max_distance)
    for start in range(0, tree.n_prims, block):
        prims = np.arange(start, min(start + block, tree.n_prims))
        r = np.repeat(np.arange(n), prims.size)
        p = np.tile(prims, n)
        ok, t = _bvh.intersect(tree.inverse[p], tree.origin[p], o[r], w[r], best_t[r])
        _record_hits(best, best_t, r[ok], p[ok], t[ok], any_hit)
    return best_t, best


def _trace_numpy(tree, rays, max_distance, any_hit, accel, bar):
    """Tree-order simplex or -1 per ray of ``rays`` (:class:`_Rays`), in float64."""
    hit = np.empty(rays.n, dtype=np.int64)
    trace = _trace_numpy_bvh if accel == "bvh" else _trace_numpy_brute
    for start in range(0, rays.n, _NUMPY_RAYS_PER_STEP):
        stop = min(rays.n, start + _NUMPY_RAYS_PER_STEP)
        o, w = rays.chunk(start, stop, np.float64)
        hit[start:stop] = trace(tree, o, w, max_distance, any_hit)[1]
        bar.update(stop - start)
    return hit


def _ao_numpy(tree, points, normals, samples, seed, offset, max_distance, accel, bar, index=None, first=0):
    n = len(points)
    counts = np.empty(n, dtype=np.int64)
    per_step = max(1, _NUMPY_RAYS_PER_STEP // samples)
    for start in range(0, n, per_step):
        sl = slice(start, min(n, start + per_step))
        w = cosine_hemisphere(
            normals[sl], samples, seed=seed, index_offset=start, index=None if index is None else index[sl], first=first
        )
        o = points[sl] + offset * normals[sl]
        o = np.repeat(o, samples, axis=0)
        trace = _trace_numpy_bvh if accel == "bvh" else _trace_numpy_brute
        hit = trace(tree, o, w.reshape(-1, tree.dim), max_distance, True)[1]
        counts[sl] = (hit.reshape(-1, samples) >= 0).sum(1)
        bar.update((sl.stop - sl.start) * samples)
    return counts
