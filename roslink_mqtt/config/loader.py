"""robots.yaml → :class:`Fleet`, with errors that name file, line and key path."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path as FsPath
from typing import Any

from .. import ros_names
from ..protocol.enums import RobotType
from ..protocol.lease import CONTROL_MODES, ESTOP_MODES  # robots.<name>.control, .estop: state/control says them
from ..protocol.link import UPLINK_MODES  # bridge.uplink: state/link says it
from ..protocol.messages import SPECS_BY_NAME
from ..protocol.messages import Direction as MsgDirection
from ..ros_names import well_formed
from ..topics import (
    BRIDGE_STATE_NAMES,
    OPERATORS,
    RESERVED_RULE_LEVELS,
    TopicError,
    TopicTree,
    Verb,
    check_name,
    check_path,
    first_level,
    join_leaf,
    last_level,
    state_leaf,
    state_rule_name,
)
from .interfaces import SERVICE_PRESETS, UNCHECKED, VELOCITY_TYPES, interface_table, preset_type_problem
from .model import (
    BUFFER_NONE,
    BUFFERS,
    ENCODING_JSON,
    ENCODING_RAW,
    ENCODINGS,
    EXECUTORS,
    LIMIT_MODES,
    PRIORITY_NAMES,
    RAW_TYPES,
    ROBOT_FILE,
    SNAPSHOT_WHO,
    VDA_BUILT_IN_ACTIONS,
    VDA_CALL_TYPES,
    VDA_CLASSES,
    VDA_KINEMATICS,
    VIDEO_CODECS,
    VIDEO_PRIORITIES,
    VIDEO_TYPES,
    ActionRule,
    BridgeSettings,
    BrokerSettings,
    Direction,
    FailsafeAction,
    Fleet,
    Grant,
    ParameterRule,
    Priority,
    Robot,
    Role,
    RosQos,
    Rule,
    ServiceRule,
    SnapshotSettings,
    SnapshotTopic,
    TlsSettings,
    User,
    Vda5050Call,
    Vda5050Settings,
    VelocityLimits,
    VideoStream,
)
from .passwords import PasswordHashError, check_hash_format
from .yamlsource import ConfigError, Path, Source, load_yaml

_REQUIRED: Any = object()
_VDA_LEVEL = re.compile(r"^[A-Za-z0-9_.:-]+$")  # VDA 5050 §6.3: the characters of a topic level
_VDA_ACTION = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")  # an actionType (startCharging, initPosition, …)
_ROS_NAME = re.compile(r"^~?/?[A-Za-z_{][A-Za-z0-9_{}]*(/[A-Za-z_{][A-Za-z0-9_{}]*)*$")
_MQTT_URL = re.compile(r"^(mqtts?|ws|wss)://[^:/\s]+(:\d{1,5})?/?$")


def load_fleet(path: str | FsPath, *, need_hashes: bool = False) -> Fleet:
    """Load and validate a fleet file (or a robot file: ``robot_file``); raise ConfigError (with file:line) if
    anything is wrong. ``need_hashes``: the caller checks logins (the broker, an ACL export), which a robot file,
    holding no password hashes, cannot serve."""
    name = str(path)
    try:
        text = FsPath(path).read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"cannot read fleet file: {err.strerror or err}", file=name) from None
    fleet = parse_fleet(text, name)
    if need_hashes and fleet.robot_file is not None:
        raise ConfigError(f"this is the robot file of {fleet.robot_file} (written by `roslink-mqtt fleet split`: no "
                          "password hashes): the broker and the ACL exports need the fleet file (robots.yaml)",
                          file=name)
    return fleet


def parse_fleet(text: str, file: str = "<string>") -> Fleet:
    return _FleetReader(load_yaml(text, file)).fleet()


class _FleetReader:
    def __init__(self, source: Source) -> None:
        self.src = source
        self.robot_file: str | None = None  # a robot file's robot (no password hashes), read first
        self.types = interface_table()
        self.notes: list[str] = []  # what could not be checked here (types outside the table)

    # -- primitive readers --------------------------------------------------
    def err(self, path: Path, message: str) -> ConfigError:
        return self.src.error(path, message)

    def get(self, path: Path) -> Any:
        value: Any = self.src.data
        for part in path:
            value = value[part]
        return value

    def mapping(self, path: Path, allowed: tuple[str, ...]) -> dict[str, Any]:
        value = self.get(path)
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise self.err(path, f"expected a mapping, got {_show(value)}")
        for key in value:
            if key not in allowed:
                hint = _closest(key, allowed)
                raise self.err(path + (key,), f"unknown key '{key}'" + (f" (did you mean '{hint}'?)" if hint else
                                                                         f"; allowed: {', '.join(allowed)}"))
        return value

    def sequence(self, path: Path) -> list[Any]:
        value = self.get(path)
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.err(path, f"expected a list, got {_show(value)}")
        return value

    def value(self, parent: Path, key: str, check: Callable[[Path, Any], Any], default: Any = _REQUIRED) -> Any:
        data = self.get(parent)
        path = parent + (key,)
        if not isinstance(data, dict) or key not in data or data[key] is None:
            if default is _REQUIRED:
                raise self.err(parent, f"missing required key '{key}'")
            return default
        return check(path, data[key])

    def integer(self, lo: int, hi: int) -> Callable[[Path, Any], int]:
        def check(path: Path, v: Any) -> int:
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise self.err(path, f"expected integer {lo}..{hi}, got {_show(v)}")
            return v
        return check

    def number(self, lo: float, hi: float = math.inf, *, open_low: bool = False) -> Callable[[Path, Any], float]:
        def check(path: Path, v: Any) -> float:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if ok:
                ok = (v > lo if open_low else v >= lo) and v <= hi
            if not ok:
                low = f"> {lo}" if open_low else f">= {lo}"
                rng = low if hi == math.inf else f"{low} and <= {hi}"
                raise self.err(path, f"expected a finite number {rng}, got {_show(v)}")
            return float(v)
        return check

    def string(self, path: Path, v: Any) -> str:
        if not isinstance(v, str) or not v:
            raise self.err(path, f"expected a non-empty string, got {_show(v)}")
        return v

    def boolean(self, path: Path, v: Any) -> bool:
        if not isinstance(v, bool):
            raise self.err(path, f"expected true or false, got {_show(v)}")
        return v

    def choice(self, choices: tuple[str, ...]) -> Callable[[Path, Any], str]:
        def check(path: Path, v: Any) -> str:
            if not isinstance(v, str) or v not in choices:
                raise self.err(path, f"expected one of {', '.join(choices)}, got {_show(v)}")
            return v
        return check

    def topic_name(self, what: str) -> Callable[[Path, Any], str]:
        def check(path: Path, v: Any) -> str:
            try:
                return check_name(v, what)
            except TopicError as e:
                raise self.err(path, str(e)) from None
        return check

    def topic_path(self, path: Path, v: Any) -> str:
        try:
            return check_path(v, "topic")
        except TopicError as e:
            raise self.err(path, str(e)) from None

    def ros_type(self, kind: str) -> Callable[[Path, Any], str]:
        def check(path: Path, v: Any) -> str:
            if not well_formed(v, kind):
                example = {"msg": "geometry_msgs/msg/Twist", "srv": "std_srvs/srv/Trigger",
                           "action": "nav2_msgs/action/NavigateToPose"}[kind]
                raise self.err(path, f"expected a ROS {kind} type like {example}, got {_show(v)}")
            return v
        return check

    def interface(self, path: Path, name: str) -> None:
        """A type the table covers must exist there; any other is noted as unchecked (the bridge checks it)."""
        problem = self.types.type_problem(name)
        if problem:
            raise self.err(path, problem)
        if not self.types.covers(name):
            self.notes.append(str(self.err(path, f"{name} is not a common_interfaces type: it {UNCHECKED}")))

    def ros_name(self, path: Path, v: Any) -> str:
        if not isinstance(v, str) or not _ROS_NAME.match(v):
            raise self.err(path, f"expected a ROS name like 'cmd_vel' or '/robot/odom', got {_show(v)}")
        return v

    def login_hash(self, path: Path) -> str:
        """The ``password`` hash of the robot or user at ``path``; none ("") in a robot file, which must not hold one
        (it is copied to the robot: a stolen robot must not carry material for an offline attack on any login)."""
        if self.robot_file is None:
            hashed: str = self.value(path, "password", self.password_hash)
            return hashed
        if "password" in (self.get(path) or {}):
            raise self.err(path + ("password",), "a robot file holds no password hash: remove it (the robot's own "
                                                 "password comes from ROSLINK_PASSWORD, --password-file or "
                                                 "bridge.password_file; users log in at the broker)")
        return ""

    def password_hash(self, path: Path, v: Any) -> str:
        if not isinstance(v, str):
            raise self.err(path, f"expected a password hash string, got {_show(v)}")
        try:
            check_hash_format(v)
        except PasswordHashError as e:
            raise self.err(path, str(e)) from None
        return v

    # -- sections -------------------------------------------------------------
    def fleet(self) -> Fleet:
        root: Path = ()
        self.mapping(root, (ROBOT_FILE, "prefix", "broker", "robots", "users"))
        self.robot_file = self.value(root, ROBOT_FILE, self.topic_name("robot name"), None)
        prefix = self.value(root, "prefix", self.topic_path, "roslink")
        broker = self.broker(("broker",)) if "broker" in self.get(root) else BrokerSettings()
        robots = self.robots(("robots",))
        if self.robot_file is not None and list(robots) != [self.robot_file]:
            raise self.err(("robots",), f"a robot file holds its own robot only ('{self.robot_file}'), found: "
                                        f"{', '.join(robots)}")
        if self.robot_file is not None:
            if "users" in self.get(root):
                raise self.err(("users",), "a robot file holds no users: its bridge takes the robot's grants from "
                                           "the broker (roslink/<robot>/grants); write it again with "
                                           "`roslink-mqtt fleet split`")
            return Fleet(self.src.file, prefix, broker, robots, {}, tuple(self.notes), self.robot_file,
                         grants_pending=True)
        users = self.users(("users",), robots)
        self.check_supervisors(robots, users)
        self.check_vda5050(robots, users)
        return Fleet(self.src.file, prefix, broker, robots, users, tuple(self.notes), self.robot_file)

    def names(self, path: Path, what: str) -> tuple[str, ...]:
        """A list of login names (each a valid topic level), without repeats."""
        check = self.topic_name(what)
        names = tuple(check(path + (i,), v) for i, v in enumerate(self.sequence(path)))
        for i, name in enumerate(names):
            if name in names[:i]:
                raise self.err(path + (i,), f"'{name}' is listed twice")
        return names

    def check_supervisors(self, robots: dict[str, Robot], users: dict[str, User]) -> None:
        """A supervisor must be an operator of the robot (a grant with role operator, or an admin)."""
        keys = {r.key: r.name for r in robots.values()}
        for robot in robots.values():
            for i, name in enumerate(robot.supervisors):
                user = users.get(name)
                operator = user is not None and (user.admin or any(
                    keys.get(g.key) == robot.name and g.role is Role.OPERATOR for g in user.grants))
                if not operator:
                    why = "no such user" if user is None else f"'{name}' is not an operator of {robot.name}"
                    raise self.err(("robots", robot.name, "supervisors", i),
                                   f"a supervisor must be an operator of the robot: {why}")

    def check_vda5050(self, robots: dict[str, Robot], users: dict[str, User]) -> None:
        """A master control is an operator of its robot; no two robots share a VDA 5050 identity."""
        keys = {r.key: r.name for r in robots.values()}
        seen: dict[tuple[str, str], str] = {}
        for robot in robots.values():
            vda = robot.vda5050
            if vda is None:
                continue
            path = ("robots", robot.name, "vda5050")
            user = users.get(vda.master)
            if user is None or not (user.admin or any(keys.get(g.key) == robot.name and g.role is Role.OPERATOR
                                                      for g in user.grants)):
                why = "no such user" if user is None else f"'{vda.master}' is not an operator of {robot.name}"
                raise self.err(path + ("master",), f"the master control must be an operator of the robot: {why}")
            identity = (vda.manufacturer, vda.serial_number)
            if identity in seen:
                raise self.err(path + ("serial_number",), f"{vda.manufacturer}/{vda.serial_number} is already robot "
                                                          f"'{seen[identity]}'s VDA 5050 identity")
            seen[identity] = robot.name

    def broker(self, path: Path) -> BrokerSettings:
        self.mapping(path, ("host", "port", "ws_port", "ws_host", "tls", "max_payload", "allow_plaintext"))
        port = self.integer(1, 65535)
        tls = None
        if self.get(path) and self.get(path).get("tls") is not None:
            tp = path + ("tls",)
            self.mapping(tp, ("port", "certfile", "keyfile", "cafile", "host", "ws_port"))
            tls = TlsSettings(self.value(tp, "port", port, 8883), self.value(tp, "certfile", self.string),
                              self.value(tp, "keyfile", self.string), self.value(tp, "cafile", self.string, None),
                              self.value(tp, "host", self.string, None), self.value(tp, "ws_port", port, None))
        settings = BrokerSettings(
            host=self.value(path, "host", self.string, "127.0.0.1"),
            port=self.value(path, "port", self.integer(0, 65535), 1883),  # 0: no plain MQTT listener
            ws_port=self.value(path, "ws_port", self.integer(0, 65535), 8083) or None,
            ws_host=self.value(path, "ws_host", self.string, None),
            tls=tls,
            max_payload=self.value(path, "max_payload", self.integer(1024, 256 * 1024 * 1024), 4 * 1024 * 1024),
            allow_plaintext=self.value(path, "allow_plaintext", self.boolean, False),
        )
        if not settings.port and not settings.ws_port and tls is None:
            raise self.err(path + ("port",), "port: 0 turns the plain MQTT listener off, and there is no other "
                                             "(ws_port is off and no tls): the broker would accept no connection")
        return settings

    def robots(self, path: Path) -> dict[str, Robot]:
        data = self.get(path) if "robots" in self.src.data else None
        if not data:
            raise self.err((), "missing required key 'robots' (at least one robot)")
        if not isinstance(data, dict):
            raise self.err(path, f"expected a mapping of robot name to settings, got {_show(data)}")
        robots: dict[str, Robot] = {}
        seen_ids: dict[int, str] = {}
        seen_keys: dict[str, str] = {}
        for name in data:
            rp = path + (name,)
            self.topic_name("robot name")(rp, name)
            if name == OPERATORS:
                raise self.err(rp, f"'{OPERATORS}' is reserved in the topic tree; choose another robot name")
            robot = self.robot(rp, name)
            if robot.system_id in seen_ids:
                raise self.err(rp + ("system_id",), f"system_id {robot.system_id} is already used by robot "
                                                    f"'{seen_ids[robot.system_id]}'")
            if robot.key in seen_keys:
                raise self.err(rp + ("key",), f"key is already used by robot '{seen_keys[robot.key]}'")
            seen_ids[robot.system_id], seen_keys[robot.key] = name, name
            robots[name] = robot
        return robots

    def robot(self, path: Path, name: str) -> Robot:
        self.mapping(path, ("system_id", "key", "password", "previous_password", "type", "bridge", "rules",
                            "services", "actions", "parameters", "control", "supervisors", "estop", "snapshot",
                            "vda5050", "video"))
        types = tuple(t.name.lower() for t in RobotType)
        rtype = self.value(path, "type", self.choice(types), "ground")
        rules = self.rules(path + ("rules",)) if "rules" in self.get(path) else ()
        return Robot(
            name=name,
            system_id=self.value(path, "system_id", self.integer(0, 65535)),
            key=self.value(path, "key", self.string),
            password_hash=self.login_hash(path),
            type=RobotType[rtype.upper()],
            bridge=self.bridge(path + ("bridge",)) if self.get(path).get("bridge") is not None else BridgeSettings(),
            rules=rules,
            services=self.services(path + ("services",)) if "services" in self.get(path) else (),
            actions=self.actions(path + ("actions",)) if "actions" in self.get(path) else (),
            parameters=self.parameters(path + ("parameters",)) if "parameters" in self.get(path) else (),
            control=self.value(path, "control", self.choice(CONTROL_MODES), "auto"),
            supervisors=self.names(path + ("supervisors",), "supervisor") if "supervisors" in self.get(path) else (),
            estop=self.value(path, "estop", self.choice(ESTOP_MODES), "viewers"),
            previous_password_hash=self.previous_hash(path),
            snapshot=self.snapshot(path + ("snapshot",), rules) if self.get(path).get("snapshot") is not None
            else None,
            vda5050=self.vda5050(path + ("vda5050",), name) if self.get(path).get("vda5050") is not None else None,
            video=self.video(path + ("video",), rules) if self.get(path).get("video") is not None else (),
        )

    def video(self, path: Path, rules: tuple[Rule, ...]) -> tuple[VideoStream, ...]:
        """``video:``: the cameras sent as video, each on ``state/<name>`` (a name no rule's state uses)."""
        taken = {state_rule_name(r.mqtt_topic) for r in rules if r.direction is Direction.ROS_TO_MQTT}
        out: list[VideoStream] = []
        for i in range(len(self.sequence(path))):
            vp = path + (i,)
            self.mapping(vp, ("name", "ros_topic", "ros_type", "codec", "fps", "ladder", "min_kbit_s",
                              "max_kbit_s", "priority"))
            ros_topic = self.value(vp, "ros_topic", self.ros_name)
            name = self.value(vp, "name", self.topic_name("video stream name"), None) or ros_names.flat(ros_topic)
            if name in taken or name in BRIDGE_STATE_NAMES:
                raise self.err(vp + ("name",), f"state/{name} is already used (a rule's or the bridge's own): name "
                                               "the stream")
            taken.add(name)
            d = VideoStream(name, ros_topic, VIDEO_TYPES[0])
            low = self.value(vp, "min_kbit_s", self.number(8, 100_000), d.min_kbit_s)
            high = self.value(vp, "max_kbit_s", self.number(8, 100_000), d.max_kbit_s)
            if low > high:
                raise self.err(vp + ("min_kbit_s",), f"min_kbit_s {low:g} is above max_kbit_s {high:g}")
            fps = self.value(vp, "fps", self.number(0, 120, open_low=True), d.fps)
            out.append(VideoStream(
                name=name, ros_topic=ros_topic,
                ros_type=self.value(vp, "ros_type", self.choice(VIDEO_TYPES)),
                codec=self.value(vp, "codec", self.choice(VIDEO_CODECS), d.codec), fps=fps,
                ladder=self.video_ladder(vp + ("ladder",)) if self.get(vp).get("ladder") is not None else (),
                min_kbit_s=low, max_kbit_s=high, line=self.src.line_of(vp),
                priority=Priority[self.value(vp, "priority", self.choice(VIDEO_PRIORITIES), "state").upper()]))
        return tuple(out)

    def video_ladder(self, path: Path) -> tuple[tuple[int, int, float], ...]:
        """``ladder: [[640, 480, 30], [320, 240, 15]]``: sizes (even, 16..8192) and frame rates, largest first."""
        rungs: list[tuple[int, int, float]] = []
        for i in range(len(self.sequence(path))):
            rp = path + (i,)
            rung = self.get(rp)
            ok = isinstance(rung, list) and len(rung) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in rung)
            if not ok or rung[0] % 2 or rung[1] % 2 or not (16 <= rung[0] <= 8192 and 16 <= rung[1] <= 8192) \
                    or not 0 < rung[2] <= 120 or rung[0] != int(rung[0]) or rung[1] != int(rung[1]):
                raise self.err(rp, f"expected [width, height, fps]: even sizes 16..8192 and 0 < fps ≤ 120, got "
                                   f"{_show(rung)}")
            if rungs and rung[0] * rung[1] * rung[2] > rungs[-1][0] * rungs[-1][1] * rungs[-1][2]:
                raise self.err(rp, "rungs go from the largest (pixels a second) to the smallest")
            rungs.append((int(rung[0]), int(rung[1]), float(rung[2])))
        if not rungs:
            raise self.err(path, "a ladder needs at least one [width, height, fps] (or leave `ladder:` out)")
        return tuple(rungs)

    def vda5050(self, path: Path, robot: str) -> Vda5050Settings:
        """``vda5050:``: the robot's VDA 5050 identity (topic levels of the standard's own alphabet), its map, its
        master control's login, the ROS names it drives and reads, and what its factsheet says."""
        self.mapping(path, ("manufacturer", "serial_number", "map_id", "master", "navigate", "navigate_type", "frame",
                            "odometry", "battery", "estop", "actions", "tolerance", "state_interval",
                            "visualization_interval", "vehicle"))
        vp = path + ("vehicle",)
        if self.get(path).get("vehicle") is None:
            raise self.err(path, "missing required key 'vehicle' (the factsheet's width, length and height in m)")
        self.mapping(vp, ("width", "length", "height", "acceleration", "series_name", "kinematic", "class"))
        d = Vda5050Settings("", "", "", "", 0.0, 0.0, 0.0)
        size = self.number(0, 100, open_low=True)
        return Vda5050Settings(
            manufacturer=self.value(path, "manufacturer", self.vda_level),
            serial_number=self.value(path, "serial_number", self.vda_level, robot),
            map_id=self.value(path, "map_id", self.string),
            master=self.value(path, "master", self.topic_name("master control login")),
            width=self.value(vp, "width", size), length=self.value(vp, "length", size),
            height=self.value(vp, "height", size), acceleration=self.value(vp, "acceleration", size, d.acceleration),
            navigate=self.value(path, "navigate", self.ros_name, d.navigate),
            navigate_type=self.value(path, "navigate_type", self.ros_type("action"), d.navigate_type),
            frame=self.value(path, "frame", self.string, d.frame),
            odometry=self.value(path, "odometry", self.ros_name, d.odometry),
            battery=self.value(path, "battery", self.ros_name, d.battery),
            estop=self.value(path, "estop", self.ros_name, d.estop),
            actions=self.vda5050_calls(path + ("actions",)) if self.get(path).get("actions") is not None else (),
            tolerance=self.value(path, "tolerance", self.number(0, 100, open_low=True), d.tolerance),
            state_interval=self.value(path, "state_interval", self.number(1, 30), d.state_interval),
            visualization_interval=self.value(path, "visualization_interval", self.number(0, 60),
                                              d.visualization_interval),
            series_name=self.value(vp, "series_name", self.string, d.series_name),
            kinematic=self.value(vp, "kinematic", self.choice(VDA_KINEMATICS), d.kinematic),
            vehicle_class=self.value(vp, "class", self.choice(VDA_CLASSES), d.vehicle_class),
        )

    def vda5050_calls(self, path: Path) -> tuple[Vda5050Call, ...]:
        """``actions:`` instant action type → ``{service, type}``: what the robot does for the master's own
        instant actions (the factsheet lists them with the built-in ones)."""
        calls = []
        for name in self.mapping(path, tuple(self.get(path) or ())):
            ap = path + (name,)
            if not isinstance(name, str) or not _VDA_ACTION.match(name):
                raise self.err(ap, f"expected an instant action type (letters and digits), got {_show(name)}")
            if name in VDA_BUILT_IN_ACTIONS:
                raise self.err(ap, f"'{name}' is one of the standard's actions the bridge carries out itself")
            self.mapping(ap, ("service", "type"))
            calls.append(Vda5050Call(name, self.value(ap, "service", self.ros_name),
                                     self.value(ap, "type", self.choice(VDA_CALL_TYPES), "std_srvs/srv/Trigger")))
        return tuple(calls)

    def vda_level(self, path: Path, v: Any) -> str:
        """A VDA 5050 topic level (manufacturer, serial number): the standard's alphabet, A-Z a-z 0-9 _ . : -"""
        if not isinstance(v, str) or not _VDA_LEVEL.match(v):
            raise self.err(path, f"expected letters, digits and _ . : - only (a VDA 5050 topic level), got {_show(v)}")
        return v

    def snapshot(self, path: Path, rules: tuple[Rule, ...]) -> SnapshotSettings:
        """``snapshot:``: the ring buffer's topics (a ROS topic a ``ros_to_mqtt`` rule names, or
        ``{ros_topic, ros_type}``), its length and size, who may ask, and the failsafe's own snapshots."""
        self.mapping(path, ("topics", "seconds", "max_bytes", "who", "on_failsafe", "dir", "keep"))
        d = SnapshotSettings(())
        known = {r.ros_topic: r.ros_type for r in rules if r.direction is Direction.ROS_TO_MQTT}
        topics: list[SnapshotTopic] = []
        tp = path + ("topics",)
        for i in range(len(self.sequence(tp))):
            ep = tp + (i,)
            entry = self.get(ep)
            if isinstance(entry, str):
                name = self.ros_name(ep, entry)
                if name not in known:
                    raise self.err(ep, f"'{name}' is not the ros_topic of a ros_to_mqtt rule of this robot: give its "
                                       "type, {ros_topic: " + name + ", ros_type: pkg/msg/Type}")
                topic = SnapshotTopic(name, known[name])
            else:
                self.mapping(ep, ("ros_topic", "ros_type"))
                ros_type = self.value(ep, "ros_type", self.ros_type("msg"))
                self.interface(ep + ("ros_type",), ros_type)
                topic = SnapshotTopic(self.value(ep, "ros_topic", self.ros_name), ros_type)
            if any(t.ros_topic == topic.ros_topic for t in topics):
                raise self.err(ep, f"'{topic.ros_topic}' is listed twice")
            topics.append(topic)
        if not topics:
            raise self.err(tp, "a snapshot needs at least one ROS topic (or leave `snapshot:` out)")
        return SnapshotSettings(
            topics=tuple(topics),
            seconds=self.value(path, "seconds", self.number(0, 3600, open_low=True), d.seconds),
            max_bytes=self.value(path, "max_bytes", self.integer(65536, 1 << 34), d.max_bytes),
            who=self.value(path, "who", self.choice(SNAPSHOT_WHO), d.who),
            on_failsafe=self.value(path, "on_failsafe", self.boolean, d.on_failsafe),
            dir=self.value(path, "dir", self.string, d.dir),
            keep=self.value(path, "keep", self.integer(1, 100000), d.keep),
        )

    def previous_hash(self, path: Path) -> str:
        """A robot's ``previous_password`` (a hash, accepted with ``password`` while the robot moves to the new
        one); a robot file holds none either."""
        if "previous_password" not in self.get(path):
            return ""
        if self.robot_file is not None:
            raise self.err(path + ("previous_password",), "a robot file holds no password hash: remove it")
        hashed: str = self.value(path, "previous_password", self.password_hash)
        return hashed

    def limits(self, path: Path) -> VelocityLimits:
        self.mapping(path, ("linear", "angular", "mode"))
        d = VelocityLimits()
        return VelocityLimits(self.value(path, "linear", self.number(0), d.linear),
                              self.value(path, "angular", self.number(0), d.angular),
                              self.value(path, "mode", self.choice(LIMIT_MODES), d.mode))

    def bridge(self, path: Path) -> BridgeSettings:
        self.mapping(path, ("broker", "password", "password_file", "keepalive", "heartbeat_period",
                            "operator_timeout", "command_timeout", "link_timeout", "stop_hold", "limits",
                            "on_failsafe", "provided_queue_depth", "provided_max_calls",
                            "max_requests_per_user", "viewer_message_rate", "executor", "retained_refresh",
                            "uplink", "uplink_target_delay", "buffer_dir", "buffer_max_bytes", "buffer_max_age",
                            "exit_on_refused_login"))
        d = BridgeSettings()
        positive = self.number(0, 3600, open_low=True)

        def url(p: Path, v: Any) -> str:
            """One URL, or a cluster's nodes (a list, or comma-separated): the bridge fails over between them."""
            items = v if isinstance(v, list) else v.split(",") if isinstance(v, str) else [v]
            items = [i.strip() if isinstance(i, str) else i for i in items]
            if not items or any(not isinstance(i, str) or not _MQTT_URL.match(i) for i in items):
                raise self.err(p, "expected a broker URL like mqtt://host:1883 or mqtts://host:8883 (or a list of "
                                  f"them: a cluster's nodes), got {_show(v)}")
            if len({i.split(":", 1)[0] for i in items}) > 1:
                raise self.err(p, f"the broker URLs {_show(v)} mix schemes: the nodes of one list are reached one "
                                  "way (all mqtts://, say)")
            return ",".join(items)

        return BridgeSettings(
            broker_url=self.value(path, "broker", url, d.broker_url),
            password=self.value(path, "password", self.string, None),
            password_file=self.value(path, "password_file", self.string, None),
            keepalive=self.value(path, "keepalive", self.integer(1, 65535), d.keepalive),
            heartbeat_period=self.value(path, "heartbeat_period", positive, d.heartbeat_period),
            operator_timeout=self.value(path, "operator_timeout", positive, d.operator_timeout),
            command_timeout=self.value(path, "command_timeout", positive, d.command_timeout),
            link_timeout=self.value(path, "link_timeout", positive, d.link_timeout),
            stop_hold=self.value(path, "stop_hold", self.number(0, 60), d.stop_hold),
            limits=self.limits(path + ("limits",)) if self.get(path).get("limits") is not None else d.limits,
            on_failsafe=self.failsafe_actions(path + ("on_failsafe",)) if "on_failsafe" in self.get(path) else (),
            provided_queue_depth=self.value(path, "provided_queue_depth", self.integer(1, 10000),
                                            d.provided_queue_depth),
            provided_max_calls=self.value(path, "provided_max_calls", self.integer(1, 10000), d.provided_max_calls),
            max_requests_per_user=self.value(path, "max_requests_per_user", self.integer(1, 10000),
                                             d.max_requests_per_user),
            viewer_message_rate=self.value(path, "viewer_message_rate", self.number(1, 1_000_000),
                                           d.viewer_message_rate),
            executor=self.value(path, "executor", self.choice(EXECUTORS), d.executor),
            retained_refresh=self.value(path, "retained_refresh", self.number(0, 3600), d.retained_refresh),
            uplink=self.value(path, "uplink", self.choice(UPLINK_MODES), d.uplink),
            uplink_target_delay=self.value(path, "uplink_target_delay", self.number(0.01, 10),
                                           d.uplink_target_delay),
            buffer_dir=self.value(path, "buffer_dir", self.string, d.buffer_dir),
            buffer_max_bytes=self.value(path, "buffer_max_bytes", self.integer(65536, 1 << 40), d.buffer_max_bytes),
            buffer_max_age=self.value(path, "buffer_max_age", self.number(1, 366 * 24 * 3600), d.buffer_max_age),
            exit_on_refused_login=self.value(path, "exit_on_refused_login", self.boolean, d.exit_on_refused_login),
        )

    def failsafe_actions(self, path: Path) -> tuple[FailsafeAction, ...]:
        out = []
        for i in range(len(self.sequence(path))):
            ap = path + (i,)
            self.mapping(ap, ("ros_topic", "ros_type", "message"))
            message = self.get(ap).get("message") or {}
            if not isinstance(message, dict):
                raise self.err(ap + ("message",), f"expected a mapping (the ROS message as JSON), got {_show(message)}")
            ros_type = self.value(ap, "ros_type", self.ros_type("msg"))
            self.interface(ap + ("ros_type",), ros_type)
            out.append(FailsafeAction(self.value(ap, "ros_topic", self.ros_name), ros_type, message))
        return tuple(out)

    def rules(self, path: Path) -> tuple[Rule, ...]:
        rules = tuple(self.rule(path + (i,), i) for i in range(len(self.sequence(path))))
        outputs: dict[tuple[Direction, str], Rule] = {}
        ros_sides: dict[str, Rule] = {}
        for rule in rules:
            rp = path + (rule.index,)
            key = (rule.direction, rule.mqtt_topic)
            if key in outputs:
                raise self.err(rp + ("mqtt_topic",), f"{rule.label} duplicates {outputs[key].label}: "
                                                     f"same MQTT topic in the same direction")
            outputs[key] = rule
            other = ros_sides.get(rule.ros_topic)
            if other is not None:
                if other.direction is not rule.direction:
                    raise self.err(rp + ("ros_topic",), f"{rule.label} and {other.label} loop: the same ROS topic "
                                                        "is both published to and read from MQTT")
                if rule.direction is Direction.MQTT_TO_ROS:
                    raise self.err(rp + ("ros_topic",), f"{rule.label} duplicates {other.label}: two MQTT topics "
                                                        "write the same ROS topic")
            ros_sides.setdefault(rule.ros_topic, rule)
        return rules

    def rule(self, path: Path, index: int) -> Rule:
        self.mapping(path, ("direction", "ros_topic", "ros_type", "mqtt_topic", "preset", "mqtt_qos", "retain",
                            "ros_qos", "max_rate", "fields", "limits", "on_demand", "encoding", "priority",
                            "latest_only", "buffer"))
        direction = Direction(self.value(path, "direction", self.choice(tuple(d.value for d in Direction))))
        mqtt_topic = self.value(path, "mqtt_topic", self.topic_path)
        first = first_level(mqtt_topic)
        if direction is Direction.ROS_TO_MQTT and state_rule_name(mqtt_topic) is None:
            raise self.err(path + ("mqtt_topic",), f"a ros_to_mqtt rule publishes under state/, e.g. "
                                                   f"{state_leaf(last_level(mqtt_topic))}; got '{mqtt_topic}'")
        if direction is Direction.ROS_TO_MQTT and state_rule_name(mqtt_topic) in BRIDGE_STATE_NAMES:
            written = ", ".join(state_leaf(name) for name in BRIDGE_STATE_NAMES)
            raise self.err(path + ("mqtt_topic",), f"'{mqtt_topic}' is written by the bridge itself "
                                                   f"({written}); choose another name")
        if direction is Direction.MQTT_TO_ROS and first in RESERVED_RULE_LEVELS:
            example = TopicTree().from_user("<robot>", "<user>", "<mqtt_topic>")
            raise self.err(path + ("mqtt_topic",), f"'{first}/' is reserved; an mqtt_to_ros rule reads {example}, "
                                                   f"e.g. {join_leaf(Verb.CMD, 'twist')}")
        preset = self.value(path, "preset", self.choice(tuple(SPECS_BY_NAME)), None)
        if preset is not None:
            wanted = MsgDirection.STATE if direction is Direction.ROS_TO_MQTT else MsgDirection.COMMAND
            if SPECS_BY_NAME[preset].direction is not wanted:
                raise self.err(path + ("preset",), f"preset '{preset}' is a {SPECS_BY_NAME[preset].direction.value} "
                                                   f"message and cannot be used in a {direction.value} rule")
        # A command preset may also target a ROS service (e.g. arm → std_srvs/srv/SetBool): the bridge calls it.
        service_ok = direction is Direction.MQTT_TO_ROS and preset in SERVICE_PRESETS
        raw_type = self.get(path).get("ros_type")
        ros_type = self.value(path, "ros_type", self.ros_type(
            "srv" if service_ok and isinstance(raw_type, str) and ros_names.mentions_kind(raw_type, "srv") else "msg"))
        self.interface(path + ("ros_type",), ros_type)
        if preset is not None and (problem := preset_type_problem(preset, ros_type)):
            raise self.err(path + ("preset",), problem)
        qos = RosQos()
        if self.get(path).get("ros_qos") is not None:
            qp = path + ("ros_qos",)
            self.mapping(qp, ("depth", "reliability", "durability"))
            qos = RosQos(self.value(qp, "depth", self.integer(1, 10000), qos.depth),
                         self.value(qp, "reliability", self.choice(("reliable", "best_effort")), qos.reliability),
                         self.value(qp, "durability", self.choice(("volatile", "transient_local")), qos.durability))
        on_demand = self.value(path, "on_demand", self.boolean, False)
        if on_demand and (direction is not Direction.MQTT_TO_ROS or preset is not None):
            raise self.err(path + ("on_demand",), "on_demand applies to generic mqtt_to_ros rules only (ROSLink "
                                                  "commands keep their ROS publisher: the failsafe needs it)")
        if on_demand and ros_type in VELOCITY_TYPES:
            raise self.err(path + ("on_demand",), f"on_demand is not for velocity commands (the failsafe must "
                                                  f"always be able to publish zero velocity on {ros_type})")
        fields: dict[str, str] = {}
        if self.get(path).get("fields") is not None:
            fp = path + ("fields",)
            raw = self.get(fp)
            if not isinstance(raw, dict):
                raise self.err(fp, f"expected a mapping of MQTT field to ROS field path, got {_show(raw)}")
            for k, v in raw.items():
                fields[k] = self.string(fp + (k,), v)
                if problem := self.types.field_path_problem(ros_type, fields[k]):
                    raise self.err(fp + (k,), problem)
        encoding = self.encoding(path, direction, ros_type, preset, fields)
        priority = self.value(path, "priority", self.choice(PRIORITY_NAMES), None)
        latest_only = self.value(path, "latest_only", self.boolean, None)
        buffer = self.value(path, "buffer", self.choice(BUFFERS), None)
        if direction is Direction.MQTT_TO_ROS:
            for key, value in (("priority", priority), ("latest_only", latest_only), ("buffer", buffer)):
                if value is not None:
                    raise self.err(path + (key,), f"{key} applies to ros_to_mqtt rules only (what the robot sends "
                                                  "on its uplink); commands to the robot are checked for age instead")
        return Rule(
            index=index,
            direction=direction,
            ros_topic=self.value(path, "ros_topic", self.ros_name),
            ros_type=ros_type,
            mqtt_topic=mqtt_topic,
            preset=preset,
            mqtt_qos=self.value(path, "mqtt_qos", self.integer(0, 2), 0),
            retain=self.value(path, "retain", self.boolean, False),
            ros_qos=qos,
            max_rate=self.value(path, "max_rate", self.number(0, 10000, open_low=True), None),
            fields=fields,
            limits=self.limits(path + ("limits",)) if self.get(path).get("limits") is not None else None,
            on_demand=on_demand,
            line=self.src.line_of(path),
            encoding=encoding,
            priority_setting=Priority[priority.upper()] if priority is not None else None,
            latest_only_setting=latest_only,
            buffer=buffer or BUFFER_NONE,
        )

    def encoding(self, path: Path, direction: Direction, ros_type: str, preset: str | None,
                 fields: dict[str, str]) -> str:
        """A rule's ``encoding``: json (default), cbor or raw, where each makes sense (docs/config.md)."""
        encoding: str = self.value(path, "encoding", self.choice(ENCODINGS), ENCODING_JSON)
        if encoding == ENCODING_JSON:
            return encoding
        ep = path + ("encoding",)
        where = f"the rule at line {self.src.line_of(path)}"
        if direction is not Direction.ROS_TO_MQTT:
            raise self.err(ep, f"{where}: encoding '{encoding}' applies to ros_to_mqtt rules only (commands "
                               "arrive as JSON)")
        if preset is not None:
            raise self.err(ep, f"{where}: encoding '{encoding}' is for generic rules; preset '{preset}' publishes "
                               "a ROSLink message, which is always JSON")
        if encoding == ENCODING_RAW:
            if ros_type not in RAW_TYPES:
                raise self.err(ep, f"{where}: encoding 'raw' publishes the image bytes alone, so it needs ros_type "
                                   f"{' or '.join(RAW_TYPES)}, not {ros_type} (use 'cbor' to keep arrays binary)")
            if fields:
                raise self.err(ep, f"{where}: encoding 'raw' publishes the image bytes alone; it cannot select "
                                   "fields (drop 'fields' or use 'cbor')")
        return encoding

    def services(self, path: Path) -> tuple[ServiceRule, ...]:
        out: list[ServiceRule] = []
        names: set[str] = set()
        for i in range(len(self.sequence(path))):
            sp = path + (i,)
            self.mapping(sp, ("name", "ros_service", "ros_type", "read_only", "timeout"))
            ros_service = self.value(sp, "ros_service", self.ros_name)
            name = self.value(sp, "name", self.topic_path, None) or ros_names.flat(ros_service)
            if name in names:
                raise self.err(sp + ("name",), f"service name '{name}' is used twice")
            names.add(name)
            ros_type = self.value(sp, "ros_type", self.ros_type("srv"))
            self.interface(sp + ("ros_type",), ros_type)
            out.append(ServiceRule(name, ros_service, ros_type,
                                   self.value(sp, "read_only", self.boolean, False),
                                   self.value(sp, "timeout", self.number(0, 3600, open_low=True), 5.0),
                                   self.src.line_of(sp)))
        return tuple(out)

    def actions(self, path: Path) -> tuple[ActionRule, ...]:
        out: list[ActionRule] = []
        names: set[str] = set()
        for i in range(len(self.sequence(path))):
            ap = path + (i,)
            self.mapping(ap, ("name", "ros_action", "ros_type", "viewers", "timeout", "feedback_rate"))
            ros_action = self.value(ap, "ros_action", self.ros_name)
            name = self.value(ap, "name", self.topic_path, None) or ros_names.flat(ros_action)
            if name in names:
                raise self.err(ap + ("name",), f"action name '{name}' is used twice")
            names.add(name)
            ros_type = self.value(ap, "ros_type", self.ros_type("action"))
            self.interface(ap + ("ros_type",), ros_type)
            out.append(ActionRule(name, ros_action, ros_type,
                                  self.value(ap, "viewers", self.boolean, False),
                                  self.value(ap, "timeout", self.number(0, 86400, open_low=True), 60.0),
                                  self.value(ap, "feedback_rate", self.number(0, 1000, open_low=True), 10.0),
                                  self.src.line_of(ap)))
        return tuple(out)

    def parameters(self, path: Path) -> tuple[ParameterRule, ...]:
        out: list[ParameterRule] = []
        names: set[str] = set()
        for i in range(len(self.sequence(path))):
            pp = path + (i,)
            self.mapping(pp, ("node", "name", "viewers_may_set", "timeout"))
            node = self.value(pp, "node", self.ros_name)
            name = self.value(pp, "name", self.topic_name("parameter name"), None) or ros_names.flat(node)
            if name in names:
                raise self.err(pp + ("name",), f"parameter node name '{name}' is used twice")
            names.add(name)
            out.append(ParameterRule(name, node, self.value(pp, "viewers_may_set", self.boolean, False),
                                     self.value(pp, "timeout", self.number(0, 3600, open_low=True), 5.0),
                                     self.src.line_of(pp)))
        return tuple(out)

    def users(self, path: Path, robots: dict[str, Robot]) -> dict[str, User]:
        data = self.get(path) if "users" in self.src.data else None
        if data is None:
            return {}
        if not isinstance(data, dict):
            raise self.err(path, f"expected a mapping of user name to settings, got {_show(data)}")
        keys = {r.key for r in robots.values()}
        users: dict[str, User] = {}
        for name in data:
            up = path + (name,)
            self.topic_name("user name")(up, name)
            if name in robots:
                raise self.err(up, f"'{name}' is both a robot and a user; login names must be unique")
            self.mapping(up, ("password", "grants", "admin"))
            grants = []
            for i in range(len(self.sequence(up + ("grants",))) if "grants" in self.get(up) else 0):
                gp = up + ("grants", i)
                self.mapping(gp, ("key", "role"))
                key = self.value(gp, "key", self.string)
                if key not in keys:
                    raise self.err(gp + ("key",), "no robot has this key")
                grants.append(Grant(key, Role(self.value(gp, "role", self.choice(tuple(r.value for r in Role))))))
            users[name] = User(name, self.login_hash(up), tuple(grants),
                               self.value(up, "admin", self.boolean, False))
        return users


def _show(value: Any) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _closest(key: str, allowed: tuple[str, ...]) -> str | None:
    import difflib

    match = difflib.get_close_matches(str(key), allowed, n=1, cutoff=0.75)
    return match[0] if match else None
