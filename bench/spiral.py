"""Benchmark: the ROSLink cloud paper's spiral — how evenly twist commands reach the robot, per path.

    .venv/bin/python bench/spiral.py [--quick] [--paths onboard,embedded,...] [--plot-dir DIR]

A sender streams geometry_msgs/Twist commands at a fixed rate: constant turn rate, forward speed growing
by ``step`` every tick, so the robot drives a spiral (the paper: 2 Hz with steps 0.05 and 0.13; here also
10 and 50 Hz with the same acceleration). An rclpy subscriber on the robot's ``cmd_vel`` (this process)
stamps each arrival. Jitter is the arrival spacing minus the sending period: a command that arrives
early or late makes the robot hold the previous speed for the wrong time, which bends the spiral.

Paths (each sender is a process of its own, paced by absolute deadlines):

* ``onboard``: an rclpy node on the robot publishes ``cmd_vel`` (the paper's on-board baseline);
* ``embedded`` / ``mosquitto``: the SDK (RobotClient as alice) -> broker -> turtle1's bridge -> ``cmd_vel``;
* ``embedded+image`` / ``mosquitto+image``: the same while the bridge streams a 30 Hz 640×480 JPEG
  (``encoding: raw``) to a viewer (issue: command jitter stays ≤ 2× on-board under large data);
* ``cloud20`` / ``cloud60``: Mosquitto, with the bridge's connection through roslink_mqtt.shaped_link
  (20 ± 5 ms each way; 60 ± 20 ms each way with 1 % of chunks lost and resent after 200 ms) — the
  paper's two cloud runs, which this kernel cannot shape with netem.

The bench runs the bridge on a copy of robots.yaml whose velocity limit is raised to cover the spiral's
top speed (the paper's step 0.13 at 2 Hz reaches 1.56 m/s; turtle1's limit is 0.5): a clamped command would
bend the plotted track, not the timing. Everything else (dead-man, presence, executor) is as deployed.

Prints a table per rate (jitter mean |j|, std, coefficient of variation, like the paper's Table 1) and
writes the tracks the robot would drive (the paper's Fig. 4) and a jitter box plot (its Fig. 5).
Never asserts on timing.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: brokers, bridge, bookkeeping shared by the benches)

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "robots.yaml"
ROBOT, ROBOT_PASSWORD = "turtle1", "turtle1-demo"
OPERATOR, VIEWER = ("alice", "alice-demo"), ("bob", "bob-demo")
PLOT_DIR = ROOT / "docs" / "performance"
TURN = 1.0  # rad/s, every spiral tick (inside turtle1's angular limit)
PRIME_TURN = 0.01  # rad/s: priming commands, told apart from the spiral's by their turn rate
SPIRAL_TOP_SPEED = 2.0  # m/s: the bench fleet's linear limit (paper step 0.13 × 12 ticks = 1.56 m/s)
PRIME_SECONDS = 20.0
IMAGE_RATE, IMAGE_TOPIC, IMAGE_STATE = 30.0, "/bench_spiral/image", "spiral_image"


@dataclass(frozen=True, slots=True)
class Case:
    rate: float  # Hz
    step: float  # m/s added to the forward speed every tick
    ticks: int

    @property
    def label(self) -> str:
        return f"{self.rate:g} Hz, step {self.step:g}"


def cases(quick: bool) -> list[Case]:
    """The paper's two 2 Hz runs, then 10 and 50 Hz with the paper's acceleration (0.1 m/s per second)."""
    scale = 0.5 if quick else 1.0
    return [Case(2.0, 0.05, int(12 * scale)), Case(2.0, 0.13, int(12 * scale)),
            Case(10.0, 0.01, int(60 * scale)), Case(50.0, 0.002, int(200 * scale))]


@dataclass(frozen=True, slots=True)
class Route:
    key: str
    label: str
    broker: str | None  # None: on board, no broker
    image: bool = False
    shape: tuple[float, float, float] | None = None  # delay ms, jitter ms, loss
    rates: tuple[float, ...] = (2.0, 10.0, 50.0)  # which of the cases this path runs


PATHS = [
    Route("onboard", "on board: rclpy -> rclpy", None),
    Route("embedded", "SDK -> embedded broker -> bridge", "embedded"),
    Route("mosquitto", "SDK -> Mosquitto -> bridge", "mosquitto"),
    # the image load matters where commands meet frames most often; the cloud runs at the paper's rate and 50 Hz
    Route("embedded+image", "embedded, 30 Hz JPEG streaming", "embedded", image=True, rates=(50.0,)),
    Route("mosquitto+image", "Mosquitto, 30 Hz JPEG streaming", "mosquitto", image=True, rates=(50.0,)),
    Route("cloud20", "Mosquitto, bridge link 20±5 ms", "mosquitto", shape=(20.0, 5.0, 0.0), rates=(2.0, 50.0)),
    Route("cloud60", "Mosquitto, bridge link 60±20 ms, 1% loss", "mosquitto", shape=(60.0, 20.0, 0.01),
          rates=(2.0, 50.0)),
]


# -- the sender (a child process of its own, both kinds) ---------------------------------------------
def pace_spiral(case: Case, send: Callable[[float, float], None], go: threading.Event) -> bool:
    """Prime until ``go`` (the bench saw a command arrive), then the spiral's ticks on absolute deadlines."""
    period = 1.0 / case.rate
    deadline = time.monotonic() + PRIME_SECONDS
    while not go.is_set():
        if time.monotonic() > deadline:
            return False
        send(0.0, PRIME_TURN)
        go.wait(min(period, 0.1))
    time.sleep(0.3)  # the last primers are through; the first tick starts from a quiet link
    start = time.monotonic()
    for k in range(case.ticks):
        delay = start + k * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        send(case.step * (k + 1), TURN)
    return True


