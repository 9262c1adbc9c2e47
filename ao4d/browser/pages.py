"""Pages for people: a whole result in one file, and any page shown inline in Jupyter.

:func:`view` is ``ao4d.view``: meshes go to the slicing page (:mod:`ao4d.browser.viewer`), a rendered
image (a :class:`~ao4d.rendering.pipeline.RenderResult`, or the ``.vti`` / ``.mhd`` file of ``ao4d render``)
to the ray-marching page (:mod:`ao4d.browser.image_viewer`). With a path it writes the page and returns a
:class:`Page` (a :class:`pathlib.Path`); without one it returns an :class:`InlinePage`. Both
have ``_repr_html_``, so a notebook shows the page in its output: an ``iframe`` whose ``srcdoc``
holds the self-contained page, or, above :data:`INLINE_LIMIT`, an ``iframe`` on the page served
from 127.0.0.1 by this kernel (:class:`ao4d.browser.viewer.ViewServer`).

:func:`result_page` writes one file with both views of a scene: the slices of its meshes and the
projection of its rendered image, as tabs or side by side (``ao4d demo``'s ``view.html``). Each
view is its own page in an ``iframe`` (``srcdoc``), with its own ``window.ao4d``; the outer page's
URL fragment holds the layout and both views' states, ``#tab=image&s.w=0.3&i.az=40``
(``s.`` keys go to the slicing view, ``i.`` keys to the image view).

Examples
--------
>>> import ao4d, numpy as np
>>> shade = np.zeros((6, 6, 6), np.float32); shade[1:5, 1:5, 1:5] = 0.7
>>> page = ao4d.view(shade)
>>> page._repr_html_()[:30]
'<iframe class="ao4d-view" srcd'
"""

from __future__ import annotations

import html
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .._atomic import check_output_file
from ._page import scene_json, with_common_script, write_page

__all__ = ["INLINE_LIMIT", "InlinePage", "Page", "inline", "is_image", "result_page", "view"]

INLINE_LIMIT = 20_000_000  # characters of page inlined in a notebook; above it the page is served
HEIGHT = 560  # pixels of the notebook's iframe
LAYOUTS = ("image", "slices", "both")


def is_image(what: Any) -> bool:
    """True for what :mod:`ao4d.browser.image_viewer` shows: a RenderResult, its ImageData, a .vti/.mhd
    path, or a 3D numpy array of shade values.

    Parameters
    ----------
    what : object
        What :func:`view` was given.

    Returns
    -------
    bool
        Whether the image page shows it (otherwise the meshes' page does).
    """
    import numpy as np

    from .image_viewer import ImageData

    if isinstance(what, (str, os.PathLike)):
        return Path(what).suffix.lower() in (".vti", ".mhd")
    if isinstance(what, ImageData) or (isinstance(what, np.ndarray) and what.ndim == 3):
        return True
    return all(hasattr(what, k) for k in ("rgba8", "geometry", "object_id", "shade"))


def _iframe(page: str, height: int, title: str) -> str:
    return (
        f'<iframe class="ao4d-view" srcdoc="{html.escape(page, quote=True)}" '
        f'title="{html.escape(title, quote=True)}" style="width: 100%; height: {int(height)}px; '
        f'border: 0" allowfullscreen></iframe>'
    )


class InlinePage:
    """A page held in memory; shown inline by Jupyter (``_repr_html_``).

    Attributes
    ----------
    html : str
        The self-contained page.
    height : int
        Height of the notebook's frame in pixels.
    inline_limit : int
        Pages longer than this are served from 127.0.0.1 instead of inlined.
    server : ViewServer or None
        The server, once a page too large to inline has been shown.
    """

    def __init__(self, text: str, *, title: str = "ao4d view", height: int = HEIGHT, inline_limit: int = INLINE_LIMIT):
        if isinstance(height, bool) or not isinstance(height, int) or height < 50:
            raise ValueError(f"`height` must be an integer number of pixels >= 50, got {height!r}")
        if isinstance(inline_limit, bool) or not isinstance(inline_limit, int) or inline_limit < 0:
            raise ValueError(f"`inline_limit` must be an integer >= 0, got {inline_limit!r}")
        self.html, self.title, self.height, self.inline_limit = text, title, height, inline_limit
        self.server = None

    def _repr_html_(self) -> str:
        if len(self.html) <= self.inline_limit:
            return _iframe(self.html, self.height, self.title)
        if self.server is None:
            from .viewer import ViewServer

            self.server = ViewServer(self.html.encode("utf-8"), [], "127.0.0.1", 0)
        return (
            f'<iframe class="ao4d-view" src="{self.server.url}" title="{html.escape(self.title)}" '
            f'style="width: 100%; height: {self.height}px; border: 0"></iframe>'
            f'<div style="font-size: 11px; color: #777">served by this kernel at '
            f"{self.server.url} ({len(self.html) / 1e6:.0f} MB: over the inline limit)</div>"
        )

    def save(self, path: str | os.PathLike) -> Page:
        """Write the page (.html, atomically) and return it as a :class:`Page`.

        Parameters
        ----------
        path : path-like
            The file, ending in .html or .htm.

        Returns
        -------
        Page
            The path written.
        """
        return Page(write_page(path, lambda: self.html))

    def close(self) -> None:
        """Stop the server, if one was started."""
        if self.server is not None:
            self.server.close()
            self.server = None

    def __repr__(self) -> str:
        return f"InlinePage({self.title!r}, {len(self.html) / 1e6:.1f} MB)"


