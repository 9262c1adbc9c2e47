"""Tests for ao4d.marching.cells, the marching engine: case indices, cell tables, the tie rule,
interpolation (also of the infinite padding of ``closed=True``), welding across slabs, the
layout independence of the strides, and the slab memory check."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import ao4d
from ao4d.marching import cells, lut

DIMS = (2, 3, 4)


def _geometry(shape, perm=None):
    d = len(shape)
    perm = tuple(range(d)) if perm is None else perm
    return cells.Geometry(tuple(shape), perm, np.zeros(d), np.ones(d))


@pytest.mark.parametrize("d", DIMS)
def test_case_index_has_bit_v_set_iff_corner_v_is_positive(d):
    rng = np.random.default_rng(2400 + d)
    positive = rng.random((3,) * d) < 0.5
    case = cells._cases(positive, tuple(range(d)))
    for cell in itertools.product(range(2), repeat=d):  # cells with their lowest corner here
        expect = 0
        for v in range(1 << d):
            corner = tuple(c + ((v >> k) & 1) for k, c in enumerate(cell))
            expect |= int(positive[corner]) << v
        assert int(case[cell]) == expect
    # the last layer along every axis holds no cell
    for axis in range(d):
        assert not case[(slice(None),) * axis + (-1,)].any()


@pytest.mark.parametrize("d", DIMS)
def test_cases_do_not_depend_on_the_slab_axis(d):
    rng = np.random.default_rng(2410 + d)
    positive = rng.random((4, 3, 5, 2)[:d]) < 0.5
    ref = cells._cases(positive, tuple(range(d)))
    perm = tuple(range(d))[::-1]  # the engine array holds user axis perm[e] at axis e
    flipped = cells._cases(np.ascontiguousarray(positive.T), perm)
    np.testing.assert_array_equal(flipped.T, ref)


@pytest.mark.parametrize("d", DIMS)
def test_cube_table_edges_and_rows_follow_lut(d):
    table = cells.cube_table(d)
    source = lut.load(d, "cube")
    np.testing.assert_array_equal(table.corner & table.mask, 0)  # lower corner, direction
    np.testing.assert_array_equal(table.corner | table.mask, source.edges.max(axis=1))
    assert [bin(int(m)).count("1") for m in table.mask] == [1] * len(table.mask)  # cube edges
    np.testing.assert_array_equal(table.counts, np.diff(source.offsets))
    assert table.counts[0] == 0 and table.counts[-1] == 0  # all negative / all positive


@pytest.mark.parametrize("d", DIMS)
def test_kuhn_table_splits_each_cube_into_d_factorial_simplices(d):
    table = cells.kuhn_table(d)
    simplex = lut.load(d, "simplex")
    assert len(simplex.cells) == math.factorial(d)
    # per cube case, the Kuhn simplices' own cases add up to the rows listed for it
    n = 1 << d
    cases = np.arange(1 << n)
    bits = (cases[:, None, None] >> simplex.cells[None].astype(np.int64)) & 1
    sub_case = (bits << np.arange(d + 1)).sum(axis=2)
    np.testing.assert_array_equal(table.counts, np.diff(simplex.offsets)[sub_case].sum(axis=1))
    # edges: every cube edge or diagonal (a, m) with a & m == 0 once
    assert len(table.corner) == len({(int(a), int(m)) for a, m in zip(table.corner, table.mask)})
    np.testing.assert_array_equal(table.corner & table.mask, 0)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("inside, toward", [("below", -np.inf), ("above", np.inf)])
def test_values_equal_to_the_level_are_positive(d, inside, toward):
    # DESIGN.md: a vertex is positive when f >= level (inside="above": f <= level), so integer
    # data at a level equal to some of its values give exactly the mesh of the next float on
    # the solid's side of the level (nextafter(level, -inf) for "below")
    rng = np.random.default_rng(2420 + d)
    v = rng.integers(0, 4, size=(7,) * d)
    v = np.pad(v, 1, constant_values=5 if inside == "below" else -1)
    assert (v == 2).sum() > 3
    for method in ("cubes", "simplices"):
        at = ao4d.extract(v, 2, method=method, inside=inside)
        near = ao4d.extract(v, np.nextafter(2.0, toward), method=method, inside=inside)
        np.testing.assert_array_equal(at.simplices, near.simplices)
        np.testing.assert_allclose(at.vertices, near.vertices, rtol=0, atol=1e-12)
        assert at.check().ok


def test_interpolation_stays_on_its_edge_and_takes_the_padding_limit():
    d = 2
    geom = _geometry((2, 3))
    plan = cells.Plan.make(cells.cube_table(d), geom)
    slab = np.array([[0.0, 1e-300, np.inf], [1.0, -np.inf, 3.0]])
    # edges: (0,0)-(0,1) along axis 1, (0,1)-(0,2) along axis 1 into +inf, (1,1)-(1,2) from -inf
    lin = np.array([0, 1, 4])
    masks = np.array([2, 2, 2])
    level = 0.5
    p = cells.interpolate(slab, lin, masks, 0, level, plan)
    # 0 -> 1e-300 does not cross 0.5 in exact arithmetic, but the engine only interpolates edges
    # it found crossed; t = 0.5 / 1e-300 is clipped to the edge, never beyond its end
    assert p[0].tolist() == [0.0, 1.0]
    assert p[1].tolist() == [0.0, 1.0]  # t = (0.5 - 1e-300) / inf = 0: at the finite end
    assert p[2].tolist() == [1.0, 2.0]  # inf / inf: the limit, the finite (upper) end


@pytest.mark.parametrize("method", ("cubes", "simplices"))
def test_welding_across_slabs_does_not_depend_on_the_slab_size(method):
    rng = np.random.default_rng(2430)
    from scipy.ndimage import gaussian_filter

    v = gaussian_filter(rng.standard_normal((9, 6, 7, 5)), 1.0)
    one = ao4d.extract(v, 0.0, method=method)
    for chunk in (1, 2, 3, 7):
        m = ao4d.extract(v, 0.0, method=method, chunk=chunk)
        assert m.n_vertices == one.n_vertices and m.n_simplices == one.n_simplices
        assert m.check().n_boundary_faces == one.check().n_boundary_faces
        np.testing.assert_array_equal(np.unique(m.vertices, axis=0), np.unique(one.vertices, axis=0))
        assert m.volume == pytest.approx(one.volume, rel=1e-12)


def test_corner_offsets_follow_the_user_axes_under_any_slab_axis():
    shape = (4, 5, 6)
    for perm in itertools.permutations(range(3)):
        engine = tuple(shape[a] for a in perm)
        offs = cells.corner_offsets(_geometry(engine, perm), 3)
        strides = np.cumprod((1,) + engine[:0:-1])[::-1]  # engine C-order strides
        for v in range(8):
            user = [(v >> k) & 1 for k in range(3)]
            assert offs[v] == sum(user[perm[e]] * strides[e] for e in range(3))


def test_slab_memory_check_refuses_absurd_grids_before_work():
    geom = _geometry((10**6, 10**6, 10**6, 10**6))
    with pytest.raises(MemoryError, match="use thinner slabs"):
        cells.check_slab_memory(geom, 1, "cubes", 8)
    layers = cells.layers_per_slab(None, _geometry((100, 100, 100, 100)), "cubes")
    assert layers >= 1 and (layers + 1) * 100**3 * 4 <= 2 * cells._KEYS_PER_SLAB
    assert cells.layers_per_slab(3, _geometry((10, 10)), "cubes") == 3
    with pytest.raises(ValueError, match="`chunk`"):
        cells.layers_per_slab(0, _geometry((10, 10)), "cubes")


@pytest.mark.parametrize(
    "dtype", [np.float16, np.float32, np.float64, np.int8, np.uint8, np.int16, np.uint16, np.int32, np.int64]
)
@pytest.mark.parametrize("inside", ["below", "above"])
def test_threshold_equals_the_widened_comparison(dtype, inside):
    """`v op thr` in the data's dtype equals float64(v) op level, for levels on, between and
    beyond the dtype's values (every value of the small dtypes; neighbours of the level else)."""
    rng = np.random.default_rng(2900 + np.dtype(dtype).itemsize)
    dt = np.dtype(dtype)
    if dt.kind == "f":
        finite = np.finfo(dt)
        base = rng.standard_normal(200).astype(dt)
        levels = [float(x) for x in base[:20]] + [
            float(np.nextafter(x, dt.type(np.inf))) * 0.5 + float(x) * 0.5 for x in base[:20]
        ]
        levels += [1.0001, 1.00000001, 0.1, -0.0, float(finite.max) * 1.5, -float(finite.max) * 1.5]
        values = np.concatenate([base, np.array([np.inf, -np.inf, finite.max, finite.min, 0.0, -0.0, 1.0], dtype=dt)])
        with np.errstate(over="ignore"):
            values = np.concatenate(
                [values, np.nextafter(values, dt.type(np.inf)), np.nextafter(values, dt.type(-np.inf))]
            )
    else:
        info = np.iinfo(dt)
        values = np.unique(np.clip(rng.integers(-300, 300, 400), info.min, info.max)).astype(dt)
        values = np.concatenate([values, np.array([info.min, info.max], dtype=dt)])
        levels = [-300.5, -1.5, -1.0, -0.5, 0.0, 0.25, 7.0, 7.5, 254.5, 255.0, 255.5, 1e30, -1e30]
        if dt.itemsize < 8:  # 64-bit integers beyond 2^53 compare exactly, not as float64 does
            levels += [float(info.max) + 0.5, float(info.min) - 0.5]
    wide = values.astype(np.float64)
    for level in levels:
        got = cells._positive(values, level, inside)
        expect = wide >= level if inside == "below" else wide <= level
        np.testing.assert_array_equal(got, expect, err_msg=f"{dt} level {level!r}")


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize(
    "dtype,level", [(np.float16, 1.0001), (np.float32, 1.00000001), (np.float16, 0.99999), (np.int16, 0.5)]
)
def test_narrow_dtypes_are_compared_with_the_level_as_given(d, dtype, level):
    """float16 data at level 1.0001 with values exactly 1.0: the values are below the level, as
    in float64 (comparing in float16 rounds the level to 1.0 and puts them above)."""
    rng = np.random.default_rng(2910 + d)
    shape = (7, 6, 5, 4)[:d]
    values = rng.integers(0, 3, shape).astype(dtype)  # many values exactly 1
    wide = values.astype(np.float64)
    for method in ("cubes", "simplices"):
        for inside in ("below", "above"):
            ref = ao4d.extract(wide, level, method=method, inside=inside, backend="numpy")
            got = ao4d.extract(values, level, method=method, inside=inside, backend="numpy")
            assert got.n_simplices == ref.n_simplices > 0
            np.testing.assert_array_equal(got.simplices, ref.simplices)
            np.testing.assert_array_equal(got.vertices, ref.vertices)  # t in float64 as well


