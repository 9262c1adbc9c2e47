"""``ao4d extract``: a closed tetrahedral mesh from a named 4D shape or a data file."""

from __future__ import annotations

import argparse
import time
from typing import Any

from ._options import add_force, add_pair

HELP = "extract a closed, oriented simplex mesh from a named shape or a 2D/3D/4D data file"
EXAMPLES = """  ao4d extract --shape spheritorus --grid 48 --out torus.npz
  ao4d extract --shape tiger --grid 64 --method simplices --out tiger.npz --vtu tiger.vtu
  ao4d extract --shape hypersphere --grid 32 --bounds -1.5 1.5 --out ball.npz
  ao4d extract --input ct.npy --level 300 --inside above --spacing 0.5 --out bone.npz
  ao4d extract --input fmri.nii.gz --level 0.5 --inside above --out blob.npz
  ao4d extract --input sim.h5:/fields/density --level 1 --out shock.npz
  ao4d extract --input 'frames_*.vti' --spacing 1 1 1 0.1 --out series.npz
inputs: .npy (memory-mapped), .nii/.nii.gz, .zarr[:/array], file.h5:/dataset, .mhd/.mha,
  or a quoted glob of 3D frames (.vti, .mhd, .npy, .nii.gz) stacked along w in natural order;
  spacing and origin come from the file where it has them (--spacing/--origin override)
shapes: hypersphere, spheritorus, torisphere, ditorus, tiger, duocylinder, tesseract,
  indented_cube, metaballs, gyroid (default parameters; see ao4d.fields for your own)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..fields import PRESETS
    from ..marching.march import METHODS

    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--shape", choices=sorted(PRESETS), help="a named 4D shape")
    src.add_argument("--input", metavar="FILE", help="a 2D/3D/4D data file or a glob of 3D frames (see inputs below)")
    parser.add_argument("--out", required=True, metavar="MESH.npz", help="output mesh (.npz)")
    parser.add_argument("--vtu", metavar="MESH.vtu", help="also write a VTK unstructured grid")
    parser.add_argument("--grid", type=int, default=48, help="points per axis for --shape (48)")
    add_pair(
        parser, "--bounds", metavar=("LO", "HI"), help="grid box for --shape (default: the shape's extent plus 10%%)"
    )
    parser.add_argument("--level", type=float, default=0.0, help="iso-value (0)")
    parser.add_argument("--method", choices=METHODS, default="cubes", help="cell split (cubes)")
    parser.add_argument(
        "--inside",
        choices=("below", "above"),
        default="below",
        help="solid is f < level (below, signed distances) or f > level (above, CT data)",
    )
    parser.add_argument(
        "--spacing",
        type=_step,
        nargs="+",
        metavar="STEP",
        help="grid step(s) for --input, one or one per axis; 'file' keeps the "
        "file's step on that axis (default: from the file, else 1)",
    )
    parser.add_argument(
        "--origin", type=float, nargs="+", help="grid origin for --input (default: from the file, else 0)"
    )
    parser.add_argument(
        "--w-scale",
        type=float,
        metavar="LENGTH_PER_TIME",
        help="length units per time unit for the time axis of a 4D NIfTI (e.g. "
        "0.001 mm per ms); by default one frame is one mean x/y/z step",
    )
    parser.add_argument(
        "--affine",
        action="store_true",
        help="place the vertices by the file's affine (NIfTI scanner coordinates, oblique axes included)",
    )
    parser.add_argument(
        "--closed",
        action="store_true",
        help="close the mesh where the solid touches the grid's edge (the grid padded by one outside cell)",
    )
    parser.add_argument("--dim", type=int, choices=(2, 3, 4), help="refuse --input files of another dimension")
    parser.add_argument("--chunk", type=int, help="cell layers per slab (default: ~100 MB slabs)")
    parser.add_argument("--no-check", action="store_true", help="skip the closedness check")
    add_force(parser, help="extract even when the estimate is above the ten-minute limit")


def _step(text: str) -> float | None:
    """One --spacing entry: a number, or 'file' (keep the file's step on that axis)."""
    if text.lower() == "file":
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid step {text!r}: a number or 'file'") from None


def _one_or_many(values: list[float] | None):
    if values is None:
        return None
    return values[0] if len(values) == 1 else values


# the library's parameters that options become under another name (errors name the option)
PARAMETERS = {"shape": "--grid", "values": "--input", "path": "--input", "field": "--shape"}

_INPUT_ONLY = ("spacing", "origin", "w_scale", "affine", "dim")
_SHAPE_ONLY = ("grid", "bounds")


# Typical rate here (cells/s: sampling a field and marching, 2 cores), for the estimate printed
# before long work, and the largest grid extracted without --force (about ten minutes at that rate).
CELLS_PER_SECOND = 1e7
MAX_CELLS = 600 * CELLS_PER_SECOND


def _estimate(n_cells: float, force: bool) -> None:
    from .._budget import duration

    seconds = n_cells / CELLS_PER_SECOND
    if n_cells >= 1e8:
        print(f"{n_cells:.3g} cells: {duration(seconds)} at ~{CELLS_PER_SECOND:.0e} cells/s", flush=True)
    if n_cells > MAX_CELLS and not force:
        raise ValueError(
            f"{n_cells:.3g} cells would take {duration(seconds)}, above the limit of "
            f"{MAX_CELLS:.3g} cells; use a smaller --grid or pass --force"
        )


def run(args: argparse.Namespace) -> int:
    import warnings

    from .._atomic import all_or_nothing, check_output_file
    from ..io.mesh_files import SUFFIXES, MeshArrays, write
    from ..marching.march import EmptyMeshWarning

    _check_options(args)
    outputs = [check_output_file(args.out, "--out", SUFFIXES)]  # before any work
    if args.vtu:
        outputs.append(check_output_file(args.vtu, "--vtu", (".vtu",)))
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", EmptyMeshWarning)
        if args.shape is not None:
            mesh, what, info, field = _from_shape(args)
        else:
            mesh, what, info, field = _from_input(args)
    for w in seen:
        if issubclass(w.category, EmptyMeshWarning):  # nothing to write: say why, exit 2
            raise ValueError(str(w.message))
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    elapsed = time.perf_counter() - start
    print(f"extracted {what} ({args.method}) in {elapsed:.2f} s")
    if not args.no_check:
        print(mesh.check())
    print(f"enclosed {mesh.dim}-volume:  {mesh.volume:.6g}" + _error(mesh.volume, field, "volume"))
    area_error = _error(mesh.measure, field, "boundary_measure")
    print(f"boundary {mesh.dim - 1}-volume:  {mesh.measure:.6g}" + area_error)
    info["level"] = float(args.level)
    info["closed"] = bool(args.closed)
    with all_or_nothing(outputs):
        write(
            args.out,
            MeshArrays(mesh.vertices, mesh.simplices, dict(mesh.point_data), dict(mesh.cell_data)),
            field_data=info,
        )
        if args.vtu:
            mesh.to_vtu(args.vtu)
    print("wrote " + ", ".join(map(str, outputs)))
    return 0


def _from_shape(args: argparse.Namespace) -> tuple[Any, str, dict, Any]:
    """(mesh, what was extracted, what the mesh file records, the field) for ``--shape``."""
    from ..fields import preset
    from ..marching.march import extract, extract_field

    field = preset(args.shape)
    _estimate(float(args.grid - 1) ** field.dim, args.force)
    if args.bounds is not None:
        bounds = tuple(args.bounds)
    else:
        lo, hi = field.extent
        pad = 0.1 * (hi - lo)
        bounds = (lo - pad, hi + pad)
    if args.closed:  # the padding works on values: sample the field, then extract
        from ..fields import sample

        mesh = extract(
            sample(field, args.grid, bounds),
            args.level,
            method=args.method,
            inside=args.inside,
            chunk=args.chunk,
            closed=True,
            spacing=(bounds[1] - bounds[0]) / (args.grid - 1),
            origin=bounds[0],
        )
    else:
        mesh = extract_field(
            field, args.grid, bounds, args.level, method=args.method, inside=args.inside, chunk=args.chunk
        )
    what = f"{field.name} on a {args.grid}^{field.dim} grid"
    return mesh, what, {"source": f"--shape {args.shape}"}, field


def _from_input(args: argparse.Namespace) -> tuple[Any, str, dict, None]:
    """(mesh, what was extracted, what the mesh file records, no field) for ``--input``."""
    import math

    import numpy as np

    from ..io.grids import read_grid
    from ..marching.march import extract

    grid = read_grid(
        args.input,
        spacing=_one_or_many(args.spacing),
        origin=_one_or_many(args.origin),
        ndim=args.dim,
        w_scale=args.w_scale,
        keep_affine=args.affine,
    )
    print(
        f"read {grid.source}: shape {grid.shape}, {grid.values.dtype}"
        f"{' (lazy, block by block)' if grid.lazy else ''}; spacing "
        f"{np.round(grid.spacing, 6).tolist()}, origin {np.round(grid.origin, 6).tolist()}"
        + (f" ({'; '.join(grid.notes)})" if grid.notes else "")
    )
    _estimate(float(math.prod(n - 1 for n in grid.shape)), args.force)
    if grid.w_scale is not None:
        print(
            f"w scale: {grid.w_scale:.6g} length units per {grid.units[3]} "
            f"(w step {grid.spacing[3]:.6g}; recorded in the mesh file)"
        )
    place = {"affine": grid.affine} if grid.affine is not None else {"spacing": grid.spacing, "origin": grid.origin}
    mesh = extract(
        grid.values,
        args.level,
        method=args.method,
        inside=args.inside,
        chunk=args.chunk,
        closed=args.closed,
        **place,
    )
    what = f"{args.input} {grid.shape} at level {args.level:g}"
    return mesh, what, _grid_info(grid), None


def _check_options(args: argparse.Namespace) -> None:
    """Refuse options that the chosen source would ignore, and bounds that are no box."""
    import math

    defaults = {
        "grid": 48,
        "bounds": None,
        "spacing": None,
        "origin": None,
        "w_scale": None,
        "affine": False,
        "dim": None,
    }
    unused = _INPUT_ONLY if args.shape is not None else _SHAPE_ONLY
    given = [name for name in unused if getattr(args, name) != defaults[name]]
    if given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        source, other = ("--shape", "--input") if args.shape is not None else ("--input", "--shape")
        raise ValueError(f"{flags} {'applies' if len(given) == 1 else 'apply'} to {other} only, not to {source}")
    if args.w_scale is not None and not args.w_scale > 0:
        raise ValueError(f"`--w-scale` must be > 0, got {args.w_scale}")
    if args.bounds is not None:
        lo, hi = args.bounds
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"`--bounds` must be two finite numbers LO < HI, got {lo!r} {hi!r}")


def _grid_info(grid) -> dict:
    """What the mesh file records about the grid: where it came from and how it was scaled."""
    import numpy as np

    info = {
        "source": grid.source,
        "spacing": np.asarray(grid.spacing),
        "origin": np.asarray(grid.origin),
        "notes": np.array(list(grid.notes) or [""]),
    }
    if grid.units:
        info["units"] = np.array(list(grid.units))
    if grid.w_scale is not None:
        info["w_scale"] = np.float64(grid.w_scale)
    if grid.affine is not None:
        info["affine"] = np.asarray(grid.affine)
    return info


def _error(value: float, field, attr: str) -> str:
    exact = getattr(field, attr, None)
    if exact is None:
        return ""
    return f"  (analytic {exact:.6g}, error {100 * (value / exact - 1):+.3f} %)"
