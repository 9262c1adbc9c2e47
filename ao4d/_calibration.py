"""Time estimates from rates measured on this machine: the ``about N s`` of ``ao4d ao`` and ``render``.

Fixed rates cannot be right everywhere (a GPU traces 50x faster than a 2-core CPU) and a rate
of rays alone leaves out the BVH build and the per-point work, which on large meshes take as
long as the rays. So the first estimate on a device times a short run of the same stages on a
small closed mesh (a spheritorus of ~80,000 tetrahedra on OpenCL): the BVH build, AO at 1 and
at 32 rays per vertex, and two small renders (one that hits the mesh, one that misses it).
That takes ~0.3 s, once: the rates are kept in ``calibration.json`` in the sample-data cache
(:func:`ao4d.data.cache_dir`), keyed by ao4d version, backend and device, and read back by
every later command. A cache that cannot be written only means measuring again next time.

The estimates are a model, ``work / rate`` summed over the stages; a mesh whose rays travel
farther than the calibration mesh's (dense, nested shapes) traces slower, so they are meant
to be right within a factor of two, not better.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

__all__ = ["Rates", "rates", "measure", "ao_seconds", "render_seconds", "ray_rate", "seconds_text", "CACHE_NAME"]

CACHE_NAME = "calibration.json"
# calibration mesh (grid points per axis) and AO rays per vertex, per backend: ~0.3 s each
_GRID = {"opencl": 20, "numpy": 8}
_SAMPLES = {"opencl": 32, "numpy": 4}
_IMAGE = {"opencl": 24, "numpy": 8}
_FLOOR = 1e-4  # s: a stage timed shorter than this is taken as this long (timer noise)

_memo: dict[str, Rates] = {}


@dataclass(frozen=True)
class Rates:
    """Work per second of each stage, measured on one device.

    Attributes
    ----------
    bvh : float
        Simplices per second put into a BVH (build and upload).
    points : float
        AO query points per second, rays aside (normals, origins, launches).
    ao_rays : float
        AO (any-hit) rays per second.
    voxels : float
        Render voxels per second whose primary ray misses (ray and per-voxel work).
    hits : float
        Render hits per second beyond a miss's cost (closest hit, shading).
    setup : float
        Simplices per second of a render's work once per mesh (normals...), after a preview.
    simplices : int
        The calibration mesh's simplices (rays through deeper trees take longer).
    device : str
        The device, as :func:`ao4d.opencl.cl.describe` names it.
    seconds : float
        How long the calibration took.
    """

    bvh: float
    points: float
    ao_rays: float
    voxels: float
    hits: float
    setup: float
    simplices: int
    device: str
    seconds: float


def _key(backend: str, device: str) -> str:
    from . import __version__

    return f"ao4d {__version__} | {backend} | {device}"


def _cache_files() -> list[Path]:
    """Where the rates may be kept: the sample-data cache, then (default cache only) its fallback."""
    from .data import ENV, cache_dir, fallback_dir

    folders = [cache_dir()] if os.environ.get(ENV) else [cache_dir(), fallback_dir()]
    return [folder / CACHE_NAME for folder in folders]


def _read(path: Path) -> dict[str, Any]:
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError):  # absent, unreadable or damaged: measure again
        return {}
    return table if isinstance(table, dict) else {}


def _load(key: str) -> Rates | None:
    names = {f.name for f in fields(Rates)}
    for path in _cache_files():
        entry = _read(path).get(key)
        if isinstance(entry, dict) and set(entry) >= names:
            try:
                return Rates(**{name: entry[name] for name in names})
            except TypeError:
                return None
    return None


def _store(key: str, measured: Rates) -> Path | None:
    from ._atomic import atomic_open

    for path in _cache_files():
        table = _read(path)
        table[key] = asdict(measured)
        try:
            with atomic_open(path, "w") as fh:
                json.dump(table, fh, indent=1, sort_keys=True)
        except OSError:
            continue
        return path
    return None


def rates(runtime: Any, *, say: Any = None) -> Rates:
    """The rates of ``runtime``'s device: from the cache, else measured now (~0.3 s) and kept.

    Parameters
    ----------
    runtime : Runtime or None
        A resolved backend (:func:`ao4d.opencl.cl.resolve_backend`); None is the numpy backend.
    say : callable, optional
        Called with one line before a measurement (so the user knows what the pause is).

    Returns
    -------
    Rates
        The device's rates.
    """
    from .opencl import cl

    backend, device = cl.backend_name(runtime), cl.describe(runtime)
    key = _key(backend, device)
    if key in _memo:
        return _memo[key]
    found = _load(key)
    if found is None:
        if say is not None:
            say(f"timing this device once for the estimates ({backend}; kept in {_cache_files()[0]})")
        found = measure(runtime)
        _store(key, found)
    _memo[key] = found
    return found


def measure(runtime: Any) -> Rates:
    """Time the stages on a small closed 4D mesh on ``runtime`` (nothing cached).

    Parameters
    ----------
    runtime : Runtime or None
        A resolved backend; None is the numpy backend.

    Returns
    -------
    Rates
        The measured rates.
    """
    from . import fields
    from .ao import ambient_occlusion
    from .bvh import get_bvh
    from .marching.march import extract_field
    from .opencl import cl
    from .rays.api import cast_rays
    from .rendering.camera import Camera4D
    from .rendering.pipeline import render

    started = time.perf_counter()
    backend = cl.backend_name(runtime)
    grid, samples, side = _GRID[backend], _SAMPLES[backend], _IMAGE[backend]
    mesh = extract_field(fields.spheritorus(1.0, 0.4), grid, (-1.5, 1.5), progress=False)
    n_v, n_s = mesh.n_vertices, mesh.n_simplices

    def timed(work) -> float:
        t = time.perf_counter()
        work()
        return max(time.perf_counter() - t, _FLOOR)

    build = timed(lambda: get_bvh(mesh, runtime=runtime))
    # a fixed, small workload: never refused by a ray budget (a caller's, or a test's)
    run_ao = dict(seed=0, backend=backend, progress=False, max_rays=math.inf)
    ambient_occlusion(mesh, points=mesh.vertices[:1], normals=[[0.0, 1.0, 0.0, 0.0]], samples=1, **run_ao)
    one = timed(lambda: ambient_occlusion(mesh, samples=1, **run_ao))
    many = timed(lambda: ambient_occlusion(mesh, samples=samples, **run_ao))
    ray_seconds = max(many - one, _FLOOR)

    shape = (side,) * 3
    facing = Camera4D.framing(mesh.bounds)
    away = Camera4D(eye=(0, 0, 0, 4.0), target=(0, 0, 0, 8.0))  # looks away: every ray misses
    options = dict(ao="none", backend=backend, progress=False, max_rays=math.inf)
    # as `ao4d render` does: a preview of the hits first, then the first render (normals...)
    origins, directions = facing.rays((12, 12, 12))
    cast_rays(mesh, origins.reshape(-1, 4), directions.reshape(-1, 4), closest=False, backend=backend)
    first = timed(lambda: render(mesh, facing, shape, **options))
    miss = timed(lambda: render(mesh, away, shape, **options))
    t = time.perf_counter()
    hit = int(render(mesh, facing, shape, **options).hit.sum())
    hitting = max(time.perf_counter() - t, _FLOOR)
    voxels = math.prod(shape)
    return Rates(
        bvh=n_s / build,
        points=n_v / one,
        ao_rays=n_v * (samples - 1) / ray_seconds,
        voxels=voxels / miss,
        hits=max(hit, 1) / max(hitting - miss, _FLOOR),
        setup=n_s / max(first - hitting, _FLOOR),
        simplices=n_s,
        device=cl.describe(runtime),
        seconds=time.perf_counter() - started,
    )


def ao_seconds(r: Rates, *, simplices: int, points: int, rays: float, build: bool = True) -> float:
    """Seconds of :func:`ao4d.ambient_occlusion` on a mesh (BVH build included when ``build``).

    Parameters
    ----------
    r : Rates
        The device's rates.
    simplices : int
        The mesh's simplices (the BVH's size).
    points : int
        Query points (vertices or simplices).
    rays : float
        Rays in all (``points * samples``).
    build : bool
        Count the BVH build (a mesh loaded from a file has none yet).

    Returns
    -------
    float
        The estimate.
    """
    return (simplices / r.bvh if build else 0.0) + points / r.points + rays / ray_rate(r, simplices)


def ray_rate(r: Rates, simplices: int) -> float:
    """AO rays per second through the tree of a mesh of ``simplices``.

    A ray's work grows with the tree's depth, ``log2`` of its size: rates measured on the small
    calibration mesh are scaled by the depth ratio (never up: small trees are not faster than
    the caches make them already).
    """
    depth = math.log2(max(simplices, 2)) / math.log2(max(r.simplices, 2))
    return r.ao_rays / max(depth, 1.0)


def render_seconds(
    r: Rates,
    *,
    voxels: int,
    hits: float,
    simplices: int,
    rays_per_hit: float = 0.0,
    other_rays: float = 0.0,
    other_points: int = 0,
    extra_seconds: float = 0.0,
) -> float:
    """Seconds of :func:`ao4d.render` once the mesh's BVH exists (its first render).

    Parameters
    ----------
    r : Rates
        The device's rates.
    voxels : int
        Voxels (primary rays).
    simplices : int
        The scene's simplices (the BVH's size).
    hits : float
        Expected hits (times the layers a transparent scene composites).
    rays_per_hit : float
        AO (``ao="hits"``) and shadow rays cast from every hit.
    other_rays, other_points : float, int
        Per-vertex AO computed first (``ao="vertices"`` without stored AO): its rays and points.
    extra_seconds : float
        Work estimated otherwise (screen-space look-ups, the denoise filter).

    Returns
    -------
    float
        The estimate.
    """
    return (
        simplices / r.setup
        + voxels / r.voxels
        + hits / r.hits
        + (hits * rays_per_hit + other_rays) / ray_rate(r, simplices)
        + other_points / r.points
        + extra_seconds
    )


def seconds_text(seconds: float) -> str:
    """An estimate in words: ``about 0.4 s``, ``about 12 s``, ``about 3 min``."""
    from ._budget import duration

    if seconds < 9.5:
        return f"about {seconds:.1g} s" if seconds < 1 else f"about {seconds:.1f} s"
    return duration(seconds)
