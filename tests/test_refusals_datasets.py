"""Hostile inputs to dataset generation ("nothing silently wrong"):
each is refused at config load with a message naming the key (or file), or handled without
losing anything, before any long work."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from _datasets import BALL, config, family, write_config

from datasets_gen import ConfigError, load_config, run
from datasets_gen.config import MAX_ITEMS, Config, config_text
from datasets_gen.runner import main
from datasets_gen.samples import MAX_SIGMA

# one small hypersphere: a run of it takes about a second
SMALL = config("small", 0, [family("hypersphere", 1, BALL)], grid=6, padding=0.2, ao=False)


def _with(**defaults) -> dict:
    """:data:`SMALL` with some defaults set."""
    data = copy.deepcopy(SMALL)
    data["defaults"].update(defaults)
    return data


def _param(spec) -> dict:
    """:data:`SMALL` with the hypersphere's radius given by ``spec``."""
    data = copy.deepcopy(SMALL)
    data["family"][0]["params"] = {"radius": spec}
    return data


# --------------------------------------------------------------------------- samples.sigmas


@pytest.mark.parametrize("sigmas", [[0.01, 0.01], [0.1, 0.10000000000000001], [1, 1.0]])
def test_repeated_sigmas_are_refused(sigmas):
    # the record's rows are keyed by sigma: a repeat overwrote the first block's rows
    samples = {"uniform": 10, "near_surface": 5, "sigmas": sigmas, "surface": 5}
    with pytest.raises(ConfigError, match=r"samples\.sigmas.*distinct"):
        load_config(_with(samples=samples))


@pytest.mark.parametrize("sigma", [1e308, MAX_SIGMA * 1.5])
def test_a_sigma_past_the_bound_is_refused(sigma):
    # 1e308 box diagonals made a third of the stored points inf
    samples = {"uniform": 10, "near_surface": 5, "sigmas": [sigma], "surface": 5}
    with pytest.raises(ConfigError, match=r"samples\.sigmas.*at most"):
        load_config(_with(samples=samples))
    samples["sigmas"] = [MAX_SIGMA]
    assert load_config(_with(samples=samples)).families[0].settings["samples"]["sigmas"] == [MAX_SIGMA]


def test_too_many_points_per_item_are_refused():
    samples = {"uniform": 1 << 24, "near_surface": 1 << 24, "sigmas": [0.01], "surface": 0}
    with pytest.raises(ConfigError, match=r"`samples` asks for 33554432 points"):
        load_config(_with(samples=samples))


# --------------------------------------------------------------------------- numbers


@pytest.mark.parametrize(
    "settings, match",
    [
        ({"padding": True}, r"`padding` must be a number"),
        ({"padding": math.nan}, r"`padding` must be a number"),
        ({"bounds": [-math.inf, math.inf]}, r"`bounds` must be \[lo, hi\], finite"),
        ({"bounds": [False, True]}, r"`bounds` must be \[lo, hi\], finite"),
        ({"bounds": [-1e308, 1e308]}, r"`bounds` must be \[lo, hi\], finite"),
        ({"ao": {"max_distance": True}}, r"`ao.max_distance` must be a number"),
        ({"ao": {"samples": 10**9}}, r"`ao.samples` must be an integer in \[1, 65536\]"),
        ({"renders": [{"name": "v", "shape": [True, 8, 8]}]}, r"render 'v': `shape`"),
        ({"renders": [{"name": "v", "samples": "many"}]}, r"render 'v': `samples`"),
        ({"renders": [{"name": "v", "fov": math.inf}]}, r"render 'v': `fov`"),
    ],
)
def test_bad_numbers_in_settings_are_refused(settings, match):
    with pytest.raises(ConfigError, match=r"\[\[family\]\] #1 \(hypersphere\): " + match):
        load_config(_with(**settings))


@pytest.mark.parametrize(
    "spec, match",
    [
        ({"uniform": [0.5, math.inf]}, r"params\.radius: `uniform` needs two finite numbers"),
        ({"normal": [math.nan, 0.1]}, r"params\.radius: `normal` needs two finite numbers"),
        ({"uniform": [-1e308, 1e308]}, r"params\.radius: `uniform` needs a range b - a that is a finite"),
        ({"choice": [0.5, math.inf]}, r"params\.radius\.choice\[1\]: must be finite"),
        ({"choice": [0.5, {"uniform": [0, 1]}]}, r"params\.radius\.choice\[1\]: must be a number"),
        (math.nan, r"params\.radius: must be finite"),
        (True, r"params\.radius: must be a number or a string, got the bool"),
    ],
)
def test_bad_parameters_are_refused_at_load(spec, match):
    # [0.5, inf] passed the check, and every item then failed with an OverflowError
    with pytest.raises(ConfigError, match=match):
        load_config(_param(spec))


@pytest.mark.parametrize(
    "kind, params, match",
    [
        ("metaballs", {"n": 10**7}, r"params\.n: must be an integer in \[1, 64\]"),
        ("metaballs", {"n": {"uniform": [2, 5]}}, r"params\.n: must be an integer"),
        ("tesseracts", {"n": {"integers": [1, 100]}}, r"params\.n: must be an integer in \[1, 64\]"),
        ("lifted", {"detail": 40}, r"params\.detail: must be an integer in \[0, 6\]"),
        ("lifted", {"op": "spin", "k": {"choice": [6, 10**9]}}, r"params\.k: must be an integer in \[3, 1024\]"),
    ],
)
def test_counts_of_parts_are_bounded_at_load(kind, params, match):
    # ten million metaballs ran for minutes in every item before failing
    data = copy.deepcopy(SMALL)
    data["family"] = [family(kind, 1, params)]
    with pytest.raises(ConfigError, match=rf"\({kind}\): " + match):
        load_config(data)


