"""Both names of the Foxglove WebSocket protocol on one port.

foxglove-sdk's server (0.30, and its source to this day: ``websocket/handshake.rs``) accepts only the
subprotocol ``foxglove.sdk.v1`` and answers 400 to a client that offers only ``foxglove.websocket.v1``: Foxglove
Studio 1.48, Lichtblick before December 2025, and @foxglove/ws-protocol's FoxgloveClient by default. Foxglove
states that the two names are one protocol, and the SDK has no option to accept the old one.

``SubprotocolGate`` is the least code that makes both work: a TCP relay in front of the SDK's server. It reads
the client's HTTP upgrade request, and when the client offers only the old name it puts the SDK's name in the
request and the old one back in the server's answer. After the handshake it copies bytes both ways unchanged:
it never parses a WebSocket frame. What it costs: one more loopback hop (two socket copies per message) and a
thread running an asyncio loop (the monitor's benchmark measures it). Standard library only.
"""
from __future__ import annotations

import asyncio
import threading
from typing import NamedTuple

from .errors import MonitorError

SDK_SUBPROTOCOL = 'foxglove.sdk.v1'
LEGACY_SUBPROTOCOL = 'foxglove.websocket.v1'
HEADER = b'sec-websocket-protocol'
MAX_HEAD = 64 * 1024      # an HTTP upgrade request or answer is well under this
CHUNK = 256 * 1024


def offered(head: bytes) -> list:
    """The subprotocols an HTTP upgrade request offers, in order."""
    names = []
    for line in head.split(b'\r\n')[1:]:
        key, sep, value = line.partition(b':')
        if sep and key.strip().lower() == HEADER:
            names += [v.strip().decode('latin-1') for v in value.split(b',') if v.strip()]
    return names


def replace_protocol(head: bytes, name: str) -> bytes:
    """``head`` with every Sec-WebSocket-Protocol header replaced by one that names ``name``."""
    lines = head.split(b'\r\n')
    out, done = [lines[0]], False
    for line in lines[1:]:
        key, sep, _ = line.partition(b':')
        if sep and key.strip().lower() == HEADER:
            if not done:
                out.append(key + b': ' + name.encode('latin-1'))
                done = True
            continue
        out.append(line)
    return b'\r\n'.join(out)


class Translated(NamedTuple):
    """A WebSocket request as the SDK gets it: the request head, and the subprotocol to answer the client with (None:
    the SDK's answer passes unchanged)."""

    head: bytes
    answer_with: str | None


def translate_request(head: bytes) -> Translated:
    """The request head for the SDK, and the name to answer with (``Translated``)."""
    names = offered(head)
    if SDK_SUBPROTOCOL in names or LEGACY_SUBPROTOCOL not in names:
        return Translated(head, None)          # the SDK's own name, or one neither knows: the SDK decides
    return Translated(replace_protocol(head, SDK_SUBPROTOCOL), LEGACY_SUBPROTOCOL)


async def _read_head(reader: asyncio.StreamReader) -> tuple:
    """(head without its blank line, bytes read after it); ValueError if there is none within MAX_HEAD."""
    data = b''
    while b'\r\n\r\n' not in data:
        chunk = await reader.read(CHUNK)
        if not chunk or len(data) > MAX_HEAD:
            raise ValueError('no HTTP head')
        data += chunk
    head, _, rest = data.partition(b'\r\n\r\n')
    return head, rest


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while chunk := await reader.read(CHUNK):
            writer.write(chunk)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        writer.close()


class SubprotocolGate:
    """Listen on ``host:port`` (0: any free port; ``.port`` says which) and relay each connection to the SDK's
    server on ``127.0.0.1:upstream_port``, accepting both subprotocol names. ``close()`` stops it."""

    def __init__(self, host: str, port: int, upstream_port: int):
        self.upstream_port = upstream_port
        self.loop = asyncio.new_event_loop()
        try:
            self.server = self.loop.run_until_complete(asyncio.start_server(self._relay, host, port))
        except OSError as exc:
            self.loop.close()
            reason = 'is already in use' if exc.errno == 98 else f'cannot be opened ({exc.strerror})'
            raise MonitorError(f'port {port} on {host} {reason}; expected a free port '
                               f'(-p port:=<another>, or 0 for any)') from None
        self.port = self.server.sockets[0].getsockname()[1]
        self.thread = threading.Thread(target=self.loop.run_forever, name='foxglove-gate', daemon=True)
        self.thread.start()

    async def _relay(self, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        try:
            head, rest = await _read_head(client_r)
            head, answer_as = translate_request(head)
            up_r, up_w = await asyncio.open_connection('127.0.0.1', self.upstream_port)
        except (ValueError, OSError):
            client_w.close()
            return
        up_w.write(head + b'\r\n\r\n' + rest)
        try:
            reply, more = await _read_head(up_r)
        except (ValueError, OSError):
            client_w.close()
            up_w.close()
            return
        if answer_as is not None and SDK_SUBPROTOCOL.encode() in reply:
            reply = replace_protocol(reply, answer_as)
        client_w.write(reply + b'\r\n\r\n' + more)
        await asyncio.gather(_pipe(client_r, up_w), _pipe(up_r, client_w))

    def close(self) -> None:
        async def stop():
            self.server.close()
            for task in asyncio.all_tasks():
                if task is not asyncio.current_task():
                    task.cancel()
        if self.loop.is_running():
            asyncio.run_coroutine_threadsafe(stop(), self.loop).result(timeout=5)
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(timeout=5)
        self.loop.close()
