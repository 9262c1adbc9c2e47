"""ao4d.data: the sample files exist, are made deterministically, and work as documented."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ao4d
from ao4d import data

NAMES = tuple(data.SAMPLES)


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """A fresh, empty sample cache for one test."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("AO4D_DATA_DIR", str(folder))
    return folder


@pytest.mark.parametrize("name", NAMES)
def test_sample_is_made_once_in_the_cache_folder_and_same_bytes_in_a_fresh_one(name, cache, tmp_path, monkeypatch):
    path = data.SAMPLES[name]()
    assert path.is_file() and cache in path.parents
    first = path.read_bytes()
    stamp = path.stat().st_mtime_ns
    assert data.SAMPLES[name]() == path and path.stat().st_mtime_ns == stamp  # read back, not remade
    path.unlink()
    assert data.SAMPLES[name]().read_bytes() == first  # remade: the same bytes
    monkeypatch.setenv("AO4D_DATA_DIR", str(tmp_path / "other"))
    other = data.SAMPLES[name]()
    assert other != path and other.read_bytes() == first


def test_cache_key_follows_the_version(cache, monkeypatch):
    path = data.grid_4d()
    monkeypatch.setattr(ao4d, "__version__", "9.9.9")
    again = data.grid_4d()
    assert again != path and "9.9.9" in again.parent.name and again.read_bytes() == path.read_bytes()


def test_cache_dir_default_is_xdg_cache_home(monkeypatch, tmp_path):
    monkeypatch.delenv("AO4D_DATA_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert data.cache_dir() == tmp_path / "ao4d"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/path")  # ignored, as the XDG spec says
    assert data.cache_dir() == Path.home() / ".cache" / "ao4d"


def test_unwritable_data_dir_is_a_clear_error(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("AO4D_DATA_DIR", str(blocker / "cache"))  # even root cannot write under a file
    with pytest.raises(OSError, match=r"cannot write sample 'grid_4d' into the ao4d data cache \(AO4D_DATA_DIR="):
        data.grid_4d()


def test_unwritable_default_cache_falls_back_to_the_temporary_folder(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    monkeypatch.delenv("AO4D_DATA_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    monkeypatch.setattr(data.tempfile, "tempdir", str(tmp_path / "tmp"))
    path = data.grid_4d()
    assert path.is_file() and (tmp_path / "tmp") in path.parents


def test_a_file_in_a_cache_that_cannot_be_written_is_read(cache, monkeypatch):
    path = data.grid_4d()

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("ao4d._atomic._new_temp", refuse)
    assert data.grid_4d() == path


def test_scan_4d_header_units_affine_and_the_readme_extraction(cache):
    import nibabel as nib

    image = nib.load(data.scan_4d())
    assert image.shape == (32, 32, 32, 16) and image.get_data_dtype() == np.int16
    assert image.header.get_xyzt_units() == ("mm", "sec")
    assert np.allclose(image.header.get_zooms(), (1.5, 1.5, 1.5, 0.1))
    affine = np.diag([1.5, 1.5, 1.5, 1.0])
    affine[:3, 3] = (-24, -30, -12)
    assert np.array_equal(image.affine, affine)
    grid = ao4d.read_grid(data.scan_4d())
    assert grid.units == ("mm", "mm", "mm", "s")
    assert np.allclose(grid.spacing, 1.5) and np.allclose(grid.origin, (-24, -30, -12, 0))
    values = np.asarray(grid.values)
    assert values.min() < 100 and values.max() > 900  # tissue ~40 HU, blob ~1000 HU
    mesh = ao4d.extract(grid.values, 300, spacing=grid.spacing, origin=grid.origin, inside="above", closed=True)
    report = mesh.check()
    assert report.closed and mesh.n_simplices > 10_000


def test_grid_4d_is_the_documented_spheritorus(cache):
    values = np.load(data.grid_4d())
    assert values.shape == (24, 24, 24, 24) and values.dtype == np.float32
    expected = ao4d.sample(ao4d.fields.spheritorus(1.0, 0.4), 24, (-1.5, 1.5)).astype(np.float32)
    assert np.array_equal(values, expected)
    assert ao4d.extract(values, spacing=3 / 23, origin=-1.5).check().closed


def test_scene_is_the_demo_scene_with_ao_and_object_ids(cache):
    mesh = ao4d.SimplexMesh.load(data.scene())
    assert mesh.dim == 4 and mesh.check().closed
    assert mesh.n_vertices == 31_274 and mesh.n_simplices == 184_684
    assert sorted(np.unique(mesh.cell_data["object_id"])) == [0, 1, 2, 3]
    ao = mesh.point_data["ao"]
    assert ao.shape == (mesh.n_vertices,) and 0 <= ao.min() and ao.max() <= 1 and ao.max() > 0.5


def test_surface_3d_is_closed_outward_and_lifts(cache):
    surface = ao4d.lift.load_surface(data.surface_3d())
    assert surface.is_watertight and surface.volume > 0 and len(surface.faces) == 1280
    assert ao4d.lift.prism(surface, 0.5).check().closed


def test_command_line_prints_the_path(cache):
    env = dict(os.environ, AO4D_DATA_DIR=str(cache))
    out = subprocess.run(
        [sys.executable, "-m", "ao4d.data", "grid_4d"], capture_output=True, text=True, env=env, check=True
    ).stdout
    assert Path(out.strip()) == data.grid_4d()
    bad = subprocess.run([sys.executable, "-m", "ao4d.data", "nope"], capture_output=True, text=True, env=env)
    assert bad.returncode == 2 and "unknown sample 'nope'" in bad.stderr


def test_data_is_a_lazy_module_of_the_package():
    assert ao4d.data is data and "data" not in ao4d.__all__
