"""Benchmark: the sim's camera as video across thin links, next to today's JPEG path, with the robot's telemetry on.

    .venv/bin/python bench/video.py [--seconds 20] [--rates 0,1000,256] [--models visible,hidden] [--fall]
        [--modes video,jpeg] [--viewers 10] [--keep-logs DIR]

turtle1 (the demo fleet: its ``video:`` camera, 640×480 at 30 Hz from the simulator) reaches the embedded broker
through ``roslink_mqtt.shaped_link`` as in bench/weak_link.py: 40 ms each way, an uplink of the row's rate (0: no
link, loopback), the downlink four times faster, on both link models (``visible``: a modem whose queue backs up
into the robot's socket; ``hidden``: a hop that acknowledges at once). ``--fall``: a row whose uplink falls from
1 Mbit/s to 256 kbit/s after CHANGE_AT s.

* ``video`` rows: bob watches ``camera`` with the SDK (``RobotClient.video``) and decodes every frame with PyAV.
* ``jpeg`` rows: today's path: a 30 Hz 640×480 JPEG (``CompressedImage``, a ``raw`` rule at bulk priority, what
  bench/weak_link.py's camera rows send) published by a child here.

Per row: frames/s bob received (and decoded), the size, kbit/s received, frame age (arrival − the capture stamp:
one clock, every process runs here) p50/p95, time to the first picture after the watch began, the bridge's CPU
(% of one core, encoding included), and in the same row the telemetry's global_motion age p99, the largest
heartbeat gap and alice's emergency stop → the bridge's acknowledgement (slowest). The fall row adds the time from
the fall until a picture comes again, until the pictures are fresh (the p95 of the ages from there to the row's
end under FRESH: the issue's "fresh") and until every picture after is. ``--viewers N``: a
loopback row where N viewers watch at once; the robot's uplink bytes for the camera (its state/link report) beside
one viewer's. Never asserts: a table (and a plot in docs/performance/video.png). ``--keep-logs DIR`` copies the
broker's, bridges' and links' logs there; with ``WEAK_BRIDGE_LOG=DEBUG`` they hold the uplink's windows (rates,
pacing, what each lane holds) and the stream's counters (pictures, encoded, skipped for want of room).
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
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: versions)
import weak_link as wl  # (bench/weak_link.py: the shaped link, the viewer of telemetry, the e-stop watch)
from _support import cpu_seconds

from roslink_mqtt.protocol.video import VideoFrame
from roslink_mqtt.topics import state_leaf

ROOT = Path(__file__).resolve().parents[1]
PLOT = ROOT / "docs" / "performance" / "video.png"
STREAM = "front_camera"  # the demo fleet's video stream of turtle1
CHANGE_AT = 16.0  # s after the link starts: the fall row's fall
AFTER_CHANGE = 10.0
FRESH = 0.4  # s: a picture this young is fresh
JPEG_TOPIC = wl.IMAGE_TOPIC


@dataclass
class Row:
    label: str
    mode: str
    seconds: float = 0.0
    frames: list[tuple[float, float, int, str, bool]] = field(default_factory=list)  # arrival, age, bytes, size, key
    decoded: int = 0
    first_picture: float | None = None  # s from the watch to the first decoded picture
    cpu: float = float("nan")  # the bridge's CPU, % of one core
    telemetry: Any = None  # weak_link's Run: motion ages, heartbeats, stops
    fall_at: float | None = None
    viewers: int = 1
    uplink_kbit: float | None = None  # the camera stream's kbit/s in the bridge's state/link report
    note: str = ""


class Watcher:
    """bob's video subscription: records every frame of the row and decodes it."""

    def __init__(self, client: Any, row: Row) -> None:
        from roslink_mqtt.video.decoder import VideoDecoder

        self.row, self.decoder = row, VideoDecoder()
        self.began = time.monotonic()
        self.sub = client.video(wl.ROBOT, STREAM, self._on_frame)

    def _on_frame(self, frame: VideoFrame) -> None:
        now = time.monotonic()
        age = time.time() - frame.stamp
        self.row.frames.append((now, age, len(frame.data), f"{frame.width}×{frame.height}", frame.key))
        if self.decoder.decode(frame) is not None:
            self.row.decoded += 1
            if self.row.first_picture is None:
                self.row.first_picture = now - self.began

    def close(self) -> None:
        self.sub.close()


