"""Headless Chromium driven over the Chrome DevTools Protocol (a websocket, JSON messages).

Small on purpose: launch, navigate, evaluate JavaScript, wait for a condition. It records
uncaught page exceptions and console errors so a test can assert there were none.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import ClientConnection, connect

from tests.system_packages import chromium_executable, unavailable


class PageError(AssertionError):
    """JavaScript evaluated in the page threw."""


def find_chromium() -> str:
    """The chromium executable. The tests never install it themselves (``make test``
    does, once, first): when missing, the browser tests skip, or fail where required."""
    found = chromium_executable()
    if found is None:
        unavailable("BROWSER", "chromium is not installed")
    return found


class Chromium:
    """One headless browser with one page."""

    def __init__(self, executable: str, profile: Path, *, width: int = 1400, height: int = 1800):
        self.profile = profile
        # Chromium makes its singleton socket's folder (org.chromium.Chromium.*) in TMPDIR
        # and leaves it when stopped by a signal: a folder of its own, removed at close
        # (not the profile's: a socket's path is limited to 107 characters).
        self.temporary = Path(tempfile.mkdtemp(prefix="adchromium-"))
        self._log = (profile / "chromium.log").open("wb")
        self.process = subprocess.Popen(
            [
                executable,
                "--headless",
                "--no-sandbox",  # tests may run as root, where the sandbox refuses to start
                "--disable-gpu",
                "--enable-unsafe-swiftshader",  # WebGL (the 3D robot view) drawn on the CPU
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-background-timer-throttling",
                "--disable-renderer-backgrounding",
                "--remote-debugging-port=0",
                f"--user-data-dir={profile}",
                f"--window-size={width},{height}",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=self._log,
            env={**os.environ, "TMPDIR": str(self.temporary)},
        )
        self.errors: list[str] = []
        self.requested: list[str] = []
        """Every URL the page asked for (documents, scripts, fetches, images)."""
        self._next_id = 0
        self._exits = contextlib.ExitStack()
        try:
            self._socket = self._connect()
            self.send("Runtime.enable")
            self.send("Page.enable")
            self.send("Network.enable")
        except BaseException:
            self.close()  # a browser that never came up leaves no process or folder
            raise

    def _connect(self) -> ClientConnection:
        port_file = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not port_file.is_file() or not port_file.read_text().strip():
            if self.process.poll() is not None or time.monotonic() > deadline:
                log = (self.profile / "chromium.log").read_text(errors="replace")
                raise RuntimeError(f"chromium did not open its DevTools port:\n{log}")
            time.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        targets = httpx.get(f"http://127.0.0.1:{port}/json/list", timeout=10).json()
        page = next(target for target in targets if target["type"] == "page")
        return self._exits.enter_context(
            connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=30)
        )

    def send(self, method: str, timeout: float = 60.0, **params: Any) -> dict[str, Any]:
        self._next_id += 1
        message_id = self._next_id
        self._socket.send(json.dumps({"id": message_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            message = json.loads(self._socket.recv(timeout=max(deadline - time.monotonic(), 0.01)))
            if message.get("id") == message_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return dict(message.get("result", {}))
            self._record(message)

    def _record(self, event: dict[str, Any]) -> None:
        method = event.get("method")
        params = event.get("params", {})
        if method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            text = details.get("exception", {}).get("description") or details.get("text")
            self.errors.append(f"uncaught: {text}")
        elif method == "Network.requestWillBeSent":
            self.requested.append(params.get("request", {}).get("url", ""))
        elif method == "Runtime.consoleAPICalled" and params.get("type") == "error":
            args = [arg.get("value", arg.get("description")) for arg in params.get("args", [])]
            self.errors.append(f"console.error: {args}")

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression (promises awaited), returned by value."""
        result = self.send(
            "Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise PageError(f"{expression!r} threw: {text}")
        return result["result"].get("value")

    def navigate(self, url: str) -> None:
        self.send("Page.navigate", url=url)

    def wait_for(self, expression: str, timeout: float = 30.0, interval: float = 0.02) -> Any:
        """Poll ``expression`` until its value, as Python sees it, is truthy (so a DOM
        node, which comes back as ``{}``, needs ``!!``); returns the value. Fails naming
        the expression, its last value and any page errors."""
        deadline = time.monotonic() + timeout
        value: Any = None
        while time.monotonic() < deadline:
            try:
                value = self.evaluate(expression)
            except PageError as error:
                value = str(error)
            else:
                if value:
                    return value
            time.sleep(interval)
        raise AssertionError(
            f"timed out after {timeout}s waiting for {expression!r}; last value {value!r}; "
            f"page errors: {self.errors}"
        )

    def screenshot(self, path: Path) -> None:
        import base64

        data = self.send("Page.captureScreenshot", format="png")["data"]
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        try:
            self._exits.close()
        finally:
            if self.process.poll() is None:
                self.process.terminate()
                try:
                    self.process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()
            self._log.close()
            shutil.rmtree(self.temporary, ignore_errors=True)
