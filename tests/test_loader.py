"""Tests for datasets_gen.loader: load() on a small dataset with samples, splits and sequences."""

from __future__ import annotations

import multiprocessing
import os
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from _datasets import BALL, BOX_PRISM, config, family, learning, made_once, make

import datasets_gen
from datasets_gen import DatasetError, load

CONFIG = learning(
    "loader",
    1,
    [family("hypersphere", 3, BALL), family("lifted", 1, BOX_PRISM, rotation="none")],
    split={"train": 0.5, "val": 0.25, "test": 0.25},
    points=(300, 100, 200),
    grid=8,
    sequence={"frames": 3},
)

dataset = made_once(CONFIG)


def test_items_hold_the_files_arrays_and_record(dataset):
    ds = load(dataset)
    assert len(ds) == 4 and ds.indices == [0, 1, 2, 3]
    item = ds[0]
    with np.load(dataset / "items/00000/mesh.npz") as z:
        np.testing.assert_array_equal(item["vertices"], z["vertices"])
        np.testing.assert_array_equal(item["simplices"], z["simplices"])
    with np.load(dataset / "items/00000/samples.npz") as z:
        for name in ("points", "occupancy", "sdf", "surface_points", "surface_normals", "surface_ao"):
            np.testing.assert_array_equal(item[name], z[name])
    assert item["ao"].shape == (len(item["vertices"]),)
    assert item["points"].shape == (400, 4) and item["record"]["index"] == 0
    assert [r["index"] for r in ds.records] == [0, 1, 2, 3]
    assert ds[-1]["record"]["kind"] == "lifted"
    with pytest.raises(IndexError):
        ds[4]


def test_splits_are_disjoint_and_cover_the_dataset(dataset):
    full = load(dataset)
    names = {r["split"] for r in full.records}
    parts = {name: load(dataset, split=name).indices for name in names}
    every = sorted(i for idx in parts.values() for i in idx)
    assert every == full.indices
    for name, idx in parts.items():
        assert all(full.record(i)["split"] == name for i in idx)
    with pytest.raises(DatasetError, match="'nope' is not a split"):
        load(dataset, split="nope")


def test_normalize_and_transform(dataset):
    raw, norm = load(dataset)[1], load(dataset, normalize=True)[1]
    loc, scale = np.array(raw["record"]["normalization"]["loc"]), raw["record"]["normalization"]["scale"]
    np.testing.assert_allclose(norm["vertices"], (raw["vertices"] - loc) / scale)
    assert np.linalg.norm(norm["vertices"], axis=1).max() == pytest.approx(1.0)
    np.testing.assert_allclose(norm["points"], (raw["points"] - loc) / scale, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(norm["sdf"], raw["sdf"] / scale, rtol=1e-6)
    np.testing.assert_array_equal(norm["occupancy"], raw["occupancy"])
    ds = load(dataset, transform=lambda item: item["points"].shape)
    assert ds[0] == (400, 4)


def test_verify_names_the_item_and_file(tmp_path, dataset):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    path = copy / "items/00002/samples.npz"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"item 2: samples.npz .*checksum"):
        load(copy, verify=True)[2]
    load(copy, verify=True)[1]  # the other items still load
    with pytest.raises(DatasetError, match=r"item 2: samples.npz is damaged"):
        load(copy)[2]  # without verify: a damaged archive is still a clear error


def _points_sum(args):
    ds, i = args
    return float(ds[i]["points"].astype(np.float64).sum())


def test_loads_in_a_process_pool_and_pickles(dataset):
    ds = load(dataset, verify=True)
    ds.records  # noqa: B018 - cached state must pickle too
    again = pickle.loads(pickle.dumps(ds))
    assert len(again) == len(ds)
    want = [_points_sum((ds, i)) for i in range(len(ds))]
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        assert list(pool.map(_points_sum, [(ds, i) for i in range(len(ds))])) == want


def test_frames_of_an_item_without_a_sequence(tmp_path, dataset):
    import json
    import shutil

    copy = shutil.copytree(dataset, tmp_path / "copy")
    path = copy / "items/00000/record.json"
    rec = json.loads(path.read_text())
    del rec["files"]["sequence.npz"]
    path.write_text(json.dumps(rec))
    with pytest.raises(DatasetError, match="item 0 has no sequence.npz"):
        load(copy).frames(0)


