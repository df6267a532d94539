"""Benchmark: latency and jitter the bridge adds to commands and state, per broker, next to plain ROS.

    .venv/bin/python bench/latency.py [--count 400] [--rate 20] [--quick] [--keep-throttle]

Streams messages at a fixed rate in both directions at once (the state message half a period after the
command) and times each one from the moment the sender hands it over to the moment the receiver's
callback runs. Every row has its own N messages after 20 warm-up messages.

* command, direct ROS: geometry_msgs/Twist from an rclpy publisher in a child process to an rclpy
  subscriber here (the baseline: one DDS hop between two processes).
* command via the bridge: ROSLink twist commands from the SDK (RobotClient as alice, with operator
  presence) -> broker -> bridge -> ROS ``cmd_vel`` -> an rclpy subscriber here.
* state, direct ROS: nav_msgs/Odometry, rclpy publisher (child process) -> rclpy subscriber here.
* state via the bridge: Odometry on ``odom`` from here -> bridge (global_motion preset) -> broker ->
  a paho subscriber here (bob, a viewer).

The bridge rows run once against the embedded amqtt broker and once against Mosquitto running the
fleet's exported config (skipped if Mosquitto is not installed). No simulated robot runs: it would
publish odom and consume cmd_vel itself. Everything is on loopback; DDS stays on this machine
(roslink_mqtt.ros_env: localhost discovery, loopback-only Fast DDS profile, a fresh domain id).

Matching a received message to its send time:

* direct rows: the index and the send time travel in the message (Twist linear.x/linear.y, Odometry
  pose.position.x/y). time.monotonic() is CLOCK_MONOTONIC, one clock for every process on the machine.
* command via the bridge: a marker in lx, 0.0001 * (i % 999 + 1) m/s, well inside the fleet's velocity
  limit so the bridge never clamps it, and never 0 (the bridge's failsafe stops are zero twists); the
  send time stays here, keyed by marker.
* state via the bridge: index and send time in pose.position.x/y, which the global_motion preset carries
  unchanged as GlobalMotion x/y.

The demo fleet throttles odom -> state/global_motion to ``max_rate`` 10 Hz (newest wins). Above that
rate the throttle drops messages and delays others by up to a period, which would measure the throttle,
not the bridge; so the bench runs the bridge on a copy of robots.yaml without that throttle, and says so.
``--keep-throttle`` measures the fleet file as it is.

Never asserts on timing: it prints one table.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson
import paho.mqtt.client as mqtt

from roslink_mqtt.client import RobotClient
from roslink_mqtt.config import load_fleet
from roslink_mqtt.localproc import (
    ChildExited,
    Mosquitto,
    fleet_copy,
    free_port,
    mosquitto_exe,
    start_child,
    start_embedded_broker,
    tail,
)
from roslink_mqtt.mqtt import make_client
from roslink_mqtt.protocol import SystemStatus
from roslink_mqtt.topics import TopicTree, Verb, join_leaf, state_leaf

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ROBOT, ROBOT_PASSWORD = "turtle1", "turtle1-demo"
OPERATOR = ("alice", "alice-demo")  # may command turtle1
VIEWER = ("bob", "bob-demo")  # may read turtle1's state
STATE_NAME = "global_motion"
DIRECT_CMD, DIRECT_STATE = "/bench_cmd_vel", "/bench_odom"  # the baseline's own topics, nothing else uses them
WARMUP = 20  # messages sent and discarded before each row's N
MARKER_STEP = 1e-4  # m/s per marker unit in lx
MARKERS = 999  # markers 1..999 -> lx 0.0001 .. 0.0999 m/s
PRIME_SECONDS = 15.0  # bound on waiting for the first message through a freshly started bridge
ROS_DEPTH = 50  # reliable, volatile; deep enough that a late executor never drops a sample
Sample = tuple[int, float, float]  # (index, sent, received), time.monotonic() seconds


# -- processes ------------------------------------------------------------------------------------
def wait_until(predicate: Callable[[], bool], timeout: float, step: float = 0.02) -> bool:
    """Poll ``predicate`` until it holds or ``timeout`` passes: every wait in the bench is bounded."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(step)
    return True


