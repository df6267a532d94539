"""Benchmark: how fast ``roslink-mqtt record`` keeps up, side by side with a subscriber that only counts.

    .venv/bin/python bench/record.py [--rates 1000,3000,6000] [--seconds 3] [--plot PATH] [--quick]

One embedded broker (Mosquitto-compatible, loopback) and a publisher process logged in as turtle1 sending
``state/global_motion`` envelopes at each rate for a window. For each rate two windows run, one after the other:

* **reference**: a paho subscriber as bob (a viewer) that only counts what arrives;
* **record**: the recorder (client/recorder.py) as bob, writing an MCAP file with its schemas, zstd chunks.

The table gives, per rate and path, what arrived, what the recorder wrote and dropped (its queue is bounded), the
CPU this process spent per 1,000 messages and the file's bytes per message. Everything shares two cores. Never
asserts on timing.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

from _support import cpu_seconds

from roslink_mqtt.client.recorder import Recorder
from roslink_mqtt.localproc import free_port, start_embedded_broker
from roslink_mqtt.mqtt import make_client
from roslink_mqtt.topics import TopicTree

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
DEFAULT_PLOT = ROOT / "docs" / "performance" / "record.png"
TREE = TopicTree()
TOPIC = TREE.state("turtle1", "global_motion")
GAP = 1.0  # s after a window: what is in flight arrives

PUBLISHER = """
import sys, time, orjson
from roslink_mqtt.mqtt import make_client
port, rate, seconds, topic = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
client = make_client("bench-record-pub", username="turtle1", password="turtle1-demo",
                     url=f"mqtt://127.0.0.1:{port}")
client.connect("127.0.0.1", port)
client.loop_start()
time.sleep(0.3)
body = {"roslink_version": 2, "ros_version": 24, "system_id": 1, "message_id": 2, "sequence_number": 0,
        "payload": {"time_boot_ms": 0, "x": 1.0, "y": 2.0, "z": 0.0, "vx": 0.1, "vy": 0.0, "vz": 0.0, "wx": 0.0,
                    "wy": 0.0, "wz": 0.2, "roll": 0.0, "pitch": 0.0, "yaw": 1.5}}
n, start = int(rate * seconds), time.monotonic()
for i in range(n):
    body["sequence_number"] = i
    body["payload"]["time_boot_ms"] = i
    client.publish(topic, orjson.dumps(body), qos=0)
    delay = start + (i + 1) / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)
time.sleep(0.5)
client.disconnect()
client.loop_stop()
print(n)
"""


@dataclass
class Row:
    rate: int
    path: str
    sent: int
    arrived: int
    written: int
    dropped: int
    cpu_per_1000: float
    bytes_per_message: float


def publish(port: int, rate: int, seconds: float) -> int:
    done = subprocess.run([sys.executable, "-c", PUBLISHER, str(port), str(rate), str(seconds), TOPIC],
                          capture_output=True, text=True, cwd=ROOT, timeout=seconds + 60)
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-2000:])
    return int(done.stdout.strip())


def reference(port: int, rate: int, seconds: float) -> Row:
    count = [0]
    client = make_client("bench-record-ref", username="bob", password="bob-demo", url=f"mqtt://127.0.0.1:{port}")
    client.on_message = lambda *_: count.__setitem__(0, count[0] + 1)
    subscribed = threading.Event()
    client.on_subscribe = lambda *_: subscribed.set()
    client.on_connect = lambda c, *_: c.subscribe(TOPIC, qos=0)
    client.connect("127.0.0.1", port)
    client.loop_start()
    subscribed.wait(5)
    cpu = cpu_seconds(os.getpid())
    sent = publish(port, rate, seconds)
    time.sleep(GAP)
    used = cpu_seconds(os.getpid()) - cpu
    client.disconnect()
    client.loop_stop()
    return Row(rate, "reference", sent, count[0], 0, 0, used / max(count[0], 1) * 1000, 0.0)


def record(port: int, rate: int, seconds: float, out: Path) -> Row:
    recorder = Recorder(url=f"mqtt://127.0.0.1:{port}", username="bob", password="bob-demo", robots=["turtle1"],
                        out=out, topics=["global_motion"])
    recorder.connect()
    stop = threading.Event()
    result: list = []
    writer = threading.Thread(target=lambda: result.append(recorder.run(duration=None, stop=stop)))
    writer.start()
    time.sleep(0.3)
    cpu = cpu_seconds(os.getpid())
    sent = publish(port, rate, seconds)
    time.sleep(GAP)
    stop.set()
    writer.join()
    used = cpu_seconds(os.getpid()) - cpu
    progress = result[0]
    written = progress.per_topic.get(TOPIC, 0)
    return Row(rate, "record", sent, written + progress.dropped, written, progress.dropped,
               used / max(written, 1) * 1000, out.stat().st_size / max(written, 1))


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for name in ("reference", "record"):
        mine = [r for r in rows if r.path == name]
        ax.plot([r.rate for r in mine], [r.cpu_per_1000 * 1000 for r in mine], marker="o", label=name)
    ax.set_xlabel("messages/s published")
    ax.set_ylabel("CPU ms per 1,000 messages")
    ax.set_title("roslink-mqtt record vs a counting subscriber")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rates", default="1000,3000,6000")
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT)
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--quick", action="store_true", help="one 1 s window at 1,000/s (a smoke run)")
    args = p.parse_args()
    rates = [1000] if args.quick else [int(r) for r in args.rates.split(",")]
    if args.quick:
        args.seconds = 1.0
    rows: list[Row] = []
    with ExitStack() as stack, tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        start_embedded_broker(stack, CONFIG, port, Path(tmp) / "broker.log", None, "--limit", "user_publish_rate=0")
        for rate in rates:
            rows.append(reference(port, rate, args.seconds))
            rows.append(record(port, rate, args.seconds, Path(tmp) / f"bench-{rate}.mcap"))
    print(f"{'rate/s':>7} {'path':<10} {'sent':>7} {'arrived':>8} {'written':>8} {'dropped':>8} "
          f"{'CPU ms/1000':>12} {'bytes/msg':>10}")
    for r in rows:
        print(f"{r.rate:>7} {r.path:<10} {r.sent:>7} {r.arrived:>8} {r.written:>8} {r.dropped:>8} "
              f"{r.cpu_per_1000 * 1000:>12.1f} {r.bytes_per_message:>10.1f}")
    if not args.no_plot:
        plot(rows, args.plot)
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
