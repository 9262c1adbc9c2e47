"""Benchmark: ao4d extraction on the OpenCL device against VTK's flying edges (3D) and ao4d's own
numpy engine (4D), in one run, cases taken in turn.

3D: a sphere sampled on 256^3 and 384^3 grids: ao4d on the device (``backend="auto"``, what
``ao4d.extract`` does) on the grid as ``ao4d.sample`` returns it (page-aligned: a CPU device
reads it in place) and on a copy 8 bytes past a page (as a numpy array may be: copied to the
device), ao4d's numpy engine, and ``vtkFlyingEdges3D`` (no normals, gradients or
scalars) on one thread (``vtkSMPTools`` backend ``Sequential``) and on all threads (the wheel's
threaded backend, named in the output). 4D: a hypersphere on 64^4 and 96^4 grids, both methods,
device against the numpy engine. Every case runs once untimed (table loading, kernel builds,
first-touch pages), then ``--rounds`` times in turn, so that machine load falls on all cases
alike, each group's order rotated by one case every round (see ``_rotated``), each round behind
the load gate of ``bench._protocol`` (which also gives the machine line, printed first); the
table shows the median with the min-max spread, and ratios of medians. ao4d's times
are what the user waits for: ``ao4d.extract`` from the array to the SimplexMesh, checks
included.

Also measured, each in a fresh process (once): the first call at 256^3 (device discovery, kernel
build with an empty and with a warm kernel cache, extraction) and a 128^4 spheritorus extracted
slab by slab with ``extract_field`` on both backends (time and peak resident memory, VmHWM),
beside the time the field's evaluation alone takes.

    python -m bench.extract                     # everything, 5 rounds (about 7 min, quiet 2 cores)
    python -m bench.extract --sizes3 256 --sizes4 64 --rounds 3 --torus 0
    python -m bench.extract --profile           # also the device engine's time per stage

(run from the repository root).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import _protocol as protocol

ROOT = Path(__file__).resolve().parent.parent  # the fresh processes run from it: this checkout's ao4d


def _vtk_runner(values: np.ndarray, backend: str):
    import vtk
    from vtk.util import numpy_support

    image = vtk.vtkImageData()
    image.SetDimensions(*values.shape)
    # VTK's x runs fastest: the Fortran-order ravel of values[i, j, k] puts i fastest
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(values.ravel(order="F"), deep=True))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, 0.0)
    fe.ComputeNormalsOff()
    fe.ComputeGradientsOff()
    fe.ComputeScalarsOff()

    def run() -> int:
        vtk.vtkSMPTools.SetBackend(backend)
        fe.Modified()
        fe.Update()
        return fe.GetOutput().GetNumberOfCells()

    return run


def vtk_threaded_backend() -> str:
    """The wheel's threaded vtkSMPTools backend (TBB, OpenMP or STDThread), or Sequential."""
    import vtk

    smp = vtk.vtkSMPTools
    sys.stderr.flush()
    saved = os.dup(2)
    with open(os.devnull, "w") as null:  # VTK prints a warning for every backend it lacks
        os.dup2(null.fileno(), 2)
        try:
            for name in ("TBB", "OpenMP", "STDThread"):
                smp.SetBackend(name)
                if smp.GetBackend() == name:
                    return name
            return "Sequential"
        finally:
            smp.SetBackend("Sequential")
            os.dup2(saved, 2)
            os.close(saved)


def _cases(sizes3, sizes4, threaded: str):
    import ao4d
    from ao4d import fields
    from ao4d._pages import aligned_empty

    cases = []
    for n in sizes3:
        sphere = ao4d.sample(fields.hypersphere(1.0, dim=3), n, (-1.2, 1.2))
        group = f"3D sphere {n}^3"
        # the same grid 8 bytes past a page, as an array numpy allocated may be: a CPU device
        # copies it instead of reading it in place (ao4d._pages)
        shifted = aligned_empty(sphere.size + 1, sphere.dtype)[1:].reshape(sphere.shape)
        shifted[...] = sphere
        cases += [
            (group, "ao4d device", sphere, lambda v=sphere: ao4d.extract(v, 0.0, progress=False).n_simplices),
            (
                group,
                "ao4d device, not aligned",
                shifted,
                lambda v=shifted: ao4d.extract(v, 0.0, progress=False).n_simplices,
            ),
            (
                group,
                "ao4d numpy",
                sphere,
                lambda v=sphere: ao4d.extract(v, 0.0, progress=False, backend="numpy").n_simplices,
            ),
            (group, "VTK FE 1 thread", sphere, _vtk_runner(sphere, "Sequential")),
            (group, f"VTK FE {threaded}", sphere, _vtk_runner(sphere, threaded)),
        ]
    for n in sizes4:
        ball = ao4d.sample(fields.hypersphere(1.0), n, (-1.2, 1.2))
        for method in ("cubes", "simplices"):
            group = f"4D {method} {n}^4"
            cases += [
                (
                    group,
                    "ao4d device",
                    ball,
                    lambda v=ball, m=method: ao4d.extract(v, 0.0, method=m, progress=False).n_simplices,
                ),
                (
                    group,
                    "ao4d numpy",
                    ball,
                    lambda v=ball, m=method: (
                        ao4d.extract(v, 0.0, method=m, progress=False, backend="numpy").n_simplices
                    ),
                ),
            ]
    return cases


