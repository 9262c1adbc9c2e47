"""Tests for datasets_gen.items: one item made the same way anywhere, every file written
through the store (record last), complete only when every hash matches."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from datasets_gen import load_config, run
from datasets_gen._files import sha256_file
from datasets_gen._store import LocalStore, MemoryStore
from datasets_gen.items import (
    Job,
    item_complete,
    item_folder,
    item_seed,
    make_item,
    resolved_backend,
    versions,
    write_item,
)
from datasets_gen.runner import main


def _job(config: Path, index: int, out: Path) -> Job:
    cfg = load_config(config)
    return Job(cfg.items()[index], cfg.seed, str(out), resolved_backend(cfg.backend))


def test_item_does_not_depend_on_order_or_neighbours(tiny_reference, tiny_config, tmp_path):
    """Item 3 made alone, in a fresh folder, has the same bytes as in the full run."""
    make_item(_job(tiny_config, 3, tmp_path))
    for name in ("mesh.npz", "ao.npz", "view.png", "record.json"):
        a = tmp_path / "items" / "00003" / name
        assert a.read_bytes() == (tiny_reference / "items" / "00003" / name).read_bytes(), name
    assert item_complete(LocalStore(tmp_path), 3) and not item_complete(LocalStore(tmp_path), 2)


def test_every_write_goes_through_the_store(tiny_reference, tiny_config, tmp_path):
    """An item made into a store in memory leaves nothing on disk and has the run's bytes;
    written into a folder that holds a stale attempt, it replaces it, the record last."""
    scratch = MemoryStore()
    make_item(_job(tiny_config, 4, tmp_path / "never"), scratch)
    assert not (tmp_path / "never").exists()
    rel = item_folder(4)
    files = {name: scratch.read_bytes(f"{rel}/{name}") for name in scratch.files(rel)}
    assert set(files) == {"mesh.npz", "ao.npz", "view.png", "timing.json", "record.json"}
    for name in set(files) - {"timing.json"}:
        assert files[name] == (tiny_reference / rel / name).read_bytes(), name

    class Recording(LocalStore):
        def write_bytes(self, rel: str, data: bytes) -> None:
            written.append(rel)
            super().write_bytes(rel, data)

    written: list[str] = []
    store = Recording(tmp_path / "out")
    store.write_bytes(f"{rel}/.view.png.0123abcd.tmp.png", b"an interrupted attempt")
    store.write_bytes(f"{rel}/mesh.npz", b"half")
    store.write_bytes(f"{rel}/notes.txt", b"a user's file: never the run's to delete")
    write_item(store, 4, files)
    assert sorted(store.files(rel)) == sorted([*files, "notes.txt"]) and written[-1] == f"{rel}/record.json"
    assert item_complete(store, 4)
    store.write_bytes(f"{rel}/ao.npz", b"changed after the record")
    assert not item_complete(store, 4)


def test_item_seeds_and_folders():
    assert item_folder(3) == "items/00003" and item_folder(12345) == "items/12345"
    a, b = item_seed(3, 1), item_seed(3, 2)
    assert a.entropy == [3, 1] and a.generate_state(2).tolist() != b.generate_state(2).tolist()
    assert item_seed(3, 1).generate_state(2).tolist() == a.generate_state(2).tolist()


def test_versions_name_the_code_that_made_the_item():
    import hashlib

    import ao4d
    from ao4d._resources import data_dir

    v = versions()
    assert v["ao4d"] == ao4d.__version__
    manifest = (data_dir("lut") / "manifest.json").read_bytes()
    assert v["lut_manifest_sha256"] == hashlib.sha256(manifest).hexdigest()
    assert all(len(v[k]) == 64 for k in ("kernels_sha256", "lut_cube_4d_sha256", "lut_simplex_4d_sha256"))


def test_timing_has_every_stage_and_the_run_prints_them(tiny_config, tmp_path, capsys):
    """timing.json times every stage of an item (their sum within the item's total), and the
    command line ends with the per-stage table of the items it made and items/min."""
    out = tmp_path / "run"
    assert main([str(tiny_config), "--out", str(out), "--no-progress"]) == 0
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


def test_rerun_skips_complete_items_and_redoes_damaged_ones(tiny_reference, tiny_config, tmp_path):
    out = tmp_path / "run"
    run(tiny_config, out, progress=False)
    items = out / "items"
    (items / "00001" / "record.json").unlink()  # interrupted before its record
    (items / "00002" / "mesh.npz").write_bytes(b"truncated")  # damaged after its record
    (items / "00004" / ".view.png.abc.tmp.png").write_bytes(b"")  # stray temp file of a kill
    summary = run(tiny_config, out, progress=False)
    assert (summary.made, summary.skipped) == (2, 3)
    assert (out / "manifest.json").read_bytes() == (tiny_reference / "manifest.json").read_bytes()


def test_lifted_family_from_a_mesh_file(tmp_path):
    import trimesh

    trimesh.creation.icosphere(1, radius=3.0).export(tmp_path / "ball.stl")
    params = {"shape": "file", "path": str(tmp_path / "ball.stl"), "op": "cone", "size": 0.5, "height": 2.0}
    summary = run({"family": [{"kind": "lifted", "ao": False, "params": params}]}, tmp_path / "out", progress=False)
    assert summary.made == 1, summary
    record = json.loads((tmp_path / "out" / "items" / "00000" / "record.json").read_text())
    assert record["derived"]["file_sha256"] == sha256_file(tmp_path / "ball.stl")
    assert record["mesh"]["check"]["ok"] and abs(record["mesh"]["volume_rel_error"]) < 1e-9
    # scaled to bounding radius 0.5: the mesh's 3D extent is within the ball of that radius
    assert np.max(np.abs(record["mesh"]["bounds"])) <= 1.0 + 1e-9
    assert not (tmp_path / "out" / "items" / "00000" / "ao.npz").exists()


def test_records_name_what_the_marching_table_proves_and_it_holds(tiny_reference):
    """An extracted item's check takes its face counts from the marching table
    (record["mesh"]["check"]["proved"]); the full face sort of its saved mesh agrees with every
    count. A lifted solid is not marched: every field of its check is computed."""
    from ao4d import topology
    from ao4d.mesh import SimplexMesh

    kinds = set()
    for folder in sorted((tiny_reference / "items").iterdir()):
        record = json.loads((folder / "record.json").read_text())
        check = record["mesh"]["check"]
        marched = record["kind"] != "lifted"
        kinds.add(marched)
        assert tuple(check["proved"]) == (topology.MARCHING_CLOSED_PROVED if marched else ())
        full = SimplexMesh.load(folder / "mesh.npz").check()  # a loaded mesh proves nothing
        assert full.proved == ()
        computed = {k: v for k, v in dataclasses.asdict(full).items() if k not in ("proved", "hint")}
        assert {k: check[k] for k in computed} == computed, folder.name
    assert kinds == {True, False}


def test_backend_is_resolved_to_the_one_that_computes():
    assert resolved_backend("numpy") == "numpy"
    assert resolved_backend("auto") in ("opencl", "numpy")
    with pytest.raises(ValueError, match="backend"):
        resolved_backend("cuda")


def test_render_takes_the_occlusion_as_data_and_leaves_the_mesh_alone():
    """An item's render shades the per-vertex occlusion it is given (as data: nothing is
    attached to the item's mesh); without one it traces AO at the hits (none on a ball)."""
    import ao4d
    from datasets_gen import items

    mesh = ao4d.extract_field(ao4d.fields.hypersphere(0.8), 8, (-1, 1), progress=False)
    render = {"name": "view", "shape": [6, 6, 6], "samples": 2}
    shaded = {}
    ramp = np.linspace(0.0, 1.0, mesh.n_vertices)
    for name, occlusion in (("zero", np.zeros(mesh.n_vertices)), ("ramp", ramp), ("hits", None)):
        settings = {"ao": None if occlusion is None else {"at": "vertices"}}
        shaded[name] = items._render(render, mesh, occlusion, settings, 1, "numpy", "t", {})
        assert "ao" not in mesh.point_data
    assert shaded["zero"] == shaded["hits"]  # a convex solid occludes nothing
    assert shaded["ramp"] != shaded["zero"]
