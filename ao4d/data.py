"""Sample data: small inputs for the examples, made at first use (as ``skimage.data``).

Each function returns the path of one file: a 4D scan (:func:`scan_4d`), a 4D grid
(:func:`grid_4d`), a scene of 4D meshes (:func:`scene`) and a 3D surface (:func:`surface_3d`).
Nothing is downloaded and nothing is shipped: a file is made deterministically the first time it
is asked for (in well under 2 s) and kept in the cache folder (:func:`cache_dir`), written
atomically (:mod:`ao4d._atomic`) so that a run stopped half-way or two processes at once never
leave half a file. The cache is keyed by the ao4d version and a hash of the code that makes the
file: a file made by other code is never reused, it is made again under a new key.

The cache folder is ``$AO4D_DATA_DIR`` when set, else ``$XDG_CACHE_HOME/ao4d`` (by default
``~/.cache/ao4d``). A file already there is read even when the folder cannot be written. When a
file must be made and the default folder cannot be written, the samples go to a folder in the
system's temporary directory instead; when ``AO4D_DATA_DIR`` cannot be written, that is an error
(it names the folder).

On the command line, ``python -m ao4d.data NAME`` makes a sample and prints its path::

    ao4d render "$(python -m ao4d.data scene)" --out scene.vti --size 48

Examples
--------
>>> import ao4d
>>> grid = ao4d.read_grid(ao4d.data.scan_4d())
>>> grid.values.shape
(32, 32, 32, 16)
"""

from __future__ import annotations

import hashlib
import math
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ._optional import require

__all__ = ["cache_dir", "scan_4d", "grid_4d", "scene", "surface_3d", "SAMPLES"]

ENV = "AO4D_DATA_DIR"

# scan_4d: a heart-like bright blob beating and swaying in soft tissue, in Hounsfield-like units
SCAN_SHAPE = (32, 32, 32, 16)  # x, y, z voxels, time frames
SCAN_SPACING_MM = 1.5
SCAN_ORIGIN_MM = (-24.0, -30.0, -12.0)  # scanner coordinates of voxel (0, 0, 0)
SCAN_FRAME_S = 0.1  # seconds between frames; 16 frames = one beat of 1.6 s
SCAN_TISSUE, SCAN_BRIGHT = 40.0, 1000.0  # HU of the background and of the blob's inside

# grid_4d: a spheritorus (its signed distance) on a 24^4 grid over [-1.5, 1.5]^4
GRID_POINTS, GRID_BOUNDS = 24, (-1.5, 1.5)

# scene: the demo scene, coarser than `ao4d demo`'s (grid cell 0.085) so that it is made in ~1 s
SCENE_CELL, SCENE_SAMPLES = 0.12, 64


def cache_dir() -> Path:
    """The folder the samples are kept in (not created here).

    Returns
    -------
    pathlib.Path
        ``$AO4D_DATA_DIR`` when it is set and not empty, else ``$XDG_CACHE_HOME/ao4d`` (an unset or
        relative ``XDG_CACHE_HOME`` means ``~/.cache``, as the XDG specification says).

    Examples
    --------
    >>> import ao4d
    >>> folder = ao4d.data.cache_dir()  # ~/.cache/ao4d unless AO4D_DATA_DIR or XDG_CACHE_HOME say
    >>> ao4d.data.scan_4d().is_relative_to(folder)
    True
    """
    explicit = os.environ.get(ENV)
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "ao4d"


def fallback_dir() -> Path:
    """Where samples go when the default cache cannot be written: one folder per user."""
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    return Path(tempfile.gettempdir()) / f"ao4d-{user}"


def _key(name: str, modules: tuple[str, ...]) -> str:
    """``<version>-<hash>``: the ao4d version and a hash of the files of the code that makes
    sample ``name`` (this module and ``modules``), so that other code makes another file."""
    from . import __version__

    digest = hashlib.sha256(f"{__version__}\0{name}".encode())
    digest.update(Path(__file__).read_bytes())
    for module in modules:
        digest.update((Path(__file__).parent / f"{module.replace('.', '/')}.py").read_bytes())
    return f"{__version__}-{digest.hexdigest()[:12]}"


