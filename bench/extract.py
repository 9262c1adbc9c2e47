"""Benchmark: ao4d extraction on the OpenCL device against its numpy engine, VTK's flying edges
and scikit-image, in one run, cases taken in turn.

3D: a sphere sampled on 128^3, 256^3 and 384^3 grids: ao4d on the device (``backend="auto"``, what
``ao4d.extract`` does), ao4d's numpy engine (``backend="numpy"``), ``vtkFlyingEdges3D`` (one
thread: VTK's SMP backend set to sequential; no normals, gradients or scalars) and
scikit-image's ``marching_cubes`` (Lorensen). 4D: a hypersphere on 48^4, 64^4 and 96^4 grids,
both methods, device against numpy. Every case runs once untimed (table loading, kernel
builds), then ``--repeats`` times in turn; the table shows the best time, cells and output
simplices (triangles, tetrahedra) per second, and ratios. ao4d's times are what the user waits
for: ``ao4d.extract`` from the array to the SimplexMesh, checks included.

Also measured, each in a fresh process: the first call (device discovery, kernel build with an
empty kernel cache, extraction) and, with ``--torus``, a 128^4 spheritorus extracted slab by
slab with ``extract_field`` on both backends (time and peak resident memory).

    python bench/extract.py                     # everything, best of 3
    python bench/extract.py --sizes3 128 256 --sizes4 48 64 --repeats 3 --no-torus
    python bench/extract.py --profile           # where the device engine's time goes
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

# the rates the numpy engine reached before the device engine (issue 22's figures, 64^4)
TODAY_4D = {"cubes": 24.0, "simplices": 3.6}  # Mcells/s


def _vtk_runner(values: np.ndarray):
    import vtk
    from vtk.util import numpy_support

    vtk.vtkSMPTools.SetBackend("Sequential")
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
        fe.Modified()
        fe.Update()
        return fe.GetOutput().GetNumberOfCells()

    return run


def _cases(sizes3, sizes4):
    import ao4d
    from ao4d import fields
    from skimage import measure

    cases = []
    for n in sizes3:
        sphere = ao4d.sample(fields.hypersphere(1.0, dim=3), n, (-1.2, 1.2))
        group = f"3D sphere {n}^3"
        cases += [
            (group, "ao4d device", sphere,
             lambda v=sphere: ao4d.extract(v, 0.0, progress=False).n_simplices),
            (group, "ao4d numpy", sphere,
             lambda v=sphere: ao4d.extract(v, 0.0, progress=False, backend="numpy").n_simplices),
            (group, "VTK flying edges", sphere, _vtk_runner(sphere)),
            (group, "scikit-image", sphere,
             lambda v=sphere: len(measure.marching_cubes(v, 0.0, method="lorensen")[1])),
        ]
    for n in sizes4:
        ball = ao4d.sample(fields.hypersphere(1.0), n, (-1.2, 1.2))
        for method in ("cubes", "simplices"):
            group = f"4D {method} {n}^4"
            cases += [
                (group, "ao4d device", ball, lambda v=ball, m=method:
                 ao4d.extract(v, 0.0, method=m, progress=False).n_simplices),
                (group, "ao4d numpy", ball, lambda v=ball, m=method:
                 ao4d.extract(v, 0.0, method=m, progress=False, backend="numpy").n_simplices),
            ]
    return cases


_FIRST_CALL = """
import time, json
t0 = time.perf_counter()
import ao4d
from ao4d import fields, cl
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