def test_fsspec_url_and_frames(dataset):
    ds = load(f"file://{dataset}")
    np.testing.assert_array_equal(ds[3]["sdf"], load(dataset)[3]["sdf"])
    frames = ds.frames(0)
    assert len(frames) == 3 and all(0 <= f.metadata["time"] <= 1 for f in frames)
    assert "ao" in frames[0].vertex_attributes
    # normalised frames: the slice of the normalised item (axis w: frame coordinates are x, y, z)
    rec = ds.record(0)
    loc, scale = np.array(rec["normalization"]["loc"]), rec["normalization"]["scale"]
    for raw, norm in zip(frames, load(dataset, normalize=True).frames(0)):
        np.testing.assert_allclose(norm.vertices, (raw.vertices - loc[:3]) / scale)


def test_frame_samples(tmp_path, dataset):
    import json
    import shutil

    ds, normed = load(dataset), load(dataset, normalize=True)
    rec = ds.record(0)
    info = rec["sequence"]["frame_samples"]
    frames, samples = ds.frames(0), ds.frame_samples(0)
    assert len(samples) == len(frames) == 3
    loc, scale = np.array(rec["normalization"]["loc"]), rec["normalization"]["scale"]
    with np.load(dataset / "items/00000/sequence.npz") as z:
        np.testing.assert_array_equal(np.concatenate([f["points"] for f in samples]), z["frame_points"])
        np.testing.assert_array_equal(np.concatenate([f["surface_ao"] for f in samples]), z["frame_surface_ao"])
    for frame, sample, norm in zip(frames, samples, normed.frame_samples(0)):
        assert sample["time"] == frame.metadata["time"]
        assert len(sample["points"]) == info["uniform"] + info["near_surface"] * len(info["sigmas"])
        assert len(sample["surface_points"]) == info["surface"]
        np.testing.assert_array_equal(sample["sdf"] < 0, sample["occupancy"])
        # axis w: the frame's coordinates are x, y, z, normalised as the frame's vertices
        np.testing.assert_allclose(norm["points"], (sample["points"] - loc[:3]) / scale, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(norm["sdf"], sample["sdf"] / scale, rtol=1e-6)
        np.testing.assert_array_equal(norm["surface_normals"], sample["surface_normals"])
    copy = shutil.copytree(dataset, tmp_path / "copy")  # a sequence made without samples
    path = copy / "items/00000/sequence.npz"
    with np.load(path) as z:
        kept = {k: z[k] for k in z.files if not k.startswith("frame_")}
    np.savez(path, **kept)
    rec_path = copy / "items/00000/record.json"
    del rec["sequence"]["frame_samples"]
    rec_path.write_text(json.dumps(rec))
    with pytest.raises(DatasetError, match="item 0: its sequence.npz has no frame samples"):
        load(copy).frame_samples(0)


def test_not_a_dataset(tmp_path):
    with pytest.raises(DatasetError, match="holds no readable dataset"):
        datasets_gen.load(tmp_path)


def test_dataset_labels_against_analytic_volumes(dataset):
    # every item: the uniform points' inside fraction x the box's 4-volume is the solid's
    # analytic 4-volume, within 5 binomial standard deviations; sdf < 0 exactly where inside
    for item in load(dataset):
        rec = item["record"]
        n = rec["samples"]["uniform"]
        lo, hi = (np.array(b) for b in rec["samples"]["box"])
        box = float(np.prod(hi - lo))
        p = rec["mesh"]["volume_expected"] / box
        frac = item["occupancy"][:n].mean()
        assert abs(frac - p) <= 5 * np.sqrt(p * (1 - p) / n), rec["index"]
        np.testing.assert_array_equal(item["sdf"] < 0, item["occupancy"])
        assert set(rec["samples"]["labels"]) >= {"occupancy", "sdf", "surface_points"}


@pytest.mark.parametrize("url", ["nosuchprotocol://x/y", "://x"])
def test_a_url_the_loader_cannot_open_names_its_parameter(url):
    # the writer's store says `out`; a user of load() gave `path`
    with pytest.raises((ValueError, DatasetError), match="`path`"):
        load(url)[0]


# ---- keys, dtype, epochs ---------------------------------------------------------------------


def _reads(monkeypatch):
    """The relative paths the loader reads from a local folder, in order."""
    from datasets_gen._store import LocalStore

    seen: list[str] = []
    real = LocalStore.read_bytes

    def read_bytes(self, rel):
        seen.append(rel)
        return real(self, rel)

    monkeypatch.setattr(LocalStore, "read_bytes", read_bytes)
    return seen


def test_keys_open_only_the_files_they_live_in(dataset, monkeypatch):
    seen = _reads(monkeypatch)
    ds = load(dataset, keys=("points", "occupancy", "surface_points"))
    for i in range(len(ds)):
        item = ds[i]
        assert sorted(item) == ["index", "occupancy", "points", "surface_points"]
        assert item["index"] == ds.indices[i]
    opened = {rel.rpartition("/")[2] for rel in seen if rel.startswith("items/")}
    assert opened == {"record.json", "samples.npz"}  # never mesh.npz nor ao.npz
    full = load(dataset)
    for i in range(len(ds)):
        for name in ("points", "occupancy", "surface_points"):
            np.testing.assert_array_equal(ds[i][name], full[i][name])
    seen.clear()
    mesh_only = load(dataset, keys=("vertices", "record"))
    assert sorted(mesh_only[0]) == ["index", "record", "vertices"]
    assert {rel.rpartition("/")[2] for rel in seen if rel.startswith("items/")} == {"record.json", "mesh.npz"}


def test_dtype_casts_every_floating_array_and_keeps_the_others(dataset):
    full, cast = load(dataset, normalize=True), load(dataset, normalize=True, dtype="float32")
    a, b = full[0], cast[0]
    for name, value in a.items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f":
            assert b[name].dtype == np.float32
            np.testing.assert_array_equal(b[name], value.astype(np.float32))
        elif isinstance(value, np.ndarray):
            assert b[name].dtype == value.dtype and np.array_equal(b[name], value)
    assert a["vertices"].dtype == np.float64 and a["occupancy"].dtype == bool


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"keys": ("points", "mesh")}, ValueError, "`keys` names 'mesh'"),
        ({"keys": "points"}, TypeError, "`keys` must be a sequence"),
        ({"keys": ()}, ValueError, "`keys` names nothing"),
        ({"dtype": "int32"}, ValueError, "`dtype` must be a floating type"),
        ({"dtype": "float31"}, ValueError, "`dtype`"),
        ({"split": 3}, TypeError, "`split`"),
    ],
)
def test_bad_keys_and_dtype(dataset, kwargs, error, match):
    with pytest.raises(error, match=match):
        load(dataset, **kwargs)


