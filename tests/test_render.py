"""render(): hit masks and depths against analytic ray-sphere and ray-tetrahedron answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import ao4d
from ao4d.camera import Camera4D
from ao4d.mesh import SimplexMesh
from ao4d.render import RenderResult, prepare_scene, render

R = 1.0
GRID = 20  # 20^4 samples over [-1.2, 1.2]^4: spacing h = 0.126


@pytest.fixture(scope="module")
def sphere():
    return ao4d.extract_field(ao4d.fields.hypersphere(R), (GRID,) * 4, (-1.2, 1.2))


def _analytic_sphere(cam, shape):
    """Closest positive root of |o + t w|^2 = R^2 per voxel ray (inf on a miss)."""
    o, w = (a.reshape(-1, 4) for a in cam.rays(shape))
    b = np.einsum("nd,nd->n", o, w)
    disc = b**2 - (np.einsum("nd,nd->n", o, o) - R**2)
    t = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    return t.reshape(shape), (o + np.where(np.isfinite(t), t, 0)[:, None] * w).reshape(shape + (4,))


# The mesh interpolates the sphere linearly on a grid of spacing h: its tetrahedra lie inside
# the sphere by at most rho^2 / (2 R) with rho <= h (circumradius of a marching tetrahedron),
# i.e. 0.008 here. Depth may be that much larger along the normal; dividing by the cosine of the
# ray's incidence angle (>= 0.6 for |u| <= 0.8 R) gives the depth tolerance below.
DEPTH_TOL = 0.126**2 / 2 / 0.6
# Rays whose distance to the centre is within a band of the silhouette may hit either way.
SILHOUETTE_BAND = 0.126**2 / 2 + 1e-6


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_sphere_hit_mask_and_depth(sphere, projection):
    cam = Camera4D([0.1, -0.2, 0.05, -4], [0.1, -0.2, 0.05, 0], projection=projection,
                   half_width=1.4 if projection == "orthographic" else None, fov=45)
    shape = (24, 22, 20)
    img = render(sphere, cam, shape, ao="none")
    t_true, _ = _analytic_sphere(cam, shape)
    o, w = (a.reshape(shape + (4,)) for a in cam.rays(shape))
    # distance of each ray's line from the sphere's centre
    closest = o - np.einsum("...d,...d->...", o, w)[..., None] * w
    miss_dist = np.linalg.norm(closest, axis=-1)
    clear = np.abs(miss_dist - R) > SILHOUETTE_BAND
    np.testing.assert_array_equal(img.hit[clear], np.isfinite(t_true)[clear])
    assert img.hit.sum() > 1000
    inner = miss_dist < 0.8 * R
    err = img.depth[inner] - t_true[inner]
    assert err.min() > -1e-4  # the inscribed mesh is never hit before the true sphere
    assert err.max() < DEPTH_TOL
    np.testing.assert_array_equal(img.depth[~img.hit], np.inf)
    np.testing.assert_array_equal(img.object_id[~img.hit], -1)
    np.testing.assert_array_equal(img.object_id[img.hit], 0)


def test_shade_without_ao_or_light_is_ambient(sphere):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    img = render(sphere, cam, (12, 12, 12), ao="none", ambient=0.7)
    assert img.shade.dtype == np.float32 and img.shade.shape == (12, 12, 12)
    np.testing.assert_allclose(img.shade[img.hit], 0.7, rtol=1e-6)
    np.testing.assert_array_equal(img.shade[~img.hit], 0.0)
    np.testing.assert_array_equal(img.occlusion[img.hit], 0.0)
    assert np.isnan(img.occlusion[~img.hit]).all()


@pytest.mark.parametrize("normals", ["smooth", "flat"])
def test_lambert_term_matches_sphere_normal(sphere, normals):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    light = np.array([0.3, 0.5, -0.2, -1.0])
    shape = (20, 20, 20)
    img = render(sphere, cam, shape, ao="none", ambient=0.25, light=light, diffuse=0.75,
                 normals=normals)
    t_true, points = _analytic_sphere(cam, shape)
    lam = np.clip(points @ (light / np.linalg.norm(light)) / R, 0, None)
    expected = 0.25 + 0.75 * lam
    assert img.shade.min() >= 0 and img.shade.max() <= 1.0 + 1e-6
    inner = np.linalg.norm(points[..., :3], axis=-1) < 0.8 * R
    inner &= img.hit
    # facet normals deviate from the sphere's by about rho / R <= h (0.13 rad); interpolated
    # area-weighted vertex normals average those deviations (measured max 0.064 rad, bound
    # taken as 0.08). The shade error is at most 0.75 * angle.
    tol = 0.75 * (0.13 if normals == "flat" else 0.08)
    assert np.abs(img.shade[inner] - expected[inner]).max() < tol


def _tet_mesh(vertices):
    return SimplexMesh(np.asarray(vertices, float), [[0, 1, 2, 3]])


def test_flat_tetrahedron_appears_unmirrored():
    # a tetrahedron in the hyperplane w = 0 seen along +w is the 3D tetrahedron itself:
    # voxel u is hit iff u lies inside it, at depth exactly |eye_w|.
    corners3 = np.array([[-0.8, -0.6, -0.5], [0.9, -0.5, -0.4], [-0.5, 0.8, -0.3], [-0.4, -0.4, 0.9]])
    mesh = _tet_mesh(np.hstack([corners3, np.zeros((4, 1))]))
    cam = Camera4D([0, 0, 0, -3], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    shape = (20, 20, 20)
    img = render(mesh, cam, shape, ao="none")
    u = cam.project(cam.voxel_centers(shape))
    # barycentric coordinates of every voxel centre in the 3D tetrahedron
    m = np.vstack([corners3.T, np.ones(4)])
    lam = np.linalg.solve(m, np.concatenate([u.reshape(-1, 3), np.ones((u[..., 0].size, 1))], 1).T).T
    inside = (lam > 1e-9).all(1).reshape(shape)
    outside = (lam < -1e-9).any(1).reshape(shape)
    np.testing.assert_array_equal(img.hit[inside], True)
    np.testing.assert_array_equal(img.hit[outside], False)
    np.testing.assert_allclose(img.depth[img.hit], 3.0, rtol=1e-5)


def test_two_objects_get_their_ids():
    left = ao4d.extract_field(ao4d.fields.hypersphere(0.8, [-1, 0, 0, 0]), (14,) * 4,
                              ([-2, -1, -1, -1], [0, 1, 1, 1]))
    right = ao4d.extract_field(ao4d.fields.hypersphere(0.8, [1, 0, 0, 0]), (14,) * 4,
                               ([0, -1, -1, -1], [2, 1, 1, 1]))
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.0)
    img = render([left, right], cam, (16, 8, 8), ao="none")
    x = cam.project(cam.voxel_centers((16, 8, 8)))[..., 0]
    assert set(np.unique(img.object_id[img.hit & (x < 0)])) == {0}
    assert set(np.unique(img.object_id[img.hit & (x > 0)])) == {1}
    scene, ids = prepare_scene([left, right])
    assert ids.shape == (left.n_simplices + right.n_simplices,)
    assert ids.max() == 1


@pytest.fixture(scope="module")
def touching_pair():
    # two hyperspheres close together occlude each other near the gap; each alone is convex
    # and unoccluded, so A is 0 on the far sides and positive near the gap
    bounds = ([-2.2, -1.1, -1.1, -1.1], [2.2, 1.1, 1.1, 1.1])
    field = ao4d.fields.union(ao4d.fields.hypersphere(1.0, [-1.05, 0, 0, 0]),
                              ao4d.fields.hypersphere(1.0, [1.05, 0, 0, 0]))
    return ao4d.extract_field(field, (24, 12, 12, 12), bounds)


def test_ao_darkens_the_gap(touching_pair):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.2)
    img = render(touching_pair, cam, (24, 12, 12), ao="vertices", samples=48, seed=1)
    occ = img.occlusion[img.hit]
    assert np.isfinite(occ).all() and occ.min() >= 0 and occ.max() <= 1
    x = cam.project(cam.voxel_centers((24, 12, 12)))[..., 0]
    gap = img.hit & (np.abs(x) < 0.3)
    far = img.hit & (np.abs(x) > 1.6)
    assert img.occlusion[gap].mean() > 0.15
    assert img.occlusion[far].mean() < 0.02
    np.testing.assert_allclose(img.shade[img.hit], 1 - img.occlusion[img.hit], atol=1e-6)
    assert img.info["ao_rays"] == touching_pair.n_vertices * 48


def test_ao_at_hits_agrees_with_vertex_ao(touching_pair):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.2)
    shape = (16, 8, 8)
    by_vertex = render(touching_pair, cam, shape, ao="vertices", samples=64, seed=2)
    by_hit = render(touching_pair, cam, shape, ao="hits", samples=64, seed=3)
    np.testing.assert_array_equal(by_vertex.hit, by_hit.hit)
    assert by_hit.info["ao_rays"] == by_hit.hit.sum() * 64
    # each estimate has standard error <= 0.5 / sqrt(64) = 0.0625 per voxel; the mean over
    # many voxels differs only by interpolation bias plus noise / sqrt(n)
    diff = by_vertex.occlusion[by_vertex.hit] - by_hit.occlusion[by_hit.hit]
    assert abs(diff.mean()) < 0.03
    assert np.sqrt((diff**2).mean()) < 0.12


def test_stored_vertex_ao_is_used(sphere):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    mesh = sphere.copy()
    mesh.point_data["ao"] = np.full(mesh.n_vertices, 0.25)
    img = render(mesh, cam, (10, 10, 10), ao="vertices")
    np.testing.assert_allclose(img.occlusion[img.hit], 0.25, atol=1e-6)
    np.testing.assert_allclose(img.shade[img.hit], 0.75, atol=1e-6)
    assert img.info["ao_rays"] == 0


def test_save_round_trip(sphere, tmp_path):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    img = render(sphere, cam, (10, 9, 8), ao="none")
    assert isinstance(img, RenderResult)
    vti = img.save(tmp_path / "r.vti")
    back = ao4d.io.read_vti(vti, array="depth")
    np.testing.assert_array_equal(np.isnan(back.data), ~img.hit)
    np.testing.assert_allclose(back.data[img.hit], img.depth[img.hit])
    assert back.spacing == pytest.approx((img.geometry.spacing,) * 3)
    np.testing.assert_array_equal(ao4d.io.read_vti(vti, array="object_id").data, img.object_id)
    mhd = ao4d.io.read_mhd(img.save(tmp_path / "r.mhd"))
    np.testing.assert_array_equal(mhd.data, img.shade)
    assert mhd.origin == pytest.approx(img.geometry.origin)


@pytest.mark.parametrize("backend", ["opencl", "numpy"])
def test_backends_agree(backend, request):
    if backend == "opencl":
        request.getfixturevalue("cl_runtime")
    tet = _tet_mesh([[-0.8, -0.6, -0.5, 0.1], [0.9, -0.5, -0.4, -0.1], [-0.5, 0.8, -0.3, 0.2],
                     [-0.4, -0.4, 0.9, 0.0]])
    cam = Camera4D([0.2, 0, 0, -3], [0, 0, 0, 0], fov=50)
    img = render(tet, cam, (10, 10, 10), ao="none", backend=backend)
    ref = render(tet, cam, (10, 10, 10), ao="none", backend="numpy")
    np.testing.assert_array_equal(img.hit, ref.hit)
    np.testing.assert_allclose(img.depth[img.hit], ref.depth[ref.hit], rtol=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(camera="cam"), TypeError, "`camera` must be an ao4d.Camera4D"),
        (dict(ao="bent"), ValueError, "`ao` must be one of"),
        (dict(normals="phong"), ValueError, "`normals` must be one of"),
        (dict(backend="cuda"), ValueError, "`backend` must be one of"),
        (dict(light=[0, 0, 0, 0]), ValueError, "`light` must be a non-zero"),
        (dict(light=[0, 0, 1]), ValueError, "`light` must have shape"),
        (dict(ambient=-1), ValueError, "`ambient` must be"),
        (dict(light=[0, 0, 0, 1], diffuse=math.nan), ValueError, "`diffuse` must be"),
        (dict(samples=0), ValueError, "`samples` must be >= 1"),
        (dict(max_distance=0), ValueError, "`max_distance` must be > 0"),
        (dict(shape=(4, 4)), ValueError, "3 entries"),
        (dict(meshes=[]), ValueError, "at least one"),
        (dict(meshes=["x"]), TypeError, r"`meshes\[0\]` must be a SimplexMesh"),
        (dict(meshes=SimplexMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])), ValueError,
         "must be 4D meshes"),
    ],
)
def test_bad_render_input(kwargs, error, match):
    args = dict(meshes=_tet_mesh(np.eye(4)), camera=Camera4D([0, 0, 0, -3], [0, 0, 0, 0]),
                shape=(4, 4, 4))
    args.update(kwargs)
    with pytest.raises(error, match=match):
        render(args.pop("meshes"), args.pop("camera"), args.pop("shape"), **args)


def test_closed_mesh_smooth_normals_are_never_flipped():
    # A closed outward surface is always seen from its front, so the Lambert term must be
    # max(0, n_s . l) with n_s the interpolated vertex normal as is. Near silhouettes and sharp
    # edges n_s may lean away from the ray although the face is seen from its front; flipping
    # it there lit the far side and sprinkled dark voxels over the demo's images.
    from ao4d.ao import cast_rays

    cube = ao4d.extract_field(ao4d.fields.tesseract(0.6), (10,) * 4, (-0.8, 0.8))
    cam = Camera4D([1.3, 1.6, -1.1, -3.2], [0, 0, 0, 0], fov=50)
    light = np.array([-0.6, 1.0, 0.3, -0.5])
    light /= np.linalg.norm(light)
    shape = (24, 24, 24)
    img = render(cube, cam, shape, ao="none", ambient=0.0, light=light, diffuse=1.0)
    o, w = (a.reshape(-1, 4) for a in cam.rays(shape))
    hits = cast_rays(cube, o, w)
    hit = hits.simplex >= 0
    corners = cube.simplices[hits.simplex[hit]]
    n_s = np.einsum("hk,hkd->hd", hits.barycentric[hit], np.asarray(cube.vertex_normals)[corners])
    n_s /= np.linalg.norm(n_s, axis=1, keepdims=True)
    expected = np.zeros(len(o))
    expected[hit] = np.clip(n_s @ light, 0, None)
    leaning = np.einsum("hd,hd->h", n_s, w[hit]) > 0
    assert leaning.sum() > 0  # the view really has such hits
    np.testing.assert_allclose(img.shade.ravel(), expected, atol=1e-5)


def test_silhouette_normals_are_not_flipped(sphere):
    # A closed surface is always seen from its front. Near the silhouette an interpolated
    # vertex normal may lean away from the ray; it must not be flipped (that lit the far side
    # and sprinkled dark voxels over the image). Light from the side, perpendicular to the
    # view, makes any flip show as a large error at the silhouette.
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.1)
    shape = (24, 24, 24)
    light = cam.basis[0]
    img = render(sphere, cam, shape, ao="none", ambient=0.0, light=light, diffuse=1.0)
    o, w = (a.reshape(shape + (4,)) for a in cam.rays(shape))
    p = o + np.where(img.hit, img.depth, 0)[..., None] * w  # where the mesh was hit
    n_true = p / np.linalg.norm(p, axis=-1, keepdims=True)
    expected = np.clip(n_true @ light, 0, None)
    # vertex normals deviate by <= 0.08 rad from the sphere's (see the Lambert test above);
    # the hit point is off the sphere by <= the chord sag, which tilts n_true by < 0.02 rad
    assert np.abs(img.shade[img.hit] - expected[img.hit]).max() < 0.1


@settings(max_examples=15, deadline=None)
@given(corners=st.lists(st.lists(st.floats(-0.9, 0.9, allow_subnormal=False), min_size=3,
                                 max_size=3), min_size=4, max_size=4).map(np.array),
       w=st.floats(-0.5, 0.5, allow_subnormal=False))
def test_random_flat_tetrahedron_is_seen_where_it_is(corners, w):
    # any tetrahedron in a hyperplane w = const, seen along +w orthographically, covers exactly
    # the voxels whose centres lie inside it (up to voxels on its boundary), at depth eye - w
    m = np.vstack([corners.T, np.ones(4)])
    assume(abs(np.linalg.det(m)) > 0.05)  # not too flat in 3D
    mesh = _tet_mesh(np.hstack([corners, np.full((4, 1), w)]))
    cam = Camera4D([0, 0, 0, -3], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    shape = (12, 12, 12)
    img = render(mesh, cam, shape, ao="none", backend="numpy")
    u = cam.project(cam.voxel_centers(shape)).reshape(-1, 3)
    lam = np.linalg.solve(m, np.vstack([u.T, np.ones(len(u))])).T
    margin = 1e-6
    inside = (lam > margin).all(1).reshape(shape)
    outside = (lam < -margin).any(1).reshape(shape)
    np.testing.assert_array_equal(img.hit[inside], True)
    np.testing.assert_array_equal(img.hit[outside], False)
    np.testing.assert_allclose(img.depth[img.hit], 3.0 + w, rtol=1e-6)
