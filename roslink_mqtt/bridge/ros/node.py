"""The bridge's ROS adapter: publishers, service clients and timers around the ROS-free command endpoint.

Every decision about what users send (parse, authorize, validate, presence and motion gates, the sequence
rule, failsafe stops) is :class:`~roslink_mqtt.bridge.core.endpoint.CommandEndpoint`'s. This module owns what
needs rclpy: the ROS → MQTT subscriptions, the publishers and service clients the endpoint's decisions go
to, the services both ways (:mod:`.service_caller`, :mod:`.service_provider`), on-demand publishers, and the
timers that drive heartbeats and supervision.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from rclpy.node import Node

from ...config import Fleet, Priority, Robot
from ...config.model import BUFFER_DISK
from ...protocol import AckResult, SystemStatus
from ...protocol.description import DESCRIPTION
from ...protocol.lease import CONTROL
from ...protocol.link import LINK
from ...topics import Verb, join_leaf, state_name
from ..core import trace
from ..core.budget import RequestBudget
from ..core.capabilities import (
    ACTION_PORT,
    ACTION_PROVIDER_PORT,
    ADVERTISE_PORT,
    CHUNK_PORT,
    FAILSAFE_FILE_PORT,
    PARAMETER_PORT,
    PROVIDER_PORT,
    SDK_PARAMETER_PORT,
    SERVICE_PORT,
    SNAPSHOT_PORT,
    VIDEO_PORT,
    Snapshots,
)
from ..core.capabilities.ports import Ports
from ..core.capabilities.registry import Wiring, build_all
from ..core.claim import EXIT_LOGIN_REFUSED, Claim, ClaimWatch
from ..core.endpoint import SUPERVISION_RATE, CommandEndpoint
from ..core.fleet_follower import FleetFollower, LinkKind
from ..core.graph_check import GRAPH_CHECK_DELAY, GRAPH_CHECK_PERIOD, SERVICE, TOPIC, Expected, changes, check
from ..core.inbox import Inbox
from ..core.intake import Intake
from ..core.link import MqttLink, bridge_client_id
from ..core.on_executor import OnExecutor
from ..core.pending import PendingCalls
from ..core.ros_types import UnknownTypeError, load_interface
from ..core.routes import Inbound
from ..core.safety import STANDSTILL, VELOCITY_TYPES, UnsafeCommand, make_safe_twist
from ..core.spool import Spool, buffer_dir
from ..core.systemd import SystemdNotifier
from ..core.throttle import Throttle
from ..core.uplink_sender import Uplink
from .action_caller import ActionCaller
from .action_provider import ProvidedActions
from .convert import ConversionError, converter_for
from .on_demand import OnDemandPublishers
from .parameters import RosParameters
from .ports import RosSide, Supervised, made_ports
from .rules import Outbound, RuleError, compile_rules, ros_qos
from .sdk_params import SdkParameterNodes
from .service_caller import RosServices
from .service_provider import ProvidedServices
from .snapshot import STREAM as SNAPSHOT_STREAM
from .snapshot import FailsafeFiles, RosSnapshotBuffer, UplinkChunks, snapshot_dir
from .vda5050_node import VdaRobot
from .video import RosVideo

log = logging.getLogger("roslink_mqtt.bridge")

COMMAND_SERVICE_TIMEOUT = 5.0  # s for preset commands carried out by a ROS service
VIEWER_LINK_HEAD_START = 3.0  # s the command link waits at start for the viewer link's subscriptions
STOP_DELIVERY_WAIT = 0.5  # s a stopping bridge waits for its last zero velocity's acknowledgement (per output)


@dataclass
class _CommandCall:
    """A preset command carried out by a ROS service, waiting for its outcome to acknowledge."""

    preset: str
    resumes_motion: bool  # arm: motion may be commanded again once the service succeeds
    message_id: int | None
    sequence: int | None
    service: str
    future: Any


class RosActuators:
    """:class:`~roslink_mqtt.bridge.core.endpoint.Actuators` with rclpy: one publisher or service client per route."""

    def __init__(self, node: Node, robot: Robot, routes: dict[str, Inbound], on_demand: OnDemandPublishers) -> None:
        self.node, self.robot, self.on_demand = node, robot, on_demand
        self.velocity: list[tuple[Inbound, Any]] = []
        self.publishers: dict[str, Any] = {}
        self.services: dict[str, Any] = {}
        self.calls: PendingCalls[_CommandCall] = PendingCalls()
        self.endpoint: CommandEndpoint | None = None  # set once the endpoint exists (it acknowledges outcomes)
        self.actions: ActionCaller | None = None  # set once built (its refusals go through the endpoint)
        self.on_cancel_goals: Callable[[], None] | None = None  # the VDA 5050 vehicle's check, when it has one
        for name, route in routes.items():
            if route.is_service:
                self.services[name] = node.create_client(route.ros_cls, route.rule.ros_topic)
            elif not route.rule.on_demand:  # an on-demand publisher comes and goes with its advertisers
                qos = ros_qos(route.rule.ros_qos, latched=route.behaviour.latched)
                pub = self.publishers[name] = node.create_publisher(route.ros_cls, route.rule.ros_topic, qos)
                if route.is_velocity:
                    self.velocity.append((route, pub))
        self.on_failsafe: list[tuple[Any, Any]] = []
        for i, action in enumerate(robot.bridge.on_failsafe):
            try:
                cls = load_interface(action.ros_type)
                message = converter_for(cls).from_dict(action.message)
                if action.ros_type in VELOCITY_TYPES and make_safe_twist(message, STANDSTILL):
                    raise UnsafeCommand("a failsafe action must not move the robot: every velocity must be 0")
            except (UnknownTypeError, ConversionError, UnsafeCommand) as err:
                raise RuleError(f"bridge.on_failsafe[{i}]: {err}") from None
            self.on_failsafe.append((node.create_publisher(cls, action.ros_topic, 10), message))

    # -- Actuators ---------------------------------------------------------------------------
    def publish(self, user: str, route: Inbound, msg: Any) -> None:
        if trace.TRACE is not None:
            trace.TRACE.mark("ros_out", route.rule.ros_topic)
        if route.rule.on_demand:
            self.on_demand.publish(user, route.name, msg)
        else:
            self.publishers[route.name].publish(msg)

    def call_service(self, route: Inbound, request: Any, message_id: int | None, sequence: int | None) -> str | None:
        client = self.services[route.name]
        if not client.service_is_ready():
            return f"service not available: {route.rule.ros_topic} ({route.rule.ros_type})"
        future = client.call_async(request)
        preset = route.spec.name if route.spec is not None else route.name
        key = self.calls.add(_CommandCall(preset, route.behaviour.resumes_motion, message_id, sequence,
                                          route.rule.ros_topic, future),
                             time.monotonic() + COMMAND_SERVICE_TIMEOUT)
        future.add_done_callback(lambda f, key=key: self._service_done(key, f))
        return None

    def zero_velocity(self) -> None:
        for route, pub in self.velocity:
            pub.publish(route.ros_cls())

    def delivered_zero(self, timeout: float) -> bool:
        """Wait (at most ``timeout`` s per output) until every reliable subscriber of the velocity outputs has
        acknowledged what was published. A reliable writer repairs a lost sample only while it lives: a bridge
        that exits right after its last zero would take a dropped one along, and the robot would keep its last
        command (a take-over's fenced bridge, once in CI, its zero's datagram dropped on a loaded machine). How
        soon the acknowledgement comes is the DDS configuration's heartbeat period (the bundled loopback profile:
        100 ms; Fast DDS's default: 3 s, so the wait ends at ``timeout``). True when all acknowledged."""
        from rclpy.duration import Duration

        return all(pub.wait_for_all_acked(Duration(seconds=timeout)) for _, pub in self.velocity)

    def failsafe_actions(self) -> None:
        for pub, msg in self.on_failsafe:
            pub.publish(msg)

    def cancel_goals(self, user: str | None, reason: str) -> int:
        if self.on_cancel_goals is not None:
            self.on_cancel_goals()  # a VDA 5050 order's navigation goal is checked at once (bridge/ros/vda5050_node.py)
        return self.actions.cancel_goals(user, reason) if self.actions is not None else 0

    # -- outcomes of service-backed commands ---------------------------------------------------------
    def _service_done(self, key: int, future: Any) -> None:
        call = self.calls.take(key)
        if call is None or self.endpoint is None:  # already acknowledged as a timeout
            return
        response = future.result() if not future.cancelled() and future.exception() is None else None
        ok = response is not None and getattr(response, "success", True)
        if ok and call.resumes_motion:
            self.endpoint.resume_motion()
        text = getattr(response, "message", "") if response is not None else f"{call.service} failed"
        self.endpoint.publish_ack(call.message_id or 0, call.sequence, AckResult.ACCEPTED if ok else AckResult.FAILED,
                                  text or f"{call.preset} {'done' if ok else 'failed'}")

    def expire(self, now: float) -> None:
        """Acknowledge service-backed commands whose service did not answer in time."""
        for call in self.calls.expire(now):
            call.future.cancel()
            if self.endpoint is not None:
                self.endpoint.publish_ack(call.message_id or 0, call.sequence, AckResult.FAILED,
                                          f"{call.preset}: {call.service} did not answer within "
                                          f"{COMMAND_SERVICE_TIMEOUT:g} s")


