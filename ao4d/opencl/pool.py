"""Device buffers kept between calls: a call takes a context's set out, puts it back after.

A fresh OpenCL buffer on a CPU device costs a page fault per page on its first write (on the
project's 2-core VM a fresh 32 MiB buffer took 13 ms to write once and 1.2 ms after that; a
1.2 M-tetrahedron BVH build spent as long in the kernel's fault handling as in its own work).
Work that runs again and again in one process (``cast_rays`` launches, BVH builds for every item
of a dataset) therefore keeps its scratch here. A call takes the whole set of one context out,
so concurrent calls never share buffers (the second one allocates its own), and puts it back
when done; the set holding more bytes is the one kept, up to the pool's ``max_bytes``.
:meth:`BufferPool.clear` drops them.

Buffers that outlive a call (a BVH's leaf blocks and node arrays, the build's copies of the
mesh) come from a :class:`Recycler` instead: they go back when their owner (the tree) is
collected, and the next owner of a context takes the smallest held buffer that fits. A dataset
run builds one tree per item; without it every build faulted in its tree afresh (a 3.3 M-tet
tree's 480 MB: 117 000 page faults, a quarter of the build's wall time on the project's VM).
"""

from __future__ import annotations

import threading
import weakref
from typing import Any

__all__ = ["BufferPool", "Taken", "Recycler", "RECYCLE_MIN_BYTES", "TREES"]

# smaller buffers are allocated afresh: their faults cost microseconds, and holding them would
# only fragment the recycler's list
RECYCLE_MIN_BYTES = 1 << 20


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


class Recycler:
    """Device buffers that outlive one call, handed on to the next owner instead of freed.

    :meth:`get` gives the smallest held buffer of the context that holds ``nbytes`` (else a new
    one, a quarter larger, so that slowly growing owners reallocate seldom); :meth:`give` and
    :meth:`give_when` put buffers back. Held buffers beyond ``max_bytes`` are freed, the
    smallest first (the large ones cost most to fault in again).

    Parameters
    ----------
    max_bytes : int
        The most bytes held while no owner uses them.

    Examples
    --------
    >>> recycler = Recycler(max_bytes=1 << 30)
    >>> blocks = recycler.get(ctx, 4 * n)  # doctest: +SKIP
    >>> recycler.give_when(tree, ctx, blocks)  # back when `tree` is collected  # doctest: +SKIP
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        # the context's handle (int_ptr: its Python wrappers differ, queue.context is a new
        # one) -> (the context, kept so that the handle is not reused; held buffers)
        self._held: dict[int, tuple[Any, list[Any]]] = {}
        self._lock = threading.Lock()

    def get(self, ctx: Any, nbytes: int) -> Any:
        """A read-write buffer of at least ``nbytes`` on ``ctx``; its contents are whatever
        an earlier owner left (write before reading).

        Parameters
        ----------
        ctx : pyopencl.Context
            The context.
        nbytes : int
            Bytes it must hold.

        Returns
        -------
        pyopencl.Buffer
            The buffer (possibly larger).
        """
        import pyopencl as pcl

        nbytes = max(int(nbytes), 1)
        if nbytes >= RECYCLE_MIN_BYTES:
            with self._lock:
                held = self._held.get(ctx.int_ptr, (None, []))[1]
                fits = [b for b in held if b.size >= nbytes]
                if fits:
                    buf = min(fits, key=lambda b: b.size)
                    held.remove(buf)
                    return buf
            nbytes += nbytes // 4
        return pcl.Buffer(ctx, pcl.mem_flags.READ_WRITE, nbytes)

    def upload(self, queue: Any, array: Any) -> Any:
        """A buffer from :meth:`get` holding a copy of ``array`` (a blocking copy, so that
        ``array`` may change afterwards).

        Parameters
        ----------
        queue : pyopencl.CommandQueue
            The queue that copies (its context owns the buffer).
        array : numpy.ndarray
            C-contiguous data.

        Returns
        -------
        pyopencl.Buffer
            The buffer; its first ``array.nbytes`` bytes are the array's.
        """
        import pyopencl as pcl

        buf = self.get(queue.context, array.nbytes)
        if array.nbytes:
            pcl.enqueue_copy(queue, buf, array, is_blocking=True)
        return buf

    def give(self, ctx: Any, *buffers: Any) -> None:
        """Hold ``buffers`` of ``ctx`` for the next :meth:`get` (no caller may use them after).

        Parameters
        ----------
        ctx : pyopencl.Context
            Their context.
        *buffers : pyopencl.Buffer
            The buffers; those under :data:`RECYCLE_MIN_BYTES` are simply dropped.
        """
        with self._lock:
            held = self._held.setdefault(ctx.int_ptr, (ctx, []))[1]
            held.extend(b for b in buffers if b is not None and b.size >= RECYCLE_MIN_BYTES)
            self._trim()

    def give_when(self, owner: Any, ctx: Any, *buffers: Any) -> None:
        """:meth:`give` ``buffers`` back once ``owner`` is garbage-collected.

        Parameters
        ----------
        owner : object
            The object whose life the buffers share (it must support weak references).
        ctx : pyopencl.Context
            Their context.
        *buffers : pyopencl.Buffer
            The buffers.
        """
        weakref.finalize(owner, self.give, ctx, *buffers).atexit = False

    def _trim(self) -> None:
        """Free the smallest held buffers until at most ``max_bytes`` are held (lock held)."""
        everything = [(b.size, key, b) for key, (_, held) in self._held.items() for b in held]
        total = sum(size for size, _, _ in everything)
        for size, key, buf in sorted(everything, key=lambda t: t[0]):
            if total <= self.max_bytes:
                break
            self._held[key][1].remove(buf)
            total -= size

    def clear(self) -> None:
        """Free every held buffer (device memory)."""
        with self._lock:
            self._held.clear()

    def nbytes(self) -> int:
        """Bytes of device memory held for the next owner.

        Returns
        -------
        int
            The sizes of every held buffer, summed.
        """
        with self._lock:
            return sum(int(b.size) for _, held in self._held.values() for b in held)


# The BVHs' device buffers (ao4d.bvh: leaf blocks, nodes, the build's copies of the mesh), held
# for the next tree; ao4d.bvh.device.release_buffers() frees them
TREES = Recycler(max_bytes=1 << 30)
