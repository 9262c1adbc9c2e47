"""``ao4d view IMAGE.vti`` / :mod:`ao4d.browser.image_viewer`: the 8-bit image, the transfer function,
the numpy ray-march against analytic answers, and the page in headless Chromium (SwiftShader)
held to that numpy ray-march pixel by pixel.

The browser tests read the page's own pixels (``window.ao4d.capture()``: premultiplied RGBA, alpha
0 where nothing is drawn) and compare them with :func:`ao4d.browser.image_viewer.reference_march` of the
same image, transfer function, clipping and camera: the silhouettes (alpha > 1/2) overlap by
IoU >= 95 % and the median colour error over pixels inside both is <= 0.02. The ray-march is nearest-voxel on both sides, so a disagreement is a real difference of
sampling or compositing, not filtering round-off.
"""

from __future__ import annotations

import base64
import math
import zlib

import numpy as np
import pytest
from _chromium import browser_or_skip, capture, open_page

import ao4d
from ao4d import cli
from ao4d.browser import image_viewer as iv

# --------------------------------------------------------------------------- images


@pytest.fixture(scope="module")
def sphere_image():
    """The hypersphere R = 1 seen by a 4D perspective camera from w = -4: 28^3 voxels, lit."""
    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (14,) * 4, (-1.3, 1.3), progress=False)
    mesh.point_data["ao"] = np.clip(0.5 + 0.45 * mesh.vertices[:, 0], 0.0, 1.0)
    cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], fov=40)
    return ao4d.render(mesh, cam, (28, 28, 28), ao="vertices", light=[0, 1, 0, -1], backend="numpy", progress=False)


def _box(value=0.8, n=(10, 12, 16)):
    shade = np.zeros(n, np.float32)
    shade[...] = value
    return shade


# --------------------------------------------------------------------------- numpy side


def test_encode_quantises_and_marks_the_hits(sphere_image):
    data = iv.encode(sphere_image)
    assert data.shape == (28, 28, 28) and data.arrays == iv.ARRAYS
    assert np.array_equal(data.hit, sphere_image.hit)
    hit = sphere_image.hit
    assert 0.1 < hit.mean() < 0.6
    # q = floor(255 v + 1/2): within half a step of the value
    assert np.abs(data.scalars[..., 0][hit] / 255.0 - sphere_image.shade[hit]).max() <= 0.5 / 255 + 1e-7
    assert np.abs(data.scalars[..., 1][hit] / 255.0 - sphere_image.occlusion[hit]).max() <= 0.5 / 255 + 1e-7
    d = sphere_image.depth[hit]
    lo, hi = data.ranges["depth"]
    assert (lo, hi) == (pytest.approx(d.min()), pytest.approx(d.max()))
    assert data.scalars[..., 2][hit].min() == 0 and data.scalars[..., 2][hit].max() == 255
    assert (data.scalars[~hit] == 0).all() and (data.colors[~hit] == 0).all()
    assert np.array_equal(data.colors[hit], sphere_image.rgba8[hit])


def test_files_give_the_image_of_the_result(sphere_image, tmp_path):
    data = iv.encode(sphere_image)
    assert data.notes == () and data.ranges["shade"] == (0.0, 1.0)  # ao4d's own: as it is
    vti = iv.load_image(sphere_image.save(tmp_path / "s.vti"))
    assert np.array_equal(vti.scalars, data.scalars) and np.array_equal(vti.colors, data.colors)
    assert np.allclose(vti.spacing, data.spacing) and np.allclose(vti.origin, data.origin)
    mhd = iv.load_image(sphere_image.save(tmp_path / "s.mhd"))  # shade only: hit = shade > 0
    assert mhd.colors is None and mhd.arrays == ("shade",)  # only what the file holds
    assert np.array_equal(mhd.scalars[..., 0], data.scalars[..., 0])
    assert np.array_equal(mhd.hit, sphere_image.hit & (sphere_image.shade > 0))
    with pytest.raises(ValueError, match="image extension"):
        iv.load_image(tmp_path / "s.npz")
    with pytest.raises(FileNotFoundError, match="no such file"):
        iv.load_image(tmp_path / "none.vti")
    with pytest.raises(TypeError, match="`image` must be a RenderResult"):
        iv.encode([1, 2, 3])


