"""Lift 3D solids into closed 4D boundaries: prisms, cones (pyramids) and spins.

A watertight triangle mesh bounds a 3D solid ``S``. Each function here builds the *boundary* of a
4D solid made from ``S`` as a closed, outward-oriented tetrahedral mesh (a 3-manifold in R^4,
DESIGN.md conventions):

- :func:`prism` — ``S x [w0, w0 + h]``: two tetrahedral caps (``S`` at both ends) and side walls
  ``dS x [w0, w0 + h]``. Enclosed 4-volume ``vol(S) * h``.
- :func:`cone` — the pyramid over ``S`` with its apex at height ``h``: one cap (``S`` at ``w0``)
  and the cone over ``dS``. Enclosed 4-volume ``vol(S) * h / 4``.
- :func:`spin` — ``S`` (in the half-space ``x >= 0``) rotated in the (x, w) plane about the plane
  ``x = w = 0``, sampled at ``k`` angles. Its boundary is ``dS x circle``: no cap, because every
  point of ``S`` lies on some rotated copy. Enclosed 4-volume exactly ``k sin(2 pi / k) x_c
  vol(S)`` (x_c: centroid x), tending to Pappus' ``integral over S of 2 pi x dV3 = 2 pi x_c
  vol(S)`` as ``k -> oo``.
- :func:`sweep` — a 3D solid moving and deforming in time (w = t), given as frames of one mesh:
  the space-time solid ``{(x, t): x in S(t)}`` with vertices moving linearly between frames. Two
  caps (the first and last frames) and walls ``dS(t)`` swept frame to frame. Enclosed 4-volume
  ``integral of vol(S(t)) dt``.

The caps need ``S`` itself, cut into tetrahedra: :func:`tetrahedralize` joins the faces to the
centre of a star-shaped solid (exact, deterministic) or else runs fTetWild (pytetwild), and the
side walls are built on the boundary triangles of those tetrahedra so that caps and walls share
their faces exactly. A triangle x interval (a triangular prism) is cut into
three tetrahedra by the global vertex order rule (the staircase split keyed on vertex ids), which
two neighbouring prisms always agree on, so the walls are conforming.

Why this file is long: the four lifts share the cap cutting, the wall rule and the surface checks,
which no other stage uses; apart, they would import each other's private helpers.

References
----------
Y. Hu, T. Schneider, B. Wang, D. Zorin, D. Panozzo, "Fast Tetrahedral Meshing in the Wild",
ACM Trans. Graph. 39(4), 2020. https://doi.org/10.1145/3386569.3392385
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Union

import numpy as np

from ._validate import as_array, as_real, check_choice, check_memory, check_positive_int
from .geometry import simplex_normals
from .topology import face_structure

if TYPE_CHECKING:
    import trimesh

    from .mesh import SimplexMesh

__all__ = ["TetSolid", "load_surface", "tetrahedralize", "prism", "cone", "spin", "sweep"]

# Faces of a positively oriented tetrahedron (0, 1, 2, 3), each listed so that its normal points
# out of the tetrahedron (the face opposite vertex i is row i).
_TET_FACES_OUT = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


@dataclass(frozen=True, eq=False)
class TetSolid:
    """A 3D solid cut into positively oriented tetrahedra.

    Attributes
    ----------
    points : (P, 3) float64
        Vertex positions.
    tets : (T, 4) int64
        Vertex indices; every tetrahedron has ``det[p1 - p0; p2 - p0; p3 - p0] > 0``.
    """

    points: np.ndarray
    tets: np.ndarray

    @classmethod
    def from_arrays(cls, points: np.ndarray, tets: np.ndarray) -> TetSolid:
        """Validate ``points`` (P, 3) and ``tets`` (T, 4), orient tetrahedra positively.

        Parameters
        ----------
        points : (P, 3) array_like of float
            The vertices.
        tets : (T, 4) array_like of int
            The tetrahedra, as vertex indices.

        Returns
        -------
        TetSolid
            The solid, every tetrahedron positively oriented.

        Raises
        ------
        ValueError
            If the shapes are wrong, indices are out of range, or a tetrahedron is flat.
        """
        points = as_array(points, "points", ndim=2, shape_tail=(3,), dtype=np.float64, finite=True, min_size=12)
        tets = as_array(tets, "tets", ndim=2, shape_tail=(4,), min_size=4)
        if tets.dtype.kind not in "iu":
            raise TypeError(f"`tets` must hold integer vertex indices, got dtype {tets.dtype}")
        tets = tets.astype(np.int64)
        if tets.min() < 0 or tets.max() >= len(points):
            raise ValueError(f"`tets` indices must lie in [0, {len(points)}), got [{tets.min()}, {tets.max()}]")
        det = _tet_dets(points, tets)
        flat = np.abs(det) <= 1e-14 * _scale(points) ** 3
        if flat.any():
            raise ValueError(f"`tets` holds {int(flat.sum())} flat (zero-volume) tetrahedra")
        tets = np.where((det < 0)[:, None], tets[:, [0, 2, 1, 3]], tets)
        points.setflags(write=False)
        tets.setflags(write=False)
        return cls(points, tets)

    @cached_property
    def volume(self) -> float:
        """Total 3-volume."""
        return float(_tet_dets(self.points, self.tets).sum() / 6.0)

    @cached_property
    def centroid(self) -> np.ndarray:
        """(3,) float64 centre of mass of the (uniform) solid."""
        vol = _tet_dets(self.points, self.tets) / 6.0
        centres = self.points[self.tets].mean(axis=1)
        return (vol[:, None] * centres).sum(axis=0) / vol.sum()

    @cached_property
    def boundary(self) -> np.ndarray:
        """(F, 3) int64 boundary triangles, oriented with outward normals.

        A face lies on the boundary when exactly one tetrahedron has it
        (:func:`ao4d.topology.face_structure` groups them).
        """
        once = face_structure(self.tets, len(self.points)).multiplicity == 1  # (T, 4)
        tris = self.tets[:, _TET_FACES_OUT][once]
        tris.setflags(write=False)
        return tris


# a 3D solid: a triangle mesh in any form ao4d.mesh.as_mesh takes, or tetrahedra
MeshLike = Union["trimesh.Trimesh", "SimplexMesh", tuple, TetSolid]


def load_surface(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a closed triangle mesh (.stl, .obj, .ply, ... anything trimesh reads) for lifting.

    Duplicate vertices are merged (STL stores separate triangles), so a closed surface comes
    out watertight; an inside-out file (negative volume) is turned around.

    Parameters
    ----------
    path : path-like
        The file.

    Returns
    -------
    trimesh.Trimesh
        Watertight, consistently wound, outward oriented.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        The file holds no triangles, several disconnected pieces that trimesh cannot join
        into one mesh, or a surface with holes.
    """
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"`path` {str(p)!r} does not exist or is not a file")
    try:
        surface = trimesh.load(p, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ValueError(f"`path` {str(p)!r}: trimesh cannot read it as a triangle mesh: {exc}") from None
    if not isinstance(surface, trimesh.Trimesh) or len(surface.faces) == 0:
        raise ValueError(f"`path` {str(p)!r} holds no triangles")
    if surface.is_watertight and surface.is_winding_consistent and surface.volume < 0:
        surface.invert()
    _check_surface(surface, f"path {str(p)!r}")
    return surface


def tetrahedralize(
    surface: trimesh.Trimesh,
    *,
    method: Literal["auto", "star", "tetwild"] = "auto",
    center: np.ndarray | None = None,
    edge_length: float = 0.1,
    optimize: bool = True,
    threads: int = 1,
) -> TetSolid:
    """Cut the solid bounded by a watertight triangle mesh into tetrahedra.

    Two methods:

    - ``"star"`` joins every boundary triangle to one centre point that sees all of them
      (the solid must be star-shaped from it: convex solids, balls, capsules, ...). The
      boundary is the input surface exactly, and the result is deterministic.
    - ``"tetwild"`` runs fTetWild (pytetwild) and works for any solid (tori, knots). Its output
      differs from run to run (even with one thread), so datasets that must be byte-identical
      when regenerated should use star-shaped solids or :func:`spin` (which needs no cap).

    ``"auto"`` uses ``"star"`` when the centre sees every face, else ``"tetwild"``.

    Parameters
    ----------
    surface : trimesh.Trimesh, SimplexMesh or (vertices, triangles)
        Watertight, consistently wound, outward-oriented surface; a 3D triangle mesh in any form
        :func:`ao4d.mesh.as_mesh` takes.
    method : {"auto", "star", "tetwild"}
        See above.
    center : (3,) array_like, optional
        Star centre; default the solid's centre of mass.
    edge_length : float
        Target tetrahedron edge length as a fraction of the bounding-box diagonal, in (0, 1].
    optimize : bool
        Let fTetWild improve tetrahedron quality. Without it the output often holds flat
        slivers (zero-volume tetrahedra), which would become degenerate simplices of the 4D
        caps and are refused. Optimising moves boundary points within fTetWild's envelope
        (1e-3 of the bounding-box diagonal), so the volume differs from the surface's by up
        to about ``1e-3 * area * diagonal``.
    threads : int
        Threads for fTetWild.

    Returns
    -------
    TetSolid
        Positively oriented tetrahedra.

    Raises
    ------
    TypeError
        If ``surface`` is not a triangle mesh.
    ValueError
        If ``surface`` is not 3D, watertight, consistently wound and outward, or is empty.

    Examples
    --------
    >>> import trimesh
    >>> solid = tetrahedralize(trimesh.creation.box(extents=(1, 2, 3)))
    >>> round(solid.volume, 9)
    6.0
    """
    surface = _as_surface(surface, "surface")
    check_choice(method, "method", ("auto", "star", "tetwild"))
    if method != "tetwild":
        centre = (
            surface.center_mass
            if center is None
            else as_array(center, "center", ndim=1, shape_tail=(3,), dtype=np.float64, finite=True)
        )
        star = _star_tets(surface, centre)
        if star is not None:
            return star
        if method == "star":
            raise ValueError(
                "`surface` is not star-shaped from `center` (some face is not "
                "visible from it); use method='tetwild' or another `center`"
            )
    edge_length = as_real(edge_length, "edge_length", gt=0, le=1)
    threads = check_positive_int(threads, "threads")
    from ._optional import require

    # pytetwild (a core dependency) imports pyvista when it loads, which ao4d[vtk] installs
    pytetwild = require("pytetwild", "tetrahedralising a solid with fTetWild", extra="vtk")
    with _scratch_cwd():
        points, tets = pytetwild.tetrahedralize(
            np.asarray(surface.vertices, dtype=np.float64),
            np.asarray(surface.faces, dtype=np.int32),
            edge_length_fac=float(edge_length),
            optimize=bool(optimize),
            num_threads=threads,
            quiet=True,
        )
    if len(tets) == 0:
        raise ValueError("`surface`: fTetWild produced no tetrahedra (is the solid too thin?)")
    return TetSolid.from_arrays(points, tets)


_CWD_LOCK = threading.Lock()


@contextlib.contextmanager
def _scratch_cwd():
    """Run in a temporary working directory: fTetWild writes ``__tracked_surface.stl`` into the
    current one, which would litter the user's folder (the cwd is process-wide, hence the lock)."""
    with _CWD_LOCK, tempfile.TemporaryDirectory(prefix="ao4d-tetwild-") as scratch:
        previous = os.getcwd()
        os.chdir(scratch)
        try:
            yield
        finally:
            os.chdir(previous)


def prism(solid: MeshLike, height: float = 1.0, *, base: float = 0.0) -> SimplexMesh:
    """Boundary of the 4D prism ``solid x [base, base + height]`` along w.

    Parameters
    ----------
    solid : trimesh.Trimesh, SimplexMesh, (vertices, triangles) or TetSolid
        The 3D solid; a triangle mesh (any form :func:`ao4d.mesh.as_mesh` takes) is cut with
        :func:`tetrahedralize` (``method="auto"``).
    height : float
        Extent along w, > 0.
    base : float
        w of the lower cap.

    Returns
    -------
    SimplexMesh
        Closed, outward oriented; vertices (2P, 4), the solid's points at ``base`` then at
        ``base + height``. Enclosed 4-volume ``solid.volume * height``.

    Examples
    --------
    >>> import trimesh
    >>> mesh = prism(trimesh.creation.box(extents=(1, 1, 1)), 2.0)
    >>> round(mesh.volume, 9), mesh.check().ok
    (2.0, True)
    """
    tet_solid = _as_solid(solid, "solid")
    height = as_real(height, "height", gt=0)
    base = as_real(base, "base")
    pts, tets, tris = tet_solid.points, tet_solid.tets, tet_solid.boundary
    n = len(pts)
    vertices = np.concatenate([_with_w(pts, base), _with_w(pts, base + height)])
    ids = np.arange(n)
    simplices = np.concatenate(
        [
            _reversed(tets),  # lower cap: outward is -w, opposite to a positive tet's normal (+w)
            tets + n,  # upper cap: outward is +w
            _wall_tets(tris, ids, ids + n),
        ]
    )
    return _mesh(vertices, simplices)


def cone(
    solid: MeshLike,
    height: float = 1.0,
    *,
    apex: np.ndarray | None = None,
    base: float = 0.0,
) -> SimplexMesh:
    """Boundary of the 4D pyramid over ``solid`` (at w = ``base``) with apex at ``base + height``.

    Parameters
    ----------
    solid : trimesh.Trimesh, SimplexMesh, (vertices, triangles) or TetSolid
        The 3D base solid; a triangle mesh in any form :func:`ao4d.mesh.as_mesh` takes, or
        tetrahedra.
    height : float
        w distance from the base to the apex, > 0.
    apex : (3,) array_like, optional
        x, y, z of the apex; default the solid's centroid. The volume does not depend on it.
    base : float
        w of the base.

    Returns
    -------
    SimplexMesh
        Closed, outward oriented; enclosed 4-volume ``solid.volume * height / 4``.

    Examples
    --------
    >>> import trimesh
    >>> mesh = cone(trimesh.creation.box(extents=(1, 1, 1)), 2.0)
    >>> round(mesh.volume, 9)
    0.5
    """
    tet_solid = _as_solid(solid, "solid")
    height = as_real(height, "height", gt=0)
    base = as_real(base, "base")
    top = (
        tet_solid.centroid
        if apex is None
        else as_array(apex, "apex", ndim=1, shape_tail=(3,), dtype=np.float64, finite=True)
    )
    pts, tris = tet_solid.points, tet_solid.boundary
    n = len(pts)
    vertices = np.concatenate([_with_w(pts, base), [[*top, base + height]]])
    # Lateral tetrahedron (a, c, b, apex): with (a, b, c) outward in 3D, (a, b, c, apex) has its
    # DESIGN.md normal pointing into the pyramid, so one swap makes it outward.
    lateral = np.column_stack([tris[:, 0], tris[:, 2], tris[:, 1], np.full(len(tris), n)])
    simplices = np.concatenate([_reversed(tet_solid.tets), lateral])
    return _mesh(vertices, simplices)


def spin(surface: MeshLike, k: int = 32, *, axis_tolerance: float = 1e-9) -> SimplexMesh:
    """Boundary of the 4D solid swept by rotating ``surface``'s solid about the plane x = w = 0.

    Point (x, y, z) of the solid (x >= 0) sweeps the circle ``(x cos t, y, z, x sin t)``; the
    circle is replaced by the regular ``k``-gon through ``t_j = 2 pi j / k``. The 4D boundary is
    ``surface x k-gon`` (no caps are needed). Faces of ``surface`` lying on the plane x = 0 sweep
    nothing (they end up inside), so a solid may rest on that plane with whole faces, e.g. a
    half-ball spins into a 4-ball. A solid touching x = 0 only at points or edges would sweep a
    pinched, non-manifold boundary and is refused.

    Parameters
    ----------
    surface : trimesh.Trimesh, SimplexMesh, (vertices, triangles) or TetSolid
        Watertight outward surface in x >= 0, a 3D triangle mesh in any form
        :func:`ao4d.mesh.as_mesh` takes (a TetSolid contributes its boundary).
    k : int
        Number of rotation steps, >= 3.
    axis_tolerance : float
        Points with ``x <= axis_tolerance * diagonal`` count as lying on the plane x = 0.

    Returns
    -------
    SimplexMesh
        Closed, outward oriented. Its 4-volume is exactly ``k sin(2 pi / k) * x_c vol(S)``
        (x_c: the solid's centroid x): in the basis (e_j, e_j+1, y, z) of one angular wedge
        (a linear map of determinant ``sin(2 pi / k)``) the wedge's walls are flat prisms
        bounding ``{(a, b, y, z): a, b >= 0, (a + b, y, z) in S}``, of volume ``x_c vol(S)``.
        As ``k -> oo`` this tends to Pappus' ``2 pi x_c vol(S)``.

    Raises
    ------
    ValueError
        If the solid reaches into x < 0 or touches x = 0 at isolated points or edges.

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(3, radius=0.5)
    >>> ball.apply_translation([1.0, 0.0, 0.0])  # doctest: +ELLIPSIS
    <trimesh.Trimesh...>
    >>> torisphere = spin(ball, 64)
    >>> torisphere.check().ok
    True
    """
    pts, tris = _surface_arrays(surface, "surface")
    k = check_positive_int(k, "k", minimum=3)
    tol = as_real(axis_tolerance, "axis_tolerance", ge=0) * _scale(pts)
    if pts[:, 0].min() < -tol:
        raise ValueError(
            f"`surface` must lie in the half-space x >= 0 to spin about x = w = 0; "
            f"its smallest x is {pts[:, 0].min():.6g} (translate it first)"
        )
    on_axis = pts[:, 0] <= tol
    tris = _drop_axis_faces(tris, on_axis)

    # Vertex (p, j) of the swept boundary; points on the axis do not move and are shared by all j.
    n, off = len(pts), np.flatnonzero(~on_axis)
    ids = np.empty((k, n), dtype=np.int64)
    ids[:, on_axis] = np.arange(on_axis.sum())
    ids[:, off] = on_axis.sum() + np.arange(k)[:, None] * len(off) + np.arange(len(off))
    angles = 2.0 * np.pi * np.arange(k) / k
    axis_pts = np.column_stack([np.zeros(on_axis.sum()), pts[on_axis, 1:], np.zeros(on_axis.sum())])
    x, rest = pts[off, 0], pts[off, 1:]
    ring = [np.column_stack([x * math.cos(a), rest, x * math.sin(a)]) for a in angles]
    vertices = np.concatenate([axis_pts, *ring])

    # Rotation carries the interval direction t -> t + dt to +w at t = 0 (x > 0), so the walls
    # are oriented exactly like a prism's side walls.
    walls = [_wall_tets(tris, ids[j], ids[(j + 1) % k]) for j in range(k)]
    simplices = np.concatenate(walls)
    simplices = simplices[_distinct_rows(simplices)]  # tetrahedra collapsed on the axis
    return _mesh(vertices, simplices)


# a frame of a sweep: a triangle mesh, or a file load_surface reads
FrameLike = Union["trimesh.Trimesh", "SimplexMesh", tuple, str, os.PathLike]


def sweep(frames: Sequence[FrameLike], times: Sequence[float] | np.ndarray | None = None) -> SimplexMesh:
    """Boundary of the space-time solid swept by a 3D solid moving through ``frames``.

    Frame k is the solid ``S(t_k)`` at time ``t_k = times[k]``, put at w = t_k; between two
    frames every vertex moves linearly. The result bounds ``{(x, t): x in S(t), t_0 <= t <=
    t_{n-1}}``: a cap at each end (the first solid at w = t_0, facing -w; the last at
    w = t_{n-1}, facing +w), cut into tetrahedra from their centre of mass as
    :func:`tetrahedralize` (``method="star"``) does, and walls: each boundary triangle times each
    time interval is a triangular prism in 4D, cut into three tetrahedra by the staircase rule
    on vertex ids (as :func:`prism`'s walls), which neighbouring prisms agree on.

    Parameters
    ----------
    frames : sequence of trimesh.Trimesh, SimplexMesh, (vertices, triangles) or path-like
        At least 2 watertight, consistently wound, outward 3D triangle meshes with the same
        faces and vertex count (one mesh, moved: vertex i of every frame is the same material
        point); a path is read with :func:`load_surface`. The first and last frames must be
        star-shaped from their centre of mass (or bounding-box centre), so that the caps keep
        their surfaces exactly (fTetWild would remesh them, and the walls would not meet them).
    times : sequence of float, optional
        Strictly increasing, finite, one per frame; default ``0, 1, ..., n - 1``.

    Returns
    -------
    SimplexMesh
        Closed, outward oriented; vertices ``(n V + 2, 4)``: frame k's V vertices at w = t_k
        (frame after frame, unused vertices dropped), then the two cap centres. Its slice at
        w = t_k is frame k for k >= 1 (up to triangulation); at w = t_0 the hyperplane holds the
        whole first cap, and :meth:`~ao4d.SimplexMesh.slice` counts vertices on it as beyond it,
        so that slice is empty (cut just after t_0 instead).

    Raises
    ------
    TypeError
        If ``frames`` is not a sequence of meshes or paths.
    ValueError
        Naming the frame or ``times``: fewer than 2 frames; a frame that is open, badly wound,
        inside-out (negative volume) or has non-finite vertices; frames with different faces or
        vertex counts; first or last frame not star-shaped; ``times`` of the wrong length, not
        finite or not strictly increasing; a motion that turns a wall over (below).

    Notes
    -----
    **Volume.** The slice ``S(t)`` of the result at a time t inside an interval is the linear
    interpolation of the two frames, except that each edge (u, v), u < v in vertex id, is kinked
    through ``(1 - s) p_u(t_k) + s p_v(t_{k+1})`` (s the fraction of the interval): the wall
    tetrahedra are flat, the ruled surface swept by a moving edge is not. For translations and
    uniform scalings about a moving centre the kink lies on the edge and ``S(t)`` is exactly the
    interpolated mesh. Either way the corners of ``S(t)`` move linearly, so ``vol(S(t))`` is a
    cubic on each interval and the enclosed 4-volume, ``integral of vol(S(t)) dt``, is exactly
    Simpson's rule ``sum_k (t_{k+1} - t_k) (V_k + 4 V_{k+1/2} + V_{k+1}) / 6`` with
    ``V_{k+1/2}`` the volume of the slice at the interval's midpoint.

    **Motion that turns a wall over** is refused. Within one interval each wall tetrahedron's
    slice is a flat piece of ``S(t)`` whose normal is the tetrahedron's 4D normal restricted to
    x, y, z, the same at every t. In the straight prism (no motion) all three pieces of a
    triangle face along its outward normal; if one faces against the triangle's outward normal
    ``N_k`` in frame k or ``N_{k+1}`` in frame k + 1, the slice folds back over itself there,
    and the 4D boundary folds over the space-time solid (it is no longer the boundary of
    ``{(x, t): x in S(t)}`` and its "volume" counts some space-time negatively). So every wall
    tetrahedron must satisfy ``n_xyz . N_k > 0`` and ``n_xyz . N_{k+1} > 0``; for the two
    tetrahedra holding a frame's triangle this is ``N_k . N_{k+1} > 0`` (no triangle turns by
    90 degrees or more between two frames). In addition the linearly moving triangle's own area
    normal ``N(s)``, a quadratic in s, must stay on the positive side of both ``N_k`` and
    ``N_{k+1}`` for all s in [0, 1] (tested exactly on the quadratics' Bernstein coefficients):
    it never degenerates or reverses. The first test is about the flat pieces and is cured by
    smaller steps (the pieces tend to the moving triangle as the step shrinks): a triangle
    turning within its own plane by more than its smallest angle folds its middle piece, e.g. a
    box's 1:5 right triangles spinning by 12 degrees per frame. Both are local tests: two
    distant parts of the surface passing through each other (the frames themselves are not
    tested for self-intersection either) are not detected.

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(2, radius=0.5)
    >>> frames = [ball.copy().apply_translation([0.2 * k, 0.0, 0.0]) for k in range(3)]
    >>> mesh = sweep(frames, times=[0.0, 0.5, 1.0])
    >>> mesh.check().ok, bool(abs(mesh.volume - ball.volume) < 1e-12)
    (True, True)
    """
    points, tris = _sweep_frames(frames)
    n, n_pts = points.shape[:2]
    t = _sweep_times(times, n)
    # the result (int64 tetrahedra, float64 vertices) and the mesh's normals, before any work
    check_memory(
        (3 * len(tris) * (n - 1) + 2 * len(tris)) * 4 * 8 * 2 + n * n_pts * 4 * 8,
        "sweeping these frames",
        hint="use fewer frames or coarser meshes",
    )
    caps = [_star_cap(points[k], tris, f"frames[{k}]") for k in (0, n - 1)]
    _check_sweep_walls(points, tris, t)

    ids = np.arange(n_pts)
    centre_ids = (n * n_pts, n * n_pts + 1)
    vertices = np.concatenate(
        [_with_w(points[k], t[k]) for k in range(n)]
        + [_with_w(caps[0].points[-1:], t[0]), _with_w(caps[1].points[-1:], t[-1])]
    )

    def cap_tets(solid: TetSolid, k: int, centre: int) -> np.ndarray:
        # the star's points are the frame's, then its centre (index n_pts)
        return np.where(solid.tets == n_pts, centre, solid.tets + k * n_pts)

    simplices = np.concatenate(
        [
            _reversed(cap_tets(caps[0], 0, centre_ids[0])),  # first cap faces -w (as prism's lower cap)
            cap_tets(caps[1], n - 1, centre_ids[1]),  # last cap faces +w
            *(_wall_tets(tris, k * n_pts + ids, (k + 1) * n_pts + ids) for k in range(n - 1)),
        ]
    )
    return _mesh(vertices, simplices)


# --- helpers ---------------------------------------------------------------------------------


def _star_tets(surface: trimesh.Trimesh, centre: np.ndarray) -> TetSolid | None:
    """Tetrahedra (centre, face) for every face, or None if some face is not seen from centre.

    A face is seen when its tetrahedron is positive by a margin (1e-9 of the diagonal cubed), so
    no flat tetrahedron is made.
    """
    pts = np.asarray(surface.vertices, dtype=np.float64)
    faces = np.asarray(surface.faces, dtype=np.int64)
    points = np.vstack([pts, centre[None, :]])
    # det[a - o; b - o; c - o] = (a - o) . ((b - a) x (c - a)) > 0 iff outward (a, b, c) faces
    # away from o
    tets = np.column_stack([np.full(len(faces), len(pts)), faces])
    if (_tet_dets(points, tets) <= 1e-9 * _scale(points) ** 3).any():
        return None
    return TetSolid.from_arrays(points, tets)


def _sweep_frames(frames: object) -> tuple[np.ndarray, np.ndarray]:
    """Frames as points (n, V, 3) float64 (referenced vertices only) and outward triangles
    (F, 3) int64 shared by all, checked (see :func:`sweep`)."""
    if isinstance(frames, (str, os.PathLike)) or hasattr(frames, "vertices") or not hasattr(frames, "__iter__"):
        raise TypeError(
            "`frames` must be a sequence of frames (triangle meshes, (vertices, triangles) pairs or "
            f"paths), got {type(frames).__name__}"
        )
    frames = list(frames)  # a generator of frames too
    if len(frames) < 2:
        raise ValueError(f"`frames` must hold at least 2 frames (the motion's start and end), got {len(frames)}")
    points, faces = [], None
    for k, frame in enumerate(frames):
        name = f"frames[{k}]"
        surface = _sweep_frame(frame, name)
        pts = np.asarray(surface.vertices, dtype=np.float64)
        tris = np.asarray(surface.faces, dtype=np.int64)
        if k == 0:
            faces = tris
        elif len(pts) != len(points[0]):
            raise ValueError(
                f"`{name}` has {len(pts)} vertices but `frames[0]` has {len(points[0])}: the frames must be "
                "one mesh moved (same vertices, same faces)"
            )
        elif tris.shape != faces.shape or not np.array_equal(tris, faces):
            where = (
                f"{len(tris)} faces against {len(faces)}"
                if tris.shape != faces.shape
                else f"first at face {int(np.flatnonzero((tris != faces).any(axis=1))[0])}"
            )
            raise ValueError(
                f"`{name}` has other faces than `frames[0]` ({where}): the frames must be one mesh "
                "moved (same vertices, same faces)"
            )
        points.append(pts)
    used, tris = np.unique(faces, return_inverse=True)  # drop vertices no face uses
    return np.stack(points)[:, used], tris.reshape(-1, 3).astype(np.int64)


def _sweep_frame(frame: object, name: str) -> trimesh.Trimesh:
    """One frame as a checked trimesh; non-finite vertices refused before trimesh sees them."""
    if isinstance(frame, (str, os.PathLike)):
        try:
            return load_surface(frame)
        except ValueError as exc:
            raise ValueError(f"`{name}`: {exc}") from None
    vertices = getattr(frame, "vertices", None)
    if vertices is None and isinstance(frame, (tuple, list)) and len(frame) == 2:
        vertices = frame[0]
    if vertices is not None:
        as_array(vertices, name, dtype=np.float64, finite=True)
    return _as_surface(frame, name)


def _sweep_times(times: object, n: int) -> np.ndarray:
    """``times`` as (n,) float64, finite and strictly increasing (default 0 .. n - 1)."""
    if times is None:
        return np.arange(n, dtype=np.float64)
    t = as_array(times, "times", ndim=1, dtype=np.float64, finite=True)
    if len(t) != n:
        raise ValueError(f"`times` must give one time per frame ({n}), got {len(t)}")
    steps = np.diff(t)
    if (steps <= 0).any():
        k = int(np.flatnonzero(steps <= 0)[0])
        raise ValueError(
            f"`times` must be strictly increasing, got times[{k}] = {t[k]:g} >= times[{k + 1}] = {t[k + 1]:g}"
        )
    return t


def _star_cap(points: np.ndarray, tris: np.ndarray, name: str) -> TetSolid:
    """The frame's solid cut from its centre of mass (else its bounding-box centre) into
    tetrahedra, its points the frame's followed by the centre; refused if neither sees every face."""
    import trimesh

    surface = trimesh.Trimesh(points, tris, process=False)
    for centre in (surface.center_mass, points.min(axis=0) / 2 + points.max(axis=0) / 2):
        star = _star_tets(surface, np.asarray(centre, dtype=np.float64))
        if star is not None:
            return star
    raise ValueError(
        f"`{name}` is not star-shaped from its centre of mass or bounding-box centre: sweep cuts the "
        "first and last solids into tetrahedra from a centre that sees every face, which keeps their "
        "surfaces (the walls start from them) exactly; begin and end the motion with a star-shaped "
        "(e.g. convex) frame"
    )


# A wall piece faces outward when its normal's cosine with the triangle's outward normals is
# above this: zero up to rounding (a flat or turned-over piece has <= 0).
_WALL_COS = 1e-12


def _check_sweep_walls(points: np.ndarray, tris: np.ndarray, t: np.ndarray) -> None:
    """Refuse a motion that turns a wall over between two frames (criterion: :func:`sweep`)."""
    ids = np.arange(points.shape[1])
    for k in range(len(points) - 1):
        lo, hi = points[k][tris], points[k + 1][tris]  # (F, 3 corners, 3)
        e1, e2 = lo[:, 1] - lo[:, 0], lo[:, 2] - lo[:, 0]
        f1, f2 = hi[:, 1] - hi[:, 0], hi[:, 2] - hi[:, 0]
        n0, n1 = np.cross(e1, e2), np.cross(f1, f2)
        half_mixed = (np.cross(e1, f2) + np.cross(f1, e2)) / 2  # N(s) = (1-s)^2 n0 + 2s(1-s) m + s^2 n1
        len0, len1 = np.linalg.norm(n0, axis=1), np.linalg.norm(n1, axis=1)
        bad = np.zeros(len(tris), dtype=bool)
        for ref, length in ((n0, len0), (n1, len1)):
            # N(s) . ref > 0 on [0, 1] iff its Bernstein coefficients a, c > 0 and b > -sqrt(a c)
            a, b, c = (np.einsum("ij,ij->i", v, ref) for v in (n0, half_mixed, n1))
            tol = _WALL_COS * length * np.maximum(len0, len1)
            bad |= (a <= tol) | (c <= tol) | (b <= -np.sqrt(np.maximum(a, 0) * np.maximum(c, 0)) + tol)
        # the three wall tetrahedra per triangle, at unit time steps (the test is scale-free in w)
        vertices = np.concatenate([_with_w(points[k], 0.0), _with_w(points[k + 1], 1.0)])
        walls = _wall_tets(tris, ids, ids + len(ids))
        n_xyz = simplex_normals(vertices, walls)[:, :3].reshape(len(tris), 3, 3)
        len_w = np.linalg.norm(n_xyz, axis=2)
        for ref, length in ((n0, len0), (n1, len1)):
            cos = np.einsum("ijk,ik->ij", n_xyz, ref)
            bad |= (cos <= _WALL_COS * len_w * length[:, None]).any(axis=1)
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"`frames`: the motion from frames[{k}] (t = {t[k]:g}) to frames[{k + 1}] (t = {t[k + 1]:g}) "
                f"turns {int(bad.sum())} wall(s) over, e.g. triangle {j} (vertices {tris[j].tolist()} after "
                "dropping unused ones): moving linearly it degenerates, turns by 90 degrees or more, or its "
                "swept wall folds back. Add frames in between (smaller steps) or check the frames' vertex order"
            )


