"""datasets_gen into an fsspec URL (``--out file:///...``, ``memory://...``): every process that
makes items writes its own into the URL, with the same atomic protocol as into a folder, and
the manifest is byte-identical to a one-process run into a local folder."""

from __future__ import annotations

import contextlib
import hashlib
import json
import uuid
from pathlib import Path

import pytest

from datasets_gen import run
from datasets_gen._store import FsspecStore, LocalStore, MemoryStore, open_store
from datasets_gen.runner import main

fsspec = pytest.importorskip("fsspec", reason="fsspec is a dependency of ao4d (dask)")


def _memory_url() -> str:
    return f"memory://ao4d-test-{uuid.uuid4().hex[:8]}/run"


def _tree(store, rel: str = "") -> dict[str, bytes]:
    """Every file under ``rel`` of a store, by relative path."""
    out = {}
    for name in store.files(rel):
        path = f"{rel}/{name}" if rel else name
        out[path] = store.read_bytes(path)
    fs = getattr(store, "fs", None)
    subdirs = (
        [e["name"].rpartition("/")[2] for e in fs.ls(store._path(rel), detail=True) if e["type"] == "directory"]
        if fs is not None
        else [p.name for p in store._path(rel).iterdir() if p.is_dir()]
    )
    for sub in subdirs:
        out.update(_tree(store, f"{rel}/{sub}" if rel else sub))
    return out


def test_file_url_from_two_processes_equals_one_process_folder(tiny_config, tiny_reference, tmp_path):
    out = tmp_path / "run ä"  # a non-ASCII path inside the URL
    summary = run(tiny_config, f"file://{out}", workers=2, progress=False)  # fsspec: no %-decoding
    assert (summary.made, summary.failed) == (5, {}), summary
    assert (out / "manifest.json").read_bytes() == (tiny_reference / "manifest.json").read_bytes()
    # the items were written by the worker processes, not by this one
    pids = {json.loads(p.read_text())["pid"] for p in (out / "items").glob("*/timing.json")}
    import os

    assert os.getpid() not in pids and pids
    assert not [p for p in out.rglob(".*")]  # no temporary files left


def test_file_url_on_a_local_cluster_sends_no_item_bytes_back(tiny_config, tiny_reference, tmp_path):
    pytest.importorskip("distributed", reason="distributed is a dependency of ao4d")
    out = tmp_path / "run"
    summary = run(tiny_config, f"file://{out}", scheduler="local:2", progress=False)
    assert (summary.made, summary.failed, summary.received) == (5, {}, 0), summary
    assert (out / "manifest.json").read_bytes() == (tiny_reference / "manifest.json").read_bytes()


def test_memory_url_same_bytes_and_resume(tiny_config, tiny_reference):
    url = _memory_url()
    summary = run(tiny_config, url, progress=False)
    assert summary.out == url and (summary.made, summary.failed) == (5, {})
    store = open_store(url)
    assert isinstance(store, FsspecStore)
    local = LocalStore(tiny_reference)
    expected = {k: v for k, v in _tree(local).items() if not k.endswith(("timing.json", "summary.json"))}
    got = {k: v for k, v in _tree(store).items() if not k.endswith(("timing.json", "summary.json"))}
    assert got == expected  # every hashed file, byte for byte
    again = run(tiny_config, url, progress=False)
    assert (again.made, again.skipped) == (0, 5)
    assert store.read_bytes("manifest.json") == (tiny_reference / "manifest.json").read_bytes()


def test_memory_url_interrupted_item_is_redone(tiny_config, tiny_reference):
    url = _memory_url()
    run(tiny_config, url, progress=False)
    store = open_store(url)
    # a run killed mid-item: a damaged mesh, no record, and a temporary file of a write
    store.remove("items/00002/record.json")
    store.write_bytes("items/00002/mesh.npz", b"half a file")
    store.fs.pipe_file(store._path("items/00002/.ao.npz.0123456789ab.tmp"), b"partial")
    store.write_bytes("items/00003/ao.npz", b"changed after the record was written")
    summary = run(tiny_config, url, progress=False)
    assert (summary.made, summary.skipped) == (2, 3)
    assert store.read_bytes("manifest.json") == (tiny_reference / "manifest.json").read_bytes()
    assert not [n for n in store.files("items/00002") if n.startswith(".")]