def test_full_state_names_bad_values():
    s = iv.full_state({"az": 270, "el": 100}, image=iv.encode(_box()))
    assert (s["array"], s["az"], s["el"], s["cmap"]) == ("shade", -90.0, 90.0, "magma")
    with pytest.raises(ValueError, match="unknown key.*'w'"):
        iv.full_state({"w": 0.3})
    with pytest.raises(ValueError, match=r"state\['array'\]"):
        iv.full_state({"array": "rgba"}, image=iv.encode(_box()))
    with pytest.raises(ValueError, match=r"state\['cmap'\]"):
        iv.full_state({"cmap": "jet"})
    with pytest.raises(ValueError, match=r"state\['opacity'\]"):
        iv.full_state({"opacity": 1.5})
    with pytest.raises(ValueError, match=r"state\['x0'\]` must be <="):
        iv.full_state({"x0": 0.8, "x1": 0.2})
    with pytest.raises(TypeError, match="`state` must be a mapping"):
        iv.full_state("az=3")


def test_transfer_function_ramp():
    colours, a = iv.transfer_function({"lo": 0.2, "hi": 0.6, "opacity": 0.5})
    s = np.arange(256) / 255
    assert np.allclose(a, 0.5 * np.clip((s - 0.2) / 0.4, 0, 1))
    _, step = iv.transfer_function({"lo": 0.5, "hi": 0.5})  # hi <= lo: a step at lo
    assert (step == (s >= 0.5)).all()
    assert colours.shape == (256, 3) and np.allclose(colours[-1], [252 / 255, 253 / 255, 191 / 255])


def test_reference_march_composites_a_slab_analytically():
    # a box of 16 voxels along z seen head on: the centre ray takes 2 * 16 samples (STEP = 1/2),
    # each of opacity 1 - (1 - a)^(1/2), so the box lets (1 - a)^16 through
    a = 0.05
    data = iv.encode(_box(0.8, (12, 12, 16)))
    pic = iv.reference_march(data, {"az": 0, "el": 0, "opacity": a, "array": "shade"}, 40, 40)
    centre = pic[20, 20]
    assert centre[3] == pytest.approx(1 - (1 - a) ** 16, rel=1e-9)
    q = math.floor(255 * 0.8 + 0.5)
    colour = iv.transfer_function({})[0][q]
    assert np.allclose(centre[:3], colour * centre[3])  # premultiplied colour of one value
    assert (pic[0, 0] == 0).all()  # a ray that misses the box
    # opaque: the first sample decides; clipping the box in half halves the path
    assert iv.reference_march(data, {"az": 0, "el": 0}, 40, 40)[20, 20, 3] == pytest.approx(1.0)
    half = iv.reference_march(data, {"az": 0, "el": 0, "opacity": a, "z0": 0.5}, 40, 40)[20, 20, 3]
    assert half == pytest.approx(1 - (1 - a) ** 8, rel=1e-9)
    # the box's silhouette head on: 12 voxels wide at distance D, scale px per unit
    frame = iv.image_frame(data)
    cam = ao4d.browser.viewer.camera({"az": 0, "el": 0}, 40, 40, frame=frame)
    near = cam.distance - 8.0  # the front face, z = +8 from the centre
    width_px = (pic[20, :, 3] > 0).sum()
    assert width_px == pytest.approx(12 * cam.scale / near, abs=1.0)


def test_reference_of_an_empty_image_is_empty():
    pic = iv.reference_march(np.zeros((8, 8, 8)), {"opacity": 1.0}, 30, 20)
    assert pic.shape == (20, 30, 4) and not pic.any()


def test_page_holds_the_image(sphere_image, tmp_path):
    page = iv.view_image(sphere_image, tmp_path / "s.html", state={"array": "occlusion", "az": 40})
    text = page.read_text()
    assert text.startswith("<!DOCTYPE html>") and "http://" not in text.replace("http://www.w3.org", "")
    info = iv.page_info(text)
    assert info["state"]["array"] == "occlusion" and info["state"]["az"] == 40
    assert info["shape"] == [28, 28, 28] and info["hits"] == int(sphere_image.hit.sum())
    tag = f'id="{info["scalars"]["id"]}">'
    start = text.index(tag) + len(tag)
    raw = zlib.decompress(base64.b64decode(text[start : text.index("</script>", start)]))
    # x runs fastest in the 3D texture
    scalars = np.frombuffer(raw, np.uint8).reshape(28, 28, 28, 4).transpose(2, 1, 0, 3)
    assert np.array_equal(scalars, iv.encode(sphere_image).scalars)
    # the hit box and the occupied blocks the page skips by
    hit = sphere_image.hit
    (i0, j0, k0), (i1, j1, k1) = info["hit_box"]
    assert hit[i0:i1, j0:j1, k0:k1].sum() == hit.sum() and hit[i0].any() and hit[i1 - 1].any()
    assert info["blocks_shape"] == [4, 4, 4] and info["block"] == iv.BLOCK
    with pytest.raises(ValueError, match="`path`.*html"):
        iv.view_image(sphere_image, tmp_path / "s.png")
    with pytest.raises(ValueError, match="max_bytes"):
        iv.view_image(sphere_image, tmp_path / "t.html", max_bytes=1000)
    with pytest.raises(ValueError, match=r"state\['zoom'\]"):
        iv.view_image(sphere_image, tmp_path / "t.html", state={"zoom": 0})


