"""Simplex mesh files: the formats behind :meth:`SimplexMesh.save <ao4d.mesh.SimplexMesh.save>`
and :meth:`SimplexMesh.load <ao4d.mesh.SimplexMesh.load>`, and 3D slice-mesh export.

This module knows arrays, not the mesh class (``mesh`` imports it, never the reverse): writers
take a :class:`MeshArrays`, readers return one. :func:`write` and :func:`read` choose the format
by suffix. Three formats, every write atomic (an interrupted write leaves the old file or the
new one):

``.npz`` (suffix ``.npz``)
    Lossless: ``vertices``, ``simplices`` and every point/cell data array (stored under
    ``point_data/<name>`` and ``cell_data/<name>``), plus a format version and, when the
    writer gives it, ``field_data/<name>`` about the whole mesh (:func:`read_field_data`).
``.vtu`` (suffix ``.vtu``)
    For ParaView. Points need three coordinates: a 4D mesh writes x, y, z as the points, the
    fourth coordinate as point array ``"w"`` and its tetrahedra as ``VTK_TETRA``; a 3D mesh writes
    triangles (``VTK_TRIANGLE``), a 2D mesh line segments (``VTK_LINE``, z = 0). Point and cell
    data go along as arrays. Reading rebuilds the mesh (w from ``"w"``).
Plain text (any other suffix, e.g. ``.txt``)
    Human-readable geometry (no data arrays)::

        # ao4d simplex mesh (text format 1)     <- lines starting with '#' are comments
        ao4d-mesh 1
        dim 4
        vertices V
        x y z w                                  <- V lines, floats in shortest repr form
        simplices S
        i j k l                                  <- S lines, 0-based vertex indices

    Floats are written with ``repr`` precision, so a round trip is exact.

3D slices of 4D meshes (``trimesh.Trimesh``) are written by :func:`save_slice_mesh` as PLY, GLB,
OBJ or STL, coloured by AO.
"""

from __future__ import annotations

import os
import re
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .._atomic import atomic_open, atomic_path
from .._npz import npz_member_problem, write_npz
from .._optional import require
from .._validate import check_choice, regular_file
from .pictures import ao_colors, slice_scalars

__all__ = [
    "MeshArrays",
    "write",
    "read",
    "read_field_data",
    "to_pyvista",
    "save_slice_mesh",
    "SUFFIXES",
    "SLICE_SUFFIXES",
]

SUFFIXES = (".npz", ".vtu", ".txt")  # the formats SimplexMesh.save writes (text: any other suffix)
SLICE_SUFFIXES = (".ply", ".glb")  # 3D slice meshes (save_slice_mesh)

NPZ_FORMAT = 1
TEXT_FORMAT = 1
_TEXT_MAGIC = "ao4d-mesh"


class MeshArrays(NamedTuple):
    """What a mesh file holds: the arguments of :class:`ao4d.SimplexMesh`.

    Attributes
    ----------
    vertices : (V, d) numpy.ndarray
        The vertices.
    simplices : (S, d) numpy.ndarray
        The simplices, as vertex indices.
    point_data, cell_data : mapping of str to numpy.ndarray
        Arrays per vertex and per simplex.
    """

    vertices: np.ndarray
    simplices: np.ndarray
    point_data: Mapping[str, np.ndarray]
    cell_data: Mapping[str, np.ndarray]

    @property
    def dim(self) -> int:
        return int(self.vertices.shape[1])


# the fields' own docstrings (a named tuple's default is "Alias for field number k")
for _field, _doc in zip(
    MeshArrays._fields,
    (
        "The vertices, (V, d).",
        "The simplices, (S, d) vertex indices.",
        "Arrays per vertex, by name.",
        "Arrays per simplex, by name.",
    ),
):
    getattr(MeshArrays, _field).__doc__ = _doc


def _format(path: str | os.PathLike) -> str:
    suffix = Path(path).suffix.lower()
    return {".npz": "npz", ".vtu": "vtu"}.get(suffix, "text")