class _Bar:
    def __init__(self):
        self.done = 0

    def update(self, n):
        self.done += n


@pytest.mark.parametrize("layers", [1, 2, 3, 7, 100])
def test_the_slab_loop_covers_the_grid_with_shared_layers(layers):
    """Job.slabs, the loop of both engines: consecutive slabs share their boundary layer, the
    last one ends at the grid's last layer, progress counts every cell layer once, and the
    values are checked when asked."""
    values = np.arange(8 * 3 * 2, dtype=float).reshape(8, 3, 2)
    reads = []

    def read(a, b):
        reads.append((a, b))
        return values[a:b]

    bar = _Bar()
    job = cells.Job(
        read,
        _geometry(values.shape),
        0.0,
        cells.cell_table(3, "cubes"),
        "below",
        layers,
        check_values=True,
        progress=bar,
    )
    got = [(z0, z1, slab) for z0, z1, slab in job.slabs()]
    ranges = [(z0, z1) for z0, z1, _ in got]
    want = [(z, min(z + layers, 7)) for z in range(0, 7, layers)]
    assert ranges == want and reads == [(a, b + 1) for a, b in want] and bar.done == 7
    for z0, z1, slab in got:
        np.testing.assert_array_equal(slab, values[z0 : z1 + 1])
    assert [z for z, _, _ in job.slabs(3, report=False)] == [0, 3, 6] and bar.done == 7
    values[5, 1, 1] = np.nan
    with pytest.raises(ValueError, match="values"):
        list(job.slabs())


