"""Benchmark: large messages (camera image, point cloud, map) through the bridge, per encoding and broker.

    .venv/bin/python bench/large.py [--seconds 4] [--quick] [--plot PATH]

An rclpy publisher in this process publishes, one stream at a time:

* ``image``: a 640×480 JPEG ``sensor_msgs/CompressedImage`` (made once with Pillow) at 30 Hz;
* ``cloud``: a ``sensor_msgs/PointCloud2`` of 65,536 points × 16 B (1 MiB of data) at 10 Hz;
* ``map``:   a 2000×2000 ``nav_msgs/OccupancyGrid`` (4 MB of cells) at 1 Hz.

turtle1's bridge runs on a copy of robots.yaml that adds one ROS→MQTT rule per stream and encoding (json and
cbor for all three, raw for the image; no ``max_rate``, so every frame is offered), against the embedded broker
and against Mosquitto running the fleet's exported config. A paho subscriber here (bob, a viewer) receives the
stream. Per row: MQTT payload bytes per message, frames/s published and delivered, latency p50/p99 from
``publish()`` to the subscriber's callback, and the bridge's and the broker's CPU over the window (user + system
from /proc, % of one core). The direct rows publish the same messages to an rclpy subscriber in a child process
(one DDS hop, no bridge); their "bytes" are the serialized CDR size.

Matching a receipt to its send: the frame's index travels in ``header.frame_id`` (json, cbor, direct) or, for
raw images (which carry no header), in a JPEG comment segment right after the SOI marker; the send time stays
here, keyed by index. Every clock reading is time.monotonic() (CLOCK_MONOTONIC, one clock for every process).

The twist rows reuse bench/latency.py's command path (SDK RobotClient as alice with presence -> broker ->
bridge -> ``cmd_vel`` -> an rclpy subscriber here) at 20 Hz, once idle and once while the 30 Hz raw image
stream flows to a viewer.

The broker's ``max_payload`` is 4 MiB (robots.yaml ``broker.max_payload``): the JSON map (~10 MB) exceeds it.
The bench sends it anyway and reports what happens (last rows, so it cannot disturb the others).

Never asserts on timing: it prints one table and writes a chart (matplotlib).
"""

from __future__ import annotations

import argparse
import array
import io
import os
import re
import statistics
import struct
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: the twist command path and its bookkeeping)
from _support import cpu_seconds

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ROBOT, ROBOT_PASSWORD = "turtle1", "turtle1-demo"
DEFAULT_PLOT = ROOT / "docs" / "performance" / "large.png"
PRIME_SECONDS = 12.0  # bound on waiting for a stream's first frame through a freshly matched bridge subscription
SETTLE = 2.0  # bound on waiting for frames in flight after a window
TWIST_RATE = 20.0
ROS_TOPIC = "/bench_large/{stream}"  # one ROS topic per stream; the bridge's rules of every encoding read it
DIRECT_TOPIC = "/bench_large_direct/{stream}"  # the direct rows' own topics: the bridge does not subscribe them


@dataclass(frozen=True, slots=True)
class Stream:
    name: str
    ros_type: str
    rate: float
    encodings: tuple[str, ...]
    what: str


STREAMS = {
    "image": Stream("image", "sensor_msgs/msg/CompressedImage", 30.0, ("raw", "cbor", "json"), "640×480 JPEG"),
    "cloud": Stream("cloud", "sensor_msgs/msg/PointCloud2", 10.0, ("cbor", "json"), "PointCloud2 1 MiB"),
    "map": Stream("map", "nav_msgs/msg/OccupancyGrid", 1.0, ("cbor", "json"), "OccupancyGrid 2000²"),
}


