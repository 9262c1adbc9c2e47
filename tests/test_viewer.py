"""``ao4d view`` / :mod:`ao4d.browser.viewer`: the page's geometry in numpy, the HTML file, and the page
itself in a real headless Chromium (software WebGL2: SwiftShader), asserting on pixels.

The browser tests compare the page's own pixels (``window.ao4d.capture()``: the canvas, alpha 0
where nothing is drawn) with analytic slices of hyperspheres under the page's camera
(:func:`ao4d.browser.viewer.camera`) and with the CPU slice (:meth:`SimplexMesh.slice` via
:func:`ao4d.browser.viewer.slice_for_state`) rasterised here in numpy with :func:`ao4d.browser.viewer.project`.
"""

from __future__ import annotations

import base64
import json
import math
import re
import time
import urllib.error
import urllib.request
import zlib

import numpy as np
import pytest
from _chromium import browser_or_skip, capture, open_page
from hypothesis import given, settings
from hypothesis import strategies as st

import ao4d
from ao4d import cli
from ao4d.browser import viewer

HALF = math.radians(viewer.HALF_FOV_DEG)


# --------------------------------------------------------------------------- meshes


def _ball(radius=1.0, center=(0.0, 0.0, 0.0, 0.0), n=16, dim=4):
    c = np.asarray(center, dtype=float)
    lo, hi = c - 1.3 * radius, c + 1.3 * radius
    return ao4d.extract_field(ao4d.fields.hypersphere(radius, c), (n,) * dim, (lo, hi))


@pytest.fixture(scope="module")
def sphere():
    """Hypersphere R = 1 at the origin (16^4 grid: 39,360 tetrahedra), AO = a ramp in x."""
    mesh = _ball(1.0)
    mesh.point_data["ao"] = np.clip(0.5 + 0.45 * mesh.vertices[:, 0], 0.0, 1.0)
    return mesh


@pytest.fixture(scope="module")
def small_sphere():
    return _ball(1.0, n=8)


@pytest.fixture(scope="module")
def demo_like():
    """The demo's default scene at the tiny grid, with 4D AO (16 samples): four objects."""
    from ao4d.scenes import default_scene, extract_scene

    scene_def = default_scene()
    meshes = extract_scene(scene_def, cell=0.2, progress=False)
    joined = ao4d.mesh.concatenate(meshes)
    joined.point_data["ao"] = ao4d.ambient_occlusion(
        joined, samples=16, seed=0, progress=False, max_distance=scene_def.max_distance
    )
    return viewer.split_objects(joined), [o.name for o in scene_def.objects]


def _canonical(corners):
    """Triangles (T, 3, 3) as a sorted array, each rolled to start at its smallest corner."""
    corners = np.round(np.asarray(corners, dtype=float), 9)
    out = []
    for tri in corners:
        k = min(range(3), key=lambda i: tuple(tri[i]))
        out.append(np.roll(tri, -k, axis=0).ravel())
    out = np.array(out).reshape(-1, 9)
    return out[np.lexsort(out.T[::-1])]


# --------------------------------------------------------------------------- geometry in numpy


def test_rotation_order_and_planes():
    e = np.eye(4)
    assert np.allclose(viewer.rotation({"xw": 90}) @ e[0], e[3])  # x turns towards w
    assert np.allclose(viewer.rotation({"xw": 90}) @ e[3], -e[0])
    assert np.allclose(viewer.rotation({"yz": 90}) @ e[1], e[2])
    # xy is applied first: x -> y, then xw leaves y alone (the other order would give w)
    assert np.allclose(viewer.rotation({"xy": 90, "xw": 90}) @ e[0], e[1])
    angles = dict(xy=10, xz=-20, xw=33, yz=47, yw=-71, zw=150)
    r = viewer.rotation(angles)
    product = np.eye(4)
    for name in viewer.ANGLES:
        product = viewer.rotation({name: angles[name]}) @ product
    assert np.allclose(r, product, atol=1e-15)
    assert np.allclose(r @ r.T, np.eye(4), atol=1e-14) and np.isclose(np.linalg.det(r), 1.0)


def test_full_state_wraps_clamps_and_names_errors():
    frame = viewer.Frame(np.array([0.0, 0.0, 0.0, 0.25]), 1.0)
    s = viewer.full_state({"xy": 270, "az": -180, "el": 120, "light": True, "hide": [2, 0, 2]}, frame=frame)
    assert (s["xy"], s["az"], s["el"], s["light"], s["hide"]) == (-90.0, 180.0, 90.0, 1, (0, 2))
    assert s["w"] == 0.25  # the scene's centre in w
    with pytest.raises(ValueError, match="unknown key.*'tilt'"):
        viewer.full_state({"tilt": 3})
    with pytest.raises(ValueError, match=r"state\['zoom'\]"):
        viewer.full_state({"zoom": 0})
    with pytest.raises(TypeError, match=r"state\['w'\]"):
        viewer.full_state({"w": "high"})
    with pytest.raises(ValueError, match=r"state\['w'\]"):
        viewer.full_state({"w": float("nan")})
    with pytest.raises(ValueError, match=r"state\['light'\]"):
        viewer.full_state({"light": 2})
    with pytest.raises(ValueError, match=r"state\['hide'\]"):
        viewer.full_state({"hide": [-1]})


def test_camera_frames_the_ball_whatever_w_and_angles():
    frame = viewer.Frame(np.array([0.5, -1.0, 2.0, 0.0]), 2.0)
    w, h = 400, 300
    base = viewer.camera({"az": 40, "el": -25}, w, h, frame=frame)
    # the target is the image centre; the camera is outside the ball
    assert np.allclose(
        viewer.project([frame.center[:3]], {"az": 40, "el": -25}, w, h, frame=frame)[0, :2], [w / 2, h / 2]
    )
    assert base.distance > frame.radius and base.near > 0
    # the ball's silhouette: radius scale * tan(asin(r / D)) = 1 / 1.1 of the half short side
    rho = base.scale * math.tan(math.asin(frame.radius / base.distance))
    assert rho == pytest.approx(min(w, h) / 2 * math.tan(math.asin(math.sin(HALF) / 1.1)) / math.tan(HALF))
    assert rho < min(w, h) / 2
    rng = np.random.default_rng(0)
    pts = frame.center[:3] + rng.normal(size=(50, 3))
    p0 = viewer.project(pts, {"az": 40, "el": -25}, w, h, frame=frame)
    p1 = viewer.project(pts, {"az": 40, "el": -25, "w": 1.5, "xw": 80, "yz": 12}, w, h, frame=frame)
    assert np.array_equal(p0, p1)  # the 4D state never moves the camera
    p2 = viewer.project(pts, {"az": 40, "el": -25, "zoom": 2.0}, w, h, frame=frame)
    assert np.allclose(p2[:, :2] - [w / 2, h / 2], 2 * (p0[:, :2] - [w / 2, h / 2]))
    # right is +x and up is +y at az = el = 0
    q = viewer.project([[1.0, 0, 0], [0, 1.0, 0]], {"az": 0, "el": 0}, w, h, frame=viewer.Frame(np.zeros(4), 1.0))
    assert q[0, 0] > w / 2 and np.isclose(q[0, 1], h / 2) and q[1, 1] < h / 2


