"""The browser viewer: one self-contained WebGL2 page that slices 4D tetrahedral meshes on the GPU.

:func:`view` writes an HTML file holding the page (``ao4d/browser/viewer_page.html``: HTML, JavaScript,
GLSL, in the frame and with the script every ao4d page shares, :mod:`ao4d.browser._page`) and the meshes (float32 vertices, uint32 simplices, float32 AO; zlib-compressed and
base64-encoded, inflated in the browser by ``DecompressionStream``). It needs no network and
opens from ``file://``. Scenes too large to inline are served by :func:`serve` on 127.0.0.1.

Every frame, the vertex shader turns each tetrahedron's four 4D vertices (read from a data
texture, one instance per tetrahedron) and cuts it by the hyperplane: 0, 1 or 2 triangles by
marching tetrahedra, the same table and the same interpolation as :meth:`SimplexMesh.slice`.
Moving the hyperplane or turning the object costs the CPU nothing.

Why this stays one module: everything here is a convention the page's JavaScript mirrors (state,
rotation, camera, cut table, chunk layout, culling) or the writer of the data laid out by those
conventions; keeping them side by side is what lets the tests hold the two sides equal.

Conventions (the page and this module agree exactly)
----------------------------------------------------
Scene frame
    ``c`` = centre of the axis-aligned box of every vertex of every object (each moved by its
    ``offsets`` entry), unless ``center`` is given; ``r`` = largest distance of a vertex from
    ``c``. Every rotation about ``c`` keeps the scene in the ball (c, r), so the 3D camera,
    which frames that ball, never changes with ``w`` or the angles (:func:`scene_frame`).
4D placement and rotation
    ``x' = R (x + offset - c) + c`` with
    ``R = R_zw(zw) R_yw(yw) R_yz(yz) R_xw(xw) R_xz(xz) R_xy(xy)`` (``xy`` applied first).
    ``R_ab(t)`` turns axis a towards axis b by t degrees: ``e_a -> cos t e_a + sin t e_b``,
    ``e_b -> -sin t e_a + cos t e_b`` (:func:`rotation`). 3D meshes are only moved by ``offset``.
Page coordinates
    The page works relative to ``c``: it receives float32 of ``x + offset - c``, formed in
    float64 here (:func:`_centred`), turns them by ``R``, and cuts at ``w - c_w`` (formed in
    JavaScript's doubles); its camera targets the origin. A scene far from the origin (scanner
    millimetres, a time axis with an offset) therefore keeps float32's precision relative to
    its radius, as one at the origin does.
Hyperplane
    ``x'_w = w`` (w in scene units); a slice point's 3D position is ``(x'_x, x'_y, x'_z)``
    (:func:`slice_for_state` reproduces the page's slice with :meth:`SimplexMesh.slice`).
3D camera (y up, perspective)
    Target ``c_xyz``; direction to the eye ``b = (cos el sin az, sin el, cos el cos az)``;
    distance ``D = 1.1 r / sin 15 deg``; screen up ``u = (-sin el sin az, cos el,
    -sin el cos az)``, right = ``-b x u``. The shorter side of the canvas spans
    ``2 atan(tan(15 deg) / zoom)``. Pixel x grows to the right and pixel y downwards, pixel
    (i, j) covering ``[i, i+1) x [j, j+1)`` (:func:`project`).
Shading
    ``colour = ramp(1 - AO) * (0.3 + 0.7 max(n . l, 0))`` with AO = ``point_data["ao"]``
    (1 = occluded) interpolated along the cut edges, ``n`` the slice triangle's normal turned to
    the viewer (exactly the x, y, z part of the turned tetrahedron's 4D normal, computed in the
    vertex shader) and ``l`` a light above-left of the eye; ``light=0`` drops the Lambert factor.
    Objects without AO are shaded as open (``1 - AO = 1``). One object: the ``magma`` colour
    map; several: a ramp from dark to light of each object's colour.
State
    ``w, xy, xz, xw, yz, yw, zw`` (4D only), ``az, el, zoom``, ``light`` (0 or 1), ``hide``
    (object indices), in the URL fragment ``#w=0.3&xw=90&az=30&el=20&zoom=1``; the page
    exposes ``window.ao4d.setState / state / ready / stats / capture / bench``.

Examples
--------
>>> import ao4d, tempfile, pathlib
>>> mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (8,) * 4, (-1.3, 1.3))
>>> with tempfile.TemporaryDirectory() as tmp:
...     page = ao4d.view(mesh, pathlib.Path(tmp) / "sphere.html")
...     print(page.read_text()[:15])
<!DOCTYPE html>
>>> tri = ao4d.browser.viewer.slice_for_state(mesh, {"w": 0.5, "xw": 30})
>>> bool(abs(np.linalg.norm(tri.vertices, axis=1).max() - np.sqrt(1 - 0.25)) < 0.1)
True
"""

from __future__ import annotations

import base64
import http.server
import inspect
import math
import os
import threading
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import as_array, as_real, check_bool, check_choice
from ..slicing import SLICE_CASES
from ._page import b64_size, check_max_bytes, scene_json, template, wrap_degrees, write_page

if TYPE_CHECKING:  # pragma: no cover
    import trimesh

    from ..mesh import SimplexMesh

__all__ = [
    "ANGLES",
    "DEFAULT_STATE",
    "Camera",
    "Frame",
    "ViewServer",
    "camera",
    "cut_table",
    "full_state",
    "page_text",
    "project",
    "rotation",
    "scene_frame",
    "serve",
    "slice_for_state",
    "split_objects",
    "transform",
    "view",
]

ANGLES = ("xy", "xz", "xw", "yz", "yw", "zw")
_PLANES = {"xy": (0, 1), "xz": (0, 2), "xw": (0, 3), "yz": (1, 2), "yw": (1, 3), "zw": (2, 3)}
# w = None means the centre of the scene in w
DEFAULT_STATE: dict[str, Any] = {
    "w": None,
    **{a: 0.0 for a in ANGLES},
    "az": 30.0,
    "el": 20.0,
    "zoom": 1.0,
    "light": 1,
    "hide": (),
}
_NUMBER_KEYS = ("w", *ANGLES, "az", "el", "zoom")

