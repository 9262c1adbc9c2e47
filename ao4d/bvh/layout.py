"""The BVH's layout: the binary tree, its 8-wide kernel form, the tree's frame, the ray test.

Each simplex is stored as the inverse of the matrix ``[e1 .. e_{d-1} | n]`` (edges from vertex 0
and the normal, as columns) plus vertex 0, so a ray test costs d+1 dot products: the last row
gives the height over the simplex's hyperplane, the others the barycentric coordinates
(``kernels/common/geometry.h`` and :func:`intersect` use the same formula). Degenerate simplices (zero
(d-1)-measure) can never be hit by a ray and are left out of the tree.

Boxes are stored in float32, rounded outwards and enlarged by the barycentric tolerance and
``1e-5`` of the scene diagonal, so that the box tests never reject a ray that the primitive test
(float32 on the device, float64 in numpy) would accept: the BVH answer equals the brute-force
answer exactly.

The OpenCL kernels traverse the 8-wide form (:class:`WideBVH`, made by :mod:`ao4d.bvh.blocks`):
one node visit tests 8 boxes with float8 arithmetic and one leaf block tests ``lanes``
simplices at once (16 on CPUs, 4 on GPUs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "BVH",
    "Frame",
    "WideBVH",
    "intersect",
    "barycentric",
    "box_area",
    "sah_cost",
    "BARY_EPS",
    "WIDTH",
    "LANES",
    "STACK_SIZE",
    "LEAF_BLOCKS",
    "MAX_LEAF_BLOCKS",
]

# Barycentric tolerance: a ray through a face shared by two simplices counts for at least one of
# them despite rounding (float32 dot products of O(1) barycentrics err by ~1e-7).
BARY_EPS = 1e-5
_BOX_MARGIN = 1e-5  # of the scene diagonal: covers float32 error of slab tests
# times the largest |coordinate|, as a floor of the extent _BOX_MARGIN scales: 1e-6 |coordinate|
# covers fma slab tests of rays from up to 16 times the scene's farthest point
_BOX_FMA_MARGIN = 0.1

WIDTH = 8  # children per node of the kernels' tree by default: one float8 per box coordinate (16 on
# AVX-512 CPUs: cache.node_width)
LANES = 16  # simplices per leaf block: one float16 per simplex coordinate (kernels' LANES)
STACK_SIZE = 256  # traversal stack entries, passed to kernels/bvh/bvh.h as -D STACK_SIZE (1 KiB of ints)
LEAF_BLOCKS = 1  # most leaf blocks per leaf slot of a wide node (the encoding allows 4)
MAX_LEAF_BLOCKS = 4  # most leaf blocks one slot can name: leaves of at most 4 * lanes simplices


@dataclass(frozen=True)
class Frame:
    """The float64 map from world coordinates to a tree's: ``x_tree = (x - centre) * scale``.

    The ray-casting module builds every tree in the frame that :meth:`fit` gives a mesh: centred
    on its bounding box and scaled by a power of two that brings the box's half extent into
    [1/2, 1). Geometry and rays are mapped in float64 before anything is rounded to float32, so
    rounding errs relative to the scene's size wherever the scene lies (a scene 1e6 from the
    origin, or scanner millimetres, traces as it does at the origin), and the power of two keeps
    lengths exact both ways.

    Attributes
    ----------
    centre : (d,) float64
    scale : float
        A power of two.
    """

    centre: np.ndarray
    scale: float

    @classmethod
    def identity(cls, dim: int) -> "Frame":
        """The frame that leaves coordinates as they are.

        Parameters
        ----------
        dim : int
            Ambient dimension d.

        Returns
        -------
        Frame
            Centre at the origin, scale 1.
        """
        return cls(np.zeros(dim), 1.0)

    @classmethod
    def fit(cls, vertices: np.ndarray) -> "Frame":
        """The frame of points ``vertices`` (V, d): their box's centre, half extent in [1/2, 1).

        Parameters
        ----------
        vertices : (V, d) array_like
            The points the frame must hold.

        Returns
        -------
        Frame
            Centred on the points' bounding box, scaled by a power of two.
        """
        lo, hi = vertices.min(0).astype(np.float64), vertices.max(0).astype(np.float64)
        half = float(np.max(hi - lo)) / 2
        exponent = math.frexp(half)[1] if half > 0 else 0
        return cls(0.5 * (lo + hi), math.ldexp(1.0, -exponent))

    def points(self, x: np.ndarray) -> np.ndarray:
        """Points (N, d) in tree coordinates, float64.

        Parameters
        ----------
        x : (N, d) array_like
            Points in world coordinates.

        Returns
        -------
        (N, d) float64
            ``(x - centre) * scale``.
        """
        out = np.subtract(x, self.centre, dtype=np.float64)
        out *= self.scale
        return out

    def length(self, t: float) -> float:
        """A world length (or ray parameter of a unit direction) in tree units.

        Exact both ways: the scale is a power of two.

        Parameters
        ----------
        t : float
            A length in world units.

        Returns
        -------
        float
            ``t * scale``.
        """
        return t * self.scale

    def world_length(self, t):
        """A tree length (scalar or array) in world units.

        Parameters
        ----------
        t : float or ndarray
            A length in tree units.

        Returns
        -------
        float or ndarray
            ``t / scale``.
        """
        return t / self.scale


@dataclass
class BVH:
    """A flattened BVH, ready for the OpenCL kernels and the numpy traversal.

    Attributes
    ----------
    dim : int
        Ambient dimension d.
    lo, hi : (K, 4) float32
        Node bounds (coordinates beyond d are zero).
    meta : (K, 2) int32
        Internal node: ``(left, right)`` child indices. Leaf: ``(-(start + 1), count)``.
    inverse : (P, d, d) float64
        Per simplex in tree order, the inverse of ``[e1 .. e_{d-1} | n]``.
    origin : (P, d) float64
        Vertex 0 of each simplex in tree order.
    prim : (P,) int64
        Index into the mesh's simplices of each simplex in tree order.
    n_skipped : int
        Degenerate simplices left out.
    depth : int
        Number of levels (root = 1).
    diagonal : float
        Length of the scene's bounding box diagonal (in the tree's coordinates).
    frame : Frame
        The map from world to tree coordinates (identity unless the caller set one: the trees
        of :func:`ao4d.bvh.get_bvh` are built in ``Frame.fit(mesh.vertices)``).
    """

    dim: int
    lo: np.ndarray
    hi: np.ndarray
    meta: np.ndarray
    inverse: np.ndarray
    origin: np.ndarray
    prim: np.ndarray
    n_skipped: int
    depth: int
    diagonal: float
    frame: Frame | None = None  # None: the identity (set in __post_init__)
    _wide: dict = field(default_factory=dict, repr=False, compare=False)  # (lanes, width) -> WideBVH (blocks.wide)

    def __post_init__(self) -> None:
        if self.frame is None:
            self.frame = Frame.identity(self.dim)

    @property
    def world_diagonal(self) -> float:
        """``diagonal`` in world units (see ``frame``)."""
        return float(self.frame.world_length(self.diagonal))

    @property
    def n_nodes(self) -> int:
        return len(self.meta)

    @property
    def n_prims(self) -> int:
        return len(self.prim)

    def frames(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``inverse[p]`` and ``origin[p]`` of tree-order simplices ``p`` (a device-built tree
        computes just these instead of all).

        Parameters
        ----------
        p : (N,) int array
            Tree-order simplex indices.

        Returns
        -------
        inverse : (N, d, d) float64
            The simplices' inverse matrices.
        origin : (N, d) float64
            Their vertex 0.
        """
        return self.inverse[p], self.origin[p]


