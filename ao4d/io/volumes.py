"""3D image volumes in files: MetaImage (``.mhd`` + ``.raw``) and VTK ImageData (``.vti``).

Volumes follow the grid convention of DESIGN.md: ``data[i, j, k]`` is the voxel at
``origin + spacing * (i, j, k)`` along x, y, z. In files this becomes

* MetaImage (``.mhd`` header + ``.raw`` data, written by hand per the ITK MetaIO spec):
  ``DimSize = nx ny nz``, ``ElementSpacing``/``Offset`` in x, y, z order, and the raw bytes in
  x-fastest (Fortran) order, little-endian. ITK, VTK, ParaView, 3D Slicer and Fiji therefore see
  voxel ``(i, j, k)`` at the same place as numpy does; the tests read our files back with VTK's
  own ``vtkMetaImageReader`` to prove it.
* VTK ImageData (``.vti``, VTK's XML format written by hand: one appended binary block, each
  array zlib-compressed once at level 1 in VTK's blocked layout), which can hold several
  named arrays (shade, depth, object id, AO) in one file; VTK's ``vtkXMLImageDataReader``
  reads it back in the tests.

Every write goes through :mod:`ao4d._atomic`; the ``.mhd`` header and its ``.raw`` are
written as one set (:func:`ao4d._atomic.all_or_nothing`).

References
----------
MetaIO file format: https://itk.org/Wiki/ITK/MetaIO/Documentation
VTK file formats (XML ImageData, appended data, compressed blocks):
https://docs.vtk.org/en/latest/design_documents/VTKFileFormats.html
"""

from __future__ import annotations

import math
import os
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import all_or_nothing, atomic_open
from .._optional import require
from .._validate import as_array, as_vector, check_choice

__all__ = [
    "Volume",
    "write_mhd",
    "read_mhd",
    "write_vti",
    "read_vti",
    "write_volume",
    "read_volume",
    "volume_array",
    "pyvista_offscreen",
    "check_mhd_path",
]


def _quoteattr(text: str) -> str:
    """``xml.sax.saxutils.quoteattr``'s quoted XML attribute value, the same characters (that
    module imports urllib and http: 40 ms of a first extraction's imports)."""
    for plain, entity in (
        ("&", "&amp;"),
        (">", "&gt;"),
        ("<", "&lt;"),
        ("\n", "&#10;"),
        ("\r", "&#13;"),
        ("\t", "&#9;"),
    ):
        text = text.replace(plain, entity)
    if '"' not in text:
        return f'"{text}"'
    if "'" not in text:
        return f"'{text}'"
    return '"' + text.replace('"', "&quot;") + '"'


# numpy dtype -> MetaImage ElementType (the types both ITK and VTK's reader understand)
_MET_TYPES = {
    np.dtype(np.int8): "MET_CHAR",
    np.dtype(np.uint8): "MET_UCHAR",
    np.dtype(np.int16): "MET_SHORT",
    np.dtype(np.uint16): "MET_USHORT",
    np.dtype(np.int32): "MET_INT",
    np.dtype(np.uint32): "MET_UINT",
    np.dtype(np.float32): "MET_FLOAT",
    np.dtype(np.float64): "MET_DOUBLE",
}
_MET_DTYPES = {v: k for k, v in _MET_TYPES.items()}


@dataclass(frozen=True)
class Volume:
    """A 3D image read from a file.

    Attributes
    ----------
    data : (nx, ny, nz) ndarray
        ``data[i, j, k]`` is the voxel at ``origin + spacing * (i, j, k)``.
    spacing : (3,) tuple of float
    origin : (3,) tuple of float
    name : str
        Array name (``.vti``) or the file stem (``.mhd``).
    """

    data: np.ndarray
    spacing: tuple[float, float, float]
    origin: tuple[float, float, float]
    name: str = ""


# ---------------------------------------------------------------------------------------------
# volumes


def volume_array(data, name: str = "data") -> np.ndarray:
    """``data`` as a 3D numeric array (booleans as uint8), else an error naming ``name``.

    Parameters
    ----------
    data : array_like
        The voxels.
    name : str
        The parameter named in the error.

    Returns
    -------
    (nx, ny, nz) numpy.ndarray
        The array.
    """
    arr = as_array(data, name, ndim=3, min_size=1)
    if arr.dtype == bool:
        arr = arr.astype(np.uint8)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"`{name}` must hold numbers, got dtype {arr.dtype}")
    return arr


