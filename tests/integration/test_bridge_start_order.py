"""Start order does not matter: the bridge waits for a broker that is not there yet, and for ROS topics."""

from __future__ import annotations

import time

import pytest

from roslink_mqtt.protocol import MessageId, SystemStatus, decode
from tests.support.fleet_brokers import fleet_password_file
from tests.support.mosquitto import run_mosquitto
from tests.support.mqtt_client import TestClient
from tests.support.net import free_port
from tests.support.procs import bridge_args, bridge_env, run

pytestmark = pytest.mark.timeout(90)


def test_bridge_first_then_robot_then_broker(tmp_path) -> None:
    port = free_port()  # nothing listens here yet
    with run(bridge_args("turtle1", port), tmp_path / "bridge.log", bridge_env("turtle1")) as bridge:
        time.sleep(2.0)  # the bridge keeps retrying a broker that does not exist
        assert bridge.popen.poll() is None, f"bridge gave up without a broker:\n{bridge.output()}"
        with run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"):
            time.sleep(1.0)
            conf = f"allow_anonymous false\npassword_file {fleet_password_file(tmp_path)}\n"
            with run_mosquitto(tmp_path, conf, port=port), \
                    TestClient(port, "alice", "alice-demo", operator=True) as alice:
                assert alice.connect() == 0
                alice.subscribe("roslink/turtle1/#")
                heartbeat = alice.wait_for(lambda m: m.topic == "roslink/turtle1/heartbeat", timeout=20)
                assert decode(heartbeat.payload, MessageId.HEARTBEAT).payload["system_status"] == SystemStatus.ACTIVE
                motion = alice.wait_for(lambda m: m.topic == "roslink/turtle1/state/global_motion", timeout=20)
                assert decode(motion.payload, MessageId.GLOBAL_MOTION).system_id == 1
        assert bridge.popen.poll() is None, "the bridge must survive its robot going away"
