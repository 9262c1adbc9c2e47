"""Tests for datasets_gen.sequence: the frames of a 4D ball against its analytic slices."""

from __future__ import annotations

import math

import numpy as np
import pytest

from datasets_gen.families import build_shape
from datasets_gen.samples import check_samples
from datasets_gen.sequence import check_sequence, frame_samples_of, frames_of, make_sequence

SETTINGS = {
    "grid": 14,
    "method": "cubes",
    "padding": 0.15,
    "bounds": None,
    "rotation": "none",
    "tetrahedra": "star",
    "ao": False,
    "renders": [],
}


def _ball(radius=0.8):
    return build_shape("hypersphere", {"radius": radius}, SETTINGS, np.random.default_rng(0), None)


@pytest.mark.parametrize("axis", ["w", "x"])
def test_frames_are_the_balls_slices(axis):
    shape = _ball()
    arrays, record = make_sequence(shape, "hypersphere", check_sequence({"frames": 7, "axis": axis}))
    frames = frames_of(arrays)
    assert len(frames) == 7 and record["empty_frames"] == 0
    t = np.array([f.metadata["time"] for f in frames])
    assert np.all((0 <= t) & (t <= 1)) and np.all(np.diff(t) > 0)
    lo, hi = record["extent"]
    spacing = max(shape.grid["spacing"])
    for f, value in zip(frames, arrays["value"]):
        assert value == pytest.approx(lo + (hi - lo) * f.metadata["time"])
        want = math.sqrt(0.8**2 - value**2)  # the slice of the ball: a 3-ball
        r = np.linalg.norm(f.vertices, axis=1)
        assert np.abs(r - want).max() < spacing
        assert f.is_watertight and f.volume > 0  # closed, outward


@pytest.mark.parametrize("axis", ["w", "y"])
def test_frames_equal_the_meshs_own_slices(axis):
    # the sequence cuts only the simplices a frame's hyperplane can cross: the same triangles,
    # vertices and source simplices as SimplexMesh.slice testing every simplex
    shape = _ball(0.7)
    arrays, _ = make_sequence(shape, "hypersphere", check_sequence({"frames": 5, "axis": axis}))
    k = "xyzw".index(axis)
    normal = np.eye(4)[k]
    for frame, value in zip(frames_of(arrays), arrays["value"]):
        whole = shape.mesh.slice(normal * value, normal)
        np.testing.assert_array_equal(frame.vertices, whole.vertices)
        np.testing.assert_array_equal(frame.faces, whole.faces)


def test_triangles_distance_equals_the_numpy_distance_far_from_the_origin():
    import trimesh

    from datasets_gen.samples import corners_distance
    from datasets_gen.sequence import triangles_distance

    rng = np.random.default_rng(3)
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=24, minor_sections=10)
    for offset in (0.0, 1e5):
        vertices = np.asarray(torus.vertices) + offset
        faces = np.asarray(torus.faces, np.int64)
        points = offset + np.concatenate([rng.uniform(-2, 2, (300, 3)), torus.vertices[:50] * 1.01])
        got = triangles_distance(vertices, faces, points)
        want = corners_distance(vertices[faces], points)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * (1 + offset))


def test_frame_ao():
    shape = _ball()
    occ = shape.mesh.vertices[:, 0].copy()
    arrays, record = make_sequence(shape, "hypersphere", check_sequence(True), occlusion=occ)
    assert record["frames"] == 17 and "frame_samples" not in record and frame_samples_of(arrays) == []
    for f in frames_of(arrays):  # x is linear: interpolated exactly onto the slice's vertices (basis: x, y, z)
        np.testing.assert_allclose(f.vertex_attributes["ao"], f.vertices[:, 0], atol=1e-6)
    assert "ao" not in shape.mesh.point_data  # the values went to the slices as data


FRAMES = 5
SAMPLES = {"uniform": FRAMES * 1500, "near_surface": FRAMES * 100, "sigmas": [0.01, 0.05], "surface": FRAMES * 150}


def _ball_sequence(seed=0, radius=0.8, occlusion=True):
    shape = _ball(radius)
    occ = shape.mesh.vertices[:, 0].copy() if occlusion else None  # AO = x: linear, so exact on every frame
    return shape, *make_sequence(
        shape,
        "hypersphere",
        check_sequence({"frames": FRAMES, "axis": "w"}),
        occlusion=occ,
        samples=check_samples(SAMPLES),
        rng=np.random.default_rng(seed),
    )


