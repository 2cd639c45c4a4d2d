"""Drive a headless Chromium through the DevTools protocol over a pipe (stdlib only).

``chromium --remote-debugging-pipe`` reads protocol commands from file
descriptor 3 and writes replies and events to descriptor 4, each message a
JSON text terminated by a NUL byte. That is all this module needs: no
websocket, no Playwright/Selenium. :func:`load_page` opens a file URL, waits
for the load event, and returns what a test wants to know: console messages,
uncaught exceptions, network requests, evaluated expressions and a full-page
PNG screenshot.
"""

from __future__ import annotations

import base64
import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any

__all__ = ["FLAGS", "PageResult", "find_chromium", "load_page"]

#: Where the Debian package puts the browser (scripts/install-browser.sh installs it).
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser")

#: Flags for a quiet, offline, sandbox-free headless run in a container.
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--disable-default-apps",
    "--mute-audio",
    "--hide-scrollbars",
    "--remote-debugging-pipe",
)


def find_chromium() -> str | None:
    """Path of a Chromium binary, or ``None``."""
    env = os.environ.get("MAGLEVID_CHROMIUM")
    if env:
        return env if os.access(env, os.X_OK) else None
    for c in CHROMIUM_CANDIDATES:
        if os.access(c, os.X_OK):
            return c
    return shutil.which("chromium")


