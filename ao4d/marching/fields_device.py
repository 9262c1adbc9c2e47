"""The shape library's fields sampled on the OpenCL device (``kernels/marching/fields.cl``), where the
grid is marched.

A :class:`ao4d.fields.Field` built by :mod:`ao4d.fields` (primitives, CSG, smooth union,
translations, rotations, scaling, metaballs, gyroid, ground) carries ``program``, an expression
tree of its operations. Here that tree becomes an OpenCL function (one generated function per
node, calling the primitives of ``kernels/marching/fields.cl``; the parameters in a constant buffer, so a
program is built once per shape of tree), and a kernel samples it on a slab of grid layers:

* :func:`ao4d.marching.march.extract_field` hands the device engine (:mod:`ao4d.marching.cells_device`) slabs that
  are sampled straight into the engine's value buffer: the host never holds the grid's values
  (:func:`reader`); the numpy engine gets the same values sampled on the device and downloaded.
* Any other callable (no ``program``, or a tree with a plain callable in it), a device without
  ``cl_khr_fp64`` (or :data:`ao4d.marching.cells_device.FLOAT32` set) and ``backend="numpy"`` keep the
  host's sampling (:func:`ao4d.fields.evaluate_layers`).

Exactness: the kernel evaluates in double with numpy's operations in numpy's order and no
contraction (``#pragma OPENCL FP_CONTRACT OFF``). +, -, *, /, sqrt and comparisons are correctly
rounded on both sides; numpy's ``einsum`` sums of squares are summed in the order the host's
numpy takes (two SIMD lanes or index order: :func:`host_matches` checks), and ``hypot`` is
glibc's (2.35 and later), which numpy calls. So the values are the host's bit for bit wherever
:func:`host_matches` is true, and the extracted mesh is the host-sampled one, array for array.
Two kinds of node use the device's own transcendental functions, which OpenCL does not require
to be correctly rounded: ``metaballs`` (``exp``) and ``gyroid`` (``sin``, ``cos``). Measured on
Intel's CPU runtime against numpy 2.4 (AVX-512) on 2.9 million random points: ``exp`` gave
numpy's bits every time (metaballs are tested bit for bit where the probe passes), ``sin`` and
``cos`` did not: the gyroid's values (sums of four products of magnitude at most 1) differ by up
to 5 units of 2^-52 (``TRANSCENDENTAL_ULPS`` = 8 is the tested bound), and the meshes of generic
levels have the same simplices with vertices within 1e-12 of the host-sampled ones.

Non-finite values are caught on the device (a flag per slab); the slab is then downloaded and
checked on the host, which names the first bad point as host sampling does.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..opencl import cl

__all__ = ["TRANSCENDENTAL_ULPS", "device_source", "host_matches", "reader", "sample_layers"]

#: The bound, in units of 2^-52, on the difference between the device's and numpy's values of
#: the gyroid (the device's ``sin`` and ``cos``; measured: at most 5); elsewhere 0 (bit for bit).
TRANSCENDENTAL_ULPS = 8

_FIXED_4D = {"spheritorus": 2, "torisphere": 2, "ditorus": 3, "tiger": 3, "duocylinder": 2, "gyroid": 2}
_lock = threading.Lock()
_built: dict[tuple[int, str], Any] = {}  # (context id, source) -> the sample kernel
_matches: dict[str, Any] = {}


# -- the host's numpy, mirrored -----------------------------------------------------------------


def _glibc_hypot(x: float, y: float) -> float:
    """glibc's ``hypot`` (2.35 and later, no FMA) for finite x, y: the kernel's ``np_hypot``."""
    x, y = abs(x), abs(y)
    ax, ay = (y, x) if x < y else (x, y)
    scale, large, tiny, eps = 2.0**-600, 2.0**511, 2.0**-459, 2.0**-54
    if ax > large:
        return ax + ay if ay <= ax * eps else _hypot_kernel(ax * scale, ay * scale) / scale
    if ay < tiny:
        return ax + ay if ax >= ay / eps else _hypot_kernel(ax / scale, ay / scale) * scale
    return ax + ay if ay <= ax * eps else _hypot_kernel(ax, ay)


def _hypot_kernel(ax: float, ay: float) -> float:
    h = math.sqrt(ax * ax + ay * ay)
    if h <= 2.0 * ay:
        delta = h - ay
        t1 = ax * (2.0 * delta - ax)
        t2 = (delta - 2.0 * (ax - ay)) * delta
    else:
        delta = h - ax
        t1 = 2.0 * delta * (ax - 2.0 * ay)
        t2 = (4.0 * delta - ay) * ay + delta * delta
    return h - (t1 + t2) / (2.0 * h)


def _sumsq(x: Sequence[float], lanes: int) -> float:
    """Sum of squares in the order of ``fields.cl``'s ``sumsq`` with SUMSQ_LANES ``lanes``."""
    if lanes == 1:
        total = 0.0
        for v in x:
            total = total + v * v
        return total
    even = odd = 0.0
    for i, v in enumerate(x):
        if i % 2:
            odd = odd + v * v
        else:
            even = even + v * v
    return even + odd


