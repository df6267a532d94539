"""A paced lane's writes (bridge/core/pacer.py): the token bucket, and the wrapper under paho's socket writes."""

from __future__ import annotations

import socket
import threading
import time
import tracemalloc

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from roslink_mqtt.bridge.core.pacer import MIN_BURST, SLEEP_MAX, ZERO_COPY_FROM, Pacer, install, paced_send

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def test_unpaced_writes_go_through_whole() -> None:
    assert Pacer().grant(4_000_000, 0.0) == (4_000_000, 0.0)


def test_a_large_message_leaves_at_the_rate_in_small_bursts() -> None:
    """A 4 MB map written through a 1 Mbit/s-paced lane: the socket gets it at that rate, 20 ms worth at a time
    (never in one go, which behind a hop would be 32 s of a hidden queue ahead of everything else)."""
    clock, pacer = Clock(), Pacer()
    pacer.rate = 125_000.0
    written: list[int] = []
    write = paced_send(pacer, lambda buf: written.append(len(buf)) or len(buf), clock.sleep, clock)
    left = 1_000_000
    while left:
        try:
            left -= write(b"x" * left)
        except BlockingIOError:
            clock.sleep(0.001)  # paho's next turn
    assert max(written) <= max(MIN_BURST, 125_000 * 0.02)
    assert clock.now == pytest.approx(1_000_000 / 125_000, rel=0.05)


def test_a_lane_without_tokens_waits_once_then_reports_a_full_socket() -> None:
    clock, pacer = Clock(), Pacer()
    pacer.rate = 10.0  # 1,500 bytes of burst, then 10 bytes/s
    write = paced_send(pacer, len, clock.sleep, clock)
    assert write(b"x" * 1_500) == 1_500
    with pytest.raises(BlockingIOError):
        write(b"x" * 100)
    assert clock.now == pytest.approx(SLEEP_MAX)  # waited once, briefly: paho's thread reads between turns


def test_what_the_socket_did_not_take_is_refunded() -> None:
    clock, pacer = Clock(), Pacer()
    pacer.rate = 1_000.0
    write = paced_send(pacer, lambda buf: 100, clock.sleep, clock)  # a socket that takes 100 bytes
    assert write(b"x" * 1_500) == 100
    assert write(b"x" * 1_400) == 100  # the 1,400 not taken were kept: no wait
    assert clock.now == 0.0


def test_a_full_socket_spends_no_tokens() -> None:
    """A socket that takes nothing (its buffer full) raises BlockingIOError: the granted tokens were not spent (they
    were, and a lane whose small send buffer filled now and then wrote slower than its allowance)."""
    clock, pacer = Clock(), Pacer()
    pacer.rate = 1_000.0

    def full(buf: bytes | bytearray) -> int:
        raise BlockingIOError

    with pytest.raises(BlockingIOError):
        paced_send(pacer, full, clock.sleep, clock)(b"x" * 1_500)
    assert paced_send(pacer, lambda buf: len(buf), clock.sleep, clock)(b"x" * 1_500) == MIN_BURST
    assert clock.now == 0.0


def test_unpacing_lets_the_rest_through_at_once() -> None:
    pacer = Pacer()
    pacer.rate = 1_000.0
    assert pacer.grant(10_000, 0.0)[0] == MIN_BURST
    pacer.rate = None
    assert pacer.grant(10_000, 0.0) == (10_000, 0.0)


def test_a_large_packet_is_written_a_burst_at_a_time_without_copying_its_rest() -> None:
    """A 4 MB map through a paced lane: paho writes its head packet as ``packet[pos:]`` at every attempt, a copy of
    the whole rest (200 MB/s of copies at 50 bursts a second: the bridge's poses and stops were late while a map
    crossed). Queued as a view, the writes allocate no more than a burst. A real paho client writes it into a
    real socket; what arrives is the packet, whole."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="paced")
    near, far = socket.socketpair()
    near.setblocking(False)
    client._sock = near
    pacer = Pacer()
    pacer.rate = 20_000_000.0  # bytes/s: 400 kB bursts, 0.2 s for the whole map
    install(client, pacer)
    packet = bytearray(range(256)) * (4_000_000 // 256)
    client._packet_queue(mqtt.PUBLISH, packet, 1, 0, mqtt.MQTTMessageInfo(1))
    assert isinstance(client._out_packet[0]["packet"], memoryview)
    client._packet_queue(mqtt.PINGREQ, b"\xc0\x00", 0, 0)  # small packets stay as they are
    assert isinstance(client._out_packet[1]["packet"], bytes)
    assert ZERO_COPY_FROM > 2
    received = bytearray(len(packet) + 2)  # allocated before the measurement: the reader's own memory
    got = [0]

    def read() -> None:
        view = memoryview(received)
        while got[0] < len(received):
            count = far.recv_into(view[got[0]:])
            if not count:
                return
            got[0] += count

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    tracemalloc.start()
    try:
        deadline = time.monotonic() + 30.0  # 0.2 s at the rate; a loaded machine may give the reader less
        while client._out_packet and time.monotonic() < deadline:
            client._packet_write()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    reader.join(10)
    near.close()
    far.close()
    assert not client._out_packet
    assert got[0] == len(received) and received == packet + b"\xc0\x00"
    assert peak < 1_000_000, f"{peak} bytes allocated while writing a 4 MB packet: its rest was copied"
