"""Tests for datasets_gen.transforms.SubsamplePoints and datasets_gen.collate: fixed-size items,
deterministic per (seed, item, epoch), batched by PyTorch's default collate in spawned workers
(or by a spawned process pool where torch is not installed)."""

from __future__ import annotations

import importlib.util
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from _datasets import BALL, BOX_PRISM, config, family, learning, made_once, make

import datasets_gen
from datasets_gen import collate, load
from datasets_gen.transforms import SubsamplePoints

CONFIG = learning(
    "batches",
    2,
    [family("hypersphere", 3, BALL), family("lifted", 1, BOX_PRISM, rotation="none")],
    split={"train": 0.75, "test": 0.25},
    points=(120, 40, 60),
)

dataset = made_once(CONFIG)


def test_fixed_rows_taken_together_from_each_group(dataset):
    full = load(dataset)
    ds = load(dataset, transform=SubsamplePoints(points=50, surface=20, seed=1))
    for i in range(len(ds)):
        item, raw = ds[i], full[i]
        assert item["points"].shape == (50, 4) and item["occupancy"].shape == (50,) and item["sdf"].shape == (50,)
        assert item["surface_points"].shape == (20, 4) and item["surface_ao"].shape == (20,)
        assert "vertices" not in item and "record" not in item and item["index"] == ds.indices[i]
        # the rows of one group are the same rows of each of its arrays, drawn without replacement
        rows = [int(np.flatnonzero((raw["points"] == p).all(axis=1))[0]) for p in item["points"]]
        assert len(set(rows)) == 50
        np.testing.assert_array_equal(item["occupancy"], raw["occupancy"][rows])
        np.testing.assert_array_equal(item["sdf"], raw["sdf"][rows])
        np.testing.assert_array_equal(item["loc"], raw["record"]["normalization"]["loc"])


def test_deterministic_per_epoch_and_different_across_epochs(dataset):
    a = load(dataset, transform=SubsamplePoints(points=30, surface=10, seed=5))
    b = load(dataset, transform=SubsamplePoints(points=30, surface=10, seed=5))
    np.testing.assert_array_equal(a[2]["points"], b[2]["points"])
    np.testing.assert_array_equal(a[2]["points"], a[2]["points"])
    epoch0 = a[2]["points"]
    a.set_epoch(1)
    assert not np.array_equal(a[2]["points"], epoch0)
    a.set_epoch(0)
    np.testing.assert_array_equal(a[2]["points"], epoch0)
    other_seed = load(dataset, transform=SubsamplePoints(points=30, surface=10, seed=6))
    assert not np.array_equal(other_seed[2]["points"], epoch0)
    assert not np.array_equal(a[1]["points"], a[2]["points"])


def test_more_rows_than_an_item_has_are_drawn_with_replacement_said_once(dataset):
    ds = load(dataset, transform=SubsamplePoints(points=500, surface=None))
    with pytest.warns(UserWarning, match="fewer than the 500 asked.*with replacement") as caught:
        items = [ds[i] for i in range(len(ds))]
    assert len(caught) == 1
    assert all(it["points"].shape == (500, 4) for it in items) and "surface_points" not in items[0]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"points": 0}, "`points` must be a positive integer"),
        ({"points": -3}, "`points`"),
        ({"surface": 2.5}, "`surface`"),
        ({"points": True}, "`points`"),
        ({"points": None, "surface": None}, "both None"),
        ({"seed": -1}, "`seed`"),
    ],
)
def test_bad_counts(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SubsamplePoints(**kwargs)


def test_an_item_without_samples(tmp_path):
    bare = make(tmp_path, config("bare", 2, [family("hypersphere", 1, BALL)], grid=6, ao=False))
    with pytest.raises(ValueError, match="item 0 has none of points, occupancy, sdf"):
        load(bare, transform=SubsamplePoints(points=8))[0]


def test_collate_stacks_what_has_one_shape_and_lists_the_rest(dataset):
    ds = load(dataset)
    batch = collate([ds[i] for i in range(3)])
    assert batch["points"].shape == (3, 160, 4) and batch["occupancy"].dtype == bool
    assert isinstance(batch["record"], list) and [r["index"] for r in batch["record"]] == ds.indices[:3]
    np.testing.assert_array_equal(batch["index"], ds.indices[:3])
    sizes = {len(ds[i]["vertices"]) for i in range(3)}
    if len(sizes) > 1:
        assert isinstance(batch["vertices"], list)
    with pytest.raises(ValueError, match="`batch` is empty"):
        collate([])
    with pytest.raises(ValueError, match="`batch` item 1 has keys"):
        collate([{"a": 1}, {"b": 2}])


def _batch_of(args):
    ds, positions = args
    return collate([ds[i] for i in positions])


def test_batches_in_spawned_workers(dataset):
    ds = load(dataset, split="train", dtype="float32", transform=SubsamplePoints(points=64, surface=16))
    want = [ds[i] for i in range(len(ds))]
    if importlib.util.find_spec("torch") is not None:
        import torch

        loader = torch.utils.data.DataLoader(
            ds, batch_size=2, num_workers=2, shuffle=True, multiprocessing_context="spawn", drop_last=False
        )
        got = {}
        for batch in loader:  # PyTorch's default collate
            assert batch["points"].dtype == torch.float32 and batch["points"].shape[1:] == (64, 4)
            for k, index in enumerate(batch["index"].tolist()):
                got[index] = batch["points"][k].numpy()
    else:
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
            batches = list(pool.map(_batch_of, [(ds, [0, 1]), (ds, list(range(2, len(ds))))]))
        got = {int(i): b["points"][k] for b in batches for k, i in enumerate(b["index"])}
    assert sorted(got) == ds.indices
    for item in want:
        np.testing.assert_array_equal(got[item["index"]], item["points"])  # the same rows in a worker


def test_package_exports():
    assert datasets_gen.collate is collate and datasets_gen.transforms.SubsamplePoints is SubsamplePoints
    assert repr(SubsamplePoints(points=8)) == "SubsamplePoints(points=8, surface=None, seed=0)"
