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
        "import inspect, ao4d.rendering.pipeline as m, ao4d\n"
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
        "for name in ('fields', 'marching', 'mesh', 'ao', 'sampling', 'browser', 'bvh', 'rendering'):\n"
        "    assert type(getattr(ao4d, name)) is types.ModuleType, name\n"
        "    assert name not in ao4d.__all__\n"
        "assert sorted(dir(ao4d)) == sorted(ao4d.__all__ + ['__version__'])  # loaded modules too\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_every_public_top_level_module_is_reachable_as_an_attribute():
    # not attributes: the command line (modules and subpackages alike are top-level here)
    top = {m.split(".")[1] for m in PUBLIC if m.count(".") >= 1} - {"cli", "commands"}
    assert top <= set(ao4d._MODULES), sorted(top - set(ao4d._MODULES))
    assert not set(ao4d._MODULES) & set(ao4d.__all__)


# -- subpackages: their faces; the modules that moved into them keep no old paths ----------------

SUBPACKAGES = sorted(m.removesuffix(".__init__") for m in MODULES if m.count(".") == 2 and m.endswith(".__init__"))


def test_subpackages_are_the_issues_and_named_for_no_exported_function():
    assert {
        "ao4d.marching",
        "ao4d.browser",
        "ao4d.opencl",
        "ao4d.bvh",
        "ao4d.rays",
        "ao4d.rendering",
        "ao4d.io",
    } <= set(SUBPACKAGES)
    # (the command modules are named for their commands: `ao4d render` runs ao4d.render)
    leaves = {m.removesuffix(".__init__").rpartition(".")[2] for m in MODULES if not m.startswith("ao4d.commands.")}
    assert not leaves & set(ao4d.__all__), sorted(leaves & set(ao4d.__all__))


def test_module_leaf_names_are_unique():
    # a module's test file is tests/test_<last part>.py: the last part must name one module
    # (the commands, named for theirs, are tested in test_cli.py)
    leaves = [m.rpartition(".")[2] for m in MODULES if not m.endswith("__init__") and ".commands." not in m]
    assert len(leaves) == len(set(leaves)), sorted({x for x in leaves if leaves.count(x) > 1})


# modules tested in another module's file (where the file names the home of the tests)
_TESTED_ELSEWHERE = {
    "ao4d.scenes": "test_demo.py",  # the demo scene, through `ao4d demo`
    "ao4d.bvh.blocks": "test_bvh.py",
    "ao4d.bvh.cache": "test_bvh.py",
    "ao4d.bvh.host": "test_bvh.py",
    "ao4d.bvh.layout": "test_bvh.py",
    "ao4d.bvh.device": "test_bvh_device.py",
    "ao4d.bvh.collapse": "test_bvh_collapse.py",
    "ao4d.opencl.binaries": "test_cl.py",  # kernel binaries reused across processes, unwritable caches
    "ao4d.opencl.tbb": "test_cl.py",  # the foreign TBB, Open3D in either order
    "ao4d.io.sources": "test_readers.py",
    "ao4d.io.nifti": "test_readers.py",
    "ao4d.io.hdf5": "test_readers.py",
    "ao4d.io.zarr_files": "test_readers.py",
    "ao4d.io.metaimage": "test_readers.py",
    "ao4d.io.vti": "test_readers.py",
    "ao4d.io.frames": "test_readers.py",
    "ao4d.io.grids": "test_readers.py",
    "ao4d.rendering.pipeline": "test_rendering.py",
    "ao4d.rays.api": "test_rays.py",
    "ao4d.rays.launches": "test_rays.py",
    "ao4d.rays.reference": "test_rays.py",
    "ao4d.rays.refine": "test_rays.py",
    "ao4d.rays.rows": "test_rays.py",
}


def test_every_public_module_has_its_test_file():
    tests = ROOT / "tests"
    missing = []
    for name in PUBLIC:
        if name.startswith("ao4d.commands."):  # one file: test_cli.py
            expected = "test_cli.py"
        else:
            expected = _TESTED_ELSEWHERE.get(name, f"test_{name.rpartition('.')[2]}.py")
        if not (tests / expected).is_file():
            missing.append(f"{name}: tests/{expected}")
    assert not missing, missing


@pytest.mark.parametrize("package", [p for p in SUBPACKAGES if p != "ao4d.commands"])
def test_subpackage_face_is_its_all_and_imports_lazily(package):
    # `import ao4d.<package>` is as cheap as `import ao4d`; its names are its __all__, each the
    # object its module defines; `from ao4d.<package> import *` gives exactly those
    code = (
        f"import sys, importlib, ao4d, {package} as p\n"
        "lazy = 'numpy' not in sys.modules and 'pyopencl' not in sys.modules\n"
        f"assert lazy or {package!r} == 'ao4d.bvh', sorted(m for m in sys.modules if m.startswith('ao4d'))\n"
        "public = [n for n in dir(p) if not n.startswith('_')]\n"
        "assert p.__all__ and public == sorted(p.__all__) or p.__name__ == 'ao4d.bvh', public\n"
        "for name in p.__all__:\n"
        "    value = getattr(p, name)\n"
        "    home = importlib.import_module(getattr(value, '__module__', None) or p.__name__)\n"
        "    assert home.__name__.startswith(p.__name__ + '.') or home is p, (name, home)\n"
        "    assert getattr(home, getattr(value, '__name__', name), value) is value, name\n"
        "ns = {}\n"
        f"exec('from {package} import *', ns)\n"
        "assert sorted(k for k in ns if k != '__builtins__') == sorted(p.__all__)\n"
    )
    subprocess.run([sys.executable, "-W", "error", "-c", code], check=True, timeout=120)