def test_keys_that_the_dataset_does_not_store(tmp_path):
    bare = make(tmp_path, config("bare", 2, [family("hypersphere", 1, BALL)], grid=6, ao=False))
    with pytest.raises(DatasetError, match=r"`keys` 'points'.*has no samples.npz"):
        load(bare, keys=("points",))
    with pytest.raises(DatasetError, match=r"`keys` 'ao'.*has no ao.npz"):
        load(bare, keys=("vertices", "ao"))
    assert sorted(load(bare)[0]) == ["index", "record", "simplices", "vertices"]


def test_set_epoch_reaches_the_transform(dataset):
    class Probe:
        epoch = None

        def set_epoch(self, k):
            self.epoch = k

        def __call__(self, item):
            return self.epoch

    ds = load(dataset, transform=Probe())
    assert ds[0] is None
    ds.set_epoch(3)
    assert ds.epoch == 3 and ds[0] == 3
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="`epoch`"):
            ds.set_epoch(bad)


# ---- a split the config names always exists --------------------------------------------------


def test_a_split_that_received_no_item_exists_and_is_empty(tmp_path):
    with pytest.warns(UserWarning, match="'val' get no item"):
        empty = make(
            tmp_path,
            config("empty", 5, [family("hypersphere", 2, BALL)], split={"train": 0.5, "val": 0.0, "test": 0.5}, grid=6),
        )
    ds = load(empty)
    assert ds.splits == ["train", "val", "test"]
    assert len(load(empty, split="val")) == 0 and list(load(empty, split="val")) == []
    assert len(load(empty, split="train")) + len(load(empty, split="test")) == 2
    with pytest.raises(DatasetError, match="`split` 'valid' is not a split.*'train', 'val', 'test'"):
        load(empty, split="valid")


# ---- nothing silently wrong: a damaged or hostile dataset folder ----------------------------


@pytest.fixture
def damaged(tmp_path, dataset):
    import shutil

    return shutil.copytree(dataset, tmp_path / "copy")


@pytest.mark.parametrize("verify", [False, True])
@pytest.mark.parametrize("cut", ["emptied", "two rows", "duplicated row", "header only"])
def test_a_truncated_or_duplicated_index_is_an_error(damaged, cut, verify):
    path = damaged / "items.csv"
    lines = path.read_text().splitlines(keepends=True)
    text = {
        "emptied": "",
        "two rows": "".join(lines[:3]),
        "duplicated row": "".join(lines + lines[-1:]),
        "header only": lines[0],
    }[cut]
    path.write_text(text)
    with pytest.raises(DatasetError, match="items.csv"):
        load(damaged, verify=verify)


