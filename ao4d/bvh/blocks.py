"""Leaf blocks and the kernels' wide tree (8 or 16 children a node: :func:`ao4d.bvh.node_width`):
the binary tree collapsed (SAH-optimal: :mod:`ao4d.bvh.collapse`), every leaf split into blocks of ``lanes`` simplices stored as
structure of arrays, filled on the host (:func:`widen`) or on the device that built the tree
(:func:`device_wide_tree`).

A subtree of at most ``LEAF_BLOCKS`` blocks (or one leaf's blocks) may become one leaf slot of
consecutive blocks.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from ..opencl.pool import TREES
from . import layout
from .collapse import collapse
from .layout import BVH, LANES, LEAF_BLOCKS, MAX_LEAF_BLOCKS, WIDTH, WideBVH, box_area

__all__ = ["wide", "widen", "widen_topology", "block_ranges", "device_wide_tree", "release_source"]


def wide(tree: BVH, lanes: int | None = None, width: int = WIDTH) -> WideBVH:
    """The wide, structure-of-arrays form the OpenCL kernels traverse, built once per
    ``lanes`` (simplices per leaf block, default ``LANES``) and ``width`` and kept on the tree.

    Parameters
    ----------
    tree : BVH
        A binary tree.
    lanes : {4, 8, 16}, optional
        Simplices per leaf block (default ``LANES``).
    width : {8, 16}, optional
        Children per wide node (default ``WIDTH``; :func:`ao4d.bvh.node_width` gives a device's).

    Returns
    -------
    WideBVH
        The tree's wide form (the same object on later calls).
    """
    lanes = LANES if lanes is None else lanes
    if (lanes, width) not in tree._wide:
        tree._wide[lanes, width] = widen(tree, lanes, width)
    return tree._wide[lanes, width]


def widen(tree: BVH, lanes: int = LANES, width: int = WIDTH) -> WideBVH:
    """Collapse the binary tree into wide nodes (SAH-optimal: :func:`ao4d.bvh.collapse.collapse`).

    Each binary leaf becomes ``ceil(count / lanes)`` consecutive leaf blocks of ``lanes``
    (4, 8 or 16) simplices. :mod:`ao4d.ao` asks for 16 on CPUs (one AVX-512 register per row of
    a block test, faster than 4 or 8 lanes: the benchmarks log) and 4 on GPUs, whose work-items
    run vector lanes one after another and would only pay for wide vectors in registers.

    Parameters
    ----------
    tree : BVH
        A binary tree.
    lanes : {4, 8, 16}, optional
        Simplices per leaf block.
    width : {8, 16}, optional
        Children per wide node.

    Returns
    -------
    WideBVH
        A new wide tree (:func:`wide` keeps one per ``lanes`` and ``width`` on the tree).

    Raises
    ------
    ValueError
        If ``lanes`` is not 4, 8 or 16, or ``width`` not 8 or 16.
    RuntimeError
        If the tree is deeper than the kernels' traversal stack holds.
    """
    boxes, children, block_first, block_count, depth = widen_topology(tree, lanes, width)
    lane = np.arange(lanes)
    block_prim = np.where(lane < block_count[:, None], block_first[:, None] + lane, -1)
    d = tree.dim
    blocks = np.zeros((len(block_prim), d + 1, d, lanes), dtype=np.float32)
    used = block_prim >= 0
    b, l = np.nonzero(used)
    inverse, origin = tree.frames(block_prim[used])
    # a well-shaped simplex far below float32's resolution of the scene (1e-12 of it, where a
    # grid value nearly equals the level) has inverse entries beyond FLT_MAX: they round to inf
    # as on the device (convert_float), and its rays' t = inf / inf = NaN is never a hit
    with np.errstate(over="ignore"):
        blocks[b, :d, :, l] = inverse
    blocks[b, d, :, l] = origin
    return WideBVH(boxes=boxes, children=children, blocks=blocks, block_prim=block_prim, depth=depth)


def _levels(meta: np.ndarray) -> list[np.ndarray]:
    """Node ids level by level from the root (left children before right ones)."""
    levels = [np.array([0])]
    while True:
        ids = levels[-1]
        inner = ids[meta[ids, 0] >= 0]
        if inner.size == 0:
            return levels
        levels.append(np.stack([meta[inner, 0], meta[inner, 1]], 1).ravel().astype(np.int64))


def block_ranges(tree: BVH, lanes: int = LANES) -> tuple[np.ndarray, np.ndarray]:
    """First tree-order simplex and simplex count (B,) int64 of every leaf block: each binary
    leaf, in simplex order, becomes ``ceil(count / lanes)`` consecutive blocks, block k holding
    its simplices ``k * lanes`` to ``(k + 1) * lanes - 1``. The collapse does not change them, so
    :mod:`ao4d.bvh.device` fills the blocks on the device while the host collapses.

    Parameters
    ----------
    tree : BVH
        A binary tree, whose leaves are cut into blocks.
    lanes : int, optional
        Simplices per block.

    Returns
    -------
    first : (B,) int64
        First tree-order simplex of each block.
    count : (B,) int64
        Its number of simplices (1 to ``lanes``).
    """
    leaves, per_leaf, first_block = _leaf_blocks(tree, lanes)
    start = -tree.meta[leaves, 0].astype(np.int64) - 1
    size = tree.meta[leaves, 1].astype(np.int64)
    leaf = np.repeat(np.arange(leaves.size), per_leaf)
    k = np.arange(leaf.size) - first_block[leaf]
    return start[leaf] + k * lanes, np.minimum(size[leaf] - k * lanes, lanes)


def _leaf_blocks(tree: BVH, lanes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The binary leaves in simplex order, their block counts and their first blocks."""
    leaves = np.flatnonzero(tree.meta[:, 0] < 0)
    leaves = leaves[np.argsort(tree.meta[leaves, 0])[::-1]]  # by first simplex: -(start + 1)
    per_leaf = -(-tree.meta[leaves, 1].astype(np.int64) // lanes)
    return leaves, per_leaf, np.cumsum(per_leaf) - per_leaf


def widen_topology(
    tree: BVH, lanes: int = LANES, width: int = WIDTH
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """The wide form of :func:`widen` without the leaf blocks' contents.

    :func:`widen` fills the blocks on the host, :mod:`ao4d.bvh.device` on the device.

    Parameters
    ----------
    tree : BVH
        The binary tree to collapse.
    lanes : {4, 8, 16}, optional
        Simplices per leaf block, which sets how many blocks each leaf needs.
    width : {8, 16}, optional
        Children per wide node (W).

    Returns
    -------
    boxes : (K, 2, d, W) float32
        The wide nodes' child boxes (see :class:`WideBVH`).
    children : (K, W) int32
        The wide nodes' children (see :class:`WideBVH`).
    block_first : (B,) int32
        Per leaf block, its first tree-order simplex (lane l holds simplex first + l).
    block_count : (B,) int32
        Per leaf block, its number of simplices.
    depth : int
        Levels of wide nodes.

    Raises
    ------
    ValueError
        If ``lanes`` is not 4, 8 or 16, or ``width`` not 8 or 16.
    RuntimeError
        If the tree is deeper than the kernels' traversal stack (``STACK_SIZE`` entries) holds.
    """
    if lanes not in (4, 8, 16):
        raise ValueError(f"`lanes` must be 4, 8 or 16, got {lanes!r}")
    if width not in (8, 16):
        raise ValueError(f"`width` must be 8 or 16, got {width!r}")
    d = tree.dim
    left = np.where(tree.meta[:, 0] >= 0, tree.meta[:, 0], -1).astype(np.int64)
    right = np.where(tree.meta[:, 0] >= 0, tree.meta[:, 1], -1).astype(np.int64)
    levels = _levels(tree.meta)
    n_blocks, first_block, max_blocks = _subtree_blocks(tree, lanes, left, right, levels)
    # wide nodes level by level; each holds up to `width` binary nodes (its slots), chosen by the
    # SAH-optimal collapse
    area = box_area(tree.lo[:, :d].astype(np.float64), tree.hi[:, :d].astype(np.float64))
    plan = collapse(left, right, area, levels, n_blocks, n_blocks <= max_blocks, width)
    slots, depth = _wide_slots(plan)
    # a node visit pushes at most width - 1 more entries than it pops
    if depth * (width - 1) + 1 > layout.STACK_SIZE:  # read at call time: tests vary it
        raise RuntimeError(
            f"BVH too deep for the kernels' traversal stack: {depth} wide levels need "
            f"{depth * (width - 1) + 1} entries, STACK_SIZE is {layout.STACK_SIZE}"
        )
    valid = slots >= 0
    safe = np.where(valid, slots, 0)
    inner = valid & ~plan.leaf[safe]
    # wide ids follow creation order: the inner slots in row-major order are nodes 1, 2, ...
    children = np.zeros(slots.shape, dtype=np.int64)
    children[inner] = 1 + np.arange(inner.sum())
    leafy = valid & plan.leaf[safe]
    leaf_nodes = slots[leafy]
    children[leafy] = -(1 + 4 * first_block[leaf_nodes] + (n_blocks[leaf_nodes] - 1))
    boxes = np.zeros((len(slots), 2, d, width), dtype=np.float32)
    boxes[:, 0] = tree.lo[safe][..., :d].transpose(0, 2, 1)
    boxes[:, 1] = tree.hi[safe][..., :d].transpose(0, 2, 1)
    boxes[~np.broadcast_to(valid[:, None, None, :], boxes.shape)] = 0.0
    first, count = block_ranges(tree, lanes)
    return boxes, children.astype(np.int32), first.astype(np.int32), count.astype(np.int32), depth


def _subtree_blocks(tree: BVH, lanes: int, left, right, levels):
    """Per binary node, its subtree's leaf-block count and first block (B,) int64 each, and the
    most blocks one leaf slot may hold: a subtree of at most that many may become one slot
    (its blocks are consecutive: blocks follow the simplex order)."""
    leaves, leaf_blocks, leaf_first = _leaf_blocks(tree, lanes)
    max_blocks = max(LEAF_BLOCKS, int(leaf_blocks.max()))
    if max_blocks > MAX_LEAF_BLOCKS:  # the leaf encoding holds 1 to 4 blocks
        raise ValueError(
            f"the OpenCL kernels need leaves of at most {MAX_LEAF_BLOCKS * lanes} simplices for {lanes} lanes"
        )
    n_blocks = np.zeros(tree.n_nodes, dtype=np.int64)
    n_blocks[leaves] = leaf_blocks
    first_block = np.full(tree.n_nodes, -1, dtype=np.int64)
    first_block[leaves] = leaf_first
    for ids in reversed(levels):  # bottom up, each node once
        ids = ids[left[ids] >= 0]
        n_blocks[ids] = n_blocks[left[ids]] + n_blocks[right[ids]]
        first_block[ids] = first_block[left[ids]]
    return n_blocks, first_block, max_blocks


def _wide_slots(plan) -> tuple[np.ndarray, int]:
    """The binary nodes in each wide node's slots (K, width), -1 for none, and the wide depth."""
    if plan.leaf[0]:  # the whole tree is one leaf: a root with a single leaf child
        return np.concatenate([[0], np.full(plan.width - 1, -1)])[None], 1
    level, all_slots = np.array([0]), []
    while level.size:
        slots = plan.slots(level)
        all_slots.append(slots)
        valid = slots >= 0
        level = slots[valid & ~plan.leaf[np.where(valid, slots, 0)]]
    return np.concatenate(all_slots), len(all_slots)


def device_wide_tree(tree: BVH, runtime, lanes: int, width: int = WIDTH) -> dict[str, Any] | None:
    """Device buffers of ``tree``'s wide form with the leaf blocks filled on the device.

    Returns ``None`` when ``tree`` was not built on ``runtime``'s context (then the host widens
    it). The dict holds ``boxes``, ``children``, ``blocks`` (buffers), ``n_blocks``, ``lanes``,
    ``width`` and ``block_first`` (the tree-order simplex in lane 0 of each block; lane l holds
    the next).
    """

    done = tree.device_wide.get((lanes, width)) if hasattr(tree, "device_wide") else None
    if done is not None and done["context"] is runtime.context:
        return done  # filled at the build, whose device copies of the mesh may be freed since
    source = getattr(tree, "device_source", None)
    if source is None or source["context"] is not runtime.context:
        return None
    first, count = block_ranges(tree, lanes)
    d = tree.dim
    n_blocks = len(first)
    ctx, queue = runtime.context, runtime.queue
    block_range = TREES.upload(queue, np.stack([first, count], 1).astype(np.int32))
    # the tree's buffers are the recycled ones of trees already collected (TREES)
    blocks = TREES.get(ctx, 4 * n_blocks * (d + 1) * d * lanes)
    source["kernels"]["fill_blocks"](
        queue,
        (n_blocks * lanes,),
        None,
        source["vertices"],
        source["simplices"],
        source["order"],
        block_range,
        np.int32(lanes),
        blocks,
    )
    queue.flush()  # the device fills the blocks while the host collapses the tree
    boxes, children, _, _, _ = widen_topology(tree, lanes, width)
    boxes_buf, children_buf = (TREES.upload(queue, np.ascontiguousarray(a)) for a in (boxes, children))
    out = _DeviceTree(
        {
            "boxes": boxes_buf,
            "children": children_buf,
            "blocks": blocks,
            "n_blocks": np.int32(n_blocks),
            "lanes": lanes,
            "width": width,
            "block_first": first,
            "context": ctx,
        }
    )
    # back to TREES once nothing holds the dict (the tree, a mesh's cache): not when the tree
    # goes, as a cache may keep the dict longer
    TREES.give_when(out, ctx, blocks, boxes_buf, children_buf)
    queue.finish()
    TREES.give(ctx, block_range)
    tree.device_wide[lanes, width] = out
    return out


class _DeviceTree(dict):
    """The dict :func:`device_wide_tree` returns (a subclass, so that it takes weak references)."""


_SOURCE_BUFFERS = ("vertices", "simplices", "order")


def give_source_when(tree: Any) -> None:
    """Give the build's device copies of the mesh (``tree.device_source``) back to
    :data:`~ao4d.opencl.pool.TREES` when ``tree`` is collected, unless :func:`release_source`
    gave them back before."""
    weakref.finalize(tree, _give_source, tree.device_source).atexit = False


def _give_source(source: dict[str, Any]) -> None:
    TREES.give(source["context"], *(source.pop(key, None) for key in _SOURCE_BUFFERS))


def release_source(tree: Any) -> None:
    """Give back the build's device copies of the mesh (vertices, simplices, simplex order:
    about 1.4 GB at 55 M tetrahedra, more than :data:`~ao4d.opencl.pool.TREES` holds: then
    freed) once the traversed wide form exists; another leaf-block width is then widened on
    the host."""
    source, tree.device_source = tree.device_source, None
    if source is not None:
        _give_source(source)