def test_a_url_nobody_can_open_fails_before_any_work(tiny_config, capsys):
    with pytest.raises(ValueError, match=r"`out` 'nosuchprotocol://x/run'"):
        run(tiny_config, "nosuchprotocol://x/run", progress=False)
    assert main([str(tiny_config), "--out", "nosuchprotocol://x/run", "--no-progress"]) == 2
    assert "cannot open `out`" in capsys.readouterr().err


def test_a_url_holding_another_run_is_refused(tiny_config):
    url = _memory_url()
    store = open_store(url)
    store.write_bytes("notes.txt", b"someone else's files")
    with pytest.raises(FileExistsError, match="is not empty and holds no run.json"):
        run(tiny_config, url, progress=False)
    with pytest.raises(ValueError, match="is a file"):
        run(tiny_config, f"{url}/notes.txt", progress=False)


def test_store_writes_are_whole_or_absent(tmp_path, monkeypatch):
    # a failing move leaves neither the target nor the temporary file
    store = open_store(f"file://{tmp_path / 's'}")
    store.write_bytes("a/b.bin", b"one")
    assert store.read_bytes("a/b.bin") == b"one" and store.files("a") == ["b.bin"]

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(store.fs, "mv", broken)  # fsspec shares one instance: undone after
    with pytest.raises(OSError, match="disk full"):
        store.write_bytes("a/b.bin", b"two")
    assert store.read_bytes("a/b.bin") == b"one" and store.files("a") == ["b.bin"]
    assert sorted(p.name for p in (tmp_path / "s" / "a").iterdir()) == ["b.bin"]
    assert store.files("missing") == [] and store.sha256("a/b.bin") == LocalStore(tmp_path / "s").sha256("a/b.bin")
    assert Path(store.root) == tmp_path / "s"


# ---------------------------------------------------------------- hostile outputs


def _hidden(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(".*")]


