"""Tests for ao4d.marching.march: closedness, orientation, accuracy against analytic volumes, agreement
with scikit-image (3D marching cubes, 2D contours) and trimesh, slab welding, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.ndimage import gaussian_filter
from scipy.spatial import cKDTree

import ao4d
from ao4d import fields as F
from ao4d.marching import cells, march
from ao4d.topology import GRID_EDGE_KEY

METHODS = ("cubes", "simplices")

# the 4D shapes with analytic volumes used for accuracy (fixed parameters, see ao4d.fields)
TORI = {
    "hypersphere": F.hypersphere(1.0),
    "spheritorus": F.spheritorus(1.0, 0.4),
    "torisphere": F.torisphere(1.0, 0.4),
    "ditorus": F.ditorus(1.0, 0.45, 0.2),
    "tiger": F.tiger(0.8, 0.8, 0.35),
}


def _box(field: F.Field, pad: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    return field.extent[0] - pad, field.extent[1] + pad


def _canonical(simplices: np.ndarray) -> np.ndarray:
    """Simplices as sorted rows of sorted vertex ids plus the parity of the sorting permutation
    (which carries the orientation), independent of simplex order and vertex rotation."""
    order = np.argsort(simplices, axis=1)
    rows = np.take_along_axis(simplices, order, axis=1)
    d = simplices.shape[1]
    inversions = sum((order[:, i] > order[:, j]).astype(int) for i in range(d) for j in range(i + 1, d))
    flat = np.concatenate([rows, (inversions % 2)[:, None]], axis=1)
    return flat[np.lexsort(flat.T[::-1])]


def _assert_same_mesh(a: ao4d.SimplexMesh, b: ao4d.SimplexMesh, tol: float = 1e-9) -> None:
    """Same vertices (matched within ``tol``) and the same oriented simplices, in any order."""
    assert a.n_simplices == b.n_simplices and a.n_vertices == b.n_vertices
    dist, match = cKDTree(a.vertices).query(b.vertices)
    assert dist.max(initial=0.0) < tol and len(np.unique(match)) == len(match)
    np.testing.assert_array_equal(_canonical(a.simplices), _canonical(match[b.simplices]))


def _noise(rng: np.random.Generator, shape: tuple[int, ...], sigma: float = 1.5) -> np.ndarray:
    """Smooth random field with a positive border, so that the level-0 set is closed."""
    v = gaussian_filter(rng.standard_normal(shape), sigma, mode="wrap")
    v /= np.abs(v).max()
    border = np.zeros(shape, dtype=bool)
    for axis in range(len(shape)):
        idx = [slice(None)] * len(shape)
        idx[axis] = [0, -1]
        border[tuple(idx)] = True
    v[border] = 1.0
    return v


# --------------------------------------------------------------------------------------------
# closed, manifold, oriented
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(F.PRESETS))
def test_every_preset_gives_a_closed_oriented_mesh(name, method):
    field = F.preset(name)
    mesh = ao4d.extract_field(field, 13, _box(field), method=method)
    report = mesh.check()
    assert report.ok, str(report)
    assert mesh.volume > 0  # outward orientation: positive enclosed volume
    if field.volume is not None:  # a coarse grid (h ~ 0.25) still lands within 25 %
        assert mesh.volume == pytest.approx(field.volume, rel=0.25)


@pytest.mark.parametrize("method", METHODS)
def test_normals_point_out_of_the_ball(method):
    mesh = ao4d.extract_field(F.hypersphere(1.0), 14, (-1.2, 1.2), method=method)
    good = mesh.simplex_measures > 1e-12
    radial = mesh.simplex_centroids[good]
    assert np.all(np.einsum("ij,ij->i", mesh.simplex_normals[good], radial) > 0)


@st.composite
def _tricky_grid(draw):
    """Small random grid with exact ties to the level, tiny values and a positive border."""
    d = draw(st.sampled_from([2, 3, 4]))
    n = draw(st.integers(3, {2: 9, 3: 7, 4: 5}[d]))
    seed = draw(st.integers(0, 2**32 - 1))
    kind = draw(st.sampled_from(["smooth", "integers", "tiny", "level_in_data"]))
    rng = np.random.default_rng(seed)
    v = _noise(rng, (n,) * d, sigma=draw(st.sampled_from([0.5, 1.0])))
    level = 0.0
    if kind == "integers":  # many values exactly equal to the level
        v = np.round(2 * v)
        v[v > 1] = 1
    elif kind == "tiny":  # differences near the smallest normal/subnormal numbers
        v = v * 1e-305
    elif kind == "level_in_data":
        inner = v[(slice(1, -1),) * d]
        level = float(rng.choice(inner.ravel()))
        v[v >= 1.0] = max(1.0, level + 1.0)
    return v, level


@pytest.mark.filterwarnings("ignore::ao4d.marching.march.EmptyMeshWarning")
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(grid=_tricky_grid(), method=st.sampled_from(METHODS))
def test_random_fields_give_closed_oriented_meshes(grid, method):
    values, level = grid
    mesh = ao4d.extract(values, level, method=method)
    if mesh.n_simplices == 0:  # no negative value at all: nothing to extract
        assert not np.any(values < level)
        return
    report = mesh.check()
    assert report.ok, str(report)
    # every vertex lies on a grid edge between its two samples (t in [0, 1])
    assert np.all(mesh.vertices >= 0) and np.all(mesh.vertices <= np.array(values.shape) - 1)
    assert mesh.volume >= 0


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rough_4d_noise_with_ties_is_closed(seed, method):
    # nearly white noise on 9^4: many cells with several sign components; rounding adds ties
    rng = np.random.default_rng(100 + seed)
    rough = _noise(rng, (9,) * 4, sigma=0.3)
    for values in (rough, np.clip(np.round(2 * rough), -1, 1)):
        report = ao4d.extract(values, 0.0, method=method).check()
        assert report.ok, str(report)
        assert report.n_simplices > 1000


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("d", [2, 3, 4])
def test_inside_above_equals_negated_field(d, method):
    rng = np.random.default_rng(10 + d)
    v = _noise(rng, (6,) * d)
    a = ao4d.extract(v, 0.1, method=method)
    b = ao4d.extract(-v, -0.1, method=method, inside="above")
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.simplices, b.simplices)
    assert a.check().ok


# --------------------------------------------------------------------------------------------
# accuracy against analytic values
# --------------------------------------------------------------------------------------------

# Measured relative errors at 24^4 on these boxes are at most 3.7 % (volume, ditorus cubes) and
# 1.3 % (boundary); the bounds leave ~35 % headroom. The errors are negative: linear
# interpolation cuts chords inside convex surfaces.
ACCURACY_24 = {"volume": 0.05, "measure": 0.02}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(TORI))
def test_volume_and_boundary_accuracy_24(name, method):
    field = TORI[name]
    mesh = ao4d.extract_field(field, 24, _box(field), method=method)
    ev = mesh.volume / field.volume - 1
    em = mesh.measure / field.boundary_measure - 1
    assert -ACCURACY_24["volume"] < ev < 0
    assert -ACCURACY_24["measure"] < em < 0


def _errors(field, sizes, method):
    out = []
    for n in sizes:
        mesh = ao4d.extract_field(field, n, _box(field), method=method, progress=False)
        out.append((abs(mesh.volume / field.volume - 1), abs(mesh.measure / field.boundary_measure - 1)))
    return np.array(out)


def _slope(sizes, errors):
    h = 1.0 / (np.asarray(sizes) - 1.0)
    return np.polyfit(np.log(h), np.log(errors), 1)[0]


@pytest.mark.parametrize("method", METHODS)
def test_hypersphere_errors_shrink_like_h_squared(method):
    sizes = (12, 16, 24)
    err = _errors(TORI["hypersphere"], sizes, method)
    # linear interpolation of a smooth surface: O(h^2); measured slopes 1.99-2.00
    assert _slope(sizes, err[:, 0]) == pytest.approx(2.0, abs=0.15)
    assert _slope(sizes, err[:, 1]) == pytest.approx(2.0, abs=0.15)


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(TORI))
def test_accuracy_and_convergence_48(name, method):
    sizes = (24, 32, 48)
    err = _errors(TORI[name], sizes, method)
    assert err[-1, 0] < 0.01 and err[-1, 1] < 0.005  # measured: <= 0.9 % and <= 0.3 %
    # the thin ditorus (r2 = 0.2 is 4 cells at 24^4) is still pre-asymptotic: wider band
    tol = 0.35 if name == "ditorus" else 0.2
    assert _slope(sizes, err[:, 0]) == pytest.approx(2.0, abs=tol)
    assert _slope(sizes, err[:, 1]) == pytest.approx(2.0, abs=tol)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(("d", "n", "bound"), [(2, 101, 3e-4), (3, 64, 2e-3)])
def test_disk_and_ball_accuracy(d, n, bound, method):
    # chords of a unit circle/sphere with h = 0.024 / 0.038: measured area/volume errors
    # 1.2e-4 / 8.7e-4 (and smaller for the perimeter/area); bounds with 2x headroom
    field = F.hypersphere(1.0, dim=d)
    mesh = ao4d.extract_field(field, n, (-1.2, 1.2), method=method)
    assert mesh.check().ok
    assert -bound < mesh.volume / field.volume - 1 < 0
    assert -bound < mesh.measure / field.boundary_measure - 1 < 0


def test_cubes_and_simplices_agree_within_discretisation_error():
    field = TORI["spheritorus"]
    a = ao4d.extract_field(field, 20, _box(field), method="cubes")
    b = ao4d.extract_field(field, 20, _box(field), method="simplices")
    # both are within 2.1 % of the truth at 20^4 (O(h^2) with the constants measured above)
    assert abs(a.volume - b.volume) < 0.01 * field.volume
    assert abs(a.measure - b.measure) < 0.01 * field.boundary_measure


# --------------------------------------------------------------------------------------------
# 3D and 2D against scikit-image and trimesh
# --------------------------------------------------------------------------------------------


def _same_point_sets(a: np.ndarray, b: np.ndarray, tol: float) -> None:
    assert len(a) == len(b)
    da, _ = cKDTree(b).query(a)
    db, _ = cKDTree(a).query(b)
    assert da.max() < tol and db.max() < tol


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_3d_vertices_match_skimage_lorensen(seed):
    measure = pytest.importorskip("skimage.measure")
    rng = np.random.default_rng(seed)
    v = _noise(rng, (22, 19, 17), sigma=2.0)
    level = 0.05
    verts, faces, _, _ = measure.marching_cubes(v, level, method="lorensen")
    mesh = ao4d.extract(v, level)
    # scikit-image interpolates in float32: 1e-5 grid units covers its rounding (~2e-6 at 20)
    _same_point_sets(mesh.vertices, np.unique(verts, axis=0), 1e-5)
    assert mesh.check().ok


@pytest.mark.parametrize("method", METHODS)
def test_3d_closed_and_volume_agrees_with_trimesh(method):
    trimesh = pytest.importorskip("trimesh")
    rng = np.random.default_rng(7)
    v = _noise(rng, (18, 18, 18), sigma=2.0)
    mesh = ao4d.extract(v, 0.0, method=method, spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3))
    tm = trimesh.Trimesh(mesh.vertices, mesh.simplices, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0  # trimesh's outward orientation is ours
    assert mesh.volume == pytest.approx(tm.volume, rel=1e-10)
    assert mesh.measure == pytest.approx(tm.area, rel=1e-10)


def test_3d_sphere_volume_matches_skimage_and_analytic():
    measure = pytest.importorskip("skimage.measure")
    trimesh = pytest.importorskip("trimesh")
    x = np.linspace(-1.3, 1.3, 40)
    g = np.meshgrid(x, x, x, indexing="ij")
    v = np.sqrt(sum(c**2 for c in g)) - 1.0
    h = x[1] - x[0]
    ours = ao4d.extract(v, spacing=h, origin=x[0])
    verts, faces, _, _ = measure.marching_cubes(v, 0.0, spacing=(h, h, h), method="lorensen")
    theirs = abs(trimesh.Trimesh(verts, faces).volume)
    exact = 4 / 3 * np.pi
    # both are O(h^2) = 0.4 % chords of the same sphere through the same vertices
    assert ours.volume == pytest.approx(exact, rel=0.01)
    assert ours.volume == pytest.approx(theirs, rel=1e-3)


def test_2d_vertices_match_skimage_find_contours():
    measure = pytest.importorskip("skimage.measure")
    rng = np.random.default_rng(3)
    v = _noise(rng, (40, 33), sigma=3.0)
    contours = measure.find_contours(v, 0.0)
    pts = np.unique(np.concatenate(contours), axis=0)
    mesh = ao4d.extract(v, 0.0)
    _same_point_sets(mesh.vertices, pts, 1e-9)
    assert mesh.check().ok
    # a disk has no saddle: the polygons are identical, so the shoelace areas agree
    x = np.linspace(-1, 1, 31)
    disk = np.hypot(*np.meshgrid(x, x, indexing="ij")) - 0.7
    (contour,) = measure.find_contours(disk, 0.0)
    shoelace = 0.5 * abs(np.dot(contour[:-1, 0], contour[1:, 1]) - np.dot(contour[1:, 0], contour[:-1, 1]))
    assert ao4d.extract(disk).volume == pytest.approx(shoelace, rel=1e-12)


# --------------------------------------------------------------------------------------------
# slabs, memory layouts, files
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("chunk", [1, 2, 5])
def test_slab_welding_matches_single_slab(method, chunk):
    field = F.spheritorus(1.0, 0.4)
    box = _box(field)
    whole = ao4d.extract(ao4d.sample(field, 11, box), method=method, chunk=100)
    spacing = (box[1] - box[0]) / 10
    whole = ao4d.SimplexMesh(box[0] + spacing * whole.vertices, whole.simplices)
    slabs = ao4d.extract_field(field, 11, box, method=method, chunk=chunk)
    assert slabs.check().ok
    _assert_same_mesh(whole, slabs)


@pytest.mark.parametrize("d", [2, 3, 4])
def test_memory_layouts_and_dtypes_give_the_same_mesh(d, tmp_path):
    rng = np.random.default_rng(20 + d)
    v = _noise(rng, (7, 6, 5, 6)[:d])
    ref = ao4d.extract(v, 0.0)
    _assert_same_mesh(ref, ao4d.extract(np.asfortranarray(v), 0.0))
    _assert_same_mesh(ref, ao4d.extract(v.tolist(), 0.0))
    path = tmp_path / "v.npy"
    np.save(path, v)
    _assert_same_mesh(ref, ao4d.extract(np.load(path, mmap_mode="r"), 0.0, chunk=1))
    strided = np.zeros((14, *v.shape[1:]))
    strided[::2] = v
    _assert_same_mesh(ref, ao4d.extract(strided[::2], 0.0, chunk=2))
    f32 = ao4d.extract(v.astype(np.float32), 0.0)
    assert f32.n_simplices == ref.n_simplices
    ints = np.round(4 * v).astype(np.int16)
    _assert_same_mesh(ao4d.extract(ints.astype(float), 0.5), ao4d.extract(ints, 0.5))


def test_spacing_and_origin_place_vertices():
    rng = np.random.default_rng(30)
    v = _noise(rng, (6, 7, 5, 6))
    unit = ao4d.extract(v)
    moved = ao4d.extract(v, spacing=(0.5, 1, 2, 3), origin=(-1, 0, 1, 2))
    np.testing.assert_allclose(moved.vertices, unit.vertices * [0.5, 1, 2, 3] + [-1, 0, 1, 2])
    assert moved.volume == pytest.approx(unit.volume * 3.0)


def test_field_is_evaluated_slab_by_slab():
    calls = []

    def field(p):
        calls.append(p.shape[:-1])
        return np.sqrt((p**2).sum(axis=-1)) - 1.0

    mesh = ao4d.extract_field(field, (9, 10, 11, 12), (-1.3, 1.3), chunk=2)
    assert mesh.check().ok
    # slabs of 3 layers along the last axis, the shared layer evaluated only once
    assert max(int(np.prod(s)) for s in calls) <= 3 * 9 * 10 * 11
    assert sum(int(np.prod(s)) for s in calls) == 9 * 10 * 11 * 12


def test_extract_field_never_holds_the_whole_grid():
    import tracemalloc

    n = 56
    full_grid = 8 * n**4  # bytes of the sampled float64 grid (75 MiB)
    field = F.hypersphere(0.15)  # small object in a big box: the output stays tiny (< 1 MiB)
    with pytest.warns(march.EmptyMeshWarning):  # too coarse to see the ball; loads the table
        ao4d.extract_field(field, 8, (-1.2, 1.2))
    tracemalloc.start()
    try:
        mesh = ao4d.extract_field(field, n, (-1.2, 1.2), chunk=2, progress=False)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert mesh.check().ok
    # numpy reports its buffers to tracemalloc. Measured peak: 28 MiB, mostly the field's
    # temporaries on 2^18-point blocks (~18 MiB) plus 3-layer slabs; the grid alone is 75 MiB
    assert peak < full_grid / 2


def test_progress_bar_is_shown_on_request(capsys, monkeypatch):
    from ao4d import _progress

    monkeypatch.setattr(_progress, "LOG_INTERVAL", 0.0)  # a line per update (stderr is not a TTY)
    ao4d.extract_field(F.hypersphere(1.0), 8, (-1.2, 1.2), progress=True)
    err = capsys.readouterr().err
    assert "extract: " in err and "layers" in err
    assert "\r" not in err and "\x1b" not in err  # plain lines in logs, no bar redraws
    ao4d.extract_field(F.hypersphere(1.0), 8, (-1.2, 1.2))  # small grid: silent by default
    assert capsys.readouterr().err == ""


def test_level_outside_the_data_gives_an_empty_mesh():
    v = _noise(np.random.default_rng(0), (5, 5, 5, 5))
    for level in (-5.0, 5.0):
        # the warning gives the data's range
        with pytest.warns(
            march.EmptyMeshWarning, match=r"`level` [-0-9.]+ is outside the data range \[-?[0-9.]+, [0-9.]+\]"
        ):
            mesh = ao4d.extract(v, level)
        assert mesh.n_simplices == 0 and mesh.n_vertices == 0 and mesh.dim == 4


def test_kuhn_table_orientation_and_size():
    table = cells.kuhn_table(3)
    # the all-positive and all-negative cube cases are empty; a single negative corner at the
    # origin is cut by the 6 Kuhn cells that contain it: 6 triangles
    assert table.counts[0] == table.counts[-1] == 0
    assert table.counts[0xFF ^ 1] == 6
    assert np.all((table.corner & table.mask) == 0)


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------

GOOD = np.ones((4, 4, 4, 4))


def _nan_memmap(tmp_path):
    v = GOOD.copy()
    v[2, 2, 2, 2] = np.nan
    np.save(tmp_path / "nan.npy", v)
    return np.load(tmp_path / "nan.npy", mmap_mode="r")


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"values": np.ones(5)}, ValueError, r"`values` must be a 2D, 3D or 4D array, got shape \(5,\)"),
        ({"values": np.ones((2,) * 5)}, ValueError, "`values` must be a 2D, 3D or 4D"),
        ({"values": np.ones((4, 1, 4))}, ValueError, "at least 2 points along every axis"),
        ({"values": np.full((3, 3), np.nan)}, ValueError, "`values` contains 9 non-finite"),
        ({"values": np.full((3, 3), np.inf)}, ValueError, "`values` contains 9 non-finite"),
        ({"values": np.ones((3, 3), dtype=complex)}, TypeError, "`values` must hold real numbers"),
        ({"values": [["a", "b"], ["c", "d"]]}, TypeError, "`values` must hold real numbers"),
        ({"level": np.nan}, ValueError, "`level` must be finite"),
        ({"level": "zero"}, TypeError, "`level` must be a real number"),
        ({"spacing": 0.0}, ValueError, "`spacing` must be > 0"),
        ({"spacing": (1, 1, 1)}, ValueError, "`spacing` must be a scalar or have 4 entries"),
        ({"origin": (0, np.inf, 0, 0)}, ValueError, "`origin` contains"),
        ({"method": "tetra"}, ValueError, "`method` must be one of 'cubes', 'simplices'"),
        ({"inside": "in"}, ValueError, "`inside` must be one of"),
        ({"chunk": 0}, ValueError, "`chunk` must be >= 1"),
        ({"progress": "yes"}, TypeError, "`progress`"),
        ({"values": np.broadcast_to(1.0, (10**4,) * 4)}, MemoryError, r"shape \(10000, .* would need about"),
    ],
)
def test_extract_bad_input_is_named(kwargs, error, match):
    args = {"values": GOOD, **kwargs}
    with pytest.raises(error, match=match):
        ao4d.extract(args.pop("values"), **args)


def test_nan_in_memmap_is_reported(tmp_path):
    with pytest.raises(ValueError, match="`values` contains 1 non-finite"):
        ao4d.extract(_nan_memmap(tmp_path), 0.5, chunk=1)


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        ((F.hypersphere(1.0), 10**5, (-1, 1)), {}, MemoryError, "would need about"),
        ((F.hypersphere(1.0), 1, (-1, 1)), {}, ValueError, "at least 2 points"),
        ((F.hypersphere(1.0, dim=5), 3, (-1, 1)), {}, ValueError, "2D, 3D or 4D grid"),
        ((F.hypersphere(1.0), 8, (-1, 1)), {"method": "x"}, ValueError, "`method`"),
        ((F.hypersphere(1.0), 8, (-1, 1)), {"level": np.inf}, ValueError, "`level`"),
        (("sphere", 8, (-1, 1)), {}, TypeError, "`field` must be callable"),
        ((lambda p: np.full(p.shape[:-1], np.nan), (4, 4, 4), (-1, 1)), {}, ValueError, "non-finite"),
    ],
)
def test_extract_field_bad_input_is_named(args, kwargs, error, match):
    with pytest.raises(error, match=match):
        ao4d.extract_field(*args, **kwargs)


def test_extract_field_takes_blocks_and_no_chunks_keyword():
    # `chunk` (cell layers per slab) and `chunks` (dask blocks) read alike: the blocks are
    # `blocks`, and `chunks` is no alias of it
    with pytest.raises(TypeError, match="chunks"):
        ao4d.extract_field(F.hypersphere(1.0, dim=3), 10, (-1.3, 1.3), chunks=5)


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------


def test_cli_extract_shape_writes_a_checked_mesh(tmp_path, capsys):
    from ao4d.cli import main

    out, vtu = tmp_path / "torus.npz", tmp_path / "torus.vtu"
    args = ["extract", "--shape", "spheritorus", "--grid", "14", "--out", str(out), "--vtu", str(vtu)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "=> OK" in text and "analytic 6.56921" in text
    mesh = ao4d.SimplexMesh.load(out)
    assert mesh.check().ok and vtu.stat().st_size > 0
    field = F.preset("spheritorus")
    lo, hi = field.extent
    ref = ao4d.extract_field(field, 14, (lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo)))
    _assert_same_mesh(ref, mesh)


def test_cli_extract_npy_input(tmp_path, capsys):
    from ao4d.cli import main

    v = _noise(np.random.default_rng(40), (8, 7, 9))
    np.save(tmp_path / "v.npy", -v)
    out = tmp_path / "m.npz"
    args = [
        "extract",
        "--input",
        str(tmp_path / "v.npy"),
        "--level",
        "-0.1",
        "--inside",
        "above",
        "--spacing",
        "0.5",
        "1",
        "2",
        "--method",
        "simplices",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    assert "=> OK" in capsys.readouterr().out
    ref = ao4d.extract(v, 0.1, spacing=(0.5, 1, 2), method="simplices")
    _assert_same_mesh(ref, ao4d.SimplexMesh.load(out))


def test_cli_extract_reports_bad_input(tmp_path, capsys):
    from ao4d.cli import main

    np.save(tmp_path / "v.npy", np.ones(5))
    assert main(["extract", "--input", str(tmp_path / "v.npy"), "--out", str(tmp_path / "m.npz")]) == 2
    assert "`--input` must be a 2D, 3D or 4D array" in capsys.readouterr().err
    assert not (tmp_path / "m.npz").exists()
    with pytest.raises(SystemExit):
        main(["extract", "--shape", "klein", "--out", str(tmp_path / "m.npz")])


@pytest.mark.slow
def test_slab_extraction_of_a_160_grid_stays_under_1_5_gb():
    # the slab path needs the output plus bounded slabs, whatever the grid (measured
    # 0.57 GB peak RSS for this 160^4 grid, whose float64 samples alone would be 5.2 GB)
    import subprocess
    import sys

    # the child's own VmHWM: getrusage's maxrss carries the parent's peak over fork + exec
    code = (
        "import ao4d\n"
        "m = ao4d.extract_field(ao4d.fields.hypersphere(0.3), 160, (-1.2, 1.2), progress=False)\n"
        "assert m.check().ok\n"
        "print([l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1])\n"
    )
    run = subprocess.run([sys.executable, "-c", code], check=True, timeout=900, capture_output=True, text=True)
    peak_gb = int(run.stdout.split()[-1]) * 1024 / 1e9  # kB
    assert peak_gb < 1.5, f"peak RSS {peak_gb:.2f} GB"


# --------------------------------------------------------------------------------------------
# closed=True: a solid touching the grid's edge
# --------------------------------------------------------------------------------------------


def _ramp(d: int, n: int = 9) -> np.ndarray:
    """x0 - 0.5 on [0, 1]^d: the solid {x0 < 0.5} fills half the grid and touches its edge."""
    x = np.linspace(0.0, 1.0, n)
    return np.meshgrid(*[x] * d, indexing="ij")[0] - 0.5


@pytest.mark.parametrize("d", (2, 3, 4))
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("inside", ("below", "above"))
def test_closed_true_closes_a_solid_cut_by_the_grid_to_its_exact_volume(d, method, inside):
    v = _ramp(d) if inside == "below" else -_ramp(d)
    open_ = ao4d.extract(v, 0.0, spacing=1 / 8, method=method, inside=inside)
    assert not open_.check().closed
    mesh = ao4d.extract(v, 0.0, spacing=1 / 8, method=method, inside=inside, closed=True)
    report = mesh.check()
    assert report.ok, report
    # the level set of linear data is the plane x0 = 0.5 exactly; the caps lie on the grid's faces
    assert mesh.volume == pytest.approx(0.5, rel=1e-12)
    lo, hi = mesh.bounds
    np.testing.assert_array_equal(lo, 0.0)
    np.testing.assert_array_equal(hi, [0.5] + [1.0] * (d - 1))
    # vertices inside the grid are those of closed=False, bit for bit
    inner = {tuple(p) for p in open_.vertices}
    assert inner <= {tuple(p) for p in mesh.vertices}


@pytest.mark.parametrize("d", (2, 3, 4))
def test_closed_pieces_of_a_ball_add_up_to_the_ball(d):
    # cut the grid of a ball into its 2^d orthants (sharing the planes x_k = 0) and close each:
    # the caps of two neighbours lie on their shared grid face with opposite orientations, so
    # the closed volumes add up to the whole ball's (to round-off) exactly when every cap is
    # the solid's section by that face, and every piece is closed on its own
    import itertools

    n = {2: 21, 3: 13, 4: 9}[d]
    x = np.linspace(-1.0, 1.0, 2 * n - 1)
    r = np.sqrt(sum(g * g for g in np.meshgrid(*[x] * d, indexing="ij")))
    whole = ao4d.extract(r, 0.8, spacing=x[1] - x[0], origin=-1.0)
    total = 0.0
    for upper in itertools.product((False, True), repeat=d):
        box = tuple(slice(n - 1, None) if u else slice(0, n) for u in upper)
        piece = ao4d.extract(r[box], 0.8, spacing=x[1] - x[0], closed=True, origin=[0.0 if u else -1.0 for u in upper])
        assert piece.check().ok
        total += piece.volume
    assert total == pytest.approx(whole.volume, rel=1e-12)


def _corner_rows(mesh: ao4d.SimplexMesh) -> np.ndarray:
    """Each simplex as its corners' coordinates in lexicographic order, rows sorted."""
    corners = mesh.vertices[mesh.simplices]  # (S, d, d)
    d = corners.shape[1]
    order = np.lexsort(np.moveaxis(corners, 2, 0)[::-1], axis=-1)  # per simplex, corner order
    rows = np.take_along_axis(corners, order[:, :, None], axis=1).reshape(len(corners), d * d)
    return rows[np.lexsort(rows.T[::-1])]


