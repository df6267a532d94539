"""Fault injection on the operator's side, with real processes: kill and freeze an operator, silence its stream; the
robot stops within docs/safety.md's deadlines (each printed, and collected in the run's closing summary).

These faults leave the broker and the bridge as they were, so the tests share one stack per broker (the faults to
brokers and bridges, which need a fresh one each: test_failsafe_faults.py).
"""

from __future__ import annotations

import queue
import signal
import time
from contextlib import ExitStack

import pytest

from tests.support.fault_stack import BROKERS, COMMAND_TIMEOUT, OPERATOR_TIMEOUT, Stack, check, cmd_vel_probe, zero
from tests.support.waits import never

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def probe():
    p = cmd_vel_probe()
    yield p
    p.close()


@pytest.fixture(scope="module", params=BROKERS)
def shared(request, tmp_path_factory, probe):
    """Every fault is injected against the embedded amqtt broker and against Mosquitto."""
    with ExitStack() as exits:
        stack = Stack(tmp_path_factory.mktemp(f"operator-faults-{request.param}"), probe, exits, request.param)
        stack.name = request.param
        yield stack


@pytest.fixture
def stack(shared: Stack) -> Stack:
    """The module's stack, as the previous test left it: the bridge alive, nothing moving, the viewer's queue empty."""
    assert shared.bridge.poll() is None, "the bridge died in an earlier test"
    while True:  # what earlier tests left: an ack this test waits for must be its own
        try:
            shared.viewer.messages.get_nowait()
        except queue.Empty:
            break
    return shared


def test_operator_sigkill_stops_robot(stack: Stack) -> None:
    t0 = time.monotonic()
    with stack.operator() as op:
        stack.wait_moving(t0)
        fault = time.monotonic()
        op.signal(signal.SIGKILL)
        check(stack, "operator SIGKILL → zero twist", stack.time_to_stop(fault, 0.5), 0.5)
        never("motion after the failsafe",
              lambda: [m for _, m in stack.probe.cmd_vel.since(fault + 0.5) if not zero(m)], seconds=1.0)
        stack.assert_no_motion_after(fault + 0.5)


def test_operator_sigstop_stops_robot(stack: Stack) -> None:
    t0 = time.monotonic()
    with stack.operator() as op:
        stack.wait_moving(t0)
        fault = time.monotonic()
        op.signal(signal.SIGSTOP)
        try:
            deadline = OPERATOR_TIMEOUT + 0.5
            check(stack, "operator SIGSTOP → stop", stack.time_to_stop(fault, deadline), deadline)
            stopped = time.monotonic()
            never("motion after the failsafe",
                  lambda: [m for _, m in stack.probe.cmd_vel.since(stopped) if not zero(m)], seconds=1.0)
            stack.assert_no_motion_after(stopped)
        finally:
            op.signal(signal.SIGCONT)


@pytest.mark.parametrize("shared", ["embedded"], indirect=True)  # the bridge's operator timeout: any broker shows it
def test_operator_sigstop_during_goal_stops_after_operator_timeout(stack: Stack) -> None:
    """No command stream (a waypoint goal): only operator presence can notice the frozen client."""
    from geometry_msgs.msg import PoseStamped

    goals = stack.probe.watch(PoseStamped, "/goal_pose")
    goals.wait_matched()
    t0 = time.monotonic()
    with stack.operator("--waypoint") as op:
        goals.wait_for(lambda m: m.pose.position.x == 2.0, timeout=20, after=t0)
        time.sleep(0.3)  # kept: the fault hits a goal under way, not one the bridge has just forwarded
        fault = time.monotonic()
        op.signal(signal.SIGSTOP)
        try:
            ack = stack.viewer.wait_for(lambda m: m.topic.endswith("/state/ack"), timeout=OPERATOR_TIMEOUT + 3)
            measured = ack.at - fault
            assert "operator alice went away" in ack.json()["payload"]["text"]
            check(stack, "operator SIGSTOP (goal, no stream) → stop", measured, OPERATOR_TIMEOUT + 0.5)
            # the heartbeat timeout (last beat up to 1 s before the freeze), not some other trigger
            assert measured >= OPERATOR_TIMEOUT - 1.1
        finally:
            op.signal(signal.SIGCONT)


def test_driving_client_killed_stops_robot_while_its_user_watches_elsewhere(stack: Stack) -> None:
    """alice watches from an SDK client (STANDBY presence) and drives a goal from another process.

    The user stays live through the watcher, and a goal has no dead-man: only the per-client rule
    (a *commanding* client of the driver went away) can stop the robot here.
    """
    from geometry_msgs.msg import PoseStamped

    from roslink_mqtt.client import RobotClient

    goals = stack.probe.watch(PoseStamped, "/goal_pose")
    goals.wait_matched()
    with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{stack.port}", robots=["turtle1"]) as watcher:
        watcher.wait_for_robot("turtle1", timeout=10)
        t0 = time.monotonic()
        with stack.operator("--waypoint") as op:
            goals.wait_for(lambda m: m.pose.position.x == 2.0, timeout=20, after=t0)
            time.sleep(0.3)  # kept: the fault hits a goal under way, not one the bridge has just forwarded
            fault = time.monotonic()
            op.signal(signal.SIGKILL)
            ack = stack.viewer.wait_for(lambda m: m.topic.endswith("/state/ack") and m.at > fault, timeout=5)
            assert "operator alice went away" in ack.json()["payload"]["text"]
            check(stack, "driving client SIGKILL, user still live → stop", ack.at - fault, 0.5)
        assert watcher.connected and watcher.robot("turtle1").online


@pytest.mark.parametrize("shared", ["embedded"], indirect=True)  # the dead-man is the bridge's: any broker shows it
def test_dead_man_stops_silent_stream(stack: Stack) -> None:
    t0 = time.monotonic()
    # stays alive (presence) but stops commanding 8 s after it connected: long enough for the bridge to obey some of
    # the stream on a loaded machine (3 s was not, once in a clean-clone run beside a CPU hog: nothing moved)
    with stack.operator("--stream-seconds", "8"):
        moving_at, _ = stack.probe.cmd_vel.wait_for(lambda m: m.linear.x > 0, timeout=20, after=t0)
        # the stop ends the stream, whenever the operator process got going: waited for, not slept on
        stop_at, _ = stack.probe.cmd_vel.wait_for(zero, timeout=20, after=moving_at)
        last_command = max(at for at, m in stack.probe.cmd_vel.since(t0) if at < stop_at and m.linear.x > 0)
        measured = stop_at - last_command
        check(stack, "command stream silent → dead-man stop", measured, COMMAND_TIMEOUT + 0.2)
        assert measured >= COMMAND_TIMEOUT - 0.1  # not earlier than promised either
        stack.assert_no_motion_after(stop_at)