# -- messages ---------------------------------------------------------------------------------------
def make_jpeg() -> bytes:
    """A real 640×480 JPEG of a camera-like scene (gradients, shapes, sensor noise), quality 80."""
    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(17)
    y, x = np.mgrid[0:480, 0:640]
    img = np.zeros((480, 640, 3), np.float32)
    img[..., 0] = 120 + 80 * np.sin(x / 50.0)
    img[..., 1] = 100 + 60 * np.cos(y / 35.0)
    img[..., 2] = 90 + 0.2 * x
    shapes = ((160, 240, 70, (230, 40, 40)), (420, 180, 90, (40, 200, 60)), (520, 380, 50, (30, 30, 220)))
    for cx, cy, r, colour in shapes:
        img[(x - cx) ** 2 + (y - cy) ** 2 < r * r] = colour
    img += rng.normal(0, 12, img.shape)
    out = io.BytesIO()
    Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)).save(out, "JPEG", quality=80)
    return out.getvalue()


INDEX_MARK = b"idx:"
COMMENT = b"\xff\xfe" + struct.pack(">H", 2 + len(INDEX_MARK) + 8)  # JPEG COM segment holding "idx:NNNNNNNN"


def frame_id(index: int) -> str:
    return f"{index:08d}"  # fixed width: every frame has the same size


class Frames:
    """The three messages, built once; ``stamp(stream, index)`` writes the index into one and returns it."""

    def __init__(self) -> None:
        import numpy as np
        from nav_msgs.msg import OccupancyGrid
        from sensor_msgs.msg import CompressedImage, PointCloud2, PointField

        jpeg = make_jpeg()
        self.jpeg_size = len(jpeg)
        self._jpeg = bytearray(jpeg[:2] + COMMENT + INDEX_MARK + b"00000000" + jpeg[2:])
        self._mark_at = 2 + len(COMMENT) + len(INDEX_MARK)
        self.image = CompressedImage(format="jpeg")
        self.image.header.frame_id = "camera"
        points = 65536
        cloud = PointCloud2(height=1, width=points, point_step=16, row_step=16 * points, is_dense=True,
                            fields=[PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                                    for i, n in enumerate(("x", "y", "z", "intensity"))])
        rng = np.random.default_rng(3)
        cloud.data = rng.normal(0, 5, points * 4).astype(np.float32).tobytes()
        self.cloud = cloud
        grid = OccupancyGrid()
        grid.info.width = grid.info.height = 2000
        grid.info.resolution = 0.05
        grid.info.origin.orientation.w = 1.0
        cells = np.full(2000 * 2000, -1, np.int8)
        cells[: 2000 * 1200] = rng.choice(np.array([0, 0, 0, 0, 100], np.int8), 2000 * 1200)
        grid.data = array.array("b", cells.tobytes())
        self.map = grid

    def stamp(self, stream: str, index: int) -> Any:
        if stream == "image":
            self._jpeg[self._mark_at:self._mark_at + 8] = frame_id(index).encode()
            self.image.data = bytes(self._jpeg)
            self.image.header.frame_id = frame_id(index)
            return self.image
        msg = self.cloud if stream == "cloud" else self.map
        msg.header.frame_id = frame_id(index)
        return msg


FRAME_ID_JSON = re.compile(rb'"frame_id":\s*"(\d{8})"')


def index_of(payload: bytes, encoding: str) -> int | None:
    """The frame index a received payload carries (None: not one of ours)."""
    if encoding == "raw":
        at = payload.find(INDEX_MARK, 0, 64)
        return int(payload[at + len(INDEX_MARK):at + len(INDEX_MARK) + 8]) if at >= 0 else None
    if encoding == "json":
        match = FRAME_ID_JSON.search(payload, 0, 400)
        return int(match.group(1)) if match else None
    import cbor2

    header = cbor2.loads(payload).get("header", {})
    fid = header.get("frame_id", "")
    return int(fid) if fid.isdigit() else None


# -- processes --------------------------------------------------------------------------------------
def rule_name(stream: str, encoding: str) -> str:
    return f"large_{stream}_{encoding}"


def bench_fleet(work: Path, port: int) -> Path:
    """A copy of the demo fleet on ``port`` with one ROS→MQTT rule per (stream, encoding), no throttle."""
    def add_rules(data: dict[str, Any]) -> None:
        rules = data["robots"][ROBOT]["rules"]  # shared with turtle2 through the YAML anchor: harmless here
        for stream in STREAMS.values():
            for encoding in stream.encodings:
                rules.append({"direction": "ros_to_mqtt", "ros_topic": ROS_TOPIC.format(stream=stream.name),
                              "ros_type": stream.ros_type,
                              "mqtt_topic": lat.join("state", rule_name(stream.name, encoding)),
                              "encoding": encoding})

    return lat.fleet_copy(work / f"robots-large-{port}.yaml", CONFIG, port=port, ws_port=0, edit=add_rules)


