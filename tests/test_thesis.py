"""The thesis' scenes, at a small size: AO is graded, and mirror-symmetric scenes render symmetric."""

from __future__ import annotations

import io as stdio

import numpy as np
import pytest

from datasets_gen import thesis

SIZE = 20
SAMPLES = 32


@pytest.fixture(scope="module")
def raw():
    return thesis.raw_scenes()


def test_raw_scenes_are_mirror_symmetric(raw):
    for name, mesh in raw.items():
        mirrored = mesh.vertices * np.array([-1, 1, 1, 1])

        # the set of tetrahedra equals its mirror image (compare sorted corner coordinates)
        def canon(v):
            tets = np.sort(np.round(v[mesh.simplices], 9).reshape(len(mesh.simplices), -1), axis=1)
            return tets[np.lexsort(tets.T)]

        np.testing.assert_allclose(canon(mesh.vertices), canon(mirrored), atol=1e-12, err_msg=name)


@pytest.mark.parametrize("name", ["tetrahedra structure", "indented cubes"])
def test_ao_is_graded(raw, name):
    # the thesis' AO was stuck at 0 or 1; with 32 rays a voxel's estimate is k/32, so a graded
    # AO shows many different k strictly between 0 and 32
    _, with_ao = thesis.render_pair(raw[name], SIZE, samples=SAMPLES, seed=0)
    occ = with_ao.occlusion[with_ao.hit]
    inner = occ[(occ > 0) & (occ < 1)]
    assert occ.size > 200
    assert inner.size > 0.4 * occ.size
    assert np.unique(inner).size >= 10


@pytest.fixture(scope="module")
def closed():
    return thesis.closed_scenes(grid=12)


@pytest.mark.parametrize(
    ("kind", "name"),
    [("raw", "two tetrahedra"), ("raw", "tetrahedra structure"), ("closed", "indented cubes")],
)
def test_mirror_symmetric_scene_renders_symmetric(request, kind, name):
    meshes = request.getfixturevalue(kind)[name]
    plain, with_ao = thesis.render_pair(meshes, SIZE, samples=SAMPLES, seed=1)
    # the camera's eye is in the mirror hyperplane and image axis 0 is world x
    np.testing.assert_allclose(thesis.thesis_camera().basis[0], [1, 0, 0, 0], atol=1e-12)
    mismatch = (with_ao.hit != np.flip(with_ao.hit, axis=0)).sum()
    assert mismatch <= 0.01 * with_ao.hit.sum()  # rays grazing an edge may round either way
    both = with_ao.hit & np.flip(with_ao.hit, axis=0)
    # without AO the picture is deterministic: exact symmetry up to float rounding
    np.testing.assert_allclose(plain.shade[both], np.flip(plain.shade, 0)[both], atol=1e-4)
    diff = (with_ao.occlusion - np.flip(with_ao.occlusion, 0))[both]
    # each AO estimate has standard error <= 0.5 / sqrt(32) = 0.088; a difference of two
    # independent estimates <= 0.125. A left/right bias (the thesis bug) shifts the mean; the
    # mean of n differences has standard error <= 0.125 / sqrt(n): allow 4 of those.
    assert abs(diff.mean()) < 4 * 0.125 / np.sqrt(diff.size)
    assert np.sqrt((diff**2).mean()) < 1.5 * 0.125


def test_closed_scenes_are_closed_and_symmetric():
    scenes = thesis.closed_scenes(grid=10)
    assert set(scenes) == set(thesis.SCENES)
    for name, (left, right) in scenes.items():
        assert left.check().closed and right.check().closed, name
        assert left.volume > 0 and right.volume == pytest.approx(left.volume)
        np.testing.assert_allclose(right.bounds[:, 0], -left.bounds[::-1, 0])


def test_script_writes_volumes_and_png(tmp_path):
    out = tmp_path / "thesis"
    results = thesis.run(out, size=8, samples=4, grid=8, stream=stdio.StringIO())
    assert set(results) == set(thesis.SCENES)
    names = {p.name for p in out.iterdir()}
    assert "thesis_scenes.png" in names
    assert sum(n.endswith(".vti") for n in names) == 18  # 3 scenes x raw/closed x 3 models
    import matplotlib.image

    img = matplotlib.image.imread(out / "thesis_scenes.png")
    assert img[..., :3].std() > 0.05


def test_cli_rejects_bad_size(capsys):
    with pytest.raises(SystemExit):
        thesis.main(["--out", "x", "--size", "1"])
    assert "--size" in capsys.readouterr().err