def test_view_projection_matrix_matches_project():
    frame = viewer.Frame(np.array([0.2, 0.1, -0.3, 0.0]), 1.5)
    state = {"az": -70, "el": 35, "zoom": 1.3}
    cam = viewer.camera(state, 320, 200, frame=frame)
    m = viewer._view_projection(cam)
    pts = np.random.default_rng(1).uniform(-1, 1, size=(20, 3))
    clip = np.c_[pts, np.ones(20)] @ m.T
    ndc = clip[:, :3] / clip[:, 3:]
    px = viewer.project(pts, state, 320, 200, frame=frame)
    assert np.allclose((ndc[:, 0] + 1) * 160, px[:, 0]) and np.allclose((1 - ndc[:, 1]) * 100, px[:, 1])
    assert (np.abs(ndc[:, 2]) < 1).all()  # inside the depth range: the whole ball is


@settings(max_examples=25, deadline=None)
@given(angles=st.lists(st.floats(-180, 180), min_size=6, max_size=6), w=st.floats(-0.95, 0.95))
def test_page_shader_mirror_equals_mesh_slice(small_sphere, angles, w):
    """The page's cut table and interpolation (numpy mirror) give SimplexMesh.slice's triangles."""
    state = dict(zip(viewer.ANGLES, angles), w=w)
    frame = viewer.scene_frame(small_sphere)
    corners, _, _ = viewer._page_triangles(small_sphere, state, frame=frame)
    tri = viewer.slice_for_state(small_sphere, state)
    assert len(corners) == len(tri.faces)
    assert np.allclose(_canonical(corners), _canonical(tri.vertices[tri.faces]), atol=1e-8)


def test_cut_table_orientation_and_ao_match_slice(sphere):
    """Same triangles with the same winding (outward) and the same interpolated AO."""
    state = {"w": 0.3, "xw": 35, "zw": -20}
    frame = viewer.scene_frame(sphere)
    corners, ao, _ = viewer._page_triangles(sphere, state, frame=frame)
    tri = viewer.slice_for_state(sphere, state)
    assert np.allclose(_canonical(corners), _canonical(tri.vertices[tri.faces]), atol=1e-8)
    # outward: the normals point away from the slice ball's centre
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert (np.einsum("ij,ij->i", n, corners.mean(axis=1)) > 0).all()
    page = np.c_[corners.reshape(-1, 3), ao.reshape(-1, 1)]
    cpu = np.c_[tri.vertices[tri.faces].reshape(-1, 3), tri.vertex_attributes["ao"][tri.faces].reshape(-1, 1)]
    assert np.allclose(
        page[np.lexsort(np.round(page, 9).T[::-1])], cpu[np.lexsort(np.round(cpu, 9).T[::-1])], atol=1e-8
    )


@settings(max_examples=25, deadline=None)
@given(angles=st.lists(st.floats(-180, 180), min_size=6, max_size=6), w=st.floats(-1.0, 1.0))
def test_chunk_culling_never_drops_a_cut_tetrahedron(sphere, angles, w):
    state = dict(zip(viewer.ANGLES, angles), w=w)
    frame = viewer.scene_frame(sphere)
    centred = viewer._centred(sphere.vertices, frame)  # the page's coordinates
    order, balls = viewer._chunk_order(centred, sphere.simplices)
    # every chunk's ball holds its vertices
    v = centred[np.asarray(sphere.simplices)[order]]
    k = np.arange(len(order)) // viewer.CHUNK
    assert (np.linalg.norm(v - balls[k, None, :4], axis=2) <= balls[k, 4:5]).all()
    active = viewer._active_chunks(balls, state, frame=frame)
    _, _, tets = viewer._page_triangles(sphere, state, frame=frame)
    position = np.empty(len(order), dtype=np.int64)
    position[order] = np.arange(len(order))
    assert active[position[tets] // viewer.CHUNK].all()


def test_culling_skips_most_chunks_off_centre(sphere):
    frame = viewer.scene_frame(sphere)
    _, balls = viewer._chunk_order(viewer._centred(sphere.vertices, frame), sphere.simplices)
    active = viewer._active_chunks(balls, {"w": 0.9}, frame=frame)
    assert active.mean() < 0.5


def test_back_faces_are_culled_only_on_closed_consistently_oriented_meshes(small_sphere):
    v, s = np.asarray(small_sphere.vertices), np.asarray(small_sphere.simplices)
    assert small_sphere.check().ok and viewer._facing(v, s) == "back"
    assert viewer._facing(v, np.asarray(small_sphere.flipped().simplices)) == "front"  # inside out
    one = s.copy()
    one[7, [0, 1]] = one[7, [1, 0]]  # one simplex turned: no longer consistently oriented
    assert viewer._facing(v, one) == "none"
    assert viewer._facing(v, s[1:]) == "none"  # a hole: not closed
    ball3 = _ball(1.0, (0, 0, 0), n=8, dim=3)
    assert viewer._facing(np.asarray(ball3.vertices), np.asarray(ball3.simplices)) == "back"
    open_sheet = ao4d.SimplexMesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    assert viewer._facing(np.asarray(open_sheet.vertices), np.asarray(open_sheet.simplices)) == "none"


def test_slice_for_state_errors(small_sphere):
    with pytest.raises(ValueError, match="one mesh"):
        viewer.slice_for_state([small_sphere, small_sphere], {})
    with pytest.raises(ValueError, match="4D"):
        viewer.slice_for_state(_ball(1.0, (0, 0, 0), n=8, dim=3), {})
    with pytest.raises(ValueError, match="unknown key"):
        viewer.slice_for_state(small_sphere, {"q": 1})


def test_slice_for_state_off_centre_sphere_turned_in_xw():
    mesh = _ball(0.45, (0.5, 0, 0, 0), n=14)
    frame = viewer.scene_frame(mesh, center=np.zeros(4))
    tri = viewer.slice_for_state(mesh, {"w": 0.5, "xw": 90}, frame=frame)
    r = np.linalg.norm(tri.vertices, axis=1)  # centred at the origin after the turn
    assert abs(r.mean() - 0.45) < 0.01 and r.max() < 0.46
    assert len(viewer.slice_for_state(mesh, {"w": 0.5, "xw": -90}, frame=frame).faces) == 0
    assert len(viewer.slice_for_state(mesh, {"w": 0.5}, frame=frame).faces) == 0


def test_split_objects_round_trip(demo_like):
    meshes, _ = demo_like
    joined = ao4d.mesh.concatenate(meshes)
    again = viewer.split_objects(joined)
    for a, b in zip(meshes, again):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.simplices, b.simplices)
        assert np.array_equal(a.point_data["ao"], b.point_data["ao"])
    with pytest.raises(ValueError, match="object_id"):
        viewer.split_objects(meshes[0])