def sender(kind: str, case: Case, url: str) -> int:
    """Hidden ``--send`` mode: ``ros`` publishes cmd_vel itself, ``sdk`` sends ROSLink twists as alice."""
    go = threading.Event()
    signal.signal(signal.SIGUSR1, lambda *_: go.set())
    facts = lat.fleet_facts(CONFIG)
    if kind == "ros":
        import rclpy
        from geometry_msgs.msg import Twist
        from rclpy.signals import SignalHandlerOptions

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("spiral_onboard_sender")
        try:
            pub = node.create_publisher(Twist, facts.cmd_topic, 50)
            if not lat.wait_until(lambda: pub.get_subscription_count() > 0, 20.0):
                print("spiral: the recorder never matched", file=sys.stderr)
                return 2
            twist = Twist()

            def send_ros(lx: float, az: float) -> None:
                twist.linear.x, twist.angular.z = lx, az
                pub.publish(twist)

            ok = pace_spiral(case, send_ros, go)
            send_ros(0.0, 0.0)
            time.sleep(0.5)  # reliable DDS: let the last ticks arrive before the writer goes
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
        return 0 if ok else 3

    from roslink_mqtt.client import RobotClient

    with RobotClient(*OPERATOR, url=url, robots=[ROBOT]) as client:
        if not client.directory.wait(lambda robots: ROBOT in robots and robots[ROBOT].online, 20.0):
            print(f"spiral: {ROBOT} never came online at {url}", file=sys.stderr)
            return 2
        ok = pace_spiral(case, lambda lx, az: client.twist(ROBOT, lx=lx, az=az), go)
        client.twist(ROBOT)  # stop; az 0 is not a tick
        time.sleep(0.3)
    return 0 if ok else 3


def image_load(url: str) -> int:
    """Hidden ``--image-load`` mode: a 30 Hz JPEG CompressedImage on the robot and bob viewing it, until SIGINT."""
    import large
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import CompressedImage

    from roslink_mqtt.mqtt import make_client, parse_broker_url
    from roslink_mqtt.topics import TopicTree

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())  # the bench's stop: finish the loop, report, clean up
    received = [0]
    viewer = make_client(f"bob-spiral-{os.getpid()}", username=VIEWER[0], password=VIEWER[1], url=url)
    viewer.on_connect = lambda c, *_: c.subscribe(TopicTree(lat.load_fleet(CONFIG).prefix).state(ROBOT, IMAGE_STATE))
    viewer.on_message = lambda *_: received.__setitem__(0, received[0] + 1)
    broker = parse_broker_url(url)
    viewer.connect(broker.host, broker.port, keepalive=30)
    viewer.loop_start()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("spiral_camera")
    pub = node.create_publisher(CompressedImage, IMAGE_TOPIC, 5)
    msg = CompressedImage(format="jpeg", data=large.make_jpeg())
    published, start, period = 0, time.monotonic(), 1.0 / IMAGE_RATE
    while not stop.wait(max(0.0, start + published * period - time.monotonic())):
        pub.publish(msg)
        published += 1
    print(f"images published {published} received {received[0]}", flush=True)
    viewer.loop_stop()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def pairs(ticks: list[int]) -> list[tuple[int, int]]:
    """Consecutive received ticks (a lost tick makes one pair span two periods)."""
    return list(zip(ticks, ticks[1:], strict=False))


