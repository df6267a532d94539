"""Benchmark: the demo robot on a thin uplink, the bridge's scheduled uplink next to plain FIFO.

    .venv/bin/python bench/weak_link.py [--seconds 20] [--rates 1000,256,64] [--modes fifo,scheduled,rosbridge,zenoh]
        [--models visible,hidden] [--changes lossy,fall,dead]

The robot's bridge reaches the embedded broker through ``roslink_mqtt.shaped_link``: 40 ms each way, an uplink
of 1 Mbit/s, 256 kbit/s or 64 kbit/s (one FIFO shared by the bridge's connections, like a modem; the downlink
four times faster). The simulated robot publishes the demo's telemetry (20 Hz odometry → 10 Hz global_motion, a
5 Hz 360-beam scan, 1 Hz GPS and battery); the "+ camera + map" rows add a 30 Hz 640×480 JPEG (raw) and a 4 MB
OccupancyGrid (CBOR) every 10 s. bob, a viewer on the broker's side, times what arrives; alice, an operator,
calls the robot's ``reset`` service once a second and times each reply (the control round trip), and presses the
emergency stop every 3 s, timed from her call to the stop's ``std_msgs/Bool`` on the robot's ROS topic (an
rclpy subscriber in this process) and to the bridge's acknowledgement on ``state/ack`` back at her, then arms
again.

Each row runs once per mode in one run: the fleet file's ``bridge.uplink: fifo`` (every message handed to the
network at once: the behaviour before the scheduler, and rosbridge's and foxglove_bridge's), ``scheduled``, and
``rosbridge``: the peer (``rosbridge-server-rs``, ``make bench-peers``) serving the same sim's odometry and scan to
WebSocket clients across the same link, throttled to our rates with ``queue_length`` 1, and ``zenoh``: the same two
streams put with Zenoh's priorities (odometry express at ``INTERACTIVE_HIGH``, the scan at ``DATA_LOW``, both dropped
rather than queued when Zenoh's queue is full) by a client on the robot's side to a Zenoh router across the same
link (bench/zenoh_peer.py says how that stands for ``zenoh-bridge-ros2dds``). Every row runs on each link
model (``visible``: a modem whose queue backs up into the robot's socket; ``hidden``: a hop that acknowledges at
once), and the changing links after them (``--changes``: 2 % loss stalls with jitter, a fall from 1 Mbit/s to
128 kbit/s, a 4 s dead spot; the time to fresh after each change is in their rows).

Columns: per stream the rate bob received and the age of what he received (arrival − the message's own
timestamp, one clock: everything runs on this machine) at p50/p99 — 50 to 150 ms of a pose's age is the robot's
own (the 20 Hz odometry throttled to 10 Hz holds a pose up to 50 ms, in a phase that differs at each bridge
start), as the 1 Mbit/s rows show; the largest gap between heartbeats; the reply
round trip p50/p99. Never asserts: it prints a table (and writes a plot).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import defaultdict
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: brokers, bridge, bookkeeping shared by the benches)
import orjson

from roslink_mqtt.protocol import SystemStatus
from roslink_mqtt.protocol.link import LINK, LinkReport
from roslink_mqtt.topics import Kind, TopicTree, state_leaf

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
PLOT_DIR = ROOT / "docs" / "performance"
ROBOT, ROBOT_PASSWORD = "turtle1", "turtle1-demo"
OPERATOR = ("alice", "alice-demo")
VIEWER = ("bob", "bob-demo")
DELAY_MS = 40
DOWN_FACTOR = 4
IMAGE_TOPIC, MAP_TOPIC = "camera/image/compressed", "map_grid"
IMAGE_STATE, MAP_STATE = "image", "occupancy"
IMAGE_RATE, MAP_PERIOD = 30.0, 10.0
WARMUP = 4.0  # s after the robot is online before measuring
MOTION_RATE = 10.0  # the demo fleet's max_rate for global_motion
ESTOP_TOPIC = "/emergency_stop"  # where the demo fleet's emergency_stop rule publishes (std_msgs/Bool, latched)
BROKER_LOG_LEVEL = os.environ.get("WEAK_BROKER_LOG", "WARNING")  # INFO shows every connection (with --keep-logs)
BRIDGE_LOG_LEVEL = os.environ.get("WEAK_BRIDGE_LOG", "WARNING")  # DEBUG: the uplink's rates every window (--keep-logs)
STOP_PERIOD = 3.0  # s between alice's emergency stops
PEERS = ("rosbridge", "zenoh")  # rows of what users would pick instead: odometry and the scan, no bridge of ours


CHANGE_AT = 14.0  # s after the link starts: a changing row's change (the robot is online and warmed up by then)
AFTER_CHANGE = 8.0  # s measured after it
DEAD_SPOT = 4.0  # s of the dead-spot row's outage (both directions)
FRESH = 0.8  # s: a pose this young is fresh (time to fresh: from a change until every pose after is)
# changing rows: name -> (label, the link's options, its changes in s after CHANGE_AT)
CHANGES: dict[str, tuple[str, list[str], tuple[float, ...]]] = {
    "lossy": ("128 kbit/s, 2 % loss stalls, ±15 ms", ["--up-kbit", "128", "--down-kbit", "512", "--loss", "0.02",
                                                      "--jitter-ms", "15"], ()),
    "fall": ("1 Mbit/s → 128 kbit/s", ["--phases", f"{CHANGE_AT:g}:1024,600:128", "--down-kbit", "512",
                                       "--phases-once"], (0.0,)),
    "dead": (f"256 kbit/s, {DEAD_SPOT:g} s dead spot",
             ["--phases", f"{CHANGE_AT:g}:256,{DEAD_SPOT:g}:0,600:256",
              "--down-phases", f"{CHANGE_AT:g}:1024,{DEAD_SPOT:g}:0,600:1024", "--phases-once"], (0.0, DEAD_SPOT)),
}


@dataclass(frozen=True, slots=True)
class Case:
    kbit: int
    extras: bool  # camera + map
    hidden: bool = False  # the link's queue hidden behind a hop that acknowledges at once (shaped_link --hidden-queue)
    change: str = ""  # a changing link (CHANGES), else a steady one of ``kbit``

    @property
    def label(self) -> str:
        head = CHANGES[self.change][0] if self.change else f"{self.kbit:g} kbit/s"
        return head + (" + camera + map" if self.extras else "") + (" hidden" if self.hidden else "")

    def link_args(self) -> list[str]:
        """shaped_link's options for this row's link (the delay and the hidden queue aside)."""
        if self.change:
            return CHANGES[self.change][1]
        return ["--jitter-ms", "0", "--up-kbit", str(self.kbit), "--down-kbit", str(self.kbit * DOWN_FACTOR)]


def cases(rates: list[int], models: list[str] | None = None, changes: list[str] | None = None) -> list[Case]:
    """Every rate on every link model (``visible``: a modem whose queue backs up into the robot's socket;
    ``hidden``: a split-TCP proxy, VPN or load balancer that acknowledges at once); 1000 adds camera + map; then
    each changing link (CHANGES) on every model."""
    out = []
    for model in models or ["visible"]:
        hidden = model == "hidden"
        rows = [Case(rate, False, hidden) for rate in rates]
        if 1000 in rates:
            rows.insert(1, Case(1000, True, hidden))
        out += rows + [Case(0, False, hidden, change) for change in changes or []]
    return out


# -- the load child: camera and map on the robot ------------------------------------------------------------
def stamp_index() -> int:
    """Wall clock in 10 ms units (mod 1e8): the frame index the camera and map carry, read back as their age."""
    return int(time.time() * 100) % 100_000_000


def age_of_index(index: int, now: float) -> float:
    return ((int(now * 100) - index) % 100_000_000) / 100


def load(_url: str) -> int:
    """Hidden ``--load`` mode: the 30 Hz camera and the 4 MB map every 10 s, until SIGINT."""
    import large
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("weak_link_load")
    frames = large.Frames()
    from nav_msgs.msg import OccupancyGrid
    from sensor_msgs.msg import CompressedImage

    image_pub = node.create_publisher(CompressedImage, IMAGE_TOPIC, 5)
    map_pub = node.create_publisher(OccupancyGrid, MAP_TOPIC, 1)
    start, period, n, next_map = time.monotonic(), 1.0 / IMAGE_RATE, 0, time.monotonic() + 1.0
    while not stop.wait(max(0.0, start + n * period - time.monotonic())):
        image_pub.publish(frames.stamp("image", stamp_index()))
        n += 1
        if time.monotonic() >= next_map:
            map_pub.publish(frames.stamp("map", stamp_index()))
            next_map += MAP_PERIOD
    print(f"load: {n} images, jpeg {frames.jpeg_size} bytes", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# -- one run --------------------------------------------------------------------------------------------------
@dataclass
class Run:
    case: Case
    mode: str
    seconds: float = 0.0
    ages: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))  # stream -> ages (s)
    motion: list[tuple[float, float]] = field(default_factory=list)  # global_motion (arrival, age), monotonic s
    changes: list[float] = field(default_factory=list)  # when the link changed (monotonic s)
    heartbeats: list[float] = field(default_factory=list)  # arrival times
    replies: list[float] = field(default_factory=list)  # round trips (s)
    stops: list[float] = field(default_factory=list)  # emergency stop sent → its Bool on the robot's ROS topic (s)
    stop_acks: list[float] = field(default_factory=list)  # emergency stop sent → the bridge's state/ack (s; inf: none)
    failed_calls: int = 0
    failures: list[str] = field(default_factory=list)  # why calls failed
    link: Any = None  # the bridge's last state/link report (a LinkReport)
    silent: int = 0  # times the bridge found the broker silent (a heartbeat's PUBACK late): each one a stop
    warnings: list[str] = field(default_factory=list)  # the bridge's last warnings, shown when it found silence
    note: str = ""


class Viewer:
    """bob on the broker: records, per state stream, the age of every message while ``recording`` is set."""

    def __init__(self, port: int, prefix: str) -> None:
        import cbor2

        self.cbor_loads = cbor2.loads
        self.run: Run | None = None
        self.online = threading.Event()
        self.client = lat.make_client(f"bob-weak-{os.getpid()}", username=VIEWER[0], password=VIEWER[1],
                                      url=f"mqtt://127.0.0.1:{port}")
        topics = TopicTree(prefix)
        self.topics = topics
        self.heartbeat_topic = topics.heartbeat(ROBOT)
        self.client.on_connect = lambda c, *_: c.subscribe([(self.heartbeat_topic, 0),
                                                            (topics.state_filter(ROBOT), 0)])
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", port, keepalive=30)
        self.client.loop_start()

    def _on_message(self, _c: Any, _u: Any, message: Any) -> None:
        now = time.time()
        topic, payload = message.topic, message.payload
        if topic == self.heartbeat_topic:
            if message.retain:
                return
            status = orjson.loads(payload)["payload"]["system_status"]
            if status != SystemStatus.OFFLINE:
                self.online.set()
            if self.run is not None:
                self.run.heartbeats.append(time.monotonic())
            return
        run = self.run
        if run is None or message.retain:
            return
        parsed = self.topics.parse(topic)
        if parsed is None or parsed.kind is not Kind.STATE:
            return
        name = parsed.name
        if name == LINK and payload:
            run.link = LinkReport.from_json(payload)
            return
        try:
            if name == "global_motion":
                age = now - orjson.loads(payload)["payload"]["time_boot_ms"] / 1000
                run.ages[name].append(age)
                run.motion.append((time.monotonic(), age))
            elif name == "range_finder_data":
                run.ages[name].append(now - orjson.loads(payload)["payload"]["time_usec"] / 1e6)
            elif name == IMAGE_STATE:
                import large

                index = large.index_of(payload, "raw")
                if index is not None:
                    run.ages[name].append(age_of_index(index, now))
            elif name == MAP_STATE:
                frame = self.cbor_loads(payload)["header"]["frame_id"]
                run.ages[name].append(age_of_index(int(frame), now))
        except (KeyError, ValueError, TypeError):
            pass

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def bench_fleet(work: Path, port: int, mode: str, extras: bool) -> Path:
    def edit(data: dict[str, Any]) -> None:
        robot = data["robots"][ROBOT]
        robot["bridge"] = {**robot["bridge"], "uplink": mode}
        if extras:
            robot["rules"] = [*robot["rules"],
                              {"direction": "ros_to_mqtt", "ros_topic": IMAGE_TOPIC,
                               "ros_type": "sensor_msgs/msg/CompressedImage", "mqtt_topic": state_leaf(IMAGE_STATE),
                               "encoding": "raw"},
                              {"direction": "ros_to_mqtt", "ros_topic": MAP_TOPIC,
                               "ros_type": "nav_msgs/msg/OccupancyGrid", "mqtt_topic": state_leaf(MAP_STATE),
                               "encoding": "cbor", "ros_qos": {"durability": "volatile"}}]
        data["broker"]["max_payload"] = 16 << 20

    return lat.fleet_copy(work / f"robots-{mode}-{int(extras)}.yaml", CONFIG, port=port, ws_port=0, edit=edit)


def caller(operator: Any, stop: threading.Event, run_: list[Run | None]) -> None:
    """alice calls ``reset`` once a second; each reply's round trip goes to the row it was sent in."""
    from roslink_mqtt.client import ServiceError, ServiceTimeout

    while not stop.wait(1.0):
        began, row = time.monotonic(), run_[0]  # the row it was sent in (a call between rows meets no bridge)
        try:
            operator.call(ROBOT, "reset", timeout=10.0)
        except (ServiceError, ServiceTimeout, OSError) as err:
            if row is not None and row is run_[0]:  # its bridge ran the whole time: a real failure
                row.failed_calls += 1
                row.failures.append(str(err)[:120])
            continue
        if row is not None:
            row.replies.append(time.monotonic() - began)