class Page(type(Path())):  # type: ignore[misc]
    """The path of a page written by :func:`view`; a notebook shows the page itself.

    Parameters
    ----------
    *args : str or path-like
        The path's segments, as for :class:`pathlib.Path`.
    **kwargs
        Passed to :class:`pathlib.Path`.
    """

    def _repr_html_(self) -> str:
        return InlinePage(self.read_text(encoding="utf-8"), title=self.name)._repr_html_()


def _page_text(what: Any, options: dict) -> str:
    _check_view_input(what, options)
    if is_image(what):
        from .image_viewer import image_page_text

        return image_page_text(what, **options)
    from .viewer import page_text

    return page_text(what, **options)


def _check_view_input(what: Any, options: dict) -> None:
    """Refuse, naming the parameter, what neither page shows and options neither page takes."""
    import inspect

    import numpy as np

    if isinstance(what, np.ndarray) and what.ndim != 3:
        raise TypeError(
            f"`what` must be a SimplexMesh, a .npz path, a sequence of them, a RenderResult, "
            f"a .vti/.mhd path or a 3D array of shade values; got an array of shape "
            f"{what.shape}: extract a mesh from it first (ao4d.extract(values, level)) or "
            "render one (ao4d.render)"
        )
    if is_image(what):
        from .image_viewer import view_image as target

        kind = "an image's page"
    else:
        from .viewer import view as target

        kind = "the meshes' page"
    known = [name for name, p in inspect.signature(target).parameters.items() if p.kind == p.KEYWORD_ONLY]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise TypeError(
            f"ao4d.view got unknown option(s) {', '.join(map(repr, unknown))} for {kind}; "
            f"it takes {', '.join(known)} (and path, height, inline_limit)"
        )


def inline(what: Any, *, height: int = HEIGHT, inline_limit: int = INLINE_LIMIT, **options: Any) -> InlinePage:
    """The page of ``what`` (meshes or an image, as for :func:`view`) held in memory.

    Parameters
    ----------
    what : mesh, .npz path, a sequence of them, RenderResult, .vti / .mhd path or 3D array
        What to show, as for :func:`view`.
    height : int
        Height of the notebook's frame in pixels (at least 50).
    inline_limit : int
        Pages longer than this are served from 127.0.0.1 instead of inlined.
    **options
        Those of :func:`ao4d.browser.viewer.view` (meshes) or :func:`ao4d.browser.image_viewer.view_image`
        (images).

    Returns
    -------
    InlinePage
        The page; a notebook shows it.

    Raises
    ------
    TypeError
        If ``what`` is neither meshes nor an image, or an option is unknown.
    ValueError
        A bad option value.
    """
    text = _page_text(what, options)
    return InlinePage(text, title=str(options.get("title") or "ao4d view"), height=height, inline_limit=inline_limit)


