"""The robot description: what one robot maps, retained on ``state/description`` (docs/protocol.md).

A robot's bridge publishes one :class:`RobotDescription` whenever it connects: its name, ROSLink type and
system id, the protocol version, its velocity limits, and every entry of its part of the fleet file — state it
publishes (with the ROSLink message or the ROS type each carries), commands it takes, ROS services users may
call, ROS actions users may send goals to — with the field layout of every ROS type those entries mention,
nested messages expanded, like ``ros2 interface show``. Dashboards and Node-RED flows build their UI from it;
``roslink-mqtt info ROBOT`` prints it.

**The same for everyone.** The description lives under ``state/``, which every user granted the robot reads
through one ACL entry; a broker's ACL cannot serve one retained message differently per role. So it is *not*
filtered per role: it lists everything and marks each entry with who may use it, ``operators`` or ``viewers``
(viewers and operators). What *you* may use is your own access report (``to/<user>/access``,
:class:`~roslink_mqtt.protocol.control.AccessReport`); a client combines the two.

Like the other bodies a client reads, parsing is lenient about fields it does not know (the bridge may add
some) and strict about the shape of those it does, with the exact reason in the :class:`ProtocolError`.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import Any

from ..topics import TopicTree, Verb, join_leaf
from .body import (
    BodyField,
    Boolean,
    Choice,
    Integer,
    NestedBody,
    Nullable,
    Number,
    Obj,
    Objects,
    Text,
    TextMap,
    body_of,
    read,
    write,
)
from .codec import ROS_VERSION, ROSLINK_VERSION
from .errors import ProtocolError
from .json_value import JsonObject
from .validate import describe

DESCRIPTION = "description"  # the state name: roslink/<robot>/state/description
# the retained state every bridge publishes besides its rules' (protocol.link.LINK, protocol.lease.CONTROL)
BRIDGE_STATES = (DESCRIPTION, "link", "control")
OPERATORS, VIEWERS = "operators", "viewers"  # who may use an entry (viewers: viewers and operators)
WHO = (OPERATORS, VIEWERS)
_DOC = TopicTree()

# A field layout: field name → a primitive type as a .msg file spells it (``float64``, ``string``, ``float64[36]``,
# ``int32[]``, ``int32[<=5]``, ``string<=10``) or, for a nested message, {"type": "pkg/msg/Type", "fields": {…}}
# (arrays of messages: the element's fields, and "type" reads ``pkg/msg/Type[]``). A service type's layout is
# {"request": …, "response": …}, an action type's {"goal": …, "result": …, "feedback": …}.
Layout = JsonObject


def _where(path: str, what: str, value: Any) -> ProtocolError:
    return ProtocolError(f"description: {path}: expected {what}, got {describe(value)}")


_ENTRY_SHAPE = "expected an object"


def _read_entry(fields: tuple[BodyField, ...], body: Any, path: str) -> dict[str, Any]:
    """One entry's declared fields: values as declared (a wrong one is a broken description), unknown ones ignored
    (a newer bridge may add some); refusals say where (``description: state[0].name: …``)."""
    try:
        return read(fields, body, shape=_ENTRY_SHAPE, known_only=False)
    except ProtocolError as err:
        text = str(err)
        raise ProtocolError(f"description: {path}: {text}" if text.startswith(_ENTRY_SHAPE) else
                            f"description: {path}.{text}") from None


def _drop_empty(body: dict[str, Any]) -> dict[str, Any]:
    """Leave out optional keys that say nothing (None, False, {}), so the body stays small."""
    return {k: v for k, v in body.items() if v is not None and v is not False and v != {}}


_TIMEOUT = BodyField("timeout", Nullable(Number()), False, "s the bridge waits for ROS", None, written="null")
_FIELD_MAP = TextMap("object of strings (MQTT field → ROS field path)")


def _text_or_null(name: str, doc: str) -> BodyField:
    """An optional non-empty string (null or left out: none)."""
    return BodyField(name, Nullable(Text(1)), False, doc, None)


def _who(default: str) -> BodyField:
    return BodyField("who", Choice(WHO), False, f"who may use it (`{VIEWERS}`: viewers and operators)", default)


@dataclass(frozen=True, slots=True)
class StateEntry(NestedBody):
    """A state stream, ``state/<name>``: a ROSLink message (``message``) or a ROS message as JSON (``ros_type``)."""

    name: str
    message: str | None = None  # the ROSLink message it carries (a preset), None for generic ROS JSON
    ros_type: str | None = None  # the ROS type it comes from (None: the bridge's own, e.g. ack)
    retained: bool = False
    max_rate: float | None = None  # Hz, newest wins
    fields: dict[str, str] = field(default_factory=dict)  # generic rules that select fields: MQTT → ROS path
    who: str = VIEWERS  # everyone granted the robot reads state
    encoding: str | None = None  # generic rules: "cbor" or "raw" (docs/protocol.md, "State encodings"); None: JSON
    warning: str | None = None  # why it may send nothing: its ROS topic has no publisher (the bridge checks)

    FIELDS = (
        BodyField("name", Text(1), True, "its topic: `state/<name>`"),
        _text_or_null("message", "the ROSLink message it carries (presets); without it the body is the ROS "
                                 "message of `ros_type` as JSON"),
        _text_or_null("ros_type", "the ROS type it comes from (none: the bridge's own, `ack`)"),
        BodyField("retained", Boolean(), False, "published retained", False),
        BodyField("max_rate", Nullable(Number()), False, "Hz at most, newest wins", None),
        BodyField("fields", _FIELD_MAP, False, "the fields a generic rule selects", {}),
        _who(VIEWERS),
        _text_or_null("encoding", "`cbor` or `raw` (\"State encodings\"); left out for JSON"),
        _text_or_null("warning", "while its ROS topic has no publisher (the bridge checks a few seconds after it "
                                 "starts, then every few seconds: `reads ROS topic /odm, which has no publisher "
                                 "(did you mean /odom?)`)"),
    )

    def to_body(self) -> dict[str, Any]:  # False and {} are left out too, not only None
        return _drop_empty(body_of(self.FIELDS, self))

    @classmethod
    def from_body(cls, body: Any, path: str) -> StateEntry:
        got = _read_entry(cls.FIELDS, body, path)
        return cls(**{**got, "encoding": None if got["encoding"] == "json" else got["encoding"]})


@dataclass(frozen=True, slots=True)
class CommandEntry(NestedBody):
    """A command input, ``from/<user>/<name>`` (``cmd/twist``; a generic rule's ``lights``)."""

    name: str  # the topic leaf under from/<user>/
    message: str | None = None  # the ROSLink command (a preset), None for generic ROS JSON
    ros_type: str | None = None  # what the bridge publishes to ROS (or the ROS service a preset calls)
    on_demand: bool = False
    fields: dict[str, str] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)  # velocity inputs: the limits the bridge clamps to
    who: str = OPERATORS
    warning: str | None = None  # why it may fail: the ROS service it calls has no server (the bridge checks)

    FIELDS = (
        BodyField("name", Text(1), True, "the topic under `from/<user>/`: `cmd/twist`, a generic rule's `lights`"),
        _text_or_null("message", "the ROSLink command (presets); without it the body is the ROS JSON of "
                                 "`ros_type`"),
        _text_or_null("ros_type", "what the bridge publishes to ROS (or the ROS service a preset calls)"),
        BodyField("on_demand", Boolean(), False, "the bridge creates its ROS publisher on first use", False),
        BodyField("fields", _FIELD_MAP, False, "the fields a generic rule takes", {}),
        BodyField("limits", Obj(), False, "velocity inputs: what the bridge clamps to (`linear`, `angular`, "
                                          "`mode`)", {}),
        _who(OPERATORS),
        _text_or_null("warning", "while the ROS service a command calls has no server"),
    )

    def to_body(self) -> dict[str, Any]:  # False and {} are left out too, not only None
        return _drop_empty(body_of(self.FIELDS, self))

    @classmethod
    def from_body(cls, body: Any, path: str) -> CommandEntry:
        return cls(**_read_entry(cls.FIELDS, body, path))


