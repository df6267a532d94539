"""Rule encodings (issue 17): json (today's bytes, unchanged), cbor (typed arrays kept binary), raw (the image).

Each ROS message is built in-process, serialized by the compiled rule, decoded as a client would (the SDK's
:mod:`roslink_mqtt.client.encodings`), and turned back into the same ROS message. Run with ``-s`` to see the
size table (bytes per encoding for a 640×480 rgb8 Image, a ~1 MB PointCloud2, a 2000×2000 OccupancyGrid).
"""

from __future__ import annotations

import array
import math
import time
from dataclasses import replace

import orjson
import pytest

from roslink_mqtt.client.encodings import decode_state, image_format, sniff, to_json_form
from roslink_mqtt.client.subscriptions import parse_state_item
from roslink_mqtt.config import ConfigError
from roslink_mqtt.protocol.description import RobotDescription
from roslink_mqtt.topics import TopicTree
from tests.support.one_robot import one_robot_fleet

pytest.importorskip("rclpy")
cbor2 = pytest.importorskip("cbor2")

import numpy as np  # noqa: E402
from nav_msgs.msg import OccupancyGrid, Odometry  # noqa: E402
from sensor_msgs.msg import CompressedImage, Image, LaserScan, PointCloud2, PointField  # noqa: E402

from roslink_mqtt.bridge.ros.convert import converter_for  # noqa: E402
from roslink_mqtt.bridge.ros.description import build_description, ros_fields_of  # noqa: E402
from roslink_mqtt.bridge.ros.rules import RuleError, compile_rules  # noqa: E402

JPEG = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + bytes(range(256)) * 4 + b"\xff\xd9"
PNG = b"\x89PNG\r\n\x1a\n" + bytes(200)




def rule(ros_type: str, encoding: str | None, topic: str = "state/x", extra: str = "") -> str:
    enc = f", encoding: {encoding}" if encoding else ""
    return f"{{direction: ros_to_mqtt, ros_topic: /x, ros_type: {ros_type}, mqtt_topic: {topic}{enc}{extra}}}"


def serializer(ros_type: str, encoding: str | None, extra: str = ""):
    outbound, _ = compile_rules(one_robot_fleet(rule(ros_type, encoding, extra=extra)).robots["r1"], TopicTree())
    return outbound[0].serialize


# -- messages ----------------------------------------------------------------------------------------------

def image(width: int = 640, height: int = 480) -> Image:
    rng = np.random.default_rng(1)
    msg = Image(height=height, width=width, encoding="rgb8", step=width * 3)
    msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec = "camera", 12, 345
    msg.data = rng.integers(0, 256, width * height * 3, dtype=np.uint8).tobytes()
    return msg


def compressed(data: bytes = JPEG, fmt: str = "jpeg") -> CompressedImage:
    msg = CompressedImage(format=fmt)
    msg.header.frame_id = "camera"
    msg.data = data
    return msg


def cloud(points: int = 65536) -> PointCloud2:
    """x, y, z, intensity float32 (16 bytes a point): 65536 points ≈ 1 MB."""
    rng = np.random.default_rng(2)
    fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
              for i, n in enumerate("xyz")] + [PointField(name="intensity", offset=12, datatype=7, count=1)]
    msg = PointCloud2(height=1, width=points, fields=fields, is_bigendian=False, point_step=16,
                      row_step=16 * points, is_dense=True)
    msg.header.frame_id = "lidar"
    msg.data = rng.standard_normal(points * 4).astype(np.float32).tobytes()
    return msg


def grid(side: int = 2000) -> OccupancyGrid:
    rng = np.random.default_rng(3)
    msg = OccupancyGrid()
    msg.header.frame_id = "map"
    msg.info.resolution, msg.info.width, msg.info.height = 0.05, side, side
    msg.info.origin.position.x, msg.info.origin.orientation.w = -50.0, 1.0
    cells = rng.choice(np.array([-1, 0, 100], dtype=np.int8), side * side, p=[0.3, 0.6, 0.1])
    msg.data = cells.tolist() if side < 100 else array.array("b", cells.tobytes())
    return msg


def scan(beams: int = 720) -> LaserScan:
    msg = LaserScan(angle_min=-math.pi, angle_max=math.pi, angle_increment=2 * math.pi / beams, range_min=0.1,
                    range_max=30.0)
    msg.header.frame_id = "laser"
    ranges = np.linspace(0.5, 10.0, beams, dtype=np.float32)
    ranges[3], ranges[5], ranges[7] = np.inf, -np.inf, np.nan
    msg.ranges = ranges.tolist()
    msg.intensities = np.linspace(0, 1, beams, dtype=np.float32).tolist()
    return msg


def odometry() -> Odometry:
    msg = Odometry(child_frame_id="base_link")
    msg.header.frame_id, msg.header.stamp.sec = "odom", 7
    msg.pose.pose.position.x, msg.pose.pose.orientation.w = 1.25, 1.0
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = 0.5, -0.1
    msg.pose.covariance = [float(i) / 7 for i in range(36)]
    msg.twist.covariance[0] = math.nan
    return msg


