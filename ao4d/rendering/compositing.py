"""Front-to-back compositing ("over", Porter & Duff): the one place it is written.

Layers are added behind what is already accumulated, nearest first. The accumulator holds
premultiplied colour ``C`` and accumulated opacity ``A``; a layer of colour ``c`` (not
premultiplied) and opacity ``a`` adds::

    C += (1 - A) a c,    A += (1 - A) a

:func:`ao4d.render` composites the surfaces along each 4D ray with it, :mod:`ao4d.io.pictures`
the slices of a 3D image along an axis, and :func:`ao4d.browser.image_viewer.reference_march` the
samples of the page's ray-march.

References
----------
T. Porter and T. Duff, "Compositing digital images", SIGGRAPH 1984, doi:10.1145/800031.808606.
"""

from __future__ import annotations

import numpy as np

__all__ = ["over", "unpremultiply"]


def over(acc: np.ndarray, rgb: np.ndarray, *alphas: np.ndarray | float) -> None:
    """Add one layer behind what ``acc`` holds, in place.

    Parameters
    ----------
    acc : (..., 4) float64 numpy.ndarray
        Premultiplied colour and accumulated opacity so far (updated).
    rgb : (..., 3) float64 numpy.ndarray
        The layer's colour (not premultiplied).
    *alphas : (...) float64 numpy.ndarray or float
        The layer's opacity, as one value or as factors whose product it is (multiplied in
        the order given, after ``1 - A``: ``(1 - A) * a1 * a2``).

    Examples
    --------
    >>> acc = np.zeros((1, 4))
    >>> over(acc, np.array([[1.0, 0, 0]]), np.array([0.5]))   # red in front
    >>> over(acc, np.array([[0.0, 0, 1]]), np.array([0.5]))   # blue behind
    >>> acc.tolist()
    [[0.5, 0.0, 0.25, 0.75]]
    """
    weight = 1.0 - acc[..., 3]
    for alpha in alphas:
        weight = weight * alpha
    acc[..., :3] += weight[..., None] * rgb
    acc[..., 3] += weight


def unpremultiply(acc: np.ndarray) -> np.ndarray:
    """Straight colour and opacity of a premultiplied accumulator, colour clipped to [0, 1].

    Parameters
    ----------
    acc : (..., 4) float64 numpy.ndarray
        Premultiplied colour and accumulated opacity.

    Returns
    -------
    (..., 4) float64 numpy.ndarray
        ``C / A`` (0 where ``A = 0``) clipped to [0, 1], and ``A``.

    Examples
    --------
    >>> unpremultiply(np.array([[0.5, 0.0, 0.25, 0.75]])).round(4).tolist()
    [[0.6667, 0.0, 0.3333, 0.75]]
    """
    alpha = acc[..., 3:]
    out = np.empty_like(acc)
    out[..., :3] = np.clip(np.where(alpha > 0, acc[..., :3] / np.maximum(alpha, 1e-300), 0.0), 0, 1)
    out[..., 3] = alpha[..., 0]
    return out
