"""Tests for ao4d.topology through SimplexMesh.check: closed, manifold, oriented, singular vertices.

Each defect is made by hand on a closed reference mesh (tests/_shapes.py) and must be counted.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from _shapes import ball_polytope, simplex_boundary, translated

from ao4d.mesh import MeshReport, SimplexMesh, concatenate

DIMS = (2, 3, 4)


@pytest.fixture(params=DIMS, ids=lambda d: f"{d}D")
def closed_mesh(request) -> SimplexMesh:
    return ball_polytope(request.param, 2)


def test_closed_mesh_is_ok(closed_mesh):
    report = closed_mesh.check()
    assert isinstance(report, MeshReport)
    assert report.ok and report.closed and report.manifold and report.oriented
    assert report.n_components == 1 and report.n_degenerate == 0 and report.n_unused_vertices == 0
    assert report.n_faces * 2 == report.n_simplices * closed_mesh.dim
    text = str(report)
    assert "=> OK" in text and f"{closed_mesh.n_simplices} simplices" in text


def test_removed_simplex_opens_mesh(closed_mesh):
    d = closed_mesh.dim
    open_mesh = SimplexMesh(closed_mesh.vertices, closed_mesh.simplices[1:])
    report = open_mesh.check()
    # the removed simplex leaves its d faces with one neighbour each
    assert report.n_boundary_faces == d and not report.closed and not report.ok
    assert report.oriented and report.manifold  # boundary vertices have disk links
    boundary = open_mesh.boundary_faces()
    assert boundary.shape == (d, d - 1)
    if d == 3:  # the hole's rim is an oriented loop: every vertex starts one edge, ends one
        assert sorted(boundary[:, 0]) == sorted(boundary[:, 1])
    if d == 4:  # the rim is a closed oriented surface: each directed edge meets its reverse
        directed = {tuple(e) for t in boundary.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        assert len(directed) == 3 * d and directed == {(b, a) for a, b in directed}
    assert np.array_equal(
        np.sort(np.sort(open_mesh.boundary_faces(), axis=1), axis=0),
        np.sort(np.sort(closed_mesh.simplices[0][[[j for j in range(d) if j != i] for i in range(d)]], axis=1), axis=0),
    )


def test_flipped_simplex_is_misoriented(closed_mesh):
    d = closed_mesh.dim
    simplices = closed_mesh.simplices.copy()
    simplices[3, [0, 1]] = simplices[3, [1, 0]]
    report = SimplexMesh(closed_mesh.vertices, simplices).check()
    assert report.n_misoriented_faces == d and not report.oriented
    assert report.closed and not report.ok


def test_face_shared_by_three_is_nonmanifold(closed_mesh):
    d = closed_mesh.dim
    # a copy of simplex 0 with one vertex replaced by a new point: its face opposite that vertex
    # is now shared by three simplices; its other d-1 faces are new boundary faces
    vertices = np.vstack([closed_mesh.vertices, np.full(d, 0.1)])
    extra = closed_mesh.simplices[0].copy()
    extra[0] = len(vertices) - 1
    report = SimplexMesh(vertices, np.vstack([closed_mesh.simplices, extra])).check()
    assert report.n_nonmanifold_faces == 1 and not report.manifold and not report.closed
    assert report.n_boundary_faces == d - 1


@pytest.mark.parametrize("d", DIMS)
def test_degenerate_simplices_counted(d):
    mesh = simplex_boundary(d)
    vertices = mesh.vertices.copy()
    # vertex 2 onto vertex 1 (plus a round-off-sized nudge): the d-1 facets holding both
    # collapse to zero measure; the topology is untouched
    vertices[2] = vertices[1] + 1e-15
    collapsed = SimplexMesh(vertices, mesh.simplices)
    report = collapsed.check()
    assert report.n_degenerate == d - 1 and report.closed and report.oriented
    if d > 2:  # 2D: the nudge is a length of 1.4e-15, a degenerate segment only with rtol > 0
        assert collapsed.check(rtol=0.0).n_degenerate == 0
    assert mesh.check().n_degenerate == 0


@pytest.mark.parametrize(("d", "shared"), [(3, "vertex"), (4, "vertex"), (4, "edge")])
def test_pinched_meshes_are_singular(d, shared):
    """Two simplex boundaries touching at a vertex (or, in 4D, along an edge) are closed and
    oriented, and no face is shared, but the star of each touching vertex has two pieces.
    (In 3D an edge is a face, so a shared edge is a non-manifold face, tested above.)"""
    a = simplex_boundary(d)
    e = np.eye(d)
    # point reflection of a through e_1 touches it only at e_1; through (e_1 + e_2)/2 it
    # touches along the edge e_1 e_2 (with e_1, e_2 swapped). transformed() keeps b outward.
    centre = e[0] if shared == "vertex" else (e[0] + e[1]) / 2
    b = a.transformed(-np.eye(d), 2 * centre)
    index_b = np.arange(b.n_vertices) + a.n_vertices
    if shared == "vertex":
        index_b[1] = 1
    else:
        index_b[1], index_b[2] = 2, 1
    mesh = SimplexMesh(np.vstack([a.vertices, b.vertices]), np.vstack([a.simplices, index_b[b.simplices]]))
    report = mesh.check()
    assert report.closed and report.oriented and report.n_nonmanifold_faces == 0
    assert report.n_singular_vertices == (1 if shared == "vertex" else 2)
    assert not report.manifold and not report.ok
    assert report.n_components == 2 and report.n_unused_vertices == (1 if shared == "vertex" else 2)
    assert mesh.volume == pytest.approx(2 / math.factorial(d), rel=1e-12)


def test_vertex_with_torus_link_is_singular():
    """The suspension of a triangulated torus: a closed, oriented 3-pseudo-manifold whose two
    apexes have a torus as link (Euler characteristic 0, not 2). Their stars are connected, so
    only the link Euler test can catch them; torus vertices have links that are suspended
    circles (spheres) and pass."""
    k = 6
    a, b = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    vid = lambda i, j: (i % k) * k + (j % k)  # noqa: E731
    triangles = np.concatenate(
        [
            np.stack([vid(a, b), vid(a + 1, b), vid(a + 1, b + 1)], axis=-1).reshape(-1, 3),
            np.stack([vid(a, b), vid(a + 1, b + 1), vid(a, b + 1)], axis=-1).reshape(-1, 3),
        ]
    )
    angle = 2 * np.pi * np.arange(k) / k
    u, v = np.meshgrid(angle, angle, indexing="ij")
    torus = np.stack([np.cos(u), np.sin(u), np.cos(v), np.sin(v)], axis=-1).reshape(-1, 4) / math.sqrt(2)
    top, bottom = k * k, k * k + 1
    vertices = np.vstack([torus, [[0.1, 0.2, 0.3, 0.9], [-0.2, 0.1, -0.3, -0.8]]])
    # apex first; the bottom cone reversed so the shared torus triangles get opposite orientations
    tets = np.concatenate(
        [
            np.column_stack([np.full(len(triangles), top), triangles]),
            np.column_stack([np.full(len(triangles), bottom), triangles[:, [0, 2, 1]]]),
        ]
    )
    report = SimplexMesh(vertices, tets).check()
    assert report.closed and report.oriented and report.n_nonmanifold_faces == 0
    assert report.n_singular_vertices == 2 and not report.manifold


@pytest.mark.slow
def test_check_two_million_tetrahedra():
    # 80 translated copies of a 24576-tetrahedron polytope: the vectorised check must stay
    # correct (and feasible) at millions of simplices
    base = ball_polytope(4, 8)
    mesh = concatenate([translated(base, [3.0 * i, 0, 0, 0]) for i in range(80)])
    report = mesh.check()
    assert report.ok and report.n_components == 80 and report.n_simplices == 80 * base.n_simplices
    assert mesh.volume == pytest.approx(80 * base.volume, rel=1e-12)


# --------------------------------------------------------------------------------------------
# the check against the reference implementation (tests/_topology_reference.py) on random
# defective meshes: every kind of defect, alone and combined
# --------------------------------------------------------------------------------------------

from _topology_reference import reference_boundary_faces, reference_components, reference_report  # noqa: E402

from ao4d import topology  # noqa: E402


def _extracted(d: int, rng: np.random.Generator) -> SimplexMesh:
    """A closed mesh of a random smooth-ish field (several components, level-valued samples)."""
    from ao4d import extract

    shape = (5, 5, 4, 4) if d == 4 else (12,) * d  # small: the reference is plain Python
    values = np.round(rng.normal(size=shape), 1)  # many samples exactly at the level
    return extract(np.pad(values, 1, constant_values=1.0), 0.0)


def _defective(d: int, defect: str, rng: np.random.Generator) -> SimplexMesh:
    base = ball_polytope(d, 2) if rng.random() < 0.5 else _extracted(d, rng)
    v, s = base.vertices.copy(), base.simplices.copy()
    k = max(1, len(s) // 20)
    if defect == "holes":
        s = np.delete(s, rng.choice(len(s), k, replace=False), axis=0)
    elif defect == "flipped":
        rows = rng.choice(len(s), k, replace=False)
        s[rows, :2] = s[rows, 1::-1]
    elif defect == "duplicated":
        s = np.vstack([s, s[rng.choice(len(s), k)]])
    elif defect == "glued":  # vertex pairs merged: pinched vertices, non-manifold edges/faces
        a, b = rng.choice(len(v), (2, k))
        s = np.where(np.isin(s, b), a[np.searchsorted(b, s, sorter=np.argsort(b)).clip(0, k - 1)], s)
        s = s[np.array([len(set(row)) == d for row in s.tolist()], dtype=bool)]
    elif defect == "components":
        parts = [translated(base, [3.0 * i] + [0.0] * (d - 1)) for i in range(int(rng.integers(2, 4)))]
        merged = concatenate(parts)
        v, s = merged.vertices.copy(), merged.simplices.copy()
    elif defect == "pinched":  # two copies sharing one vertex
        other = translated(base, [0.0] * d)
        s = np.vstack([s, other.simplices + len(v)])
        s[s == len(v) + int(s[0, 0])] = int(s[0, 0])
        v = np.vstack([v, other.vertices])
    elif defect == "inside_out":
        s = s[:, [1, 0, *range(2, d)]]
    elif defect == "unused":
        v = np.vstack([v, rng.normal(size=(3, d))])
    return SimplexMesh(v, s)


DEFECTS = ["holes", "flipped", "duplicated", "glued", "components", "pinched", "inside_out", "unused"]


def _assert_same_as_reference(mesh: SimplexMesh) -> None:
    report = mesh.check()
    assert report == reference_report(mesh)
    assert np.array_equal(mesh.components(), reference_components(mesh.simplices, mesh.n_vertices))
    got = np.sort(np.sort(mesh.boundary_faces(), axis=1), axis=0)
    want = np.sort(np.sort(reference_boundary_faces(mesh.simplices, mesh.n_vertices), axis=1), axis=0)
    assert np.array_equal(got, want)

    # orientation of each boundary face: the same oriented face up to an even permutation
    def canonical(faces: np.ndarray) -> list[tuple]:
        if mesh.dim < 4:  # a point or a directed edge: the listing is the orientation
            return sorted(map(tuple, faces.tolist()))
        # a triangle up to rotation (an even permutation): smallest vertex first
        return sorted(tuple(f[f.index(min(f)) :] + f[: f.index(min(f))]) for f in faces.tolist())

    assert canonical(mesh.boundary_faces()) == canonical(reference_boundary_faces(mesh.simplices, mesh.n_vertices))


@pytest.mark.parametrize("d", DIMS, ids=lambda d: f"{d}D")
@pytest.mark.parametrize("defect", DEFECTS)
def test_check_matches_reference_on_defective_meshes(d, defect):
    rng = np.random.default_rng([d, DEFECTS.index(defect)])
    for _ in range(3):
        mesh = _defective(d, defect, rng)
        _assert_same_as_reference(mesh)
        # and with a second defect on top
        again = _defective(d, DEFECTS[int(rng.integers(len(DEFECTS)))], rng)
        _assert_same_as_reference(again)


@pytest.mark.parametrize("d", DIMS, ids=lambda d: f"{d}D")
@pytest.mark.parametrize("broken", ["merged-faces", "no-parity"])
def test_reference_catches_a_broken_face_grouping(monkeypatch, d, broken):
    """The reference shares no code with ao4d.topology, so it catches a bug there: a face
    packing that merges faces differing in one vertex bit, or a row sort that loses the
    parity, makes the fast check (and the components) disagree with it."""
    rng = np.random.default_rng([d, 5])
    meshes = [_defective(d, defect, rng) for defect in ("holes", "flipped", "components")]
    want = [(reference_report(m), reference_components(m.simplices, m.n_vertices)) for m in meshes]
    for mesh, (report, labels) in zip(meshes, want):
        fresh = SimplexMesh(mesh.vertices, mesh.simplices)
        assert fresh.check() == report and np.array_equal(fresh.components(), labels)
    if broken == "merged-faces":
        pack = topology._pack_face

        def wrong(cols, kept, b, out):
            pack(cols, kept, b, out)
            out >>= np.uint64(1)  # faces whose last vertices differ in their lowest bit merge
            return out

        monkeypatch.setattr(topology, "_pack_face", wrong)
    else:
        sort = topology._sort_simplices

        def wrong(simplices, local=True):
            cols, locs, odd = sort(simplices, local)
            return cols, locs, np.zeros_like(odd)

        monkeypatch.setattr(topology, "_sort_simplices", wrong)
    caught = 0
    for mesh, (report, labels) in zip(meshes, want):
        fresh = SimplexMesh(mesh.vertices, mesh.simplices)
        caught += fresh.check() != report or not np.array_equal(fresh.components(), labels)
    assert caught == len(meshes)


@pytest.mark.parametrize("d", DIMS, ids=lambda d: f"{d}D")
def test_face_multiplicity_counts_the_simplices_of_each_face(d):
    """Faces.multiplicity (what lift.TetSolid.boundary reads): entry (i, k) is how many
    simplices have simplex i's face opposite its local vertex k, as the reference counts."""
    from _topology_reference import face_table

    rng = np.random.default_rng([d, 9])
    for defect in ("holes", "duplicated", "glued"):
        mesh = _defective(d, defect, rng)
        rows = mesh.simplices.tolist()
        table = face_table(rows)
        want = [[len(table[tuple(sorted(r[:k] + r[k + 1 :]))]) for k in range(d)] for r in rows]
        got = topology.face_structure(mesh.simplices, mesh.n_vertices).multiplicity
        assert got.tolist() == want


