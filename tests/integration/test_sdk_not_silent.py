"""Issue 13 items 1 and 6 against a real Mosquitto: the SDK never drops a command unseen, and stops on a refused login.

Item 1: a command or call on a client that is not connected (never connected, closed, or between a lost broker
and the reconnect) raises at once and sends nothing; an emergency stop the broker does not acknowledge raises.

Item 6: a login the broker refuses on a reconnect (a changed password) is tried once, not in an endless loop
that also feeds the broker's per-address login throttle: the SDK reports it through ``on_error`` and raises it
from then on, and a long-running CLI command exits with status 1 and the reason. A broker that is merely gone
is still retried.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from roslink_mqtt.client import ConnectError, RobotClient, RobotError, ServiceError
from tests.support.fleet_brokers import fleet_password_file
from tests.support.mosquitto import MosquittoProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT
from tests.support.waits import never, wait_until

pytestmark = pytest.mark.timeout(120)

REFUSED = re.compile(r"not authori[sz]ed|bad user name or password", re.I)


def _broker(workdir: Path) -> tuple[MosquittoProcess, Path]:
    pwfile = fleet_password_file(workdir)
    return MosquittoProcess(workdir, f"allow_anonymous false\npassword_file {pwfile}\n"), pwfile


def _change_password(pwfile: Path, user: str, like: str) -> None:
    """Give ``user`` the password of ``like`` (an admin changed it: the running client still has the old one)."""
    lines = dict(line.split(":", 1) for line in pwfile.read_text().splitlines())
    lines[user] = lines[like]
    pwfile.write_text("".join(f"{name}:{digest}\n" for name, digest in lines.items()))


# -- item 1 -------------------------------------------------------------------------------------------------
def test_a_client_that_never_connected_raises_and_sends_nothing(tmp_path) -> None:
    broker, _ = _broker(tmp_path)
    with broker, TestClient(broker.port, "admin", "admin-demo") as admin:
        assert admin.connect() == 0
        admin.subscribe("roslink/#")
        url = f"mqtt://127.0.0.1:{broker.port}"
        errors: queue.Queue[RobotError] = queue.Queue()
        client = RobotClient("alice", "alice-demo", url=url, on_error=errors.put)  # the docs' old Errors snippet
        try:
            with pytest.raises(ConnectError, match="not connected") as stop:
                client.emergency_stop("turtle1", "person in the aisle")
            assert type(stop.value).__name__ == "NotConnectedError" and "connect()" in str(stop.value)
            with pytest.raises(ConnectError, match="not connected"):
                client.twist("turtle1", lx=0.2, check=0.5)
            started = time.monotonic()
            with pytest.raises(ConnectError, match="not connected"):
                client.call("turtle1", "reset", timeout=5)
            assert time.monotonic() - started < 1, "the call waited for a reply that could never come"
            assert admin.drain(1.0) == [], "something reached the broker"
        finally:
            client.close()
        with pytest.raises(ConnectError, match="closed"):
            client.emergency_stop("turtle1")
        with pytest.raises(ServiceError, match="closed"):
            client.call("turtle1", "reset", timeout=5)


def test_commands_while_the_broker_is_away_raise(tmp_path) -> None:
    broker, _ = _broker(tmp_path)
    broker.start()
    url = f"mqtt://127.0.0.1:{broker.port}"
    try:
        with RobotClient("alice", "alice-demo", url=url) as client:
            broker.stop()
            wait_until("the client to notice the broker leave", lambda: not client.connected, timeout=15)
            with pytest.raises(ConnectError, match="connection .* was lost"):
                client.twist("turtle1", lx=0.2)
            with pytest.raises(ConnectError, match="was lost"):
                client.emergency_stop("turtle1", "broker restart")
            with pytest.raises(ConnectError, match="was lost"):
                client.call("turtle1", "reset", timeout=5)
            broker.start()  # a transient failure: the client reconnects by itself
            assert client.connection.connected.wait(15), "the client did not reconnect"
            with TestClient(broker.port, "admin", "admin-demo") as admin:
                assert admin.connect() == 0
                admin.subscribe("roslink/turtle1/from/alice/cmd/emergency_stop")
                assert client.emergency_stop("turtle1", "after the restart") is not None
                assert admin.wait_for(lambda m: True, timeout=5).json()["payload"]["reason"] == "after the restart"
    finally:
        broker.stop()


def test_node_publishers_while_the_broker_is_away(tmp_path, caplog) -> None:
    """rclpy's publish does not raise for the network: a warning (throttled) says what was not sent; a stop raises."""
    from roslink_mqtt.client import rclpy

    broker, _ = _broker(tmp_path)
    broker.start()
    node = rclpy.create_node("not_silent", robot="turtle1", url=f"mqtt://127.0.0.1:{broker.port}",
                             username="alice", password="alice-demo")
    try:
        twist = node.create_publisher("geometry_msgs/msg/Twist", "cmd/twist", 10)
        stop = node.create_publisher("std_msgs/msg/Bool", "cmd/emergency_stop", 10)
        broker.stop()
        wait_until("the node to notice the broker leave", lambda: not node.robot_client.connected, timeout=15)
        with caplog.at_level("WARNING"):
            for _ in range(20):
                twist.publish({"linear": {"x": 0.1}})
        warnings = [r.getMessage() for r in caplog.records if "not sent" in r.getMessage()]
        assert warnings == ["cmd/twist on turtle1 not sent: the connection to the broker is down"], warnings
        with pytest.raises(ConnectError, match="was lost"):
            stop.publish({"reason": "broker away"})
    finally:
        node.destroy_node()
        broker.stop()


