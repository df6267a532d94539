"""A program without ROS that serves a ROS action through the bridge (the SDK's serve_action), run as a process.

    python -m tests.support.action_provider_proc URL USER PASSWORD ROBOT [STEP_SECONDS]

Serves ``plan`` (test_msgs/action/Fibonacci): one term per STEP_SECONDS (default 0.1) with feedback after
each, honouring cancel requests; rejects orders over 40. Prints "serving" once the offer is out.
"""

from __future__ import annotations

import sys
import threading

from roslink_mqtt.client import RobotClient


def main() -> None:
    url, user, password, robot = sys.argv[1:5]
    step = float(sys.argv[5]) if len(sys.argv) > 5 else 0.1

    def execute(goal):  # -> dict
        sequence = [0, 1]
        for _ in range(2, goal.goal.get("order", 0) + 1):
            if goal.wait_for_cancel(step):
                goal.canceled()
                return {"sequence": sequence}
            sequence.append(sequence[-1] + sequence[-2])
            goal.publish_feedback({"sequence": sequence})
        return {"sequence": sequence}

    with RobotClient(user, password, url=url, robots=[robot]) as client:
        client.wait_for_robot(robot, timeout=20)
        client.serve_action(robot, "plan", "test_msgs/action/Fibonacci", execute,
                            goal_callback=lambda goal: 0 <= goal.get("order", 0) <= 40, accept_timeout=5)
        print("serving", flush=True)
        threading.Event().wait()  # serve until the test stops this process


if __name__ == "__main__":
    main()
