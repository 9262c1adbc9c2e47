"""Tests for ao4d._validate: every check names the parameter and says what it expected."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ao4d
from ao4d._validate import as_real, as_vector, check_bool, check_int, check_positive_int


@pytest.mark.parametrize(
    ("value", "error", "message"),
    [
        (np.nan, ValueError, "`x` must be finite"),
        (np.inf, ValueError, "`x` must be finite"),
        ("one", TypeError, "`x` must be a real number"),
        (None, TypeError, "`x` must be a real number"),
        (True, TypeError, "`x` must be a real number"),
        ([1.0], TypeError, "`x` must be a real number"),
    ],
)
def test_as_real_names_the_parameter(value, error, message):
    with pytest.raises(error, match=message):
        as_real(value, "x")
    assert as_real(np.float32(2.5), "x") == 2.5
    assert as_real(np.array(3), "x") == 3.0


@pytest.mark.parametrize(
    ("kwargs", "value", "message"),
    [
        (dict(gt=0), 0.0, r"`x` must be > 0, got 0.0"),
        (dict(ge=1), 0.5, r"`x` must be >= 1, got 0.5"),
        (dict(lt=2), 2, r"`x` must be < 2, got 2"),
        (dict(gt=0, lt=180, unit=" degrees"), 180, r"`x` must be in \(0, 180\) degrees"),
        (dict(ge=0, lt=1), -1, r"`x` must be in \[0, 1\)"),
        (dict(gt=0, le=1), 1.5, r"`x` must be in \(0, 1\]"),
        (dict(gt=0, finite=False), math.nan, r"`x` must be > 0"),
    ],
)
def test_as_real_bounds(kwargs, value, message):
    with pytest.raises(ValueError, match=message):
        as_real(value, "x", **kwargs)


def test_as_real_allows_infinity_when_asked():
    assert as_real(math.inf, "max_distance", finite=False, gt=0) == math.inf
    with pytest.raises(ValueError, match="must be a number"):
        as_real(math.nan, "x", finite=False)


def test_as_vector():
    np.testing.assert_array_equal(as_vector(2.0, "spacing", 3), [2.0, 2.0, 2.0])
    np.testing.assert_array_equal(as_vector([1, 2, 3, 4], "eye", 4, scalar=False), [1, 2, 3, 4])
    with pytest.raises(ValueError, match="`spacing` must be a scalar or have 4 entries, got 3"):
        as_vector([1, 1, 1], "spacing", 4)
    with pytest.raises(ValueError, match=r"`eye` must have shape \(\.\.\., 4\)"):
        as_vector([1, 1, 1], "eye", 4, scalar=False)
    with pytest.raises(ValueError, match="`spacing` must be > 0"):
        as_vector([1, 0, 1], "spacing", 3, positive=True)
    with pytest.raises(ValueError, match="`view` must be a non-zero vector"):
        as_vector([0, 0, 0, 0], "view", 4, nonzero=True)
    with pytest.raises(ValueError, match="`origin` contains 1 non-finite"):
        as_vector([0, np.nan], "origin", 2)


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64, np.complex128])
def test_check_finite_finds_every_bad_value_and_passes_large_finite_ones(dtype):
    """The fast sums (a dot product for contiguous float32/float64, numpy's sum otherwise) let
    no NaN or infinity through, in any layout; finite values whose squares or sum overflow take
    the exact test and pass."""
    from ao4d._validate import check_finite

    values = np.linspace(-1e3, 1e3, 99 * 101).astype(dtype).reshape(99, 101)
    for layout in (values, values.T, values[:, ::2], np.asfortranarray(values)):
        check_finite(layout, "x")
    for bad in (np.nan, np.inf, -np.inf):
        for where in ((0, 0), (50, 7), (98, 100)):
            damaged = values.copy()
            damaged[where] = bad
            for layout in (damaged, damaged.T, np.asfortranarray(damaged)):
                with pytest.raises(ValueError, match="`x` contains 1 non-finite value"):
                    check_finite(layout, "x")
    huge = np.finfo(dtype).max
    check_finite(np.full((7, 3), huge, dtype=dtype), "huge")
    check_finite(np.array([huge, -huge] * 5, dtype=dtype), "huge")
    check_finite(np.zeros((0, 4), dtype=dtype), "empty")


def test_integers_and_bools():
    assert check_int(-3, "seed") == -3 and check_positive_int(np.int64(4), "n") == 4
    with pytest.raises(TypeError, match="`seed` must be an integer"):
        check_int(1.5, "seed")
    with pytest.raises(ValueError, match="`n` must be >= 1, got 0"):
        check_positive_int(0, "n")
    assert check_bool(np.bool_(True), "closest") is True
    with pytest.raises(TypeError, match="`closest` must be True or False"):
        check_bool("yes", "closest")


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        # the parameter's name and the value, not float()'s message
        (lambda: ao4d.fields.hypersphere("big"), TypeError, "`radius` must be a real number, got str 'big'"),
        (lambda: ao4d.fields.spheritorus(1.0, "thin"), TypeError, "`r` must be a real number"),
        (lambda: ao4d.fields.tesseract(1.0, -0.1), ValueError, "`rounding` must be in"),
        (lambda: ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], fov="wide"), TypeError, "`fov` must be a real number"),
        (lambda: ao4d.Camera4D.framing([[-1] * 4, [1] * 4], margin="x"), TypeError, "`margin` must be a real"),
        (lambda: ao4d.scenes.extract_scene(ao4d.scenes.default_scene(), cell=0), ValueError, "`cell` must be > 0"),
    ],
)
def test_public_functions_name_the_parameter(call, error, match):
    with pytest.raises(error, match=match):
        call()
