"""Services both ways through the bridge, with real processes (sim robot, bridge, Mosquitto, a provider)."""

from __future__ import annotations

import signal
import threading
import time
import uuid
from pathlib import Path

import pytest
import yaml

from tests.support.mqtt_client import TestClient
from tests.support.procs import CONFIG, run
from tests.support.ros import RosProbe
from tests.support.stack import live_robot
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(120)


def services_config(tmp: Path) -> Path:
    """The demo fleet plus services that are missing, slow and read-only, for the error cases."""
    fleet = yaml.safe_load(CONFIG.read_text())
    fleet["robots"]["turtle1"]["services"] = [
        {"name": "reset", "ros_service": "reset", "ros_type": "std_srvs/srv/Trigger", "timeout": 5.0},
        {"name": "missing", "ros_service": "no_such_service", "ros_type": "std_srvs/srv/Trigger", "timeout": 2.0},
        {"name": "slow", "ros_service": "/slow_service", "ros_type": "std_srvs/srv/Trigger", "timeout": 1.0},
        {"name": "peek", "ros_service": "/peek", "ros_type": "std_srvs/srv/Trigger", "read_only": True},
    ]
    mine = ("cmd/takeoff", "cmd/land")  # the demo maps these too (to the sim); here they call the test's services
    fleet["robots"]["turtle1"]["rules"] = [r for r in fleet["robots"]["turtle1"]["rules"]
                                           if r["mqtt_topic"] not in mine] + [
        {"direction": "mqtt_to_ros", "mqtt_topic": "cmd/takeoff", "ros_topic": "/takeoff_srv",
         "ros_type": "std_srvs/srv/Trigger", "preset": "takeoff"},
        {"direction": "mqtt_to_ros", "mqtt_topic": "cmd/land", "ros_topic": "/land_srv",
         "ros_type": "std_srvs/srv/SetBool", "preset": "land"},
    ]
    path = tmp / "robots.yaml"
    path.write_text(yaml.safe_dump(fleet))
    return path


@pytest.fixture(scope="module", params=["single", "events"])
def stack(tmp_path_factory, request):
    """Services both ways through a bridge spun by each executor (bridge.executor): same behaviour expected."""
    from std_srvs.srv import Trigger

    work = tmp_path_factory.mktemp(f"services-{request.param}")
    config = services_config(work)
    probe = RosProbe()
    release = threading.Event()

    def slow(_req, resp):
        release.wait(3.0)
        resp.success, resp.message = True, "late"
        return resp

    def peek(_req, resp):
        resp.success, resp.message = True, "looked"
        return resp

    def takeoff(_req, resp):
        resp.success, resp.message = True, "airborne"
        return resp

    probe.node.create_service(Trigger, "/takeoff_srv", takeoff)
    probe.node.create_service(Trigger, "/slow_service", slow)
    probe.node.create_service(Trigger, "/peek", peek)
    try:
        with live_robot(work, "logins", bridge_config=config,
                        bridge_env_extra={"ROSLINK_EXECUTOR": request.param}) as live:
            alice = live.client("alice", operator=True,
                                subscribe=("roslink/turtle1/to/alice/#", "roslink/turtle1/heartbeat"))
            _wait_until_served(alice, "peek")  # the probe's services discovered by the bridge (they share a node)
            yield {"port": live.port, "alice": alice, "probe": probe, "work": work, "release": release}
    finally:
        release.set()
        probe.close()


def call(client: TestClient, user: str, service: str, args: dict | None = None, timeout: float = 15.0) -> dict:
    call_id = uuid.uuid4().hex
    client.publish(f"roslink/turtle1/from/{user}/call/{service}", {"id": call_id, "args": args or {}})
    reply = client.wait_for(lambda m: m.topic == f"roslink/turtle1/to/{user}/reply/{service}"
                            and m.json().get("id") == call_id, timeout=timeout)
    return reply.json()


def _wait_until_served(client: TestClient, service: str, timeout: float = 20.0) -> dict:
    """Until the bridge sees the ROS server of ``service`` (before that it answers "service not available"): the
    first reply that succeeded."""
    return wait_until(f"the bridge to see a server for '{service}'",
                      lambda: (reply := call(client, "alice", service))["result"] and reply,
                      timeout=timeout, period=0.2)


def test_ros_service_called_from_mqtt(stack) -> None:
    reply = _wait_until_served(stack["alice"], "reset", timeout=15)  # the sim's service may take a moment
    assert reply["result"] is True
    assert reply["values"] == {"success": True, "message": "pose reset to the room centre"}


def test_service_errors(stack) -> None:
    alice = stack["alice"]
    bad = call(alice, "alice", "reset", {"force": True})
    assert bad["result"] is False and bad["error"].startswith("bad arguments: args.force: unknown field")
    unknown = call(alice, "alice", "warp")
    assert unknown["result"] is False and "unknown service 'warp'" in unknown["error"]
    missing = call(alice, "alice", "missing")
    assert missing["result"] is False and "service not available" in missing["error"]


def test_service_timeout_does_not_block_topics(stack) -> None:
    alice = stack["alice"]
    t0 = time.monotonic()
    call_id = uuid.uuid4().hex
    alice.publish("roslink/turtle1/from/alice/call/slow", {"id": call_id, "args": {}})
    alice.subscribe("roslink/turtle1/state/global_motion")
    # state keeps flowing while the call is pending: motion arrives before the call's (timeout) reply
    motions = []
    reply = alice.wait_for(lambda m: (motions.append(m) if m.topic.endswith("/state/global_motion") else None)
                           or (m.topic.endswith("/reply/slow") and m.json()["id"] == call_id), timeout=10)
    assert motions and motions[0].at < reply.at
    assert reply.json() == {"id": call_id, "result": False, "error": "timeout: no answer within 1 s"}
    assert 0.9 <= time.monotonic() - t0 < 3.0
    stack["release"].set()


