"""Byte-reproducible .npz archives (used by lut/, SimplexMesh.save and datasets_gen)."""

from __future__ import annotations

import time

import numpy as np
import pytest

import ao4d
from ao4d._npz import write_npz


@pytest.mark.parametrize("compress", [True, False])
def test_same_arrays_same_bytes_and_np_load_reads_them(tmp_path, compress):
    rng = np.random.default_rng(3)
    arrays = {"a": rng.normal(size=(50, 4)), "scalar": np.array(7), "i": np.arange(5, dtype=np.int8)}
    write_npz(tmp_path / "x.npz", arrays, compress=compress)
    time.sleep(1.1)  # np.savez would stamp a different time now
    write_npz(tmp_path / "y.npz", arrays, compress=compress)
    assert (tmp_path / "x.npz").read_bytes() == (tmp_path / "y.npz").read_bytes()
    with np.load(tmp_path / "x.npz") as data:
        assert data["scalar"].shape == () and int(data["scalar"]) == 7
        np.testing.assert_array_equal(data["a"], arrays["a"])
        assert data["i"].dtype == np.int8


def test_object_arrays_refused(tmp_path):
    with pytest.raises(TypeError, match="dtype object"):
        write_npz(tmp_path / "z.npz", {"o": np.array([None])})
    assert not (tmp_path / "z.npz").exists()


def test_mesh_save_is_reproducible(tmp_path):
    mesh = ao4d.extract(ao4d.sample(ao4d.fields.hypersphere(1.0), 8, (-1.2, 1.2)))
    mesh.point_data["ao"] = np.linspace(0, 1, mesh.n_vertices)
    mesh.save(tmp_path / "a.npz")
    time.sleep(1.1)
    mesh.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