class StopWatch:
    """An rclpy subscriber here on the robot's ``emergency_stop`` topic: when each stop reached ROS."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import Bool

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("weak_link_stop_watch")
        self.arrivals: list[float] = []
        self.cond = threading.Condition()
        self.subscription = self.node.create_subscription(Bool, ESTOP_TOPIC, self._on_stop, 10)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _on_stop(self, msg: Any) -> None:
        if msg.data:
            with self.cond:
                self.arrivals.append(time.monotonic())
                self.cond.notify_all()

    def wait_matched(self, timeout: float) -> bool:
        """Until the (new) bridge's publisher is discovered: a stop published before that is not seen here."""
        deadline = time.monotonic() + timeout
        while self.subscription.get_publisher_count() < 1:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def wait_after(self, t: float, timeout: float) -> float | None:
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                later = [a for a in self.arrivals if a >= t]
                if later:
                    return later[0]
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self.thread.join(2)
        self.node.destroy_node()
        rclpy.try_shutdown()


def stopper(operator: Any, watch: StopWatch, stop: threading.Event, run_: list[Run | None]) -> None:
    """alice presses the emergency stop every STOP_PERIOD s, times it to the robot's ROS topic, and arms again."""
    while not stop.wait(STOP_PERIOD):
        sent, row = time.monotonic(), run_[0]  # the row it was sent in (a stop sent between rows meets no bridge)
        acked: float | None = None
        try:  # the stop, then its acknowledgement on state/ack (the SDK's emergency_stop_all times it)
            ack = operator.emergency_stop_all("bench", robots=[ROBOT], timeout=5.0)[ROBOT]
            acked = ack.seconds if ack.acknowledged else None
        except Exception:  # noqa: BLE001 - a stop the broker did not confirm: counted as not arrived below
            pass
        arrived = watch.wait_after(sent, 5.0)
        if row is not None and (arrived is not None or row is run_[0]):  # an ended row's bridge may be gone
            row.stops.append(float("inf") if arrived is None else arrived - sent)
            row.stop_acks.append(float("inf") if acked is None else acked)
        try:
            operator.arm(ROBOT)
        except Exception:  # noqa: BLE001 - the next stop is measured all the same
            pass