def test_closed_gives_the_same_mesh_on_every_path(tmp_path):
    da = pytest.importorskip("dask.array", reason="dask is a dependency of ao4d")
    rng = np.random.default_rng(2201)
    v = gaussian_filter(rng.standard_normal((9, 8, 7, 6)), 1.2)  # touches every face
    ref = ao4d.extract(v, 0.0, closed=True, spacing=(0.5, 1, 1, 2), origin=(1, 0, 0, 3))
    assert ref.check().ok
    np.save(tmp_path / "v.npy", v)
    np.save(tmp_path / "f.npy", np.asfortranarray(v))
    others = [
        ao4d.extract(
            np.load(tmp_path / "v.npy", mmap_mode="r"), 0.0, closed=True, spacing=(0.5, 1, 1, 2), origin=(1, 0, 0, 3)
        ),
        ao4d.extract(
            da.from_array(v, chunks=(4, 3, 7, 2)), 0.0, closed=True, spacing=(0.5, 1, 1, 2), origin=(1, 0, 0, 3)
        ),
    ]
    for mesh in others:
        np.testing.assert_array_equal(mesh.vertices, ref.vertices)
        np.testing.assert_array_equal(mesh.simplices, ref.simplices)
    for mesh in (
        ao4d.extract(
            np.load(tmp_path / "f.npy", mmap_mode="r"), 0.0, closed=True, spacing=(0.5, 1, 1, 2), origin=(1, 0, 0, 3)
        ),
        ao4d.extract(
            np.load(tmp_path / "v.npy", mmap_mode="r"),
            0.0,
            closed=True,
            chunk=2,
            spacing=(0.5, 1, 1, 2),
            origin=(1, 0, 0, 3),
        ),
    ):
        # other slabs: the same simplices in another order (compared by their corners' exact
        # coordinates: the caps have coincident vertices, so vertex matching is ambiguous)
        np.testing.assert_array_equal(_corner_rows(mesh), _corner_rows(ref))
        assert mesh.volume == pytest.approx(ref.volume, rel=1e-12) and mesh.check().ok
    # integer data: dask pads float64 as the slab reader converts
    q = np.round(v * 10).astype(np.int16)
    a = ao4d.extract(q, 1, closed=True)
    b = ao4d.extract(da.from_array(q, chunks=5), 1, closed=True)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.simplices, b.simplices)
    assert a.check().ok


