"""The embedded broker's routing tables (roslink_mqtt/broker/subscriptions.py): the subscription tree agrees
with amqtt's own matcher on every topic and filter, the retained tree with MQTT's matching, and both behave as
the dicts amqtt's code reads and writes, forgetting what they are told to."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest
from amqtt.broker import Broker
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.broker.acl import topic_matches
from roslink_mqtt.broker.subscriptions import RetainedTable, SubscriptionTable

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


@settings(max_examples=200, deadline=None)  # 200 random cases a run keep the unit suite in seconds
@given(st.lists(topic_filter(), max_size=30, unique=True), st.lists(TOPIC, min_size=1, max_size=10))
def test_the_table_finds_exactly_the_filters_amqtt_matches(filters: list[str], topics: list[str]) -> None:
    table = SubscriptionTable()
    for f in filters:
        table[f] = [f"subscribers of {f}"]
    assert len(table) == len(filters)
    assert sorted(table) == sorted(filters)
    for topic in topics:
        expected = sorted((f, [f"subscribers of {f}"]) for f in filters if stock_matches(topic, f))
        assert sorted(table.matches(topic)) == expected, topic


def _filters(found: list[tuple[str, object]]) -> list[str]:
    return sorted(f for f, _subscribers in found)


def test_wildcards_the_standard_names() -> None:
    table = SubscriptionTable()
    for f in ("roslink/+/heartbeat", "roslink/turtle1/#", "#", "+/+", "roslink/turtle1/state/odom", "$SYS/#"):
        table[f] = []
    assert _filters(table.matches("roslink/turtle1/heartbeat")) == ["#", "roslink/+/heartbeat", "roslink/turtle1/#"]
    assert _filters(table.matches("roslink/turtle1")) == ["#", "+/+", "roslink/turtle1/#"]  # a/# matches a
    assert _filters(table.matches("$SYS/broker/load")) == ["$SYS/#"]  # never '#' or '+/+' for $ (MQTT-4.7.2-1)


def test_the_table_is_the_mapping_amqtt_uses_and_prunes_what_it_forgets() -> None:
    """amqtt's add_subscription and _del_all_subscriptions read and write ``_subscriptions`` as a dict."""
    table = SubscriptionTable()
    twist, mine = "roslink/turtle1/from/+/cmd/twist", "roslink/turtle1/from/alice/#"
    if twist not in table:
        table[twist] = []
    table[twist].append(("session", 1))  # amqtt appends to the list it finds
    table[mine] = [("a", 0)]
    table[mine] = [("b", 0)]  # replaced: still one entry
    assert len(table) == 2 and table[twist] == [("session", 1)] and table.get("roslink/nope") is None
    del table[twist]
    with pytest.raises(KeyError):
        del table["roslink/never/added"]
    with pytest.raises(KeyError):
        table["roslink/turtle1"]  # a node on the way to a filter is not a filter
    assert twist not in table
    assert table.matches("roslink/turtle1/from/alice/cmd/twist") == [(mine, [("b", 0)])]
    for f in table:  # iterating a snapshot while deleting, as _del_all_subscriptions does
        del table[f]
    assert len(table) == 0 and table._root == {}  # nothing left behind
    table["x"] = []
    table.clear()
    assert len(table) == 0 and list(table) == []


RETAINED_LEVELS = st.sampled_from(["a", "b", "roslink", "$SYS", "x y", ""])
RETAINED_TOPICS = st.lists(RETAINED_LEVELS, min_size=1, max_size=4).map("/".join)
RETAINED_FILTERS = st.lists(st.sampled_from(["a", "b", "roslink", "$SYS", "+", ""]), min_size=0, max_size=3).flatmap(
    lambda head: st.sampled_from(["", "/#"]).map(lambda tail: "/".join(head) + tail if head else "#"))


@given(st.sets(RETAINED_TOPICS, max_size=20), RETAINED_FILTERS)
def test_the_retained_table_finds_exactly_what_mqtt_matching_finds(topics: set[str], topic_filter: str) -> None:
    table = RetainedTable()
    for topic in topics:
        table[topic] = f"message on {topic}"
    expected = {(t, f"message on {t}") for t in topics if topic_matches(topic_filter.split("/"), t.split("/"))}
    assert set(table.matches(topic_filter)) == expected
    for topic in topics:
        del table[topic]
    assert len(table) == 0 and table._root == {}, "empty branches must be pruned"


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
