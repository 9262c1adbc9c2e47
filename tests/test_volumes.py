"""Tests for ao4d.io.volumes: MetaImage (by hand) and .vti (by VTK) files, read back by VTK's own readers."""

from __future__ import annotations

import numpy as np
import pytest

from ao4d.io import volumes as io

pv = pytest.importorskip("pyvista")
vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402


def _ramp(shape=(7, 5, 3), dtype=np.float32):
    # distinct value per voxel that encodes its index: orientation mistakes cannot cancel out
    i, j, k = np.indices(shape)
    return (100 * i + 10 * j + k).astype(dtype)


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
    path = io.write_vti(tmp_path / "v.vti", {"shade": shade, "object_id": ids}, spacing=0.1, origin=(1, 2, 3))
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
        (lambda p: io.write_mhd(p / "a.mhd", _ramp(), spacing=(1, 0, 1)), ValueError, "`spacing` must be > 0"),
        (lambda p: io.write_mhd(p / "a.mhd", _ramp(), origin=(1, 2)), ValueError, "`origin` must be"),
        (lambda p: io.write_vti(p / "a.vti", {"a": _ramp(), "b": _ramp((2, 2, 2))}), ValueError, "same shape"),
        (lambda p: io.write_vti(p / "a.vti", {}), ValueError, "at least one"),
        (lambda p: io.write_vti(p / "a.mhd", _ramp()), ValueError, "must end in .vti"),
        (lambda p: io.write_volume(p / "a.nii", _ramp()), ValueError, "path extension"),
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


def test_truncated_vti_is_named_unreadable(tmp_path):
    # VTK reads a cut-short file as an empty grid, with no error
    whole = io.write_vti(tmp_path / "a.vti", {"a": _ramp(), "b": _ramp()}).read_bytes()
    for cut in (len(whole) // 2, len(whole) - 60, 200, 0):  # (the last 27 bytes close the XML)
        (tmp_path / "t.vti").write_bytes(whole[:cut])
        with pytest.raises(
            ValueError,
            match=r"`path` '.*t.vti' is unreadable or truncated as VTK "
            r"ImageData \(.vti\)",
        ):
            io.read_vti(tmp_path / "t.vti")


def test_vtk_reader_failure_is_quoted(tmp_path, monkeypatch):
    # pyvista raising (some damage does) is reported with VTK's own words, whitespace folded
    path = io.write_vti(tmp_path / "a.vti", _ramp())

    def broken(_path):
        raise RuntimeError("bad\n   header   line")

    monkeypatch.setattr(io.pyvista_offscreen(), "read", broken)
    with pytest.raises(ValueError, match=r"unreadable or truncated .*bad header line"):
        io.read_vti(path)


def _vtk_read_arrays(path):
    """Every point array of a .vti as VTK's own XML reader sees it, in (nx, ny, nz[, c]) order."""
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    dims = image.GetDimensions()
    out = {}
    for n in range(image.GetPointData().GetNumberOfArrays()):
        flat = vtk_to_numpy(image.GetPointData().GetArray(n))
        out[image.GetPointData().GetArrayName(n)] = flat.reshape(dims + flat.shape[1:], order="F")
    return image, out


@pytest.mark.parametrize("shape", [(7, 5, 3), (128, 64, 32), (256, 128, 24)])
def test_vti_every_dtype_and_block_count_as_vtk_reads_it(tmp_path, shape):
    # (128, 64, 32) float32 is exactly 1 MiB (one full block), (256, 128, 24) several with a
    # partial last one: every branch of the compressed layout against VTK's reader
    rng = np.random.default_rng(7)
    arrays = {
        "shade": rng.random(shape).astype(np.float32),
        'odd "name" <&>': _ramp(shape, np.float64),
        "object_id": rng.integers(-1, 4, size=shape).astype(np.int32),
        "small": rng.integers(-300, 300, size=shape).astype(np.int16),
        "rgba": rng.integers(0, 256, size=shape + (4,)).astype(np.uint8),
    }
    path = io.write_vti(tmp_path / "v.vti", arrays, spacing=(0.5, 0.25, 2.0), origin=(-1, 0, 3.5))
    image, seen = _vtk_read_arrays(path)
    assert image.GetDimensions() == shape
    np.testing.assert_allclose(image.GetSpacing(), (0.5, 0.25, 2.0))
    np.testing.assert_allclose(image.GetOrigin(), (-1, 0, 3.5))
    assert image.GetPointData().GetScalars().GetName() == "shade"  # the first array is active
    assert list(seen) == list(arrays)
    for name, arr in arrays.items():
        assert seen[name].dtype == arr.dtype, name
        np.testing.assert_array_equal(seen[name], arr, err_msg=name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.vti"]


def test_vti_is_compressed_in_one_fast_pass(tmp_path):
    # a render's background is mostly constant: the file must be far smaller than the arrays
    data = np.zeros((64, 64, 64), np.float32)
    data[20:40, 20:40, 20:40] = 1.0
    path = io.write_vti(tmp_path / "v.vti", data)
    assert path.stat().st_size < data.nbytes / 20


def test_mhd_non_ascii_name_is_refused_before_any_file_is_written(tmp_path):
    old_raw = tmp_path / "keep_é.raw"
    old_raw.write_bytes(b"old data")
    with pytest.raises(ValueError, match="ASCII"):
        io.write_mhd(tmp_path / "keep_é.mhd", _ramp())
    assert old_raw.read_bytes() == b"old data"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep_é.raw"]
    with pytest.raises(ValueError, match="`--out`.*ASCII"):
        io.check_mhd_path(tmp_path / "keep_é.mhd", "--out")


def test_mhd_header_failure_puts_the_old_raw_back(tmp_path, monkeypatch):
    old = io.write_mhd(tmp_path / "v.mhd", _ramp())
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    real = io.atomic_open

    def failing_header(path, mode="wb", **kwargs):
        if str(path).endswith(".mhd"):
            raise OSError(28, "No space left on device")
        return real(path, mode, **kwargs)

    monkeypatch.setattr(io, "atomic_open", failing_header)
    with pytest.raises(OSError, match="No space"):
        io.write_mhd(old, _ramp() + 1)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_attribute_quoting_equals_the_standard_librarys():
    """volumes writes XML attributes with its own copy of xml.sax.saxutils.quoteattr (that
    module's imports cost a first extraction 40 ms): the same text for any string."""
    from xml.sax.saxutils import quoteattr

    from hypothesis import given
    from hypothesis import strategies as st

    @given(st.text(alphabet=st.sampled_from("ab&<>\"'\n\r\t ü€"), max_size=12) | st.text(max_size=12))
    def same(text):
        assert io._quoteattr(text) == quoteattr(text)

    same()
