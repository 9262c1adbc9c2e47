"""Tests for datasets_gen.loader: load() on a small dataset with samples, splits and sequences."""

from __future__ import annotations

import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from _datasets import BALL, BOX_PRISM, config, family, make

import datasets_gen
from datasets_gen import DatasetError, load

CONFIG = config(
    "loader",
    1,
    [family("hypersphere", 3, BALL), family("lifted", 1, BOX_PRISM, rotation="none")],
    split={"train": 0.5, "val": 0.25, "test": 0.25},
    grid=8,
    padding=0.15,
    rotation="random",
    ao={"samples": 4},
    sequence={"frames": 3},
    samples={"uniform": 300, "near_surface": 100, "sigmas": [0.02], "surface": 200},
)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make(tmp_path_factory.mktemp("loader"), CONFIG)


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
