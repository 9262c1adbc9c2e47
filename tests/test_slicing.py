"""Tests for ao4d.slicing: hyperplane bases and cuts of 4D meshes (SimplexMesh.slice).

Slices of convex polytopes are checked against the hull of their vertices (qhull), of the
ball polytope against the sphere, and of the tesseract against exact volumes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _shapes import ball_polytope, simplex_boundary, tesseract_boundary
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial import ConvexHull

from ao4d.slicing import hyperplane_basis

DIMS = (2, 3, 4)


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
