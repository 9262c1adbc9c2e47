"""``ao4d info``: versions, OpenCL platforms and devices, which one ao4d uses, and why."""

from __future__ import annotations

import argparse
import sys

HELP = "show versions, OpenCL platforms/devices, which device ao4d uses and why"
EXAMPLES = """  ao4d info
  AO4D_DEVICE=none ao4d info     # what happens without OpenCL (numpy backend)
  AO4D_DEVICE=intel ao4d info    # choose by platform or device name (cpu, gpu, none also work)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    del parser  # no options


def run(args: argparse.Namespace) -> int:
    """Print the report; exit status 2 when ``AO4D_DEVICE`` cannot be met."""
    import os
    import platform

    import numpy as np

    from .. import __version__
    from ..opencl import cl
    from ..opencl import tbb as _tbb

    try:
        import pyopencl

        pyopencl_version = pyopencl.VERSION_TEXT
    except ImportError:  # pragma: no cover - a hard dependency
        pyopencl_version = "missing"
    print(
        f"ao4d {__version__}  python {platform.python_version()}  numpy {np.__version__}  pyopencl {pyopencl_version}"
    )
    folder = cl.register_bundled_runtimes()
    if folder:
        print(f"ICD vendors folder: {folder} (the system's vendors + this Python's Intel CPU runtime)")
    tbb = _tbb.preload_state()
    tbb_line = {
        "loaded": f"loaded at `import ao4d`: {tbb.get('path')}",
        "foreign tbb": f"NOT loaded: another copy was loaded first: {', '.join(tbb.get('foreign', []))}",
        "disabled": f"not preloaded (AO4D_PRELOAD_TBB=0): {tbb.get('path')}",
        "failed": f"failed to load: {tbb.get('error')}",
    }.get(str(tbb["status"]))
    if tbb_line:
        print(f"Intel runtime's TBB: {tbb_line}")
    cache = cl.kernel_cache_dir()
    print(f"kernel binary cache: {cache if cache else 'none writable (kernels compile in every process)'}")

    request, raw = cl.device_request()
    reports = cl.device_reports()
    if os.environ.get("PYOPENCL_NO_CACHE"):
        print("pyopencl's own caches: off (PYOPENCL_NO_CACHE; ao4d sets it when they cannot be written)")
    how = {
        "auto": "not set: a GPU first, then a CPU (Intel's runtime before others), else numpy",
        "none": f"{raw.strip()!r}: OpenCL switched off, numpy backend",
        "cpu": f"{raw.strip()!r}: a CPU device",
        "gpu": f"{raw.strip()!r}: a GPU",
    }.get(request, f"{raw.strip()!r}: the device whose platform or device name contains it")
    print(f"AO4D_DEVICE {how}")
    print("OpenCL devices:" if reports else "OpenCL devices: none found in this process")
    error = None
    try:
        selection = cl.select_device(reports, request, source=f"AO4D_DEVICE={raw.strip()!r}")
        notes = {id(rep): why for rep, why in selection.notes}
    except cl.DeviceSelectionError as exc:
        wanted = f"works, but AO4D_DEVICE={raw.strip()!r} does not ask for it"
        notes = {id(rep): wanted if rep.usable else f"skipped: {rep.reason}" for rep in reports}
        error = exc
    for rep in reports:
        types = "" if rep.types in ("", rep.kind) else f" ({rep.types})"
        print(
            f"  [{rep.kind}{types}] {rep.device} | {rep.platform} | {rep.version} | "
            f"driver {rep.driver or '?'} | {rep.compute_units} CUs, {rep.global_mem_mib} MiB"
        )
        print(f"      {notes[id(rep)]}")
    problems = cl.platform_problems()
    if problems:
        print("platforms that failed or disappeared in this process:")
        for line in problems:
            print(f"  {line}")
    sys.stdout.flush()
    if error is not None:
        print(f"ao4d info: error: {error}", file=sys.stderr)
        return 2
    runtime = cl.get_runtime(warn=False)
    print(f"chosen: {cl.describe(runtime)}")
    return 0
