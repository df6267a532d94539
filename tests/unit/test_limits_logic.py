"""The pure logic behind the broker's limits: retained index and quota, outbox, packet gate, docs drift."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.broker.acl import topic_matches
from roslink_mqtt.broker.guard import BadTopic, PacketGate, PacketTooLarge
from roslink_mqtt.broker.limits import BrokerLimits, RetainedIndex, RetainedQuota
from roslink_mqtt.broker.outbox import Outbox, Verdict
from tests.support.rawmqtt import connect_packet, publish_packet, subscribe_packet

ROOT = Path(__file__).resolve().parents[2]
LEVELS = st.sampled_from(["a", "b", "roslink", "$SYS", "x y", ""])
TOPICS = st.lists(LEVELS, min_size=1, max_size=4).map("/".join)
FILTERS = st.lists(st.sampled_from(["a", "b", "roslink", "$SYS", "+", ""]), min_size=0, max_size=3).flatmap(
    lambda head: st.sampled_from(["", "/#"]).map(lambda tail: "/".join(head) + tail if head else "#"))


@given(st.sets(TOPICS, max_size=20), FILTERS)
def test_retained_index_finds_exactly_what_mqtt_matching_finds(topics: set[str], topic_filter: str) -> None:
    index = RetainedIndex()
    for topic in topics:
        index.add(topic)
    expected = {t for t in topics if topic_matches(topic_filter.split("/"), t.split("/"))}
    assert set(index.matches(topic_filter)) == expected
    for topic in topics:
        index.discard(topic)
    assert len(index) == 0 and index._root == {}, "empty branches must be pruned"


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
