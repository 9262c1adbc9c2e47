"""Screen-space ambient occlusion in 4D: occlusion read from the image's depth volume.

A 4D camera's "screen" is its 3D image, and its depth buffer is a 3D volume holding, per voxel,
the depth of the visible 3-manifold (:class:`DepthVolume`). Screen-space AO estimates the
DESIGN.md occlusion ``A`` at a visible point ``p`` with viewer-facing normal ``n`` from that
volume alone, with a fixed number of look-ups per point instead of rays through a BVH.

Why this file is long: the depth volume, the march on both backends and the denoiser stay one
module because they are one technique and share its conventions (depth, normals, the reach).

The variant
-----------
The ray-traced definition asks, per cosine-weighted direction ``w`` (the same directions
:func:`ao4d.ambient_occlusion` traces: :mod:`ao4d.sampling`, same seed, same point index),
whether the ray ``p + r w``, ``0 < r <= L`` (``L = max_distance``), meets geometry. Here the ray
is marched in ``steps`` points ``q_k = p + r_k w``, ``r_k = L (k + 1) / steps`` (the last at the
reach itself), and the direction counts as occluded at its first ``q_k`` that the image hides:

    bias < delta(q_k) < thickness,

with ``delta`` the depth along ``q_k``'s own view ray by which the visible surface lies in front
of ``q_k``. ``A`` is the fraction of occluded directions. This is the ray-marched, normal-oriented
form of screen-space AO; each term generalises from a 2D depth buffer to the 3D depth volume:

- *Sample kernel*: Mittring (2007) samples a sphere around ``p``; the hemisphere of ``n`` (as in
  HBAO, whose horizons are measured from the tangent plane) with cosine weights (as in
  ground-truth AO, Jimenez et al. 2016, which is the DESIGN.md definition) is used here. In R^4
  that hemisphere is 3-dimensional, and its directions are the same ones the ray-traced AO
  traces, so the two estimates share their Monte Carlo noise and differ only by what the depth
  volume cannot see.
- *Projection and look-up*: ``q`` is projected with the 4D camera (Hollasch's perspective or
  orthographic map onto the image hyperplane) to a voxel of the 3D image (nearest voxel) instead
  of a pixel of a 2D image.
- *Depth comparison*: a 2D SSAO compares ``q``'s depth with the depth buffer. Here the voxel
  holds the visible hit point ``s`` and its normal ``m`` (a normal volume beside the depth
  volume), and ``delta = (q - s) . m / (u . m)`` is the depth of the voxel's tangent hyperplane
  along ``q``'s view ray ``u``: exact for flat surfaces whatever voxel ``q`` falls in, so a flat
  open surface never occludes itself (the "depth-buffer acne" a plain look-up gives at the voxel
  scale needs no voxel-sized bias). Where the hyperplane is too oblique to extend
  (``|u . m| < 0.1``) the voxel's own depth is compared.
- *Bias* (Mittring's self-occlusion bias; HBAO's tangent bias): ``delta`` must exceed ``bias``
  (default ``1e-3 L``), which only has to absorb float32 rounding here.
- *Range limit* (Mittring's range check; HBAO's radius attenuation): ``delta < thickness``
  (default ``L``). The depth volume only knows a surface's front: everything up to ``thickness``
  behind a visible surface is taken as solid, nothing farther behind it.

*Denoising* (:func:`denoise`, optional and separate; ``render(..., denoise=1)``): a depth- and
normal-aware box filter over the image, the 3D form of the blur real-time SSAO applies after
few samples.

What it converges to: with ``steps -> inf`` it is the ray-traced AO (same directions, same reach)
of the "thick depth volume" -- every visible surface extruded ``thickness`` away from the
viewer, everything not visible dropped. For an occluder that hides every point behind it up to
the reach (a wall, a floor, a large solid: a half-space as far as the hemisphere reaches) only
``q`` at ``r = L`` matters, so the estimate equals the ray-traced one for any ``steps``, up to
the voxels where ``q`` lands on the occluder's silhouette or beside its contact line.

Wrong by construction (the README's experiment shows these): occluders outside the image or
behind visible surfaces (hidden, so absent from the volume) do not occlude; an object thinner
than ``thickness`` along the view direction occludes the space behind it as if it were solid
(haloes behind thin objects); one thinner than ``L / steps`` along ``w`` can be stepped over;
and ``A`` is view-dependent, unlike the ray-traced value.

References
----------
M. Mittring, "Finding next gen: CryEngine 2", SIGGRAPH 2007 course *Advanced Real-Time
Rendering in 3D Graphics and Games*, doi:10.1145/1281500.1281671.
L. Bavoil, M. Sainz, K. Dimitrov, "Image-space horizon-based ambient occlusion", SIGGRAPH 2008
talks, doi:10.1145/1401032.1401061.
J. Jimenez, X. Wu, A. Pesce, A. Jarabo, "Practical real-time strategies for accurate indirect
occlusion" (ground-truth AO), SIGGRAPH 2016 course *Physically Based Shading*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._budget import RAYS_PER_SECOND, check_rays
from .._validate import as_array, as_real, check_int, check_memory, check_positive_int, check_seed
from ..mesh import as_mesh
from ..opencl import cl
from ..sampling import cosine_hemisphere, sobol_table
from .camera import Camera4D, image_shape

__all__ = [
    "DepthVolume",
    "screen_space_occlusion",
    "denoise",
    "default_steps",
    "viewer_side",
    "STEP_VOXELS",
    "MIN_STEPS",
    "MAX_STEPS",
    "GRAZING",
    "LOOKUPS_PER_SECOND",
    "DENOISE_PER_SECOND",
    "MAX_SAMPLES",
    "check_samples",
    "march_steps",
]

# Default march: one point per STEP_VOXELS voxels of reach (at the target's distance), between
# MIN_STEPS and MAX_STEPS: a short reach needs few points (more only add look-ups that land on
# the surface's own voxels), a long one needs more, or whole objects are stepped over.
STEP_VOXELS, MIN_STEPS, MAX_STEPS = 8, 4, 16
GRAZING = 0.1  # |u . m| below which the voxel's depth replaces its tangent hyperplane
# Rates for render's estimates before work, on the fast side (_budget.RAYS_PER_SECOND's rule):
# depth look-ups per second and denoise filter-window voxels per second, per backend
LOOKUPS_PER_SECOND = {"opencl": 1e8, "numpy": 1e6}
DENOISE_PER_SECOND = {"opencl": 1e9, "numpy": 1.5e7}
# directions per point: beyond 2**16 the estimate's standard error (at most 1/(2 sqrt(samples)))
# is below 0.002, under the depth volume's own error, so more only cost time
MAX_SAMPLES = 1 << 16
_BIAS = 1e-3  # default bias, times the reach
_POINTS_PER_LAUNCH = 1 << 15
_NUMPY_CHUNK = 1 << 18  # (point, sample, step) triples per numpy chunk


@dataclass(frozen=True)
class DepthVolume:
    """What the camera sees: per voxel the first hit's depth and viewer-facing normal.

    The hit point of a voxel is its own view ray at that depth, so depth and normal (the 3D
    image's G-buffer) fix the visible surface's tangent hyperplane in every voxel.

    Attributes
    ----------
    depth : (nx, ny, nz) float64
        Ray parameter of the first hit (as :attr:`ao4d.RenderResult.depth`); inf on background.
    normals : (nx, ny, nz, 4) float64
        Unit normal of the hit simplex turned towards the viewer (0 on background).
    camera : Camera4D
        The camera that made the image.
    """

    depth: np.ndarray
    normals: np.ndarray
    camera: Camera4D

    @classmethod
    def from_hits(cls, camera: Camera4D, shape, depth, normals) -> DepthVolume:
        """Build the volume from per-voxel arrays (flat or image-shaped), validating them.

        Parameters
        ----------
        camera : Camera4D
            The camera that cast the rays.
        shape : (3,) tuple of int
            The image's voxels along x, y, z.
        depth : (nx * ny * nz,) or (nx, ny, nz) array_like
            inf (or NaN) where no ray hit.
        normals : (nx * ny * nz, 4) or (nx, ny, nz, 4) array_like
            Viewer-facing normals (normalised here); ignored on background.

        Returns
        -------
        DepthVolume
            The volume.
        """
        shape = _camera_shape(camera, shape)
        depth = as_array(depth, "depth", dtype=np.float64)
        if depth.size != math.prod(shape):
            raise ValueError(f"`depth` must hold {math.prod(shape)} voxels, got shape {depth.shape}")
        depth = np.where(np.isnan(depth), np.inf, depth).reshape(shape)
        hit = np.isfinite(depth)
        if (depth[hit] <= 0).any():
            raise ValueError("`depth` must be > 0 where a ray hit")
        arr = as_array(normals, "normals", shape_tail=(4,), dtype=np.float64)
        if arr.size != 4 * depth.size:
            raise ValueError(f"`normals` must hold (voxels, 4) = ({depth.size}, 4) values, got shape {arr.shape}")
        arr = np.where(hit[..., None], arr.reshape(shape + (4,)), 0.0)
        length = np.linalg.norm(arr, axis=-1)
        if not (np.isfinite(length[hit]).all() and (length[hit] > 0).all()):
            raise ValueError("`normals` must be finite and non-zero where `depth` is finite")
        arr[hit] /= length[hit][:, None]
        return cls(depth=depth, normals=arr, camera=camera)

    @classmethod
    def trace(cls, mesh, camera: Camera4D, shape, *, backend: str = "auto") -> DepthVolume:
        """Cast one primary ray per voxel (closest hit, :func:`ao4d.rays.api.cast_rays`) and keep
        the depth and viewer-facing simplex normal of each first hit: the volume
        :func:`ao4d.render` builds for ``ao="screen"`` (:meth:`of_first_hits`).

        Parameters
        ----------
        mesh : SimplexMesh or (vertices, simplices)
            A 4D mesh, in any form :func:`ao4d.mesh.as_mesh` takes (join several with
            :func:`ao4d.mesh.concatenate`).
        camera : Camera4D
            The view.
        shape : (3,) tuple of int
            As for :meth:`from_hits`.
        backend : {"auto", "opencl", "numpy"}
            Where the rays are cast.

        Returns
        -------
        DepthVolume
            The volume.

        Raises
        ------
        TypeError
            If ``mesh`` is not a mesh.
        ValueError
            If it is not 4D.
        """
        from ..rays.api import cast_rays

        mesh = as_mesh(mesh)
        shape = _camera_shape(camera, shape)
        if mesh.dim != 4:
            raise ValueError(f"`mesh` must be a 4D mesh (tetrahedra in R^4), got dimension {mesh.dim}")
        origins, directions = (a.reshape(-1, 4) for a in camera.rays(shape))
        hits = cast_rays(mesh, origins, directions, backend=backend)
        built = cls.of_first_hits(camera, shape, directions, hits.t, hits.simplex, np.asarray(mesh.simplex_normals))
        return cls.from_hits(camera, shape, built.depth, built.normals)

    @classmethod
    def of_first_hits(
        cls,
        camera: Camera4D,
        shape: tuple[int, int, int],
        directions: np.ndarray,
        t: np.ndarray,
        simplex: np.ndarray,
        simplex_normals: np.ndarray,
    ) -> DepthVolume:
        """The volume of one closest-hit ray per voxel, built without checks (valid by
        construction: the caller cast the rays).

        Parameters
        ----------
        camera : Camera4D
            Whose :meth:`~ao4d.Camera4D.rays` were cast.
        shape : (3,) tuple of int
            ``(nx, ny, nz)``, already checked.
        directions : (nx * ny * nz, 4) float64 numpy.ndarray
            The rays' directions (:meth:`ao4d.Camera4D.rays`, C order).
        t : (nx * ny * nz,) float64 numpy.ndarray
            Hit distances (ignored where ``simplex`` is -1).
        simplex : (nx * ny * nz,) int64 numpy.ndarray
            The hit simplex per ray, -1 on a miss.
        simplex_normals : (S, 4) float64 numpy.ndarray
            The mesh's unit simplex normals.

        Returns
        -------
        DepthVolume
            Depth (inf on background) and the hit simplex's normal turned towards the viewer.
        """
        hit = simplex >= 0
        normals = np.zeros((len(t), 4))
        rows = np.flatnonzero(hit)
        raw = simplex_normals[simplex[rows]]
        normals[rows] = raw * viewer_side(raw, directions[rows])[:, None]
        return cls(depth=np.where(hit, t, np.inf).reshape(shape), normals=normals.reshape(shape + (4,)), camera=camera)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.depth.shape)  # type: ignore[return-value]

    @property
    def hit(self) -> np.ndarray:
        """(nx, ny, nz) bool: voxels that see a surface."""
        return np.isfinite(self.depth)

    def hit_points(self) -> np.ndarray:
        """The visible points of the hit voxels (C order).

        Returns
        -------
        (V, 4) float64 numpy.ndarray
            The points.
        """
        origins, directions = (a[self.hit] for a in self.camera.rays(self.shape))
        return origins + self.depth[self.hit][:, None] * directions

    @cached_property
    def gbuffer(self) -> np.ndarray:
        """(nx * ny * nz, 4) float64: the kernel's G-buffer (``kernels/rendering/screen_ao.cl``): the
        viewer-facing normal in the camera's basis, its last component's sign carried by the
        depth in the fourth column (inf on background). Computed once, read-only."""
        # einsum, not matmul: matmul would start BLAS threads that compete for the cores with
        # the OpenCL runtime's threads of the launch just before
        g = np.einsum("nk,jk->nj", self.normals.reshape(-1, 4), self.camera.basis)  # rows a, b, c, d
        depth = self.depth.reshape(-1)  # inf on background (normals 0 there)
        g[:, 3] = np.copysign(depth, np.where(g[:, 3] < 0, -1.0, 1.0))
        g.setflags(write=False)
        return g

    @cached_property
    def _gbuffer32(self) -> np.ndarray:
        return np.ascontiguousarray(self.gbuffer, dtype=np.float32)

    def default_reach(self) -> float:
        """The reach used for ``max_distance=inf``, and the most any reach marches.

        Returns
        -------
        float
            The diagonal of the visible points' box (the image's extent), in world units.
        """
        return self._extent

    @cached_property
    def _extent(self) -> float:
        pts = self.hit_points()
        if not len(pts):
            return 1.0
        return max(float(np.linalg.norm(np.ptp(pts, axis=0))), 1e-12)

    @cached_property
    def _rounding(self) -> float:
        """The least depth difference both backends resolve: ``2^-16`` times the largest
        eye distance of a visible point (float32 keeps 24 bits; the kernel's plane test divides
        by ``|u . m| >= GRAZING`` and rounds a few times)."""
        depth = self.depth[self.hit]
        return 2.0**-16 * (float(depth.max()) if depth.size else 0.0)


def _camera_shape(camera: Camera4D, shape) -> tuple[int, int, int]:
    """``shape`` checked (:func:`ao4d.rendering.camera.image_shape`) once ``camera`` is a Camera4D."""
    if not isinstance(camera, Camera4D):
        raise TypeError(f"`camera` must be an ao4d.Camera4D, got {type(camera).__name__}")
    return image_shape(shape)


def check_samples(samples: object) -> int:
    """``samples`` as a count of directions per point, 1 to :data:`MAX_SAMPLES`.

    Parameters
    ----------
    samples : int
        The directions per point asked for.

    Returns
    -------
    int
        ``samples``, checked.

    Raises
    ------
    ValueError
        Naming ``samples``: not a positive integer, or above :data:`MAX_SAMPLES` (more directions
        than the depth volume can resolve).
    """
    samples = check_positive_int(samples, "samples")
    if samples > MAX_SAMPLES:
        raise ValueError(
            f"`samples` of screen-space AO must be at most {MAX_SAMPLES}, got {samples}: beyond it the "
            "estimate's error is below the depth volume's own, so more directions only cost time"
        )
    return samples


def screen_space_occlusion(
    volume: DepthVolume,
    points,
    normals,
    *,
    samples: int = 64,
    max_distance: float = math.inf,
    steps: int | None = None,
    bias: float | None = None,
    thickness: float | None = None,
    seed: int = 0,
    backend: str = "auto",
    max_rays: float | None = None,
) -> np.ndarray:
    """Screen-space ambient occlusion at points, from a depth volume (module docstring).

    Parameters
    ----------
    volume : DepthVolume
        The image's depth, hit points and viewer-facing normals.
    points : (N, 4) array_like of float
        Where AO is wanted (usually the visible hits themselves).
    normals : (N, 4) array_like of float
        Their normals, facing the viewer (normalised here).
    samples : int
        Cosine-weighted directions per point (>= 1); point i uses the directions the ray-traced
        :func:`ao4d.ambient_occlusion` traces for point i with the same ``seed``.
    max_distance : float
        The reach ``L`` (> 0): directions are marched to ``p + L w``, ``L`` clamped to the
        diagonal of the visible points' bounding box (the image's extent; ``inf`` takes it).
    steps : int, optional
        March points per direction (>= 1): ``samples * steps`` look-ups per point at most;
        default :func:`default_steps` (4 to 16, one per 8 voxels of reach).
    bias : float, optional
        Depth (>= 0) by which a surface must lie in front of a march point to hide it; default
        ``1e-3 L``. At least ``2^-16`` times the largest eye distance of the points and the
        visible surface, on both backends: the float32 kernel cannot resolve less, and would
        count its rounding as occlusion.
    thickness : float, optional
        Range limit (> ``bias``): surfaces farther than this in front of a march point do not
        hide it (the depth volume's assumed thickness); default ``L``.
    seed : int
        Seeds the directions, in ``[0, 2**32)`` (deterministic: the same seed gives the same result).
    backend : {"auto", "opencl", "numpy"}
        OpenCL kernel ``kernels/rendering/screen_ao.cl`` or the numpy reference (float64); they agree up
        to float32 rounding at the voxel and depth thresholds.
    max_rays : float, optional
        Refuse, before any work, when the ``N * samples * steps`` depth look-ups, counted as
        rays at their cost (``LOOKUPS_PER_SECOND``), exceed this (default
        ``ao4d._budget.MAX_RAYS`` of the backend: about half an hour); ``math.inf`` lifts it.

    Returns
    -------
    occlusion : (N,) float64
        In [0, 1], multiples of ``1 / samples``; 1 = fully occluded.

    Raises
    ------
    ValueError
        Points and normals of different lengths or not (N, 4), non-finite values, a zero
        normal, non-positive ``max_distance``, ``steps``, ``samples`` or ``thickness``, or
        look-ups above ``max_rays``.

    Examples
    --------
    A hyperplane facing an orthographic camera occludes nothing:

    >>> import numpy as np, ao4d
    >>> cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1)
    >>> shape = (4, 4, 4)
    >>> centers = cam.voxel_centers(shape).reshape(-1, 4)
    >>> up = np.tile([0.0, 0, 0, -1], (64, 1))
    >>> vol = DepthVolume.from_hits(cam, shape, np.full(64, 4.0), up)
    >>> a = screen_space_occlusion(vol, centers, up, samples=16, max_distance=0.5, backend="numpy")
    >>> float(a.max())
    0.0
    """
    if not isinstance(volume, DepthVolume):
        raise TypeError(f"`volume` must be an ao4d.rendering.screen_ao.DepthVolume, got {type(volume).__name__}")
    pts = as_array(points, "points", ndim=2, shape_tail=(4,), dtype=np.float64, finite=True)
    nrm = as_array(normals, "normals", ndim=2, shape_tail=(4,), dtype=np.float64, finite=True)
    if len(pts) != len(nrm):
        raise ValueError(f"`points` and `normals` must have the same length, got {len(pts)} and {len(nrm)}")
    length = np.linalg.norm(nrm, axis=1)
    if (length <= 0).any():
        raise ValueError(f"`normals` must be non-zero, got a zero row at {int(np.argmin(length))}")
    nrm = nrm / length[:, None]
    samples = check_samples(samples)
    seed = check_seed(seed)
    reach = _reach(volume, max_distance)
    steps = default_steps(volume, reach) if steps is None else check_positive_int(steps, "steps")
    bias = _BIAS * reach if bias is None else as_real(bias, "bias", ge=0)
    thickness = reach if thickness is None else as_real(thickness, "thickness", gt=bias, finite=False)
    # below float32's resolution of the points the kernel would count rounding as depth
    eye_distance = float(np.linalg.norm(pts - volume.camera.eye, axis=1).max()) if len(pts) else 0.0
    bias = max(bias, volume._rounding, 2.0**-16 * eye_distance)
    check_memory(samples * 4 * 12.0, f"the direction table for samples={samples}", hint="use fewer `samples`")
    runtime = cl.resolve_backend(backend)
    name = cl.backend_name(runtime)
    # the work budget of the ray casts, look-ups counted at their cost: a run is refused before
    # it starts, not only when its direction table would not fit in memory
    lookups = len(pts) * samples * steps
    check_rays(
        lookups / LOOKUPS_PER_SECOND[name] * RAYS_PER_SECOND[name],
        name,
        max_rays,
        what=f"`samples`={samples} x {steps} steps at {len(pts):,} points ({lookups:.3g} depth look-ups, "
        "counted as rays at their cost)",
        hint="use fewer `samples` or points, or pass max_rays=math.inf",
    )
    if not len(pts):
        return np.zeros(0)
    args = dict(samples=samples, steps=steps, reach=reach, bias=bias, thickness=thickness, seed=seed)
    if runtime is None:
        counts = _numpy_counts(volume, pts, nrm, **args)
    else:
        counts = _opencl_counts(runtime, volume, pts, nrm, **args)
    return counts / samples


def _reach(volume: DepthVolume, max_distance) -> float:
    """The reach marched: ``max_distance`` clamped to the image's extent
    (:meth:`DepthVolume.default_reach`). Farther march points lie outside the image, or behind
    everything it holds: a longer reach would only spread the same steps thinner."""
    reach = as_real(max_distance, "max_distance", gt=0, finite=False)
    if math.isnan(reach):
        raise ValueError("`max_distance` must be a number, got nan")
    if not volume.hit.any():  # an empty image has no extent to clamp to
        return volume.default_reach() if math.isinf(reach) else reach
    return min(reach, volume.default_reach())


def default_steps(volume: DepthVolume, max_distance: float) -> int:
    """March points per direction by default: ``ceil(L / (STEP_VOXELS voxel sizes))`` clipped to
    ``[MIN_STEPS, MAX_STEPS]``, with ``L`` the reach (``inf``: the visible points' diagonal) and
    the voxel size at the target's distance.

    Parameters
    ----------
    volume : DepthVolume
        The depth volume.
    max_distance : float
        The reach.

    Returns
    -------
    int
        March points per direction.

    Examples
    --------
    >>> import ao4d
    >>> cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=2)
    >>> vol = DepthVolume(np.full((80, 80, 80), np.inf), np.zeros((80, 80, 80, 4)), cam)
    >>> default_steps(vol, 1.0), default_steps(vol, 3.0)   # 20 and 60 voxels of reach
    (4, 8)
    """
    reach = _reach(volume, max_distance)
    return march_steps(reach / volume.camera.geometry(volume.shape).spacing)


def march_steps(reach_voxels: float) -> int:
    """March points per direction for a reach of ``reach_voxels`` voxel sizes:
    ``ceil(reach_voxels / STEP_VOXELS)`` clipped to ``[MIN_STEPS, MAX_STEPS]``.

    Parameters
    ----------
    reach_voxels : float
        The reach, in voxel sizes at the target's distance.

    Returns
    -------
    int
        March points per direction.
    """
    return int(min(MAX_STEPS, max(MIN_STEPS, math.ceil(reach_voxels / STEP_VOXELS))))


def denoise(
    occlusion,
    volume: DepthVolume,
    *,
    radius: int = 1,
    tolerance: float = 2.0,
    normal_min: float = 0.8,
    backend: str = "auto",
) -> np.ndarray:
    """Depth- and normal-aware box filter of a screen-space AO image (a separate, optional step).

    Few directions per voxel leave Monte Carlo noise of up to ``0.5 / sqrt(samples)``; as
    screen-space AO usually does (Mittring 2007; Bavoil & Sainz 2008 blur across the screen
    with depth-aware weights), neighbouring voxels of the same surface are averaged. Voxel ``v``
    takes the mean over the ``(2 radius + 1)^3`` voxels around it that see a surface whose normal
    is within ``normal_min`` (cosine) of ``v``'s and whose hit point lies within ``tolerance``
    voxel sizes (at ``v``'s depth) of ``v``'s tangent hyperplane, so creases and depth
    discontinuities stay sharp. The average is unweighted: on a flat surface with occlusion
    varying linearly it is unbiased; it blurs features smaller than the window.

    Parameters
    ----------
    occlusion : (nx, ny, nz) array_like of float
        Occlusion per voxel (NaN or anything on background), e.g. ``RenderResult.occlusion``.
    volume : DepthVolume
        The image's depth volume (same shape).
    radius : int
        Half width of the window in voxels (>= 0; 0 returns the input on hits).
    tolerance : float
        Plane-distance limit in voxel sizes (> 0).
    normal_min : float
        Least cosine between the normals (in [-1, 1]).
    backend : {"auto", "opencl", "numpy"}

    Returns
    -------
    smoothed : (nx, ny, nz) float64
        NaN on background.
    """
    if not isinstance(volume, DepthVolume):
        raise TypeError(f"`volume` must be an ao4d.rendering.screen_ao.DepthVolume, got {type(volume).__name__}")
    occ = as_array(occlusion, "occlusion", dtype=np.float64)
    if occ.shape != volume.shape:
        raise ValueError(f"`occlusion` must have the volume's shape {volume.shape}, got {occ.shape}")
    if not np.isfinite(occ[volume.hit]).all():
        raise ValueError("`occlusion` must be finite where the volume sees a surface")
    radius = check_int(radius, "radius", minimum=0)
    tolerance = as_real(tolerance, "tolerance", gt=0)
    normal_min = as_real(normal_min, "normal_min", ge=-1, le=1)
    runtime = cl.resolve_backend(backend)
    f = _frame(volume, np.zeros((0, 4)), np.zeros((0, 4)))
    if runtime is None:
        return _numpy_denoise(volume, occ, f, radius, tolerance, normal_min)
    return _opencl_denoise(runtime, volume, occ, f, radius, tolerance, normal_min)


def _surfaces(g: np.ndarray, idx: np.ndarray, f: dict) -> tuple[np.ndarray, np.ndarray]:
    """Hit points minus eye and unit normals (camera basis) of G-buffer rows at voxel indices."""
    d = np.abs(g[..., 3])
    m = g.copy()
    m[..., 3] = np.copysign(np.sqrt(np.maximum(0.0, 1.0 - (g[..., :3] ** 2).sum(-1))), g[..., 3])
    centre = np.concatenate([f["origin"] + f["spacing"] * idx, np.full(idx.shape[:-1] + (1,), f["distance"])], axis=-1)
    if f["perspective"]:
        s = d[..., None] * centre / np.linalg.norm(centre, axis=-1, keepdims=True)
    else:
        s = np.concatenate([centre[..., :3], d[..., None]], axis=-1)
    return s, m


def _numpy_denoise(volume, occ, f, radius, tolerance, normal_min) -> np.ndarray:
    shape = volume.shape
    hit = volume.hit
    g = f["gbuffer"].reshape(shape + (4,))
    idx = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), axis=-1)
    s, m = _surfaces(np.where(hit[..., None], g, 0.0), idx, f)
    if f["perspective"]:
        centre = np.concatenate([f["origin"] + f["spacing"] * idx, np.full(shape + (1,), f["distance"])], axis=-1)
        size = f["spacing"] * np.linalg.norm(s, axis=-1) / np.linalg.norm(centre, axis=-1)
    else:
        size = np.full(shape, f["spacing"])
    limit = tolerance * size
    total = np.zeros(shape)
    count = np.zeros(shape)
    values = np.where(hit, occ, 0.0)
    r = radius
    for dx in range(-r, r + 1):
        for dy in range(-r, r + 1):
            for dz in range(-r, r + 1):
                dst = tuple(slice(max(0, -o), k - max(0, o)) for o, k in zip((dx, dy, dz), shape))
                src = tuple(slice(max(0, o), k - max(0, -o)) for o, k in zip((dx, dy, dz), shape))
                ok = hit[dst] & hit[src]
                ok &= np.einsum("...k,...k->...", m[src], m[dst]) >= normal_min
                ok &= np.abs(np.einsum("...k,...k->...", s[src] - s[dst], m[dst])) <= limit[dst]
                total[dst] += np.where(ok, values[src], 0.0)
                count[dst] += ok
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(hit, total / count, np.nan)


def _opencl_denoise(runtime, volume, occ, f, radius, tolerance, normal_min) -> np.ndarray:
    import pyopencl as pcl

    n_vox = volume.depth.size
    cl.check_device_memory(
        runtime, {"the G-buffer": n_vox * 16, "the occlusion": n_vox * 8}, task="denoising screen-space AO"
    )
    kernel = cl.build_kernels(runtime, "rendering/screen_ao.cl", {"DIM": 4})["denoise"]
    ctx, queue = runtime.context, runtime.queue
    ro = pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR
    values = np.ascontiguousarray(np.where(volume.hit, occ, 0.0).reshape(-1), dtype=np.float32)
    out = np.empty(n_vox, dtype=np.float32)
    buf_out = pcl.Buffer(ctx, pcl.mem_flags.WRITE_ONLY, out.nbytes)
    kernel(
        queue,
        (n_vox,),
        None,
        pcl.Buffer(ctx, ro, hostbuf=volume._gbuffer32),
        pcl.Buffer(ctx, ro, hostbuf=values),
        *[np.int32(k) for k in volume.shape],
        np.asarray(list(f["origin"]) + [f["spacing"]], dtype=np.float32),
        np.float32(f["distance"]),
        np.int32(f["perspective"]),
        np.int32(radius),
        np.float32(tolerance),
        np.float32(normal_min),
        buf_out,
    )
    pcl.enqueue_copy(queue, out, buf_out)
    queue.finish()
    return out.reshape(volume.shape).astype(np.float64)


def viewer_side(normals: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """+1 where a normal faces against its ray (its front is seen), -1 where along it.

    Parameters
    ----------
    normals, directions : (H, 4) float64 numpy.ndarray
        Normals and ray directions.

    Returns
    -------
    (H,) numpy.ndarray
        The signs.
    """
    return np.where(np.einsum("hd,hd->h", normals, directions) > 0, -1.0, 1.0)


# -- the camera as both backends see it --------------------------------------------------------


def _frame(volume: DepthVolume, pts, nrm):
    """Query points relative to the eye in the camera's basis; the G-buffer (kernel comment)."""
    cam = volume.camera
    geo = cam.geometry(volume.shape)
    return dict(
        points=np.einsum("nk,jk->nj", pts - cam.eye, cam.basis),
        gbuffer=volume.gbuffer,
        distance=cam.distance,
        perspective=cam.projection == "perspective",
        origin=np.asarray(geo.origin, dtype=np.float64),
        spacing=geo.spacing,
    )


def _numpy_counts(volume: DepthVolume, pts, nrm, *, samples, steps, reach, bias, thickness, seed):
    """Occluded-direction counts per point, float64; the reference for the kernel (same steps,
    in the camera's basis relative to the eye)."""
    f = _frame(volume, pts, nrm)
    shape = np.array(volume.shape)
    g = f["gbuffer"]
    radii = reach * np.arange(1, steps + 1) / steps
    counts = np.zeros(len(pts), dtype=np.int64)
    chunk = max(1, _NUMPY_CHUNK // (samples * steps))
    for start in range(0, len(pts), chunk):
        stop = min(start + chunk, len(pts))
        # directions in world coordinates (those of the ray-traced AO), then in the basis
        w = cosine_hemisphere(nrm[start:stop], samples, seed=seed, index_offset=start)
        w = w @ volume.camera.basis.T
        c = f["points"][start:stop, None, None, :] + radii[None, None, :, None] * w[:, :, None, :]
        if f["perspective"]:
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(c[..., 3] > 0, f["distance"] / c[..., 3], np.nan)
        else:
            scale = np.ones(c.shape[:-1])
        with np.errstate(invalid="ignore"):
            idx = np.floor((c[..., :3] * scale[..., None] - f["origin"]) / f["spacing"] + 0.5)
            inside = np.isfinite(idx).all(-1) & (idx >= 0).all(-1) & (idx < shape).all(-1)
        idx = np.where(inside[..., None], idx, 0).astype(np.int64)
        gv = g[(idx[..., 0] * shape[1] + idx[..., 1]) * shape[2] + idx[..., 2]]
        seen = inside & np.isfinite(gv[..., 3])
        d = np.abs(gv[..., 3])
        se, m = _surfaces(gv, idx, f)
        if f["perspective"]:
            tq = np.linalg.norm(c, axis=-1)
            u = c / tq[..., None]
        else:
            tq = c[..., 3]
            u = np.zeros_like(c)
            u[..., 3] = 1.0
        um = np.einsum("...k,...k->...", u, m)
        with np.errstate(divide="ignore", invalid="ignore"):
            plane = np.einsum("...k,...k->...", c - se, m) / um
            delta = np.where(np.abs(um) >= GRAZING, plane, tq - d)
            hidden = seen & (delta > bias) & (delta < thickness)
        counts[start:stop] = hidden.any(axis=2).sum(axis=1)
    return counts


def _opencl_counts(runtime, volume: DepthVolume, pts, nrm, *, samples, steps, reach, bias, thickness, seed):
    """The same counts from ``kernels/rendering/screen_ao.cl`` (float32, camera basis)."""
    import pyopencl as pcl

    n_vox = volume.depth.size
    n = len(pts)
    cl.check_device_memory(runtime, {"the G-buffer": n_vox * 16, "the AO points": n * 36}, task="screen-space AO")
    f = _frame(volume, pts, nrm)
    kernel = cl.build_kernels(runtime, "rendering/screen_ao.cl", {"DIM": 4})["screen_ao"]
    ctx, queue = runtime.context, runtime.queue
    ro = pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR
    f4 = lambda a: np.ascontiguousarray(a, dtype=np.float32).reshape(-1, 4)  # noqa: E731
    vec = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    # world points relative to the eye and world normals (the kernel makes the ray-traced AO's
    # directions from them, then takes everything into the camera's basis)
    cam = volume.camera
    eye = np.zeros(4, dtype=np.float32)
    axes = cam.basis.astype(np.float32)
    args = (
        [pcl.Buffer(ctx, ro, hostbuf=volume._gbuffer32)]
        + [np.int32(s) for s in volume.shape]
        + [
            eye,
            axes[0],
            axes[1],
            axes[2],
            axes[3],
            np.float32(f["distance"]),
            np.int32(f["perspective"]),
            vec(list(f["origin"]) + [f["spacing"]]),
            pcl.Buffer(ctx, ro, hostbuf=f4(pts - cam.eye)),
            pcl.Buffer(ctx, ro, hostbuf=f4(nrm)),
            pcl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(sobol_table(samples, 3, seed=seed))),
            np.int32(samples),
            np.uint32(seed & 0xFFFFFFFF),
            np.int32(steps),
            np.float32(reach),
            np.float32(bias),
            np.float32(min(thickness, 3e38)),
        ]
    )
    counts = np.empty(n, dtype=np.int32)
    buf_counts = pcl.Buffer(ctx, pcl.mem_flags.WRITE_ONLY, counts.nbytes)
    args.append(buf_counts)
    for start in range(0, n, _POINTS_PER_LAUNCH):
        count = min(_POINTS_PER_LAUNCH, n - start)
        kernel(queue, (count,), None, *args, global_offset=(start,)).wait()
    pcl.enqueue_copy(queue, counts, buf_counts)
    queue.finish()
    return counts.astype(np.int64)