def test_closed_still_refuses_non_finite_values(tmp_path):
    da = pytest.importorskip("dask.array", reason="dask is a dependency of ao4d")
    v = _ramp(3)
    v[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="`values` contains 1 non-finite"):
        ao4d.extract(v, 0.0, closed=True)
    np.save(tmp_path / "v.npy", v)
    with pytest.raises(ValueError, match="`values` contains 1 non-finite"):
        ao4d.extract(np.load(tmp_path / "v.npy", mmap_mode="r"), 0.0, closed=True, chunk=1)
    with pytest.raises(ValueError, match="`values` contains 1 non-finite"):
        ao4d.extract(da.from_array(v, chunks=4), 0.0, closed=True)
    with pytest.raises(TypeError, match="`closed` must be True or False"):
        ao4d.extract(v, 0.0, closed="yes")


def test_an_open_mesh_cut_by_the_grid_says_what_closes_it():
    from ao4d.ao import OpenMeshWarning

    mesh = ao4d.extract(_ramp(3), 0.0)
    text = str(mesh.check())
    assert "NOT OK" in text and "lie on the grid's boundary" in text
    assert "closed=True" in text and "--closed" in text
    with pytest.warns(OpenMeshWarning, match=r"the mesh is open \(\d+ boundary faces\).*closed=True"):
        ao4d.ambient_occlusion(mesh, samples=4, backend="numpy")
    import warnings

    with warnings.catch_warnings():  # once per mesh
        warnings.simplefilter("error")
        ao4d.ambient_occlusion(mesh, samples=4, backend="numpy")
        closed = ao4d.extract(_ramp(3), 0.0, closed=True)
        assert "grid's boundary" not in str(closed.check())
        ao4d.ambient_occlusion(closed, samples=4, backend="numpy")
        # a mesh whose level set stays inside the grid carries no hint
        inside = ao4d.extract(_noise(np.random.default_rng(2202), (8, 8, 8)), 0.0)
        assert GRID_EDGE_KEY not in inside.cache


