"""ao4d.opencl.pool: device buffers kept between calls, one set per context."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from ao4d.opencl.pool import BufferPool


def test_buffers_are_kept_grown_and_never_shared(cl_runtime):
    import pyopencl as pcl

    ctx = cl_runtime.context
    pool = BufferPool()
    with pool.take(ctx) as bufs:
        a = bufs.get("a", 1000)
        assert a.size >= 1000
        assert bufs.get("a", 900) is a  # large enough: the same buffer
        b = bufs.get("b", 10)
    assert pool.nbytes() == a.size + b.size
    with pool.take(ctx) as bufs:
        assert bufs.get("a", 1000) is a  # kept for the next call
        # a call that holds them leaves none for a concurrent one
        with pool.take(ctx) as other:
            assert other.get("a", 1000) is not a
        grown = bufs.get("a", 5000)  # too small now: replaced by a larger one
        assert grown is not a and grown.size >= 5000
    # the set holding more bytes is the one kept
    with pool.take(ctx) as bufs:
        assert bufs.get("a", 10) is grown
    # a kept buffer works as any other
    data = np.arange(100, dtype=np.float32)
    with pool.take(ctx) as bufs:
        buf = bufs.get("a", data.nbytes)
        pcl.enqueue_copy(cl_runtime.queue, buf, data)
        back = np.empty_like(data)
        pcl.enqueue_copy(cl_runtime.queue, back, buf)
    np.testing.assert_array_equal(back, data)
    pool.clear()
    assert pool.nbytes() == 0


def test_calls_that_overlap_in_time_never_share_a_buffer(cl_runtime):
    import threading

    ctx = cl_runtime.context
    pool = BufferPool()
    with pool.take(ctx) as bufs:
        bufs.get("x", 64)  # one set kept before the threads start
    held = threading.Barrier(4)

    def call(_):
        with pool.take(ctx) as bufs:
            buf = bufs.get("x", 64)
            held.wait(timeout=30)  # all four hold their buffers at once
            return buf.int_ptr

    with ThreadPoolExecutor(4) as ex:
        pointers = list(ex.map(call, range(4)))
    assert len(set(pointers)) == 4
    assert pool.nbytes() > 0


def test_sets_above_max_bytes_are_not_kept(cl_runtime):
    ctx = cl_runtime.context
    pool = BufferPool(max_bytes=4096)
    with pool.take(ctx) as bufs:
        small = bufs.get("a", 1000)
    assert pool.nbytes() == small.size
    with pool.take(ctx) as bufs:
        bufs.get("a", 100_000)  # grows past the limit: dropped when given back
    assert pool.nbytes() == 0


def test_recycler_hands_the_smallest_fitting_buffer_to_the_next_owner(cl_runtime, monkeypatch):
    import gc

    from ao4d.opencl import pool as pool_module
    from ao4d.opencl.pool import Recycler

    monkeypatch.setattr(pool_module, "RECYCLE_MIN_BYTES", 100)
    ctx, queue = cl_runtime.context, cl_runtime.queue
    rec = Recycler(max_bytes=1 << 20)
    big = rec.get(ctx, 4000)
    assert big.size == 5000  # a new one is a quarter larger than asked
    small = rec.get(ctx, 1000)
    rec.give(ctx, big, small)
    assert rec.nbytes() == big.size + small.size
    assert rec.get(ctx, 900) is small  # the smallest that fits, not the first held
    assert rec.get(ctx, 900) is big
    assert rec.get(ctx, 900) not in (big, small)  # none held: a new one
    assert rec.nbytes() == 0
    # buffers under RECYCLE_MIN_BYTES are not held (their faults cost nothing)
    tiny = rec.get(ctx, 50)
    assert tiny.size == 50
    rec.give(ctx, tiny, None)
    assert rec.nbytes() == 0

    # given back when the owner is collected, not before; a held buffer's upload is exact
    class Owner:
        pass

    owner = Owner()
    data = np.arange(2000, dtype=np.float32)
    buf = rec.upload(queue, data)
    rec.give_when(owner, ctx, buf)
    assert rec.nbytes() == 0
    del owner
    gc.collect()
    assert rec.nbytes() == buf.size
    again = rec.upload(queue, data[::-1].copy())
    assert again is buf
    back = np.empty_like(data)
    pcl = pytest.importorskip("pyopencl")
    pcl.enqueue_copy(queue, back, again)
    np.testing.assert_array_equal(back, data[::-1])
    rec.clear()
    assert rec.nbytes() == 0


def test_recycler_frees_the_smallest_held_buffers_beyond_max_bytes(cl_runtime, monkeypatch):
    from ao4d.opencl import pool as pool_module
    from ao4d.opencl.pool import Recycler

    monkeypatch.setattr(pool_module, "RECYCLE_MIN_BYTES", 100)
    ctx = cl_runtime.context
    rec = Recycler(max_bytes=12_000)
    a, b, c = (rec.get(ctx, n) for n in (1000, 3000, 6000))  # 1250, 3750, 7500 bytes
    rec.give(ctx, a, b, c)
    # 12 500 held > 12 000: the smallest goes first, the large ones (costly to fault in) stay
    assert rec.nbytes() == b.size + c.size
    assert rec.get(ctx, 5000) is c and rec.get(ctx, 100) is b