@dataclass(frozen=True, slots=True)
class ServiceEntry(NestedBody):
    """A ROS service users may call: ``from/<user>/call/<name>`` → ``to/<user>/reply/<name>``."""

    name: str
    ros_type: str
    read_only: bool = False
    timeout: float | None = None  # s the bridge waits for the ROS service
    who: str = OPERATORS
    warning: str | None = None  # why calls may fail: the ROS service has no server (the bridge checks)

    FIELDS = (
        BodyField("name", Text(1), True, "the service's name in `call/<name>`"),
        BodyField("ros_type", Text(1), True, "its ROS type, `pkg/srv/Type`"),
        BodyField("read_only", Boolean(), False, "it changes nothing: viewers may call it", False),
        _TIMEOUT,
        BodyField("who", Choice(WHO), False, "`viewers` when read-only, else `operators`", OPERATORS),
        _text_or_null("warning", "while the ROS service has no server"),
    )

    def to_body(self) -> dict[str, Any]:  # a null timeout is written, a None warning left out
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, body: Any, path: str) -> ServiceEntry:
        return cls(**_read_entry(cls.FIELDS, body, path))


@dataclass(frozen=True, slots=True)
class ActionEntry(NestedBody):
    """A ROS action users may send goals to: ``from/<user>/goal/<name>``, ``cancel/<name>``."""

    name: str
    ros_type: str
    viewers: bool = False  # viewers may send goals too
    timeout: float | None = None  # s from acceptance to result
    feedback_rate: float | None = None  # Hz at most per goal
    who: str = OPERATORS

    FIELDS = (
        BodyField("name", Text(1), True, "the action's name in `goal/<name>`"),
        BodyField("ros_type", Text(1), True, "its ROS type, `pkg/action/Type`"),
        BodyField("viewers", Boolean(), False, "viewers may send goals too", False),
        BodyField("timeout", Nullable(Number()), False, "s from acceptance to result", None, written="null"),
        BodyField("feedback_rate", Nullable(Number()), False, "Hz of feedback at most, per goal", None,
                  written="null"),
        BodyField("who", Choice(WHO), False, "`viewers` when open to viewers, else `operators`", OPERATORS),
    )

    def to_body(self) -> dict[str, Any]:  # null timeout and feedback_rate are written, not left out
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, body: Any, path: str) -> ActionEntry:
        return cls(**_read_entry(cls.FIELDS, body, path))


