"""Issue 13 items 4 and 8 against real brokers and a real bridge: nothing is refused unseen, nobody sees others' errors.

Item 4: the broker drops a viewer's command or forbidden call without a word (MQTT 3.1.1 has no negative PUBACK),
so the bridge never hears of it. The bridge publishes a retained access report per user; the SDK and the CLI refuse
from it at once (CommandRefused / ServiceError / ``offer.refused``; exit status 1 and the reason).

Item 8: every program of a user reads ``to/<user>/error``; reports name the sender's client id, and the SDK and CLI
show their own (and those that name nobody) only.

Both brokers: the embedded one and Mosquitto running the files ``acl export`` writes. No sim is needed: the bridge
alone answers (a call to ``reset`` then fails with "service not available", which proves it reached the bridge).
"""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from roslink_mqtt.client import CommandRefused, RobotClient, RobotError, ServiceError
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT, bridge_args, bridge_env, run
from tests.support.stack import live_robot
from tests.support.waits import never, paced, wait_until

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module", params=["embedded", "mosquitto"])
def stack(request, tmp_path_factory):
    work = tmp_path_factory.mktemp(f"refusals-{request.param}")
    fleet = write_fleet(work)  # demo fleet + read-only service 'status' (bob, a viewer, may call it)
    with live_robot(work, request.param, fleet=fleet, sim=False) as live:
        yield SimpleNamespace(backend=request.param, port=live.port, url=live.url, work=work)


def cli(port: int, user: str, *args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, "--url", f"mqtt://127.0.0.1:{port}",
                           "-u", user], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def _access(client: RobotClient, robot: str, timeout: float = 5.0):  # -> AccessReport
    wait_until(f"an access report from {robot}", lambda: client.access(robot) is not None, timeout=timeout)
    report = client.access(robot)
    assert report is not None
    return report


# -- item 4: broker denials are visible -------------------------------------------------------------------
def test_cli_viewer_gets_the_reason_and_a_non_zero_exit(stack) -> None:
    pub = cli(stack.port, "bob", "pub", "turtle1", "twist", '{"lx": 0.2}')
    assert pub.returncode == 1, pub.stdout + pub.stderr
    assert "not an operator of turtle1" in pub.stdout and "sent 1" not in pub.stdout
    started = time.monotonic()
    call = cli(stack.port, "bob", "call", "turtle1", "reset", "--timeout", "8")
    assert call.returncode == 1 and "may not call 'reset'" in call.stdout, call.stdout + call.stderr
    assert time.monotonic() - started < 6, "the refusal came from a timeout, not from what the client knows"
    allowed = cli(stack.port, "bob", "call", "turtle1", "status", "--timeout", "8")  # read-only: reaches the bridge
    assert allowed.returncode == 1 and "service not available" in allowed.stdout, allowed.stdout + allowed.stderr


def test_sdk_viewer_is_refused_at_the_call_site(stack) -> None:
    with RobotClient("bob", "bob-demo", url=stack.url, robots=["turtle1"]) as bob:
        bob.wait_for_robot("turtle1", timeout=10)
        with pytest.raises(CommandRefused, match="not an operator of turtle1") as refused:
            bob.twist("turtle1", lx=0.3)  # no check=: the broker would drop it, so nothing could come back
        assert refused.value.error.topic == "roslink/turtle1/from/bob/cmd/twist"
        # any granted user may stop the robot (robots.yaml `estop: operators` would refuse it here)
        bob.emergency_stop("turtle1", "viewer stops", check=0.5)
        with RobotClient("alice", "alice-demo", url=stack.url, robots=["turtle1"]) as alice:
            alice.wait_for_robot("turtle1", timeout=10)
            alice.arm("turtle1", check=0.5)  # only an operator (the holder of control) resumes it
        started = time.monotonic()
        with pytest.raises(ServiceError, match="may not call 'reset'"):
            bob.call("turtle1", "reset", timeout=5)
        assert time.monotonic() - started < 1
        with pytest.raises(ServiceError, match="service not available"):
            bob.call("turtle1", "status", timeout=10)
        offer = bob.provide("turtle1", "bob_service", "std_srvs/srv/Trigger", lambda args: {"success": True})
        assert offer.refused is not None and "may not provide services" in offer.refused
        assert any(e.topic.endswith("/provide/bob_service") for e in bob.recent_errors)
        from roslink_mqtt.protocol import AccessReport

        assert _access(bob, "turtle1") == AccessReport("viewer", ("status",), estop=True)


def test_sdk_operator_is_not_refused_and_a_stranger_is(stack) -> None:
    with RobotClient("alice", "alice-demo", url=stack.url, robots=["turtle1"]) as alice:
        alice.wait_for_robot("turtle1", timeout=10)
        assert alice.twist("turtle1", lx=0.0, check=0.3) is not None
        with pytest.raises(ServiceError, match="service not available"):  # no sim: the bridge itself answers
            alice.call("turtle1", "reset", timeout=10)
        from roslink_mqtt.protocol import AccessReport

        assert _access(alice, "turtle1") == AccessReport("operator", ("reset", "status"), ("fibonacci",), estop=True,
                                                         snapshot=True)
    if stack.backend == "embedded":  # it refuses carol's subscription to turtle1/to/carol/# (SUBACK 0x80)
        with RobotClient("carol", "carol-demo", url=stack.url, robots=["turtle1"]) as carol:
            with pytest.raises(CommandRefused, match="no grant on turtle1"):
                carol.twist("turtle1", lx=0.1)