def test_moved_modules_keep_no_alias_at_their_old_paths():
    # the package has no released users: a module that moved lives at its new path only
    code = (
        "import ao4d, importlib, sys\n"
        "for old in ('lut', 'cl', 'march', 'viewer', 'pages', 'cells'):\n"
        "    try:\n"
        "        importlib.import_module('ao4d.' + old)\n"
        "    except ModuleNotFoundError:\n"
        "        pass\n"
        "    else:\n"
        "        raise AssertionError('ao4d.' + old + ' imported')\n"
        "    assert not hasattr(ao4d, old), old\n"
        "assert not any(type(f).__module__.startswith('ao4d') for f in sys.meta_path)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_python_m_on_a_module_path():
    # `python -m ao4d.lut` once failed inside the alias finder ("'_MovedModule' object has no
    # attribute 'get_code'"); now the old path is Python's plain "No module named", and the
    # tables' real module runs the `ao4d lut` command
    old = subprocess.run([sys.executable, "-m", "ao4d.lut", "--help"], capture_output=True, text=True, timeout=120)
    assert old.returncode == 1 and "No module named ao4d.lut" in old.stderr and "Traceback" not in old.stderr
    new = subprocess.run(
        [sys.executable, "-m", "ao4d.marching.lut", "--help"], capture_output=True, text=True, timeout=120
    )
    assert new.returncode == 0 and "verify" in new.stdout, new.stderr


# -- imports: nothing upward, private names inside their subpackage ------------------------------


def _is_module(name: str) -> bool:
    return name in MODULES or f"{name}.__init__" in MODULES


def _import_targets(name: str):
    """(target module, imported name, line) for every ``from X import n`` in ``name``'s source."""
    package = _subpackage(name)
    for node in ast.walk(ast.parse(_module_file(name).read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                target = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "ao4d" or target.startswith("ao4d."):
                for alias in node.names:
                    yield target, alias.name, node.lineno
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("ao4d."):
                    head, _, leaf = alias.name.rpartition(".")
                    yield head, leaf, node.lineno


def _subpackage(module: str) -> str:
    """The package a module belongs to: ``ao4d.marching`` for ``ao4d.marching.lut`` and for
    ``ao4d.marching.__init__``, ``ao4d`` for the top-level modules."""
    return module.removesuffix(".__init__") if module.endswith(".__init__") else module.rpartition(".")[0]


def test_nothing_imports_upward():
    # a module takes names from the modules that define them, never from a package above it
    # (whose face re-exports them lazily): the version is the one name the package itself defines
    upward = []
    for name in MODULES:
        for target, imported, line in _import_targets(name):
            if _is_module(f"{target}.{imported}") or imported == "__version__":
                continue
            if f"{target}.__init__" in MODULES and name.startswith(target + "."):
                upward.append(f"{name}:{line} from {target} import {imported}")
    assert not upward, upward


def test_underscore_names_cross_module_borders_only_within_a_subpackage():
    # a private module of a subpackage serves that subpackage; a private name of a module serves
    # its subpackage (the top-level modules, each its own: ao4d's shared private helpers
    # _validate, _atomic, ... are modules, imported whole or for their public names)
    crossing = []
    for name in MODULES:
        for target, imported, line in _import_targets(name):
            full = f"{target}.{imported}"
            if _is_module(full):  # a module
                private = imported.startswith("_")
                home = target  # the package that holds the module
                ok = not private or home == "ao4d" or name.startswith(home + ".")
            elif imported.startswith("_") and not imported.startswith("__"):  # a name in a module
                home = _subpackage(target)
                ok = target == name or (home != "ao4d" and name.startswith(home + "."))
            else:
                continue
            if not ok:
                crossing.append(f"{name}:{line} takes {imported} from {target}")
    assert not crossing, crossing


def test_the_import_rules_find_what_they_forbid(tmp_path, monkeypatch):
    # the two rules above on a tiny package of their own kind
    global PACKAGE, MODULES
    root = tmp_path / "ao4d"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "top.py").write_text("from .sub.a import _hidden\nfrom .sub import _priv\n")
    (root / "sub" / "__init__.py").write_text("")
    (root / "sub" / "a.py").write_text("from . import b\nfrom .b import _ok\nfrom .. import thing\n")
    (root / "sub" / "b.py").write_text("_ok = 1\n")
    (root / "sub" / "_priv.py").write_text("")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", root)
    monkeypatch.setattr(
        sys.modules[__name__],
        "MODULES",
        ["ao4d.__init__", "ao4d.top", "ao4d.sub.__init__", "ao4d.sub.a", "ao4d.sub.b", "ao4d.sub._priv"],
    )
    with pytest.raises(AssertionError, match=r"ao4d\.sub\.a:3 from ao4d import thing"):
        test_nothing_imports_upward()
    with pytest.raises(AssertionError) as info:
        test_underscore_names_cross_module_borders_only_within_a_subpackage()
    assert "ao4d.top:1 takes _hidden from ao4d.sub.a" in str(info.value)
    assert "ao4d.top:2 takes _priv from ao4d.sub" in str(info.value)
    assert "ao4d.sub.a" not in str(info.value).replace("from ao4d.sub.a", "")


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
