"""Headless Chromium driven over the Chrome DevTools Protocol (a websocket, JSON messages).

Small on purpose: launch, navigate, evaluate JavaScript, wait for a condition. It records
uncaught page exceptions and console errors so a test can assert there were none.

A ``ChromiumProcess`` is one browser; ``Chromium`` is one page. A page either has a
browser of its own (``Chromium(executable, profile)``: a profile on disk, stopped at
close) or a browser context of its own in a shared browser (``Chromium.in_context``:
cookies, storage and cache of its own, like a new profile's, disposed at close).
``SharedChromium`` hands out such pages from one browser, and one page that tests take in
turn, and starts a new browser when the one it has died or stopped answering.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from tests.system_packages import chromium_executable, unavailable

BROKEN = (ConnectionClosed, OSError, TimeoutError, RuntimeError)
"""What talking to a browser that died or hangs raises."""


POLL = """(async () => {
  const deadline = performance.now() + %(ms)f;
  const pythonTruthy = (value) => Array.isArray(value) ? value.length > 0
    : value !== null && typeof value === 'object' ? Object.keys(value).length > 0
    : !!value;
  for (;;) {
    let polled;
    try {
      polled = {value: await (
%(expression)s
)};
    } catch (error) {
      polled = {error: String(error)};
    }
    if (('value' in polled && pythonTruthy(polled.value)) || performance.now() >= deadline) {
      return polled;
    }
    await new Promise((resolve) => setTimeout(resolve, %(interval)f));
  }
})()"""
"""Evaluates an expression in the page until its value is truthy as Python sees values
(null, false, 0, "", [] and {} are not) or the deadline passes."""


def _origin(url: str) -> str | None:
    """An http(s) URL's origin (scheme, host and port), None for any other URL."""
    parts = urlsplit(url)
    return f"{parts.scheme}://{parts.netloc}" if parts.scheme in ("http", "https") else None


def leave(page: Chromium) -> None:
    """Blank the shared page before its test's server stops (a page polling a stopped
    server would log errors); a browser that does not answer is marked broken, to be
    replaced at the next take, instead of failing a test that is over."""
    try:
        page.blank()
    except (*BROKEN, AssertionError):
        page.owner.broken = True


class PageError(AssertionError):
    """JavaScript evaluated in the page threw."""


def find_chromium() -> str:
    """The chromium executable. The tests never install it themselves (``make test``
    does, once, first): when missing, the browser tests skip, or fail where required."""
    found = chromium_executable()
    if found is None:
        unavailable("BROWSER", "chromium is not installed")
    return found


class DevTools:
    """One DevTools websocket: commands answered by id; other messages (events) go to
    ``on_event``."""

    def __init__(
        self, url: str, on_event: Callable[[dict[str, Any]], None] = lambda event: None
    ) -> None:
        self._exits = contextlib.ExitStack()
        self._socket: ClientConnection = self._exits.enter_context(
            connect(url, max_size=None, open_timeout=30, close_timeout=2)
        )
        self._on_event = on_event
        self._next_id = 0

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
            self._on_event(message)

    def close(self) -> None:
        self._exits.close()


class ChromiumProcess:
    """One headless Chromium with its profile in ``profile``, reached over its browser
    DevTools socket."""

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
        self.broken = False
        """Set when a page found the browser not answering: ``SharedChromium`` replaces it."""
        try:
            self.port, browser_path = self._devtools_port()
            self.devtools = DevTools(f"ws://127.0.0.1:{self.port}{browser_path}")
        except BaseException:
            self.close()  # a browser that never came up leaves no process or folder
            raise

    def _devtools_port(self) -> tuple[int, str]:
        port_file = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while len(lines := self._read(port_file)) < 2:
            if self.process.poll() is not None or time.monotonic() > deadline:
                log = (self.profile / "chromium.log").read_text(errors="replace")
                raise RuntimeError(f"chromium did not open its DevTools port:\n{log}")
            time.sleep(0.05)
        return int(lines[0]), lines[1]

    @staticmethod
    def _read(port_file: Path) -> list[str]:
        return port_file.read_text().split() if port_file.is_file() else []

    def page_url(self, target_id: str) -> str:
        return f"ws://127.0.0.1:{self.port}/devtools/page/{target_id}"

    def first_page(self) -> str:
        """The target id of the page the browser opened at start."""
        targets = httpx.get(f"http://127.0.0.1:{self.port}/json/list", timeout=10).json()
        return str(next(target for target in targets if target["type"] == "page")["id"])

    def responsive(self, timeout: float = 10.0) -> bool:
        """Whether the browser runs and answers a command within ``timeout`` seconds."""
        if self.broken or self.process.poll() is not None:
            return False
        try:
            self.devtools.send("Browser.getVersion", timeout=timeout)
        except BROKEN:
            self.broken = True
            return False
        return True

    def close(self) -> None:
        try:
            if hasattr(self, "devtools"):
                self.devtools.close()
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