# -- the recorder (this process) ---------------------------------------------------------------------
@dataclass
class Run:
    path: Route
    case: Case
    arrivals: dict[int, float] = field(default_factory=dict)  # tick index -> monotonic arrival
    note: str = ""

    def jitter_ms(self) -> list[float]:
        """Arrival spacing minus the sending period (× ticks skipped), ms, in tick order."""
        period = 1.0 / self.case.rate
        ticks = sorted(self.arrivals)
        return [1000 * (self.arrivals[b] - self.arrivals[a] - (b - a) * period) for a, b in pairs(ticks)]

    def spacing_ms(self) -> list[float]:
        ticks = sorted(self.arrivals)
        return [1000 * (self.arrivals[b] - self.arrivals[a]) / (b - a) for a, b in pairs(ticks)]


class Recorder:
    """The robot's side: an rclpy subscriber on cmd_vel stamping each spiral tick on arrival."""

    def __init__(self, cmd_topic: str) -> None:
        import rclpy
        from geometry_msgs.msg import Twist
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("spiral_recorder")
        self.run: Run | None = None
        self.primed = threading.Event()
        self.node.create_subscription(Twist, cmd_topic, self._on_twist, 50)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, name="spiral-ros", daemon=True)
        self.thread.start()

    def _on_twist(self, msg: Any) -> None:
        at = time.monotonic()
        run = self.run
        if run is None:
            return
        if abs(msg.angular.z - TURN) < 1e-9:
            run.arrivals.setdefault(round(msg.linear.x / run.case.step) - 1, at)
        elif abs(msg.angular.z - PRIME_TURN) < 1e-9:
            self.primed.set()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2)
        self.thread.join(timeout=2)
        self.node.destroy_node()
        self._rclpy.try_shutdown()


def one_run(recorder: Recorder, path: Route, case: Case, work: Path, env: dict[str, str], url: str) -> Run:
    run = Run(path, case)
    recorder.primed.clear()
    recorder.run = run
    kind = "ros" if path.broker is None else "sdk"
    log = work / f"sender-{path.key}-{case.rate:g}-{case.step:g}.log"
    with ExitStack() as phase:
        child = lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--send", kind, "--url", url,
                                        "--rate", str(case.rate), "--step", str(case.step), "--ticks",
                                        str(case.ticks)], log, env)
        if recorder.primed.wait(PRIME_SECONDS + 10):
            child.signal(signal.SIGUSR1)
        try:
            code = child.popen.wait(timeout=PRIME_SECONDS + 30 + case.ticks / case.rate)
        except Exception:  # noqa: BLE001  (overran: stopped by the ExitStack, reported below)
            code = None
        lat.wait_until(lambda: len(run.arrivals) >= case.ticks, 2.0)
    recorder.run = None
    if code != 0:
        run.note = f"sender exit {code}: {lat.tail(log, 5)}"
    return run


# -- brokers, links, bridge ----------------------------------------------------------------------------
def bench_fleet(work: Path, port: int) -> Path:
    """The demo fleet on ``port``, the linear limit raised to the spiral's top speed, one raw camera rule."""
    def edit(data: dict[str, Any]) -> None:
        robot = data["robots"][ROBOT]
        robot["bridge"] = {**robot["bridge"], "limits": {**robot["bridge"]["limits"], "linear": SPIRAL_TOP_SPEED}}
        robot["rules"] = [*robot["rules"], {"direction": "ros_to_mqtt", "ros_topic": IMAGE_TOPIC,
                                            "ros_type": "sensor_msgs/msg/CompressedImage",
                                            "mqtt_topic": lat.join("state", IMAGE_STATE), "encoding": "raw"}]

    return lat.fleet_copy(work / f"robots-spiral-{port}.yaml", CONFIG, port=port, ws_port=0, edit=edit)


