"""Camera4D: Hollasch's From/To/Up/Over basis, rays through voxel centres, and its errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ao4d.geometry import cross
from ao4d.rendering.camera import Camera4D

# tolerance for float64 basis algebra on O(1) vectors (a few ulps times a few operations)
EPS = 1e-10


def test_looking_along_w_gives_identity_basis():
    cam = Camera4D([0, 0, 0, -5], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0])
    np.testing.assert_allclose(cam.basis, np.eye(4), atol=EPS)
    # and the image sees x, y, z of the world unmirrored
    np.testing.assert_allclose(cam.project([[0.3, -0.2, 0.1, 0.0]]), [[0.3, -0.2, 0.1]], atol=EPS)


vec4 = st.lists(st.floats(-3, 3, allow_nan=False, allow_subnormal=False), min_size=4, max_size=4).map(np.array)


def _independent(*vectors, tol=0.05):
    m = np.array([v / np.linalg.norm(v) for v in vectors])
    return np.linalg.svd(m, compute_uv=False).min() > tol


@settings(max_examples=60, deadline=None)
@given(eye=vec4, target=vec4, up=vec4, over=vec4)
def test_basis_properties(eye, target, up, over):
    view = target - eye
    assume(np.linalg.norm(view) > 0.1 and np.linalg.norm(up) > 0.1 and np.linalg.norm(over) > 0.1)
    assume(_independent(view, up, over))
    cam = Camera4D(eye, target, up, over)
    a, b, c, d = cam.basis
    np.testing.assert_allclose(cam.basis @ cam.basis.T, np.eye(4), atol=EPS)  # orthonormal
    assert np.linalg.det(cam.basis) == pytest.approx(1.0, abs=EPS)  # right-handed
    np.testing.assert_allclose(cross(a, b, c), d, atol=EPS)  # d is the image's normal
    np.testing.assert_allclose(d, view / np.linalg.norm(view), atol=EPS)
    # Hollasch: c is `over` made orthogonal to d; `up` lies in span(b, c, d) with b > 0
    o = over - (over @ d) * d
    np.testing.assert_allclose(c, o / np.linalg.norm(o), atol=1e-8)
    assert abs(up @ a) < 1e-8 * np.linalg.norm(up)
    assert up @ b > 0


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
@pytest.mark.parametrize("shape", [(5, 4, 3), (1, 6, 2), (8, 8, 8)])
def test_rays_pass_through_voxel_centres(projection, shape):
    cam = Camera4D([1, 2, -3, 4], [0.5, 0, 0.2, -0.3], [0, 1, 0.3, 0], [0.2, 0, 1, 0], projection=projection, fov=50)
    origins, directions = cam.rays(shape)
    centres = cam.voxel_centers(shape)
    assert origins.shape == directions.shape == centres.shape == shape + (4,)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=-1), 1.0, atol=EPS)
    t = np.linalg.norm(centres - origins, axis=-1, keepdims=True)
    np.testing.assert_allclose(origins + t * directions, centres, atol=1e-9)
    # centres lie on the image hyperplane through the target, on a regular cubic grid
    np.testing.assert_allclose((centres - cam.target) @ cam.view, 0.0, atol=1e-9)
    geo = cam.geometry(shape)
    if shape[0] > 1:
        np.testing.assert_allclose(
            centres[1] - centres[0], np.broadcast_to(geo.spacing * cam.basis[0], centres[0].shape), atol=1e-9
        )
    np.testing.assert_allclose(centres.reshape(-1, 4).mean(0), cam.target, atol=1e-9)
    assert geo.spacing * max(shape) == pytest.approx(2 * cam.half_width)
    # each voxel appears where its centre is: project() inverts voxel_centers()
    u = np.stack(np.meshgrid(*[o + geo.spacing * np.arange(n) for o, n in zip(geo.origin, shape)], indexing="ij"), -1)
    np.testing.assert_allclose(cam.project(centres), u, atol=1e-9)


def test_perspective_rays_start_at_eye_and_span_fov():
    fov = 60.0
    cam = Camera4D([0, 0, 0, -3], [0, 0, 0, 0], fov=fov)
    origins, directions = cam.rays((4, 4, 4))
    np.testing.assert_allclose(origins, np.broadcast_to(cam.eye, origins.shape))
    # the outer voxel boundary of the longest axis is seen at fov/2 off the view direction
    edge = cam.target + cam.half_width * cam.basis[0]
    angle = math.degrees(math.acos(cam.view @ (edge - cam.eye) / np.linalg.norm(edge - cam.eye)))
    assert angle == pytest.approx(fov / 2)


def test_orthographic_rays_are_parallel():
    cam = Camera4D([1, 1, 1, 1], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], projection="orthographic", half_width=2.0)
    origins, directions = cam.rays((3, 5, 7))
    np.testing.assert_allclose(directions, np.broadcast_to(cam.view, directions.shape), atol=EPS)
    # origins spread over the eye's hyperplane, not a single point
    np.testing.assert_allclose((origins - cam.eye) @ cam.view, 0.0, atol=1e-9)
    assert np.ptp(origins.reshape(-1, 4), axis=0).max() > 1.0


def test_symmetric_image_grid():
    # voxel centres mirror about the target along every image axis (what the thesis broke)
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0])
    for shape in [(6, 6, 6), (7, 5, 4)]:
        u = cam.project(cam.voxel_centers(shape))
        for k in range(3):
            np.testing.assert_allclose(u[..., k], -np.flip(u, axis=k)[..., k], atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(eye=[1, 2, 3, 4], target=[1, 2, 3, 4]), "`eye` and `target` must differ"),
        (dict(up=[0, 0, 0, 3]), "`up` is parallel to the view"),
        (dict(over=[0, 0, 0, -1]), "`over` is parallel to the view"),
        (dict(up=[0, 0, 0, 0]), "`up` must be a non-zero"),
        (dict(over=[0, 2, 0, 0]), "`over` lies in the plane"),
        (dict(over=[0, 1, 0, 1]), "`over` lies in the plane"),
        (dict(eye=[0, 0, np.nan, -4]), "`eye` contains 1 non-finite"),
        (dict(target=[0, 0, 0]), r"`target` must have shape \(\.\.\., 4\)"),
        (dict(fov=180), "`fov` must be in"),
        (dict(fov=0), "`fov` must be in"),
        (dict(projection="fisheye"), "`projection` must be one of"),
        (dict(half_width=-1.0), "`half_width` must be > 0"),
    ],
)
def test_bad_camera(kwargs, match):
    args = dict(eye=[0, 0, 0, -4], target=[0, 0, 0, 0], up=[0, 1, 0, 0], over=[0, 0, 1, 0])
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Camera4D(**args)


@pytest.mark.parametrize(
    ("shape", "error", "match"),
    [
        ((4, 4), ValueError, "3 entries"),
        ((4, 0, 4), ValueError, "shape"),
        ((4, 4.5, 4), TypeError, "shape"),
        (7, TypeError, "shape"),
    ],
)
def test_bad_shape(shape, error, match):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0])
    with pytest.raises(error, match=match):
        cam.rays(shape)


def test_axis_permutations_keep_positive_orientation():
    # every choice of view/up/over among the coordinate axes gives det = +1
    for d_ax, u_ax, o_ax in itertools.permutations(range(4), 3):
        e = np.eye(4)
        for sign in (1, -1):
            cam = Camera4D(-4 * sign * e[d_ax], np.zeros(4), e[u_ax], e[o_ax])
            assert np.linalg.det(cam.basis) == pytest.approx(1.0)
            assert cam.basis[1] @ e[u_ax] == pytest.approx(1.0)
            assert cam.basis[2] @ e[o_ax] == pytest.approx(1.0)


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_framing_sees_the_whole_box(projection):
    rng = np.random.default_rng(7)
    lo = rng.uniform(-2, 0, 4)
    hi = lo + rng.uniform(0.5, 3, 4)
    view = rng.normal(size=4)
    cam = Camera4D.framing([lo, hi], view=view, projection=projection, fov=35)
    np.testing.assert_allclose(cam.view, view / np.linalg.norm(view), atol=EPS)
    np.testing.assert_allclose(cam.target, (lo + hi) / 2, atol=EPS)
    corners = np.array(list(itertools.product(*zip(lo, hi))))
    u = cam.project(corners)
    # every corner appears inside the image (|u| within the half width on each axis)
    assert np.isfinite(u).all()
    assert np.abs(u).max() <= cam.half_width * (1 + 1e-9)
    # and tightly: orthographic reaches half_width / margin exactly; perspective, whose far
    # corners shrink, still fills more than half of the image
    if projection == "orthographic":
        assert np.abs(u).max() == pytest.approx(cam.half_width / 1.1)
    else:
        assert np.abs(u).max() > 0.5 * cam.half_width


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(bounds=[[0, 0, 0, 0], [-1, 1, 1, 1]]), "lo <= hi"),
        (dict(bounds=[0, 1]), "`bounds` must"),
        (dict(margin=0.5), "`margin` must be >= 1"),
        (dict(view=[0, 0, 0, 0]), "`view` must be a non-zero"),
        (dict(fov=200), "`fov` must be in"),
    ],
)
def test_framing_errors(kwargs, match):
    args = dict(bounds=[[-1] * 4, [1] * 4])
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Camera4D.framing(args.pop("bounds"), **args)
