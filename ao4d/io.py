"""Files people open: 3D image volumes (MetaImage, VTK), PNG previews, and 3D slices of 4D meshes.

Volumes follow the grid convention of DESIGN.md: ``data[i, j, k]`` is the voxel at
``origin + spacing * (i, j, k)`` along x, y, z. In files this becomes

* MetaImage (``.mhd`` header + ``.raw`` data, written by hand per the ITK MetaIO spec):
  ``DimSize = nx ny nz``, ``ElementSpacing``/``Offset`` in x, y, z order, and the raw bytes in
  x-fastest (Fortran) order, little-endian. ITK, VTK, ParaView, 3D Slicer and Fiji therefore see
  voxel ``(i, j, k)`` at the same place as numpy does; the tests read our files back with VTK's
  own ``vtkMetaImageReader`` to prove it.
* VTK ImageData (``.vti``, written by pyvista/VTK), which can hold several named arrays
  (shade, depth, object id, AO) in one file.

Pictures are made without a display: matplotlib's Agg canvas for slice montages, and pyvista
off-screen for volume renderings (with a numpy front-to-back compositing fallback) and for 3D
slice meshes. Every write goes through :func:`ao4d._atomic.atomic_path`.

References
----------
MetaIO file format: https://itk.org/Wiki/ITK/MetaIO/Documentation
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ._atomic import atomic_open, atomic_path
from ._validate import as_array, check_choice, check_positive_int

__all__ = [
    "Volume",
    "write_mhd",
    "read_mhd",
    "write_vti",
    "read_vti",
    "write_volume",
    "read_volume",
    "save_montage",
    "save_volume_png",
    "composite",
    "save_slice_mesh",
    "save_slice_png",
    "ao_colors",
]

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


def _volume_array(data, name: str = "data") -> np.ndarray:
    arr = as_array(data, name, ndim=3, min_size=1)
    if arr.dtype == bool:
        arr = arr.astype(np.uint8)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"`{name}` must hold numbers, got dtype {arr.dtype}")
    return arr


def _triple(value, name: str, *, positive: bool) -> tuple[float, float, float]:
    arr = as_array(value, name, ndim=(0, 1), dtype=np.float64, finite=True)
    arr = np.broadcast_to(arr, (3,)) if arr.ndim == 0 or arr.shape == (1,) else arr
    if arr.shape != (3,):
        raise ValueError(f"`{name}` must be a scalar or 3 numbers (x, y, z), got shape {arr.shape}")
    if positive and (arr <= 0).any():
        raise ValueError(f"`{name}` must be positive, got {tuple(arr)}")
    return tuple(float(x) for x in arr)  # type: ignore[return-value]


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
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "v.mhd"
    >>> _ = write_mhd(p, np.arange(24, dtype=np.float32).reshape(2, 3, 4), spacing=0.5)
    >>> float(read_mhd(p).data[1, 2, 3])
    23.0
    """
    path = Path(path)
    if path.suffix.lower() != ".mhd":
        raise ValueError(f"`path` must end in .mhd, got {path.name!r}")
    arr = _volume_array(data)
    if arr.dtype not in _MET_TYPES:
        kinds = ", ".join(str(d) for d in _MET_TYPES)
        raise TypeError(f"`data` dtype {arr.dtype} has no MetaImage type; use one of {kinds}")
    spacing3 = _triple(spacing, "spacing", positive=True)
    origin3 = _triple(origin, "origin", positive=False)
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
    # data first: a reader never finds a new header pointing at an old or missing .raw
    with atomic_open(raw, "wb") as fh:
        fh.write(np.asfortranarray(little).tobytes(order="F"))  # x varies fastest
    with atomic_open(path, "w", encoding="ascii") as fh:
        fh.write(header)
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
    spacing = _triple(fields.get("ElementSpacing", "1 1 1").split(), "ElementSpacing", positive=True)
    origin = _triple(fields.get("Offset", "0 0 0").split(), "Offset", positive=False)
    return Volume(np.ascontiguousarray(data), spacing, origin, path.stem)


