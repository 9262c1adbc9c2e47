"""Progress that suits a terminal and a log file.

On a terminal (stderr is a TTY) long work shows a tqdm bar. Anywhere else, a bar would write
carriage returns and cursor codes into the log, so a plain line is printed instead, at most every
``LOG_INTERVAL`` seconds, plus one line at the end if any was printed::

    AO: 3.1 M / 11.2 M rays (28%), 10 s elapsed, about 26 s left

``set_enabled(False)`` (the command line's ``--no-progress``) silences every bar and line in the
process. Whether a given piece of work shows progress at all is the caller's ``show`` argument.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

__all__ = ["bar", "set_enabled", "enabled", "LOG_INTERVAL"]

LOG_INTERVAL = 10.0  # seconds between log lines
_state = {"enabled": True}


def set_enabled(flag: bool) -> None:
    """Switch every progress display of this process on or off (``--no-progress``)."""
    _state["enabled"] = bool(flag)


def enabled() -> bool:
    """False once :func:`set_enabled` switched progress off."""
    return _state["enabled"]


def bar(
    total: float,
    desc: str,
    *,
    unit: str = "it",
    show: bool = True,
    unit_scale: bool = False,
    initial: int = 0,
    stream: TextIO | None = None,
) -> Any:
    """A progress display over ``total`` units: tqdm on a terminal, log lines elsewhere.

    Parameters
    ----------
    total : float
        Units of work.
    desc : str
        What is being done (starts every line).
    unit : str
        Name of a unit ("ray", "layer", "item").
    show : bool
        False gives a display that shows nothing (``update`` still works).
    unit_scale : bool
        Print large counts with k/M/G prefixes.
    initial : int
        Units already done (resumed work).
    stream : text file, optional
        Where to write (default: ``sys.stderr``).

    Returns
    -------
    object
        With ``update(n)``, ``close()`` and the context-manager protocol.
    """
    stream = sys.stderr if stream is None else stream
    if not (show and _state["enabled"]):
        return _Silent(total, initial)
    isatty = getattr(stream, "isatty", None)
    if isatty is not None and isatty():
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit, unit_scale=unit_scale, initial=initial, leave=False, file=stream)
    return _LogLines(total, desc, unit=unit, unit_scale=unit_scale, initial=initial, stream=stream)


class _Silent:
    """Counts like a tqdm bar (``n``, ``total``) and shows nothing."""

    def __init__(self, total: float | None = None, initial: float = 0) -> None:
        self.total, self.n = total, initial

    def update(self, n: float = 1) -> None:
        self.n += n

    def close(self) -> None:
        pass

    def __enter__(self) -> _Silent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _count(n: float, scale: bool) -> str:
    if not scale:
        return f"{n:,.0f}"
    for factor, prefix in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if abs(n) >= factor:
            return f"{n / factor:.1f}{prefix}"
    return f"{n:.0f}"


class _LogLines(_Silent):
    """One plain line at most every LOG_INTERVAL seconds: no carriage returns in logs."""

    def __init__(self, total: float, desc: str, *, unit: str, unit_scale: bool, initial: int, stream: TextIO) -> None:
        super().__init__(total, initial)
        self.desc, self.unit, self.scale = desc, unit, unit_scale
        self.stream = stream
        self.start = self.last = time.monotonic()
        self.printed = False

    def update(self, n: float = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.last >= LOG_INTERVAL:
            self.last = now
            self._line(now)

    def close(self) -> None:
        if self.printed:
            self._line(time.monotonic(), final=True)
        self.printed = False

    def _line(self, now: float, final: bool = False) -> None:
        elapsed = now - self.start
        text = f"{self.desc}: {_count(self.n, self.scale)}"
        if self.total:
            text += f" / {_count(self.total, self.scale)} {self.unit}s ({100 * self.n / self.total:.0f}%)"
        else:
            text += f" {self.unit}s"
        text += f", {elapsed:.0f} s elapsed"
        if final:
            text += ", done"
        elif self.total and self.n > 0:
            text += f", about {elapsed * (self.total - self.n) / self.n:.0f} s left"
        print(text, file=self.stream, flush=True)
        self.printed = True