_FIRST_CALL = """
import time, json
t0 = time.perf_counter()
import ao4d
from ao4d import fields
from ao4d.opencl import cl
values = ao4d.sample(fields.hypersphere(1.0, dim=3), 256, (-1.2, 1.2))
t1 = time.perf_counter()
mesh = ao4d.extract(values, 0.0, progress=False)
t2 = time.perf_counter()
mesh = ao4d.extract(values, 0.0, progress=False)
t3 = time.perf_counter()
print(json.dumps({"first": t2 - t1, "second": t3 - t2, "stats": cl.kernel_build_stats(),
                  "device": cl.describe(cl.get_runtime(warn=False))}))
"""

_TORUS = """
import json, sys, time
import ao4d
from ao4d import fields
f = fields.spheritorus(1.0, 0.4)
n = int(sys.argv[1])
bounds = (f.extent[0] - 0.1, f.extent[1] + 0.1)
t = time.perf_counter()
if sys.argv[2] == "sample":  # the field's evaluation alone, layer by layer as extract_field does
    axes = fields.grid_axes(n, bounds, dim=4)
    simplices = 0
    for a in range(n):
        fields.evaluate_layers(f, axes, a, a + 1)
else:
    simplices = ao4d.extract_field(f, n, bounds, progress=False, backend=sys.argv[2]).n_simplices
t = time.perf_counter() - t
# VmHWM: this process's own peak (getrusage's maxrss carries the parent's over fork + exec)
hwm = [line for line in open("/proc/self/status") if line.startswith("VmHWM")][0]
print(json.dumps({"time": t, "simplices": simplices, "peak_mib": int(hwm.split()[1]) / 1024}))
"""


def _rotated(cases: list, r: int) -> list:
    """The cases of round ``r``: the groups in order, each group's cases rotated by ``r``.

    On this project's VM the case that runs first after another group's long run (the 96^4 numpy
    engine's 11 s) ran 1.5-2x slower than in a loop (sign pass 8-14 ms against 4.5: memory reads
    of a single-threaded numpy sum of the same array 4x slower, then normal again), while the
    cases after it found the machine warm. A fixed order gave that penalty to the same case, ao4d's
    device engine, every round; rotating spreads it over every case of a group alike.
    """
    out = []
    for group in dict.fromkeys(g for g, *_ in cases):
        members = [c for c in cases if c[0] == group]
        k = r % len(members)
        out += members[k:] + members[:k]
    return out


def _subprocess(code: str, *args: str, env: dict | None = None) -> dict:
    """Run ``code`` in a fresh Python from the repository root; its last line of output as JSON."""
    env = {**os.environ, **(env or {})}
    out = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, env=env, cwd=ROOT, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options."""
    parser = argparse.ArgumentParser(
        prog="python -m bench.extract",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--sizes3", type=int, nargs="*", default=[256, 384])
    parser.add_argument("--sizes4", type=int, nargs="*", default=[64, 96])
    protocol.add_rounds(parser, 5, "timed rounds, cases in turn")
    parser.add_argument("--torus", type=int, default=128, help="spheritorus grid (0: skip)")
    parser.add_argument("--no-first-call", action="store_true", help="skip the fresh processes")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="also print the device engine's time per stage (drains the queue after every stage)",
    )
    return parser.parse_args(argv)


def time_cases(cases: list, rounds: protocol.Rounds) -> tuple[dict, dict]:
    """Every case once untimed, then once a round in turn: (group, name) -> seconds per round,
    and (group, name) -> the simplices it made."""
    times: dict[tuple[str, str], list[float]] = {(g, n): [] for g, n, _, _ in cases}
    outputs: dict[tuple[str, str], int] = {}
    for group, name, _, run in cases:  # warm-up: tables, kernel builds, first-touch pages
        gc.collect()
        outputs[(group, name)] = run()
    for r in rounds:  # in turn, so machine load affects all cases alike
        for group, name, _, run in _rotated(cases, r):
            gc.collect()  # a mesh sits in a reference cycle: free the last one before timing
            t0 = time.perf_counter()
            outputs[(group, name)] = run()
            times[(group, name)].append(time.perf_counter() - t0)
    return times, outputs


def print_cases(cases: list, times: dict, outputs: dict, rounds: protocol.Rounds) -> None:
    """The table: per case the median time (min-max), cells per second, simplices, and the
    device engine's advantage."""
    print(
        f"\nmedian (min-max) of {len(rounds)} rounds taken in turn; 'device is': the other's "
        "median time over the device's (higher: ao4d's device engine faster)"
    )
    if rounds.warning():
        print(rounds.warning())
    print(
        f"{'case':20s} {'engine':22s} {'time s (min-max)':>24s} {'Mcells/s':>9s} {'simplices':>10s} {'device is':>10s}"
    )
    for group in dict.fromkeys(g for g, _, _, _ in cases):
        rows = [(n, v) for g, n, v, _ in cases if g == group]
        dev = float(np.median(times[(group, "ao4d device")]))
        for name, values in rows:
            med = float(np.median(times[(group, name)]))
            cells = int(np.prod(np.array(values.shape) - 1))
            ratio = "" if name == "ao4d device" else f"{med / dev:9.2f}x"
            spread = protocol.format_spread(times[(group, name)], ".3f", "-")
            print(
                f"{group:20s} {name:22s} {spread:>24s} "
                f"{cells / med / 1e6:9.2f} {outputs[(group, name)]:10d} {ratio:>10s}"
            )


