"""The 4D camera's 3D image in the browser: one self-contained WebGL2 page that ray-marches it.

:func:`view_image` writes an HTML file holding the page (``ao4d/browser/image_page.html``, in the frame and
with the script every ao4d page shares, :mod:`ao4d.browser._page`) and the image
of :func:`ao4d.render` (a :class:`~ao4d.rendering.pipeline.RenderResult`, or the ``.vti`` / ``.mhd`` file
``ao4d render`` writes). The page ray-marches the volume on the GPU every frame, with a transfer
function (colour map presets and an opacity ramp dragged on the page), axis-aligned clipping
planes and the orbit camera of the slicing page (:mod:`ao4d.browser.viewer`). It needs no network and
opens from ``file://``. :func:`reference_march` is the same ray-march in numpy, sample for sample.

Why this stays one module: the page's JavaScript mirrors every convention below, and
:func:`reference_march` is their executable statement; split, the two halves would drift apart.

Conventions (the page and this module agree exactly)
----------------------------------------------------
Voxels
    Voxel ``(i, j, k)`` of an ``(nx, ny, nz)`` image is the box ``origin + spacing * ((i, j, k)
    + [-1/2, 1/2]^3)`` (the volume files' convention: the voxel's centre at ``origin + spacing *
    index``). The page works relative to the centre ``c`` of the whole box; its half extent is
    ``h = spacing * n / 2``.
Arrays on the page
    ``rgba`` (the voxels' own colours, when the image has them), ``shade``, ``occlusion`` and
    ``depth``. Each scalar is quantised to 8 bits, ``q = floor(255 v + 1/2)`` with ``v`` =
    shade and occlusion clipped to [0, 1], and depth mapped linearly from its range over hit
    voxels (near 0, far 1) (:func:`encode`). A voxel is *hit* when ``object_id >= 0``, else
    (files without ids) when its depth is finite, else (``.mhd``: shade only) when shade > 0.
    Empty voxels are transparent whatever the transfer function. Only the arrays the image
    holds are offered (a ``.mhd`` or a bare array: ``shade`` alone).
Foreign images
    Shade outside [0, 1] (a volume not written by ao4d: CT numbers, densities) is mapped
    linearly from its finite range ``[lo, hi]`` onto [0, 1] (``ranges["shade"] = (lo, hi)``;
    voxels at ``lo`` are empty, as shade 0 is), and the image carries a note saying so
    (:attr:`ImageData.notes`; the page's writers warn with :class:`ImageRangeWarning`).
Transfer function
    256 entries, entry ``q``: colour ``cmap(q / 255)`` (a matplotlib map, sampled at 256
    points), opacity ``opacity * clamp((q / 255 - lo) / (hi - lo), 0, 1)``, or ``opacity *
    [q / 255 >= lo]`` when ``hi <= lo`` (:func:`transfer_function`). With ``array="rgba"`` the
    colour is the voxel's own and the opacity is the ramp at the voxel's shade times its alpha.
Ray-march
    The camera is :func:`ao4d.browser.viewer.camera` of the frame (``c``, ``|h|``): pixel ``(i, j)``
    (x right, y down) casts the ray from the eye through its centre, direction
    ``normalize(forward + (i + 1/2 - W/2) / scale * right - (j + 1/2 - H/2) / scale * up)``.
    The ray is clipped to the box ``[-h + 2 h x0, -h + 2 h x1]`` (per axis, the state's
    ``x0 .. z1`` in [0, 1]); samples lie at ``t_k = t_in + (k + 1/2) dt`` for ``t_k < t_out``,
    ``dt = STEP * min(spacing)``, each taking its voxel's value (nearest: the voxel holding the
    point). The opacity ``a`` of the entry is corrected for the step,
    ``alpha = 1 - (1 - a) ** STEP``, and samples are composited front to back,
    ``C += (1 - A) alpha c``, ``A += (1 - A) alpha``, until ``A >= A_STOP``. The pixel is
    ``(C, A)``, premultiplied, over the page's background. Empty voxels add exactly nothing, so
    both sides start at the box of hit voxels (one sample early) and stop one sample past it,
    and the page also jumps over blocks of ``BLOCK^3`` voxels holding no hit voxel: the samples
    taken are still the ``t_k`` above, and the pixel the same.
State
    ``array, cmap, lo, hi, opacity, x0, x1, y0, y1, z0, z1, az, el, zoom``, in the URL fragment
    ``#array=shade&cmap=magma&lo=0&hi=0&opacity=1&x0=0&...&az=30&el=20&zoom=1``; the page
    exposes ``window.ao4d.setState / state / ready / stats / capture / bench``.

Examples
--------
>>> import ao4d, numpy as np, tempfile, pathlib
>>> shade = np.zeros((8, 8, 8), np.float32); shade[2:6, 2:6, 2:6] = 0.8
>>> with tempfile.TemporaryDirectory() as tmp:
...     page = view_image(shade, pathlib.Path(tmp) / "cube.html")
...     print(page.read_text()[:15])
<!DOCTYPE html>
>>> picture = reference_march(encode(shade), {"az": 0, "el": 0}, 32, 24)
>>> picture.shape, bool(picture[12, 16, 3] > 0.99), float(picture[0, 0, 3])
((24, 32, 4), True, 0.0)
"""

