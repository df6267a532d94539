"""Benchmark: what the bridge costs a robot's CPU at the demo robot's steady state, per rclpy executor, and what
the snapshot ring buffer adds.

    .venv/bin/python bench/bridge_cpu.py [--seconds 20] [--variants events,events+snapshot,single] [--quick]
                                         [--plot PATH]

The simulated robot (``python -m roslink_mqtt.sim``: 20 Hz odometry, 5 Hz 360-beam scan, 1 Hz GPS and
battery, and the motion it integrates) and turtle1's bridge run against the embedded broker, with no MQTT
client connected, as a robot idles in the field. For each executor the bridge is started fresh, given a
few seconds to settle, and then its CPU time (user + system, from /proc) and the simulator's are read over
the same window. An rclpy subscriber here counts the ROS messages the bridge's rules subscribe to in that
window, so the table also gives the bridge's CPU per 1,000 messages it forwards. A variant without
``+snapshot`` runs turtle1 without its ``snapshot:`` section; ``events+snapshot`` with it (30 s of odom, scan and
cmd_vel in the ring buffer, as the demo fleet has it), side by side in one run.

Nothing here asserts on timing: it prints one table and writes a bar chart (matplotlib) of the same rows.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from _support import cpu_seconds, rss_bytes

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ROBOT, ROBOT_PASSWORD = "turtle1", "turtle1-demo"
SETTLE = 4.0  # s after the bridge is online before measuring: discovery and first messages are not steady state
DEFAULT_PLOT = ROOT / "docs" / "performance" / "bridge_cpu.png"


@dataclass(frozen=True, slots=True)
class Row:
    executor: str
    seconds: float
    messages: int  # ROS messages on the bridge's subscribed topics in the window
    bridge_cpu: float  # s of CPU in the window
    sim_cpu: float
    bridge_rss: int  # bytes at the end of the window

    @property
    def bridge_core(self) -> float:
        return 100 * self.bridge_cpu / self.seconds

    @property
    def sim_core(self) -> float:
        return 100 * self.sim_cpu / self.seconds

    @property
    def per_1000(self) -> float:
        """ms of bridge CPU per 1,000 forwarded messages."""
        return 1e6 * self.bridge_cpu / self.messages if self.messages else float("nan")


def bridge_inputs() -> list[tuple[str, str]]:
    """(ROS topic, type) of every ROS→MQTT rule of the robot: what the bridge subscribes to."""
    from roslink_mqtt.config import load_fleet
    from roslink_mqtt.config.model import Direction

    robot = load_fleet(CONFIG).robots[ROBOT]
    return [(r.ros_topic, r.ros_type) for r in robot.rules if r.direction is Direction.ROS_TO_MQTT]


class Counter:
    """Counts ROS messages on the given topics from an rclpy node spinning in a thread of this process."""

    def __init__(self, topics: list[tuple[str, str]]) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from roslink_mqtt.bridge.core.ros_types import load_interface

        rclpy.init()
        self.node = rclpy.create_node("bench_bridge_cpu_counter")
        self.count, self._lock = 0, threading.Lock()
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)  # matches reliable publishers too
        for topic, type_name in topics:
            self.node.create_subscription(load_interface(type_name), topic, self._on, qos)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on(self, _msg: Any) -> None:
        with self._lock:
            self.count += 1

    def read(self) -> int:
        with self._lock:
            return self.count

    def close(self) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=2)
        self.node.destroy_node()
        rclpy.shutdown()


def wait_online(port: int, log: Path, timeout: float = 30.0) -> None:
    """The bridge's retained heartbeat says ACTIVE; the checking client disconnects before the measurement."""
    from roslink_mqtt.localproc import tail
    from roslink_mqtt.mqtt import make_client
    from roslink_mqtt.topics import TopicTree

    seen = threading.Event()
    client = make_client("bench-cpu-check", username="bob", password="bob-demo", url=f"mqtt://127.0.0.1:{port}")

    def on_message(_c: Any, _u: Any, msg: Any) -> None:
        if b'"system_status":4' in msg.payload.replace(b" ", b""):
            seen.set()

    client.on_message = on_message
    client.on_connect = lambda c, *_: c.subscribe(TopicTree().heartbeat(ROBOT), 1)
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        if not seen.wait(timeout):
            raise SystemExit(f"bridge_cpu bench: {ROBOT} not online after {timeout:g} s:\n{tail(log)}")
    finally:
        client.disconnect()
        client.loop_stop()