# -- the fleet ------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class FleetFacts:
    """What the bench takes from robots.yaml instead of hard-coding it."""

    cmd_topic: str  # ROS topic of the cmd/twist rule
    state_topic: str  # ROS topic of the state/global_motion rule
    max_rate: float | None  # that rule's throttle, Hz
    linear_limit: float  # m/s, what the bridge clamps lx to
    command_timeout: float  # s, the dead-man on a silent velocity stream


def fleet_facts(path: Path) -> FleetFacts:
    """Read the rules the bench drives, so a changed fleet file changes the bench, not silently its numbers."""
    robot = load_fleet(path).robots[ROBOT]
    by_topic = {rule.mqtt_topic: rule for rule in robot.rules}
    cmd, state = by_topic.get(join_leaf(Verb.CMD, "twist")), by_topic.get(state_leaf(STATE_NAME))
    if cmd is None or state is None or state.ros_type != "nav_msgs/msg/Odometry":
        raise SystemExit(f"latency bench: {path} needs a cmd/twist rule and an Odometry state/{STATE_NAME} rule "
                         f"for {ROBOT}")
    limits = cmd.limits or robot.bridge.limits
    return FleetFacts(cmd.ros_topic, state.ros_topic, state.max_rate, limits.linear, robot.bridge.command_timeout)


def bench_fleet(work: Path, port: int, keep_throttle: bool) -> Path:
    """A copy of the demo fleet on ``port`` (no WebSocket listener), the state throttle lifted unless kept.

    A copy because Mosquitto's exported config takes its port from the fleet file, and because the
    throttle would be measured instead of the bridge (see the module docstring).
    """
    def lift_throttle(data: dict[str, Any]) -> None:
        rules = [rule for rule in data["robots"][ROBOT]["rules"] if rule.get("mqtt_topic") == state_leaf(STATE_NAME)]
        if len(rules) != 1:  # an edit that finds nothing must not silently measure the throttle
            raise SystemExit(f"latency bench: expected one state/{STATE_NAME} rule for {ROBOT}, found {len(rules)}")
        rules[0].pop("max_rate", None)

    return fleet_copy(work / f"robots-{port}.yaml", CONFIG, port=port, ws_port=0,
                      edit=None if keep_throttle else lift_throttle)


# -- brokers and the bridge -----------------------------------------------------------------------
def start_embedded(stack: ExitStack, work: Path, env: dict[str, str], keep_throttle: bool) -> tuple[int, Path]:
    """The embedded amqtt broker as deployed (logins + ACL), on a free loopback port."""
    port = free_port()
    fleet = bench_fleet(work, port, keep_throttle)
    start_embedded_broker(stack, fleet, port, work / "embedded.log", env)
    return port, fleet


def start_mosquitto(stack: ExitStack, work: Path, env: dict[str, str], keep_throttle: bool
                    ) -> tuple[int, Path] | None:
    """Mosquitto running exactly what ``roslink-mqtt acl export`` writes (set_tcp_nodelay included)."""
    if mosquitto_exe() is None:
        return None
    port = free_port()
    fleet = bench_fleet(work, port, keep_throttle)
    mosquitto = Mosquitto.exported(work, fleet, export_dir="mosquitto")
    stack.callback(mosquitto.stop)
    mosquitto.start()
    return port, fleet


def start_bridge(stack: ExitStack, work: Path, env: dict[str, str], fleet: Path, port: int) -> Path:
    """The robot's bridge, as a robot runs it; returns its log (printed if it never comes up)."""
    log = work / f"bridge-{port}.log"
    start_child(stack, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot",
                        ROBOT, "--url", f"mqtt://127.0.0.1:{port}", "--log-level", "WARNING"],
                log, {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD})
    return log


