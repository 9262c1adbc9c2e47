"""Render 4D meshes into 3D image volumes with a :class:`~ao4d.camera.Camera4D`.

One primary ray per voxel (closest hit through :func:`ao4d.raycast.cast_rays`). At a hit with
ambient occlusion ``A`` (DESIGN.md definition), normal ``n`` turned towards the viewer and, per
light k, unit direction ``l_k`` towards it, shadow visibility ``V_k`` and intensity ``I_k``::

    shade = [ambient * (1 - A)
             + sum_k I_k V_k (diffuse * max(0, n . l_k) + specular * max(0, n . h_k)^shininess)]
            * cue(depth)

with ``h_k`` the 4D Blinn-Phong half-vector of ``l_k`` and the direction to the eye, the
specular term only where ``n . l_k > 0``, and ``cue`` the depth cue (:mod:`ao4d.lighting`; 1
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
``ambient * (1 - A) + diffuse * max(0, n . l)`` to the bit, as before these terms existed.

With ``ao="screen"`` the occlusion comes from the image itself (:mod:`ao4d.screen_ao`): the first
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from . import _progress, cl
from ._validate import (as_array, as_real, check_bool, check_choice, check_int, check_memory,
                        check_positive_int)
from .ao import ORIGIN_OFFSET, ambient_occlusion
from .camera import Camera4D, ImageGeometry, _image_shape
from .lighting import Light, as_lights, blinn_phong, check_depth_cue, depth_cue, lambert
from .mesh import SimplexMesh, _mesh_list, concatenate, warn_if_inside_out
from .raycast import RAYS_PER_SECOND, cast_rays, check_distance, check_rays
from .screen_ao import (DENOISE_PER_SECOND, LOOKUPS_PER_SECOND, MAX_STEPS, MIN_STEPS, STEP_VOXELS, DepthVolume,
                        default_steps, screen_space_occlusion, viewer_side)
from .screen_ao import denoise as denoise_occlusion
from .volumes import write_mhd, write_vti

__all__ = ["render", "RenderResult", "prepare_scene", "ShadeRangeWarning", "composite_layer", "MAX_LAYERS",
           "default_weights"]

# Default shading weights (the command line uses the same): 1 - AO alone without a light; with
# lights 0.7 (1 - AO) + 0.3 Lambert, so one light of intensity 1 keeps shade in [0, 1].
AMBIENT, AMBIENT_LIT, DIFFUSE = 1.0, 0.7, 0.3

# Primary rays per cast_rays call: bounds host memory and lets tqdm show progress.
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
        (:func:`ao4d.cl.describe`).
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
        parts = [f"{k} {info[f'{k}_seconds']:.2f} s" for k in ("primary", "layer", "shadow", "ao")
                 if info.get(f"{k}_seconds")]
        timing = f", {info['seconds']:.2f} s ({', '.join(parts)})" if "seconds" in info else ""
        return (f"RenderResult({shape} voxels, {hits:,} hit ({hits / max(self.shade.size, 1):.0%})"
                f", backend={info.get('backend')!r}{timing})")

    def _repr_html_(self) -> str:
        """The image's ray-marching page (:mod:`ao4d.image_viewer`), shown inline in Jupyter."""
        from .pages import inline

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
        arrays = {"shade": self.shade, "depth": depth, "object_id": self.object_id,
                  "occlusion": self.occlusion, "rgba": self.rgba8}
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


