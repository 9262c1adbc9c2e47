"""Ambient occlusion and ray casting on simplex meshes in 2D, 3D and 4D (OpenCL or numpy).

Definition (DESIGN.md): at a point p with unit normal n,
``A = (1/|B^{d-1}|) * integral over the hemisphere of V(p, w) (w . n) dw``, V = 1 when the ray
from p along w hits the mesh within ``max_distance``. Directions are cosine-weighted
(:mod:`ao4d.sampling`), so the estimate is the fraction of occluded rays. 1 = fully occluded.

Both backends trace the same rays: the same BVH (:mod:`ao4d.bvh`), the same directions (a shared
Sobol table and per-point integer-hash offsets), the same ray-simplex test with barycentric
tolerance ``ao4d.bvh.BARY_EPS``. The OpenCL kernels (``kernels/ao.cl``) compute in float32, the
numpy traversal in float64; they differ only on rays that graze an edge or the ``max_distance``
sphere.

Rays start at ``p + offset * n`` with ``offset = 1e-4 * (bounding-box diagonal)`` so that they do
not hit the simplices p lies on; geometry closer than that to p is not seen.

Work is split into launches of at most ``RAYS_PER_LAUNCH`` rays with a tqdm bar; Ctrl-C stops
between launches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import bvh as _bvh
from ._validate import as_array, check_choice, check_memory, check_positive_int
from .sampling import cosine_hemisphere, sobol_table

__all__ = ["ambient_occlusion", "cast_rays", "RayHits", "ORIGIN_OFFSET", "RAYS_PER_LAUNCH"]

ORIGIN_OFFSET = 1e-4  # times the bounding-box diagonal
RAYS_PER_LAUNCH = 1 << 21  # ~0.5-2 s per launch on a 2-core CPU: responsive bar and Ctrl-C
_NUMPY_RAYS_PER_STEP = 1 << 14  # bounds the (ray, node) frontier of the numpy traversal
_PROGRESS_MIN_RAYS = 1 << 22  # show a bar by default only for work this large


@dataclass(frozen=True)
class RayHits:
    """Result of :func:`cast_rays`.

    Attributes
    ----------
    t : (N,) float64
        Distance along the (normalised) direction to the hit; ``inf`` on a miss.
    simplex : (N,) int64
        Index of the hit simplex in ``mesh.simplices``; -1 on a miss.
    barycentric : (N, d) float64
        Weights of the hit simplex's d vertices (in ``mesh.simplices`` order) at the hit point,
        summing to 1; zeros on a miss.
    """

    t: np.ndarray
    simplex: np.ndarray
    barycentric: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: rays that hit."""
        return self.simplex >= 0


# -- input handling ---------------------------------------------------------------------------


