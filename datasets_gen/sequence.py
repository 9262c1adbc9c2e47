"""An item as a sequence of 3D frames: ``sequence = { frames = 17, axis = "w" }`` -> ``sequence.npz``.

Frame ``j`` of ``frames`` is the item's 3D slice (:meth:`ao4d.SimplexMesh.slice`) by the
hyperplane ``x[axis] = lo + (hi - lo) * t_j`` with ``t_j = (j + 1/2) / frames``, ``[lo, hi]``
the mesh's extent along ``axis``: evenly spaced values across the extent (the half-step
inset keeps the first and last cuts off the extreme points, where a slice is empty).
``time`` is ``t_j``, the normalised position in [0, 1].

``sequence.npz`` holds the frames concatenated:

``time``, ``value`` (F,) float64
    Normalised time and the coordinate along ``axis``.
``axis`` () int64, ``basis`` (3, 4) float64
    The frame's 3D coordinates are ``y = basis @ (x - x0)`` with ``x0`` on the hyperplane
    (``ao4d.slicing.hyperplane_basis``: for ``axis = "w"`` exactly x, y, z).
``vertices`` (V, 3) float64, ``faces`` (T, 3) int64, ``vertex_offsets`` (F + 1,), ``face_offsets`` (F + 1,)
    Frame ``j`` is ``vertices[vertex_offsets[j]:vertex_offsets[j + 1]]`` with its
    ``faces[face_offsets[j]:face_offsets[j + 1]]`` (indices local to the frame); outward
    oriented triangles.
``ao`` (V,) float32 (per-vertex AO, interpolated) or ``face_ao`` (T,) float32 (per-simplex AO)
    When the item has AO.
Per-frame 3D samples, when the item has ``samples`` (3D coordinates of the frames; frame ``j``'s
rows are ``[frame_point_offsets[j]:frame_point_offsets[j + 1]]``, and likewise for the surface):

``frame_points`` (P, 3) float32, ``frame_occupancy`` (P,) bool, ``frame_sdf`` (P,) float32, ``frame_point_offsets`` (F + 1,)
    Per frame, ``uniform // frames`` points uniform in the frame's box (the samples box's other
    three axes, ``record["sequence"]["frame_samples"]["box"]``), then for each sigma in order
    ``near_surface // frames`` points on the frame's triangles (uniform by area) plus Gaussian
    offsets of ``sigma`` times the box's 3D diagonal (none in an empty frame: one without
    triangles of positive area); each count at least 1 where the 4D count is not 0
    (:func:`frame_counts`). Occupancy is the 4D solid's at
    the point (the frame is the solid's slice): the field's sign, or the mesh inside test for
    lifted items; ``frame_sdf`` is the exact distance to the frame's triangles signed by
    occupancy (negative exactly where occupied; infinite in an empty frame).
``frame_surface_points``, ``frame_surface_normals`` (Q, 3) float32, ``frame_surface_ao`` (Q,) float32, ``frame_surface_offsets`` (F + 1,)
    Per non-empty frame ``surface // frames`` points uniform by area on its triangles, the
    triangle's outward unit normal, and the AO there (interpolated per vertex, or the cut
    simplex's value) when the item has AO.

``record["sequence"]["frame_samples"]`` holds the per-frame counts, sigmas, box,
``offset_scale`` and ``labels`` (per label ``"field"`` or ``"mesh"``, as for ``samples.npz``;
``sdf`` is always ``"mesh"``: the 4D field's value is no distance within a frame).
:func:`frame_samples_of` splits the arrays by frame.

Cost: each frame slices only the simplices its hyperplane can cut (their extents along the axis
are found once per item), and the distances to a frame's triangles come from libigl's AABB tree
(:func:`triangles_distance`).

:func:`frames_of` turns the arrays back into ``trimesh.Trimesh`` objects.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._checks import check_keys

__all__ = [
    "AXES",
    "DEFAULT_SEQUENCE",
    "check_sequence",
    "make_sequence",
    "frames_of",
    "frame_counts",
    "frame_samples_of",
]

AXES = ("x", "y", "z", "w")
DEFAULT_SEQUENCE: dict[str, Any] = {"frames": 17, "axis": "w"}
_MAX_FRAMES = 4096


def check_sequence(value: Any) -> dict[str, Any] | bool:
    """The validated ``sequence`` setting (``False``: none; ``True``: the defaults).

    Raises ``ValueError`` naming the bad key.
    """
    if value is False:
        return False
    if value is True:
        return dict(DEFAULT_SEQUENCE)
    if not isinstance(value, dict):
        raise ValueError(f"`sequence` must be a table (or true/false), got {value!r}")
    check_keys(value, DEFAULT_SEQUENCE, "`sequence`")
    out = {**DEFAULT_SEQUENCE, **value}
    frames = out["frames"]
    if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= _MAX_FRAMES:
        raise ValueError(f"`sequence.frames` must be an integer in [1, {_MAX_FRAMES}], got {frames!r}")
    if out["axis"] not in AXES:
        raise ValueError(f"`sequence.axis` must be one of {', '.join(map(repr, AXES))}, got {out['axis']!r}")
    return out


def make_sequence(
    shape: Any,
    kind: str,
    settings: dict[str, Any],
    *,
    occlusion: np.ndarray | None = None,
    ao_at: str = "vertices",
    samples: dict[str, Any] | None = None,
    rng: np.random.Generator | None = None,
    backend: str = "auto",
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays of ``sequence.npz`` and the record's ``sequence`` entry for one item.

    ``samples`` (the item's validated samples setting) and ``rng`` add per-frame samples.
    """
    from ao4d.slicing import hyperplane_basis, slice_mesh

    mesh = shape.mesh
    k = AXES.index(settings["axis"])
    frames = settings["frames"]
    lo, hi = (float(b[k]) for b in mesh.bounds)
    time = (np.arange(frames) + 0.5) / frames
    value = lo + (hi - lo) * time
    normal = np.zeros(4)
    normal[k] = 1.0
    basis = hyperplane_basis(normal)
    vertex_ao = occlusion is not None and ao_at == "vertices"
    # the vertex AO interpolated onto each frame, given as data (the mesh is not changed)
    attributes = {"ao": np.asarray(occlusion, np.float64)} if vertex_ao else {}
    # one pass over the simplices: their extents along the axis say which ones each frame's
    # hyperplane x[k] = v may cut (min < v <= max, the slice's own sign rule), so a frame costs
    # its crossed simplices, not the whole mesh
    along = mesh.vertices[:, k][mesh.simplices]
    low, high = along.min(axis=1), along.max(axis=1)
    slices = [
        slice_mesh(mesh, normal * v, normal, attributes, candidates=np.flatnonzero((low < v) & (high >= v)))
        for v in value
    ]
    counts_v = [len(s.vertices) for s in slices]
    counts_f = [len(s.faces) for s in slices]
    arrays: dict[str, np.ndarray] = {
        "time": time,
        "value": value,
        "axis": np.int64(k),
        "basis": basis,
        "vertices": np.concatenate([np.asarray(s.vertices, np.float64).reshape(-1, 3) for s in slices]),
        "faces": np.concatenate([np.asarray(s.faces, np.int64).reshape(-1, 3) for s in slices]),
        "vertex_offsets": np.concatenate([[0], np.cumsum(counts_v)]).astype(np.int64),
        "face_offsets": np.concatenate([[0], np.cumsum(counts_f)]).astype(np.int64),
    }
    if vertex_ao:
        arrays["ao"] = np.concatenate([np.asarray(s.vertex_attributes.get("ao", np.zeros(0))) for s in slices]).astype(
            np.float32
        )
    face_ao = None
    if occlusion is not None and not vertex_ao:
        occ = np.asarray(occlusion)
        face_ao = [occ[np.asarray(s.face_attributes.get("simplex", np.zeros(0, int)), np.int64)] for s in slices]
        arrays["face_ao"] = np.concatenate([np.zeros(0), *face_ao]).astype(np.float32)
    record: dict[str, Any] = {
        **settings,
        "extent": [lo, hi],
        "vertices": int(sum(counts_v)),
        "faces": int(sum(counts_f)),
        "empty_frames": int(sum(c == 0 for c in counts_f)),
    }
    if samples and rng is not None:
        frame_arrays, record["frame_samples"] = _frame_samples(
            shape, kind, samples, rng, backend, slices, basis, normal * value[:, None], vertex_ao, face_ao
        )
        arrays.update(frame_arrays)
    return arrays, record