def jpeg_load() -> int:
    """Hidden ``--jpeg-load`` mode: the 30 Hz JPEG of bench/weak_link.py's camera rows, until SIGINT."""
    import large
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import CompressedImage

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("video_bench_jpeg")
    frames = large.Frames()
    pub = node.create_publisher(CompressedImage, JPEG_TOPIC, 5)
    start, period, n = time.monotonic(), 1.0 / wl.IMAGE_RATE, 0
    while not stop.wait(max(0.0, start + n * period - time.monotonic())):
        pub.publish(frames.stamp("image", wl.stamp_index()))
        n += 1
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def fleet_for(work: Path, port: int, mode: str) -> Path:
    """The demo fleet with its camera as video (``video`` rows) or as a raw JPEG rule (``jpeg`` rows)."""
    def edit(data: dict[str, Any]) -> None:
        robot = data["robots"][wl.ROBOT]
        if mode == "jpeg":
            robot.pop("video", None)
            robot["rules"] = [*robot["rules"], {"direction": "ros_to_mqtt", "ros_topic": JPEG_TOPIC,
                                                "ros_type": "sensor_msgs/msg/CompressedImage",
                                                "mqtt_topic": state_leaf(wl.IMAGE_STATE), "encoding": "raw"}]
        data["broker"]["max_payload"] = 16 << 20

    return lat.fleet_copy(work / f"robots-{mode}.yaml", wl.CONFIG, port=port, ws_port=0, edit=edit)


def link_args(kbit: int, fall: bool) -> list[str]:
    if fall:
        return ["--phases", f"{CHANGE_AT:g}:1024,600:256", "--down-kbit", "1024", "--phases-once"]
    return ["--jitter-ms", "0", "--up-kbit", str(kbit), "--down-kbit", str(kbit * wl.DOWN_FACTOR)]


def one_row(row: Row, kbit: int, hidden: bool, fall: bool, seconds: float, work: Path, env: dict[str, str],
            port: int, viewer: Any, current: list[Any], watch: Any) -> Row:
    from roslink_mqtt.client import RobotClient

    with ExitStack() as phase:
        fleet = fleet_for(work, port, row.mode)
        url_port = port
        link_up = time.monotonic()
        if kbit or fall:
            url_port = lat.free_port()
            lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.shaped_link", "--listen",
                                    f"127.0.0.1:{url_port}", "--to", f"127.0.0.1:{port}", "--delay-ms",
                                    str(wl.DELAY_MS), *link_args(kbit, fall), *(["--hidden-queue"] if hidden else [])],
                            work / f"link-{url_port}.log", env, port=url_port, what="shaped link")
            link_up = time.monotonic()
        if row.mode == "jpeg":
            lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--jpeg-load"],
                            work / f"jpeg-{url_port}.log", env)
        viewer.online.clear()
        bridge_log = work / f"bridge-{row.mode}-{url_port}.log"
        bridge = lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet),
                                         "--robot", wl.ROBOT, "--url", f"mqtt://127.0.0.1:{url_port}",
                                         "--log-level", wl.BRIDGE_LOG_LEVEL],
                                 bridge_log, {**env, "ROSLINK_PASSWORD": wl.ROBOT_PASSWORD})
        if not viewer.online.wait(30):
            row.note = f"the robot did not come online: {lat.tail(bridge_log, 5)}"
            return row
        time.sleep(wl.WARMUP)
        run = wl.Run(wl.Case(kbit, row.mode == "jpeg", hidden), row.mode)
        viewer.run = current[0] = row.telemetry = run
        logins = (wl.VIEWER, wl.OPERATOR, ("admin", "admin-demo"))  # (a user watches from 8 clients at most)
        clients = [RobotClient(*logins[i % len(logins)], client_id=f"video-{i}-{os.getpid()}",
                               url=f"mqtt://127.0.0.1:{port}").connect() for i in range(row.viewers)]
        for client in clients:
            phase.callback(client.close)
            client.wait_for_robot(wl.ROBOT)
        began = time.monotonic()
        cpu0 = cpu_seconds(bridge.proc.pid)
        watchers = [Watcher(client, row) for client in clients[:1]] if row.mode == "video" else []
        extra = [client.video(wl.ROBOT, STREAM) for client in clients[1:]] if row.mode == "video" else []
        if fall:
            seconds = max(seconds, link_up + CHANGE_AT + AFTER_CHANGE - began)
            row.fall_at = link_up + CHANGE_AT if row.mode == "video" else None  # JPEG rows: ages only
        time.sleep(seconds)
        row.seconds = time.monotonic() - began
        row.cpu = 100 * (cpu_seconds(bridge.proc.pid) - cpu0) / row.seconds
        viewer.run = current[0] = None
        report = run.link
        if report is not None and STREAM in report.streams:
            row.uplink_kbit = report.streams[STREAM].kbit_s
        for w in watchers:
            w.close()
        for sub in extra:
            sub.close()
        if row.mode == "jpeg":
            row.frames = [(0.0, age, 0, "640×480", True) for age in run.ages.get(wl.IMAGE_STATE, [])]
            row.decoded = len(row.frames)
    return row