def start_path(phase: ExitStack, path: Route, work: Path, env: dict[str, str]) -> tuple[str, Path | None] | None:
    """Broker, shaped link, bridge (and camera) of one path: (the operator's URL, the camera's log).

    None: Mosquitto is not installed.
    """
    port = lat.free_port()
    fleet = bench_fleet(work, port)
    if path.broker == "embedded":
        lat.start_embedded_broker(phase, fleet, port, work / f"embedded-{port}.log", env)
    else:
        if lat.mosquitto_exe() is None:
            return None
        mosquitto = lat.Mosquitto.exported(work, fleet, export_dir=f"mosquitto-{port}")
        phase.callback(mosquitto.stop)
        mosquitto.start()
    url = f"mqtt://127.0.0.1:{port}"
    bridge_url = url
    if path.shape is not None:
        link_port = lat.free_port()
        delay, jitter, loss = path.shape
        lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.shaped_link", "--listen",
                                f"127.0.0.1:{link_port}", "--to", f"127.0.0.1:{port}", "--delay-ms", str(delay),
                                "--jitter-ms", str(jitter), "--loss", str(loss), "--seed", "7"],
                        work / f"link-{link_port}.log", env, port=link_port, what="shaped link")
        bridge_url = f"mqtt://127.0.0.1:{link_port}"
    bridge_log = work / f"bridge-{port}.log"
    lat.start_child(phase, [sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot",
                            ROBOT, "--url", bridge_url, "--log-level", "WARNING"],
                    bridge_log, {**env, "ROSLINK_PASSWORD": ROBOT_PASSWORD})
    if path.image:
        image_log = work / f"images-{port}.log"
        lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--image-load", "--url", url],
                        image_log, env)
        return url, image_log
    return url, None


# -- report ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Stats:
    received: int
    sent: int
    mean_abs: float  # ms
    std: float  # ms, of the jitter
    cov: float  # %, std of the spacing / mean spacing
    worst: float  # ms, largest |jitter|


def stats(run: Run) -> Stats | None:
    jitter, spacing = run.jitter_ms(), run.spacing_ms()
    if len(jitter) < 3:
        return None
    return Stats(len(run.arrivals), run.case.ticks, statistics.fmean(abs(j) for j in jitter),
                 statistics.pstdev(jitter), 100 * statistics.pstdev(spacing) / statistics.fmean(spacing),
                 max(abs(j) for j in jitter))


def report(runs: list[Run]) -> None:
    print("\nSpiral command jitter at the robot (arrival spacing − sending period), like the paper's Table 1;"
          "\n×onboard = this row's jitter std / the on-board rclpy row's at the same rate and step.")
    for case in dict.fromkeys(r.case for r in runs):
        rows = [r for r in runs if r.case == case]
        base = next((stats(r) for r in rows if r.path.key == "onboard"), None)
        print(f"\n{case.label} ({case.ticks} ticks)")
        print(f"{'path':<44} {'recv':>7} {'mean|j| ms':>10} {'std ms':>7} {'CoV %':>6} {'max ms':>7} {'×onboard':>8}")
        for run in rows:
            s = stats(run)
            if s is None:
                print(f"{run.path.label:<44} {len(run.arrivals):>3}/{case.ticks:<3} (too few) {run.note}")
                continue
            ratio = f"{s.std / base.std:8.2f}" if base and base.std > 0 and run.path.key != "onboard" else f"{'':>8}"
            print(f"{run.path.label:<44} {s.received:>3}/{s.sent:<3} {s.mean_abs:10.2f} {s.std:7.2f} {s.cov:6.2f} "
                  f"{s.worst:7.2f} {ratio} {run.note}")


def track(run: Run | None, case: Case) -> tuple[list[float], list[float]]:
    """The unicycle track a robot drives holding each command from its arrival to the next one's.

    ``run`` None: the ideal track (every command held exactly one period).
    """
    period = 1.0 / case.rate
    if run is None:
        held = [(case.step * (k + 1), period) for k in range(case.ticks)]
    else:
        ticks = sorted(run.arrivals)
        held = [(case.step * (a + 1), run.arrivals[b] - run.arrivals[a]) for a, b in pairs(ticks)]
        if ticks:
            held.append((case.step * (ticks[-1] + 1), period))
    x = y = yaw = 0.0
    xs, ys = [x], [y]
    for speed, dt in held:
        for _ in range(10):  # integrate each hold in 10 sub-steps
            x += speed * math.cos(yaw) * dt / 10
            y += speed * math.sin(yaw) * dt / 10
            yaw += TURN * dt / 10
            xs.append(x)
            ys.append(y)
    return xs, ys