HALF_FOV_DEG = 15.0  # half the view angle across the canvas' shorter side at zoom 1
MARGIN = 1.1  # the bounding ball's angular radius is asin(sin(15 deg) / MARGIN)
ZOOM_RANGE = (0.05, 50.0)
AMBIENT = 0.3
MAX_BYTES = 150_000_000
CHUNK = 256  # tetrahedra per culling chunk (the page skips chunks the hyperplane misses)
# Tableau 10: object colours when several meshes are shown
PALETTE = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac")
_TEMPLATE = "viewer_page.html"


# --------------------------------------------------------------------------- state and geometry


@dataclass(frozen=True)
class Frame:
    """The scene's bounding ball: rotation centre and camera target ``center``, radius ``radius``.

    Attributes
    ----------
    center : (d,) float64
        Rotation centre and camera target.
    radius : float
        Largest distance of a vertex from ``center``.
    """

    center: np.ndarray  # (d,) float64
    radius: float

    @property
    def dim(self) -> int:
        return int(self.center.shape[0])


def scene_frame(meshes: Any, *, center: Any = None, offsets: Any = None) -> Frame:
    """The bounding ball the page frames and rotates about (see the module conventions).

    Parameters
    ----------
    meshes : SimplexMesh, trimesh.Trimesh, (vertices, simplices), path to an .npz mesh, or a sequence of them
        As for :func:`view`.
    center : (d,) array_like, optional
        Rotation centre and camera target (default: centre of the scene's bounding box).
    offsets : (n_meshes, d) array_like, optional
        Translation of each mesh in the scene (default 0).

    Returns
    -------
    frame : Frame
        ``center`` (d,) float64 and ``radius`` = largest distance of a vertex from it.
    """
    items = _as_meshes(meshes, None)
    return _frame([m for m, _ in items], center, _offsets(offsets, len(items), items[0][0].dim))


def _frame(meshes: list, center: Any, offsets: np.ndarray) -> Frame:
    d = meshes[0].dim
    lo = np.min([np.asarray(m.vertices).min(axis=0) + o for m, o in zip(meshes, offsets)], axis=0)
    hi = np.max([np.asarray(m.vertices).max(axis=0) + o for m, o in zip(meshes, offsets)], axis=0)
    if center is None:
        c = 0.5 * (lo + hi)
    else:
        c = as_array(center, "center", ndim=1, shape_tail=(d,), dtype=np.float64, finite=True)
    radius = max(float(np.linalg.norm(np.asarray(m.vertices) + o - c, axis=1).max()) for m, o in zip(meshes, offsets))
    if not radius > 0.0:
        raise ValueError("`meshes` span a single point: nothing to frame")
    return Frame(np.array(c, dtype=np.float64), radius)


def merged_state(state: Mapping[str, Any] | None, defaults: Mapping[str, Any], example: str) -> dict:
    """``defaults`` updated by the non-None entries of a page's ``state``; a non-mapping or an
    unknown key is an error naming ``state`` (``example``: a valid one, for the message)."""
    if state is not None and not isinstance(state, Mapping):
        hint = " (a URL fragment such as 'w=0.3' goes after the page's #)" if isinstance(state, str) else ""
        raise TypeError(f"`state` must be a mapping such as {example}, got {type(state).__name__} {state!r}{hint}")
    given = {} if state is None else dict(state)
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise ValueError(f"`state` has unknown key(s) {unknown}; known: {list(defaults)}")
    out = dict(defaults)
    out.update({k: v for k, v in given.items() if v is not None})
    return out


def full_state(state: Mapping[str, Any] | None = None, *, frame: Frame | None = None) -> dict:
    """Complete and check a view state the way the page does.

    Parameters
    ----------
    state : mapping, optional
        Any of ``w, xy, xz, xw, yz, yw, zw, az, el, zoom`` (numbers; angles in degrees),
        ``light`` (0/1 or bool) and ``hide`` (object indices). Missing keys take
        :data:`DEFAULT_STATE`; ``w`` defaults to the scene's centre in w (needs ``frame``).
    frame : Frame, optional
        The scene's frame (:func:`scene_frame`), for the default ``w``.

    Returns
    -------
    state : dict
        Angles wrapped into (-180, 180], ``el`` clamped to [-90, 90], ``light`` an int,
        ``hide`` a sorted tuple of ints.
    """
    out = merged_state(state, DEFAULT_STATE, "{'w': 0.3, 'xw': 90}")
    for key in _NUMBER_KEYS:
        if key == "w" and out[key] is None:
            out["w"] = float(frame.center[3]) if frame is not None and frame.dim == 4 else 0.0
            continue
        out[key] = as_real(out[key], f"state['{key}']")
    for key in (*ANGLES, "az"):
        out[key] = wrap_degrees(out[key])
    out["el"] = min(90.0, max(-90.0, out["el"]))
    lo, hi = ZOOM_RANGE
    out["zoom"] = as_real(out["zoom"], "state['zoom']", ge=lo, le=hi)
    light = out["light"]
    if isinstance(light, (bool, np.bool_)):
        light = int(light)
    out["light"] = int(check_choice(light, "state['light']", (0, 1)))
    hide = out["hide"]
    if isinstance(hide, (str, bytes)) or not isinstance(hide, (Sequence, np.ndarray, set, frozenset)):
        raise TypeError(f"`state['hide']` must be a sequence of object indices, got {hide!r}")
    if any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) or i < 0 for i in hide):
        raise ValueError(f"`state['hide']` must hold object indices >= 0, got {list(hide)}")
    out["hide"] = tuple(sorted({int(i) for i in hide}))
    return out