@dataclass(frozen=True, slots=True)
class ParameterEntry(NestedBody):
    """A ROS node whose parameters users may read (``param/<name>``, get/list/describe) and set."""

    name: str  # the MQTT name: from/<user>/param/<name>
    node: str  # the ROS node
    set_by: str = OPERATORS  # who may set them (everyone granted the robot may read them)
    timeout: float | None = None  # s for the node to answer
    who: str = VIEWERS  # who may use it: reading is open to every granted user

    FIELDS = (
        BodyField("name", Text(1), True, "the name in `param/<name>`"),
        BodyField("node", Text(1), True, "the ROS node"),
        BodyField("set_by", Choice(WHO), False, "who may set its parameters (`viewers` where the fleet file opens "
                                                "it)", OPERATORS),
        BodyField("timeout", Nullable(Number()), False, "s for the node to answer", None, written="null"),
        BodyField("who", Choice(WHO), False, "who may read them: `viewers`", VIEWERS),
    )

    def to_body(self) -> dict[str, Any]:  # a null timeout is written, not left out
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, body: Any, path: str) -> ParameterEntry:
        return cls(**_read_entry(cls.FIELDS, body, path))


@dataclass(frozen=True, slots=True)
class VideoEntry(NestedBody):
    """A camera sent as video (docs/video.md): frames on ``state/<name>`` while someone watches ``watch/<name>``."""

    name: str
    ros_type: str  # sensor_msgs/msg/Image or CompressedImage
    codec: str  # h264, vp8, vp9, av1
    fps: float  # the most frames a second it is sent at
    max_kbit_s: float  # the most it takes of the uplink
    who: str = VIEWERS  # every granted user may watch

    FIELDS = (
        BodyField("name", Text(1), True, "its frames come on `state/<name>` while a watch on `watch/<name>` is "
                                         "fresh"),
        BodyField("ros_type", Text(1), True, "the ROS image type it is encoded from"),
        BodyField("codec", Text(1), True, "`h264`, `vp8`, `vp9` or `av1`"),
        BodyField("fps", Number(), True, "the most frames a second it is sent at"),
        BodyField("max_kbit_s", Number(), True, "the most of the uplink it takes, kbit/s (it takes less when "
                                                "control and state leave less)"),
        BodyField("who", Choice(WHO), False, "who may watch: `viewers`", VIEWERS),
    )

    def to_body(self) -> dict[str, Any]:
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, body: Any, path: str) -> VideoEntry:
        return cls(**_read_entry(cls.FIELDS, body, path))