# --------------------------------------------------------------------------- the HTML file


def _scene_of(path):
    text = path.read_text(encoding="utf-8")
    scene = json.loads(
        re.search(r'<script type="application/json" id="ao4d-scene">(.*?)</script>', text, re.DOTALL).group(1)
    )

    def blob(meta):
        b64 = re.search(
            f'<script type="application/octet-stream" id="{meta["id"]}">(.*?)</script>', text, re.DOTALL
        ).group(1)
        data = base64.b64decode(b64)
        if meta["encoding"] == "deflate":
            data = zlib.decompress(data)
        dtype = {"float32": "<f4", "float64": "<f8", "uint32": "<u4"}[meta["dtype"]]
        return np.frombuffer(data, dtype=dtype).reshape(meta["shape"])

    return text, scene, blob


@pytest.mark.parametrize("compress", [True, False])
def test_page_is_self_contained_and_holds_the_mesh(tmp_path, sphere, compress):
    path = viewer.view(sphere, tmp_path / "p.html", compress=compress, state={"w": 0.3, "xw": 90})
    text, scene, blob = _scene_of(path)
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    # nothing fetched from anywhere: no URLs, no external scripts, styles or images
    assert not re.search(r"https?://", text)
    assert not re.search(r"<(script|img|iframe)[^>]*\ssrc=|<link\b(?![^>]*href=\"data:)|@import", text, re.IGNORECASE)
    assert scene["dim"] == 4 and scene["state"]["w"] == 0.3 and scene["state"]["xw"] == 90
    assert scene["cut"] == viewer.cut_table()
    frame = viewer.scene_frame(sphere)
    assert scene["center"] == frame.center.tolist() and scene["radius"] == frame.radius
    (obj,) = scene["objects"]
    assert obj["has_ao"] and obj["vertices"]["encoding"] == ("deflate" if compress else "raw")
    centred = viewer._centred(sphere.vertices, frame)
    assert np.array_equal(blob(obj["vertices"]), centred.astype(np.float32))
    assert np.array_equal(blob(obj["ao"]), np.asarray(sphere.point_data["ao"], dtype=np.float32))
    order, balls = viewer._chunk_order(centred, sphere.simplices)
    assert np.array_equal(blob(obj["simplices"]), np.asarray(sphere.simplices)[order])
    assert np.array_equal(blob(obj["chunks"]), balls)
    assert list(tmp_path.iterdir()) == [path]  # the atomic write left no temporary file


def _shader_cut_float32(scene, blob, state):
    """numpy mirror of the page's float32 work for one 4D object: each tetrahedron's cut case and
    its first cut point in scene coordinates (page coordinates + centre, in float64)."""
    (obj,) = scene["objects"]
    v32 = blob(obj["vertices"]).astype(np.float32)
    tets = blob(obj["simplices"]).astype(np.int64)
    st = viewer.full_state({**scene["state"], **state})
    rot32 = viewer.rotation(st).astype(np.float32)
    p = v32 @ rot32.T  # float32, as uRot * vertex in the vertex shader
    w32 = np.float32(st["w"] - scene["center"][3])  # JavaScript doubles, then the uniform
    s = p[tets, 3] - w32
    case = ((s >= 0) * (1 << np.arange(4))).sum(axis=1)
    cut = (case != 0) & (case != 15)
    rows = np.arange(len(s))
    other = np.argmax((s >= 0) != (s[:, :1] >= 0), axis=1)  # an edge from vertex 0 across the cut
    sa, sb = s[:, 0], s[rows, other]
    t = sa / np.where(sa != sb, sa - sb, 1)
    pa, pb = p[tets[:, 0], :3], p[tets[rows, other], :3]
    point = (pa + t[:, None] * (pb - pa)).astype(np.float64) + np.asarray(scene["center"][:3])
    return case, point, cut


@pytest.mark.parametrize("shift", [1e3, 1e6])
def test_page_far_from_the_origin_looks_like_the_page_at_it(tmp_path, sphere, shift):
    # the page gets recentred vertices: absolute float32 ones (0.06 apart at 1e6) and a float32
    # translation would cut a scene far from the origin into noise
    moved = ao4d.SimplexMesh(
        np.asarray(sphere.vertices) + shift, sphere.simplices, point_data={"ao": sphere.point_data["ao"]}
    )
    state = {"w": 0.3, "xw": 30.0, "yz": 20.0}
    here = viewer.view(sphere, tmp_path / "here.html", state=state)
    there = viewer.view(moved, tmp_path / "there.html", state={**state, "w": 0.3 + shift})
    _, scene_a, blob_a = _scene_of(here)
    _, scene_b, blob_b = _scene_of(there)
    np.testing.assert_allclose(scene_b["center"], np.asarray(scene_a["center"]) + shift, rtol=0, atol=1e-9)
    case_a, point_a, cut_a = _shader_cut_float32(scene_a, blob_a, {})
    case_b, point_b, cut_b = _shader_cut_float32(scene_b, blob_b, {})
    assert cut_a.sum() > 1000
    # float32 of x + shift - c differs from float32 of x - c by float64 round-off at most: the
    # same cases except for vertices within that of the hyperplane
    assert (case_a != case_b).mean() < 1e-3
    both = cut_a & cut_b & (case_a == case_b)
    err = np.abs(point_b[both] - shift - point_a[both]).max()
    assert err < 1e-5, err  # float32 at the scene's size (radius 1), not at its distance
    # the culling mirror, on the page's own chunk balls
    active = viewer._active_chunks(
        blob_b(scene_b["objects"][0]["chunks"]), {**state, "w": 0.3 + shift}, frame=viewer.scene_frame(moved)
    )
    chunk_of_cut = np.flatnonzero(cut_b) // viewer.CHUNK
    assert active[chunk_of_cut].all() and active.mean() < 0.9


def test_page_size_limit_points_to_serve(tmp_path, sphere):
    with pytest.raises(ValueError, match="--serve"):
        viewer.view(sphere, tmp_path / "p.html", max_bytes=100_000)
    assert not (tmp_path / "p.html").exists()
    with pytest.raises(ValueError, match="max_bytes"):
        viewer.view(sphere, tmp_path / "p.html", max_bytes=0)


