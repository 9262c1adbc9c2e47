"""Tests for datasets_gen: configs, parameter draws, reproducible and resumable runs."""

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

from datasets_gen import ConfigError, load_config, run, shipped_configs
from datasets_gen import runner as runner_mod
from datasets_gen._files import sha256_file, write_json, write_npz
from datasets_gen.config import sample_params
from datasets_gen.families import build_shape, random_rotation

# A run small enough for tests (a few seconds): implicit, CSG and lifted items, AO, one render.
# The numpy AO backend spares every spawned worker an OpenCL kernel build; the OpenCL path is
# covered by the slow test on the shipped smoke config.
TINY = """
name = "tiny"
seed = 3
backend = "numpy"

[defaults]
grid = 10
padding = 0.15
rotation = "random"
ao = { samples = 4 }

[[family]]
kind = "hypersphere"
count = 2
params = { radius = { uniform = [0.6, 0.9] } }

[[family]]
kind = "tesseracts"
count = 1
params = { n = 2, half = 0.4, spread = 0.2 }

[[family]]
kind = "lifted"
count = 2
rotation = "none"
params = { shape = "box", op = { choice = ["prism", "spin"] }, size = { uniform = [0.3, 0.5] }, k = 5 }
renders = [{ name = "view", shape = [8, 8, 8], samples = 2 }]
"""


def _write(tmp_path: Path, text: str, name: str = "cfg.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _manifest(out: Path) -> bytes:
    return (out / "manifest.json").read_bytes()


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory) -> Path:
    return _write(tmp_path_factory.mktemp("cfg"), TINY, "tiny.toml")


@pytest.fixture(scope="module")
def reference(tiny_config, tmp_path_factory) -> Path:
    """One clean single-process run of TINY, the baseline the other runs must reproduce."""
    out = tmp_path_factory.mktemp("ref") / "run"
    summary = run(tiny_config, out, progress=False)
    assert summary.made == 5 and not summary.failed, summary
    return out


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
        shape = build_shape(fam.kind, sample_params(fam.params, rng), settings, rng,
                            random_rotation(rng) if settings["rotation"] == "random" else None)
        assert shape.mesh.check().ok, fam.name
        if fam.kind == "lifted":  # exact for lifted solids (see tests/test_lift.py)
            assert shape.mesh.volume == pytest.approx(shape.volume_expected, rel=1e-9)


