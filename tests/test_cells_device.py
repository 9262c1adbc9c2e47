"""Tests for ao4d.cells_device, the marching engine on the OpenCL device: the same vertices and
simplices as the numpy engine (ao4d.cells), array for array and in the same order, for both
methods in 2D, 3D and 4D, on random fields, values exactly at the level, flat fields, thin
slabs, Fortran arrays, closed=True, fields and dask blocks; and the table property the kernels
rely on (a case uses exactly its crossed edges).

Every comparison is ``np.array_equal`` on the raw arrays, which fails on any reordering of
vertices or simplices (and on any change of a vertex's float64 bits)."""

from __future__ import annotations

import numpy as np
import pytest

import ao4d
from ao4d import cells, cells_device

DIMS = (2, 3, 4)
METHODS = ("cubes", "simplices")
SHAPES = {2: (9, 7), 3: (7, 6, 8), 4: (6, 5, 7, 4)}


def _engines(values, level, method, inside="below", layers=None, runtime=None):
    """(numpy engine result, device engine result) for a C-order array."""
    d = values.ndim
    geom = cells._Geometry(values.shape, tuple(range(d)), np.zeros(d), np.ones(d))
    table = cells._cell_table(d, method)
    layers = layers or cells._layers_per_slab(None, geom, method)

    def read(a, b):
        return np.ascontiguousarray(values[a:b])

    kw = dict(table=table, inside=inside, layers_per_slab=layers, check_values=False, progress=None)
    return cells._march(read, geom, level, **kw), cells_device.march(read, geom, level,
                                                                     runtime=runtime, **kw)


def _assert_same(ref, got):
    ref_v, ref_s = ref
    got_v, got_s = got
    assert got_v.dtype == ref_v.dtype and got_v.shape == ref_v.shape
    np.testing.assert_array_equal(got_v, ref_v)  # bit for bit, in order
    assert got_s.shape == ref_s.shape
    np.testing.assert_array_equal(got_s, ref_s)  # vertex indices, in cell order


def _assert_same_mesh(a, b):
    _assert_same((a.vertices, a.simplices), (b.vertices, b.simplices))


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("method", METHODS)
def test_every_case_uses_exactly_its_crossed_edges(d, method):
    """What lets the kernels read the used edges off the signs instead of marking them."""
    table = cells._cell_table(d, method)
    n_cases, n_edges = len(table.counts), len(table.corner)
    case_of_row = np.repeat(np.arange(n_cases), table.counts)
    used = np.zeros((n_cases, n_edges), dtype=bool)
    used[np.repeat(case_of_row, d), table.simplices.ravel().astype(np.int64)] = True
    cases = np.arange(n_cases)[:, None]
    crossed = ((cases >> table.corner) & 1) != ((cases >> (table.corner | table.mask)) & 1)
    np.testing.assert_array_equal(used, crossed)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("inside", ["below", "above"])
def test_random_fields_give_the_numpy_engines_arrays(cl_runtime, d, method, inside):
    rng = np.random.default_rng(2200 + 10 * d + len(method) + len(inside))
    values = rng.standard_normal(SHAPES[d])
    for layers in (None, 1, 2, 3):  # one slab, and slabs that share layers
        ref, got = _engines(values, 0.1, method, inside, layers, cl_runtime)
        assert len(ref[1]) > 0
        _assert_same(ref, got)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("method", METHODS)
def test_values_exactly_at_the_level_and_flat_regions(cl_runtime, d, method):
    rng = np.random.default_rng(2300 + d)
    values = rng.integers(-1, 2, SHAPES[d]).astype(np.float64)  # many values equal to 0
    values[(slice(0, 2),) * d] = 0.0  # a flat block exactly at the level
    for layers in (None, 1, 2):
        _assert_same(*_engines(values, 0.0, method, "below", layers, cl_runtime))
    # float32 values and a level between two float32 neighbours
    values32 = (rng.standard_normal(SHAPES[d]) * 0.1).astype(np.float32)
    level = float(values32.flat[7]) + 1e-12
    _assert_same(*_engines(values32, level, method, "below", 2, cl_runtime))