def test_view_input_errors(tmp_path, sphere):
    out = tmp_path / "p.html"
    flat = ao4d.SimplexMesh(np.array([[0.0, 0], [1, 0], [0, 1]]), np.array([[0, 1], [1, 2], [2, 0]]))
    with pytest.raises(ValueError, match="3D or 4D"):
        viewer.view(flat, out)
    ball3 = _ball(1.0, (0, 0, 0), n=8, dim=3)
    with pytest.raises(ValueError, match="same dimension"):
        viewer.view([sphere, ball3], out)
    with pytest.raises(ValueError, match="`names`"):
        viewer.view([sphere, sphere], out, names=["a"])
    with pytest.raises(FileNotFoundError, match=r"meshes\[1\]"):
        viewer.view([sphere, tmp_path / "missing.npz"], out)
    with pytest.raises(TypeError, match="`meshes`"):
        viewer.view(3, out)
    with pytest.raises(ValueError, match="at least one"):
        viewer.view([], out)
    with pytest.raises(ValueError, match="offsets"):
        viewer.view([sphere, sphere], out, offsets=np.zeros((3, 4)))
    with pytest.raises(ValueError, match="colors"):
        viewer.view([sphere, sphere], out, colors=["red"])
    with pytest.raises(ValueError, match=r"colors\[1\]"):
        viewer.view([sphere, sphere], out, colors=["red", "not-a-colour"])
    with pytest.raises(ValueError, match="cmap"):
        viewer.view(sphere, out, cmap="no-such-map")
    with pytest.raises(ValueError, match="hide"):
        viewer.view(sphere, out, state={"hide": [1]})
    bad = ao4d.SimplexMesh(sphere.vertices, sphere.simplices)
    bad.point_data["ao"] = np.full(bad.n_vertices, 1.5)
    with pytest.raises(ValueError, match=r"point_data\['ao'\].*\[0, 1\]"):
        viewer.view(bad, out)
    bad.point_data["ao"] = np.full(bad.n_vertices, np.nan)
    with pytest.raises(ValueError, match="non-finite"):
        viewer.view(bad, out)
    assert not out.exists()


def test_mesh_without_ao_is_marked_and_3d_meshes_are_accepted(tmp_path):
    ball3 = _ball(1.0, (0, 0, 0), n=8, dim=3)
    path = viewer.view([ball3, ball3], tmp_path / "p.html", names=["a", "b"], offsets=[[0, 0, 0], [3, 0, 0]])
    _, scene, blob = _scene_of(path)
    assert scene["dim"] == 3 and [o["name"] for o in scene["objects"]] == ["a", "b"]
    assert not scene["objects"][0]["has_ao"] and scene["objects"][0]["ao"] is None
    assert scene["objects"][1]["offset"] == [3.0, 0.0, 0.0]
    # the frame holds both balls
    v = np.asarray(ball3.vertices)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0) + [3, 0, 0])
    assert scene["center"] == pytest.approx(c.tolist()) and c[0] == pytest.approx(1.5)
    assert scene["radius"] == np.linalg.norm(np.vstack([v, v + [3, 0, 0]]) - c, axis=1).max()
    assert np.array_equal(blob(scene["objects"][0]["simplices"]), np.asarray(ball3.simplices, dtype=np.uint32))


def test_cli_view_writes_the_page(tmp_path, small_sphere, capsys):
    npz = tmp_path / "ball.npz"
    small_sphere.save(npz)
    out = tmp_path / "ball.html"
    assert cli.main(["view", str(npz), "--out", str(out), "--w", "0.3", "--xw", "90", "--zoom", "1.5"]) == 0
    assert "wrote" in capsys.readouterr().out
    _, scene, _ = _scene_of(out)
    assert scene["title"] == "ball" and scene["objects"][0]["name"] == "ball"
    assert (scene["state"]["w"], scene["state"]["xw"], scene["state"]["zoom"]) == (0.3, 90, 1.5)
    assert cli.main(["view", str(npz), "--serve", "--out", str(out)]) == 2
    assert "exclude" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path / "nope.npz"), "--out", str(out)]) == 2
    assert cli.main(["view", str(npz), "--out", str(out), "--max-mb", "0.01"]) == 2
    assert "--serve" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["view", "--help"])
    assert "URL" in capsys.readouterr().out


def test_serve_gives_page_and_buffers(small_sphere):
    with viewer.serve(small_sphere) as server:
        assert server.url.startswith("http://127.0.0.1:")
        page = urllib.request.urlopen(server.url, timeout=10).read().decode()
        scene = json.loads(re.search(r'id="ao4d-scene">(.*?)</script>', page, re.DOTALL).group(1))
        meta = scene["objects"][0]["vertices"]
        data = urllib.request.urlopen(server.url + meta["url"], timeout=10).read()
        centred = viewer._centred(small_sphere.vertices, viewer.scene_frame(small_sphere))
        assert np.array_equal(
            np.frombuffer(zlib.decompress(data), "<f4").reshape(meta["shape"]), centred.astype(np.float32)
        )
        with pytest.raises(urllib.error.HTTPError, match="404"):
            urllib.request.urlopen(server.url + "etc/passwd", timeout=10)
    with pytest.raises(ValueError, match="host"):
        viewer.serve(small_sphere, host="0.0.0.0")
    with pytest.raises(ValueError, match="port"):
        viewer.serve(small_sphere, port=70000)


def test_page_text_and_serve_take_the_options_of_view(small_sphere, tmp_path):
    # one list of options (view's signature): the same page by view and page_text, and an option
    # view does not take (or serve: max_bytes) refused naming the function
    options = {"names": ["ball"], "state": {"w": 0.2, "xw": 30}, "title": "t", "cull": "none"}
    assert viewer.view(small_sphere, tmp_path / "a.html", **options).read_text() == viewer.page_text(
        small_sphere, **options
    )
    with pytest.raises(TypeError, match=r"page_text\(\) got unknown option\(s\) 'colour'; it takes .*colors"):
        viewer.page_text(small_sphere, colour="red")
    with pytest.raises(TypeError, match=r"serve\(\) got unknown option\(s\) 'max_bytes'"):
        viewer.serve(small_sphere, max_bytes=10**9)
    with pytest.raises(ValueError, match="`max_bytes` must be a positive integer"):
        viewer.page_text(small_sphere, max_bytes=0)


# --------------------------------------------------------------------------- in the browser

WIDTH, HEIGHT = 700, 420  # window; the canvas is what the panel leaves (424 x 420)


@pytest.fixture(scope="module")
def browser():
    yield from browser_or_skip(WIDTH, HEIGHT)


