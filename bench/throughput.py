"""Benchmark: the highest message rate the bridge carries without loss, each way, per message type and broker.

    .venv/bin/python bench/throughput.py [--quick] [--brokers embedded,mosquitto] [--seconds 2] [--plot PATH]

Four streams, each stepped through rising rates (one window per rate, a pause between):

* ROS -> MQTT: an rclpy publisher (a child process) -> turtle1's bridge (generic JSON rule, no throttle)
  -> broker -> a paho subscriber here (bob, a viewer);
* MQTT -> ROS: the SDK's rclpy-shaped publisher here (alice, MQTT QoS 0 as ``qos_profile_sensor_data``
  chooses) -> broker -> bridge -> an rclpy subscriber (a child process);

for ``nav_msgs/Odometry`` and a 720-beam ``sensor_msgs/LaserScan``. Each message carries its window and
index, so the receiver counts exactly what arrived per window. A window is lossless when every message
arrived. CPU (user + system from /proc, or this process's own) of every process on the path is read at the
window's edges and given per 1,000 messages. Goal (issue 17): ≥ 5,000 Odometry/s ROS -> MQTT on Mosquitto.

Both brokers run as deployed except the embedded broker's per-user publish pacing (100 PUBLISH/s, a flood
defence: docs/safety.md), lifted with ``--limit user_publish_rate=0`` so the MQTT -> ROS rows measure the
bridge. Everything is on loopback; on a 2-core machine the publisher, the broker, the bridge and the
receiver share two cores, which is part of what the table shows. Never asserts on timing.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: brokers and the process helpers shared by the benches)
import orjson
from _support import cpu_seconds

from roslink_mqtt import ros_names

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ROBOT, ROBOT_PASSWORD = "turtle1", "turtle1-demo"
OPERATOR, VIEWER = ("alice", "alice-demo"), ("bob", "bob-demo")
DEFAULT_PLOT = ROOT / "docs" / "performance" / "throughput.png"
GAP = 1.0  # s between windows: what is in flight arrives, queues drain
TYPES = {"odom": "nav_msgs/msg/Odometry", "scan": "sensor_msgs/msg/LaserScan"}
RATES = {"odom": (2000, 3000, 4000, 5000), "scan": (1000, 2000, 3000)}
BEAMS = 720


def ros_topic(direction: str, kind: str) -> str:
    return ros_names.absolute("bench_tp", direction, kind)


def rule_name(direction: str, kind: str) -> str:
    return f"tp_{direction}_{kind}"


# -- messages: window in one field, index in another ---------------------------------------------------------
def ros_message(kind: str) -> tuple[Any, Any]:
    """(message, stamp(message, window, index)) for the ROS side."""
    if kind == "odom":
        from nav_msgs.msg import Odometry

        msg = Odometry()
        msg.header.frame_id = "odom"
        msg.pose.pose.orientation.w = 1.0

        def stamp(m: Any, window: int, index: int) -> None:
            m.pose.pose.position.x, m.pose.pose.position.y = float(window), float(index)

        return msg, stamp
    from sensor_msgs.msg import LaserScan

    msg = LaserScan(angle_min=-3.14, angle_max=3.14, angle_increment=6.28 / BEAMS, range_min=0.1, range_max=30.0)
    msg.header.frame_id = "laser"
    msg.ranges = [1.0 + (i % 50) / 10 for i in range(BEAMS)]

    def stamp(m: Any, window: int, index: int) -> None:
        m.scan_time, m.time_increment = float(window), float(index)

    return msg, stamp


def json_message(kind: str) -> tuple[dict[str, Any], Any]:
    """(ROS-shaped dict, stamp) for the SDK side."""
    if kind == "odom":
        msg: dict[str, Any] = {"header": {"frame_id": "odom"},
                               "pose": {"pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                                                 "orientation": {"w": 1.0}}}}

        def stamp(m: dict[str, Any], window: int, index: int) -> None:
            m["pose"]["pose"]["position"]["x"], m["pose"]["pose"]["position"]["y"] = float(window), float(index)

        return msg, stamp
    msg = {"header": {"frame_id": "laser"}, "angle_min": -3.14, "angle_max": 3.14, "angle_increment": 6.28 / BEAMS,
           "range_min": 0.1, "range_max": 30.0, "ranges": [1.0 + (i % 50) / 10 for i in range(BEAMS)]}

    def stamp_scan(m: dict[str, Any], window: int, index: int) -> None:
        m["scan_time"], m["time_increment"] = float(window), float(index)

    return msg, stamp_scan


def window_of(kind: str, body: dict[str, Any]) -> int:
    if kind == "odom":
        return int(body["pose"]["pose"]["position"]["x"])
    return int(body["scan_time"])


# -- the schedule: both processes know when each window starts (CLOCK_MONOTONIC is shared) --------------
@dataclass(frozen=True, slots=True)
class Window:
    index: int
    rate: int
    start: float  # time.monotonic()
    seconds: float

    @property
    def count(self) -> int:
        return int(self.rate * self.seconds)


def schedule(rates: tuple[int, ...], seconds: float, start: float) -> list[Window]:
    return [Window(i, rate, start + i * (seconds + GAP), seconds) for i, rate in enumerate(rates)]


def send_windows(windows: list[Window], send: Any) -> list[int]:
    """Send each window's messages on its schedule (1 ms batches: sleeping per message is too coarse)."""
    sent = []
    for w in windows:
        if (delay := w.start - time.monotonic()) > 0:
            time.sleep(delay)
        n = 0
        while n < w.count:
            due = min(w.count, int((time.monotonic() - w.start) * w.rate) + 1)
            while n < due:
                send(w.index, n)
                n += 1
            if n < w.count:
                time.sleep(0.001)
            if time.monotonic() > w.start + w.seconds + GAP / 2:  # cannot keep up: stop before the next window
                break
        sent.append(n)
    return sent


