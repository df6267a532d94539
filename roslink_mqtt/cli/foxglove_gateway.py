"""``roslink-mqtt foxglove``: robots behind NAT in Foxglove or Lichtblick, through the broker, as one user.

The gateway runs on the user's machine. It logs in to the broker as the user (an SDK :class:`RobotClient`, so the
broker's ACL, the user's presence, the control lease and the robot's failsafe apply as to every other client) and
serves the Foxglove WebSocket protocol (``foxglove.websocket.v1``) on localhost with the ``foxglove-sdk`` server:
the protocol's reference implementation, kept by Foxglove, that Foxglove and Lichtblick are tested against; a
front (:mod:`.foxglove_front`) lets clients name the protocol either ``foxglove.sdk.v1`` or ``foxglove.websocket.v1``
and decides who may connect: since whoever connects acts as the user, a web page from another origin is refused and
the URL must carry a secret made for this run (``ws://127.0.0.1:8765/?token=…``).

Everything is named as in the MQTT topic tree, so a layout made live opens ``roslink-mqtt record``'s files too:

* **channels**: each robot's heartbeat and every state topic its description lists, as JSON with a ``jsonschema``
  (:mod:`..client.json_channels`, shared with the recorder). The gateway subscribes to a topic on the broker only
  while some Foxglove panel does, so a camera nobody watches costs no bandwidth; a video stream
  (``foxglove.CompressedVideo``) is watched while a panel shows it, so the robot encodes it only then.
* **services**: ``<prefix>/<robot>/call/<service>`` for each service the user may call (JSON request and response,
  schemas from the description's field layouts), and ``<prefix>/<robot>/emergency_stop`` for every granted robot.
* **parameters**: ``<prefix>/<robot>/param/<node>/<name>`` for the nodes the description exposes.
* **client publishing** (operators): a channel advertised as ``<prefix>/<robot>/cmd/twist`` — a
  ``geometry_msgs/msg/Twist`` in JSON, what Foxglove's Teleop panel sends — drives the robot: the first twist claims
  control when nobody holds it, the robot clamps and its dead-man stops it when the twists stop. A viewer's twist,
  or one the robot refuses, comes back as a status message (Foxglove shows it as a problem).
"""

from __future__ import annotations

import functools
import logging
import math
import queue
import secrets
import threading
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import foxglove
import orjson
from foxglove.websocket import Capability, ChannelView, Client, ClientChannel, ServerListener, ServiceRequest

from ..client.errors import CommandRefused, RobotError, RoslinkError
from ..client.json_channels import VIDEO, JsonChannels, video_message
from ..client.results import ParameterValue
from ..protocol.schemas import STATE_BODIES, ros_schema
from ..topics import Verb
from .connect import parse_json_object
from .control_cmd import claim_if_free
from .foxglove_front import Admission, ProtocolFront, check_token, loopback_tls, normalize_origin

if TYPE_CHECKING:
    from ..client.robot_client import RobotClient
    from ..client.video import VideoSubscription
    from ..protocol.description import RobotDescription
    from ..protocol.video import VideoFrame

log = logging.getLogger("roslink_mqtt.foxglove")

DISCOVERY_PERIOD = 1.0  # s between looks for robots that came online
DESCRIPTION_WAIT = 5.0  # s for a robot's retained description
PARAM_WAIT = 5.0  # s for a node's parameters (a Foxglove panel waits for them)
REPEAT_AFTER = 5.0  # s before the same status message is sent again
TWIST, EMERGENCY_STOP = "twist", "emergency_stop"  # the commands the gateway offers (cmd/<name>)
_LINEAR = ("lx", "ly", "lz")
_ANGULAR = ("ax", "ay", "az")


@dataclass
class _Advertised:
    """One client channel the gateway accepted: the robot its twists drive."""

    robot: str
    topic: str


