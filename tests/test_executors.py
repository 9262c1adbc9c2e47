"""Tests for datasets_gen.executors: spawned processes and dask.distributed (``--scheduler``)
give the same bytes as a one-process run, also when a worker is killed mid-item or the client
is killed and rerun. The workers of these clusters see the output folder, so they write the
items themselves (the client only the index and the manifest); one test makes them send the
bytes back instead, as workers without the folder do."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from _datasets import tiny, write_config

from datasets_gen import run
from datasets_gen.executors import Dask, InProcess, ProcessPool, executor_for
from datasets_gen.runner import main

distributed = pytest.importorskip("distributed", reason="distributed is a dependency of ao4d")

# the suite's tiny config with somewhat heavier items (finer grids, more AO samples: 0.3 to
# 1.3 s each here), so that a worker can be caught in the middle of one
CONFIG = tiny("tiny14", grid=14, ao={"samples": 8})


def _manifest(out: Path) -> bytes:
    return (out / "manifest.json").read_bytes()


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    return write_config(tmp_path_factory.mktemp("cfg"), CONFIG, "tiny14.toml")


@pytest.fixture(scope="module")
def reference(config, tmp_path_factory):
    """A one-process (``workers=1``) run: the bytes every distributed run must reproduce."""
    out = tmp_path_factory.mktemp("ref") / "run"
    summary = run(config, out, progress=False)
    assert summary.made == 5 and not summary.failed, summary
    return out


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes of one thread, shared by the tests of this module."""
    from distributed import LocalCluster

    from ao4d import worker_environment

    with worker_environment():
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    with cluster:
        yield cluster


def test_two_workers_give_identical_manifest(tiny_reference, tiny_config, tmp_path):
    summary = run(tiny_config, tmp_path / "par", workers=2, progress=False)
    assert summary.made == 5 and not summary.failed
    assert _manifest(tmp_path / "par") == _manifest(tiny_reference)


def test_executors_from_workers_and_scheduler(tiny_config, tmp_path):
    assert executor_for() == InProcess() and executor_for(3) == ProcessPool(3)
    assert executor_for(1, "local:2") == Dask("local:2", workers_write=True)
    with pytest.raises(ValueError, match="give `executor`"):
        run(tiny_config, tmp_path / "a", workers=2, executor=InProcess())
    assert not (tmp_path / "a").exists()


def test_local_cluster_manifest_equals_one_process(config, reference, tmp_path, capsys):
    out = tmp_path / "run"
    assert main([str(config), "--out", str(out), "--scheduler", "local:2", "--no-progress"]) == 0
    assert "5 made, 0 skipped (already complete), 0 failed of 5" in capsys.readouterr().out
    assert _manifest(out) == _manifest(reference)
    # the workers wrote nothing here but the client did: no scratch folders, no temp files left
    assert not [p for p in (tmp_path / "run").rglob(".*")]


def _writers(out: Path) -> set[int]:
    """The process ids that made the items (timing.json records them)."""
    return {json.loads(p.read_text())["pid"] for p in (out / "items").glob("*/timing.json")}


def test_workers_write_their_items_when_they_see_the_folder(config, reference, cluster, tmp_path):
    from distributed import Client

    out = tmp_path / "run"
    summary = run(config, out, scheduler=cluster.scheduler_address, progress=False)
    assert (summary.made, summary.failed) == (5, {}) and summary.received == 0
    assert _manifest(out) == _manifest(reference)
    with Client(cluster) as client:
        worker_pids = set(client.run(os.getpid).values())
    assert _writers(out) <= worker_pids and os.getpid() not in _writers(out)
    assert set(summary.stages) >= {"build", "check", "bvh", "ao", "write", "total"}


def test_workers_without_the_folder_send_the_items_back(config, reference, cluster, tmp_path):
    out = tmp_path / "run"
    as_if_unseen = Dask(cluster.scheduler_address, workers_write=False)
    summary = run(config, out, executor=as_if_unseen, progress=False)
    assert (summary.made, summary.failed) == (5, {})
    hashed = json.loads(_manifest(out))["files"]
    item_bytes = sum(f["bytes"] for name, f in hashed.items() if name.startswith("items/"))
    timing_bytes = sum(p.stat().st_size for p in (out / "items").glob("*/timing.json"))
    assert summary.received == item_bytes + timing_bytes
    assert _manifest(out) == _manifest(reference)


