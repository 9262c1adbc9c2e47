"""Pictures made without a display: slice montages, volume renderings and 3D slice meshes (PNG).

matplotlib's Agg canvas draws the montages and frames every picture. Volume renderings are
drawn by numpy (:func:`voxel_view`: each pixel shows the nearest voxel its ray meets, as a
ray-cast volume mapper with nearest sampling and opaque voxels does; no render window), or by
pyvista off-screen on request, or as a flat front-to-back composite (:func:`composite`). 3D
slices of 4D meshes are drawn by a numpy z-buffer (:func:`triangle_view`) or pyvista, coloured
by openness ``1 - AO`` (:func:`ao_colors`). Every write is atomic.

Why this stays one module: every picture shares one view (:data:`VIEW_DIRECTION`), one frame
(title, labelled box, colour bar, PNG settings) and one montage layout, so they look alike and
change together.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Literal

import numpy as np

from .._atomic import atomic_path
from .._validate import as_array, as_real, as_vector, check_choice, check_positive_int
from ..rendering.compositing import over
from .volumes import pyvista_offscreen, volume_array

__all__ = [
    "save_montage",
    "save_volume_png",
    "composite",
    "save_slice_png",
    "ao_colors",
    "slice_scalars",
    "rgba_array",
    "over_background",
    "save_rgba_montage",
    "composite_rgba",
    "save_rgba_volume_png",
    "voxel_view",
    "surface_view",
    "triangle_view",
    "VIEW_DIRECTION",
]

# Every 3D picture looks from the front (+z), above (+y) and a little to the right: x right and
# y up on screen. The direction points from the scene towards the viewer.
VIEW_DIRECTION = (0.45, 0.55, 1.0)

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
    with atomic_path(path) as tmp:  # zlib level 1: a third of the encoding time, a little larger
        fig.savefig(tmp, format="png", dpi=fig.dpi, facecolor=fig.get_facecolor(), pil_kwargs={"compress_level": 1})
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
    return [
        origin[0] - spacing[0] / 2,
        origin[0] + spacing[0] * (shape[0] - 0.5),
        origin[1] - spacing[1] / 2,
        origin[1] + spacing[1] * (shape[1] - 0.5),
    ]


def _montage(occupied: np.ndarray, n_slices: int, columns: int, extent, z0: float, dz: float, *, colorbar: bool):
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
        grid = fig.add_gridspec(
            rows,
            columns + 1,
            width_ratios=[1] * columns + [0.06],
            left=0.04,
            right=0.9,
            top=top,
            bottom=0.03,
            wspace=0.08,
            hspace=0.25,
        )
    else:
        grid = fig.add_gridspec(rows, columns, left=0.03, right=0.97, top=top, bottom=0.03, wspace=0.08, hspace=0.25)
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
        The 3D image's values.
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
        The montage written (``path``).
    """
    path = _png_path(path)
    arr = _masked(volume_array(data).astype(np.float64), background)
    n_slices = min(check_positive_int(n_slices, "n_slices"), arr.shape[2])
    columns = check_positive_int(columns, "columns")
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    lo, hi = _value_range(arr, vmin, vmax)
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    colormap = matplotlib.colormaps[cmap].with_extremes(bad=(0.33, 0.38, 0.45))
    extent = _xy_extent(arr.shape, spacing3, origin3)
    occupied = (~np.ma.getmaskarray(arr)).any(axis=(0, 1))
    ks = _slice_indices(occupied, n_slices)
    columns = min(columns, len(ks))
    rows = math.ceil(len(ks) / columns)
    aspect = (extent[3] - extent[2]) / (extent[1] - extent[0])
    panel = 2.2
    fig = figure(panel * columns + 1.2, panel * aspect * rows + 0.9)
    top = 1 - 0.55 / fig.get_figheight()
    # one image of all panels on one axes (a dozen axes cost most of a montage's time), each
    # panel titled with its z; same layout, colours and colour bar as a montage of axes
    norm = Normalize(lo, hi)
    tiles, gap = _tile([arr[:, :, k].T[::-1] for k in ks], columns, norm, colormap)
    ax = fig.add_axes((0.04, 0.03, 0.86 - 0.04, top - 0.03))
    ax.imshow(tiles, interpolation="nearest", aspect=spacing3[1] / spacing3[0])
    ax.set_axis_off()
    ny, nx = arr.shape[1], arr.shape[0]
    for n, k in enumerate(ks):
        r, c = divmod(n, columns)
        ax.text(
            c * (nx + gap) + nx / 2 - 0.5,
            gap * 3 + r * (ny + gap * 3) - 0.6,
            f"z = {origin3[2] + spacing3[2] * k:.3g}",
            fontsize=8,
            ha="center",
            va="bottom",
        )
    cax = fig.add_axes((0.895, 0.03, 0.02, top - 0.03))
    bar = fig.colorbar(ScalarMappable(norm, colormap), cax=cax)
    bar.set_label(label, fontsize=9)
    bar.ax.tick_params(labelsize=8)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def _slice_indices(occupied: np.ndarray, n_slices: int) -> np.ndarray:
    """``n_slices`` z indices evenly through the occupied z range (all of it if none)."""
    z = np.flatnonzero(occupied)
    k0, k1 = (z[0], z[-1]) if z.size else (0, len(occupied) - 1)
    return np.unique(np.linspace(k0, k1, n_slices).round().astype(int))