def measure(variant: str, seconds: float, env: dict[str, str], work: Path, counter: Counter) -> Row:
    from roslink_mqtt.localproc import fleet_copy, free_port, start_child, start_embedded_broker

    executor, _, extra = variant.partition("+")
    with ExitStack() as stack:
        port = free_port()
        fleet = fleet_copy(work / f"robots-{variant}.yaml", CONFIG, port=port, ws_port=0,
                           edit=None if extra == "snapshot" else lambda data: data["robots"][ROBOT].pop("snapshot"))
        start_embedded_broker(stack, fleet, port, work / f"broker-{executor}.log", env)
        sim = start_child(stack, [sys.executable, "-m", "roslink_mqtt.sim"], work / f"sim-{executor}.log", env)
        bridge = start_child(stack, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet),
                                     "--robot", ROBOT, "--url", f"mqtt://127.0.0.1:{port}", "--log-level",
                                     "WARNING", "--executor", executor],
                             work / f"bridge-{variant}.log", {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD})
        wait_online(port, work / f"bridge-{variant}.log")
        time.sleep(SETTLE)
        b0, s0, m0, t0 = cpu_seconds(bridge.pid), cpu_seconds(sim.pid), counter.read(), time.monotonic()
        time.sleep(seconds)
        b1, s1, m1, t1 = cpu_seconds(bridge.pid), cpu_seconds(sim.pid), counter.read(), time.monotonic()
        rss = rss_bytes(bridge.pid)
    return Row(variant, t1 - t0, m1 - m0, b1 - b0, s1 - s0, rss)


def table(rows: list[Row]) -> str:
    head = (f"{'variant':<16} {'window s':>8} {'ROS msg/s':>9} {'bridge % core':>13} {'ms CPU / 1000 msg':>17} "
            f"{'sim % core':>10} {'bridge RSS MB':>13}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r.executor:<16} {r.seconds:>8.1f} {r.messages / r.seconds:>9.1f} {r.bridge_core:>13.1f} "
                     f"{r.per_1000:>17.0f} {r.sim_core:>10.1f} {r.bridge_rss / 1e6:>13.1f}")
    return "\n".join(lines)


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2), dpi=110)
    names = [r.executor for r in rows]
    xs = range(len(rows))
    ax.bar([x - 0.2 for x in xs], [r.bridge_core for r in rows], width=0.4, label="bridge")
    ax.bar([x + 0.2 for x in xs], [r.sim_core for r in rows], width=0.4, label="simulated robot")
    ax.set_xticks(list(xs), names)
    ax.set_ylabel("% of one core")
    ax.set_ylim(0, 1.35 * max([r.bridge_core for r in rows] + [r.sim_core for r in rows] + [1.0]))
    ax.set_title("Bridge CPU at the demo robot's steady state")
    ax.legend(loc="upper center", ncol=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0, help="measurement window per executor")
    p.add_argument("--variants", "--executors", default="events,events+snapshot,single",
                   help="comma-separated: events or single, each optionally +snapshot (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="a 6 s window (a smoke run, noisier numbers)")
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="where to write the chart (default: %(default)s)")
    args = p.parse_args(argv)
    seconds = 6.0 if args.quick else args.seconds
    variants = [e.strip() for e in args.variants.split(",") if e.strip()]
    bad = [v for v in variants if v.partition("+")[0] not in ("events", "single") or v.partition("+")[2] not in
           ("", "snapshot")]
    if bad:
        p.error(f"unknown variant(s): {', '.join(bad)} (events or single, each optionally +snapshot)")

    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children inherit the same domain
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    os.environ["ROS_LOG_DIR"] = env["ROS_LOG_DIR"]
    counter = Counter(bridge_inputs())
    rows = []
    try:
        with tempfile.TemporaryDirectory(prefix="roslink-bench-cpu-") as tmp:
            for variant in variants:
                rows.append(measure(variant, seconds, env, Path(tmp), counter))
                print(f"  {variant}: bridge {rows[-1].bridge_core:.1f} % of a core", flush=True)
    finally:
        counter.close()
    print(f"\nbridge CPU, demo steady state, no MQTT client connected ({os.cpu_count()} cores, "
          f"{seconds:g} s windows)\n")
    print(table(rows))
    if len(rows) > 1 and rows[0].bridge_cpu and rows[-1].bridge_cpu:
        base = next((r for r in rows if r.executor == "single"), rows[-1])
        for r in rows:
            if r is not base and "+" not in r.executor:
                print(f"\n{r.executor}: {r.bridge_cpu / base.bridge_cpu:.2f} × the CPU of {base.executor}")
    by_name = {r.executor: r for r in rows}
    for r in rows:
        plain = by_name.get(r.executor.partition("+")[0])
        if "+snapshot" in r.executor and plain is not None:
            print(f"\n{r.executor}: {r.bridge_core - plain.bridge_core:+.2f} % of a core, "
                  f"{(r.bridge_rss - plain.bridge_rss) / 1e6:+.1f} MB RSS against {plain.executor} (the ring buffer)")
    plot(rows, args.plot)
    print(f"\nplot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
