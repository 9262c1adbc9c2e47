"""``ao4d view``: a self-contained WebGL2 page that slices and turns 4D meshes in the browser, or
ray-marches the 3D image of a 4D camera (``.vti`` / ``.mhd`` from ``ao4d render``): chosen by the
files' suffix."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._options import add_meshes

HELP = (
    "write a self-contained HTML page that slices 4D meshes (.npz) or ray-marches a rendered "
    "3D image (.vti, .mhd) on the GPU, in the browser"
)
EXAMPLES = """  ao4d view scene.npz --out scene.html              open scene.html in any current browser
  ao4d view a.npz b.npz --names ball torus --out both.html
  ao4d view scene.npz --w 0.3 --xw 90 --out turned.html
  ao4d view huge.npz --serve --port 8000            serve on 127.0.0.1 (pages over 150 MB)
  ao4d view image.vti --out image.html              the 4D camera's 3D image, ray-marched
  ao4d view image.vti --array occlusion --out ao.html
  page state lives in the URL: scene.html#w=0.3&xw=90&az=30&el=20&zoom=1,
  image.html#array=shade&cmap=magma&lo=0&hi=0&opacity=1&x0=0&x1=1&...&az=30&el=20&zoom=1
"""


def _port(text: str) -> int:
    """``--port``'s value: a TCP port, 0..65535 (0: any free one)."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"must be an integer in 0..65535 (0: any free one), got {text!r}")
    return port


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..browser.viewer import ANGLES, MAX_BYTES

    add_meshes(
        parser,
        metavar="FILE",
        help="meshes saved by ao4d (.npz: all 4D, or all 3D), or one image written by ao4d render (.vti or .mhd)",
    )
    parser.add_argument(
        "--out", type=Path, metavar="PAGE.html", help="the page to write (default: view.html; not with --serve)"
    )
    parser.add_argument(
        "--serve",
        action="store_true",
        help="serve the page on 127.0.0.1 instead of writing it (any size); Ctrl-C stops",
    )
    parser.add_argument(
        "--port", type=_port, default=0, help="port for --serve (default: any free one; the URL is printed)"
    )
    parser.add_argument("--open", action="store_true", help="open the page in the default browser")
    parser.add_argument("--names", nargs="+", metavar="NAME", help="one label per mesh")
    parser.add_argument("--title", help="page title")
    start = parser.add_argument_group("initial view (the URL fragment overrides it)")
    start.add_argument("--w", type=float, help="hyperplane offset (default: the scene's centre in w)")
    for name in ANGLES:
        start.add_argument(
            f"--{name}", type=float, default=0.0, metavar="DEG", help=f"4D rotation in the {name} plane, degrees"
        )
    start.add_argument("--az", type=float, default=30.0, metavar="DEG", help="camera azimuth (30)")
    start.add_argument("--el", type=float, default=20.0, metavar="DEG", help="camera elevation (20)")
    start.add_argument("--zoom", type=float, default=1.0, help="camera zoom (1)")
    start.add_argument(
        "--array",
        choices=("rgba", "shade", "occlusion", "depth"),
        help="images: the array shown (default rgba when present, else shade)",
    )
    start.add_argument(
        "--cmap",
        default="magma",
        help="images: colour map of the scalar arrays (magma, viridis, inferno, cividis, gray, coolwarm)",
    )
    parser.add_argument(
        "--no-compress",
        action="store_true",
        help="store the buffers uncompressed (for browsers without DecompressionStream)",
    )
    parser.add_argument(
        "--max-mb",
        type=float,
        default=MAX_BYTES / 1e6,
        help=f"largest page to write, in MB (default {MAX_BYTES / 1e6:g}); beyond it use --serve",
    )


