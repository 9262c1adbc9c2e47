"""ao4d.solid_mesh: SolidMesh volume, boundary, check, slices, files."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ao4d
from ao4d.solid_mesh import SolidMesh


def _hyperball(n: int = 11):
    return ao4d.extract_solid_field(ao4d.fields.hypersphere(1.0), n, (-1.3, 1.3), method="simplices")


def test_one_triangle():
    s = SolidMesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]])
    assert s.volume == 0.5 and s.check().ok
    b = s.boundary()
    assert b.n_simplices == 3 and b.volume == pytest.approx(0.5) and b.check().closed


def test_check_finds_overused_and_misoriented_faces():
    v = [[0, 0], [1, 0], [0, 1], [1, 1]]
    assert SolidMesh(v, [[0, 1, 2], [1, 3, 2]]).check().ok
    flipped = SolidMesh(v, [[0, 1, 2], [3, 1, 2]]).check()
    assert flipped.negative == 1 and flipped.misoriented_facets == 1 and not flipped.ok


def test_slice_of_hyperball_at_w0_is_a_ball():
    """Cut at w = 0 (a grid layer: vertices lie in the plane), the slice is the 3D cut of the
    piecewise-linear solid: the ball of radius 1 up to the 4D extraction's chord error
    (relative d^2 h^2 / (8 r^2) with d = 4, as in test_solid.py)."""
    solid = _hyperball(11)
    cut = solid.slice([0, 0, 0, 0], [0, 0, 0, 1])
    vols = ao4d.geometry.signed_volumes(cut.vertices, cut.tets)
    assert (vols > 0).all()
    report = cut.to_solid().check()
    assert report.ok
    h = 2.6 / 10
    exact = 4 / 3 * math.pi
    assert 0 < (exact - cut.volume) / exact <= 16 * h * h / 8
    # the 3D slice at w = 0 is also the solid of the 3D field at w = 0 (same grid layer)
    x = np.linspace(-1.3, 1.3, 11)
    r3 = np.sqrt(sum(g * g for g in np.meshgrid(x, x, x, indexing="ij")))
    own = ao4d.extract_solid(r3, 1.0, spacing=h, origin=-1.3, method="simplices")
    assert cut.volume == pytest.approx(own.volume, rel=1e-9)


def test_oblique_slice_is_conforming():
    cut = _hyperball(9).slice([0.05, 0, 0.1, 0.02], [1, 2, 0.5, 3])
    assert cut.to_solid().check().ok and cut.volume > 0


def test_slice_vtu_round_trip(tmp_path):
    pv = pytest.importorskip("pyvista")
    cut = _hyperball(9).slice([0, 0, 0, 0.1], [0, 0, 0, 1])
    path = cut.save(tmp_path / "cut.vtu")
    grid = pv.read(path)
    assert grid.n_cells == len(cut.tets)
    assert set(np.unique(grid.celltypes)) == {int(pv.CellType.TETRA)}
    assert float(grid.compute_cell_sizes()["Volume"].sum()) == pytest.approx(cut.volume, rel=1e-9)


def test_3d_solid_vtu_and_npz_round_trip(tmp_path):
    pv = pytest.importorskip("pyvista")
    x = np.linspace(-1.2, 1.2, 9)
    r = np.sqrt(sum(g * g for g in np.meshgrid(x, x, x, indexing="ij")))
    solid = ao4d.extract_solid(r, 1.0, spacing=0.3, origin=-1.2)
    grid = pv.read(solid.save(tmp_path / "ball.vtu"))
    assert float(grid.compute_cell_sizes()["Volume"].sum()) == pytest.approx(solid.volume, rel=1e-9)
    back = SolidMesh.load(solid.save(tmp_path / "ball.npz"))
    assert np.array_equal(back.vertices, solid.vertices) and np.array_equal(back.simplices, solid.simplices)


def test_files_refused(tmp_path):
    solid = _hyperball(5)
    with pytest.raises(ValueError, match="`path`.*slice"):
        solid.save(tmp_path / "x.vtu")
    with pytest.raises(ValueError, match="`path`"):
        solid.save(tmp_path / "x.obj")
    surface = ao4d.extract_field(ao4d.fields.hypersphere(1.0), 5, (-1.3, 1.3))
    surface.save(tmp_path / "s.npz")
    with pytest.raises(ValueError, match="not a SolidMesh file"):
        SolidMesh.load(tmp_path / "s.npz")
    solid.save(tmp_path / "solid.npz")
    with pytest.raises(ValueError, match="SolidMesh"):
        ao4d.SimplexMesh.load(tmp_path / "solid.npz")


def test_bad_arrays_refused():
    with pytest.raises(ValueError, match="`vertices`"):
        SolidMesh(np.zeros((3, 5)), [[0, 1, 2]])
    with pytest.raises(ValueError, match="`simplices`"):
        SolidMesh(np.zeros((3, 2)), [[0, 1]])
    with pytest.raises(ValueError, match="`simplices`"):
        SolidMesh(np.zeros((3, 2)), [[0, 1, 7]])
    with pytest.raises(ValueError, match="`vertices`"):
        SolidMesh([[0, np.nan], [1, 0], [0, 1]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="4D"):
        SolidMesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]]).slice([0, 0], [0, 1])


def test_ao4d_load_reads_what_each_mesh_saves(tmp_path):
    solid = _hyperball(5)
    surface = solid.boundary()
    back = ao4d.load(solid.save(tmp_path / "solid.npz"))
    assert isinstance(back, SolidMesh) and np.array_equal(back.simplices, solid.simplices)
    for name in ("surface.npz", "surface.vtu"):
        back = ao4d.load(surface.save(tmp_path / name))
        assert isinstance(back, ao4d.SimplexMesh) and np.array_equal(back.simplices, surface.simplices)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="`path`.*not a readable .npz"):
        ao4d.load(tmp_path / "junk.npz")
