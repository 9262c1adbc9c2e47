"""ao4d's dask helpers, shared by the block-wise extraction, the file readers and datasets_gen.

dask is an extra (``pip install "ao4d[dask]"``): :func:`is_dask_array` never imports it, the other
helpers import it when called.

Workers
-------
dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which makes ao4d's numpy-heavy
tasks 2-3x slower: start workers inside :func:`worker_environment` (ao4d warns once per client
otherwise: :class:`WorkerEnvironmentWarning`).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

from ._optional import require

__all__ = [
    "is_dask_array",
    "block_sizes",
    "worker_environment",
    "check_workers",
    "WorkerEnvironmentWarning",
]


@contextlib.contextmanager
def worker_environment() -> Iterator[None]:
    """Start dask workers inside this block without dask's ``MALLOC_TRIM_THRESHOLD_``.

    dask's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536`` (config key
    ``distributed.nanny.pre-spawn-environ``) so that freed memory goes back to the OS at once.
    Setting that variable also switches off glibc's adaptive mmap threshold: every numpy
    temporary above 128 KiB becomes a fresh ``mmap`` that page-faults on first touch. ao4d's
    marching (numpy temporaries of megabytes per slab) ran 1.9x slower in one such process and
    3.4x slower on a 2-worker LocalCluster here. Inside this block the variable is left out
    (the documented ``None`` override) and also kept out of this process's own environment,
    which the nanny fills in and new workers inherit::

        with ao4d.worker_environment():
            cluster = LocalCluster(n_workers=8)      # or SLURMCluster(...), KubeCluster(...)

    For ``dask worker`` processes started elsewhere (dask-jobqueue, Kubernetes), put
    ``distributed: {nanny: {pre-spawn-environ: {MALLOC_TRIM_THRESHOLD_: null}}}`` into their
    dask configuration (``~/.config/dask/distributed.yaml``), or start them with
    ``--no-nanny``.

    Yields
    ------
    None
        Start the workers inside the ``with`` block.
    """
    import os

    dask = require("dask", "worker_environment")
    saved = os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
            yield
    finally:
        os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
        if saved is not None:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = saved


class WorkerEnvironmentWarning(UserWarning):
    """The dask workers run with a malloc setting that makes block-wise extraction slow."""


_WARNED_CLIENTS: set[str] = set()


def _trim_setting() -> tuple[int, str | None]:
    """(Runs on a worker.) Its process id and ``MALLOC_TRIM_THRESHOLD_``, if set."""
    import os

    return os.getpid(), os.environ.get("MALLOC_TRIM_THRESHOLD_")


def check_workers(client: Any) -> None:
    """Warn once per client when its workers run with ``MALLOC_TRIM_THRESHOLD_`` set."""
    import warnings

    if client.id in _WARNED_CLIENTS:
        return
    _WARNED_CLIENTS.add(client.id)
    try:
        settings = client.run(_trim_setting)
    except Exception:  # noqa: BLE001  (a diagnostic only: never stop the work for it)
        return
    import os

    # workers in this very process (processes=False) started with this process's malloc
    slow = sorted(w for w, (pid, v) in settings.items() if v is not None and pid != os.getpid())
    if slow:
        warnings.warn(
            f"{len(slow)} of {len(settings)} dask workers run with MALLOC_TRIM_THRESHOLD_="
            f"{settings[slow[0]][1]} (dask's default), which made ao4d's block-wise extraction 3.4x "
            "slower here: start them inside `with ao4d.worker_environment():` (see its "
            "docstring)",
            WorkerEnvironmentWarning,
            stacklevel=5,
        )


def is_dask_array(value: Any) -> bool:
    """Whether ``value`` is a dask array (checked without importing dask).

    Parameters
    ----------
    value : object
        Anything.

    Returns
    -------
    bool
        True for a dask array.
    """
    module = sys.modules.get("dask.array")
    return module is not None and isinstance(value, module.Array)


def block_sizes(chunks: Any, shape: tuple[int, ...], *, name: str = "chunks") -> tuple[tuple[int, ...], ...]:
    """Dask's per-axis block sizes for ``chunks`` on a grid of ``shape``, else an error naming ``name``.

    Parameters
    ----------
    chunks : int, sequence of int, dask block sizes or "auto"
        Points per block (dask's ``normalize_chunks`` rules).
    shape : tuple of int
        Grid points per axis.
    name : str, optional
        The caller's parameter, named in errors.

    Returns
    -------
    tuple of tuple of int
        The sizes of the blocks along each axis.
    """
    normalize_chunks = require("dask.array.core", f"`{name}` (blocks as dask tasks)").normalize_chunks
    if isinstance(chunks, bool) or (isinstance(chunks, (int, np.integer)) and chunks < 1):
        raise ValueError(f"`{name}` must be a positive int, per-axis sizes or 'auto', got {chunks!r}")
    try:
        out = normalize_chunks(chunks, shape, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"`{name}` {chunks!r} does not fit a grid of shape {shape}: {exc}") from None
    if any(c < 1 for sizes in out for c in sizes):
        raise ValueError(f"`{name}` must be positive, got {chunks!r}")
    return out