class FoxgloveGateway(ServerListener):
    """Serve ``client``'s robots (``robots``: only these; default every robot whose heartbeat the user sees) on
    ``host:port`` (:meth:`start`); :meth:`close` ends it. Foxglove callbacks come on the server's threads; every
    MQTT round trip they would wait for is done on the gateway's own worker threads instead."""

    def __init__(self, client: RobotClient, robots: Sequence[str] = (), *, host: str = "127.0.0.1",
                 port: int = 8765, topics: Sequence[str] = (), require_token: bool = True, token: str | None = None,
                 allow_origins: Sequence[str] = ()) -> None:
        """``require_token``: clients must give :attr:`token` in the URL (:attr:`url`); ``token``: the user's own
        (default: a new one, :func:`secrets.token_urlsafe`). ``allow_origins``: web origins allowed besides the
        hosted apps (:mod:`.foxglove_front`). ValueError for a token or an origin that is not one."""
        self.client, self.host, self.port = client, host, port
        self.token = (check_token(token) if token else secrets.token_urlsafe(32)) if require_token else None
        self.admission = Admission(self.token, frozenset(normalize_origin(o) for o in allow_origins))
        self.named = list(robots)
        self.prefix = client.topics.prefix
        self.routes = JsonChannels(client.topics, _Robots(self), topics)
        self.served: dict[str, RobotDescription | None] = {}  # robots whose channels are advertised
        self._channels: dict[str, foxglove.Channel] = {}  # MQTT topic → channel
        self._watchers: Counter[str] = Counter()  # MQTT topic → Foxglove subscriptions to it
        self._videos: dict[str, VideoSubscription] = {}  # video streams watched for Foxglove panels, by topic
        self._client_channels: dict[tuple[int, int], _Advertised] = {}
        self._lock = threading.Lock()
        self._work: queue.Queue[tuple[str, Any]] = queue.Queue()  # subscribe/unsubscribe, off the server's thread
        self._twists: dict[str, dict[str, float]] = {}  # robot → latest twist not yet sent (latest wins)
        self._twist_ready = threading.Condition()
        self._claimed: set[str] = set()
        self._said: dict[str, float] = {}  # status text → when it was last sent
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.server: Any = None
        self.front: ProtocolFront | None = None
        self.context: Any = None
        client.on_error = self._on_robot_error

    # -- lifecycle ------------------------------------------------------------------------------------------
    def start(self) -> int:
        """Listen; returns the port (``port=0`` picks a free one)."""
        self.context = foxglove.Context()
        # Foxglove's server on a loopback port of its own, behind the front, which checks who connects and also
        # takes clients that name the protocol foxglove.websocket.v1 (cli/foxglove_front.py). It speaks only TLS
        # with a certificate of this run that only the front trusts: no browser page can talk to it directly.
        cert, key, trust = loopback_tls()
        self.server = foxglove.start_server(
            name=f"roslink-mqtt ({self.client.username})", host="127.0.0.1", port=0, context=self.context,
            capabilities=[Capability.ClientPublish, Capability.Services, Capability.Parameters],
            supported_encodings=["json"], server_listener=self, tls_cert=cert, tls_key=key)
        self.front = ProtocolFront(self.host, self.port, int(self.server.port), admission=self.admission,
                                   upstream_tls=trust)
        try:
            self.port = self.front.start()
        except OSError:
            self.server.stop()
            raise
        for target, name in ((self._discover, "discover"), (self._do_work, "subscribe"),
                             (self._send_twists, "twist")):
            thread = threading.Thread(target=target, name=f"foxglove-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self.port

    @property
    def url(self) -> str:
        """The URL clients open: ``ws://host:port/``, with ``?token=…`` when one is required."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def close(self) -> None:
        self._stop.set()
        with self._twist_ready:
            self._twist_ready.notify_all()
        self._work.put(("stop", None))
        for video in list(self._videos.values()):
            video.close()
        if self.front is not None:
            self.front.stop()
        if self.server is not None:
            self.server.stop()
        for thread in self._threads:
            thread.join(2)

    # -- robots and their channels ---------------------------------------------------------------------------
    def _discover(self) -> None:
        for robot in self.named:
            self.client.watch(robot)
        while not self._stop.is_set():
            robots = self.client.robots()
            for robot in self.named or sorted(robots):
                info = robots.get(robot)
                if robot not in self.served and info is not None and info.online:
                    self._serve(robot)
            self._stop.wait(DISCOVERY_PERIOD)

    def _serve(self, robot: str) -> None:
        """Advertise ``robot``'s channels, services and parameters (once, from its description)."""
        try:
            description = self.client.description(robot, timeout=DESCRIPTION_WAIT)
        except RoslinkError as err:
            log.warning("%s: no description (%s); serving its heartbeat only", robot, err)
            description = None
        self.served[robot] = description
        topics = [self.client.topics.heartbeat(robot)]
        if description is not None:
            self.routes.use(robot, description)
            topics += [self.client.topics.state(robot, name) for name in STATE_BODIES]  # the bridge's own
            topics += [self.client.topics.state(robot, entry.name) for entry in description.state]
            topics += [self.client.topics.state(robot, entry.name) for entry in description.video]
        for topic in topics:
            route = self.routes.route(topic)
            if route is None or topic in self._channels:
                continue
            schema = foxglove.Schema(name=route.schema_name, encoding="jsonschema", data=orjson.dumps(route.schema))
            self._channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding="json",
                                                     context=self.context)
        self.server.add_services(self._services(robot, description))
        log.info("serving %s: %d channels", robot, len(topics))

    def _services(self, robot: str, description: RobotDescription | None) -> list[Any]:
        from foxglove import MessageSchema, Schema, Service, ServiceSchema

        def json_schema(name: str, value: dict[str, Any] | None) -> MessageSchema:
            return MessageSchema(encoding="json", schema=Schema(name=name, encoding="jsonschema",
                                                                data=orjson.dumps(value or {"type": "object"})))

        stop = json_schema("EmergencyStop_Request", {"type": "object", "properties": {"reason": {"type": "string"}}})
        services = [Service(self.client.topics.gateway_name(robot, Verb.CMD, EMERGENCY_STOP),
                            schema=ServiceSchema("EmergencyStop", request=stop),
                            handler=lambda request: self._emergency_stop(robot, request))]
        for entry in description.services if description is not None else ():
            if self.client.refusal(robot, Verb.CALL, entry.name) is not None:
                continue  # not ours to call: not offered
            layout = description.types.get(entry.ros_type) if description is not None else None
            parts = layout if isinstance(layout, dict) else {}
            request = ros_schema("request", {"request": parts.get("request")}) if parts.get("request") else None
            response = ros_schema("response", {"response": parts.get("response")}) if parts.get("response") else None
            services.append(Service(
                self.client.topics.gateway_name(robot, Verb.CALL, entry.name),
                schema=ServiceSchema(entry.ros_type, request=json_schema(f"{entry.ros_type}_Request", request),
                                     response=json_schema(f"{entry.ros_type}_Response", response)),
                handler=functools.partial(self._call, robot, entry.name)))
        return services

    # -- Foxglove subscriptions → MQTT subscriptions ----------------------------------------------------------
    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self._work.put(("subscribe", channel.topic))

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        self._work.put(("unsubscribe", channel.topic))

    def _do_work(self) -> None:
        while True:
            what, topic = self._work.get()
            if what == "stop":
                return
            if what == "subscribe":
                self._watchers[topic] += 1
                if self._watchers[topic] == 1:
                    self._carry(topic)
            elif what == "unsubscribe" and self._watchers[topic] > 0:
                self._watchers[topic] -= 1
                if self._watchers[topic] == 0:
                    video = self._videos.pop(topic, None)
                    if video is not None:
                        video.close()  # the robot stops encoding once nobody else watches
                    else:
                        self.client.connection.unsubscribe(topic, self._on_mqtt)

    def _carry(self, topic: str) -> None:
        """Subscribe to ``topic`` on the broker for a Foxglove panel; a video stream is watched (its frames come
        only while someone does), the others subscribed."""
        route = self.routes.route(topic)
        if route is not None and route.encoding == VIDEO:
            try:
                self._videos[topic] = self.client.video(route.robot, route.name,
                                                        functools.partial(self._on_video, topic))
            except RoslinkError as err:
                self.status(f"{topic}: {err}", error=True)
        elif not self.client.connection.subscribe(topic, self._on_mqtt):
            self.status(f"the broker refused {topic} to {self.client.username}", error=True)

    def _on_video(self, topic: str, frame: VideoFrame) -> None:
        channel, route = self._channels.get(topic), self.routes.route(topic)
        if channel is not None and route is not None:
            data, _stamp = video_message(route.name, frame)
            channel.log(data, log_time=time.time_ns())

    def _on_mqtt(self, topic: str, payload: bytes, _retained: bool) -> None:
        channel, route = self._channels.get(topic), self.routes.route(topic)
        if channel is None or route is None or not payload:
            return
        arrived = time.time_ns()
        try:
            data, _published = self.routes.encode(route, payload, arrived)
        except Exception as err:  # a malformed CBOR payload: kept out, the stream goes on
            log.warning("%s: not forwarded: %s", topic, err)
            return
        channel.log(data, log_time=arrived)

    # -- services --------------------------------------------------------------------------------------------
    def _call(self, robot: str, service: str, request: ServiceRequest) -> bytes:
        """A Foxglove service call: the robot's reply as JSON, or an exception whose text Foxglove shows."""
        args = _json_object(request.payload, f"the request to {service}")
        return orjson.dumps(self.client.call(robot, service, args))

    def _emergency_stop(self, robot: str, request: ServiceRequest) -> bytes:
        body = _json_object(request.payload, "the emergency stop's request") if request.payload else {}
        reason = str(body.get("reason") or f"Foxglove ({self.client.username})")
        with self._twist_ready:
            self._twists.pop(robot, None)
        self.client.emergency_stop(robot, reason, check=0.5)
        return orjson.dumps({"stopped": robot, "reason": reason})

    # -- parameters ------------------------------------------------------------------------------------------
    def _param_name(self, robot: str, node: str, name: str) -> str:
        return self.client.topics.gateway_param(robot, node, name)

    def on_get_parameters(self, client: Client, param_names: list[str], request_id: str | None = None) -> list[Any]:
        from foxglove import Parameter

        wanted: dict[tuple[str, str], list[str]] = {}  # (robot, node) → names asked for ([]: all of them)
        for full in param_names:
            where = self._parse_param(full)
            if where is not None:
                wanted.setdefault(where[:2], []).append(where[2])
        out = []
        for robot, description in list(self.served.items()):
            for entry in description.parameters if description is not None else ():
                if param_names and (robot, entry.name) not in wanted:
                    continue
                try:
                    names = wanted.get((robot, entry.name)) or self.client.list_parameters(robot, entry.name,
                                                                                           timeout=PARAM_WAIT)
                    values = self.client.get_parameters(robot, entry.name, names, timeout=PARAM_WAIT) if names else {}
                except RoslinkError as err:
                    self.status(f"parameters of {robot}'s {entry.name}: {err}", error=True)
                    continue
                out += [Parameter(self._param_name(robot, entry.name, name), value=_foxglove_value(value))
                        for name, value in values.items() if value is not None]
        return out

    def on_set_parameters(self, client: Client, parameters: list[Any], request_id: str | None = None) -> list[Any]:
        from foxglove import Parameter

        changed: dict[tuple[str, str], dict[str, Any]] = {}
        for parameter in parameters:
            where = self._parse_param(parameter.name)
            if where is None:
                self.status(f"no parameter {parameter.name} (names are <prefix>/<robot>/param/<node>/<name>)",
                            error=True)
                continue
            robot, node, name = where
            changed.setdefault((robot, node), {})[name] = parameter.get_value()
        out = []
        for (robot, node), values in changed.items():
            try:
                results = self.client.set_parameters(robot, node, values, timeout=PARAM_WAIT)
                for name, result in results.items():
                    if not result.get("successful", False):
                        self.status(f"{robot} {node} {name}: {result.get('reason') or 'refused'}", error=True)
                now = self.client.get_parameters(robot, node, list(values), timeout=PARAM_WAIT)
            except RoslinkError as err:
                self.status(f"setting {', '.join(values)} on {robot}'s {node}: {err}", error=True)
                continue
            out += [Parameter(self._param_name(robot, node, name), value=_foxglove_value(value))
                    for name, value in now.items() if value is not None]
        return out

    def _parse_param(self, full: str) -> tuple[str, str, str] | None:
        """``(robot, node entry, parameter)`` of a gateway parameter name; None when it names none we serve."""
        parsed = self.client.topics.parse_gateway_param(full)
        if parsed is None:
            return None
        description = self.served.get(parsed[0])
        if description is None or not any(e.name == parsed[1] for e in description.parameters):
            return None
        return parsed

    # -- client publishing: twists ---------------------------------------------------------------------------
    def on_client_advertise(self, client: Client, channel: ClientChannel) -> None:
        robot = self._twist_robot(channel.topic)
        if robot is None:
            self.status(f"{channel.topic}: the gateway takes twists only, on "
                        f"{self.client.topics.gateway_name('ROBOT', Verb.CMD, TWIST)}", error=True)
            return
        if channel.encoding != "json":
            self.status(f"{channel.topic}: twists must be JSON, not {channel.encoding}", error=True)
            return
        with self._lock:
            self._client_channels[(client.id, channel.id)] = _Advertised(robot, channel.topic)

    def on_client_unadvertise(self, client: Client, client_channel_id: int) -> None:
        with self._lock:
            self._client_channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client: Client, client_channel_id: int, data: bytes) -> None:
        with self._lock:
            advertised = self._client_channels.get((client.id, client_channel_id))
        if advertised is None:
            return
        try:
            twist = twist_of(orjson.loads(data))
        except (orjson.JSONDecodeError, ValueError) as err:
            self.status(f"{advertised.topic}: {err}; nothing sent", error=True)
            return
        with self._twist_ready:
            self._twists[advertised.robot] = twist  # latest wins: a slow broker never builds a queue of twists
            self._twist_ready.notify()

    def _twist_robot(self, topic: str) -> str | None:
        parsed = self.client.topics.parse_gateway_name(topic)
        return parsed[0] if parsed is not None and parsed[1] is Verb.CMD and parsed[2] == TWIST else None

    def _send_twists(self) -> None:
        while not self._stop.is_set():
            with self._twist_ready:
                while not self._twists and not self._stop.is_set():
                    self._twist_ready.wait()
                if self._stop.is_set():
                    return
                robot, twist = self._twists.popitem()
            try:
                if robot not in self._claimed and any(twist.values()):
                    why = claim_if_free(self.client, robot)
                    if why is not None:
                        self.status(why, error=True)
                        continue
                    self._claimed.add(robot)
                self.client.twist(robot, **twist)
            except CommandRefused as err:
                self.status(str(err), error=True)
            except RoslinkError as err:
                self.status(f"twist to {robot}: {err}", error=True)

    # -- what the robots and the gateway have to say -----------------------------------------------------------
    def _on_robot_error(self, error: RobotError) -> None:
        self.status(f"{error.robot}: {error.error}", error=True)

    def status(self, text: str, *, error: bool = False) -> None:
        """A status message to every Foxglove client (the gateway is one user's: its clients are that user's).
        The same text is said once per :data:`REPEAT_AFTER` (a refused twist stream would say it ten times a
        second)."""
        from foxglove.websocket import StatusLevel

        now = time.monotonic()
        with self._lock:
            if now - self._said.get(text, -REPEAT_AFTER) < REPEAT_AFTER:
                return
            self._said = {t: at for t, at in self._said.items() if now - at < REPEAT_AFTER}
            self._said[text] = now
        (log.warning if error else log.info)("%s", text)
        if self.server is not None:
            self.server.publish_status(text, StatusLevel.Error if error else StatusLevel.Info)


