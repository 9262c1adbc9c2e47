"""Fault injection: bad files, bad places to write, inside-out and empty results.

No case is silent or ends in a traceback: each asserts that the message names the problem and,
where files are written, that nothing partial is left behind.
"""

from __future__ import annotations

import math
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

import ao4d
from ao4d import _atomic, cli
from ao4d.marching import march
from ao4d.mesh import InsideOutWarning, SimplexMesh


@pytest.fixture(scope="module")
def ball() -> SimplexMesh:
    return ao4d.extract_field(ao4d.fields.hypersphere(1.0), 10, (-1.3, 1.3))


@pytest.fixture()
def mesh_file(ball, tmp_path) -> Path:
    return ball.save(tmp_path / "ball.npz")


def _read_only_folder() -> Path:
    """A folder nobody may write, not even root (sysfs refuses new files)."""
    folder = Path("/sys")
    try:
        fd, probe = tempfile.mkstemp(dir=folder)
    except OSError:
        return folder
    os.close(fd)
    os.unlink(probe)
    pytest.skip("no folder on this machine refuses writes (needed to test read-only outputs)")


def _cli(capsys, *argv) -> tuple[int, str]:
    code = cli.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


# -- inside-out meshes ------------------------------------------------------------------------


def test_inside_out_mesh_is_reported(ball):
    # a negative volume is not "=> OK"
    report = ball.flipped().check()
    assert report.inside_out and not report.ok
    assert "inside out" in str(report) and "NOT OK" in str(report)
    assert ball.check().ok and not ball.check().inside_out


def test_extract_warns_when_inside_is_probably_wrong():
    with pytest.warns(InsideOutWarning, match="inside='above'.*try inside='below'"):
        mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), 10, (-1.3, 1.3), inside="above")
    assert mesh.volume < 0


def test_ambient_occlusion_warns_on_inside_out_meshes(ball):
    # AO is 1.0 at every vertex of an inside-out mesh: said, not silent
    with pytest.warns(InsideOutWarning, match=r"inside out.*AO = 1 everywhere.*mesh.flipped\(\)"):
        ao4d.ambient_occlusion(ball.flipped(), samples=4, backend="numpy")


# -- files that cannot be written -------------------------------------------------------------


def test_output_checks_come_before_the_work(tmp_path):
    ro = _read_only_folder()
    with pytest.raises(ValueError, match=r"`--out` '/sys/x.npz': cannot write in '/sys'"):
        _atomic.check_output_file(ro / "x.npz", "--out", (".npz",))
    with pytest.raises(ValueError, match="is a folder; give a file name"):
        _atomic.check_output_file(tmp_path, "--out")
    with pytest.raises(ValueError, match=r"must end in \.npz or \.vtu"):
        _atomic.check_output_file(tmp_path / "x.png", "--out", (".npz", ".vtu"))
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file, not a folder"):
        _atomic.check_output_file(tmp_path / "file" / "x.npz", "--out")
    with pytest.raises(ValueError, match="is a file; give a folder"):
        _atomic.check_output_folder(tmp_path / "file", "out")
    assert _atomic.check_output_file(tmp_path / "new" / "x.npz", "--out", (".npz",)).name == "x.npz"


def test_ao_command_refuses_a_bad_out_before_tracing(mesh_file, tmp_path, capsys, monkeypatch):
    traced = []
    monkeypatch.setattr("ao4d.ao.count_occluded", lambda *a, **k: traced.append(1))
    ro = _read_only_folder()
    for out, problem in [
        (ro / "ball_ao.npz", "cannot write in '/sys'"),
        (tmp_path, "is a folder"),
        (tmp_path / "ball_ao.png", "must end in .npz or .vtu or .txt"),
    ]:
        code, text = _cli(capsys, "ao", mesh_file, "--out", out, "--samples", "2", "--backend", "numpy")
        assert code == 2 and problem in text and "Traceback" not in text
    assert not traced  # refused before any ray


def test_ao_command_writes_the_format_its_suffix_names(mesh_file, tmp_path, capsys):
    # `ao --out x.vtu` writes a .vtu, not an npz named .vtu
    code, _ = _cli(capsys, "ao", mesh_file, "--out", tmp_path / "x.vtu", "--samples", "2", "--backend", "numpy")
    assert code == 0
    assert not zipfile.is_zipfile(tmp_path / "x.vtu")
    back = SimplexMesh.load(tmp_path / "x.vtu")
    assert "ao" in back.point_data and back.n_simplices > 0


