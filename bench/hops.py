"""Benchmark: the legacy paper's Fig. 3 — where the time goes between a program without ROS and a ROS node.

    .venv/bin/python bench/hops.py [--count 1000] [--rate 200] [--brokers embedded,mosquitto] [--quick] [--plot PATH]

Four exchanges, ``--count`` measurements each (after 50 warm-up), every message four 64-bit integers
(``std_msgs/msg/Int64MultiArray``; the services carry ``test_msgs/srv/BasicTypes`` with the index in its
int64 field):

1. an SDK publisher (the rclpy-shaped API, as alice) -> ROS subscriber;
2. a ROS publisher -> SDK subscriber;
3. a ROS node calls a service an SDK node provides;
4. the SDK calls a ROS service.

Each is split into hops with timestamps taken in each process (``time.monotonic_ns()``: one clock for every
process on the machine): the SDK program (a child process), this process (the ROS side), and the bridge
itself, which stamps every message at its four doors when ``ROSLINK_BRIDGE_TRACE`` names a file
(roslink_mqtt/bridge/core/trace.py). A hop "SDK -> bridge" is therefore the SDK's send, its broker and the
bridge's MQTT client; "bridge" is the bridge's own work (parse, authorize, convert, hand to rclpy or paho);
"bridge -> ROS" is DDS and the receiving executor. Topics run at ``--rate``; calls go one at a time.
Runs against the embedded broker and Mosquitto (the exported config). Prints a table per broker and writes
a stacked bar chart of the p50 hops. Never asserts on timing. The embedded broker runs without its per-user
publish pacing (100/s), which these rates exceed on purpose.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: brokers and the process helpers shared by the benches)
import orjson

from roslink_mqtt import ros_names
from roslink_mqtt.bridge.core.trace import ENV as TRACE_ENV
from roslink_mqtt.topics import TopicTree

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ROBOT, ROBOT_PASSWORD, OPERATOR = "turtle1", "turtle1-demo", ("alice", "alice-demo")
DEFAULT_PLOT = ROOT / "docs" / "performance" / "hops.png"
WARMUP = 50
IN_NAME, OUT_NAME = "hops_in", "hops_out"  # generic rules: from/alice/hops_in -> ROS, ROS -> state/hops_out
IN_ROS, OUT_ROS = "/bench_hops/in", "/bench_hops/out"
PROVIDED, ECHO, ECHO_ROS = "hops_provided", "hops_echo", "/bench_hops/echo"
ARRAY, SERVICE = "std_msgs/msg/Int64MultiArray", "test_msgs/srv/BasicTypes"
PACING_NOTE = ("the embedded broker runs with --limit user_publish_rate=0: its flood defence paces a user login to "
               "100 PUBLISH/s, which 200 Hz topics and back-to-back calls exceed (docs/safety.md)")
EXCHANGES = ("SDK publisher -> ROS subscriber", "ROS publisher -> SDK subscriber",
             "ROS client -> SDK-provided service", "SDK client -> ROS service")


# -- the SDK program (a child process; commands on stdin, one per line) ----------------------------------
def sdk_program(url: str) -> int:
    """Hidden ``--sdk`` mode: alice's program without ROS. Commands: ``pub N RATE``, ``calls N``, ``report``."""
    from roslink_mqtt.client import rclpy as sdk

    received: list[tuple[int, int]] = []  # (index, ns) of state/hops_out
    served: list[tuple[int, int]] = []  # (index, ns) the provided service was called
    sent: list[tuple[int, int]] = []  # (index, ns) published on hops_in
    calls: list[tuple[int, int, int]] = []  # (index, ns sent, ns answered) of hops_echo

    def on_out(msg: dict[str, Any]) -> None:
        received.append((int(msg["data"][0]), time.monotonic_ns()))

    def provide(request: dict[str, Any], response: dict[str, Any]) -> dict[str, Any]:
        served.append((int(request["int64_value"]), time.monotonic_ns()))
        return {**response, "int64_value": request["int64_value"]}

    node = sdk.create_node("hops_sdk", robot=ROBOT, url=url, username=OPERATOR[0], password=OPERATOR[1])
    pub = node.create_publisher(ARRAY, IN_NAME, 10)
    node.create_subscription(ARRAY, OUT_NAME, on_out, 10)
    node.create_service(SERVICE, PROVIDED, provide)
    echo = node.create_client(SERVICE, ECHO)
    threading.Thread(target=sdk.spin, args=(node,), daemon=True).start()
    echo.wait_for_service(timeout_sec=20)
    print("ready", flush=True)
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        if words[0] == "pub":
            count, rate = int(words[1]), float(words[2])
            start = time.monotonic()
            for i in range(count):
                if (delay := start + i / rate - time.monotonic()) > 0:
                    time.sleep(delay)
                ns = time.monotonic_ns()
                pub.publish({"data": [i, ns, 0, 0]})
                sent.append((i, ns))
        elif words[0] == "calls":
            for i in range(int(words[1])):
                ns = time.monotonic_ns()
                echo.call({"int64_value": i})
                calls.append((i, ns, time.monotonic_ns()))
        elif words[0] == "report":
            print(orjson.dumps({"received": received, "served": served, "sent": sent, "calls": calls}).decode(),
                  flush=True)
            continue
        elif words[0] == "quit":
            break
        print("done", flush=True)
    node.destroy_node()
    return 0


