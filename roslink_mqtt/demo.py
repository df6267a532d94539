"""``make demo``: the whole system on this machine, in about 10 seconds.

Starts the embedded broker, the simulated robot and the bridge as real
processes (DDS kept on loopback, a fresh ROS domain), then plays a short
scene with plain MQTT clients: a viewer watches live ROSLink messages, an
operator drives the robot, a malformed command is refused, a ROS service is
called over MQTT, an action goal reports its progress, and the operator's silence triggers the dead-man stop.

``--dashboard`` (``make dashboard``) also serves the web dashboard and keeps everything running until
Ctrl-C, so a browser can log in and drive the simulated robot; everything stops cleanly either way.
"""

from __future__ import annotations

import argparse
import os
import queue
import signal
import sys
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

import orjson
import paho.mqtt.client as mqtt

from .config import load_fleet
from .demo_vda5050 import run_scene
from .fastdds_shm import remove_zombie_segments
from .localproc import ChildExited, LocalProcess, can_listen, free_port, listener_of, start_child, tail
from .mqtt import make_client
from .presence import operator_heartbeat
from .protocol import MessageId, ProtocolError, decode
from .protocol.control import CallReply, CallRequest, ErrorReport
from .protocol.goals import GoalRequest
from .protocol.params import ParamRequest
from .ros_env import domains_in_use, local_ros_env
from .topics import Kind, TopicTree, Verb

if TYPE_CHECKING:
    from .dashboard import DashboardServer

DEMO_PASSWORDS = {"turtle1": "turtle1-demo", "alice": "alice-demo", "bob": "bob-demo"}


class Scene:
    """Plain MQTT clients (no SDK needed): what any Node-RED flow or phone app would do."""

    def __init__(self, port: int, topics: TopicTree) -> None:
        self.topics = topics
        self.inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self.viewer = self._client("bob", "demo-viewer", port)
        self.viewer.on_message = lambda c, u, m: self.inbox.put((m.topic, bytes(m.payload)))
        self.viewer.connect("127.0.0.1", port)
        self.viewer.loop_start()
        self.viewer.subscribe([(topics.heartbeat("turtle1"), 1), (topics.all_state("turtle1"), 0)])
        self.operator = self._client("alice", "demo-alice", port)
        self.operator.will_set(topics.operator("alice", "demo-alice"), b"", qos=1, retain=True)
        self.replies: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self.operator.on_message = lambda c, u, m: self.replies.put((m.topic, bytes(m.payload)))
        self.operator.connect("127.0.0.1", port)
        self.operator.loop_start()
        # errors and service replies only (to/alice/ also carries the retained access report)
        self.operator.subscribe([(topics.error("turtle1", "alice"), 1),
                                 *((topics.verb_filter("turtle1", "alice", verb), 1)
                                   for verb in (Verb.REPLY, Verb.GOAL_STATUS, Verb.FEEDBACK, Verb.RESULT,
                                                Verb.PARAM_REPLY))])

    @staticmethod
    def _client(user: str, client_id: str, port: int) -> mqtt.Client:
        return make_client(client_id, username=user, password=DEMO_PASSWORDS[user], url=f"mqtt://127.0.0.1:{port}")

    def beat(self) -> None:
        self.operator.publish(self.topics.operator("alice", "demo-alice"), operator_heartbeat("alice", "demo-alice"),
                              qos=1, retain=True)

    def watch(self, seconds: float, show: set[str], *, until_shown: bool = False) -> dict[str, dict[str, Any]]:
        """Print the state messages named in ``show`` for ``seconds`` (or, ``until_shown``, until each has been
        printed once); return the latest of each."""
        latest: dict[str, dict[str, Any]] = {}
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0 and not (until_shown and not show):
            try:
                topic, payload = self.inbox.get(timeout=left)
            except queue.Empty:
                break
            parsed = self.topics.parse(topic)
            assert parsed is not None  # the viewer subscribed to this tree's heartbeat and state topics only
            name = parsed.name if parsed.kind is Kind.STATE else parsed.kind.value  # "heartbeat"
            assert name is not None  # a state topic names its state
            try:
                env = decode(payload)
            except ProtocolError:
                continue  # not a ROSLink message: the robot description, parameter events (shown elsewhere)
            latest[name] = env.payload
            if name in show:
                print(f"  bob sees {topic}: {_summary(name, env.payload)}")
                show.discard(name)
        return latest

    def newest(self, name: str, settle: float = 0.5) -> dict[str, Any]:
        """Print the newest ``name`` message seen within ``settle`` s: the queue still holds older ones."""
        newest = self.watch(settle, set()).get(name) or {}
        if newest:
            print(f"  bob sees {self.topics.state('turtle1', name)}: {_summary(name, newest)}")
        return newest

    def reply(self, timeout: float = 5.0) -> tuple[str, bytes]:
        """The next error report or service reply for alice: its topic and its body as sent."""
        return self.replies.get(timeout=timeout)

    def close(self) -> None:
        self.operator.publish(self.topics.operator("alice", "demo-alice"), b"", qos=1, retain=True)
        for c in (self.operator, self.viewer):
            c.disconnect()
            c.loop_stop()