def write(path: str | os.PathLike, mesh: MeshArrays, *, field_data: Mapping[str, Any] | None = None) -> Path:
    """Write ``mesh`` in the format its suffix names (``.npz``, ``.vtu``, else text), atomically.

    ``field_data`` (``.npz`` only): small arrays or strings about the whole mesh (how it was
    made: the grid's spacing, the w scale), stored as ``field_data/<name>`` and read back by
    :func:`read_field_data`; other formats leave it out.

    Parameters
    ----------
    path : str or path-like
        The file.
    mesh : MeshArrays
        The mesh.
    field_data : mapping of str to array_like or str, optional
        Data about the whole mesh.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    if not isinstance(mesh, MeshArrays):
        raise TypeError(f"`mesh` must be a MeshArrays (see SimplexMesh.save), got {type(mesh).__name__}")
    if _format(path) == "npz":
        _save_npz(mesh, path, field_data or {})
    else:
        {"vtu": _save_vtu, "text": _save_text}[_format(path)](mesh, path)
    return Path(path)


def read_field_data(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The ``field_data`` a ``.npz`` mesh file holds (:func:`write`); empty for other formats.

    Parameters
    ----------
    path : str or path-like
        A mesh file (any format: only ``.npz`` files hold field data).

    Returns
    -------
    dict of str to numpy.ndarray
        The arrays by name.
    """
    if _format(path) != "npz":
        return {}
    p = _existing(path)
    try:
        with np.load(p, allow_pickle=False) as data:
            return {k.split("/", 1)[1]: data[k] for k in data.files if k.startswith("field_data/")}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        raise ValueError(f"`path` {str(p)!r} is not a readable .npz file ({npz_member_problem(exc)})") from None


def read(path: str | os.PathLike) -> MeshArrays:
    """Read a mesh file in the format its suffix names (``.npz``, ``.vtu``, else text).

    Parameters
    ----------
    path : str or path-like
        The file.

    Returns
    -------
    MeshArrays
        What the file holds.
    """
    reader = {"npz": _load_npz, "vtu": _load_vtu, "text": _load_text}[_format(path)]
    return reader(path)


def _existing(path: str | os.PathLike) -> Path:
    """``path`` once it is an existing regular file (a FIFO would block the reader)."""
    return regular_file(path, "path")


# ------------------------------------------------------------------------------------ npz
def _save_npz(mesh: MeshArrays, path: str | os.PathLike, field_data: Mapping[str, Any] | None = None) -> None:
    """Write a mesh with all its data to a compressed ``.npz`` file, atomically and reproducibly.

    Parameters
    ----------
    mesh : MeshArrays
        The mesh.
    path : path-like
        Destination; ``.npz`` is not appended automatically.
    """
    arrays = {
        "format": np.array(NPZ_FORMAT),
        "vertices": mesh.vertices,
        "simplices": mesh.simplices,
    }
    for kind in ("point_data", "cell_data"):
        for name, value in sorted(getattr(mesh, kind).items()):
            arr = np.asarray(value)
            if arr.dtype == object:
                raise TypeError(f"`mesh.{kind}[{name!r}]` has dtype object, which .npz cannot store safely")
            arrays[f"{kind}/{name}"] = arr
    for name, value in sorted((field_data or {}).items()):
        arr = np.asarray(value)
        if arr.dtype == object:
            raise TypeError(f"`field_data[{name!r}]` has dtype object, which .npz cannot store safely")
        arrays[f"field_data/{name}"] = arr
    write_npz(path, arrays)  # fixed zip dates: the same mesh always gives the same bytes


def _load_npz(path: str | os.PathLike) -> MeshArrays:
    """Read a mesh written by :func:`_save_npz`.

    Returns
    -------
    mesh : MeshArrays
    """
    p = _existing(path)
    if not zipfile.is_zipfile(p):
        what = "empty" if p.stat().st_size == 0 else "not a zip archive"
        raise ValueError(f"`path` {str(p)!r} is not a readable .npz file ({what})")
    try:
        with np.load(p, allow_pickle=False) as data:
            files = dict(data.items())
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        # truncated or bit-flipped archives fail here (CRC, inflate, short reads), and members
        # that are no .npy arrays (numpy then suggests allow_pickle=True: never)
        raise ValueError(f"`path` {str(p)!r} is not a readable .npz file ({npz_member_problem(exc)})") from None
    if "solid_format" in files:
        raise ValueError(
            f"`path` {str(p)!r} holds a SolidMesh (simplices filling a region): read it with ao4d.SolidMesh.load"
        )
    missing = {"format", "vertices", "simplices"} - set(files)
    if missing:
        raise ValueError(f"`path` {str(p)!r} is not an ao4d mesh file (missing {sorted(missing)})")
    try:
        version = int(files.pop("format"))
    except (TypeError, ValueError):
        raise ValueError(
            f"`path` {str(p)!r} is not an ao4d mesh file (its `format` entry is not a version number)"
        ) from None
    if version > NPZ_FORMAT:
        raise ValueError(f"`path` {str(p)!r} has mesh format {version}; this ao4d reads up to {NPZ_FORMAT}")
    point_data = {k.split("/", 1)[1]: v for k, v in files.items() if k.startswith("point_data/")}
    cell_data = {k.split("/", 1)[1]: v for k, v in files.items() if k.startswith("cell_data/")}
    return MeshArrays(files["vertices"], files["simplices"], point_data, cell_data)


