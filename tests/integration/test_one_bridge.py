"""One live bridge per robot: a bridge frozen without a last-will is replaced after a few heartbeat periods, and
stands down when it wakes up. A second bridge refused and ``--take-over`` fencing the live one run on the embedded
broker and the exported Mosquitto in tests/integration/test_one_driver.py (which shares their stack), on RabbitMQ in
tests/integration/test_rabbitmq_cluster.py; which of two claims wins is unit-tested in tests/unit/test_bridge_claim.py.
"""

from __future__ import annotations

import signal
import time
from contextlib import ExitStack
from pathlib import Path

import pytest

from roslink_mqtt.bridge.core.claim import EXIT_FENCED
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.mqtt_client import Received, TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(150)

REPLACED_WITHIN = 20.0  # s, a safety deadline: 2.5 heartbeat periods of silence plus a bridge's start


def _heartbeat(m: Received) -> dict:
    return m.json()["payload"]


def _online(m: Received, instance: str | None = None) -> bool:
    if not m.topic.endswith("/heartbeat") or m.retain or not m.payload:
        return False
    body = _heartbeat(m)
    return body["system_status"] == 4 and (instance is None or body["instance"] == instance)


def _exit_code(proc, timeout: float) -> int | None:
    """``proc``'s exit code, once it has exited; None if it still runs after ``timeout`` s."""
    try:
        wait_until("the process to exit", lambda: proc.poll() is not None, timeout=timeout)
    except AssertionError:
        return None
    return proc.poll()


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
        replaced_after = time.monotonic() - started  # the successor's start (ROS, the claim's wait) included
        record_measurement("silent bridge replaced (start to heartbeat)", replaced_after, REPLACED_WITHIN)
        assert replaced_after < REPLACED_WITHIN
        assert "stopped without a last-will" in successor.output()
        frozen.signal(signal.SIGCONT)
        assert _exit_code(frozen, 20) == EXIT_FENCED, frozen.output()
        assert successor.poll() is None