def host_matches() -> dict[str, Any]:
    """How the host's numpy sums squares and whether its ``hypot`` is glibc's: probed once.

    Returns
    -------
    dict
        ``"lanes"``: 2 or 1, the order of ``einsum`` sums of squares the kernels mirror (2 where
        neither matches), ``"einsum"``: whether one matched, ``"hypot"``: whether ``np.hypot``
        is glibc's; ``"exact"``: both (the device's values are then the host's bit for bit,
        except ``exp``, ``sin``, ``cos``).
    """
    with _lock:
        if not _matches:
            rng = np.random.default_rng(12345)
            pts = rng.standard_normal((4096, 4)) * rng.uniform(0.01, 100.0, (4096, 1))
            found = None
            for lanes in (2, 1):
                ok = all(
                    np.array_equal(np.einsum("...i,...i->...", sub, sub), [_sumsq(row, lanes) for row in sub.tolist()])
                    for sub in (pts[:, :2], pts[:, :3], pts, np.ascontiguousarray(pts[:, :3]))
                )
                if ok:
                    found = lanes
                    break
            a, b = pts[:, 0], pts[:, 1] * rng.uniform(1e-3, 1e3, 4096)
            hyp = np.array_equal(np.hypot(a, b), [_glibc_hypot(x, y) for x, y in zip(a.tolist(), b.tolist())])
            _matches.update(lanes=found or 2, einsum=found is not None, hypot=hyp, exact=found is not None and hyp)
        return dict(_matches)


# -- the expression tree as OpenCL ------------------------------------------------------------


def _primitive_ok(op: str, params: tuple, dim: int) -> bool:
    """Whether a primitive node has the parameters the kernel reads for a ``dim``-D grid."""
    if op in _FIXED_4D:
        return dim == 4 and len(params) == _FIXED_4D[op]
    if op == "hypersphere":
        return len(params) == 1 + dim
    if op == "tesseract":
        return len(params) == 3 and params[2] == dim
    if op == "metaballs":
        return len(params) >= 2 + dim + 1 and params[1] == dim and (len(params) - 2) % (dim + 1) == 0
    if op == "ground":
        return len(params) == 3 and params[2] == dim and 0 <= params[1] < dim
    return False