def test_viewer_may_call_read_only_services_only(stack) -> None:
    with TestClient(stack["port"], "bob", "bob-demo", operator=True) as bob:
        assert bob.connect() == 0
        bob.subscribe("roslink/turtle1/to/bob/#")
        refused = call(bob, "bob", "reset")
        assert refused["result"] is False
        assert refused["error"] == "user 'bob' may not call 'reset' (operators only; it is not read-only): not an " \
                                   "operator of turtle1 (a viewer)"
        allowed = call(bob, "bob", "peek")
        assert allowed == {"id": allowed["id"], "result": True, "values": {"success": True, "message": "looked"}}


def test_mqtt_provided_service_called_from_ros(stack) -> None:
    from std_srvs.srv import Trigger

    probe, work, port = stack["probe"], stack["work"], stack["port"]
    client = probe.node.create_client(Trigger, "/self_test")
    hang = probe.node.create_client(Trigger, "/hang")
    args = ["-m", "tests.support.provider_proc", str(port), "alice", "alice-demo", "turtle1"]
    with run(args, work / "provider.log") as provider:
        assert client.wait_for_service(timeout_sec=15), "the provided service never appeared in ROS"
        result = _call_sync(client, Trigger.Request(), 10)
        assert (result.success, result.message) == (True, "all good")
        # a call the provider never answers, then the provider dies: it fails cleanly
        assert hang.wait_for_service(timeout_sec=10)
        future = hang.call_async(Trigger.Request())
        # the call is pending once the bridge has passed it on (alice, the provider's login, reads its requests too)
        stack["alice"].wait_for(lambda m: m.topic == "roslink/turtle1/to/alice/request/hang", timeout=10)
        killed = time.monotonic()
        provider.signal(signal.SIGKILL)
        response = _wait(future, 10)
        assert response.success is False and "went away" in response.message
        assert time.monotonic() - killed < 3.0
    wait_until("the provided service to leave ROS with its provider", lambda: not client.service_is_ready(),
               timeout=10, period=0.1)


def test_provided_calls_overlap_and_time_out(stack) -> None:
    """Waiting calls hold no bridge thread: many overlap; a provider that stays silent times out."""
    from std_srvs.srv import Trigger

    probe, work, port, alice = stack["probe"], stack["work"], stack["port"], stack["alice"]
    later = probe.node.create_client(Trigger, "/later")
    mute = probe.node.create_client(Trigger, "/mute")
    args = ["-m", "tests.support.provider_proc", str(port), "alice", "alice-demo", "turtle1"]
    with run(args, work / "provider-overlap.log"):
        assert later.wait_for_service(timeout_sec=15) and mute.wait_for_service(timeout_sec=15)
        # one call first: a ROS client may see the service before its response path is matched
        assert _wait(later.call_async(Trigger.Request()), 15).success
        # 8 at once: 4x what a thread-per-call bridge allowed, and within the ROS default service queue (10)
        futures = [later.call_async(Trigger.Request()) for _ in range(8)]
        silent = mute.call_async(Trigger.Request())
        answers = [_wait(f, 15) for f in futures]
        assert all(a.success for a in answers), [a.message for a in answers]
        assert len({a.message for a in answers}) == 8, "each call must get its own answer"
        response = _wait(silent, 10)
        assert (response.success, response.message) == (False, "provider alice did not answer within 1 s")
        # a response naming no waiting call (here: an id that is not even a string) is refused, not fatal
        alice.publish("roslink/turtle1/from/alice/response/later", {"id": [1], "result": True})
        error = alice.wait_for(lambda m: m.topic == "roslink/turtle1/to/alice/error", timeout=5).json()
        assert "no pending request with id [1]" in str(error)
        assert _wait(later.call_async(Trigger.Request()), 15).success, "the bridge must keep serving"


def _wait(future, timeout: float):
    wait_until("the ROS call to complete", future.done, timeout=timeout, period=0.02)
    return future.result()


def _call_sync(client, request, timeout: float):
    return _wait(client.call_async(request), timeout)


def test_command_preset_carried_out_by_a_ros_service(stack) -> None:
    alice = stack["alice"]
    alice.subscribe("roslink/turtle1/state/ack")

    def acked():  # the probe's service may take a moment to be discovered by the bridge: until then, an error
        seq = int(time.monotonic() * 1000)
        alice.publish("roslink/turtle1/from/alice/cmd/takeoff",
                      {"message_id": 102, "sequence_number": seq, "payload": {"altitude": 1.5}})
        got = alice.wait_for(lambda m: m.topic.endswith("/state/ack") or m.topic.endswith("/to/alice/error"), 5)
        return got if got.topic.endswith("/state/ack") else None

    got = wait_until("an ack of takeoff (carried out by the probe's service)", acked, timeout=15, period=0.3)
    ack = got.json()["payload"]
    assert ack["command"] == 102 and ack["result"] == 0 and ack["text"] == "airborne"
    alice.publish("roslink/turtle1/from/alice/cmd/land", {})
    err = alice.wait_for(lambda m: m.topic.endswith("/to/alice/error")).json()
    assert "service not available: /land_srv (std_srvs/srv/SetBool)" in err["error"]