def test_frame_gives_each_engine_axis_its_index_origin_and_spacing():
    """What cells.interpolate adds and scales and the device kernel receives: per engine axis
    (engine axis e holds user axis perm[e]) the slab's first grid index, with a block's offset,
    the origin and the spacing."""
    geom = cells.Geometry(
        (4, 5, 6), (2, 0, 1), np.array([0.5, -1.0, 2.0]), np.array([0.1, 0.2, 0.3]), np.array([10, 20, 30])
    )
    index, origin, spacing = geom.frame(3)
    assert index == [3 + 30, 10, 20] and origin == [2.0, 0.5, -1.0] and spacing == [0.3, 0.1, 0.2]
    assert _geometry((4, 5)).frame(2)[0] == [2, 0]


def test_join_concatenates_parts_in_their_index_type_or_widened():
    d = 3
    parts = [
        cells.SlabMesh(
            np.full((k, d), float(k)), np.full((k + 1, d), k, dtype=np.int32), np.zeros(0), np.zeros(0), np.zeros(0)
        )
        for k in (1, 2)
    ]
    v, s = cells.join(parts, d)
    assert v.shape == (3, d) and s.dtype == np.int32 and s.shape == (5, d)
    v, s = cells.join(parts, d, widen=True)
    assert s.dtype == np.int64 and s[:2].tolist() == [[1] * d] * 2 and s[2:].tolist() == [[2] * d] * 3
    v, s = cells.join(parts[:1], d, widen=True)
    assert s is parts[0].simplices and v is parts[0].vertices  # one part: no copy
    v, s = cells.join([], d)
    assert v.shape == (0, d) and s.shape == (0, d) and s.dtype == np.int64
