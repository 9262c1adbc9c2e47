"""Tests for ao4d.mesh (SimplexMesh, check, slicing, concatenate) and ao4d.meshio (file formats).

Reference shapes are built here independently of ao4d: convex polytopes from scipy's ConvexHull
(qhull), oriented with ``numpy.linalg.det`` straight from the DESIGN.md definition
``n . x = det[p1 - p0; ...; p_{d-1} - p0; x]``, and 3D meshes from trimesh.
"""

from __future__ import annotations

import itertools
import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial import ConvexHull

from ao4d import meshio
from ao4d.mesh import MeshReport, SimplexMesh, concatenate, hyperplane_basis, simplex_normals

DIMS = (2, 3, 4)


# --------------------------------------------------------------------------------------------
# reference shapes (independent of ao4d)
# --------------------------------------------------------------------------------------------


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


@pytest.fixture(scope="module")
def ball4() -> SimplexMesh:
    return ball_polytope(4, 8)


# --------------------------------------------------------------------------------------------
# exact measures and volumes
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", DIMS)
def test_simplex_boundary_exact(d):
    mesh = simplex_boundary(d)
    # d facets in the coordinate hyperplanes, each a standard (d-1)-simplex of measure
    # 1/(d-1)!, and the slanted facet conv(e_1..e_d), sqrt(d) times larger.
    assert mesh.measure == pytest.approx((d + math.sqrt(d)) / math.factorial(d - 1), rel=1e-14)
    assert mesh.volume == pytest.approx(1.0 / math.factorial(d), rel=1e-14)
    assert mesh.check().ok


def test_tesseract_exact():
    half = 1.5
    mesh = tesseract_boundary(half)
    side = 2 * half
    assert mesh.volume == pytest.approx(side**4, rel=1e-14)
    assert mesh.measure == pytest.approx(8 * side**3, rel=1e-14)
    report = mesh.check()
    assert report.ok and report.n_simplices == 48 and report.n_faces == 96  # 48 * 4 / 2
    # each facet normal is +-e_k: unit normals are signed axis vectors pointing outward
    normals = mesh.simplex_normals
    assert np.allclose(np.abs(normals).max(axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", normals, mesh.simplex_centroids) > 0)


def test_tesseract_matches_qhull_volume():
    # the same polytope from qhull's triangulation (different tetrahedra): same volume/measure
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=4)))
    hull = ConvexHull(corners)
    mesh = SimplexMesh(corners, orient_outward(corners, hull.simplices, np.zeros(4)))
    assert mesh.volume == pytest.approx(hull.volume, rel=1e-12)
    assert mesh.measure == pytest.approx(hull.area, rel=1e-12)
    assert mesh.volume == pytest.approx(16.0, rel=1e-12)


@pytest.mark.parametrize("d", DIMS)
def test_matches_qhull_on_random_hull(d):
    rng = np.random.default_rng(1 + d)
    p = rng.normal(size=(60, d))
    hull = ConvexHull(p)
    mesh = SimplexMesh(p, orient_outward(p, hull.simplices, p[hull.vertices].mean(axis=0)))
    # qhull sums the same simplices: agreement to round-off
    assert mesh.volume == pytest.approx(hull.volume, rel=1e-12)
    assert mesh.measure == pytest.approx(hull.area, rel=1e-12)
    assert mesh.check().ok


def test_ball4_converges_to_pi2_over_2():
    """Inscribed polytopes of the 4-ball: volume and boundary converge like h^2.

    The cube-sphere points have spacing h ~ 1/n, and an inscribed polytope misses the ball by
    O(h^2) (chord sagitta), so the relative error e(n) ~ C / n^2: e(4)/e(8) ~ 4, and the
    Richardson extrapolation (4 V(8) - V(4)) / 3 cancels the h^2 term (measured: 0.3% off).
    """
    r = 1.3
    coarse, fine = ball_polytope(4, 4, r), ball_polytope(4, 8, r)
    exact_v, exact_m = math.pi**2 / 2 * r**4, 2 * math.pi**2 * r**3
    for mesh in (coarse, fine):  # inscribed in a convex body: strictly smaller
        assert 0 < mesh.volume < exact_v and 0 < mesh.measure < exact_m
    ev = [1 - m.volume / exact_v for m in (coarse, fine)]
    em = [1 - m.measure / exact_m for m in (coarse, fine)]
    assert 3.0 < ev[0] / ev[1] < 5.0 and 3.0 < em[0] / em[1] < 5.0
    assert (4 * fine.volume - coarse.volume) / 3 == pytest.approx(exact_v, rel=0.01)
    assert (4 * fine.measure - coarse.measure) / 3 == pytest.approx(exact_m, rel=0.01)