def plot(runs: list[Run], plot_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_dir.mkdir(parents=True, exist_ok=True)
    all_cases = list(dict.fromkeys(r.case for r in runs))
    fig, axes = plt.subplots(1, len(all_cases), figsize=(4 * len(all_cases), 4.2), dpi=100)
    for ax, case in zip(list(axes), all_cases, strict=False):
        ideal = track(None, case)
        ax.plot(*ideal, color="black", linewidth=3, alpha=0.25, label="ideal")
        for run in (r for r in runs if r.case == case):
            xs, ys = track(run, case)
            miss = 1000 * math.hypot(xs[-1] - ideal[0][-1], ys[-1] - ideal[1][-1])
            ax.plot(xs, ys, linewidth=1, label=f"{run.path.key}: ends {miss:.0f} mm off")
        ax.legend(fontsize=6, loc="lower left")
        ax.set_title(case.label, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle("Spiral tracks a robot drives from the commands as they arrived (x, y in m)", fontsize=10)
    fig.tight_layout()
    tracks = plot_dir / "spiral_tracks.png"
    fig.savefig(tracks)
    plt.close(fig)

    fig, axes = plt.subplots(1, len(all_cases), figsize=(4 * len(all_cases), 4.2), dpi=100)
    for ax, case in zip(list(axes), all_cases, strict=False):
        rows = [r for r in runs if r.case == case and len(r.jitter_ms()) >= 3]
        ax.boxplot([r.jitter_ms() for r in rows], showfliers=True, flierprops={"markersize": 2})
        ax.set_xticks(range(1, len(rows) + 1), [r.path.key for r in rows], rotation=60, fontsize=7)
        ax.set_title(case.label, fontsize=9)
        ax.set_ylabel("jitter, ms")
        ax.axhline(0, color="grey", linewidth=0.5)
    fig.suptitle("Command jitter at the robot per path", fontsize=10)
    fig.tight_layout()
    boxes = plot_dir / "spiral_jitter.png"
    fig.savefig(boxes)
    plt.close(fig)
    return [tracks, boxes]


# -- main -------------------------------------------------------------------------------------------------
def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="half the ticks per run")
    p.add_argument("--paths", default=",".join(path.key for path in PATHS),
                   help="comma-separated (default: all): " + ", ".join(path.key for path in PATHS))
    p.add_argument("--plot-dir", type=Path, default=PLOT_DIR, help="where the two PNGs go (default: %(default)s)")
    p.add_argument("--send", choices=("ros", "sdk"), help=argparse.SUPPRESS)  # the bench's own child processes
    p.add_argument("--image-load", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--url", default="", help=argparse.SUPPRESS)
    p.add_argument("--rate", type=float, default=2.0, help=argparse.SUPPRESS)
    p.add_argument("--step", type=float, default=0.05, help=argparse.SUPPRESS)
    p.add_argument("--ticks", type=int, default=16, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    keys = [k.strip() for k in args.paths.split(",") if k.strip()]
    unknown = sorted(set(keys) - {path.key for path in PATHS})
    if unknown:
        p.error(f"unknown path(s): {', '.join(unknown)}")
    args.chosen = [path for path in PATHS if path.key in keys]
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.send or args.image_load:
        local = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST"
        if not local or "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ:
            print("spiral: the child modes are started by the bench itself, with loopback-only DDS", file=sys.stderr)
            return 2
        if args.image_load:
            return image_load(args.url)
        return sender(args.send, Case(args.rate, args.step, args.ticks), args.url)

    began = time.monotonic()
    from roslink_mqtt.ros_env import apply_local_ros_env

    env = apply_local_ros_env()  # before rclpy is imported; the children inherit the same domain
    env["ROS_LOG_DIR"] = env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="roslink-bench-roslog-")
    os.environ["ROS_LOG_DIR"] = env["ROS_LOG_DIR"]
    runs: list[Run] = []
    recorder = Recorder(lat.fleet_facts(CONFIG).cmd_topic)
    try:
        with tempfile.TemporaryDirectory(prefix="roslink-spiral-") as tmp:
            work = Path(tmp)
            for path in args.chosen:
                with ExitStack() as phase:
                    started = ("", None) if path.broker is None else start_path(phase, path, work, env)
                    if started is None:
                        print(f"  {path.key}: Mosquitto not installed, skipped", flush=True)
                        continue
                    for case in cases(args.quick):
                        if case.rate not in path.rates:
                            continue
                        run = one_run(recorder, path, case, work, env, started[0])
                        runs.append(run)
                        s = stats(run)
                        print(f"  {path.key:<16} {case.label:<20} "
                              + (f"jitter std {s.std:6.2f} ms, {s.received}/{s.sent}" if s else f"failed {run.note}"),
                              flush=True)
                if started[1] is not None:  # the camera has stopped: its last line counts the frames
                    print(f"  {path.key}: {lat.tail(started[1], 1).strip()}", flush=True)
    except KeyboardInterrupt:
        print("spiral: interrupted", file=sys.stderr)
        return 130
    except (lat.ChildExited, TimeoutError) as e:
        raise SystemExit(f"spiral: {e}") from None
    finally:
        recorder.close()
    report(runs)
    for written in plot(runs, args.plot_dir):
        print(f"plot: {written}")
    print(f"{lat.versions()}; run took {time.monotonic() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
