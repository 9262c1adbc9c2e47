"""What the writers of ao4d's pages share: :mod:`ao4d.browser.viewer`, :mod:`ao4d.browser.image_viewer` and
:mod:`ao4d.browser.pages`.

Every page holds the one shared script, ``ao4d/browser/page_common.js`` (the fragment, buffers, camera,
shader compiling, frames on demand, orbit and keys, PNG and read-back, the page's life), inlined
once as its own ``<script>`` where its template says ``<!--AO4D_COMMON-->``; the page's own
script then uses its functions (``ao4dPage``). The slicing page and the image page also share
their frame, ``ao4d/browser/page_frame.html`` (the panel, the canvas, their style): each fills in its
head, its panel and its body (:func:`framed`). A page stays one self-contained file that opens
from ``file://``.
Here too: the scene's JSON inside a ``<script>``, the size of base64 text, degrees wrapped as the
pages wrap them, and the page's atomic write.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

from .._atomic import atomic_open, check_output_file

__all__ = [
    "COMMON_MARK",
    "b64_size",
    "check_max_bytes",
    "common_script",
    "framed",
    "scene_json",
    "template",
    "with_common_script",
    "wrap_degrees",
    "write_page",
]

COMMON_MARK = "<!--AO4D_COMMON-->"  # where a template takes the shared script
_COMMON_FILE = "page_common.js"
_DATA_MARK = "<!--AO4D_DATA-->"  # where a page's buffers go, after its scene's JSON
_FRAME_FILE = "page_frame.html"
_SCENE_MARK = "__AO4D_SCENE__"  # where the frame takes the page's scene (JSON)
_SLOTS = ("<!--AO4D_HEAD-->", "<!--AO4D_PANEL-->", "<!--AO4D_BODY-->")  # a page's parts, in order


@functools.cache
def common_script() -> str:
    """The text of the shared script (``ao4d/browser/page_common.js``)."""
    text = resources.files("ao4d.browser").joinpath(_COMMON_FILE).read_text(encoding="utf-8")
    # inlined in a <script> and searched for the templates' marks: it may hold neither
    for bad in ("</script", COMMON_MARK, _DATA_MARK, *_SLOTS, "__AO4D_", "__TITLE__", "__META__"):
        if bad in text:  # pragma: no cover - the shipped script holds none
            raise RuntimeError(f"ao4d/{_COMMON_FILE} holds {bad!r}, which a page cannot inline")
    return text


def with_common_script(text: str) -> str:
    """A template with the shared script in place of its one ``<!--AO4D_COMMON-->``."""
    if text.count(COMMON_MARK) != 1:  # pragma: no cover - the shipped templates have one each
        raise RuntimeError(f"a page template must hold {COMMON_MARK} once, got {text.count(COMMON_MARK)}")
    return text.replace(COMMON_MARK, f"<script>\n{common_script()}</script>")


def framed(name: str) -> str:
    """A shipped page (``ao4d/browser/viewer_page.html``, ``ao4d/browser/image_page.html``) in the shared frame
    (``ao4d/browser/page_frame.html``: the panel, the canvas, the shared style and script): the page's
    three parts, after its lines ``<!--AO4D_HEAD-->``, ``<!--AO4D_PANEL-->`` and
    ``<!--AO4D_BODY-->``, go where the frame has the same lines."""
    files = resources.files("ao4d.browser")
    frame = with_common_script(files.joinpath(_FRAME_FILE).read_text(encoding="utf-8"))
    page = files.joinpath(name).read_text(encoding="utf-8")
    head, sep, rest = page.partition(_SLOTS[0] + "\n")
    if head.strip() or not sep:  # pragma: no cover - the shipped pages start with their head
        raise RuntimeError(f"ao4d/{name} must start with {_SLOTS[0]}")
    parts = []
    for slot in _SLOTS[1:]:
        part, sep, rest = rest.partition(slot + "\n")
        if not sep:  # pragma: no cover - the shipped pages have every part
            raise RuntimeError(f"ao4d/{name} lacks {slot}")
        parts.append(part)
    parts.append(rest)
    for slot, part in zip(_SLOTS, parts):
        if frame.count(slot + "\n") != 1:  # pragma: no cover - the shipped frame has each once
            raise RuntimeError(f"ao4d/{_FRAME_FILE} must hold {slot} once")
        frame = frame.replace(slot + "\n", part)
    return frame


def template(name: str) -> tuple[str, str, str]:
    """A shipped page, framed (:func:`framed`), cut at its scene's JSON and its buffers:
    ``(head, middle, tail)``, the page being ``head + json + middle + buffers + tail``."""
    text = framed(name)
    head, sep, rest = text.partition(_SCENE_MARK)
    middle, sep2, tail = rest.partition(_DATA_MARK)
    if not sep or not sep2:  # pragma: no cover - the shipped templates have both
        raise RuntimeError(f"ao4d/{name} lacks its placeholders")
    return head, middle, tail


def scene_json(scene: dict) -> str:
    """``scene`` as JSON that may stand inside a ``<script>``: no ``</`` in it."""
    return json.dumps(scene, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")


def b64_size(n: int) -> int:
    """Characters of the base64 text of ``n`` bytes."""
    return 4 * ((n + 2) // 3)


def wrap_degrees(angle: float) -> float:
    """Degrees into (-180, 180], as the pages wrap angles."""
    a = (angle + 180.0) % 360.0 - 180.0
    return 180.0 if a == -180.0 else a + 0.0


def check_max_bytes(value: Any) -> int:
    """``max_bytes`` of a page writer: a positive integer."""
    import numpy as np

    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"`max_bytes` must be a positive integer, got {value!r}")
    return int(value)


def write_page(path: str | os.PathLike, text: Callable[[], str]) -> Path:
    """Check ``path`` (.html or .htm) before any work, then write ``text()`` there atomically."""
    target = check_output_file(path, "path", (".html", ".htm"))
    page = text()
    with atomic_open(target, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(page)
    return target
