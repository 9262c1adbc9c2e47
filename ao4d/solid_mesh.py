"""Solid simplex meshes: d-simplices filling a region of R^d (pentatopes in 4D), as
:func:`ao4d.extract_solid` makes them; their volume, boundary, hyperplane cuts and files.

A :class:`SolidMesh` has ``vertices`` (n, d) and ``simplices`` (m, d + 1), every simplex
positively oriented (``det[p1 - p0; ...; pd - p0] >= 0``). Its boundary is the
(d-1)-faces used by one simplex, oriented outward (a :class:`ao4d.SimplexMesh`). The cut of a 4D
solid by a hyperplane is a :class:`SolidSlice`: tetrahedra in the hyperplane's 3D frame
(:func:`ao4d.slicing.hyperplane_basis`, as :meth:`ao4d.SimplexMesh.slice` uses), written as
``.vtu`` (``VTK_TETRA``) for ParaView. Files: ``.npz`` (with the key ``solid_format``, which
marks a solid) and, for 2D and 3D solids, ``.vtu``; :func:`load` (``ao4d.load``) reads a solid
or a surface file, whichever it holds.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._optional import require
from ._validate import as_array
from .geometry import signed_volumes

__all__ = ["SolidMesh", "SolidSlice", "SolidReport", "SOLID_FORMAT", "load"]

SOLID_FORMAT = 1  # the npz key ``solid_format``: marks a SolidMesh file and its version


def _facets(simplices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All (d-1)-faces, outward oriented for positive simplices: (faces (m*(d+1), d) in their
    orientation, the row-sorted faces, and the simplex of each)."""
    k = simplices.shape[1]
    d = k - 1
    faces = []
    for i in range(k):
        f = np.delete(simplices, i, axis=1)
        if (d - i) % 2 == 0:  # the face opposite vertex i: this order points inward, swap
            f = f[:, [1, 0, *range(2, d)]]
        faces.append(f)
    faces = np.concatenate(faces)
    return faces, np.sort(faces, axis=1), np.tile(np.arange(len(simplices)), k)


@dataclass(frozen=True)
class SolidReport:
    """What :meth:`SolidMesh.check` found.

    Attributes
    ----------
    ok : bool
        Conforming, consistently oriented, no negative volume, closed boundary.
    boundary_facets, interior_facets : int
        Faces used by one simplex, and by two.
    overused_facets : int
        Faces used by more than two simplices (0 when conforming).
    misoriented_facets : int
        Interior faces that both simplices orient the same way.
    negative, degenerate : int
        Simplices of negative volume, and of zero volume (below ``rtol`` of the largest).
    boundary_closed : bool
        Whether the boundary's (d-2)-faces are each shared by exactly two boundary faces.
    """

    ok: bool
    boundary_facets: int
    interior_facets: int
    overused_facets: int
    misoriented_facets: int
    negative: int
    degenerate: int
    boundary_closed: bool


