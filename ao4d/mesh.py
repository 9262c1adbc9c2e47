"""Simplicial hypersurfaces in R^d (d = 2, 3, 4): the mesh type every ao4d stage passes around.

A :class:`SimplexMesh` holds ``vertices`` (V, d) and ``simplices`` (S, d): each simplex is a
(d-1)-simplex of d vertex indices, so a 4D mesh is made of tetrahedra (a 3-manifold in R^4), a 3D
mesh of triangles and a 2D mesh of line segments.

Orientation (DESIGN.md): simplex (p0, ..., p_{d-1}) has normal n with
``n . x = det[p1 - p0; ...; p_{d-1} - p0; x]`` (rows, x last). In 3D this is the cross product
``(p1 - p0) x (p2 - p0)``; in 2D it is ``(p1 - p0)`` turned clockwise, so an outward-oriented 2D
polygon runs clockwise. ``|n| = (d-1)! * measure``. Meshes that ao4d produces are outward
oriented, so the enclosed volume is positive.

Caching follows trimesh: the source arrays (``vertices``, ``simplices``) are stored read-only, and
every derived value (normals, measures, volume, face adjacency, components, the check report, and
whatever other modules put in :attr:`SimplexMesh.cache`, such as the BVH) is computed once and
dropped as soon as a source array is replaced (``mesh.vertices = new``). In-place edits of the
source arrays are refused (numpy raises "assignment destination is read-only"), so a cached value
can never be stale. The file is long because it stays one module: the class and the cache that
ties every derived value to its arrays are one idea (the computations live in geometry,
topology, slicing and mesh_files).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import slicing, topology
from ._validate import as_array, as_real
from .geometry import simplex_normals, vertex_sums
from .io import mesh_files
from .topology import InsideOutWarning, MeshReport, warn_if_inside_out  # noqa: F401 (re-exported)

if TYPE_CHECKING:  # pragma: no cover - typing only
    import os

    import trimesh

__all__ = ["SimplexMesh", "MeshReport", "as_mesh", "as_meshes", "concatenate", "InsideOutWarning", "warn_if_inside_out"]

DIMS = (2, 3, 4)


# --------------------------------------------------------------------------------------------
# per-element data dictionaries
# --------------------------------------------------------------------------------------------


class _DataDict(dict):
    """A dict of arrays whose first axis must match the mesh's vertex or simplex count.

    It holds the count, not the mesh (the mesh updates it when its arrays change): a reference
    back would make every mesh a reference cycle, kept with its BVH and device buffers until
    the garbage collector runs rather than freed when the last name goes.
    """

    def __init__(self, n: int, kind: str, data: Mapping[str, Any] | None = None):
        super().__init__()
        self.n = int(n)
        self._kind = kind
        for key, value in (data or {}).items():
            self[key] = value

    def _expected(self) -> int:
        return self.n

    def __setitem__(self, key: str, value: Any) -> None:
        if not isinstance(key, str) or not key:
            raise TypeError(f"`{self._kind}` keys must be nonempty strings, got {key!r}")
        arr = as_array(value, f"{self._kind}[{key!r}]")
        n = self._expected()
        if arr.ndim == 0 or arr.shape[0] != n:
            raise ValueError(
                f"`{self._kind}[{key!r}]` must have first dimension {n} (one value per "
                f"{'vertex' if self._kind == 'point_data' else 'simplex'}), got shape {arr.shape}"
            )
        super().__setitem__(key, arr)

    def update(self, *args: Any, **kwargs: Any) -> None:  # route through validation
        for key, value in dict(*args, **kwargs).items():
            self[key] = value

    def setdefault(self, key: str, default: Any = None) -> Any:
        if key not in self:
            self[key] = default
        return self[key]

    def copy_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(v, copy=True) for k, v in self.items()}


# --------------------------------------------------------------------------------------------
# the mesh
# --------------------------------------------------------------------------------------------


def _cached(func: Callable[[SimplexMesh], Any]) -> property:
    """A property computed once per mesh version; arrays are returned read-only."""
    name = func.__name__

    def getter(self: SimplexMesh) -> Any:
        try:
            return self._derived[name]
        except KeyError:
            value = func(self)
            if isinstance(value, np.ndarray):
                value.flags.writeable = False
            self._derived[name] = value
            return value

    getter.__doc__ = func.__doc__
    getter.__name__ = name
    return property(getter)


class SimplexMesh:
    """A hypersurface in R^d made of (d-1)-simplices: segments (2D), triangles (3D), tetrahedra (4D).

    Parameters
    ----------
    vertices : (V, d) array_like of float
        Vertex coordinates, d in {2, 3, 4}; converted to float64; must be finite.
    simplices : (S, d) array_like of int
        Vertex indices of each simplex, in ``[0, V)``; converted to int64. The vertex order
        defines the orientation (module docstring).
    point_data : mapping of str to (V, ...) array_like, optional
        Per-vertex attributes (for example ``"ao"``), carried through slicing and file I/O.
    cell_data : mapping of str to (S, ...) array_like, optional
        Per-simplex attributes.

    Notes
    -----
    ``vertices`` and ``simplices`` are stored as read-only copies; replace them by assignment
    (``mesh.vertices = new``), which validates the new array and drops every cached value. The
    :attr:`cache` dict is for other modules' per-mesh data (ao4d.bvh keeps the BVH there); it is
    emptied on the same occasions.

    Examples
    --------
    The boundary of the unit right triangle, oriented clockwise (outward, see module docstring):

    >>> mesh = SimplexMesh([[0, 0], [1, 0], [0, 1]], [[0, 2], [2, 1], [1, 0]])
    >>> float(mesh.volume), mesh.check().ok
    (0.5, True)
    """

    def __init__(
        self,
        vertices: Any,
        simplices: Any,
        *,
        point_data: Mapping[str, Any] | None = None,
        cell_data: Mapping[str, Any] | None = None,
    ) -> None:
        self._derived: dict[str, Any] = {}
        self._cache: dict[str, Any] = {}
        self._version = 0
        vertices = _as_vertices(vertices)
        self._vertices = vertices
        self._simplices = _as_simplices(simplices, vertices.shape[0], vertices.shape[1])
        self._point_data = _DataDict(len(vertices), "point_data", point_data)
        self._cell_data = _DataDict(len(self._simplices), "cell_data", cell_data)

    @classmethod
    def _adopt(cls, vertices: np.ndarray, simplices: np.ndarray) -> SimplexMesh:
        """A mesh that takes ``vertices`` ((V, d) float64) and ``simplices`` ((S, d) int64), both
        C-contiguous, finite and in range, as they are: no copy, no check; both become read-only.

        For arrays that ao4d's own engines just made (marching extraction), which nobody else
        holds: the copies and checks of the constructor cost as much as the marching there.
        """
        if (
            vertices.dtype != np.float64
            or simplices.dtype != np.int64
            or vertices.ndim != 2
            or simplices.shape[1:] != vertices.shape[1:]
            or not vertices.flags.c_contiguous
            or not simplices.flags.c_contiguous
        ):
            return cls(vertices, simplices)
        mesh = cls.__new__(cls)
        mesh._derived, mesh._cache, mesh._version = {}, {}, 0
        vertices.flags.writeable = False
        simplices.flags.writeable = False
        mesh._vertices, mesh._simplices = vertices, simplices
        mesh._point_data = _DataDict(len(vertices), "point_data", None)
        mesh._cell_data = _DataDict(len(simplices), "cell_data", None)
        return mesh

    # ---------------------------------------------------------------- source arrays
    @property
    def vertices(self) -> np.ndarray:
        """(V, d) float64, read-only: vertex coordinates."""
        return self._vertices

    @vertices.setter
    def vertices(self, value: Any) -> None:
        new = _as_vertices(value)
        if new.shape[1] != self.dim:
            raise ValueError(f"`vertices` must keep dimension {self.dim}, got shape {new.shape}")
        if new.shape[0] != self.n_vertices:
            if self._point_data:
                raise ValueError(
                    f"`vertices` must keep {self.n_vertices} rows while point_data is set; "
                    "build a new SimplexMesh to change the vertex count"
                )
            _check_indices(self._simplices, new.shape[0])
        self._vertices = new
        self._point_data.n = len(new)
        self._invalidate()

    @property
    def simplices(self) -> np.ndarray:
        """(S, d) int64, read-only: vertex indices of each simplex."""
        return self._simplices

    @simplices.setter
    def simplices(self, value: Any) -> None:
        new = _as_simplices(value, self.n_vertices, self.dim)
        if new.shape[0] != self.n_simplices and self._cell_data:
            raise ValueError(
                f"`simplices` must keep {self.n_simplices} rows while cell_data is set; "
                "build a new SimplexMesh to change the simplex count"
            )
        self._simplices = new
        self._cell_data.n = len(new)
        self._invalidate()

    @property
    def point_data(self) -> dict[str, np.ndarray]:
        """Per-vertex arrays, name -> (V, ...); assignments are checked for length."""
        return self._point_data

    @property
    def cell_data(self) -> dict[str, np.ndarray]:
        """Per-simplex arrays, name -> (S, ...); assignments are checked for length."""
        return self._cell_data

    @property
    def cache(self) -> dict[str, Any]:
        """Scratch space for other modules' per-mesh data (the BVH); cleared when the mesh changes."""
        return self._cache

    @property
    def version(self) -> int:
        """Incremented whenever ``vertices`` or ``simplices`` is replaced."""
        return self._version

    def _invalidate(self) -> None:
        self._version += 1
        self._derived.clear()
        self._cache.clear()

    # ---------------------------------------------------------------- basic facts
    @property
    def dim(self) -> int:
        """Ambient dimension d (2, 3 or 4)."""
        return int(self._vertices.shape[1])

    @property
    def n_vertices(self) -> int:
        return int(self._vertices.shape[0])

    @property
    def n_simplices(self) -> int:
        return int(self._simplices.shape[0])

    def __len__(self) -> int:
        return self.n_simplices

    def __reduce__(self) -> tuple:
        # pickle/deepcopy rebuild through __init__ (validated), never with stale caches
        return (
            _restore,
            (self._vertices, self._simplices, dict(self._point_data), dict(self._cell_data)),
        )

    def __repr__(self) -> str:
        data = ""
        if self._point_data:
            data += f", point_data={sorted(self._point_data)}"
        if self._cell_data:
            data += f", cell_data={sorted(self._cell_data)}"
        return f"SimplexMesh(dim={self.dim}, n_vertices={self.n_vertices}, n_simplices={self.n_simplices}{data})"

    def copy(self) -> SimplexMesh:
        """An independent copy (arrays and data copied; caches not shared).

        Returns
        -------
        SimplexMesh
            The copy.
        """
        return SimplexMesh(
            self._vertices.copy(),
            self._simplices.copy(),
            point_data=self._point_data.copy_arrays(),
            cell_data=self._cell_data.copy_arrays(),
        )

    # ---------------------------------------------------------------- derived geometry
    @_cached
    def bounds(self) -> np.ndarray:
        """(2, d) float64: per-axis minimum and maximum of the vertices (zeros if empty)."""
        if self.n_vertices == 0:
            return np.zeros((2, self.dim))
        return np.stack([self._vertices.min(axis=0), self._vertices.max(axis=0)])

    @property
    def scale(self) -> float:
        """Length of the bounding-box diagonal."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    @_cached
    def _raw_normals(self) -> np.ndarray:
        return simplex_normals(self._vertices, self._simplices)

    @_cached
    def simplex_measures(self) -> np.ndarray:
        """(S,) float64: (d-1)-volume of each simplex (length, area, volume for d = 2, 3, 4)."""
        return np.linalg.norm(self._raw_normals, axis=1) / math.factorial(self.dim - 1)

    @_cached
    def simplex_normals(self) -> np.ndarray:
        """(S, d) float64: unit normals (zero for degenerate simplices); outward on ao4d meshes."""
        raw = self._raw_normals
        length = np.linalg.norm(raw, axis=1, keepdims=True)
        return np.divide(raw, length, out=np.zeros_like(raw), where=length > 0)

    @_cached
    def simplex_centroids(self) -> np.ndarray:
        """(S, d) float64: mean of each simplex's vertices."""
        out = np.zeros((self.n_simplices, self.dim))
        for k in range(self.dim):
            out += self._vertices[self._simplices[:, k]]
        return out / self.dim

    @_cached
    def vertex_normals(self) -> np.ndarray:
        """(V, d) float64: unit, measure-weighted mean of the adjacent simplex normals.

        Vertices used by no simplex (or only by degenerate ones) get a zero vector.
        """
        total = self._vertex_normal_sums
        length = np.linalg.norm(total, axis=1, keepdims=True)
        return np.divide(total, length, out=np.zeros_like(total), where=length > 0)

    @_cached
    def _vertex_normal_sums(self) -> np.ndarray:
        # (V, d): the sum of the raw normals around each vertex (|raw| is proportional to the
        # measure: the weighting we want); AO's query normals start from the same sums
        raw = self._raw_normals
        return vertex_sums(raw, self._simplices, self.n_vertices)

    @property
    def measure(self) -> float:
        """Total (d-1)-volume: perimeter (2D), area (3D), boundary 3-volume (4D)."""
        return float(self.simplex_measures.sum())

    @_cached
    def _volume(self) -> float:
        # Divergence theorem: V = (1/d) sum_s integral_s x . n_hat dA = sum_s (p0 . n_s) / d!.
        # Measured from the bounding-box centre to limit cancellation far from the origin; for a
        # closed mesh the result does not depend on that choice.
        if self.n_simplices == 0:
            return 0.0
        centre = self.bounds.mean(axis=0)
        p0 = self._vertices[self._simplices[:, 0]] - centre
        return float(np.einsum("ij,ij->", p0, self._raw_normals) / math.factorial(self.dim))

    def _volume_not_negative(self) -> bool:
        """``self.volume >= 0``, mostly without the volume: from the vertex normal sums N_v.

        Every corner of a simplex lies on its hyperplane, so ``d * sum_s (p0 - c) . n_s`` is
        ``sum_v (v - c) . N_v``: V rows instead of a gather of S (a twentieth of the volume's
        time at a million simplices; the sums are kept for the vertex normals and AO). Where
        that sum is within its rounding bound of zero, the volume itself decides.
        """
        if self.n_simplices == 0 or "_volume" in self._derived:
            return self.volume >= 0
        rel = self._vertices - self.bounds.mean(axis=0)
        total = float(np.einsum("ij,ij->", rel, self._vertex_normal_sums))
        radius = float(np.sqrt(np.einsum("ij,ij->i", rel, rel).max()))
        raw = self._raw_normals
        measures = math.sqrt(self.n_simplices * float(np.vdot(raw, raw)))  # >= sum |n_s|
        # both sums err by far less than 1e-6 of radius * sum |n_s| (their terms' size); the
        # second term covers the corners' rounding off a sliver's hyperplane (edges <= 2 radius)
        bound = 1e-6 * self.dim * radius * measures + 1e-13 * self.n_simplices * (2.0 * radius) ** self.dim
        return total > bound or self.volume >= 0

    @property
    def volume(self) -> float:
        """Enclosed d-volume (area in 2D), positive for outward orientation.

        Exact for closed meshes; for open meshes it is the signed volume of the cone from the
        bounding-box centre.
        """
        return self._volume

    # ---------------------------------------------------------------- topology
    @_cached
    def _faces(self) -> topology.Faces:
        return topology.face_structure(self._simplices, self.n_vertices)

    @_cached
    def face_adjacency(self) -> np.ndarray:
        """(P, 2) int64: pairs of simplices sharing a (d-2)-face (a chain for non-manifold faces)."""
        return topology.face_adjacency(self._faces, self.dim)

    @_cached
    def _singular_vertices(self) -> int:
        return topology.singular_vertices(self._simplices, self.n_vertices, self._faces)

    @_cached
    def _component_labels(self) -> np.ndarray:
        stars = self._derived.get("_singular_vertices") == 0  # connected: the vertex graph will do
        return topology.component_labels(self._simplices, self.n_vertices, None if stars else self._faces)

    @_cached
    def _face_counts(self) -> tuple[int, int, int, int]:
        return topology.face_counts(self._simplices, self.n_vertices, self._derived.get("_faces"))

    def components(self) -> np.ndarray:
        """Label of the connected component of each simplex (joined through shared faces).

        Returns
        -------
        labels : (S,) int64
            Labels ``0..C-1``, numbered in order of each component's first simplex.
        """
        return self._component_labels.copy()

    def split(self) -> list[SimplexMesh]:
        """One mesh per connected component (see :meth:`components`), unused vertices dropped.

        Returns
        -------
        list of SimplexMesh
            The components.
        """
        labels = self._component_labels
        return [self.submesh(labels == c) for c in range(int(labels.max(initial=-1)) + 1)]

    def submesh(self, which: Any) -> SimplexMesh:
        """The simplices selected by a boolean mask or index array, with their vertices only.

        Parameters
        ----------
        which : (S,) bool or (K,) int array_like
            Simplices to keep.

        Returns
        -------
        mesh : SimplexMesh
            Vertices renumbered in their original order; point and cell data carried along.
        """
        sel = as_array(which, "which", ndim=1)
        if sel.dtype == bool:
            if sel.shape[0] != self.n_simplices:
                raise ValueError(f"`which` mask must have length {self.n_simplices}, got {sel.shape[0]}")
            sel = np.flatnonzero(sel)
        elif sel.size and sel.dtype.kind not in "iu":
            raise TypeError(f"`which` must be a boolean mask or integer indices, got {sel.dtype}")
        sel = sel.astype(np.int64)
        if sel.size and (sel.min() < -self.n_simplices or sel.max() >= self.n_simplices):
            raise IndexError(f"`which` holds simplex indices outside [0, {self.n_simplices})")
        simplices = self._simplices[sel]
        used = np.unique(simplices)
        remap = np.full(self.n_vertices, -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return SimplexMesh(
            self._vertices[used],
            remap[simplices],
            point_data={k: v[used] for k, v in self._point_data.items()},
            cell_data={k: v[sel] for k, v in self._cell_data.items()},
        )

    def boundary_faces(self) -> np.ndarray:
        """The (d-2)-faces used by only one simplex.

        Each face is listed in the orientation its simplex induces on it (the boundary operator),
        so the boundary of an oriented open mesh comes out oriented (in 2D a face is one vertex
        and its sign is not represented); empty for a closed mesh.

        Returns
        -------
        (B, d-1) int64 numpy.ndarray
            Vertex indices of the boundary faces.
        """
        return topology.boundary_faces(self._simplices, self._faces)

    def _mark_constructed(self, proved: tuple[str, ...]) -> None:
        """Record the report fields its construction guarantees (dropped when the arrays change)."""
        self._derived["_proved"] = tuple(proved)

    def check(self, *, rtol: float = 1e-12) -> MeshReport:
        """Topology and orientation report: closed, manifold, oriented, degenerate simplices.

        Vectorised: one sort of packed 64-bit face words, label propagation and an edge sort
        for vertex stars and links (skipped on a mesh straight from marching extraction, whose
        construction settles them: ``report.proved``; the face sort too on a mesh marched by
        cubes clear of the grid's boundary), a sparse-graph search for components.

        Parameters
        ----------
        rtol : float
            A simplex is degenerate when its measure is at most ``rtol * scale**(d-1)``
            (``scale`` = bounding-box diagonal); the default is about 10^4 float64 round-offs.

        Returns
        -------
        report : MeshReport
            ``report.ok`` is True for a closed, manifold, consistently oriented mesh;
            ``print(report)`` gives a readable summary.
        """
        key = ("report", as_real(rtol, "rtol", ge=0, lt=1))
        if key in self._derived:
            return self._derived[key]
        marks = self._derived.get("_proved", ())
        if marks == topology.MARCHING_CLOSED_PROVED and self.n_simplices * self.dim % 2 == 0:
            # closed and oriented by the table: every face in exactly two simplices (d faces each)
            n_faces, n_boundary, n_nonmanifold, n_misoriented = self.n_simplices * self.dim // 2, 0, 0, 0
            proved = marks
        else:
            n_faces, n_boundary, n_nonmanifold, n_misoriented = self._face_counts
            # the guarantee on vertex stars counts only where the computed faces agree with it
            marked = "n_singular_vertices" in marks
            proved = ("n_singular_vertices",) if marked and not (n_nonmanifold or n_misoriented) else ()
        threshold = rtol * self.scale ** (self.dim - 1)
        uses = np.bincount(self._simplices.ravel(), minlength=self.n_vertices)
        n_unused = int(np.count_nonzero(uses == 0))
        if proved:
            self._derived.setdefault("_singular_vertices", 0)
        n_singular = self._singular_vertices  # first: connected stars make the components cheaper
        n_components = (
            topology.component_count(self._simplices, self.n_vertices, n_unused)
            if n_singular == 0 and "_component_labels" not in self._derived
            else int(self._component_labels.max(initial=-1)) + 1
        )
        report = MeshReport(
            dim=self.dim,
            n_vertices=self.n_vertices,
            n_simplices=self.n_simplices,
            n_faces=n_faces,
            n_boundary_faces=n_boundary,
            n_nonmanifold_faces=n_nonmanifold,
            n_misoriented_faces=n_misoriented,
            n_singular_vertices=n_singular,
            n_degenerate=int(np.count_nonzero(self.simplex_measures <= threshold)),
            n_components=n_components,
            n_unused_vertices=n_unused,
            volume=self.volume,
            proved=proved,
            hint=self._cache.get(topology.GRID_EDGE_KEY, "") if n_boundary else "",
        )
        self._derived[key] = report
        return report

    # ---------------------------------------------------------------- transforms
    def flipped(self) -> SimplexMesh:
        """The same mesh with every simplex's orientation reversed (last two vertices swapped).

        Returns
        -------
        SimplexMesh
            The reversed mesh.
        """
        simplices = self._simplices.copy()
        simplices[:, [-2, -1]] = simplices[:, [-1, -2]]
        return SimplexMesh(
            self._vertices.copy(),
            simplices,
            point_data=self._point_data.copy_arrays(),
            cell_data=self._cell_data.copy_arrays(),
        )

    def transformed(self, matrix: Any, offset: Any = 0.0) -> SimplexMesh:
        """The mesh with vertices ``x @ matrix.T + offset`` (orientation reversed if det < 0).

        Parameters
        ----------
        matrix : (d, d) array_like
            Linear part; must be invertible.
        offset : (d,) array_like or float
            Translation.

        Returns
        -------
        SimplexMesh
            The transformed mesh, outward oriented like this one.
        """
        d = self.dim
        m = as_array(matrix, "matrix", ndim=2, shape_tail=(d, d), dtype=np.float64, finite=True)
        t = as_array(offset, "offset", ndim=(0, 1), dtype=np.float64, finite=True)
        if t.shape not in ((), (d,)):
            raise ValueError(f"`offset` must be a scalar or have shape ({d},), got {t.shape}")
        # the rank is relative to the matrix's size; a determinant of small steps underflows
        if np.linalg.matrix_rank(m) < d:
            raise ValueError(f"`matrix` must be invertible, got rank {np.linalg.matrix_rank(m)} of {d}")
        det = float(np.sign(np.linalg.slogdet(m)[0]))
        mesh = SimplexMesh(
            self._vertices @ m.T + t,
            self._simplices.copy(),
            point_data=self._point_data.copy_arrays(),
            cell_data=self._cell_data.copy_arrays(),
        )
        return mesh.flipped() if det < 0 else mesh

    # ---------------------------------------------------------------- slicing
    def slice(
        self,
        point: Any,
        normal: Any,
        *,
        attributes: Sequence[str] | None = None,
    ) -> trimesh.Trimesh:
        """Cut a 4D mesh by the hyperplane through ``point`` with ``normal``: a 3D triangle mesh.

        Marching tetrahedra on the signed distance ``s = (x - point) . n_hat`` of the vertices;
        a vertex with ``s == 0`` counts as on the positive side, so vertices, edges and faces
        lying exactly in the plane are handled without gaps or duplicates. Output vertices are
        merged (one per cut mesh edge, or the mesh vertex itself when it lies on the plane).

        Parameters
        ----------
        point : (4,) array_like
            A point of the hyperplane.
        normal : (4,) array_like
            Its normal (any nonzero length).
        attributes : sequence of str, optional
            Names in :attr:`point_data` to interpolate linearly onto the slice's vertices
            (default: all). Every cell_data array is copied to the triangles it produced.

        Returns
        -------
        slice : trimesh.Trimesh
            Vertices in the hyperplane's coordinates ``y = B (x - point)`` with ``B =
            slicing.hyperplane_basis(normal)`` (so ``x = point + y @ B``); triangles oriented outward
            within the slice when the mesh is outward oriented; point attributes in
            ``vertex_attributes``, cell data and ``"simplex"`` (source tetrahedron index) in
            ``face_attributes``. Empty (no faces) when the plane misses the mesh.
        """
        if self.dim != 4:
            raise ValueError(f"`slice` needs a 4D mesh, this one is {self.dim}D")
        if self.n_simplices == 0:
            raise ValueError("`mesh` has no simplices: there is nothing to slice")
        origin = as_array(point, "point", ndim=1, shape_tail=(4,), dtype=np.float64, finite=True)
        n = slicing.unit_normal(normal, 4)
        if attributes is None:
            names = list(self._point_data)
        else:
            if isinstance(attributes, str):
                raise TypeError("`attributes` must be a sequence of names, not a single string")
            names = list(attributes)
            missing = [a for a in names if a not in self._point_data]
            if missing:
                raise KeyError(f"`attributes` names unknown point_data {missing}; have {sorted(self._point_data)}")
        return slicing.slice_mesh(self, origin, n, {name: self._point_data[name] for name in names})

    # ---------------------------------------------------------------- conversions and I/O
    def to_trimesh(self) -> trimesh.Trimesh:
        """A 3D mesh as ``trimesh.Trimesh`` (no processing, vertex order kept); 3D only.

        Returns
        -------
        trimesh.Trimesh
            The triangles.
        """
        import trimesh

        if self.dim != 3:
            raise ValueError(f"`to_trimesh` needs a 3D mesh, this one is {self.dim}D")
        return trimesh.Trimesh(self._vertices.copy(), self._simplices.copy(), process=False)

    @classmethod
    def from_trimesh(cls, mesh: trimesh.Trimesh) -> SimplexMesh:
        """Wrap a ``trimesh.Trimesh`` (its face winding gives the orientation).

        Parameters
        ----------
        mesh : trimesh.Trimesh
            A 3D triangle mesh.

        Returns
        -------
        SimplexMesh
            The same triangles as a 3D simplex mesh.
        """
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.faces))

    def _arrays(self) -> mesh_files.MeshArrays:
        return mesh_files.MeshArrays(self._vertices, self._simplices, dict(self._point_data), dict(self._cell_data))

    def save(self, path: str | os.PathLike) -> Path:
        """Write the mesh to a file whose suffix names the format, atomically.

        ``.npz``: lossless, every point/cell data array, byte-reproducible; ``.vtu``: VTK
        unstructured grid for ParaView (4D: x, y, z as points, w as point array ``"w"``); any
        other suffix (``.txt``): plain text, geometry only. See :mod:`ao4d.io.mesh_files`.

        Parameters
        ----------
        path : str or path-like
            The file to write.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        return mesh_files.write(path, self._arrays())

    @classmethod
    def load(cls, path: str | os.PathLike) -> SimplexMesh:
        """Read a mesh written by :meth:`save` (format by suffix: ``.npz``, ``.vtu``, else text).

        Parameters
        ----------
        path : str or path-like
            A mesh file.

        Returns
        -------
        SimplexMesh
            The mesh, with its point and cell data.
        """
        vertices, simplices, point_data, cell_data = mesh_files.read(path)
        try:
            return cls(vertices, simplices, point_data=point_data, cell_data=cell_data)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"`path` {str(path)!r} does not hold a valid mesh: {exc}") from None

    def to_vtu(self, path: str | os.PathLike) -> Path:
        """Write a VTK ``.vtu`` for ParaView: :meth:`save` with a path that must end in ``.vtu``.

        Parameters
        ----------
        path : str or path-like
            The file to write, ending in ``.vtu``.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        if Path(path).suffix.lower() != ".vtu":
            raise ValueError(f"`path` must end in .vtu, got {str(path)!r}")
        return self.save(path)

    def to_pyvista(self):
        """The mesh as a ``pyvista.UnstructuredGrid`` (the ``.vtu`` layout).

        Returns
        -------
        pyvista.UnstructuredGrid
            The grid; in 4D x, y, z as points and w as the point array ``"w"``.
        """
        return mesh_files.to_pyvista(self._arrays())


