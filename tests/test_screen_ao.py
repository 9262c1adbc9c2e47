"""4D screen-space AO: analytic flat cases, the two backends, ray-traced AO, what it cannot see,
and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _scenes import flat_patch

import ao4d
from ao4d.mesh import SimplexMesh, concatenate
from ao4d.rendering.camera import Camera4D
from ao4d.rendering.pipeline import render
from ao4d.rendering.screen_ao import DepthVolume, default_steps, denoise, screen_space_occlusion

BETA = math.radians(30.0)  # the wall scene's camera looks this far down onto the floor
WALL_X, REACH = 1.0, 1.0


def wall_occlusion(a, L):
    """4D AO at a point with normal e_last at distance a from a perpendicular wall, hits within
    L (the closed form of tests/test_ao.py: the volume of a ball cap over the ball's)."""
    c = min(a / L, 1.0)
    return (1 - c) ** 2 * (2 + c) / 4


def _floor(lo=(-2.0, -2.5, -2.5), hi=(WALL_X, 2.5, 2.5)):
    return SimplexMesh(*flat_patch(4, lo, hi, 0.0, n=2))


def _wall_scene():
    """The floor x_3 = 0 (x_0 <= WALL_X) and a tall wall x_0 = WALL_X standing on it."""
    wall = SimplexMesh(*flat_patch(4, (-2.5, -2.5, -0.1), (2.5, 2.5, 3.0), WALL_X, n=2, axis=0))
    return concatenate([_floor(), wall])


def _oblique_camera(projection="orthographic"):
    """Looking towards +x_0 (at the wall's face) and BETA down onto the floor."""
    view = np.array([math.cos(BETA), 0.0, 0.0, -math.sin(BETA)])
    target = np.array([0.55, 0.0, 0.0, 0.35])
    return Camera4D(
        target - 6.0 * view, target, up=[0, 0, 0, 1], over=[0, 0, 1, 0], fov=30, projection=projection, half_width=1.5
    )


def _volume(scene, cam, shape, backend="numpy"):
    """Depth volume of ``scene`` (its viewer-facing face normals), the hit points, the hit mask."""
    volume = DepthVolume.trace(scene, cam, shape, backend=backend)
    origins, directions = (a.reshape(-1, 4) for a in cam.rays(shape))
    hit = volume.hit.reshape(-1)
    depth = np.where(hit, volume.depth.reshape(-1), 0.0)
    return volume, origins + depth[:, None] * directions, hit


# -- analytic cases -----------------------------------------------------------------------------


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_open_hyperplane_facing_the_camera_gets_zero(projection, backend):
    # every march point lies above the floor; the voxel's tangent hyperplane extended to the
    # point's own view ray lies behind it, whatever voxel it falls in: exactly 0, no acne
    floor = _floor(lo=(-4.0, -4.0, -4.0), hi=(4.0, 4.0, 4.0))
    cam = _oblique_camera(projection)
    img = render(floor, cam, (16, 16, 16), ao="screen", samples=16, max_distance=0.8, backend=backend)
    assert img.hit.sum() > 1000
    assert (img.occlusion[img.hit] == 0).all()
    assert img.info["ao_rays"] == 0 and img.info["screen_lookups"] == img.hit.sum() * 16 * 4
    assert default_steps(DepthVolume.trace(floor, cam, (16, 16, 16)), 0.8) == 4  # 0.8 = 4.3 voxels


def test_foot_of_a_visible_perpendicular_wall_matches_the_closed_form(backend):
    # Floor points p at distance a from the wall x_0 = WALL_X, normal e_3, reach L = 1. A ray
    # meets the wall within L iff its end p + L w lies beyond the wall; seen from the camera
    # (on the wall's front side) such an end is hidden by the wall, one in front of it is not.
    # So for a half-space occluder only the march's last point (r = L) decides and the estimate
    # is the ray-traced one direction by direction, with two exceptions:
    # - the range limit: an end lies (x_0 - WALL_X) / cos(BETA) <= (L - a) / cos(BETA) behind the
    #   wall along the view, below the default thickness L when a > L (1 - cos BETA) = 0.134;
    #   the points below have a >= 0.2;
    # - ends beyond the wall whose nearest voxel shows the floor (within half a voxel diagonal
    #   h of the wall's foot in the image) are missed: their height is below h / cos(BETA), so
    #   they are among the directions with w . n < eps = h / (L cos BETA); under the 4D cosine
    #   density P(w . n < eps) = 1 - (1 - eps^2)^(3/2). That bounds the (one-sided) bias.
    scene = _wall_scene()
    cam = _oblique_camera()
    shape = (32, 32, 32)
    volume, points, hit = _volume(scene, cam, shape)
    a = WALL_X - points[:, 0]
    band = hit & (np.abs(points[:, 3]) < 1e-6) & (a >= 0.2) & (a <= 0.9)
    band &= (np.abs(points[:, 1]) <= 0.3) & (np.abs(points[:, 2]) <= 0.3)
    p, n = points[band], np.tile([0.0, 0, 0, 1], (int(band.sum()), 1))
    assert len(p) >= 100
    samples = 64
    screen = screen_space_occlusion(volume, p, n, samples=samples, max_distance=REACH, backend=backend)
    exact = np.array([wall_occlusion(x, REACH) for x in a[band]])
    h = cam.geometry(shape).spacing * math.sqrt(3) / 2
    eps = h / (REACH * math.cos(BETA))
    missed = 1 - (1 - eps**2) ** 1.5  # 0.013
    sigma = math.sqrt(exact.mean() * (1 - exact.mean()) / (len(p) * samples))
    assert -missed - 4 * sigma <= screen.mean() - exact.mean() <= 4 * sigma
    # the same directions as the ray-traced AO: the difference has no Monte Carlo noise left
    # beyond the misses (and the ray offset of 1e-4 diagonals, negligible here)
    traced = ao4d.ambient_occlusion(scene, points=p, normals=n, samples=samples, max_distance=REACH, backend=backend)
    diff = screen - traced
    assert -missed - 0.005 <= diff.mean() <= 0.005
    assert (np.abs(diff) <= 3 / samples).mean() >= 0.95


def test_occluders_outside_the_image_are_not_seen():
    # wrong by construction: with the wall out of view the floor's screen-space AO is 0,
    # while the ray-traced AO still sees the wall
    scene = _wall_scene()
    view = np.array([math.cos(BETA), 0.0, 0.0, -math.sin(BETA)])
    target = np.array([-1.0, 0.0, 0.0, 0.0])
    cam = Camera4D(
        target - 6.0 * view, target, up=[0, 0, 0, 1], over=[0, 0, 1, 0], projection="orthographic", half_width=0.6
    )
    volume, points, hit = _volume(scene, cam, (12, 12, 12))
    assert hit.sum() > 1000 and np.abs(points[hit, 3]).max() < 1e-5  # only floor
    p = np.array([[WALL_X - 0.3, 0.0, 0.0, 0.0]])
    n = np.array([[0.0, 0, 0, 1]])
    assert screen_space_occlusion(volume, p, n, samples=64, max_distance=REACH, backend="numpy")[0] == 0
    traced = ao4d.ambient_occlusion(scene, points=p, normals=n, samples=64, max_distance=REACH, backend="numpy")[0]
    assert traced == pytest.approx(wall_occlusion(0.3, REACH), abs=4 * 0.5 / 8)


# -- backends, determinism, ray-traced AO ---------------------------------------------------------


PAIR_CAMERAS = {
    "orthographic": Camera4D([0, 0.5, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2.2),
    "perspective": Camera4D([0.3, 0.8, 0, -5], [0, 0, 0, 0], fov=55),
}


@pytest.mark.parametrize("projection", sorted(PAIR_CAMERAS))
def test_backends_agree(touching_pair, projection, cl_runtime):
    # the same integers, the same steps; float32 against float64 may flip a march point lying
    # within rounding of a voxel boundary or of the bias: allow 1 % of the voxels to differ
    cam = PAIR_CAMERAS[projection]
    images = {
        b: render(touching_pair, cam, (24, 12, 12), ao="screen", samples=32, max_distance=1.0, seed=5, backend=b)
        for b in ("numpy", "opencl")
    }
    ref, dev = (images[b].occlusion[images[b].hit] for b in ("numpy", "opencl"))
    np.testing.assert_array_equal(images["numpy"].hit, images["opencl"].hit)
    assert (ref != dev).mean() <= 0.01
    assert np.abs(ref - dev).max() <= 2 / 32
    assert ref.max() > 0.2  # the gap is occluded: the comparison is not between zeros


def test_deterministic_for_a_seed(touching_pair):
    cam = PAIR_CAMERAS["orthographic"]
    one, two, other = (
        render(touching_pair, cam, (12, 6, 6), ao="screen", samples=16, max_distance=1.0, seed=s, backend="numpy")
        for s in (3, 3, 4)
    )
    np.testing.assert_array_equal(one.occlusion, two.occlusion)
    assert not np.array_equal(one.occlusion[one.hit], other.occlusion[other.hit])


@pytest.mark.parametrize("projection", sorted(PAIR_CAMERAS))
def test_close_to_ray_traced_ao_on_a_small_scene(touching_pair, projection, backend):
    # measured on this scene (64 directions, reach 1, seeds 2 and 7): MAE 0.015-0.019,
    # correlation 0.75-0.79, screen-space higher by 0.015-0.018 on average (each sphere's
    # visible front is taken as solid up to the reach behind it, so it occludes the other's
    # points behind it too). The bounds leave room for other seeds and float32 roundings and
    # fail when the estimate goes wrong (no occlusion at all gives correlation 0; a flipped
    # depth test occludes every open point: MAE above 0.5)
    cam = PAIR_CAMERAS[projection]
    shape = (24, 12, 12)
    screen = render(touching_pair, cam, shape, ao="screen", samples=64, max_distance=1.0, seed=2, backend=backend)
    traced = render(touching_pair, cam, shape, ao="hits", samples=64, max_distance=1.0, seed=2, backend=backend)
    a, b = screen.occlusion[screen.hit], traced.occlusion[traced.hit]
    assert np.abs(a - b).mean() < 0.03
    assert np.corrcoef(a, b)[0, 1] > 0.6


def test_render_uses_the_images_own_depth_volume(touching_pair):
    cam = PAIR_CAMERAS["perspective"]
    shape = (12, 6, 6)
    img = render(touching_pair, cam, shape, ao="screen", samples=16, max_distance=0.7, seed=1, backend="numpy")
    volume, points, hit = _volume(touching_pair, cam, shape)
    normals = volume.normals.reshape(-1, 4)[hit]
    direct = screen_space_occlusion(volume, points[hit], normals, samples=16, max_distance=0.7, seed=1, backend="numpy")
    np.testing.assert_array_equal(img.occlusion.reshape(-1)[hit], direct)
    np.testing.assert_allclose(img.shade[img.hit], 1 - img.occlusion[img.hit], atol=1e-6)


def test_cli_render_with_screen_ao(touching_pair, tmp_path, capsys):
    from ao4d import cli

    path = tmp_path / "pair.npz"
    touching_pair.save(path)
    out = tmp_path / "img.vti"
    assert (
        cli.main(
            [
                "render",
                "--no-progress",
                str(path),
                "--out",
                str(out),
                "--size",
                "8",
                "--ao",
                "screen",
                "--samples",
                "8",
                "--max-distance",
                "1",
                "--denoise",
                "1",
                "--backend",
                "numpy",
            ]
        )
        == 0
    )
    back = ao4d.io.volumes.read_vti(out, array="occlusion").data
    assert np.nanmax(back) > 0 and np.nanmin(back) >= 0


# -- denoising ------------------------------------------------------------------------------------


def test_denoise_keeps_planes_and_edges_and_the_backends_agree(cl_runtime):
    # the wall scene: a linear ramp on the floor is kept (a symmetric mean of a linear function
    # over a full window; the window is cut only at the floor's edges), the wall's
    # values never leak onto the floor across the crease (normals 90 degrees apart), and the
    # numbers on the device are those of the numpy reference up to float32 rounding
    scene = _wall_scene()
    cam = _oblique_camera("perspective")
    shape = (16, 16, 16)
    volume, points, hit = _volume(scene, cam, shape)
    on_wall = hit & (np.abs(points[:, 0] - WALL_X) < 1e-6)
    on_floor = hit & ~on_wall
    occ = np.full(len(hit), np.nan)
    occ[on_floor] = 0.2 + 0.1 * points[on_floor, 1]
    occ[on_wall] = 1.0
    occ = occ.reshape(shape)
    ref = denoise(occ, volume, radius=1, backend="numpy")
    dev = denoise(occ, volume, radius=1, backend="opencl")
    np.testing.assert_array_equal(np.isnan(ref), ~volume.hit)
    np.testing.assert_allclose(dev[volume.hit], ref[volume.hit], atol=1e-6)
    floor_img, wall_img = on_floor.reshape(shape), on_wall.reshape(shape)
    np.testing.assert_allclose(ref[wall_img], 1.0)
    assert ref[floor_img].max() <= 0.2 + 0.1 * points[on_floor, 1].max() + 1e-9  # no wall leaks in
    # inside the floor (window full, all floor): the ramp itself, up to the perspective map's
    # second-order asymmetry of the window's floor patch (measured 2.1e-4)
    full = np.zeros(shape, dtype=bool)
    full[1:-1, 1:-1, 1:-1] = True
    for d in np.ndindex(3, 3, 3):
        sl = tuple(slice(o, k - 2 + o) for o, k in zip(d, shape))
        full[1:-1, 1:-1, 1:-1] &= floor_img[sl]
    assert full.sum() > 50
    np.testing.assert_allclose(ref[full], occ[full], atol=1e-3)
    assert np.array_equal(denoise(occ, volume, radius=0, backend="numpy")[volume.hit], occ[volume.hit])


def test_denoised_few_directions_stay_close_to_ray_traced(touching_pair):
    # 8 directions: per-voxel noise up to 0.5 / sqrt(8) = 0.18; the 3^3 filter averages about
    # 9 to 27 voxels of the same surface. Measured MAE against 64 traced rays (seeds 4, 9;
    # both cameras): 0.011-0.012 raw, 0.009-0.011 denoised (most voxels of this scene see
    # nothing, so both are small); the test asks for the gain and a bound with room
    cam = PAIR_CAMERAS["orthographic"]
    shape = (24, 12, 12)
    traced = render(touching_pair, cam, shape, ao="hits", samples=64, max_distance=1.0, seed=4)
    raw = render(touching_pair, cam, shape, ao="screen", samples=8, max_distance=1.0, seed=4)
    smooth = render(touching_pair, cam, shape, ao="screen", samples=8, max_distance=1.0, seed=4, denoise=1)
    ref = traced.occlusion[traced.hit]
    mae_raw = np.abs(raw.occlusion[raw.hit] - ref).mean()
    mae_smooth = np.abs(smooth.occlusion[smooth.hit] - ref).mean()
    assert mae_smooth < mae_raw and mae_smooth < 0.03
    with pytest.raises(ValueError, match="`denoise` filters screen-space AO"):
        render(touching_pair, cam, shape, ao="hits", denoise=1)


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_any_reach_agrees_on_both_backends_and_long_ones_clamp_to_the_image(projection, cl_runtime):
    # a reach of 1e4 or more marched past the image (AO 0; 1e300 overflowed); 1e-6 left the
    # float32 kernel counting its rounding as occlusion (0.19-0.27 against numpy's 0)
    cam = _oblique_camera(projection)
    volume, points, hit = _volume(_wall_scene(), cam, (12, 12, 12))
    points, normals = points[hit], volume.normals.reshape(-1, 4)[hit]
    extent = volume.default_reach()
    runs = {}
    for reach in (1e-6, 1e-3, 0.3, 2.0, extent, 1e4, 1e300, math.inf):
        a, b = (
            screen_space_occlusion(volume, points, normals, samples=16, max_distance=reach, backend=backend)
            for backend in ("numpy", "opencl")
        )
        # float32 against float64 at the voxel and depth thresholds: a few directions of a few points
        assert np.abs(a - b).max() <= 2 / 16 and np.mean(a != b) <= 0.01, reach
        runs[reach] = a
    assert runs[1e-6].max() == 0.0  # nothing within a micron of a flat floor and wall
    for reach in (1e4, 1e300, math.inf):  # clamped to the image's extent
        np.testing.assert_array_equal(runs[reach], runs[extent])
    assert runs[extent].mean() > 0.05  # the wall occludes the floor at its foot


# -- bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(steps=0), ValueError, "`steps` must be >= 1"),
        (dict(samples=0), ValueError, "`samples` must be >= 1"),
        (dict(max_distance=0), ValueError, "`max_distance` must be > 0"),
        (dict(max_distance=math.nan), ValueError, "`max_distance`"),
        (dict(bias=-1), ValueError, "`bias` must be >= 0"),
        (dict(thickness=0.0), ValueError, "`thickness` must be > "),
        (dict(points=np.zeros((2, 3))), ValueError, r"`points` must have shape \(\.\.\., 4\)"),
        (dict(points=np.zeros((2, 4))), ValueError, "same length"),
        (dict(normals=np.zeros((1, 4))), ValueError, "`normals` must be non-zero"),
        (dict(volume="depth"), TypeError, "`volume` must be"),
        (dict(backend="cuda"), ValueError, "`backend` must be one of"),
    ],
)
def test_bad_input(kwargs, error, match):
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.0)
    volume = DepthVolume.from_hits(cam, (2, 2, 2), np.full(8, 4.0), np.tile([0, 0, 0, -1.0], (8, 1)))
    args = dict(volume=volume, points=np.zeros((1, 4)), normals=[[0, 0, 0, -1.0]])
    args.update(kwargs)
    with pytest.raises(error, match=match):
        screen_space_occlusion(args.pop("volume"), args.pop("points"), args.pop("normals"), **args)