# ------------------------------------------------------------------------------------ vtu
def _vtk_cell_type(dim: int) -> int:
    pv = require("pyvista", "VTK meshes (.vtu)")

    return {2: pv.CellType.LINE, 3: pv.CellType.TRIANGLE, 4: pv.CellType.TETRA}[dim]


def to_pyvista(mesh: MeshArrays):
    """The mesh as a ``pyvista.UnstructuredGrid`` (layout as in the module docstring).

    Parameters
    ----------
    mesh : MeshArrays
        The mesh.

    Returns
    -------
    pyvista.UnstructuredGrid
        The grid.
    """
    pv = require("pyvista", "writing .vtu meshes")
    points = np.zeros((len(mesh.vertices), 3))
    points[:, : min(3, mesh.dim)] = mesh.vertices[:, :3]
    grid = pv.UnstructuredGrid({_vtk_cell_type(mesh.dim): mesh.simplices}, points)
    if mesh.dim == 4:
        if "w" in mesh.point_data:
            raise ValueError("`mesh.point_data` must not use the name 'w': it holds the 4th coordinate in .vtu")
        grid.point_data["w"] = mesh.vertices[:, 3]
    for name, value in mesh.point_data.items():
        grid.point_data[name] = np.asarray(value)
    for name, value in mesh.cell_data.items():
        grid.cell_data[name] = np.asarray(value)
    return grid


def _save_vtu(mesh: MeshArrays, path: str | os.PathLike) -> None:
    """Write a VTK unstructured grid (``.vtu``, binary) for ParaView, atomically.

    Parameters
    ----------
    mesh : MeshArrays
        Any dimension (see the module docstring for the layout).
    path : path-like
        Destination ending in ``.vtu``.
    """
    if Path(path).suffix.lower() != ".vtu":
        raise ValueError(f"`path` must end in .vtu, got {str(path)!r}")
    grid = to_pyvista(mesh)
    with atomic_path(path) as tmp:
        grid.save(tmp, binary=True)


def _load_vtu(path: str | os.PathLike) -> MeshArrays:
    """Read a ``.vtu`` written by :func:`_save_vtu` (a tetrahedral grid with ``"w"`` is 4D).

    Returns
    -------
    mesh : MeshArrays
        Point and cell data arrays are restored (``"w"`` becomes the 4th coordinate).
    """
    pv = require("pyvista", "reading .vtu meshes")
    p = _existing(path)
    try:
        grid = pv.read(p)
        n_cells = grid.n_cells
    except Exception as exc:  # VTK raises assorted errors on foreign or damaged files
        raise ValueError(f"`path` {str(p)!r} is not a readable .vtu file ({exc})") from None
    if n_cells == 0 and grid.n_points == 0:
        raise ValueError(f"`path` {str(p)!r} is not a readable .vtu file (no points or cells)")
    kinds = {int(c) for c in np.unique(grid.celltypes)}
    known = {int(pv.CellType.TETRA): 4, int(pv.CellType.TRIANGLE): 3, int(pv.CellType.LINE): 2}
    if len(kinds) != 1 or next(iter(kinds)) not in known:
        raise ValueError(
            f"`path` {str(p)!r} must hold cells of one type (tetra, triangle or line), got {sorted(kinds)}"
        )
    cell_type = next(iter(kinds))
    d = known[cell_type]
    simplices = grid.cells_dict[cell_type]
    points = np.asarray(grid.points, dtype=np.float64)
    point_data = {k: np.asarray(v) for k, v in grid.point_data.items()}
    if d == 4:
        if "w" not in point_data:
            raise ValueError(f"`path` {str(p)!r} holds tetrahedra without a 'w' point array: not a 4D ao4d mesh")
        vertices = np.column_stack([points, point_data.pop("w")])
    else:
        vertices = points[:, :d]
    cell_data = {k: np.asarray(v) for k, v in grid.cell_data.items()}
    return MeshArrays(vertices, simplices, point_data, cell_data)


# ------------------------------------------------------------------------------------ text
def _save_text(mesh: MeshArrays, path: str | os.PathLike) -> None:
    """Write the plain-text format (geometry only; see the module docstring), atomically."""
    with atomic_open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(f"# ao4d simplex mesh (text format {TEXT_FORMAT}); '#' starts a comment\n")
        fh.write(f"{_TEXT_MAGIC} {TEXT_FORMAT}\ndim {mesh.dim}\nvertices {len(mesh.vertices)}\n")
        # repr() of a Python float is the shortest string that reads back to the same double
        fh.writelines(" ".join(map(repr, row)) + "\n" for row in mesh.vertices.tolist())
        fh.write(f"simplices {len(mesh.simplices)}\n")
        fh.writelines(" ".join(map(str, row)) + "\n" for row in mesh.simplices.tolist())