def _wall_tets(tris: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Three tetrahedra per triangle x interval, outward for outward triangles.

    ``lo[v]`` / ``hi[v]`` are the 4D vertex ids of 3D vertex ``v`` at the interval's two ends.
    The staircase split on the triangle's vertices sorted by id cuts each side quad (u, v), u < v,
    along the diagonal lo[u]-hi[v], so neighbouring prisms agree.
    """
    order = np.argsort(tris, axis=1, kind="stable")
    v = np.take_along_axis(tris, order, axis=1)
    a, b, c = v[:, 0], v[:, 1], v[:, 2]
    # In staircase order the 2nd tetrahedron is negative with respect to the product orientation,
    # so its last two vertices are swapped here; all three then share the orientation of
    # (sorted triangle) x interval.
    stair = np.stack(
        [
            np.column_stack([lo[a], lo[b], lo[c], hi[c]]),
            np.column_stack([lo[a], lo[b], hi[c], hi[b]]),
            np.column_stack([lo[a], hi[a], hi[b], hi[c]]),
        ],
        axis=1,
    )
    # Sorting by an odd permutation reversed the triangle. (triangle x interval) with the triangle
    # outward has its DESIGN.md normal pointing inward (det expands to -h (B x C).n3), so the
    # product orientation is flipped once more; both flips together: reverse when sorting was even.
    odd = _is_odd_permutation(order)
    out = np.where(odd[:, None, None], stair, stair[:, :, [0, 2, 1, 3]])
    return out.reshape(-1, 4)


def _is_odd_permutation(order: np.ndarray) -> np.ndarray:
    """Parity of each row of an (F, 3) permutation array: True when odd."""
    inversions = (order[:, 0] > order[:, 1]).astype(int) + (order[:, 0] > order[:, 2]) + (order[:, 1] > order[:, 2])
    return inversions % 2 == 1


def _reversed(simplices: np.ndarray) -> np.ndarray:
    """Same simplices, opposite orientation (swap the first two vertices)."""
    return simplices[:, [1, 0, 2, 3]]


def _distinct_rows(simplices: np.ndarray) -> np.ndarray:
    """Mask of rows whose vertex ids are all different."""
    s = np.sort(simplices, axis=1)
    return (np.diff(s, axis=1) != 0).all(axis=1)


def _drop_axis_faces(tris: np.ndarray, on_axis: np.ndarray) -> np.ndarray:
    """Remove triangles lying on x = 0; refuse point or edge contact (it would pinch)."""
    flat = on_axis[tris].all(axis=1)
    if not on_axis.any():
        return tris
    covered = np.zeros(len(on_axis), dtype=bool)
    covered[tris[flat].ravel()] = True
    if (on_axis & ~covered).any():
        bad = np.flatnonzero(on_axis & ~covered)[:3]
        raise ValueError(
            "`surface` touches the rotation plane x = 0 at isolated points (e.g. vertices "
            f"{bad.tolist()}); spinning would pinch the boundary. Move it into x > 0, or let it "
            "rest on x = 0 with whole faces"
        )
    edges = np.sort(tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    axis_edges = edges[on_axis[edges].all(axis=1)]
    face_edges = np.sort(tris[flat][:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    loose = ~_rows_in(axis_edges, face_edges)
    if loose.any():
        raise ValueError(
            "`surface` touches the rotation plane x = 0 along edges that bound no face on it "
            f"(e.g. edge {axis_edges[loose][0].tolist()}); spinning would pinch the boundary"
        )
    return tris[~flat]


def _rows_in(rows: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Mask of ``rows`` (N, 2) that appear in ``table`` (M, 2)."""
    if len(table) == 0:
        return np.zeros(len(rows), dtype=bool)
    width = int(max(rows.max(initial=0), table.max()) + 1)
    return np.isin(rows[:, 0] * width + rows[:, 1], table[:, 0] * width + table[:, 1])


def _tet_dets(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = points[tets]
    return np.linalg.det(p[:, 1:] - p[:, :1])


def _scale(points: np.ndarray) -> float:
    """Bounding-box diagonal (1 for a single point), the length unit for tolerances."""
    diag = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    return diag if diag > 0 else 1.0


def _with_w(points: np.ndarray, w: float) -> np.ndarray:
    return np.column_stack([points, np.full(len(points), w)])


def _as_surface(surface: object, name: str) -> trimesh.Trimesh:
    """``surface`` as a checked ``trimesh.Trimesh``: a trimesh as it is, a 3D triangle mesh in any
    other form :func:`ao4d.mesh.as_mesh` takes converted (vertices and winding kept)."""
    import trimesh

    from .mesh import as_mesh

    if not isinstance(surface, trimesh.Trimesh):
        try:
            mesh = as_mesh(surface, name)
        except TypeError:
            raise TypeError(
                f"`{name}` must be a trimesh.Trimesh, a 3D SimplexMesh, a (vertices, triangles) pair "
                f"or a TetSolid, got {type(surface).__name__}"
            ) from None
        if mesh.dim != 3:
            raise ValueError(f"`{name}` must be a 3D triangle mesh, got dimension {mesh.dim}")
        surface = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.simplices), process=False)
    _check_surface(surface, name)
    return surface


