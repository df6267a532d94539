"""``roslink-mqtt record``'s pure parts: the JSON schemas (protocol/schemas.py) and how each payload is written
(client/recorder.py), checked by reading the file back with the mcap reader. No broker: the recorder is fed."""

from __future__ import annotations

import base64
import dataclasses
import json
from pathlib import Path

import cbor2
import orjson
from mcap.reader import make_reader

from roslink_mqtt.client.recorder import Recorder
from roslink_mqtt.protocol.description import EXAMPLE, StateEntry
from roslink_mqtt.protocol.schemas import DRAFT, ros_schema, schema_for
from roslink_mqtt.topics import TopicTree

T = TopicTree()
DESCRIPTION = dataclasses.replace(EXAMPLE, robot="turtle1", state=(
    *EXAMPLE.state, StateEntry("pose_cbor", ros_type="std_msgs/msg/Float32", encoding="cbor")))


def _schema(topic: str) -> dict:
    parsed = T.parse(topic)
    assert parsed is not None
    return schema_for(parsed, topic, DESCRIPTION)


def test_each_kind_of_topic_gets_the_schema_of_its_declaration() -> None:
    assert _schema(T.heartbeat("turtle1"))["title"] == "roslink.heartbeat"
    ack = _schema(T.state("turtle1", "ack"))
    assert ack["title"] == "roslink.ack" and ack["properties"]["payload"]["properties"]["result"]["type"] == "integer"
    assert _schema(T.state("turtle1", "camera"))["title"] == "foxglove.CompressedImage"
    voltage = _schema(T.state("turtle1", "battery_voltage"))
    assert voltage["title"] == "std_msgs/msg/Float32" and voltage["properties"]["data"] == {"type": "number"}
    assert _schema(T.state("turtle1", "control"))["properties"]["holder"]["anyOf"][1] == {"type": "null"}
    error = _schema(T.error("turtle1", "bob"))
    assert error["title"] == "ErrorReport" and "error" in error["required"]
    assert _schema(T.state("turtle1", "unknown_thing")) == {"$schema": DRAFT, "type": "object",
                                                             "title": "roslink/turtle1/state/unknown_thing"}


def test_ros_layouts_become_nested_schemas_with_arrays() -> None:
    types = {"x/msg/T": {"covariance": "float64[36]", "names": "string[]", "label": "string<=10", "count": "uint8",
                         "stamp": {"type": "builtin_interfaces/msg/Time", "fields": {"sec": "int32"}}}}
    schema = ros_schema("x/msg/T", types)
    assert schema is not None
    props = schema["properties"]
    assert props["covariance"] == {"type": "array", "items": {"type": "number"}}
    assert props["names"] == {"type": "array", "items": {"type": "string"}}
    assert props["label"] == {"type": "string"} and props["count"] == {"type": "integer"}
    assert props["stamp"]["properties"]["sec"] == {"type": "integer"}
    assert ros_schema("y/msg/Unknown", types) is None


