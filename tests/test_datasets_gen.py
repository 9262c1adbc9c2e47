"""Tests for datasets_gen (its runner and configs): configs, parameter draws, reproducible and
resumable runs, the command line."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from datasets_gen import ConfigError, executors, load_config, run, shipped_configs
from datasets_gen import runner as runner_mod
from datasets_gen._files import write_json, write_npz
from datasets_gen.config import config_text, sample_params
from datasets_gen.families import build_shape, random_rotation
from datasets_gen.items import item_folder

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def _write(tmp_path: Path, text: str, name: str = "cfg.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _manifest(out: Path) -> bytes:
    return (out / "manifest.json").read_bytes()


# --------------------------------------------------------------------------- configs


@pytest.mark.parametrize("name", ["smoke", "tori", "blobs", "lifted", "thesis"])
def test_shipped_configs_load(name):
    assert name in shipped_configs()
    cfg = load_config(name)
    assert cfg.source == f"shipped:{name}" and cfg.items()
    assert [it.index for it in cfg.items()] == list(range(len(cfg.items())))


@pytest.mark.parametrize("name", ["tori", "blobs", "lifted", "thesis"])
def test_every_shipped_family_builds_a_closed_mesh(name):
    """Item 0 of each family, on a coarse grid: parameters and builders are wired correctly."""
    for fam in load_config(name).families:
        settings = {**fam.settings, "grid": 12}
        rng = np.random.default_rng(0)
        shape = build_shape(
            fam.kind,
            sample_params(fam.params, rng),
            settings,
            rng,
            random_rotation(rng) if settings["rotation"] == "random" else None,
        )
        assert shape.mesh.check().ok, fam.name
        if fam.kind == "lifted":  # exact for lifted solids (see tests/test_lift.py)
            assert shape.mesh.volume == pytest.approx(shape.volume_expected, rel=1e-9)


@pytest.mark.parametrize(
    "text, match",
    [
        ("seed = 0\n", "needs at least one"),
        ("colour = 1\n[[family]]\nkind = 'hypersphere'\n", "unknown key.*'colour'"),
        ("[[family]]\nkind = 'klein_bottle'\n", "`kind` must be one of"),
        ("[[family]]\nkind = 'hypersphere'\ncount = 0\n", r"`count` must be an integer in \[1, "),
        ("[[family]]\nkind = 'hypersphere'\nparams = { R = 1.0 }\n", "unknown key.*'R'.*allowed: center, radius"),
        ("[[family]]\nkind = 'hypersphere'\nparams = { radius = { uniform = [2, 1] } }\n", "a <= b"),
        ("[[family]]\nkind = 'hypersphere'\nparams = { radius = { gamma = [2, 1] } }\n", "a distribution is one key"),
        ("[[family]]\nkind = 'hypersphere'\nparams = { radius = { loguniform = [0, 1] } }\n", "0 < a <= b"),
        ("[[family]]\nkind = 'hypersphere'\ngrid = 2\n", "`grid` must be an integer in"),
        ("[[family]]\nkind = 'hypersphere'\nmethod = 'tets'\n", "`method` must be"),
        ("[[family]]\nkind = 'hypersphere'\nao = { samples = 0 }\n", "`ao.samples` must be"),
        ("[[family]]\nkind = 'hypersphere'\nrenders = [{ shape = [8, 8, 8] }]\n", "identifier `name`"),
        ("seed = -1\n[[family]]\nkind = 'hypersphere'\n", "`seed` must be an integer >= 0"),
        ("[[family]\n", "not valid TOML"),
    ],
)
def test_bad_configs_are_refused_naming_the_key(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_config(_write(tmp_path, text))


@pytest.mark.parametrize("name", ["smoke", "training", "thesis"])
def test_a_config_given_as_a_mapping_is_the_same_config(name):
    shipped = load_config(name)
    data = tomllib.loads(shipped.text)
    cfg = load_config(data)
    assert cfg.source == "<mapping>" and tomllib.loads(cfg.text) == data
    assert cfg.name == shipped.name and cfg.seed == shipped.seed and cfg.split == shipped.split
    assert cfg.families == shipped.families
    assert config_text(tomllib.loads(cfg.text)) == cfg.text  # a fixed point


def test_a_mapping_with_a_value_toml_cannot_hold_is_refused():
    with pytest.raises(ConfigError, match=r"family #1\.params.*NoneType"):
        load_config({"family": [{"kind": "hypersphere", "params": None}]})
    with pytest.raises(ConfigError, match="unknown key"):
        load_config({"colour": "red", "family": [{"kind": "hypersphere"}]})
    assert (
        load_config({"family": [{"kind": "hypersphere", "ao": {"max_distance": math.inf}}]})
        .families[0]
        .settings["ao"]["max_distance"]
        == math.inf
    )


def test_unknown_config_name():
    with pytest.raises(FileNotFoundError, match="neither a file nor a shipped configuration"):
        load_config("no_such_config")


def test_sample_params_draws_each_distribution_in_range():
    specs = {
        "u": {"uniform": [1.0, 2.0]},
        "l": {"loguniform": [0.01, 100.0]},
        "i": {"integers": [3, 4]},
        "c": {"choice": ["a", "b"]},
        "n": {"normal": [5.0, 0.0]},
        "k": 7,
        "s": "box",
    }
    rng = np.random.default_rng(11)
    draws = [sample_params(specs, rng) for _ in range(200)]
    assert all(1.0 <= d["u"] < 2.0 and 0.01 <= d["l"] <= 100.0 for d in draws)
    assert {d["i"] for d in draws} == {3, 4}  # both ends included
    assert {d["c"] for d in draws} == {"a", "b"}
    assert all(d["n"] == 5.0 and d["k"] == 7 and d["s"] == "box" for d in draws)
    # log-uniform: half the draws below the geometric midpoint 1 (binomial sd of 200 draws: 7)
    assert abs(sum(d["l"] < 1.0 for d in draws) - 100) < 30


def test_sample_params_do_not_depend_on_key_order():
    a = {"x": {"uniform": [0, 1]}, "y": {"uniform": [0, 1]}}
    b = dict(reversed(list(a.items())))
    assert sample_params(a, np.random.default_rng(5)) == sample_params(b, np.random.default_rng(5))


def test_random_rotation_is_a_rotation_and_spreads_directions():
    rng = np.random.default_rng(2)
    qs = np.array([random_rotation(rng) for _ in range(400)])
    assert np.allclose(qs @ qs.transpose(0, 2, 1), np.eye(4), atol=1e-12)
    assert np.allclose(np.linalg.det(qs), 1.0)
    # Haar: the image of e_w is uniform on S^3, so each coordinate has mean 0 and variance 1/4
    # (standard error of the mean: sqrt(1/4 / 400) = 0.025)
    col = qs[:, :, 3]
    assert np.all(np.abs(col.mean(axis=0)) < 0.1)
    assert np.allclose((col**2).mean(axis=0), 0.25, atol=0.05)


# --------------------------------------------------------------------------- files


def test_write_npz_is_byte_reproducible_and_loadable(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {"a": rng.normal(size=(5, 4)), "b": np.arange(7, dtype=np.int32)}
    write_npz(tmp_path / "x.npz", arrays)
    time.sleep(1.1)  # np.savez would stamp a later time into the zip here
    write_npz(tmp_path / "y.npz", arrays)
    assert (tmp_path / "x.npz").read_bytes() == (tmp_path / "y.npz").read_bytes()
    with np.load(tmp_path / "x.npz") as data:
        assert np.array_equal(data["a"], arrays["a"]) and data["b"].dtype == np.int32
    with zipfile.ZipFile(tmp_path / "x.npz") as zf:
        assert {i.date_time for i in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)}
    with pytest.raises(TypeError, match="dtype object"):
        write_npz(tmp_path / "z.npz", {"o": np.array([None])})


def test_write_json_is_canonical(tmp_path):
    write_json(tmp_path / "a.json", {"b": np.float64(1.5), "a": [np.int64(2), math.inf]})
    assert (tmp_path / "a.json").read_text() == '{\n  "a": [\n    2,\n    "inf"\n  ],\n  "b": 1.5\n}\n'


# --------------------------------------------------------------------------- runs


def test_other_seed_gives_other_items(tiny_reference, tiny_config, tmp_path):
    run(tiny_config, tmp_path / "s4", seed=4, progress=False)
    a = json.loads(_manifest(tiny_reference))["files"]
    b = json.loads(_manifest(tmp_path / "s4"))["files"]
    assert a.keys() == b.keys()
    assert a["items/00000/mesh.npz"]["sha256"] != b["items/00000/mesh.npz"]["sha256"]


def test_interrupted_run_resumes(tiny_reference, tiny_config, tmp_path, monkeypatch):
    out = tmp_path / "run"
    real = executors.make_item
    calls = []

    def interrupt_on_third(job, store):
        calls.append(job.spec.index)
        if len(calls) == 3:
            folder = out / item_folder(job.spec.index)
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "mesh.npz").write_bytes(b"half")  # as if killed mid-item
            raise KeyboardInterrupt
        return real(job, store)

    monkeypatch.setattr(executors, "make_item", interrupt_on_third)
    with pytest.raises(KeyboardInterrupt):
        run(tiny_config, out, progress=False)
    monkeypatch.setattr(executors, "make_item", real)
    summary = run(tiny_config, out, progress=False)
    assert (summary.made, summary.skipped) == (3, 2)
    assert _manifest(out) == _manifest(tiny_reference)


def test_killed_process_resumes(tiny_reference, tiny_config, tmp_path):
    """SIGKILL a real run once its first item is complete, then rerun to completion."""
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "datasets_gen", str(tiny_config), "--out", str(out), "--no-progress"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    first = out / "items" / "00000" / "record.json"
    deadline = time.monotonic() + 120
    while not first.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert first.exists()
    summary = run(tiny_config, out, progress=False)
    # killed 10 ms after item 0 completed, long before the other items (~0.1 s each) were done
    assert summary.skipped >= 1 and summary.made >= 1 and summary.made + summary.skipped == 5
    assert _manifest(out) == _manifest(tiny_reference)


def test_command_line(tiny_config, tmp_path, capsys):
    assert runner_mod.main([str(tiny_config), "--out", str(tmp_path / "o"), "--list"]) == 0
    assert "tiny" in capsys.readouterr().out
    assert runner_mod.main(["nonexistent", "--out", str(tmp_path / "o")]) == 2
    assert "neither a file nor a shipped" in capsys.readouterr().err
    assert runner_mod.main(["--kinds"]) == 0
    assert "spheritorus(R, r)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        runner_mod.main([str(tiny_config)])  # --out missing
    assert "--out" in capsys.readouterr().err


@pytest.mark.slow
def test_smoke_config_with_opencl_is_reproducible_across_workers(tmp_path, cl_runtime):
    one = run("smoke", tmp_path / "one", workers=1, progress=False)
    two = run("smoke", tmp_path / "two", workers=2, progress=False)
    assert one.made == two.made == len(load_config("smoke").items())
    assert _manifest(tmp_path / "one") == _manifest(tmp_path / "two")
