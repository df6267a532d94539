"""Benchmark: round trip of a ROS action goal (goal → accepted → result) over MQTT vs directly in ROS.

    .venv/bin/python bench/actions.py [--goals 300] [--warmup 20] [--max-seconds 120]

Starts the simulated robot (its ``fibonacci`` action, test_msgs/action/Fibonacci), Mosquitto running exactly
what ``roslink-mqtt acl export`` writes for the demo fleet, the embedded broker, and one bridge for turtle1 on
each broker (DDS on loopback, a fresh ROS domain). Then, one goal at a time, the same goal (order 1: the
server answers at once, so the round trip is the transport's, not the computation's) is sent

* directly from an rclpy ActionClient in this process (the baseline: send_goal → accepted → get_result),
* from the SDK (``RobotClient.send_goal(...).result()``) through Mosquitto and its bridge, and
* from the SDK through the embedded broker and its bridge.

The paths take turns goal by goal (round robin), so a busy moment lands on all of them. Prints p50/p99/mean/
max per path and the ratio to the direct path. Loopback only; bounded in goals and seconds.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

from roslink_mqtt.localproc import (
    ChildExited,
    Mosquitto,
    fleet_copy,
    free_port,
    mosquitto_exe,
    start_child,
    start_embedded_broker,
)

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ACTION = "fibonacci"


class Budget:
    """Stops every phase once the whole run has used ``seconds``: the bench is bounded."""

    def __init__(self, seconds: float) -> None:
        self.deadline = time.monotonic() + seconds

    def left(self) -> float:
        return self.deadline - time.monotonic()


def measure(paths: dict[str, Callable[[], object]], goals: int, warmup: int, budget: Budget
            ) -> dict[str, list[float]]:
    samples: dict[str, list[float]] = {name: [] for name in paths}
    for i in range(warmup + goals):
        if budget.left() <= 0:
            break
        for name, send in paths.items():
            t0 = time.perf_counter()
            send()
            if i >= warmup:
                samples[name].append(time.perf_counter() - t0)
    return samples


def row(name: str, samples: list[float], base: float) -> str:
    if len(samples) < 2:
        return f"{name:<48} {'(no samples)':>40}"
    ms = [s * 1000 for s in samples]
    p99 = statistics.quantiles(ms, n=100, method="inclusive")[98]
    p50 = statistics.median(ms)
    ratio = f"{p50 / base:6.1f}x" if base else "     -"
    return f"{name:<48} {p50:8.2f} {p99:8.2f} {statistics.fmean(ms):8.2f} {max(ms):8.2f} {len(ms):6d} {ratio}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--goals", type=int, default=300, help="measured goals per path (default: %(default)s)")
    p.add_argument("--warmup", type=int, default=20, help="unmeasured goals first (default: %(default)s)")
    p.add_argument("--max-seconds", type=float, default=120.0, help="bound on the whole run (default: %(default)s)")
    args = p.parse_args(argv)
    if mosquitto_exe() is None:
        raise SystemExit("actions bench: needs Mosquitto (apt-get install mosquitto)")

    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children get the same domain
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor
    from test_msgs.action import Fibonacci

    import roslink_mqtt.client as sdk

    budget = Budget(args.max_seconds)
    with ExitStack() as stack, tempfile.TemporaryDirectory(prefix="roslink-bench-") as tmp:
        work = Path(tmp)
        fleet = fleet_copy(work / "robots.yaml", CONFIG, port=free_port(), ws_port=0)
        try:
            mosquitto = Mosquitto.exported(work, fleet)
            stack.callback(mosquitto.stop)
            mosquitto.start()
            embedded_port = free_port()
            start_embedded_broker(stack, fleet, embedded_port, work / "broker.log", env, log_level="INFO")
            start_child(stack, [sys.executable, "-m", "roslink_mqtt.sim"], work / "sim.log", env)
            for label, port in (("mosquitto", mosquitto.port), ("embedded", embedded_port)):
                start_child(stack, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet),
                                    "--robot", "turtle1", "--url", f"mqtt://127.0.0.1:{port}", "--log-level",
                                    "WARNING"], work / f"bridge-{label}.log",
                            {**env, "ROSLINK_PASSWORD": "turtle1-demo"})
        except (ChildExited, TimeoutError) as e:
            raise SystemExit(f"actions bench: {e}") from None

        rclpy.init()
        stack.callback(rclpy.try_shutdown)
        node = rclpy.create_node("actions_bench")
        stack.callback(node.destroy_node)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        direct = ActionClient(node, Fibonacci, "/fibonacci")
        if not direct.wait_for_server(timeout_sec=min(20.0, budget.left())):
            raise SystemExit("actions bench: the sim's fibonacci action never appeared")

        def spin_until(future: object, what: str) -> object:
            # spin_once in a loop, not spin_until_future_complete (its own cost would flatter the MQTT paths)
            deadline = time.monotonic() + 5.0
            while not future.done() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
            if not future.done():
                raise SystemExit(f"actions bench: direct {what} timed out")
            return future.result()

        def send_direct() -> object:
            handle = spin_until(direct.send_goal_async(Fibonacci.Goal(order=1)), "goal")
            if not handle.accepted:
                raise SystemExit("actions bench: direct goal rejected")
            return spin_until(handle.get_result_async(), "result")

        def sdk_path(port: int) -> Callable[[], object]:
            client = stack.enter_context(sdk.RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{port}",
                                                         robots=["turtle1"]))
            client.wait_for_robot("turtle1", timeout=min(20.0, budget.left()))

            def send() -> object:
                result = client.send_goal("turtle1", ACTION, {"order": 1}).result(timeout=5)
                if result.status != "succeeded":
                    raise SystemExit(f"actions bench: goal ended {result.status}: {result.error}")
                return result

            deadline = time.monotonic() + 15  # the bridge may not have discovered the server yet
            while True:
                try:
                    send()
                    return send
                except sdk.GoalError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.3)

        paths = {
            "rclpy ActionClient -> fibonacci (direct, DDS)": send_direct,
            "SDK -> Mosquitto -> bridge -> fibonacci": sdk_path(mosquitto.port),
            "SDK -> embedded broker -> bridge -> fibonacci": sdk_path(embedded_port),
        }
        results = list(measure(paths, args.goals, args.warmup, budget).items())

    print(f"\nROS action round trip (test_msgs/action/Fibonacci order 1: goal -> accepted -> result), one goal at a "
          f"time, loopback; ROS 2 Jazzy {os.environ.get('RMW_IMPLEMENTATION')}")
    print(f"{'path':<48} {'p50 ms':>8} {'p99 ms':>8} {'mean ms':>8} {'max ms':>8} {'goals':>6} {'vs ROS':>7}")
    base = statistics.median(results[0][1]) * 1000 if results[0][1] else 0.0
    for name, samples in results:
        print(row(name, samples, base))
    if budget.left() <= 0:
        print(f"(stopped early at the {args.max_seconds:g} s bound)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
