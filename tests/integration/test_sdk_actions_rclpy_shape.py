"""The rclpy-shaped ActionClient/ActionServer of SDK nodes, against real processes.

ActionClient: an SDK node sends goals to the simulated robot's ``fibonacci`` through the bridge (embedded
broker). ActionServer: an SDK node serves ``sdk_plan``; a real rclpy ActionClient in the test calls it.
"""

from __future__ import annotations

import threading
import time

import pytest

from roslink_mqtt.client import rclpy as sdk
from roslink_mqtt.client.rclpy.action import STATUS_CANCELED, STATUS_SUCCEEDED, ActionClient, ActionServer
from tests.support.robot_stack import turtle1_online
from tests.support.ros import RosProbe
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(120)


def test_action_client_and_server_shaped_like_rclpy(tmp_path) -> None:
    from rclpy.action import ActionClient as RosActionClient
    from test_msgs.action import Fibonacci

    probe = RosProbe()
    try:
        with turtle1_online(tmp_path) as port:
            node = sdk.create_node("porting", robot="turtle1", url=f"mqtt://127.0.0.1:{port}", username="alice",
                                   password="alice-demo")
            threading.Thread(target=sdk.spin, args=(node,), daemon=True).start()  # callbacks run while spinning
            try:
                client = ActionClient(node, "test_msgs/action/Fibonacci", "fibonacci")
                assert client.wait_for_server(timeout_sec=10)
                feedback: list = []
                handle = client.send_goal_async({"order": 5}, feedback.append).result(timeout=15)
                assert handle.accepted
                response = handle.get_result_async().result(timeout=15)
                assert response.status == STATUS_SUCCEEDED and response.result == {"sequence": [0, 1, 1, 2, 3, 5]}
                wait_until("feedback from the fibonacci goal", lambda: feedback, timeout=10)
                assert feedback and feedback[-1].feedback["sequence"][:2] == [0, 1]
                rejected = client.send_goal_async({"order": 99}).result(timeout=15)
                assert not rejected.accepted

                def execute(goal_handle):  # rclpy's shape: request, feedback, cancel, the result
                    sequence = [0, 1]
                    for _ in range(2, goal_handle.request["order"] + 1):
                        if goal_handle.is_cancel_requested:
                            goal_handle.canceled()
                            return {"sequence": sequence}
                        time.sleep(0.05)  # kept: the goal's own work, long enough for a cancel to land mid-goal
                        sequence.append(sequence[-1] + sequence[-2])
                        goal_handle.publish_feedback({"sequence": sequence})
                    goal_handle.succeed()
                    return {"sequence": sequence}

                server = ActionServer(node, "test_msgs/action/Fibonacci", "sdk_plan", execute)
                ros = RosActionClient(probe.node, Fibonacci, "/sdk_plan")
                assert ros.wait_for_server(timeout_sec=15)
                done = threading.Event()
                box: list = []
                future = probe.on_spin(lambda: ros.send_goal_async(Fibonacci.Goal(order=4)))
                future.add_done_callback(lambda f: (box.append(f.result()), done.set()))
                assert done.wait(15) and box[0].accepted
                result = probe.on_spin(box[0].get_result_async)
                wait_until("the result of the goal of order 4", result.done, timeout=15, period=0.02)
                assert list(result.result().result.sequence) == [0, 1, 1, 2, 3]
                long = probe.on_spin(lambda: ros.send_goal_async(Fibonacci.Goal(order=40)))
                wait_until("the answer to the goal of order 40", long.done, timeout=15, period=0.02)
                probe.on_spin(long.result().cancel_goal_async)
                ended = probe.on_spin(long.result().get_result_async)
                wait_until("the result of the canceled goal", ended.done, timeout=15, period=0.02)
                assert ended.result().status == STATUS_CANCELED
                server.destroy()
            finally:
                node.destroy_node()
    finally:
        probe.close()
