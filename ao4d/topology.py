"""Face topology of simplicial meshes: (d-2)-faces keyed and grouped, and the health report.

Everything is vectorised over the S*d (d-2)-faces of a mesh with one sort: entry r is the face of
simplex r // d omitting local vertex r % d. From the grouping follow face adjacency, boundary
faces, orientation consistency (boundary operator of simplicial homology) and singular vertices.
:class:`~ao4d.mesh.SimplexMesh` caches the grouping and calls these functions; they take plain
arrays and do no validation.

Why this file is long: the face grouping and every check that reads it (adjacency, boundary,
orientation, components, singular vertices, the report) stay one module because they share the
one sort of the faces; each public function documents its arrays in numpydoc sections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import check_memory

__all__ = [
    "Faces",
    "MeshReport",
    "MARCHING_PROVED",
    "InsideOutWarning",
    "warn_if_inside_out",
    "face_structure",
    "face_adjacency",
    "boundary_faces",
    "singular_vertices",
    "connected_labels",
    "component_labels",
    "component_count",
    "misoriented_faces",
    "face_counts",
]

# --------------------------------------------------------------------------------------------
# face structure: (d-2)-faces keyed and grouped, vectorised with one sort
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Faces:
    """The S*d (d-2)-faces of a mesh, grouped: entry r is the face of simplex r // d omitting
    its (r % d)-th smallest vertex index.

    ``order`` sorts the entries by face; ``starts`` (F+1,) delimits the groups of equal faces in
    that order; ``sign`` (S*d,) is the orientation the simplex induces on its face (+1/-1)
    relative to the face's sorted vertex order; ``columns`` (d, S) each simplex's vertex indices
    in increasing order, one row per rank (the face of entry r is simplex r // d's vertices
    without rank r % d); ``perm`` (S, d) int8 the local index (in the simplex) of each rank.

    Attributes
    ----------
    order : (S*d,) int64
        The entries sorted by face.
    starts : (F+1,) int64
        Delimits the groups of equal faces in ``order``.
    sign : (S*d,) int8
        The orientation (+1/-1) each entry's simplex induces on its face.
    columns : (d, S) int
        Each simplex's vertex indices in increasing order, one row per rank.
    perm : (S, d) int8
        The local index (in the simplex) of each rank.
    """

    order: np.ndarray
    starts: np.ndarray
    sign: np.ndarray
    columns: np.ndarray
    perm: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.starts)

    @property
    def local(self) -> np.ndarray:
        """(S*d, d-1) int8: local indices of each entry's face vertices, in sorted vertex order."""
        d = self.perm.shape[1]
        return self.perm[:, _opposite(d)].reshape(-1, d - 1)

    @property
    def multiplicity(self) -> np.ndarray:
        """(S, d) int64: how many simplices have the face of simplex i opposite its local
        vertex k (1 on the boundary)."""
        s, d = self.perm.shape
        per_entry = np.empty(s * d, dtype=np.int64)
        per_entry[self.order] = np.repeat(self.counts, self.counts)
        out = np.empty((s, d), dtype=np.int64)
        np.put_along_axis(out, self.perm.astype(np.intp), per_entry.reshape(s, d), axis=1)
        return out


# the compare-exchange networks that sort d = 1..4 values (Knuth, TAOCP 5.3.4)
_NETWORKS = {1: [], 2: [(0, 1)], 3: [(0, 1), (1, 2), (0, 1)], 4: [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)]}
# odd 64-bit constant (2^64 / golden ratio): multiplying by it permutes the uint64 keys and
# spreads them over the top bits, which then key the sort when a face key and its entry index
# do not fit together into 64 bits
_MIX = np.uint64(0x9E3779B97F4A7C15)
_WORD_BITS = 64  # bits of a sort word (tests lower it to exercise the mixed and row paths)


def _opposite(d: int) -> np.ndarray:
    """(d, d-1): the ranks a face keeps, for the face omitting each rank k."""
    return np.array([[j for j in range(d) if j != k] for k in range(d)], dtype=np.intp)


