"""ao4d.io: every format on files written here (values, spacing, origin) and every bad file."""

from __future__ import annotations

import gzip
import pickle
import shutil
import warnings

import numpy as np
import pytest

import ao4d
from ao4d.io.frames import natural_key
from ao4d.io.grids import read_grid
from ao4d.io.sources import ObliqueAffineWarning

nib = pytest.importorskip("nibabel", reason="nibabel is a dependency of ao4d")
h5py = pytest.importorskip("h5py", reason="h5py is a dependency of ao4d")
zarr = pytest.importorskip("zarr", reason="zarr is a dependency of ao4d")
da = pytest.importorskip("dask.array", reason="dask is a dependency of ao4d")


@pytest.fixture
def grid4():
    """A 4D grid with distinct values everywhere (so any axis mix-up or flip shows)."""
    rng = np.random.default_rng(0)
    return rng.standard_normal((5, 6, 7, 4)).astype(np.float32)


def _values(vol):
    return np.asarray(vol.values.compute() if vol.lazy else vol.values)


def _write_mhd(
    path, values, *, spacing, offset, element="MET_FLOAT", dtype="<f4", local=False, compressed=False, extra=""
):
    """A MetaImage written by hand from the format description (x fastest)."""
    payload = np.asarray(values, dtype=dtype).ravel(order="F").tobytes()
    if compressed:
        import zlib

        payload = zlib.compress(payload)
    d = values.ndim
    header = (
        f"ObjectType = Image\nNDims = {d}\nBinaryData = True\n"
        f"BinaryDataByteOrderMSB = {'True' if dtype.startswith('>') else 'False'}\n"
        f"CompressedData = {compressed}\n"
        f"ElementSpacing = {' '.join(map(str, spacing))}\n"
        f"Offset = {' '.join(map(str, offset))}\n{extra}"
        f"DimSize = {' '.join(map(str, values.shape))}\nElementType = {element}\n"
    )
    if local:
        path.write_bytes((header + "ElementDataFile = LOCAL\n").encode() + payload)
    else:
        raw = path.with_suffix(".raw")
        raw.write_bytes(payload)
        path.write_text(header + f"ElementDataFile = {raw.name}\n")
    return path


# ---------------------------------------------------------------------------- .npy


def test_npy_memory_mapped(tmp_path, grid4):
    np.save(tmp_path / "v.npy", grid4)
    vol = read_grid(tmp_path / "v.npy")
    assert isinstance(vol.values, np.memmap) and not vol.lazy
    np.testing.assert_array_equal(vol.values, grid4)
    assert vol.spacing.tolist() == [1.0] * 4 and vol.origin.tolist() == [0.0] * 4
    vol = read_grid(tmp_path / "v.npy", spacing=(0.5, 1, 2, 3), origin=-1)
    assert vol.spacing.tolist() == [0.5, 1, 2, 3] and vol.origin.tolist() == [-1.0] * 4


def test_npy_bad_files(tmp_path, grid4):
    with pytest.raises(FileNotFoundError, match="nope.npy"):
        read_grid(tmp_path / "nope.npy")
    np.save(tmp_path / "v.npy", grid4)
    data = (tmp_path / "v.npy").read_bytes()
    (tmp_path / "cut.npy").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut\.npy.*truncated"):
        read_grid(tmp_path / "cut.npy")
    (tmp_path / "junk.npy").write_bytes(b"not an array")
    with pytest.raises(ValueError, match="junk.npy"):
        read_grid(tmp_path / "junk.npy")
    np.save(tmp_path / "three.npy", grid4[..., 0])
    with pytest.raises(ValueError, match=r"three\.npy.*3D grid.*4D grid is needed"):
        read_grid(tmp_path / "three.npy", ndim=4)
    with pytest.raises(ValueError, match="`spacing` must be > 0"):
        read_grid(tmp_path / "v.npy", spacing=0)
    with pytest.raises(ValueError, match="unknown format '.txt'"):
        (tmp_path / "a.txt").write_text("1 2 3")
        read_grid(tmp_path / "a.txt")


def test_chunks_make_a_file_backed_dask_array(tmp_path, grid4):
    np.save(tmp_path / "v.npy", grid4)
    vol = read_grid(tmp_path / "v.npy", chunks=(2, 3, 7, 3))
    assert vol.lazy and vol.values.chunks[0] == (2, 2, 1)
    # the graph refers to the file by name: its pickle is small, not the array
    assert len(pickle.dumps(dict(vol.values.dask))) < grid4.nbytes / 2
    np.testing.assert_array_equal(_values(vol), grid4)


# ---------------------------------------------------------------------------- NIfTI