from __future__ import annotations

import base64
import json
import os
import warnings
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import as_real, check_bool, check_choice
from ..rendering.compositing import over
from ._page import b64_size, check_max_bytes, scene_json, template, wrap_degrees, write_page
from .viewer import HALF_FOV_DEG, MARGIN, ZOOM_RANGE, Camera, Frame, camera, merged_state

__all__ = [
    "ARRAYS",
    "CMAPS",
    "DEFAULT_STATE",
    "PRESETS",
    "STEP",
    "ImageData",
    "ImageRangeWarning",
    "encode",
    "full_state",
    "image_frame",
    "image_page_text",
    "load_image",
    "reference_march",
    "transfer_function",
    "view_image",
]

ARRAYS = ("rgba", "shade", "occlusion", "depth")
CMAPS = ("magma", "viridis", "inferno", "cividis", "gray", "coolwarm")
STEP = 0.5  # sample spacing in voxels (of the smallest spacing)
A_STOP = 0.995  # accumulated opacity at which a ray stops
MAX_STEPS = 8192  # the shader's loop bound
BLOCK = 8  # voxels per side of the blocks the page skips when they hold no hit voxel
MAX_BYTES = 150_000_000
# array = None: "rgba" when the image has colours, else "shade"
DEFAULT_STATE: dict[str, Any] = {
    "array": None,
    "cmap": "magma",
    "lo": 0.0,
    "hi": 0.0,
    "opacity": 1.0,
    "x0": 0.0,
    "x1": 1.0,
    "y0": 0.0,
    "y1": 1.0,
    "z0": 0.0,
    "z1": 1.0,
    "az": 30.0,
    "el": 20.0,
    "zoom": 1.0,
}
CLIPS = ("x0", "x1", "y0", "y1", "z0", "z1")
# transfer-function presets: the page's buttons (colour map and opacity ramp)
PRESETS: dict[str, dict[str, Any]] = {
    "surface": {"lo": 0.0, "hi": 0.0, "opacity": 1.0},
    "glass": {"lo": 0.0, "hi": 1.0, "opacity": 0.15},
    "bright": {"lo": 0.35, "hi": 0.8, "opacity": 1.0},
    "cloud": {"lo": 0.0, "hi": 1.0, "opacity": 0.04},
}
_TEMPLATE = "image_page.html"
# shade this far outside [0, 1] is round-off of ao4d's own (1 - A with A = -1e-16), not foreign
_SHADE_SLACK = 1e-6


# --------------------------------------------------------------------------- the image


class ImageRangeWarning(UserWarning):
    """An image's shade lies outside [0, 1] and is shown mapped from its own range."""


