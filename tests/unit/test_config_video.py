"""robots.yaml's ``video:`` section: cameras sent as video, read with errors that say where."""

from __future__ import annotations

import textwrap

import pytest

from roslink_mqtt.config import ConfigError, Priority, parse_fleet

from .test_config import _with_snapshot


def _fleet_with(section: str) -> str:
    return _with_snapshot(section)


def test_a_camera_with_defaults_and_one_with_its_own_ladder() -> None:
    fleet = parse_fleet(_fleet_with("""\
        video:
          - {ros_topic: camera/image_raw, ros_type: sensor_msgs/msg/Image}
          - {name: rear, ros_topic: rear/image/compressed, ros_type: sensor_msgs/msg/CompressedImage, codec: vp8,
             fps: 15, ladder: [[640, 480, 15], [320, 240, 10]], min_kbit_s: 30, max_kbit_s: 800, priority: bulk}
        """), "robots.yaml")
    front, rear = fleet.robots["turtle1"].video
    assert (front.name, front.codec, front.fps, front.ladder, front.priority) == (
        "camera_image_raw", "h264", 30.0, (), Priority.STATE)
    assert (rear.name, rear.codec, rear.ladder, rear.min_kbit_s, rear.max_kbit_s, rear.priority) == (
        "rear", "vp8", ((640, 480, 15.0), (320, 240, 10.0)), 30, 800, Priority.BULK)
    assert fleet.robots["turtle1"].video_stream("rear") is rear
    assert fleet.robots["turtle2"].video == ()


@pytest.mark.parametrize(("section", "expected"), [
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/LaserScan}\n",
     "robots.turtle1.video[0].ros_type: expected one of"),
    ("video:\n  - {name: odom, ros_topic: cam, ros_type: sensor_msgs/msg/Image}\n",
     "robots.turtle1.video[0].name: state/odom is already used"),
    ("video:\n  - {name: link, ros_topic: cam, ros_type: sensor_msgs/msg/Image}\n",
     "robots.turtle1.video[0].name: state/link is already used"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image}\n  - {ros_topic: cam, "
     "ros_type: sensor_msgs/msg/Image}\n", "robots.turtle1.video[1].name: state/cam is already used"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, codec: h265}\n",
     "robots.turtle1.video[0].codec: expected one of"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, ladder: [[641, 480, 30]]}\n",
     "robots.turtle1.video[0].ladder[0]: expected [width, height, fps]"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, ladder: [[320, 240, 10], [640, 480, 30]]}\n",
     "robots.turtle1.video[0].ladder[1]: rungs go from the largest"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, ladder: []}\n",
     "robots.turtle1.video[0].ladder: a ladder needs at least one"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, min_kbit_s: 900, max_kbit_s: 800}\n",
     "robots.turtle1.video[0].min_kbit_s: min_kbit_s 900 is above max_kbit_s 800"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, fps: 0}\n",
     "robots.turtle1.video[0].fps: expected a finite number > 0"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, priority: motion}\n",
     "robots.turtle1.video[0].priority: expected"),
    ("video:\n  - {ros_topic: cam, ros_type: sensor_msgs/msg/Image, bitrate: 5}\n",
     "robots.turtle1.video[0].bitrate: unknown key 'bitrate'"),
])
def test_a_bad_video_section_says_where(section: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_fleet(textwrap.dedent(_fleet_with(section)), "robots.yaml")
    assert expected in str(info.value)