@pytest.mark.slow
def test_ball4_fine_polytope():
    # n = 24: e(n) ~ 1.98 / n^2 = 0.34% (constant measured at n = 8, 12)
    mesh = ball_polytope(4, 24)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(math.pi**2 / 2, rel=0.005)
    assert mesh.measure == pytest.approx(2 * math.pi**2, rel=0.005)


@pytest.mark.parametrize("d", DIMS)
def test_vertex_normals_of_ball_are_radial(d):
    # on a polytope inscribed in a sphere, the measure-weighted vertex normal tends to the
    # radial direction; at n = 8 the facets span ~15 degrees, and the near-symmetric fans keep
    # the deviation well below that (measured max: 1.1, 2.1, 3.0 degrees in 2D, 3D, 4D)
    mesh = ball_polytope(d, 8)
    cosines = np.einsum("ij,ij->i", mesh.vertex_normals, mesh.vertices)
    assert cosines.min() > math.cos(math.radians(5))
    assert np.allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0)


# --------------------------------------------------------------------------------------------
# 3D cross-check with trimesh
# --------------------------------------------------------------------------------------------


def _trimesh_shapes():
    trimesh = pytest.importorskip("trimesh")
    cylinder = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=16)
    side = np.abs(cylinder.face_normals[:, 2]) < 0.5  # drop the two caps: a tube with two rims
    return {
        "icosphere": trimesh.creation.icosphere(subdivisions=2, radius=1.7),
        "box": trimesh.creation.box(extents=(1.0, 2.0, 3.0)),
        "torus": trimesh.creation.torus(2.0, 0.5, major_sections=24, minor_sections=12),
        "open_cylinder": trimesh.Trimesh(cylinder.vertices, cylinder.faces[side], process=False),
    }


@pytest.mark.parametrize("name", ["icosphere", "box", "torus", "open_cylinder"])
def test_3d_matches_trimesh(name):
    import trimesh

    tm = _trimesh_shapes()[name]
    mesh = SimplexMesh.from_trimesh(tm)
    assert mesh.measure == pytest.approx(tm.area, rel=1e-12)
    assert np.allclose(mesh.simplex_measures, tm.area_faces, rtol=1e-12, atol=0)
    assert np.allclose(mesh.simplex_normals, tm.face_normals, atol=1e-12)
    # trimesh's own vertex_normals are angle-weighted: compare with its area-weighted mean
    area_weighted = trimesh.geometry.mean_vertex_normals(
        len(tm.vertices), tm.faces, tm.face_normals * tm.area_faces[:, None]
    )
    length = np.linalg.norm(area_weighted, axis=1, keepdims=True)
    # unused vertices (the open cylinder's cap centres) must get zero normals
    area_weighted = np.divide(area_weighted, length, out=np.zeros_like(area_weighted), where=length > 0)
    assert np.allclose(mesh.vertex_normals, area_weighted, atol=1e-12)
    report = mesh.check()
    assert report.closed == tm.is_watertight
    assert report.oriented == tm.is_winding_consistent
    # (trimesh's body_count would also count unused vertices as bodies; split() does not)
    assert report.n_components == len(tm.split(only_watertight=False))
    if tm.is_watertight:
        assert mesh.volume == pytest.approx(tm.volume, rel=1e-12)
        assert report.ok
    else:
        assert report.n_boundary_faces == 32  # two rims of 16 edges
        assert report.n_unused_vertices == 2 and np.all(mesh.vertex_normals[length[:, 0] == 0] == 0)


def test_to_trimesh_round_trip():
    tm = _trimesh_shapes()["torus"]
    back = SimplexMesh.from_trimesh(tm).to_trimesh()
    assert np.array_equal(back.faces, tm.faces) and np.array_equal(back.vertices, tm.vertices)
    with pytest.raises(ValueError, match="`to_trimesh` needs a 3D mesh"):
        simplex_boundary(4).to_trimesh()