@pytest.mark.parametrize("text, match", [
    ("seed = 0\n", "needs at least one"),
    ("colour = 1\n[[family]]\nkind = 'hypersphere'\n", "unknown key.*'colour'"),
    ("[[family]]\nkind = 'klein_bottle'\n", "`kind` must be one of"),
    ("[[family]]\nkind = 'hypersphere'\ncount = 0\n", "`count` must be an integer >= 1"),
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
])
def test_bad_configs_are_refused_naming_the_key(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_config(_write(tmp_path, text))


def test_unknown_config_name():
    with pytest.raises(FileNotFoundError, match="neither a file nor a shipped configuration"):
        load_config("no_such_config")


def test_sample_params_draws_each_distribution_in_range():
    specs = {"u": {"uniform": [1.0, 2.0]}, "l": {"loguniform": [0.01, 100.0]},
             "i": {"integers": [3, 4]}, "c": {"choice": ["a", "b"]}, "n": {"normal": [5.0, 0.0]},
             "k": 7, "s": "box"}
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


def test_reference_run_records(reference):
    from ao4d import SimplexMesh
    from ao4d._resources import data_dir

    lut_sha = sha256_file(data_dir("lut") / "manifest.json")
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


def test_item_does_not_depend_on_order_or_neighbours(reference, tiny_config, tmp_path):
    """Item 3 made alone, in a fresh folder, has the same bytes as in the full run."""
    cfg = load_config(tiny_config)
    runner_mod._check_out(tmp_path, cfg, 3)
    runner_mod.make_item(runner_mod._Job(cfg.items()[3], 3, str(tmp_path), cfg.backend))
    for name in ("mesh.npz", "ao.npz", "view.png", "record.json"):
        a = tmp_path / "items" / "00003" / name
        assert a.read_bytes() == (reference / "items" / "00003" / name).read_bytes(), name


def test_timing_has_every_stage_and_the_run_prints_them(tiny_config, tmp_path, capsys):
    """timing.json times every stage of an item (their sum within the item's total), and the
    command line ends with the per-stage table of the items it made and items/min."""
    out = tmp_path / "run"
    assert runner_mod.main([str(tiny_config), "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    summed: dict[str, float] = {}
    for index in range(5):
        folder = out / "items" / f"{index:05d}"
        seconds = json.loads((folder / "timing.json").read_text())["seconds"]
        record = json.loads((folder / "record.json").read_text())
        stages = {"build", "check", "bvh", "ao", "write", "total"}
        stages |= {f"{kind}_{r['name']}" for r in record["renders"] for kind in ("render", "picture")}
        assert set(seconds) == stages
        parts = sum(v for k, v in seconds.items() if k != "total")
        assert 0 < parts <= seconds["total"] and all(v >= 0 for v in seconds.values())
        for k, v in seconds.items():
            summed[k] = summed.get(k, 0.0) + v
    table = {line.split()[0]: line.split() for line in printed.splitlines()[1:] if line.startswith("  ")}
    for stage in ("build", "check", "bvh", "ao", "write"):
        assert float(table[stage][1]) == pytest.approx(summed[stage], abs=0.006)
        assert float(table[stage][2]) == pytest.approx(summed[stage] / 5, abs=0.0006)
    assert float(table["render_*"][1]) == pytest.approx(summed["render_view"], abs=0.006)
    assert float(table["items"][1]) == pytest.approx(summed["total"], abs=0.006)
    assert "items/min" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stages"] == pytest.approx(summed)


def test_two_workers_give_identical_manifest(reference, tiny_config, tmp_path):
    summary = run(tiny_config, tmp_path / "par", workers=2, progress=False)
    assert summary.made == 5 and not summary.failed
    assert _manifest(tmp_path / "par") == _manifest(reference)


def test_other_seed_gives_other_items(reference, tiny_config, tmp_path):
    run(tiny_config, tmp_path / "s4", seed=4, progress=False)
    a = json.loads(_manifest(reference))["files"]
    b = json.loads(_manifest(tmp_path / "s4"))["files"]
    assert a.keys() == b.keys()
    assert a["items/00000/mesh.npz"]["sha256"] != b["items/00000/mesh.npz"]["sha256"]


def test_rerun_skips_complete_items_and_redoes_damaged_ones(reference, tiny_config, tmp_path):
    out = tmp_path / "run"
    run(tiny_config, out, progress=False)
    items = out / "items"
    (items / "00001" / "record.json").unlink()  # interrupted before its record
    (items / "00002" / "mesh.npz").write_bytes(b"truncated")  # damaged after its record
    (items / "00004" / ".view.png.abc.tmp.png").write_bytes(b"")  # stray temp file of a kill
    summary = run(tiny_config, out, progress=False)
    assert (summary.made, summary.skipped) == (2, 3)
    assert _manifest(out) == _manifest(reference)


def test_interrupted_run_resumes(reference, tiny_config, tmp_path, monkeypatch):
    out = tmp_path / "run"
    real = runner_mod.make_item
    calls = []

    def interrupt_on_third(job):
        calls.append(job.spec.index)
        if len(calls) == 3:
            folder = runner_mod.item_dir(out, job.spec.index)
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "mesh.npz").write_bytes(b"half")  # as if killed mid-item
            raise KeyboardInterrupt
        return real(job)

    monkeypatch.setattr(runner_mod, "make_item", interrupt_on_third)
    with pytest.raises(KeyboardInterrupt):
        run(tiny_config, out, progress=False)
    monkeypatch.setattr(runner_mod, "make_item", real)
    summary = run(tiny_config, out, progress=False)
    assert (summary.made, summary.skipped) == (3, 2)
    assert _manifest(out) == _manifest(reference)


def test_killed_process_resumes(reference, tiny_config, tmp_path):
    """SIGKILL a real run once its first item is complete, then rerun to completion."""
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "datasets_gen", str(tiny_config), "--out", str(out),
                             "--no-progress"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
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
    assert _manifest(out) == _manifest(reference)


def test_out_folder_of_another_run_is_refused(reference, tiny_config, tmp_path):
    with pytest.raises(FileExistsError, match="holds a run of config 'tiny' with seed 3"):
        run(tiny_config, reference, seed=9, progress=False)
    (tmp_path / "junk.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not empty and holds no run.json"):
        run(tiny_config, tmp_path, progress=False)
    with pytest.raises(ValueError, match="`workers` must be >= 1"):
        run(tiny_config, tmp_path / "new", workers=0)


def test_failed_item_is_reported_and_others_finish(tmp_path):
    cfg = _write(tmp_path, TINY.replace("params = { n = 2, half = 0.4, spread = 0.2 }",
                                        "params = { n = 2, half = 0.4, operation = 'xor' }"))
    summary = run(cfg, tmp_path / "out", progress=False)
    assert list(summary.failed) == [2] and "operation" in summary.failed[2]
    assert summary.made == 4
    manifest = json.loads(_manifest(tmp_path / "out"))
    assert not manifest["complete"]
    assert not any(name.startswith("items/00002/") for name in manifest["files"])


def test_manifest_leaves_out_files_of_items_that_failed_midway(tiny_config, tmp_path, monkeypatch):
    def broken_render(*args, **kwargs):
        raise RuntimeError("renderer exploded")

    monkeypatch.setattr(runner_mod, "_render", broken_render)
    summary = run(tiny_config, tmp_path / "out", progress=False)
    assert sorted(summary.failed) == [3, 4]  # the lifted items are the ones with a render
    assert (tmp_path / "out" / "items" / "00003" / "mesh.npz").is_file()  # written before the failure
    names = json.loads(_manifest(tmp_path / "out"))["files"]
    assert "items/00000/mesh.npz" in names
    assert not any(name.startswith(("items/00003/", "items/00004/")) for name in names)


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


def test_lifted_family_from_a_mesh_file(tmp_path):
    import trimesh

    trimesh.creation.icosphere(1, radius=3.0).export(tmp_path / "ball.stl")
    cfg = _write(tmp_path, f"""
[[family]]
kind = "lifted"
ao = false
params = {{ shape = "file", path = "{tmp_path / 'ball.stl'}", op = "cone", size = 0.5, height = 2.0 }}
""")
    summary = run(cfg, tmp_path / "out", progress=False)
    assert summary.made == 1, summary
    record = json.loads((tmp_path / "out" / "items" / "00000" / "record.json").read_text())
    assert record["derived"]["file_sha256"] == sha256_file(tmp_path / "ball.stl")
    assert record["mesh"]["check"]["ok"] and abs(record["mesh"]["volume_rel_error"]) < 1e-9
    # scaled to bounding radius 0.5: the mesh's 3D extent is within the ball of that radius
    assert np.max(np.abs(record["mesh"]["bounds"])) <= 1.0 + 1e-9
    assert not (tmp_path / "out" / "items" / "00000" / "ao.npz").exists()