@pytest.mark.parametrize("d", DIMS)
def test_empty_slabs_between_surfaces(cl_runtime, d):
    """Slabs without a simplex reset the carried layer, as the numpy engine does."""
    values = np.ones(SHAPES[d])
    values[1] = -1.0  # a thin solid at the bottom ...
    values[-2] = -1.0  # ... and one at the top, empty slabs between
    for method in METHODS:
        for layers in (1, 2):
            ref, got = _engines(values, 0.0, method, "below", layers, cl_runtime)
            assert len(ref[1]) > 0
            _assert_same(ref, got)
    ref, got = _engines(np.ones(SHAPES[d]), 0.0, "cubes", "below", 1, cl_runtime)
    assert len(got[1]) == 0 and got[0].shape == (0, d)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("method", METHODS)
def test_extract_backends_agree(cl_runtime, d, method):
    rng = np.random.default_rng(2500 + d)
    values = rng.standard_normal(SHAPES[d])
    for kwargs in ({}, {"chunk": 2}, {"closed": True}, {"inside": "above", "chunk": 1}):
        ref = ao4d.extract(values, 0.2, method=method, backend="numpy", **kwargs)
        _assert_same_mesh(ref, ao4d.extract(values, 0.2, method=method, backend="opencl", **kwargs))
    fortran = np.asfortranarray(values)  # slabs along the last user axis
    _assert_same_mesh(ao4d.extract(fortran, 0.2, method=method, backend="numpy", chunk=2),
                      ao4d.extract(fortran, 0.2, method=method, backend="opencl", chunk=2))


@pytest.mark.parametrize("method", METHODS)
def test_fields_and_dask_blocks_agree(cl_runtime, method):
    pytest.importorskip("dask")
    import dask.array as da

    from ao4d import fields

    field = fields.hypersphere(1.0, dim=3)
    ref = ao4d.extract_field(field, 12, (-1.3, 1.3), method=method, chunk=3, backend="numpy")
    _assert_same_mesh(ref, ao4d.extract_field(field, 12, (-1.3, 1.3), method=method, chunk=3,
                                              backend="opencl"))
    _assert_same_mesh(ref, ao4d.extract_field(field, 12, (-1.3, 1.3), method=method, chunk=3,
                                              chunks=7, backend="opencl"))
    values = ao4d.sample(fields.hypersphere(1.0), 9, (-1.3, 1.3))
    ref = ao4d.extract(values, method=method, backend="numpy")
    _assert_same_mesh(ref, ao4d.extract(da.from_array(values, chunks=4), method=method,
                                        backend="opencl"))


def test_a_large_grid_in_several_slabs(cl_runtime):
    """A 4D hypersphere of 30^4 in the default slabs (several): same arrays."""
    from ao4d import fields

    values = ao4d.sample(fields.hypersphere(1.0), 30, (-1.2, 1.2))
    for method in METHODS:
        _assert_same_mesh(ao4d.extract(values, method=method, backend="numpy", chunk=7),
                          ao4d.extract(values, method=method, chunk=7))


def test_the_numpy_backend_never_touches_the_device(monkeypatch):
    def fail(*args, **kwargs):
        raise AssertionError("the device engine ran")

    monkeypatch.setattr(cells_device, "march", fail)
    mesh = ao4d.extract(np.linspace(-1, 1, 16).reshape(4, 4), backend="numpy")
    assert mesh.n_simplices > 0
    monkeypatch.setenv("AO4D_DEVICE", "none")
    assert cells_device.get_runtime("auto") is None


def test_bad_backend_is_named():
    with pytest.raises(ValueError, match="`backend`"):
        ao4d.extract(np.zeros((3, 3)), backend="cuda")
    with pytest.raises(ValueError, match="`backend`"):
        cells_device.get_runtime("gpu-please")