def window(run: Run, link_up: float, began: float, seconds: float) -> float:
    """Seconds to measure from ``began``: ``seconds``, or for a changing link until AFTER_CHANGE after its last
    change (whose times go to ``run.changes``); a note on ``run`` when the robot came online too late for them."""
    if not run.case.change:
        return seconds
    at = CHANGES[run.case.change][2]
    run.changes = [link_up + CHANGE_AT + t for t in at]
    if began > link_up + CHANGE_AT - 2.0:
        run.note = f"online {began - link_up:.1f} s after the link started: too late for its change"
    return link_up + CHANGE_AT + (max(at) if at else 0.0) + AFTER_CHANGE - began


def rosbridge_run(case: Case, seconds: float, work: Path, env: dict[str, str], rosbridge_port: int) -> Run:
    """The peer row: the same sim's odometry and scan from rosbridge (``rosbridge-server-rs``) to WebSocket
    clients across the same link (the robot's uplink is the proxy's down direction there), with rosbridge's own
    remedies for a thin link set: ``throttle_rate`` at our rows' rates (odometry 10 Hz like global_motion, the
    scan 5 Hz) and ``queue_length`` 1 (latest wins)."""
    import rosbridge_peer as rp

    run = Run(case, "rosbridge")
    with ExitStack() as phase:
        link_port = lat.free_port()
        lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.shaped_link", "--listen",
                                f"127.0.0.1:{link_port}", "--to", f"127.0.0.1:{rosbridge_port}", "--delay-ms",
                                str(DELAY_MS), *rp.reversed_link(case.link_args()),
                                *(["--hidden-queue"] if case.hidden else [])],
                        work / f"link-rb-{link_port}.log", env, port=link_port, what="shaped link")
        link_up = time.monotonic()
        url = f"ws://127.0.0.1:{link_port}"
        ages = rp.OdomAges(url, throttle_rate=int(1000 / MOTION_RATE), queue_length=1, backend="websockets",
                           connect_timeout=20.0)
        phase.callback(ages.close)
        # and the scan, as a viewer of our rows gets it (5 Hz): the same link carries both, as ours does
        scans = rp.OdomAges(url, topic="/scan", msg_type="sensor_msgs/msg/LaserScan", throttle_rate=200,
                            queue_length=1, backend="websockets", connect_timeout=20.0)
        phase.callback(scans.close)
        if not ages.wait_first(30.0):
            run.note = "no odometry came through rosbridge within 30 s"
            return run
        time.sleep(WARMUP)
        began = time.monotonic()
        seconds = window(run, link_up, began, seconds)
        if run.note:
            return run
        time.sleep(seconds)
        run.seconds = time.monotonic() - began
        run.motion = [(arrived, age) for arrived, age in list(ages.timed) if arrived >= began]
        run.ages["global_motion"] = [age for _, age in run.motion]
        run.ages["range_finder_data"] = [age for arrived, age in list(scans.timed) if arrived >= began]
        if ages.disconnects or scans.disconnects:
            run.note = f"rosbridge dropped the clients {ages.disconnects + scans.disconnects} times"
    return run


