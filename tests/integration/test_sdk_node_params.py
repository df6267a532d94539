"""Parameters of SDK nodes (helium parity): a program without ROS declares parameters; ROS clients set them.

Real processes: embedded broker, simulated robot, bridge; an SDK node ``legacy_arm`` in this process (and one
in a subprocess, to be SIGKILLed); a real rclpy parameter client (``AsyncParameterClient``) in this process's
own ROS context. Checks: the declared parameters are visible to ROS (list, get, describe); a ROS set reaches the
SDK callback and changes ``node.get_parameter``; the callback's refusal reaches the ROS client with its reason;
a local set reaches ROS; destroying, killing or freezing the SDK node removes the ROS node's parameter services within
a bounded time (printed); an SDK node that does not answer times out with a reason; a viewer cannot declare
(refused with a reason); the bridge's refusals (name taken, malformed body, stray result) on the error topic.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from roslink_mqtt.client import rclpy as sdk
from roslink_mqtt.client.rclpy.parameter import Parameter, ParameterDescriptor, SetParametersResult
from tests.support.mqtt_client import TestClient
from tests.support.robot_stack import BROKERS, turtle1_online
from tests.support.ros import RosProbe
from tests.support.waits import never, wait_until

pytestmark = pytest.mark.timeout(180)

ROOT = Path(__file__).resolve().parents[2]


def _wait(future: Any, timeout: float = 10.0) -> Any:
    wait_until("the ROS parameter service's answer", future.done, timeout=timeout, period=0.01)
    return future.result()


def _first_call(make: Any, timeout: float = 20.0, resend: float = 2.0) -> Any:
    """The first ROS service call to a node just discovered, sent again every ``resend`` s until answered: a
    request sent while the service's request reader is still matching the client's writer (DDS discovery goes on
    after ``wait_for_services``) is lost, and its future never completes (once in a loaded CI run)."""
    calls: list[tuple[float, Any]] = []  # (sent at, future)

    def answered() -> bool:
        if not calls or (not calls[-1][1].done() and time.monotonic() - calls[-1][0] >= resend):
            calls.append((time.monotonic(), make()))
        return calls[-1][1].done()

    wait_until("the ROS parameter service's answer", answered, timeout=timeout, period=0.01)
    return calls[-1][1].result()


def _until(predicate: Any, timeout: float, what: str) -> float:
    start = time.monotonic()
    wait_until(what, predicate, timeout=timeout)
    return time.monotonic() - start


def _has_parameter_services(probe: RosProbe, node: str) -> bool:
    """The ROS node exists and serves set_parameters (the graph also lists service names our clients use)."""
    if (node, "/") not in probe.node.get_node_names_and_namespaces():
        return False
    return any(name == f"/{node}/set_parameters"
               for name, _ in probe.node.get_service_names_and_types_by_node(node, "/"))


def _ready_node(url: str, name: str, user: str = "alice", password: str = "alice-demo") -> Any:
    node = sdk.create_node(name, robot="turtle1", url=url, username=user, password=password)
    node.robot_client.wait_for_robot("turtle1", timeout=10)
    wait_until("turtle1's access report", lambda: node.robot_client.access("turtle1") is not None,
               timeout=10)  # the access report says what we are
    return node


@pytest.mark.parametrize("broker", BROKERS[:1])  # the bridge's and the SDK's logic: any broker shows it
def test_ros_parameter_client_reaches_the_sdk_node(tmp_path, broker: str) -> None:
    from rclpy.parameter import Parameter as RosParameter
    from rclpy.parameter_client import AsyncParameterClient

    probe = RosProbe()
    try:
        with turtle1_online(tmp_path, broker) as port:
            url = f"mqtt://127.0.0.1:{port}"
            node = _ready_node(url, "legacy_arm")
            seen: list[list[Parameter]] = []

            def on_set(params: list[Parameter]) -> SetParametersResult:
                seen.append(params)
                for p in params:
                    if p.name == "max_force" and p.value > 5.0:
                        return SetParametersResult(successful=False, reason="max_force must be at most 5 N")
                return SetParametersResult(successful=True)

            spinner = threading.Thread(target=sdk.spin, args=(node,), daemon=True)
            try:
                node.add_on_set_parameters_callback(on_set)
                assert node.declare_parameter("max_force", 2.5, {"description": "gripper force limit (N)"}).value == 2.5
                node.declare_parameters("", [("speed", 3), ("port", "/dev/ttyUSB0",
                                                            ParameterDescriptor(read_only=True))])
                assert node.get_parameter("max_force").type_ is Parameter.Type.DOUBLE
                assert node.has_parameter("speed") and not node.has_parameter("nope")
                spinner.start()

                ros = AsyncParameterClient(probe.node, "legacy_arm")
                t0 = time.monotonic()
                assert ros.wait_for_services(timeout_sec=15), "no /legacy_arm parameter services"
                print(f"\nROS parameter services of /legacy_arm up {time.monotonic() - t0:.2f} s after waiting")
                names = _first_call(ros.list_parameters).result.names
                assert {"max_force", "speed", "port"} <= set(names)
                values = _wait(ros.get_parameters(["max_force", "speed", "port"])).values
                assert [values[0].double_value, values[1].integer_value, values[2].string_value] == \
                    [2.5, 3, "/dev/ttyUSB0"]
                described = _wait(ros.describe_parameters(["max_force", "port"])).descriptors
                assert described[0].description == "gripper force limit (N)" and described[1].read_only

                # a ROS set reaches the SDK callback (inside spin) and the SDK's value changes
                t0 = time.monotonic()
                result = _wait(ros.set_parameters([RosParameter("max_force", RosParameter.Type.DOUBLE, 3.0)]))
                print(f"ROS set_parameters answered by the SDK node in {(time.monotonic() - t0) * 1000:.0f} ms")
                assert result.results[0].successful, result.results[0].reason
                assert node.get_parameter("max_force").value == 3.0
                assert seen[-1][0].name == "max_force" and seen[-1][0].value == 3.0

                # the callback refuses: the ROS client gets the SDK's reason, nothing changes
                result = _wait(ros.set_parameters([RosParameter("max_force", RosParameter.Type.DOUBLE, 9.0)]))
                assert not result.results[0].successful
                assert result.results[0].reason == "max_force must be at most 5 N"
                assert node.get_parameter("max_force").value == 3.0
                assert _wait(ros.get_parameters(["max_force"])).values[0].double_value == 3.0
                # read-only: ROS refuses it itself (the SDK is not asked)
                result = _wait(ros.set_parameters([RosParameter("port", RosParameter.Type.STRING, "/dev/x")]))
                assert not result.results[0].successful and node.get_parameter("port").value == "/dev/ttyUSB0"

                # a local set goes through the callbacks too, and reaches ROS
                assert not node.set_parameters({"max_force": 7.0})[0].successful
                assert node.set_parameters([Parameter("max_force", value=4)])[0].successful
                assert node.get_parameter("max_force").value == 4.0  # an integer is a fine double
                _until(lambda: _wait(ros.get_parameters(["max_force"])).values[0].double_value == 4.0, 5,
                       "the local set on ROS")
                bad = node.set_parameters({"speed": "fast"})[0]
                assert not bad.successful and "expected integer" in bad.reason

                # destroying the SDK node removes the ROS node's parameter services
                t0 = time.monotonic()
                node.destroy_node()
                took = _until(lambda: not _has_parameter_services(probe, "legacy_arm"), 10,
                              "removal after destroy_node")
                print(f"/legacy_arm parameter services gone {took:.2f} s after destroy_node")
            finally:
                node.destroy_node()
                spinner.join(timeout=5)
    finally:
        probe.close()


_KILLED = """
import sys, time
from roslink_mqtt.client import rclpy as sdk
node = sdk.create_node(sys.argv[2], robot="turtle1", url=sys.argv[1], username="alice", password="alice-demo",
                       keepalive=2)