def _restore(vertices, simplices, point_data, cell_data) -> SimplexMesh:
    return SimplexMesh(vertices, simplices, point_data=point_data, cell_data=cell_data)


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------


def _as_vertices(value: Any) -> np.ndarray:
    raw = value if isinstance(value, np.ndarray) else _plain_array(value, "vertices")
    if raw.dtype.kind not in "iuf" and raw.size:
        # strings, complex, bool, Decimal or other objects would be converted (or fail) silently
        raise TypeError(f"`vertices` must hold real numbers (float or int), got dtype {_dtype_words(raw)}")
    arr = as_array(raw, "vertices", ndim=2, dtype=np.float64, finite=True)
    if arr.shape[1] not in DIMS:
        raise ValueError(f"`vertices` must have shape (V, d) with d in {DIMS}, got {arr.shape}")
    arr = np.array(arr, dtype=np.float64, order="C", copy=True)
    arr.flags.writeable = False
    return arr


def _as_simplices(value: Any, n_vertices: int, d: int) -> np.ndarray:
    arr = as_array(value, "simplices")
    if arr.size == 0:
        arr = arr.reshape(0, d) if arr.ndim < 2 or arr.shape[-1] == 0 else arr
    if arr.ndim != 2 or arr.shape[1] != d:
        raise ValueError(
            f"`simplices` must have shape (S, {d}) for {d}D vertices (d vertex indices per "
            f"simplex), got shape {arr.shape}"
        )
    if arr.dtype.kind not in "iu" and arr.size:
        if arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
            pass  # integral floats (e.g. from a text file) are accepted
        else:
            raise TypeError(f"`simplices` must hold integer vertex indices, got dtype {_dtype_words(arr)}")
    # checked in the given dtype: as int64, uint64 indices >= 2**63 wrap to negatives and
    # floats beyond int64 become anything
    _check_indices(arr, n_vertices)
    arr = np.array(arr, dtype=np.int64, order="C", copy=True)
    arr.flags.writeable = False
    return arr