def zenoh_run(case: Case, seconds: float, work: Path, env: dict[str, str], router: Any, router_port: int) -> Run:
    """The Zenoh row: the same sim's odometry (thinned to 10 Hz) and scan, put with Zenoh's priorities by a client
    on the robot's side (bench/zenoh_peer.py) across the same link to a Zenoh router on the far side."""
    import zenoh_peer

    run = Run(case, "zenoh")
    router.clear()
    with ExitStack() as phase:
        link_port = lat.free_port()
        lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.shaped_link", "--listen",
                                f"127.0.0.1:{link_port}", "--to", f"127.0.0.1:{router_port}", "--delay-ms",
                                str(DELAY_MS), *case.link_args(), *(["--hidden-queue"] if case.hidden else [])],
                        work / f"link-zenoh-{link_port}.log", env, port=link_port, what="shaped link")
        link_up = time.monotonic()
        log = work / f"zenoh-robot-{link_port}.log"
        lat.start_child(phase, [sys.executable, str(Path(__file__).with_name("zenoh_peer.py")), "--robot",
                                "--connect", zenoh_peer.locator(link_port)], log, env)
        if not router.first.wait(30.0):
            run.note = f"no odometry came through Zenoh within 30 s: {lat.tail(log, 3)}"
            return run
        time.sleep(WARMUP)
        began = time.monotonic()
        seconds = window(run, link_up, began, seconds)
        if run.note:
            return run
        time.sleep(seconds)
        end = time.monotonic()
        run.seconds = end - began
        run.motion = router.between("odom", began, end)
        run.ages["global_motion"] = [age for _, age in run.motion]
        run.ages["range_finder_data"] = [age for _, age in router.between("scan", began, end)]
    return run


