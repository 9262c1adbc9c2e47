"""Face topology of simplicial meshes: (d-2)-faces keyed and grouped, and the health report.

Everything is vectorised over the S*d (d-2)-faces of a mesh with one sort: entry r is the face of
simplex r // d omitting local vertex r % d. From the grouping follow face adjacency, boundary
faces, orientation consistency (boundary operator of simplicial homology) and singular vertices.
:class:`~ao4d.mesh.SimplexMesh` caches the grouping and calls these functions; they take plain
arrays and do no validation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import check_memory

__all__ = ["Faces", "MeshReport", "InsideOutWarning", "warn_if_inside_out", "face_structure", "face_adjacency", "boundary_faces",
           "singular_vertices", "connected_labels"]

# --------------------------------------------------------------------------------------------
# face structure: (d-2)-faces keyed and grouped, vectorised with one sort
# --------------------------------------------------------------------------------------------


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
    check_memory(s * d * (d - 1) * 8 * 3.0, "the face table of this mesh")
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


# --------------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------------


# SimplexMesh.cache key under which ao4d.extract records that the solid touches the grid's edge
# (the text says where the mesh is cut open and what to pass to close it); the report prints it
GRID_EDGE_KEY = "ao4d.grid_edge"


@dataclass(frozen=True)
class MeshReport:
    """Topological and geometric health of a :class:`SimplexMesh` (see :meth:`SimplexMesh.check`).

    Attributes
    ----------
    dim : int
        Ambient dimension d.
    n_vertices, n_simplices, n_faces : int
        Counts; faces are the distinct (d-2)-faces (triangles in 4D, edges in 3D, points in 2D).
    n_boundary_faces : int
        Faces used by exactly one simplex (0 for a closed mesh).
    n_nonmanifold_faces : int
        Faces used by three or more simplices.
    n_misoriented_faces : int
        Faces shared by two simplices that induce the same orientation on them.
    n_singular_vertices : int
        Vertices whose star (the simplices around them) falls apart into several pieces that
        are joined only at the vertex or along an edge (pinch points).
    n_degenerate : int
        Simplices of (near-)zero measure: at most ``rtol * scale**(d-1)``.
    n_components : int
        Connected components, simplices joined through shared faces.
    n_unused_vertices : int
        Vertices no simplex refers to (allowed; they do not affect ``ok``).
    volume : float
        Enclosed d-volume (positive for outward orientation, DESIGN.md).
    closed, manifold, oriented : bool
        ``closed``: every face shared by exactly two simplices. ``manifold``: no face shared by
        more than two simplices and no singular vertex. ``oriented``: every face shared by two
        simplices gets opposite orientations from them. ``inside_out``: closed and consistently
        oriented, but the normals point inwards (negative volume): ``mesh.flipped()`` fixes it.
    """

    dim: int
    n_vertices: int
    n_simplices: int
    n_faces: int
    n_boundary_faces: int
    n_nonmanifold_faces: int
    n_misoriented_faces: int
    n_singular_vertices: int
    n_degenerate: int
    n_components: int
    n_unused_vertices: int
    volume: float = 0.0
    hint: str = ""  # why the mesh is open and what closes it, when known (printed when open)

    @property
    def closed(self) -> bool:
        return self.n_simplices > 0 and self.n_boundary_faces == 0 and self.n_nonmanifold_faces == 0

    @property
    def manifold(self) -> bool:
        return self.n_nonmanifold_faces == 0 and self.n_singular_vertices == 0

    @property
    def oriented(self) -> bool:
        return self.n_misoriented_faces == 0

    @property
    def empty(self) -> bool:
        return self.n_simplices == 0

    @property
    def inside_out(self) -> bool:
        return self.closed and self.oriented and self.volume < 0

    @property
    def ok(self) -> bool:
        """Closed, manifold, consistently oriented and outward (degenerate simplices are only
        reported: extraction legitimately makes zero-measure simplices where values equal the
        level)."""
        return self.closed and self.manifold and self.oriented and not self.inside_out

    def __str__(self) -> str:
        def flag(value: bool) -> str:
            return "yes" if value else "NO"

        if self.empty:
            return (f"{self.dim}D simplex mesh: empty ({self.n_vertices} vertices, no simplices)\n"
                    "  => NOT OK (an empty mesh encloses nothing)")
        if not self.closed:
            outward = "n/a (open mesh: no enclosed volume)"
        elif self.inside_out:
            outward = f"NO (enclosed volume {self.volume:.6g} < 0: inside out, use mesh.flipped())"
        else:
            outward = f"yes (enclosed volume {self.volume:.6g})"
        lines = [
            f"{self.dim}D simplex mesh: {self.n_vertices} vertices, {self.n_simplices} simplices, "
            f"{self.n_faces} faces, {self.n_components} component(s)",
            f"  closed:   {flag(self.closed)} ({self.n_boundary_faces} boundary faces)",
            f"  manifold: {flag(self.manifold)} ({self.n_nonmanifold_faces} faces shared by >2 "
            f"simplices, {self.n_singular_vertices} singular vertices)",
            f"  oriented: {flag(self.oriented)} ({self.n_misoriented_faces} misoriented faces)",
            f"  outward:  {outward}",
            f"  degenerate simplices: {self.n_degenerate}; unused vertices: {self.n_unused_vertices}",
        ]
        if self.hint and not self.closed:
            lines.append(f"  open at the grid's edge: {self.hint}")
        lines.append(f"  => {'OK' if self.ok else 'NOT OK'}")
        return "\n".join(lines)



class InsideOutWarning(UserWarning):
    """A closed mesh whose normals point inwards (negative enclosed volume)."""


def warn_if_inside_out(mesh: Any, consequence: str, *, stacklevel: int = 3) -> None:
    """Warn when ``mesh`` is closed but encloses a negative volume (normals point inwards).

    The volume is cheap and cached; the closedness check runs only when it is negative.
    ``consequence`` says what the caller's result will look like (e.g. "AO will be 1 everywhere").
    """
    if getattr(mesh, "check", None) is None or mesh.n_simplices == 0 or mesh.volume >= 0:
        return
    if mesh.check().closed:
        import warnings

        warnings.warn(
            f"the mesh is inside out: closed, but it encloses a negative volume ({mesh.volume:.4g}), "
            f"so its normals point inwards and {consequence}; use mesh.flipped()",
            InsideOutWarning, stacklevel=stacklevel)


# --------------------------------------------------------------------------------------------
# queries on the grouped faces
# --------------------------------------------------------------------------------------------


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