@dataclass
class WideBVH:
    """The kernels' form of a :class:`BVH`: 8-wide nodes and 16-simplex leaf blocks (SoA).

    Attributes
    ----------
    boxes : (K, 2, d, 8) float32
        Node k's child boxes: ``boxes[k, 0, j, s]`` is the low bound of coordinate j of child s,
        ``boxes[k, 1]`` the high bounds (the binary tree's float32 boxes, unchanged).
    children : (K, 8) int32
        Child s of node k: a node index > 0, 0 for no child, or a leaf ``-(1 + 4 b + m - 1)``:
        the m (1 to 4) consecutive leaf blocks starting at block b.
    blocks : (B, d + 1, d, lanes) float32
        Leaf block b: ``blocks[b, i, j, l]`` is entry (i, j) of lane l's inverse matrix for
        i < d and coordinate j of its vertex 0 for i = d; unused lanes are all zero (never hit).
    block_prim : (B, lanes) int64
        Tree-order simplex of each lane (-1 for unused lanes).
    depth : int
        Levels of wide nodes.
    """

    boxes: np.ndarray
    children: np.ndarray
    blocks: np.ndarray
    block_prim: np.ndarray
    depth: int

    def nbytes(self) -> int:
        return self.boxes.nbytes + self.children.nbytes + self.blocks.nbytes


