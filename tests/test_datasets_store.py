"""datasets_gen into an fsspec URL (``--out file:///...``, ``memory://...``): every process that
makes items writes its own into the URL, with the same atomic protocol as into a folder, and
the manifest is byte-identical to a one-process run into a local folder."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import pytest

from datasets_gen import run
from datasets_gen import runner as runner_mod
from datasets_gen._store import FsspecStore, LocalStore, open_store

fsspec = pytest.importorskip("fsspec", reason="fsspec is a dependency of ao4d (dask)")

from test_datasets_gen import TINY  # noqa: E402  (the suite's tiny config: a few seconds)


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny.toml"
    path.write_text(TINY, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def reference(config, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "run"
    summary = run(config, out, progress=False)
    assert summary.made >= 3 and not summary.failed, summary
    return out


def _memory_url() -> str:
    return f"memory://ao4d-test-{uuid.uuid4().hex[:8]}/run"


def _tree(store, rel: str = "") -> dict[str, bytes]:
    """Every file under ``rel`` of a store, by relative path."""
    out = {}
    for name in store.files(rel):
        path = f"{rel}/{name}" if rel else name
        out[path] = store.read_bytes(path)
    fs = getattr(store, "fs", None)
    subdirs = ([e["name"].rpartition("/")[2] for e in fs.ls(store._path(rel), detail=True) if e["type"] == "directory"]
               if fs is not None else [p.name for p in store._path(rel).iterdir() if p.is_dir()])
    for sub in subdirs:
        out.update(_tree(store, f"{rel}/{sub}" if rel else sub))
    return out


def test_file_url_from_two_processes_equals_one_process_folder(config, reference, tmp_path):
    out = tmp_path / "run ä"  # a non-ASCII path inside the URL
    summary = run(config, f"file://{out}", workers=2, progress=False)  # fsspec: no %-decoding
    assert (summary.made, summary.failed) == (5, {}), summary
    assert (out / "manifest.json").read_bytes() == (reference / "manifest.json").read_bytes()
    # the items were written by the worker processes, not by this one
    pids = {json.loads(p.read_text())["pid"] for p in (out / "items").glob("*/timing.json")}
    import os

    assert os.getpid() not in pids and pids
    assert not [p for p in out.rglob(".*")]  # no temporary files left


def test_file_url_on_a_local_cluster_sends_no_item_bytes_back(config, reference, tmp_path):
    pytest.importorskip("distributed", reason="distributed is a dependency of ao4d")
    out = tmp_path / "run"
    summary = run(config, f"file://{out}", scheduler="local:2", progress=False)
    assert (summary.made, summary.failed, summary.received) == (5, {}, 0), summary
    assert (out / "manifest.json").read_bytes() == (reference / "manifest.json").read_bytes()


def test_memory_url_same_bytes_and_resume(config, reference):
    url = _memory_url()
    summary = run(config, url, progress=False)
    assert summary.out == url and (summary.made, summary.failed) == (5, {})
    store = open_store(url)
    assert isinstance(store, FsspecStore)
    local = LocalStore(reference)
    expected = {k: v for k, v in _tree(local).items() if not k.endswith(("timing.json", "summary.json"))}
    got = {k: v for k, v in _tree(store).items() if not k.endswith(("timing.json", "summary.json"))}
    assert got == expected  # every hashed file, byte for byte
    again = run(config, url, progress=False)
    assert (again.made, again.skipped) == (0, 5)
    assert store.read_bytes("manifest.json") == (reference / "manifest.json").read_bytes()


def test_memory_url_interrupted_item_is_redone(config, reference):
    url = _memory_url()
    run(config, url, progress=False)
    store = open_store(url)
    # a run killed mid-item: a damaged mesh, no record, and a temporary file of a write
    store.remove("items/00002/record.json")
    store.write_bytes("items/00002/mesh.npz", b"half a file")
    store.fs.pipe_file(store._path("items/00002/.ao.npz.0123456789ab.tmp"), b"partial")
    store.write_bytes("items/00003/ao.npz", b"changed after the record was written")
    summary = run(config, url, progress=False)
    assert (summary.made, summary.skipped) == (2, 3)
    assert store.read_bytes("manifest.json") == (reference / "manifest.json").read_bytes()
    assert not [n for n in store.files("items/00002") if n.startswith(".")]


def test_a_url_nobody_can_open_fails_before_any_work(config, capsys):
    with pytest.raises(ValueError, match=r"`out` 'nosuchprotocol://x/run'"):
        run(config, "nosuchprotocol://x/run", progress=False)
    assert runner_mod.main([str(config), "--out", "nosuchprotocol://x/run", "--no-progress"]) == 2
    assert "cannot open `out`" in capsys.readouterr().err


def test_a_url_holding_another_run_is_refused(config):
    url = _memory_url()
    store = open_store(url)
    store.write_bytes("notes.txt", b"someone else's files")
    with pytest.raises(FileExistsError, match="is not empty and holds no run.json"):
        run(config, url, progress=False)
    with pytest.raises(ValueError, match="is a file"):
        run(config, f"{url}/notes.txt", progress=False)


def test_store_writes_are_whole_or_absent(tmp_path):
    # a failing move leaves neither the target nor the temporary file
    store = open_store(f"file://{tmp_path / 's'}")
    store.write_bytes("a/b.bin", b"one")
    assert store.read_bytes("a/b.bin") == b"one" and store.files("a") == ["b.bin"]

    def broken(*args, **kwargs):
        raise OSError("disk full")

    store.fs.mv = broken
    with pytest.raises(OSError, match="disk full"):
        store.write_bytes("a/b.bin", b"two")
    assert store.read_bytes("a/b.bin") == b"one" and store.files("a") == ["b.bin"]
    assert sorted(p.name for p in (tmp_path / "s" / "a").iterdir()) == ["b.bin"]
    assert store.files("missing") == [] and store.sha256("a/b.bin") == LocalStore(tmp_path / "s").sha256("a/b.bin")
    assert Path(store.root) == tmp_path / "s"