# --------------------------------------------------------------------------------------------
# check(): each defect detected and counted
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# components, split, concatenate
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", DIMS)
def test_concatenate_components_split(d):
    base = ball_polytope(d, 2)
    base.point_data["radius"] = np.linalg.norm(base.vertices, axis=1)
    base.cell_data["area"] = base.simplex_measures.copy()
    parts = [base, base.transformed(2 * np.eye(d), 5.0), base.transformed(np.eye(d), -5.0)]
    both = concatenate(parts)
    assert both.volume == pytest.approx(sum(p.volume for p in parts), rel=1e-12)
    assert both.volume == pytest.approx((2 + 2**d) * base.volume, rel=1e-12)
    ids = both.cell_data["object_id"]
    assert np.array_equal(ids, np.repeat([0, 1, 2], base.n_simplices))
    assert np.array_equal(both.point_data["radius"][: base.n_vertices], base.point_data["radius"])
    labels = both.components()
    assert both.check().n_components == 3
    # labels are a relabelling of object ids
    assert len(set(zip(labels.tolist(), ids.tolist()))) == 3
    pieces = both.split()
    assert [p.n_simplices for p in pieces] == [base.n_simplices] * 3
    assert sorted(p.volume for p in pieces) == pytest.approx(sorted(p.volume for p in parts), rel=1e-12)
    assert np.allclose(pieces[0].point_data["radius"], base.point_data["radius"])


@settings(max_examples=25, deadline=None)
@given(
    scales=st.lists(st.floats(0.1, 10), min_size=1, max_size=4),
    shift=st.floats(-50, 50),
    d=st.sampled_from(DIMS),
)
def test_concatenate_sums_volumes(scales, shift, d):
    base = simplex_boundary(d)
    parts = [base.transformed(s * np.eye(d), shift + 3 * i) for i, s in enumerate(scales)]
    both = concatenate(parts)
    assert both.volume == pytest.approx(sum(s**d for s in scales) / math.factorial(d), rel=1e-9)
    assert both.measure == pytest.approx(sum(p.measure for p in parts), rel=1e-12)
    assert both.n_simplices == sum(p.n_simplices for p in parts)


def test_concatenate_errors():
    a, b = simplex_boundary(3), simplex_boundary(4)
    with pytest.raises(ValueError, match="at least one"):
        concatenate([])
    with pytest.raises(ValueError, match="same dimension"):
        concatenate([a, b])
    with pytest.raises(TypeError, match=r"`meshes\[1\]` must be a SimplexMesh"):
        concatenate([a, "mesh"])
    c = a.copy()
    c.point_data["ao"] = np.zeros(c.n_vertices)
    with pytest.raises(ValueError, match="same point_data names"):
        concatenate([a, c])


def test_submesh_errors():
    mesh = simplex_boundary(3)
    with pytest.raises(ValueError, match="`which` mask must have length 4"):
        mesh.submesh(np.ones(3, dtype=bool))
    with pytest.raises(IndexError, match="outside"):
        mesh.submesh([7])
    with pytest.raises(TypeError, match="boolean mask or integer"):
        mesh.submesh([0.5])


# --------------------------------------------------------------------------------------------
# property tests: rigid motions, reflections, scaling, reversal
# --------------------------------------------------------------------------------------------


def _orthogonal(entries: np.ndarray) -> np.ndarray:
    q, r = np.linalg.qr(entries)
    return q * np.sign(np.diag(r))


def _matrix_strategy(d):
    elements = st.floats(-1, 1, allow_nan=False).filter(lambda x: abs(x) > 1e-3)
    return hnp.arrays(np.float64, (d, d), elements=elements).filter(
        lambda m: abs(np.linalg.det(m)) > 1e-2
    )


@pytest.mark.parametrize("d", DIMS)
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_rigid_motions_keep_volume_and_measure(d, data):
    mesh = ball_polytope(d, 2) if d < 4 else tesseract_boundary(0.7)
    q = _orthogonal(data.draw(_matrix_strategy(d)))
    shift = data.draw(hnp.arrays(np.float64, d, elements=st.floats(-100, 100)))
    moved = mesh.transformed(q, shift)  # transformed() reverses orientation when det(q) < 0
    # round-off: ~1e-16 relative per coordinate, amplified by |shift| / size <= 1e2 and by the
    # (d-1)-fold products in the normals: 1e-10 is ample
    assert moved.volume == pytest.approx(mesh.volume, rel=1e-10)
    assert moved.measure == pytest.approx(mesh.measure, rel=1e-10)
    assert moved.check().ok


@pytest.mark.parametrize("d", DIMS)
@settings(max_examples=25, deadline=None)
@given(scale=st.floats(1e-3, 1e3))
def test_scaling_and_reversal(d, scale):
    mesh = ball_polytope(d, 2)
    scaled = mesh.transformed(scale * np.eye(d))
    assert scaled.volume == pytest.approx(scale**d * mesh.volume, rel=1e-12)
    assert scaled.measure == pytest.approx(scale ** (d - 1) * mesh.measure, rel=1e-12)
    flipped = scaled.flipped()
    assert flipped.volume == pytest.approx(-scaled.volume, rel=1e-12)
    assert np.allclose(flipped.simplex_normals, -scaled.simplex_normals, atol=1e-12)
    assert flipped.check().ok  # consistently inward is still consistent


