"""Frames cut from a byte stream in one pass (roslink_mqtt/broker/frames.py): the packets amqtt's own encoder writes
come out whole and in order however the stream is split; the packet gate's refusals hold."""

from __future__ import annotations

import pytest
from amqtt.mqtt.pingreq import PingReqPacket
from amqtt.mqtt.puback import PubackPacket
from amqtt.mqtt.publish import PublishPacket
from amqtt.mqtt.subscribe import SubscribePacket
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.broker.frames import FrameParser, Malformed, read_publish
from roslink_mqtt.broker.guard import PUBLISH, SUBSCRIBE, BadTopic, PacketTooLarge

pytestmark = pytest.mark.unit


def parser(limits: dict[int, int] | None = None) -> FrameParser:
    return FrameParser(lambda kind: (limits or {}).get(kind, 0), lambda: "test")


def publish(topic: str, payload: bytes, qos: int = 0, retain: bool = False, pid: int | None = None) -> bytes:
    return bytes(PublishPacket.build(topic, payload, pid if qos else None, False, qos, retain).to_bytes())


STREAM = [
    publish("roslink/k/turtle1/state/pose", b'{"x":1}'),
    bytes(SubscribePacket.build([("roslink/k/+/cmd/#", 1)], 7).to_bytes()),
    publish("roslink/k/turtle1/hb", b"h" * 300, qos=1, retain=True, pid=9),
    bytes(PingReqPacket().to_bytes()),
    publish("t", b"x" * 20000, qos=2, pid=65535),  # a three-byte remaining length
    bytes(PubackPacket.build(9).to_bytes()),
    publish("empty", b""),
]


def test_a_stream_of_packets_comes_out_frame_by_frame_with_their_fields() -> None:
    frames = parser().feed(b"".join(STREAM))
    assert [f.kind for f in frames] == [3, 8, 3, 12, 3, 4, 3]
    assert [f.body for f in frames] == [p[len(p) - len(f.body):] for p, f in zip(STREAM, frames, strict=True)]
    first, retained, big = (read_publish(frames[i].flags, frames[i].body) for i in (0, 2, 4))
    assert (first.topic, first.qos, first.retain, first.packet_id, first.payload) == (
        "roslink/k/turtle1/state/pose", 0, False, None, b'{"x":1}')
    assert (retained.qos, retained.retain, retained.packet_id, retained.payload) == (1, True, 9, b"h" * 300)
    assert (big.qos, big.packet_id, len(big.payload)) == (2, 65535, 20000)
    assert frames[1].flags == 0b0010  # SUBSCRIBE's fixed flags (MQTT-3.8.1-1)
    assert read_publish(frames[6].flags, frames[6].body).payload == b""


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=5000), max_size=40))
def test_however_the_bytes_arrive_the_same_frames_come_out_in_order(cuts: list[int]) -> None:
    data = b"".join(STREAM)
    p, frames, at = parser(), [], 0
    for cut in cuts:
        frames += p.feed(data[at:at + cut])
        at += cut
        assert p.held <= len(data)
    frames += p.feed(data[at:])
    assert [(f.kind, f.body) for f in frames] == [(f.kind, f.body) for f in parser().feed(data)]
    assert p.held == 0 and p.announced == 0


def test_an_incomplete_frame_says_how_large_it_will_be_once_its_header_is_in() -> None:
    p, big = parser(), STREAM[4]
    assert p.feed(big[:2]) == [] and p.announced == 0  # the remaining length is not complete yet
    assert p.feed(big[2:100]) == [] and p.announced == len(big) and p.held == 100
    assert len(p.feed(big[100:])) == 1 and p.announced == 0 and p.held == 0


def test_a_frame_over_its_limit_is_refused_from_its_header_before_its_body_arrives() -> None:
    p = parser({PUBLISH: 1000, SUBSCRIBE: 10})
    assert len(p.feed(publish("a", b"x" * 900))) == 1
    with pytest.raises(PacketTooLarge):
        p.feed(publish("a", b"x" * 2000)[:4])  # header only
    with pytest.raises(PacketTooLarge):
        parser({SUBSCRIBE: 10}).feed(STREAM[1])


def test_bad_topics_and_malformed_frames_end_the_connection() -> None:
    for topic in ("a/+/b", "a/#", "a\0b"):
        raw = bytearray(publish("a" * len(topic), b"p"))
        raw[4:4 + len(topic)] = topic.encode()
        with pytest.raises(BadTopic):
            parser().feed(bytes(raw))
    with pytest.raises(Malformed):
        parser().feed(b"\x30\xff\xff\xff\xff\x01")  # five length bytes
    with pytest.raises(Malformed):
        parser().feed(b"\x30\x03\x00\x09a")  # a topic longer than the frame
    with pytest.raises(Malformed):
        read_publish(0b0110, b"\x00\x01a\x00\x01")  # QoS 3
    with pytest.raises(Malformed):
        read_publish(0b0010, b"\x00\x01a")  # QoS 1 without its packet id
    with pytest.raises(Malformed):
        read_publish(0, b"\x00\x02\xff\xfe")  # not UTF-8