def pct(values: list[float], q: float) -> float:
    return wl.pct(values, q)


def _seconds(value: float | None) -> str:
    return "never" if value is None else f"{value:.1f} s"


def fresh_from(ages: list[float]) -> int | None:
    """The first picture from which the ages are fresh as the issue means it: the 95th percentile of the pictures
    from there to the row's end is under FRESH (None: never)."""
    return next((i for i in range(len(ages)) if pct(ages[i:], 0.95) < FRESH), None)


def fall_cells(row: Row) -> str:
    """The fall row: the longest wait for a picture after the fall, when the pictures are fresh (p95 < FRESH) from
    then on, and when every one is."""
    if row.fall_at is None:
        return ""
    after = [(at, age) for at, age, *_ in row.frames if at >= row.fall_at]
    arrivals = [row.fall_at] + [at for at, _ in after]
    gap = max((b - a for a, b in zip(arrivals, arrivals[1:], strict=False)), default=None)
    stale = [i for i, (_, age) in enumerate(after) if age >= FRESH]
    every = None if not after or (stale and stale[-1] == len(after) - 1) else \
        after[stale[-1] + 1 if stale else 0][0] - row.fall_at
    first = fresh_from([age for _, age in after])
    p95 = None if first is None else after[first][0] - row.fall_at
    return (f"; after the fall: longest wait for a picture {_seconds(gap)}, fresh (p95 < {FRESH * 1000:.0f} ms) "
            f"from {_seconds(p95)}, every picture from {_seconds(every)}")


def line(row: Row) -> str:
    frames, secs = row.frames, max(row.seconds, 1e-9)
    ages = [age for _, age, *_ in frames]
    sizes = sorted({size for *_, size, _key in frames})
    kbit = sum(b for _, _, b, _, _ in frames) * 8 / 1000 / secs
    run = row.telemetry
    motion = run.ages.get("global_motion", []) if run is not None else []
    first = "-" if row.first_picture is None else f"{row.first_picture:.2f} s"
    cpu = "-" if row.cpu != row.cpu else f"{row.cpu:.0f} %"
    estop = wl.stop_cell(run.stop_acks) if run is not None else "-"
    return (f"{row.label:<26} {row.mode:<5} {row.decoded / secs:5.1f} fps {', '.join(sizes) or '-':<16} "
            f"{kbit:6.0f} kbit/s  age {pct(ages, 0.5) * 1000:5.0f}/{pct(ages, 0.95) * 1000:5.0f} ms  first {first:>7}"
            f"  cpu {cpu:>5}  motion p99 {pct(motion, 0.99) * 1000:5.0f} ms  hb gap "
            f"{wl.heartbeat_gap(run) if run is not None else float('nan'):.2f} s  e-stop→ack {estop}"
            + (f"  uplink {row.uplink_kbit:.0f} kbit/s ×{row.viewers} viewers" if row.viewers > 1 and
               row.uplink_kbit is not None else "")
            + fall_cells(row) + (f"  [{row.note}]" if row.note else ""))


