"""Hits refined in float64: a hit's ``t`` and barycentrics recomputed on the hit simplex when
first read, by ``kernels/rays/refine.cl`` on fp64 devices with a device-built tree, else by the host,
the same operations in the same order: the same bits.
"""

from __future__ import annotations

import numpy as np

from ..opencl import cl
from .rows import _ROW_BLOCK, Tracer, _frame_values, _miss_values, _row_types

__all__ = ["REFINE_ON_DEVICE"]


#: Let fp64 devices refine the hits of a device-built tree themselves (kernels/rays/refine.cl); tests
#: clear it to take the host's refinement, which gives the same bits. Read when a trace starts.
REFINE_ON_DEVICE = True


def _refines_on_device(tree, runtime) -> bool:
    """Whether the hits of a trace of ``tree`` on ``runtime`` are refined by the device: an fp64
    device and a tree it built (whose float64 vertices in the tree's frame it keeps)."""
    return (
        REFINE_ON_DEVICE
        and runtime is not None
        and "cl_khr_fp64" in runtime.device.extensions
        and hasattr(tree, "mesh_arrays")
    )


def _refine_kernel(runtime, dim: int, ray_type: str):
    """The ``refine_hits`` kernel (kernels/rays/refine.cl) for rows of C type ``ray_type``."""
    return cl.build_kernels(runtime, "rays/refine.cl", {"DIM": dim, "RAY_T": ray_type})["refine_hits"]


def _refine_block(inv: np.ndarray, origin: np.ndarray, o: np.ndarray, w: np.ndarray):
    """Ray parameters (tree units) and barycentrics of rays ``o + t w`` (float64, tree frame)
    hitting simplices of inverse frames ``inv`` (k, d, d) and vertex 0 ``origin`` (k, d).

    Products and sums one column at a time, left to right: ``kernels/rays/refine.cl`` repeats these
    operations in this order, so the device's refinement gives the same bits (numpy's
    ``einsum`` chooses its own summation order).
    """
    d = inv.shape[-1]
    rel = o - origin
    num, den = inv[:, -1, 0] * rel[:, 0], inv[:, -1, 0] * w[:, 0]
    for j in range(1, d):
        num = num + inv[:, -1, j] * rel[:, j]
        den = den + inv[:, -1, j] * w[:, j]
    t = -num / den
    x = (o + t[:, None] * w) - origin
    bary = np.empty((len(t), d))
    for i in range(d - 1):
        beta = inv[:, i, 0] * x[:, 0]
        for j in range(1, d):
            beta = beta + inv[:, i, j] * x[:, j]
        bary[:, i + 1] = beta
    total = bary[:, 1].copy()
    for i in range(2, d):
        total = total + bary[:, i]
    bary[:, 0] = 1.0 - total
    return t, bary


def _refine_hits(
    tree,
    n: int,
    rows: np.ndarray,
    p: np.ndarray,
    o: np.ndarray,
    w: np.ndarray,
    inv_length: np.ndarray,
    out: tuple[np.ndarray, np.ndarray] | None = None,
):
    """``t`` (world units) and barycentrics of the hits, recomputed in float64 on the host on the
    hit simplices (tree-order ``p``) of rays ``rows`` (world origins ``o``, directions ``w`` and
    their ``1 / |w|``), written into ``out`` (``t`` and barycentrics holding the misses' inf and
    zeros) when given.

    Block by block of ``_ROW_BLOCK`` hits: every step is per row, so the blocks give the bits
    the whole arrays give, while the frames' float64 temporaries (about 40 d^2 bytes a hit)
    stay in cache instead of faulting in fresh pages (0.3-0.7 s for 0.9 M hits, all at once).
    """
    t, bary = _miss_values(n, tree.dim) if out is None else out
    for a in range(0, len(rows), _ROW_BLOCK):
        b = min(len(rows), a + _ROW_BLOCK)
        inv, origin = tree.frames(p[a:b])
        w_k = w[a:b].astype(np.float64) * inv_length[a:b, None]
        t_hit, bary[rows[a:b]] = _refine_block(inv, origin, tree.frame.points(o[a:b]), w_k)
        t[rows[a:b]] = tree.frame.world_length(t_hit)
    return t, bary


def _refine_on_device(
    tracer: Tracer,
    n: int,
    rows: np.ndarray,
    simplex: np.ndarray,
    o: np.ndarray,
    w: np.ndarray,
    out: tuple[np.ndarray, np.ndarray] | None = None,
):
    """:func:`_refine_hits`' answer (the same bits) from ``kernels/rays/refine.cl``: one work-item per
    hit (mesh simplex ``simplex``, ray rows ``o``, ``w`` as the caller gave them) writes its row
    of ``t`` and the barycentrics (into ``out`` when given, as :func:`_refine_hits`), in place
    where the device shares the host's memory (CPUs). The tree's float64 vertices and the
    simplices go to the device once per tree."""
    import pyopencl as pcl

    tree, runtime, dev = tracer.tree, tracer.runtime, tracer.device
    d = tree.dim
    t, bary = _miss_values(n, d) if out is None else out
    if not len(rows):
        return t, bary
    ctx, queue = runtime.context, runtime.queue
    mf = pcl.mem_flags
    cl.check_device_memory(runtime, {"the refined hits": t.nbytes + bary.nbytes}, task="the hits' refinement")
    mesh = dev.get("refine mesh")
    if mesh is None:
        vertices, simplices = tree.mesh_arrays
        mesh = dev["refine mesh"] = tuple(
            pcl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a, dtype=dtype))
            for a, dtype in ((vertices, np.float64), (simplices, np.int32))
        )
    real, ray_type = _row_types(o, w)  # float32 rows stay float32
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR
    inputs = [
        pcl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(a, dtype=dtype))
        for a, dtype in (
            (o, real),
            (w, real),
            (_frame_values(tree.frame), np.float64),
            (simplex, np.int32),
            (rows, np.int64),
        )
    ]
    outputs = [pcl.Buffer(ctx, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=a) for a in (t, bary)]
    kernel = _refine_kernel(runtime, d, ray_type)
    kernel(queue, (len(rows),), None, *inputs, *mesh, *outputs)
    for buf, a in zip(outputs, (t, bary)):  # the device's writes, seen by the host (no copy on CPUs)
        mapped, _ = pcl.enqueue_map_buffer(queue, buf, pcl.map_flags.READ, 0, a.shape, a.dtype)
        mapped.base.release(queue)
    queue.finish()
    return t, bary