@pytest.mark.parametrize("d", (2, 3, 4))
def test_affine_places_vertices_and_keeps_the_mesh_closed_and_outward(d):
    rng = np.random.default_rng(2203 + d)
    v = _noise(rng, (7,) * d)
    ref = ao4d.extract(v, 0.0)
    for sign in (1.0, -1.0):
        q, _ = np.linalg.qr(rng.standard_normal((d, d)))
        m = q * rng.uniform(0.5, 2.0, d)
        if np.sign(np.linalg.det(m)) != sign:
            m[:, 0] *= -1
        a = np.eye(d + 1)
        a[:d, :d], a[:d, d] = m, rng.normal(size=d) * 100
        mesh = ao4d.extract(v, 0.0, affine=a)
        report = mesh.check()
        assert report.ok, report  # closed and outward: simplices reversed when det < 0
        assert mesh.volume == pytest.approx(abs(np.linalg.det(m)) * ref.volume, rel=1e-9)
        np.testing.assert_allclose(mesh.vertices, ref.vertices @ m.T + a[:d, d], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="either `affine` or `spacing`"):
        ao4d.extract(v, 0.0, affine=np.eye(d + 1), spacing=2.0)
    with pytest.raises(ValueError, match="`affine` must have shape"):
        ao4d.extract(v, 0.0, affine=np.eye(d))
    with pytest.raises(ValueError, match="invertible"):
        ao4d.extract(v, 0.0, affine=np.zeros((d, d + 1)))