@pytest.mark.parametrize("d", DIMS)
@settings(max_examples=20, deadline=None)
@given(matrix=st.data())
def test_general_linear_map_scales_volume_by_det(d, matrix):
    # volume is multiplied by |det A| exactly (transformed() keeps the orientation outward)
    m = matrix.draw(_matrix_strategy(d))
    mesh = simplex_boundary(d)
    moved = mesh.transformed(m)
    assert moved.volume == pytest.approx(abs(np.linalg.det(m)) * mesh.volume, rel=1e-9)


@settings(max_examples=30, deadline=None)
@given(hnp.arrays(np.float64, 4, elements=st.floats(-10, 10)).filter(lambda v: np.linalg.norm(v) > 1e-3))
def test_hyperplane_basis_properties(normal):
    basis = hyperplane_basis(normal)
    n = normal / np.linalg.norm(normal)
    assert basis.shape == (3, 4)
    assert np.allclose(basis @ basis.T, np.eye(3), atol=1e-12)
    assert np.allclose(basis @ n, 0.0, atol=1e-12)
    assert np.linalg.det(np.vstack([basis, n])) == pytest.approx(1.0, abs=1e-12)
    assert np.array_equal(hyperplane_basis(normal), basis)  # deterministic


def test_hyperplane_basis_axes():
    assert np.array_equal(hyperplane_basis([0, 0, 0, 3]), np.eye(4)[:3])
    with pytest.raises(ValueError, match="`normal` must be a nonzero vector"):
        hyperplane_basis([0, 0, 0, 0])
    with pytest.raises(ValueError, match="`normal` must have shape"):
        hyperplane_basis([0, 0, 1])


# --------------------------------------------------------------------------------------------
# slicing 4D meshes
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("c", [0.0, 0.4, -0.7])
def test_slice_ball_is_sphere(ball4, c):
    """The slice w = c of the unit 4-ball is the 3-ball of radius sqrt(1 - c^2).

    The polytope is inscribed, so its slice lies inside the exact ball: volume and area are
    below the exact values. Its vertices lie on polytope edges (chords), at most a sagitta
    h^2 / 8 inside S^3 with chord length h ~ 0.3 at n = 8, so points of the slice are short of
    the unit sphere by < 1.2%, i.e. short of the slice radius rho by < 0.012 / rho relative:
    volume short by < 3 * 0.012 / rho, area by < 2 * 0.012 / rho; the flat facets between the
    vertices add a deficit of the same order, hence the factor 2. (Measured volume deficits:
    1.8%, 2.3%, 3.2% for c = 0, 0.4, -0.7 against bounds of 7.2%, 7.9%, 10%.)
    """
    sl = ball4.slice([0, 0, 0, c], [0, 0, 0, 1])
    rho = math.sqrt(1 - c * c)
    exact_v, exact_a = 4 / 3 * math.pi * rho**3, 4 * math.pi * rho**2
    assert sl.is_watertight and sl.is_winding_consistent
    assert 0 < sl.volume < exact_v and 0 < sl.area < exact_a
    assert sl.volume == pytest.approx(exact_v, rel=2 * 3 * 0.012 / rho)
    assert sl.area == pytest.approx(exact_a, rel=2 * 2 * 0.012 / rho)
    radii = np.linalg.norm(sl.vertices, axis=1)
    assert radii.max() <= rho + 1e-12 and radii.min() > rho - 0.03
    assert np.array_equal(sl.face_attributes["simplex"].shape, (len(sl.faces),))


def test_slice_general_direction_matches_axis_slice(ball4):
    # the polytope is not rotation invariant, but for a rotated plane the slice is still close
    # to the exact ball of radius sqrt(1 - c^2): check at c = 0.3 with an oblique normal
    n = np.array([1.0, -2.0, 0.5, 1.0])
    sl = ball4.slice(0.3 * n / np.linalg.norm(n), n)
    rho = math.sqrt(1 - 0.09)
    assert sl.is_watertight and sl.is_winding_consistent
    assert sl.volume == pytest.approx(4 / 3 * math.pi * rho**3, rel=0.08)