class SolidMesh:
    """A solid in R^d (d = 2, 3, 4) cut into positively oriented d-simplices.

    Parameters
    ----------
    vertices : (n, d) array_like
        Finite vertex coordinates.
    simplices : (m, d + 1) array_like of int
        Vertex indices of each simplex.

    Examples
    --------
    >>> solid = SolidMesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]])
    >>> solid.volume, solid.boundary().n_simplices
    (0.5, 3)
    """

    def __init__(self, vertices: Any, simplices: Any) -> None:
        v = as_array(vertices, "vertices", ndim=2, dtype=np.float64, finite=True)
        if v.shape[1] not in (2, 3, 4):
            raise ValueError(f"`vertices` must have 2, 3 or 4 columns, got shape {v.shape}")
        s = as_array(simplices, "simplices", ndim=2)
        if s.size == 0:
            s = s.reshape(0, v.shape[1] + 1)
        if s.dtype.kind not in "iu":
            raise TypeError(f"`simplices` must hold integers, got dtype {s.dtype}")
        if s.shape[1] != v.shape[1] + 1:
            raise ValueError(
                f"`simplices` must have {v.shape[1] + 1} columns for {v.shape[1]}D vertices, got {s.shape}"
            )
        if len(s) and (s.min() < 0 or s.max() >= len(v)):
            raise ValueError(f"`simplices` must index the {len(v)} vertices, got values in [{s.min()}, {s.max()}]")
        self._vertices, self._simplices = v.copy(), s.astype(np.int64)
        self._volumes: np.ndarray | None = None

    @classmethod
    def _adopt(cls, vertices: np.ndarray, simplices: np.ndarray) -> SolidMesh:
        """Wrap an extractor's own fresh arrays without copies or checks."""
        self = cls.__new__(cls)
        self._vertices, self._simplices, self._volumes = vertices, simplices, None
        return self

    @property
    def vertices(self) -> np.ndarray:
        """(n, d) float64 vertex coordinates (read-only view)."""
        view = self._vertices.view()
        view.flags.writeable = False
        return view

    @property
    def simplices(self) -> np.ndarray:
        """(m, d + 1) int64 vertex indices (read-only view)."""
        view = self._simplices.view()
        view.flags.writeable = False
        return view

    @property
    def dim(self) -> int:
        """The dimension d."""
        return int(self._vertices.shape[1])

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return len(self._vertices)

    @property
    def n_simplices(self) -> int:
        """Number of simplices."""
        return len(self._simplices)

    def __repr__(self) -> str:
        return f"SolidMesh(dim={self.dim}, vertices={self.n_vertices}, simplices={self.n_simplices})"

    @property
    def simplex_volumes(self) -> np.ndarray:
        """(m,) signed d-volume of each simplex (>= 0 for a positively oriented solid)."""
        if self._volumes is None:
            self._volumes = signed_volumes(self._vertices, self._simplices)
        return self._volumes

    @property
    def volume(self) -> float:
        """Total d-volume (area in 2D): the sum of the simplices' volumes."""
        return float(self.simplex_volumes.sum())

    def boundary(self) -> Any:
        """The faces used by one simplex, oriented outward: a closed :class:`ao4d.SimplexMesh`.

        Returns
        -------
        SimplexMesh
            Only the vertices the boundary uses, in the solid's order.
        """
        from .mesh import SimplexMesh

        faces, keys, _ = _facets(self._simplices)
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        faces = faces[counts[inverse.ravel()] == 1]
        used = np.unique(faces)
        remap = np.full(self.n_vertices, -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return SimplexMesh(self._vertices[used], remap[faces])

    def check(self, *, rtol: float = 1e-12) -> SolidReport:
        """Conformity, orientation and the boundary's closedness.

        Parameters
        ----------
        rtol : float
            Simplices with ``|volume|`` below ``rtol`` times the largest count as degenerate.

        Returns
        -------
        SolidReport
            The counts; ``ok`` when nothing is wrong.
        """
        faces, keys, _ = _facets(self._simplices)
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.ravel()
        n_once, n_twice, n_over = (int((counts == c).sum()) for c in (1, 2)), None, int((counts > 2).sum())
        n_once, n_twice = n_once
        # an interior face's two copies must be opposite: their orientations, as the parity of
        # the sort that makes them equal, differ
        parity = _parity(faces)
        twice = counts[inverse] == 2
        order = np.argsort(inverse[twice], kind="stable")
        par = parity[twice][order].reshape(-1, 2)
        misoriented = int((par[:, 0] == par[:, 1]).sum())
        vol = self.simplex_volumes
        scale = float(np.abs(vol).max()) if len(vol) else 0.0
        negative = int((vol < -rtol * scale).sum())
        degenerate = int((np.abs(vol) <= rtol * scale).sum())
        closed = True
        if n_once:
            closed = self.boundary().check().closed
        ok = n_over == 0 and misoriented == 0 and negative == 0 and closed
        return SolidReport(ok, n_once, n_twice, n_over, misoriented, negative, degenerate, closed)

    def slice(self, point: Any, normal: Any) -> SolidSlice:
        """The cut of a 4D solid by the hyperplane through ``point`` with ``normal``: tetrahedra.

        Each pentatope crossed by the hyperplane gives the simplex table's tetrahedra of its
        cross-section (vertices sorted by index, so neighbours agree on shared faces); a vertex
        in the hyperplane is one output vertex, and tetrahedra with a repeated vertex (zero
        volume) are left out.

        Parameters
        ----------
        point : (4,) array_like
            A point of the hyperplane.
        normal : (4,) array_like
            Its normal (any nonzero length).

        Returns
        -------
        SolidSlice
            Vertices ``y = B (x - point)`` with ``B = slicing.hyperplane_basis(normal)``, as in
            :meth:`ao4d.SimplexMesh.slice`; tetrahedra positively oriented in that frame.
        """
        from . import slicing

        if self.dim != 4:
            raise ValueError(f"`slice` needs a 4D solid, this one is {self.dim}D")
        origin = as_array(point, "point", ndim=1, shape_tail=(4,), dtype=np.float64, finite=True)
        n = slicing.unit_normal(normal, 4)
        return _slice(self._vertices, self._simplices, origin, n)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the solid, atomically: ``.npz`` (any d, lossless) or ``.vtu`` (2D triangles,
        3D tetrahedra; for a 4D solid write a :meth:`slice`).

        Parameters
        ----------
        path : str or path-like
            The file to write, its suffix naming the format.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        from ._npz import write_npz

        suffix = Path(path).suffix.lower()
        if suffix == ".npz":
            write_npz(
                path,
                {"solid_format": np.array(SOLID_FORMAT), "vertices": self._vertices, "simplices": self._simplices},
            )
            return Path(path)
        if suffix == ".vtu":
            if self.dim == 4:
                raise ValueError("`path`: a 4D solid has no VTK cell type; save a slice() of it as .vtu")
            return _write_vtu(path, self._vertices, self._simplices)
        raise ValueError(f"`path` must end in .npz or .vtu, got {str(path)!r}")

    @classmethod
    def load(cls, path: str | os.PathLike) -> SolidMesh:
        """Read a solid written by :meth:`save` as ``.npz``.

        Parameters
        ----------
        path : str or path-like
            A ``.npz`` file with the key ``solid_format``.

        Returns
        -------
        SolidMesh
            The solid.
        """
        import zipfile

        from ._validate import regular_file

        p = regular_file(path, "path")
        if not zipfile.is_zipfile(p):
            raise ValueError(f"`path` {str(p)!r} is not a readable .npz file")
        with np.load(p, allow_pickle=False) as data:
            if "solid_format" not in data.files:
                raise ValueError(
                    f"`path` {str(p)!r} is not a SolidMesh file (no `solid_format` key; a surface mesh "
                    "is read with ao4d.SimplexMesh.load)"
                )
            if int(data["solid_format"]) > SOLID_FORMAT:
                raise ValueError(
                    f"`path` {str(p)!r} has solid format {int(data['solid_format'])}; this reads {SOLID_FORMAT}"
                )
            return cls(data["vertices"], data["simplices"])


def load(path: str | os.PathLike):
    """Read any mesh ao4d saves: a surface (:class:`ao4d.SimplexMesh`) or, from a ``.npz``
    holding the key ``solid_format``, a solid (:class:`ao4d.SolidMesh`).

    Parameters
    ----------
    path : str or path-like
        A file written by ``SimplexMesh.save`` (``.npz``, ``.vtu``, text) or ``SolidMesh.save``
        (``.npz``; a solid's ``.vtu`` reads as the surface of its cells' type, so load it with
        ``pyvista``).

    Returns
    -------
    SimplexMesh or SolidMesh
        What the file holds.

    Examples
    --------
    >>> import ao4d, tempfile, pathlib
    >>> solid = ao4d.extract_solid_field(ao4d.fields.hypersphere(1.0), 6, (-1.3, 1.3))
    >>> path = solid.save(pathlib.Path(tempfile.mkdtemp()) / "ball.npz")
    >>> type(ao4d.load(path)).__name__
    'SolidMesh'
    """
    import zipfile
    import zlib

    from ._npz import npz_member_problem
    from ._validate import regular_file
    from .mesh import SimplexMesh

    if Path(path).suffix.lower() == ".npz" and zipfile.is_zipfile(regular_file(path, "path")):
        p = Path(path)  # (not a zip archive: SimplexMesh.load says why)
        try:
            with np.load(p, allow_pickle=False) as data:
                solid = "solid_format" in data.files
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ValueError(f"`path` {str(p)!r} is not a readable .npz file ({npz_member_problem(exc)})") from None
        if solid:
            return SolidMesh.load(p)
    return SimplexMesh.load(path)


def _parity(rows: np.ndarray) -> np.ndarray:
    """(k,) parity (0 even, 1 odd) of the permutation that sorts each row."""
    order = np.argsort(rows, axis=1, kind="stable")
    k = rows.shape[1]
    inv = np.zeros(len(rows), dtype=np.int64)
    for i in range(k):
        for j in range(i + 1, k):
            inv += order[:, i] > order[:, j]
    return inv % 2


@dataclass(frozen=True)
class SolidSlice:
    """Tetrahedra of a 4D solid's cut by a hyperplane, in the hyperplane's 3D frame.

    Attributes
    ----------
    vertices : (k, 3) numpy.ndarray
        ``y = basis @ (x - point)``.
    tets : (t, 4) numpy.ndarray
        Positively oriented tetrahedra.
    point, normal : (4,) numpy.ndarray
        The hyperplane (unit normal).
    basis : (3, 4) numpy.ndarray
        :func:`ao4d.slicing.hyperplane_basis` of the normal.
    """

    vertices: np.ndarray
    tets: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    basis: np.ndarray

    @property
    def volume(self) -> float:
        """Total 3-volume of the tetrahedra."""
        return float(signed_volumes(self.vertices, self.tets).sum())

    def to_solid(self) -> SolidMesh:
        """The cut as a 3D :class:`SolidMesh`.

        Returns
        -------
        SolidMesh
            The same vertices and tetrahedra.
        """
        return SolidMesh(self.vertices, self.tets)

    def to_pyvista(self) -> Any:
        """A ``pyvista.UnstructuredGrid`` of ``VTK_TETRA`` cells.

        Returns
        -------
        pyvista.UnstructuredGrid
            The tetrahedra.
        """
        return _grid(self.vertices, self.tets)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the tetrahedra as a ``.vtu`` for ParaView, atomically.

        Parameters
        ----------
        path : str or path-like
            Ending in ``.vtu``.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        if Path(path).suffix.lower() != ".vtu":
            raise ValueError(f"`path` must end in .vtu, got {str(path)!r}")
        return _write_vtu(path, self.vertices, self.tets)


def _grid(vertices: np.ndarray, simplices: np.ndarray) -> Any:
    pv = require("pyvista", "writing .vtu meshes")
    points = np.zeros((len(vertices), 3))
    points[:, : vertices.shape[1]] = vertices
    kind = pv.CellType.TETRA if simplices.shape[1] == 4 else pv.CellType.TRIANGLE
    return pv.UnstructuredGrid({kind: np.asarray(simplices, dtype=np.int64)}, points)


def _write_vtu(path: str | os.PathLike, vertices: np.ndarray, simplices: np.ndarray) -> Path:
    from ._atomic import atomic_path

    grid = _grid(vertices, simplices)
    with atomic_path(path) as tmp:
        grid.save(tmp, binary=True)
    return Path(path)


def _slice(vertices: np.ndarray, simplices: np.ndarray, origin: np.ndarray, normal: np.ndarray) -> SolidSlice:
    """Marching pentatopes on ``s = (x - origin) . normal`` with the 4D simplex table."""
    from .marching import lut
    from .slicing import hyperplane_basis

    table = lut.load(4, "simplex")
    basis = hyperplane_basis(normal)
    n_v = len(vertices)
    s = (vertices - origin) @ normal
    srt = np.sort(simplices, axis=1)  # local vertex i: the i-th smallest index (shared faces agree)
    p = vertices[srt]
    # the table's reference simplex 0, e0, e0+e1, ... maps onto the sorted pentatope: its
    # orientation is that of the sorted rows (det of the map = det of the rows' differences)
    parity = np.sign(np.linalg.det(p[:, 1:] - p[:, :1]))
    case = ((s[srt] >= 0).astype(np.int64) << np.arange(5)).sum(axis=1)
    counts = np.diff(table.offsets)[case]
    total = int(counts.sum())
    if total == 0:
        return SolidSlice(np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int64), origin, normal, basis)
    first = np.cumsum(counts) - counts
    rows = np.repeat(table.offsets[:-1][case] - first, counts) + np.arange(total)
    src = np.repeat(np.arange(len(srt)), counts)
    edges = table.edges[table.simplices[rows]]  # (T, 4, 2) local ends: lower-case end first
    a = srt[src[:, None], edges[..., 0]]
    b = srt[src[:, None], edges[..., 1]]
    neg_a = s[a] < 0  # order each edge (negative end, positive end)
    lo, hi = np.where(neg_a, a, b), np.where(neg_a, b, a)
    key = np.where(s[hi] == 0.0, n_v * n_v + hi, lo * n_v + hi)  # a vertex in the plane: itself
    tets = key
    flip = parity[src] < 0
    tets[flip, :2] = tets[flip, 1::-1]
    unique, inverse = np.unique(tets, return_inverse=True)
    tets = inverse.reshape(-1, 4)
    good = np.array([len(set(r)) == 4 for r in tets.tolist()], dtype=bool) if len(tets) else np.zeros(0, bool)
    tets = tets[good]
    on_vertex = unique >= n_v * n_v
    ga = np.where(on_vertex, unique - n_v * n_v, unique // n_v)
    gb = np.where(on_vertex, ga, unique % n_v)
    sa, sb = s[ga], s[gb]
    t = np.where(on_vertex, 0.0, sa / np.where(on_vertex, -1.0, sa - sb))
    points = vertices[ga] + t[:, None] * (vertices[gb] - vertices[ga])
    coords = (points - origin) @ basis.T
    used = np.unique(tets)
    remap = np.full(len(unique), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return SolidSlice(coords[used], remap[tets], origin, normal, basis)
