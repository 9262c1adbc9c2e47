"""BVH build (structure, bounds, degenerate simplices, caching) and the ray-simplex test."""

from __future__ import annotations

import numpy as np
import pytest
from _scenes import random_soup
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import ao4d
from ao4d import bvh
from ao4d.geometry import cross

DIMS = (2, 3, 4)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("leaf_size", [1, 4, 7, 16])
def test_tree_structure_and_bounds(d, leaf_size, build_bvh):
    rng = np.random.default_rng(100 * d + leaf_size)
    vertices, simplices = random_soup(rng, d, 500)
    tree = build_bvh(vertices, simplices, leaf_size=leaf_size)
    assert sorted(tree.prim.tolist()) == list(range(500))  # every simplex exactly once
    corners = vertices[simplices[tree.prim]]
    lo, hi = tree.lo[:, :d], tree.hi[:, :d]
    seen = np.zeros(tree.n_prims, dtype=int)
    reached = np.zeros(tree.n_nodes, dtype=int)
    reached[0] = 1
    for k, (a, b) in enumerate(tree.meta):
        if a < 0:
            first, count = -a - 1, b
            assert 1 <= count <= leaf_size
            seen[first : first + count] += 1
            box = corners[first : first + count]
            assert (box.min((0, 1)) >= lo[k]).all() and (box.max((0, 1)) <= hi[k]).all()
        else:
            assert a > k and b > k  # numbered breadth first: children after their parent
            reached[[a, b]] += 1
            for c in (a, b):
                assert (lo[c] >= lo[k]).all() and (hi[c] <= hi[k]).all()
    assert (seen == 1).all()  # leaves partition the primitive range
    assert (reached == 1).all()  # a tree: every node has exactly one parent
    assert (tree.lo[:, d:] == 0).all() and (tree.hi[:, d:] == 0).all()  # float4 padding
    assert tree.depth < 64  # the kernels' stack bound
    # the stored inverse really inverts [e1 .. e_{d-1} | n]
    edges = corners[:, 1:] - corners[:, :1]
    normals = corner_normals(corners)
    matrix = np.concatenate([edges, normals[:, None]], axis=1).transpose(0, 2, 1)
    np.testing.assert_allclose(tree.inverse @ matrix, np.broadcast_to(np.eye(d), matrix.shape), atol=1e-8)


def test_degenerate_simplices_are_skipped(build_bvh):
    rng = np.random.default_rng(7)
    vertices, simplices = random_soup(rng, 4, 50)
    flat = simplices.copy()
    flat[:5, 1] = flat[:5, 0]  # repeated vertex: zero volume
    tree = build_bvh(vertices, flat)
    assert tree.n_skipped == 5 and tree.n_prims == 45
    assert set(tree.prim.tolist()) == set(range(5, 50))


@settings(max_examples=80, deadline=None)
@given(
    d=st.sampled_from(DIMS),
    seed=st.integers(0, 2**32 - 1),
    distance=st.floats(0.01, 10.0),
)
def test_ray_hits_the_point_it_aims_at(d, seed, distance):
    rng = np.random.default_rng(seed)
    corners = rng.normal(size=(1, d, d))
    n = corner_normals(corners)[0]
    edges = corners[0, 1:] - corners[0, :1]
    # well-shaped simplices only: the tolerance is relative to barycentric units
    assume(np.linalg.norm(n) > 0.05 * np.prod(np.linalg.norm(edges, axis=1)))
    weights = rng.dirichlet(np.ones(d))
    assume(weights.min() > 1e-3)
    target = weights @ corners[0]
    w = rng.normal(size=d)
    w /= np.linalg.norm(w)
    assume(abs(w @ n) > 0.05 * np.linalg.norm(n))  # not grazing
    origin = target - distance * w
    tree = bvh.build(corners[0], [list(range(d))])
    hit, t = bvh.intersect(tree.inverse, tree.origin, origin[None], w[None], np.array([np.inf]))
    assert hit[0]
    assert t[0] == pytest.approx(distance, rel=1e-9, abs=1e-9)
    np.testing.assert_allclose(bvh.barycentric(tree.inverse, tree.origin, target[None])[0], weights, atol=1e-9)
    # shorter max distance, or the ray pointing away: no hit
    assert not bvh.intersect(tree.inverse, tree.origin, origin[None], w[None], np.array([0.99 * distance]))[0][0]
    assert not bvh.intersect(tree.inverse, tree.origin, origin[None], -w[None], np.array([np.inf]))[0][0]
    # aimed clearly outside the simplex (one barycentric at -0.05): no hit
    outside = weights.copy()
    outside[0] -= 0.05 + weights[0]
    outside[1:] += (0.05 + weights[0]) / (d - 1)
    miss_target = outside @ corners[0]
    assert not bvh.intersect(
        tree.inverse, tree.origin, (miss_target - distance * w)[None], w[None], np.array([np.inf])
    )[0][0]