def first_call_report() -> None:
    """The first call at 256^3 in a fresh process, with an empty and a warm kernel cache."""
    with tempfile.TemporaryDirectory() as cache:
        cold = _subprocess(_FIRST_CALL, env={"XDG_CACHE_HOME": cache})
        warm = _subprocess(_FIRST_CALL, env={"XDG_CACHE_HOME": cache})
    print(f"\nfirst call in a fresh process, 256^3 sphere ({cold['device']}), once:")
    print(
        f"  empty kernel cache: first {cold['first']:.3f} s (programs compiled: "
        f"{cold['stats']['compiled']}), second {cold['second']:.3f} s"
    )
    print(
        f"  warm kernel cache:  first {warm['first']:.3f} s (programs from cache: "
        f"{warm['stats']['from_cache']}), second {warm['second']:.3f} s"
    )


def torus_report(n: int) -> None:
    """The spheritorus on ``n``^4 slab by slab on both backends, and its sampling alone, each in
    a fresh process: time and peak resident memory."""
    print(f"\nspheritorus {n}^4, extract_field slab by slab, one fresh process each, once:")
    res = {be: _subprocess(_TORUS, str(n), be) for be in ("numpy", "auto", "sample")}
    for be, r in res.items():
        label = {"auto": "device", "numpy": "numpy", "sample": "sampling the field alone"}[be]
        print(f"  {label:6s} {r['time']:8.2f} s  peak {r['peak_mib']:7.0f} MiB  {r['simplices']:,} simplices")
    print(
        f"  device is {res['numpy']['time'] / res['auto']['time']:.2f}x faster, peak memory "
        f"{res['auto']['peak_mib'] / res['numpy']['peak_mib']:.2f}x the numpy path's; "
        f"the numpy path's extraction alone (minus its host sampling): "
        f"{res['numpy']['time'] - res['sample']['time']:.2f} s (the device samples the field itself)"
    )


def profile_report(sizes3: list[int], sizes4: list[int]) -> None:
    """The device engine's seconds per stage (queue drained after each), once per grid."""
    import ao4d
    from ao4d import fields
    from ao4d.marching import cells_device

    print("\ndevice engine stages (seconds, summed over slabs; queue drained after each):")
    cells_device.PROFILE = True
    profiled = [
        (f"3D sphere {n}^3", ao4d.sample(fields.hypersphere(1.0, dim=3), n, (-1.2, 1.2)), "cubes") for n in sizes3
    ] + [
        (f"4D {m} {n}^4", ao4d.sample(fields.hypersphere(1.0), n, (-1.2, 1.2)), m)
        for n in sizes4
        for m in ("cubes", "simplices")
    ]
    for label, values, method in profiled:
        ao4d.extract(values, 0.0, method=method, progress=False)  # warm
        gc.collect()
        cells_device.profile.clear()
        t0 = time.perf_counter()
        ao4d.extract(values, 0.0, method=method, progress=False)
        total = time.perf_counter() - t0
        stages = dict(cells_device.profile)
        rest = total - sum(stages.values())
        print(
            f"  {label:20s} total {total:6.3f}: "
            + ", ".join(f"{k} {v:.3f}" for k, v in stages.items())
            + f", outside the engine {rest:.3f}"
        )
    cells_device.PROFILE = False


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``argv``: the options)."""
    args = parse_args(argv)
    start = time.perf_counter()
    print(protocol.machine_line(protocol.opencl_runtime()))
    print(f"load average before: {protocol.load_average()}", flush=True)
    threaded = vtk_threaded_backend() if args.sizes3 else "Sequential"
    if args.sizes3:
        print(f"VTK's vtkSMPTools backends: Sequential (1 thread) and {threaded} (all threads) in this wheel")
    cases = _cases(args.sizes3, args.sizes4, threaded)
    rounds = protocol.Rounds(args.rounds)
    times, outputs = time_cases(cases, rounds)
    print_cases(cases, times, outputs, rounds)
    if not args.no_first_call:
        protocol.gate("first call")
        first_call_report()
    if args.torus:
        protocol.gate("spheritorus")
        torus_report(args.torus)
    if args.profile:
        profile_report(args.sizes3, args.sizes4)
    print(f"\nafter: load average {protocol.load_average()}; the whole run took {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
