"""Load the bundled Intel OpenCL runtime's own TBB before another library can load an older one.

Intel's CPU runtime from PyPI (``<prefix>/lib/libintelocl.so``) needs ``libtbb.so.12`` from the
same folder (the ``tbb`` wheel), and uses TBB functions that older TBB releases lack. The dynamic
loader resolves a library by its soname: once *any* ``libtbb.so.12`` is in the process, every
later request for that name gets that copy. Open3D ships an older ``libtbb.so.12`` of its own; when
it is imported first, loading Intel's runtime fails with an undefined TBB symbol, the ICD loader
drops the platform without a word, and ``clGetPlatformIDs`` answers ``PLATFORM_NOT_FOUND_KHR``.

So ``import ao4d`` loads the runtime's TBB first (``RTLD_GLOBAL``, as ``LD_PRELOAD`` would).
Libraries imported afterwards that need ``libtbb.so.12`` get this newer copy, which oneTBB keeps
binary compatible with older 2021+ releases. Where another copy is already loaded, nothing is
loaded (two copies of TBB in one process would be worse) and :func:`foreign_tbb` names it so
that discovery can say why the platform is missing and what to do.

Costs at import: one ``stat`` when the runtime is absent; otherwise importing ``ctypes`` and
mapping the library, a few milliseconds (the benchmarks log has the figures). It imports
neither pyopencl nor anything that touches a device. ``AO4D_PRELOAD_TBB=0`` turns it off.
"""

from __future__ import annotations

import os
import sys

__all__ = ["foreign_tbb", "mapped_libraries", "preload_runtime_tbb", "preload_state", "runtime_lib_dir"]

_RUNTIME = "libintelocl.so"
_TBB = "libtbb.so.12"
_state: dict[str, object] = {"status": "not tried"}


def runtime_lib_dir() -> str | None:
    """Folder of the Intel CPU runtime installed in this Python's prefix, or ``None``.

    A venv's own copy wins over the base interpreter's (registering both would list the same
    device twice).
    """
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        lib = os.path.join(prefix, "lib")
        if os.path.isfile(os.path.join(lib, _RUNTIME)):
            return os.path.realpath(lib)
    return None


def mapped_libraries() -> list[str]:
    """Paths of the shared objects mapped into this process (``/proc/self/maps``), in load order.

    Empty where ``/proc`` is not available.
    """
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return []
    paths: dict[str, None] = {}
    for line in lines:
        parts = line.split(None, 5)
        if len(parts) == 6 and parts[5].startswith("/") and ".so" in parts[5]:
            paths[parts[5].removesuffix(" (deleted)")] = None
    return list(paths)


def _is_tbb(path: str) -> bool:
    # libtbb.so.12, libtbb.so.12.20 (or an unversioned libtbb.so); not libtbbmalloc/libtbbbind,
    # and not TBB 2020's libtbb.so.2, whose other soname does not clash
    name = os.path.basename(path)
    return name == "libtbb.so" or name.startswith(_TBB)


def foreign_tbb(lib_dir: str | None = None) -> list[str]:
    """``libtbb`` copies mapped into this process that are not the runtime's own.

    Parameters
    ----------
    lib_dir : str, optional
        The runtime's folder; by default :func:`runtime_lib_dir`. Returns ``[]`` when no
        bundled runtime exists (nothing to conflict with).
    """
    lib_dir = lib_dir or runtime_lib_dir()
    if lib_dir is None:
        return []
    own = os.path.realpath(lib_dir)
    return [p for p in mapped_libraries() if _is_tbb(p) and os.path.dirname(os.path.realpath(p)) != own]


def preload_runtime_tbb() -> dict[str, object]:
    """Load the Intel runtime's ``libtbb.so.12`` now, unless it is absent or another is loaded.

    Called by ``import ao4d``; safe to call again (it does the work once). Never raises.

    Returns
    -------
    dict
        :func:`preload_state`: ``status`` is one of ``"loaded"``, ``"no runtime"``, ``"disabled"``,
        ``"foreign tbb"`` (another copy was already loaded: ``foreign`` lists it) or ``"failed"``
        (``error`` says why); ``path`` is the runtime's TBB when there is one.
    """
    if _state["status"] != "not tried":
        return dict(_state)
    lib_dir = runtime_lib_dir()
    if lib_dir is None or not os.path.isfile(os.path.join(lib_dir, _TBB)):
        _state["status"] = "no runtime"
        return dict(_state)
    path = os.path.join(lib_dir, _TBB)
    _state["path"] = path
    if os.environ.get("AO4D_PRELOAD_TBB", "").strip().lower() in ("0", "no", "false", "off"):
        _state["status"] = "disabled"
        return dict(_state)
    import ctypes

    try:  # cheap test by soname first; the maps scan only when some libtbb.so.12 is present
        ctypes.CDLL(_TBB, mode=os.RTLD_NOLOAD)
        already = True
    except OSError:
        already = False
    if already:
        foreign = foreign_tbb(lib_dir)
        if foreign:
            _state.update(status="foreign tbb", foreign=foreign)
            return dict(_state)
    try:
        ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
        _state["status"] = "loaded"
    except OSError as exc:
        _state.update(status="failed", error=str(exc))
    return dict(_state)


def preload_state() -> dict[str, object]:
    """What :func:`preload_runtime_tbb` did in this process (a copy)."""
    return dict(_state)