def _subprocess(code: str, *args: str, env: dict | None = None) -> dict:
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         env={**os.environ, **(env or {})}, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes3", type=int, nargs="*", default=[128, 256, 384])
    parser.add_argument("--sizes4", type=int, nargs="*", default=[48, 64, 96])
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per case (best)")
    parser.add_argument("--torus", type=int, default=128, help="spheritorus grid (0: skip)")
    parser.add_argument("--no-torus", action="store_const", const=0, dest="torus")
    parser.add_argument("--profile", action="store_true",
                        help="also print the device engine's time per stage (drains the queue "
                             "after every stage)")
    args = parser.parse_args(argv)

    from ao4d import cells_device, cl

    print(f"device: {cl.describe(cl.get_runtime(warn=False))}")
    cases = _cases(args.sizes3, args.sizes4)
    times: dict[tuple[str, str], list[float]] = {(g, n): [] for g, n, _, _ in cases}
    outputs: dict[tuple[str, str], int] = {}
    for group, name, _, run in cases:  # warm-up: tables, kernel builds, first-touch pages
        outputs[(group, name)] = run()
    for _ in range(args.repeats):  # in turn, so machine load affects all cases alike
        for group, name, _, run in cases:
            t0 = time.perf_counter()
            outputs[(group, name)] = run()
            times[(group, name)].append(time.perf_counter() - t0)

    print(f"\nbest of {args.repeats} runs (median in brackets); ratios are speeds (higher: ao4d device faster)")
    print(f"{'case':22s} {'engine':18s} {'time s':>8s} {'(median)':>9s} {'Mcells/s':>9s} "
          f"{'simplices':>10s} {'Msimp/s':>8s} {'device is':>10s}")
    groups = list(dict.fromkeys(g for g, _, _, _ in cases))
    for group in groups:
        rows = [(n, v) for g, n, v, _ in cases if g == group]
        dev = min(times[(group, "ao4d device")])
        for name, values in rows:
            best = min(times[(group, name)])
            med = float(np.median(times[(group, name)]))
            cells = int(np.prod(np.array(values.shape) - 1))
            ratio = "" if name == "ao4d device" else f"{best / dev:9.2f}x"
            print(f"{group:22s} {name:18s} {best:8.3f} {med:9.3f} {cells / best / 1e6:9.2f} "
                  f"{outputs[(group, name)]:10d} {outputs[(group, name)] / best / 1e6:8.2f} {ratio:>10s}")
        if group.startswith("4D"):
            method = group.split()[1]
            rate = cells / dev / 1e6
            print(f"{'':22s} {'vs issue 22 today':18s} {TODAY_4D[method]:8.1f} Mcells/s -> "
                  f"{rate:.1f} Mcells/s: {rate / TODAY_4D[method]:.2f}x")

    with tempfile.TemporaryDirectory() as cache:
        cold = _subprocess(_FIRST_CALL, env={"XDG_CACHE_HOME": cache})
        warm = _subprocess(_FIRST_CALL, env={"XDG_CACHE_HOME": cache})
    print(f"\nfirst call in a fresh process, 256^3 sphere ({cold['device']}):")
    print(f"  empty kernel cache: first {cold['first']:.3f} s (programs compiled: "
          f"{cold['stats']['compiled']}), second {cold['second']:.3f} s")
    print(f"  warm kernel cache:  first {warm['first']:.3f} s (programs from cache: "
          f"{warm['stats']['from_cache']}), second {warm['second']:.3f} s")

    if args.torus:
        n = args.torus
        print(f"\nspheritorus {n}^4, extract_field slab by slab, one fresh process each:")
        res = {be: _subprocess(_TORUS, str(n), be) for be in ("numpy", "auto", "sample")}
        for be, r in res.items():
            label = {"auto": "device", "numpy": "numpy", "sample": "sampling the field alone"}[be]
            print(f"  {label:6s} {r['time']:8.2f} s  peak {r['peak_mib']:7.0f} MiB  "
                  f"{r['simplices']:,} simplices")
        print(f"  device is {res['numpy']['time'] / res['auto']['time']:.2f}x faster, peak memory "
              f"{res['auto']['peak_mib'] / res['numpy']['peak_mib']:.2f}x the numpy path's; "
              f"extraction alone (minus sampling): numpy "
              f"{res['numpy']['time'] - res['sample']['time']:.2f} s, device "
              f"{res['auto']['time'] - res['sample']['time']:.2f} s")

    if args.profile:
        import ao4d
        from ao4d import fields

        print("\ndevice engine stages (seconds, summed over slabs; queue drained after each):")
        cells_device.PROFILE = True
        for label, values, method in (
            [(f"3D sphere {n}^3", ao4d.sample(fields.hypersphere(1.0, dim=3), n, (-1.2, 1.2)), "cubes")
             for n in args.sizes3[len(args.sizes3) // 2:][:1]]
            + [(f"4D {m} {n}^4", ao4d.sample(fields.hypersphere(1.0), n, (-1.2, 1.2)), m)
               for n in args.sizes4[len(args.sizes4) // 2:][:1] for m in ("cubes", "simplices")]):
            cells_device.profile.clear()
            t0 = time.perf_counter()
            ao4d.extract(values, 0.0, method=method, progress=False)
            total = time.perf_counter() - t0
            stages = dict(cells_device.profile)
            rest = total - sum(stages.values())
            print(f"  {label:22s} total {total:6.3f}: " + ", ".join(
                f"{k} {v:.3f}" for k, v in stages.items()) + f", outside the engine {rest:.3f}")
        cells_device.PROFILE = False
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