def start_broker(stack: ExitStack, work: Path, env: dict[str, str], kind: str) -> tuple[int, Path, int] | None:
    """(port, fleet file, broker pid) of a fresh broker: the embedded one or the exported Mosquitto."""
    port = lat.free_port()
    fleet = bench_fleet(work, port)
    if kind == "embedded":
        child = lat.start_embedded_broker(stack, fleet, port, work / "embedded.log", env)
        return port, fleet, child.pid
    if lat.mosquitto_exe() is None:
        return None
    mosquitto = lat.Mosquitto.exported(work, fleet, export_dir="mosquitto")
    stack.callback(mosquitto.stop)
    mosquitto.start()
    return port, fleet, mosquitto.pid


# -- rows -------------------------------------------------------------------------------------------
@dataclass
class Row:
    path: str  # "direct ROS", "embedded", "mosquitto"
    stream: str
    encoding: str  # "cdr" for direct rows, "twist" / "twist+image" for command rows
    seconds: float = 0.0
    published: int = 0
    received: int = 0
    sizes: list[int] = field(default_factory=list)
    latencies: list[float] = field(default_factory=list)  # ms
    bridge_cpu: float = float("nan")  # % of one core
    broker_cpu: float = float("nan")
    note: str = ""

    def pct(self, q: int) -> float:
        if len(self.latencies) < 2:
            return self.latencies[0] if self.latencies else float("nan")
        return statistics.quantiles(self.latencies, n=100, method="inclusive")[q - 1]


class Receipts:
    """Indices received, with time and size; filled from paho's or rclpy's thread."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: dict[int, tuple[float, int]] = {}
        self.any = threading.Event()

    def add(self, index: int | None, at: float, size: int) -> None:
        if index is None:
            return
        with self.lock:
            self.items.setdefault(index, (at, size))
        self.any.set()


class Publisher:
    """Publishes one stream at its rate from a thread, remembering each index's send time."""

    def __init__(self, pub: Any, frames: Frames, stream: Stream) -> None:
        self.pub, self.frames, self.stream = pub, frames, stream
        self.sent: dict[int, float] = {}
        self.next_index = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"large-pub-{self.stream.name}")
        self._thread.start()

    def _run(self) -> None:
        period, start, k = 1.0 / self.stream.rate, time.monotonic(), 0
        while not self._stop.is_set():
            delay = start + k * period - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                break
            index = self.next_index
            msg = self.frames.stamp(self.stream.name, index)
            self.sent[index] = time.monotonic()
            self.pub.publish(msg)
            self.next_index += 1
            k += 1
            if delay < -1.0:  # more than a second behind (a slow publish): restart the schedule, do not burst
                start, k = time.monotonic(), 0

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)


class RosSide:
    """This process's rclpy node: large-message publishers, the cmd_vel subscriber of the twist rows."""

    def __init__(self) -> None:
        import rclpy
        from geometry_msgs.msg import Twist
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from roslink_mqtt.bridge.core.ros_types import load_interface

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self._rclpy = rclpy
        self.node = rclpy.create_node("large_bench")
        self.frames = Frames()
        self.pubs = {s.name: self.node.create_publisher(load_interface(s.ros_type), ROS_TOPIC.format(stream=s.name), 10)
                     for s in STREAMS.values()}
        self.direct_pubs = {s.name: self.node.create_publisher(load_interface(s.ros_type),
                                                               DIRECT_TOPIC.format(stream=s.name), 10)
                            for s in STREAMS.values()}
        self.cmd: lat.Case | None = None
        self.node.create_subscription(Twist, lat.fleet_facts(CONFIG).cmd_topic, self._on_twist, 50)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True, name="large-ros")
        self.thread.start()

    def _on_twist(self, msg: Any) -> None:
        received = time.monotonic()
        marker = round(msg.linear.x / lat.MARKER_STEP)
        if marker and self.cmd is not None:
            self.cmd.got_marker(marker, received)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2)
        self.thread.join(timeout=2)
        self.node.destroy_node()
        self._rclpy.try_shutdown()


