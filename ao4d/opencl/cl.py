"""OpenCL runtime discovery: the one place that finds, probes, chooses and names a device.

Why this file is long: it stays one module because choosing, naming and checking a device (its
memory, its kernel builds) are one idea that every other module asks about in one place.

Every device is accepted only after it really builds and runs a tiny kernel (the PoCL inside
some pyopencl wheels lists a CPU device but cannot compile for new CPUs). Then, unless
``AO4D_DEVICE`` says otherwise:

1. a GPU (a device that reports the GPU type and nothing else);
2. a CPU device, Intel's CPU runtime before any other (PoCL): on this project's 2-core machine
   Intel's runtime traced ao4d's AO kernels 2-3x faster than a system PoCL;
3. otherwise the numpy backend, with one :class:`NoOpenCLDeviceWarning` that says why.

A device that reports several types at once (Oclgrind's simulator says ACCELERATOR|GPU|CPU) is
neither a GPU nor a CPU: it is used only when named (``AO4D_DEVICE=oclgrind``).

``AO4D_DEVICE`` takes ``cpu``, ``gpu``, ``none`` or a case-insensitive substring of a platform or
device name (``intel``, ``NVIDIA``), each but ``none`` optionally followed by ``:k`` for the k-th
working device it matches, from 0 (``gpu:1``: the second GPU, where two identical GPUs differ only
by their place). A request that cannot be met (an unknown name, ``gpu`` on a
machine without one) is a :class:`DeviceSelectionError` at the first device use, listing the
devices that exist; it never falls back silently.

Intel's CPU runtime from PyPI (``intel-opencl-rt``) installs ``<prefix>/lib/libintelocl.so`` but
registers it with a placeholder path. Before the first platform query we write an ICD folder that
lists it by absolute path together with every vendor the system already has, and point the ICD
loader at that folder through ``OCL_ICD_VENDORS``; the user never sets anything. Its TBB is loaded
at ``import ao4d`` (see ``ao4d/opencl/tbb.py``); when a platform still fails to load, discovery says
which library broke it (:func:`platform_problems`).

Compiled programs persist across processes in ``$XDG_CACHE_HOME/ao4d/kernels`` (``~/.cache``
by default; a temporary folder when that is read-only), keyed by the source with every kernel
header, the build options, and the platform, device and driver versions
(``ao4d/opencl/binaries.py``).

Nothing here runs at ``import ao4d``: pyopencl is imported on first use.
"""

from __future__ import annotations

import hashlib
import os
import re
import sys
import tempfile
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .._resources import data_dir
from .._validate import check_choice
from . import binaries as _kernel_binaries
from . import tbb as _tbb
from .binaries import kernel_build_stats, kernel_cache_dir

__all__ = [
    "BACKENDS",
    "check_device_memory",
    "DeviceReport",
    "DeviceSelectionError",
    "NoOpenCLDeviceError",
    "NoOpenCLDeviceWarning",
    "Runtime",
    "Selection",
    "backend_name",
    "build_kernels",
    "describe",
    "device_reports",
    "device_request",
    "get_runtime",
    "kernel_build_stats",
    "kernel_cache_dir",
    "kind_of",
    "platform_problems",
    "register_bundled_runtimes",
    "resolve_backend",
    "select_device",
]

#: The values of every ``backend=`` option: ``"auto"`` takes OpenCL when a device works.
BACKENDS = ("auto", "opencl", "numpy")

_SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
_PROBE_SOURCE = """
__kernel void ao4d_probe(__global float *a) { int i = get_global_id(0); a[i] = 2.0f * a[i] + 1.0f; }
"""
_WHY_INTEL = "Intel's CPU runtime is preferred: measured 2-3x faster than PoCL on ao4d's kernels"

# OpenCL device type bits (the OpenCL 1.2 specification, table 4.3)
_TYPE_BITS = {1: "DEFAULT", 2: "CPU", 4: "GPU", 8: "ACCELERATOR", 16: "CUSTOM"}

