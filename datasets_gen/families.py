"""Shape families: how one item's parameters become a closed 4D mesh.

Implicit families build an :class:`ao4d.fields.Field` and extract it on a grid fitted to the
rotated solid; lifted families build a 3D solid with trimesh and lift it with
:mod:`ao4d.lift`. Every builder takes the item's drawn parameters and its random generator
(for randomness beyond the parameters, e.g. metaball centres) and returns a :class:`Shape`.

Grid fitting. The grid of an implicit item covers the solid's extent along each axis *after*
the item's rotation, grown by ``padding`` (a fraction of the width) and then by
:data:`MARGIN_CELLS` grid cells; its cells are cubes, ``grid`` points across the widest axis
and fewer across narrower ones (see :func:`fitted_grid`). The extent comes from the solid's
support function ``h(u) = max_{x in S} u . x``: the solid ``Q S`` spans
``[-h(-Q^T e_k), h(Q^T e_k)]`` along axis k. Each field carries its own support
(:attr:`ao4d.fields.Field.support`; the analytic shapes are Minkowski sums of circles, spheres,
disks and cubes with a ball, whose supports add): exact for the analytic shapes and CSG unions,
a containing bound for metaballs (balls of each term's reach), gyroid balls (the ball) and CSG
differences (the first operand). A closed form is preferred over fitting by sampling the
field: it is exact and costs nothing, needs no Lipschitz bound (metaballs and gyroids have
none worth using), and cannot miss a thin part between samples. The box of the rotated
extent box's corners, which it replaces, was up to 2 times too wide per axis, and the cube
grid over its widest axis 1.6-5.6 times wider than a rotated ``tori`` item on some axis.
"""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ao4d.fields import Support

__all__ = [
    "KINDS",
    "kinds",
    "Kind",
    "Shape",
    "random_rotation",
    "build_shape",
    "MARGIN_CELLS",
    "support_extent",
    "fitted_grid",
    "INTEGER_PARAMS",
]

#: family parameters that count parts or steps: (kind, name) -> (least, most). The
#: configuration reader refuses a value outside (a constant, an ``integers`` or ``choice``
#: distribution; no continuous one), before anything is built: ten million metaballs, or a
#: spin in a billion steps, would run for hours and then exhaust memory in every item.
INTEGER_PARAMS: dict[tuple[str, str], tuple[int, int]] = {
    ("metaballs", "n"): (1, 64),
    ("tesseracts", "n"): (1, 64),
    ("lifted", "detail"): (0, 6),  # icosphere subdivisions: 20 * 4**6 = 81920 faces
    ("lifted", "k"): (3, 1024),  # spin steps
}

# Grid cells between the solid's extent (plus padding) and the grid's outermost points: keeps the
# zero set off the boundary points (which must be positive for a closed mesh) with room to spare.
MARGIN_CELLS = 1.0


@dataclass
class Shape:
    """What a family builds for one item.

    Attributes
    ----------
    mesh : SimplexMesh
        The closed 4D boundary.
    volume_expected : float or None
        The 4-volume the mesh should enclose (analytic for fields; exact for lifted solids).
    derived : dict
        Further random quantities drawn for the item (recorded in its JSON).
    grid : dict
        Extraction grid for implicit families (empty for lifted ones): ``shape`` (points per
        axis), ``bounds`` ([lo, hi], each 4 floats), ``spacing`` (4 floats) and ``extent``
        ([lo, hi]: the rotated solid's extent the grid was fitted to; ``None`` when the
        config gives ``bounds``).
    field : Field or None
        The (rotated) field that was extracted; ``None`` for lifted families.
    """

    mesh: Any
    volume_expected: float | None
    derived: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    field: Any = None


@dataclass(frozen=True)
class Kind:
    """A family kind: the parameter names it accepts and its builder."""

    params: tuple[str, ...]
    build: Callable[[dict, dict, np.random.Generator, np.ndarray | None], Shape]
    doc: str