def start_zenoh(stack: ExitStack) -> tuple[Any, int, str]:
    """The Zenoh router for the Zenoh rows: (it, its port, "") or (None, 0, why it cannot run)."""
    import zenoh_peer

    try:
        port = lat.free_port()
        router = zenoh_peer.ZenohViewer(port)
    except ImportError as err:
        return None, 0, f"zenoh could not run: {err} (`make bench-peers` installs eclipse-zenoh)"
    stack.callback(router.close)
    return router, port, ""


def one_run(case: Case, mode: str, seconds: float, work: Path, env: dict[str, str], port: int, viewer: Viewer,
            current: list[Run | None], watch: StopWatch | None = None) -> Run:
    run = Run(case, mode)
    with ExitStack() as phase:
        fleet = bench_fleet(work, port, mode, case.extras)
        link_port = lat.free_port()
        lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.shaped_link", "--listen",
                                f"127.0.0.1:{link_port}", "--to", f"127.0.0.1:{port}", "--delay-ms", str(DELAY_MS),
                                *case.link_args(), *(["--hidden-queue"] if case.hidden else [])],
                        work / f"link-{link_port}.log", env, port=link_port, what="shaped link")
        link_up = time.monotonic()  # (its phases count from its start: it listens just before this)
        if case.extras:
            lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--load"],
                            work / f"load-{link_port}.log", env)
        viewer.online.clear()
        bridge_log = work / f"bridge-{mode}-{link_port}.log"
        lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot",
                                ROBOT, "--url", f"mqtt://127.0.0.1:{link_port}", "--log-level", BRIDGE_LOG_LEVEL],
                        bridge_log, {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD})
        if not viewer.online.wait(30):
            run.note = f"the robot did not come online: {lat.tail(bridge_log, 5)}"
            return run
        time.sleep(WARMUP)
        if watch is not None and not watch.wait_matched(10.0):
            print("  (the bench's ROS subscriber has not discovered the bridge's emergency_stop publisher: its stops "
                  "may go unseen)", flush=True)
        began = time.monotonic()
        seconds = window(run, link_up, began, seconds)
        if run.note:
            return run
        viewer.run = current[0] = run
        before = bridge_log.read_text(errors="replace").count("broker silent")
        time.sleep(seconds)
        viewer.run = current[0] = None
        run.seconds = time.monotonic() - began
        log_text = bridge_log.read_text(errors="replace")
        run.silent = log_text.count("broker silent") - before
        run.warnings = [line for line in log_text.splitlines()
                        if (" WARNING " in line or " ERROR " in line) and "emergency stop by" not in line][-5:]
    return run