def test_bvh_is_cached_on_the_mesh_and_rebuilt_after_edits():
    rng = np.random.default_rng(9)
    vertices, simplices = random_soup(rng, 3, 40)
    mesh = ao4d.SimplexMesh(vertices, simplices)
    first = bvh.get_bvh(mesh)
    assert bvh.get_bvh(mesh) is first
    mesh.vertices = vertices + 1.0
    second = bvh.get_bvh(mesh)
    assert second is not first
    # trees hold their mesh in its own frame: the same local geometry, a moved centre
    np.testing.assert_allclose(second.frame.centre, first.frame.centre + 1.0)
    world = [t.origin / t.frame.scale + t.frame.centre for t in (first, second)]
    np.testing.assert_allclose(world[1], world[0] + 1.0)


def test_fallback_cache_for_plain_objects():
    class Plain:
        pass

    rng = np.random.default_rng(10)
    obj = Plain()
    obj.vertices, obj.simplices = random_soup(rng, 3, 10)
    first = bvh.get_bvh(obj)
    assert bvh.get_bvh(obj) is first
    obj.vertices = obj.vertices * 2  # arrays replaced: the fingerprint changes
    assert bvh.get_bvh(obj) is not first


def test_get_bvh_takes_a_trimesh_and_a_pair():
    trimesh = pytest.importorskip("trimesh")
    tm = trimesh.creation.icosphere(subdivisions=1)
    ref = bvh.get_bvh(ao4d.SimplexMesh(tm.vertices, tm.faces))
    for mesh in (tm, (tm.vertices, tm.faces)):
        tree = bvh.get_bvh(mesh)
        np.testing.assert_array_equal(tree.prim, ref.prim)
        np.testing.assert_array_equal(tree.origin, ref.origin)
    with pytest.raises(TypeError, match="`mesh` must be a SimplexMesh"):
        bvh.get_bvh(tm.vertices)


