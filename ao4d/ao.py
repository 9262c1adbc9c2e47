"""Ambient occlusion on simplex meshes in 2D, 3D and 4D (OpenCL or numpy).

Definition (DESIGN.md): at a point p with unit normal n,
``A = (1/|B^{d-1}|) * integral over the hemisphere of V(p, w) (w . n) dw``, V = 1 when the ray
from p along w hits the mesh within ``max_distance``. Directions are cosine-weighted
(:mod:`ao4d.sampling`), so the estimate is the fraction of occluded rays. 1 = fully occluded.

The rays are traced by :func:`ao4d.raycast.count_occluded`: the same rays on both backends (a
shared Sobol table and per-point integer-hash offsets), through the same BVH.

Rays start at ``p + offset * n`` with ``offset = 1e-4 * (bounding-box diagonal)`` so that they do
not hit the simplices p lies on; geometry closer than that to p is not seen.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._validate import as_array, check_choice, check_memory, check_positive_int, check_seed
from .bvh.host import nondegenerate_given
from .bvh.layout import Frame
from .geometry import vertex_sums
from .mesh import SimplexMesh, as_mesh, warn_if_inside_out
from .opencl import cl
from .raycast import ACCELS, check_distance, check_rays, count_occluded, get_bvh, mesh_arrays, progress_bar, unit_rows
from .topology import GRID_EDGE_KEY

__all__ = ["ambient_occlusion", "ORIGIN_OFFSET", "OpenMeshWarning"]

ORIGIN_OFFSET = 1e-4  # times the bounding-box diagonal

# Meshes whose coordinates stay within 2**64 of the origin and whose box is at least 2**-64
# wide are traced as they are (their bytes as ever); others are recentred and scaled by a power
# of two first: a normal multiplies d - 1 lengths and its squared length 2 (d - 1), which
# overflow float64 above ~1e77 (3D) or ~1e51 (4D) and underflow below ~1e-77 / ~1e-51, where
# every normal came back NaN and so did every AO value.
_SAFE_EXPONENT = 64


class OpenMeshWarning(UserWarning):
    """AO of a mesh cut open at its grid's edge: rays leak out through the open faces."""


def warn_if_open(mesh: Any, *, stacklevel: int = 3) -> None:
    """Warn once per mesh (version) when an extracted mesh is open at its grid's edge."""
    cache = getattr(mesh, "cache", None)
    if cache is None or GRID_EDGE_KEY not in cache or cache.get("ao4d.open_warned"):
        return
    cache["ao4d.open_warned"] = True
    n_open = len(mesh.boundary_faces())
    if n_open:
        import warnings

        warnings.warn(
            f"the mesh is open ({n_open:,} boundary faces): {cache[GRID_EDGE_KEY]}; rays leak out "
            "through the open faces, so AO near them is too low",
            OpenMeshWarning,
            stacklevel=stacklevel,
        )


def _working_mesh(mesh: SimplexMesh) -> tuple[SimplexMesh, Frame | None]:
    """The mesh AO is computed on, and the frame that maps world coordinates to it (None: the
    mesh itself, in world coordinates).

    A mesh within the safe range is used as it is; another is recentred on its box and scaled by
    a power of two (:meth:`ao4d.bvh.Frame.fit`) in float64, kept in the mesh's cache. AO does
    not depend on a uniform scaling or a translation, so the result is the same.
    """
    cached = mesh.cache.get("ao4d.ao.working_mesh")
    if cached is not None:
        return cached
    vertices = mesh.vertices
    result: tuple[SimplexMesh, Frame | None] = (mesh, None)
    if vertices.size:
        lo, hi = vertices.min(0), vertices.max(0)
        with np.errstate(over="ignore"):
            extent = float(np.max(hi - lo))
        reach = float(max(np.abs(lo).max(), np.abs(hi).max()))
        if not np.isfinite(extent):
            raise ValueError(
                f"`mesh` spans {lo.min():.3g} to {hi.max():.3g}: its extent overflows float64; "
                "give its coordinates in other units"
            )
        if reach > 2.0**_SAFE_EXPONENT or 0 < extent < 2.0**-_SAFE_EXPONENT:
            frame = Frame.fit(vertices)
            result = (SimplexMesh(frame.points(vertices), mesh.simplices), frame)
    if result[1] is not None:  # never the mesh itself: a cycle would keep it (and its tree) alive
        mesh.cache["ao4d.ao.working_mesh"] = result
    return result


