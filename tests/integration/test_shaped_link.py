"""The shaped link (roslink_mqtt/shaped_link.py): the delay, jitter, order and loss bench/spiral.py relies on."""

from __future__ import annotations

import asyncio
import fcntl
import socket
import struct
import termios
import time

from roslink_mqtt.shaped_link import Shape, ShapedLink, kbit


def test_a_round_trip_through_the_link_takes_twice_the_delay_and_keeps_every_byte_in_order() -> None:
    async def scenario() -> tuple[list[float], bytes, bytes]:
        async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            while data := await reader.read(65536):
                writer.write(data)
                await writer.drain()
            writer.close()

        upstream = await asyncio.start_server(echo, "127.0.0.1", 0)
        target = upstream.sockets[0].getsockname()[:2]
        link = ShapedLink(target, Shape(delay=0.03, jitter=0.01), seed=3)
        proxy = await link.start("127.0.0.1", 0)
        reader, writer = await asyncio.open_connection(*proxy.sockets[0].getsockname()[:2])
        rtts, sent, got = [], b"", b""
        for i in range(10):
            line = f"message {i}\n".encode()
            sent += line
            began = time.monotonic()
            writer.write(line)
            await writer.drain()
            got += await asyncio.wait_for(reader.readline(), 5)
            rtts.append(time.monotonic() - began)
        burst = bytes(range(256)) * 400  # 100 kB written at once: several chunks, order kept
        writer.write(burst)
        sent += burst
        got += await asyncio.wait_for(reader.readexactly(len(burst)), 5)
        writer.close()
        proxy.close()
        upstream.close()
        return rtts, sent, got

    rtts, sent, got = asyncio.run(scenario())
    assert got == sent
    mean = sum(rtts) / len(rtts)
    assert 0.04 < mean < 0.5, rtts  # ~60 ms: both directions delayed; generous upper bound for a loaded machine
    assert min(rtts) > 0.01






def _unsent(sock: socket.socket) -> int:
    """Bytes the kernel holds for ``sock`` not yet acknowledged by the peer (SIOCOUTQ)."""
    return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0" * 4))[0]


def test_a_rate_limited_link_is_shared_by_its_connections_and_its_queue_stays_in_the_senders_sockets() -> None:
    """Two connections saturate one 256 kbit/s uplink: together they get its rate, each about half, and what the
    link has not carried waits where the senders see it (their SIOCOUTQ), not inside the proxy."""
    rate = kbit(256)

    async def scenario() -> tuple[list[int], list[int], list[int], float]:
        got = [0, 0]

        async def sink(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            index = (await reader.readexactly(1))[0]
            while data := await reader.read(65536):
                got[index] += len(data)
            writer.close()

        upstream = await asyncio.start_server(sink, "127.0.0.1", 0)
        link = ShapedLink(upstream.sockets[0].getsockname()[:2], Shape(delay=0.02), up_rate=rate)
        proxy = await link.start("127.0.0.1", 0)
        senders = [socket.create_connection(proxy.sockets[0].getsockname()[:2]) for _ in range(2)]
        written = [0, 0]
        for i, s in enumerate(senders):
            s.setblocking(False)
            written[i] += s.send(bytes([i]))
        began = time.monotonic()
        for _ in range(20):  # 2 s: each sender keeps 100 kB waiting
            for i, s in enumerate(senders):
                while written[i] - _unsent(s) - got[i] < 100_000 and _unsent(s) < 100_000:
                    try:
                        written[i] += s.send(b"x" * 4096)
                    except BlockingIOError:
                        break
            await asyncio.sleep(0.1)
        elapsed = time.monotonic() - began
        unseen = [w - _unsent(s) - g for w, s, g in zip(written, senders, got, strict=True)]
        for s in senders:
            s.close()
        proxy.close()
        upstream.close()
        return got, written, unseen, elapsed

    got, _written, unseen, elapsed = asyncio.run(scenario())
    total = sum(got) / elapsed
    assert 0.6 * rate < total < 1.1 * rate, (got, elapsed)  # the link's rate (a loaded machine may lag it)
    assert min(got) > 0.3 * sum(got), got  # shared, not one connection first
    assert max(unseen) < 8192, unseen  # a packet, the delay line and a small read-ahead: the rest is visible
