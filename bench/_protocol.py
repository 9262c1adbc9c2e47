"""The benchmarks' protocol: the machine line, the load gate, rounds taken in turn, spreads.

Every script in ``bench/`` runs as ``python -m bench.NAME`` from the repository root and follows
it. A figure without the machine it was measured on is not worth much for a traversal bound by
memory traffic: the machine line (:func:`machine_line`, printed first) names the CPU, its widest
SIMD registers, its L2 and L3 (from ``lscpu``, else sysfs) and the OpenCL device and driver.
Measurements are taken in :class:`Rounds`, every case once a round, in turn, so that all see the
same machine load; every time or ratio is printed as the median over rounds with its minimum and
maximum (:func:`format_spread`, :func:`format_ratio`).

The 1-minute load average counts the benchmark's own work (the meshes it extracts, its previous
round: it runs on every core), so it is printed, but before each round the load gate
(:func:`gate`) pauses and measures how many CPUs other processes keep busy (:func:`others_load`:
``/proc/stat`` less this process tree's own CPU time); a round that starts with that figure above
:data:`LOAD_LIMIT` is flagged loudly, and :meth:`Rounds.warning` repeats the flag under the table.

The memory latency line (:func:`memory_latency`: one work-item chasing a random cycle through
256 MiB, before and after the rounds) describes the machine at the time of a run, beside the
machine line. It is not an explanation: on this project's VM ao4d's AO trace rate once fell 20-25 %
for an hour on the same code (Embree's 7 %) while the line read 177-200 ns, and recovered while it
read 254-267 ns.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import time
import warnings
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

LOAD_LIMIT = 0.5  # CPUs busy with other work before a round above which the round is flagged

_UNITS = {
    "": 1,
    "B": 1,
    "K": 1 << 10,
    "KB": 1 << 10,
    "KIB": 1 << 10,
    "M": 1 << 20,
    "MB": 1 << 20,
    "MIB": 1 << 20,
    "G": 1 << 30,
    "GB": 1 << 30,
    "GIB": 1 << 30,
}


def parse_size(text: str) -> int | None:
    """Bytes of a cache size as lscpu or sysfs write it ("105 MiB (1 instance)", "2048K")."""
    match = re.match(r"\s*([\d.]+)\s*([KMG]?i?B?)", text, re.IGNORECASE)
    if not match:
        return None
    unit = _UNITS.get(match.group(2).upper())
    return None if unit is None else int(float(match.group(1)) * unit)


def parse_lscpu(text: str) -> dict[str, str]:
    """``lscpu``'s "Key: value" lines as a dict (keys stripped)."""
    out = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() and key.strip() not in out:
            out[key.strip()] = value.strip()
    return out


def simd_width(flags: Iterable[str]) -> int:
    """Widest SIMD register in bits from x86 CPU flags (AVX-512 512, AVX 256, SSE 128; else 0)."""
    flags = set(flags)
    if "avx512f" in flags:
        return 512
    if "avx" in flags or "avx2" in flags:
        return 256
    if flags & {"sse2", "sse", "neon", "asimd"}:
        return 128
    return 0


def format_bytes(n: int | float | None) -> str:
    """A size in KiB / MiB ("?" when unknown)."""
    if n is None:
        return "?"
    if n >= 1 << 20:
        return f"{n / (1 << 20):.3g} MiB"
    return f"{n / (1 << 10):.3g} KiB"


def _sysfs_caches() -> dict[int, int]:
    """Per level, the size of one instance of the unified or data cache (sysfs, cpu0)."""
    out = {}
    for index in sorted(Path("/sys/devices/system/cpu/cpu0/cache").glob("index*")):
        try:
            level = int((index / "level").read_text())
            kind = (index / "type").read_text().strip()
            size = parse_size((index / "size").read_text())
        except (OSError, ValueError):
            continue
        if kind in ("Unified", "Data") and size:
            out[level] = size
    return out