def test_cli_extract_affine_flag_places_by_the_files_affine(tmp_path, capsys):
    # the command line keeps `--affine` (read_grid's keep_affine=True); no deprecation on the way
    from ao4d.cli import main

    v = F.sample(F.hypersphere(0.8, dim=3), (9, 10, 11), (-1, 1))
    np.save(tmp_path / "v.npy", v)
    assert (
        main(
            [
                "extract",
                "--input",
                str(tmp_path / "v.npy"),
                "--affine",
                "--spacing",
                "0.5",
                "2",
                "1",
                "--level",
                "0",
                "--no-progress",
                "--out",
                str(tmp_path / "m.npz"),
            ]
        )
        == 0
    )
    ref = ao4d.extract(v, 0.0, spacing=(0.5, 2, 1))
    got = ao4d.SimplexMesh.load(tmp_path / "m.npz")
    np.testing.assert_allclose(got.vertices, ref.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.simplices, ref.simplices)


def test_ties_take_the_positive_side_like_a_level_just_below():
    # DESIGN.md: a vertex is positive when f >= level, so values equal to the level are outside;
    # integer data at such a level give the mesh of the next float below the level, cell for cell
    rng = np.random.default_rng(2204)
    for d in (2, 3, 4):
        v = np.pad(rng.integers(0, 4, size=(6,) * d), 1, constant_values=5)
        for method in METHODS:
            at = ao4d.extract(v, 2, method=method)
            below = ao4d.extract(v, np.nextafter(2.0, -np.inf), method=method)
            assert (v == 2).any() and at.check().ok
            np.testing.assert_array_equal(at.simplices, below.simplices)
            np.testing.assert_allclose(at.vertices, below.vertices, rtol=0, atol=1e-12)