class Bridge:
    """Owns one rclpy node (composition, not inheritance: no clashes with rclpy's own attributes).

    Threads: ROS callbacks and the supervision timer run in the executor; MQTT messages arrive on paho's
    network thread and go straight to the endpoint, whose lock serialises motion state.
    """

    def __init__(self, fleet: Fleet, robot: Robot, node: Node, *, password: str | None, broker_url: Any,
                 ca_file: str | None = None, action_node: Node | None = None, claim: Claim | None = None,
                 on_fenced: Callable[[], None] = lambda: None,
                 on_login_refused: Callable[[], None] = lambda: None) -> None:
        """``claim``: this bridge's (bridge/core/claim.py; the start check made it); ``on_fenced``: called once another
        bridge has taken the robot over and this one has stopped it (main() then exits). ``on_login_refused``:
        called when the broker refused the robot's login and ``bridge.exit_on_refused_login`` says to exit then
        (:attr:`login_refused` says why; main() exits with EXIT_LOGIN_REFUSED).
        ``action_node``: a second node, spun by a SingleThreadedExecutor of its own, for the action servers of
        actions provided by MQTT clients (when ``node``'s executor is the EventsExecutor, which runs an action
        server's callbacks to completion ahead of everything else); None: they live on ``node``."""
        self.node, self.robot = node, robot
        self.topics = fleet.topics
        settings = robot.bridge
        outbound, routes = compile_rules(robot, self.topics)
        self._flushers: list[Callable[[], None]] = []  # throttled rules flushed by the supervision tick
        self._retained_at = 0.0  # monotonic: the retained description and access reports last went out
        # the ROS names rules need someone on the other end of (bridge/core/graph_check.py), resolved as ROS does
        self._expected = [Expected(o.rule.mqtt_topic, TOPIC, node.resolve_topic_name(o.rule.ros_topic),
                                   o.rule.ros_type) for o in outbound]
        self._expected += [Expected(name, SERVICE, node.resolve_service_name(r.rule.ros_topic), r.rule.ros_type)
                           for name, r in routes.items() if r.is_service]
        self._expected += [Expected(join_leaf(Verb.CALL, s.name), SERVICE, node.resolve_service_name(s.ros_service),
                                    s.ros_type) for s in robot.services]
        self.graph_warnings: dict[str, str] = {}  # entry → why nothing comes (no publisher, no server)
        self._graph_check_at = time.monotonic() + GRAPH_CHECK_DELAY
        self.link = MqttLink(
            client_id=bridge_client_id(robot.name), username=robot.name, password=password, url=broker_url,
            keepalive=settings.keepalive, will=None, subscriptions=self.mqtt_subscriptions,
            on_message=self._on_mqtt, on_up=self.on_link_up, on_down=self.on_link_down, ca_file=ca_file,
            max_payload=fleet.broker.max_payload)
        # State streams, and each bulk stream, leave on connections of their own (lanes), so a scan or a map that
        # takes long to cross a thin link never sits in front of a heartbeat, an acknowledgement, a pose or another
        # bulk stream (bridge/core/uplink_sender.py). None in fifo mode: everything then goes out on the command link.
        scheduled = settings.uplink == "scheduled"

        def lane(purpose: str) -> MqttLink:
            # the state lane carries the description too: published again each time that lane connects
            return MqttLink(client_id=bridge_client_id(robot.name, purpose), username=robot.name, password=password,
                            url=broker_url, keepalive=settings.keepalive, will=None, subscriptions=list,
                            on_message=self._on_mqtt, ca_file=ca_file, max_payload=fleet.broker.max_payload,
                            on_up=self._describe_when_up if purpose == "state" else (lambda: None))

        self.state_link, self.bulk_links, self.state_links = self._lanes(outbound, lane) if scheduled else \
            (None, {}, {})
        self.uplink = Uplink(self.link, self.state_link, self.bulk_links, fifo=not scheduled,
                             state_links=self.state_links,
                             target_delay=settings.uplink_target_delay,
                             report_topic=self.topics.state(robot.name, LINK))
        # The description (several kB: every rule's field layout) is state: on a thin link, sent on the command
        # connection at each connect, it held heartbeats, acknowledgements and the path's probes back for seconds
        # (64 kbit/s: the command connection lost its keep-alive behind it, reconnected, sent it again, and again)
        self._description = self.uplink.stream(self.topics.state(robot.name, DESCRIPTION), Priority.STATE,
                                               latest_only=True, label=DESCRIPTION)
        if any(o.rule.buffer == BUFFER_DISK for o in outbound):
            directory = buffer_dir(settings.buffer_dir)
            try:
                self.uplink.use_spool(Spool(directory, robot.name, max_bytes=settings.buffer_max_bytes,
                                            max_age=settings.buffer_max_age))
            except OSError as err:
                raise RuleError(f"bridge.buffer_dir: cannot keep the disk buffer of `buffer: disk` rules in "
                                f"{directory}: {err}") from None
            log.info("disk buffer for %s in %s", robot.name, directory)
        for rule in outbound:
            self._subscribe_ros(rule)
        self.snapshot_buffer = RosSnapshotBuffer(node, robot.snapshot) if robot.snapshot is not None else None
        # Viewers' traffic (their requests and presence) arrives on a connection of its own: however much of it
        # a viewer sends, it queues behind nothing of the operators', whose commands and stops keep their own
        # TCP stream and paho thread, and it is read at most viewer_message_rate messages a second, so it cannot
        # take the bridge's time either. Everything the bridge publishes goes out on the command link.
        self.viewer_link = MqttLink(
            client_id=bridge_client_id(robot.name, "viewers"), username=robot.name, password=password,
            url=broker_url, keepalive=settings.keepalive, will=None, subscriptions=self.viewer_subscriptions,
            on_message=self._on_mqtt, ca_file=ca_file,
            # the first link to dial (start()): it says why the bridge is not connected (the others, dialling the
            # same broker with the same login, say it at DEBUG)
            report=True, on_refused=self._refused,
            # read at a bounded rate: a viewer's flood waits at the broker, not in the bridge's time
            # (bridge/core/intake.py)
            intake=Intake(settings.viewer_message_rate, "viewers' requests and presence"))
        # Operators' emergency stops also arrive on a connection that carries nothing else: on a thin downlink they
        # never wait behind a large request, response or log line in the broker's queue or the socket. Each stop
        # then arrives twice (this link and the command link); the second copy is dropped (bridge/core/stops.py). Only
        # operators' (those the endpoint obeys): nothing a viewer sends can queue in front of a stop.
        stop_leaves = tuple(name for name, r in routes.items() if r.behaviour.never_stale)
        self.stop_link = MqttLink(
            client_id=bridge_client_id(robot.name, "stop"), username=robot.name, password=password,
            url=broker_url, keepalive=settings.keepalive, will=None, subscriptions=self.stop_subscriptions,
            on_message=self._on_mqtt, ca_file=ca_file) if stop_leaves else None
        budget = RequestBudget(settings.max_requests_per_user)  # calls and parameter requests together
        self.on_executor = OnExecutor()  # main() hands it the executor before start()
        self.action_on_executor = OnExecutor() if action_node is not None else self.on_executor
        self._ticks = 0
        on_demand = {n: r for n, r in routes.items() if r.rule.on_demand}
        self.on_demand = OnDemandPublishers(node, on_demand, self._is_live)
        self.actuators = RosActuators(node, robot, routes, self.on_demand)
        try:
            self.services = RosServices(node, robot)
        except UnknownTypeError as err:
            raise RuleError(f"services: {err}") from None
        self.parameters = RosParameters(node, robot, self.topics, self.link_publish_qos, self.on_executor)
        try:
            self.actions = ActionCaller(node, robot, self.topics, self.link_publish_qos, self.on_executor)
        except UnknownTypeError as err:
            raise RuleError(str(err)) from None
        # calls and parameter requests share the request budget (bridge.max_requests_per_user)
        self.provided = ProvidedServices(node, robot, self.topics, self._publish_reliable, self._is_live,
                                         self.on_executor,
                                         max_concurrent=settings.provided_max_calls,
                                         queue_depth=settings.provided_queue_depth)
        self.sdk_params = SdkParameterNodes(node, robot, self.topics, self.link_publish_qos, self._is_live)
        self.provided_actions = ProvidedActions(action_node or node, robot, self.topics, self._publish_reliable,
                                                self._is_live, self.action_on_executor)
        # cameras as video, encoded once while anyone watches (bridge/ros/video.py)
        self.video = RosVideo(node, robot, self.topics, self.uplink, self._is_live, self.on_executor)
        # the core's operations (capabilities/registry.py), each built from the ports the ROS side implements: those
        # the bridge drives itself, and those the ROS modules declare (bridge/ros/ports.py)
        ports = self._ports()
        made = made_ports(RosSide(node, robot, self.topics, routes, self.uplink, self._publish_reliable,
                                  self.link_publish_qos, self._is_live, self.on_executor), ports)
        self._supervised = [port for port in made if isinstance(port, Supervised)]
        capabilities = build_all(Wiring(robot, self.topics, routes, ports, self._refuse, self._publish_reliable,
                                        self.link_publish_qos, budget))
        self.snapshots = next(c for c in capabilities if isinstance(c, Snapshots))
        self.endpoint = CommandEndpoint(fleet, robot, self.link, self.actuators, routes, claim=claim,
                                        capabilities=capabilities)
        self.endpoint.on_failsafe_stop = self.snapshots.failsafe  # every failsafe stop leaves a record
        # the users and grants obeyed, and what follows when they change: one path for everything a user holds
        self.follower = FleetFollower(fleet, robot, self.topics, self.endpoint, self._publish_retained,
                                      stop_leaves=stop_leaves,
                                      operators_hold=(self.provided, self.provided_actions, self.on_demand,
                                                      self.sdk_params),
                                      users_hold=(self.video,))
        self.follower.use_links({LinkKind.COMMAND: self.link, LinkKind.VIEWER: self.viewer_link,
                                 **({LinkKind.STOP: self.stop_link} if self.stop_link is not None else {})})
        self._heartbeat_topic = self.follower.heartbeat_topic
        self.fenced_by: Claim | None = None  # the bridge this one stood down for
        self._on_fenced = on_fenced
        self.login_refused: str | None = None  # why the bridge exits (bridge.exit_on_refused_login)
        self._on_login_refused = on_login_refused
        self.claims = ClaimWatch(self.endpoint.claim, self._fence, self.endpoint.publish_heartbeat)
        self.inbox = Inbox(robot.name, heartbeat_topic=self.follower.heartbeat_topic,
                           announce_topic=self.follower.announce_topic, grants_topic=self.follower.grants_topic,
                           claims=self.claims, on_grants=self.follower.on_grants, stop_leaves=stop_leaves,
                           endpoint=self.endpoint.on_mqtt)
        self.actuators.endpoint = self.endpoint
        self.link.set_will(self.topics.heartbeat(robot.name), self.endpoint.heartbeat(SystemStatus.OFFLINE))
        self.actuators.actions = self.actions
        # A VDA 5050 master control's orders (docs/vda5050.md): a connection and a navigation client of their own.
        self.vda: VdaRobot | None = None
        if robot.vda5050 is not None:
            try:
                self.vda = VdaRobot(node, fleet, robot, robot.vda5050, password=password, broker_url=broker_url,
                                    ca_file=ca_file, endpoint=self.endpoint, on_executor=self.on_executor,
                                    uplink=self.uplink)
            except UnknownTypeError as err:
                raise RuleError(str(err)) from None
            self.actuators.on_cancel_goals = self.vda.check_now
        self.systemd = SystemdNotifier()
        node.create_timer(settings.heartbeat_period, self.endpoint.publish_heartbeat)
        node.create_timer(1.0 / SUPERVISION_RATE, self.supervise)
        log.info("bridge for %s: %d ROS→MQTT, %d MQTT→ROS rules, %d velocity outputs, %d actions", robot.name,
                 len(outbound), len(routes), len(self.actuators.velocity), len(self.actions.actions))

    def _ports(self) -> Ports:
        """The ports the bridge drives itself (supervised, starting and stopping with it, withdrawn from a demoted
        user), for the core's operations; the ROS modules' own (``MAKES``) join them."""
        ports = (Ports().provide(SERVICE_PORT, self.services).provide(PARAMETER_PORT, self.parameters)
                 .provide(ACTION_PORT, self.actions).provide(ADVERTISE_PORT, self.on_demand)
                 .provide(PROVIDER_PORT, self.provided).provide(ACTION_PROVIDER_PORT, self.provided_actions)
                 .provide(SDK_PARAMETER_PORT, self.sdk_params).provide(VIDEO_PORT, self.video))
        kept = self.robot.snapshot
        if kept is None or self.snapshot_buffer is None:
            return ports
        # snapshots: the ring buffer, the uplink's chunks (a stream in state/link), failsafe snapshots on disk
        return (ports.provide(SNAPSHOT_PORT, self.snapshot_buffer).provide(CHUNK_PORT, UplinkChunks(self.uplink))
                .provide(FAILSAFE_FILE_PORT, FailsafeFiles(snapshot_dir(kept.dir), self.robot.name, kept.keep)))

    def _lanes(self, outbound: Sequence[Outbound], lane: Callable[[str], MqttLink]
               ) -> tuple[MqttLink | None, dict[str, MqttLink], dict[str, MqttLink]]:
        """The uplink's connections besides the command link: one for state streams (if any), one per bulk stream,
        snapshot chunks and video stream (by topic; a video stream of the state class in the third map)."""
        robot = self.robot
        state_link = lane("state") if any(o.rule.priority is Priority.STATE for o in outbound) else None
        bulk_rules = [o for o in outbound if o.rule.priority is Priority.BULK]
        bulk_links = {o.topic: lane(f"bulk{i}") for i, o in enumerate(bulk_rules)}
        if robot.snapshot is not None:  # snapshot chunks: a paced bulk lane of their own
            bulk_links[SNAPSHOT_STREAM] = lane(SNAPSHOT_STREAM)
        state_links: dict[str, MqttLink] = {}
        for i, video in enumerate(robot.video):  # each video stream too, in its class (docs/video.md)
            links = state_links if video.priority is Priority.STATE else bulk_links
            links[self.topics.state(robot.name, video.name)] = lane(f"video{i}")
        return state_link, bulk_links, state_links

    # the endpoint's, looked up at call time (the endpoint is built after the helpers that need these)
    def _is_live(self, user: str, client_id: str | None = None) -> bool:
        return self.endpoint.operators.is_live(user, client_id)

    def _refuse(self, *args: Any, **kwargs: Any) -> None:
        self.endpoint.refuse(*args, **kwargs)

    def take_over_claim(self) -> None:
        """The start check replaced another bridge: this one's heartbeats say so (a take-over claim), so that one,
        should it still be running (frozen, cut off), stands down when it sees them. Before :meth:`start`."""
        claim = replace(self.endpoint.claim, take_over=True)
        self.endpoint.claim = self.claims.me = claim
        self.link.set_will(self._heartbeat_topic, self.endpoint.heartbeat(SystemStatus.OFFLINE))

    def _fence(self, reason: str, rival: Claim) -> None:
        """Another bridge keeps the robot (bridge/core/claim.py): stop it, say why, and have main() exit."""
        log.error("%s: stopping the robot and exiting", reason)
        self.fenced_by = rival
        self.endpoint.fence(reason)
        self._on_fenced()

    def _refused(self, reason: str) -> None:
        """The broker refused the robot's login (network thread): the link retries, slowly, unless the fleet says
        to exit (bridge.exit_on_refused_login), for a supervisor that should not restart it."""
        if self.robot.bridge.exit_on_refused_login and self.login_refused is None:
            self.login_refused = reason
            log.error("%s: exiting with status %d (bridge.exit_on_refused_login)", reason, EXIT_LOGIN_REFUSED)
            self._on_login_refused()

    def _on_mqtt(self, topic: str, payload: bytes, retained: bool = False, arrived: float | None = None) -> None:
        """Every link's messages (paho's threads): the inbox routes them (bridge/core/inbox.py). Looked up at call
        time: the links exist before the inbox."""
        self.inbox.on_message(topic, payload, retained, arrived)

    def _publish_reliable(self, topic: str, payload: bytes) -> None:
        self.link.publish(topic, payload, qos=1)

    def _publish_retained(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        self.link.publish(topic, payload, qos=qos, retain=retain)

    @property
    def fleet(self) -> Fleet:
        """The users and grants obeyed now (bridge/core/fleet_follower.py)."""
        return self.follower.fleet

    @property
    def grants_arrived(self) -> threading.Event:
        return self.follower.grants_arrived

    def on_grants(self, payload: bytes) -> None:
        """The robot's grants from the broker (paho's thread): bridge/core/fleet_follower.py."""
        self.follower.on_grants(payload)

    def reload(self, fleet: Fleet) -> None:
        """Apply a re-read fleet file now (SIGHUP): its users and grants (bridge/core/fleet_follower.py); rule
        changes need a restart. Revoking an operator who owns the current motion stops the robot at once."""
        self.follower.reload(fleet)

    # -- lifecycle ---------------------------------------------------------------
    def start(self) -> None:
        """Connect; the viewer link first, so that once the robot's heartbeat says it is up (command link),
        a viewer's first request finds the bridge subscribed (the two connections are not ordered otherwise)."""
        self.viewer_link.start()
        head_start_ends = time.monotonic() + VIEWER_LINK_HEAD_START
        while not self.viewer_link.subscribed.wait(0.05) and time.monotonic() < head_start_ends:
            if self.login_refused is not None:
                return  # refused, and the fleet says to exit: main() stops the bridge at once; nothing more dials
        # a robot file's bridge knows its users once the broker's retained grants arrive (right after the viewer
        # link subscribed, where the broker has them): operators' commands then find the command link subscribed
        while (self.fleet.grants_pending and self.viewer_link.subscribed.is_set()
               and not self.grants_arrived.wait(0.05) and time.monotonic() < head_start_ends):
            pass
        if not self.viewer_link.subscribed.is_set():
            # not connected: the viewer link's own lines say why (unreachable, refused login); connected but not
            # subscribed yet is worth a line of its own
            log.log(logging.INFO if self.viewer_link.connected.is_set() else logging.DEBUG,
                    "viewer link not subscribed after %g s; connecting the command link anyway",
                    VIEWER_LINK_HEAD_START)
        self.uplink.start()
        self.video.start()
        for lane in self.lanes:
            lane.start()
        if self.stop_link is not None:
            self.stop_link.start()
        if self.vda is not None:
            self.vda.start()
        # READY before the command link dials: its connected status comes from paho's thread and must not
        # overtake READY (systemd, and the unit test, read them in order)
        self.systemd.ready(f"connecting to {self.link.url}")
        self.link.start()

    def stop(self) -> None:
        """Clean shutdown: stop the robot, tell everyone we are offline (the will covers unclean ones)."""
        self.systemd.stopping()
        with self.endpoint.lock:
            self.actuators.zero_velocity()
        if not self.actuators.delivered_zero(STOP_DELIVERY_WAIT):
            log.debug("the last zero velocity was not acknowledged within %g s", STOP_DELIVERY_WAIT)
        if self.vda is not None:  # OFFLINE first: the master sees a clean stop, not a broken connection
            self.vda.stop()
        self.snapshots.close()
        self.video.stop()
        self.uplink.stop()
        for lane in self.lanes:
            lane.stop()
        if self.stop_link is not None:
            self.stop_link.stop()
        self.viewer_link.stop()
        # A bridge that stood down for an older one leaves the robot's heartbeat alone (it is the other one's); one
        # that was taken over says offline, which the new bridge waits for before it starts.
        yielded = self.fenced_by is not None and not self.fenced_by.take_over
        with self.endpoint.lock:  # nobody drives a robot without a bridge: its retained control state says so
            self.endpoint.lease.ended(self.endpoint.lease.holder or "", "the bridge stopped", time.time())
        last_words = [(self.topics.state(self.robot.name, CONTROL), self.endpoint.control_state().to_json(), 1, True),
                      (self._heartbeat_topic, self.endpoint.heartbeat(SystemStatus.OFFLINE), 1, True)]
        self.link.stop([] if yielded else last_words)

    def set_password(self, password: str) -> None:
        """A rotated password (SIGHUP): every connection uses it from its next connect on; none is dropped (the
        broker accepts the previous one until the fleet file drops it: docs/operations.md)."""
        for link in (self.link, self.viewer_link, self.stop_link, *self.lanes,
                     self.vda.link if self.vda is not None else None):
            if link is not None:
                link.set_password(password)

    @property
    def lanes(self) -> list[MqttLink]:
        """The uplink's extra connections (state, bulk), started and stopped with the bridge."""
        return ([self.state_link] if self.state_link is not None else []) + list(self.bulk_links.values()) + \
            list(self.state_links.values())

    def mqtt_subscriptions(self) -> list[tuple[str, int]]:
        """The command link's (re-read at each connect): bridge/core/fleet_follower.py."""
        return self.follower.subscriptions(LinkKind.COMMAND)

    def viewer_subscriptions(self) -> list[tuple[str, int]]:
        return self.follower.subscriptions(LinkKind.VIEWER)

    def stop_subscriptions(self) -> list[tuple[str, int]]:
        return self.follower.subscriptions(LinkKind.STOP)

    def on_link_up(self) -> None:
        self._retained_at = time.monotonic()
        self.systemd.status(f"connected to {self.link.url}")
        self.endpoint.link_up()
        self.endpoint.publish_heartbeat()
        self.endpoint.publish_control()
        self.publish_access()
        self._describe_when_up()

    def _describe_when_up(self) -> None:
        """Once the command connection and the description's own (the state lane, if any) are both up, whichever
        came second: the uplink drops state offered while the command connection is down."""
        if self.link.connected.is_set() and (self.state_link is None or self.state_link.connected.is_set()):
            self.publish_description()

    def publish_description(self) -> None:
        """Retained ``state/description``: what this robot maps, with field layouts (bridge/ros/description.py).
        Through the uplink as state: on the state lane where there is one, never in front of control."""
        from .description import description_message

        topic, body = description_message(self.robot, self.topics, warnings=self.graph_warnings)
        self.uplink.offer(self._description, topic, body, 1, True)

    def check_graph(self) -> None:
        """Warn about rules whose ROS topic has no publisher or whose ROS service has no server, with the closest
        name that exists (a typo in robots.yaml otherwise just sends nothing); mark them in the description."""
        node = self.node

        def has_peer(e: Expected) -> bool:
            return (node.count_publishers(e.name) if e.kind == TOPIC else node.count_services(e.name)) > 0

        def existing(kind: str) -> list[tuple[str, list[str]]]:
            if kind == TOPIC:
                return [(n, t) for n, t in node.get_topic_names_and_types() if node.count_publishers(n) > 0]
            return [(n, t) for n, t in node.get_service_names_and_types() if node.count_services(n) > 0]

        found = check(self._expected, has_peer, existing)
        new, cleared = changes(self.graph_warnings, found)
        for entry, text in new.items():
            log.warning("%s: the rule for %s %s: nothing goes through it until one appears", self.robot.name, entry,
                        text)
        for entry in cleared:
            log.info("%s: the rule for %s has someone on the other end now", self.robot.name, entry)
        self.graph_warnings = found
        if (new or cleared) and self.link.connected.is_set():
            self.publish_description()

    def publish_access(self) -> None:
        self.follower.publish_access()

    def on_link_down(self, reason: str) -> None:
        closing = self.link.closing  # our own stop() disconnected: a shutdown, not a failure
        self.systemd.status("disconnected (stopping)" if closing else f"broker lost ({reason}); reconnecting")
        self.endpoint.link_down(reason, closing=closing)

    # -- ROS → MQTT ------------------------------------------------------------------
    def _subscribe_ros(self, out: Outbound) -> None:
        """Forward a ROS topic to its state topic: throttled to ``max_rate``, then through the uplink (its slot,
        class and the link's budget decide when it leaves, and whether a newer message replaces it first)."""
        offer, topic, serialize = self.uplink.offer, out.topic, out.serialize
        qos, retain = out.rule.mqtt_qos, out.rule.retain
        stream = self.uplink.stream(topic, out.rule.priority, out.rule.latest_only,
                                    label=state_name(out.rule.mqtt_topic), max_rate=out.rule.max_rate,
                                    buffered=out.rule.buffer == BUFFER_DISK)

        def link(topic: str, payload: bytes, qos: int, retain: bool) -> None:
            offer(stream, topic, payload, qos, retain)
        if not out.period:
            def forward(msg: Any) -> None:
                link(topic, serialize(msg), qos, retain)
        else:
            throttle = Throttle(1.0 / out.period)

            def forward(msg: Any) -> None:
                if throttle.offer(msg, time.monotonic()) is not None:
                    link(topic, serialize(msg), qos, retain)

            def flush() -> None:
                msg = throttle.flush(time.monotonic())
                if msg is not None:
                    link(topic, serialize(msg), qos, retain)

            # A kept message must go out once its slot opens: checked at least twice per period. The
            # supervision tick does that for rates up to half its own; only faster rules get a timer (every
            # timer wake-up costs the executor, and at the demo's rates the flush timers were most of them).
            if out.period >= 2.0 / SUPERVISION_RATE:
                self._flushers.append(flush)
            else:
                self.node.create_timer(out.period / 4, flush)
        if trace.TRACE is not None:
            untraced, ros_topic, tracer = forward, out.rule.ros_topic, trace.TRACE  # set once, at import

            def forward(msg: Any) -> None:
                tracer.mark("ros_in", ros_topic)
                untraced(msg)

        self.node.create_subscription(out.ros_cls, out.rule.ros_topic, forward, ros_qos(out.rule.ros_qos))

    def link_publish_qos(self, topic: str, payload: bytes, qos: int) -> None:
        self.link.publish(topic, payload, qos)

    def _tick_provided_actions(self, now: float) -> None:
        """Their timeouts and servers: here, or on their own executor (10 Hz, and only while any exist: every
        wake-up of a Python executor costs, and the point of the split is a bridge that costs little)."""
        actions = self.provided_actions
        if self.action_on_executor is self.on_executor:
            actions.expire(now)
            actions.refresh()
            return
        self._ticks += 1
        if self._ticks % 2 == 0 and actions.busy():
            def tick() -> None:
                actions.expire(time.monotonic())
                actions.refresh()

            self.action_on_executor.run(tick)

    # -- supervision (executor, 20 Hz) -------------------------------------------------
    def supervise(self) -> None:
        now = time.monotonic()
        refresh = self.robot.bridge.retained_refresh
        if refresh and now - self._retained_at >= refresh and self.link.connected.is_set():
            self._retained_at = now
            self.publish_access()
            self.publish_description()
            self.endpoint.publish_control()
        self.systemd.ping()  # from here: a starved executor stops the pings and systemd restarts us
        if now >= self._graph_check_at:
            self._graph_check_at = now + GRAPH_CHECK_PERIOD
            self.check_graph()
        self.endpoint.supervise(now)
        self.services.expire(now)
        self.provided.expire(now)
        self.actuators.expire(now)
        self.actions.supervise(now)
        self.parameters.expire(now)
        self._tick_provided_actions(now)
        self.provided.refresh()
        for flush in self._flushers:
            flush()
        self.on_demand.refresh()
        self.sdk_params.refresh()
        for port in self._supervised:  # the ROS modules' own ports (bridge/ros/ports.py)
            port.supervise(now)
