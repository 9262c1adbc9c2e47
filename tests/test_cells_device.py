"""Tests for ao4d.marching.cells_device, the marching engine on the OpenCL device: the same vertices and
simplices as the numpy engine (ao4d.marching.cells), array for array and in the same order, for both
methods in 2D, 3D and 4D, on random fields, values exactly at the level, flat fields, thin
slabs, Fortran arrays, closed=True, fields and dask blocks; and the table property the kernels
rely on (a case uses exactly its crossed edges).

Every comparison is ``np.array_equal`` on the raw arrays, which fails on any reordering of
vertices or simplices (and on any change of a vertex's float64 bits)."""

from __future__ import annotations

import numpy as np
import pytest

import ao4d
from ao4d.marching import cells, cells_device

DIMS = (2, 3, 4)
METHODS = ("cubes", "simplices")
SHAPES = {2: (9, 7), 3: (7, 6, 8), 4: (6, 5, 7, 4)}


def _engines(values, level, method, inside="below", layers=None, runtime=None, reread=False, origin=0.0, spacing=1.0):
    """(numpy engine result, device engine result) for a C-order array."""
    d = values.ndim
    geom = cells.Geometry(
        values.shape, tuple(range(d)), np.full(d, origin, dtype=float), np.full(d, spacing, dtype=float)
    )
    table = cells.cell_table(d, method)
    layers = layers or cells.layers_per_slab(None, geom, method)

    def read(a, b):
        return np.ascontiguousarray(values[a:b])

    job = cells.Job(read, geom, level, table, inside, layers, check_values=False)
    return cells.march(job), cells_device.march(job, runtime=runtime, reread=reread)


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
    table = cells.cell_table(d, method)
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


@pytest.mark.parametrize("method", METHODS)
def test_rows_of_every_width_give_the_numpy_engines_arrays(cl_runtime, method):
    """classify takes 16 points of a row at a time and a row's last width % 16 one at a time:
    rows shorter than, as long as, and longer than one or more vectors, in 2D, 3D and 4D, in
    one slab and in slabs that share layers."""
    rng = np.random.default_rng(2290 + len(method))
    shapes = [(5, w) for w in (16, 33)] + [(4, 3, w) for w in (15, 16, 17, 32, 47)] + [(3, 3, 2, w) for w in (16, 35)]
    for shape in shapes:
        values = rng.standard_normal(shape)
        for layers in (None, 1, 2):
            ref, got = _engines(values, 0.1, method, "below", layers, cl_runtime)
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
    _assert_same_mesh(
        ao4d.extract(fortran, 0.2, method=method, backend="numpy", chunk=2),
        ao4d.extract(fortran, 0.2, method=method, backend="opencl", chunk=2),
    )


@pytest.mark.parametrize("method", METHODS)
def test_fields_and_dask_blocks_agree(cl_runtime, method):
    pytest.importorskip("dask")
    import dask.array as da

    from ao4d import fields

    field = fields.hypersphere(1.0, dim=3)
    ref = ao4d.extract_field(field, 12, (-1.3, 1.3), method=method, chunk=3, backend="numpy")
    _assert_same_mesh(ref, ao4d.extract_field(field, 12, (-1.3, 1.3), method=method, chunk=3, backend="opencl"))
    _assert_same_mesh(
        ref, ao4d.extract_field(field, 12, (-1.3, 1.3), method=method, chunk=3, blocks=7, backend="opencl")
    )
    values = ao4d.sample(fields.hypersphere(1.0), 9, (-1.3, 1.3))
    ref = ao4d.extract(values, method=method, backend="numpy")
    _assert_same_mesh(ref, ao4d.extract(da.from_array(values, chunks=4), method=method, backend="opencl"))


def test_a_large_grid_in_several_slabs(cl_runtime):
    """A 4D hypersphere of 30^4 in the default slabs (several): same arrays."""
    from ao4d import fields

    values = ao4d.sample(fields.hypersphere(1.0), 30, (-1.2, 1.2))
    for method in METHODS:
        _assert_same_mesh(
            ao4d.extract(values, method=method, backend="numpy", chunk=7), ao4d.extract(values, method=method, chunk=7)
        )


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