MESSAGES = {
    "Image": ("sensor_msgs/msg/Image", lambda: image(64, 48)),
    "CompressedImage": ("sensor_msgs/msg/CompressedImage", compressed),
    "PointCloud2": ("sensor_msgs/msg/PointCloud2", lambda: cloud(256)),
    "OccupancyGrid": ("nav_msgs/msg/OccupancyGrid", lambda: grid(40)),
    "LaserScan": ("sensor_msgs/msg/LaserScan", scan),
    "Odometry": ("nav_msgs/msg/Odometry", odometry),
}


def same(a, b) -> bool:
    """Two ROS messages equal field by field, NaN equal to NaN (rclpy's == says NaN != NaN)."""
    conv = converter_for(type(a))
    return orjson.dumps(conv.to_dict(a)) == orjson.dumps(conv.to_dict(b))


def keys(value):
    if isinstance(value, dict):
        return {k: keys(v) for k, v in value.items()}
    if isinstance(value, list) and value and isinstance(value[0], dict):
        return [keys(v) for v in value]
    return None


# -- json: today's bytes -------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", MESSAGES)
def test_json_is_byte_identical_to_before(name: str) -> None:
    ros_type, make = MESSAGES[name]
    msg = make()
    expected = converter_for(type(msg)).to_json(msg)  # what a rule without `encoding` published before
    assert serializer(ros_type, None)(msg) == expected
    assert serializer(ros_type, "json")(msg) == expected
    assert sniff(expected) == "json"
    assert same(converter_for(type(msg)).from_dict(decode_state(expected)), msg)


# -- cbor -----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", MESSAGES)
def test_cbor_round_trips_and_matches_the_json_object(name: str) -> None:
    ros_type, make = MESSAGES[name]
    msg = make()
    payload = serializer(ros_type, "cbor")(msg)
    assert sniff(payload) == "cbor"
    decoded = decode_state(payload)
    as_json = to_json_form(decoded)
    conv = converter_for(type(msg))
    assert same(conv.from_dict(as_json), msg)
    # the same object the JSON encoding gives: same keys everywhere, same message once read back
    from_json = orjson.loads(serializer(ros_type, "json")(msg))
    assert keys(as_json) == keys(from_json)
    assert same(conv.from_dict(as_json), conv.from_dict(from_json))
    item = parse_state_item(payload, "r1", "x")  # what an SDK subscriber gets
    assert isinstance(item, dict) and to_json_form(item) == as_json


def test_cbor_keeps_arrays_binary() -> None:
    d = decode_state(serializer("sensor_msgs/msg/Image", "cbor")(image(8, 4)))
    assert isinstance(d["data"], bytes) and len(d["data"]) == 8 * 4 * 3
    assert d["header"] == {"stamp": {"sec": 12, "nanosec": 345}, "frame_id": "camera"}
    s = decode_state(serializer("sensor_msgs/msg/LaserScan", "cbor")(scan(16)))
    assert isinstance(s["ranges"], array.array) and s["ranges"].typecode == "f"
    assert math.isinf(s["ranges"][3]) and math.isnan(s["ranges"][7])
    g = decode_state(serializer("nav_msgs/msg/OccupancyGrid", "cbor")(grid(10)))
    assert g["data"].typecode == "b" and -1 in g["data"].tolist()
    o = decode_state(serializer("nav_msgs/msg/Odometry", "cbor")(odometry()))
    assert o["pose"]["covariance"].typecode == "d" and len(o["pose"]["covariance"]) == 36
    # the tags on the wire: float32 little-endian 85, sint8 72, float64 little-endian 86; uint8[] untagged
    raw = cbor2.loads(serializer("nav_msgs/msg/OccupancyGrid", "cbor")(grid(10)))
    assert raw["data"].tag == 72
    assert cbor2.loads(serializer("sensor_msgs/msg/LaserScan", "cbor")(scan(16)))["ranges"].tag == 85
    assert cbor2.loads(serializer("nav_msgs/msg/Odometry", "cbor")(odometry()))["pose"]["covariance"].tag == 86


def test_cbor_with_fields_selects_like_json() -> None:
    fields = ", fields: {x: pose.pose.position.x, cov: pose.covariance, frame: header.frame_id}"
    d = decode_state(serializer("nav_msgs/msg/Odometry", "cbor", fields)(odometry()))
    j = orjson.loads(serializer("nav_msgs/msg/Odometry", None, fields)(odometry()))
    assert to_json_form(d) == j


# -- raw --------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("data", "fmt"), [(JPEG, "jpeg"), (PNG, "png")])
def test_raw_is_the_image_itself(data: bytes, fmt: str) -> None:
    payload = serializer("sensor_msgs/msg/CompressedImage", "raw")(compressed(data, fmt))
    assert payload == data
    assert sniff(payload) == "raw" and image_format(payload) == fmt
    assert parse_state_item(payload, "r1", "camera") == {"format": fmt, "data": data}
    assert decode_state(payload, "raw") == {"format": fmt, "data": data}


# -- description -----------------------------------------------------------------------------------------------

