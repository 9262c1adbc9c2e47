"""Tests for the benchmarks (``bench/``): the protocol's pieces (``bench._protocol``: the machine
line's parsing, the load gate, rounds, spreads), the shapes and figures of ``bench.ao``, and every
script run as ``python -m bench.NAME`` from the repository root (``--help``, and a tiny real run
where the script has small sizes)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench import _embree
from bench import _protocol as protocol
from bench import ao as ao_bench
from tests._chromium import find_chromium

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ("ao", "ao_accuracy", "cast", "datasets", "extract", "scale", "training_io", "view", "view_image")

LSCPU = """Architecture:                            x86_64
Model name:                              AMD EPYC 7B13
Flags:                                   fpu sse sse2 avx avx2 fma
L1d cache:                               64 KiB (2 instances)
L2 cache:                                1 MiB (2 instances)
L3 cache:                                32 MiB (1 instance)
"""


@pytest.mark.parametrize(
    "text, size",
    [
        ("105 MiB (1 instance)", 105 << 20),
        ("1 MiB (2 instances)", 1 << 20),
        ("2048K", 2048 << 10),
        ("48K\n", 48 << 10),
        ("512 KiB", 512 << 10),
        ("1.5 MiB", 3 << 19),
        ("8 GB", 8 << 30),
        ("none", None),
    ],
)
def test_cache_sizes_parse_as_lscpu_and_sysfs_write_them(text, size):
    assert protocol.parse_size(text) == size


def test_lscpu_lines_become_a_dict():
    info = protocol.parse_lscpu(LSCPU)
    assert info["Model name"] == "AMD EPYC 7B13"
    assert protocol.parse_size(info["L3 cache"]) == 32 << 20
    assert protocol.simd_width(info["Flags"].split()) == 256


@pytest.mark.parametrize(
    "flags, bits",
    [
        (["sse2", "avx", "avx2", "avx512f"], 512),
        (["sse2", "avx2"], 256),
        (["sse", "sse2"], 128),
        (["asimd"], 128),
        ([], 0),
    ],
)
def test_simd_width_is_the_widest_register(flags, bits):
    assert protocol.simd_width(flags) == bits


def test_machine_line_names_cpu_simd_and_caches():
    info = {"model": "AMD EPYC 7B13", "simd": 256, "l2": 1 << 20, "l3": 32 << 20, "cpus": 2}
    line = protocol.machine_line(None, info)
    assert line == "machine: AMD EPYC 7B13, 2 CPUs, SIMD 256 bit, L2 1 MiB, L3 32 MiB"
    assert "L3 ?" in protocol.machine_line(None, dict(info, l3=None))


def test_this_machine_has_a_line():
    info = protocol.cpu_info()
    assert info["cpus"] >= 1 and info["simd"] in (0, 128, 256, 512)
    assert protocol.machine_line(None, info).startswith("machine: ")


def test_ratios_print_median_and_range():
    assert protocol.spread([1.0, 3.0, 2.0, 5.0, 4.0]) == (3.0, 1.0, 5.0)
    assert protocol.format_ratio([0.9, 1.2, 1.1]) == "1.10x (0.90–1.20)"
    assert protocol.format_ratio(iter([2.0])) == "2.00x (2.00–2.00)"


def test_a_busy_round_is_flagged_loudly(capsys):
    # a limit below zero makes any machine busy; a huge one makes it quiet
    assert protocol.check_round(0, 5, limit=-1.0, pause=0.05) is False
    out = capsys.readouterr().out
    assert "round 1/5: load average" in out and "!!! WARNING: round 1" in out
    assert protocol.check_round(1, 5, limit=1e9, pause=0.05) is True
    assert "WARNING" not in capsys.readouterr().out


def test_the_gate_names_its_step(capsys):
    assert protocol.gate("first call", limit=-1.0, pause=0.01) is False
    out = capsys.readouterr().out
    assert out.startswith("first call: load average ")
    assert "!!! WARNING: first call starts on a busy machine" in out


def test_rounds_are_taken_in_turn_each_behind_the_gate(capsys):
    rounds = protocol.Rounds(3, limit=-1.0, pause=0.01)  # every round busy
    assert len(rounds) == 3 and rounds.warning() == ""  # nothing measured yet
    seen = []
    for index in rounds:
        seen.append(index)
        assert len(rounds.quiet) == index + 1  # the gate ran before the round
    assert seen == [0, 1, 2] and rounds.noisy == [1, 2, 3]
    assert rounds.warning().startswith("!!! WARNING: rounds [1, 2, 3] started on a busy machine")
    out = capsys.readouterr().out
    assert [line.split(":")[0] for line in out.splitlines() if "load average" in line] == [
        "round 1/3",
        "round 2/3",
        "round 3/3",
    ]
    quiet = protocol.Rounds(2, limit=1e9, pause=0.01)
    assert list(quiet) == [0, 1] and quiet.noisy == [] and quiet.warning() == ""
    with pytest.raises(ValueError, match="at least 1"):
        protocol.Rounds(0)


def test_rounds_option_takes_at_least_one(capsys):
    parser = argparse.ArgumentParser()
    protocol.add_rounds(parser, 5, "rounds", "--repeat")
    assert parser.parse_args([]).rounds == 5
    assert parser.parse_args(["--repeat", "2"]).rounds == 2
    with pytest.raises(SystemExit):
        parser.parse_args(["--rounds", "0"])
    assert "must be at least 1, got 0" in capsys.readouterr().err


def test_spreads_format_median_min_and_max():
    assert protocol.format_spread([0.2, 0.1, 0.4]) == "0.200 (0.100–0.400)"
    assert protocol.format_spread([3.0, 1.0], ".1f", "-") == "2.0 (1.0-3.0)"


def test_timed_gives_the_median_of_repeats_and_the_result():
    calls = []

    def step():
        calls.append(1)
        time.sleep(0.01 * len(calls))  # 10, 20, 30 ms: the median 20
        return len(calls)

    seconds, result = protocol.timed(step, 3)
    assert result == 3 and 0.019 <= seconds < 0.2


def test_the_clock_laps_wall_and_cpu_time():
    clock = protocol.Clock()
    time.sleep(0.02)
    wall, cpu = clock.lap()
    assert wall >= 0.02 and 0 <= cpu < wall
    assert clock.lap()[0] < 0.02  # a lap starts where the last ended


def test_others_load_is_a_cpu_count():
    load = protocol.others_load(0.05)
    assert load is None or 0.0 <= load <= 64


@pytest.mark.parametrize("lines", [1, 2, 7, 1000])
def test_the_chase_visits_every_line_once_then_returns(lines):
    nxt = protocol.chase_cycle(lines, seed=lines)
    seen, i = [], 0
    for _ in range(lines):
        seen.append(i)
        i = int(nxt[i])
    assert i == 0 and sorted(seen) == [16 * k for k in range(lines)]


def test_memory_latency_is_a_positive_time(cl_runtime):
    latency = protocol.memory_latency(cl_runtime, mib=1, steps=1000)
    assert 0 < latency < 1e6
    assert protocol.memory_line(cl_runtime).startswith("memory latency: ")


@pytest.mark.parametrize("kind", ["tori", "metaballs"])
def test_dense_3d_analogues_are_closed_outward_level_sets_of_their_fields(kind):
    # bench/ao.py's 3D analogues of the dense 4D shapes (Embree's dense workload): a closed
    # surface of about the asked size, facing outwards, on its field's zero level: half a cell's
    # step along each vertex normal leaves the solid, a step against it enters it
    tm = _embree.dense3d_trimesh(kind, 20_000)
    assert tm.is_watertight and tm.volume > 0
    assert 10_000 < len(tm.faces) < 40_000
    field = _embree.dense3d_field(kind)
    step = 0.5 * float(tm.edges_unique_length.mean())  # about half a cell of the extraction's grid
    out = field(tm.vertices + step * tm.vertex_normals) > 0
    inside = field(tm.vertices - step * tm.vertex_normals) < 0
    assert out.mean() > 0.95 and inside.mean() > 0.95  # not where tubes cross (creases)
    assert field(np.full((1, 3), 1.45))[0] > 0  # the corners of the grid are outside
    if kind == "tori":  # the ball and a point on each core circle (inside that torus only) are inside
        a = np.sqrt((0.81 - 0.36) / 2)  # the turned circle at z = 0.6
        assert (field(np.array([[0, 0, 0], [0.9, 0, 0], [0, 0, 0.9], [a, a, 0.6]])) < 0).all()


def test_cache_ceiling_is_the_trace_ratio_times_the_gain_of_a_tree_in_cache(capsys):
    # bench/ao.py's cache ceiling: per round, seconds per ray of the full mesh over the small
    # mesh's, times that round's trace ratio against Open3D; rounds stay apart
    full = [{"trace": (3.0, 5.8), "first": (4.0, 7.0), "rays": 1000}] * 3
    small = [{"trace": (t, 2 * t), "first": (t, t), "rays": 50} for t in (0.1, 0.15, 0.12)]  # gains 1.5, 1.0, 1.25
    assert ao_bench.cache_gains(full, small) == pytest.approx([1.5, 1.0, 1.25])
    peer = [
        {"trace": (t, 2 * t), "first": (t, t), "rays": 1000} for t in (1.5, 1.5, 2.4)
    ]  # ao4d at 0.5x, 0.5x, 0.8x: at most 0.75x, 0.5x, 1.0x
    runs = {("metaballs", "ao4d"): full, ("metaballs", "ao4d small"): small, ("metaballs", "Open3D"): peer}
    ao_bench.ceiling_report(runs, ["metaballs", "tiger"], {"metaballs": (15.0, 10.0)})  # no small tiger: no row
    out = capsys.readouterr().out
    assert "tiger" not in out
    rows = [line.split() for line in out.splitlines() if line.strip().startswith("metaballs")]
    # ns a ray on one core: 3 s / 1000 rays x cores; the small mesh's median 0.12 s / 50 rays x cores;
    # and per test: 15 tests a ray on the full mesh, 10 on the small one
    c = os.cpu_count() or 1
    assert rows == [
        ["metaballs:", f"{3e6 * c:.0f}", f"{2.4e6 * c:.0f}", "15.0", "10.0", f"{2e5 * c:.1f}", f"{2.4e5 * c:.1f}"]
        + ["1.25x", "(1.00–1.50)", "0.75x", "(0.50–1.00)"]
    ]


def _bench(*args: str, timeout: float = 120) -> str:
    """``python -m bench.NAME ARGS`` from the repository root; its output (it must succeed)."""
    run = subprocess.run(
        [sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout, check=False
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    return run.stdout


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_script_runs_as_a_module_of_the_package(name):
    out = _bench(f"bench.{name}", "--help")
    assert out.startswith(f"usage: python -m bench.{name}")
    assert not (ROOT / "bench" / f"{name}.py").read_text(encoding="utf-8").count("sys.path")


def _machine_first(out: str, rounds: int = 1) -> None:
    """The machine line comes first, and every round starts behind the load gate."""
    assert out.startswith("machine: ")
    for k in range(1, rounds + 1):
        assert f"round {k}/{rounds}: load average" in out


# tiny real runs, a few seconds each (the gate's pause included); the slower ones under -m slow
def test_extract_runs_tiny(cl_runtime):
    out = _bench("bench.extract", "--sizes3", "16", "--sizes4", "6", "--rounds", "1", "--torus", "0", "--no-first-call")
    _machine_first(out)
    rows = [line for line in out.splitlines() if line.startswith(("3D sphere 16^3", "4D cubes 6^4"))]
    assert len(rows) == 7 and all("(" in row and "-" in row for row in rows)  # median (min-max)


def test_ao_runs_tiny(cl_runtime):
    out = _bench(
        "bench.ao",
        *("--tets", "2000", "--shapes", "spheritorus", "--rounds", "1", "--quality-points", "50"),
        *("--numpy-tets", "2000", "--numpy-points", "20", "--no-per-ray", "--no-cache-ceiling"),
    )
    _machine_first(out)
    assert "spheritorus, ao4d " in out and "BVH speed-up over brute force" in out


def test_datasets_runs_tiny(cl_runtime):
    out = _bench("bench.datasets", "--skip-writes", "--rounds", "1", "--grid", "10")
    _machine_first(out)
    assert "median (min–max) over 1 rounds: extract " in out


def test_scale_runs_one_case_in_its_fresh_process():
    out = _bench("bench.scale", "--_case", "slab", "--grid", "10")
    assert '"case": "slab"' in out and '"closed": true' in out


@pytest.mark.slow
@pytest.mark.parametrize(
    "args",
    [
        ("bench.cast", "--triangles", "2000", "--tets", "2000", "--points", "100", "--samples", "8", "--rounds", "1"),
        ("bench.ao_accuracy", "--shapes", "spheritorus", "--tets", "2000", "--reference", "256", "--rounds", "1"),
        ("bench.training_io", "--rounds", "1", "--workers", "1"),
    ],
    ids=lambda args: args[0],
)
def test_slower_scripts_run_tiny(cl_runtime, args):
    _machine_first(_bench(*args, timeout=300))


@pytest.mark.slow
@pytest.mark.skipif(find_chromium() is None, reason="Chromium is not installed")
@pytest.mark.parametrize(
    "args",
    [("bench.view", "--sizes", "2000", "--window", "320", "200"), ("bench.view_image", "--sizes", "16")],
    ids=lambda args: args[0],
)
def test_browser_benches_run_tiny(args):
    out = _bench(*args, timeout=300)
    assert out.startswith("machine: ")


STUB_OPEN3D = """
import numpy as np


