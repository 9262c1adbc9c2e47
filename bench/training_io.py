"""Benchmark: what a training loop waits for when it reads a dataset, and what an export costs.

On a dataset folder (``--dataset DIR``; made from ``--config``, by default :data:`SMALL`, into a
scratch folder when not given), taken in turn over ``--rounds`` rounds:

- an epoch of every item as ``datasets_gen.load(DIR)[i]`` gives it (mesh, AO, samples, record);
- an epoch of the samples only, ``load(DIR, keys=("points", "occupancy", "surface_points"))``;
- the same from the WebDataset and the Parquet export of the dataset.

and once: the bytes of the dataset's item files against each export's shards. Prints the machine
line, each round's load gate, and the median (min–max) of every time and ratio (``bench._protocol``).

    python -m bench.training_io --dataset data/occ --rounds 5

(run from the repository root).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from bench import _protocol as protocol

SAMPLES = ("points", "occupancy", "surface_points")
# the dataset made when neither --dataset nor --config is given: small items with learning samples
SMALL = {
    "name": "training-io-bench",
    "seed": 5,
    "defaults": {
        "grid": 12,
        "ao": {"samples": 8},
        "samples": {"uniform": 4096, "near_surface": 4096, "sigmas": [0.01, 0.05], "surface": 4096},
    },
    "family": [
        {"kind": "hypersphere", "count": 4, "params": {"radius": {"uniform": [0.6, 0.9]}}},
        {"kind": "spheritorus", "count": 4, "params": {"R": {"uniform": [0.6, 0.8]}, "r": {"uniform": [0.25, 0.35]}}},
    ],
}
ITEM_FILES = ("mesh.npz", "ao.npz", "samples.npz", "sequence.npz", "record.json")


def epoch(ds) -> float:
    """Seconds to read every item of ``ds`` once."""
    start = time.perf_counter()
    for i in range(len(ds)):
        ds[i]
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``argv``: the options)."""
    parser = argparse.ArgumentParser(prog="python -m bench.training_io", description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", type=Path, help="a datasets_gen output folder (default: made from --config)")
    parser.add_argument(
        "--config", help="the config made when --dataset is not given (default: 8 small items with samples)"
    )
    parser.add_argument("--workers", type=int, default=2, help="processes that make the dataset (2)")
    protocol.add_rounds(parser, 5, "rounds taken in turn (5)")
    args = parser.parse_args(argv)

    import datasets_gen
    from datasets_gen.export import export

    print(protocol.machine_line(protocol.opencl_runtime()), flush=True)
    with tempfile.TemporaryDirectory(prefix="ao4d-training-io-") as scratch:
        folder = args.dataset
        if folder is None:
            folder = Path(scratch) / "dataset"
            datasets_gen.run(args.config or SMALL, folder, workers=args.workers, progress=False)
        stored = sum(p.stat().st_size for p in Path(folder).glob("items/*/*") if p.name in ITEM_FILES)
        exports = {}
        for fmt in ("webdataset", "parquet"):
            out = Path(scratch) / fmt
            start = time.perf_counter()
            manifest = export(folder, out, format=fmt, progress=False)
            seconds = time.perf_counter() - start
            exports[fmt] = out
            size = sum(s["bytes"] for s in manifest["shards"])
            print(
                f"{fmt}: {len(manifest['shards'])} shards, {size / 2**20:.1f} MiB = {size / stored:.2f}x the "
                f"dataset's {stored / 2**20:.1f} MiB of item files; written in {seconds:.1f} s",
                flush=True,
            )
        cases = {
            "folder, whole items": lambda: datasets_gen.load(folder),
            "folder, samples only": lambda: datasets_gen.load(folder, keys=SAMPLES),
            "webdataset, samples only": lambda: datasets_gen.load(exports["webdataset"], keys=SAMPLES),
            "parquet, samples only": lambda: datasets_gen.load(exports["parquet"], keys=SAMPLES),
        }
        n = len(datasets_gen.load(folder))
        times: dict[str, list[float]] = {name: [] for name in cases}
        rounds = protocol.Rounds(args.rounds)
        for _ in rounds:
            for name, make in cases.items():
                times[name].append(epoch(make()))
    base = times["folder, whole items"]
    print(f"\nan epoch of {n} items, median (min–max) of {args.rounds} rounds taken in turn:")
    if rounds.warning():
        print(rounds.warning())
    for name, values in times.items():
        m, lo, hi = protocol.spread(values)
        ratio = protocol.format_ratio(b / v for b, v in zip(base, values))
        print(f"  {name:26s} {1000 * m / n:7.1f} ms an item ({1000 * lo / n:.1f}–{1000 * hi / n:.1f}); {ratio} as fast")
    return 0


if __name__ == "__main__":
    sys.exit(main())