def wait_online(client: RobotClient, bridge_log: Path, timeout: float = 20.0) -> None:
    """Wait for the bridge's retained heartbeat to say ACTIVE (system_status 4): it is connected and ready."""
    def active(robots: dict[str, Any]) -> bool:
        info = robots.get(ROBOT)
        return info is not None and info.online and info.system_status == SystemStatus.ACTIVE

    if not client.directory.wait(active, timeout):
        raise SystemExit(f"latency bench: {ROBOT}'s bridge not online after {timeout:g} s:\n{tail(bridge_log)}")


def connect_viewer(stack: ExitStack, port: int, topic: str, on_message: Callable[..., None]) -> mqtt.Client:
    """A plain paho subscriber (TCP_NODELAY via make_client) timing state on its network thread, no queue between."""
    client = make_client(f"bob-latency-{os.getpid()}-{port}", username=VIEWER[0], password=VIEWER[1],
                         url=f"mqtt://127.0.0.1:{port}")
    connected, subscribed = threading.Event(), threading.Event()
    client.on_connect = lambda _c, _u, _f, rc, _p: None if rc.is_failure else connected.set()
    client.on_subscribe = lambda *_args: subscribed.set()
    client.on_message = on_message
    client.connect("127.0.0.1", port, keepalive=30)
    client.loop_start()

    def stop() -> None:
        client.disconnect()
        client.loop_stop()

    stack.callback(stop)
    if not connected.wait(10):
        raise SystemExit(f"latency bench: {VIEWER[0]} could not log in on port {port}")
    client.subscribe(topic, qos=1)
    if not subscribed.wait(10):
        raise SystemExit(f"latency bench: no SUBACK for {topic}")
    return client


# -- samples --------------------------------------------------------------------------------------
@dataclass
class Case:
    """The samples of one row. Indices below ``first`` are warm-up; ``count`` indices from there are measured."""

    count: int
    first: int = 0
    samples: list[Sample] = field(default_factory=list)  # appended from ROS / paho threads
    sent_by_marker: dict[int, tuple[int, float]] = field(default_factory=dict)

    def got(self, index: int, sent: float, received: float) -> None:
        self.samples.append((index, sent, received))

    def sent_marker(self, marker: int, index: int, sent: float) -> None:
        """Remember a send whose message carries only a marker (the bridge's command path)."""
        self.sent_by_marker[marker] = (index, sent)

    def got_marker(self, marker: int, received: float) -> None:
        hit = self.sent_by_marker.get(marker)
        if hit is not None:
            self.got(hit[0], hit[1], received)

    def measured(self) -> list[Sample]:
        """Measured samples in arrival order, first receipt of each index only."""
        seen: set[int] = set()
        out = []
        for sample in list(self.samples):
            if self.first <= sample[0] < self.first + self.count and sample[0] not in seen:
                seen.add(sample[0])
                out.append(sample)
        return out

    def complete(self) -> bool:
        return len(self.measured()) >= self.count


def settle(cases: list[Case], timeout: float = 1.0) -> None:
    """After the last send, give messages still in flight a bounded moment to arrive."""
    wait_until(lambda: all(case.complete() for case in cases), timeout)


def pace(first: int, total: int, rate: float, send_cmd: Callable[[int], None], send_state: Callable[[int], None],
         done: Callable[[], bool] | None = None) -> int:
    """Send indices ``first`` .. ``first + total - 1`` on both paths at ``rate``, state half a period after command.

    Absolute deadlines (start + k * half period): one late wake-up does not shift every later message.
    The half-period offset keeps the two streams from queueing behind each other. Stops early when
    ``done()`` holds (checked once per period); returns the next unused index.
    """
    half = 0.5 / rate
    start = time.monotonic()
    for k in range(2 * total):
        delay = start + k * half - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        index = first + k // 2
        if k % 2 == 0:
            if done is not None and done():
                return index
            send_cmd(index)
        else:
            send_state(index)
    return first + total