class _Tensor:
    def __init__(self, array):
        self.array = np.asarray(array)

    def __getitem__(self, key):
        return _Tensor(self.array[key])

    def __len__(self):
        return len(self.array)

    def numpy(self):
        return self.array


class _Scene:
    def add_triangles(self, vertices, faces):
        self.faces = faces

    def test_occlusions(self, rays, tfar=float("inf")):
        return _Tensor(np.zeros(len(rays), dtype=bool))


class core:
    Tensor = _Tensor


class t:
    class geometry:
        RaycastingScene = _Scene
"""


def test_the_open3d_worker_serves_jobs_from_its_own_process(tmp_path, monkeypatch):
    # a stand-in for open3d (no hits): the worker starts as python -m bench._embree from the
    # repository root and answers each job with one JSON line
    (tmp_path / "open3d").mkdir()
    (tmp_path / "open3d" / "__init__.py").write_text(STUB_OPEN3D, encoding="utf-8")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.delenv("AO4D_BENCH_OPEN3D_PYTHON", raising=False)
    assert _embree.have_open3d() is None
    worker = _embree.Open3D()
    try:
        assert worker.info == {"ready": True}
        for reach, kind in ((0.0, "torus"), (0.25, "tori")):
            answer = worker.run(2000, 50, 4, reach, kind)
            assert answer["rays"] == 200 and answer["hit"] == 0.0
            assert len(answer["build"]) == len(answer["trace"]) == 2
            assert answer["first"] == pytest.approx([b + t for b, t in zip(answer["build"], answer["trace"])])
    finally:
        worker.close()
    assert worker.proc.returncode == 0
