"""Pure logic of issue 13 items 4 and 8: sender ids in requests and reports, access reports, client-side filtering.

The integration tests (tests/integration/test_visible_refusals.py) show the same against a real broker and
bridge; these pin the wire format and the decisions without one.
"""

from __future__ import annotations

import queue

import orjson
import pytest

from roslink_mqtt.bridge.core.access import access_reports, cleared_reports
from roslink_mqtt.client import RobotClient, RobotError
from roslink_mqtt.client.commands import CommandStreams
from roslink_mqtt.config import load_fleet
from roslink_mqtt.protocol import (
    AccessReport,
    ErrorReport,
    MessageId,
    ProtocolError,
    decode,
    encode_message,
    error_reply,
    sender_id,
)
from roslink_mqtt.protocol.control import pop_generic_sender
from roslink_mqtt.topics import TopicTree
from tests.support.broker_setup import write_fleet


def test_envelope_names_its_sender() -> None:
    data = encode_message(MessageId.TWIST, {"lx": 0.1}, sequence_number=5, client_id="alice-sdk-1")
    assert orjson.loads(data)["client_id"] == "alice-sdk-1"
    assert decode(data, MessageId.TWIST).client_id == "alice-sdk-1"
    assert decode(encode_message(MessageId.TWIST, {}), MessageId.TWIST).client_id is None
    assert "client_id" not in orjson.loads(encode_message(MessageId.TWIST, {}))  # absent unless given
    for bad in ("", "x" * 129, 7):
        body = {"message_id": 100, "payload": {}, "client_id": bad}
        with pytest.raises(ProtocolError, match="client_id: expected a string of 1..128"):
            decode(orjson.dumps(body), MessageId.TWIST)


def test_error_reports_repeat_the_sender() -> None:
    body = error_reply("roslink/t/from/a/cmd/twist", "bad", message_id=100, sequence_number=3, client_id="c1")
    assert orjson.loads(body) == {"topic": "roslink/t/from/a/cmd/twist", "error": "bad", "message_id": 100,
                                  "sequence_number": 3, "client_id": "c1"}
    assert ErrorReport.from_json(body).client_id == "c1"
    assert "client_id" not in orjson.loads(error_reply("t", "x"))
    assert RobotError.from_json("turtle1", orjson.loads(body)).client_id == "c1"


def test_sender_id_is_read_from_every_kind_of_request() -> None:
    assert sender_id(encode_message(MessageId.ARM, {}, client_id="a")) == "a"
    assert sender_id(orjson.dumps({"id": "1", "args": {}, "client_id": "b"})) == "b"  # call, offer, response
    assert sender_id(orjson.dumps({"data": True, "$client_id": "c"})) == "c"  # generic ROS JSON
    assert sender_id(orjson.dumps({"client_id": "field", "$client_id": "c"})) == "c"  # a ROS field never wins
    for payload in (b"", b"not json", b"[1]", orjson.dumps({"data": True}), orjson.dumps({"client_id": 5})):
        assert sender_id(payload) is None
    big = orjson.dumps({"client_id": "a", "data": "x" * 70_000})  # not parsed twice on the refusal path
    assert sender_id(big) is None
    body = {"data": True, "$client_id": "c"}
    assert pop_generic_sender(body) == "c" and body == {"data": True}
    with pytest.raises(ProtocolError):
        pop_generic_sender({"$client_id": ""})


def test_sdk_commands_and_calls_carry_the_client_id() -> None:
    streams = CommandStreams(TopicTree(), "alice", client_id="alice-sdk-9")
    _, data, _ = streams.build("turtle1", "twist", {"lx": 0.1})
    assert orjson.loads(data)["client_id"] == "alice-sdk-9"
    _, data, _ = streams.build("turtle1", "lights", {"data": True})
    assert orjson.loads(data) == {"data": True, "$client_id": "alice-sdk-9"}


def test_access_reports_follow_the_fleet(tmp_path) -> None:
    fleet = load_fleet(write_fleet(tmp_path))  # the demo fleet plus a read-only service 'status'
    topics = TopicTree(fleet.prefix)
    reports = {topic: AccessReport.from_json(body) for topic, body in access_reports(fleet, "turtle1", topics).items()}
    assert reports == {
        "roslink/turtle1/to/admin/access": AccessReport("operator", ("reset", "status"), ("fibonacci",), True, True),
        "roslink/turtle1/to/alice/access": AccessReport("operator", ("reset", "status"), ("fibonacci",), True, True),
        "roslink/turtle1/to/bob/access": AccessReport("viewer", ("status",), (), True),
    }
    assert not reports["roslink/turtle1/to/bob/access"].may_send_goal("fibonacci")
    bob = reports["roslink/turtle1/to/bob/access"]
    assert bob.may_call("status") and not bob.may_call("reset") and not bob.operator
    assert reports["roslink/turtle1/to/alice/access"].may_call("anything")  # the bridge answers unknown names
    without_bob = load_fleet(write_fleet(tmp_path, name="less.yaml", edit=lambda t: t.replace(
        "      - {key: demo-key-turtle1, role: viewer}\n", "      - {key: demo-key-turtle2, role: viewer}\n")))
    assert cleared_reports(fleet, without_bob, "turtle1", topics) == ["roslink/turtle1/to/bob/access"]
    with pytest.raises(ProtocolError, match="role"):
        AccessReport.from_json(b'{"role": "king"}')


def test_a_client_shows_its_own_reports_and_those_without_a_sender() -> None:
    errors: queue.Queue[RobotError] = queue.Queue()
    client = RobotClient("alice", "x", client_id="alice-me", on_error=errors.put)  # never connected: no network
    try:
        topic = "roslink/turtle1/to/alice/error"
        for cid in ("alice-me", "alice-other", None):
            body = {"topic": "roslink/turtle1/from/alice/fly", "error": f"for {cid}"}
            if cid is not None:
                body["client_id"] = cid
            client._on_to_user(topic, orjson.dumps(body), False)
        seen = sorted(errors.get(timeout=2).error for _ in range(2))
        assert seen == ["for None", "for alice-me"]
        assert errors.empty() and [e.error for e in client.recent_errors] == ["for alice-me", "for None"]
        client.all_errors = True  # a dashboard (roslink-mqtt monitor) shows the user's reports from every program
        client._on_to_user(topic, orjson.dumps({"topic": "t", "error": "theirs", "client_id": "alice-other"}), False)
        assert errors.get(timeout=2).error == "theirs"
    finally:
        client.close()