# -- child processes -----------------------------------------------------------------------------------------
def ros_child(mode: str, kind: str, rates: tuple[int, ...], seconds: float, start: float, out: Path) -> int:
    """Hidden ``--ros-pub`` / ``--ros-sub`` mode: the ROS end of a stream; writes what it did to ``out``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from roslink_mqtt.bridge.core.ros_types import load_interface

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"throughput_{mode}_{kind}")
    windows = schedule(rates, seconds, start)
    try:
        if mode == "pub":
            msg, stamp = ros_message(kind)
            pub = node.create_publisher(type(msg), ros_topic("out", kind), 1000)
            lat.wait_until(lambda: pub.get_subscription_count() > 0, 20.0)

            def send(window: int, index: int) -> None:
                stamp(msg, window, index)
                pub.publish(msg)

            out.write_bytes(orjson.dumps({"sent": send_windows(windows, send)}))
            time.sleep(0.5)
            return 0
        counts = [0] * len(windows)

        def on_msg(m: Any) -> None:
            w = int(m.pose.pose.position.x) if kind == "odom" else int(m.scan_time)
            if 0 <= w < len(counts):
                counts[w] += 1

        node.create_subscription(load_interface(TYPES[kind]), ros_topic("in", kind), on_msg, 1000)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        end = windows[-1].start + seconds + GAP
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
        out.write_bytes(orjson.dumps({"received": counts}))
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


# -- measuring -----------------------------------------------------------------------------------------------
@dataclass
class Row:
    broker: str
    direction: str  # "ROS->MQTT" / "MQTT->ROS"
    kind: str
    rate: int
    seconds: float
    sent: int = 0
    received: int = 0
    cpu: dict[str, float] = field(default_factory=dict)  # process -> CPU s in the window

    @property
    def lossless(self) -> bool:
        return self.sent > 0 and self.received >= self.sent

    def per_1000(self, process: str) -> float:
        """ms of CPU per 1,000 messages sent."""
        return 1e6 * self.cpu.get(process, float("nan")) / self.sent if self.sent else float("nan")


class CpuSampler:
    """Reads every process's CPU at each window's start and end, from a thread that follows the schedule."""

    def __init__(self, pids: dict[str, int | None], windows: list[Window]) -> None:
        self.pids, self.windows = pids, windows
        self.samples: list[dict[str, float]] = []  # per window: process -> CPU s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        for w in self.windows:
            for edge, store in ((w.start, None), (w.start + w.seconds, True)):
                if (delay := edge - time.monotonic()) > 0:
                    time.sleep(delay)
                now = {name: cpu_seconds(pid) if pid is not None else time.process_time()  # None: this process
                       for name, pid in self.pids.items()}
                if store is None:
                    begin = now
                else:
                    self.samples.append({name: now[name] - begin[name] for name in now})

    def join(self) -> list[dict[str, float]]:
        self._thread.join(timeout=5)
        return self.samples


def bench_fleet(work: Path, port: int) -> Path:
    """The demo fleet on ``port`` with one generic JSON rule per (direction, type), no throttle."""
    def edit(data: dict[str, Any]) -> None:
        robot = data["robots"][ROBOT]
        extra = []
        for kind, ros_type in TYPES.items():
            extra.append({"direction": "ros_to_mqtt", "ros_topic": ros_topic("out", kind), "ros_type": ros_type,
                          "mqtt_topic": lat.join("state", rule_name("out", kind)),
                          "ros_qos": {"depth": 1000}})
            extra.append({"direction": "mqtt_to_ros", "mqtt_topic": rule_name("in", kind),
                          "ros_topic": ros_topic("in", kind), "ros_type": ros_type})
        robot["rules"] = [*robot["rules"], *extra]

    return lat.fleet_copy(work / f"robots-tp-{port}.yaml", CONFIG, port=port, ws_port=0, edit=edit)


def start_broker(stack: ExitStack, work: Path, env: dict[str, str], kind: str) -> tuple[int, Path, int] | None:
    port = lat.free_port()
    fleet = bench_fleet(work, port)
    if kind == "embedded":
        child = lat.start_embedded_broker(stack, fleet, port, work / f"embedded-{port}.log", env,
                                          "--limit", "user_publish_rate=0")
        return port, fleet, child.pid
    if lat.mosquitto_exe() is None:
        return None
    mosquitto = lat.Mosquitto.exported(work, fleet, export_dir=f"mosquitto-{port}")
    stack.callback(mosquitto.stop)
    mosquitto.start()
    return port, fleet, mosquitto.pid


def ros_to_mqtt(broker: str, kind: str, port: int, pids: dict[str, int | None], work: Path, env: dict[str, str],
                seconds: float) -> list[Row]:
    """rclpy publisher (child) -> bridge -> broker -> paho counter here."""
    from roslink_mqtt.mqtt import make_client
    from roslink_mqtt.topics import TopicTree

    rates = RATES[kind]
    counts = [0] * len(rates)
    topic = TopicTree(lat.load_fleet(CONFIG).prefix).state(ROBOT, rule_name("out", kind))

    def on_message(_c: Any, _u: Any, message: Any) -> None:
        w = window_of(kind, orjson.loads(message.payload))
        if 0 <= w < len(counts):
            counts[w] += 1

    client = make_client(f"bob-tp-{os.getpid()}-{kind}", username=VIEWER[0], password=VIEWER[1],
                         url=f"mqtt://127.0.0.1:{port}")
    subscribed = threading.Event()
    client.on_connect = lambda c, *_: c.subscribe(topic, qos=0)
    client.on_subscribe = lambda *_: subscribed.set()
    client.on_message = on_message
    client.connect("127.0.0.1", port, keepalive=30)
    client.loop_start()
    try:
        if not subscribed.wait(10):
            raise SystemExit(f"throughput bench: no SUBACK for {topic}")
        start = time.monotonic() + 4.0  # the child imports rclpy and matches the bridge's subscription first
        windows = schedule(rates, seconds, start)
        out = work / f"pub-{broker}-{kind}.json"
        with ExitStack() as phase:
            child = lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--ros-pub", kind,
                                            "--start", repr(start), "--seconds", str(seconds), "--out", str(out)],
                                    work / f"pub-{broker}-{kind}.log", env)
            sampler = CpuSampler({**pids, "ROS publisher": child.pid, "MQTT subscriber": None}, windows)
            child.popen.wait(timeout=windows[-1].start + seconds + GAP + 30 - time.monotonic())
            cpu = sampler.join()
        sent = orjson.loads(out.read_bytes())["sent"]
    finally:
        client.disconnect()
        client.loop_stop()
    return [Row(broker, "ROS->MQTT", kind, w.rate, seconds, sent[w.index], counts[w.index], cpu[w.index])
            for w in windows]


def mqtt_to_ros(broker: str, kind: str, port: int, pids: dict[str, int | None], work: Path, env: dict[str, str],
                seconds: float) -> list[Row]:
    """SDK publisher here -> broker -> bridge -> rclpy counter (child)."""
    from roslink_mqtt.client import rclpy as sdk
    from roslink_mqtt.client.rclpy.qos import qos_profile_sensor_data

    rates = RATES[kind]
    start = time.monotonic() + 5.0
    windows = schedule(rates, seconds, start)
    out = work / f"sub-{broker}-{kind}.json"
    with ExitStack() as phase:
        child = lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--ros-sub", kind,
                                        "--start", repr(start), "--seconds", str(seconds), "--out", str(out)],
                                work / f"sub-{broker}-{kind}.log", env)
        node = sdk.create_node(f"tp_{kind}", robot=ROBOT, url=f"mqtt://127.0.0.1:{port}", username=OPERATOR[0],
                               password=OPERATOR[1])
        phase.callback(node.destroy_node)
        pub = node.create_publisher(TYPES[kind], rule_name("in", kind), qos_profile_sensor_data)
        msg, stamp = json_message(kind)

        def send(window: int, index: int) -> None:
            stamp(msg, window, index)
            pub.publish(msg)

        sampler = CpuSampler({**pids, "ROS subscriber": child.pid, "MQTT publisher": None}, windows)
        sent = send_windows(windows, send)
        cpu = sampler.join()
        child.popen.wait(timeout=windows[-1].start + seconds + GAP + 30 - time.monotonic())
    received = orjson.loads(out.read_bytes())["received"]
    return [Row(broker, "MQTT->ROS", kind, w.rate, seconds, sent[w.index], received[w.index], cpu[w.index])
            for w in windows]


def run_broker(kind: str, work: Path, env: dict[str, str], seconds: float) -> list[Row] | None:
    rows: list[Row] = []
    with ExitStack() as phase:
        started = start_broker(phase, work, env, kind)
        if started is None:
            return None
        port, fleet, broker_pid = started
        bridge = lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet),
                                         "--robot", ROBOT, "--url", f"mqtt://127.0.0.1:{port}", "--log-level",
                                         "WARNING"], work / f"bridge-{kind}.log",
                                 {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD})
        pids: dict[str, int | None] = {"bridge": bridge.pid, "broker": broker_pid}
        name = "embedded" if kind == "embedded" else "Mosquitto"
        for stream in TYPES:
            rows += ros_to_mqtt(name, stream, port, pids, work, env, seconds)
            print(f"  {name} ROS->MQTT {stream}: done", flush=True)
            rows += mqtt_to_ros(name, stream, port, pids, work, env, seconds)
            print(f"  {name} MQTT->ROS {stream}: done", flush=True)
    return rows


# -- report --------------------------------------------------------------------------------------------------
PROCESSES = ("ROS publisher", "ROS subscriber", "MQTT publisher", "MQTT subscriber", "bridge", "broker")


def report(rows: list[Row]) -> None:
    print(f"\nThroughput per window ({rows[0].seconds:g} s each), loopback, {os.cpu_count()} cores; "
          f"CPU in ms per 1,000 messages. {lat.versions()}")
    print(f"{'broker':<10} {'direction':<10} {'type':<5} {'rate/s':>7} {'sent':>7} {'recv':>7} {'loss %':>7} "
          f"{'bridge':>7} {'broker':>7} {'ROS end':>8} {'MQTT end':>8}")
    for r in rows:
        loss = 100 * (1 - r.received / r.sent) if r.sent else float("nan")
        ros_end = r.per_1000("ROS publisher") if r.direction == "ROS->MQTT" else r.per_1000("ROS subscriber")
        mqtt_end = r.per_1000("MQTT subscriber") if r.direction == "ROS->MQTT" else r.per_1000("MQTT publisher")
        short = f" (sent {r.sent / r.seconds:.0f}/s)" if r.sent < r.rate * r.seconds else ""
        print(f"{r.broker:<10} {r.direction:<10} {r.kind:<5} {r.rate:>7} {r.sent:>7} {r.received:>7} {loss:7.2f} "
              f"{r.per_1000('bridge'):7.0f} {r.per_1000('broker'):7.0f} {ros_end:8.0f} {mqtt_end:8.0f}{short}")
    print("\nHighest lossless rate (msg/s) per stream:")
    for key in dict.fromkeys((r.broker, r.direction, r.kind) for r in rows):
        stream = [r for r in rows if (r.broker, r.direction, r.kind) == key]
        best = max((r.rate for r in stream if r.lossless), default=0)
        first_lossy = next((r for r in stream if not r.lossless and r.rate > best), None)
        beyond = (f"; at {first_lossy.rate}/s {100 * first_lossy.received / max(first_lossy.sent, 1):.1f} % arrived"
                  if first_lossy else "; no loss at any rate tried")
        print(f"  {key[0]:<10} {key[1]:<10} {key[2]:<5} {best:>6}{beyond}")


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), dpi=100)
    for ax, kind in zip(axes, TYPES, strict=False):
        for key in dict.fromkeys((r.broker, r.direction) for r in rows if r.kind == kind):
            stream = [r for r in rows if (r.broker, r.direction) == key and r.kind == kind]
            ax.plot([r.rate for r in stream], [r.received / r.seconds for r in stream], marker="o",
                    label=f"{key[0]} {key[1]}")
        top = max(RATES[kind])
        ax.plot([0, top], [0, top], color="grey", linewidth=0.8, linestyle="--", label="offered")
        ax.set_xlabel("offered, msg/s")
        ax.set_ylabel("delivered, msg/s")
        ax.set_title(f"{TYPES[kind]}", fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle("Bridge throughput: delivered vs offered per window", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=2.0, help="window per rate (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="1 s windows")
    p.add_argument("--brokers", default="embedded,mosquitto", help="comma-separated (default: %(default)s)")
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="(default: %(default)s)")
    p.add_argument("--ros-pub", choices=tuple(TYPES), help=argparse.SUPPRESS)  # the bench's own children
    p.add_argument("--ros-sub", choices=tuple(TYPES), help=argparse.SUPPRESS)
    p.add_argument("--start", type=float, default=0.0, help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, default=Path("throughput-child.json"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    seconds = 1.0 if args.quick else args.seconds
    if args.ros_pub or args.ros_sub:
        kind = args.ros_pub or args.ros_sub
        mode = "pub" if args.ros_pub else "sub"
        return ros_child(mode, kind, RATES[kind], seconds, args.start, args.out)
    brokers = [b.strip() for b in args.brokers.split(",") if b.strip()]
    if set(brokers) - {"embedded", "mosquitto"} or not 0.2 <= seconds <= 30:
        p.error("--brokers from embedded, mosquitto; --seconds in [0.2, 30]")
    began = time.monotonic()
    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    rows: list[Row] = []
    try:
        with tempfile.TemporaryDirectory(prefix="roslink-tp-") as tmp:
            for kind in brokers:
                got = run_broker(kind, Path(tmp), env, seconds)
                if got is None:
                    print(f"  {kind}: Mosquitto not installed, skipped")
                rows += got or []
    except KeyboardInterrupt:
        print("throughput bench: interrupted", file=sys.stderr)
        return 130
    except (lat.ChildExited, TimeoutError) as e:
        raise SystemExit(f"throughput bench: {e}") from None
    if rows:
        report(rows)
        plot(rows, args.plot)
        print(f"plot: {args.plot}")
    print(f"run took {time.monotonic() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
