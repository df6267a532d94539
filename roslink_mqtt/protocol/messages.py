"""ROSLink message ids and payload schemas.

One table describes every message: the codec validates against it, the docs
are written from it and the property tests generate from it, so a field added
here is a field known everywhere. Field names follow the ROSLink paper
(which borrows MAVLink's); units are SI and degrees for GPS.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any


class MessageId(IntEnum):
    HEARTBEAT = 0
    ROBOT_STATUS = 1
    GLOBAL_MOTION = 2
    GPS_RAW_INFO = 3
    RANGE_FINDER_DATA = 4
    IMAGE = 5
    MAP = 6
    GEO_TAGGED_IMAGE = 7
    TWIST = 100
    GO_TO_WAYPOINT = 101
    TAKEOFF = 102
    LAND = 103
    ARM = 104
    DISARM = 105
    SET_MODE = 106
    GET_MAP = 107
    EMERGENCY_STOP = 108
    ACK = 109


class FieldKind(Enum):
    """Wire type of a payload field (what JSON value is accepted)."""

    INT = "integer"
    FLOAT = "number"
    STR = "string"
    BOOL = "boolean"
    FLOAT_LIST = "array of numbers"
    RANGE_LIST = "array of numbers or null"  # null = no return (ROS uses inf)
    INT_LIST = "array of integers"
    BASE64 = "base64 string"


_REQUIRED: Any = object()

INT32 = (-(2**31), 2**31 - 1)
UINT8 = (0, 255)
UINT32 = (0, 2**32 - 1)
UINT64 = (0, 2**64 - 1)


@dataclass(frozen=True, slots=True)
class Field:
    name: str
    kind: FieldKind
    default: Any = _REQUIRED
    bounds: tuple[int, int] | None = None  # inclusive, for INT and INT_LIST items
    doc: str = ""

    @property
    def required(self) -> bool:
        return self.default is _REQUIRED

    def as_data(self) -> dict[str, Any]:
        """The field as JSON data: the dashboard reads messages from the same declarations (static/message.mjs)."""
        out: dict[str, Any] = {"name": self.name, "kind": self.kind.name.lower(), "required": self.required}
        if not self.required:
            out["default"] = self.default
        if self.bounds is not None:
            out["bounds"] = list(self.bounds)
        return out


class Direction(Enum):
    STATE = "state"  # robot → users
    COMMAND = "command"  # users → robot


@dataclass(frozen=True, slots=True)
class MessageSpec:
    message_id: MessageId
    name: str  # canonical topic leaf: state/<name> or cmd/<name>
    direction: Direction
    fields: tuple[Field, ...]
    doc: str = ""

    def as_data(self) -> dict[str, Any]:
        return {"id": int(self.message_id), "fields": [f.as_data() for f in self.fields]}

    def defaults(self) -> dict[str, Any]:
        """A payload with every optional field at its default (required ones absent)."""
        return {f.name: _copy(f.default) for f in self.fields if not f.required}


def _copy(value: Any) -> Any:
    return list(value) if isinstance(value, list) else value


def _f(name: str, doc: str = "", default: Any = _REQUIRED) -> Field:
    return Field(name, FieldKind.FLOAT, default, None, doc)


def _i(name: str, bounds: tuple[int, int], doc: str = "", default: Any = _REQUIRED) -> Field:
    return Field(name, FieldKind.INT, default, bounds, doc)


def _s(name: str, doc: str = "", default: Any = _REQUIRED) -> Field:
    return Field(name, FieldKind.STR, default, None, doc)


_STATE, _CMD = Direction.STATE, Direction.COMMAND

SPECS: tuple[MessageSpec, ...] = (
    MessageSpec(MessageId.HEARTBEAT, "heartbeat", _STATE, (
        _i("type", UINT8, "RobotType"),
        _s("name", "robot name"),
        _i("system_status", UINT8, "SystemStatus; 8 = offline (last-will)"),
        _s("owner_id", "user who holds control of the robot (the control lease), '' when none"),
        _i("mode", UINT8, "FlightMode"),
        _i("session", UINT32, "grows with every bridge start", default=0),
        _s("instance", "this bridge process's random id: two bridges of one robot tell each other apart by it",
           default=""),
        _s("host", "the machine the bridge runs on", default=""),
        _i("pid", UINT32, "the bridge's process id on that machine", default=0),
        _f("since", "when this bridge started, s since the Unix epoch (the older live bridge keeps the robot)",
           default=0.0),
        _i("take_over", UINT8, "1: this bridge deliberately replaced another (`--take-over`, or one that fell "
                               "silent); a live older bridge that sees it stops its robot and exits", default=0),
    ), "Sent retained once a second; its last-will says offline."),
    MessageSpec(MessageId.ROBOT_STATUS, "robot_status", _STATE, (
        _i("onboard_control_sensors_present", UINT32, "bitmask", default=0),
        _i("onboard_control_sensors_enabled", UINT32, "bitmask", default=0),
        _i("onboard_control_sensors_health", UINT32, "bitmask", default=0),
        _f("load", "CPU load 0..1", default=0.0),
        _f("voltage_battery", "V"),
        _f("current_battery", "A (negative while discharging, as in sensor_msgs/BatteryState)"),
        _f("battery_remaining", "percent 0..100, -1 unknown"),
        _i("errors_count", UINT32, default=0),
    )),
    MessageSpec(MessageId.GLOBAL_MOTION, "global_motion", _STATE, (
        _i("time_boot_ms", UINT64, "time of the measurement, ms (ROS clock)", default=0),
        _f("x", "m"), _f("y", "m"), _f("z", "m"),
        _f("vx", "m/s"), _f("vy", "m/s"), _f("vz", "m/s"),
        _f("wx", "rad/s"), _f("wy", "rad/s"), _f("wz", "rad/s"),
        _f("roll", "rad"), _f("pitch", "rad"), _f("yaw", "rad"),
    )),
    MessageSpec(MessageId.GPS_RAW_INFO, "gps_raw_info", _STATE, (
        _i("time_usec", UINT64, default=0),
        _i("fix_type", UINT8, "0 no fix, 2 2D, 3 3D"),
        _f("lat", "degrees"), _f("lon", "degrees"), _f("alt", "m"),
        _f("eph", "horizontal dilution", default=0.0),
        _f("epv", "vertical dilution", default=0.0),
        _f("vel", "ground speed m/s", default=0.0),
        _f("cog", "course over ground, degrees", default=0.0),
        _i("satellites_visible", UINT8, default=0),
    )),
    MessageSpec(MessageId.RANGE_FINDER_DATA, "range_finder_data", _STATE, (
        _i("time_usec", UINT64, default=0),
        _f("range_min", "m"), _f("range_max", "m"),
        _f("angle_min", "rad"), _f("angle_max", "rad"), _f("angle_increment", "rad"),
        _f("time_increment", "s", default=0.0), _f("scan_time", "s", default=0.0),
        Field("ranges", FieldKind.RANGE_LIST, _REQUIRED, None, "m; null where nothing was hit"),
        Field("intensities", FieldKind.FLOAT_LIST, [], None),
    )),
    MessageSpec(MessageId.IMAGE, "image", _STATE, (
        _i("time_usec", UINT64, default=0),
        _i("width", UINT32, default=0), _i("height", UINT32, default=0),
        _s("format", "jpeg, png, …"),
        Field("data", FieldKind.BASE64, _REQUIRED, None, "compressed image bytes"),
    )),
    MessageSpec(MessageId.MAP, "map", _STATE, (
        _i("time_usec", UINT64, default=0),
        _i("width", UINT32, "cells"), _i("height", UINT32, "cells"),
        _f("resolution", "m/cell"),
        _f("origin_x", "m"), _f("origin_y", "m"), _f("origin_yaw", "rad", default=0.0),
        Field("data", FieldKind.INT_LIST, _REQUIRED, (-1, 100), "row-major occupancy, -1 unknown"),
    )),
    MessageSpec(MessageId.GEO_TAGGED_IMAGE, "geo_tagged_image", _STATE, (
        _i("time_usec", UINT64, default=0),
        _f("lat", "degrees"), _f("lon", "degrees"), _f("alt", "m"),
        _i("width", UINT32, default=0), _i("height", UINT32, default=0),
        _s("format", "jpeg, png, …"),
        Field("data", FieldKind.BASE64, _REQUIRED, None, "compressed image bytes"),
    )),
    MessageSpec(MessageId.TWIST, "twist", _CMD, (
        _f("lx", "m/s", 0.0), _f("ly", "m/s", 0.0), _f("lz", "m/s", 0.0),
        _f("ax", "rad/s", 0.0), _f("ay", "rad/s", 0.0), _f("az", "rad/s", 0.0),
    ), "Omitted components are zero. The bridge clamps to the robot's limits."),
    MessageSpec(MessageId.GO_TO_WAYPOINT, "go_to_waypoint", _CMD, (
        _i("frame_type", UINT8, "0 map (x, y, z in m), 1 GPS (lat, lon, alt), 2 robot (base_link)", 0),
        _f("x"), _f("y"), _f("z", default=0.0),
    )),
    MessageSpec(MessageId.TAKEOFF, "takeoff", _CMD, (_f("altitude", "m"),)),
    MessageSpec(MessageId.LAND, "land", _CMD, ()),
    MessageSpec(MessageId.ARM, "arm", _CMD, ()),
    MessageSpec(MessageId.DISARM, "disarm", _CMD, ()),
    MessageSpec(MessageId.SET_MODE, "set_mode", _CMD, (_s("mode", "a FlightMode name, e.g. GUIDED"),)),
    MessageSpec(MessageId.GET_MAP, "get_map", _CMD, ()),
    MessageSpec(MessageId.EMERGENCY_STOP, "emergency_stop", _CMD, (_s("reason", default=""),)),
    MessageSpec(MessageId.ACK, "ack", _STATE, (
        _i("command", (0, 255), "message_id acknowledged (0 for failsafe notices)"),
        _i("command_sequence", INT32, "sequence_number of that command, -1 if none", -1),
        _i("result", UINT8, "AckResult: 0 accepted, 1 rejected, 2 failed, 3 failsafe"),
        _s("text", "why", default=""),
    ), "Acknowledgements and failsafe notices, on state/ack."),
)

SPECS_BY_ID: dict[int, MessageSpec] = {s.message_id: s for s in SPECS}
SPECS_BY_NAME: dict[str, MessageSpec] = {s.name: s for s in SPECS}


def spec_for(message: int | str) -> MessageSpec:
    """Look up a spec by id or canonical name; raises KeyError."""
    if isinstance(message, str):
        return SPECS_BY_NAME[message]
    return SPECS_BY_ID[message]
