"""Learning samples of one item: labelled points, surface points, and the item's normalisation.

``samples = { uniform = 16384, near_surface = 16384, sigmas = [0.01, 0.05], surface = 16384 }``
in a configuration's ``[defaults]`` or a ``[[family]]`` makes each item's ``samples.npz``:

``points`` (N, 4) float32
    ``uniform`` points uniform in the item's box (``record["samples"]["box"]``: the grid's
    bounds for implicit families, the mesh's bounds grown by 5 % of their width per side for
    lifted ones), then for each sigma in order ``near_surface`` points: surface points plus
    Gaussian offsets of standard deviation ``sigma`` times the box's diagonal. So
    ``N = uniform + near_surface * len(sigmas)`` (at most :data:`MAX_POINTS`). The sigmas are
    distinct, finite, > 0 and at most :data:`MAX_SIGMA` (box diagonals: a larger offset puts
    the points far outside anything the item describes, and past ~1e300 makes them inf).
``occupancy`` (N,) bool
    True inside the solid.
``sdf`` (N,) float32
    Signed distance, negative inside; ``sdf < 0`` exactly where ``occupancy``.
``surface_points``, ``surface_normals`` (M, 4) float32, ``surface_ao`` (M,) float32
    Points uniform by 3-volume on the mesh (a simplex with probability proportional to its
    3-volume, then a uniform point in it), the simplex's outward unit normal, and the
    occlusion interpolated there (per vertex: barycentric; per simplex: the simplex's value),
    ``surface_ao`` only when the item has AO.

Label provenance (``record["samples"]["labels"]``): ``occupancy`` is ``"field"`` (the sign of
the family's field, the solid's own definition) for implicit families and ``"mesh"`` (the
first hit of three rays, inside where it leaves through the outward mesh, by majority) for
lifted ones; ``sdf`` is ``"exact"`` for kinds whose field is a closed-form signed distance
(:data:`EXACT_SDF_KINDS`: the value of the rotated field) and otherwise ``"mesh"``: the exact
distance to the mesh's simplices, signed by ``occupancy``. Labels are computed at the float32
points that are stored. Everything is drawn from the item's own generator, so the same seed
gives the same bytes.

Cost: exact-field labels cost one field evaluation per point. Mesh distances test every
simplex whose bounding ball comes within the best distance found (a k-d tree of centroids
finds them): a few per point near the surface, hundreds for a point far from a fine mesh
(about 400 for uniform points around a 3e4-simplex metaball at grid 24), at a few
microseconds each here, so ``uniform`` points dominate the ``samples`` stage of such items.

``record["normalization"] = {"loc": [...], "scale": s}`` maps the item into the unit ball:
``(x - loc) / scale``, ``loc`` the centre of the mesh's bounding box and ``scale`` the largest
distance of a vertex from it.
"""

from __future__ import annotations

import copy
import functools
import itertools
import math
from typing import Any

import numpy as np

from ._checks import check_keys

__all__ = [
    "SAMPLE_KEYS",
    "DEFAULT_SAMPLES",
    "EXACT_SDF_KINDS",
    "check_samples",
    "normalization",
    "sample_box",
    "surface_samples",
    "mesh_distance",
    "corners_distance",
    "mesh_occupancy",
    "make_samples",
    "SAMPLE_ARRAYS",
    "MAX_POINTS",
    "MAX_SIGMA",
]

DEFAULT_SAMPLES: dict[str, Any] = {"uniform": 16384, "near_surface": 16384, "sigmas": [0.01, 0.05], "surface": 16384}
SAMPLE_KEYS = frozenset(DEFAULT_SAMPLES)
#: the arrays a samples.npz may hold
SAMPLE_ARRAYS = ("points", "occupancy", "sdf", "surface_points", "surface_normals", "surface_ao")
#: family kinds whose field is an exact signed distance (a rotation keeps it one)
EXACT_SDF_KINDS = frozenset(
    {"hypersphere", "spheritorus", "torisphere", "ditorus", "tiger", "duocylinder", "tesseract"}
)
_MAX_COUNT = 1 << 24
#: the most points of ``points`` (uniform and near-surface together) in one item
MAX_POINTS = 1 << 24
#: the largest ``sigma``, in box diagonals: 10 diagonals already puts most near-surface points
#: far outside the item's box; float32 points stay finite far beyond it
MAX_SIGMA = 10.0
_PAIRS_PER_BLOCK = 1 << 14  # point-simplex pairs per block of mesh_distance's arithmetic
_BOX_GROWTH = 0.05  # lifted items: the mesh's bounds grown by this fraction of the width per side