def test_scheduler_address_and_resume(config, reference, cluster, tmp_path, capsys):
    out = tmp_path / "run"
    summary = run(config, out, scheduler=cluster.scheduler_address, progress=False)
    assert (summary.made, summary.failed) == (5, {})
    assert _manifest(out) == _manifest(reference)
    items = out / "items"
    (items / "00001" / "record.json").unlink()  # interrupted before its record
    (items / "00002" / "mesh.npz").write_bytes(b"truncated")  # damaged after its record
    (items / "00004" / ".view.png.abc.tmp.png").write_bytes(b"")  # stray temp file
    summary = run(config, out, scheduler=cluster.scheduler_address, progress=False)
    assert (summary.made, summary.skipped) == (2, 3)
    assert _manifest(out) == _manifest(reference)


def _executing(client) -> dict[str, list[str]]:
    """Worker address -> keys of the item tasks it is running right now."""
    return client.run(
        lambda dask_worker: [str(ts.key) for ts in dask_worker.state.executing if "datasets_gen-item" in str(ts.key)]
    )


def test_worker_killed_mid_item_loses_nothing(config, reference, cluster, tmp_path):
    from distributed import Client

    out = tmp_path / "run"
    result: dict = {}
    thread = threading.Thread(
        target=lambda: result.setdefault(
            "summary", run(config, out, scheduler=cluster.scheduler_address, progress=False)
        )
    )
    with Client(cluster) as client:
        pids = client.run(os.getpid)
        thread.start()
        victim = key = None
        deadline = time.monotonic() + 120
        while victim is None and thread.is_alive() and time.monotonic() < deadline:
            for worker, keys in _executing(client).items():
                if keys:  # running now: kill its worker at once
                    victim, key = worker, keys[0]
                    break
            time.sleep(0.005)
        assert victim is not None, "no item was seen running on a worker"
        os.kill(pids[victim], signal.SIGKILL)  # a worker process this test's cluster started
        thread.join(timeout=300)
        assert not thread.is_alive()
        story = client.run_on_scheduler(
            lambda dask_scheduler, key=key: [t[2] for t in dask_scheduler.story(key) if len(t) > 2]
        )
    summary = result["summary"]
    assert (summary.made, summary.failed) == (5, {}), summary
    # the killed worker's item was started again elsewhere, and nothing differs
    assert story.count("processing") >= 2, story
    assert _manifest(out) == _manifest(reference)
    index = int(key.split("-")[2])
    record = json.loads((out / "items" / f"{index:05d}" / "record.json").read_text())
    assert record["index"] == index
    # made again, in the folder, by a worker other than the killed one (and not the client)
    remade = json.loads((out / "items" / f"{index:05d}" / "timing.json").read_text())["pid"]
    assert remade != pids[victim] and remade != os.getpid() and summary.received == 0


def test_killed_client_resumes(config, reference, cluster, tmp_path):
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "datasets_gen",
            str(config),
            "--out",
            str(out),
            "--scheduler",
            cluster.scheduler_address,
            "--no-progress",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    records = out / "items"
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline and not list(records.glob("*/record.json")):
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = len(list(records.glob("*/record.json")))
    assert 1 <= done < 5
    summary = run(config, out, scheduler=cluster.scheduler_address, progress=False)
    assert summary.skipped >= done and summary.made + summary.skipped == 5 and not summary.failed
    assert _manifest(out) == _manifest(reference)


def test_scheduler_errors(config, tmp_path, capsys):
    with pytest.raises(ValueError, match="`scheduler` 'local:N' needs a worker count"):
        run(config, tmp_path / "a", scheduler="local:0")
    with pytest.raises(ValueError, match="`scheduler`"):
        run(config, tmp_path / "b", scheduler="local:two")
    with pytest.raises(ValueError, match="not both"):
        run(config, tmp_path / "c", scheduler="local:2", workers=2)
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert (
            main([str(config), "--out", str(tmp_path / "d"), "--scheduler", "tcp://127.0.0.1:9", "--no-progress"]) == 2
        )
    assert "cannot reach the dask scheduler" in capsys.readouterr().err


# -- addresses where no dask scheduler listens: fail at once, with a clear message ------------


def _serve(handler):
    """A TCP server on localhost running ``handler(connection)`` per connection; its port."""
    import socket

    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def loop():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            threading.Thread(target=handler, args=(conn, stop), daemon=True).start()
        server.close()

    threading.Thread(target=loop, daemon=True).start()
    return server.getsockname()[1], stop