@pytest.mark.parametrize("path", ["mixed-keys", "row-sort"])
@pytest.mark.parametrize("d", DIMS, ids=lambda d: f"{d}D")
def test_face_grouping_paths_agree(monkeypatch, d, path):
    """The sort words that do not hold key and index (large meshes) take the mixed-key path,
    and keys wider than a word the row sort; with a weak mix (the identity) most faces share
    a run with others and must be separated by the collision pass."""
    rng = np.random.default_rng(d)
    meshes = [_defective(d, defect, rng) for defect in ("holes", "duplicated", "glued", "flipped")]
    want = [reference_report(m) for m in meshes]
    for mix in (topology._MIX, np.uint64(1)):
        monkeypatch.setattr(topology, "_MIX", mix)
        for mesh, expected in zip(meshes, want):
            # a word that holds the face key but not the entry index, or not even the key
            key_bits = topology._bits(mesh.n_vertices) * (d - 1)
            monkeypatch.setattr(topology, "_WORD_BITS", key_bits if path == "mixed-keys" else key_bits - 1)
            fresh = SimplexMesh(mesh.vertices, mesh.simplices)
            assert fresh.check() == expected
            assert np.array_equal(fresh.components(), reference_components(mesh.simplices, mesh.n_vertices))


# --------------------------------------------------------------------------------------------
# what marching extraction guarantees (MARCHING_PROVED), proved on random fields
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", (3, 4), ids=lambda d: f"{d}D")
@pytest.mark.parametrize("method", ["cubes", "simplices"])
def test_marching_guarantee_holds_on_random_fields(d, method, backend):
    """Every extraction of a random field, closed or touching the grid border, with samples
    exactly at the level and either inside convention, on the host or the device, as values,
    padded by ``closed=True``, or sampled from a field, far from the origin or not, passes the
    full face sort and the star and link tests of the reference check, and its fast report,
    which takes what the construction guarantees from it (the vertex stars; by cubes clear of
    the grid's edge also the face counts: topology.MARCHING_CLOSED_PROVED), equals the
    reference report in every field."""
    from ao4d import extract, extract_field

    rng = np.random.default_rng([d, len(method)])
    kinds = {True: 0, False: 0}
    for trial in range(12 if d == 4 else 20):
        shape = tuple(rng.integers(3, 6 if d == 4 else 12, d))
        values = rng.normal(size=shape)
        if trial % 3 == 0:
            values = np.round(values)  # a third of the samples exactly at the level
        if trial % 2 == 0:
            values = np.pad(values, 1, constant_values=1.0)  # closed; odd trials are open
        inside = "above" if trial % 4 == 3 else "below"
        origin = 1e6 * (trial % 5 == 4)  # a grid far from the origin: exact boundary tests still
        if trial % 6 == 1:  # open values closed by padding
            mesh = extract(values, 0.0, method=method, inside=inside, closed=True, origin=origin, backend=backend)
        elif trial % 6 == 5 and inside == "below":  # the same values as a field on a grid
            axes = [origin + np.arange(n, dtype=np.float64) for n in values.shape]
            table = values.copy()

            def field(points, table=table, origin=origin):
                return table[tuple(np.moveaxis(np.rint(points - origin).astype(int), -1, 0))]

            bounds = ([a[0] for a in axes], [a[-1] for a in axes])
            mesh = extract_field(field, values.shape, bounds, method=method, backend=backend)
        else:
            mesh = extract(values, 0.0, method=method, inside=inside, origin=origin, backend=backend)
        if mesh.n_simplices == 0:
            continue
        want = reference_report(mesh)
        assert want.n_singular_vertices == 0 and want.n_nonmanifold_faces == 0 and want.oriented
        got = mesh.check()
        closed_proof = got.proved == topology.MARCHING_CLOSED_PROVED
        assert closed_proof or got.proved == topology.MARCHING_PROVED
        if closed_proof:  # sound: claimed only where true
            assert method == "cubes" and want.closed
        elif method == "cubes" and trial % 2 == 0:  # and claimed where the border is outside
            pytest.fail(f"trial {trial}: cubes in a grid bordered by outside values, yet the faces were not proved")
        kinds[closed_proof] += 1
        assert dataclasses.replace(got, proved=(), hint="") == want
        assert np.array_equal(mesh.components(), reference_components(mesh.simplices, mesh.n_vertices))
    assert kinds[False] and (kinds[True] or method == "simplices")  # both kinds of proof were tried