def _query_points(mesh, at, points, normals, d, frame: Frame | None = None):
    """Points and unit normals where AO is wanted; NaN rows mark undefined normals. Given
    points are mapped by ``frame`` into the coordinates of ``mesh`` (the working mesh)."""
    if (points is None) != (normals is None):
        raise ValueError("`points` and `normals` must be given together")
    if points is not None:
        points = as_array(points, "points", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True)
        normals = as_array(normals, "normals", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True)
        if len(points) != len(normals):
            raise ValueError(f"`points` and `normals` must have the same length, got {len(points)} and {len(normals)}")
        if frame is not None:
            points = frame.points(points)
        return points, unit_rows(normals, "normals"), np.ones(len(points), dtype=bool)
    check_choice(at, "at", ("vertices", "simplices"))
    # at the vertices, kept in the mesh's cache (cleared when the mesh changes; (V, d) values, as
    # much as the vertex normals): the normals and the degeneracy test were a third of a repeated
    # call's time at a million simplices (benchmarks guide). Per simplex it would hold 2 (S, d).
    key = "ao4d.ao.query_points.vertices"
    cached = mesh.cache.get(key) if at == "vertices" else None
    if cached is not None:
        return cached
    vertices, simplices = mesh_arrays(mesh)
    vertices, simplices = np.asarray(vertices, dtype=np.float64), np.asarray(simplices)
    # the mesh's own normals (shared with its volume, measures and vertex normals), zero where
    # the BVH's degeneracy test (relative to the simplex's size) finds no measure: an exact zero
    # test would depend on the scene's scale, as scaling rounds the corners of a flat simplex
    # off its hyperplane and its normal becomes rounding noise pointing anywhere
    raw = mesh._raw_normals
    keep = nondegenerate_given(vertices, simplices, raw)
    if not keep.all():
        raw = np.where(keep[:, None], raw, 0.0)
    if at == "vertices":
        sums = mesh._vertex_normal_sums if keep.all() else vertex_sums(raw, simplices, len(vertices))
        points, normals = vertices, _unit(sums)
    else:
        points, normals = vertices[simplices].mean(1), _unit(raw)
    length = np.linalg.norm(normals, axis=1)
    defined = np.isfinite(length) & (length > 0.5)  # unit, or zero where undefined
    query = (points, np.where(defined[:, None], normals, 0.0), defined)
    if at == "vertices":
        for array in query:
            array.flags.writeable = False
        mesh.cache[key] = query
    return query


def _unit(normals: np.ndarray) -> np.ndarray:
    """Unit rows (zero rows stay zero), components below 1e-12 set to zero.

    The directions' tangent frame (:func:`ao4d.sampling.tangent_frames`) flips with the sign of
    the last component: grid data has many normals whose exact zeros come back as +-1e-17 after
    a scaling of the scene, and their rays would change with the scale.
    """
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    unit = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    unit[np.abs(unit) < 1e-12] = 0.0
    length = np.linalg.norm(unit, axis=1, keepdims=True)
    return np.divide(unit, length, out=np.zeros_like(unit), where=length > 0)