node.declare_parameter("gain", 1.5)
print("declared", flush=True)
sdk.spin(node)
"""


def test_killed_sdk_node_and_refusals(tmp_path) -> None:
    from rclpy.parameter import Parameter as RosParameter
    from rclpy.parameter_client import AsyncParameterClient

    probe = RosProbe()
    try:
        with turtle1_online(tmp_path) as port:
            url = f"mqtt://127.0.0.1:{port}"
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            proc = subprocess.Popen([sys.executable, "-c", _KILLED, url, "doomed_arm"], stdout=subprocess.PIPE,
                                    env=env, cwd=ROOT, text=True)
            frozen = subprocess.Popen([sys.executable, "-c", _KILLED, url, "frozen_arm"], stdout=subprocess.PIPE,
                                      env=env, cwd=ROOT, text=True)
            try:
                assert proc.stdout.readline().strip() == "declared"
                ros = AsyncParameterClient(probe.node, "doomed_arm")
                assert ros.wait_for_services(timeout_sec=15)
                assert _first_call(lambda: ros.get_parameters(["gain"])).values[0].double_value == 1.5
                assert _wait(ros.set_parameters([RosParameter("gain", RosParameter.Type.DOUBLE, 2.0)])
                             ).results[0].successful
                proc.send_signal(signal.SIGKILL)
                t0 = time.monotonic()
                took = _until(lambda: not _has_parameter_services(probe, "doomed_arm"), 20, "removal after SIGKILL")
                print(f"/doomed_arm parameter services gone {took:.2f} s after SIGKILL (its last-will)")
                # alive but silent (no FIN, no last-will yet): the robot's presence timeout ends it
                assert frozen.stdout.readline().strip() == "declared"
                _until(lambda: _has_parameter_services(probe, "frozen_arm"), 15, "frozen_arm on ROS")
                frozen.send_signal(signal.SIGSTOP)
                took = _until(lambda: not _has_parameter_services(probe, "frozen_arm"), 20, "removal after SIGSTOP")
                print(f"/frozen_arm parameter services gone {took:.2f} s after SIGSTOP (presence timeout)")
            finally:
                for p in (proc, frozen):
                    p.kill()
                    p.wait(timeout=5)

            # an SDK node that never spins cannot answer: a ROS set times out with a reason
            lazy = _ready_node(url, "lazy_arm")
            try:
                lazy.declare_parameter("gain", 1.0)
                ros = AsyncParameterClient(probe.node, "lazy_arm")
                assert ros.wait_for_services(timeout_sec=15)
                with TestClient(port, "bob", "bob-demo") as bob:  # the bridge's own executor keeps running
                    assert bob.connect() == 0
                    bob.subscribe("roslink/turtle1/state/global_motion")
                    bob.drain(0.5)
                    t0 = time.monotonic()
                    result = _wait(ros.set_parameters([RosParameter("gain", RosParameter.Type.DOUBLE, 2.5)]))
                    waited = time.monotonic() - t0
                    arrivals = [t0] + [m.at for m in bob.drain(0.2) if t0 <= m.at <= t0 + waited] + [t0 + waited]
                gap = max(b - a for a, b in zip(arrivals, arrivals[1:], strict=False))
                print(f"set on a silent SDK node answered after {waited:.2f} s: {result.results[0].reason}; "
                      f"longest gap in state/global_motion meanwhile {gap * 1000:.0f} ms")
                assert gap < 1.0, "the bridge's executor stalled while a ROS set waited for the SDK"
                assert not result.results[0].successful
                assert result.results[0].reason == "timeout: lazy_arm did not answer within 2 s"
                assert lazy.get_parameter("gain").value == 1.0
            finally:
                lazy.destroy_node()

            # a viewer's SDK node: refused at once with the reason (the broker would drop its declaration)
            viewer = _ready_node(url, "viewer_arm", "bob", "bob-demo")
            try:
                viewer.declare_parameter("gain", 1.0)
                _until(lambda: any(e.topic.endswith("/declare/viewer_arm") for e in viewer.robot_client.recent_errors),
                       5, "the viewer's refusal")
                error = next(e for e in viewer.robot_client.recent_errors if e.topic.endswith("/declare/viewer_arm"))
                assert error.error == ("user 'bob' may not declare parameters on turtle1 (as node 'viewer_arm') "
                                       "(operators only): not an operator of turtle1 (a viewer)")
                never("viewer_arm's parameter services on ROS", lambda: _has_parameter_services(probe, "viewer_arm"),
                      seconds=1.0)
            finally:
                viewer.destroy_node()

            # the bridge's own refusals (a broker without ACLs would let these through): on the error topic
            with TestClient(port, "admin", "admin-demo") as admin, \
                    TestClient(port, "alice", "alice-demo", operator=True) as alice:
                assert admin.connect() == 0 and alice.connect() == 0
                admin.subscribe("roslink/turtle1/to/admin/error")
                alice.subscribe("roslink/turtle1/to/alice/error")
                alice.publish("roslink/turtle1/from/alice/declare/held_arm",
                              {"client_id": alice.client_id, "parameters": {"gain": {"value": 1, "type": "integer"}}})
                _until(lambda: _has_parameter_services(probe, "held_arm"), 10, "a raw MQTT client's declaration")
                admin.publish("roslink/turtle1/from/admin/declare/held_arm",
                              {"client_id": admin.client_id, "parameters": {}})
                err = admin.wait_for(lambda m: m.json()["topic"].endswith("/declare/held_arm")).json()
                assert err["error"] == "node 'held_arm' is already declared on turtle1 by alice"
                alice.publish("roslink/turtle1/from/alice/declare/held_arm", b"")
                _until(lambda: not _has_parameter_services(probe, "held_arm"), 10, "withdrawal")
                alice.publish("roslink/turtle1/from/alice/declare/bad_arm",
                              {"client_id": alice.client_id, "parameters": {"gain": {"value": "x", "type": "double"}}})
                err = alice.wait_for(lambda m: m.json()["topic"].endswith("/declare/bad_arm")).json()
                assert err["error"] == "parameters.gain.value: expected double, got string 'x'"
                alice.publish("roslink/turtle1/from/alice/param_result/bad_arm", {"id": "turtle1-p999",
                                                                                  "successful": True})
                err = alice.wait_for(lambda m: m.json()["topic"].endswith("/param_result/bad_arm")).json()
                assert err["error"] == "no pending parameter set with id 'turtle1-p999' for node 'bad_arm'"
    finally:
        probe.close()
