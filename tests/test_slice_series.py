"""``ao4d slice``: the w-series (PLY + VTP + ParaView .pvd) and the picture title of one slice."""

from __future__ import annotations

import numpy as np
import pytest

import ao4d
from ao4d import fields
from ao4d.cli import main
from ao4d.commands.slice import describe_hyperplane

pv = pytest.importorskip("pyvista", reason="pyvista (installed with pytetwild[all]) reads .pvd")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A 4D torus with a smooth stand-in 'ao' array (any per-vertex data must be carried)."""
    mesh = ao4d.extract_field(fields.spheritorus(0.8, 0.35), 14, (-1.3, 1.3))
    v = mesh.vertices
    mesh.point_data["ao"] = np.clip(0.5 + 0.4 * v[:, 0] * v[:, 3], 0.0, 1.0)
    path = tmp_path_factory.mktemp("scene") / "torus.npz"
    mesh.save(path)
    return path, ao4d.SimplexMesh.load(path)


def test_series_writes_ply_vtp_and_a_pvd_vtk_plays(scene, tmp_path, capsys):
    path, mesh = scene
    out = tmp_path / "series"
    ws = np.linspace(-0.3, 0.3, 5)
    assert main(["slice", str(path), "--w-range", "-0.3", "0.3", "--count", "5", "--out", str(out)]) == 0
    assert "5 slices" in capsys.readouterr().out

    reader = pv.get_reader(str(out / "series.pvd"))
    assert type(reader).__name__ == "PVDReader"
    np.testing.assert_allclose(reader.time_values, ws, rtol=0, atol=0)
    for k, w in enumerate(ws):
        reader.set_active_time_point(k)
        block = reader.read()[0]
        tri = mesh.slice([0, 0, 0, w], [0, 0, 0, 1])
        assert block.n_points == len(tri.vertices) > 0 and block.n_cells == len(tri.faces)
        np.testing.assert_allclose(block.points, tri.vertices, atol=1e-6)  # float32 points
        np.testing.assert_allclose(block.point_data["ao"], tri.vertex_attributes["ao"], atol=1e-7)
        np.testing.assert_array_equal(block.regular_faces, tri.faces)
        # the PLY of the same step: same triangles, AO as colours and as a vertex property
        ply = pv.read(str(out / f"slice_{k:04d}.ply"))
        assert ply.n_points == len(tri.vertices) and ply.n_cells == len(tri.faces)
        assert "RGBA" in ply.point_data or "RGB" in ply.point_data


def test_series_vtp_files_open_in_vtk_xml_reader(scene, tmp_path):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    path, mesh = scene
    out = tmp_path / "s"
    assert main(["slice", str(path), "--w-range", "0", "0.2", "--count", "2", "--out", str(out)]) == 0
    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(out / "slice_0001.vtp"))
    reader.Update()
    poly = reader.GetOutput()
    tri = mesh.slice([0, 0, 0, 0.2], [0, 0, 0, 1])
    assert poly.GetNumberOfPoints() == len(tri.vertices)
    np.testing.assert_allclose(vtk_to_numpy(poly.GetPointData().GetArray("ao")), tri.vertex_attributes["ao"], atol=1e-7)


def test_series_past_the_mesh_keeps_every_step(scene, tmp_path):
    path, mesh = scene
    out = tmp_path / "wide"
    hi = mesh.bounds[1][3]
    assert main(["slice", str(path), "--w-range", "0", str(hi + 0.5), "--count", "4", "--out", str(out)]) == 0
    reader = pv.get_reader(str(out / "series.pvd"))
    assert len(reader.time_values) == 4
    reader.set_active_time_point(3)  # w beyond the mesh: an empty step, still a valid file
    assert reader.read()[0].n_points == 0
    assert (out / "slice_0003.ply").read_text().startswith("ply\n")


def test_series_errors(scene, tmp_path, capsys):
    path, mesh = scene
    bad = [
        (["--w-range", "5", "6", "--count", "3"], "misses the mesh"),
        (["--w-range", "0", "1", "--count", "0"], "`--count` must be >= 1"),
        (["--w-range", "0", "1", "--normal", "1", "0", "0", "0"], "no `--normal`"),
        (["--w", "0", "--count", "3"], "`--count` needs `--w-range"),
    ]
    for extra, message in bad:
        assert main(["slice", str(path), *extra, "--out", str(tmp_path / "x")]) == 2
        assert message in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main(["slice", str(path), "--w-range", "0", "1", "--out", str(tmp_path / "file")]) == 2
    assert "is a file; give a folder" in capsys.readouterr().err


def test_describe_hyperplane():
    assert describe_hyperplane([0, 0, 0, 0.3], [0, 0, 0, 1]) == "w = 0.3"
    assert describe_hyperplane([0, 0, 0, 0.3], [0, 0, 0, -2]) == "w = 0.3"
    assert describe_hyperplane([0, 0, 0, 0.3], [1, 0, 0, 0]) == "x = 0"
    assert describe_hyperplane([0.5, 0, 0, 0.3], [0, -3, 0, 0]) == "y = 0"
    assert describe_hyperplane([0, 0, 0, 0.5], [1, 0, 0, 1]) == "0.707 x + 0.707 w = 0.354"
    assert describe_hyperplane([0, 0, 0, 0.5], [-1, 0, 0, 1]) == "-0.707 x + 0.707 w = 0.354"


def test_single_slice_title_describes_the_hyperplane_cut(scene, tmp_path, monkeypatch):
    # `--normal 1 0 0 0 --w 0.3` cuts the hyperplane x = 0 through (0, 0, 0, 0.3): the title
    # names that hyperplane, not "w = 0.3"
    import ao4d.io.pictures

    titles = []

    def record(path, tri, **kwargs):
        titles.append(kwargs["title"])
        return path

    monkeypatch.setattr(ao4d.io.pictures, "save_slice_png", record)
    path, _ = scene
    args = ["slice", str(path), "--out", str(tmp_path / "s.ply"), "--png", str(tmp_path / "s.png")]
    assert main([*args, "--normal", "1", "0", "0", "0", "--w", "0.3"]) == 0
    assert main([*args, "--w", "0.3"]) == 0
    assert main([*args, "--point", "0", "0", "0", "0.5", "--normal", "1", "0", "0", "1"]) == 0
    assert "x = 0" in titles[0] and "w = 0.3" not in titles[0]
    assert "w = 0.3" in titles[1]
    assert "0.707 x + 0.707 w = 0.354" in titles[2]


def test_a_rerun_with_fewer_slices_leaves_no_old_slice_files(scene, tmp_path):
    path, _ = scene
    out = tmp_path / "series"
    assert main(["slice", str(path), "--w-range", "-0.3", "0.3", "--count", "6", "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")  # not a slice file: kept
    assert main(["slice", str(path), "--w-range", "-0.3", "0.3", "--count", "3", "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["notes.txt", "series.pvd"] + [f"slice_{k:04d}.{s}" for k in range(3) for s in ("ply", "vtp")]
    assert len(pv.get_reader(str(out / "series.pvd")).time_values) == 3


def test_a_w_range_of_one_point_is_refused_for_several_slices(scene, tmp_path, capsys):
    path, _ = scene
    assert main(["slice", str(path), "--w-range", "0.2", "0.2", "--count", "3", "--out", str(tmp_path / "s")]) == 2
    assert "is one point: 3 slices would all be the same" in capsys.readouterr().err
    assert (
        main(["slice", str(path), "--w-range", "0.2", "0.2", "--count", "1", "--out", str(tmp_path / "s")]) == 0
    )  # one slice of one point is fine
