"""A TCP proxy that makes a loopback connection behave like a long, uneven Internet link.

    python -m roslink_mqtt.shaped_link --listen 127.0.0.1:18830 --to 127.0.0.1:1883 \
        --delay-ms 60 --jitter-ms 20 --loss 0.01

Why it exists: this machine's kernel has no ``netem``, yet the benchmarks (bench/spiral.py) and anyone
trying a robot "over the cloud" need a link with delay, jitter and loss between the bridge and the
broker. Point the bridge's ``--url`` at the proxy's port instead of the broker's.

What it does to each direction of every connection, independently:

* **delay**: every chunk read is written ``delay ± jitter`` ms later (normal distribution, never
  negative, so the mean one-way delay is ``delay``);
* **order**: TCP never reorders, so a chunk is never written before the one read ahead of it (a late
  chunk holds up the ones behind it, as on a real link);
* **loss**: TCP never loses data either; a lost segment is retransmitted after the sender's
  retransmission timeout, so with probability ``loss`` a chunk is held back an extra ``--rto-ms``
  (200 ms, Linux's minimum RTO) and everything behind it with it.

Chunks are what one ``read`` returned (up to 64 KiB), not IP packets: a good model for small MQTT
messages, a coarse one for large transfers. Both sockets get TCP_NODELAY so the proxy adds no Nagle
stall of its own. Pure asyncio, no ROS, no MQTT: it shapes any TCP service.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import random
import socket
import sys
import time
from dataclasses import dataclass

CHUNK = 65536
QUEUED_CHUNKS = 1024  # per direction: a reader this far ahead of the writer waits (bounded memory)


@dataclass(frozen=True, slots=True)
class Shape:
    """One direction's delay model; all times in seconds."""

    delay: float = 0.0
    jitter: float = 0.0
    loss: float = 0.0
    rto: float = 0.2

    def __post_init__(self) -> None:
        if self.delay < 0 or self.jitter < 0 or self.rto < 0:
            raise ValueError("delay, jitter and rto must not be negative")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError("loss is a probability in [0, 1)")


class Schedule:
    """When each chunk of one direction may be written: delay, jitter and loss, never out of order."""

    def __init__(self, shape: Shape, rng: random.Random) -> None:
        self.shape, self.rng = shape, rng
        self.last = 0.0  # release time of the previous chunk

    def release_time(self, now: float) -> float:
        """The moment a chunk read at ``now`` may be written."""
        shape = self.shape
        delay = max(0.0, self.rng.gauss(shape.delay, shape.jitter)) if shape.jitter else shape.delay
        if shape.loss and self.rng.random() < shape.loss:
            delay += shape.rto  # the segment was lost and sent again after the retransmission timeout
        self.last = max(self.last, now + delay)
        return self.last


def _nodelay(writer: asyncio.StreamWriter) -> None:
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, schedule: Schedule) -> None:
    """Copy one direction through the schedule; end (and half-close) when the reader ends."""
    queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(QUEUED_CHUNKS)
    loop = asyncio.get_running_loop()

    async def read() -> None:
        try:
            while chunk := await reader.read(CHUNK):
                await queue.put((schedule.release_time(loop.time()), chunk))
        except (ConnectionError, OSError):
            pass
        await queue.put(None)

    async def write() -> None:
        while (item := await queue.get()) is not None:
            release, chunk = item
            if (wait := release - loop.time()) > 0:
                await asyncio.sleep(wait)
            writer.write(chunk)
            await writer.drain()
        with contextlib.suppress(OSError):
            writer.write_eof()

    reading = asyncio.create_task(read())
    try:
        await write()
    except (ConnectionError, OSError):
        pass
    finally:
        reading.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reading


class ShapedLink:
    """The proxy: one listening socket, every accepted connection forwarded to ``target`` through two schedules."""

    def __init__(self, target: tuple[str, int], shape: Shape, *, seed: int | None = None) -> None:
        self.target, self.shape = target, shape
        self.rng = random.Random(seed)
        self.connections = 0

    async def _serve(self, client_reader: asyncio.StreamReader, client_writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        try:
            upstream_reader, upstream_writer = await asyncio.open_connection(*self.target)
        except OSError:
            client_writer.close()  # the far end is down: the client sees a refused/closed connection
            return
        for w in (client_writer, upstream_writer):
            _nodelay(w)
        try:
            await asyncio.gather(
                _pump(client_reader, upstream_writer, Schedule(self.shape, self.rng)),
                _pump(upstream_reader, client_writer, Schedule(self.shape, self.rng)),
            )
        finally:
            for w in (client_writer, upstream_writer):
                w.close()

    async def start(self, host: str, port: int) -> asyncio.Server:
        return await asyncio.start_server(self._serve, host, port, reuse_address=True)


def _address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "127.0.0.1", int(port)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m roslink_mqtt.shaped_link", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", type=_address, required=True, help="HOST:PORT to accept connections on")
    p.add_argument("--to", type=_address, required=True, help="HOST:PORT to forward them to (the broker)")
    p.add_argument("--delay-ms", type=float, default=20.0, help="mean one-way delay (default: %(default)s)")
    p.add_argument("--jitter-ms", type=float, default=5.0, help="its standard deviation (default: %(default)s)")
    p.add_argument("--loss", type=float, default=0.0, help="share of chunks lost and resent (default: 0)")
    p.add_argument("--rto-ms", type=float, default=200.0, help="what a loss costs (default: %(default)s)")
    p.add_argument("--seed", type=int, default=None, help="random seed, for repeatable runs")
    args = p.parse_args(argv)
    try:
        args.shape = Shape(args.delay_ms / 1000, args.jitter_ms / 1000, args.loss, args.rto_ms / 1000)
    except ValueError as e:
        p.error(str(e))
    return args


async def _run(args: argparse.Namespace) -> None:
    link = ShapedLink(args.to, args.shape, seed=args.seed)
    server = await link.start(*args.listen)
    shape = args.shape
    print(f"shaped link {args.listen[0]}:{args.listen[1]} -> {args.to[0]}:{args.to[1]}: "
          f"{shape.delay * 1000:g} ± {shape.jitter * 1000:g} ms each way, loss {shape.loss:g} "
          f"(+{shape.rto * 1000:g} ms)", flush=True)
    async with server:
        await server.serve_forever()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    started = time.monotonic()
    try:
        asyncio.run(_run(args))
    except KeyboardInterrupt:
        pass
    except OSError as e:
        print(f"shaped link: {e}", file=sys.stderr)
        return 1
    print(f"shaped link: stopped after {time.monotonic() - started:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
