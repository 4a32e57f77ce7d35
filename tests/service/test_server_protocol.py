"""The server's HTTP protocol on a real loopback connection: one write per answer.

The protocol runs in this test's event loop behind a real socket; its transport is
wrapped only to count the writes that reach the socket.
"""

from __future__ import annotations

import asyncio
from typing import Any

import uvicorn
from starlette.responses import JSONResponse, StreamingResponse
from uvicorn.server import ServerState

from adservice.server import protocol_class
from adservice.settings import Settings


class CountedWrites:
    """A real transport whose writes are recorded on their way to the socket."""

    def __init__(self, transport: asyncio.Transport, writes: list[bytes]) -> None:
        self._transport = transport
        self._writes = writes

    def write(self, data: bytes) -> None:
        self._writes.append(bytes(data))
        self._transport.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._transport, name)


async def app(scope: dict[str, Any], receive: Any, send: Any) -> None:
    if scope["path"] == "/stream":

        async def chunks() -> Any:
            yield b"first;"
            await asyncio.sleep(0.3)
            yield b"second"

        response: Any = StreamingResponse(chunks(), media_type="text/plain")
    else:
        response = JSONResponse({"status": "ok"})
    await response(scope, receive, send)


async def counted_server(writes: list[bytes]) -> tuple[asyncio.Server, int]:
    """The server's protocol on a loopback port; its socket writes land in ``writes``."""
    config = uvicorn.Config(app, log_level="warning", lifespan="off")
    config.load()
    base = protocol_class(Settings())

    class Counted(base):  # type: ignore[misc, valid-type]
        def connection_made(self, transport: asyncio.Transport) -> None:
            super().connection_made(CountedWrites(transport, writes))

    state = ServerState()
    server = await asyncio.get_running_loop().create_server(
        lambda: Counted(config=config, server_state=state, app_state={}), "127.0.0.1", 0
    )
    return server, server.sockets[0].getsockname()[1]


async def serve_and_ask(paths: list[str]) -> tuple[list[bytes], list[tuple[float, bytes]]]:
    """Ask ``paths`` on one keep-alive connection; returns the server's socket writes and
    what the client read, with when it read it."""
    writes: list[bytes] = []
    server, port = await counted_server(writes)
    loop = asyncio.get_running_loop()
    reads: list[tuple[float, bytes]] = []
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        for path in paths:
            writer.write(f"GET {path} HTTP/1.1\r\nhost: 127.0.0.1\r\n\r\n".encode())
            expected = b"second" if path == "/stream" else b'{"status":"ok"}'
            received = b""
            while not received.rstrip(b"\r\n0").endswith(expected.rstrip(b"0")):
                chunk = await asyncio.wait_for(reader.read(65_536), 10)
                assert chunk, f"the connection closed before {path}'s answer ended"
                received += chunk
                reads.append((loop.time(), chunk))
    finally:
        writer.close()
        server.close()
        await server.wait_closed()
    return writes, reads


def test_an_answer_leaves_in_one_write() -> None:
    """uvicorn writes the head and the body apart; the client then wakes twice per answer."""
    writes, _ = asyncio.run(serve_and_ask(["/healthz", "/again", "/third"]))
    assert len(writes) == 3, [w[:40] for w in writes]
    for write in writes:
        head, _, body = write.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 200 OK")
        assert body == b'{"status":"ok"}'


def test_a_streamed_answer_sends_its_head_before_a_slow_body() -> None:
    """The held head goes out when the loop turns, not only when the body comes."""
    writes, reads = asyncio.run(serve_and_ask(["/stream"]))
    assert writes[0].startswith(b"HTTP/1.1 200 OK")
    assert b"second" not in writes[0]
    assert b"second" in b"".join(writes)
    first_read_at, first = reads[0]
    last_read_at, _ = reads[-1]
    assert b"first;" in first
    assert last_read_at - first_read_at >= 0.2  # the head and first chunk came before the pause


async def answer_before_body() -> tuple[bytes, bytes]:
    """A POST whose body has not come when the app answers (as a refused token is): what
    the client reads, and what it reads after sending the body and a second request."""
    server, port = await counted_server([])
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(b"POST /early HTTP/1.1\r\nhost: 127.0.0.1\r\ncontent-length: 8\r\n\r\n")
        answer = b""
        while not answer.endswith(b'{"status":"ok"}'):
            chunk = await asyncio.wait_for(reader.read(65_536), 10)
            assert chunk, "closed before the answer"
            answer += chunk
        writer.write(b"{'x': 1}GET /again HTTP/1.1\r\nhost: 127.0.0.1\r\n\r\n")
        after = await asyncio.wait_for(reader.read(65_536), 10)
    finally:
        writer.close()
        server.close()
        await server.wait_closed()
    return answer, after


def test_an_answer_before_its_request_body_ends_the_connection_and_says_so() -> None:
    """The server closes a connection whose body it never read; the answer must say so,
    or a client that read it whole sends its next request into a reset."""
    answer, after = asyncio.run(answer_before_body())
    head = answer.partition(b"\r\n\r\n")[0].lower()
    assert head.startswith(b"http/1.1 200 ok")
    assert b"\r\nconnection: close" in head
    assert after == b""  # closed: the second request got no answer on this connection