def _nifti(path, data, affine, *, dt=None, toffset=None):
    img = nib.Nifti1Image(data, affine)
    if dt is not None:
        img.header.set_zooms(img.header.get_zooms()[:3] + (dt,))
    if toffset is not None:
        img.header["toffset"] = toffset
    nib.save(img, str(path))
    return path


def test_nifti_axis_aligned(tmp_path, grid4):
    affine = np.diag([0.5, 0.75, 1.25, 1.0])
    affine[:3, 3] = [-10.0, 2.5, 30.0]
    for name in ("v.nii", "v.nii.gz"):
        path = _nifti(tmp_path / name, grid4, affine, dt=2.0, toffset=3.0)
        vol = read_grid(path)
        np.testing.assert_array_equal(_values(vol), grid4)
        assert vol.spacing.tolist() == [0.5, 0.75, 1.25, 2.0]
        assert vol.origin.tolist() == [-10.0, 2.5, 30.0, 3.0]
    assert isinstance(read_grid(tmp_path / "v.nii").values, np.memmap)


def test_nifti_flipped_axis_is_in_scanner_coordinates(tmp_path, grid4):
    affine = np.diag([-0.5, 1.0, 2.0, 1.0])  # radiological x: i runs towards -x
    affine[:3, 3] = [4.0, 0.0, -1.0]
    vol = read_grid(_nifti(tmp_path / "f.nii", grid4, affine))
    n = grid4.shape[0]
    np.testing.assert_array_equal(_values(vol), grid4[::-1])
    assert vol.spacing.tolist()[:3] == [0.5, 1.0, 2.0]
    assert vol.origin.tolist()[:3] == [4.0 - 0.5 * (n - 1), 0.0, -1.0]
    # voxel i sits at x = 4 - 0.5 i in the scanner; after the flip, at origin + spacing * (n-1-i)
    i = 1
    assert vol.origin[0] + vol.spacing[0] * (n - 1 - i) == 4.0 - 0.5 * i
    assert "flipped" in " ".join(vol.notes)


def test_nifti_oblique_warns_and_uses_zooms(tmp_path, grid4):
    c, s = np.cos(0.3), np.sin(0.3)
    affine = np.array([[c, -s, 0, 1.0], [s, c, 0, 2.0], [0, 0, 1.5, 3.0], [0, 0, 0, 1]])
    path = _nifti(tmp_path / "o.nii", grid4, affine)
    with pytest.warns(ObliqueAffineWarning, match=r"o\.nii.*oblique"):
        vol = read_grid(path)
    np.testing.assert_allclose(vol.spacing[:3], [1.0, 1.0, 1.5], rtol=1e-6)
    assert vol.origin.tolist()[:3] == [1.0, 2.0, 3.0]
    np.testing.assert_array_equal(_values(vol), grid4)


def test_nifti_scaled_is_lazy_and_scaled(tmp_path):
    data = np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6)
    img = nib.Nifti1Image(data, np.eye(4))
    img.header.set_slope_inter(0.5, -3.0)
    nib.save(img, str(tmp_path / "s.nii"))
    vol = read_grid(tmp_path / "s.nii")
    assert vol.lazy
    np.testing.assert_array_equal(_values(vol), data * 0.5 - 3.0)