def window(publisher: Publisher, receipts: Receipts, seconds: float, pids: tuple[int | None, int | None],
           row: Row, refresh: Callable[[], None] = lambda: None) -> Row:
    """Publish for ``seconds`` (the stream already runs), then fill ``row`` from what arrived.

    ``refresh`` updates ``receipts`` from elsewhere (the direct rows' child process) before each look.
    """
    first = publisher.next_index
    c0 = [cpu_seconds(p) for p in pids]
    t0 = time.monotonic()
    time.sleep(seconds)
    last = publisher.next_index
    t1 = time.monotonic()
    c1 = [cpu_seconds(p) for p in pids]

    def complete() -> bool:
        refresh()
        with receipts.lock:
            return all(i in receipts.items for i in range(first, last))

    lat.wait_until(complete, SETTLE, 0.05)
    refresh()
    with receipts.lock:
        got = {i: v for i, v in receipts.items.items() if first <= i < last}
    row.seconds, row.published, row.received = t1 - t0, last - first, len(got)
    row.sizes = [size for _at, size in got.values()]
    row.latencies = sorted((at - publisher.sent[i]) * 1000 for i, (at, _size) in got.items())
    row.bridge_cpu, row.broker_cpu = (100 * (b - a) / (t1 - t0) for a, b in zip(c0, c1, strict=True))
    return row


def connect_viewer(stack: ExitStack, port: int, topic: str, on_message: Callable[..., None], name: str) -> Any:
    """A paho subscriber (bob, a viewer) on ``topic``; messages handled on its network thread."""
    from roslink_mqtt.mqtt import make_client

    client = make_client(f"bob-large-{name}-{os.getpid()}", username="bob", password="bob-demo",
                         url=f"mqtt://127.0.0.1:{port}")
    subscribed = threading.Event()
    client.on_subscribe = lambda *_a: subscribed.set()
    client.on_message = on_message
    client.connect("127.0.0.1", port, keepalive=30)
    client.subscribe(topic, qos=0)
    client.loop_start()

    def stop() -> None:
        client.disconnect()
        client.loop_stop()

    stack.callback(stop)
    if not subscribed.wait(10):
        raise SystemExit(f"large bench: no SUBACK for {topic}")
    return client


def stream_row(ros: RosSide, port: int, fleet: Path, pids: tuple[int | None, int | None], path: str,
               stream: Stream, encoding: str, seconds: float) -> Row:
    """One (stream, encoding) row through the bridge on one broker."""
    topic = lat.TopicTree(lat.load_fleet(fleet).prefix).state(ROBOT, rule_name(stream.name, encoding))
    receipts = Receipts()
    row = Row(path, stream.name, encoding)

    def on_message(_c: Any, _u: Any, message: Any) -> None:
        at = time.monotonic()
        receipts.add(index_of(message.payload, encoding), at, len(message.payload))

    publisher = Publisher(ros.pubs[stream.name], ros.frames, stream)
    with ExitStack() as phase:
        connect_viewer(phase, port, topic, on_message, f"{stream.name}-{encoding}")
        publisher.start()
        phase.callback(publisher.stop)
        if not receipts.any.wait(max(PRIME_SECONDS, 3 / stream.rate)):
            row.note = f"nothing arrived in {max(PRIME_SECONDS, 3 / stream.rate):g} s of priming"
        window(publisher, receipts, seconds, pids, row)
    return row