def _check_indices(simplices: np.ndarray, n_vertices: int) -> None:
    if simplices.size and (simplices.min() < 0 or simplices.max() >= n_vertices):
        bad = int(np.count_nonzero((simplices < 0) | (simplices >= n_vertices)))
        # .item() keeps the true value of any dtype (int() of a uint64 is right too, but a
        # float index is shown as given)
        raise ValueError(
            f"`simplices` holds {bad} vertex index(es) outside [0, {n_vertices}) "
            f"(range found: {simplices.min().item()}..{simplices.max().item()})"
        )


def _plain_array(value: Any, name: str) -> np.ndarray:
    """``value`` as numpy reads it, with no dtype forced (a ragged list is an error naming ``name``)."""
    try:
        return np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"`{name}` must be array-like of numbers: {exc}") from None


def _dtype_words(arr: np.ndarray) -> str:
    """The dtype, and for an object array the type of its first entry (``object (Decimal)``)."""
    if arr.dtype.kind == "O" and arr.size:
        return f"object ({type(arr.flat[0]).__name__})"
    return str(arr.dtype)


# --------------------------------------------------------------------------------------------
# combining meshes
# --------------------------------------------------------------------------------------------


_MESH_FORMS = (
    "a SimplexMesh, a trimesh.Trimesh, a (vertices, simplices) pair or an object with `vertices` and `simplices`"
)


