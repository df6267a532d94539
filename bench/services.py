"""Benchmark: round trip of a ROS service call made over MQTT through the bridge vs made directly in ROS.

    .venv/bin/python bench/services.py [--calls 1000] [--warmup 50] [--max-seconds 120]

Starts its own Mosquitto (127.0.0.1) running exactly what ``roslink-mqtt acl export``
writes for the demo fleet (logins and ACL: the deployed configuration, as in
bench/latency.py), the simulated robot and the bridge for turtle1, with DDS kept on loopback and a fresh ROS
domain. Then, one call at a time, the same std_srvs/srv/Trigger ``reset`` of
the sim robot is called

* directly from an rclpy client in this process (the baseline), and
* from the SDK's RobotClient: MQTT → Mosquitto → bridge → ROS service → back;

and, for the other direction, an rclpy client calls a trivial Trigger service
*provided* by an SDK Node in this process: ROS → bridge → MQTT → provider →
back. The paths take turns call by call (round robin), so a busy moment on the
machine lands on all of them. Prints p50/p99/mean/max per path. Loopback only.

The exported config has ``set_tcp_nodelay true``: without it, a reply that Mosquitto
writes right after its PUBACK to the same client waits for the client's delayed
ACK (Nagle), and every call over MQTT takes ~40 ms longer.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

from roslink_mqtt.localproc import ChildExited, Mosquitto, fleet_copy, free_port, mosquitto_exe, start_child

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"


# -- processes ----------------------------------------------------------------------------------
def start_mosquitto(stack: ExitStack, work: Path) -> tuple[int, Path]:
    """Mosquitto with the fleet's exported logins and ACL, on a free loopback port; returns it and the fleet copy."""
    if mosquitto_exe() is None:
        raise SystemExit("services bench: needs Mosquitto (apt-get install mosquitto)")
    # a copy of the fleet because the exported config takes its port from the fleet file
    fleet = fleet_copy(work / "robots.yaml", CONFIG, port=free_port(), ws_port=0)
    mosquitto = Mosquitto.exported(work, fleet)
    stack.callback(mosquitto.stop)
    mosquitto.start()
    return mosquitto.port, fleet


# -- measuring ------------------------------------------------------------------------------------
class Budget:
    """Stops every phase once the whole run has used ``seconds``: the bench is bounded."""

    def __init__(self, seconds: float) -> None:
        self.deadline = time.monotonic() + seconds

    def left(self) -> float:
        return self.deadline - time.monotonic()


def measure(paths: dict[str, Callable[[], object]], calls: int, warmup: int, budget: Budget
            ) -> dict[str, list[float]]:
    """Round robin: one call of each path per round, so load changes on the machine hit every path alike."""
    samples: dict[str, list[float]] = {name: [] for name in paths}
    for i in range(warmup + calls):
        if budget.left() <= 0:
            break
        for name, call in paths.items():
            t0 = time.perf_counter()
            call()
            if i >= warmup:
                samples[name].append(time.perf_counter() - t0)
    return samples


