"""``ao4d slice``: cut a 4D mesh by a hyperplane into a 3D triangle mesh coloured by AO."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "cut a 4D mesh (.npz) by a hyperplane into a 3D mesh (.ply/.glb) coloured by AO"
EXAMPLES = """  ao4d slice scene.npz --w 0.0 --out slice.ply
  ao4d slice scene.npz --w 0.3 --out slice.glb --png slice.png
  ao4d slice scene.npz --point 0 0 0 0 --normal 1 0 0 1 --out tilted.ply
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", type=Path, metavar="MESH.npz", help="4D mesh saved by ao4d")
    parser.add_argument("--out", required=True, type=Path, help="output .ply or .glb")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--w", type=float, help="slice at w = W (default 0)")
    where.add_argument("--point", type=float, nargs=4, metavar="X",
                       help="a point of the hyperplane (with --normal)")
    parser.add_argument("--normal", type=float, nargs=4, metavar="X", default=[0, 0, 0, 1],
                        help="hyperplane normal (default 0 0 0 1)")
    parser.add_argument("--png", type=Path, metavar="FILE.png", help="also render a PNG")


def run(args: argparse.Namespace) -> int:
    from .. import io as aio
    from ..mesh import SimplexMesh

    mesh = SimplexMesh.load(args.mesh)
    if mesh.dim != 4:
        raise ValueError(f"`mesh` must be a 4D mesh, got dimension {mesh.dim}")
    point = args.point if args.point is not None else [0.0, 0.0, 0.0, args.w or 0.0]
    tri = mesh.slice(point, args.normal)
    if len(tri.faces) == 0:
        raise ValueError("the hyperplane misses the mesh: the slice is empty")
    has_ao = "ao" in tri.vertex_attributes
    written = [aio.save_slice_mesh(args.out, tri, occlusion="ao" if has_ao else None)]
    if args.png is not None:
        where = f"w = {point[3]:g}" if args.point is None else f"point {point}, normal {args.normal}"
        written.append(aio.save_slice_png(
            args.png, tri, occlusion="ao" if has_ao else None,
            title=f"{args.mesh.name}: slice {where}" + (", coloured by 4D AO" if has_ao else "")))
    print(f"slice: {len(tri.vertices):,} vertices, {len(tri.faces):,} triangles"
          + ("" if has_ao else " (mesh has no 'ao' point data: uncoloured)")
          + "; wrote " + ", ".join(map(str, written)))
    return 0