_lock = threading.RLock()
_runtime_cache: dict[str, Runtime | None] = {}
_by_device: dict[DeviceReport, Runtime] = {}
_reports: list[DeviceReport] = []
_problems: list[str] = []
_discovered = False
_registered: str | None = None
_kernel_cache: dict[tuple, dict[str, Any]] = {}


class NoOpenCLDeviceWarning(RuntimeWarning):
    """No working OpenCL device: ao4d computes with its (slower) numpy backend."""


class NoOpenCLDeviceError(RuntimeError):
    """``backend="opencl"`` was asked for, but no OpenCL device works."""


class DeviceSelectionError(ValueError):
    """``AO4D_DEVICE`` (or ``prefer``) asks for a device that does not exist or does not work."""


@dataclass(frozen=True)
class DeviceReport:
    """What discovery found about one OpenCL device.

    Attributes
    ----------
    platform : str
        Name of the platform that lists the device.
    device : str
        The device's name.
    kind : {"GPU", "CPU", "OTHER"}
        ``"OTHER"`` for several types at once and for accelerators (see :func:`kind_of`).
    version : str
        The device's OpenCL version string.
    compute_units : int
        Its compute units.
    global_mem_mib : int
        Its global memory in MiB.
    usable : bool
        Whether it built and ran the probe kernel.
    reason : str
        Why it cannot be used, or ``"ok"``.
    types : str
        Every type the device reports, e.g. ``"ACCELERATOR|GPU|CPU"``.
    driver : str
        The driver version.
    position : int
        Index among its platform's devices (tells identical devices apart).
    """

    platform: str
    device: str
    kind: str  # "GPU", "CPU" or "OTHER" (several types at once, accelerators): see kind_of
    version: str
    compute_units: int
    global_mem_mib: int
    usable: bool
    reason: str  # why it cannot be used, or "ok"
    types: str = ""  # every type the device reports, e.g. "ACCELERATOR|GPU|CPU"
    driver: str = ""
    position: int = 0  # index among its platform's devices: tells identical devices apart

    @property
    def line(self) -> str:
        """The device line: ``"AMD EPYC (Intel(R) OpenCL, CPU)"``."""
        return f"{self.device} ({self.platform}, {self.kind})"


@dataclass
class Runtime:
    """A chosen OpenCL device with its context and in-order command queue.

    Attributes
    ----------
    context : pyopencl.Context
        A context on the device alone.
    queue : pyopencl.CommandQueue
        An in-order queue on it.
    device : pyopencl.Device
        The device.
    report : DeviceReport
        What discovery found about it.
    """

    context: Any
    queue: Any
    device: Any
    report: DeviceReport

    @property
    def name(self) -> str:
        """The device line (see :func:`describe`)."""
        return self.report.line


@dataclass(frozen=True)
class Selection:
    """Which device a request chose and why each device was or was not chosen.

    Attributes
    ----------
    request : str
        ``"auto"``, ``"cpu"``, ``"gpu"``, ``"none"`` or ``"name:<substring>"``.
    chosen : DeviceReport or None
        The device chosen, or ``None`` for numpy.
    notes : tuple of (DeviceReport, str)
        For each report, why it was or was not chosen.
    """

    request: str  # "auto", "cpu", "gpu", "none" or "name:<substring>"
    chosen: DeviceReport | None
    notes: tuple[tuple[DeviceReport, str], ...]


# -- naming -----------------------------------------------------------------------------------


def backend_name(runtime: Runtime | None) -> str:
    """The backend that actually runs: ``"opencl"`` for a runtime, ``"numpy"`` for ``None``.

    Parameters
    ----------
    runtime : Runtime or None
        What :func:`resolve_backend` gave.

    Returns
    -------
    {"opencl", "numpy"}
        The backend's name.
    """
    return "numpy" if runtime is None else "opencl"


