"""SAH-optimal collapse of a binary BVH into wide nodes (the kernels' tree of 8 or 16 children a node).

The dynamic programme of Ylitie, Karras & Laine (*Efficient incoherent ray traversal on GPUs
through compressed wide BVHs*, HPG 2017): bottom up, ``cost[n, i]`` is the least expected cost
of node n's subtree spread over at most i slots of its parent, with ``COST_NODE`` per wide-node
visit and ``COST_BLOCK`` per leaf block tested, each weighted by the box area (the chance that a
ray meets the box). One slot is n itself: a leaf slot (where allowed) or a wide node holding its
children's best split of ``width`` slots; more slots split i between the two children. Then top
down, the choices give each wide node its slots. Everything is vectorised over a tree level.

Why not a greedy collapse (open the child of largest area until the node is full): it leaves
about half the slots empty, so the tree has more wide nodes and rays visit more of them (the
benchmarks log has the figures).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Collapse", "collapse", "COST_NODE", "COST_BLOCK"]

# a 4D leaf block test costs about three wide-node visits on a CPU; ratios of 1.5 to 6 traced
# alike within the noise of bench/ao.py
COST_NODE = 1.0
COST_BLOCK = 3.0


@dataclass
class Collapse:
    """The chosen collapse: ``leaf[n]`` tells whether binary node n, where it is a slot, is a
    leaf slot (else a wide node); ``split[n, i]`` is the left child's share of a budget of i
    slots (0: n takes one slot itself); ``share[n]`` splits n's children among the slots of n's
    own wide node."""

    left: np.ndarray
    right: np.ndarray
    leaf: np.ndarray
    split: np.ndarray
    share: np.ndarray
    width: int

    def slots(self, nodes: np.ndarray) -> np.ndarray:
        """Slots (binary node ids, -1 where unused, in tree order) of the wide nodes of binary
        inner ``nodes``: (len(nodes), width), following the split choices for all at once."""
        m, width = nodes.size, self.width
        out = np.full((m, width), -1, dtype=np.int64)
        fill = np.zeros(m, dtype=np.int64)
        k = self.share[nodes].astype(np.int64)
        row = np.concatenate([np.arange(m), np.arange(m)])
        node = np.concatenate([self.left[nodes], self.right[nodes]])
        budget = np.concatenate([k, width - k])
        while row.size:
            k = self.split[node, budget].astype(np.int64)
            done = (k == 0) | (self.left[node] < 0)
            r, nd = row[done], node[done]
            order = np.argsort(r, kind="stable")  # a row's slots keep their tree order
            r, nd = r[order], nd[order]
            out[r, fill[r] + np.arange(r.size) - np.searchsorted(r, r)] = nd
            np.add.at(fill, r, 1)
            go = ~done
            row = np.concatenate([row[go], row[go]])
            nd, k, b = node[go], k[go], budget[go]
            node = np.concatenate([self.left[nd], self.right[nd]])
            budget = np.concatenate([k, b - k])
        return out


def collapse(
    left: np.ndarray,
    right: np.ndarray,
    area: np.ndarray,
    levels: list[np.ndarray],
    n_blocks: np.ndarray,
    may_be_leaf: np.ndarray,
    width: int,
) -> Collapse:
    """Choose the wide tree of least expected cost.

    Parameters
    ----------
    left, right : (N,) int64
        Children of each binary node, -1 for leaves.
    area : (N,) float64
        Box area of each node.
    levels : list of int arrays
        Node ids level by level from the root.
    n_blocks : (N,) int64
        Leaf blocks under each node.
    may_be_leaf : (N,) bool
        Nodes that may become one leaf slot (binary leaves always are).
    width : int
        Slots per wide node.
    """
    n = len(left)
    cost = np.full((n, width + 1), np.inf)  # column i: at most i slots (column 0 unused)
    split = np.zeros((n, width + 1), dtype=np.int8)
    share = np.zeros(n, dtype=np.int8)
    leaf = np.zeros(n, dtype=bool)
    leaf_cost = np.where(may_be_leaf | (left < 0), area * n_blocks * COST_BLOCK, np.inf)
    bottom = left < 0
    cost[bottom, 1:] = leaf_cost[bottom, None]
    leaf[bottom] = True
    leaves = np.ones(n, dtype=np.int64)  # binary leaves under each node
    # A subtree of L binary leaves cannot use more than L slots: its costs (and split choices)
    # for i >= L slots equal those for L (the sums below are monotone in each term, and the
    # split k = L_left reaches the least one). Most nodes lie near the bottom, with few leaves,
    # so each node's programme runs only up to a bound u >= min(L, width), the smallest of
    # 2, 4, 8, ... that holds it, and the columns beyond u repeat column u: the same arrays as
    # running every node to `width`, at a third of the time on 4 M tetrahedra.
    bounds = sorted({min(1 << b, width) for b in range(1, width.bit_length() + 1)})
    for ids in reversed(levels):  # children before parents
        ids = ids[left[ids] >= 0]
        if ids.size == 0:
            continue
        leaves[ids] = leaves[left[ids]] + leaves[right[ids]]
        cap = np.minimum(leaves[ids], width)
        below = 1
        for u in bounds:
            group = ids[(cap > below) & (cap <= u)]
            below = u
            if group.size:
                _programme(group, u, width, left, right, area, leaf_cost, cost, split, share, leaf)
    return Collapse(left=left, right=right, leaf=leaf, split=split, share=share, width=width)


def _programme(ids, u, width, left, right, area, leaf_cost, cost, split, share, leaf) -> None:
    """The dynamic programme's step for the nodes ``ids`` (children done), whose subtrees have
    at most ``u`` leaves or ``u = width``: columns 1..u computed, the rest copies of column u."""
    m = ids.size
    cl, cr = cost[left[ids], : u + 1], cost[right[ids], : u + 1]
    both = np.full((m, u + 1), np.inf)  # both children, i slots between them
    k_best = np.zeros((m, u + 1), dtype=np.int8)
    rows = np.arange(m)
    for i in range(2, u + 1):
        c = cl[:, 1:i] + cr[:, i - 1 : 0 : -1]  # k = 1 .. i-1 slots for the left child
        k = np.argmin(c, axis=1)  # the first of equal costs, as a loop over k would keep
        both[:, i] = c[rows, k]
        k_best[:, i] = k + 1
    if u == width:
        share[ids] = k_best[:, width]
    else:
        # the first k of 1 .. width-1 with the least cl[k] + cr[width - k]: the least is
        # cl[L_left] + cr[L_right], and for k < L_left the right term is cr[u] (constant), so
        # the first such k lies in 1 .. u-1 (L_left <= u - 1)
        share[ids] = np.argmin(cl[:, 1:u] + cr[:, u : u + 1], axis=1) + 1
    wide = area[ids] * COST_NODE + both[:, u]
    leaf[ids] = leaf_cost[ids] <= wide
    c_n = np.empty((m, width + 1))
    s_n = np.zeros((m, width + 1), dtype=np.int8)
    c_n[:, 0] = np.inf
    c_n[:, 1] = np.minimum(leaf_cost[ids], wide)
    for i in range(2, u + 1):
        use = both[:, i] < c_n[:, i - 1]
        c_n[:, i] = np.where(use, both[:, i], c_n[:, i - 1])
        s_n[:, i] = np.where(use, k_best[:, i], s_n[:, i - 1])
    c_n[:, u + 1 :] = c_n[:, u : u + 1]
    s_n[:, u + 1 :] = s_n[:, u : u + 1]
    cost[ids], split[ids] = c_n, s_n
