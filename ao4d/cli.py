"""The ``ao4d`` command line. Each subcommand lives in ``ao4d/commands/<name>.py``.

A command module defines ``HELP`` (one line), ``EXAMPLES`` (text shown under ``--help``),
``add_arguments(parser)`` and ``run(args) -> int``; optionally ``PARAMETERS``, the library
parameters its options become under another name (``{"shape": "--size"}``), so that an error
from the library names the option the user typed.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys

# order shown in `ao4d --help`
COMMANDS = ("demo", "info", "lut", "extract", "lift", "ao", "render", "slice", "view")

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
        _take_negative_numbers(cmd)
        for action in cmd._actions:  # and the subcommands' own (``ao4d lut verify``)
            if isinstance(action, argparse._SubParsersAction):
                for subparser in action.choices.values():
                    _take_negative_numbers(subparser)
        cmd.set_defaults(_run=module.run, _options=_option_names(cmd, getattr(module, "PARAMETERS", {})))
    return parser


def _option_names(parser: argparse.ArgumentParser, extra: dict[str, str]) -> dict[str, str]:
    """Library parameter name -> the command's option: each option's own ``dest``
    (``max_distance`` -> ``--max-distance``), then the command's ``PARAMETERS``."""
    names = {}
    for action in parser._actions:
        longs = [o for o in action.option_strings if o.startswith("--")]
        if longs and action.dest not in ("help", "no_progress"):
            names[action.dest] = longs[0]
    return {**names, **extra}


# argparse takes ``-1`` and ``-.5`` for values but ``-inf``, ``-nan`` and ``-1e3`` for options,
# and then fails with "--bounds: expected 2 arguments"; every word that reads as a negative
# number is a value here (no ao4d option looks like one), and the option's own check refuses
# what is not finite. argparse keeps this pattern per parser (a private attribute since 3.2).
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


def _take_negative_numbers(parser: argparse.ArgumentParser) -> None:
    """Make ``parser`` read any negative number, ``-inf`` and ``-nan`` as a value."""
    if hasattr(parser, "_negative_number_matcher"):
        parser._negative_number_matcher = _NEGATIVE_NUMBER


def _with_option_names(message: str, names: dict[str, str]) -> str:
    """``message`` with each backticked library parameter replaced by the command's option."""
    return re.sub(r"`([A-Za-z_]\w*)`", lambda m: f"`{names.get(m.group(1), m.group(1))}`", message)


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
        print(f"ao4d {args.command}: error: {_with_option_names(str(exc), args._options)}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
