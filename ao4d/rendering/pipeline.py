"""Render 4D meshes into 3D image volumes with a :class:`~ao4d.rendering.camera.Camera4D`.

One primary ray per voxel (closest hit through :func:`ao4d.rays.api.trace`). At a hit with
ambient occlusion ``A`` (DESIGN.md definition), normal ``n`` turned towards the viewer and, per
light k, unit direction ``l_k`` towards it, shadow visibility ``V_k`` and intensity ``I_k``::

    shade = [ambient * (1 - A)
             + sum_k I_k V_k (diffuse * max(0, n . l_k) + specular * max(0, n . h_k)^shininess)]
            * cue(depth)

with ``h_k`` the 4D Blinn-Phong half-vector of ``l_k`` and the direction to the eye, the
specular term only where ``n . l_k > 0``, and ``cue`` the depth cue (:mod:`ao4d.rendering.lighting`; 1
without ``depth_cue``). ``V_k`` is 1, or with ``shadows=True`` 0 where an any-hit 4D shadow ray
from the hit finds the light blocked (with transparent objects: the product of ``1 - opacity``
over the surfaces the shadow ray crosses). The colour of a hit on an object of RGB colour ``c`` is::

    rgb = [c * (ambient * (1 - A) + sum_k I_k V_k C_k diffuse max(0, n . l_k))
           + sum_k I_k V_k C_k specular max(0, n . h_k)^shininess] * cue(depth)

(``C_k`` the light's colour; clipped to [0, 1]). Objects with opacity below 1 are composited
front to back over the first ``layers`` (default :data:`MAX_LAYERS` = 4) surfaces along each
ray: a further closest-hit ray is cast from just past (1e-4 bounding-box diagonals) each
transparent hit. With ``light=`` a
direction (one white light), ``specular=0``, ``shadows=False`` and no depth cue, ``shade`` is
``ambient * (1 - A) + diffuse * max(0, n . l)`` to the bit: terms whose weight is 0 or factor
is 1 are left out of the sum, not added as zeros or multiplied in.

With ``ao="screen"`` the occlusion comes from the image itself (:mod:`ao4d.rendering.screen_ao`): the first
hits' depths, points and viewer-facing normals form a depth volume, and every shaded hit (those
behind transparent surfaces too, against the same first-hit volume) reads its occlusion there.

Background voxels have shade 0, depth inf, object id -1 and RGBA (0, 0, 0, 0).

Why this stays one module: the shading model above, the layers behind transparent hits, the
shadow rays and the ray budget all work on the same hits and materials, and one function
(:func:`render`) drives them in order; split, each part would need the others' private state.

References
----------
S. R. Hollasch, "Four-Space Visualization of 4D Objects", MSc thesis, Arizona State University,
1991 (4D ray tracing into a 3D voxel image: highlights, shadows, transparency, depth cueing).
T. Porter and T. Duff, "Compositing digital images", SIGGRAPH 1984, doi:10.1145/800031.808606.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .. import _progress
from .._budget import RAYS_PER_SECOND, check_rays
from .._validate import (
    as_array,
    as_real,
    check_bool,
    check_choice,
    check_int,
    check_memory,
    check_positive_int,
    check_seed,
)
from ..ao import ORIGIN_OFFSET, ambient_occlusion
from ..io.volumes import write_mhd, write_vti
from ..mesh import SimplexMesh, as_meshes, concatenate, warn_if_inside_out
from ..opencl import cl
from ..rays.api import trace
from ..rays.rows import Tracer, check_distance
from .camera import Camera4D, ImageGeometry, image_shape
from .compositing import over, unpremultiply
from .lighting import Light, as_lights, blinn_phong, check_depth_cue, depth_cue, lambert
from .screen_ao import (
    DENOISE_PER_SECOND,
    LOOKUPS_PER_SECOND,
    DepthVolume,
    check_samples,
    default_steps,
    march_steps,
    screen_space_occlusion,
    viewer_side,
)
from .screen_ao import denoise as denoise_occlusion

__all__ = [
    "render",
    "RenderResult",
    "prepare_scene",
    "ShadeRangeWarning",
    "MAX_LAYERS",
    "default_weights",
]

# Default shading weights (the command line uses the same): 1 - AO alone without a light; with
# lights 0.7 (1 - AO) + 0.3 Lambert, so one light of intensity 1 keeps shade in [0, 1].
AMBIENT, AMBIENT_LIT, DIFFUSE = 1.0, 0.7, 0.3

# Rays per trace call: bounds the host memory of refining hits (float64 simplex frames) and
# lets tqdm show progress.
_CHUNK = 1 << 16
# Show progress by default only for images with at least this many voxels.
_PROGRESS_VOXELS = 1 << 18
# Surfaces composited along one ray by default (and the most a shadow ray lets light through).
MAX_LAYERS = 4
_LAYER_LIMIT = 16  # largest `layers` accepted
# Accumulated opacity at which a ray counts as opaque (no further layer is traced).
_OPAQUE = 1.0 - 1e-6


@dataclass
class RenderResult:
    """A rendered 3D image and what each voxel's ray hit.

    Attributes
    ----------
    shade : (nx, ny, nz) float32
        The grey illumination of the first hit (module docstring); 0 on background.
    depth : (nx, ny, nz) float32
        Ray parameter of the first hit (distance from the eye for perspective, from the eye's
        hyperplane for orthographic); inf on background.
    object_id : (nx, ny, nz) int32
        Index of the mesh hit first (order of the list given to :func:`render`); -1 on
        background.
    occlusion : (nx, ny, nz) float32
        Ambient occlusion ``A`` at the first hit (0 where ``ao="none"``); NaN on background.
    rgba : (nx, ny, nz, 4) float32
        Colour in [0, 1] composited front to back over up to ``layers`` surfaces, *not*
        premultiplied by alpha; alpha is the accumulated opacity (1 where an opaque object is
        hit, 0 on background). Shown over a background colour ``b``: ``rgb * a + b * (1 - a)``.
    camera : Camera4D
    geometry : ImageGeometry
        Voxel spacing and origin on the image hyperplane (what volume files store).
    info : dict
        Counts and timings: ``primary_rays``, ``layer_rays`` (rays past transparent hits),
        ``shadow_rays``, ``ao_rays``, ``screen_lookups`` (depth-volume look-ups of
        ``ao="screen"``, an upper bound), ``hits``; ``primary_seconds``, ``layer_seconds``,
        ``shadow_seconds``, ``ao_seconds``, ``seconds`` (the whole call); ``backend``, the one
        that ran (``"opencl"`` or ``"numpy"``), with ``device``, its description
        (:func:`ao4d.opencl.cl.describe`).
    """

    shade: np.ndarray
    depth: np.ndarray
    object_id: np.ndarray
    occlusion: np.ndarray
    rgba: np.ndarray
    camera: Camera4D
    geometry: ImageGeometry
    info: dict = field(default_factory=dict)

    @property
    def hit(self) -> np.ndarray:
        """(nx, ny, nz) bool: voxels whose ray hit the scene."""
        return self.object_id >= 0

    @property
    def rgba8(self) -> np.ndarray:
        """(nx, ny, nz, 4) uint8: :attr:`rgba` scaled to 0..255 (what ``.vti`` files store)."""
        return np.round(np.clip(self.rgba, 0.0, 1.0) * 255.0).astype(np.uint8)

    def __repr__(self) -> str:
        info = self.info
        shape = "x".join(map(str, self.shade.shape))
        hits = int(info.get("hits", int(self.hit.sum())))
        parts = [
            f"{k} {info[f'{k}_seconds']:.2f} s"
            for k in ("primary", "layer", "shadow", "ao")
            if info.get(f"{k}_seconds")
        ]
        timing = f", {info['seconds']:.2f} s ({', '.join(parts)})" if "seconds" in info else ""
        return (
            f"RenderResult({shape} voxels, {hits:,} hit ({hits / max(self.shade.size, 1):.0%})"
            f", backend={info.get('backend')!r}{timing})"
        )

    def _repr_html_(self) -> str:
        """The image's ray-marching page (:mod:`ao4d.browser.image_viewer`), shown inline in Jupyter."""
        from ..browser.pages import inline

        return inline(self)._repr_html_()

    def save(self, path: str | os.PathLike) -> Path:
        """Write the image: ``.vti`` holds every array; ``.mhd`` holds the shade.

        The ``.vti`` arrays are ``shade`` (active), ``depth``, ``object_id``, ``occlusion`` and
        ``rgba``: 4 unsigned-char components (:attr:`rgba8`), which ParaView shows as the
        voxels' own colours when *Map Scalars* is unticked (Coloring: ``rgba``; for volume
        rendering also untick *Map Scalars*, and the 4th component sets opacity). Background
        depth and occlusion are stored as NaN (ParaView and ITK leave NaN out of colour ranges;
        inf would stretch them).

        Parameters
        ----------
        path : str or path-like
            The file to write, ending in ``.vti`` or ``.mhd``.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        path = Path(path)
        spacing, origin = self.geometry.spacing, self.geometry.origin
        suffix = check_choice(path.suffix.lower(), "path extension", (".mhd", ".vti"))
        if suffix == ".mhd":
            return write_mhd(path, self.shade, spacing=spacing, origin=origin)
        depth = np.where(self.hit, self.depth, np.nan).astype(np.float32)
        arrays = {
            "shade": self.shade,
            "depth": depth,
            "object_id": self.object_id,
            "occlusion": self.occlusion,
            "rgba": self.rgba8,
        }
        return write_vti(path, arrays, spacing=spacing, origin=origin)


def default_weights(ambient: float | None, diffuse: float | None, lit: bool) -> tuple[float, float]:
    """``(ambient, diffuse)`` with the defaults filled in.

    Parameters
    ----------
    ambient, diffuse : float or None
        The weights given, None for the default.
    lit : bool
        Whether there is a light.

    Returns
    -------
    tuple of float
        ``ambient`` (default 1 without a light and 0.7 with one) and ``diffuse`` (default 0.3):
        their sum stays at most 1 for one light of intensity 1.
    """
    ambient = (AMBIENT_LIT if lit else AMBIENT) if ambient is None else as_real(ambient, "ambient", ge=0)
    diffuse = DIFFUSE if diffuse is None else as_real(diffuse, "diffuse", ge=0)
    return ambient, diffuse


def _check_vertex_ao(values: np.ndarray, scene, name: str) -> np.ndarray:
    """Per-vertex AO as float64, refused where it would shade wrongly (NaN or outside [0, 1] at
    vertices that simplices use)."""
    values = np.asarray(values, dtype=np.float64)
    used = np.zeros(scene.n_vertices, dtype=bool)
    used[scene.simplices.ravel()] = True
    bad_nan = used & ~np.isfinite(values)
    if bad_nan.any():
        raise ValueError(
            f"`{name}` is NaN at {int(bad_nan.sum())} vertices that simplices use "
            f"(first: vertex {int(np.argmax(bad_nan))}); recompute it with ao4d.ambient_occlusion"
        )
    outside = used & ((values < 0) | (values > 1))
    if outside.any():
        raise ValueError(
            f"`{name}` must be occlusion in [0, 1], got values in [{values[used].min():.4g}, {values[used].max():.4g}]"
        )
    return values


def _given_ao(ao, meshes, scene) -> np.ndarray:
    """``render(ao=...)`` given as values: one (V,) array for the joined scene, or one array
    per mesh of the list (joined in the list's order, as the vertices are)."""
    per_mesh = (
        isinstance(meshes, Sequence)
        and isinstance(ao, (list, tuple))
        and len(ao) == len(meshes)
        and all(np.ndim(item) == 1 for item in ao)
    )
    if per_mesh:
        parts = [as_array(item, f"ao[{k}]", ndim=1, dtype=np.float64) for k, item in enumerate(ao)]
        for k, (part, mesh) in enumerate(zip(parts, meshes)):
            if len(part) != mesh.n_vertices:
                raise ValueError(
                    f"`ao[{k}]` must hold one value per vertex of meshes[{k}] ({mesh.n_vertices}), got {len(part)}"
                )
        values = np.concatenate(parts)
    else:
        values = as_array(ao, "ao", ndim=1, dtype=np.float64)
        if len(values) != scene.n_vertices:
            raise ValueError(
                f"`ao` must hold one value per vertex ({scene.n_vertices}), or be one of "
                f"'vertices', 'hits', 'screen', 'none'; got {len(values)} values"
            )
    return _check_vertex_ao(values, scene, "ao")


def _check_weights(ambient: float, diffuse: float, specular: np.ndarray, lights) -> None:
    """Say when the weights let shade exceed 1."""
    lit = sum(light.intensity for light in lights)
    brightest = ambient + lit * (diffuse + float(np.max(specular, initial=0.0)))
    if brightest > 1 + 1e-9:
        import warnings

        warnings.warn(
            f"`ambient` + light intensity x (`diffuse` + `specular`) = {brightest:.3g} > 1: shade can "
            "exceed 1 (it is in [0, 1] when they sum to at most 1)",
            ShadeRangeWarning,
            stacklevel=4,
        )


class ShadeRangeWarning(UserWarning):
    """The shading weights allow shade above 1."""


def prepare_scene(meshes) -> tuple[Any, np.ndarray]:
    """One SimplexMesh for a mesh or a list of meshes, and the object id of each simplex.

    Parameters
    ----------
    meshes : SimplexMesh, (vertices, simplices), or a sequence of them
        4D meshes, each in any form :func:`ao4d.mesh.as_mesh` takes. A single SimplexMesh is used as is (not copied, so its cached BVH is reused) and
        keeps the ``cell_data["object_id"]`` it may carry (e.g. a saved scene), else id 0. A
        list of several is joined with :func:`ao4d.mesh.concatenate` (ids = list positions).

    Returns
    -------
    scene : SimplexMesh
        The joined mesh.
    object_id : (S,) int32
        The object id of each simplex.
    """
    items = as_meshes(meshes)
    scene = items[0] if len(items) == 1 else concatenate(items)
    if scene.dim != 4:
        raise ValueError(f"`meshes` must be 4D meshes (tetrahedra in R^4), got dimension {scene.dim}")
    if scene.n_simplices == 0:
        raise ValueError("`meshes` holds no simplices: nothing to render")
    ids = scene.cell_data.get("object_id")
    if ids is None or (len(items) == 1 and not isinstance(meshes, SimplexMesh)):
        ids = np.zeros(scene.n_simplices, dtype=np.int32)
    return scene, np.asarray(ids, dtype=np.int32)


def render(
    meshes,
    camera: Camera4D,
    shape=(64, 64, 64),
    *,
    ao: Literal["vertices", "hits", "screen", "none"] | Any = "vertices",
    samples: int = 64,
    max_distance: float = math.inf,
    seed: int = 0,
    denoise: int = 0,
    ambient: float | None = None,
    light=None,
    diffuse: float | None = None,
    specular=0.0,
    shininess=32.0,
    shadows: bool = False,
    depth_cue=None,
    color=None,
    opacity=None,
    layers: int = MAX_LAYERS,
    shading: Literal["smooth", "flat"] = "smooth",
    backend: Literal["auto", "opencl", "numpy"] = "auto",
    progress: bool | None = None,
    max_rays: float | None = None,
) -> RenderResult:
    """Render 4D meshes into a 3D image volume (one primary ray per voxel).

    Parameters
    ----------
    meshes : SimplexMesh, (vertices, simplices), or a sequence of them
        4D meshes (closed surfaces or raw open tetrahedra), each in any form
        :func:`ao4d.mesh.as_mesh` takes. Lists are joined; the result's
        ``object_id`` is the list position (a single mesh keeps its ``cell_data["object_id"]``).
    camera : Camera4D
        The 4D camera; its image hyperplane holds the 3D image.
    shape : (3,) tuple of int
        Image size ``(nx, ny, nz)`` along the camera's image axes.
    ao : {"vertices", "hits", "screen", "none"} or array_like
        ``"vertices"``: per-vertex occlusion from ``mesh.point_data["ao"]`` (computed with
        :func:`ao4d.ambient_occlusion` when absent) interpolated with the hit's barycentric
        weights. An array: that per-vertex occlusion (in [0, 1]), shaded as ``"vertices"``:
        ``(V,)`` for the mesh (the joined list), or one ``(V_k,)`` array per mesh of a list. ``"hits"``: occlusion computed at every hit point with the normal facing the
        viewer (exact per voxel and right for open, two-sided geometry). ``"screen"``: 4D
        screen-space AO at every hit, read from the image's own depth volume (first hits,
        their points and viewer-facing normals) with the same directions as ``"hits"``
        (:func:`ao4d.rendering.screen_ao.screen_space_occlusion`, :func:`ao4d.rendering.screen_ao.default_steps` look-ups
        per direction; no AO rays): fast, but blind to what the image does not show.
        ``"none"``: A = 0.
    samples : int
        Hemisphere rays (``"screen"``: directions) per AO estimate (when AO is computed here).
    max_distance : float
        AO ray length (inf: any hit occludes; ``"screen"`` then marches to the diagonal of the
        visible points' bounding box).
    seed : int
        AO random seed, in ``[0, 2**32)`` (results are deterministic).
    denoise : int
        With ``ao="screen"``: radius in voxels of the depth- and normal-aware box filter
        (:func:`ao4d.rendering.screen_ao.denoise`) applied to the first hits' occlusion before shading, so
        that few ``samples`` suffice; 0 (default) for none.
    ambient : float, optional
        Weight of the ambient term ``1 - A`` (default 1 without a light, 0.7 with lights). Shade
        stays in [0, 1] when ``ambient + (sum of light intensities) * (diffuse + specular)`` is
        at most 1; weights above that give a :class:`ShadeRangeWarning`.
    light : (4,) array_like, Light, or sequence of Light, optional
        A 4-vector is the direction *towards* one white directional light of intensity 1 (as
        always); :class:`ao4d.Light` gives directional or point lights with colour and
        intensity, several in a list.
    diffuse : float, optional
        Weight of the Lambert term (default 0.3; no effect without a light).
    specular : float or (n_objects,) array_like
        Weight of the 4D Blinn-Phong term, for all objects or one per object id (>= 0).
    shininess : float or (n_objects,) array_like
        Blinn-Phong exponent (> 0), for all objects or per object.
    shadows : bool
        Cast a 4D shadow ray from every lit hit towards each light (any-hit, from the hit
        moved ``1e-4`` bounding-box diagonals along its viewer-facing normal, as AO rays are);
        a blocked light adds nothing there. Transparent objects let ``1 - opacity`` of the light
        through per surface crossed (up to ``layers`` surfaces; farther ones are not counted).
        A point light is blocked only by geometry between the hit and the light.
    depth_cue : (3,) array_like, optional
        ``(near, far, strength)``: shade and colour are multiplied by ``1 - strength *
        clip((t - near) / (far - near), 0, 1)`` with ``t`` the 4D distance along the view ray
        (:func:`ao4d.rendering.lighting.depth_cue`); ``0 <= near < far``, ``strength`` in [0, 1].
    color : (3,) or (n_objects, 3) array_like, optional
        RGB in [0, 1] of all objects, or one row per object id; default white (then ``rgba``
        is the clipped ``shade`` for white lights).
    opacity : float or (n_objects,) array_like, optional
        Opacity in [0, 1] of all objects or per object; default 1 (opaque). Below 1, further
        surfaces along the ray show through it.
    layers : int
        Surfaces composited front to back along a ray (1..16; default 4): a ray ends after
        ``layers`` hits or at its first opaque hit.
    shading : {"smooth", "flat"}
        Shading normals interpolated from vertex normals, or the hit simplex's own.
    backend : {"auto", "opencl", "numpy"}
        Resolved once (:func:`ao4d.opencl.cl.resolve_backend`); primary, layer and shadow rays
        (:func:`ao4d.rays.api.trace`) and AO (:func:`ao4d.ambient_occlusion`) all run on it.
    progress : bool, optional
        Progress bars (:mod:`ao4d._progress`: silenced by ``--no-progress``); default on for
        images of 2^18 voxels or more.
    max_rays : float, optional
        Refuse, before any work, a render whose rays (primary, AO, shadow and layer rays, an
        upper bound) exceed this; default :data:`ao4d._budget.MAX_RAYS` of the backend
        (about half an hour of work), ``math.inf`` for no limit (CLI: ``--force``).

    Returns
    -------
    RenderResult
        ``shade``, ``depth``, ``object_id``, ``occlusion`` (first hit), ``rgba`` (composited).

    Raises
    ------
    ValueError
        Bad shape, negative weights, zero light direction, colours or opacities out of [0, 1],
        per-object values whose length is not the number of objects, non-4D meshes, empty
        scene.

    Examples
    --------
    >>> import ao4d
    >>> sphere = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (16,) * 4, (-1.2, 1.2))
    >>> cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.5)
    >>> image = ao4d.render(sphere, cam, (16, 16, 16), ao="none", color=(1, 0.5, 0))
    >>> bool(image.hit[8, 8, 8]), bool(image.hit[0, 0, 0])
    (True, False)
    >>> [float(x) for x in image.rgba[8, 8, 8]]  # ambient 1, no light: the object's colour
    [1.0, 0.5, 0.0, 1.0]
    """
    started = time.perf_counter()
    opts = _Options.check(
        camera,
        shape,
        ao=ao,
        samples=samples,
        max_distance=max_distance,
        seed=seed,
        denoise=denoise,
        ambient=ambient,
        light=light,
        diffuse=diffuse,
        shadows=shadows,
        depth_cue=depth_cue,
        layers=layers,
        shading=shading,
        backend=backend,
        progress=progress,
    )
    scene = _Scene.of(meshes, opts, ao, color=color, opacity=opacity, specular=specular, shininess=shininess)
    runtime = cl.resolve_backend(backend)
    name = cl.backend_name(runtime)  # what runs: every stage on the same device
    _check_budget(scene, opts, camera, name, max_rays)
    if opts.ao == "hits" or (opts.ao == "vertices" and scene.vertex_ao is None):
        # only AO computed here: given or stored AO was checked where it was made, and the
        # check costs a pass over every simplex
        warn_if_inside_out(scene.mesh, "AO is 1 on its surface and the image dark")
    run = _Run(
        opts=opts,
        scene=scene,
        backend=name,
        tracer=Tracer.of(scene.mesh, runtime),
        stats=_Stats(primary_rays=math.prod(opts.shape), backend=name, device=cl.describe(runtime)),
    )
    stats = run.stats

    origins, directions = (a.reshape(-1, 4) for a in camera.rays(opts.shape))
    tick = time.perf_counter()
    t, simplex, bary = _cast(run, origins, directions, "primary rays")
    stats.primary_seconds = time.perf_counter() - tick
    hit = simplex >= 0
    stats.hits = int(hit.sum())
    rows = np.flatnonzero(hit)
    if rows.size:
        run = _with_first_hits(run, camera, directions, t, simplex)
    first = _shade(
        run,
        origins[rows] + t[rows, None] * directions[rows],
        directions[rows],
        t[rows],
        simplex[rows],
        bary[rows],
        first=True,
    )
    rgba = _composite_rays(run, origins, directions, rows, t[rows], simplex[rows], first)
    stats.seconds = time.perf_counter() - started
    shape = opts.shape
    return RenderResult(
        shade=_scatter(shape, hit, first.shade, 0.0, np.float32),
        depth=_scatter(shape, hit, t[hit], np.inf, np.float32),
        object_id=_scatter(shape, hit, scene.object_ids[simplex[hit]], -1, np.int32),
        occlusion=_scatter(shape, hit, first.occlusion, np.nan, np.float32),
        rgba=rgba.reshape(shape + (4,)),
        camera=camera,
        geometry=camera.geometry(shape),
        info=stats.as_dict(),
    )


# -- options, scene, statistics: fixed before the first ray --------------------------------------


@dataclass(frozen=True)
class _Options:
    """:func:`render`'s options, validated once."""

    shape: tuple[int, int, int]
    ao: str  # "vertices", "hits", "screen" or "none" ("vertices" when values are given)
    samples: int
    max_distance: float
    seed: int
    denoise: int
    ambient: float
    diffuse: float
    lights: tuple[Light, ...]
    shadows: bool
    cue: tuple[float, float, float] | None
    layers: int
    shading: str
    show: bool

    @classmethod
    def check(
        cls,
        camera,
        shape,
        *,
        ao,
        samples,
        max_distance,
        seed,
        denoise,
        ambient,
        light,
        diffuse,
        shadows,
        depth_cue,
        layers,
        shading,
        backend,
        progress,
    ) -> _Options:
        if not isinstance(camera, Camera4D):
            raise TypeError(f"`camera` must be an ao4d.Camera4D, got {type(camera).__name__}")
        shape = image_shape(shape)
        ao = check_choice(ao, "ao", _AO_MODES) if isinstance(ao, str) else "vertices"
        check_choice(shading, "shading", ("smooth", "flat"))
        check_choice(backend, "backend", cl.BACKENDS)
        denoise = check_int(denoise, "denoise", minimum=0)
        if denoise and ao != "screen":
            raise ValueError(f"`denoise` filters screen-space AO: it needs ao='screen', got ao={ao!r}")
        lights = as_lights(light, "light")
        ambient, diffuse = default_weights(ambient, diffuse, bool(lights))
        layers = check_positive_int(layers, "layers")
        if layers > _LAYER_LIMIT:
            raise ValueError(f"`layers` must be <= {_LAYER_LIMIT}, got {layers}")
        n_voxels = math.prod(shape)
        check_memory(n_voxels * 4 * 8 * 10, "rendering an image of this shape")
        return cls(
            shape=shape,
            ao=ao,
            samples=check_samples(samples) if ao == "screen" else check_positive_int(samples, "samples"),
            max_distance=check_distance(max_distance),
            seed=check_seed(seed),
            denoise=denoise,
            ambient=ambient,
            diffuse=diffuse,
            lights=lights,
            shadows=check_bool(shadows, "shadows"),
            cue=check_depth_cue(depth_cue),
            layers=layers,
            shading=shading,
            show=n_voxels >= _PROGRESS_VOXELS if progress is None else bool(progress),
        )


_AO_MODES = ("vertices", "hits", "screen", "none")


@dataclass(frozen=True)
class _Material:
    """Per-object properties, indexed by object id."""

    color: np.ndarray  # (n, 3)
    opacity: np.ndarray  # (n,)
    specular: np.ndarray  # (n,)
    shininess: np.ndarray  # (n,)

    @property
    def opaque(self) -> bool:
        return bool((self.opacity >= 1.0).all())


@dataclass(frozen=True)
class _Scene:
    """The joined mesh and what shading reads of it, fetched once."""

    mesh: Any
    object_ids: np.ndarray  # (S,) per simplex
    material: _Material
    simplices: np.ndarray  # (S, 4)
    simplex_normals: np.ndarray  # (S, 4)
    vertex_normals: np.ndarray | None  # (V, 4), for smooth shading with lights
    vertex_ao: np.ndarray | None  # (V,) given or stored per-vertex AO
    offset: float  # how far rays leave a surface: ORIGIN_OFFSET bounding-box diagonals
    diagonal: float  # of the bounding box

    @classmethod
    def of(cls, meshes, opts: _Options, ao, *, color, opacity, specular, shininess) -> _Scene:
        mesh, object_ids = prepare_scene(meshes)
        n_objects = int(object_ids.max()) + 1
        material = _Material(
            color=_per_object(color, "color", n_objects, (1.0, 1.0, 1.0), unit=True),
            opacity=_per_object(opacity, "opacity", n_objects, 1.0, unit=True),
            specular=_per_object(specular, "specular", n_objects, 0.0, unit=False),
            shininess=_per_object(shininess, "shininess", n_objects, 32.0, unit=False, positive=True),
        )
        vertex_ao = None
        if not isinstance(ao, str):
            vertex_ao = _given_ao(ao, meshes, mesh)
        elif opts.ao == "vertices" and "ao" in mesh.point_data:
            vertex_ao = _check_vertex_ao(mesh.point_data["ao"], mesh, "point_data['ao']")
        _check_weights(opts.ambient, opts.diffuse, material.specular, opts.lights)
        lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
        diagonal = float(np.linalg.norm(hi - lo))
        smooth = opts.lights and opts.shading == "smooth"
        return cls(
            mesh=mesh,
            object_ids=object_ids,
            material=material,
            simplices=mesh.simplices,
            simplex_normals=np.asarray(mesh.simplex_normals),
            vertex_normals=np.asarray(mesh.vertex_normals) if smooth else None,
            vertex_ao=vertex_ao,
            offset=ORIGIN_OFFSET * diagonal,
            diagonal=diagonal,
        )


def _per_object(value, name: str, n_objects: int, default, *, unit: bool, positive: bool = False) -> np.ndarray:
    """``value`` for every object: one entry (or RGB triple) for all, or one per object id."""
    width = np.size(default)
    if value is None:
        value = default
    if np.asarray(value).dtype == bool:  # True would silently be 1
        raise TypeError(f"`{name}` must be a number (or one per object), got {value!r}")
    arr = as_array(value, name, ndim=(0, 1) if width == 1 else (1, 2), dtype=np.float64, finite=True)
    if arr.ndim == (0 if width == 1 else 1):
        if width > 1 and arr.shape[0] != width:
            raise ValueError(
                f"`{name}` must be an RGB triple or one per object ({n_objects}, 3), got shape {arr.shape}"
            )
        arr = np.broadcast_to(arr, (n_objects,) + arr.shape)
    elif arr.shape[0] != n_objects or (width > 1 and arr.shape[1] != width):
        want = f"({n_objects},)" if width == 1 else f"({n_objects}, {width})"
        raise ValueError(
            f"`{name}` must be one value for all objects or {want} (one per object id), got shape {arr.shape}"
        )
    if unit and ((arr < 0) | (arr > 1)).any():
        raise ValueError(f"`{name}` must be in [0, 1], got {value!r}")
    if positive and (arr <= 0).any():
        raise ValueError(f"`{name}` must be > 0, got {value!r}")
    if not unit and (arr < 0).any():
        raise ValueError(f"`{name}` must be >= 0, got {value!r}")
    return np.array(arr)


@dataclass
class _Stats:
    """Counts and timings of one render (:attr:`RenderResult.info`)."""

    primary_rays: int
    backend: str
    device: str
    layer_rays: int = 0
    shadow_rays: int = 0
    ao_rays: int = 0
    screen_lookups: int = 0
    hits: int = 0
    primary_seconds: float = 0.0
    layer_seconds: float = 0.0
    shadow_seconds: float = 0.0
    ao_seconds: float = 0.0
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return dict(vars(self))


@dataclass(frozen=True)
class _Run:
    """One render's resolved state: options, scene, the backend and its tracer, statistics, and
    what the first hits fix for every layer (per-vertex AO, the screen-space depth volume)."""

    opts: _Options
    scene: _Scene
    backend: str
    tracer: Tracer
    stats: _Stats
    vertex_ao: np.ndarray | None = None
    volume: DepthVolume | None = None


def _check_budget(scene: _Scene, opts: _Options, camera, backend: str, max_rays) -> None:
    """Refuse a render whose rays would exceed ``max_rays``, before any of them is cast.

    An upper bound: every voxel's ray hits ``layers`` surfaces (1 in opaque scenes), each with
    AO at the hit (``ao="hits"``; ``"screen"``: ``samples`` directions of at most
    :func:`_screen_steps` look-ups, and the ``denoise`` filter's window per voxel, as rays
    taking as long) and a shadow ray per light (transparent scenes: ``layers`` per light).
    """
    ao, samples, n_voxels, denoise = opts.ao, opts.samples, math.prod(opts.shape), opts.denoise
    layers = 1 if scene.material.opaque else opts.layers
    per_hit = (samples if ao == "hits" else 0) + (len(opts.lights) * layers if opts.shadows else 0)
    ao_vertices = scene.mesh.n_vertices * samples if ao == "vertices" and scene.vertex_ao is None else 0
    total = n_voxels * layers * (1 + per_hit) + ao_vertices
    what = f"rendering {n_voxels:,} voxels with ao={ao!r}, `samples`={samples}"
    if ao == "screen":  # look-ups and the filter's window, counted as rays at their cost
        lookups = n_voxels * layers * samples * _screen_steps(scene, camera, opts)
        window = n_voxels * (2 * denoise + 1) ** 3 if denoise else 0
        seconds = lookups / LOOKUPS_PER_SECOND[backend] + window / DENOISE_PER_SECOND[backend]
        total += seconds * RAYS_PER_SECOND[backend]
        what += (
            f"{f', `denoise`={denoise}' if denoise else ''} ({lookups:.3g} depth look-ups"
            f"{f' and {window:.3g} filter-window voxels' if window else ''}, counted as rays "
            "at their cost)"
        )
    check_rays(
        total,
        backend,
        max_rays,
        what=what,
        hint="use fewer `samples`, a smaller `denoise` or `shape`, or pass max_rays=math.inf (CLI: --force)",
    )


def _screen_steps(scene: _Scene, camera, opts: _Options) -> int:
    """An upper bound of :func:`ao4d.rendering.screen_ao.default_steps` before the image exists: the
    reach clamped to the scene's diagonal (the visible points' box is inside it)."""
    reach = min(opts.max_distance, scene.diagonal)
    return march_steps(reach / camera.geometry(opts.shape).spacing)


# -- the pipeline: rays, first hits, shading, layers ----------------------------------------------


def _cast(run: _Run, origins, directions, desc, *, closest=True, max_distance=math.inf):
    """Hits of many rays: ``t``, ``simplex``, barycentric weights; one :func:`ao4d.rays.api.trace`
    per batch of ``_CHUNK`` rays on the render's tracer (progress bar over rays)."""
    n = len(origins)
    t = np.full(n, np.inf)
    simplex = np.full(n, -1, dtype=np.int64)
    bary = np.zeros((n, 4))
    with _progress.bar(n, desc, unit="ray", show=run.opts.show, unit_scale=True) as bar:
        for start in range(0, n, _CHUNK):
            stop = min(start + _CHUNK, n)
            hits = trace(
                run.tracer,
                origins[start:stop],
                directions[start:stop],
                closest=closest,
                max_distance=max_distance,
                bar=bar,
            )
            t[start:stop], simplex[start:stop], bary[start:stop] = hits.t, hits.simplex, hits.barycentric
    return t, simplex, bary


def _with_first_hits(run: _Run, camera, directions, t, simplex) -> _Run:
    """What the first hits fix for every layer: the per-vertex AO (``ao="vertices"``, given,
    stored or computed here once) or the depth volume (``ao="screen"``)."""
    opts, scene = run.opts, run.scene
    if opts.ao == "vertices":
        values = scene.vertex_ao
        if values is None:
            start = time.perf_counter()
            values = ambient_occlusion(
                scene.mesh,
                samples=opts.samples,
                max_distance=opts.max_distance,
                at="vertices",
                seed=opts.seed,
                backend=run.backend,
                max_rays=math.inf,
            )  # render checked its budget
            run.stats.ao_seconds += time.perf_counter() - start
            run.stats.ao_rays += scene.mesh.n_vertices * opts.samples
        return replace(run, vertex_ao=np.asarray(values, dtype=np.float64))
    if opts.ao == "screen":
        volume = DepthVolume.of_first_hits(camera, opts.shape, directions, t, simplex, scene.simplex_normals)
        return replace(run, volume=volume)
    return run


def _occlusion(run: _Run, points, face_n, tri, bary, first: bool) -> np.ndarray:
    """(H,) AO at hits: interpolated per-vertex values, AO rays, or the depth volume (the
    first hits' values filtered with ``denoise``)."""
    opts, stats = run.opts, run.stats
    if opts.ao == "none" or not len(points):
        return np.zeros(len(points))
    if opts.ao == "vertices":
        # weights a rounding below 0 or summing above 1 would leave [0, 1]
        return np.clip(np.einsum("hk,hk->h", bary, run.vertex_ao[tri]), 0.0, 1.0)
    start = time.perf_counter()
    if opts.ao == "hits":  # the hemisphere around the normal that faces the viewer
        occ = ambient_occlusion(
            run.scene.mesh,
            samples=opts.samples,
            max_distance=opts.max_distance,
            points=points,
            normals=face_n,
            seed=opts.seed,
            backend=run.backend,
            progress=opts.show,
            max_rays=math.inf,
        )  # render checked its budget
        stats.ao_rays += len(points) * opts.samples
    else:
        volume = run.volume
        occ = screen_space_occlusion(
            volume,
            points,
            face_n,
            samples=opts.samples,
            max_distance=opts.max_distance,
            seed=opts.seed,
            backend=run.backend,
            max_rays=math.inf,
        )  # render checked its budget
        stats.screen_lookups += len(points) * opts.samples * default_steps(volume, opts.max_distance)
        if first and opts.denoise:
            image = np.full(volume.depth.size, np.nan)
            image[volume.hit.reshape(-1)] = occ
            occ = denoise_occlusion(image.reshape(opts.shape), volume, radius=opts.denoise, backend=run.backend)[
                volume.hit
            ]
    stats.ao_seconds += time.perf_counter() - start
    return np.asarray(occ, dtype=np.float64)


@dataclass(frozen=True)
class _Shaded:
    """Shading of a set of hits."""

    shade: np.ndarray  # (H,) the grey illumination
    rgb: np.ndarray  # (H, 3) colour, clipped to [0, 1]
    occlusion: np.ndarray  # (H,)


def _shade(run: _Run, points, directions, depth, simplex, bary, *, first: bool = False) -> _Shaded:
    """Shade hits: points (H, 4), ray directions (H, 4), depths (H,), simplices, weights;
    ``first``: the primary rays' hits (in voxel order)."""
    opts, scene = run.opts, run.scene
    tri = scene.simplices[simplex]  # (H, 4) vertex ids of the hit tetrahedra
    # two-sided shading: the side of the hit simplex that faces the ray decides, for the face
    # normal and for the interpolated vertex normal alike (near silhouettes an interpolated
    # normal may lean away from the ray although the face is seen from its front)
    raw_n = scene.simplex_normals[simplex]
    side = viewer_side(raw_n, directions)
    face_n = raw_n * side[:, None]
    occ = _occlusion(run, points, face_n, tri, bary, first)

    objects = scene.object_ids[simplex]
    material = scene.material
    open_ = opts.ambient * (1.0 - np.clip(occ, 0.0, 1.0))
    shade = open_
    diffuse_rgb = np.zeros((len(simplex), 3))
    highlight_rgb = np.zeros((len(simplex), 3))
    if opts.lights and len(simplex):
        if opts.shading == "smooth":
            lam_n = np.einsum("hk,hkd->hd", bary, scene.vertex_normals[tri])
            lam_n /= np.maximum(np.linalg.norm(lam_n, axis=1, keepdims=True), 1e-12)
            lam_n = lam_n * side[:, None]
        else:
            lam_n = face_n
        spec_w = material.specular[objects]
        shiny = material.shininess[objects]
        for light in opts.lights:
            to_light, _ = light.towards(points)
            lit = lambert(lam_n, to_light)
            term = opts.diffuse * lit * light.intensity
            spec = None  # skipped, not multiplied by 0: without highlights shade is the plain sum
            if (spec_w > 0).any():
                spec = spec_w * blinn_phong(lam_n, to_light, -directions, shiny) * light.intensity
            if opts.shadows:
                seen = _visibility(run, points, face_n, light, lit > 0)
                term = term * seen
                spec = None if spec is None else spec * seen
            shade = shade + term
            diffuse_rgb += term[:, None] * light.color
            if spec is not None:
                shade = shade + spec
                highlight_rgb += spec[:, None] * light.color
    rgb = material.color[objects] * (open_[:, None] + diffuse_rgb) + highlight_rgb
    if opts.cue is not None:
        factor = depth_cue(depth, *opts.cue)
        shade = shade * factor
        rgb = rgb * factor[:, None]
    return _Shaded(shade=shade, rgb=np.clip(rgb, 0.0, 1.0), occlusion=occ)


def _visibility(run: _Run, points, face_n, light: Light, lit) -> np.ndarray:
    """(H,) fraction of ``light`` reaching each hit (1 where not ``lit``: no term anyway)."""
    seen = np.ones(len(points))
    rows = np.flatnonzero(lit)
    if not rows.size:
        return seen
    start = time.perf_counter()
    origins = points[rows] + run.scene.offset * face_n[rows]
    if light.direction is not None:
        dirs = np.broadcast_to(light.direction, origins.shape)
        reach = np.full(len(rows), np.inf)
    else:  # a point light: only what lies between the (moved) origin and the light counts
        offset = light.position - origins
        reach = np.linalg.norm(offset, axis=1)
        dirs = offset / np.maximum(reach, 1e-300)[:, None]
        keep = reach > 0  # a hit on the light itself is lit
        rows, origins, dirs, reach = rows[keep], origins[keep], dirs[keep], reach[keep]
    if rows.size:
        seen[rows] = _transmittance(run, origins, dirs, reach)
    run.stats.shadow_seconds += time.perf_counter() - start
    return seen


def _transmittance(run: _Run, origins, dirs, reach) -> np.ndarray:
    """Light fraction arriving along rays ``origins + s dirs``, ``0 < s < reach``."""
    scene, stats = run.scene, run.stats
    n = len(origins)
    finite = np.isfinite(reach)
    longest = float(reach[finite].max()) if finite.any() else math.inf
    longest = math.inf if (~finite).any() or not longest > 0 else longest
    if scene.material.opaque:
        # any hit blocks; for point lights a reported hit beyond the light says nothing about
        # the stretch before it, so those rays are asked again for their closest hit
        stats.shadow_rays += n
        t, simplex, _ = _cast(run, origins, dirs, "shadow rays", closest=False, max_distance=longest)
        blocked = (simplex >= 0) & (t < reach)
        unsure = np.flatnonzero((simplex >= 0) & (t >= reach))
        if unsure.size:
            stats.shadow_rays += unsure.size
            t2, s2, _ = _cast(run, origins[unsure], dirs[unsure], "shadow rays", max_distance=longest)
            blocked[unsure] = (s2 >= 0) & (t2 < reach[unsure])
        return np.where(blocked, 0.0, 1.0)
    # transparent objects: walk the closest hits, losing (1 - opacity) per surface
    passed = np.ones(n)
    active = np.arange(n)
    start = np.zeros(n)  # distance travelled from each origin
    for _ in range(run.opts.layers):
        if not active.size:
            break
        stats.shadow_rays += active.size
        o = origins[active] + start[active, None] * dirs[active]
        t, simplex, _ = _cast(run, o, dirs[active], "shadow rays", max_distance=longest)
        got = (simplex >= 0) & (start[active] + t < reach[active])
        active, t, simplex = active[got], t[got], simplex[got]
        passed[active] *= 1.0 - scene.material.opacity[scene.object_ids[simplex]]
        start[active] += t + scene.offset
        active = active[passed[active] > 0]
    return passed


def _composite_rays(run: _Run, origins, directions, rows, t, simplex, first: _Shaded):
    """(N, 4) float32 RGBA of every ray: the first layer, then the layers behind transparent hits.

    ``rows`` are the rays with a first hit; ``at`` indexes them for the rays still going.
    """
    scene, stats, layers = run.scene, run.stats, run.opts.layers
    acc = np.zeros((len(rows), 4))  # premultiplied colour and opacity of the rays that hit
    at = np.arange(len(rows))
    layer = first
    for depth_index in range(layers):
        alpha = scene.material.opacity[scene.object_ids[simplex]]
        if depth_index == 0:
            over(acc, layer.rgb, alpha)
        else:
            sub = acc[at]
            over(sub, layer.rgb, alpha)
            acc[at] = sub
        if depth_index == layers - 1:
            break
        go = (alpha < 1.0) & (acc[at, 3] < _OPAQUE)
        if not go.any():
            break
        at, t = at[go], t[go]
        ray = rows[at]
        start = t + scene.offset
        tick = time.perf_counter()
        o = origins[ray] + start[:, None] * directions[ray]
        t_next, simplex, bary = _cast(run, o, directions[ray], "rays behind transparent hits")
        stats.layer_rays += len(ray)
        stats.layer_seconds += time.perf_counter() - tick
        hit = simplex >= 0
        at, ray, simplex, bary = at[hit], ray[hit], simplex[hit], bary[hit]
        points, t = o[hit] + t_next[hit, None] * directions[ray], start[hit] + t_next[hit]
        layer = _shade(run, points, directions[ray], t, simplex, bary)
    out = np.zeros((len(origins), 4), dtype=np.float32)
    out[rows] = unpremultiply(acc)
    return out


def _scatter(shape, hit, values, fill, dtype) -> np.ndarray:
    out = np.full(hit.shape, fill, dtype=dtype)
    out[hit] = values
    return out.reshape(shape)
