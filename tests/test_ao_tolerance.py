"""AO to a stated accuracy (``ambient_occlusion(..., tolerance=)``): coverage on analytic scenes,
determinism across launch sizes, the minimum-sample rule, the standard error and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _scenes import flat_patch

import ao4d
from ao4d import ao, bvh
from ao4d.rays import api, launches, reference

T_7 = 2.364624251592785  # Student's t, 7 degrees of freedom (8 replicates), at 0.975


def roof_scene(d, m, seed):
    """Points under a flat roof at height 1 (a patch wide enough for every ray within reach 1),
    at heights spread so that their exact AO covers (0, 1), with normal +last axis.

    Hits count within ``max_distance = 1``: a ray at angle theta meets the roof at distance
    h / cos(theta), so it counts when cos(theta) >= h. Under the cosine-weighted density
    cos(theta) = sqrt(1 - r^2), r^(d-1) uniform on (0, 1) (Malley), so
    A = (1 - h^2)^((d-1)/2) (the parallel plane of test_ao.py), h measured from the rays' origin.
    """
    rng = np.random.default_rng(seed)
    mesh = ao4d.SimplexMesh(*flat_patch(d, -1.6, 1.6, 1.0, n=2))
    h = rng.uniform(0.02, 0.999, m)
    points = np.zeros((m, d))
    points[:, :-1] = rng.uniform(-0.3, 0.3, (m, d - 1))
    points[:, -1] = 1.0 - h
    normals = np.tile(np.eye(d)[-1], (m, 1))
    eps = ao.ORIGIN_OFFSET * bvh.get_bvh(mesh).world_diagonal
    exact = (1.0 - np.minimum(h - eps, 1.0) ** 2) ** ((d - 1) / 2)
    return mesh, points, normals, exact


def wall_scene(d, m, seed):
    """Points beside a perpendicular wall ``x_0 = a`` (a spread over (0.02, 1.2)), normal +last
    axis, hits within 1: A is the cap of the unit (d-1)-ball beyond ``c = a`` (test_ao.py's
    wall): 3D (arccos c - c sqrt(1 - c^2)) / pi, 4D (1 - c)^2 (2 + c) / 4."""
    rng = np.random.default_rng(seed)
    lo = np.full(d - 1, -2.0)
    hi = np.full(d - 1, 2.0)
    lo[-1] = -0.1
    mesh = ao4d.SimplexMesh(*flat_patch(d, lo, hi, 0.0, n=2, axis=0))
    a = rng.uniform(0.02, 1.2, m)
    points = np.zeros((m, d))
    points[:, 0] = -a
    points[:, 1:-1] = rng.uniform(-0.3, 0.3, (m, d - 2))
    normals = np.tile(np.eye(d)[-1], (m, 1))
    c = np.minimum(a, 1.0)
    if d == 3:
        exact = (np.arccos(c) - c * np.sqrt(1 - c * c)) / math.pi
    else:
        exact = (1 - c) ** 2 * (2 + c) / 4
    return mesh, points, normals, exact


@pytest.mark.parametrize(
    "scene, d, tolerance",
    [(roof_scene, 4, 0.02), (roof_scene, 3, 0.01), (wall_scene, 4, 0.01), (wall_scene, 3, 0.05)],
)
def test_coverage_on_analytic_scenes(scene, d, tolerance):
    # at confidence 0.95, at least 95 % of the points end within the tolerance of the exact AO,
    # seed after seed (measured 97-99 %: the stopping rule looks only a few times, and the
    # replicates' t interval is conservative for these smooth integrands)
    mesh, points, normals, exact = scene(d, 800, 11 * d)
    fractions = []
    for seed in range(4):
        result = ao4d.ambient_occlusion(
            mesh, points=points, normals=normals, max_distance=1.0, tolerance=tolerance, seed=seed, return_error=True
        )
        a, error = result
        assert ((a >= 0) & (a <= 1)).all()
        fractions.append(float(np.mean(np.abs(a - exact) <= tolerance)))
        # the error is the replicates' standard error: a point that stopped before max_samples
        # has a t half-width at most the tolerance
        stopped = result.rays < 4096
        assert stopped.mean() > 0.9
        assert (T_7 * error[stopped] <= tolerance * (1 + 1e-12)).all()
    print(f"{scene.__name__} {d}D tolerance {tolerance}: within", fractions)
    assert min(fractions) >= 0.95, fractions


def test_rays_go_where_the_ao_is_hard():
    mesh, points, normals, exact = roof_scene(4, 400, 5)
    result = ao4d.ambient_occlusion(
        mesh, points=points, normals=normals, max_distance=1.0, tolerance=0.02, return_error=True
    )
    fewest = ao.minimum_samples(0.02)
    # open points (h near 1: A near 0) stop at the minimum; half-occluded ones take more
    assert (result.rays[exact < 1e-3] == fewest).all()
    middle = (exact > 0.3) & (exact < 0.7)
    assert result.rays[middle].mean() > fewest
    assert (result.rays % ao.REPLICATES == 0).all() and (result.rays <= 4096).all()


@pytest.mark.parametrize("tolerance, confidence, expected", [(0.01, 0.95, 299), (0.02, 0.95, 149), (0.05, 0.99, 90)])
def test_minimum_samples_rule(tolerance, confidence, expected):
    # N = ceil(log(1 - confidence) / log(1 - tolerance)): N rays all escaping bound the hit
    # fraction below the tolerance at that confidence, (1 - tolerance)^N <= 1 - confidence
    assert (1 - tolerance) ** expected <= 1 - confidence < (1 - tolerance) ** (expected - 1)
    fewest = ao.minimum_samples(tolerance, confidence)
    assert fewest == ao.REPLICATES * max(ao.MIN_POINTS, -(-expected // ao.REPLICATES))
    # an open point (nothing to hit) traces exactly the minimum; so does one fully occluded
    mesh = ao4d.SimplexMesh(*flat_patch(3, -50, 50, 1.0, n=1))
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    result = ao4d.ambient_occlusion(
        mesh, points=points, normals=normals, tolerance=tolerance, confidence=confidence, return_error=True
    )
    assert result.rays.tolist() == [fewest, fewest]
    assert result.occlusion[1] == 0.0 and result.error[1] == 0.0
    assert result.occlusion[0] > 0.99  # the 100-wide roof 1 above: A = 1 - 1 / (1 + 50^2)


def test_same_bytes_whatever_the_launch_size(monkeypatch, backend):
    rng = np.random.default_rng(7)
    from _scenes import sphere_over_ground

    mesh = sphere_over_ground(rng, 4)
    kw = dict(tolerance=0.05, seed=3, return_error=True, backend=backend)
    whole = ao4d.ambient_occlusion(mesh, **kw)
    monkeypatch.setattr(launches, "RAYS_PER_LAUNCH", 1000)
    monkeypatch.setattr(reference, "_NUMPY_RAYS_PER_STEP", 100)
    again = ao4d.ambient_occlusion(ao4d.SimplexMesh(mesh.vertices, mesh.simplices), **kw)
    for x, y in zip((*whole, whole.rays), (*again, again.rays)):
        assert x.tobytes() == y.tobytes()
    assert np.unique(whole.rays).size > 1  # points stopped in different rounds


def test_a_points_rays_depend_on_its_index_only(backend):
    # the rounds trace only the points still going: each keeps the rays of its own index
    rng = np.random.default_rng(9)
    from _scenes import sphere_over_ground, up_points

    mesh = sphere_over_ground(rng, 4)
    p, n = up_points(rng, 4, 50, 0.8)
    runtime = ao4d.opencl.cl.resolve_backend(backend)
    trace = dict(samples=24, seed=5, offset=1e-4, max_distance=math.inf, runtime=runtime)
    every = api.count_occluded(mesh, p, n, **trace)
    some = np.arange(1, 50, 3)
    assert (api.count_occluded(mesh, p[some], n[some], **trace, index=some) == every[some]).all()
    # and a later call continues the sequence: rows 0-9 then 10-23 are the 24 rows
    head = api.count_occluded(mesh, p, n, **{**trace, "samples": 10})
    tail = api.count_occluded(mesh, p, n, **{**trace, "samples": 14}, first=10)
    assert (head + tail == every).all()


def test_tolerance_none_keeps_the_fixed_samples_bytes():
    rng = np.random.default_rng(8)
    from _scenes import sphere_over_ground

    mesh = sphere_over_ground(rng, 3)
    plain = ao4d.ambient_occlusion(mesh, samples=32, backend="numpy")
    a, error = ao4d.ambient_occlusion(mesh, samples=32, backend="numpy", return_error=True)
    assert a.tobytes() == plain.tobytes()
    # fixed samples: the standard error of independent rays
    np.testing.assert_array_equal(error, np.sqrt(a * (1 - a) / 32))


def test_points_that_reach_max_samples_report_their_error():
    mesh, points, normals, exact = roof_scene(3, 40, 9)
    middle = (exact > 0.3) & (exact < 0.7)
    result = ao4d.ambient_occlusion(
        mesh,
        points=points[middle],
        normals=normals[middle],
        max_distance=1.0,
        tolerance=0.002,
        max_samples=ao.minimum_samples(0.002) + 8,
        return_error=True,
    )
    assert (result.rays == ao.minimum_samples(0.002) + 8).all()
    assert (result.error > 0).all() and (T_7 * result.error > 0.002).any()


def test_vertices_without_a_normal_get_an_ao_and_an_error():
    # integer data at an integer level (test_ao.py): zero-measure simplices, a hole of no volume
    values = np.zeros((6, 6, 6), dtype=np.int16)
    values = np.pad(values, 1, constant_values=5)
    values[4, 4, 4] = 2  # the hole: no normal and no neighbour with one
    rim = np.zeros(values.shape, dtype=bool)
    rim[1:-1, 1:-1, 1:-1] = True
    rim[2:-2, 2:-2, 2:-2] = False
    values[rim & (np.random.default_rng(3).random(values.shape) < 0.3)] = 2
    mesh = ao4d.extract(values, 2)
    result = ao4d.ambient_occlusion(mesh, tolerance=0.05, return_error=True)
    assert np.isfinite(result.occlusion).all() and np.isfinite(result.error).all()
    hole = np.flatnonzero(np.all(mesh.vertices == 4, axis=1))
    assert hole.size and (result.occlusion[hole] == 1.0).all()  # both hemispheres: enclosed
    assert (result.rays[hole] == 2 * ao.minimum_samples(0.05)).all()


def test_bad_inputs():
    mesh = ao4d.SimplexMesh(*flat_patch(3, -1, 1, 1.0, n=1))
    for bad in (0, 0.0, -0.1, 1, 1.5):
        with pytest.raises(ValueError, match="`tolerance` must be in \\(0, 1\\)"):
            ao4d.ambient_occlusion(mesh, tolerance=bad)
    with pytest.raises(ValueError, match="`tolerance` must be finite"):
        ao4d.ambient_occlusion(mesh, tolerance=math.nan)
    for bad in (0, 1, 1.2, -0.5):
        with pytest.raises(ValueError, match="`confidence` must be in \\(0, 1\\)"):
            ao4d.ambient_occlusion(mesh, tolerance=0.05, confidence=bad)
    with pytest.raises(TypeError, match="`tolerance` must be a real number"):
        ao4d.ambient_occlusion(mesh, tolerance="0.1")
    fewest = ao.minimum_samples(0.01)
    with pytest.raises(ValueError, match=f"`max_samples` must be >= {fewest} for tolerance=0.01"):
        ao4d.ambient_occlusion(mesh, tolerance=0.01, max_samples=fewest - 1)
    with pytest.raises(TypeError, match="`max_samples` must be an integer"):
        ao4d.ambient_occlusion(mesh, tolerance=0.01, max_samples=1000.0)
    with pytest.raises(ValueError, match="give `samples` \\(128\\) or `tolerance`"):
        ao4d.ambient_occlusion(mesh, samples=128, tolerance=0.05)
    with pytest.raises(TypeError, match="`return_error` must be True or False"):
        ao4d.ambient_occlusion(mesh, return_error=1)
    with pytest.raises(ValueError, match="`max_samples`=40960 at 4 points \\(at worst\\)"):
        ao4d.ambient_occlusion(mesh, tolerance=0.05, max_samples=40960, max_rays=1e5)
    with pytest.raises(ValueError, match="`tolerance`"):
        ao.minimum_samples(1.0)


def test_cli_tolerance_writes_the_error(tmp_path, capsys):
    from ao4d.cli import main
    from ao4d.io.mesh_files import read

    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (10,) * 4, (-1.3, 1.3))
    path = tmp_path / "ball.npz"
    mesh.save(path)
    out = tmp_path / "ao.npz"
    assert main(["ao", str(path), "--tolerance", "0.05", "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "tolerance 0.05" in text
    arrays = read(out)
    assert set(arrays.point_data) >= {"ao", "ao_error"}
    assert np.nanmax(arrays.point_data["ao_error"]) * T_7 <= 0.05
    # bad values name the command's options
    assert main(["ao", str(path), "--tolerance", "2", "--out", str(out)]) != 0
    assert "`--tolerance` must be in (0, 1)" in capsys.readouterr().err
    assert main(["ao", str(path), "--tolerance", "0.01", "--max-samples", "100", "--out", str(out)]) != 0
    assert "`--max-samples` must be >= 304" in capsys.readouterr().err
    assert main(["ao", str(path), "--tolerance", "0.05", "--samples", "16", "--out", str(out)]) != 0
    assert "`--samples`" in capsys.readouterr().err


def test_dataset_config_ao_tolerance(tmp_path):
    from _datasets import config, family

    from datasets_gen import ConfigError, load_config, run

    def cfg(ao):
        return config("tol", 1, [family("hypersphere", 1, {"radius": 0.8})], grid=10, ao=ao)

    settings = load_config(cfg({"tolerance": 0.05})).families[0].settings["ao"]
    assert settings["tolerance"] == 0.05
    for ao_table, match in (
        ({"tolerance": 0.05, "samples": 32}, "give `ao.samples` or `ao.tolerance`, not both"),
        ({"tolerance": 1.0}, r"`ao.tolerance` must be a number in \(0, 1\), got 1.0"),
        ({"tolerance": 0.05, "confidence": 0}, r"`ao.confidence` must be a number in \(0, 1\)"),
        ({"tolerance": 0.01, "max_samples": 100}, r"`ao.max_samples` must be an integer in \[304, 65536\]"),
        ({"confidence": 0.9}, "`ao.confidence` is used only with `ao.tolerance`"),
    ):
        with pytest.raises(ConfigError, match=match):
            load_config(cfg(ao_table))
    # an item's ao.npz holds the standard errors beside the values
    run(cfg({"tolerance": 0.1}), out=tmp_path / "ds", progress=False)
    with np.load(next((tmp_path / "ds").rglob("ao.npz"))) as f:
        assert set(f.files) == {"occlusion", "error"}
        assert np.isfinite(f["error"]).all() and (f["error"] * T_7 <= 0.1).all()