def test_description_names_each_entry_encoding() -> None:
    f = one_robot_fleet(rule("sensor_msgs/msg/CompressedImage", "raw", "state/camera"),
              rule("sensor_msgs/msg/PointCloud2", "cbor", "state/cloud").replace("/x", "/cloud"),
              rule("nav_msgs/msg/Odometry", "json", "state/odom").replace("/x", "/odom"))
    desc = build_description(f.robots["r1"], ros_fields_of)
    body = orjson.loads(desc.to_json())
    by_name = {e["name"]: e for e in body["state"]}
    assert by_name["camera"]["encoding"] == "raw" and by_name["cloud"]["encoding"] == "cbor"
    assert "encoding" not in by_name["odom"]  # JSON goes without saying
    again = RobotDescription.from_json(desc.to_json())
    assert {e.name: e.encoding for e in again.state} == {"camera": "raw", "cloud": "cbor", "odom": None,
                                                          "ack": None}


# -- config errors ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("text", "fragment"), [
    (rule("nav_msgs/msg/Odometry", "msgpack"), "robots.r1.rules[0].encoding: expected one of json, cbor, raw, "
                                               'got "msgpack"'),
    (rule("sensor_msgs/msg/Image", "raw"), "the rule at line 8: encoding 'raw' publishes the image bytes alone, so "
                                           "it needs ros_type sensor_msgs/msg/CompressedImage, not "
                                           "sensor_msgs/msg/Image"),
    (rule("sensor_msgs/msg/CompressedImage", "raw", extra=", fields: {f: format}"), "cannot select fields"),
    (rule("sensor_msgs/msg/CompressedImage", "cbor", extra=", preset: image"), "preset 'image' publishes a "
                                                                               "ROSLink message, which is always JSON"),
    ("{direction: mqtt_to_ros, ros_topic: /l, ros_type: std_msgs/msg/Bool, mqtt_topic: lights, encoding: cbor}",
     "encoding 'cbor' applies to ros_to_mqtt rules only"),
])
def test_config_refuses_encodings_where_they_make_no_sense(text: str, fragment: str) -> None:
    with pytest.raises(ConfigError) as info:
        one_robot_fleet(text)
    assert fragment in str(info.value)
    assert "robots.yaml:" in str(info.value)


def test_config_accepts_json_on_a_command_and_defaults_to_json() -> None:
    f = one_robot_fleet("{direction: mqtt_to_ros, ros_topic: /l, ros_type: std_msgs/msg/Bool, mqtt_topic: lights, "
              "encoding: json}", rule("nav_msgs/msg/Odometry", None))
    assert [r.encoding for r in f.robots["r1"].rules] == ["json", "json"]


def test_bridge_refuses_a_raw_rule_built_past_the_loader() -> None:
    robot = one_robot_fleet(rule("sensor_msgs/msg/Image", None)).robots["r1"]
    robot = replace(robot, rules=(replace(robot.rules[0], encoding="raw"),))
    with pytest.raises(RuleError, match=r"rules\[0\] \(/x → state/x\): encoding 'raw' needs ros_type"):
        compile_rules(robot, TopicTree())


# -- sizes -----------------------------------------------------------------------------------------------------

def test_size_table() -> None:
    """Bytes on the wire per encoding for the issue's large messages (printed; run with -s)."""
    cases = [("640×480 rgb8 Image", "sensor_msgs/msg/Image", image()),
             ("PointCloud2, 65536 points × 16 B", "sensor_msgs/msg/PointCloud2", cloud()),
             ("2000×2000 OccupancyGrid", "nav_msgs/msg/OccupancyGrid", grid()),
             ("720-beam LaserScan", "sensor_msgs/msg/LaserScan", scan()),
             ("Odometry", "nav_msgs/msg/Odometry", odometry())]
    rows = []
    for label, ros_type, msg in cases:
        sizes, times = {}, {}
        for enc in ("json", "cbor"):
            ser = serializer(ros_type, enc)
            ser(msg)
            t0 = time.perf_counter()
            payload = ser(msg)
            times[enc] = (time.perf_counter() - t0) * 1000
            sizes[enc] = len(payload)
        rows.append((label, sizes["json"], sizes["cbor"], times["json"], times["cbor"]))
        if ros_type != "nav_msgs/msg/Odometry":
            assert sizes["cbor"] < sizes["json"]
    print("\n| message | json bytes | cbor bytes | cbor/json | json ms | cbor ms |\n|---|---|---|---|---|---|")
    for label, js, cb, tj, tc in rows:
        print(f"| {label} | {js:,} | {cb:,} | {cb / js:.2f} | {tj:.1f} | {tc:.1f} |")
    jpeg = compressed(JPEG * 40)
    raw = serializer("sensor_msgs/msg/CompressedImage", "raw")(jpeg)
    print(f"| CompressedImage ({len(jpeg.data):,} B JPEG) | "
          f"{len(serializer('sensor_msgs/msg/CompressedImage', 'json')(jpeg)):,} | "
          f"{len(serializer('sensor_msgs/msg/CompressedImage', 'cbor')(jpeg)):,} | raw: {len(raw):,} | | |")
