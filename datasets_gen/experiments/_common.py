"""Shared pieces of the experiment scripts: command line, CSV and figure output, timing."""

from __future__ import annotations

import argparse
import csv
import io
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ao4d._atomic import atomic_open, atomic_path

__all__ = [
    "parse_args",
    "write_csv",
    "write_results",
    "figure",
    "measured",
    "finish_panel",
    "save_figure",
    "best_time",
    "machine",
]


def parse_args(name: str, description: str, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """``--out DIR`` (required) and ``--quick``."""
    parser = argparse.ArgumentParser(prog=f"python -m datasets_gen.experiments.{name}", description=description)
    parser.add_argument("--out", required=True, type=Path, help="folder for NAME.csv and NAME.png")
    parser.add_argument("--quick", action="store_true", help="small sizes (seconds), for tests")
    return parser.parse_args(argv)


def write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    """Write dict rows (same keys, in order) as CSV, atomically; floats with repr precision."""
    if not rows:
        raise ValueError("`rows` is empty: nothing to write")
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text.getvalue())
    return path


def write_results(
    out: Path,
    name: str,
    rows: list[dict[str, Any]],
    plot: Callable[[list[dict[str, Any]], Path], Any],
    extra_tables: dict[str, list[dict[str, Any]]] | None = None,
) -> list[Path]:
    """Write ``NAME.csv``, any ``NAME_<suffix>.csv`` tables and the plot ``NAME.png`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    written = [write_csv(out / f"{name}.csv", rows)]
    for suffix, table in (extra_tables or {}).items():
        written.append(write_csv(out / f"{name}_{suffix}.csv", table))
    plot(rows, out / f"{name}.png")
    written.append(out / f"{name}.png")
    print("wrote " + ", ".join(str(path) for path in written))
    return written


def figure(n_panels: int = 1, *, width: float = 5.0, height: float = 3.8):
    """A matplotlib Figure on an Agg canvas (no pyplot state) and its axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width * n_panels, height), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(1, n_panels, i + 1) for i in range(n_panels)]
    return fig, axes


def measured(ax, rows: list[dict[str, Any]], x: str, y: str, style: str, **options: Any) -> None:
    """One measured series on log-log axes: column ``y`` of ``rows`` against column ``x``,
    markers of size 4, ``options`` (``color``, ``label``) to ``loglog``; nothing for no rows."""
    if rows:
        ax.loglog([r[x] for r in rows], [r[y] for r in rows], style, ms=4, **options)


def finish_panel(ax, *, title: str, xlabel: str, ylabel: str) -> None:
    """Title, axis labels, a grid on every (log) decade and a small legend: a throughput panel."""
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


def save_figure(fig, path: Path) -> Path:
    """Save a PNG atomically."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path


def best_time(func: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """Smallest wall-clock time of ``repeats`` calls (the least disturbed by other load), and the
    last result."""
    best, result = float("inf"), None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        result = func()
        best = min(best, time.perf_counter() - t0)
    return best, result


def machine() -> str:
    """One line naming the machine and the OpenCL device, for plot footnotes."""
    import os

    from ao4d.opencl import cl

    runtime = cl.get_runtime(warn=False)
    device = runtime.name if runtime else "no OpenCL device"
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; {device}"
