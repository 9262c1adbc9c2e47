"""Compiled OpenCL programs kept across processes, keyed by everything their build reads.

One file per program and device: ``<key>.bin`` in :func:`kernel_cache_dir`, written atomically
(``ao4d/_atomic.py``). The key hashes the source, the text of every kernel header, the build
options (``-D`` defines included), the platform, device and driver names and versions,
pyopencl's version (it adds its own ``-I`` to every build) and the runtime's ``CL_CONFIG_*``
environment variables (they change its code generation). A damaged or stale entry is dropped
and rebuilt. On the project's machine Intel's CPU runtime compiles ``ao.cl`` in 0.5-0.65 s and
loads its binary in 8-10 ms.

Used by :mod:`ao4d.opencl.cl` (device probes and ``build_kernels``); nothing here chooses devices.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
import warnings
from pathlib import Path

__all__ = ["build_log", "built_program", "cache_dir", "cache_key", "kernel_build_stats", "kernel_cache_dir"]

_CACHE_FORMAT = "ao4d-kernel-binary-1"
_lock = threading.Lock()
_stats = {"compiled": 0, "from_cache": 0, "cache_write_failed": 0}


def kernel_cache_dir() -> Path | None:
    """Folder where compiled kernel binaries persist across processes, or ``None``.

    ``$XDG_CACHE_HOME/ao4d/kernels`` (``~/.cache/ao4d/kernels`` when it is unset or not an
    absolute path); when that cannot be written, a per-user folder in the temporary
    directory; when neither can, ``None`` (kernels are then compiled in every process).

    Returns
    -------
    pathlib.Path or None
        The folder, or ``None``.
    """
    return cache_dir("kernels")


def cache_dir(kind: str) -> Path | None:
    """The per-user cache folder ``ao4d/<kind>`` (see :func:`kernel_cache_dir`), or ``None``."""
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if os.path.isabs(xdg) else Path.home() / ".cache"
    uid = os.getuid() if hasattr(os, "getuid") else 0
    for folder in (base / "ao4d" / kind, Path(tempfile.gettempdir()) / f"ao4d-{kind}-{uid}"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(folder, os.W_OK | os.X_OK):
            return folder
    return None


def kernel_build_stats() -> dict[str, int]:
    """Counts for this process: programs ``compiled`` from source, loaded ``from_cache``.

    Returns
    -------
    dict of str to int
        A copy of the counts.
    """
    with _lock:
        return dict(_stats)


def _runtime_settings() -> str:
    """The environment variables that change what a runtime compiles (Intel's ``CL_CONFIG_*``,
    such as ``CL_CONFIG_CPU_TARGET_ARCH``): a binary built under ``corei7-avx`` traced AO 350x
    slower, and without them in the key later processes loaded it."""
    return "\0".join(f"{k}={v}" for k, v in sorted(os.environ.items()) if k.startswith("CL_CONFIG_"))


def cache_key(device, depends: str, text: str, options: list[str]) -> str:
    """The file name (32 hex digits) of the program ``text`` built with ``options`` for ``device``."""
    from pyopencl import VERSION_TEXT as cl_version

    platform = device.platform
    parts = (
        _CACHE_FORMAT,
        depends,
        text,
        "\0".join(options),
        platform.name,
        platform.vendor,
        platform.version,
        device.name,
        device.vendor,
        device.version,
        device.driver_version,
        cl_version,  # pyopencl adds its own -I and defines to every build
        _runtime_settings(),
    )
    h = hashlib.sha256()
    for part in parts:
        h.update(str(part).encode())
        h.update(b"\0")
    return h.hexdigest()[:32]


def built_program(cl, ctx, device, depends: str, text: str, options: list[str]):
    """A built program for ``device``: from the binary cache when it holds one, else compiled.

    Parameters
    ----------
    cl : module
        pyopencl.
    ctx, device : pyopencl.Context, pyopencl.Device
        Where the program runs (a context of that one device).
    depends : str
        Everything else the build reads (the headers' text); part of the key.
    text : str
        The program source.
    options : list of str
        Build options (``-I``, ``-cl-std``, ``-D``).

    Raises
    ------
    pyopencl.RuntimeError
        The source does not compile (its message carries the log: :func:`build_log`).
    """
    folder = kernel_cache_dir()
    path = folder / f"{cache_key(device, depends, text, options)}.bin" if folder else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pyopencl warns on any non-empty build log
        if path is not None and path.is_file():
            try:
                program = cl.Program(ctx, [device], [path.read_bytes()]).build(options=options)
                with _lock:
                    _stats["from_cache"] += 1
                return program
            except Exception:  # stale or damaged entry: drop it and compile
                path.unlink(missing_ok=True)
        program = cl.Program(ctx, text).build(options=options, devices=[device], cache_dir=False)
    with _lock:
        _stats["compiled"] += 1
    if path is not None:
        from .._atomic import atomic_open

        try:
            binary = program.get_info(cl.program_info.BINARIES)[0]
            with atomic_open(path, "wb") as fh:
                fh.write(binary)
        except OSError:  # read-only or full disk: the program still works, it is just not kept
            with _lock:
                _stats["cache_write_failed"] += 1
    return program


def build_log(exc: Exception, platform: str) -> str:
    """The compiler's log from a failed pyopencl build (its message carries it).

    pyopencl also saves the source to a temporary file and names it; the source is the file in
    ``kernels/``, so that copy is removed rather than left in the temporary folder.
    """
    import re

    text = str(exc).strip()
    saved = re.search(r"\(source saved as (.+?\.cl)\)", text)
    if saved:
        copy = Path(saved.group(1))
        if copy.parent == Path(tempfile.gettempdir()) and copy.name.startswith("tmp"):
            copy.unlink(missing_ok=True)
        text = text[: saved.start()].rstrip()
    start = text.find("Build on ")
    if start >= 0:
        text = text[text.find("\n", start) + 1 :].strip()
    end = text.rfind("\n(options:")
    if end >= 0:
        text = text[:end].rstrip()
    return text or f"(the {platform} compiler gave no log)"
