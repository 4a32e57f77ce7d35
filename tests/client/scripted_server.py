"""A real HTTP server on loopback that answers from a script, to test the SDK's transport.

Each request takes the next step of the script (the last step repeats): an answer
``Reply(status, body, headers)`` or ``HangUp()``, which reads the request and closes
the connection without a word. Every request is recorded with its arrival time.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any


@dataclass
class Reply:
    status: int = 200
    body: Any = None
    headers: dict[str, str] = field(default_factory=dict)
    raw: bytes | None = None
    """Exact bytes to send instead of ``body`` as JSON."""


@dataclass
class HangUp:
    """Read the request, then close the connection without answering."""


@dataclass
class Seen:
    method: str
    path: str
    headers: dict[str, str]
    body: bytes
    at: float


class ScriptedServer:
    def __init__(self) -> None:
        self.script: list[Reply | HangUp] = [Reply(200, {})]
        self.seen: list[Seen] = []
        self._lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: object) -> None:
                pass

            def _handle(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                body = self.rfile.read(length) if length else b""
                with server._lock:
                    server.seen.append(
                        Seen(self.command, self.path, dict(self.headers), body, time.monotonic())
                    )
                    step = server.script[0] if len(server.script) == 1 else server.script.pop(0)
                if isinstance(step, HangUp):
                    self.close_connection = True
                    return
                payload = step.raw
                if payload is None and step.body is not None:
                    payload = json.dumps(step.body).encode()
                payload = payload or b""
                self.send_response(step.status)
                headers = {"Content-Type": "application/json", **step.headers}
                for key, value in headers.items():
                    self.send_header(key, value)
                self.send_header("Content-Length", str(len(payload)))
                self.end_headers()
                self.wfile.write(payload)

            do_GET = do_POST = do_PUT = do_DELETE = _handle

        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self._httpd.server_address[1]}"
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True
        )

    def start(self) -> ScriptedServer:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join()

    def play(self, *steps: Reply | HangUp) -> None:
        with self._lock:
            self.script = list(steps)
            self.seen.clear()


def refused_url() -> str:
    """A loopback URL where nothing listens: a port bound and released at once."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"http://127.0.0.1:{port}"