def _summary(name: str, p: dict[str, Any]) -> str:
    if name == "heartbeat":
        status = {4: "ACTIVE", 6: "EMERGENCY", 8: "OFFLINE"}.get(p["system_status"], p["system_status"])
        return f"{p['name']} {status} session={p['session']}"
    if name == "global_motion":
        return f"x={p['x']:+.2f} y={p['y']:+.2f} yaw={p['yaw']:+.2f} vx={p['vx']:.2f} wz={p['wz']:.2f}"
    if name == "robot_status":
        return f"battery {p['battery_remaining']:.1f}% {p['voltage_battery']:.2f} V"
    if name == "range_finder_data":
        hits = [r for r in p["ranges"] if r is not None]
        return f"{len(p['ranges'])} beams, nearest wall {min(hits):.2f} m" if hits else "no returns"
    if name == "gps_raw_info":
        return f"fix {p['fix_type']} lat {p['lat']:.6f} lon {p['lon']:.6f}"
    if name == "ack":
        return f"ack result={p['result']} '{p['text']}'"
    return orjson.dumps(p).decode()[:100]


class Terminated(Exception):
    """SIGTERM (a ``kill``, ``make`` passing one on) or SIGHUP (the terminal closed): stop everything, like Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class ChildDied(Exception):
    """One of the demo's processes exited while the scene ran."""


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    raise Terminated(signum)


def _exit_status(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class ChildWatch:
    """Watches the demo's processes from a thread; the first that exits interrupts the scene in the main thread.

    Without it a dead bridge shows only as replies that never come ("(no result seen)") while the
    demo says all is well. SIGUSR1 to the main thread wakes whatever it blocks in; its handler raises
    :class:`ChildDied` with the child's name, how it ended and the end of its log.
    """

    POLL_S = 0.2

    def __init__(self) -> None:
        self.children: dict[str, LocalProcess] = {}
        self.death: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="demo-child-watch", daemon=True)

    def add(self, name: str, child: LocalProcess) -> None:
        self.children[name] = child

    def start(self) -> ChildWatch:
        signal.signal(signal.SIGUSR1, self._raise)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Called before the children are stopped on purpose: their exit is then no news."""
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(self.POLL_S):
            for name, child in self.children.items():
                code = child.poll()
                if code is not None and not self._stop.is_set():
                    self.death = (f"the {name} exited ({_exit_status(code)}) while the scene ran; the end of "
                                  f"{child.log}:\n{tail(child.log)}")
                    signal.pthread_kill(threading.main_thread().ident or 0, signal.SIGUSR1)
                    return

    def _raise(self, signum: int, frame: FrameType | None) -> None:
        if self.death is not None:
            raise ChildDied(self.death)


def _pick_port(wanted: int, what: str) -> int:
    """``wanted`` when free; otherwise another port, saying plainly who holds ``wanted``."""
    if can_listen(wanted):  # as the broker binds: a port in TIME_WAIT after the last demo is free
        return wanted
    port = free_port()
    holder = listener_of(wanted) or "a process this user cannot see"
    print(f"demo: port {wanted} ({what}) is taken by {holder}\n"
          f"      an earlier demo still running? This demo uses port {port} instead: commands that name "
          f"127.0.0.1:{wanted} reach the other one.", flush=True)
    return port


def main(argv: list[str] | None = None) -> int:
    """Run the demo; stop every process it started on return, Ctrl-C, SIGTERM, SIGHUP or a child's death."""
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _raise_terminated)
    try:
        return _run(argv)
    except KeyboardInterrupt:
        print("\ndemo: interrupted; everything it started is stopped.", flush=True)
        return 130
    except Terminated as e:
        print(f"\ndemo: {e} received; everything it started is stopped.", flush=True)
        return 128 + e.signum
    except ChildDied as e:
        print(f"demo: {e}\ndemo: stopped the other processes.", file=sys.stderr, flush=True)
        return 1