def test_cli_view_writes_the_image_page(sphere_image, tmp_path, capsys):
    vti = sphere_image.save(tmp_path / "s.vti")
    out = tmp_path / "page.html"
    assert cli.main(["view", str(vti), "--out", str(out), "--array", "depth", "--az", "10"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert iv.page_info(out.read_text())["state"]["array"] == "depth"
    assert cli.main(["view", str(vti), str(tmp_path / "m.npz"), "--out", str(out)]) == 2
    assert "separate pages" in capsys.readouterr().err
    mhd = sphere_image.save(tmp_path / "s.mhd")
    assert cli.main(["view", str(mhd), "--out", str(out), "--array", "rgba"]) == 2
    assert "`--array` 'rgba'" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path / "gone.vti"), "--out", str(out)]) == 2
    assert "gone.vti" in capsys.readouterr().err


def test_mhd_offers_only_the_shade_it_holds(sphere_image, tmp_path, capsys):
    # a .mhd holds shade alone: occlusion and depth would be all zeros
    mhd = sphere_image.save(tmp_path / "s.mhd")
    page = iv.view_image(mhd, tmp_path / "m.html")
    assert iv.page_info(page.read_text())["arrays"] == ["shade"]
    for array in ("occlusion", "depth"):
        with pytest.raises(
            ValueError,
            match=rf"`state\['array'\]` '{array}' is not in the image 's', "
            r"which holds 'shade'",
        ):
            iv.view_image(mhd, tmp_path / "m.html", state={"array": array})
        assert cli.main(["view", str(mhd), "--out", str(tmp_path / "o.html"), "--array", array]) == 2
        err = capsys.readouterr().err
        assert f"`--array` '{array}'" in err and "holds only 'shade' (a .mhd file holds shade alone)" in err
    assert not (tmp_path / "o.html").exists()
    assert iv.encode(_box()).arrays == ("shade",)  # a bare array: shade alone
    vti = ao4d.io.volumes.write_vti(tmp_path / "two.vti", {"shade": _box(), "depth": _box(2.0)})
    assert iv.load_image(vti).arrays == ("shade", "depth")


def _foreign(values_at, n=16):
    """A ball of radius 6 voxels whose values run along x, on a background, as another tool
    would write it: one array, no ids, no depth."""
    i = np.indices((n, n, n)).astype(np.float64)
    inside = ((i - (n - 1) / 2) ** 2).sum(axis=0) <= 36
    ramp = (i[0] - i[0][inside].min()) / (i[0][inside].max() - i[0][inside].min())  # 0..1 inside
    return values_at(np.where(inside, 0.2 + 0.8 * ramp, 0.0)), inside


@pytest.mark.parametrize("lo, hi", [(0.0, 1000.0), (-5.0, -1.0)], ids=["0..1000", "-5..-1"])
def test_foreign_image_is_shown_over_its_own_range(tmp_path, capsys, lo, hi):
    # [0, 1000] drew saturated and [-5, -1] drew nothing, without a word
    unit, inside = _foreign(lambda v: v)
    values = lo + (hi - lo) * unit  # background at lo, the ball in [lo + 0.2 (hi - lo), hi]
    path = ao4d.io.volumes.write_vti(tmp_path / "ct.vti", {"density": values.astype(np.float32)})
    data = iv.load_image(path)
    assert data.ranges["shade"] == (lo, hi) and len(data.notes) == 1
    assert f"shade spans [{lo:g}, {hi:g}]" in data.notes[0] and "mapped linearly" in data.notes[0]
    assert np.array_equal(data.hit, inside)
    expected = iv.encode(unit)  # the same image in [0, 1]: what ao4d itself would show
    assert np.array_equal(data.scalars, expected.scalars)
    state = {"az": 20, "el": 10, "lo": 0.1, "hi": 0.9}
    picture = iv.reference_march(data, state, 48, 40)
    assert np.array_equal(picture, iv.reference_march(expected, state, 48, 40))
    alpha = picture[..., 3]
    assert alpha.max() > 0.9 and 0.05 < (alpha > 0.5).mean() < 0.6  # drawn, and not a solid box
    colour = picture[..., 0][alpha > 0.5] / alpha[alpha > 0.5]
    assert colour.max() - colour.min() > 0.3  # the values vary on the picture (not saturated)
    with pytest.warns(iv.ImageRangeWarning, match=r"shown mapped linearly"):
        text = iv.image_page_text(path)
    info = iv.page_info(text)
    assert info["ranges"]["shade"] == [lo, hi] and info["notes"] == list(data.notes)
    assert info["arrays"] == ["shade"] and info["hits"] == int(inside.sum())
    assert cli.main(["view", str(path), "--out", str(tmp_path / "ct.html")]) == 0
    assert "ao4d view: note: `image` ct: shade spans" in capsys.readouterr().err


