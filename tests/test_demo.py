"""`ao4d demo` end to end at a tiny size, and the render/slice subcommands on its files."""

from __future__ import annotations

import numpy as np
import pytest

from ao4d import cli
from ao4d.io import volumes as io
from ao4d.mesh import SimplexMesh

EXPECTED = [
    "scene.npz",
    "image.mhd",
    "image.raw",
    "image.vti",
    "image_slices.png",
    "image_volume.png",
    "image_color_slices.png",
    "image_color_volume.png",
    "slice_w0.ply",
    "slice_w0.glb",
    "slice_w0.png",
    "view.html",
]


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert cli.main(["demo", "--tiny", "--out", str(out)]) == 0
    return out


def _not_blank(path):
    import matplotlib.image

    return matplotlib.image.imread(path)[..., :3].std() > 0.05


def test_demo_writes_every_file(demo_dir):
    assert sorted(p.name for p in demo_dir.iterdir()) == sorted(EXPECTED)
    vol = io.read_mhd(demo_dir / "image.mhd")
    assert vol.data.shape == (26, 10, 16) and vol.data.dtype == np.float32
    # shade = 0.4 (1 - AO) + 0.3 Lambert + 0.3 specular lies in [0, 1]; some voxels hit, some not
    assert 0.0 <= vol.data.min() and vol.data.max() <= 1.0 + 1e-6
    assert 0 < (vol.data > 0).mean() < 1
    ids = io.read_vti(demo_dir / "image.vti", array="object_id").data
    assert set(np.unique(ids)) <= {-1, 0, 1, 2, 3} and len(np.unique(ids)) >= 3
    for png in (
        "image_slices.png",
        "image_volume.png",
        "image_color_slices.png",
        "image_color_volume.png",
        "slice_w0.png",
    ):
        assert _not_blank(demo_dir / png), png


@pytest.mark.parametrize("quality", ["tiny", "default", "high"])
def test_default_scene_fits_in_the_demo_image(quality):
    # every object appears whole: its mesh's vertices project inside the image box (voxel
    # centres +- half a voxel) of the shape the demo renders at that quality
    from ao4d.mesh import concatenate
    from ao4d.scenes import QUALITY, default_scene, extract_scene

    scene = default_scene()
    mesh = concatenate(extract_scene(scene, cell=0.2, progress=False))
    geo = scene.camera.geometry(QUALITY[quality]["image"])
    lo = np.asarray(geo.origin) - geo.spacing / 2
    hi = lo + geo.spacing * np.asarray(geo.shape)
    where = scene.camera.project(mesh.vertices)
    assert (where > lo).all() and (where < hi).all()
    # and the box is not mostly empty: the scene reaches within 10 % of each side along x and z
    span = hi - lo
    assert (where.min(axis=0) - lo)[[0, 2]].max() < 0.1 * span[[0, 2]].min()


def test_demo_scene_has_graded_ao_and_object_ids(demo_dir):
    scene = SimplexMesh.load(demo_dir / "scene.npz")
    assert scene.dim == 4 and scene.check().closed
    ao = scene.point_data["ao"]
    assert ao.min() >= 0 and ao.max() <= 1
    assert ((ao > 0) & (ao < 1)).mean() > 0.05  # contacts and the indent are partly occluded
    assert set(np.unique(scene.cell_data["object_id"])) == {0, 1, 2, 3}


def test_demo_prints_summary(tmp_path, capsys):
    import io as stdio

    from ao4d.commands.demo import run_demo

    stream = stdio.StringIO()
    report = run_demo(tmp_path / "d", quality="tiny", progress=False, stream=stream)
    text = stream.getvalue()
    for word in ("hypersphere", "torisphere", "indented tesseract", "M rays/s", "wall time"):
        assert word in text
    assert report.ao_rays == sum(o[1] for o in report.objects) * 8  # tiny: 8 samples per vertex
    assert report.rays_per_second > 0
    assert all(p.exists() for p in report.files)


