""":mod:`ao4d.browser.pages`: ``ao4d.view`` for meshes and images, inline display in Jupyter (a real
notebook executed by ``nbclient`` in a real kernel), and the demo's one page with both views,
loaded in headless Chromium (SwiftShader).

The browser tests hold the result page's projection view of the demo image to the numpy
ray-march (:func:`ao4d.browser.image_viewer.reference_march`) as ``tests/test_image_viewer.py`` does for
a page of its own: silhouette IoU >= 95 %, median colour error <= 0.02.
"""

from __future__ import annotations

import html
import io
import re
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from _chromium import Chromium, browser_or_skip, capture, find_chromium

import ao4d
from ao4d.browser import _page, pages
from ao4d.browser import image_viewer as iv


@pytest.fixture(scope="module")
def sphere():
    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (10,) * 4, (-1.3, 1.3), progress=False)
    mesh.point_data["ao"] = np.clip(0.5 + 0.45 * mesh.vertices[:, 0], 0.0, 1.0)
    return mesh


@pytest.fixture(scope="module")
def image(sphere):
    cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], fov=40)
    return ao4d.render(sphere, cam, (24, 24, 24), ao="vertices", light=[0, 1, 0, -1], backend="numpy", progress=False)


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    from ao4d.commands.demo import run_demo

    out = tmp_path_factory.mktemp("demo")
    run_demo(out, quality="tiny", progress=False, stream=io.StringIO())
    return out


def _srcdoc(markup):
    start = markup.index('srcdoc="') + len('srcdoc="')
    return html.unescape(markup[start : markup.index('"', start)])


def test_view_dispatches_meshes_and_images(sphere, image, tmp_path):
    page = ao4d.view(sphere, tmp_path / "m.html")
    assert isinstance(page, Path) and isinstance(page, pages.Page) and page.exists()
    assert 'content="ao4d view"' in page.read_text()
    page = ao4d.view(image, tmp_path / "i.html")
    assert 'content="ao4d view (image)"' in page.read_text()
    vti = image.save(tmp_path / "i.vti")
    assert iv.page_info(ao4d.view(vti, tmp_path / "f.html").read_text())["hits"] == int(image.hit.sum())
    # the notebook form: the page itself in an iframe's srcdoc
    for what, generator in ((sphere, "ao4d view"), (image, "ao4d view (image)")):
        shown = ao4d.view(what)
        assert isinstance(shown, pages.InlinePage)
        markup = shown._repr_html_()
        assert markup.startswith('<iframe class="ao4d-view" srcdoc="')
        assert _srcdoc(markup) == shown.html and f'content="{generator}"' in shown.html
    assert _srcdoc(image._repr_html_()) == pages.inline(image).html  # RenderResult in Jupyter
    assert 'content="ao4d view (image)"' in _srcdoc(page._repr_html_())  # a written Page too
    with pytest.raises(TypeError, match="unknown option.*'colour'.*takes .*colors"):
        ao4d.view(sphere, colour="red")
    with pytest.raises(ValueError, match="`height`"):
        ao4d.view(image, height=3)


def test_a_page_over_the_inline_limit_is_served(image):
    shown = ao4d.view(image, inline_limit=1000)
    try:
        markup = shown._repr_html_()
        assert "srcdoc" not in markup and shown.server.url in markup
        with urllib.request.urlopen(shown.server.url, timeout=10) as reply:
            assert reply.read().decode() == shown.html
    finally:
        shown.close()


def test_view_refuses_an_array_and_unknown_options_naming_them(sphere, image, tmp_path):
    # an array met "`meshes[0]` must be ..."; foo=1 "page_text() got an unexpected keyword"
    with pytest.raises(TypeError, match=r"`what` must be a SimplexMesh.*array of shape \(4, 4, 4, 4\).*ao4d.extract"):
        ao4d.view(np.zeros((4, 4, 4, 4)))
    with pytest.raises(TypeError, match="`what` must be"):
        ao4d.view(np.zeros((4, 4, 4, 4)), tmp_path / "a.html")
    for what, kind in ((image, "an image's page"), (sphere, "the meshes' page")):
        for path in (None, tmp_path / "b.html"):
            with pytest.raises(TypeError, match=f"unknown option.*'foo' for {kind}; it takes .*title"):
                ao4d.view(what, path, foo=1)
    assert not (tmp_path / "a.html").exists() and not (tmp_path / "b.html").exists()
    assert "ao4d" in ao4d.view(image, title="t")._repr_html_()


def test_result_page_errors(sphere, image, tmp_path):
    with pytest.raises(ValueError, match="`tab`"):
        pages.result_page(sphere, image, tmp_path / "r.html", tab="left")
    with pytest.raises(ValueError, match="`path`"):
        pages.result_page(sphere, image, tmp_path / "r.txt")
    with pytest.raises(ValueError, match="max_bytes"):
        pages.result_page(sphere, image, tmp_path / "r.html", max_bytes=5000)


