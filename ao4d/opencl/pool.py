"""Device buffers kept between calls: a call takes a context's set out, puts it back after.

A fresh OpenCL buffer on a CPU device costs a page fault per page on its first write (on the
project's 2-core VM a fresh 32 MiB buffer took 13 ms to write once and 1.2 ms after that; a
1.2 M-tetrahedron BVH build spent as long in the kernel's fault handling as in its own work).
Work that runs again and again in one process (``cast_rays`` launches, BVH builds for every item
of a dataset) therefore keeps its scratch here. A call takes the whole set of one context out,
so concurrent calls never share buffers (the second one allocates its own), and puts it back
when done; the set holding more bytes is the one kept, up to the pool's ``max_bytes``.
:meth:`BufferPool.clear` drops them.
"""

from __future__ import annotations

import threading
from typing import Any

__all__ = ["BufferPool", "Taken"]


class Taken:
    """One call's buffers from a :class:`BufferPool`, by name (see :meth:`BufferPool.take`).

    Parameters
    ----------
    pool : BufferPool
        The pool they go back to.
    ctx : pyopencl.Context
        Their context.
    kept : dict of str to pyopencl.Buffer
        The buffers taken out of the pool (empty when it held none).
    """

    def __init__(self, pool: BufferPool, ctx: Any, kept: dict[str, Any]) -> None:
        self._pool, self._ctx, self._buffers = pool, ctx, kept

    def get(self, name: str, nbytes: int) -> Any:
        """A read-write buffer of at least ``nbytes`` under ``name``.

        The kept one when large enough, else a new one a quarter larger (so that slowly
        growing calls reallocate seldom). Its contents are whatever an earlier call left:
        write before reading.

        Parameters
        ----------
        name : str
            The buffer's name within the call.
        nbytes : int
            Bytes it must hold.

        Returns
        -------
        pyopencl.Buffer
            The buffer.
        """
        import pyopencl as pcl

        nbytes = max(int(nbytes), 1)
        buf = self._buffers.get(name)
        if buf is None or buf.size < nbytes:
            self._buffers.pop(name, None)  # freed before the new one is allocated
            buf = self._buffers[name] = pcl.Buffer(self._ctx, pcl.mem_flags.READ_WRITE, nbytes + nbytes // 4)
        return buf

    def __enter__(self) -> Taken:
        return self

    def __exit__(self, *exc: Any) -> None:
        self._pool._give(self._ctx, self._buffers)


class BufferPool:
    """Named device buffers per OpenCL context, kept between calls.

    Parameters
    ----------
    max_bytes : int, optional
        Keep no set of more bytes than this (the memory a pool may hold while its owner is idle).

    Examples
    --------
    >>> pool = BufferPool()
    >>> with pool.take(ctx) as bufs:  # doctest: +SKIP
    ...     scratch = bufs.get("records", 48 * n)
    """

    def __init__(self, max_bytes: int | None = None) -> None:
        self.max_bytes = max_bytes  # a larger set is dropped when given back, not kept
        # id(context) -> (the context, kept so that its id is not reused; name -> buffer)
        self._kept: dict[int, tuple[Any, dict[str, Any]]] = {}
        self._lock = threading.Lock()

    def take(self, ctx: Any) -> Taken:
        """Take ``ctx``'s buffers out of the pool (none when another call holds them).

        Parameters
        ----------
        ctx : pyopencl.Context
            The context the buffers belong to.

        Returns
        -------
        Taken
            A context manager: :meth:`Taken.get` buffers by name; leaving it puts them back.
        """
        with self._lock:
            kept = self._kept.pop(id(ctx), None)
        return Taken(self, ctx, {} if kept is None else kept[1])

    def _give(self, ctx: Any, buffers: dict[str, Any]) -> None:
        if self.max_bytes is not None and _nbytes(buffers) > self.max_bytes:
            return  # too large to hold on to between calls
        with self._lock:
            kept = self._kept.get(id(ctx))
            if kept is None or _nbytes(buffers) >= _nbytes(kept[1]):
                self._kept[id(ctx)] = (ctx, buffers)

    def clear(self) -> None:
        """Drop every kept buffer (device memory)."""
        with self._lock:
            self._kept.clear()

    def nbytes(self) -> int:
        """Bytes of device memory the pool keeps.

        Returns
        -------
        int
            The sizes of every kept buffer, summed.
        """
        with self._lock:
            return sum(_nbytes(b) for _, b in self._kept.values())


def _nbytes(buffers: dict[str, Any]) -> int:
    return sum(int(b.size) for b in buffers.values())