def random_rotation(rng: np.random.Generator, dim: int = 4) -> np.ndarray:
    """A rotation matrix uniform (Haar) on SO(dim): QR of a Gaussian matrix, signs fixed."""
    q, r = np.linalg.qr(rng.standard_normal((dim, dim)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


# --------------------------------------------------------------------------- implicit families


def _rotated_field(f: Any, rotation: np.ndarray | None) -> Any:
    """The solid ``rotation @ S``: ``g(x) = f(rotation^T x)``, support ``h(rotation^T u)``,
    extent the box of the rotated extent's corners (loose: grids are fitted to the support)."""
    if rotation is None:
        return f
    from itertools import product

    from ao4d.fields import Field

    ext = f.extent
    if ext is not None:
        corners = np.array(list(product(*ext.T))) @ rotation.T
        ext = (corners.min(axis=0), corners.max(axis=0))
    h = f.support
    return Field(
        lambda p: f(p @ rotation),
        dim=f.dim,
        name=f"rotated({f.name})",
        volume=f.volume,
        boundary_measure=f.boundary_measure,
        extent=ext,
        support=None if h is None else lambda u: h(u @ rotation),
    )


# --------------------------------------------------------------------------- grids


def support_extent(support: Support, rotation: np.ndarray | None = None, *, dim: int = 4) -> np.ndarray:
    """The axis-aligned extent ``(2, dim)`` [lo, hi] of ``rotation @ S`` from S's support.

    Along axis k the solid ``Q S`` reaches ``max_{x in S} e_k . Q x = h(Q^T e_k)`` (row k of Q)
    and down to ``-h(-Q^T e_k)``: the extent is exact where the support is.
    """
    q = np.eye(dim) if rotation is None else np.asarray(rotation, dtype=float)
    return np.stack([-support(-q), support(q)])


def fitted_grid(extent: Any, n: int, *, padding: float = 0.0, margin: float = MARGIN_CELLS) -> dict[str, Any]:
    """Grid of cubic cells over ``extent`` grown by ``padding`` and ``margin`` cells.

    The widest axis gets ``n`` points: its extent, widened by ``padding`` times its width,
    spans ``n - 1 - 2 margin`` cells, which fixes the spacing ``h`` of every axis. Each other
    axis gets the fewest points whose span covers its (padded) width plus ``margin`` cells per
    side, centred on the extent. So the outermost grid points lie at least ``margin`` cells
    outside the padded extent on every side, and the grid never has more than ``n^d`` points.

    Parameters
    ----------
    extent : (2, d) array_like
        [lo, hi] of the solid.
    n : int
        Points along the widest axis.
    padding : float
        Extra width, as a fraction of each axis' width, split between its two sides.
    margin : float
        Cells between the padded extent and the outermost grid points.

    Returns
    -------
    dict
        ``shape`` (points per axis), ``bounds`` ([lo, hi]), ``spacing`` and ``extent``
        (plain lists).
    """
    ext = np.asarray(extent, dtype=float).reshape(2, -1)
    cells = n - 1 - 2 * margin
    if cells < 1:
        raise ValueError(f"`grid` must exceed 2 * {margin:g} + 2 points for a margin of {margin:g} cells, got {n}")
    width = (ext[1] - ext[0]) * (1 + padding)
    if not np.all(np.isfinite(width)) or not np.all(width > 0):
        raise ValueError(f"the solid's extent must be finite and not flat, got {ext.tolist()}")
    h = float(width.max()) / cells
    # 1e-9: the widest axis' width / h + 2 margin is n - 1 up to rounding
    counts = np.ceil(width / h + 2 * margin - 1e-9).astype(int) + 1
    centre = ext.mean(axis=0)
    lo, hi = centre - (counts - 1) * h / 2, centre + (counts - 1) * h / 2
    return {
        "shape": counts.tolist(),
        "bounds": [lo.tolist(), hi.tolist()],
        "spacing": ((hi - lo) / (counts - 1)).tolist(),
        "extent": ext.tolist(),
    }


def _grid_for(f: Any, g: Any, rotation: np.ndarray | None, settings: dict) -> dict:
    """The extraction grid of one item (``f`` the field, ``g`` it rotated): the config's
    ``bounds`` (a cube), else fitted to the rotated solid (``f``'s support, or ``g``'s loose
    extent where there is none)."""
    n = settings["grid"]
    if settings["bounds"] is not None:
        lo, hi = (float(v) for v in settings["bounds"])
        lo_v, hi_v = np.full(4, lo), np.full(4, hi)
        return {
            "shape": [n] * 4,
            "bounds": [lo_v.tolist(), hi_v.tolist()],
            "spacing": ((hi_v - lo_v) / (n - 1)).tolist(),
            "extent": None,
        }
    if f.support is not None:
        extent = support_extent(f.support, rotation)
    elif g.extent is not None:
        extent = g.extent
    else:
        raise ValueError(f"{g.name} has no known extent; give `bounds` in the config")
    return fitted_grid(extent, n, padding=float(settings["padding"]))


def _extract(f: Any, settings: dict, rotation: np.ndarray | None, derived: dict) -> Shape:
    """Extract ``f`` (rotated) on its grid, fitted to its support."""
    from ao4d.marching.march import extract_field

    g = _rotated_field(f, rotation)
    grid = _grid_for(f, g, rotation, settings)
    mesh = extract_field(
        g,
        grid["shape"],
        (np.array(grid["bounds"][0]), np.array(grid["bounds"][1])),
        method=settings["method"],
        progress=False,
    )
    if mesh.n_simplices == 0:
        raise ValueError(f"{f.name}: extraction gave an empty mesh (shape smaller than a cell?)")
    return Shape(mesh, g.volume, derived, grid, g)


def _field_kind(name: str) -> Kind:
    """A family for one constructor of ao4d.fields, its keyword parameters the family's."""
    from ao4d import fields

    func = getattr(fields, name)
    signature = inspect.signature(func)
    params = tuple(p.name for p in signature.parameters.values() if p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD)

    def build(params_: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
        del rng
        return _extract(func(**params_), settings, rotation, {})  # the constructor validates

    return Kind(params, build, (func.__doc__ or "").strip().splitlines()[0])


def _count(p: dict, default: int) -> int:
    """The parameter ``n`` (how many parts), at least 1."""
    n = int(p.get("n", default))
    if n < 1:
        raise ValueError(f"`n` must be >= 1, got {n}")
    return n


def _floats(p: dict, **defaults: float) -> tuple[float, ...]:
    """The parameters named by ``defaults``, as floats, in that order."""
    return tuple(float(p.get(name, value)) for name, value in defaults.items())


def _metaballs(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """``n`` balls, centres uniform in [-spread, spread]^4, radii radius * U(1 - jitter, 1 + jitter)."""
    from ao4d import fields

    n = _count(p, 4)
    spread, radius, jitter = _floats(p, spread=0.5, radius=0.4, jitter=0.3)
    centres = rng.uniform(-spread, spread, size=(n, 4))
    radii = radius * rng.uniform(1 - jitter, 1 + jitter, size=n)
    sharpness = float(p.get("sharpness", 2.0))
    f = fields.metaballs(centres, radii, sharpness=sharpness)  # its support: a bound
    return _extract(f, settings, rotation, {"centers": centres, "radii": radii})


def _tesseracts(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """CSG of ``n`` randomly rotated, shifted rounded tesseracts: union, or the first minus the rest."""
    from ao4d import fields

    n = _count(p, 3)
    half, spread, rounding = _floats(p, half=0.4, spread=0.4, rounding=0.05)
    operation = p.get("operation", "union")
    if operation not in ("union", "difference"):
        raise ValueError(f"`operation` must be 'union' or 'difference', got {operation!r}")
    parts, shifts, rotations = [], [], []
    for i in range(n):
        q = random_rotation(rng)
        shift = np.zeros(4) if (operation == "difference" and i == 0) else rng.uniform(-spread, spread, 4)
        size = half * (1.5 if (operation == "difference" and i == 0) else 1.0)
        round_ = min(rounding, 0.9 * size)
        parts.append(fields.translate(_rotated_field(fields.tesseract(size, round_), q), shift))
        shifts.append(shift)
        rotations.append(q)
    if operation == "union":  # support exact: the parts' largest
        f = fields.union(*parts) if n > 1 else parts[0]
    else:  # support a bound: the first part's, from which the others are cut
        f = parts[0] if n == 1 else fields.difference(parts[0], fields.union(*parts[1:]))
    return _extract(f, settings, rotation, {"shifts": shifts, "rotations": rotations})


def _gyroid_ball(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """A gyroid sheet clipped to a ball: ``intersection(gyroid(period, thickness), ball(radius))``."""
    from ao4d import fields

    del rng
    radius = float(p.get("radius", 1.0))
    f = fields.intersection(
        fields.gyroid(float(p.get("period", 1.0)), float(p.get("thickness", 0.3))), fields.hypersphere(radius)
    )
    return _extract(f, settings, rotation, {})  # support a bound: the ball's


# --------------------------------------------------------------------------- lifted families

SHAPES_3D = ("box", "sphere", "capsule", "cylinder", "torus", "file")


def _solid_3d(shape: str, size: float, aspect: float, detail: int):
    """A watertight trimesh solid centred at the origin, about ``size`` in radius."""
    import trimesh

    if shape == "box":
        return trimesh.creation.box(extents=2 * size * np.array([1.0, aspect, aspect**2]))
    if shape == "sphere":
        return trimesh.creation.icosphere(detail, radius=size)
    if shape == "capsule":
        return trimesh.creation.capsule(height=2 * size * aspect, radius=size, count=[4 * detail + 4] * 2)
    if shape == "cylinder":
        return trimesh.creation.cylinder(radius=size, height=2 * size * aspect, sections=8 * detail)
    if shape == "torus":
        return trimesh.creation.torus(
            size, size * min(aspect, 0.9), major_sections=8 * detail, minor_sections=4 * detail + 4
        )
    raise ValueError(f"`shape` must be one of {', '.join(SHAPES_3D)}, got {shape!r}")  # file: above


def _solid_from_file(path: Any, size: float):
    """A watertight mesh file, centred on its centre of mass and scaled to bounding radius ``size``."""
    from ao4d import lift

    from ._files import sha256_file

    if not isinstance(path, str):
        raise ValueError("`shape = 'file'` needs `path`, the mesh file (.stl, .obj, .ply, ...)")
    solid = lift.load_surface(path)
    solid.apply_translation(-solid.center_mass)
    solid.apply_scale(size / float(np.max(np.linalg.norm(solid.vertices, axis=1))))
    return solid, sha256_file(path)


def _lifted(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """A trimesh solid (``shape``, or ``shape = "file"`` with ``path``) lifted by ``op``: prism/cone
    of ``height``, or spin in ``k`` steps at distance ``offset`` from the rotation plane."""
    from ao4d import lift

    del rng
    shape, op = p.get("shape", "box"), p.get("op", "prism")
    size, aspect = float(p.get("size", 0.5)), float(p.get("aspect", 1.0))
    detail = int(p.get("detail", 2))
    derived: dict[str, Any] = {}
    if shape == "file":
        solid3, derived["file_sha256"] = _solid_from_file(p.get("path"), size)
    else:
        solid3 = _solid_3d(shape, size, aspect, detail)
    derived["faces_3d"] = len(solid3.faces)
    if op in ("prism", "cone"):
        height = float(p.get("height", 1.0))
        solid = lift.tetrahedralize(solid3, method=settings["tetrahedra"])
        func = lift.prism if op == "prism" else lift.cone
        mesh = func(solid, height, base=-height / 2)
        expected = solid.volume * height * (1.0 if op == "prism" else 0.25)
    elif op == "spin":
        k = int(p.get("k", 24))
        solid3.apply_translation([float(p.get("offset", 0.25)) - solid3.bounds[0, 0], 0, 0])
        mesh = lift.spin(solid3, k)
        expected = k * math.sin(2 * math.pi / k) * solid3.volume * solid3.center_mass[0]
    else:
        raise ValueError(f"`op` must be 'prism', 'cone' or 'spin', got {op!r}")
    if rotation is not None:
        from ao4d.mesh import SimplexMesh

        mesh = SimplexMesh(mesh.vertices @ rotation.T, mesh.simplices)
    return Shape(mesh, float(expected), derived, {})


# a sweep's frames come from one glob; more files than this is a wrong pattern, not a motion
MAX_SWEEP_FRAMES = 4096


def _natural_key(path: str) -> list:
    """Sort key with runs of digits compared as numbers (frame_2 before frame_10)."""
    import re

    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path)]


def _sweep(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """Frames of one moving mesh (``frames``: a glob of mesh files, in the numeric order of their
    names) swept through time by :func:`ao4d.lift.sweep`, at ``times`` (one per frame) or evenly
    over ``duration`` centred on w = 0."""
    import glob

    from ao4d import lift

    from ._files import sha256_file

    del rng, settings
    pattern = p.get("frames")
    if not isinstance(pattern, str) or not pattern.strip():
        raise ValueError("`frames` must be a glob of mesh files (a string such as 'walk/frame_*.ply')")
    paths = sorted(glob.glob(pattern), key=_natural_key)
    if len(paths) < 2:
        raise ValueError(f"`frames` {pattern!r} must match at least 2 files, matched {len(paths)}")
    if len(paths) > MAX_SWEEP_FRAMES:
        raise ValueError(f"`frames` {pattern!r} matched {len(paths)} files, more than {MAX_SWEEP_FRAMES}")
    if "times" in p:
        times = np.asarray(p["times"], dtype=float)
    else:
        duration = float(p.get("duration", 1.0))
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"`duration` must be finite and > 0, got {duration!r}")
        times = np.linspace(-duration / 2, duration / 2, len(paths))
    frames = [lift.load_surface(path) for path in paths]
    mesh = lift.sweep(frames, times)  # checks times against the frames
    # Expected volume: Simpson's rule on the frames' volumes (trimesh) and the 3D slices at the
    # intervals' midpoints, exact for the cubic vol(S(t)) (ao4d.lift.sweep, Notes): a check of
    # the 4D volume against 3D ones
    mids = [mesh.slice([0.0, 0.0, 0.0, (a + b) / 2], [0.0, 0.0, 0.0, 1.0]).volume for a, b in zip(times, times[1:])]
    vols = [f.volume for f in frames]
    expected = sum((b - a) * (v0 + 4 * vm + v1) / 6 for a, b, v0, vm, v1 in zip(times, times[1:], vols, mids, vols[1:]))
    derived = {
        "frames": len(paths),
        "frames_sha256": _hash_list([sha256_file(path) for path in paths]),
        "times": times.tolist(),
        "faces_3d": len(frames[0].faces),
    }
    if rotation is not None:
        from ao4d.mesh import SimplexMesh

        mesh = SimplexMesh(mesh.vertices @ rotation.T, mesh.simplices)
    return Shape(mesh, float(expected), derived, {})


def _hash_list(hashes: list[str]) -> str:
    """One SHA-256 for an ordered list of file hashes (the frames of a sweep)."""
    import hashlib

    return hashlib.sha256("\n".join(hashes).encode()).hexdigest()


def _kinds() -> dict[str, Kind]:
    from ao4d.fields import PRESETS

    # every named shape of ao4d.fields is a family, its parameters the constructor's, except the
    # two with families of their own below (metaballs placed at random, the gyroid cut by a ball)
    kinds = {name: _field_kind(name) for name in PRESETS if name not in ("metaballs", "gyroid")}
    kinds["metaballs"] = Kind(("n", "spread", "radius", "jitter", "sharpness"), _metaballs, _metaballs.__doc__)
    kinds["tesseracts"] = Kind(("n", "half", "spread", "rounding", "operation"), _tesseracts, _tesseracts.__doc__)
    kinds["gyroid_ball"] = Kind(("period", "thickness", "radius"), _gyroid_ball, _gyroid_ball.__doc__)
    kinds["lifted"] = Kind(
        ("shape", "path", "op", "size", "aspect", "detail", "height", "k", "offset"), _lifted, _lifted.__doc__
    )
    kinds["sweep"] = Kind(("frames", "times", "duration"), _sweep, _sweep.__doc__)
    return kinds


@functools.cache
def kinds() -> dict[str, Kind]:
    """The registry of family kinds (built on first use: it imports ao4d.fields)."""
    return _kinds()


def __getattr__(name: str) -> Any:
    if name == "KINDS":  # module attribute computed lazily (PEP 562)
        return kinds()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build_shape(
    kind: str, params: dict, settings: dict, rng: np.random.Generator, rotation: np.ndarray | None
) -> Shape:
    """Build one item's mesh; errors name the family kind."""
    try:
        return kinds()[kind].build(params, settings, rng, rotation)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"family kind {kind!r} with params {params}: {exc}") from exc
