"""``ao4d demo``: the whole pipeline on the embedded default scene, into ``./ao4d-demo/``.

Scene (ao4d.scenes.default_scene) -> extraction per object -> one mesh with object ids ->
per-vertex 4D ambient occlusion -> 3D image volume from a 4D camera (AO, Lambert, 4D
highlights and shadows, object colours) -> files and pictures.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from ._options import add_backend

HELP = "run the whole pipeline on a built-in 4D scene and write volumes, meshes and pictures"
EXAMPLES = """  ao4d demo                          writes ./ao4d-demo/ (under a minute on 2 CPU cores)
  ao4d demo --out pictures --quality high
  ao4d-demo/view.html                the scene in a browser: slices and the 3D image (tabs)
  paraview ao4d-demo/image.vti       3D image: shade, depth, object_id, occlusion, rgba
                                     (colour by rgba, untick Map Scalars: the voxels' own colours)
"""


# shade = 0.4 (1 - AO) + 0.3 Lambert + 0.3 Blinn-Phong (lit, unshadowed voxels)
_AMBIENT, _DIFFUSE = 0.4, 0.3


@dataclass
class DemoReport:
    """What the demo made: sizes, speeds and files."""

    objects: list[tuple[str, int, int]]  # (name, vertices, simplices)
    ao_rays: int
    ao_seconds: float
    device: str
    image_shape: tuple[int, int, int]
    files: list[Path]
    stage_seconds: dict[str, float] = field(default_factory=dict)
    file_seconds: dict[str, float] = field(default_factory=dict)  # the "files" stage, per step
    wall_seconds: float = 0.0

    @property
    def rays_per_second(self) -> float:
        return self.ao_rays / self.ao_seconds if self.ao_seconds > 0 else float("nan")

    def table(self) -> str:
        """The summary printed at the end of ``ao4d demo``."""
        lines = ["", f"{'object':<22}{'vertices':>10}{'tetrahedra':>12}"]
        for name, nv, ns in self.objects:
            lines.append(f"{name:<22}{nv:>10,}{ns:>12,}")
        total_v = sum(o[1] for o in self.objects)
        total_s = sum(o[2] for o in self.objects)
        lines.append(f"{'total':<22}{total_v:>10,}{total_s:>12,}")
        lines.append("")
        lines.append(
            f"AO: {self.ao_rays:,} rays in {self.ao_seconds:.1f} s = "
            f"{self.rays_per_second / 1e6:.2f} M rays/s on {self.device}"
        )
        lines.append("stages: " + ", ".join(f"{k} {v:.2f} s" for k, v in self.stage_seconds.items()))
        if self.file_seconds:
            lines.append("files stage: " + ", ".join(f"{k} {v:.2f} s" for k, v in self.file_seconds.items()))
        lines.append(f"image: {'x'.join(map(str, self.image_shape))} voxels")
        lines.append("files:")
        for path in self.files:
            lines.append(f"  {path}  ({_size(path)})")
        lines.append(f"wall time: {self.wall_seconds:.1f} s")
        return "\n".join(lines)


def _size(path: Path) -> str:
    n = path.stat().st_size
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"  # pragma: no cover


def _device(backend: str) -> str:
    from ..opencl import cl

    return cl.describe(cl.resolve_backend(backend, warn=False))


def run_demo(
    out: str | Path = "ao4d-demo",
    *,
    quality: str = "default",
    backend: str = "auto",
    progress: bool | None = True,
    stream: TextIO | None = None,
) -> DemoReport:
    """Build, shade and render the default scene; write every file into ``out``.

    Parameters
    ----------
    out : path-like
        Output folder (created).
    quality : {"tiny", "default", "high"}
        Grid cell, image size and AO samples (:data:`ao4d.scenes.QUALITY`); "tiny" is for tests.
    backend : {"auto", "opencl", "numpy"}
    progress : bool, optional
        Progress bars for extraction, AO and rendering.
    stream : text file, optional
        Where stage lines and the table go (default stdout); pass ``io.StringIO()`` to silence.

    Returns
    -------
    DemoReport
    """

    from .._atomic import all_or_nothing, check_output_folder
    from .._validate import check_choice
    from ..ao import ambient_occlusion
    from ..bvh import get_bvh
    from ..mesh import concatenate
    from ..opencl import cl
    from ..rendering.pipeline import render
    from ..scenes import QUALITY, default_scene, extract_scene

    check_choice(quality, "quality", tuple(QUALITY))
    check_choice(backend, "backend", cl.BACKENDS)
    stream = sys.stdout if stream is None else stream
    settings = QUALITY[quality]
    out = check_output_folder(out, "out")  # before the work: a file there, or no write access
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    stages: dict[str, float] = {}

    def say(text: str) -> None:
        print(text, file=stream, flush=True)

    scene_def = default_scene()
    shape = settings["image"]
    say(
        f"ao4d demo: {len(scene_def.objects)} objects, grid cell {settings['cell']}, "
        f"{settings['samples']} AO samples, {'x'.join(map(str, shape))} image -> {out}/"
    )

    t = time.perf_counter()
    meshes = extract_scene(scene_def, cell=settings["cell"], progress=progress)
    scene = concatenate(meshes)
    stages["extract"] = time.perf_counter() - t
    say(f"extracted {scene.n_simplices:,} tetrahedra in {stages['extract']:.1f} s")

    # BVH build (on the device that traces, its wide form included), then kernel loading and
    # the sampling tables once, each timed apart from the AO rays themselves
    t = time.perf_counter()
    get_bvh(scene, runtime=cl.resolve_backend(backend, warn=False))
    stages["BVH"] = time.perf_counter() - t
    t = time.perf_counter()
    ambient_occlusion(
        scene, points=scene.vertices[:1], normals=[[0.0, 1.0, 0.0, 0.0]], samples=1, backend=backend, progress=False
    )
    stages["kernels"] = time.perf_counter() - t

    t = time.perf_counter()
    occlusion = ambient_occlusion(
        scene,
        samples=settings["samples"],
        seed=0,
        backend=backend,
        max_distance=scene_def.max_distance,
        progress=progress,
    )
    ao_seconds = time.perf_counter() - t
    stages["AO"] = ao_seconds
    scene.point_data["ao"] = occlusion
    ao_rays = scene.n_vertices * settings["samples"]
    say(f"ambient occlusion: {ao_rays:,} rays in {ao_seconds:.1f} s")

    t = time.perf_counter()
    # the full model: AO, Lambert, 4D Blinn-Phong highlights, 4D shadows, object colours
    # (weights sum to 1, so shade stays in [0, 1])
    image = render(
        scene,
        scene_def.camera,
        shape,
        ao="vertices",
        light=scene_def.light,
        ambient=_AMBIENT,
        diffuse=_DIFFUSE,
        specular=scene_def.speculars,
        shininess=scene_def.shininess,
        shadows=True,
        color=scene_def.colors,
        backend=backend,
        progress=progress,
    )
    stages["render"] = time.perf_counter() - t
    say(f"rendered {'x'.join(map(str, shape))} voxels in {stages['render']:.1f} s")

    t = time.perf_counter()
    file_seconds: dict[str, float] = {}
    with all_or_nothing(folder=out):  # a failing picture takes the files of this run with it
        files = _write_files(out, scene, image, settings, file_seconds, names=[o.name for o in scene_def.objects])
    stages["files"] = time.perf_counter() - t

    report = DemoReport(
        objects=[(o.name, m.n_vertices, m.n_simplices) for o, m in zip(scene_def.objects, meshes)],
        ao_rays=ao_rays,
        ao_seconds=ao_seconds,
        device=_device(backend),
        image_shape=shape,
        files=files,
        stage_seconds=stages,
        file_seconds=file_seconds,
        wall_seconds=time.perf_counter() - started,
    )
    say(report.table())
    return report


def _write_files(out: Path, scene, image, settings, seconds: dict[str, float], *, names: list[str]) -> list[Path]:
    """Every file of the demo; returns their paths in the order written and adds the seconds
    of each step to ``seconds`` (imports included: they are part of what the step costs)."""
    geo = image.geometry
    samples = settings["samples"]
    params = f"{'x'.join(map(str, geo.shape))} voxels, {samples} AO samples"
    model = f"{_AMBIENT:g} (1 - AO) + {_DIFFUSE:g} Lambert + specular, 4D shadows"
    files: list[Path] = []
    clock = [time.perf_counter()]

    def done(step: str, *paths: Path) -> None:
        now = time.perf_counter()
        seconds[step] = seconds.get(step, 0.0) + now - clock[0]
        clock[0] = now
        files.extend(paths)

    scene.save(out / "scene.npz")
    done("scene.npz", out / "scene.npz")
    done("image.mhd", image.save(out / "image.mhd"), out / "image.raw")
    done("image.vti", image.save(out / "image.vti"))
    from ..io.pictures import save_montage, save_rgba_montage, save_rgba_volume_png, save_slice_png, save_volume_png
    from .render import shade_picture

    done(
        "montage",
        shade_picture(
            save_montage,
            out / "image_slices.png",
            image,
            f"ao4d demo: z-slices of the 3D image, shade = {model} ({params})",
            cmap="magma",
        ),
    )
    done(
        "volume picture",
        shade_picture(
            save_volume_png,
            out / "image_volume.png",
            image,
            f"ao4d demo: 3D image of a 4D scene ({params})",
            cmap="magma",
        ),
    )
    done(
        "colour montage",
        save_rgba_montage(
            out / "image_color_slices.png",
            image.rgba,
            title=f"ao4d demo: z-slices of the colour 3D image: 4D AO, highlights and shadows ({params})",
            n_slices=8,
            spacing=geo.spacing,
            origin=geo.origin,
        ),
    )
    done(
        "colour volume picture",
        save_rgba_volume_png(
            out / "image_color_volume.png",
            image.rgba,
            title=f"ao4d demo: colour 3D image of a 4D scene ({params})",
            spacing=geo.spacing,
            origin=geo.origin,
        ),
    )
    from ..io.mesh_files import save_slice_mesh

    tri = scene.slice([0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], attributes=["ao"])
    done("slice")
    for suffix in (".ply", ".glb"):
        done("slice meshes", save_slice_mesh(out / f"slice_w0{suffix}", tri, occlusion="ao"))
    done(
        "slice picture",
        save_slice_png(
            out / "slice_w0.png",
            tri,
            occlusion="ao",
            title=f"ao4d demo: slice w = 0 coloured by 4D AO ({samples} samples)",
        ),
    )
    from ..browser.pages import result_page  # the same scene in the browser: slices and projection
    from ..browser.viewer import split_objects

    done("view.html", result_page(split_objects(scene), image, out / "view.html", title="ao4d demo", names=names))
    return files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="ao4d-demo", metavar="DIR", help="output folder (default: ./ao4d-demo)")
    parser.add_argument(
        "--quality",
        choices=("default", "high"),
        default="default",
        help="default: about 5 s on 2 cores, 132x48x80 image; high: finer grids, 212x76x128 image, 128 AO samples",
    )
    add_backend(parser, help="OpenCL device (auto) or the numpy fallback")
    parser.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)  # for tests


def run(args: argparse.Namespace) -> int:
    run_demo(
        args.out,
        quality="tiny" if args.tiny else args.quality,
        backend=args.backend,
        progress=None if args.tiny else True,
    )
    return 0
