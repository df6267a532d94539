"""Issue 12 (8) with real processes: the speed limit bounds the combined velocity that reaches /cmd_vel.

``limits.linear: 0.5`` used to let lx, ly and lz each reach 0.5 (0.87 m/s together). Now the bridge
scales an over-limit vector down whole (same direction); the demo fleet uses the default mode (norm).
"""

from __future__ import annotations

import math
import time

import pytest

from tests.support.fleet_brokers import mosquitto_with_logins
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import paced

pytestmark = pytest.mark.timeout(60)

LINEAR, ANGULAR = 0.5, 1.5  # the demo fleet's limits


def test_combined_speed_is_limited_by_norm(tmp_path) -> None:
    from geometry_msgs.msg import Twist

    probe = RosProbe()
    try:
        cmd_vel = probe.watch(Twist, "/cmd_vel", 100)
        with mosquitto_with_logins(tmp_path) as port, \
                run(bridge_args("turtle1", port), tmp_path / "bridge.log", bridge_env("turtle1")), \
                TestClient(port, "alice", "alice-demo", operator=True) as alice:
            assert alice.connect() == 0
            alice.subscribe("roslink/turtle1/heartbeat")
            alice.wait_for(lambda m: m.topic.endswith("/heartbeat") and m.json()["payload"]["system_status"] == 4,
                           timeout=20)
            cmd_vel.wait_matched()
            t0 = time.monotonic()
            for i in paced(0.1, count=10):
                alice.publish("roslink/turtle1/from/alice/cmd/twist", {
                    "message_id": 100, "sequence_number": i + 1,
                    "payload": {"lx": 0.5, "ly": 0.5, "lz": -0.5, "ax": 1.5, "ay": 0.0, "az": 1.5}}, qos=0)
            _, m = cmd_vel.wait_for(lambda m: m.linear.x > 0, timeout=10, after=t0)
    finally:
        probe.close()
    lin = (m.linear.x, m.linear.y, m.linear.z)
    ang = (m.angular.x, m.angular.y, m.angular.z)
    assert math.hypot(*lin) <= LINEAR and math.hypot(*ang) <= ANGULAR
    assert math.hypot(*lin) == pytest.approx(LINEAR) and math.hypot(*ang) == pytest.approx(ANGULAR)
    assert lin == pytest.approx((LINEAR / math.sqrt(3), LINEAR / math.sqrt(3), -LINEAR / math.sqrt(3)))
    assert ang == pytest.approx((ANGULAR / math.sqrt(2), 0.0, ANGULAR / math.sqrt(2)))
