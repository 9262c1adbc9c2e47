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
``frame_points`` (F * K, 3) float32, ``frame_occupancy`` (F * K,) bool
    When the item has samples: ``K = max(1, samples.uniform // frames)`` points uniform in each
    frame's 3D box (the samples box's other three axes), labelled by the same rule as the 4D
    samples (the field's sign, or the mesh inside test) at the point in 4D.

:func:`frames_of` turns the arrays back into ``trimesh.Trimesh`` objects.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._checks import check_keys

__all__ = ["AXES", "DEFAULT_SEQUENCE", "check_sequence", "make_sequence", "frames_of"]

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
    from ao4d.slicing import hyperplane_basis

    from .samples import _labels, sample_box

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
    if vertex_ao:
        mesh.point_data["ao"] = np.asarray(occlusion, np.float64)
    try:
        slices = [mesh.slice(normal * v, normal, attributes=["ao"] if vertex_ao else []) for v in value]
    finally:
        if vertex_ao:
            del mesh.point_data["ao"]
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
    elif occlusion is not None:
        occ = np.asarray(occlusion)
        arrays["face_ao"] = np.concatenate(
            [occ[np.asarray(s.face_attributes.get("simplex", np.zeros(0, int)), np.int64)] for s in slices]
        ).astype(np.float32)
    record: dict[str, Any] = {
        **settings,
        "extent": [lo, hi],
        "vertices": int(sum(counts_v)),
        "faces": int(sum(counts_f)),
        "empty_frames": int(sum(c == 0 for c in counts_f)),
    }
    if samples and rng is not None:
        per = max(1, samples["uniform"] // frames)
        blo, bhi = sample_box(shape)
        ylo, yhi = basis @ blo, basis @ bhi  # basis rows are signed unit axes or a reflection
        ylo, yhi = np.minimum(ylo, yhi), np.maximum(ylo, yhi)
        ys = (ylo + (yhi - ylo) * rng.random((frames, per, 3))).astype(np.float32)
        xs = ys.astype(np.float64) @ basis + (normal * value[:, None])[:, None, :]
        occupancy, _ = _labels(shape, kind, xs.reshape(-1, 4), rng, backend, sdf=False)
        arrays["frame_points"] = ys.reshape(-1, 3)
        arrays["frame_occupancy"] = occupancy
        record["frame_samples"] = per
    return arrays, record


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