def twist_row(ros: RosSide, port: int, bridge_log: Path, pids: tuple[int | None, int | None], path: str,
              seconds: float, with_images: Stream | None) -> Row:
    """Twist command latency (bench/latency.py's path) at 20 Hz, idle or while the image stream flows."""
    count = max(20, int(seconds * TWIST_RATE))
    case = lat.Case(count)
    label = "twist + 30 Hz image" if with_images else "twist (idle)"
    row = Row(path, "cmd", label)
    with ExitStack() as phase:
        images = Receipts()
        publisher = None
        if with_images is not None:
            fleet_prefix = lat.load_fleet(lat.CONFIG).prefix
            topic = lat.TopicTree(fleet_prefix).state(ROBOT, rule_name(with_images.name, "raw"))
            connect_viewer(phase, port, topic, lambda _c, _u, m: images.add(index_of(m.payload, "raw"),
                                                                           time.monotonic(), len(m.payload)), "twist")
            publisher = Publisher(ros.pubs[with_images.name], ros.frames, with_images)
            publisher.start()
            phase.callback(publisher.stop)
            images.any.wait(PRIME_SECONDS)
        operator = phase.enter_context(lat.RobotClient(*lat.OPERATOR, url=f"mqtt://127.0.0.1:{port}", robots=[ROBOT]))
        lat.wait_online(operator, bridge_log)
        ros.cmd = case
        try:
            send = lat.twist_sender(operator, case)
            nxt = lat.pace(0, int(PRIME_SECONDS * TWIST_RATE), TWIST_RATE, send, lambda _i: None,
                           done=lambda: bool(case.samples))
            if not case.samples:
                row.note = "no twist reached cmd_vel"
                return row
            case.first = nxt + lat.WARMUP
            first_image = publisher.next_index if publisher else 0
            c0, t0 = [cpu_seconds(p) for p in pids], time.monotonic()
            lat.pace(nxt, lat.WARMUP + count, TWIST_RATE, send, lambda _i: None)
            t1, c1 = time.monotonic(), [cpu_seconds(p) for p in pids]
            operator.twist(ROBOT)
            lat.settle([case], SETTLE)
            if publisher is not None:
                last_image = publisher.next_index
                with images.lock:
                    delivered = sum(1 for i in images.items if first_image <= i < last_image)
                row.note = f"images meanwhile: {delivered}/{last_image - first_image} delivered"
        finally:
            ros.cmd = None
    samples = case.measured()
    # the paced span includes the warm-up commands: rates are over the measured commands' share of it
    row.seconds, row.published, row.received = (t1 - t0) * count / (lat.WARMUP + count), count, len(samples)
    row.latencies = sorted((r - s) * 1000 for _i, s, r in samples)
    row.bridge_cpu, row.broker_cpu = (100 * (b - a) / (t1 - t0) for a, b in zip(c0, c1, strict=True))
    return row


def broker_rows(ros: RosSide, work: Path, env: dict[str, str], kind: str, seconds: float) -> list[Row]:
    """Every bridge row on one broker: twist idle, the image encodings, twist under images, cloud, map."""
    rows: list[Row] = []
    with ExitStack() as stack:
        started = start_broker(stack, work, env, kind)
        if started is None:
            return [Row(kind, "-", "-", note="mosquitto not installed: skipped")]
        port, fleet, broker_pid = started
        bridge_log = work / f"bridge-{kind}.log"
        bridge = lat.start_child(stack, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet),
                                         "--robot", ROBOT, "--url", f"mqtt://127.0.0.1:{port}", "--log-level",
                                         "WARNING"], bridge_log, {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD})
        pids = (bridge.pid, broker_pid)
        with lat.RobotClient(*lat.VIEWER, url=f"mqtt://127.0.0.1:{port}", robots=[ROBOT]) as check:
            lat.wait_online(check, bridge_log)
        image, cloud, grid = STREAMS["image"], STREAMS["cloud"], STREAMS["map"]
        plan: list[Callable[[], Row]] = [
            lambda: twist_row(ros, port, bridge_log, pids, kind, seconds, None),
            *[lambda e=e: stream_row(ros, port, fleet, pids, kind, image, e, seconds) for e in image.encodings],
            lambda: twist_row(ros, port, bridge_log, pids, kind, seconds, image),
            *[lambda e=e: stream_row(ros, port, fleet, pids, kind, cloud, e, seconds) for e in cloud.encodings],
            *[lambda e=e: stream_row(ros, port, fleet, pids, kind, grid, e, max(seconds, 5 / grid.rate))
              for e in grid.encodings],  # json last: over max_payload
        ]
        for step in plan:
            rows.append(step())
            print(f"  {fmt(rows[-1])}", flush=True)
            if bridge.poll() is not None:
                rows[-1].note += f" (bridge exited: {lat.tail(bridge_log)})"
                break
        log = bridge_log.read_text(errors="replace")
        disconnects = log.count("disconnected") + log.count("lost the broker") + log.count("connection lost")
        if disconnects:
            rows[-1].note += f"; bridge log: {disconnects} disconnect line(s)"
        rows[-1].note = rows[-1].note.lstrip("; ")
    return rows


