"""Tests for ao4d.pictures: montages, volume renderings (pyvista and numpy), slice pictures, colours."""

from __future__ import annotations

import numpy as np
import pytest

from _shapes import graded_icosphere
from ao4d import pictures

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
    for name in ("pyvista", "numpy"):
        real = getattr(pictures, f"_volume_png_{name}")

        def spy(*args, _real=real, _name=name, **kwargs):
            result = _real(*args, **kwargs)
            used.append(_name)
            return result

        monkeypatch.setattr(pictures, f"_volume_png_{name}", spy)
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
    path = pictures.save_montage(tmp_path / "m.png", data, background=bg, title="ball", label="shade",
                           n_slices=6, spacing=0.1)
    _assert_not_blank(path)


@pytest.mark.parametrize("backend", ["pyvista", "numpy"])
def test_volume_png(tmp_path, backend, monkeypatch):
    data, bg = _ball_volume()
    used = _spy_backends(monkeypatch)
    path = pictures.save_volume_png(tmp_path / "v.png", data, background=bg, title="ball", label="shade",
                                    backend=backend, size=(320, 280))
    assert path == tmp_path / "v.png"
    assert used == [backend]
    _assert_not_blank(tmp_path / "v.png")


def test_ao_colors_dark_means_occluded():
    rgba = pictures.ao_colors([0.0, 1.0, np.nan])
    assert rgba[0, :3].sum() > rgba[1, :3].sum()  # open (0) brighter than occluded (1)
    np.testing.assert_array_equal(rgba[2, :3], [128, 128, 128])


def test_slice_png(tmp_path):
    path = pictures.save_slice_png(tmp_path / "s.png", graded_icosphere(), occlusion="ao", title="slice",
                             size=(320, 280))
    _assert_not_blank(path)


def test_volume_png_falls_back_to_numpy_when_pyvista_fails(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("no OpenGL context")

    monkeypatch.setattr(pictures, "_volume_png_pyvista", broken)
    data, bg = _ball_volume(12)
    used = _spy_backends(monkeypatch)
    assert pictures.save_volume_png(tmp_path / "v.png", data, background=bg) == tmp_path / "v.png"
    assert used == ["numpy"]
    _assert_not_blank(tmp_path / "v.png")
    with pytest.raises(RuntimeError, match="no OpenGL"):
        pictures.save_volume_png(tmp_path / "w.png", data, background=bg, backend="pyvista")
    assert not (tmp_path / "w.png").exists()  # nothing half-written