# -- report ---------------------------------------------------------------------------------------------------
def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def stream_cell(run: Run, name: str) -> str:
    ages = run.ages.get(name, [])
    if not ages:
        return "none"
    rate = len(ages) / run.seconds
    return f"{rate:5.1f}/s {pct(ages, 0.5) * 1000:6.0f}/{pct(ages, 0.99) * 1000:6.0f} ms"


def stop_cell(times: list[float]) -> str:
    """The slowest of a row's emergency stops (inf: not seen within 5 s), and how many there were."""
    if not times:
        return "-"
    unseen = sum(1 for t in times if t == float("inf"))
    seen = [t for t in times if t != float("inf")]
    text = f"{max(seen) * 1000:.0f} ms" if seen else "unseen"
    return text + (f" ({len(seen)}/{len(times)})" if unseen else f" ({len(times)})")


def heartbeat_gap(run: Run) -> float:
    beats = run.heartbeats
    return max((b - a for a, b in zip(beats, beats[1:], strict=False)), default=float("nan"))


def fresh_after(run: Run, event: float) -> float | None:
    """Seconds from ``event`` until every pose that arrives is under FRESH old (None: not within the row)."""
    after = [(arrived, age) for arrived, age in run.motion if arrived >= event]
    stale = [i for i, (_, age) in enumerate(after) if age >= FRESH]
    if not after or (stale and stale[-1] == len(after) - 1):
        return None
    return after[stale[-1] + 1 if stale else 0][0] - event


def change_cell(run: Run) -> str:
    """A changing row: pose age p99 from 2 s after the (first) change, and the time to fresh after each change."""
    if not run.changes:
        return ""
    later = [age for arrived, age in run.motion if arrived >= run.changes[0] + 2.0]
    fresh = [fresh_after(run, at) for at in run.changes]
    cells = ", ".join("never" if f is None else f"{f:.1f} s" for f in fresh)
    return f"p99 {pct(later, 0.99) * 1000:.0f} ms from 2 s after; fresh after {cells}"