# -- ROS ------------------------------------------------------------------------------------------
class RosSide:
    """This process's rclpy node, spun in a background thread: every ROS-side receipt is timed here on arrival.

    It also publishes the Odometry the bridge forwards. ``cmd``/``state`` are the cases being filled.
    """

    def __init__(self, facts: FleetFacts) -> None:
        import rclpy
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        # rclpy's own SIGINT handler would shut ROS down under our feet; Ctrl-C must reach the ExitStack instead
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("latency_bench")
        self.cmd: Case | None = None
        self.state: Case | None = None
        self.node.create_subscription(Twist, DIRECT_CMD, self._on_direct_twist, ROS_DEPTH)
        self.node.create_subscription(Odometry, DIRECT_STATE, self._on_direct_odom, ROS_DEPTH)
        self.node.create_subscription(Twist, facts.cmd_topic, self._on_bridge_twist, ROS_DEPTH)
        self.odom_pub = self.node.create_publisher(Odometry, facts.state_topic, ROS_DEPTH)
        self.odom = Odometry()  # one message, refilled per send: rclpy serialises at publish()
        self.odom.header.frame_id = "odom"
        self.odom.pose.pose.orientation.w = 1.0
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, name="latency-ros", daemon=True)
        self.thread.start()

    def _on_direct_twist(self, msg: Any) -> None:
        received = time.monotonic()
        if self.cmd is not None:
            self.cmd.got(int(msg.linear.x), msg.linear.y, received)

    def _on_direct_odom(self, msg: Any) -> None:
        received = time.monotonic()
        if self.state is not None:
            position = msg.pose.pose.position
            self.state.got(int(position.x), position.y, received)

    def _on_bridge_twist(self, msg: Any) -> None:
        received = time.monotonic()
        marker = round(msg.linear.x / MARKER_STEP)
        if marker and self.cmd is not None:  # 0 = a failsafe or final stop, not one of ours
            self.cmd.got_marker(marker, received)

    def publish_odom(self, index: int) -> None:
        """Odometry for the bridge: index in position.x, send time in position.y."""
        position = self.odom.pose.pose.position
        position.x = float(index)
        position.y = time.monotonic()
        self.odom_pub.publish(self.odom)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2)
        self.thread.join(timeout=2)
        self.node.destroy_node()
        self._rclpy.try_shutdown()