def _disc_radius(frame, state, width, height, rho):
    """Pixel radius of a ball of radius rho centred on the camera target (perspective)."""
    cam = viewer.camera(state, width, height, frame=frame)
    return cam.scale * math.tan(math.asin(rho / cam.distance))


def _rasterize(triangles, values, owners, state, width, height, frame):
    """Pixel-centre rasterisation with a depth buffer: owner (-1 = none) and the value there,
    interpolated perspective-correctly as the GPU does."""
    t = len(triangles)
    p = viewer.project(triangles.reshape(-1, 3), state, width, height, frame=frame).reshape(t, 3, 3)
    depth = np.full((height, width), np.inf)
    value = np.full((height, width), np.nan)
    owner = np.full((height, width), -1)
    for k in range(t):
        x, y, z = p[k, :, 0], p[k, :, 1], p[k, :, 2]
        i0, i1 = max(int(np.floor(x.min() - 0.5)), 0), min(int(np.ceil(x.max() - 0.5)), width - 1)
        j0, j1 = max(int(np.floor(y.min() - 0.5)), 0), min(int(np.ceil(y.max() - 0.5)), height - 1)
        area = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0])
        if i0 > i1 or j0 > j1 or area == 0:
            continue
        gx, gy = np.meshgrid(np.arange(i0, i1 + 1) + 0.5, np.arange(j0, j1 + 1) + 0.5)
        l0 = ((x[1] - gx) * (y[2] - gy) - (x[2] - gx) * (y[1] - gy)) / area
        l1 = ((x[2] - gx) * (y[0] - gy) - (x[0] - gx) * (y[2] - gy)) / area
        l2 = 1.0 - l0 - l1
        inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        q = np.stack([l0 / z[0], l1 / z[1], l2 / z[2]])
        d = 1.0 / q.sum(axis=0)
        v = (q[0] * values[k, 0] + q[1] * values[k, 1] + q[2] * values[k, 2]) * d
        win = depth[j0 : j1 + 1, i0 : i1 + 1]
        take = inside & (d < win)
        win[take] = d[take]
        value[j0 : j1 + 1, i0 : i1 + 1][take] = v[take]
        owner[j0 : j1 + 1, i0 : i1 + 1][take] = owners[k]
    return owner, value


def _cpu_picture(meshes, state, width, height, frame):
    tris, vals, owners = [], [], []
    for i, m in enumerate(meshes):
        tri = viewer.slice_for_state(m, state, frame=frame)
        if len(tri.faces) == 0:
            continue
        tris.append(tri.vertices[tri.faces])
        ao = tri.vertex_attributes.get("ao", np.zeros(len(tri.vertices)))
        vals.append(1.0 - np.asarray(ao)[tri.faces])
        owners.append(np.full(len(tri.faces), i))
    if not tris:
        return np.full((height, width), -1), np.full((height, width), np.nan)
    return _rasterize(np.concatenate(tris), np.concatenate(vals), np.concatenate(owners), state, width, height, frame)


def _openness(rgb, ramp):
    """Invert a colour ramp (256, 4) uint8: the 1 - AO whose colour is nearest (as the GPU
    filters it: linear between entries)."""
    fine = np.linspace(0, 255, 255 * 16 + 1)
    table = np.stack([np.interp(fine, np.arange(256), ramp[:, c].astype(float)) for c in range(3)], 1)
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(table).query(np.asarray(rgb, dtype=float))
    return fine[nearest] / 255.0


def _ramp_of(page_scene, i):
    return np.frombuffer(base64.b64decode(page_scene["objects"][i]["ramp"]), np.uint8).reshape(256, 4)


def _iou(a, b):
    return (a & b).sum() / max(1, (a | b).sum())


@pytest.fixture(scope="module")
def sphere_page(tmp_path_factory, sphere):
    return viewer.view(sphere, tmp_path_factory.mktemp("view") / "sphere.html").as_uri()


@pytest.mark.parametrize("w", [0.0, 0.6])
def test_browser_hypersphere_slice_is_a_ball(browser, sphere, sphere_page, w):
    state = {"w": w, "az": 30, "el": 20, "zoom": 1}
    stats = open_page(browser, sphere_page, f"#w={w}&az=30&el=20&zoom=1")
    img = capture(browser)
    h, w_px = img.shape[:2]
    assert [w_px, h] == stats["canvas"]
    covered = img[..., 3] > 127
    frame = viewer.scene_frame(sphere)
    radius = _disc_radius(frame, state, w_px, h, math.sqrt(1.0 - w * w))
    # 16^4 grid (cell 0.17): the inscribed polytope is up to ~0.5 % smaller in radius; pixel
    # edges add ~perimeter / 2 pixels: 3 % covers both
    assert covered.sum() == pytest.approx(math.pi * radius**2, rel=0.03)
    jj, ii = np.nonzero(covered)
    assert abs(ii.mean() + 0.5 - w_px / 2) < 1.0 and abs(jj.mean() + 0.5 - h / 2) < 1.0
    # the triangle count is the CPU slice's
    assert stats["triangles"] == len(viewer.slice_for_state(sphere, state).faces)
    assert browser.errors == []


def test_browser_empty_slice_is_empty_and_says_so(browser, sphere_page):
    stats = open_page(browser, sphere_page, "#w=1.2")
    assert stats["triangles"] == 0 and stats["empty"]
    assert "Empty slice" in stats["message"]
    assert (capture(browser)[..., 3] == 0).all()
    # moving back into the object draws it again and the message goes
    browser.evaluate("window.ao4d.setState({w: 0.2})")
    assert (capture(browser)[..., 3] > 127).sum() > 1000
    browser.wait_for("window.ao4d.stats().message === ''", timeout=5)
    assert browser.errors == []


def test_browser_off_centre_hypersphere_turned_90_in_xw(browser, tmp_path):
    mesh = _ball(0.45, (0.5, 0, 0, 0), n=14)
    frame = viewer.scene_frame(mesh, center=np.zeros(4))
    url = viewer.view(mesh, tmp_path / "off.html", center=np.zeros(4)).as_uri()
    for fragment, rho in [
        ("#w=0.5&xw=90", 0.45),
        ("#w=0.3&xw=90", math.sqrt(0.45**2 - 0.2**2)),
        ("#w=0.5&xw=-90", None),
        ("#w=0.5&xw=0", None),
    ]:
        stats = open_page(browser, url, fragment + "&az=30&el=20")
        img = capture(browser)
        covered = img[..., 3] > 127
        h, w_px = covered.shape
        if rho is None:  # turned the other way, or not at all: the hyperplane misses it
            assert stats["triangles"] == 0 and not covered.any(), fragment
            continue
        state = {"w": float(fragment.split("=")[1].split("&")[0]), "xw": 90, "az": 30, "el": 20}
        radius = _disc_radius(frame, state, w_px, h, rho)
        assert covered.sum() == pytest.approx(math.pi * radius**2, rel=0.04), fragment
        jj, ii = np.nonzero(covered)  # centred on the origin, the camera's target
        assert abs(ii.mean() + 0.5 - w_px / 2) < 1.0 and abs(jj.mean() + 0.5 - h / 2) < 1.0
    assert browser.errors == []


