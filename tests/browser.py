"""A report as a reader's browser shows it: headless Chromium driven over the DevTools protocol on a pipe.

:func:`open_report` loads an HTML file in a fresh Chromium (no network, a
throw-away profile), and returns what a reader would meet: console errors and
uncaught exceptions, images that did not decode, elements wider than the
window (horizontal overflow) and a full-page screenshot. The protocol runs
over ``--remote-debugging-pipe`` (file descriptors 3 and 4, messages ended by
a NUL byte), so nothing but Chromium is needed: no websocket library, no
WebDriver. :func:`chromium` finds the browser (``$CHROMIUM``, then the
usual names on PATH).
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

#: Flags of a quiet, isolated headless Chromium (no network services, no sandbox for containers).
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
         "--remote-debugging-pipe")

#: What the page reports about itself once loaded: images that did not decode, and what is wider than the window.
_CHECK = """(() => {
  const width = document.documentElement.clientWidth;
  const broken = [...document.images].filter(i => !i.complete || i.naturalWidth === 0)
                                     .map(i => i.alt || i.src.slice(0, 60));
  const wide = [...document.querySelectorAll('body *')].filter(e => e.getBoundingClientRect().right > width + 1)
                 .map(e => e.tagName.toLowerCase() + (e.className ? '.' + e.className : '') + ' '
                      + (e.textContent || e.alt || '').trim().slice(0, 40));
  return JSON.stringify({broken, wide, scroll_width: document.documentElement.scrollWidth, width,
                         height: document.documentElement.scrollHeight, images: document.images.length});
})()"""


def chromium() -> str | None:
    """The Chromium executable: ``$CHROMIUM``, else ``chromium``, ``chromium-browser`` or ``google-chrome`` on PATH."""
    for name in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


@dataclass
class PageReport:
    """What a reader's browser met on a page."""

    console_errors: list[str] = field(default_factory=list)
    broken_images: list[str] = field(default_factory=list)
    overflowing: list[str] = field(default_factory=list)
    scroll_width: int = 0
    width: int = 0
    height: int = 0
    images: int = 0
    screenshot: Path | None = None

    @property
    def problems(self) -> list[str]:
        """Every problem, one line each (empty when the page reads right)."""
        out = [f"console: {m}" for m in self.console_errors]
        out += [f"broken image: {m}" for m in self.broken_images]
        if self.scroll_width > self.width:
            out.append(f"horizontal overflow: {self.scroll_width} px wide in a {self.width} px window: "
                       + "; ".join(self.overflowing[:5]))
        return out


class _Pipe:
    """The DevTools protocol over Chromium's pipe: ``call`` a method, gather the events it sends meanwhile."""

    def __init__(self, proc, to_browser, from_browser):
        self.proc, self.out, self.inp = proc, to_browser, from_browser
        self.buffer, self.next_id, self.events = b"", 0, []

    def _message(self, deadline: float) -> dict:
        while b"\0" not in self.buffer:
            if time.monotonic() > deadline:
                raise TimeoutError("Chromium did not answer in time")
            chunk = os.read(self.inp, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed its DevTools pipe")
            self.buffer += chunk
        raw, self.buffer = self.buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, session: str | None = None, timeout: float = 60.0, **params) -> dict:
        self.next_id += 1
        message = {"id": self.next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self.out, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._message(deadline)
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_for(self, event: str, timeout: float = 60.0) -> dict:
        deadline = time.monotonic() + timeout
        for k, e in enumerate(self.events):
            if e.get("method") == event:
                return self.events.pop(k)
        while True:
            e = self._message(deadline)
            if e.get("method") == event:
                return e
            self.events.append(e)


def _console_errors(events: list[dict]) -> list[str]:
    out = []
    for e in events:
        method, params = e.get("method"), e.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            out.append(" ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", [])))
        elif method == "Runtime.exceptionThrown":
            out.append(params.get("exceptionDetails", {}).get("text", "exception"))
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            out.append(params["entry"].get("text", ""))
    return out


def _onto_3_and_4(read_end: int, write_end: int) -> None:
    """In the child: its fd 3 reads ``read_end``, its fd 4 writes ``write_end`` (moved above 9 first: no clash)."""
    high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (read_end, write_end)]
    os.dup2(high[0], 3)
    os.dup2(high[1], 4)


def open_report(html: str | os.PathLike, screenshot: str | os.PathLike | None = None, width: int = 1400,
                height: int = 900, timeout: float = 120.0) -> PageReport:
    """Load ``html`` in headless Chromium at ``width`` px and report what a reader meets.

    Parameters
    ----------
    html : path
        The page (a local file).
    screenshot : path, optional
        Where to write a full-page PNG screenshot.
    width, height : int
        The window, CSS pixels.
    timeout : float
        Seconds for the load and each protocol call.

    Raises
    ------
    RuntimeError
        No Chromium (see :func:`chromium`), or it failed.
    """
    browser = chromium()
    if browser is None:
        raise RuntimeError("no Chromium found (set CHROMIUM or install chromium)")
    to_browser_r, to_browser_w = os.pipe()
    from_browser_r, from_browser_w = os.pipe()
    with tempfile.TemporaryDirectory() as profile:
        # Chromium reads commands on its fd 3 and writes replies on its fd 4
        proc = subprocess.Popen([browser, *FLAGS, f"--user-data-dir={profile}", "about:blank"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                pass_fds=(3, 4), preexec_fn=lambda: _onto_3_and_4(to_browser_r, from_browser_w))
        os.close(to_browser_r)
        os.close(from_browser_w)
        pipe = _Pipe(proc, to_browser_w, from_browser_r)
        try:
            target = pipe.call("Target.createTarget", url="about:blank", timeout=timeout)["targetId"]
            session = pipe.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            for domain in ("Page", "Runtime", "Log"):
                pipe.call(f"{domain}.enable", session)
            pipe.call("Emulation.setDeviceMetricsOverride", session, width=width, height=height,
                      deviceScaleFactor=1, mobile=False)
            pipe.call("Page.navigate", session, url=Path(html).resolve().as_uri())
            pipe.wait_for("Page.loadEventFired", timeout)
            found = json.loads(pipe.call("Runtime.evaluate", session, expression=_CHECK,
                                         returnByValue=True)["result"]["value"])
            report = PageReport(console_errors=_console_errors(pipe.events), broken_images=found["broken"],
                                overflowing=found["wide"], scroll_width=found["scroll_width"],
                                width=found["width"], height=found["height"], images=found["images"])
            if screenshot is not None:
                shot = pipe.call("Page.captureScreenshot", session, format="png", captureBeyondViewport=True,
                                 clip={"x": 0, "y": 0, "width": width, "height": found["height"], "scale": 1},
                                 timeout=timeout)
                Path(screenshot).write_bytes(base64.b64decode(shot["data"]))
                report.screenshot = Path(screenshot)
            return report
        finally:
            try:
                pipe.call("Browser.close", timeout=10)
            except (RuntimeError, TimeoutError, OSError):
                pass
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            os.close(to_browser_w)
            os.close(from_browser_r)
