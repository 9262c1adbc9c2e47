"""Tests for ao4d.rays: closest and any hits on both backends, BVH against brute force, Embree.

Hits are compared with brute force over every simplex, between OpenCL (float32) and numpy
(float64), and with Embree (trimesh + embreex) on the same 3D rays.
"""

from __future__ import annotations

import numpy as np
import pytest
from _scenes import embree_scene, flat_patch, random_rays, random_soup, soup_scene, sphere_over_ground, up_points
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import ao4d
from ao4d import bvh
from ao4d.opencl import cl
from ao4d.rays import api, reference
from ao4d.rays import launches as ray_launches
from ao4d.rays import refine as ray_refine
from ao4d.rays import rows as ray_rows

DIMS = (2, 3, 4)


def _shifted_soup(seed, d, shift):
    """A random simplex soup and 3000 random rays, both moved by ``shift`` along every axis."""
    rng = np.random.default_rng(seed)
    mesh = soup_scene(rng, d)
    o, w = random_rays(rng, d, 3000)
    return ao4d.SimplexMesh(mesh.vertices + shift, mesh.simplices), o + shift, w


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("closest", [True, False])
@pytest.mark.parametrize("shift", [0.0, 1000.0])  # far from the coordinate origin: float32 slabs
def test_bvh_equals_brute_force(d, closest, shift, backend):
    mesh, o, w = _shifted_soup(900 + d, d, shift)
    for max_distance in (np.inf, 0.7):
        fast = api.cast_rays(mesh, o, w, closest=closest, backend=backend, max_distance=max_distance)
        slow = api.cast_rays(mesh, o, w, closest=closest, backend=backend, accel="brute", max_distance=max_distance)
        # same primitive test on the same data; the boxes are conservative: identical answers
        np.testing.assert_array_equal(fast.hit, slow.hit)
        assert 0.01 < fast.hit.mean() < 0.95  # a scene where the question is not trivial
        if closest:
            np.testing.assert_array_equal(fast.t, slow.t)
            same = fast.simplex == slow.simplex
            # a different simplex only on exact ties (a ray through a shared point)
            np.testing.assert_array_equal(fast.t[~same], slow.t[~same])


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("shift", [0.0, 30.0])
def test_box_margin_keeps_corner_hits(d, shift, backend):
    # rays aimed at the vertices of a simplex hit it at its box's corners, where the float32
    # slab test is closest to rejecting (its error grows with |o|: ao4d.bvh.layout._BOX_FMA_MARGIN)
    rng = np.random.default_rng(1100 + d)
    corners = rng.uniform(-1, 1, size=(d, d)) + shift
    mesh = ao4d.SimplexMesh(corners, [list(range(d))])
    o = np.repeat(corners, 500, axis=0) + rng.normal(size=(500 * d, d))
    w = np.repeat(corners, 500, axis=0) - o
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    fast = api.cast_rays(mesh, o, w, backend=backend, closest=False)
    slow = api.cast_rays(mesh, o, w, backend=backend, closest=False, accel="brute")
    np.testing.assert_array_equal(fast.hit, slow.hit)
    assert slow.hit.mean() > 0.5  # the primitive test takes most of them (BARY_EPS)


@pytest.mark.parametrize("d", DIMS)
def test_gpu_block_layout_gives_the_same_answers(d, cl_runtime, monkeypatch):
    # GPUs get leaf blocks of 4 simplices, CPUs of 16 (bvh.block_lanes); the per-lane
    # arithmetic is the same explicit fma sequence, so answers agree exactly
    rng = np.random.default_rng(1200 + d)
    mesh = soup_scene(rng, d)
    o, w = random_rays(rng, d, 3000)
    pts, nrm = o[:200], w[:200]
    results = {}
    for lanes in (16, 4):
        monkeypatch.setattr(bvh.cache, "block_lanes", lambda runtime, dim=None, lanes=lanes: lanes)
        hits = api.cast_rays(mesh, o, w, backend="opencl")
        occ = ao4d.ambient_occlusion(mesh, points=pts, normals=nrm, samples=32, backend="opencl")
        results[lanes] = hits, occ
    (h16, a16), (h4, a4) = results[16], results[4]
    np.testing.assert_array_equal(h4.simplex, h16.simplex)
    np.testing.assert_array_equal(h4.t, h16.t)
    np.testing.assert_array_equal(a4, a16)
    assert 0.01 < h4.hit.mean() < 0.95


@pytest.mark.parametrize("d", DIMS)
def test_node_widths_give_the_same_answers(d, cl_runtime, monkeypatch):
    # wide nodes of 16 children (AVX-512 CPUs: bvh.node_width) or 8 (elsewhere): the boxes are
    # conservative either way and the leaf test the same, so hits, distances and AO counts of
    # both traversals agree exactly, far from the origin too
    import pyopencl as pcl

    device = cl_runtime.device
    cpu16 = bool(device.type & pcl.device_type.CPU) and device.native_vector_width_float >= 16
    assert bvh.node_width(cl_runtime) == (16 if cpu16 else 8)
    mesh, o, w = _shifted_soup(1250 + d, d, 700.0)
    pts, nrm = o[:300], w[:300] / np.linalg.norm(w[:300], axis=1, keepdims=True)
    results = {}
    for width in (8, 16):
        monkeypatch.setattr(bvh.cache, "node_width", lambda runtime, width=width: width)
        closest = api.cast_rays(mesh, o, w, backend="opencl")
        anyhit = api.cast_rays(mesh, o, w, backend="opencl", closest=False, max_distance=2.0)
        occ = ao4d.ambient_occlusion(mesh, points=pts, normals=nrm, samples=40, backend="opencl")
        results[width] = closest.simplex, closest.t, anyhit.simplex >= 0, occ
        tree = bvh.get_bvh(mesh, runtime=cl_runtime)
        assert bvh.device_tree(mesh, tree, cl_runtime)["width"] == width
    for a, b in zip(results[8], results[16]):
        np.testing.assert_array_equal(a, b)
    assert 0.01 < (results[8][0] >= 0).mean() < 0.95 and 0 < results[8][3].mean() < 1


@pytest.mark.parametrize("d", DIMS)
def test_hits_are_consistent(d, backend):
    rng = np.random.default_rng(1000 + d)
    mesh = soup_scene(rng, d)
    o, w = random_rays(rng, d, 2000)
    hits = api.cast_rays(mesh, o, w, backend=backend)
    anyhit = api.cast_rays(mesh, o, w, backend=backend, closest=False)
    np.testing.assert_array_equal(hits.hit, anyhit.hit)
    assert (anyhit.t[anyhit.hit] >= hits.t[hits.hit]).all()
    h = hits.hit
    assert np.isinf(hits.t[~h]).all() and (hits.barycentric[~h] == 0).all()
    np.testing.assert_allclose(hits.barycentric[h].sum(1), 1.0, atol=1e-12)
    assert (hits.barycentric[h] > -2 * bvh.BARY_EPS).all()
    corners = mesh.vertices[mesh.simplices[hits.simplex[h]]]
    points = np.einsum("si,sid->sd", hits.barycentric[h], corners)
    np.testing.assert_allclose(points, o[h] + hits.t[h, None] * w[h], atol=1e-9)
    # nothing closer: the closest hit of a ray shortened to just below t is a miss
    short = api.cast_rays(mesh, o[h], w[h], backend=backend, max_distance=1.0)
    assert (short.hit == (hits.t[h] <= 1.0)).all()


