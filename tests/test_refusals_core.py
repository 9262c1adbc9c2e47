"""Hostile input to the core package ("nothing silently wrong"): each case works or is refused
early, naming what is wrong; none is silent, wrong, blocking or murky."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

import ao4d
from ao4d import cli


@pytest.fixture(scope="module")
def ball3():
    return ao4d.extract_field(ao4d.fields.hypersphere(1.0, dim=3), (10,) * 3, (-1.3, 1.3))


@pytest.fixture(scope="module")
def ball4():
    return ao4d.extract_field(ao4d.fields.hypersphere(1.0), (8,) * 4, (-1.3, 1.3))


@pytest.fixture(scope="module")
def ball_file(tmp_path_factory, ball4):
    path = tmp_path_factory.mktemp("refusals") / "ball.npz"
    ball4.save(path)
    return path


def _cli(argv, capsys):
    """Exit code and stderr of ``ao4d ARGV``."""
    code = cli.main([str(a) for a in argv])
    return code, capsys.readouterr().err


# -- 1. AO at extreme scales ---------------------------------------------------------------------


@pytest.mark.parametrize("scale", [1e100, 1e-100])
@pytest.mark.parametrize("dim", [3, 4])
def test_ao_at_extreme_scales_equals_the_unscaled_ao(dim, scale, backend, ball3, ball4):
    # no NaN: the normals' squared lengths would over- or underflow float64 beyond ~1e78 / 1e-120
    # in 3D, ~1e52 / 1e-60 in 4D
    base = ball3 if dim == 3 else ball4
    kw = dict(samples=8, backend=backend)
    want = ao4d.ambient_occlusion(base, max_distance=0.5, **kw)
    mesh = ao4d.SimplexMesh(base.vertices * scale, base.simplices)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no overflow on the way either
        got = ao4d.ambient_occlusion(mesh, max_distance=0.5 * scale, **kw)
    assert not np.isnan(got).any()
    assert np.abs(got - want).max() <= 1 / 8  # one ray of eight at most (the scale's rounding)
    # given points and normals are mapped with the mesh
    points, normals = base.vertices[:5] * 0.5, base.vertex_normals[:5]
    want = ao4d.ambient_occlusion(base, points=points, normals=normals, **kw)
    got = ao4d.ambient_occlusion(mesh, points=points * scale, normals=normals, **kw)
    assert np.abs(got - want).max() <= 1 / 8


def test_ao_of_a_huge_mesh_far_from_the_origin(ball3):
    # scaled by 1e100 and moved 3e100 along x: recentred and rescaled in float64 first
    kw = dict(samples=8, backend="numpy")
    want = ao4d.ambient_occlusion(ball3, max_distance=0.5, **kw)
    far = ao4d.SimplexMesh(ball3.vertices * 1e100 + [3e100, 0, 0], ball3.simplices)
    got = ao4d.ambient_occlusion(far, max_distance=0.5e100, **kw)
    assert np.abs(got - want).max() <= 1 / 8


def test_ao_of_a_mesh_whose_extent_overflows_is_refused():
    mesh = ao4d.SimplexMesh([[-1e308, 0, 0], [1e308, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="`mesh` spans .* overflows float64"):
        ao4d.ambient_occlusion(mesh, samples=2, backend="numpy")


# -- 2. seeds ------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [2**32, 2**40 + 1, -1])
def test_seeds_outside_32_bits_are_refused(seed, ball3):
    # refused, not cut to its low 32 bits (seed 2**32 would trace the rays of seed 0)
    with pytest.raises(ValueError, match=r"`seed` must be an integer in \[0, 2\*\*32\)"):
        ao4d.ambient_occlusion(ball3, samples=4, seed=seed, backend="numpy")
    from ao4d.sampling import cosine_hemisphere, sobol_table

    with pytest.raises(ValueError, match="`seed`"):
        sobol_table(4, 3, seed=seed)
    with pytest.raises(ValueError, match="`seed`"):
        cosine_hemisphere(np.array([[0.0, 0, 1]]), 4, seed=seed)


def test_seeds_in_range_keep_their_rays(ball3):
    # the bytes of every existing seed stay as they were (datasets depend on them)
    from ao4d.sampling import sobol_table

    assert sobol_table(16, 3, seed=2**32 - 1).shape == (16, 3)
    a = ao4d.ambient_occlusion(ball3, samples=4, seed=7, backend="numpy")
    np.testing.assert_array_equal(a, ao4d.ambient_occlusion(ball3, samples=4, seed=7, backend="numpy"))


def test_cli_seed_out_of_range_names_the_option(ball_file, tmp_path, capsys):
    code, err = _cli(["ao", ball_file, "--out", tmp_path / "a.npz", "--seed", "-1", "--samples", "2"], capsys)
    assert code == 2 and "`--seed` must be an integer in [0, 2**32)" in err
    assert not (tmp_path / "a.npz").exists()


# -- 3. no compatibility layer -------------------------------------------------------------------


def test_modules_live_at_one_path_with_no_aliases():
    import importlib

    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("ao4d.lut")
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("ao4d._deprecation")


# -- 4. FIFOs and folders as input files ---------------------------------------------------------


@pytest.fixture
def fifo(tmp_path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    path = tmp_path / "fifo.npy"
    os.mkfifo(path)
    return path


def test_extract_refuses_a_fifo_instead_of_blocking(fifo, tmp_path, capsys):
    # refused before np.load could open the FIFO and wait for a writer, for ever
    code, err = _cli(["extract", "--input", fifo, "--out", tmp_path / "o.npz"], capsys)
    assert code == 2 and "`--input` file" in err and "is a FIFO (named pipe); a regular file is expected" in err


@pytest.mark.parametrize("name", ["fifo.npy", "frames_*.npy"])
def test_read_grid_refuses_fifos_and_folders(fifo, tmp_path, name):
    from ao4d.io.grids import read_grid

    np.save(tmp_path / "frames_0.npy", np.zeros((3, 3, 3)))
    os.mkfifo(tmp_path / "frames_1.npy")
    with pytest.raises(ValueError, match="FIFO"):
        read_grid(tmp_path / name)
    (tmp_path / "folder.npy").mkdir()
    with pytest.raises(ValueError, match=r"`path` file .*folder\.npy' is a folder"):
        read_grid(tmp_path / "folder.npy")


def test_mesh_files_refuse_fifos(fifo):
    with pytest.raises(ValueError, match="is a FIFO"):
        ao4d.SimplexMesh.load(_renamed(fifo, "m.npz"))


def _renamed(path, name):
    target = path.with_name(name)
    os.rename(path, target)
    return target


# -- 5. screen-space AO has a work budget --------------------------------------------------------


def test_screen_space_occlusion_refuses_work_above_the_budget():
    # the work is checked, not only the direction table's memory: samples=10**7 would run for minutes
    from ao4d.rendering.screen_ao import DepthVolume, screen_space_occlusion

    cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], projection="orthographic", half_width=1)
    shape = (16, 16, 16)
    centers = cam.voxel_centers(shape).reshape(-1, 4)
    up = np.tile([0.0, 0, 0, -1], (len(centers), 1))
    vol = DepthVolume.from_hits(cam, shape, np.full(len(centers), 4.0), up)
    with pytest.raises(ValueError, match=r"`samples`=60000 .* above the limit"):
        screen_space_occlusion(vol, centers, up, samples=60000, steps=16, backend="numpy")
    small = screen_space_occlusion(vol, centers[:2], up[:2], samples=4, backend="numpy", max_rays=1e6)
    assert small.shape == (2,)


# -- 6. files that are no .npy / .npz ------------------------------------------------------------

_PNG = b"\x89PNG\r\n\x1a\n" + bytes(64)


@pytest.mark.parametrize(
    "content, reason",
    [(_PNG, "looks like a PNG image"), (bytes(range(256)) * 4, "no .npy header"), (b"", "it is empty")],
)
def test_a_file_that_is_no_npy_says_so_without_the_pickle_hint(tmp_path, content, reason):
    from ao4d.io.grids import read_grid

    path = tmp_path / "x.npy"
    path.write_bytes(content)
    with pytest.raises(ValueError) as info:
        read_grid(path)
    text = str(info.value)
    assert "x.npy' is not a valid .npy file" in text and reason in text
    assert "allow_pickle" not in text and "pickled" not in text


def test_object_arrays_are_never_loaded(tmp_path):
    from ao4d.io.grids import read_grid

    np.save(tmp_path / "obj.npy", np.array([[{"a": 1}] * 2] * 2, dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="Python objects") as info:
        read_grid(tmp_path / "obj.npy")
    assert "allow_pickle" not in str(info.value)
    np.savez(
        tmp_path / "obj.npz",
        format=np.array(1),
        vertices=np.array([[1.0, 2.0]], dtype=object),
        simplices=np.zeros((0, 2), int),
        allow_pickle=True,
    )
    with pytest.raises(ValueError, match="obj.npz' is not a readable .npz file .*Python objects") as info:
        ao4d.SimplexMesh.load(tmp_path / "obj.npz")
    assert "allow_pickle" not in str(info.value)


def test_a_lut_file_that_is_no_npz(tmp_path):
    from ao4d.marching import lut

    (tmp_path / "cube_3d.npz").write_bytes(_PNG)
    with pytest.raises(ValueError, match="cube_3d.npz' is not a valid .npz file") as info:
        lut.read(tmp_path / "cube_3d.npz")
    assert "allow_pickle" not in str(info.value)


# -- 7. and 13. vertices of other dtypes, uint64 indices -----------------------------------------


@pytest.mark.parametrize(
    "dtype, words",
    [(object, "object (float)"), (str, "<U32"), (complex, "complex128"), (bool, "bool"), ("decimal", "Decimal")],
)
def test_vertices_of_other_dtypes_say_what_is_wrong(dtype, words):
    from decimal import Decimal

    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    if dtype == "decimal":
        vertices = [[Decimal(int(x)) for x in row] for row in vertices]
    else:
        vertices = vertices.astype(dtype)
    # the error names `vertices` and its dtype, not the pair as a whole
    with pytest.raises(TypeError, match=r"`vertices` must hold real numbers \(float or int\), got dtype") as info:
        ao4d.ambient_occlusion((vertices, [[0, 1, 2]]), samples=2, backend="numpy")
    assert words in str(info.value) and "got tuple" not in str(info.value)


@pytest.mark.parametrize("index", [2**64 - 1, 2**63])
def test_uint64_indices_are_shown_as_they_are(index):
    # not converted to int64 first, where 2**64 - 1 would show as -1
    with pytest.raises(ValueError, match=rf"range found: 0\.\.{index}\)"):
        ao4d.SimplexMesh(np.eye(3), np.array([[0, 1, index]], dtype=np.uint64))


# -- 8.-11. the command line ---------------------------------------------------------------------


def test_bounds_take_negative_numbers_and_refuse_non_finite(tmp_path, capsys):
    out = tmp_path / "o.npz"
    # -inf is a number, not an option (argparse's "expected 2 arguments")
    code, err = _cli(["extract", "--shape", "hypersphere", "--bounds", "-inf", "inf", "--out", out], capsys)
    assert code == 2 and "`--bounds` must be two finite numbers LO < HI, got -inf inf" in err
    code, err = _cli(["extract", "--shape", "hypersphere", "--bounds", "2", "-1", "--out", out], capsys)
    assert code == 2 and "LO < HI" in err
    code, _ = _cli(
        ["extract", "--shape", "hypersphere", "--grid", "6", "--bounds", "-1.5e0", "1.5", "--out", out], capsys
    )
    assert code == 0 and out.exists()


def test_ao_refuses_an_empty_name_before_the_trace(ball_file, tmp_path, capsys):
    code = cli.main(["ao", str(ball_file), "--out", str(tmp_path / "a.npz"), "--name", "", "--samples", "2"])
    captured = capsys.readouterr()
    assert code == 2 and "`--name` must be a non-empty data array name" in captured.err
    assert "AO:" not in captured.out  # nothing traced, not even the estimate printed


@pytest.mark.parametrize(
    "argv, option",
    [
        (["slice", "{ball}", "--w", "nan", "--out", "{tmp}/s.ply"], "`--w` must be finite"),
        (["slice", "{ball}", "--point", "0", "0", "0", "inf", "--out", "{tmp}/s.ply"], "`--point` contains"),
        (["slice", "{ball}", "--normal", "0", "0", "0", "0", "--out", "{tmp}/s.ply"], "`--normal` must be a non-zero"),
        (["render", "{ball}", "--out", "{tmp}/r.vti", "--light", "nan", "0", "0", "0"], "`--light` takes finite"),
        (["render", "{ball}", "--out", "{tmp}/r.vti", "--light", "0", "0", "0", "0"], "`--light` '0 0 0 0': its"),
        (["render", "{ball}", "--out", "{tmp}/r.vti", "--max-distance", "nan", "--size", "4"], "`--max-distance`"),
        (
            ["render", "{ball}", "--out", "{tmp}/r.vti", "--eye", "nan", "0", "0", "0", "--target", "0", "0", "0", "0"],
            "`--eye`",
        ),
        (["ao", "{ball}", "--out", "{tmp}/a.npz", "--max-distance", "-1"], "`--max-distance` must be > 0"),
    ],
)
def test_cli_errors_name_the_option(argv, option, ball_file, tmp_path, capsys):
    # the option, not the library's parameter (`point` for `--w nan`, `direction` for `--light nan ...`)
    code, err = _cli([a.format(ball=ball_file, tmp=tmp_path) for a in argv], capsys)
    assert code == 2 and option in err, err
    assert "`point`" not in err and "`direction`" not in err


def test_lut_verify_of_a_missing_folder_says_so(tmp_path, capsys):
    code, err = _cli(["lut", "verify", "--dir", tmp_path / "nope", "--no-rebuild"], capsys)
    assert code == 2 and "`--dir`" in err and "does not exist" in err and "MISMATCH" not in err
    from ao4d.marching import lut

    with pytest.raises(FileNotFoundError, match="`folder` .* does not exist"):
        lut.verify(tmp_path / "nope")


# -- 12. no numpy RuntimeWarning in the command line's output --------------------------------------


@pytest.mark.parametrize(
    "extra, outcome",
    [
        # a reach beyond float32 is unbounded, with no "overflow encountered in cast"
        (["--max-distance", "1e300", "--ao", "hits", "--samples", "2"], 0),
        # only up's direction counts: no overflow, not "parallel to the view direction"
        (["--up", "1e300", "1e300", "0", "0"], 0),
        # points 1e300 apart: the limit named, not "`eye` and `target` must differ" after an overflow
        (["--eye", "0", "0", "0", "1e300", "--target", "0", "0", "0", "0"], "within about 1e150"),
        # the fov is named, not the eye it would frame at 1e302
        (["--fov", "1e-300"], "`--fov` 1e-300 degrees is too narrow"),
    ],
)
def test_render_extremes_warn_nothing(extra, outcome, ball_file, tmp_path, capsys):
    argv = ["render", ball_file, "--out", tmp_path / "r.vti", "--size", "4", "--backend", "numpy", *extra]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        code, err = _cli(argv, capsys)
    if outcome == 0:
        assert code == 0, err
    else:
        assert code == 2 and outcome in err, err


def test_slice_by_a_huge_normal_is_the_slice_by_its_direction(ball_file, tmp_path, capsys):
    # the norm of (1e300, 1e300, 0, 0) overflows float64: the slice is taken by its direction, not "empty"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        code, err = _cli(
            ["slice", ball_file, "--normal", "1e300", "1e300", "0", "0", "--out", tmp_path / "a.ply"], capsys
        )
    assert code == 0, err
    _cli(["slice", ball_file, "--normal", "1", "1", "0", "0", "--out", tmp_path / "b.ply"], capsys)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_screen_space_ao_refuses_more_directions_than_it_can_resolve(ball_file, tmp_path, capsys):
    from ao4d.cli import main
    from ao4d.rendering.screen_ao import MAX_SAMPLES, check_samples

    assert check_samples(MAX_SAMPLES) == MAX_SAMPLES
    with pytest.raises(ValueError, match="`samples` of screen-space AO must be at most 65536"):
        check_samples(MAX_SAMPLES + 1)
    argv = ["render", str(ball_file), "--ao", "screen", "--samples", "10000000", "--size", "16"]
    assert main([*argv, "--out", str(tmp_path / "r.vti")]) == 2
    err = capsys.readouterr().err
    assert "`--samples`" in err and "65536" in err and not (tmp_path / "r.vti").exists()