# -- direct ROS -------------------------------------------------------------------------------------
def ros_receiver(stream: str, seconds: float, out: Path) -> int:
    """Hidden ``--ros-receiver``: an rclpy subscriber of one direct topic, writing "index time size" lines."""
    import rclpy
    from rclpy.serialization import serialize_message
    from rclpy.signals import SignalHandlerOptions

    from roslink_mqtt.bridge.core.ros_types import load_interface

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("large_bench_receiver")
    spec = STREAMS[stream]
    size: list[int] = []
    with out.open("w", buffering=1) as f:
        def on(msg: Any) -> None:
            at = time.monotonic()
            if not size:
                size.append(len(serialize_message(msg)))
            fid = msg.header.frame_id
            if fid.isdigit():
                f.write(f"{int(fid)} {at:.6f} {size[0]}\n")

        node.create_subscription(load_interface(spec.ros_type), DIRECT_TOPIC.format(stream=stream), on, 10)
        deadline = time.monotonic() + seconds
        try:
            while time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    return 0


def direct_row(ros: RosSide, work: Path, env: dict[str, str], stream: Stream, seconds: float) -> Row:
    """The same messages, rclpy publisher here -> rclpy subscriber in a child process."""
    out = work / f"direct-{stream.name}.txt"
    row = Row("direct ROS", stream.name, "cdr")
    pub = ros.direct_pubs[stream.name]
    publisher = Publisher(pub, ros.frames, stream)
    budget = PRIME_SECONDS + seconds + SETTLE + 10
    with ExitStack() as phase:
        child = lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--ros-receiver", stream.name,
                                        "--seconds", str(budget), "--out", str(out)],
                                work / f"direct-{stream.name}.log", env)
        if not lat.wait_until(lambda: pub.get_subscription_count() > 0, PRIME_SECONDS):
            row.note = "the receiver never matched"
            return row
        publisher.start()
        phase.callback(publisher.stop)
        time.sleep(max(1.0, 2 / stream.rate))  # warm-up: discovery of the data path, first fragments
        receipts = Receipts()

        def poll() -> None:
            for line in out.read_text().splitlines():
                parts = line.split()
                if len(parts) == 3:
                    receipts.add(int(parts[0]), float(parts[1]), int(parts[2]))

        window(publisher, receipts, max(seconds, 5 / stream.rate), (child.pid, None), row, poll)
    row.bridge_cpu = float("nan")  # the receiver's CPU is not the bridge's; not reported
    return row


# -- report -----------------------------------------------------------------------------------------
def fmt(row: Row) -> str:
    if not row.published and not row.received:
        return f"{row.path:<11} {row.stream:<6} {row.encoding:<20} {row.note}"
    size = f"{statistics.median(row.sizes):>11,.0f}" if row.sizes else f"{'—':>11}"
    rate_pub = row.published / row.seconds if row.seconds else float("nan")
    rate_got = row.received / row.seconds if row.seconds else float("nan")

    def num(v: float, w: int = 7, d: int = 1) -> str:
        return f"{'—':>{w}}" if v != v else f"{v:>{w}.{d}f}"

    return (f"{row.path:<11} {row.stream:<6} {row.encoding:<20} {size} {rate_pub:>7.1f} {rate_got:>7.1f} "
            f"{num(row.pct(50), 8)} {num(row.pct(99), 8)} {num(row.bridge_cpu)} {num(row.broker_cpu)}  {row.note}")


