"""A 4D camera whose image is a 3D grid of voxels (Hollasch's From/To/Up/Over viewing model).

The eye sits at ``eye`` and looks at ``target``. The image is a 3D grid of voxels lying in the
hyperplane through ``target`` perpendicular to the view direction; one primary ray goes through
each voxel centre. ``up`` tilts the image's second axis and ``over`` its third, exactly as a 3D
camera's up vector fixes the picture's vertical.

Basis (rows of :attr:`Camera4D.basis`): ``a``, ``b``, ``c`` (image axes x, y, z) and ``d`` (view
direction). It is orthonormal and positively oriented in the DESIGN.md determinant convention:
``det[a; b; c; d] = +1``, i.e. ``d`` is the normal of the image hyperplane in the sense of
``n . x = det[a; b; c; x]``. So a camera looking along +w with ``up = +y``, ``over = +z`` has image
axes +x, +y, +z: the rendered volume is oriented like a hyperplane slice ``w = const``.

References
----------
S. R. Hollasch, "Four-Space Visualization of 4D Objects", MSc thesis, Arizona State University,
1991, ch. 4 (4D viewing model and ray tracing). https://hollasch.github.io/ray4/
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._validate import as_array, as_real, as_vector, check_choice, check_memory, check_positive_int
from ..geometry import cross

__all__ = ["Camera4D", "ImageGeometry", "image_shape"]

# |sin| of the angle below which two directions count as parallel (about 0.06 degrees)
_PARALLEL_TOL = 1e-3


@dataclass(frozen=True)
class ImageGeometry:
    """Where the voxels of an image of a given shape sit, in image-hyperplane coordinates.

    Coordinate k of voxel ``(i, j, l)`` along image axis k is ``origin[k] + spacing * index_k``,
    measured from ``target`` along the basis vectors ``a``, ``b``, ``c`` (world units at the
    target distance). These are what volume files store as Offset/ElementSpacing.

    Attributes
    ----------
    shape : (3,) tuple of int
        Voxels along the image axes x, y, z.
    spacing : float
        Edge of the (cubic) voxels.
    origin : (3,) tuple of float
        Coordinates of voxel (0, 0, 0).
    """

    shape: tuple[int, int, int]
    spacing: float
    origin: tuple[float, float, float]


class Camera4D:
    """A 4D pinhole (or orthographic) camera producing a 3D image.

    Parameters
    ----------
    eye : (4,) array_like
        Eye position ("From").
    target : (4,) array_like
        Point looked at ("To"); the image hyperplane passes through it.
    up : (4,) array_like
        Direction that appears as the image's +y axis ("Up"); must not be parallel to the view
        direction.
    over : (4,) array_like
        Direction that appears as the image's +z axis ("Over"); must not lie in the plane of
        ``up`` and the view direction.
    fov : float
        Full viewing angle in degrees across the longest image axis, in (0, 180). For
        ``projection="orthographic"`` it only sets the default ``half_width``.
    projection : {"perspective", "orthographic"}
        Perspective rays start at the eye; orthographic rays are parallel to the view
        direction and start on the hyperplane through the eye.
    half_width : float, optional
        Half the image extent along its longest axis, in world units at the target. Default
        ``|target - eye| * tan(fov / 2)``, so both projections frame the target alike.

    Attributes
    ----------
    basis : (4, 4) float64
        Rows ``a, b, c, d``: image axes x, y, z and the view direction; orthonormal with
        ``det = +1``.

    Raises
    ------
    ValueError
        ``eye`` equal to ``target``; ``up`` or ``over`` (nearly) parallel to the view direction;
        ``over`` in the plane of ``up`` and the view direction (e.g. parallel to ``up``); a
        non-finite or wrongly shaped vector; ``fov`` or ``half_width`` out of range.

    References
    ----------
    S. R. Hollasch, "Four-Space Visualization of 4D Objects", MSc thesis, Arizona State
    University, 1991.

    Examples
    --------
    >>> cam = Camera4D([0, 0, 0, -4], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0])
    >>> bool(np.allclose(cam.basis, np.eye(4)))  # looking along +w: image axes are x, y, z
    True
    >>> origins, directions = cam.rays((8, 8, 8))
    >>> directions.shape
    (8, 8, 8, 4)
    """

    def __init__(
        self,
        eye,
        target,
        up=(0.0, 1.0, 0.0, 0.0),
        over=(0.0, 0.0, 1.0, 0.0),
        *,
        fov: float = 45.0,
        projection: Literal["perspective", "orthographic"] = "perspective",
        half_width: float | None = None,
    ) -> None:
        self.eye = as_vector(eye, "eye", 4, scalar=False)
        self.target = as_vector(target, "target", 4, scalar=False)
        up_v = as_vector(up, "up", 4, scalar=False)
        over_v = as_vector(over, "over", 4, scalar=False)
        self.projection = check_choice(projection, "projection", ("perspective", "orthographic"))
        self.fov = fov = as_real(fov, "fov", gt=0, lt=180, unit=" degrees")
        self.basis = _hollasch_basis(self.eye, self.target, up_v, over_v)
        self.up = up_v
        self.over = over_v
        self.distance = float(np.linalg.norm(self.target - self.eye))
        if half_width is None:
            half_width = self.distance * math.tan(math.radians(fov) / 2)
        self.half_width = as_real(half_width, "half_width", gt=0)

    @classmethod
    def framing(
        cls,
        bounds,
        *,
        view=(0.0, 0.0, 0.0, 1.0),
        up=(0.0, 1.0, 0.0, 0.0),
        over=(0.0, 0.0, 1.0, 0.0),
        fov: float = 40.0,
        projection: Literal["perspective", "orthographic"] = "perspective",
        margin: float = 1.1,
    ) -> Camera4D:
        """A camera looking along ``view`` at the centre of ``bounds`` with all of it in view.

        With ``e_k`` the box's half extent along image axis k and ``r`` its half extent along
        the view direction, the image half width is ``margin * max_k e_k`` plus, for
        perspective, ``r * tan(fov / 2)``, and the eye sits at ``margin * max_k e_k /
        tan(fov / 2) + r`` from the centre: the box's nearest face then still fits.

        Parameters
        ----------
        bounds : (2, 4) array_like
            ``(lo, hi)`` of what must be seen, e.g. ``mesh.bounds``.
        view : (4,) array_like
            View direction.
        up, over : (4,) array_like
            As in :class:`Camera4D`.
        fov : float
            As in :class:`Camera4D`.
        projection : {"perspective", "orthographic"}
            As in :class:`Camera4D`.
        margin : float
            Extra room around the object (>= 1).

        Returns
        -------
        Camera4D
            The camera.
        """
        box = as_array(bounds, "bounds", shape_tail=(2, 4), ndim=2, dtype=np.float64, finite=True)
        if (box[1] < box[0]).any():
            raise ValueError("`bounds` must be (lo, hi) with lo <= hi")
        margin = as_real(margin, "margin", ge=1)
        direction = as_vector(view, "view", 4, scalar=False, nonzero=True)
        direction /= np.linalg.norm(direction)
        centre = box.mean(axis=0)
        half = 0.5 * (box[1] - box[0])
        fov = as_real(fov, "fov", gt=0, lt=180, unit=" degrees")
        basis = cls(centre - direction, centre, up, over).basis  # depends on directions only
        lateral = max(float((np.abs(basis[:3]) @ half).max()), 1e-9) * margin
        along = float(np.abs(basis[3]) @ half)
        tan = math.tan(math.radians(fov) / 2)
        if projection == "orthographic":
            distance, half_width = lateral + along + 1.0, lateral
        else:
            distance, half_width = lateral / tan + along, lateral + along * tan
            if not distance < 1e150:  # the eye would sit where Camera4D refuses it, for fov's sake
                raise ValueError(
                    f"`fov` {fov:g} degrees is too narrow to frame the scene: the eye would sit "
                    f"{distance:.3g} from it; use a wider `fov` or give the eye"
                )
        return cls(
            centre - distance * direction, centre, up, over, fov=fov, projection=projection, half_width=half_width
        )

    # basis vectors by name
    @property
    def view(self) -> np.ndarray:
        """(4,) float64: unit view direction ``d``."""
        return self.basis[3]

    def __repr__(self) -> str:
        fmt = lambda v: "(" + ", ".join(f"{x:g}" for x in v) + ")"  # noqa: E731
        return (
            f"Camera4D(eye={fmt(self.eye)}, target={fmt(self.target)}, up={fmt(self.up)}, "
            f"over={fmt(self.over)}, fov={self.fov:g}, projection={self.projection!r}, "
            f"half_width={self.half_width:g})"
        )

    def geometry(self, shape) -> ImageGeometry:
        """Voxel spacing and origin of an image of ``shape`` in image-hyperplane coordinates.

        Voxels are cubes; the longest axis spans ``2 * half_width``, and the grid is centred on
        ``target``.

        Parameters
        ----------
        shape : (3,) tuple of int
            Voxels along the image axes x, y, z.

        Returns
        -------
        ImageGeometry
            Spacing and origin of the voxels.
        """
        shape = image_shape(shape)
        spacing = 2.0 * self.half_width / max(shape)
        origin = tuple(-0.5 * spacing * (n - 1) for n in shape)
        return ImageGeometry(shape=shape, spacing=spacing, origin=origin)

    def voxel_centers(self, shape) -> np.ndarray:
        """World positions of the voxel centres on the image hyperplane.

        Parameters
        ----------
        shape : (3,) tuple of int
            As for :meth:`geometry`.

        Returns
        -------
        centers : (nx, ny, nz, 4) float64
            ``target + u_x a + u_y b + u_z c`` with ``u`` from :meth:`geometry`.
        """
        geo = self.geometry(shape)
        check_memory(8 * 4 * 3 * math.prod(geo.shape), "camera rays for this image shape")
        axes = [o + geo.spacing * np.arange(n) for o, n in zip(geo.origin, geo.shape)]
        u = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)  # (nx, ny, nz, 3)
        return self.target + u @ self.basis[:3]

    def rays(self, shape) -> tuple[np.ndarray, np.ndarray]:
        """One primary ray per voxel centre.

        Parameters
        ----------
        shape : (3,) tuple of int
            Image size ``(nx, ny, nz)``.

        Returns
        -------
        origins : (nx, ny, nz, 4) float64
            The eye (perspective), or the voxel centre moved back to the eye's hyperplane
            (orthographic).
        directions : (nx, ny, nz, 4) float64
            Unit directions; each ray passes through its voxel centre at parameter
            ``t = |centre - origin|``.
        """
        centers = self.voxel_centers(shape)
        if self.projection == "orthographic":
            directions = np.broadcast_to(self.view, centers.shape).copy()
            origins = centers - self.distance * self.view
        else:
            origins = np.broadcast_to(self.eye, centers.shape).copy()
            directions = centers - self.eye
            directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        return origins, directions

    def project(self, points) -> np.ndarray:
        """Image-hyperplane coordinates ``(x, y, z)`` of world points (where they appear).

        Parameters
        ----------
        points : (..., 4) array_like
            Points in front of the eye.

        Returns
        -------
        coords : (..., 3) float64
            Coordinates along ``a, b, c`` on the image hyperplane, in the units of
            :meth:`geometry`; NaN for points not in front of the eye (perspective).
        """
        p = as_array(points, "points", shape_tail=(4,), dtype=np.float64)
        rel = p - self.eye
        depth = rel @ self.view
        lateral = rel @ self.basis[:3].T
        if self.projection == "orthographic":
            return lateral
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(depth > 0, self.distance / depth, np.nan)
        return lateral * scale[..., None]


def image_shape(shape) -> tuple[int, int, int]:
    """A 3D image's size as three positive ints, else an error naming ``shape``.

    Parameters
    ----------
    shape : (3,) sequence of int
        ``(nx, ny, nz)``, each at least 1.

    Returns
    -------
    tuple of int
        The same three numbers as ints.

    Examples
    --------
    >>> image_shape([4, 5, 6])
    (4, 5, 6)
    """
    try:
        items = tuple(shape)
    except TypeError:
        raise TypeError(f"`shape` must be a tuple of 3 integers, got {shape!r}") from None
    if len(items) != 3:
        raise ValueError(f"`shape` must have 3 entries (nx, ny, nz), got {len(items)}")
    return tuple(check_positive_int(n, "shape") for n in items)  # type: ignore[return-value]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _hollasch_basis(eye, target, up, over) -> np.ndarray:
    """Rows ``a, b, c, d``: orthonormal, ``det = +1``, ``b`` toward ``up``, ``c`` toward ``over``."""
    with np.errstate(over="ignore", invalid="ignore"):  # said below, in words
        view = target - eye
        dist = np.linalg.norm(view)
        scale = max(np.linalg.norm(eye), np.linalg.norm(target), 1.0)
    if not (np.isfinite(dist) and np.isfinite(scale)):
        # points 1e300 apart overflow the distance: say so, not "must differ"
        raise ValueError(
            "`eye` and `target` must lie within about 1e150 of the origin (their distances "
            f"overflow float64), got eye={eye.tolist()}, target={target.tolist()}"
        )
    if dist <= 1e-12 * scale:
        raise ValueError("`eye` and `target` must differ: the view direction is undefined")
    d = view / dist
    # only their directions count: scaled to a largest entry of 1 first, so that 1e300 entries
    # do not overflow the norm (and read as "parallel")
    up, over = (v / np.max(np.abs(v)) if np.any(v) else v for v in (up, over))
    for vec, name in ((up, "up"), (over, "over")):
        n = np.linalg.norm(vec)
        if n == 0:
            raise ValueError(f"`{name}` must be a non-zero vector")
        sin = np.linalg.norm(vec / n - (vec @ d) * d / n)
        if sin < _PARALLEL_TOL:
            raise ValueError(f"`{name}` is parallel to the view direction (target - eye)")
    u = up / np.linalg.norm(up)
    o = over / np.linalg.norm(over)
    # |cross(up, over, d)| is the 3-volume spanned; near zero means over lies in span(up, d)
    a_raw = cross(u, o, d)
    if np.linalg.norm(a_raw) < _PARALLEL_TOL:
        raise ValueError(
            "`over` lies in the plane spanned by `up` and the view direction (e.g. parallel "
            "to `up`); it must add a third independent direction"
        )
    # Hollasch's construction with repeated cross products: a is orthogonal to up, over and d;
    # b to over, d, a (the part of up the others leave free); c to d, a, b. Each line is fixed
    # by the cross product; the signs are chosen so that b follows up, c follows over and
    # det[a; b; c; d] = +1 (DESIGN.md: d = cross(a, b, c)).
    a = _unit(a_raw)
    b = _unit(cross(o, d, a))
    b = b if b @ u > 0 else -b
    c = _unit(cross(d, a, b))
    c = c if c @ o > 0 else -c
    if np.linalg.det(np.stack([a, b, c, d])) < 0:
        a = -a
    basis = np.stack([a, b, c, d])
    _check_basis(basis)
    return basis


def _check_basis(basis: np.ndarray) -> None:
    """The invariants every camera relies on; a failure here is a bug, not bad input."""
    gram_err = np.abs(basis @ basis.T - np.eye(4)).max()
    det = np.linalg.det(basis)
    if gram_err > 1e-9 or abs(det - 1.0) > 1e-9:
        raise RuntimeError(f"camera basis is not orthonormal/positive (err {gram_err}, det {det})")