def report(runs: list[Run]) -> None:
    extras = any(r.case.extras for r in runs)
    head = (f"{'uplink':<33} {'mode':<10} {'global_motion rate, age p50/p99':<34} {'scan rate, age p50/p99':<30}"
            f" {'hb gap':>7} {'silent':>6} {'reply p50/p99':>15} {'e-stop max':>10} {'ack max':>10}")
    if extras:
        head += f"  {'image rate, age p50/p99':<30} {'map rate, age p50/p99':<30}"
    print()
    print(head)
    print("-" * len(head))
    for run in runs:
        if run.note:
            print(f"{run.case.label:<33} {run.mode:<10} failed: {run.note}")
            continue
        replies = f"{pct(run.replies, 0.5) * 1000:5.0f}/{pct(run.replies, 0.99) * 1000:5.0f} ms"
        if run.failed_calls:
            replies += f" ({run.failed_calls} failed)"
        line = (f"{run.case.label:<33} {run.mode:<10} {stream_cell(run, 'global_motion'):<34} "
                f"{stream_cell(run, 'range_finder_data'):<30} {heartbeat_gap(run):6.2f}s {run.silent:>6} {replies:>15}"
                f" {stop_cell(run.stops):>10} {stop_cell(run.stop_acks):>10}")
        if extras:
            line += f"  {stream_cell(run, IMAGE_STATE):<30} {stream_cell(run, MAP_STATE):<30}"
        if run.changes:
            line += f"  {change_cell(run)}"
        print(line)
    print("\nsilent: heartbeats the broker did not acknowledge in time (each one is a failsafe stop of a driven robot)")
    print(f"e-stop max: alice's emergency stops (one every {STOP_PERIOD:g} s) from her call to the Bool on the robot's "
          f"{ESTOP_TOPIC}, the slowest (seen/sent when some were not seen within 5 s); ack max: the same stops "
          "from her call to the bridge's acknowledgement on state/ack, back at alice")
    print(f"changing links: the change {CHANGE_AT:g} s after the link started, measured until {AFTER_CHANGE:g} s after "
          f"the last; fresh after: from each change (a dead spot: its start, then the link's return) until every pose "
          f"that arrives is under {FRESH * 1000:.0f} ms old")
    print(f"rates: messages a second bob received (global_motion is throttled to {MOTION_RATE:g} Hz on the robot, "
          "the scan is 5 Hz); age = arrival − the message's own timestamp")