STATE = {"w": 0.15, "xy": 12, "xz": -25, "xw": 37, "yz": 8, "yw": -19, "zw": 44, "az": -50, "el": 30, "zoom": 1.4}


def _fragment(state):
    return "#" + "&".join(f"{k}={v}" for k, v in state.items())


@pytest.mark.parametrize("aa", [None, 1])
def test_browser_silhouette_equals_cpu_slice(browser, demo_like, tmp_path, aa):
    """Default (no multisampling on software GL) and forced multisampling (``#aa=1``)."""
    meshes, names = demo_like
    frame = viewer.scene_frame(meshes)
    url = viewer.view(meshes, tmp_path / "demo.html", names=names).as_uri()
    stats = open_page(browser, url, _fragment(STATE) + ("" if aa is None else f"&aa={aa}"))
    assert stats["antialias"] is (aa == 1)  # SwiftShader: off unless asked for
    img = capture(browser)
    h, w_px = img.shape[:2]
    owner, _ = _cpu_picture(meshes, STATE, w_px, h, frame)
    gpu, cpu = img[..., 3] > 127, owner >= 0
    assert cpu.sum() > 5000  # a real picture
    assert _iou(gpu, cpu) >= 0.95
    assert stats["per_object"] == [len(viewer.slice_for_state(m, STATE, frame=frame).faces) for m in meshes]
    assert browser.errors == []


def test_browser_colours_are_the_cpu_slice_ao(browser, demo_like, tmp_path):
    """With lighting off each pixel's colour is ramp(1 - AO) of the CPU slice there; the AO of
    the demo-like scene is graded (contacts, the indent), and so are the colours."""
    meshes, names = demo_like
    frame = viewer.scene_frame(meshes)
    path = viewer.view(meshes, tmp_path / "demo.html", names=names)
    _, page_scene, _ = _scene_of(path)
    state = dict(STATE, light=0, w=0.0, xw=10, yw=0, zw=0)
    open_page(browser, path.as_uri(), _fragment(state))
    img = capture(browser)
    h, w_px = img.shape[:2]
    owner, value = _cpu_picture(meshes, state, w_px, h, frame)
    # compare away from edges: the pixel and its 4 neighbours belong to the same object
    pad = np.pad(owner, 1, constant_values=-2)
    same = np.ones_like(owner, dtype=bool)
    for dj, di in [(0, 1), (2, 1), (1, 0), (1, 2)]:
        same &= pad[dj : dj + h, di : di + w_px] == owner
    interior = same & (owner >= 0) & (img[..., 3] == 255)
    errors, graded = [], []
    for i in range(len(meshes)):
        sel = interior & (owner == i)
        if sel.sum() < 200:
            continue
        got = _openness(img[sel][:, :3], _ramp_of(page_scene, i))
        errors.append(np.abs(got - value[sel]))
        graded.append(got)
    errors = np.concatenate(errors)
    assert len(errors) > 5000
    assert np.median(errors) < 0.01 and np.quantile(errors, 0.95) < 0.04
    allv = np.concatenate(graded)
    assert allv.std() > 0.05 and np.quantile(allv, 0.95) - np.quantile(allv, 0.05) > 0.2
    # lighting only darkens (Lambert term in [0.3, 1]) and does somewhere
    browser.evaluate("window.ao4d.setState({light: 1})")
    lit = capture(browser)
    both = (lit[..., 3] == 255) & (img[..., 3] == 255)
    assert (lit[both][:, :3].astype(int) <= img[both][:, :3].astype(int) + 1).all()
    assert (lit[both][:, :3].astype(int).sum(1) < img[both][:, :3].astype(int).sum(1) - 30).mean() > 0.2
    assert browser.errors == []


def test_browser_lambert_term_is_the_slice_triangles_normal(browser, sphere, sphere_page):
    """lit / unlit = 0.3 + 0.7 max(n . l, 0), n the CPU slice triangle's normal at the pixel."""
    state = {"w": 0.4, "xw": 25, "az": -40, "el": 25, "zoom": 1.1}
    open_page(browser, sphere_page, _fragment(state) + "&light=0")
    flat = capture(browser).astype(float)
    browser.evaluate("window.ao4d.setState({light: 1})")
    lit = capture(browser).astype(float)
    h, w_px = flat.shape[:2]
    frame = viewer.scene_frame(sphere)
    tri = viewer.slice_for_state(sphere, state)
    corners = tri.vertices[tri.faces]
    owner, _ = _rasterize(corners, np.ones(corners.shape[:2]), np.arange(len(corners)), state, w_px, h, frame)
    cam = viewer.camera(state, w_px, h, frame=frame)
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= np.sign(np.einsum("ij,ij->i", n, cam.eye - corners.mean(axis=1)))[:, None]
    expected = 0.3 + 0.7 * np.clip(n @ cam.light, 0, None)
    sel = (owner >= 0) & (flat[..., 3] == 255) & (flat[..., :3].max(axis=2) > 60)
    ratio = lit[sel][:, :3].sum(axis=1) / flat[sel][:, :3].sum(axis=1)
    err = np.abs(ratio - expected[owner[sel]])
    assert sel.sum() > 5000 and np.median(err) < 0.01 and np.quantile(err, 0.95) < 0.05
    assert expected[owner[sel]].std() > 0.1  # a real spread of light and shade
    assert browser.errors == []


def test_browser_mesh_without_ao_has_shade_one(browser, small_sphere, tmp_path):
    path = viewer.view(small_sphere, tmp_path / "noao.html")
    _, page_scene, _ = _scene_of(path)
    stats = open_page(browser, path.as_uri(), "#w=0&light=0")
    img = capture(browser)
    top = _ramp_of(page_scene, 0)[255, :3].astype(int)
    px = img[img[..., 3] == 255][:, :3].astype(int)
    assert len(px) > 1000 and (np.abs(px - top) <= 1).all()
    assert "no AO" in browser.evaluate("document.getElementById('objects').textContent")
    assert stats["triangles"] > 0


