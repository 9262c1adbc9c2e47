"""Tests for datasets_gen.families: support functions, fitted grids, and the tori items' accuracy.

The fitted grid of an item must contain the whole zero set (the field is positive on the grid
box's boundary) and be tight (each side one cell of margin from the solid's true extent). Both
are measured with the field itself, independently of the support functions: for a signed
distance field the minimum of ``f`` over a facet of the box is the distance from that facet's
plane to the solid (the solid lies inside the box, so its point nearest to the plane projects
into the facet), i.e. the gap between the grid's side and the solid's true extent.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ao4d import fields
from datasets_gen import load_config
from datasets_gen.config import sample_params
from datasets_gen.families import (
    MARGIN_CELLS,
    build_shape,
    fitted_grid,
    random_rotation,
    support_extent,
)
from datasets_gen.runner import item_seed

TORI = ("spheritorus", "torisphere", "ditorus", "tiger", "duocylinder")
# The bound on the volume error that tori.toml promises for its items (see its header).
VOLUME_TOLERANCE = 0.015


def _item(config, index: int, *, grid: int | None = None):
    """Build item ``index`` of ``config`` as datasets_gen.runner.make_item draws it (seed,
    parameters, rotation, the builder's generator), without AO or renders."""
    spec = config.items()[index]
    settings_ = dict(spec.family.settings)
    if grid is not None:
        settings_["grid"] = grid
    params_ss, rotation_ss, _ = item_seed(config.seed, index).spawn(3)
    rng = np.random.default_rng(params_ss)
    params = sample_params(spec.family.params, rng)
    rotation = random_rotation(np.random.default_rng(rotation_ss)) if settings_["rotation"] == "random" else None
    return build_shape(spec.family.kind, params, settings_, rng, rotation)


def _facets(bounds) -> list[tuple[int, int, float]]:
    """(axis, side, coordinate) of the 2d facets of the box ``bounds`` ([lo, hi])."""
    lo, hi = (np.asarray(b, dtype=float) for b in bounds)
    return [(k, side, float((lo, hi)[side][k])) for k in range(lo.size) for side in (0, 1)]


def _facet_points(bounds, axis: int, value: float, lo_f, hi_f, n: int) -> np.ndarray:
    """An n^(d-1) lattice on the facet ``x[axis] = value`` over the facet box [lo_f, hi_f]."""
    d = len(bounds[0])
    free = [k for k in range(d) if k != axis]
    axes = [np.linspace(lo_f[i], hi_f[i], n) for i in range(d - 1)]
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d - 1)
    pts = np.empty((mesh.shape[0], d))
    pts[:, free] = mesh
    pts[:, axis] = value
    return pts


def _facet_minimum(f, bounds, axis: int, value: float, *, n: int = 17, rounds: int = 8, keep: int = 64) -> float:
    """Minimum of a 1-Lipschitz ``f`` over a facet, by branch and bound on lattices.

    A lattice point p with spacing ``step`` cannot have a value below ``f(p) - step sqrt(3) / 2``
    in its cell, so only points within that of the best value are refined (the ``keep``
    lowest of them), each into a 5^3 lattice over its cell (spacing step / 4), clipped to the
    facet.
    """
    lo, hi = (np.asarray(b, dtype=float) for b in bounds)
    free = [k for k in range(lo.size) if k != axis]
    flo, fhi = lo[free], hi[free]
    pts = _facet_points(bounds, axis, value, flo, fhi, n)
    vals = f(pts)
    best = float(vals.min())
    step = float(np.max(fhi - flo)) / (n - 1)
    for _ in range(rounds):
        order = np.argsort(vals)[:keep]
        order = order[vals[order] <= best + step * math.sqrt(3) / 2]
        pts = np.concatenate(
            [
                _facet_points(bounds, axis, value, np.maximum(c - step / 2, flo), np.minimum(c + step / 2, fhi), 5)
                for c in pts[order][:, free]
            ]
        )
        vals = f(pts)
        best = min(best, float(vals.min()))
        step /= 4
    return best


def _side_gaps(f, grid: dict) -> np.ndarray:
    """(2, d) minimum of ``f`` over each facet of the grid box: [lower sides, upper sides]."""
    gaps = np.empty((2, len(grid["bounds"][0])))
    for axis, side, value in _facets(grid["bounds"]):
        gaps[side, axis] = _facet_minimum(f, grid["bounds"], axis, value)
    return gaps


def _expected_gaps(grid: dict) -> np.ndarray:
    """Gap between each side of the grid box and the fitted extent."""
    lo, hi = (np.asarray(b) for b in grid["bounds"])
    elo, ehi = (np.asarray(b) for b in grid["extent"])
    return np.stack([elo - lo, hi - ehi])