def check_samples(value: Any) -> dict[str, Any] | bool:
    """The validated ``samples`` setting: ``False`` (none), or the four keys with defaults filled.

    ``True`` means the defaults. Raises ``ValueError`` naming the bad key (the configuration
    reader adds the file and table).
    """
    if value is False:
        return False
    if value is True:
        return copy.deepcopy(DEFAULT_SAMPLES)
    if not isinstance(value, dict):
        raise ValueError(f"`samples` must be a table (or true/false), got {value!r}")
    check_keys(value, SAMPLE_KEYS, "`samples`")
    out = {**copy.deepcopy(DEFAULT_SAMPLES), **copy.deepcopy(value)}
    for key in ("uniform", "near_surface", "surface"):
        n = out[key]
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= _MAX_COUNT:
            raise ValueError(f"`samples.{key}` must be an integer in [0, {_MAX_COUNT}], got {n!r}")
    sigmas = out["sigmas"]
    if not isinstance(sigmas, list) or not all(isinstance(s, (int, float)) and not isinstance(s, bool) for s in sigmas):
        raise ValueError(f"`samples.sigmas` must be a list of numbers, got {sigmas!r}")
    bad = [s for s in sigmas if not (math.isfinite(s) and 0 < s <= MAX_SIGMA)]
    if bad:
        raise ValueError(
            f"`samples.sigmas` must all be finite, > 0 and at most {MAX_SIGMA:g} (box diagonals), got {bad}"
        )
    sigmas = [float(s) for s in sigmas]
    # each sigma names its rows of `points` in the record (repr of the float, one-to-one on
    # distinct finite floats): a repeated sigma would overwrite the rows of the first
    repeated = sorted({s for s in sigmas if sigmas.count(s) > 1})
    if repeated:
        raise ValueError(f"`samples.sigmas` must be distinct, got {sigmas} ({', '.join(map(repr, repeated))} repeated)")
    if out["near_surface"] and not sigmas:
        raise ValueError("`samples.near_surface` > 0 needs at least one sigma in `samples.sigmas`")
    out["sigmas"] = sigmas
    points = out["uniform"] + out["near_surface"] * len(sigmas)
    if points > MAX_POINTS:
        raise ValueError(
            f"`samples` asks for {points} points per item (uniform + near_surface * {len(sigmas)} sigmas); "
            f"at most {MAX_POINTS}"
        )
    if points + out["surface"] == 0:
        raise ValueError("`samples` asks for no points at all (every count is 0); use samples = false")
    return out


def normalization(mesh: Any) -> dict[str, Any]:
    """``{"loc": centre of the mesh's bounding box, "scale": largest vertex distance from it}``."""
    lo, hi = mesh.bounds
    loc = (np.asarray(lo, float) + np.asarray(hi, float)) / 2
    scale = float(np.max(np.linalg.norm(mesh.vertices - loc, axis=1)))
    return {"loc": loc.tolist(), "scale": scale if scale > 0 else 1.0}


def sample_box(shape: Any) -> tuple[np.ndarray, np.ndarray]:
    """The box uniform points fill: the item's grid bounds, or the mesh's bounds grown 5 %."""
    if shape.grid:
        lo, hi = (np.asarray(b, float) for b in shape.grid["bounds"])
        return lo, hi
    lo, hi = (np.asarray(b, float) for b in shape.mesh.bounds)
    grow = _BOX_GROWTH * (hi - lo)
    return lo - grow, hi + grow


