"""Slow and oversized clients against a real server, and the fresh client that probes it
meanwhile: one huge header, slowloris (headers never finished), slow bodies, idle
connections. A test checks the server refuses and closes them; bench/slow_clients.py
measures what they cost the probe."""

from __future__ import annotations

import contextlib
import select
import socket
import threading
import time
from dataclasses import dataclass, field

import httpx

BIG_HEADER_BYTES = 100_000_000


@dataclass
class Attack:
    """What an attack saw, on the monotonic clock: connections opened, those the server
    closed (the first when), how long they were all held open, what it answered."""

    opened: int = 0
    closed: int = 0
    started: float = field(default_factory=time.monotonic)
    held_from: float | None = None
    """When every connection was open (None until then)."""
    first_close_at: float | None = None
    sent: int = 0
    """Bytes of the huge header sent before the server closed (socket buffers included)."""
    answers: str = ""

    @property
    def first_close_s(self) -> float | None:
        """Seconds from the attack's start to the server's first close."""
        return None if self.first_close_at is None else self.first_close_at - self.started

    def close_seen(self, reply: bytes) -> None:
        self.closed += 1
        if self.first_close_at is None:
            self.first_close_at = time.monotonic()
        status = reply[:12].decode("latin-1").strip()
        if status and status not in self.answers:
            self.answers = f"{self.answers} {status}".strip()


def healthz_seconds(port: int) -> float:
    """One ``GET /healthz`` on a new connection, as a fresh client would; seconds taken."""
    started = time.monotonic()
    with httpx.Client(timeout=120) as client:
        client.get(f"http://127.0.0.1:{port}/healthz").raise_for_status()
    return time.monotonic() - started


def big_header(port: int, stop: threading.Event, size: int = BIG_HEADER_BYTES) -> Attack:
    """One connection sends a header of ``size`` bytes as fast as the server takes it."""
    attack = Attack(opened=1)
    chunk = b"a" * 65_536
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(120)
        attack.held_from = time.monotonic()
        try:
            sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: ")
            for _ in range(size // len(chunk)):
                if stop.is_set():
                    return attack
                sock.sendall(chunk)
                attack.sent += len(chunk)
            sock.sendall(b"\r\n\r\n")
        except OSError:
            pass
        try:
            reply = sock.recv(4096)
        except OSError:
            reply = b""
        attack.close_seen(reply)
    return attack


def _trickle(
    port: int, stop: threading.Event, count: int, opening: bytes, drip: bytes | None
) -> Attack:
    """``count`` connections send ``opening``, then ``drip`` once a second each, until
    ``stop``; a connection the server answers or closes is counted once."""
    attack = Attack()
    open_socks: list[socket.socket] = []
    for _ in range(count):
        sock = socket.create_connection(("127.0.0.1", port))
        sock.sendall(opening)
        open_socks.append(sock)
    attack.opened = len(open_socks)
    attack.held_from = time.monotonic()
    next_drip = time.monotonic() + 1.0
    try:
        while open_socks and not stop.is_set():
            readable, _, _ = select.select(open_socks, [], [], 0.1)
            for sock in readable:
                try:
                    reply = sock.recv(4096)
                except OSError:
                    reply = b""
                attack.close_seen(reply)
                open_socks.remove(sock)
                sock.close()
            if drip is not None and time.monotonic() >= next_drip:
                next_drip += 1.0
                for sock in open_socks:
                    with contextlib.suppress(OSError):
                        sock.send(drip)
    finally:
        for sock in open_socks:
            sock.close()
    return attack


def slowloris(port: int, stop: threading.Event, count: int = 250) -> Attack:
    return _trickle(
        port, stop, count, b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n", b"X-a: b\r\n"
    )


def slow_body(port: int, stop: threading.Event, count: int = 100) -> Attack:
    opening = (
        b"POST /api/v1/studies HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: application/json\r\nContent-Length: 10000\r\n\r\n{"
    )
    return _trickle(port, stop, count, opening, b" ")


def idle(port: int, stop: threading.Event, count: int = 250) -> Attack:
    return _trickle(port, stop, count, b"", None)