# --------------------------------------------------------------------------- support functions

# kind -> a valid parameter set made from three numbers in [0, 1)
_PARAMS = {
    "hypersphere": lambda a, b, c: {"radius": 0.3 + a, "center": [b - 0.5, 0.0, c, -0.2]},
    "spheritorus": lambda a, b, c: {"R": 0.6 + 0.4 * a, "r": 0.1 + 0.4 * b},
    "torisphere": lambda a, b, c: {"R": 0.6 + 0.4 * a, "r": 0.1 + 0.4 * b},
    "ditorus": lambda a, b, c: {"R": 1.0 + 0.3 * a, "r1": 0.3 + 0.2 * b, "r2": 0.1 + 0.15 * c},
    "tiger": lambda a, b, c: {"R1": 0.5 + 0.5 * a, "R2": 0.5 + 0.5 * b, "r": 0.1 + 0.3 * c},
    "duocylinder": lambda a, b, c: {"r1": 0.3 + a, "r2": 0.3 + b},
    "tesseract": lambda a, b, c: {"half": 0.5 + 0.5 * a, "rounding": 0.4 * b},
    "indented_cube": lambda a, b, c: {"half": 0.6 + 0.4 * a, "indent": 0.2 + 0.3 * b},
}


@pytest.mark.parametrize("kind", sorted(_PARAMS))
def test_support_gives_the_fields_axis_aligned_extent(kind):
    """Unrotated, the support's extent is the box ao4d.fields derives for the shape."""
    f = getattr(fields, kind)(**_PARAMS[kind](0.3, 0.6, 0.2))
    extent = support_extent(f.support)
    np.testing.assert_allclose(extent, f.extent, rtol=0, atol=1e-12)


@settings(max_examples=12, deadline=None)
@given(
    kind=st.sampled_from(sorted(_PARAMS)),
    a=st.floats(0, 0.999),
    b=st.floats(0, 0.999),
    c=st.floats(0, 0.999),
    seed=st.integers(0, 2**32 - 1),
)
def test_rotated_extent_is_exact(kind, a, b, c, seed):
    """For a random rotation, every side of a fitted grid is exactly its margin away from the
    rotated solid: the minimum of the signed distance over each facet is that gap."""
    args = _PARAMS[kind](a, b, c)
    q = random_rotation(np.random.default_rng(seed))
    f0 = getattr(fields, kind)(**args)
    extent = support_extent(f0.support, q)
    grid = fitted_grid(extent, 24)
    h = grid["spacing"][0]
    gaps = _side_gaps(lambda p: f0(p @ q), grid)
    # the search ends with lattice steps of 1e-5 cells; a wrong support is off by tenths of a
    # cell or more (a hundredth of a cell is far below it)
    np.testing.assert_allclose(gaps, _expected_gaps(grid), rtol=0, atol=0.01 * h)


# --------------------------------------------------------------------------- fitted grids


@settings(max_examples=50, deadline=None)
@given(
    lo=st.lists(st.floats(-3, 3), min_size=4, max_size=4),
    width=st.lists(st.floats(0.05, 4), min_size=4, max_size=4),
    n=st.integers(4, 80),
    padding=st.floats(0, 0.5),
)
def test_fitted_grid_has_cubic_cells_and_the_margin(lo, width, n, padding):
    lo, width = np.array(lo), np.array(width)
    extent = np.stack([lo, lo + width])
    grid = fitted_grid(extent, n, padding=padding)
    spacing = np.array(grid["spacing"])
    assert np.allclose(spacing, spacing[0], rtol=1e-9)  # cubic cells
    h = spacing[0]
    shape = np.array(grid["shape"])
    assert shape.max() == n and shape[np.argmax(width)] == n
    assert np.all(shape <= n)
    glo, ghi = (np.array(b) for b in grid["bounds"])
    np.testing.assert_allclose(ghi - glo, (shape - 1) * h, rtol=1e-9)
    # each side: padding/2 of the width, then at least MARGIN_CELLS and under MARGIN_CELLS + 1/2
    # cells (the rounding up to whole cells is split between the two sides)
    side = np.stack([lo - glo, ghi - (lo + width)]) - padding * width / 2
    assert np.all(side >= MARGIN_CELLS * h * (1 - 1e-9))
    assert np.all(side <= (MARGIN_CELLS + 0.5) * h * (1 + 1e-9))
    widest = np.argmax(width)
    np.testing.assert_allclose(side[:, widest], MARGIN_CELLS * h, rtol=1e-7)
    np.testing.assert_allclose(grid["extent"], extent)


