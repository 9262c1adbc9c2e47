"""Shape families: how one item's parameters become a closed 4D mesh.

Implicit families build an :class:`ao4d.fields.Field` and extract it on a grid that encloses the
field's extent; lifted families build a 3D solid with trimesh and lift it with
:mod:`ao4d.lift`. Every builder takes the item's drawn parameters and its random generator
(for randomness beyond the parameters, e.g. metaball centres) and returns a :class:`Shape`.
"""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["KINDS", "kinds", "Kind", "Shape", "random_rotation", "build_shape"]


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
        Extraction grid (shape, bounds, spacing) for implicit families; empty for lifted ones.
    """

    mesh: Any
    volume_expected: float | None
    derived: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)


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
    """The solid ``rotation @ S``: ``g(x) = f(rotation^T x)``, extent = box of rotated corners."""
    if rotation is None:
        return f
    from itertools import product

    from ao4d.fields import Field

    ext = f.extent
    if ext is not None:
        corners = np.array(list(product(*ext.T))) @ rotation.T
        ext = (corners.min(axis=0), corners.max(axis=0))
    return Field(lambda p: f(p @ rotation), dim=f.dim, name=f"rotated({f.name})",
                 volume=f.volume, boundary_measure=f.boundary_measure, extent=ext)


def _grid_for(f: Any, settings: dict) -> dict:
    """Cube grid enclosing the field's extent with a margin (equal spacing on every axis)."""
    n = settings["grid"]
    if settings["bounds"] is not None:
        lo, hi = (float(v) for v in settings["bounds"])
        lo_v, hi_v = np.full(4, lo), np.full(4, hi)
    else:
        if f.extent is None:
            raise ValueError(f"{f.name} has no known extent; give `bounds` in the config")
        centre = f.extent.mean(axis=0)
        half = float(np.max(f.extent[1] - f.extent[0])) / 2 * (1 + settings["padding"])
        # keep the zero set off the outermost grid points even with padding = 0
        half += 1.0 * half / (n - 1)
        lo_v, hi_v = centre - half, centre + half
    spacing = (hi_v - lo_v) / (n - 1)
    return {"shape": [n] * 4, "bounds": [lo_v.tolist(), hi_v.tolist()], "spacing": spacing.tolist()}


def _extract(f: Any, settings: dict, rotation: np.ndarray | None, derived: dict) -> Shape:
    from ao4d.march import extract_field

    g = _rotated_field(f, rotation)
    grid = _grid_for(g, settings)
    mesh = extract_field(g, grid["shape"], (np.array(grid["bounds"][0]), np.array(grid["bounds"][1])),
                         method=settings["method"], progress=False)
    if mesh.n_simplices == 0:
        raise ValueError(f"{f.name}: extraction gave an empty mesh (shape smaller than a cell?)")
    return Shape(mesh, g.volume, derived, grid)


def _field_kind(name: str) -> Kind:
    """A family for one constructor of ao4d.fields, its keyword parameters the family's."""
    from ao4d import fields

    func = getattr(fields, name)
    params = tuple(p.name for p in inspect.signature(func).parameters.values()
                   if p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD)

    def build(params_: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
        del rng
        return _extract(func(**params_), settings, rotation, {})

    return Kind(params, build, (func.__doc__ or "").strip().splitlines()[0])


def _metaballs(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """``n`` balls, centres uniform in [-spread, spread]^4, radii radius * U(1 - jitter, 1 + jitter)."""
    from ao4d import fields

    n = int(p.get("n", 4))
    if n < 1:
        raise ValueError(f"`n` must be >= 1, got {n}")
    spread, radius, jitter = (float(p.get(k, d)) for k, d in
                              (("spread", 0.5), ("radius", 0.4), ("jitter", 0.3)))
    centres = rng.uniform(-spread, spread, size=(n, 4))
    radii = radius * rng.uniform(1 - jitter, 1 + jitter, size=n)
    f = fields.metaballs(centres, radii, sharpness=float(p.get("sharpness", 2.0)))
    return _extract(f, settings, rotation, {"centers": centres, "radii": radii})


def _tesseracts(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """CSG of ``n`` randomly rotated, shifted rounded tesseracts: union, or the first minus the rest."""
    from ao4d import fields

    n = int(p.get("n", 3))
    if n < 1:
        raise ValueError(f"`n` must be >= 1, got {n}")
    half, spread, rounding = (float(p.get(k, d)) for k, d in
                              (("half", 0.4), ("spread", 0.4), ("rounding", 0.05)))
    operation = p.get("operation", "union")
    if operation not in ("union", "difference"):
        raise ValueError(f"`operation` must be 'union' or 'difference', got {operation!r}")
    parts, shifts, rotations = [], [], []
    for i in range(n):
        q = random_rotation(rng)
        shift = np.zeros(4) if (operation == "difference" and i == 0) else rng.uniform(-spread, spread, 4)
        size = half * (1.5 if (operation == "difference" and i == 0) else 1.0)
        part = fields.translate(_rotated_field(fields.tesseract(size, min(rounding, 0.9 * size)), q),
                                shift)
        parts.append(part)
        shifts.append(shift)
        rotations.append(q)
    if operation == "union":
        f = fields.union(*parts) if n > 1 else parts[0]
    else:
        f = parts[0] if n == 1 else fields.difference(parts[0], fields.union(*parts[1:]))
    return _extract(f, settings, rotation, {"shifts": shifts, "rotations": rotations})


def _gyroid_ball(p: dict, settings: dict, rng: np.random.Generator, rotation) -> Shape:
    """A gyroid sheet clipped to a ball: ``intersection(gyroid(period, thickness), ball(radius))``."""
    from ao4d import fields

    del rng
    f = fields.intersection(fields.gyroid(float(p.get("period", 1.0)), float(p.get("thickness", 0.3))),
                            fields.hypersphere(float(p.get("radius", 1.0))))
    return _extract(f, settings, rotation, {})


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
        return trimesh.creation.torus(size, size * min(aspect, 0.9), major_sections=8 * detail,
                                      minor_sections=4 * detail + 4)
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


def _kinds() -> dict[str, Kind]:
    kinds = {name: _field_kind(name) for name in (
        "hypersphere", "spheritorus", "torisphere", "ditorus", "tiger", "duocylinder",
        "tesseract", "indented_cube")}
    kinds["metaballs"] = Kind(("n", "spread", "radius", "jitter", "sharpness"), _metaballs,
                              _metaballs.__doc__)
    kinds["tesseracts"] = Kind(("n", "half", "spread", "rounding", "operation"), _tesseracts,
                               _tesseracts.__doc__)
    kinds["gyroid_ball"] = Kind(("period", "thickness", "radius"), _gyroid_ball, _gyroid_ball.__doc__)
    kinds["lifted"] = Kind(("shape", "path", "op", "size", "aspect", "detail", "height", "k", "offset"),
                           _lifted, _lifted.__doc__)
    return kinds


@functools.cache
def kinds() -> dict[str, Kind]:
    """The registry of family kinds (built on first use: it imports ao4d.fields)."""
    return _kinds()


def __getattr__(name: str) -> Any:
    if name == "KINDS":  # module attribute computed lazily (PEP 562)
        return kinds()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")



def build_shape(kind: str, params: dict, settings: dict, rng: np.random.Generator,
                rotation: np.ndarray | None) -> Shape:
    """Build one item's mesh; errors name the family kind."""
    try:
        return kinds()[kind].build(params, settings, rng, rotation)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"family kind {kind!r} with params {params}: {exc}") from exc