def _emit(node: Any, dim: int, funcs: list[str], prm: list[float]) -> str | None:
    """Append the OpenCL function of ``node`` (children first) to ``funcs``; its name, or None
    when the tree holds something the kernel cannot evaluate for a ``dim``-D grid."""
    try:
        op, params, kids = node
        params = tuple(float(x) for x in params)
    except (TypeError, ValueError):
        return None
    names = []
    for kid in kids:
        name = _emit(kid, dim, funcs, prm)
        if name is None:
            return None
        names.append(name)
    base = len(prm)
    prm.extend(params)
    q = f"prm + {base}"
    loop = "double q[DIM];\n    for (int i = 0; i < DIM; ++i) "
    if op in ("union", "intersection") and names:
        how = "np_min" if op == "union" else "np_max"
        body = (
            f"double v = {names[0]}(p, prm);\n"
            + "".join(f"    v = {how}(v, {n}(p, prm));\n" for n in names[1:])
            + "    return v;"
        )
    elif op == "difference" and len(names) == 2 and not params:
        body = f"return np_max({names[0]}(p, prm), -{names[1]}(p, prm));"
    elif op == "smooth_union" and len(names) == 2 and len(params) == 1:
        body = (
            f"const double k = prm[{base}];\n"
            f"    const double fa = {names[0]}(p, prm), fb = {names[1]}(p, prm);\n"
            "    const double h = np_clip01(0.5 + 0.5 * (fb - fa) / k);\n"
            "    return fb * (1.0 - h) + fa * h - k * h * (1.0 - h);"
        )
    elif op == "translate" and len(names) == 1 and len(params) == dim:
        body = f"{loop}q[i] = p[i] - prm[{base} + i];\n    return {names[0]}(q, prm);"
    elif op == "scale" and len(names) == 1 and len(params) == 1:
        body = f"const double s = prm[{base}];\n    {loop}q[i] = p[i] / s;\n    return s * {names[0]}(q, prm);"
    elif op == "rotate" and len(names) == 1 and len(params) == 5:
        i, j = int(params[0]), int(params[1])
        if not (0 <= i < dim and 0 <= j < dim and i != j):
            return None
        c, s, ms = (f"prm[{base + k}]" for k in (2, 3, 4))
        body = (
            f"{loop}q[i] = p[i];\n    q[{i}] = {c} * p[{i}] + {s} * p[{j}];\n"
            f"    q[{j}] = {ms} * p[{i}] + {c} * p[{j}];\n    return {names[0]}(q, prm);"
        )
    elif not names and _primitive_ok(op, params, dim):
        extra = f", {(len(params) - 2) // (dim + 1)}" if op == "metaballs" else ""
        body = f"return f_{op}(p, {q}{extra});"
    else:
        return None
    name = f"node{len(funcs)}"
    funcs.append(f"inline double {name}(const double *p, __constant const double *prm)\n{{\n    {body}\n}}\n")
    return name


def device_source(field: Any, dim: int) -> tuple[str, np.ndarray] | None:
    """The generated part of the sampling program for ``field`` on a ``dim``-D grid.

    Parameters
    ----------
    field : callable
        A field; only :class:`ao4d.fields.Field` objects with a ``program`` qualify.
    dim : int
        The grid's dimension.

    Returns
    -------
    (str, (P,) float64 ndarray) or None
        The OpenCL source appended to ``kernels/marching/fields.cl`` (it defines ``field_value``) and the
        parameters it reads; ``None`` when the field must be sampled on the host.
    """
    program = getattr(field, "program", None)
    if program is None or getattr(field, "dim", dim) not in (None, dim):
        return None
    funcs: list[str] = []
    prm: list[float] = []
    top = _emit(program, dim, funcs, prm)
    if top is None:
        return None
    funcs.append(
        f"double field_value(const double *p, __constant const double *prm)\n{{\n    return {top}(p, prm);\n}}\n"
    )
    return "".join(funcs), np.array(prm or [0.0], dtype=np.float64)


def _kernel(runtime: cl.Runtime, generated: str, dim: int) -> Any:
    """The ``sample_field`` kernel of ``kernels/marching/fields.cl`` with ``generated`` appended, built once
    per context and source (and kept in the binary cache across processes)."""
    from .._resources import data_dir
    from ..opencl import binaries as _kernel_binaries

    lanes = host_matches()["lanes"]
    text = (
        f"#define DIM {dim}\n#define SUMSQ_LANES {lanes}\n"
        + (data_dir("kernels") / "marching/fields.cl").read_text()
        + "\n"
        + generated
    )
    key = (id(runtime.context), text)
    with _lock:
        if key not in _built:
            import pyopencl as clmod

            options = ["-cl-std=CL1.2"]
            try:
                program = _kernel_binaries.built_program(
                    clmod, runtime.context, runtime.device, "marching/fields.cl", text, options
                )
            except clmod.RuntimeError as exc:
                raise RuntimeError(
                    f"building OpenCL kernels fields.cl for {runtime.name} failed; compiler log:\n"
                    f"{_kernel_binaries.build_log(exc, runtime.report.platform)}"
                ) from None
            _built[key] = program.sample_field
        return _built[key]


