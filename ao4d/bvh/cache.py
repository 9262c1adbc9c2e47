"""Trees of meshes: built once per mesh in its own frame, uploaded once per OpenCL context.

:func:`get_bvh` is the one entry for a mesh's tree (the device builder where a runtime traces
it, else the host builder), cached on the mesh; :func:`device_tree` its device copies in the
kernels' 8-wide form (filled on the device that built the tree, else widened on the host),
kept in ``mesh.cache`` so that a render after an AO call reuses them.
"""

from __future__ import annotations

import hashlib
import weakref
from typing import Any

import numpy as np

from .._validate import check_choice, check_positive_int
from ..opencl import cl
from . import blocks, device, host, layout
from .blocks import device_wide_tree
from .layout import BVH, LANES, MAX_LEAF_BLOCKS, WIDTH, Frame

__all__ = ["get_bvh", "device_tree", "block_lanes", "node_width", "BUILDERS"]

BUILDERS = ("auto", "host", "device")

_fallback_cache: "weakref.WeakKeyDictionary[Any, dict]" = weakref.WeakKeyDictionary()


def _fingerprint(vertices: np.ndarray, simplices: np.ndarray) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in (vertices, simplices):
        a = np.ascontiguousarray(a)
        h.update(str((a.shape, a.dtype.str)).encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def _build_tree(builder: str, vertices, simplices, leaf_size: int, runtime) -> BVH:
    """The tree of the mesh in its own frame (:class:`ao4d.bvh.Frame`): recentred and scaled in
    float64, so that the float32 kernels see coordinates of order one wherever the mesh lies."""
    vertices = np.asarray(vertices, dtype=np.float64)  # the builders check it
    frame = Frame.fit(vertices)
    local = frame.points(vertices)
    if builder == "device":
        if runtime is None:
            runtime = cl.get_runtime(warn=False)
            if runtime is None:
                raise cl.NoOpenCLDeviceError("builder='device' needs an OpenCL device; none works (see `ao4d info`)")
        tree = device.build(
            local,
            simplices,
            leaf_size=leaf_size,
            runtime=runtime,
            lanes=block_lanes(runtime, local.shape[1]),
            width=node_width(runtime),
        )
    else:
        tree = host.build(local, simplices, leaf_size=leaf_size)
    tree.frame = frame
    return tree


def get_bvh(mesh: Any, *, leaf_size: int = 16, builder: str = "auto", runtime: Any = None) -> BVH:
    """The BVH of ``mesh``, built once and cached on it.

    Parameters
    ----------
    mesh : SimplexMesh, any object with ``vertices`` and ``simplices``, trimesh.Trimesh or (vertices, simplices)
        The mesh whose tree is wanted. A ``trimesh.Trimesh`` or a pair is read by
        :func:`ao4d.mesh.as_mesh` into a new mesh, so its tree is built on every call.
    leaf_size : int
        Most simplices per leaf.
    builder : {"auto", "host", "device"}
        ``"host"``: ``ao4d.bvh.host.build`` (numpy); ``"device"``: ``ao4d.bvh.device.build`` on
        ``runtime`` (default: the device :func:`ao4d.opencl.cl.get_runtime` chooses). ``"auto"``: a
        tree already cached for the mesh, whichever built it; else the device builder when
        ``runtime`` is given (the ray-casting functions pass theirs), the host builder otherwise.
    runtime : ao4d.opencl.cl.Runtime, optional
        The OpenCL device that will trace the tree.

    Returns
    -------
    ao4d.bvh.BVH
        A ``DeviceBVH`` (``ao4d.bvh.device``) when built on the device. Its geometry is in the
        tree's coordinates, ``tree.frame.points(mesh.vertices)``: rays must be mapped likewise.

    Notes
    -----
    Uses the mesh's ``cache`` dict when it has one (dropped when the mesh changes); otherwise a
    weak-keyed cache checked against a hash of the vertex and simplex arrays.
    """
    check_choice(builder, "builder", BUILDERS)
    leaf_size = check_positive_int(leaf_size, "leaf_size")
    if not hasattr(mesh, "simplices"):  # a trimesh.Trimesh or a (vertices, simplices) pair
        # imported here: importing the tree need not import the mesh's files and pictures
        from ..mesh import as_mesh

        mesh = as_mesh(mesh)
    lanes = None if runtime is None else block_lanes(runtime, np.shape(mesh.vertices)[1])
    if lanes is not None and leaf_size > MAX_LEAF_BLOCKS * lanes:
        raise ValueError(
            f"`leaf_size` must be at most {MAX_LEAF_BLOCKS * lanes} on this device "
            f"(leaf blocks of {lanes} simplices, at most {MAX_LEAF_BLOCKS} per leaf), "
            f"got {leaf_size}"
        )
    keys = {b: f"ao4d.bvh/{b}/leaf={leaf_size}" for b in ("device", "host")}
    cache = getattr(mesh, "cache", None)
    stamp = None
    if cache is None:
        vertices, simplices = np.asarray(mesh.vertices), np.asarray(mesh.simplices)
        stamp = _fingerprint(vertices, simplices)
        try:
            entry = _fallback_cache.setdefault(mesh, {})
        except TypeError:  # not weak-referenceable: build every time
            entry = {}
        cache = {k: v[1] for k, v in entry.items() if v[0] == stamp}
    if builder == "auto":
        for b in ("device", "host"):
            if keys[b] in cache:
                return cache[keys[b]]
        builder = "device" if runtime is not None else "host"
    tree = cache.get(keys[builder])
    if tree is None:
        tree = _build_tree(builder, mesh.vertices, mesh.simplices, leaf_size, runtime)
        if stamp is None:
            cache[keys[builder]] = tree
        else:
            entry[keys[builder]] = (stamp, tree)
    return tree


def block_lanes(runtime, dim: int | None = None) -> int:
    """Simplices per leaf block on this device: ``bvh.LANES`` (16) on CPUs, 4 elsewhere (why:
    bvh.widen); 8 for triangles and segments (``dim`` <= 3) on CPUs whose native float vectors
    hold fewer than 16.

    A block's test runs on all its lanes at once. On AVX2 a 16-lane block costs two vector
    operations per step; in 3D its rows are short enough that the halved work and the fuller
    blocks pay for the extra block fetches: 3D ``cast_rays`` any hit traced in 0.91-0.93x the
    time with 8 lanes, 3D AO in 0.94x; 4D AO and 4D ``cast_rays`` did not change beyond the
    noise (0.96-1.03x), so 4D keeps 16 (a 2-core AMD EPYC with AVX2, the benchmarks log).

    Parameters
    ----------
    runtime : ao4d.opencl.cl.Runtime
        The device that traverses the tree.
    dim : int, optional
        The mesh's dimension (2, 3 or 4); without it, the 4D answer.

    Returns
    -------
    int
        16, 8 or 4.
    """
    import pyopencl as pcl

    if not runtime.device.type & pcl.device_type.CPU:
        return 4
    if dim is not None and dim <= 3 and runtime.device.native_vector_width_float < 16:
        return 8
    return LANES


def node_width(runtime) -> int:
    """Children per wide node on this device: 16 where the device's native float vectors hold
    16 (AVX-512 CPUs: a node's 16 child boxes cost one vector operation per bound, and rays visit
    fewer nodes), else 8 (AVX2 CPUs, where 16 traced 3 % slower, and GPUs).

    Measured on a 2-core AMD EPYC with AVX-512 (the benchmarks log): AO traced 8-14 % faster
    with 16 children; with the same runtime compiling for AVX2, 3 % slower.

    Parameters
    ----------
    runtime : ao4d.opencl.cl.Runtime
        The device that traverses the tree.

    Returns
    -------
    int
        8 or 16.
    """
    import pyopencl as pcl

    cpu = bool(runtime.device.type & pcl.device_type.CPU)
    return 16 if cpu and runtime.device.native_vector_width_float >= 16 else WIDTH


def device_tree(mesh: Any, tree: BVH, runtime) -> dict[str, Any]:
    """Device copies of the wide tree, uploaded once per context and kept in ``mesh.cache``
    (dropped with the tree when the mesh changes; meshes without a cache upload per call).

    Parameters
    ----------
    mesh : SimplexMesh or object
        The mesh whose tree this is; its ``cache`` (when it has one) keeps the copies.
    tree : BVH
        The mesh's tree (:func:`get_bvh`).
    runtime : ao4d.opencl.cl.Runtime
        The device to upload to.

    Returns
    -------
    dict
        The device buffers ``boxes``, ``children`` and ``blocks`` and the host values
        ``n_blocks``, ``lanes``, ``width`` and ``block_first``.

    Raises
    ------
    MemoryError
        If the wide tree does not fit in the device's memory.
    """
    lanes, width = block_lanes(runtime, tree.dim), node_width(runtime)
    key = ("ao4d.bvh/device-tree", id(runtime.context), lanes, width, id(tree), layout.STACK_SIZE)
    cache = getattr(mesh, "cache", None)
    if cache is not None and key in cache:
        return cache[key]
    import pyopencl as pcl

    dev = device_wide_tree(tree, runtime, lanes, width)  # a tree built on this device
    if dev is not None:
        if cache is not None:
            cache[key] = dev
        return dev
    wide = blocks.wide(tree, lanes, width)
    cl.check_device_memory(
        runtime,
        {
            "the BVH leaf blocks": wide.blocks.nbytes,
            "the BVH nodes": wide.boxes.nbytes,
            "the BVH": wide.nbytes(),
        },
        task="ray tracing",
    )
    flags = pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR
    ctx = runtime.context
    dev = {
        "boxes": pcl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(wide.boxes)),
        "children": pcl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(wide.children)),
        "blocks": pcl.Buffer(ctx, flags, hostbuf=np.ascontiguousarray(wide.blocks)),
        "n_blocks": np.int32(len(wide.blocks)),
        "lanes": lanes,
        "width": width,
        "block_first": wide.block_prim[:, 0],
    }
    if cache is not None:
        cache[key] = dev
    return dev