def test_bad_depth_volume():
    cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0])
    up = np.tile([0, 0, 0, -1.0], (8, 1))
    with pytest.raises(ValueError, match="`depth` must hold 8 voxels"):
        DepthVolume.from_hits(cam, (2, 2, 2), np.ones(7), up)
    with pytest.raises(ValueError, match="`depth` must be > 0"):
        DepthVolume.from_hits(cam, (2, 2, 2), np.zeros(8), up)
    with pytest.raises(ValueError, match="`normals` must be finite and non-zero"):
        DepthVolume.from_hits(cam, (2, 2, 2), np.ones(8), np.zeros((8, 4)))
    with pytest.raises(TypeError, match="`camera` must be"):
        DepthVolume.from_hits("cam", (2, 2, 2), np.ones(8), up)
    # background voxels need no normal
    vol = DepthVolume.from_hits(cam, (2, 2, 2), np.full(8, np.inf), np.zeros((8, 4)))
    assert not vol.hit.any()


def test_trace_takes_a_pair_and_refuses_other_types_naming_mesh():
    import trimesh

    scene = _wall_scene()
    cam = _oblique_camera()
    want = DepthVolume.trace(scene, cam, (8, 8, 8), backend="numpy")
    got = DepthVolume.trace((scene.vertices, scene.simplices), cam, (8, 8, 8), backend="numpy")
    assert want.hit.sum() > 100
    np.testing.assert_array_equal(got.depth, want.depth)
    np.testing.assert_array_equal(got.normals, want.normals)
    with pytest.raises(TypeError, match="`mesh` must be a SimplexMesh, a trimesh.Trimesh"):
        DepthVolume.trace("scene.npz", cam, (8, 8, 8))
    with pytest.raises(ValueError, match="`mesh` must be a 4D mesh"):  # a trimesh is 3D
        DepthVolume.trace(trimesh.creation.box(), cam, (8, 8, 8))