def _domain_id(text: str) -> int:
    """A ROS domain id as DDS on Linux takes it: 0..232 (101 and below are safe everywhere)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 <= value <= 232:
        raise argparse.ArgumentTypeError(f"{value} is not a ROS domain id (0..232)")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Run the roslink-mqtt demo on this machine.")
    parser.add_argument("--config", help="the fleet (default: config/robots.yaml; with --vda5050 "
                                         "examples/vda5050/robots.yaml)")
    parser.add_argument("--vda5050", action="store_true",
                        help="play the VDA 5050 scene (make vda5050): a master control drives turtle1 through an order")
    parser.add_argument("--logs", default="run/demo",
                        help="where the processes' logs go (and the robot's failsafe snapshots, in snapshots/)")
    parser.add_argument("--dashboard", action="store_true",
                        help="serve the web dashboard too and keep everything running until Ctrl-C")
    parser.add_argument("--dashboard-port", type=int, default=8090, help="0: any free port (default %(default)s)")
    parser.add_argument("--ros-domain-id", type=_domain_id, metavar="N",
                        help="the ROS domain of the simulated robot and its bridge (default: one that no ROS process "
                             "on this machine uses)")
    return parser


def _run(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    args.config = args.config or ("examples/vda5050/robots.yaml" if args.vda5050 else "config/robots.yaml")
    fleet = load_fleet(args.config)
    topics = fleet.topics
    logs = Path(args.logs)
    logs.mkdir(parents=True, exist_ok=True)
    port = _pick_port(fleet.broker.port, "the fleet's MQTT port, the one the README's commands use")
    ws_port = _pick_port(fleet.broker.ws_port, "the fleet's MQTT-over-WebSocket port") if fleet.broker.ws_port \
        else free_port()
    remove_zombie_segments()  # a killed earlier run must not leave this one stale DDS state
    env = local_ros_env(args.ros_domain_id)
    chosen = "unused on this machine" if args.ros_domain_id is None else "as asked"
    print(f"roslink-mqtt demo — broker on 127.0.0.1:{port}, ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']} ({chosen}; DDS on "
          f"loopback), logs in {logs}/")
    if args.ros_domain_id is not None and args.ros_domain_id in domains_in_use():
        print(f"demo: ROS domain {args.ros_domain_id} is in use by another ROS graph on this machine: its nodes and "
              "the demo's see each other", file=sys.stderr, flush=True)
    with ExitStack() as stack:
        def start(name: str, cmd: list[str], extra_env: dict[str, str] | None = None,
                  port: int | None = None) -> LocalProcess:
            """Start ``python cmd…``; stopped (SIGINT, then SIGKILL) when the stack closes, whatever happens."""
            try:
                return start_child(stack, [sys.executable, *cmd], logs / f"{name}.log",
                                   {**env, **(extra_env or {}), "PYTHONUNBUFFERED": "1"}, port=port,
                                   what=f"the {name}")
            except (ChildExited, TimeoutError) as e:
                raise SystemExit(f"demo: {e}") from None

        broker = start("broker", ["-m", "roslink_mqtt.broker", "--config", args.config, "--host", "127.0.0.1",
                                  "--port", str(port), "--ws-port", str(ws_port)], port=port)
        print(f"1. embedded broker up (authentication + ROSLink-key ACLs; MQTT over WebSocket on {ws_port})")
        dashboard = _start_dashboard(stack, args.dashboard_port, ws_port, fleet.prefix) if args.dashboard else None
        watch = ChildWatch()
        watch.add("broker", broker)
        watch.add("sim", start("sim", ["-m", "roslink_mqtt.sim"]))
        watch.add("bridge", start("bridge", ["-m", "roslink_mqtt.bridge.main", "--config", args.config, "--robot",
                                             "turtle1", "--url", f"mqtt://127.0.0.1:{port}"],
                                  # the demo's files stay in its folder: failsafe snapshots in <logs>/snapshots,
                                  # the disk buffer in <logs> (as systemd's StateDirectory= gives a service)
                                  {"ROSLINK_PASSWORD": "turtle1-demo", "STATE_DIRECTORY": str(logs.resolve())}))
        stack.callback(watch.stop)  # before the children are stopped (the stack unwinds in reverse)
        watch.start()
        print("2. simulated robot and bridge for turtle1 started")
        if args.vda5050:
            code = run_scene(port, fleet)
            print("Done: stopping the bridge (it says OFFLINE first), robot and broker.")
            return code
        scene = Scene(port, topics)
        stack.callback(scene.close)
        if (code := _play(scene, topics)) != 0:
            return code
        if dashboard is None:
            print("Web dashboard: run `make dashboard` to keep this scene running and drive turtle1 from a browser.")
        else:
            _wait_for_ctrl_c(dashboard.url)
        print("Done: stopping the bridge (its offline heartbeat is retained), robot and broker.")
    return 0


def _play(scene: Scene, topics: TopicTree) -> int:
    """Steps 3 to 9: bob watches; alice drives, is refused, calls a service, sends a goal, sets a parameter and
    goes silent."""
    print(f"3. bob (viewer) subscribes to {topics.heartbeat('turtle1')} and {topics.state_filter('turtle1')} :")
    latest = scene.watch(8.0, {"heartbeat", "global_motion", "robot_status", "range_finder_data",
                               "gps_raw_info"}, until_shown=True)
    if "heartbeat" not in latest:
        print("  the robot did not come online; see the logs")
        return 1
    _drive(scene, topics, latest.get("global_motion", {}).get("x", 0.0))
    _call_reset(scene, topics)
    _goal(scene, topics)
    set_speed = _lower_speed(scene, topics)
    _dead_man(scene, topics, set_speed)
    return 0


def _drive(scene: Scene, topics: TopicTree, start_x: float) -> None:
    """Steps 4 and 5: alice drives for 2 s, then sends a malformed twist."""
    print("4. alice (operator) announces her presence and drives: lx=0.4 m/s, az=0.5 rad/s for 2 s")
    cmd = topics.command("turtle1", "alice", "twist")
    for seq in range(1, 21):
        if seq % 10 == 1:
            scene.beat()
        scene.operator.publish(cmd, orjson.dumps({"message_id": int(MessageId.TWIST), "sequence_number": seq,
                                                  "payload": {"lx": 0.4, "az": 0.5}}))
        time.sleep(0.1)
    motion = scene.newest("global_motion")
    print(f"  the robot moved {abs(motion.get('x', start_x) - start_x):.2f} m in x")
    print("5. alice sends a malformed twist {\"lx\": \"fast\"}:")
    scene.beat()
    scene.operator.publish(cmd, b'{"lx": "fast"}')
    topic, body = scene.reply()
    print(f"  {topic}: {ErrorReport.from_json(body).error}")


def _call_reset(scene: Scene, topics: TopicTree) -> None:
    """Step 6: the robot's ROS service over MQTT."""
    print("6. alice calls the robot's ROS service 'reset' over MQTT:")
    for attempt in range(10):
        scene.beat()
        scene.operator.publish(topics.call("turtle1", "alice", "reset"), CallRequest(id=attempt).to_json())
        topic, body = scene.reply()
        if topic == topics.reply("turtle1", "alice", "reset") and CallReply.from_json(body).result:
            break
        time.sleep(0.5)
    print(f"  {topic}: {body.decode()}")


