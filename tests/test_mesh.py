"""Tests for ao4d.mesh: SimplexMesh (measures, normals, caching, transforms) and concatenate.

Reference shapes (tests/_shapes.py) are built independently of ao4d: convex polytopes from
scipy's ConvexHull (qhull), oriented with ``numpy.linalg.det`` straight from the DESIGN.md
definition, and 3D meshes from trimesh.
"""

from __future__ import annotations

import itertools
import math
import pickle

import numpy as np
import pytest
from _shapes import ball_polytope, orient_outward, simplex_boundary, tesseract_boundary
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial import ConvexHull

from ao4d.mesh import SimplexMesh, concatenate

DIMS = (2, 3, 4)


# --------------------------------------------------------------------------------------------
# exact measures and volumes
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", DIMS)
def test_simplex_boundary_exact(d):
    mesh = simplex_boundary(d)
    # d facets in the coordinate hyperplanes, each a standard (d-1)-simplex of measure
    # 1/(d-1)!, and the slanted facet conv(e_1..e_d), sqrt(d) times larger.
    assert mesh.measure == pytest.approx((d + math.sqrt(d)) / math.factorial(d - 1), rel=1e-14)
    assert mesh.volume == pytest.approx(1.0 / math.factorial(d), rel=1e-14)
    assert mesh.check().ok


def test_tesseract_exact():
    half = 1.5
    mesh = tesseract_boundary(half)
    side = 2 * half
    assert mesh.volume == pytest.approx(side**4, rel=1e-14)
    assert mesh.measure == pytest.approx(8 * side**3, rel=1e-14)
    report = mesh.check()
    assert report.ok and report.n_simplices == 48 and report.n_faces == 96  # 48 * 4 / 2
    # each facet normal is +-e_k: unit normals are signed axis vectors pointing outward
    normals = mesh.simplex_normals
    assert np.allclose(np.abs(normals).max(axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", normals, mesh.simplex_centroids) > 0)


def test_tesseract_matches_qhull_volume():
    # the same polytope from qhull's triangulation (different tetrahedra): same volume/measure
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=4)))
    hull = ConvexHull(corners)
    mesh = SimplexMesh(corners, orient_outward(corners, hull.simplices, np.zeros(4)))
    assert mesh.volume == pytest.approx(hull.volume, rel=1e-12)
    assert mesh.measure == pytest.approx(hull.area, rel=1e-12)
    assert mesh.volume == pytest.approx(16.0, rel=1e-12)


@pytest.mark.parametrize("d", DIMS)
def test_matches_qhull_on_random_hull(d):
    rng = np.random.default_rng(1 + d)
    p = rng.normal(size=(60, d))
    hull = ConvexHull(p)
    mesh = SimplexMesh(p, orient_outward(p, hull.simplices, p[hull.vertices].mean(axis=0)))
    # qhull sums the same simplices: agreement to round-off
    assert mesh.volume == pytest.approx(hull.volume, rel=1e-12)
    assert mesh.measure == pytest.approx(hull.area, rel=1e-12)
    assert mesh.check().ok


def test_ball4_converges_to_pi2_over_2():
    """Inscribed polytopes of the 4-ball: volume and boundary converge like h^2.

    The cube-sphere points have spacing h ~ 1/n, and an inscribed polytope misses the ball by
    O(h^2) (chord sagitta), so the relative error e(n) ~ C / n^2: e(4)/e(8) ~ 4, and the
    Richardson extrapolation (4 V(8) - V(4)) / 3 cancels the h^2 term (measured: 0.3% off).
    """
    r = 1.3
    coarse, fine = ball_polytope(4, 4, r), ball_polytope(4, 8, r)
    exact_v, exact_m = math.pi**2 / 2 * r**4, 2 * math.pi**2 * r**3
    for mesh in (coarse, fine):  # inscribed in a convex body: strictly smaller
        assert 0 < mesh.volume < exact_v and 0 < mesh.measure < exact_m
    ev = [1 - m.volume / exact_v for m in (coarse, fine)]
    em = [1 - m.measure / exact_m for m in (coarse, fine)]
    assert 3.0 < ev[0] / ev[1] < 5.0 and 3.0 < em[0] / em[1] < 5.0
    assert (4 * fine.volume - coarse.volume) / 3 == pytest.approx(exact_v, rel=0.01)
    assert (4 * fine.measure - coarse.measure) / 3 == pytest.approx(exact_m, rel=0.01)