def test_browser_url_state_round_trip(browser, sphere_page):
    open_page(browser, sphere_page, "#w=0.3&xw=90&az=30&el=20&zoom=1.5")
    s = browser.evaluate("window.ao4d.state()")
    assert (s["w"], s["xw"], s["az"], s["el"], s["zoom"], s["xy"]) == (0.3, 90, 30, 20, 1.5, 0)
    # setState wraps and clamps like ao4d.browser.viewer.full_state, and writes the fragment
    s = browser.evaluate("window.ao4d.setState({yz: 12.5, xy: 270, el: 120, light: 0})")
    py = viewer.full_state({"yz": 12.5, "xy": 270, "el": 120, "light": 0})
    assert (s["yz"], s["xy"], s["el"], s["light"]) == (py["yz"], py["xy"], py["el"], py["light"])
    assert (s["yz"], s["xy"], s["el"], s["light"]) == (12.5, -90, 90, 0)
    fragment = browser.wait_for("location.hash.includes('yz=12.5') && location.hash", timeout=5)
    assert "xy=-90" in fragment and "light=0" in fragment and "w=0.3" in fragment
    # a fresh load of that URL restores the same state
    open_page(browser, sphere_page, fragment)
    assert browser.evaluate("window.ao4d.state()") == s
    assert browser.errors == []


def test_browser_mouse_keys_wheel_and_play(browser, sphere_page):
    open_page(browser, sphere_page, "#w=0&az=30&el=20&zoom=1")
    x, y = 276 + 200, 200  # on the canvas, right of the panel

    browser.mouse("mousePressed", x, y, buttons=1)
    browser.mouse("mouseMoved", x + 50, y + 25, buttons=1)
    browser.mouse("mouseReleased", x + 50, y + 25)
    s = browser.evaluate("window.ao4d.state()")
    assert s["az"] == pytest.approx(30 - 0.4 * 50) and s["el"] == pytest.approx(20 + 0.4 * 25)
    browser.mouse("mousePressed", x, y, buttons=1, modifiers=8)  # shift: turn in xw / yw
    browser.mouse("mouseMoved", x + 40, y - 20, buttons=1, modifiers=8)
    browser.mouse("mouseReleased", x + 40, y - 20, modifiers=8)
    s = browser.evaluate("window.ao4d.state()")
    assert s["xw"] == pytest.approx(20) and s["yw"] == pytest.approx(-10) and s["az"] == pytest.approx(10)
    browser.mouse("mouseWheel", x, y, deltaX=0, deltaY=-200)
    browser.wait_for("window.ao4d.state().zoom > 1.01", timeout=5)
    assert browser.evaluate("window.ao4d.state().zoom") == pytest.approx(math.exp(0.3), rel=1e-6)
    for key in ("ArrowRight", "]"):
        browser.send("Input.dispatchKeyEvent", session=True, type="keyDown", key=key)
        browser.send("Input.dispatchKeyEvent", session=True, type="keyUp", key=key)
    s = browser.evaluate("window.ao4d.state()")
    assert s["az"] == pytest.approx(5) and s["w"] == pytest.approx(
        0.02 * browser.evaluate("window.ao4d.scene().radius")
    )
    # play sweeps w and measures frames per second
    browser.evaluate("document.getElementById('play').click()")
    w0 = browser.evaluate("window.ao4d.state().w")
    time.sleep(1.0)
    stats = browser.evaluate("window.ao4d.stats()")
    browser.evaluate("window.ao4d.play(false)")
    assert stats["playing"] and stats["fps"] > 0
    assert browser.evaluate("window.ao4d.state().w") != w0
    assert browser.errors == []


def test_browser_png_button_and_hidden_objects(browser, demo_like, tmp_path):
    meshes, names = demo_like
    url = viewer.view(meshes, tmp_path / "demo.html", names=names).as_uri()
    stats = open_page(browser, url, "#w=0&hide=1,3")
    assert stats["per_object"][1] == 0 and stats["per_object"][3] == 0 and stats["per_object"][0] > 0
    assert browser.evaluate("[0,1,2,3].map(i => document.getElementById('vis-' + i).checked)") == [
        True,
        False,
        True,
        False,
    ]
    browser.send("Browser.setDownloadBehavior", behavior="allow", downloadPath=str(tmp_path))
    browser.evaluate("document.getElementById('shot').click()")
    png = tmp_path / "ao4d-view.png"
    deadline = time.monotonic() + 10
    while not png.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    import matplotlib.image

    picture = matplotlib.image.imread(png)
    assert list(picture.shape[1::-1]) == stats["canvas"]
    # opaque, background colour in the corner, the scene in the middle
    assert np.allclose(picture[0, 0, :3] * 255, [0x3D, 0x43, 0x4F], atol=1)
    assert picture[..., :3].std() > 0.05
    assert browser.errors == []


def test_browser_3d_mesh_orbit_view(browser, tmp_path):
    ball3 = _ball(1.0, (0, 0, 0), n=24, dim=3)
    ball3.point_data["ao"] = np.zeros(ball3.n_vertices)
    frame = viewer.scene_frame(ball3)
    url = viewer.view(ball3, tmp_path / "ball3.html").as_uri()
    state = {"az": 70, "el": -10, "zoom": 0.9}
    stats = open_page(browser, url, _fragment(state))
    assert browser.evaluate("getComputedStyle(document.getElementById('controls4d')).display") == "none"
    img = capture(browser)
    h, w_px = img.shape[:2]
    tri = np.asarray(ball3.vertices)[np.asarray(ball3.simplices)]
    owner, _ = _rasterize(tri, np.ones(tri.shape[:2]), np.zeros(len(tri), int), state, w_px, h, frame)
    gpu = img[..., 3] > 127
    assert _iou(gpu, owner >= 0) >= 0.95
    radius = _disc_radius(frame, state, w_px, h, 1.0)
    assert gpu.sum() == pytest.approx(math.pi * radius**2, rel=0.03)
    assert stats["triangles"] == ball3.n_simplices
    assert browser.evaluate("location.hash") == _fragment(state)  # as loaded
    browser.evaluate("window.ao4d.setState({az: 10})")
    frag = browser.wait_for("location.hash", timeout=5)
    assert frag.startswith("#az=10&el=-10&zoom=0.9") and "w=" not in frag
    assert browser.errors == []


def test_browser_served_page_equals_file_page(browser, small_sphere, tmp_path):
    fragment = "#w=0.25&xw=30&yz=40"
    file_stats = open_page(browser, viewer.view(small_sphere, tmp_path / "s.html").as_uri(), fragment)
    file_img = capture(browser)
    with viewer.serve(small_sphere) as server:
        stats = open_page(browser, server.url, fragment)
        img = capture(browser)
    assert stats["triangles"] == file_stats["triangles"] > 0
    assert np.array_equal(img, file_img)
    assert browser.errors == []


