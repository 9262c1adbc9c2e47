"""Benchmark: ao4d beyond one process — block-wise extraction on dask.distributed, and datasets.

1. Extraction of a lazy field on a large grid (default 192^4 = 1.36 G points, 10.9 GB as
   float64, never held anywhere): the in-process slab path (``extract_field``) against
   ``extract_field(..., blocks=)`` on a ``LocalCluster`` of 2 worker processes (1 thread each),
   started with dask's default worker environment and inside
   ``ao4d.worker_environment()`` (no ``MALLOC_TRIM_THRESHOLD_``).
   Wall time, cells per second, peak resident memory of the client process (taken when the
   extraction returns) and of each worker (``ru_maxrss``), and whether the two meshes are identical (sha256 of vertices and simplices).
   Each case runs in a fresh process, one after the other.
2. Datasets: items per minute of ``python -m datasets_gen`` with ``--workers 2`` against
   ``--scheduler local:2`` on the same configuration (start-up of the pool or cluster included),
   and whether the two manifests are byte-identical.

The machine line comes first (``bench._protocol``); each part takes its cases in turn over
``--rounds`` rounds (1: a 192^4 case runs for minutes), each round behind the load gate, and
prints times as the median (min–max) over the rounds; memory and meshes are the first round's.

    python -m bench.scale                          # 192^4, chunks of 64^4 points; datasets
    python -m bench.scale --grid 128 --chunks 48 --skip-datasets

(run from the repository root).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import _protocol as protocol

ROOT = Path(__file__).resolve().parent.parent  # the cases' fresh processes run from it

# A dataset of moderate items (grid 24, AO with 32 samples): seconds each, so that start-up
# does not dominate.
DATASET = {
    "name": "scale-bench",
    "seed": 11,
    "defaults": {"grid": 24, "padding": 0.15, "rotation": "random", "ao": {"samples": 32}},
    "family": [
        {"kind": "hypersphere", "count": 6, "params": {"radius": {"uniform": [0.6, 0.9]}}},
        {"kind": "spheritorus", "count": 6, "params": {"R": {"uniform": [0.6, 0.8]}, "r": {"uniform": [0.25, 0.35]}}},
    ],
}


def _field():
    from ao4d import fields

    return fields.hypersphere(0.6), (-1.2, 1.2)


def _maxrss_mib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _digest(mesh) -> str:
    import hashlib

    import numpy as np

    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices).tobytes())
    h.update(np.ascontiguousarray(mesh.simplices).tobytes())
    return h.hexdigest()[:16]


def _case(kind: str, grid: int, chunks: int) -> dict:
    """One extraction in this (fresh) process; returns the figures as a dict."""
    import ao4d

    field, bounds = _field()
    result: dict = {"case": kind, "grid": grid}
    if kind == "slab":
        t0 = time.perf_counter()
        mesh = ao4d.extract_field(field, grid, bounds, progress=False)
        result["seconds"] = time.perf_counter() - t0
        result["client_mib"] = _maxrss_mib()  # before the checks below, which need memory too
        result["workers_mib"] = []
    else:
        import contextlib
        import warnings

        from distributed import Client, LocalCluster

        from ao4d import WorkerEnvironmentWarning, worker_environment

        warnings.simplefilter("ignore", WorkerEnvironmentWarning)  # the default case is measured
        env = worker_environment() if kind == "cluster-tuned" else contextlib.nullcontext()
        with env:
            cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
        with cluster, Client(cluster) as client:
            client.run(lambda: __import__("ao4d.marching.blockwise"))  # warm the workers' imports
            t0 = time.perf_counter()
            mesh = ao4d.extract_field(field, grid, bounds, blocks=chunks, progress=False)
            result["seconds"] = time.perf_counter() - t0
            result["client_mib"] = _maxrss_mib()
            peaks = client.run(_maxrss_mib)
            result["workers_mib"] = [peaks[w] for w in sorted(peaks)]
        result["chunks"] = chunks
    result["mesh_mib"] = (mesh.vertices.nbytes + mesh.simplices.nbytes) / 2**20
    result["cells"] = (grid - 1) ** 4
    result["vertices"], result["simplices"] = mesh.n_vertices, mesh.n_simplices
    result["digest"] = _digest(mesh)
    result["closed"] = bool(mesh.check().ok)
    return result


def _run_case(kind: str, grid: int, chunks: int) -> dict:
    """:func:`_case` in a fresh process (``python -m bench.scale --_case KIND``)."""
    out = subprocess.run(
        [sys.executable, "-m", "bench.scale", "--_case", kind, "--grid", str(grid), "--chunks", str(chunks)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(f"case {kind} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _datasets(folder: Path, rounds: protocol.Rounds) -> dict[str, list[dict]]:
    """Both runs of :data:`DATASET` once a round, in turn: label -> the rounds' figures."""
    from datasets_gen.config import config_text

    config = folder / "scale.toml"
    config.write_text(config_text(DATASET), encoding="utf-8")
    rows: dict[str, list[dict]] = {}
    runs = (("--workers 2", ["--workers", "2"]), ("--scheduler local:2", ["--scheduler", "local:2"]))
    for r, (label, extra) in ((r, run) for r in rounds for run in runs):
        out = folder / f"{label.replace(' ', '_').replace(':', '').strip('-')}_{r}"
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "datasets_gen", str(config), "--out", str(out), "--no-progress", *extra],
            capture_output=True,
            text=True,
            cwd=ROOT,
            check=False,
        )
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"datasets {label} failed:\n{proc.stderr[-3000:]}")
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
        rows.setdefault(label, []).append(
            {
                "label": label,
                "made": summary["made"],
                "run_seconds": summary["seconds"],
                "wall": wall,
                "items_per_minute": summary["items_per_minute"],
                "manifest": (out / "manifest.json").read_bytes(),
            }
        )
    return rows


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options."""
    parser = argparse.ArgumentParser(
        prog="python -m bench.scale",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--grid", type=int, default=192, help="points per axis (192)")
    parser.add_argument("--chunks", type=int, default=64, help="points per block per axis (64)")
    protocol.add_rounds(parser, 1, "rounds, cases in turn (1)")
    parser.add_argument("--skip-datasets", action="store_true", help="extraction only")
    parser.add_argument("--skip-extract", action="store_true", help="datasets only")
    parser.add_argument("--_case", choices=("slab", "cluster", "cluster-tuned"), help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def extraction(grid: int, chunks: int, rounds: protocol.Rounds) -> None:
    """Part 1: the slab path and the two clusters, each in a fresh process, once a round."""
    field, bounds = _field()
    print(
        f"\nextraction of {field!r} on a {grid}^4 grid over {bounds} "
        f"({grid**4 * 8 / 2**30:.1f} GiB as float64, never held), cubes"
    )
    kinds = ("slab", "cluster", "cluster-tuned")
    runs: dict[str, list[dict]] = {kind: [] for kind in kinds}
    for _ in rounds:
        for kind in kinds:
            runs[kind].append(_run_case(kind, grid, chunks))
    if rounds.warning():
        print(rounds.warning())
    slab, cluster, tuned = (runs[kind][0] for kind in kinds)
    wall = {kind: [row["seconds"] for row in runs[kind]] for kind in kinds}
    print(
        f"{'path':52s} {'wall s (min–max)':>22s} {'Mcells/s':>9s} {'client MiB':>11s} {'worker MiB (peak each)':>24s}"
    )
    for kind, name in (
        ("slab", "in-process slab path (extract_field)"),
        ("cluster", f"LocalCluster(2), {chunks}^4 blocks, dask env"),
        ("cluster-tuned", f"LocalCluster(2), {chunks}^4 blocks, worker_environment"),
    ):
        row = runs[kind][0]
        workers = ", ".join(f"{m:.0f}" for m in row["workers_mib"]) or "-"
        print(
            f"{name:52s} {protocol.format_spread(wall[kind], '.1f'):>22s} "
            f"{row['cells'] / statistics.median(wall[kind]) / 1e6:9.2f} {row['client_mib']:11.0f} {workers:>24s}"
        )
    same = all(row["digest"] == slab["digest"] for rows in runs.values() for row in rows)
    print(
        f"mesh: {slab['vertices']:,} vertices, {slab['simplices']:,} simplices "
        f"({slab['mesh_mib']:.0f} MiB as float64/int64 arrays), closed "
        f"{slab['closed'] and cluster['closed'] and tuned['closed']}; identical arrays on all "
        f"paths: {same}; speed-up over the slab path "
        f"{protocol.format_ratio(s / c for s, c in zip(wall['slab'], wall['cluster']))} "
        f"(dask's worker environment), "
        f"{protocol.format_ratio(s / t for s, t in zip(wall['slab'], wall['cluster-tuned']))} "
        "(ao4d.worker_environment)"
    )


def datasets(rounds: protocol.Rounds) -> None:
    """Part 2: ``--workers 2`` against ``--scheduler local:2``, once a round."""
    with tempfile.TemporaryDirectory(prefix="ao4d-scale-") as tmp:
        runs = _datasets(Path(tmp), rounds)
    print("\ndatasets_gen, 12 items (grid 24, AO 32 samples), start-up included")
    print(f"{'run':24s} {'items':>6s} {'run s (min–max)':>20s} {'items/min':>10s}")
    for label, rows in runs.items():
        seconds = protocol.format_spread((row["run_seconds"] for row in rows), ".1f")
        per_minute = statistics.median(row["items_per_minute"] for row in rows)
        print(f"{label:24s} {rows[0]['made']:6d} {seconds:>20s} {per_minute:10.1f}")
    manifests = {row["manifest"] for rows in runs.values() for row in rows}
    print(f"manifests byte-identical: {len(manifests) == 1}")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``argv``: the options), or with ``--_case`` one extraction case."""
    args = parse_args(argv)
    if args._case:
        print(json.dumps(_case(args._case, args.grid, args.chunks)))
        return 0
    print(protocol.machine_line(protocol.opencl_runtime()))
    print("runs one after the other, each in a fresh process", flush=True)
    if not args.skip_extract:
        extraction(args.grid, args.chunks, protocol.Rounds(args.rounds))
    if not args.skip_datasets:
        datasets(protocol.Rounds(args.rounds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