def test_frame_samples_of_a_ball_against_its_analytic_slices():
    # frame at w is the 3-ball of radius sqrt(r^2 - w^2); the field (|x| - r) labels occupancy exactly
    radius = 0.8
    shape, arrays, record = _ball_sequence(radius=radius)
    info = record["frame_samples"]
    assert info["uniform"] == 1500 and info["near_surface"] == 100 and info["surface"] == 150
    assert info["labels"] == {
        "occupancy": "field",
        "sdf": "mesh",
        "surface_points": "mesh",
        "surface_normals": "mesh",
        "surface_ao": "mesh",
    }
    np.testing.assert_array_equal(np.diff(arrays["frame_point_offsets"]), 1500 + 2 * 100)
    np.testing.assert_array_equal(np.diff(arrays["frame_surface_offsets"]), 150)
    lo, hi = (np.array(b) for b in info["box"])
    spacing = max(shape.grid["spacing"])
    frames = frame_samples_of(arrays)
    assert len(frames) == FRAMES
    for frame, w in zip(frames, arrays["value"]):
        rho = math.sqrt(radius**2 - w**2)
        y = frame["points"].astype(np.float64)
        norm = np.linalg.norm(y, axis=1)
        uniform = y[:1500]
        assert np.all((uniform >= lo) & (uniform <= hi))
        np.testing.assert_array_equal(frame["occupancy"], norm**2 + w**2 < radius**2)
        # the uniform points' inside fraction x the box's 3-volume: the 3-ball's volume (4 sigma)
        p = frame["occupancy"][:1500].mean()
        box = float(np.prod(hi - lo))
        want = 4 / 3 * math.pi * rho**3
        assert abs(p * box - want) < 4 * box * math.sqrt(want / box * (1 - want / box) / 1500) + 1e-9
        # sdf: negative exactly where occupied; its size the distance to the slice's mesh
        np.testing.assert_array_equal(frame["sdf"] < 0, frame["occupancy"])
        assert np.abs(np.abs(frame["sdf"]) - np.abs(norm - rho)).max() < spacing
        # surface points on the frame's mesh: the 4D field within a cell of the level at (y, w)
        s = frame["surface_points"].astype(np.float64)
        field = shape.field(np.column_stack([s, np.full(len(s), w)]))
        assert np.abs(field).max() < spacing
        n = frame["surface_normals"].astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
        assert (np.einsum("kd,kd->k", n, s / np.linalg.norm(s, axis=1)[:, None]) > 0.5).all()  # outward
        np.testing.assert_allclose(frame["surface_ao"], s[:, 0], atol=1e-5)  # AO = x, linear
        # near-surface points: within a few sigmas of the frame's surface
        near = norm[1500:1600]
        assert np.abs(near - rho).max() < spacing + 5 * 0.01 * info["offset_scale"]


def test_frame_samples_same_seed_same_bytes():
    from ao4d._npz import npz_bytes

    one, two, other = (npz_bytes(_ball_sequence(seed)[1]) for seed in (3, 3, 4))
    assert one == two and one != other


def test_an_empty_frame_has_uniform_points_only():
    import trimesh

    from datasets_gen.sequence import _frame_samples

    shape = _ball()
    w = np.array([0.0, 0.0, 0.0, 1.0])
    slices = [shape.mesh.slice(w * 0.1, w), trimesh.Trimesh(), shape.mesh.slice(w * -0.1, w)]
    origins = w * np.array([0.1, 0.95, -0.1])[:, None]
    samples = check_samples({"uniform": 3 * 50, "near_surface": 3 * 20, "sigmas": [0.01], "surface": 3 * 10})
    basis = np.eye(4)[:3]
    arrays, record = _frame_samples(
        shape, "hypersphere", samples, np.random.default_rng(0), "numpy", slices, basis, origins, False, None
    )
    np.testing.assert_array_equal(arrays["frame_point_offsets"], [0, 70, 120, 190])
    np.testing.assert_array_equal(arrays["frame_surface_offsets"], [0, 10, 10, 20])
    empty = slice(70, 120)
    assert not arrays["frame_occupancy"][empty].any() and np.isposinf(arrays["frame_sdf"][empty]).all()
    assert record["points"] == 190 and record["surface_points"] == 20 and "surface_ao" not in record["labels"]


def test_frame_samples_of_a_lifted_prism():
    # a lifted box prism (mesh labels): frames inside its height are the box, of known volume
    from _datasets import BOX_PRISM

    settings = {**SETTINGS, "grid": 8, "tetrahedra": "star"}
    shape = build_shape("lifted", dict(BOX_PRISM), settings, np.random.default_rng(0), None)
    samples = check_samples({"uniform": 3 * 400, "near_surface": 0, "sigmas": [], "surface": 3 * 50})
    arrays, record = make_sequence(
        shape, "lifted", check_sequence({"frames": 3, "axis": "w"}), samples=samples, rng=np.random.default_rng(1)
    )
    assert record["frame_samples"]["labels"]["occupancy"] == "mesh"
    box_lo, box_hi = (np.asarray(b)[:3] for b in shape.mesh.bounds)
    for frame in frame_samples_of(arrays):
        y = frame["points"].astype(np.float64)
        inside = np.all((y > box_lo) & (y < box_hi), axis=1)
        assert (frame["occupancy"] == inside).mean() > 0.99  # exact but for points on the faces
        np.testing.assert_array_equal(frame["sdf"] < 0, frame["occupancy"])
        s = frame["surface_points"].astype(np.float64)
        on_face = np.minimum(np.abs(s - box_lo), np.abs(s - box_hi)).min(axis=1)
        assert on_face.max() < 1e-5


@pytest.mark.parametrize(
    "value, message",
    [
        ({"frames": 0}, "frames"),
        ({"axis": "t"}, "axis"),
        ({"frames": 3, "speed": 1}, "unknown"),
        ("w", "table"),
    ],
)
def test_bad_sequence_settings(value, message):
    with pytest.raises(ValueError, match=message):
        check_sequence(value)
