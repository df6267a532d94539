"""on_demand rules: the bridge's ROS publisher exists while someone publishes through it, and goes with them."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import pytest
import yaml

from roslink_mqtt.client import rclpy as sdk
from tests.support.mqtt_client import TestClient
from tests.support.procs import CONFIG, run
from tests.support.ros import RosProbe, Watch
from tests.support.stack import live_robot
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(120)

LIGHTS = {"direction": "mqtt_to_ros", "mqtt_topic": "lights", "ros_topic": "/lights", "ros_type": "std_msgs/msg/Bool",
          "on_demand": True}


def lights_config(tmp: Path) -> Path:
    fleet = yaml.safe_load(CONFIG.read_text())
    fleet["robots"]["turtle1"]["rules"] = [r for r in fleet["robots"]["turtle1"]["rules"]
                                           if r["mqtt_topic"] != LIGHTS["mqtt_topic"]] + [LIGHTS]
    path = tmp / "robots.yaml"
    path.write_text(yaml.safe_dump(fleet))
    return path


def publishers_become(watch: Watch, count: int, timeout: float = 10.0) -> bool:
    """Whether the watched topic comes to have ``count`` ROS publishers within ``timeout`` (the caller says why)."""
    try:
        wait_until(f"{count} ROS publisher(s) on the topic", lambda: watch.subscription.get_publisher_count() == count,
                   timeout=timeout)
    except AssertionError:
        return False
    return True


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    from std_msgs.msg import Bool

    work = tmp_path_factory.mktemp("on_demand")
    probe = RosProbe()
    try:
        with live_robot(work, "logins", bridge_config=lights_config(work), sim=False, viewer="admin") as live:
            yield {"port": live.port, "url": live.url, "probe": probe, "work": work,
                   "lights": probe.watch(Bool, "/lights")}
    finally:
        probe.close()


def test_sdk_publisher_creates_and_destroys_the_ros_publisher(stack) -> None:
    lights = stack["lights"]
    assert publishers_become(lights, 0, timeout=2), "an on_demand rule must have no ROS publisher at start"
    node = sdk.create_node("lights_panel", robot="turtle1", url=stack["url"], username="alice", password="alice-demo")
    try:
        pub = node.create_publisher("std_msgs/msg/Bool", "lights", 10)
        assert publishers_become(lights, 1), "advertising did not create the ROS publisher"
        # as with any new ROS publisher, subscribers match it a moment later: publish until one arrives (bounded)
        t0 = time.monotonic()

        def arrived() -> object:
            pub.publish({"data": True})
            return lights.since(t0)

        wait_until("a message on /lights through the new publisher", arrived, timeout=15, period=0.2)
        lights.wait_for(lambda m: m.data is True, after=t0, timeout=1)
        node.destroy_publisher(pub)
        assert publishers_become(lights, 0), "destroy_publisher did not remove the ROS publisher"
    finally:
        node.destroy_node()


def test_plain_mqtt_publish_is_an_implicit_advertisement(stack) -> None:
    lights = stack["lights"]
    with TestClient(stack["port"], "alice", "alice-demo", operator=True) as alice:
        assert alice.connect() == 0
        alice.publish("roslink/turtle1/from/alice/lights", {"data": False})
        assert publishers_become(lights, 1), "a plain client's message did not create the ROS publisher"
    assert publishers_become(lights, 0), "the publisher outlived the only client that used it"


def test_publisher_goes_when_its_process_dies(stack) -> None:
    lights = stack["lights"]
    code = ("import sys, time; from roslink_mqtt.client import rclpy as sdk\n"
            f"node = sdk.create_node('doomed', robot='turtle1', url='{stack['url']}', username='alice', "
            "password='alice-demo')\n"
            "node.create_publisher('std_msgs/msg/Bool', 'lights', 10)\n"
            "print('advertised', flush=True); time.sleep(60)\n")
    with run(["-c", code], stack["work"] / "doomed.log") as doomed:
        assert publishers_become(lights, 1, timeout=15), doomed.output()
        doomed.signal(signal.SIGKILL)
        killed = time.monotonic()
        assert publishers_become(lights, 0), "the ROS publisher outlived its SIGKILLed program"
        print(f"\non_demand publisher removed {time.monotonic() - killed:.2f} s after SIGKILL", file=sys.stderr)


def test_advertisements_are_checked(stack) -> None:
    with TestClient(stack["port"], "alice", "alice-demo", operator=True) as alice, \
            TestClient(stack["port"], "bob", "bob-demo", operator=True) as bob:
        assert alice.connect() == 0 and bob.connect() == 0
        alice.subscribe("roslink/turtle1/to/alice/error")
        alice.publish("roslink/turtle1/from/alice/advertise/lights", {"type": "std_msgs/msg/String"}, retain=True)
        wrong = alice.wait_for(lambda m: True, timeout=5).json()
        assert "'lights' carries std_msgs/msg/Bool, not std_msgs/msg/String" in str(wrong)
        alice.publish("roslink/turtle1/from/alice/advertise/lights", b"", retain=True)
        alice.publish("roslink/turtle1/from/alice/advertise/cmd/warp", {"type": "std_msgs/msg/Bool"})
        unknown = alice.wait_for(lambda m: "warp" in str(m.json()), timeout=5).json()
        assert "no mapping 'cmd/warp'" in str(unknown)
        bob.subscribe("roslink/turtle1/to/bob/error")
        bob.publish("roslink/turtle1/from/bob/advertise/lights", {"type": "std_msgs/msg/Bool"})
        refused = bob.wait_for(lambda m: True, timeout=5).json()
        assert refused["error"] == ("user 'bob' may not publish on 'lights' (operators only): not an operator of "
                                    "turtle1 (a viewer)")
    assert publishers_become(stack["lights"], 0, timeout=2), "a refused advertisement must not create a publisher"