def frame_counts(samples: dict[str, Any], frames: int) -> dict[str, int]:
    """Per-frame sample counts: each of ``uniform``, ``near_surface`` and ``surface`` divided
    by ``frames`` (at least 1 where the 4D count is not 0)."""
    return {
        key: 0 if not samples[key] else max(1, samples[key] // frames) for key in ("uniform", "near_surface", "surface")
    }


def _area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The total area of a triangle mesh (0 for none, or only degenerate triangles)."""
    corners = vertices[faces]
    return float(np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum())


def _triangle_samples(
    vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``count`` points uniform by area on a triangle mesh: points (count, 3), the triangle's
    unit normal (by its winding: outward for a frame), triangle index, barycentric (count, 3)."""
    corners = vertices[faces]  # (T, 3, 3)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(cross, axis=1)
    cdf = np.cumsum(area) / area.sum()
    tri = np.minimum(np.searchsorted(cdf, rng.random(count), side="right"), len(cdf) - 1)
    bary = -np.log1p(-rng.random((count, 3)))  # Dirichlet(1, 1, 1): uniform in a triangle
    bary /= bary.sum(axis=1, keepdims=True)
    points = np.einsum("nk,nkd->nd", bary, corners[tri])
    return points, cross[tri] / area[tri, None], tri.astype(np.int64), bary


def _frame_samples(
    shape: Any,
    kind: str,
    samples: dict[str, Any],
    rng: np.random.Generator,
    backend: str,
    slices: list[Any],
    basis: np.ndarray,
    origins: np.ndarray,
    vertex_ao: bool,
    face_ao: list[np.ndarray] | None,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The ``frame_*`` arrays of ``sequence.npz`` and the record's ``frame_samples`` entry.

    Per frame ``j`` (3D coordinates ``y``, the 4D point ``x = y @ basis + origins[j]``): the
    uniform points in the frame's box, then for each sigma the near-surface points (points
    uniform by area on the frame's triangles plus Gaussian offsets of ``sigma`` times the box's
    3D diagonal; none in a frame without triangles of positive area), labelled by occupancy at ``x`` (as the 4D samples:
    the field's sign or the mesh inside test) and the exact distance to the frame's triangles
    signed by occupancy; then the surface points, normals and AO (``vertex_ao``: the frames'
    interpolated vertex AO; ``face_ao``: per frame, each triangle's value). Every draw comes from
    ``rng``, frame by frame, so the same seed gives the same bytes.
    """
    from .samples import _labels, labels_provenance, sample_box, signed_float32

    counts = frame_counts(samples, len(slices))
    blo, bhi = sample_box(shape)
    ylo, yhi = basis @ blo, basis @ bhi  # basis rows are signed unit axes or a reflection
    ylo, yhi = np.minimum(ylo, yhi), np.maximum(ylo, yhi)
    diagonal = float(np.linalg.norm(yhi - ylo))
    points, surface, normals, surface_ao, has_surface = [], [], [], [], []
    for j, frame in enumerate(slices):
        vertices = np.asarray(frame.vertices, np.float64).reshape(-1, 3)
        faces = np.asarray(frame.faces, np.int64).reshape(-1, 3)
        parts = [ylo + (yhi - ylo) * rng.random((counts["uniform"], 3))]
        has_surface.append(bool(len(faces)) and _area(vertices, faces) > 0)
        if has_surface[-1]:
            for sigma in samples["sigmas"]:
                base = _triangle_samples(vertices, faces, counts["near_surface"], rng)[0]
                parts.append(base + rng.normal(0.0, sigma * diagonal, size=(counts["near_surface"], 3)))
            at, normal, tri, bary = _triangle_samples(vertices, faces, counts["surface"], rng)
            surface.append(at)
            normals.append(normal)
            if vertex_ao:  # interpolated as the frame's vertices were
                surface_ao.append(np.einsum("nk,nk->n", bary, np.asarray(frame.vertex_attributes["ao"])[faces[tri]]))
            elif face_ao is not None:  # per simplex: the value of the 4D simplex the triangle cuts
                surface_ao.append(face_ao[j][tri])
        points.append(np.concatenate(parts).astype(np.float32))
    point_offsets = np.concatenate([[0], np.cumsum([len(p) for p in points])]).astype(np.int64)
    surface_offsets = np.zeros(len(slices) + 1, np.int64)
    surface_offsets[1:] = np.cumsum([counts["surface"] if has else 0 for has in has_surface])
    y = np.concatenate(points)
    frame_of = np.repeat(np.arange(len(slices)), np.diff(point_offsets))
    x = y.astype(np.float64) @ basis + origins[frame_of]
    occupancy, _ = _labels(shape, kind, x, rng, backend, sdf=False)
    distance = np.full(len(y), np.inf)
    for j, frame in enumerate(slices):
        rows = slice(point_offsets[j], point_offsets[j + 1])
        if has_surface[j] and rows.stop > rows.start:
            distance[rows] = triangles_distance(
                np.asarray(frame.vertices, np.float64), np.asarray(frame.faces, np.int64), y[rows]
            )
    arrays = {
        "frame_points": y,
        "frame_occupancy": occupancy,
        "frame_sdf": signed_float32(occupancy, np.where(occupancy, -distance, distance)),
        "frame_point_offsets": point_offsets,
        "frame_surface_points": _rows3(surface),
        "frame_surface_normals": _rows3(normals),
        "frame_surface_offsets": surface_offsets,
    }
    provenance = labels_provenance(shape, kind)
    provenance["sdf"] = "mesh"  # the 4D field's value is no distance within the frame
    if vertex_ao or face_ao is not None:
        arrays["frame_surface_ao"] = np.concatenate([np.zeros(0), *surface_ao]).astype(np.float32)
    else:
        del provenance["surface_ao"]
    record = {
        **counts,
        "sigmas": list(samples["sigmas"]),
        "box": [ylo.tolist(), yhi.tolist()],
        "offset_scale": diagonal,
        "labels": provenance,
        "points": int(len(y)),
        "surface_points": int(surface_offsets[-1]),
    }
    return arrays, record


def triangles_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact distance (float64) from each point (K, 3) to the nearest triangle of ``faces`` (T, 3)
    on ``vertices`` (V, 3): libigl's AABB tree (``igl.point_mesh_squared_distance``), several
    times faster than :func:`datasets_gen.samples.corners_distance`, which serves 4D meshes;
    both agree to round-off (tests/test_sequence.py). Points are taken relative to the
    triangles' first vertex so that far coordinates lose nothing."""
    from ao4d._optional import require

    igl = require("igl", "distances of a sequence's frame samples")
    shift = vertices[0] if len(vertices) else np.zeros(3)
    squared, _, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(points, np.float64) - shift, np.ascontiguousarray(vertices - shift), faces
    )
    return np.sqrt(squared)


def _rows3(parts: list[np.ndarray]) -> np.ndarray:
    """Rows of 3D points concatenated as float32 (0, 3) when there are none."""
    return np.concatenate([np.zeros((0, 3)), *parts]).astype(np.float32)


def frames_of(arrays: Any) -> list[Any]:
    """The frames of a ``sequence.npz`` (a mapping of its arrays) as ``trimesh.Trimesh`` objects,
    with ``vertex_attributes["ao"]`` / ``face_attributes["ao"]`` and ``metadata["time"]``."""
    import trimesh

    vo, fo = np.asarray(arrays["vertex_offsets"]), np.asarray(arrays["face_offsets"])
    vertices, faces, time = arrays["vertices"], arrays["faces"], arrays["time"]
    out = []
    for j in range(len(vo) - 1):
        kwargs: dict[str, Any] = {}
        if "ao" in arrays:
            kwargs["vertex_attributes"] = {"ao": np.asarray(arrays["ao"][vo[j] : vo[j + 1]])}
        if "face_ao" in arrays:
            kwargs["face_attributes"] = {"ao": np.asarray(arrays["face_ao"][fo[j] : fo[j + 1]])}
        m = trimesh.Trimesh(
            np.asarray(vertices[vo[j] : vo[j + 1]]), np.asarray(faces[fo[j] : fo[j + 1]]), process=False, **kwargs
        )
        m.metadata["time"] = float(time[j])
        out.append(m)
    return out


#: the per-frame sample arrays of a sequence.npz, by the offsets that split them
FRAME_SAMPLE_ARRAYS = {
    "frame_point_offsets": ("points", "occupancy", "sdf"),
    "frame_surface_offsets": ("surface_points", "surface_normals", "surface_ao"),
}


def frame_samples_of(arrays: Any) -> list[dict[str, Any]]:
    """The per-frame 3D samples of a ``sequence.npz`` (a mapping of its arrays), one dict per
    frame: ``points``, ``occupancy``, ``sdf``, ``surface_points``, ``surface_normals``,
    ``surface_ao`` (when the item has AO) and ``time``; empty when the item has no samples."""
    if "frame_point_offsets" not in arrays:
        return []
    time = np.asarray(arrays["time"])
    out: list[dict[str, Any]] = [{"time": float(t)} for t in time]
    for offsets, names in FRAME_SAMPLE_ARRAYS.items():
        o = np.asarray(arrays[offsets])
        for name in names:
            if f"frame_{name}" in arrays:
                a = np.asarray(arrays[f"frame_{name}"])
                for j, frame in enumerate(out):
                    frame[name] = a[o[j] : o[j + 1]]
    return out