@pytest.mark.parametrize("d", DIMS)
def test_opencl_and_numpy_agree(d, cl_runtime):
    rng = np.random.default_rng(1100 + d)
    mesh = soup_scene(rng, d)
    o, w = random_rays(rng, d, 5000)
    gpu = api.cast_rays(mesh, o, w, backend="opencl")
    cpu = api.cast_rays(mesh, o, w, backend="numpy")
    # float32 vs float64 decide differently only for rays grazing an edge: < 0.1%
    assert (gpu.hit != cpu.hit).mean() <= 1e-3
    both = gpu.hit & cpu.hit & (gpu.simplex == cpu.simplex)
    assert both.mean() > 0.99 * min(gpu.hit.mean(), cpu.hit.mean())
    np.testing.assert_allclose(gpu.t[both], cpu.t[both], rtol=1e-12)  # refined in float64
    scene = sphere_over_ground(rng, d)
    a = ao4d.ambient_occlusion(scene, samples=64, backend="opencl")
    b = ao4d.ambient_occlusion(scene, samples=64, backend="numpy")
    # same seed: same directions; a point may differ by a grazing ray or two
    assert np.mean(a == b) >= 0.97
    assert np.abs(a - b).max() <= 2 / 64


def test_closest_hits_match_embree(backend):
    pytest.importorskip("embreex")
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    rng = np.random.default_rng(1200)
    scene, mesh = embree_scene(rng)
    o, w = random_rays(rng, 3, 20000)
    ours = api.cast_rays(mesh, o, w, backend=backend)
    locations, index_ray, index_tri = RayMeshIntersector(scene).intersects_location(o, w, multiple_hits=False)
    theirs = np.zeros(len(o), dtype=bool)
    theirs[index_ray] = True
    # Embree and we disagree only on rays grazing an edge: at most 0.1%
    assert np.mean(ours.hit != theirs) <= 1e-3
    t_embree = np.full(len(o), np.inf)
    t_embree[index_ray] = np.einsum("nd,nd->n", locations - o[index_ray], w[index_ray])
    both = ours.hit & theirs
    # Embree works in float32: distances of order 1 agree to ~1e-5
    close = np.isclose(ours.t[both], t_embree[both], atol=1e-4)
    assert close.mean() >= 0.999


def test_device_memory_is_checked_before_work():
    class Device:
        max_mem_alloc_size = 1000
        global_mem_size = 4000

    class Runtime:
        device = Device()
        name = "tiny device"

    with pytest.raises(MemoryError, match="tiny device"):
        cl.check_device_memory(Runtime(), {"the BVH": 2000}, task="ray tracing")
    with pytest.raises(MemoryError, match="80%"):
        cl.check_device_memory(Runtime(), {"a": 900, "b": 900, "c": 900, "d": 900}, task="ray tracing")
    cl.check_device_memory(Runtime(), {"a": 900}, task="ray tracing")


def test_bad_inputs():
    rng = np.random.default_rng(1700)
    mesh = sphere_over_ground(rng, 3)
    o, w = random_rays(rng, 3, 5)
    with pytest.raises(ValueError, match="`directions` has 1 zero-length"):
        api.cast_rays(mesh, o, np.r_[w[:4], [[0, 0, 0]]], backend="numpy")
    with pytest.raises(ValueError, match="`origins` and `directions` must have the same length"):
        api.cast_rays(mesh, o, w[:3], backend="numpy")
    with pytest.raises(TypeError, match="`closest`"):
        api.cast_rays(mesh, o, w, closest="yes", backend="numpy")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    d=st.sampled_from(DIMS),
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 60),
    leaf_size=st.integers(1, 6),
    max_distance=st.sampled_from([np.inf, 0.3, 1.0]),
)
def test_numpy_bvh_traversal_equals_brute_force(d, seed, n, leaf_size, max_distance, build_bvh):
    # both builders' trees (the fixture is stateless: reusing it across examples is safe)
    rng = np.random.default_rng(seed)
    vertices, simplices = random_soup(rng, d, n, size=rng.uniform(0.02, 0.4))
    try:
        tree = build_bvh(vertices, simplices, leaf_size=leaf_size)
    except ValueError:
        assume(False)  # every random simplex degenerate: nothing to trace
    o = rng.uniform(-0.2, 1.2, size=(200, d))
    w = rng.normal(size=(200, d))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    for any_hit in (True, False):
        t1, p1 = reference._trace_numpy_bvh(tree, o, w, max_distance, any_hit)
        t2, p2 = reference._trace_numpy_brute(tree, o, w, max_distance, any_hit)
        np.testing.assert_array_equal(p1 >= 0, p2 >= 0)
        if not any_hit:
            np.testing.assert_array_equal(t1, t2)


def test_kernel_macros_are_all_used():
    # every macro a kernel header defines is used somewhere (vloadW was defined and never used)
    import re

    from ao4d._resources import data_dir

    sources = {p.name: p.read_text() for p in data_dir("kernels").glob("*.[ch]*")}
    text = "\n".join(sources.values())
    defined = set(re.findall(r"^\s*#define\s+(\w+)", text, flags=re.M))
    unused = sorted(m for m in defined if len(re.findall(rf"\b{m}\b", text)) < 2)
    assert not unused, f"macros defined but never used in kernels/: {unused}"


# -- kernel edge cases (checked under Oclgrind and PoCL) -----------------------------------------