def _goal(scene: Scene, topics: TopicTree) -> None:
    """Step 7: a goal to the robot's ROS action, its progress and result."""
    print("7. alice sends a goal to the robot's ROS action 'fibonacci' (order 6) and watches it progress:")
    scene.beat()
    scene.operator.publish(topics.goal("turtle1", "alice", "fibonacci"),
                           GoalRequest("demo-goal", {"order": 6}).to_json(), qos=1)
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        try:
            topic, body = scene.reply(timeout=deadline - time.monotonic())
        except queue.Empty:
            print("  (no result seen)")
            break
        parsed = topics.parse(topic)
        if parsed is None or parsed.name != "fibonacci":
            continue
        assert parsed.verb is not None  # a to/<user>/ topic: reply, goal status, feedback, result
        print(f"  {parsed.verb.value}: {body.decode()}")
        if parsed.verb is Verb.RESULT:
            break


def _lower_speed(scene: Scene, topics: TopicTree) -> str:
    """Step 8: a ROS parameter set over MQTT; the topic it was set on."""
    print("8. alice lowers the robot's top speed: parameter max_speed of ROS node sim_robot := 0.2, over MQTT")
    scene.beat()
    set_speed = topics.param("turtle1", "alice", "sim_robot")
    scene.operator.publish(set_speed, ParamRequest("demo-speed", "set", values={"max_speed": 0.2}).to_json(),
                           qos=1)
    try:
        while (answer := scene.reply(timeout=10))[0] != topics.user_topic("turtle1", "alice", Verb.PARAM_REPLY,
                                                                        "sim_robot"):
            pass
        print(f"  {answer[0]}: {answer[1].decode()}")
    except queue.Empty:
        print("  (no parameter reply seen)")
    return set_speed


