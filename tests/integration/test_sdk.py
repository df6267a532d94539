"""The Python SDK against real processes: Mosquitto, the sim robot and its bridge; rclpy on the ROS side.

* RobotClient: robots and presence, typed state, a twist that reaches ROS
  ``cmd_vel``, error reports, ``reset`` called sync and with asyncio, a viewer refused.
* the rclpy-shaped Node API: services provided from here and called by an
  rclpy client (appear, answer, fail cleanly, disappear after destroy_service).
* the examples, run as programs without rclpy and amqtt (import blocker):
  legacy_service.py + ros_caller.py end to end, SIGKILL of the provider mid-call,
  call_from_cloud.py.
"""

from __future__ import annotations

import asyncio
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import pytest

import roslink_mqtt.client as sdk
from roslink_mqtt.client import CommandRefused, RobotClient, RobotError, ServiceError, ServiceTimeout, rclpy
from roslink_mqtt.client.messages import GlobalMotion, RangeFinderData
from roslink_mqtt.client.rclpy.node import Node
from roslink_mqtt.client.rclpy.qos import qos_profile_sensor_data
from roslink_mqtt.protocol import Envelope, MessageId, ProtocolError, SystemStatus, encode
from tests.support.fleet_brokers import fleet_password_file
from tests.support.mosquitto import run_mosquitto
from tests.support.mqtt_client import TestClient
from tests.support.no_ros import no_ros_env
from tests.support.procs import ROOT, run
from tests.support.ros import RosProbe
from tests.support.stack import live_robot
from tests.support.waits import never, paced, wait_until

pytestmark = pytest.mark.timeout(120)


