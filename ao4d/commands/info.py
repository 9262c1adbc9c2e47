"""``ao4d info``: versions, OpenCL platforms and devices, and the one ao4d chooses."""

from __future__ import annotations

import argparse
import sys

HELP = "show versions, OpenCL platforms/devices and which device ao4d uses"
EXAMPLES = """  ao4d info
  AO4D_DEVICE=none ao4d info     # what happens without OpenCL (numpy backend)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    del parser  # no options


def run(args: argparse.Namespace) -> int:
    import os
    import platform

    import numpy as np

    from .. import __version__, cl

    print(f"ao4d {__version__}  python {platform.python_version()}  numpy {np.__version__}")
    folder = cl.register_bundled_runtimes()
    if folder:
        print(f"ICD vendors folder: {folder} (registers this Python's Intel CPU runtime)")
    reports = cl.device_reports()
    if not reports:
        print("OpenCL: no platforms found")
    for rep in reports:
        state = "usable" if rep.usable else f"skipped: {rep.reason}"
        print(
            f"  [{rep.kind}] {rep.device} | {rep.platform} | {rep.version} | "
            f"{rep.compute_units} CUs, {rep.global_mem_mib} MiB | {state}"
        )
    runtime = cl.get_runtime(warn=False)
    env = os.environ.get("AO4D_DEVICE")
    why = f" (AO4D_DEVICE={env})" if env else " (GPU first, then CPU)"
    if runtime is None:
        print(f"chosen: numpy backend - no working OpenCL device{why}")
    else:
        print(f"chosen: {runtime.name}{why}")
    sys.stdout.flush()
    return 0
