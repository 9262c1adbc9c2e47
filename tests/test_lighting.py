"""ao4d.rendering.lighting: lights and the shading terms against closed forms in R^4."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ao4d
from ao4d.rendering.lighting import Light, as_lights, blinn_phong, check_depth_cue, depth_cue, half_vectors, lambert

angles = st.floats(-1.5, 1.5, allow_nan=False, allow_subnormal=False)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(4, 4)))
    return q * np.sign(np.diag(r))


def test_light_kinds_and_normalisation():
    sun = Light(direction=[0, 3, 0, -4])
    assert sun.kind == "directional" and sun.white
    np.testing.assert_allclose(sun.direction, [0, 0.6, 0, -0.8])
    lamp = Light(position=[1, 2, 3, 4], color=(1, 0.5, 0), intensity=2)
    assert lamp.kind == "point" and not lamp.white
    assert ao4d.Light is Light
    with pytest.raises(ValueError, match="read-only"):
        sun.direction[0] = 1.0
    assert repr(lamp) == "Light(position=(1, 2, 3, 4), color=(1, 0.5, 0), intensity=2)"


def test_point_light_directions_and_distances():
    lamp = Light(position=[0, 3, 0, 0])
    points = np.array([[0.0, 0, 0, 0], [4, 3, 0, 0], [0, 3, 0, 0]])
    to_light, distance = lamp.towards(points)
    np.testing.assert_allclose(distance, [3, 4, 0])
    np.testing.assert_allclose(to_light, [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 0]])
    sun = Light(direction=[0, 0, 0, -2])
    to_sun, far = Light.towards(sun, points)
    np.testing.assert_array_equal(to_sun, [0, 0, 0, -1])
    assert np.isinf(far).all()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(), "exactly one of `direction`"),
        (dict(direction=[0, 1, 0, 0], position=[0, 0, 0, 0]), "exactly one of `direction`"),
        (dict(direction=[0, 0, 0, 0]), "`direction` must be a non-zero vector"),
        (dict(direction=[0, 1, 0]), "`direction` must have shape"),
        (dict(position=[0, np.nan, 0, 0]), "`position` contains 1 non-finite"),
        (dict(direction=[0, 1, 0, 0], color=(1, 2, 0)), r"`color` must hold values in \[0, 1\]"),
        (dict(direction=[0, 1, 0, 0], color=(1, 1)), "`color` must have shape"),
        (dict(direction=[0, 1, 0, 0], intensity=-1), "`intensity` must be >= 0"),
    ],
)
def test_bad_lights(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Light(**kwargs)


def test_as_lights_forms():
    assert as_lights(None) == ()
    (one,) = as_lights([0, 2, 0, 0])
    assert one.kind == "directional" and one.white
    np.testing.assert_array_equal(one.direction, [0, 1, 0, 0])
    lamp = Light(position=[0, 1, 0, 0])
    assert as_lights(lamp) == (lamp,)
    two = as_lights([lamp, [1, 0, 0, 0]])
    assert two[0] is lamp and two[1].kind == "directional"
    assert len(as_lights(np.eye(4)[:3])) == 3
    with pytest.raises(ValueError, match=r"`light\[1\]` must be a non-zero vector"):
        as_lights([lamp, [0, 0, 0, 0]])
    with pytest.raises(ValueError, match="`light` must have shape"):
        as_lights([0, 0, 1])


def test_lambert_closed_form():
    n = np.array([[0.0, 1, 0, 0]] * 3)
    l = np.array([[0.0, 0.6, 0, 0.8], [0.8, 0, -0.6, 0], [0, -1.0, 0, 0]])
    np.testing.assert_allclose(lambert(n, l), [0.6, 0, 0])
    # one direction for all points: the matrix-vector path gives the same numbers
    np.testing.assert_allclose(lambert(_unit(l), l[0]), np.clip(_unit(l) @ l[0], 0, None))


@settings(max_examples=60, deadline=None)
@given(a=angles, b=angles, s=st.floats(1.0, 80.0))
def test_blinn_phong_in_a_plane(a, b, s):
    # n = +y; l at angle a from n and v at angle b on the other side, both in the (y, w) plane:
    # l + v = 2 cos((a + b) / 2) (0, cos((a - b) / 2), 0, sin((a - b) / 2)), so n . h =
    # cos((a - b) / 2) and the term is cos((a - b) / 2)^s (n . l = cos a > 0 for |a| < pi / 2)
    n = np.array([[0.0, 1, 0, 0]])
    l = np.array([0.0, math.cos(a), 0, math.sin(a)])
    v = np.array([[0.0, math.cos(b), 0, -math.sin(b)]])
    assert blinn_phong(n, l, v, s)[0] == pytest.approx(math.cos((a - b) / 2) ** s, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), s=st.floats(1.0, 50.0))
def test_blinn_phong_is_rotation_invariant_and_lit_only(seed, s):
    rng = np.random.default_rng(seed)
    n, l, v = (_unit(rng.normal(size=(16, 4))) for _ in range(3))
    term = blinn_phong(n, l, v, s)
    rot = _rotation(rng)
    np.testing.assert_allclose(blinn_phong(n @ rot.T, l @ rot.T, v @ rot.T, s), term, atol=1e-9)
    assert (term[np.einsum("hd,hd->h", n, l) <= 0] == 0).all()
    assert term.min() >= 0 and term.max() <= 1 + 1e-12


def test_highlight_is_one_where_n_is_the_half_vector():
    rng = np.random.default_rng(5)
    l = _unit(rng.normal(size=(8, 4)))
    v = _unit(rng.normal(size=(8, 4)))
    v = np.where((np.einsum("hd,hd->h", l, v) > -0.9)[:, None], v, -v)
    h = half_vectors(l, v)
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), 1.0)
    np.testing.assert_allclose(blinn_phong(h, l, v, 200.0), 1.0)
    # opposite light and eye: no half-vector
    np.testing.assert_array_equal(half_vectors(l[:1], -l[:1]), 0.0)


def test_depth_cue_closed_form():
    t = np.array([0.0, 2.0, 3.0, 4.0, 6.0, 1e9])
    np.testing.assert_allclose(depth_cue(t, 2.0, 6.0, 0.8), [1, 1, 0.8, 0.6, 0.2, 0.2])
    assert check_depth_cue(None) is None
    assert check_depth_cue([1, 5, 0.5]) == (1.0, 5.0, 0.5)


@settings(max_examples=40, deadline=None)
@given(near=st.floats(0, 5), span=st.floats(0.01, 5), strength=st.floats(0, 1), seed=st.integers(0, 2**32 - 1))
def test_depth_cue_is_monotone(near, span, strength, seed):
    t = np.sort(np.random.default_rng(seed).uniform(0, 12, 50))
    f = depth_cue(t, near, near + span, strength)
    assert (np.diff(f) <= 1e-15).all()
    assert f.max() <= 1 and f.min() >= 1 - strength - 1e-12


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ([1, 2], "`depth_cue` must have shape"),
        ([3, 2, 0.5], "near < far"),
        ([-1, 2, 0.5], "0 <= near"),
        ([1, 2, 1.5], r"strength must be in \[0, 1\]"),
        ([1, np.inf, 0.5], "`depth_cue` contains 1 non-finite"),
    ],
)
def test_bad_depth_cue(value, match):
    with pytest.raises(ValueError, match=match):
        check_depth_cue(value)
