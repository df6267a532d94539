"""The shaped link (roslink_mqtt/shaped_link.py): the delay, jitter, order and loss bench/spiral.py relies on."""

from __future__ import annotations

import asyncio
import random
import time

import pytest

from roslink_mqtt.shaped_link import Schedule, Shape, ShapedLink, parse_args


@pytest.mark.unit
def test_schedule_never_reorders_and_adds_the_delay() -> None:
    schedule = Schedule(Shape(delay=0.05, jitter=0.03), random.Random(1))
    releases = [schedule.release_time(i * 0.02) for i in range(500)]  # 50 Hz, as in the spiral bench
    assert releases == sorted(releases)  # a late chunk holds up the ones behind it, like TCP
    extra = [r - i * 0.02 for i, r in enumerate(releases)]
    assert min(extra) >= 0.0
    assert 0.05 <= sum(extra) / len(extra) < 0.075  # the delay, plus what holding up late chunks adds


@pytest.mark.unit
def test_a_lost_chunk_costs_a_retransmission_timeout() -> None:
    schedule = Schedule(Shape(delay=0.01, loss=0.5, rto=0.2), random.Random(2))
    extra = [schedule.release_time(i * 1.0) - i * 1.0 for i in range(200)]  # far apart: no holding up
    lost = [e for e in extra if e > 0.1]
    assert 60 < len(lost) < 140
    assert all(abs(e - 0.21) < 1e-9 for e in lost)
    assert all(abs(e - 0.01) < 1e-9 for e in extra if e <= 0.1)


@pytest.mark.unit
@pytest.mark.parametrize("bad", [["--delay-ms", "-1"], ["--loss", "1.5"], ["--to", "nohostport"]])
def test_bad_shapes_are_refused(bad: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2"] + bad
    with pytest.raises(SystemExit) as exit_info:
        parse_args(argv)
    assert exit_info.value.code == 2
    assert capsys.readouterr().err


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
