"""``RobotClient``: watch and command robots, call and provide services — no ROS needed.

One object per login. It owns one MQTT connection with operator presence
(robots refuse commands without it), learns robots from their retained
heartbeats, and subscribes ``<prefix>/<robot>/to/<user>/#`` once per robot it
talks to, which carries service replies, requests to services we provide,
the robot's error reports and our access report. User callbacks run in the
client's dispatcher thread, never on the network thread, so they may call
services synchronously.

Nothing is dropped silently: a command or call on a client that is not
connected raises :class:`NotConnectedError` (it is not queued for later); an
emergency stop also waits for the broker's acknowledgement; what the broker's
ACL would drop without a word (a viewer's command, a call to a service the
user may not call) is refused at the call site from the robot's access report;
a login the broker refuses on reconnect ends the retries and raises
:class:`LoginRefused` from then on.
"""

from __future__ import annotations

import asyncio
import collections
import dataclasses
import difflib
import logging
import secrets
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future
from contextlib import ExitStack
from pathlib import Path
from typing import Any, cast

import paho.mqtt.client as mqtt

# The connection vocabulary (names, defaults, environment) is shared with the bridge, the CLI and the examples.
from ..authorize import refusal
from ..config.model import Role
from ..connection_options import (
    DEFAULT_URL,
    ENV_USERNAME,
    env_ca_file,
    env_password,
    env_url,
    env_username,
)
from ..mqtt import LOGIN_WAIT, BrokerUrl, acknowledged
from ..protocol import ProtocolError, SystemStatus
from ..protocol.control import AccessReport
from ..protocol.description import DESCRIPTION, RobotDescription
from ..protocol.lease import ControlState
from ..protocol.link import LINK, LinkReport
from ..protocol.rosout import MAX_MSG as MAX_LOG_MSG
from ..protocol.rosout import LogLine
from ..protocol.video import VideoFrame
from ..topics import DEFAULT_PREFIX, Kind, TopicTree, Verb, check_name, state_name
from .action_servers import ActionServers, Execute, GoalCallback, ServedAction
from .advertisements import Advertisements
from .calls import ServiceCalls, Values
from .commands import CommandStreams, command_leaf, roslink_command
from .connection import Connection
from .control import StopReport
from .directory import DEFAULT_STALE_AFTER, RobotDirectory, RobotInfo
from .dispatch import CallbackQueue, DispatchThread, Scheduler
from .encodings import ENCODINGS
from .errors import (
    CommandNotConfirmed,
    CommandRefused,
    InvalidArgument,
    LoginRefused,
    NotConnectedError,
    NotGranted,
    RobotError,
    RobotNotice,
    RoslinkError,
    ServiceError,
    SnapshotError,
    WaitTimeout,
)
from .goals import ActionGoals, FeedbackCallback, GoalHandle
from .params import ParameterRequests
from .providers import Handler, ProvidedService, ServiceProviders
from .results import ParameterDescription, ParameterValue, SetResult
from .snapshots import Snapshot, SnapshotTransfers
from .subscriptions import StateItem, StateSubscription
from .video import VideoSubscription
from .waiters import ErrorWaiters

log = logging.getLogger("roslink_mqtt.client")

DEFAULT_CALL_TIMEOUT = 10.0  # s; longer than the robot's own per-service timeout (5 s in the demo), so its reason wins
DEFAULT_STOP_CONFIRM = 2.0  # s an emergency stop waits for the broker's PUBACK before raising CommandNotConfirmed
TYPO_WAIT = 1.0  # s a robot never seen is waited for when one we see online has a close name: then "did you mean"
ACCESS_WAIT = 0.5  # s after subscribing to a robot's to/<user>/# that a first command waits for the access report