@dataclass(frozen=True)
class ImageData:
    """A 3D image as the page holds it: 8-bit arrays, the hit mask, and where the voxels sit.

    Attributes
    ----------
    scalars : (nx, ny, nz, 4) uint8
        Quantised ``shade``, ``occlusion``, ``depth`` and 255 where hit, 0 where empty.
    colors : (nx, ny, nz, 4) uint8 or None
        The voxels' own RGBA (``RenderResult.rgba8``), when the image has them.
    spacing : (3,) float64
    origin : (3,) float64
        Centre of voxel (0, 0, 0).
    ranges : dict
        ``{"shade": (lo, hi), "occlusion": ..., "depth": ...}``: the values ``q = 0`` and
        ``q = 255`` stand for.
    name : str
    present : tuple of str, optional
        The arrays the image holds, of :data:`ARRAYS` (None: every array, ``rgba`` when
        ``colors`` is given).
    notes : tuple of str
        What was done to show the image (foreign shade mapped from its range).
    """

    scalars: np.ndarray
    colors: np.ndarray | None
    spacing: np.ndarray
    origin: np.ndarray
    ranges: dict
    name: str = "image"
    present: tuple[str, ...] | None = None
    notes: tuple[str, ...] = ()

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.scalars.shape[:3])  # type: ignore[return-value]

    @property
    def hit(self) -> np.ndarray:
        return self.scalars[..., 3] > 0

    @property
    def arrays(self) -> tuple[str, ...]:
        """The arrays the page offers: those the image holds, in :data:`ARRAYS`' order."""
        every = ARRAYS if self.colors is not None else ARRAYS[1:]
        return every if self.present is None else tuple(a for a in every if a in self.present)


def _quantise(v: np.ndarray) -> np.ndarray:
    return np.floor(255.0 * np.clip(v, 0.0, 1.0) + 0.5).astype(np.uint8)


def encode(image: Any, *, name: str | None = None) -> ImageData:
    """The page's 8-bit form of an image (see the module conventions).

    Parameters
    ----------
    image : RenderResult, path to a .vti / .mhd file, ImageData, or (nx, ny, nz) array_like
        A bare array is taken as ``shade`` (voxels with shade > 0 hit), spacing 1, origin 0.
    name : str, optional
        Label on the page (default: the file stem, or "image").

    Returns
    -------
    ImageData
        The image as the page holds it (``image`` itself when it is one already).
    """
    if isinstance(image, ImageData):
        return image
    if isinstance(image, (str, os.PathLike)):
        return load_image(image)
    if all(
        hasattr(image, k) for k in ("shade", "depth", "object_id", "occlusion", "rgba8", "geometry")
    ):  # a RenderResult
        geo = image.geometry
        spacing = np.broadcast_to(np.asarray(geo.spacing, dtype=np.float64), (3,)).copy()
        return _encode_arrays(
            np.asarray(image.shade),
            depth=np.asarray(image.depth),
            occlusion=np.asarray(image.occlusion),
            hit=np.asarray(image.object_id) >= 0,
            colors=np.asarray(image.rgba8),
            spacing=spacing,
            origin=np.asarray(geo.origin, dtype=np.float64),
            name=name or "image",
        )
    try:
        shade = np.asarray(image)
    except Exception:  # pragma: no cover - numpy refuses the object
        shade = None
    if shade is None or shade.ndim != 3 or shade.dtype.kind not in "iufb":
        raise TypeError(
            "`image` must be a RenderResult, a path to a .vti or .mhd file, or a 3D "
            f"array of shade values; got {type(image).__name__}"
            + (f" of shape {shade.shape}" if shade is not None and shade.ndim else "")
        )
    shade = shade.astype(np.float64)
    return _encode_arrays(
        shade,
        depth=None,
        occlusion=None,
        hit=None,
        colors=None,
        spacing=np.ones(3),
        origin=np.zeros(3),
        name=name or "image",
    )


def _shade_range(shade: np.ndarray, name: str) -> tuple[np.ndarray, tuple[float, float], tuple[str, ...]]:
    """Shade in [0, 1] as the page shows it, the values 0 and 1 stand for, and the notes: a
    foreign image's shade outside [0, 1] is mapped linearly from its finite range."""
    finite = np.isfinite(shade)
    if not finite.any():
        return np.zeros_like(shade), (0.0, 1.0), ()
    lo, hi = float(shade[finite].min()), float(shade[finite].max())
    if lo >= -_SHADE_SLACK and hi <= 1.0 + _SHADE_SLACK:  # ao4d's own (round-off clipped)
        return np.where(finite, shade, 0.0), (0.0, 1.0), ()
    if hi > lo:
        rel = np.where(finite, (shade - lo) / (hi - lo), 0.0)
        empty = f"voxels at {lo:g} are empty"
    else:
        rel = np.where(finite, 1.0, 0.0)
        empty = "every voxel is drawn"
    note = (
        f"`image` {name}: shade spans [{lo:g}, {hi:g}], outside the [0, 1] of ao4d's images "
        f"(not written by ao4d?); shown mapped linearly from [{lo:g}, {hi:g}] onto [0, 1] "
        f"({empty})"
    )
    return rel, (lo, hi), (note,)


