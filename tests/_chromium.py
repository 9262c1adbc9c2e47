"""Headless Chromium over the DevTools protocol on a pipe: a tiny client for tests and benches.

A helper of the tests (``tests/test_viewer.py``, ``test_image_viewer.py``, ``test_pages.py``) and of
``bench.view`` and ``bench.view_image`` (which import it as ``tests._chromium``, run from the
repository root); not part of the package. :func:`browser_or_skip`, :func:`open_page` and :func:`capture` are the steps every browser
test takes: start a browser (or skip without one), load a page until it is drawn, read its pixels.

No websocket, no extra package: Chromium is started with ``--remote-debugging-pipe`` and reads
NUL-terminated JSON commands on file descriptor 3 and writes replies and events on 4 (here the
child's stdin and stdout are duplicated onto 3 and 4 by ``sh``). One page (target) per
:class:`Chromium`; its console errors and uncaught exceptions are collected in :attr:`errors`.

Software WebGL: ``--use-angle=swiftshader --enable-unsafe-swiftshader`` (SwiftShader through
ANGLE), so the browser needs no GPU and no display.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["Chromium", "ChromiumError", "browser_or_skip", "capture", "find_chromium", "open_page"]

FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-extensions",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--mute-audio",
    "--hide-scrollbars",
    "--disable-dev-shm-usage",
)


def _gl_warning(text: str) -> bool:
    """WebGL reports misuse (an invalid draw, a bad texture) as console warnings: count them."""
    return "WebGL:" in text or "GL_INVALID" in text or "GL ERROR" in text


class ChromiumError(RuntimeError):
    """The browser failed, a protocol command failed, or a wait timed out."""


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable (``AO4D_CHROMIUM`` first), or None."""
    env = os.environ.get("AO4D_CHROMIUM")
    if env:
        return env if Path(env).exists() else None
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