def test_sdk_imports_without_rclpy_and_amqtt(tmp_path) -> None:
    code = """
import sys
for name in ("rclpy", "amqtt"):
    try:
        __import__(name)
    except ImportError:
        pass
    else:
        raise SystemExit(f"the blocker let {name} through")
import roslink_mqtt.client as sdk
from roslink_mqtt.client import RobotClient
from roslink_mqtt.client.rclpy import create_node
from roslink_mqtt.client.messages import GlobalMotion
from roslink_mqtt.client.commands import CommandStreams
from roslink_mqtt.topics import TopicTree
topic, data, seq = CommandStreams(TopicTree(), "alice").build("turtle1", "twist", {"lx": 0.2})
assert topic == "roslink/turtle1/from/alice/cmd/twist" and seq is not None
loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "amqtt", "rosidl_runtime_py"))
assert not loaded, loaded
print("sdk ok without", ", ".join(("rclpy", "amqtt")))
"""
    out = subprocess.run([sys.executable, "-c", code], env=no_ros_env(tmp_path), capture_output=True, text=True,
                         timeout=30, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "sdk ok without rclpy, amqtt" in out.stdout


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")
def test_tls_connection(tmp_path) -> None:
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=localhost",
                    "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)
    conf = f"allow_anonymous false\npassword_file {fleet_password_file(tmp_path)}\ncertfile {cert}\nkeyfile {key}\n"
    with run_mosquitto(tmp_path, conf) as port:
        url = f"mqtts://127.0.0.1:{port}"
        with RobotClient("alice", "alice-demo", url=url, ca_file=str(cert)) as client:
            assert client.connected and client.wildcard_heartbeats
            with pytest.raises(ServiceTimeout):
                client.call("turtle1", "reset", timeout=0.2)  # a call went out and nothing broke; no robot here
        with RobotClient("alice", "alice-demo", url=url, insecure_tls=True) as client:
            assert client.connected
        with pytest.raises(sdk.ConnectError, match="certificate verify failed"):
            RobotClient("alice", "alice-demo", url=url).connect(timeout=5)  # not signed by a CA we trust


def test_reconnect_restores_subscriptions_presence_and_offers(tmp_path) -> None:
    from tests.support.mqtt_client import TestClient
    from tests.support.net import free_port

    port, conf = free_port(), f"allow_anonymous false\npassword_file {fleet_password_file(tmp_path)}\n"
    got: queue.Queue = queue.Queue()
    motion = encode(Envelope(MessageId.GLOBAL_MOTION, {k: 0.0 for k in ("x", "y", "z", "vx", "vy", "vz", "wx", "wy",
                                                                         "wz", "roll", "pitch", "yaw")}, 1, 5))
    with run_mosquitto(tmp_path, conf, port=port):
        client = RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{port}", robots=["turtle1"]).connect()
        client.subscribe("turtle1", "global_motion", got.put)
        client.provide("turtle1", "self_test", "std_srvs/srv/Trigger", lambda args: {"success": True})
    try:
        # the broker restarted without persistence: every retained message and subscription is gone
        with run_mosquitto(tmp_path, conf, port=port), TestClient(port, "admin", "admin-demo") as admin:
            assert client.connection.connected.wait(10), "the SDK did not reconnect"
            assert admin.connect() == 0
            admin.subscribe("roslink/turtle1/from/alice/provide/#")
            admin.subscribe("roslink/operators/alice/+")
            offer = admin.wait_for(lambda m: "/provide/" in m.topic and m.payload, timeout=5).json()
            assert offer == {"type": "std_srvs/srv/Trigger", "timeout": 5.0, "client_id": client.client_id}
            admin.wait_for(lambda m: m.topic == f"roslink/operators/alice/{client.client_id}" and m.payload,
                           timeout=5)
            for _ in paced(0.1, within=5, stop=lambda: not got.empty()):  # re-subscribed: state flows again
                admin.publish("roslink/turtle1/state/global_motion", motion, qos=0)
            assert isinstance(got.get(timeout=1), GlobalMotion)
    finally:
        client.close()


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    from geometry_msgs.msg import Twist

    work = tmp_path_factory.mktemp("sdk")
    probe = RosProbe()
    cmd_vel = probe.watch(Twist, "/cmd_vel")
    try:
        with live_robot(work, "logins") as live:
            port, url, bridge = live.port, live.url, live.bridge
            with RobotClient("alice", "alice-demo", url=url, robots=["turtle1"]) as alice:
                alice.wait_for_robot("turtle1", timeout=20)
                failed: list[ServiceError] = []

                def reset_answers() -> bool:
                    try:
                        alice.call("turtle1", "reset", timeout=5)
                    except ServiceError as err:
                        failed.append(err)
                        return False
                    return True

                try:  # the bridge discovers the sim's reset service a moment after start
                    wait_until("an answer from the sim's reset service", reset_answers, timeout=15, period=0.2)
                except AssertionError:
                    raise failed[-1] from None
                yield SimpleNamespace(port=port, url=url, work=work, probe=probe, cmd_vel=cmd_vel, alice=alice,
                                      bridge=bridge)
    finally:
        probe.close()


# -- RobotClient -------------------------------------------------------------------------------
def test_robots_and_typed_state(stack) -> None:
    alice = stack.alice
    robots = alice.robots()
    assert robots["turtle1"].online and robots["turtle1"].system_status == SystemStatus.ACTIVE
    assert robots["turtle1"].system_id == 1 and alice.wildcard_heartbeats is True  # Mosquitto grants the wildcard
    with alice.subscribe("turtle1", "state/global_motion") as motion:
        first = motion.get(timeout=5)
        assert isinstance(first, GlobalMotion) and first.robot == "turtle1" and first.system_id == 1
        assert isinstance(first.sequence_number, int) and first.state_name == "global_motion"
        second = motion.get(timeout=5)
        assert (second.sequence_number - first.sequence_number) % 2**32 >= 1
    got: queue.Queue = queue.Queue()
    scan_sub = alice.subscribe("turtle1", "range_finder_data", got.put)
    scan = got.get(timeout=5)
    scan_sub.close()
    assert isinstance(scan, RangeFinderData) and len(scan.ranges) == 360 and isinstance(scan.ranges, tuple)

    async def first_async() -> object:
        with alice.subscribe("turtle1", "robot_status") as status:
            async for message in status:
                return message

    status = asyncio.run(asyncio.wait_for(first_async(), timeout=5))
    assert type(status).__name__ == "RobotStatus" and 0 < status.battery_remaining <= 100


def test_twist_reaches_ros_cmd_vel(stack) -> None:
    """Streamed at 10 Hz as an operator drives, until one arrives: a bridge starved of the CPU may rightly drop a
    command that waited too long inside it, but a live stream must get through."""
    t0 = time.monotonic()
    deadline = t0 + 15
    msg = None
    while msg is None and time.monotonic() < deadline:
        stack.alice.twist("turtle1", lx=0.3, az=0.2)
        try:
            _, msg = stack.cmd_vel.wait_for(lambda m: m.linear.x > 0, after=t0, timeout=0.1)
        except TimeoutError:
            pass
    assert msg is not None, f"no twist reached /cmd_vel in 15 s; alice was told: {list(stack.alice.recent_errors)}"
    assert msg.linear.x == pytest.approx(0.3) and msg.angular.z == pytest.approx(0.2)


def test_presence_says_standby_until_the_first_command(stack) -> None:
    with TestClient(stack.port, "admin", "admin-demo") as admin:
        assert admin.connect() == 0
        admin.subscribe("roslink/operators/alice/sdk-presence-test")
        with RobotClient("alice", "alice-demo", url=stack.url, client_id="sdk-presence-test") as client:
            first = admin.wait_for(lambda m: bool(m.payload)).json()["payload"]
            assert first["system_status"] == SystemStatus.STANDBY and first["name"] == "sdk-presence-test"
            sent = time.monotonic()
            client.twist("turtle1", lx=0.0)
            active = admin.wait_for(lambda m: bool(m.payload) and m.json()["payload"]["system_status"]
                                    == SystemStatus.ACTIVE, timeout=3)
            assert active.at - sent < 0.5  # announced with the command, not at the next 1 s beat


def test_errors_surface_as_callbacks_and_exceptions(stack) -> None:
    errors: queue.Queue[RobotError] = queue.Queue()
    with RobotClient("alice", "alice-demo", url=stack.url, robots=["turtle1"], on_error=errors.put) as client:
        client.command("turtle1", "fly", {"x": 1})
        error = errors.get(timeout=5)
        assert error.robot == "turtle1" and error.topic == "roslink/turtle1/from/alice/fly"
        assert "no mapping for 'fly'" in error.error
        with pytest.raises(CommandRefused, match="frame_type 1 is not supported") as refused:
            client.command("turtle1", "go_to_waypoint", {"frame_type": 1, "x": 1.0, "y": 2.0}, check=3.0)
        assert refused.value.error.message_id == MessageId.GO_TO_WAYPOINT
        assert client.twist("turtle1", lx=0.0, check=0.3) is not None  # accepted: no report within the window
        with pytest.raises(ProtocolError, match="unknown field 'lxx'"):
            client.command("turtle1", "twist", {"lxx": 0.2})  # caught before it is sent
        assert any("no mapping" in e.error for e in client.recent_errors)


def test_reset_sync_and_async(stack) -> None:
    alice = stack.alice
    expected = {"success": True, "message": "pose reset to the room centre"}
    assert alice.call("turtle1", "reset") == expected

    async def several() -> list:
        return await asyncio.gather(*(alice.call_async("turtle1", "reset") for _ in range(3)))

    assert asyncio.run(several()) == [expected] * 3
    with pytest.raises(ServiceError, match="unknown service 'warp'") as err:
        alice.call("turtle1", "warp")
    assert err.value.robot == "turtle1" and err.value.service == "warp"
    with pytest.raises(ServiceError, match="bad arguments: args.force"):
        asyncio.run(alice.call_async("turtle1", "reset", {"force": True}))


def test_call_timeout_and_offline_robot(stack) -> None:
    alice = stack.alice
    t0 = time.monotonic()
    with pytest.raises(ServiceTimeout):
        alice.call("turtle2", "reset", timeout=0.3)  # no bridge for turtle2: nobody answers
    assert time.monotonic() - t0 < 2
    # a robot whose retained heartbeat says offline (its bridge's last-will) fails at once
    offline = encode(Envelope(MessageId.HEARTBEAT, {"type": 1, "name": "turtle2", "system_status": 8,
                                                    "owner_id": "", "mode": 0}, 2, 1))
    alice.connection.publish("roslink/turtle2/heartbeat", offline, qos=1, retain=True).wait_for_publish(5)
    try:
        assert alice.directory.wait(lambda r: "turtle2" in r and not r["turtle2"].online, timeout=5)
        with pytest.raises(ServiceError, match="turtle2 is offline"):
            alice.call("turtle2", "reset", timeout=5)
    finally:
        alice.connection.publish("roslink/turtle2/heartbeat", b"", qos=1, retain=True).wait_for_publish(5)


def test_viewer_is_refused(stack) -> None:
    with RobotClient("bob", "bob-demo", url=stack.url, robots=["turtle1"]) as bob:
        with pytest.raises(ServiceError, match="user 'bob' may not call 'reset'"):
            bob.call("turtle1", "reset")
        with pytest.raises(CommandRefused, match="not an operator of turtle1"):
            bob.twist("turtle1", lx=0.3, check=3.0)
        offer = bob.provide("turtle1", "bob_service", "std_srvs/srv/Trigger", lambda args: {"success": True})
        wait_until("the refusal of bob's offer", lambda: offer.refused is not None, timeout=5)
        assert offer.refused is not None and "may not provide services" in offer.refused
    with pytest.raises(sdk.ConnectError, match="refused bob"):
        RobotClient("bob", "wrong", url=stack.url).connect()


# -- the rclpy-shaped Node API ---------------------------------------------------------------------------
def _spin_in_thread(node: Node) -> tuple[threading.Thread, threading.Event]:
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set() and not node.destroyed:
            rclpy.spin_once(node, timeout_sec=0.1)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread, stop


def _ros_call(client, request, timeout: float = 10.0):
    future = client.call_async(request)
    wait_until(f"a ROS answer from {client.srv_name}", future.done, timeout=timeout, period=0.01)
    return future.result()


def _wait_gone(client, timeout: float = 10.0) -> None:
    wait_until(f"{client.srv_name} to leave the ROS graph", lambda: not client.service_is_ready(), timeout=timeout,
               period=0.1)


def test_node_services_called_from_rclpy(stack) -> None:
    from std_srvs.srv import SetBool, Trigger

    ros = stack.probe.node
    node = rclpy.create_node("sdk_test_provider", robot="turtle1", url=stack.url, username="alice",
                           password="alice-demo")
    requests: list[dict] = []
    entered, release = threading.Event(), threading.Event()

    def enable(request: dict, response: dict) -> dict:
        requests.append(request)
        response["success"], response["message"] = True, f"motors {'on' if request['data'] else 'off'}"
        return response

    def check(_request: dict, response: dict) -> None:
        response.update(success=True, message="checked")  # returning None means "the response I filled in"

    def broken(_request: dict, _response: dict) -> dict:
        raise RuntimeError("sensor unplugged")

    def hang(_request: dict, response: dict) -> dict:
        entered.set()
        release.wait(10)
        return response

    thread, stop = _spin_in_thread(node)
    try:
        services = {
            "enable": node.create_service("std_srvs/srv/SetBool", "sdk_enable", enable),
            "check": node.create_service("std_srvs/srv/Trigger", "sdk_check", check),
            "broken": node.create_service("std_srvs/srv/Trigger", "sdk_broken", broken),
            "hang": node.create_service("std_srvs/srv/Trigger", "sdk_hang", hang, timeout=20),
        }
        clients = {"enable": ros.create_client(SetBool, "/sdk_enable"),
                   "check": ros.create_client(Trigger, "/sdk_check"),
                   "broken": ros.create_client(Trigger, "/sdk_broken"),
                   "hang": ros.create_client(Trigger, "/sdk_hang")}
        for name, client in clients.items():
            assert client.wait_for_service(timeout_sec=15), f"{name} never appeared in ROS"
        on = _ros_call(clients["enable"], SetBool.Request(data=True))
        assert (on.success, on.message) == (True, "motors on") and requests == [{"data": True}]
        assert _ros_call(clients["check"], Trigger.Request()).message == "checked"
        failed = _ros_call(clients["broken"], Trigger.Request())
        assert failed.success is False and "RuntimeError: sensor unplugged" in failed.message
        # a call the provider is still working on when it withdraws the service fails at once
        pending = clients["hang"].call_async(Trigger.Request())
        assert entered.wait(5)
        withdrawn_at = time.monotonic()
        node.destroy_service(services["hang"])
        wait_until("the pending ROS call to end with the withdrawn service", pending.done,
                   timeout=withdrawn_at + 3 - time.monotonic(), period=0.01)
        assert pending.result().success is False and "withdrawn" in pending.result().message
        release.set()
        assert node.destroy_service(services["enable"]) and not node.destroy_service(services["enable"])
        _wait_gone(clients["enable"])
        assert clients["check"].service_is_ready()  # the others stay
    finally:
        release.set()
        stop.set()
        thread.join(5)
        node.destroy_node()
    _wait_gone(clients["check"])  # destroying the node withdraws the rest
    for client in clients.values():
        ros.destroy_client(client)


def test_node_topics_and_client(stack) -> None:
    node = rclpy.create_node("sdk_test_topics", robot="turtle1", url=stack.url, username="alice",
                           password="alice-demo")
    typed, plain = queue.Queue(), queue.Queue()
    node.create_subscription(GlobalMotion, "global_motion", typed.put, 10)
    node.create_subscription("nav_msgs/msg/Odometry", "state/global_motion", plain.put, 10)
    twist = node.create_publisher("geometry_msgs/msg/Twist", "cmd/twist", 10)
    waypoints = {"default": node.create_publisher("geometry_msgs/msg/PoseStamped", "go_to_waypoint", 10),
                 "best_effort": node.create_publisher("geometry_msgs/msg/PoseStamped", "go_to_waypoint",
                                                      qos_profile_sensor_data)}
    ticks = []
    node.create_timer(0.1, lambda: (ticks.append(1), twist.publish({"linear": {"x": 0.25}, "angular": {"z": -0.4}})))
    reset = node.create_client("std_srvs/srv/Trigger", "reset")
    t0 = time.monotonic()
    thread, stop = _spin_in_thread(node)
    try:
        assert isinstance(typed.get(timeout=5), GlobalMotion)
        assert {"x", "y", "yaw"} <= set(plain.get(timeout=5))
        _, msg = stack.cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.25), after=t0, timeout=5)
        assert msg.angular.z == pytest.approx(-0.4)
        assert reset.wait_for_service(timeout_sec=5) and twist.get_subscription_count() == 1
        assert reset.call()["success"] is True
        future = reset.call_async({})
        assert future.result(timeout=10) == {"success": True, "message": "pose reset to the room centre"}
        with TestClient(stack.port, "admin", "admin-demo") as admin:  # sees the QoS the SDK published at
            assert admin.connect() == 0
            admin.subscribe("roslink/turtle1/from/alice/cmd/go_to_waypoint", qos=1)  # in force: SUBACK waited for
            for kind, publisher in waypoints.items():
                publisher.publish({"x": 0.0, "y": 0.0, "z": 0.0})
                got = admin.wait_for(lambda m: True)
                assert got.qos == (1 if kind == "default" else 0), kind
        wait_until("three ticks of the node's timer", lambda: len(ticks) >= 3, timeout=2)  # it ticks in spin
    finally:
        stop.set()
        thread.join(5)
        node.destroy_node()
    with pytest.raises(ServiceError, match="closed"):
        reset.call_async({}).result(timeout=2)  # the node's connection is gone