def face_structure(simplices: np.ndarray, n_vertices: int) -> Faces:
    """Group the (d-2)-faces of a mesh's simplices (the table the other checks read).

    Parameters
    ----------
    simplices : (S, d) int ndarray
        The mesh's simplices, as vertex indices.
    n_vertices : int
        Vertices of the mesh (every index lies below it).

    Returns
    -------
    Faces
        The grouping.

    Raises
    ------
    MemoryError
        If the face table would need more memory than ao4d allows itself.
    """
    s, d = simplices.shape
    check_memory(s * d * 8 * 6.0, "the face table of this mesh")
    cols, locs, odd = _sort_simplices(simplices)
    columns, perm = np.stack(cols), np.stack(locs, axis=1)
    # Boundary operator: [q0..q_{d-1}] = parity * [p0..p_{d-1}], and the face omitting q_k
    # carries (-1)^k in its sorted vertex order.
    alternating = ((-1) ** np.arange(d)).astype(np.int8)
    sign = np.where(odd[:, None], -alternating, alternating).astype(np.int8).ravel()
    order, starts = _group_faces(columns, n_vertices)
    return Faces(order=order, starts=starts, sign=sign, columns=columns, perm=perm)


def _sort_simplices(
    simplices: np.ndarray, local: bool = True
) -> tuple[list[np.ndarray], list[np.ndarray] | None, np.ndarray]:
    """Each row sorted by a compare-exchange network: d contiguous (S,) int64 columns of the
    sorted vertex indices (one per rank), d (S,) int8 columns of their local indices (None
    unless ``local``), and (S,) bool the odd parity of each row's sorting permutation."""
    s, d = simplices.shape
    cols = [np.ascontiguousarray(simplices[:, i], dtype=np.int64) for i in range(d)]
    locs = [np.full(s, i, dtype=np.int8) for i in range(d)] if local else None
    odd = np.zeros(s, dtype=bool)
    for i, j in _NETWORKS[d]:
        swap = cols[i] > cols[j]
        cols[i], cols[j] = np.minimum(cols[i], cols[j]), np.maximum(cols[i], cols[j])
        if locs is not None:
            locs[i], locs[j] = np.where(swap, locs[j], locs[i]), np.where(swap, locs[i], locs[j])
        odd ^= swap
    return cols, locs, odd


def _bits(n: int) -> int:
    """Bits that hold the integers 0 .. n - 1 (at least one)."""
    return max(1, (int(n) - 1).bit_length())


def _pack_face(cols: Any, kept: np.ndarray, b: int, out: np.ndarray) -> np.ndarray:
    """The face key of every simplex into ``out`` (S,) uint64 and returned: the sorted vertex
    indices of ranks ``kept`` (``cols``: one contiguous int64 column per rank), ``b`` bits
    each, the first in the highest bits. The one packing of faces (grouping and counting)."""
    np.copyto(out, cols[kept[0]].view(np.uint64))
    for j in kept[1:]:
        out <<= np.uint64(b)
        out |= cols[j].view(np.uint64)
    return out


