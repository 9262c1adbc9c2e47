"""Block-wise extraction of dask arrays and fields (ao4d.marching.blockwise) against the one-process path.

The block path promises the slab path's mesh array for array (same vertex and simplex order), so
the comparisons here are exact (``np.array_equal``), which implies the weaker claims too (same
vertices, same oriented simplices as sets). Each case also checks closedness and orientation
(positive enclosed volume) on its own.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import ao4d
from ao4d import fields

da = pytest.importorskip("dask.array", reason="dask is a dependency of ao4d (pip install dask[array])")
distributed = pytest.importorskip("distributed", reason="distributed is a dependency of ao4d")


def _noise(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Smooth random field, positive on the border: its level-0 set is closed, many components."""
    v = gaussian_filter(rng.standard_normal(shape), 1.2, mode="wrap")
    v /= np.abs(v).max()
    for axis in range(len(shape)):
        idx = [slice(None)] * len(shape)
        idx[axis] = [0, -1]
        v[tuple(idx)] = 1.0
    return v


def _assert_identical(ref: ao4d.SimplexMesh, got: ao4d.SimplexMesh) -> None:
    assert got.n_vertices == ref.n_vertices and got.n_simplices == ref.n_simplices
    np.testing.assert_array_equal(got.vertices, ref.vertices)
    np.testing.assert_array_equal(got.simplices, ref.simplices)


def _assert_closed_outward(mesh: ao4d.SimplexMesh) -> None:
    report = mesh.check()
    assert report.ok, report
    assert mesh.volume > 0


# odd chunk sizes that align with nothing, per dimension (points per block per axis)
CASES = {
    2: ((29, 23), [(5, 7), (3, 23), ((10, 1, 11, 7), (2, 9, 12))]),
    3: ((17, 15, 19), [(4, 7, 5), (17, 2, 19), ((1, 9, 7), (15,), (6, 6, 7))]),
    4: ((11, 9, 12, 10), [(3, 5, 4, 7), (11, 9, 12, 3), ((5, 1, 5), (2, 7), (12,), (4, 3, 3))]),
}


@pytest.mark.parametrize("method", ["cubes", "simplices"])
@pytest.mark.parametrize("dim", [2, 3, 4])
def test_dask_array_equals_in_memory_threaded(dim, method):
    rng = np.random.default_rng(100 + dim)
    shape, chunkings = CASES[dim]
    values = _noise(rng, shape)
    spacing = rng.uniform(0.5, 2.0, dim)
    origin = rng.uniform(-3.0, 3.0, dim)
    ref = ao4d.extract(values, 0.05, spacing=spacing, origin=origin, method=method)
    assert ref.n_simplices > 50
    _assert_closed_outward(ref)
    for chunks in chunkings:
        got = ao4d.extract(
            da.from_array(values, chunks=chunks), 0.05, spacing=spacing, origin=origin, method=method, progress=False
        )
        _assert_identical(ref, got)


@pytest.mark.parametrize("chunk", [1, 2])
def test_dask_array_reproduces_the_slab_order(chunk):
    # thin slabs (chunk=) in the slab path: vertices on slab-boundary layers are numbered by the
    # slab below; the block path must reproduce that numbering exactly
    values = _noise(np.random.default_rng(7), (10, 9, 8, 11))
    for method in ("cubes", "simplices"):
        ref = ao4d.extract(values, 0.0, method=method, chunk=chunk)
        got = ao4d.extract(da.from_array(values, chunks=(3, 4, 5, 2)), 0.0, method=method, chunk=chunk)
        _assert_identical(ref, got)


def test_dask_dtypes_inside_and_fortran_source():
    rng = np.random.default_rng(3)
    values = (-_noise(rng, (13, 12, 11)) * 1000).astype(np.int16)  # bright blobs, dark border
    ref = ao4d.extract(values, 100, inside="above")
    got = ao4d.extract(da.from_array(values, chunks=(4, 5, 6)), 100, inside="above")
    _assert_identical(ref, got)
    f32 = np.asfortranarray(_noise(rng, (12, 10, 9, 8)).astype(np.float32))
    ref = ao4d.extract(np.ascontiguousarray(f32), 0.1)
    got = ao4d.extract(da.from_array(f32, chunks=5), 0.1)
    _assert_identical(ref, got)


def test_dask_empty_and_flat_fields():
    from ao4d.marching.march import EmptyMeshWarning

    ones = da.ones((6, 7, 8, 5), chunks=3)
    with pytest.warns(EmptyMeshWarning, match="empty"):
        mesh = ao4d.extract(ones, 0.5)
    assert mesh.n_vertices == 0 and mesh.n_simplices == 0 and mesh.dim == 4
    # exactly at the level: vertices where values equal the level, still closed
    values = np.ones((9, 9, 9))
    values[3:6, 3:6, 3:6] = 0.0
    values[4, 4, 4] = -1.0
    ref = ao4d.extract(values, 0.0)
    _assert_identical(ref, ao4d.extract(da.from_array(values, chunks=(2, 5, 4)), 0.0))