def test_json_cbor_and_raw_payloads_are_written_as_json_channels(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    recorder = Recorder(url="mqtt://127.0.0.1:1", username="bob", password="x", robots=["turtle1"], out=out)
    recorder.write(T.state("turtle1", "description"), DESCRIPTION.to_json(), 1_000, retained=True)
    recorder.write(T.state("turtle1", "description"), DESCRIPTION.to_json(), 1_001, retained=True)  # twice: once
    recorder.write(T.state("turtle1", "pose_cbor"), cbor2.dumps({"data": 1.5, "raw": b"\x00\x01"}), 2_000)
    jpeg = b"\xff\xd8\xff\xe0fake"
    recorder.write(T.state("turtle1", "camera"), jpeg, 3_000_000_123)
    stamped = {"header": {"stamp": {"sec": 7, "nanosec": 5}}, "data": 2.0}
    recorder.write(T.state("turtle1", "battery_voltage"), orjson.dumps(stamped), 4_000)
    recorder.write(T.state("turtle2", "battery_voltage"), orjson.dumps(stamped), 5_000)  # not a robot recorded
    recorder.write(T.state("turtle1", "battery_voltage"), b"", 6_000)  # a cleared retained message
    recorder.close()
    with out.open("rb") as f:
        got = [(channel.topic, schema.name, message)
               for schema, channel, message in make_reader(f).iter_messages(log_time_order=False)]
    assert [t for t, _, _ in got] == [T.state("turtle1", n) for n in ("description", "pose_cbor", "camera",
                                                                    "battery_voltage")]
    _, _, cbor_message = got[1]
    assert json.loads(cbor_message.data) == {"data": 1.5, "raw": base64.b64encode(b"\x00\x01").decode()}
    _, image_schema, image = got[2]
    decoded = json.loads(image.data)
    assert image_schema == "foxglove.CompressedImage" and decoded["format"] == "jpeg"
    assert base64.b64decode(decoded["data"]) == jpeg and decoded["timestamp"] == {"sec": 3, "nsec": 123}
    _, _, voltage = got[3]
    assert voltage.publish_time == 7 * 10**9 + 5 and voltage.log_time == 4_000  # the message's own stamp


def test_play_renames_a_robot_in_its_topics_and_in_the_bodies_that_name_it(tmp_path: Path) -> None:
    from roslink_mqtt.client.player import frames

    out = tmp_path / "r.mcap"
    recorder = Recorder(url="mqtt://127.0.0.1:1", username="bob", password="x", robots=["turtle1"], out=out)
    heartbeat = {"message_id": 0, "payload": {"type": 1, "name": "turtle1", "system_status": 4}}
    recorder.write(T.state("turtle1", "description"), DESCRIPTION.to_json(), 1_000_000_000, retained=True)
    recorder.write(T.heartbeat("turtle1"), orjson.dumps(heartbeat), 1_500_000_000)
    recorder.write(T.error("turtle1", "bob"), orjson.dumps({"topic": "x", "error": "no"}), 1_600_000_000)
    recorder.write(T.state("turtle1", "battery_voltage"), b'{"data": 1.0}', 2_000_000_000)
    recorder.close()
    played = list(frames(out, T, {"turtle1": "turtle2"}))
    assert [(f.topic, f.retain, f.at) for f in played] == [
        (T.state("turtle2", "description"), True, 0.0), (T.heartbeat("turtle2"), True, 0.5),
        (T.state("turtle2", "battery_voltage"), False, 1.0)]  # bob's error is not played: it was his
    assert json.loads(played[0].payload)["robot"] == "turtle2"
    assert json.loads(played[1].payload)["payload"]["name"] == "turtle2"
    assert played[2].payload == b'{"data": 1.0}'


def test_a_video_stream_is_written_as_compressed_video_only_when_named(tmp_path: Path) -> None:
    """The description's video entry (EXAMPLE's front_camera): ``foxglove.CompressedVideo`` stamped with the capture
    time; a recorder not asked for it (``--topic``) learns the description all the same and leaves the frames out."""
    from roslink_mqtt.protocol.video import VideoFrame

    frame = VideoFrame("h264", True, 3, 12.5, 320, 240, "avc1.42c01f", b"\x00\x00\x01\x67\x42")
    for wanted, expected in ((["front_camera"], 1), ([], 1), (["global_motion"], 0)):
        out = tmp_path / f"v{len(wanted)}{expected}.mcap"
        recorder = Recorder(url="mqtt://127.0.0.1:1", username="bob", password="x", robots=["turtle1"], out=out,
                            topics=wanted)
        recorder.write(T.state("turtle1", "description"), DESCRIPTION.to_json(), 1_000, retained=True)
        recorder.write(T.state("turtle1", "front_camera"), frame.to_bytes(), 2_000)
        recorder.close()
        assert recorder.channels.descriptions["turtle1"].video[0].name == "front_camera"  # learnt either way
        if not out.exists():  # nothing was written at all
            assert expected == 0, wanted
            continue
        with out.open("rb") as f:
            got = [(schema.name, message) for schema, channel, message in make_reader(f).iter_messages()
                   if channel.topic == T.state("turtle1", "front_camera")]
        assert len(got) == expected, wanted
        if got:
            schema, message = got[0]
            decoded = json.loads(message.data)
            assert schema == "foxglove.CompressedVideo" and decoded["format"] == "h264"
            assert base64.b64decode(decoded["data"]) == frame.data and decoded["timestamp"] == {"sec": 12,
                                                                                               "nsec": 500_000_000}
            assert message.publish_time == 12_500_000_000 and message.log_time == 2_000
