"""Tests for datasets_gen.export: shards read back by webdataset and pyarrow, byte for byte
against datasets_gen.load; shard sizes, manifest hashes, resuming, refusing a non-empty folder."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest
from _datasets import BALL, config, family, make

from datasets_gen import export as export_mod
from datasets_gen import load
from datasets_gen.export import export, item_arrays, parse_size

CONFIG = config(
    "export",
    4,
    [family("hypersphere", 4, BALL), family("spheritorus", 1, {"R": 0.7, "r": 0.3}, ao=False, sequence={"frames": 2})],
    split={"train": 0.5, "test": 0.5},
    grid=7,
    padding=0.15,
    rotation="random",
    ao={"samples": 4},
    samples={"uniform": 200, "near_surface": 50, "sigmas": [0.02], "surface": 100},
)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make(tmp_path_factory.mktemp("export"), CONFIG)


def _same(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _check_manifest(out):
    manifest = json.loads((out / "manifest.json").read_text())
    for shard in manifest["shards"]:
        data = (out / shard["name"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == shard["sha256"] and len(data) == shard["bytes"]
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]
    return manifest


# webdataset 1.0 leaves its shard files to the garbage collector (ResourceWarning)
@pytest.mark.filterwarnings("ignore::ResourceWarning", "ignore::pytest.PytestUnraisableExceptionWarning")
def test_webdataset_shards_read_back_by_webdataset(tmp_path, dataset):
    import gc

    import webdataset as wds

    out = tmp_path / "wds"
    manifest = export(dataset, out, format="webdataset", shard_size=40_000, progress=False)
    manifest = _check_manifest(out)
    assert len(manifest["shards"]) > 1
    for shard in manifest["shards"]:
        assert shard["bytes"] <= 40_000 or (shard["oversize"] and len(shard["items"]) == 1)
    ds = load(dataset)
    urls = [str(out / s["name"]) for s in manifest["shards"]]
    samples = list(wds.WebDataset(urls, shardshuffle=False, empty_check=False).decode())
    assert sorted(int(s["__key__"]) for s in samples) == ds.indices
    for sample in samples:
        i = ds.indices.index(int(sample["__key__"]))
        want = item_arrays(ds, i)
        assert sample["record.json"] == json.loads(json.dumps(want["record"]))
        assert sample["split.txt"] == want["record"]["split"]  # the split beside the record
        names = {k[: -len(".npy.gz")] for k in sample if k.endswith(".npy.gz")}
        assert names == set(want) - {"record"}
        for name in names:
            _same(sample[f"{name}.npy.gz"], want[name])
        assert ("sequence.vertices" in names) == (want["record"]["kind"] == "spheritorus")  # it has a sequence
    del samples
    gc.collect()


def test_parquet_shards_read_back_by_pyarrow(tmp_path, dataset):
    import pyarrow.parquet as pq

    out = tmp_path / "pq"
    export(dataset, out, format="parquet", shard_size=60_000, progress=False)
    manifest = _check_manifest(out)
    rows = []
    for shard in manifest["shards"]:
        assert shard["bytes"] <= 60_000 or shard["oversize"]
        rows += pq.read_table(out / shard["name"]).to_pylist()
    ds = load(dataset)
    assert sorted(r["index"] for r in rows) == ds.indices
    tables = [pq.read_table(out / s["name"]) for s in manifest["shards"]]
    seen = 0
    for table in tables:
        for row in range(table.num_rows):
            i = ds.indices.index(table.column("index")[row].as_py())
            want = item_arrays(ds, i)
            assert json.loads(table.column("record")[row].as_py()) == json.loads(json.dumps(want["record"]))
            assert table.column("split")[row].as_py() == want["record"]["split"]
            for name, value in want.items():
                if name == "record":
                    continue
                cell = table.column(name)[row]
                if value.ndim == 0:
                    got = np.asarray(cell.as_py(), value.dtype)
                elif value.ndim == 1:
                    got = cell.values.to_numpy(zero_copy_only=False)
                else:  # the one call the guide documents for (n, k) arrays
                    got = np.asarray(cell.values.to_tensor())
                _same(got, value)
            for name in set(table.column_names) - set(want) - {"index", "split", "record"}:
                assert table.column(name)[row].as_py() is None  # this item has no such array
            seen += 1
    assert seen == len(ds)


def test_split_export_and_same_bytes_twice(tmp_path, dataset):
    a = export(dataset, tmp_path / "a", format="parquet", split="train", progress=False)
    b = export(dataset, tmp_path / "b", format="parquet", split="train", progress=False)
    assert a["shards"] == b["shards"] and len(a["shards"]) == 1
    assert a["shards"][0]["items"] == load(dataset, split="train").indices


def test_refuses_a_non_empty_folder_and_bad_arguments(tmp_path, dataset):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not empty"):
        export(dataset, out, format="webdataset")
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    with pytest.raises(ValueError, match="`format`"):
        export(dataset, tmp_path / "x", format="zip")
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(ValueError, match="cannot create the folder `out`"):
        export(dataset, tmp_path / "file" / "shards", format="parquet")
    with pytest.raises(ValueError, match="`shard_size`"):
        export(dataset, tmp_path / "x", format="parquet", shard_size=10)
    assert parse_size("1GB") == 10**9 and parse_size("64kB") == 64_000 and parse_size("5000") == 5000
    with pytest.raises(ValueError, match="shard-size"):
        parse_size("lots")


def test_an_interrupted_export_leaves_whole_shards_and_resumes(tmp_path, dataset, monkeypatch):
    clean = export(dataset, tmp_path / "clean", format="webdataset", shard_size=40_000, progress=False)
    real, calls = export_mod.tar_bytes, []

    def failing(parts):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(parts)

    out = tmp_path / "cut"
    monkeypatch.setattr(export_mod, "tar_bytes", failing)
    with pytest.raises(KeyboardInterrupt):
        export(dataset, out, format="webdataset", shard_size=40_000, progress=False)
    left = sorted(p.name for p in out.iterdir())
    assert left == [".export.json", "train-000000.tar"]  # whole shards only, no manifest
    monkeypatch.setattr(export_mod, "tar_bytes", real)
    with pytest.raises(FileExistsError):  # another shard size is another export
        export(dataset, out, format="webdataset", shard_size=50_000, progress=False)
    resumed = export(dataset, out, format="webdataset", shard_size=40_000, progress=False)
    assert resumed["shards"] == clean["shards"]
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in (tmp_path / "clean").iterdir())


def test_command_line(tmp_path, dataset):
    out = tmp_path / "cli"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "datasets_gen",
            "export",
            str(dataset),
            "--format",
            "parquet",
            "--out",
            str(out),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "5 items in 2 parquet shards" in done.stdout
    again = subprocess.run(
        [sys.executable, "-m", "datasets_gen", "export", str(dataset), "--format", "parquet", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert again.returncode == 2 and "not empty" in again.stderr