def _every_case_grid(d, rng, n_bits=None):
    """Values whose cells at even indices hold every case of the d-cube once (the cells between
    them hold other cases), each corner value drawn away from the level 0; with ``n_bits``,
    2^n_bits cases drawn at random instead."""
    n_bits = 1 << d if n_bits is None else n_bits
    bits = [n_bits // d + (k < n_bits % d) for k in range(d)]  # the cases' bits over d axes
    side = tuple(1 << b for b in bits)
    values = np.empty(tuple(2 * n for n in side))
    cases = np.arange(1 << n_bits) if n_bits == 1 << d else rng.permutation(1 << (1 << d))[: 1 << n_bits]
    cases = cases.reshape(side)
    mag = rng.uniform(0.2, 1.0, values.shape)
    for v in range(1 << d):
        corner = tuple(slice((v >> k) & 1, None, 2) for k in range(d))
        values[corner] = np.where((cases >> v) & 1, mag[corner], -mag[corner])
    return values


@pytest.mark.parametrize("d", (2, 3))
@pytest.mark.parametrize("method", METHODS)
def test_every_table_case_gives_the_numpy_engines_arrays(cl_runtime, d, method):
    rng = np.random.default_rng(2950 + d)
    values = _every_case_grid(d, rng)
    for layers in (None, 1, 3):
        for reread in (False, True):
            ref, got = _engines(values, 0.0, method, "below", layers, cl_runtime, reread)
            assert len(ref[1]) >= (1 << (1 << d)) - 2  # every case but the two empty ones
            _assert_same(ref, got)


@pytest.mark.parametrize("method", METHODS)
def test_4d_table_cases_give_the_numpy_engines_arrays(cl_runtime, method):
    """4096 of the 65,536 4D cases, drawn at random (all of them: the slow test below)."""
    values = _every_case_grid(4, np.random.default_rng(2954), n_bits=12)
    for layers, reread in ((None, True), (3, False)):
        _assert_same(*_engines(values, 0.0, method, "below", layers, cl_runtime, reread))


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_every_4d_table_case_gives_the_numpy_engines_arrays(cl_runtime, method):
    values = _every_case_grid(4, np.random.default_rng(2954))
    ref, got = _engines(values, 0.0, method, "below", None, cl_runtime, True)
    assert len(ref[1]) >= (1 << 16) - 2
    _assert_same(ref, got)


@pytest.mark.parametrize(
    "dtype", [np.float16, np.float32, np.float64, np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.int64]
)
def test_every_dtype_is_compared_and_interpolated_as_the_numpy_engine_does(cl_runtime, dtype):
    """Values in their own dtype on the device (no widening on the host): the same arrays,
    levels on, between and beyond the values (float16 at 1.0001 with values exactly 1)."""
    rng = np.random.default_rng(2960 + np.dtype(dtype).itemsize)
    values = rng.integers(0, 4, SHAPES[4]).astype(dtype)
    for level, inside in ((1.0001, "below"), (1.0, "above"), (2.5, "below"), (1.00000001, "above")):
        for method in METHODS:
            ref, got = _engines(values, level, method, inside, 2, cl_runtime)
            assert len(ref[1]) > 0
            _assert_same(ref, got)
    ref, got = _engines(values, 300.0, "cubes", "below", None, cl_runtime)  # beyond int8's range
    assert len(ref[1]) == len(got[1]) == 0
    wide = ao4d.extract(values.astype(np.float64), 1.0001, backend="numpy")
    _assert_same_mesh(wide, ao4d.extract(values, 1.0001, backend="opencl"))


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("method", METHODS)
def test_device_slabs_of_every_size_keep_the_numpy_engines_order(cl_runtime, monkeypatch, d, method):
    """Device slabs of 1, 2, ... numpy slabs (and the whole grid), counted first or not, with
    carried layers and boundaries of the numpy slabs inside them: the same arrays."""
    rng = np.random.default_rng(2970 + d)
    shape = {2: (23, 9), 3: (13, 7, 8), 4: (11, 5, 6, 4)}[d]
    values = rng.standard_normal(shape)
    layer = int(np.prod(shape[1:]))
    for period in (1, 2, 3):
        for per_slab in (1, 2, 3, 100):  # device slab: this many numpy slabs
            monkeypatch.setattr(cells_device, "_SLAB_POINTS", per_slab * period * layer)
            for reread in (False, True):
                _assert_same(*_engines(values, 0.3, method, "below", period, cl_runtime, reread))
            geom = cells.Geometry(shape, tuple(range(d)), np.zeros(d), np.ones(d))
            job = cells.Job(
                lambda a, b: values[a:b], geom, 0.3, cells.cell_table(d, method), "below", period, check_values=False
            )
            parts = list(cells_device.march_slabs(job, runtime=cl_runtime))
            ref = list(cells.march_slabs(job))
            for name in ("keys", "cells", "counts"):  # what block-wise welding reads
                np.testing.assert_array_equal(
                    np.concatenate([getattr(p, name) for p in parts]), np.concatenate([getattr(p, name) for p in ref])
                )


def test_small_device_slabs_with_closed_fields_and_dask(cl_runtime, monkeypatch):
    pytest.importorskip("dask")
    import dask.array as da

    from ao4d import fields

    values = ao4d.sample(fields.hypersphere(1.0), 11, (-1.3, 1.3)).astype(np.float32)
    # numpy slabs of one layer without chunk= (which fixes the device's slabs too)
    monkeypatch.setattr(cells, "_KEYS_PER_SLAB", 2 * 13**3 * 4)
    for method in METHODS:
        ref = ao4d.extract(values, method=method, backend="numpy", closed=True)
        ref_blocks = ao4d.extract(da.from_array(values, chunks=6), method=method, backend="numpy")
        ref_field = ao4d.extract_field(fields.hypersphere(1.0), 11, (-1.3, 1.3), method=method, backend="numpy")
        for points in (11**3, 3 * 11**3):  # device slabs of 1 and of 3 numpy slabs
            monkeypatch.setattr(cells_device, "_SLAB_POINTS", points)
            _assert_same_mesh(ref, ao4d.extract(values, method=method, backend="opencl", closed=True))
            _assert_same_mesh(
                ref_blocks, ao4d.extract(da.from_array(values, chunks=6), method=method, backend="opencl")
            )
            _assert_same_mesh(
                ref_field, ao4d.extract_field(fields.hypersphere(1.0), 11, (-1.3, 1.3), method=method, backend="opencl")
            )
        # chunk= fixes the device's slabs: the user bounds memory with it
        _assert_same_mesh(
            ao4d.extract(values, method=method, backend="numpy", chunk=2),
            ao4d.extract(values, method=method, backend="opencl", chunk=2),
        )


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.float16])
@pytest.mark.parametrize("method", METHODS)
def test_the_float32_path_gives_the_same_simplices_and_close_vertices(cl_runtime, monkeypatch, dtype, method):
    """Where the device has no cl_khr_fp64 (forced here): exact comparisons (the same
    simplices, in order) and vertices within the bound stated in ao4d.marching.cells_device, far from
    the origin too (the bound grows with |origin|)."""
    from ao4d import fields

    monkeypatch.setattr(cells_device, "FLOAT32", True)
    values = ao4d.sample(fields.hypersphere(1.0), 14, (-1.3, 1.3)).astype(dtype)
    level = 0.0123
    for origin, spacing in ((-1.3, 0.2), (1000.0, 0.2)):
        ref, got = _engines(values, level, method, "below", 2, cl_runtime, origin=origin, spacing=spacing)
        np.testing.assert_array_equal(got[1], ref[1])
        assert got[0].shape == ref[0].shape and len(ref[0]) > 0
        # the stated bound, per vertex: index part and t part
        f = values.astype(np.float64)
        index = (ref[0] - origin) / spacing
        lo = np.floor(index + 1e-9).astype(int)
        bound_index = 2.0**-21 * (abs(origin) + spacing * (np.abs(lo) + 1))
        span = 2 * float(np.abs(f).max()) + abs(level)
        df = np.min(np.abs(np.diff(np.unique(f))))  # the smallest value step: the worst |f1 - f0|
        bound_t = spacing * (2.0**-22 * span / df + 2.0**-23)
        err = np.abs(got[0] - ref[0])
        assert np.all(err <= bound_index + bound_t), float((err - bound_index - bound_t).max())
        assert float(err.max()) < 1e-4 * (abs(origin) + spacing * 14)


