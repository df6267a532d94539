"""ROSLink messages as frozen dataclasses, one per message, generated from the protocol's SPECS.

Generated rather than hand-written so a field added to the schema
(roslink_mqtt/protocol/messages.py) appears here without anyone editing the
SDK. Each class carries where the message came from (``robot``,
``state_name``, ``system_id``, ``sequence_number``) as keyword-only fields, so
one callback can serve several robots. Lists become tuples (the objects are
immutable and hashable); base64 fields become ``bytes``.
"""

from __future__ import annotations

import base64
import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

from ..protocol import SPECS, Envelope, Kind, MessageId, MessageSpec, decode, spec_for

_PYTHON_TYPES: dict[Kind, Any] = {
    Kind.INT: int, Kind.FLOAT: float, Kind.STR: str, Kind.BOOL: bool,
    Kind.FLOAT_LIST: tuple[float, ...], Kind.RANGE_LIST: tuple[float | None, ...],
    Kind.INT_LIST: tuple[int, ...], Kind.BASE64: bytes,
}
_SEQUENCES = (Kind.FLOAT_LIST, Kind.RANGE_LIST, Kind.INT_LIST)


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
            if field.kind is Kind.BASE64:
                value = base64.b64encode(value).decode("ascii")
            elif field.kind in _SEQUENCES:
                value = list(value)
            out[field.name] = value
        return out


M = TypeVar("M", bound=RoslinkMessage)


def _make(spec: MessageSpec) -> type[RoslinkMessage]:
    fields: list[tuple[str, Any, Any]] = []
    for f in sorted(spec.fields, key=lambda f: not f.required):  # required fields first, as dataclasses need
        if f.required:
            fields.append((f.name, _PYTHON_TYPES[f.kind], dataclasses.field(metadata={"doc": f.doc})))
        else:
            default = tuple(f.default) if isinstance(f.default, list) else f.default
            fields.append((f.name, _PYTHON_TYPES[f.kind], dataclasses.field(default=default, metadata={"doc": f.doc})))
    name = "".join(part.capitalize() for part in spec.name.split("_"))
    cls = dataclasses.make_dataclass(
        name, fields, bases=(RoslinkMessage,), frozen=True, slots=True,
        namespace={"SPEC": spec, "MESSAGE_ID": spec.message_id, "NAME": spec.name,
                   "__doc__": f"ROSLink message {int(spec.message_id)} ({spec.name}). {spec.doc}".strip()})
    cls.__module__ = __name__  # make_dataclass(module=) is 3.12+
    return cls


MESSAGE_CLASSES: dict[str, type[RoslinkMessage]] = {spec.name: _make(spec) for spec in SPECS}

# Named for imports and IDEs: `from roslink_mqtt.client import GlobalMotion`.
Heartbeat = MESSAGE_CLASSES["heartbeat"]
RobotStatus = MESSAGE_CLASSES["robot_status"]
GlobalMotion = MESSAGE_CLASSES["global_motion"]
GpsRawInfo = MESSAGE_CLASSES["gps_raw_info"]
RangeFinderData = MESSAGE_CLASSES["range_finder_data"]
Image = MESSAGE_CLASSES["image"]
Map = MESSAGE_CLASSES["map"]
GeoTaggedImage = MESSAGE_CLASSES["geo_tagged_image"]
Twist = MESSAGE_CLASSES["twist"]
GoToWaypoint = MESSAGE_CLASSES["go_to_waypoint"]
Takeoff = MESSAGE_CLASSES["takeoff"]
Land = MESSAGE_CLASSES["land"]
Arm = MESSAGE_CLASSES["arm"]
Disarm = MESSAGE_CLASSES["disarm"]
SetMode = MESSAGE_CLASSES["set_mode"]
GetMap = MESSAGE_CLASSES["get_map"]
EmergencyStop = MESSAGE_CLASSES["emergency_stop"]
Ack = MESSAGE_CLASSES["ack"]


def message_class(message: int | str) -> type[RoslinkMessage]:
    """The class for a message id or name (``2`` or ``"global_motion"``); KeyError if unknown."""
    return MESSAGE_CLASSES[spec_for(message).name]


def from_envelope(envelope: Envelope, *, robot: str = "", state_name: str = "") -> RoslinkMessage:
    """A typed message from a decoded (hence validated) envelope."""
    spec = envelope.spec
    values: dict[str, Any] = {}
    for f in spec.fields:
        value = envelope.payload[f.name]
        if f.kind is Kind.BASE64:
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


_EXPECTED: dict[str, int] = {spec.name: int(spec.message_id) for spec in SPECS}

__all__ = ["MESSAGE_CLASSES", "Ack", "Arm", "Disarm", "EmergencyStop", "GeoTaggedImage", "GetMap", "GlobalMotion",
           "GoToWaypoint", "GpsRawInfo", "Heartbeat", "Image", "Land", "Map", "RangeFinderData", "RobotStatus",
           "RoslinkMessage", "SetMode", "Takeoff", "Twist", "from_envelope", "message_class", "parse_state"]