def describe(runtime: Runtime | None) -> str:
    """One line naming what computes, used wherever ao4d names its device.

    ``"AMD EPYC (Intel(R) OpenCL, CPU)"`` for a runtime; for ``None`` ``"numpy (no OpenCL
    device)"`` when discovery found none, ``"numpy (AO4D_DEVICE=none)"`` when OpenCL is switched
    off, and ``"numpy"`` when the numpy backend was asked for. Never starts discovery.

    Parameters
    ----------
    runtime : Runtime or None
        The device that computes (what :func:`get_runtime` or :func:`resolve_backend` gave), or
        ``None`` for numpy.

    Returns
    -------
    str
        The line.
    """
    if runtime is not None:
        return runtime.name
    if device_request()[0] == "none":
        return "numpy (AO4D_DEVICE=none)"
    with _lock:
        if _discovered and not any(r is not None for r in _runtime_cache.values()):
            return "numpy (no OpenCL device)"
    return "numpy"


# -- the ICD folder ---------------------------------------------------------------------------


def _icd_library_candidates() -> list[Path]:
    """Vendor libraries installed by PyPI runtimes into this Python's prefix."""
    lib_dir = _tbb.runtime_lib_dir()
    return [Path(lib_dir) / "libintelocl.so"] if lib_dir else []


def register_bundled_runtimes() -> str | None:
    """Make PyPI-installed OpenCL runtimes visible to the ICD loader.

    Writes (once, atomically) a vendors folder holding the system's ICD files plus one for each
    runtime found in this Python's prefix, and sets ``OCL_ICD_VENDORS`` to it. Must run before
    the first platform query of the process.

    Returns
    -------
    str or None
        The folder, or ``None`` when there is nothing to add.
    """
    global _registered
    with _lock:
        if _registered is not None and os.environ.get("OCL_ICD_VENDORS") == _registered:
            return _registered
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
        _registered = str(folder)
        return _registered


def _icd_entries() -> list[tuple[str, str]]:
    """(ICD file, vendor library) pairs the ICD loader reads in this process."""
    current = os.environ.get("OCL_ICD_VENDORS", "")
    base = Path(current) if current else _SYSTEM_VENDORS
    files = sorted(base.glob("*.icd")) if base.is_dir() else [base] if base.is_file() else []
    out = []
    for f in files:
        try:
            out.append((f.name, f.read_text().strip()))
        except OSError:
            continue
    return out


def _guard_pyopencl_caches() -> None:
    """Switch pyopencl's own disk caches off where their folder cannot be written.

    pyopencl keeps the Python code that sets kernel arguments in a pytools cache under the user
    cache folder and creates it at the first kernel call; on a read-only home that call fails,
    and every device would look broken. ``PYOPENCL_NO_CACHE=1`` (read when pyopencl is imported)
    makes it generate that code in memory instead. ao4d's own binary cache falls back by itself.
    """
    if "pyopencl" in sys.modules or os.environ.get("PYOPENCL_NO_CACHE"):
        return
    try:
        import platformdirs  # pytools' own rule for its folder

        folder = Path(platformdirs.user_cache_dir("pytools", "pytools"))
        folder.mkdir(parents=True, exist_ok=True)
        writable = os.access(folder, os.W_OK | os.X_OK)
    except Exception:
        writable = False
    if not writable:
        os.environ["PYOPENCL_NO_CACHE"] = "1"


def _import_cl():
    with _lock:
        # also when the user imported pyopencl first: the loader reads OCL_ICD_VENDORS at the
        # first platform query, not at import
        register_bundled_runtimes()
        _guard_pyopencl_caches()
        try:
            import pyopencl as cl
        except ImportError:  # pragma: no cover - pyopencl is a hard dependency
            return None
        return cl


# -- discovery --------------------------------------------------------------------------------