def _tile(panels: list[np.ndarray], columns: int, norm, colormap) -> tuple[np.ndarray, int]:
    """RGBA image of equal-shaped 2D ``panels`` (rows top first) in rows of ``columns``, with
    transparent gaps (one pixel in 16, at least 1) between panels and three times that between
    rows (room for the panel titles); returns (image, gap)."""
    ny, nx = panels[0].shape
    gap = max(1, round(max(nx, ny) / 16))
    rows = math.ceil(len(panels) / columns)
    out = np.zeros((rows * ny + (rows - 1) * gap * 3 + gap * 3, columns * nx + (columns - 1) * gap, 4))
    for n, data in enumerate(panels):
        r, c = divmod(n, columns)
        y0, x0 = gap * 3 + r * (ny + gap * 3), c * (nx + gap)
        out[y0 : y0 + ny, x0 : x0 + nx] = colormap(norm(data))
    return out, gap


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
        The 3D image's values.
    background : (nx, ny, nz) bool array_like, optional
        Transparent voxels (non-finite values are also transparent).
    cmap : str
        Colour map of the values (a matplotlib name).
    vmin, vmax : float, optional
        Values at the ends of the colour map (default: the range of the visible values).
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
        over(out, layer_c, layer_a)
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
    backend: Literal["auto", "surface", "voxels", "pyvista", "numpy"] = "auto",
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
        The 3D image's values.
    title, label, cmap : str
        As in :func:`save_montage`.
    background : (nx, ny, nz) bool array_like, optional
        As in :func:`save_montage`.
    vmin, vmax : float, optional
        As in :func:`save_montage`.
    spacing, origin : float or (3,) array_like
        As in :func:`save_montage`.
    backend : {"auto", "surface", "voxels", "pyvista", "numpy"}
        ``"surface"`` (and ``"auto"``): numpy draws the voxels' smoothed outer surface in their
        colours (:func:`surface_view`), no render window; ``"voxels"``: the nearest voxel along
        each ray, cubes and all (:func:`voxel_view`); ``"pyvista"`` renders off-screen with
        VTK's ray-cast volume mapper; ``"numpy"`` composites along z with :func:`composite`.
    size : (2,) tuple of int
        Picture size in pixels (the voxel view spans 0.78 of the width).

    Returns
    -------
    Path
        The volume rendering written (``path``).
    """
    path = _png_path(path)
    check_choice(backend, "backend", ("auto", "surface", "voxels", "pyvista", "numpy"))
    arr = _masked(volume_array(data).astype(np.float64), background)
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    lo, hi = _value_range(arr, vmin, vmax)
    if backend == "pyvista":
        _volume_png_pyvista(
            path, arr, lo, hi, title=title, label=label, cmap=cmap, spacing=spacing3, origin=origin3, size=size
        )
    elif backend == "numpy":
        _volume_png_numpy(path, arr, lo, hi, title=title, label=label, cmap=cmap, spacing=spacing3, origin=origin3)
    else:
        import matplotlib

        colormap = matplotlib.colormaps[cmap]
        colours = colormap((arr.filled(lo) - lo) / (hi - lo))[..., :3]
        mappable = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(lo, hi), cmap=colormap)
        draw = _voxel_picture if backend == "voxels" else _surface_picture
        draw(
            path,
            colours,
            ~np.ma.getmaskarray(arr),
            title=title,
            spacing=spacing3,
            origin=origin3,
            width=int(0.78 * size[0]),
            colorbar=(mappable, label),
        )
    return path


def _view_basis(direction=VIEW_DIRECTION) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Screen right, screen up and the unit direction into the scene (orthographic, y up)."""
    back = np.asarray(direction, dtype=np.float64)
    back /= np.linalg.norm(back)
    forward = -back
    right = np.cross(forward, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward), forward


