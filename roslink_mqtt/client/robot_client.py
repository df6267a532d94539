"""``RobotClient``: watch and command robots, call and provide services — no ROS needed.

One object per login. It owns one MQTT connection with operator presence
(robots refuse commands without it), learns robots from their retained
heartbeats, and subscribes ``<prefix>/<robot>/to/<user>/#`` once per robot it
talks to, which carries service replies, requests to services we provide and
the robot's error reports. User callbacks run in the client's dispatcher
thread, never on the network thread, so they may call services synchronously.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import secrets
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from typing import Any

from ..mqtt import BrokerUrl
from ..protocol import ProtocolError, loads
from ..topics import DEFAULT_PREFIX, Kind, TopicTree, check_name
from .advertisements import Advertisements
from .calls import ServiceCalls, Values
from .commands import CommandStreams, command_leaf, roslink_command
from .connection import Connection
from .directory import DEFAULT_STALE_AFTER, RobotDirectory, RobotInfo
from .dispatch import CallbackQueue, DispatchThread, Scheduler
from .errors import CommandRefused, RobotError, ServiceError
from .providers import Handler, ProvidedService, ServiceProviders
from .subscriptions import StateItem, StateSubscription

log = logging.getLogger("roslink_mqtt.client")

DEFAULT_URL = "mqtt://127.0.0.1:1883"
DEFAULT_CALL_TIMEOUT = 10.0  # s; longer than the robot's own per-service timeout (5 s in the demo), so its reason wins
ENV_URL, ENV_USERNAME, ENV_PASSWORD = "ROSLINK_URL", "ROSLINK_USERNAME", "ROSLINK_PASSWORD"
ENV_CA_FILE = "ROSLINK_CA_FILE"


class RobotClient:
    """A connection to the fleet's broker as one user.

    ``url``, ``username`` and ``password`` default to the environment
    (``ROSLINK_URL``, ``ROSLINK_USERNAME``, ``ROSLINK_PASSWORD``, ``ROSLINK_CA_FILE``),
    then to the local demo broker. ``robots`` names robots to watch from the start;
    the client also tries the wildcard ``<prefix>/+/heartbeat`` (brokers that
    refuse it leave you with the named robots and those you talk to).
    """

    def __init__(self, username: str | None = None, password: str | None = None, *, url: str | BrokerUrl | None = None,
                 robots: Iterable[str] = (), client_id: str | None = None, presence: bool = True,
                 ca_file: str | None = None, insecure_tls: bool = False, prefix: str = DEFAULT_PREFIX,
                 keepalive: int = 5, stale_after: float = DEFAULT_STALE_AFTER,
                 on_error: Callable[[RobotError], None] | None = None,
                 callbacks: CallbackQueue | None = None) -> None:
        username = username or os.environ.get(ENV_USERNAME)
        if not username:
            raise ValueError(f"no username: pass username= or set {ENV_USERNAME}")
        self.username = check_name(username, "username")
        password = password if password is not None else os.environ.get(ENV_PASSWORD)
        self.topics = TopicTree(prefix)
        self.client_id = check_name(client_id or f"{username}-sdk-{secrets.token_hex(8)}", "client id")
        self.connection = Connection(username=username, password=password, url=url or os.environ.get(ENV_URL)
                                     or DEFAULT_URL, client_id=self.client_id, topics=self.topics, presence=presence,
                                     ca_file=ca_file or os.environ.get(ENV_CA_FILE), insecure_tls=insecure_tls,
                                     keepalive=keepalive)
        self.on_error = on_error
        self.recent_errors: collections.deque[RobotError] = collections.deque(maxlen=100)
        self.directory = RobotDirectory(stale_after)
        self.callbacks = callbacks or CallbackQueue()
        self._dispatcher = None if callbacks is not None else DispatchThread(self.callbacks, f"{self.client_id}-cb")
        self._scheduler = Scheduler(f"{self.client_id}-timers")
        self._streams = CommandStreams(self.topics, username)
        self._calls = ServiceCalls(self.connection, self._scheduler, self.topics, username)
        self._providers = ServiceProviders(self.connection, self.topics, username)
        self._advertisements = Advertisements(self.connection, self.topics, username)
        self._watched: set[str] = set()
        self._watch_lock = threading.Lock()
        self._initial_robots = [check_name(r, "robot") for r in robots]
        self._error_waiters: list[tuple[str, int | None, threading.Event, list[RobotError]]] = []
        self._waiters_lock = threading.Lock()
        self._logged_errors: dict[tuple[str, str], float] = {}
        self.wildcard_heartbeats: bool | None = None  # did the broker grant <prefix>/+/heartbeat?
        self._closed = False

    # -- lifecycle ----------------------------------------------------------------------
    def connect(self, timeout: float = 10.0) -> RobotClient:
        """Log in (ConnectError if refused), start presence, watch the named robots.

        A failed connect closes the client (its threads end); make a new one to retry.
        """
        try:
            self.connection.connect(timeout)
        except Exception:
            self.close()
            raise
        self.wildcard_heartbeats = self.connection.subscribe(self.topics.all_heartbeats(), self._on_heartbeat)
        if not self.wildcard_heartbeats:
            log.info("%s: broker refused %s; watching named robots only", self.client_id,
                     self.topics.all_heartbeats())
        for robot in self._initial_robots:
            self.watch(robot)
        return self

    def close(self) -> None:
        """Withdraw provided services, fail pending calls, clear presence, disconnect."""
        if self._closed:
            return
        self._closed = True
        if self.connection.connected.is_set():
            self._providers.withdraw_all()
            self._advertisements.withdraw_all()
        self._calls.fail_all("the client was closed")
        self.connection.close()
        self._scheduler.close()
        if self._dispatcher is not None:
            self._dispatcher.stop()

    def __enter__(self) -> RobotClient:
        return self.connect()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    async def __aenter__(self) -> RobotClient:
        await asyncio.to_thread(self.connect)
        return self

    async def __aexit__(self, *_exc: object) -> None:
        await asyncio.to_thread(self.close)

    @property
    def connected(self) -> bool:
        return self.connection.connected.is_set()

    # -- robots ---------------------------------------------------------------------------
    def watch(self, robot: str) -> None:
        """Follow ``robot``: its heartbeat, and our replies/requests/errors from it (idempotent)."""
        check_name(robot, "robot")
        with self._watch_lock:
            if robot in self._watched:
                return
            self._watched.add(robot)
        self.connection.subscribe(self.topics.heartbeat(robot), self._on_heartbeat)
        # one filter for replies, requests and error reports (TopicTree builds concrete topics only)
        self.connection.subscribe(f"{self.topics.robot_root(robot)}/to/{self.username}/#", self._on_to_user)

    def robots(self) -> dict[str, RobotInfo]:
        """Every robot whose heartbeat we have seen, by name (check ``.online``)."""
        return self.directory.snapshot()

    def robot(self, robot: str) -> RobotInfo | None:
        return self.directory.get(robot)

    def wait_for_robot(self, robot: str, timeout: float = 10.0) -> RobotInfo:
        """Block until ``robot`` is online; TimeoutError otherwise."""
        self.watch(robot)
        if not self.directory.wait(lambda robots: robot in robots and robots[robot].online, timeout):
            info = self.directory.get(robot)
            state = "never seen" if info is None else f"status {info.system_status!r}"
            raise TimeoutError(f"robot {robot} not online after {timeout:g} s ({state})")
        info = self.directory.get(robot)
        assert info is not None
        return info

    # -- state --------------------------------------------------------------------------
    def subscribe(self, robot: str, name: str, callback: Callable[[StateItem], None] | None = None, *,
                  maxsize: int = 100) -> StateSubscription:
        """Messages from ``<prefix>/<robot>/state/<name>`` (``name`` with or without ``state/``).

        ROSLink state arrives typed (``GlobalMotion``…), generic rules as dicts.
        With ``callback`` it runs in the dispatcher thread; without, iterate the
        returned subscription (``for``/``async for``/``get(timeout)``).
        """
        self.watch(robot)
        name = name.strip("/").removeprefix("state/")
        topic = self.topics.state(robot, name)
        sub = StateSubscription(robot, name, topic, callback, self.callbacks, maxsize,
                                on_close=lambda s: self.connection.unsubscribe(s.topic, s.deliver))
        self.connection.subscribe(topic, sub.deliver)
        return sub

    # -- commands -------------------------------------------------------------------------
    def command(self, robot: str, name: str, payload: dict[str, Any] | None = None, *, qos: int | None = None,
                check: float | None = None) -> int | None:
        """Send a command; returns its sequence number (None for generic rules).

        ``name`` is a ROSLink command (``"twist"``, ``"cmd/arm"``) or a generic
        rule's topic under ``from/<user>/``. ROSLink payloads are validated here
        (ProtocolError). With ``check=seconds`` the call waits that long for an
        error report about this command and raises CommandRefused if one comes;
        silence means accepted (robots do not acknowledge every command).
        """
        self.watch(robot)
        topic, data, seq = self._streams.build(robot, name, payload)
        if self.connection.presence is not None:
            self.connection.presence.start_commanding()  # from now on, our going away stops what we drive
        if qos is None:
            qos = 0 if roslink_command(command_leaf(name)) == "twist" else 1  # a velocity stream repeats itself
        if check is None:
            self.connection.publish(topic, data, qos=qos)
            return seq
        event, box = threading.Event(), []
        waiter = (topic, seq, event, box)
        with self._waiters_lock:
            self._error_waiters.append(waiter)
        try:
            self.connection.publish(topic, data, qos=qos)
            if event.wait(check):
                raise CommandRefused(box[0])
        finally:
            with self._waiters_lock:
                self._error_waiters.remove(waiter)
        return seq

    def twist(self, robot: str, lx: float = 0.0, ly: float = 0.0, lz: float = 0.0, ax: float = 0.0,
              ay: float = 0.0, az: float = 0.0, *, check: float | None = None) -> int | None:
        """Velocity command (m/s, rad/s); the robot clamps to its limits and stops if the stream goes silent."""
        return self.command(robot, "twist", {"lx": lx, "ly": ly, "lz": lz, "ax": ax, "ay": ay, "az": az},
                            check=check)

    def go_to_waypoint(self, robot: str, x: float, y: float, z: float = 0.0, frame_type: int = 0, *,
                       check: float | None = None) -> int | None:
        """Goal in the map frame (``frame_type`` 0), GPS (1: x=lat, y=lon, z=alt) or robot frame (2)."""
        return self.command(robot, "go_to_waypoint", {"frame_type": frame_type, "x": x, "y": y, "z": z},
                            check=check)

    def emergency_stop(self, robot: str, reason: str = "", *, check: float | None = None) -> int | None:
        """Stop now and refuse motion until an operator sends :meth:`arm`."""
        return self.command(robot, "emergency_stop", {"reason": reason}, check=check)

    def arm(self, robot: str, *, check: float | None = None) -> int | None:
        return self.command(robot, "arm", {}, check=check)

    def disarm(self, robot: str, *, check: float | None = None) -> int | None:
        return self.command(robot, "disarm", {}, check=check)

    # -- services ----------------------------------------------------------------------------
    def call_future(self, robot: str, service: str, args: dict[str, Any] | None = None,
                    timeout: float = DEFAULT_CALL_TIMEOUT) -> Future[Values]:
        """Start a call; the future holds the reply's values or a ServiceError."""
        reason = "the client was closed" if self._closed else None
        if reason is None:
            self.watch(robot)
            info = self.directory.get(robot)
            if info is not None and not info.online:
                reason = f"robot {robot} is offline"
        if reason is not None:
            future: Future[Values] = Future()
            future.set_exception(ServiceError(robot, service, reason))
            return future
        return self._calls.start(robot, service, args, timeout)

    def call(self, robot: str, service: str, args: dict[str, Any] | None = None,
             timeout: float = DEFAULT_CALL_TIMEOUT) -> Values:
        """Call a ROS service on ``robot``; returns the response fields or raises ServiceError/ServiceTimeout."""
        return self.call_future(robot, service, args, timeout).result()

    async def call_async(self, robot: str, service: str, args: dict[str, Any] | None = None,
                         timeout: float = DEFAULT_CALL_TIMEOUT) -> Values:
        """``await`` form of :meth:`call` (the network work happens off the event loop)."""
        if robot not in self._watched:
            await asyncio.to_thread(self.watch, robot)  # waits for SUBACKs: keep it off the loop
        return await asyncio.wrap_future(self.call_future(robot, service, args, timeout))

    def provide(self, robot: str, service: str, srv_type: str, handler: Handler, *, timeout: float = 5.0
                ) -> ProvidedService:
        """Offer a ROS service on ``robot``: ``handler(request_fields) -> response_fields``.

        The robot creates ROS service ``service`` of type ``srv_type`` (e.g.
        ``"std_srvs/srv/SetBool"``) while this client is alive; each ROS call
        runs ``handler`` in the dispatcher thread. Raising in the handler fails
        the ROS call with the exception text. Operators only.
        """
        self.watch(robot)
        return self._providers.provide(robot, service, srv_type, handler, self.callbacks, timeout)

    def advertise(self, robot: str, topic: str, ros_type: str) -> None:
        """Announce that we publish ``ros_type`` on the generic rule ``topic`` of ``robot``.

        Rules marked ``on_demand`` in the fleet file have a ROS publisher only while someone
        advertises them (or publishes on them): this creates it before the first message, and
        :meth:`unadvertise` (or closing, or dying) removes it. Harmless for other rules.
        """
        if self.connection.presence is None:
            raise ValueError("advertising needs operator presence: the robot keeps the ROS publisher only while "
                             "our presence heartbeat is live (create the client with presence=True)")
        self.watch(robot)
        self._advertisements.advertise(check_name(robot, "robot"), topic, ros_type)

    def unadvertise(self, robot: str, topic: str) -> None:
        """Undo one :meth:`advertise`; the last one for a topic withdraws it."""
        self._advertisements.withdraw(robot, topic)

    # -- network thread ------------------------------------------------------------------------
    def _on_heartbeat(self, topic: str, payload: bytes, _retained: bool) -> None:
        parsed = self.topics.parse(topic)
        if parsed is not None and parsed.kind is Kind.HEARTBEAT and parsed.robot:
            self.directory.update(parsed.robot, payload)

    def _on_to_user(self, topic: str, payload: bytes, _retained: bool) -> None:
        parsed = self.topics.parse(topic)
        if parsed is None or parsed.kind is not Kind.TO or parsed.user != self.username or not parsed.name:
            return
        robot, (kind, _, leaf) = parsed.robot or "", parsed.name.partition("/")
        if kind == "reply" and leaf:
            self._calls.on_reply(robot, leaf, payload)
        elif kind == "request" and leaf:
            self._providers.on_request(robot, leaf, payload)
        elif kind == "error" and not leaf:
            self._on_error(robot, payload)

    def _on_error(self, robot: str, payload: bytes) -> None:
        try:
            error = RobotError.from_json(robot, loads(payload))
        except ProtocolError:
            error = RobotError(robot, "", f"unreadable error report: {payload[:200]!r}")
        self.recent_errors.append(error)
        awaited = False
        with self._waiters_lock:
            for topic, seq, event, box in self._error_waiters:
                if error.topic == topic and (seq is None or error.sequence_number in (None, seq)):
                    box.append(error)
                    event.set()
                    awaited = True
        provider_error = self._providers.on_error(error)
        callback = self.on_error
        if callback is not None:
            self.callbacks.put(lambda: callback(error))
        elif not (provider_error or awaited):  # a check= caller raises it instead
            now = time.monotonic()
            key = (error.topic, error.error)
            if now - self._logged_errors.get(key, -1e9) > 5.0:  # a refused 10 Hz stream must not flood the log
                self._logged_errors[key] = now
                log.warning("%s refused %s: %s", robot, error.topic, error.error)