def kind_of(type_bits: int) -> tuple[str, str]:
    """Classify a device by its ``CL_DEVICE_TYPE`` bits: ``(kind, all types)``.

    ``kind`` is ``"GPU"`` or ``"CPU"`` only for a device that reports that type alone (the
    DEFAULT bit aside); several types at once (Oclgrind's ACCELERATOR|GPU|CPU simulator) or an
    accelerator give ``"OTHER"``, which ao4d uses only when named in ``AO4D_DEVICE``.

    Parameters
    ----------
    type_bits : int
        The device's ``CL_DEVICE_TYPE`` bit field.

    Returns
    -------
    kind : {"GPU", "CPU", "OTHER"}
        The kind ao4d chooses by.
    types : str
        Every type reported, joined by ``|`` (``"DEFAULT"`` or ``"NONE"`` when none).

    Examples
    --------
    >>> kind_of(4), kind_of(8 | 4 | 2)
    (('GPU', 'GPU'), ('OTHER', 'ACCELERATOR|GPU|CPU'))
    """
    bits = int(type_bits) & ~1
    names = [name for bit, name in sorted(_TYPE_BITS.items(), reverse=True) if bits & bit]
    types = "|".join(names) or ("DEFAULT" if type_bits & 1 else "NONE")
    if bits == 4:
        return "GPU", types
    if bits == 2:
        return "CPU", types
    return "OTHER", types


def _probe(cl, device) -> str:
    """Build and run a tiny kernel on ``device``; return "ok" or why it failed."""
    import numpy as np

    try:
        ctx = cl.Context([device])
        queue = cl.CommandQueue(ctx)
        prg = _kernel_binaries.built_program(cl, ctx, device, "probe", _PROBE_SOURCE, ["-cl-std=CL1.2"])
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
    """List every OpenCL platform/device with whether it works (probing each once per process).

    Returns
    -------
    list of DeviceReport
        In platform order, then device order.
    """
    global _discovered
    with _lock:
        if _discovered:
            return list(_reports)
        cl = _import_cl()
        platforms = []
        if cl is not None:
            try:
                platforms = cl.get_platforms()
            except Exception as exc:
                text = str(exc).strip() or type(exc).__name__
                _problems.append(f"the ICD loader found no platform ({text})")
        for platform in platforms:
            pname = platform.name.strip()
            try:
                devices = platform.get_devices()
            except Exception as exc:
                _problems.append(f"platform {pname!r} lists no devices: {str(exc).strip()}")
                devices = []
            for position, device in enumerate(devices):
                reason = _probe(cl, device)
                kind, types = kind_of(device.type)
                _reports.append(
                    DeviceReport(
                        platform=pname,
                        device=device.name.strip(),
                        kind=kind,
                        version=device.version.strip(),
                        compute_units=int(device.max_compute_units),
                        global_mem_mib=int(device.global_mem_size >> 20),
                        usable=reason == "ok",
                        reason=reason,
                        types=types,
                        driver=str(device.driver_version).strip(),
                        position=position,
                    )
                )
        _problems.extend(_missing_platforms())
        _discovered = True
        return list(_reports)


def _missing_platforms() -> list[str]:
    """Why vendor libraries named by the ICD files did not become platforms in this process.

    The ICD loader drops a library that fails to load without a word. A library it kept is
    mapped into the process; for each one that is not, load it ourselves to learn the loader's
    error, and name a foreign ``libtbb`` when one is mapped (the Open3D case, ``ao4d/opencl/tbb.py``).
    """
    mapped = _tbb.mapped_libraries()
    if not mapped:
        return []  # no /proc: nothing to compare with
    names = {os.path.basename(p) for p in mapped} | set(mapped)
    real = {os.path.realpath(p) for p in mapped}
    out = []
    for icd, lib in _icd_entries():
        if lib in names or os.path.basename(lib) in names or os.path.realpath(lib) in real:
            continue
        import ctypes

        try:
            ctypes.CDLL(lib)
            why = "it loads, but reported no platform to the ICD loader"
        except OSError as exc:
            why = f"it cannot be loaded: {exc}"
        out.append(f"{lib} (from {icd}) gave no platform: {why}")
        lib_dir = os.path.dirname(os.path.realpath(lib)) if os.path.isabs(lib) else None
        foreign = _tbb.foreign_tbb(lib_dir) if lib_dir == _tbb.runtime_lib_dir() else []
        if foreign:
            state = _tbb.preload_state()
            own = state.get("path", os.path.join(lib_dir, "libtbb.so.12"))
            when = (
                "before the Intel runtime (AO4D_PRELOAD_TBB=0 turned ao4d's own preload off)"
                if state.get("status") == "disabled"
                else "before ao4d"
            )
            out.append(
                f"cause: {foreign[0]} was loaded into this process {when} (by a library that "
                f"bundles its own TBB, such as Open3D); the Intel runtime needs its own newer "
                f"{own}, and the dynamic loader reuses the copy already loaded. "
                "Fix: import ao4d before that library (ao4d then loads its TBB first and the other "
                f"library uses it), start Python with LD_PRELOAD={own}, or run the other "
                "library in a separate process"
            )
    return out


