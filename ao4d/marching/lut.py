"""Marching lookup tables for d-cubes and Kuhn simplices, d = 2, 3, 4.

The cube table follows Bhaniramka, Wenger & Crawfis [1]_: for every sign configuration of the cell's
corners, the isosurface patch is the part of the boundary of

    conv(positive corners  U  midpoints of bipolar edges)

that does not lie in the cell's boundary. Its facets are split into (d-1)-simplices whose vertices
are bipolar edges, by the recursive *pulling* rule: cone the smallest-label vertex of a face over
the pulled triangulations of its facets that do not contain it. The restriction of a pulling
triangulation to any face is the pulling triangulation of that face, and edge labels are ordered
translation-invariantly (by axis, then by lower corner), so the simplices a patch puts on a shared
cell facet depend only on that facet's signs: neighbouring cells match face to face.

Hulls are computed once per class of the hyperoctahedral group (2^d d! symmetries of the cube;
402 classes in 4D). The true, possibly non-simplicial, hull facets of a class representative are
recovered from Qhull by grouping its triangulated output by hyperplane on exact small-integer
coordinates (corners 0/2, midpoints 1), mapped as vertex sets to every other entry of the class,
and split there with that entry's own labels.

The simplex tables split the cube into Kuhn's d! simplices [2]_.

Tables ship in ``lut/`` (see ``lut/README.md``); ``load`` reads them, ``build`` regenerates them,
``verify`` checks checksums and compares a rebuild.

Why this file is long: generator, table files and verification stay one module because a table
is only trusted together with the code that regenerates and byte-compares it (the point of
keeping the generator in the package, unlike scikit-image's opaque tables).

References
----------
.. [1] P. Bhaniramka, R. Wenger, R. Crawfis, "Isosurfacing in higher dimensions", Proc. IEEE
   Visualization 2000, 267-273; and "Isosurface construction in any dimension using convex
   hulls", IEEE Trans. Vis. Comput. Graph. 10(2), 2004, 130-141.
.. [2] H. W. Kuhn, "Some combinatorial lemmas in topology", IBM J. Res. Dev. 4(5), 1960, 518-524,
   doi:10.1147/rd.45.0518.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import os
import time
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._npz import npz_bytes, npz_member_problem
from .._validate import check_choice, regular_file
from ..geometry import cross

__all__ = [
    "Table",
    "TableStats",
    "VerifyReport",
    "DIMS",
    "KINDS",
    "load",
    "build",
    "read",
    "save",
    "write_tables",
    "verify",
    "stats",
    "table_filename",
]

DIMS = (2, 3, 4)
KINDS = ("cube", "simplex")
FORMAT_VERSION = 1

# Everything the generated arrays depend on; written into lut/manifest.json.
GENERATOR = {
    "generator": "ao4d.lut.build",
    "format": FORMAT_VERSION,
    "hull": "scipy.spatial.ConvexHull (Qhull, default options, never QJ), doubled integer "
    "coordinates: corners 0/2, edge midpoints 0/1/2",
    "facets": "Qhull's simplicial facets grouped by hyperplane (all points within 1e-6)",
    "split": "recursive pulling triangulation from the smallest edge label",
    "cube_edge_order": "by (axis, index of the lower corner)",
    "simplex_edge_order": "pairs (i, j), i < j of Kuhn chain positions, lexicographic",
    "symmetry": "hyperoctahedral group (2^d d!) for cubes; none for the simplex",
    "orientation": "n . x = det[p1-p0; ...; p_{d-1}-p0; x] points to the positive side (f >= level)",
    "simplex_rows": "vertices ascending, first two swapped when that orientation is wrong; "
    "rows sorted by their sorted vertex labels",
}

# Qhull works on floats; the doubled coordinates are exact small integers, so points of a facet
# sit within rounding (~1e-15) of its hyperplane while any other point is at least 1/|n| away
# for the primitive integer normal n: measured >= 0.189 (= 1/sqrt(28)) over all 4D classes.
_PLANE_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class Table:
    """A marching lookup table for one cell type.

    Attributes
    ----------
    dim : int
        Dimension d of the cell, in {2, 3, 4}.
    kind : {"cube", "simplex"}
        ``"cube"``: the d-cube. ``"simplex"``: the reference Kuhn simplex; the cube is split into
        the d! simplices of ``cells``.
    vertices : (n, d) int8
        Cell corners: n = 2^d cube corners, corner v at ``((v >> k) & 1)_k``; or the n = d + 1
        corners 0, e0, e0+e1, ..., (1, ..., 1) of the reference Kuhn simplex.
    edges : (E, 2) int64
        Corner indices of each edge, lower corner first. Cube: the d 2^(d-1) edges sorted by
        (axis, lower corner). Simplex: all d(d+1)/2 pairs (i, j), i < j, lexicographically.
    offsets : (2^n + 1,) int64
        Entry c (bit v set iff corner v is positive, f >= level) is
        ``simplices[offsets[c]:offsets[c + 1]]``.
    simplices : (M, d) int64
        Edge indices; the patch vertex on edge e lies on that edge. Each row is oriented so that
        the normal ``n . x = det[p1-p0; ...; p_{d-1}-p0; x]`` points to the positive side.
    cells : (d!, d + 1) int64 or None
        Simplex tables only: Kuhn cell j's local vertex i is cube corner ``cells[j, i]``;
        ``cells[j] = 0, e_p0, e_p0 + e_p1, ...`` for the j-th permutation p of
        ``itertools.permutations(range(d))``.
    cell_parity : (d!,) int8 or None
        Simplex tables only: the sign of permutation j. The affine map from the reference simplex
        to cell j preserves orientation iff +1; extraction reverses simplex orientation (swap two
        vertices) in cells of parity -1.
    """

    dim: int
    kind: str
    vertices: np.ndarray
    edges: np.ndarray
    offsets: np.ndarray
    simplices: np.ndarray
    cells: np.ndarray | None = None
    cell_parity: np.ndarray | None = None

    @property
    def n_entries(self) -> int:
        """Number of entries, 2^n for a cell with n corners."""
        return len(self.offsets) - 1

    @property
    def counts(self) -> np.ndarray:
        """(2^n,) int64: number of simplices of each entry."""
        return np.diff(self.offsets)

    def entry(self, case: int) -> np.ndarray:
        """The simplices of one entry.

        Parameters
        ----------
        case : int
            The case: bit v set iff corner v is positive.

        Returns
        -------
        (k, d) numpy.ndarray
            Edge indices of the entry's k simplices.
        """
        if not 0 <= int(case) < self.n_entries:
            raise ValueError(f"`case` must be in [0, {self.n_entries}), got {case}")
        return self.simplices[self.offsets[case] : self.offsets[case + 1]]

    def arrays(self) -> dict[str, np.ndarray]:
        """The table's arrays by name.

        Returns
        -------
        dict of str to numpy.ndarray
            ``vertices``, ``edges``, ``offsets``, ``simplices``; ``cells`` and ``cell_parity``
            only for simplex tables.
        """
        names = ["vertices", "edges", "offsets", "simplices"]
        if self.kind == "simplex":
            names += ["cells", "cell_parity"]
        return {name: getattr(self, name) for name in names}

    def equals(self, other: Table) -> bool:
        """Whether ``other`` is the same table.

        Parameters
        ----------
        other : Table
            The table to compare with.

        Returns
        -------
        bool
            True if ``other`` has the same dim, kind and identical arrays.
        """
        if (self.dim, self.kind) != (other.dim, other.kind):
            return False
        mine, theirs = self.arrays(), other.arrays()
        return mine.keys() == theirs.keys() and all(np.array_equal(mine[k], theirs[k]) for k in mine)


@dataclass(frozen=True)
class TableStats:
    """Size and symmetry figures of one table (``ao4d lut stats``).

    Attributes
    ----------
    dim : int
        Dimension of the cell.
    kind : str
        ``"cube"`` or ``"simplex"``.
    entries : int
        Number of cases, 2 to the number of corners.
    classes : int
        Classes of cases under the cell's symmetries.
    classes_with_complement : int
        Classes when complementing the signs is a symmetry too.
    group_order : int
        Number of symmetries.
    simplices : int
        Simplices over all entries.
    max_per_entry : int
        Most simplices in one entry.
    mean_per_entry : float
        Mean simplices per entry.
    """

    dim: int
    kind: str
    entries: int
    classes: int
    classes_with_complement: int
    group_order: int
    simplices: int
    max_per_entry: int
    mean_per_entry: float


@dataclass
class VerifyReport:
    """Result of :func:`verify`: one line per checked file and whether everything matched.

    Attributes
    ----------
    lines : list of str
        One line per checked file; mismatches start with ``MISMATCH``.
    ok : bool
        True when every file matched.
    """

    lines: list[str] = field(default_factory=list)
    ok: bool = True

    def fail(self, line: str) -> None:
        self.lines.append("MISMATCH " + line)
        self.ok = False


# --------------------------------------------------------------------------------------------
# Cell geometry


@dataclass(frozen=True)
class _Cell:
    """Corners, edges, symmetries and boundary of one cell type, in the generator's terms."""

    dim: int
    kind: str
    corners: np.ndarray  # (n, d) int8
    edges: np.ndarray  # (E, 2) int64
    group: np.ndarray  # (G, n + E) point permutations; point ids: corners, then edges
    boundary: np.ndarray  # (B,) int64 corner bitmasks of the cell's facets

    @property
    def n(self) -> int:
        return len(self.corners)

    @property
    def coords2(self) -> np.ndarray:
        """(n + E, d) int64 doubled coordinates of corners then edge midpoints."""
        c = self.corners.astype(np.int64)
        return np.concatenate([2 * c, c[self.edges[:, 0]] + c[self.edges[:, 1]]])

    @property
    def support(self) -> np.ndarray:
        """(n + E,) int64 bitmask of the corners each point is a convex combination of."""
        corner_bits = np.int64(1) << np.arange(self.n, dtype=np.int64)
        return np.concatenate([corner_bits, corner_bits[self.edges].sum(1)])