def test_cli_extract_closed_and_refused_options(tmp_path, capsys):
    from ao4d.cli import main

    np.save(tmp_path / "v.npy", _ramp(3))
    out = tmp_path / "m.npz"
    assert main(["extract", "--input", str(tmp_path / "v.npy"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "NOT OK" in text and "--closed" in text
    assert main(["extract", "--input", str(tmp_path / "v.npy"), "--closed", "--out", str(out)]) == 0
    assert "=> OK" in capsys.readouterr().out
    assert ao4d.SimplexMesh.load(out).check().ok
    from ao4d.io.mesh_files import read_field_data

    info = read_field_data(out)
    assert bool(info["closed"]) and str(info["source"]) == str(tmp_path / "v.npy")
    np.testing.assert_array_equal(info["spacing"], 1.0)
    for extra in (["--spacing", "0.1"], ["--dim", "3"], ["--origin", "1"], ["--w-scale", "2"], ["--affine"]):
        assert main(["extract", "--shape", "hypersphere", "--grid", "8", *extra, "--out", str(tmp_path / "s.npz")]) == 2
        assert "to --input only, not to --shape" in capsys.readouterr().err
    assert main(["extract", "--input", str(tmp_path / "v.npy"), "--grid", "20", "--out", str(tmp_path / "s.npz")]) == 2
    assert "--grid applies to --shape only" in capsys.readouterr().err
    assert not (tmp_path / "s.npz").exists()
    assert (
        main(
            [
                "extract",
                "--shape",
                "hypersphere",
                "--grid",
                "10",
                "--bounds",
                "0",
                "1.5",
                "--closed",
                "--out",
                str(tmp_path / "s.npz"),
            ]
        )
        == 0
    )
    quarter = ao4d.SimplexMesh.load(tmp_path / "s.npz")
    assert quarter.check().ok and quarter.bounds[0].tolist() == [0.0] * 4


def test_masked_arrays_are_refused_or_read_plainly():
    v = _noise(np.random.default_rng(2205), (7, 7, 7))
    holey = v.copy()
    holey[3, 3, 3] = np.nan
    with pytest.raises(ValueError, match=r"`values` is a masked array with 1 masked entries"):
        ao4d.extract(np.ma.masked_invalid(holey), 0.0)  # the NaN hidden under the mask
    with pytest.raises(ValueError, match=r"`values` contains 1 non-finite"):
        ao4d.extract(np.ma.array(holey), 0.0)  # nothing masked: the NaN itself
    _assert_same_mesh(ao4d.extract(v, 0.0), ao4d.extract(np.ma.array(v), 0.0), tol=0.0 + 1e-15)


@pytest.mark.parametrize("spacing", [1e-300, 1e300, (1.0, 1.0, 1.0, 1e300), (1e-60, 1.0, 1.0, 1.0)])
def test_spacings_whose_products_leave_float64_are_refused(spacing):
    # 1e-300: every simplex degenerate yet check() "OK"; 1e300: volume nan; both with exit 0
    values = np.random.default_rng(3500).normal(size=(5, 5, 5, 5))
    with pytest.raises(ValueError, match="`spacing`.*(too small|too large).*float64"):
        ao4d.extract(values, spacing=spacing)
    with pytest.raises(ValueError, match="`spacing`.*float64"):
        ao4d.extract(values, spacing=spacing, closed=True, method="simplices")
    with pytest.raises(ValueError, match="`affine`.*float64"):
        ao4d.extract(values, affine=np.diag([*np.broadcast_to(spacing, 4), 1.0]))
    # the largest and smallest steps that pass keep their measures
    for ok in (1e-45, 1e45):
        mesh = ao4d.extract_field(lambda p: np.linalg.norm(p, axis=-1) - 0.7 * ok, (6,) * 4, (-ok, ok))
        report = mesh.check()
        assert report.ok and report.n_degenerate == 0 and np.isfinite(mesh.volume)


def test_field_bounds_whose_products_leave_float64_are_refused():
    with pytest.raises(ValueError, match="`bounds`.*too small"):
        ao4d.extract_field(lambda p: p[..., 0], (5,) * 4, (0.0, 1e-300))


@pytest.mark.parametrize("step", [1e-3, 1e-4, 1e-20])
def test_affine_with_small_uniform_steps_is_invertible(step):
    # data stored in metres: an absolute determinant test refused steps below 1e-3 in 4D
    values = ao4d.sample(ao4d.fields.hypersphere(0.7), (8,) * 4, (-1.0, 1.0))
    ref = ao4d.extract(values, spacing=2 / 7, origin=-1.0)
    a = np.diag([step] * 4 + [1.0])
    a[:4, 4] = 5 * step
    mesh = ao4d.extract(values, affine=a)
    assert mesh.check().ok
    np.testing.assert_allclose(mesh.volume, ref.volume * (step * 7 / 2) ** 4, rtol=1e-9)
    flat = np.diag([step] * 4 + [1.0])
    flat[:4, 3] = [step, 0.0, 0.0, step * 1e-13]  # the w axis along x: no 4D grid
    with pytest.raises(ValueError, match="invertible.*condition number"):
        ao4d.extract(values, affine=flat)
    stretched = np.diag([step, step, step, step * 1e-13, 1.0])  # other steps per axis are fine
    assert ao4d.extract(values, affine=stretched).check().ok


def test_empty_results_say_why_for_constant_and_two_valued_grids():
    # "`level` 1 is outside the data range [1, 1]" and "0 is outside [0, 1]" said nothing useful
    with pytest.warns(march.EmptyMeshWarning, match=r"the grid is constant \(every value is 1\)"):
        ao4d.extract(np.ones((3, 3, 3, 3)), 1.0)
    binary = (np.random.default_rng(3700).random((4, 4, 4, 4)) > 0.5).astype(np.uint8)
    with pytest.warns(
        march.EmptyMeshWarning, match=r"`level` 0 equals the data's minimum: the solid is f < level.*e\.g\. 0\.5"
    ):
        ao4d.extract(binary, 0.0)
    with pytest.warns(march.EmptyMeshWarning, match=r"`level` 1 equals the data's maximum: the solid is f > level"):
        ao4d.extract(binary, 1.0, inside="above")
    with pytest.warns(march.EmptyMeshWarning, match=r"`level` 2 is outside the data range \[0, 1\]"):
        ao4d.extract(binary, 2.0)
    assert ao4d.extract(binary, 0.5).n_simplices > 0


def test_a_none_spacing_entry_keeps_the_default_step():
    # read_grid's None ("keep the file's step") met "3 non-finite values" in extract
    values = ao4d.sample(ao4d.fields.hypersphere(0.7), (6,) * 4, (-1.0, 1.0))
    mesh = ao4d.extract(values, spacing=(None, None, None, 0.5))
    np.testing.assert_array_equal(mesh.vertices, ao4d.extract(values, spacing=(1, 1, 1, 0.5)).vertices)
    with pytest.raises(ValueError, match="`spacing` must be > 0"):
        ao4d.extract(values, spacing=(None, None, None, -1.0))


def test_a_complex_valued_field_is_refused_like_complex_values():
    field = lambda p: np.linalg.norm(p, axis=-1) - 0.5 + 0j  # noqa: E731
    with pytest.raises(TypeError, match="`field` must return real numbers, got dtype complex128"):
        ao4d.extract_field(field, (5,) * 4, (-1.0, 1.0))
    with pytest.raises(TypeError, match="`field` must return real numbers"):
        ao4d.sample(field, (5,) * 4, (-1.0, 1.0))


@pytest.mark.parametrize("d", [2, 3, 4])
def test_the_grid_edge_hint_counts_the_vertices_on_each_face(d):
    """A level set that meets one face of the grid (each axis, each side, spacing and origin
    of any size) is found and its vertices there counted; one that stays inside is not."""
    n = 5
    rng = np.random.default_rng(3144 + d)
    spacing, origin = rng.uniform(0.1, 3.0, d), rng.uniform(-1e3, 1e3, d)
    index = np.stack(np.meshgrid(*[np.arange(n)] * d, indexing="ij"), axis=-1)
    for axis in range(d):
        for side in (0, n - 1):
            # a bump that crosses the level on the face index[axis] == side only
            dist = np.linalg.norm(index - np.where(np.arange(d) == axis, side, (n - 1) / 2), axis=-1)
            values = dist - 1.3
            mesh = ao4d.extract(values, 0.0, spacing=spacing, origin=origin, progress=False)
            face = origin[axis] + spacing[axis] * side
            expected = int(np.count_nonzero(mesh.vertices[:, axis] == face))
            assert expected > 0
            assert mesh.cache[GRID_EDGE_KEY].startswith(f"{expected:,} vertices lie on the grid's boundary")
    centred = np.linalg.norm(index - (n - 1) / 2, axis=-1) - 1.3
    assert GRID_EDGE_KEY not in ao4d.extract(centred, 0.0, spacing=spacing, origin=origin, progress=False).cache