def cpu_info() -> dict:
    """CPU model, SIMD width (bits), L2 and L3 in bytes (totals as lscpu reports them; else one
    instance from sysfs), logical CPUs."""
    try:
        lscpu = parse_lscpu(
            subprocess.run(
                ["lscpu"], capture_output=True, text=True, check=False, env=dict(os.environ, LC_ALL="C")
            ).stdout
        )
    except OSError:
        lscpu = {}
    flags = lscpu.get("Flags", "").split()
    if not flags:
        try:
            text = Path("/proc/cpuinfo").read_text()
            flags = next(
                (ln.split(":", 1)[1].split() for ln in text.splitlines() if ln.startswith(("flags", "Features"))), []
            )
        except OSError:
            pass
    sysfs = _sysfs_caches()
    l2 = parse_size(lscpu["L2 cache"]) if "L2 cache" in lscpu else sysfs.get(2)
    l3 = parse_size(lscpu["L3 cache"]) if "L3 cache" in lscpu else sysfs.get(3)
    return {
        "model": lscpu.get("Model name", "unknown CPU"),
        "simd": simd_width(flags),
        "l2": l2,
        "l3": l3,
        "cpus": os.cpu_count() or 0,
    }


def machine_line(runtime=None, info: dict | None = None) -> str:
    """One line naming the machine: CPU, SIMD width, L2, L3, OpenCL device and driver."""
    info = cpu_info() if info is None else info
    line = (
        f"machine: {info['model']}, {info['cpus']} CPUs, SIMD {info['simd']} bit, "
        f"L2 {format_bytes(info['l2'])}, L3 {format_bytes(info['l3'])}"
    )
    if runtime is not None:
        device = runtime.device
        line += (
            f"; OpenCL: {device.name.strip()} ({device.platform.name.strip()}, driver {device.driver_version.strip()})"
        )
    return line


def load_average() -> str:
    """The 1, 5 and 15-minute load averages ("unknown" where the OS has none)."""
    try:
        return ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


def _busy_jiffies() -> tuple[int, int] | None:
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    except (OSError, IndexError):
        return None
    values = [int(x) for x in fields]
    idle = values[3] + (values[4] if len(values) > 4 else 0)  # idle + iowait
    return sum(values[:8]) - idle, sum(values[:8])


def _own_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def others_load(pause: float = 1.0) -> float | None:
    """CPUs kept busy by other processes during a ``pause`` of this one (None without /proc)."""
    a, own_a, wall_a = _busy_jiffies(), _own_seconds(), time.perf_counter()
    time.sleep(pause)
    b, own_b, wall_b = _busy_jiffies(), _own_seconds(), time.perf_counter()
    if a is None or b is None:
        return None
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    busy = (b[0] - a[0]) / tick - (own_b - own_a)
    return max(0.0, busy / (wall_b - wall_a))


def gate(label: str, limit: float = LOAD_LIMIT, pause: float = 2.0) -> bool:
    """The load gate before the timed step ``label`` ("round 2/5"): print the load averages and
    the CPUs other processes keep busy during a ``pause``; warn loudly when that exceeds
    ``limit``. Returns whether the step starts quiet."""
    others = others_load(pause)
    loud = others is not None and others > limit
    what = f"other processes keep {others:.2f} CPUs busy" if others is not None else "others' load unknown"
    print(f"{label}: load average {load_average()} (includes this benchmark); {what}", flush=True)
    if loud:
        print(
            f"!!! WARNING: {label} starts on a busy machine ({others:.2f} CPUs busy with other "
            f"work, above {limit}): its figures are not quiet figures !!!",
            flush=True,
        )
    return not loud


def check_round(index: int, rounds: int, limit: float = LOAD_LIMIT, pause: float = 2.0) -> bool:
    """:func:`gate` before round ``index`` (0-based) of ``rounds``."""
    return gate(f"round {index + 1}/{rounds}", limit, pause)


class Rounds:
    """``count`` rounds taken in turn, each behind the load gate: iterating gives the round
    indices (0-based), :attr:`quiet` whether each round started quiet.

    Parameters
    ----------
    count : int
        Rounds, at least 1.
    limit : float
        CPUs busy with other work above which a round is flagged.
    pause : float
        Seconds the gate measures the others' load for.
    """

    def __init__(self, count: int, *, limit: float = LOAD_LIMIT, pause: float = 2.0):
        if count < 1:
            raise ValueError(f"rounds must be at least 1, got {count}")
        self.count, self.limit, self.pause = count, limit, pause
        self.quiet: list[bool] = []

    def __len__(self) -> int:
        return self.count

    def __iter__(self) -> Iterator[int]:
        for index in range(self.count):
            self.quiet.append(check_round(index, self.count, self.limit, self.pause))
            yield index

    @property
    def noisy(self) -> list[int]:
        """The rounds (1-based) that started on a busy machine."""
        return [i + 1 for i, quiet in enumerate(self.quiet) if not quiet]

    def warning(self) -> str:
        """The loud line for the table's head when a round started busy, else ""."""
        if not self.noisy:
            return ""
        return f"!!! WARNING: rounds {self.noisy} started on a busy machine: these are not quiet figures !!!"


