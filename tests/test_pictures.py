"""Tests for ao4d.io.pictures: montages, volume renderings (pyvista and numpy), slice pictures, colours."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _shapes import graded_icosphere

from ao4d.io import pictures

pv = pytest.importorskip("pyvista")


def _ramp(shape=(7, 5, 3), dtype=np.float32):
    i, j, k = np.indices(shape)
    return (100 * i + 10 * j + k).astype(dtype)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda p: pictures.save_montage(p / "a.jpg", _ramp()), ValueError, "must end in .png"),
        (lambda p: pictures.save_montage(p / "a.png", _ramp(), n_slices=0), ValueError, "n_slices"),
        (lambda p: pictures.save_volume_png(p / "a.png", _ramp(), backend="ospray"), ValueError, "backend"),
        (lambda p: pictures.composite(_ramp(), opacity=0), ValueError, "opacity"),
    ],
)
def test_bad_inputs(tmp_path, call, error, match):
    with pytest.raises(error, match=match):
        call(tmp_path)


def _spy_backends(monkeypatch) -> list[str]:
    """Record which volume-rendering backend draws each picture."""
    used: list[str] = []
    for name, attr in (
        ("pyvista", "_volume_png_pyvista"),
        ("numpy", "_volume_png_numpy"),
        ("voxels", "_voxel_picture"),
        ("surface", "_surface_picture"),
    ):
        real = getattr(pictures, attr)

        def spy(*args, _real=real, _name=name, **kwargs):
            result = _real(*args, **kwargs)
            used.append(_name)
            return result

        monkeypatch.setattr(pictures, attr, spy)
    return used


def _png_pixels(path):
    import matplotlib.image

    return matplotlib.image.imread(path)


def _assert_not_blank(path):
    img = _png_pixels(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    # a picture with content varies; a blank canvas has (near) zero variance
    assert img[..., :3].std() > 0.05


def test_composite_matches_closed_form():
    # n identical layers of opacity a: accumulated alpha is 1 - (1 - a)^n, colour c * alpha
    n, a = 6, 0.3
    data = np.full((2, 3, n), 0.5)
    rgba = pictures.composite(data, cmap="gray", vmin=0.0, vmax=1.0, opacity=a)
    assert rgba.shape == (2, 3, 4)
    np.testing.assert_allclose(rgba[..., 3], 1 - (1 - a) ** n)
    grey = np.array(__import__("matplotlib").colormaps["gray"](0.5)[:3])
    np.testing.assert_allclose(rgba[..., :3], np.broadcast_to(grey * (1 - (1 - a) ** n), (2, 3, 3)))
    # background voxels are transparent
    empty = pictures.composite(data, background=np.ones_like(data, bool), opacity=a)
    np.testing.assert_array_equal(empty, 0.0)


def test_composite_front_layer_dominates():
    # an opaque front voxel hides everything behind it (front-to-back = index 0 first)
    data = np.zeros((1, 1, 3))
    data[0, 0, 0] = 1.0
    rgba = pictures.composite(data, cmap="gray", vmin=0, vmax=1, opacity=1.0)
    np.testing.assert_allclose(rgba[0, 0], [1, 1, 1, 1])


def _ball_volume(n=24):
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    inside = X**2 + Y**2 + Z**2 < 0.7
    return np.where(inside, 0.5 + 0.5 * X, 0.0).astype(np.float32), ~inside


def test_montage_png(tmp_path):
    data, bg = _ball_volume()
    path = pictures.save_montage(
        tmp_path / "m.png", data, background=bg, title="ball", label="shade", n_slices=6, spacing=0.1
    )
    _assert_not_blank(path)


@pytest.mark.parametrize("backend", ["auto", "surface", "voxels", "pyvista", "numpy"])
def test_volume_png(tmp_path, backend, monkeypatch):
    data, bg = _ball_volume()
    used = _spy_backends(monkeypatch)
    path = pictures.save_volume_png(
        tmp_path / "v.png", data, background=bg, title="ball", label="shade", backend=backend, size=(320, 280)
    )
    assert path == tmp_path / "v.png"
    assert used == ["surface" if backend == "auto" else backend]
    _assert_not_blank(tmp_path / "v.png")


def test_ao_colors_dark_means_occluded():
    rgba = pictures.ao_colors([0.0, 1.0, np.nan])
    assert rgba[0, :3].sum() > rgba[1, :3].sum()  # open (0) brighter than occluded (1)
    np.testing.assert_array_equal(rgba[2, :3], [128, 128, 128])


def test_slice_png(tmp_path):
    path = pictures.save_slice_png(
        tmp_path / "s.png", graded_icosphere(), occlusion="ao", title="slice", size=(320, 280)
    )
    _assert_not_blank(path)


def test_pictures_need_no_render_window(tmp_path, monkeypatch):
    # the volume and slice pictures render off-screen, with no VTK render window (1-2 s each)
    def broken(*args, **kwargs):
        raise RuntimeError("no OpenGL context")

    monkeypatch.setattr(pictures, "pyvista_offscreen", broken)
    data, bg = _ball_volume(12)
    _assert_not_blank(pictures.save_volume_png(tmp_path / "v.png", data, background=bg))
    rgba = np.zeros(data.shape + (4,))
    rgba[~bg] = (0.9, 0.2, 0.1, 1.0)
    _assert_not_blank(pictures.save_rgba_volume_png(tmp_path / "c.png", rgba))
    _assert_not_blank(pictures.save_slice_png(tmp_path / "s.png", graded_icosphere(), occlusion="ao"))
    with pytest.raises(RuntimeError, match="no OpenGL"):
        pictures.save_volume_png(tmp_path / "w.png", data, background=bg, backend="pyvista")
    assert not (tmp_path / "w.png").exists()  # nothing half-written


def _ray_pixels(extent, shape):
    """Pixel-centre rays of an orthographic picture: bases (H, W, 3) and the view direction."""
    right, up, forward = pictures._view_basis()
    h, w = shape
    px = extent[0] + (np.arange(w) + 0.5) * (extent[1] - extent[0]) / w
    py = extent[3] - (np.arange(h) + 0.5) * (extent[3] - extent[2]) / h
    return px[None, :, None] * right + py[:, None, None] * up, forward


def test_voxel_view_equals_brute_force_ray_casting():
    # every occupied voxel tested against every pixel's ray: the nearest box entry wins; the
    # candidate pruning (voxels hidden by their three viewer-side neighbours) must lose nothing
    rng = np.random.default_rng(5)
    occupied = rng.random((7, 6, 5)) < 0.45
    spacing, origin = (0.5, 0.3, 0.4), (1.0, -2.0, 0.5)
    voxel, depth, extent = pictures.voxel_view(occupied, spacing=spacing, origin=origin, width=64)
    base, forward = _ray_pixels(extent, voxel.shape)
    ids = np.flatnonzero(occupied)
    centre = np.asarray(origin) + np.asarray(spacing) * np.stack(np.unravel_index(ids, occupied.shape), 1)
    half = np.asarray(spacing) / 2
    rel = centre[None, None] - base[:, :, None]  # (H, W, N, 3)
    t1, t2 = (rel - half) / forward, (rel + half) / forward
    near, far = np.minimum(t1, t2).max(axis=3), np.maximum(t1, t2).min(axis=3)
    near = np.where(near <= far, near, np.inf)
    nearest = near.min(axis=2)
    expected = np.where(np.isfinite(nearest), ids[near.argmin(axis=2)], -1)
    assert (expected >= 0).mean() > 0.3
    agree = voxel == expected
    # a pixel whose ray enters two voxels at the same depth (through a shared face) may show either
    two = np.minimum(np.sort(near, axis=2)[..., :2], 1e300)  # inf: no entry
    tie = (two[..., 1] < 1e300) & (two[..., 1] - two[..., 0] < 1e-9)
    assert (agree | tie).all() and agree.mean() > 0.95
    np.testing.assert_allclose(np.isfinite(depth), expected >= 0)


def test_triangle_view_equals_brute_force_ray_casting():
    rng = np.random.default_rng(9)
    points = rng.random((60, 3)) * 4.0
    faces = rng.integers(0, 60, size=(40, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    face, weights, extent = pictures.triangle_view(points, faces, width=48)
    base, forward = _ray_pixels(extent, face.shape)
    # Moller-Trumbore for every pixel and triangle
    p0, p1, p2 = (points[faces[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    pvec = np.cross(forward, e2)
    det = np.einsum("fd,fd->f", e1, pvec)
    tvec = base[:, :, None] - p0
    u = np.einsum("hwfd,fd->hwf", tvec, pvec) / det
    qvec = np.cross(tvec, e1)
    v = np.einsum("d,hwfd->hwf", forward, qvec) / det
    t = np.einsum("fd,hwfd->hwf", e2, qvec) / det
    inside = (u >= 0) & (v >= 0) & (u + v <= 1)
    t = np.where(inside, t, np.inf)
    expected = np.where(np.isfinite(t.min(axis=2)), t.argmin(axis=2), -1)
    assert (expected >= 0).mean() > 0.2
    # pixels on a shared edge or where two triangles cross at the same depth may differ
    close = np.minimum(np.sort(t, axis=2)[..., :2], 1e300)  # inf: no hit
    unsure = (close[..., 1] < 1e300) & (close[..., 1] - close[..., 0] < 1e-9)
    edge = np.isclose(u, 0, atol=1e-9) | np.isclose(v, 0, atol=1e-9) | np.isclose(u + v, 1, atol=1e-9)
    unsure |= edge.any(axis=2)
    assert ((face == expected) | unsure).all() and (face == expected).mean() > 0.97
    hit = face >= 0
    # the weights reproduce the pixel centre's screen position
    right, up, _ = pictures._view_basis()
    corners = points[faces[face[hit]]]  # (P, 3, 3)
    at = np.einsum("pk,pkd->pd", weights[hit], corners)
    np.testing.assert_allclose(at @ right, base[hit] @ right, atol=1e-9)
    np.testing.assert_allclose(at @ up, base[hit] @ up, atol=1e-9)


def test_montage_tiles_put_each_slice_in_its_panel():
    import matplotlib
    from matplotlib.colors import Normalize

    panels = [np.full((3, 5), float(v)) for v in range(7)]
    cmap = matplotlib.colormaps["gray"]
    tiles, gap = pictures._tile(panels, 3, Normalize(0, 6), cmap)
    assert gap == 1 and tiles.shape == (3 * 3 + 2 * 3 + 3, 3 * 5 + 2, 4)
    for n in range(7):
        r, c = divmod(n, 3)
        y0, x0 = 3 + r * 6, c * 6
        np.testing.assert_allclose(tiles[y0 : y0 + 3, x0 : x0 + 5], np.broadcast_to(np.array(cmap(n / 6)), (3, 5, 4)))
    assert tiles[:3, :, 3].max() == 0 and tiles[3:6, 5, 3].max() == 0  # transparent gaps


def _ball(n: int, radius: float) -> np.ndarray:
    """Voxels (unit spacing, centres at integer indices) whose centres lie within ``radius`` of the middle."""
    c = (n - 1) / 2
    i = np.indices((n, n, n)) - c
    return (i**2).sum(axis=0) <= radius**2


def test_surface_view_draws_a_ball_as_its_round_silhouette():
    # the silhouette of a voxelised ball of radius r (unit voxels) is a disc: its pixel area is
    # pi r^2 / pixel^2 to within the voxelisation's half voxel, and its outline is rounder than the
    # voxels': the boundary pixels of the disc (4-neighbour perimeter) shrink towards 2 pi r
    radius, width = 10.0, 200
    occ = _ball(25, radius)
    colours = np.broadcast_to([0.2, 0.4, 0.6], occ.shape + (3,))
    rgb, shown, extent, lost = pictures.surface_view(occ, colours, width=width)
    voxel, _, voxel_extent = pictures.voxel_view(occ, width=width)
    np.testing.assert_allclose(extent, voxel_extent)
    assert shown.shape == voxel.shape and not lost.any()
    pixel = (extent[1] - extent[0]) / width
    disc = math.pi * (radius / pixel) ** 2
    # the voxel set's own radius lies between r and r + sqrt(3)/2 (cube corners); the blurred
    # surface at 1/2 follows the cubes' faces, so the area is that of a radius within [r, r + 0.6]
    assert disc <= shown.sum() <= math.pi * ((radius + 0.6) / pixel) ** 2

    def perimeter(mask):
        edges = (mask[1:] != mask[:-1]).sum() + (mask[:, 1:] != mask[:, :-1]).sum()
        return edges * pixel

    # a 4-connected outline of a smooth disc measures 4/pi times its circumference (the
    # staircase metric); the cubes' outline is longer, with their corners added
    smooth = perimeter(shown) / (2 * math.pi * radius * 4 / math.pi)
    cubes = perimeter(voxel >= 0) / (2 * math.pi * radius * 4 / math.pi)
    assert 0.97 < smooth < 1.1 and smooth < cubes
    # a uniform colour comes back unchanged (normalised convolution: empty voxels give none)
    np.testing.assert_allclose(rgb[shown], np.broadcast_to([0.2, 0.4, 0.6], (shown.sum(), 3)), atol=1e-5)


def test_surface_view_keeps_sheets_and_save_volume_png_draws_lone_voxels(tmp_path, monkeypatch):
    sheet = np.zeros((12, 12, 12), bool)
    sheet[2:10, 5, 2:10] = True  # one voxel thick: its surface survives the blur
    colours = np.ones(sheet.shape + (3,)) * 0.5
    _, shown, _, lost = pictures.surface_view(sheet, colours, width=60)
    # inside, that is; only its rim (where the blur thins it further) goes to the voxel view
    assert shown.any() and lost.any() and not lost[3:9, 5, 3:9].any()
    lone = np.zeros((12, 12, 12), bool)
    lone[6, 6, 6] = True
    _, shown, _, lost = pictures.surface_view(lone, colours, width=60)
    assert not shown.any() and lost[6, 6, 6] and lost.sum() == 1
    # a line and a sheet of voxels touching at their edges melt in the blur: all of them are
    # handed to the voxel view, so no data vanishes from the picture
    index = np.indices((12, 12, 12))
    for thin in ((index[1] == 6) & (index[2] == 6), index.sum(axis=0) == 17):
        _, shown, _, lost = pictures.surface_view(thin, colours, width=60)
        assert not shown.any() and np.array_equal(lost, thin)
    # the picture still shows it, from the voxel view
    drawn = []
    real = pictures._boxed_picture
    monkeypatch.setattr(
        pictures,
        "_boxed_picture",
        lambda fig, picture, *a, **k: (drawn.append(picture), real(fig, picture, *a, **k))[1],
    )
    pictures.save_volume_png(tmp_path / "lone.png", np.where(lone, 1.0, np.nan), backend="surface", vmin=0, vmax=2)
    assert (drawn[0] < 0.99).any()


def test_blur_and_trilinear_equal_scipy_ndimage():
    # the surface picture's numpy Gaussian and interpolation, against the library they replace
    from scipy import ndimage

    rng = np.random.default_rng(0)
    volume = rng.random((9, 8, 7))
    colours = rng.random((9, 8, 7, 3))
    for sigma in (0.7, 1.3):
        np.testing.assert_allclose(
            pictures._blur(volume, sigma), ndimage.gaussian_filter(volume, sigma, mode="constant"), atol=1e-12
        )
    blurred = pictures._blur(colours, 0.7)
    want = np.stack([ndimage.gaussian_filter(colours[..., k], 0.7, mode="constant") for k in range(3)], axis=-1)
    np.testing.assert_allclose(blurred, want, atol=1e-12)
    points = rng.uniform(0, 6, (40, 3))
    np.testing.assert_allclose(pictures._trilinear(volume, points), ndimage.map_coordinates(volume, points.T, order=1))
