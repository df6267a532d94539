"""The fleet as typed, validated objects (what robots.yaml becomes).

Everything here is immutable: the broker swaps a whole new Fleet on SIGHUP
instead of editing one in place, so a half-applied reload cannot exist.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from functools import cached_property
from typing import Any

from ..compat import StrEnum
from ..protocol.enums import RobotType
from ..topics import TopicTree


class Role(StrEnum):
    OPERATOR = "operator"  # may watch and command
    VIEWER = "viewer"  # may watch, and call read-only services


class Direction(StrEnum):
    ROS_TO_MQTT = "ros_to_mqtt"
    MQTT_TO_ROS = "mqtt_to_ros"


# How a ros_to_mqtt rule's payload is encoded (docs/protocol.md, "State encodings").
ENCODING_JSON, ENCODING_CBOR, ENCODING_RAW = "json", "cbor", "raw"
ENCODINGS = (ENCODING_JSON, ENCODING_CBOR, ENCODING_RAW)
RAW_TYPES = ("sensor_msgs/msg/CompressedImage",)  # the types whose payload can be their bytes alone
ESTOP_PRESET = "emergency_stop"  # the preset whose rules are emergency stops
BUFFER_NONE, BUFFER_DISK = "none", "disk"
BUFFERS = (BUFFER_NONE, BUFFER_DISK)


class Priority(IntEnum):
    """A ros_to_mqtt rule's class on the robot's uplink, in the order the link serves them (docs/config.md,
    "Weak links"). The bridge's own control traffic (heartbeat, acks, replies, errors) is always ``control``."""

    CONTROL = 0  # sent at once, never held back: alarms a rule must not delay
    MOTION = 1  # where the robot is and how it moves
    STATE = 2  # other telemetry
    BULK = 3  # images, clouds, maps: what the link has left, on a connection of its own


PRIORITY_NAMES = tuple(p.name.lower() for p in Priority)
# Defaults by preset, then by ROS type; everything else is STATE.
PRESET_PRIORITIES = {"global_motion": Priority.MOTION, "image": Priority.BULK, "map": Priority.BULK}
TYPE_PRIORITIES = {
    "nav_msgs/msg/Odometry": Priority.MOTION,
    "geometry_msgs/msg/PoseStamped": Priority.MOTION,
    "geometry_msgs/msg/PoseWithCovarianceStamped": Priority.MOTION,
    "geometry_msgs/msg/Pose": Priority.MOTION,
    "geometry_msgs/msg/Twist": Priority.MOTION,
    "geometry_msgs/msg/TwistStamped": Priority.MOTION,
    "tf2_msgs/msg/TFMessage": Priority.MOTION,
    "sensor_msgs/msg/Image": Priority.BULK,
    "sensor_msgs/msg/CompressedImage": Priority.BULK,
    "sensor_msgs/msg/PointCloud2": Priority.BULK,
    "nav_msgs/msg/OccupancyGrid": Priority.BULK,
}


def default_priority(preset: str | None, ros_type: str) -> Priority:
    """A ros_to_mqtt rule's class when robots.yaml does not say: motion for poses and odometry, bulk for images,
    clouds and maps, state for the rest."""
    if preset is not None and preset in PRESET_PRIORITIES:
        return PRESET_PRIORITIES[preset]
    return TYPE_PRIORITIES.get(ros_type, Priority.STATE)


def default_latest_only(retain: bool, mqtt_qos: int) -> bool:
    """State streams are latest-wins unless retained or QoS 1/2, which are ordered and never silently dropped."""
    return not retain and mqtt_qos == 0


@dataclass(frozen=True, slots=True)
class TlsSettings:
    port: int
    certfile: str
    keyfile: str
    cafile: str | None = None
    # The address the TLS listener binds when not broker.host: a public TLS listener while the plain and WebSocket
    # ones stay on loopback (for local programs and a TLS-terminating proxy)
    host: str | None = None
    ws_port: int | None = None  # MQTT over secure WebSocket (wss://), on the TLS listener's address; None: none