def test_nifti_bad_files(tmp_path, grid4):
    path = _nifti(tmp_path / "v.nii", grid4, np.eye(4))
    data = path.read_bytes()
    (tmp_path / "cut.nii").write_bytes(data[: len(data) - 100])
    with pytest.raises(ValueError, match=r"cut\.nii.*truncated"):
        read_grid(tmp_path / "cut.nii")
    gz = gzip.compress(data)
    (tmp_path / "cut.nii.gz").write_bytes(gz[: len(gz) // 2])
    with pytest.raises(ValueError, match=r"cut\.nii\.gz"):
        read_grid(tmp_path / "cut.nii.gz")
    (tmp_path / "junk.nii").write_bytes(b"\0" * 400)
    with pytest.raises(ValueError, match=r"junk\.nii.*not a readable NIfTI"):
        read_grid(tmp_path / "junk.nii")
    with pytest.raises(FileNotFoundError, match="missing.nii.gz"):
        read_grid(tmp_path / "missing.nii.gz")
    _nifti(tmp_path / "three.nii", grid4[..., 0], np.eye(4))
    with pytest.raises(ValueError, match=r"three\.nii.*3D grid.*4D grid is needed"):
        read_grid(tmp_path / "three.nii", ndim=4)


# ---------------------------------------------------------------------------- zarr, HDF5


def test_zarr_lazy_with_attributes(tmp_path, grid4):
    store = tmp_path / "v.zarr"
    arr = zarr.open_array(str(store), mode="w", shape=grid4.shape, chunks=(2, 3, 7, 2), dtype=grid4.dtype)
    arr[...] = grid4
    arr.attrs["spacing"] = [0.25, 0.5, 1.0, 2.0]
    arr.attrs["origin"] = [1.0, 2.0, 3.0, 4.0]
    vol = read_grid(store)
    assert vol.lazy
    np.testing.assert_array_equal(_values(vol), grid4)
    assert vol.spacing.tolist() == [0.25, 0.5, 1.0, 2.0] and vol.origin.tolist() == [1, 2, 3, 4]
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w")
    group.create_array("series/a", shape=grid4.shape, dtype=grid4.dtype)[...] = grid4
    group.create_array("series/b", shape=(3, 3), dtype="f8")
    np.testing.assert_array_equal(_values(read_grid(f"{tmp_path / 'g.zarr'}:/series/a")), grid4)
    assert read_grid(f"{tmp_path / 'g.zarr'}:/series/a").spacing.tolist() == [1.0] * 4
    with pytest.raises(ValueError, match=r"g\.zarr.*has no array '/series/c'"):
        read_grid(f"{tmp_path / 'g.zarr'}:/series/c")
    with pytest.raises(ValueError, match="is a group"):
        read_grid(f"{tmp_path / 'g.zarr'}:/series")
    with pytest.raises(FileNotFoundError, match="none.zarr"):
        read_grid(tmp_path / "none.zarr")


def test_hdf5_lazy_with_attributes(tmp_path, grid4):
    path = tmp_path / "v.h5"
    with h5py.File(path, "w") as fh:
        dset = fh.create_dataset("/scan/values", data=grid4, chunks=(5, 6, 7, 1))
        dset.attrs["spacing"] = [0.5, 0.5, 2.0, 0.1]
        dset.attrs["origin"] = [0.0, -1.0, 5.0, 0.0]
        fh.create_dataset("/scan/other", data=np.zeros(3))
    vol = read_grid(f"{path}:/scan/values")
    assert vol.lazy
    np.testing.assert_array_equal(_values(vol), grid4)
    assert vol.spacing.tolist() == [0.5, 0.5, 2.0, 0.1] and vol.origin.tolist() == [0, -1, 5, 0]
    # picklable: workers open the file by name
    again = pickle.loads(pickle.dumps(vol.values))
    np.testing.assert_array_equal(np.asarray(again[1:3, :, 2].compute()), grid4[1:3, :, 2])
    with pytest.raises(ValueError, match=r"v\.h5.*no dataset '/scan/nope'.*/scan/values"):
        read_grid(f"{path}:/scan/nope")
    with pytest.raises(ValueError, match=r"holds 2 datasets.*name one"):
        read_grid(path)
    with pytest.raises(FileNotFoundError, match="gone.h5"):
        read_grid(f"{tmp_path / 'gone.h5'}:/x")
    data = path.read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[:1000])
    with pytest.raises(ValueError, match=r"cut\.h5"):
        read_grid(f"{tmp_path / 'cut.h5'}:/scan/values")
    with h5py.File(tmp_path / "three.h5", "w") as fh:
        fh["v"] = grid4[..., 0]
    with pytest.raises(ValueError, match=r"three\.h5.*3D grid.*4D grid is needed"):
        read_grid(tmp_path / "three.h5", ndim=4)


# ---------------------------------------------------------------------------- MetaImage


@pytest.mark.parametrize("layout", ["raw", "local", "compressed", "big-endian int16"])
def test_metaimage_4d(tmp_path, grid4, layout):
    values = grid4 if layout != "big-endian int16" else (grid4 * 1000).astype(np.int16)
    kwargs = {
        "raw": {},
        "local": {"local": True},
        "compressed": {"compressed": True},
        "big-endian int16": {"element": "MET_SHORT", "dtype": ">i2"},
    }[layout]
    path = _write_mhd(
        tmp_path / ("v.mha" if layout == "local" else "v.mhd"),
        values,
        spacing=(0.5, 1.5, 2.0, 0.25),
        offset=(-1.0, 0.0, 1.0, 10.0),
        **kwargs,
    )
    vol = read_grid(path)
    np.testing.assert_array_equal(_values(vol), values)
    assert vol.spacing.tolist() == [0.5, 1.5, 2.0, 0.25]
    assert vol.origin.tolist() == [-1.0, 0.0, 1.0, 10.0]
    if layout == "raw":
        assert isinstance(vol.values, np.memmap)


def test_metaimage_3d_matches_vtk(tmp_path):
    # VTK's own MetaImage reader (3D) is the trusted tool for the axis order and geometry
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOImage import vtkMetaImageReader

    values = np.random.default_rng(1).standard_normal((6, 5, 4)).astype(np.float32)
    path = _write_mhd(tmp_path / "v.mhd", values, spacing=(0.5, 1.0, 2.0), offset=(1, 2, 3))
    reader = vtkMetaImageReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    ref = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(image.GetDimensions(), order="F")
    vol = read_grid(path)
    np.testing.assert_array_equal(_values(vol), ref)
    assert vol.spacing.tolist() == list(image.GetSpacing())
    assert vol.origin.tolist() == list(image.GetOrigin())


def test_metaimage_bad_files(tmp_path, grid4):
    path = _write_mhd(tmp_path / "v.mhd", grid4, spacing=(1, 1, 1, 1), offset=(0, 0, 0, 0))
    raw = path.with_suffix(".raw")
    raw.write_bytes(raw.read_bytes()[:-8])
    with pytest.raises(ValueError, match=r"v\.raw' is truncated"):
        read_grid(path)
    raw.unlink()
    with pytest.raises(FileNotFoundError, match=r"v\.mhd.*names the data file 'v\.raw'"):
        read_grid(path)
    (tmp_path / "bad.mhd").write_text("hello world\n")
    with pytest.raises(ValueError, match=r"bad\.mhd.*not a MetaImage"):
        read_grid(tmp_path / "bad.mhd")
    (tmp_path / "type.mhd").write_text(
        "NDims = 4\nDimSize = 2 2 2 2\nElementType = MET_BLOB\nElementDataFile = x.raw\n"
    )
    with pytest.raises(ValueError, match=r"type\.mhd.*ElementType 'MET_BLOB'"):
        read_grid(tmp_path / "type.mhd")
    three = _write_mhd(tmp_path / "three.mhd", grid4[..., 0], spacing=(1, 1, 1), offset=(0, 0, 0))
    with pytest.raises(ValueError, match=r"three\.mhd.*3D grid.*4D grid is needed"):
        read_grid(three, ndim=4)
    rot = _write_mhd(
        tmp_path / "rot.mhd",
        grid4[..., 0],
        spacing=(1, 1, 1),
        offset=(0, 0, 0),
        extra="TransformMatrix = 0 1 0 -1 0 0 0 0 1\n",
    )
    with pytest.warns(ObliqueAffineWarning, match="TransformMatrix"):
        read_grid(rot)


# ---------------------------------------------------------------------------- frame series


def test_natural_sort():
    names = ["f10.vti", "f2.vti", "f1.vti", "F3.vti"]
    assert sorted(names, key=natural_key) == ["f1.vti", "f2.vti", "F3.vti", "f10.vti"]


def _frames(tmp_path, kind, n=11, shape=(4, 5, 3)):
    """Frames frame_0 .. frame_{n-1} whose values encode (x, y, z, frame index)."""
    import pyvista as pv

    grid = np.indices(shape).astype(np.float64)
    base = grid[0] + 10 * grid[1] + 100 * grid[2]
    for k in range(n):
        values = (base + 1000 * k).astype(np.float32)
        path = tmp_path / f"frame_{k}{kind}"
        if kind == ".vti":
            image = pv.ImageData(dimensions=shape, spacing=(0.5, 0.25, 2.0), origin=(1, 2, 3))
            image.point_data["f"] = values.ravel(order="F")
            image.save(path)
        elif kind == ".mhd":
            _write_mhd(path, values, spacing=(0.5, 0.25, 2.0), offset=(1, 2, 3))
        elif kind == ".npy":
            np.save(path, values)
        else:
            affine = np.diag([0.5, 0.25, 2.0, 1.0])
            affine[:3, 3] = [1, 2, 3]
            nib.save(nib.Nifti1Image(values, affine), str(path))
    return base, str(tmp_path / f"frame_*{kind}")


@pytest.mark.parametrize("kind", [".vti", ".mhd", ".npy", ".nii.gz"])
def test_frames_stacked_along_w_in_natural_order(tmp_path, kind):
    base, pattern = _frames(tmp_path, kind)
    vol = read_grid(pattern, spacing=None)
    assert vol.lazy and vol.shape == (4, 5, 3, 11)
    expected = np.stack([base + 1000 * k for k in range(11)], axis=-1)  # frame_10 last
    np.testing.assert_array_equal(_values(vol), expected)
    if kind == ".npy":
        assert vol.spacing.tolist() == [1.0] * 4 and vol.origin.tolist() == [0.0] * 4
    else:
        assert vol.spacing.tolist() == [0.5, 0.25, 2.0, 1.0]
        assert vol.origin.tolist() == [1.0, 2.0, 3.0, 0.0]
    vol = read_grid(pattern, spacing=(1, 1, 1, 0.1), origin=(0, 0, 0, 5))
    assert vol.spacing[3] == 0.1 and vol.origin[3] == 5.0


def test_frames_bad_series(tmp_path):
    _frames(tmp_path, ".npy", n=3)
    np.save(tmp_path / "frame_3.npy", np.zeros((4, 5, 4), np.float32))
    with pytest.raises(ValueError, match=r"different shapes.*frame_0\.npy.*frame_3\.npy"):
        read_grid(str(tmp_path / "frame_*.npy"))
    with pytest.raises(FileNotFoundError, match=r"no files match .*nothing_\*\.npy"):
        read_grid(str(tmp_path / "nothing_*.npy"))
    other = tmp_path / "four"
    other.mkdir()
    np.save(other / "a1.npy", np.zeros((2, 2, 2, 2)))
    np.save(other / "a2.npy", np.zeros((2, 2, 2, 2)))
    with pytest.raises(ValueError, match=r"a1\.npy.*4D.*frames must be 3D"):
        read_grid(str(other / "a*.npy"))
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    np.save(mixed / "m1.npy", np.zeros((2, 2, 2)))
    shutil.copy(mixed / "m1.npy", mixed / "m2.dat")
    with pytest.raises(ValueError, match="different kinds"):
        read_grid(str(mixed / "m*"))


def test_frames_truncated_frame_named_when_read(tmp_path):
    _frames(tmp_path, ".vti", n=3)
    path = tmp_path / "frame_2.vti"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # VTK may print its own complaint too
        with pytest.raises(ValueError, match=r"frame_2\.vti"):
            vol = read_grid(str(tmp_path / "frame_*.vti"))
            _values(vol)


# ---------------------------------------------------------------------------- end to end


def test_extract_from_files_equals_extract_from_array(tmp_path):
    from ao4d import fields

    values = ao4d.sample(fields.spheritorus(0.8, 0.35), 12, (-1.3, 1.3))
    spacing, origin = (0.25, 0.5, 0.25, 0.5), (-1.0, 0.0, 1.0, 2.0)
    ref = ao4d.extract(values, 0.0, spacing=spacing, origin=origin)
    _write_mhd(tmp_path / "v.mhd", values, spacing=spacing, offset=origin, element="MET_DOUBLE", dtype="<f8")
    with h5py.File(tmp_path / "v.h5", "w") as fh:
        fh.create_dataset("d", data=values, chunks=(5, 5, 5, 5)).attrs["spacing"] = spacing
        fh["d"].attrs["origin"] = origin
    for source in (tmp_path / "v.mhd", f"{tmp_path / 'v.h5'}:/d"):
        vol = read_grid(source)
        mesh = ao4d.extract(vol.values, 0.0, spacing=vol.spacing, origin=vol.origin)
        # the same vertices and oriented simplices as sets (a Fortran-ordered MetaImage is read
        # transposed, which numbers the vertices in another order)
        assert _oriented_simplex_set(mesh) == _oriented_simplex_set(ref)


def _oriented_simplex_set(mesh):
    """Each simplex as (its sorted vertex coordinates, the parity of the sorting permutation):
    equal for two simplices with the same vertices and the same orientation."""
    out = set()
    for simplex in mesh.vertices[mesh.simplices]:
        rows = [tuple(p) for p in simplex]
        order = sorted(range(len(rows)), key=rows.__getitem__)
        parity = sum(order[a] > order[b] for a in range(len(order)) for b in range(a + 1, len(order)))
        out.add((tuple(rows[k] for k in order), parity % 2))
    return out


def test_cli_extract_input_formats(tmp_path, capsys):
    from ao4d import fields
    from ao4d.cli import main

    values = ao4d.sample(fields.hypersphere(0.9), 10, (-1.2, 1.2)).astype(np.float32)
    with h5py.File(tmp_path / "v.h5", "w") as fh:
        fh.create_dataset("/a/b", data=values).attrs["spacing"] = [0.5, 0.5, 0.5, 0.5]
    out = tmp_path / "m.npz"
    assert main(["extract", "--input", f"{tmp_path / 'v.h5'}:/a/b", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "=> OK" in text and "spacing" in text
    ref = ao4d.extract(values, 0.0, spacing=0.5)
    np.testing.assert_array_equal(ao4d.SimplexMesh.load(out).vertices, ref.vertices)
    # --spacing overrides the file
    assert main(["extract", "--input", f"{tmp_path / 'v.h5'}:/a/b", "--spacing", "2", "--out", str(out)]) == 0
    np.testing.assert_array_equal(ao4d.SimplexMesh.load(out).vertices, ao4d.extract(values, 0.0, spacing=2.0).vertices)
    # a glob of frames
    for k in range(values.shape[3]):
        np.save(tmp_path / f"t{k}.npy", values[..., k])
    assert main(["extract", "--input", str(tmp_path / "t*.npy"), "--out", str(out)]) == 0
    np.testing.assert_array_equal(ao4d.SimplexMesh.load(out).vertices, ao4d.extract(values, 0.0).vertices)
    capsys.readouterr()
    assert main(["extract", "--input", f"{tmp_path / 'v.h5'}:/a/c", "--out", str(out)]) == 2
    assert "no dataset '/a/c'" in capsys.readouterr().err
    assert main(["extract", "--input", str(tmp_path / "t0.npy"), "--dim", "4", "--out", str(tmp_path / "x.npz")]) == 2
    assert "4D grid is needed" in capsys.readouterr().err


# ---------------------------------------------------------------------------- units, affine


def _nifti_4d(path, values, *, zooms=(2.0, 2.0, 2.2, 2000.0), units=("mm", "msec"), affine=None, toffset=0.0):
    img = nib.Nifti1Image(values, np.diag([*zooms[:3], 1.0]) if affine is None else affine)
    img.header.set_zooms(zooms)
    img.header.set_xyzt_units(*units)
    img.header["toffset"] = toffset
    nib.save(img, path)
    return path


def test_nifti_time_axis_is_not_taken_as_a_length(tmp_path, grid4):
    path = _nifti_4d(tmp_path / "t.nii", grid4, toffset=500.0)
    vol = read_grid(path)
    assert vol.units == ("mm", "mm", "mm", "ms")
    mean_step = np.mean([2.0, 2.0, np.float32(2.2)])
    assert vol.spacing[3] == pytest.approx(mean_step)  # one frame = one mean x/y/z step
    assert vol.origin[3] == pytest.approx(500.0 / 2000.0 * mean_step)
    assert vol.w_scale == pytest.approx(mean_step / 2000.0)
    assert any("not taken as a length" in n and "2000 ms" in n for n in vol.notes)
    vol = read_grid(path, w_scale=0.001)  # 1 µm per ms
    assert vol.spacing.tolist() == pytest.approx([2.0, 2.0, 2.2, 2.0])
    assert vol.origin[3] == pytest.approx(0.5) and vol.w_scale == 0.001
    vol = read_grid(path, spacing=(None, None, None, 0.5))  # per axis: w only
    assert vol.spacing.tolist() == pytest.approx([2.0, 2.0, 2.2, 0.5])
    assert vol.w_scale == pytest.approx(0.5 / 2000.0)
    vol = read_grid(path, spacing=(1, 1, 1, 1))
    assert vol.spacing.tolist() == [1.0] * 4
    # no time unit in the header: pixdim[4] as before
    vol = read_grid(_nifti_4d(tmp_path / "u.nii", grid4, units=("unknown", "unknown")))
    assert vol.spacing[3] == 2000.0 and vol.w_scale is None
    with pytest.raises(ValueError, match="`w_scale` must be > 0"):
        read_grid(path, w_scale=0.0)
    nib.save(nib.Nifti1Image(grid4[..., 0], np.eye(4)), tmp_path / "3d.nii")
    with pytest.raises(ValueError, match="`w_scale` scales a time axis"):
        read_grid(tmp_path / "3d.nii", w_scale=1.0)


def test_cli_records_and_prints_the_w_scale(tmp_path, capsys):
    from ao4d.cli import main
    from ao4d.io.mesh_files import read_field_data

    x = np.linspace(-1, 1, 7)
    r = np.sqrt(sum(g * g for g in np.meshgrid(x, x, x, x, indexing="ij")))
    path = _nifti_4d(tmp_path / "t.nii", (r * 100).astype(np.int16))
    out = tmp_path / "m.npz"
    assert main(["extract", "--input", str(path), "--level", "70", "--w-scale", "0.001", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "w scale: 0.001 length units per ms" in text and "=> OK" in text
    info = read_field_data(out)
    assert float(info["w_scale"]) == 0.001 and info["units"].tolist() == ["mm", "mm", "mm", "ms"]
    assert info["spacing"].tolist() == pytest.approx([2.0, 2.0, 2.2, 2.0])
    mesh = ao4d.SimplexMesh.load(out)
    assert mesh.bounds[1][3] - mesh.bounds[0][3] < 6 * 2.0 + 1e-9  # w spans at most 6 frames of 2
    assert (
        main(
            [
                "extract",
                "--input",
                str(path),
                "--level",
                "70",
                "--spacing",
                "file",
                "file",
                "file",
                "0.25",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert read_field_data(out)["spacing"].tolist() == pytest.approx([2.0, 2.0, 2.2, 0.25])


@pytest.mark.parametrize("flip", (False, True))
def test_nifti_affine_true_places_vertices_in_scanner_coordinates(tmp_path, flip):
    rng = np.random.default_rng(2301)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    if (np.linalg.det(q) < 0) != flip:
        q[:, 0] *= -1
    affine = np.eye(4)
    affine[:3, :3], affine[:3, 3] = q @ np.diag([2.0, 1.5, 1.0]), [-90.0, 120.0, 30.0]
    x = np.linspace(-1, 1, 9)
    r = np.sqrt(sum(g * g for g in np.meshgrid(x, x, x, indexing="ij")))
    nib.save(nib.Nifti1Image(r.astype(np.float32), affine), tmp_path / "o.nii")
    with pytest.warns(ObliqueAffineWarning, match="keep_affine=True"):
        read_grid(tmp_path / "o.nii")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # keep_affine=True: no oblique warning
        vol = read_grid(tmp_path / "o.nii", keep_affine=True)
    np.testing.assert_allclose(vol.affine, affine, rtol=0, atol=1e-6)  # float32 in the header
    mesh = ao4d.extract(vol.values, 0.8, affine=vol.affine)
    index = ao4d.extract(np.asarray(vol.values), 0.8)
    report = mesh.check()
    assert report.ok, report  # closed and outward even when det < 0
    assert mesh.volume == pytest.approx(abs(np.linalg.det(vol.affine[:3, :3])) * index.volume, rel=1e-9)
    np.testing.assert_allclose(
        mesh.vertices, index.vertices @ vol.affine[:3, :3].T + vol.affine[:3, 3], rtol=0, atol=1e-9
    )
    # a vertex sits where nibabel's own affine puts its voxel coordinates
    np.testing.assert_allclose(mesh.vertices[:5], nib.affines.apply_affine(vol.affine, index.vertices[:5]), atol=1e-9)


def test_other_formats_give_a_diagonal_affine_with_affine_true(tmp_path, grid4):
    np.save(tmp_path / "v.npy", grid4)
    vol = read_grid(tmp_path / "v.npy", spacing=(0.5, 1, 2, 3), origin=(1, 2, 3, 4), keep_affine=True)
    expect = np.eye(5)
    expect[:4, :4], expect[:4, 4] = np.diag([0.5, 1, 2, 3]), [1, 2, 3, 4]
    np.testing.assert_array_equal(vol.affine, expect)
    assert read_grid(tmp_path / "v.npy").affine is None


def test_keep_affine_is_a_bool_and_the_removed_affine_keyword_is_refused(tmp_path, grid4):
    # `affine` is the matrix in ao4d.extract; read_grid's bool is `keep_affine` (no alias kept)
    np.save(tmp_path / "v.npy", grid4)
    with pytest.raises(TypeError, match="affine"):
        read_grid(tmp_path / "v.npy", spacing=0.5, affine=True)
    with pytest.raises(TypeError, match="`keep_affine`"):
        read_grid(tmp_path / "v.npy", keep_affine="yes")


def test_read_grid_ndim_must_be_ints(tmp_path, grid4):
    np.save(tmp_path / "v.npy", grid4)
    for bad in ("4", 4.0, (3, "4"), (), True):
        with pytest.raises(TypeError, match="`ndim` must be an int or a tuple of ints"):
            read_grid(tmp_path / "v.npy", ndim=bad)
    assert read_grid(tmp_path / "v.npy", ndim=(3, 4)).ndim == 4


# ---------------------------------------------------------------------------- review, sweep


def test_nifti_chunks_keep_array_data_out_of_the_graph(tmp_path):
    values = np.random.default_rng(2302).standard_normal((24, 20, 16, 4)).astype(np.float32)
    for name, affine in (("a.nii", np.eye(4)), ("flipped.nii", np.diag([-1.0, 1.0, -2.0, 1.0]))):
        nib.save(nib.Nifti1Image(values, affine), tmp_path / name)
        vol = read_grid(tmp_path / name, chunks=12)
        graph = pickle.dumps(dict(vol.values.__dask_graph__()))
        assert len(graph) < 0.05 * values.nbytes  # names and offsets only, never the volume
        np.testing.assert_array_equal(vol.values.compute(), np.asarray(read_grid(tmp_path / name).values))


def test_a_glob_of_compressed_mhd_frames_is_not_decompressed_to_scan_headers(tmp_path, grid4, monkeypatch):
    import zlib

    from ao4d.io import metaimage

    for k in range(grid4.shape[3]):
        _write_mhd(tmp_path / f"f{k}.mhd", grid4[..., k], spacing=(1, 1, 1), offset=(0, 0, 0), compressed=True)
    calls = []
    real = zlib.decompress
    monkeypatch.setattr(metaimage.zlib, "decompress", lambda *a: calls.append(1) or real(*a))
    vol = read_grid(tmp_path / "f*.mhd")
    assert calls == []  # the header scan reads no data
    np.testing.assert_array_equal(vol.values.compute(), grid4)
    assert len(calls) == grid4.shape[3]  # each frame once, in its task


def test_mhd_bad_headers_name_the_problem(tmp_path, grid4):
    frame = grid4[..., 0]
    good = _write_mhd(tmp_path / "g.mhd", frame, spacing=(1, 1, 1), offset=(0, 0, 0))
    text = good.read_text()
    (tmp_path / "neg.mhd").write_text(text.replace("DimSize = 5 6 7", "DimSize = 5 -6 7"))
    with pytest.raises(ValueError, match=r"DimSize = 5 -6 7 must be positive integers"):
        read_grid(tmp_path / "neg.mhd")
    (tmp_path / "hs.mhd").write_text(text.replace("ObjectType = Image", "ObjectType = Image\nHeaderSize = abc"))
    with pytest.raises(ValueError, match=r"HeaderSize = 'abc' is not an integer"):
        read_grid(tmp_path / "hs.mhd")
    (tmp_path / "folder.raw").mkdir()
    (tmp_path / "folder.mhd").write_text(text.replace("ElementDataFile = g.raw", "ElementDataFile = folder.raw"))
    with pytest.raises(ValueError, match="names the data file 'folder.raw', which is a folder"):
        read_grid(tmp_path / "folder.mhd")
    shutil.copy(tmp_path / "g.raw", tmp_path / "données_é.raw")
    (tmp_path / "utf8.mhd").write_bytes(
        text.replace("ElementDataFile = g.raw", "ElementDataFile = données_é.raw").encode("utf-8")
    )
    np.testing.assert_array_equal(np.asarray(read_grid(tmp_path / "utf8.mhd").values), frame)


def test_w_scale_or_spacing_whose_products_leave_float64_is_refused(tmp_path, grid4):
    # --w-scale 1e300 gave a volume of inf and a report of "OK"
    path = _nifti_4d(tmp_path / "t.nii", grid4)
    with pytest.raises(ValueError, match="`w_scale` gives the grid an extent of .* too large"):
        read_grid(path, w_scale=1e300)
    with pytest.raises(ValueError, match="`spacing` .* too small"):
        read_grid(path, spacing=(None, None, None, 1e-300))


def test_affine_true_with_a_given_spacing_keeps_the_oblique_rotation(tmp_path, grid4):
    # spacing= (CLI: --spacing file file file 0.5) replaced the file's oblique affine by a
    # diagonal one while the notes still said "vertices placed by the file's affine"
    rng = np.random.default_rng(3600)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    affine = np.eye(4)
    affine[:3, :3], affine[:3, 3] = q @ np.diag([2.0, 1.5, 1.0]), [-90.0, 120.0, 30.0]
    path = _nifti_4d(tmp_path / "o.nii", grid4, zooms=(2.0, 1.5, 1.0, 3.0), units=("mm", "unknown"), affine=affine)
    whole = read_grid(path, keep_affine=True)
    np.testing.assert_allclose(whole.affine[:3, :3], affine[:3, :3], atol=1e-6)
    w_only = read_grid(path, keep_affine=True, spacing=(None, None, None, 0.5))
    np.testing.assert_allclose(w_only.affine[:3], whole.affine[:3], atol=0)  # rotation kept
    assert w_only.affine[3, 3] == 0.5 and w_only.affine[3, 4] == whole.affine[3, 4]
    assert any("vertices placed by the file's affine" in n for n in w_only.notes)
    assert any("axes w take the given spacing" in n for n in w_only.notes)
    every = read_grid(path, keep_affine=True, spacing=0.25, origin=(1, 2, 3, 4))
    np.testing.assert_allclose(
        every.affine[:4, :4], whole.affine[:4, :4] / np.linalg.norm(whole.affine[:4, :4], axis=0) * 0.25, atol=1e-12
    )
    np.testing.assert_array_equal(every.affine[:4, 4], [1, 2, 3, 4])
    mesh = ao4d.extract(np.asarray(w_only.values), 0.0, affine=w_only.affine)
    index = ao4d.extract(np.asarray(w_only.values), 0.0)
    np.testing.assert_allclose(
        mesh.vertices, index.vertices @ w_only.affine[:4, :4].T + w_only.affine[:4, 4], atol=1e-9
    )


@pytest.mark.parametrize("spacing", [(1, 1, 1, "x"), (None, None, None, "x"), (1, "y", 1, 1)])
def test_a_bad_spacing_entry_names_the_parameter(tmp_path, grid4, spacing):
    np.save(tmp_path / "v.npy", grid4)
    with pytest.raises(TypeError, match="`spacing` must be"):
        read_grid(tmp_path / "v.npy", spacing=spacing)