def test_an_emergency_stop_the_broker_does_not_acknowledge_raises(tmp_path) -> None:
    broker, _ = _broker(tmp_path)
    broker.start()
    try:
        with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{broker.port}", keepalive=30) as client:
            broker.signal(signal.SIGSTOP)  # the connection looks fine; nothing answers
            try:
                started = time.monotonic()
                with pytest.raises(TimeoutError, match="did not acknowledge") as err:
                    client.emergency_stop("turtle1", "frozen broker")
                assert type(err.value).__name__ == "CommandNotConfirmed"
                assert 1.5 < time.monotonic() - started < 5  # the default: 2 s
            finally:
                broker.signal(signal.SIGCONT)
    finally:
        broker.stop()


# -- item 6 -------------------------------------------------------------------------------------------------
def _refusals(broker: MosquittoProcess, since: int) -> int:
    return len(REFUSED.findall(broker.output()[since:]))


def test_a_refused_login_on_reconnect_is_not_retried(tmp_path) -> None:
    broker, pwfile = _broker(tmp_path)
    broker.start()
    url = f"mqtt://127.0.0.1:{broker.port}"
    errors: queue.Queue[RobotError] = queue.Queue()
    client = RobotClient("alice", "alice-demo", url=url, robots=["turtle1"], on_error=errors.put).connect()
    from roslink_mqtt.client import rclpy

    node = rclpy.create_node("refused", robot="turtle1", url=url, username="alice", password="alice-demo")
    try:
        motion = client.subscribe("turtle1", "global_motion")
        _change_password(pwfile, "alice", like="bob")  # the admin changes alice's password; the broker restarts
        broker.stop()
        wait_until("the client to notice the broker leave", lambda: not client.connected, timeout=15)
        since = len(broker.output())
        broker.start()
        wait_until("the clients to try to log in again", lambda: _refusals(broker, since) >= 2, timeout=15)
        # more than the reconnect backoff cap (3 s): a retrying client would have tried again
        never("a third login try", lambda: _refusals(broker, since) > 2 and broker.output()[since:], seconds=4)
        assert _refusals(broker, since) == 2, f"retried: {broker.output()[since:]}"  # the client and the node
        error = errors.get(timeout=5)
        assert error.robot == "" and "refused the login of alice" in error.error and "not retrying" in error.error
        assert client.login_refused is not None and not client.connected
        with pytest.raises(ConnectError, match="refused the login") as refused:
            client.twist("turtle1", lx=0.1)
        assert type(refused.value).__name__ == "LoginRefused"
        with pytest.raises(ConnectError, match="refused the login"):
            motion.get(timeout=5)  # a waiting reader is told, not left waiting forever
        assert node.robot_client.login_refused is not None
        with pytest.raises(ConnectError, match="refused the login"):
            rclpy.spin(node)  # would otherwise spin forever on a connection that is over
    finally:
        node.destroy_node()
        client.close()
        broker.stop()


def test_cli_exits_when_its_login_is_refused_on_reconnect(tmp_path) -> None:
    broker, pwfile = _broker(tmp_path)
    broker.start()
    env = {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}
    echo = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.cli.main", "echo", "turtle1", "global_motion",
                             "--url", f"mqtt://127.0.0.1:{broker.port}", "-u", "alice"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
                            stdin=subprocess.DEVNULL)
    try:
        wait_until("echo to log in", lambda: "as alice" in broker.output() or "u'alice'" in broker.output(),
                   timeout=15)
        time.sleep(0.5)  # kept: echo's subscription (its SUBACK) after the login shows in no log at this log level
        _change_password(pwfile, "alice", like="bob")
        broker.stop()
        since = len(broker.output())
        broker.start()
        out, err = echo.communicate(timeout=20)  # before the fix: it retried forever
        assert echo.returncode == 1, out + err
        assert "refused the login of alice" in err and "Traceback" not in err, err
        wait_until("the broker to log the refused login", lambda: _refusals(broker, since) >= 1)
        never("a second refused login", lambda: _refusals(broker, since) > 1, seconds=1)
        assert _refusals(broker, since) == 1
    finally:
        if echo.poll() is None:
            echo.kill()
            echo.communicate()
        broker.stop()


def test_the_embedded_broker_refusing_a_changed_password_is_not_retried(tmp_path) -> None:
    """The same against the embedded broker, which answers CONNACK 5 (and counts each try in its throttle)."""
    from roslink_mqtt.config import load_fleet
    from tests.support.broker_setup import write_fleet
    from tests.support.embedded_broker import EmbeddedBrokerProcess

    fleet = write_fleet(tmp_path, read_only_service=False)
    broker = EmbeddedBrokerProcess(tmp_path, fleet).start()
    errors: queue.Queue[RobotError] = queue.Queue()
    client = RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{broker.port}", on_error=errors.put)
    try:
        client.connect()
        hashes = load_fleet(fleet)
        fleet.write_text(fleet.read_text().replace(hashes.password_hash("alice"), hashes.password_hash("bob")))
        broker.stop()
        wait_until("the client to notice the broker leave", lambda: not client.connected, timeout=15)
        since = len(broker.output())
        broker.start()
        error = errors.get(timeout=15)
        assert "refused the login of alice" in error.error

        def refused() -> list[str]:
            return [line for line in broker.output()[since:].splitlines() if "refused" in line and "alice" in line]

        never("a second login try", lambda: len(refused()) > 1 and refused(), seconds=4)  # > the backoff cap (3 s)
        assert len(refused()) == 1, refused()
    finally:
        client.close()
        broker.stop()
