"""Lights and the local shading terms of the 3D image of a 4D scene (pure numpy, no rays).

A :class:`Light` is directional (at infinity, given by the direction *towards* it) or a point light
(given by its position; no fall-off with distance). At a surface point with unit normal ``n``
(turned towards the viewer), unit direction ``l`` towards a light and unit direction ``v``
towards the eye, :mod:`ao4d.rendering.pipeline` adds per light

* the Lambert term ``max(0, n . l)`` (:func:`lambert`),
* the Blinn-Phong term ``max(0, n . h)^shininess`` with ``h = (l + v) / |l + v|``, only where
  ``n . l > 0`` (:func:`blinn_phong`),

both zero where a 4D shadow ray finds the light blocked, and multiplies the result by the depth
cue :func:`depth_cue` of the hit's distance along the view ray. Every vector here lives in R^4;
nothing is projected to 3D before shading.

References
----------
J. F. Blinn, "Models of light reflection for computer synthesized pictures", SIGGRAPH 1977,
doi:10.1145/563858.563893.
S. R. Hollasch, "Four-Space Visualization of 4D Objects", MSc thesis, Arizona State University,
1991 (4D ray tracing with specular highlights, shadows and depth cueing).
A. J. Hanson and P. A. Heng, "Illuminating the fourth dimension", IEEE CG&A 12(4), 1992,
doi:10.1109/38.144825.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._validate import as_array, as_real, as_vector

__all__ = ["Light", "as_lights", "lambert", "blinn_phong", "half_vectors", "depth_cue", "check_depth_cue"]


class Light:
    """A directional or point light with an RGB colour and an intensity.

    Parameters
    ----------
    direction : (4,) array_like, optional
        Direction *towards* a directional light (normalised here). Give this or ``position``.
    position : (4,) array_like, optional
        Position of a point light (no fall-off: intensity is the same at every distance).
    color : (3,) array_like of float
        RGB in [0, 1]; the light's colour tints diffuse and specular light in
        ``RenderResult.rgba`` (the grey ``shade`` uses ``intensity`` only).
    intensity : float
        Multiplies the light's diffuse and specular terms (>= 0).

    Raises
    ------
    ValueError
        Neither or both of ``direction`` and ``position``; a zero direction; a colour outside
        [0, 1]; a negative intensity; non-finite or wrongly shaped values.

    Examples
    --------
    >>> sun = Light(direction=[0, 1, 0, -1])
    >>> sun.kind, [round(float(x), 4) for x in sun.direction]
    ('directional', [0.0, 0.7071, 0.0, -0.7071])
    >>> Light(position=[0, 3, 0, 0], color=(1, 0.8, 0.6), intensity=0.5).kind
    'point'
    """

    __slots__ = ("direction", "position", "color", "intensity")

    def __init__(self, *, direction=None, position=None, color=(1.0, 1.0, 1.0), intensity: float = 1.0) -> None:
        if (direction is None) == (position is None):
            raise ValueError(
                "a Light needs exactly one of `direction` (directional light) and `position` (point light)"
            )
        if direction is not None:
            d = as_vector(direction, "direction", 4, scalar=False, nonzero=True)
            self.direction: np.ndarray | None = d / np.linalg.norm(d)
            self.position: np.ndarray | None = None
        else:
            self.direction = None
            self.position = as_vector(position, "position", 4, scalar=False)
        rgb = as_vector(color, "color", 3, scalar=False)
        if ((rgb < 0) | (rgb > 1)).any():
            raise ValueError(f"`color` must hold values in [0, 1], got {color!r}")
        self.color = rgb
        self.intensity = as_real(intensity, "intensity", ge=0)
        for value in (self.direction, self.position, self.color):
            if value is not None:
                value.setflags(write=False)

    @property
    def kind(self) -> str:
        """``"directional"`` or ``"point"``."""
        return "directional" if self.direction is not None else "point"

    @property
    def white(self) -> bool:
        """True for a white light of intensity 1 (today's ``light=`` direction)."""
        return self.intensity == 1.0 and bool((self.color == 1.0).all())

    def towards(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions from ``points`` to the light, and the distances to it.

        Parameters
        ----------
        points : (H, 4) float64
            The lit points.

        Returns
        -------
        to_light : (4,) or (H, 4) float64
            The light's direction for a directional light (one row for every point), else
            one unit row per point (zero where a point sits on the light).
        distance : (H,) float64
            ``inf`` for a directional light.
        """
        if self.direction is not None:
            return self.direction, np.full(len(points), np.inf)
        offset = self.position - points
        distance = np.linalg.norm(offset, axis=1)
        return offset / np.maximum(distance, 1e-300)[:, None], distance

    def __repr__(self) -> str:
        fmt = lambda v: "(" + ", ".join(f"{x:g}" for x in v) + ")"  # noqa: E731
        where = f"direction={fmt(self.direction)}" if self.direction is not None else f"position={fmt(self.position)}"
        return f"Light({where}, color={fmt(self.color)}, intensity={self.intensity:g})"


def as_lights(light: Any, name: str = "light") -> tuple[Light, ...]:
    """The lights meant by a ``light=`` argument.

    Parameters
    ----------
    light : None, (4,) array_like, Light, or sequence of Light or (4,) array_like
        ``None``: no light. A 4-vector: one white directional light of intensity 1 in that
        direction (what ``light=`` always meant). A :class:`Light`, or several.
    name : str
        Parameter name for error messages.

    Returns
    -------
    tuple of Light
        The lights, none for ``None``.
    """
    if light is None:
        return ()
    if isinstance(light, Light):
        return (light,)
    several = (isinstance(light, np.ndarray) and light.ndim == 2) or (
        isinstance(light, Sequence)
        and not isinstance(light, (str, bytes))
        and any(isinstance(item, Light) or np.ndim(item) >= 1 for item in light)
    )
    if several:
        return tuple(
            item
            if isinstance(item, Light)
            else Light(direction=as_vector(item, f"{name}[{i}]", 4, scalar=False, nonzero=True))
            for i, item in enumerate(light)
        )
    return (Light(direction=as_vector(light, name, 4, scalar=False, nonzero=True)),)


def _dot(normals: np.ndarray, to_light: np.ndarray) -> np.ndarray:
    # a single direction: a matrix-vector product (the renderer's historic arithmetic, so that
    # images without the new terms stay bit-identical); one row per point: row-wise dots
    if to_light.ndim == 1:
        return normals @ to_light
    return np.einsum("hd,hd->h", normals, to_light)


def lambert(normals: np.ndarray, to_light: np.ndarray) -> np.ndarray:
    """Lambert term ``max(0, n·l)``.

    Parameters
    ----------
    normals : (H, 4) float64
        Unit surface normals.
    to_light : (4,) or (H, 4) float64
        Unit directions towards the light.

    Returns
    -------
    (H,) float64 in [0, 1]
        The Lambert term.

    Examples
    --------
    >>> lambert(np.array([[0.0, 1, 0, 0], [0, -1, 0, 0]]), np.array([0.0, 0.6, 0, 0.8]))
    array([0.6, 0. ])
    """
    return np.clip(_dot(normals, to_light), 0.0, None)


def half_vectors(to_light: np.ndarray, to_eye: np.ndarray) -> np.ndarray:
    """Unit half-vectors ``h = (l + v) / |l + v|`` (zero where ``l = -v``).

    Parameters
    ----------
    to_light : (4,) or (H, 4) float64
        Unit directions towards the light.
    to_eye : (H, 4) float64
        Unit directions from the points towards the eye (``-`` the ray direction).

    Returns
    -------
    (H, 4) float64
        The half-vectors.
    """
    h = to_eye + to_light
    length = np.linalg.norm(h, axis=1, keepdims=True)
    return np.where(length > 1e-12, h / np.maximum(length, 1e-300), 0.0)


def blinn_phong(normals: np.ndarray, to_light: np.ndarray, to_eye: np.ndarray, shininess) -> np.ndarray:
    """Blinn-Phong specular term ``max(0, n·h)^shininess`` where ``n·l > 0``, else 0.

    Parameters
    ----------
    normals : (H, 4) float64
        Unit surface normals (facing the viewer).
    to_light : (4,) or (H, 4) float64
        Unit directions towards the light.
    to_eye : (H, 4) float64
        Unit directions towards the eye.
    shininess : float or (H,) array_like
        Exponent (> 0); larger is a smaller, sharper highlight.

    Returns
    -------
    (H,) float64 in [0, 1]
        1 where ``n = h``.

    Examples
    --------
    >>> n = np.array([[0.0, 1, 0, 0]])
    >>> l = np.array([0.0, 0.6, 0, 0.8]); v = np.array([[0.0, 0.6, 0, -0.8]])
    >>> blinn_phong(n, l, v, 50.0)  # mirror configuration: n = h
    array([1.])
    """
    cos_h = np.clip(np.einsum("hd,hd->h", normals, half_vectors(to_light, to_eye)), 0.0, None)
    lit = _dot(normals, to_light) > 0
    return np.where(lit, np.power(cos_h, shininess), 0.0)


def check_depth_cue(depth_cue: Any) -> tuple[float, float, float] | None:
    """``depth_cue`` as ``(near, far, strength)`` floats, ``None`` unchanged, else an error.

    ``0 <= near < far`` (``far`` finite) and ``0 <= strength <= 1``.

    Parameters
    ----------
    depth_cue : None or (3,) sequence of float
        ``(near, far, strength)``.

    Returns
    -------
    tuple of float or None
        ``(near, far, strength)``, or None.

    Raises
    ------
    ValueError
        If the values are out of range.
    """
    if depth_cue is None:
        return None
    values = as_array(depth_cue, "depth_cue", ndim=1, shape_tail=(3,), dtype=np.float64, finite=True)
    near, far, strength = (float(v) for v in values)
    if not 0 <= near < far:
        raise ValueError(
            f"`depth_cue` must be (near, far, strength) with 0 <= near < far, got near={near:g}, far={far:g}"
        )
    if not 0 <= strength <= 1:
        raise ValueError(f"`depth_cue` strength must be in [0, 1], got {strength:g}")
    return near, far, strength


def depth_cue(depth: np.ndarray, near: float, far: float, strength: float) -> np.ndarray:
    """Depth-cue factor: 1 up to ``near``, falling linearly to ``1 - strength`` at ``far``.

    ``f(t) = 1 - strength * clip((t - near) / (far - near), 0, 1)``, non-increasing in the 4D
    distance ``t`` along the view ray; colours are multiplied by it (fading towards black).

    Parameters
    ----------
    depth : (H,) float64
        Distances along the view rays.
    near, far, strength : float
        Where the fading starts and ends, and how much it takes away.

    Returns
    -------
    (H,) float64 in [1 - strength, 1]
        The factor.

    Examples
    --------
    >>> depth_cue(np.array([1.0, 3.0, 5.0, 9.0]), 2.0, 6.0, 0.5)
    array([1.   , 0.875, 0.625, 0.5  ])
    """
    return 1.0 - strength * np.clip((depth - near) / (far - near), 0.0, 1.0)