def _mesh_arrays(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    try:
        vertices, simplices = np.asarray(mesh.vertices), np.asarray(mesh.simplices)
    except AttributeError:
        raise TypeError(
            f"`mesh` must be an ao4d.SimplexMesh (vertices and simplices), got {type(mesh).__name__}"
        ) from None
    if vertices.ndim != 2 or vertices.shape[1] not in (2, 3, 4):
        raise ValueError(f"`mesh` must live in 2D, 3D or 4D, got vertices of shape {vertices.shape}")
    if simplices.ndim != 2 or simplices.shape[0] == 0:
        raise ValueError("`mesh` has no simplices: nothing can occlude or be hit")
    return vertices, simplices


def _resolve_backend(backend: str):
    """Return ("opencl", runtime) or ("numpy", None)."""
    check_choice(backend, "backend", ("auto", "opencl", "numpy"))
    if backend == "numpy":
        return "numpy", None
    from . import cl

    runtime = cl.get_runtime(warn=backend == "auto")
    if runtime is None:
        if backend == "opencl":
            raise RuntimeError("backend='opencl' was requested but no OpenCL device works (see `ao4d info`)")
        return "numpy", None
    return "opencl", runtime


def _check_distance(max_distance: float) -> float:
    try:
        value = float(max_distance)
    except (TypeError, ValueError):
        raise TypeError(f"`max_distance` must be a number, got {type(max_distance).__name__}") from None
    if not value > 0:  # also rejects NaN
        raise ValueError(f"`max_distance` must be > 0 (inf for unlimited), got {max_distance}")
    return value


def _unit_rows(values: np.ndarray, name: str) -> np.ndarray:
    length = np.linalg.norm(values, axis=1)
    bad = np.flatnonzero(~(length > 0))
    if bad.size:
        raise ValueError(f"`{name}` has {bad.size} zero-length row(s), first at index {bad[0]}")
    return values / length[:, None]


def _progress_bar(progress: bool | None, total: int, desc: str):
    from tqdm.auto import tqdm

    disable = total < _PROGRESS_MIN_RAYS if progress is None else not progress
    return tqdm(total=total, desc=desc, unit="ray", unit_scale=True, disable=disable, leave=False)


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


# -- OpenCL side ------------------------------------------------------------------------------


def _check_device_memory(runtime, nbytes: dict[str, int]) -> None:
    dev = runtime.device
    for what, size in nbytes.items():
        if size > dev.max_mem_alloc_size:
            raise MemoryError(
                f"{what} needs {size / 2**20:.0f} MiB in one buffer, above the "
                f"{dev.max_mem_alloc_size / 2**20:.0f} MiB allowed by {runtime.name}; "
                "use a smaller mesh or backend='numpy'"
            )
    total = sum(nbytes.values())
    if total > 0.8 * dev.global_mem_size:
        raise MemoryError(
            f"ray tracing needs {total / 2**20:.0f} MiB on {runtime.name}, above 80% of its "
            f"{dev.global_mem_size / 2**20:.0f} MiB; use a smaller mesh or backend='numpy'"
        )


def _block_lanes(runtime) -> int:
    """Simplices per leaf block on this device: ``bvh.LANES`` (16) on CPUs, 4 elsewhere (why:
    bvh.widen)."""
    import pyopencl as cl

    return _bvh.LANES if runtime.device.type & cl.device_type.CPU else 4


def _device_tree(tree: _bvh.BVH, runtime) -> dict[str, Any]:
    """Device copies of the wide tree, uploaded once per context and cached on the tree."""
    lanes = _block_lanes(runtime)
    key = (id(runtime.context), lanes)
    if key not in tree.device:
        import pyopencl as cl

        wide = tree.wide(lanes)
        _check_device_memory(
            runtime,
            {
                "the BVH leaf blocks": wide.blocks.nbytes,
                "the BVH nodes": wide.boxes.nbytes,
                "the BVH": wide.nbytes(),
            },
        )
        flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        ctx = runtime.context
        tree.device[key] = {
            "boxes": cl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(wide.boxes)),
            "children": cl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(wide.children)),
            "blocks": cl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(wide.blocks)),
            "n_blocks": np.int32(len(wide.blocks)),
            "lanes": lanes,
            "slot_prim": wide.block_prim.ravel(),
        }
    return tree.device[key]


def _kernels(runtime, dim: int, lanes: int) -> dict[str, Any]:
    from . import cl

    defines = {"DIM": dim, "BARY_EPS": f"{_bvh.BARY_EPS:.9g}f", "WIDTH": _bvh.WIDTH, "LANES": lanes}
    return cl.build_kernels(runtime, "ao.cl", defines)


def _pad4(a: np.ndarray) -> np.ndarray:
    out = np.zeros((len(a), 4), dtype=np.float32)
    out[:, : a.shape[1]] = a
    return out


