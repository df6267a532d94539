"""The Foxglove gateway's front door: one port for both names of the Foxglove WebSocket protocol.

Foxglove's own server (``foxglove-sdk``, which the gateway uses) accepts only the protocol's current name,
``foxglove.sdk.v1``, and refuses the handshake of a client that offers the earlier ``foxglove.websocket.v1`` — the
same messages under their first name, which Lichtblick releases before December 2025, Foxglove Studio, PlotJuggler's
and other tools' clients and ``@foxglove/ws-protocol``'s default offer. The front accepts either name and relays
every frame, unchanged, to the SDK's server on a loopback port of its own; a client that offers both gets
``foxglove.sdk.v1``. A slow client slows only its own relay; the SDK's server drops what waits for it too long, as
it does for a client connected directly.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from typing import Any

log = logging.getLogger("roslink_mqtt.foxglove")

CURRENT, FIRST = "foxglove.sdk.v1", "foxglove.websocket.v1"
NAMES = (CURRENT, FIRST)  # the server's preference: the current name when a client offers both


class ProtocolFront:
    """Listen on ``host:port`` (0: a free port) and relay each client to ``ws://127.0.0.1:<upstream>``."""

    def __init__(self, host: str, port: int, upstream: int) -> None:
        self.host, self.port, self.upstream = host, port, upstream
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="foxglove-front", daemon=True)

    def start(self, timeout: float = 10.0) -> int:
        """Listen; the port listened on. OSError when the address cannot be had."""
        self._thread.start()
        if not self._ready.wait(timeout):
            raise OSError(f"the Foxglove front did not start within {timeout:g} s")
        if self._error is not None:
            raise self._error
        return self.port

    def stop(self) -> None:
        loop, server = self._loop, self._server
        if loop is not None and server is not None:
            loop.call_soon_threadsafe(server.close)
        self._thread.join(5)

    def _run(self) -> None:
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        from websockets.asyncio.server import serve
        from websockets.typing import Subprotocol

        self._loop = asyncio.get_running_loop()
        try:
            self._server = await serve(self._relay, self.host, self.port,
                                       subprotocols=[Subprotocol(name) for name in NAMES], max_size=None,
                                       compression=None)
        except OSError as err:
            self._error = err
            self._ready.set()
            return
        self.port = self._server.sockets[0].getsockname()[1]
        self._ready.set()
        await self._server.wait_closed()

    async def _relay(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import WebSocketException
        from websockets.typing import Subprotocol

        try:
            async with connect(f"ws://127.0.0.1:{self.upstream}", subprotocols=[Subprotocol(CURRENT)], max_size=None,
                               compression=None, ping_interval=None) as server:
                pumps = [asyncio.create_task(_pump(client, server)), asyncio.create_task(_pump(server, client))]
                _done, pending = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
                for task in pending:
                    task.cancel()
        except (OSError, WebSocketException) as err:
            log.warning("a Foxglove client (%s) was dropped: %s", client.subprotocol, err)


async def _pump(source: Any, sink: Any) -> None:
    """Every frame from ``source`` to ``sink`` as it came (text as text, binary as binary), until either closes."""
    from websockets.exceptions import ConnectionClosed

    try:
        async for frame in source:
            await sink.send(frame)
    except ConnectionClosed:
        pass
    finally:
        await sink.close()