def write_mhd(path: str | os.PathLike, data, *, spacing=1.0, origin=0.0) -> Path:
    """Write a 3D image as MetaImage: ``path`` (``.mhd`` header) and a ``.raw`` file beside it.

    Parameters
    ----------
    path : path-like
        Header file name; must end in ``.mhd``. The data go to the same name with ``.raw``.
    data : (nx, ny, nz) array_like
        int8/16/32, uint8/16/32, float32/64 or bool (stored as uint8). Index order x, y, z.
    spacing : float or (3,) array_like
        Voxel size along x, y, z.
    origin : float or (3,) array_like
        Position of voxel ``(0, 0, 0)``.

    Returns
    -------
    Path
        The header path.

    Examples
    --------
    >>> import pathlib, shutil, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "v.mhd"
    >>> _ = write_mhd(p, np.arange(24, dtype=np.float32).reshape(2, 3, 4), spacing=0.5)
    >>> float(read_mhd(p).data[1, 2, 3])
    23.0
    >>> shutil.rmtree(p.parent)
    """
    path = check_mhd_path(path)
    arr = volume_array(data)
    if arr.dtype not in _MET_TYPES:
        kinds = ", ".join(str(d) for d in _MET_TYPES)
        raise TypeError(f"`data` dtype {arr.dtype} has no MetaImage type; use one of {kinds}")
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    raw = path.with_suffix(".raw")
    little = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    fmt = lambda xs: " ".join(repr(float(x)) for x in xs)  # noqa: E731 - full precision
    header = "\n".join(
        [
            "ObjectType = Image",
            "NDims = 3",
            "BinaryData = True",
            "BinaryDataByteOrderMSB = False",
            "CompressedData = False",
            "TransformMatrix = 1 0 0 0 1 0 0 0 1",
            f"Offset = {fmt(origin3)}",
            "CenterOfRotation = 0 0 0",
            f"ElementSpacing = {fmt(spacing3)}",
            "DimSize = " + " ".join(str(n) for n in arr.shape),
            f"ElementType = {_MET_TYPES[arr.dtype]}",
            f"ElementDataFile = {raw.name}",  # must be the last field
            "",
        ]
    )
    # data first: a reader never finds a new header pointing at an old or missing .raw; as one
    # set, so a failing header puts the old .raw back
    with all_or_nothing([raw, path]):
        with atomic_open(raw, "wb") as fh:
            fh.write(np.asfortranarray(little).tobytes(order="F"))  # x varies fastest
        with atomic_open(path, "w", encoding="ascii") as fh:
            fh.write(header)
    return path


