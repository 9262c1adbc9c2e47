"""A brute-force reference for the face topology that ``tests/test_topology.py`` compares
:meth:`ao4d.SimplexMesh.check`, :meth:`~ao4d.SimplexMesh.components` and
:meth:`~ao4d.SimplexMesh.boundary_faces` against.

It shares nothing with :mod:`ao4d.topology` but the :class:`~ao4d.topology.MeshReport` it fills
in: plain Python over lists of vertex indices, faces keyed by sorted tuples in a dict, the sign
of a face from the parity of the permutation that sorts it (counted inversions), components by
union-find, vertex stars and links walked vertex by vertex. Small meshes only (thousands of
simplices). The definitions are those the report documents:

- a (d-2)-face is shared by the simplices that contain its d-1 vertices; a simplex induces on
  its face opposite local vertex i the orientation (-1)^i times the parity that sorts the face;
- boundary faces are used once, non-manifold faces three times or more, misoriented faces twice
  with the same induced orientation;
- components join simplices that share a face (any number of them), numbered by their first
  simplex;
- a used vertex is singular when its star is not connected through the faces through it that
  exactly two simplices share, or (4D) when the Euler characteristic of its link (edges minus
  triangles plus tetrahedra through it, each counted once, tetrahedra as listed) is not 2, or
  1 for a vertex on a boundary face.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from ao4d.topology import MeshReport


def _parity(seq: list[int]) -> int:
    """+1 for an even number of inversions, -1 for an odd one."""
    inversions = sum(1 for a, b in combinations(seq, 2) if a > b)
    return -1 if inversions % 2 else 1


def face_table(simplices: list[list[int]]) -> dict[tuple[int, ...], list[tuple[int, int, int]]]:
    """Sorted face -> [(simplex, omitted local vertex, induced sign), ...] in simplex order."""
    table: dict[tuple[int, ...], list[tuple[int, int, int]]] = {}
    for si, simplex in enumerate(simplices):
        for i in range(len(simplex)):
            face = simplex[:i] + simplex[i + 1 :]
            sign = (-1) ** i * _parity(face)
            table.setdefault(tuple(sorted(face)), []).append((si, i, sign))
    return table


def _find(parent: list[int], x: int) -> int:
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


def _union(parent: list[int], a: int, b: int) -> None:
    ra, rb = _find(parent, a), _find(parent, b)
    if ra != rb:
        parent[max(ra, rb)] = min(ra, rb)


def reference_components(simplices, n_vertices: int) -> np.ndarray:
    """(S,) labels of the components through shared faces, numbered in order of first simplex."""
    rows = np.asarray(simplices).tolist()
    return _components(len(rows), face_table(rows))


def _components(n_simplices: int, table: dict) -> np.ndarray:
    parent = list(range(n_simplices))
    for users in table.values():
        for si, _, _ in users[1:]:
            _union(parent, users[0][0], si)
    labels: dict[int, int] = {}
    return np.array([labels.setdefault(_find(parent, si), len(labels)) for si in range(n_simplices)], dtype=np.int64)


def reference_boundary_faces(simplices, n_vertices: int) -> np.ndarray:
    """(B, d-1) the faces used once, each as its simplex induces it (an odd face with its first
    two vertices swapped)."""
    rows = np.asarray(simplices).tolist()
    d = len(rows[0]) if rows else np.asarray(simplices).shape[1]
    out = []
    for users in face_table(rows).values():
        if len(users) == 1:
            si, i, _ = users[0]
            face = rows[si][:i] + rows[si][i + 1 :]
            if i % 2 and len(face) >= 2:
                face[0], face[1] = face[1], face[0]
            out.append(face)
    return np.array(out, dtype=np.int64).reshape(-1, d - 1)


def _singular(rows: list[list[int]], pairs: dict, vertex: int, star: list[int], on_boundary: bool) -> bool:
    """Whether ``vertex`` (used by the simplices ``star``; ``on_boundary``: it lies on a face
    used once) is singular (see the module text). ``pairs``: the faces shared by exactly two
    simplices, by sorted vertices."""
    parent = {si: si for si in star}
    for si in star:
        simplex = rows[si]
        for i in range(len(simplex)):
            if simplex[i] == vertex:
                continue  # the face opposite the vertex does not contain it
            pair = pairs.get(tuple(sorted(simplex[:i] + simplex[i + 1 :])))
            if pair is not None:
                _union(parent, *pair)
    if len({_find(parent, si) for si in star}) > 1:
        return True
    if len(rows[0]) != 4:
        return False
    edges, triangles = set(), set()
    for si in star:
        others = [w for w in rows[si] if w != vertex]
        edges.update(others)
        triangles.update(tuple(sorted(pair)) for pair in combinations(others, 2))
    # link: vertices = edges through the vertex, edges = triangles, triangles = tetrahedra
    chi = len(edges) - len(triangles) + len(star)
    return chi != (1 if on_boundary else 2)


def reference_report(mesh, rtol: float = 1e-12) -> MeshReport:
    """The :class:`~ao4d.topology.MeshReport` of ``mesh`` by brute force (measures and volume,
    which are geometry, taken from the mesh)."""
    rows = np.asarray(mesh.simplices, dtype=np.int64).tolist()
    n, d = mesh.n_vertices, mesh.dim
    table = face_table(rows)
    stars: dict[int, list[int]] = {}
    for si, simplex in enumerate(rows):
        for w in simplex:
            stars.setdefault(w, []).append(si)
    boundary = {w for face, users in table.items() if len(users) == 1 for w in face}
    pairs = {face: (users[0][0], users[1][0]) for face, users in table.items() if len(users) == 2}
    singular = 0 if d == 2 else sum(_singular(rows, pairs, w, star, w in boundary) for w, star in stars.items())
    labels = _components(len(rows), table)
    measures = mesh.simplex_measures
    return MeshReport(
        dim=d,
        n_vertices=n,
        n_simplices=len(rows),
        n_faces=len(table),
        n_boundary_faces=sum(1 for users in table.values() if len(users) == 1),
        n_nonmanifold_faces=sum(1 for users in table.values() if len(users) > 2),
        n_misoriented_faces=sum(1 for users in table.values() if len(users) == 2 and users[0][2] == users[1][2]),
        n_singular_vertices=int(singular),
        n_degenerate=int(np.count_nonzero(measures <= rtol * mesh.scale ** (d - 1))),
        n_components=len(set(labels.tolist())),
        n_unused_vertices=n - len(stars),
        volume=mesh.volume,
    )