def _run_image(args: argparse.Namespace) -> int:
    import warnings

    from ..browser.image_viewer import ImageRangeWarning, full_state, image_page_text, load_image, view_image

    if len(args.meshes) != 1:
        raise ValueError(f"`FILE`: one image (.vti or .mhd) per page, got {len(args.meshes)} files")
    if args.names:
        raise ValueError("`--names` labels meshes; an image page has one image (use --title)")
    state = {"az": args.az, "el": args.el, "zoom": args.zoom, "array": args.array, "cmap": args.cmap}
    full_state(state)  # bad values are named before the image is read
    image = args.meshes[0]
    if not image.is_file():
        raise FileNotFoundError(f"`FILE`: no such image file: {image}")
    if args.serve and args.out is not None:
        raise ValueError("`--out` and `--serve` exclude each other: --serve writes no file")
    out = None if args.serve else _page_file(args)
    data = load_image(image)
    if args.array is not None and args.array not in data.arrays:
        raise ValueError(
            f"`--array` {args.array!r}: {image} holds only "
            f"{', '.join(map(repr, data.arrays))}"
            + (" (a .mhd file holds shade alone)" if image.suffix.lower() == ".mhd" else "")
        )
    for note in data.notes:
        print(f"ao4d view: note: {note}", file=sys.stderr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImageRangeWarning)  # the notes are printed above
        if args.serve:
            from ..browser.viewer import ViewServer

            text = image_page_text(data, state=state, title=args.title, compress=not args.no_compress)
            server = ViewServer(text.encode("utf-8"), [], "127.0.0.1", args.port)
            return _serve_until_stopped(server, f"{image}", args.open)
        path = view_image(
            data, out, state=state, title=args.title, compress=not args.no_compress, max_bytes=int(args.max_mb * 1e6)
        )
    return _written(path, args.open)


def _page_file(args: argparse.Namespace) -> Path:
    """The page to write (``--out``, default view.html), checked with ``--max-mb`` before any work."""
    from .._atomic import check_output_file

    if not args.max_mb > 0:
        raise ValueError(f"`--max-mb` must be > 0, got {args.max_mb}")
    return check_output_file(args.out if args.out is not None else Path("view.html"), "--out", (".html", ".htm"))


def _written(path: Path, open_browser: bool) -> int:
    """Say where the page was written and open it if asked."""
    print(
        f"ao4d view: wrote {path} ({path.stat().st_size / 1e6:.1f} MB); open it in a browser (file://{path.resolve()})"
    )
    if open_browser:
        import webbrowser

        webbrowser.open(path.resolve().as_uri())
    return 0


def _serve_until_stopped(server, what: str, open_browser: bool) -> int:
    """Say where ``server`` serves ``what``, open it if asked, and serve until Ctrl-C."""
    print(f"ao4d view: serving {what} at {server.url}  (Ctrl-C stops)", flush=True)
    if open_browser:
        import webbrowser

        webbrowser.open(server.url)
    try:
        server.wait()
    except KeyboardInterrupt:
        print("ao4d view: stopped", file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> int:
    from ..browser.viewer import ANGLES, serve, view

    suffixes = {p.suffix.lower() for p in args.meshes}
    if suffixes & {".vti", ".mhd"}:
        if suffixes - {".vti", ".mhd"}:
            raise ValueError(
                f"`FILE`: meshes (.npz) and images (.vti, .mhd) go on separate pages, got {sorted(suffixes)}"
            )
        return _run_image(args)

    state = {"w": args.w, "az": args.az, "el": args.el, "zoom": args.zoom, **{a: getattr(args, a) for a in ANGLES}}
    options = dict(names=args.names, state=state, title=args.title, compress=not args.no_compress)
    if args.serve:
        if args.out is not None:
            raise ValueError("`--out` and `--serve` exclude each other: --serve writes no file")
        server = serve(args.meshes, port=args.port, **options)
        return _serve_until_stopped(server, f"{len(args.meshes)} mesh(es)", args.open)
    out = _page_file(args)  # before loading the meshes
    path = view(args.meshes, out, max_bytes=int(args.max_mb * 1e6), **options)
    return _written(path, args.open)