@pytest.mark.parametrize(
    ("point", "normal", "volume", "area"),
    [
        ([0, 0, 0, 0.3], [0, 0, 0, 1], 8.0, 24.0),  # cube [-1, 1]^3
        ([0.5, 0, 0, 0], [-2, 0, 0, 0], 8.0, 24.0),
        # the plane holds the facet w = 1: that facet's tetrahedra have s = 0 everywhere and
        # emit nothing; the side facets emit exactly the cube through the on-plane vertices
        ([0, 0, 0, 1], [0, 0, 0, 1], 8.0, 24.0),
        # through the centre, normal to the main diagonal: the regular octahedron with vertices
        # (+-1, +-1, -+1, -+1) (two +1, two -1), edge 2 sqrt(2); volume sqrt(2)/3 a^3 = 32/3,
        # area 2 sqrt(3) a^2 = 16 sqrt(3). The plane passes exactly through mesh vertices.
        ([0, 0, 0, 0], [1, 1, 1, 1], 32 / 3, 16 * math.sqrt(3)),
    ],
)
def test_slice_tesseract_exact(point, normal, volume, area):
    sl = tesseract_boundary(1.0).slice(point, normal)
    assert sl.is_watertight and sl.is_winding_consistent
    assert sl.volume == pytest.approx(volume, rel=1e-12)
    assert sl.area == pytest.approx(area, rel=1e-12)
    assert sl.body_count == 1


@pytest.mark.parametrize("shape", ["tesseract", "ball"])
@settings(max_examples=30, deadline=None)
@given(
    normal=hnp.arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.1),
    offset=st.floats(-0.85, 0.85),
)
def test_slice_of_convex_polytope_is_hull_of_its_vertices(shape, normal, offset):
    """A hyperplane section of a convex polytope is convex, with the cut points as vertices:
    its volume must equal qhull's volume of the slice's own vertex cloud, for any plane. The
    inradii are 1 (tesseract) and 0.862 (4-ball polytope at n = 2, from qhull's facet
    equations), so |offset| <= 0.85 always cuts a solid piece."""
    mesh = tesseract_boundary(1.0) if shape == "tesseract" else ball_polytope(4, 2)
    n = normal / np.linalg.norm(normal)
    sl = mesh.slice(offset * n, normal)
    assert sl.is_watertight and sl.is_winding_consistent
    # both sum the same flat pieces up to round-off
    assert sl.volume == pytest.approx(ConvexHull(sl.vertices).volume, rel=1e-9)
    assert sl.area == pytest.approx(ConvexHull(sl.vertices).area, rel=1e-9)


def test_slice_on_the_far_side_facet_is_empty():
    # with s >= 0 counted as positive, the plane w = -1 leaves every vertex on the positive
    # side: no sign change, no triangles (the w = 1 case above shows the other side)
    sl = tesseract_boundary(1.0).slice([0, 0, 0, -1], [0, 0, 0, 1])
    assert len(sl.faces) == 0 and len(sl.vertices) == 0


def test_slice_interpolates_attributes_and_maps_back(ball4):
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=4), 0.25
    mesh = ball4.copy()
    mesh.point_data["linear"] = mesh.vertices @ a + b
    mesh.point_data["pair"] = np.column_stack([mesh.vertices[:, 3], np.ones(mesh.n_vertices)])
    mesh.cell_data["id"] = np.arange(mesh.n_simplices)
    point, normal = np.array([0.1, 0.0, -0.2, 0.3]), np.array([0.3, -1.0, 0.2, 2.0])
    sl = mesh.slice(point, normal)
    x4 = point + sl.vertices @ hyperplane_basis(normal)
    # linear interpolation reproduces a linear function exactly (up to round-off)
    assert np.allclose(sl.vertex_attributes["linear"], x4 @ a + b, atol=1e-12)
    assert np.allclose(sl.vertex_attributes["pair"], np.column_stack([x4[:, 3], np.ones(len(x4))]), atol=1e-12)
    # points lie on the hyperplane and on the source tetrahedra's 3-spaces
    assert np.allclose((x4 - point) @ normal, 0.0, atol=1e-12)
    tet = sl.face_attributes["simplex"]
    assert np.array_equal(sl.face_attributes["id"], tet)
    n4 = mesh.simplex_normals[tet]
    p0 = mesh.vertices[mesh.simplices[tet, 0]]
    for k in range(3):
        assert np.allclose(np.einsum("ij,ij->i", x4[sl.faces[:, k]] - p0, n4), 0.0, atol=1e-12)
    only = mesh.slice(point, normal, attributes=["linear"])
    assert set(only.vertex_attributes) == {"linear"}


