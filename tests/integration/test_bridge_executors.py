"""The bridge under rclpy's EventsExecutor (bridge.executor: events): goals, parameters, motion and stops.

Real processes: the embedded broker, the simulated robot and turtle1's bridge started with
``ROSLINK_EXECUTOR=events``. A goal to the robot's own action server (an rclpy ActionClient in the bridge), a
parameter read and set (rclpy service clients), a twist and the dead-man stop all go through. Services both
ways run under both executors in tests/integration/test_services.py, actions provided by MQTT clients (on their own node
and executor under this one) in tests/integration/test_provided_actions.py; bench/bridge_cpu.py measures what it saves.
"""

from __future__ import annotations

import time
import uuid
from contextlib import ExitStack

import orjson
import pytest

from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import paced

pytestmark = pytest.mark.timeout(90)

T = "roslink/turtle1"


def test_the_events_executor_serves_goals_parameters_motion_and_the_dead_man(tmp_path) -> None:
    from geometry_msgs.msg import Twist

    probe = RosProbe()
    with ExitStack() as exits:
        exits.callback(probe.close)
        cmd_vel = probe.watch(Twist, "/cmd_vel", 200)
        broker = exits.enter_context(EmbeddedBrokerProcess(tmp_path))
        exits.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        bridge = exits.enter_context(run(bridge_args("turtle1", broker.port), tmp_path / "bridge.log",
                                         {**bridge_env("turtle1"), "ROSLINK_EXECUTOR": "events"}))
        # an operator keeps its presence (a heartbeat a second) for as long as it commands: one heartbeat, then a
        # goal that took longer than the 1.5 s it lasts, was canceled for "operator alice went away"
        alice = exits.enter_context(TestClient(broker.port, "alice", "alice-demo", client_id="alice-ev",
                                               operator=True))
        assert alice.connect() == 0
        alice.subscribe(f"{T}/to/alice/#")
        alice.subscribe(f"{T}/heartbeat")
        alice.wait_for(lambda m: m.topic.endswith("/heartbeat") and m.json()["payload"]["system_status"] == 4,
                       timeout=30)

        # a goal through the bridge's ActionClient: feedback and a result
        goal_id = uuid.uuid4().hex[:8]
        alice.publish(f"{T}/from/alice/goal/fibonacci", {"id": goal_id, "goal": {"order": 5}})
        result = alice.wait_for(lambda m: "/result/fibonacci" in m.topic and m.json()["id"] == goal_id,
                                timeout=20).json()
        assert result["status"] == "succeeded" and result["result"]["sequence"][-1] == 5, result

        # parameters: set, then read back (rclpy service clients on the events executor)
        alice.publish(f"{T}/from/alice/param/sim_robot", {"id": "s1", "op": "set", "values": {"max_speed": 0.7}})
        set_reply = alice.wait_for(lambda m: "/param_reply/" in m.topic and m.json()["id"] == "s1", timeout=10).json()
        assert set_reply["result"] and set_reply["values"]["max_speed"]["successful"], set_reply
        alice.publish(f"{T}/from/alice/param/sim_robot", {"id": "g1", "op": "get", "names": ["max_speed"]})
        got = alice.wait_for(lambda m: "/param_reply/" in m.topic and m.json()["id"] == "g1", timeout=10).json()
        assert got["values"] == {"max_speed": 0.7}, got

        # motion, then the dead-man stop (supervision timer on the events executor)
        sent = time.monotonic()
        seq = 0

        def delivered() -> bool:
            return seq >= 5 and any(m.linear.x == pytest.approx(0.2) for _, m in cmd_vel.since(sent))

        # until ROS delivers one: the probe must have matched the bridge's publisher
        for _ in paced(0.1, count=100, stop=delivered):
            seq += 1
            alice.publish(f"{T}/from/alice/cmd/twist",
                          orjson.dumps({"message_id": 100, "sequence_number": seq, "payload": {"lx": 0.2}}), qos=0)
        moved_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.2), after=sent, timeout=10)
        stopped_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0.0, after=moved_at + 0.5, timeout=5)
        assert stopped_at - moved_at < 3.0

        assert bridge.popen.poll() is None, bridge.output()[-3000:]
