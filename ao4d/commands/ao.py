"""``ao4d ao``: ambient occlusion of a mesh file, stored as point (or cell) data."""

from __future__ import annotations

import argparse
import math
import time

HELP = "compute ambient occlusion of a mesh (.npz) and store it as point_data['ao']"
EXAMPLES = """  ao4d ao torus.npz --samples 64 --out torus_ao.npz
  ao4d ao torus.npz --samples 256 --max-distance 0.5 --out torus_ao.npz
  ao4d ao torus.npz --at simplices --out torus_ao.npz        # cell_data['ao'] at centroids
  AO4D_DEVICE=none ao4d ao small.npz --out small_ao.npz       # numpy backend (slow)
occlusion is in [0, 1], 1 = fully occluded; shade with 1 - ao.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", metavar="MESH.npz", help="input mesh (ao4d .npz)")
    parser.add_argument("--out", required=True, metavar="OUT.npz", help="output mesh with the AO data")
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    parser.add_argument(
        "--max-distance", type=float, default=math.inf, help="only hits this close occlude (inf)"
    )
    parser.add_argument(
        "--at", choices=("vertices", "simplices"), default="vertices",
        help="per vertex (point_data) or per simplex centroid (cell_data) (vertices)",
    )
    parser.add_argument("--seed", type=int, default=0, help="direction seed (0)")
    parser.add_argument(
        "--backend", choices=("auto", "opencl", "numpy"), default="auto",
        help="OpenCL when a device works, else numpy (auto)",
    )
    parser.add_argument("--name", default="ao", help="data array name (ao)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from .. import cl
    from ..ao import ambient_occlusion
    from ..bvh import get_bvh
    from ..mesh import SimplexMesh

    if not Path(args.mesh).is_file():
        raise FileNotFoundError(f"mesh file {args.mesh!r} does not exist")
    if args.samples < 1:
        raise ValueError(f"`--samples` must be >= 1, got {args.samples}")
    mesh = SimplexMesh.load(args.mesh)
    if args.backend == "numpy":
        device = "numpy backend"
    else:
        runtime = cl.get_runtime(warn=False)
        if runtime is None and args.backend == "opencl":
            raise ValueError("--backend opencl: no working OpenCL device (see `ao4d info`)")
        device = runtime.name if runtime is not None else "numpy backend (no OpenCL device)"
    print(f"{mesh.dim}D mesh: {mesh.n_vertices} vertices, {mesh.n_simplices} simplices; device: {device}")
    start = time.perf_counter()
    tree = get_bvh(mesh)  # cached on the mesh: ambient_occlusion reuses it
    print(f"BVH: {tree.n_prims} simplices ({tree.n_skipped} degenerate skipped), {time.perf_counter() - start:.2f} s")
    start = time.perf_counter()
    ao = ambient_occlusion(
        mesh,
        samples=args.samples,
        max_distance=args.max_distance,
        at=args.at,
        seed=args.seed,
        backend=args.backend,
        progress=False if args.no_progress else True,
    )
    elapsed = time.perf_counter() - start
    rays = int(np.isfinite(ao).sum()) * args.samples
    target = mesh.point_data if args.at == "vertices" else mesh.cell_data
    target[args.name] = ao
    mesh.save(args.out)
    print(
        f"AO at {ao.size} {args.at} x {args.samples} samples: {elapsed:.2f} s "
        f"({rays / max(elapsed, 1e-9) / 1e6:.2f} M rays/s); "
        f"mean {np.nanmean(ao):.3f}, range [{np.nanmin(ao):.3f}, {np.nanmax(ao):.3f}] -> {args.out}"
    )
    return 0