def platform_problems() -> list[str]:
    """What made OpenCL platforms fail or disappear in this process (after discovery).

    Returns
    -------
    list of str
        One line per problem; empty when every vendor library the ICD loader was given produced
        its platform.
    """
    device_reports()
    with _lock:
        return list(_problems)


# -- choosing ---------------------------------------------------------------------------------


def device_request() -> tuple[str, str]:
    """``AO4D_DEVICE`` parsed: ``(request, raw value)``.

    ``request`` is ``"auto"`` (unset or empty), ``"cpu"``, ``"gpu"``, ``"none"`` or
    ``"name:<lower-case substring>"``; the last three may end in ``"#<k>"``, from a value such as
    ``gpu:1`` or ``nvidia:1``: the k-th (from 0) of the working devices it matches, in the order
    ``ao4d info`` lists them (two identical GPUs differ only by it).

    Returns
    -------
    request : str
        The parsed request.
    raw : str
        The variable's value as set (empty when unset).
    """
    raw = os.environ.get("AO4D_DEVICE", "")
    value = raw.strip().lower()
    if value in ("", "auto"):
        return "auto", raw
    match = re.fullmatch(r"(.+?):(\d+)", value)
    value, suffix = (match.group(1), f"#{int(match.group(2))}") if match else (value, "")
    if value in ("cpu", "gpu", "none"):
        return value + ("" if value == "none" else suffix), raw
    return f"name:{value}{suffix}", raw


def _rank(rep: DeviceReport, index: int) -> tuple[int, int, int]:
    kind = {"GPU": 0, "CPU": 1}.get(rep.kind, 2)
    vendor = 0 if rep.kind == "CPU" and "intel" in rep.platform.lower() else 1
    return kind, vendor, index


def _state(rep: DeviceReport) -> str:
    return "works" if rep.usable else rep.reason


def _device_list(reports: list[DeviceReport]) -> str:
    if not reports:
        return "  (none)"
    return "\n".join(
        f"  [{r.kind}{'' if r.kind != 'OTHER' else ': ' + r.types}] {r.device} | {r.platform} | {_state(r)}"
        for r in reports
    )


def _selection_error(source: str, problem: str, reports: list[DeviceReport], hint: str) -> DeviceSelectionError:
    text = f"{source}: {problem}. OpenCL devices in this process:\n{_device_list(reports)}"
    if not reports and _problems:
        text += "\nWhy platforms are missing:\n" + "\n".join(f"  {p}" for p in _problems)
    return DeviceSelectionError(f"{text}\n{hint}")