def surface_samples(
    mesh: Any, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``count`` points uniform by 3-volume on ``mesh``.

    Returns
    -------
    points (count, 4) float64, normals (count, 4) outward unit, simplex (count,) int64,
    barycentric (count, 4) float64
    """
    measures = mesh.simplex_measures
    total = float(measures.sum())
    if not total > 0:
        raise ValueError("the mesh has no 3-volume to sample surface points on")
    cdf = np.cumsum(measures) / total
    simplex = np.minimum(np.searchsorted(cdf, rng.random(count), side="right"), len(cdf) - 1)
    # uniform in a simplex: barycentric weights Dirichlet(1, 1, 1, 1) (normalised exponentials)
    bary = -np.log1p(-rng.random((count, 4)))
    bary /= bary.sum(axis=1, keepdims=True)
    corners = mesh.vertices[mesh.simplices[simplex]]  # (count, 4, 4)
    points = np.einsum("nk,nkd->nd", bary, corners)
    return points, mesh.simplex_normals[simplex], simplex.astype(np.int64), bary


# --------------------------------------------------------------------------- mesh labels

# every non-empty face of a tetrahedron, as vertex subsets (4 vertices, 6 edges, 4 triangles, 1)
_FACES = [list(c) for k in range(1, 5) for c in itertools.combinations(range(4), k)]


def _solve_small(gram: np.ndarray, rhs: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched ``gram @ x = rhs`` for (K, m, m) Gram matrices, m <= 3, by Cramer's rule
    (elementwise arithmetic: far faster than a LAPACK call per tiny system); also returns
    which systems are well conditioned: determinant above ``1e-10 scale^m``, ``scale`` (K,) the
    squared size of the simplex the face belongs to. The Gram entries come from differences of
    products of size ``scale``, so their round-off is about ``1e-16 scale``: measured against
    the face's own diagonal, an edge of two coincident corners passed as well conditioned, and
    its projection, all round-off, claimed a distance of 0 far from the simplex. A face skipped
    as degenerate is covered by its own faces, within its width (under ``1e-5`` of the size)."""
    m = gram.shape[1]
    g = [[gram[:, i, j] for j in range(m)] for i in range(m)]
    r = [rhs[:, i] for i in range(m)]
    if m == 1:
        det = g[0][0]
        x = [r[0]]
    elif m == 2:
        det = g[0][0] * g[1][1] - g[0][1] * g[1][0]
        x = [r[0] * g[1][1] - g[0][1] * r[1], g[0][0] * r[1] - r[0] * g[1][0]]
    else:
        c00 = g[1][1] * g[2][2] - g[1][2] * g[2][1]
        c01 = g[1][2] * g[2][0] - g[1][0] * g[2][2]
        c02 = g[1][0] * g[2][1] - g[1][1] * g[2][0]
        det = g[0][0] * c00 + g[0][1] * c01 + g[0][2] * c02
        # the inverse of a symmetric matrix is its cofactor matrix over the determinant
        c11 = g[0][0] * g[2][2] - g[0][2] * g[2][0]
        c12 = g[0][1] * g[2][0] - g[0][0] * g[2][1]
        c22 = g[0][0] * g[1][1] - g[0][1] * g[1][0]
        x = [
            c00 * r[0] + c01 * r[1] + c02 * r[2],
            c01 * r[0] + c11 * r[1] + c12 * r[2],
            c02 * r[0] + c12 * r[1] + c22 * r[2],
        ]
    ok = np.abs(det) > 1e-10 * np.asarray(scale) ** m
    safe = np.where(ok, det, 1.0)
    return np.stack([xi / safe for xi in x], axis=1), ok


def _simplex_distance(p: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from points ``p`` (K, d) to tetrahedra ``corners`` (K, 4, d).

    The closest point lies in the relative interior of one face, where the projection onto that
    face's affine hull has non-negative barycentric weights; every such projection is a point of
    the tetrahedron, so the least distance over the valid projections is the distance.
    """
    best = np.full(len(p), np.inf)
    size = np.einsum("knd,knd->kn", corners - corners[:, :1], corners - corners[:, :1]).max(axis=1)
    for face in _FACES:
        a0 = corners[:, face[0]]
        r = p - a0
        if len(face) == 1:
            best = np.minimum(best, np.einsum("kd,kd->k", r, r))
            continue
        e = corners[:, face[1:]] - a0[:, None, :]  # (K, m, d)
        gram = np.einsum("kmd,knd->kmn", e, e)
        rhs = np.einsum("kmd,kd->km", e, r)
        lam, ok = _solve_small(gram, rhs, size)
        ok &= (lam >= 0).all(axis=1) & (lam.sum(axis=1) <= 1)
        diff = r - np.einsum("km,kmd->kd", lam, e)
        d2 = np.einsum("kd,kd->k", diff, diff)
        best = np.where(ok, np.minimum(best, d2), best)
    return np.sqrt(best)


def _faces(corners: int) -> list[list[int]]:
    """Every face of two or more of a simplex's ``corners`` corners, as corner subsets."""
    return [list(c) for k in range(2, corners + 1) for c in itertools.combinations(range(corners), k)]


class _Simplices:
    """Per-simplex values for fast exact point-to-simplex distances (:meth:`distance`).

    ``corners`` (S, n, d): tetrahedra (n = 4) of a 4D mesh or triangles (n = 3) of a 3D frame.
    Every vector is taken relative to the simplex's first corner (no cancellation between
    large coordinates): ``E`` (S, n, d) the corners minus corner 0 (row 0 zero) and the
    diagonal of their Gram matrix; for each face of two or more corners, the inverse of its
    edges' Gram matrix, the constant part of its projection's right-hand side, and whether
    it is well conditioned.
    """

    def __init__(self, corners: np.ndarray):
        self.n = corners.shape[1]
        self.v0 = np.ascontiguousarray(corners[:, 0])
        self.E = corners - corners[:, :1]
        W = np.einsum("sid,sjd->sij", self.E, self.E)
        self.diag = np.ascontiguousarray(np.einsum("sii->si", W))
        self.faces = []
        for face in _faces(self.n):
            i0, rest = face[0], list(face[1:])
            m = len(rest)
            gram = np.empty((len(W), m, m))
            for a_, ia in enumerate(rest):
                for b_, ib in enumerate(rest):
                    gram[:, a_, b_] = W[:, ia, ib] - W[:, ia, i0] - W[:, i0, ib] + W[:, i0, i0]
            inverse, ok = _inverse_small(gram, self.diag.max(axis=1))
            const = np.stack([W[:, i0, i0] - W[:, k, i0] for k in rest], axis=1)
            self.faces.append((i0, rest, inverse, const, ok))

    def distance(self, p: np.ndarray, sim: np.ndarray) -> np.ndarray:
        """Exact distances from points ``p`` (K, d) to simplices ``sim`` (K,): the least over
        the faces whose hull projection lies in the face (see :func:`_simplex_distance`).
        Worked in blocks of pairs that stay in cache, with every small product written out."""
        out = np.empty(len(sim))
        for start in range(0, len(sim), _PAIRS_PER_BLOCK):
            block = slice(start, start + _PAIRS_PER_BLOCK)
            out[block] = self._distance(p[block], sim[block])
        return out

    def _distance(self, p: np.ndarray, sim: np.ndarray) -> np.ndarray:
        r0 = p - self.v0[sim]
        E = self.E[sim]
        P = [np.zeros(len(sim))] + [np.einsum("kd,kd->k", E[:, i], r0) for i in range(1, self.n)]  # r0 . E_i
        diag = self.diag[sim]
        rr = np.einsum("kd,kd->k", r0, r0)
        # |p - v_i|^2 = |r0|^2 - 2 r0.E_i + E_i.E_i
        norms = [rr] + [rr - 2 * P[i] + diag[:, i] for i in range(1, self.n)]
        best = functools.reduce(np.minimum, norms)
        for i0, rest, inverse, const, ok in self.faces:
            inv, c = inverse[sim], const[sim]
            # rhs_k = (E_k - E_i0) . (r0 - E_i0)
            rhs = [P[k] - P[i0] + c[:, a_] for a_, k in enumerate(rest)]
            m = len(rest)
            lam = [sum(inv[:, a_, b_] * rhs[b_] for b_ in range(m)) for a_ in range(m)]
            valid = ok[sim]
            total = lam[0]
            for a_ in range(m):
                valid &= lam[a_] >= 0
                if a_:
                    total = total + lam[a_]
            valid &= total <= 1
            # the projection's squared distance: |r|^2 - lam . rhs (lam = G^-1 rhs)
            d2 = norms[i0] - sum(lam[a_] * rhs[a_] for a_ in range(m))
            np.minimum(best, d2, out=best, where=valid)
        return np.sqrt(np.maximum(best, 0.0))


def _inverse_small(gram: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses of (S, m, m) symmetric matrices, m <= 3, by cofactors; and which are well
    conditioned against ``scale`` (see :func:`_solve_small`)."""
    m = gram.shape[1]
    eye = np.eye(m)
    cols = [_solve_small(gram, np.broadcast_to(eye[:, j], (len(gram), m)), scale)[0] for j in range(m)]
    _, ok = _solve_small(gram, np.zeros((len(gram), m)), scale)
    return np.stack(cols, axis=2), ok


def mesh_distance(mesh: Any, points: np.ndarray, *, pairs_per_step: int = 1 << 18) -> np.ndarray:
    """Exact distance from each point to the mesh (the nearest simplex), float64.

    Candidates come from a k-d tree of simplex centroids: with ``u`` the distance to the nearest
    of a few candidates, only simplices whose bounding ball (centroid, farthest corner) comes
    within ``u`` can be nearer, and those are all tested (:func:`corners_distance`).
    """
    return corners_distance(mesh.vertices[mesh.simplices], points, pairs_per_step=pairs_per_step)


def corners_distance(corners: np.ndarray, points: np.ndarray, *, pairs_per_step: int = 1 << 18) -> np.ndarray:
    """Exact distance from each point (K, d) to the nearest of the simplices ``corners``
    (S, n, d): tetrahedra of a 4D mesh, triangles of a 3D frame; float64. See :func:`mesh_distance`."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64)
    corners = np.asarray(corners, np.float64)
    if not len(corners):
        raise ValueError("`corners` holds no simplex to measure distances to")
    table = _Simplices(corners)
    centroids = corners.mean(axis=1)
    radii = np.max(np.linalg.norm(corners - centroids[:, None, :], axis=2), axis=1)
    tree = cKDTree(centroids)
    k = min(8, len(centroids))
    _, near = tree.query(points, k=k)
    near = near.reshape(len(points), k)
    upper = table.distance(np.repeat(points, k, axis=0), near.ravel()).reshape(-1, k).min(axis=1)
    out = upper.copy()
    # simplices in classes of similar bounding radius (doubling from twice the median), each with
    # its own tree: a few long slivers widen only their own class's search, not every search
    cut = max(float(np.median(radii)), 1e-300) * 2.0 ** np.arange(1, 64)
    group = np.searchsorted(cut, radii)
    classes = []
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        classes.append((members, float(radii[members].max()), cKDTree(centroids[members])))
    # all simplices whose bounding ball may come nearer than the best so far, in bounded
    # steps of points with similar bounds (sorted, within `band`), the pairs found by one k-d
    # tree join per class
    order = np.argsort(upper, kind="stable")
    ordered = upper[order]
    # a step's bounds differ by at most `band`: no wide search for the points near the mesh
    band = 2.0 * float(np.median(radii)) or float(radii.max())
    step = 64
    start = 0
    while start < len(order):
        stop = start + max(1, int(np.searchsorted(ordered[start : start + step], ordered[start] + band, side="right")))
        chunk = order[start:stop]
        start = stop
        found = 0
        chunk_tree = cKDTree(points[chunk])
        for members, rho, class_tree in classes:
            pairs = chunk_tree.sparse_distance_matrix(
                class_tree, float(upper[chunk].max()) + rho, output_type="ndarray"
            )
            found += len(pairs)
            if not len(pairs):
                continue
            idx, sim = chunk[pairs["i"]], members[pairs["j"]]
            # each simplex lies in its ball: one farther than the best so far cannot come nearer
            keep = pairs["v"] - radii[sim] <= upper[idx]
            idx, sim = idx[keep], sim[keep]
            if len(sim):
                np.minimum.at(out, idx, table.distance(points[idx], sim))
        # keep steps near pairs_per_step pairs
        step = int(np.clip(step * pairs_per_step / max(1, found), 1, 4096))
    return out


def mesh_occupancy(mesh: Any, points: np.ndarray, rng: np.random.Generator, backend: str) -> np.ndarray:
    """Inside test against a closed outward-oriented mesh: three rays per point in random
    directions; a ray that first leaves through a simplex (its outward normal along the ray)
    votes inside; the majority decides."""
    from ao4d.rays.api import cast_rays

    points = np.asarray(points, np.float64)
    votes = np.zeros(len(points), np.int64)
    if not len(points):
        return votes.astype(bool)
    for _ in range(3):
        w = rng.standard_normal(4)
        w /= np.linalg.norm(w)
        dirs = np.broadcast_to(w, points.shape)
        hits = cast_rays(mesh, points, dirs, backend=backend, progress=False)
        hit = hits.simplex >= 0
        leaving = np.zeros(len(points), bool)
        leaving[hit] = mesh.simplex_normals[hits.simplex[hit]] @ w > 0
        votes += leaving
    return votes >= 2


def _labels(
    shape: Any, kind: str, points: np.ndarray, rng: np.random.Generator, backend: str, *, sdf: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """Occupancy (bool) and signed distance (float32, negative exactly where occupied; ``None``
    when ``sdf`` is false)."""
    if shape.field is not None:
        value = np.asarray(shape.field(points), np.float64)
        occupancy = value < 0
        signed = value if kind in EXACT_SDF_KINDS else None
    else:
        occupancy = mesh_occupancy(shape.mesh, points, rng, backend)
        signed = None
    if not sdf:
        return occupancy, None
    if signed is None:
        signed = np.where(occupancy, -1.0, 1.0) * mesh_distance(shape.mesh, points)
    return occupancy, signed_float32(occupancy, signed)


def signed_float32(occupancy: np.ndarray, signed: np.ndarray) -> np.ndarray:
    """``signed`` as float32 with its sign made to agree with ``occupancy``: negative exactly
    where occupied (a rounding to -0.0 or a point on the mesh becomes the least negative
    float32; a negative value outside becomes 0)."""
    sdf32 = np.asarray(signed).astype(np.float32)
    tiny = np.float32(np.finfo(np.float32).smallest_subnormal)
    sdf32[occupancy & ~(sdf32 < 0)] = -tiny
    sdf32[~occupancy & (sdf32 < 0)] = 0.0
    return sdf32


def labels_provenance(shape: Any, kind: str) -> dict[str, str]:
    """Per label: ``"exact"`` (closed-form signed distance), ``"field"`` (the family field's
    sign), or ``"mesh"`` (computed from the extracted mesh)."""
    implicit = shape.field is not None
    return {
        "occupancy": "field" if implicit else "mesh",
        "sdf": "exact" if implicit and kind in EXACT_SDF_KINDS else "mesh",
        "surface_points": "mesh",
        "surface_normals": "mesh",
        "surface_ao": "mesh",
    }


def make_samples(
    shape: Any,
    kind: str,
    settings: dict[str, Any],
    rng: np.random.Generator,
    *,
    occlusion: np.ndarray | None = None,
    ao_at: str = "vertices",
    backend: str = "auto",
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays of ``samples.npz`` and the record's ``samples`` entry for one item.

    Parameters
    ----------
    shape : datasets_gen.families.Shape
    kind : str
        The family kind (decides whether the field is an exact signed distance).
    settings : dict
        The validated ``samples`` setting (:func:`check_samples`).
    rng : numpy.random.Generator
        The item's samples generator (the only source of randomness here).
    occlusion : array, optional
        The item's AO (per vertex or per simplex, ``ao_at``); gives ``surface_ao``.
    backend : str
        Ray-casting backend for the mesh inside test of lifted items.
    """
    mesh = shape.mesh
    lo, hi = sample_box(shape)
    diagonal = float(np.linalg.norm(hi - lo))
    parts = [lo + (hi - lo) * rng.random((settings["uniform"], 4))]
    rows = {"uniform": [0, settings["uniform"]]}
    start = settings["uniform"]
    for sigma in settings["sigmas"]:
        n = settings["near_surface"]
        base, _, _, _ = surface_samples(mesh, n, rng)
        parts.append(base + rng.normal(0.0, sigma * diagonal, size=(n, 4)))
        key = f"sigma={sigma!r}"
        if key in rows:  # check_samples refuses repeated sigmas; never overwrite a block's rows
            raise ValueError(f"`samples.sigmas` holds {sigma!r} twice: its rows would be lost from the record")
        rows[key] = [start, start + n]
        start += n
    points = np.concatenate(parts).astype(np.float32)
    occupancy, sdf = _labels(shape, kind, points.astype(np.float64), rng, backend)
    arrays: dict[str, np.ndarray] = {"points": points, "occupancy": occupancy, "sdf": sdf}
    surface, normals, simplex, bary = surface_samples(mesh, settings["surface"], rng)
    arrays["surface_points"] = surface.astype(np.float32)
    arrays["surface_normals"] = normals.astype(np.float32)
    if occlusion is not None:
        occ = np.asarray(occlusion, np.float64)
        if ao_at == "vertices":
            ao = np.einsum("nk,nk->n", bary, occ[mesh.simplices[simplex]])
        else:
            ao = occ[simplex]
        arrays["surface_ao"] = ao.astype(np.float32)
    provenance = labels_provenance(shape, kind)
    if occlusion is None:
        del provenance["surface_ao"]
    n_uniform = settings["uniform"]
    record = {
        **settings,
        "box": [lo.tolist(), hi.tolist()],
        "offset_scale": diagonal,
        "rows": rows,
        "labels": provenance,
        "inside_fraction_uniform": float(occupancy[:n_uniform].mean()) if n_uniform else None,
    }
    return arrays, record