def _trace_opencl(tree, runtime, origins, directions, max_distance, any_hit, accel, bar):
    """Return (t float32, tree-order simplex or -1) per ray, launch by launch."""
    import pyopencl as cl

    n = len(origins)
    _check_device_memory(runtime, {"the rays": n * 32, "the ray results": n * 8})
    ctx, queue = runtime.context, runtime.queue
    mf = cl.mem_flags
    buf_o = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=_pad4(origins))
    buf_w = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=_pad4(directions))
    t = np.empty(n, dtype=np.float32)
    hit = np.empty(n, dtype=np.int32)
    buf_t = cl.Buffer(ctx, mf.WRITE_ONLY, t.nbytes)
    buf_h = cl.Buffer(ctx, mf.WRITE_ONLY, hit.nbytes)
    dev = _device_tree(tree, runtime)
    kernel, head = _traversal_kernel(runtime, tree.dim, dev, "cast", accel)
    args = head + [buf_o, buf_w, np.float32(max_distance), np.int32(any_hit), buf_t, buf_h]
    for start in range(0, n, RAYS_PER_LAUNCH):
        count = min(RAYS_PER_LAUNCH, n - start)
        kernel(queue, (count,), None, *args, global_offset=(start,)).wait()
        bar.update(count)
    cl.enqueue_copy(queue, t, buf_t)
    cl.enqueue_copy(queue, hit, buf_h)
    queue.finish()
    # kernels report LANES * leaf block + lane: map to tree-order simplices
    prim = np.where(hit >= 0, dev["slot_prim"][np.maximum(hit, 0)], -1)
    return t, prim


def _traversal_kernel(runtime, dim: int, dev: dict, name: str, accel: str):
    """The ``{name}_bvh`` or ``{name}_brute`` kernel and its leading scene arguments."""
    kernels = _kernels(runtime, dim, dev["lanes"])
    if accel == "bvh":
        return kernels[f"{name}_bvh"], [dev["boxes"], dev["children"], dev["blocks"]]
    return kernels[f"{name}_brute"], [dev["blocks"], dev["n_blocks"]]


def _ao_opencl(tree, runtime, points, normals, samples, seed, max_distance, accel, bar):
    """Occluded-ray counts per point on the device (points Morton-sorted for coherence)."""
    import pyopencl as cl

    n = len(points)
    _check_device_memory(runtime, {"the AO points": n * 36, "the AO results": n * 4})
    order = _morton_order(points)
    ctx, queue = runtime.context, runtime.queue
    mf = cl.mem_flags
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR
    table = sobol_table(samples, tree.dim - 1, seed=seed)
    buffers = [
        cl.Buffer(ctx, ro, hostbuf=_pad4(points[order])),
        cl.Buffer(ctx, ro, hostbuf=_pad4(normals[order])),
        cl.Buffer(ctx, ro, hostbuf=order.astype(np.uint32)),  # global index: same directions
        cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(table)),
    ]
    counts = np.empty(n, dtype=np.int32)
    buf_counts = cl.Buffer(ctx, mf.WRITE_ONLY, counts.nbytes)
    dev = _device_tree(tree, runtime)
    kernel, head = _traversal_kernel(runtime, tree.dim, dev, "ao", accel)
    offset = ORIGIN_OFFSET * tree.diagonal
    args = head + buffers + [
        np.int32(samples), np.uint32(seed & 0xFFFFFFFF), np.float32(offset),
        np.float32(max_distance), buf_counts,
    ]
    per_launch = max(1, RAYS_PER_LAUNCH // samples)
    for start in range(0, n, per_launch):
        count = min(per_launch, n - start)
        kernel(queue, (count,), None, *args, global_offset=(start,)).wait()
        bar.update(count * samples)
    cl.enqueue_copy(queue, counts, buf_counts)
    queue.finish()
    out = np.empty(n, dtype=np.int64)
    out[order] = counts
    return out


def _directions_opencl(runtime, normals: np.ndarray, samples: int, seed: int) -> np.ndarray:
    """The directions the AO kernels trace, computed on the device (used by the tests)."""
    import pyopencl as cl

    n, d = normals.shape
    ctx, queue = runtime.context, runtime.queue
    ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    out = np.empty((n * samples, 4), dtype=np.float32)
    buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    _kernels(runtime, d, _block_lanes(runtime))["sample_directions"](
        queue, (n,), None,
        cl.Buffer(ctx, ro, hostbuf=_pad4(normals)),
        cl.Buffer(ctx, ro, hostbuf=np.arange(n, dtype=np.uint32)),
        cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(sobol_table(samples, d - 1, seed=seed))),
        np.int32(samples), np.uint32(seed & 0xFFFFFFFF), buf,
    )
    cl.enqueue_copy(queue, out, buf)
    queue.finish()
    return out[:, :d].reshape(n, samples, d).astype(np.float64)