def ambient_occlusion(
    mesh: Any,
    *,
    samples: int = 64,
    max_distance: float = math.inf,
    at: str = "vertices",
    points: Any = None,
    normals: Any = None,
    seed: int = 0,
    backend: str = "auto",
    progress: bool | None = None,
    accel: str = "bvh",
    max_rays: float | None = None,
) -> np.ndarray:
    """Ambient occlusion of a simplex mesh in 2D, 3D or 4D.

    ``A(p) = (1/|B^{d-1}|) * integral over the hemisphere of V(p, w) (w . n) dw``, estimated with
    ``samples`` cosine-weighted rays per point (:func:`ao4d.sampling.cosine_hemisphere`); its
    standard error is at most ``0.5 / sqrt(samples)``.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        Occluding geometry, (d-1)-simplices in R^d, d in {2, 3, 4}, in any form
        :func:`ao4d.mesh.as_mesh` takes (a ``SimplexMesh`` keeps its BVH between calls).
    samples : int
        Rays per point (>= 1); 64 by default, as in :func:`ao4d.render` and ``ao4d ao``.
    max_distance : float
        Only hits within this distance occlude (``inf``: any hit).
    at : {"vertices", "simplices"}
        Evaluate at the vertices (with measure-weighted vertex normals) or at simplex centroids
        (with simplex normals). Ignored when ``points`` and ``normals`` are given.
    points, normals : (N, d) array_like of float, optional
        Evaluate at these points with these normals instead (normalised here; zero length is an
        error). Give both or neither.
    seed : int
        Seeds the directions, in ``[0, 2**32)`` (a 32-bit seed; others are refused); the same
        seed gives the same rays on every backend.
    backend : {"auto", "opencl", "numpy"}
        ``"auto"``: OpenCL when a device works, else numpy (with a warning).
    progress : bool, optional
        Show progress (default: only for more than ~4M rays): a bar on a terminal, a line every
        few seconds in a log.
    accel : {"bvh", "brute"}
        ``"brute"`` tests every simplex (for checks and benchmarks; same answer).
    max_rays : float, optional
        Refuse, before any work, to trace more rays than this (default
        ``ao4d.raycast.MAX_RAYS`` of the backend that runs: about half an hour of work at its
        typical rate); ``math.inf`` lifts the limit.

    Returns
    -------
    occlusion : (N,) float64
        In [0, 1]; 1 = fully occluded. N is the number of vertices, simplices or points. NaN
        where the normal is undefined: an unreferenced vertex, a degenerate simplex
        (``at="simplices"``). A vertex whose every simplex has zero measure (extraction makes
        such simplices where values equal the level exactly) has no normal of its own; it sits
        where its neighbours in those simplices sit, so it takes their mean AO; a cluster of
        such simplices with no other neighbour (a grid point exactly at the level, surrounded by
        the solid) takes the mean AO of the two hemispheres about the first axis. So every
        vertex a simplex uses gets a finite AO at ``at="vertices"``.

    Warns
    -----
    OpenMeshWarning
        Once per mesh, when a mesh from :func:`ao4d.extract` is open because the solid touches
        the grid's edge (``closed=True`` closes it).

    Notes
    -----
    Rays start ``1e-4`` bounding-box diagonals above the point along its normal
    (``ORIGIN_OFFSET``). Degenerate simplices (the BVH's test, relative to each simplex's size:
    :func:`ao4d.bvh.host.nondegenerate`) are left out of the BVH, cannot occlude and add nothing
    to vertex normals; normal components below 1e-12 count as zero. So the result does not
    depend on the scene's scale. A mesh farther than ``2**64`` from the origin, or smaller than
    ``2**-64`` across, is recentred and scaled by a power of two first (``max_distance`` and
    ``points`` with it), in float64: its normals' products would overflow or underflow.

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
    mesh = as_mesh(mesh)
    vertices, _ = mesh_arrays(mesh)
    d = vertices.shape[1]
    samples = check_positive_int(samples, "samples")
    max_distance = check_distance(max_distance)
    seed = check_seed(seed)
    check_choice(accel, "accel", ACCELS)
    work, frame = _working_mesh(mesh)
    if frame is not None and math.isfinite(max_distance):  # > 0, and stays > 0 in the frame
        max_distance = max(frame.length(max_distance), np.finfo(np.float64).tiny)
    pts, nrm, defined = _query_points(work, at, points, normals, d, frame)
    runtime = cl.resolve_backend(backend)
    check_rays(
        int(defined.sum()) * samples,
        cl.backend_name(runtime),
        max_rays,
        what=f"`samples`={samples} at {int(defined.sum())} points",
        hint="use fewer `samples` or points, or pass max_rays=math.inf (CLI: --force)",
    )
    # the Sobol table holds samples x (d - 1) float64 values (and a float32 copy for the device)
    check_memory(samples * d * 12.0, f"the direction table for samples={samples}", hint="use fewer `samples`")
    if points is None:  # at the mesh's own points: inward normals look into the solid
        warn_if_inside_out(work, "every hemisphere looks into the solid (AO = 1 everywhere)")
    warn_if_open(mesh)
    mesh = work  # from here on, in the working frame (the mesh itself when within range)
    tree = get_bvh(mesh, runtime=runtime)  # built by the device that traces it
    occlusion = np.full(len(pts), np.nan)
    idx = np.flatnonzero(defined)
    if idx.size == 0:
        return occlusion
    pts, nrm = pts[idx], nrm[idx]
    # how every ray of this call is traced (the AO rays and those of points without a normal)
    trace = dict(
        samples=samples,
        seed=seed,
        offset=ORIGIN_OFFSET * tree.world_diagonal,
        max_distance=max_distance,
        runtime=runtime,
        accel=accel,
    )
    desc = f"{d}D AO ({cl.backend_name(runtime)})"
    with progress_bar(progress, idx.size * samples, desc) as bar:
        counts = count_occluded(mesh, pts, nrm, **trace, bar=bar)
    occlusion[idx] = counts / samples
    if points is None and at == "vertices":
        simplices = np.asarray(mesh_arrays(mesh)[1])
        _fill_flat_vertices(occlusion, simplices)
        alone = np.flatnonzero(_referenced(len(occlusion), simplices) & np.isnan(occlusion))
        if alone.size:  # clusters of zero measure only: no neighbour has an AO to share
            occlusion[alone] = _both_sides(mesh, np.asarray(mesh_arrays(mesh)[0])[alone], trace)
    return occlusion


def _referenced(n: int, simplices: np.ndarray) -> np.ndarray:
    used = np.zeros(n, dtype=bool)
    used[simplices.ravel()] = True
    return used


def _both_sides(mesh, pts: np.ndarray, trace: dict[str, Any]) -> np.ndarray:
    """AO of points without a normal: the mean over the two hemispheres about the first axis.

    A cluster of zero-measure simplices that touches nothing else (a grid point exactly at the
    level whose neighbours all lie on the solid side: a hole of no volume) has no normal and no
    neighbour to take an AO from; rays in every direction see what surrounds the point (all of
    them hit when it is enclosed by the solid).
    """
    d = pts.shape[1]
    axis = np.zeros((len(pts), d))
    axis[:, 0] = 1.0
    total = np.zeros(len(pts))
    for sign in (1.0, -1.0):
        total += count_occluded(mesh, pts, sign * axis, **trace)
    return total / (2 * trace["samples"])


def _fill_flat_vertices(occlusion: np.ndarray, simplices: np.ndarray) -> None:
    """Give referenced vertices without AO (only zero-measure simplices around them) the mean
    AO of the vertices they share a simplex with, spreading until nothing more can be filled."""
    referenced = _referenced(len(occlusion), simplices)
    while True:  # each pass fills one more ring of the zero-measure clusters
        missing = referenced & np.isnan(occlusion)
        if not missing.any():
            return
        rows = simplices[missing[simplices].any(axis=1)]
        values = occlusion[rows]
        known = ~np.isnan(values)
        total = np.zeros(len(occlusion))
        count = np.zeros(len(occlusion))
        row_sum = np.where(known, values, 0.0).sum(1)
        row_n = known.sum(1)
        for k in range(rows.shape[1]):
            np.add.at(total, rows[:, k], row_sum)
            np.add.at(count, rows[:, k], row_n)
        fill = missing & (count > 0)
        if not fill.any():
            return
        occlusion[fill] = total[fill] / count[fill]