def test_demo_view_html_holds_both_views(demo_dir):
    text = (demo_dir / "view.html").read_text()
    assert 'content="ao4d result page"' in text
    inner = [html.unescape(part.split('"', 1)[0]) for part in text.split('srcdoc="')[1:]]
    assert len(inner) == 2
    assert 'content="ao4d view"' in inner[0] and 'content="ao4d view (image)"' in inner[1]
    assert iv.page_info(inner[1])["shape"] == [26, 10, 16]


# --------------------------------------------------------------------------- one shared script

_SLOTS = (
    "<!--AO4D_HEAD-->",
    "<!--AO4D_PANEL-->",
    "<!--AO4D_BODY-->",
    "<!--AO4D_COMMON-->",
    "<!--AO4D_DATA-->",
    "__AO4D_SCENE__",
)


def _own_script(text):
    """A page's text without the shared script: what the page itself brings."""
    common = _page.common_script()
    assert text.count(common) == 1, f"the shared script {text.count(common)} times"
    return text.replace(common, "")


def _shared_definitions():
    """The functions and arrow constants ao4d/browser/page_common.js defines (at its top level)."""
    script = _page.common_script()
    names = set(re.findall(r"^  (?:async )?function (\w+)\(|^  const (\w+) = \(", script, re.M))
    names = {a or b for a, b in names}
    assert {
        "fragmentPairs",
        "loadBlob",
        "compile",
        "orbitCamera",
        "bindOrbit",
        "bindKeys",
        "page",
        "readCanvas",
        "savePNG",
        "cross",
    } <= names
    return names


def _assert_one_shared_script(text):
    rest = _own_script(text)
    assert "const ao4dPage" not in rest and rest.count("<!DOCTYPE html>") == 1
    for slot in _SLOTS:
        assert slot not in text, slot
    for name in _shared_definitions():  # no copy of a shared function left in the page's own script
        assert not re.search(rf"function {name}\(|const {name} = \(", rest), name


def test_pages_hold_the_shared_script_once_and_no_copy(sphere, image, tmp_path):
    from ao4d.browser import viewer

    _assert_one_shared_script(viewer.page_text(sphere))
    _assert_one_shared_script(iv.image_page_text(image))
    with viewer.serve(sphere) as server, urllib.request.urlopen(server.url, timeout=10) as reply:
        _assert_one_shared_script(reply.read().decode())
    # the result page: its own script uses the shared one too, and each view holds it once
    text = pages.result_page(sphere, image, tmp_path / "r.html").read_text()
    inner = [html.unescape(part.split('"', 1)[0]) for part in text.split('srcdoc="')[1:]]
    assert len(inner) == 2
    outer = text
    for page in inner:
        _assert_one_shared_script(page)
        outer = outer.replace(html.escape(page, quote=True), "")
    _assert_one_shared_script(outer)
    assert "fragmentPairs(location.hash)" in outer and "decodeURIComponent" not in _own_script(outer)


def test_page_sources_share_no_run_of_six_lines():
    """The pages' sources and the shared frame and script: each idea written once (the
    ``duplicates`` tool's bar, exact lines here)."""
    folder = Path(ao4d.__file__).parent / "browser"
    sources = {
        name: (folder / name).read_text().splitlines()
        for name in ("viewer_page.html", "image_page.html", "page_frame.html", "page_common.js")
    }
    sources["pages._OUTER"] = pages._OUTER.splitlines()
    runs = {}
    for name, lines in sources.items():
        for i in range(len(lines) - 5):
            window = tuple(line.strip() for line in lines[i : i + 6])
            if sum(bool(line) for line in window) >= 4:
                runs.setdefault(window, set()).add(name)
    shared = [(sorted(names), window) for window, names in runs.items() if len(names) > 1]
    assert not shared, shared[:3]


# --------------------------------------------------------------------------- notebooks


def _notebook(tmp_path):
    nbformat = pytest.importorskip("nbformat", reason="notebook tests need nbformat (the test extra)")
    pytest.importorskip("nbclient", reason="notebook tests need nbclient (the test extra)")
    pytest.importorskip("ipykernel", reason="notebook tests need ipykernel (the test extra)")
    cells = [
        "import numpy as np, ao4d\n"
        "mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (10,) * 4, (-1.3, 1.3), progress=False)\n"
        "cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], fov=40)\n"
        "result = ao4d.render(mesh, cam, (24, 24, 24), ao='none', light=[0, 1, 0, -1], backend='numpy', progress=False)",
        "result",
        "ao4d.view(mesh)",
    ]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    from nbclient import NotebookClient

    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    return nb


