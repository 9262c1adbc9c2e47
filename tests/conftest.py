"""Shared fixtures. OpenCL tests skip (saying why) only when no OpenCL device exists."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import pytest
from hypothesis import settings

# helper modules and scripts (tests/_*.py) are imported by tests, never collected: --doctest-modules
# would otherwise import scripts such as _oclgrind_check.py, which set up OpenCL on import
collect_ignore_glob = ["_*.py"]

# sample data (ao4d.data) and the device's timings (ao4d._calibration) go to a folder of this
# session, removed at its end, never into the user's cache; set before any test or doctest runs
if not os.environ.get("AO4D_DATA_DIR"):
    os.environ["AO4D_DATA_DIR"] = tempfile.mkdtemp(prefix="ao4d-test-data-")
    atexit.register(shutil.rmtree, os.environ["AO4D_DATA_DIR"], True)

# CI replays the same examples on every run (reproducible verdicts); local runs keep exploring.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(autouse=True)
def _progress_switch():
    """Every test starts with progress on: a command run with --no-progress (``main([...])``)
    switches it off for the whole process, and a later test of the progress lines saw none."""
    from ao4d import _progress

    _progress.set_enabled(True)
    yield
    _progress.set_enabled(True)


@pytest.fixture(params=["numpy", "opencl"])
def backend(request):
    """Both ray-casting backends; the OpenCL case skips (saying why) without a device."""
    if request.param == "opencl":
        request.getfixturevalue("cl_runtime")
    return request.param


@pytest.fixture(params=["host", "device"])
def build_bvh(request):
    """Both BVH builders as ``build_bvh(vertices, simplices, leaf_size=16)``: numpy on the host
    and the OpenCL kernels (ao4d.bvh.device; skips, saying why, without a device)."""
    from ao4d import bvh
    from ao4d.bvh import device

    if request.param == "host":
        return bvh.build
    runtime = request.getfixturevalue("cl_runtime")

    def build(vertices, simplices, *, leaf_size=16):
        return device.build(vertices, simplices, leaf_size=leaf_size, runtime=runtime)

    return build


@pytest.fixture(scope="module")
def touching_pair():
    """Two hyperspheres close together: they occlude each other near the gap; each alone is
    convex and unoccluded, so A is 0 on the far sides and positive near the gap."""
    import ao4d

    bounds = ([-2.2, -1.1, -1.1, -1.1], [2.2, 1.1, 1.1, 1.1])
    field = ao4d.fields.union(
        ao4d.fields.hypersphere(1.0, [-1.05, 0, 0, 0]), ao4d.fields.hypersphere(1.0, [1.05, 0, 0, 0])
    )
    return ao4d.extract_field(field, (24, 12, 12, 12), bounds)


@pytest.fixture(scope="module")
def ball4():
    """A convex polytope inscribed in the unit 4-ball (qhull), outward oriented."""
    from _shapes import ball_polytope

    return ball_polytope(4, 8)


@pytest.fixture(scope="session")
def tiny_config(tmp_path_factory):
    """The TOML file of the suite's tiny dataset configuration (tests/_datasets.py: TINY)."""
    from _datasets import TINY, write_config

    return write_config(tmp_path_factory.mktemp("cfg"), TINY, "tiny.toml")


@pytest.fixture(scope="session")
def tiny_reference(tiny_config, tmp_path_factory):
    """One clean single-process run of the tiny configuration: the bytes that every other
    way of making it (processes, dask, URLs, resumed runs) must reproduce."""
    from _datasets import TINY_ITEMS

    from datasets_gen import run

    out = tmp_path_factory.mktemp("ref") / "run"
    summary = run(tiny_config, out, progress=False)
    assert summary.made == TINY_ITEMS and not summary.failed, summary
    return out


@pytest.fixture(scope="session")
def cl_runtime():
    """The OpenCL runtime ao4d chooses; skips the test when this machine has none."""
    from ao4d.opencl import cl

    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        pytest.skip("no working OpenCL device on this machine (see `ao4d info`)")
    return runtime


def pytest_report_header(config):
    from ao4d.opencl import cl

    runtime = cl.get_runtime(warn=False)
    return f"ao4d OpenCL device: {runtime.name if runtime else 'none (numpy backend only)'}"
