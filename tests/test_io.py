"""Volume files (MetaImage by hand, .vti by VTK), read back by VTK's own readers; PNG previews."""

from __future__ import annotations

import numpy as np
import pytest

from ao4d import io

pv = pytest.importorskip("pyvista")
vtk = pytest.importorskip("vtk")
trimesh = pytest.importorskip("trimesh")
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402


def _ramp(shape=(7, 5, 3), dtype=np.float32):
    # distinct value per voxel that encodes its index: orientation mistakes cannot cancel out
    i, j, k = np.indices(shape)
    return (100 * i + 10 * j + k).astype(dtype)


def _png_pixels(path):
    import matplotlib.image

    return matplotlib.image.imread(path)


def _assert_not_blank(path):
    img = _png_pixels(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    # a picture with content varies; a blank canvas has (near) zero variance
    assert img[..., :3].std() > 0.05


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8, np.int16, np.int32, np.uint16])
def test_mhd_round_trip(tmp_path, dtype):
    data = _ramp(dtype=dtype)
    path = io.write_mhd(tmp_path / "v.mhd", data, spacing=(0.5, 0.25, 2.0), origin=(-1, 0, 3.5))
    assert (tmp_path / "v.raw").stat().st_size == data.nbytes
    vol = io.read_mhd(path)
    assert vol.data.dtype == data.dtype and vol.data.shape == data.shape
    np.testing.assert_array_equal(vol.data, data)
    assert vol.spacing == (0.5, 0.25, 2.0) and vol.origin == (-1.0, 0.0, 3.5)
    # no temporary files are left behind by the atomic writes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mhd", "v.raw"]


def test_mhd_bool_is_stored_as_uint8(tmp_path):
    mask = _ramp() > 300
    vol = io.read_mhd(io.write_mhd(tmp_path / "m.mhd", mask))
    assert vol.data.dtype == np.uint8
    np.testing.assert_array_equal(vol.data, mask)


def _vtk_point_value(image, array_index, xyz):
    """Value VTK sees at the world point ``xyz`` (a voxel centre): orientation as ITK/VTK see it."""
    pid = image.FindPoint(*xyz)
    assert np.allclose(image.GetPoint(pid), xyz)
    return vtk_to_numpy(image.GetPointData().GetArray(array_index))[pid]


def test_mhd_orientation_as_vtk_reads_it(tmp_path):
    data = _ramp()
    spacing, origin = np.array([0.5, 0.25, 2.0]), np.array([-1.0, 0.0, 3.5])
    path = io.write_mhd(tmp_path / "v.mhd", data, spacing=spacing, origin=origin)
    reader = vtk.vtkMetaImageReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    assert image.GetDimensions() == data.shape
    np.testing.assert_allclose(image.GetSpacing(), spacing)
    np.testing.assert_allclose(image.GetOrigin(), origin)
    # voxel (i, j, k) of our array sits at origin + spacing * (i, j, k) in VTK's world
    for ijk in [(0, 0, 0), (6, 0, 0), (0, 4, 0), (0, 0, 2), (3, 1, 2), (6, 4, 2)]:
        xyz = origin + spacing * np.array(ijk)
        assert _vtk_point_value(image, 0, xyz) == data[ijk]