def test_slice_outward_matches_projected_normals(ball4):
    # triangle normals in the slice point along the source tetrahedra's normals projected
    # into the hyperplane (the outward direction of the slice)
    normal = np.array([0.0, 1.0, 0.0, 1.0])
    sl = ball4.slice([0, 0, 0, 0], normal)
    projected = ball4.simplex_normals[sl.face_attributes["simplex"]] @ hyperplane_basis(normal).T
    assert np.all(np.einsum("ij,ij->i", sl.face_normals, projected) > 0)


def test_slice_errors(ball4):
    with pytest.raises(ValueError, match="`slice` needs a 4D mesh"):
        simplex_boundary(3).slice([0, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match="`normal` must be a nonzero vector"):
        ball4.slice([0, 0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(ValueError, match="`point` must have shape"):
        ball4.slice([0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(ValueError, match="`point` contains 1 non-finite"):
        ball4.slice([0, 0, 0, np.nan], [0, 0, 0, 1])
    with pytest.raises(KeyError, match="unknown point_data"):
        ball4.slice([0, 0, 0, 0], [0, 0, 0, 1], attributes=["ao"])
    with pytest.raises(TypeError, match="sequence of names"):
        ball4.slice([0, 0, 0, 0], [0, 0, 0, 1], attributes="ao")


# --------------------------------------------------------------------------------------------
# caching
# --------------------------------------------------------------------------------------------


def test_cache_is_reused_and_read_only():
    mesh = ball_polytope(4, 2)
    normals = mesh.simplex_normals
    assert mesh.simplex_normals is normals  # computed once
    for arr in (normals, mesh.vertices, mesh.simplices, mesh.vertex_normals, mesh.bounds):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 0
    assert mesh.check() is mesh.check()


def test_cache_dropped_when_arrays_change():
    mesh = ball_polytope(3, 2)
    volume, normals = mesh.volume, mesh.simplex_normals
    mesh.check()
    mesh.cache["bvh"] = object()
    version = mesh.version
    mesh.vertices = 2.0 * mesh.vertices
    assert mesh.version == version + 1 and "bvh" not in mesh.cache
    assert mesh.volume == pytest.approx(8 * volume, rel=1e-12)
    assert mesh.simplex_normals is not normals and np.allclose(mesh.simplex_normals, normals)
    mesh.simplices = mesh.simplices[:, ::-1]  # reversal flips the orientation in 3D
    assert mesh.volume == pytest.approx(-8 * volume, rel=1e-12)
    assert mesh.check().oriented


def test_setter_validation():
    mesh = simplex_boundary(3)
    mesh.point_data["ao"] = np.zeros(4)
    with pytest.raises(ValueError, match="must keep 4 rows while point_data is set"):
        mesh.vertices = np.zeros((5, 3))
    with pytest.raises(ValueError, match="must keep dimension 3"):
        mesh.vertices = np.zeros((4, 4))
    with pytest.raises(ValueError, match="outside"):
        mesh.simplices = [[0, 1, 9]]
    with pytest.raises(ValueError, match=r"`point_data\['x'\]` must have first dimension 4"):
        mesh.point_data["x"] = np.zeros(3)
    with pytest.raises(ValueError, match=r"`cell_data\['x'\]` must have first dimension 4"):
        mesh.cell_data.update(x=np.zeros(5))


def test_copy_and_pickle_are_independent():
    mesh = ball_polytope(4, 2)
    mesh.point_data["ao"] = np.linspace(0, 1, mesh.n_vertices)
    mesh.check()
    for other in (mesh.copy(), pickle.loads(pickle.dumps(mesh))):
        assert np.array_equal(other.vertices, mesh.vertices)
        assert np.array_equal(other.point_data["ao"], mesh.point_data["ao"])
        other.vertices = other.vertices + 1.0
        assert mesh.volume == pytest.approx(other.volume, rel=1e-12)
        assert not np.array_equal(other.vertices, mesh.vertices)


def test_repr_and_basic_properties():
    mesh = simplex_boundary(4)
    mesh.point_data["ao"] = np.zeros(5)
    assert repr(mesh) == "SimplexMesh(dim=4, n_vertices=5, n_simplices=5, point_data=['ao'])"
    assert (mesh.dim, mesh.n_vertices, mesh.n_simplices, len(mesh)) == (4, 5, 5, 5)
    assert np.array_equal(mesh.bounds, [[0, 0, 0, 0], [1, 1, 1, 1]])
    assert mesh.scale == pytest.approx(2.0)


# --------------------------------------------------------------------------------------------
# input validation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("vertices", "simplices", "error", "match"),
    [
        (np.zeros((3, 5)), [[0, 1, 2, 0, 1]], ValueError, r"`vertices` must have shape \(V, d\) with d in"),
        (np.zeros(3), [[0]], ValueError, "`vertices` must be a 2D array"),
        ([[0, 0], [1, np.nan]], [[0, 1]], ValueError, "`vertices` contains 1 non-finite"),
        ([[0, 0], [1, np.inf]], [[0, 1]], ValueError, "`vertices` contains 1 non-finite"),
        ([["a", "b"]], [[0, 0]], TypeError, "`vertices` must be array-like of numbers"),
        (np.zeros((3, 3)), [[0, 1]], ValueError, r"`simplices` must have shape \(S, 3\)"),
        (np.zeros((3, 3)), [[0, 1, 3]], ValueError, r"`simplices` holds 1 vertex index\(es\) outside \[0, 3\)"),
        (np.zeros((3, 3)), [[0, 1, -1]], ValueError, "outside"),
        (np.zeros((3, 3)), [[0, 1, 1.5]], TypeError, "`simplices` must hold integer vertex indices"),
        (np.zeros((3, 3)), [[True, False, True]], TypeError, "integer vertex indices"),
    ],
)
def test_bad_input(vertices, simplices, error, match):
    with pytest.raises(error, match=match):
        SimplexMesh(vertices, simplices)


def test_bad_data_and_options():
    with pytest.raises(ValueError, match=r"`point_data\['ao'\]` must have first dimension 3"):
        SimplexMesh(np.zeros((3, 2)), [[0, 1]], point_data={"ao": np.zeros(2)})
    with pytest.raises(TypeError, match="keys must be nonempty strings"):
        SimplexMesh(np.zeros((3, 2)), [[0, 1]], cell_data={1: np.zeros(1)})
    with pytest.raises(ValueError, match="`rtol` must be a number"):
        simplex_boundary(2).check(rtol=-1)
    with pytest.raises(ValueError, match="`matrix` must be invertible"):
        simplex_boundary(2).transformed(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"`offset` must be a scalar or have shape \(2,\)"):
        simplex_boundary(2).transformed(np.eye(2), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"`matrix` must have shape"):
        simplex_boundary(2).transformed(np.eye(3))
    with pytest.raises(TypeError, match="unexpected keyword"):
        SimplexMesh(np.zeros((3, 2)), [[0, 1]], colors=1)


def test_empty_mesh():
    mesh = SimplexMesh(np.zeros((0, 4)), np.zeros((0, 4), dtype=int))
    assert mesh.volume == 0.0 and mesh.measure == 0.0
    report = mesh.check()
    assert report.n_simplices == 0 and not report.closed and not report.ok
    assert mesh.split() == []
    assert len(mesh.slice([0, 0, 0, 0], [0, 0, 0, 1]).faces) == 0
    assert SimplexMesh(np.zeros((2, 3)), []).n_simplices == 0


def test_simplex_normals_function_matches_definition():
    rng = np.random.default_rng(3)
    for d in DIMS:
        p = rng.normal(size=(10, d))
        simplices = rng.integers(0, 10, size=(20, d))
        normals = simplex_normals(p, simplices)
        x = rng.normal(size=d)
        rows = p[simplices]
        dets = np.linalg.det(np.concatenate([rows[:, 1:] - rows[:, :1], np.broadcast_to(x, (20, 1, d))], axis=1))
        assert np.allclose(normals @ x, dets, atol=1e-12)


# --------------------------------------------------------------------------------------------
# file formats
# --------------------------------------------------------------------------------------------


def _decorated(d: int) -> SimplexMesh:
    mesh = ball_polytope(d, 2)
    rng = np.random.default_rng(11)
    mesh.point_data["ao"] = rng.random(mesh.n_vertices)
    mesh.point_data["normal"] = mesh.vertex_normals.copy()
    mesh.cell_data["label"] = rng.integers(0, 5, mesh.n_simplices).astype(np.int32)
    # awkward floats must survive exactly
    vertices = mesh.vertices.copy()
    vertices[0, 0] = 1 / 3
    vertices[1, 0] = 1e-300
    vertices[2, 0] = 0.1
    mesh = SimplexMesh(vertices, mesh.simplices, point_data=mesh.point_data, cell_data=mesh.cell_data)
    return mesh


def _assert_same(a: SimplexMesh, b: SimplexMesh, *, data: bool = True):
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.simplices, b.simplices)
    if data:
        assert set(a.point_data) == set(b.point_data) and set(a.cell_data) == set(b.cell_data)
        for k in a.point_data:
            assert np.array_equal(a.point_data[k], b.point_data[k])
        for k in a.cell_data:
            assert np.array_equal(a.cell_data[k], b.cell_data[k])
            assert a.cell_data[k].dtype == b.cell_data[k].dtype


@pytest.mark.parametrize("d", DIMS)
def test_npz_round_trip(d, tmp_path):
    mesh = _decorated(d)
    path = tmp_path / "mesh.npz"
    mesh.save(path)
    _assert_same(mesh, SimplexMesh.load(path))
    _assert_same(mesh, meshio.load(path))


@pytest.mark.parametrize("d", DIMS)
def test_text_round_trip(d, tmp_path):
    mesh = _decorated(d)
    path = tmp_path / "mesh.txt"
    mesh.save_text(path)
    back = SimplexMesh.load_text(path)
    _assert_same(mesh, back, data=False)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#") and lines[1:4] == ["ao4d-mesh 1", f"dim {d}", f"vertices {mesh.n_vertices}"]


@pytest.mark.parametrize("d", DIMS)
def test_vtu_round_trip(d, tmp_path):
    pv = pytest.importorskip("pyvista")
    mesh = _decorated(d)
    path = tmp_path / "mesh.vtu"
    mesh.to_vtu(path)
    grid = pv.read(path)
    cell_type = {2: pv.CellType.LINE, 3: pv.CellType.TRIANGLE, 4: pv.CellType.TETRA}[d]
    assert set(np.unique(grid.celltypes)) == {cell_type}
    assert np.array_equal(grid.cells_dict[cell_type], mesh.simplices)
    assert np.array_equal(grid.points[:, : min(d, 3)], mesh.vertices[:, :3])
    if d == 4:
        assert np.array_equal(grid.point_data["w"], mesh.vertices[:, 3])
    assert np.array_equal(grid.point_data["ao"], mesh.point_data["ao"])
    assert np.array_equal(grid.cell_data["label"], mesh.cell_data["label"])
    _assert_same(mesh, meshio.load(path))


def test_writes_are_atomic(tmp_path):
    mesh = _decorated(4)
    path = tmp_path / "mesh.npz"
    mesh.save(path)
    before = path.read_bytes()
    bad = mesh.copy()
    bad.point_data["obj"] = np.array([object()] * bad.n_vertices)
    with pytest.raises(TypeError, match="dtype object"):
        bad.save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.npz"]  # no temporary left


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("ao4d-mesh 1\ndim 2\nvertices 2\n0 0\n1 1\nsimplices 1\n0\n", "simplex line 0 must have 2 numbers"),
        ("ao4d-mesh 1\ndim 2\nvertices 2\n0 0\n1 x\nsimplices 1\n0 1\n", "vertex line 1 is not 2 numbers"),
        ("ao4d-mesh 1\ndim 2\nvertices 3\n0 0\n1 1\nsimplices 1\n0 1\n", "expected 'simplices <count>'"),
        ("ao4d-mesh 9\n", "text format 9"),
        ("hello\n", "expected 'ao4d-mesh <count>'"),
        ("ao4d-mesh 1\ndim 2\nvertices 2\n0 0\n1 1\nsimplices 1\n0 5\n", "outside"),
    ],
)
def test_bad_text_files(tmp_path, text, match):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises((ValueError, TypeError), match=match):
        meshio.load_text(path)


def test_io_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        SimplexMesh.load(tmp_path / "missing.npz")
    (tmp_path / "other.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable .npz"):
        SimplexMesh.load(tmp_path / "other.npz")
    np.savez(tmp_path / "plain.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not an ao4d mesh file"):
        SimplexMesh.load(tmp_path / "plain.npz")
    with pytest.raises(ValueError, match="must end in .vtu"):
        simplex_boundary(4).to_vtu(tmp_path / "mesh.vtk")
    mesh = simplex_boundary(4)
    mesh.point_data["w"] = np.zeros(5)
    with pytest.raises(ValueError, match="must not use the name 'w'"):
        mesh.to_vtu(tmp_path / "mesh.vtu")
    with pytest.raises(TypeError, match="`mesh` must be a SimplexMesh"):
        meshio.save_npz("mesh", tmp_path / "x.npz")


# --------------------------------------------------------------------------------------------
# scale
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_check_two_million_tetrahedra():
    # 80 translated copies of a 24576-tetrahedron polytope: the vectorised check must stay
    # correct (and feasible) at millions of simplices
    base = ball_polytope(4, 8)
    mesh = concatenate([translated(base, [3.0 * i, 0, 0, 0]) for i in range(80)])
    report = mesh.check()
    assert report.ok and report.n_components == 80 and report.n_simplices == 80 * base.n_simplices
    assert mesh.volume == pytest.approx(80 * base.volume, rel=1e-12)