def test_demo_out_that_is_a_file_is_refused_before_the_work(tmp_path, capsys, monkeypatch):
    (tmp_path / "taken").write_text("not a folder")
    extracted = []
    monkeypatch.setattr("ao4d.scenes.extract_scene", lambda *a, **k: extracted.append(1))
    code, text = _cli(capsys, "demo", "--tiny", "--out", tmp_path / "taken")
    assert code == 2 and "is a file; give a folder" in text and not extracted


def test_a_failing_later_file_takes_the_earlier_ones_with_it(tmp_path):
    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    (tmp_path / "old.txt").write_text("kept")
    with pytest.raises(OSError, match="disk full"):
        with _atomic.all_or_nothing(folder=tmp_path):
            first.write_text("new")
            raise OSError("disk full")  # stands for the failing second write
    assert not first.exists() and not second.exists()
    assert (tmp_path / "old.txt").read_text() == "kept"


def test_cli_turns_a_write_fault_into_one_line(mesh_file, tmp_path, capsys, monkeypatch):
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / "out.npz"))

    monkeypatch.setattr("ao4d.io.mesh_files.write", refuse)
    code, text = _cli(capsys, "ao", mesh_file, "--out", tmp_path / "out.npz", "--samples", "2", "--backend", "numpy")
    assert code == 2 and "Permission denied" in text and "Traceback" not in text


# -- files that cannot be read ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda b: b"", r"not a readable \.npz file \(empty\)"),
        (lambda b: b[: len(b) // 2], r"not a readable \.npz file"),
        (lambda b: b[:200] + bytes([b[200] ^ 0xFF]) + b[201:], r"not a readable \.npz file"),
        (lambda b: b"\x89PNG\r\n\x1a\n" + b"\0" * 64, r"not a readable \.npz file \(not a zip archive\)"),
    ],
    ids=["empty", "truncated", "bit-flipped", "png"],
)
def test_damaged_mesh_files_get_one_clear_error(mesh_file, tmp_path, damage, message):
    # one ValueError, not BadZipFile / EOFError / zlib errors
    bad = tmp_path / "bad.npz"
    bad.write_bytes(damage(mesh_file.read_bytes()))
    with pytest.raises(ValueError, match=message) as info:
        SimplexMesh.load(bad)
    assert "bad.npz" in str(info.value)


def test_foreign_files_given_as_meshes(tmp_path, capsys):
    png = tmp_path / "picture.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    with pytest.raises(ValueError, match="picture.png.*not an ao4d mesh file"):
        SimplexMesh.load(png)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="other.npz.*not an ao4d mesh file"):
        SimplexMesh.load(tmp_path / "other.npz")
    np.savez(tmp_path / "shapes.npz", format=np.array(1), vertices=np.zeros((3, 5)), simplices=np.zeros((1, 5)))
    with pytest.raises(ValueError, match="shapes.npz.*does not hold a valid mesh"):
        SimplexMesh.load(tmp_path / "shapes.npz")
    code, text = _cli(capsys, "ao", png, "--out", tmp_path / "x.npz")
    assert code == 2 and "not an ao4d mesh file" in text and "Traceback" not in text


# -- checks before long work ------------------------------------------------------------------


def test_max_distance_is_checked_before_the_bvh(ball, monkeypatch):
    built = []
    monkeypatch.setattr("ao4d.bvh.build", lambda *a, **k: built.append(1))
    fresh = ball.copy()
    with pytest.raises(ValueError, match="`max_distance` must be > 0"):
        ao4d.ambient_occlusion(fresh, max_distance=-1.0, backend="numpy")
    assert not built


def test_absurd_sample_counts_are_refused_with_an_estimate(ball):
    # samples=10**7 would start 2e10 rays; samples=10**9 would allocate 24 GiB in scipy
    with pytest.raises(ValueError, match=r"`samples`=10000000 .* asks for .* rays, about .* max_rays=math.inf"):
        ao4d.ambient_occlusion(ball, samples=10**7, backend="numpy")
    with pytest.raises(MemoryError, match="direction table for samples=1000000000"):
        ao4d.ambient_occlusion(ball, samples=10**9, max_rays=math.inf, backend="numpy")