class RobotClient:
    """A connection to the fleet's broker as one user.

    ``url`` is one broker, or a cluster's nodes (comma-separated or a list): a lost connection moves on to the
    next node. ``url``, ``username`` and ``password`` default to the environment
    (``ROSLINK_URL``, ``ROSLINK_USERNAME``, ``ROSLINK_PASSWORD``, ``ROSLINK_CA_FILE``),
    then to the local demo broker. ``robots`` names robots to watch from the start;
    the client also tries the wildcard ``<prefix>/+/heartbeat`` (brokers that
    refuse it leave you with the named robots and those you talk to).
    """

    def __init__(self, username: str | None = None, password: str | None = None, *,
                 url: str | BrokerUrl | Sequence[str] | None = None,
                 robots: Iterable[str] = (), client_id: str | None = None, presence: bool = True,
                 ca_file: str | None = None, insecure_tls: bool = False, prefix: str = DEFAULT_PREFIX,
                 keepalive: int = 5, stale_after: float = DEFAULT_STALE_AFTER,
                 on_error: Callable[[RobotError], None] | None = None,
                 callbacks: CallbackQueue | None = None) -> None:
        username = username or env_username()
        if not username:
            raise InvalidArgument(f"no username: pass username= or set {ENV_USERNAME}")
        self.username = check_name(username, "username")
        password = password if password is not None else env_password()
        self.topics = TopicTree(prefix)
        self.client_id = check_name(client_id or f"{username}-sdk-{secrets.token_hex(8)}", "client id")
        self.connection = Connection(username=username, password=password, url=url or env_url() or DEFAULT_URL,
                                     client_id=self.client_id, topics=self.topics, presence=presence,
                                     ca_file=ca_file or env_ca_file(), insecure_tls=insecure_tls,
                                     keepalive=keepalive)
        self.on_error = on_error
        # Reports about other programs of this user are ignored, unless a dashboard asks for every one of them.
        self.all_errors = False
        self.recent_errors: collections.deque[RobotError] = collections.deque(maxlen=100)
        # what robots carried out, but changed (a clamped twist): handed to on_notice, or logged as a warning
        self.on_notice: Callable[[RobotNotice], None] | None = None
        self.recent_notices: collections.deque[RobotNotice] = collections.deque(maxlen=100)
        self.directory = RobotDirectory(stale_after)
        self.callbacks = callbacks or CallbackQueue()
        self._dispatcher = None if callbacks is not None else DispatchThread(self.callbacks, f"{self.client_id}-cb")
        self._scheduler = Scheduler(f"{self.client_id}-timers")
        self._streams = CommandStreams(self.topics, username, client_id=self.client_id)
        self._calls = ServiceCalls(self.connection, self._scheduler, self.topics, username, client_id=self.client_id)
        self._providers = ServiceProviders(self.connection, self.topics, username)
        self._goals = ActionGoals(self.connection, self.callbacks, self.topics, username, client_id=self.client_id)
        self._action_servers = ActionServers(self.connection, self.topics, username)
        self._params = ParameterRequests(self.connection, self._scheduler, self.topics, username,
                                         client_id=self.client_id)
        self._advertisements = Advertisements(self.connection, self.topics, username)
        self._snapshots = SnapshotTransfers(self.connection, self.topics, username, client_id=self.client_id)
        # robot, node, payload of a ROS client's set of our SDK node's parameters (set by Node; network thread)
        self.on_param_set: Callable[[str, str, bytes], None] | None = None
        self._watched: set[str] = set()
        self._watch_lock = threading.Lock()
        self._initial_robots = [check_name(r, "robot") for r in robots]
        self._errors = ErrorWaiters()  # callers waiting for a refusal (check=, control requests)
        self._logged_errors: dict[tuple[str, str], float] = {}
        self.wildcard_heartbeats: bool | None = None  # did the broker grant <prefix>/+/heartbeat?
        self._closed = False
        # What the broker lets us do per robot (retained access reports), and when we subscribed to them.
        self._access: dict[str, AccessReport] = {}
        self._access_asked: dict[str, float] = {}
        self._no_grant: set[str] = set()  # robots whose to/<user>/# the broker refused to let us read
        self._granted: set[str] = set()  # robots it let us read at some point (a later refusal: grant removed)
        self._user_filters: dict[str, str] = {}  # our to/<user>/# filter → its robot
        self._settling: set[str] = set()  # robots whose to/<user>/# awaits its SUBACK after a reconnect
        self._unheard: set[str] = set()  # robots whose (retained) heartbeat has not come since that reconnect
        self._reconnected_at: float | None = None
        self._access_changed = threading.Condition()
        self._subscriptions: list[StateSubscription] = []
        self.connection.on_failure.append(self._on_login_refused)
        self.connection.on_suback.append(self._on_suback)
        self.connection.on_connected.append(self._on_reconnected)

    # -- lifecycle ----------------------------------------------------------------------
    def connect(self, timeout: float = LOGIN_WAIT) -> RobotClient:
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
            self._action_servers.withdraw_all()
            self._advertisements.withdraw_all()
        self._calls.fail_all("the client was closed")
        self._goals.fail_all("the client was closed")
        self._params.fail_all("the client was closed")
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

    @property
    def login_refused(self) -> LoginRefused | None:
        """Why the broker refused our login on a reconnect (the client then stopped retrying), else None."""
        return self.connection.failure

    def access(self, robot: str) -> AccessReport | None:
        """What the broker lets us do on ``robot`` (``.role``, ``.services``), from its bridge; None if unknown."""
        with self._access_changed:
            return self._access.get(robot)

    def description(self, robot: str, timeout: float = 5.0) -> RobotDescription:
        """What ``robot`` maps (a :class:`~roslink_mqtt.protocol.description.RobotDescription`): its state,
        commands, services and actions, each marked with who may use it, and the field layout of every ROS type.

        Read from the bridge's retained ``state/description``; WaitTimeout when none comes within ``timeout``
        (robot never connected, or an older bridge), SubscriptionFailed when the broker refuses to let us read it.
        """
        payload = self._retained(robot, DESCRIPTION, "description", timeout)
        if payload is None:
            raise WaitTimeout(f"no description of {robot} within {timeout:g} s (is its bridge connected, and "
                              "recent enough to publish one?)")
        return RobotDescription.from_json(payload)

    def _unknown_state(self, robot: str, name: str, timeout: float = 1.0) -> str | None:
        """Why ``robot`` will never send ``state/<name>`` (with the closest names it has), or None.

        Decided from the robot's description when it is at hand: the robot is online, so its bridge's retained
        description arrives with the subscription. Otherwise (an offline robot, an older bridge) None: the name
        may yet come. A typo used to wait for ever.
        """
        info = self.robot(robot)
        if "+" in name or "#" in name or info is None or not info.online:
            return None
        try:
            description = self.description(robot, timeout)
        except RoslinkError:  # WaitTimeout, SubscriptionFailed, ProtocolError, NotConnectedError
            return None
        why: str | None = description.unknown_state(name)  # a RobotDescription's
        return why

    def link(self, robot: str, timeout: float = 2.0) -> LinkReport | None:
        """What ``robot``'s uplink carries (a :class:`~roslink_mqtt.protocol.link.LinkReport`: its measured rate,
        per state stream the rate offered and sent, how many were superseded), from the bridge's retained
        ``state/link``; None when none comes within ``timeout`` (an older bridge, or one not yet connected)."""
        payload = self._retained(robot, LINK, "link report", timeout)
        return None if payload is None else LinkReport.from_json(payload)

    # -- who drives (docs/protocol.md, "Control") ---------------------------------------------------
    def control(self, robot: str, timeout: float = 2.0) -> ControlState | None:
        """Who holds control of ``robot`` (a :class:`~roslink_mqtt.protocol.lease.ControlState`: ``holder``,
        ``since``, ``summary()`` says "driven by alice since 12:03:05"), from the bridge's retained
        ``state/control``; None when none comes within ``timeout``."""
        from .control import read_control

        return read_control(self._retained, robot, timeout)

    def claim_control(self, robot: str, *, take_over: bool = False, timeout: float = 2.0) -> ControlState:
        """Hold control of ``robot``: only the holder's commands move it (emergency stops excepted). Returns the new
        control state; CommandRefused says who holds it instead (``take_over=True`` takes it from them: the robot
        stops, and they are told). The lease ends when this client's presence does, or with
        :meth:`release_control`."""
        from ..protocol.lease import ControlOp
        from .control import request_control

        return request_control(self, robot, ControlOp.TAKE_OVER if take_over else ControlOp.CLAIM, timeout,
                               refusal=self.refusal, send=self._send, errors=self._errors)

    def release_control(self, robot: str, *, timeout: float = 2.0) -> ControlState:
        """Give control of ``robot`` back (CommandRefused when we do not hold it)."""
        from ..protocol.lease import ControlOp
        from .control import request_control

        return request_control(self, robot, ControlOp.RELEASE, timeout, refusal=self.refusal, send=self._send,
                               errors=self._errors)

    def emergency_stop_all(self, reason: str = "", *, robots: Iterable[str] | None = None,
                           timeout: float = 1.0) -> dict[str, StopReport]:
        """Stop every robot we may stop (``robots``: those named; default: every robot whose heartbeat we see) at
        once, and report per robot whether its bridge acknowledged the stop within ``timeout`` (a
        :class:`~roslink_mqtt.client.control.StopReport`: ``acknowledged``, ``seconds``, ``error``)."""
        from .control import stop_all

        names = sorted(robots) if robots is not None else sorted(self.robots())
        with self._access_changed:
            stoppable = [r for r in names if r not in self._access or self._access[r].estop]
        return stop_all(self, stoppable, reason, timeout)

    def _retained(self, robot: str, name: str, what: str, timeout: float) -> bytes | None:
        """The first non-empty message on ``state/<name>`` of ``robot`` within ``timeout`` (a retained snapshot)."""
        from .errors import SubscriptionFailed

        self.connection.require(f"{what} of {robot}", now=False)
        topic, box, arrived = self.topics.state(robot, name), [], threading.Event()

        def on_message(_topic: str, payload: bytes, _retained: bool) -> None:
            if payload and not arrived.is_set():
                box.append(payload)
                arrived.set()

        try:
            if not self.connection.subscribe(topic, on_message, timeout=timeout):
                raise SubscriptionFailed(f"the broker refused {topic} to {self.username} (is {robot} granted?)")
            arrived.wait(timeout)
        finally:
            self.connection.unsubscribe(topic, on_message)
        return box[0] if box else None

    # -- robots ---------------------------------------------------------------------------
    def watch(self, robot: str, *, timeout: float = 5.0) -> None:
        """Follow ``robot``: its heartbeat, and our replies/requests/errors from it (idempotent).

        Waits up to ``timeout`` s for each SUBACK (a reply must not beat its subscription).
        """
        check_name(robot, "robot")
        with self._watch_lock:
            if robot in self._watched:
                return
            self._watched.add(robot)
        self.connection.subscribe(self.topics.heartbeat(robot), self._on_heartbeat, timeout=timeout)
        # one filter for replies, requests, error and access reports (TopicTree builds concrete topics only)
        mine = self.topics.to_user_filter(robot, self.username)
        with self._access_changed:
            self._user_filters[mine] = robot
        granted = self.connection.subscribe(mine, self._on_to_user, timeout=timeout)
        with self._access_changed:
            if granted:
                self._granted.add(robot)
                self._access_asked[robot] = time.monotonic()  # its retained access report follows the SUBACK
            elif self.connection.connected.is_set() and mine not in self.connection.subscribed():
                self._no_grant.add(robot)  # refused (0x80): the embedded broker says we have no grant

    def robots(self) -> dict[str, RobotInfo]:
        """Every robot whose heartbeat we have seen, by name (check ``.online``)."""
        return self.directory.snapshot()

    def robot(self, robot: str) -> RobotInfo | None:
        return self.directory.get(robot)

    def wait_for_robot(self, robot: str, timeout: float = 10.0) -> RobotInfo:
        """Block until ``robot`` is online. NotGranted at once when the broker says we may not use it; TimeoutError
        otherwise, saying why as far as we can tell (a likely typo of a robot we see: within TYPO_WAIT s, with
        "did you mean"); NotConnectedError if we cannot be told."""
        self.connection.require(f"waiting for {robot}", now=False)
        self.watch(robot)
        started = time.monotonic()

        def decided(robots: dict[str, RobotInfo]) -> bool:
            if robot in self._no_grant:
                return True
            if robot in self._settling or robot in self._unheard:  # reconnected: is it still ours? (its SUBACK
                return False  # and its retained heartbeat say, within a round trip)
            if robot in robots and robots[robot].online:
                return True
            return robot not in robots and time.monotonic() - started >= TYPO_WAIT and bool(self._near(robot))

        self.directory.wait(decided, timeout)
        info = self.directory.get(robot)
        if robot not in self._no_grant and robot not in self._unheard and info is not None and info.online:
            return info
        raise self.not_online(robot, time.monotonic() - started)

    def _near(self, robot: str) -> list[str]:
        """Robots we have seen online whose names are close to ``robot`` (a typo's likely meaning)."""
        online = [name for name, info in self.directory.snapshot().items() if info.online and name != robot]
        return difflib.get_close_matches(robot, online, n=3, cutoff=0.6)

    def not_online(self, robot: str, waited: float) -> RoslinkError:
        """Why ``robot`` is not online for us, as one exception: the broker's refusal (NotGranted), or what we
        saw of it in ``waited`` s (WaitTimeout), with the robots whose names are close when we never saw it."""
        with self._access_changed:
            no_grant, removed = robot in self._no_grant, robot in self._granted
        info = self.directory.get(robot)
        near = self._near(robot) if info is None else []
        if no_grant and near and not removed:  # the embedded broker refuses a robot that does not exist too
            return NotGranted(f"no robot {robot} that {self.username} may use (the broker refused to let us read "
                              f"{self.topics.to_user_filter(robot, self.username)}); did you mean "
                              f"{' or '.join(near)}?")
        if no_grant:
            return NotGranted(self._grant_refusal(robot, removed))
        if robot in self._unheard and self._reconnected_at is not None:
            # a broker that only filters what it delivers (Mosquitto) says nothing of a removed grant: but a robot
            # that ran has a retained heartbeat, sent at once to whoever may read it
            return WaitTimeout(f"nothing from {robot} since reconnecting {time.monotonic() - self._reconnected_at:.1f}"
                               f" s ago, though it was online before: the broker no longer delivers it to "
                               f"{self.username}; was your grant to {robot} removed by the fleet? (ask its admin)")
        if info is not None:
            state = "offline" if info.system_status == SystemStatus.OFFLINE else "silent (its heartbeat is stale)"
            return WaitTimeout(f"robot {robot} is {state}: its bridge is not connected to the broker")
        if near:
            return WaitTimeout(f"no robot {robot} (never seen in {waited:.1f} s); did you mean "
                               f"{' or '.join(near)}?")
        return WaitTimeout(f"robot {robot} never seen in {waited:.1f} s: no heartbeat from it (is the name right, "
                           f"is its bridge running, and is it granted to {self.username}?)")

    def _grant_refusal(self, robot: str, removed: bool) -> str:
        mine = self.topics.to_user_filter(robot, self.username)
        if removed:
            return (f"your grant to {robot} was removed by the fleet: the broker no longer lets {self.username} "
                    f"read {mine} (ask the fleet's admin)")
        return f"user '{self.username}' has no grant on {robot}: the broker refused to let us read {mine}"

    def _on_reconnected(self) -> None:
        """A new connection (network thread): what the broker lets us read is asked again with every filter;
        until each robot's SUBACK answers, whether it is still ours is open (a grant may have gone meanwhile)."""
        if not self.connection.ever_connected:
            return
        with self._access_changed:
            self._settling = set(self._user_filters.values()) - self._no_grant
            # a robot seen before has a retained heartbeat (its last-will at least): it comes with the SUBACK
            self._unheard = {robot for robot in self._settling if self.directory.get(robot) is not None}
            self._reconnected_at = time.monotonic()

    def _on_suback(self, topic: str, granted: bool) -> None:
        """The broker answered one of our filters (network thread). A refused to/<user>/# of a robot means no
        grant — after a reconnect, one the fleet removed (its admin's `fleet apply` drops the connections it
        affects)."""
        with self._access_changed:
            robot = self._user_filters.get(topic)
            if robot is None:
                return
            self._settling.discard(robot)
            removed = False
            if not granted:
                self._no_grant.add(robot)
                self._access.pop(robot, None)
                removed = robot in self._granted
            self._access_changed.notify_all()
        self.directory.touch()  # wake wait_for_robot
        if removed:
            reason = self._grant_refusal(robot, removed=True)
            log.warning("%s: %s", self.client_id, reason)
            self._on_error(robot, RobotError(robot, topic, reason, client_id=self.client_id))

    # -- state --------------------------------------------------------------------------
    def subscribe(self, robot: str, name: str, callback: Callable[[StateItem], None] | None = None, *,
                  maxsize: int = 100, encoding: str | None = None) -> StateSubscription:
        """Messages from ``<prefix>/<robot>/state/<name>`` (``name`` with or without ``state/``).

        ROSLink state arrives typed (``GlobalMotion``…), generic rules as dicts: decoded from JSON, CBOR or a
        raw image as the rule's ``encoding`` says (:mod:`.encodings`; told from the payload unless
        ``encoding`` — ``json``, ``cbor``, ``raw``, what the description's entry says — is given).
        With ``callback`` it runs in the dispatcher thread; without, iterate the
        returned subscription (``for``/``async for``/``get(timeout)``).
        """
        self.watch(robot)
        name = state_name(name)
        topic = self.topics.state(robot, name)
        if encoding is not None and encoding not in ENCODINGS:
            raise InvalidArgument(f"encoding must be one of {', '.join(ENCODINGS)}, not {encoding!r}")
        if (why := self._unknown_state(robot, name)) is not None:
            raise InvalidArgument(why)
        sub = StateSubscription(robot, name, topic, callback, self.callbacks, maxsize,
                                on_close=self._unsubscribe_state, encoding=encoding)
        with self._watch_lock:
            self._subscriptions.append(sub)
        if self.connection.failure is not None:
            sub.fail(self.connection.failure)
        self.connection.subscribe(topic, sub.deliver)
        return sub

    def video(self, robot: str, stream: str, callback: Callable[[VideoFrame], None] | None = None, *,
              maxsize: int = 60) -> VideoSubscription:
        """Watch ``robot``'s video ``stream`` (its robot file's ``video:``; docs/video.md): frames as
        :class:`~roslink_mqtt.protocol.video.VideoFrame` (header and bitstream) until ``close()``.

        The robot encodes only while someone watches: the subscription renews its watch every few seconds and
        leaves when closed. With ``callback`` frames run in the dispatcher thread; without, iterate it or
        ``get(timeout)``. Decode with :class:`roslink_mqtt.video.decoder.VideoDecoder` (needs PyAV:
        ``pip install roslink-mqtt[video]``)."""
        self.connection.require(f"video of {robot}")
        self.watch(robot)
        if (why := self._unknown_state(robot, stream)) is not None:
            raise InvalidArgument(why)
        return VideoSubscription(self.connection, self._scheduler, self.callbacks, self.topics, self.username,
                                 self.client_id, robot, stream, callback, maxsize).start()

    def _unsubscribe_state(self, sub: StateSubscription) -> None:
        with self._watch_lock:
            if sub in self._subscriptions:
                self._subscriptions.remove(sub)
        self.connection.unsubscribe(sub.topic, sub.deliver)

    # -- commands -------------------------------------------------------------------------
    def command(self, robot: str, name: str, payload: dict[str, Any] | None = None, *, qos: int | None = None,
                check: float | None = None, confirm: float | None = None) -> int | None:
        """Send a command; returns its sequence number (None for generic rules).

        ``name`` is a ROSLink command (``"twist"``, ``"cmd/arm"``) or a generic
        rule's topic under ``from/<user>/``. ROSLink payloads are validated here
        (ProtocolError). Nothing is sent, and an exception says why, when the
        client is not connected (NotConnectedError, LoginRefused) or the robot's
        access report says the broker would drop it (CommandRefused: we are a
        viewer). With ``check=seconds`` the call waits that long for an error
        report about this command and raises CommandRefused if one comes;
        silence means accepted (robots do not acknowledge every command). With
        ``confirm=seconds`` (QoS 1) it waits for the broker's acknowledgement and
        raises CommandNotConfirmed without one.

        An emergency stop goes out before anything else, even before the client
        subscribes to the robot's reports (a broker that does not answer would
        hold it for the SUBACK timeouts); what would have refused it is checked
        right after, and raises then.
        """
        topic, data, seq = self._streams.build(robot, name, payload)
        leaf = command_leaf(name)
        self.connection.require(leaf)
        urgent = roslink_command(leaf) == "emergency_stop"
        if qos is None:
            qos = 0 if roslink_command(leaf) == "twist" else 1  # a velocity stream repeats itself
        deadline = None if confirm is None else time.monotonic() + confirm
        with ExitStack() as waiting:
            waiter = waiting.enter_context(self._errors.waiting(topic, seq)) if check is not None else None
            if urgent:
                info = self._send(topic, data, qos, leaf)
                self.watch(robot, timeout=ACCESS_WAIT)
                self._raise_if_refused(robot, topic, leaf)  # the broker dropped it: say so
            else:
                self.watch(robot)
                self._raise_if_refused(robot, topic, leaf)
                info = self._send(topic, data, qos, leaf)
            if deadline is not None and qos > 0:
                self._confirm(info, deadline, f"{leaf} to {robot}", confirm)
            refused = waiter.wait(check) if waiter is not None and check is not None else None
            if refused is not None:
                raise CommandRefused(refused)
        return seq

    def _raise_if_refused(self, robot: str, topic: str, leaf: str) -> None:
        why = self.refusal(robot, Verb.CMD, leaf)
        if why is not None:
            raise CommandRefused(RobotError(robot, topic, why, client_id=self.client_id))

    def _send(self, topic: str, data: bytes, qos: int, what: str) -> mqtt.MQTTMessageInfo:
        """Publish (presence says "commanding" first); a message paho could not even queue raises."""
        if self.connection.presence is not None:
            self.connection.presence.start_commanding()  # from now on, our going away stops what we drive
        info = self.connection.publish(topic, data, qos=qos)
        if info.rc == mqtt.MQTT_ERR_NO_CONN and qos == 0:  # the connection dropped just now: paho discarded it
            self.connection.require(what)
            raise NotConnectedError(f"{what} not sent: the connection to {self.connection.url} was lost")
        return info

    def _confirm(self, info: mqtt.MQTTMessageInfo, deadline: float, what: str, confirm: float | None) -> None:
        """Wait for the broker's PUBACK until ``deadline``; CommandNotConfirmed without one."""
        if self.connection.on_network_thread():
            return  # the network thread cannot wait for itself
        if not acknowledged(info, max(0.0, deadline - time.monotonic())):
            raise CommandNotConfirmed(f"{what}: the broker did not acknowledge it within {confirm:g} s; it may not "
                                      "have reached the robot (paho sends it again if the connection comes back)")

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

    def emergency_stop(self, robot: str, reason: str = "", *, check: float | None = None,
                       confirm: float = DEFAULT_STOP_CONFIRM) -> int | None:
        """Stop now and refuse motion until an operator sends :meth:`arm`.

        A stop is never lost silently: it raises NotConnectedError when the client is
        not connected, and CommandNotConfirmed when the broker does not acknowledge it
        within ``confirm`` seconds (QoS 1) — then stop the robot another way.
        """
        return self.command(robot, "emergency_stop", {"reason": reason}, check=check, confirm=confirm)

    def arm(self, robot: str, *, check: float | None = None) -> int | None:
        return self.command(robot, "arm", {}, check=check)

    def disarm(self, robot: str, *, check: float | None = None) -> int | None:
        return self.command(robot, "disarm", {}, check=check)

    # -- services ----------------------------------------------------------------------------
    def call_future(self, robot: str, service: str, args: dict[str, Any] | None = None,
                    timeout: float = DEFAULT_CALL_TIMEOUT) -> Future[Values]:
        """Start a call; the future holds the reply's values or a ServiceError.

        A call that cannot go out fails at once: NotConnectedError/LoginRefused when
        the client is not connected, ServiceError when the robot is offline or its
        access report says the broker would drop the call (not ours to call).
        """
        future: Future[Values] = Future()
        reason = "the client was closed" if self._closed else None
        if reason is None:
            try:
                self.connection.require(f"call to {service}")
            except RoslinkError as err:
                future.set_exception(err)
                return future
            self.watch(robot)
            info = self.directory.get(robot)
            if info is not None and not info.online:
                reason = f"robot {robot} is offline"
            else:
                reason = self.refusal(robot, Verb.CALL, service)
        if reason is not None:
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

    def send_goal(self, robot: str, action: str, goal: dict[str, Any] | None = None,
                  feedback_callback: FeedbackCallback | None = None, *, goal_id: str | None = None) -> GoalHandle:
        """Send a goal to the ROS action ``action`` of ``robot``; returns at once with a :class:`GoalHandle`.

        ``goal`` is the action's goal as a dict (``{"order": 5}`` for test_msgs/action/Fibonacci);
        ``feedback_callback(feedback_dict)`` runs in the dispatcher thread for each (rate-limited) feedback.
        ``handle.result(timeout)`` blocks for the end; ``handle.cancel()`` cancels. The robot cancels the goal
        itself if this program's operator presence ends (the client must run presence, as for commands).
        """
        self.connection.require(f"goal for {action}")
        self.watch(robot)
        handle = self._goals.send(robot, action, goal, feedback_callback, goal_id=goal_id)
        reason = self.refusal(robot, Verb.GOAL, action)
        if reason is not None:
            self._goals.on_error(RobotError(robot, self.topics.goal(robot, self.username, action), reason,
                                            client_id=self.client_id, request_id=handle.id))
        return handle

    async def send_goal_async(self, robot: str, action: str, goal: dict[str, Any] | None = None,
                              feedback_callback: FeedbackCallback | None = None, *,
                              goal_id: str | None = None) -> GoalHandle:
        """``await`` form of :meth:`send_goal`: returns once the goal is accepted (GoalError if not)."""
        handle = await asyncio.to_thread(self.send_goal, robot, action, goal, feedback_callback, goal_id=goal_id)
        await asyncio.wrap_future(handle.accepted_future)
        return handle

    def send_log(self, robot: str, node: str, level: int, msg: str, file: str = "", function: str = "",
                 line: int = 0) -> bool:
        """One log line for ``robot``'s ``/rosout`` as ROS node ``node`` (what a Node's logger calls).

        Never raises: a line is dropped (False) while disconnected, or when the robot's access report says we
        are not an operator (the robot would refuse it). Lines longer than the protocol allows are cut.
        """
        if not self.connection.connected.is_set():
            return False
        with self._access_changed:
            report = self._access.get(robot)
        if report is not None and not report.operator:
            return False
        if len(msg) > MAX_LOG_MSG:
            msg = msg[: MAX_LOG_MSG - 1] + "…"
        try:
            body = LogLine(level, msg, file[-512:], function[-256:], line, self.client_id)
            self.connection.publish(self.topics.log(robot, self.username, node), body.to_json(), qos=LogLine.QOS)
        except Exception:  # a log line must never break the program
            return False
        return True

    def serve_action(self, robot: str, action: str, action_type: str, execute: Execute, *,
                     goal_callback: GoalCallback | None = None, accept_timeout: float = 5.0,
                     result_timeout: float = 600.0) -> ServedAction:
        """Serve the ROS action ``action`` (type ``pkg/action/Type``) on ``robot`` from this program.

        While this client's presence is live the robot has a ROS action server ``action`` in its bridge's
        namespace. Each ROS goal runs ``execute(goal)`` in its own thread: ``goal.goal`` is the goal as a dict,
        ``goal.publish_feedback(dict)``, ``goal.is_cancel_requested`` / ``goal.wait_for_cancel(s)``; return the
        result fields (succeeded), call ``goal.canceled()`` or ``goal.abort(reason)`` first to end otherwise,
        or raise (aborted). ``goal_callback(goal_dict) -> bool`` may reject goals. Operators only.
        """
        self.connection.require(f"serving {action}", now=False)
        self.watch(robot)
        why = self.refusal(robot, Verb.PROVIDE_ACTION, action)
        if why is not None:
            raise CommandRefused(RobotError(robot, self.topics.user_topic(robot, self.username, Verb.PROVIDE_ACTION,
                                                                          action), why, client_id=self.client_id))
        return self._action_servers.serve(robot, action, action_type, execute, goal_callback=goal_callback,
                                          accept_timeout=accept_timeout, result_timeout=result_timeout)

    # -- parameters of the robot's ROS nodes -------------------------------------------------------------
    def _param(self, robot: str, node: str, op: str, timeout: float, **kwargs: Any) -> dict[str, Any]:
        self.connection.require(f"parameter {op} on {node}")
        self.watch(robot)
        return self._params.start(robot, node, op, timeout=timeout, **kwargs).result()

    def get_parameters(self, robot: str, node: str, names: list[str], *,
                       timeout: float = 10.0) -> dict[str, ParameterValue]:
        """``{name: value}`` of ``node``'s parameters (None: not declared); ParameterError if refused or silent."""
        return cast("dict[str, ParameterValue]", self._param(robot, node, "get", timeout, names=tuple(names)))

    def set_parameters(self, robot: str, node: str, values: dict[str, Any], *,
                       timeout: float = 10.0) -> dict[str, SetResult]:
        """Set parameters; ``{name: {"successful": bool, "reason": str}}`` as the node's own validation answered.

        A value of the wrong type (a string for a double…) raises ParameterError before anything is set.
        """
        return cast("dict[str, SetResult]", self._param(robot, node, "set", timeout, values=values))

    def list_parameters(self, robot: str, node: str, prefixes: list[str] | None = None, *,
                        timeout: float = 10.0) -> list[str]:
        return list(self._param(robot, node, "list", timeout, names=tuple(prefixes or ())).get("names", []))

    def describe_parameters(self, robot: str, node: str, names: list[str], *,
                            timeout: float = 10.0) -> dict[str, ParameterDescription]:
        """``{name: {"type", "description", "read_only", "dynamic_typing", ranges…}}``."""
        return cast("dict[str, ParameterDescription]",
                    self._param(robot, node, "describe", timeout, names=tuple(names)))

    def snapshot(self, robot: str, last: float = 30.0, *, path: str | Path | None = None, timeout: float = 300.0,
                 stall: float = 10.0, on_progress: Callable[[int, int], None] | None = None) -> Snapshot:
        """The last ``last`` seconds of ``robot``'s snapshot topics (its robot file's ``snapshot:``), as MCAP: the
        ROS messages as recorded on the robot (CDR, ``ros2msg`` schemas), what ``ros2 bag`` and Foxglove read.

        Sent in chunks at the robot's bulk priority; a transfer with no chunk for ``stall`` s is asked again from its
        first missing chunk (a reconnect lost some). Returns the :class:`~.snapshots.Snapshot` once every chunk is in
        and its SHA-256 matches (written to ``path`` too, when given); SnapshotError when the robot refuses (with its
        reason) or the file arrived damaged, WaitTimeout after ``timeout`` s. ``on_progress(chunks, of)`` runs as
        chunks arrive (in this thread)."""
        if not 0 < last <= 3600:
            raise InvalidArgument(f"last must be 0 < s <= 3600, not {last!r}")
        self.connection.require(f"snapshot of {robot}")
        self.watch(robot)
        why = self.refusal(robot, Verb.SNAPSHOT, "snapshot")  # the broker would drop it without a word
        if why is not None:
            raise SnapshotError(robot, "", why)
        got = self._snapshots.fetch(robot, last, timeout=timeout, stall=stall, on_progress=on_progress)
        if path is None:
            return got
        target = Path(path)
        partial = target.with_name(target.name + ".part")
        partial.write_bytes(got.data)
        partial.replace(target)
        return dataclasses.replace(got, path=target)

    def provide(self, robot: str, service: str, srv_type: str, handler: Handler, *, timeout: float = 5.0
                ) -> ProvidedService:
        """Offer a ROS service on ``robot``: ``handler(request_fields) -> response_fields``.

        The robot creates ROS service ``service`` of type ``srv_type`` (e.g.
        ``"std_srvs/srv/SetBool"``) while this client is alive; each ROS call
        runs ``handler`` in the dispatcher thread. Raising in the handler fails
        the ROS call with the exception text. Operators only: when the robot's
        access report says we are not one, the offer's ``refused`` says so at once
        (and it is reported like a robot's refusal); a later report sets it then.
        """
        self.connection.require(f"offer of {service}", now=False)
        self.watch(robot)
        why = self.refusal(robot, Verb.PROVIDE, service)
        offer = self._providers.provide(robot, service, srv_type, handler, self.callbacks, timeout, refused=why)
        if why is not None:
            self._on_error(robot, RobotError(robot, self.topics.provide(robot, self.username, service), why,
                                             client_id=self.client_id))
        return offer

    def advertise(self, robot: str, topic: str, ros_type: str) -> None:
        """Announce that we publish ``ros_type`` on the generic rule ``topic`` of ``robot``.

        Rules marked ``on_demand`` in the fleet file have a ROS publisher only while someone
        advertises them (or publishes on them): this creates it before the first message, and
        :meth:`unadvertise` (or closing, or dying) removes it. Harmless for other rules.
        """
        if self.connection.presence is None:
            raise InvalidArgument("advertising needs operator presence: the robot keeps the ROS publisher only while "
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
            self._unheard.discard(parsed.robot)
            self.directory.update(parsed.robot, payload)

    def _on_to_user(self, topic: str, payload: bytes, _retained: bool) -> None:
        parsed = self.topics.parse(topic)
        if parsed is None or parsed.kind is not Kind.TO or parsed.user != self.username:
            return
        robot, verb, name = parsed.robot or "", parsed.verb, parsed.name or ""
        if verb is Verb.REPLY:
            self._calls.on_reply(robot, name, payload)
        elif verb is Verb.REQUEST:
            self._providers.on_request(robot, name, payload)
        elif verb is Verb.ERROR:
            error = RobotError.from_json(robot, payload)  # a malformed report is shown as what it is
            if error.client_id is not None and error.client_id != self.client_id and not self.all_errors:
                log.debug("%s: ignoring an error report for %s: %s", self.client_id, error.client_id, error.error)
                return  # another program of the same user sent what was refused
            self._on_error(robot, error)
        elif verb is Verb.NOTICE:
            self._on_notice(robot, RobotNotice.from_json(robot, payload))
        elif verb is Verb.ACCESS:
            self._on_access(robot, payload)
        elif verb is Verb.GOAL_STATUS:
            self._goals.on_status(robot, name, payload)
        elif verb is Verb.FEEDBACK:
            self._goals.on_feedback(robot, name, payload)
        elif verb is Verb.RESULT:
            self._goals.on_result(robot, name, payload)
        elif verb is Verb.PARAM_REPLY:
            self._params.on_reply(robot, name, payload)
        elif verb is Verb.PARAM_SET and self.on_param_set is not None:
            self.on_param_set(robot, name, payload)
        elif verb is Verb.ACTION_REQUEST:
            self._action_servers.on_request(robot, name, payload)
        elif verb is Verb.SNAPSHOT_DATA:
            self._snapshots.on_chunk(robot, name, payload)

    # -- what the broker lets us do ---------------------------------------------------------------
    def _on_access(self, robot: str, payload: bytes) -> None:
        """The robot's retained access report for us (empty: withdrawn, we lost the grant)."""
        try:
            report = AccessReport.from_json(payload) if payload else None
        except ProtocolError as err:
            log.warning("%s: unreadable access report from %s: %s", self.client_id, robot, err)
            return
        with self._access_changed:
            if report is None:
                self._access.pop(robot, None)
            else:
                self._access[robot] = report
                self._no_grant.discard(robot)
            self._access_changed.notify_all()
        if report is not None and not report.operator:
            reason = self.refusal(robot, Verb.PROVIDE, wait=False)
            for offer in self._providers.refuse_robot(robot, reason or ""):
                self._on_error(robot, RobotError(robot, self.topics.provide(robot, self.username, offer.name),
                                                 offer.refused or "", client_id=self.client_id))

    def refusal(self, robot: str, verb: Verb, name: str = "", *, wait: bool = True) -> str | None:
        """Why the broker would drop ``verb`` on ``name`` (a command's leaf, a service, an action, a node) on
        ``robot``, None if it would not: the one authorization rule (:func:`roslink_mqtt.authorize.refusal`) with
        the role of our access report, worded as the robot words it, plus what a viewer may use instead. A program
        asks it to grey out what it may not do (``client.refusal("turtle1", Verb.CALL, "reset")``).

        The report is retained and arrives right after our subscription's SUBACK, so a
        command made at once waits up to ACCESS_WAIT for it; a robot whose bridge does not
        publish one (an older bridge) is never refused here.
        """
        with self._access_changed:
            if robot in self._no_grant:
                return (f"user '{self.username}' has no grant on {robot}: the broker refused to let us read "
                        f"{self.topics.to_user_filter(robot, self.username)}")
            if wait and not self.connection.on_network_thread():
                deadline = self._access_asked.get(robot, 0.0) + ACCESS_WAIT
                while robot not in self._access and time.monotonic() < deadline:
                    self._access_changed.wait(deadline - time.monotonic())
            report = self._access.get(robot)
        if report is None:
            return None
        role = Role.OPERATOR if report.operator else Role.VIEWER
        if verb is Verb.CMD and roslink_command(name) == "emergency_stop":  # any granted user may, unless it says not
            if report.operator or report.estop:
                return None
            why = refusal(self.username, role, verb, name, robot=robot)
            return f"{why}; {robot} says `estop: operators`"
        if verb is Verb.SNAPSHOT:
            if report.snapshot:
                return None
            if report.operator:
                return f"{robot} keeps no snapshots: its robot file has no `snapshot:` section"
            return refusal(self.username, role, verb, name, robot=robot)
        read_only = (report.may_call(name) if verb is Verb.CALL else
                     report.may_send_goal(name) if verb is Verb.GOAL else False)
        why = refusal(self.username, role, verb, name, robot=robot, read_only=read_only)
        if why is not None and verb is Verb.CALL:
            return f"{why}; you may call: {', '.join(report.services) or 'none'}"
        if why is not None and verb is Verb.GOAL:
            return f"{why}; you may use: {', '.join(report.actions) or 'none'}"
        return why

    def _on_login_refused(self, failure: LoginRefused) -> None:
        """The broker refused our login on reconnect (network thread): fail what waits, tell the caller."""
        self._calls.fail_all(str(failure))
        self._goals.fail_all(str(failure))
        self._params.fail_all(str(failure))
        with self._watch_lock:
            subscriptions = list(self._subscriptions)
        for sub in subscriptions:
            sub.fail(failure)
        self._on_error("", RobotError("", "", str(failure), client_id=self.client_id))

    def _on_notice(self, robot: str, notice: RobotNotice) -> None:
        """Something we sent was carried out, but changed (network thread): ``on_notice``, or a warning."""
        if notice.client_id is not None and notice.client_id != self.client_id and not self.all_errors:
            return  # another program of the same user sent it
        self.recent_notices.append(notice)
        callback = self.on_notice
        if callback is not None:
            self.callbacks.put(lambda: callback(notice))
        else:  # the robot says it once per stream: no flood to hold back
            log.warning("%s: %s: %s", robot, notice.topic, notice.notice)

    def report_refusal(self, error: RobotError) -> None:
        """Treat ``error`` as a refusal the robot sent: ``on_error``, ``recent_errors`` or the log (the SDK's own
        parts report this way what they refuse before sending, as the rclpy-shaped node's parameters do)."""
        self._on_error(error.robot, error)

    def _on_error(self, robot: str, error: RobotError) -> None:
        """A refusal meant for us: wake a ``check=`` waiter, mark an offer, hand it to ``on_error`` or log it."""
        self.recent_errors.append(error)
        awaited = self._errors.deliver(error)
        self._providers.on_error(error)
        if self._goals.on_error(error) or self._params.on_error(error) or self._snapshots.on_error(error):
            awaited = True  # the goal's handle (GoalError) or the request (ParameterError) raises it
        callback = self.on_error
        if callback is not None:
            self.callbacks.put(lambda: callback(error))
        elif robot and not awaited:  # a check= caller raises it instead; a refused login was logged already
            now = time.monotonic()
            key = (error.topic, error.error)
            if now - self._logged_errors.get(key, -1e9) > 5.0:  # a refused 10 Hz stream must not flood the log
                self._logged_errors[key] = now
                log.warning("%s refused %s: %s", robot, error.topic, error.error)