@pytest.mark.parametrize("in_place", [True, False])
def test_output_written_in_place_or_read_back_is_the_same(cl_runtime, monkeypatch, in_place):
    """CPU devices write the final arrays in place; other devices fill device buffers that are
    read back (forced here): the same arrays, in one slab and in several."""
    monkeypatch.setattr(cells_device, "IN_PLACE", in_place)
    rng = np.random.default_rng(2980)
    values = rng.standard_normal((9, 6, 5, 7))
    for method in METHODS:
        for points in (1 << 20, 2 * 6 * 5 * 7):
            monkeypatch.setattr(cells_device, "_SLAB_POINTS", points)
            for reread in (False, True):
                _assert_same(*_engines(values, 0.1, method, "below", 1, cl_runtime, reread))


@pytest.mark.parametrize("in_place", [True, False])
def test_values_read_in_place_or_copied_give_the_same_arrays(cl_runtime, monkeypatch, in_place):
    """A CPU device reads an array aligned to 128 bytes in place (ao4d._pages), others are copied
    (and every array on other devices, forced here): the numpy engine's arrays either way, the
    caller's array unchanged and not kept."""
    import sys

    from ao4d._pages import HOST_PTR_ALIGN, aligned_empty, readable_in_place

    monkeypatch.setattr(cells_device, "IN_PLACE", in_place)
    rng = np.random.default_rng(3029)
    for shape in ((40, 33, 35), (9, 6, 5, 7)):
        base = aligned_empty(int(np.prod(shape)) + 2, np.float64)
        aligned = base[: np.prod(shape)].reshape(shape)
        shifted = base[2:].reshape(shape)  # 16 bytes past the alignment: copied
        assert readable_in_place(aligned) and not readable_in_place(shifted)
        assert aligned.ctypes.data % HOST_PTR_ALIGN == 0
        for values in (aligned, shifted):
            values[...] = rng.standard_normal(shape)
            before, refs = values.copy(), sys.getrefcount(values)
            read_only = values.view()
            read_only.flags.writeable = False  # np.load(..., mmap_mode="r") and frozen arrays
            for method in METHODS:
                ref = ao4d.extract(values, 0.1, method=method, progress=False, backend="numpy")
                for given in (values, read_only):
                    got = ao4d.extract(given, 0.1, method=method, progress=False, backend="opencl")
                    _assert_same_mesh(ref, got)
            del read_only
            assert sys.getrefcount(values) == refs
            np.testing.assert_array_equal(values, before)


