"""Pictures made without a display: slice montages, volume renderings and 3D slice meshes (PNG).

matplotlib's Agg canvas draws the montages; pyvista off-screen draws volume renderings (with a
numpy front-to-back compositing fallback, :func:`composite`) and 3D slices of 4D meshes,
coloured by openness ``1 - AO`` (:func:`ao_colors`). Every write is atomic.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Literal

import numpy as np

from ._atomic import atomic_path
from ._validate import as_array, as_vector, check_choice, check_positive_int
from .volumes import pyvista_offscreen, volume_array

__all__ = ["save_montage", "save_volume_png", "composite", "save_slice_png", "ao_colors", "slice_scalars",
           "rgba_array", "over_background", "save_rgba_montage", "composite_rgba", "save_rgba_volume_png"]

# ---------------------------------------------------------------------------------------------
# pictures


def figure(width: float, height: float):
    """A matplotlib Figure on an Agg canvas: no display, no pyplot global state."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: Path) -> Path:
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


def _xy_extent(shape, spacing, origin) -> list[float]:
    """imshow's extent of an (x, y, ...) voxel array: voxel centres at origin + spacing * i."""
    return [origin[0] - spacing[0] / 2, origin[0] + spacing[0] * (shape[0] - 0.5),
            origin[1] - spacing[1] / 2, origin[1] + spacing[1] * (shape[1] - 0.5)]