# -- the examples, as programs without rclpy and amqtt ------------------------------------------------------
def test_legacy_service_example_end_to_end(stack) -> None:
    from std_srvs.srv import Trigger

    env = no_ros_env(stack.work)
    args = ["examples/legacy_service.py", "--url", stack.url, "--self-test-seconds", "2", "--run-seconds", "60"]
    with run(args, stack.work / "legacy_service.log", env) as legacy:
        caller = subprocess.run([sys.executable, "examples/ros_caller.py", "--timeout", "20"], capture_output=True,
                                text=True, timeout=60, cwd=ROOT)
        assert caller.returncode == 0, caller.stdout + caller.stderr + legacy.output()
        assert "enable_motors(true): success=True message='motors enabled'" in caller.stdout
        assert "self_test: success=True message='self test passed: controller answers, motors enabled'" \
            in caller.stdout
        assert "enable_motors(false): success=True message='motors disabled'" in caller.stdout
        # kill the provider while a ROS call waits for it: the call fails cleanly, the services vanish
        self_test = stack.probe.node.create_client(Trigger, "/self_test")
        assert self_test.wait_for_service(timeout_sec=10)
        pending = self_test.call_async(Trigger.Request())
        never("the self test (2 s) ending before its provider is killed", pending.done, seconds=0.5)
        killed = time.monotonic()
        legacy.signal(signal.SIGKILL)
        wait_until("the pending call to fail after the provider died", pending.done,
                   timeout=killed + 4 - time.monotonic(), period=0.01)
        assert pending.result().success is False and "went away" in pending.result().message
        _wait_gone(self_test)
        stack.probe.node.destroy_client(self_test)
    assert "providing enable_motors and self_test on turtle1 as alice" in legacy.output()


