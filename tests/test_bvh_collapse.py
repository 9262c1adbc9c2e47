"""The SAH-optimal collapse into wide nodes: optimal against exhaustive search, and a valid tree."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from _scenes import random_soup
from hypothesis import given, settings
from hypothesis import strategies as st

from ao4d import bvh
from ao4d.bvh.collapse import COST_BLOCK, COST_NODE, collapse


def random_tree(rng, n_leaves: int):
    """A random binary tree (node ids breadth first), areas growing towards the root, 1-3 blocks
    per leaf: (left, right, area, levels, n_blocks)."""
    left, right = [-1], [-1]
    frontier = [0]
    for _ in range(n_leaves - 1):  # split a random leaf
        k = frontier.pop(rng.integers(len(frontier)))
        left[k], right[k] = len(left), len(left) + 1
        left += [-1, -1]
        right += [-1, -1]
        frontier += [left[k], right[k]]
    left, right = np.array(left), np.array(right)
    n = len(left)
    area = np.zeros(n)
    n_blocks = np.zeros(n, dtype=np.int64)
    levels = [np.array([0])]
    while True:
        ids = levels[-1][left[levels[-1]] >= 0]
        if not ids.size:
            break
        levels.append(np.stack([left[ids], right[ids]], 1).ravel())
    for ids in reversed(levels):
        for k in ids:
            if left[k] < 0:
                area[k], n_blocks[k] = rng.uniform(0.1, 1.0), rng.integers(1, 4)
            else:
                n_blocks[k] = n_blocks[left[k]] + n_blocks[right[k]]
                area[k] = (area[left[k]] + area[right[k]]) * rng.uniform(0.6, 1.0)
    return left, right, area, levels, n_blocks


def exhaustive_cost(left, right, area, n_blocks, may_be_leaf, width):
    """Least cost of a wide tree rooted at node 0 by enumerating every slot set (antichain cut)
    of every wide node: an independent reference for the dynamic programme."""

    @functools.lru_cache(maxsize=None)
    def cuts(k):  # every way to cover k's subtree by a set of its nodes, at most `width` of them
        out = {(k,)}
        if left[k] >= 0:
            for a in cuts(left[k]):
                for b in cuts(right[k]):
                    if len(a) + len(b) <= width:
                        out.add(a + b)
        return frozenset(out)

    @functools.lru_cache(maxsize=None)
    def slot(k):  # a slot holding node k: a leaf slot, or a wide node
        leaf = area[k] * n_blocks[k] * COST_BLOCK if (may_be_leaf[k] or left[k] < 0) else np.inf
        return min(leaf, wide(k)) if left[k] >= 0 else leaf

    @functools.lru_cache(maxsize=None)
    def wide(k):  # node k as a wide node over a cut of its children's subtrees
        best = np.inf
        for a in cuts(left[k]):
            for b in cuts(right[k]):
                if len(a) + len(b) <= width:
                    best = min(best, sum(slot(s) for s in a + b))
        return area[k] * COST_NODE + best

    return wide(0)


def realised_cost(plan, area, n_blocks):
    """The cost of the wide tree the plan's slots build (every wide node's area, every leaf
    slot's blocks), and the binary leaves it covers."""
    cost, covered, level = 0.0, [], np.array([0])
    while level.size:
        cost += area[level].sum() * COST_NODE
        slots = plan.slots(level)
        assert ((slots >= 0).sum(1) >= 2).all()  # a wide node has at least two slots
        used = slots[slots >= 0]
        leaf = plan.leaf[used]
        cost += (area[used[leaf]] * n_blocks[used[leaf]]).sum() * COST_BLOCK
        covered += used[leaf].tolist()
        level = used[~leaf]
    return cost, covered