@pytest.mark.parametrize("dim", [2, 3, 4])
def test_extract_field_chunks_equals_slab_path(dim):
    field = fields.spheritorus(0.8, 0.35) if dim == 4 else fields.hypersphere(0.9, dim=dim)
    shape = {2: 31, 3: 19, 4: 13}[dim]
    for method in ("cubes", "simplices"):
        ref = ao4d.extract_field(field, shape, (-1.3, 1.3), method=method)
        _assert_closed_outward(ref)
        got = ao4d.extract_field(field, shape, (-1.3, 1.3), method=method, blocks=(5, 4, 7, 3)[:dim])
        _assert_identical(ref, got)


def test_extract_field_chunks_lambda_field():
    # a plain closure (pickled by cloudpickle for distributed workers)
    centre = np.array([0.1, -0.2, 0.05])
    field = lambda p: np.linalg.norm(p - centre, axis=-1) - 0.7  # noqa: E731
    ref = ao4d.extract_field(field, (16, 15, 17), (-1.0, 1.0), chunk=2)
    got = ao4d.extract_field(field, (16, 15, 17), (-1.0, 1.0), chunk=2, blocks=6)
    _assert_identical(ref, got)


def test_field_blocks_name_a_non_finite_field():
    def field(p):
        r = np.linalg.norm(p, axis=-1) - 0.5
        return np.where(p[..., 0] > 0.7, np.nan, r)

    with pytest.raises(ValueError, match=r"`field` returned \d+ non-finite value\(s\).*at point"):
        ao4d.extract_field(field, (12, 12, 12), (-1, 1), blocks=5)


def test_field_array_equals_sample():
    from ao4d.marching.blockwise import field_array

    field = fields.spheritorus(0.8, 0.35)
    x = field_array(field, (9, 8, 7, 10), (-1.3, 1.3), chunks=(4, 3, 7, 4))
    assert x.chunks[0] == (4, 4, 1) and x.dtype == np.float64
    np.testing.assert_array_equal(x.compute(), ao4d.sample(field, (9, 8, 7, 10), (-1.3, 1.3)))


def test_client_never_gathers_the_array(monkeypatch):
    values = _noise(np.random.default_rng(5), (12, 11, 10))
    x = da.from_array(values, chunks=5)
    ref = ao4d.extract(values, 0.0)

    def refuse(*args, **kwargs):
        raise AssertionError("the whole dask array was gathered into the client")

    monkeypatch.setattr(da.Array, "__array__", refuse)
    monkeypatch.setattr(da.Array, "compute", refuse)
    _assert_identical(ref, ao4d.extract(x, 0.0))


def test_dask_bad_input_named():
    with pytest.raises(ValueError, match="`values` must be a 2D, 3D or 4D array"):
        ao4d.extract(da.zeros(5, chunks=2))
    with pytest.raises(ValueError, match="at least 2 points"):
        ao4d.extract(da.zeros((5, 1, 4), chunks=2))
    with pytest.raises(TypeError, match="real numbers"):
        ao4d.extract(da.zeros((5, 4), chunks=2, dtype=complex))
    with pytest.raises(ValueError, match="`spacing`"):
        ao4d.extract(da.zeros((5, 4), chunks=2), spacing=(1, 0))
    with pytest.raises(ValueError, match="`method`"):
        ao4d.extract(da.zeros((5, 4), chunks=2), method="tets")
    with pytest.raises(ValueError, match="`level`"):
        ao4d.extract(da.zeros((5, 4), chunks=2), np.nan)
    x = da.zeros((8, 8), chunks=4)
    with pytest.raises(ValueError, match="unknown chunk sizes"):
        ao4d.extract(x[x[:, 0] > -1])
    nan = np.zeros((9, 9))
    nan[7, 2] = np.nan
    with pytest.raises(ValueError, match="`values` contains 1 non-finite"):
        ao4d.extract(da.from_array(nan, chunks=4))


def test_too_many_blocks_refused_before_work(monkeypatch):
    from ao4d.marching import blockwise

    monkeypatch.setattr(blockwise, "MAX_BLOCKS", 100)
    with pytest.raises(ValueError, match="blocks .*use larger chunks"):
        ao4d.extract(da.zeros((40, 40, 40), chunks=5))
    # the errors name the parameter the caller gave: `blocks` (extract_field), `chunks` (field_array)
    with pytest.raises(ValueError, match="`blocks`"):
        ao4d.extract_field(fields.hypersphere(1.0), 64, (-1, 1), blocks=0)
    with pytest.raises(ValueError, match="`blocks`"):
        ao4d.extract_field(fields.hypersphere(1.0), 64, (-1, 1), blocks=(4, 4))
    with pytest.raises(ValueError, match="`blocks=2`"):
        ao4d.extract_field(fields.hypersphere(1.0), 64, (-1, 1), blocks=2)
    with pytest.raises(ValueError, match="`chunks`"):
        blockwise.field_array(fields.hypersphere(1.0), 64, (-1, 1), chunks=0)


