"""``ao4d render``: render saved 4D meshes into a 3D image volume (.mhd/.vti) and PNG previews."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from pathlib import Path

from ._options import add_backend, add_force, add_meshes

HELP = "render 4D meshes (.npz) into a 3D image volume (.mhd or .vti) with a 4D camera"
EXAMPLES = """  ao4d render scene.npz --out image.mhd
  ao4d render a.npz b.npz --out image.vti --size 96 --ao hits --samples 64 --png image.png
  ao4d render scene.npz --out fast.vti --size 80 --ao screen --max-distance 1 --png fast.png
  ao4d render scene.npz --out faster.vti --ao screen --samples 8 --denoise 1 --max-distance 1
  ao4d render scene.npz --out image.mhd --eye 0 1.6 -0.6 -5.5 --target 0 0.45 0 0 --fov 40
  ao4d render ball.npz ground.npz --out lit.vti --light 0 1 0 -0.5 --specular 0.4 --shadows \\
      --color ball 0.9 0.2 0.1 --opacity ball 0.5 --png lit.png
  ao4d render scene.npz --out two.vti --light point 0 3 0 -1 1 0.9 0.8 --light 1 1 0 0 0.3 0.4 1 0.5
"""

# the library's parameters that options become under another name (errors name the option)
PARAMETERS = {"shape": "--size", "light": "--light", "path": "MESH.npz"}

# the options that go to ao4d.render unchanged, under the same name
PASSED_TO_RENDER = (
    "ao",
    "samples",
    "max_distance",
    "denoise",
    "ambient",
    "diffuse",
    "specular",
    "shininess",
    "shadows",
    "depth_cue",
    "layers",
    "backend",
)

LIGHT_HELP = (
    "a light (repeatable): X Y Z W is the direction towards a white directional light; "
    "'point X Y Z W' a point light at that position; optional R G B colour (0..1) and "
    "intensity I after the four numbers"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_meshes(parser, metavar="MESH.npz", help="4D meshes saved by ao4d (several: object ids follow their order)")
    parser.add_argument("--out", required=True, type=Path, help="output volume, .mhd or .vti")
    parser.add_argument(
        "--size",
        type=int,
        nargs="+",
        default=[64],
        metavar="N",
        help="voxels per axis: one number or three (nx ny nz); default 64",
    )
    parser.add_argument("--eye", type=float, nargs=4, metavar="X", help="eye position")
    parser.add_argument("--target", type=float, nargs=4, metavar="X", help="point looked at")
    parser.add_argument("--up", type=float, nargs=4, default=[0, 1, 0, 0], metavar="X")
    parser.add_argument("--over", type=float, nargs=4, default=[0, 0, 1, 0], metavar="X")
    parser.add_argument("--fov", type=float, default=40.0, help="viewing angle in degrees")
    parser.add_argument("--projection", choices=("perspective", "orthographic"), default="perspective")
    parser.add_argument(
        "--ao",
        choices=("vertices", "hits", "screen", "none"),
        default="vertices",
        help="AO per vertex (stored 'ao' or computed), ray traced at each hit, "
        "screen-space from the image's depth volume, or none",
    )
    parser.add_argument("--samples", type=int, default=64, help="AO rays (screen: directions) per point")
    parser.add_argument(
        "--max-distance", type=float, default=math.inf, help="AO reach: only hits this close occlude (default inf)"
    )
    parser.add_argument(
        "--denoise",
        type=int,
        default=0,
        metavar="R",
        help="with --ao screen: depth-aware box filter of radius R voxels (default 0: none)",
    )
    parser.add_argument("--light", action="append", nargs="+", metavar="ARG", help=LIGHT_HELP)
    parser.add_argument("--ambient", type=float, help="weight of 1 - AO (default 1 without a light, else 0.7)")
    parser.add_argument("--diffuse", type=float, help="Lambert weight (default 0.3)")
    parser.add_argument("--specular", type=float, default=0.0, help="4D Blinn-Phong weight (default 0: no highlights)")
    parser.add_argument("--shininess", type=float, default=32.0, help="Blinn-Phong exponent (default 32)")
    parser.add_argument("--shadows", action="store_true", help="cast 4D shadow rays towards every light")
    parser.add_argument(
        "--depth-cue",
        type=float,
        nargs=3,
        metavar=("NEAR", "FAR", "STRENGTH"),
        help="fade to black with 4D distance along the view ray",
    )
    parser.add_argument(
        "--color",
        action="append",
        nargs=4,
        metavar=("OBJ", "R", "G", "B"),
        help="RGB (0..1) of object OBJ: its index (0 = first mesh or object id 0) or its file name (repeatable)",
    )
    parser.add_argument(
        "--opacity", action="append", nargs=2, metavar=("OBJ", "A"), help="opacity (0..1) of object OBJ (repeatable)"
    )
    parser.add_argument(
        "--layers", type=int, default=4, help="surfaces composited along a ray behind transparent hits (default 4)"
    )
    add_backend(parser)
    add_force(parser, help="render even when the rays would take more than about half an hour")
    parser.add_argument(
        "--png",
        type=Path,
        metavar="FILE.png",
        help="also write a z-slice montage (FILE.png), a volume rendering "
        "(FILE_volume.png) and both in colour (FILE_color.png, "
        "FILE_color_volume.png)",
    )


def parse_light(tokens: list[str]):
    """One ``--light`` value: ``[point] X Y Z W [R G B [I]]`` -> :class:`ao4d.Light`."""
    from ..rendering.lighting import Light

    words = list(tokens)
    kind = words.pop(0) if words and words[0] in ("point", "dir", "direction") else "dir"
    try:
        numbers = [float(w) for w in words]
    except ValueError:
        raise ValueError(f"`--light` takes [point] X Y Z W [R G B [I]], got {' '.join(tokens)!r}") from None
    if len(numbers) not in (4, 7, 8):
        raise ValueError(
            f"`--light` takes [point] X Y Z W [R G B [I]] (4, 7 or 8 numbers), got {len(numbers)}: {' '.join(tokens)!r}"
        )
    if not all(math.isfinite(x) for x in numbers):
        raise ValueError(f"`--light` takes finite numbers, got {' '.join(tokens)!r}")
    where = {"position" if kind == "point" else "direction": numbers[:4]}
    color = numbers[4:7] if len(numbers) >= 7 else (1.0, 1.0, 1.0)
    intensity = numbers[7] if len(numbers) == 8 else 1.0
    try:
        return Light(**where, color=color, intensity=intensity)
    except (TypeError, ValueError) as exc:
        # the Light's parameter, as a word: `color` here is not the option --color
        reason = re.sub(r"`(\w+)`", r"its \1", str(exc))
        raise ValueError(f"`--light` {' '.join(tokens)!r}: {reason}") from None


def object_index(name: str, paths: list[Path], n_objects: int, option: str) -> int:
    """The object id an ``--color``/``--opacity`` OBJ names: an index or a mesh file name."""
    for i, path in enumerate(paths):
        if name in (path.name, path.stem):
            return i
    try:
        index = int(name)
    except ValueError:
        names = ", ".join(p.stem for p in paths)
        raise ValueError(f"`{option}` object {name!r} is neither an index nor one of the meshes ({names})") from None
    if not 0 <= index < n_objects:
        raise ValueError(
            f"`{option}` object {index} is out of range: the scene has {n_objects} object(s), 0..{n_objects - 1}"
        )
    return index


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from .._atomic import all_or_nothing, check_output_file
    from ..io.volumes import check_mhd_path
    from ..mesh import SimplexMesh, concatenate
    from ..rendering.camera import Camera4D
    from ..rendering.pipeline import render

    # every output checked before the work; .mhd also writes its .raw
    outputs = [check_output_file(args.out, "--out", (".vti", ".mhd"))]
    if Path(args.out).suffix.lower() == ".mhd":
        check_mhd_path(args.out, "--out")  # the header names its .raw in ASCII
        outputs.append(check_output_file(Path(args.out).with_suffix(".raw"), "--out"))
    if args.png is not None:
        stem = check_output_file(args.png, "--png", (".png",)).with_suffix("")
        outputs += [Path(args.png)] + [Path(f"{stem}{s}.png") for s in ("_volume", "_color", "_color_volume")]
    size = args.size * 3 if len(args.size) == 1 else args.size
    if len(size) != 3:
        raise ValueError(f"`--size` takes one or three numbers, got {len(size)}")
    if (args.eye is None) != (args.target is None):
        raise ValueError("`--eye` and `--target` go together (or leave both out to frame all)")
    lights = [parse_light(tokens) for tokens in args.light or []]
    meshes = [SimplexMesh.load(p) for p in args.meshes]
    for path, mesh in zip(args.meshes, meshes):
        if mesh.dim != 4:
            raise ValueError(f"`meshes`: {path.name} is a {mesh.dim}D mesh; render takes 4D meshes (tetrahedra in R^4)")
    scene = meshes[0] if len(meshes) == 1 else concatenate(meshes)
    ids = scene.cell_data.get("object_id") if len(meshes) == 1 else None
    n_objects = len(meshes) if ids is None else int(np.max(ids)) + 1
    color = np.ones((n_objects, 3))
    for obj, *rgb in args.color or []:
        color[object_index(obj, args.meshes, n_objects, "--color")] = [float(c) for c in rgb]
    opacity = np.ones(n_objects)
    for obj, alpha in args.opacity or []:
        opacity[object_index(obj, args.meshes, n_objects, "--opacity")] = float(alpha)
    if args.eye is None:
        camera = Camera4D.framing(scene.bounds, up=args.up, over=args.over, fov=args.fov, projection=args.projection)
    else:
        camera = Camera4D(args.eye, args.target, args.up, args.over, fov=args.fov, projection=args.projection)
    print(camera)
    print(_estimate(args, scene, camera, tuple(size), lights, opacity))
    image = render(
        scene,
        camera,
        tuple(size),
        light=lights or None,
        color=color,
        opacity=opacity,
        max_rays=math.inf if args.force else None,
        **{name: getattr(args, name) for name in PASSED_TO_RENDER},
    )
    print(image)
    with all_or_nothing(outputs):  # a failing picture leaves no new .vti behind
        written = _write(args, image, size)
    print(f"{int(image.hit.sum()):,} of {image.hit.size:,} voxels hit; wrote " + ", ".join(map(str, written)))
    return 0


# primary rays per axis of the preview that counts the hits before the render
_PREVIEW = 12


def _estimate(args: argparse.Namespace, scene, camera, size: tuple[int, int, int], lights: list, opacity) -> str:
    """One line: the render's work and its time on this device (:mod:`ao4d._calibration`).

    The per-hit work (AO and shadow rays, shading) depends on how much of the image the scene
    covers, so a preview of at most ``_PREVIEW``^3 primary rays over the same image counts the
    hits first. It builds the scene's BVH, which the render then uses.
    """
    import numpy as np

    from .._budget import RAYS_PER_SECOND
    from .._calibration import rates, render_seconds, seconds_text
    from ..opencl import cl
    from ..rays.api import cast_rays
    from ..rendering.screen_ao import DENOISE_PER_SECOND, LOOKUPS_PER_SECOND, march_steps

    runtime = cl.resolve_backend(args.backend, warn=False)
    backend = cl.backend_name(runtime)
    measured = rates(runtime, say=print)
    voxels = math.prod(size)
    preview = tuple(min(n, _PREVIEW) for n in size)
    origins, directions = camera.rays(preview)
    hit = cast_rays(scene, origins.reshape(-1, 4), directions.reshape(-1, 4), closest=False, backend=backend).hit
    layers = 1 if np.all(opacity >= 1) else args.layers  # a transparent hit lets the ray go on
    hits = float(hit.mean()) * voxels * layers
    per_hit = (args.samples if args.ao == "hits" else 0) + (len(lights) if args.shadows else 0)
    vertex_ao = args.ao == "vertices" and "ao" not in scene.point_data
    extra = 0.0
    if args.ao == "screen":  # depth look-ups and the filter window, at the rates of their estimate
        spacing = camera.geometry(size).spacing
        reach = min(args.max_distance, float(np.linalg.norm(np.subtract(*scene.bounds[::-1]))))
        steps = march_steps(reach / spacing)
        window = voxels * (2 * args.denoise + 1) ** 3 if args.denoise else 0
        # those rates are the reference machine's: scaled by how fast rays go here against it
        slower = RAYS_PER_SECOND[backend] / measured.ao_rays
        extra = slower * (
            hits * args.samples * steps / LOOKUPS_PER_SECOND[backend] + window / DENOISE_PER_SECOND[backend]
        )
    seconds = render_seconds(
        measured,
        voxels=voxels,
        hits=hits,
        simplices=scene.n_simplices,
        rays_per_hit=per_hit,
        other_points=scene.n_vertices if vertex_ao else 0,
        other_rays=scene.n_vertices * args.samples if vertex_ao else 0,
        extra_seconds=extra,
    )
    work = [f"{voxels:,} voxels, {hit.mean():.0%} hit (a preview of {hit.size:,} rays)"]
    if per_hit:
        work.append(f"{per_hit} ray(s) per hit")
    if vertex_ao:
        work.append(f"AO at {scene.n_vertices:,} vertices first")
    return f"render: {', '.join(work)}; {seconds_text(seconds)} (rates measured on this device)"


def _write(args: argparse.Namespace, image, size) -> list:
    from ..io.pictures import save_montage, save_rgba_montage, save_rgba_volume_png, save_volume_png

    written = [image.save(args.out)]
    if args.png is not None:
        geo = image.geometry
        title = f"{', '.join(p.name for p in args.meshes)}: {'x'.join(map(str, size))} voxels, AO {args.ao}"
        written.append(shade_picture(save_montage, args.png, image, title))
        stem = args.png.with_suffix("")
        written.append(shade_picture(save_volume_png, f"{stem}_volume.png", image, title))
        written.append(
            save_rgba_montage(f"{stem}_color.png", image.rgba, title=title, spacing=geo.spacing, origin=geo.origin)
        )
        written.append(
            save_rgba_volume_png(
                f"{stem}_color_volume.png", image.rgba, title=title, spacing=geo.spacing, origin=geo.origin
            )
        )
    return written


def shade_picture(save: Callable[..., Path], path, image, title: str, **options) -> Path:
    """One picture of a rendered image's shade: ``save`` (:func:`ao4d.io.pictures.save_montage` or
    :func:`ao4d.io.pictures.save_volume_png`) on ``image.shade`` in world coordinates, the voxels no
    ray hit drawn as background; ``options`` go to ``save`` (``cmap``...). Returns its path."""
    geo = image.geometry
    return save(
        path,
        image.shade,
        background=~image.hit,
        title=title,
        label="shade",
        spacing=geo.spacing,
        origin=geo.origin,
        **options,
    )