def _dead_man(scene: Scene, topics: TopicTree, set_speed: str) -> None:
    """Step 9: alice drives again, then goes silent: the dead-man stops the robot; the speed goes back."""
    cmd = topics.command("turtle1", "alice", "twist")
    print("9. alice drives again at 0.3 m/s (the robot now tops out at 0.2), then goes silent: the dead-man "
          "stops the robot")
    for seq in range(21, 36):
        if seq % 10 == 1:
            scene.beat()  # presence lasts operator_timeout (1.5 s): keep it up while driving
        scene.operator.publish(cmd, orjson.dumps({"message_id": 100, "sequence_number": seq,
                                                  "payload": {"lx": 0.3}}))
        time.sleep(0.1)
    motion = scene.newest("global_motion", settle=0.2)
    if motion:
        print(f"  the robot drives at vx={motion.get('vx', 0.0):.2f} m/s")
    scene.beat()
    latest = scene.watch(2.0, {"ack"}, until_shown=True)
    if "ack" not in latest:
        print("  (no failsafe notice seen)")
    scene.operator.publish(set_speed, ParamRequest("demo-speed-back", "set", values={"max_speed": 1.0}).to_json(),
                           qos=1)


def _start_dashboard(stack: ExitStack, port: int, ws_port: int, prefix: str) -> DashboardServer:
    from .dashboard import DashboardServer, MqttJsMissing

    try:
        server = DashboardServer("127.0.0.1", port, ws_port=ws_port, prefix=prefix).start()
    except MqttJsMissing as e:
        raise SystemExit(f"demo: {e} (run `make install`)") from None
    except OSError as e:
        raise SystemExit(f"demo: the dashboard cannot listen on 127.0.0.1:{port}: {e}") from None
    stack.callback(server.stop)
    print(f"   web dashboard on {server.url} (log in as alice / alice-demo to drive, bob / bob-demo to watch)")
    return server


def _wait_for_ctrl_c(url: str) -> None:
    """Until Ctrl-C, SIGTERM or SIGHUP: each is the normal end of ``make dashboard``."""
    print(f"The scene keeps running: open {url} — Ctrl-C stops everything.", flush=True)
    try:
        while True:
            time.sleep(3600)
    except (KeyboardInterrupt, Terminated):
        print()


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
