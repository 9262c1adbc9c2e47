"""The ``ao4d`` command line. Each subcommand lives in ``ao4d/commands/<name>.py``.

A command module defines ``HELP`` (one line), ``EXAMPLES`` (text shown under ``--help``),
``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# order shown in `ao4d --help`
COMMANDS = ("demo", "info", "lut", "extract", "ao", "render", "slice", "view")

EPILOG = """examples:
  ao4d demo                      render the default 4D scene into ./ao4d-demo/
  ao4d info                      list OpenCL platforms/devices and which one ao4d uses
  ao4d lut verify                check the shipped lookup tables against their checksums
  ao4d <command> --help          options and examples of one command
"""


def _load(name: str):
    return importlib.import_module(f"ao4d.commands.{name}")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="ao4d",
        description="True 4D surfaces, 4D ambient occlusion (OpenCL) and renders into 3D volumes.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"ao4d {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--no-progress", action="store_true", help="no progress bars or progress lines (errors and results still print)"
    )
    for name in COMMANDS:
        module = _load(name)
        cmd = sub.add_parser(
            name,
            parents=[common],
            help=module.HELP,
            description=module.HELP,
            epilog="examples:\n" + module.EXAMPLES,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    from . import _progress
    from .opencl import cl

    _progress.set_enabled(not args.no_progress)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("ao4d: interrupted", file=sys.stderr)
        return 130
    except (ValueError, TypeError, OSError, MemoryError, cl.NoOpenCLDeviceError) as exc:
        print(f"ao4d {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