def _check_inputs(scene, ao: str, ambient: float, diffuse: float, specular: np.ndarray, lights) -> None:
    """Refuse stored AO that would shade wrongly, and say when the weights can exceed 1."""
    if ao == "vertices" and "ao" in scene.point_data:
        values = np.asarray(scene.point_data["ao"], dtype=np.float64)
        used = np.zeros(scene.n_vertices, dtype=bool)
        used[scene.simplices.ravel()] = True
        bad_nan = used & ~np.isfinite(values)
        if bad_nan.any():
            raise ValueError(f"`point_data['ao']` is NaN at {int(bad_nan.sum())} vertices that simplices use "
                             f"(first: vertex {int(np.argmax(bad_nan))}); recompute it with ao4d.ambient_occlusion")
        outside = used & ((values < 0) | (values > 1))
        if outside.any():
            raise ValueError(f"`point_data['ao']` must be occlusion in [0, 1], got values in "
                             f"[{values[used].min():.4g}, {values[used].max():.4g}]")
    lit = sum(light.intensity for light in lights)
    brightest = ambient + lit * (diffuse + float(np.max(specular, initial=0.0)))
    if brightest > 1 + 1e-9:
        import warnings

        warnings.warn(
            f"`ambient` + light intensity x (`diffuse` + `specular`) = {brightest:.3g} > 1: shade can "
            "exceed 1 (it is in [0, 1] when they sum to at most 1)", ShadeRangeWarning, stacklevel=3)


class ShadeRangeWarning(UserWarning):
    """The shading weights allow shade above 1."""