def _cube_corners(dim: int) -> np.ndarray:
    return ((np.arange(2**dim)[:, None] >> np.arange(dim)) & 1).astype(np.int8)


def _cube_edges(dim: int) -> np.ndarray:
    """(E, 2) corner pairs sorted by (axis, lower corner): translation-invariant label order."""
    corners = np.arange(2**dim)
    rows = [(u, u | 1 << k) for k in range(dim) for u in corners if not (u >> k) & 1]
    return np.array(rows, dtype=np.int64)


def _edge_lookup(edges: np.ndarray, n: int) -> np.ndarray:
    """(n, n) array: edge index of corner pair (a, b) in either order, -1 if not an edge."""
    lookup = np.full((n, n), -1, dtype=np.int64)
    ids = np.arange(len(edges))
    lookup[edges[:, 0], edges[:, 1]] = ids
    lookup[edges[:, 1], edges[:, 0]] = ids
    return lookup


def _hyperoctahedral_corner_maps(dim: int) -> np.ndarray:
    """(2^d d!, 2^d) corner permutations: axis permutations combined with reflections.

    Row order is deterministic with the identity first.
    """
    corners = _cube_corners(dim).astype(np.int64)
    weights = 1 << np.arange(dim)
    rows = []
    for perm in itertools.permutations(range(dim)):
        for flip in range(2**dim):
            flipped = corners ^ ((flip >> np.arange(dim)) & 1)
            moved = np.empty_like(flipped)
            moved[:, list(perm)] = flipped  # coordinate k goes to axis perm[k]
            rows.append(moved @ weights)
    return np.array(rows, dtype=np.int64)