def test_an_index_without_its_index_column(damaged):
    path = damaged / "items.csv"
    path.write_text(path.read_text().replace("index,", "number,", 1))
    with pytest.raises(DatasetError, match="items.csv is damaged: it has no `index` column"):
        load(damaged)


def _edit_record(folder, index, edit):
    import json

    path = folder / f"items/{index:05d}/record.json"
    rec = json.loads(path.read_text())
    rec = edit(rec)
    path.write_text(json.dumps(rec))


def test_a_record_without_files_is_an_error(damaged):
    _edit_record(damaged, 1, lambda r: {k: v for k, v in r.items() if k != "files"})
    with pytest.raises(DatasetError, match="item 1: record.json is damaged: it has no `files`"):
        load(damaged)[1]
    load(damaged)[0]


def test_a_record_that_is_not_a_table(damaged):
    _edit_record(damaged, 2, lambda r: [1])
    with pytest.raises(DatasetError, match="item 2: record.json is damaged"):
        load(damaged)[2]


def test_a_record_without_normalization_under_normalize(damaged):
    _edit_record(damaged, 0, lambda r: {k: v for k, v in r.items() if k != "normalization"})
    load(damaged)[0]  # not needed without normalize
    with pytest.raises(DatasetError, match="item 0: record.json has no valid `normalization`"):
        load(damaged, normalize=True)[0]


def test_records_are_copies(dataset):
    ds = load(dataset, normalize=True)
    first = ds[0]["points"].copy()
    item = ds[0]
    item["record"]["normalization"]["scale"] = 1000.0
    ds.record(0)["normalization"]["loc"][0] = 99.0
    ds.records[0]["index"] = 7
    np.testing.assert_array_equal(ds[0]["points"], first)
    assert ds.record(0)["index"] == 0


def test_a_later_chdir_reads_the_same_folder(dataset, tmp_path, monkeypatch):
    monkeypatch.chdir(dataset.parent)
    ds = load(dataset.name)
    want = ds[1]["points"]
    other = tmp_path / "elsewhere"
    (other / dataset.name).mkdir(parents=True)
    monkeypatch.chdir(other)
    np.testing.assert_array_equal(ds[1]["points"], want)
    assert ds.location == str(dataset)


def test_missing_and_unverifiable_files_say_so(damaged):
    import json

    (damaged / "items/00001/record.json").unlink()
    with pytest.raises(DatasetError, match=r"cannot read .*items/00001/record.json") as info:
        load(damaged)[1]
    assert "JSON" not in str(info.value)
    manifest = json.loads((damaged / "manifest.json").read_text())
    del manifest["files"]["items/00002/mesh.npz"]["sha256"]
    (damaged / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match=r"item 2: mesh.npz .* has no sha256 in manifest.json"):
        load(damaged, verify=True)[2]


def test_a_manifest_that_is_not_a_table(damaged):
    (damaged / "manifest.json").write_text("[]")
    with pytest.raises(DatasetError, match="manifest.json is damaged"):
        load(damaged)


def test_archives_without_their_arrays(damaged):
    with np.load(damaged / "items/00001/mesh.npz") as z:
        np.savez(damaged / "items/00001/mesh.npz", vertices=z["vertices"])
    with pytest.raises(DatasetError, match="item 1: mesh.npz has no array 'simplices'"):
        load(damaged)[1]
    with np.load(damaged / "items/00000/sequence.npz") as z:
        np.savez(damaged / "items/00000/sequence.npz", **{k: z[k] for k in z.files if k != "time"})
    with pytest.raises(DatasetError, match="item 0: sequence.npz is damaged: no array 'time'"):
        load(damaged).frames(0)


def test_bytes_paths_and_empty_paths(dataset):
    assert len(load(os.fsencode(str(dataset)))) == len(load(dataset))
    with pytest.raises(ValueError, match="`path` is empty"):
        load("")
    with pytest.raises(TypeError, match="`path`"):
        load(3)


@pytest.mark.parametrize("name", ["items.csv", "items/00002/samples.npz"])
def test_a_fifo_is_refused_not_read(damaged, name):
    path = damaged / name
    path.unlink()
    os.mkfifo(path)
    with pytest.raises(DatasetError, match="not a regular file"):
        load(damaged)[2]


def test_a_manifest_of_another_format(tmp_path):
    (tmp_path / "manifest.json").write_text('{"format": "zip", "shards": []}')
    with pytest.raises(DatasetError, match="format 'zip', neither a datasets_gen run nor an export"):
        load(tmp_path)
