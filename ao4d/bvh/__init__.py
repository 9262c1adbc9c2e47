"""Bounding volume hierarchies over the simplices of a mesh in R^d: one home for the tree.

=========================  ======================================================================
:mod:`~ao4d.bvh.layout`    the binary tree (:class:`BVH`), its 8-wide kernel form
                           (:class:`WideBVH`), the tree's frame (:class:`Frame`), the ray test
:mod:`~ao4d.bvh.host`      the reference builder in numpy (binned SAH, level by level)
:mod:`~ao4d.bvh.device`    the same kind of tree built by OpenCL kernels (``kernels/bvh/bvh_build.cl``)
:mod:`~ao4d.bvh.collapse`  the SAH-optimal collapse of the binary tree into 8-wide nodes
:mod:`~ao4d.bvh.blocks`    leaf blocks and the wide tree, filled on the host or on the device
:mod:`~ao4d.bvh.cache`     :func:`get_bvh` and :func:`device_tree`: the one entry for a mesh's tree
=========================  ======================================================================

Data flow one way: layout <- host, collapse <- blocks <- device <- cache. The ray-casting
module (:mod:`ao4d.rays`) asks :func:`get_bvh` for a mesh's tree and :func:`device_tree`
for its device copies, and traverses them.
"""

from __future__ import annotations

from . import layout
from .blocks import block_ranges, wide, widen, widen_topology
from .cache import BUILDERS, block_lanes, device_tree, get_bvh, node_width
from .host import build, check_mesh_arrays
from .layout import *  # noqa: F403  (the names of layout.__all__, listed there once)

__all__ = [
    *layout.__all__,
    "build",
    "check_mesh_arrays",
    "wide",
    "widen",
    "widen_topology",
    "block_ranges",
    "get_bvh",
    "device_tree",
    "block_lanes",
    "node_width",
    "BUILDERS",
]