def as_mesh(mesh: Any, name: str = "mesh") -> SimplexMesh:
    """``mesh`` as a :class:`SimplexMesh`: the one way every function that takes a mesh reads it.

    Parameters
    ----------
    mesh : SimplexMesh, trimesh.Trimesh or (vertices, simplices)
        A :class:`SimplexMesh` (returned as it is, so its cached values are reused); a 3D
        ``trimesh.Trimesh`` (its vertices and faces, :meth:`SimplexMesh.from_trimesh`); a pair
        of a (V, d) vertex array and an (S, d) simplex array; or any object with ``vertices``
        and ``simplices`` arrays. The last three are copied into a new mesh on every call.
    name : str
        The parameter's name in error messages.

    Returns
    -------
    SimplexMesh
        The mesh.

    Raises
    ------
    TypeError
        ``mesh`` is none of these, naming ``name``.
    ValueError
        The pair's arrays do not make a mesh (the reason, naming ``name``).

    Examples
    --------
    >>> as_mesh(([[0, 0], [1, 0], [0, 1]], [[0, 2], [2, 1], [1, 0]])).n_simplices
    3
    """
    if isinstance(mesh, SimplexMesh):
        return mesh
    if _is_trimesh(mesh):
        return SimplexMesh.from_trimesh(mesh)
    pair = _as_pair(mesh)
    if pair is None and hasattr(mesh, "vertices") and hasattr(mesh, "simplices"):
        pair = mesh.vertices, mesh.simplices
    if pair is None:
        raise TypeError(f"`{name}` must be {_MESH_FORMS}, got {type(mesh).__name__}")
    try:
        return SimplexMesh(*pair)
    except (TypeError, ValueError) as exc:
        raise type(exc)(f"`{name}` holds no valid mesh: {exc}") from None


