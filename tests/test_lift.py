"""Tests for ao4d.lift: prisms, cones and spins of 3D solids are closed, oriented 4D boundaries
whose enclosed 4-volumes match the analytic values."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ao4d import lift

# Star-cut solids keep the input surface exactly, so volumes agree to rounding: the 4-volume is
# a sum of a few hundred determinants of O(1) numbers, each exact to ~1e-16 relative.
EXACT = 1e-11


def _box(lo=(0.0, 0.0, 0.0), hi=(1.0, 2.0, 3.0)) -> trimesh.Trimesh:
    return trimesh.creation.box(bounds=[lo, hi])


def _ball(radius=0.5, centre=(1.0, 0.0, 0.0), subdivisions=2) -> trimesh.Trimesh:
    ball = trimesh.creation.icosphere(subdivisions, radius=radius)
    ball.apply_translation(centre)
    return ball


def _half_ball(radius=1.0) -> trimesh.Trimesh:
    """Half-ball x >= 0 with its flat face on the plane x = 0."""
    t = np.linspace(0.0, np.pi / 2, 9)
    profile = np.vstack([[0.0, 0.0], radius * np.column_stack([np.cos(t), np.sin(t)])])
    half = trimesh.creation.revolve(profile, sections=16)  # flat face on z = 0, dome in z > 0
    half.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    half.vertices[np.abs(half.vertices[:, 0]) < 1e-12, 0] = 0.0  # rotation leaves ~6e-17
    return half


def _first_moment_x(surface: trimesh.Trimesh) -> float:
    """Integral of x over the solid, from trimesh's mass properties (independent of lift)."""
    return float(surface.volume * surface.center_mass[0])


def _polygon_factor(k: int) -> float:
    return k * math.sin(2 * math.pi / k) / (2 * math.pi)


# --------------------------------------------------------------------------- tetrahedralize


def test_star_cut_keeps_surface_and_volume():
    box = _box()
    solid = lift.tetrahedralize(box, method="star")
    assert solid.tets.shape == (12, 4)  # one tetrahedron per face
    assert solid.volume == pytest.approx(box.volume, rel=EXACT)
    assert np.allclose(solid.centroid, box.center_mass, atol=1e-12)
    boundary = trimesh.Trimesh(solid.points, solid.boundary, process=False)
    assert boundary.is_watertight and boundary.volume == pytest.approx(box.volume, rel=EXACT)


def test_star_cut_refuses_a_solid_not_star_shaped():
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=12, minor_sections=6)
    with pytest.raises(ValueError, match="not star-shaped"):
        lift.tetrahedralize(torus, method="star")


def test_tetwild_cut_of_a_torus():
    torus = trimesh.creation.torus(1.0, 0.4, major_sections=12, minor_sections=8)
    solid = lift.tetrahedralize(torus, method="auto", edge_length=0.3)  # auto falls back
    assert solid.points.shape[0] != len(torus.vertices) + 1  # not a star cut (no centre added)
    boundary = trimesh.Trimesh(solid.points, solid.boundary, process=False)
    assert boundary.is_watertight
    # fTetWild keeps its surface within eps = 1e-3 of the bounding-box diagonal, so the volume
    # may move by at most about eps * diagonal * area.
    diag = float(np.linalg.norm(np.ptp(torus.vertices, axis=0)))
    assert abs(solid.volume - torus.volume) <= 1e-3 * diag * torus.area
    mesh = lift.prism(solid, 0.5)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(solid.volume * 0.5, rel=EXACT)