def rotation(state: Mapping[str, Any] | None = None) -> np.ndarray:
    """The page's 4D rotation ``R = R_zw R_yw R_yz R_xw R_xz R_xy`` (xy applied first).

    Parameters
    ----------
    state : mapping, optional
        Angles ``xy, xz, xw, yz, yw, zw`` in degrees (missing ones are 0).

    Returns
    -------
    R : (4, 4) float64
        Orthogonal, det 1; a point turns as ``R @ x``.

    Examples
    --------
    >>> np.round(rotation({"xw": 90}) @ [1, 0, 0, 0], 12)
    array([0., 0., 0., 1.])
    """
    st = full_state({k: v for k, v in (state or {}).items() if k in ANGLES})
    r = np.eye(4)
    for name in ANGLES:
        a, b = _PLANES[name]
        t = math.radians(st[name])
        g = np.eye(4)
        g[a, a] = g[b, b] = math.cos(t)
        g[b, a] = math.sin(t)
        g[a, b] = -math.sin(t)
        r = g @ r
    return r


def transform(points: Any, state: Mapping[str, Any] | None = None, *, frame: Frame, offset: Any = None) -> np.ndarray:
    """Scene positions ``R (x + offset - c) + c`` of 4D points, as the page turns them.

    Parameters
    ----------
    points : (N, 4) array_like
        4D points of the object.
    state : mapping, optional
        The page's state (:func:`full_state`).
    frame : Frame
        The scene's frame (:func:`scene_frame`).
    offset : (4,) array_like, optional
        The object's offset in the scene.

    Returns
    -------
    turned : (N, 4) float64
        The points as the page places them.
    """
    x = as_array(points, "points", ndim=2, shape_tail=(4,), dtype=np.float64, finite=True)
    if frame.dim != 4:
        raise ValueError(f"`frame` must be a 4D scene's frame, got dimension {frame.dim}")
    o = (
        np.zeros(4)
        if offset is None
        else as_array(offset, "offset", ndim=1, shape_tail=(4,), dtype=np.float64, finite=True)
    )
    c = frame.center
    return (x + o - c) @ rotation(state).T + c


