"""OpenCL discovery: the chosen device really builds and runs kernels, and errors are clear."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from ao4d import cl


def test_import_ao4d_does_not_import_pyopencl():
    code = "import ao4d, sys; assert 'pyopencl' not in sys.modules, 'pyopencl imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.skipif(
    not (sys.platform.startswith("linux") and platform.machine() == "x86_64"),
    reason="the Intel CPU runtime from PyPI is a dependency only on x86_64 Linux",
)
def test_a_device_works_on_this_machine():
    # this project's machines have no GPU; the Intel CPU runtime must be found and usable
    reports = cl.device_reports()
    assert any(r.usable for r in reports), reports


def test_tiny_kernel_through_build_kernels(cl_runtime, tmp_path):
    import pyopencl as pcl

    kernels = cl.build_kernels(cl_runtime, "selftest.cl", {"SCALE": 3})
    x = np.arange(1000, dtype=np.float32)
    buf = pcl.Buffer(cl_runtime.context, pcl.mem_flags.READ_WRITE | pcl.mem_flags.COPY_HOST_PTR, hostbuf=x)
    kernels["scale_add"](cl_runtime.queue, x.shape, None, buf, np.float32(0.5))
    out = np.empty_like(x)
    pcl.enqueue_copy(cl_runtime.queue, out, buf)
    np.testing.assert_array_equal(out, 3 * x + 0.5)
    # built once per context and options: the second call returns the same kernel objects
    assert cl.build_kernels(cl_runtime, "selftest.cl", {"SCALE": 3}) is kernels


def test_build_error_shows_compiler_log(cl_runtime):
    with pytest.raises(RuntimeError, match="selftest.cl"):
        cl.build_kernels(cl_runtime, "selftest.cl", {"SCALE": "not_a_number("})


def test_missing_kernel_source(cl_runtime):
    with pytest.raises(FileNotFoundError, match="nope.cl"):
        cl.build_kernels(cl_runtime, "nope.cl")


def test_bad_prefer():
    with pytest.raises(ValueError, match="prefer"):
        cl.get_runtime("tpu")


def test_no_device_falls_back_with_one_warning():
    code = (
        "import warnings, ao4d.cl as c\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        "    assert c.get_runtime() is None\n"
        "    assert c.get_runtime() is None\n"
        "assert len(w) == 1 and issubclass(w[0].category, c.NoOpenCLDeviceWarning), w\n"
    )
    env = dict(os.environ, AO4D_DEVICE="none")
    subprocess.run([sys.executable, "-c", code], check=True, env=env)


def test_info_command_names_the_chosen_device():
    out = subprocess.run(
        [sys.executable, "-m", "ao4d", "info"], check=True, capture_output=True, text=True
    ).stdout
    assert "chosen:" in out