def plot(rows: list[Row], path: Path) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    shown = [r for r in rows if r.frames]
    if not shown:
        return None
    fig, ax = plt.subplots(figsize=(10, 4.5))
    ax.boxplot([[age * 1000 for _, age, *_ in r.frames] for r in shown], showfliers=False)
    ax.set_xticks(range(1, len(shown) + 1), [f"{r.label}\n{r.mode}" for r in shown], fontsize=7, rotation=30)
    ax.set_ylabel("frame age at the viewer, ms")
    ax.set_yscale("log")
    ax.set_title("turtle1's camera: video next to JPEG, per link")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0, help="measured per row (default: %(default)s)")
    p.add_argument("--rates", default="0,1000,256", help="uplink kbit/s per row, 0: loopback (default: %(default)s)")
    p.add_argument("--models", default="visible,hidden", help="link models (default: %(default)s)")
    p.add_argument("--modes", default="video,jpeg", help="video and/or jpeg (default: %(default)s)")
    p.add_argument("--fall", action=argparse.BooleanOptionalAction, default=True,
                   help="a row whose uplink falls from 1 Mbit/s to 256 kbit/s (default: on)")
    p.add_argument("--viewers", type=int, default=10, help="a loopback row with this many viewers (0: none)")
    p.add_argument("--plot", type=Path, default=PLOT)
    p.add_argument("--keep-logs", type=Path, help="copy the broker's, bridges' and links' logs here")
    p.add_argument("--jpeg-load", action="store_true", help=argparse.SUPPRESS)
    return p.parse_args(argv)


def rows_of(args: argparse.Namespace) -> list[tuple[Row, int, bool, bool]]:
    modes = [m for m in args.modes.split(",") if m]
    models = [m for m in args.models.split(",") if m]
    out: list[tuple[Row, int, bool, bool]] = []
    for kbit in (int(r) for r in args.rates.split(",") if r.strip()):
        for model in (["visible"] if kbit == 0 else models):
            label = "loopback" if kbit == 0 else f"{kbit} kbit/s {model}"
            out += [(Row(label, mode), kbit, model == "hidden", False) for mode in modes]
    if args.fall:
        for model in models:
            out += [(Row(f"1000 → 256 kbit/s {model}", mode), 1000, model == "hidden", True) for mode in modes]
    if args.viewers > 1 and "video" in modes:
        out += [(Row("loopback, one viewer", "video"), 0, False, False),
                (Row(f"loopback, {args.viewers} viewers", "video", viewers=args.viewers), 0, False, False)]
    return out


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.jpeg_load:
        return jpeg_load()
    began = time.monotonic()
    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    os.environ["ROS_LOG_DIR"] = env["ROS_LOG_DIR"]
    from roslink_mqtt.client import RobotClient

    rows: list[Row] = []
    current: list[Any] = [None]
    stop = threading.Event()
    with tempfile.TemporaryDirectory(prefix="roslink-video-") as tmp, ExitStack() as stack:
        work = Path(tmp)
        if args.keep_logs is not None:  # (callbacks run last first: once the children have stopped and written all)
            stack.callback(shutil.copytree, work, args.keep_logs, dirs_exist_ok=True)
        port = lat.free_port()
        lat.start_embedded_broker(stack, fleet_for(work, port, "video"), port, work / "broker.log", env,
                                  log_level=wl.BROKER_LOG_LEVEL)
        lat.start_child(stack, [sys.executable, "-m", "roslink_mqtt.sim"], work / "sim.log", env)
        viewer = wl.Viewer(port, lat.load_fleet(fleet_for(work, port, "video")).prefix)
        stack.callback(viewer.close)
        operator = RobotClient(*wl.OPERATOR, url=f"mqtt://127.0.0.1:{port}").connect()
        stack.callback(operator.close)
        watch = wl.StopWatch()
        stack.callback(watch.close)
        stops = threading.Thread(target=wl.stopper, args=(operator, watch, stop, current), daemon=True)
        stops.start()
        stack.callback(stop.set)
        try:
            for row, kbit, hidden, fall in rows_of(args):
                one_row(row, kbit, hidden, fall, args.seconds, work, env, port, viewer, current, watch)
                rows.append(row)
                print(line(row), flush=True)
        except KeyboardInterrupt:
            return 130
    print()
    for row in rows:
        print(line(row))
    written = plot(rows, args.plot)
    if written is not None:
        print(f"plot: {written}")
    print(f"{lat.versions()}; {wl.DELAY_MS} ms each way, downlink {wl.DOWN_FACTOR}× the uplink; run took "
          f"{time.monotonic() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