def _montage(occupied: np.ndarray, n_slices: int, columns: int, extent, z0: float, dz: float,
             *, colorbar: bool):
    """A figure of ``n_slices`` z-slice panels through the occupied z range only (empty panels
    say nothing), with a narrow last column for a colour bar if asked: (figure, grid spec,
    [(axes, z index)]); each panel is titled with its z and has no ticks."""
    z = np.flatnonzero(occupied)
    k0, k1 = (z[0], z[-1]) if z.size else (0, len(occupied) - 1)
    ks = np.unique(np.linspace(k0, k1, n_slices).round().astype(int))
    columns = min(columns, len(ks))
    rows = math.ceil(len(ks) / columns)
    aspect = (extent[3] - extent[2]) / (extent[1] - extent[0])
    panel = 2.2
    fig = figure(panel * columns + (1.2 if colorbar else 0.4), panel * aspect * rows + 0.9)
    top = 1 - 0.55 / fig.get_figheight()
    if colorbar:
        grid = fig.add_gridspec(rows, columns + 1, width_ratios=[1] * columns + [0.06], left=0.04,
                                right=0.9, top=top, bottom=0.03, wspace=0.08, hspace=0.25)
    else:
        grid = fig.add_gridspec(rows, columns, left=0.03, right=0.97, top=top, bottom=0.03,
                                wspace=0.08, hspace=0.25)
    panels = []
    for n, k in enumerate(ks):
        ax = fig.add_subplot(grid[n // columns, n % columns])
        ax.set_title(f"z = {z0 + dz * k:.3g}", fontsize=8, pad=2)
        ax.set_xticks([])
        ax.set_yticks([])
        panels.append((ax, k))
    return fig, grid, panels


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
    arr = _masked(volume_array(data).astype(np.float64), background)
    n_slices = min(check_positive_int(n_slices, "n_slices"), arr.shape[2])
    columns = check_positive_int(columns, "columns")
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    lo, hi = _value_range(arr, vmin, vmax)
    import matplotlib

    colormap = matplotlib.colormaps[cmap].with_extremes(bad=(0.33, 0.38, 0.45))
    extent = _xy_extent(arr.shape, spacing3, origin3)
    occupied = (~np.ma.getmaskarray(arr)).any(axis=(0, 1))
    fig, grid, panels = _montage(occupied, n_slices, columns, extent, origin3[2], spacing3[2],
                                 colorbar=True)
    image = None
    for ax, k in panels:
        image = ax.imshow(arr[:, :, k].T, origin="lower", cmap=colormap, vmin=lo, vmax=hi,
                          extent=extent, interpolation="nearest")
    cax = fig.add_subplot(grid[:, -1])
    bar = fig.colorbar(image, cax=cax)
    bar.set_label(label, fontsize=9)
    bar.ax.tick_params(labelsize=8)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


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
    arr = _masked(volume_array(data).astype(np.float64), background)
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
) -> Path:
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
    Path
        The picture written (``"auto"`` falls back to numpy when pyvista has no OpenGL context;
        the picture's title says "composited along z" then).
    """
    path = _png_path(path)
    check_choice(backend, "backend", ("auto", "pyvista", "numpy"))
    arr = _masked(volume_array(data).astype(np.float64), background)
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    lo, hi = _value_range(arr, vmin, vmax)
    if backend in ("auto", "pyvista"):
        try:
            _volume_png_pyvista(path, arr, lo, hi, title=title, label=label, cmap=cmap,
                                spacing=spacing3, origin=origin3, size=size)
            return path
        except Exception:  # no usable OpenGL context: fall back unless pyvista was demanded
            if backend == "pyvista":
                raise
    _volume_png_numpy(path, arr, lo, hi, title=title, label=label, cmap=cmap,
                      spacing=spacing3, origin=origin3)
    return path


def _frame_and_save(plotter, path: Path, title: str, *, ticks: str | None) -> None:
    """Title, labelled x/y/z bounds and the shared view of every 3D picture, then the PNG."""
    plotter.add_title(title, font_size=7, color="black")
    plotter.show_bounds(color="black", font_size=12, xtitle="x", ytitle="y", ztitle="z",
                        n_xlabels=3, n_ylabels=3, n_zlabels=3, fmt="%.1f",
                        location="outer", ticks=ticks, minor_ticks=False)
    # from the front (+z), above (+y) and a little to the right: x right, y up on screen
    plotter.view_vector((0.45, 0.55, 1.0), viewup=(0.0, 1.0, 0.0))
    plotter.camera.zoom(0.85)
    with atomic_path(path) as tmp:
        plotter.screenshot(str(tmp))


def _volume_png_pyvista(path, arr, lo, hi, *, title, label, cmap, spacing, origin, size):
    pv = pyvista_offscreen()
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
        _frame_and_save(plotter, path, title, ticks="outside")
    finally:
        plotter.close()


def _volume_png_numpy(path, arr, lo, hi, *, title, label, cmap, spacing, origin):
    import matplotlib

    rgba = composite(arr.data, background=arr.mask, cmap=cmap, vmin=lo, vmax=hi, axis=2)
    white = np.ones(3)
    picture = rgba[..., :3] + (1.0 - rgba[..., 3:]) * white  # over a white background
    extent = _xy_extent(arr.shape, spacing, origin)
    fig = figure(6.4, 5.4)
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
    save_figure(fig, path)


# ---------------------------------------------------------------------------------------------
# colour pictures of RGBA images (ao4d.RenderResult.rgba)

_BACKGROUND = (0.33, 0.38, 0.45)  # the montages' blue-grey for voxels no ray hit


def rgba_array(rgba, name: str = "rgba") -> np.ndarray:
    """``rgba`` as an (nx, ny, nz, 4) float64 array in [0, 1] (uint8 is scaled by 1/255)."""
    arr = as_array(rgba, name, ndim=4, shape_tail=(4,))
    if arr.dtype == np.uint8:
        return arr.astype(np.float64) / 255.0
    arr = as_array(arr, name, dtype=np.float64)
    if not np.isfinite(arr).all() or arr.min() < 0 or arr.max() > 1:
        raise ValueError(f"`{name}` must hold finite values in [0, 1] (or be uint8)")
    return arr


def over_background(rgba: np.ndarray, background=_BACKGROUND) -> np.ndarray:
    """Straight (not premultiplied) RGBA shown over a background colour: ``rgb a + b (1 - a)``.

    Parameters
    ----------
    rgba : (..., 4) float array_like in [0, 1]
    background : (3,) array_like

    Returns
    -------
    rgb : (..., 3) float64

    Examples
    --------
    >>> over_background(np.array([1.0, 0.0, 0.0, 0.25]), (0.0, 0.0, 1.0)).tolist()
    [0.25, 0.0, 0.75]
    """
    arr = np.asarray(rgba, dtype=np.float64)
    bg = as_vector(background, "background", 3)
    return arr[..., :3] * arr[..., 3:] + bg * (1.0 - arr[..., 3:])


def save_rgba_montage(
    path: str | os.PathLike,
    rgba,
    *,
    title: str = "",
    n_slices: int = 12,
    spacing=1.0,
    origin=0.0,
    columns: int = 4,
) -> Path:
    """Save a montage of z-slices of an RGBA image in its own colours (PNG).

    Like :func:`save_montage` (x to the right, y up, panels titled with their z), but each
    voxel shows its colour over the blue-grey background by its alpha; no colour map.

    Parameters
    ----------
    path : path-like
        Output ``.png``.
    rgba : (nx, ny, nz, 4) array_like
        Straight RGBA in [0, 1] (float) or 0..255 (uint8), e.g. ``RenderResult.rgba``.
    title, n_slices, spacing, origin, columns
        As in :func:`save_montage`; slices span the z range where alpha > 0.

    Returns
    -------
    Path
    """
    path = _png_path(path)
    arr = rgba_array(rgba)
    n_slices = min(check_positive_int(n_slices, "n_slices"), arr.shape[2])
    columns = check_positive_int(columns, "columns")
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    extent = _xy_extent(arr.shape, spacing3, origin3)
    fig, _, panels = _montage((arr[..., 3] > 0).any(axis=(0, 1)), n_slices, columns, extent,
                              origin3[2], spacing3[2], colorbar=False)
    shown = np.clip(over_background(arr), 0.0, 1.0)
    for ax, k in panels:
        ax.imshow(np.swapaxes(shown[:, :, k], 0, 1), origin="lower", extent=extent,
                  interpolation="nearest")
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def composite_rgba(rgba, *, opacity: float = 0.9, axis: int = 2) -> np.ndarray:
    """Numpy front-to-back compositing of an RGBA image along one axis (index 0 first).

    Each voxel has its own colour and opacity ``opacity * alpha``; layers are blended with
    ``C += (1 - A) a c``, ``A += (1 - A) a`` as in :func:`composite`.

    Parameters
    ----------
    rgba : (nx, ny, nz, 4) array_like
        Straight RGBA (float in [0, 1] or uint8).
    opacity : float
        Opacity of a voxel of alpha 1, in (0, 1].
    axis : {0, 1, 2}
        Viewing axis.

    Returns
    -------
    rgba : (n_u, n_v, 4) float64
        Premultiplied colour and accumulated opacity of the two remaining axes (in order).

    Examples
    --------
    >>> image = np.zeros((1, 1, 2, 4)); image[0, 0, 0] = (1, 0, 0, 0.5); image[0, 0, 1] = (0, 0, 1, 1)
    >>> composite_rgba(image, opacity=1.0)[0, 0].tolist()
    [0.5, 0.0, 0.5, 1.0]
    """
    if not (0.0 < opacity <= 1.0):
        raise ValueError(f"`opacity` must be in (0, 1], got {opacity}")
    check_choice(axis, "axis", (0, 1, 2))
    arr = np.moveaxis(rgba_array(rgba), axis, 0)
    out = np.zeros(arr.shape[1:3] + (4,))
    for layer in arr:
        weight = (1.0 - out[..., 3]) * opacity * layer[..., 3]
        out[..., :3] += weight[..., None] * layer[..., :3]
        out[..., 3] += weight
    return out


def save_rgba_volume_png(
    path: str | os.PathLike,
    rgba,
    *,
    title: str = "",
    spacing=1.0,
    origin=0.0,
    backend: Literal["auto", "pyvista", "numpy"] = "auto",
    size: tuple[int, int] = (720, 640),
) -> Path:
    """Save a volume rendering of an RGBA image in its own colours (PNG), as ParaView shows it.

    The voxels keep their colours (VTK's direct RGBA volume mode, what ParaView does for a
    4-component unsigned-char array with *Map Scalars* off); alpha sets opacity, so background
    is transparent and opaque hits read as a solid object.

    Parameters
    ----------
    path : path-like
        Output ``.png``.
    rgba : (nx, ny, nz, 4) array_like
        Straight RGBA in [0, 1] (float) or 0..255 (uint8), e.g. ``RenderResult.rgba``.
    title, spacing, origin, backend, size
        As in :func:`save_volume_png` (the numpy fallback composites along z with
        :func:`composite_rgba`).

    Returns
    -------
    Path
    """
    path = _png_path(path)
    check_choice(backend, "backend", ("auto", "pyvista", "numpy"))
    arr = rgba_array(rgba)
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    if backend in ("auto", "pyvista"):
        try:
            _rgba_volume_png_pyvista(path, arr, title=title, spacing=spacing3, origin=origin3,
                                     size=size)
            return path
        except Exception:  # no usable OpenGL context: fall back unless pyvista was demanded
            if backend == "pyvista":
                raise
    layered = composite_rgba(arr, axis=2)  # premultiplied: over white is C + (1 - A) white
    picture = layered[..., :3] + (1.0 - layered[..., 3:])
    extent = _xy_extent(arr.shape, spacing3, origin3)
    fig = figure(6.0, 5.4)
    ax = fig.add_axes([0.1, 0.08, 0.85, 0.8])
    ax.imshow(np.swapaxes(np.clip(picture, 0, 1), 0, 1), origin="lower", extent=extent,
              interpolation="nearest")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"{title}\n(composited along z)", fontsize=9)
    return save_figure(fig, path)


def _rgba_volume_png_pyvista(path, arr, *, title, spacing, origin, size):
    pv = pyvista_offscreen()
    grid = pv.ImageData(dimensions=arr.shape[:3], spacing=spacing, origin=origin)
    grid.point_data["rgba"] = np.round(arr * 255.0).astype(np.uint8).reshape(-1, 4, order="F")
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        plotter.set_background("white")
        # alpha is opacity per quarter voxel: an opaque voxel hides what lies behind it (at
        # VTK's default of about one voxel the solid looks hazy)
        actor = plotter.add_volume(grid, scalars="rgba", mapper="smart", shade=False,
                                   opacity_unit_distance=0.25 * min(spacing))
        actor.prop.interpolation_type = "nearest"  # no blending with transparent background
        _frame_and_save(plotter, path, title, ticks="outside")
    finally:
        plotter.close()


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


def slice_scalars(tri, scalars, name: str) -> np.ndarray | None:
    """Per-vertex values of a slice mesh: an array, or the name of one of its vertex attributes."""
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
        As in :func:`ao4d.mesh_files.save_slice_mesh`; without it the mesh is drawn in one colour.
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
    occ = slice_scalars(tri, occlusion, "occlusion")
    pv = pyvista_offscreen()
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
        _frame_and_save(plotter, path, title, ticks=None)
    finally:
        plotter.close()
    return path