def view(
    what: Any,
    path: str | os.PathLike | None = None,
    *,
    height: int = HEIGHT,
    inline_limit: int = INLINE_LIMIT,
    **options: Any,
) -> Page | InlinePage:
    """Show 4D meshes or a rendered 3D image in the browser or a notebook.

    Parameters
    ----------
    what : mesh, .npz path, sequence of them, RenderResult, or .vti / .mhd path
        Meshes (each a SimplexMesh, a trimesh.Trimesh, a (vertices, simplices) pair or an .npz
        file) get the slicing page (:func:`ao4d.browser.viewer.view`), an image the ray-marching page
        (:func:`ao4d.browser.image_viewer.view_image`).
    path : path-like, optional
        Where to write the page (.html). Without it nothing is written.
    height : int
        Height of the page's frame in a notebook, in pixels.
    inline_limit : int
        Largest page (characters) a notebook gets inline; a larger one is served from
        127.0.0.1 by the kernel.
    **options
        Keyword options of :func:`ao4d.browser.viewer.view` or :func:`ao4d.browser.image_viewer.view_image`
        (``state``, ``title``, ``names``, ...); an unknown one is a ``TypeError``.

    Returns
    -------
    page : Page or InlinePage
        ``Page`` (a ``pathlib.Path``) when ``path`` is given, else an ``InlinePage``; both show
        the page inline in Jupyter.
    """
    if path is None:
        return inline(what, height=height, inline_limit=inline_limit, **options)
    _check_view_input(what, options)
    if is_image(what):
        from .image_viewer import view_image

        return Page(view_image(what, path, **options))
    from .viewer import view as view_meshes

    return Page(view_meshes(what, path, **options))


_OUTER = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="ao4d result page">
<title>__TITLE__</title>
<link rel="icon" href="data:,">
<!-- ao4d result page (ao4d/browser/pages.py): the slicing view and the projection view of one 4D scene,
     each a self-contained page in an iframe (srcdoc). Self-contained: no network access. -->