@pytest.mark.parametrize("d", (3, 4))
@pytest.mark.parametrize("closest", [True, False])
def test_far_scene_with_zero_direction_components(d, closest, backend):
    # at 1e9, o * (1 / 1e-30) for a zero direction component is +-inf in float32, and the box
    # test must still accept the boxes its rays hit (axis-aligned orthographic cameras give
    # exact zeros): the answer equals brute force
    rng = np.random.default_rng(1300 + d)
    scale = 1e9
    base = soup_scene(rng, d)
    mesh = ao4d.SimplexMesh(base.vertices * scale, base.simplices)
    n = 6000
    o, w = random_rays(rng, d, n, spread=1.2)
    w[np.arange(n), rng.integers(0, d, n)] = 0.0  # one exactly zero component
    axis = rng.integers(0, d, n // 2)
    w[: n // 2] = np.eye(d)[axis] * rng.choice([-1.0, 1.0], size=(n // 2, 1))  # axis-aligned
    fast = api.cast_rays(mesh, o * scale, w, closest=closest, backend=backend)
    slow = api.cast_rays(mesh, o * scale, w, closest=closest, backend=backend, accel="brute")
    assert slow.hit.sum() > 100  # the question is not trivial
    np.testing.assert_array_equal(fast.hit, slow.hit)
    if closest:
        np.testing.assert_array_equal(fast.t, slow.t)


@pytest.mark.parametrize("d", DIMS)
def test_no_rays_give_empty_results(d, backend):
    # OpenCL refused buffers of zero bytes (INVALID_BUFFER_SIZE); numpy returned empty arrays
    mesh = soup_scene(np.random.default_rng(1400 + d), d, n=20)
    for closest in (True, False):
        hits = api.cast_rays(mesh, np.zeros((0, d)), np.zeros((0, d)), closest=closest, backend=backend)
        assert hits.t.shape == (0,) and hits.simplex.shape == (0,) and hits.barycentric.shape == (0, d)
    occ = ao4d.ambient_occlusion(mesh, points=np.zeros((0, d)), normals=np.zeros((0, d)), backend=backend)
    assert occ.shape == (0,)


def _private_bytes(runtime, kernel) -> int:
    import pyopencl as pcl

    return kernel.get_work_group_info(pcl.kernel_work_group_info.PRIVATE_MEM_SIZE, runtime.device)


def test_traversal_stack_size_comes_from_python(cl_runtime, monkeypatch):
    # one stack size, written once: Python passes it (-D STACK_SIZE) to kernels/bvh/bvh.h and
    # refuses trees whose traversal could overflow it
    rng = np.random.default_rng(1500)
    mesh = soup_scene(rng, 3, n=2000)
    o, w = random_rays(rng, 3, 3000)
    width = bvh.node_width(cl_runtime)
    depth = bvh.wide(bvh.get_bvh(mesh, runtime=cl_runtime), bvh.block_lanes(cl_runtime, 3), width).depth
    assert depth >= 3
    needed = depth * (width - 1) + 1
    brute = api.cast_rays(mesh, o, w, backend="opencl", accel="brute")
    sizes = {}
    for stack in (needed, 4 * needed):
        monkeypatch.setattr(bvh.layout, "STACK_SIZE", stack)
        fresh = ao4d.SimplexMesh(mesh.vertices, mesh.simplices)  # no cached device tree
        hits = api.cast_rays(fresh, o, w, backend="opencl")
        np.testing.assert_array_equal(hits.simplex >= 0, brute.simplex >= 0)
        np.testing.assert_array_equal(hits.t, brute.t)
        kernel = ray_launches._kernels(cl_runtime, 3, bvh.block_lanes(cl_runtime, 3), source="rays/cast.cl")["cast_bvh"]
        sizes[stack] = _private_bytes(cl_runtime, kernel)
    if sizes[needed] > 0:  # runtimes that report private memory: it follows the stack
        assert sizes[4 * needed] >= sizes[needed] + 3 * needed * 4
    monkeypatch.setattr(bvh.layout, "STACK_SIZE", needed - 1)
    fresh = ao4d.SimplexMesh(mesh.vertices, mesh.simplices)
    with pytest.raises(RuntimeError, match="too deep for the kernels' traversal stack"):
        api.cast_rays(fresh, o, w, backend="opencl")


# -- geometry recentred and scaled in float64 before the float32 kernels ------------------------


@pytest.fixture(scope="module")
def hypersphere14():
    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), 14, (-1.3, 1.3))
    assert mesh.check().closed
    return mesh


# shift / scale up to 1e6: float64 itself keeps 1e-10 of the scene's size there
@pytest.mark.parametrize("shift, scale", [(1e6, 1.0), (1e4, 1.0), (-0.3, 1e-6), (2e3, 1e6), (1e12, 1e6)])
def test_far_and_scaled_scene_traces_as_at_the_origin(hypersphere14, shift, scale, backend):
    # absolute float32 coordinates lost hits through a closed hypersphere 1e4 from the origin
    # (105 of 15k rays), and its AO, exactly 0 for this convex shape, became 0.54 on OpenCL
    rng = np.random.default_rng(1600)
    base = hypersphere14
    moved = ao4d.SimplexMesh(base.vertices * scale + shift, base.simplices)
    n = 4000 if backend == "opencl" else 600
    w = rng.normal(size=(n, 4))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    o = rng.uniform(-0.3, 0.3, size=(n, 4))  # inside: every ray crosses the surface once
    ref = api.cast_rays(base, o, w, backend=backend)
    got = api.cast_rays(moved, o * scale + shift, w, backend=backend)
    assert ref.hit.all() and got.hit.all()
    assert (got.simplex == ref.simplex).mean() > 0.995  # other simplices only on shared faces
    np.testing.assert_allclose(got.t / scale, ref.t, rtol=1e-7)
    samples = 16
    idx = rng.choice(len(base.vertices), 300 if backend == "opencl" else 40, replace=False)
    normals = base.vertex_normals[idx]
    a_ref = ao4d.ambient_occlusion(base, points=base.vertices[idx], normals=normals, samples=samples, backend=backend)
    a_got = ao4d.ambient_occlusion(moved, points=moved.vertices[idx], normals=normals, samples=samples, backend=backend)
    assert a_ref.max() == 0.0  # convex: nothing occludes
    assert np.abs(a_got - a_ref).max() <= 1 / samples


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_ao_does_not_depend_on_the_scene_scale(scale, cl_runtime):
    # the rays' start offset scales with the scene: a fixed offset would let rays hit their own
    # simplices at scale 1e3 and jump over nearby occluders at 1e-3
    rng = np.random.default_rng(1700)
    base = sphere_over_ground(rng, 4)
    scaled = ao4d.SimplexMesh(base.vertices * scale, base.simplices)
    a = ao4d.ambient_occlusion(base, samples=32, backend="opencl")
    b = ao4d.ambient_occlusion(scaled, samples=32, backend="opencl")
    assert 0.05 < np.nanmean(a) < 0.9  # graded: the question is not trivial
    np.testing.assert_array_equal(a, b)


def test_hit_exactly_at_max_distance_counts(backend):
    # hits count for 0 < t <= max_distance on both backends (t < max_distance lost them on OpenCL)
    for d in DIMS:
        patch = ao4d.SimplexMesh(*flat_patch(d, -1.0, 1.0, 1.0, n=2))
        o = np.zeros((1, d))
        w = np.eye(d)[-1:]
        assert api.cast_rays(patch, o, w, max_distance=1.0, backend=backend).hit[0]
        short = 1.0 - 2.0**-20  # a float32 value: the kernels' t_max is float32
        assert not api.cast_rays(patch, o, w, max_distance=short, backend=backend).hit[0]
        for closest in (True, False):
            hit = api.cast_rays(patch, o, w, max_distance=1.0, closest=closest, backend=backend)
            assert hit.hit[0] and hit.t[0] == 1.0


