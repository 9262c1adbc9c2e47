"""Render 4D meshes into 3D image volumes with a :class:`~ao4d.camera.Camera4D`.

One primary ray per voxel (closest hit through :func:`ao4d.ao.cast_rays`), then

    shade = ambient * (1 - A) + diffuse * max(0, n . l)

with ``A`` the 4D ambient occlusion at the hit (DESIGN.md definition), ``n`` the surface normal
turned towards the viewer, and ``l`` the unit direction towards an optional directional light.
Background voxels have shade 0, depth inf and object id -1.

References
----------
S. R. Hollasch, "Four-Space Visualization of 4D Objects", MSc thesis, Arizona State University,
1991 (4D ray tracing into a 3D voxel image).
"""

from __future__ import annotations

import math
import os
import sys
import types
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ._validate import as_array, check_choice, check_memory, check_positive_int
from .camera import Camera4D, ImageGeometry, _image_shape

__all__ = ["render", "RenderResult", "prepare_scene"]

# Primary rays per cast_rays call: bounds host memory and lets tqdm show progress.
_CHUNK = 1 << 16
# Show progress by default only for images with at least this many voxels.
_PROGRESS_VOXELS = 1 << 18


@dataclass
class RenderResult:
    """A rendered 3D image and what each voxel's ray hit.

    Attributes
    ----------
    shade : (nx, ny, nz) float32
        ``ambient * (1 - A) + diffuse * max(0, n . l)``; 0 on background.
    depth : (nx, ny, nz) float32
        Ray parameter of the hit (distance from the eye for perspective, from the eye's
        hyperplane for orthographic); inf on background.
    object_id : (nx, ny, nz) int32
        Index of the mesh hit (order of the list given to :func:`render`); -1 on background.
    occlusion : (nx, ny, nz) float32
        Ambient occlusion ``A`` at the hit (0 where ``ao="none"``); NaN on background.
    camera : Camera4D
    geometry : ImageGeometry
        Voxel spacing and origin on the image hyperplane (what volume files store).
    info : dict
        Counts and timings: ``primary_rays``, ``ao_rays``, ``ao_seconds``, ``backend``.
    """

    shade: np.ndarray
    depth: np.ndarray
    object_id: np.ndarray
    occlusion: np.ndarray
    camera: Camera4D
    geometry: ImageGeometry
    info: dict = field(default_factory=dict)

    @property
    def hit(self) -> np.ndarray:
        """(nx, ny, nz) bool: voxels whose ray hit the scene."""
        return self.object_id >= 0

    def save(self, path: str | os.PathLike) -> Path:
        """Write the image: ``.vti`` holds shade, depth, object_id and occlusion; ``.mhd`` shade.

        Background depth and occlusion are stored as NaN (ParaView and ITK leave NaN out of
        colour ranges; inf would stretch them).
        """
        from . import io

        path = Path(path)
        spacing, origin = self.geometry.spacing, self.geometry.origin
        suffix = check_choice(path.suffix.lower(), "path extension", (".mhd", ".vti"))
        if suffix == ".mhd":
            return io.write_mhd(path, self.shade, spacing=spacing, origin=origin)
        depth = np.where(self.hit, self.depth, np.nan).astype(np.float32)
        arrays = {"shade": self.shade, "depth": depth, "object_id": self.object_id,
                  "occlusion": self.occlusion}
        return io.write_vti(path, arrays, spacing=spacing, origin=origin)


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
    object_id : (S,) int32
    """
    from .mesh import SimplexMesh, _mesh_list, concatenate

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
    ao: Literal["vertices", "hits", "none"] = "vertices",
    samples: int = 64,
    max_distance: float = math.inf,
    seed: int = 0,
    ambient: float = 1.0,
    light=None,
    diffuse: float = 0.5,
    normals: Literal["smooth", "flat"] = "smooth",
    backend: Literal["auto", "opencl", "numpy"] = "auto",
    progress: bool | None = None,
) -> RenderResult:
    """Render 4D meshes into a 3D image volume (one primary ray per voxel).

    Parameters
    ----------
    meshes : SimplexMesh or sequence of SimplexMesh
        4D meshes (closed surfaces or raw open tetrahedra). Lists are joined; the result's
        ``object_id`` is the list position.
    camera : Camera4D
    shape : (3,) tuple of int
        Image size ``(nx, ny, nz)`` along the camera's image axes.
    ao : {"vertices", "hits", "none"}
        ``"vertices"``: per-vertex occlusion from ``mesh.point_data["ao"]`` (computed with
        :func:`ao4d.ambient_occlusion` when absent) interpolated with the hit's barycentric
        weights. ``"hits"``: occlusion computed at every hit point with the normal facing the
        viewer (exact per voxel and right for open, two-sided geometry). ``"none"``: A = 0.
    samples : int
        Hemisphere rays per AO estimate (when AO is computed here).
    max_distance : float
        AO ray length (inf: any hit occludes).
    seed : int
        AO random seed (results are deterministic).
    ambient : float
        Weight of the ambient term ``1 - A``.
    light : (4,) array_like, optional
        Direction *towards* a directional light; adds ``diffuse * max(0, n . l)``.
    diffuse : float
        Weight of the Lambert term (ignored without ``light``).
    normals : {"smooth", "flat"}
        Lambert normals interpolated from vertex normals, or the hit simplex's own.
    backend : {"auto", "opencl", "numpy"}
        Passed to :func:`ao4d.ao.cast_rays` and :func:`ao4d.ambient_occlusion`.
    progress : bool, optional
        tqdm progress bar; default on for images of 2^18 voxels or more.

    Returns
    -------
    RenderResult
        ``shade`` in ``[0, ambient + diffuse]``, ``depth``, ``object_id``, ``occlusion``.

    Raises
    ------
    ValueError
        Bad shape, negative weights, zero light direction, non-4D meshes, empty scene.

    Examples
    --------
    >>> import ao4d
    >>> sphere = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (16,) * 4, (-1.2, 1.2))
    >>> cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1.5)
    >>> image = ao4d.render(sphere, cam, (16, 16, 16), ao="none")
    >>> bool(image.hit[8, 8, 8]), bool(image.hit[0, 0, 0])
    (True, False)
    """
    if not isinstance(camera, Camera4D):
        raise TypeError(f"`camera` must be an ao4d.Camera4D, got {type(camera).__name__}")
    shape = _image_shape(shape)
    check_choice(ao, "ao", ("vertices", "hits", "none"))
    check_choice(normals, "normals", ("smooth", "flat"))
    check_choice(backend, "backend", ("auto", "opencl", "numpy"))
    samples = check_positive_int(samples, "samples")
    ambient = _weight(ambient, "ambient")
    light_dir = None
    if light is not None:
        diffuse = _weight(diffuse, "diffuse")
        lv = as_array(light, "light", ndim=1, shape_tail=(4,), dtype=np.float64, finite=True)
        norm = np.linalg.norm(lv)
        if norm == 0:
            raise ValueError("`light` must be a non-zero direction")
        light_dir = lv / norm
    max_distance = float(max_distance)
    if not max_distance > 0:
        raise ValueError(f"`max_distance` must be > 0, got {max_distance}")
    n_rays = math.prod(shape)
    check_memory(n_rays * 4 * 8 * 6, "rendering an image of this shape")
    scene, object_ids = prepare_scene(meshes)
    show = n_rays >= _PROGRESS_VOXELS if progress is None else bool(progress)

    from .ao import cast_rays

    origins, directions = (a.reshape(-1, 4) for a in camera.rays(shape))
    t, simplex, bary = _cast_chunked(cast_rays, scene, origins, directions, backend, show)
    hit = simplex >= 0
    tri = scene.simplices[simplex[hit]]  # (H, 4) vertex ids of the hit tetrahedra
    dirs = directions[hit]
    # two-sided shading: the side of the hit simplex that faces the ray decides, for the face
    # normal and for the interpolated vertex normal alike (near silhouettes an interpolated
    # normal may lean away from the ray although the face is seen from its front)
    raw_n = np.asarray(scene.simplex_normals)[simplex[hit]]
    side = _viewer_side(raw_n, dirs)
    face_n = raw_n * side[:, None]
    info: dict[str, Any] = {"primary_rays": n_rays, "ao_rays": 0, "ao_seconds": 0.0,
                            "backend": backend, "hits": int(hit.sum())}

    occ = np.zeros(hit.sum())
    if ao == "vertices":
        occ = _vertex_occlusion(scene, tri, bary[hit], samples=samples, seed=seed,
                                max_distance=max_distance, backend=backend, info=info)
    elif ao == "hits" and hit.any():
        points = origins[hit] + t[hit, None] * dirs
        occ = _hit_occlusion(scene, points, face_n, samples=samples, seed=seed,
                             max_distance=max_distance, backend=backend, info=info, show=show)

    shade_hit = ambient * (1.0 - np.clip(occ, 0.0, 1.0))
    if light_dir is not None:
        if normals == "smooth":
            vn = np.asarray(scene.vertex_normals)[tri]  # (H, 4, 4)
            lam_n = np.einsum("hk,hkd->hd", bary[hit], vn)
            lam_n /= np.maximum(np.linalg.norm(lam_n, axis=1, keepdims=True), 1e-12)
            lam_n = lam_n * side[:, None]
        else:
            lam_n = face_n
        shade_hit = shade_hit + diffuse * np.clip(lam_n @ light_dir, 0.0, None)

    return RenderResult(
        shade=_scatter(shape, hit, shade_hit, 0.0, np.float32),
        depth=_scatter(shape, hit, t[hit], np.inf, np.float32),
        object_id=_scatter(shape, hit, object_ids[simplex[hit]], -1, np.int32),
        occlusion=_scatter(shape, hit, occ, np.nan, np.float32),
        camera=camera,
        geometry=camera.geometry(shape),
        info=info,
    )


def _weight(value, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"`{name}` must be a finite number >= 0, got {value}")
    return value


def _cast_chunked(cast_rays, scene, origins, directions, backend, show):
    """Closest hits of all primary rays, in chunks (progress bar over voxels)."""
    from tqdm.auto import tqdm

    n = len(origins)
    t = np.full(n, np.inf)
    simplex = np.full(n, -1, dtype=np.int64)
    bary = np.zeros((n, 4))
    with tqdm(total=n, desc="primary rays", unit="ray", disable=not show, leave=False) as bar:
        for start in range(0, n, _CHUNK):
            stop = min(start + _CHUNK, n)
            hits = cast_rays(scene, origins[start:stop], directions[start:stop],
                             closest=True, backend=backend)
            t[start:stop] = hits.t
            simplex[start:stop] = hits.simplex
            bary[start:stop] = hits.barycentric
            bar.update(stop - start)
    return t, simplex, bary


def _viewer_side(normals: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """+1 where the normal faces against the ray (front side seen), -1 where it faces along."""
    return np.where(np.einsum("hd,hd->h", normals, directions) > 0, -1.0, 1.0)


def _vertex_occlusion(scene, tri, bary, *, samples, seed, max_distance, backend, info):
    """Per-vertex AO (stored or computed once) interpolated at the hits."""
    import time

    from .ao import ambient_occlusion

    if "ao" not in scene.point_data:
        start = time.perf_counter()
        values = ambient_occlusion(scene, samples=samples, max_distance=max_distance,
                                   at="vertices", seed=seed, backend=backend)
        info["ao_seconds"] += time.perf_counter() - start
        info["ao_rays"] += scene.n_vertices * samples
    else:
        values = scene.point_data["ao"]
    per_vertex = np.asarray(values, dtype=np.float64)
    return np.einsum("hk,hk->h", bary, per_vertex[tri])


def _hit_occlusion(scene, points, normals, *, samples, seed, max_distance, backend, info, show):
    """AO at every hit point, hemisphere around the normal that faces the viewer."""
    import time

    from .ao import ambient_occlusion

    start = time.perf_counter()
    values = ambient_occlusion(scene, samples=samples, max_distance=max_distance, points=points,
                               normals=normals, seed=seed, backend=backend, progress=show)
    info["ao_seconds"] += time.perf_counter() - start
    info["ao_rays"] += len(points) * samples
    return np.asarray(values, dtype=np.float64)


def _scatter(shape, hit, values, fill, dtype) -> np.ndarray:
    out = np.full(hit.shape, fill, dtype=dtype)
    out[hit] = values
    return out.reshape(shape)


class _CallableModule(types.ModuleType):
    """``ao4d.render`` is both this module and the function: importing the submodule makes
    Python bind the module to the package attribute ``ao4d.render``, replacing the lazily
    exported function, so the module forwards calls to :func:`render`."""

    def __call__(self, *args: Any, **kwargs: Any) -> RenderResult:
        return render(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