def test_vti_round_trip_and_vtk_reader(tmp_path):
    rng = np.random.default_rng(3)
    shade = rng.random((6, 4, 5)).astype(np.float32)
    ids = rng.integers(-1, 3, size=(6, 4, 5)).astype(np.int32)
    path = io.write_vti(tmp_path / "v.vti", {"shade": shade, "object_id": ids},
                        spacing=0.1, origin=(1, 2, 3))
    vol = io.read_vti(path)
    assert vol.name == "shade"
    np.testing.assert_array_equal(vol.data, shade)
    assert vol.spacing == pytest.approx((0.1,) * 3) and vol.origin == (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(io.read_vti(path, array="object_id").data, ids)
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    for ijk in [(5, 0, 0), (0, 3, 0), (0, 0, 4), (2, 1, 3)]:
        xyz = np.array([1.0, 2.0, 3.0]) + 0.1 * np.array(ijk)
        arr = [image.GetPointData().GetArrayName(n) for n in range(2)].index("object_id")
        assert _vtk_point_value(image, arr, xyz) == ids[ijk]


@pytest.mark.parametrize("suffix", [".mhd", ".vti"])
def test_write_read_volume_dispatch(tmp_path, suffix):
    data = _ramp()
    vol = io.read_volume(io.write_volume(tmp_path / f"a{suffix}", data, spacing=2.0))
    np.testing.assert_array_equal(vol.data, data)
    assert vol.spacing == (2.0, 2.0, 2.0)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda p: io.write_mhd(p / "a.raw", _ramp()), ValueError, "`path` must end in .mhd"),
        (lambda p: io.write_mhd(p / "a.mhd", _ramp()[0]), ValueError, "`data` must be a 3D"),
        (lambda p: io.write_mhd(p / "a.mhd", _ramp(dtype=np.int64)), TypeError, "MetaImage type"),
        (lambda p: io.write_mhd(p / "a.mhd", _ramp(), spacing=(1, 0, 1)), ValueError, "`spacing` must be positive"),
        (lambda p: io.write_mhd(p / "a.mhd", _ramp(), origin=(1, 2)), ValueError, "`origin` must be"),
        (lambda p: io.write_vti(p / "a.vti", {"a": _ramp(), "b": _ramp((2, 2, 2))}), ValueError, "same shape"),
        (lambda p: io.write_vti(p / "a.vti", {}), ValueError, "at least one"),
        (lambda p: io.write_vti(p / "a.mhd", _ramp()), ValueError, "must end in .vti"),
        (lambda p: io.write_volume(p / "a.nii", _ramp()), ValueError, "path extension"),
        (lambda p: io.save_montage(p / "a.jpg", _ramp()), ValueError, "must end in .png"),
        (lambda p: io.save_montage(p / "a.png", _ramp(), n_slices=0), ValueError, "n_slices"),
        (lambda p: io.save_volume_png(p / "a.png", _ramp(), backend="ospray"), ValueError, "backend"),
        (lambda p: io.composite(_ramp(), opacity=0), ValueError, "opacity"),
    ],
)
def test_bad_inputs(tmp_path, call, error, match):
    with pytest.raises(error, match=match):
        call(tmp_path)


def test_read_mhd_errors(tmp_path):
    bad = tmp_path / "bad.mhd"
    bad.write_text("NDims = 3\nDimSize = 2 2 2\n")
    with pytest.raises(ValueError, match="missing ElementType"):
        io.read_mhd(bad)
    io.write_mhd(tmp_path / "ok.mhd", _ramp())
    text = (tmp_path / "ok.mhd").read_text()
    (tmp_path / "z.mhd").write_text(text.replace("CompressedData = False", "CompressedData = True"))
    with pytest.raises(ValueError, match="compressed"):
        io.read_mhd(tmp_path / "z.mhd")
    (tmp_path / "short.mhd").write_text(text.replace("DimSize = 7 5 3", "DimSize = 7 5 4"))
    with pytest.raises(ValueError, match="expected 140 values"):
        io.read_mhd(tmp_path / "short.mhd")
    with pytest.raises(ValueError, match="`array` must be one of"):
        io.read_vti(io.write_vti(tmp_path / "a.vti", _ramp()), array="nope")


def test_composite_matches_closed_form():
    # n identical layers of opacity a: accumulated alpha is 1 - (1 - a)^n, colour c * alpha
    n, a = 6, 0.3
    data = np.full((2, 3, n), 0.5)
    rgba = io.composite(data, cmap="gray", vmin=0.0, vmax=1.0, opacity=a)
    assert rgba.shape == (2, 3, 4)
    np.testing.assert_allclose(rgba[..., 3], 1 - (1 - a) ** n)
    grey = np.array(__import__("matplotlib").colormaps["gray"](0.5)[:3])
    np.testing.assert_allclose(rgba[..., :3], np.broadcast_to(grey * (1 - (1 - a) ** n), (2, 3, 3)))
    # background voxels are transparent
    empty = io.composite(data, background=np.ones_like(data, bool), opacity=a)
    np.testing.assert_array_equal(empty, 0.0)