@pytest.mark.parametrize("d", DIMS)
def test_rays_at_the_barycentric_tolerance_equal_brute_force(d, backend):
    # rays aimed just outside a simplex's extreme vertex, within the barycentric tolerance: the
    # primitive test takes them, so the boxes must be grown to match (bvh's box margin), also
    # for small simplices far from the origin (a tenth of the scene: float32 resolves a
    # barycentric tolerance of 1e-5 on them)
    rng = np.random.default_rng(1800 + d)
    centres = 1e-3 * rng.uniform(-1, 1, size=(30, d)) + 5e4
    corners = centres[:, None, :] + 1e-4 * rng.uniform(-1, 1, size=(30, d, d))
    mesh = ao4d.SimplexMesh(corners.reshape(-1, d), np.arange(30 * d).reshape(30, d))
    inside = corners.mean(axis=1, keepdims=True)
    # each vertex pushed outwards by half the tolerance, in barycentric terms
    targets = (corners + 0.5 * bvh.BARY_EPS * (corners - inside)).reshape(-1, d)
    normals = mesh.simplex_normals
    w = -np.repeat(normals, d, axis=0) + 0.3 * rng.normal(size=(len(targets), d))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    o = targets - 1e-4 * w
    fast = api.cast_rays(mesh, o, w, backend=backend, closest=False)
    slow = api.cast_rays(mesh, o, w, backend=backend, closest=False, accel="brute")
    assert slow.hit.mean() > 0.9  # the primitive test accepts them
    np.testing.assert_array_equal(fast.hit, slow.hit)


# -- the AO kernel's shared-origin packets (kernels/bvh/bvh.h trace_packet) -------------------------


def _surface_points(mesh, runtime, every: int = 1):
    """Vertices with a clear normal (every ``every``-th), their normals, the mesh's tree on
    ``runtime`` and the AO rays' origin offset."""
    normals = mesh.vertex_normals
    keep = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)[::every]
    tree = bvh.get_bvh(mesh, runtime=runtime)
    return mesh.vertices[keep], normals[keep], tree, ao4d.ao.ORIGIN_OFFSET * tree.diagonal


def _ao_counts(mesh, runtime, points, normals, samples, offset, max_distance, *, traversal="packet", accel="bvh"):
    # _ao_opencl takes points in the tree's frame; offset and reach below are tree lengths
    tree = bvh.get_bvh(mesh, runtime=runtime)
    return ray_launches._ao_opencl(
        mesh,
        tree,
        runtime,
        tree.frame.points(points),
        normals,
        samples,
        7,
        offset,
        max_distance,
        accel,
        ray_rows._NullBar(),
        traversal=traversal,
    )


def _surface_scene(rng, d, shift):
    """sphere_over_ground moved by ``shift``; AO points on its surface (vertex normals, the
    usual AO case: origins next to their own simplices) and above the ground."""
    base = sphere_over_ground(rng, d)
    mesh = ao4d.SimplexMesh(base.vertices + shift, base.simplices)
    normals = mesh.vertex_normals
    keep = np.linalg.norm(normals, axis=1) > 0.5
    p, n = up_points(rng, d, 60, 1.0)
    return mesh, np.concatenate([mesh.vertices[keep], p + shift]), np.concatenate([normals[keep], n])


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("lanes", [16, 4])
@pytest.mark.parametrize("shift", [0.0, 1000.0])  # far from the coordinate origin: float32 slabs
@pytest.mark.parametrize("packet_size", [32, 64])  # GPUs' and CPUs' (ray_launches.ao_packet)
def test_packet_traversal_gives_the_per_ray_and_brute_force_counts(
    d, lanes, shift, packet_size, cl_runtime, monkeypatch
):
    # the packet kernel tests, per ray, exactly the boxes and blocks of the per-ray kernel with
    # the same arithmetic: bit-identical counts, also for packets cut short (40 and 70 samples
    # are not multiples of ray_launches.ao_packet's 32 or 64) and with a finite reach
    monkeypatch.setattr(bvh.cache, "block_lanes", lambda runtime, dim=None: lanes)
    monkeypatch.setattr(ray_launches, "ao_packet", lambda runtime: packet_size)
    rng = np.random.default_rng(1600 + d)
    mesh, p, n = _surface_scene(rng, d, shift)
    tree = bvh.get_bvh(mesh, runtime=cl_runtime)
    offset = ao4d.ao.ORIGIN_OFFSET * tree.diagonal
    for max_distance in (np.inf, 0.25 * tree.diagonal):
        for samples in (40, 70):
            packet = _ao_counts(mesh, cl_runtime, p, n, samples, offset, max_distance)
            rays = _ao_counts(mesh, cl_runtime, p, n, samples, offset, max_distance, traversal="rays")
            brute = _ao_counts(mesh, cl_runtime, p, n, samples, offset, max_distance, accel="brute")
            np.testing.assert_array_equal(packet, rays)
            np.testing.assert_array_equal(rays, brute)
            share = packet.sum() / (len(p) * samples)
            assert 0.02 < share < 0.9  # occlusion is neither absent nor total
            assert 0.05 < np.mean((packet > 0) & (packet < samples))  # partly occluded points


def test_packet_traversal_on_an_extracted_4d_surface(cl_runtime):
    # a marched 4D surface: every vertex's rays start next to its own tetrahedra, deep in the tree
    field = ao4d.fields.spheritorus(1.0, 0.4)
    mesh = ao4d.extract_field(field, (15, 15, 15, 7), ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))
    p, n, tree, offset = _surface_points(mesh, cl_runtime)
    for max_distance in (np.inf, 0.25 * tree.diagonal):
        packet = _ao_counts(mesh, cl_runtime, p, n, 64, offset, max_distance)
        rays = _ao_counts(mesh, cl_runtime, p, n, 64, offset, max_distance, traversal="rays")
        np.testing.assert_array_equal(packet, rays)
        assert 0.01 < packet.mean() / 64 < 0.5
    sub = slice(0, None, 25)
    brute = _ao_counts(mesh, cl_runtime, p[sub], n[sub], 64, offset, np.inf, accel="brute")
    np.testing.assert_array_equal(_ao_counts(mesh, cl_runtime, p[sub], n[sub], 64, offset, np.inf), brute)


def test_packet_traversal_shares_node_visits(cl_runtime):
    # the packet fetches a node once for all its rays: far fewer node fetches per ray than box
    # tests per ray. Its nearest-first order changes only which tests a ray makes before its
    # first hit, so its box and block tests per ray stay close to the per-ray traversal's
    field = ao4d.fields.spheritorus(1.0, 0.4)
    mesh = ao4d.extract_field(field, (15, 15, 15, 7), ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))
    normals = mesh.vertex_normals
    keep = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)[::5]
    tree = bvh.get_bvh(mesh, runtime=cl_runtime)
    kw = dict(samples=64, offset=ao4d.ao.ORIGIN_OFFSET * tree.world_diagonal, runtime=cl_runtime, detail=True)
    per_ray = api.traversal_counts(mesh, mesh.vertices[keep], normals[keep], traversal="rays", **kw)
    packet = api.traversal_counts(mesh, mesh.vertices[keep], normals[keep], traversal="packet", **kw)
    assert per_ray[0] == per_ray[2] and per_ray[1] == per_ray[3]
    assert 0.9 * per_ray[2] < packet[2] < 1.15 * per_ray[2]
    assert 0.9 * per_ray[3] < packet[3] < 1.15 * per_ray[3]
    assert packet[0] < 0.3 * per_ray[0] and packet[1] < 0.5 * per_ray[1]