def _at_least_one(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def add_rounds(parser: argparse.ArgumentParser, default: int | None, help: str, *aliases: str) -> None:
    """``--rounds`` (and ``aliases``) on ``parser``: an integer of at least 1."""
    parser.add_argument("--rounds", *aliases, dest="rounds", type=_at_least_one, default=default, help=help)


class Clock:
    """Wall and process CPU time (all threads: OpenCL's and Embree's included) since the last lap."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def lap(self) -> tuple[float, float]:
        """(wall, CPU) seconds since the last lap or the start."""
        wall, cpu = time.perf_counter(), time.process_time()
        out = (wall - self.wall, cpu - self.cpu)
        self.wall, self.cpu = wall, cpu
        return out


def timed(fn: Callable[[], Any], repeat: int = 1) -> tuple[float, Any]:
    """(median wall seconds of ``repeat`` calls of ``fn``, the last call's result)."""
    walls, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - start)
    return statistics.median(walls), result


def opencl_runtime():
    """ao4d's OpenCL runtime for the machine line, or None without a device."""
    from ao4d.opencl import cl

    return cl.get_runtime(warn=False)


_CHASE = """
__kernel void chase(__global const int *next, const int steps, __global int *out)
{
    int i = 0;
    for (int k = 0; k < steps; ++k) i = next[i];
    out[0] = i;
}
"""
_LINE_INTS = 16  # one read per 64-byte cache line


def chase_cycle(lines: int, seed: int = 0):
    """(lines * 16,) int32 array whose entries at multiples of 16 form one random cycle through
    every line: ``next[16 i]`` is the start of the line after line ``i`` (a dependent chain of
    reads the prefetchers cannot guess)."""
    import numpy as np

    order = np.random.default_rng(seed).permutation(lines).astype(np.int32)
    nxt = np.zeros(lines * _LINE_INTS, dtype=np.int32)
    nxt[order * _LINE_INTS] = np.roll(order, -1) * _LINE_INTS
    return nxt


def memory_latency(runtime, mib: int = 256, steps: int = 1 << 19) -> float:
    """Nanoseconds per read of one OpenCL work-item following :func:`chase_cycle` through
    ``mib`` MiB (median of three runs): the latency of a read that misses every cache."""
    import numpy as np
    import pyopencl as cl

    nxt = chase_cycle(mib * (1 << 20) // (4 * _LINE_INTS))
    ctx, queue = runtime.context, runtime.queue
    with warnings.catch_warnings():  # the runtime's build log ("Compilation started ...")
        warnings.simplefilter("ignore", cl.CompilerWarning)
        kernel = cl.Kernel(cl.Program(ctx, _CHASE).build(), "chase")
    flags = cl.mem_flags
    buf = cl.Buffer(ctx, flags.READ_ONLY | flags.COPY_HOST_PTR, hostbuf=nxt)
    out = cl.Buffer(ctx, flags.WRITE_ONLY, 4)
    times = []
    for _ in range(4):  # the first run pages the buffer in
        start = time.perf_counter()
        kernel(queue, (1,), None, buf, np.int32(steps), out).wait()
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:]) / steps * 1e9


def memory_line(runtime) -> str:
    """``memory latency: N ns a read (...)`` for the machine line's neighbour."""
    return f"memory latency: {memory_latency(runtime):.0f} ns a read (one work-item, random 64-byte lines of 256 MiB)"


def spread(values: Iterable[float]) -> tuple[float, float, float]:
    """Median, minimum and maximum of ``values``."""
    values = list(values)
    return statistics.median(values), min(values), max(values)


def format_spread(values: Iterable[float], spec: str = ".3f", dash: str = "–") -> str:
    """``median (min–max)`` of ``values``, each formatted with ``spec``, e.g. ``0.123 (0.120–0.130)``."""
    m, lo, hi = spread(values)
    return f"{m:{spec}} ({lo:{spec}}{dash}{hi:{spec}})"


def format_ratio(values: Iterable[float]) -> str:
    """``median x (min–max)`` of ratios over rounds, e.g. ``1.23x (1.10–1.40)``."""
    m, lo, hi = spread(values)
    return f"{m:.2f}x ({lo:.2f}–{hi:.2f})"