def _point_maps(corner_maps: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Extend corner permutations to corners + edges (an edge maps to the edge of its image)."""
    n = corner_maps.shape[1]
    lookup = _edge_lookup(edges, n)
    edge_maps = lookup[corner_maps[:, edges[:, 0]], corner_maps[:, edges[:, 1]]]
    if (edge_maps < 0).any():
        raise AssertionError("a symmetry did not map edges to edges")
    return np.concatenate([corner_maps, n + edge_maps], axis=1)


@functools.cache
def _cell(dim: int, kind: str) -> _Cell:
    if kind == "cube":
        corners = _cube_corners(dim)
        edges = _cube_edges(dim)
        group = _point_maps(_hyperoctahedral_corner_maps(dim), edges)
        # facet x_k = b holds the corners whose bit k equals b
        ids = np.arange(2**dim)
        boundary = [int(((1 << ids[((ids >> k) & 1) == b]).sum())) for k in range(dim) for b in (0, 1)]
    else:
        corners = np.tril(np.ones((dim + 1, dim), dtype=np.int8), -1)
        edges = np.array(list(itertools.combinations(range(dim + 1), 2)), dtype=np.int64)
        n = dim + 1
        # the reference simplex is built alone: the only symmetry used is the identity
        group = np.arange(n + len(edges), dtype=np.int64)[None, :]
        boundary = [((1 << n) - 1) & ~(1 << i) for i in range(n)]  # facet opposite corner i
    return _Cell(dim, kind, corners, edges, group, np.array(boundary, dtype=np.int64))


def _kuhn_cells(dim: int) -> tuple[np.ndarray, np.ndarray]:
    """(d!, d+1) cube corners of the Kuhn cells and (d!,) int8 permutation signs."""
    cells, parity = [], []
    for perm in itertools.permutations(range(dim)):
        chain = np.concatenate([[0], np.cumsum([1 << p for p in perm])])
        cells.append(chain)
        inversions = sum(perm[i] > perm[j] for i in range(dim) for j in range(i + 1, dim))
        parity.append(1 - 2 * (inversions % 2))
    return np.array(cells, dtype=np.int64), np.array(parity, dtype=np.int8)


# --------------------------------------------------------------------------------------------
# Classes of sign configurations


def _orbits(corner_maps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Class representative (smallest member) of every configuration and a symmetry taking it there.

    Returns ``rep`` (N,) and ``elem`` (N,) with ``g = elem[c]`` mapping ``rep[c]`` to ``c``.
    """
    n = corner_maps.shape[1]
    count = 1 << n
    weights = np.int64(1) << corner_maps  # (G, n): where each corner's bit goes
    bit_index = np.arange(n)
    rep = np.full(count, -1, dtype=np.int64)
    elem = np.full(count, -1, dtype=np.int64)
    for c in range(count):
        if rep[c] >= 0:
            continue  # reached from a smaller representative
        images = (weights * ((c >> bit_index) & 1)).sum(1)
        targets, first = np.unique(images, return_index=True)
        rep[targets] = c
        elem[targets] = first
    return rep, elem


def _class_counts(dim: int, kind: str) -> tuple[int, int, int]:
    """(group order, classes, classes with complement) of the table's configurations."""
    cell = _cell(dim, kind)
    if kind == "cube":
        corner_maps = cell.group[:, : cell.n]
    else:
        # the hull construction is symmetric under every permutation of the simplex's corners
        corner_maps = np.array(list(itertools.permutations(range(cell.n))), dtype=np.int64)
    rep, _ = _orbits(corner_maps)
    complement = rep[(1 << cell.n) - 1 - np.arange(1 << cell.n)]
    merged = np.minimum(rep, complement)
    return len(corner_maps), len(np.unique(rep)), len(np.unique(merged))


# --------------------------------------------------------------------------------------------
# Hulls and their face lattices


def _hull_facets(points: np.ndarray, coords2: np.ndarray) -> list[frozenset[int]]:
    """Vertex sets (point ids) of the true facets of ``conv(coords2[points])``."""
    from scipy.spatial import ConvexHull

    xyz = coords2[points].astype(np.float64)
    hull = ConvexHull(xyz)  # default options triangulate (Qt); never joggle (QJ)
    signed = xyz @ hull.equations[:, :-1].T + hull.equations[:, -1]  # (P, F)
    if (signed > _PLANE_TOL).any():
        raise AssertionError("Qhull returned a facet with points outside")
    on_plane = np.unique(np.abs(signed.T) < _PLANE_TOL, axis=0)  # one row per true facet
    return [frozenset(points[row].tolist()) for row in on_plane]


def _subfacets(face: frozenset[int], siblings: Sequence[frozenset[int]]) -> list[frozenset[int]]:
    """Facets of ``face``: the inclusion-maximal intersections with the other facets ``siblings``.

    Every facet of a polytope's facet is shared with exactly one other facet, and every other
    intersection is a smaller face, so this recovers the face lattice combinatorially.
    """
    meets = {face & other for other in siblings if other != face}
    meets.discard(frozenset())
    return sorted((s for s in meets if not any(s < t for t in meets)), key=sorted)


def _flags(face: frozenset[int], siblings: Sequence[frozenset[int]], level: int) -> Iterator[tuple]:
    """Chains (F_level, ..., F_1) of faces, each a facet of the previous, down to edges."""
    if level == 1:
        if len(face) != 2:
            raise AssertionError(f"an edge of a hull facet has {len(face)} vertices")
        yield (face,)
        return
    subs = _subfacets(face, siblings)
    for sub in subs:
        for rest in _flags(sub, subs, level - 1):
            yield (face, *rest)


def _class_flags(cell: _Cell, rep: int) -> list[tuple]:
    """All flags of the isosurface facets of configuration ``rep``, in point ids."""
    n, d = cell.n, cell.dim
    positive = (rep >> np.arange(n)) & 1
    bipolar = positive[cell.edges[:, 0]] != positive[cell.edges[:, 1]]
    points = np.concatenate([np.flatnonzero(positive), n + np.flatnonzero(bipolar)])
    facets = _hull_facets(points, cell.coords2)
    support = cell.support
    flags = []
    for facet in facets:
        union = np.bitwise_or.reduce(support[list(facet)])
        if ((union & ~cell.boundary) == 0).any():
            continue  # lies in the cell's boundary
        if min(facet) < n:
            raise AssertionError(f"isosurface facet of case {rep} has a corner vertex")
        flags.extend(_flags(facet, facets, d - 1))
    return flags


def _pad(faces: Sequence[frozenset[int]], fill: int) -> np.ndarray:
    width = max(len(f) for f in faces)
    out = np.full((len(faces), width), fill, dtype=np.int64)
    for i, face in enumerate(faces):
        out[i, : len(face)] = sorted(face)
    return out


def _pull(flags: list[tuple], labels: np.ndarray, sentinel: int) -> tuple[np.ndarray, np.ndarray]:
    """Pulling-triangulation simplices of the flags under many labelings at once.

    A flag (F_{d-1}, ..., F_1) yields the simplex {min F_{d-1}, ..., min F_2} U F_1 iff
    min F_i is not in F_{i-1} for every i >= 2 (min by label): that is the recursive rule
    "cone the smallest vertex over the faces not containing it", unrolled.

    Parameters
    ----------
    flags : list of tuples of frozensets of point ids
    labels : (L, P + 1) int64
        Label of every point id (and of the padding id ``sentinel``) in each of L entries.

    Returns
    -------
    rows : (K,) int64
        Which labeling each simplex belongs to.
    simplices : (K, d) int64
        Vertex labels.
    """
    depth = len(flags[0])
    levels = [_pad([flag[i] for flag in flags], sentinel) for i in range(depth)]
    lab = [labels[:, lv] for lv in levels]  # each (L, nflags, width)
    mins = [x.min(-1) for x in lab[:-1]]
    keep = np.ones(mins[0].shape if mins else lab[-1].shape[:2], dtype=bool)
    for i, m in enumerate(mins):
        keep &= ~(lab[i + 1] == m[..., None]).any(-1)
    simplex = np.concatenate([np.stack(mins, -1) if mins else lab[-1][..., :0], lab[-1]], -1)
    rows = np.nonzero(keep)[0]
    return rows, simplex[keep]


# --------------------------------------------------------------------------------------------
# Build


def _orient(cell: _Cell, entries: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Sort each row, then swap its first two labels where the normal points to the negative side.

    The positive side of a patch facet is the hull's interior; the centroid of an entry's hull
    points is strictly inside it (all those points are hull vertices, and the hull is full-
    dimensional), so the normal must have a positive dot product with (centroid - p0). All in
    exact integers: doubled coordinates, and the centroid scaled by the number of hull points.
    """
    n = cell.n
    simplices = np.sort(simplices, axis=1)
    configs = np.arange(1 << n)
    positive = (configs[:, None] >> np.arange(n)) & 1  # (N, n)
    bipolar = (positive[:, cell.edges[:, 0]] != positive[:, cell.edges[:, 1]]).astype(np.int64)
    coords2 = cell.coords2.astype(np.int32)  # |entries| <= 2: int32 products cannot overflow
    total = positive @ coords2[:n] + bipolar @ coords2[n:]  # (N, d)
    count = positive.sum(1) + bipolar.sum(1)
    p = coords2[n + simplices]  # (M, d, d)
    normal = cross(*np.moveaxis(p[:, 1:] - p[:, :1], 1, 0))  # (M, d), exact in integers
    if not np.abs(normal).any(1).all():  # integer vector, zero iff the simplex is flat
        raise AssertionError("degenerate simplex in the table")
    side = np.einsum("md,md->m", normal, total[entries] - count[entries, None] * p[:, 0])
    if (side == 0).any():
        raise AssertionError("a hull centroid lies on a patch facet")
    flip = side < 0
    simplices[flip, :2] = simplices[flip, 1::-1]
    return simplices


def _assemble(cell: _Cell, entries: np.ndarray, simplices: np.ndarray) -> tuple[np.ndarray, ...]:
    """Offsets per entry and rows sorted by (entry, sorted labels): one int64 key, base E."""
    base = len(cell.edges)
    key = entries.astype(np.int64)
    for column in np.sort(simplices, axis=1).T:
        key = key * base + column  # < 2^16 * 32^4 in 4D
    order = np.argsort(key, kind="stable")
    counts = np.bincount(entries, minlength=1 << cell.n)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return offsets, simplices[order]


def _build_arrays(cell: _Cell, *, show: bool) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and oriented, sorted simplices of every entry of ``cell``'s table.

    One hull per class of ``cell.group``; its facets' flags are pulled in the labels of every
    entry of the class at once.
    """
    from .. import _progress

    n = cell.n
    rep, elem = _orbits(cell.group[:, :n])
    reps = np.unique(rep[1:-1])  # all-negative and all-positive cases are empty
    members = np.argsort(rep, kind="stable")  # cases grouped by class
    starts = np.searchsorted(rep[members], reps, side="left")
    stops = np.searchsorted(rep[members], reps, side="right")
    sentinel = cell.group.shape[1]
    # labels of point ids under each symmetry: edge index of the image midpoint; the padding id
    # maps to a label larger than any edge
    big = np.int64(1 << 20)
    edge_labels = np.concatenate([cell.group - n, np.full((len(cell.group), 1), big)], axis=1)

    entries_out, simplices_out = [], []
    bar = _progress.bar(len(reps), f"lut {cell.kind} {cell.dim}D", unit="class", show=show)
    for rep_c, lo, hi in zip(reps, starts, stops):
        bar.update(1)
        flags = _class_flags(cell, int(rep_c))
        cases = members[lo:hi]
        rows, simplices = _pull(flags, edge_labels[elem[cases]], sentinel)
        entries_out.append(cases[rows])
        simplices_out.append(simplices)
    bar.close()
    entries = np.concatenate(entries_out)
    simplices = _orient(cell, entries, np.concatenate(simplices_out))
    return _assemble(cell, entries, simplices)


def build(dim: int, kind: str = "cube", *, progress: bool | None = None) -> Table:
    """Generate the lookup table for a d-cube or the reference Kuhn d-simplex.

    Parameters
    ----------
    dim : {2, 3, 4}
        Dimension of the cell.
    kind : {"cube", "simplex"}
        Cell type.
    progress : bool, optional
        Show a progress bar over the configuration classes; default: only for ``dim=4`` cubes.

    Returns
    -------
    table : Table
        Arrays identical to ``load(dim, kind)`` (the files in ``lut/`` are written from this).

    Examples
    --------
    >>> import ao4d
    >>> t = ao4d.marching.lut.build(3)
    >>> t.entry(1).tolist()  # corner 0 positive: one triangle on its y, x and z edges
    [[4, 0, 8]]
    """
    dim = _check_dim(dim)
    kind = check_choice(kind, "kind", KINDS)
    cell = _cell(dim, kind)
    show = (dim == 4 and kind == "cube") if progress is None else bool(progress)
    offsets, simplices = _build_arrays(cell, show=show)
    cells = parity = None
    if kind == "simplex":
        cells, parity = _kuhn_cells(dim)
    return _freeze(
        Table(
            dim=dim,
            kind=kind,
            vertices=cell.corners.copy(),
            edges=cell.edges.copy(),
            offsets=offsets,
            simplices=simplices.astype(np.int64),
            cells=cells,
            cell_parity=parity,
        )
    )


def _freeze(table: Table) -> Table:
    for arr in table.arrays().values():
        arr.flags.writeable = False
    return table


def _check_dim(dim: int) -> int:
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)):
        raise TypeError(f"`dim` must be an integer in {DIMS}, got {type(dim).__name__}")
    return int(check_choice(int(dim), "dim", DIMS))


