"""Ray casting on simplex meshes in 2D, 3D and 4D: the public traversals.

Both backends trace the same rays through the same BVH (:mod:`ao4d.bvh`) with the same
ray-simplex test and barycentric tolerance ``ao4d.bvh.BARY_EPS``. The OpenCL kernels
(:mod:`ao4d.rays.launches`) compute in float32 and traverse the tree's wide form; the numpy
traversal (:mod:`ao4d.rays.reference`) walks the binary tree in float64.

Three traversals: :func:`cast_rays` (closest or any hit of given rays; it validates, then calls
:func:`trace`, which :func:`ao4d.render` calls directly with its :class:`~ao4d.rays.rows.Tracer`:
the mesh's tree and device copies fetched once on a resolved backend), :func:`count_occluded`
(any-hit counts of cosine-distributed rays generated on the device: ambient occlusion) and
:func:`traversal_counts` (the nodes and leaves each AO ray visits). The trees and their device
copies come from :func:`ao4d.bvh.get_bvh` and :func:`ao4d.bvh.device_tree` (cached on the mesh).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._validate import check_bool, check_choice, check_memory
from ..bvh import get_bvh
from ..mesh import as_mesh
from ..opencl import cl
from .launches import AO_TRAVERSALS, _ao_opencl, _trace_opencl
from .reference import _NUMPY_RAYS_PER_STEP, _ao_numpy, _trace_numpy
from .refine import _refine_hits, _refine_on_device, _refines_on_device
from .rows import Tracer, _float_rows, _NullBar, _Rays, _Results, check_distance, mesh_arrays, progress_bar

__all__ = ["ACCELS", "RayHits", "cast_rays", "trace", "count_occluded", "traversal_counts"]


ACCELS = ("bvh", "brute")


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

    ``t`` and ``barycentric`` are recomputed in float64 on the hit simplices when first read:
    callers that only ask whether rays hit (shadow and occlusion rays) never pay for them. For
    closest hits their arrays are made during the trace, with the misses' values, while the
    device works; any-hit calls make them only when they are read.
    """

    __slots__ = ("simplex", "_t", "_barycentric", "_pending")

    def __init__(
        self, t: np.ndarray | None, simplex: np.ndarray, barycentric: np.ndarray | None, *, pending: Any = None
    ) -> None:
        self.simplex = simplex
        self._t, self._barycentric, self._pending = t, barycentric, pending

    def _resolve(self) -> None:
        if self._pending is not None:
            self._t, self._barycentric = self._pending()
            self._pending = None

    @property
    def t(self) -> np.ndarray:
        self._resolve()
        return self._t

    @property
    def barycentric(self) -> np.ndarray:
        self._resolve()
        return self._barycentric

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: rays that hit."""
        return self.simplex >= 0

    def __repr__(self) -> str:
        return f"RayHits({len(self.simplex)} rays, {int(self.hit.sum())} hits)"


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
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        A mesh in R^d, d in {2, 3, 4}, in any form :func:`ao4d.mesh.as_mesh` takes. A
        ``SimplexMesh`` builds its BVH on first use and keeps it; the other forms are converted,
        and their tree built, on every call.
    origins : (N, d) array_like of float
        Where the rays start.
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

    Notes
    -----
    On CPUs, any-hit rays in consecutive rows with the same origin (shadow and AO rays from
    shared points, a pinhole camera's rays) are traced together, up to 64 at a time, as the AO
    kernel traces a point's rays: put such rays next to each other.

    Examples
    --------
    >>> import ao4d
    >>> tri = ao4d.SimplexMesh([[0, 0, 1], [1, 0, 1], [0, 1, 1]], [[0, 1, 2]])
    >>> hits = cast_rays(tri, [[0.2, 0.2, 0]], [[0, 0, 1]], backend="numpy")
    >>> float(hits.t[0]), int(hits.simplex[0])
    (1.0, 0)
    """
    mesh = as_mesh(mesh)
    vertices, _ = mesh_arrays(mesh)
    d = vertices.shape[1]
    # float32 or float64 inputs are kept as they are: each launch converts its own rays
    origins = _float_rows(origins, "origins", d)
    directions = _float_rows(directions, "directions", d)
    if len(origins) != len(directions):
        raise ValueError(
            f"`origins` and `directions` must have the same length, got {len(origins)} and {len(directions)}"
        )
    max_distance = check_distance(max_distance)
    closest = check_bool(closest, "closest")
    check_choice(accel, "accel", ACCELS)
    runtime = cl.resolve_backend(backend)
    if len(origins) == 0:  # no tree is needed to miss
        return trace(None, origins, directions)
    with progress_bar(progress, len(origins), "rays") as bar:
        return trace(
            Tracer.of(mesh, runtime),
            origins,
            directions,
            max_distance=max_distance,
            closest=closest,
            accel=accel,
            bar=bar,
        )