def _encode_arrays(shade, *, depth, occlusion, hit, colors, spacing, origin, name, present=None) -> ImageData:
    if shade.ndim != 3 or min(shade.shape) < 1:
        raise ValueError(f"`image` must be a 3D image with at least one voxel, got shape {shade.shape}")
    if not np.isfinite(spacing).all() or (spacing <= 0).any():
        raise ValueError(f"`image` spacing must be positive, got {spacing.tolist()}")
    if not np.isfinite(origin).all():
        raise ValueError(f"`image` origin must be finite, got {origin.tolist()}")
    shade, shade_range, notes = _shade_range(shade, name)
    if hit is None:
        hit = np.isfinite(depth) if depth is not None else shade > 0
    hit = np.asarray(hit, dtype=bool)
    scalars = np.zeros(shade.shape + (4,), dtype=np.uint8)
    scalars[..., 0] = _quantise(shade)
    if occlusion is not None:
        occ = np.where(hit & np.isfinite(occlusion), occlusion, 0.0)
        scalars[..., 1] = _quantise(occ)
    d_lo, d_hi = 0.0, 0.0
    if depth is not None and hit.any():
        d = np.asarray(depth, dtype=np.float64)[hit]
        d = d[np.isfinite(d)]
        if d.size:
            d_lo, d_hi = float(d.min()), float(d.max())
            span = d_hi - d_lo if d_hi > d_lo else 1.0
            rel = np.where(hit & np.isfinite(depth), (np.asarray(depth, np.float64) - d_lo) / span, 0.0)
            scalars[..., 2] = _quantise(rel)
    scalars[..., 3] = np.where(hit, 255, 0)
    if colors is not None:
        colors = np.ascontiguousarray(colors, dtype=np.uint8)
        if colors.shape != shade.shape + (4,):
            raise ValueError(f"`image` rgba must have shape {shade.shape + (4,)}, got {colors.shape}")
        colors = np.where(hit[..., None], colors, 0).astype(np.uint8)
    if present is None:
        present = (
            ("shade",)
            + (("occlusion",) if occlusion is not None else ())
            + (("depth",) if depth is not None else ())
            + (("rgba",) if colors is not None else ())
        )
    return ImageData(
        scalars,
        colors,
        np.asarray(spacing, np.float64),
        np.asarray(origin, np.float64),
        {"shade": shade_range, "occlusion": (0.0, 1.0), "depth": (d_lo, d_hi)},
        name,
        tuple(present),
        notes,
    )


def load_image(path: str | os.PathLike) -> ImageData:
    """Read a ``.vti`` (every array ``ao4d render`` writes) or ``.mhd`` (shade) image.

    Parameters
    ----------
    path : path-like
        A file written by ``ao4d render`` / :meth:`RenderResult.save`; a ``.vti`` needs the
        ``shade`` array (or holds one array, taken as shade); ``depth``, ``occlusion``,
        ``object_id`` and ``rgba`` are used when present.

    Returns
    -------
    ImageData
        The image in the page's 8-bit form.

    Raises
    ------
    ValueError
        If the extension is neither .vti nor .mhd, or the file lacks the arrays it needs.
    FileNotFoundError
        If there is no such file.
    """
    from ..io.volumes import read_mhd, read_vtk_image

    p = Path(path)
    suffix = check_choice(p.suffix.lower(), "image extension", (".vti", ".mhd"))
    if not p.is_file():
        raise FileNotFoundError(f"`image`: no such file: {p}")
    if suffix == ".mhd":
        vol = read_mhd(p)
        return _encode_arrays(
            np.asarray(vol.data, np.float64),
            depth=None,
            occlusion=None,
            hit=None,
            colors=None,
            spacing=np.asarray(vol.spacing, np.float64),
            origin=np.asarray(vol.origin, np.float64),
            name=p.stem,
        )
    grid = read_vtk_image(p, "image")  # an unreadable or truncated file is named as such
    dims = tuple(int(n) for n in grid.dimensions)
    names = list(grid.point_data.keys())

    def get(key: str) -> np.ndarray | None:
        if key not in names:
            return None
        flat = np.asarray(grid.point_data[key])
        return np.ascontiguousarray(flat.reshape(dims + flat.shape[1:], order="F"))

    shade = get("shade")
    if shade is None:
        if len(names) != 1:
            raise ValueError(
                f"`image` {p.name} has no 'shade' array, and more than one other "
                f"(has {names}): which to show is unclear"
            )
        shade = get(names[0])
    if shade.ndim != 3:
        raise ValueError(f"`image` {p.name}: shade must be one value per voxel, got shape {shade.shape}")
    ids, rgba = get("object_id"), get("rgba")
    if rgba is not None and (rgba.ndim != 4 or rgba.shape[3] != 4):
        rgba = None
    if rgba is not None and rgba.dtype != np.uint8:
        rgba = _quantise(np.asarray(rgba, np.float64))
    return _encode_arrays(
        np.asarray(shade, np.float64),
        depth=get("depth"),
        occlusion=get("occlusion"),
        hit=None if ids is None else ids >= 0,
        colors=rgba,
        spacing=np.asarray(grid.spacing, np.float64),
        origin=np.asarray(grid.origin, np.float64),
        name=p.stem,
    )