def box_area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Boundary (d-1)-measure of boxes: the chance that a random ray meets a convex body is
    proportional to it (Cauchy), which makes it the SAH weight in any dimension.

    Parameters
    ----------
    lo, hi : (..., d) ndarray
        Low and high corners of the boxes (d = 2, 3 or 4).

    Returns
    -------
    (...,) ndarray
        The boundary measure of each box (empty extents count as zero).
    """
    e = np.maximum(hi - lo, 0.0)
    d = e.shape[-1]
    if d == 2:
        return 2.0 * (e[..., 0] + e[..., 1])
    if d == 3:
        return 2.0 * (e[..., 0] * (e[..., 1] + e[..., 2]) + e[..., 1] * e[..., 2])
    a, b, c, f = e[..., 0], e[..., 1], e[..., 2], e[..., 3]
    return 2.0 * (a * b * (c + f) + c * f * (a + b))


def sah_cost(tree: BVH, *, traversal: float = 1.0, intersection: float = 1.0) -> float:
    """Surface-area-heuristic cost of a binary BVH, relative to its root box.

    ``sum over inner nodes of A(n) * traversal + sum over leaves of A(l) * count(l) *
    intersection``, divided by ``A(root)``, with ``A`` the boxes' boundary (d-1)-measure (the
    weight :mod:`ao4d.bvh.host` splits by): the expected cost of a random ray that meets the root.

    Parameters
    ----------
    tree : BVH
        A binary tree.
    traversal : float, optional
        Cost of visiting an inner node.
    intersection : float, optional
        Cost of one ray-simplex test.

    Returns
    -------
    float
        The relative cost (NaN when the root box has no area).
    """
    d = tree.dim
    area = box_area(tree.lo[:, :d].astype(np.float64), tree.hi[:, :d].astype(np.float64))
    leaf = tree.meta[:, 0] < 0
    inner = float(area[~leaf].sum()) * traversal
    leaves = float((area[leaf] * tree.meta[leaf, 1]).sum()) * intersection
    return (inner + leaves) / float(area[0]) if area[0] > 0 else math.nan


def intersect(
    inverse: np.ndarray, origin: np.ndarray, ray_o: np.ndarray, ray_w: np.ndarray, t_max: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Ray-simplex tests for matched pairs (float64; the formula of ``kernels/common/geometry.h``).

    Parameters
    ----------
    inverse : (P, d, d) float64
        Per simplex, the inverse of ``[e1 .. e_{d-1} | n]`` (``BVH.inverse``).
    origin : (P, d) float64
        Vertex 0 of each simplex.
    ray_o, ray_w : (P, d) float64
        Ray origins and directions.
    t_max : (P,) float64
        Hits count for ``0 < t <= t_max``.

    Returns
    -------
    hit : (P,) bool
        Whether ray p hits simplex p within ``t_max``.
    t : (P,) float64
        Ray parameter of the hyperplane crossing (meaningful where ``hit``).
    """
    rel = ray_o - origin
    normal_row = inverse[:, -1, :]
    q = np.einsum("pk,pk->p", normal_row, rel)
    r = np.einsum("pk,pk->p", normal_row, ray_w)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -q / r
        ok = (t > 0) & (t <= t_max) & np.isfinite(t)
        x = rel + t[:, None] * ray_w
        beta = np.einsum("pik,pk->pi", inverse[:, :-1, :], x)
        ok &= (beta >= -BARY_EPS).all(1) & (1.0 - beta.sum(1) >= -BARY_EPS)
    return ok, t


def barycentric(inverse: np.ndarray, origin: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights ``(P, d)`` of points lying on simplices (vertex 0 first).

    Parameters
    ----------
    inverse, origin : ndarray
        As for :func:`intersect`.
    points : (P, d) float64
        One point on each simplex.

    Returns
    -------
    (P, d) float64
        The weights of the simplex's vertices 0 to d-1, summing to one.
    """
    beta = np.einsum("pik,pk->pi", inverse[:, :-1, :], points - origin)
    return np.concatenate([1.0 - beta.sum(1, keepdims=True), beta], axis=1)
