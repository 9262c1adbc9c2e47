"""Ambient occlusion and ray casting: analytic 2D/3D/4D cases, Embree, BVH vs brute force,
OpenCL vs numpy, symmetry, grading, convergence and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _scenes import embree_scene, flat_patch, sphere_hull, sphere_over_ground, up_points

import ao4d
from ao4d import ao, bvh, sampling
from ao4d.rays import api, launches
from ao4d.rays import reference as ray_reference

DIMS = (2, 3, 4)


def binomial_tolerance(expected, n_rays, k=4.0):
    # randomised QMC is at least as accurate as i.i.d. sampling: k binomial standard errors
    return k * math.sqrt(max(expected * (1 - expected), 1e-4) / n_rays)


# -- analytic cases ---------------------------------------------------------------------------


@pytest.mark.parametrize("d", DIMS)
def test_open_plane_is_unoccluded(d, backend):
    rng = np.random.default_rng(200 + d)
    mesh = ao4d.SimplexMesh(*flat_patch(d, -1.0, 1.0, 0.0))
    # the vertices of a flat open patch see nothing: exactly zero, no self-hits
    a = ao4d.ambient_occlusion(mesh, samples=64, backend=backend)
    assert (a == 0).all()
    p, n = up_points(rng, d, 50, 0.9)
    assert (ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=64, backend=backend) == 0).all()


def parallel_plane_occlusion(d, h, L):
    """A under an infinite parallel plane at height h, counting hits within L (derivation).

    A ray at angle theta from n meets the plane at distance h / cos(theta); it counts when
    t = cos(theta) >= c = h / L. Under the cosine-weighted density t = sqrt(1 - r^2) with r the
    radius of a uniform point of the unit (d-1)-ball, P(r <= s) = s^(d-1), so
    A = P(r <= sqrt(1 - c^2)) = (1 - c^2)^((d-1)/2): 3D 1 - c^2, 4D (1 - c^2)^(3/2).
    """
    c = min(h / L, 1.0)
    return (1 - c * c) ** ((d - 1) / 2)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("h, L", [(1.0, 2.0), (1.0, 1.25), (0.5, 4.0), (1.0, 0.9)])
def test_parallel_plane(d, h, L, backend):
    rng = np.random.default_rng(300 + d)
    reach = math.sqrt(max(L * L - h * h, 0.0)) + 0.5  # the plane covers every ray hit within L
    mesh = ao4d.SimplexMesh(*flat_patch(d, -reach, reach, h, n=3))
    p, n = up_points(rng, d, 64, 0.2)
    samples = 256
    a = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=samples, max_distance=L, backend=backend)
    # rays start ORIGIN_OFFSET diagonals above the point: the plane is that much closer
    eps = ao.ORIGIN_OFFSET * bvh.get_bvh(mesh).world_diagonal
    expected = parallel_plane_occlusion(d, h - eps, L)
    assert abs(a.mean() - expected) <= binomial_tolerance(expected, a.size * samples)
    if d == 4 and (h, L) == (1.0, 2.0):
        assert expected == pytest.approx((3 / 4) ** 1.5, abs=1e-3)


def wall_occlusion(d, a, L):
    """A at a point with normal e_last from the wall x_0 = a (perpendicular), hits within L.

    The wall is met at distance a / w_0, so the ray counts when w_0 >= c = a / L. The tangential
    part of a cosine-weighted direction is a uniform point b of the unit (d-1)-ball (Malley) and
    w_0 = b_0, so A = P(b_0 >= c) = volume of a ball cap / ball volume:
    2D: (1 - c) / 2; 3D: (arccos c - c sqrt(1 - c^2)) / pi; 4D: (1 - c)^2 (2 + c) / 4.
    """
    c = min(a / L, 1.0)
    if d == 2:
        return (1 - c) / 2
    if d == 3:
        return (math.acos(c) - c * math.sqrt(1 - c * c)) / math.pi
    return (1 - c) ** 2 * (2 + c) / 4


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("a, L", [(0.5, 1.0), (0.2, 2.0), (1.0, 1.5)])
def test_perpendicular_wall(d, a, L, backend):
    rng = np.random.default_rng(400 + d)
    lo = np.full(d - 1, -L - 0.5)
    hi = np.full(d - 1, L + 0.5)
    lo[-1] = -0.1  # the last of the other coordinates is the height
    mesh = ao4d.SimplexMesh(*flat_patch(d, lo, hi, a, n=3, axis=0))
    p = np.zeros((64, d))
    p[:, 1:-1] = rng.uniform(-0.1, 0.1, size=(64, d - 2))  # along the wall: A does not change
    n = np.tile(np.eye(d)[-1], (64, 1))
    samples = 256
    occ = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=samples, max_distance=L, backend=backend)
    expected = wall_occlusion(d, a, L)
    assert abs(occ.mean() - expected) <= binomial_tolerance(expected, occ.size * samples)
    if d == 4:
        # cross-check the closed form with a quadrature of the cap: (3/4) int_c^1 (1 - x^2) dx
        from scipy.integrate import quad

        c = a / L
        assert expected == pytest.approx(0.75 * quad(lambda x: 1 - x * x, c, 1)[0], rel=1e-9)


@pytest.mark.parametrize("d", DIMS)
def test_points_inside_a_closed_surface_are_fully_occluded(d, backend):
    # also the leak test: every ray from inside must hit a simplex, including rays through
    # shared edges and vertices of the hull
    rng = np.random.default_rng(500 + d)
    mesh = ao4d.SimplexMesh(*sphere_hull(rng, d, {2: 30, 3: 200, 4: 300}[d]))
    p = rng.normal(size=(100, d))
    p *= (0.6 * rng.random(100) ** (1 / d) / np.linalg.norm(p, axis=1))[:, None]
    n = rng.normal(size=(100, d))
    a = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=128, backend=backend)
    assert (a == 1.0).all()
    # aimed exactly at the hull's vertices (shared by many simplices): still no leak
    target = mesh.vertices[rng.choice(len(mesh.vertices), 200)]
    hits = api.cast_rays(mesh, np.zeros((200, d)), target, backend=backend)
    assert hits.hit.all()
    np.testing.assert_allclose(hits.t, 1.0, atol=1e-9)  # the vertices lie on the unit sphere
    # from outside, a convex surface does not occlude itself: exactly zero at its vertices
    assert (ao4d.ambient_occlusion(mesh, samples=32, backend=backend) == 0).all()


# -- symmetry, grading, convergence ---------------------------------------------------------


@pytest.mark.parametrize("d", (3, 4))
def test_mirror_symmetric_scene_gives_mirror_symmetric_ao(d, backend):
    rng = np.random.default_rng(600 + d)
    mesh = sphere_over_ground(rng, d, mirrored=True)
    p, n = up_points(rng, d, 150, 1.2)
    mirror = p * np.r_[-1.0, np.ones(d - 1)]
    samples = 128
    a = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=samples, backend=backend)
    b = ao4d.ambient_occlusion(mesh, points=mirror, normals=n, samples=samples, backend=backend, seed=1)
    sigma = math.sqrt(0.25 / samples)  # binomial standard error bound per point
    diff = a - b
    assert np.abs(diff).max() <= 5 * math.sqrt(2) * sigma
    # no systematic left/right bias (the 2021 thesis had one): mean difference within 4 SE
    assert abs(diff.mean()) <= 4 * math.sqrt(2) * sigma / math.sqrt(len(diff))


@pytest.mark.parametrize("d", (3, 4))
def test_ao_near_a_sphere_is_graded(d, backend):
    rng = np.random.default_rng(700 + d)
    mesh = sphere_over_ground(rng, d)
    p, n = up_points(rng, d, 200, 0.8)
    g = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=128, backend=backend)
    inner = g[(g > 0) & (g < 1)]
    # the 2021 thesis' values stuck at 0 or 1; here the ground is shaded smoothly
    assert inner.size >= 0.9 * g.size
    assert len(np.unique(inner)) >= 20
    assert g.max() - g.min() > 0.3
    # closer to the sphere's foot means more occlusion (radial trend)
    r = np.linalg.norm(p[:, :-1], axis=1)
    assert np.corrcoef(r, g)[0, 1] < -0.8
    a = ao4d.ambient_occlusion(mesh, samples=32, backend=backend)  # at the vertices
    assert np.all((a >= 0) & (a <= 1))


def test_error_falls_like_inverse_sqrt_samples(cl_runtime):
    rng = np.random.default_rng(800)
    mesh = sphere_over_ground(rng, 4)
    p, n = up_points(rng, 4, 40, 0.8)
    reference = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=16384, seed=99, backend="opencl")
    counts = np.array([16, 64, 256, 1024])
    errors = [
        np.sqrt(
            np.mean(
                (ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=int(s), backend="opencl") - reference) ** 2
            )
        )
        for s in counts
    ]
    slope = np.polyfit(np.log(counts), np.log(errors), 1)[0]
    # Monte Carlo gives -1/2; the reference's own error (~0.002) only flattens the last point
    assert slope < -0.4, (slope, errors)


# -- backends and trusted tools ---------------------------------------------------------------


def test_ao_matches_embree_with_the_same_directions(backend):
    pytest.importorskip("embreex")
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    rng = np.random.default_rng(1300)
    scene, mesh = embree_scene(rng)
    idx = rng.choice(len(scene.vertices), 300, replace=False)
    p, n = scene.vertices[idx], scene.vertex_normals[idx]
    samples = 64
    ours = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=samples, backend=backend)
    w = sampling.cosine_hemisphere(n, samples).reshape(-1, 3)
    origins = np.repeat(p + ao.ORIGIN_OFFSET * bvh.get_bvh(mesh).world_diagonal * n, samples, axis=0)
    theirs = RayMeshIntersector(scene).intersects_any(origins, w).reshape(-1, samples).mean(1)
    # identical rays: per point at most a couple of grazing rays differ, and no bias
    assert np.abs(ours - theirs).max() <= 3 / samples
    assert abs(ours.mean() - theirs.mean()) <= 1e-3
    assert 0.05 < ours.mean() < 0.95


# -- modes, chunking, bad input ---------------------------------------------------------------


def test_simplex_mode_equals_explicit_centroids():
    rng = np.random.default_rng(1400)
    mesh = sphere_over_ground(rng, 3)
    a = ao4d.ambient_occlusion(mesh, at="simplices", samples=32, backend="numpy")
    assert a.shape == (mesh.n_simplices,)
    b = ao4d.ambient_occlusion(
        mesh, points=mesh.simplex_centroids, normals=mesh.simplex_normals, samples=32, backend="numpy"
    )
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("at", ["vertices", "simplices"])
def test_the_query_points_kept_on_the_mesh_follow_its_changes(at):
    # a repeated call reuses the mesh's normals; a moved vertex must not see stale ones
    mesh = sphere_over_ground(np.random.default_rng(1450), 4)
    first = ao4d.ambient_occlusion(mesh, at=at, samples=16, backend="numpy")
    assert ("ao4d.ao.query_points.vertices" in mesh.cache) == (at == "vertices")  # (S, d) twice: not kept
    np.testing.assert_array_equal(ao4d.ambient_occlusion(mesh, at=at, samples=16, backend="numpy"), first)
    moved = mesh.vertices.copy()
    moved[:, -1] *= 1.5
    mesh.vertices = moved
    fresh = ao4d.SimplexMesh(moved, mesh.simplices)
    again = ao4d.ambient_occlusion(mesh, at=at, samples=16, backend="numpy")
    np.testing.assert_array_equal(again, ao4d.ambient_occlusion(fresh, at=at, samples=16, backend="numpy"))
    assert not np.array_equal(again, first, equal_nan=True)


def one_pass_query_normals(v, s, at):
    """The query normals as AO computed them before it shared the mesh's normals: normals of
    the kept simplices (the degenerate ones zero), summed per vertex corner by corner."""
    from ao4d.bvh.host import nondegenerate
    from ao4d.geometry import simplex_normals

    raw = simplex_normals(v, s)
    raw[~nondegenerate(v, s)] = 0.0
    if at == "simplices":
        return ao._unit(raw)
    total = np.zeros(v.shape)
    for k in range(s.shape[1]):
        ids = np.ascontiguousarray(s[:, k])
        for j in range(v.shape[1]):
            total[:, j] += np.bincount(ids, raw[:, j], len(v))
    return ao._unit(total)


@pytest.mark.parametrize("d", (2, 3, 4))
@pytest.mark.parametrize("at", ("vertices", "simplices"))
@pytest.mark.parametrize("degenerate", (False, True))
@pytest.mark.parametrize("shift", (0.0, 3e6))
def test_query_normals_are_the_bits_of_the_kept_simplices_normals(d, at, degenerate, shift):
    # AO takes the mesh's own normals and vertex sums (shared with its volume and vertex
    # normals) and tests degeneracy from a bound: the rays, and so the counts, must not change
    scene = sphere_over_ground(np.random.default_rng(1470 + d), d)
    v, s = scene.vertices + shift, scene.simplices
    if degenerate:  # zero-measure simplices and slivers at the threshold, which the bound leaves to the full test
        s = s.copy()
        s[:5, -1] = s[:5, 0]
        v = v.copy()
        v[s[5:9, -1]] = v[s[5:9, 0]] + 1e-12 * np.abs(v).max() * np.random.default_rng(d).normal(size=(4, d))
    mesh = ao4d.SimplexMesh(v, s)
    if d == 3:
        mesh.vertex_normals  # noqa: B018 - the sums cached first, as a caller's own use leaves them
    points, normals, defined = ao._query_points(mesh, at, None, None, d)
    expected = one_pass_query_normals(mesh.vertices, mesh.simplices, at)
    length = np.linalg.norm(expected, axis=1)
    assert normals.tobytes() == np.where((length > 0.5)[:, None], expected, 0.0).tobytes()
    np.testing.assert_array_equal(defined, np.isfinite(length) & (length > 0.5))


def test_launch_size_does_not_change_results(monkeypatch, cl_runtime):
    rng = np.random.default_rng(1500)
    mesh = sphere_over_ground(rng, 4)
    whole = ao4d.ambient_occlusion(mesh, samples=32, backend="opencl")
    monkeypatch.setattr(launches, "RAYS_PER_LAUNCH", 1000)
    np.testing.assert_array_equal(whole, ao4d.ambient_occlusion(mesh, samples=32, backend="opencl"))


def test_numpy_step_size_does_not_change_results(monkeypatch):
    rng = np.random.default_rng(1600)
    mesh = sphere_over_ground(rng, 3)
    whole = ao4d.ambient_occlusion(mesh, samples=16, backend="numpy")
    monkeypatch.setattr(ray_reference, "_NUMPY_RAYS_PER_STEP", 100)
    np.testing.assert_array_equal(whole, ao4d.ambient_occlusion(mesh, samples=16, backend="numpy"))


def test_undefined_normals_give_nan():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [2, 0, 0]], dtype=float)
    mesh = ao4d.SimplexMesh(v, [[0, 1, 2], [0, 1, 4], [0, 2, 1]])
    a = ao4d.ambient_occlusion(mesh, samples=8, backend="numpy")
    assert np.isnan(a[3])  # unreferenced vertex
    s = ao4d.ambient_occlusion(mesh, samples=8, at="simplices", backend="numpy")
    assert np.isnan(s[1]) and not np.isnan(s[0])  # (0, 1, 4) is degenerate (collinear)


def test_a_trimesh_or_a_pair_gives_the_ao_of_the_same_simplex_mesh():
    trimesh = pytest.importorskip("trimesh")
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    ground = trimesh.creation.box(extents=(4.0, 4.0, 0.2))
    ground.apply_translation((0, 0, -1.2))
    tm = trimesh.util.concatenate([sphere, ground])
    mesh = ao4d.SimplexMesh(tm.vertices, tm.faces)
    kw = dict(samples=16, seed=3, backend="numpy")
    ref = ao4d.ambient_occlusion(mesh, **kw)
    assert 0 < np.nanmean(ref) < 1  # the ground shades the sphere's underside
    np.testing.assert_array_equal(ao4d.ambient_occlusion(tm, **kw), ref)
    np.testing.assert_array_equal(ao4d.ambient_occlusion((tm.vertices, tm.faces), **kw), ref)
    np.testing.assert_array_equal(
        ao4d.ambient_occlusion([tm.vertices.tolist(), tm.faces.tolist()], at="simplices", **kw),
        ao4d.ambient_occlusion(mesh, at="simplices", **kw),
    )


def test_default_samples_are_renders_and_the_command_lines():
    import inspect

    from ao4d.cli import build_parser

    default = inspect.signature(ao4d.ambient_occlusion).parameters["samples"].default
    assert default == 64 == inspect.signature(ao4d.render).parameters["samples"].default
    assert build_parser().parse_args(["ao", "m.npz", "--out", "a.npz"]).samples == default
    rng = np.random.default_rng(1750)
    mesh = sphere_over_ground(rng, 3)
    p, n = up_points(rng, 3, 4, 0.5)
    np.testing.assert_array_equal(
        ao4d.ambient_occlusion(mesh, points=p, normals=n, backend="numpy"),
        ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=64, backend="numpy"),
    )


def test_bad_inputs():
    rng = np.random.default_rng(1700)
    mesh = sphere_over_ground(rng, 3)
    p, n = up_points(rng, 3, 4, 0.5)
    run = ao4d.ambient_occlusion
    with pytest.raises(ValueError, match="`samples` must be >= 1"):
        run(mesh, samples=0, backend="numpy")
    with pytest.raises(TypeError, match="`samples`"):
        run(mesh, samples=1.5, backend="numpy")
    with pytest.raises(ValueError, match="`normals` has 1 zero-length"):
        run(mesh, points=p, normals=np.r_[n[:3], [[0, 0, 0]]], backend="numpy")
    with pytest.raises(ValueError, match="`points` contains 1 non-finite"):
        run(mesh, points=np.r_[p[:3], [[np.nan, 0, 0]]], normals=n, backend="numpy")
    with pytest.raises(ValueError, match="given together"):
        run(mesh, points=p, backend="numpy")
    with pytest.raises(ValueError, match="same length"):
        run(mesh, points=p, normals=n[:2], backend="numpy")
    with pytest.raises(ValueError, match="`points` must have shape"):
        run(mesh, points=p[:, :2], normals=n[:, :2], backend="numpy")
    with pytest.raises(ValueError, match="`at`"):
        run(mesh, at="corners", backend="numpy")
    with pytest.raises(ValueError, match="`backend`"):
        run(mesh, backend="cuda")
    with pytest.raises(ValueError, match="`accel`"):
        run(mesh, accel="kdtree", backend="numpy")
    with pytest.raises(ValueError, match="`max_distance`"):
        run(mesh, max_distance=0.0, backend="numpy")
    with pytest.raises(ValueError, match="`max_distance`"):
        run(mesh, max_distance=np.nan, backend="numpy")
    with pytest.raises(TypeError, match="`seed`"):
        run(mesh, seed=1.5, backend="numpy")
    with pytest.raises(TypeError, match="`mesh` must be a SimplexMesh, a trimesh.Trimesh"):
        run(np.zeros((3, 3)), backend="numpy")
    with pytest.raises(ValueError, match=r"`mesh` holds no valid mesh: `simplices` must have shape \(S, 3\)"):
        run((mesh.vertices, mesh.simplices[:, :2]), backend="numpy")
    with pytest.raises(ValueError, match="`mesh` has no simplices"):
        run(ao4d.SimplexMesh(np.zeros((0, 4)), np.zeros((0, 4), dtype=int)), backend="numpy")
    with pytest.raises(ValueError, match="all 1 simplices are degenerate"):
        run(ao4d.SimplexMesh(np.eye(3), [[0, 1, 1]]), backend="numpy")
    with pytest.raises(TypeError, match="unexpected keyword"):
        run(mesh, sample=4)  # typo: unknown options are errors


# -- command line -----------------------------------------------------------------------------


def test_cli_stores_ao_and_reports_rate(tmp_path, capsys):
    from ao4d import cli

    rng = np.random.default_rng(1800)
    mesh = sphere_over_ground(rng, 3)
    mesh.save(tmp_path / "scene.npz")
    out = tmp_path / "scene_ao.npz"
    argv = ["ao", str(tmp_path / "scene.npz"), "--samples", "16", "--out", str(out), "--backend", "numpy"]
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "M rays/s" in text and "device: numpy" in text
    stored = ao4d.SimplexMesh.load(out).point_data["ao"]
    np.testing.assert_array_equal(stored, ao4d.ambient_occlusion(mesh, samples=16, backend="numpy"))
    argv = [
        "ao",
        str(tmp_path / "scene.npz"),
        "--at",
        "simplices",
        "--samples",
        "4",
        "--out",
        str(out),
        "--backend",
        "numpy",
    ]
    assert cli.main(argv) == 0
    assert ao4d.SimplexMesh.load(out).cell_data["ao"].shape == (mesh.n_simplices,)


def test_cli_errors_and_help(tmp_path, capsys):
    from ao4d import cli

    assert cli.main(["ao", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "x.npz")]) == 2
    assert "does not exist" in capsys.readouterr().err
    rng = np.random.default_rng(1900)
    sphere_over_ground(rng, 3).save(tmp_path / "s.npz")
    assert cli.main(["ao", str(tmp_path / "s.npz"), "--samples", "0", "--out", str(tmp_path / "x.npz")]) == 2
    assert "--samples" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()
    with pytest.raises(SystemExit):
        cli.main(["ao", "--help"])
    assert "ao4d ao torus.npz --samples 64" in capsys.readouterr().out


# -- extracted 4D surfaces (the 2021 thesis' failure modes) ---------------------------------


def extracted_spheritorus(n):
    field = ao4d.fields.spheritorus(1.0, 0.4)
    # a grid symmetric about x = 0: the extracted vertex set is mirror-symmetric in x
    return ao4d.extract_field(field, (n, n, n, n // 2 + 1), ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))


def mirror_partner(vertices):
    from scipy.spatial import cKDTree

    dist, partner = cKDTree(vertices).query(vertices * np.r_[-1.0, 1, 1, 1])
    assert dist.max() < 1e-9
    return partner


@pytest.mark.parametrize("n, samples", [(13, 64), pytest.param(33, 256, marks=pytest.mark.slow)])
def test_extracted_4d_surface_is_graded_and_mirror_symmetric(cl_runtime, n, samples):
    mesh = extracted_spheritorus(n)
    a = ao4d.ambient_occlusion(mesh, samples=samples, backend="opencl")
    assert np.isfinite(a).all() and (a >= 0).all() and (a <= 1).all()
    # the inner side (towards the hole of the spheritorus) is shaded, with many grey levels
    inner = np.linalg.norm(mesh.vertices[:, :3], axis=1) < 0.9
    assert a[inner].mean() > 0.1
    graded = a[(a > 0) & (a < 1)]
    assert graded.size > 0.1 * a.size and len(np.unique(graded)) > min(samples // 2, 30)
    # mirror x -> -x: per-vertex differences are noise only, no left/right bias
    diff = a - a[mirror_partner(mesh.vertices)]
    sigma = math.sqrt(0.25 / samples)
    assert np.abs(diff).max() <= 5 * math.sqrt(2) * sigma
    assert abs(diff.mean()) <= 4 * math.sqrt(2) * sigma / math.sqrt(diff.size)


@pytest.mark.slow
def test_extracted_4d_surface_numpy_matches_opencl(cl_runtime):
    mesh = extracted_spheritorus(17)
    rng = np.random.default_rng(2000)
    idx = rng.choice(mesh.n_vertices, 400, replace=False)
    p, n = mesh.vertices[idx], mesh.vertex_normals[idx]
    a = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=64, backend="opencl")
    b = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=64, backend="numpy")
    assert np.mean(a == b) >= 0.97 and np.abs(a - b).max() <= 2 / 64
    # points strictly inside the closed solid see only its boundary: fully occluded
    inside = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, 1.2, 0.1], [0.7, 0.7, 0, -0.1]])
    normals = rng.normal(size=inside.shape)
    assert (ao4d.ambient_occlusion(mesh, points=inside, normals=normals, samples=512) == 1).all()


@pytest.mark.parametrize("backend_name", ["numpy", "opencl"])
def test_interrupt_between_launches_leaves_a_usable_state(monkeypatch, request, backend_name):
    if backend_name == "opencl":
        request.getfixturevalue("cl_runtime")
    rng = np.random.default_rng(2100)
    mesh = sphere_over_ground(rng, 3)
    expected = ao4d.ambient_occlusion(mesh, samples=16, backend=backend_name)

    class InterruptingBar:
        calls = 0

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def update(self, n):
            InterruptingBar.calls += 1
            if InterruptingBar.calls == 2:
                raise KeyboardInterrupt  # what Ctrl-C raises after a launch returns

    monkeypatch.setattr(launches, "RAYS_PER_LAUNCH", 500)
    monkeypatch.setattr(ray_reference, "_NUMPY_RAYS_PER_STEP", 500)
    with monkeypatch.context() as patch:
        patch.setattr(ao, "progress_bar", lambda *args: InterruptingBar())
        with pytest.raises(KeyboardInterrupt):
            ao4d.ambient_occlusion(mesh, samples=16, backend=backend_name)
    assert InterruptingBar.calls == 2  # stopped after the first launch, not at the end
    np.testing.assert_array_equal(ao4d.ambient_occlusion(mesh, samples=16, backend=backend_name), expected)


def test_without_opencl_auto_falls_back_and_opencl_is_refused():
    import subprocess
    import sys

    code = (
        "import warnings, numpy as np, ao4d\n"
        "from ao4d import ao\n"
        "mesh = ao4d.SimplexMesh([[0, 0, 1.0], [1, 0, 1], [0, 1, 1]], [[0, 1, 2]])\n"
        "p, n = [[0.2, 0.2, 0.0]], [[0, 0, 1.0]]\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        "    a = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=64)\n"
        "assert any(issubclass(x.category, ao4d.opencl.cl.NoOpenCLDeviceWarning) for x in w), w\n"
        "assert a[0] == ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=64, backend='numpy')[0]\n"
        "try:\n"
        "    ao4d.ambient_occlusion(mesh, points=p, normals=n, backend='opencl')\n"
        "except RuntimeError as exc:\n"
        "    assert 'no OpenCL device' in str(exc), exc\n"
        "else:\n"
        "    raise AssertionError('backend=opencl without a device must fail')\n"
    )
    env = dict(__import__("os").environ, AO4D_DEVICE="none")
    subprocess.run([sys.executable, "-c", code], check=True, env=env)


# -- integer data at an integer level: zero-measure simplices --------------------------------


def _holes_in_a_block(d):
    """Integer values: a solid block (0 < level 2) in an outside frame (5), with single grid
    points exactly at the level inside it (holes of no volume: their simplices all have zero
    measure and touch nothing else) and random level-valued points near its surface."""
    rng = np.random.default_rng(2100 + d)
    n = {2: 14, 3: 9, 4: 7}[d]
    values = np.zeros((n,) * d, dtype=np.int16)
    values[(slice(2, -2),) * d] = 0
    values = np.pad(values, 1, constant_values=5)
    values[(n // 2 + 1,) * d] = 2  # a hole in the middle of the block
    rim = np.zeros(values.shape, dtype=bool)
    rim[(slice(1, -1),) * d] = True
    rim[(slice(2, -2),) * d] = False
    values[rim & (rng.random(values.shape) < 0.3)] = 2  # level values on the surface
    return values


@pytest.mark.parametrize("d", DIMS)
def test_every_vertex_of_integer_data_at_an_integer_level_gets_a_finite_ao(d, backend):
    values = _holes_in_a_block(d)
    mesh = ao4d.extract(values, 2)
    hole = np.flatnonzero(np.all(mesh.vertices == (values.shape[0] // 2,) * d, axis=1))
    assert hole.size and (np.linalg.norm(mesh.vertex_normals[hole], axis=1) == 0).all()
    a = ao4d.ambient_occlusion(mesh, samples=32, backend=backend)
    assert np.isfinite(a).all()
    # the hole lies inside the closed solid: every ray from it hits the block's surface
    np.testing.assert_array_equal(a[hole], 1.0)
    assert ((a >= 0) & (a <= 1)).all()


def test_cli_ao_counts_nan_values_instead_of_printing_their_range(tmp_path, capsys):
    from ao4d import cli

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], dtype=float)
    mesh = ao4d.SimplexMesh(v, [[0, 1, 2], [0, 1, 3]])  # (0, 1, 3) is degenerate (collinear)
    mesh.save(tmp_path / "m.npz")
    argv = [
        "ao",
        str(tmp_path / "m.npz"),
        "--at",
        "simplices",
        "--samples",
        "4",
        "--out",
        str(tmp_path / "o.npz"),
        "--backend",
        "numpy",
    ]
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "1 of 2 values are NaN (no normal: zero-measure simplices)" in text
    assert "the other values: mean" in text and "note: the mesh is open (4 boundary faces)" in text
    assert np.isnan(ao4d.SimplexMesh.load(tmp_path / "o.npz").cell_data["ao"]).sum() == 1


def test_cli_ao_keeps_the_input_files_field_data(tmp_path):
    from ao4d import cli
    from ao4d.io import mesh_files

    rng = np.random.default_rng(2105)
    mesh = sphere_over_ground(rng, 3)
    arrays = mesh_files.MeshArrays(mesh.vertices, mesh.simplices, {}, {})
    mesh_files.write(tmp_path / "in.npz", arrays, field_data={"w_scale": np.float64(0.5)})
    assert (
        cli.main(
            ["ao", str(tmp_path / "in.npz"), "--samples", "2", "--out", str(tmp_path / "out.npz"), "--backend", "numpy"]
        )
        == 0
    )
    assert float(mesh_files.read_field_data(tmp_path / "out.npz")["w_scale"]) == 0.5


def _ball_with_holes(d: int) -> np.ndarray:
    """A ball sampled on a grid (f = |x|^2 - 0.64 on [-1, 1]^d, level 0) with its centre and
    some points next to the surface exactly at the level: zero-measure simplices enclosed by
    the solid (a hole) and on the surface (vertices without a normal of their own)."""
    n = 9
    x = np.linspace(-1.0, 1.0, n)
    values = (np.stack(np.meshgrid(*[x] * d, indexing="ij"), -1) ** 2).sum(-1) - 0.64
    values[(n // 2,) * d] = 0.0
    values[6, 5] = values[2, 3] = values[5, 2] = 0.0  # |x|^2 = 0.625 (d = 3, 4: rows of them)
    return values


@pytest.mark.parametrize("d", (3, 4))
def test_ao_does_not_depend_on_the_scenes_scale(d, backend):
    # the rays of a hole (no normal: both hemispheres) started an offset in the tree's units
    # where world units were meant: AO 0 at scale 1e-6 for a hole that is 1 at 1; flat simplices
    # whose normals are rounding noise after the scaling, and normals whose zero components
    # came back as +-1e-17 (the rays' tangent frame flips with their sign), changed AO too
    samples = 8
    base = ao4d.extract(_ball_with_holes(d), 0.0, spacing=0.25, origin=-1.0)
    hole = np.flatnonzero(np.all(base.vertices == 0.0, axis=1))
    flat = np.flatnonzero(np.linalg.norm(base.vertex_normals, axis=1) == 0)
    assert hole.size and flat.size > hole.size  # level-valued points on the surface too
    rng = np.random.default_rng(3300 + d)
    points = rng.uniform(-1, 1, (40, d))
    normals = rng.normal(size=(40, d))

    def all_paths(scale, at_simplices):
        mesh = ao4d.SimplexMesh(base.vertices * scale, base.simplices)
        kw = dict(samples=samples, backend=backend)
        return (
            ao4d.ambient_occlusion(mesh, **kw),
            ao4d.ambient_occlusion(mesh, points=points * scale, normals=normals, **kw),
            ao4d.ambient_occlusion(mesh, points=points * scale, normals=normals, max_distance=0.5 * scale, **kw),
        ) + ((ao4d.ambient_occlusion(mesh, at="simplices", **kw),) if at_simplices else ())

    reference = all_paths(1.0, True)
    np.testing.assert_array_equal(reference[0][hole], 1.0)
    for scale in (1e-6, 1e-3, 1e3, 1e6):  # the simplices' path (slow on numpy) at the extremes
        for got, want in zip(all_paths(scale, scale in (1e-6, 1e6)), reference):
            np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
            assert np.nanmax(np.abs(got - want)) <= 1 / samples, scale
