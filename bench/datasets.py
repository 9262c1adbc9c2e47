"""Benchmark: where a dataset's time and bytes go.

The machine line comes first (``bench._protocol``). Part 1, the check against the extraction on
the same mesh (1.2 M-tet spheritorus, 48^4 grid; ``--grid``), taken in turn over ``--rounds`` rounds, each
behind the load gate: extraction, the normals and volume (shared with AO), ``check()`` of the
extracted mesh (its vertex links from the construction) and of the same arrays as a plain mesh
(everything computed); each round's line, then their medians (min–max).

Part 2, a dataset on a 2-worker LocalCluster, once with the workers writing their items into
the folder and once with the items sent back to the client: the item bytes the client
received and the client's peak traced memory (tracemalloc) per item, and whether the two
manifests are identical; then the stage table of the second run (its stages around AO
against the AO stage). Each run is taken once, behind the load gate: what it measures are
bytes and memory, whose values do not depend on the machine's load.

    python -m bench.datasets                       # both parts, the smoke config
    python -m bench.datasets --config tori --skip-check

(run from the repository root).
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tracemalloc
from pathlib import Path

from bench import _protocol as protocol


def bench_check(rounds: int, grid: int = 48) -> None:
    """Part 1: extraction, normals, ``check()`` and the plain mesh's check, in rounds."""
    import ao4d
    from ao4d import SimplexMesh

    f = ao4d.fields.spheritorus(1.0, 0.4)
    ao4d.extract_field(f, grid, (-1.5, 1.5)).check()  # warm: kernels, imports
    print(f"{'extract':>8} {'normals':>8} {'check':>8} {'computed':>9}  (seconds; check after normals)")
    columns: dict[str, list[float]] = {"extract": [], "normals": [], "check": [], "computed": []}
    for _ in protocol.Rounds(rounds):
        t = time.perf_counter()
        mesh = ao4d.extract_field(f, grid, (-1.5, 1.5))
        te = time.perf_counter() - t
        t = time.perf_counter()
        _ = mesh.volume, mesh.simplex_measures
        tn = time.perf_counter() - t
        t = time.perf_counter()
        report = mesh.check()
        tc = time.perf_counter() - t
        plain = SimplexMesh(mesh.vertices, mesh.simplices)
        _ = plain.volume, plain.simplex_measures
        t = time.perf_counter()
        assert plain.check().ok and report.ok
        tf = time.perf_counter() - t
        print(f"{te:8.2f} {tn:8.2f} {tc:8.2f} {tf:9.2f}   ratio check/extract {tc / te:.2f}")
        for key, value in zip(columns, (te, tn, tc, tf)):
            columns[key].append(value)
    print(
        f"median (min–max) over {rounds} rounds: "
        + ", ".join(f"{key} {protocol.format_spread(values, '.2f')} s" for key, values in columns.items())
        + "; check/extract "
        + protocol.format_ratio(c / e for c, e in zip(columns["check"], columns["extract"]))
    )


def bench_writes(config: str, workers: int) -> None:
    """Part 2: a dataset with the workers writing their items, and with the items sent back."""
    from datasets_gen import run
    from datasets_gen.executors import Dask

    manifests = {}
    for shared in (False, True):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "run"
            protocol.gate(f"workers write: {shared}")
            tracemalloc.start()
            summary = run(config, out, executor=Dask(f"local:{workers}", workers_write=shared), progress=False)
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            manifests[shared] = (out / "manifest.json").read_bytes()
            n = max(summary.made, 1)
            print(
                f"workers write: {str(shared):5}  {summary.made} items, {summary.seconds:.1f} s; "
                f"client received {summary.received / 2**20:.2f} MiB ({summary.received / n / 2**20:.2f} "
                f"MiB per item), client peak traced memory {peak / 2**20:.1f} MiB "
                f"({peak / n / 2**20:.2f} MiB per item); dataset {summary.bytes / 2**20:.1f} MiB; "
                f"load average {protocol.load_average()}"
            )
            if shared:  # where the time went (wall-clock per stage, so load inflates it)
                print(summary.stage_table())
    print("manifests identical:", manifests[False] == manifests[True])


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``argv``: the options)."""
    parser = argparse.ArgumentParser(prog="python -m bench.datasets", description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="smoke")
    parser.add_argument("--workers", type=int, default=2)
    protocol.add_rounds(parser, 3, "rounds of part 1, taken in turn (3)", "--repeats")
    parser.add_argument("--grid", type=int, default=48, help="part 1's grid, points per axis (48)")
    parser.add_argument("--skip-check", action="store_true")
    parser.add_argument("--skip-writes", action="store_true")
    args = parser.parse_args(argv)
    print(protocol.machine_line(protocol.opencl_runtime()), flush=True)
    if not args.skip_check:
        bench_check(args.rounds, args.grid)
    if not args.skip_writes:
        bench_writes(args.config, args.workers)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
