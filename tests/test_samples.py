"""Tests for datasets_gen.samples: labelled points against analytic volumes and distances,
surface points uniform by 3-volume on the mesh, provenance, reproducibility, bad settings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ao4d._npz import npz_bytes
from datasets_gen import ConfigError
from datasets_gen.config import _parse
from datasets_gen.families import build_shape, random_rotation
from datasets_gen.samples import (
    _simplex_distance,
    check_samples,
    corners_distance,
    make_samples,
    mesh_distance,
    normalization,
)

SETTINGS = {
    "grid": 12,
    "method": "cubes",
    "padding": 0.15,
    "bounds": None,
    "rotation": "random",
    "tetrahedra": "star",
    "ao": False,
    "renders": [],
}


def _shape(kind, params, rotate=True, **settings):
    rotation = random_rotation(np.random.default_rng(5)) if rotate else None
    return build_shape(kind, params, {**SETTINGS, **settings}, np.random.default_rng(1), rotation)


def _samples(shape, kind, seed=0, **counts):
    cfg = check_samples({"uniform": 20000, "near_surface": 2000, "sigmas": [0.01, 0.05], "surface": 4000, **counts})
    return make_samples(shape, kind, cfg, np.random.default_rng(seed), backend="numpy")


def _binomial_tolerance(p, n, k=5.0):
    return k * math.sqrt(max(p * (1 - p), 1e-4) / n)


def test_occupancy_matches_the_analytic_volume_from_the_field():
    shape = _shape("hypersphere", {"radius": 0.8})
    arrays, record = _samples(shape, "hypersphere")
    lo, hi = (np.array(b) for b in record["box"])
    n = record["uniform"]
    frac = arrays["occupancy"][:n].mean()
    expected = math.pi**2 * 0.8**4 / 2 / np.prod(hi - lo)
    assert abs(frac - expected) <= _binomial_tolerance(expected, n)
    # the uniform points fill the box
    pts = arrays["points"][:n]
    assert (pts >= lo.astype(np.float32) - 1e-6).all() and (pts <= hi.astype(np.float32) + 1e-6).all()
    assert record["labels"]["occupancy"] == "field" and record["labels"]["sdf"] == "exact"
    # exact signed distance of the ball
    r = np.linalg.norm(arrays["points"].astype(np.float64), axis=1) - 0.8
    np.testing.assert_allclose(arrays["sdf"], r, atol=1e-6)


def test_mesh_labels_of_a_lifted_box_match_the_4d_box():
    # a prism of a 3D box of half-size 0.4 and height 1: exactly the 4D box [-.4,.4]^3 x [-.5,.5]
    shape = _shape("lifted", {"shape": "box", "op": "prism", "size": 0.4, "height": 1.0}, rotate=False)
    arrays, record = _samples(shape, "lifted", uniform=4000, near_surface=500, surface=4000)
    assert record["labels"]["occupancy"] == "mesh" and record["labels"]["sdf"] == "mesh"
    half = np.array([0.4, 0.4, 0.4, 0.5])
    p = arrays["points"].astype(np.float64)
    q = np.abs(p) - half
    box_sdf = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    inside = box_sdf < 0
    clear = np.abs(box_sdf) > 1e-6
    np.testing.assert_array_equal(arrays["occupancy"][clear], inside[clear])
    np.testing.assert_allclose(arrays["sdf"], box_sdf, atol=1e-6)
    lo, hi = (np.array(b) for b in record["box"])
    n = record["uniform"]
    expected = np.prod(2 * half) / np.prod(hi - lo)
    assert abs(arrays["occupancy"][:n].mean() - expected) <= _binomial_tolerance(expected, n)
    # surface points uniform by 3-volume: the caps |w| = 0.5 hold 2 * 0.8^3 of the boundary
    s = arrays["surface_points"].astype(np.float64)
    on_cap = np.abs(np.abs(s[:, 3]) - 0.5) < 1e-6
    share = 2 * 0.8**3 / (2 * 0.8**3 + 6 * 0.8**2 * 1.0)
    assert abs(on_cap.mean() - share) <= _binomial_tolerance(share, len(s))
    # normals outward unit: the cap points' normals are +-w
    np.testing.assert_allclose(np.linalg.norm(arrays["surface_normals"], axis=1), 1, atol=1e-6)
    np.testing.assert_allclose(arrays["surface_normals"][on_cap, 3], np.sign(s[on_cap, 3]), atol=1e-6)


def test_sdf_sign_and_occupancy_never_disagree():
    for kind, params in (("hypersphere", {"radius": 0.7}), ("metaballs", {"n": 2, "spread": 0.3, "radius": 0.4})):
        shape = _shape(kind, params)
        arrays, _ = _samples(shape, kind, uniform=1500, near_surface=300, surface=10)
        np.testing.assert_array_equal(arrays["sdf"] < 0, arrays["occupancy"])
        assert arrays["points"].shape == (1500 + 600, 4) and arrays["points"].dtype == np.float32


def test_surface_points_lie_on_the_mesh_near_the_level_set():
    shape = _shape("spheritorus", {"R": 0.7, "r": 0.3})
    arrays, _ = _samples(shape, "spheritorus", uniform=10, near_surface=10, surface=3000)
    spacing = max(shape.grid["spacing"])
    level = shape.field(arrays["surface_points"].astype(np.float64))
    assert np.abs(level).max() < spacing
    # and on the mesh itself: distance 0 up to float32 rounding
    d = mesh_distance(shape.mesh, arrays["surface_points"][:200].astype(np.float64))
    assert d.max() < 1e-6


def test_mesh_distance_is_the_brute_force_minimum():
    shape = _shape("metaballs", {"n": 2, "spread": 0.3, "radius": 0.4}, grid=8)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.2, 1.2, (40, 4))
    corners = shape.mesh.vertices[shape.mesh.simplices]
    brute = np.array([_simplex_distance(np.repeat(p[None], len(corners), 0), corners).min() for p in pts])
    np.testing.assert_allclose(mesh_distance(shape.mesh, pts), brute, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("dim", [3, 4])
def test_distance_to_a_simplex_with_two_corners_a_rounding_apart(dim):
    # a triangle of a tiger's w-slice (seed 0) whose last two corners differ by one rounding:
    # the edge between them is noise, and the distance is the one to the segment the triangle
    # is, 0.0539; the Gram matrix built from products once called that edge well conditioned
    # and returned 0
    a = [1.0071536576491131, -0.14628032446430517, -0.9264420549405992]
    b = [1.0096871698409942, -0.04876010815476861, -0.8289218386310628]
    twin = [1.0096871698409942, -0.04876010815476861, -0.8289218386310626]
    p = np.array([1.0623382329940796, -0.09539888799190521, -0.876648485660553] + [0.25] * (dim - 3))
    corners = np.array([a, b, twin] + [[1.0, -0.1, -0.9]] * (dim - 3), float)
    if dim == 4:  # the triangle in the hyperplane w = 0.25, plus a fourth corner off it
        corners = np.hstack([corners, [[0.25], [0.25], [0.25], [0.9]]])
        corners[3, :3] = corners[0, :3]
    a_, b_ = corners[0], corners[1]
    t = np.clip((p - a_) @ (b_ - a_) / ((b_ - a_) @ (b_ - a_)), 0, 1)
    segment = np.linalg.norm(a_ + t * (b_ - a_) - p)
    want = segment if dim == 3 else min(segment, _simplex_distance(p[None], corners[None])[0])
    assert want > 0.05
    assert corners_distance(corners[None], p[None])[0] == pytest.approx(want, rel=1e-9)


def test_triangle_distances_against_trimesh_with_slivers():
    # 3D frames: exact distances to triangles, also where a few long slivers widen the search
    import trimesh

    mesh = trimesh.creation.torus(0.6, 0.25, major_sections=48, minor_sections=16)
    slivers = np.array(
        [[[-0.9, 0.0, 0.0], [0.9, 0.0, 0.01], [0.9, 0.02, 0.0]], [[0, -1, 0.3], [0, 1, 0.3], [0, 1, 0.31]]]
    )
    corners = np.concatenate([mesh.vertices[mesh.faces], slivers])
    rng = np.random.default_rng(2)
    pts = np.concatenate([rng.uniform(-1.2, 1.2, (300, 3)), mesh.sample(100, seed=1) + rng.normal(0, 0.01, (100, 3))])
    # brute force: trimesh's closest point on every triangle, the least distance per point
    near = [trimesh.triangles.closest_point(corners, np.repeat(p[None], len(corners), 0)) for p in pts]
    want = np.array([np.linalg.norm(c - p, axis=1).min() for c, p in zip(near, pts)])
    np.testing.assert_allclose(corners_distance(corners, pts), want, rtol=1e-9, atol=1e-12)


def test_point_to_tetrahedron_distance_cases():
    tet = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], float)[None]
    cases = {
        (0.2, 0.2, 0.2, 0.0): 0.0,
        (0.2, 0.2, 0.2, 0.5): 0.5,
        (-1, 0, 0, 0): 1.0,
        (2, 0, 0, 0): 1.0,
        (1, 1, 1, 0): math.sqrt(3) - 1 / math.sqrt(3),
    }
    for p, want in cases.items():
        assert _simplex_distance(np.array([p], float), tet)[0] == pytest.approx(want, abs=1e-12)


def test_near_surface_rows_follow_each_sigma_in_order():
    shape = _shape("hypersphere", {"radius": 0.8})
    arrays, record = _samples(shape, "hypersphere", uniform=100, near_surface=3000, sigmas=[0.01, 0.05])
    diag = record["offset_scale"]
    r = np.linalg.norm(arrays["points"].astype(np.float64), axis=1) - 0.8
    for sigma, (a, b) in zip([0.01, 0.05], [record["rows"]["sigma=0.01"], record["rows"]["sigma=0.05"]]):
        # offsets are 4D Gaussians of std sigma*diag; their radial part has that std too
        assert np.std(r[a:b]) == pytest.approx(sigma * diag, rel=0.1, abs=0.05 * sigma * diag + 0.01 * 0.8 / 12)


def test_same_seed_same_bytes_and_another_seed_differs():
    shape = _shape("hypersphere", {"radius": 0.8})
    a = npz_bytes(_samples(shape, "hypersphere", seed=4, uniform=500)[0])
    b = npz_bytes(_samples(shape, "hypersphere", seed=4, uniform=500)[0])
    c = npz_bytes(_samples(shape, "hypersphere", seed=5, uniform=500)[0])
    assert a == b and a != c


def test_surface_ao_interpolates_the_vertex_occlusion():
    shape = _shape("hypersphere", {"radius": 0.8})
    occ = shape.mesh.vertices[:, 0].copy()  # a linear function: interpolation is exact
    cfg = check_samples({"uniform": 10, "near_surface": 0, "sigmas": [], "surface": 100})
    arrays, record = make_samples(shape, "hypersphere", cfg, np.random.default_rng(0), occlusion=occ)
    np.testing.assert_allclose(arrays["surface_ao"], arrays["surface_points"][:, 0], atol=1e-6)
    assert record["labels"]["surface_ao"] == "mesh"


def test_normalization_maps_the_mesh_into_the_unit_ball():
    shape = _shape("spheritorus", {"R": 0.7, "r": 0.3})
    norm = normalization(shape.mesh)
    v = (shape.mesh.vertices - norm["loc"]) / norm["scale"]
    assert np.linalg.norm(v, axis=1).max() == pytest.approx(1.0)


@pytest.mark.parametrize(
    "samples, message",
    [
        ("{ uniform = 10, bogus = 1 }", "unknown key.*'bogus'"),
        ("{ uniform = -1 }", r"samples.uniform.*\[0,"),
        ("{ surface = 1.5 }", "samples.surface"),
        ("{ sigmas = [0.01, 0] }", r"samples.sigmas.*> 0"),
        ("{ sigmas = [-0.1] }", r"samples.sigmas.*> 0"),
        ("{ near_surface = 10, sigmas = [] }", "needs at least one sigma"),
        ("{ uniform = 0, near_surface = 0, surface = 0 }", "no points"),
        ("7", "must be a table"),
    ],
)
def test_bad_samples_settings_are_clear_config_errors(samples, message):
    import tomllib

    text = f'[defaults]\nsamples = {samples}\n[[family]]\nkind = "hypersphere"\n'
    with pytest.raises(ConfigError, match=message):
        _parse(tomllib.loads(text), text, "t.toml")


def test_samples_true_means_the_defaults():
    assert check_samples(True)["uniform"] == 16384 and check_samples(False) is False


def test_the_shipped_training_config_asks_for_exact_labels():
    from datasets_gen import load_config
    from datasets_gen.samples import EXACT_SDF_KINDS

    cfg = load_config("training")
    assert cfg.split == {"train": 0.8, "val": 0.1, "test": 0.1}
    for fam in cfg.families:
        assert fam.kind in EXACT_SDF_KINDS and fam.settings["samples"]["uniform"] == 16384
        assert fam.settings["sequence"] == {"frames": 17, "axis": "w"}
