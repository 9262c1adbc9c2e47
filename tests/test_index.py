"""Tests for datasets_gen.index: run.json claims one output for one run; items.csv, the
manifest and summary.json list exactly the complete items."""

from __future__ import annotations

import copy
import json
import uuid
from pathlib import Path

import numpy as np
import pytest
from _datasets import TINY, tiny

from datasets_gen import executors, items, load_config, run
from datasets_gen._files import sha256_file
from datasets_gen._store import LocalStore, open_store
from datasets_gen.index import RunSummary, claim_out, run_info


def _manifest(out: Path) -> bytes:
    return (out / "manifest.json").read_bytes()


def test_reference_run_records(tiny_reference):
    from ao4d import SimplexMesh
    from ao4d._resources import data_dir

    lut_sha = sha256_file(data_dir("lut") / "manifest.json")
    reference = tiny_reference
    manifest = json.loads(_manifest(reference))
    assert manifest["complete"] and manifest["n_items"] == 5 and manifest["seed"] == 3
    for name, entry in manifest["files"].items():
        assert sha256_file(reference / name) == entry["sha256"]
    assert not any(Path(n).name in ("timing.json", "summary.json") for n in manifest["files"])
    for index in range(5):
        folder = reference / "items" / f"{index:05d}"
        record = json.loads((folder / "record.json").read_text())
        assert record["seed"]["entropy"] == [3, index]
        assert record["versions"]["lut_manifest_sha256"] == lut_sha
        assert record["mesh"]["check"]["ok"]
        mesh = SimplexMesh.load(folder / "mesh.npz")
        assert mesh.n_simplices == record["mesh"]["simplices"]
        with np.load(folder / "ao.npz") as ao:
            assert ao["occlusion"].shape == (mesh.n_vertices,)
            assert 0.0 <= ao["occlusion"].min() and ao["occlusion"].max() <= 1.0
        if record["kind"] == "lifted":
            assert abs(record["mesh"]["volume_rel_error"]) < 1e-9
            assert (folder / "view.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        else:
            assert record["rotation"] is not None  # random rotation recorded
    items_csv = (reference / "items.csv").read_text().splitlines()
    assert len(items_csv) == 6 and items_csv[0].startswith("index,family")


def test_out_folder_of_another_run_is_refused(tiny_reference, tiny_config, tmp_path):
    with pytest.raises(FileExistsError, match="holds a run of config 'tiny' with seed 3"):
        run(tiny_config, tiny_reference, seed=9, progress=False)
    (tmp_path / "junk.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not empty and holds no run.json"):
        run(tiny_config, tmp_path, progress=False)
    with pytest.raises(ValueError, match="`workers` must be >= 1"):
        run(tiny_config, tmp_path / "new", workers=0)


def test_failed_item_is_reported_and_others_finish(tmp_path):
    cfg = copy.deepcopy(TINY)
    cfg["family"][1]["params"] = {"n": 2, "half": 0.4, "operation": "xor"}
    summary = run(cfg, tmp_path / "out", progress=False)
    assert list(summary.failed) == [2] and "operation" in summary.failed[2]
    assert summary.made == 4
    manifest = json.loads(_manifest(tmp_path / "out"))
    assert not manifest["complete"]
    assert not any(name.startswith("items/00002/") for name in manifest["files"])


def test_manifest_leaves_out_files_of_items_that_failed_midway(tiny_config, tmp_path, monkeypatch):
    def broken_render(*args, **kwargs):
        raise RuntimeError("renderer exploded")

    monkeypatch.setattr(items, "_render", broken_render)
    summary = run(tiny_config, tmp_path / "out", progress=False)
    assert sorted(summary.failed) == [3, 4]  # the lifted items are the ones with a render
    assert (tmp_path / "out" / "items" / "00003" / "mesh.npz").is_file()  # written before the failure
    names = json.loads(_manifest(tmp_path / "out"))["files"]
    assert "items/00000/mesh.npz" in names
    assert not any(name.startswith(("items/00003/", "items/00004/")) for name in names)


def test_damaged_run_json_is_named(tiny_config, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    for text in ("{not json", "[1, 2]", '{"config_name": "x"}', "\udcff"):
        (out / "run.json").write_bytes(text.encode("utf-8", "surrogateescape"))
        with pytest.raises(ValueError, match=r"run.json \(.*run/run.json\) is (unreadable or )?damaged"):
            run(tiny_config, out, progress=False)
    assert sorted(p.name for p in out.iterdir()) == ["run.json"]


def test_two_configs_of_one_name_into_one_folder(tiny_config, tiny_reference, tmp_path):
    other = tmp_path / "tiny.toml"  # the same name, another text
    other.write_text(tiny_config.read_text().replace("count = 2", "count = 1", 1), encoding="utf-8")
    with pytest.raises(
        FileExistsError,
        match=r"holds a run of config 'tiny' with seed 3 \(.*tiny.toml, "
        r"text sha256 \w{12}\), not of config 'tiny' .*the "
        r"configs' texts differ",
    ):
        run(other, tiny_reference, progress=False)


def test_two_runs_starting_into_one_new_folder(tiny_config, tmp_path, monkeypatch):
    # the other run creates run.json between this run's look at the folder and its own write
    other = tmp_path / "other.toml"
    other.write_text(tiny_config.read_text().replace('name = "tiny"', 'name = "other"'), encoding="utf-8")
    out = tmp_path / "run"
    real = LocalStore.prepare

    def prepare(self):
        empty = real(self)
        monkeypatch.setattr(LocalStore, "prepare", real)
        claim_out(LocalStore(self.root), load_config(other), 3)
        return empty

    monkeypatch.setattr(LocalStore, "prepare", prepare)
    with pytest.raises(FileExistsError, match=r"holds a run of config 'other'.*another config"):
        run(tiny_config, out, progress=False)
    assert json.loads((out / "run.json").read_text())["config_name"] == "other"
    assert not (out / "items").exists()


def test_a_run_taken_over_while_running_writes_no_index(tiny_config, tmp_path, monkeypatch):
    other = tiny("other")
    out = tmp_path / "run"
    real = executors.make_item

    def make(job, store):
        if job.spec.index == 2:  # the other run replaces run.json meanwhile
            (out / "run.json").write_bytes(run_info(load_config(other), 3))
        return real(job, store)

    monkeypatch.setattr(executors, "make_item", make)
    with pytest.raises(FileExistsError, match=r"holds a run of config 'other'"):
        run(tiny_config, out, progress=False)
    assert not (out / "manifest.json").exists()


def test_made_items_missing_from_the_store_are_not_counted(tiny_config, monkeypatch):
    # a worker that wrote its item somewhere this process cannot see: never "made"
    url = f"memory://ao4d-test-{uuid.uuid4().hex[:8]}/run"
    real = executors.make_item

    def elsewhere(job, store):
        return real(job, store) if job.spec.index != 1 else {"index": 1, "seconds": {}}

    monkeypatch.setattr(executors, "make_item", elsewhere)
    summary = run(tiny_config, url, progress=False)
    assert (summary.made, list(summary.failed)) == (4, [1])
    assert "record.json is not in `out`" in summary.failed[1]
    assert not json.loads(open_store(url).read_bytes("manifest.json"))["complete"]


def test_stage_table_groups_renders_and_shares_the_total():
    summary = RunSummary(Path("x"), 2, made=2, seconds=60.0)
    summary.add_timing({"build": 1.0, "ao": 2.0, "render_a": 0.5, "picture_a": 0.25, "total": 4.0})
    summary.add_timing({"build": 1.0, "ao": 2.0, "render_b": 0.5, "picture_b": 0.25, "total": 4.0})
    rows = {line.split()[0]: line.split() for line in summary.stage_table().splitlines()[1:]}
    assert float(rows["render_*"][1]) == 1.0 and float(rows["picture_*"][1]) == 0.5
    assert float(rows["ao"][3].rstrip("%")) == 50.0 and float(rows["items"][1]) == 8.0
    assert summary.items_per_minute == 2.0 and "2 made" in str(summary)
    assert summary.around_ao == {"seconds": 0.5, "ao": 4.0, "ratio": 0.125}  # the pictures only
    summary.add_timing({"check": 0.5, "bvh": 0.25, "write": 0.25, "ao": 4.0, "samples": 9.0})
    assert summary.around_ao == {"seconds": 1.5, "ao": 8.0, "ratio": 1.5 / 8.0}
    assert "around AO (check, bvh, write, picture_*): 1.50 s = 0.19 x the ao stage" in summary.stage_table()
    assert RunSummary(Path("x"), 1, made=1).around_ao is None
