"""Embedded scenes: the default demo scene (objects on a ground hyperplane) and its camera.

A :class:`Scene` is a list of named fields, each with the box it is extracted in, plus a camera
and a light. Each object is extracted separately (fine grids where it is, none where it is not)
and the meshes are joined so that every simplex knows its object id.

The default scene, in world units with y up: a ground slab (the 4D analogue of a floor: a thin
box spanning x, z and w), and resting on it a hypersphere, a torisphere lying flat (a circle of
3-balls: in every w-slice near 0 a 3D ring torus) and a tesseract with a round indent facing
the viewer. Contacts and the indent make ambient occlusion visible.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._validate import as_real, check_choice
from .rendering.camera import Camera4D

__all__ = ["SceneObject", "Scene", "default_scene", "box", "extract_scene", "QUALITY"]

# Settings per quality: grid cell size (world units), image shape (voxels along the image's x, y
# and z: the default scene's box, see default_scene's camera, in cubic voxels), AO samples.
QUALITY: dict[str, dict[str, Any]] = {
    "tiny": {"cell": 0.2, "image": (26, 10, 16), "samples": 8},
    "default": {"cell": 0.085, "image": (132, 48, 80), "samples": 64},
    "high": {"cell": 0.045, "image": (212, 76, 128), "samples": 128},
}


@dataclass(frozen=True)
class SceneObject:
    """One object: a field (negative inside) and the box ``(lo, hi)`` it is extracted in.

    The box must contain the solid with a margin, so that the extracted surface is closed.

    Attributes
    ----------
    name : str
        The object's name.
    field : callable
        ``(..., 4) -> (...)`` signed distance, negative inside.
    lo, hi : tuple of float
        The box the object is extracted in.
    coarseness : float
        Grid cell as a multiple of the scene's cell (flat objects need few).
    min_points : tuple of int
        Grid points per axis at least.
    min_step : float
        Never a finer grid than this.
    color : tuple of float
        RGB in [0, 1] (:func:`ao4d.render`'s ``color``).
    specular : float
        Blinn-Phong weight (:func:`ao4d.render`'s ``specular``).
    """

    name: str
    field: Callable[[np.ndarray], np.ndarray]
    lo: tuple[float, float, float, float]
    hi: tuple[float, float, float, float]
    coarseness: float = 1.0  # grid cell = coarseness * the scene's cell (flat objects need few)
    min_points: tuple[int, int, int, int] = (4, 4, 4, 4)  # grid points per axis at least
    min_step: float = 0.0  # never a finer grid than this (flat objects gain nothing from it)
    color: tuple[float, float, float] = (0.8, 0.8, 0.8)  # RGB in [0, 1] (ao4d.render `color`)
    specular: float = 0.0  # Blinn-Phong weight (ao4d.render `specular`)


@dataclass(frozen=True)
class Scene:
    """Objects (with colours and specular weights), a camera and a light (direction towards it).

    Attributes
    ----------
    name : str
        The scene's name.
    objects : tuple of SceneObject
        The objects, in object-id order.
    camera : Camera4D
        The view.
    light : (4,) float64 numpy.ndarray or None
        Unit direction towards the light.
    max_distance : float
        Reach of the AO rays.
    notes : dict
        Free-form notes.
    shininess : float
        Blinn-Phong exponent of every object.
    """

    name: str
    objects: tuple[SceneObject, ...]
    camera: Camera4D
    light: np.ndarray | None = None
    max_distance: float = math.inf
    notes: dict = field(default_factory=dict)
    shininess: float = 32.0  # Blinn-Phong exponent of every object

    @property
    def colors(self) -> np.ndarray:
        """(n_objects, 3) float64: the objects' RGB colours, in object-id order."""
        return np.array([obj.color for obj in self.objects], dtype=np.float64)

    @property
    def speculars(self) -> np.ndarray:
        """(n_objects,) float64: the objects' Blinn-Phong weights, in object-id order."""
        return np.array([obj.specular for obj in self.objects], dtype=np.float64)


def box(lo, hi) -> Callable[[np.ndarray], np.ndarray]:
    """Signed distance to the axis-aligned box ``[lo, hi]`` (any dimension).

    Parameters
    ----------
    lo, hi : (d,) array_like
        The box's corners.

    Returns
    -------
    callable
        ``(..., d) -> (...)`` exact Euclidean signed distance (negative inside).

    Examples
    --------
    >>> f = box([0, 0, 0, 0], [2, 1, 1, 1])
    >>> float(f(np.array([1.0, 0.5, 0.5, 0.5]))), float(f(np.array([3.0, 0.5, 0.5, 0.5])))
    (-0.5, 1.0)
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if lo.shape != hi.shape or lo.ndim != 1 or (hi <= lo).any():
        raise ValueError(f"`lo` and `hi` must be (d,) with lo < hi, got {lo} and {hi}")
    centre, half = (lo + hi) / 2, (hi - lo) / 2

    def distance(p: np.ndarray) -> np.ndarray:
        q = np.abs(np.asarray(p, dtype=np.float64) - centre) - half
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        return outside + np.minimum(q.max(axis=-1), 0.0)

    return distance


def _padded(lo, hi, pad: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    return tuple(float(x) - pad for x in lo), tuple(float(x) + pad for x in hi)


def default_scene() -> Scene:
    """The demo scene: hypersphere, torisphere and indented tesseract on a ground slab.

    Returns
    -------
    Scene
        Objects in the order ground, hypersphere, torisphere, indented tesseract (their
        object ids 0..3), a perspective camera looking along +w from above, and a light.
    """
    from . import fields

    # margin around each solid; an odd value keeps grid points off the surfaces (a grid point
    # exactly on a surface gives zero-measure tetrahedra, legal but useless for rendering)
    pad = 0.2637
    # the slab is flat: linear interpolation reproduces its faces exactly on a coarse grid
    ground_lo, ground_hi = (-2.7, -0.24, -1.7, -0.95), (2.7, 0.0, 1.7, 0.95)
    # (8 points across its thickness so that coarse settings keep it)
    ground = SceneObject(
        "ground",
        box(ground_lo, ground_hi),
        *_padded(ground_lo, ground_hi, pad),
        coarseness=1.6,
        min_points=(4, 8, 4, 4),
        min_step=0.1,
        color=(0.95, 0.93, 0.87),
    )

    r_sphere = 0.75
    c_sphere = np.array([-1.45, r_sphere, 0.35, 0.0])
    sphere = SceneObject(
        "hypersphere",
        fields.hypersphere(r_sphere, c_sphere),
        *_padded(c_sphere - r_sphere, c_sphere + r_sphere, pad),
        color=(0.95, 0.24, 0.17),
        specular=0.3,
    )

    # torisphere: core circle of radius R in the xy plane, swept 3-ball of radius r; turned
    # into the xz plane (lying flat), resting on the ground at y = 0
    big, small = 0.55, 0.24
    c_torus = np.array([0.15, small, -0.55, 0.0])
    torus_field = fields.translate(fields.rotate(fields.torisphere(big, small), (1, 2), math.pi / 2), c_torus)
    reach = np.array([big + small, small, big + small, small])
    torus = SceneObject(
        "torisphere",
        torus_field,
        *_padded(c_torus - reach, c_torus + reach, pad),
        color=(0.2, 0.55, 0.95),
        specular=0.3,
    )

    # tesseract of half side h with a round indent in its +z facet, which faces the viewer of
    # the 3D image (camera over = +z)
    half, indent = 0.55, 0.38
    c_cube = np.array([1.5, half, 0.25, 0.0])
    cube_field = fields.translate(fields.indented_cube(half, indent, axis=2), c_cube)
    cube = SceneObject(
        "indented tesseract",
        cube_field,
        *_padded(c_cube - half, c_cube + half, pad),
        color=(1.0, 0.78, 0.2),
        specular=0.3,
    )

    # fov 62 degrees across x: the image spans x in +-3.4 (the slab's near corners appear at
    # +-3.3, nearer the eye and larger); QUALITY's shapes give y +-1.24 and z +-2.06 in cubic voxels
    camera = Camera4D(
        eye=[0.0, 1.6, -0.6, -5.5], target=[0.0, 0.45, 0.0, 0.0], up=[0, 1, 0, 0], over=[0, 0, 1, 0], fov=62.0
    )
    light = np.array([-0.35, 1.0, -0.25, -0.45])
    return Scene("default", (ground, sphere, torus, cube), camera, light / np.linalg.norm(light), shininess=20.0)


def extract_scene(
    scene: Scene,
    *,
    cell: float = 0.085,
    method: str = "cubes",
    progress: bool | None = None,
) -> list:
    """Extract every object of ``scene`` on a grid of (about) ``cell`` world units.

    Parameters
    ----------
    scene : Scene
        The scene, e.g. :func:`default_scene`.
    cell : float
        Target grid spacing; each object's box gets ``ceil(extent / step) + 1`` points per
        axis with ``step = max(cell * coarseness, min_step)`` (at least the object's
        ``min_points``).
    method : {"cubes", "simplices"}
        Passed to :func:`ao4d.extract_field`.
    progress : bool, optional
        Passed to :func:`ao4d.extract_field`.

    Returns
    -------
    list of SimplexMesh
        One closed mesh per object, in scene order.
    """
    from .marching.march import extract_field

    cell = as_real(cell, "cell", gt=0)
    check_choice(method, "method", ("cubes", "simplices"))
    meshes = []
    for obj in scene.objects:
        lo, hi = np.asarray(obj.lo), np.asarray(obj.hi)
        step = max(cell * obj.coarseness, obj.min_step)
        shape = tuple(max(m, int(math.ceil((h - l) / step)) + 1) for l, h, m in zip(lo, hi, obj.min_points))
        meshes.append(extract_field(obj.field, shape, (lo, hi), method=method, progress=progress))
    return meshes