# -- item 8: each program sees its own errors ----------------------------------------------------------------
def test_error_reports_reach_only_their_sender(stack) -> None:
    got_a: queue.Queue[RobotError] = queue.Queue()
    got_b: queue.Queue[RobotError] = queue.Queue()
    with RobotClient("alice", "alice-demo", url=stack.url, robots=["turtle1"], on_error=got_a.put) as a, \
            RobotClient("alice", "alice-demo", url=stack.url, robots=["turtle1"], on_error=got_b.put) as b:
        a.wait_for_robot("turtle1", timeout=10)
        b.wait_for_robot("turtle1", timeout=10)
        a.command("turtle1", "fly", {"x": 1})  # a generic rule the robot does not have
        a.disarm("turtle1")
        try:
            a.go_to_waypoint("turtle1", x=1.0, y=0.0)  # a ROSLink envelope, refused: motion is disarmed
            mine = [got_a.get(timeout=5), got_a.get(timeout=5)]
        finally:
            a.arm("turtle1")
        never("a's errors reaching b", lambda: not got_b.empty(), seconds=1.0)
        assert got_b.empty(), f"b saw a's errors: {list(got_b.queue)}"
        assert sorted(e.topic.rsplit("/", 1)[1] for e in mine) == ["fly", "go_to_waypoint"]
        assert "disarmed by alice" in next(e.error for e in mine if e.topic.endswith("go_to_waypoint"))
        assert {e.client_id for e in mine} == {a.client_id}
        assert not any(e.client_id == a.client_id for e in b.recent_errors)
        # a sender that names no client id: its report may concern anyone, so every program shows it
        with TestClient(stack.port, "alice", "alice-demo") as raw:
            assert raw.connect() == 0
            raw.publish("roslink/turtle1/from/alice/fly", {"x": 1})
        for got in (got_a, got_b):
            error = got.get(timeout=5)
            assert error.client_id is None and "no mapping for 'fly'" in error.error


@pytest.mark.parametrize("stack", ["embedded"], indirect=True)  # the CLI's filtering: any broker shows it
def test_cli_pub_does_not_print_another_programs_errors(stack) -> None:
    env = {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}
    pub = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.cli.main", "pub", "turtle1", "twist", '{"lx": 0.0}',
                            "--rate", "10", "--duration", "3", "--url", stack.url, "-u", "alice"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
                           stdin=subprocess.DEVNULL)
    try:
        with RobotClient("alice", "alice-demo", url=stack.url, robots=["turtle1"]) as other:
            other.wait_for_robot("turtle1", timeout=10)
            for _ in paced(0.2, within=3, stop=lambda: pub.poll() is not None):
                other.command("turtle1", "fly", {"x": 1})  # refused: a report for `other`, not for pub
        out, err = pub.communicate(timeout=30)
    finally:
        if pub.poll() is None:
            pub.kill()
    assert pub.returncode == 0 and "sent 30 × twist" in out, out + err
    assert "fly" not in out + err, err


def test_cli_teleop_as_a_viewer_ends_with_the_reason(stack) -> None:
    """teleop streams twists in a loop of its own: the SDK's refusal must end it cleanly, not as a traceback."""
    import pty

    primary, secondary = pty.openpty()  # teleop needs a terminal
    env = {**os.environ, "ROSLINK_PASSWORD": "bob-demo"}
    try:
        done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "teleop", "turtle1", "--url", stack.url,
                               "-u", "bob"], stdin=secondary, capture_output=True, text=True, env=env, cwd=ROOT,
                              timeout=30)
    finally:
        os.close(primary)
        os.close(secondary)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "not an operator of turtle1" in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_access_reports_follow_a_reload(tmp_path) -> None:
    """SIGHUP: the bridge republishes every report (bob promoted) and clears the report of a user who lost the robot."""
    import signal

    from tests.support.net import free_port

    viewer = "      - {key: demo-key-turtle1, role: viewer}\n"
    fleet = write_fleet(tmp_path, port=free_port())
    assert viewer in fleet.read_text()
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker, \
            run(bridge_args("turtle1", broker.port, config=fleet), tmp_path / "bridge.log", bridge_env("turtle1")) \
            as bridge, TestClient(broker.port, "admin", "admin-demo") as admin:
        assert admin.connect() == 0
        admin.subscribe("roslink/turtle1/to/+/access")
        bob = "roslink/turtle1/to/bob/access"
        assert admin.wait_for(lambda m: m.topic == bob, timeout=30).json() == {"role": "viewer",
                                                                               "services": ["status"], "actions": [],
                                                                               "estop": True, "snapshot": False}
        fleet.write_text(fleet.read_text().replace(viewer, viewer.replace("viewer", "operator")))
        bridge.signal(signal.SIGHUP)
        promoted = admin.wait_for(lambda m: m.topic == bob, timeout=10).json()
        assert promoted == {"role": "operator", "services": ["reset", "status"], "actions": ["fibonacci"],
                            "estop": True, "snapshot": True}  # an operator may ask for turtle1's snapshots
        fleet.write_text(fleet.read_text().replace(viewer.replace("viewer", "operator"), ""))
        bridge.signal(signal.SIGHUP)
        cleared = admin.wait_for(lambda m: m.topic == bob, timeout=10)
        assert cleared.payload == b"" and cleared.retain is False  # a live delivery of the clearing message