class SdkProgram:
    """The bench's end of the child's stdin/stdout: one command at a time, every wait bounded."""

    def __init__(self, stack: ExitStack, url: str, env: dict[str, str], log: Path) -> None:
        self.log = log
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--sdk", "--url", url],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log.open("wb"), env=env,
                                     text=True, bufsize=1)
        stack.callback(self._stop)
        self.expect("ready", 40)

    def _stop(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()

    def expect(self, word: str, timeout: float) -> str:
        line: list[str] = []
        reader = threading.Thread(target=lambda: line.append(self.proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        if not line or not line[0].startswith(word):
            raise SystemExit(f"hops bench: the SDK program did not answer {word!r} within {timeout:g} s:\n"
                             f"{lat.tail(self.log)}")
        return line[0]

    def command(self, text: str, answer: str = "done", timeout: float = 120.0) -> str:
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()
        return self.expect(answer, timeout)


# -- the ROS side (this process) ---------------------------------------------------------------------------
class RosSide:
    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import Int64MultiArray
        from test_msgs.srv import BasicTypes

        self._rclpy, self.msg_cls, self.srv_cls = rclpy, Int64MultiArray, BasicTypes
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("hops_bench")
        self.received: list[tuple[int, int]] = []  # (index, ns) on IN_ROS
        self.served: list[tuple[int, int]] = []  # (index, ns) ECHO_ROS was called
        self.node.create_subscription(Int64MultiArray, IN_ROS, self._on_in, 100)
        self.pub = self.node.create_publisher(Int64MultiArray, OUT_ROS, 100)
        self.node.create_service(BasicTypes, ECHO_ROS, self._echo)
        self.client = self.node.create_client(BasicTypes, ros_names.absolute(PROVIDED))
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, name="hops-ros", daemon=True)
        self.thread.start()

    def _on_in(self, msg: Any) -> None:
        self.received.append((int(msg.data[0]), time.monotonic_ns()))

    def _echo(self, request: Any, response: Any) -> Any:
        self.served.append((int(request.int64_value), time.monotonic_ns()))
        response.int64_value = request.int64_value
        return response

    def publish(self, count: int, rate: float) -> list[tuple[int, int]]:
        sent, msg, start = [], self.msg_cls(), time.monotonic()
        for i in range(count):
            if (delay := start + i / rate - time.monotonic()) > 0:
                time.sleep(delay)
            ns = time.monotonic_ns()
            msg.data = [i, ns, 0, 0]
            self.pub.publish(msg)
            sent.append((i, ns))
        return sent

    def call(self, count: int) -> list[tuple[int, int, int]]:
        if not self.client.wait_for_service(timeout_sec=20):
            raise SystemExit(f"hops bench: the SDK-provided service /{PROVIDED} never appeared in ROS")
        calls = []
        for i in range(count):
            done = threading.Event()
            ns = time.monotonic_ns()
            future = self.client.call_async(self.srv_cls.Request(int64_value=i))
            future.add_done_callback(lambda _f, done=done: done.set())
            if not done.wait(5):
                raise SystemExit(f"hops bench: call {i} of /{PROVIDED} got no answer in 5 s")
            calls.append((i, ns, time.monotonic_ns()))
        return calls

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2)
        self.thread.join(timeout=2)
        self.node.destroy_node()
        self._rclpy.try_shutdown()


# -- one broker --------------------------------------------------------------------------------------------
def bench_fleet(work: Path, port: int) -> Path:
    """The demo fleet on ``port`` with the two generic rules and the ROS service the exchanges use."""
    def edit(data: dict[str, Any]) -> None:
        robot = data["robots"][ROBOT]
        robot["rules"] = [*robot["rules"],
                          {"direction": "mqtt_to_ros", "mqtt_topic": IN_NAME, "ros_topic": IN_ROS, "ros_type": ARRAY},
                          {"direction": "ros_to_mqtt", "ros_topic": OUT_ROS, "ros_type": ARRAY,
                           "mqtt_topic": lat.join("state", OUT_NAME)}]
        robot["services"] = [*robot["services"], {"name": ECHO, "ros_service": ECHO_ROS, "ros_type": SERVICE,
                                                  "read_only": False, "timeout": 5.0}]

    return lat.fleet_copy(work / f"robots-hops-{port}.yaml", CONFIG, port=port, ws_port=0, edit=edit)


def trace_events(path: Path) -> dict[tuple[str, str], list[int]]:
    """The bridge's trace as (stage, topic) -> ns in order."""
    events: dict[tuple[str, str], list[int]] = {}
    if path.exists():
        for line in path.read_bytes().splitlines():
            event = orjson.loads(line)
            events.setdefault((event["stage"], event["topic"]), []).append(event["ns"])
    return events


Hops = dict[str, list[float]]  # hop name -> ms per measured message, in index order


def hops_of(stamps: list[list[int | None]], names: list[str], count: int) -> Hops:
    """Stamp lists (one per point on the path, indexed by message) -> the time of each hop, ms, measured ones only."""
    out: Hops = {name: [] for name in [*names, "total"]}
    for i in range(WARMUP, WARMUP + count):
        points = [s[i] if i < len(s) else None for s in stamps]
        if any(p is None for p in points):
            continue
        for name, a, b in zip(names, points, points[1:], strict=False):
            out[name].append((b - a) / 1e6)
        out["total"].append((points[-1] - points[0]) / 1e6)
    return out


def by_index(pairs: list[tuple[int, int]] | list[list[int]], n: int) -> list[int | None]:
    out: list[int | None] = [None] * n
    for item in pairs:
        if 0 <= item[0] < n and out[item[0]] is None:
            out[item[0]] = item[1]
    return out


def run_broker(ros: RosSide, kind: str, work: Path, env: dict[str, str], count: int, rate: float
               ) -> dict[str, Hops] | None:
    total = WARMUP + count
    trace = work / f"bridge-trace-{kind}.jsonl"
    with ExitStack() as phase:
        port = lat.free_port()
        fleet = bench_fleet(work, port)
        if kind == "embedded":
            lat.start_embedded_broker(phase, fleet, port, work / f"embedded-{port}.log", env,
                                      "--limit", "user_publish_rate=0")  # see PACING_NOTE
        else:
            if lat.mosquitto_exe() is None:
                return None
            mosquitto = lat.Mosquitto.exported(work, fleet, export_dir=f"mosquitto-{port}")
            phase.callback(mosquitto.stop)
            mosquitto.start()
        url = f"mqtt://127.0.0.1:{port}"
        lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot",
                                ROBOT, "--url", url, "--log-level", "WARNING"], work / f"bridge-{kind}.log",
                        {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD, TRACE_ENV: str(trace)})
        ros.received.clear()
        ros.served.clear()
        sdk = SdkProgram(phase, url, env, work / f"sdk-{kind}.log")
        # 1: SDK publisher -> ROS subscriber. Primed first: until one arrives, the bridge's publisher may still be
        # matching the subscriber (DDS discovery), which would show as a first-message hop, not the bridge
        sdk.command(f"pub 1 {rate}")
        lat.wait_until(lambda: bool(ros.received), 10)
        ros.received.clear()
        sdk.command(f"pub {total} {rate}")
        lat.wait_until(lambda: len(ros.received) >= total, 5)
        # 2: ROS publisher -> SDK subscriber (primed the same way: the bridge's subscription matches ours)
        lat.wait_until(lambda: ros.pub.get_subscription_count() > 0, 10)
        ros_sent = ros.publish(total, rate)
        time.sleep(0.5)
        # 3: ROS client -> SDK-provided service, one call at a time
        ros_calls = ros.call(total)
        # 4: SDK client -> ROS service
        sdk.command(f"calls {total}")
        report = orjson.loads(sdk.command("report", answer="{"))
    # the bridge has exited: its trace is on disk
    events = trace_events(trace)
    topics = TopicTree(lat.load_fleet(CONFIG).prefix)

    def bridge(stage: str, topic: str) -> list[int | None]:
        """The bridge's stamps of one door, aligned to the last ``total`` messages: the exchange-1 primer and
        anything DDS dropped while still matching are at the start, never among the measured ones."""
        stamps: list[int | None] = list(events.get((stage, topic), []))[-total:]
        return [None] * (total - len(stamps)) + stamps

    in_mqtt, in_ros = bridge("mqtt_in", topics.from_user(ROBOT, OPERATOR[0], IN_NAME)), bridge("ros_out", IN_ROS)
    out_ros, out_mqtt = bridge("ros_in", OUT_ROS), bridge("mqtt_out", topics.state(ROBOT, OUT_NAME))
    req_out = bridge("mqtt_out", topics.request(ROBOT, OPERATOR[0], PROVIDED))
    resp_in = bridge("mqtt_in", topics.response(ROBOT, OPERATOR[0], PROVIDED))
    call_in = bridge("mqtt_in", topics.call(ROBOT, OPERATOR[0], ECHO))
    reply_out = bridge("mqtt_out", topics.reply(ROBOT, OPERATOR[0], ECHO))
    n = total
    results = {
        EXCHANGES[0]: hops_of([by_index(report["sent"], n), in_mqtt, in_ros, by_index(ros.received, n)],
                              ["SDK -> broker -> bridge", "bridge", "bridge -> ROS"], count),
        EXCHANGES[1]: hops_of([by_index(ros_sent, n), out_ros, out_mqtt, by_index(report["received"], n)],
                              ["ROS -> bridge", "bridge", "bridge -> broker -> SDK"], count),
        EXCHANGES[2]: hops_of([[c[1] for c in ros_calls], req_out, by_index(report["served"], n), resp_in,
                               [c[2] for c in ros_calls]],
                              ["ROS -> bridge (request)", "bridge -> broker -> SDK", "SDK -> broker -> bridge",
                               "bridge -> ROS (response)"], count),
        EXCHANGES[3]: hops_of([[c[1] for c in report["calls"]], call_in, by_index(ros.served, n), reply_out,
                               [c[2] for c in report["calls"]]],
                              ["SDK -> broker -> bridge", "bridge -> ROS (request)", "ROS -> bridge (response)",
                               "bridge -> broker -> SDK"], count),
    }
    return results


