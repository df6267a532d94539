"""The pure logic behind the broker's limits: retained index and quota, outbox, packet gate, docs drift."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import pytest

from roslink_mqtt.broker.guard import READ_CHUNK, BadTopic, PacketGate, PacketStalled, PacketTooLarge, PartialBudget
from roslink_mqtt.broker.limits import BrokerLimits, RetainedQuota
from roslink_mqtt.broker.outbox import Outbox, Verdict
from tests.support.rawmqtt import connect_packet, publish_packet, subscribe_packet

ROOT = Path(__file__).resolve().parents[2]
def test_retained_quota_per_login_and_total() -> None:
    quota = RetainedQuota(BrokerLimits(retained_bytes_total=250))
    assert quota.check("bob", 100, "t/1", 60) is None
    quota.stored("bob", "t/1", 60)
    assert "this login" in quota.check("bob", 100, "t/2", 60)
    assert quota.check("bob", 100, "t/1", 100) is None  # replacing his own message frees its bytes first
    quota.stored("robot", "r/1", 150)
    assert "broker-wide" in quota.check("admin", None, "a/1", 50)
    quota.cleared("t/1")
    assert quota.used_by("bob") == 0 and quota.total == 150
    assert quota.check("admin", None, "a/1", 50) is None


def test_outbox_drops_over_the_limit_then_disconnects_after_the_timeout() -> None:
    limits = BrokerLimits(max_queued_messages=3, max_queued_bytes=1000, slow_consumer_timeout=5.0)
    box = Outbox()
    assert [box.admit(100, 0, 0.0, limits) for _ in range(3)] == [Verdict.SEND] * 3
    assert box.admit(100, 0, 1.0, limits) is Verdict.DROP  # 3 messages waiting
    box.done(100)
    assert box.admit(100, 950, 2.0, limits) is Verdict.DROP  # the socket buffer counts too
    assert box.admit(100, 950, 6.5, limits) is Verdict.DISCONNECT  # over the limit since t=1 s
    box2 = Outbox()
    assert box2.admit(100, 990, 0.0, limits) is Verdict.DROP
    assert box2.admit(100, 0, 1.0, limits) is Verdict.SEND  # under again: the clock restarts
    assert box2.over_since is None


class _Bytes:
    """A reader that hands out a byte string in reads of the sizes amqtt uses."""

    def __init__(self, data: bytes) -> None:
        self.data = data

    async def read(self, n: int = -1) -> bytes:
        out, self.data = self.data[:n], self.data[n:]
        return out

    def feed_eof(self) -> None:
        pass


def _read_all(data: bytes, limits: dict[int, int], sizes: list[int]) -> None:
    gate = PacketGate(_Bytes(data), lambda t: limits.get(t, 0), lambda: "test")

    async def go() -> None:
        i = 0
        while gate.inner.data:
            await gate.read(sizes[i % len(sizes)])
            i += 1
    asyncio.run(go())


@pytest.mark.parametrize("sizes", [[1], [2, 7], [4096]])
def test_packet_gate_follows_the_framing_however_it_is_read(sizes: list[int]) -> None:
    stream = (connect_packet("c", "u", "p") + subscribe_packet(["a/b"] * 10) + publish_packet("t/x", b"y" * 300)
              + publish_packet("t/z", b"", qos=1) + b"\xc0\x00")  # PINGREQ
    _read_all(stream, {8: 1000, 3: 1000, 1: 1000}, sizes)
    with pytest.raises(PacketTooLarge):
        _read_all(stream, {8: 50}, sizes)  # the SUBSCRIBE announces more than 50 bytes
    with pytest.raises(PacketTooLarge):
        _read_all(subscribe_packet(["f"] * 200_000), {8: 65536}, [1])  # refused at its header
    with pytest.raises(BadTopic):
        _read_all(stream + publish_packet("t/+", b"x"), {}, sizes)
    with pytest.raises(BadTopic):
        _read_all(publish_packet(b"t/\x00", b"x"), {}, sizes)


class _Trickle(_Bytes):
    """Hands out ``data``, but only ``open_until`` bytes of it until ``more`` is set (a sender that stopped)."""

    def __init__(self, data: bytes, open_until: int) -> None:
        super().__init__(data)
        self.open_until, self.given, self.more = open_until, 0, asyncio.Event()

    async def read(self, n: int = -1) -> bytes:
        if self.given + n > self.open_until:
            await self.more.wait()
        self.given += n
        return await super().read(n)


def test_a_large_body_is_read_in_pieces_charged_to_the_login_until_it_is_complete() -> None:
    body = bytes(range(256)) * 1024  # 256 KiB: four pieces
    budget = PartialBudget(8 * READ_CHUNK)

    async def go() -> None:
        reader = _Trickle(body, 2 * READ_CHUNK)
        gate = PacketGate(reader, lambda t: 0, lambda: "test")
        gate.budget = budget
        read = asyncio.ensure_future(gate.read(len(body)))
        await asyncio.sleep(0.01)
        assert budget.held == 3 * READ_CHUNK  # two pieces arrived, the third is charged while it is awaited
        reader.more.set()
        assert await read == body
        assert budget.held == 0
    asyncio.run(go())


def test_a_connection_that_would_overdraw_its_logins_budget_is_refused_and_the_budget_freed() -> None:
    budget = PartialBudget(3 * READ_CHUNK)

    async def go() -> None:
        stuck = _Trickle(b"x" * 4 * READ_CHUNK, 2 * READ_CHUNK)  # a half-sent 256 KiB body on one connection
        first = PacketGate(stuck, lambda t: 0, lambda: "first")
        first.budget = budget
        held = asyncio.ensure_future(first.read(4 * READ_CHUNK))
        await asyncio.sleep(0.01)
        second = PacketGate(_Bytes(b"y" * 2 * READ_CHUNK), lambda t: 0, lambda: "second")
        second.budget = budget
        with pytest.raises(PacketStalled, match="limit"):
            await second.read(2 * READ_CHUNK)  # its second piece would take the login over 3 pieces
        assert budget.held == 3 * READ_CHUNK  # the refused one gave back what it had
        held.cancel()
        with pytest.raises(asyncio.CancelledError):
            await held
        assert budget.held == 0
    asyncio.run(go())


def test_a_large_body_that_stops_arriving_is_closed_after_the_piece_timeout() -> None:
    budget = PartialBudget(8 * READ_CHUNK)

    async def go() -> None:
        gate = PacketGate(_Trickle(b"z" * 4 * READ_CHUNK, READ_CHUNK), lambda t: 0, lambda: "test")
        gate.budget, gate.piece_timeout = budget, 0.05
        with pytest.raises(PacketStalled, match="did not arrive within 0.05 s"):
            await asyncio.wait_for(gate.read(4 * READ_CHUNK), 5)
        assert budget.held == 0
    asyncio.run(go())


@pytest.mark.parametrize("doc", ["docs/safety.md", "broker/README.md"])
def test_every_limit_is_documented(doc: str) -> None:
    text = (ROOT / doc).read_text()
    missing = [name for name in BrokerLimits.names()
               if not re.search(rf"`{name}`|`{name.rsplit('_', 1)[0]}_", text)]
    assert not missing, f"{doc} does not list {missing}"


def test_a_client_with_nothing_waiting_takes_one_message_larger_than_its_queue() -> None:
    """A 4 MB map under max_payload but over max_queued_bytes (2 MiB) must still reach an idle client."""
    limits, box = BrokerLimits(), Outbox()
    big = 4_000_000
    assert big > limits.max_queued_bytes
    assert box.admit(big, 0, 0.0, limits) is Verdict.SEND
    assert box.admit(big, 0, 0.1, limits) is Verdict.DROP  # the next waits for the first to be written
    assert box.admit(1000, 500, 0.1, limits) is Verdict.DROP  # over the limit while the big one waits
    box.done(big)
    assert box.admit(big, 0, 0.2, limits) is Verdict.SEND
    box.done(big)
    assert box.admit(big, 100, 0.3, limits) is Verdict.DROP  # something still in the socket: the limit holds