def as_meshes(meshes: Any, name: str = "meshes") -> list[SimplexMesh]:
    """``meshes``, one mesh or a sequence of them, as a non-empty list of :class:`SimplexMesh`.

    Parameters
    ----------
    meshes : mesh or sequence of meshes
        One mesh in any form :func:`as_mesh` takes, or a list or tuple of them.
    name : str
        The parameter's name in error messages (an entry is ``name[i]``).

    Returns
    -------
    list of SimplexMesh
        At least one mesh.

    Raises
    ------
    TypeError
        ``meshes`` or an entry is not a mesh, naming it.
    ValueError
        ``meshes`` is empty, or a pair's arrays do not make a mesh.
    """
    if (
        isinstance(meshes, SimplexMesh)
        or _is_trimesh(meshes)
        or _as_pair(meshes) is not None
        or (hasattr(meshes, "vertices") and hasattr(meshes, "simplices"))
    ):
        return [as_mesh(meshes, name)]
    if isinstance(meshes, (str, bytes)) or not isinstance(meshes, Iterable):
        raise TypeError(f"`{name}` must be {_MESH_FORMS}, or a sequence of them, got {type(meshes).__name__}")
    items = [as_mesh(m, f"{name}[{i}]") for i, m in enumerate(meshes)]
    if not items:
        raise ValueError(f"`{name}` must contain at least one mesh")
    return items


