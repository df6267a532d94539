"""Fault injection with real processes: kill and freeze brokers and bridges; the robot stops, and comes back.

Each test prints the measured time (collected in the run's closing summary). The deadlines are the safety
guarantees of docs/safety.md, not performance goals. Each fault gets a fresh stack (the operator's faults, which
leave the stack whole, share one: test_failsafe_operator.py).
"""

from __future__ import annotations

import signal
import time
from contextlib import ExitStack

import pytest

from tests.support.fault_stack import BROKERS, Stack, check, cmd_vel_probe, zero
from tests.support.waits import never, wait_until

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def probe():
    p = cmd_vel_probe()
    yield p
    p.close()


@pytest.fixture(params=BROKERS)
def stack(request, tmp_path, probe):
    """Every fault is injected against the embedded amqtt broker and against Mosquitto."""
    with ExitStack() as exits:
        stack = Stack(tmp_path, probe, exits, request.param)
        stack.name = request.param
        yield stack


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP], ids=["SIGKILL", "SIGSTOP"])
def test_broker_fault_stops_robot(stack: Stack, sig: int) -> None:
    t0 = time.monotonic()
    with stack.operator():
        stack.wait_moving(t0)
        fault = time.monotonic()
        stack.broker.signal(sig)
        try:
            check(stack, f"broker {sig.name} → stop", stack.time_to_stop(fault, 2.0), 2.0)
            stopped = time.monotonic()
            never("non-zero velocity after the failsafe",
                  lambda: [m for _, m in stack.probe.cmd_vel.since(stopped) if not zero(m)][:3], seconds=1.0)
            stack.assert_no_motion_after(stopped)
        finally:
            if sig == signal.SIGSTOP:
                stack.broker.signal(signal.SIGCONT)


def test_broker_restart_bridge_recovers(stack: Stack) -> None:
    before = stack.viewer.wait_for(lambda m: m.topic.endswith("/heartbeat"), timeout=3).json()
    stack.broker.kill()
    wait_until("the bridge to notice the broker gone", lambda: "lost the broker" in stack.bridge.output())
    restart = time.monotonic()
    stack.broker.start()
    viewer = stack.connect_viewer()  # waits for a retained heartbeat with status ACTIVE
    after = stack.heartbeat
    if after["sequence_number"] <= before["sequence_number"]:
        # The kill can take the PUBACK of the last heartbeat with it; paho then sends that heartbeat again when it
        # reconnects (QoS 1 is at least once), so the first one seen may be the old one: wait for the next.
        after = viewer.wait_for(lambda m: m.topic.endswith("/heartbeat")
                                and m.json()["sequence_number"] > before["sequence_number"], timeout=5).json()
    check(stack, "broker restart → bridge back online", time.monotonic() - restart, 5.0)
    # The same bridge process came back (not a restarted one) and this heartbeat was sent after the restart.
    assert stack.bridge.poll() is None, "the bridge exited when the broker went away"
    assert after["payload"]["session"] == before["payload"]["session"], (before, after)
    assert after["sequence_number"] > before["sequence_number"], (before, after)
    t0 = time.monotonic()
    with stack.operator():
        stack.wait_moving(t0)  # commands work again


def test_bridge_sigkill_shows_offline(stack: Stack) -> None:
    fault = time.monotonic()
    stack.bridge.signal(signal.SIGKILL)
    stack.viewer.wait_for(lambda m: m.topic.endswith("/heartbeat") and m.json()["payload"]["system_status"] == 8,
                          timeout=5)
    check(stack, "bridge SIGKILL → clients see offline", time.monotonic() - fault, 1.0)

