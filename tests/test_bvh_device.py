"""The BVH built by OpenCL kernels (ao4d.bvh.device) against the numpy builder and brute force.

Structure, bounds, degenerate simplices and bad input are checked for both builders in
tests/test_bvh.py (fixture ``build_bvh``), the numpy traversal of both trees in
tests/test_rays.py. Here: per-simplex data equal to the host's bit for bit, OpenCL hits equal
to brute force with the device tree and with the host tree, identical AO, tree quality (SAH
cost), independence of the work decomposition, and the cache on the mesh.
"""

from __future__ import annotations

import numpy as np
import pytest
from _scenes import random_rays, random_soup, soup_scene, sphere_over_ground

import ao4d
from ao4d import bvh
from ao4d.bvh import cache, device
from ao4d.rays import api

DIMS = (2, 3, 4)


def has_double(runtime) -> bool:
    return device._has_double(runtime.device)


def extracted(d: int, n: int) -> ao4d.SimplexMesh:
    """A closed surface extracted from a field: a sphere in 3D, a spheritorus in 4D."""
    if d == 3:
        return ao4d.extract_field(lambda p: np.linalg.norm(p, axis=-1) - 0.8, (n, n, n), (-1.0, 1.0))
    field = ao4d.fields.spheritorus(1.0, 0.4)
    return ao4d.extract_field(field, (n, n, n, max(6, n // 3)), ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))


def device_blocks(runtime, tree, lanes):
    import pyopencl as pcl

    dev = bvh.blocks.device_wide_tree(tree, runtime, lanes)
    blocks = np.empty((int(dev["n_blocks"]), tree.dim + 1, tree.dim, lanes), dtype=np.float32)
    pcl.enqueue_copy(runtime.queue, blocks, dev["blocks"])
    runtime.queue.finish()
    return dev, blocks


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("lanes", [16, 4])
def test_leaf_blocks_filled_on_the_device_equal_the_host_widening(d, lanes, cl_runtime):
    # the kernels repeat the host's float64 operations: every lane of every block is bit-equal
    # to bvh.widen's (which rounds the host's float64 inverse to float32)
    if not has_double(cl_runtime):
        pytest.skip("the device has no double precision: its inverses are float32 computations")
    rng = np.random.default_rng(10 + d)
    vertices, simplices = random_soup(rng, d, 1500)
    tree = device.build(vertices, simplices, runtime=cl_runtime, subtree=128, chunk=64)
    dev, blocks = device_blocks(cl_runtime, tree, lanes)
    wide = bvh.widen(tree, lanes)  # host widening of the same tree, from the host's float64 data
    np.testing.assert_array_equal(blocks, wide.blocks)
    np.testing.assert_array_equal(dev["block_first"], wide.block_prim[:, 0])
    host = bvh.build(vertices, simplices)
    where = np.argsort(host.prim)[tree.prim]  # the host tree's position of each simplex
    np.testing.assert_array_equal(tree.inverse, host.inverse[where])
    np.testing.assert_array_equal(tree.origin, host.origin[where])
    inv, org = tree.frames(np.array([5, 0, 17]))
    np.testing.assert_array_equal(inv, host.inverse[where[[5, 0, 17]]])
    np.testing.assert_array_equal(org, host.origin[where[[5, 0, 17]]])


@pytest.mark.parametrize("d", DIMS)
def test_boxes_equal_the_host_boxes_of_their_simplices(d, cl_runtime):
    # with leaf_size=1 every host leaf box is one simplex's box (margins, outward rounding);
    # a device node's box must be exactly the union of its simplices' host boxes
    if not has_double(cl_runtime):
        pytest.skip("the device has no double precision: boxes are float32 computations")
    rng = np.random.default_rng(20 + d)
    vertices, simplices = random_soup(rng, d, 800)
    host = bvh.build(vertices, simplices, leaf_size=1)
    leaf = host.meta[:, 0] < 0
    box_lo = np.empty((host.n_prims, 4), dtype=np.float32)
    box_hi = np.empty((host.n_prims, 4), dtype=np.float32)
    simplex = host.prim[-host.meta[leaf, 0] - 1]
    box_lo[simplex], box_hi[simplex] = host.lo[leaf], host.hi[leaf]
    tree = device.build(vertices, simplices, runtime=cl_runtime, subtree=64, chunk=32)
    for k, (a, b) in enumerate(tree.meta):
        if a < 0:
            ids = tree.prim[-a - 1 : -a - 1 + b]
            np.testing.assert_array_equal(tree.lo[k], box_lo[ids].min(0))
            np.testing.assert_array_equal(tree.hi[k], box_hi[ids].max(0))
    assert tree.diagonal == host.diagonal


@pytest.mark.parametrize("d", DIMS)
def test_work_decomposition_does_not_change_the_tree(d, cl_runtime):
    # subtree/chunk sizes follow the device (GPUs get small ones); the tree must not: the
    # level passes over large nodes and the per-work-item subtrees choose the same splits
    rng = np.random.default_rng(30 + d)
    vertices, simplices = random_soup(rng, d, 3000, size=0.05)
    trees = [
        device.build(vertices, simplices, runtime=cl_runtime, subtree=s, chunk=c)
        for s, c in ((None, None), (32, 16), (256, 1000), (4096, 256))
    ]
    for other in trees[1:]:
        for name in ("lo", "hi", "meta", "prim"):
            np.testing.assert_array_equal(getattr(other, name), getattr(trees[0], name))
        assert other.depth == trees[0].depth
    again = device.build(vertices, simplices, runtime=cl_runtime, subtree=32, chunk=16)
    np.testing.assert_array_equal(again.meta, trees[1].meta)  # deterministic despite atomics


@pytest.mark.parametrize("d", (3, 4))
def test_sah_cost_is_no_worse_than_the_host_tree(d, cl_runtime):
    mesh = extracted(d, 20 if d == 4 else 40)
    host = bvh.build(mesh.vertices, mesh.simplices)
    tree = device.build(mesh.vertices, mesh.simplices, runtime=cl_runtime)
    assert tree.n_prims == host.n_prims > 5000
    # the same binned SAH without rounding left sides to whole leaves: at most a few % worse
    # (measured: 40% lower on the benchmark's spheritorus, whose AO then runs 6-15% faster)
    assert bvh.sah_cost(tree) <= 1.03 * bvh.sah_cost(host)
    assert tree.depth <= bvh.host._SAH_MAX_LEVEL + np.log2(tree.n_prims) + 1


def test_sah_cost_of_a_two_leaf_tree():
    # two unit squares' diagonals far apart in 3D: root box area A, leaf boxes a each
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [9, 0, 0], [10, 0, 0], [9, 1, 0]], float)
    tree = bvh.build(v, [[0, 1, 2], [3, 4, 5]], leaf_size=1)
    assert tree.n_nodes == 3
    d = 3
    area = bvh.box_area(tree.lo[:, :d].astype(float), tree.hi[:, :d].astype(float))
    expected = (2.0 * area[0] + 3.0 * (area[1] + area[2])) / area[0]
    assert bvh.sah_cost(tree, traversal=2.0, intersection=3.0) == pytest.approx(expected, rel=1e-12)
    # about the analytic value: each leaf a flat 1 x 1 box, the root 10 x 1 (margins aside)
    assert bvh.sah_cost(tree) == pytest.approx(1 + 2 * (2 * 1) / (2 * 10), rel=1e-3)


def test_flat_centroids_and_duplicates(cl_runtime):
    # 300 copies of one triangle: every centroid equal, no SAH split exists; halves instead
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    simplices = np.tile([0, 1, 2], (300, 1))
    for subtree in (None, 32):
        tree = device.build(v, simplices, runtime=cl_runtime, subtree=subtree, chunk=16)
        assert sorted(tree.prim.tolist()) == list(range(300))
        leaves = tree.meta[tree.meta[:, 0] < 0]
        assert leaves[:, 1].max() <= 16 and leaves[:, 1].sum() == 300
    mesh = ao4d.SimplexMesh(v, simplices)
    bvh.get_bvh(mesh, builder="device", runtime=cl_runtime)
    hits = api.cast_rays(mesh, [[0.2, 0.2, -1.0], [0.9, 0.9, -1]], [[0, 0, 1], [0, 0, 1]], backend="opencl")
    assert hits.simplex[0] >= 0 and hits.simplex[1] == -1
    assert hits.t[0] == pytest.approx(1.0)


def test_all_degenerate_and_bad_parameters(cl_runtime):
    with pytest.raises(ValueError, match="all 2 simplices are degenerate"):
        device.build(np.eye(3), [[0, 1, 1], [2, 2, 2]], runtime=cl_runtime)
    with pytest.raises(ValueError, match="`subtree`"):
        device.build(np.eye(3), [[0, 1, 2]], runtime=cl_runtime, subtree=4)
    with pytest.raises(ValueError, match="`chunk`"):
        device.build(np.eye(3), [[0, 1, 2]], runtime=cl_runtime, chunk=0)
    with pytest.raises(ValueError, match="`builder` must be one of"):
        bvh.get_bvh(ao4d.SimplexMesh(np.eye(3), [[0, 1, 2]]), builder="gpu")


# -- tracing both trees -----------------------------------------------------------------------


def mesh_with_tree(mesh, builder, runtime):
    """A fresh copy of ``mesh`` whose cached tree comes from ``builder``."""
    fresh = ao4d.SimplexMesh(mesh.vertices, mesh.simplices)
    bvh.get_bvh(fresh, builder=builder, runtime=runtime)
    return fresh


@pytest.mark.parametrize("d", (3, 4))
@pytest.mark.parametrize("lanes", [16, 4])  # CPUs, GPUs (bvh.block_lanes)
def test_both_trees_give_brute_force_hits_and_the_same_ao(d, lanes, cl_runtime, monkeypatch):
    monkeypatch.setattr(cache, "block_lanes", lambda runtime, dim=None: lanes)
    rng = np.random.default_rng(40 + d)
    scene = soup_scene(rng, d, n=600)
    o, w = random_rays(rng, d, 4000)
    ground = sphere_over_ground(rng, d)
    results = {}
    for builder in ("host", "device"):
        mesh = mesh_with_tree(scene, builder, cl_runtime)
        assert isinstance(bvh.get_bvh(mesh), device.DeviceBVH) == (builder == "device")
        for closest in (True, False):
            fast = api.cast_rays(mesh, o, w, closest=closest, backend="opencl")
            slow = api.cast_rays(mesh, o, w, closest=closest, backend="opencl", accel="brute")
            np.testing.assert_array_equal(fast.hit, slow.hit)
            assert 0.05 < fast.hit.mean() < 0.95
            if closest:
                np.testing.assert_array_equal(fast.t, slow.t)
                results[builder] = fast
        shaded = mesh_with_tree(ground, builder, cl_runtime)
        results[builder + " ao"] = ao4d.ambient_occlusion(shaded, samples=32, backend="opencl")
    np.testing.assert_array_equal(results["host"].t, results["device"].t)
    np.testing.assert_array_equal(results["host"].hit, results["device"].hit)
    a, b = results["host ao"], results["device ao"]
    np.testing.assert_array_equal(a, b)  # bit-equal leaf data, exact trees: identical AO
    assert 0.05 < np.nanmean(a) < 0.95


@pytest.mark.parametrize("d", (3, 4))
def test_numpy_backend_traces_a_device_tree(d, cl_runtime):
    # a device-built tree computes its float64 frames on the host when the numpy traversal needs them
    rng = np.random.default_rng(50 + d)
    mesh = mesh_with_tree(soup_scene(rng, d), "device", cl_runtime)
    o, w = random_rays(rng, d, 500)
    numpy_hits = api.cast_rays(mesh, o, w, backend="numpy")
    host_hits = api.cast_rays(mesh_with_tree(mesh, "host", None), o, w, backend="numpy")
    np.testing.assert_array_equal(numpy_hits.simplex, host_hits.simplex)
    np.testing.assert_array_equal(numpy_hits.t, host_hits.t)


def test_tree_is_built_once_and_reused_by_render(cl_runtime, monkeypatch):
    builds = []
    real_build = device.build

    def counting(*args, **kwargs):
        builds.append(1)
        return real_build(*args, **kwargs)

    monkeypatch.setattr(device, "build", counting)
    monkeypatch.setattr(bvh.host, "build", lambda *a, **k: pytest.fail("the host builder ran"))
    rng = np.random.default_rng(60)
    mesh = sphere_over_ground(rng, 4)
    ao4d.ambient_occlusion(mesh, samples=8, backend="opencl")
    assert len(builds) == 1
    tree = bvh.get_bvh(mesh)
    assert isinstance(tree, device.DeviceBVH)
    camera = ao4d.Camera4D(eye=(0, -3, 1, 0), target=(0, 0, 0.3, 0), up=(0, 0, 1, 0), over=(0, 0, 0, 1))
    ao4d.render(mesh, camera, (8, 8, 4), ao="vertices", backend="opencl")
    ao4d.ambient_occlusion(mesh, samples=8, backend="opencl")
    api.cast_rays(mesh, [[0, 0, 3, 0]], [[0, 0, -1, 0]], backend="opencl")
    assert len(builds) == 1 and bvh.get_bvh(mesh) is tree
    mesh.vertices = mesh.vertices * 2.0  # an edited mesh drops its tree
    ao4d.ambient_occlusion(mesh, samples=8, backend="opencl")
    assert len(builds) == 2


def test_numpy_backend_builds_on_the_host(monkeypatch):
    monkeypatch.setattr(device, "build", lambda *a, **k: pytest.fail("the device builder ran"))
    mesh = soup_scene(np.random.default_rng(70), 3, n=50)
    ao4d.ambient_occlusion(mesh, samples=4, backend="numpy")
    assert not isinstance(bvh.get_bvh(mesh), device.DeviceBVH)


def test_traversal_counts_of_a_one_leaf_tree(cl_runtime):
    # one triangle: the wide tree is a root with one leaf slot, so every ray visits one node and
    # tests the leaf block iff it meets the triangle's box; rays away from it test none
    mesh = ao4d.SimplexMesh([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], [[0, 1, 2]])
    bvh.get_bvh(mesh, runtime=cl_runtime)
    up = np.tile([0.0, 0.0, 1.0], (50, 1))
    points = np.column_stack([np.zeros((50, 2)), np.ones(50)])
    nodes, blocks = api.traversal_counts(mesh, points, up, samples=16, offset=0.0, runtime=cl_runtime)
    assert (nodes, blocks) == (1.0, 0.0)
    nodes, blocks = api.traversal_counts(mesh, points, -up, samples=64, offset=0.0, runtime=cl_runtime)
    occluded = ao4d.ambient_occlusion(mesh, points=points, normals=-up, samples=64, backend="opencl")
    assert nodes == 1.0
    assert occluded.mean() <= blocks <= 1.0  # every hit tested the block; so did near misses
    assert 0.2 < occluded.mean() < 0.9


@pytest.mark.parametrize("d", (3, 4))
def test_single_precision_devices(d, cl_runtime, monkeypatch):
    # devices without cl_khr_fp64 compute the per-simplex data in float: the tree must still
    # answer exactly as brute force over its own leaf blocks, and AO stay near the host tree's
    monkeypatch.setattr(device, "_has_double", lambda device: False)
    rng = np.random.default_rng(80 + d)
    scene = soup_scene(rng, d, n=400)
    mesh = mesh_with_tree(scene, "device", cl_runtime)
    o, w = random_rays(rng, d, 3000)
    fast = api.cast_rays(mesh, o, w, backend="opencl")
    slow = api.cast_rays(mesh, o, w, backend="opencl", accel="brute")
    np.testing.assert_array_equal(fast.hit, slow.hit)
    np.testing.assert_array_equal(fast.t, slow.t)
    host = api.cast_rays(mesh_with_tree(scene, "host", None), o, w, backend="opencl")
    assert (fast.hit != host.hit).mean() <= 1e-3  # float32 inverses: only grazing rays differ
    ground = sphere_over_ground(rng, d)
    a = ao4d.ambient_occlusion(mesh_with_tree(ground, "device", cl_runtime), samples=32, backend="opencl")
    b = ao4d.ambient_occlusion(mesh_with_tree(ground, "host", None), samples=32, backend="opencl")
    assert np.mean(a == b) >= 0.97 and np.nanmax(np.abs(a - b)) <= 2 / 32


@pytest.mark.parametrize("d", (3, 4))
def test_kept_build_scratch_gives_the_trees_of_fresh_buffers(d, cl_runtime):
    """Builds keep their scratch for the next build (ao4d.opencl.pool): a small mesh built after
    a large one (its records, bins and nodes left in the buffers), and meshes built by four
    threads at once, give the trees of builds on fresh buffers."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(2150 + d)
    meshes = [soup_scene(rng, d, n=n) for n in (3000, 200, 1200)]

    def tree_of(mesh):
        t = device.build(mesh.vertices, mesh.simplices, runtime=cl_runtime)
        return t.meta, t.lo, t.hi, t.prim

    fresh = []
    for mesh in meshes:
        device.release_buffers()
        fresh.append(tree_of(mesh))
    assert device._scratch.nbytes() > 0  # the last build kept its scratch
    for mesh, want in zip(meshes, fresh):  # large, small, middle: each reuses the last's
        for a, b in zip(tree_of(mesh), want):
            np.testing.assert_array_equal(a, b)
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(tree_of, meshes * 4))
    for tree, want in zip(got, fresh * 4):
        for a, b in zip(tree, want):
            np.testing.assert_array_equal(a, b)
    device.release_buffers()
    assert device._scratch.nbytes() == 0


def test_build_copies_are_freed_once_the_traversed_tree_exists(cl_runtime):
    # the build's device copies of the mesh (1.4 GB at 55 M tets) stayed for the mesh's lifetime
    rng = np.random.default_rng(2100)
    mesh = soup_scene(rng, 4, n=500)
    tree = bvh.get_bvh(mesh, builder="device", runtime=cl_runtime)
    assert tree.device_source is None and tree.device_wide  # the traversed form stays
    o, w = random_rays(rng, 4, 2000)
    hits = api.cast_rays(mesh, o, w, backend="opencl")
    brute = api.cast_rays(mesh, o, w, backend="opencl", accel="brute")
    np.testing.assert_array_equal(hits.simplex >= 0, brute.simplex >= 0)
    # the traced form is the one filled at the build: freeing the copies made the first trace
    # widen the tree again on the host (3.4 of a first AO call's 7.9 s at 1.2 M tets)
    assert not tree._wide
    # another block width is widened on the host from the same tree
    assert bvh.blocks.device_wide_tree(tree, cl_runtime, 4) is None
    assert bvh.wide(tree, 4).blocks.shape[-1] == 4


@pytest.mark.parametrize("d", (3, 4))
def test_trees_on_recycled_buffers_trace_as_trees_on_fresh_ones(d, cl_runtime, monkeypatch):
    """A tree's device buffers go back to ao4d.opencl.pool.TREES when nothing holds them, and
    the next tree is built in them: its hits and AO equal a tree's on fresh buffers, and a tree
    still held (by its mesh's cache) keeps its own."""
    import gc

    from ao4d.opencl import pool

    monkeypatch.setattr(pool, "RECYCLE_MIN_BYTES", 1)  # these small trees' buffers too
    rng = np.random.default_rng(2170 + d)
    scenes = [soup_scene(rng, d, n=n) for n in (1500, 300, 900)]
    o, w = random_rays(rng, d, 3000)

    def traced(scene):
        mesh = ao4d.SimplexMesh(scene.vertices, scene.simplices)  # no tree yet
        hits = api.cast_rays(mesh, o, w, backend="opencl")
        return mesh, hits.simplex, ao4d.ambient_occlusion(mesh, samples=16, backend="opencl")

    device.release_buffers()
    fresh = []
    for scene in scenes:
        _, simplex, ao = traced(scene)
        fresh.append((simplex, ao))
        device.release_buffers()  # each on fresh buffers
    assert pool.TREES.nbytes() == 0
    held, _, _ = traced(scenes[0])  # this mesh keeps its tree
    (traversed,) = bvh.get_bvh(held).device_wide.values()
    mine = {traversed[key].int_ptr for key in ("boxes", "children", "blocks")}

    def recycled():
        return {b.int_ptr for _, bufs in pool.TREES._held.values() for b in bufs}

    gc.collect()
    assert recycled() and not recycled() & mine  # the build's copies are back, not the tree
    for scene, (simplex, ao) in zip(scenes[1:] * 2, fresh[1:] * 2):
        mesh, got_simplex, got_ao = traced(scene)
        np.testing.assert_array_equal(got_simplex, simplex)
        np.testing.assert_array_equal(got_ao, ao)
        (dev,) = bvh.get_bvh(mesh).device_wide.values()
        theirs = {dev[key].int_ptr for key in ("boxes", "children", "blocks")}
        del mesh, dev
        gc.collect()
        assert theirs <= recycled()  # back for the next tree once the mesh went
        assert not recycled() & mine
    # the held tree was never built over
    np.testing.assert_array_equal(api.cast_rays(held, o, w, backend="opencl").simplex, fresh[0][0])
    device.release_buffers()
    assert pool.TREES.nbytes() == 0


@pytest.mark.parametrize("lanes", [4, 16])  # 4: a GPU's blocks, accepted up to 64 and failing at the trace
def test_leaf_size_beyond_the_leaf_encoding_is_refused_up_front(lanes, cl_runtime, monkeypatch):
    monkeypatch.setattr(cache, "block_lanes", lambda runtime, dim=None: lanes)
    mesh = soup_scene(np.random.default_rng(2200), 3, n=50)
    with pytest.raises(ValueError, match=rf"`leaf_size` must be at most {4 * lanes} on this device"):
        bvh.get_bvh(mesh, leaf_size=4 * lanes + 1, runtime=cl_runtime)
    assert bvh.get_bvh(mesh, leaf_size=4 * lanes, runtime=cl_runtime).n_prims == 50


def test_block_lanes_follow_the_device_and_the_dimension():
    # GPUs: 4; CPUs: 16, except triangles and segments on CPUs whose float vectors hold 8 (AVX2),
    # where 8-lane blocks traced 3D rays in 0.91-0.94x the time; the leaf-size limit follows
    import types

    import pyopencl as pcl

    def fake(kind, width):
        return types.SimpleNamespace(device=types.SimpleNamespace(type=kind, native_vector_width_float=width))

    cpu, gpu = pcl.device_type.CPU, pcl.device_type.GPU
    assert [cache.block_lanes(fake(gpu, 8), d) for d in (2, 3, 4, None)] == [4, 4, 4, 4]
    assert [cache.block_lanes(fake(cpu, 8), d) for d in (2, 3, 4, None)] == [8, 8, 16, 16]
    assert [cache.block_lanes(fake(cpu, 16), d) for d in (2, 3, 4, None)] == [16, 16, 16, 16]


def test_a_3d_tree_on_this_device_has_the_devices_block_lanes(cl_runtime):
    mesh = soup_scene(np.random.default_rng(2250), 3, n=300)
    tree = bvh.get_bvh(mesh, runtime=cl_runtime)
    dev = bvh.device_tree(mesh, tree, cl_runtime)
    assert dev["lanes"] == cache.block_lanes(cl_runtime, 3)
    lanes = dev["lanes"]
    with pytest.raises(ValueError, match=rf"`leaf_size` must be at most {4 * lanes} on this device"):
        bvh.get_bvh(mesh, leaf_size=4 * lanes + 1, runtime=cl_runtime)


# a tetrahedron of R^4 at the degeneracy threshold: |n| / L^3 falls between the one rounding of
# numpy's L ** 3 and the two of the kernel's L * L * L; a unit one far away keeps the
# mesh from being all degenerate
SLIVER_A, SLIVER_H = 2.0219080013611848, 4.088111965968381e-12


def sliver_mesh(first: bool) -> ao4d.SimplexMesh:
    a, h = SLIVER_A, SLIVER_H
    sliver = [(0, 0, 0, 0), (a, 0, 0, 0), (0, 1, 0, 0), (0, 0, 0, h)]
    unit = [(5, 0, 0, 0), (6, 0, 0, 0), (5, 1, 0, 0), (5, 0, 1, 0)]
    simplices = [[0, 1, 2, 3], [4, 5, 6, 7]] if first else [[4, 5, 6, 7], [0, 1, 2, 3]]
    return ao4d.SimplexMesh(np.array(sliver + unit, dtype=float), simplices)


@pytest.mark.parametrize("double", [True, False])  # False: a device without cl_khr_fp64, forced
@pytest.mark.parametrize("first", [True, False])
def test_sliver_at_the_degeneracy_threshold_traces_alike_on_both_backends(double, first, cl_runtime, monkeypatch):
    if double and not has_double(cl_runtime):
        pytest.skip("this OpenCL device has no cl_khr_fp64")
    if not double:
        monkeypatch.setattr(device, "_has_double", lambda device: False)
    h = SLIVER_H
    o, w = [(0.3, 0.3, -1.0, h / 4)], [(0.0, 0.0, 1.0, 0.0)]
    hits = {b: api.cast_rays(sliver_mesh(first), o, w, backend=b) for b in ("numpy", "opencl")}
    np.testing.assert_array_equal(hits["opencl"].simplex, hits["numpy"].simplex)
    np.testing.assert_array_equal(hits["opencl"].t, hits["numpy"].t)  # closest hit: t in float64
    assert hits["numpy"].simplex[0] == (0 if first else 1) and hits["numpy"].t[0] == 1.0
    any_hit = api.cast_rays(sliver_mesh(first), o, w, closest=False, backend="opencl")
    np.testing.assert_array_equal(any_hit.simplex, hits["numpy"].simplex)


@pytest.mark.parametrize("d", (3, 4))
def test_both_builders_keep_the_same_simplices_without_doubles(d, cl_runtime, monkeypatch):
    # a float test kept slivers the float64 one skips (44-232 per extracted mesh) and the
    # closest-hit refinement of a hit on one raised
    monkeypatch.setattr(device, "_has_double", lambda device: False)
    rng = np.random.default_rng(3100 + d)
    scene = soup_scene(rng, d, n=300)
    v = scene.vertices.copy()
    flat = rng.integers(0, len(scene.simplices), 60)  # squash 60 simplices to slivers of every thinness
    s = scene.simplices[flat]
    v = np.concatenate(
        [
            v,
            v[s[:, 0]]
            + (v[s[:, 1]] - v[s[:, 0]]) * 0.5
            + 10.0 ** rng.uniform(-16, -8, (60, 1)) * rng.normal(size=(60, d)),
        ]
    )
    simplices = scene.simplices.copy()
    simplices[flat, -1] = len(scene.vertices) + np.arange(60)
    mesh = ao4d.SimplexMesh(v, simplices)
    dev = bvh.get_bvh(mesh_with_tree(mesh, "device", cl_runtime), builder="device")
    cpu = bvh.get_bvh(mesh_with_tree(mesh, "host", None), builder="host")
    assert cpu.n_skipped > 0
    assert dev.n_skipped == cpu.n_skipped
    np.testing.assert_array_equal(np.sort(dev.prim), np.sort(cpu.prim))
    o, w = random_rays(rng, d, 2000)
    fast = api.cast_rays(mesh_with_tree(mesh, "device", cl_runtime), o, w, backend="opencl")
    assert np.isfinite(fast.t[fast.hit]).all()  # the float64 refinement of every closest hit


def test_inverses_of_kept_slivers_are_finite():
    # DeviceBVH.frames' fallback when the device keeps a simplex the float64 test skips
    mesh = sliver_mesh(True)
    inverse = device._frames_unfiltered(mesh.vertices, mesh.simplices)
    assert np.isfinite(inverse).all()
    _, _, exact = bvh.host.frames(mesh.vertices, mesh.simplices[1:])
    np.testing.assert_allclose(inverse[1], exact[0], atol=1e-12)


def test_a_traced_mesh_and_its_tree_go_with_the_last_name(cl_runtime):
    # no reference cycle through the mesh, its cache, the tree or the device buffers: the
    # tree's buffers are back for the next one at once, not at the next collection
    import gc
    import weakref

    mesh = sphere_over_ground(np.random.default_rng(2190), 4)
    ao4d.ambient_occlusion(mesh, samples=8, backend="opencl")
    mesh_ref, tree_ref = weakref.ref(mesh), weakref.ref(bvh.get_bvh(mesh))
    gc.collect()
    gc.disable()
    try:
        del mesh
        assert mesh_ref() is None and tree_ref() is None
    finally:
        gc.enable()