def check_mhd_path(path: str | os.PathLike, name: str = "path") -> Path:
    """``path`` as a Path if it can name a MetaImage header, else a ``ValueError`` naming ``name``.

    The header must end in ``.mhd``, and the data file it names (the same name with ``.raw``)
    must be ASCII: MetaIO headers are ASCII text, and ITK and VTK read the name as bytes. Checked
    before any work, so no file is written for a name the header cannot hold.

    Parameters
    ----------
    path : str or path-like
        The header's path.
    name : str
        The parameter named in the error.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    if path.suffix.lower() != ".mhd":
        raise ValueError(f"`{name}` must end in .mhd, got {path.name!r}")
    raw = path.with_suffix(".raw").name
    if not raw.isascii() or any(c in raw for c in "\r\n"):
        raise ValueError(
            f"`{name}` {path.name!r}: a MetaImage header names its data file in ASCII, "
            f"and {raw!r} is not; use an ASCII file name (or .vti)"
        )
    return path


def read_mhd(path: str | os.PathLike) -> Volume:
    """Read a 3D MetaImage written by :func:`write_mhd` (or any uncompressed 3D MetaImage).

    Parameters
    ----------
    path : path-like
        The ``.mhd`` header.

    Returns
    -------
    Volume
        ``data`` in x, y, z index order.
    """
    path = Path(path)
    fields: dict[str, str] = {}
    for line in path.read_text(encoding="ascii", errors="replace").splitlines():
        key, sep, value = line.partition("=")
        if sep:
            fields[key.strip()] = value.strip()
    missing = [k for k in ("NDims", "DimSize", "ElementType", "ElementDataFile") if k not in fields]
    if missing:
        raise ValueError(f"{path.name}: not a MetaImage header (missing {', '.join(missing)})")
    if fields.get("CompressedData", "False").lower() == "true":
        raise ValueError(f"{path.name}: compressed MetaImage data is not supported")
    if int(fields.get("ElementNumberOfChannels", "1")) != 1:
        raise ValueError(f"{path.name}: only single-channel images are supported")
    dims = tuple(int(x) for x in fields["DimSize"].split())
    if int(fields["NDims"]) != 3 or len(dims) != 3:
        raise ValueError(f"{path.name}: expected a 3D image, got NDims = {fields['NDims']}")
    try:
        dtype = _MET_DTYPES[fields["ElementType"]]
    except KeyError:
        raise ValueError(f"{path.name}: unsupported ElementType {fields['ElementType']}") from None
    msb = fields.get("BinaryDataByteOrderMSB", fields.get("ElementByteOrderMSB", "False"))
    dtype = dtype.newbyteorder(">" if msb.lower() == "true" else "<")
    if "TransformMatrix" in fields:
        matrix = np.array(fields["TransformMatrix"].split(), dtype=float)
        if not np.allclose(matrix, np.eye(3).ravel()):
            raise ValueError(f"{path.name}: rotated images (TransformMatrix) are not supported")
    raw = path.parent / fields["ElementDataFile"]
    count = math.prod(dims)
    flat = np.fromfile(raw, dtype=dtype, count=count)
    if flat.size != count:
        raise ValueError(f"{raw.name}: expected {count} values, file holds {flat.size}")
    data = flat.reshape(dims, order="F").astype(dtype.newbyteorder("="))
    spacing = tuple(as_vector(fields.get("ElementSpacing", "1 1 1").split(), "ElementSpacing", 3, positive=True))
    origin = tuple(as_vector(fields.get("Offset", "0 0 0").split(), "Offset", 3))
    return Volume(np.ascontiguousarray(data), spacing, origin, path.stem)


def pyvista_offscreen(what: str = "backend='pyvista'"):
    """Import pyvista for off-screen use, silencing VTK's harmless missing-X-server warning.

    Parameters
    ----------
    what : str, optional
        The feature that needs pyvista, named when it is not installed (``ao4d[vtk]``).

    Returns
    -------
    module
        ``pyvista``.
    """
    pv = require("pyvista", what)
    import vtk

    pv.OFF_SCREEN = True
    # VTK logs "bad X server connection" as a WARN before falling back to off-screen rendering
    vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_ERROR)
    return pv


def read_vtk_image(path: str | os.PathLike, name: str = "path") -> Any:
    """pyvista's ImageData of a ``.vti`` file, checked whole: every point-data array holds one
    value (or tuple) per grid point.

    Parameters
    ----------
    path : path-like
        An existing ``.vti`` file.
    name : str
        The parameter named in messages.

    Raises
    ------
    ValueError
        VTK cannot read the file (not VTK XML, truncated, damaged), or it holds no point-data
        arrays, or an array is shorter than the grid: the message says the file is unreadable
        or truncated (VTK reports such files as an empty grid, not as an error).
    """
    import warnings

    pv = pyvista_offscreen("reading .vti images")
    import vtk

    path = Path(path)
    shown = vtk.vtkObject.GetGlobalWarningDisplay()
    vtk.vtkObject.GlobalWarningDisplayOff()  # VTK's own error lines; the message below says it
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                grid = pv.read(path)
            except Exception as exc:  # pyvista raises for some damage, returns empty for other
                grid, caught = None, [*caught, warnings.WarningMessage(str(exc), UserWarning, "", 0)]
    finally:
        vtk.vtkObject.SetGlobalWarningDisplay(shown)
    why = None
    if grid is None or caught:
        why = " ".join(" ".join(str(m.message) for m in caught).split())[:300] if caught else "VTK read nothing"
    elif not list(grid.point_data.keys()):
        why = "VTK read no point-data arrays (it reads a damaged or cut-short file as an empty grid)"
    else:
        points = int(np.prod([int(n) for n in grid.dimensions]))
        short = [k for k in grid.point_data.keys() if len(np.asarray(grid.point_data[k])) != points]
        if points == 0 or short:
            why = f"arrays {short} do not hold one value per grid point" if short else "an empty grid"
    if why is not None:
        raise ValueError(f"`{name}` {str(path)!r} is unreadable or truncated as VTK ImageData (.vti): {why}")
    return grid


def write_vti(path: str | os.PathLike, arrays, *, spacing=1.0, origin=0.0) -> Path:
    """Write one or more 3D arrays on the same grid as VTK ImageData (``.vti``).

    VTK's XML format with the arrays appended in binary, each compressed once with zlib at
    level 1 (VTK's blocked layout, so VTK, ParaView and pyvista read it); no VTK import.

    Parameters
    ----------
    path : path-like
        Must end in ``.vti``.
    arrays : (nx, ny, nz) array_like or mapping of str to (nx, ny, nz) array_like
        Point data; a bare array is stored under the name ``"data"``. The first one is active.
        An (nx, ny, nz, c) array (c <= 4) is stored with c components (e.g. uint8 RGBA).
    spacing, origin : float or (3,) array_like
        As in :func:`write_mhd`.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import pathlib, shutil, tempfile
    >>> p = write_vti(pathlib.Path(tempfile.mkdtemp()) / "v.vti", {"a": np.ones((2, 3, 4))})
    >>> read_vti(p).data.shape
    (2, 3, 4)
    >>> shutil.rmtree(p.parent)
    """
    path = Path(path)
    if path.suffix.lower() != ".vti":
        raise ValueError(f"`path` must end in .vti, got {path.name!r}")
    named = dict(arrays) if isinstance(arrays, Mapping) else {"data": arrays}
    if not named:
        raise ValueError("`arrays` must hold at least one array")
    checked = {str(k): _components(v, f"arrays[{k!r}]") for k, v in named.items()}
    shapes = {a.shape[:3] for a in checked.values()}
    if len(shapes) != 1:
        raise ValueError(f"`arrays` must all have the same shape, got {sorted(shapes)}")
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    shape = shapes.pop()
    extent = " ".join(f"0 {n - 1}" for n in shape)
    fmt = lambda xs: " ".join(repr(float(x)) for x in xs)  # noqa: E731 - full precision
    entries, blocks, offset = [], [], 0
    for name, arr in checked.items():
        vtk_type = _VTK_TYPES.get(arr.dtype)
        if vtk_type is None:
            raise TypeError(f"`arrays[{name!r}]` dtype {arr.dtype} has no VTK type")
        components = arr.shape[3] if arr.ndim == 4 else 1
        block = _vtk_compressed(_vtk_point_bytes(arr))
        entries.append(
            f'        <DataArray type="{vtk_type}" Name={_quoteattr(name)} '
            f'NumberOfComponents="{components}" format="appended" offset="{offset}"/>'
        )
        blocks.append(block)
        offset += len(block)
    head = "\n".join(
        [
            '<?xml version="1.0"?>',
            '<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian" header_type="UInt64" '
            'compressor="vtkZLibDataCompressor">',
            f'  <ImageData WholeExtent="{extent}" Origin="{fmt(origin3)}" Spacing="{fmt(spacing3)}" '
            'Direction="1 0 0 0 1 0 0 0 1">',
            f'    <Piece Extent="{extent}">',
            f"      <PointData Scalars={_quoteattr(next(iter(checked)))}>",
            *entries,
            "      </PointData>",
            "      <CellData>",
            "      </CellData>",
            "    </Piece>",
            "  </ImageData>",
            '  <AppendedData encoding="raw">',
            "   _",
        ]
    ).encode("utf-8")
    with atomic_open(path, "wb") as fh:
        fh.write(head)
        for block in blocks:
            fh.write(block)
        fh.write(b"\n  </AppendedData>\n</VTKFile>\n")
    return path


# numpy dtype -> VTK XML type name
_VTK_TYPES = {
    np.dtype(t): n
    for t, n in [
        (np.int8, "Int8"),
        (np.uint8, "UInt8"),
        (np.int16, "Int16"),
        (np.uint16, "UInt16"),
        (np.int32, "Int32"),
        (np.uint32, "UInt32"),
        (np.int64, "Int64"),
        (np.uint64, "UInt64"),
        (np.float32, "Float32"),
        (np.float64, "Float64"),
    ]
}
_VTK_BLOCK = 1 << 20  # uncompressed bytes per compressed block


def _vtk_point_bytes(arr: np.ndarray) -> bytes:
    """Little-endian bytes in VTK's point order: x fastest, a point's components together."""
    little = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    return np.ascontiguousarray(little.transpose(2, 1, 0, *range(3, arr.ndim))).tobytes()


def _vtk_compressed(raw: bytes) -> bytes:
    """VTK's compressed-array layout: a UInt64 header (blocks, block size, size of a partial
    last block or 0, each block's compressed size), then the zlib blocks (level 1)."""
    view = memoryview(raw)
    chunks = [zlib.compress(view[i : i + _VTK_BLOCK], 1) for i in range(0, len(raw), _VTK_BLOCK)]
    header = np.array([len(chunks), _VTK_BLOCK, len(raw) % _VTK_BLOCK] + [len(c) for c in chunks], dtype="<u8")
    return header.tobytes() + b"".join(chunks)


def _components(data, name: str) -> np.ndarray:
    """A 3D array, or a 4D one whose last axis holds up to 4 components per voxel."""
    arr = np.asarray(data)
    if arr.ndim == 4 and 1 <= arr.shape[3] <= 4:
        return np.stack([volume_array(arr[..., c], name) for c in range(arr.shape[3])], axis=-1)
    return volume_array(data, name)


def read_vti(path: str | os.PathLike, *, array: str | None = None) -> Volume:
    """Read one point-data array of a ``.vti`` file.

    Parameters
    ----------
    path : path-like
        The ``.vti`` file.
    array : str, optional
        Array name; default the active scalars (the first array :func:`write_vti` wrote).

    Returns
    -------
    Volume
        The array with its grid.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    grid = read_vtk_image(path)
    names = list(grid.point_data.keys())
    name = array if array is not None else (grid.active_scalars_name or names[0])
    if name not in names:
        raise ValueError(f"`array` must be one of {', '.join(map(repr, names))}; got {name!r}")
    dims = tuple(int(n) for n in grid.dimensions)
    flat = np.asarray(grid.point_data[name])
    data = flat.reshape(dims + flat.shape[1:], order="F")  # (nx, ny, nz[, components])
    return Volume(
        np.ascontiguousarray(data),
        tuple(float(s) for s in grid.spacing),  # type: ignore[arg-type]
        tuple(float(o) for o in grid.origin),  # type: ignore[arg-type]
        name,
    )


def write_volume(path: str | os.PathLike, data, *, spacing=1.0, origin=0.0) -> Path:
    """Write a 3D array as ``.mhd`` (+ ``.raw``) or ``.vti``, chosen by the file extension.

    Parameters
    ----------
    path : str or path-like
        The file, ending in ``.mhd`` or ``.vti``.
    data : (nx, ny, nz) array_like
        The voxels.
    spacing, origin : float or (3,) array_like
        Voxel size and the position of voxel (0, 0, 0).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    suffix = Path(path).suffix.lower()
    check_choice(suffix, "path extension", (".mhd", ".vti"))
    if suffix == ".mhd":
        return write_mhd(path, data, spacing=spacing, origin=origin)
    return write_vti(path, data, spacing=spacing, origin=origin)


def read_volume(path: str | os.PathLike, *, array: str | None = None) -> Volume:
    """Read a ``.mhd`` or ``.vti`` volume.

    Parameters
    ----------
    path : str or path-like
        The file.
    array : str, optional
        The ``.vti`` array to read; default the active one.

    Returns
    -------
    Volume
        The array with its grid.
    """
    suffix = Path(path).suffix.lower()
    check_choice(suffix, "path extension", (".mhd", ".vti"))
    return read_mhd(path) if suffix == ".mhd" else read_vti(path, array=array)
