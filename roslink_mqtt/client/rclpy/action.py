"""rclpy-shaped actions for SDK nodes: ``ActionClient`` and ``ActionServer`` as ``rclpy.action`` spells them.

Ported code keeps its shape: ``ActionClient(node, "test_msgs/action/Fibonacci", "fibonacci")``,
``send_goal_async(goal, feedback_callback)`` → a future of a goal handle with ``accepted``,
``get_result_async()`` and ``cancel_goal_async()``; ``ActionServer(node, type, name, execute_callback)`` where
the callback gets a goal handle with ``request``, ``publish_feedback``, ``is_cancel_requested``, ``succeed``,
``abort``, ``canceled`` and returns the result. Goals, feedback and results are dicts (the action's fields),
as everywhere in the SDK; statuses are ROS's ``action_msgs/GoalStatus`` numbers. Underneath are
:meth:`RobotClient.send_goal` and :meth:`RobotClient.serve_action` on the node's robot.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, TypeVar

from ...protocol.goals import GoalResult
from ..errors import GoalError
from ..goals import GoalHandle

if TYPE_CHECKING:
    from ..action_servers import ServerGoal

_T = TypeVar("_T")
_R = TypeVar("_R")

# action_msgs/msg/GoalStatus
STATUS_UNKNOWN, STATUS_ACCEPTED, STATUS_SUCCEEDED, STATUS_CANCELED, STATUS_ABORTED = 0, 1, 4, 5, 6
_STATUS = {"succeeded": STATUS_SUCCEEDED, "canceled": STATUS_CANCELED, "aborted": STATUS_ABORTED,
           "timeout": STATUS_ABORTED, "failed": STATUS_ABORTED}


def _chain(source: Future[_T], convert: Callable[[_T], _R]) -> Future[_R]:
    """A future of ``convert(source's result)`` (its exception passed on)."""
    out: Future[_R] = Future()

    def done(f: Future[_T]) -> None:
        error = f.exception()
        if error is not None:
            out.set_exception(error)
        else:
            try:
                out.set_result(convert(f.result()))
            except Exception as err:  # noqa: BLE001 - handed to the caller through the future
                out.set_exception(err)

    source.add_done_callback(done)
    return out


class ClientGoalHandle:
    """rclpy's ClientGoalHandle: ``accepted``, ``status``, ``get_result_async()``, ``cancel_goal_async()``."""

    def __init__(self, handle: GoalHandle) -> None:
        self._handle = handle
        self.goal_id = handle.id

    @property
    def accepted(self) -> bool:
        return self._handle.accepted_future.done() and self._handle.accepted_future.exception() is None

    @property
    def status(self) -> int:
        return _STATUS.get(self._handle.status, STATUS_ACCEPTED if self.accepted else STATUS_UNKNOWN)

    def get_result_async(self) -> Future[SimpleNamespace]:
        """A future of ``SimpleNamespace(status=<GoalStatus number>, result=<dict>)``, as rclpy's result response."""
        def convert(result: GoalResult) -> SimpleNamespace:
            return SimpleNamespace(status=_STATUS.get(result.status, STATUS_ABORTED), result=result.result or {},
                                   error=result.error)
        return _chain(self._handle.result_future, convert)

    def cancel_goal_async(self) -> Future[None]:
        self._handle.cancel()
        done: Future[None] = Future()
        done.set_result(None)
        return done


class ActionClient:
    """``rclpy.action.ActionClient`` for an SDK node: goals go to the node's robot over MQTT."""

    def __init__(self, node: Any, action_type: str, action_name: str) -> None:
        self._node, self.action_type, self.action_name = node, action_type, action_name

    def server_is_ready(self) -> bool:
        """The robot is online and lets us send goals to this action (its access report)."""
        client, robot = self._node.robot_client, self._node.robot
        info, access = client.directory.get(robot), client.access(robot)
        return info is not None and info.online and access is not None and access.may_send_goal(self.action_name)

    def wait_for_server(self, timeout_sec: float | None = None) -> bool:
        import time
        deadline = None if timeout_sec is None else time.monotonic() + timeout_sec
        while not self.server_is_ready():
            if deadline is not None and time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def send_goal_async(self, goal: dict[str, Any], feedback_callback: Callable[[Any], None] | None = None
                        ) -> Future[ClientGoalHandle]:
        """A future of a :class:`ClientGoalHandle` once the goal is answered (rejected: ``accepted`` False)."""
        callback = None
        if feedback_callback is not None:
            def callback(feedback: dict[str, Any]) -> None:  # rclpy passes a FeedbackMessage with .feedback
                feedback_callback(SimpleNamespace(feedback=feedback))
        handle = self._node.robot_client.send_goal(self._node.robot, self.action_name, goal, callback)
        wrapped = ClientGoalHandle(handle)
        out: Future[ClientGoalHandle] = Future()

        def answered(f: Future[bool]) -> None:
            error = f.exception()
            if error is not None and not isinstance(error, GoalError):
                out.set_exception(error)
            else:
                out.set_result(wrapped)  # a rejected goal is a handle with accepted False, as in rclpy

        handle.accepted_future.add_done_callback(answered)
        return out

    def send_goal(self, goal: dict[str, Any], feedback_callback: Callable[[Any], None] | None = None,
                  timeout: float | None = None) -> SimpleNamespace:
        """Blocking: the result response (``status``, ``result``)."""
        handle = self.send_goal_async(goal, feedback_callback).result(timeout)
        return handle.get_result_async().result(timeout)

    def destroy(self) -> None:
        pass


class ServerGoalHandle:
    """rclpy's ServerGoalHandle over a served goal: ``request``, feedback, cancel, and how it ends."""

    def __init__(self, goal: ServerGoal) -> None:
        self._goal = goal
        self.request = goal.goal
        self.goal_id = goal.id

    @property
    def is_cancel_requested(self) -> bool:
        return self._goal.is_cancel_requested

    def publish_feedback(self, feedback: dict[str, Any]) -> None:
        self._goal.publish_feedback(feedback)

    def succeed(self) -> None:
        pass  # the default end of a returned result

    def abort(self) -> None:
        self._goal.abort()

    def canceled(self) -> None:
        self._goal.canceled()


class ActionServer:
    """``rclpy.action.ActionServer`` for an SDK node: the node's robot runs the ROS action server, goals come here.

    ``execute_callback(goal_handle) -> dict`` runs in a thread per goal; ``goal_callback(request) -> bool``
    (rclpy: ``GoalResponse``; here True accepts) may reject goals.
    """

    def __init__(self, node: Any, action_type: str, action_name: str, execute_callback: Callable[[Any], Any], *,
                 goal_callback: Callable[[dict[str, Any]], Any] | None = None, result_timeout: float = 600.0) -> None:
        self._node, self.action_type, self.action_name = node, action_type, action_name

        def execute(goal: Any) -> dict[str, Any]:
            result = execute_callback(ServerGoalHandle(goal))
            return dict(result or {})

        accept = None if goal_callback is None else (lambda request: bool(goal_callback(request)))
        self._served = node.robot_client.serve_action(node.robot, action_name, action_type, execute,
                                                      goal_callback=accept, result_timeout=result_timeout)

    def destroy(self) -> None:
        self._served.withdraw()
