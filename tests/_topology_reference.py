"""The check of ao4d 0.x before its fast rewrite, kept verbatim as the reference that
``tests/test_topology.py`` compares :meth:`ao4d.SimplexMesh.check` against on random defective
meshes: one argsort of (d-2)-face keys, sparse-graph components for simplices and for vertex
stars, and the 4D link Euler characteristic from a sort of all edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ao4d.topology import MeshReport


@dataclass(frozen=True)
class Faces:
    """The S*d (d-2)-faces of a mesh, grouped: entry r is the face of simplex r // d omitting
    local vertex r % d.

    ``order`` sorts the entries by face; ``starts`` (F+1,) delimits the groups of equal faces in
    that order; ``sign`` (S*d,) is the orientation the simplex induces on its face (+1/-1) relative
    to the face's sorted vertex order; ``local`` (S*d, d-1) the local indices (in the simplex) of
    the face's vertices in sorted vertex order.
    """

    order: np.ndarray
    starts: np.ndarray
    sign: np.ndarray
    local: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.starts)


def face_structure(simplices: np.ndarray, n_vertices: int) -> Faces:
    s, d = simplices.shape
    itype = np.int32 if n_vertices < 2**31 else np.int64
    # local vertex indices of the face opposite vertex i: all j != i, in increasing order
    opposite = np.array([[j for j in range(d) if j != i] for i in range(d)], dtype=np.int8)
    faces = simplices.astype(itype, copy=False)[:, opposite].reshape(s * d, d - 1)
    local = np.tile(opposite, (s, 1))
    # Face opposite local vertex i carries the induced orientation (-1)^i times the parity of
    # the permutation that sorts its vertices (boundary operator of simplicial homology).
    sign = np.tile((-1) ** np.arange(d), s).astype(np.int8)
    _sort_rows_tracking(faces, local, sign)

    order = _lexsort_rows(faces, n_vertices)
    sorted_faces = faces[order]
    if len(order):
        new_group = np.any(sorted_faces[1:] != sorted_faces[:-1], axis=1)
        starts = np.concatenate([[0], np.flatnonzero(new_group) + 1, [len(order)]])
    else:
        starts = np.zeros(1, dtype=np.int64)
    return Faces(order=order, starts=starts.astype(np.int64), sign=sign, local=local)


def _sort_rows_tracking(rows: np.ndarray, local: np.ndarray, sign: np.ndarray) -> None:
    """Sort each row of ``rows`` (N, m <= 3) in place with a sorting network, applying the same
    swaps to ``local`` and flipping ``sign`` once per swap (a swap is a transposition).

    Three vectorised compare-exchanges beat ``argsort(axis=1)`` several times on tall arrays.
    """
    m = rows.shape[1]
    network = {1: [], 2: [(0, 1)], 3: [(0, 1), (1, 2), (0, 1)]}[m]
    for i, j in network:
        swap = rows[:, i] > rows[:, j]
        for arr in (rows, local):
            first = arr[swap, i]
            arr[swap, i] = arr[swap, j]
            arr[swap, j] = first
        np.negative(sign, out=sign, where=swap)


def _lexsort_rows(rows: np.ndarray, base: int) -> np.ndarray:
    """Indices that sort the small-integer rows (N, m) lexicographically."""
    m = rows.shape[1]
    if base ** m < 2**63:
        key = np.zeros(len(rows), dtype=np.int64)
        for k in range(m):
            key = key * base + rows[:, k]
        return np.argsort(key)
    return np.lexsort(rows.T[::-1])


def _unique_ints(values: np.ndarray) -> np.ndarray:
    """Sorted distinct values (a sort is several times faster than numpy 2's hash-based unique
    on tens of millions of int64 keys)."""
    values = np.sort(values)
    if len(values) == 0:
        return values
    keep = np.empty(len(values), dtype=bool)
    keep[0] = True
    np.not_equal(values[1:], values[:-1], out=keep[1:])
    return values[keep]


def _pairs_within_groups(starts: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive entries (in sorted order) of every group: a chain linking each group."""
    n = len(order)
    if n < 2:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    same = np.ones(n - 1, dtype=bool)
    same[starts[1:-1] - 1] = False  # the step from a group's last entry to the next group's first
    idx = np.flatnonzero(same)
    return order[idx], order[idx + 1]


def connected_labels(n_nodes: int, a: np.ndarray, b: np.ndarray) -> tuple[int, np.ndarray]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(a), dtype=bool), (a, b)), shape=(n_nodes, n_nodes)).tocsr()
    return connected_components(graph, directed=False)


