"""datasets_gen into an fsspec URL (``--out file:///...``, ``memory://...``): every process that
makes items writes its own into the URL, with the same atomic protocol as into a folder, and
the manifest is byte-identical to a one-process run into a local folder."""

from __future__ import annotations

import contextlib
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


# ---------------------------------------------------------------- hostile outputs (issue 31)


def _hidden(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(".*")]


def test_memory_url_is_refused_on_the_command_line(config, capsys):
    # a filesystem inside the process: "5 made", then everything gone at exit
    url = _memory_url()
    assert runner_mod.main([str(config), "--out", url, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "`--out`" in err and "gone when the command exits" in err
    assert not open_store(url).fs.exists(open_store(url).root)  # nothing was made


def test_memory_url_with_worker_processes_is_refused_before_any_work(config):
    url = _memory_url()
    with pytest.raises(ValueError, match=r"lives in this process only, so the 2 `workers`"):
        run(config, url, workers=2, progress=False)
    store = open_store(url)
    assert not store.fs.exists(store.root)


def test_made_items_missing_from_the_store_are_not_counted(config, monkeypatch):
    # a worker that wrote its item somewhere this process cannot see: never "made"
    url = _memory_url()
    real = runner_mod.make_item_anywhere

    def elsewhere(job):
        return real(job) if job.spec.index != 1 else {"index": 1, "seconds": {}}

    monkeypatch.setattr(runner_mod, "make_item_anywhere", elsewhere)
    summary = run(config, url, progress=False)
    assert (summary.made, list(summary.failed)) == (4, [1])
    assert "record.json is not in `out`" in summary.failed[1]
    assert not json.loads(open_store(url).read_bytes("manifest.json"))["complete"]


@pytest.mark.parametrize("out", ["://x", "://", "memory://", "3d://x", "s 3://x", "a::://x"])
def test_malformed_url_is_refused(config, out, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=r"is not a URL of the form PROTOCOL://PATH"):
        run(config, out, progress=False)
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


def test_full_disk_while_writing_the_index_of_a_file_url(config, tmp_path, monkeypatch, capsys):
    from fsspec.implementations.local import LocalFileSystem

    real = LocalFileSystem.pipe_file
    fail = _full_disk_on("manifest.json")

    def pipe_file(self, path, value, **kwargs):
        fail(path, value)
        return real(self, path, value, **kwargs)

    monkeypatch.setattr(LocalFileSystem, "pipe_file", pipe_file)
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=r"cannot write the index of `out` .*manifest.json.*"
                                         r"No space left on device.*finished items are kept"):
        run(config, f"file://{out}", progress=False)
    assert _hidden(out) == []  # no temporary file left behind
    assert len(list((out / "items").glob("*/record.json"))) == 5
    assert runner_mod.main([str(config), "--out", f"file://{out}", "--no-progress"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    monkeypatch.undo()
    again = run(config, f"file://{out}", progress=False)  # room again: the rerun finishes
    assert (again.made, again.skipped) == (0, 5) and (out / "manifest.json").is_file()


def test_full_disk_while_writing_the_index_of_a_folder(config, tmp_path, monkeypatch):
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
        run(config, out, progress=False)
    assert _hidden(out) == [] and not (out / "items.csv").exists()


def test_damaged_run_json_is_named(config, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    for text in ("{not json", "[1, 2]", '{"config_name": "x"}', "\udcff"):
        (out / "run.json").write_bytes(text.encode("utf-8", "surrogateescape"))
        with pytest.raises(ValueError, match=r"run.json \(.*run/run.json\) is (unreadable or )?damaged"):
            run(config, out, progress=False)
    assert sorted(p.name for p in out.iterdir()) == ["run.json"]


def test_two_configs_of_one_name_into_one_folder(config, reference, tmp_path):
    other = tmp_path / "tiny.toml"  # the same name, another text
    other.write_text(config.read_text().replace("count = 2", "count = 1", 1), encoding="utf-8")
    with pytest.raises(FileExistsError, match=r"holds a run of config 'tiny' with seed 3 \(.*tiny.toml, "
                                              r"text sha256 \w{12}\), not of config 'tiny' .*the "
                                              r"configs' texts differ"):
        run(other, reference, progress=False)


def test_two_runs_starting_into_one_new_folder(config, tmp_path, monkeypatch):
    # the other run creates run.json between this run's look at the folder and its own write
    other = tmp_path / "other.toml"
    other.write_text(config.read_text().replace('name = "tiny"', 'name = "other"'), encoding="utf-8")
    out = tmp_path / "run"
    real = LocalStore.prepare

    def prepare(self):
        empty = real(self)
        monkeypatch.setattr(LocalStore, "prepare", real)
        runner_mod._check_out(LocalStore(self.root), runner_mod.load_config(other), 3)
        return empty

    monkeypatch.setattr(LocalStore, "prepare", prepare)
    with pytest.raises(FileExistsError, match=r"holds a run of config 'other'.*another config"):
        run(config, out, progress=False)
    assert json.loads((out / "run.json").read_text())["config_name"] == "other"
    assert not (out / "items").exists()


def test_a_run_taken_over_while_running_writes_no_index(config, tmp_path, monkeypatch):
    other = tmp_path / "other.toml"
    other.write_text(config.read_text().replace('name = "tiny"', 'name = "other"'), encoding="utf-8")
    out = tmp_path / "run"
    real = runner_mod.make_item_anywhere

    def make(job):
        if job.spec.index == 2:  # the other run replaces run.json meanwhile
            (out / "run.json").write_bytes(runner_mod._run_info(runner_mod.load_config(other), 3))
        return real(job)

    monkeypatch.setattr(runner_mod, "make_item_anywhere", make)
    with pytest.raises(FileExistsError, match=r"holds a run of config 'other'"):
        run(config, out, progress=False)
    assert not (out / "manifest.json").exists()


def test_impossible_device_is_refused_before_any_work(config, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("AO4D_DEVICE", "nonsense-device-xyz")
    out = tmp_path / "run"
    from ao4d.cl import DeviceSelectionError

    with pytest.raises(DeviceSelectionError, match="AO4D_DEVICE='nonsense-device-xyz'"):
        run(config, out, progress=False)
    assert not out.exists()  # no folder, no items left behind
    assert runner_mod.main([str(config), "--out", str(out), "--workers", "2", "--no-progress"]) == 2
    assert "error: AO4D_DEVICE='nonsense-device-xyz'" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("kind", ["folder", "file-url", "memory"])
def test_create_bytes_writes_only_a_new_file(kind, tmp_path):
    store = {"folder": lambda: LocalStore(tmp_path / "s"), "file-url": lambda: open_store(f"file://{tmp_path / 's'}"),
             "memory": lambda: open_store(_memory_url())}[kind]()
    assert store.create_bytes("a/run.json", b"first") is True
    assert store.create_bytes("a/run.json", b"second") is False
    assert store.read_bytes("a/run.json") == b"first" and store.files("a") == ["run.json"]