def _face_keys(columns: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """(S*d,) uint64 packed sorted face vertices (entry order), or None when they need more
    than 64 bits."""
    d, s = columns.shape
    b = _bits(n_vertices)
    if b * (d - 1) > _WORD_BITS:
        return None
    keys = np.empty((s, d), dtype=np.uint64)
    for k, kept in enumerate(_opposite(d)):
        keys[:, k] = _pack_face(columns, kept, b, np.empty(s, dtype=np.uint64))
    return keys.ravel()


def _group_faces(columns: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """``order`` and ``starts`` of the face groups, from one sort of 64-bit words.

    Each word holds a face key in its high bits and the entry index in its low bits, so
    ``np.sort`` (SIMD, several times faster than ``argsort``) yields the permutation. When key
    and index do not fit, the high bits hold the top of the mixed (bijectively permuted) key:
    equal faces still sort together, and the rare runs where two faces share those bits are
    sorted again by their full keys.
    """
    d, s = columns.shape
    n = s * d
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64)
    keys = _face_keys(columns, n_vertices)
    if keys is None:  # more than 2^21 vertices in 4D: lexicographic sort of the rows
        rows = columns.T[:, _opposite(d)].reshape(n, d - 1)
        order = np.lexsort(rows.T[::-1]).astype(np.int64)
        srt = rows[order]
        new = np.any(srt[1:] != srt[:-1], axis=1)
    else:
        e = _bits(n)
        exact = _bits(n_vertices) * (d - 1) + e <= _WORD_BITS
        words = keys.copy() if exact else keys * _MIX
        if not exact:
            words >>= np.uint64(e)
        words <<= np.uint64(e)
        words |= np.arange(n, dtype=np.uint64)
        words.sort()
        order = (words & np.uint64((1 << e) - 1)).astype(np.int64)
        if exact:
            words >>= np.uint64(e)
            new = words[1:] != words[:-1]
        else:
            sorted_keys = keys[order]
            _resort_collisions(words >> np.uint64(e), sorted_keys, order)
            new = sorted_keys[1:] != sorted_keys[:-1]
    starts = np.concatenate([[0], np.flatnonzero(new) + 1, [n]]).astype(np.int64)
    return order, starts


def _resort_collisions(prefix: np.ndarray, sorted_keys: np.ndarray, order: np.ndarray) -> None:
    """Make equal keys contiguous inside runs of equal ``prefix`` that hold several keys (in place)."""
    clash = (prefix[1:] == prefix[:-1]) & (sorted_keys[1:] != sorted_keys[:-1])
    if not clash.any():
        return
    bad = np.isin(prefix, np.unique(prefix[1:][clash]))
    where = np.flatnonzero(bad)  # whole runs, each contiguous: sorting them by key keeps runs in place
    idx = np.lexsort((order[where], sorted_keys[where], prefix[where]))
    order[where] = order[where][idx]
    sorted_keys[where] = sorted_keys[where][idx]


def face_counts(simplices: np.ndarray, n_vertices: int, faces: Faces | None = None) -> tuple[int, int, int, int]:
    """Distinct faces, boundary faces (one simplex), non-manifold faces (three or more) and
    misoriented faces (two simplices inducing the same orientation).

    Without ``faces`` one ``np.sort`` of words holding the face key and the induced sign's bit
    settles all four (no permutation is needed); with ``faces`` (or keys too wide for that
    word) they come from the grouping.

    Parameters
    ----------
    simplices : (S, d) int ndarray
        The simplices whose faces are counted.
    n_vertices : int
        Vertices of the mesh (it sizes the face keys).
    faces : Faces, optional
        The grouping of the mesh's faces, when already made (:func:`face_structure`).

    Returns
    -------
    n_faces : int
        Distinct faces.
    boundary : int
        Faces used by one simplex.
    non_manifold : int
        Faces used by three or more simplices.
    misoriented : int
        Faces shared by two simplices that induce the same orientation.
    """
    s, d = simplices.shape
    if faces is None and s and _bits(n_vertices) * (d - 1) + 1 <= _WORD_BITS:
        words = _face_sign_words(simplices, n_vertices)
        words.sort()
        # closed, manifold and oriented: the sorted words pair up as (face, +) (face, -), and
        # each pair's face differs from the next pair's
        first, second = words[0::2], words[1::2]
        if (
            len(words) % 2 == 0
            and np.array_equal(second - first, np.ones_like(first))
            and np.all((words[2::2] ^ words[1:-1:2]) > 1)
        ):
            return len(first), 0, 0, 0
        face = words >> np.uint64(1)
        starts = np.concatenate([[0], np.flatnonzero(face[1:] != face[:-1]) + 1, [len(words)]])
        counts = np.diff(starts)
        two = starts[:-1][counts == 2]
        same_sign = (words[two] & np.uint64(1)) == (words[two + 1] & np.uint64(1))
        return (
            len(counts),
            int(np.count_nonzero(counts == 1)),
            int(np.count_nonzero(counts > 2)),
            int(np.count_nonzero(same_sign)),
        )
    if faces is None:
        faces = face_structure(simplices, n_vertices)
    counts = faces.counts
    return (
        len(counts),
        int(np.count_nonzero(counts == 1)),
        int(np.count_nonzero(counts > 2)),
        misoriented_faces(faces),
    )


def _face_sign_words(simplices: np.ndarray, n_vertices: int) -> np.ndarray:
    """(S*d,) uint64, rank-major: each face's packed sorted vertices, shifted left by one and
    holding 1 in the lowest bit where the simplex induces the negative orientation on it."""
    s, d = simplices.shape
    cols, _, odd = _sort_simplices(simplices, local=False)
    words = np.empty(s * d, dtype=np.uint64)
    for k, kept in enumerate(_opposite(d)):
        view = _pack_face(cols, kept, _bits(n_vertices), words[k * s : (k + 1) * s])
        view <<= np.uint64(1)
        view |= (odd ^ bool(k % 2)).view(np.uint8)  # sign (-1)^k * parity negative
    return words


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
    """Connected components of the undirected graph with edges ``(a[i], b[i])``.

    Parameters
    ----------
    n_nodes : int
        Number of nodes.
    a, b : (E,) int ndarray
        The edges' end nodes.

    Returns
    -------
    n_components : int
        Number of components.
    labels : (n_nodes,) int ndarray
        The component of each node.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(a), dtype=bool), (a, b)), shape=(n_nodes, n_nodes)).tocsr()
    return connected_components(graph, directed=False)


# --------------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------------

# What marching extraction guarantees by construction (ao4d.marching.march marks its meshes; the marks
# go when the arrays change): every vertex link is a sphere, or a disk where the mesh is open.
# Each cell's patch is a ball bounded on the cell's facets, neighbours agree on shared facets,
# and vertices are welded per grid edge, so a vertex's star is the patches of the cells around
# its edge glued into a ball. tests/test_topology.py checks it against the full star and link
# tests on random fields (both methods, exact level values, open and closed).
MARCHING_PROVED = ("n_singular_vertices",)

# What marching cubes on one grid also guarantees when no vertex lies on the grid's boundary:
# every face is shared by exactly two simplices that orient it oppositely, so the face counts
# need no sort (n_faces = d * n_simplices / 2). Each entry's patch pairs its inner faces with
# opposite orientations and leaves its other faces each on one cube facet
# (tests/test_lut.py::test_patch_faces_pair_up_inside_each_entry); the cut on a facet depends
# only on the facet's signs and the two cubes sharing it orient it oppositely
# (test_cube_patches_conform_across_facets); vertices are welded per grid edge, so the two
# cubes' copies of a face are the same vertex indices; a face left on the grid's own boundary
# would have its vertices there. tests/test_topology.py checks it against the full face sort.
MARCHING_CLOSED_PROVED = (
    "n_faces",
    "n_boundary_faces",
    "n_nonmanifold_faces",
    "n_misoriented_faces",
    "n_singular_vertices",
)


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
    proved : tuple of str
        The fields taken from the mesh's construction rather than computed (empty: all
        computed). A mesh straight from marching extraction has :data:`MARCHING_PROVED`: when
        its computed faces show no face shared by more than two simplices and no misoriented
        face, its vertex links are spheres (disks on an open border) by the table's
        construction, so ``n_singular_vertices`` is 0 without the star and link tests. A
        mesh marched by cubes whose vertices all lie inside the grid's box has
        :data:`MARCHING_CLOSED_PROVED`: closed, every face shared by two simplices with
        opposite orientations, by the table's construction, without the face sort.
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
    proved: tuple[str, ...] = ()
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
    def measurable(self) -> bool:
        """Some simplex has a measure and the volume is finite (coordinates whose products
        underflow or overflow float64 make every simplex degenerate, or the volume nan/inf)."""
        return self.n_degenerate < self.n_simplices and math.isfinite(self.volume)

    @property
    def ok(self) -> bool:
        """Closed, manifold, consistently oriented, outward and measurable (degenerate simplices
        are otherwise only reported: extraction legitimately makes zero-measure simplices where
        values equal the level)."""
        return self.closed and self.manifold and self.oriented and not self.inside_out and self.measurable

    def __str__(self) -> str:
        def flag(value: bool) -> str:
            return "yes" if value else "NO"

        if self.empty:
            return (
                f"{self.dim}D simplex mesh: empty ({self.n_vertices} vertices, no simplices)\n"
                "  => NOT OK (an empty mesh encloses nothing)"
            )
        if not self.closed:
            outward = "n/a (open mesh: no enclosed volume)"
        elif self.inside_out:
            outward = f"NO (enclosed volume {self.volume:.6g} < 0: inside out, use mesh.flipped())"
        else:
            outward = f"yes (enclosed volume {self.volume:.6g})"

        def by(field: str) -> str:
            return " by construction" if field in self.proved else ""

        lines = [
            f"{self.dim}D simplex mesh: {self.n_vertices} vertices, {self.n_simplices} simplices, "
            f"{self.n_faces} faces, {self.n_components} component(s)",
            f"  closed:   {flag(self.closed)} ({self.n_boundary_faces} boundary faces{by('n_boundary_faces')})",
            f"  manifold: {flag(self.manifold)} ({self.n_nonmanifold_faces} faces shared by >2 "
            f"simplices{by('n_nonmanifold_faces')}, {self.n_singular_vertices} singular vertices"
            f"{by('n_singular_vertices')})",
            f"  oriented: {flag(self.oriented)} ({self.n_misoriented_faces} misoriented faces"
            f"{by('n_misoriented_faces')})",
            f"  outward:  {outward}",
            f"  degenerate simplices: {self.n_degenerate}; unused vertices: {self.n_unused_vertices}",
        ]
        if self.hint and not self.closed:
            lines.append(f"  open at the grid's edge: {self.hint}")
        if not self.measurable:
            lines.append(
                f"  measures: NO (volume {self.volume:.6g}, {self.n_degenerate} of {self.n_simplices} "
                "simplices degenerate: coordinates whose products underflow or overflow "
                "float64; rescale the mesh)"
            )
        lines.append(f"  => {'OK' if self.ok else 'NOT OK'}")
        return "\n".join(lines)


class InsideOutWarning(UserWarning):
    """A closed mesh whose normals point inwards (negative enclosed volume)."""


def warn_if_inside_out(mesh: Any, consequence: str, *, stacklevel: int = 3) -> None:
    """Warn when ``mesh`` is closed but encloses a negative volume (normals point inwards).

    The volume's sign comes from the vertex normal sums (the volume itself only where they
    leave it in doubt); the closedness check runs only when it is negative.

    Parameters
    ----------
    mesh : SimplexMesh
        The mesh to check.
    consequence : str
        What the caller's result will look like (e.g. "AO will be 1 everywhere").
    stacklevel : int
        Passed to :func:`warnings.warn`.
    """
    if getattr(mesh, "check", None) is None or mesh.n_simplices == 0 or mesh._volume_not_negative():
        return
    if mesh.check().closed:
        import warnings

        warnings.warn(
            f"the mesh is inside out: closed, but it encloses a negative volume ({mesh.volume:.4g}), "
            f"so its normals point inwards and {consequence}; use mesh.flipped()",
            InsideOutWarning,
            stacklevel=stacklevel,
        )


# --------------------------------------------------------------------------------------------
# queries on the grouped faces
# --------------------------------------------------------------------------------------------


def face_adjacency(faces: Faces, d: int) -> np.ndarray:
    """(P, 2) int64: pairs of simplices sharing a (d-2)-face (a chain for non-manifold faces).

    Parameters
    ----------
    faces : Faces
        The face grouping of the mesh (:func:`face_structure`).
    d : int
        Vertices per simplex.

    Returns
    -------
    (P, 2) int64
        Simplex index pairs.
    """
    a, b = _pairs_within_groups(faces.starts, faces.order)
    return np.stack([a // d, b // d], axis=1).astype(np.int64)


def boundary_faces(simplices: np.ndarray, faces: Faces) -> np.ndarray:
    """(B, d-1) int64: the faces used by one simplex, in the orientation it induces on them.

    Parameters
    ----------
    simplices : (S, d) int ndarray
        The simplices the faces were grouped from.
    faces : Faces
        Their grouping (:func:`face_structure`).

    Returns
    -------
    (B, d-1) int64
        Vertex indices of each boundary face.
    """
    d = simplices.shape[1]
    entries = faces.order[faces.starts[:-1][faces.counts == 1]]
    # the local index the face omits: the one missing from its d - 1 local indices
    opposite = d * (d - 1) // 2 - faces.local[entries].sum(axis=1, dtype=np.int64)
    rows = simplices[entries // d]
    keep = np.arange(d)[None, :] != opposite[:, None]
    out = rows[keep].reshape(-1, d - 1)
    # (-1)^i times the face in increasing local order; fix odd signs by swapping two entries
    odd = (opposite % 2 == 1) & (d - 1 >= 2)
    out[odd, :2] = out[odd, 1::-1]
    return out


def misoriented_faces(faces: Faces) -> int:
    """Faces shared by two simplices that induce the same orientation on them.

    Parameters
    ----------
    faces : Faces
        A face grouping (:func:`face_structure`) with the induced signs.

    Returns
    -------
    int
        Their number.
    """
    if not len(faces.order):
        return 0
    group_sign = np.add.reduceat(faces.sign[faces.order].astype(np.int64), faces.starts[:-1])
    return int(np.count_nonzero((faces.counts == 2) & (group_sign != 0)))


def _first_order_labels(labels: np.ndarray) -> np.ndarray:
    """Labels renumbered 0..C-1 in order of each label's first occurrence."""
    if len(labels) == 0:
        return labels.astype(np.int64)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse]