def test_composite_front_layer_dominates():
    # an opaque front voxel hides everything behind it (front-to-back = index 0 first)
    data = np.zeros((1, 1, 3))
    data[0, 0, 0] = 1.0
    rgba = io.composite(data, cmap="gray", vmin=0, vmax=1, opacity=1.0)
    np.testing.assert_allclose(rgba[0, 0], [1, 1, 1, 1])


def _ball_volume(n=24):
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    inside = X**2 + Y**2 + Z**2 < 0.7
    return np.where(inside, 0.5 + 0.5 * X, 0.0).astype(np.float32), ~inside


def test_montage_png(tmp_path):
    data, bg = _ball_volume()
    path = io.save_montage(tmp_path / "m.png", data, background=bg, title="ball", label="shade",
                           n_slices=6, spacing=0.1)
    _assert_not_blank(path)


@pytest.mark.parametrize("backend", ["pyvista", "numpy"])
def test_volume_png(tmp_path, backend):
    data, bg = _ball_volume()
    used = io.save_volume_png(tmp_path / "v.png", data, background=bg, title="ball", label="shade",
                              backend=backend, size=(320, 280))
    assert used == backend
    _assert_not_blank(tmp_path / "v.png")


def _slice_mesh():
    tri = trimesh.creation.icosphere(subdivisions=2)
    tri.vertex_attributes["ao"] = (tri.vertices[:, 0] + 1) / 2  # graded values in [0, 1]
    return tri


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_slice_mesh_colours_round_trip(tmp_path, suffix):
    tri = _slice_mesh()
    path = io.save_slice_mesh(tmp_path / f"s{suffix}", tri, occlusion="ao")
    back = trimesh.load(path, force="mesh", process=False)
    assert len(back.faces) == len(tri.faces)
    want = io.ao_colors(tri.vertex_attributes["ao"])
    got = np.asarray(back.visual.vertex_colors)
    # glb may reorder vertices: compare colour per position
    order_t = np.lexsort(np.round(tri.vertices, 6).T)
    order_b = np.lexsort(np.round(back.vertices, 6).T)
    np.testing.assert_array_equal(got[order_b], want[order_t])


def test_ao_colors_dark_means_occluded():
    rgba = io.ao_colors([0.0, 1.0, np.nan])
    assert rgba[0, :3].sum() > rgba[1, :3].sum()  # open (0) brighter than occluded (1)
    np.testing.assert_array_equal(rgba[2, :3], [128, 128, 128])


def test_slice_png(tmp_path):
    path = io.save_slice_png(tmp_path / "s.png", _slice_mesh(), occlusion="ao", title="slice",
                             size=(320, 280))
    _assert_not_blank(path)


def test_slice_errors(tmp_path):
    tri = _slice_mesh()
    with pytest.raises(ValueError, match="not a vertex attribute"):
        io.save_slice_mesh(tmp_path / "s.ply", tri, occlusion="nope")
    with pytest.raises(ValueError, match="one value per vertex"):
        io.save_slice_mesh(tmp_path / "s.ply", tri, occlusion=np.zeros(3))
    with pytest.raises(ValueError, match="path extension"):
        io.save_slice_mesh(tmp_path / "s.obj", tri)
    with pytest.raises(ValueError, match="no faces"):
        io.save_slice_png(tmp_path / "s.png", trimesh.Trimesh())


def test_volume_png_falls_back_to_numpy_when_pyvista_fails(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("no OpenGL context")

    monkeypatch.setattr(io, "_volume_png_pyvista", broken)
    data, bg = _ball_volume(12)
    assert io.save_volume_png(tmp_path / "v.png", data, background=bg) == "numpy"
    _assert_not_blank(tmp_path / "v.png")
    with pytest.raises(RuntimeError, match="no OpenGL"):
        io.save_volume_png(tmp_path / "w.png", data, background=bg, backend="pyvista")
    assert not (tmp_path / "w.png").exists()  # nothing half-written