@pytest.mark.slow
def test_ball4_fine_polytope():
    # n = 24: e(n) ~ 1.98 / n^2 = 0.34% (constant measured at n = 8, 12)
    mesh = ball_polytope(4, 24)
    assert mesh.check().ok
    assert mesh.volume == pytest.approx(math.pi**2 / 2, rel=0.005)
    assert mesh.measure == pytest.approx(2 * math.pi**2, rel=0.005)


@pytest.mark.parametrize("d", DIMS)
def test_vertex_normals_of_ball_are_radial(d):
    # on a polytope inscribed in a sphere, the measure-weighted vertex normal tends to the
    # radial direction; at n = 8 the facets span ~15 degrees, and the near-symmetric fans keep
    # the deviation well below that (measured max: 1.1, 2.1, 3.0 degrees in 2D, 3D, 4D)
    mesh = ball_polytope(d, 8)
    cosines = np.einsum("ij,ij->i", mesh.vertex_normals, mesh.vertices)
    assert cosines.min() > math.cos(math.radians(5))
    assert np.allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0)


# --------------------------------------------------------------------------------------------
# 3D cross-check with trimesh
# --------------------------------------------------------------------------------------------


def _trimesh_shapes():
    trimesh = pytest.importorskip("trimesh")
    cylinder = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=16)
    side = np.abs(cylinder.face_normals[:, 2]) < 0.5  # drop the two caps: a tube with two rims
    return {
        "icosphere": trimesh.creation.icosphere(subdivisions=2, radius=1.7),
        "box": trimesh.creation.box(extents=(1.0, 2.0, 3.0)),
        "torus": trimesh.creation.torus(2.0, 0.5, major_sections=24, minor_sections=12),
        "open_cylinder": trimesh.Trimesh(cylinder.vertices, cylinder.faces[side], process=False),
    }


@pytest.mark.parametrize("name", ["icosphere", "box", "torus", "open_cylinder"])
def test_3d_matches_trimesh(name):
    import trimesh

    tm = _trimesh_shapes()[name]
    mesh = SimplexMesh.from_trimesh(tm)
    assert mesh.measure == pytest.approx(tm.area, rel=1e-12)
    assert np.allclose(mesh.simplex_measures, tm.area_faces, rtol=1e-12, atol=0)
    assert np.allclose(mesh.simplex_normals, tm.face_normals, atol=1e-12)
    # trimesh's own vertex_normals are angle-weighted: compare with its area-weighted mean
    area_weighted = trimesh.geometry.mean_vertex_normals(
        len(tm.vertices), tm.faces, tm.face_normals * tm.area_faces[:, None]
    )
    length = np.linalg.norm(area_weighted, axis=1, keepdims=True)
    # unused vertices (the open cylinder's cap centres) must get zero normals
    area_weighted = np.divide(area_weighted, length, out=np.zeros_like(area_weighted), where=length > 0)
    assert np.allclose(mesh.vertex_normals, area_weighted, atol=1e-12)
    report = mesh.check()
    assert report.closed == tm.is_watertight
    assert report.oriented == tm.is_winding_consistent
    # (trimesh's body_count would also count unused vertices as bodies; split() does not)
    assert report.n_components == len(tm.split(only_watertight=False))
    if tm.is_watertight:
        assert mesh.volume == pytest.approx(tm.volume, rel=1e-12)
        assert report.ok
    else:
        assert report.n_boundary_faces == 32  # two rims of 16 edges
        assert report.n_unused_vertices == 2 and np.all(mesh.vertex_normals[length[:, 0] == 0] == 0)


def test_to_trimesh_round_trip():
    tm = _trimesh_shapes()["torus"]
    back = SimplexMesh.from_trimesh(tm).to_trimesh()
    assert np.array_equal(back.faces, tm.faces) and np.array_equal(back.vertices, tm.vertices)
    with pytest.raises(ValueError, match="`to_trimesh` needs a 3D mesh"):
        simplex_boundary(4).to_trimesh()