# the description's lists of entries: key → entry type (docs/protocol.md renders a table of each)
DESCRIPTION_ENTRIES: tuple[tuple[str, type[StateEntry | CommandEntry | ServiceEntry | ActionEntry |
                                          ParameterEntry | VideoEntry]], ...] = (
    ("state", StateEntry), ("commands", CommandEntry), ("services", ServiceEntry), ("actions", ActionEntry),
    ("parameters", ParameterEntry), ("video", VideoEntry))


@dataclass(frozen=True, slots=True)
class RobotDescription:
    """What one robot maps, retained on ``state/description`` by its bridge (read by every granted user)."""

    robot: str
    system_id: int
    type: str = "ground"  # RobotType name, lower case
    protocol_version: int = ROSLINK_VERSION
    ros_version: int = ROS_VERSION
    limits: dict[str, Any] = field(default_factory=dict)  # {"linear": m/s, "angular": rad/s, "mode": …}
    state: tuple[StateEntry, ...] = ()
    commands: tuple[CommandEntry, ...] = ()
    services: tuple[ServiceEntry, ...] = ()
    actions: tuple[ActionEntry, ...] = ()
    types: dict[str, Layout] = field(default_factory=dict)  # ROS type name → field layout
    parameters: tuple[ParameterEntry, ...] = ()
    video: tuple[VideoEntry, ...] = ()

    FIELDS = (
        BodyField("robot", Text(1), True, "the robot's name"),
        BodyField("system_id", Integer(), True, "its ROSLink system id"),
        BodyField("type", Text(), True, "its ROSLink robot type: `generic`, `ground`, `quadrotor`, …",
                  "generic"),
        BodyField("protocol_version", Integer(), True, "the ROSLink protocol version its bridge speaks "
                                                      f"({ROSLINK_VERSION})", ROSLINK_VERSION),
        BodyField("ros_version", Integer(), True, f"the envelope's `ros_version` ({ROS_VERSION}: ROS 2 Jazzy)",
                  ROS_VERSION),
        BodyField("limits", Obj(), True, "the bridge's velocity limits: `linear` (m/s), `angular` (rad/s), "
                                            "`mode` (`norm` or `per_axis`); a velocity command may have its "
                                            "own (`limits` in its entry)", {}),
        BodyField("state", Objects(), True, "what the robot publishes on `state/<name>` (entries below), the "
                                            "bridge's own `ack` included", ()),
        BodyField("commands", Objects(), True, "what the robot takes on `from/<user>/<name>` (entries below)", ()),
        BodyField("services", Objects(), True, "ROS services to `call/<name>` (entries below)", ()),
        BodyField("actions", Objects(), True, "ROS actions to send `goal/<name>` (entries below)", ()),
        BodyField("parameters", Objects(), True, "ROS nodes whose parameters `param/<name>` reads and sets "
                                                 "(entries below)", ()),
        BodyField("video", Objects(), False, "cameras sent as video on `state/<name>` while watched (entries "
                                             "below; docs/video.md)", ()),
        BodyField("types", Obj(), True, "every ROS type named above → its field layout: field → primitive "
                                           "type as a .msg file spells it (`float64`, `string`, `float64[36]`, "
                                           "`int32[]`, `string<=10`) or, "
                                           "for a nested message, `{\"type\": \"pkg/msg/Type\", \"fields\": "
                                           "{…}}`; a service is `{\"request\", \"response\"}`, an action "
                                           "`{\"goal\", \"result\", \"feedback\"}`", {}),
    )
    QOS = 1
    RETAINED = True

    def state_names(self) -> tuple[str, ...]:
        """Every ``state/<name>`` the robot's bridge publishes: its rules' streams and the bridge's own."""
        return (*(e.name for e in self.state), *(v.name for v in self.video), *BRIDGE_STATES)

    def unknown_state(self, name: str) -> str | None:
        """None when the robot publishes ``state/<name>``; else why not, with the closest names it has."""
        names = self.state_names()
        if name in names:
            return None
        close = difflib.get_close_matches(name, names, n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(close)}?" if close else "."
        return (f"{self.robot} publishes no state/{name}{hint} It publishes: "
                f"{', '.join(sorted(e.name for e in self.state))} (and the bridge's {', '.join(BRIDGE_STATES)})")

    def state_entry(self, name: str) -> StateEntry | None:
        """The entry of ``state/<name>``, None when no rule of the robot publishes it."""
        return next((e for e in self.state if e.name == name), None)

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> RobotDescription:
        got = read(cls.FIELDS, data, shape="description: expected a JSON object", strict=False, what="description")
        if not all(isinstance(v, dict) for v in got["types"].values()):
            raise _where("types", "an object of ROS type → field layout", got["types"])
        for key, entry in DESCRIPTION_ENTRIES:
            got[key] = tuple(entry.from_body(item, f"{key}[{i}]") for i, item in enumerate(got[key]))
        return cls(**{**got, "type": got["type"] or "generic"})

    # -- reading it --------------------------------------------------------------------------------------
    def entry(self, name: str
              ) -> StateEntry | CommandEntry | ServiceEntry | ActionEntry | ParameterEntry | VideoEntry | None:
        """The first entry called ``name`` (state, then commands, services, actions, parameters, video)."""
        for entries in (self.state, self.commands, self.services, self.actions, self.parameters, self.video):
            for e in entries:
                if e.name == name:
                    return e
        return None

    def layout(self, ros_type: str | None) -> Layout | None:
        """The field layout of ``ros_type`` (None when the description has none)."""
        return self.types.get(ros_type) if ros_type else None


