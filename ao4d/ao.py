"""Ambient occlusion on simplex meshes in 2D, 3D and 4D (OpenCL or numpy).

Definition (DESIGN.md): at a point p with unit normal n,
``A = (1/|B^{d-1}|) * integral over the hemisphere of V(p, w) (w . n) dw``, V = 1 when the ray
from p along w hits the mesh within ``max_distance``. Directions are cosine-weighted
(:mod:`ao4d.sampling`), so the estimate is the fraction of occluded rays. 1 = fully occluded.

The rays are traced by :func:`ao4d.rays.api.count_occluded`: the same rays on both backends (a
shared Sobol table and per-point integer-hash offsets), through the same BVH.

Rays start at ``p + offset * n`` with ``offset = 1e-4 * (bounding-box diagonal)`` so that they do
not hit the simplices p lies on; geometry closer than that to p is not seen.

With a ``tolerance``, each point traces ``REPLICATES`` independently scrambled Sobol sequences
(each with its own seed, derived from the call's seed with :class:`numpy.random.SeedSequence`),
extended in rounds; a point stops when the Student-t half-width of its replicates' mean is at
most the tolerance, after at least :func:`minimum_samples` rays. The user guide's "AO to a
stated accuracy" describes the estimator and its measured coverage.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from ._budget import check_rays
from ._validate import (
    as_array,
    as_real,
    check_bool,
    check_choice,
    check_int,
    check_memory,
    check_positive_int,
    check_seed,
)
from .bvh import get_bvh
from .bvh.host import nondegenerate_given
from .bvh.layout import Frame
from .geometry import vertex_sums
from .mesh import SimplexMesh, as_mesh, warn_if_inside_out
from .opencl import cl
from .rays.api import ACCELS, count_occluded
from .rays.rows import check_distance, mesh_arrays, progress_bar, unit_rows
from .topology import GRID_EDGE_KEY

__all__ = [
    "ambient_occlusion",
    "minimum_samples",
    "replicate_seed",
    "OcclusionEstimate",
    "ORIGIN_OFFSET",
    "REPLICATES",
    "OpenMeshWarning",
]

ORIGIN_OFFSET = 1e-4  # times the bounding-box diagonal

# AO to a tolerance: independently scrambled Sobol sequences per point (replicates), traced
# together in rounds that extend every replicate by a factor of about GROWTH; the fewest points
# a replicate starts with
REPLICATES = 8
GROWTH = 1.5
MIN_POINTS = 4

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


class OcclusionEstimate(tuple):
    """``(occlusion, error)``, from ``ambient_occlusion(..., return_error=True)``.

    A pair, so ``occlusion, error = ambient_occlusion(mesh, tolerance=0.01, return_error=True)``
    unpacks it; ``rays`` holds the rays each point traced.

    Attributes
    ----------
    occlusion : (N,) float64 numpy.ndarray
        The AO values, as ``ambient_occlusion`` returns them without ``return_error``.
    error : (N,) float64 numpy.ndarray
        Their standard errors (NaN where the AO is NaN).
    rays : (N,) int64 numpy.ndarray
        Rays traced per point (0 where none were: undefined normals, and the vertices that take
        their neighbours' values).
    """

    occlusion: np.ndarray
    error: np.ndarray
    rays: np.ndarray

    def __new__(cls, occlusion: np.ndarray, error: np.ndarray, rays: np.ndarray) -> OcclusionEstimate:
        self = super().__new__(cls, (occlusion, error))
        self.occlusion, self.error, self.rays = occlusion, error, rays
        return self

    def __repr__(self) -> str:
        return f"OcclusionEstimate(occlusion=<{self.occlusion.size} values>, error=..., rays={int(self.rays.sum()):,})"


def minimum_samples(tolerance: float, confidence: float = 0.95) -> int:
    """The fewest rays a point traces before its AO may stop at ``tolerance``.

    A point whose ``N`` rays all escape (or all hit) has a zero sample variance; that run is
    credible at ``confidence`` only when an occlusion of ``tolerance`` would make it unlikely:
    ``(1 - tolerance)^N <= 1 - confidence``, so ``N >= log(1 - confidence) / log(1 - tolerance)``
    (about ``3 / tolerance`` at 95 %: the "rule of three"). The rays are shared equally by the
    ``REPLICATES`` replicates, each of at least ``MIN_POINTS`` rays.

    Parameters
    ----------
    tolerance : float
        In (0, 1): the half-width the AO must reach.
    confidence : float
        In (0, 1): the interval's confidence level.

    Returns
    -------
    int
        ``REPLICATES * max(MIN_POINTS, ceil(N / REPLICATES))``.

    Examples
    --------
    >>> minimum_samples(0.01), minimum_samples(0.02), minimum_samples(0.1)
    (304, 152, 32)
    """
    tolerance = as_real(tolerance, "tolerance", gt=0, lt=1)
    confidence = as_real(confidence, "confidence", gt=0, lt=1)
    rays = max(1, math.ceil(math.log1p(-confidence) / math.log1p(-tolerance) * (1 - 1e-12)))
    return max(MIN_POINTS, -(-rays // REPLICATES)) * REPLICATES


def replicate_seed(seed: int, replicate: int) -> int:
    """The 32-bit seed of a replicate: ``SeedSequence(seed, spawn_key=(replicate,))``'s first word.

    Parameters
    ----------
    seed : int
        The call's seed, in ``[0, 2**32)``.
    replicate : int
        The replicate's number (0 to ``REPLICATES - 1``).

    Returns
    -------
    int
        The seed of that replicate's Sobol scrambling and per-point shifts.
    """
    return int(np.random.SeedSequence(seed, spawn_key=(replicate,)).generate_state(1)[0])


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
    # call's time at a million simplices (the benchmarks log). Per simplex it would hold 2 (S, d).
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
    tolerance: float | None = None,
    confidence: float = 0.95,
    max_samples: int = 4096,
    return_error: bool = False,
) -> np.ndarray | OcclusionEstimate:
    """Ambient occlusion of a simplex mesh in 2D, 3D or 4D.

    ``A(p) = (1/|B^{d-1}|) * integral over the hemisphere of V(p, w) (w . n) dw``, estimated with
    ``samples`` cosine-weighted rays per point (:func:`ao4d.sampling.cosine_hemisphere`); its
    standard error is at most ``0.5 / sqrt(samples)``. Or, with ``tolerance``, to a stated
    accuracy: each point traces rays until its AO is within ``tolerance`` at ``confidence``.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        Occluding geometry, (d-1)-simplices in R^d, d in {2, 3, 4}, in any form
        :func:`ao4d.mesh.as_mesh` takes (a ``SimplexMesh`` keeps its BVH between calls).
    samples : int
        Rays per point (>= 1); 64 by default, as in :func:`ao4d.render` and ``ao4d ao``. Left
        at its default when ``tolerance`` is given (the two are exclusive).
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
        ``ao4d._budget.MAX_RAYS`` of the backend that runs: about half an hour of work at its
        typical rate); ``math.inf`` lifts the limit. With ``tolerance`` the most rays any
        point may take (``max_samples``) count.
    tolerance : float, optional
        In (0, 1): trace each point until the half-width of its AO's confidence interval is at
        most this, in rounds that extend ``REPLICATES`` independently scrambled Sobol sequences
        (whose hit fractions are unbiased and independent), never fewer than
        :func:`minimum_samples` rays and at most ``max_samples``. ``None`` (default): a fixed
        ``samples`` rays per point, the rays and bytes of earlier versions.
    confidence : float
        In (0, 1): the confidence level of the interval (0.95).
    max_samples : int
        With ``tolerance``: the most rays a point traces (a multiple of ``REPLICATES``: the
        rest is not used); at least :func:`minimum_samples` of the tolerance. A point that reaches it stops there,
        and its ``error`` says how good its AO is.
    return_error : bool
        Also return each value's standard error, as an :class:`OcclusionEstimate`
        ``(occlusion, error)`` (with ``.rays``, the rays per point). With ``tolerance``: the
        replicates' standard error (see Notes); with fixed ``samples``: that of independent
        rays, ``sqrt(A (1 - A) / samples)`` (the stratified rays do better; 0 where all rays
        agree).

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
        vertex a simplex uses gets a finite AO at ``at="vertices"``. With ``return_error``, an
        :class:`OcclusionEstimate`, the pair ``(occlusion, error)``.

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

    With ``tolerance``, replicate ``k`` (``k < REPLICATES = 8``) of a point is the start of its
    own scrambled Sobol sequence (seed :func:`replicate_seed` ``(seed, k)``, and a shift hashed
    from the point's index), so each replicate's hit fraction ``Y_k`` over its ``n`` rays is an
    unbiased estimate of ``A``, independent of the others. Each round extends every replicate
    of the points still going (``n`` grows by about 1.5 a round, from
    ``minimum_samples / 8``); the AO is ``mean(Y)`` and its standard error ``se = s / sqrt(8)``,
    ``s`` the replicates' sample standard deviation. A point stops when
    ``t_7((1 + confidence) / 2) * se <= tolerance`` (Student's t with 7 degrees of freedom) or
    when it reaches ``max_samples``. Measured on analytic scenes and a dense 4D shape (the user
    guide), 97-99 % of the points end within ``tolerance`` of the exact AO at
    ``confidence=0.95``. Only the points still going are traced in each round, so the rays go
    where the AO is hard. The rays of a point depend only on ``seed``, its index and the
    replicate: the result is the same bytes however the work is split into launches.

    References
    ----------
    M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 3rd ed., 13.6.3 (Malley).
    P. L'Ecuyer, C. Lemieux, *Recent advances in randomized quasi-Monte Carlo methods*, 2002.

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

    To a stated accuracy, with the standard error:

    >>> a, err = ambient_occlusion(roof, points=[[0, 0, 0]], normals=[[0, 0, 1]],
    ...                            max_distance=2 ** 0.5, tolerance=0.05, return_error=True,
    ...                            backend="numpy")
    >>> abs(float(a[0]) - 0.5) < 0.05, bool(err[0] < 0.05 / 2)
    (True, True)
    """
    mesh = as_mesh(mesh)
    vertices, _ = mesh_arrays(mesh)
    d = vertices.shape[1]
    samples = check_positive_int(samples, "samples")
    max_distance = check_distance(max_distance)
    seed = check_seed(seed)
    check_choice(accel, "accel", ACCELS)
    rule = _tolerance_rule(tolerance, confidence, max_samples, samples)
    return_error = check_bool(return_error, "return_error")
    work, frame = _working_mesh(mesh)
    if frame is not None and math.isfinite(max_distance):  # > 0, and stays > 0 in the frame
        max_distance = max(frame.length(max_distance), np.finfo(np.float64).tiny)
    pts, nrm, defined = _query_points(work, at, points, normals, d, frame)
    runtime = cl.resolve_backend(backend)
    per_point = samples if rule is None else rule.max_points * REPLICATES
    check_rays(
        int(defined.sum()) * per_point,
        cl.backend_name(runtime),
        max_rays,
        what=f"`samples`={samples} at {int(defined.sum())} points"
        if rule is None
        else f"`max_samples`={per_point} at {int(defined.sum())} points (at worst)",
        hint="use fewer `samples` or points, or pass max_rays=math.inf (CLI: --force)"
        if rule is None
        else "lower `max_samples`, raise `tolerance`, or pass max_rays=math.inf (CLI: --force)",
    )
    # the Sobol table holds samples x (d - 1) float64 values (and a float32 copy for the device)
    check_memory(samples * d * 12.0, f"the direction table for samples={samples}", hint="use fewer `samples`")
    if points is None:  # at the mesh's own points: inward normals look into the solid
        warn_if_inside_out(work, "every hemisphere looks into the solid (AO = 1 everywhere)")
    warn_if_open(mesh)
    mesh = work  # from here on, in the working frame (the mesh itself when within range)
    tree = get_bvh(mesh, runtime=runtime)  # built by the device that traces it
    occlusion = np.full(len(pts), np.nan)
    error = np.full(len(pts), np.nan)
    rays = np.zeros(len(pts), dtype=np.int64)
    idx = np.flatnonzero(defined)
    if idx.size == 0:
        return OcclusionEstimate(occlusion, error, rays) if return_error else occlusion
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
    with progress_bar(progress, idx.size * per_point, desc) as bar:
        if rule is None:
            counts = count_occluded(mesh, pts, nrm, **trace, bar=bar)
            occlusion[idx] = counts / samples
            error[idx] = _binomial_error(occlusion[idx], samples)
            rays[idx] = samples
        else:
            occlusion[idx], error[idx], rays[idx] = _to_tolerance(mesh, pts, nrm, idx, trace, rule, bar)
    if points is None and at == "vertices":
        simplices = np.asarray(mesh_arrays(mesh)[1])
        _fill_flat_vertices(occlusion, simplices, error)
        alone = np.flatnonzero(_referenced(len(occlusion), simplices) & np.isnan(occlusion))
        if alone.size:  # clusters of zero measure only: no neighbour has an AO to share
            where = np.asarray(mesh_arrays(mesh)[0])[alone]
            occlusion[alone], error[alone], rays[alone] = _both_sides(mesh, where, alone, trace, rule)
    return OcclusionEstimate(occlusion, error, rays) if return_error else occlusion


class _Rule(NamedTuple):
    """How AO to a tolerance runs: the checked parameters; points per replicate."""

    tolerance: float
    confidence: float
    first_points: int
    max_points: int

    def schedule(self) -> list[int]:
        """Points per replicate after each round: from ``first_points`` up by ``GROWTH``."""
        steps = [self.first_points]
        while steps[-1] < self.max_points:
            steps.append(min(self.max_points, max(steps[-1] + 1, math.ceil(steps[-1] * GROWTH))))
        return steps


def _tolerance_rule(tolerance: Any, confidence: Any, max_samples: Any, samples: int) -> _Rule | None:
    """The checked tolerance parameters (None: fixed ``samples``), before any work."""
    confidence = as_real(confidence, "confidence", gt=0, lt=1)
    max_samples = check_int(max_samples, "max_samples")
    if tolerance is None:
        return None
    tolerance = as_real(tolerance, "tolerance", gt=0, lt=1)
    if samples != 64:
        raise ValueError(
            f"give `samples` ({samples}) or `tolerance` ({tolerance:g}), not both: with a tolerance "
            "each point traces as many rays as it needs, at most `max_samples`"
        )
    fewest = minimum_samples(tolerance, confidence)
    if max_samples < fewest:
        raise ValueError(
            f"`max_samples` must be >= {fewest} for tolerance={tolerance:g} at confidence="
            f"{confidence:g} (the fewest rays that make a run of all-escaping or all-hitting rays "
            f"credible, shared by {REPLICATES} replicates), got {max_samples}"
        )
    return _Rule(tolerance, confidence, fewest // REPLICATES, max_samples // REPLICATES)


def _binomial_error(occlusion: np.ndarray, samples: int) -> np.ndarray:
    """Standard error of a hit fraction of ``samples`` independent rays."""
    return np.sqrt(occlusion * (1.0 - occlusion) / samples)


def _replicate_error(hits: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Standard errors of the mean of the replicates' hit fractions (``ambient_occlusion``'s
    Notes), from the integer hit counts (P, REPLICATES) over ``points`` (P,) rays a replicate:
    the spread is an exact integer, so the bits do not depend on the order of the work."""
    r = hits.shape[1]
    total = hits.sum(1)
    spread = r * (hits * hits).sum(1) - total * total  # r (r - 1) n^2 s^2, an exact integer >= 0
    variance = spread / (r * (r - 1)) / (points * points.astype(np.float64))
    return np.sqrt(variance / r)


def _to_tolerance(mesh, pts, nrm, index, trace: dict[str, Any], rule: _Rule, bar) -> tuple[np.ndarray, ...]:
    """AO, standard error and rays per point: every replicate of the points still going
    extended round by round until a point's half-width is at most ``rule.tolerance`` (or its
    replicates have ``rule.max_points`` rays each)."""
    from scipy.special import stdtrit

    m = len(pts)
    hits = np.zeros((m, REPLICATES), dtype=np.int64)
    points = np.zeros(m, dtype=np.int64)
    active = np.arange(m)
    index = np.asarray(index, dtype=np.int64)
    quantile = float(stdtrit(REPLICATES - 1, 0.5 + rule.confidence / 2))
    seeds = [replicate_seed(trace["seed"], k) for k in range(REPLICATES)]
    start = 0
    for stop in rule.schedule():
        for k, seed in enumerate(seeds):
            step = {**trace, "samples": stop - start, "seed": seed}
            hits[active, k] += count_occluded(
                mesh, pts[active], nrm[active], **step, first=start, bar=bar, index=index[active]
            )
        points[active] = stop
        half = quantile * _replicate_error(hits[active], points[active])
        active = active[~(half <= rule.tolerance)]
        if active.size == 0:
            break
        start = stop
    rays = REPLICATES * points
    return hits.sum(1) / rays, _replicate_error(hits, points), rays


def _referenced(n: int, simplices: np.ndarray) -> np.ndarray:
    used = np.zeros(n, dtype=bool)
    used[simplices.ravel()] = True
    return used


def _both_sides(mesh, pts: np.ndarray, index: np.ndarray, trace: dict[str, Any], rule: _Rule | None):
    """AO of points without a normal: the mean over the two hemispheres about the first axis.

    A cluster of zero-measure simplices that touches nothing else (a grid point exactly at the
    level whose neighbours all lie on the solid side: a hole of no volume) has no normal and no
    neighbour to take an AO from; rays in every direction see what surrounds the point (all of
    them hit when it is enclosed by the solid). Returns the AO, its standard error and the rays
    per point; with a tolerance each hemisphere is traced to it (the second one's rays hashed
    from the point's index plus ``2**31``).
    """
    d = pts.shape[1]
    axis = np.zeros((len(pts), d))
    axis[:, 0] = 1.0
    if rule is None:
        samples = trace["samples"]
        total = np.zeros(len(pts))
        for sign in (1.0, -1.0):
            total += count_occluded(mesh, pts, sign * axis, **trace)
        occlusion = total / (2 * samples)
        return occlusion, _binomial_error(occlusion, 2 * samples), np.full(len(pts), 2 * samples)
    sides = [
        _to_tolerance(mesh, pts, s * axis, index + k * 2**31, trace, rule, None) for k, s in enumerate((1.0, -1.0))
    ]
    (a, ea, ra), (b, eb, rb) = sides
    return (a + b) / 2, np.hypot(ea, eb) / 2, ra + rb


def _fill_flat_vertices(occlusion: np.ndarray, simplices: np.ndarray, error: np.ndarray | None = None) -> None:
    """Give referenced vertices without AO (only zero-measure simplices around them) the mean
    AO of the vertices they share a simplex with, spreading until nothing more can be filled;
    ``error`` (the standard errors, NaN where the AO is) is filled the same way."""
    if error is not None:
        _fill_flat_vertices(error, simplices)
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
