"""``roslink-mqtt-bridge``: run the bridge for one robot of the fleet.

    roslink-mqtt-bridge --config config/robots.yaml --robot turtle1 [--url mqtt://127.0.0.1:1883]
                        [--ros-args -r __ns:=/robot1 -r cmd_vel:=/base/cmd_vel]

The connection options are the ones every roslink-mqtt program takes (:mod:`roslink_mqtt.connection_options`):
the broker is ``--url``, else ``ROSLINK_URL``, else the config's ``bridge.broker``. The bridge logs in as its
robot; the robot's password comes from ``--password-file``, ``ROSLINK_PASSWORD``, the config's
``bridge.password_file`` or (demo only) ``bridge.password`` — never from the command line, where ``ps``
would show it. The old ``--broker`` and ``ROSLINK_MQTT_PASSWORD`` still work for one release and log a
deprecation line. SIGHUP re-reads the fleet file's users and grants (as the broker does); rule changes need
a restart.

A robot has one live bridge (bridge/core/claim.py): a bridge that finds another live one for its robot does not start
and exits with 3 (the systemd unit does not restart it); ``--take-over`` stops the other one instead. A bridge that
another one took over stops its robot and exits with 4. A refused login (wrong username or password) is logged and
retried slowly (5 s, doubling up to 60 s); with ``bridge.exit_on_refused_login: true`` the bridge exits with 5
instead (not restarted by the unit either).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from ..config.model import EXECUTORS
from ..connection_options import (
    ENV_PASSWORD,
    OLD_BRIDGE_PASSWORD_ENV,
    add_connection_options,
    read_password_file,
    resolve_ca_file,
    resolve_url,
)
from ..connection_options import resolve_password as resolve_login_password

if TYPE_CHECKING:
    from rclpy.node import Node

    from ..config import Fleet, Robot
    from ..mqtt import BrokerUrl
    from .ros.node import Bridge

PROG = "roslink-mqtt-bridge"
ENV_EXECUTOR = "ROSLINK_EXECUTOR"


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                epilog="Everything after --ros-args goes to ROS (remapping, namespace, parameters).")
    p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    p.add_argument("--robot", default=None,
                   help="robot name in the fleet file (the bridge logs in as it); may be left out with a robot file "
                        "(`roslink-mqtt fleet split`) or a fleet of one robot")
    add_connection_options(p, username=False, default_url=None, url_fallback="else bridge.broker in the config")
    p.add_argument("--take-over", action="store_true",
                   help="if another bridge for this robot is live, make it stop the robot and exit, then start "
                        "(without this, a second bridge refuses to start)")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    p.add_argument("--executor", choices=EXECUTORS, default=None,
                   help=f"rclpy executor: 'events' (rclpy.experimental.EventsExecutor, C++: least CPU) or 'single' "
                        f"(SingleThreadedExecutor); default: ${ENV_EXECUTOR}, else bridge.executor in the config, "
                        f"else events")
    return p.parse_args(argv)


def make_executor(kind: str) -> Any:
    """One thread either way: every callback is short and nothing blocks in one (a provided service's call
    waits as a coroutine). rclpy 7.1's MultiThreadedExecutor stalled ~1 in 20 service replies by 0.2-0.8 s.

    The SingleThreadedExecutor rebuilds its wait set in Python at every wake-up: at the demo robot's rates
    that was most of the bridge's CPU (bench/bridge_cpu.py). The EventsExecutor dispatches from C++.
    """
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def resolve_password(args: argparse.Namespace, bridge_password: str | None, bridge_password_file: str | None,
                     config_dir: Path) -> str:
    """The shared order (``--password-file``, ``ROSLINK_PASSWORD``), then the fleet file's own settings.

    The config's ``password_file`` is relative to the config file, so a unit started from ``/`` finds it.
    """
    password = resolve_login_password(args, PROG, old_env=OLD_BRIDGE_PASSWORD_ENV)
    if password:
        return password
    if bridge_password_file:
        path = Path(bridge_password_file)
        return read_password_file(path if path.is_absolute() else config_dir / path, PROG)
    if bridge_password:
        return bridge_password
    raise SystemExit(f"{PROG}: no password for robot '{args.robot}': set {ENV_PASSWORD}, "
                     "--password-file or bridge.password_file in the config")


def reload_grants(bridge: Any, config: str) -> None:
    """SIGHUP: re-read the fleet file; a broken file keeps the running grants (and says why)."""
    from ..config import ConfigError, load_fleet

    try:
        fleet = load_fleet(config)
    except ConfigError as err:
        logging.getLogger("roslink_mqtt.bridge").error("reload failed, keeping the current grants: %s", err)
        return
    bridge.reload(fleet)


def reload_password(args: argparse.Namespace, robot: Any, password: str, bridge: Any) -> str:
    """SIGHUP: read the robot's password again (a password file: rotation); a new one is used from the next
    connection on, and nothing is dropped now. The password in use."""
    try:
        fresh = resolve_password(args, robot.bridge.password, robot.bridge.password_file,
                                 Path(args.config).resolve().parent)
    except SystemExit as err:  # the file is gone or empty: keep the one that works
        logging.getLogger("roslink_mqtt.bridge").error("reload: keeping the robot's password: %s", err)
        return password
    if fresh != password:
        logging.getLogger("roslink_mqtt.bridge").info("reload: the robot's password changed; the next connection "
                                                      "uses it (the current ones stay)")
        bridge.set_password(fresh)
    return fresh


class StartCheck(threading.Thread):
    """The one-bridge check (bridge/core/claim.py), run while ROS starts: it needs the broker, not ROS."""

    def __init__(self, robot: Any, urls: Sequence[BrokerUrl], password: str, ca_file: str | None, take_over: bool,
                 topic: str, announce_topic: str) -> None:
        super().__init__(name="claim-check", daemon=True)
        from .core.claim import Claim

        self.robot, self.urls, self.password, self.ca_file = robot, urls, password, ca_file
        self.topic, self.announce_topic = topic, announce_topic
        self.claim = Claim.mine(take_over=take_over)
        self.result: Any = None

    def run(self) -> None:
        from .core.claim import StartCheck as Result
        from .core.claim import Verdict, announcement, check_claim, paho_connector

        robot = self.robot
        connect, close = paho_connector(self.urls, robot.name, self.password, self.ca_file, self.topic,
                                        self.announce_topic)
        try:
            self.result = check_claim(connect, robot.name, self.claim, robot.bridge.heartbeat_period,
                                      announce=announcement(self.claim))
        except Exception as err:  # the check must never keep a robot without its bridge
            self.result = Result(Verdict.START, note=f"could not check for another bridge ({err})")
        finally:
            close()


def without_ros_args(argv: list[str]) -> list[str]:
    """``argv`` without its ROS arguments (``--ros-args … [--]``, as rclpy's ``remove_ros_args`` reads them): here,
    so that the one-bridge check starts before rclpy is even imported."""
    out, inside = [], False
    for arg in argv:
        if arg == "--ros-args":
            inside = True
        elif inside and arg == "--":
            inside = False
        elif not inside:
            out.append(arg)
    return out


@dataclass
class _Start:
    """What the command line and the fleet file say the bridge is to run."""

    fleet: Fleet
    robot: Robot
    urls: tuple[BrokerUrl, ...]
    password: str
    executor: str  # EXECUTORS


def _read_start(args: argparse.Namespace) -> _Start | int:
    """The robot, its brokers, password and executor; an exit code (the reason printed) when one is missing."""
    import importlib.util

    from ..config import ConfigError, load_fleet
    from ..mqtt import parse_broker_urls

    if importlib.util.find_spec("rclpy") is None:
        print(f"{PROG}: rclpy is not importable in this Python ({sys.executable}): install the ROS 2 Jazzy wheels "
              "(pip install 'roslink-mqtt[bridge]', Python 3.11) or source your ROS installation first (source "
              "/opt/ros/jazzy/setup.bash; under systemd, its PYTHONPATH, LD_LIBRARY_PATH and AMENT_PREFIX_PATH in "
              "the unit's environment file): bridge/README.md, 'ROS from apt'", file=sys.stderr)
        return 2
    try:
        fleet = load_fleet(args.config)
    except ConfigError as err:
        print(f"roslink-mqtt-bridge: {err}", file=sys.stderr)
        return 2
    if args.robot is None:
        args.robot = fleet.robot_file or (next(iter(fleet.robots)) if len(fleet.robots) == 1 else None)
        if args.robot is None:
            print(f"roslink-mqtt-bridge: which robot? --robot NAME (robots in {args.config}: "
                  f"{', '.join(fleet.robots)})", file=sys.stderr)
            return 2
    robot = fleet.robots.get(args.robot)
    if robot is None:
        print(f"roslink-mqtt-bridge: no robot '{args.robot}' in {args.config} "
              f"(robots: {', '.join(fleet.robots)})", file=sys.stderr)
        return 2
    try:
        urls = parse_broker_urls(resolve_url(args, PROG, default=robot.bridge.broker_url))
    except ValueError as err:
        print(f"roslink-mqtt-bridge: {err}", file=sys.stderr)
        return 2
    password = resolve_password(args, robot.bridge.password, robot.bridge.password_file,
                                Path(args.config).resolve().parent)
    kind = args.executor or os.environ.get(ENV_EXECUTOR) or robot.bridge.executor
    if kind not in EXECUTORS:
        print(f"roslink-mqtt-bridge: ${ENV_EXECUTOR}={kind!r} is not one of {', '.join(EXECUTORS)}", file=sys.stderr)
        return 2
    return _Start(fleet, robot, urls, password, kind)


def _make_bridge(args: argparse.Namespace, start: _Start, check: StartCheck,
                 stop: Callable[[], None]) -> tuple[Node, Node | None, Bridge]:
    """The bridge's nodes and the bridge itself (rclpy initialised); a bad rule ends the process (exit 2)."""
    import rclpy

    from .ros.node import Bridge
    from .ros.rules import RuleError

    robot = start.robot
    try:
        node = rclpy.create_node("roslink_mqtt_bridge")
        # Under the EventsExecutor, actions provided by MQTT clients get a node and a single-threaded executor
        # of their own (Bridge says why); the main node keeps the cheap one.
        action_node = rclpy.create_node("roslink_mqtt_bridge_actions") if start.executor == "events" else None
        bridge = Bridge(start.fleet, robot, node, password=start.password, broker_url=start.urls,
                        ca_file=resolve_ca_file(args), action_node=action_node, claim=check.claim,
                        on_fenced=stop, on_login_refused=stop)
    except RuleError as err:
        line = f":{err.rule.line}" if err.rule is not None and err.rule.line else ""
        print(f"roslink-mqtt-bridge: {args.config}{line} robots.{robot.name}.{err}", file=sys.stderr)
        rclpy.shutdown()
        _leave_before_start(2)
    return node, action_node, bridge


def _settle_start_check(check: StartCheck, stopping: threading.Event, robot: Robot, nodes: Sequence[Node | None],
                        bridge: Bridge) -> None:
    """Only now, with ROS set up meanwhile, does the bridge need the start check's answer: nothing has reached the
    broker or ROS's actuators yet. Another live bridge (or a stop meanwhile) ends the process here."""
    import rclpy

    from .core.claim import EXIT_DUPLICATE, Verdict

    while check.is_alive() and not stopping.is_set():  # a Ctrl-C need not wait for the check (a daemon thread)
        check.join(0.1)
    log = logging.getLogger("roslink_mqtt.bridge")
    if stopping.is_set() or check.result.verdict is Verdict.REFUSE:
        if stopping.is_set():
            log.info("stopped while starting: nothing was connected yet")
        else:
            print(f"roslink-mqtt-bridge: {check.result.refusal(robot.name)}", file=sys.stderr)
        for created in nodes:
            if created is not None:
                created.destroy_node()
        rclpy.shutdown()
        _leave_before_start(0 if stopping.is_set() else EXIT_DUPLICATE)
    if check.result.verdict is Verdict.REPLACE:
        log.warning("%s", check.result.note)
        bridge.take_over_claim()
    elif check.result.note:
        log.info("%s", check.result.note)


def _serve(args: argparse.Namespace, start: _Start, bridge: Bridge, spun: list[tuple[Any, Node, Any]],
           stopping: threading.Event, wake: threading.Event, reload_asked: threading.Event) -> None:
    """Spin the executors and run the bridge until a signal (SIGHUP: reload); then the clean shutdown: zero
    velocity and the offline heartbeat while ROS and MQTT still work, then ROS."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    def spin(executor: Any) -> None:
        # spin_once in a loop, not spin(): rclpy 7.1's EventsExecutor.spin() busy-waits (a full core with
        # nothing to do), while its spin_once(timeout) sleeps until an event or the timeout
        try:
            while rclpy.ok() and not stopping.is_set():
                executor.spin_once(timeout_sec=0.5)
        except ExternalShutdownException:
            pass
        finally:
            stopping.set()

    spinners = [threading.Thread(target=spin, args=(executor,), name=f"ros-executor-{i}", daemon=True)
                for i, (executor, _, _) in enumerate(spun)]
    for spinner in spinners:
        spinner.start()
    bridge.start()
    password = start.password
    try:
        while not stopping.is_set():
            wake.wait(0.5)
            wake.clear()
            if reload_asked.is_set() and not stopping.is_set():
                reload_asked.clear()
                reload_grants(bridge, args.config)
                password = reload_password(args, start.robot, password, bridge)
    finally:
        bridge.stop()  # zero velocity and the offline heartbeat while ROS and MQTT still work
        for executor, _, handoff in spun:
            handoff.executor = None  # nothing more is queued for an executor about to stop
            executor.shutdown(timeout_sec=2)
        for spinner in spinners:
            spinner.join(timeout=2)
        for _, spun_node, _ in spun:
            spun_node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        _ignore_executor_teardown()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    args = parse_args(without_ros_args(argv)[1:])
    logging.basicConfig(level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    # Ctrl-C or SIGTERM while the bridge starts (loading ROS takes seconds on a busy machine) ends the start
    # cleanly, once nothing half-made is left: no traceback from inside rclpy. From the main loop on, the same
    # flag makes the clean shutdown (zero velocity, offline heartbeat).
    stopping, wake, reload_asked = threading.Event(), threading.Event(), threading.Event()

    def on_signal(flag: threading.Event) -> None:
        flag.set()
        wake.set()

    signal.signal(signal.SIGINT, lambda *_: on_signal(stopping))
    signal.signal(signal.SIGTERM, lambda *_: on_signal(stopping))
    start = _read_start(args)
    if isinstance(start, int):
        return start
    from .core.claim import ANNOUNCE, EXIT_FENCED, EXIT_LOGIN_REFUSED

    if stopping.is_set():
        return 0  # stopped before anything was made
    robot, topics = start.robot, start.fleet.topics
    check = StartCheck(robot, start.urls, start.password, resolve_ca_file(args), args.take_over,
                       topics.heartbeat(robot.name), topics.state(robot.name, ANNOUNCE))
    check.start()  # meanwhile, rclpy loads and ROS starts
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    # We handle SIGINT/SIGTERM ourselves: rclpy's handler would invalidate the context before we
    # could publish the final zero velocity and the offline heartbeat.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node, action_node, bridge = _make_bridge(args, start, check, lambda: on_signal(stopping))
    _settle_start_check(check, stopping, robot, (node, action_node), bridge)
    spun = [(make_executor(start.executor), node, bridge.on_executor)]
    if action_node is not None:
        spun.append((make_executor("single"), action_node, bridge.action_on_executor))
    for executor, spun_node, handoff in spun:
        executor.add_node(spun_node)
        handoff.executor = executor
    signal.signal(signal.SIGHUP, lambda *_: on_signal(reload_asked))
    _serve(args, start, bridge, spun, stopping, wake, reload_asked)
    if bridge.login_refused is not None:
        return EXIT_LOGIN_REFUSED
    return EXIT_FENCED if bridge.fenced_by is not None else 0


def _ignore_executor_teardown() -> None:
    """From here on, an rclpy executor collected at the interpreter's exit whose guard condition rclpy's shutdown
    destroyed already is not reported as an error (it was printed as a traceback now and then, ``Executor.__del__``:
    "cannot use Destroyable because destruction was requested", and a README command's test failed on it in a
    clean-clone run). Everything else still reaches Python's own hook. Ending the process at once instead
    (``os._exit``) was tried: events a ``buffer: disk`` rule had kept were lost across a bridge restart."""
    default = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        where = getattr(unraisable.object, "__qualname__", "")
        if where == "Executor.__del__" and type(unraisable.exc_value).__name__ == "InvalidHandle":
            return
        default(unraisable)

    sys.unraisablehook = hook


def _leave_before_start(code: int) -> NoReturn:
    """End a bridge that was made but never started (refused: another live bridge has the robot; a rule ROS
    cannot serve) with ``code``, skipping the interpreter's teardown. What the bridge made meanwhile (rclpy's
    node, publishers and subscriptions, paho clients) is then torn down by garbage collection after rclpy has shut
    down, which crashed the process now and then (SIGSEGV instead of exit status 3, which the systemd unit and
    the tests rely on). Nothing of it reached the broker or ROS's actuators: there is nothing to finish."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
