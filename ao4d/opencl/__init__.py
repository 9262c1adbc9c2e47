"""OpenCL: device discovery and choice, kernel builds and their binary cache, the runtime's TBB.

:mod:`ao4d.opencl.cl` finds, probes, chooses and names the device (``AO4D_DEVICE``) and builds
the kernels of ``kernels/``; :mod:`ao4d.opencl.binaries` keeps compiled programs across
processes; :mod:`ao4d.opencl.tbb` loads the Intel CPU runtime's TBB at ``import ao4d``. The names
below load on first use: importing this package touches no device and imports no pyopencl.
"""

from __future__ import annotations

from .._lazy import lazy_face

__all__ = ["BACKENDS", "DeviceSelectionError", "NoOpenCLDeviceWarning", "describe", "get_runtime", "kernel_cache_dir"]

__getattr__, __dir__ = lazy_face(__name__, {name: f"cl:{name}" for name in __all__})
