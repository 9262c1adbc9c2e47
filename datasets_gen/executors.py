"""Where a run's items are made: in this process, in spawned processes, or on dask.distributed.

An executor makes a list of :class:`~datasets_gen.items.Job` and counts each item made or
failed in a :class:`~datasets_gen.index.RunSummary`. Each item is made by
:func:`datasets_gen.items.make_item`, whichever the executor, so the output is the same byte
for byte:

* :class:`InProcess` and :class:`ProcessPool` (spawned processes, no fork: OpenCL state must
  not be copied) write each item into the run's store themselves;
* :class:`Dask` runs the items as tasks on a scheduler (an address, or ``"local:N"`` for a
  LocalCluster started here). A worker that sees the output (its ``run.json`` has the run's
  hash: a shared folder, a LocalCluster, an fsspec URL it reaches) writes its item there; any
  other makes it in memory and sends the files back, which this process writes
  (:func:`datasets_gen.items.write_item`).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ._store import MemoryStore, Store, is_url, open_store
from .index import RunSummary
from .items import Job, item_folder, make_item, write_item

__all__ = ["Executor", "InProcess", "ProcessPool", "Dask", "executor_for", "SCHEDULER_PROBE_SECONDS"]

# How long a scheduler address may take to accept a connection and greet it: a dask scheduler
# sends its handshake at once, so silence means something else listens there
SCHEDULER_PROBE_SECONDS = 10.0


class Executor:
    """Makes a run's items somewhere; see :class:`InProcess`, :class:`ProcessPool`, :class:`Dask`."""

    def check(self) -> None:
        """Refuse impossible settings before the output is touched (errors name the parameter)."""

    def make(self, todo: list[Job], store: Store, summary: RunSummary, bar: Any) -> None:
        """Make the items of ``todo`` into ``store``, counting each in ``summary``.

        Parameters
        ----------
        todo : list of Job
            The items to make.
        store : Store
            The run's output.
        summary : RunSummary
            Gets each item made (with its stage seconds) or failed (with its error).
        bar : progress bar
            Updated once per item (``ao4d._progress.bar``).
        """
        raise NotImplementedError


def _make_here(job: Job) -> dict[str, Any]:
    """Make an item into its run's output from this process. Top-level: spawn-safe."""
    return make_item(job, open_store(job.out))


def _collect(summary: RunSummary, job: Job, call: Callable[[], dict | None]) -> None:
    """Count the item of ``job`` made (``call()`` returned its timing) or failed (it raised)."""
    try:
        result = call()
        summary.made += 1
        summary.made_items.add(job.spec.index)
        summary.add_timing((result or {}).get("seconds", {}))
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # one bad item must not stop the dataset; reported at the end
        summary.failed[job.spec.index] = f"{type(exc).__name__}: {exc}"


@dataclass(frozen=True)
class InProcess(Executor):
    """One item after the other in this process."""

    def make(self, todo: list[Job], store: Store, summary: RunSummary, bar: Any) -> None:
        for job in todo:
            _collect(summary, job, lambda job=job: make_item(job, store))
            bar.update()


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the parent, which cancels and terminates them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# Environment variables that size a worker's thread pools (OpenBLAS, OpenMP, Intel's OpenCL
# CPU runtime); one the user set is left as it is
_THREAD_VARIABLES = (
    "OPENBLAS_NUM_THREADS",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "DPCPP_CPU_NUM_CUS",
    "CL_CONFIG_CPU_TBB_NUM_WORKERS",
)


def _start_worker(threads: int) -> None:
    """Set up a spawned worker before its first item (top-level: spawn-safe).

    ``workers`` processes on as many cores each get ``threads`` = cores // workers threads per
    pool: with every process's BLAS and OpenCL runtime spreading over every core, the pools
    spin against each other (OpenBLAS's idle threads alone took 7 % of the cycles of a 2-worker
    ``tori`` run). Freed memory is kept in the process (:func:`_keep_freed_memory`).
    """
    _ignore_sigint()
    for name in _THREAD_VARIABLES:  # read when a runtime starts: OpenCL and scipy's BLAS
        os.environ.setdefault(name, str(threads))
    if os.environ["OPENBLAS_NUM_THREADS"] == str(threads):  # numpy's BLAS is loaded already
        from ao4d._optional import require

        require("threadpoolctl", "limiting the workers' BLAS threads").threadpool_limits(threads, user_api="blas")
    _keep_freed_memory()