# --------------------------------------------------------------------------------------------
# check(): each defect detected and counted
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# components, split, concatenate
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", DIMS)
def test_concatenate_components_split(d):
    base = ball_polytope(d, 2)
    base.point_data["radius"] = np.linalg.norm(base.vertices, axis=1)
    base.cell_data["area"] = base.simplex_measures.copy()
    parts = [base, base.transformed(2 * np.eye(d), 5.0), base.transformed(np.eye(d), -5.0)]
    both = concatenate(parts)
    assert both.volume == pytest.approx(sum(p.volume for p in parts), rel=1e-12)
    assert both.volume == pytest.approx((2 + 2**d) * base.volume, rel=1e-12)
    ids = both.cell_data["object_id"]
    assert np.array_equal(ids, np.repeat([0, 1, 2], base.n_simplices))
    assert np.array_equal(both.point_data["radius"][: base.n_vertices], base.point_data["radius"])
    labels = both.components()
    assert both.check().n_components == 3
    # labels are a relabelling of object ids
    assert len(set(zip(labels.tolist(), ids.tolist()))) == 3
    pieces = both.split()
    assert [p.n_simplices for p in pieces] == [base.n_simplices] * 3
    assert sorted(p.volume for p in pieces) == pytest.approx(sorted(p.volume for p in parts), rel=1e-12)
    assert np.allclose(pieces[0].point_data["radius"], base.point_data["radius"])


@settings(max_examples=25, deadline=None)
@given(
    scales=st.lists(st.floats(0.1, 10), min_size=1, max_size=4),
    shift=st.floats(-50, 50),
    d=st.sampled_from(DIMS),
)
def test_concatenate_sums_volumes(scales, shift, d):
    base = simplex_boundary(d)
    parts = [base.transformed(s * np.eye(d), shift + 3 * i) for i, s in enumerate(scales)]
    both = concatenate(parts)
    assert both.volume == pytest.approx(sum(s**d for s in scales) / math.factorial(d), rel=1e-9)
    assert both.measure == pytest.approx(sum(p.measure for p in parts), rel=1e-12)
    assert both.n_simplices == sum(p.n_simplices for p in parts)


def test_concatenate_errors():
    a, b = simplex_boundary(3), simplex_boundary(4)
    with pytest.raises(ValueError, match="at least one"):
        concatenate([])
    with pytest.raises(ValueError, match="same dimension"):
        concatenate([a, b])
    with pytest.raises(TypeError, match=r"`meshes\[1\]` must be a SimplexMesh"):
        concatenate([a, "mesh"])
    c = a.copy()
    c.point_data["ao"] = np.zeros(c.n_vertices)
    with pytest.raises(ValueError, match="same point_data names"):
        concatenate([a, c])


# --------------------------------------------------------------------------------------------
# as_mesh / as_meshes: every form of a mesh a function takes
# --------------------------------------------------------------------------------------------


def test_as_mesh_takes_a_mesh_a_trimesh_a_pair_and_a_plain_object():
    from ao4d.mesh import as_mesh

    mesh = simplex_boundary(3)
    assert as_mesh(mesh) is mesh  # as it is: its cache stays
    tm = _trimesh_shapes()["icosphere"]
    from_tm = as_mesh(tm)
    np.testing.assert_array_equal(from_tm.vertices, tm.vertices)
    np.testing.assert_array_equal(from_tm.simplices, tm.faces)
    assert from_tm.volume == pytest.approx(tm.volume, rel=1e-12)  # trimesh's winding is ours
    for pair in ((mesh.vertices, mesh.simplices), [mesh.vertices.tolist(), mesh.simplices.tolist()]):
        got = as_mesh(pair)
        np.testing.assert_array_equal(got.vertices, mesh.vertices)
        np.testing.assert_array_equal(got.simplices, mesh.simplices)

    class Plain:
        vertices, simplices = mesh.vertices, mesh.simplices

    np.testing.assert_array_equal(as_mesh(Plain()).simplices, mesh.simplices)
    from ao4d.mesh import as_meshes

    assert [m.n_simplices for m in as_meshes(Plain())] == [mesh.n_simplices]


def test_as_meshes_reads_pairs_while_trimesh_is_half_imported(monkeypatch):
    # another thread importing trimesh leaves a module without `Trimesh` in sys.modules for a
    # while; a pair or a mesh must not be taken for (or fail on) a Trimesh then
    import sys
    import types

    from ao4d.mesh import as_meshes

    mesh = simplex_boundary(3)
    monkeypatch.setitem(sys.modules, "trimesh", types.ModuleType("trimesh"))
    got = as_meshes([(mesh.vertices, mesh.simplices), mesh])
    assert [m.n_simplices for m in got] == [mesh.n_simplices] * 2


