"""Tests for datasets_gen.splits: validation, determinism, fractions, and splits in a run."""

from __future__ import annotations

import csv
import json
from collections import Counter

import numpy as np
import pytest
from _datasets import BALL, BOX_PRISM, config, family

from datasets_gen import ConfigError, load_config, run
from datasets_gen.splits import check_split, split_of

FRACTIONS = {"train": 0.8, "val": 0.1, "test": 0.1}


def test_split_depends_only_on_seed_and_index():
    a = [split_of(FRACTIONS, 7, i) for i in range(50)]
    assert a == [split_of(FRACTIONS, 7, i) for i in range(50)]
    assert a[20:30] == [split_of(FRACTIONS, 7, i) for i in range(20, 30)]  # any order
    assert a != [split_of(FRACTIONS, 8, i) for i in range(50)]
    assert split_of(None, 7, 3) is None


@pytest.mark.parametrize("n", [10, 40, 1000])
def test_fractions_hold_on_every_block_of_items(n):
    for seed in range(5):
        for start in (0, 13):
            counts = Counter(split_of(FRACTIONS, seed, i) for i in range(start, start + n))
            for name, frac in FRACTIONS.items():
                assert abs(counts[name] - frac * n) <= 2, (seed, start, counts)


def test_a_zero_fraction_gets_no_items():
    split = {"train": 0.5, "val": 0.0, "test": 0.5}
    assert "val" not in {split_of(split, 0, i) for i in range(200)}


@pytest.mark.parametrize(
    "value, message",
    [
        ({"train": 0.8, "val": 0.1}, "sum to 1"),
        ({"train": 1.2, "val": -0.2}, r"\[0, 1\]"),
        ({"train": "a"}, r"split.train"),
        ({}, "table"),
        ({"tr ain": 1.0}, "identifiers"),
    ],
)
def test_bad_split_tables(value, message):
    with pytest.raises(ValueError, match=message):
        check_split(value)


def test_bad_split_in_a_config_is_a_config_error(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('split = { train = 0.7, test = 0.2 }\n[[family]]\nkind = "hypersphere"\n')
    with pytest.raises(ConfigError, match=r"c.toml.*sum to 1"):
        load_config(path)


CONFIG = config(
    "splits",
    2,
    [family("hypersphere", 7, BALL), family("lifted", 1, BOX_PRISM)],
    split={"train": 0.5, "val": 0.25, "test": 0.25},
    grid=6,
    padding=0.2,
    ao=False,
    samples={"uniform": 60, "near_surface": 20, "sigmas": [0.05], "surface": 20},
    sequence={"frames": 2},
)


def _splits(folder):
    with open(folder / "items.csv") as fh:
        rows = list(csv.DictReader(fh))
    records = [json.loads((folder / "items" / f"{int(r['index']):05d}" / "record.json").read_text()) for r in rows]
    assert [r["split"] for r in rows] == [rec["split"] for rec in records]
    return [r["split"] for r in rows]


def test_splits_and_samples_are_the_same_for_any_worker_count(tmp_path):
    # the samples and sequences (field and mesh labels) are byte-identical too: same manifest
    one = run(CONFIG, tmp_path / "one", progress=False)
    two = run(CONFIG, tmp_path / "two", workers=2, progress=False)
    assert not one.failed and not two.failed
    a, b = _splits(tmp_path / "one"), _splits(tmp_path / "two")
    assert a == b == [split_of({"train": 0.5, "val": 0.25, "test": 0.25}, 2, i) for i in range(8)]
    assert set(a) == {"train", "val", "test"}
    assert (tmp_path / "one" / "manifest.json").read_bytes() == (tmp_path / "two" / "manifest.json").read_bytes()
    # the sequences hold per-frame samples (the lifted item's labelled by rays from its generator)
    for index in (0, 7):
        with np.load(tmp_path / "two" / "items" / f"{index:05d}" / "sequence.npz") as z:
            assert len(z["frame_points"]) == len(z["frame_occupancy"]) == len(z["frame_sdf"]) > 0