def ros_sender(count: int, rate: float) -> int:
    """Hidden ``--ros-sender`` mode: the publisher process of the direct-ROS rows.

    A separate process, so the baseline crosses a process boundary through DDS as the bridge's ROS hop
    does (inside one process Fast DDS may hand messages over in memory, which would flatter ROS).
    """
    local = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST"
    if not local or "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ:
        print("latency bench: --ros-sender is started by the bench itself, with loopback-only DDS", file=sys.stderr)
        return 2
    import rclpy
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # SIGINT (our stop) -> KeyboardInterrupt -> finally
    node = rclpy.create_node("latency_bench_sender")
    try:
        cmd_pub = node.create_publisher(Twist, DIRECT_CMD, ROS_DEPTH)
        state_pub = node.create_publisher(Odometry, DIRECT_STATE, ROS_DEPTH)
        if not wait_until(lambda: cmd_pub.get_subscription_count() > 0 and state_pub.get_subscription_count() > 0,
                          20.0):
            print("latency bench: the bench's subscribers were never matched", file=sys.stderr)
            return 2
        twist, odom = Twist(), Odometry()
        odom.header.frame_id = "odom"
        odom.pose.pose.orientation.w = 1.0

        def send_cmd(index: int) -> None:
            twist.linear.x, twist.linear.y = float(index), time.monotonic()
            cmd_pub.publish(twist)

        def send_state(index: int) -> None:
            position = odom.pose.pose.position
            position.x, position.y = float(index), time.monotonic()
            state_pub.publish(odom)

        pace(0, WARMUP + count, rate, send_cmd, send_state)
        time.sleep(0.5)  # reliable DDS: let the last messages arrive before the writer goes away
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# -- the rows -------------------------------------------------------------------------------------
def run_direct(ros: RosSide, work: Path, env: dict[str, str], count: int, rate: float) -> tuple[Case, Case]:
    """Baseline rows: a child rclpy publisher -> this process's subscribers, both paths at once."""
    cmd, state = Case(count, first=WARMUP), Case(count, first=WARMUP)
    ros.cmd, ros.state = cmd, state
    log = work / "ros-sender.log"
    with ExitStack() as phase:
        proc = start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--ros-sender", "--count",
                                   str(count), "--rate", str(rate)], log, env).popen
        try:
            proc.wait(timeout=30 + (WARMUP + count) / rate)
        except subprocess.TimeoutExpired:
            print("latency bench: the ROS sender overran its time; stopped", file=sys.stderr)
        settle([cmd, state])
    if proc.returncode:
        print(f"latency bench: ROS sender failed (code {proc.returncode}):\n{tail(log)}", file=sys.stderr)
    ros.cmd = ros.state = None
    return cmd, state


def state_receiver(case: Case) -> Callable[..., None]:
    """paho on_message for GlobalMotion: index in x, send time in y, timed before anything else."""
    def on_message(_client: mqtt.Client, _userdata: object, message: mqtt.MQTTMessage) -> None:
        received = time.monotonic()
        payload = orjson.loads(message.payload)["payload"]
        case.got(int(payload["x"]), payload["y"], received)

    return on_message


def twist_sender(client: RobotClient, case: Case) -> Callable[[int], None]:
    """Send a ROSLink twist whose lx is the message's marker; remember when."""
    def send(index: int) -> None:
        marker = index % MARKERS + 1
        case.sent_marker(marker, index, time.monotonic())
        client.twist(ROBOT, lx=marker * MARKER_STEP)

    return send


def run_bridge(ros: RosSide, work: Path, env: dict[str, str], start_broker: Callable[[ExitStack], Any],
               count: int, rate: float) -> tuple[Case, Case] | None:
    """Bridge rows for one broker: start broker + bridge, prime both paths, warm up, measure, stop everything."""
    cmd, state = Case(count), Case(count)
    with ExitStack() as phase:
        started = start_broker(phase)
        if started is None:
            return None
        port, fleet = started
        bridge_log = start_bridge(phase, work, env, fleet, port)
        topic = TopicTree(load_fleet(fleet).prefix).state(ROBOT, STATE_NAME)
        connect_viewer(phase, port, topic, state_receiver(state))
        operator = phase.enter_context(RobotClient(*OPERATOR, url=f"mqtt://127.0.0.1:{port}", robots=[ROBOT]))
        wait_online(operator, bridge_log)
        ros.cmd, ros.state = cmd, state
        try:
            send_cmd = twist_sender(operator, cmd)
            # prime: until the bridge has seen our presence and DDS has matched both ROS hops
            nxt = pace(0, int(PRIME_SECONDS * rate), rate, send_cmd, ros.publish_odom,
                       done=lambda: bool(cmd.samples and state.samples))
            if not (cmd.samples and state.samples):
                which = "commands" if not cmd.samples else "state"
                raise SystemExit(f"latency bench: no {which} through the bridge after {PRIME_SECONDS:g} s:\n"
                                 f"{tail(bridge_log)}")
            cmd.first = state.first = nxt + WARMUP
            pace(nxt, WARMUP + count, rate, send_cmd, ros.publish_odom)
            operator.twist(ROBOT)  # a clean stop before presence goes (lx 0 carries no marker)
            settle([cmd, state])
        finally:
            ros.cmd = ros.state = None
    return cmd, state