def test_as_mesh_takes_a_subclass_of_trimesh():
    import trimesh

    class Tagged(trimesh.Trimesh):
        pass

    from ao4d.mesh import as_mesh

    tm = _trimesh_shapes()["icosphere"]
    got = as_mesh(Tagged(vertices=tm.vertices, faces=tm.faces, process=False))
    np.testing.assert_array_equal(got.simplices, tm.faces)


@pytest.mark.parametrize(
    ("value", "error", "match"),
    [
        (
            np.zeros((3, 3)),
            TypeError,
            r"`solid` must be a SimplexMesh, a trimesh.Trimesh, a \(vertices, simplices\) "
            r"pair.*got ndarray",
        ),
        ("mesh.npz", TypeError, "`solid` must be a SimplexMesh.*got str"),
        (([[0, 0], [1, 0]], [[0, 5]]), ValueError, r"`solid` holds no valid mesh: `simplices` holds 1 vertex index"),
        (([[0, 0], [1, 0]], [[0.5, 1]]), TypeError, "`solid` holds no valid mesh: `simplices` must hold integer"),
        (([0, 1], [[0, 1]]), TypeError, "`solid` must be"),  # a 1D first entry is no vertex array
        ((np.eye(3), np.eye(3, dtype=int), 1), TypeError, "`solid` must be"),
    ],
)
def test_as_mesh_bad_input_names_the_parameter(value, error, match):
    from ao4d.mesh import as_mesh

    with pytest.raises(error, match=match):
        as_mesh(value, "solid")


def test_as_meshes_one_or_many_in_any_form():
    from ao4d.mesh import as_meshes

    a, b = simplex_boundary(3), simplex_boundary(3).transformed(np.eye(3), 2.0)
    assert as_meshes(a) == [a]
    assert as_meshes([a, b]) == [a, b] and as_meshes((a, b)) == [a, b]  # two meshes, not a pair
    pairs = [(a.vertices, a.simplices), (b.vertices, b.simplices)]
    got = as_meshes(pairs)  # a list of two pairs, not a pair
    assert [m.n_vertices for m in got] == [4, 4] and np.array_equal(got[1].vertices, b.vertices)
    square = ([[0, 0], [0, 1], [1, 1], [1, 0]], [[0, 1], [1, 2], [2, 3], [3, 0]])
    assert len(as_meshes(square)) == 1 and as_meshes(square)[0].volume == pytest.approx(1.0)
    assert len(as_meshes([_trimesh_shapes()["box"], a])) == 2
    with pytest.raises(TypeError, match=r"`scene\[1\]` must be a SimplexMesh"):
        as_meshes([a, 3], "scene")
    with pytest.raises(TypeError, match="`scene` must be a SimplexMesh.*or a sequence of them, got int"):
        as_meshes(3, "scene")
    with pytest.raises(ValueError, match="`scene` must contain at least one mesh"):
        as_meshes([], "scene")


def test_concatenate_takes_pairs_and_trimeshes():
    a = simplex_boundary(3)
    tm = _trimesh_shapes()["box"]
    both = concatenate([(a.vertices, a.simplices), tm])
    assert both.volume == pytest.approx(a.volume + tm.volume, rel=1e-12)
    assert np.array_equal(np.bincount(both.cell_data["object_id"]), [4, len(tm.faces)])


def test_submesh_errors():
    mesh = simplex_boundary(3)
    with pytest.raises(ValueError, match="`which` mask must have length 4"):
        mesh.submesh(np.ones(3, dtype=bool))
    with pytest.raises(IndexError, match="outside"):
        mesh.submesh([7])
    with pytest.raises(TypeError, match="boolean mask or integer"):
        mesh.submesh([0.5])


# --------------------------------------------------------------------------------------------
# property tests: rigid motions, reflections, scaling, reversal
# --------------------------------------------------------------------------------------------


def _orthogonal(entries: np.ndarray) -> np.ndarray:
    q, r = np.linalg.qr(entries)
    return q * np.sign(np.diag(r))