def select_device(reports: list[DeviceReport], request: str, *, source: str = "AO4D_DEVICE") -> Selection:
    """Choose a device among ``reports`` for ``request`` (see :func:`device_request`).

    Parameters
    ----------
    reports : list of DeviceReport
        What discovery found (:func:`device_reports`), in platform order.
    request : str
        ``"auto"``, ``"cpu"``, ``"gpu"``, ``"none"`` or ``"name:<substring>"``.
    source : str
        How the request was given, for messages (``"AO4D_DEVICE='gpu'"``).

    Returns
    -------
    Selection
        The chosen report (``None`` for ``"none"`` and for ``"auto"`` without a working GPU
        or CPU) and, for each report, why it was or was not chosen.

    Raises
    ------
    DeviceSelectionError
        A ``cpu``/``gpu``/name request that no working device meets; the message lists the
        devices and what to set instead.
    """
    request, _, which = request.partition("#")
    order = sorted(range(len(reports)), key=lambda i: _rank(reports[i], i))
    ranked = [reports[i] for i in order]
    accepted = [
        "cpu",
        "gpu",
        "none",
        "or part of a platform/device name",
        "each optionally with :k for the k-th match (from 0)",
    ]
    usage = "AO4D_DEVICE takes " + ", ".join(accepted) + "; unset it to choose automatically."
    if request == "none":
        return Selection(request, None, tuple((r, "not used: AO4D_DEVICE=none") for r in reports))
    if request == "auto":
        pool = [r for r in ranked if r.usable and r.kind in ("GPU", "CPU")]
    elif request in ("cpu", "gpu"):
        kind = request.upper()
        pool = [r for r in ranked if r.usable and r.kind == kind]
        if not pool:
            asked = [r for r in reports if r.kind == kind]
            problem = f"no {kind} device works" if asked else f"there is no {kind} among the OpenCL devices"
            working = [r.line for r in ranked if r.usable and r.kind in ("GPU", "CPU")]
            hint = (
                f"Devices that work: {'; '.join(working)}. Unset AO4D_DEVICE to use "
                f"{working[0]}, or set it to one of their names."
                if working
                else "No device works: set AO4D_DEVICE=none to use the numpy backend."
            )
            raise _selection_error(source, problem, reports, hint)
    elif request.startswith("name:"):
        text = request[5:]
        matches = [r for r in ranked if text in r.platform.lower() or text in r.device.lower()]
        pool = [r for r in matches if r.usable]
        if not matches:
            raise _selection_error(
                source,
                f"{text!r} is not cpu, gpu or none and names no OpenCL platform or device",
                reports,
                usage,
            )
        if not pool:
            raise _selection_error(source, f"the device(s) named by {text!r} do not work", reports, usage)
    else:
        raise ValueError(f"`request` must be auto, cpu, gpu, none or name:<text>; got {request!r}")
    if which:
        if int(which) >= len(pool):
            raise _selection_error(
                source,
                f"asks for working device {which} (from 0) of those it matches, but "
                f"{len(pool)} match{'es' if len(pool) == 1 else ''}",
                reports,
                usage,
            )
    chosen = pool[int(which or 0)] if pool else None
    notes = []
    for rep in reports:
        if rep is chosen:
            if request.startswith("name:"):
                why = f"chosen: {source} names it"
            elif rep.kind == "GPU":
                why = "chosen: the first working GPU"
            elif any(r.kind == "CPU" and r is not rep for r in pool) and _rank(rep, 0)[1] == 0:
                why = f"chosen: {'no working GPU; ' if request == 'auto' else ''}{_WHY_INTEL}"
            else:
                why = f"chosen: {'no working GPU; ' if request == 'auto' else ''}the first working CPU device"
        elif not rep.usable:
            why = f"skipped: {rep.reason}"
        elif which and rep in pool:
            why = f"works, not chosen: {source} asks for match {which} (from 0)"
        elif rep.kind == "OTHER" and not request.startswith("name:"):
            why = (
                f"works, never chosen automatically: it reports several device types ({rep.types}), "
                "as simulators such as Oclgrind do; choose it by name in AO4D_DEVICE"
            )
        elif request.startswith("name:") and rep not in pool:
            why = f"not chosen: {source} does not name it"
        elif request in ("cpu", "gpu") and rep.kind != request.upper():
            why = f"not chosen: {source} asks for a {request.upper()}"
        elif chosen is not None and rep.kind == chosen.kind == "CPU" and _rank(chosen, 0) < _rank(rep, 0):
            why = f"works, not chosen: {_WHY_INTEL}"
        elif chosen is not None and chosen.kind == "GPU" and rep.kind != "GPU":
            why = "works, not chosen: a GPU comes first"
        else:
            why = f"works, not chosen: {chosen.line if chosen else 'another device'} comes first"
        notes.append((rep, why))
    return Selection(request, chosen, tuple(notes))