# -- report ----------------------------------------------------------------------------------------------
def pct(values: list[float], q: int) -> float:
    if len(values) < 2:
        return values[0] if values else float("nan")
    return statistics.quantiles(values, n=100, method="inclusive")[q - 1]


def report(all_results: dict[str, dict[str, Hops]], count: int, rate: float) -> None:
    print(f"\nHops, {count} measurements per exchange after {WARMUP} warm-up; topics at {rate:g} Hz, calls one at a "
          f"time; ms. {lat.versions()}")
    for broker, results in all_results.items():
        print(f"\n{broker}" + (f" ({PACING_NOTE})" if broker.startswith("embedded") else ""))
        print(f"{'exchange / hop':<52} {'p50':>7} {'p99':>7} {'mean':>7} {'n':>6}")
        for exchange, hops in results.items():
            print(exchange)
            for name, values in hops.items():
                label = f"  {name}" if name != "total" else "  = end to end"
                print(f"{label:<52} {pct(values, 50):7.3f} {pct(values, 99):7.3f} "
                      f"{statistics.fmean(values) if values else float('nan'):7.3f} {len(values):>6}")


def plot(all_results: dict[str, dict[str, Hops]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    brokers = list(all_results)
    fig, axes = plt.subplots(1, len(brokers), figsize=(6.5 * len(brokers), 3.8), dpi=100, squeeze=False)
    for ax, broker in zip(axes[0], brokers, strict=False):
        results = all_results[broker]
        for row, hops in enumerate(results.values()):
            left = 0.0
            for k, (name, values) in enumerate((n, v) for n, v in hops.items() if n != "total"):
                width = pct(values, 50)
                ax.barh(row, width, left=left, color=f"C{k}", edgecolor="white")
                if width > 0.08:
                    ax.text(left + width / 2, row, name.replace(" -> ", "→"), ha="center", va="center", fontsize=6)
                left += width
        ax.set_yticks(range(len(results)), list(results), fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel("p50, ms")
        ax.set_title(f"{broker}: hops of each exchange (p50)", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=None, help="measurements per exchange (default: 1000)")
    p.add_argument("--rate", type=float, default=200.0, help="topic messages per second (default: %(default)s)")
    p.add_argument("--brokers", default="embedded,mosquitto", help="comma-separated (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="200 measurements per exchange")
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="(default: %(default)s)")
    p.add_argument("--sdk", action="store_true", help=argparse.SUPPRESS)  # the bench's own child process
    p.add_argument("--url", default="", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.sdk:
        return sdk_program(args.url)
    count = args.count if args.count is not None else 200 if args.quick else 1000
    brokers = [b.strip() for b in args.brokers.split(",") if b.strip()]
    if count < 2 or not 0 < args.rate <= 2000 or set(brokers) - {"embedded", "mosquitto"}:
        p.error("--count ≥ 2, --rate in (0, 2000], --brokers from embedded, mosquitto")
    began = time.monotonic()
    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children inherit the same domain
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    os.environ["ROS_LOG_DIR"] = env["ROS_LOG_DIR"]
    all_results: dict[str, dict[str, Hops]] = {}
    ros = RosSide()
    try:
        with tempfile.TemporaryDirectory(prefix="roslink-hops-") as tmp:
            for kind in brokers:
                results = run_broker(ros, kind, Path(tmp), env, count, args.rate)
                if results is None:
                    print(f"  {kind}: Mosquitto not installed, skipped")
                    continue
                all_results["embedded broker" if kind == "embedded" else "Mosquitto"] = results
                print(f"  {kind}: done", flush=True)
    except KeyboardInterrupt:
        print("hops bench: interrupted", file=sys.stderr)
        return 130
    except (lat.ChildExited, TimeoutError) as e:
        raise SystemExit(f"hops bench: {e}") from None
    finally:
        ros.close()
    report(all_results, count, args.rate)
    plot(all_results, args.plot)
    print(f"plot: {args.plot}\nrun took {time.monotonic() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())


