"""The browser: self-contained WebGL2 pages of 4D meshes and rendered images, files or served.

:mod:`ao4d.browser.viewer` writes the slicing page (``viewer_page.html``) and serves pages;
:mod:`ao4d.browser.image_viewer` the projection page of a rendered 3D image
(``image_page.html``); :mod:`ao4d.browser.pages` chooses between them (:func:`view`), shows them
inline in Jupyter and writes both views of a scene in one file (:func:`result_page`). Every page
inlines one shared script (``page_common.js``) into one shared frame (``page_frame.html``). The
names below load on first use: importing this package imports no numpy.
"""

from __future__ import annotations

from .._lazy import lazy_face

__all__ = ["result_page", "view"]

__getattr__, __dir__ = lazy_face(__name__, {name: f"pages:{name}" for name in __all__})
