"""ROS actions served by an MQTT client (the SDK's serve_action), called from a real rclpy ActionClient.

Real processes: broker (embedded, and Mosquitto with the exported ACL), the bridge, and the provider as its own
process so it can be killed. goal → feedback → result; a cancel; a rejection by the provider; the provider's
SIGKILL aborts the goal it held (time printed) and takes the ROS action server down; a viewer cannot serve.
"""

from __future__ import annotations

import signal
import sys
import time
from types import SimpleNamespace

import pytest

from tests.support.broker_setup import write_fleet
from tests.support.measure import record_measurement
from tests.support.procs import run
from tests.support.ros import RosProbe
from tests.support.stack import live_robot
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(180)


def _wait(future, timeout: float = 15.0):
    wait_until("an answer from the action server", future.done, timeout=timeout, period=0.02)
    return future.result()


@pytest.fixture(scope="module", params=["embedded", "mosquitto", "embedded-events"])
def stack(request, tmp_path_factory):
    """``-events``: the bridge runs rclpy's EventsExecutor, which moves provided actions to a node and a
    single-threaded executor of their own (bridge/main.py): the same behaviour is expected."""
    from rclpy.action import ActionClient
    from test_msgs.action import Fibonacci

    work = tmp_path_factory.mktemp(f"provided-actions-{request.param}")
    backend, _, executor = request.param.partition("-")
    probe = RosProbe()
    try:
        with live_robot(work, backend, fleet=write_fleet(work), sim=False,
                        bridge_env_extra={"ROSLINK_EXECUTOR": executor or "single"}) as live:
            client = ActionClient(probe.node, Fibonacci, "/plan")
            yield SimpleNamespace(backend=backend, port=live.port, work=work, client=client, probe=probe,
                                  Goal=Fibonacci.Goal, url=live.url)
    finally:
        probe.close()


def gone(client, timeout: float = 10.0) -> None:
    """Wait until no action server answers on /plan (a provider that left takes it down)."""
    wait_until("the action server to go with its provider", lambda: not client.server_is_ready(), timeout=timeout,
               period=0.1)


def provider(stack, name: str = "provider"):
    gone(stack.client)  # an earlier test's provider: its server must be down first
    return run(["-m", "tests.support.action_provider_proc", stack.url, "alice", "alice-demo", "turtle1"],
               stack.work / f"{name}.log")


def test_goal_feedback_result_cancel_and_rejection(stack) -> None:
    from action_msgs.msg import GoalStatus

    with provider(stack):
        assert stack.client.wait_for_server(timeout_sec=20), "the bridge never served /plan"
        feedback: list[list[int]] = []
        handle = _wait(stack.probe.on_spin(lambda: stack.client.send_goal_async(
            stack.Goal(order=6), feedback_callback=lambda fb: feedback.append(list(fb.feedback.sequence)))))
        assert handle.accepted
        result = _wait(stack.probe.on_spin(handle.get_result_async))
        assert result.status == GoalStatus.STATUS_SUCCEEDED
        assert list(result.result.sequence) == [0, 1, 1, 2, 3, 5, 8]
        assert feedback and feedback[-1][:3] == [0, 1, 1]
        running: list[list[int]] = []
        long = _wait(stack.probe.on_spin(lambda: stack.client.send_goal_async(
            stack.Goal(order=40), feedback_callback=lambda fb: running.append(list(fb.feedback.sequence)))))
        assert long.accepted
        wait_until("feedback from the long goal (it runs)", lambda: running, timeout=15)
        cancel = _wait(stack.probe.on_spin(long.cancel_goal_async))
        assert len(cancel.goals_canceling) == 1
        ended = _wait(stack.probe.on_spin(long.get_result_async))
        assert ended.status == GoalStatus.STATUS_CANCELED and len(ended.result.sequence) < 41
        rejected = _wait(stack.probe.on_spin(lambda: stack.client.send_goal_async(stack.Goal(order=99))))
        assert not rejected.accepted


def test_provider_sigkill_aborts_its_goal_and_removes_the_server(stack) -> None:
    from action_msgs.msg import GoalStatus

    with provider(stack, "doomed") as proc:
        assert stack.client.wait_for_server(timeout_sec=20)
        running: list[list[int]] = []
        handle = _wait(stack.probe.on_spin(lambda: stack.client.send_goal_async(
            stack.Goal(order=40), feedback_callback=lambda fb: running.append(list(fb.feedback.sequence)))))
        assert handle.accepted
        result_future = stack.probe.on_spin(handle.get_result_async)
        wait_until("feedback from the goal (the provider runs it)", lambda: running, timeout=15)
        killed = time.monotonic()
        proc.signal(signal.SIGKILL)
        result = _wait(result_future, timeout=10)
        took = time.monotonic() - killed
    assert result.status == GoalStatus.STATUS_ABORTED
    record_measurement(f"[{stack.backend}] provider SIGKILL -> goal aborted", took, 3.0)
    print(f"[{stack.backend}] provider SIGKILL -> goal aborted in {took * 1000:.0f} ms", file=sys.stderr)
    gone(stack.client)


def test_a_viewer_cannot_serve(stack) -> None:
    from roslink_mqtt.client import CommandRefused, RobotClient

    with RobotClient("bob", "bob-demo", url=stack.url, robots=["turtle1"]) as bob:
        bob.wait_for_robot("turtle1", timeout=10)
        with pytest.raises(CommandRefused, match="may not provide"):
            bob.serve_action("turtle1", "plan", "test_msgs/action/Fibonacci", lambda goal: {})