def image_frame(image: ImageData) -> Frame:
    """The page's frame: centre of the image's box and its half diagonal (3D).

    Parameters
    ----------
    image : ImageData
        The image (:func:`encode`).

    Returns
    -------
    Frame
        Centre and radius the page's camera orbits.
    """
    half = 0.5 * image.spacing * np.asarray(image.shape, np.float64)
    center = image.origin + half - 0.5 * image.spacing
    return Frame(center, float(np.linalg.norm(half)))


# --------------------------------------------------------------------------- state and TF


def full_state(state: Mapping[str, Any] | None = None, *, image: ImageData | None = None) -> dict:
    """Complete and check a view state of the image page, the way the page does.

    Parameters
    ----------
    state : mapping, optional
        Any of :data:`DEFAULT_STATE`'s keys. ``array`` in {"rgba", "shade", "occlusion",
        "depth"} (default "rgba" when the image has colours, else "shade"), ``cmap`` in
        :data:`CMAPS`, ``lo, hi`` in [0, 1], ``opacity`` in [0, 1], clip planes ``x0 <= x1``,
        ``y0 <= y1``, ``z0 <= z1`` in [0, 1], ``az, el, zoom`` as in :func:`ao4d.browser.viewer.full_state`.
    image : ImageData, optional
        Checks that ``array`` is one the image has.

    Returns
    -------
    state : dict
        Every key of :data:`DEFAULT_STATE`, checked.

    Raises
    ------
    ValueError
        If a key is unknown or a value out of range.
    """
    out = merged_state(state, DEFAULT_STATE, "{'array': 'shade', 'az': 40}")
    arrays = image.arrays if image is not None else ARRAYS
    if out["array"] is None:
        out["array"] = arrays[0]
    if image is not None and out["array"] in ARRAYS and out["array"] not in arrays:
        raise ValueError(
            f"`state['array']` {out['array']!r} is not in the image {image.name!r}, "
            f"which holds {', '.join(map(repr, arrays))} (a .mhd file or a bare array "
            "holds shade only)"
        )
    out["array"] = check_choice(out["array"], "state['array']", arrays)
    out["cmap"] = check_choice(out["cmap"], "state['cmap']", CMAPS)
    for key in ("lo", "hi", "opacity", *CLIPS):
        out[key] = as_real(out[key], f"state['{key}']", ge=0.0, le=1.0)
    for a, b in (("x0", "x1"), ("y0", "y1"), ("z0", "z1")):
        if out[a] > out[b]:
            raise ValueError(f"`state['{a}']` must be <= `state['{b}']`, got {out[a]} > {out[b]}")
    out["az"] = wrap_degrees(as_real(out["az"], "state['az']"))
    out["el"] = min(90.0, max(-90.0, as_real(out["el"], "state['el']")))
    out["zoom"] = as_real(out["zoom"], "state['zoom']", ge=ZOOM_RANGE[0], le=ZOOM_RANGE[1])
    return out


