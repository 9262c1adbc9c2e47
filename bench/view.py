"""Benchmark: frames per second of the ``ao4d view`` page in headless Chromium, software WebGL2.

Hypersphere meshes of about 10 k, 100 k and 1 M tetrahedra (AO = a ramp in x, so the AO path
runs) are written with :func:`ao4d.view` and loaded in Debian's Chromium with SwiftShader
(``--use-angle=swiftshader``: the GPU emulated on the CPU cores). Each frame the page cuts every
tetrahedron the hyperplane may meet in its vertex shader. Two figures per size:

* ``draw ms``: frames drawn back to back by ``window.ao4d.bench(n)``, each waiting for the
  renderer with a 1-pixel read (no vsync cap), while w sweeps the middle half of the scene;
  as the page runs by default on a software renderer (no multisampling) and with ``#aa=1``
  (4x multisampling, the default on GPUs);
* ``play fps``: the page's own counter (``window.ao4d.stats().fps``) while its play button
  sweeps w: frames actually rendered (the page waits for each frame's fence), at most the
  display rate (60).

The peer is ao4d's CPU slice (``SimplexMesh.slice``, numpy) of the same mesh, which a page
without GPU slicing would have to run per frame (and then upload the triangles).
The design target is a GPU: 1 M tetrahedra at 60 fps; SwiftShader on this machine's cores
stands in for one here, far slower.

Of ``bench._protocol`` it uses the machine line (printed first: the CPU SwiftShader runs on; no
OpenCL device takes part) and the load gate before the table. It takes no rounds: a 1 M-tet
page takes minutes to load in SwiftShader, and each figure is already a mean over many frames
(the CPU slice: the median of three).

    python -m bench.view                       # 10k, 100k, 1M tets, 1024x640 window
    python -m bench.view --sizes 10000 100000 --window 800 600
    python -m bench.view --screenshots docs    # also write docs/view_*.png

(run from the repository root).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import _protocol as protocol
from tests._chromium import Chromium, find_chromium  # the headless-Chromium client of the tests


def _hypersphere(target: int):
    import ao4d

    n = max(6, round(1 + (target / 11.66) ** (1 / 3)))  # 16^4 -> 39,360 tets
    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (n,) * 4, (-1.3, 1.3), progress=False)
    mesh.point_data["ao"] = np.clip(0.5 + 0.45 * mesh.vertices[:, 0], 0.0, 1.0)
    return mesh, n


def _open(browser, url: str) -> float:
    t = time.perf_counter()
    browser.goto("about:blank")
    browser.goto(url)
    browser.wait_for("window.ao4d && (window.ao4d.ready || window.ao4d.error)", timeout=600)
    error = browser.evaluate("window.ao4d.error")
    if error:
        raise RuntimeError(f"page failed: {error}")
    return time.perf_counter() - t


def _draw_ms(browser, budget_s: float = 8.0) -> float:
    one = browser.evaluate("window.ao4d.bench(1).ms_per_frame", timeout=600)
    frames = int(max(3, min(40, budget_s * 1000 / max(one, 1e-3))))
    return browser.evaluate(f"window.ao4d.bench({frames}).ms_per_frame", timeout=600)


def _play_fps(browser, seconds: float = 3.0) -> float:
    browser.evaluate("window.ao4d.play(true)")
    time.sleep(seconds)
    fps = browser.evaluate("window.ao4d.stats().fps")
    browser.evaluate("window.ao4d.play(false)")
    return fps


def bench(sizes, window, out_dir: Path) -> list[dict]:
    """Per size: the page's figures and the CPU slice's, a row each (printed as it comes)."""
    import ao4d

    rows = []
    with Chromium(width=window[0], height=window[1], timeout=600) as browser:
        for target in sizes:
            mesh, n = _hypersphere(target)
            t = time.perf_counter()
            page = ao4d.view(mesh, out_dir / f"bench_{target}.html", state={"w": 0.0})
            write_s = time.perf_counter() - t
            load_s = _open(browser, page.as_uri())
            stats = browser.evaluate("window.ao4d.stats()")
            draw = _draw_ms(browser)
            play = _play_fps(browser)
            _open(browser, page.as_uri() + "#aa=1")
            draw_aa = _draw_ms(browser)
            cpu = []
            for _ in range(3):
                t = time.perf_counter()
                mesh.slice([0, 0, 0, 0.0], [0, 0, 0, 1])
                cpu.append(time.perf_counter() - t)
            rows.append(
                dict(
                    tets=mesh.n_simplices,
                    grid=n,
                    triangles=stats["triangles"],
                    submitted=stats["submitted_tets"],
                    mb=page.stat().st_size / 1e6,
                    write_s=write_s,
                    load_s=load_s,
                    draw_ms=draw,
                    draw_aa_ms=draw_aa,
                    play_fps=play,
                    cpu_slice_ms=1000 * statistics.median(cpu),
                    canvas=stats["canvas"],
                    renderer=stats["renderer"],
                )
            )
            print(_row(rows[-1]), flush=True)
    return rows


HEADER = (
    f"{'tets':>10} {'grid':>5} {'tris(w=0)':>10} {'drawn':>9} {'page MB':>8} {'load s':>7} "
    f"{'draw ms':>8} {'fps':>6} {'4xAA ms':>8} {'play fps':>9} {'CPU slice ms':>13}"
)


def _row(r: dict) -> str:
    return (
        f"{r['tets']:>10,} {r['grid']:>4}^4 {r['triangles']:>10,} {r['submitted']:>9,} "
        f"{r['mb']:>8.1f} {r['load_s']:>7.1f} {r['draw_ms']:>8.1f} {1000 / r['draw_ms']:>6.1f} "
        f"{r['draw_aa_ms']:>8.1f} {r['play_fps']:>9.1f} {r['cpu_slice_ms']:>13.1f}"
    )


def screenshots(out: Path, window) -> list[Path]:
    """The two README pictures: a 4D tiger with its 4D AO, and the demo scene."""
    import ao4d
    from ao4d.commands.demo import run_demo

    out.mkdir(parents=True, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        field = ao4d.fields.tiger()
        lo, hi = field.extent
        mesh = ao4d.extract_field(field, (36,) * 4, (np.asarray(lo) - 0.1, np.asarray(hi) + 0.1), progress=False)
        mesh.point_data["ao"] = ao4d.ambient_occlusion(mesh, samples=64, seed=0, progress=False)
        tiger = ao4d.view(mesh, Path(tmp) / "tiger.html", names=["tiger"], title="4D tiger, 4D AO (64 samples)")
        import io

        run_demo(Path(tmp) / "demo", progress=False, stream=io.StringIO())
        shots = [
            (tiger, "#w=0.15&xy=0&xz=0&xw=20&yz=0&yw=35&zw=0&az=35&el=35&zoom=1.05", out / "view_tiger.png"),
            (Path(tmp) / "demo" / "view.html", "#w=0&az=25&el=22&zoom=1.8", out / "view_demo.png"),
        ]
        with Chromium(width=window[0], height=window[1], timeout=600) as browser:
            for page, fragment, png in shots:
                _open(browser, page.as_uri() + fragment)
                browser.evaluate("window.ao4d.stats()")  # settle the census and its caption
                time.sleep(0.6)
                png.write_bytes(browser.screenshot())
                written.append(png)
                print(f"wrote {png}", flush=True)
    return written


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``argv``: the options); 2 without Chromium."""
    parser = argparse.ArgumentParser(prog="python -m bench.view", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000], help="approximate tetrahedra per mesh"
    )
    parser.add_argument("--window", type=int, nargs=2, default=[1024, 640], metavar=("W", "H"))
    parser.add_argument(
        "--screenshots", type=Path, metavar="DIR", help="write the README pictures into DIR instead of benchmarking"
    )
    args = parser.parse_args(argv)
    if find_chromium() is None:
        print("bench.view needs Chromium (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    if args.screenshots is not None:
        screenshots(args.screenshots, (1100, 640))
        return 0
    print(protocol.machine_line(), flush=True)
    protocol.gate("the table")
    with tempfile.TemporaryDirectory() as tmp:
        print(HEADER, flush=True)
        rows = bench(args.sizes, args.window, Path(tmp))
    r = rows[-1]
    print(f"\nrenderer: {r['renderer']}; canvas {r['canvas'][0]}x{r['canvas'][1]}")
    print(
        "draw ms: back-to-back frames (w sweeping), page defaults (no AA on software GL); "
        "fps = 1000 / draw ms; 4xAA ms: the same with #aa=1; play fps: the page's own counter "
        "of rendered frames while it sweeps w (at most 60)"
    )
    for r in rows:
        print(
            f"{r['tets']:>10,} tets: GPU-path frame {r['draw_ms']:.0f} ms vs CPU slice "
            f"{r['cpu_slice_ms']:.0f} ms (x{r['cpu_slice_ms'] / r['draw_ms']:.2f}); "
            f"1 M-tet target at 60 fps = {1e6 / r['tets'] * r['draw_ms'] / (1000 / 60):.0f}x "
            f"this renderer's speed"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
