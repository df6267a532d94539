"""SubscriptionIndex (roslink_mqtt/broker/subscriptions.py): the embedded broker's filter tree agrees with
amqtt's own matcher on every topic and filter, and forgets what it is told to."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest
from amqtt.broker import Broker
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.broker.subscriptions import SubscriptionIndex

_STOCK = SimpleNamespace(logger=logging.getLogger("stock-matcher"))


def stock_matches(topic: str, topic_filter: str) -> bool:
    """amqtt 0.12.1's matcher, the semantics every delivery had before the index."""
    return Broker._matches(_STOCK, topic, topic_filter)  # type: ignore[arg-type]


LEVEL = st.sampled_from(["roslink", "turtle1", "turtle2", "state", "from", "alice", "", "$SYS", "x"])
TOPIC = st.lists(LEVEL, min_size=1, max_size=5).map("/".join)


@st.composite
def topic_filter(draw: st.DrawFn) -> str:
    parts = draw(st.lists(st.one_of(LEVEL, st.just("+")), min_size=1, max_size=5))
    if draw(st.booleans()):
        parts.append("#")
    return "/".join(parts)


@settings(max_examples=400, deadline=None)
@given(st.lists(topic_filter(), max_size=30, unique=True), st.lists(TOPIC, min_size=1, max_size=10))
def test_the_index_finds_exactly_the_filters_amqtt_matches(filters: list[str], topics: list[str]) -> None:
    index = SubscriptionIndex()
    for f in filters:
        index.add(f)
    assert len(index) == len(filters)
    for topic in topics:
        expected = sorted(f for f in filters if stock_matches(topic, f))
        assert sorted(index.matches(topic)) == expected, topic


def test_wildcards_the_standard_names() -> None:
    index = SubscriptionIndex()
    for f in ("roslink/+/heartbeat", "roslink/turtle1/#", "#", "+/+", "roslink/turtle1/state/odom", "$SYS/#"):
        index.add(f)
    assert sorted(index.matches("roslink/turtle1/heartbeat")) == ["#", "roslink/+/heartbeat", "roslink/turtle1/#"]
    assert sorted(index.matches("roslink/turtle1")) == ["#", "+/+", "roslink/turtle1/#"]  # a/# matches a
    assert index.matches("$SYS/broker/load") == ["$SYS/#"]  # never '#' or '+/+' for a $ topic (MQTT-4.7.2-1)


def test_discard_forgets_the_filter_and_prunes_its_branch() -> None:
    index = SubscriptionIndex()
    index.add("roslink/turtle1/from/+/cmd/twist")
    index.add("roslink/turtle1/from/alice/#")
    index.add("roslink/turtle1/from/alice/#")  # twice: still one
    assert len(index) == 2
    index.discard("roslink/turtle1/from/+/cmd/twist")
    index.discard("roslink/never/added")
    assert "roslink/turtle1/from/+/cmd/twist" not in index
    assert index.matches("roslink/turtle1/from/alice/cmd/twist") == ["roslink/turtle1/from/alice/#"]
    index.discard("roslink/turtle1/from/alice/#")
    assert len(index) == 0 and index._root == {}  # nothing left behind


@pytest.mark.parametrize("size", [0, 5, 127 - 12, 200, 20_000, 3_000_000])
@pytest.mark.parametrize("retain", [False, True])
def test_the_direct_qos0_publish_is_byte_for_byte_what_amqtt_sends(size: int, retain: bool) -> None:
    """hardened fix 25 writes QoS 0 deliveries itself: the bytes must equal amqtt's own PUBLISH packet."""
    from amqtt.mqtt.publish import PublishPacket

    from roslink_mqtt.broker.hardened import publish_packet_qos0

    payload = bytes(i % 251 for i in range(size))
    topic = "roslink/turtle1/state/global_motion"
    assert publish_packet_qos0(topic, payload, retain) == PublishPacket.build(topic, payload, None, False, 0,
                                                                               retain).to_bytes()