# docs/protocol.md's example (protocol/reference.py renders it)
EXAMPLE = RobotDescription(
    "turtle1", 1, "ground", limits={"linear": 0.5, "angular": 1.5, "mode": "norm"},
    state=(StateEntry("battery_voltage", None, "std_msgs/msg/Float32", max_rate=1.0),
           StateEntry("camera", None, "sensor_msgs/msg/CompressedImage", max_rate=10.0, encoding="raw"),
           StateEntry("ack", "ack")),
    commands=(CommandEntry(join_leaf(Verb.CMD, "twist"), "twist", "geometry_msgs/msg/Twist",
                           limits={"linear": 0.5, "angular": 1.5, "mode": "norm"}),
              CommandEntry("lights", None, "std_msgs/msg/Bool", on_demand=True)),
    services=(ServiceEntry("reset", "std_srvs/srv/Trigger", False, 5.0),),
    actions=(ActionEntry("fibonacci", "test_msgs/action/Fibonacci", False, 30.0, 5.0),),
    parameters=(ParameterEntry("sim_robot", "sim_robot", OPERATORS, 5.0),),
    video=(VideoEntry("front_camera", "sensor_msgs/msg/Image", "h264", 30.0, 2000.0),),
    types={"std_msgs/msg/Float32": {"data": "float32"},
           "sensor_msgs/msg/CompressedImage": {
               "header": {"type": "std_msgs/msg/Header",
                          "fields": {"stamp": {"type": "builtin_interfaces/msg/Time",
                                               "fields": {"sec": "int32", "nanosec": "uint32"}},
                                     "frame_id": "string"}},
               "format": "string", "data": "uint8[]"},
           "geometry_msgs/msg/Twist": {part: {"type": "geometry_msgs/msg/Vector3",
                                              "fields": {"x": "float64", "y": "float64", "z": "float64"}}
                                       for part in ("linear", "angular")},
           "std_msgs/msg/Bool": {"data": "bool"},
           "std_srvs/srv/Trigger": {"request": {}, "response": {"success": "bool", "message": "string"}},
           "test_msgs/action/Fibonacci": {"goal": {"order": "int32"}, "result": {"sequence": "int32[]"},
                                          "feedback": {"sequence": "int32[]"}}},
)

# (title, topic, type) for the rendered reference, after the goal bodies
DESCRIPTION_BODIES: tuple[tuple[str, str, type], ...] = (
    ("robot description", f"`{_DOC.state('<robot>', DESCRIPTION)}` (written by the robot's bridge)",
     RobotDescription),
)