def prepare_scene(meshes) -> tuple[Any, np.ndarray]:
    """One SimplexMesh for a mesh or a list of meshes, and the object id of each simplex.

    Parameters
    ----------
    meshes : SimplexMesh or sequence of SimplexMesh
        4D meshes. A single mesh is used as is (not copied, so its cached BVH is reused) and
        keeps the ``cell_data["object_id"]`` it may carry (e.g. a saved scene), else id 0. A
        list of several is joined with :func:`ao4d.mesh.concatenate` (ids = list positions).

    Returns
    -------
    scene : SimplexMesh
        The joined mesh.
    object_id : (S,) int32
        The object id of each simplex.
    """
    if isinstance(meshes, SimplexMesh):
        items = [meshes]
    elif isinstance(meshes, Sequence) and not isinstance(meshes, (str, bytes)):
        items = _mesh_list(meshes)
    else:
        raise TypeError(
            f"`meshes` must be a SimplexMesh or a list of them, got {type(meshes).__name__}"
        )
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
    ao: Literal["vertices", "hits", "screen", "none"] = "vertices",
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
    normals: Literal["smooth", "flat"] = "smooth",
    backend: Literal["auto", "opencl", "numpy"] = "auto",
    progress: bool | None = None,
    max_rays: float | None = None,
) -> RenderResult:
    """Render 4D meshes into a 3D image volume (one primary ray per voxel).

    Parameters
    ----------
    meshes : SimplexMesh or sequence of SimplexMesh
        4D meshes (closed surfaces or raw open tetrahedra). Lists are joined; the result's
        ``object_id`` is the list position (a single mesh keeps its ``cell_data["object_id"]``).
    camera : Camera4D
        The 4D camera; its image hyperplane holds the 3D image.
    shape : (3,) tuple of int
        Image size ``(nx, ny, nz)`` along the camera's image axes.
    ao : {"vertices", "hits", "screen", "none"}
        ``"vertices"``: per-vertex occlusion from ``mesh.point_data["ao"]`` (computed with
        :func:`ao4d.ambient_occlusion` when absent) interpolated with the hit's barycentric
        weights. ``"hits"``: occlusion computed at every hit point with the normal facing the
        viewer (exact per voxel and right for open, two-sided geometry). ``"screen"``: 4D
        screen-space AO at every hit, read from the image's own depth volume (first hits,
        their points and viewer-facing normals) with the same directions as ``"hits"``
        (:func:`ao4d.screen_ao.screen_space_occlusion`, :func:`ao4d.screen_ao.default_steps` look-ups
        per direction; no AO rays): fast, but blind to what the image does not show.
        ``"none"``: A = 0.
    samples : int
        Hemisphere rays (``"screen"``: directions) per AO estimate (when AO is computed here).
    max_distance : float
        AO ray length (inf: any hit occludes; ``"screen"`` then marches to the diagonal of the
        visible points' bounding box).
    seed : int
        AO random seed (results are deterministic).
    denoise : int
        With ``ao="screen"``: radius in voxels of the depth- and normal-aware box filter
        (:func:`ao4d.screen_ao.denoise`) applied to the first hits' occlusion before shading, so
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
        (:func:`ao4d.lighting.depth_cue`); ``0 <= near < far``, ``strength`` in [0, 1].
    color : (3,) or (n_objects, 3) array_like, optional
        RGB in [0, 1] of all objects, or one row per object id; default white (then ``rgba``
        is the clipped ``shade`` for white lights).
    opacity : float or (n_objects,) array_like, optional
        Opacity in [0, 1] of all objects or per object; default 1 (opaque). Below 1, further
        surfaces along the ray show through it.
    layers : int
        Surfaces composited front to back along a ray (1..16; default 4): a ray ends after
        ``layers`` hits or at its first opaque hit.
    normals : {"smooth", "flat"}
        Shading normals interpolated from vertex normals, or the hit simplex's own.
    backend : {"auto", "opencl", "numpy"}
        Resolved once (:func:`ao4d.cl.resolve_backend`); primary, layer and shadow rays
        (:func:`ao4d.raycast.cast_rays`) and AO (:func:`ao4d.ambient_occlusion`) all run on it.
    progress : bool, optional
        Progress bars (:mod:`ao4d._progress`: silenced by ``--no-progress``); default on for
        images of 2^18 voxels or more.
    max_rays : float, optional
        Refuse, before any work, a render whose rays (primary, AO, shadow and layer rays, an
        upper bound) exceed this; default :data:`ao4d.raycast.MAX_RAYS` of the backend
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
    if not isinstance(camera, Camera4D):
        raise TypeError(f"`camera` must be an ao4d.Camera4D, got {type(camera).__name__}")
    shape = _image_shape(shape)
    check_choice(ao, "ao", ("vertices", "hits", "screen", "none"))
    check_choice(normals, "normals", ("smooth", "flat"))
    check_choice(backend, "backend", cl.BACKENDS)
    samples = check_positive_int(samples, "samples")
    seed = check_int(seed, "seed")
    denoise = check_int(denoise, "denoise", minimum=0)
    if denoise and ao != "screen":
        raise ValueError(f"`denoise` filters screen-space AO: it needs ao='screen', got ao={ao!r}")
    lights = as_lights(light, "light")
    ambient, diffuse = default_weights(ambient, diffuse, bool(lights))
    shadows = check_bool(shadows, "shadows")
    cue = check_depth_cue(depth_cue)
    layers = check_positive_int(layers, "layers")
    if layers > _LAYER_LIMIT:
        raise ValueError(f"`layers` must be <= {_LAYER_LIMIT}, got {layers}")
    max_distance = check_distance(max_distance)
    n_rays = math.prod(shape)
    check_memory(n_rays * 4 * 8 * 10, "rendering an image of this shape")
    scene, object_ids = prepare_scene(meshes)
    n_objects = int(object_ids.max()) + 1
    material = _Material(
        color=_per_object(color, "color", n_objects, (1.0, 1.0, 1.0), unit=True),
        opacity=_per_object(opacity, "opacity", n_objects, 1.0, unit=True),
        specular=_per_object(specular, "specular", n_objects, 0.0, unit=False),
        shininess=_per_object(shininess, "shininess", n_objects, 32.0, unit=False, positive=True),
    )
    _check_inputs(scene, ao, ambient, diffuse, material.specular, lights)
    show = n_rays >= _PROGRESS_VOXELS if progress is None else bool(progress)
    runtime = cl.resolve_backend(backend)
    backend = cl.backend_name(runtime)  # what runs: every stage on the same device
    _check_budget(scene, n_rays, ao=ao, samples=samples, lights=lights, shadows=shadows,
                  layers=1 if material.opaque else layers, backend=backend, max_rays=max_rays,
                  camera=camera, shape=shape, max_distance=max_distance, denoise=denoise)
    if ao == "hits" or (ao == "vertices" and "ao" not in scene.point_data):
        # only AO computed here: stored AO was computed (and warned about) where it was made,
        # and the check costs a pass over every simplex
        warn_if_inside_out(scene, "AO is 1 on its surface and the image dark")
    info: dict[str, Any] = {"primary_rays": n_rays, "layer_rays": 0, "shadow_rays": 0,
                            "ao_rays": 0, "screen_lookups": 0, "primary_seconds": 0.0,
                            "layer_seconds": 0.0, "shadow_seconds": 0.0, "ao_seconds": 0.0,
                            "backend": backend,
                            "device": cl.describe(runtime)}
    lo, hi = np.asarray(scene.bounds, dtype=np.float64)
    shading = _Shading(
        scene=scene, object_ids=object_ids, material=material, lights=lights, ambient=ambient,
        diffuse=diffuse, shadows=shadows, cue=cue, layers=layers, ao=ao, normals=normals,
        samples=samples, seed=seed, max_distance=max_distance, backend=backend, show=show,
        offset=ORIGIN_OFFSET * float(np.linalg.norm(hi - lo)), info=info,
    )

    origins, directions = (a.reshape(-1, 4) for a in camera.rays(shape))
    tick = time.perf_counter()
    t, simplex, bary = _cast_chunked(scene, origins, directions, backend, show, "primary rays")
    info["primary_seconds"] = time.perf_counter() - tick
    hit = simplex >= 0
    info["hits"] = int(hit.sum())
    rows = np.flatnonzero(hit)
    points = origins[rows] + t[rows, None] * directions[rows]
    occlusion = None
    if ao == "screen" and rows.size:
        tick = time.perf_counter()
        volume = shading.screen = _depth_volume(scene, camera, shape, directions, t, simplex)
        occlusion = screen_space_occlusion(volume, points, volume.normals.reshape(-1, 4)[rows],
                                           samples=samples, max_distance=max_distance, seed=seed,
                                           backend=backend)
        info["screen_lookups"] += rows.size * samples * default_steps(volume, max_distance)
        if denoise:
            image = np.full(n_rays, np.nan)
            image[rows] = occlusion
            occlusion = denoise_occlusion(image.reshape(shape), volume, radius=denoise,
                                          backend=backend).reshape(-1)[rows]
        info["ao_seconds"] += time.perf_counter() - tick
    first = shading.hits(points, directions[rows], t[rows], simplex[rows], bary[rows],
                         occlusion=occlusion)
    rgba = _composite_rays(shading, origins, directions, rows, t[rows], simplex[rows], first)
    info["seconds"] = time.perf_counter() - started
    return RenderResult(
        shade=_scatter(shape, hit, first.shade, 0.0, np.float32),
        depth=_scatter(shape, hit, t[hit], np.inf, np.float32),
        object_id=_scatter(shape, hit, object_ids[simplex[hit]], -1, np.int32),
        occlusion=_scatter(shape, hit, first.occlusion, np.nan, np.float32),
        rgba=rgba.reshape(shape + (4,)),
        camera=camera,
        geometry=camera.geometry(shape),
        info=info,
    )


def composite_layer(acc: np.ndarray, rgb: np.ndarray, alpha: np.ndarray) -> None:
    """Add one layer behind what ``acc`` holds: front-to-back "over", in place.

    ``C += (1 - A) a c`` and ``A += (1 - A) a`` (premultiplied accumulation; Porter & Duff).

    Parameters
    ----------
    acc : (H, 4) float64
        Premultiplied colour and accumulated opacity so far (updated).
    rgb : (H, 3) float64
        The layer's colour (not premultiplied).
    alpha : (H,) float64
        The layer's opacity.

    Examples
    --------
    >>> acc = np.zeros((1, 4))
    >>> composite_layer(acc, np.array([[1.0, 0, 0]]), np.array([0.5]))   # red in front
    >>> composite_layer(acc, np.array([[0.0, 0, 1]]), np.array([0.5]))   # blue behind
    >>> acc.tolist()
    [[0.5, 0.0, 0.25, 0.75]]
    """
    weight = (1.0 - acc[:, 3]) * alpha
    acc[:, :3] += weight[:, None] * rgb
    acc[:, 3] += weight


# -- materials ---------------------------------------------------------------------------------


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


def _per_object(value, name: str, n_objects: int, default, *, unit: bool,
                positive: bool = False) -> np.ndarray:
    """``value`` for every object: one entry (or RGB triple) for all, or one per object id."""
    width = np.size(default)
    if value is None:
        value = default
    if np.asarray(value).dtype == bool:  # True would silently be 1
        raise TypeError(f"`{name}` must be a number (or one per object), got {value!r}")
    arr = as_array(value, name, ndim=(0, 1) if width == 1 else (1, 2), dtype=np.float64,
                   finite=True)
    if arr.ndim == (0 if width == 1 else 1):
        if width > 1 and arr.shape[0] != width:
            raise ValueError(f"`{name}` must be an RGB triple or one per object ({n_objects}, 3), "
                             f"got shape {arr.shape}")
        arr = np.broadcast_to(arr, (n_objects,) + arr.shape)
    elif arr.shape[0] != n_objects or (width > 1 and arr.shape[1] != width):
        want = f"({n_objects},)" if width == 1 else f"({n_objects}, {width})"
        raise ValueError(f"`{name}` must be one value for all objects or {want} (one per object "
                         f"id), got shape {arr.shape}")
    if unit and ((arr < 0) | (arr > 1)).any():
        raise ValueError(f"`{name}` must be in [0, 1], got {value!r}")
    if positive and (arr <= 0).any():
        raise ValueError(f"`{name}` must be > 0, got {value!r}")
    if not unit and (arr < 0).any():
        raise ValueError(f"`{name}` must be >= 0, got {value!r}")
    return np.array(arr)


# -- shading -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Shaded:
    """Shading of a set of hits."""

    shade: np.ndarray  # (H,) the grey illumination
    rgb: np.ndarray  # (H, 3) colour, clipped to [0, 1]
    occlusion: np.ndarray  # (H,)


@dataclass
class _Shading:
    """Everything needed to shade hits; :meth:`hits` is called once per layer."""

    scene: Any
    object_ids: np.ndarray
    material: _Material
    lights: tuple[Light, ...]
    ambient: float
    diffuse: float
    shadows: bool
    cue: tuple[float, float, float] | None
    layers: int
    ao: str
    normals: str
    samples: int
    seed: int
    max_distance: float
    backend: str
    show: bool
    offset: float
    info: dict
    _vertex_ao: np.ndarray | None = None
    screen: DepthVolume | None = None  # the first hits, for ao="screen"

    def hits(self, points, directions, depth, simplex, bary, occlusion=None) -> _Shaded:
        """Shade hits: points (H, 4), ray directions (H, 4), depths (H,), simplices, weights;
        ``occlusion`` (H,) when already known (the first hits' screen-space AO)."""
        scene = self.scene
        tri = scene.simplices[simplex]  # (H, 4) vertex ids of the hit tetrahedra
        # two-sided shading: the side of the hit simplex that faces the ray decides, for the
        # face normal and for the interpolated vertex normal alike (near silhouettes an
        # interpolated normal may lean away from the ray although the face is seen from its
        # front)
        raw_n = np.asarray(scene.simplex_normals)[simplex]
        side = _viewer_side(raw_n, directions)
        face_n = raw_n * side[:, None]

        occ = np.zeros(len(simplex))
        if occlusion is not None:
            occ = np.asarray(occlusion, dtype=np.float64)
        elif self.ao == "vertices" and len(simplex):
            # weights a rounding below 0 or summing above 1 would leave [0, 1]
            occ = np.clip(np.einsum("hk,hk->h", bary, self._per_vertex_ao()[tri]), 0.0, 1.0)
        elif self.ao == "hits" and len(simplex):
            occ = _hit_occlusion(scene, points, face_n, samples=self.samples, seed=self.seed,
                                 max_distance=self.max_distance, backend=self.backend,
                                 info=self.info, show=self.show)
        elif self.ao == "screen" and len(simplex):
            start = time.perf_counter()
            occ = screen_space_occlusion(self.screen, points, face_n, samples=self.samples,
                                         max_distance=self.max_distance, seed=self.seed,
                                         backend=self.backend)
            self.info["ao_seconds"] += time.perf_counter() - start
            self.info["screen_lookups"] += (len(points) * self.samples
                                            * default_steps(self.screen, self.max_distance))

        objects = self.object_ids[simplex]
        open_ = self.ambient * (1.0 - np.clip(occ, 0.0, 1.0))
        shade = open_
        diffuse_rgb = np.zeros((len(simplex), 3))
        highlight_rgb = np.zeros((len(simplex), 3))
        if self.lights and len(simplex):
            if self.normals == "smooth":
                vn = np.asarray(scene.vertex_normals)[tri]  # (H, 4, 4)
                lam_n = np.einsum("hk,hkd->hd", bary, vn)
                lam_n /= np.maximum(np.linalg.norm(lam_n, axis=1, keepdims=True), 1e-12)
                lam_n = lam_n * side[:, None]
            else:
                lam_n = face_n
            spec_w = self.material.specular[objects]
            shiny = self.material.shininess[objects]
            for light in self.lights:
                to_light, _ = light.towards(points)
                lit = lambert(lam_n, to_light)
                term = self.diffuse * lit * light.intensity
                spec = None
                if (spec_w > 0).any():
                    spec = spec_w * blinn_phong(lam_n, to_light, -directions, shiny) * light.intensity
                if self.shadows:
                    seen = self._visibility(points, face_n, light, lit > 0)
                    term = term * seen
                    spec = None if spec is None else spec * seen
                shade = shade + term
                diffuse_rgb += term[:, None] * light.color
                if spec is not None:
                    shade = shade + spec
                    highlight_rgb += spec[:, None] * light.color
        rgb = self.material.color[objects] * (open_[:, None] + diffuse_rgb) + highlight_rgb
        if self.cue is not None:
            factor = depth_cue(depth, *self.cue)
            shade = shade * factor
            rgb = rgb * factor[:, None]
        return _Shaded(shade=shade, rgb=np.clip(rgb, 0.0, 1.0), occlusion=occ)

    def _per_vertex_ao(self) -> np.ndarray:
        """Per-vertex AO, stored on the mesh or computed once per render."""
        if self._vertex_ao is None:
            scene = self.scene
            if "ao" not in scene.point_data:
                start = time.perf_counter()
                values = ambient_occlusion(scene, samples=self.samples,
                                           max_distance=self.max_distance, at="vertices",
                                           seed=self.seed, backend=self.backend,
                                           max_rays=math.inf)  # render checked its budget
                self.info["ao_seconds"] += time.perf_counter() - start
                self.info["ao_rays"] += scene.n_vertices * self.samples
            else:
                values = scene.point_data["ao"]
            self._vertex_ao = np.asarray(values, dtype=np.float64)
        return self._vertex_ao

    def _visibility(self, points, face_n, light: Light, lit) -> np.ndarray:
        """(H,) fraction of ``light`` reaching each hit (1 where not ``lit``: no term anyway)."""
        seen = np.ones(len(points))
        rows = np.flatnonzero(lit)
        if not rows.size:
            return seen
        start = time.perf_counter()
        origins = points[rows] + self.offset * face_n[rows]
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
            seen[rows] = self._transmittance(origins, dirs, reach)
        self.info["shadow_seconds"] += time.perf_counter() - start
        return seen

    def _transmittance(self, origins, dirs, reach) -> np.ndarray:
        """Light fraction arriving along rays ``origins + s dirs``, ``0 < s < reach``."""
        scene, backend, show = self.scene, self.backend, self.show
        n = len(origins)
        finite = np.isfinite(reach)
        longest = float(reach[finite].max()) if finite.any() else math.inf
        longest = math.inf if (~finite).any() or not longest > 0 else longest
        if self.material.opaque:
            # any hit blocks; for point lights a reported hit beyond the light says nothing
            # about the stretch before it, so those rays are asked again for their closest hit
            self.info["shadow_rays"] += n
            t, simplex, _ = _cast_chunked(scene, origins, dirs, backend, show, "shadow rays",
                                          closest=False, max_distance=longest)
            blocked = (simplex >= 0) & (t < reach)
            unsure = np.flatnonzero((simplex >= 0) & (t >= reach))
            if unsure.size:
                self.info["shadow_rays"] += unsure.size
                t2, s2, _ = _cast_chunked(scene, origins[unsure], dirs[unsure], backend, show,
                                          "shadow rays", closest=True, max_distance=longest)
                blocked[unsure] = (s2 >= 0) & (t2 < reach[unsure])
            return np.where(blocked, 0.0, 1.0)
        # transparent objects: walk the closest hits, losing (1 - opacity) per surface
        passed = np.ones(n)
        active = np.arange(n)
        start = np.zeros(n)  # distance travelled from each origin
        for _ in range(self.layers):
            if not active.size:
                break
            self.info["shadow_rays"] += active.size
            o = origins[active] + start[active, None] * dirs[active]
            t, simplex, _ = _cast_chunked(scene, o, dirs[active], backend, show, "shadow rays",
                                          closest=True, max_distance=longest)
            got = (simplex >= 0) & (start[active] + t < reach[active])
            active, t, simplex = active[got], t[got], simplex[got]
            passed[active] *= 1.0 - self.material.opacity[self.object_ids[simplex]]
            start[active] += t + self.offset
            active = active[passed[active] > 0]
        return passed


def _composite_rays(shading: _Shading, origins, directions, rows, t, simplex, first: _Shaded):
    """(N, 4) float32 RGBA of every ray: the first layer, then the layers behind transparent hits.

    ``rows`` are the rays with a first hit; ``at`` indexes them for the rays still going.
    """
    acc = np.zeros((len(rows), 4))  # premultiplied colour and opacity of the rays that hit
    material, info = shading.material, shading.info
    at = np.arange(len(rows))
    layer = first
    for depth_index in range(shading.layers):
        alpha = material.opacity[shading.object_ids[simplex]]
        if depth_index == 0:
            composite_layer(acc, layer.rgb, alpha)
        else:
            sub = acc[at]
            composite_layer(sub, layer.rgb, alpha)
            acc[at] = sub
        if depth_index == shading.layers - 1:
            break
        go = (alpha < 1.0) & (acc[at, 3] < _OPAQUE)
        if not go.any():
            break
        at, t = at[go], t[go]
        ray = rows[at]
        start = t + shading.offset
        tick = time.perf_counter()
        o = origins[ray] + start[:, None] * directions[ray]
        t_next, simplex, bary = _cast_chunked(shading.scene, o, directions[ray], shading.backend,
                                              shading.show, "rays behind transparent hits")
        info["layer_rays"] += len(ray)
        info["layer_seconds"] += time.perf_counter() - tick
        hit = simplex >= 0
        at, ray, simplex, bary = at[hit], ray[hit], simplex[hit], bary[hit]
        points, t = o[hit] + t_next[hit, None] * directions[ray], start[hit] + t_next[hit]
        layer = shading.hits(points, directions[ray], t, simplex, bary)
    out = np.zeros((len(origins), 4), dtype=np.float32)
    alpha = acc[:, 3:]
    out[rows, :3] = np.clip(np.where(alpha > 0, acc[:, :3] / np.maximum(alpha, 1e-300), 0.0), 0, 1)
    out[rows, 3] = alpha[:, 0]
    return out


def _check_budget(scene, n_voxels: int, *, ao: str, samples: int, lights, shadows: bool,
                  layers: int, backend: str, max_rays, camera=None, shape=None,
                  max_distance: float = math.inf, denoise: int = 0) -> None:
    """Refuse a render whose rays would exceed ``max_rays``, before any of them is cast.

    An upper bound: every voxel's ray hits ``layers`` surfaces, each with AO at the hit
    (``ao="hits"``; ``"screen"``: ``samples`` directions of at most :func:`_screen_steps`
    look-ups, and the ``denoise`` filter's window per voxel, as rays taking as long) and a
    shadow ray per light (transparent scenes: ``layers`` per light).
    """
    per_hit = (samples if ao == "hits" else 0) + (len(lights) * layers if shadows else 0)
    ao_vertices = scene.n_vertices * samples if ao == "vertices" and "ao" not in scene.point_data else 0
    total = n_voxels * layers * (1 + per_hit) + ao_vertices
    what = f"rendering {n_voxels:,} voxels with ao={ao!r}, `samples`={samples}"
    if ao == "screen":  # look-ups and the filter's window, counted as rays at their cost
        lookups = n_voxels * layers * samples * _screen_steps(scene, camera, shape, max_distance)
        window = n_voxels * (2 * denoise + 1) ** 3 if denoise else 0
        seconds = lookups / LOOKUPS_PER_SECOND[backend] + window / DENOISE_PER_SECOND[backend]
        total += seconds * RAYS_PER_SECOND[backend]
        what += (f"{f', `denoise`={denoise}' if denoise else ''} ({lookups:.3g} depth look-ups"
                 f"{f' and {window:.3g} filter-window voxels' if window else ''}, counted as rays "
                 "at their cost)")
    check_rays(total, backend, max_rays, what=what,
               hint="use fewer `samples`, a smaller `denoise` or `shape`, or pass max_rays=math.inf "
                    "(CLI: --force)")


def _screen_steps(scene, camera, shape, max_distance) -> int:
    """An upper bound of :func:`ao4d.screen_ao.default_steps` before the image exists: the
    reach clamped to the scene's diagonal (the visible points' box is inside it)."""
    lo, hi = np.asarray(scene.bounds, dtype=np.float64)
    reach = min(max_distance, float(np.linalg.norm(hi - lo)))
    voxels = reach / camera.geometry(shape).spacing
    return int(min(MAX_STEPS, max(MIN_STEPS, math.ceil(voxels / STEP_VOXELS))))


def _cast_chunked(scene, origins, directions, backend, show, desc, *, closest=True,
                  max_distance=math.inf):
    """Hits of many rays, in chunks (progress bar over rays)."""
    n = len(origins)
    t = np.full(n, np.inf)
    simplex = np.full(n, -1, dtype=np.int64)
    bary = np.zeros((n, 4))
    with _progress.bar(n, desc, unit="ray", show=show, unit_scale=True) as bar:
        for start in range(0, n, _CHUNK):
            stop = min(start + _CHUNK, n)
            hits = cast_rays(scene, origins[start:stop], directions[start:stop],
                             closest=closest, max_distance=max_distance, backend=backend)
            t[start:stop] = hits.t
            simplex[start:stop] = hits.simplex
            bary[start:stop] = hits.barycentric
            bar.update(stop - start)
    return t, simplex, bary


_viewer_side = viewer_side  # +1 where a normal faces against its ray, -1 where along it


def _depth_volume(scene, camera, shape, directions, t, simplex) -> DepthVolume:
    """The first hits as a depth volume: depth and viewer-facing face normal (valid by
    construction: built directly, without :meth:`DepthVolume.from_hits`' checks)."""
    hit = simplex >= 0
    normals = np.zeros((len(t), 4))
    rows = np.flatnonzero(hit)
    raw_n = np.asarray(scene.simplex_normals)[simplex[rows]]
    normals[rows] = raw_n * _viewer_side(raw_n, directions[rows])[:, None]
    return DepthVolume(depth=np.where(hit, t, np.inf).reshape(shape),
                       normals=normals.reshape(shape + (4,)), camera=camera)


def _hit_occlusion(scene, points, normals, *, samples, seed, max_distance, backend, info, show):
    """AO at every hit point, hemisphere around the normal that faces the viewer."""
    start = time.perf_counter()
    values = ambient_occlusion(scene, samples=samples, max_distance=max_distance, points=points,
                               normals=normals, seed=seed, backend=backend, progress=show,
                               max_rays=math.inf)  # render checked its budget before any ray
    info["ao_seconds"] += time.perf_counter() - start
    info["ao_rays"] += len(points) * samples
    return np.asarray(values, dtype=np.float64)


def _scatter(shape, hit, values, fill, dtype) -> np.ndarray:
    out = np.full(hit.shape, fill, dtype=dtype)
    out[hit] = values
    return out.reshape(shape)