def test_progress_counts_blocks(monkeypatch):
    from ao4d import _progress

    bars = []

    class Recorder:
        def __init__(self, total, desc, **kwargs):
            self.total, self.n, self.unit = total, 0, kwargs.get("unit")
            bars.append(self)

        def update(self, n=1):
            self.n += n

        def close(self):
            pass

    monkeypatch.setattr(_progress, "bar", Recorder)
    values = _noise(np.random.default_rng(9), (10, 10, 10))
    ao4d.extract(da.from_array(values, chunks=4), 0.0, progress=True)
    assert [(b.total, b.n, b.unit) for b in bars] == [(27, 27, "block")]
    ao4d.extract(da.from_array(values, chunks=4), 0.0)  # small grid: no bar by default
    assert len(bars) == 1


# ---------------------------------------------------------------------------- distributed


@pytest.fixture(scope="module")
def cluster_client():
    """One small in-process cluster for the module: 2 workers, 1 thread each."""
    from distributed import Client, LocalCluster

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        yield client


@pytest.mark.parametrize("method", ["cubes", "simplices"])
@pytest.mark.parametrize("dim", [2, 3, 4])
def test_dask_array_equals_in_memory_on_local_cluster(cluster_client, dim, method):
    rng = np.random.default_rng(200 + dim)
    shape, chunkings = CASES[dim]
    values = _noise(rng, shape)
    ref = ao4d.extract(values, -0.05, method=method)
    with distributed.get_task_stream(cluster_client) as stream:
        got = ao4d.extract(da.from_array(values, chunks=chunkings[0]), -0.05, method=method)
    ran = {
        t["worker"]
        for t in stream.data
        if str(t["key"]).startswith("('ao4d-block-") or str(t["key"]).startswith("ao4d-block-")
    }
    # on the workers: their addresses as they answer now (scheduler_info() is a cached copy of
    # the scheduler's identity, refreshed in the background, and was once empty here in CI)
    assert ran and ran <= set(cluster_client.run(lambda: None))
    _assert_identical(ref, got)
    _assert_closed_outward(got)


def test_extract_field_chunks_on_local_cluster(cluster_client):
    field = fields.spheritorus(0.8, 0.35)
    ref = ao4d.extract_field(field, 14, (-1.3, 1.3), method="simplices")
    got = ao4d.extract_field(field, 14, (-1.3, 1.3), method="simplices", blocks=(5, 6, 4, 7))
    _assert_identical(ref, got)


def test_worker_errors_reach_the_client(cluster_client):
    nan = np.zeros((9, 9, 9))
    nan[1, 7, 2] = np.inf
    with pytest.raises(ValueError, match="`values` contains 1 non-finite"):
        ao4d.extract(da.from_array(nan, chunks=4))


def test_process_workers_pickle_the_tasks(tmp_path):
    # separate processes: every task (field closure, block spec, block mesh) crosses pickling
    import os

    from distributed import Client, LocalCluster

    from ao4d import WorkerEnvironmentWarning, worker_environment

    values = _noise(np.random.default_rng(11), (11, 10, 9, 8))
    np.save(tmp_path / "v.npy", values)
    ref = ao4d.extract(values, 0.0)
    field = fields.hypersphere(0.9)
    ref_field = ao4d.extract_field(field, 12, (-1.2, 1.2))
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster),
    ):
        from ao4d.io.grids import read_grid

        grid = read_grid(tmp_path / "v.npy", chunks=(4, 5, 9, 3))  # file-backed, by name
        # dask's default worker environment is slow for ao4d, and ao4d says so, once
        with pytest.warns(WorkerEnvironmentWarning, match="MALLOC_TRIM_THRESHOLD_=65536"):
            got = ao4d.extract(grid.values, 0.0)
        got_field = ao4d.extract_field(field, 12, (-1.2, 1.2), blocks=5)
    _assert_identical(ref, got)
    _assert_identical(ref_field, got_field)
    before = os.environ.get("MALLOC_TRIM_THRESHOLD_")  # dask's nanny put it here
    with worker_environment():
        assert "MALLOC_TRIM_THRESHOLD_" not in os.environ
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0")
    assert os.environ.get("MALLOC_TRIM_THRESHOLD_") == before  # restored
    with cluster, Client(cluster) as client:  # no warning with the recommended environment
        assert list(client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_")).values()) == [None]
        _assert_identical(ref_field, ao4d.extract_field(field, 12, (-1.2, 1.2), blocks=5))