def _check_surface(surface: object, name: str) -> None:
    """Refuse anything but a watertight, consistently wound, outward triangle mesh."""
    import trimesh

    if not isinstance(surface, trimesh.Trimesh):
        raise TypeError(f"`{name}` must be a trimesh.Trimesh or TetSolid, got {type(surface).__name__}")
    if len(surface.faces) < 4:
        raise ValueError(f"`{name}` must have at least 4 faces, got {len(surface.faces)}")
    if not surface.is_watertight:
        raise ValueError(
            f"`{name}` is not watertight (it has boundary or non-manifold edges); "
            "it must bound a solid (try trimesh's fill_holes / repair)"
        )
    if not surface.is_winding_consistent:
        raise ValueError(f"`{name}` has inconsistent face winding (try trimesh.repair.fix_winding)")
    if surface.volume <= 0:
        raise ValueError(f"`{name}` is inside-out (negative volume {surface.volume:.6g}); call its .invert() first")


def _as_solid(solid: MeshLike, name: str) -> TetSolid:
    if isinstance(solid, TetSolid):
        return solid
    return tetrahedralize(_as_surface(solid, name))


def _surface_arrays(surface: MeshLike, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, 3) float64 and outward triangles (F, 3) int64 of a surface or solid."""
    if isinstance(surface, TetSolid):
        used, tris = np.unique(surface.boundary, return_inverse=True)
        return surface.points[used], tris.reshape(-1, 3).astype(np.int64)
    surface = _as_surface(surface, name)
    pts = np.asarray(surface.vertices, dtype=np.float64)
    used, tris = np.unique(np.asarray(surface.faces), return_inverse=True)
    return pts[used], tris.reshape(-1, 3).astype(np.int64)


def _mesh(vertices: np.ndarray, simplices: np.ndarray) -> SimplexMesh:
    from .mesh import SimplexMesh

    return SimplexMesh(vertices, simplices)