class _Robots:
    """The robots whose topics the gateway routes: the named ones, else every robot it serves."""

    def __init__(self, gateway: FoxgloveGateway) -> None:
        self.gateway = gateway

    def __contains__(self, robot: object) -> bool:
        return robot in self.gateway.named if self.gateway.named else robot in self.gateway.served

    def __iter__(self) -> Any:
        return iter(self.gateway.named or list(self.gateway.served))

    def __len__(self) -> int:
        return len(self.gateway.named or self.gateway.served)


def twist_of(value: Any) -> dict[str, float]:
    """A twist from a ``geometry_msgs/msg/Twist`` in JSON (Foxglove's Teleop panel) or the ROSLink body
    (``lx`` … ``az``); ValueError, naming the field, for anything else or a non-finite number."""
    if not isinstance(value, dict):
        raise ValueError("a twist must be a JSON object")
    if "linear" in value or "angular" in value:
        out = {}
        for part, names in (("linear", _LINEAR), ("angular", _ANGULAR)):
            vector = value.get(part) or {}
            if not isinstance(vector, dict):
                raise ValueError(f"{part} must be an object with x, y, z")
            for axis, name in zip("xyz", names, strict=True):
                out[name] = _finite(vector.get(axis, 0.0), f"{part}.{axis}")
        return out
    unknown = set(value) - set(_LINEAR) - set(_ANGULAR)
    if unknown:
        raise ValueError(f"unknown twist field(s) {', '.join(sorted(unknown))}: send linear/angular or lx … az")
    return {name: _finite(value.get(name, 0.0), name) for name in _LINEAR + _ANGULAR}


def _finite(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, not {value!r}")
    return float(value)


def _json_object(payload: bytes, what: str) -> dict[str, Any]:
    return parse_json_object(payload, what) if payload else {}


__all__ = ["FoxgloveGateway", "twist_of"]


def _foxglove_value(value: ParameterValue) -> Any:
    """A ROS parameter value as foxglove's Parameter takes it: the same value (its annotation spells arrays as lists
    of any of its values, and a list[bool] is not one to a type checker: lists are invariant)."""
    return value