def _load_text(path: str | os.PathLike) -> MeshArrays:
    """Read the plain-text format written by :func:`_save_text`.

    Returns
    -------
    mesh : MeshArrays
    """
    p = _existing(path)
    try:
        with open(p, encoding="ascii") as fh:
            lines = [ln.split("#", 1)[0].strip() for ln in fh]
    except UnicodeDecodeError:
        raise ValueError(
            f"`path` {str(p)!r} is not an ao4d mesh file (binary data; mesh files are .npz, .vtu or ao4d text)"
        ) from None
    lines = [ln for ln in lines if ln]
    where = f"`path` {str(p)!r}"

    def header(index: int, word: str) -> int:
        if index >= len(lines):
            raise ValueError(f"{where}: file ends before the '{word}' line")
        m = re.fullmatch(rf"{word}\s+(\d+)", lines[index])
        if not m:
            raise ValueError(f"{where}: expected '{word} <count>', got {lines[index]!r}")
        return int(m.group(1))

    version = header(0, _TEXT_MAGIC)
    if version > TEXT_FORMAT:
        raise ValueError(f"{where} has text format {version}; this ao4d reads up to {TEXT_FORMAT}")
    dim = header(1, "dim")
    n_vertices = header(2, "vertices")
    vertex_lines = lines[3 : 3 + n_vertices]
    n_simplices = header(3 + n_vertices, "simplices")
    simplex_lines = lines[4 + n_vertices : 4 + n_vertices + n_simplices]
    if len(simplex_lines) != n_simplices or len(lines) != 4 + n_vertices + n_simplices:
        raise ValueError(
            f"{where}: expected {n_simplices} simplex lines after the header, file has {len(lines) - 4 - n_vertices}"
        )
    vertices = _parse_rows(vertex_lines, dim, float, where, "vertex")
    simplices = _parse_rows(simplex_lines, dim, int, where, "simplex")
    return MeshArrays(vertices, simplices, {}, {})


def _parse_rows(rows: list[str], width: int, kind: type, where: str, what: str) -> np.ndarray:
    out = np.empty((len(rows), width), dtype=np.float64 if kind is float else np.int64)
    for i, row in enumerate(rows):
        parts = row.split()
        if len(parts) != width:
            raise ValueError(f"{where}: {what} line {i} must have {width} numbers, got {row!r}")
        try:
            out[i] = [kind(x) for x in parts]
        except ValueError:
            raise ValueError(f"{where}: {what} line {i} is not {width} numbers: {row!r}") from None
    return out


# ------------------------------------------------------------------------------------ 3D slices
def save_slice_mesh(path: str | os.PathLike, tri, *, occlusion=None, cmap: str = "magma") -> Path:
    """Write a 3D slice mesh as ``.ply`` or ``.glb`` with per-vertex colours from occlusion.

    Parameters
    ----------
    path : path-like
        ``.ply`` (keeps the occlusion as a vertex property too) or ``.glb``.
    tri : trimesh.Trimesh
        A slice, e.g. from ``SimplexMesh.slice``.
    occlusion : (V,) array_like or str, optional
        Per-vertex occlusion in [0, 1], or the name of one of ``tri.vertex_attributes``.
        Colours show ``1 - occlusion`` with ``cmap``.
    cmap : str
        A matplotlib colour map.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    suffix = check_choice(path.suffix.lower(), "path extension", SLICE_SUFFIXES)
    occ = slice_scalars(tri, occlusion, "occlusion")
    out = _ply_safe(tri) if suffix == ".ply" else tri.copy()
    if occ is not None:
        out.visual.vertex_colors = ao_colors(occ, cmap=cmap)
        if suffix == ".ply":
            out.vertex_attributes = {"ao": occ.astype(np.float32)}
    with atomic_path(path) as tmp:
        out.export(tmp, file_type=suffix[1:])
    return path


def _ply_safe(tri):
    """``tri`` with 64-bit integer attributes (the source ``simplex`` of each triangle) stored
    as 32-bit: PLY has no 64-bit integer type, and VTK's PLY reader (ParaView's) crashes on the
    ``int64`` properties trimesh writes. Attributes that do not fit are left out."""
    out = tri.copy()
    for attrs in (out.face_attributes, out.vertex_attributes):
        for name in list(attrs):
            values = np.asarray(attrs[name])
            if values.dtype.kind in "iu" and values.dtype.itemsize > 4:
                if values.size and (values.min() < -(2**31) or values.max() >= 2**31):
                    del attrs[name]
                else:
                    attrs[name] = values.astype(np.int32)
    return out
