"""Tests for ao4d.lift.sweep: frames of a moving 3D solid become the closed, outward 4D boundary
of its space-time solid, whose 4-volume is the exact integral of the frames' volume over time."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from ao4d import lift
from ao4d.cli import main as ao4d_main

# The 4-volume is a sum of a few thousand determinants of O(1) numbers, each exact to ~1e-16
# relative; measured errors are below 1e-13, so 1e-9 leaves ample room and still catches any
# wrong tetrahedron (one of ~5000 is ~1e-4 of the volume).
EXACT = 1e-9


def _ball(subdivisions: int = 1, radius: float = 0.5) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions, radius=radius)


def _moved(mesh: trimesh.Trimesh, matrix=None, offset=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """``mesh`` with vertices ``x @ matrix.T + offset`` (same faces)."""
    matrix = np.eye(3) if matrix is None else np.asarray(matrix)
    return trimesh.Trimesh(np.asarray(mesh.vertices) @ matrix.T + offset, mesh.faces, process=False)


def _rotation(axis, angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]


def _midpoint_volume(p0: np.ndarray, p1: np.ndarray, faces: np.ndarray) -> float:
    """Volume of the sweep's slice halfway between two frames, from the frames alone.

    Derived from the staircase split (independent of ao4d's slicing): for a face with vertex ids
    a < b < c, the three wall tetrahedra cut at half time give the hexagon
    ``M_a, D_ab, M_b, D_bc, M_c, D_ac`` with ``M_v = (p0_v + p1_v) / 2`` and
    ``D_uv = (p0_u + p1_v) / 2`` (u < v): corner triangles at M_a and M_c, and the planar quad
    ``D_ab, M_b, D_bc, D_ac``. Faces whose sorting is an odd permutation are turned around.
    """
    order = np.argsort(faces, axis=1)
    a, b, c = np.take_along_axis(faces, order, axis=1).T
    odd = ((order[:, 0] > order[:, 1]).astype(int) + (order[:, 0] > order[:, 2]) + (order[:, 1] > order[:, 2])) % 2
    m = (p0 + p1) / 2
    ab, bc, ac = (p0[a] + p1[b]) / 2, (p0[b] + p1[c]) / 2, (p0[a] + p1[c]) / 2
    pieces = [(m[a], ab, ac), (ab, m[b], bc), (ab, bc, ac), (ac, bc, m[c])]
    dets = sum(np.einsum("ij,ij->i", x, np.cross(y, z)) for x, y, z in pieces)
    return float(np.sum(np.where(odd == 1, -dets, dets)) / 6.0)


def _simpson_volume(points: list[np.ndarray], faces: np.ndarray, times) -> float:
    """The exact 4-volume: Simpson's rule per interval on the cubic vol(S(t))."""
    vols = [trimesh.Trimesh(p, faces, process=False).volume for p in points]
    total = 0.0
    for k in range(len(points) - 1):
        mid = _midpoint_volume(points[k], points[k + 1], faces)
        total += (times[k + 1] - times[k]) * (vols[k] + 4 * mid + vols[k + 1]) / 6
    return total


def _assert_closed_outward(mesh) -> None:
    report = mesh.check()
    assert report.ok, report
    assert report.n_degenerate == 0 and report.n_components == 1 and report.n_unused_vertices == 0
    assert mesh.volume > 0


# --------------------------------------------------------------------------- exact volumes


@pytest.mark.parametrize("times", [None, [0.0, 0.5, 2.0, 2.25], [-3.0, -2.9, 10.0, 11.0]])
def test_translating_ball_volume_is_volume_times_duration(times):
    ball = _ball(2)
    offsets = [(0, 0, 0), (0.3, 0, 0), (0.3, 0.7, -0.2), (-1.0, 0.1, 0.4)]
    mesh = lift.sweep([_moved(ball, offset=o) for o in offsets], times)
    _assert_closed_outward(mesh)
    t = np.arange(4.0) if times is None else np.asarray(times)
    assert mesh.volume == pytest.approx(ball.volume * (t[-1] - t[0]), rel=EXACT)
    assert np.allclose(mesh.bounds[:, 3], [t[0], t[-1]])
    assert mesh.n_vertices == 4 * len(ball.vertices) + 2  # frames, then the two cap centres


def test_scaling_ball_volume_is_the_integral_of_s_cubed():
    """Uniform scaling s(t) (linear between frames) about a moving centre: each slice is the frame
    scaled, so the 4-volume is vol0 * integral of s^3 = vol0 * sum dt (a^3 + a^2 b + a b^2 + b^3) / 4."""
    ball = _ball(2)
    vol0 = ball.volume  # the polyhedron's volume, not the ideal sphere's
    scales = [1.0, 1.6, 0.4, 0.4, 1.1]
    times = [0.0, 0.3, 1.0, 1.5, 1.7]
    centres = [(0, 0, 0), (0.2, 0, 0), (0.2, -0.5, 0), (0, 0, 1), (0, 0, 1)]
    mesh = lift.sweep([_moved(ball, s * np.eye(3), c) for s, c in zip(scales, centres)], times)
    _assert_closed_outward(mesh)
    exact = vol0 * sum(
        (t1 - t0) * (a**3 + a**2 * b + a * b**2 + b**3) / 4
        for t0, t1, a, b in zip(times, times[1:], scales, scales[1:])
    )
    assert mesh.volume == pytest.approx(exact, rel=EXACT)


def test_rotation_volume_is_simpson_with_the_kinked_midpoint_and_the_slices_agree():
    """A rigid rotation (slices between frames are kinked, not the interpolated mesh): the 4-volume
    equals Simpson's rule with the midpoint volume from the staircase formula, and ao4d's own
    slices at the midpoints have that volume too."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.3))
    frames = [_moved(box, _rotation([0.3, 1, 0.2], a), (0.1 * a, 0, 0)) for a in (0.0, 0.5, 1.2)]
    times = [0.0, 1.0, 1.5]
    mesh = lift.sweep(frames, times)
    _assert_closed_outward(mesh)
    points = [np.asarray(f.vertices) for f in frames]
    exact = _simpson_volume(points, box.faces, times)
    assert mesh.volume == pytest.approx(exact, rel=EXACT)
    # the linearly interpolated mesh is smaller (chords): the kinks are real, not rounding
    interp = trimesh.Trimesh((points[0] + points[1]) / 2, box.faces, process=False).volume
    mid = _midpoint_volume(points[0], points[1], box.faces)
    assert abs(mid - interp) > 1e-3 * box.volume
    for k in range(2):
        cut = mesh.slice([0, 0, 0, (times[k] + times[k + 1]) / 2], [0, 0, 0, 1])
        assert cut.is_watertight
        assert cut.volume == pytest.approx(_midpoint_volume(points[k], points[k + 1], box.faces), rel=EXACT)


def test_slices_at_frame_times_are_the_frames():
    ball = _ball(1)
    scales = [1.0, 1.3, 0.7, 1.0]
    times = [0.0, 0.4, 1.0, 1.6]
    frames = [_moved(ball, np.diag([s, 1 / s, 1.0]), (0, 0.5 * k, 0)) for k, s in enumerate(scales)]
    mesh = lift.sweep(frames, times)
    _assert_closed_outward(mesh)
    for k in range(1, len(frames)):  # at w = times[0] the plane holds the whole first cap
        cut = mesh.slice([0, 0, 0, times[k]], [0, 0, 0, 1])
        frame = frames[k]
        assert cut.is_watertight
        got = np.unique(np.round(cut.vertices, 12), axis=0)
        want = np.unique(np.round(frame.vertices, 12), axis=0)
        assert got.shape == want.shape and np.allclose(got, want, rtol=0, atol=1e-9)
        assert cut.volume == pytest.approx(frame.volume, rel=EXACT)
        assert cut.area == pytest.approx(frame.area, rel=EXACT)
    # just after the start the slice is the first frame, to first order in the step
    eps = 1e-9
    cut = mesh.slice([0, 0, 0, times[0] + eps], [0, 0, 0, 1])
    assert cut.volume == pytest.approx(frames[0].volume, rel=1e-6)


def test_static_frames_give_the_prism():
    ball = _ball(1)
    mesh = lift.sweep([ball, ball, ball], [0.0, 0.5, 2.0])
    prism = lift.prism(ball, 2.0)
    assert mesh.volume == pytest.approx(prism.volume, rel=EXACT)
    assert mesh.measure == pytest.approx(prism.measure, rel=EXACT)


def test_frames_as_pairs_and_files(tmp_path):
    ball = _ball(1)
    frames = [_moved(ball, offset=(0.1 * k, 0, 0)) for k in range(3)]
    for k, frame in enumerate(frames):
        frame.export(tmp_path / f"f{k}.ply")
    from_meshes = lift.sweep(frames)
    from_pairs = lift.sweep([(f.vertices, f.faces) for f in frames])
    from_files = lift.sweep([tmp_path / f"f{k}.ply" for k in range(3)])
    from_generator = lift.sweep(f for f in frames)
    for mesh in (from_pairs, from_files, from_generator):
        assert np.array_equal(mesh.simplices, from_meshes.simplices)
        assert np.allclose(mesh.vertices, from_meshes.vertices, atol=1e-6)  # PLY stores float32


# --------------------------------------------------------------------------- refusals


def test_refuses_frames_that_are_not_one_mesh_moved():
    ball = _ball(1)
    with pytest.raises(ValueError, match=r"`frames\[1\]` has 162 vertices but `frames\[0\]` has 42"):
        lift.sweep([ball, _ball(2)])
    other = trimesh.Trimesh(ball.vertices, ball.faces[:, [1, 2, 0]][::-1], process=False)  # same surface
    with pytest.raises(ValueError, match=r"`frames\[1\]` has other faces than `frames\[0\]`"):
        lift.sweep([ball, other])
    with pytest.raises(ValueError, match="at least 2 frames"):
        lift.sweep([ball])
    with pytest.raises(ValueError, match="at least 2 frames"):
        lift.sweep([])
    with pytest.raises(TypeError, match="`frames` must be a sequence"):
        lift.sweep(ball)
    with pytest.raises(TypeError, match="`frames` must be a sequence"):
        lift.sweep("frame.ply")
    with pytest.raises(TypeError, match=r"`frames\[1\]`"):
        lift.sweep([ball, 3.0])


def test_refuses_open_inverted_and_non_finite_frames(tmp_path):
    ball = _ball(1)
    open_ball = trimesh.Trimesh(ball.vertices, ball.faces[1:], process=False)
    with pytest.raises(ValueError, match=r"`frames\[1\]` is not watertight"):
        lift.sweep([ball, open_ball])
    inverted = ball.copy()
    inverted.invert()
    with pytest.raises(ValueError, match=r"`frames\[0\]` is inside-out"):
        lift.sweep([inverted, ball])
    for bad in (np.nan, np.inf):
        vertices = ball.vertices.copy()
        vertices[3, 1] = bad
        with pytest.raises(ValueError, match=r"`frames\[1\]` contains 1 non-finite"):
            lift.sweep([ball, (vertices, ball.faces)])
        with pytest.raises(ValueError, match=r"`frames\[2\]` contains 1 non-finite"):
            lift.sweep([ball, ball, trimesh.Trimesh(vertices, ball.faces, process=False)])
    with pytest.raises(FileNotFoundError):
        lift.sweep([ball, tmp_path / "missing.ply"])
    (tmp_path / "open.ply").write_bytes(open_ball.export(file_type="ply"))
    with pytest.raises(ValueError, match=r"`frames\[1\]`.*not watertight"):
        lift.sweep([ball, tmp_path / "open.ply"])


@pytest.mark.parametrize(
    "times, match",
    [
        ([0.0, 1.0], "one time per frame \\(3\\), got 2"),
        ([0.0, 1.0, 2.0, 3.0], "one time per frame \\(3\\), got 4"),
        ([0.0, 1.0, 1.0], r"strictly increasing, got times\[1\] = 1 >= times\[2\] = 1"),
        ([0.0, 2.0, 1.0], "strictly increasing"),
        ([0.0, np.nan, 2.0], "`times` contains 1 non-finite"),
        ([0.0, 1.0, np.inf], "`times` contains 1 non-finite"),
        ([[0.0, 1.0, 2.0]], "`times` must be a 1D array"),
    ],
)
def test_refuses_bad_times(times, match):
    ball = _ball(1)
    with pytest.raises(ValueError, match=match):
        lift.sweep([ball, ball, ball], times)


def test_refuses_a_cap_that_is_not_star_shaped():
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=10, minor_sections=6)
    with pytest.raises(ValueError, match=r"`frames\[0\]` is not star-shaped"):
        lift.sweep([torus, _moved(torus, offset=(0.1, 0, 0))])


@pytest.mark.parametrize("angle", [math.radians(95), math.radians(180)])
def test_refuses_a_motion_that_turns_walls_over(angle):
    """A triangle turning by 90 degrees or more between frames: its first and last wall pieces
    face opposite ways, the slice folds over."""
    box = trimesh.creation.box(extents=(1.0, 0.8, 0.6))
    with pytest.raises(ValueError, match=r"`frames`: the motion from frames\[0\] \(t = 0\) to frames\[1\]"):
        lift.sweep([box, _moved(box, _rotation([0, 0, 1], angle))])


def test_refuses_a_wall_folding_although_every_face_keeps_its_side():
    """Both frames are valid and every face's normals in the two frames agree (N_0 . N_1 > 0),
    but face 0 (ids 0 < 1 < 2) shears so that its middle wall piece, spanned by edge 01 of
    frame 0 and edge 12 of frame 1, faces inward: the slice between the frames folds over."""
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    p0 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, -1]])
    p1 = np.array([[0.0, 0, 0], [1, 2, 0], [-1, 1, 0], [0.2, 0.2, -1]])
    for p in (p0, p1):
        assert trimesh.Trimesh(p, faces, process=False).volume > 0
    normal = lambda p: np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])  # noqa: E731
    assert (np.einsum("ij,ij->i", normal(p0), normal(p1)) > 0).all()
    # the middle piece's normal (edge 01 at t0) x (edge 12 at t1) points down, the face's up
    assert np.cross(p0[1] - p0[0], p1[2] - p1[1])[2] < 0
    with pytest.raises(ValueError, match=r"turns 2 wall\(s\) over, e.g. triangle 0"):
        lift.sweep([(p0, faces), (p1, faces)])


def test_wall_test_catches_a_triangle_that_collapses_between_frames():
    """The moving triangle's own normal: vertex 2 passes through vertex 0 halfway, so the area
    normal N(s) vanishes and reverses in between, although it is +z in both frames and every
    wall tetrahedron faces +z (the quadratic's Bernstein test catches it, the pieces' does not)."""
    tris = np.array([[0, 1, 2]])
    p0 = np.array([[0.0, 0, 0], [-1, -1, 0], [1, 0, 0]])
    p1 = np.array([[0.0, 0, 0], [-1, 1, 0], [-1, 0, 0]])
    mid = (p0 + p1) / 2
    assert np.allclose(mid[2], mid[0])  # degenerate at s = 1/2
    with pytest.raises(ValueError, match="turns 1 wall"):
        lift._check_sweep_walls(np.stack([p0, p1]), tris, np.array([0.0, 1.0]))
    lift._check_sweep_walls(np.stack([p0, p0 + 0.3]), tris, np.array([0.0, 1.0]))  # a translation passes


def test_accepts_a_moderate_rotation_between_frames():
    box = trimesh.creation.box(extents=(1.0, 0.8, 0.6))
    angles = np.radians([0, 40, 80, 120])
    frames = [_moved(box, _rotation([0, 0, 1], a)) for a in angles]
    mesh = lift.sweep(frames)
    _assert_closed_outward(mesh)
    assert mesh.volume == pytest.approx(_simpson_volume([f.vertices for f in frames], box.faces, range(4)), rel=EXACT)


# --------------------------------------------------------------------------- property test


def _folds(p0: np.ndarray, p1: np.ndarray, faces: np.ndarray) -> bool:
    """Whether the slice halfway between two frames folds over: one of its flat pieces (the
    hexagon of :func:`_midpoint_volume`) faces against the face's outward normal in a frame."""
    order = np.argsort(faces, axis=1)
    a, b, c = np.take_along_axis(faces, order, axis=1).T
    inversions = (order[:, 0] > order[:, 1]).astype(int) + (order[:, 0] > order[:, 2]) + (order[:, 1] > order[:, 2])
    sign = np.where(inversions % 2 == 1, -1.0, 1.0)
    m = (p0 + p1) / 2
    ab, bc, ac = (p0[a] + p1[b]) / 2, (p0[b] + p1[c]) / 2, (p0[a] + p1[c]) / 2
    pieces = [(m[a], ab, ac), (ab, m[b], bc), (ab, bc, ac), (ac, bc, m[c])]
    for p in (p0, p1):
        n = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
        for x, y, z in pieces:
            if (sign * np.einsum("ij,ij->i", np.cross(y - x, z - x), n) <= 0).any():
                return True
    return False


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 4),
    seed=st.integers(0, 2**32 - 1),
    max_angle=st.floats(0.0, 0.6),
    max_scale=st.floats(0.0, 0.7),
)
def test_random_rigid_motions_and_scalings_are_closed_outward_with_simpson_volume(n, seed, max_angle, max_scale):
    """Rigid motions with uniform scaling. A box's right triangles spinning in their plane by more
    than their smallest angle fold the staircase-cut walls: such steps must be refused (the fold
    found independently, on the midpoint slice's pieces), every other one swept exactly."""
    rng = np.random.default_rng(seed)
    base = trimesh.creation.box(extents=rng.uniform(0.3, 1.5, 3))  # a small closed mesh
    frames, matrix, offset = [], np.eye(3), np.zeros(3)
    for _ in range(n):
        frames.append(_moved(base, matrix, offset))
        step = _rotation(rng.standard_normal(3), rng.uniform(-max_angle, max_angle))
        matrix = math.exp(rng.uniform(-max_scale, max_scale)) * step @ matrix
        offset = offset + rng.uniform(-1, 1, 3)
    times = np.cumsum(rng.uniform(0.1, 2.0, n)) - 1.0
    points = [np.asarray(f.vertices) for f in frames]
    if any(_folds(p0, p1, base.faces) for p0, p1 in zip(points, points[1:])):
        with pytest.raises(ValueError, match="turns .* wall"):
            lift.sweep(frames, times)
        return
    mesh = lift.sweep(frames, times)
    _assert_closed_outward(mesh)
    assert mesh.volume == pytest.approx(_simpson_volume(points, base.faces, times), rel=EXACT)