def usable(runtime: cl.Runtime | None) -> bool:
    """Whether fields may be sampled on ``runtime``: it exists, has ``cl_khr_fp64``, and
    :data:`ao4d.marching.cells_device.FLOAT32` (the path of devices without it) is not set."""
    from . import cells_device

    return runtime is not None and not cells_device.FLOAT32 and "cl_khr_fp64" in runtime.device.extensions


class _Sampler:
    """One field on one grid: the kernel's arguments, and slabs sampled into device buffers."""

    def __init__(
        self,
        generated: str,
        params: np.ndarray,
        axes: Sequence[np.ndarray],
        check: Callable[[np.ndarray, int], None] | None,
        first: list[float] | None,
    ) -> None:
        self.generated, self.params = generated, params
        self.axes = [np.asarray(a, dtype=np.float64) for a in axes]
        self.dim = len(self.axes)
        self.inner = tuple(len(a) for a in self.axes[:-1])
        self.offsets = np.cumsum([0] + [len(a) for a in self.axes])[:-1]
        self.check, self.first = check, first
        self._bufs: dict[int, tuple[Any, Any, Any, Any]] = {}

    def _buffers(self, runtime: cl.Runtime) -> tuple[Any, Any, Any, Any]:
        key = id(runtime.context)
        if key not in self._bufs:
            import pyopencl as clmod

            mf = clmod.mem_flags
            ro = mf.READ_ONLY | mf.COPY_HOST_PTR
            self._bufs[key] = (
                _kernel(runtime, self.generated, self.dim),
                clmod.Buffer(runtime.context, ro, hostbuf=np.concatenate(self.axes)),
                clmod.Buffer(runtime.context, ro, hostbuf=self.params),
                clmod.Buffer(runtime.context, mf.READ_WRITE, 4),
            )
        return self._bufs[key]

    def shape(self, a: int, b: int) -> tuple[int, ...]:
        return (b - a, *self.inner)

    def fill(self, runtime: cl.Runtime, buffer: Any, a: int, b: int) -> None:
        """Sample layers [a, b) into the device ``buffer`` (float64, the slab's C order); check
        that every value is finite, and record the grid's first value when ``a == 0``."""
        import pyopencl as clmod

        queue = runtime.queue
        kernel, axes, prm, bad = self._buffers(runtime)
        shape = self.shape(a, b)
        inner = self.inner
        grid = (
            (inner[0], b - a, 1)
            if self.dim == 2
            else (inner[1], inner[0], b - a)
            if self.dim == 3
            else (inner[2], inner[1], (b - a) * inner[0])
        )
        offs = [np.int32(x) for x in (list(self.offsets) + [0] * 4)[:4]]
        flag = np.zeros(1, dtype=np.int32)
        clmod.enqueue_copy(queue, bad, flag, is_blocking=False)
        kernel(queue, grid, None, buffer, axes, prm, np.int32(inner[0]), *offs, np.int32(a), bad)
        clmod.enqueue_copy(queue, flag, bad, is_blocking=True)
        if flag[0] and self.check is not None:
            values = np.empty(shape, dtype=np.float64)
            clmod.enqueue_copy(queue, values, buffer, is_blocking=True)
            self.check(values, a)
        if a == 0 and self.first is not None:
            corner = np.empty(1, dtype=np.float64)
            clmod.enqueue_copy(queue, corner, buffer, is_blocking=True)
            self.first.append(float(corner[0]))

    def download(self, runtime: cl.Runtime, a: int, b: int) -> np.ndarray:
        """Layers [a, b) sampled on the device, as a host array."""
        import pyopencl as clmod

        values = np.empty(self.shape(a, b), dtype=np.float64)
        buffer = clmod.Buffer(runtime.context, clmod.mem_flags.READ_WRITE, max(values.nbytes, 8))
        try:
            self.fill(runtime, buffer, a, b)
            clmod.enqueue_copy(runtime.queue, values, buffer, is_blocking=True)
        finally:
            buffer.release()
        return values


class _DeviceSlab:
    """Layers [a, b) of a field's grid, sampled when the device engine asks: it has the array
    attributes the engine reads (``shape``, ``dtype``, ``size``, ``nbytes``, ``ndim``) and
    ``fill_device(runtime, buffer)``, which samples into the engine's value buffer."""

    dtype = np.dtype(np.float64)

    def __init__(self, sampler: _Sampler, a: int, b: int) -> None:
        self.sampler, self.a, self.b = sampler, a, b
        self.shape = sampler.shape(a, b)
        self.ndim = len(self.shape)
        self.size = math.prod(self.shape)
        self.nbytes = self.size * 8

    def fill_device(self, runtime: cl.Runtime, buffer: Any) -> None:
        self.sampler.fill(runtime, buffer, self.a, self.b)