@pytest.mark.parametrize("d", DIMS)
def test_directions_eight_at_a_time_are_the_same_bits(d, cl_runtime):
    # the packet kernel generates its directions on vector lanes (vector cbrt / sincos / sqrt),
    # the per-ray kernel one at a time: the AO counts can only agree if these are the same bits
    rng = np.random.default_rng(1700 + d)
    normals = rng.normal(size=(3000, d))
    normals[:40] = np.eye(d)[rng.integers(0, d, 40)] * rng.choice([-1.0, 1.0], size=(40, 1))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    one = ray_launches.sample_directions(cl_runtime, normals, 77, 5)  # 77: a last group of five
    eight = ray_launches.sample_directions(cl_runtime, normals, 77, 5, eight=True)
    np.testing.assert_array_equal(eight, one)
    assert np.all(np.einsum("nsd,nd->ns", one, normals) >= -1e-6)  # in the normals' hemispheres


def test_packet_kernel_private_memory_is_bounded(cl_runtime):
    # GPU readiness: the packet's rays (32 or 64 x 20 words in 4D) and its stack of (node, ray mask)
    # entries are fixed-size private arrays; no local memory
    import pyopencl as pcl

    for d in (2, 3, 4):
        kernel = ray_launches._kernels(cl_runtime, d, bvh.block_lanes(cl_runtime, d))["ao_bvh"]
        assert kernel.get_work_group_info(pcl.kernel_work_group_info.LOCAL_MEM_SIZE, cl_runtime.device) == 0
        private = _private_bytes(cl_runtime, kernel)
        packet = ray_launches.ao_packet(cl_runtime)
        needed = packet * 5 * d * 4 + bvh.STACK_SIZE * (8 + packet // 8)  # node, key, ray mask
        if private > 0:  # runtimes that report it: the packet and the stack, little more
            assert needed <= private <= needed + 4096


def test_ao_uses_the_packet_kernel_on_cpus(cl_runtime, monkeypatch):
    import pyopencl as pcl

    used = []
    real = ray_launches._traversal_kernel

    def spy(runtime, dim, dev, name, accel, count_visits=False, suffix="", ray_type=None):
        used.append(suffix)
        return real(runtime, dim, dev, name, accel, count_visits, suffix, ray_type)

    monkeypatch.setattr(ray_launches, "_traversal_kernel", spy)
    rng = np.random.default_rng(1800)
    mesh = soup_scene(rng, 3, n=50)
    ao4d.ambient_occlusion(mesh, samples=8, backend="opencl")
    cpu = bool(cl_runtime.device.type & pcl.device_type.CPU)
    assert used == ["" if cpu else "_rays"]  # ao_bvh (packets) on CPUs, ao_bvh_rays elsewhere
    with pytest.raises(ValueError, match="`traversal` must be one of"):
        api.traversal_counts(
            mesh, mesh.vertices[:3], np.eye(3)[[0, 1, 2]], samples=4, offset=0.0, runtime=cl_runtime, traversal="wide"
        )


def test_any_hit_traversal_stops_at_its_first_hit(cl_runtime):
    # rays up through eight stacked patches hit all of them; an any-hit traversal that went on
    # after its first hit (same answers) would test leaf blocks of every patch
    d = 3
    parts = [flat_patch(d, -30.0, 30.0, 1.0 + k, n=24) for k in range(8)]
    vertices = np.concatenate([v for v, _ in parts])
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    simplices = np.concatenate([s + o for (_, s), o in zip(parts, offsets)])
    mesh = ao4d.SimplexMesh(vertices, simplices)
    rng = np.random.default_rng(1900)
    p, n = up_points(rng, d, 200, 1.0)
    nodes, blocks = api.traversal_counts(
        mesh, p, n, samples=16, offset=0.0, runtime=cl_runtime, max_distance=100.0, traversal="rays"
    )
    occ = ao4d.ambient_occlusion(mesh, points=p, normals=n, samples=16, backend="opencl")
    assert occ.min() > 0.9  # nearly every ray hits the lowest patch
    assert blocks < 2.5, blocks  # a traversal that continues tests at least one block per patch


def _reference_chunk(frame, origins, directions, dtype, width):
    """The kernels' ray inputs by the plain formulas, one column at a time over every ray (the
    mapping cast_rays used before its block-wise form): the bits the block-wise form must give."""
    n, d = origins.shape
    length2, column = np.zeros(n), np.empty(n)
    for k in range(d):
        np.multiply(directions[:, k], directions[:, k], out=column, dtype=np.float64)
        length2 += column
    inv_length = (1.0 / np.sqrt(length2)).astype(dtype)
    o = np.zeros((n, width), dtype=dtype)
    w = np.zeros((n, width), dtype=dtype)
    for k in range(d):
        np.subtract(origins[:, k], frame.centre[k], out=column)
        np.multiply(column, frame.scale, out=o[:, k])
        np.multiply(directions[:, k], inv_length, out=w[:, k])
    return o, w


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("in_dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shift", [0.0, 1e6])  # far from the origin: the float64 mapping matters
def test_ray_mapping_gives_the_plain_formulas_bits(d, in_dtype, shift, monkeypatch):
    # block-wise (blocks of 1000 rows here, a last one cut short) = column by column over all rays
    monkeypatch.setattr(ray_rows, "_ROW_BLOCK", 1000)
    rng = np.random.default_rng(2800 + d)
    n = 4321
    origins = (rng.normal(size=(n, d)) * 3 + shift).astype(in_dtype)
    directions = (rng.normal(size=(n, d)) * rng.uniform(1e-3, 1e3, (n, 1))).astype(in_dtype)
    frame = bvh.Frame.fit(origins[:50].astype(np.float64) * 0.5 + shift * 0.5)
    rays = ray_rows._Rays(frame, origins, directions)
    for dtype, width in ((np.float32, 4), (np.float64, d)):
        for start, stop in ((0, n), (1500, 3999)):
            got = rays.chunk(start, stop, dtype, width)
            want = _reference_chunk(frame, origins[start:stop], directions[start:stop], dtype, width)
            for a, b in zip(got, want):
                assert a.dtype == dtype
                np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8))


