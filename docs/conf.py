"""Sphinx configuration for the ao4d documentation site.

Build it from the repository root with ``sphinx-build -W -b html docs docs/_build/html``.
"""

from __future__ import annotations

import os
import sys
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # document this checkout's ao4d and datasets_gen

import ao4d  # noqa: E402

project = "ao4d"
author = "the ao4d developers"
copyright = f"{time.strftime('%Y')}, {author}"
version = release = ao4d.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
# ARCHITECTURE.md and the experiments' figures are read on GitHub and linked from the README
exclude_patterns = [
    "_build",
    "ARCHITECTURE.md",
    "experiments",
    "examples",  # sphinx-gallery's sources: their pages are made in auto_examples/
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
    "auto_examples/*.md5",
    "auto_examples/*.codeobj.json",
    "sg_execution_times.rst",
]

# every cross-reference must resolve (-W turns the warnings into errors)
nitpicky = True
nitpick_ignore_regex = [
    # internal modules (private, or the engines behind a documented module) have no pages;
    # docstrings name them so that a reader of the source can follow
    (r"py:.*", r"ao4d\.(\w+\.)?_.*"),
    (r"py:.*", r"ao4d\.marching\.(cells|cells_device|fields_device)(\..*)?"),
    (r"py:.*", r"ao4d\.opencl\.(binaries|tbb)(\..*)?"),
    (r"py:.*", r"ao4d\.bvh\.(host|device|collapse|layout|blocks|cache)(\..*)?"),
    (r"py:.*", r"_.*"),
    ("py:class", r"numpy\.typing\..*"),
]

# -- autodoc / autosummary / numpydoc ----------------------------------------------------
autosummary_generate = True
autosummary_imported_members = False
autosummary_ignore_module_all = False
autodoc_typehints = "none"  # the numpydoc sections carry the types, with shapes
autodoc_member_order = "bysource"
add_module_names = False

numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_attributes_as_param_list = True
# numpydoc validation of every documented public docstring; the checks left out are house style
# (summaries that run over one line, extended summaries, See Also everywhere, Examples everywhere)
numpydoc_validation_checks = {
    "all",
    "GL01",  # the summary may start on the line of the opening quotes
    "GL02",
    "ES01",  # no extended summary required
    "SA01",  # no See Also required
    "EX01",  # no Examples required
    "SS05",  # summaries may start with any verb form
    "SS06",  # summaries may run over one line
    "RT02",  # the return value is named when there is a name to give
    "PR09",  # parameter descriptions may end without a period (shapes, code)
    "RT05",
    "PR08",
}
# Every documented function, class, method and property of every module on the API pages is
# validated. The one exclusion: module and class constants (autodata). They are values, not
# callables: their one-line ``#:`` comments have no sections to check, and autodoc gives a
# constant without such a comment its value type's docstring (``int``'s, ``tuple``'s), which
# numpydoc would then check as if it were the constant's.
numpydoc_validation_exclude = {
    r"\.[A-Z][A-Z0-9_]+$",
}
# Records (dataclasses, named tuples) document their fields under Attributes, which is also
# their constructor's signature: PR01 would ask for every field twice.
numpydoc_validation_overrides = {"PR01": [r"Attributes\n\s*-{3,}"]}

intersphinx_mapping = {
    "python": ("https://docs.python.org/3", None),
    "numpy": ("https://numpy.org/doc/stable/", None),
    "scipy": ("https://docs.scipy.org/doc/scipy/", None),
    "trimesh": ("https://trimesh.org/", None),
    "pyvista": ("https://docs.pyvista.org/", None),
    "dask": ("https://docs.dask.org/en/stable/", None),
}


def _reachable(url: str) -> bool:
    """Whether ``url``'s ``objects.inv`` answers within a few seconds."""
    try:
        with urllib.request.urlopen(url.rstrip("/") + "/objects.inv", timeout=4) as answer:
            return answer.status == 200
    except (OSError, ValueError):
        return False


# Inventories come from docs/_intersphinx/NAME.inv when present, else from the web. On a machine
# without network (this project's CI) an unreachable inventory is dropped instead of failing the
# -W build, and references into that project are then left as plain text (nitpick_ignore below):
# the same pages, without the outbound links.
_CACHE = Path(__file__).parent / "_intersphinx"
_OFFLINE = os.environ.get("AO4D_DOCS_OFFLINE", "") not in ("", "0")
for _name, (_url, _) in list(intersphinx_mapping.items()):
    _inv = _CACHE / f"{_name}.inv"
    if _inv.exists():
        intersphinx_mapping[_name] = (_url, str(_inv))
    elif _OFFLINE or not _reachable(_url):
        del intersphinx_mapping[_name]
        print(f"ao4d docs: no inventory for {_name} ({_url}): its references stay plain text")
_EXTERNAL = {
    "python": r"(builtins\.)?[A-Za-z]*(Error|Warning|Exception|Interrupt)|int|float|str|bool|bytes"
    r"|dict|list|tuple|set|object|type|callable|None|Path|"
    + r"|".join(rf"{m}\..*" for m in sorted(sys.stdlib_module_names)),
    "numpy": r"(numpy|np)\..*",
    "scipy": r"scipy\..*",
    "trimesh": r"trimesh\..*",
    "pyvista": r"pyvista\..*",
    "dask": r"(dask|distributed)\..*",
}
for _name, _pattern in _EXTERNAL.items():
    if _name not in intersphinx_mapping:
        nitpick_ignore_regex += [
            (_role, _pattern)
            for _role in (
                "py:class",
                "py:exc",
                "py:func",
                "py:meth",
                "py:obj",
                "py:data",
                "py:attr",
                "py:mod",
            )
        ]


def _resolve_short_names(app, env, node, contnode):
    """Resolve ``SimplexMesh.slice``-style references written relative to another module.

    Docstrings name objects as their own module sees them (``SimplexMesh`` in ``ao4d.topology``,
    ``RenderResult.save`` in ``ao4d.browser.image_viewer``); the pages document them under their public
    names (``ao4d.SimplexMesh``). A reference that Sphinx cannot resolve is looked up as the end
    of exactly one documented name, preferring the shortest; an attribute documented only in its
    class's Attributes section resolves to the class.
    """
    if node.get("refdomain") != "py":
        return None
    domain = env.get_domain("py")
    target = node["reftarget"].lstrip(".~")
    scopes = [node.get("py:class"), node.get("py:module")]
    candidates = [target] + [f"{s}.{target}" for s in scopes if s]
    for name in candidates:
        parts = name.split(".")
        for drop in (0, 1):
            wanted = ".".join(parts[: len(parts) - drop]) if drop else name
            if not wanted:
                continue
            found = sorted((n for n in domain.objects if n == wanted or n.endswith("." + wanted)), key=len)
            if found and (len(found) == 1 or len(found[0]) < len(found[1])):
                resolved = domain.resolve_any_xref(env, node["refdoc"], app.builder, found[0], node, contnode)
                if resolved:
                    return resolved[0][1]
    return None


def setup(app):
    app.connect("missing-reference", _resolve_short_names)


# -- sphinx-gallery ---------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("matplotlib",),
    "abort_on_example_error": True,
    "only_warn_on_example_error": False,
    "show_memory": False,
    "plot_gallery": "True",
}

# -- HTML --------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"ao4d {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
}
myst_heading_anchors = 3