def header() -> str:
    return (f"{'path':<11} {'stream':<6} {'encoding':<20} {'bytes/msg':>11} {'pub/s':>7} {'recv/s':>7} "
            f"{'p50 ms':>8} {'p99 ms':>8} {'bridge%':>7} {'broker%':>7}  note")


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = [r for r in rows if r.stream in STREAMS and r.published]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    labels = [f"{r.stream} {r.encoding}\n{r.path.replace('direct ROS', 'direct')}" for r in data]
    xs = list(range(len(data)))
    sizes = [statistics.median(r.sizes) / 1e6 if r.sizes else 0 for r in data]
    delivered = [100 * r.received / r.published for r in data]
    colours = {"direct ROS": "tab:gray", "embedded": "tab:blue", "mosquitto": "tab:orange"}
    ax1.bar(xs, delivered, color=[colours.get(r.path, "tab:green") for r in data])
    for x, s in zip(xs, sizes, strict=True):
        ax1.text(x, 2, f"{s:.2f} MB", rotation=90, ha="center", va="bottom", fontsize=7, color="white")
    ax1.set_xticks(xs, labels, rotation=90, fontsize=7)
    ax1.set_ylabel("% of published frames delivered")
    ax1.set_ylim(0, 110)
    ax1.set_title("Delivered (bar label: bytes per message)")
    p50 = [r.pct(50) if r.latencies else 0 for r in data]
    p99 = [r.pct(99) if r.latencies else 0 for r in data]
    ax2.bar([x - 0.2 for x in xs], p50, width=0.4, label="p50")
    ax2.bar([x + 0.2 for x in xs], p99, width=0.4, label="p99")
    ax2.set_yscale("log")
    ax2.set_xticks(xs, labels, rotation=90, fontsize=7)
    ax2.set_ylabel("latency, ms (log)")
    ax2.set_title("publish() → subscriber callback")
    ax2.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=4.0, help="measurement window per row (maps: at least 5 s)")
    p.add_argument("--quick", action="store_true", help="4 s windows (a smoke run, noisier numbers)")
    p.add_argument("--brokers", default="embedded,mosquitto", help="comma-separated: embedded, mosquitto")
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="where to write the chart (default: %(default)s)")
    p.add_argument("--logs", type=Path, help="keep the fleet copies and every process's log in this directory")
    p.add_argument("--ros-receiver", help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.ros_receiver:
        return ros_receiver(args.ros_receiver, args.seconds, args.out)
    seconds = 4.0 if args.quick else args.seconds
    began = time.monotonic()

    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children inherit the same domain
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    os.environ["ROS_LOG_DIR"] = env["ROS_LOG_DIR"]
    rows: list[Row] = []
    print(header(), flush=True)
    try:
        with ExitStack() as stack:
            if args.logs:
                args.logs.mkdir(parents=True, exist_ok=True)
            work = args.logs or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="roslink-large-")))
            ros = RosSide()
            stack.callback(ros.close)
            print(f"  (JPEG: {ros.frames.jpeg_size:,} bytes)", flush=True)
            for stream in STREAMS.values():
                rows.append(direct_row(ros, work, env, stream, seconds))
                print(f"  {fmt(rows[-1])}", flush=True)
            for kind in [b.strip() for b in args.brokers.split(",") if b.strip()]:
                rows.extend(broker_rows(ros, work, env, kind, seconds))
    except KeyboardInterrupt:
        print("large bench: interrupted", file=sys.stderr)
        return 130
    except (lat.ChildExited, TimeoutError) as e:
        raise SystemExit(f"large bench: {e}") from None
    print(f"\nLarge messages through the bridge, loopback, {os.cpu_count()} cores, {seconds:g} s windows "
          f"(maps ≥ 5 s); bytes = MQTT payload (direct: CDR); latency = publish() -> subscriber callback; "
          f"CPU = % of one core over the window.\n{lat.versions()}\n")
    print(header())
    print("-" * len(header()))
    for row in rows:
        print(fmt(row))
    plot(rows, args.plot)
    print(f"\nplot: {args.plot}\nrun took {time.monotonic() - began:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