def _needs_fp64(runtime):
    if "cl_khr_fp64" not in runtime.device.extensions:
        pytest.skip("the device maps rays itself only with cl_khr_fp64")


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("in_dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shift", [0.0, 1e6, -3e9])
def test_device_ray_mapping_gives_the_hosts_bits(d, in_dtype, shift, cl_runtime):
    # the cast_rows_* kernels map the caller's rows in double: the same float32 bits as the host's
    # mapping, for directions short and long and origins far out, next to the frame's centre
    # (subnormal results) and on it
    _needs_fp64(cl_runtime)
    rng = np.random.default_rng(3100 + d)
    n = 3000
    origins = rng.normal(size=(n, d)) * 3 + shift
    # lengths from 1e-30 to 1e30: float32 holds their inverses (both mappings round 1 / |w| to it)
    directions = rng.normal(size=(n, d)) * np.exp(rng.uniform(np.log(1e-30), np.log(1e30), (n, 1)))
    directions[:50, 1:] = 0.0  # axis-aligned
    frame = bvh.Frame.fit(origins[:50] * 0.5 + shift * 0.5)
    origins[50:60] = frame.centre  # exactly on the centre: zeros
    origins[60:70] = frame.centre + rng.normal(size=(10, d)) * 1e-39 / frame.scale  # subnormal float32
    origins, directions = origins.astype(in_dtype), directions.astype(in_dtype)
    want = _reference_chunk(frame, origins, directions, np.float32, 4)
    for ray_type in ("float", "double") if in_dtype == np.float32 else ("double",):
        got = ray_launches.device_ray_mapping(cl_runtime, frame, origins, directions, ray_type)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