@dataclass(frozen=True, slots=True)
class BrokerSettings:
    host: str = "127.0.0.1"
    port: int = 1883  # 0: no plain MQTT listener (a TLS-only deployment)
    ws_port: int | None = 8083
    ws_host: str | None = None  # where the WebSocket listener binds when not ``host``
    tls: TlsSettings | None = None
    max_payload: int = 4 * 1024 * 1024
    # Plain (not TLS) listeners on a non-loopback host carry every password in clear text: refused unless this says
    # the network is trusted (config/exposure.py)
    allow_plaintext: bool = False

    def ws_bind(self, host: str | None = None) -> str:
        """Where the plain WebSocket listener binds; ``host``: the plain listeners' host when overridden."""
        return self.ws_host or (self.host if host is None else host)

    def tls_host(self, host: str | None = None) -> str | None:
        """Where the TLS listener binds (None: no TLS); ``host``: the plain listeners' host when overridden."""
        if self.tls is None:
            return None
        return self.tls.host or (self.host if host is None else host)


LIMIT_NORM, LIMIT_PER_AXIS = "norm", "per_axis"
LIMIT_MODES = (LIMIT_NORM, LIMIT_PER_AXIS)
ROBOT_FILE = "robot_file"  # the top-level key of a robot file (`fleet split`): the robot it is for
EXECUTORS = ("single", "events")  # bridge.executor: rclpy's SingleThreadedExecutor, or its EventsExecutor


@dataclass(frozen=True, slots=True)
class VelocityLimits:
    """Absolute speed limits.

    ``norm`` (default) bounds the length of the linear and of the angular
    vector, scaling an over-limit vector down whole; ``per_axis`` clamps each
    component into ±limit on its own (then the combined speed may reach
    √3 × limit).
    """

    linear: float = 0.5  # m/s
    angular: float = 1.5  # rad/s
    mode: str = LIMIT_NORM  # LIMIT_MODES


@dataclass(frozen=True, slots=True)
class RosQos:
    depth: int = 10
    reliability: str = "reliable"  # reliable | best_effort
    durability: str = "volatile"  # volatile | transient_local


@dataclass(frozen=True, slots=True)
class Rule:
    """One topic mapping between the robot's ROS graph and MQTT."""

    index: int
    direction: Direction
    ros_topic: str
    ros_type: str
    mqtt_topic: str  # under state/ (ros_to_mqtt) or from/<user>/ (mqtt_to_ros)
    preset: str | None = None
    mqtt_qos: int = 0
    retain: bool = False
    ros_qos: RosQos = field(default_factory=RosQos)
    max_rate: float | None = None  # Hz; newest wins
    fields: dict[str, str] = field(default_factory=dict)  # mqtt field -> ros field path
    limits: VelocityLimits | None = None
    on_demand: bool = False  # mqtt_to_ros: the ROS publisher exists only while a live operator advertises it
    line: int | None = None
    encoding: str = ENCODING_JSON  # ros_to_mqtt: ENCODINGS
    # ros_to_mqtt: the uplink class and latest-wins; None = the default for the preset/type (default_priority,
    # default_latest_only), resolved by the properties below so a Rule built in code gets them too
    priority_setting: Priority | None = None
    latest_only_setting: bool | None = None
    buffer: str = BUFFER_NONE  # ros_to_mqtt: BUFFERS; "disk" keeps messages offered while the broker is away

    @property
    def priority(self) -> Priority:
        if self.priority_setting is not None:
            return self.priority_setting
        return default_priority(self.preset, self.ros_type)

    @property
    def latest_only(self) -> bool:
        if self.latest_only_setting is not None:
            return self.latest_only_setting
        return default_latest_only(self.retain, self.mqtt_qos)

    @property
    def label(self) -> str:
        arrow = "→"
        if self.direction is Direction.ROS_TO_MQTT:
            return f"rules[{self.index}] ({self.ros_topic} {arrow} {self.mqtt_topic})"
        return f"rules[{self.index}] ({self.mqtt_topic} {arrow} {self.ros_topic})"


