"""OpenCL runtime discovery: the one place that finds, probes and chooses a device.

Order: a GPU, then a CPU device, each accepted only after it really builds and runs a tiny
kernel (the PoCL inside some pyopencl wheels lists a CPU device but cannot compile for new CPUs);
when none works, callers fall back to the numpy backend with one warning.

Intel's CPU runtime from PyPI (``intel-opencl-rt``) installs ``<prefix>/lib/libintelocl.so`` but
registers it with a placeholder path. Before pyopencl is first used we write an ICD folder that
lists it by absolute path together with every vendor the system already has, and point the ICD
loader at that folder through ``OCL_ICD_VENDORS``; the user never sets anything.

Nothing here runs at ``import ao4d``: pyopencl is imported on first use.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ._resources import data_dir

__all__ = [
    "Runtime",
    "DeviceReport",
    "NoOpenCLDeviceWarning",
    "get_runtime",
    "have_opencl",
    "device_reports",
    "build_kernels",
    "register_bundled_runtimes",
]

_SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
_PROBE_SOURCE = """
__kernel void ao4d_probe(__global float *a) { int i = get_global_id(0); a[i] = 2.0f * a[i] + 1.0f; }
"""
_lock = threading.RLock()
_runtime_cache: dict[str, Runtime | None] = {}
_reports: list[DeviceReport] = []
_kernel_cache: dict[tuple, dict[str, Any]] = {}


class NoOpenCLDeviceWarning(RuntimeWarning):
    """No working OpenCL device: ao4d computes with its (slower) numpy backend."""


@dataclass(frozen=True)
class DeviceReport:
    """What discovery found about one OpenCL device."""

    platform: str
    device: str
    kind: str  # "GPU", "CPU" or "OTHER"
    version: str
    compute_units: int
    global_mem_mib: int
    usable: bool
    reason: str  # why it was skipped, or "ok"


@dataclass
class Runtime:
    """A chosen OpenCL device with its context and in-order command queue."""

    context: Any
    queue: Any
    device: Any
    report: DeviceReport
    extra: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.report.device} ({self.report.platform}, {self.report.kind})"


def _icd_library_candidates() -> list[Path]:
    """Vendor libraries installed by PyPI runtimes into this Python's prefix.

    A venv's own copy wins over the base interpreter's: registering both would list the same
    device twice.
    """
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        lib = Path(prefix) / "lib" / "libintelocl.so"
        if lib.is_file():
            return [lib.resolve()]
    return []


def register_bundled_runtimes() -> str | None:
    """Make PyPI-installed OpenCL runtimes visible to the ICD loader.

    Writes (once, atomically) a vendors folder holding the system's ICD files plus one for each
    runtime found in this Python's prefix, and sets ``OCL_ICD_VENDORS`` to it. Must run before
    pyopencl first lists platforms. Returns the folder, or ``None`` when there is nothing to add.
    """
    libs = _icd_library_candidates()
    if not libs:
        return None
    current = os.environ.get("OCL_ICD_VENDORS", "")
    sources: list[Path] = []
    base = Path(current) if current else _SYSTEM_VENDORS
    if base.is_dir():
        sources += sorted(base.glob("*.icd"))
    elif base.is_file():
        sources.append(base)
    lines = {f"{src.name}": src.read_text().strip() for src in sources if src.is_file()}
    for lib in libs:
        lines[f"ao4d-{lib.stem}.icd"] = str(lib)
    key = hashlib.sha256(repr(sorted(lines.items())).encode()).hexdigest()[:16]
    uid = os.getuid() if hasattr(os, "getuid") else 0
    folder = Path(tempfile.gettempdir()) / f"ao4d-icd-{uid}-{key}"
    if not folder.is_dir():
        staging = Path(tempfile.mkdtemp(prefix="ao4d-icd-staging-"))
        for name, text in lines.items():
            (staging / name).write_text(text + "\n")
        try:
            os.replace(staging, folder)  # atomic: other processes see all files or none
        except OSError:
            for f in staging.iterdir():
                f.unlink()
            staging.rmdir()  # another process won the race; its folder has the same content
    os.environ["OCL_ICD_VENDORS"] = str(folder)
    return str(folder)


def _import_cl():
    with _lock:
        if "pyopencl" not in sys.modules:
            register_bundled_runtimes()
        try:
            import pyopencl as cl
        except ImportError:  # pragma: no cover - pyopencl is a hard dependency
            return None
        return cl


def _kind(cl, device) -> str:
    if device.type & cl.device_type.GPU:
        return "GPU"
    if device.type & cl.device_type.CPU:
        return "CPU"
    return "OTHER"


def _probe(cl, device) -> str:
    """Build and run a tiny kernel on ``device``; return "ok" or why it failed."""
    import numpy as np

    try:
        ctx = cl.Context([device])
        queue = cl.CommandQueue(ctx)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            prg = cl.Program(ctx, _PROBE_SOURCE).build()
        a = np.arange(16, dtype=np.float32)
        buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
        cl.Kernel(prg, "ao4d_probe")(queue, (16,), None, buf)
        out = np.empty_like(a)
        cl.enqueue_copy(queue, out, buf)
        queue.finish()
        if not np.array_equal(out, 2 * a + 1):
            return "probe kernel returned wrong values"
        return "ok"
    except Exception as exc:  # any driver failure means: skip this device, say why
        msg = str(exc).strip().splitlines()
        return f"cannot build/run kernels: {msg[0] if msg else type(exc).__name__}"


def device_reports() -> list[DeviceReport]:
    """List every OpenCL platform/device with whether it works (probing each once)."""
    with _lock:
        if _reports:
            return list(_reports)
        cl = _import_cl()
        if cl is None:
            return []
        try:
            platforms = cl.get_platforms()
        except Exception:
            platforms = []
        for platform in platforms:
            try:
                devices = platform.get_devices()
            except Exception:
                devices = []
            for device in devices:
                reason = _probe(cl, device)
                _reports.append(
                    DeviceReport(
                        platform=platform.name.strip(),
                        device=device.name.strip(),
                        kind=_kind(cl, device),
                        version=device.version.strip(),
                        compute_units=int(device.max_compute_units),
                        global_mem_mib=int(device.global_mem_size >> 20),
                        usable=reason == "ok",
                        reason=reason,
                    )
                )
        return list(_reports)


def _choose(reports: list[DeviceReport], prefer: str) -> DeviceReport | None:
    order = {"auto": ("GPU", "CPU", "OTHER"), "gpu": ("GPU",), "cpu": ("CPU",)}[prefer]
    for kind in order:
        for rep in reports:
            if rep.usable and rep.kind == kind:
                return rep
    return None


def get_runtime(prefer: str = "auto", *, warn: bool = True) -> Runtime | None:
    """Return the chosen OpenCL runtime, or ``None`` (with one warning) if no device works.

    Parameters
    ----------
    prefer : {"auto", "gpu", "cpu"}
        ``"auto"`` takes a GPU first, then a CPU. The environment variable ``AO4D_DEVICE``
        (``gpu``/``cpu``/``none``) overrides ``"auto"``.
    warn : bool
        Emit :class:`NoOpenCLDeviceWarning` when falling back.
    """
    if prefer not in ("auto", "gpu", "cpu"):
        raise ValueError(f"`prefer` must be one of 'auto', 'gpu', 'cpu'; got {prefer!r}")
    env = os.environ.get("AO4D_DEVICE", "").strip().lower()
    if prefer == "auto" and env in ("gpu", "cpu", "none"):
        prefer = env
    with _lock:
        if prefer not in _runtime_cache:
            runtime = None
            if prefer != "none":
                rep = _choose(device_reports(), prefer)
                if rep is not None:
                    runtime = _make_runtime(rep)
            _runtime_cache[prefer] = runtime
            if runtime is None and warn:
                warnings.warn(
                    "ao4d: no working OpenCL device found (see `ao4d info`); "
                    "using the numpy backend, which is much slower",
                    NoOpenCLDeviceWarning,
                    stacklevel=2,
                )
        return _runtime_cache[prefer]


def have_opencl() -> bool:
    """True when a working OpenCL device exists (never warns)."""
    return get_runtime(warn=False) is not None


def _make_runtime(rep: DeviceReport) -> Runtime:
    cl = _import_cl()
    for platform in cl.get_platforms():
        if platform.name.strip() != rep.platform:
            continue
        for device in platform.get_devices():
            if device.name.strip() == rep.device and _kind(cl, device) == rep.kind:
                ctx = cl.Context([device])
                return Runtime(ctx, cl.CommandQueue(ctx), device, rep)
    raise RuntimeError(f"OpenCL device {rep.device!r} disappeared after probing")


def build_kernels(
    runtime: Runtime, source: str, defines: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Build ``kernels/<source>`` for ``runtime`` once and return its kernels by name.

    Shared code is reached with ``#include`` (the kernels folder is passed with ``-I``);
    specialisation uses ``-D NAME=VALUE`` from ``defines``. A build failure raises
    ``RuntimeError`` carrying the compiler log.
    """
    cl = _import_cl()
    folder = data_dir("kernels")
    path = folder / source
    if not path.is_file():
        raise FileNotFoundError(f"kernel source {source!r} not found in {folder}")
    text = path.read_text()
    # include files are part of the cache key so that an edited header rebuilds
    includes = "".join(p.read_text() for p in sorted(folder.glob("*.h")))
    defs = tuple(sorted((defines or {}).items()))
    key = (id(runtime.context), source, defs, hashlib.sha256((text + includes).encode()).hexdigest())
    with _lock:
        if key not in _kernel_cache:
            options = ["-I", str(folder), "-cl-std=CL1.2"] + [f"-D{k}={v}" for k, v in defs]
            program = cl.Program(runtime.context, text)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # pyopencl warns on any non-empty log
                    program = program.build(options=options)
            except cl.RuntimeError as exc:
                raise RuntimeError(f"building OpenCL kernels {source} failed:\n{exc}") from None
            _kernel_cache[key] = {k.function_name: k for k in program.all_kernels()}
        return _kernel_cache[key]
