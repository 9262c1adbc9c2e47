"""Cutting a 4D simplex mesh by a hyperplane: marching tetrahedra on signed distances.

The cut of a closed, outward-oriented tetrahedral mesh is a closed, outward-oriented triangle
mesh in the hyperplane's own coordinates (:func:`hyperplane_basis`). Used by
:meth:`ao4d.mesh.SimplexMesh.slice`, which validates its arguments.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ._validate import as_array

__all__ = ["hyperplane_basis", "unit_normal", "slice_mesh", "SLICE_CASES"]


def hyperplane_basis(normal: Any) -> np.ndarray:
    """Deterministic orthonormal basis (b1, b2, b3) of the hyperplane orthogonal to ``normal`` in R^4.

    The basis is right-handed with the normal: ``det[b1; b2; b3; n] > 0`` with n the unit
    normal, so slicing a closed outward-oriented 4D mesh gives outward-oriented 3D slices. For
    ``normal = (0, 0, 0, 1)`` the basis is x, y, z exactly. It is built from a Householder
    reflection that maps ``-e_w`` (or ``e_w``) onto ``n``, picked by the sign of ``n_w`` for
    stability.

    Parameters
    ----------
    normal : (4,) array_like
        Nonzero, finite; need not be unit length.

    Returns
    -------
    basis : (3, 4) float64
        Rows b1, b2, b3.

    Examples
    --------
    >>> hyperplane_basis([0, 0, 0, 2.0])
    array([[1., 0., 0., 0.],
           [0., 1., 0., 0.],
           [0., 0., 1., 0.]])
    """
    n = unit_normal(normal, 4)
    e_w = np.array([0.0, 0.0, 0.0, 1.0])
    # A reflection H = I - 2 v v^T / |v|^2 with v = n + e_w sends e_w to -n (det H = -1): its
    # first three columns span the hyperplane and det[h0, h1, h2, n] = +1. For n_w < 0 use
    # v = n - e_w (H e_w = n, det[h0, h1, h2, n] = -1) and swap h0, h1 to fix the handedness.
    flip = n[3] < 0
    v = n - e_w if flip else n + e_w
    h = np.eye(4) - 2.0 * np.outer(v, v) / (v @ v)
    basis = h[:, :3].T.copy()
    if flip:
        basis[[0, 1]] = basis[[1, 0]]
    basis[np.abs(basis) < 1e-17] = 0.0  # avoid -0.0 in exact axis cases
    return basis


def unit_normal(normal: Any, d: int) -> np.ndarray:
    """``normal`` as a unit vector; an error naming ``normal`` if it is zero or not finite.

    Parameters
    ----------
    normal : (d,) array_like
        The normal.
    d : int
        The dimension.

    Returns
    -------
    (d,) float64 numpy.ndarray
        The unit normal.
    """
    n = as_array(normal, "normal", ndim=1, shape_tail=(d,), dtype=np.float64, finite=True)
    if not np.any(n):
        raise ValueError("`normal` must be a nonzero vector")
    n = n / np.max(np.abs(n))  # a largest entry of 1: the norm of 1e300 entries would overflow
    return n / float(np.linalg.norm(n))


def _slice_cases() -> list[list[tuple[tuple[int, int], ...]]]:
    """Triangles per tetrahedron case (bit i set iff local vertex i has s >= 0).

    Each triangle lists its corners as (negative, positive) local vertex pairs: the corner lies
    on that edge. Orientation rule: within the tetrahedron's own 3-space, oriented by its
    vertex order, the triangle's right-hand normal must point to the negative side. Why: in
    the 2-plane orthogonal to the triangle, (u, N) (u the in-tetrahedron normal towards s > 0,
    N the tetrahedron's outward normal) and (T, n) (T the outward normal within the
    hyperplane, n the hyperplane normal) have opposite handedness, so det[e1; e2; T; n] > 0
    (the triangle positive in the basis of :func:`hyperplane_basis`) iff det[e1; e2; u; N] < 0.
    The rule is settled once on the reference tetrahedron (0, e1, e2, e3), where it is a plain
    3D cross product, and carries over to every tetrahedron by the affine map.
    """
    ref = np.vstack([np.zeros(3), np.eye(3)])
    table: list[list[tuple[tuple[int, int], ...]]] = []
    for case in range(16):
        positive = [(case >> i) & 1 == 1 for i in range(4)]
        neg = [i for i in range(4) if not positive[i]]
        pos = [i for i in range(4) if positive[i]]
        if not neg or not pos:
            table.append([])
            continue
        if len(neg) == 1 or len(pos) == 1:
            polygon = [(a, b) for a in neg for b in pos]
        else:  # a planar quad: consecutive corners share a tetrahedron face
            (a0, a1), (b0, b1) = neg, pos
            polygon = [(a0, b0), (a0, b1), (a1, b1), (a1, b0)]
        s = np.where(positive, 1.0, -1.0)
        gradient = s[1:] - s[0]  # s is linear on the reference tetrahedron
        corner = {e: ref[e[0]] + 0.5 * (ref[e[1]] - ref[e[0]]) for e in polygon}
        triangles = []
        for k in range(1, len(polygon) - 1):
            tri = (polygon[0], polygon[k], polygon[k + 1])
            normal = np.cross(corner[tri[1]] - corner[tri[0]], corner[tri[2]] - corner[tri[0]])
            if normal @ gradient > 0:
                tri = (tri[0], tri[2], tri[1])
            triangles.append(tri)
        table.append(triangles)
    return table


SLICE_CASES = _slice_cases()


def slice_mesh(mesh: Any, origin: np.ndarray, normal: np.ndarray, attributes: Mapping[str, Any], candidates=None):
    """The cut of ``mesh`` (a 4D SimplexMesh) by the plane through ``origin`` with unit ``normal``.

    See :meth:`ao4d.SimplexMesh.slice` for the conventions; no validation here.

    Parameters
    ----------
    mesh : SimplexMesh
        A 4D mesh.
    origin : (4,) float64 numpy.ndarray
        A point of the hyperplane.
    normal : (4,) float64 numpy.ndarray
        The hyperplane's unit normal.
    attributes : mapping of str to (V, ...) array_like
        Per-vertex values to interpolate onto the cut, by name (``mesh.point_data``'s, or values
        the caller has for the mesh's vertices without storing them on it).
    candidates : (k,) int numpy.ndarray, optional
        Increasing indices of the simplices that may cross the plane (a superset of those that
        do: a caller cutting many parallel planes finds them from the simplices' extents along
        the normal, instead of testing every simplex per plane). Default: all.

    Returns
    -------
    trimesh.Trimesh
        The cut in the hyperplane's 3D coordinates, the named arrays as vertex attributes.
    """
    import trimesh

    vertices, simplices = mesh.vertices, mesh.simplices
    n_vertices = mesh.n_vertices
    s = (vertices - origin) @ normal
    positive = s >= 0.0
    pool = simplices if candidates is None else simplices[candidates]
    case = np.zeros(len(pool), dtype=np.int8)
    for i in range(4):
        case |= positive[pool[:, i]].astype(np.int8) << i
    # only the few tetrahedra the plane crosses go on (cases 0 and 15 cut nothing)
    crossed = np.flatnonzero((case != 0) & (case != 15))
    case = case[crossed]
    if candidates is not None:
        crossed = np.asarray(candidates)[crossed]
    keys, sources = [], []
    for c in np.unique(case):
        triangles = SLICE_CASES[c]
        if not triangles:
            continue
        tets = crossed[case == c]
        for tri in triangles:
            corner_keys = []
            for a, b in tri:
                ga, gb = simplices[tets, a], simplices[tets, b]
                # The positive end lying on the plane is the corner itself: key it by that
                # vertex so every tetrahedron around it finds the same output vertex.
                corner_keys.append(np.where(s[gb] == 0.0, n_vertices * n_vertices + gb, ga * n_vertices + gb))
            keys.append(np.stack(corner_keys, axis=1))
            sources.append(tets)
    if not keys:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    keys = np.concatenate(keys)
    sources = np.concatenate(sources)
    unique, faces = np.unique(keys, return_inverse=True)
    faces = faces.reshape(-1, 3)
    # triangles with a repeated corner have zero area (a plane through a tetrahedron's edge)
    good = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces, sources = faces[good], sources[good]

    on_vertex = unique >= n_vertices * n_vertices
    ga = np.where(on_vertex, unique - n_vertices * n_vertices, unique // n_vertices)
    gb = np.where(on_vertex, ga, unique % n_vertices)
    sa, sb = s[ga], s[gb]
    t = np.where(on_vertex, 0.0, sa / np.where(on_vertex, -1.0, sa - sb))

    def lerp(values: np.ndarray) -> np.ndarray:
        tt = t.reshape((-1,) + (1,) * (values.ndim - 1))
        return values[ga] + tt * (values[gb] - values[ga])

    points = lerp(vertices)
    coords = (points - origin) @ hyperplane_basis(normal).T
    vertex_attributes = {name: lerp(np.asarray(values, dtype=np.float64)) for name, values in attributes.items()}
    face_attributes = {"simplex": sources}
    face_attributes.update({k: np.asarray(v)[sources] for k, v in mesh.cell_data.items()})
    # drop output vertices only referenced by removed zero-area triangles
    used = np.zeros(len(unique), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return trimesh.Trimesh(
        coords[used],
        remap[faces],
        vertex_attributes={k: v[used] for k, v in vertex_attributes.items()},
        face_attributes=face_attributes,
        process=False,
    )