@dataclass
class PageResult:
    """What the browser saw."""

    console: list[dict[str, Any]] = field(default_factory=list)
    exceptions: list[dict[str, Any]] = field(default_factory=list)
    log_entries: list[dict[str, Any]] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)
    failed_requests: list[dict[str, Any]] = field(default_factory=list)
    values: dict[str, Any] = field(default_factory=dict)
    screenshot: bytes = b""

    @property
    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions, error log entries, failed loads."""
        out = [
            f"console.{c.get('type')}: {_args_text(c)}"
            for c in self.console
            if c.get("type") in ("error", "assert")
        ]
        out += [
            "uncaught: " + (e.get("exception", {}).get("description") or e.get("text", ""))
            for e in self.exceptions
        ]
        out += [
            f"log {e.get('source')}: {e.get('text')}"
            for e in self.log_entries
            if e.get("level") == "error"
        ]
        out += [f"failed request: {f}" for f in self.failed_requests]
        return out


def _args_text(entry: dict[str, Any]) -> str:
    return " ".join(str(a.get("value", a.get("description", ""))) for a in entry.get("args", []))


class _Pipe:
    def __init__(self, to_browser: int, from_browser: int):
        self.w = to_browser
        self.r = from_browser
        self.buf = b""
        self.next_id = 0
        self.events: list[dict[str, Any]] = []

    def _read_message(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self.buf:
            if time.monotonic() > deadline:
                raise TimeoutError("no reply from Chromium in time")
            chunk = os.read(self.r, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed the DevTools pipe")
            self.buf += chunk
        msg, _, self.buf = self.buf.partition(b"\0")
        return json.loads(msg)

    def send(
        self,
        method: str,
        params: dict | None = None,
        *,
        session: str | None = None,
        timeout: float = 30.0,
    ) -> dict[str, Any]:
        self.next_id += 1
        mid = self.next_id
        msg: dict[str, Any] = {"id": mid, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == mid:
                if "error" in reply:
                    raise RuntimeError(f"{method} failed: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_event(self, method: str, *, timeout: float = 30.0) -> dict[str, Any]:
        for i, ev in enumerate(self.events):
            if ev.get("method") == method:
                return self.events.pop(i)
        deadline = time.monotonic() + timeout
        while True:
            ev = self._read_message(deadline)
            if ev.get("method") == method:
                return ev
            self.events.append(ev)


def load_page(
    url: str,
    *,
    expressions: dict[str, str] | None = None,
    width: int = 1280,
    height: int = 900,
    full_page: bool = True,
    chromium: str | None = None,
    timeout: float = 60.0,
) -> PageResult:
    """Open ``url`` in headless Chromium and report what happened.

    Parameters
    ----------
    url : str
        Usually ``Path(...).as_uri()``.
    expressions : mapping of name -> JavaScript expression
        Evaluated after the load event (values returned by value).
    width, height : int
        Viewport in CSS pixels (device scale factor 1).
    full_page : bool
        Screenshot the whole page, not only the viewport.
    """
    exe = chromium or find_chromium()
    if exe is None:
        raise FileNotFoundError("Chromium not found (run scripts/install-browser.sh)")
    profile = tempfile.mkdtemp(prefix="maglevid-chromium-")
    # fds 3 (commands in) and 4 (replies out) in the child, via posix_spawn file actions.
    cmd_r, cmd_w = os.pipe()
    res_r, res_w = os.pipe()
    log = tempfile.TemporaryFile()
    argv = [
        exe,
        *FLAGS,
        f"--user-data-dir={profile}",
        f"--window-size={width},{height}",
        "about:blank",
    ]
    actions = [
        (os.POSIX_SPAWN_DUP2, cmd_r, 100),
        (os.POSIX_SPAWN_DUP2, res_w, 101),
        (os.POSIX_SPAWN_DUP2, 100, 3),
        (os.POSIX_SPAWN_DUP2, 101, 4),
        (os.POSIX_SPAWN_CLOSE, 100),
        (os.POSIX_SPAWN_CLOSE, 101),
        (os.POSIX_SPAWN_DUP2, log.fileno(), 1),
        (os.POSIX_SPAWN_DUP2, log.fileno(), 2),
    ]
    env = {k: v for k, v in os.environ.items() if k not in ("DBUS_SESSION_BUS_ADDRESS",)}
    pid = os.posix_spawn(exe, argv, env, file_actions=actions)
    os.close(cmd_r)
    os.close(res_w)
    result = PageResult()
    pipe = _Pipe(cmd_w, res_r)
    try:
        target = pipe.send("Target.createTarget", {"url": "about:blank"}, timeout=timeout)
        att = pipe.send("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})
        sid = att["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            pipe.send(f"{domain}.enable", session=sid)
        pipe.send(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            session=sid,
        )
        pipe.send("Page.navigate", {"url": url}, session=sid)
        pipe.wait_event("Page.loadEventFired", timeout=timeout)
        # Let late console messages and image decoding settle.
        pipe.send("Runtime.evaluate", {"expression": "1", "awaitPromise": True}, session=sid)
        for name, expr in (expressions or {}).items():
            r = pipe.send(
                "Runtime.evaluate",
                {"expression": expr, "returnByValue": True, "awaitPromise": True},
                session=sid,
            )
            if "exceptionDetails" in r:
                result.exceptions.append(r["exceptionDetails"])
            result.values[name] = r.get("result", {}).get("value")
        params: dict[str, Any] = {"format": "png"}
        if full_page:
            metrics = pipe.send("Page.getLayoutMetrics", session=sid)
            size = metrics.get("cssContentSize") or metrics["contentSize"]
            params["clip"] = {
                "x": 0,
                "y": 0,
                "width": width,
                "height": math.ceil(size["height"]),
                "scale": 1,
            }
            params["captureBeyondViewport"] = True
        shot = pipe.send("Page.captureScreenshot", params, session=sid, timeout=timeout)
        result.screenshot = base64.b64decode(shot["data"])
        for ev in pipe.events:
            m, p = ev.get("method"), ev.get("params", {})
            if m == "Runtime.consoleAPICalled":
                result.console.append(p)
            elif m == "Runtime.exceptionThrown":
                result.exceptions.append(p.get("exceptionDetails", {}))
            elif m == "Log.entryAdded":
                result.log_entries.append(p.get("entry", {}))
            elif m == "Network.requestWillBeSent":
                result.requests.append(p.get("request", {}).get("url", ""))
            elif m == "Network.loadingFailed":
                result.failed_requests.append(p)
        try:
            pipe.send("Browser.close", timeout=10)
        except (RuntimeError, TimeoutError):
            pass
    finally:
        os.close(cmd_w)
        os.close(res_r)
        _reap(pid)
        log.close()
        shutil.rmtree(profile, ignore_errors=True)
    return result


def _reap(pid: int, grace: float = 10.0) -> None:
    """Wait for the browser we started; kill it (by its pid) if it does not exit."""
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done:
            return
        time.sleep(0.05)
    try:
        os.kill(pid, 9)
    except ProcessLookupError:
        return
    os.waitpid(pid, 0)
