"""Scenes for the ray-casting and AO tests: flat patches, sphere hulls (qhull), ray sets.

Built with numpy and scipy only; orientation from the DESIGN.md convention via ao4d.geometry.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import ConvexHull

import ao4d
from ao4d.geometry import simplex_normals


def oriented(vertices, simplices, direction):
    """Swap two vertices of simplices whose normal points against ``direction`` (V, d) or (d,)."""
    simplices = np.array(simplices)
    n = simplex_normals(np.asarray(vertices, dtype=float), simplices)
    ref = np.broadcast_to(direction, n.shape) if np.ndim(direction) == 1 else direction
    flip = np.einsum("sd,sd->s", n, ref) < 0
    simplices[flip, :2] = simplices[flip, 1::-1]
    return simplices


def flat_patch(d, lo, hi, height, n=4, axis=None):
    """A Kuhn-triangulated axis-aligned (d-1)-box at ``x[axis] = height`` (default: last axis).

    ``lo``/``hi`` bound the other d-1 coordinates; normals point towards +axis.
    """
    axis = d - 1 if axis is None else axis
    others = [k for k in range(d) if k != axis]
    lo = np.broadcast_to(np.asarray(lo, float), (d - 1,))
    hi = np.broadcast_to(np.asarray(hi, float), (d - 1,))
    ticks = [np.linspace(a, b, n + 1) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*ticks, indexing="ij"), -1).reshape(-1, d - 1)
    vertices = np.zeros((len(grid), d))
    vertices[:, others] = grid
    vertices[:, axis] = height
    strides = (n + 1) ** np.arange(d - 2, -1, -1)
    cells = np.stack(np.meshgrid(*[np.arange(n)] * (d - 1), indexing="ij"), -1).reshape(-1, d - 1)
    simplices = []
    for perm in itertools.permutations(range(d - 1)):
        corner, ids = cells.copy(), [cells @ strides]
        for k in perm:
            corner = corner.copy()
            corner[:, k] += 1
            ids.append(corner @ strides)
        simplices.append(np.stack(ids, 1))
    up = np.eye(d)[axis]
    return vertices, oriented(vertices, np.concatenate(simplices), up)


def sphere_hull(rng, d, n_points, radius=1.0, centre=0.0):
    """Outward-oriented convex hull of points on a sphere: a closed (d-1)-manifold."""
    points = rng.normal(size=(n_points, d))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    hull = ConvexHull(points)
    simplices = oriented(points, hull.simplices, hull.equations[:, :d])
    return radius * points + centre, simplices


def merge(*parts):
    vertices, simplices, offset = [], [], 0
    for v, s in parts:
        vertices.append(v)
        simplices.append(s + offset)
        offset += len(v)
    return ao4d.SimplexMesh(np.concatenate(vertices), np.concatenate(simplices))


def sphere_over_ground(rng, d, *, mirrored=False):
    """A sphere of radius 0.5 at height 0.6 over a ground patch [-2, 2]^(d-1) at height 0."""
    ground = flat_patch(d, -2.0, 2.0, 0.0, n=6 if d < 4 else 4)
    v, s = sphere_hull(rng, d, {2: 40, 3: 300, 4: 400}[d])
    if mirrored:  # make the point set symmetric in x so the hull is a mirror-symmetric solid
        v = np.concatenate([v, v * np.r_[-1.0, np.ones(d - 1)]])
        hull = ConvexHull(v)
        s = oriented(v, hull.simplices, hull.equations[:, :d])
    centre = np.zeros(d)
    centre[-1] = 0.6
    return merge(ground, (0.5 * v + centre, s))


def up_points(rng, d, n, half):
    """Points on the ground plane within ``half`` of the origin, with normal +e_last."""
    p = np.zeros((n, d))
    p[:, :-1] = rng.uniform(-half, half, size=(n, d - 1))
    normals = np.tile(np.eye(d)[-1], (n, 1))
    return p, normals


def random_rays(rng, d, n, spread=1.5):
    o = rng.uniform(-spread, spread, size=(n, d))
    w = rng.normal(size=(n, d))
    return o, w / np.linalg.norm(w, axis=1, keepdims=True)


def soup_scene(rng, d, n=300):
    centres = rng.uniform(-1, 1, size=(n, 1, d))
    v = (centres + 0.25 * rng.normal(size=(n, d, d))).reshape(-1, d)
    return ao4d.SimplexMesh(v, np.arange(n * d).reshape(n, d))


def embree_scene(rng):
    import trimesh

    parts = [
        trimesh.creation.icosphere(subdivisions=3, radius=0.6),
        trimesh.creation.box(extents=(0.5, 0.4, 0.3)).apply_translation((0.9, 0.0, 0.0)),
    ]
    tri = rng.uniform(-1.2, 1.2, size=(1000, 1, 3)) + 0.12 * rng.normal(size=(1000, 3, 3))
    parts.append(trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3000).reshape(-1, 3), process=False))
    scene = trimesh.util.concatenate(parts)
    return scene, ao4d.SimplexMesh(scene.vertices, scene.faces)


def random_soup(rng, d, n, size=0.15):
    """n random (d-1)-simplices with corners near uniform centres in the unit cube."""
    centres = rng.random((n, 1, d))
    vertices = (centres + size * rng.normal(size=(n, d, d))).reshape(-1, d)
    return vertices, np.arange(n * d).reshape(n, d)