def test_bad_inputs(build_bvh):
    good_v = np.eye(3)
    with pytest.raises(ValueError, match="`simplices` is empty"):
        build_bvh(good_v, np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match="`vertices`.*non-finite"):
        build_bvh([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="`simplices` indices"):
        build_bvh(good_v, [[0, 1, 3]])
    with pytest.raises(ValueError, match="`vertices` must have 2, 3 or 4 columns"):
        build_bvh(np.eye(5), [[0, 1, 2, 3, 4]])
    with pytest.raises(ValueError, match="`simplices` must have shape"):
        build_bvh(good_v, [[0, 1]])
    with pytest.raises(ValueError, match="all 1 simplices are degenerate"):
        build_bvh(good_v, [[0, 1, 1]])
    with pytest.raises(ValueError, match="leaf_size"):
        build_bvh(good_v, [[0, 1, 2]], leaf_size=0)
    with pytest.raises(TypeError, match="`simplices` must hold integers"):
        build_bvh(good_v, [[0.0, 1.0, 2.0]])


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("lanes", [4, 16])  # GPUs, CPUs
@pytest.mark.parametrize("leaf_size", [4, 16])
def test_wide_tree_holds_the_binary_tree(d, lanes, leaf_size):
    rng = np.random.default_rng(200 + d)
    vertices, simplices = random_soup(rng, d, 700)
    tree = bvh.build(vertices, simplices, leaf_size=leaf_size)
    wide = bvh.wide(tree, lanes)
    assert wide is bvh.wide(tree, lanes)  # built once
    assert wide.blocks.shape[1:] == (d + 1, d, lanes)
    # every simplex sits in exactly one lane of one leaf block
    used = wide.block_prim >= 0
    assert sorted(wide.block_prim[used].tolist()) == list(range(tree.n_prims))
    b, lane = np.nonzero(used)
    prim = wide.block_prim[b, lane]
    np.testing.assert_array_equal(wide.blocks[b, :d, :, lane], tree.inverse[prim].astype(np.float32))
    np.testing.assert_array_equal(wide.blocks[b, d, :, lane], tree.origin[prim].astype(np.float32))
    b0, lane0 = np.nonzero(~used)
    assert (wide.blocks[b0, :, :, lane0] == 0).all()  # unused lanes can never be hit
    # every wide node but the root is some node's child exactly once; child boxes hold
    # everything below them
    corners = vertices[simplices[tree.prim]]
    inner = wide.children[wide.children > 0]
    assert sorted(inner.tolist()) == list(range(1, len(wide.children)))

    def blocks_of(c):  # a leaf child -(1 + 4 b + m - 1): blocks b .. b + m - 1 (m <= 4)
        v = -int(c) - 1
        return range(v >> 2, (v >> 2) + (v & 3) + 1)

    listed = [b for c in wide.children[wide.children < 0] for b in blocks_of(c)]
    assert sorted(listed) == list(range(len(wide.blocks)))  # every block in exactly one leaf

    def below(c):
        if c < 0:
            return [p for b in blocks_of(c) for p in wide.block_prim[b] if p >= 0]
        return [p for child in wide.children[c] if child != 0 for p in below(child)]

    for node in range(len(wide.children)):
        for s, c in enumerate(wide.children[node]):
            if c == 0:
                continue
            prims = below(c)
            lo, hi = wide.boxes[node, 0, :, s], wide.boxes[node, 1, :, s]
            assert (corners[prims].min((0, 1)) >= lo).all() and (corners[prims].max((0, 1)) <= hi).all()
    assert wide.depth * 7 + 1 <= bvh.STACK_SIZE


def test_wide_tree_of_a_single_simplex():
    tree = bvh.build(np.eye(3), [[0, 1, 2]])
    wide = bvh.wide(tree, bvh.LANES)
    assert wide.children.tolist() == [[-1, 0, 0, 0, 0, 0, 0, 0]]  # block 0, one block
    assert wide.block_prim.tolist() == [[0] + [-1] * (bvh.LANES - 1)]


def test_wide_tree_needs_small_leaves():
    rng = np.random.default_rng(11)
    tree = bvh.build(*random_soup(rng, 3, 80), leaf_size=20)
    assert len(bvh.wide(tree, 16).blocks) >= 4  # two blocks of 16 per leaf of 20
    with pytest.raises(ValueError, match="at most 16 simplices for 4 lanes"):
        bvh.wide(tree, 4)  # five blocks of 4: more than a leaf slot encodes
    with pytest.raises(ValueError, match="`lanes` must be 4, 8 or 16"):
        bvh.wide(tree, 5)


def corner_normals(corners: np.ndarray) -> np.ndarray:
    """DESIGN.md normals of simplices given by their corners (S, d, d)."""
    return cross(*np.moveaxis(corners[:, 1:] - corners[:, :1], 1, 0))


@pytest.mark.parametrize("d", (2, 3, 4))
def test_nondegenerate_is_the_test_frames_applies(d):
    # the device builder on devices without doubles takes its keep/skip from here
    rng = np.random.default_rng(3200 + d)
    v = rng.normal(size=(40, d))
    s = rng.integers(0, 40, (300, d))
    s[:50, -1] = s[:50, 0]  # repeated vertices: zero measure
    v[s[50:80, -1]] = v[s[50:80, 0]] + 1e-13 * rng.normal(size=(30, d))  # slivers
    keep = bvh.host.nondegenerate(v, s, chunk=7)
    np.testing.assert_array_equal(np.flatnonzero(keep), bvh.host.frames(v, s)[0])
    assert not keep[:50].any() and keep.sum() < 300


def sliver_mesh(rng, d: int, scale: float, shift: float, thin: float):
    """300 simplices of distinct random corners among 40 vertices: 50 with a repeated vertex, and
    30 slivers whose last corner, a vertex of their own, sits ``thin`` times the scale from
    their first (near the degeneracy threshold); the other 220 are kept."""
    v = rng.normal(size=(40, d)) * scale + shift
    s = np.array([rng.choice(40, d, replace=False) for _ in range(300)])
    s[:50, -1] = s[:50, 0]
    tips = v[s[50:80, 0]] + thin * scale * rng.normal(size=(30, d))
    s[50:80, -1] = 40 + np.arange(30)
    return np.concatenate([v, tips]), s


@settings(max_examples=60, deadline=None)
@given(
    d=st.sampled_from((2, 3, 4)),
    seed=st.integers(0, 2**16),
    scale=st.sampled_from((1e-6, 1.0, 1e5)),
    shift=st.sampled_from((0.0, 3e6)),
    thin=st.sampled_from((0.0, 1e-13, 1e-12, 3e-12, 1e-11, 1e-9)),
)
def test_nondegenerate_given_normals_is_nondegenerate(d, seed, scale, shift, thin):
    # AO's degeneracy test skips the edges of simplices whose |n| clears the bounding box's
    # bound; the slivers near the threshold take the full test, so the answer must be its own
    from ao4d.geometry import simplex_normals

    v, s = sliver_mesh(np.random.default_rng(seed), d, scale, shift, thin)
    expected = bvh.host.nondegenerate(v, s)
    np.testing.assert_array_equal(bvh.host.nondegenerate_given(v, s, simplex_normals(v, s)), expected)
    assert not expected[:50].any() and expected[80:].all()


def test_nondegenerate_given_normals_on_empty_and_point_meshes():
    from ao4d.geometry import simplex_normals

    assert bvh.host.nondegenerate_given(np.zeros((3, 3)), np.zeros((0, 3), dtype=int), np.zeros((0, 3))).shape == (0,)
    v, s = np.ones((4, 4)), np.array([[0, 1, 2, 3]])  # every corner at one point: no measure
    assert not bvh.host.nondegenerate_given(v, s, simplex_normals(v, s)).any()
