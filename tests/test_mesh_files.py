"""Tests for ao4d.io.mesh_files: .npz, .vtu and text round trips (SimplexMesh.save/load), slice meshes.

.vtu files are read back by VTK (pyvista); slice meshes by trimesh.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from _shapes import ball_polytope, graded_icosphere, simplex_boundary

from ao4d.io import mesh_files, pictures
from ao4d.mesh import SimplexMesh

DIMS = (2, 3, 4)


def _decorated(d: int) -> SimplexMesh:
    mesh = ball_polytope(d, 2)
    rng = np.random.default_rng(11)
    mesh.point_data["ao"] = rng.random(mesh.n_vertices)
    mesh.point_data["normal"] = mesh.vertex_normals.copy()
    mesh.cell_data["label"] = rng.integers(0, 5, mesh.n_simplices).astype(np.int32)
    # awkward floats must survive exactly
    vertices = mesh.vertices.copy()
    vertices[0, 0] = 1 / 3
    vertices[1, 0] = 1e-300
    vertices[2, 0] = 0.1
    mesh = SimplexMesh(vertices, mesh.simplices, point_data=mesh.point_data, cell_data=mesh.cell_data)
    return mesh


def _assert_same(a: SimplexMesh, b: SimplexMesh, *, data: bool = True):
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.simplices, b.simplices)
    if data:
        assert set(a.point_data) == set(b.point_data) and set(a.cell_data) == set(b.cell_data)
        for k in a.point_data:
            assert np.array_equal(a.point_data[k], b.point_data[k])
        for k in a.cell_data:
            assert np.array_equal(a.cell_data[k], b.cell_data[k])
            assert a.cell_data[k].dtype == b.cell_data[k].dtype


@pytest.mark.parametrize("d", DIMS)
def test_npz_round_trip(d, tmp_path):
    mesh = _decorated(d)
    path = tmp_path / "mesh.npz"
    mesh.save(path)
    _assert_same(mesh, SimplexMesh.load(path))


@pytest.mark.parametrize("d", DIMS)
def test_text_round_trip(d, tmp_path):
    mesh = _decorated(d)
    path = tmp_path / "mesh.txt"
    mesh.save(path)
    back = SimplexMesh.load(path)
    _assert_same(mesh, back, data=False)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#") and lines[1:4] == ["ao4d-mesh 1", f"dim {d}", f"vertices {mesh.n_vertices}"]


@pytest.mark.parametrize("d", DIMS)
def test_vtu_round_trip(d, tmp_path):
    pv = pytest.importorskip("pyvista")
    mesh = _decorated(d)
    path = tmp_path / "mesh.vtu"
    mesh.to_vtu(path)
    grid = pv.read(path)
    cell_type = {2: pv.CellType.LINE, 3: pv.CellType.TRIANGLE, 4: pv.CellType.TETRA}[d]
    assert set(np.unique(grid.celltypes)) == {cell_type}
    assert np.array_equal(grid.cells_dict[cell_type], mesh.simplices)
    assert np.array_equal(grid.points[:, : min(d, 3)], mesh.vertices[:, :3])
    if d == 4:
        assert np.array_equal(grid.point_data["w"], mesh.vertices[:, 3])
    assert np.array_equal(grid.point_data["ao"], mesh.point_data["ao"])
    assert np.array_equal(grid.cell_data["label"], mesh.cell_data["label"])
    _assert_same(mesh, SimplexMesh.load(path))


def test_writes_are_atomic(tmp_path):
    mesh = _decorated(4)
    path = tmp_path / "mesh.npz"
    mesh.save(path)
    before = path.read_bytes()
    bad = mesh.copy()
    bad.point_data["obj"] = np.array([object()] * bad.n_vertices)
    with pytest.raises(TypeError, match="dtype object"):
        bad.save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.npz"]  # no temporary left


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("ao4d-mesh 1\ndim 2\nvertices 2\n0 0\n1 1\nsimplices 1\n0\n", "simplex line 0 must have 2 numbers"),
        ("ao4d-mesh 1\ndim 2\nvertices 2\n0 0\n1 x\nsimplices 1\n0 1\n", "vertex line 1 is not 2 numbers"),
        ("ao4d-mesh 1\ndim 2\nvertices 3\n0 0\n1 1\nsimplices 1\n0 1\n", "expected 'simplices <count>'"),
        ("ao4d-mesh 9\n", "text format 9"),
        ("hello\n", "expected 'ao4d-mesh <count>'"),
        ("ao4d-mesh 1\ndim 2\nvertices 2\n0 0\n1 1\nsimplices 1\n0 5\n", "outside"),
    ],
)
def test_bad_text_files(tmp_path, text, match):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises((ValueError, TypeError), match=match):
        SimplexMesh.load(path)


def test_io_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        SimplexMesh.load(tmp_path / "missing.npz")
    (tmp_path / "other.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable .npz"):
        SimplexMesh.load(tmp_path / "other.npz")
    np.savez(tmp_path / "plain.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not an ao4d mesh file"):
        SimplexMesh.load(tmp_path / "plain.npz")
    with pytest.raises(ValueError, match="must end in .vtu"):
        simplex_boundary(4).to_vtu(tmp_path / "mesh.vtk")
    mesh = simplex_boundary(4)
    mesh.point_data["w"] = np.zeros(5)
    with pytest.raises(ValueError, match="must not use the name 'w'"):
        mesh.to_vtu(tmp_path / "mesh.vtu")
    with pytest.raises(TypeError, match="`mesh` must be a MeshArrays"):
        mesh_files.write(tmp_path / "x.npz", "mesh")


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_slice_mesh_colours_round_trip(tmp_path, suffix):
    tri = graded_icosphere()
    path = mesh_files.save_slice_mesh(tmp_path / f"s{suffix}", tri, occlusion="ao")
    back = trimesh.load(path, force="mesh", process=False)
    assert len(back.faces) == len(tri.faces)
    want = pictures.ao_colors(tri.vertex_attributes["ao"])
    got = np.asarray(back.visual.vertex_colors)
    # glb may reorder vertices: compare colour per position
    order_t = np.lexsort(np.round(tri.vertices, 6).T)
    order_b = np.lexsort(np.round(back.vertices, 6).T)
    np.testing.assert_array_equal(got[order_b], want[order_t])


def test_slice_errors(tmp_path):
    tri = graded_icosphere()
    with pytest.raises(ValueError, match="not a vertex attribute"):
        mesh_files.save_slice_mesh(tmp_path / "s.ply", tri, occlusion="nope")
    with pytest.raises(ValueError, match="one value per vertex"):
        mesh_files.save_slice_mesh(tmp_path / "s.ply", tri, occlusion=np.zeros(3))
    with pytest.raises(ValueError, match="path extension"):
        mesh_files.save_slice_mesh(tmp_path / "s.obj", tri)
    with pytest.raises(ValueError, match="no faces"):
        pictures.save_slice_png(tmp_path / "s.png", trimesh.Trimesh())


def test_slice_ply_has_no_64_bit_properties(ball4, tmp_path):
    # VTK's PLY reader (ParaView) crashed on the int64 "simplex" face property trimesh wrote
    tri = ball4.slice([0, 0, 0, 0.1], [0, 0, 0, 1])
    assert tri.face_attributes["simplex"].dtype == np.int64
    path = mesh_files.save_slice_mesh(tmp_path / "s.ply", tri)
    header = path.read_bytes().split(b"end_header")[0].decode("ascii")
    assert "simplex" in header and "int64" not in header and "uint64" not in header
    back = trimesh.load(path, process=False)
    np.testing.assert_array_equal(back.metadata["_ply_raw"]["face"]["data"]["simplex"], tri.face_attributes["simplex"])


def test_npz_field_data_round_trips_and_old_readers_ignore_it(tmp_path):
    mesh = _decorated(4)
    info = {
        "spacing": np.array([2.0, 2.0, 2.2, 2.0]),
        "units": np.array(["mm", "mm", "mm", "ms"]),
        "w_scale": np.float64(0.001),
        "source": np.asarray("scan.nii"),
    }
    arrays = mesh_files.MeshArrays(mesh.vertices, mesh.simplices, mesh.point_data, mesh.cell_data)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    mesh_files.write(a, arrays, field_data=info)
    mesh_files.write(b, arrays, field_data=dict(reversed(list(info.items()))))
    assert a.read_bytes() == b.read_bytes()  # reproducible whatever the dict order
    back = mesh_files.read_field_data(a)
    assert sorted(back) == sorted(info)
    for name, value in info.items():
        np.testing.assert_array_equal(back[name], value)
    _assert_same(mesh, SimplexMesh.load(a))  # the mesh itself is unchanged
    assert mesh_files.read_field_data(tmp_path / "a.txt") == {}
    mesh.save(tmp_path / "plain.npz")
    assert mesh_files.read_field_data(tmp_path / "plain.npz") == {}
    with pytest.raises(TypeError, match=r"`field_data\['bad'\]` has dtype object"):
        mesh_files.write(tmp_path / "c.npz", arrays, field_data={"bad": np.array([None])})


def test_npz_whose_format_is_not_a_number_is_named(tmp_path):
    from ao4d._npz import write_npz

    mesh = _decorated(3)
    for bad in (np.array("one"), np.array([1, 2])):
        write_npz(tmp_path / "f.npz", {"format": bad, "vertices": mesh.vertices, "simplices": mesh.simplices})
        with pytest.raises(ValueError, match="its `format` entry is not a version number"):
            SimplexMesh.load(tmp_path / "f.npz")