# -- numpy side -------------------------------------------------------------------------------


def _box_hits(lo, hi, o, inv_w, t_max):
    """Slab test in float64 like ``hit_boxes`` in kernels/geometry.h (which keeps the inverse
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


def _trace_numpy(tree, origins, directions, max_distance, any_hit, accel, bar):
    n = len(origins)
    t = np.empty(n)
    hit = np.empty(n, dtype=np.int64)
    trace = _trace_numpy_bvh if accel == "bvh" else _trace_numpy_brute
    for start in range(0, n, _NUMPY_RAYS_PER_STEP):
        sl = slice(start, min(n, start + _NUMPY_RAYS_PER_STEP))
        t[sl], hit[sl] = trace(tree, origins[sl], directions[sl], max_distance, any_hit)
        bar.update(sl.stop - sl.start)
    return t, hit


def _ao_numpy(tree, points, normals, samples, seed, max_distance, accel, bar):
    n = len(points)
    counts = np.empty(n, dtype=np.int64)
    offset = ORIGIN_OFFSET * tree.diagonal
    per_step = max(1, _NUMPY_RAYS_PER_STEP // samples)
    for start in range(0, n, per_step):
        sl = slice(start, min(n, start + per_step))
        w = cosine_hemisphere(normals[sl], samples, seed=seed, index_offset=start)
        o = points[sl] + offset * normals[sl]
        o = np.repeat(o, samples, axis=0)
        _, hit = _trace_numpy(
            tree, o, w.reshape(-1, tree.dim), max_distance, True, accel, _NullBar()
        )
        counts[sl] = (hit.reshape(-1, samples) >= 0).sum(1)
        bar.update((sl.stop - sl.start) * samples)
    return counts


class _NullBar:
    def update(self, n: int) -> None:
        pass


# -- public API -------------------------------------------------------------------------------


def cast_rays(
    mesh: Any,
    origins: Any,
    directions: Any,
    *,
    max_distance: float = math.inf,
    closest: bool = True,
    backend: str = "auto",
    accel: str = "bvh",
    progress: bool | None = None,
) -> RayHits:
    """Intersect rays with a simplex mesh: closest hit, or any hit.

    Parameters
    ----------
    mesh : SimplexMesh
        A mesh in R^d, d in {2, 3, 4}. Its BVH is built on first use and cached on it.
    origins : (N, d) array_like of float
    directions : (N, d) array_like of float
        Normalised here; zero-length directions are an error.
    max_distance : float
        Hits count for ``0 < t <= max_distance``.
    closest : bool
        ``True``: the nearest hit. ``False``: any hit within ``max_distance`` (faster, for
        shadow/occlusion rays; ``t`` and ``simplex`` belong to some hit, not the nearest).
    backend : {"auto", "opencl", "numpy"}
        ``"auto"`` uses OpenCL when a device works, else numpy.
    accel : {"bvh", "brute"}
        ``"brute"`` tests every simplex (for checks and benchmarks; gives the same answer).
    progress : bool, optional
        Show a tqdm bar (default: only for more than ~4M rays).

    Returns
    -------
    RayHits
        ``t`` (N,) float64, ``simplex`` (N,) int64 (-1 on a miss), ``barycentric`` (N, d) float64.
        Distances and weights of hits are recomputed in float64 on the hit simplex.

    Examples
    --------
    >>> import ao4d
    >>> tri = ao4d.SimplexMesh([[0, 0, 1], [1, 0, 1], [0, 1, 1]], [[0, 1, 2]])
    >>> hits = cast_rays(tri, [[0.2, 0.2, 0]], [[0, 0, 1]], backend="numpy")
    >>> float(hits.t[0]), int(hits.simplex[0])
    (1.0, 0)
    """
    vertices, _ = _mesh_arrays(mesh)
    d = vertices.shape[1]
    origins = as_array(origins, "origins", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True)
    directions = as_array(
        directions, "directions", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True
    )
    if len(origins) != len(directions):
        raise ValueError(
            f"`origins` and `directions` must have the same length, got {len(origins)} and {len(directions)}"
        )
    directions = _unit_rows(directions, "directions")
    max_distance = _check_distance(max_distance)
    if not isinstance(closest, (bool, np.bool_)):
        raise TypeError(f"`closest` must be a bool, got {type(closest).__name__}")
    check_choice(accel, "accel", ("bvh", "brute"))
    name, runtime = _resolve_backend(backend)
    tree = _bvh.get_bvh(mesh)
    n = len(origins)
    with _progress_bar(progress, n, "rays") as bar:
        if name == "opencl":
            _, hit = _trace_opencl(tree, runtime, origins, directions, max_distance, not closest, accel, bar)
        else:
            check_memory(n * 64.0, "the numpy ray arrays")
            _, hit = _trace_numpy(tree, origins, directions, max_distance, not closest, accel, bar)
    return _refine_hits(tree, origins, directions, hit)


def _refine_hits(tree, origins, directions, hit) -> RayHits:
    """Distances and barycentrics of the hits, recomputed in float64."""
    n, d = origins.shape
    t = np.full(n, np.inf)
    simplex = np.full(n, -1, dtype=np.int64)
    bary = np.zeros((n, d))
    rows = np.flatnonzero(hit >= 0)
    p = hit[rows].astype(np.int64)
    inv, origin = tree.inverse[p], tree.origin[p]
    nrow = inv[:, -1, :]
    o, w = origins[rows], directions[rows]
    t_hit = -np.einsum("pk,pk->p", nrow, o - origin) / np.einsum("pk,pk->p", nrow, w)
    t[rows] = t_hit
    simplex[rows] = tree.prim[p]
    bary[rows] = _bvh.barycentric(inv, origin, o + t_hit[:, None] * w)
    return RayHits(t=t, simplex=simplex, barycentric=bary)


def _query_points(mesh, at, points, normals, d):
    """Points and unit normals where AO is wanted; NaN rows mark undefined normals."""
    if (points is None) != (normals is None):
        raise ValueError("`points` and `normals` must be given together")
    if points is not None:
        points = as_array(points, "points", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True)
        normals = as_array(normals, "normals", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True)
        if len(points) != len(normals):
            raise ValueError(
                f"`points` and `normals` must have the same length, got {len(points)} and {len(normals)}"
            )
        return points, _unit_rows(normals, "normals"), np.ones(len(points), dtype=bool)
    check_choice(at, "at", ("vertices", "simplices"))
    if at == "vertices":
        points, normals = np.asarray(mesh.vertices, dtype=np.float64), _vertex_normals(mesh)
    else:
        points, normals = _simplex_points(mesh)
    length = np.linalg.norm(normals, axis=1)
    defined = np.isfinite(length) & (length > 0.5)  # unit, or zero where undefined
    return points, np.where(defined[:, None], normals, 0.0), defined


def _vertex_normals(mesh) -> np.ndarray:
    if hasattr(mesh, "vertex_normals"):
        return np.asarray(mesh.vertex_normals, dtype=np.float64)
    vertices, simplices = _mesh_arrays(mesh)
    raw = _bvh.simplex_normals(vertices[simplices])  # length ~ measure: area weighting
    total = np.zeros_like(vertices, dtype=np.float64)
    for k in range(simplices.shape[1]):
        np.add.at(total, simplices[:, k], raw)
    length = np.linalg.norm(total, axis=1, keepdims=True)
    return np.divide(total, length, out=np.zeros_like(total), where=length > 0)


def _simplex_points(mesh) -> tuple[np.ndarray, np.ndarray]:
    vertices, simplices = _mesh_arrays(mesh)
    corners = vertices[simplices].astype(np.float64)
    raw = _bvh.simplex_normals(corners)
    length = np.linalg.norm(raw, axis=1, keepdims=True)
    normals = np.divide(raw, length, out=np.zeros_like(raw), where=length > 0)
    return corners.mean(1), normals


def ambient_occlusion(
    mesh: Any,
    *,
    samples: int = 256,
    max_distance: float = math.inf,
    at: str = "vertices",
    points: Any = None,
    normals: Any = None,
    seed: int = 0,
    backend: str = "auto",
    progress: bool | None = None,
    accel: str = "bvh",
) -> np.ndarray:
    """Ambient occlusion of a simplex mesh in 2D, 3D or 4D.

    ``A(p) = (1/|B^{d-1}|) * integral over the hemisphere of V(p, w) (w . n) dw``, estimated with
    ``samples`` cosine-weighted rays per point (:func:`ao4d.sampling.cosine_hemisphere`); its
    standard error is at most ``0.5 / sqrt(samples)``.

    Parameters
    ----------
    mesh : SimplexMesh
        Occluding geometry, (d-1)-simplices in R^d, d in {2, 3, 4}.
    samples : int
        Rays per point (>= 1).
    max_distance : float
        Only hits within this distance occlude (``inf``: any hit).
    at : {"vertices", "simplices"}
        Evaluate at the vertices (with measure-weighted vertex normals) or at simplex centroids
        (with simplex normals). Ignored when ``points`` and ``normals`` are given.
    points, normals : (N, d) array_like of float, optional
        Evaluate at these points with these normals instead (normalised here; zero length is an
        error). Give both or neither.
    seed : int
        Seeds the directions; the same seed gives the same rays on every backend.
    backend : {"auto", "opencl", "numpy"}
        ``"auto"``: OpenCL when a device works, else numpy (with a warning).
    progress : bool, optional
        Show a tqdm bar (default: only for more than ~4M rays).
    accel : {"bvh", "brute"}
        ``"brute"`` tests every simplex (for checks and benchmarks; same answer).

    Returns
    -------
    occlusion : (N,) float64
        In [0, 1]; 1 = fully occluded. N is the number of vertices, simplices or points. NaN
        where the normal is undefined (an unreferenced vertex, a degenerate simplex).

    Notes
    -----
    Rays start ``1e-4`` bounding-box diagonals above the point along its normal
    (``ORIGIN_OFFSET``). Degenerate simplices are left out of the BVH: they cannot occlude.

    References
    ----------
    M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 3rd ed., 13.6.3 (Malley).

    Examples
    --------
    A point under a large parallel triangle pair at height 1 sees it in a cone of half-angle
    45 degrees with ``max_distance = sqrt(2)``: ``A = 1 - (h / L)^2 = 0.5`` in 3D.

    >>> import ao4d
    >>> roof = ao4d.SimplexMesh([[-9, -9, 1], [9, -9, 1], [9, 9, 1], [-9, 9, 1]],
    ...                         [[0, 1, 2], [0, 2, 3]])
    >>> a = ambient_occlusion(roof, points=[[0, 0, 0]], normals=[[0, 0, 1]],
    ...                       max_distance=2 ** 0.5, samples=4096, backend="numpy")
    >>> abs(float(a[0]) - 0.5) < 0.03
    True
    """
    vertices, _ = _mesh_arrays(mesh)
    d = vertices.shape[1]
    samples = check_positive_int(samples, "samples")
    max_distance = _check_distance(max_distance)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"`seed` must be an integer, got {type(seed).__name__}")
    check_choice(accel, "accel", ("bvh", "brute"))
    pts, nrm, defined = _query_points(mesh, at, points, normals, d)
    name, runtime = _resolve_backend(backend)
    tree = _bvh.get_bvh(mesh)
    occlusion = np.full(len(pts), np.nan)
    idx = np.flatnonzero(defined)
    if idx.size == 0:
        return occlusion
    pts, nrm = pts[idx], nrm[idx]
    desc = f"{d}D AO ({name})"
    with _progress_bar(progress, idx.size * samples, desc) as bar:
        if name == "opencl":
            counts = _ao_opencl(tree, runtime, pts, nrm, samples, int(seed), max_distance, accel, bar)
        else:
            counts = _ao_numpy(tree, pts, nrm, samples, int(seed), max_distance, accel, bar)
    occlusion[idx] = counts / samples
    return occlusion