def _vertex_components(simplices: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Components of the graph joining each simplex's vertices in a chain (every vertex of the
    mesh is a node: unused ones are components of their own)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a, b = simplices[:, :-1].ravel(), simplices[:, 1:].ravel()
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=True, connection="weak")


def component_count(simplices: np.ndarray, n_vertices: int, n_unused: int) -> int:
    """Connected components of a mesh whose vertex stars are all connected through faces (no
    singular vertex): then simplices sharing a vertex are joined through faces, and the
    components are those of the vertex graph (less the ``n_unused`` lone vertices).

    Parameters
    ----------
    simplices : (S, d) int ndarray
        The simplices; no vertex may be singular.
    n_vertices : int
        Vertices of the mesh, used or not.
    n_unused : int
        Vertices no simplex uses.

    Returns
    -------
    int
        Number of components.
    """
    if len(simplices) == 0:
        return 0
    return int(_vertex_components(simplices, n_vertices)[0]) - n_unused


def component_labels(simplices: np.ndarray, n_vertices: int, faces: Faces | None) -> np.ndarray:
    """(S,) int64 connected components of simplices joined through shared (d-2)-faces,
    numbered in order of each component's first simplex.

    ``faces=None`` says that every vertex's star is connected through faces (no singular
    vertex): then the components are those of the much smaller vertex graph.

    Parameters
    ----------
    simplices : (S, d) int ndarray
        The simplices to label.
    n_vertices : int
        Vertices of the mesh (the nodes of the vertex graph).
    faces : Faces or None
        The grouping of the mesh's faces (:func:`face_structure`), or ``None`` (above).

    Returns
    -------
    (S,) int64
        The component of each simplex.
    """
    s, d = simplices.shape
    if s == 0:
        return np.zeros(0, dtype=np.int64)
    if faces is None:
        labels = _vertex_components(simplices, n_vertices)[1][simplices[:, 0]]
    else:
        adj = face_adjacency(faces, d)
        _, labels = connected_labels(s, adj[:, 0], adj[:, 1])
    return _first_order_labels(labels)