@pytest.mark.parametrize("float32_path", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.float16])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_the_device_finds_non_finite_values_in_its_first_pass(cl_runtime, monkeypatch, float32_path, dtype, bad):
    """A grid in one device slab is checked by the sign kernel, not by a host pass; the error
    names `values` and counts the bad values, as the host check's does (float64 stored as
    ordered integers where the device lacks fp64: forced here)."""
    from ao4d.marching import march

    monkeypatch.setattr(cells_device, "FLOAT32", float32_path)
    host_checks = []
    monkeypatch.setattr(march, "check_finite", lambda *a: host_checks.append(a))
    values = np.linspace(-1.0, 1.0, 11 * 12 * 13).reshape(11, 12, 13).astype(dtype)
    values[0, 0, 0] = values[10, 5, 12] = values[4, 11, 3] = bad
    with pytest.raises(ValueError, match=r"`values` contains 3 non-finite value\(s\)"):
        ao4d.extract(values, 0.0, progress=False, backend="opencl")
    assert host_checks == []
    values[values != values] = 0.5  # NaN gone
    values[np.isinf(values)] = 0.5
    ao4d.extract(values, 0.0, progress=False, backend="opencl")  # nothing flagged


@pytest.mark.parametrize("float32_path", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.float16])
def test_the_sign_pass_flags_a_bad_value_in_every_lane_and_in_the_tail(cl_runtime, monkeypatch, float32_path, dtype):
    """The sign kernel reads 16 values per work-item and the n % 16 left one at a time: one NaN
    at the first and last lane of a vector, and in the scalar tail (1716 = 107 * 16 + 4 points),
    is found wherever it is."""
    monkeypatch.setattr(cells_device, "FLOAT32", float32_path)
    base = np.linspace(-1.0, 1.0, 11 * 12 * 13).astype(dtype)
    assert base.size % 16 == 4
    for at in (0, 15, 16, base.size - 5, base.size - 4, base.size - 1):
        values = base.copy()
        values[at] = np.nan
        with pytest.raises(ValueError, match=r"`values` contains 1 non-finite value"):
            ao4d.extract(values.reshape(11, 12, 13), 0.0, progress=False, backend="opencl")


def test_a_grid_in_several_device_slabs_is_checked_before_any_marching(cl_runtime, monkeypatch):
    """Where the device would mark slab after slab (``chunk=`` fixes its slabs), the host checks
    the whole array first, so a bad value in the last layer fails before the first slab."""

    def march(*args, **kwargs):
        raise AssertionError("marched before the values were checked")

    monkeypatch.setattr(cells_device, "march", march)
    values = np.linspace(-1.0, 1.0, 20 * 6 * 7).reshape(20, 6, 7)
    values[-1, 3, 3] = np.nan
    with pytest.raises(ValueError, match=r"`values` contains 1 non-finite value"):
        ao4d.extract(values, 0.0, progress=False, backend="opencl", chunk=2)