def _fetch(name: str, filename: str, make: Callable[[Path], None], modules: tuple[str, ...] = ()) -> Path:
    """The path of sample ``name``: the cached file, or ``make(tmp)`` written there atomically."""
    from ._atomic import atomic_path

    relative = Path("data") / f"{name}-{_key(name, modules)}" / filename
    root = cache_dir()
    roots = [root] if os.environ.get(ENV) else [root, fallback_dir()]
    for folder in roots:
        if (folder / relative).is_file():
            return folder / relative
    errors = []
    for folder in roots:
        target = folder / relative
        try:
            with atomic_path(target) as tmp:
                make(tmp)
        except OSError as exc:
            errors.append(f"{folder}: {exc.strerror or exc}")
            continue
        return target
    where = f"{ENV}={errors[0]}" if os.environ.get(ENV) else "; ".join(errors)
    raise OSError(
        f"cannot write sample {name!r} into the ao4d data cache ({where}); set {ENV} to a folder you can write"
    )


# -- the samples ------------------------------------------------------------------------------


def scan_4d() -> Path:
    """A 4D NIfTI scan: a bright blob beating over time, as in a cardiac CT (3D + time).

    Made at first use (in about 0.1 s; 1 MB) from formulas, no real patient: a 32 x 32 x 32
    volume of 1.5 mm voxels over 16 frames 0.1 s apart (one beat of 1.6 s), ``int16`` values
    in Hounsfield-like units: soft tissue of 40 HU around an ellipsoidal blob of 1000 HU
    (contrast-filled, like a heart chamber) whose radii swell by a quarter and shrink again
    over the beat while its centre sways 3 mm along x. The edge is smooth (about 1 mm wide) and
    the values carry noise of 15 HU (seeded: the same bytes every time). A level of 300 HU
    with ``inside="above"`` gives the blob; it is there in every frame, so its 4D solid
    touches the grid's first and last frames and needs ``closed=True`` to be closed.

    Header: ``xyzt_units`` (mm, s); zooms (1.5, 1.5, 1.5, 0.1); an axis-aligned affine
    ``diag(1.5, 1.5, 1.5, 1)`` with the origin ``(-24, -30, -12)`` mm (scanner coordinates of
    voxel (0, 0, 0)); ``toffset`` 0. :func:`ao4d.read_grid` takes x, y, z spacing and origin
    from the affine and, as the time is no length, one frame as one mean spatial step (1.5).

    Returns
    -------
    pathlib.Path
        The ``scan_4d.nii`` file (uncompressed NIfTI-1, so it is memory-mapped).

    Examples
    --------
    >>> import ao4d
    >>> grid = ao4d.read_grid(ao4d.data.scan_4d())
    >>> grid.values.shape, [float(s) for s in grid.spacing], grid.units
    ((32, 32, 32, 16), [1.5, 1.5, 1.5, 1.5], ('mm', 'mm', 'mm', 's'))
    >>> mesh = ao4d.extract(
    ...     grid.values, 300, spacing=grid.spacing, origin=grid.origin, inside="above", closed=True
    ... )
    >>> mesh.check().closed
    True
    """
    return _fetch("scan_4d", "scan_4d.nii", _make_scan)


