"""ROSLink messages as frozen dataclasses, one per message, generated from the protocol's SPECS.

Generated rather than hand-written so the schema
(roslink_mqtt/protocol/messages.py) stays the one place a field is declared;
generated as source (the block below, written by
``python -m roslink_mqtt.client.message_codegen``) rather than at import time
so type checkers and IDEs see every class and field. A test fails when the
block and the schema differ. Each class carries where the message came from (``robot``,
``state_name``, ``system_id``, ``sequence_number``) as keyword-only fields, so
one callback can serve several robots. Lists become tuples (the objects are
immutable and hashable); base64 fields become ``bytes``.

No ``from __future__ import annotations`` here: field types stay real types at
run time (``dataclasses.fields(GlobalMotion)[0].type is float``), as they were
when the classes were built at import time.
"""

import base64
import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

from ..protocol import SPECS, SPECS_BY_NAME, Envelope, FieldKind, MessageId, MessageSpec, decode, spec_for
from ..protocol.codec import decode_object

_SEQUENCES = (FieldKind.FLOAT_LIST, FieldKind.RANGE_LIST, FieldKind.INT_LIST)


@dataclass(frozen=True, slots=True, kw_only=True)
class RoslinkMessage:
    """Base of the generated message classes: the metadata every message carries."""

    robot: str = ""  # which robot sent it
    state_name: str = ""  # the topic leaf it arrived on (``global_motion``; differs for extra preset rules)
    system_id: int = 0
    sequence_number: int | None = None

    SPEC: ClassVar[MessageSpec]
    MESSAGE_ID: ClassVar[MessageId]
    NAME: ClassVar[str]

    def payload(self) -> dict[str, Any]:
        """The message fields as a wire payload (what ``encode_message`` accepts)."""
        out: dict[str, Any] = {}
        for field in self.SPEC.fields:
            value = getattr(self, field.name)
            if field.kind is FieldKind.BASE64:
                value = base64.b64encode(value).decode("ascii")
            elif field.kind in _SEQUENCES:
                value = list(value)
            out[field.name] = value
        return out


M = TypeVar("M", bound=RoslinkMessage)


# BEGIN GENERATED: message classes (python -m roslink_mqtt.client.message_codegen)