def test_memory_url_is_refused_on_the_command_line(tiny_config, capsys):
    # a filesystem inside the process: "5 made", then everything gone at exit
    url = _memory_url()
    assert main([str(tiny_config), "--out", url, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "`--out`" in err and "gone when the command exits" in err
    assert not open_store(url).fs.exists(open_store(url).root)  # nothing was made


def test_memory_url_with_worker_processes_is_refused_before_any_work(tiny_config):
    url = _memory_url()
    with pytest.raises(ValueError, match=r"lives in this process only, so the 2 `workers`"):
        run(tiny_config, url, workers=2, progress=False)
    store = open_store(url)
    assert not store.fs.exists(store.root)


@pytest.mark.parametrize("out", ["://x", "://", "memory://", "3d://x", "s 3://x", "a::://x"])
def test_malformed_url_is_refused(tiny_config, out, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=r"is not a URL of the form PROTOCOL://PATH"):
        run(tiny_config, out, progress=False)
    assert list(tmp_path.iterdir()) == []  # not written into ./:/x


def test_chained_and_plain_urls_are_accepted():
    from datasets_gen._store import check_url

    for url in ("s3://bucket/run", "file:///data/run", "simplecache::s3://b/r", "memory://a/b"):
        assert check_url(url) == url


def _full_disk_on(name: str):
    """A write that stops half way with ENOSPC when the file (or its temporary) is ``name``."""
    import errno

    def fail(path, data):
        if name in str(path):
            Path(path).write_bytes(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")
        return None

    return fail


def test_full_disk_while_writing_the_index_of_a_file_url(tiny_config, tmp_path, monkeypatch, capsys):
    from fsspec.implementations.local import LocalFileSystem

    real = LocalFileSystem.pipe_file
    fail = _full_disk_on("manifest.json")

    def pipe_file(self, path, value, **kwargs):
        fail(path, value)
        return real(self, path, value, **kwargs)

    monkeypatch.setattr(LocalFileSystem, "pipe_file", pipe_file)
    out = tmp_path / "run"
    with pytest.raises(
        ValueError,
        match=r"cannot write the index of `out` .*manifest.json.*"
        r"No space left on device.*finished items are kept",
    ):
        run(tiny_config, f"file://{out}", progress=False)
    assert _hidden(out) == []  # no temporary file left behind
    assert len(list((out / "items").glob("*/record.json"))) == 5
    assert main([str(tiny_config), "--out", f"file://{out}", "--no-progress"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    monkeypatch.undo()
    again = run(tiny_config, f"file://{out}", progress=False)  # room again: the rerun finishes
    assert (again.made, again.skipped) == (0, 5) and (out / "manifest.json").is_file()


def test_full_disk_while_writing_the_index_of_a_folder(tiny_config, tmp_path, monkeypatch):
    import datasets_gen._store as store_mod

    real = store_mod.atomic_open
    fail = _full_disk_on("items.csv")

    @contextlib.contextmanager
    def atomic_open(path, mode="wb"):
        with real(path, mode) as fh:

            class Half:
                def write(self, data):
                    fail(fh.name, data)
                    return fh.write(data)

            yield Half()

    monkeypatch.setattr(store_mod, "atomic_open", atomic_open)
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=r"cannot write the index of `out` .*items.csv.*No space"):
        run(tiny_config, out, progress=False)
    assert _hidden(out) == [] and not (out / "items.csv").exists()


def test_impossible_device_is_refused_before_any_work(tiny_config, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("AO4D_DEVICE", "nonsense-device-xyz")
    out = tmp_path / "run"
    from ao4d.opencl.cl import DeviceSelectionError

    with pytest.raises(DeviceSelectionError, match="AO4D_DEVICE='nonsense-device-xyz'"):
        run(tiny_config, out, progress=False)
    assert not out.exists()  # no folder, no items left behind
    assert main([str(tiny_config), "--out", str(out), "--workers", "2", "--no-progress"]) == 2
    assert "error: AO4D_DEVICE='nonsense-device-xyz'" in capsys.readouterr().err
    assert not out.exists()


_STORES = {
    "folder": lambda tmp: LocalStore(tmp / "s"),
    "file-url": lambda tmp: open_store(f"file://{tmp / 's'}"),
    "memory": lambda tmp: open_store(_memory_url()),
    "scratch": lambda tmp: MemoryStore(),
}


@pytest.mark.parametrize("kind", sorted(_STORES))
def test_every_store_lists_reads_and_removes_alike(kind, tmp_path):
    store = _STORES[kind](tmp_path)
    assert not store.prepare() and store.files() == [] and store.files("a") == []
    store.write_bytes("a/b/c.bin", b"deep")
    store.write_bytes("a/x.bin", b"one")
    store.write_bytes("a/x.bin", b"two")
    store.write_bytes("top.json", b"{}")
    assert store.files() == ["top.json"] and store.files("a") == ["x.bin"] and store.files("a/b") == ["c.bin"]
    assert store.read_bytes("a/x.bin") == b"two" and store.read_text("top.json") == "{}"
    assert store.size("a/b/c.bin") == 4 and store.is_file("a/x.bin") and not store.is_file("a/b")
    assert store.sha256("a/x.bin") == hashlib.sha256(b"two").hexdigest()
    store.remove("a/x.bin")
    store.remove("a/x.bin")  # a missing file is no error
    assert store.files("a") == [] and not store.is_file("a/x.bin") and store.prepare()
    with pytest.raises(FileNotFoundError):
        store.read_bytes("a/x.bin")


@pytest.mark.parametrize("kind", sorted(_STORES))
def test_create_bytes_writes_only_a_new_file(kind, tmp_path):
    store = _STORES[kind](tmp_path)
    assert store.create_bytes("a/run.json", b"first") is True
    assert store.create_bytes("a/run.json", b"second") is False
    assert store.read_bytes("a/run.json") == b"first" and store.files("a") == ["run.json"]