def _is_trimesh(value: Any) -> bool:
    # by the class's home, not ``sys.modules["trimesh"]``: that module may be half-imported by
    # another thread, and reading the class's name imports nothing
    return any(c.__name__ == "Trimesh" and c.__module__ == "trimesh.base" for c in type(value).__mro__)


def _as_pair(value: Any) -> tuple[np.ndarray, Any] | None:
    """(vertices as an array, simplices) when ``value`` is a 2-sequence whose first entry is a
    2D array of numbers (so a list of two meshes is not a pair), else None."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        return None
    first = value[0]
    if isinstance(first, SimplexMesh) or _is_trimesh(first):
        return None
    try:
        vertices = np.asarray(first)
    except (TypeError, ValueError):  # ragged: a sequence of meshes or pairs
        return None
    if vertices.ndim != 2 or vertices.size == 0 and vertices.dtype.kind not in "iuf":
        return None
    # a 2D array of anything is a pair's vertices: SimplexMesh then says what is wrong with
    # their dtype (strings, complex, bool, objects) instead of "no mesh, got tuple"
    return vertices, value[1]


def concatenate(meshes: Iterable[SimplexMesh]) -> SimplexMesh:
    """Put several meshes of the same dimension into one (no vertex welding).

    Parameters
    ----------
    meshes : iterable of meshes
        At least one, each in any form :func:`as_mesh` takes; all of the same dimension and with the same point_data / cell_data names.

    Returns
    -------
    mesh : SimplexMesh
        Vertices stacked, simplex indices offset, data concatenated, and ``cell_data
        ["object_id"]`` (S,) int32 giving the input mesh each simplex came from (replacing any
        existing ``"object_id"``).

    Examples
    --------
    >>> a = SimplexMesh([[0, 0], [1, 0], [0, 1]], [[0, 2], [2, 1], [1, 0]])
    >>> both = concatenate([a, a.transformed(np.eye(2), 5.0)])
    >>> float(both.volume), both.cell_data["object_id"].tolist()
    (1.0, [0, 0, 0, 1, 1, 1])
    """
    meshes = as_meshes(meshes)
    dims = {m.dim for m in meshes}
    if len(dims) > 1:
        raise ValueError(f"`meshes` must all have the same dimension, got {sorted(dims)}")
    point_names = _common_names(meshes, "point_data")
    cell_names = _common_names(meshes, "cell_data") - {"object_id"}
    offsets = np.cumsum([0] + [m.n_vertices for m in meshes])
    vertices = np.concatenate([m.vertices for m in meshes])
    simplices = np.concatenate([m.simplices + off for m, off in zip(meshes, offsets)])
    point_data = {k: np.concatenate([m.point_data[k] for m in meshes]) for k in sorted(point_names)}
    cell_data = {k: np.concatenate([m.cell_data[k] for m in meshes]) for k in sorted(cell_names)}
    cell_data["object_id"] = np.repeat(np.arange(len(meshes), dtype=np.int32), [m.n_simplices for m in meshes])
    return SimplexMesh(vertices, simplices, point_data=point_data, cell_data=cell_data)


def _common_names(meshes: list[SimplexMesh], kind: str) -> set[str]:
    sets = [set(getattr(m, kind)) - ({"object_id"} if kind == "cell_data" else set()) for m in meshes]
    if any(s != sets[0] for s in sets):
        raise ValueError(f"`meshes` must share the same {kind} names; got " + ", ".join(str(sorted(s)) for s in sets))
    return sets[0]


# --------------------------------------------------------------------------------------------
# slicing a 4D mesh by a hyperplane: marching tetrahedra on signed distances
# --------------------------------------------------------------------------------------------