def test_call_from_cloud_example(stack) -> None:
    env = no_ros_env(stack.work)
    out = subprocess.run([sys.executable, "examples/call_from_cloud.py", "--url", stack.url], env=env,
                         capture_output=True, text=True, timeout=30, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.count("'message': 'pose reset to the room centre'") == 2
    viewer = subprocess.run([sys.executable, "examples/call_from_cloud.py", "--url", stack.url, "--username", "bob",
                             "--password", "bob-demo"], env=env, capture_output=True, text=True, timeout=30, cwd=ROOT)
    assert viewer.returncode == 1 and "may not call 'reset'" in viewer.stderr


def test_spiral_example_draws_a_growing_track(stack, tmp_path) -> None:
    track = tmp_path / "track.csv"
    out = subprocess.run([sys.executable, "examples/spiral.py", "--url", stack.url, "--seconds", "3", "--csv",
                          str(track)], env=no_ros_env(stack.work), capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "reset: pose reset to the room centre" in out.stdout
    line = next(ln for ln in out.stdout.splitlines() if "poses reported" in ln)
    quarters = [float(d.split()[0]) for d in line.split(": ", 1)[1].split(", ")]
    assert len(quarters) == 4 and quarters[0] < quarters[3], line  # it moved, and outwards
    rows = track.read_text().splitlines()
    assert rows[0] == "t,x,y,yaw" and len(rows) > 10
    assert "S" in out.stdout and "E" in out.stdout