class _Reader:
    """``read(a, b)`` for the device engine (slabs sampled into its buffers); ``host`` is the
    reader for the numpy engine (the same values, sampled on the device and downloaded)."""

    def __init__(self, sampler: _Sampler, runtime: cl.Runtime) -> None:
        self.sampler, self.runtime = sampler, runtime

    def __call__(self, a: int, b: int) -> _DeviceSlab:
        return _DeviceSlab(self.sampler, a, b)

    def host(self, a: int, b: int) -> np.ndarray:
        return self.sampler.download(self.runtime, a, b)


def reader(
    field: Callable,
    axes: Sequence[np.ndarray],
    backend: str,
    host_read: Callable[[int, int], np.ndarray],
    *,
    check: Callable[[np.ndarray, int], None] | None = None,
    first: list[float] | None = None,
) -> Callable[[int, int], Any]:
    """The slab reader of :func:`ao4d.marching.march.extract_field`: on the device where it can be.

    Parameters
    ----------
    field : callable
        The field.
    axes : sequence of (n_k,) float64 arrays
        The grid's coordinates per axis (:func:`ao4d.fields.grid_axes`).
    backend : {"auto", "opencl", "numpy"}
        As for :func:`ao4d.marching.march.extract_field` (validated there).
    host_read : callable
        ``host_read(a, b)``: the host's sampled layers, returned where the field or the device
        does not qualify (:func:`device_source`, :func:`usable`).
    check : callable, optional
        ``check(values, a)``: called with a slab's values (layers from ``a``) when one of them
        is not finite; expected to raise.
    first : list, optional
        Gets the grid's first value appended when layer 0 is sampled.

    Returns
    -------
    callable
        ``host_read`` itself, or a reader whose slabs the device engine samples into its own
        buffers (:class:`ao4d.marching.cells_device` calls their ``fill_device``) and whose ``host``
        attribute reads host arrays sampled on the device (for the numpy engine).
    """
    if backend == "numpy":
        return host_read
    found = device_source(field, len(axes))
    if found is None:
        return host_read
    runtime = cl.resolve_backend(backend, warn=False)
    if not usable(runtime):
        return host_read
    return _Reader(_Sampler(*found, axes, check, first), runtime)


def sample_layers(
    field: Callable, axes: Sequence[np.ndarray], start: int, stop: int, runtime: cl.Runtime | None = None
) -> np.ndarray:
    """:func:`ao4d.fields.evaluate_layers` on the device: the same layout and values.

    Parameters
    ----------
    field : Field
        A field with a device program (:func:`device_source` not None).
    axes : sequence of (n_k,) float64 arrays
        The grid's coordinates per axis.
    start, stop : int
        The layers (last-axis indices) to sample.
    runtime : ao4d.opencl.cl.Runtime, optional
        The device; default the chosen one (:func:`ao4d.opencl.cl.get_runtime`).

    Returns
    -------
    (stop - start, n_0, ..., n_{d-2}) float64 ndarray
        The values, the grid's last axis first.

    Raises
    ------
    ValueError
        ``field`` has no device program for this grid, or ``start, stop`` is not a range of
        layers.
    RuntimeError
        No OpenCL device with ``cl_khr_fp64``.
    """
    found = device_source(field, len(axes))
    if found is None:
        raise ValueError(f"`field` {field!r} has no device program for a {len(axes)}D grid")
    if not 0 <= start < stop <= len(axes[-1]):
        raise ValueError(f"`start`, `stop` must be layers 0 <= start < stop <= {len(axes[-1])}, got {start}, {stop}")
    runtime = runtime if runtime is not None else cl.get_runtime(warn=False)
    if not usable(runtime):
        raise RuntimeError("sampling fields on the device needs an OpenCL device with cl_khr_fp64")
    return _Sampler(*found, axes, None, None).download(runtime, start, stop)