def _matrix_strategy(d):
    elements = st.floats(-1, 1, allow_nan=False).filter(lambda x: abs(x) > 1e-3)
    return hnp.arrays(np.float64, (d, d), elements=elements).filter(lambda m: abs(np.linalg.det(m)) > 1e-2)


@pytest.mark.parametrize("d", DIMS)
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_rigid_motions_keep_volume_and_measure(d, data):
    mesh = ball_polytope(d, 2) if d < 4 else tesseract_boundary(0.7)
    q = _orthogonal(data.draw(_matrix_strategy(d)))
    shift = data.draw(hnp.arrays(np.float64, d, elements=st.floats(-100, 100)))
    moved = mesh.transformed(q, shift)  # transformed() reverses orientation when det(q) < 0
    # round-off: ~1e-16 relative per coordinate, amplified by |shift| / size <= 1e2 and by the
    # (d-1)-fold products in the normals: 1e-10 is ample
    assert moved.volume == pytest.approx(mesh.volume, rel=1e-10)
    assert moved.measure == pytest.approx(mesh.measure, rel=1e-10)
    assert moved.check().ok


@pytest.mark.parametrize("d", DIMS)
@settings(max_examples=25, deadline=None)
@given(scale=st.floats(1e-3, 1e3))
def test_scaling_and_reversal(d, scale):
    mesh = ball_polytope(d, 2)
    scaled = mesh.transformed(scale * np.eye(d))
    assert scaled.volume == pytest.approx(scale**d * mesh.volume, rel=1e-12)
    assert scaled.measure == pytest.approx(scale ** (d - 1) * mesh.measure, rel=1e-12)
    flipped = scaled.flipped()
    assert flipped.volume == pytest.approx(-scaled.volume, rel=1e-12)
    assert np.allclose(flipped.simplex_normals, -scaled.simplex_normals, atol=1e-12)
    report = flipped.check()
    # consistently inward is still consistent, but inside out is not OK
    assert report.closed and report.oriented and report.manifold
    assert report.inside_out and not report.ok and "inside out" in str(report)


@pytest.mark.parametrize("d", DIMS)
@settings(max_examples=20, deadline=None)
@given(matrix=st.data())
def test_general_linear_map_scales_volume_by_det(d, matrix):
    # volume is multiplied by |det A| exactly (transformed() keeps the orientation outward)
    m = matrix.draw(_matrix_strategy(d))
    mesh = simplex_boundary(d)
    moved = mesh.transformed(m)
    assert moved.volume == pytest.approx(abs(np.linalg.det(m)) * mesh.volume, rel=1e-9)


# --------------------------------------------------------------------------------------------
# slicing 4D meshes
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# caching
# --------------------------------------------------------------------------------------------


def test_cache_is_reused_and_read_only():
    mesh = ball_polytope(4, 2)
    normals = mesh.simplex_normals
    assert mesh.simplex_normals is normals  # computed once
    for arr in (normals, mesh.vertices, mesh.simplices, mesh.vertex_normals, mesh.bounds):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 0
    assert mesh.check() is mesh.check()


def test_cache_dropped_when_arrays_change():
    mesh = ball_polytope(3, 2)
    volume, normals = mesh.volume, mesh.simplex_normals
    mesh.check()
    mesh.cache["bvh"] = object()
    version = mesh.version
    mesh.vertices = 2.0 * mesh.vertices
    assert mesh.version == version + 1 and "bvh" not in mesh.cache
    assert mesh.volume == pytest.approx(8 * volume, rel=1e-12)
    assert mesh.simplex_normals is not normals and np.allclose(mesh.simplex_normals, normals)
    mesh.simplices = mesh.simplices[:, ::-1]  # reversal flips the orientation in 3D
    assert mesh.volume == pytest.approx(-8 * volume, rel=1e-12)
    assert mesh.check().oriented


def test_setter_validation():
    mesh = simplex_boundary(3)
    mesh.point_data["ao"] = np.zeros(4)
    with pytest.raises(ValueError, match="must keep 4 rows while point_data is set"):
        mesh.vertices = np.zeros((5, 3))
    with pytest.raises(ValueError, match="must keep dimension 3"):
        mesh.vertices = np.zeros((4, 4))
    with pytest.raises(ValueError, match="outside"):
        mesh.simplices = [[0, 1, 9]]
    with pytest.raises(ValueError, match=r"`point_data\['x'\]` must have first dimension 4"):
        mesh.point_data["x"] = np.zeros(3)
    with pytest.raises(ValueError, match=r"`cell_data\['x'\]` must have first dimension 4"):
        mesh.cell_data.update(x=np.zeros(5))