def singular_vertices(simplices: np.ndarray, n_vertices: int, faces: Faces) -> int:
    """Vertices whose link is not a sphere (or, on the boundary, a disk), as far as we test.

    Two tests. (1) The star must be connected through (d-2)-faces containing the vertex:
    nodes are (simplex, vertex) incidences, joined when their simplices share a face used by
    exactly two simplices through that vertex; more than one group is a pinch point (or, in 4D,
    a pinched edge). With manifold faces this settles 3D, where a connected 2-regular link is a
    circle. (2) In 4D the link is a closed surface (boundary vertices: a surface with boundary),
    so we also require its Euler characteristic #edges - #triangles + #tetrahedra through the
    vertex to be 2 (1 on the boundary): a connected closed surface with chi = 2 is a sphere.

    Parameters
    ----------
    simplices : (S, d) int ndarray
        The simplices whose vertex stars are tested.
    n_vertices : int
        Vertices of the mesh (the answer counts among them).
    faces : Faces
        Their face grouping (:func:`face_structure`).

    Returns
    -------
    int
        Number of singular vertices.
    """
    s, d = simplices.shape
    if s == 0 or d == 2:
        return 0  # in 2D the faces are the vertices: face counts already say everything
    labels = _star_labels(faces)
    vertex = faces.columns.T.ravel()  # the vertex of each incidence node
    any_node = np.empty(n_vertices, dtype=np.int64)
    any_node[vertex] = np.arange(len(vertex))  # one node of each used vertex (whichever)
    singular = np.zeros(n_vertices, dtype=bool)
    singular[vertex[labels != labels[any_node[vertex]]]] = True
    if d == 4:
        singular |= _link_euler_defect(simplices, n_vertices, faces)
    return int(np.count_nonzero(singular))