@dataclass(frozen=True, slots=True)
class ServiceRule:
    """A ROS service on the robot that MQTT users may call."""

    name: str  # MQTT name: call/<name>
    ros_service: str
    ros_type: str
    read_only: bool = False  # viewers may call read-only services
    timeout: float = 5.0
    line: int | None = None


@dataclass(frozen=True, slots=True)
class ActionRule:
    """A ROS action on the robot that MQTT users may send goals to (docs/protocol.md, "Actions")."""

    name: str  # MQTT name: goal/<name>, cancel/<name>
    ros_action: str  # resolved by the bridge node, so remapping and namespaces apply
    ros_type: str  # pkg/action/Type
    viewers: bool = False  # viewers may send goals too (operators always may)
    timeout: float = 60.0  # s from acceptance to result; the bridge cancels the goal and reports "timeout" after
    feedback_rate: float = 10.0  # Hz at most per goal; newer feedback replaces older (newest wins)
    line: int | None = None


@dataclass(frozen=True, slots=True)
class ParameterRule:
    """A ROS node whose parameters MQTT users may read (every granted user) and set (operators)."""

    name: str  # MQTT name: param/<name>
    node: str  # the ROS node's name; relative names resolve in the bridge node's namespace
    viewers_may_set: bool = False  # viewers may set too (they may always read)
    timeout: float = 5.0  # s for the node's parameter services to answer
    line: int | None = None


@dataclass(frozen=True, slots=True)
class FailsafeAction:
    """A ROS message the bridge publishes on every failsafe stop (e.g. cancel a goal, raise an e-stop line)."""

    ros_topic: str
    ros_type: str
    message: dict[str, Any] = field(default_factory=dict)  # JSON form of the message (generic conversion)


@dataclass(frozen=True, slots=True)
class SnapshotTopic:
    """A ROS topic the bridge keeps in its snapshot ring buffer (as CDR, the way ``ros2 bag`` records it)."""

    ros_topic: str
    ros_type: str  # pkg/msg/Type


SNAPSHOT_WHO = ("operators", "viewers")


@dataclass(frozen=True, slots=True)
class SnapshotSettings:
    """On-robot snapshots (docs/recording.md, "Snapshots"): the last ``seconds`` of ``topics``, at most
    ``max_bytes`` (the oldest go first), sent as MCAP to whom ``who`` names, and written to ``dir`` on every
    failsafe stop (``on_failsafe``; the newest ``keep`` files stay)."""

    topics: tuple[SnapshotTopic, ...]
    seconds: float = 30.0
    max_bytes: int = 32 * 1024 * 1024
    who: str = "operators"
    on_failsafe: bool = True
    dir: str | None = None  # None: $STATE_DIRECTORY/snapshots (systemd), else ~/.local/state/roslink-mqtt/snapshots
    keep: int = 20


VIDEO_CODECS = ("h264", "vp8", "vp9", "av1")
VIDEO_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
VIDEO_PRIORITIES = ("state", "bulk")  # a video stream's class on the uplink (VideoStream.priority)


@dataclass(frozen=True, slots=True)
class VideoStream:
    """A camera the bridge sends as video (docs/video.md): encoded once on the robot while someone watches, at the
    bitrate the uplink leaves after control and state, on ``state/<name>``. Every granted user may watch (a viewer
    too: the frames are state, which every granted user reads).

    ``ladder``: (width, height, fps) from the largest to the smallest; () takes the camera's own size at ``fps``
    and at 20, then ¾, ½ and ¼ of it (``roslink_mqtt.video.ladder.Ladder.for_camera``)."""

    name: str
    ros_topic: str
    ros_type: str  # VIDEO_TYPES
    codec: str = "h264"
    fps: float = 30.0  # the most frames a second it is sent at
    ladder: tuple[tuple[int, int, float], ...] = ()
    min_kbit_s: float = 50.0
    max_kbit_s: float = 2000.0
    # its class on the uplink: STATE shares what motion leaves with the other state (a camera an operator drives by
    # is worth as much as a laser scan); BULK takes only what state leaves (a camera watched now and then)
    priority: Priority = Priority.STATE
    line: int | None = None


