"""Tests for ao4d.topology through SimplexMesh.check: closed, manifold, oriented, singular vertices.

Each defect is made by hand on a closed reference mesh (tests/_shapes.py) and must be counted.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from _shapes import ball_polytope, simplex_boundary, translated
from ao4d.mesh import MeshReport, SimplexMesh, concatenate

DIMS = (2, 3, 4)


@pytest.fixture(params=DIMS, ids=lambda d: f"{d}D")
def closed_mesh(request) -> SimplexMesh:
    return ball_polytope(request.param, 2)


def test_closed_mesh_is_ok(closed_mesh):
    report = closed_mesh.check()
    assert isinstance(report, MeshReport)
    assert report.ok and report.closed and report.manifold and report.oriented
    assert report.n_components == 1 and report.n_degenerate == 0 and report.n_unused_vertices == 0
    assert report.n_faces * 2 == report.n_simplices * closed_mesh.dim
    text = str(report)
    assert "=> OK" in text and f"{closed_mesh.n_simplices} simplices" in text


def test_removed_simplex_opens_mesh(closed_mesh):
    d = closed_mesh.dim
    open_mesh = SimplexMesh(closed_mesh.vertices, closed_mesh.simplices[1:])
    report = open_mesh.check()
    # the removed simplex leaves its d faces with one neighbour each
    assert report.n_boundary_faces == d and not report.closed and not report.ok
    assert report.oriented and report.manifold  # boundary vertices have disk links
    boundary = open_mesh.boundary_faces()
    assert boundary.shape == (d, d - 1)
    if d == 3:  # the hole's rim is an oriented loop: every vertex starts one edge, ends one
        assert sorted(boundary[:, 0]) == sorted(boundary[:, 1])
    if d == 4:  # the rim is a closed oriented surface: each directed edge meets its reverse
        directed = {tuple(e) for t in boundary.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        assert len(directed) == 3 * d and directed == {(b, a) for a, b in directed}
    assert np.array_equal(
        np.sort(np.sort(open_mesh.boundary_faces(), axis=1), axis=0),
        np.sort(np.sort(closed_mesh.simplices[0][[[j for j in range(d) if j != i] for i in range(d)]], axis=1), axis=0),
    )


def test_flipped_simplex_is_misoriented(closed_mesh):
    d = closed_mesh.dim
    simplices = closed_mesh.simplices.copy()
    simplices[3, [0, 1]] = simplices[3, [1, 0]]
    report = SimplexMesh(closed_mesh.vertices, simplices).check()
    assert report.n_misoriented_faces == d and not report.oriented
    assert report.closed and not report.ok


def test_face_shared_by_three_is_nonmanifold(closed_mesh):
    d = closed_mesh.dim
    # a copy of simplex 0 with one vertex replaced by a new point: its face opposite that vertex
    # is now shared by three simplices; its other d-1 faces are new boundary faces
    vertices = np.vstack([closed_mesh.vertices, np.full(d, 0.1)])
    extra = closed_mesh.simplices[0].copy()
    extra[0] = len(vertices) - 1
    report = SimplexMesh(vertices, np.vstack([closed_mesh.simplices, extra])).check()
    assert report.n_nonmanifold_faces == 1 and not report.manifold and not report.closed
    assert report.n_boundary_faces == d - 1


@pytest.mark.parametrize("d", DIMS)
def test_degenerate_simplices_counted(d):
    mesh = simplex_boundary(d)
    vertices = mesh.vertices.copy()
    # vertex 2 onto vertex 1 (plus a round-off-sized nudge): the d-1 facets holding both
    # collapse to zero measure; the topology is untouched
    vertices[2] = vertices[1] + 1e-15
    collapsed = SimplexMesh(vertices, mesh.simplices)
    report = collapsed.check()
    assert report.n_degenerate == d - 1 and report.closed and report.oriented
    if d > 2:  # 2D: the nudge is a length of 1.4e-15, a degenerate segment only with rtol > 0
        assert collapsed.check(rtol=0.0).n_degenerate == 0
    assert mesh.check().n_degenerate == 0


@pytest.mark.parametrize(("d", "shared"), [(3, "vertex"), (4, "vertex"), (4, "edge")])
def test_pinched_meshes_are_singular(d, shared):
    """Two simplex boundaries touching at a vertex (or, in 4D, along an edge) are closed and
    oriented, and no face is shared, but the star of each touching vertex has two pieces.
    (In 3D an edge is a face, so a shared edge is a non-manifold face, tested above.)"""
    a = simplex_boundary(d)
    e = np.eye(d)
    # point reflection of a through e_1 touches it only at e_1; through (e_1 + e_2)/2 it
    # touches along the edge e_1 e_2 (with e_1, e_2 swapped). transformed() keeps b outward.
    centre = e[0] if shared == "vertex" else (e[0] + e[1]) / 2
    b = a.transformed(-np.eye(d), 2 * centre)
    index_b = np.arange(b.n_vertices) + a.n_vertices
    if shared == "vertex":
        index_b[1] = 1
    else:
        index_b[1], index_b[2] = 2, 1
    mesh = SimplexMesh(np.vstack([a.vertices, b.vertices]), np.vstack([a.simplices, index_b[b.simplices]]))
    report = mesh.check()
    assert report.closed and report.oriented and report.n_nonmanifold_faces == 0
    assert report.n_singular_vertices == (1 if shared == "vertex" else 2)
    assert not report.manifold and not report.ok
    assert report.n_components == 2 and report.n_unused_vertices == (1 if shared == "vertex" else 2)
    assert mesh.volume == pytest.approx(2 / math.factorial(d), rel=1e-12)


def test_vertex_with_torus_link_is_singular():
    """The suspension of a triangulated torus: a closed, oriented 3-pseudo-manifold whose two
    apexes have a torus as link (Euler characteristic 0, not 2). Their stars are connected, so
    only the link Euler test can catch them; torus vertices have links that are suspended
    circles (spheres) and pass."""
    k = 6
    a, b = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    vid = lambda i, j: (i % k) * k + (j % k)  # noqa: E731
    triangles = np.concatenate([
        np.stack([vid(a, b), vid(a + 1, b), vid(a + 1, b + 1)], axis=-1).reshape(-1, 3),
        np.stack([vid(a, b), vid(a + 1, b + 1), vid(a, b + 1)], axis=-1).reshape(-1, 3),
    ])
    angle = 2 * np.pi * np.arange(k) / k
    u, v = np.meshgrid(angle, angle, indexing="ij")
    torus = np.stack([np.cos(u), np.sin(u), np.cos(v), np.sin(v)], axis=-1).reshape(-1, 4) / math.sqrt(2)
    top, bottom = k * k, k * k + 1
    vertices = np.vstack([torus, [[0.1, 0.2, 0.3, 0.9], [-0.2, 0.1, -0.3, -0.8]]])
    # apex first; the bottom cone reversed so the shared torus triangles get opposite orientations
    tets = np.concatenate([
        np.column_stack([np.full(len(triangles), top), triangles]),
        np.column_stack([np.full(len(triangles), bottom), triangles[:, [0, 2, 1]]]),
    ])
    report = SimplexMesh(vertices, tets).check()
    assert report.closed and report.oriented and report.n_nonmanifold_faces == 0
    assert report.n_singular_vertices == 2 and not report.manifold


@pytest.mark.slow
def test_check_two_million_tetrahedra():
    # 80 translated copies of a 24576-tetrahedron polytope: the vectorised check must stay
    # correct (and feasible) at millions of simplices
    base = ball_polytope(4, 8)
    mesh = concatenate([translated(base, [3.0 * i, 0, 0, 0]) for i in range(80)])
    report = mesh.check()
    assert report.ok and report.n_components == 80 and report.n_simplices == 80 * base.n_simplices
    assert mesh.volume == pytest.approx(80 * base.volume, rel=1e-12)