@dataclass(frozen=True, slots=True)
class Heartbeat(RoslinkMessage):
    """ROSLink message 0 (heartbeat). Sent retained once a second; its last-will says offline."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['heartbeat']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.HEARTBEAT
    NAME: ClassVar[str] = 'heartbeat'

    type: int = dataclasses.field(metadata={'doc': 'RobotType'})
    name: str = dataclasses.field(metadata={'doc': 'robot name'})
    system_status: int = dataclasses.field(metadata={'doc': 'SystemStatus; 8 = offline (last-will)'})
    owner_id: str = dataclasses.field(metadata={'doc': "user who holds control of the robot (the control lease), '' when none"})  # noqa: E501
    mode: int = dataclasses.field(metadata={'doc': 'FlightMode'})
    session: int = dataclasses.field(default=0, metadata={'doc': 'grows with every bridge start'})
    instance: str = dataclasses.field(default='', metadata={'doc': "this bridge process's random id: two bridges of one robot tell each other apart by it"})  # noqa: E501
    host: str = dataclasses.field(default='', metadata={'doc': 'the machine the bridge runs on'})
    pid: int = dataclasses.field(default=0, metadata={'doc': "the bridge's process id on that machine"})
    since: float = dataclasses.field(default=0.0, metadata={'doc': 'when this bridge started, s since the Unix epoch (the older live bridge keeps the robot)'})  # noqa: E501
    take_over: int = dataclasses.field(default=0, metadata={'doc': '1: this bridge deliberately replaced another (`--take-over`, or one that fell silent); a live older bridge that sees it stops its robot and exits'})  # noqa: E501


@dataclass(frozen=True, slots=True)
class RobotStatus(RoslinkMessage):
    """ROSLink message 1 (robot_status)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['robot_status']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.ROBOT_STATUS
    NAME: ClassVar[str] = 'robot_status'

    voltage_battery: float = dataclasses.field(metadata={'doc': 'V'})
    current_battery: float = dataclasses.field(metadata={'doc': 'A (negative while discharging, as in sensor_msgs/BatteryState)'})  # noqa: E501
    battery_remaining: float = dataclasses.field(metadata={'doc': 'percent 0..100, -1 unknown'})
    onboard_control_sensors_present: int = dataclasses.field(default=0, metadata={'doc': 'bitmask'})
    onboard_control_sensors_enabled: int = dataclasses.field(default=0, metadata={'doc': 'bitmask'})
    onboard_control_sensors_health: int = dataclasses.field(default=0, metadata={'doc': 'bitmask'})
    load: float = dataclasses.field(default=0.0, metadata={'doc': 'CPU load 0..1'})
    errors_count: int = dataclasses.field(default=0, metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class GlobalMotion(RoslinkMessage):
    """ROSLink message 2 (global_motion)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['global_motion']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.GLOBAL_MOTION
    NAME: ClassVar[str] = 'global_motion'

    x: float = dataclasses.field(metadata={'doc': 'm'})
    y: float = dataclasses.field(metadata={'doc': 'm'})
    z: float = dataclasses.field(metadata={'doc': 'm'})
    vx: float = dataclasses.field(metadata={'doc': 'm/s'})
    vy: float = dataclasses.field(metadata={'doc': 'm/s'})
    vz: float = dataclasses.field(metadata={'doc': 'm/s'})
    wx: float = dataclasses.field(metadata={'doc': 'rad/s'})
    wy: float = dataclasses.field(metadata={'doc': 'rad/s'})
    wz: float = dataclasses.field(metadata={'doc': 'rad/s'})
    roll: float = dataclasses.field(metadata={'doc': 'rad'})
    pitch: float = dataclasses.field(metadata={'doc': 'rad'})
    yaw: float = dataclasses.field(metadata={'doc': 'rad'})
    time_boot_ms: int = dataclasses.field(default=0, metadata={'doc': 'time of the measurement, ms (ROS clock)'})


@dataclass(frozen=True, slots=True)
class GpsRawInfo(RoslinkMessage):
    """ROSLink message 3 (gps_raw_info)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['gps_raw_info']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.GPS_RAW_INFO
    NAME: ClassVar[str] = 'gps_raw_info'

    fix_type: int = dataclasses.field(metadata={'doc': '0 no fix, 2 2D, 3 3D'})
    lat: float = dataclasses.field(metadata={'doc': 'degrees'})
    lon: float = dataclasses.field(metadata={'doc': 'degrees'})
    alt: float = dataclasses.field(metadata={'doc': 'm'})
    time_usec: int = dataclasses.field(default=0, metadata={'doc': ''})
    eph: float = dataclasses.field(default=0.0, metadata={'doc': 'horizontal dilution'})
    epv: float = dataclasses.field(default=0.0, metadata={'doc': 'vertical dilution'})
    vel: float = dataclasses.field(default=0.0, metadata={'doc': 'ground speed m/s'})
    cog: float = dataclasses.field(default=0.0, metadata={'doc': 'course over ground, degrees'})
    satellites_visible: int = dataclasses.field(default=0, metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class RangeFinderData(RoslinkMessage):
    """ROSLink message 4 (range_finder_data)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['range_finder_data']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.RANGE_FINDER_DATA
    NAME: ClassVar[str] = 'range_finder_data'

    range_min: float = dataclasses.field(metadata={'doc': 'm'})
    range_max: float = dataclasses.field(metadata={'doc': 'm'})
    angle_min: float = dataclasses.field(metadata={'doc': 'rad'})
    angle_max: float = dataclasses.field(metadata={'doc': 'rad'})
    angle_increment: float = dataclasses.field(metadata={'doc': 'rad'})
    ranges: tuple[float | None, ...] = dataclasses.field(metadata={'doc': 'm; null where nothing was hit'})
    time_usec: int = dataclasses.field(default=0, metadata={'doc': ''})
    time_increment: float = dataclasses.field(default=0.0, metadata={'doc': 's'})
    scan_time: float = dataclasses.field(default=0.0, metadata={'doc': 's'})
    intensities: tuple[float, ...] = dataclasses.field(default=(), metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class Image(RoslinkMessage):
    """ROSLink message 5 (image)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['image']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.IMAGE
    NAME: ClassVar[str] = 'image'

    format: str = dataclasses.field(metadata={'doc': 'jpeg, png, …'})
    data: bytes = dataclasses.field(metadata={'doc': 'compressed image bytes'})
    time_usec: int = dataclasses.field(default=0, metadata={'doc': ''})
    width: int = dataclasses.field(default=0, metadata={'doc': ''})
    height: int = dataclasses.field(default=0, metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class Map(RoslinkMessage):
    """ROSLink message 6 (map)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['map']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.MAP
    NAME: ClassVar[str] = 'map'

    width: int = dataclasses.field(metadata={'doc': 'cells'})
    height: int = dataclasses.field(metadata={'doc': 'cells'})
    resolution: float = dataclasses.field(metadata={'doc': 'm/cell'})
    origin_x: float = dataclasses.field(metadata={'doc': 'm'})
    origin_y: float = dataclasses.field(metadata={'doc': 'm'})
    data: tuple[int, ...] = dataclasses.field(metadata={'doc': 'row-major occupancy, -1 unknown'})
    time_usec: int = dataclasses.field(default=0, metadata={'doc': ''})
    origin_yaw: float = dataclasses.field(default=0.0, metadata={'doc': 'rad'})


@dataclass(frozen=True, slots=True)
class GeoTaggedImage(RoslinkMessage):
    """ROSLink message 7 (geo_tagged_image)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['geo_tagged_image']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.GEO_TAGGED_IMAGE
    NAME: ClassVar[str] = 'geo_tagged_image'

    lat: float = dataclasses.field(metadata={'doc': 'degrees'})
    lon: float = dataclasses.field(metadata={'doc': 'degrees'})
    alt: float = dataclasses.field(metadata={'doc': 'm'})
    format: str = dataclasses.field(metadata={'doc': 'jpeg, png, …'})
    data: bytes = dataclasses.field(metadata={'doc': 'compressed image bytes'})
    time_usec: int = dataclasses.field(default=0, metadata={'doc': ''})
    width: int = dataclasses.field(default=0, metadata={'doc': ''})
    height: int = dataclasses.field(default=0, metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class Twist(RoslinkMessage):
    """ROSLink message 100 (twist). Omitted components are zero. The bridge clamps to the robot's limits."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['twist']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.TWIST
    NAME: ClassVar[str] = 'twist'

    lx: float = dataclasses.field(default=0.0, metadata={'doc': 'm/s'})
    ly: float = dataclasses.field(default=0.0, metadata={'doc': 'm/s'})
    lz: float = dataclasses.field(default=0.0, metadata={'doc': 'm/s'})
    ax: float = dataclasses.field(default=0.0, metadata={'doc': 'rad/s'})
    ay: float = dataclasses.field(default=0.0, metadata={'doc': 'rad/s'})
    az: float = dataclasses.field(default=0.0, metadata={'doc': 'rad/s'})


@dataclass(frozen=True, slots=True)
class GoToWaypoint(RoslinkMessage):
    """ROSLink message 101 (go_to_waypoint)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['go_to_waypoint']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.GO_TO_WAYPOINT
    NAME: ClassVar[str] = 'go_to_waypoint'

    x: float = dataclasses.field(metadata={'doc': ''})
    y: float = dataclasses.field(metadata={'doc': ''})
    frame_type: int = dataclasses.field(default=0, metadata={'doc': '0 map (x, y, z in m), 1 GPS (lat, lon, alt), 2 robot (base_link)'})  # noqa: E501
    z: float = dataclasses.field(default=0.0, metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class Takeoff(RoslinkMessage):
    """ROSLink message 102 (takeoff)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['takeoff']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.TAKEOFF
    NAME: ClassVar[str] = 'takeoff'

    altitude: float = dataclasses.field(metadata={'doc': 'm'})


@dataclass(frozen=True, slots=True)
class Land(RoslinkMessage):
    """ROSLink message 103 (land)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['land']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.LAND
    NAME: ClassVar[str] = 'land'


@dataclass(frozen=True, slots=True)
class Arm(RoslinkMessage):
    """ROSLink message 104 (arm)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['arm']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.ARM
    NAME: ClassVar[str] = 'arm'


@dataclass(frozen=True, slots=True)
class Disarm(RoslinkMessage):
    """ROSLink message 105 (disarm)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['disarm']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.DISARM
    NAME: ClassVar[str] = 'disarm'


@dataclass(frozen=True, slots=True)
class SetMode(RoslinkMessage):
    """ROSLink message 106 (set_mode)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['set_mode']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.SET_MODE
    NAME: ClassVar[str] = 'set_mode'

    mode: str = dataclasses.field(metadata={'doc': 'a FlightMode name, e.g. GUIDED'})


@dataclass(frozen=True, slots=True)
class GetMap(RoslinkMessage):
    """ROSLink message 107 (get_map)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['get_map']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.GET_MAP
    NAME: ClassVar[str] = 'get_map'


@dataclass(frozen=True, slots=True)
class EmergencyStop(RoslinkMessage):
    """ROSLink message 108 (emergency_stop)."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['emergency_stop']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.EMERGENCY_STOP
    NAME: ClassVar[str] = 'emergency_stop'

    reason: str = dataclasses.field(default='', metadata={'doc': ''})


@dataclass(frozen=True, slots=True)
class Ack(RoslinkMessage):
    """ROSLink message 109 (ack). Acknowledgements and failsafe notices, on state/ack."""

    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME['ack']
    MESSAGE_ID: ClassVar[MessageId] = MessageId.ACK
    NAME: ClassVar[str] = 'ack'

    command: int = dataclasses.field(metadata={'doc': 'message_id acknowledged (0 for failsafe notices)'})
    result: int = dataclasses.field(metadata={'doc': 'AckResult: 0 accepted, 1 rejected, 2 failed, 3 failsafe'})
    command_sequence: int = dataclasses.field(default=-1, metadata={'doc': 'sequence_number of that command, -1 if none'})  # noqa: E501
    text: str = dataclasses.field(default='', metadata={'doc': 'why'})


MESSAGE_CLASSES: dict[str, type[RoslinkMessage]] = {
    'heartbeat': Heartbeat,
    'robot_status': RobotStatus,
    'global_motion': GlobalMotion,
    'gps_raw_info': GpsRawInfo,
    'range_finder_data': RangeFinderData,
    'image': Image,
    'map': Map,
    'geo_tagged_image': GeoTaggedImage,
    'twist': Twist,
    'go_to_waypoint': GoToWaypoint,
    'takeoff': Takeoff,
    'land': Land,
    'arm': Arm,
    'disarm': Disarm,
    'set_mode': SetMode,
    'get_map': GetMap,
    'emergency_stop': EmergencyStop,
    'ack': Ack,
}
# END GENERATED: message classes


def message_class(message: int | str) -> type[RoslinkMessage]:
    """The class for a message id or name (``2`` or ``"global_motion"``); KeyError if unknown."""
    return MESSAGE_CLASSES[spec_for(message).name]


def from_envelope(envelope: Envelope, *, robot: str = "", state_name: str = "") -> RoslinkMessage:
    """A typed message from a decoded (hence validated) envelope."""
    spec = envelope.spec
    values: dict[str, Any] = {}
    for f in spec.fields:
        value = envelope.payload[f.name]
        if f.kind is FieldKind.BASE64:
            value = base64.b64decode(value)
        elif f.kind in _SEQUENCES:
            value = tuple(value)
        values[f.name] = value
    return MESSAGE_CLASSES[spec.name](**values, robot=robot, state_name=state_name or spec.name,
                                      system_id=envelope.system_id, sequence_number=envelope.sequence_number)


def parse_state(payload: bytes, *, robot: str, state_name: str) -> RoslinkMessage:
    """Decode a state message; the leaf names the expected message when it is a canonical one.

    Raises ProtocolError when the payload is not a valid ROSLink message (e.g.
    a generic rule's plain ROS JSON).
    """
    expected = _EXPECTED.get(state_name)
    return from_envelope(decode(payload, expected), robot=robot, state_name=state_name)


def state_message(body: Any, *, robot: str, state_name: str) -> RoslinkMessage:
    """Like :func:`parse_state` for a payload already parsed from JSON (so a caller that falls back to a generic
    rule's plain ROS JSON parses it once)."""
    return from_envelope(decode_object(body, _EXPECTED.get(state_name)), robot=robot, state_name=state_name)


_EXPECTED: dict[str, int] = {spec.name: int(spec.message_id) for spec in SPECS}

__all__ = ["MESSAGE_CLASSES", "Ack", "Arm", "Disarm", "EmergencyStop", "GeoTaggedImage", "GetMap", "GlobalMotion",
           "GoToWaypoint", "GpsRawInfo", "Heartbeat", "Image", "Land", "Map", "RangeFinderData", "RobotStatus",
           "RoslinkMessage", "SetMode", "Takeoff", "Twist", "from_envelope", "message_class", "parse_state",
           "state_message"]
