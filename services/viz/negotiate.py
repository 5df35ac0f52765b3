"""A front for the Foxglove SDK's WebSocket server that also accepts the older subprotocol.

The SDK (0.30) serves only ``foxglove.sdk.v1``; Lichtblick, older Foxglove apps and the
``@foxglove/ws-protocol`` client offer ``foxglove.websocket.v1`` and get "400 Missing expected
sec-websocket-protocol header". Both name the same protocol, so this front passes every
connection through to the SDK's server, rewriting only the subprotocol of the handshake (the
request's offer and the answer's choice); the WebSocket frames themselves pass untouched.
"""

from __future__ import annotations

import asyncio
import contextlib

SDK = "foxglove.sdk.v1"
LEGACY = "foxglove.websocket.v1"
_MAX_HEAD = 16 * 1024


def _protocols(head: bytes) -> list[str]:
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"sec-websocket-protocol":
            return [p.strip() for p in value.decode("latin-1").split(",")]
    return []


def _set_protocol(head: bytes, protocol: str) -> bytes:
    lines = head.split(b"\r\n")
    out = [lines[0]] + [line for line in lines[1:]
                        if line.partition(b":")[0].strip().lower() != b"sec-websocket-protocol"]
    return b"\r\n".join([*out[:1], f"Sec-WebSocket-Protocol: {protocol}".encode(), *out[1:]])


async def _read_head(reader: asyncio.StreamReader) -> bytes:
    """An HTTP head (up to, not including, the blank line); raises ValueError if too long."""
    data = await reader.readuntil(b"\r\n\r\n")
    if len(data) > _MAX_HEAD:
        raise ValueError("HTTP head too long")
    return data[:-4]


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()


async def _serve(client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter,
                 upstream: tuple[str, int]) -> None:
    """One client's connection, passed through to ``upstream`` (the SDK's server). Cancelled
    (the service stopping with a client connected), it closes the client and ends quietly:
    Python 3.11's server reports a connection handler's cancellation as an error, with a
    traceback on every stop."""
    try:
        await _pass_through(client_r, client_w, upstream)
    except asyncio.CancelledError:
        with contextlib.suppress(Exception):
            client_w.close()


async def _pass_through(client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter,
                        upstream: tuple[str, int]) -> None:
    try:
        head = await _read_head(client_r)
        legacy = LEGACY in _protocols(head) and SDK not in _protocols(head)
        if legacy:
            head = _set_protocol(head, SDK)
        up_r, up_w = await asyncio.open_connection(*upstream)
        up_w.write(head + b"\r\n\r\n")
        await up_w.drain()
        answer = await _read_head(up_r)
        if legacy and SDK in _protocols(answer):
            answer = _set_protocol(answer, LEGACY)
        client_w.write(answer + b"\r\n\r\n")
        await client_w.drain()
    except (ValueError, ConnectionError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
        client_w.close()
        return
    await asyncio.gather(_pipe(client_r, up_w), _pipe(up_r, client_w))


async def serve_both_subprotocols(host: str, port: int, upstream_port: int) -> asyncio.Server:
    """Listen on ``host:port`` in front of the SDK server at ``127.0.0.1:upstream_port``."""
    return await asyncio.start_server(
        lambda r, w: _serve(r, w, ("127.0.0.1", upstream_port)), host, port, limit=_MAX_HEAD)
