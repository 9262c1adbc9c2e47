"""Tests for datasets_gen.sequence: the frames of a 4D ball against its analytic slices."""

from __future__ import annotations

import math

import numpy as np
import pytest

from datasets_gen.families import build_shape
from datasets_gen.samples import check_samples
from datasets_gen.sequence import check_sequence, frames_of, make_sequence

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


def test_frame_ao_and_frame_samples():
    shape = _ball()
    occ = shape.mesh.vertices[:, 0].copy()
    samples = check_samples({"uniform": 700, "near_surface": 0, "sigmas": [], "surface": 0})
    arrays, record = make_sequence(
        shape, "hypersphere", check_sequence(True), occlusion=occ, samples=samples, rng=np.random.default_rng(0)
    )
    assert record["frames"] == 17 and record["frame_samples"] == 700 // 17
    frames = frames_of(arrays)
    for f in frames:  # x is linear: interpolated exactly onto the slice's vertices (basis: x, y, z)
        np.testing.assert_allclose(f.vertex_attributes["ao"], f.vertices[:, 0], atol=1e-6)
    per = record["frame_samples"]
    y = arrays["frame_points"].astype(np.float64).reshape(17, per, 3)
    inside = (np.linalg.norm(y, axis=2) ** 2 + arrays["value"][:, None] ** 2) < 0.8**2
    np.testing.assert_array_equal(arrays["frame_occupancy"].reshape(17, per), inside)


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
