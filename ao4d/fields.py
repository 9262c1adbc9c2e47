"""Shape library: scalar fields on R^d (mostly d = 4), negative inside, and grid sampling.

A field is a callable taking an ``(..., d)`` array of points and returning an ``(...)`` array.
The fields built here are :class:`Field` objects: besides being callable they carry their
dimension, a bounding box of the solid (``extent``), its support function (``support``) and,
where a closed form exists, the enclosed
d-volume (``volume``) and the boundary (d-1)-volume (``boundary_measure``), which the tests use to
check extraction accuracy. Fields are signed distances, or bounds on them, in the sense of
sphere tracing [1]_; on four-space shapes and how to see them: [2]_.

Why this file is long: it is one module because it is one catalogue (each shape is a short
function with its closed-form volume and boundary measure, plus the combinators and ``sample``);
splitting the catalogue would only scatter shapes that are read and tested side by side.

Analytic values (derived with Pappus-type integrals; see each function's Notes):

==============  ====================================  ======================================
shape           enclosed 4-volume                     boundary 3-volume
==============  ====================================  ======================================
hypersphere     pi^2 r^4 / 2                          2 pi^2 r^3
spheritorus     4 pi^2 R^2 r^2 + pi^2 r^4             8 pi^2 R^2 r + 4 pi^2 r^3
torisphere      8/3 pi^2 R r^3                        8 pi^2 R r^2
ditorus         4 pi^3 R r1 r2^2                      8 pi^3 R r1 r2
tiger           4 pi^3 R1 R2 r^2                      8 pi^3 R1 R2 r
duocylinder     pi^2 r1^2 r2^2                        2 pi^2 r1 r2 (r1 + r2)
tesseract       16 h^4 (sharp; Steiner sum if round)  64 h^3 (sharp)
==============  ====================================  ======================================

References
----------
.. [1] J. C. Hart, "Sphere tracing: a geometric method for the antialiased ray tracing of
   implicit surfaces", The Visual Computer 12 (1996), doi:10.1007/s003710050084.
.. [2] S. R. Hollasch, "Four-space visualization of 4D objects", MSc thesis, Arizona State
   University (1991).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ._pages import aligned_empty
from ._validate import as_array, as_real, as_vector, check_memory, check_positive_int

__all__ = [
    "Field",
    "sample",
    "grid_axes",
    "hypersphere",
    "spheritorus",
    "torisphere",
    "ditorus",
    "tiger",
    "duocylinder",
    "tesseract",
    "indented_cube",
    "metaballs",
    "gyroid",
    "ground",
    "union",
    "intersection",
    "difference",
    "smooth_union",
    "translate",
    "scale",
    "rotate",
    "PRESETS",
    "preset",
]

# Points evaluated per call of a field while sampling a grid: bounds the temporary (..., d) array.
_POINTS_PER_BLOCK = 1 << 18

Support = Callable[[np.ndarray], np.ndarray]
"""A support function: ``(..., d)`` directions u -> ``(...)`` values, max over the solid of u . x."""


class Field:
    """A scalar field on R^d, negative inside the solid it describes.

    Parameters
    ----------
    func : callable
        Maps an ``(..., d)`` float64 array to an ``(...)`` array. Called only through
        :meth:`__call__`, which validates the points.
    dim : int or None
        Dimension d of the points, or ``None`` when the field works in any dimension.
    name : str
        Short description used by ``repr``.
    volume, boundary_measure : float, optional
        Analytic enclosed d-volume and boundary (d-1)-volume of the solid ``{f < 0}``.
    extent : (2, d) array_like, optional
        A box ``(lo, hi)`` containing the solid; ``None`` when unbounded or unknown.
    support : callable, optional
        The solid's support function ``h(u) = max over the solid of u . x``: ``(..., d)``
        directions to ``(...)`` values; exact for the primitives, an upper bound where a
        constructor says so (the solid then lies in ``{x : u . x <= h(u)}`` for every u, which
        is all a bound is used for); ``None`` when unbounded or unknown. Rotated solids take
        their extents from it (``Field.extent`` is a box, loose under rotation).
    program : tuple, optional
        The same field as a small expression tree ``(op, params, children)`` that
        ``ao4d.marching.fields_device`` evaluates in an OpenCL kernel with ``func``'s operations;
        ``None`` (any other callable): sampled on the host only.
    """

    __slots__ = ("_func", "dim", "name", "volume", "boundary_measure", "extent", "support", "program")

    def __init__(
        self,
        func: Callable[[np.ndarray], np.ndarray],
        *,
        dim: int | None,
        name: str,
        volume: float | None = None,
        boundary_measure: float | None = None,
        extent: Any = None,
        support: Support | None = None,
        program: tuple | None = None,
    ) -> None:
        self._func = func
        self.support = support
        self.program = program
        self.dim = dim
        self.name = name
        self.volume = None if volume is None else float(volume)
        self.boundary_measure = None if boundary_measure is None else float(boundary_measure)
        self.extent = None if extent is None else np.array(extent, dtype=float).reshape(2, -1)
        if self.extent is not None:
            self.extent.setflags(write=False)

    def __call__(self, points: Any) -> np.ndarray:
        """Evaluate the field at ``points``.

        Parameters
        ----------
        points : (..., d) array_like
            Points in R^d (d must match the field's ``dim`` when it has one).

        Returns
        -------
        (...) float64 ndarray
            The field's value at each point.

        Raises
        ------
        ValueError
            If ``points`` has the wrong last axis, or the function returns a wrong shape.
        """
        pts = as_array(points, "points", dtype=np.float64)
        if pts.ndim == 0 or (self.dim is not None and pts.shape[-1] != self.dim):
            want = "d" if self.dim is None else str(self.dim)
            raise ValueError(f"`points` must have shape (..., {want}), got {pts.shape}")
        out = np.asarray(self._func(pts), dtype=np.float64)
        if out.shape == pts.shape[:-1]:
            return out
        try:  # constant parts (e.g. a scalar) broadcast to the points' shape
            return np.broadcast_to(out, pts.shape[:-1])
        except ValueError:
            raise ValueError(f"field {self.name} returned shape {out.shape} for points {pts.shape}") from None

    def __repr__(self) -> str:
        return f"<Field {self.name} dim={self.dim}>"


def _dim_of(field: Any) -> int | None:
    return getattr(field, "dim", None)


def _common_dim(fields: Sequence[Any]) -> int | None:
    dims = {d for d in map(_dim_of, fields) if d is not None}
    if len(dims) > 1:
        raise ValueError(f"`fields` mix dimensions {sorted(dims)}")
    return dims.pop() if dims else None


def _extent_of(field: Any) -> np.ndarray | None:
    return getattr(field, "extent", None)


def _support_of(field: Any) -> Support | None:
    return getattr(field, "support", None)


def _program(op: str, params: Sequence[float], *children: Any) -> tuple | None:
    """A field's expression tree for ``ao4d.marching.fields_device``: ``(op, params, children)``, the
    children being the operands' trees; ``None`` when an operand has none (a plain callable)."""
    kids = tuple(getattr(c, "program", None) for c in children)
    if any(k is None for k in kids):
        return None
    return (op, tuple(float(x) for x in params), kids)


def _named(op: str, **params: float) -> dict[str, Any]:
    """A primitive's ``name`` (``"tiger(R1=0.8, R2=0.8, r=0.35)"``) and ``program`` (its
    expression tree), both from the one list of its parameters."""
    text = ", ".join(f"{key}={value:g}" for key, value in params.items())
    return {"name": f"{op}({text})", "program": _program(op, tuple(params.values()))}


def _ball_volume(dim: int, radius: float) -> float:
    return math.pi ** (dim / 2) / math.gamma(dim / 2 + 1) * radius**dim


def _norm(points: np.ndarray, axes: slice | list[int]) -> np.ndarray:
    sub = points[..., axes]
    return np.sqrt(np.einsum("...i,...i->...", sub, sub))


# --------------------------------------------------------------------------------------------
# primitives
# --------------------------------------------------------------------------------------------


def hypersphere(radius: float = 1.0, center: Any = 0.0, *, dim: int | None = None) -> Field:
    """Ball of ``radius`` about ``center`` as a signed distance ``|x - c| - r``.

    Parameters
    ----------
    radius : float
        Radius r > 0.
    center : float or (d,) array_like
        Center; a scalar is broadcast to every axis.
    dim : int, optional
        Dimension d; defaults to ``len(center)`` or 4.

    Returns
    -------
    Field
        ``volume`` = pi^(d/2) r^d / Gamma(d/2 + 1) (pi^2 r^4 / 2 in 4D) and
        ``boundary_measure`` = d volume / r (2 pi^2 r^3 in 4D).

    Examples
    --------
    >>> f = hypersphere(2.0)
    >>> float(f([2.0, 0, 0, 0]))
    0.0
    """
    r = as_real(radius, "radius", gt=0)
    c_arr = np.asarray(center, dtype=float)
    if dim is None:
        dim = c_arr.shape[0] if c_arr.ndim == 1 else 4
    dim = check_positive_int(dim, "dim")
    c = as_vector(center, "center", dim)
    vol = _ball_volume(dim, r)
    return Field(
        lambda p: _norm(p - c, slice(None)) - r,
        dim=dim,
        name=f"hypersphere(r={r:g})",
        volume=vol,
        boundary_measure=dim * vol / r,
        extent=(c - r, c + r),
        support=lambda u: r * _norm(u, slice(None)) + u @ c,
        program=_program("hypersphere", (r, *c)),
    )


def spheritorus(R: float = 1.0, r: float = 0.4) -> Field:
    """Spheritorus ``(sqrt(x^2 + y^2 + z^2) - R)^2 + w^2 = r^2`` (a 2-sphere swept disk).

    Parameters
    ----------
    R, r : float
        Major radius R (distance from the origin to the core 2-sphere) and minor radius r < R.

    Returns
    -------
    Field
        Exact signed distance to the surface; ``volume = 4 pi^2 R^2 r^2 + pi^2 r^4`` and
        ``boundary_measure = 8 pi^2 R^2 r + 4 pi^2 r^3``; ``support`` the Minkowski sum's
        (2-sphere of radius R in xyz plus an r-ball: supports add), ``R |u_xyz| + r |u|``.

    Notes
    -----
    In coordinates (rho = \\|(x, y, z)\\|, w) the solid is the disk (rho - R)^2 + w^2 <= r^2 swept
    by 2-spheres of area 4 pi rho^2. With rho = R + u the 4-volume is
    ``4 pi * int_disk (R + u)^2 = 4 pi (pi R^2 r^2 + pi r^4 / 4) = 4 pi^2 R^2 r^2 + pi^2 r^4``
    and the boundary 3-volume ``4 pi * int_0^2pi (R + r cos t)^2 r dt = 8 pi^2 R^2 r + 4 pi^2 r^3``.
    """
    R, r = as_real(R, "R", gt=0), as_real(r, "r", gt=0)
    if r >= R:
        raise ValueError(f"`r` must be smaller than `R` (got r={r:g}, R={R:g})")
    a = R + r
    return Field(
        lambda p: np.hypot(_norm(p, slice(0, 3)) - R, p[..., 3]) - r,
        dim=4,
        volume=4 * math.pi**2 * R**2 * r**2 + math.pi**2 * r**4,
        boundary_measure=8 * math.pi**2 * R**2 * r + 4 * math.pi**2 * r**3,
        extent=([-a, -a, -a, -r], [a, a, a, r]),
        support=lambda u: R * _norm(u, slice(0, 3)) + r * _norm(u, slice(None)),
        **_named("spheritorus", R=R, r=r),
    )


def torisphere(R: float = 1.0, r: float = 0.4) -> Field:
    """Torisphere ``(sqrt(x^2 + y^2) - R)^2 + z^2 + w^2 = r^2`` (a circle swept 3-ball).

    Parameters
    ----------
    R, r : float
        Radius R of the core circle in the xy plane and radius r < R of the swept ball.

    Returns
    -------
    Field
        Exact signed distance to the surface; ``volume = 8/3 pi^2 R r^3`` and
        ``boundary_measure = 8 pi^2 R r^2``; ``support`` (circle plus ball) ``R |u_xy| + r |u|``.

    Notes
    -----
    In (rho = \\|(x, y)\\|, z, w) the solid is a 3-ball of radius r centred at rho = R, swept by
    circles of length 2 pi rho. Pappus (centroid at rho = R): 4-volume
    ``2 pi R * 4/3 pi r^3 = 8/3 pi^2 R r^3``, boundary 3-volume ``2 pi R * 4 pi r^2 = 8 pi^2 R r^2``.
    """
    R, r = as_real(R, "R", gt=0), as_real(r, "r", gt=0)
    if r >= R:
        raise ValueError(f"`r` must be smaller than `R` (got r={r:g}, R={R:g})")
    a = R + r
    return Field(
        lambda p: np.sqrt((_norm(p, slice(0, 2)) - R) ** 2 + p[..., 2] ** 2 + p[..., 3] ** 2) - r,
        dim=4,
        volume=8 / 3 * math.pi**2 * R * r**3,
        boundary_measure=8 * math.pi**2 * R * r**2,
        extent=([-a, -a, -r, -r], [a, a, r, r]),
        support=lambda u: R * _norm(u, slice(0, 2)) + r * _norm(u, slice(None)),
        **_named("torisphere", R=R, r=r),
    )


def ditorus(R: float = 1.0, r1: float = 0.45, r2: float = 0.2) -> Field:
    """Ditorus ``(sqrt((sqrt(x^2 + y^2) - R)^2 + z^2) - r1)^2 + w^2 = r2^2``.

    Parameters
    ----------
    R, r1, r2 : float
        Major radius R, radius r1 of the 3D torus tube, and radius r2 of the swept disk;
        requires r1 + r2 < R and r2 < r1.

    Returns
    -------
    Field
        Exact signed distance to the surface; ``volume = 4 pi^3 R r1 r2^2`` and
        ``boundary_measure = 8 pi^3 R r1 r2``; ``support`` ``R |u_xy| + r1 |u_xyz| + r2 |u|``.

    Notes
    -----
    With rho = \\|(x, y)\\|, (rho - R, z) = q (cos phi, sin phi), the volume element is
    ``2 pi rho q dq dphi dw`` with rho = R + q cos phi; the cos phi term integrates to 0.
    The solid is the disk (q - r1)^2 + w^2 <= r2^2, so the 4-volume is
    ``4 pi^2 R * int_disk q = 4 pi^2 R * r1 * pi r2^2 = 4 pi^3 R r1 r2^2`` and the boundary
    3-volume ``4 pi^2 R * int_circle q ds = 4 pi^2 R * r1 * 2 pi r2 = 8 pi^3 R r1 r2``.
    The solid is the 3D torus surface T (R, r1) in w = 0 grown by an r2-ball. T's support is
    ``max_phi [R a + r1 sqrt(a^2 + u_z^2)]`` with ``a = u_xy . (cos phi, sin phi)``, largest at
    ``a = |u_xy|``: ``R |u_xy| + r1 |u_xyz|``.
    """
    R, r1, r2 = as_real(R, "R", gt=0), as_real(r1, "r1", gt=0), as_real(r2, "r2", gt=0)
    if not (r2 < r1 and r1 + r2 < R):
        raise ValueError(f"need r2 < r1 and r1 + r2 < R (got R={R:g}, r1={r1:g}, r2={r2:g})")

    def f(p: np.ndarray) -> np.ndarray:
        q = np.hypot(_norm(p, slice(0, 2)) - R, p[..., 2])
        return np.hypot(q - r1, p[..., 3]) - r2

    a, b = R + r1 + r2, r1 + r2
    return Field(
        f,
        dim=4,
        volume=4 * math.pi**3 * R * r1 * r2**2,
        boundary_measure=8 * math.pi**3 * R * r1 * r2,
        extent=([-a, -a, -b, -r2], [a, a, b, r2]),
        support=lambda u: R * _norm(u, slice(0, 2)) + r1 * _norm(u, slice(0, 3)) + r2 * _norm(u, slice(None)),
        **_named("ditorus", R=R, r1=r1, r2=r2),
    )


def tiger(R1: float = 0.8, R2: float = 0.8, r: float = 0.35) -> Field:
    """Tiger ``(sqrt(x^2 + y^2) - R1)^2 + (sqrt(z^2 + w^2) - R2)^2 = r^2``.

    Parameters
    ----------
    R1, R2 : float
        Radii of the two core circles (xy and zw planes).
    r : float
        Tube radius, r < min(R1, R2).

    Returns
    -------
    Field
        Exact signed distance to the surface; ``volume = (2 pi R1) (2 pi R2) (pi r^2)`` and
        ``boundary_measure = (2 pi R1) (2 pi R2) (2 pi r)``: the two core circles times the tube's
        disk and circle; ``support`` (the flat torus, two circles in the xy and zw planes, plus
        an r-ball) ``R1 |u_xy| + R2 |u_zw| + r |u|``.

    Notes
    -----
    In (rho1, rho2) the solid is a disk of radius r about (R1, R2), swept by the torus of
    circles with area element ``(2 pi rho1)(2 pi rho2)``; the cross terms vanish over the disk:
    4-volume ``4 pi^2 R1 R2 pi r^2 = 4 pi^3 R1 R2 r^2``, boundary ``8 pi^3 R1 R2 r``.
    """
    R1, R2, r = as_real(R1, "R1", gt=0), as_real(R2, "R2", gt=0), as_real(r, "r", gt=0)
    if r >= min(R1, R2):
        raise ValueError(f"`r` must be smaller than `R1` and `R2` (got r={r:g})")
    a, b = R1 + r, R2 + r
    return Field(
        lambda p: np.hypot(_norm(p, slice(0, 2)) - R1, _norm(p, slice(2, 4)) - R2) - r,
        dim=4,
        volume=4 * math.pi**3 * R1 * R2 * r**2,
        boundary_measure=8 * math.pi**3 * R1 * R2 * r,
        extent=([-a, -a, -b, -b], [a, a, b, b]),
        support=lambda u: R1 * _norm(u, slice(0, 2)) + R2 * _norm(u, slice(2, 4)) + r * _norm(u, slice(None)),
        **_named("tiger", R1=R1, R2=R2, r=r),
    )


def duocylinder(r1: float = 1.0, r2: float = 1.0) -> Field:
    """Duocylinder: product of the disks ``x^2 + y^2 <= r1^2`` and ``z^2 + w^2 <= r2^2``.

    Parameters
    ----------
    r1, r2 : float
        Radii of the two disks.

    Returns
    -------
    Field
        Exact signed distance (the boundary has a sharp ridge, a flat 2-torus).
        ``volume = pi^2 r1^2 r2^2``; ``boundary_measure = 2 pi^2 r1 r2 (r1 + r2)``
        (two solid tori: circle 2 pi r1 times disk pi r2^2, and vice versa); ``support`` (the
        product of two disks is their Minkowski sum) ``r1 |u_xy| + r2 |u_zw|``.
    """
    r1, r2 = as_real(r1, "r1", gt=0), as_real(r2, "r2", gt=0)

    def f(p: np.ndarray) -> np.ndarray:
        a = _norm(p, slice(0, 2)) - r1
        b = _norm(p, slice(2, 4)) - r2
        return np.minimum(np.maximum(a, b), 0.0) + np.hypot(np.maximum(a, 0.0), np.maximum(b, 0.0))

    return Field(
        f,
        dim=4,
        volume=math.pi**2 * r1**2 * r2**2,
        boundary_measure=2 * math.pi**2 * r1 * r2 * (r1 + r2),
        extent=([-r1, -r1, -r2, -r2], [r1, r1, r2, r2]),
        support=lambda u: r1 * _norm(u, slice(0, 2)) + r2 * _norm(u, slice(2, 4)),
        **_named("duocylinder", r1=r1, r2=r2),
    )


def _box_distance(p: np.ndarray, half: float) -> np.ndarray:
    q = np.abs(p) - half
    outside = np.sqrt(np.einsum("...i,...i->...", np.maximum(q, 0.0), np.maximum(q, 0.0)))
    return outside + np.minimum(q.max(axis=-1), 0.0)


def tesseract(half: float = 1.0, rounding: float = 0.0, *, dim: int = 4) -> Field:
    """Axis-aligned hypercube ``[-half, half]^d``, optionally with rounded edges.

    Parameters
    ----------
    half : float
        Half the side length h.
    rounding : float
        Radius rho in [0, half) of the rounding: the solid is the cube of half side
        ``h - rho`` grown by a ball of radius rho (same outer size as the sharp cube).
    dim : int
        Dimension d.

    Returns
    -------
    Field
        Exact signed distance. ``volume`` and ``boundary_measure`` follow Steiner's formula:
        with a = h - rho, the cube has C(d,k) 2^k faces of dimension d-k, each of
        (d-k)-volume (2a)^(d-k) with an orthant (1/2^k) of a k-ball as normal cone, so
        ``V = sum_k C(d,k) (2a)^(d-k) omega_k rho^k`` (omega_k: unit k-ball volume) and the
        boundary is dV/drho; the sharp 4-cube gives 16 h^4 and 64 h^3. ``support`` (the cube
        plus a rho-ball) ``a |u|_1 + rho |u|``.
    """
    h = as_real(half, "half", gt=0)
    rho = as_real(rounding, "rounding", ge=0, lt=h, unit=" (`half`)")
    dim = check_positive_int(dim, "dim")
    a = h - rho
    terms = [(math.comb(dim, k) * (2 * a) ** (dim - k), _ball_volume(k, 1.0), k) for k in range(dim + 1)]
    vol = sum(c * w * rho**k for c, w, k in terms)
    area = sum(c * w * k * rho ** (k - 1) for c, w, k in terms if k > 0)
    return Field(
        lambda p: _box_distance(p, a) - rho,
        dim=dim,
        name=f"tesseract(half={h:g}, rounding={rho:g})",
        volume=vol,
        boundary_measure=area,
        extent=(np.full(dim, -h), np.full(dim, h)),
        support=lambda u: a * np.abs(u).sum(axis=-1) + rho * _norm(u, slice(None)),
        program=_program("tesseract", (a, rho, dim)),
    )


def indented_cube(half: float = 1.0, indent: float = 0.6, *, axis: int = 3) -> Field:
    """The thesis' "cube-like structure with an indent": a tesseract with a spherical dent.

    A ball of radius ``indent`` centred on the middle of the facet ``x[axis] = +half`` is
    removed from the tesseract ``[-half, half]^4``: the facet gets a round 4D crater, a
    shape whose inner faces occlude each other (a test scene for ambient occlusion).

    Parameters
    ----------
    half : float
        Half side h of the tesseract.
    indent : float
        Radius rho < h of the removed ball.
    axis : int
        Axis {0, 1, 2, 3} normal to the indented facet.

    Returns
    -------
    Field
        ``max(cube, -ball)``. Half of the ball lies inside the cube, so
        ``volume = 16 h^4 - pi^2 rho^4 / 4`` and the boundary loses a 3-ball (4/3 pi rho^3) of
        the facet and gains a half 3-sphere (pi^2 rho^3):
        ``boundary_measure = 64 h^3 - 4/3 pi rho^3 + pi^2 rho^3``; ``support`` the cube's,
        exact: the dent (radius < h, centred on a facet) keeps every vertex of the cube, where
        a linear function is largest.
    """
    h = as_real(half, "half", gt=0)
    rho = as_real(indent, "indent", gt=0)
    if rho >= h:
        raise ValueError(f"`indent` must be smaller than `half` ({h:g}), got {indent!r}")
    if axis not in range(4):
        raise ValueError(f"`axis` must be one of 0, 1, 2, 3; got {axis!r}")
    center = np.zeros(4)
    center[axis] = h
    cube = tesseract(h)
    ball = hypersphere(rho, center)
    return Field(
        lambda p: np.maximum(cube(p), -ball(p)),
        dim=4,
        name=f"indented_cube(half={h:g}, indent={rho:g})",
        volume=16 * h**4 - math.pi**2 * rho**4 / 4,
        boundary_measure=64 * h**3 - 4 / 3 * math.pi * rho**3 + math.pi**2 * rho**3,
        extent=cube.extent,
        support=cube.support,
        program=_program("difference", (), cube, ball),  # the same operations
    )


def metaballs(centers: Any, radii: Any = 0.5, *, sharpness: float = 2.0) -> Field:
    """Blobby union of balls: ``1 - sum_i exp(-s (|x - c_i|^2 / r_i^2 - 1))``.

    Parameters
    ----------
    centers : (k, d) array_like
        Ball centers.
    radii : float or (k,) array_like
        Ball radii: a lone ball's zero set is exactly the sphere of radius r_i.
    sharpness : float
        s > 0; larger values blend less.

    Returns
    -------
    Field
        Negative inside the blended solid (not a distance). Its extent and ``support`` (a
        bound: the union of balls of radius ``r_i sqrt(1 + ln(k) / s)`` about the centers) use
        that a point farther than that from every center has each term below 1/k.
    """
    c = as_array(centers, "centers", ndim=2, dtype=np.float64, finite=True, min_size=1)
    k, dim = c.shape
    r = as_array(radii, "radii", ndim=(0, 1), dtype=np.float64, finite=True)
    if r.ndim == 1 and r.shape[0] != k:
        raise ValueError(f"`radii` must be a scalar or have length {k}, got {r.shape[0]}")
    r = np.broadcast_to(r, (k,)).copy()
    if (r <= 0).any():
        raise ValueError("`radii` must be > 0")
    s = as_real(sharpness, "sharpness", gt=0)
    inv_r2 = 1.0 / r**2

    def f(p: np.ndarray) -> np.ndarray:
        total = np.zeros(p.shape[:-1])
        for ci, wi in zip(c, inv_r2):
            d2 = np.einsum("...i,...i->...", p - ci, p - ci)
            total += np.exp(-s * (d2 * wi - 1.0))
        return 1.0 - total

    reach = r * math.sqrt(1.0 + math.log(k) / s)

    def support(u: np.ndarray) -> np.ndarray:
        return np.max([ri * _norm(u, slice(None)) + u @ ci for ci, ri in zip(c, reach)], axis=0)

    return Field(
        f,
        dim=dim,
        name=f"metaballs(k={k})",
        extent=((c - reach[:, None]).min(axis=0), (c + reach[:, None]).max(axis=0)),
        support=support,
        program=_program("metaballs", (-s, dim, *np.column_stack([c, inv_r2]).ravel())),
    )


def gyroid(period: float = 1.0, thickness: float = 0.3) -> Field:
    """A 4D gyroid-like periodic sheet: ``|g(x)| - thickness`` with
    ``g = sin x cos y + sin y cos z + sin z cos w + sin w cos x`` (angles ``2 pi x / period``).

    Unbounded: intersect it with a bounded field (e.g. :func:`hypersphere`) to get a closed mesh.

    Parameters
    ----------
    period : float
        Spatial period along each axis.
    thickness : float
        Half-thickness of the sheet in units of g (a sum of four products, so \\|g\\| <= 4).

    Returns
    -------
    Field
        Negative inside the sheet (not a distance); no ``extent`` or ``support`` (unbounded).
    """
    k = 2 * math.pi / as_real(period, "period", gt=0)
    t = as_real(thickness, "thickness", gt=0)

    def f(p: np.ndarray) -> np.ndarray:
        s, c = np.sin(k * p), np.cos(k * p)
        g = sum(s[..., i] * c[..., (i + 1) % 4] for i in range(4))
        return np.abs(g) - t

    return Field(f, dim=4, name=f"gyroid(period={period:g}, thickness={t:g})", program=_program("gyroid", (k, t)))


def ground(height: float = 0.0, axis: int = 1, *, dim: int = 4) -> Field:
    """Half-space ``x[axis] < height`` (the floor of a scene), as signed distance.

    Parameters
    ----------
    height : float
        Level of the plane.
    axis : int
        Axis normal to the plane (default 1, "y up").
    dim : int
        Dimension d.

    Returns
    -------
    Field
        ``x[axis] - height``; unbounded (intersect with a box to extract it): no ``extent`` or
        ``support``.
    """
    h = as_real(height, "height")
    dim = check_positive_int(dim, "dim")
    if axis not in range(dim):
        raise ValueError(f"`axis` must be in 0..{dim - 1}, got {axis!r}")
    return Field(
        lambda p: p[..., axis] - h,
        dim=dim,
        name=f"ground(height={h:g}, axis={axis})",
        program=_program("ground", (h, axis, dim)),
    )


# --------------------------------------------------------------------------------------------
# combinations and transforms
# --------------------------------------------------------------------------------------------


def _hull(extents: Sequence[np.ndarray | None]) -> np.ndarray | None:
    if any(e is None for e in extents):
        return None
    return np.stack([np.min([e[0] for e in extents], axis=0), np.max([e[1] for e in extents], axis=0)])


def _support_max(supports: Sequence[Support | None]) -> Support | None:
    """Support of a union: the largest of the parts' supports; ``None`` if a part has none."""
    if any(h is None for h in supports):
        return None
    return lambda u: np.max([h(u) for h in supports], axis=0)


def _support_min(supports: Sequence[Support | None]) -> Support | None:
    """A bound on an intersection's support: the smallest of the parts' that have one (the
    intersection lies inside each part); ``None`` if none has one."""
    known = [h for h in supports if h is not None]
    if not known:
        return None
    return lambda u: np.min([h(u) for h in known], axis=0)


def _check_fields(fields: Sequence[Any], name: str) -> None:
    if len(fields) == 0:
        raise ValueError(f"`{name}` needs at least one field")
    for f in fields:
        if not callable(f):
            raise TypeError(f"`{name}` must be callables on (..., d) points, got {type(f).__name__}")


def union(*fields: Callable) -> Field:
    """Union of solids: pointwise ``min`` (exact distance outside, a bound inside).

    Parameters
    ----------
    *fields : Field or callable
        The solids' fields, all of one dimension.

    Returns
    -------
    Field
        The union's field; it has an ``extent`` (the box around the operands') and a
        ``support`` (the largest of the operands', exact where theirs are) only when every
        operand has one.
    """
    _check_fields(fields, "fields")
    dim = _common_dim(fields)
    return Field(
        lambda p: np.min([np.asarray(f(p), dtype=float) for f in fields], axis=0),
        dim=dim,
        name="union(" + ", ".join(map(repr, fields)) + ")",
        extent=_hull([_extent_of(f) for f in fields]),
        support=_support_max([_support_of(f) for f in fields]),
        program=_program("union", (), *fields),
    )


def intersection(*fields: Callable) -> Field:
    """Intersection of solids: pointwise ``max``.

    Parameters
    ----------
    *fields : Field or callable
        The solids' fields, all of one dimension; an unbounded one (a gyroid, the ground) is cut
        to the ``extent`` of the others.

    Returns
    -------
    Field
        The intersection's field; its ``support`` is a bound, the smallest of the operands'
        that have one (``None`` if none has).
    """
    _check_fields(fields, "fields")
    dim = _common_dim(fields)
    boxes = [_extent_of(f) for f in fields if _extent_of(f) is not None]
    extent = None
    if boxes:
        extent = np.stack([np.max([b[0] for b in boxes], axis=0), np.min([b[1] for b in boxes], axis=0)])
    return Field(
        lambda p: np.max([np.asarray(f(p), dtype=float) for f in fields], axis=0),
        dim=dim,
        name="intersection(" + ", ".join(map(repr, fields)) + ")",
        extent=extent,
        support=_support_min([_support_of(f) for f in fields]),
        program=_program("intersection", (), *fields),
    )


def difference(a: Callable, b: Callable) -> Field:
    """Solid ``a`` minus solid ``b``: ``max(a, -b)``.

    Parameters
    ----------
    a, b : Field or callable
        The solid to cut from and the solid cut away.

    Returns
    -------
    Field
        The difference's field; its ``extent`` and ``support`` are ``a``'s (a bound).
    """
    _check_fields((a, b), "a, b")
    return Field(
        lambda p: np.maximum(a(p), -np.asarray(b(p), dtype=float)),
        dim=_common_dim((a, b)),
        name=f"difference({a!r}, {b!r})",
        extent=_extent_of(a),
        support=_support_of(a),
        program=_program("difference", (), a, b),
    )


def smooth_union(a: Callable, b: Callable, k: float = 0.2) -> Field:
    """Union with a fillet of width ``k`` (polynomial smooth minimum).

    ``h = clip(0.5 + 0.5 (b - a) / k, 0, 1)``; ``f = b (1 - h) + a h - k h (1 - h)``.
    Equals ``min(a, b)`` where ``|a - b| >= k``, is smooth elsewhere and never above min.

    Parameters
    ----------
    a, b : Field or callable
        The two solids' fields.
    k : float
        Width of the fillet, > 0.

    Returns
    -------
    Field
        The smooth union's field; no ``support``: the fillet reaches past both solids by an
        amount their fields do not bound in general (not distances, e.g. metaballs).
    """
    _check_fields((a, b), "a, b")
    k = as_real(k, "k", gt=0)

    def f(p: np.ndarray) -> np.ndarray:
        fa, fb = np.asarray(a(p), dtype=float), np.asarray(b(p), dtype=float)
        h = np.clip(0.5 + 0.5 * (fb - fa) / k, 0.0, 1.0)
        return fb * (1 - h) + fa * h - k * h * (1 - h)

    hull = _hull([_extent_of(a), _extent_of(b)])
    # the fillet lies where both fields are below k/4 (the largest dip), within k/4 of the hull
    return Field(
        f,
        dim=_common_dim((a, b)),
        name=f"smooth_union({a!r}, {b!r}, k={k:g})",
        extent=None if hull is None else hull + np.array([[-k / 4], [k / 4]]),
        program=_program("smooth_union", (k,), a, b),
    )


def translate(field: Callable, offset: Any) -> Field:
    """Move the solid by ``offset``: ``f(x - offset)``.

    Parameters
    ----------
    field : Field or callable
        The solid's field.
    offset : (d,) array_like
        The translation.

    Returns
    -------
    Field
        The moved solid's field; ``support`` ``h(u) + u . offset``.
    """
    _check_fields((field,), "field")
    off = as_array(offset, "offset", ndim=1, dtype=np.float64, finite=True, min_size=1)
    dim = _dim_of(field)
    if dim is not None and off.shape[0] != dim:
        raise ValueError(f"`offset` must have length {dim}, got {off.shape[0]}")
    ext = _extent_of(field)
    h = _support_of(field)
    return Field(
        lambda p: field(p - off),
        dim=off.shape[0],
        name=f"translate({field!r})",
        volume=getattr(field, "volume", None),
        boundary_measure=getattr(field, "boundary_measure", None),
        extent=None if ext is None else ext + off,
        support=None if h is None else lambda u: h(u) + u @ off,
        program=_program("translate", off, field),
    )


def scale(field: Callable, factor: float) -> Field:
    """Scale the solid uniformly by ``factor`` > 0 about the origin: ``factor * f(x / factor)``.

    Distances stay distances; the volume scales by factor^d and the boundary by factor^(d-1).

    Parameters
    ----------
    field : Field or callable
        The solid's field.
    factor : float
        Scale factor, > 0.

    Returns
    -------
    Field
        The scaled solid's field; ``support`` ``factor * h(u)``.
    """
    _check_fields((field,), "field")
    s = as_real(factor, "factor", gt=0)
    dim = _dim_of(field)
    vol, area = getattr(field, "volume", None), getattr(field, "boundary_measure", None)
    ext = _extent_of(field)
    h = _support_of(field)
    return Field(
        lambda p: s * np.asarray(field(p / s), dtype=float),
        dim=dim,
        name=f"scale({field!r}, {s:g})",
        volume=None if vol is None or dim is None else vol * s**dim,
        boundary_measure=None if area is None or dim is None else area * s ** (dim - 1),
        extent=None if ext is None else ext * s,
        support=None if h is None else lambda u: s * h(u),
        program=_program("scale", (s,), field),
    )


def rotate(field: Callable, plane: tuple[int, int] = (0, 3), angle: float = 0.0) -> Field:
    """Rotate the solid by ``angle`` radians in the coordinate plane ``(i, j)``, from axis i
    towards axis j (4D has six planes: (0,1), (0,2), (0,3), (1,2), (1,3), (2,3)).

    Parameters
    ----------
    field : callable
        Field to rotate.
    plane : (int, int)
        Two distinct axes.
    angle : float
        Angle in radians.

    Returns
    -------
    Field
        ``f(R^-1 x)``; volume and boundary measure are unchanged; ``support`` ``h(R^-1 u)``.
    """
    _check_fields((field,), "field")
    try:
        i, j = (int(v) for v in plane)
    except (TypeError, ValueError):
        raise ValueError(f"`plane` must be two axis indices (i, j), got {plane!r}") from None
    dim = _dim_of(field)
    top = dim if dim is not None else max(i, j) + 1
    if i == j or not (0 <= i < top and 0 <= j < top):
        raise ValueError(f"`plane` must be two distinct axes in 0..{top - 1}, got {plane!r}")
    a = as_real(angle, "angle")
    c, s = math.cos(a), math.sin(a)

    def back(p: np.ndarray) -> np.ndarray:
        q = p.copy()
        q[..., i] = c * p[..., i] + s * p[..., j]  # R^-1 = rotation by -angle
        q[..., j] = -s * p[..., i] + c * p[..., j]
        return q

    h = _support_of(field)

    ext = _extent_of(field)
    if ext is not None:  # bounding box of the rotated box's corners
        corners = np.array(list(itertools.product(*ext.T)))
        rot = corners.copy()
        rot[:, i] = c * corners[:, i] - s * corners[:, j]
        rot[:, j] = s * corners[:, i] + c * corners[:, j]
        ext = np.stack([rot.min(axis=0), rot.max(axis=0)])
    return Field(
        lambda p: field(back(p)),
        dim=dim,
        name=f"rotate({field!r}, plane=({i}, {j}), angle={a:g})",
        volume=getattr(field, "volume", None),
        boundary_measure=getattr(field, "boundary_measure", None),
        extent=ext,
        support=None if h is None else lambda u: h(back(u)),
        program=_program("rotate", (i, j, c, s, -s), field),
    )


# --------------------------------------------------------------------------------------------
# presets (command line) and grid sampling
# --------------------------------------------------------------------------------------------

PRESETS: dict[str, Callable[[], Field]] = {
    "hypersphere": lambda: hypersphere(1.0),
    "spheritorus": lambda: spheritorus(1.0, 0.4),
    "torisphere": lambda: torisphere(1.0, 0.4),
    "ditorus": lambda: ditorus(1.0, 0.45, 0.2),
    "tiger": lambda: tiger(0.8, 0.8, 0.35),
    "duocylinder": lambda: duocylinder(1.0, 1.0),
    "tesseract": lambda: tesseract(1.0, 0.25),
    "indented_cube": lambda: indented_cube(1.0, 0.6),
    "metaballs": lambda: metaballs([[-0.5, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.6, 0, 0.3]], 0.5),
    "gyroid": lambda: intersection(gyroid(1.0, 0.3), hypersphere(1.0)),
}


def preset(name: str) -> Field:
    """One of the named shapes in ``PRESETS`` with default parameters.

    Parameters
    ----------
    name : str
        A key of ``PRESETS`` (``"hypersphere"``, ``"tiger"``, ...).

    Returns
    -------
    Field
        The shape's field.

    Raises
    ------
    ValueError
        If ``name`` is not a preset.
    """
    if name not in PRESETS:
        raise ValueError(f"`shape` must be one of {', '.join(PRESETS)}; got {name!r}")
    return PRESETS[name]()


def grid_axes(shape: Any, bounds: Any, *, dim: int | None = None) -> list[np.ndarray]:
    """Coordinates of the grid points along each axis: ``lo + (hi - lo) * i / (n - 1)``.

    Parameters
    ----------
    shape : int or sequence of int
        Points per axis (each >= 2); an int needs ``dim``.
    bounds : (lo, hi)
        Each a scalar or a (d,) sequence, lo < hi.
    dim : int, optional
        Dimension when ``shape`` is an int.

    Returns
    -------
    list of (n_k,) float64 arrays
        The coordinates along axis k, from lo to hi.
    """
    if isinstance(shape, (int, np.integer)) and not isinstance(shape, bool):
        if dim is None:
            raise ValueError("`shape` is an int but the field's dimension is unknown; pass a tuple")
        shape = (int(shape),) * dim
    try:
        shape = tuple(int(n) for n in shape)
    except (TypeError, ValueError):
        raise TypeError(f"`shape` must be an int or a sequence of ints, got {shape!r}") from None
    if dim is not None and len(shape) != dim:
        raise ValueError(f"`shape` must have {dim} entries for this {dim}D field, got {shape}")
    if not shape or any(n < 2 for n in shape):
        raise ValueError(f"`shape` needs at least 2 points along every axis, got {shape}")
    try:
        lo, hi = bounds
    except (TypeError, ValueError):
        raise ValueError(f"`bounds` must be a pair (lo, hi), got {bounds!r}") from None
    lo = as_vector(lo, "bounds", len(shape))
    hi = as_vector(hi, "bounds", len(shape))
    if not (hi > lo).all():
        raise ValueError(f"`bounds` must have lo < hi on every axis, got lo={lo}, hi={hi}")
    return [l + (h - l) * np.arange(n) / (n - 1) for l, h, n in zip(lo, hi, shape)]


def evaluate_layers(field: Callable, axes: Sequence[np.ndarray], start: int, stop: int) -> np.ndarray:
    """Evaluate ``field`` on the grid points with last-axis index in ``[start, stop)``.

    Returns the values laid out with the last grid axis first, shape ``(stop - start, n_0, ...,
    n_{d-2})`` (C order), so that each layer is contiguous. The field is called on blocks of at
    most about ``_POINTS_PER_BLOCK`` points (whole layers, or rows of one layer), which bounds the
    (..., d) point array and the field's own temporaries.
    """
    d = len(axes)
    inner = [len(a) for a in axes[:-1]]
    out = np.empty((stop - start, *inner), dtype=np.float64)
    rows = inner[0] if inner else 1
    per_row = math.prod(inner[1:])
    per_layer = rows * per_row
    if per_layer <= _POINTS_PER_BLOCK:
        layer_step, row_step = max(1, _POINTS_PER_BLOCK // max(per_layer, 1)), rows
    else:
        layer_step, row_step = 1, max(1, _POINTS_PER_BLOCK // per_row)
    for k0 in range(start, stop, layer_step):
        k1 = min(stop, k0 + layer_step)
        for r0 in range(0, rows, row_step):
            r1 = min(rows, r0 + row_step)
            block = [axes[-1][k0:k1]] + ([axes[0][r0:r1]] if inner else []) + list(axes[1:-1])
            pts = np.empty((*(len(b) for b in block), d))
            for pos, coords in enumerate(block):  # pts axis `pos` runs along `coords`
                axis = d - 1 if pos == 0 else pos - 1
                pts[..., axis] = coords.reshape([-1 if q == pos else 1 for q in range(d)])
            vals = np.asarray(field(pts))
            if vals.dtype.kind not in "fiub":  # complex parts would be dropped with a warning
                raise TypeError(
                    f"`field` must return real numbers, got dtype {vals.dtype} (as "
                    "ao4d.extract refuses such values: take .real or abs() first)"
                )
            vals = vals.astype(np.float64, copy=False)
            if vals.shape != pts.shape[:-1]:
                raise ValueError(f"`field` returned shape {vals.shape} for points of shape {pts.shape}")
            out[k0 - start : k1 - start, r0:r1] = vals
    return out


def sample(field: Callable, shape: Any, bounds: Any) -> np.ndarray:
    """Sample ``field`` on a regular grid including both bounds.

    Parameters
    ----------
    field : callable
        Maps (..., d) points to (...) values.
    shape : int or sequence of int
        Grid points per axis (each >= 2); an int means the same on every axis (needs a
        :class:`Field` with known ``dim``).
    bounds : (lo, hi)
        Box corners, scalars or (d,) sequences. Grid point i sits at
        ``lo + (hi - lo) * i / (n - 1)`` per axis.

    Returns
    -------
    values : (n_0, ..., n_{d-1}) float64 ndarray
        ``values[i0, ..., i_{d-1}] = field(point(i))``; axis k is coordinate k.

    Examples
    --------
    >>> v = sample(hypersphere(1.0), 3, (-1, 1))
    >>> v.shape, float(v[1, 1, 1, 1])
    ((3, 3, 3, 3), -1.0)
    """
    if not callable(field):
        raise TypeError(f"`field` must be callable on (..., d) points, got {type(field).__name__}")
    axes = grid_axes(shape, bounds, dim=_dim_of(field))
    n = [len(a) for a in axes]
    # the layers are evaluated last-axis-first, then reordered: two float64 grids at the peak
    check_memory(16.0 * math.prod(n), f"sampling a grid of shape {tuple(n)}")
    layers = evaluate_layers(field, axes, 0, n[-1])
    # on a page: a CPU device then reads the grid in place when it is extracted (ao4d._pages)
    values = aligned_empty(n, layers.dtype)
    values[...] = np.moveaxis(layers, 0, -1)
    return values