def _star_labels(faces: Faces) -> np.ndarray:
    """(S*d,) a label per incidence node s*d + m (simplex s, its m-th smallest vertex): the
    smallest node joined to it through faces shared by exactly two simplices.

    Minimum-label propagation with pointer jumping: stars are small (tens of simplices), so it
    settles in a few vectorised rounds.
    """
    d, s = faces.columns.shape
    n = s * d
    itype = np.int32 if n < 2**31 else np.int64
    partner = np.full(n, -1, dtype=np.int64)
    pairs = faces.starts[:-1][faces.counts == 2]
    first, second = faces.order[pairs], faces.order[pairs + 1]
    partner[first], partner[second] = second, first
    partner = partner.reshape(s, d)
    base = np.arange(s, dtype=np.int64) * d
    # node (s, m) meets its simplex's d - 1 faces omitting k != m; in face k it is vertex
    # t = m - (m > k), which in the partner face (omitting k2) is vertex t + (t >= k2)
    neighbours = np.empty((d - 1, s, d), dtype=itype)
    for m in range(d):
        for slot, k in enumerate(kk for kk in range(d) if kk != m):
            p = partner[:, k]
            t = m - (m > k)
            k2 = p % d
            neighbours[slot, :, m] = np.where(p >= 0, p - k2 + t + (t >= k2), base + m)
    neighbours = neighbours.reshape(d - 1, n)
    labels = np.arange(n, dtype=itype)
    while True:
        new = labels.copy()
        for nb in neighbours:
            np.minimum(new, labels[nb], out=new)
        new = new[new]  # jump: each label to its own label
        if np.array_equal(new, labels):
            return labels
        labels = new