VDA_KINEMATICS = ("DIFF", "OMNI", "THREEWHEEL")
VDA_CALL_TYPES = ("std_srvs/srv/Trigger", "std_srvs/srv/Empty")  # what a mapped instant action may call
VDA_BUILT_IN_ACTIONS = ("startPause", "stopPause", "cancelOrder", "stateRequest", "factsheetRequest")


@dataclass(frozen=True, slots=True)
class Vda5050Call:
    """An instant action the robot carries out by calling a ROS service (``startCharging`` → ``dock``)."""

    action_type: str
    service: str
    service_type: str = "std_srvs/srv/Trigger"

VDA_CLASSES = ("FORKLIFT", "CONVEYOR", "TUGGER", "CARRIER")


@dataclass(frozen=True, slots=True)
class Vda5050Settings:
    """The robot speaks VDA 5050 2.1.0 to a master control (docs/vda5050.md): its topics
    ``uagv/v2/<manufacturer>/<serial_number>/…``, orders driven through the ROS action ``navigate`` (the shape of
    Nav2's NavigateToPose), pose and velocity from ``odometry``, charge from ``battery``. ``master`` is the one
    login that may send orders and instant actions (an operator of the robot); the factsheet gives the vehicle's
    size and kind."""

    manufacturer: str
    serial_number: str
    map_id: str
    master: str
    width: float  # m, for the factsheet's physicalParameters
    length: float
    height: float
    acceleration: float = 0.5  # m/s², the factsheet's accelerationMax and decelerationMax
    navigate: str = "navigate_to_pose"
    navigate_type: str = "nav2_msgs/action/NavigateToPose"  # any action whose goal has `pose` (PoseStamped)
    frame: str = "map"  # the frame of the nodes' positions (the goals' header.frame_id and the odometry's pose)
    odometry: str = "odom"
    battery: str = "battery_state"  # sensor_msgs/msg/BatteryState: batteryState (charge, charging, voltage)
    estop: str | None = None  # std_msgs/msg/Bool from the robot's own e-stop: true = pressed (eStop MANUAL)
    actions: tuple[Vda5050Call, ...] = ()  # instant actions carried out through ROS services
    tolerance: float = 0.25  # m: "on the node" when an order's node allows no deviation of its own
    state_interval: float = 30.0  # s: a state at least this often (and on every event)
    visualization_interval: float = 1.0  # s between visualization messages; 0: none
    series_name: str = "ROSLink robot"
    kinematic: str = "DIFF"
    vehicle_class: str = "CARRIER"