def voxel_view(
    occupied, *, spacing=1.0, origin=0.0, width: int = 560, direction=VIEW_DIRECTION
) -> tuple[np.ndarray, np.ndarray, tuple[float, ...]]:
    """Which voxel each pixel of an orthographic view shows: the nearest occupied one its ray meets.

    The ray through each pixel centre is cut with every candidate voxel's box (slab test); the
    nearest entry wins (a z-buffer). Candidates are the voxels with an empty neighbour on a side
    that faces the viewer: a voxel whose three viewer-facing neighbours are occupied is hidden
    by them (``direction`` has no zero component). What VTK's ray-cast mapper shows for opaque
    voxels with nearest-voxel sampling, in an orthographic view.

    Parameters
    ----------
    occupied : (nx, ny, nz) bool array_like
        The voxels drawn.
    spacing, origin : float or (3,) array_like
        Grid geometry.
    width : int
        Pixels across the box's projection (the height follows).
    direction : (3,) array_like
        From the scene towards the viewer (no zero component).

    Returns
    -------
    voxel : (H, W) int64
        Flat (C-order) index of the voxel each pixel shows, -1 where none (row 0 is the top).
    depth : (H, W) float64
        Distance along the view from the box's nearest corner (inf where none).
    extent : (4,) tuple of float
        ``(left, right, bottom, top)`` of the picture in screen units (for imshow).

    Examples
    --------
    >>> voxel, _, _ = voxel_view(np.ones((1, 1, 1), bool), width=8)
    >>> bool((voxel == 0).any()), bool((voxel == -1).any())
    (True, True)
    """
    occ = as_array(occupied, "occupied", ndim=3, dtype=bool)
    spacing3 = np.asarray(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = np.asarray(as_vector(origin, "origin", 3))
    width = check_positive_int(width, "width")
    right, up, forward = _view_basis(direction)
    if (forward == 0).any():
        raise ValueError(f"`direction` must have no zero component, got {direction}")
    shape = np.array(occ.shape)
    lo, hi = origin3 - spacing3 / 2, origin3 + spacing3 * (shape - 0.5)
    pixel, height, extent = _frame(lo, hi, width, fit="width", direction=direction)
    sz = _corners(lo, hi) @ forward
    # candidates: occupied, with an empty (or outside) neighbour towards the viewer
    toward = np.where(forward < 0, 1, -1)  # the neighbour nearer the viewer along each axis
    covered = np.ones(occ.shape, bool)
    for axis in range(3):
        shifted = np.zeros_like(occ)
        src = [slice(None)] * 3
        dst = [slice(None)] * 3
        if toward[axis] > 0:
            src[axis], dst[axis] = slice(1, None), slice(None, -1)
        else:
            src[axis], dst[axis] = slice(None, -1), slice(1, None)
        shifted[tuple(dst)] = occ[tuple(src)]
        covered &= shifted
    ids = np.flatnonzero(occ & ~covered)
    voxel = np.full(height * width, -1, dtype=np.int64)
    depth = np.full(height * width, np.inf)
    if ids.size:
        centre = origin3 + spacing3 * np.stack(np.unravel_index(ids, occ.shape), axis=1)
        cx, cy = centre @ right, centre @ up
        half = spacing3 / 2
        reach_x, reach_y = float(half @ np.abs(right)), float(half @ np.abs(up))
        kx = np.arange(-int(math.ceil(reach_x / pixel)) - 1, int(math.ceil(reach_x / pixel)) + 2)
        ky = np.arange(-int(math.ceil(reach_y / pixel)) - 1, int(math.ceil(reach_y / pixel)) + 2)
        dx, dy = (a.ravel() for a in np.meshgrid(kx, ky))
        col0 = np.floor((cx - extent[0]) / pixel).astype(np.int64)
        row0 = np.floor((extent[3] - cy) / pixel).astype(np.int64)
        # the pixel centre's ray, base + t forward, against the voxel's box (slab test, one axis
        # at a time: the ray enters through the face towards the viewer on each axis). The
        # entry and exit along axis a split into a per-voxel and a per-offset term, so the
        # (voxels, offsets) arrays cost one subtraction each instead of a gather and a product.
        px0 = extent[0] + (col0 + 0.5) * pixel
        py0 = extent[3] - (row0 + 0.5) * pixel
        near = far = None
        for a in range(3):
            rel = (centre[:, a] - (px0 * right[a] + py0 * up[a])) / forward[a]
            step = abs(half[a] / forward[a])
            shift = (dx * pixel * right[a] - dy * pixel * up[a]) / forward[a]
            enter = (rel - step)[:, None] - shift
            leave = (rel + step)[:, None] - shift
            near = enter if near is None else np.maximum(near, enter, out=near)
            far = leave if far is None else np.minimum(far, leave, out=far)
        col, row = col0[:, None] + dx, row0[:, None] + dy
        hit = (near <= far) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
        voxel_of, offset = np.nonzero(hit)
        flat = row[voxel_of, offset] * width + col[voxel_of, offset]
        near = near[voxel_of, offset] - sz.min()
        best = np.full(height * width, np.inf)
        np.minimum.at(best, flat, near)
        win = near == best[flat]
        voxel[flat[win]] = ids[voxel_of[win]]
        depth[flat[win]] = near[win]
    return voxel.reshape(height, width), depth.reshape(height, width), extent


def _corners(lo, hi) -> np.ndarray:
    """The 8 corners (8, 3) of the box ``lo``..``hi``."""
    return np.array([[(lo, hi)[(c >> k) & 1][k] for k in range(3)] for c in range(8)])


def _frame(lo, hi, width: int, *, fit: str = "both", direction=VIEW_DIRECTION) -> tuple[float, int, tuple[float, ...]]:
    """Pixel size, height and ``(left, right, bottom, top)`` of a ``width``-pixel view of a box:
    its projection spans the width (``fit="width"``) or fits in a square of it (``"both"``)."""
    right, up, _ = _view_basis(direction)
    corners = _corners(lo, hi)
    sx, sy = corners @ right, corners @ up
    span = sx.max() - sx.min() if fit == "width" else max(sx.max() - sx.min(), sy.max() - sy.min())
    pixel = max(span, 1e-300) / width
    height = int(math.ceil((sy.max() - sy.min()) / pixel))
    return (
        pixel,
        height,
        (float(sx.min()), float(sx.min() + width * pixel), float(sy.max() - height * pixel), float(sy.max())),
    )


def triangle_view(
    points, faces, *, width: int = 560, direction=VIEW_DIRECTION, box=None, fit: str = "both"
) -> tuple[np.ndarray, np.ndarray, tuple[float, ...]]:
    """Which triangle each pixel of an orthographic view shows, and where on it (a z-buffer).

    Parameters
    ----------
    points : (V, 3) array_like
        The mesh's vertices.
    faces : (F, 3) int array_like
        Vertex indices per triangle.
    width : int
        Pixels across the projection of ``box``.
    direction : (3,) array_like
        From the scene towards the viewer.
    box : (2, 3) array_like, optional
        The box framed (default: the points' bounding box).
    fit : {"both", "width"}
        The box's projection fits in a ``width`` square, or spans ``width`` (as in
        :func:`voxel_view`, whose frame it then shares).

    Returns
    -------
    face : (H, W) int64
        The triangle nearest the viewer at each pixel centre, -1 where none (row 0 is the top).
    weights : (H, W, 3) float64
        Barycentric weights of the pixel centre on that triangle (0 where none).
    extent : (4,) tuple of float
        ``(left, right, bottom, top)`` in screen units.
    """
    pts = as_array(points, "points", ndim=2, shape_tail=(3,), dtype=np.float64, finite=True)
    tris = as_array(faces, "faces", ndim=2, shape_tail=(3,))
    right, up, forward = _view_basis(direction)
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if box is None else np.asarray(box, dtype=np.float64)
    check_choice(fit, "fit", ("both", "width"))
    pixel, height, extent = _frame(lo, hi, width, fit=fit, direction=direction)
    # pixel coordinates (column, row from the top) and depth of every point
    u = (pts @ right - extent[0]) / pixel
    v = (extent[3] - pts @ up) / pixel
    z = pts @ forward
    tu, tv, tz = u[tris], v[tris], z[tris]  # (F, 3)
    c0 = np.clip(np.ceil(tu.min(axis=1) - 0.5), 0, width).astype(np.int64)
    c1 = np.clip(np.floor(tu.max(axis=1) - 0.5), -1, width - 1).astype(np.int64)
    r0 = np.clip(np.ceil(tv.min(axis=1) - 0.5), 0, height).astype(np.int64)
    r1 = np.clip(np.floor(tv.max(axis=1) - 0.5), -1, height - 1).astype(np.int64)
    nw, nh = np.maximum(c1 - c0 + 1, 0), np.maximum(r1 - r0 + 1, 0)
    count = nw * nh
    face_of = np.repeat(np.arange(len(tris)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    col = c0[face_of] + k % np.maximum(nw[face_of], 1)
    row = r0[face_of] + k // np.maximum(nw[face_of], 1)
    pu, pv = col + 0.5, row + 0.5
    a_u, a_v = tu[face_of].T, tv[face_of].T
    area = (a_u[1] - a_u[0]) * (a_v[2] - a_v[0]) - (a_u[2] - a_u[0]) * (a_v[1] - a_v[0])
    safe = np.where(area != 0, area, 1.0)
    l0 = ((a_u[1] - pu) * (a_v[2] - pv) - (a_u[2] - pu) * (a_v[1] - pv)) / safe
    l1 = ((a_u[2] - pu) * (a_v[0] - pv) - (a_u[0] - pu) * (a_v[2] - pv)) / safe
    l2 = 1.0 - l0 - l1
    inside = (area != 0) & (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    face_of, col, row = face_of[inside], col[inside], row[inside]
    l0, l1, l2 = l0[inside], l1[inside], l2[inside]
    depth = l0 * tz[face_of, 0] + l1 * tz[face_of, 1] + l2 * tz[face_of, 2]
    flat = row * width + col
    best = np.full(height * width, np.inf)
    np.minimum.at(best, flat, depth)
    win = depth == best[flat]
    face = np.full(height * width, -1, dtype=np.int64)
    weights = np.zeros((height * width, 3))
    face[flat[win]] = face_of[win]
    weights[flat[win]] = np.stack([l0[win], l1[win], l2[win]], axis=1)
    return face.reshape(height, width), weights.reshape(height, width, 3), extent


def _voxel_axes(ax, shape, spacing, origin) -> None:
    """The box of the voxels with labelled x, y and z edges (min, middle, max), as VTK's bounds."""
    right, up, _ = _view_basis()
    spacing3, origin3 = np.asarray(spacing), np.asarray(origin)
    lo, hi = origin3, origin3 + spacing3 * (np.asarray(shape) - 1)
    to2d = lambda p: (float(np.dot(p, right)), float(np.dot(p, up)))  # noqa: E731
    # an edge per axis, as VTK's outer bounds: x along the bottom front, y up the left front,
    # z along the top left; ticks and labels point away from the box
    for axis, fixed, offset in (
        (0, (None, lo[1], hi[2]), (0.0, -1.0)),
        (1, (lo[0], None, hi[2]), (-1.0, 0.0)),
        (2, (lo[0], hi[1], None), (-0.7, 0.7)),
    ):
        a = np.array([lo[axis] if f is None else f for f in fixed])
        b = np.array([hi[axis] if f is None else f for f in fixed])
        (x0, y0), (x1, y1) = to2d(a), to2d(b)
        ax.plot([x0, x1], [y0, y1], color="black", lw=0.8)
        pad = 0.04 * float(np.max(hi - lo))
        for frac in (0.0, 0.5, 1.0):
            value = lo[axis] + frac * (hi[axis] - lo[axis])
            x, y = x0 + frac * (x1 - x0), y0 + frac * (y1 - y0)
            ax.plot([x, x + 0.4 * pad * offset[0]], [y, y + 0.4 * pad * offset[1]], color="black", lw=0.8)
            # z's label at the corner it shares with y's top goes straight up, clear of y's
            shift = (0.0, 1.0) if axis == 2 and frac == 1.0 else offset
            ax.text(
                x + pad * shift[0],
                y + pad * shift[1],
                f"{value:.1f}",
                fontsize=8,
                ha="right" if shift[0] < 0 else "center",
                va="top" if shift[1] < 0 else "bottom" if shift[1] > 0 else "center",
            )
        mid = (0.5 * (x0 + x1) + 4.5 * pad * offset[0], 0.5 * (y0 + y1) + 4.5 * pad * offset[1])
        ax.text(*mid, "xyz"[axis], fontsize=9, ha="center", va="center")


def _voxel_picture(
    path: Path, colours: np.ndarray, occupied: np.ndarray, *, title: str, spacing, origin, width: int, colorbar=None
) -> None:
    """A volume picture drawn by :func:`voxel_view`: voxel colours over white, labelled box,
    title, and a colour bar ``(mappable, label)`` if given."""
    voxel, _, extent = voxel_view(occupied, spacing=spacing, origin=origin, width=width)
    picture = np.ones(voxel.shape + (3,))
    shown = voxel >= 0
    picture[shown] = colours.reshape(-1, 3)[voxel[shown]]
    fig = figure(7.2, 6.4)
    _boxed_picture(fig, picture, extent, occupied.shape, spacing, origin, title=title, colorbar=colorbar)
    save_figure(fig, path)


def surface_view(
    occupied, colours, *, spacing=1.0, origin=0.0, width: int = 560, sigma: float = 0.7
) -> tuple[np.ndarray, np.ndarray, tuple[float, ...], np.ndarray]:
    """An orthographic view of the voxels' smoothed outer surface, in the voxels' colours.

    The occupancy, blurred by a Gaussian of ``sigma`` voxels, is contoured at 1/2 (scikit-image's
    marching cubes), so a ball's boundary reads as round rather than as cubes; each surface
    vertex takes the Gaussian-weighted mean colour of the occupied voxels around it (a
    normalised convolution: empty voxels give no colour), and :func:`triangle_view` draws the
    surface with colours interpolated across each triangle. At ``sigma = 0.7`` a sheet one
    voxel thick keeps its surface (its blurred value is 0.53, over the contour's 0.5); a line one
    voxel thick (0.25-0.32), a sheet of voxels touching at their edges (at most 0.33) and a lone
    voxel (0.15) melt away, so voxels under 0.4 are drawn by :func:`save_volume_png` from
    :func:`voxel_view` where the surface leaves the pixel empty (a box's corner voxel keeps 0.48:
    the rounded corner stands, without the cube's tooth).

    Parameters
    ----------
    occupied : (nx, ny, nz) bool array_like
        The voxels drawn.
    colours : (nx, ny, nz, 3) array_like
        Their RGB colours in [0, 1].
    spacing, origin : float or (3,) array_like
        Grid geometry.
    width : int
        Pixels across the box's projection (the height follows), as in :func:`voxel_view`.
    sigma : float
        Blur in voxels (> 0).

    Returns
    -------
    rgb : (H, W, 3) float64
        The picture (zero where ``shown`` is False).
    shown : (H, W) bool
        Pixels on the surface.
    extent : (4,) tuple of float
        ``(left, right, bottom, top)``, the same as :func:`voxel_view`'s for these arguments.
    lost : (nx, ny, nz) bool
        Occupied voxels whose blurred value is under 0.4 (lines, edge-touching sheets, lone
        voxels), which the surface does not draw.
    """
    from skimage.measure import marching_cubes

    occ = as_array(occupied, "occupied", ndim=3, dtype=bool)
    rgb = as_array(colours, "colours", ndim=4, shape_tail=(3,), dtype=np.float64)
    if rgb.shape[:3] != occ.shape:
        raise ValueError(f"`colours` must be {occ.shape + (3,)}, got {rgb.shape}")
    spacing3 = np.asarray(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = np.asarray(as_vector(origin, "origin", 3))
    width = check_positive_int(width, "width")
    sigma = as_real(sigma, "sigma", gt=0)
    # the box framed is voxel_view's (voxel boxes, not centres), so both pictures line up
    box = np.stack([origin3 - spacing3 / 2, origin3 + spacing3 * (np.array(occ.shape) - 0.5)])
    pad = _blur_radius(sigma) + 1  # closed at the box's faces, whatever the blur reaches
    blurred = _blur(np.pad(occ.astype(np.float32), pad), sigma)
    inner = (slice(pad, -pad),) * 3
    lost = occ & (blurred[inner] < 0.4)
    if blurred.max() <= 0.5:  # nothing survives the blur: an empty view of the same frame
        face, _, extent = triangle_view(box, np.zeros((0, 3), np.int64), width=width, box=box, fit="width")
        return np.zeros(face.shape + (3,)), face >= 0, extent, lost
    verts, faces, _, _ = marching_cubes(blurred, 0.5)
    weighted = _blur(np.pad(rgb * occ[..., None], ((pad, pad),) * 3 + ((0, 0),)).astype(np.float32), sigma)
    vertex_rgb = _trilinear(weighted, verts) / np.maximum(_trilinear(blurred, verts), 1e-12)[:, None]
    points = origin3 + spacing3 * (verts - pad)  # in the voxel index space of ``occupied``
    face, bary, extent = triangle_view(points, faces, width=width, box=box, fit="width")
    shown = face >= 0
    picture = np.zeros(face.shape + (3,))
    picture[shown] = np.einsum("pk,pkc->pc", bary[shown], vertex_rgb[faces[face[shown]]])
    return np.clip(picture, 0.0, 1.0), shown, extent, lost


def _blur_radius(sigma: float) -> int:
    """Taps on each side of the Gaussian :func:`_blur` applies (4 sigma, as scipy.ndimage's)."""
    return max(1, int(4.0 * sigma + 0.5))


def _blur(volume: np.ndarray, sigma: float) -> np.ndarray:
    """``volume`` (nx, ny, nz[, c]) convolved with a Gaussian of ``sigma`` voxels along its first
    three axes, zero outside: what ``scipy.ndimage.gaussian_filter(mode="constant")`` gives,
    without importing scipy.ndimage (half a second of the demo's wall time)."""
    r = _blur_radius(sigma)
    taps = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    taps = (taps / taps.sum()).astype(volume.dtype)
    out = volume
    for axis in range(3):
        padded = np.pad(out, [(r, r) if a == axis else (0, 0) for a in range(out.ndim)])
        n = out.shape[axis]
        out = sum(w * np.take(padded, range(k, k + n), axis=axis) for k, w in enumerate(taps))
    return out


def _trilinear(volume: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``volume`` (nx, ny, nz[, c]) interpolated trilinearly at ``points`` (n, 3) in index space
    (inside the grid)."""
    base = np.clip(np.floor(points).astype(np.int64), 0, np.array(volume.shape[:3]) - 2)
    frac = points - base
    out = 0.0
    for corner in range(8):
        bit = np.array([(corner >> k) & 1 for k in range(3)])
        weight = np.prod(np.where(bit, frac, 1.0 - frac), axis=1)
        value = volume[tuple((base + bit).T)]
        out = out + (weight[:, None] * value if value.ndim > 1 else weight * value)
    return out


def _surface_picture(
    path: Path, colours: np.ndarray, occupied: np.ndarray, *, title: str, spacing, origin, width: int, colorbar=None
) -> None:
    """A volume picture drawn by :func:`surface_view` over white, with :func:`voxel_view`
    drawing the lines and lone voxels the blur dropped where the surface leaves a pixel empty;
    labelled box, title, colour bar."""
    picture, shown, extent, lost = surface_view(occupied, colours, spacing=spacing, origin=origin, width=width)
    out = np.ones(picture.shape)
    out[shown] = picture[shown]
    if lost.any():
        voxel, _, voxel_extent = voxel_view(lost, spacing=spacing, origin=origin, width=width)
        if voxel.shape == shown.shape and np.allclose(voxel_extent, extent):
            fill = (voxel >= 0) & ~shown
            out[fill] = colours.reshape(-1, 3)[voxel[fill]]
    fig = figure(7.2, 6.4)
    _boxed_picture(fig, out, extent, occupied.shape, spacing, origin, title=title, colorbar=colorbar)
    save_figure(fig, path)


def _boxed_picture(fig, picture: np.ndarray, extent, shape, spacing, origin, *, title: str, colorbar=None) -> None:
    """Draw an RGB ``picture`` (view coordinates ``extent``) in the labelled x/y/z box of a
    ``shape`` grid at ``spacing`` and ``origin``, under ``title``, with a colour bar
    ``(mappable, label)`` at the right if given."""
    ax = fig.add_axes([0.1, 0.1, 0.68 if colorbar is not None else 0.8, 0.78])
    # the picture is drawn a little smaller than its pixels: resample with a filter, not nearest
    ax.imshow(np.clip(picture, 0, 1), extent=extent, interpolation="antialiased")
    _voxel_axes(ax, shape, spacing, origin)
    pad_x, pad_y = 0.12 * (extent[1] - extent[0]), 0.12 * (extent[3] - extent[2])
    ax.set_xlim(extent[0] - pad_x, extent[1] + 0.3 * pad_x)
    ax.set_ylim(extent[2] - pad_y, extent[3] + 0.3 * pad_y)
    ax.set_aspect("equal")
    ax.set_axis_off()
    fig.suptitle(title, fontsize=10, y=0.97)
    if colorbar is not None:
        mappable, label = colorbar
        cax = fig.add_axes([0.86, 0.18, 0.03, 0.62])
        fig.colorbar(mappable, cax=cax).set_label(label, fontsize=9)


def _scalar_bar(title: str, fmt: str) -> dict[str, object]:
    """PyVista's ``scalar_bar_args`` of every 3D picture: a black vertical bar at the right."""
    return {
        "title": title,
        "color": "black",
        "vertical": True,
        "position_x": 0.86,
        "position_y": 0.15,
        "height": 0.7,
        "width": 0.07,
        "fmt": fmt,
    }


def _frame_and_save(plotter, path: Path, title: str, *, ticks: str | None) -> None:
    """Title, labelled x/y/z bounds and the shared view of every 3D picture, then the PNG."""
    plotter.add_title(title, font_size=7, color="black")
    plotter.show_bounds(
        color="black",
        font_size=12,
        xtitle="x",
        ytitle="y",
        ztitle="z",
        n_xlabels=3,
        n_ylabels=3,
        n_zlabels=3,
        fmt="%.1f",
        location="outer",
        ticks=ticks,
        minor_ticks=False,
    )
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
            grid,
            scalars=label or "value",
            cmap=cmap,
            clim=(floor, hi),
            opacity=opacity,
            shade=False,
            mapper="smart",
            scalar_bar_args=_scalar_bar(label or "value", "%.2f"),
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
    fig = _composited_figure(rgba, _xy_extent(arr.shape, spacing, origin), title, (6.4, 5.4), [0.08, 0.08, 0.72, 0.8])
    cax = fig.add_axes([0.85, 0.15, 0.03, 0.66])
    mappable = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(lo, hi), cmap=matplotlib.colormaps[cmap])
    fig.colorbar(mappable, cax=cax).set_label(label, fontsize=9)
    save_figure(fig, path)


# ---------------------------------------------------------------------------------------------
# colour pictures of RGBA images (ao4d.RenderResult.rgba)

_BACKGROUND = (0.33, 0.38, 0.45)  # the montages' blue-grey for voxels no ray hit


def rgba_array(rgba, name: str = "rgba") -> np.ndarray:
    """``rgba`` as an (nx, ny, nz, 4) float64 array in [0, 1] (uint8 is scaled by 1/255).

    Parameters
    ----------
    rgba : (nx, ny, nz, 4) array_like
        Straight RGBA in [0, 1] (float) or 0..255 (uint8).
    name : str
        The parameter it came from, named in errors.

    Returns
    -------
    (nx, ny, nz, 4) float64
        The colours in [0, 1].

    Raises
    ------
    ValueError
        If the shape is wrong or a float value is outside [0, 1].
    """
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
        Straight colours and their alpha.
    background : (3,) array_like
        The background's RGB in [0, 1].

    Returns
    -------
    rgb : (..., 3) float64
        The colours seen.

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
    title : str
        Figure title.
    n_slices : int
        Number of evenly spaced z-slices, spanning the z range where alpha > 0.
    spacing, origin : float or (3,) array_like
        Grid geometry, as in :func:`save_montage`.
    columns : int
        Panels per row, as in :func:`save_montage`.

    Returns
    -------
    Path
        The montage of colours written (``path``).
    """
    path = _png_path(path)
    arr = rgba_array(rgba)
    n_slices = min(check_positive_int(n_slices, "n_slices"), arr.shape[2])
    columns = check_positive_int(columns, "columns")
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    extent = _xy_extent(arr.shape, spacing3, origin3)
    fig, _, panels = _montage(
        (arr[..., 3] > 0).any(axis=(0, 1)), n_slices, columns, extent, origin3[2], spacing3[2], colorbar=False
    )
    shown = np.clip(over_background(arr), 0.0, 1.0)
    for ax, k in panels:
        ax.imshow(np.swapaxes(shown[:, :, k], 0, 1), origin="lower", extent=extent, interpolation="nearest")
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
        over(out, layer[..., :3], opacity, layer[..., 3])
    return out


def save_rgba_volume_png(
    path: str | os.PathLike,
    rgba,
    *,
    title: str = "",
    spacing=1.0,
    origin=0.0,
    backend: Literal["auto", "surface", "voxels", "pyvista", "numpy"] = "auto",
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
    title : str
        Title above the picture.
    spacing, origin : float or (3,) array_like
        Grid geometry, as in :func:`save_montage`.
    backend : {"auto", "surface", "voxels", "pyvista", "numpy"}
        As in :func:`save_volume_png` (``"numpy"`` composites along z with
        :func:`composite_rgba`; ``"surface"`` and ``"voxels"`` draw the voxels of alpha > 0,
        each in its colour over white by its alpha).
    size : (2,) tuple of int
        Picture size in pixels.

    Returns
    -------
    Path
        The colour volume rendering written (``path``).
    """
    path = _png_path(path)
    check_choice(backend, "backend", ("auto", "surface", "voxels", "pyvista", "numpy"))
    arr = rgba_array(rgba)
    spacing3 = tuple(as_vector(spacing, "spacing", 3, positive=True))
    origin3 = tuple(as_vector(origin, "origin", 3))
    if backend == "pyvista":
        _rgba_volume_png_pyvista(path, arr, title=title, spacing=spacing3, origin=origin3, size=size)
        return path
    if backend in ("auto", "surface", "voxels"):
        colours = arr[..., :3] * arr[..., 3:] + (1.0 - arr[..., 3:])  # over white
        (_voxel_picture if backend == "voxels" else _surface_picture)(
            path, colours, arr[..., 3] > 0, title=title, spacing=spacing3, origin=origin3, width=int(0.78 * size[0])
        )
        return path
    fig = _composited_figure(
        composite_rgba(arr, axis=2), _xy_extent(arr.shape, spacing3, origin3), title, (6.0, 5.4), [0.1, 0.08, 0.85, 0.8]
    )
    return save_figure(fig, path)


def _composited_figure(layered, extent, title: str, size, rect):
    """A figure of premultiplied RGBA composited along z, shown over white (``C + (1 - A)``)."""
    picture = layered[..., :3] + (1.0 - layered[..., 3:])
    fig = figure(*size)
    ax = fig.add_axes(rect)
    ax.imshow(np.swapaxes(np.clip(picture, 0, 1), 0, 1), origin="lower", extent=extent, interpolation="nearest")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"{title}\n(composited along z)", fontsize=9)
    return fig


def _rgba_volume_png_pyvista(path, arr, *, title, spacing, origin, size):
    pv = pyvista_offscreen()
    grid = pv.ImageData(dimensions=arr.shape[:3], spacing=spacing, origin=origin)
    grid.point_data["rgba"] = np.round(arr * 255.0).astype(np.uint8).reshape(-1, 4, order="F")
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        plotter.set_background("white")
        # alpha is opacity per quarter voxel: an opaque voxel hides what lies behind it (at
        # VTK's default of about one voxel the solid looks hazy)
        actor = plotter.add_volume(
            grid, scalars="rgba", mapper="smart", shade=False, opacity_unit_distance=0.25 * min(spacing)
        )
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
    cmap : str
        Matplotlib colour map.

    Returns
    -------
    colors : (N, 4) uint8
        The colour of each value.
    """
    import matplotlib

    occ = as_array(occlusion, "occlusion", ndim=1, dtype=np.float64)
    colours = matplotlib.colormaps[cmap].with_extremes(bad=(0.5, 0.5, 0.5))(
        np.ma.masked_invalid(1.0 - np.clip(occ, 0.0, 1.0))
    )
    return (np.asarray(colours) * 255).round().astype(np.uint8)


def slice_scalars(tri, scalars, name: str) -> np.ndarray | None:
    """Per-vertex values of a slice mesh: an array, or the name of one of its vertex attributes.

    Parameters
    ----------
    tri : trimesh.Trimesh
        The slice mesh.
    scalars : (V,) array_like, str or None
        The values, or the name of a vertex attribute of ``tri``.
    name : str
        The parameter they came from, named in errors.

    Returns
    -------
    (V,) float64 or None
        The values (``None`` for ``None``).

    Raises
    ------
    ValueError
        If the name is not a vertex attribute or the values are not one per vertex.
    """
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
        raise ValueError(f"`{name}` must have one value per vertex ({len(tri.vertices)}), got {arr.shape[0]}")
    return arr


def save_slice_png(
    path: str | os.PathLike,
    tri,
    *,
    occlusion=None,
    title: str = "",
    cmap: str = "magma",
    size: tuple[int, int] = (720, 640),
    backend: Literal["auto", "numpy", "pyvista"] = "auto",
) -> Path:
    """Render a 3D slice mesh off-screen, coloured by openness ``1 - occlusion``.

    Parameters
    ----------
    path : path-like
        Output ``.png``.
    tri : trimesh.Trimesh
        The slice mesh (:meth:`ao4d.SimplexMesh.slice`).
    occlusion : (V,) array_like or str, optional
        As in :func:`ao4d.io.mesh_files.save_slice_mesh`; without it the mesh is drawn in one colour.
    title : str
        Title above the slice.
    cmap : str
        Matplotlib colour map.
    size : (2,) tuple of int
        Picture size in pixels.
    backend : {"auto", "numpy", "pyvista"}
        ``"numpy"`` (and ``"auto"``): :func:`triangle_view` with smooth (Gouraud) colours and a
        two-sided light above-left of the viewer, no render window; ``"pyvista"``: VTK
        off-screen.

    Returns
    -------
    Path
        The picture of the slice written (``path``).
    """
    path = _png_path(path)
    check_choice(backend, "backend", ("auto", "numpy", "pyvista"))
    if len(tri.faces) == 0:
        raise ValueError("`tri` has no faces: the hyperplane misses the mesh")
    occ = slice_scalars(tri, occlusion, "occlusion")
    if backend != "pyvista":
        _slice_png_numpy(path, tri, occ, title=title, cmap=cmap, size=size)
        return path
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
                poly,
                scalars="1 - AO",
                cmap=cmap,
                clim=(0.0, 1.0),
                smooth_shading=True,
                scalar_bar_args=_scalar_bar("1 - AO", "%.1f"),
            )
        _frame_and_save(plotter, path, title, ticks=None)
    finally:
        plotter.close()
    return path


def _slice_png_numpy(path: Path, tri, occ, *, title: str, cmap: str, size) -> None:
    """The slice drawn by :func:`triangle_view`: colour ``cmap(1 - AO)`` (or one colour) times
    ``0.3 + 0.7 |n . l|`` (interpolated vertex normals, ``l`` above-left of the viewer), in a
    labelled box."""
    import matplotlib

    points = np.asarray(tri.vertices, dtype=np.float64)
    faces = np.asarray(tri.faces)
    face, weights, extent = triangle_view(points, faces, width=int(0.78 * size[0]))
    shown = face >= 0
    corner = faces[face[shown]]  # (P, 3) vertex ids of the triangle under each pixel
    w = weights[shown]
    normals = np.asarray(tri.vertex_normals, dtype=np.float64)
    n = np.einsum("pk,pkd->pd", w, normals[corner])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    right, up, forward = _view_basis()
    towards = -forward + 0.6 * up - 0.3 * right  # a light above-left of the viewer, as the page's
    light = 0.3 + 0.7 * np.abs(n @ (towards / np.linalg.norm(towards)))
    colormap = matplotlib.colormaps[cmap]
    if occ is None:
        base = np.broadcast_to(matplotlib.colors.to_rgb("lightsteelblue"), (len(w), 3))
    else:
        openness = np.einsum("pk,pk->p", w, 1.0 - np.clip(occ, 0.0, 1.0)[corner])
        base = colormap(openness)[:, :3]
    picture = np.ones(face.shape + (3,))
    picture[shown] = base * light[:, None]
    lo, hi = points.min(axis=0), points.max(axis=0)
    colorbar = None
    if occ is not None:
        colorbar = (matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0, 1), cmap=colormap), "1 - AO")
    fig = figure(size[0] / 100, size[1] / 100)
    _boxed_picture(fig, picture, extent, np.array([2, 2, 2]), hi - lo, lo, title=title, colorbar=colorbar)
    save_figure(fig, path)