class Chromium:
    """One page: of a headless browser of its own, or (``in_context``) of a fresh browser
    context in a shared one."""

    def __init__(self, executable: str, profile: Path, *, width: int = 1400, height: int = 1800):
        self._attach(ChromiumProcess(executable, profile, width=width, height=height), None)

    @classmethod
    def in_context(cls, owner: ChromiumProcess) -> Chromium:
        """A page in a new browser context of ``owner`` (disposed at close)."""
        context = owner.devtools.send("Target.createBrowserContext", disposeOnDetach=False)
        page = cls.__new__(cls)
        page._attach(owner, str(context["browserContextId"]))
        return page

    def _attach(self, owner: ChromiumProcess, context: str | None) -> None:
        """Open the page: the browser's first one (a browser of its own, ``context``
        None) or a new one in ``context``."""
        self.owner = owner
        self.context = context
        self.errors: list[str] = []
        self.requested: list[str] = []
        """Every URL the page asked for (documents, scripts, fetches, images)."""
        try:
            target = (
                owner.first_page()
                if context is None
                else owner.devtools.send(
                    "Target.createTarget", url="about:blank", browserContextId=context
                )["targetId"]
            )
            self._devtools = DevTools(owner.page_url(target), self._record)
            self.send("Runtime.enable")
            self.send("Page.enable")
            self.send("Network.enable")
        except BaseException:
            self.close()
            raise

    @property
    def process(self) -> subprocess.Popen[bytes]:
        return self.owner.process

    @property
    def temporary(self) -> Path:
        return self.owner.temporary

    def send(self, method: str, timeout: float = 60.0, **params: Any) -> dict[str, Any]:
        return self._devtools.send(method, timeout, **params)

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
        the expression, its last value and any page errors.

        The page polls (every ``interval`` seconds, for up to a second per call): one
        DevTools round trip a second, not one a poll. A navigation that replaces the
        page's document while it polls ends that call; the next one polls the new one."""
        deadline = time.monotonic() + timeout
        value: Any = None
        while True:
            called = time.monotonic()
            seconds = min(deadline - called, 1.0)
            try:
                value = self._poll(expression, seconds, interval)
            except PageError as error:
                value = str(error)
            except RuntimeError as error:  # the document polled was replaced
                value = str(error)
            else:
                if value:
                    return value
            if time.monotonic() >= deadline:
                break
            if time.monotonic() - called < seconds:  # back early: not a busy loop
                time.sleep(interval)
        raise AssertionError(
            f"timed out after {timeout}s waiting for {expression!r}; last value {value!r}; "
            f"page errors: {self.errors}"
        )

    def _poll(self, expression: str, seconds: float, interval: float) -> Any:
        """The first value of ``expression`` within ``seconds`` that would be truthy in
        Python (the caller checks), or its last value; raises if its last try threw."""
        script = POLL % {
            "expression": expression,
            "ms": max(seconds, 0) * 1000,
            "interval": interval * 1000,
        }
        polled = self.evaluate(script)
        if "error" in polled:
            raise PageError(f"{expression!r} threw: {polled['error']}")
        return polled.get("value")

    def blank(self) -> None:
        """Leave the document for about:blank, clear the cookies, cache and storage (local,
        session and the rest) of the page's browser context for every origin the page
        asked anything of, and forget the errors and requests recorded: the next test on
        a page tests share starts from an empty page with nothing kept, as on a new one
        (and a page polling a server stopped after its test would log errors)."""
        self.navigate("about:blank")
        self.wait_for("location.href === 'about:blank'")
        origins = {origin for url in self.requested if (origin := _origin(url))}
        self.send("Network.clearBrowserCookies")
        self.send("Network.clearBrowserCache")
        for origin in sorted(origins):
            self.send("Storage.clearDataForOrigin", origin=origin, storageTypes="all")
        self.errors.clear()
        self.requested.clear()

    def screenshot(self, path: Path) -> None:
        data = self.send("Page.captureScreenshot", format="png")["data"]
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        """Stop the browser of its own, or dispose of its context (its page, cookies,
        storage and cache); a shared browser that does not answer is marked broken."""
        try:
            with contextlib.suppress(AttributeError):
                self._devtools.close()
        finally:
            if self.context is None:
                self.owner.close()
            elif self.context is not None and not self.owner.broken:
                try:
                    self.owner.devtools.send(
                        "Target.disposeBrowserContext", timeout=10, browserContextId=self.context
                    )
                except BROKEN:
                    self.owner.broken = True


class SharedChromium:
    """One browser for many tests, each page in a browser context of its own; a browser
    that died or stopped answering is stopped and a new one started (profiles in
    ``folder``)."""

    def __init__(self, executable: str, folder: Path, *, answer_within: float = 10.0) -> None:
        self.executable = executable
        self.folder = folder
        self.answer_within = answer_within
        """Seconds a browser has to answer before it counts as hung."""
        self.current: ChromiumProcess | None = None
        self.started = 0
        self._shared: Chromium | None = None

    def shared_page(self) -> Chromium:
        """One page that tests take in turn, blank and with nothing recorded (its browser
        context, so its cookies and storage, live as long as the browser): made on first
        use and again once its browser was replaced."""
        if self.current is None or not self.current.responsive(self.answer_within):
            self._replace()
        if self._shared is None or self._shared.owner is not self.current:
            self._shared = self.page()
        self._shared.blank()
        return self._shared

    def page(self) -> Chromium:
        if self.current is None or not self.current.responsive(self.answer_within):
            self._replace()
        assert self.current is not None
        try:
            return Chromium.in_context(self.current)
        except BROKEN:
            self._replace()  # it broke after answering: once more, on a new one
            assert self.current is not None
            return Chromium.in_context(self.current)

    def _replace(self) -> None:
        self.close()
        self.started += 1
        profile = self.folder / f"profile-{self.started}"
        profile.mkdir()
        self.current = ChromiumProcess(self.executable, profile)

    def close(self) -> None:
        self._shared = None
        if self.current is not None:
            current, self.current = self.current, None
            if current.process.poll() is None and not current.responsive(timeout=5):
                current.process.kill()  # wedged: terminate may not reach it
            current.close()