# -- far from the origin, fragments ----------------------------------------------------------


def test_browser_scene_far_from_the_origin_looks_like_the_one_at_it(browser, sphere, tmp_path):
    # recentred vertices: absolute float32 vertices and translation would cut noise at 1e6
    shift = 1e6
    moved = ao4d.SimplexMesh(
        np.asarray(sphere.vertices) + shift, sphere.simplices, point_data={"ao": sphere.point_data["ao"]}
    )
    state = {"xw": 30, "yz": 20, "az": 30, "el": 20, "zoom": 1}
    here = viewer.view(sphere, tmp_path / "here.html").as_uri()
    there = viewer.view(moved, tmp_path / "there.html").as_uri()
    stats_a = open_page(browser, here, _fragment({"w": 0.3, **state}))
    img_a = capture(browser).astype(int)
    stats_b = open_page(browser, there, _fragment({"w": 0.3 + shift, **state}))
    img_b = capture(browser).astype(int)
    assert stats_a["triangles"] > 1000
    assert abs(stats_b["triangles"] - stats_a["triangles"]) <= 0.001 * stats_a["triangles"]
    differ = np.abs(img_a - img_b).max(axis=2) > 8
    assert differ.mean() < 0.002, differ.mean()
    assert browser.errors == []


@pytest.mark.parametrize("fragment", ["#w=%", "#zoom=%E0%A4%A", "#light=banana", "#zoom=abc&xw=", "#hide=x"])
def test_browser_bad_fragment_values_are_ignored_with_a_warning(browser, sphere_page, fragment):
    # no blank page on "URI malformed", and light=banana keeps the light on
    browser.console.clear()
    open_page(browser, sphere_page, fragment)
    s = browser.evaluate("window.ao4d.state()")
    default = viewer.full_state(None, frame=viewer.scene_frame(_ball(1.0)))
    assert s["light"] == 1 and s["zoom"] == default["zoom"] and s["hide"] == []
    assert s["w"] == pytest.approx(default["w"], abs=1e-9)
    assert any(kind == "warning" and "ao4d view: ignoring" in text for kind, text in browser.console)
    assert browser.errors == []


def test_browser_url_holds_the_whole_view(browser, small_sphere, tmp_path):
    # hide is written when empty and light when 1, and a reload takes the fragment as the whole
    # state: the objects the user showed come back shown and lit
    path = viewer.view(
        [small_sphere, small_sphere],
        tmp_path / "two.html",
        offsets=[[0, 0, 0, 0], [3, 0, 0, 0]],
        state={"hide": [1], "light": 0},
    )
    open_page(browser, path.as_uri())
    assert browser.evaluate("window.ao4d.state()")["hide"] == [1]
    browser.evaluate("window.ao4d.setState({hide: [], light: 1, az: 40})")
    fragment = browser.wait_for("location.hash.includes('az=40') && location.hash", timeout=5)
    assert "light=1" in fragment and re.search(r"(^#|&)hide=(&|$)", fragment), fragment
    open_page(browser, path.as_uri(), fragment)
    s = browser.evaluate("window.ao4d.state()")
    assert s["hide"] == [] and s["light"] == 1 and s["az"] == 40
    # a hand-written fragment with view keys is the view: every object shown and lit
    open_page(browser, path.as_uri(), "#az=10")
    s = browser.evaluate("window.ao4d.state()")
    assert s["hide"] == [] and s["light"] == 1 and s["az"] == 10
    assert browser.errors == []


def test_view_refuses_what_the_command_line_refuses(tmp_path, small_sphere):
    with pytest.raises(ValueError, match=r"`path` must end in \.html or \.htm"):
        viewer.view(small_sphere, tmp_path / "p.png")  # no HTML written into a .png
    assert not (tmp_path / "p.png").exists()
    with pytest.raises(TypeError, match=r"`state` must be a mapping.*'w=0.3'.*#"):
        viewer.view(small_sphere, tmp_path / "p.html", state="w=0.3")


def test_view_into_a_folder_it_cannot_write_names_the_page(tmp_path, small_sphere, monkeypatch):
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)  # the folder check's probe
    with pytest.raises(ValueError, match=r"`path` .*p\.html.*cannot write") as err:
        viewer.view(small_sphere, tmp_path / "p.html")
    assert ".tmp" not in str(err.value)


def test_a_busy_port_is_named(small_sphere):
    with viewer.serve(small_sphere) as first:
        with pytest.raises(OSError, match=f"port {first.port}.*--port"):
            viewer.serve(small_sphere, port=first.port)


def test_a_trimesh_and_pairs_give_the_pages_of_the_simplex_mesh(small_sphere, tmp_path):
    import trimesh

    tri = trimesh.creation.icosphere(subdivisions=1)
    mesh3 = ao4d.SimplexMesh.from_trimesh(tri)
    want3 = viewer.page_text(mesh3)
    assert viewer.page_text(tri) == want3
    assert viewer.page_text((np.asarray(tri.vertices), np.asarray(tri.faces))) == want3
    pair = (small_sphere.vertices, small_sphere.simplices)
    assert viewer.page_text([small_sphere, pair]) == viewer.page_text([small_sphere, small_sphere])
    want = viewer.view(small_sphere, tmp_path / "mesh.html").read_bytes()
    assert viewer.view(pair, tmp_path / "pair.html").read_bytes() == want
    frame, got = viewer.scene_frame(small_sphere), viewer.scene_frame(pair)
    np.testing.assert_array_equal(got.center, frame.center)
    assert got.radius == frame.radius
    cut, cut_pair = (viewer.slice_for_state(m, {"w": 0.3, "xw": 20}) for m in (small_sphere, pair))
    assert len(cut.faces) > 50
    np.testing.assert_array_equal(cut_pair.vertices, cut.vertices)
    np.testing.assert_array_equal(cut_pair.faces, cut.faces)


def test_a_wrong_mesh_type_is_a_type_error_naming_the_parameter(small_sphere, tmp_path):
    forms = r"a SimplexMesh, a trimesh.Trimesh, a \(vertices, simplices\) pair or a path to an .npz mesh"
    with pytest.raises(TypeError, match=f"`meshes` must be {forms}, or a sequence of them; got float"):
        viewer.page_text(3.0)
    with pytest.raises(TypeError, match=rf"`meshes\[1\]` must be {forms}; got dict"):
        viewer.view([small_sphere, {}], tmp_path / "bad.html")
    with pytest.raises(TypeError, match=f"`mesh` must be {forms}"):
        viewer.slice_for_state(object(), {})
    with pytest.raises(TypeError, match=f"`meshes` must be {forms}"):
        viewer.scene_frame(None)
    assert not (tmp_path / "bad.html").exists()