def _silent(conn, stop):
    with conn:
        stop.wait(30)  # accepts, never answers


def _http_reply(conn, stop):
    with conn:  # answers at once, as a proxy in front of the port did
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
        stop.wait(30)


@pytest.mark.parametrize(
    "handler, match",
    [
        (_silent, r"accepted the connection but sent nothing in 1 s"),
        (_http_reply, r"answers like an HTTP server, not a dask scheduler"),
    ],
)
def test_a_scheduler_address_that_is_not_a_scheduler_fails_fast(config, tmp_path, handler, match):
    port, stop = _serve(handler)
    try:
        with pytest.raises(ValueError, match=match):
            run(config, tmp_path / "o", executor=Dask(f"tcp://127.0.0.1:{port}", probe_seconds=1.0), progress=False)
    finally:
        stop.set()
    assert not (tmp_path / "o").exists()  # refused before the output folder is made


def test_an_http_server_is_not_taken_for_a_scheduler(config, tmp_path, capsys):
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    server = ThreadingHTTPServer(("127.0.0.1", 0), BaseHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        assert (
            main(
                [
                    str(config),
                    "--out",
                    str(tmp_path / "o"),
                    "--scheduler",
                    f"127.0.0.1:{server.server_address[1]}",
                    "--no-progress",
                ]
            )
            == 2
        )
    finally:
        server.shutdown()
        server.server_close()
    err = capsys.readouterr().err
    assert "is it a dask scheduler's address" in err and "Traceback" not in err
    with pytest.raises(ValueError, match="not an address of the form tcp://HOST:PORT"):
        run(config, tmp_path / "p", scheduler="tcp://no-port-here")


def test_a_real_scheduler_passes_the_probe(cluster):
    Dask(cluster.scheduler_address, probe_seconds=1.0).check()  # no error: it greets at once


def _worker_state() -> dict:
    """What a spawned worker's pools look like (runs in the worker)."""
    import numpy  # noqa: F401  (its BLAS)
    from threadpoolctl import threadpool_info

    return {
        "blas": sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}),
        "env": {name: os.environ.get(name) for name in ("OPENBLAS_NUM_THREADS", "DPCPP_CPU_NUM_CUS")},
        "mkl": os.environ.get("MKL_NUM_THREADS"),
        "pid": os.getpid(),
    }


@pytest.mark.parametrize("threads", [1, 2])
def test_spawned_workers_size_their_thread_pools_to_their_share_of_the_cores(threads, monkeypatch):
    """With as many workers as cores, each worker's BLAS and (Intel's CPU) OpenCL runtime use
    one thread: pools over every core spin against the other workers'. A variable the user set
    is left as it is."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from datasets_gen.executors import _start_worker

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.delenv("DPCPP_CPU_NUM_CUS", raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "7")  # the user's: kept
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context, initializer=_start_worker, initargs=(threads,)) as pool:
        state = pool.submit(_worker_state).result(timeout=300)
    assert state["pid"] != os.getpid() and state["mkl"] == "7"
    assert state["env"] == {"OPENBLAS_NUM_THREADS": str(threads), "DPCPP_CPU_NUM_CUS": str(threads)}
    # numpy's OpenBLAS was loaded before the worker's set-up ran: limited by threadpoolctl
    # (Intel's runtime takes DPCPP_CPU_NUM_CUS for its threads, not for the units it reports)
    assert state["blas"] == [threads]


def test_freed_memory_stays_in_the_worker():
    """glibc keeps a worker's freed arrays for its next item (no mapping per large array,
    returned at free and faulted in and zeroed again); elsewhere the call is a no-op."""
    import platform

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("not glibc: the workers' malloc is left as it is")
    code = (
        "import sys, numpy as np\n"
        "from datasets_gen.executors import _keep_freed_memory\n"
        "if sys.argv[1] == 'keep': assert _keep_freed_memory()\n"
        "a = np.ones(1 << 25); del a  # 256 MiB\n"
        "print(int(open('/proc/self/statm').read().split()[1]) * 4096 >> 20)"
    )

    def resident_mib(mode):
        done = subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True, check=True)
        return int(done.stdout)

    assert resident_mib("keep") - resident_mib("default") > 200  # still held for the next item