# -- report ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Row:
    p50: float
    p90: float
    p99: float
    max: float
    jitter: float  # ms, standard deviation of inter-arrival times
    received: int
    sent: int


def summarize(case: Case | None) -> Row | None:
    """Latency percentiles and jitter (ms) of a case's measured samples; None when too few arrived."""
    if case is None:
        return None
    samples = case.measured()
    if len(samples) < 3:
        return None
    latency = [(received - sent) * 1000 for _i, sent, received in samples]
    arrivals = sorted(received for _i, _s, received in samples)
    gaps = [(b - a) * 1000 for a, b in zip(arrivals, arrivals[1:], strict=False)]
    q = statistics.quantiles(latency, n=100, method="inclusive")
    return Row(q[49], q[89], q[98], max(latency), statistics.pstdev(gaps), len(samples), case.count)


def format_row(label: str, row: Row | None, base: Row | None, note: str = "(no samples)") -> str:
    if row is None:
        return f"{label:<50} {note}"
    extra = f"{row.p50 - base.p50:+8.2f}" if base is not None else f"{'':>8}"
    return (f"{label:<50} {row.p50:7.2f} {row.p90:7.2f} {row.p99:7.2f} {row.max:7.2f} {row.jitter:9.2f} {extra}"
            f" {row.received:>5}/{row.sent}")


def versions() -> str:
    """Versions that explain the numbers, for the table's caption."""
    parts = [f"ROS 2 Jazzy {os.environ.get('RMW_IMPLEMENTATION')}",
             f"paho-mqtt {importlib.metadata.version('paho-mqtt')}", f"amqtt {importlib.metadata.version('amqtt')}"]
    exe = mosquitto_exe()
    if exe is not None:
        try:
            out = subprocess.run([exe, "-h"], capture_output=True, text=True, timeout=5).stdout.split("\n", 1)[0]
            parts.append(f"Mosquitto {out.split()[-1]}" if out else "Mosquitto")
        except (OSError, subprocess.TimeoutExpired):
            pass
    return ", ".join(parts)


def throttle_note(facts: FleetFacts, rate: float, keep_throttle: bool) -> str:
    if not facts.max_rate:
        return f"odom -> state/{STATE_NAME} has no max_rate in {CONFIG.name}"
    if keep_throttle and rate <= facts.max_rate:
        return f"odom -> state/{STATE_NAME} kept at max_rate {facts.max_rate:g} Hz, not below the sending rate"
    if keep_throttle:
        return (f"odom -> state/{STATE_NAME} kept at max_rate {facts.max_rate:g} Hz (newest wins): at {rate:g} Hz "
                "the state rows lose messages and wait for the throttle's slots")
    return (f"odom -> state/{STATE_NAME} has max_rate {facts.max_rate:g} Hz in {CONFIG.name}; lifted in this run's "
            "copy so the state rows show the bridge, not the throttle (--keep-throttle to keep it)")


