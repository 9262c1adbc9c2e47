"""Front-to-back compositing: exact values, order, factors, and the callers that share it."""

import numpy as np
import pytest

from ao4d.rendering.compositing import over, unpremultiply


def test_two_layers_front_to_back_exact():
    acc = np.zeros((1, 4))
    over(acc, np.array([[1.0, 0.0, 0.0]]), np.array([0.5]))
    over(acc, np.array([[0.0, 0.0, 1.0]]), np.array([0.5]))
    # red takes half, blue half of what is left
    assert acc.tolist() == [[0.5, 0.0, 0.25, 0.75]]
    assert unpremultiply(acc)[0, 3] == 0.75
    assert np.allclose(unpremultiply(acc)[0, :3], [2 / 3, 0.0, 1 / 3])


def test_an_opaque_front_layer_hides_what_is_behind():
    acc = np.zeros((2, 3, 4))
    over(acc, np.full((2, 3, 3), 0.25), np.ones((2, 3)))
    over(acc, np.ones((2, 3, 3)), np.ones((2, 3)))
    assert np.array_equal(acc[..., :3], np.full((2, 3, 3), 0.25))
    assert np.array_equal(acc[..., 3], np.ones((2, 3)))


@pytest.mark.parametrize("seed", [0, 1])
def test_factors_are_multiplied_in_order_and_match_the_closed_form(seed):
    rng = np.random.default_rng(seed)
    colours, alphas, scale = rng.random((5, 7, 3)), rng.random((5, 7)), 0.9
    acc = np.zeros((7, 4))
    for c, a in zip(colours, alphas):
        over(acc, c, scale, a)
    # closed form: layer k's weight is a_k prod_{j<k} (1 - a_j)
    a = scale * alphas
    weights = a * np.cumprod(np.vstack([np.ones(7), 1 - a[:-1]]), axis=0)
    assert np.allclose(acc[:, :3], np.einsum("kn,knc->nc", weights, colours))
    assert np.allclose(acc[:, 3], 1 - np.prod(1 - a, axis=0))


def test_unpremultiply_of_nothing_is_transparent_black():
    assert unpremultiply(np.zeros((3, 4))).tolist() == [[0.0] * 4] * 3