def _no_device_reason() -> str:
    with _lock:
        problems = list(_problems)
    if _reports:
        reasons = "; ".join(
            f"{r.line}: {'works, but is chosen only by name' if r.usable else r.reason}" for r in _reports
        )
        text = f"no OpenCL GPU or CPU device works ({reasons})"
    else:
        text = "no OpenCL platform was found"
    if problems:
        text += ". " + " ".join(problems)
    return text


def get_runtime(prefer: str = "auto", *, warn: bool = True) -> Runtime | None:
    """Return the chosen OpenCL runtime, or ``None`` (with one warning) if no device works.

    Parameters
    ----------
    prefer : {"auto", "gpu", "cpu"}
        ``"auto"`` follows ``AO4D_DEVICE`` when it is set, and otherwise takes a GPU first,
        then a CPU (Intel's runtime before others). ``"gpu"``/``"cpu"`` ask for that kind.
    warn : bool
        Emit :class:`NoOpenCLDeviceWarning` when falling back to numpy. The answer is kept per
        request, and the warning comes only with the call that first finds it.

    Returns
    -------
    Runtime or None
        The device's runtime, or ``None`` for the numpy backend.

    Raises
    ------
    DeviceSelectionError
        ``AO4D_DEVICE`` (or ``prefer``) asks for a device that does not exist or does not work.
    """
    check_choice(prefer, "prefer", ("auto", "gpu", "cpu"))
    if prefer == "auto":
        request, raw = device_request()
        source = f"AO4D_DEVICE={raw.strip()!r}"
    else:
        request, source = prefer, f"prefer={prefer!r}"
    with _lock:
        if request not in _runtime_cache:
            runtime = None
            if request != "none":
                sel = select_device(device_reports(), request, source=source)  # may raise
                if sel.chosen is not None:
                    # one context per device, whatever the request: kernels are built per context
                    if sel.chosen not in _by_device:
                        _by_device[sel.chosen] = _make_runtime(sel.chosen)
                    runtime = _by_device[sel.chosen]
            _runtime_cache[request] = runtime
            if runtime is None and warn:
                why = "AO4D_DEVICE=none" if request == "none" else _no_device_reason()
                warnings.warn(
                    f"ao4d: using the numpy backend, which is much slower: {why} (see `ao4d info`)",
                    NoOpenCLDeviceWarning,
                    stacklevel=2,
                )
        return _runtime_cache[request]


def resolve_backend(backend: str, *, warn: bool = True) -> Runtime | None:
    """Check a ``backend=`` value and return the runtime that will compute (``None``: numpy).

    Parameters
    ----------
    backend : {"auto", "opencl", "numpy"}
        ``"auto"`` takes the chosen OpenCL device and falls back to numpy (with one
        :class:`NoOpenCLDeviceWarning` when ``warn``); ``"opencl"`` requires a device.
    warn : bool
        Warn when ``"auto"`` falls back to numpy.

    Returns
    -------
    Runtime or None
        The runtime that computes; ``None`` when numpy does (asked for, or the fallback).

    Raises
    ------
    ValueError
        ``backend`` is not one of :data:`BACKENDS`.
    NoOpenCLDeviceError
        ``backend="opencl"`` and no OpenCL device works (the message says why).
    DeviceSelectionError
        ``AO4D_DEVICE`` cannot be met.
    """
    check_choice(backend, "backend", BACKENDS)
    if backend == "numpy":
        return None
    runtime = get_runtime(warn=warn and backend == "auto")
    if runtime is None and backend == "opencl":
        why = "AO4D_DEVICE=none" if device_request()[0] == "none" else _no_device_reason()
        raise NoOpenCLDeviceError(
            f"backend='opencl' was requested but no OpenCL device can be used: {why} (see `ao4d info`)"
        )
    return runtime


def _make_runtime(rep: DeviceReport) -> Runtime:
    cl = _import_cl()
    for platform in cl.get_platforms():
        if platform.name.strip() != rep.platform:
            continue
        devices = platform.get_devices()
        if rep.position < len(devices):
            device = devices[rep.position]
            if device.name.strip() == rep.device and kind_of(device.type)[0] == rep.kind:
                ctx = cl.Context([device])
                return Runtime(ctx, cl.CommandQueue(ctx), device, rep)
    raise RuntimeError(f"OpenCL device {rep.device!r} disappeared after probing")