def row(name: str, samples: list[float]) -> str:
    if len(samples) < 2:
        return f"{name:<52} {'(no samples)':>40}"
    ms = [s * 1000 for s in samples]
    p99 = statistics.quantiles(ms, n=100, method="inclusive")[98]
    return (f"{name:<52} {statistics.median(ms):8.2f} {p99:8.2f} {statistics.fmean(ms):8.2f} {max(ms):8.2f}"
            f" {len(ms):7d}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--calls", type=int, default=1000, help="measured calls per path (default: %(default)s)")
    p.add_argument("--warmup", type=int, default=50, help="unmeasured calls first (default: %(default)s)")
    p.add_argument("--max-seconds", type=float, default=120.0, help="bound on the whole run (default: %(default)s)")
    args = p.parse_args(argv)

    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children get the same domain
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    import roslink_mqtt.client as sdk
    from roslink_mqtt.client import rclpy as sdk_rclpy

    budget = Budget(args.max_seconds)
    with ExitStack() as stack, tempfile.TemporaryDirectory(prefix="roslink-bench-") as tmp:
        work = Path(tmp)
        try:
            port, fleet = start_mosquitto(stack, work)
        except (ChildExited, TimeoutError) as e:
            raise SystemExit(f"services bench: {e}") from None
        url = f"mqtt://127.0.0.1:{port}"
        start_child(stack, [sys.executable, "-m", "roslink_mqtt.sim"], work / "sim.log", env)
        start_child(stack, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot",
                            "turtle1", "--url", url, "--log-level", "WARNING"], work / "bridge.log",
                    {**env, "ROSLINK_PASSWORD": "turtle1-demo"})

        rclpy.init()
        stack.callback(rclpy.try_shutdown)
        node = rclpy.create_node("services_bench")
        stack.callback(node.destroy_node)
        executor = SingleThreadedExecutor()
        executor.add_node(node)

        def ros_caller(name: str) -> Callable[[], object]:
            client = node.create_client(Trigger, name)
            if not client.wait_for_service(timeout_sec=min(20.0, budget.left())):
                raise SystemExit(f"services bench: ROS service {name} never appeared")

            def call() -> object:
                # spin_once in a loop, not spin_until_future_complete: that helper alone costs 3-7 ms per call
                # in rclpy (Jazzy) on this kind of machine, which would flatter the MQTT paths
                future = client.call_async(Trigger.Request())
                deadline = time.monotonic() + 5.0
                while not future.done() and time.monotonic() < deadline:
                    executor.spin_once(timeout_sec=0.1)
                if not future.done() or not future.result().success:
                    outcome = future.result() if future.done() else "timeout"
                    raise SystemExit(f"services bench: {name} failed: {outcome}")
                return future.result()

            return call

        # everything up first: the bridge has discovered the sim's service, the provider is offered
        client = stack.enter_context(sdk.RobotClient("alice", "alice-demo", url=url, robots=["turtle1"]))
        client.wait_for_robot("turtle1", timeout=min(20.0, budget.left()))
        deadline = time.monotonic() + 15
        while True:
            try:
                client.call("turtle1", "reset", timeout=5)
                break
            except sdk.ServiceError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        provider = sdk_rclpy.create_node("bench_provider", robot="turtle1", url=url, username="alice",
                                   password="alice-demo")
        stack.callback(provider.destroy_node)
        provider.create_service("std_srvs/srv/Trigger", "bench_echo",
                                lambda _req, resp: {**resp, "success": True, "message": "echo"})
        threading.Thread(target=sdk_rclpy.spin, args=(provider,), daemon=True).start()

        paths = {
            "rclpy client -> reset (direct, DDS)": ros_caller("/reset"),
            "SDK call -> Mosquitto -> bridge -> reset": lambda: client.call("turtle1", "reset", timeout=5),
            "rclpy client -> bridge -> SDK provider (MQTT)": ros_caller("/bench_echo"),
        }
        results = list(measure(paths, args.calls, args.warmup, budget).items())

    import paho.mqtt

    print(f"\nROS service round trip (std_srvs/srv/Trigger), one call at a time, loopback: "
          f"Mosquitto with the exported ACL, ROS 2 Jazzy {os.environ.get('RMW_IMPLEMENTATION')}, "
          f"paho-mqtt {paho.mqtt.__version__}")
    print(f"{'path':<52} {'p50 ms':>8} {'p99 ms':>8} {'mean ms':>8} {'max ms':>8} {'calls':>7}")
    for name, samples in results:
        print(row(name, samples))
    if budget.left() <= 0:
        print(f"(stopped early at the {args.max_seconds:g} s bound)")
    base = statistics.median(results[0][1]) if results[0][1] else 0.0
    if base and results[1][1]:
        print(f"MQTT path adds {1000 * (statistics.median(results[1][1]) - base):.2f} ms at p50 over direct ROS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