@dataclass(frozen=True, slots=True)
class BridgeSettings:
    broker_url: str = "mqtt://127.0.0.1:1883"
    password: str | None = None  # plaintext: demo only; prefer env or password_file
    password_file: str | None = None
    keepalive: int = 5  # s
    heartbeat_period: float = 1.0  # s
    operator_timeout: float = 1.5  # s
    command_timeout: float = 1.0  # s
    link_timeout: float = 0.5  # s without PUBACK for a heartbeat = broker lost
    stop_hold: float = 0.5  # s: zero velocity is repeated at 20 Hz this long after a stop
    limits: VelocityLimits = field(default_factory=VelocityLimits)
    on_failsafe: tuple[FailsafeAction, ...] = ()
    # Services MQTT clients provide to ROS: the ROS request/response queue depth of each, and how many calls
    # may wait for their providers at once (all services together); calls beyond that fail at once.
    provided_queue_depth: int = 100
    provided_max_calls: int = 64
    # Service calls and parameter requests one user may have unanswered at once (goals have their own bound):
    # a flood of requests never queues unbounded work on the robot's ROS nodes.
    max_requests_per_user: int = 16
    # Messages a second the bridge reads from viewers (their requests and presence, all of them together, on a
    # connection of their own): a viewer's flood waits at the broker instead of taking the bridge's time.
    viewer_message_rate: float = 500.0
    # The rclpy executor: "events" (rclpy.experimental.EventsExecutor: about a third of the CPU of the other at
    # the demo's rates; actions provided by MQTT clients then get a small single-threaded executor of their own)
    # or "single" (SingleThreadedExecutor for everything).
    executor: str = "events"
    # s between re-publications of the retained description and access reports (0: only on connecting). A broker
    # cluster that keeps retained messages per node (RabbitMQ 3.10) gives them only to clients on the bridge's
    # node: with this set, clients on every node have them within that time (docs/scaling.md).
    retained_refresh: float = 0.0
    # What the robot sends on its uplink (docs/config.md, "Weak links"): "scheduled" keeps state the link cannot
    # carry yet in latest-wins slots served by priority, with at most uplink_target_delay s of data waiting in the
    # network beyond one round trip; "fifo" hands every message to the network at once (the behaviour before,
    # and every other ROS bridge's; for comparison: on a thin link its queue grows to seconds of stale data).
    uplink: str = "scheduled"
    uplink_target_delay: float = 0.1
    # Rules with `buffer: disk` keep what they offer while the broker is unreachable in files under buffer_dir
    # (None: $STATE_DIRECTORY from systemd, else ~/.local/state/roslink-mqtt), at most buffer_max_bytes and
    # buffer_max_age s old, and send it after reconnecting, oldest first, after live data (docs/config.md).
    buffer_dir: str | None = None
    buffer_max_bytes: int = 64 * 1024 * 1024
    buffer_max_age: float = 24 * 3600.0
    # When the broker refuses the robot's login (wrong username or password): False keeps retrying, slowly (5 s,
    # doubling up to 60 s), so a fixed password (the broker reloaded) brings the robot back by itself; True exits with
    # EXIT_LOGIN_REFUSED (5), which the systemd unit does not restart (RestartPreventExitStatus).
    exit_on_refused_login: bool = False


@dataclass(frozen=True, slots=True)
class Robot:
    name: str
    system_id: int
    key: str
    password_hash: str
    type: RobotType = RobotType.GROUND
    bridge: BridgeSettings = field(default_factory=BridgeSettings)
    rules: tuple[Rule, ...] = ()
    services: tuple[ServiceRule, ...] = ()
    actions: tuple[ActionRule, ...] = ()
    parameters: tuple[ParameterRule, ...] = ()
    # Who drives (docs/safety.md, "One driver"): "auto" lets an operator's first command claim a free control
    # lease, "explicit" needs a claim first; supervisors take over by claiming and only another supervisor takes
    # their lease; estop "viewers" lets every granted user press the emergency stop, "operators" only operators.
    control: str = "auto"
    supervisors: tuple[str, ...] = ()
    estop: str = "viewers"
    # A password being rotated (docs/operations.md, "Rotate a robot's password"): the previous one's hash, still
    # accepted until the robot's bridge has moved to the new one; "" when none.
    previous_password_hash: str = ""
    snapshot: SnapshotSettings | None = None  # None: the bridge keeps no ring buffer and refuses snapshot requests
    vda5050: Vda5050Settings | None = None  # None: the robot speaks ROSLink only
    video: tuple[VideoStream, ...] = ()

    def video_stream(self, name: str) -> VideoStream | None:
        return next((v for v in self.video if v.name == name), None)

    @property
    def estop_inputs(self) -> tuple[str, ...]:
        """The leaves (``cmd/emergency_stop``) of the robot's emergency-stop rules: no lease, open to viewers when
        ``estop`` says so (the broker's ACL and the bridge read this one list)."""
        return tuple(r.mqtt_topic for r in self.rules
                     if r.direction is Direction.MQTT_TO_ROS and r.preset == ESTOP_PRESET)

    def service(self, name: str) -> ServiceRule | None:
        return next((s for s in self.services if s.name == name), None)

    def action(self, name: str) -> ActionRule | None:
        return next((a for a in self.actions if a.name == name), None)