# -- kernels ----------------------------------------------------------------------------------


def check_device_memory(
    runtime: Runtime, nbytes: dict[str, int], *, task: str, fallback: str = "backend='numpy'"
) -> None:
    """Refuse, before any work, buffers the device cannot hold: one of them, or all at once.

    Parameters
    ----------
    runtime : Runtime
        The device.
    nbytes : dict of str to int
        What each buffer holds, mapped to its size in bytes.
    task : str
        The work, named in the message.
    fallback : str, optional
        What to use instead, named in the message.

    Raises
    ------
    MemoryError
        If one buffer exceeds the device's largest allocation, or all together exceed 80% of its
        global memory.
    """
    dev = runtime.device
    for what, size in nbytes.items():
        if size > dev.max_mem_alloc_size:
            raise MemoryError(
                f"{what} needs {size / 2**20:.0f} MiB in one buffer, above the "
                f"{dev.max_mem_alloc_size / 2**20:.0f} MiB one allocation may take on {runtime.name}; "
                f"use a smaller mesh or {fallback}"
            )
    total = sum(nbytes.values())
    if total > 0.8 * dev.global_mem_size:
        raise MemoryError(
            f"{task} needs {total / 2**20:.0f} MiB on {runtime.name}, above 80% of its "
            f"{dev.global_mem_size / 2**20:.0f} MiB; use a smaller mesh or {fallback}"
        )


def build_kernels(runtime: Runtime, source: str, defines: dict[str, Any] | None = None) -> dict[str, Any]:
    """Build ``kernels/<source>`` for ``runtime`` once and return its kernels by name.

    Shared code is reached with ``#include`` (the kernels folder is passed with ``-I``);
    specialisation uses ``-D NAME=VALUE`` from ``defines``. The compiled binary is kept in
    :func:`kernel_cache_dir` (``ao4d/opencl/binaries.py``), so another process loads it
    instead of compiling.

    Parameters
    ----------
    runtime : Runtime
        The device to build for.
    source : str
        A path in ``kernels/`` (``"rays/ao.cl"``: the folders mirror the package's stages).
    defines : dict, optional
        Preprocessor definitions, passed as ``-D NAME=VALUE``.

    Returns
    -------
    dict of str to pyopencl.Kernel
        The program's kernels by function name (the same objects on later calls).

    Raises
    ------
    FileNotFoundError
        If ``kernels/<source>`` does not exist.
    RuntimeError
        If the build fails; the message carries the compiler log.
    """
    cl = _import_cl()
    folder = data_dir("kernels")
    path = folder / source
    if not path.is_file():
        raise FileNotFoundError(f"kernel source {source!r} not found in {folder}")
    text = path.read_text()
    # every header is part of the cache keys, so that an edited header rebuilds
    includes = "".join(f"\n// {p.relative_to(folder)}\n{p.read_text()}" for p in sorted(folder.rglob("*.h")))
    defs = tuple(sorted((defines or {}).items()))
    digest = hashlib.sha256((text + includes).encode()).hexdigest()
    key = (id(runtime.context), source, defs, digest)
    with _lock:
        if key not in _kernel_cache:
            options = ["-I", str(folder), "-cl-std=CL1.2"] + [f"-D{k}={v}" for k, v in defs]
            try:
                program = _kernel_binaries.built_program(
                    cl, runtime.context, runtime.device, f"{source}\0{includes}", text, options
                )
            except cl.RuntimeError as exc:
                raise RuntimeError(
                    f"building OpenCL kernels {source} for {runtime.name} failed "
                    f"(options: {' '.join(options)}); compiler log:\n{_kernel_binaries.build_log(exc, runtime.report.platform)}"
                ) from None
            _kernel_cache[key] = {k.function_name: k for k in program.all_kernels()}
        return _kernel_cache[key]
