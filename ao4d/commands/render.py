"""``ao4d render``: render saved 4D meshes into a 3D image volume (.mhd/.vti) and PNG previews."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "render 4D meshes (.npz) into a 3D image volume (.mhd or .vti) with a 4D camera"
EXAMPLES = """  ao4d render scene.npz --out image.mhd
  ao4d render a.npz b.npz --out image.vti --size 96 --ao hits --samples 64 --png image.png
  ao4d render scene.npz --out image.mhd --eye 0 1.6 -0.6 -5.5 --target 0 0.45 0 0 --fov 40
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("meshes", nargs="+", type=Path, metavar="MESH.npz",
                        help="4D meshes saved by ao4d (several: object ids follow their order)")
    parser.add_argument("--out", required=True, type=Path, help="output volume, .mhd or .vti")
    parser.add_argument("--size", type=int, nargs="+", default=[64], metavar="N",
                        help="voxels per axis: one number or three (nx ny nz); default 64")
    parser.add_argument("--eye", type=float, nargs=4, metavar="X", help="eye position")
    parser.add_argument("--target", type=float, nargs=4, metavar="X", help="point looked at")
    parser.add_argument("--up", type=float, nargs=4, default=[0, 1, 0, 0], metavar="X")
    parser.add_argument("--over", type=float, nargs=4, default=[0, 0, 1, 0], metavar="X")
    parser.add_argument("--fov", type=float, default=40.0, help="viewing angle in degrees")
    parser.add_argument("--projection", choices=("perspective", "orthographic"),
                        default="perspective")
    parser.add_argument("--ao", choices=("vertices", "hits", "none"), default="vertices",
                        help="AO per vertex (stored 'ao' or computed), at each hit, or none")
    parser.add_argument("--samples", type=int, default=64, help="AO rays per point")
    parser.add_argument("--light", type=float, nargs=4, metavar="X",
                        help="direction towards a directional light (adds a Lambert term)")
    parser.add_argument("--backend", choices=("auto", "opencl", "numpy"), default="auto")
    parser.add_argument("--png", type=Path, metavar="FILE.png",
                        help="also write a z-slice montage (FILE.png) and a volume rendering "
                             "(FILE_volume.png)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from .. import io as aio
    from ..camera import Camera4D
    from ..mesh import SimplexMesh, concatenate
    from ..render import render

    size = args.size * 3 if len(args.size) == 1 else args.size
    if len(size) != 3:
        raise ValueError(f"`--size` takes one or three numbers, got {len(size)}")
    meshes = [SimplexMesh.load(p) for p in args.meshes]
    scene = meshes[0] if len(meshes) == 1 else concatenate(meshes)
    if (args.eye is None) != (args.target is None):
        raise ValueError("`--eye` and `--target` go together (or leave both out to frame all)")
    if args.eye is None:
        camera = Camera4D.framing(scene.bounds, up=args.up, over=args.over, fov=args.fov,
                                  projection=args.projection)
    else:
        camera = Camera4D(args.eye, args.target, args.up, args.over, fov=args.fov,
                          projection=args.projection)
    print(camera)
    light = None if args.light is None else np.asarray(args.light)
    image = render(scene, camera, tuple(size), ao=args.ao, samples=args.samples, light=light,
                   ambient=1.0 if light is None else 0.7, diffuse=0.3, backend=args.backend)
    written = [image.save(args.out)]
    if args.png is not None:
        geo = image.geometry
        title = f"{', '.join(p.name for p in args.meshes)}: {'x'.join(map(str, size))} voxels, AO {args.ao}"
        written.append(aio.save_montage(args.png, image.shade, background=~image.hit,
                                        title=title, label="shade", spacing=geo.spacing,
                                        origin=geo.origin))
        volume_png = args.png.with_name(args.png.stem + "_volume.png")
        aio.save_volume_png(volume_png, image.shade, background=~image.hit, title=title,
                            label="shade", spacing=geo.spacing, origin=geo.origin)
        written.append(volume_png)
    print(f"{int(image.hit.sum()):,} of {image.hit.size:,} voxels hit; wrote "
          + ", ".join(map(str, written)))
    return 0