@dataclass(frozen=True, slots=True)
class Grant:
    key: str
    role: Role


@dataclass(frozen=True, slots=True)
class User:
    name: str
    password_hash: str
    grants: tuple[Grant, ...] = ()
    admin: bool = False


@dataclass(frozen=True)
class Fleet:
    file: str
    prefix: str
    broker: BrokerSettings
    robots: dict[str, Robot]
    users: dict[str, User]
    # "file:line key: …" for what loading could not check without ROS (types outside common_interfaces);
    # not errors: the bridge checks those when it starts.
    notes: tuple[str, ...] = ()
    # A robot file (``roslink-mqtt fleet split``): this robot's part of the fleet for its bridge, with no password
    # hash of any login (every password_hash is ""); None for the fleet file itself.
    robot_file: str | None = None
    # A robot file's users come from the broker (``P/<robot>/grants``, protocol/grants.py): until they arrive the
    # bridge knows nobody and refuses every command with that reason. False once they have (config/grants.py).
    grants_pending: bool = False

    @cached_property
    def topics(self) -> TopicTree:
        """The fleet's topic grammar (built once: the broker asks on every PUBLISH)."""
        return TopicTree(self.prefix)

    @cached_property
    def _robots_by_key(self) -> dict[str, Robot]:
        by_key: dict[str, Robot] = {}
        for robot in self.robots.values():
            by_key.setdefault(robot.key, robot)  # the first robot with a key, as a scan in order finds it
        return by_key

    def robot_by_key(self, key: str) -> Robot | None:
        return self._robots_by_key.get(key)

    def roles_of(self, user: str) -> dict[str, Role]:
        """Robots a user may access, with the strongest role granted for each."""
        u = self.users.get(user)
        if u is None:
            return {}
        if u.admin:
            return {name: Role.OPERATOR for name in self.robots}
        roles: dict[str, Role] = {}
        for grant in u.grants:
            robot = self.robot_by_key(grant.key)
            if robot is not None and roles.get(robot.name) is not Role.OPERATOR:
                roles[robot.name] = grant.role
        return roles

    @cached_property
    def _users_by_robot(self) -> dict[str, dict[str, Role]]:
        """Every robot's users, worked out once (the fleet is frozen). Why: the broker and ``fleet apply`` ask for
        each robot; asked each time, a fleet of 1,000 robots and 1,000 users cost the embedded broker 15 s of CPU
        at start (a scan of every user's grants per robot, and of every robot per grant), with its listener
        open: logins waited, a fleet took 44–79 s to connect (bench/fleet.py, py-spy)."""
        by_robot: dict[str, dict[str, Role]] = {}
        for name in self.users:
            for robot, role in self.roles_of(name).items():
                by_robot.setdefault(robot, {})[name] = role
        return by_robot

    def users_of(self, robot: str) -> dict[str, Role]:
        """Users granted ``robot`` (admins included), with their role, in the fleet file's order."""
        return dict(self._users_by_robot.get(robot, {}))

    def accepted_hashes(self, username: str) -> tuple[str, ...]:
        """Every hash a login's password may match: its own, and a robot's previous one while it is rotated."""
        robot = self.robots.get(username)
        if robot is not None and robot.previous_password_hash:
            return (robot.password_hash, robot.previous_password_hash)
        stored = self.password_hash(username)
        return (stored,) if stored is not None else ()

    def password_hash(self, username: str) -> str | None:
        """The stored hash for a robot or user login name."""
        if username in self.robots:
            return self.robots[username].password_hash
        if username in self.users:
            return self.users[username].password_hash
        return None