def trace(
    tracer: Tracer | None,
    origins: np.ndarray,
    directions: np.ndarray,
    *,
    max_distance: float = math.inf,
    closest: bool = True,
    accel: str = "bvh",
    bar: Any = None,
) -> RayHits:
    """:func:`cast_rays` on trusted inputs: one batch of rays, no validation.

    Parameters
    ----------
    tracer : Tracer
        The mesh's tree on its backend (None only when there are no rays).
    origins, directions : (N, d) float32 or float64 numpy.ndarray
        Finite rows; directions non-zero (normalised here).
    max_distance : float
        Hits count for ``0 < t <= max_distance`` (> 0, inf allowed).
    closest : bool
        The nearest hit, or any hit.
    accel : {"bvh", "brute"}
        As for :func:`cast_rays`.
    bar : tqdm-like, optional
        Counts the rays as they are traced.

    Returns
    -------
    RayHits
        As :func:`cast_rays` returns.
    """
    n, d = origins.shape
    if n == 0:  # OpenCL refuses buffers of zero bytes
        return RayHits(t=np.zeros(0), simplex=np.zeros(0, dtype=np.int64), barycentric=np.zeros((0, d)))
    bar = _NullBar() if bar is None else bar
    tree, runtime = tracer.tree, tracer.runtime
    rays = _Rays(tree.frame, origins, directions)
    reach = tree.frame.length(max_distance)
    results = _Results(tree, tracer.device if runtime is not None else None, n, closest)
    if runtime is not None:
        _trace_opencl(tracer.device, tree, runtime, rays, reach, not closest, accel, bar, results)
    else:
        check_memory(min(n, _NUMPY_RAYS_PER_STEP) * 64.0 + n * 8.0, "the numpy ray arrays")
        results.launched(0, n)
        results.answered(0, _trace_numpy(tree, rays, reach, not closest, accel, bar))
    rows, p = results.hits()
    simplex = results.simplex
    hit_simplex = simplex[rows]
    # the hit rays as they are now (the caller may change the arrays); refined when t is read
    o, w = np.take(rays.origins, rows, axis=0), np.take(rays.directions, rows, axis=0)  # faster than [rows]
    refined = results.refined
    if _refines_on_device(tree, runtime):
        pending = lambda: _refine_on_device(tracer, n, rows, hit_simplex, o, w, refined)  # noqa: E731
    else:
        inv_length = rays.inv_length_of(rows, w)
        pending = lambda: _refine_hits(tree, n, rows, p, o, w, inv_length(), refined)  # noqa: E731
    return RayHits(None, simplex, None, pending=pending)