def _pyvista():
    """Import pyvista for off-screen use, silencing VTK's harmless missing-X-server warning."""
    import pyvista as pv
    import vtk

    pv.OFF_SCREEN = True
    # VTK logs "bad X server connection" as a WARN before falling back to off-screen rendering
    vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_ERROR)
    return pv


def write_vti(path: str | os.PathLike, arrays, *, spacing=1.0, origin=0.0) -> Path:
    """Write one or more 3D arrays on the same grid as VTK ImageData (``.vti``, via pyvista).

    Parameters
    ----------
    path : path-like
        Must end in ``.vti``.
    arrays : (nx, ny, nz) array_like or mapping of str to (nx, ny, nz) array_like
        Point data; a bare array is stored under the name ``"data"``. The first one is active.
    spacing, origin : float or (3,) array_like
        As in :func:`write_mhd`.

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.suffix.lower() != ".vti":
        raise ValueError(f"`path` must end in .vti, got {path.name!r}")
    named = dict(arrays) if isinstance(arrays, Mapping) else {"data": arrays}
    if not named:
        raise ValueError("`arrays` must hold at least one array")
    checked = {str(k): _volume_array(v, f"arrays[{k!r}]") for k, v in named.items()}
    shapes = {a.shape for a in checked.values()}
    if len(shapes) != 1:
        raise ValueError(f"`arrays` must all have the same shape, got {sorted(shapes)}")
    spacing3 = _triple(spacing, "spacing", positive=True)
    origin3 = _triple(origin, "origin", positive=False)
    pv = _pyvista()
    grid = pv.ImageData(dimensions=shapes.pop(), spacing=spacing3, origin=origin3)
    for name, arr in checked.items():
        grid.point_data[name] = arr.ravel(order="F")  # VTK point ids run x-fastest
    grid.set_active_scalars(next(iter(checked)))
    with atomic_path(path) as tmp:
        grid.save(tmp, binary=True)
    return path


def read_vti(path: str | os.PathLike, *, array: str | None = None) -> Volume:
    """Read one point-data array of a ``.vti`` file.

    Parameters
    ----------
    path : path-like
    array : str, optional
        Array name; default the active scalars (the first array :func:`write_vti` wrote).

    Returns
    -------
    Volume
    """
    pv = _pyvista()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    grid = pv.read(path)
    names = list(grid.point_data.keys())
    if not names:
        raise ValueError(f"{path.name}: holds no point-data arrays")
    name = array if array is not None else (grid.active_scalars_name or names[0])
    if name not in names:
        raise ValueError(f"`array` must be one of {', '.join(map(repr, names))}; got {name!r}")
    dims = tuple(int(n) for n in grid.dimensions)
    data = np.asarray(grid.point_data[name]).reshape(dims, order="F")
    return Volume(
        np.ascontiguousarray(data),
        tuple(float(s) for s in grid.spacing),  # type: ignore[arg-type]
        tuple(float(o) for o in grid.origin),  # type: ignore[arg-type]
        name,
    )


def write_volume(path: str | os.PathLike, data, *, spacing=1.0, origin=0.0) -> Path:
    """Write a 3D array as ``.mhd`` (+ ``.raw``) or ``.vti``, chosen by the file extension."""
    suffix = Path(path).suffix.lower()
    check_choice(suffix, "path extension", (".mhd", ".vti"))
    if suffix == ".mhd":
        return write_mhd(path, data, spacing=spacing, origin=origin)
    return write_vti(path, data, spacing=spacing, origin=origin)


def read_volume(path: str | os.PathLike, *, array: str | None = None) -> Volume:
    """Read a ``.mhd`` or ``.vti`` volume (``array`` picks a ``.vti`` array)."""
    suffix = Path(path).suffix.lower()
    check_choice(suffix, "path extension", (".mhd", ".vti"))
    return read_mhd(path) if suffix == ".mhd" else read_vti(path, array=array)


# ---------------------------------------------------------------------------------------------
# pictures


def _figure(width: float, height: float):
    """A matplotlib Figure on an Agg canvas: no display, no pyplot global state."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _save_figure(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=fig.dpi, facecolor=fig.get_facecolor())
    return path