# --------------------------------------------------------------------------------------------
# Files


# on-disk dtypes: compact and explicit-endian so files are byte-identical across machines
_DISK_DTYPES = {
    "vertices": "<i1",
    "edges": "<u1",
    "offsets": "<i8",
    "simplices": "<u1",
    "cells": "<u1",
    "cell_parity": "<i1",
}
_MEMORY_DTYPES = {
    "vertices": np.int8,
    "edges": np.int64,
    "offsets": np.int64,
    "simplices": np.int64,
    "cells": np.int64,
    "cell_parity": np.int8,
}


def table_filename(dim: int, kind: str) -> str:
    """File name of a table in ``lut/``.

    Parameters
    ----------
    dim : int
        Dimension, one of ``DIMS``.
    kind : {"cube", "simplex"}
        The cell the table is for.

    Returns
    -------
    str
        The file name, e.g. ``"cube_4d.npz"``.
    """
    return f"{kind}_{dim}d.npz"


def _table_bytes(table: Table) -> bytes:
    """The table as an uncompressed .npz with fixed timestamps: byte-deterministic."""
    disk = {}
    for name, arr in table.arrays().items():
        disk[name] = np.ascontiguousarray(arr, dtype=_DISK_DTYPES[name])
        if not np.array_equal(disk[name], arr):
            raise OverflowError(f"table array {name!r} does not fit {_DISK_DTYPES[name]}")
    return npz_bytes(disk, compress=False)