def plot(runs: list[Run], plot_dir: Path) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    shown = [r for r in runs if not r.note and r.ages.get("global_motion")]
    if not shown:
        return None
    fig, ax = plt.subplots(figsize=(max(10.0, 0.55 * len(shown)), 6.0))
    data = [[a * 1000 for a in r.ages["global_motion"]] for r in shown]
    ax.boxplot(data, whis=(1, 99), showfliers=False)
    ax.set_xticks(range(1, len(shown) + 1), [f"{r.case.label}, {r.mode}" for r in shown], fontsize=7,
                  rotation=60, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel("global_motion age at the viewer (ms, log)")
    ax.set_title("Thin uplinks: " + ", ".join(dict.fromkeys(r.mode for r in shown)) + " (whiskers p1–p99)")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    path = plot_dir / "weak_link.png"
    fig.savefig(path, dpi=110)
    return path


def start_peer(stack: ExitStack, work: Path, env: dict[str, str]) -> tuple[int, str]:
    """rosbridge for the peer rows, on the sim's graph: (its port, "") or (0, why it cannot run)."""
    try:
        import rosbridge_peer as rp

        port = lat.free_port()
        rp.start_rosbridge(stack, port, rp.rosbridge_env(env), work / "rosbridge.log")
        return port, ""
    except (FileNotFoundError, lat.ChildExited, TimeoutError, ValueError) as err:
        return 0, f"rosbridge could not run: {str(err)[:200]}"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=12.0, help="measured per row (default: %(default)s)")
    p.add_argument("--rates", default="1000,256,64", help="uplinks in kbit/s (default: %(default)s; 1000 adds the "
                                                          "camera + map row)")
    p.add_argument("--modes", default="fifo,scheduled,rosbridge,zenoh", help="bridge.uplink modes, and the peers "
                   "(`make bench-peers`): rosbridge (rosbridge-server-rs) serving the same sim's odometry and scan "
                   "across the same link, zenoh (eclipse-zenoh with priorities, to a router; bench/zenoh_peer.py) "
                   "(default: %(default)s)")
    p.add_argument("--models", default="visible,hidden", help="link models: visible (a modem: the queue backs up "
                   "into the robot's socket), hidden (a hop that acknowledges at once hides it) (default: %(default)s)")
    p.add_argument("--changes", default=",".join(CHANGES), help="changing links, on every model: "
                   + "; ".join(f"{name} ({label})" for name, (label, _, _) in CHANGES.items())
                   + " ('' for none; default: %(default)s)")
    p.add_argument("--plot-dir", type=Path, default=PLOT_DIR, help="where weak_link.png goes (default: %(default)s)")
    p.add_argument("--keep-logs", type=Path, help="copy the broker's, bridges' and links' logs here")
    p.add_argument("--load", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    try:
        args.rate_list = [int(r) for r in args.rates.split(",") if r.strip()]
    except ValueError:
        p.error(f"--rates: expected kbit/s numbers, got {args.rates!r}")
    args.mode_list = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not set(args.mode_list) <= {"fifo", "scheduled", *PEERS}:
        p.error("--modes: fifo, scheduled, rosbridge and/or zenoh")
    args.model_list = [m.strip() for m in args.models.split(",") if m.strip()]
    if not args.model_list or not set(args.model_list) <= {"visible", "hidden"}:
        p.error("--models: visible and/or hidden")
    args.change_list = [c.strip() for c in args.changes.split(",") if c.strip()]
    if not set(args.change_list) <= set(CHANGES):
        p.error(f"--changes: some of {', '.join(CHANGES)}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.load:
        return load("")
    began = time.monotonic()
    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    os.environ["ROS_LOG_DIR"] = env["ROS_LOG_DIR"]
    from roslink_mqtt.client import RobotClient

    runs: list[Run] = []
    current: list[Run | None] = [None]
    stop = threading.Event()
    with tempfile.TemporaryDirectory(prefix="roslink-weak-") as tmp, ExitStack() as stack:
        work = Path(tmp)
        port = lat.free_port()
        fleet = bench_fleet(work, port, "scheduled", True)
        lat.start_embedded_broker(stack, fleet, port, work / "broker.log", env, log_level=BROKER_LOG_LEVEL)
        lat.start_child(stack, [sys.executable, "-m", "roslink_mqtt.sim"], work / "sim.log", env)
        viewer = Viewer(port, lat.load_fleet(fleet).prefix)
        stack.callback(viewer.close)
        operator = RobotClient(OPERATOR[0], OPERATOR[1], url=f"mqtt://127.0.0.1:{port}").connect()
        stack.callback(operator.close)
        calls = threading.Thread(target=caller, args=(operator, stop, current), daemon=True)
        calls.start()
        watch = StopWatch()
        stack.callback(watch.close)
        stops = threading.Thread(target=stopper, args=(operator, watch, stop, current), daemon=True)
        stops.start()
        stack.callback(stop.set)
        rosbridge_port, no_rosbridge = start_peer(stack, work, env) if "rosbridge" in args.mode_list else (0, "")
        router, router_port, no_zenoh = start_zenoh(stack) if "zenoh" in args.mode_list else (None, 0, "")
        try:
            for case in cases(args.rate_list, args.model_list, args.change_list):
                for mode in args.mode_list:
                    if mode in PEERS and case.extras:
                        continue  # (the peer rows carry odometry and the scan only)
                    if mode == "zenoh":
                        run = zenoh_run(case, args.seconds, work, env, router, router_port) if not no_zenoh \
                            else Run(case, mode, note=no_zenoh)
                    elif mode == "rosbridge":
                        run = rosbridge_run(case, args.seconds, work, env, rosbridge_port) if not no_rosbridge \
                            else Run(case, mode, note=no_rosbridge)
                    else:
                        run = one_run(case, mode, args.seconds, work, env, port, viewer, current, watch)
                    runs.append(run)
                    print(f"  {case.label:<33} {mode:<10} motion {stream_cell(run, 'global_motion')}, "
                          + (f"{change_cell(run)}, " if run.changes else "")
                          + f"hb gap {heartbeat_gap(run):.2f} s, {run.silent} silent, {len(run.replies)} replies"
                          + (f" [{run.note}]" if run.note else "")
                          + (f"\n      bridge: {run.link.summary()}" if run.link is not None else "")
                          + "".join(f"\n      call failed: {why}" for why in run.failures[:3])
                          + ("".join(f"\n      bridge log: {line[:160]}" for line in run.warnings)
                             if run.silent else ""), flush=True)
        except KeyboardInterrupt:
            print("weak_link: interrupted", file=sys.stderr)
            return 130
        except (lat.ChildExited, TimeoutError) as e:
            raise SystemExit(f"weak_link: {e}") from None
        if any(run.silent for run in runs):
            warned = [line for line in (work / "broker.log").read_text(errors="replace").splitlines()
                      if " WARNING " in line or " ERROR " in line]
            print("".join(f"  broker log: {line[:160]}\n" for line in warned[-8:]), end="")
        if args.keep_logs is not None:
            shutil.copytree(work, args.keep_logs, dirs_exist_ok=True)
    report(runs)
    written = plot(runs, args.plot_dir)
    if written is not None:
        print(f"plot: {written}")
    print(f"{lat.versions()}; {DELAY_MS} ms each way, downlink {DOWN_FACTOR}× the uplink; run took "
          f"{time.monotonic() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
