"""render(): hit masks and depths against analytic ray-sphere and ray-tetrahedron answers."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import ao4d
from ao4d.mesh import SimplexMesh
from ao4d.rendering.camera import Camera4D
from ao4d.rendering.lighting import Light
from ao4d.rendering.pipeline import RenderResult, prepare_scene, render

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
    cam = Camera4D(
        [0.1, -0.2, 0.05, -4],
        [0.1, -0.2, 0.05, 0],
        projection=projection,
        half_width=1.4 if projection == "orthographic" else None,
        fov=45,
    )
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
    img = render(sphere, cam, shape, ao="none", ambient=0.25, light=light, diffuse=0.75, shading=normals)
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


def _left_and_right(n: int):
    """Two hyperspheres of radius 0.8 at x = -1 and x = 1, each on an n^4 grid."""
    left = ao4d.extract_field(ao4d.fields.hypersphere(0.8, [-1, 0, 0, 0]), (n,) * 4, ([-2, -1, -1, -1], [0, 1, 1, 1]))
    right = ao4d.extract_field(ao4d.fields.hypersphere(0.8, [1, 0, 0, 0]), (n,) * 4, ([0, -1, -1, -1], [2, 1, 1, 1]))
    return left, right


def test_two_objects_get_their_ids():
    left, right = _left_and_right(14)
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.0)
    img = render([left, right], cam, (16, 8, 8), ao="none")
    x = cam.project(cam.voxel_centers((16, 8, 8)))[..., 0]
    assert set(np.unique(img.object_id[img.hit & (x < 0)])) == {0}
    assert set(np.unique(img.object_id[img.hit & (x > 0)])) == {1}
    scene, ids = prepare_scene([left, right])
    assert ids.shape == (left.n_simplices + right.n_simplices,)
    assert ids.max() == 1


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


def test_interpolated_vertex_ao_stays_in_the_unit_interval(sphere):
    # barycentric weights a rounding below 0 (or a sum above 1) gave occlusion -1e-16 or 1 + 1e-16
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    mesh = sphere.copy()
    rng = np.random.default_rng(3400)
    mesh.point_data["ao"] = rng.integers(0, 2, mesh.n_vertices).astype(float)
    img = render(mesh, cam, (24, 24, 24), ao="vertices")
    occ = img.occlusion[img.hit]
    assert occ.size and np.isfinite(occ).all()
    assert occ.min() >= 0.0 and occ.max() <= 1.0


def test_save_round_trip(sphere, tmp_path):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    img = render(sphere, cam, (10, 9, 8), ao="none")
    assert isinstance(img, RenderResult)
    vti = img.save(tmp_path / "r.vti")
    back = ao4d.io.volumes.read_vti(vti, array="depth")
    np.testing.assert_array_equal(np.isnan(back.data), ~img.hit)
    np.testing.assert_allclose(back.data[img.hit], img.depth[img.hit])
    assert back.spacing == pytest.approx((img.geometry.spacing,) * 3)
    np.testing.assert_array_equal(ao4d.io.volumes.read_vti(vti, array="object_id").data, img.object_id)
    mhd = ao4d.io.volumes.read_mhd(img.save(tmp_path / "r.mhd"))
    np.testing.assert_array_equal(mhd.data, img.shade)
    assert mhd.origin == pytest.approx(img.geometry.origin)


@pytest.mark.parametrize("backend", ["opencl", "numpy"])
def test_backends_agree(backend, request):
    if backend == "opencl":
        request.getfixturevalue("cl_runtime")
    tet = _tet_mesh([[-0.8, -0.6, -0.5, 0.1], [0.9, -0.5, -0.4, -0.1], [-0.5, 0.8, -0.3, 0.2], [-0.4, -0.4, 0.9, 0.0]])
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
        (dict(shading="phong"), ValueError, "`shading` must be one of"),
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
        (dict(meshes=SimplexMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])), ValueError, "must be 4D meshes"),
    ],
)
def test_bad_render_input(kwargs, error, match):
    args = dict(meshes=_tet_mesh(np.eye(4)), camera=Camera4D([0, 0, 0, -3], [0, 0, 0, 0]), shape=(4, 4, 4))
    args.update(kwargs)
    with pytest.raises(error, match=match):
        render(args.pop("meshes"), args.pop("camera"), args.pop("shape"), **args)


def test_closed_mesh_smooth_normals_are_never_flipped():
    # A closed outward surface is always seen from its front, so the Lambert term must be
    # max(0, n_s . l) with n_s the interpolated vertex normal as is. Near silhouettes and sharp
    # edges n_s may lean away from the ray although the face is seen from its front; flipping
    # it there lit the far side and sprinkled dark voxels over the demo's images.
    from ao4d.rays.api import cast_rays

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
@given(
    corners=st.lists(
        st.lists(st.floats(-0.9, 0.9, allow_subnormal=False), min_size=3, max_size=3), min_size=4, max_size=4
    ).map(np.array),
    w=st.floats(-0.5, 0.5, allow_subnormal=False),
)
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
    # rays within the barycentric tolerance of an edge count as hits by design (bvh.BARY_EPS)
    margin = 2 * ao4d.bvh.BARY_EPS
    inside = (lam > margin).all(1).reshape(shape)
    outside = (lam < -margin).any(1).reshape(shape)
    np.testing.assert_array_equal(img.hit[inside], True)
    np.testing.assert_array_equal(img.hit[outside], False)
    np.testing.assert_allclose(img.depth[img.hit], 3.0 + w, rtol=1e-6)


# -- illumination beyond AO: specular, shadows, depth cue, colour, transparency ------------------

SPEC_GRID = 24  # hypersphere grid for the specular tests: 24^4 over [-1.2, 1.2]^4, h = 0.104


@pytest.fixture(scope="module")
def fine_sphere():
    return ao4d.extract_field(ao4d.fields.hypersphere(R), (SPEC_GRID,) * 4, (-1.2, 1.2))


SPEC_LIGHT = np.array([0.4, 0.6, -0.3, -1.0])


def _specular_image(sphere, shininess, shape=(32, 32, 32)):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.1)
    img = render(
        sphere, cam, shape, ao="none", ambient=0.0, diffuse=0.0, light=SPEC_LIGHT, specular=1.0, shininess=shininess
    )
    return cam, img


def test_specular_term_matches_the_sphere_closed_form(fine_sphere):
    # orthographic camera looking along +w: v = -w everywhere; on the unit sphere n = p, so the
    # term is max(0, p . h)^s with h = (l + v) / |l + v| wherever p . l > 0 (closed form per
    # voxel, at the analytic hit point of the voxel's ray)
    shininess = 8.0
    shape = (32, 32, 32)
    cam, img = _specular_image(fine_sphere, shininess, shape)
    t_true, p = _analytic_sphere(cam, shape)
    l = SPEC_LIGHT / np.linalg.norm(SPEC_LIGHT)
    h = l - cam.view
    h /= np.linalg.norm(h)
    expected = np.where(p @ l > 0, np.clip(p @ h, 0, None) ** shininess, 0.0)
    lit = img.hit & np.isfinite(t_true) & (p @ l > 0)
    assert lit.sum() > 10000
    err = np.abs(img.shade[lit] - expected[lit])
    # smooth normals deviate from the sphere's by ~0.02 rad on average at this grid (max 0.064
    # at h = 0.126, see above); |d(cos^8)/dtheta| <= 1.8, so the mean error stays well under
    # 0.01 (measured 0.0061) while a wrong half-vector (e.g. v = +w) gives errors near 0.2
    assert err.mean() < 0.01
    assert np.percentile(err, 99) < 0.06
    assert img.shade.max() <= 1.0 + 1e-6


def test_highlight_sits_where_the_normal_is_the_half_vector(fine_sphere):
    # the maximum of (n . h)^s on the unit sphere is at p* = h; the brightest voxel must be
    # the one whose ray passes through p*, within one voxel
    cam, img = _specular_image(fine_sphere, 40.0)
    l = SPEC_LIGHT / np.linalg.norm(SPEC_LIGHT)
    h = l - cam.view
    h /= np.linalg.norm(h)
    geo = cam.geometry(img.shade.shape)
    where = (cam.project(R * h) - np.array(geo.origin)) / geo.spacing  # voxel index coordinates
    brightest = np.unravel_index(np.argmax(np.where(img.hit, img.shade, -1)), img.shade.shape)
    assert np.abs(np.array(brightest) - where).max() <= 1.0
    assert img.shade[brightest] > 0.9


def _ground(half=2.0, n=2):
    from _scenes import flat_patch

    vertices, simplices = flat_patch(4, -half, half, 0.0, n=n, axis=1)  # the hyperplane y = 0
    return SimplexMesh(vertices, simplices)


BALL_R, BALL_C = 0.6, np.array([0.2, 0.9, -0.1, 0.15])


@pytest.fixture(scope="module")
def ball_over_ground():
    pad = 0.15
    ball = ao4d.extract_field(
        ao4d.fields.hypersphere(BALL_R, BALL_C), (20,) * 4, (BALL_C - BALL_R - pad, BALL_C + BALL_R + pad)
    )
    return [_ground(), ball]


def _ground_camera(view):
    d = np.asarray(view, float) / np.linalg.norm(view)
    target = BALL_C * np.array([1, 0, 1, 1])  # below the ball, on the ground
    return Camera4D(target - 4 * d, target, [0, 0, 0, 1], [0, 0, 1, 0], projection="orthographic", half_width=1.3)


def _ground_points(cam, shape):
    o, w = (a.reshape(shape + (4,)) for a in cam.rays(shape))
    return o + (-o[..., 1] / w[..., 1])[..., None] * w  # where each ray meets y = 0


@pytest.mark.parametrize(
    ("light", "view"),
    [
        # light straight above: the shadow is the 3-ball |q - c| < r in the hyperplane
        (Light(direction=[0, 1, 0, 0]), [0.8, -1, 0, 0]),
        (Light(direction=[0.5, 1, 0.3, -0.4]), [0, -1, 0, 0]),  # oblique: an ellipsoid
        (Light(position=[0.8, 2.6, 0.3, -0.4]), [0, -1, 0, 0]),  # a point light
    ],
    ids=["vertical", "oblique", "point"],
)
def test_shadow_of_a_ball_on_the_ground(ball_over_ground, light, view):
    # a ground point q is in shadow iff the segment (point light) or ray (directional) from q
    # towards the light meets the 4-ball: distance from the centre to that line < r, with the
    # closest approach in front of q (and before the light)
    shape = (40, 40, 40)
    cam = _ground_camera(view)
    img = render(
        ball_over_ground, cam, shape, ao="none", ambient=0.3, diffuse=0.7, light=light, shadows=True, shading="flat"
    )
    q = _ground_points(cam, shape)
    to_light, reach = light.towards(q.reshape(-1, 4))
    to_light = np.broadcast_to(to_light, (q[..., 0].size, 4)).reshape(shape + (4,))
    reach = reach.reshape(shape)
    rel = BALL_C - q
    s = np.einsum("...d,...d->...", rel, to_light)
    dist = np.linalg.norm(rel - s[..., None] * to_light, axis=-1)
    shadow = (dist < BALL_R) & (s > 0) & (s < reach)
    on_ground = img.object_id == 0
    # away from the rim: the ball mesh lies inside the sphere by <= h^2 / (2 r) = 0.005 (h =
    # 0.079) and shadow rays start 1e-4 diagonals off the ground; 0.03 leaves room for both
    clear = on_ground & (np.abs(dist - BALL_R) > 0.03)
    assert (clear & shadow).sum() > 300 and (clear & ~shadow).sum() > 10000
    np.testing.assert_allclose(img.shade[clear & shadow], 0.3, atol=1e-6)
    lit = 0.3 + 0.7 * np.clip(to_light[..., 1], 0, None)  # ground normal +y
    np.testing.assert_allclose(img.shade[clear & ~shadow], lit[clear & ~shadow], atol=1e-6)
    if light.kind == "directional" and light.direction[1] == 1:
        # straight from above the shadow is the 3-ball |(q - c)_xzw| < r in the hyperplane
        ball3 = np.linalg.norm((q - BALL_C)[..., [0, 2, 3]], axis=-1) < BALL_R
        np.testing.assert_array_equal(shadow, ball3)
    # one shadow ray from every lit hit: all ground hits, the lit part of the ball's (point
    # lights may ask a ray twice)
    if light.kind == "directional":
        assert on_ground.sum() < img.info["shadow_rays"] < img.info["hits"]


def test_transparent_ball_lets_light_through(ball_over_ground):
    # a shadow ray through a ball of opacity a crosses two surfaces: (1 - a)^2 of the light
    alpha = 0.5
    light = Light(direction=[0.5, 1, 0.3, -0.4])
    shape = (40, 40, 40)
    cam = _ground_camera([0, -1, 0, 0])
    img = render(
        ball_over_ground,
        cam,
        shape,
        ao="none",
        ambient=0.3,
        diffuse=0.7,
        light=light,
        shadows=True,
        shading="flat",
        opacity=[1.0, alpha],
    )
    q = _ground_points(cam, shape)
    rel = BALL_C - q
    s = rel @ light.direction
    dist = np.linalg.norm(rel - s[..., None] * light.direction, axis=-1)
    shadow = (dist < BALL_R) & (s > 0)
    clear = (img.object_id == 0) & (np.abs(dist - BALL_R) > 0.03)
    lam = light.direction[1]
    np.testing.assert_allclose(img.shade[clear & shadow], 0.3 + 0.7 * lam * (1 - alpha) ** 2, atol=1e-6)
    np.testing.assert_allclose(img.shade[clear & ~shadow], 0.3 + 0.7 * lam, atol=1e-6)


@pytest.mark.filterwarnings("ignore::ao4d.rendering.pipeline.ShadeRangeWarning")  # two lights
def test_backends_agree_on_shadows_highlights_and_layers(ball_over_ground, cl_runtime):
    # the same image from both ray casters: directional and point light, specular, shadows
    # through a transparent ball, two layers; rays grazing an edge may differ
    cam = _ground_camera([0.3, -1, 0.1, 0.4])
    kw = dict(
        ao="none",
        ambient=0.3,
        diffuse=0.5,
        specular=0.3,
        shininess=12.0,
        shadows=True,
        light=[Light(direction=[0.5, 1, 0.3, -0.4]), Light(position=[0.8, 2.6, 0.3, -0.4])],
        opacity=[1.0, 0.5],
        color=[(0.2, 0.9, 0.3), (0.9, 0.2, 0.1)],
    )
    a = render(ball_over_ground, cam, (14, 14, 14), backend="numpy", **kw)
    b = render(ball_over_ground, cam, (14, 14, 14), backend="opencl", **kw)
    assert a.info["backend"] == "numpy" and b.info["backend"] == "opencl"
    same = a.object_id == b.object_id
    assert same.mean() > 0.99 and (a.object_id == 1).sum() > 100
    close = np.isclose(a.rgba, b.rgba, atol=1e-4).all(axis=-1)
    assert close[same].mean() > 0.98
    assert a.info["shadow_rays"] > a.info["hits"] and a.info["layer_rays"] > 0


def _flat_tet(corners3, w, slope=0.0):
    """A tetrahedron in the hyperplane w = const + slope * x, from 3D corners."""
    c = np.asarray(corners3, float)
    return _tet_mesh(np.column_stack([c, w + slope * c[:, 0]]))


BIG_TET = [[-1.5, -1.2, -1.2], [1.6, -1.2, -1.1], [-1.4, 1.7, -1.0], [-1.3, -1.1, 1.6]]


def test_depth_cue_is_monotone_in_depth():
    # a tetrahedron in the slanted hyperplane w = 0.8 x seen along +w: depth grows with x.
    # Ambient only, so shade = ambient * (1 - strength * clip((t - near) / (far - near), 0, 1))
    near, far, strength = 2.85, 3.25, 0.75
    mesh = _flat_tet(BIG_TET, 0.0, slope=0.8)
    cam = Camera4D([0, 0, 0, -3.5], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    shape = (24, 8, 8)
    img = render(mesh, cam, shape, ao="none", ambient=0.9, depth_cue=(near, far, strength), color=(1.0, 0.5, 0.25))
    t = img.depth[img.hit].astype(float)
    assert t.min() < near and t.max() > far  # the image spans the whole ramp
    expected = 0.9 * (1 - strength * np.clip((t - near) / (far - near), 0, 1))
    np.testing.assert_allclose(img.shade[img.hit], expected, rtol=1e-5)
    order = np.argsort(t, kind="stable")
    assert (np.diff(img.shade[img.hit][order]) <= 1e-6).all()  # never brighter farther away
    np.testing.assert_allclose(img.rgba[img.hit][:, :3], expected[:, None] * [1.0, 0.5, 0.25], rtol=1e-5)
    plain = render(mesh, cam, shape, ao="none", ambient=0.9)
    np.testing.assert_array_equal(plain.shade[img.hit & (img.depth < near)], img.shade[img.hit & (img.depth < near)])


RED, BLUE = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)


@pytest.mark.parametrize("red_in_front", [True, False])
def test_compositing_order_of_two_transparent_objects(red_in_front):
    # two flat tetrahedra covering the same voxels at w = 0 and w = 0.5, seen along +w; with
    # ambient 1 and no light each layer's colour is its own. Front to back: C = a1 c1 +
    # (1 - a1) a2 c2, A = a1 + (1 - a1) a2, and rgba holds C / A and A.
    a_red, a_blue = 0.5, 0.4
    red = _flat_tet(BIG_TET, 0.0 if red_in_front else 0.5)
    blue = _flat_tet(BIG_TET, 0.5 if red_in_front else 0.0)
    cam = Camera4D([0, 0, 0, -3], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    shape = (12, 12, 12)
    img = render([red, blue], cam, shape, ao="none", color=[RED, BLUE], opacity=[a_red, a_blue])
    (a1, c1), (a2, c2) = ((a_red, RED), (a_blue, BLUE)) if red_in_front else ((a_blue, BLUE), (a_red, RED))
    alpha = a1 + (1 - a1) * a2
    colour = (a1 * np.array(c1) + (1 - a1) * a2 * np.array(c2)) / alpha
    both = img.hit
    assert both.sum() > 200
    np.testing.assert_allclose(img.rgba[both], np.broadcast_to([*colour, alpha], (both.sum(), 4)), atol=1e-6)
    np.testing.assert_array_equal(img.object_id[both], 0 if red_in_front else 1)
    np.testing.assert_array_equal(img.rgba[~both], 0.0)
    assert img.info["layer_rays"] == both.sum() * 2  # a second hit, then a miss
    # one layer only: the front object alone
    front = render([red, blue], cam, shape, ao="none", color=[RED, BLUE], opacity=[a_red, a_blue], layers=1)
    np.testing.assert_allclose(front.rgba[both], np.broadcast_to([*c1, a1], (both.sum(), 4)), atol=1e-6)


def test_opaque_front_object_hides_the_back_one():
    red, blue = _flat_tet(BIG_TET, 0.0), _flat_tet(BIG_TET, 0.5)
    cam = Camera4D([0, 0, 0, -3], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    img = render([red, blue], cam, (10, 10, 10), ao="none", color=[RED, BLUE], opacity=[1.0, 0.3])
    np.testing.assert_array_equal(img.rgba[img.hit], np.broadcast_to([1, 0, 0, 1], (img.hit.sum(), 4)))
    assert img.info["layer_rays"] == 0


def _ao_lambert_shade(mesh, cam, shape, *, ambient, diffuse, light, normals, occlusion=None):
    """The AO-and-Lambert-only formula, on the same closest hits:
    ambient * (1 - A) + diffuse * max(0, n . l) (two-sided normals, per-vertex AO)."""
    from ao4d.rays.api import cast_rays

    o, w = (a.reshape(-1, 4) for a in cam.rays(shape))
    hits = cast_rays(mesh, o, w, closest=True)
    hit = hits.simplex >= 0
    tri = mesh.simplices[hits.simplex[hit]]
    raw_n = np.asarray(mesh.simplex_normals)[hits.simplex[hit]]
    side = np.where(np.einsum("hd,hd->h", raw_n, w[hit]) > 0, -1.0, 1.0)
    occ = np.zeros(hit.sum()) if occlusion is None else np.einsum("hk,hk->h", hits.barycentric[hit], occlusion[tri])
    shade = ambient * (1.0 - np.clip(occ, 0.0, 1.0))
    l = np.asarray(light, float) / np.linalg.norm(light)
    if normals == "smooth":
        n = np.einsum("hk,hkd->hd", hits.barycentric[hit], np.asarray(mesh.vertex_normals)[tri])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        n = n * side[:, None]
    else:
        n = raw_n * side[:, None]
    shade = shade + diffuse * np.clip(n @ l, 0.0, None)
    out = np.zeros(len(o), np.float32)
    out[hit] = shade
    return out.reshape(shape)


@pytest.mark.parametrize("normals", ["smooth", "flat"])
def test_without_new_terms_the_images_are_the_previous_ones_exactly(touching_pair, normals):
    mesh = touching_pair.copy()
    mesh.point_data["ao"] = np.random.default_rng(4).uniform(0, 1, mesh.n_vertices)
    cam = Camera4D([0.3, 0.8, -0.2, -4], [0, 0, 0, 0], fov=50)
    shape = (20, 12, 12)
    light = [0.3, 0.5, -0.2, -1.0]
    expected = _ao_lambert_shade(
        mesh, cam, shape, ambient=0.7, diffuse=0.3, light=light, normals=normals, occlusion=mesh.point_data["ao"]
    )
    for extra in ({}, {"shadows": False, "specular": 0.0}):
        img = render(mesh, cam, shape, ao="vertices", ambient=0.7, diffuse=0.3, light=light, shading=normals, **extra)
        np.testing.assert_array_equal(img.shade, expected)  # bit for bit
        # white objects under a white light: the colour is the grey shade (clipped), opaque
        np.testing.assert_array_equal(img.rgba[..., :3], np.repeat(np.clip(expected, 0, 1)[..., None], 3, -1))
        np.testing.assert_array_equal(img.rgba[..., 3], img.hit.astype(np.float32))
        assert img.info["shadow_rays"] == 0 and img.info["layer_rays"] == 0
    assert (expected > 0.75).any() and (expected < 0.5).any()  # light and AO both matter


@pytest.mark.filterwarnings("ignore::ao4d.rendering.pipeline.ShadeRangeWarning")  # two lights: shade up to 1.1
def test_two_coloured_lights_add_up(sphere):
    # a white object under a red light from one side and a blue one from the other: R holds
    # ambient + diffuse * max(0, n . l_red), B the same for blue, G the ambient alone
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    shape = (16, 16, 16)
    red = Light(direction=[1, 0.3, 0, -1], color=(1, 0, 0))
    blue = Light(direction=[-1, 0.3, 0, -1], color=(0, 0, 1), intensity=0.5)
    kw = dict(ao="none", ambient=0.2, diffuse=0.6)
    img = render(sphere, cam, shape, light=[red, blue], **kw)
    only_red = render(sphere, cam, shape, light=red, **kw)
    only_blue = render(sphere, cam, shape, light=blue, **kw)
    hit = img.hit
    np.testing.assert_allclose(img.rgba[hit][:, 0], only_red.shade[hit], atol=1e-6)
    np.testing.assert_allclose(img.rgba[hit][:, 2], only_blue.shade[hit], atol=1e-6)
    np.testing.assert_allclose(img.rgba[hit][:, 1], 0.2, atol=1e-6)
    np.testing.assert_allclose(img.shade[hit], only_red.shade[hit] + only_blue.shade[hit] - 0.2, atol=1e-6)


def test_specular_per_object_and_white_highlights():
    # two flat tetrahedra facing the viewer (n = -w = v) under a light along the view: n = h, so
    # the specular term is 1 exactly; it is added in the light's colour, not the object's
    a = _flat_tet(BIG_TET, 0.0)
    b = _flat_tet(np.array(BIG_TET) + [0, 0, 0], 0.5)
    cam = Camera4D([0, 0, 0, -3], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    img = render(
        [a, b],
        cam,
        (8, 8, 8),
        ao="none",
        ambient=0.0,
        diffuse=0.0,
        light=[0, 0, 0, -1],
        specular=[0.5, 0.9],
        shininess=[10.0, 3.0],
        color=[(0.2, 0.4, 1.0), (1, 1, 1)],
    )
    np.testing.assert_allclose(img.shade[img.hit], 0.5, atol=1e-9)
    np.testing.assert_allclose(img.rgba[img.hit][:, :3], 0.5, atol=1e-6)  # white highlight


def test_rgba_is_saved_as_direct_colours(sphere, tmp_path):
    # ParaView shows an unsigned-char array of 4 components as the voxels' colours when Map
    # Scalars is off: VTK's direct-scalars colour mode passes the bytes through unchanged
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    img = render(sphere, cam, (10, 9, 8), ao="none", light=[0, 1, 0, -1], ambient=0.5, color=(0.9, 0.3, 0.1))
    assert img.rgba.dtype == np.float32 and img.rgba.shape == (10, 9, 8, 4)
    assert img.rgba.min() >= 0 and img.rgba.max() <= 1
    path = img.save(tmp_path / "c.vti")
    back = ao4d.io.volumes.read_vti(path, array="rgba")
    np.testing.assert_array_equal(back.data, img.rgba8)
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    array = reader.GetOutput().GetPointData().GetArray("rgba")
    assert array.GetDataType() == vtk.VTK_UNSIGNED_CHAR and array.GetNumberOfComponents() == 4
    direct = vtk.vtkLookupTable().MapScalars(array, vtk.VTK_COLOR_MODE_DIRECT_SCALARS, -1)
    np.testing.assert_array_equal(vtk_to_numpy(direct), vtk_to_numpy(array))
    # voxel (i, j, k) is VTK point i + nx (j + ny k)
    np.testing.assert_array_equal(vtk_to_numpy(array)[5 + 10 * (4 + 9 * 3)], img.rgba8[5, 4, 3])
    assert ao4d.io.volumes.read_vti(path).name == "shade"  # the active array is unchanged


def test_result_repr_is_short(sphere):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.3)
    img = render(sphere, cam, (12, 12, 12), ao="none", backend="numpy")
    text = repr(img)
    assert text.startswith("RenderResult(12x12x12 voxels, ") and "backend='numpy'" in text
    assert f"{img.info['hits']:,} hit" in text and "array" not in text and len(text) < 200


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(specular=-0.1), ValueError, "`specular` must be >= 0"),
        (dict(shininess=0), ValueError, "`shininess` must be > 0"),
        (dict(specular=[0.1, 0.2]), ValueError, r"`specular` must be one value .* \(1,\)"),
        (dict(color=(1, 0)), ValueError, "`color` must be an RGB triple"),
        (dict(color=(1, 0, 2)), ValueError, r"`color` must be in \[0, 1\]"),
        (dict(color=[(1, 0, 0), (0, 1, 0)]), ValueError, r"\(1, 3\)"),
        (dict(opacity=1.5), ValueError, r"`opacity` must be in \[0, 1\]"),
        (dict(opacity=np.nan), ValueError, "`opacity` contains 1 non-finite"),
        (dict(shadows="yes"), TypeError, "`shadows` must be True or False"),
        (dict(layers=0), ValueError, "`layers` must be >= 1"),
        (dict(layers=17), ValueError, "`layers` must be <= 16"),
        (dict(depth_cue=(2, 1, 0.5)), ValueError, "near < far"),
        (dict(light=[Light(direction=[0, 1, 0, 0]), [0, 0, 0, 0]]), ValueError, r"`light\[1\]` must be a non-zero"),
    ],
)
def test_bad_illumination_input(kwargs, error, match):
    with pytest.raises(error, match=match):
        render(_tet_mesh(np.eye(4)), Camera4D([0, 0, 0, -3], [0, 0, 0, 0]), (4, 4, 4), **kwargs)


# -- the colour pictures and the command line -------------------------------------------------


def _red_blue_image():
    rgba = np.zeros((8, 6, 4, 4))
    rgba[:4, :, :, :] = (0.9, 0.1, 0.1, 1.0)  # x < half: red, opaque
    rgba[4:, :3, :, :] = (0.1, 0.1, 0.9, 1.0)  # the other half, lower part: blue
    return rgba


def _png_pixels(path):
    import matplotlib.image

    return matplotlib.image.imread(path)[..., :3]


def test_rgba_montage_shows_the_colours(tmp_path):
    from ao4d.io.pictures import save_rgba_montage

    path = save_rgba_montage(tmp_path / "m.png", _red_blue_image(), n_slices=2)
    px = _png_pixels(path).reshape(-1, 3)
    red = (px[:, 0] > 0.8) & (px[:, 1] < 0.2) & (px[:, 2] < 0.2)
    blue = (px[:, 2] > 0.8) & (px[:, 0] < 0.2) & (px[:, 1] < 0.2)
    background = np.all(np.abs(px - (0.33, 0.38, 0.45)) < 0.02, axis=1)
    assert red.sum() > 1.5 * blue.sum() > 0 and background.sum() > 0  # areas 24 : 12 per slice
    with pytest.raises(ValueError, match=r"`rgba` must hold finite values in \[0, 1\]"):
        save_rgba_montage(tmp_path / "x.png", _red_blue_image() * 2)


@pytest.mark.parametrize("backend", ["numpy", "pyvista"])
def test_rgba_volume_picture_shows_the_colours(tmp_path, backend):
    from ao4d.io.pictures import save_rgba_volume_png

    path = save_rgba_volume_png(tmp_path / "v.png", _red_blue_image(), backend=backend)
    px = _png_pixels(path).reshape(-1, 3)
    assert ((px[:, 0] > 0.7) & (px[:, 1] < 0.3) & (px[:, 2] < 0.3)).sum() > 100
    assert ((px[:, 2] > 0.7) & (px[:, 0] < 0.3) & (px[:, 1] < 0.3)).sum() > 50


@pytest.mark.filterwarnings("ignore::ao4d.rendering.pipeline.ShadeRangeWarning")  # 0.7 + 1.5 x 0.5
def test_render_command_with_lights_colours_and_opacity(ball_over_ground, tmp_path, capsys):
    from ao4d import cli

    ground, ball = ball_over_ground
    ground.save(tmp_path / "ground.npz")
    ball.save(tmp_path / "ball.npz")
    out = tmp_path / "lit.vti"
    argv = [
        "render",
        str(tmp_path / "ground.npz"),
        str(tmp_path / "ball.npz"),
        "--out",
        str(out),
        "--size",
        "16",
        "--ao",
        "none",
        "--eye",
        "0.2",
        "4",
        "-0.1",
        "0.15",
        "--target",
        "0.2",
        "0",
        "-0.1",
        "0.15",
        "--up",
        "0",
        "0",
        "0",
        "1",
        "--projection",
        "orthographic",
        "--light",
        "0",
        "1",
        "0",
        "0",
        "--light",
        "point",
        "0",
        "5",
        "0",
        "0",
        "0",
        "0",
        "1",
        "0.5",
        "--specular",
        "0.2",
        "--shininess",
        "10",
        "--shadows",
        "--color",
        "ball",
        "1",
        "0",
        "0",
        "--color",
        "0",
        "0",
        "1",
        "0",
        "--opacity",
        "ball",
        "1",
        "--png",
        str(tmp_path / "lit.png"),
    ]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "RenderResult(16x16x16 voxels" in printed
    ids = ao4d.io.volumes.read_vti(out, array="object_id").data
    rgba = ao4d.io.volumes.read_vti(out, array="rgba").data
    assert (ids == 1).sum() > 50 and (ids == 0).sum() > 50
    ball_px, ground_px = rgba[ids == 1].astype(int), rgba[ids == 0].astype(int)
    # a red ball and a green ground (white highlights add to every channel), opaque
    assert (ball_px[:, 0] > 100).all() and (ball_px[:, 0] > ball_px[:, 1] + 40).mean() > 0.9
    assert (ground_px[:, 1] > 100).all() and (ground_px[:, 1] > ground_px[:, 0] + 40).mean() > 0.9
    # a green ground has no blue of its own: blue there is the blue point light's highlight
    # (specular light keeps the light's colour)
    assert (ground_px[:, 2] > ground_px[:, 0] + 20).any()
    assert (rgba[..., 3][ids >= 0] == 255).all()
    for name in ("lit.png", "lit_volume.png", "lit_color.png", "lit_color_volume.png"):
        assert (tmp_path / name).is_file()


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--light", "0", "1", "0"], "4, 7 or 8 numbers"),
        (["--light", "point", "a", "1", "0", "0"], r"--light` takes \[point\]"),
        (["--color", "moon", "1", "0", "0"], "neither an index nor one of the meshes"),
        (["--opacity", "3", "0.5"], "out of range"),
        # the light's colour, not the option --color
        (
            ["--light", "0", "1", "0", "0", "2", "0", "0"],
            r"`--light` '0 1 0 0 2 0 0': its color must hold values in \[0, 1\]",
        ),
    ],
)
def test_render_command_errors(ball_over_ground, tmp_path, capsys, extra, match):
    from ao4d import cli

    ball_over_ground[1].save(tmp_path / "ball.npz")
    argv = ["render", str(tmp_path / "ball.npz"), "--out", str(tmp_path / "x.vti"), "--size", "4"]
    assert cli.main(argv + extra) == 2
    assert re.search(match, capsys.readouterr().err)


# -- render inputs out of range, and what info says ----------------------------------------------


def _small_scene():
    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), 10, (-1.3, 1.3))
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.5)
    return mesh, cam


def test_stored_ao_with_nan_or_outside_0_1_is_refused_before_the_work():
    mesh, cam = _small_scene()
    for bad, match in [
        (np.nan, r"`point_data\['ao'\]` is NaN at 1 vertices"),
        (1.5, r"`point_data\['ao'\]` must be occlusion in \[0, 1\]"),
    ]:
        values = np.zeros(mesh.n_vertices)
        values[3] = bad  # would give NaN shade, or 1.5 clamped silently
        mesh.point_data["ao"] = values
        with pytest.raises(ValueError, match=match):
            render(mesh, cam, (8, 8, 8), backend="numpy")


def test_weights_that_can_exceed_one_warn():
    mesh, cam = _small_scene()
    # ambient + diffuse > 1 can give shade above 1, although the docs say [0, 1]: a warning says so
    with pytest.warns(ao4d.rendering.pipeline.ShadeRangeWarning, match=r"= 1.5 > 1: shade can exceed 1"):
        img = render(mesh, cam, (8, 8, 8), ao="none", ambient=1.0, diffuse=0.5, light=[0, 0, 0, -1], backend="numpy")
    assert img.shade.max() > 1.0  # the warning was right
    img = render(mesh, cam, (8, 8, 8), ao="none", ambient=0.6, diffuse=0.4, light=[0, 0, 0, -1], backend="numpy")
    assert img.shade.max() <= 1.0 + 1e-6


def test_info_names_the_backend_that_ran():
    # the backend that ran ("opencl" or "numpy"), never the request ("auto")
    from ao4d.opencl import cl

    mesh, cam = _small_scene()
    img = render(mesh, cam, (6, 6, 6), ao="none")
    ran = cl.backend_name(cl.resolve_backend("auto", warn=False))
    assert img.info["backend"] == ran and img.info["backend"] in ("opencl", "numpy")
    assert img.info["device"] == cl.describe(cl.resolve_backend("auto", warn=False))


def test_inside_out_scene_warns():
    mesh, cam = _small_scene()
    with pytest.warns(ao4d.mesh.InsideOutWarning, match="inside out"):
        render(mesh.flipped(), cam, (6, 6, 6), samples=4, backend="numpy")


def test_default_weights_with_a_light_stay_in_0_1_and_match_the_cli(tmp_path):
    import warnings

    from ao4d import cli

    mesh, cam = _small_scene()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # before: defaults 1 + 0.5 gave shade up to 1.5, silently
        img = render(mesh, cam, (8, 8, 8), ao="none", light=[0, 0, 0, -1], backend="numpy")
    assert 0.95 < img.shade.max() <= 1.0 + 1e-6  # facing the light: 0.7 + 0.3 cos(angle)
    # the command line's defaults are the function's: the same .mhd, to the bit
    mesh.save(tmp_path / "ball.npz")
    assert (
        cli.main(
            [
                "render",
                str(tmp_path / "ball.npz"),
                "--out",
                str(tmp_path / "a.mhd"),
                "--size",
                "8",
                "--ao",
                "none",
                "--light",
                "0",
                "0",
                "0",
                "-1",
                "--projection",
                "orthographic",
                "--backend",
                "numpy",
                "--no-progress",
            ]
        )
        == 0
    )
    ao4d._progress.set_enabled(True)
    from ao4d.io.volumes import read_mhd

    seen = read_mhd(tmp_path / "a.mhd").data
    framed = Camera4D.framing(
        mesh.bounds, up=[0, 1, 0, 0], over=[0, 0, 1, 0], fov=40.0, projection="orthographic"
    )  # as the command frames the scene
    again = render(mesh, framed, (8, 8, 8), ao="none", light=[0, 0, 0, -1], backend="numpy")
    assert again.hit.any()
    np.testing.assert_array_equal(seen, again.shade)


@pytest.mark.parametrize("option", ["shininess", "specular", "opacity"])
def test_booleans_are_not_numbers(option):
    mesh, cam = _small_scene()
    with pytest.raises(TypeError, match=f"`{option}` must be a number"):  # before: True was 1
        render(mesh, cam, (4, 4, 4), ao="none", light=[0, 0, 0, -1], backend="numpy", **{option: True})


def test_ray_budget_is_checked_before_any_ray_and_can_be_lifted(monkeypatch):
    from ao4d import _budget
    from ao4d.rays import api

    mesh, cam = _small_scene()
    cast = []
    monkeypatch.setattr(ao4d.rendering.pipeline, "trace", lambda *a, **k: cast.append(1) or api.trace(*a, **k))
    with pytest.raises(ValueError, match=r"pass max_rays=math.inf \(CLI: --force\)"):
        render(mesh, cam, (16, 16, 16), ao="hits", samples=200000, backend="numpy")
    assert not cast  # before: the primary rays ran first, and render had no max_rays
    monkeypatch.setitem(_budget.MAX_RAYS, "numpy", 100)
    with pytest.raises(ValueError, match="above the limit"):
        render(mesh, cam, (8, 8, 8), ao="none", backend="numpy")
    img = render(mesh, cam, (8, 8, 8), ao="none", backend="numpy", max_rays=math.inf)
    assert img.hit.any() and cast


@pytest.mark.parametrize("backend", ["numpy", "opencl"])
def test_screen_ao_and_its_filter_are_budgeted_before_any_ray(backend, request, monkeypatch):
    # --samples 10000000 and --denoise 30 ran for minutes on numpy without an estimate
    from ao4d.rays import api

    if backend == "opencl":
        request.getfixturevalue("cl_runtime")
    mesh, cam = _small_scene()
    cast = []
    monkeypatch.setattr(ao4d.rendering.pipeline, "trace", lambda *a, **k: cast.append(1) or api.trace(*a, **k))
    with pytest.raises(ValueError, match=r"`samples`=60000 \(.* depth look-ups.*about \d+ (h|days) on the"):
        render(mesh, cam, (128, 128, 128), ao="screen", samples=60_000, backend=backend)
    if backend == "numpy":
        with pytest.raises(ValueError, match=r"`denoise`=30 \(.*filter-window voxels.*about \d+ min on the numpy"):
            render(mesh, cam, (64, 64, 64), ao="screen", samples=4, denoise=30, backend=backend)
    assert not cast
    img = render(mesh, cam, (8, 8, 8), ao="screen", samples=8, denoise=1, backend=backend)
    assert img.hit.any() and cast


def test_render_command_force_lifts_the_ray_budget(tmp_path, capsys, monkeypatch):
    from ao4d import _budget, cli

    mesh, _ = _small_scene()
    mesh.save(tmp_path / "ball.npz")
    monkeypatch.setitem(_budget.MAX_RAYS, "numpy", 100)
    argv = [
        "render",
        str(tmp_path / "ball.npz"),
        "--out",
        str(tmp_path / "a.vti"),
        "--size",
        "6",
        "--ao",
        "none",
        "--backend",
        "numpy",
    ]
    assert cli.main(argv) == 2
    assert "--force" in capsys.readouterr().err and not (tmp_path / "a.vti").exists()
    assert cli.main(argv + ["--force"]) == 0 and (tmp_path / "a.vti").exists()


def test_a_3d_mesh_is_named_as_the_problem(tmp_path, capsys):
    from ao4d import cli

    values = np.linalg.norm(np.indices((10,) * 3) - 4.5, axis=0) - 3.0
    mesh3 = ao4d.extract(values)
    mesh3.save(tmp_path / "m3.npz")
    code = cli.main(
        ["render", str(tmp_path / "m3.npz"), "--out", str(tmp_path / "a.vti"), "--size", "4", "--backend", "numpy"]
    )
    err = capsys.readouterr().err
    assert code == 2 and "`meshes`: m3.npz is a 3D mesh" in err and "bounds" not in err


def test_render_command_refuses_a_non_ascii_mhd_before_rendering(tmp_path, capsys, monkeypatch):
    from ao4d import cli

    mesh, _ = _small_scene()
    mesh.save(tmp_path / "ball.npz")
    (tmp_path / "keep_é.raw").write_bytes(b"old")
    rendered = []
    monkeypatch.setattr("ao4d.rendering.pipeline.render", lambda *a, **k: rendered.append(1))
    code = cli.main(
        [
            "render",
            str(tmp_path / "ball.npz"),
            "--out",
            str(tmp_path / "keep_é.mhd"),
            "--size",
            "4",
            "--backend",
            "numpy",
        ]
    )
    assert code == 2 and "ASCII" in capsys.readouterr().err and not rendered
    assert (tmp_path / "keep_é.raw").read_bytes() == b"old"
    assert not (tmp_path / "keep_é.mhd").exists()


def test_stored_ao_skips_the_inside_out_check(monkeypatch):
    # the check measures the enclosed volume (a pass over every simplex, 0.4 s at 600k
    # tetrahedra): render pays it only when it computes AO itself
    mesh, cam = _small_scene()
    flipped = mesh.flipped()
    flipped.point_data["ao"] = np.zeros(flipped.n_vertices)  # AO from elsewhere, checked there
    calls = []
    monkeypatch.setattr(ao4d.rendering.pipeline, "warn_if_inside_out", lambda *a, **k: calls.append(1))
    img = render(flipped, cam, (6, 6, 6), ao="vertices", backend="numpy")
    assert img.hit.any() and not calls
    render(mesh, cam, (6, 6, 6), ao="hits", samples=4, backend="numpy")
    assert calls == [1]


def test_ao_given_as_an_array_is_shaded_as_stored_ao_without_ao_rays():
    mesh, cam = _small_scene()
    values = np.linspace(0.0, 1.0, mesh.n_vertices)
    given = render(mesh, cam, (8, 8, 8), ao=values, backend="numpy")
    assert given.info["ao_rays"] == 0 and "ao" not in mesh.point_data
    stored = mesh.copy()
    stored.point_data["ao"] = values
    by_point_data = render(stored, cam, (8, 8, 8), ao="vertices", backend="numpy")
    assert np.array_equal(given.shade, by_point_data.shade)
    assert np.array_equal(given.occlusion, by_point_data.occlusion, equal_nan=True)
    # the occlusion at a hit interpolates the given values: not all zero, not recomputed
    assert np.nanmax(given.occlusion) > 0.1


def test_ao_given_per_mesh_of_a_list_is_joined_in_list_order():
    left, right = _left_and_right(12)
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.0)
    img = render(
        [left, right], cam, (16, 8, 8), ao=[np.zeros(left.n_vertices), np.full(right.n_vertices, 0.5)], backend="numpy"
    )
    assert np.all(img.occlusion[img.object_id == 0] == 0)
    assert np.allclose(img.occlusion[img.object_id == 1], 0.5)
    assert np.allclose(img.shade[img.object_id == 1], 0.5)


@pytest.mark.parametrize(
    "ao, match",
    [
        (np.zeros(5), r"`ao` must hold one value per vertex"),
        (np.full(1, np.nan), r"`ao` is NaN"),
        ("everywhere", r"`ao`"),
    ],
)
def test_bad_ao_values_are_refused_naming_ao(ao, match):
    mesh, cam = _small_scene()
    if np.ndim(ao) == 1 and len(ao) == 1:  # a NaN at a used vertex
        ao = np.zeros(mesh.n_vertices)
        ao[mesh.simplices[0, 0]] = np.nan
    with pytest.raises(ValueError, match=match):
        render(mesh, cam, (4, 4, 4), ao=ao, backend="numpy")


def test_ao_per_mesh_of_the_wrong_length_is_refused():
    mesh, cam = _small_scene()
    with pytest.raises(ValueError, match=r"`ao\[1\]` must hold one value per vertex of meshes\[1\]"):
        render([mesh, mesh], cam, (4, 4, 4), ao=[np.zeros(mesh.n_vertices), np.zeros(3)], backend="numpy")


def test_shading_flat_differs_and_the_removed_normals_keyword_is_refused():
    mesh, cam = _small_scene()
    kw = dict(ao="none", light=(0, 1, 0, -1), backend="numpy")
    flat = render(mesh, cam, (8, 8, 8), shading="flat", **kw)
    smooth = render(mesh, cam, (8, 8, 8), **kw)
    assert not np.array_equal(flat.shade, smooth.shade)
    with pytest.raises(ValueError, match="shading"):
        render(mesh, cam, (4, 4, 4), shading="phong", **kw)
    # `normals=` was shading's old spelling; the package has no released users, so no alias
    with pytest.raises(TypeError, match="normals"):
        render(mesh, cam, (4, 4, 4), normals="flat", **kw)


def test_one_trace_per_ray_batch_on_one_tracer(monkeypatch):
    # every batch of rays is one internal trace on the tracer resolved once: no public
    # cast_rays re-validating rays and re-resolving the backend and tree per batch
    from ao4d.rays import api

    mesh, cam = _small_scene()
    calls = []
    monkeypatch.setattr(
        ao4d.rendering.pipeline,
        "trace",
        lambda tracer, o, w, **k: calls.append((tracer, len(o))) or api.trace(tracer, o, w, **k),
    )
    monkeypatch.setattr(api, "cast_rays", lambda *a, **k: pytest.fail("public cast_rays re-entered"))
    img = render(mesh, cam, (48, 48, 32), ao="none", light=(0, 1, 0, -1), shadows=True, backend="numpy")
    chunk = ao4d.rendering.pipeline._CHUNK
    primary = 48 * 48 * 32
    assert [n for _, n in calls[:2]] == [chunk, primary - chunk]  # two batches of primary rays
    assert len({id(tracer) for tracer, _ in calls}) == 1
    assert sum(n for _, n in calls[2:]) == img.info["shadow_rays"]


def test_render_takes_pairs_and_refuses_other_types_naming_meshes(touching_pair):
    import trimesh

    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.2)
    args = dict(ao="vertices", samples=8, seed=1, light=[0, 1, 0, -1], backend="numpy", progress=False)
    pair = (touching_pair.vertices, touching_pair.simplices)
    # a fresh mesh: the fixture may hold a tree built by another builder in an earlier test, and
    # a ray through a shared edge may then report the other simplex (AO equal up to rounding)
    want = render(ao4d.SimplexMesh(*pair), cam, (12, 6, 6), **args)
    assert want.hit.sum() > 50
    for form in (pair, [pair], [touching_pair.vertices, touching_pair.simplices]):
        got = render(form, cam, (12, 6, 6), **args)
        for name in ("shade", "depth", "occlusion", "object_id", "rgba"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    with pytest.raises(ValueError, match="`meshes` must be 4D meshes"):  # a trimesh is 3D
        render(trimesh.creation.box(), cam, (4, 4, 4), **args)
    with pytest.raises(
        TypeError, match=r"`meshes` must be a SimplexMesh, a trimesh.Trimesh, a \(vertices, simplices\)"
    ):
        render(3.0, cam, (4, 4, 4), **args)
