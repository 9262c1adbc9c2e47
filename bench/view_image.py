"""Benchmark: frames per second of the image page (``ao4d view IMAGE.vti``) in headless Chromium,
software WebGL2 (SwiftShader: the GPU emulated on the CPU cores).

The 4D camera's image of a hypersphere (radius 1, seen from w = -4, one light, no AO) is rendered
by :func:`ao4d.render` at 64^3, 128^3 and 256^3 voxels, written with
:func:`ao4d.browser.image_viewer.view_image` and loaded in Debian's Chromium. Each frame the fragment
shader ray-marches every pixel through the volume (2 samples per voxel, nearest voxel, front to
back, stopping at opacity 0.995). Figures per size and transfer function:

* ``ms per frame``: frames drawn back to back by ``window.ao4d.bench(n)`` while az sweeps 20
  degrees, each waiting for the renderer with a 1-pixel read (no vsync cap);
* a 16^3 page is drawn first, so that no size pays the browser's first shader compilation;
* the transfer functions: ``surface`` (opaque: rays stop at the first hit voxel) and ``glass``
  (opacity 0.15 ramp: rays cross the whole object).

The peer is the same ray-march in numpy (:func:`ao4d.browser.image_viewer.reference_march`, one frame),
what a page without GPU marching would run per frame.

Of ``bench._protocol`` it uses the machine line (printed first: the CPU SwiftShader runs on; no
OpenCL device takes part in the figures) and the load gate before each size. It takes no rounds:
a 256^3 page takes long to load in SwiftShader, and each figure is already a mean over many
frames.

    python -m bench.view_image                      # 64, 128, 256; 1024x640 window
    python -m bench.view_image --sizes 64 128 --window 800 600
    python -m bench.view_image --screenshot docs/view_image.png

(run from the repository root).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from bench import _protocol as protocol
from tests._chromium import Chromium, find_chromium  # the headless-Chromium client of the tests


def _image(n: int):
    import ao4d

    mesh = ao4d.extract_field(ao4d.fields.hypersphere(1.0), (24,) * 4, (-1.3, 1.3), progress=False)
    cam = ao4d.Camera4D([0, 0, 0, -4], [0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], fov=40)
    return ao4d.render(mesh, cam, (n, n, n), ao="none", light=[0.3, 1, 0.2, -1], progress=False)


def _draw_ms(browser, budget_s: float = 6.0) -> float:
    """Milliseconds a frame, over as many frames as fit in about ``budget_s`` (2 to 30)."""
    one = browser.evaluate("window.ao4d.bench(1).ms_per_frame", timeout=600)
    frames = int(max(2, min(30, budget_s * 1000 / max(one, 1e-3))))
    return browser.evaluate(f"window.ao4d.bench({frames}).ms_per_frame", timeout=600)


def _fragment(preset: str) -> str:
    """The page's URL fragment for the transfer function ``preset``."""
    from ao4d.browser import image_viewer as iv

    return iv._state_fragment({"array": "rgba", **iv.PRESETS[preset]})


def warm_up(browser, folder: Path) -> None:
    """A 16^3 page drawn with both transfer functions: the first page a fresh browser draws pays
    SwiftShader's shader compilation."""
    from ao4d.browser import image_viewer as iv

    warm = iv.view_image(_image(16), folder / "warm.html")
    for preset in ("surface", "glass"):
        browser.goto(warm.as_uri() + _fragment(preset))
        browser.wait_for("window.ao4d && (window.ao4d.ready || window.ao4d.error)", timeout=600)
        _draw_ms(browser, budget_s=1.0)


def measure_size(browser, n: int, folder: Path, screenshot: Path | None, numpy: bool) -> dict:
    """One size: render, page, and per transfer function load and ms per frame (and the numpy
    ray-march's ms for ``surface``)."""
    from ao4d.browser import image_viewer as iv

    protocol.gate(f"{n}^3")
    t = time.perf_counter()
    image = _image(n)
    render_s = time.perf_counter() - t
    page = iv.view_image(image, folder / f"img{n}.html")
    row = {"size": n, "render_s": render_s, "page_mb": page.stat().st_size / 1e6}
    for preset in ("surface", "glass"):
        t = time.perf_counter()
        browser.goto("about:blank")
        browser.goto(page.as_uri() + _fragment(preset))
        browser.wait_for("window.ao4d && (window.ao4d.ready || window.ao4d.error)", timeout=600)
        if browser.evaluate("window.ao4d.error"):
            raise RuntimeError(browser.evaluate("window.ao4d.error"))
        row["load_s"] = time.perf_counter() - t
        row[preset] = _draw_ms(browser)
        row["canvas"] = browser.evaluate("window.ao4d.stats().canvas")
        if preset == "surface" and screenshot is not None:
            screenshot.parent.mkdir(parents=True, exist_ok=True)
            screenshot.write_bytes(browser.screenshot())
        if numpy and preset == "surface":
            t = time.perf_counter()
            iv.reference_march(image, {"array": "rgba", **iv.PRESETS[preset]}, *row["canvas"])
            row["numpy_ms"] = 1000 * (time.perf_counter() - t)
    print(
        f"{n}^3: render {render_s:.1f} s, page {row['page_mb']:.1f} MB, load {row['load_s']:.1f} s, "
        f"surface {row['surface']:.0f} ms ({1000 / row['surface']:.1f} fps), glass "
        f"{row['glass']:.0f} ms ({1000 / row['glass']:.1f} fps)"
        + (f", numpy {row['numpy_ms']:.0f} ms" if "numpy_ms" in row else ""),
        flush=True,
    )
    return row


def main(argv=None) -> int:
    """Run the benchmark (``argv``: the options); 2 without Chromium."""
    parser = argparse.ArgumentParser(prog="python -m bench.view_image", description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--window", type=int, nargs=2, default=[1024, 640])
    parser.add_argument("--screenshot", type=Path, help="write a PNG of the page (first size)")
    parser.add_argument("--no-numpy", action="store_true", help="skip the numpy peer")
    args = parser.parse_args(argv)
    if find_chromium() is None:
        print("bench.view_image needs Chromium (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    print(protocol.machine_line(), flush=True)
    with (
        tempfile.TemporaryDirectory() as tmp,
        Chromium(width=args.window[0], height=args.window[1], timeout=600) as browser,
    ):
        warm_up(browser, Path(tmp))
        rows = [
            measure_size(browser, n, Path(tmp), args.screenshot if k == 0 else None, not args.no_numpy)
            for k, n in enumerate(args.sizes)
        ]
    print()
    print(f"canvas {rows[0]['canvas'][0]} x {rows[0]['canvas'][1]}, SwiftShader")
    print("| image | page | ms per frame (surface) | fps | ms per frame (glass) | fps | numpy ray-march, per frame |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        numpy_ms = f"{r['numpy_ms']:.0f} ms" if "numpy_ms" in r else "-"
        print(
            f"| {r['size']}³ | {r['page_mb']:.1f} MB | {r['surface']:.0f} | {1000 / r['surface']:.1f} | "
            f"{r['glass']:.0f} | {1000 / r['glass']:.1f} | {numpy_ms} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