def test_copy_and_pickle_are_independent():
    mesh = ball_polytope(4, 2)
    mesh.point_data["ao"] = np.linspace(0, 1, mesh.n_vertices)
    mesh.check()
    for other in (mesh.copy(), pickle.loads(pickle.dumps(mesh))):
        assert np.array_equal(other.vertices, mesh.vertices)
        assert np.array_equal(other.point_data["ao"], mesh.point_data["ao"])
        other.vertices = other.vertices + 1.0
        assert mesh.volume == pytest.approx(other.volume, rel=1e-12)
        assert not np.array_equal(other.vertices, mesh.vertices)


def test_repr_and_basic_properties():
    mesh = simplex_boundary(4)
    mesh.point_data["ao"] = np.zeros(5)
    assert repr(mesh) == "SimplexMesh(dim=4, n_vertices=5, n_simplices=5, point_data=['ao'])"
    assert (mesh.dim, mesh.n_vertices, mesh.n_simplices, len(mesh)) == (4, 5, 5, 5)
    assert np.array_equal(mesh.bounds, [[0, 0, 0, 0], [1, 1, 1, 1]])
    assert mesh.scale == pytest.approx(2.0)


# --------------------------------------------------------------------------------------------
# input validation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("vertices", "simplices", "error", "match"),
    [
        (np.zeros((3, 5)), [[0, 1, 2, 0, 1]], ValueError, r"`vertices` must have shape \(V, d\) with d in"),
        (np.zeros(3), [[0]], ValueError, "`vertices` must be a 2D array"),
        ([[0, 0], [1, np.nan]], [[0, 1]], ValueError, "`vertices` contains 1 non-finite"),
        ([[0, 0], [1, np.inf]], [[0, 1]], ValueError, "`vertices` contains 1 non-finite"),
        ([["a", "b"]], [[0, 0]], TypeError, r"`vertices` must hold real numbers \(float or int\), got dtype <U1"),
        (np.zeros((3, 3)), [[0, 1]], ValueError, r"`simplices` must have shape \(S, 3\)"),
        (np.zeros((3, 3)), [[0, 1, 3]], ValueError, r"`simplices` holds 1 vertex index\(es\) outside \[0, 3\)"),
        (np.zeros((3, 3)), [[0, 1, -1]], ValueError, "outside"),
        (np.zeros((3, 3)), [[0, 1, 1.5]], TypeError, "`simplices` must hold integer vertex indices"),
        (np.zeros((3, 3)), [[True, False, True]], TypeError, "integer vertex indices"),
    ],
)
def test_bad_input(vertices, simplices, error, match):
    with pytest.raises(error, match=match):
        SimplexMesh(vertices, simplices)


def test_bad_data_and_options():
    with pytest.raises(ValueError, match=r"`point_data\['ao'\]` must have first dimension 3"):
        SimplexMesh(np.zeros((3, 2)), [[0, 1]], point_data={"ao": np.zeros(2)})
    with pytest.raises(TypeError, match="keys must be nonempty strings"):
        SimplexMesh(np.zeros((3, 2)), [[0, 1]], cell_data={1: np.zeros(1)})
    with pytest.raises(ValueError, match=r"`rtol` must be in \[0, 1\)"):
        simplex_boundary(2).check(rtol=-1)
    with pytest.raises(ValueError, match="`matrix` must be invertible"):
        simplex_boundary(2).transformed(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"`offset` must be a scalar or have shape \(2,\)"):
        simplex_boundary(2).transformed(np.eye(2), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"`matrix` must have shape"):
        simplex_boundary(2).transformed(np.eye(3))
    with pytest.raises(TypeError, match="unexpected keyword"):
        SimplexMesh(np.zeros((3, 2)), [[0, 1]], colors=1)