def leaves_under(left, right, k):
    if left[k] < 0:
        return [k]
    return leaves_under(left, right, left[k]) + leaves_under(left, right, right[k])


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_leaves=st.integers(2, 11),
    width=st.sampled_from([2, 3, 4, 8]),
    leafy=st.booleans(),
)
def test_collapse_is_optimal_and_covers_every_leaf_once(seed, n_leaves, width, leafy):
    rng = np.random.default_rng(seed)
    left, right, area, levels, n_blocks = random_tree(rng, n_leaves)
    may_be_leaf = (n_blocks <= 3) if leafy else (left < 0)
    plan = collapse(left, right, area, levels, n_blocks, may_be_leaf, width)
    cost, covered = realised_cost(plan, area, n_blocks)
    expected = exhaustive_cost(left, right, area, n_blocks, may_be_leaf, width)
    assert cost == pytest.approx(expected, rel=1e-12)
    # every binary leaf lies under exactly one leaf slot
    under = sorted(x for k in covered for x in leaves_under(left, right, k))
    assert under == sorted(np.flatnonzero(left < 0).tolist())
    assert not (plan.leaf & ~(may_be_leaf | (left < 0))).any()


def test_wide_nodes_are_fuller_than_half(build_bvh):
    # the greedy collapse it replaced left about half of all slots empty on real meshes
    rng = np.random.default_rng(3)
    vertices, simplices = random_soup(rng, 4, 20000)
    tree = build_bvh(vertices, simplices)
    boxes, children, first, count, depth = bvh.widen_topology(tree, 16)
    assert (children != 0).mean() > 0.65
    # blocks: each tree-order simplex exactly once
    lanes = np.concatenate([f + np.arange(c) for f, c in zip(first, count)])
    assert np.array_equal(np.sort(lanes), np.arange(tree.n_prims))
    # every block is reached from exactly one leaf slot
    leaf = -children[children < 0] - 1
    reached = np.concatenate([b + np.arange(m) for b, m in zip(leaf >> 2, (leaf & 3) + 1)])
    assert np.array_equal(np.sort(reached), np.arange(len(first)))


def full_programme(left, right, area, levels, n_blocks, may_be_leaf, width):
    """The dynamic programme run for every node up to ``width`` slots (collapse's earlier form,
    before it stopped at a node's leaf count): (leaf, split, share)."""
    n = len(left)
    cost = np.full((n, width + 1), np.inf)
    split = np.zeros((n, width + 1), dtype=np.int8)
    share = np.zeros(n, dtype=np.int8)
    leaf = left < 0
    leaf_cost = np.where(may_be_leaf | (left < 0), area * n_blocks * COST_BLOCK, np.inf)
    cost[left < 0, 1:] = leaf_cost[left < 0, None]
    for ids in reversed(levels):
        for k in ids[left[ids] >= 0]:
            cl, cr = cost[left[k]], cost[right[k]]
            both = np.full(width + 1, np.inf)
            k_best = np.zeros(width + 1, dtype=np.int8)
            for i in range(2, width + 1):
                sums = [cl[a] + cr[i - a] for a in range(1, i)]
                k_best[i] = 1 + int(np.argmin(sums))  # the first of equal sums
                both[i] = sums[k_best[i] - 1]
            wide = area[k] * COST_NODE + both[width]
            share[k], leaf[k] = k_best[width], leaf_cost[k] <= wide
            cost[k, 1] = min(leaf_cost[k], wide)
            for i in range(2, width + 1):
                use = both[i] < cost[k, i - 1]
                cost[k, i] = both[i] if use else cost[k, i - 1]
                split[k, i] = k_best[i] if use else split[k, i - 1]
    return leaf, split, share


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_leaves=st.integers(2, 70),
    width=st.sampled_from([2, 3, 4, 5, 8, 16]),
    leafy=st.booleans(),
    coarse=st.booleans(),
)
def test_collapse_equals_the_programme_run_to_full_width(seed, n_leaves, width, leafy, coarse):
    # collapse stops each node's programme at the bound above its leaf count; the choices,
    # ties included (coarse areas make equal sums common), must be those of the full programme
    rng = np.random.default_rng(seed)
    left, right, area, levels, n_blocks = random_tree(rng, n_leaves)
    if coarse:
        area = np.round(area * 4) / 4 + 0.25
    may_be_leaf = (n_blocks <= 3) if leafy else (left < 0)
    plan = collapse(left, right, area, levels, n_blocks, may_be_leaf, width)
    leaf, split, share = full_programme(left, right, area, levels, n_blocks, may_be_leaf, width)
    assert np.array_equal(plan.leaf, leaf)
    assert np.array_equal(plan.split, split)
    assert np.array_equal(plan.share[left >= 0], share[left >= 0])