def _cmap_table(name: str) -> np.ndarray:
    """(256, 3) uint8: the colour map at q / 255."""
    import matplotlib

    rgba = matplotlib.colormaps[name](np.arange(256) / 255.0)
    return np.floor(255.0 * np.asarray(rgba)[:, :3] + 0.5).astype(np.uint8)


def transfer_function(state: Mapping[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The page's transfer function: ``(colours (256, 3) float64 in [0, 1], opacity (256,))``.

    Colours are the 8-bit colour map the page holds, divided by 255; opacity is the ramp of the
    module conventions (before the step correction).

    Parameters
    ----------
    state : mapping, optional
        A view state (:func:`full_state`).

    Returns
    -------
    colours : (256, 3) float64
        The colour map, in [0, 1].
    opacity : (256,) float64
        The opacity ramp.
    """
    st = full_state(state)
    s = np.arange(256) / 255.0
    lo, hi = st["lo"], st["hi"]
    if hi > lo:
        ramp = np.clip((s - lo) / (hi - lo), 0.0, 1.0)
    else:
        ramp = (s >= lo).astype(np.float64)
    return _cmap_table(st["cmap"]) / 255.0, st["opacity"] * ramp


# --------------------------------------------------------------------------- the reference


def _rays(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) unit directions through the pixel centres and the eye, in page coordinates."""
    i = np.arange(cam.width) + 0.5 - cam.width / 2.0
    j = np.arange(cam.height) + 0.5 - cam.height / 2.0
    d = (
        cam.forward[None, None, :]
        + (i[None, :, None] / cam.scale) * cam.right
        - (j[:, None, None] / cam.scale) * cam.up
    )
    return d / np.linalg.norm(d, axis=2, keepdims=True), cam.eye - cam.target


def reference_march(image: Any, state: Mapping[str, Any] | None, width: int, height: int) -> np.ndarray:
    """The page's ray-march in numpy, sample for sample (see the module conventions).

    Parameters
    ----------
    image : ImageData, RenderResult, path or array
        As for :func:`view_image` (:func:`encode` is applied).
    state : mapping or None
        The page's state (:func:`full_state`).
    width, height : int
        Canvas size in pixels (``window.ao4d.stats().canvas``).

    Returns
    -------
    picture : (height, width, 4) float64
        Premultiplied colour and accumulated opacity per pixel, rows from the top (what
        ``window.ao4d.capture()`` reads back, divided by 255).
    """
    data = encode(image)
    st = full_state(state, image=data)
    frame = image_frame(data)
    cam = camera({k: st[k] for k in ("az", "el", "zoom")}, width, height, frame=frame)
    dirs, eye = _rays(cam)
    dirs = dirs.reshape(-1, 3)
    n = np.asarray(data.shape, np.float64)
    half = 0.5 * data.spacing * n
    clip_lo = np.array([st["x0"], st["y0"], st["z0"]])
    clip_hi = np.array([st["x1"], st["y1"], st["z1"]])
    lo, hi = -half + 2.0 * half * clip_lo, -half + 2.0 * half * clip_hi
    inv = 1.0 / np.where(np.abs(dirs) < 1e-9, 1e-9, dirs)  # the shader's guard
    ta, tb = (lo - eye) * inv, (hi - eye) * inv
    t_in = np.maximum(np.minimum(ta, tb).max(axis=1), 0.0)
    t_out = np.maximum(ta, tb).min(axis=1)
    dt = STEP * float(data.spacing.min())
    box = _hit_box(data)
    if box is None:
        return np.zeros((cam.height, cam.width, 4))
    hit_lo = -half + data.spacing * np.asarray(box[0])
    hit_hi = -half + data.spacing * np.asarray(box[1])
    ha, hb = (hit_lo - eye) * inv, (hit_hi - eye) * inv
    h_in, h_out = np.minimum(ha, hb).max(axis=1), np.maximum(ha, hb).min(axis=1)
    t_out = np.minimum(t_out, h_out + dt)
    first = np.maximum(0, np.ceil((h_in - t_in) / dt - 0.5).astype(np.int64) - 1)
    colours, ramp = transfer_function(st)
    mode = st["array"]
    channel = {"shade": 0, "occlusion": 1, "depth": 2, "rgba": 0}[mode]
    out = np.zeros((len(dirs), 4))
    active = np.flatnonzero((t_out > t_in) & (h_out > h_in))
    shape = np.asarray(data.shape)
    for k in range(MAX_STEPS):
        if active.size == 0:
            break
        t = t_in[active] + (first[active] + k + 0.5) * dt
        inside = t < t_out[active]
        active, t = active[inside], t[inside]
        if active.size == 0:
            break
        p = eye + t[:, None] * dirs[active]
        idx = np.clip(np.floor((p + half) / data.spacing).astype(np.int64), 0, shape - 1)
        texel = data.scalars[idx[:, 0], idx[:, 1], idx[:, 2]]
        q = texel[:, channel]
        if mode == "rgba":
            own = data.colors[idx[:, 0], idx[:, 1], idx[:, 2]] / 255.0
            c, a = own[:, :3], ramp[q] * own[:, 3]
        else:
            c, a = colours[q], ramp[q] * (texel[:, 3] / 255.0)
        alpha = 1.0 - (1.0 - a) ** STEP
        acc = out[active]
        over(acc, c, alpha)
        out[active] = acc
        active = active[acc[:, 3] < A_STOP]
    return out.reshape(cam.height, cam.width, 4)


# --------------------------------------------------------------------------- the page


def _histogram(data: ImageData) -> dict[str, list[int]]:
    hit = data.hit
    out = {}
    for name, ch in (("shade", 0), ("occlusion", 1), ("depth", 2)):
        out[name] = np.bincount(data.scalars[..., ch][hit], minlength=256).astype(int).tolist()
    return out


def _hit_box(data: ImageData) -> list[list[int]] | None:
    """Voxel index range ``[lo, hi)`` per axis of the hit voxels (None when nothing was hit)."""
    hit = data.hit
    if not hit.any():
        return None
    box = []
    for axis in range(3):
        any_hit = hit.any(axis=tuple(a for a in range(3) if a != axis))
        idx = np.flatnonzero(any_hit)
        box.append((int(idx[0]), int(idx[-1]) + 1))
    return [[b[0] for b in box], [b[1] for b in box]]


def _blocks(data: ImageData) -> np.ndarray:
    """(bx, by, bz) uint8: 255 where a block of BLOCK^3 voxels holds a hit voxel, else 0."""
    hit = data.hit
    shape = [-(-n // BLOCK) for n in hit.shape]
    padded = np.zeros([b * BLOCK for b in shape], dtype=bool)
    padded[: hit.shape[0], : hit.shape[1], : hit.shape[2]] = hit
    occupied = padded.reshape(shape[0], BLOCK, shape[1], BLOCK, shape[2], BLOCK).any(axis=(1, 3, 5))
    return np.where(occupied, 255, 0).astype(np.uint8)


def image_page_text(
    image: Any,
    *,
    state: Mapping[str, Any] | None = None,
    title: str | None = None,
    compress: bool = True,
    max_bytes: int = MAX_BYTES,
) -> str:
    """The page of :func:`view_image` as a string (for notebooks and the demo's result page).

    The same text :func:`view_image` writes to its file.

    Parameters
    ----------
    image : RenderResult, path to a .vti / .mhd file, ImageData, or (nx, ny, nz) array_like
        The image to show, as for :func:`view_image` (or already encoded, :func:`encode`).
    state : mapping, optional
        As for :func:`view_image`.
    title : str, optional
        As for :func:`view_image`.
    compress : bool
        As for :func:`view_image`.
    max_bytes : int
        As for :func:`view_image`.

    Returns
    -------
    str
        The page's HTML.

    Raises
    ------
    ValueError
        A bad image, state or option; a page over ``max_bytes``.
    TypeError
        If ``title`` is not a string.
    """
    check_bool(compress, "compress")
    check_max_bytes(max_bytes)
    if title is not None and not isinstance(title, str):
        raise TypeError(f"`title` must be a string, got {type(title).__name__}")
    data = encode(image)
    st = full_state(state, image=data)
    for note in data.notes:
        warnings.warn(note, ImageRangeWarning, stacklevel=2)
    raw = data.scalars.nbytes + (0 if data.colors is None else data.colors.nbytes)
    if not compress and b64_size(raw) > max_bytes:
        raise ValueError(f"the page would be about {b64_size(raw) / 1e6:.0f} MB, over `max_bytes`")
    blobs: list[bytes] = []

    def blob(arr: np.ndarray) -> dict:
        # WebGL's 3D textures run x fastest, then y, then z: (nz, ny, nx[, 4]) in C order
        raw_bytes = np.ascontiguousarray(np.swapaxes(arr, 0, 2)).tobytes()
        data_bytes, encoding = (zlib.compress(raw_bytes, 1), "deflate") if compress else (raw_bytes, "raw")
        blobs.append(data_bytes)
        return {"id": f"ao4d-blob-{len(blobs) - 1}", "encoding": encoding, "nbytes": len(raw_bytes)}

    tables = {name: base64.b64encode(_cmap_table(name).tobytes()).decode("ascii") for name in CMAPS}
    scene = {
        "format": "ao4d-image/1",
        "title": title or data.name,
        "shape": list(data.shape),
        "spacing": data.spacing.tolist(),
        "origin": data.origin.tolist(),
        "center": image_frame(data).center.tolist(),
        "radius": image_frame(data).radius,
        "arrays": list(data.arrays),
        "ranges": {k: list(v) for k, v in data.ranges.items()},
        "notes": list(data.notes),
        "hits": int(data.hit.sum()),
        "histogram": _histogram(data),
        "state": st,
        "presets": PRESETS,
        "cmaps": tables,
        "step": STEP,
        "a_stop": A_STOP,
        "max_steps": MAX_STEPS,
        "camera": {"half_fov_deg": HALF_FOV_DEG, "margin": MARGIN, "zoom_range": list(ZOOM_RANGE)},
        "hit_box": _hit_box(data),
        "block": BLOCK,
        "blocks_shape": list(_blocks(data).shape),
        "blocks": blob(_blocks(data)),
        "scalars": blob(data.scalars),
        "colors": None if data.colors is None else blob(data.colors),
    }
    head, middle, tail = template(_TEMPLATE)
    parts = [head, scene_json(scene), middle]
    for k, b in enumerate(blobs):
        parts.append(f'<script type="application/octet-stream" id="ao4d-blob-{k}">')
        parts.append(base64.b64encode(b).decode("ascii"))
        parts.append("</script>\n")
    parts.append(tail)
    text = "".join(parts)
    if len(text) > max_bytes:
        raise ValueError(f"the page would be {len(text) / 1e6:.0f} MB, over `max_bytes` = {max_bytes / 1e6:.0f} MB")
    return text


def view_image(
    image: Any,
    path: str | os.PathLike,
    *,
    state: Mapping[str, Any] | None = None,
    title: str | None = None,
    compress: bool = True,
    max_bytes: int = MAX_BYTES,
) -> Path:
    """Write one self-contained HTML page that ray-marches a 3D image on the GPU.

    Parameters
    ----------
    image : RenderResult, path to a .vti / .mhd file, or (nx, ny, nz) array_like
        The 4D camera's image (:func:`ao4d.render`, ``ao4d render``); a bare array is shade.
    path : path-like
        The HTML file, ending in .html or .htm (written atomically; checked before any work).
    state : mapping, optional
        Initial view (:func:`full_state`); the URL fragment overrides it.
    title : str, optional
        The page's title (default: the image's name).
    compress : bool
        zlib-compress the voxels (inflated by the browser's ``DecompressionStream``).
    max_bytes : int
        Refuse pages larger than this (default 150 MB).

    Returns
    -------
    path : Path
        The page written (``path``, checked before any work).

    Raises
    ------
    ValueError
        A bad image, state or option; a page over ``max_bytes``.
    """
    return write_page(
        path, lambda: image_page_text(image, state=state, title=title, compress=compress, max_bytes=max_bytes)
    )


def _state_fragment(state: Mapping[str, Any]) -> str:
    """The URL fragment the page writes for ``state`` (used by the tests and the bench)."""
    st = full_state(state)
    return "#" + "&".join(f"{k}={st[k]}" for k in DEFAULT_STATE)


def page_info(text: str) -> dict:
    """The scene JSON object of an image page's text (for tests and tools)."""
    for tag in (
        '<script type="application/json" id="ao4d-scene">',
        '<script type="application/json" id="ao4d-image">',
    ):  # the latter: older image pages
        if tag in text:
            start = text.index(tag) + len(tag)
            return json.loads(text[start : text.index("</script>", start)])  # "<\\/" is JSON for "</"
    raise ValueError("`text` is not an ao4d image page: it holds no scene")