@pytest.mark.parametrize("d", (3, 4))
def test_rays_mapped_on_the_device_or_the_host_hit_alike(d, cl_runtime, monkeypatch):
    # the same answers through the cast_rows_* kernels and through the host's mapping (the path
    # of devices without fp64), over several launches, float32, float64 and mixed rows; a
    # zero-length direction in a later launch is named as on the host
    _needs_fp64(cl_runtime)
    mesh, o, w = _shifted_soup(3200 + d, d, 500.0)
    monkeypatch.setattr(ray_launches, "RAYS_PER_LAUNCH", 600)
    for oo, ww in ((o, w), (o.astype(np.float32), w.astype(np.float32)), (o.astype(np.float32), w)):
        got = {}
        for on_device in (True, False):
            monkeypatch.setattr(ray_launches, "MAP_ON_DEVICE", on_device)
            for closest in (False, True):
                hits = api.cast_rays(mesh, oo, ww, closest=closest, backend="opencl", max_distance=3.0)
                got[on_device, closest] = (hits.simplex, hits.t, hits.barycentric)
        for closest in (False, True):
            for a, b in zip(got[True, closest], got[False, closest]):
                np.testing.assert_array_equal(a, b)
        assert (got[True, True][0] >= 0).mean() > 0.03  # 90 hits of 3000 rays at least
    monkeypatch.setattr(ray_launches, "MAP_ON_DEVICE", True)
    before = api.cast_rays(mesh, o, w, backend="opencl", max_distance=3.0)
    bad = w.copy()
    bad[[1500, 1700]] = 0.0
    with pytest.raises(ValueError, match=r"`directions` has 2 zero-length row\(s\), first at index 1500"):
        api.cast_rays(mesh, o, bad, backend="opencl")
    # the error left no launch buffer mapped or busy: the next call answers as before
    after = api.cast_rays(mesh, o, w, backend="opencl", max_distance=3.0)
    for a, b in ((after.simplex, before.simplex), (after.t, before.t), (after.barycentric, before.barycentric)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("shift", [0.0, 1e4])
def test_any_hit_rays_sharing_origins_go_as_packets_with_the_same_answers(d, shift, cl_runtime, monkeypatch):
    # runs of rows with one origin (1, 3, 64, 130 and 7 rows: packets cut at 64, runs too short
    # for packets in a launch of their own) hit exactly what the per-ray kernel and brute force
    # hit, float32 and float64 rows, over several launches; each reported simplex is hit (its
    # refined t is positive and its weights within the kernels' tolerance)
    _needs_fp64(cl_runtime)
    mesh, o, w = _shifted_soup(3500 + d, d, shift)
    runs = [1, 3, 64, 130, 7] * 12
    o = np.repeat(o[: len(runs)], runs, axis=0)
    w = np.random.default_rng(d).normal(size=(len(o), d))
    built, original = [], ray_launches._traversal_kernel
    monkeypatch.setattr(ray_launches, "_traversal_kernel", lambda *a, **k: built.append(a[3]) or original(*a, **k))
    for oo, ww in ((o, w), (o.astype(np.float32), w.astype(np.float32))):
        got = {}
        for packets, launch in (
            (True, ray_launches.RAYS_PER_LAUNCH),
            (True, 1000),
            (False, ray_launches.RAYS_PER_LAUNCH),
        ):
            monkeypatch.setattr(ray_launches, "CAST_PACKETS", packets)
            monkeypatch.setattr(ray_launches, "RAYS_PER_LAUNCH", launch)
            got[packets, launch] = api.cast_rays(mesh, oo, ww, closest=False, backend="opencl")
        brute = api.cast_rays(mesh, oo, ww, closest=False, backend="opencl", accel="brute")
        assert 0.02 < brute.hit.mean() < 0.95  # 90 hits of 2460 rays at least
        for hits in got.values():
            np.testing.assert_array_equal(hits.hit, brute.hit)
            h = hits.hit
            assert (hits.t[h] > 0).all() and hits.barycentric[h].min() > -1e-3
    assert "cast_packets" in built and "cast_rows" in built
    bad = w.copy()
    bad[[70, 300]] = 0.0  # zero-length directions inside packets
    monkeypatch.setattr(ray_launches, "CAST_PACKETS", True)
    with pytest.raises(ValueError, match=r"`directions` has 2 zero-length row\(s\), first at index 70"):
        api.cast_rays(mesh, o, bad, closest=False, backend="opencl")


@given(runs=st.lists(st.integers(1, 200), min_size=1, max_size=30), size=st.sampled_from([32, 64]), f32=st.booleans())
@settings(max_examples=60, deadline=None)
def test_shared_origin_packets_cover_the_runs(runs, size, f32):
    # the packets partition the rows in order, each within one run of identical origins and at
    # most `size` long; None exactly when the runs average fewer than 4 rows
    dtype = np.float32 if f32 else np.float64
    starts = np.arange(len(runs), dtype=dtype)
    origins = np.repeat(np.stack([starts, -starts, starts * 0.5], axis=1), runs, axis=0)
    packets = ray_launches.shared_origin_packets(origins, size)
    if sum(runs) < 4 * len(runs):
        assert packets is None
        return
    first, count = packets[:, 0], packets[:, 1]
    np.testing.assert_array_equal(first, np.concatenate([[0], np.cumsum(count)[:-1]]))
    assert count.sum() == len(origins) and count.max() <= size and count.min() >= 1
    run_of = np.repeat(np.arange(len(runs)), runs)
    assert all(run_of[a] == run_of[a + c - 1] for a, c in packets)
    assert len(packets) == sum(-(-r // size) for r in runs)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("shift", [0.0, 2e4])
def test_hits_refined_on_the_device_or_the_host_alike(d, shift, cl_runtime, monkeypatch):
    # kernels/rays/refine.cl repeats the host's float64 operations in order: the same bits of t and
    # the barycentrics for float32, float64 and mixed rows, far from the origin too; and the
    # refined hit lies on its simplex (the weights rebuild the hit point, sum to one, and are
    # within the kernels' tolerance of the simplex)
    _needs_fp64(cl_runtime)
    mesh, o, w = _shifted_soup(3300 + d, d, shift)
    w = w * np.exp(np.random.default_rng(d).uniform(-20, 20, (len(w), 1)))  # lengths 1e-9 to 1e9
    built, original = [], ray_refine._refine_kernel
    monkeypatch.setattr(ray_refine, "_refine_kernel", lambda *args: built.append(args) or original(*args))
    for oo, ww in ((o, w), (o.astype(np.float32), w.astype(np.float32)), (o, w.astype(np.float32))):
        got = {}
        for on_device in (True, False):
            monkeypatch.setattr(ray_refine, "REFINE_ON_DEVICE", on_device)
            before = len(built)
            hits = api.cast_rays(mesh, oo, ww, backend="opencl")
            got[on_device] = hits
            hits.t  # noqa: B018 (refined now)
            assert len(built) - before == int(on_device)  # the kernel refined, or the host
        assert (got[True].simplex >= 0).mean() > 0.03
        for name in ("simplex", "t", "barycentric"):
            np.testing.assert_array_equal(getattr(got[True], name), getattr(got[False], name), err_msg=name)
        hits = got[True]
        h = hits.hit
        assert np.isinf(hits.t[~h]).all() and not hits.barycentric[~h].any()
        corners = np.asarray(mesh.vertices)[np.asarray(mesh.simplices)[hits.simplex[h]]]
        unit = ww[h] / np.linalg.norm(ww[h].astype(np.float64), axis=1, keepdims=True)
        point = oo[h] + hits.t[h, None] * unit
        np.testing.assert_allclose(
            np.einsum("ki,kij->kj", hits.barycentric[h], corners), point, atol=1e-9 * (1 + shift)
        )
        np.testing.assert_allclose(hits.barycentric[h].sum(1), 1.0, atol=1e-12)
        assert hits.barycentric[h].min() > -1e-4 and (hits.t[h] > 0).all()


def test_refinement_of_no_hits_and_of_a_host_tree_on_the_device(cl_runtime):
    # no hit: nothing to refine on the device; a tree built on the host (no device vertices)
    # is refined on the host, with the device-built tree's bits
    mesh, o, w = _shifted_soup(3400, 4, 10.0)
    away = api.cast_rays(mesh, o + 1e3, np.abs(w), backend="opencl")
    assert not away.hit.any() and np.isinf(away.t).all() and not away.barycentric.any()
    device_tree = api.cast_rays(mesh, o, w, backend="opencl")
    host_mesh = ao4d.SimplexMesh(mesh.vertices, mesh.simplices)
    bvh.device_tree(host_mesh, bvh.get_bvh(host_mesh, builder="host"), cl_runtime)
    host_tree = api.cast_rays(host_mesh, o, w, backend="opencl")
    assert type(bvh.get_bvh(host_mesh)).__name__ == "BVH" and device_tree.hit.mean() > 0.03
    np.testing.assert_array_equal(host_tree.hit, device_tree.hit)
    same = host_tree.simplex == device_tree.simplex  # another simplex only on exact ties
    np.testing.assert_array_equal(host_tree.t, device_tree.t)
    np.testing.assert_array_equal(host_tree.barycentric[same], device_tree.barycentric[same])


@pytest.mark.parametrize("d", (3, 4))
@pytest.mark.parametrize("shift", [0.0, 1000.0])
def test_cast_rays_over_many_launches_equals_brute_force(d, shift, cl_runtime, monkeypatch):
    # launches of 700 rays take turns on two sets of mapped buffers, and the results are written
    # launch by launch: every ray's answer equals the brute-force answer, and the closest hits'
    # simplices, t and barycentrics those of one launch for all, misses included (-1, inf, 0)
    mesh, o, w = _shifted_soup(2900 + d, d, shift)
    whole = {
        closest: api.cast_rays(mesh, o, w, closest=closest, backend="opencl", max_distance=0.7)
        for closest in (False, True)
    }
    monkeypatch.setattr(ray_launches, "RAYS_PER_LAUNCH", 700)
    for closest in (False, True):
        for max_distance in (np.inf, 0.7):
            fast = api.cast_rays(mesh, o, w, closest=closest, backend="opencl", max_distance=max_distance)
            slow = api.cast_rays(
                mesh, o, w, closest=closest, backend="opencl", accel="brute", max_distance=max_distance
            )
            np.testing.assert_array_equal(fast.hit, slow.hit)
            if closest:
                np.testing.assert_array_equal(fast.t, slow.t)
            if max_distance == 0.7:
                one = whole[closest]
                assert 0.02 < one.hit.mean() < 0.98  # hits and misses in every launch's share
                np.testing.assert_array_equal(fast.hit, one.hit)
                if closest:
                    for a, b in ((fast.simplex, one.simplex), (fast.t, one.t), (fast.barycentric, one.barycentric)):
                        np.testing.assert_array_equal(a, b)
                    miss = ~fast.hit
                    assert (fast.simplex[miss] == -1).all() and np.isinf(fast.t[miss]).all()
                    assert (fast.barycentric[miss] == 0.0).all()


def test_kept_launch_buffers_serve_later_and_concurrent_calls(cl_runtime, monkeypatch):
    """cast_rays keeps its launch buffers for the next call: a smaller call reuses larger ones
    (their old contents never leak into answers), and calls from several threads at once each
    get buffers of their own (every answer equals the brute-force one)."""
    from concurrent.futures import ThreadPoolExecutor

    mesh, o, w = _shifted_soup(2911, 3, 0.0)
    monkeypatch.setattr(ray_launches, "RAYS_PER_LAUNCH", 500)
    ray_launches.release_buffers()
    parts = [slice(0, len(o)), slice(0, 300), slice(100, len(o)), slice(7, 611)]
    want = [api.cast_rays(mesh, o[p], w[p], accel="brute", backend="opencl").hit for p in parts]
    for p, expected in zip(parts, want):  # one after another: large, small, large again
        np.testing.assert_array_equal(api.cast_rays(mesh, o[p], w[p], backend="opencl").hit, expected)
    assert ray_launches._launch_pool.nbytes() > 0, "no launch buffers were kept"
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(lambda p: api.cast_rays(mesh, o[p], w[p], backend="opencl").hit, parts * 6))
    for hit, expected in zip(got, want * 6):
        np.testing.assert_array_equal(hit, expected)
    ray_launches.release_buffers()
    assert ray_launches._launch_pool.nbytes() == 0


def test_hit_rays_are_kept_as_they_were_at_the_call(cl_runtime):
    # t is computed when first read, from the rays as they were when cast_rays was called
    mesh = ao4d.SimplexMesh([[0, 0, 1], [1, 0, 1], [0, 1, 1]], [[0, 1, 2]])
    o = np.array([[0.2, 0.2, 0.0]])
    w = np.array([[0.0, 0.0, 2.0]])
    hits = api.cast_rays(mesh, o, w, backend="opencl")
    o[:] = 5.0
    w[:] = 1.0
    assert hits.t[0] == 1.0 and hits.simplex[0] == 0
    np.testing.assert_allclose(hits.barycentric[0], [0.6, 0.2, 0.2])


def _dense_4d_surfaces():
    """Small 4D surfaces with dense mutual occlusion (as bench._shapes' tori and metaballs):
    three interlocked torispheres around a ball, and a cluster of six metaballs."""
    f = ao4d.fields
    torus = f.torisphere(0.9, 0.28)
    tori = f.union(
        f.hypersphere(0.6),
        torus,
        f.rotate(f.rotate(torus, (0, 2), np.pi / 2), (1, 3), np.pi / 2),
        f.rotate(f.rotate(torus, (1, 2), np.pi / 2), (0, 3), np.pi / 4),
    )
    balls = f.metaballs(np.random.default_rng(3).uniform(-0.5, 0.5, size=(6, 4)), 0.35, sharpness=8.0)
    return {
        "tori": ao4d.extract_field(tori, (11,) * 4, (-1.3, 1.3)),
        "metaballs": ao4d.extract_field(balls, (11,) * 4, (-1.0, 1.0)),
    }


@pytest.mark.parametrize("lanes", [16, 4])  # the CPU and GPU leaf layouts
@pytest.mark.parametrize("shift", [0.0, 3e4])  # far from the origin: the tree's float64 frame
def test_ao_counts_on_dense_shapes_equal_brute_force(lanes, shift, cl_runtime, monkeypatch):
    # every AO ray's answer, both traversals, equals the any-hit answer over every simplex, with
    # unlimited reach and a quarter of the diagonal: the counts cannot change while this holds
    monkeypatch.setattr(bvh.cache, "block_lanes", lambda runtime, dim=None: lanes)
    for name, base in _dense_4d_surfaces().items():
        mesh = ao4d.SimplexMesh(base.vertices + shift, base.simplices)
        p, n, tree, offset = _surface_points(mesh, cl_runtime, every=7)
        for max_distance in (np.inf, 0.25 * tree.diagonal):
            packet = _ao_counts(mesh, cl_runtime, p, n, 40, offset, max_distance)
            rays = _ao_counts(mesh, cl_runtime, p, n, 40, offset, max_distance, traversal="rays")
            brute = _ao_counts(mesh, cl_runtime, p, n, 40, offset, max_distance, accel="brute")
            np.testing.assert_array_equal(packet, brute, err_msg=name)
            np.testing.assert_array_equal(rays, brute, err_msg=name)
            assert 0.03 < packet.mean() / 40 < 0.6, name  # occluded, not closed off


def _mesh_forms():
    """A closed 3D mesh as a SimplexMesh, as a trimesh.Trimesh and as a (vertices, simplices) pair."""
    import trimesh

    tri = trimesh.creation.icosphere(subdivisions=1)
    mesh = ao4d.SimplexMesh.from_trimesh(tri)
    return mesh, {"trimesh": tri, "pair": (np.asarray(tri.vertices), np.asarray(tri.faces))}


@pytest.mark.parametrize("form", ["trimesh", "pair"])
@pytest.mark.parametrize("closest", [True, False])
def test_cast_rays_takes_a_trimesh_and_a_pair(form, closest):
    mesh, forms = _mesh_forms()
    rng = np.random.default_rng(7)
    o = rng.normal(size=(300, 3)) * 2.0
    w = -o + rng.normal(size=(300, 3)) * 0.3  # most rays aim at the sphere
    want = api.cast_rays(mesh, o, w, closest=closest, backend="numpy")
    got = api.cast_rays(forms[form], o, w, closest=closest, backend="numpy")
    assert (want.simplex >= 0).sum() > 100
    np.testing.assert_array_equal(got.simplex, want.simplex)
    np.testing.assert_array_equal(got.t, want.t)
    np.testing.assert_array_equal(got.barycentric, want.barycentric)
    # a 4D pair too
    soup = soup_scene(np.random.default_rng(3), 4)
    o4, w4 = random_rays(np.random.default_rng(4), 4, 500)
    want4 = api.cast_rays(soup, o4, w4, backend="numpy")
    got4 = api.cast_rays((soup.vertices, soup.simplices), o4, w4, backend="numpy")
    np.testing.assert_array_equal(got4.simplex, want4.simplex)
    np.testing.assert_array_equal(got4.t, want4.t)


@pytest.mark.parametrize("form", ["trimesh", "pair"])
def test_count_occluded_takes_a_trimesh_and_a_pair(form):
    mesh, forms = _mesh_forms()
    points, normals = np.asarray(mesh.vertices) * 1.5, np.asarray(mesh.vertices)  # above the sphere, facing out
    points[::2] *= 0.0  # half of them at the centre, facing out: every ray hits
    args = dict(samples=16, seed=2, offset=1e-6, max_distance=np.inf, runtime=None)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    want = api.count_occluded(mesh, points, normals, **args)
    got = api.count_occluded(forms[form], points, normals, **args)
    assert want[::2].tolist() == [16] * len(want[::2]) and want[1::2].max() == 0
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("form", ["trimesh", "pair"])
def test_traversal_counts_takes_a_trimesh_and_a_pair(form, cl_runtime):
    mesh, forms = _mesh_forms()
    points, normals = np.asarray(mesh.vertices) * 0.5, np.asarray(mesh.vertices)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    args = dict(samples=8, offset=0.0, runtime=cl_runtime)
    want = api.traversal_counts(mesh, points, normals, **args)
    got = api.traversal_counts(forms[form], points, normals, **args)
    assert got == want


@pytest.mark.parametrize(
    "call",
    [
        lambda bad: api.cast_rays(bad, [[0, 0, 0]], [[0, 0, 1]], backend="numpy"),
        lambda bad: api.count_occluded(
            bad, np.zeros((1, 3)), np.eye(3)[:1], samples=4, seed=0, offset=0.0, max_distance=1.0, runtime=None
        ),
        lambda bad: api.traversal_counts(bad, np.zeros((1, 3)), np.eye(3)[:1], samples=4, offset=0.0, runtime=None),
        lambda bad: ray_rows.mesh_arrays(bad),
    ],
)
def test_a_wrong_mesh_type_is_a_type_error_naming_mesh(call):
    for bad in (object(), "sphere.npz", 3.0, [1, 2, 3]):
        with pytest.raises(
            TypeError, match="`mesh` must be a SimplexMesh, a trimesh.Trimesh, a \\(vertices, simplices\\)"
        ):
            call(bad)
