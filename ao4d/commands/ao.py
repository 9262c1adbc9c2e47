"""``ao4d ao``: ambient occlusion of a mesh file, stored as point (or cell) data."""

from __future__ import annotations

import argparse
import math
import time

from ._options import add_backend, add_force

# the library's parameters that arguments become under another name (errors name the argument)
PARAMETERS = {"path": "MESH.npz"}

HELP = "compute ambient occlusion of a mesh (.npz) and store it as point_data['ao']"
EXAMPLES = """  ao4d ao torus.npz --samples 64 --out torus_ao.npz
  ao4d ao torus.npz --samples 256 --max-distance 0.5 --out torus_ao.npz
  ao4d ao torus.npz --at simplices --out torus_ao.npz        # cell_data['ao'] at centroids
  ao4d ao torus.npz --tolerance 0.01 --out torus_ao.npz      # each value within 0.01 (95 %), + ao_error
  AO4D_DEVICE=none ao4d ao small.npz --out small_ao.npz       # numpy backend (slow)
occlusion is in [0, 1], 1 = fully occluded; shade with 1 - ao.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", metavar="MESH.npz", help="input mesh (ao4d .npz)")
    parser.add_argument(
        "--out",
        required=True,
        metavar="OUT.npz",
        help="output mesh with the AO data (.npz; .vtu for ParaView; .txt drops the data)",
    )
    parser.add_argument("--samples", type=int, default=64, help="rays per point (64)")
    parser.add_argument(
        "--tolerance",
        type=float,
        default=None,
        help="trace each point until its AO is within this (in (0, 1)) at --confidence, instead "
        "of --samples rays; stores the standard errors as NAME_error",
    )
    parser.add_argument(
        "--confidence", type=float, default=0.95, help="confidence level of --tolerance, in (0, 1) (0.95)"
    )
    parser.add_argument(
        "--max-samples", type=int, default=4096, help="with --tolerance: the most rays a point traces (4096)"
    )
    parser.add_argument("--max-distance", type=float, default=math.inf, help="only hits this close occlude (inf)")
    parser.add_argument(
        "--at",
        choices=("vertices", "simplices"),
        default="vertices",
        help="per vertex (point_data) or per simplex centroid (cell_data) (vertices)",
    )
    parser.add_argument("--seed", type=int, default=0, help="direction seed (0)")
    add_backend(parser, help="OpenCL when a device works, else numpy (auto)")
    parser.add_argument("--name", default="ao", help="data array name (ao)")
    add_force(parser, help="trace even when the estimate is above the half-hour limit")


def run(args: argparse.Namespace) -> int:
    from .._atomic import check_output_file
    from .._calibration import ao_seconds, rates, seconds_text
    from .._validate import check_seed
    from ..ao import ambient_occlusion, minimum_samples
    from ..io.mesh_files import SUFFIXES, MeshArrays, read_field_data, write
    from ..mesh import SimplexMesh
    from ..opencl import cl
    from ..rays.rows import check_distance

    out = check_output_file(args.out, "--out", SUFFIXES)  # before any work
    if args.samples < 1:
        raise ValueError(f"`--samples` must be >= 1, got {args.samples}")
    if args.tolerance is not None:  # the library's checks, before the mesh is read
        minimum_samples(args.tolerance, args.confidence)
        if args.samples != 64:
            raise ValueError("give `--samples` or `--tolerance`, not both")
    check_seed(args.seed, "--seed")
    check_distance(args.max_distance)
    if not args.name.strip():  # before the trace, not when the result is stored
        raise ValueError(f"`--name` must be a non-empty data array name, got {args.name!r}")
    mesh = SimplexMesh.load(args.mesh)
    runtime = cl.resolve_backend(args.backend, warn=False)
    backend = cl.backend_name(runtime)
    points = mesh.n_vertices if args.at == "vertices" else mesh.n_simplices
    tolerant = args.tolerance is not None
    rays = points * (minimum_samples(args.tolerance, args.confidence) if tolerant else args.samples)
    print(
        f"{mesh.dim}D mesh: {mesh.n_vertices:,} vertices, {mesh.n_simplices:,} simplices; "
        f"device: {cl.describe(runtime)}"
    )
    # rates measured on this device once (cached), so the estimate holds here, BVH build included
    measured = rates(runtime, say=print)
    seconds = ao_seconds(measured, simplices=mesh.n_simplices, points=points, rays=rays)
    if tolerant:
        most = ao_seconds(measured, simplices=mesh.n_simplices, points=points, rays=points * args.max_samples)
        print(
            f"AO to tolerance {args.tolerance:g} at confidence {args.confidence:g}: at least {rays:,} rays, "
            f"{seconds_text(seconds)}, at most {points * args.max_samples:,}, {seconds_text(most)}, "
            "with the BVH build (rates measured on this device)"
        )
    else:
        print(f"AO: {rays:,} rays, {seconds_text(seconds)} with the BVH build (rates measured on this device)")
    start = time.perf_counter()
    result = ambient_occlusion(
        mesh,
        samples=args.samples,
        max_distance=args.max_distance,
        at=args.at,
        seed=args.seed,
        backend=backend,
        progress=True,
        max_rays=math.inf if args.force else None,
        tolerance=args.tolerance,
        confidence=args.confidence,
        max_samples=args.max_samples,
        return_error=True,
    )
    elapsed = time.perf_counter() - start
    ao, error = result
    traced = int(result.rays.sum())
    target = mesh.point_data if args.at == "vertices" else mesh.cell_data
    target[args.name] = ao
    if tolerant:
        target[f"{args.name}_error"] = error
    # the input's field data (how the mesh was made: grid spacing, w scale) stays with it
    write(
        out,
        MeshArrays(mesh.vertices, mesh.simplices, dict(mesh.point_data), dict(mesh.cell_data)),
        field_data=read_field_data(args.mesh),
    )
    how = f"x {args.samples} samples" if not tolerant else _tolerance_summary(result, args)
    print(
        f"AO at {ao.size} {args.at} {how}: {elapsed:.2f} s, BVH build included "
        f"({traced / max(elapsed, 1e-9) / 1e6:.2f} M rays/s); {_summary(ao, args.at)} -> {out}"
    )
    n_open = len(mesh.boundary_faces())
    if n_open:
        print(
            f"note: the mesh is open ({n_open:,} boundary faces): rays leak out through them, so "
            "AO near them is too low (a mesh extracted from data that touch the grid's edge: "
            "extract it again with --closed)"
        )
    return 0


def _tolerance_summary(result, args) -> str:
    """The rays a tolerance took and how many points reached ``--max-samples`` before it."""
    import numpy as np
    from scipy.special import stdtrit

    from ..ao import REPLICATES

    traced = result.rays[result.rays > 0]
    if not traced.size:
        return f"to tolerance {args.tolerance:g}"
    half = stdtrit(REPLICATES - 1, 0.5 + args.confidence / 2) * result.error
    capped = int(((result.rays >= args.max_samples - args.max_samples % REPLICATES) & (half > args.tolerance)).sum())
    text = (
        f"to tolerance {args.tolerance:g} ({args.confidence:g}): {int(traced.sum()):,} rays, "
        f"{np.mean(traced):.0f} a point (median {np.median(traced):.0f}, max {traced.max()})"
    )
    if capped:
        text += (
            f"; {capped:,} points stopped at --max-samples {args.max_samples} above the tolerance "
            f"(largest standard error {np.nanmax(result.error):.3g}, in {args.name}_error)"
        )
    return text


def _summary(ao, at: str) -> str:
    """Mean and range of the AO values; NaN values are counted and named, never hidden."""
    import numpy as np

    finite = np.isfinite(ao)
    if finite.all():
        return f"mean {ao.mean():.3f}, range [{ao.min():.3f}, {ao.max():.3f}]"
    what = "unused vertices" if at == "vertices" else "zero-measure simplices"
    head = f"{int((~finite).sum()):,} of {ao.size:,} values are NaN (no normal: {what})"
    if not finite.any():
        return head
    return (
        f"{head}; the other values: mean {ao[finite].mean():.3f}, range "
        f"[{ao[finite].min():.3f}, {ao[finite].max():.3f}]"
    )
