"""Shared fixtures. OpenCL tests skip (saying why) only when no OpenCL device exists."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

# CI replays the same examples on every run (reproducible verdicts); local runs keep exploring.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(scope="session")
def cl_runtime():
    """The OpenCL runtime ao4d chooses; skips the test when this machine has none."""
    from ao4d import cl

    runtime = cl.get_runtime(warn=False)
    if runtime is None:
        pytest.skip("no working OpenCL device on this machine (see `ao4d info`)")
    return runtime


def pytest_report_header(config):
    from ao4d import cl

    runtime = cl.get_runtime(warn=False)
    return f"ao4d OpenCL device: {runtime.name if runtime else 'none (numpy backend only)'}"
