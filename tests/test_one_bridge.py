"""One live bridge per robot, with real bridges on the embedded broker and on the exported Mosquitto.

A second bridge for a robot refuses to start and names the live one; ``--take-over`` makes the live one stop its
robot and exit; a bridge frozen without a last-will is replaced after a few heartbeat periods, and stands down
when it wakes up. The claim itself (which of two claims wins) is unit-tested in tests/test_bridge_claim.py.
"""

from __future__ import annotations

import signal
import socket
import time
from contextlib import ExitStack
from pathlib import Path

import pytest

from roslink_mqtt.bridge.claim import EXIT_DUPLICATE, EXIT_FENCED

from .support.broker_setup import ExportedMosquitto, write_fleet
from .support.embedded_broker import EmbeddedBrokerProcess
from .support.mqtt_client import Received, TestClient
from .support.procs import bridge_args, bridge_env, run
from .support.ros import RosProbe

pytestmark = pytest.mark.timeout(150)


@pytest.fixture(scope="module")
def probe():
    from geometry_msgs.msg import Twist

    p = RosProbe()
    p.cmd_vel = p.watch(Twist, "/cmd_vel")
    yield p
    p.close()


def _heartbeat(m: Received) -> dict:
    return m.json()["payload"]


def _online(m: Received, instance: str | None = None) -> bool:
    if not m.topic.endswith("/heartbeat") or m.retain or not m.payload:
        return False
    body = _heartbeat(m)
    return body["system_status"] == 4 and (instance is None or body["instance"] == instance)


def _exit_code(proc, timeout: float) -> int | None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        code = proc.poll()
        if code is not None:
            return code
        time.sleep(0.05)
    return None


@pytest.mark.parametrize("broker", ["embedded", "mosquitto"])
def test_second_bridge_refused_then_take_over_fences_the_live_one(tmp_path: Path, probe, broker: str) -> None:
    with ExitStack() as stack:
        if broker == "mosquitto":
            config = write_fleet(tmp_path, read_only_service=False)
            server = stack.enter_context(ExportedMosquitto(tmp_path, config))
            extra = {"config": config}
        else:
            server, extra = stack.enter_context(EmbeddedBrokerProcess(tmp_path)), {}
        port = server.port
        viewer = stack.enter_context(TestClient(port, "bob", "bob-demo"))
        assert viewer.connect() == 0
        viewer.subscribe("roslink/turtle1/heartbeat")
        first = stack.enter_context(run(bridge_args("turtle1", port, **extra), tmp_path / "first.log",
                                        bridge_env("turtle1")))
        live = _heartbeat(viewer.wait_for(_online, timeout=30))
        assert live["pid"] == first.pid and live["host"] == socket.gethostname() and live["take_over"] == 0

        # a second bridge: refused, with the live one named, and an exit code systemd does not restart
        second = stack.enter_context(run(bridge_args("turtle1", port, **extra), tmp_path / "second.log",
                                         bridge_env("turtle1")))
        assert _exit_code(second, 30) == EXIT_DUPLICATE, second.output()
        said = second.output()
        assert f"already has a live bridge on {socket.gethostname()} (pid {first.pid})" in said, said
        assert "--take-over" in said
        assert first.poll() is None
        beats = [m for m in viewer.drain(2.5) if _online(m)]
        assert beats and {_heartbeat(m)["instance"] for m in beats} == {live["instance"]}, beats

        # --take-over: the live one stops its robot and exits (4); the new one runs and says it took over
        since = time.monotonic()
        third = stack.enter_context(run(bridge_args("turtle1", port, "--take-over", **extra),
                                        tmp_path / "third.log", bridge_env("turtle1")))
        assert _exit_code(first, 30) == EXIT_FENCED, first.output()
        assert "taken over by the bridge" in first.output()
        probe.cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, timeout=5, after=since)
        new = _heartbeat(viewer.wait_for(lambda m: _online(m) and _heartbeat(m)["pid"] == third.pid, timeout=30))
        assert new["take_over"] == 1
        assert "took over from the bridge" in third.output()
        assert third.poll() is None


def test_silent_bridge_replaced_and_stands_down_when_it_wakes(tmp_path: Path) -> None:
    """SIGSTOP: no last-will (the broker still sees the connection), no heartbeat. The next bridge starts after a
    few periods; the frozen one, resumed, sees the newer take-over claim and exits."""
    with ExitStack() as stack:
        server = stack.enter_context(EmbeddedBrokerProcess(tmp_path))
        viewer = stack.enter_context(TestClient(server.port, "bob", "bob-demo"))
        assert viewer.connect() == 0
        viewer.subscribe("roslink/turtle1/heartbeat")
        frozen = stack.enter_context(run(bridge_args("turtle1", server.port), tmp_path / "frozen.log",
                                         bridge_env("turtle1")))
        viewer.wait_for(_online, timeout=30)
        frozen.signal(signal.SIGSTOP)
        stack.callback(lambda: frozen.poll() is None and frozen.signal(signal.SIGCONT))
        started = time.monotonic()
        successor = stack.enter_context(run(bridge_args("turtle1", server.port), tmp_path / "successor.log",
                                            bridge_env("turtle1")))
        beat = _heartbeat(viewer.wait_for(lambda m: _online(m) and _heartbeat(m)["pid"] == successor.pid,
                                          timeout=30))
        assert beat["take_over"] == 1
        assert time.monotonic() - started < 20
        assert "stopped without a last-will" in successor.output()
        frozen.signal(signal.SIGCONT)
        assert _exit_code(frozen, 20) == EXIT_FENCED, frozen.output()
        assert successor.poll() is None