def _png_path(path) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"`path` must end in .png, got {path.name!r}")
    return path


def _masked(data: np.ndarray, background) -> np.ma.MaskedArray:
    mask = ~np.isfinite(data)
    if background is not None:
        bg = as_array(background, "background", dtype=bool)
        if bg.shape != data.shape:
            raise ValueError(f"`background` must have shape {data.shape}, got {bg.shape}")
        mask |= bg
    return np.ma.masked_array(data, mask)


def _value_range(data: np.ma.MaskedArray, vmin, vmax) -> tuple[float, float]:
    valid = data.compressed()
    lo = float(valid.min()) if vmin is None and valid.size else (0.0 if vmin is None else vmin)
    hi = float(valid.max()) if vmax is None and valid.size else (1.0 if vmax is None else vmax)
    if hi <= lo:
        hi = lo + 1.0
    return lo, hi


def save_montage(
    path: str | os.PathLike,
    data,
    *,
    title: str = "",
    label: str = "",
    cmap: str = "gray",
    n_slices: int = 12,
    background=None,
    vmin: float | None = None,
    vmax: float | None = None,
    spacing=1.0,
    origin=0.0,
    columns: int = 4,
) -> Path:
    """Save a montage of z-slices of a 3D image with a colour bar and a title (PNG).

    Each panel shows ``data[:, :, k]`` with x to the right and y up, titled with its z
    coordinate. Background voxels (``background`` True, or non-finite values) are drawn in a
    neutral blue-grey so they stand apart from dark (fully occluded) surface voxels.

    Parameters
    ----------
    path : path-like
        Output ``.png``.
    data : (nx, ny, nz) array_like
    title : str
        Figure title (put the parameters here).
    label : str
        Colour-bar label.
    cmap : str
        Matplotlib colour map.
    n_slices : int
        Number of evenly spaced z-slices (at most nz).
    background : (nx, ny, nz) bool array_like, optional
        Voxels to draw as background.
    vmin, vmax : float, optional
        Colour range; default the range of the non-background values.
    spacing, origin : float or (3,) array_like
        Grid geometry, used for the slice titles and the axis extents.
    columns : int
        Panels per row.

    Returns
    -------
    Path
    """
    path = _png_path(path)
    arr = _masked(_volume_array(data).astype(np.float64), background)
    n_slices = min(check_positive_int(n_slices, "n_slices"), arr.shape[2])
    columns = check_positive_int(columns, "columns")
    spacing3 = _triple(spacing, "spacing", positive=True)
    origin3 = _triple(origin, "origin", positive=False)
    lo, hi = _value_range(arr, vmin, vmax)
    # slices through the occupied z range only: empty panels say nothing
    occupied = np.flatnonzero((~np.ma.getmaskarray(arr)).any(axis=(0, 1)))
    k0, k1 = (occupied[0], occupied[-1]) if occupied.size else (0, arr.shape[2] - 1)
    ks = np.unique(np.linspace(k0, k1, n_slices).round().astype(int))
    columns = min(columns, len(ks))
    rows = math.ceil(len(ks) / columns)
    import matplotlib

    colormap = matplotlib.colormaps[cmap].with_extremes(bad=(0.33, 0.38, 0.45))
    extent = [
        origin3[0] - spacing3[0] / 2,
        origin3[0] + spacing3[0] * (arr.shape[0] - 0.5),
        origin3[1] - spacing3[1] / 2,
        origin3[1] + spacing3[1] * (arr.shape[1] - 0.5),
    ]
    aspect = (extent[3] - extent[2]) / (extent[1] - extent[0])
    panel = 2.2
    fig = _figure(panel * columns + 1.2, panel * aspect * rows + 0.9)
    grid = fig.add_gridspec(rows, columns + 1, width_ratios=[1] * columns + [0.06],
                            left=0.04, right=0.9, top=1 - 0.55 / fig.get_figheight(),
                            bottom=0.03, wspace=0.08, hspace=0.25)
    image = None
    for n, k in enumerate(ks):
        ax = fig.add_subplot(grid[n // columns, n % columns])
        image = ax.imshow(arr[:, :, k].T, origin="lower", cmap=colormap, vmin=lo, vmax=hi,
                          extent=extent, interpolation="nearest")
        ax.set_title(f"z = {origin3[2] + spacing3[2] * k:.3g}", fontsize=8, pad=2)
        ax.set_xticks([])
        ax.set_yticks([])
    cax = fig.add_subplot(grid[:, -1])
    bar = fig.colorbar(image, cax=cax)
    bar.set_label(label, fontsize=9)
    bar.ax.tick_params(labelsize=8)
    fig.suptitle(title, fontsize=10)
    return _save_figure(fig, path)


def composite(
    data,
    *,
    background=None,
    cmap: str = "gray",
    vmin: float | None = None,
    vmax: float | None = None,
    opacity: float = 0.35,
    axis: int = 2,
) -> np.ndarray:
    """Numpy front-to-back emission-absorption compositing of a 3D image along one axis.

    Every non-background voxel has colour ``cmap(value)`` and opacity ``opacity``; layers are
    blended front to back (index 0 first) with ``C += (1 - A) a c``, ``A += (1 - A) a``.

    Parameters
    ----------
    data : (nx, ny, nz) array_like
    background : (nx, ny, nz) bool array_like, optional
        Transparent voxels (non-finite values are also transparent).
    cmap : str
    vmin, vmax : float, optional
    opacity : float
        Per-voxel opacity in (0, 1].
    axis : {0, 1, 2}
        Viewing axis.

    Returns
    -------
    rgba : (n_u, n_v, 4) float64
        Premultiplied colour and accumulated opacity of the two remaining axes (in order).
    """
    import matplotlib

    if not (0.0 < opacity <= 1.0):
        raise ValueError(f"`opacity` must be in (0, 1], got {opacity}")
    check_choice(axis, "axis", (0, 1, 2))
    arr = _masked(_volume_array(data).astype(np.float64), background)
    lo, hi = _value_range(arr, vmin, vmax)
    colours = matplotlib.colormaps[cmap]((arr.filled(lo) - lo) / (hi - lo))[..., :3]
    alpha = np.where(arr.mask, 0.0, opacity)
    colours = np.moveaxis(colours, axis, 0)
    alpha = np.moveaxis(alpha, axis, 0)
    out = np.zeros(alpha.shape[1:] + (4,))
    for layer_c, layer_a in zip(colours, alpha):
        weight = (1.0 - out[..., 3]) * layer_a
        out[..., :3] += weight[..., None] * layer_c
        out[..., 3] += weight
    return out


def save_volume_png(
    path: str | os.PathLike,
    data,
    *,
    title: str = "",
    label: str = "",
    cmap: str = "gray",
    background=None,
    vmin: float | None = None,
    vmax: float | None = None,
    spacing=1.0,
    origin=0.0,
    backend: Literal["auto", "pyvista", "numpy"] = "auto",
    size: tuple[int, int] = (720, 640),
) -> str:
    """Save a volume rendering of a 3D image, as ParaView would show it (PNG).

    Background voxels are fully transparent; surface voxels take their colour from ``cmap`` and
    are nearly opaque, so the 3D image reads as a solid object coloured by its values.

    Parameters
    ----------
    path : path-like
        Output ``.png``.
    data : (nx, ny, nz) array_like
    title, label, cmap, background, vmin, vmax, spacing, origin
        As in :func:`save_montage`.
    backend : {"auto", "pyvista", "numpy"}
        ``"pyvista"`` renders off-screen with VTK's ray-cast volume mapper; ``"numpy"``
        composites along z with :func:`composite`; ``"auto"`` tries pyvista first.
    size : (2,) tuple of int
        Picture size in pixels (pyvista).

    Returns
    -------
    str
        The backend that made the picture, ``"pyvista"`` or ``"numpy"``.
    """
    path = _png_path(path)
    check_choice(backend, "backend", ("auto", "pyvista", "numpy"))
    arr = _masked(_volume_array(data).astype(np.float64), background)
    spacing3 = _triple(spacing, "spacing", positive=True)
    origin3 = _triple(origin, "origin", positive=False)
    lo, hi = _value_range(arr, vmin, vmax)
    if backend in ("auto", "pyvista"):
        try:
            _volume_png_pyvista(path, arr, lo, hi, title=title, label=label, cmap=cmap,
                                spacing=spacing3, origin=origin3, size=size)
            return "pyvista"
        except Exception:  # no usable OpenGL context: fall back unless pyvista was demanded
            if backend == "pyvista":
                raise
    _volume_png_numpy(path, arr, lo, hi, title=title, label=label, cmap=cmap,
                      spacing=spacing3, origin=origin3)
    return "numpy"


def _volume_png_pyvista(path, arr, lo, hi, *, title, label, cmap, spacing, origin, size):
    pv = _pyvista()
    # Background gets a value below the colour range; the opacity table (linear over the
    # scalar range) makes that first bin transparent and everything else nearly opaque.
    # With 64 opacity entries spread over [floor, hi], entry 1 sits exactly at lo.
    span = hi - lo
    floor = lo - span / 62
    scalars = arr.filled(floor)
    grid = pv.ImageData(dimensions=arr.shape, spacing=spacing, origin=origin)
    grid.point_data[label or "value"] = scalars.ravel(order="F")
    opacity = np.full(64, 0.9)
    opacity[0] = 0.0  # the background value
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        plotter.set_background("white")
        actor = plotter.add_volume(
            grid, scalars=label or "value", cmap=cmap, clim=(floor, hi), opacity=opacity,
            shade=False, mapper="smart",
            scalar_bar_args={"title": label or "value", "color": "black", "vertical": True,
                             "position_x": 0.86, "position_y": 0.15, "height": 0.7,
                             "width": 0.07, "fmt": "%.2f"},
        )
        # nearest-voxel sampling: trilinear blending of surface voxels with the background
        # value would paint a dark fringe (low values) along every silhouette
        actor.prop.interpolation_type = "nearest"
        plotter.add_title(title, font_size=7, color="black")
        plotter.show_bounds(color="black", font_size=12, xtitle="x", ytitle="y", ztitle="z",
                            n_xlabels=3, n_ylabels=3, n_zlabels=3, fmt="%.1f",
                            location="outer", ticks="outside", minor_ticks=False)
        # from the front (+z), above (+y) and a little to the right: x right, y up on screen
        plotter.view_vector((0.45, 0.55, 1.0), viewup=(0.0, 1.0, 0.0))
        plotter.camera.zoom(0.85)
        with atomic_path(path) as tmp:
            plotter.screenshot(str(tmp))
    finally:
        plotter.close()


def _volume_png_numpy(path, arr, lo, hi, *, title, label, cmap, spacing, origin):
    import matplotlib

    rgba = composite(arr.data, background=arr.mask, cmap=cmap, vmin=lo, vmax=hi, axis=2)
    white = np.ones(3)
    picture = rgba[..., :3] + (1.0 - rgba[..., 3:]) * white  # over a white background
    extent = [origin[0] - spacing[0] / 2, origin[0] + spacing[0] * (arr.shape[0] - 0.5),
              origin[1] - spacing[1] / 2, origin[1] + spacing[1] * (arr.shape[1] - 0.5)]
    fig = _figure(6.4, 5.4)
    ax = fig.add_axes([0.08, 0.08, 0.72, 0.8])
    ax.imshow(np.swapaxes(np.clip(picture, 0, 1), 0, 1), origin="lower", extent=extent,
              interpolation="nearest")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"{title}\n(composited along z)", fontsize=9)
    cax = fig.add_axes([0.85, 0.15, 0.03, 0.66])
    mappable = matplotlib.cm.ScalarMappable(
        norm=matplotlib.colors.Normalize(lo, hi), cmap=matplotlib.colormaps[cmap])
    fig.colorbar(mappable, cax=cax).set_label(label, fontsize=9)
    _save_figure(fig, path)


# ---------------------------------------------------------------------------------------------
# slices (3D triangle meshes)


def ao_colors(occlusion, *, cmap: str = "magma") -> np.ndarray:
    """RGBA uint8 colours showing openness ``1 - occlusion`` (dark = occluded).

    Parameters
    ----------
    occlusion : (N,) array_like
        Values in [0, 1]; NaN becomes grey.

    Returns
    -------
    colors : (N, 4) uint8
    """
    import matplotlib

    occ = as_array(occlusion, "occlusion", ndim=1, dtype=np.float64)
    colours = matplotlib.colormaps[cmap].with_extremes(bad=(0.5, 0.5, 0.5))(
        np.ma.masked_invalid(1.0 - np.clip(occ, 0.0, 1.0)))
    return (np.asarray(colours) * 255).round().astype(np.uint8)


def _slice_scalars(tri, scalars, name: str) -> np.ndarray | None:
    if scalars is None:
        return None
    if isinstance(scalars, str):
        attrs = getattr(tri, "vertex_attributes", {})
        if scalars not in attrs:
            have = ", ".join(map(repr, attrs)) or "none"
            raise ValueError(f"`{name}` {scalars!r} is not a vertex attribute (have {have})")
        scalars = attrs[scalars]
    arr = as_array(scalars, name, ndim=1, dtype=np.float64)
    if arr.shape[0] != len(tri.vertices):
        raise ValueError(f"`{name}` must have one value per vertex ({len(tri.vertices)}), "
                         f"got {arr.shape[0]}")
    return arr


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

    Returns
    -------
    Path
    """
    path = Path(path)
    suffix = check_choice(path.suffix.lower(), "path extension", (".ply", ".glb"))
    occ = _slice_scalars(tri, occlusion, "occlusion")
    out = tri.copy()
    if occ is not None:
        out.visual.vertex_colors = ao_colors(occ, cmap=cmap)
        if suffix == ".ply":
            out.vertex_attributes = {"ao": occ.astype(np.float32)}
    with atomic_path(path) as tmp:
        out.export(tmp, file_type=suffix[1:])
    return path


def save_slice_png(
    path: str | os.PathLike,
    tri,
    *,
    occlusion=None,
    title: str = "",
    cmap: str = "magma",
    size: tuple[int, int] = (720, 640),
) -> Path:
    """Render a 3D slice mesh off-screen (pyvista), coloured by openness ``1 - occlusion``.

    Parameters
    ----------
    path : path-like
        Output ``.png``.
    tri : trimesh.Trimesh
    occlusion : (V,) array_like or str, optional
        As in :func:`save_slice_mesh`; without it the mesh is drawn in one colour.
    title : str
    cmap : str
    size : (2,) tuple of int

    Returns
    -------
    Path
    """
    path = _png_path(path)
    if len(tri.faces) == 0:
        raise ValueError("`tri` has no faces: the hyperplane misses the mesh")
    occ = _slice_scalars(tri, occlusion, "occlusion")
    pv = _pyvista()
    faces = np.hstack([np.full((len(tri.faces), 1), 3), tri.faces]).ravel()
    poly = pv.PolyData(np.asarray(tri.vertices, dtype=np.float64), faces)
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        plotter.set_background("white")
        if occ is None:
            plotter.add_mesh(poly, color="lightsteelblue", smooth_shading=True)
        else:
            poly.point_data["1 - AO"] = 1.0 - np.clip(occ, 0.0, 1.0)
            plotter.add_mesh(
                poly, scalars="1 - AO", cmap=cmap, clim=(0.0, 1.0), smooth_shading=True,
                scalar_bar_args={"title": "1 - AO", "color": "black", "vertical": True,
                                 "position_x": 0.86, "position_y": 0.15, "height": 0.7,
                                 "width": 0.07, "fmt": "%.1f"},
            )
        plotter.add_title(title, font_size=7, color="black")
        plotter.show_bounds(color="black", font_size=12, xtitle="x", ytitle="y", ztitle="z",
                            n_xlabels=3, n_ylabels=3, n_zlabels=3, fmt="%.1f",
                            location="outer", minor_ticks=False)
        plotter.view_vector((0.45, 0.55, 1.0), viewup=(0.0, 1.0, 0.0))
        plotter.camera.zoom(0.85)
        with atomic_path(path) as tmp:
            plotter.screenshot(str(tmp))
    finally:
        plotter.close()
    return path
