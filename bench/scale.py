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

    python bench/scale.py                          # 192^4, chunks of 64^4 points; datasets
    python bench/scale.py --grid 128 --chunks 48 --skip-datasets
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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
    out = subprocess.run(
        [sys.executable, __file__, "--_case", kind, "--grid", str(grid), "--chunks", str(chunks)],
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(f"case {kind} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _datasets(folder: Path) -> list[dict]:
    from datasets_gen.config import config_text

    config = folder / "scale.toml"
    config.write_text(config_text(DATASET), encoding="utf-8")
    rows = []
    for label, extra in (("--workers 2", ["--workers", "2"]), ("--scheduler local:2", ["--scheduler", "local:2"])):
        out = folder / label.replace(" ", "_").replace(":", "").strip("-")
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "datasets_gen", str(config), "--out", str(out), "--no-progress", *extra],
            capture_output=True,
            text=True,
            check=False,
        )
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"datasets {label} failed:\n{proc.stderr[-3000:]}")
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
        rows.append(
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=int, default=192, help="points per axis (192)")
    parser.add_argument("--chunks", type=int, default=64, help="points per block per axis (64)")
    parser.add_argument("--skip-datasets", action="store_true", help="extraction only")
    parser.add_argument("--skip-extract", action="store_true", help="datasets only")
    parser.add_argument("--_case", choices=("slab", "cluster", "cluster-tuned"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args._case:
        print(json.dumps(_case(args._case, args.grid, args.chunks)))
        return 0

    print(f"machine: {os.cpu_count()} CPUs; runs one after the other, each in a fresh process")
    if not args.skip_extract:
        field, bounds = _field()
        print(
            f"\nextraction of {field!r} on a {args.grid}^4 grid over {bounds} "
            f"({args.grid**4 * 8 / 2**30:.1f} GiB as float64, never held), cubes"
        )
        slab = _run_case("slab", args.grid, args.chunks)
        cluster = _run_case("cluster", args.grid, args.chunks)
        tuned = _run_case("cluster-tuned", args.grid, args.chunks)
        print(f"{'path':52s} {'wall s':>8s} {'Mcells/s':>9s} {'client MiB':>11s} {'worker MiB (peak each)':>24s}")
        for row, name in (
            (slab, "in-process slab path (extract_field)"),
            (cluster, f"LocalCluster(2), {args.chunks}^4 blocks, dask env"),
            (tuned, f"LocalCluster(2), {args.chunks}^4 blocks, worker_environment"),
        ):
            workers = ", ".join(f"{m:.0f}" for m in row["workers_mib"]) or "-"
            print(
                f"{name:52s} {row['seconds']:8.1f} {row['cells'] / row['seconds'] / 1e6:9.2f} "
                f"{row['client_mib']:11.0f} {workers:>24s}"
            )
        same = slab["digest"] == cluster["digest"] == tuned["digest"]
        print(
            f"mesh: {slab['vertices']:,} vertices, {slab['simplices']:,} simplices "
            f"({slab['mesh_mib']:.0f} MiB as float64/int64 arrays), closed "
            f"{slab['closed'] and cluster['closed'] and tuned['closed']}; identical arrays on all "
            f"paths: {same}; speed-up over the slab path {slab['seconds'] / cluster['seconds']:.2f}x "
            f"(dask's worker environment), {slab['seconds'] / tuned['seconds']:.2f}x "
            "(ao4d.worker_environment)"
        )
    if not args.skip_datasets:
        with tempfile.TemporaryDirectory(prefix="ao4d-scale-") as tmp:
            rows = _datasets(Path(tmp))
        print("\ndatasets_gen, 12 items (grid 24, AO 32 samples), start-up included")
        print(f"{'run':24s} {'items':>6s} {'run s':>8s} {'items/min':>10s}")
        for row in rows:
            print(f"{row['label']:24s} {row['made']:6d} {row['run_seconds']:8.1f} {row['items_per_minute']:10.1f}")
        print(f"manifests byte-identical: {rows[0]['manifest'] == rows[1]['manifest']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