def slice_for_state(
    mesh: Any, state: Mapping[str, Any] | None = None, *, frame: Frame | None = None, offset: Any = None
) -> trimesh.Trimesh:
    """The slice the page shows for ``state``, by :meth:`SimplexMesh.slice` in float64.

    Parameters
    ----------
    mesh : SimplexMesh, (vertices, simplices) or path
        A 4D mesh, in any form :func:`ao4d.mesh.as_mesh` takes, or an .npz file.
    state : mapping, optional
        The page's state (:func:`full_state`).
    frame : Frame, optional
        The page's scene frame (default: the frame of ``mesh`` alone, as in a one-mesh page).
    offset : (4,) array_like, optional
        The mesh's offset in the scene.

    Returns
    -------
    slice : trimesh.Trimesh
        Vertices in scene coordinates ``(x'_x, x'_y, x'_z)``, point data (``"ao"``) attached.
    """
    from ..mesh import SimplexMesh

    items = _as_meshes(mesh, None, name="mesh")
    if len(items) != 1:
        raise ValueError(f"`mesh` must be one mesh, got {len(items)}")
    m = items[0][0]
    if m.dim != 4:
        raise ValueError(f"`mesh` must be a 4D mesh, got dimension {m.dim}")
    if frame is None:
        frame = _frame([m], None, np.zeros((1, 4)))
    st = full_state(state, frame=frame)
    turned = SimplexMesh(
        transform(m.vertices, st, frame=frame, offset=offset),
        m.simplices,
        point_data={k: np.asarray(v) for k, v in m.point_data.items()},
    )
    return turned.slice([0.0, 0.0, 0.0, st["w"]], [0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """The page's 3D camera for one canvas size (see the module conventions).

    Attributes
    ----------
    eye, target : (3,) float64
        Camera position and the point it looks at.
    right, up, forward : (3,) float64
        Unit axes of the camera; ``forward`` points from the eye to the target.
    distance : float
        From the eye to the target.
    tan_half : float
        Tangent of half the view angle across the shorter side.
    scale : float
        Pixels per unit of x/z (camera coordinates) on the image plane.
    width, height : int
        Canvas size in pixels.
    near, far : float
        Clip distances along ``forward``.
    light : (3,) float64
        Unit vector towards the light: above-left of the eye.
    """

    eye: np.ndarray  # (3,)
    target: np.ndarray  # (3,)
    right: np.ndarray  # (3,) unit
    up: np.ndarray  # (3,) unit
    forward: np.ndarray  # (3,) unit, from the eye to the target
    distance: float
    tan_half: float  # tan of half the view angle across the shorter side
    scale: float  # pixels per unit of x/z (camera coordinates) on the image plane
    width: int
    height: int
    near: float
    far: float
    light: np.ndarray  # (3,) unit, towards the light: above-left of the eye


def camera(state: Mapping[str, Any] | None, width: int, height: int, *, frame: Frame) -> Camera:
    """The page's 3D camera for a ``width`` x ``height`` canvas.

    Depends only on ``az, el, zoom`` and the frame, never on ``w`` or the 4D angles.

    Parameters
    ----------
    state : mapping or None
        The page's state (:func:`full_state`).
    width, height : int
        Canvas size in pixels.
    frame : Frame
        The scene's frame (:func:`scene_frame`).

    Returns
    -------
    Camera
        The camera the page draws with.

    Raises
    ------
    ValueError
        If a size is not a positive integer or the state is bad.
    """
    st = full_state(state, frame=frame)
    w_px, h_px = _size(width, "width"), _size(height, "height")
    az, el = math.radians(st["az"]), math.radians(st["el"])
    back = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    up = np.array([-math.sin(el) * math.sin(az), math.cos(el), -math.sin(el) * math.cos(az)])
    forward = -back
    right = np.cross(forward, up)
    half = math.radians(HALF_FOV_DEG)
    distance = MARGIN * frame.radius / math.sin(half)
    target = np.array(frame.center[:3], dtype=np.float64)
    tan_half = math.tan(half) / st["zoom"]
    light = back + 0.45 * up - 0.3 * right
    return Camera(
        eye=target + distance * back,
        target=target,
        right=right,
        up=up,
        forward=forward,
        distance=distance,
        tan_half=tan_half,
        scale=min(w_px, h_px) / 2.0 / tan_half,
        width=w_px,
        height=h_px,
        near=distance - 1.05 * frame.radius,
        far=distance + 1.05 * frame.radius,
        light=light / np.linalg.norm(light),
    )


def _size(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"`{name}` must be a positive integer number of pixels, got {value!r}")
    return int(value)


def project(points: Any, state: Mapping[str, Any] | None, width: int, height: int, *, frame: Frame) -> np.ndarray:
    """Project 3D scene points with the page's camera.

    Parameters
    ----------
    points : (N, 3) array_like
        Scene coordinates (e.g. the vertices of :func:`slice_for_state`).
    state : mapping or None
        The page's state (:func:`full_state`).
    width, height : int
        Canvas size in pixels (``window.ao4d.stats().canvas``).
    frame : Frame
        The scene's frame (:func:`scene_frame`).

    Returns
    -------
    pixels : (N, 3) float64
        Columns: pixel x (right), pixel y (down), depth along the view axis. Pixel (i, j)
        covers ``[i, i+1) x [j, j+1)``; its centre is ``(i + 0.5, j + 0.5)``.
    """
    p = as_array(points, "points", ndim=2, shape_tail=(3,), dtype=np.float64, finite=True)
    cam = camera(state, width, height, frame=frame)
    rel = p - cam.eye
    xc, yc, zc = rel @ cam.right, rel @ cam.up, rel @ cam.forward
    with np.errstate(divide="ignore", invalid="ignore"):
        px = cam.width / 2.0 + cam.scale * xc / zc
        py = cam.height / 2.0 - cam.scale * yc / zc
    return np.stack([px, py, zc], axis=1)


def _view_projection(cam: Camera) -> np.ndarray:
    """Row-major 4x4 from scene xyz to clip space (the page builds the same)."""
    sx, sy = cam.scale / (cam.width / 2.0), cam.scale / (cam.height / 2.0)
    n, f = cam.near, cam.far
    a, b = (f + n) / (f - n), -2.0 * f * n / (f - n)
    m = np.zeros((4, 4))
    m[0, :3], m[0, 3] = sx * cam.right, -sx * cam.right @ cam.eye
    m[1, :3], m[1, 3] = sy * cam.up, -sy * cam.up @ cam.eye
    m[3, :3], m[3, 3] = cam.forward, -cam.forward @ cam.eye
    m[2] = a * m[3]
    m[2, 3] += b
    return m


# --------------------------------------------------------------------------- the cut table


def cut_table() -> list[int]:
    """The page's marching-tetrahedra table: 16 ints, 4 bits per output vertex (6 per case).

    Output vertex k (0-5; vertices 0-2 and 3-5 make the two triangles) of case c is
    ``code = (table[c] >> 4k) & 15``: ``15`` emits nothing, else it lies on the edge from local
    vertex ``code >> 2`` (s < 0) to ``code & 3`` (s >= 0).

    Returns
    -------
    list of int
        One packed entry per case (16 cases of a tetrahedron's vertex signs).
    """
    packed = []
    for triangles in SLICE_CASES:  # the CPU slicer's table: page and mesh.slice cut alike
        codes = [a * 4 + b for tri in triangles for a, b in tri]
        codes += [15] * (6 - len(codes))
        packed.append(sum(c << (4 * k) for k, c in enumerate(codes)))
    return packed


def _page_triangles(
    mesh: Any, state: Mapping[str, Any] | None, *, frame: Frame, offset: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """numpy mirror of the page's vertex shader: (T, 3, 3) corners, (T, 3) AO, (T,) tet index."""
    st = full_state(state, frame=frame)
    x = transform(mesh.vertices, st, frame=frame, offset=offset)
    simplices = np.asarray(mesh.simplices)
    ao = mesh.point_data.get("ao")
    ao = np.zeros(len(x)) if ao is None else np.asarray(ao, dtype=np.float64)
    s = x[simplices, 3] - st["w"]  # (S, 4)
    case = ((s >= 0.0) * (1 << np.arange(4))).sum(axis=1)
    packed = np.asarray(cut_table(), dtype=np.int64)[case]
    rows = np.arange(len(simplices))
    corners, aos, sources = [], [], []
    for first in (0, 3):
        codes = np.stack([(packed >> (4 * (first + k))) & 15 for k in range(3)], axis=1)
        keep = codes[:, 0] != 15
        codes, r = codes[keep], rows[keep]
        a, b = codes >> 2, codes & 3
        sa, sb = s[r[:, None], a], s[r[:, None], b]
        t = sa / (sa - sb)
        ia, ib = simplices[r[:, None], a], simplices[r[:, None], b]
        corners.append(x[ia, :3] + t[..., None] * (x[ib, :3] - x[ia, :3]))
        aos.append(ao[ia] + t * (ao[ib] - ao[ia]))
        sources.append(r)
    order = np.argsort(np.concatenate(sources), kind="stable")
    return (np.concatenate(corners)[order], np.concatenate(aos)[order], np.concatenate(sources)[order])


# --------------------------------------------------------------------------- chunks


def _chunk_order(vertices: np.ndarray, simplices: np.ndarray, size: int = CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedra in Morton (Z-curve) order of their centroids, and a bounding ball per chunk.

    One sort of 64-bit Morton codes (16 bits per axis of R^4) puts tetrahedra that lie
    close together next to each other, so chunk ``k`` = ``order[k*size:(k+1)*size]`` is compact.
    Returns ``order`` (S,) (the page stores ``simplices[order]``) and ``balls`` (C, 5) float64:
    centre (4,) and radius of the vertices of each chunk. A chunk the hyperplane misses
    (``|R[3] . centre - (w - c_w)| > radius``, see :func:`_active_chunks`) holds no cut
    tetrahedron, so the page skips it.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    simplices = np.asarray(simplices)
    n = simplices.shape[0]
    centroids = sum(vertices[simplices[:, k]] for k in range(4)) / 4.0
    order = np.argsort(_morton(centroids), kind="stable")
    n_chunks = -(-n // size)
    starts = np.arange(0, n, size)
    ordered = simplices[order]
    corners = [vertices[ordered[:, k]] for k in range(4)]  # (S, 4) each, in chunk order
    lo = np.minimum(np.minimum(corners[0], corners[1]), np.minimum(corners[2], corners[3]))
    hi = np.maximum(np.maximum(corners[0], corners[1]), np.maximum(corners[2], corners[3]))
    lo, hi = np.minimum.reduceat(lo, starts), np.maximum.reduceat(hi, starts)
    centre = 0.5 * (lo + hi)
    at_centre = np.repeat(centre, size, axis=0)[:n]
    far = np.zeros(n)
    for c in corners:
        far = np.maximum(far, np.einsum("ij,ij->i", c - at_centre, c - at_centre))
    balls = np.empty((n_chunks, 5))
    balls[:, :4] = centre
    balls[:, 4] = np.sqrt(np.maximum.reduceat(far, starts)) * (1.0 + 1e-12)  # rounded up
    return order, balls


# spread 16 bits to every 4th bit of 64 ("part 1 by 3"): (shift, mask) per step
_SPREAD4 = ((24, 0x000000FF000000FF), (12, 0x000F000F000F000F), (6, 0x0303030303030303), (3, 0x1111111111111111))


def _morton(points: np.ndarray) -> np.ndarray:
    """(N,) uint64 Morton codes of (N, 4) points quantised to 16 bits over their bounding box."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    scale = 65535.0 / np.where(hi > lo, hi - lo, 1.0)
    code = np.zeros(len(points), dtype=np.uint64)
    for k in range(4):
        x = ((points[:, k] - lo[k]) * scale[k]).astype(np.uint64)
        for shift, mask in _SPREAD4:
            x = (x | (x << np.uint64(shift))) & np.uint64(mask)
        code |= x << np.uint64(k)
    return code


def _centred(vertices: Any, frame: Frame, offset: Any = None) -> np.ndarray:
    """Page coordinates ``x + offset - c`` of an object's vertices, in float64 (the page gets
    them as float32: small numbers, whatever the scene's distance from the origin)."""
    x = np.asarray(vertices, dtype=np.float64)
    o = np.zeros(x.shape[1]) if offset is None else np.asarray(offset, dtype=np.float64)
    return x + (o - frame.center)


def _active_chunks(balls: np.ndarray, state: Mapping[str, Any] | None, *, frame: Frame) -> np.ndarray:
    """numpy mirror of the page's culling: which chunks the hyperplane may cut (C,) bool.

    ``balls`` are in page coordinates (:func:`_chunk_order` of :func:`_centred` vertices).
    """
    st = full_state(state, frame=frame)
    centre_w = balls[:, :4] @ rotation(st)[3]
    slack = 1e-6 * frame.radius  # the page's float32 round-off, relative to the scene's size
    return np.abs(centre_w - (st["w"] - frame.center[3])) <= balls[:, 4] + slack


def split_objects(mesh: Any, *, key: str = "object_id") -> list[SimplexMesh]:
    """Split a joined scene (:func:`ao4d.mesh.concatenate`) into one mesh per object id.

    Parameters
    ----------
    mesh : SimplexMesh
        With ``cell_data[key]`` (S,) integer ids.
    key : str
        The name of the ids in ``cell_data``.

    Returns
    -------
    meshes : list of SimplexMesh
        One per distinct id, in increasing id order; only the vertices each uses, point data
        (``"ao"``) carried along.
    """
    from ..mesh import SimplexMesh

    if not isinstance(mesh, SimplexMesh):
        raise TypeError(f"`mesh` must be a SimplexMesh, got {type(mesh).__name__}")
    if key not in mesh.cell_data:
        raise ValueError(f"`mesh` has no cell_data[{key!r}]; have {sorted(mesh.cell_data)}")
    ids = np.asarray(mesh.cell_data[key])
    simplices = np.asarray(mesh.simplices)
    out = []
    for value in np.unique(ids):
        own = simplices[ids == value]
        used, local = np.unique(own, return_inverse=True)
        out.append(
            SimplexMesh(
                np.asarray(mesh.vertices)[used],
                local.reshape(own.shape),
                point_data={k: np.asarray(v)[used] for k, v in mesh.point_data.items()},
            )
        )
    return out


# --------------------------------------------------------------------------- input meshes


# what every function here that takes meshes accepts (each entry, for a sequence)
_MESH_FORMS = "a SimplexMesh, a trimesh.Trimesh, a (vertices, simplices) pair or a path to an .npz mesh"


def _as_meshes(meshes: Any, names: Any, *, name: str = "meshes") -> list[tuple[Any, str]]:
    from ..mesh import SimplexMesh, as_mesh

    if isinstance(meshes, (str, os.PathLike)):
        meshes = [meshes]
    else:
        try:  # one mesh in any form as_mesh takes (a SimplexMesh, a trimesh, a pair)
            meshes = [as_mesh(meshes, name)]
        except TypeError:
            pass  # a sequence of meshes and paths, read entry by entry below
    try:
        items = list(meshes)
    except TypeError:
        raise TypeError(f"`{name}` must be {_MESH_FORMS}, or a sequence of them; got {type(meshes).__name__}") from None
    if not items:
        raise ValueError(f"`{name}` must hold at least one mesh")
    if names is not None:
        if isinstance(names, str):
            names = [names]
        names = list(names)
        if len(names) != len(items):
            raise ValueError(f"`names` must have one entry per mesh ({len(items)}), got {len(names)}")
        if not all(isinstance(n, str) for n in names):
            raise TypeError("`names` must be strings")
    out = []
    for i, item in enumerate(items):
        label = f"{name}[{i}]" if len(items) > 1 else name
        if isinstance(item, (str, os.PathLike)):
            path = Path(item)
            if not path.is_file():
                raise FileNotFoundError(f"`{label}`: no such mesh file: {path}")
            mesh, default = SimplexMesh.load(path), path.stem
        else:
            try:
                mesh = as_mesh(item, label)
            except TypeError:
                raise TypeError(f"`{label}` must be {_MESH_FORMS}; got {type(item).__name__}") from None
            default = f"mesh {i}" if len(items) > 1 else "mesh"
        if mesh.dim not in (3, 4):
            raise ValueError(f"`{label}` must be a 3D or 4D mesh, got dimension {mesh.dim}")
        if mesh.n_simplices == 0:
            raise ValueError(f"`{label}` has no simplices")
        out.append((mesh, names[i] if names is not None else default))
    dims = {m.dim for m, _ in out}
    if len(dims) > 1:
        raise ValueError(f"`{name}` must all have the same dimension, got {sorted(dims)}")
    return out


def _offsets(offsets: Any, n: int, d: int) -> np.ndarray:
    if offsets is None:
        return np.zeros((n, d))
    arr = as_array(offsets, "offsets", ndim=2, shape_tail=(d,), dtype=np.float64, finite=True)
    if arr.shape[0] != n:
        raise ValueError(f"`offsets` must have one row per mesh ({n}), got {arr.shape[0]}")
    return arr


def _facing(vertices: np.ndarray, simplices: np.ndarray) -> str:
    """Which faces of the page's triangles the page may cull: ``"back"``, ``"front"`` or ``"none"``.

    Back-face culling halves the fragments of a closed surface. It is safe when every
    (d-2)-face of the mesh is shared by exactly two simplices inducing opposite orientations
    (then every slice is closed and consistently oriented too) and the mesh faces outward
    (the DESIGN.md normal): then the visible side of each triangle is its front (counter-
    clockwise on screen). A closed mesh facing inward culls front faces; anything else culls
    nothing. One sort of packed face keys that carry the induced orientation in their lowest
    bit: a closed, consistently oriented mesh sorts into pairs ``(2 f, 2 f + 1)``, one pair per
    face ``f``.
    """
    from ..geometry import simplex_normals

    d = simplices.shape[1]
    n = int(simplices.max()) + 1
    if 2.0 * float(n) ** (d - 1) >= 2.0**63:  # pragma: no cover - over 1.3 million vertices in 4D
        return "none"
    keys = []
    for i in range(d):
        cols = [simplices[:, k].astype(np.int64) for k in range(d) if k != i]
        odd = np.full(len(simplices), i % 2 == 1)  # dropping vertex i: sign (-1)^i ...
        for a, b in ((0, 1), (1, 2), (0, 1))[: 3 if d == 4 else 1]:  # ... times the sort's parity
            swap = cols[a] > cols[b]
            cols[a], cols[b] = np.minimum(cols[a], cols[b]), np.maximum(cols[a], cols[b])
            odd ^= swap
        key = cols[0]
        for c in cols[1:]:
            key = key * n + c
        keys.append(2 * key + odd)
    key = np.sort(np.concatenate(keys))
    first, second = key[0::2], key[1::2]
    if len(key) % 2 or not ((first & 1) == 0).all() or not (second == first + 1).all():
        return "none"  # a face not in one pair of opposite orientations: open, or inconsistent
    if (first[1:] == first[:-1]).any():
        return "none"  # a face shared by four or more simplices: not a manifold
    normals = simplex_normals(vertices, simplices)
    volume = float(np.einsum("ij,ij->", normals, vertices[simplices[:, 0]] - vertices.mean(axis=0)))
    return "back" if volume > 0 else "front" if volume < 0 else "none"


def _ao_of(mesh: Any, label: str) -> np.ndarray | None:
    if "ao" not in mesh.point_data:
        return None
    ao = np.asarray(mesh.point_data["ao"], dtype=np.float64)
    what = f"`{label}.point_data['ao']`"
    if ao.shape != (mesh.n_vertices,):
        raise ValueError(f"{what} must have shape ({mesh.n_vertices},), got {ao.shape}")
    if not np.isfinite(ao).all():
        raise ValueError(f"{what} contains non-finite values")
    if ao.min() < -1e-6 or ao.max() > 1 + 1e-6:
        raise ValueError(f"{what} must lie in [0, 1] (1 = occluded), got [{ao.min():g}, {ao.max():g}]")
    return np.clip(ao, 0.0, 1.0)


def _ramps(n: int, *, colors: Any, cmap: str) -> np.ndarray:
    """(n, 256, 4) uint8 colour ramps indexed by 1 - AO (entry k at 1 - AO = k / 255)."""
    import matplotlib
    import matplotlib.colors as mcolors

    v = np.linspace(0.0, 1.0, 256)[:, None]
    if colors is None and n == 1:
        if cmap not in matplotlib.colormaps:
            raise ValueError(f"`cmap` must be a matplotlib colour map name, got {cmap!r}")
        return (np.asarray(matplotlib.colormaps[cmap](v[:, 0]))[None] * 255).round().astype(np.uint8)
    if colors is None:
        colors = [PALETTE[i % len(PALETTE)] for i in range(n)]
    if isinstance(colors, str):
        colors = [colors]
    colors = list(colors)
    if len(colors) != n:
        raise ValueError(f"`colors` must have one entry per mesh ({n}), got {len(colors)}")
    out = np.empty((n, 256, 4), dtype=np.uint8)
    for i, c in enumerate(colors):
        try:
            rgb = np.asarray(mcolors.to_rgb(c))
        except ValueError:
            raise ValueError(f"`colors[{i}]` is not a colour: {c!r}") from None
        dark, light = 0.12 * rgb, rgb + 0.3 * (1.0 - rgb)
        out[i, :, :3] = ((dark + v * (light - dark)) * 255).round().astype(np.uint8)
        out[i, :, 3] = 255
    return out


# --------------------------------------------------------------------------- the page


@dataclass
class _Blob:
    data: bytes  # possibly compressed
    meta: dict


def _build(
    meshes: Any, *, names, state, center, offsets, colors, cmap, title, compress, cull, progress, external: bool
) -> tuple[dict, list[_Blob]]:
    """Validate everything, then encode the scene: (scene JSON object, blobs)."""
    items = _as_meshes(meshes, names)
    check_bool(compress, "compress")
    check_choice(cull, "cull", ("auto", "back", "front", "none"))
    d = items[0][0].dim
    offs = _offsets(offsets, len(items), d)
    mesh_list = [m for m, _ in items]
    frame = _frame(mesh_list, center, offs)
    st = full_state(state, frame=frame)
    if any(i >= len(items) for i in st["hide"]):
        raise ValueError(f"`state['hide']` names objects beyond the {len(items)} given")
    ramps = _ramps(len(items), colors=colors, cmap=cmap)
    if title is not None and not isinstance(title, str):
        raise TypeError(f"`title` must be a string, got {type(title).__name__}")
    aos = [_ao_of(m, f"meshes[{i}]" if len(items) > 1 else "meshes") for i, m in enumerate(mesh_list)]
    for i, m in enumerate(mesh_list):
        if m.n_vertices >= 2**32:
            raise ValueError(f"`meshes[{i}]` has too many vertices for uint32 indices")

    blobs: list[_Blob] = []

    def blob(arr: np.ndarray, dtype: str) -> dict:
        raw = np.ascontiguousarray(arr, dtype={"float32": "<f4", "float64": "<f8", "uint32": "<u4"}[dtype])
        if dtype == "float32" and not np.isfinite(raw).all():
            raise ValueError("`meshes` hold coordinates too large for float32")
        data = raw.tobytes()
        encoding = "raw"
        if compress:
            data, encoding = zlib.compress(data, 1), "deflate"  # level 6: 5 % smaller, 5x slower
        k = len(blobs)
        meta = {"encoding": encoding, "dtype": dtype, "shape": list(raw.shape), "nbytes": raw.nbytes}
        meta["url" if external else "id"] = f"data/{k}" if external else f"ao4d-blob-{k}"
        blobs.append(_Blob(data, meta))
        return meta

    from .._progress import bar

    if progress is not None:
        check_bool(progress, "progress")
    total = sum(m.n_simplices for m in mesh_list)
    show = total > 1_000_000 if progress is None else progress
    objects = []
    pb = bar(3 * len(items), "ao4d view: preparing the page", unit="step", show=show)
    for i, ((mesh, label), ao) in enumerate(zip(items, aos)):
        vertices, simplices = _centred(mesh.vertices, frame, offs[i]), np.asarray(mesh.simplices)
        facing = _facing(vertices, simplices) if cull == "auto" else cull
        pb.update(1)
        chunks = None
        if d == 4:
            order, balls = _chunk_order(vertices, simplices)
            simplices = simplices[order]
            chunks = blob(balls, "float64")
        pb.update(1)
        objects.append(
            {
                "name": label,
                "cull": facing,
                "n_vertices": int(mesh.n_vertices),
                "n_simplices": int(mesh.n_simplices),
                "offset": offs[i].tolist(),
                "has_ao": ao is not None,
                "ao_range": None if ao is None else [float(ao.min()), float(ao.max())],
                "ramp": base64.b64encode(ramps[i].tobytes()).decode("ascii"),
                "vertices": blob(vertices, "float32"),
                "simplices": blob(simplices, "uint32"),
                "ao": None if ao is None else blob(ao, "float32"),
                "chunks": chunks,
            }
        )
        pb.update(1)
    pb.close()
    scene = {
        "format": "ao4d-view/1",
        "title": title or (items[0][1] if len(items) == 1 else f"{len(items)} meshes"),
        "dim": d,
        "center": frame.center.tolist(),
        "radius": frame.radius,
        "state": {**st, "hide": list(st["hide"])},
        "camera": {"half_fov_deg": HALF_FOV_DEG, "margin": MARGIN, "zoom_range": list(ZOOM_RANGE)},
        "ambient": AMBIENT,
        "cut": cut_table(),
        "chunk": CHUNK,
        "objects": objects,
    }
    return scene, blobs


def _options(given: Mapping[str, Any], where: str, *, without: tuple[str, ...] = ()) -> dict:
    """The keyword options of :func:`view` (but ``without``), defaults filled in from its
    signature; an unknown one is a ``TypeError`` naming ``where``."""
    known = {
        name: p.default
        for name, p in inspect.signature(view).parameters.items()
        if p.kind == p.KEYWORD_ONLY and name not in without
    }
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise TypeError(f"{where}() got unknown option(s) {', '.join(map(repr, unknown))}; it takes {', '.join(known)}")
    return {**known, **given}


def view(
    meshes: Any,
    path: str | os.PathLike,
    *,
    names: Sequence[str] | None = None,
    state: Mapping[str, Any] | None = None,
    center: Any = None,
    offsets: Any = None,
    colors: Sequence[Any] | None = None,
    cmap: str = "magma",
    title: str | None = None,
    compress: bool = True,
    cull: str = "auto",
    max_bytes: int = MAX_BYTES,
    progress: bool | None = None,
) -> Path:
    """Write one self-contained HTML page that slices and turns the meshes on the GPU.

    Parameters
    ----------
    meshes : SimplexMesh, trimesh.Trimesh, (vertices, simplices), path to an .npz mesh, or a sequence of them
        All 4D (sliced by the hyperplane) or all 3D (plain orbit view), each in any form
        :func:`ao4d.mesh.as_mesh` takes or an .npz file. ``point_data["ao"]`` (V,) in [0, 1], if
        present, colours them.
    path : path-like
        The HTML file, ending in .html or .htm (written atomically; checked before any work).
    names : sequence of str, optional
        One label per mesh (default: file stems, or "mesh i").
    state : mapping, optional
        Initial view (:func:`full_state`); the URL fragment overrides it.
    center : (d,) array_like, optional
        Rotation centre and camera target (default: centre of the scene's bounding box).
    offsets : (n_meshes, d) array_like, optional
        Position of each mesh in the scene.
    colors : sequence of colours, optional
        Per-mesh colours (matplotlib specs); default Tableau 10 when several meshes.
    cmap : str
        Colour map of ``1 - AO`` for a single mesh (default "magma", as ``ao4d slice``).
    title : str, optional
        The page's title.
    compress : bool
        zlib-compress the buffers (inflated by the browser's ``DecompressionStream``).
    cull : {"auto", "back", "front", "none"}
        Faces the GPU may skip. "auto": back faces when a mesh is closed, consistently
        oriented and faces outward (as every mesh ao4d extracts; checked here, about 2 s per
        million tetrahedra), front faces when it faces inward, none otherwise. Culling halves
        the pixels shaded.
    max_bytes : int
        Refuse pages larger than this (default 150 MB): use :func:`serve` (``ao4d view
        --serve``) instead.
    progress : bool, optional
        Show progress while the page is prepared (default: for over a million simplices).

    Returns
    -------
    path : Path
        The page written.

    Raises
    ------
    ValueError
        Bad meshes, state or options; a page over ``max_bytes``.
    """
    check_max_bytes(max_bytes)
    options = dict(
        names=names,
        state=state,
        center=center,
        offsets=offsets,
        colors=colors,
        cmap=cmap,
        title=title,
        compress=compress,
        cull=cull,
        max_bytes=max_bytes,
        progress=progress,
    )
    return write_page(path, lambda: page_text(meshes, **options))  # the path checked before any work


def page_text(meshes: Any, **options: Any) -> str:
    """The page of :func:`view` as a string (for notebooks and the demo's result page).

    Parameters
    ----------
    meshes : SimplexMesh, trimesh.Trimesh, (vertices, simplices), path to an .npz mesh, or a sequence of them
        As for :func:`view`.
    **options
        The keyword options of :func:`view` (``names``, ``state``, ..., ``max_bytes``); an
        unknown one is a ``TypeError``.

    Returns
    -------
    page : str
        The page's HTML.

    Raises
    ------
    ValueError
        Bad meshes, state or options; a page over ``max_bytes``.
    TypeError
        An unknown option.
    """
    options = _options(options, "page_text")
    max_bytes, compress = check_max_bytes(options.pop("max_bytes")), options["compress"]
    items = _as_meshes(meshes, options.pop("names"))
    raw = sum(m.n_vertices * m.dim * 4 + m.n_simplices * m.dim * 4 + m.n_vertices * 4 for m, _ in items)
    limit_text = f"over `max_bytes` = {max_bytes / 1e6:.0f} MB; serve it instead: `ao4d view ... --serve` (or ao4d.browser.viewer.serve)"
    if not compress and b64_size(raw) > max_bytes:
        raise ValueError(f"the page would be about {b64_size(raw) / 1e6:.0f} MB, {limit_text}")
    if b64_size(raw) > 8 * max_bytes:  # beyond what compression can bring under the limit
        raise ValueError(f"the meshes hold {raw / 1e6:.0f} MB, {limit_text}")
    scene, blobs = _build([m for m, _ in items], names=[n for _, n in items], **options, external=False)
    head, middle, tail = template(_TEMPLATE)
    scene_text = scene_json(scene)
    size = len(head) + len(scene_text) + len(middle) + len(tail)
    size += sum(b64_size(len(b.data)) + 80 for b in blobs)
    if size > max_bytes:
        raise ValueError(f"the page would be {size / 1e6:.0f} MB, {limit_text}")
    parts = [head, scene_text, middle]
    for b in blobs:
        parts.append(f'<script type="application/octet-stream" id="{b.meta["id"]}">')
        parts.append(base64.b64encode(b.data).decode("ascii"))
        parts.append("</script>\n")
    parts.append(tail)
    return "".join(parts)


# --------------------------------------------------------------------------- serving


class ViewServer:
    """A page and its buffers served over HTTP on 127.0.0.1 (from :func:`serve`).

    Parameters
    ----------
    page : bytes
        The page's HTML, served at ``/`` and ``/index.html``.
    blobs : list of bytes
        Buffers served at ``/data/<k>``.
    host : str
        Address to listen on.
    port : int
        TCP port (0: any free one).

    Raises
    ------
    ValueError
        If ``port`` is not in 0..65535.
    OSError
        If the port cannot be bound.
    """

    def __init__(self, page: bytes, blobs: list[bytes], host: str, port: int):
        files = {"/": page, "/index.html": page}
        files.update({f"/data/{k}": data for k, data in enumerate(blobs)})

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                body = files.get(self.path.split("?", 1)[0].split("#", 1)[0])
                if body is None:
                    self.send_error(404)
                    return
                self.send_response(200)
                kind = "text/html; charset=utf-8" if body is page else "application/octet-stream"
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                pass

        if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= port <= 65535:
            raise ValueError(f"`port` must be an integer in 0..65535 (0: any free one), got {port!r}")
        try:
            self._httpd = http.server.ThreadingHTTPServer((host, port), Handler)
        except OSError as exc:
            raise OSError(
                exc.errno,
                f"cannot serve on {host} port {port}: {exc.strerror}"
                + ("; pick another `port` (--port) or 0 for any free one" if port else ""),
            ) from None
        self._httpd.daemon_threads = True
        self.host, self.port = host, int(self._httpd.server_address[1])
        self.url = f"http://{host}:{self.port}/"
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="ao4d-view-server", daemon=True)
        self._thread.start()

    def wait(self) -> None:
        """Block until interrupted (Ctrl-C), then stop serving."""
        try:
            while self._thread.is_alive():
                self._thread.join(0.5)
        finally:
            self.close()

    def close(self) -> None:
        """Stop serving and release the port."""
        if self._thread.is_alive():
            self._httpd.shutdown()
            self._thread.join()
        self._httpd.server_close()

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve(meshes: Any, *, port: int = 0, host: str = "127.0.0.1", **options: Any) -> ViewServer:
    """Serve the page of :func:`view` with its buffers as separate files, for any size.

    Parameters
    ----------
    meshes : SimplexMesh, trimesh.Trimesh, (vertices, simplices), path to an .npz mesh, or a sequence of them
        As for :func:`view`.
    port : int
        TCP port (0: any free one; see ``server.url``).
    host : {"127.0.0.1", "localhost"}
        Loopback only.
    **options
        The keyword options of :func:`view` but ``max_bytes`` (``names``, ``state``, ...,
        ``progress``); an unknown one is a ``TypeError``.

    Returns
    -------
    server : ViewServer
        Already serving in a background thread; ``server.url`` is the page, ``server.wait()``
        blocks until Ctrl-C, ``server.close()`` stops it.
    """
    check_choice(host, "host", ("127.0.0.1", "localhost"))
    if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= port < 65536:
        raise ValueError(f"`port` must be an integer in [0, 65535], got {port!r}")
    scene, blobs = _build(meshes, **_options(options, "serve", without=("max_bytes",)), external=True)
    head, middle, tail = template(_TEMPLATE)
    page = (head + scene_json(scene) + middle + tail).encode("utf-8")
    return ViewServer(page, [b.data for b in blobs], host, port)