# -- empty and flat results -------------------------------------------------------------------


def test_empty_results_say_why(tmp_path):
    values = np.linspace(0.0, 1.0, 4**4).reshape((4,) * 4)
    with pytest.warns(march.EmptyMeshWarning, match=r"outside the data range \[0, 1\]"):
        empty = ao4d.extract(values, 2.0)
    assert "empty" in str(empty.check()) and "boundary faces" not in str(empty.check())
    with pytest.raises(ValueError, match="`mesh` has no simplices"):
        empty.slice([0, 0, 0, 0], [0, 0, 0, 1])


def test_a_field_returning_nan_is_blamed_on_the_field():
    def holey(p):
        return np.where(p[..., 0] > 0.5, np.nan, np.linalg.norm(p, axis=-1) - 1.0)

    with pytest.raises(ValueError, match=r"`field` returned \d+ non-finite value.*at point \(0\.(5[1-9]|[6-9])"):
        ao4d.extract_field(holey, (8,) * 4, (-1.3, 1.3))


@pytest.mark.parametrize("d", [2, 3])
def test_no_nan_ao_where_simplices_have_zero_measure(d):
    # values exactly at the level make zero-measure simplices; vertices used only by them had
    # NaN AO (seeds where this happens, found by search)
    x = np.linspace(-1, 1, 10)
    r = np.sqrt(sum(g * g for g in np.meshgrid(*[x] * 4, indexing="ij")))
    rng = np.random.default_rng(1)
    values = r - 0.6
    values[(np.abs(values) < 0.25) & (rng.random(values.shape) < 0.5)] = 0.0
    values = values[(slice(None),) * d + (5,) * (4 - d)]
    mesh = ao4d.extract(values, 0.0)
    flat = (np.linalg.norm(mesh.vertex_normals, axis=1) == 0) & (
        np.bincount(mesh.simplices.ravel(), minlength=mesh.n_vertices) > 0
    )
    assert flat.any()  # the case the test is about
    ao = ao4d.ambient_occlusion(mesh, samples=16, backend="numpy")
    assert not np.isnan(ao).any()
    # a flat vertex sits on its neighbours: it gets their mean AO
    v = int(np.flatnonzero(flat)[0])
    rows = mesh.simplices[(mesh.simplices == v).any(axis=1)]
    neighbours = np.unique(rows[rows != v])
    assert ao[neighbours].min() - 1e-12 <= ao[v] <= ao[neighbours].max() + 1e-12


# -- logs ---------------------------------------------------------------------------------------


def test_logs_get_lines_not_bars(ball, capsys, monkeypatch):
    from ao4d import _progress

    monkeypatch.setattr(_progress, "LOG_INTERVAL", 0.0)
    ao4d.ambient_occlusion(ball.copy(), samples=4, backend="numpy", progress=True)
    err = capsys.readouterr().err
    assert "4D AO (numpy): " in err and "rays" in err
    assert "\r" not in err and "\x1b[" not in err  # no tqdm redraws in the log


def test_no_progress_silences_everything(mesh_file, tmp_path, capsys, monkeypatch):
    from ao4d import _progress

    monkeypatch.setattr(_progress, "LOG_INTERVAL", 0.0)
    code = cli.main(
        [
            "ao",
            str(mesh_file),
            "--out",
            str(tmp_path / "x.npz"),
            "--samples",
            "4",
            "--backend",
            "numpy",
            "--no-progress",
        ]
    )
    assert code == 0 and capsys.readouterr().err == ""
    _progress.set_enabled(True)


def test_render_png_failure_leaves_no_vti_behind(mesh_file, tmp_path, capsys, monkeypatch):
    # an error, not a traceback after the render, and no .vti left
    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("ao4d.io.pictures.save_montage", fail)
    code, text = _cli(
        capsys,
        "render",
        mesh_file,
        "--out",
        tmp_path / "img.vti",
        "--size",
        "8",
        "--ao",
        "none",
        "--backend",
        "numpy",
        "--png",
        tmp_path / "img.png",
    )
    assert code == 2 and "No space left" in text and "Traceback" not in text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ball.npz"]