def test_numpy_values_in_a_mapping_become_plain_numbers():
    data = _with(padding=np.float64(0.1), grid=np.int64(6))
    data["family"][0]["params"] = {"radius": {"uniform": np.array([0.5, 0.8])}}
    cfg = load_config(data)
    assert "np." not in cfg.text and "padding = 0.1\n" in cfg.text
    plain = _with(padding=0.1, grid=6)
    plain["family"][0]["params"] = {"radius": {"uniform": [0.5, 0.8]}}
    assert cfg.text == config_text(plain)
    assert cfg.families[0].settings["padding"] == 0.1 and type(cfg.families[0].settings["grid"]) is int


def test_odd_strings_in_a_mapping_round_trip_or_are_refused():
    # DEL must be escaped in TOML: written raw, the text did not parse
    assert load_config({**SMALL, "description": "bad\x7f"}).text.count("\\u007f") == 1
    with pytest.raises(ConfigError, match=r"description: .* not valid Unicode"):
        load_config({**SMALL, "description": "x\ud800"})


# --------------------------------------------------------------------------- counts


@pytest.mark.parametrize("counts", [[100_000_000], [MAX_ITEMS, 1]])
def test_too_many_items_are_refused_before_any_is_listed(counts, monkeypatch):
    def never(self):
        raise AssertionError("items() built")

    monkeypatch.setattr(Config, "items", never)
    data = copy.deepcopy(SMALL)
    data["family"] = [family("hypersphere", n, BALL) for n in counts]
    with pytest.raises(ConfigError, match=rf"`count`.*(\[1, {MAX_ITEMS}\]|at most {MAX_ITEMS})"):
        load_config(data)


def test_list_counts_items_without_building_them(tmp_path, monkeypatch, capsys):
    def never(self):
        raise AssertionError("items() built")

    data = copy.deepcopy(SMALL)
    data["family"] = [family("hypersphere", MAX_ITEMS, BALL)]
    path = write_config(tmp_path, data)
    monkeypatch.setattr(Config, "items", never)
    assert main([str(path), "--list"]) == 0
    assert f"{MAX_ITEMS} items" in capsys.readouterr().out


# --------------------------------------------------------------------------- files and the CLI


def test_a_config_file_with_a_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + config_text(SMALL).encode("utf-8"))
    assert load_config(path).text == config_text(SMALL)


def test_a_config_file_not_in_utf8_is_refused_naming_it(tmp_path):
    path = tmp_path / "latin.toml"
    path.write_bytes(config_text({**SMALL, "description": "bo\u00eete"}).encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin\.toml: a configuration file must be UTF-8"):
        load_config(path)


@pytest.mark.parametrize("word", ["run", "resume"])
def test_a_subcommand_like_word_is_no_config(word, capsys):
    # `run` without --out is named as no config, not asked for its --out as if it were one
    assert main([word]) == 2
    err = capsys.readouterr().err
    assert f"no config {word!r}" in err and "usage: python -m datasets_gen CONFIG --out DIR" in err
    assert "smoke" in err and "tori" in err


# --------------------------------------------------------------------------- splits


def test_an_empty_split_warns_and_is_listed(tmp_path, capsys):
    data = {**SMALL, "split": {"train": 1.0, "val": 0.0}}
    with pytest.warns(UserWarning, match=r"split\(s\) 'val' get no item of the 1 items"):
        summary = run(data, tmp_path / "out", progress=False)
    assert not summary.failed
    stats = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert stats["splits"] == {"train": 1, "val": 0} and stats["empty_splits"] == ["val"]
    info = json.loads((tmp_path / "out" / "run.json").read_text())
    assert info["split"] == {"train": 1.0, "val": 0.0}
    # on the command line too, as a plain line
    path = write_config(tmp_path, data)
    assert main([str(path), "--out", str(tmp_path / "cli"), "--no-progress"]) == 0
    assert "warning: `split` { train = 1, val = 0 }: split(s) 'val' get no item" in capsys.readouterr().err


def test_no_split_table_leaves_run_json_and_summary_as_they_were(tmp_path):
    run(SMALL, tmp_path / "out", progress=False)
    assert "split" not in json.loads((tmp_path / "out" / "run.json").read_text())
    stats = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "splits" not in stats and "empty_splits" not in stats


# --------------------------------------------------------------------------- lost data


def test_a_remade_item_keeps_files_the_run_did_not_write(tmp_path):
    out = tmp_path / "out"
    assert not run(SMALL, out, progress=False).failed
    item = out / "items" / "00000"
    (item / "notes.txt").write_text("mine")
    (item / ".mesh.npz.0123abcd.tmp.npz").write_bytes(b"an interrupted write")
    (item / "mesh.npz").write_bytes(b"damaged")
    with pytest.warns(UserWarning, match=r"items/00000: notes\.txt\).*left as they are"):
        summary = run(SMALL, out, progress=False)
    assert summary.made == 1 and not summary.failed
    assert (item / "notes.txt").read_text() == "mine"
    assert not (item / ".mesh.npz.0123abcd.tmp.npz").exists()  # the run's own leftover
    assert "items/00000/notes.txt" not in json.loads((out / "manifest.json").read_text())["files"]


def test_items_csv_indices_are_plain_integers(tmp_path):
    out = tmp_path / "out"
    data = copy.deepcopy(SMALL)
    data["family"][0]["count"] = 2
    run(data, out, progress=False)
    rows = (out / "items.csv").read_text().splitlines()[1:]
    assert [row.split(",")[0] for row in rows] == ["0", "1"]