def _scan_values() -> np.ndarray:
    """The values of :func:`scan_4d`, ``(32, 32, 32, 16) int16`` (HU), made from the formulas."""
    nx, ny, nz, nt = SCAN_SHAPE
    axes = [np.arange(n) * SCAN_SPACING_MM + o for n, o in zip((nx, ny, nz), SCAN_ORIGIN_MM)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    centre = np.array(SCAN_ORIGIN_MM) + SCAN_SPACING_MM * (np.array((nx, ny, nz)) - 1) / 2
    radii = np.array((10.0, 8.5, 7.0))  # mm, at the middle of the beat
    values = np.empty(SCAN_SHAPE, dtype=np.float64)
    for frame in range(nt):
        phase = 2 * math.pi * frame / nt
        swell = 1 + 0.12 * math.sin(phase)  # radii x 0.88 .. 1.12
        cx = centre[0] + 3.0 * math.sin(phase)
        # distance-like coordinate (mm): 0 on the ellipsoid, negative inside
        rho = np.sqrt(
            ((x - cx) / radii[0]) ** 2 + ((y - centre[1]) / radii[1]) ** 2 + ((z - centre[2]) / radii[2]) ** 2
        )
        inside = 0.5 * (1 - np.tanh((rho - swell) * radii.mean() / 1.0))  # ~1 mm wide edge
        values[..., frame] = SCAN_TISSUE + (SCAN_BRIGHT - SCAN_TISSUE) * inside
    values += np.random.default_rng(59).normal(0.0, 15.0, SCAN_SHAPE)
    return np.rint(values).astype(np.int16)


def _make_scan(path: Path) -> None:
    nib = require("nibabel", "the example scan (NIfTI)", extra="io")
    affine = np.diag([SCAN_SPACING_MM] * 3 + [1.0])
    affine[:3, 3] = SCAN_ORIGIN_MM
    image = nib.Nifti1Image(_scan_values(), affine)
    header = image.header
    header.set_xyzt_units("mm", "sec")
    header.set_zooms((SCAN_SPACING_MM,) * 3 + (SCAN_FRAME_S,))
    header["descrip"] = b"ao4d.data.scan_4d: synthetic beating blob, HU"
    header.set_qform(affine, code="scanner")
    header.set_sform(affine, code="scanner")
    nib.save(image, str(path))


def grid_4d() -> Path:
    """A 4D ``.npy`` grid: the signed distance of a spheritorus, negative inside.

    Made at first use (in about 0.05 s; 1.3 MB): :func:`ao4d.sample` of
    ``ao4d.fields.spheritorus(1.0, 0.4)`` (a 4D torus: the points within 0.4 of a unit
    2-sphere in the x, y, z space) on 24 points per axis over [-1.5, 1.5], ``(24, 24, 24, 24)
    float32``. A ``.npy`` file has no spacing: give it (3 / 23 between points, the first at
    -1.5) or work in grid units. The default level 0 and ``inside="below"`` give the surface.

    Returns
    -------
    pathlib.Path
        The ``grid_4d.npy`` file.

    Examples
    --------
    >>> import numpy as np, ao4d
    >>> values = np.load(ao4d.data.grid_4d())
    >>> values.shape, values.dtype.name
    ((24, 24, 24, 24), 'float32')
    >>> mesh = ao4d.extract(values, spacing=3 / 23, origin=-1.5)
    >>> mesh.check().closed
    True
    """
    return _fetch("grid_4d", "grid_4d.npy", _make_grid)


def _make_grid(path: Path) -> None:
    from . import fields
    from .fields import sample

    values = sample(fields.spheritorus(1.0, 0.4), GRID_POINTS, GRID_BOUNDS).astype(np.float32)
    with open(path, "wb") as fh:
        np.save(fh, values)


def scene() -> Path:
    """The demo scene as ``ao4d demo`` saves it (``scene.npz``), on a coarser grid.

    Made at first use (in about 1 s; 1 MB): :func:`ao4d.scenes.default_scene` (a ground slab
    and, on it, a hypersphere, a torisphere and an indented tesseract), each object extracted
    with :func:`ao4d.scenes.extract_scene` at a grid cell of 0.12 world units (``ao4d demo``:
    0.085) and joined: 31,274 vertices, 184,684 tetrahedra, closed, with ``cell_data
    ["object_id"]`` (0 ground, 1 hypersphere, 2 torisphere, 3 tesseract) and ``point_data
    ["ao"]``, the 4D ambient occlusion of 64 rays per vertex (seed 0, the scene's reach) on the
    default device. World units, y up; the objects span x in [-2.7, 2.7], y in [-0.24, 1.5].
    The occlusion is traced in float32 on the device, so another device may give a few
    vertices one ray more or less (the geometry is the same bits everywhere).

    Returns
    -------
    pathlib.Path
        The ``scene.npz`` file (:meth:`ao4d.SimplexMesh.load`; ``ao4d render``, ``ao4d ao``...).

    Examples
    --------
    >>> import ao4d
    >>> mesh = ao4d.SimplexMesh.load(ao4d.data.scene())
    >>> mesh.n_simplices, sorted(mesh.point_data), sorted(mesh.cell_data)
    (184684, ['ao'], ['object_id'])
    """
    return _fetch("scene", "scene.npz", _make_scene, modules=("scenes",))


def _make_scene(path: Path) -> None:
    from .ao import ambient_occlusion
    from .mesh import concatenate
    from .scenes import default_scene, extract_scene

    definition = default_scene()
    mesh = concatenate(extract_scene(definition, cell=SCENE_CELL, progress=False))
    mesh.point_data["ao"] = ambient_occlusion(
        mesh, samples=SCENE_SAMPLES, seed=0, max_distance=definition.max_distance, progress=False
    )
    mesh.save(path)


def surface_3d() -> Path:
    """A closed 3D triangle mesh for :mod:`ao4d.lift`: a bunny-like blob with two ears (PLY).

    Made at first use (in about 0.05 s; 30 kB): trimesh's icosphere (3 subdivisions, 642
    vertices, 1280 triangles) with every vertex moved along its direction ``u`` to the radius
    ``1 + 0.9 exp(-|u - e|^2 / 0.08)`` for two ear directions ``e`` (up, leaning apart) and a
    small tail, then scaled by (1, 0.8, 0.8). The surface is watertight, outward oriented
    (positive volume) and star-shaped about the origin (every ray from it leaves once), so
    :func:`ao4d.lift.tetrahedralize` cuts it exactly, without fTetWild. Lengths have no unit;
    it spans about [-1, 1] x [-0.8, 1.4] x [-1, 0.8]. Binary little-endian PLY.

    Returns
    -------
    pathlib.Path
        The ``surface_3d.ply`` file.

    Examples
    --------
    >>> import ao4d
    >>> surface = ao4d.lift.load_surface(ao4d.data.surface_3d())
    >>> surface.is_watertight, bool(surface.volume > 0)
    (True, True)
    >>> ao4d.lift.prism(surface, 0.5).check().closed
    True
    """
    return _fetch("surface_3d", "surface_3d.ply", _make_surface)


def _make_surface(path: Path) -> None:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    u = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    bumps = ((0.9, (0.35, 0.93, 0.1)), (0.9, (-0.35, 0.93, 0.1)), (0.25, (0.0, 0.2, -0.98)))
    radius = np.ones(len(u))
    for height, direction in bumps:
        e = np.asarray(direction) / np.linalg.norm(direction)
        radius += height * np.exp(-np.sum((u - e) ** 2, axis=1) / 0.08)
    vertices = u * radius[:, None] * np.array([1.0, 0.8, 0.8])
    surface = trimesh.Trimesh(vertices, sphere.faces, process=False)
    with open(path, "wb") as fh:
        fh.write(trimesh.exchange.ply.export_ply(surface, encoding="binary", include_attributes=False))


SAMPLES: dict[str, Callable[[], Path]] = {
    "scan_4d": scan_4d,
    "grid_4d": grid_4d,
    "scene": scene,
    "surface_3d": surface_3d,
}


def _main(argv: list[str]) -> int:
    """``python -m ao4d.data [NAME ...]``: make the samples named and print their paths."""
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m ao4d.data NAME [NAME ...]   (makes the samples, prints their paths)")
        for name, func in SAMPLES.items():
            print(f"  {name:<11} {(func.__doc__ or '').splitlines()[0]}")
        print(f"cache: {cache_dir()} (${ENV} sets it)")
        return 0 if argv else 2
    unknown = [name for name in argv if name not in SAMPLES]
    if unknown:
        print(f"unknown sample {unknown[0]!r}; choose from {', '.join(SAMPLES)}", file=sys.stderr)
        return 2
    for name in argv:
        print(SAMPLES[name]())
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