def test_unreadable_or_truncated_vti_is_named_so(sphere_image, tmp_path, capsys):
    whole = sphere_image.save(tmp_path / "s.vti").read_bytes()
    for name, data in [
        ("half.vti", whole[: len(whole) // 2]),
        ("cut.vti", whole[:-40]),
        ("head.vti", whole[:300]),
        ("empty.vti", b""),
        ("text.vti", b"not VTK " * 9),
    ]:
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(ValueError, match=rf"`image` '.*{name}' is unreadable or truncated"):
            iv.load_image(path)
        assert cli.main(["view", str(path), "--out", str(tmp_path / "p.html")]) == 2
        err = capsys.readouterr().err
        assert "unreadable or truncated" in err and "has no 'shade' array" not in err


# --------------------------------------------------------------------------- in the browser

WIDTH, HEIGHT = 620, 380  # window; the canvas is what the panel leaves (344 x 380)


@pytest.fixture(scope="module")
def browser():
    yield from browser_or_skip(WIDTH, HEIGHT)


def _capture(browser, api="window.ao4d"):
    return capture(browser, api) / 255.0


def agreement(page, reference):
    """(silhouette IoU, median colour error inside both): the two figures the tests bound."""
    a, b = page[..., 3] > 0.5, reference[..., 3] > 0.5
    both = a & b
    iou = both.sum() / max((a | b).sum(), 1)
    error = float(np.median(np.abs(page[both, :3] - reference[both, :3]).max(axis=1))) if both.any() else 0.0
    return float(iou), error


@pytest.fixture(scope="module")
def sphere_page(sphere_image, tmp_path_factory):
    return iv.view_image(sphere_image, tmp_path_factory.mktemp("img") / "sphere.html").as_uri()


@pytest.mark.parametrize(
    "state",
    [
        {"array": "rgba", "az": 30, "el": 20},
        {"array": "shade", "cmap": "viridis", "lo": 0.1, "hi": 0.9, "opacity": 0.3, "az": -60, "el": 35},
        {"array": "occlusion", "cmap": "magma", "z1": 0.55, "x0": 0.2, "az": 120, "el": -10, "zoom": 1.6},
        {"array": "depth", "cmap": "gray", "lo": 0.0, "hi": 0.3, "opacity": 0.35, "az": 0, "el": 0},
    ],
    ids=["rgba-surface", "shade-ramp", "occlusion-clipped", "depth-glass"],
)
def test_browser_hypersphere_image_equals_the_numpy_ray_march(browser, sphere_image, sphere_page, state):
    stats = open_page(browser, sphere_page, iv._state_fragment(state))
    assert stats["renderer"] and "swiftshader" in stats["renderer"].lower()
    page = _capture(browser)
    ref = iv.reference_march(sphere_image, state, page.shape[1], page.shape[0])
    assert (ref[..., 3] > 0.5).sum() > 2000  # the test looks at a real picture
    iou, error = agreement(page, ref)
    assert iou >= 0.95 and error <= 0.02, (iou, error)
    assert browser.errors == []


def test_browser_empty_image_draws_nothing_and_says_so(browser, tmp_path):
    url = iv.view_image(np.zeros((24, 24, 24), np.float32), tmp_path / "empty.html").as_uri()
    stats = open_page(browser, url, "#opacity=1&lo=0&hi=0")
    assert stats["empty"] and stats["hits"] == 0 and "nothing to draw" in stats["message"]
    assert not _capture(browser).any()
    assert browser.errors == []


def test_browser_url_state_round_trip(browser, sphere_page):
    open_page(browser, sphere_page, "#array=shade&az=40&el=-15&zoom=1.25&lo=0.2&hi=0.7&opacity=0.5&y1=0.6")
    s = browser.evaluate("window.ao4d.state()")
    assert (s["array"], s["az"], s["el"], s["zoom"], s["lo"], s["hi"], s["opacity"], s["y1"]) == (
        "shade",
        40,
        -15,
        1.25,
        0.2,
        0.7,
        0.5,
        0.6,
    )
    s = browser.evaluate("window.ao4d.setState({az: 270, el: 120, cmap: 'inferno', z0: 0.25})")
    py = iv.full_state({k: v for k, v in s.items()})
    assert (s["az"], s["el"], s["cmap"], s["z0"]) == (py["az"], py["el"], "inferno", 0.25) == (-90, 90, "inferno", 0.25)
    fragment = browser.wait_for("location.hash.includes('z0=0.25') && location.hash", timeout=5)
    open_page(browser, sphere_page, fragment)
    assert browser.evaluate("window.ao4d.state()") == s
    # bad values are left out with a warning
    browser.console.clear()
    open_page(browser, sphere_page, "#array=banana&opacity=x&x0=0.9&x1=0.1&zoom=%zz")
    s = browser.evaluate("window.ao4d.state()")
    assert (s["array"], s["opacity"], s["x0"], s["x1"]) == ("rgba", 1, 0, 1)
    assert any(kind == "warning" and "ao4d view: ignoring" in text for kind, text in browser.console)
    assert browser.errors == []


def test_browser_drag_the_ramp_orbit_and_presets(browser, sphere_page):
    open_page(browser, sphere_page, "#array=shade&lo=0&hi=0&opacity=1&az=30&el=20&zoom=1")

    box = browser.evaluate(
        "(() => { const r = document.getElementById('tf').getBoundingClientRect();"
        " return [r.left, r.top, r.width, r.height]; })()"
    )
    left, top, w, h = box
    # the right handle sits at (hi, opacity) = (0, 1): grab near it... the left one is nearer at
    # the bottom, so drag from the top left: hi and opacity follow the pointer
    browser.mouse("mousePressed", left + 2, top + 4, buttons=1)
    browser.mouse("mouseMoved", left + 0.75 * w, top + 4 + 0.5 * (h - 18), buttons=1)
    browser.mouse("mouseReleased", left + 0.75 * w, top + 4 + 0.5 * (h - 18))
    s = browser.evaluate("window.ao4d.state()")
    assert s["hi"] == pytest.approx(0.75, abs=0.01) and s["opacity"] == pytest.approx(0.5, abs=0.02)
    # the bottom-left handle: lo
    browser.mouse("mousePressed", left + 2, top + h - 14, buttons=1)
    browser.mouse("mouseMoved", left + 0.25 * w, top + h - 14, buttons=1)
    browser.mouse("mouseReleased", left + 0.25 * w, top + h - 14)
    assert browser.evaluate("window.ao4d.state().lo") == pytest.approx(0.25, abs=0.01)
    x, y = 276 + 150, 190  # on the canvas
    browser.mouse("mousePressed", x, y, buttons=1)
    browser.mouse("mouseMoved", x + 50, y + 25, buttons=1)
    browser.mouse("mouseReleased", x + 50, y + 25)
    s = browser.evaluate("window.ao4d.state()")
    assert s["az"] == pytest.approx(30 - 0.4 * 50) and s["el"] == pytest.approx(20 + 0.4 * 25)
    browser.mouse("mouseWheel", x, y, deltaX=0, deltaY=-200)
    browser.wait_for("window.ao4d.state().zoom > 1.01", timeout=5)
    browser.evaluate("document.getElementById('preset-glass').click()")
    s = browser.evaluate("window.ao4d.state()")
    assert {k: s[k] for k in iv.PRESETS["glass"]} == iv.PRESETS["glass"]
    bench = browser.evaluate("window.ao4d.bench(2)")
    assert bench["frames"] == 2 and bench["ms_per_frame"] > 0
    png = browser.evaluate("window.ao4d.png()")
    assert png.startswith("data:image/png;base64,")
    assert browser.errors == []


def test_cli_serves_the_image_page(sphere_image, tmp_path, capsys, monkeypatch):
    import urllib.request

    from ao4d.browser import viewer

    vti = sphere_image.save(tmp_path / "s.vti")
    got = {}

    def fetch_then_stop(server):  # instead of blocking until Ctrl-C
        with urllib.request.urlopen(server.url, timeout=10) as reply:
            got["page"] = reply.read().decode()
        server.close()

    monkeypatch.setattr(viewer.ViewServer, "wait", fetch_then_stop)
    assert cli.main(["view", str(vti), "--serve", "--array", "occlusion"]) == 0
    assert "serving" in capsys.readouterr().out
    assert iv.page_info(got["page"])["state"]["array"] == "occlusion"
    assert cli.main(["view", str(vti), "--serve", "--out", str(tmp_path / "x.html")]) == 2
    assert "exclude each other" in capsys.readouterr().err