def test_tetsolid_orients_negative_tets_and_refuses_flat_ones():
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    solid = lift.TetSolid.from_arrays(points, [[0, 2, 1, 3]])  # negative input
    assert solid.volume == pytest.approx(1 / 6, rel=EXACT)
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    with pytest.raises(ValueError, match="flat"):
        lift.TetSolid.from_arrays(flat, [[0, 1, 2, 3]])
    with pytest.raises(ValueError, match="`tets` indices"):
        lift.TetSolid.from_arrays(points, [[0, 1, 2, 4]])
    with pytest.raises(TypeError, match="`tets` must hold integer"):
        lift.TetSolid.from_arrays(points, [[0.0, 1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="`points` must have shape"):
        lift.TetSolid.from_arrays(points[:, :2], [[0, 1, 2, 3]])


# --------------------------------------------------------------------------- prism and cone


@pytest.mark.parametrize("height, base", [(1.0, 0.0), (0.25, -3.0), (7.5, 2.0)])
def test_prism_of_box_is_closed_with_volume_v3_times_h(height, base):
    box = _box()
    mesh = lift.prism(box, height, base=base)
    report = mesh.check()
    assert report.ok and report.n_degenerate == 0 and report.n_components == 1
    assert mesh.volume == pytest.approx(box.volume * height, rel=EXACT)
    assert np.allclose(mesh.bounds[:, 3], [base, base + height])
    # boundary 3-measure: two caps plus walls (surface area x height)
    assert mesh.measure == pytest.approx(2 * box.volume + box.area * height, rel=EXACT)


def test_prism_slice_is_the_input_solid():
    ball = _ball(centre=(0, 0, 0))
    mesh = lift.prism(ball, 2.0)
    cut = mesh.slice([0, 0, 0, 1.0], [0, 0, 0, 1.0])
    # slicing the walls at mid height reproduces the 3D surface: same volume as trimesh's
    assert cut.is_watertight
    assert abs(cut.volume) == pytest.approx(ball.volume, rel=EXACT)


@pytest.mark.parametrize("apex", [None, (5.0, -1.0, 2.0)])
def test_cone_volume_is_v3_times_h_over_4(apex):
    ball = _ball(subdivisions=1)
    mesh = lift.cone(ball, 3.0, apex=apex)
    assert mesh.check().ok
    # a pyramid's volume does not depend on where the apex sits at that height (shear)
    assert mesh.volume == pytest.approx(ball.volume * 3.0 / 4.0, rel=EXACT)
    top = mesh.vertices[np.argmax(mesh.vertices[:, 3])]
    expected = ball.center_mass if apex is None else apex
    assert np.allclose(top, [*expected, 3.0])


@settings(max_examples=25, deadline=None)
@given(
    extents=st.tuples(*[st.floats(0.05, 10.0)] * 3),
    shift=st.tuples(*[st.floats(-50.0, 50.0)] * 3),
    height=st.floats(0.01, 20.0),
    kind=st.sampled_from(["prism", "cone"]),
)
def test_lifted_boxes_are_closed_with_exact_volume(extents, shift, height, kind):
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(shift)
    mesh = getattr(lift, kind)(box, height)
    assert mesh.check().ok
    factor = 1.0 if kind == "prism" else 0.25
    assert mesh.volume == pytest.approx(box.volume * height * factor, rel=1e-9)


# --------------------------------------------------------------------------- spin


@pytest.mark.parametrize("k", [3, 4, 7, 32])
def test_spin_volume_is_polygon_factor_times_pappus(k):
    ball = _ball(radius=0.5, centre=(1.2, 0.3, -0.4))
    mesh = lift.spin(ball, k)
    report = mesh.check()
    assert report.ok and report.n_degenerate == 0
    pappus = 2 * math.pi * _first_moment_x(ball)
    # exact for piecewise-linear surfaces, see lift.spin's docstring
    assert mesh.volume == pytest.approx(_polygon_factor(k) * pappus, rel=EXACT)


def test_spin_converges_to_the_torisphere_volume():
    # spinning a ball of radius r centred at x = R gives the torisphere, volume 2 pi^2 R r^3
    r, big_r, k = 0.4, 1.5, 128
    ball = _ball(radius=r, centre=(big_r, 0, 0), subdivisions=3)
    mesh = lift.spin(ball, k)
    analytic = 2 * math.pi * big_r * (4 / 3) * math.pi * r**3
    # icosphere(3) holds 0.86 % less than the ball; the 128-gon loses (2 pi/k)^2/6 = 0.04 %
    assert mesh.volume / analytic - 1 == pytest.approx(-0.0086 - 0.0004, abs=3e-4)


def test_spin_of_a_tet_solid_uses_its_boundary():
    box = _box(lo=(0.5, -1.0, -1.0), hi=(1.5, 1.0, 1.0))
    solid = lift.tetrahedralize(box, method="star")  # adds an interior centre point
    a, b = lift.spin(box, 9), lift.spin(solid, 9)
    assert b.check().ok
    assert len(b.vertices) == len(a.vertices)  # the centre is not on the boundary: not swept
    assert b.volume == pytest.approx(a.volume, rel=EXACT)


def test_spin_of_box_resting_on_axis():
    box = _box(lo=(0.0, -1.0, -1.0), hi=(1.0, 1.0, 1.0))
    k = 16
    mesh = lift.spin(box, k)
    assert mesh.check().ok
    # disk of radius 1 (as a 16-gon) x square of side 2: 4 * (k/2) sin(2 pi/k)
    assert mesh.volume == pytest.approx(4 * k / 2 * math.sin(2 * math.pi / k), rel=EXACT)
    # the face on x = 0 is not swept: its 4 corners are shared, not copied per angle
    assert len(mesh.vertices) == 4 + k * 4


def test_spin_of_half_ball_is_a_4_ball():
    half = _half_ball()
    k = 24
    mesh = lift.spin(half, k)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(_polygon_factor(k) * 2 * math.pi * _first_moment_x(half), rel=EXACT)
    # and that approaches the unit 4-ball, pi^2/2, up to the coarse profile and the 24-gon
    assert mesh.volume == pytest.approx(math.pi**2 / 2, rel=0.05)


@settings(max_examples=20, deadline=None)
@given(
    k=st.integers(3, 40),
    offset=st.floats(0.51, 20.0),
    radius=st.floats(0.01, 0.5),
    seed=st.integers(0, 2**32 - 1),
)
def test_spin_of_rotated_tetrahedron(k, offset, radius, seed):
    rng = np.random.default_rng(seed)
    # a random tetrahedron inside the ball of `radius` around (offset, 0, 0): stays in x > 0
    pts = rng.normal(size=(4, 3))
    pts = radius * pts / np.linalg.norm(pts, axis=1, keepdims=True) + [offset, 0, 0]
    hull = trimesh.convex.convex_hull(pts)
    assume(hull.volume > 1e-3 * radius**3)  # nearly flat draws are refused as flat solids
    mesh = lift.spin(hull, k)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(_polygon_factor(k) * 2 * math.pi * _first_moment_x(hull), rel=1e-9)


# --------------------------------------------------------------------------- errors


def test_non_watertight_input_is_refused():
    box = _box()
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    for func in (lift.prism, lift.cone, lift.spin, lift.tetrahedralize):
        with pytest.raises(ValueError, match="not watertight"):
            func(open_box)


def test_inside_out_and_badly_wound_inputs_are_refused():
    box = _box()
    inverted = box.copy()
    inverted.invert()
    with pytest.raises(ValueError, match="inside-out"):
        lift.prism(inverted)
    faces = box.faces.copy()
    faces[0] = faces[0, ::-1]
    with pytest.raises(ValueError, match="inconsistent face winding"):
        lift.cone(trimesh.Trimesh(box.vertices, faces, process=False))
    with pytest.raises(TypeError, match="`solid` must be a trimesh.Trimesh"):
        lift.prism(np.zeros((4, 3)))


@pytest.mark.parametrize(
    "func, kwargs, match",
    [
        (lift.prism, {"height": 0.0}, "`height` must be > 0"),
        (lift.prism, {"height": float("nan")}, "`height` must be finite"),
        (lift.cone, {"height": -1.0}, "`height` must be > 0"),
        (lift.cone, {"apex": (0.0, 1.0)}, "`apex` must have shape"),
        (lift.prism, {"base": "low"}, "`base` must be a real number"),
        (lift.tetrahedralize, {"method": "delaunay"}, "`method` must be one of"),
        (lift.tetrahedralize, {"method": "tetwild", "edge_length": 0.0}, "`edge_length` must be in"),
    ],
)
def test_bad_options_are_refused(func, kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        func(_box(), **kwargs)


def test_spin_refusals():
    with pytest.raises(ValueError, match="`k` must be >= 3"):
        lift.spin(_ball(), 2)
    with pytest.raises(ValueError, match="half-space x >= 0"):
        lift.spin(_ball(centre=(0.2, 0, 0)))
    # a box standing on one edge on the plane x = 0: edge contact would pinch
    box = _box(lo=(0, 0, 0), hi=(1, 1, 1))
    box.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, [0, 0, 1]))
    box.apply_translation([-box.vertices[:, 0].min(), 0, 0])
    box.vertices[np.abs(box.vertices[:, 0]) < 1e-12, 0] = 0.0
    with pytest.raises(ValueError, match="isolated points|along edges"):
        lift.spin(box)
    # a tetrahedron touching x = 0 with one vertex
    tet = trimesh.convex.convex_hull([[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 0, 1.0]])
    with pytest.raises(ValueError, match="isolated points"):
        lift.spin(tet)


# --------------------------------------------------------------------------- files


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj"])
def test_load_surface_from_file(tmp_path, suffix):
    ball = _ball(centre=(0.0, 0.0, 0.0), subdivisions=1)
    path = tmp_path / f"ball{suffix}"
    ball.export(path)
    surface = lift.load_surface(path)
    assert surface.volume == pytest.approx(ball.volume, rel=1e-6)  # files keep ~7 digits
    mesh = lift.prism(surface, 1.5)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(surface.volume * 1.5, rel=EXACT)


def test_load_surface_turns_inside_out_files_around(tmp_path):
    box = _box()
    box.invert()
    box.export(tmp_path / "inv.ply")
    assert lift.load_surface(tmp_path / "inv.ply").volume == pytest.approx(6.0, rel=EXACT)


def test_load_surface_refuses_open_or_missing_files(tmp_path):
    box = _box()
    trimesh.Trimesh(box.vertices, box.faces[:-2]).export(tmp_path / "open.stl")
    with pytest.raises(ValueError, match="not watertight"):
        lift.load_surface(tmp_path / "open.stl")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        lift.load_surface(tmp_path / "none.stl")
    (tmp_path / "junk.stl").write_bytes(b"not a mesh at all")
    with pytest.raises(ValueError, match="junk.stl"):
        lift.load_surface(tmp_path / "junk.stl")


def test_tetwild_leaves_the_working_directory_clean(tmp_path, monkeypatch):
    # fTetWild writes __tracked_surface.stl into the cwd; ao4d must not litter the user's folder
    monkeypatch.chdir(tmp_path)
    lift.tetrahedralize(trimesh.creation.box(extents=(1, 1, 1)), method="tetwild", edge_length=0.5)
    assert list(tmp_path.iterdir()) == []


def test_boundary_is_the_faces_of_one_tet_outward():
    """TetSolid.boundary (the grouping of ao4d.topology): on a Kuhn-split 2x2x2 block of cubes
    the triangles used by one tetrahedron (counted by brute force), oriented outwards."""
    import itertools

    idx = np.arange(27).reshape(3, 3, 3)
    points = np.stack(np.meshgrid(*[np.arange(3.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    tets = []
    for corner in itertools.product(range(2), repeat=3):
        for order in itertools.permutations(range(3)):
            c = list(corner)
            path = [idx[tuple(c)]]
            for axis in order:
                c[axis] += 1
                path.append(idx[tuple(c)])
            tets.append(path)
    solid = lift.TetSolid.from_arrays(points, np.array(tets))
    uses: dict[tuple, int] = {}
    for tet in solid.tets.tolist():
        for k in range(4):
            key = tuple(sorted(tet[:k] + tet[k + 1 :]))
            uses[key] = uses.get(key, 0) + 1
    once = {face for face, n in uses.items() if n == 1}
    assert len(once) == 48 and sorted(tuple(sorted(f)) for f in solid.boundary.tolist()) == sorted(once)
    surface = trimesh.Trimesh(solid.points, solid.boundary, process=False)
    assert surface.is_watertight and surface.volume == pytest.approx(8.0, rel=1e-12)


@pytest.mark.parametrize("form", ["simplex_mesh", "pair"])
def test_a_simplex_mesh_and_a_pair_lift_as_the_trimesh_does(form):
    import ao4d

    box = _box()
    given_as = {
        "simplex_mesh": ao4d.SimplexMesh.from_trimesh(box),
        "pair": (np.asarray(box.vertices), np.asarray(box.faces)),
    }[form]
    want, got = lift.tetrahedralize(box), lift.tetrahedralize(given_as)
    np.testing.assert_array_equal(got.points, want.points)
    np.testing.assert_array_equal(got.tets, want.tets)
    for func in (lift.prism, lift.cone, lambda s: lift.spin(s, 8)):
        a, b = func(box), func(given_as)
        np.testing.assert_array_equal(b.vertices, a.vertices)
        np.testing.assert_array_equal(b.simplices, a.simplices)


def test_a_wrong_surface_type_is_a_type_error_naming_it():
    for call, name in (
        (lift.tetrahedralize, "surface"),
        (lift.prism, "solid"),
        (lift.cone, "solid"),
        (lift.spin, "surface"),
    ):
        with pytest.raises(TypeError, match=f"`{name}` must be a trimesh.Trimesh, a 3D SimplexMesh, a .*got str"):
            call("box.stl")
    square = ([[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 1], [1, 2], [2, 3], [3, 0]])
    with pytest.raises(ValueError, match="`surface` must be a 3D triangle mesh, got dimension 2"):
        lift.tetrahedralize(square)
    opened = (np.asarray(_box().vertices), np.asarray(_box().faces)[1:])
    with pytest.raises(ValueError, match="`solid` is not watertight"):
        lift.prism(opened)
