"""Tests for ao4d.fields: analytic volumes (Monte Carlo), transforms, CSG, sampling, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ao4d
from ao4d import fields as F

# Shapes with closed-form 4-volume and boundary 3-volume, all distance-like (|grad f| = 1 almost
# everywhere), so the shell {|f| < eps} has 4-volume 2 eps * boundary + O(eps^3) (coarea formula).
ANALYTIC = {
    "hypersphere": F.hypersphere(0.9),
    "hypersphere_offcenter": F.hypersphere(0.7, [0.1, -0.2, 0.3, 0.0]),
    "spheritorus": F.spheritorus(1.0, 0.4),
    "torisphere": F.torisphere(1.0, 0.4),
    "ditorus": F.ditorus(1.0, 0.45, 0.2),
    "tiger": F.tiger(0.8, 0.7, 0.3),
    "duocylinder": F.duocylinder(1.0, 0.6),
    "tesseract": F.tesseract(0.8),
    "tesseract_round": F.tesseract(0.8, 0.3),
    "indented_cube": F.indented_cube(1.0, 0.6),
    "scaled_rotated_torus": F.rotate(F.scale(F.spheritorus(1.0, 0.4), 0.8), (1, 3), 0.6),
}


def _monte_carlo(field: F.Field, n: int, eps: float, rng: np.random.Generator):
    """Estimate volume and boundary measure by uniform sampling of the padded extent box."""
    lo, hi = field.extent[0] - 2 * eps, field.extent[1] + 2 * eps
    box = float(np.prod(hi - lo))
    inside = shell = 0
    for _ in range(n // 2**18):
        f = field(rng.uniform(lo, hi, size=(2**18, field.dim)))
        inside += np.count_nonzero(f < 0)
        shell += np.count_nonzero(np.abs(f) < eps)
    p_in, p_sh = inside / n, shell / n
    vol, area = box * p_in, box * p_sh / (2 * eps)
    # binomial standard errors of the two estimates
    return vol, area, box * math.sqrt(p_in * (1 - p_in) / n), box * math.sqrt(p_sh / n) / (2 * eps)


@pytest.mark.parametrize("name", sorted(ANALYTIC))
def test_analytic_volume_and_boundary_match_monte_carlo(name):
    rng = np.random.default_rng(1)
    field = ANALYTIC[name]
    eps = 0.01  # shell bias is O(eps^2 * curvature^2) ~ 1e-3 relative, below the MC noise
    vol, area, vol_se, area_se = _monte_carlo(field, 2**20, eps, rng)
    # 4.5 standard errors: 11 shapes x 2 estimates stay clear of chance failures (p ~ 1e-4)
    assert abs(vol - field.volume) < 4.5 * vol_se + 1e-3 * field.volume
    assert abs(area - field.boundary_measure) < 4.5 * area_se + 3e-3 * field.boundary_measure


@pytest.mark.parametrize("name", sorted(F.PRESETS))
def test_solid_lies_inside_its_extent(name):
    rng = np.random.default_rng(2)
    field = F.preset(name)
    lo, hi = field.extent
    pad = 0.5 * (hi - lo)
    pts = rng.uniform(lo - pad, hi + pad, size=(200_000, field.dim))
    inside = field(pts) < 0
    assert inside.any()
    within = np.all((pts >= lo - 1e-12) & (pts <= hi + 1e-12), axis=1)
    assert not np.any(inside & ~within)


def test_hypersphere_is_dimension_generic():
    for d in (2, 3, 4, 5):
        f = F.hypersphere(2.0, dim=d)
        assert f.volume == pytest.approx(math.pi ** (d / 2) / math.gamma(d / 2 + 1) * 2.0**d)
        pt = np.zeros(d)
        pt[-1] = 2.0
        assert f(pt) == pytest.approx(0.0)
    assert F.hypersphere(1.0, dim=4).volume == pytest.approx(math.pi**2 / 2)
    assert F.hypersphere(1.0, dim=4).boundary_measure == pytest.approx(2 * math.pi**2)
    assert F.hypersphere(1.0, [0, 0, 0]).dim == 3


def test_sharp_tesseract_and_steiner_formula():
    f = F.tesseract(1.5)
    assert f.volume == pytest.approx(16 * 1.5**4)
    assert f.boundary_measure == pytest.approx(64 * 1.5**3)
    # a fully rounded cube is a ball: Steiner's sum must reduce to the ball formulas
    g = F.tesseract(1.0, 1.0 - 1e-12, dim=3)
    assert g.volume == pytest.approx(4 / 3 * math.pi, rel=1e-9)
    assert g.boundary_measure == pytest.approx(4 * math.pi, rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(
    plane=st.sampled_from([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3), (3, 0)]),
    angle=st.floats(-7.0, 7.0),
    seed=st.integers(0, 2**16),
)
def test_rotate_moves_points_with_the_shape(plane, angle, seed):
    rng = np.random.default_rng(seed)
    base = F.spheritorus(1.0, 0.4)
    rot = F.rotate(base, plane, angle)
    x = rng.normal(size=(64, 4))
    i, j = plane
    y = x.copy()  # rotate x by angle from axis i towards axis j
    y[:, i] = math.cos(angle) * x[:, i] - math.sin(angle) * x[:, j]
    y[:, j] = math.sin(angle) * x[:, i] + math.cos(angle) * x[:, j]
    np.testing.assert_allclose(rot(y), base(x), atol=1e-12)
    assert rot.volume == base.volume
    # the rotated extent still contains the rotated solid
    inside = rot(y) < 0
    assert np.all((y[inside] >= rot.extent[0] - 1e-12) & (y[inside] <= rot.extent[1] + 1e-12))


def test_rotation_by_quarter_turn_maps_axis_onto_axis():
    slab = F.Field(lambda p: np.abs(p[..., 0]) - 0.1, dim=4, name="slab")
    rot = F.rotate(slab, (0, 3), math.pi / 2)
    assert rot([0, 0, 0, 0.5]) == pytest.approx(0.4)
    assert rot([0.5, 0, 0, 0]) == pytest.approx(-0.1)


def test_translate_and_scale():
    rng = np.random.default_rng(3)
    base = F.torisphere(1.0, 0.4)
    off = np.array([0.3, -0.1, 0.2, 0.5])
    x = rng.normal(size=(100, 4))
    np.testing.assert_allclose(F.translate(base, off)(x + off), base(x), atol=1e-12)
    s = F.scale(base, 2.5)
    np.testing.assert_allclose(s(2.5 * x), 2.5 * base(x), rtol=1e-12)
    assert s.volume == pytest.approx(base.volume * 2.5**4)
    assert s.boundary_measure == pytest.approx(base.boundary_measure * 2.5**3)
    np.testing.assert_allclose(F.translate(base, off).extent, base.extent + off)


def test_csg_operations_pointwise():
    rng = np.random.default_rng(4)
    a, b = F.hypersphere(1.0), F.translate(F.hypersphere(0.8), [0.9, 0, 0, 0])
    x = rng.uniform(-2, 2, size=(5000, 4))
    fa, fb = a(x), b(x)
    np.testing.assert_array_equal(F.union(a, b)(x), np.minimum(fa, fb))
    np.testing.assert_array_equal(F.intersection(a, b)(x), np.maximum(fa, fb))
    np.testing.assert_array_equal(F.difference(a, b)(x), np.maximum(fa, -fb))
    k = 0.3
    sm = F.smooth_union(a, b, k)(x)
    assert np.all(sm <= np.minimum(fa, fb) + 1e-12)
    far = np.abs(fa - fb) >= k
    np.testing.assert_allclose(sm[far], np.minimum(fa, fb)[far], atol=1e-12)
    # the largest dip below min is k/4, reached where a == b
    assert np.min(sm - np.minimum(fa, fb)) >= -k / 4 - 1e-12


def test_metaball_alone_is_a_sphere_and_balls_blend():
    one = F.metaballs([[0.0, 0.0, 0.0, 0.0]], 0.7)
    assert one([0.7, 0, 0, 0]) == pytest.approx(0.0, abs=1e-12)
    assert one([0.0, 0, 0.69, 0]) < 0 < one([0.0, 0, 0.71, 0])
    two = F.metaballs([[-0.5, 0, 0, 0], [0.5, 0, 0, 0]], 0.45)
    assert two([0.0, 0, 0, 0]) < 0  # the gap between balls of radius 0.45 is filled


def test_gyroid_is_periodic_and_ground_is_a_half_space():
    rng = np.random.default_rng(5)
    g = F.gyroid(period=0.7, thickness=0.2)
    x = rng.normal(size=(500, 4))
    for k in range(4):
        shifted = x.copy()
        shifted[:, k] += 0.7
        np.testing.assert_allclose(g(shifted), g(x), atol=1e-9)
    floor = F.ground(-0.5, axis=1)
    assert floor([0, -1.0, 0, 0]) < 0 < floor([0, 0.0, 0, 0])


def test_sample_places_grid_points_on_both_bounds():
    coord = F.Field(lambda p: p[..., 0] + 10 * p[..., 1] + 100 * p[..., 2], dim=3, name="lin")
    v = ao4d.sample(coord, (3, 4, 5), ([0.0, -1.0, 2.0], [1.0, 2.0, 4.0]))
    i, j, k = np.meshgrid(np.arange(3), np.arange(4), np.arange(5), indexing="ij")
    x, y, z = i / 2, -1 + 3 * j / 3, 2 + 2 * k / 4
    np.testing.assert_allclose(v, x + 10 * y + 100 * z, atol=1e-12)
    # plain callables work with a tuple shape
    v2 = ao4d.sample(lambda p: p[..., 0], (2, 2), (0, 1))
    np.testing.assert_array_equal(v2, [[0, 0], [1, 1]])
    # C order on a page (a CPU device extracts it in place), whatever the field returns
    for values in (v, v2, ao4d.sample(F.hypersphere(1.0), 9, (-1, 1))):
        assert values.flags.c_contiguous and values.flags.writeable and values.dtype == np.float64
        assert values.ctypes.data % 4096 == 0


def test_sample_matches_direct_evaluation_across_blocks(monkeypatch):
    monkeypatch.setattr(F, "_POINTS_PER_BLOCK", 100)  # force many evaluation blocks
    f = F.tiger()
    axes = [np.linspace(-1.2, 1.2, n) for n in (5, 6, 7, 8)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    # linspace and lo + (hi - lo) i / (n - 1) may differ in the last bit
    np.testing.assert_allclose(ao4d.sample(f, (5, 6, 7, 8), (-1.2, 1.2)), f(pts), atol=1e-14)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: F.hypersphere(1.0)(np.zeros((5, 3))), ValueError, "`points` must have shape"),
        (lambda: F.hypersphere(-1.0), ValueError, "`radius`"),
        (lambda: F.Field(lambda p: np.zeros(3), dim=4, name="b")(np.zeros((5, 4))), ValueError, "returned"),
        (lambda: F.hypersphere(1.0, [0, 0, 0], dim=4), ValueError, "`center`"),
        (lambda: F.spheritorus(1.0, 1.5), ValueError, "`r` must be smaller"),
        (lambda: F.torisphere(0.0, 0.1), ValueError, "`R`"),
        (lambda: F.ditorus(1.0, 0.2, 0.3), ValueError, "r2 < r1"),
        (lambda: F.tiger(0.5, 0.8, 0.6), ValueError, "`r` must be smaller"),
        (lambda: F.tesseract(1.0, 1.0), ValueError, "`rounding`"),
        (lambda: F.indented_cube(1.0, 1.2), ValueError, "`indent`"),
        (lambda: F.metaballs([[0, 0, 0, 0]], [0.1, 0.2]), ValueError, "`radii`"),
        (lambda: F.rotate(F.hypersphere(1.0), (2, 2), 0.1), ValueError, "`plane`"),
        (lambda: F.rotate(F.hypersphere(1.0), (0, 4), 0.1), ValueError, "`plane`"),
        (lambda: F.union(F.hypersphere(1.0), F.hypersphere(1.0, dim=3)), ValueError, "mix dimensions"),
        (lambda: F.translate(F.hypersphere(1.0), [1, 2]), ValueError, "`offset`"),
        (lambda: F.scale(F.hypersphere(1.0), 0), ValueError, "`factor`"),
        (lambda: F.ground(0.0, axis=4), ValueError, "`axis`"),
        (lambda: F.preset("klein"), ValueError, "`shape` must be one of"),
        (lambda: ao4d.sample(F.hypersphere(1.0), 1, (-1, 1)), ValueError, "at least 2 points"),
        (lambda: ao4d.sample(F.hypersphere(1.0), (4, 4, 4), (-1, 1)), ValueError, "4 entries"),
        (lambda: ao4d.sample(F.hypersphere(1.0), 4, (1, -1)), ValueError, "lo < hi"),
        (lambda: ao4d.sample(F.hypersphere(1.0), 4, 1.0), ValueError, "`bounds` must be a pair"),
        (lambda: ao4d.sample(lambda p: p[..., 0], 4, (0, 1)), ValueError, "pass a tuple"),
        (lambda: ao4d.sample(lambda p: p[..., 0:2], (3, 3), (0, 1)), ValueError, "`field` returned"),
        (lambda: ao4d.sample("sphere", 4, (0, 1)), TypeError, "`field` must be callable"),
        (lambda: ao4d.sample(F.hypersphere(1.0), 10**5, (-1, 1)), MemoryError, "would need about"),
    ],
)
def test_bad_input_is_named(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_fields_carry_their_expression_tree_and_plain_callables_none():
    """Field.program (what ao4d.marching.fields_device evaluates on the device): every preset and
    combinator has one, with its parameters; any plain callable inside makes it None."""
    for name in F.PRESETS:
        prog = F.preset(name).program
        assert prog is not None and isinstance(prog[0], str), name
    assert F.spheritorus(1.0, 0.4).program == ("spheritorus", (1.0, 0.4), ())
    assert F.hypersphere(2.0, [1, 2, 3]).program == ("hypersphere", (2.0, 1.0, 2.0, 3.0), ())
    ball = F.hypersphere(1.0).program
    assert F.translate(F.hypersphere(1.0), [1, 0, 0, 0]).program == ("translate", (1.0, 0, 0, 0), (ball,))
    assert F.scale(F.hypersphere(1.0), 2.0).program == ("scale", (2.0,), (ball,))
    assert F.union(F.hypersphere(1.0), F.hypersphere(1.0)).program == ("union", (), (ball, ball))
    cube = F.indented_cube(1.0, 0.6)
    assert cube.program[0] == "difference" and cube.program[2][0][0] == "tesseract"

    def plain(p):
        return p[..., 0]

    assert F.Field(plain, dim=4, name="plain").program is None
    assert F.union(F.hypersphere(1.0), plain).program is None
    assert F.smooth_union(plain, F.hypersphere(1.0)).program is None
    assert F.rotate(plain, (0, 1), 0.3).program is None


# --------------------------------------------------------------------------- support functions

# Every constructor with a support, by what it promises: exact (tight) or a containing bound.
SUPPORTS_EXACT = {
    **ANALYTIC,
    "hypersphere_3d": F.hypersphere(0.6, [0.1, 0.2, -0.1]),
    "tesseract_2d": F.tesseract(0.7, 0.2, dim=2),
    "union": F.union(F.hypersphere(0.5, [0.4, 0, 0, 0]), F.tesseract(0.4, 0.1)),
    "translate": F.translate(F.tiger(0.6, 0.5, 0.2), [0.3, -0.2, 0.1, 0.4]),
    "rotate_translate_scale": F.rotate(
        F.translate(F.scale(F.duocylinder(0.7, 0.4), 1.3), [0.2, 0, 0, -0.1]), (0, 2), 1.1
    ),
}
SUPPORTS_BOUND = {
    "metaballs": F.metaballs([[-0.4, 0, 0, 0], [0.4, 0.1, 0, 0], [0, 0.5, 0, 0.2]], [0.4, 0.3, 0.35]),
    "intersection": F.intersection(F.hypersphere(0.8), F.tesseract(0.6)),
    "difference": F.difference(F.tesseract(0.7), F.hypersphere(0.5, [0.3, 0, 0, 0])),
    "gyroid_ball": F.preset("gyroid"),
}


def _support_check(field: F.Field, n: int, *, tight: bool, seed: int = 0) -> None:
    """The support against the field sampled on an n^d grid over its padded extent, in 64
    random unit directions u: no point with ``f <= 0`` lies beyond ``h(u)``; where ``tight``,
    some point with ``f <= r`` reaches ``h(u) - r``, r being the half diagonal of a cell (the
    fields are 1-Lipschitz, so every point of the solid has such a grid point that near)."""
    lo, hi = field.extent
    pad = 0.25 * (hi - lo)
    axes = F.grid_axes(n, (lo - pad, hi + pad), dim=field.dim)
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, field.dim)
    values = field(pts)
    u = np.random.default_rng(seed).standard_normal((64, field.dim))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    h = field.support(u)
    assert h.shape == (64,)
    inside = pts[values <= 0]
    assert len(inside) > 0
    assert np.all((inside @ u.T).max(axis=0) <= h + 1e-9)
    if tight:
        r = math.sqrt(sum(((a[1] - a[0]) / 2) ** 2 for a in axes))
        assert np.all((pts[values <= r] @ u.T).max(axis=0) >= h - r - 1e-9)


@pytest.mark.parametrize("name", sorted(SUPPORTS_EXACT))
def test_support_bounds_the_solid_and_is_tight_within_a_cell(name):
    field = SUPPORTS_EXACT[name]
    _support_check(field, {2: 400, 3: 60}.get(field.dim, 24), tight=True)


@pytest.mark.parametrize("name", sorted(SUPPORTS_BOUND))
def test_support_of_metaballs_and_cut_solids_bounds_them(name):
    _support_check(SUPPORTS_BOUND[name], 24, tight=False)


@settings(max_examples=15, deadline=None)
@given(
    name=st.sampled_from(["spheritorus", "torisphere", "ditorus", "tiger", "duocylinder", "tesseract_round"]),
    offset=st.lists(st.floats(-0.5, 0.5), min_size=4, max_size=4),
    factor=st.floats(0.5, 1.5),
    plane=st.sampled_from([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]),
    angle=st.floats(-math.pi, math.pi),
    seed=st.integers(0, 2**32 - 1),
)
def test_transformed_support_is_tight(name, offset, factor, plane, angle, seed):
    """translate, scale and rotate carry the support exactly, in any order."""
    field = F.translate(F.rotate(F.scale(ANALYTIC[name], factor), plane, angle), offset)
    _support_check(field, 16, tight=True, seed=seed)


def test_unbounded_and_unknown_solids_have_no_support():
    def plain(p):
        return np.linalg.norm(p, axis=-1) - 1.0

    assert F.gyroid().support is None and F.ground().support is None
    assert F.Field(plain, dim=4, name="plain").support is None
    assert F.union(F.hypersphere(1.0), plain).support is None
    assert F.translate(plain, [1, 0, 0, 0]).support is None
    assert F.smooth_union(F.hypersphere(1.0), F.hypersphere(0.5)).support is None
    # an intersection is bounded by its operands that have a support
    assert F.intersection(F.gyroid(), F.hypersphere(0.5)).support(np.eye(4)).tolist() == [0.5] * 4
    assert F.intersection(F.gyroid(), F.ground()).support is None