def test_small_rotation_steps_are_always_swept():
    """Below a box triangle's smallest angle (here atan(0.3 / 1.5) = 11.3 degrees) a rotation step
    never folds a wall: 30 steps of 8 degrees about a skew axis, with scaling, sweep exactly."""
    base = trimesh.creation.box(extents=(0.3, 1.5, 0.9))
    step = 1.02 * _rotation([1.0, -0.4, 0.7], math.radians(8))
    frames = [_moved(base, np.linalg.matrix_power(step, k), (0.05 * k, 0, 0)) for k in range(30)]
    mesh = lift.sweep(frames)
    _assert_closed_outward(mesh)
    exact = _simpson_volume([np.asarray(f.vertices) for f in frames], base.faces, np.arange(30.0))
    assert mesh.volume == pytest.approx(exact, rel=EXACT)


# --------------------------------------------------------------------------- command line


def test_command_line_sweep(tmp_path, capsys):
    ball = _ball(1)
    paths = []
    for k in range(3):
        paths.append(tmp_path / f"frame_{k}.ply")
        _moved(ball, offset=(0, 0.4 * k, 0)).export(paths[-1])
    out = tmp_path / "sweep.npz"
    rc = ao4d_main(["lift", "sweep", *map(str, paths), "--times", "-1", "0", "0.5", "--out", str(out), "--no-progress"])
    assert rc == 0
    assert "sweep: 3 frames" in capsys.readouterr().out
    from ao4d.mesh import SimplexMesh

    mesh = SimplexMesh.load(out)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(ball.volume * 1.5, rel=1e-6)  # PLY stores float32
    assert ao4d_main(["lift", "sweep", *map(str, paths), "--times-range", "0", "2", "--out", str(out)]) == 0
    assert SimplexMesh.load(out).volume == pytest.approx(ball.volume * 2.0, rel=1e-6)
    before = out.read_bytes()
    assert ao4d_main(["lift", "sweep", *map(str, paths), "--times", "0", "2", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "`--times` must be strictly increasing" in err
    assert out.read_bytes() == before  # a refused run leaves the old file
    assert ao4d_main(["lift", "sweep", str(paths[0]), "--out", str(out)]) == 2
    assert "`FRAMES` must hold at least 2 frames" in capsys.readouterr().err
    assert ao4d_main(["lift", "sweep", *map(str, paths), "--out", str(tmp_path / "mesh.png")]) == 2
    with pytest.raises(SystemExit):
        ao4d_main(["lift", "sweep", "--help"])
    assert "ao4d lift sweep ball_*.ply --out bounce.npz" in capsys.readouterr().out


def test_command_line_warns_about_frames_out_of_numeric_order(tmp_path, capsys):
    ball = _ball(1)
    names = ["f10.ply", "f2.ply"]  # as a shell pattern would expand them
    for name in names:
        ball.export(tmp_path / name)
    assert ao4d_main(["lift", "sweep", *(str(tmp_path / n) for n in names), "--out", str(tmp_path / "s.npz")]) == 0
    assert "not in the numeric order" in capsys.readouterr().err


# --------------------------------------------------------------------------- datasets_gen family


def test_sweep_family_item_has_the_exact_volume_and_occupancy(tmp_path):
    """A ball translating along y, frames found by a glob in the numeric order of their names
    (bounce_10 after bounce_7): the 4-volume matches the expected one, and the mesh occupancy
    labels agree with the exact test (x - c(t) inside the convex frame: below every face plane)."""
    from datasets_gen import run

    ball = _ball(1)
    for k in range(4):
        _moved(ball, offset=(0, 0.2 * k, 0)).export(tmp_path / f"bounce_{3 * k + 1}.ply")
    params = {"frames": str(tmp_path / "bounce_*.ply"), "duration": 1.2}
    samples = {"uniform": 400, "near_surface": 0, "sigmas": [], "surface": 0}
    family = {"kind": "sweep", "ao": False, "rotation": "none", "samples": samples, "params": params}
    summary = run({"family": [family], "backend": "numpy"}, tmp_path / "out", progress=False)
    assert summary.made == 1, summary
    item = tmp_path / "out" / "items" / "00000"
    record = json.loads((item / "record.json").read_text())
    assert record["derived"]["frames"] == 4 and record["derived"]["times"] == pytest.approx([-0.6, -0.2, 0.2, 0.6])
    assert record["mesh"]["check"]["ok"] and abs(record["mesh"]["volume_rel_error"]) < 1e-9
    assert record["mesh"]["volume"] == pytest.approx(ball.volume * 1.2, rel=1e-6)  # PLY: float32
    with np.load(item / "samples.npz") as data:
        points, occupancy = data["points"].astype(np.float64), data["occupancy"]
    t = points[:, 3]
    centre = np.column_stack([np.zeros(len(t)), 0.6 * (t + 0.6) / 1.2, np.zeros(len(t))])
    heights = (points[:, :3] - centre) @ ball.face_normals.T - np.einsum(
        "ij,ij->i", ball.triangles[:, 0], ball.face_normals
    )
    inside = (heights < 0).all(axis=1) & (np.abs(t) <= 0.6)
    clear = (np.abs(heights).min(axis=1) > 1e-5) & (np.abs(np.abs(t) - 0.6) > 1e-5)  # off the surface
    assert occupancy.any() and not occupancy.all()
    assert np.array_equal(occupancy[clear], inside[clear])
