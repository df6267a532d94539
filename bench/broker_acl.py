"""Benchmark: what the ACL costs the embedded broker, next to Mosquitto running the exported ACL.

    .venv/bin/python bench/broker_acl.py [--messages 10000] [--repeats 3] [--qos 0 1]

One publisher (robot turtle1) sends small JSON state messages to
``roslink/turtle1/state/robot_status``; one subscriber (user alice, granted turtle1) counts
them on ``roslink/turtle1/state/#``. Three brokers run side by side on loopback, all with
the demo fleet's logins:

* embedded, no ACL  -- ``roslink-mqtt-broker --no-acl`` (authentication only; benchmark mode)
* embedded + ACL    -- ``roslink-mqtt-broker`` as deployed (PUBLISH and RECEIVE checked per message)
* mosquitto + ACL   -- Mosquitto with ``roslink-mqtt acl export`` (skipped if not installed)

Runs are interleaved (each repeat visits every broker) so background load hits all alike;
the table shows the best and the median of the repeats. Goal (issue 3): the ACL costs the
embedded broker under 15 % of throughput. Clients are paho (TCP_NODELAY via
``roslink_mqtt.mqtt.make_client``), which bounds what any broker can show here.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path

import orjson
from _support import cpu_seconds

from roslink_mqtt.localproc import LocalProcess, Mosquitto, fleet_copy, free_port, mosquitto_exe, start_embedded_broker
from roslink_mqtt.mqtt import make_client
from roslink_mqtt.topics import TopicTree

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
PASSWORDS = {"turtle1": "turtle1-demo", "alice": "alice-demo"}
TOPICS = TopicTree()
TOPIC = TOPICS.state("turtle1", "robot_status")


def start_embedded(stack: ExitStack, acl: bool, log: Path) -> tuple[LocalProcess, int]:
    port = free_port()
    proc = start_embedded_broker(stack, CONFIG, port, log, dict(os.environ), *([] if acl else ["--no-acl"]))
    return proc, port


def start_mosquitto(stack: ExitStack, workdir: Path, log: Path) -> tuple[LocalProcess, int] | None:
    if mosquitto_exe() is None:
        return None
    # a copy of the fleet because the exported config takes its port from the fleet file
    fleet = fleet_copy(workdir / "robots.yaml", CONFIG, port=free_port(), ws_port=0)
    # The exported config's max_queued_messages (1000) drops QoS>0 messages for a subscriber that falls behind;
    # paho in Python always falls behind Mosquitto, and a benchmark must not lose messages.
    mosquitto = Mosquitto.exported(workdir, fleet, "max_queued_messages 0", export_dir="mosquitto",
                                   conf_name="mosquitto-bench.conf", log_name=log.name)
    stack.callback(mosquitto.stop)
    mosquitto.start()
    return mosquitto, mosquitto.port


def connect(port: int, login: str, client_id: str):
    client = make_client(client_id, username=login, password=PASSWORDS[login], url=f"mqtt://127.0.0.1:{port}")
    client.max_inflight_messages_set(100)
    client.max_queued_messages_set(0)
    ready = threading.Event()
    client.on_connect = lambda c, u, f, rc, p: ready.set() if not rc.is_failure else None
    client.connect("127.0.0.1", port, keepalive=30)
    client.loop_start()
    if not ready.wait(10):
        raise RuntimeError(f"{login} could not connect to port {port}")
    return client


def run_once(port: int, pid: int, messages: int, qos: int, tag: str) -> tuple[float, int, float]:
    """msg/s from the first publish to the last message received, how many arrived, broker CPU s."""
    payload = orjson.dumps({"roslink_version": 2, "ros_version": 24, "system_id": 1, "message_id": 1,
                            "sequence_number": 0, "payload": {"battery": 87.5, "voltage": 12.1, "status": 4}})
    done = threading.Event()
    count = [0]

    def on_message(*_args) -> None:
        count[0] += 1
        if count[0] >= messages:
            done.set()

    sub = connect(port, "alice", f"bench-sub-{tag}")
    sub.on_message = on_message
    subscribed = threading.Event()
    sub.on_subscribe = lambda *a: subscribed.set()
    sub.subscribe(TOPICS.state_filter("turtle1"), qos)
    subscribed.wait(10)
    pub = connect(port, "turtle1", f"bench-pub-{tag}")
    cpu_before = cpu_seconds(pid)
    start = time.monotonic()
    for _ in range(messages):
        pub.publish(TOPIC, payload, qos=qos)
    done.wait(max(30.0, messages / 500))  # bounded: a broker that loses messages cannot hang the bench
    elapsed = time.monotonic() - start
    cpu = cpu_seconds(pid) - cpu_before
    for client in (pub, sub):
        client.disconnect()
        client.loop_stop()
    return count[0] / elapsed, count[0], cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=10000, help="messages per run (default: %(default)s)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per broker and QoS (default: %(default)s)")
    ap.add_argument("--qos", type=int, nargs="+", default=[0, 1], choices=(0, 1, 2))
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench-broker-") as tmp, ExitStack() as stack:
        workdir = Path(tmp)
        brokers: dict[str, tuple[int, int]] = {}
        for label, starter in (
                ("embedded, no ACL", lambda: start_embedded(stack, False, workdir / "noacl.log")),
                ("embedded + ACL", lambda: start_embedded(stack, True, workdir / "acl.log")),
                ("mosquitto + exported ACL", lambda: start_mosquitto(stack, workdir, workdir / "mosq.log"))):
            started = starter()
            if started is None:
                print(f"({label}: mosquitto not installed, skipped)")
                continue
            proc, port = started
            brokers[label] = (port, proc.pid)

        results: dict[tuple[str, int], list[float]] = {}
        cpu_us: dict[tuple[str, int], list[float]] = {}
        short: list[str] = []
        for qos in args.qos:
            for r in range(args.repeats):
                order = list(brokers.items())
                for label, (port, pid) in order if r % 2 == 0 else order[::-1]:  # no broker always runs first
                    rate, got, cpu = run_once(port, pid, args.messages, qos, f"{qos}-{r}-{port}")
                    results.setdefault((label, qos), []).append(rate)
                    cpu_us.setdefault((label, qos), []).append(cpu / max(got, 1) * 1e6)
                    if got < args.messages:
                        short.append(f"{label} QoS{qos} run {r + 1}: {got}/{args.messages} received")
                    print(f"  QoS{qos} run {r + 1} {label:<26} {rate:>9,.0f} msg/s "
                          f"{cpu_us[(label, qos)][-1]:>6.1f} broker CPU us/msg", flush=True)

    print(f"\n1 publisher -> 1 subscriber, {args.messages} JSON messages of ~150 B per run, {args.repeats} runs "
          "each; msg/s best and median; broker CPU per message (median, from /proc)\n")
    print("| broker | " + " | ".join(f"QoS{q} msg/s best | median | CPU us/msg" for q in args.qos) + " |")
    print("|" + "---|" * (1 + 3 * len(args.qos)))
    for label in brokers:
        cells = []
        for q in args.qos:
            rates = results[(label, q)]
            cells += [f"{max(rates):,.0f}", f"{statistics.median(rates):,.0f}",
                      f"{statistics.median(cpu_us[(label, q)]):.1f}"]
        print(f"| {label} | " + " | ".join(cells) + " |")
    print()
    ok = True
    for q in args.qos:
        base_key, acl_key = ("embedded, no ACL", q), ("embedded + ACL", q)
        if base_key in results and acl_key in results:
            # The broker is CPU-bound, so throughput = 1 / CPU per message: the CPU ratio is the
            # ACL's share of throughput, without the scheduling noise of wall-clock rates on a busy host.
            cost = 1 - statistics.median(cpu_us[base_key]) / statistics.median(cpu_us[acl_key])
            wall = 1 - statistics.median(results[acl_key]) / statistics.median(results[base_key])
            ok &= cost < 0.15
            print(f"ACL cost on the embedded broker, QoS{q}: {cost:+.1%} of throughput (CPU per message), "
                  f"{wall:+.1%} (median msg/s) -- goal < 15 %: {'ok' if cost < 0.15 else 'OVER GOAL'}")
    for line in short:
        print(f"warning: {line}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
