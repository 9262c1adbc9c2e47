"""Tests for the extras (ao4d/_optional.py): the core works without them, and a feature that needs
one says which (``pip install "ao4d[io]"``).

The light install is imitated in a subprocess whose import system refuses the optional packages;
CI also installs the bare wheel in a fresh venv and runs ``ao4d demo`` there (``.ci/run``).
"""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ao4d import _optional

ROOT = Path(__file__).resolve().parents[1]
# every optional package: what the extras install (and the packages they bring)
BLOCKED = (
    "dask",
    "distributed",
    "nibabel",
    "zarr",
    "h5py",
    "pyvista",
    "vtk",
    "vtkmodules",
    "igl",
    "threadpoolctl",
    "embreex",
    "pyarrow",
)
# the import name of each extra's distribution, where they differ
DISTRIBUTIONS = {"igl": "libigl"}


def _pyproject() -> dict:
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _names(requirements: list[str]) -> set[str]:
    return {re.match(r"[A-Za-z0-9_.-]+", r).group(0).lower() for r in requirements}


def test_core_works_without_the_extras_and_features_name_theirs(tmp_path):
    code = textwrap.dedent(
        f"""
        import importlib.abc, sys

        BLOCKED = {BLOCKED!r}

        class Refuse(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.partition(".")[0] in BLOCKED:
                    raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
                return None

        sys.meta_path.insert(0, Refuse())
        import math
        import numpy as np
        import ao4d

        mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (10,) * 4, (-1.3, 1.3))
        assert mesh.check().closed
        occ = ao4d.ambient_occlusion(mesh, samples=8, backend="numpy")
        assert occ.shape == (len(mesh.vertices),) and np.isfinite(occ).all()
        cam = ao4d.Camera4D(eye=(0, 0, 0, -4), target=(0, 0, 0, 0), up=(0, 1, 0, 0), over=(0, 0, 1, 0))
        img = ao4d.render(mesh, cam, (6, 6, 6), ao="none", backend="numpy")
        assert img.hit.any()
        mesh.save(r"{tmp_path / "mesh.npz"}")
        open(r"{tmp_path / "scan.nii"}", "wb").write(bytes(400))

        def refused(call, extra):
            try:
                call()
            except ImportError as exc:
                assert f'pip install "ao4d[{{extra}}]"' in str(exc), exc
                print("refused:", exc)
            else:
                raise AssertionError(f"{{call}} ran without ao4d[{{extra}}]")

        refused(lambda: ao4d.read_grid(r"{tmp_path / "scan.nii"}"), "io")
        refused(lambda: ao4d.extract_field(ao4d.fields.hypersphere(1.0), 8, (-1.3, 1.3), blocks=4), "dask")
        refused(lambda: ao4d.marching.blockwise.field_array(ao4d.fields.hypersphere(1.0), 8, (-1.3, 1.3)), "dask")
        refused(lambda: ao4d.worker_environment().__enter__(), "dask")
        refused(lambda: mesh.save(r"{tmp_path / "mesh.vtu"}"), "vtk")
        import trimesh

        torus = trimesh.creation.torus(1.0, 0.3)
        refused(lambda: ao4d.lift.tetrahedralize(torus, method="tetwild"), "vtk")  # pytetwild imports pyvista
        from datasets_gen import sequence

        refused(lambda: sequence.triangles_distance(np.eye(3), np.array([[0, 1, 2]]), np.zeros((1, 3))), "datasets")
        loaded = sorted({{m.partition(".")[0] for m in sys.modules}} & set(BLOCKED))
        assert not loaded, loaded
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.count("refused:") == 7
    assert 'reading NIfTI needs nibabel: pip install "ao4d[io]"' in out.stdout


def test_require_names_the_extra_and_the_feature():
    assert _optional.require("json", "anything") is sys.modules["json"]
    _optional.EXTRAS.setdefault("ao4d_no_such_package", "io")
    try:
        with pytest.raises(
            ModuleNotFoundError, match=r'^reading X needs ao4d_no_such_package: pip install "ao4d\[io\]"$'
        ):
            _optional.require("ao4d_no_such_package.sub", "reading X")
        with pytest.raises(ModuleNotFoundError, match=r'pip install "ao4d\[dask\]"'):
            _optional.require("ao4d_no_such_package", "blocks", extra="dask")
    finally:
        del _optional.EXTRAS["ao4d_no_such_package"]


def test_extras_install_what_require_names_and_the_core_holds_none():
    project = _pyproject()
    extras = project["optional-dependencies"]
    core = _names(project["dependencies"])
    everything = _names(extras["all"][0].partition("[")[2].rstrip("]").split(","))
    assert everything <= set(extras), everything - set(extras)
    for module, extra in _optional.EXTRAS.items():
        dist = DISTRIBUTIONS.get(module, module)
        assert extra in everything, extra
        assert dist in _names(extras[extra]) or (module == "vtk" and "pyvista" in _names(extras[extra])), module
        assert dist not in core, f"{dist} is in the core"
    # the design's core, matplotlib for the demo's pictures, tomli (tomllib) on Python 3.10
    design = {"numpy", "scipy", "scikit-image", "pyopencl", "trimesh", "pytetwild", "tqdm", "matplotlib"}
    assert design <= core and not core - design - {"intel-opencl-rt", "intel-cmplr-lib-rt", "tomli"}, core
    # the README's install command (".[test]") and the docs install everything
    for name in ("test", "docs"):
        assert "ao4d[all]" in extras[name], name