class Chromium:
    """One headless Chromium with one page, driven over ``--remote-debugging-pipe``.

    Parameters
    ----------
    width, height : int
        CSS size of the page's viewport (device scale factor 1).
    executable : str, optional
        Browser to start (default :func:`find_chromium`).
    timeout : float
        Seconds any single command may take.
    """

    def __init__(self, *, width: int = 640, height: int = 480, executable: str | None = None, timeout: float = 60.0):
        exe = executable or find_chromium()
        if exe is None:
            raise ChromiumError("no Chromium found (install Debian's `chromium` or set AO4D_CHROMIUM)")
        self.timeout = timeout
        self.errors: list[str] = []
        self.console: list[tuple[str, str]] = []
        self._profile = tempfile.TemporaryDirectory(prefix="ao4d-chromium-")
        self._stderr = tempfile.TemporaryFile()
        args = [
            exe,
            *FLAGS,
            f"--user-data-dir={self._profile.name}",
            "--remote-debugging-pipe",
            f"--window-size={width},{height}",
            "about:blank",
        ]
        # fd 3 <- our commands (child's stdin), fd 4 -> replies (child's stdout)
        self._proc = subprocess.Popen(
            ["/bin/sh", "-c", 'exec "$0" "$@" 3<&0 4>&1 0</dev/null 1>&2', *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            start_new_session=True,
        )
        self._out = self._proc.stdin.fileno()
        self._in = self._proc.stdout.fileno()
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict] = []
        try:
            target = self.send("Target.createTarget", url="about:blank")["targetId"]
            self._session = self.send("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            self._target = target
            for domain in ("Runtime", "Page", "Log"):
                self.send(f"{domain}.enable", session=True)
            self.send(
                "Emulation.setDeviceMetricsOverride",
                session=True,
                width=width,
                height=height,
                deviceScaleFactor=1,
                mobile=False,
            )
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ protocol
    def _read_message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ChromiumError("timed out waiting for Chromium")
            ready, _, _ = select.select([self._in], [], [], left)
            if ready:
                chunk = os.read(self._in, 1 << 20)
                if not chunk:
                    raise ChromiumError(f"Chromium exited: {self._stderr_tail()}")
                self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(raw)

    def _stderr_tail(self) -> str:
        try:
            self._stderr.seek(0)
            return self._stderr.read().decode(errors="replace")[-2000:]
        except (OSError, ValueError):
            return ""

    def _handle_event(self, message: dict) -> None:
        method = message.get("method", "")
        params = message.get("params", {})
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
            self.console.append((params.get("type", ""), text))
            if params.get("type") in ("error", "assert") or _gl_warning(text):
                self.errors.append(f"console.{params.get('type')}: {text}")
        elif method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            desc = details.get("exception", {}).get("description") or details.get("text", "")
            self.errors.append(f"exception: {desc}")
        elif method == "Log.entryAdded":
            entry = params.get("entry", {})
            self.console.append((entry.get("level", ""), entry.get("text", "")))
            if entry.get("level") == "error" or _gl_warning(entry.get("text", "")):
                self.errors.append(f"log: {entry.get('text', '')} {entry.get('url', '')}".strip())

    def send(self, method: str, *, session: bool = False, timeout: float | None = None, **params: Any) -> dict:
        """Send one command and wait for its result (events met meanwhile are handled)."""
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = self._session
        data = json.dumps(message).encode() + b"\0"
        try:
            os.write(self._out, data)
        except BrokenPipeError:
            raise ChromiumError(f"Chromium exited: {self._stderr_tail()}") from None
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise ChromiumError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            if "method" in reply:
                self._handle_event(reply)

    # ------------------------------------------------------------------ page helpers
    def mouse(self, kind: str, x: float, y: float, buttons: int = 0, **extra: Any) -> dict:
        """One mouse event at (x, y) in CSS pixels: ``kind`` "mousePressed", "mouseMoved",
        "mouseReleased" (the left button; ``buttons=1`` while it is held) or "mouseWheel";
        ``extra`` goes to Input.dispatchMouseEvent (``modifiers=8``: shift; ``deltaY``)."""
        return self.send(
            "Input.dispatchMouseEvent",
            session=True,
            type=kind,
            x=x,
            y=y,
            button="left" if kind != "mouseWheel" else "none",
            buttons=buttons,
            clickCount=1 if kind != "mouseMoved" else 0,
            **extra,
        )

    def evaluate(self, expression: str, *, timeout: float | None = None) -> Any:
        """Evaluate JavaScript in the page (promises awaited) and return its JSON value."""
        result = self.send(
            "Runtime.evaluate",
            session=True,
            timeout=timeout,
            expression=expression,
            awaitPromise=True,
            returnByValue=True,
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            desc = details.get("exception", {}).get("description") or details.get("text")
            raise ChromiumError(f"JavaScript error: {desc}")
        return result.get("result", {}).get("value")

    def goto(self, url: str) -> None:
        """Navigate and wait for the load event."""
        self.send("Page.navigate", session=True, url=url)
        self.wait_for("document.readyState === 'complete'")

    def wait_for(self, expression: str, *, timeout: float | None = None, poll: float = 0.05) -> Any:
        """Poll a JavaScript expression until it is truthy; return its value."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            value = self.evaluate(expression, timeout=timeout)
            if value:
                return value
            if time.monotonic() > deadline:
                raise ChromiumError(f"timed out waiting for {expression!r}; errors: {self.errors}")
            time.sleep(poll)

    def screenshot(self) -> bytes:
        """PNG bytes of the viewport (page and its controls, as a user sees them)."""
        data = self.send("Page.captureScreenshot", session=True, format="png")["data"]
        return base64.b64decode(data)

    def close(self) -> None:
        """End the browser (this process only) and remove its profile."""
        proc = getattr(self, "_proc", None)
        if proc is not None and proc.poll() is None:
            try:
                self.send("Browser.close", timeout=5)
            except (ChromiumError, OSError):
                pass
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        if proc is not None:
            for stream in (proc.stdin, proc.stdout):
                try:
                    stream.close()
                except OSError:
                    pass
        self._stderr.close()
        self._profile.cleanup()

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------- what every browser test does


def browser_or_skip(width: int, height: int) -> Iterator[Chromium]:
    """A browser of this window size for a pytest fixture to yield from; skips without Chromium."""
    import pytest

    if find_chromium() is None:
        pytest.skip("Chromium is not installed (Debian: apt-get install chromium); the browser tests need it")
    with Chromium(width=width, height=height) as chromium:
        yield chromium


def open_page(browser: Chromium, url: str, fragment: str = "") -> dict:
    """Load an ao4d page afresh, wait until it is drawn, check it reports no error; its stats."""
    browser.errors.clear()
    browser.goto("about:blank")
    browser.goto(url + fragment)
    browser.wait_for("window.ao4d && (window.ao4d.ready || window.ao4d.error)", timeout=60)
    error = browser.evaluate("window.ao4d.error")
    assert error is None, error
    return browser.evaluate("window.ao4d.stats()")


def capture(browser: Chromium, api: str = "window.ao4d") -> Any:
    """The page's canvas as ``api.capture()`` reads it back: (height, width, 4) uint8, rows from the top."""
    import numpy as np

    cap = browser.evaluate(f"{api}.capture()")
    rgba = np.frombuffer(base64.b64decode(cap["rgba"]), np.uint8)
    return rgba.reshape(cap["height"], cap["width"], 4)
