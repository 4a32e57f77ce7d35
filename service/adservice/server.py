"""uvicorn's httptools protocol with the limits it lacks, the uvicorn config built from
``Settings``, and a server whose shutdown has a bound.

httptools (uvicorn's fastest parser) has no cap on header size: it joins a header's
pieces with ``bytes +=``, so one connection sending a 100 MB header kept the event loop
busy for 12 to 30 s. Nor does uvicorn time out a request whose headers never finish. h11
has a cap but costs about 19% more server CPU per ask/tell (bench/RESULTS.md,
request limits), so we keep httptools and count the bytes ourselves.
"""

from __future__ import annotations

import asyncio
import logging
import os
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

import uvicorn
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from adservice.settings import Settings


def _plain_response(status: bytes, text: bytes) -> bytes:
    return (
        b"HTTP/1.1 " + status + b"\r\ncontent-type: text/plain; charset=utf-8\r\n"
        b"content-length: " + str(len(text)).encode() + b"\r\nconnection: close\r\n\r\n" + text
    )


TOO_LARGE = _plain_response(b"431 Request Header Fields Too Large", b"Request headers too large")
TIMED_OUT = _plain_response(b"408 Request Timeout", b"Request headers not received in time")


class _OneWritePerResponse:
    """The transport as one response cycle sees it: the status line and headers are held
    until the body follows (or the loop turns), then both go out in one write.

    uvicorn writes them apart, and on loopback each write wakes the client, which then
    reads the head and the body in two system calls. One write per answer: half the
    server's context switches and 2 to 3% less client CPU per ask/tell cycle
    (bench/RESULTS.md: throughput).

    A head written while the request's body is still arriving says ``connection: close``
    (``closes_after`` is asked then): the server closes such a connection after the
    answer, and a client that read the whole answer at once must not send its next
    request down it.
    """

    __slots__ = ("_awaiting_head", "_closes_after", "_held", "_loop", "_transport")

    def __init__(
        self,
        transport: asyncio.Transport,
        loop: asyncio.AbstractEventLoop,
        closes_after: Callable[[], bool],
    ) -> None:
        self._transport = transport
        self._loop = loop
        self._closes_after = closes_after
        self._awaiting_head = True
        self._held: bytes | None = None

    def write(self, data: bytes) -> None:
        if self._awaiting_head:
            if data.startswith(b"HTTP/1.1 100 "):  # an interim answer: the head comes later
                self._transport.write(data)
                return
            self._awaiting_head = False
            if self._closes_after() and b"\r\nconnection: close\r\n" not in data.lower():
                data = data[:-2] + b"connection: close\r\n\r\n"
            self._held = data
            self._loop.call_soon(self._flush)
            return
        if self._held is not None:
            data, self._held = self._held + data, None
        self._transport.write(data)

    def _flush(self) -> None:
        if self._held is not None:
            held, self._held = self._held, None
            if not self._transport.is_closing():
                self._transport.write(held)

    def close(self) -> None:
        self._flush()
        self._transport.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._transport, name)