def test_render_refuses_bad_outputs_before_rendering(mesh_file, tmp_path, capsys, monkeypatch):
    rendered = []
    monkeypatch.setattr("ao4d.rendering.pipeline.render", lambda *a, **k: rendered.append(1))
    for extra, problem in [
        (["--out", tmp_path / "img.nii"], "`--out` must end in .vti or .mhd"),
        (["--out", tmp_path / "img.vti", "--png", tmp_path / "img.jpg"], "`--png` must end in .png"),
        (["--out", tmp_path], "is a folder"),
    ]:
        code, text = _cli(capsys, "render", mesh_file, "--size", "8", *extra)
        assert code == 2 and problem in text, text
    assert not rendered


def test_extract_command_estimates_and_refuses_huge_grids(tmp_path, capsys, monkeypatch):
    # a 300^4 grid is estimated, and refused, before any work
    sampled = []
    monkeypatch.setattr("ao4d.marching.march.extract_field", lambda *a, **k: sampled.append(1))
    code, text = _cli(capsys, "extract", "--shape", "hypersphere", "--grid", "300", "--out", tmp_path / "x.npz")
    assert code == 2 and "7.99e+09 cells: about 13 min" in text and "pass --force" in text
    assert not sampled and not (tmp_path / "x.npz").exists()


def test_extract_command_empty_result_is_an_error_with_the_reason(tmp_path, capsys):
    # exit 2, not 0 with an empty mesh file
    np.save(tmp_path / "ramp.npy", np.linspace(0.0, 1.0, 4**4).reshape((4,) * 4))
    code, text = _cli(capsys, "extract", "--input", tmp_path / "ramp.npy", "--level", "3", "--out", tmp_path / "x.npz")
    assert code == 2 and "outside the data range [0, 1]" in text
    assert not (tmp_path / "x.npz").exists()


def test_extract_command_checks_both_outputs_first(tmp_path, capsys):
    code, text = _cli(
        capsys,
        "extract",
        "--shape",
        "hypersphere",
        "--grid",
        "10",
        "--out",
        tmp_path / "x.npz",
        "--vtu",
        tmp_path / "x.vtk",
    )
    assert code == 2 and "`--vtu` must end in .vtu" in text and not (tmp_path / "x.npz").exists()


def test_slice_command_checks_outputs_before_loading(tmp_path, capsys, monkeypatch):
    loaded = []
    monkeypatch.setattr("ao4d.mesh.SimplexMesh.load", classmethod(lambda cls, p: loaded.append(p)))
    for extra, problem in [
        (["--out", tmp_path / "s.obj"], "`--out` must end in .ply or .glb"),
        (["--out", tmp_path / "s.ply", "--png", tmp_path / "s.gif"], "`--png` must end in .png"),
    ]:
        code, text = _cli(capsys, "slice", tmp_path / "any.npz", "--w", "0", *extra)
        assert code == 2 and problem in text, text
    assert not loaded


# -- datasets_gen: bad output folders, per-item seeds -----------------------------------------


@pytest.fixture()
def tiny_config_file(tmp_path) -> Path:
    from _datasets import TINY, write_config

    return write_config(tmp_path, TINY, "tiny.toml")


def test_datasets_gen_out_that_is_a_file_or_read_only_is_a_clear_error(tiny_config_file, tmp_path, capsys, monkeypatch):
    from datasets_gen import runner

    (tmp_path / "taken").write_text("not a folder")
    assert runner.main([str(tiny_config_file), "--out", str(tmp_path / "taken"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "`out`" in err and "is a file; it must be a folder" in err and "Traceback" not in err
    assert (tmp_path / "taken").read_text() == "not a folder"

    import errno

    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "mkdir", read_only)
    assert runner.main([str(tiny_config_file), "--out", str(tmp_path / "ro" / "run"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot create the output folder `out`" in err and "Read-only file system" in err
    assert "Traceback" not in err


def test_item_seeds_differ_between_items_and_repeat_for_the_same_item():
    from datasets_gen import item_seed

    def draws(seed, index):
        return np.random.default_rng(item_seed(seed, index)).random(4)

    np.testing.assert_array_equal(draws(7, 3), draws(7, 3))
    rows = np.array([draws(7, index) for index in range(20)])
    assert len(np.unique(rows[:, 0])) == 20  # every item draws its own numbers
    assert not np.array_equal(draws(7, 0), draws(8, 0))  # and the run seed matters
