"""``ao4d slice``: cut a 4D mesh by a hyperplane into a 3D triangle mesh coloured by AO, or
by N hyperplanes w = const into a time series that ParaView plays (PLY files plus a ``.pvd``).

A series folder holds ``slice_0000.ply`` ... (AO as vertex colours and an ``ao`` vertex
property), ``slice_0000.vtp`` ... (the same triangles with ``ao`` as point data: VTK's PVD
reader, ParaView's included, reads only VTK XML files) and ``series.pvd``, whose ``timestep``
attributes are the w values, so that ParaView's time slider moves through w.
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

import numpy as np

from ._options import add_pair

# the library's parameters that arguments become under another name (errors name the argument)
PARAMETERS = {"path": "MESH.npz"}

HELP = "cut a 4D mesh (.npz) by a hyperplane into a 3D mesh (.ply/.glb) coloured by AO"
EXAMPLES = """  ao4d slice scene.npz --w 0.0 --out slice.ply
  ao4d slice scene.npz --w 0.3 --out slice.glb --png slice.png
  ao4d slice scene.npz --point 0 0 0 0 --normal 1 0 0 1 --out tilted.ply
  ao4d slice scene.npz --w-range -1 1 --count 40 --out series/    # then open series/series.pvd
"""

SERIES_NAME = "series.pvd"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", type=Path, metavar="MESH.npz", help="4D mesh saved by ao4d")
    parser.add_argument("--out", required=True, type=Path, help="output .ply or .glb (a folder with --w-range)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--w", type=float, help="slice at w = W (default 0)")
    where.add_argument("--point", type=float, nargs=4, metavar="X", help="a point of the hyperplane (with --normal)")
    add_pair(
        where,
        "--w-range",
        metavar=("START", "STOP"),
        help="a series of slices w = const from START to STOP (both included)",
    )
    parser.add_argument("--count", type=int, default=None, help="number of slices of --w-range (default 10)")
    parser.add_argument(
        "--normal", type=float, nargs=4, metavar="X", default=None, help="hyperplane normal (default 0 0 0 1)"
    )
    parser.add_argument("--png", type=Path, metavar="FILE.png", help="also render a PNG")


_AXES = "xyzw"


def describe_hyperplane(point, normal) -> str:
    """The hyperplane through ``point`` with ``normal`` as an equation: ``"w = 0.3"``,
    ``"x = 0"``, ``"0.707 x + 0.707 w = 0.212"`` (unit normal)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    c = float(n @ np.asarray(point, dtype=np.float64))
    nonzero = np.flatnonzero(np.abs(n) > 1e-12)
    if len(nonzero) == 1:  # axis-aligned: "x = c"
        k = int(nonzero[0])
        return f"{_AXES[k]} = {_g(c * np.sign(n[k]))}"
    terms = []
    for k in nonzero:
        coef = _g(abs(n[k]), 3)
        sign = "-" if n[k] < 0 else "+"
        terms.append((sign, f"{coef} {_AXES[k]}"))
    text = ("-" if terms[0][0] == "-" else "") + terms[0][1]
    text += "".join(f" {sign} {term}" for sign, term in terms[1:])
    return f"{text} = {_g(c, 3)}"


def _check_numbers(args: argparse.Namespace) -> None:
    """Refuse non-finite numbers before the mesh is read, naming the option given (``--w nan``
    would otherwise surface as the library's `point`)."""
    from .._validate import as_real, as_vector

    if args.w is not None:
        as_real(args.w, "--w")
    if args.point is not None:
        as_vector(args.point, "--point", 4, scalar=False)
    if args.normal is not None:
        as_vector(args.normal, "--normal", 4, scalar=False, nonzero=True)
    if args.w_range is not None:
        as_real(args.w_range[0], "--w-range START")
        as_real(args.w_range[1], "--w-range STOP")


def _g(value: float, digits: int = 6) -> str:
    text = f"{value:.{digits}g}"
    return "0" if text in ("-0", "0") else text


def run(args: argparse.Namespace) -> int:
    from .._atomic import all_or_nothing, check_output_file, check_output_folder
    from ..io.mesh_files import SLICE_SUFFIXES, save_slice_mesh
    from ..io.pictures import save_slice_png
    from ..mesh import SimplexMesh

    if args.w_range is None and args.count is not None:
        raise ValueError("`--count` needs `--w-range START STOP`")
    _check_numbers(args)
    outputs = []
    if args.w_range is not None:
        check_output_folder(args.out, "--out")  # before loading the mesh
    else:
        outputs.append(check_output_file(args.out, "--out", SLICE_SUFFIXES))
        if args.png is not None:
            outputs.append(check_output_file(args.png, "--png", (".png",)))
    mesh = SimplexMesh.load(args.mesh)
    if mesh.dim != 4:
        raise ValueError(f"`mesh` must be a 4D mesh, got dimension {mesh.dim}")
    if args.w_range is not None:
        if args.normal is not None or args.png is not None:
            raise ValueError("`--w-range` slices along w: it takes no `--normal` or `--png`")
        return _series(mesh, args)
    normal = args.normal if args.normal is not None else [0.0, 0.0, 0.0, 1.0]
    point = args.point if args.point is not None else [0.0, 0.0, 0.0, args.w or 0.0]
    tri = mesh.slice(point, normal)
    if len(tri.faces) == 0:
        raise ValueError("the hyperplane misses the mesh: the slice is empty")
    has_ao = "ao" in tri.vertex_attributes
    with all_or_nothing(outputs):  # a failing picture leaves no new slice mesh behind
        written = [save_slice_mesh(args.out, tri, occlusion="ao" if has_ao else None)]
        if args.png is not None:
            where = describe_hyperplane(point, normal)  # the plane actually cut, whatever the flags
            written.append(
                save_slice_png(
                    args.png,
                    tri,
                    occlusion="ao" if has_ao else None,
                    title=f"{args.mesh.name}: slice {where}" + (", coloured by 4D AO" if has_ao else ""),
                )
            )
    print(
        f"slice: {len(tri.vertices):,} vertices, {len(tri.faces):,} triangles"
        + ("" if has_ao else " (mesh has no 'ao' point data: uncoloured)")
        + "; wrote "
        + ", ".join(map(str, written))
    )
    return 0