def count_occluded(
    mesh: Any,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    samples: int,
    seed: int,
    offset: float,
    max_distance: float,
    runtime: Any,
    accel: str = "bvh",
    bar: Any = None,
    index: np.ndarray | None = None,
    first: int = 0,
) -> np.ndarray:
    """Per point, how many of ``samples`` cosine-weighted rays hit ``mesh`` (any hit).

    The rays start at ``point + offset * normal``; their directions come from
    :func:`ao4d.sampling.cosine_hemisphere` (on the device the same ones are generated in the
    kernel). Points, ``offset`` and ``max_distance`` are in world units and are mapped into the
    tree's frame here. No validation: :func:`ao4d.ao.ambient_occlusion` checks the inputs.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        The occluding geometry, in any form :func:`ao4d.mesh.as_mesh` takes.
    points, normals : (N, d) float64
        Query points and their unit normals.
    samples, seed : int
        Rays per point, and the seed of the directions' random shifts.
    offset, max_distance : float
        How far above the point the rays start, and their reach (world units).
    runtime : ao4d.opencl.cl.Runtime or None
        The OpenCL device, or None for the numpy traversal.
    accel : {"bvh", "brute"}
        Traverse the BVH, or test every simplex.
    bar : tqdm-like, optional
        Updated with the number of rays traced.
    index : (N,) int, optional
        The points' global indices, which seed their directions' shifts (default: their
        positions in ``points``): a point keeps its rays whichever points are traced with it.
    first : int
        Trace directions ``first`` to ``first + samples - 1`` of each point's sequence (the
        rows of the Sobol table of ``seed``): a later call continues an earlier one's rays.

    Returns
    -------
    counts : (N,) int64
        Rays of each point that hit.
    """
    mesh = as_mesh(mesh)
    tree = get_bvh(mesh, runtime=runtime)
    bar = _NullBar() if bar is None else bar
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    frame = tree.frame
    args = (frame.points(points), normals, samples, seed, frame.length(offset), frame.length(max_distance), accel, bar)
    if runtime is not None:
        return _ao_opencl(mesh, tree, runtime, *args, index=index, first=first)
    return _ao_numpy(tree, *args, index=index, first=first)


def traversal_counts(
    mesh: Any,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    samples: int,
    offset: float,
    runtime: Any,
    seed: int = 0,
    max_distance: float = math.inf,
    traversal: str = "rays",
    detail: bool = False,
) -> tuple[float, ...]:
    """Wide nodes visited and leaf blocks tested per AO ray, on average (tree quality).

    Traces the rays of :func:`count_occluded` with a debug build of the kernels
    (``-D COUNT_VISITS``), which also counts, and returns ``(nodes per ray, blocks per ray)``.

    Parameters
    ----------
    mesh, points, normals, samples, offset, runtime, seed, max_distance : see count_occluded
        As in :func:`count_occluded`.
    traversal : {"rays", "packet"}
        ``"rays"``: one ray at a time (every visit is one ray's); ``"packet"``: the rays of a
        point together, where a node fetched once serves every ray of the packet.
    detail : bool
        Also return the box tests (ray, wide node) and block tests (ray, block) per ray:
        ``(nodes, blocks, node tests, block tests)``; for ``"rays"`` these equal the first two.

    Returns
    -------
    tuple of float
        ``(nodes per ray, blocks per ray)``, or the four figures with ``detail``.
    """
    mesh = as_mesh(mesh)
    check_choice(traversal, "traversal", AO_TRAVERSALS)
    detail = check_bool(detail, "detail")
    tree = get_bvh(mesh, runtime=runtime)
    if len(points) == 0:
        return (math.nan,) * (4 if detail else 2)
    visits = np.zeros((len(points), 4), dtype=np.int64)
    frame = tree.frame
    _ao_opencl(
        mesh,
        tree,
        runtime,
        frame.points(points),
        normals,
        samples,
        seed,
        frame.length(offset),
        frame.length(max_distance),
        "bvh",
        _NullBar(),
        visits=visits,
        traversal=traversal,
    )
    per_ray = visits.sum(0) / (len(points) * samples)
    return tuple(float(x) for x in per_ray[: 4 if detail else 2])