def test_empty_mesh():
    mesh = SimplexMesh(np.zeros((0, 4)), np.zeros((0, 4), dtype=int))
    assert mesh.volume == 0.0 and mesh.measure == 0.0
    report = mesh.check()
    assert report.n_simplices == 0 and not report.closed and not report.ok and report.empty
    assert "empty" in str(report) and "boundary faces" not in str(report)
    assert mesh.split() == []
    with pytest.raises(ValueError, match="`mesh` has no simplices"):
        mesh.slice([0, 0, 0, 0], [0, 0, 0, 1])
    assert SimplexMesh(np.zeros((2, 3)), []).n_simplices == 0


# --------------------------------------------------------------------------------------------
# file formats
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# scale
# --------------------------------------------------------------------------------------------


def test_adopt_takes_fresh_engine_arrays_without_copies():
    vertices = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    simplices = np.array([[0, 2], [2, 1], [1, 0]], dtype=np.int64)
    mesh = SimplexMesh._adopt(vertices, simplices)
    assert mesh.vertices is vertices and mesh.simplices is simplices
    assert not vertices.flags.writeable and not simplices.flags.writeable
    assert float(mesh.volume) == 0.5 and mesh.check().ok
    # anything else (another dtype) goes through the checking constructor
    other = SimplexMesh._adopt(
        np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 2], [2, 1], [1, 0]], dtype=np.int32)
    )
    assert other.simplices.dtype == np.int64 and other.check().ok


def test_a_mesh_is_freed_when_its_last_name_goes_without_the_garbage_collector():
    # point_data once held its mesh: every mesh was a reference cycle, kept (with its BVH and
    # device buffers) until a collection; a dataset run held several 3 M-tet meshes at once
    import gc
    import weakref

    mesh = simplex_boundary(3)
    mesh.point_data["ao"] = np.zeros(4)
    mesh.cell_data["id"] = np.arange(4)
    gone = weakref.ref(mesh)
    gc.disable()
    try:
        del mesh
        assert gone() is None
    finally:
        gc.enable()


def test_data_lengths_follow_the_arrays_they_describe():
    mesh = simplex_boundary(3)
    mesh.vertices = np.vstack([mesh.vertices, [[5.0, 5.0, 5.0]]])  # no point_data yet: may grow
    with pytest.raises(ValueError, match=r"`point_data\['ao'\]` must have first dimension 5"):
        mesh.point_data["ao"] = np.zeros(4)
    mesh.point_data["ao"] = np.zeros(5)
    mesh.simplices = mesh.simplices[:2]
    with pytest.raises(ValueError, match=r"`cell_data\['id'\]` must have first dimension 2"):
        mesh.cell_data["id"] = np.arange(4)
    mesh.cell_data["id"] = np.arange(2)


# -- the volume's sign from the vertex normal sums (warn_if_inside_out) -----------------------


@settings(max_examples=60, deadline=None)
@given(
    d=st.sampled_from((2, 3, 4)),
    seed=st.integers(0, 2**16),
    shift=st.sampled_from((0.0, 1e4, 3e7)),
    flip=st.booleans(),
    closed=st.booleans(),
)
def test_volume_sign_from_the_vertex_sums_is_the_volumes(d, seed, shift, flip, closed):
    # open random meshes have volumes of either sign and any size; the closed ones, both
    # orientations; far from the origin the terms cancel to many digits
    rng = np.random.default_rng(seed)
    if closed:
        base = ball_polytope(d, 4)
        v, s = base.vertices * rng.uniform(0.01, 10) + shift, base.simplices
    else:
        v, s = rng.normal(size=(30, d)) + shift, rng.integers(0, 30, (rng.integers(1, 60), d))
    if flip:  # two corners swapped: the orientation reversed
        s = s[:, [1, 0, *range(2, d)]]
    mesh = SimplexMesh(v, s)
    assert mesh._volume_not_negative() == (SimplexMesh(v, s).volume >= 0)
    if closed:
        assert mesh._volume_not_negative() != flip


def test_volume_sign_of_a_zero_volume_mesh_comes_from_the_volume():
    # a closed mesh glued to its own mirror image encloses nothing: the sums leave the sign in
    # doubt and the volume decides, whatever its rounding
    base = ball_polytope(4, 4)
    both = concatenate([base, SimplexMesh(base.vertices, base.simplices[:, [1, 0, 2, 3]])])
    assert abs(both.volume) < 1e-12
    fresh = SimplexMesh(both.vertices, both.simplices)
    assert fresh._volume_not_negative() == (both.volume >= 0)
    assert "_volume" in fresh._derived  # decided by the volume itself