def _cores() -> int:
    """The cores this process may run on (its affinity: a container's share, not the host's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _keep_freed_memory() -> bool:
    """Make glibc's malloc keep freed memory for the next item instead of returning it.

    An item allocates and frees gigabytes of arrays; by default each array over 32 MiB is its
    own mapping, returned at ``free`` and faulted in (zeroed by the kernel) at the next item's
    ``malloc``: a quarter of the CPU time of a ``tori`` run was the kernel zeroing pages. With
    no mappings and no trimming, the heap grows to the largest item's peak and stays there.
    Elsewhere than glibc this does nothing.

    Returns
    -------
    bool
        Whether glibc took the settings.
    """
    import ctypes
    import ctypes.util

    m_trim_threshold, m_mmap_max = -1, -4  # glibc's <malloc.h>
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(m_mmap_max, 0)) and bool(mallopt(m_trim_threshold, 2**31 - 1))


@dataclass(frozen=True)
class ProcessPool(Executor):
    """Items in ``workers`` spawned processes, each writing its items into the output.

    Attributes
    ----------
    workers : int
        Processes (at most one per item).
    """

    workers: int

    def make(self, todo: list[Job], store: Store, summary: RunSummary, bar: Any) -> None:
        if len(todo) <= 1:  # no process to start for one item
            InProcess().make(todo, store, summary, bar)
            return
        context = multiprocessing.get_context("spawn")  # no fork: OpenCL state must not be copied
        workers = min(self.workers, len(todo))
        threads = max(1, _cores() // workers)
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=context, initializer=_start_worker, initargs=(threads,)
        ) as pool:
            pending: dict[Future, Job] = {pool.submit(_make_here, job): job for job in todo}
            try:
                while pending:
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        job = pending.pop(fut)
                        _collect(summary, job, fut.result)
                        bar.update()
            except KeyboardInterrupt:
                processes = list((getattr(pool, "_processes", None) or {}).values())
                pool.shutdown(wait=False, cancel_futures=True)
                for proc in processes:
                    proc.terminate()  # their unfinished items are redone on the next run
                raise


def _make_on_worker(job: Job) -> dict[str, Any]:
    """Make an item on a dask worker, into the output itself when the worker sees it.

    The worker sees the output when its ``run.json`` has ``job.run_sha256``: it makes the
    item there as in one process and returns ``{"seconds": ..., "written": True}``. Otherwise
    it makes the item in memory and returns ``{"seconds": ..., "files": {name: bytes}}`` for
    the client to write.
    """
    try:
        store = open_store(job.out)
        sees = bool(job.run_sha256) and store.sha256("run.json") == job.run_sha256
    except (OSError, ValueError):
        sees = False
    if sees:
        return {**make_item(job, store), "written": True}
    scratch = MemoryStore()
    made = make_item(job, scratch)
    rel = item_folder(job.spec.index)
    files = {name: scratch.read_bytes(f"{rel}/{name}") for name in scratch.files(rel)}
    if "record.json" not in files:
        raise RuntimeError(f"item {job.spec.index} left no record.json")
    return {**made, "files": files}


@dataclass(frozen=True)
class Dask(Executor):
    """Items as tasks on a dask.distributed scheduler.

    Attributes
    ----------
    scheduler : str
        The scheduler's address (``"tcp://host:8786"``), or ``"local:N"`` for a LocalCluster
        of N worker processes of one thread, started and stopped here.
    workers_write : bool
        Let the workers that see the output write their items there (default); False has
        every item's bytes sent back to this process, as for workers without the output.
    probe_seconds : float
        How long a ``tcp://`` address may take to greet a connection before it is refused
        as not a dask scheduler.
    local_workers : int or None
        N of ``"local:N"``, None for an address: ``scheduler`` parsed once, when the executor
        is made (a malformed one is refused then).
    """

    scheduler: str
    workers_write: bool = True
    probe_seconds: float = SCHEDULER_PROBE_SECONDS
    local_workers: int | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "local_workers", _parse_scheduler(self.scheduler))

    def check(self) -> None:
        if self.local_workers is None:
            _probe_scheduler(self.scheduler, self.probe_seconds)

    def make(self, todo: list[Job], store: Store, summary: RunSummary, bar: Any) -> None:
        import uuid

        from distributed import Client, LocalCluster, as_completed

        count = self.local_workers
        cluster = None
        try:
            if count is not None:
                from ao4d import worker_environment

                # glibc's default malloc in the workers: dask's MALLOC_TRIM_THRESHOLD_ slows numpy
                with worker_environment():
                    cluster = LocalCluster(
                        n_workers=count, threads_per_worker=1, processes=True, dashboard_address=":0"
                    )
                client = Client(cluster)
            else:
                client = Client(self.scheduler)  # waits distributed.comm.timeouts.connect (30 s)
        except (OSError, TimeoutError) as exc:
            if cluster is not None:
                cluster.close()
            raise ValueError(f"cannot reach the dask scheduler at `scheduler` {self.scheduler!r}: {exc}") from None
        run_id = uuid.uuid4().hex[:8]
        futures: dict[Any, Job] = {}
        try:
            for job in todo:
                key = f"datasets_gen-item-{job.spec.index:05d}-{run_id}"
                where = job.out if is_url(job.out) else str(Path(job.out).resolve())
                task = dataclasses.replace(job, out=where, run_sha256=job.run_sha256 if self.workers_write else "")
                futures[client.submit(_make_on_worker, task, key=key, pure=False)] = job
            for future in as_completed(list(futures)):
                job = futures[future]

                def write(future=future, job=job) -> dict:
                    result = future.result()
                    if "files" in result:  # made in the worker's memory: written here
                        write_item(store, job.spec.index, result["files"])
                        summary.received += sum(len(b) for b in result["files"].values())
                    return result

                _collect(summary, job, write)
                future.release()
                bar.update()
        except KeyboardInterrupt:
            client.cancel(list(futures))  # unfinished items are redone on the next run
            raise
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def executor_for(workers: int = 1, scheduler: str | None = None) -> Executor:
    """The executor of :func:`datasets_gen.run`'s ``workers`` and ``scheduler``.

    Parameters
    ----------
    workers : int
        Processes; 1 makes the items in this process.
    scheduler : str, optional
        A dask scheduler's address or ``"local:N"`` (then ``workers`` must be 1).

    Returns
    -------
    Executor
        :class:`Dask`, :class:`ProcessPool` or :class:`InProcess`.

    Raises
    ------
    TypeError, ValueError
        A malformed ``scheduler``, or both ``workers`` and ``scheduler`` given.
    """
    if scheduler is not None:
        executor = Dask(scheduler)  # a malformed address is refused here
        if workers != 1:
            raise ValueError(f"give `workers` ({workers}) or `scheduler` ({scheduler!r}), not both")
        return executor
    return ProcessPool(workers) if workers > 1 else InProcess()


def _parse_scheduler(scheduler: Any) -> int | None:
    """The worker count of ``"local:N"``, None for an address; errors name the parameter."""
    if not isinstance(scheduler, str) or not scheduler.strip():
        raise TypeError(f"`scheduler` must be an address or 'local:N', got {scheduler!r}")
    if scheduler.startswith("local:"):
        count = scheduler[len("local:") :]
        if not count.isdigit() or int(count) < 1:
            raise ValueError(f"`scheduler` 'local:N' needs a worker count N >= 1, got {scheduler!r}")
        return int(count)
    return None


# A dask handshake is well under this; a first word beyond it is not dask's protocol (an HTTP
# reply read as a frame length asks for exbibytes)
_HANDSHAKE_MAX_BYTES = 1 << 20


def _probe_scheduler(scheduler: str, seconds: float = SCHEDULER_PROBE_SECONDS) -> None:
    """Fail fast, with a clear message, when a ``tcp://`` address is not a dask scheduler.

    dask's own connect timeout covers only the TCP connection: a listener that accepts and
    never answers stalls the client for minutes, and an HTTP server's reply is read as a frame
    length (``Unable to allocate 3.07 EiB``). A dask scheduler writes its handshake, an 8-byte
    length and a small message, as soon as it accepts; this reads those 8 bytes and closes.
    Other protocols (``tls://``, ``ucx://``, ``inproc://``) are left to dask; ``scheduler``
    is an address, not ``"local:N"``.
    """
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(scheduler if "://" in scheduler else f"tcp://{scheduler}")
    if parts.scheme != "tcp":
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if not host or port is None:
        raise ValueError(f"`scheduler` {scheduler!r} is not an address of the form tcp://HOST:PORT (or 'local:N')")
    where = f"the dask scheduler at `scheduler` {scheduler!r}"
    wait = seconds
    try:
        sock = socket.create_connection((host, port), timeout=wait)
    except OSError as exc:
        raise ValueError(f"cannot reach {where}: {exc}") from None
    head = b""
    with sock:
        try:
            while len(head) < 8:
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    break
                head += chunk
        except TimeoutError:
            pass
        except OSError as exc:
            raise ValueError(f"cannot reach {where}: {exc}") from None
    if not head:
        raise ValueError(
            f"cannot reach {where}: it accepted the connection but sent nothing in "
            f"{wait:g} s (a dask scheduler greets every connection at once); is it a "
            "dask scheduler's address (usually port 8786)?"
        )
    if head[:5].upper() in (b"HTTP/", b"<HTML", b"<!DOC") or not (
        len(head) == 8 and 0 < int.from_bytes(head, "little") <= _HANDSHAKE_MAX_BYTES
    ):
        kind = "an HTTP server" if head[:5].upper() == b"HTTP/" else "something else"
        raise ValueError(
            f"cannot use {where}: it answers like {kind}, not a dask scheduler "
            f"(first bytes {head!r}); is it the dashboard's port (8787) instead of "
            "the scheduler's (8786)?"
        )
