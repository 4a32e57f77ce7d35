"""A web site of the tests' own: pages served on a loopback port of their own (another
origin than the server under test), counting the requests for each path."""

from __future__ import annotations

import threading
from collections import Counter
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any


class LoopbackSite:
    """Serves ``pages`` (path to HTML), the page at "/" for any other path; with
    ``cache_seconds``, answers may be cached that long."""

    def __init__(self, pages: dict[str, str], *, cache_seconds: int | None = None) -> None:
        self.hits: Counter[str] = Counter()
        site = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                site.hits[self.path] += 1
                body = pages.get(self.path, pages["/"]).encode()
                self.send_response(200)
                self.send_header("Content-Type", "text/html; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                if cache_seconds is not None:
                    self.send_header("Cache-Control", f"max-age={cache_seconds}")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