def test_render_and_slice_commands(demo_dir, tmp_path, capsys):
    out = tmp_path / "r.vti"
    assert (
        cli.main(
            ["render", str(demo_dir / "scene.npz"), "--out", str(out), "--size", "12", "10", "8", "--ao", "vertices"]
        )
        == 0
    )
    vol = io.read_vti(out)
    assert vol.data.shape == (12, 10, 8) and (vol.data > 0).any()
    ply = tmp_path / "s.ply"
    assert cli.main(["slice", str(demo_dir / "scene.npz"), "--w", "0.1", "--out", str(ply)]) == 0
    import trimesh

    tri = trimesh.load(ply, process=False)
    assert len(tri.faces) > 100
    # the slice's coordinates are world x, y, z: the top of the hypersphere (centre y = 0.75,
    # radius 0.75) at w = 0.1 is y = 0.75 + sqrt(0.75^2 - 0.1^2) = 1.493; the tiny grid
    # (cell 0.2) cuts chords at most 0.2^2 / (2 * 0.75) = 0.027 below the sphere
    assert tri.vertices[:, 1].max() == pytest.approx(1.493, abs=0.03)


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["render", "nope.npz", "--out", "x.mhd"], "nope.npz"),
        (["render", "{scene}", "--out", "x.mhd", "--size", "4", "4"], "--size"),
        (["render", "{scene}", "--out", "x.nii"], "must end in .vti or .mhd"),
        (["render", "{scene}", "--out", "x.mhd", "--eye", "0", "0", "0", "-4"], "--eye"),
        (["slice", "{scene}", "--w", "99", "--out", "s.ply"], "misses the mesh"),
    ],
)
def test_command_errors(demo_dir, tmp_path, capsys, argv, match):
    argv = [a.replace("{scene}", str(demo_dir / "scene.npz")) for a in argv]
    argv = [str(tmp_path / a) if a.endswith((".mhd", ".nii", ".ply")) else a for a in argv]
    assert cli.main(argv) == 2
    assert match in capsys.readouterr().err


@pytest.mark.parametrize("command", ["demo", "render", "slice"])
def test_help_shows_examples(command, capsys):
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = capsys.readouterr().out
    assert "examples:" in text and f"ao4d {command}" in text


@pytest.mark.slow
def test_demo_default_quality(tmp_path):
    # the README's command at its real settings (about 30 s on 2 cores)
    import io as stdio

    from ao4d.commands.demo import run_demo

    report = run_demo(tmp_path, quality="default", progress=False, stream=stdio.StringIO())
    assert report.image_shape == (132, 48, 80)
    scene = SimplexMesh.load(tmp_path / "scene.npz")
    assert scene.check().closed
    ao = scene.point_data["ao"]
    # 64 samples per vertex: values k/64, graded between open (0) and contact (near 1)
    assert np.unique(ao).size > 20
    vol = io.read_vti(tmp_path / "image.vti", array="occlusion").data
    assert np.nanmax(vol) > 0.3 and np.nanmin(vol) < 0.05


def test_demo_times_every_file_step_and_the_times_add_up(tmp_path, monkeypatch):
    # the "files" stage is split per step, each measured once: the steps sum to the stage, and a
    # step made slow shows up under its own name
    import io as stdio
    import time

    from ao4d.commands.demo import run_demo
    from ao4d.rendering import pipeline as rendering

    real = rendering.write_mhd

    def slow_mhd(*args, **kwargs):  # a step that takes ~10 ms, made to take 0.5 s
        time.sleep(0.5)
        return real(*args, **kwargs)

    monkeypatch.setattr(rendering, "write_mhd", slow_mhd)
    stream = stdio.StringIO()
    report = run_demo(tmp_path / "d", quality="tiny", progress=False, stream=stream)
    steps = report.file_seconds
    assert {"image.vti", "montage", "volume picture", "slice picture", "view.html"} <= set(steps)
    assert sum(steps.values()) == pytest.approx(report.stage_seconds["files"], abs=0.05)
    assert steps["image.mhd"] >= 0.5 and steps["image.vti"] < steps["image.mhd"]
    assert "files stage: " in stream.getvalue() and "image.mhd " in stream.getvalue()