def _series(mesh, args: argparse.Namespace) -> int:
    """N slices w = const into ``args.out``: PLY + VTP per step and a ParaView collection."""
    from .. import _progress
    from .._validate import as_real, check_positive_int

    start = as_real(args.w_range[0], "--w-range START")
    stop = as_real(args.w_range[1], "--w-range STOP")
    count = check_positive_int(10 if args.count is None else args.count, "--count")
    if count > 100_000:
        raise ValueError(f"`--count` must be at most 100000, got {count}")
    if start == stop and count > 1:
        raise ValueError(
            f"`--w-range` {start:g} {stop:g} is one point: {count} slices would all "
            "be the same; give START != STOP, or --w for one slice"
        )
    lo, hi = mesh.bounds
    if max(start, stop) < lo[3] or min(start, stop) > hi[3]:
        raise ValueError(f"the w range [{start:g}, {stop:g}] misses the mesh (its w runs from {lo[3]:g} to {hi[3]:g})")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"`--out` {str(out)!r} must be a folder for a series, not a file")
    out.mkdir(parents=True, exist_ok=True)
    ws = np.linspace(start, stop, count)
    steps = write_series(mesh, ws, out, progress=_progress.bar(count, "slices", unit="slice"))
    filled = sum(1 for s in steps if s["triangles"])
    has_ao = "ao" in mesh.point_data
    print(
        f"slice series: {count} slices w = {start:g} .. {stop:g} ({filled} not empty), "
        f"{sum(s['triangles'] for s in steps):,} triangles"
        + ("" if has_ao else " (mesh has no 'ao' point data: uncoloured)")
        + f"; wrote {out / SERIES_NAME} and {2 * count} slice files in {out}"
    )
    return 0


def write_series(mesh, ws, out: Path, *, progress=None) -> list[dict]:
    """Slice ``mesh`` at each w of ``ws`` into ``out``: ``slice_NNNN.ply`` and ``.vtp`` per step
    and ``series.pvd`` (timestep = w). Every file is written atomically; returns per-step info."""
    from .._atomic import atomic_open
    from ..io.mesh_files import save_slice_mesh

    digits = max(4, len(str(len(ws) - 1)))
    steps = []
    keep = {f"slice_{k:0{digits}d}{suffix}" for k in range(len(ws)) for suffix in (".ply", ".vtp")}
    try:
        for k, w in enumerate(ws):
            tri = mesh.slice([0.0, 0.0, 0.0, float(w)], [0.0, 0.0, 0.0, 1.0])
            name = f"slice_{k:0{digits}d}"
            has_ao = "ao" in tri.vertex_attributes
            if len(tri.faces):
                save_slice_mesh(out / f"{name}.ply", tri, occlusion="ao" if has_ao else None)
            else:
                _empty_ply(out / f"{name}.ply")
            _save_vtp(out / f"{name}.vtp", tri)
            steps.append({"w": float(w), "ply": f"{name}.ply", "vtp": f"{name}.vtp", "triangles": int(len(tri.faces))})
            if progress is not None:
                progress.update()
    finally:
        if progress is not None:
            progress.close()
    lines = [
        '<?xml version="1.0"?>',
        '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
        "  <Collection>",
    ]
    lines += [f'    <DataSet timestep="{_timestep(s["w"])}" group="" part="0" file="{s["vtp"]}"/>' for s in steps]
    lines += ["  </Collection>", "</VTKFile>", ""]
    with atomic_open(out / SERIES_NAME, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    # slices of an earlier, longer series in this folder would be read as part of this one
    for stale in out.glob("slice_*"):
        if stale.is_file() and _SLICE_NAME.fullmatch(stale.name) and stale.name not in keep:
            stale.unlink()
    return steps


_SLICE_NAME = re.compile(r"slice_\d{4,}\.(ply|vtp)")


def _timestep(w: float) -> str:
    return repr(float(w)) if math.isfinite(w) else "0"


def _save_vtp(path: Path, tri) -> None:
    """The slice as VTK polydata with every 1-value-per-vertex attribute as point data."""
    from .._atomic import atomic_path
    from .._optional import require

    pv = require("pyvista", "writing .vtp slices")

    faces = np.asarray(tri.faces, dtype=np.int64)
    cells = np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces]).ravel()
    poly = pv.PolyData(np.asarray(tri.vertices, dtype=np.float64), faces=cells)
    for name, values in tri.vertex_attributes.items():
        values = np.asarray(values)
        if values.shape[:1] == (len(tri.vertices),) and values.ndim == 1:
            poly.point_data[name] = values.astype(np.float32)
    with atomic_path(path) as tmp:
        poly.save(tmp, binary=True)


def _empty_ply(path: Path) -> None:
    """A valid PLY with no vertices (a step where the hyperplane misses the mesh)."""
    from .._atomic import atomic_open

    with atomic_open(path, "w", encoding="ascii") as fh:
        fh.write(
            "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
            "property float z\nelement face 0\nproperty list uchar int vertex_indices\n"
            "end_header\n"
        )
