"""Tests for ao4d.geometry: the generalised cross product and simplex normals of DESIGN.md.

Every result is compared with ``numpy.linalg.det`` of ``[v_1; ...; v_{d-1}; x]`` (the definition),
with numpy's 3D cross product, and between the functions that use the convention.
"""

from __future__ import annotations

import numpy as np
import pytest

import ao4d
from ao4d.geometry import cross, cross_components, simplex_normals

DIMS = (2, 3, 4)
# tolerance for float64 algebra on O(1) vectors (a few ulps times a few operations)
EPS = 1e-10


def corner_normals(corners: np.ndarray) -> np.ndarray:
    return cross(*np.moveaxis(corners[:, 1:] - corners[:, :1], 1, 0))


def test_cross_matches_determinant_convention():
    # DESIGN.md: n . x = det[v1; v2; v3; x] for every x
    rng = np.random.default_rng(0)
    v = rng.normal(size=(3, 4))
    n = cross(*v)
    for x in rng.normal(size=(5, 4)):
        assert n @ x == pytest.approx(np.linalg.det(np.vstack([v, x])), abs=EPS)


def test_cross_is_3d_cross_product():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 3))
    np.testing.assert_allclose(cross(a, b), np.cross(a, b), atol=EPS)


def test_cross_wrong_count():
    with pytest.raises(ValueError, match="vectors"):
        cross([1, 0, 0, 0], [0, 1, 0, 0])


def test_simplex_normals_follow_the_design_convention():
    rng = np.random.default_rng(8)
    tri = rng.normal(size=(20, 3, 3))
    expected = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(corner_normals(tri), expected, atol=1e-12)
    tets = rng.normal(size=(20, 4, 4))
    n = corner_normals(tets)
    edges = tets[:, 1:] - tets[:, :1]
    np.testing.assert_allclose(np.einsum("sid,sd->si", edges, n), 0, atol=1e-10)
    # n . x = det[e1; e2; e3; x]: with x = n this is |n|^2 > 0
    dets = np.linalg.det(np.concatenate([edges, n[:, None]], axis=1))
    np.testing.assert_allclose(dets, (n**2).sum(1), rtol=1e-10)
    # the mesh module computes the same normals
    mesh = ao4d.SimplexMesh(tets.reshape(-1, 4), np.arange(80).reshape(20, 4))
    raw = mesh.simplex_normals * (mesh.simplex_measures * 6)[:, None]  # |n| = 3! * measure
    np.testing.assert_allclose(raw, n, atol=1e-9)


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


def test_integer_input_is_exact():
    # the lookup-table builder relies on exact integer normals
    a = np.array([[2, 0, 0, 0]]), np.array([[0, 2, 0, 0]]), np.array([[0, 0, 2, 0]])
    n = cross(*a)
    assert n.dtype.kind == "i" and n.tolist() == [[0, 0, 0, 8]]


@pytest.mark.parametrize("d", DIMS)
def test_component_major_form_matches(d):
    rng = np.random.default_rng(d)
    v = rng.normal(size=(d - 1, 7, d))
    np.testing.assert_allclose(cross_components([x.T for x in v]).T, cross(*v), atol=EPS)


def test_bad_vectors():
    with pytest.raises(ValueError, match="d - 1 vectors"):
        cross()
    with pytest.raises(ValueError, match="d - 1 vectors"):
        cross([1.0, 2.0, 3.0, 4.0, 5.0])
    with pytest.raises(TypeError, match="real numbers"):
        cross(["a", "b"])


def test_signed_volumes_orientation_scale_and_repeated_corners():
    from ao4d.geometry import signed_volumes

    # the unit 4-simplex: 1/4!; swapping two corners flips the sign; far from the origin too
    corners = np.vstack([np.zeros(4), np.eye(4)])
    simplices = np.array([[0, 1, 2, 3, 4], [1, 0, 2, 3, 4]])
    for offset in (0.0, 1e6):
        np.testing.assert_allclose(signed_volumes(corners + offset, simplices), [1 / 24, -1 / 24], rtol=1e-9)
    # two equal corners: exactly zero (the LU determinant alone leaves round-off of either sign)
    flat = np.array([[4 / 3, 4 / 3, 0, 1 / 3], [2, 2, 0, 1], [2, 1, 0, 0], [2, 1, 0, 0], [2, 2, 1 / 3, 1 / 3]])
    assert signed_volumes(flat, np.array([[0, 1, 2, 3, 4]]))[0] == 0.0
