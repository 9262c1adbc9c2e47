"""Reference shapes for the mesh tests, built independently of ao4d's geometry.

Convex polytopes come from scipy's ConvexHull (qhull), oriented with ``numpy.linalg.det``
straight from the DESIGN.md definition ``n . x = det[p1 - p0; ...; p_{d-1} - p0; x]``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.spatial import ConvexHull

from ao4d.mesh import SimplexMesh


def orient_outward(vertices: np.ndarray, simplices: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Swap two vertices of every simplex whose DESIGN.md normal points towards ``inside``."""
    simplices = np.array(simplices, dtype=np.int64)
    p = vertices[simplices]
    rows = np.concatenate([p[:, 1:] - p[:, :1], (p[:, 0] - inside)[:, None]], axis=1)
    wrong = np.linalg.det(rows) < 0
    simplices[wrong, -2:] = simplices[wrong, :-3:-1]
    return simplices


def simplex_boundary(d: int) -> SimplexMesh:
    """Boundary of the standard d-simplex conv(0, e_1, ..., e_d), outward."""
    vertices = np.vstack([np.zeros(d), np.eye(d)])
    facets = [[j for j in range(d + 1) if j != i] for i in range(d + 1)]
    return SimplexMesh(vertices, orient_outward(vertices, facets, vertices.mean(axis=0)))


def cube_sphere_points(d: int, n: int) -> np.ndarray:
    """Grid points of the boundary of [-1, 1]^d (n intervals per side) pushed onto S^(d-1)."""
    g = np.linspace(-1.0, 1.0, n + 1)
    p = np.stack(np.meshgrid(*[g] * d, indexing="ij"), axis=-1).reshape(-1, d)
    p = p[np.abs(p).max(axis=1) == 1.0]
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def ball_polytope(d: int, n: int, radius: float = 1.0) -> SimplexMesh:
    """Convex polytope inscribed in the d-ball: hull of cube-sphere points, outward."""
    p = radius * cube_sphere_points(d, n)
    hull = ConvexHull(p)
    return SimplexMesh(p, orient_outward(p, hull.simplices, np.zeros(d)))


def tesseract_boundary(half: float = 1.0) -> SimplexMesh:
    """Boundary of [-half, half]^4: each cubic facet cut into 6 Kuhn tetrahedra.

    Every facet uses the same axis order for its Kuhn split, so two facets sharing a square
    cut it along the same diagonal (min corner to max corner): the mesh is conforming.
    """
    corners = np.array(list(itertools.product((-half, half), repeat=4)))
    index = {tuple(c): i for i, c in enumerate(corners)}
    tets = []
    for axis in range(4):
        free = [k for k in range(4) if k != axis]
        for side in (-half, half):
            for perm in itertools.permutations(free):
                point = np.full(4, -half)
                point[axis] = side
                tet = [index[tuple(point)]]
                for k in perm:
                    point[k] = half
                    tet.append(index[tuple(point)])
                tets.append(tet)
    return SimplexMesh(corners, orient_outward(corners, tets, np.zeros(4)))


def ball_volume(d: int, r: float = 1.0) -> float:
    return math.pi ** (d / 2) / math.gamma(d / 2 + 1) * r**d


def sphere_measure(d: int, r: float = 1.0) -> float:
    return d * ball_volume(d, r) / r


def translated(mesh: SimplexMesh, offset) -> SimplexMesh:
    return SimplexMesh(mesh.vertices + np.asarray(offset, dtype=float), mesh.simplices)


def graded_icosphere():
    """A trimesh icosphere with a graded ``"ao"`` vertex attribute in [0, 1] (a stand-in slice)."""
    import trimesh

    tri = trimesh.creation.icosphere(subdivisions=2)
    tri.vertex_attributes["ao"] = (tri.vertices[:, 0] + 1) / 2
    return tri