class LimitedHttpToolsProtocol(HttpToolsProtocol):
    """Refuses a request whose line and headers exceed ``max_header_bytes`` (431) or do not
    arrive within ``header_timeout`` seconds of its first byte (408; a connection that
    sends nothing is closed), and closes a connection whose response went out before its
    body was read (uvicorn would keep it open as long as the body trickles in)."""

    max_header_bytes = 65_536
    header_timeout = 10.0

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._awaiting_headers = True
        self._header_bytes = 0
        self._skip_chunk = False
        """The chunk that ended the previous request also holds some of its bytes: not counted."""
        self._got_bytes = False
        self._header_timer: asyncio.TimerHandle | None = self.loop.call_later(
            self.header_timeout, self._headers_timed_out
        )

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_header_timer()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._awaiting_headers:
            self._got_bytes = True
            if self._header_timer is None:
                self._header_timer = self.loop.call_later(
                    self.header_timeout, self._headers_timed_out
                )
        super().data_received(data)
        if not self._awaiting_headers or self.transport.is_closing():
            return
        if self._skip_chunk:
            self._skip_chunk = False
            return
        self._header_bytes += len(data)
        if self._header_bytes > self.max_header_bytes:
            self._refuse(TOO_LARGE)

    def on_headers_complete(self) -> None:
        self._awaiting_headers = False
        self._cancel_header_timer()
        super().on_headers_complete()
        cycle = self.cycle
        if cycle is not None and cycle.scope is self.scope:

            def closes_after() -> bool:
                """Whether this answer ends the connection: its request's body is still
                arriving (``on_response_complete`` closes it then)."""
                if cycle.more_body:
                    cycle.keep_alive = False
                return not cycle.keep_alive

            cycle.transport = _OneWritePerResponse(self.transport, self.loop, closes_after)  # type: ignore[assignment]

    def on_message_complete(self) -> None:
        super().on_message_complete()
        self._awaiting_headers = True
        self._header_bytes = 0
        self._skip_chunk = True
        self._got_bytes = False

    def on_response_complete(self) -> None:
        unread_body = not self.pipeline and self.cycle is not None and self.cycle.more_body
        super().on_response_complete()
        if unread_body:
            self.transport.close()

    def _cancel_header_timer(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _headers_timed_out(self) -> None:
        self._header_timer = None
        if self._got_bytes:
            self._refuse(TIMED_OUT)
        elif not self.transport.is_closing():
            self.transport.close()

    def _refuse(self, response: bytes) -> None:
        self._cancel_header_timer()
        if not self.transport.is_closing():
            self.transport.write(response)
            self.transport.close()


def protocol_class(settings: Settings) -> type[LimitedHttpToolsProtocol]:
    """uvicorn builds its protocol from ``(config, server_state, app_state)`` only: the
    limits travel as class attributes of a subclass made for these settings."""
    return type(
        "LimitedHttpToolsProtocol",
        (LimitedHttpToolsProtocol,),
        {"max_header_bytes": settings.max_header_bytes, "header_timeout": settings.header_timeout},
    )


GRACEFUL_SHARE = 0.75
"""The share of ``AD_SHUTDOWN_SECONDS`` that requests in flight get to finish."""


def uvicorn_config(app: Any, settings: Settings) -> uvicorn.Config:
    return uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        access_log=False,
        http=protocol_class(settings),
        timeout_keep_alive=settings.keep_alive_timeout,  # type: ignore[arg-type]
        limit_concurrency=settings.max_connections,
        ssl_certfile=settings.ssl_certfile,
        ssl_keyfile=settings.ssl_keyfile,
        timeout_graceful_shutdown=GRACEFUL_SHARE * settings.shutdown_seconds,  # type: ignore[arg-type]
    )


class BoundedServer(uvicorn.Server):
    """uvicorn's server, ended within ``shutdown_seconds`` of SIGTERM or SIGINT.

    uvicorn waits, without a bound by default, for the requests in flight to finish,
    then for the app's shutdown (which waits for the threads computing proposals and
    expansions): a study creation computing for minutes kept a SIGTERM'd server up. Here
    requests get ``GRACEFUL_SHARE`` of the time (the config's
    ``timeout_graceful_shutdown``), then uvicorn cancels them (a creation's child is
    killed, nothing is stored) and the app shuts down; if the process is still there
    when the time is up, it logs what it leaves and exits at once with status 1 (a
    half-done write is rolled back by the database: each is one transaction)."""

    def __init__(self, config: uvicorn.Config, shutdown_seconds: float) -> None:
        super().__init__(config)
        self.shutdown_seconds = shutdown_seconds
        self._deadline: threading.Timer | None = None

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        super().handle_exit(sig, frame)
        if self._deadline is None:
            self._deadline = threading.Timer(self.shutdown_seconds, self._exit_now)
            self._deadline.daemon = True
            self._deadline.start()

    def _exit_now(self) -> None:
        logging.getLogger("adservice").error(
            "still running %g s after the signal to stop (AD_SHUTDOWN_SECONDS), with %d "
            "request(s) in flight and threads %s: exiting now",
            self.shutdown_seconds,
            len(self.server_state.tasks),
            ", ".join(sorted(thread.name for thread in threading.enumerate())),
        )
        logging.shutdown()
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os._exit(1)
