"""Tests for the package as a whole (ao4d/__init__.py): lazy exports and the shape of the house.

No module imports another in a cycle (function-level imports included: a lazy import only hides
a cycle), no module is also a function, no module shares a name with the standard library or a
well-known library, and every public module imports first in a fresh interpreter.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import types
from pathlib import Path

import pytest

import ao4d

PACKAGE = Path(ao4d.__file__).parent
MODULES = sorted(
    ".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts)
    for p in PACKAGE.rglob("*.py")
    if p.name != "__main__.py"
)
PUBLIC = [m for m in MODULES if not any(part.startswith("_") for part in m.split("."))]
# names a reader would take for something else: the standard library, and libraries ao4d's users
# know (meshio, io, render engines...)
_WELL_KNOWN = set(sys.stdlib_module_names) | {
    "meshio",
    "trimesh",
    "pyvista",
    "vtk",
    "numpy",
    "scipy",
    "dask",
    "distributed",
    "zarr",
    "h5py",
    "nibabel",
    "open3d",
    "embree",
    "skimage",
    "matplotlib",
    "tqdm",
    "pyopencl",
}


def _module_file(name: str) -> Path:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _imports(name: str) -> set[str]:
    """ao4d modules that ``name`` imports anywhere in its source (top level or in functions)."""
    tree = ast.parse(_module_file(name).read_text())
    package = name if _module_file(name).name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("ao4d")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("ao4d"):
                continue
            for alias in node.names:  # `from . import mesh` names a module; `from .mesh import X` not
                sub = f"{target}.{alias.name}"
                found.add(sub if sub in MODULES else target)
    return {m for m in found if m in MODULES and m != name}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_import_cycles():
    # the package __init__ maps names lazily; it imports nothing but ao4d.opencl.tbb at import time
    graph = {m: _imports(m) for m in MODULES if m != "ao4d"}
    for deps in graph.values():
        deps.discard("ao4d")
    assert _cycle(graph) is None, f"import cycle: {' -> '.join(_cycle(graph))}"


def test_cycle_finder_finds_cycles():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_module_imports_first_in_a_fresh_interpreter(name):
    # each module first, so that no import order hides a missing or circular import
    code = f"import {name}, sys; assert 'pyopencl' not in sys.modules or {name!r}.startswith('ao4d.opencl.cl')"
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


def test_import_ao4d_is_cheap_and_touches_no_device():
    code = "import ao4d, sys; assert 'pyopencl' not in sys.modules; assert 'numpy' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_no_module_shadows_a_well_known_name():
    leaves = {m.rpartition(".")[2] for m in MODULES} - {"__init__"}
    assert not leaves & _WELL_KNOWN, sorted(leaves & _WELL_KNOWN)


def test_no_callable_modules():
    import importlib

    for name in PUBLIC:
        module = importlib.import_module(name)
        assert type(module) is types.ModuleType, f"{name} is a {type(module).__name__}"


def test_render_is_the_function_whatever_the_import_order():
    # issue 10: after `import ao4d.render`, ao4d.render was a module masquerading as the function
    code = (
        "import inspect, ao4d.rendering as m, ao4d\n"
        "assert ao4d.render is m.render and callable(ao4d.render)\n"
        "assert 'camera' in inspect.signature(ao4d.render).parameters\n"
        "assert m.RenderResult is ao4d.RenderResult\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_lazy_exports_resolve():
    for name in ao4d.__all__:
        assert getattr(ao4d, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        ao4d.nope  # noqa: B018


def test_all_and_dir_list_functions_and_classes_and_modules_stay_attributes():
    # issue 32: `ao` beside `ambient_occlusion`, `sampling` beside `sample` in one list confused
    code = (
        "import ao4d, inspect, types\n"
        "assert ao4d.__all__ == sorted(ao4d.__all__) and ao4d.__all__\n"
        "for name in ao4d.__all__:\n"
        "    value = getattr(ao4d, name)\n"
        "    assert inspect.isfunction(value) or inspect.isclass(value), name\n"
        "assert sorted(dir(ao4d)) == sorted(ao4d.__all__ + ['__version__'])\n"
        "ns = {}\n"
        "exec('from ao4d import *', ns)\n"
        "assert sorted(k for k in ns if k != '__builtins__') == ao4d.__all__\n"
        "for name in ('fields', 'lut', 'mesh', 'ao', 'sampling', 'viewer', 'bvh', 'rendering'):\n"
        "    assert type(getattr(ao4d, name)) is types.ModuleType, name\n"
        "    assert name not in ao4d.__all__\n"
        "assert sorted(dir(ao4d)) == sorted(ao4d.__all__ + ['__version__'])  # loaded modules too\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_every_public_top_level_module_is_reachable_as_an_attribute():
    # not attributes: the command line, and the marching engines behind ao4d.marching.march
    top = {m.split(".")[1] for m in PUBLIC if m.count(".") >= 1} - {"cli", "commands", "cells", "cells_device"}
    assert top <= set(ao4d._MODULES), sorted(top - set(ao4d._MODULES))
    assert not set(ao4d._MODULES) & set(ao4d.__all__)


def test_long_files_say_why():
    # a file over about 700 lines states at its top why it stays one module
    for path in list(PACKAGE.rglob("*.py")):
        text = path.read_text()
        if text.count("\n") > 720:
            head = "\n".join(text.splitlines()[:40]).lower()
            assert "one module" in head or "why this file is long" in head, path.name


# -- the project's files: licence, citation, changelog, version, typing marker ----------------

ROOT = PACKAGE.parent


def _pyproject() -> dict:
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_version_is_written_once_and_shown_by_the_command_line():
    project = _pyproject()
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["hatch"]["version"]["path"] == "ao4d/__init__.py"
    out = subprocess.run(
        [sys.executable, "-m", "ao4d", "--version"], capture_output=True, text=True, check=True, timeout=120, cwd=ROOT
    ).stdout
    assert out.strip() == f"ao4d {ao4d.__version__}"


def test_extras_for_tests_docs_and_lint():
    extras = _pyproject()["project"]["optional-dependencies"]
    assert {"test", "docs", "lint"} <= set(extras)
    assert any(req.startswith("sphinx") for req in extras["docs"])
    assert any(req.startswith("ruff") for req in extras["lint"])
    rules = set(_pyproject()["tool"]["ruff"]["lint"]["select"])
    assert {"F", "E", "W", "I", "NPY", "B"} <= rules


def test_py_typed_ships_with_the_package():
    assert (PACKAGE / "py.typed").is_file()


def test_license_is_the_bsd_3_clause_text():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License")
    assert "the ao4d developers" in text
    assert "Neither the name of the copyright holder nor the names of its" in text


def test_citation_cff_has_the_required_keys_and_references():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors"):
        assert cff[key], key
    assert str(cff["version"]) == ao4d.__version__
    titles = {ref["title"]: ref for ref in cff["references"]}
    paper = titles["Isosurfacing in higher dimensions"]
    assert paper["year"] == 2000 and [a["family-names"] for a in paper["authors"]] == [
        "Bhaniramka",
        "Wenger",
        "Crawfis",
    ]
    thesis = titles["Ambient Occlusion in 4D"]
    assert thesis["type"] == "thesis" and thesis["year"] == 2021
    assert "Heidelberg" in thesis["institution"]["name"]
    for ref in cff["references"]:
        assert ref["authors"] and ref["type"] and ref["title"]


def test_changelog_starts_with_this_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "Keep a Changelog" in text
    releases = [line for line in text.splitlines() if line.startswith("## [") and "Unreleased" not in line]
    assert releases[0].startswith(f"## [{ao4d.__version__}]")