@pytest.mark.parametrize(
    "extent, n, match",
    [
        ([[0, 0, 0, 0], [1, 1, 1, 1]], 3, "`grid` must exceed"),
        ([[0, 0, 0, 0], [1, 1, 0, 1]], 10, "not flat"),
        ([[0, 0, 0, 0], [1, np.inf, 1, 1]], 10, "finite"),
    ],
)
def test_fitted_grid_rejects(extent, n, match):
    with pytest.raises(ValueError, match=match):
        fitted_grid(extent, n)


def test_config_bounds_give_a_cube_grid():
    rng = np.random.default_rng(0)
    settings_ = {"grid": 9, "bounds": [-1.5, 1.5], "padding": 0.0, "method": "cubes"}
    shape = build_shape("hypersphere", {"radius": 1.0}, settings_, rng, random_rotation(rng))
    assert shape.grid["shape"] == [9] * 4 and shape.grid["extent"] is None
    assert shape.grid["bounds"] == [[-1.5] * 4, [1.5] * 4]


# --------------------------------------------------------------------------- the shipped configs

# every implicit family of the shipped configs, at a small grid: the fitted box holds the zero set
_IMPLICIT = [
    (name, index)
    for name in ("tori", "blobs", "thesis", "smoke")
    for index, spec in enumerate(load_config(name).items())
    if spec.family.kind != "lifted" and spec.number == 0
]


@pytest.mark.parametrize("name, index", _IMPLICIT)
def test_fitted_box_contains_the_zero_set(name, index):
    """The field is positive on a fine lattice of every facet of the grid box, and at least
    the margin (as a distance) for signed distance fields; the grid's sides sit their
    margin from the true extent (tori and thesis shapes are exact distances)."""
    shape = _item(load_config(name), index, grid=12)
    grid, f = shape.grid, shape.field
    exact = load_config(name).items()[index].family.kind in (*TORI, "hypersphere", "tesseract", "indented_cube")
    for axis, side, value in _facets(grid["bounds"]):
        lo, hi = (np.asarray(b) for b in grid["bounds"])
        free = [k for k in range(4) if k != axis]
        values = f(_facet_points(grid["bounds"], axis, value, lo[free], hi[free], 25))
        assert values.min() > 0, (axis, side)
    if exact:
        h = grid["spacing"][0]
        np.testing.assert_allclose(_side_gaps(f, grid), _expected_gaps(grid), rtol=0, atol=0.01 * h)
        assert np.all(_expected_gaps(grid) >= MARGIN_CELLS * h * (1 - 1e-9))
    assert shape.mesh.check().ok


def test_fitted_grids_of_rotated_tori_are_tight():
    """Each axis of a tori item's box is its solid's width plus 2 MARGIN to 2 MARGIN + 1 cells
    (the old cube over the rotated box's corners was 1.6-5.6 times the solid on some axis)."""
    config = load_config("tori")
    for index in range(0, 40, 4):
        grid = _item(config, index, grid=16).grid
        width = np.subtract(*grid["extent"][::-1])
        box = np.subtract(*grid["bounds"][::-1])
        cells = (box - width) / grid["spacing"][0]
        assert np.all(cells >= 2 * MARGIN_CELLS - 1e-9), (index, cells)
        assert np.all(cells <= 2 * MARGIN_CELLS + 1 + 1e-9), (index, cells)


def _volume_error(index: int, *, check: bool = False) -> float:
    """Relative 4-volume error of tori item ``index`` at its configured grid; ``check``: also
    assert the mesh is closed (a full check of these meshes takes longer than building them)."""
    shape = _item(load_config("tori"), index)
    if check:
        assert shape.mesh.check().ok
    return shape.mesh.volume / shape.volume_expected - 1.0


# the first spheritorus, torisphere and duocylinder in the default run (the ditori and tigers
# take 5-10 s each at their grids); all 40 items in the slow run
@pytest.mark.parametrize("index", [0, 8, 32])
def test_tori_volume_error_subset(index):
    assert abs(_volume_error(index)) <= VOLUME_TOLERANCE


@pytest.mark.slow
@pytest.mark.parametrize("index", range(40))
def test_tori_volume_error_every_item(index):
    assert abs(_volume_error(index, check=True)) <= VOLUME_TOLERANCE


def test_tori_config_sizes():
    """The families the volume tests cover are the five tori kinds, 8 items each."""
    config = load_config("tori")
    assert [(f.kind, f.count) for f in config.families] == [(k, 8) for k in TORI]
    assert all(f.settings["rotation"] == "random" and f.settings["bounds"] is None for f in config.families)