def read(path: str | os.PathLike) -> Table:
    """Read a table file written by :func:`save` (dimension and kind come from its arrays).

    Parameters
    ----------
    path : path
        A ``<kind>_<dim>d.npz`` file.

    Returns
    -------
    table : Table
        Arrays read-only, in the in-memory dtypes (int64 indices).
    """
    path = regular_file(path, "path")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = {"vertices", "edges", "offsets", "simplices"} - set(data.files)
            if missing:
                raise ValueError(f"`path` {path} is not a lookup table: no {sorted(missing)}")
            arrays = {name: data[name].astype(_MEMORY_DTYPES[name]) for name in data.files}
    except (OSError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise ValueError(f"`path` {str(path)!r} is not a valid .npz file ({npz_member_problem(exc)})") from None
    except ValueError as exc:
        if "lookup table" in str(exc):
            raise
        raise ValueError(f"`path` {str(path)!r} is not a valid .npz file ({npz_member_problem(exc)})") from None
    kind = "simplex" if "cells" in arrays else "cube"
    return _freeze(Table(dim=int(arrays["vertices"].shape[1]), kind=kind, **arrays))


def save(table: Table, folder: str | os.PathLike) -> Path:
    """Write ``table`` atomically into ``folder`` under the name :func:`table_filename` gives.

    Parameters
    ----------
    table : Table
        The table to write.
    folder : str or path-like
        The folder to write into.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    from .._atomic import atomic_open

    path = Path(folder) / table_filename(table.dim, table.kind)
    with atomic_open(path, "wb") as fh:
        fh.write(_table_bytes(table))
    return path


def write_tables(
    folder: str | os.PathLike,
    dims: Sequence[int] = DIMS,
    kinds: Sequence[str] = KINDS,
    *,
    progress: bool | None = None,
) -> dict[str, float]:
    """Build tables, write them and update ``manifest.json`` in ``folder`` (atomic writes).

    Parameters
    ----------
    folder : str or path-like
        The folder to write into (``lut/`` in the repository).
    dims : sequence of int
        Dimensions to build.
    kinds : sequence of {"cube", "simplex"}
        Kinds of table to build.
    progress : bool, optional
        Show progress; None: only on a terminal.

    Returns
    -------
    seconds : dict of str to float
        Build time of each written file.
    """
    from .._atomic import atomic_open

    dims = [_check_dim(d) for d in dims]
    kinds = [check_choice(k, "kind", KINDS) for k in kinds]
    folder = Path(folder)
    manifest_path = folder / "manifest.json"
    manifest = _read_manifest(manifest_path) if manifest_path.exists() else {}
    files = manifest.get("files", {})
    seconds = {}
    for dim in dims:
        for kind in kinds:
            start = time.perf_counter()
            table = build(dim, kind, progress=progress)
            name = table_filename(dim, kind)
            seconds[name] = time.perf_counter() - start
            save(table, folder)
            files[name] = {
                "dim": dim,
                "kind": kind,
                "sha256": _sha256(folder / name),
                "entries": table.n_entries,
                "simplices": int(len(table.simplices)),
            }
    manifest = {**GENERATOR, "files": dict(sorted(files.items()))}
    with atomic_open(manifest_path, "w", encoding="utf-8") as fh:
        json.dump(manifest, fh, indent=2, sort_keys=False)
        fh.write("\n")
    return seconds


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _read_manifest(path: Path) -> dict:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _lut_folder() -> Path:
    from .._resources import data_dir

    return data_dir("lut")


@functools.cache
def _load_cached(dim: int, kind: str) -> Table:
    path = _lut_folder() / table_filename(dim, kind)
    if not path.is_file():
        raise FileNotFoundError(f"lookup table {path} is missing; run `ao4d lut build`")
    return read(path)


def load(dim: int, kind: str = "cube") -> Table:
    """Load a shipped lookup table (read once per process, arrays read-only).

    Parameters
    ----------
    dim : {2, 3, 4}
        The cell's dimension: the square's, cube's or tesseract's table (or its Kuhn simplex's).
    kind : {"cube", "simplex"}
        The table of the whole d-cube, or of the reference Kuhn d-simplex.

    Returns
    -------
    table : Table
        Identical to ``build(dim, kind)``; :func:`verify` checks that.

    Examples
    --------
    >>> import ao4d
    >>> t = ao4d.marching.lut.load(4)
    >>> t.simplices.shape[1], t.n_entries
    (4, 65536)
    """
    return _load_cached(_check_dim(dim), check_choice(kind, "kind", KINDS))


def verify(
    folder: str | os.PathLike | None = None,
    dims: Sequence[int] = DIMS,
    kinds: Sequence[str] = KINDS,
    *,
    rebuild: bool = True,
) -> VerifyReport:
    """Check table files against ``manifest.json`` and, with ``rebuild``, against a fresh build.

    Parameters
    ----------
    folder : path, optional
        Folder holding the tables; default: the shipped ``lut/``.
    dims, kinds : sequences
        Which tables to check.
    rebuild : bool
        Also regenerate each table and compare arrays (a few seconds in 4D).

    Returns
    -------
    report : VerifyReport
        ``ok`` is False on any missing file, checksum mismatch or differing rebuild.

    Raises
    ------
    FileNotFoundError
        ``folder`` does not exist or is not a folder.
    """
    folder = Path(folder) if folder is not None else _lut_folder()
    if not folder.is_dir():  # a report of "MISMATCH" would blame tables that are not there
        what = "is not a folder" if folder.exists() else "does not exist"
        raise FileNotFoundError(f"`folder` {str(folder)!r} {what}: give the folder that holds the tables")
    report = VerifyReport()
    manifest_path = folder / "manifest.json"
    if not manifest_path.is_file():
        report.fail(f"{manifest_path}: missing")
        return report
    files = _read_manifest(manifest_path).get("files", {})
    for dim in (_check_dim(d) for d in dims):
        for kind in (check_choice(k, "kind", KINDS) for k in kinds):
            name = table_filename(dim, kind)
            path = folder / name
            if not path.is_file() or name not in files:
                report.fail(f"{name}: missing file or manifest entry")
                continue
            digest = _sha256(path)
            if digest != files[name]["sha256"]:
                want = files[name]["sha256"]
                report.fail(f"{name}: sha256 {digest[:12]} != manifest {want[:12]}")
                continue
            line = f"{name}: sha256 ok"
            if rebuild:
                start = time.perf_counter()
                fresh = build(dim, kind, progress=False)
                took = time.perf_counter() - start
                if not fresh.equals(read(path)):
                    report.fail(f"{name}: rebuild differs from the file")
                    continue
                if _table_bytes(fresh) != path.read_bytes():
                    report.fail(f"{name}: rebuild equal but file bytes differ")
                    continue
                line += f", rebuild identical ({took:.2f} s)"
            report.lines.append(line)
    return report


def stats(table: Table) -> TableStats:
    """Entry, class and simplex counts of ``table``.

    Classes are counted under the cube's hyperoctahedral group (2^d d! symmetries) for cubes and
    under all permutations of the corners for the simplex (the hull's symmetries; the split of a
    non-simplicial facet then depends on labels), without and with complementation.

    Parameters
    ----------
    table : Table
        A loaded or built table.

    Returns
    -------
    TableStats
        The counts.

    Examples
    --------
    >>> from ao4d.marching import lut
    >>> s = lut.stats(lut.load(3))
    >>> s.entries, s.classes, s.simplices
    (256, 22, 836)
    """
    group, classes, with_complement = _class_counts(table.dim, table.kind)
    counts = table.counts
    return TableStats(
        dim=table.dim,
        kind=table.kind,
        entries=table.n_entries,
        classes=classes,
        classes_with_complement=with_complement,
        group_order=group,
        simplices=int(counts.sum()),
        max_per_entry=int(counts.max()),
        mean_per_entry=float(counts.mean()),
    )


if __name__ == "__main__":  # `python -m ao4d.marching.lut ...` is `ao4d lut ...`
    import sys

    from ..cli import main

    sys.exit(main(["lut", *sys.argv[1:]]))