def face_adjacency(faces: Faces, d: int) -> np.ndarray:
    """(P, 2) int64: pairs of simplices sharing a (d-2)-face (a chain for non-manifold faces)."""
    a, b = _pairs_within_groups(faces.starts, faces.order)
    return np.stack([a // d, b // d], axis=1).astype(np.int64)


def boundary_faces(simplices: np.ndarray, faces: Faces) -> np.ndarray:
    """(B, d-1) int64: the faces used by one simplex, in the orientation it induces on them."""
    d = simplices.shape[1]
    entries = faces.order[faces.starts[:-1][faces.counts == 1]]
    opposite = entries % d
    rows = simplices[entries // d]
    keep = np.arange(d)[None, :] != opposite[:, None]
    out = rows[keep].reshape(-1, d - 1)
    # (-1)^i times the face in increasing local order; fix odd signs by swapping two entries
    odd = (opposite % 2 == 1) & (d - 1 >= 2)
    out[odd, :2] = out[odd, 1::-1]
    return out


def misoriented_faces(faces: Faces) -> int:
    """Faces shared by two simplices that induce the same orientation on them."""
    if not len(faces.order):
        return 0
    group_sign = np.add.reduceat(faces.sign[faces.order].astype(np.int64), faces.starts[:-1])
    return int(np.count_nonzero((faces.counts == 2) & (group_sign != 0)))


def singular_vertices(simplices: np.ndarray, n_vertices: int, faces: Faces) -> int:
    """Vertices whose link is not a sphere (or, on the boundary, a disk), as far as we test.

    Two tests. (1) The star must be connected through (d-2)-faces containing the vertex:
    nodes are (simplex, local vertex) incidences, joined when their simplices share a face
    through that vertex; more than one group is a pinch point (or, in 4D, a pinched edge).
    With manifold faces this settles 3D, where a connected 2-regular link is a circle. (2) In
    4D the link is a closed surface (boundary vertices: a surface with boundary), so we also
    require its Euler characteristic #edges - #triangles + #tetrahedra through the vertex to
    be 2 (1 on the boundary): a connected closed surface with chi = 2 is a sphere.
    """
    s, d = simplices.shape
    if s == 0 or d == 2:
        return 0  # in 2D the faces are the vertices: face counts already say everything
    counts = faces.counts
    # only manifold pairs: a face used by >2 simplices is already reported as non-manifold
    manifold_groups = np.flatnonzero(counts == 2)
    first = faces.order[faces.starts[manifold_groups]]
    second = faces.order[faces.starts[manifold_groups] + 1]
    a = (first // d)[:, None] * d + faces.local[first]
    b = (second // d)[:, None] * d + faces.local[second]
    _, labels = connected_labels(s * d, a.ravel(), b.ravel())
    vertex = simplices.ravel()
    n_labels = int(labels.max()) + 1
    pairs = _unique_ints(vertex * n_labels + labels)
    singular = np.bincount(pairs // n_labels, minlength=n_vertices) > 1
    if d == 4:
        singular |= _link_euler_defect(simplices, n_vertices, faces)
    return int(np.count_nonzero(singular))


def _link_euler_defect(simplices: np.ndarray, n: int, faces: Faces) -> np.ndarray:
    """(V,) bool: used 4D vertices whose link's Euler characteristic is not 2 (1 on the boundary)."""
    # one representative entry per distinct triangle: its three vertices
    reps = faces.order[faces.starts[:-1]]
    tri_vertices = np.take_along_axis(simplices[reps // 4], faces.local[reps].astype(np.int64), axis=1)
    pairs = [(i, j) for i in range(4) for j in range(i + 1, 4)]
    lo = np.concatenate([np.minimum(simplices[:, i], simplices[:, j]) for i, j in pairs])
    hi = np.concatenate([np.maximum(simplices[:, i], simplices[:, j]) for i, j in pairs])
    edges = _unique_ints(lo * n + hi)
    chi = (
        np.bincount(edges // n, minlength=n) + np.bincount(edges % n, minlength=n)
        - np.bincount(tri_vertices.ravel(), minlength=n)
        + np.bincount(simplices.ravel(), minlength=n)
    )
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[tri_vertices[faces.counts == 1].ravel()] = True
    used = np.zeros(n, dtype=bool)
    used[simplices.ravel()] = True
    return used & (chi != np.where(on_boundary, 1, 2))


def reference_components(simplices: np.ndarray, n_vertices: int) -> np.ndarray:
    """(S,) component labels through shared faces, numbered by first simplex (scipy's order)."""
    d = simplices.shape[1]
    faces = face_structure(simplices, n_vertices)
    adj = face_adjacency(faces, d)
    _, labels = connected_labels(len(simplices), adj[:, 0], adj[:, 1])
    return labels.astype(np.int64)


def reference_boundary_faces(simplices: np.ndarray, n_vertices: int) -> np.ndarray:
    return boundary_faces(simplices, face_structure(simplices, n_vertices))


def reference_report(mesh, rtol: float = 1e-12) -> MeshReport:
    """The MeshReport of ``mesh`` computed by the reference implementation above."""
    simplices = np.asarray(mesh.simplices, dtype=np.int64)
    n, d = mesh.n_vertices, mesh.dim
    faces = face_structure(simplices, n)
    counts = faces.counts
    used = np.zeros(n, dtype=bool)
    used[simplices.ravel()] = True
    labels = reference_components(simplices, n)
    measures = mesh.simplex_measures
    return MeshReport(
        dim=d, n_vertices=n, n_simplices=len(simplices), n_faces=int(len(counts)),
        n_boundary_faces=int(np.count_nonzero(counts == 1)),
        n_nonmanifold_faces=int(np.count_nonzero(counts > 2)),
        n_misoriented_faces=misoriented_faces(faces),
        n_singular_vertices=singular_vertices(simplices, n, faces),
        n_degenerate=int(np.count_nonzero(measures <= rtol * mesh.scale ** (d - 1))),
        n_components=int(labels.max(initial=-1)) + 1,
        n_unused_vertices=int(np.count_nonzero(~used)),
        volume=mesh.volume,
    )
