"""Rule encodings end to end: a fleet-file copy with a `cbor` and a `raw` rule, the real bridge and embedded broker,
ROS messages published from this test, a plain MQTT subscriber decoding what arrives (issue 17)."""

from __future__ import annotations

import time

import numpy as np
import orjson
import pytest

from roslink_mqtt.client.encodings import decode_state, sniff
from roslink_mqtt.client.subscriptions import parse_state_item
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe

pytest.importorskip("cbor2")
pytestmark = pytest.mark.timeout(90)

RULES = """    rules: &rules
      - {direction: ros_to_mqtt, ros_topic: /enc_test/camera, ros_type: sensor_msgs/msg/CompressedImage,
         mqtt_topic: state/camera, encoding: raw}
      - {direction: ros_to_mqtt, ros_topic: /enc_test/points, ros_type: sensor_msgs/msg/PointCloud2,
         mqtt_topic: state/points, encoding: cbor}
"""
JPEG = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + bytes(range(256)) * 8 + b"\xff\xd9"


def test_cbor_and_raw_rules_deliver_decodable_payloads(tmp_path) -> None:
    from sensor_msgs.msg import CompressedImage, PointCloud2, PointField

    fleet = write_fleet(tmp_path, edit=lambda text: text.replace("    rules: &rules\n", RULES, 1))
    points = 4096
    cloud = PointCloud2(height=1, width=points, point_step=16, row_step=16 * points, is_dense=True,
                        fields=[PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                                for i, n in enumerate(("x", "y", "z", "intensity"))])
    cloud.header.frame_id = "lidar"
    values = np.arange(points * 4, dtype=np.float32)
    cloud.data = values.tobytes()
    image = CompressedImage(format="jpeg", data=JPEG)
    image.header.frame_id = "camera"

    with EmbeddedBrokerProcess(tmp_path, fleet) as broker, \
            run(bridge_args("turtle1", broker.port, config=fleet), tmp_path / "bridge.log", bridge_env("turtle1")):
        probe = RosProbe()
        try:
            pub_image, pub_cloud = probe.publisher(CompressedImage, "/enc_test/camera"), \
                probe.publisher(PointCloud2, "/enc_test/points")
            with TestClient(broker.port, "bob", "bob-demo") as bob:
                assert bob.connect() == 0
                bob.subscribe("roslink/turtle1/state/#")
                desc = bob.wait_for(lambda m: m.topic == "roslink/turtle1/state/description", timeout=20)
                entries = {e["name"]: e for e in orjson.loads(desc.payload)["state"]}
                assert entries["camera"]["encoding"] == "raw" and entries["points"]["encoding"] == "cbor"
                assert "encoding" not in entries["global_motion"]

                deadline = time.monotonic() + 20
                got: dict[str, bytes] = {}
                while len(got) < 2 and time.monotonic() < deadline:  # until the bridge's subscriptions match
                    pub_image.publish(image)
                    pub_cloud.publish(cloud)
                    try:
                        m = bob.wait_for(lambda m: m.topic.rsplit("/", 1)[-1] in ("camera", "points")
                                         and m.topic.rsplit("/", 1)[-1] not in got, timeout=0.5)
                    except (AssertionError, TimeoutError):
                        continue
                    got[m.topic.rsplit("/", 1)[-1]] = m.payload
        finally:
            probe.close()

    assert set(got) == {"camera", "points"}, f"only {sorted(got)} arrived"
    assert got["camera"] == JPEG and sniff(got["camera"]) == "raw"
    assert parse_state_item(got["camera"], "turtle1", "camera") == {"format": "jpeg", "data": JPEG}
    body = decode_state(got["points"], entries["points"]["encoding"])
    assert body["header"]["frame_id"] == "lidar" and body["width"] == points
    assert isinstance(body["data"], bytes) and np.array_equal(np.frombuffer(body["data"], np.float32), values)
    assert [f["name"] for f in body["fields"]] == ["x", "y", "z", "intensity"]
