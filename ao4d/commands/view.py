"""``ao4d view``: a self-contained WebGL2 page that slices and turns 4D meshes in the browser."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "write a self-contained HTML page that slices 4D meshes (.npz) on the GPU, in the browser"
EXAMPLES = """  ao4d view scene.npz --out scene.html              open scene.html in any current browser
  ao4d view a.npz b.npz --names ball torus --out both.html
  ao4d view scene.npz --w 0.3 --xw 90 --out turned.html
  ao4d view huge.npz --serve --port 8000            serve on 127.0.0.1 (pages over 150 MB)
  page state lives in the URL: scene.html#w=0.3&xw=90&az=30&el=20&zoom=1
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..viewer import ANGLES

    parser.add_argument("meshes", nargs="+", type=Path, metavar="MESH.npz",
                        help="meshes saved by ao4d (all 4D, or all 3D)")
    parser.add_argument("--out", type=Path, metavar="PAGE.html",
                        help="the page to write (default: view.html; not with --serve)")
    parser.add_argument("--serve", action="store_true",
                        help="serve the page on 127.0.0.1 instead of writing it (any size); Ctrl-C stops")
    parser.add_argument("--port", type=int, default=0,
                        help="port for --serve (default: any free one; the URL is printed)")
    parser.add_argument("--open", action="store_true", help="open the page in the default browser")
    parser.add_argument("--names", nargs="+", metavar="NAME", help="one label per mesh")
    parser.add_argument("--title", help="page title")
    start = parser.add_argument_group("initial view (the URL fragment overrides it)")
    start.add_argument("--w", type=float, help="hyperplane offset (default: the scene's centre in w)")
    for name in ANGLES:
        start.add_argument(f"--{name}", type=float, default=0.0, metavar="DEG",
                           help=f"4D rotation in the {name} plane, degrees")
    start.add_argument("--az", type=float, default=30.0, metavar="DEG", help="camera azimuth (30)")
    start.add_argument("--el", type=float, default=20.0, metavar="DEG", help="camera elevation (20)")
    start.add_argument("--zoom", type=float, default=1.0, help="camera zoom (1)")
    parser.add_argument("--no-compress", action="store_true",
                        help="store the buffers uncompressed (for browsers without DecompressionStream)")
    parser.add_argument("--max-mb", type=float, default=150.0,
                        help="largest page to write, in MB (default 150); beyond it use --serve")


def run(args: argparse.Namespace) -> int:
    from ..viewer import ANGLES, serve, view

    state = {"w": args.w, "az": args.az, "el": args.el, "zoom": args.zoom,
             **{a: getattr(args, a) for a in ANGLES}}
    options = dict(names=args.names, state=state, title=args.title, compress=not args.no_compress)
    if args.serve:
        if args.out is not None:
            raise ValueError("`--out` and `--serve` exclude each other: --serve writes no file")
        server = serve(args.meshes, port=args.port, **options)
        print(f"ao4d view: serving {len(args.meshes)} mesh(es) at {server.url}  (Ctrl-C stops)",
              flush=True)
        if args.open:
            import webbrowser

            webbrowser.open(server.url)
        try:
            server.wait()
        except KeyboardInterrupt:
            print("ao4d view: stopped", file=sys.stderr)
        return 0
    if not args.max_mb > 0:
        raise ValueError(f"`--max-mb` must be > 0, got {args.max_mb}")
    from .._atomic import check_output_file

    out = check_output_file(args.out if args.out is not None else Path("view.html"), "--out",
                            (".html", ".htm"))  # before loading the meshes
    path = view(args.meshes, out, max_bytes=int(args.max_mb * 1e6), **options)
    size = path.stat().st_size
    print(f"ao4d view: wrote {path} ({size / 1e6:.1f} MB); open it in a browser "
          f"(file://{path.resolve()})")
    if args.open:
        import webbrowser

        webbrowser.open(path.resolve().as_uri())
    return 0