def _link_euler_defect(simplices: np.ndarray, n: int, faces: Faces) -> np.ndarray:
    """(V,) bool: used 4D vertices whose link's Euler characteristic is not 2 (1 on the boundary)."""
    cols = faces.columns
    # one representative entry per distinct triangle: its three vertices
    reps = faces.order[faces.starts[:-1]]
    rs, rk = reps // 4, reps % 4
    tri_vertices = np.stack([cols[t + (t >= rk), rs] for t in range(3)], axis=1)
    b = _bits(n)
    if 2 * b <= 63:
        keys = np.concatenate([(cols[i] << b) | cols[j] for i in range(4) for j in range(i + 1, 4)])
        edges = _unique_ints(keys)
        lo, hi = edges >> b, edges & ((1 << b) - 1)
    else:
        rows = np.concatenate([cols[[i, j]].T for i in range(4) for j in range(i + 1, 4)])
        lo, hi = np.unique(rows, axis=0).T
    chi = (
        np.bincount(lo, minlength=n)
        + np.bincount(hi, minlength=n)
        - np.bincount(tri_vertices.ravel(), minlength=n)
        + np.bincount(simplices.ravel(), minlength=n)
    )
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[tri_vertices[faces.counts == 1].ravel()] = True
    used = np.zeros(n, dtype=bool)
    used[simplices.ravel()] = True
    return used & (chi != np.where(on_boundary, 1, 2))
