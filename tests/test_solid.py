"""ao4d.marching.solid: solids and interval volumes cut into simplices.

Tolerances: the extracted boundary is a piecewise-linear surface whose facets are chords of the
true level set; a chord of length L on a sphere of radius r lies within its sagitta L^2 / (8 r),
and the facets' edges are at most a cell diagonal, L <= h sqrt(d). The enclosed volume therefore
differs from the ball's by at most area * d h^2 / (8 r) = V * d^2 h^2 / (8 r^2) (area = d V / r).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ao4d
from ao4d.marching.solid import extract_solid, extract_solid_field


def _radius(d: int, n: int, lim: float = 1.3):
    x = np.linspace(-lim, lim, n)
    grids = np.meshgrid(*[x] * d, indexing="ij")
    return np.sqrt(sum(g * g for g in grids)), float(x[1] - x[0]), float(x[0])


def _ball_volume(d: int, r: float) -> float:
    return math.pi ** (d / 2) / math.gamma(d / 2 + 1) * r**d


def _sagitta_bound(d: int, h: float, r: float) -> float:
    """Relative volume error bound of a linear-interpolated sphere of radius r (module docstring)."""
    return d * d * h * h / (8 * r * r)


def simplex_set(vertices: np.ndarray, simplices: np.ndarray) -> set:
    """Simplices as sorted vertex coordinates with the parity of the sorting permutation
    (orientation; None where two vertices coincide and no orientation can be told)."""
    out = set()
    for row in simplices:
        c = [tuple(vertices[i]) for i in row]
        order = sorted(range(len(c)), key=lambda i: c[i])
        inversions = sum(order[i] > order[j] for i in range(len(order)) for j in range(i + 1, len(order)))
        out.add((tuple(sorted(c)), None if len(set(c)) < len(c) else inversions % 2))
    return out


def _assert_boundary_is_extract(solid, values, level, **kw):
    surface = ao4d.extract(values, level, closed=True, **kw)
    boundary = solid.boundary()
    assert simplex_set(boundary.vertices, boundary.simplices) == simplex_set(surface.vertices, surface.simplices)


@pytest.mark.parametrize("method", ["cubes", "simplices"])
@pytest.mark.parametrize("d", [2, 3, 4])
def test_ball_volume_conformity_orientation_and_boundary(d, method):
    n = {2: 21, 3: 13, 4: 9}[d]
    r, h, o = _radius(d, n)
    solid = extract_solid(r, 1.0, spacing=h, origin=o, method=method)
    report = solid.check()
    assert report.overused_facets == 0 and report.misoriented_facets == 0 and report.boundary_closed
    assert report.ok and report.negative == 0 and report.degenerate == 0
    assert (solid.simplex_volumes > 0).all()  # none inverted, none flat: no value equals the level
    boundary = solid.boundary()
    assert boundary.check().closed
    assert solid.volume == pytest.approx(boundary.volume, rel=1e-9)
    exact = _ball_volume(d, 1.0)
    assert 0 < (exact - solid.volume) / exact <= _sagitta_bound(d, h, 1.0)  # chords lie inside
    _assert_boundary_is_extract(solid, r, 1.0, spacing=h, origin=o, method=method)


def test_hyperball_converges_within_the_sagitta_bound():
    exact = _ball_volume(4, 1.0)
    errors = []
    for n in (9, 13):
        solid = extract_solid_field(ao4d.fields.hypersphere(1.0), n, (-1.3, 1.3), method="simplices")
        h = 2.6 / (n - 1)
        errors.append((exact - solid.volume) / exact)
        assert 0 < errors[-1] <= _sagitta_bound(4, h, 1.0)
    assert errors[1] < errors[0] * 0.75  # second order: (8/12)^2 = 0.44 ideally


def test_interval_shell_volume_and_boundary():
    r, h, o = _radius(4, 11)
    solid = extract_solid(r, 0.6, upper=1.1, spacing=h, origin=o, method="simplices")
    assert solid.check().ok
    outer, inner = _ball_volume(4, 1.1), _ball_volume(4, 0.6)
    bound = outer * _sagitta_bound(4, h, 1.1) + inner * _sagitta_bound(4, h, 0.6)
    assert abs(solid.volume - (outer - inner)) <= bound
    up = ao4d.extract(r, 1.1, closed=True, spacing=h, origin=o, method="simplices")
    low = ao4d.extract(r, 0.6, closed=True, spacing=h, origin=o, method="simplices").flipped()
    b = solid.boundary()
    assert simplex_set(b.vertices, b.simplices) == simplex_set(up.vertices, up.simplices) | simplex_set(
        low.vertices, low.simplices
    )
    assert solid.volume == pytest.approx(up.volume + low.volume, rel=1e-9)


@pytest.mark.parametrize("method", ["cubes", "simplices"])
def test_inside_above_is_the_flipped_field(method):
    r, h, o = _radius(3, 9)
    below = extract_solid(r, 1.0, spacing=h, origin=o, method=method)
    above = extract_solid(-r, -1.0, spacing=h, origin=o, inside="above", method=method)
    assert above.volume == pytest.approx(below.volume, rel=1e-12)
    _assert_boundary_is_extract(above, -r, -1.0, spacing=h, origin=o, inside="above", method=method)
    shell = extract_solid(-r, -1.0, upper=-0.5, spacing=h, origin=o, inside="above", method="simplices")
    assert shell.check().ok and shell.volume > 0


def test_the_default_method_is_simplices_positive_on_4d_noise():
    # the default cuts Kuhn simplices: positively oriented on any field, no warning, and its
    # boundary is the simplex method's surface
    values = np.random.default_rng(7).normal(size=(5, 5, 5, 5))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        solid = extract_solid(values, 0.0)
    assert (solid.simplex_volumes >= 0).all() and solid.check().ok
    _assert_boundary_is_extract(solid, values, 0.0, method="simplices")


@pytest.mark.parametrize("method", ["cubes", "simplices"])
def test_solid_touching_the_grid_edge_is_closed_there(method):
    r, h, o = _radius(3, 9, lim=0.8)  # the unit ball is cut by the grid's box
    solid = extract_solid(r, 1.0, spacing=h, origin=o, method=method)
    assert solid.check().boundary_closed and solid.check().negative == 0
    assert solid.volume == pytest.approx(1.6**3, rel=0.2)
    _assert_boundary_is_extract(solid, r, 1.0, spacing=h, origin=o, method=method)


@settings(max_examples=12, deadline=None)
@given(
    d=st.sampled_from([2, 3, 4]),
    method=st.sampled_from(["cubes", "simplices"]),
    seed=st.integers(0, 2**31),
    integer=st.booleans(),
)
def test_random_fields_conform_and_bound_the_cube_surface(d, method, seed, integer):
    """Random fields: ambiguous cells everywhere; integer values put many exactly at the level."""
    rng = np.random.default_rng(seed)
    n = {2: 8, 3: 5, 4: 4}[d]
    values = rng.integers(-2, 3, (n,) * d).astype(float) if integer else rng.normal(size=(n,) * d)
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solid = extract_solid(values, 0.0, method=method)
        surface = ao4d.extract(values, 0.0, closed=True, method=method)
    report = solid.check()
    assert report.overused_facets == 0 and report.misoriented_facets == 0 and report.boundary_closed
    left = [w for w in caught if "stay inverted" in str(w.message)]
    inverted = int((solid.simplex_volumes < 0).sum())
    if method == "simplices" or d < 4:
        assert inverted == 0 and not left
    else:  # 4D noise: a cell whose neighbourhoods are none star-shaped is left, never silently
        assert inverted == (int(str(left[0].message).split()[0]) if left else 0)
    _assert_flat_only_where_allowed(solid, values, 0.0)
    b = solid.boundary()
    assert simplex_set(b.vertices, b.simplices) == simplex_set(surface.vertices, surface.simplices)
    assert solid.volume == pytest.approx(surface.volume, rel=1e-9, abs=1e-12)


def _assert_flat_only_where_allowed(solid, values, level):
    """Zero volume only where two vertices coincide (a value equal to the level, or a crossing
    towards the padding) or all lie on one face of the grid's box (the padding layer closing the
    solid); the random fields sit at origin 0, spacing 1."""
    vol = solid.simplex_volumes
    p = solid.vertices[solid.simplices[vol == 0]]  # (k, d + 1, d)
    coincide = (p[:, :, None] == p[:, None]).all(axis=-1).sum(axis=(1, 2)) > p.shape[1]
    on_face = ((p == 0).all(axis=1) | (p == np.array(values.shape) - 1).all(axis=1)).any(axis=1)
    assert (coincide | on_face).all() or (values == level).any()  # equal values: any flat simplex


@pytest.mark.parametrize(
    ("d", "n", "seed", "inverted"),
    [(4, 9, None, 1), (4, 13, None, 13), (3, 5, 2, 2), (3, 5, 18, 2)],
)
def test_cube_cells_that_turned_over_are_recut(d, n, seed, inverted):
    """Interpolated crossings turned these fields' cube templates over (the hyperball at 9^4 and
    13^4, normal noise in 3D); the neighbourhoods are re-cut as stars and nothing stays inverted."""
    from ao4d.marching import solid as solid_module

    if seed is None:
        values, h, o = _radius(d, n)
        level = 1.0
    else:
        values, h, o, level = np.random.default_rng(seed).normal(size=(n,) * d), 1.0, 0.0, 0.0
    solid = extract_solid(values, level, spacing=h, origin=o, method="cubes")
    stats = solid_module.UNTANGLED
    assert stats["inverted"] == inverted and stats["regions"] >= 1 and stats["left"] == 0
    vol = solid.simplex_volumes
    assert (vol >= 0).all() and (seed is not None or (vol > 0).all())
    _assert_flat_only_where_allowed(solid, values, level) if seed is not None else None
    report = solid.check()
    assert report.ok and report.negative == 0
    assert solid.volume == pytest.approx(solid.boundary().volume, rel=1e-9)
    _assert_boundary_is_extract(solid, values, level, spacing=h, origin=o, method="cubes")


def test_slab_sizes_give_the_same_solid():
    r, h, o = _radius(3, 10)
    one = extract_solid(r, 1.0, spacing=h, origin=o, method="simplices")
    thin = extract_solid(r, 1.0, spacing=h, origin=o, method="simplices", chunk=1)
    assert thin.n_vertices == one.n_vertices and thin.n_simplices == one.n_simplices
    assert simplex_set(thin.vertices, thin.simplices) == simplex_set(one.vertices, one.simplices)


def test_field_and_array_give_the_same_solid():
    field = ao4d.fields.hypersphere(1.0)
    a = extract_solid_field(field, 7, (-1.3, 1.3))
    b = extract_solid(ao4d.sample(field, 7, (-1.3, 1.3)), 0.0, spacing=2.6 / 6, origin=-1.3)
    assert a.volume == pytest.approx(b.volume, rel=1e-12) and a.n_simplices == b.n_simplices


def test_3d_against_pytetwild(tmp_path, monkeypatch):
    """pytetwild tetrahedralises scikit-image's surface of the same ball; it keeps its boundary
    within epsilon (1e-3) of the bounding box diagonal, so the volumes agree within the surface
    area times that distance, plus the difference of the two marching-cubes surfaces' volumes."""
    pytetwild = pytest.importorskip("pytetwild")
    monkeypatch.chdir(tmp_path)  # fTetWild writes __tracked_surface.stl into the working directory
    skimage_measure = pytest.importorskip("skimage.measure")
    r, h, o = _radius(3, 21)
    verts, faces, _, _ = skimage_measure.marching_cubes(r, 1.0, spacing=(h, h, h))
    tv, tt = pytetwild.tetrahedralize(verts + o, faces)
    theirs = abs(float(ao4d.SolidMesh(tv, tt).volume))
    ours = extract_solid(r, 1.0, spacing=h, origin=o)
    diag = float(np.linalg.norm(tv.max(axis=0) - tv.min(axis=0)))
    area = ours.boundary().measure
    skimage_volume = abs(ao4d.SimplexMesh(verts + o, faces).volume)
    bound = area * 1e-3 * diag + abs(skimage_volume - ours.volume)
    assert abs(theirs - ours.volume) <= bound


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"upper": 0.5}, "`upper`"),
        ({"upper": 1.0}, "`upper`"),
        ({"method": "hexes"}, "`method`"),
        ({"inside": "left"}, "`inside`"),
        ({"spacing": -1.0}, "`spacing`"),
    ],
)
def test_bad_options_are_refused_naming_the_parameter(kwargs, match):
    with pytest.raises(ValueError, match=match):
        extract_solid(np.zeros((3, 3)), 1.0, **{"method": "simplices", **kwargs})


def test_bad_values_are_refused():
    with pytest.raises(ValueError, match="`values`.*2D, 3D or 4D"):
        extract_solid(np.zeros(5), 0.0)
    with pytest.raises(ValueError, match="`values`"):
        extract_solid(np.full((3, 3, 3, 3, 3), 1.0), 0.0)
    nan = np.zeros((4, 4))
    nan[1, 2] = np.nan
    with pytest.raises(ValueError, match="`values`"):
        extract_solid(nan, 0.5)
    with pytest.raises(NotImplementedError, match="`upper`.*simplices"):
        extract_solid(np.zeros((3, 3)), 0.0, upper=1.0, method="cubes")
    with pytest.raises(ValueError, match="`field`"):
        extract_solid_field(lambda p: np.full(p.shape[:-1], np.nan), (4, 4), (0, 1))