def test_notebook_shows_the_image_and_the_meshes_inline(tmp_path):
    nb = _notebook(tmp_path)
    outputs = [cell.outputs for cell in nb.cells]
    assert not any(o.get("output_type") == "error" for out in outputs for o in out)
    shown = []
    for out in outputs[1:]:
        (result,) = [o for o in out if o.get("output_type") == "execute_result"]
        markup = result["data"]["text/html"]
        assert markup.startswith('<iframe class="ao4d-view" srcdoc="')
        shown.append(_srcdoc(markup))
    assert 'content="ao4d view (image)"' in shown[0] and 'content="ao4d view"' in shown[1]
    assert iv.page_info(shown[0])["shape"] == [24, 24, 24]
    # what an HTML export of the notebook holds: the outputs' HTML in one document
    body = "\n".join(
        o["data"]["text/html"] for out in outputs[1:] for o in out if o.get("output_type") == "execute_result"
    )
    (tmp_path / "export.html").write_text(f"<!DOCTYPE html><html><body>{body}</body></html>")
    if find_chromium() is None:
        pytest.skip("Chromium is not installed: the exported notebook was not loaded")
    with Chromium(width=900, height=1300) as browser:
        browser.goto((tmp_path / "export.html").as_uri())
        ready = (
            "Array.from(document.querySelectorAll('iframe')).every((f) => f.contentWindow.ao4d"
            " && (f.contentWindow.ao4d.ready || f.contentWindow.ao4d.error))"
        )
        browser.wait_for(ready, timeout=60)
        for k in range(2):
            api = f"document.querySelectorAll('iframe')[{k}].contentWindow.ao4d"
            assert browser.evaluate(f"{api}.error") is None
            alpha = capture(browser, api)[..., 3]
            assert (alpha > 0).mean() > 0.02  # the canvas draws
        assert browser.errors == []


# --------------------------------------------------------------------------- the result page


@pytest.fixture(scope="module")
def browser():
    yield from browser_or_skip(1000, 460)


def test_browser_demo_page_both_views_and_its_fragment(browser, demo_dir):
    url = (demo_dir / "view.html").as_uri()
    browser.errors.clear()
    browser.goto(url + "#tab=image&s.w=0.2&s.hide=1&i.array=occlusion&i.az=45")
    browser.wait_for("window.ao4d && (window.ao4d.ready || window.ao4d.error)", timeout=60)
    assert browser.evaluate("window.ao4d.error") is None
    browser.wait_for("window.ao4d.views().image.state().az === 45", timeout=10)
    s = browser.evaluate("window.ao4d.views().slices.state()")
    assert s["w"] == pytest.approx(0.2) and s["hide"] == [1]
    assert browser.evaluate("window.ao4d.views().image.state().array") == "occlusion"
    # the projection view agrees with the numpy ray-march of the demo's image file
    state = browser.evaluate("window.ao4d.views().image.state()")
    page = capture(browser, "window.ao4d.views().image") / 255
    ref = iv.reference_march(demo_dir / "image.vti", state, page.shape[1], page.shape[0])
    a, b = page[..., 3] > 0.5, ref[..., 3] > 0.5
    assert b.sum() > 1000
    iou = (a & b).sum() / (a | b).sum()
    error = np.median(np.abs(page[a & b, :3] - ref[a & b, :3]).max(axis=1))
    assert iou >= 0.95 and error <= 0.02, (iou, error)
    # tabs and the outer fragment: the layout and both views' states
    browser.evaluate("document.getElementById('tab-both').click()")
    browser.evaluate("window.ao4d.views().image.setState({el: -30})")
    fragment = browser.wait_for("location.hash.includes('i.el=-30') && location.hash", timeout=5)
    assert fragment.startswith("#tab=both&") and "s.w=0.2" in fragment and "i.array=occlusion" in fragment
    browser.goto("about:blank")
    browser.goto(url + fragment)
    browser.wait_for("window.ao4d && window.ao4d.ready", timeout=60)
    browser.wait_for("window.ao4d.views().image.state().el === -30", timeout=10)
    assert browser.evaluate("window.ao4d.tab()") == "both"
    assert browser.evaluate("window.ao4d.views().slices.state().w") == pytest.approx(0.2)
    assert browser.errors == []


def test_view_and_result_page_take_a_trimesh_and_pairs(sphere, image, tmp_path):
    import trimesh

    tri = trimesh.creation.icosphere(subdivisions=1)
    mesh3 = ao4d.SimplexMesh.from_trimesh(tri)
    want3 = ao4d.view(mesh3, tmp_path / "m3.html").read_bytes()
    assert ao4d.view(tri, tmp_path / "t.html").read_bytes() == want3
    assert pages.inline((np.asarray(tri.vertices), np.asarray(tri.faces))).html == pages.inline(mesh3).html
    pair = (sphere.vertices, sphere.simplices)
    assert ao4d.view(pair).html == ao4d.view(ao4d.SimplexMesh(*pair)).html
    want = pages.result_page([ao4d.SimplexMesh(*pair)], image, tmp_path / "r.html").read_bytes()
    assert pages.result_page([pair], image, tmp_path / "rp.html").read_bytes() == want
    with pytest.raises(
        TypeError, match=r"`meshes` must be a SimplexMesh, a trimesh.Trimesh, a \(vertices, simplices\)"
    ):
        pages.result_page(3, image, tmp_path / "bad.html")
    with pytest.raises(TypeError, match=r"`meshes` must be a SimplexMesh, a trimesh.Trimesh.*; got dict"):
        ao4d.view([{"vertices": 1}], tmp_path / "bad.html")
    assert not (tmp_path / "bad.html").exists()