def test_proof_applies_only_to_unchanged_marching_meshes():
    """An edited, copied or hand-made mesh gets every field computed; so does a marching mesh
    whose computed faces contradict the guarantee."""
    from ao4d import extract

    x = np.linspace(-1.5, 1.5, 9)
    r = np.sqrt(sum(np.square(g) for g in np.meshgrid(x, x, x, x, indexing="ij")))
    mesh = extract(r, 1.0)
    assert mesh.check().proved == topology.MARCHING_CLOSED_PROVED
    assert "by construction" in str(mesh.check())
    assert mesh.copy().check().proved == ()
    assert SimplexMesh(mesh.vertices, mesh.simplices).check().proved == ()
    edited = extract(r, 1.0)
    simplices = edited.simplices.copy()
    simplices[0, :2] = simplices[0, 1::-1]
    edited.simplices = simplices
    assert edited.check().proved == () and not edited.check().oriented
    # marked as extracted, but a duplicated simplex makes faces shared by three: the computed
    # faces contradict the guarantee, so the star and link tests run
    duplicated = SimplexMesh(mesh.vertices, np.vstack([mesh.simplices, mesh.simplices[:1]]))
    duplicated._mark_constructed(topology.MARCHING_PROVED)
    report = duplicated.check()
    assert report.proved == () and report == reference_report(duplicated)
    assert report.n_singular_vertices > 0


@pytest.mark.parametrize("scale", [1e-300, 1e300])
def test_check_is_not_ok_when_measures_leave_float64(scale):
    # every simplex degenerate (1e-300) or the volume nan (1e300) was reported "OK"
    import ao4d

    mesh = ao4d.extract_field(ao4d.fields.hypersphere(0.7), (7,) * 4, (-1.0, 1.0))
    with np.errstate(all="ignore"):
        report = SimplexMesh(mesh.vertices * scale, mesh.simplices).check()
        assert not report.measurable and not report.ok
        assert "measures: NO" in str(report) and "NOT OK" in str(report)
    assert SimplexMesh(mesh.vertices, mesh.simplices).check().ok