def report(results: dict[str, tuple[Case, Case] | None], count: int, rate: float, facts: FleetFacts,
           keep_throttle: bool) -> None:
    """Print the one table: command rows, then state rows; +p50 is each bridge row's p50 minus direct ROS."""
    print(f"\nLatency send -> receiver callback, loopback, {count} messages per row at {rate:g} Hz after {WARMUP} "
          f"warm-up;\ncommand and state streams run together, half a period apart. {versions()}")
    print(throttle_note(facts, rate, keep_throttle))
    print(f"{'path':<50} {'p50 ms':>7} {'p90 ms':>7} {'p99 ms':>7} {'max ms':>7} {'jitter ms':>9} {'+p50 ms':>8}"
          f" recv/sent")
    labels = {
        "direct": ("command  rclpy -> rclpy (direct ROS)", "state    rclpy -> rclpy (direct ROS)"),
        "embedded": ("command  SDK -> embedded amqtt -> bridge -> rclpy",
                     "state    rclpy -> bridge -> embedded amqtt -> paho"),
        "mosquitto": ("command  SDK -> Mosquitto -> bridge -> rclpy",
                      "state    rclpy -> bridge -> Mosquitto -> paho"),
    }
    for path in (0, 1):
        base = summarize(results["direct"][path]) if results.get("direct") else None
        for key, names in labels.items():
            outcome = results.get(key)
            note = "(mosquitto not installed: skipped)" if key == "mosquitto" and outcome is None else "(no samples)"
            row = summarize(outcome[path]) if outcome else None
            print(format_row(names[path], row, None if key == "direct" else base, note))
    print(f"jitter = standard deviation of inter-arrival times (the sender's period is {1000 / rate:g} ms); "
          "+p50 = added to direct ROS at p50")


# -- main -----------------------------------------------------------------------------------------
def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=None, help="measured messages per row (default: 400)")
    p.add_argument("--rate", type=float, default=20.0, help="messages per second on each path (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="100 messages per row")
    p.add_argument("--keep-throttle", action="store_true", help="keep the state rule's max_rate from robots.yaml")
    p.add_argument("--ros-sender", action="store_true", help=argparse.SUPPRESS)  # the bench's own child process
    args = p.parse_args(argv)
    args.count = args.count if args.count is not None else 100 if args.quick else 400
    if args.count < 3 or not 0 < args.rate <= 500:
        p.error("--count must be at least 3 and --rate in (0, 500]")
    return args


def check_fleet_fits(facts: FleetFacts, rate: float) -> None:
    """Refuse settings under which the bridge's safety would change the measurement (clamp or dead-man)."""
    if MARKERS * MARKER_STEP >= facts.linear_limit:
        raise SystemExit(f"latency bench: markers up to {MARKERS * MARKER_STEP:g} m/s would be clamped "
                         f"(linear limit {facts.linear_limit:g})")
    if 2 / rate >= facts.command_timeout:
        raise SystemExit(f"latency bench: at {rate:g} Hz the dead-man ({facts.command_timeout:g} s) could stop "
                         f"the robot mid-run; use at least {2 / facts.command_timeout:g} Hz")


def measure_all(env: dict[str, str], args: argparse.Namespace) -> dict[str, tuple[Case, Case] | None]:
    """Direct ROS, then the bridge on each broker; each phase starts and stops its own processes."""
    results: dict[str, tuple[Case, Case] | None] = {}
    with tempfile.TemporaryDirectory(prefix="roslink-latency-") as tmp, ExitStack() as stack:
        work = Path(tmp)
        ros = RosSide(fleet_facts(CONFIG))
        stack.callback(ros.close)
        results["direct"] = run_direct(ros, work, env, args.count, args.rate)
        for key, starter in (("embedded", start_embedded), ("mosquitto", start_mosquitto)):
            def start(phase: ExitStack, starter: Callable[..., Any] = starter) -> Any:
                return starter(phase, work, env, args.keep_throttle)

            results[key] = run_bridge(ros, work, env, start, args.count, args.rate)
    return results


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.ros_sender:
        return ros_sender(args.count, args.rate)
    began = time.monotonic()
    facts = fleet_facts(CONFIG)
    check_fleet_fits(facts, args.rate)

    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children inherit the same domain
    try:
        results = measure_all(env, args)
    except KeyboardInterrupt:  # every child was stopped on the way out
        print("latency bench: interrupted", file=sys.stderr)
        return 130
    except (ChildExited, TimeoutError) as e:  # a broker or the bridge did not come up: its log's tail is in e
        raise SystemExit(f"latency bench: {e}") from None
    report(results, args.count, args.rate, facts, args.keep_throttle)
    print(f"run took {time.monotonic() - began:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