<style>
  html, body { margin: 0; height: 100%; background: #1d2027; color: #e6e8ec;
    font: 13px/1.35 system-ui, -apple-system, "Segoe UI", sans-serif; overflow: hidden; }
  #bar { height: 34px; display: flex; align-items: center; gap: 6px; padding: 0 10px;
    background: #161920; border-bottom: 1px solid #0d0f13; }
  #bar b { margin-right: 10px; }
  #bar button { background: #2d3340; color: #e6e8ec; border: 1px solid #4a5262; border-radius: 3px;
    padding: 3px 10px; cursor: pointer; font: inherit; }
  #bar button.on { background: #4e79a7; border-color: #6d95c0; }
  #views { position: absolute; top: 35px; left: 0; right: 0; bottom: 0; }
  iframe { position: absolute; top: 0; bottom: 0; border: 0; height: 100%; }
  .full { left: 0; width: 100%; }
  .left { left: 0; width: 50%; } .right { left: 50%; width: 50%; border-left: 1px solid #0d0f13; }
  .off { visibility: hidden; }
</style>
</head>
<body>
<div id="bar"><b id="title"></b>
  <button id="tab-image" title="the 4D camera's 3D image, ray-marched">projection</button>
  <button id="tab-slices" title="the meshes cut by a hyperplane">slices</button>
  <button id="tab-both" title="both views side by side">side by side</button>
</div>
<div id="views">
  <iframe id="view-slices" title="slices" srcdoc="__SLICES__"></iframe>
  <iframe id="view-image" title="projection" srcdoc="__IMAGE__"></iframe>
</div>
<script type="application/json" id="ao4d-result">__META__</script>
<!--AO4D_COMMON-->
<script>
"use strict";
(function () {
  const { fragmentPairs, hashWriter } = ao4dPage;
  const meta = JSON.parse(document.getElementById("ao4d-result").textContent);
  const LAYOUTS = ["image", "slices", "both"];
  const frames = { slices: document.getElementById("view-slices"), image: document.getElementById("view-image") };
  const prefix = { slices: "s.", image: "i." };
  let layout = meta.tab;
  document.getElementById("title").textContent = meta.title;
  // the fragment: tab=..., then s.KEY=... for the slicing view and i.KEY=... for the image view
  const start = { slices: {}, image: {} };
  for (const [key, value] of fragmentPairs(location.hash)) {
    if (key === "tab") { if (LAYOUTS.includes(value)) layout = value; else console.warn("ao4d: ignoring tab=" + value); }
    else if (key.startsWith("s.")) start.slices[key.slice(2)] = key === "s.hide" ? (value ? value.split(",").map(Number) : []) : value;
    else if (key.startsWith("i.")) start.image[key.slice(2)] = value;
  }
  function place() {
    frames.image.className = layout === "both" ? "left" : layout === "image" ? "full" : "full off";
    frames.slices.className = layout === "both" ? "right" : layout === "slices" ? "full" : "full off";
    for (const l of LAYOUTS) document.getElementById("tab-" + l).classList.toggle("on", l === layout);
  }
  function inner(name) { try { return frames[name].contentWindow.ao4d || null; } catch (e) { return null; } }
  function hashText() {
    const parts = ["tab=" + layout];
    for (const name of ["slices", "image"]) {
      const a = inner(name);
      if (!a || !a.ready) continue;
      for (const part of a.hash().replace(/^#/, "").split("&")) if (part && !part.startsWith("aa=")) parts.push(prefix[name] + part);
    }
    return "#" + parts.join("&");
  }
  const hash = hashWriter(hashText);
  const writeHash = () => hash.write();
  const applied = { slices: false, image: false };
  function poll() {
    for (const name of ["slices", "image"]) {
      const a = inner(name);
      if (a && a.ready && !applied[name]) { applied[name] = true; if (Object.keys(start[name]).length) a.setState(start[name]); }
    }
    if (applied.slices && applied.image) writeHash();  // never a fragment without a view's state
  }
  for (const l of LAYOUTS) document.getElementById("tab-" + l).addEventListener("click", () => { layout = l; place(); writeHash(); });
  place();
  setInterval(poll, 300);
  window.ao4d = {
    kind: "result",
    tab: (name) => { if (name !== undefined) { if (!LAYOUTS.includes(name)) throw new Error("tab must be one of " + LAYOUTS); layout = name; place(); writeHash(); } return layout; },
    views: () => ({ slices: inner("slices"), image: inner("image") }),
    // both views drawn, and the fragment's states applied to them
    get ready() { const s = inner("slices"), i = inner("image"); return !!(s && s.ready && i && i.ready && applied.slices && applied.image); },
    get error() { const s = inner("slices"), i = inner("image"); return (s && s.error) || (i && i.error) || null; },
    hash: () => hashText(),
  };
})();
</script>
</body>
</html>
"""


def result_page(
    meshes: Any,
    image: Any,
    path: str | os.PathLike,
    *,
    names: Any = None,
    title: str = "ao4d result",
    tab: str = "image",
    slice_state: Mapping[str, Any] | None = None,
    image_state: Mapping[str, Any] | None = None,
    max_bytes: int = 150_000_000,
) -> Page:
    """Write one page with both views of a scene: slices of ``meshes``, projection of ``image``.

    Parameters
    ----------
    meshes : SimplexMesh, trimesh.Trimesh, (vertices, simplices), .npz path, or a sequence of them
        As for :func:`ao4d.browser.viewer.view`.
    image : RenderResult, .vti / .mhd path
        The scene's rendered image, as for :func:`ao4d.browser.image_viewer.view_image`.
    path : path-like
        The page (.html; written atomically, checked before any work).
    names : sequence of str, optional
        One label per mesh.
    title : str
        The page's title.
    tab : {"image", "slices", "both"}
        The layout it opens with (the fragment's ``tab=`` overrides it).
    slice_state, image_state : mapping, optional
        Initial states of the two views.
    max_bytes : int
        Largest page written (both views together).

    Returns
    -------
    page : Page
        The path written.

    Raises
    ------
    ValueError
        A bad mesh, image, state or option; a page over ``max_bytes``.
    TypeError
        If ``title`` is not a string.
    """
    from .._validate import check_choice
    from .image_viewer import image_page_text
    from .viewer import page_text

    target = check_output_file(path, "path", (".html", ".htm"))
    check_choice(tab, "tab", LAYOUTS)
    if not isinstance(title, str):
        raise TypeError(f"`title` must be a string, got {type(title).__name__}")
    slices = page_text(meshes, names=names, state=slice_state, title=title, max_bytes=max_bytes)
    picture = image_page_text(image, state=image_state, title=title, max_bytes=max_bytes)
    if len(slices) + len(picture) > max_bytes:
        raise ValueError(
            f"the page would be {(len(slices) + len(picture)) / 1e6:.0f} MB, over "
            f"`max_bytes` = {max_bytes / 1e6:.0f} MB"
        )
    meta = scene_json({"title": title, "tab": tab})
    text = (
        with_common_script(_OUTER)
        .replace("__TITLE__", html.escape(title))
        .replace("__META__", meta)
        .replace('srcdoc="__SLICES__"', f'srcdoc="{html.escape(slices, quote=True)}"', 1)
        .replace('srcdoc="__IMAGE__"', f'srcdoc="{html.escape(picture, quote=True)}"', 1)
    )
    return Page(write_page(target, lambda: text))
