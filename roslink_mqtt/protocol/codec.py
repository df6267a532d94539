"""ROSLink envelope and its JSON codec (orjson).

``decode`` is the single gate for untrusted bytes from MQTT: it raises only
:class:`ProtocolError`, with a message that can be sent back verbatim.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import orjson

from .errors import ProtocolError
from .messages import SPECS_BY_ID, MessageId, MessageSpec
from .validate import describe, show_key, validate_payload

ROSLINK_VERSION = 2
ROS_VERSION = 24  # ROS 2 Jazzy (2024)
DEFAULT_MAX_BYTES = 4 * 1024 * 1024  # images and maps fit; anything larger is refused unread

_HEADER_BOUNDS: dict[str, tuple[int, int]] = {
    "roslink_version": (0, 255),
    "ros_version": (0, 255),
    "system_id": (0, 65535),
    "message_id": (0, 255),
    "sequence_number": (0, 2**32 - 1),
}
CLIENT_ID_KEY = "client_id"  # optional header: the sender's id, repeated in error reports (docs/protocol.md)
GENERIC_SENDER_KEY = "$client_id"  # the same in generic ROS JSON bodies (never a ROS field name)
MAX_CLIENT_ID = 128
_ENVELOPE_KEYS = frozenset(_HEADER_BOUNDS) | {"payload", CLIENT_ID_KEY}


def envelope_rules() -> dict[str, Any]:
    """What :func:`decode_object` accepts around a payload, as JSON data (the dashboard's static/message.mjs)."""
    return {"header": {key: list(bounds) for key, bounds in _HEADER_BOUNDS.items()}, "client_id": CLIENT_ID_KEY,
            "client_id_max": MAX_CLIENT_ID}


@dataclass(slots=True)
class Envelope:
    """One ROSLink message: header plus payload.

    ``sequence_number`` is None when a client sent a bare payload (no header):
    such commands are not checked for staleness. ``client_id`` names the
    sending program (optional): every program of a user reads the user's error
    topic, and a report that repeats the id lets each show only its own.
    """

    message_id: int
    payload: dict[str, Any] = field(default_factory=dict)
    system_id: int = 0
    sequence_number: int | None = None
    roslink_version: int = ROSLINK_VERSION
    ros_version: int = ROS_VERSION
    client_id: str | None = None

    @property
    def spec(self) -> MessageSpec:
        return SPECS_BY_ID[self.message_id]

    def to_dict(self) -> dict[str, Any]:
        out = {
            "roslink_version": self.roslink_version,
            "ros_version": self.ros_version,
            "system_id": self.system_id,
            "message_id": int(self.message_id),
            "sequence_number": 0 if self.sequence_number is None else self.sequence_number,
            "payload": self.payload,
        }
        if self.client_id is not None:
            out[CLIENT_ID_KEY] = self.client_id
        return out


def encode(envelope: Envelope, *, validate: bool = False) -> bytes:
    """Serialize an envelope to JSON bytes.

    ``validate=True`` checks the payload first (the SDK does, for messages
    built by hand); the bridge skips it because its payloads come from typed
    ROS messages through converters that already guarantee the shape.
    """
    if validate:
        if envelope.message_id not in SPECS_BY_ID:
            raise ProtocolError(f"message_id: unknown message_id {envelope.message_id}")
        envelope.payload = validate_payload(SPECS_BY_ID[envelope.message_id], envelope.payload)
    return orjson.dumps(envelope.to_dict())


def encode_message(message_id: int, payload: dict[str, Any], *, system_id: int = 0,
                   sequence_number: int | None = None, client_id: str | None = None) -> bytes:
    """Convenience for ``encode(Envelope(...), validate=True)``."""
    return encode(Envelope(int(message_id), payload, system_id, sequence_number, client_id=client_id),
                  validate=True)


def loads(data: bytes | bytearray | memoryview | str, max_bytes: int = DEFAULT_MAX_BYTES) -> Any:
    """Parse untrusted JSON with a size limit; raise ProtocolError on anything wrong."""
    if len(data) > max_bytes:
        raise ProtocolError(f"oversized payload: {len(data)} bytes exceeds the limit of {max_bytes}")
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError as err:
        text = str(err)
        if "infinity" in text:
            raise ProtocolError(f"non-finite number in JSON ({text})") from None
        raise ProtocolError(f"not JSON: {text}") from None


def decode(data: bytes | bytearray | memoryview | str, expected: int | None = None, *,
           max_bytes: int = DEFAULT_MAX_BYTES) -> Envelope:
    """Decode one ROSLink message from untrusted bytes.

    ``expected`` is the message id the MQTT topic implies (``cmd/twist`` → 100).
    With it, a bare payload such as ``{"lx": 0.2}`` is accepted; an envelope
    whose ``message_id`` disagrees with the topic is refused.
    """
    return decode_object(loads(data, max_bytes), expected)


def decode_object(obj: Any, expected: int | None = None) -> Envelope:
    """Like :func:`decode` for an already-parsed JSON value.

    A refused object's error names its sender (``err.client_id``) when it named one, so the refusal is addressed
    without parsing the payload again."""
    if not isinstance(obj, dict):
        raise ProtocolError(f"expected a JSON object, got {describe(obj)}")
    try:
        return _decode_dict(obj, expected)
    except ProtocolError as err:
        err.naming(err.request_id, _named_sender(obj))
        raise


def _named_sender(obj: dict[str, Any]) -> str | None:
    """The client id a JSON object names (``$client_id`` wins, as in generic bodies), if it is a valid one."""
    value = obj.get(GENERIC_SENDER_KEY, obj.get(CLIENT_ID_KEY))
    return value if isinstance(value, str) and 0 < len(value) <= MAX_CLIENT_ID else None


def _decode_dict(obj: dict[str, Any], expected: int | None) -> Envelope:
    if "message_id" not in obj and "payload" not in obj:
        if expected is None:
            raise ProtocolError("missing field 'message_id' (a bare payload needs a topic that names the message)")
        spec = _spec(expected)
        return Envelope(spec.message_id, validate_payload(spec, obj, "payload"))
    header = _check_header(obj)
    message_id = header.get("message_id")
    if message_id is None:
        if expected is None:
            raise ProtocolError("missing field 'message_id'")
        message_id = expected
    spec = _spec(message_id)
    if expected is not None and message_id != expected:
        raise ProtocolError(
            f"message_id {message_id} ({spec.name}) does not match the topic, which expects "
            f"{int(expected)} ({_spec(expected).name})")
    if "payload" not in obj:
        raise ProtocolError("missing field 'payload'")
    return Envelope(
        message_id=spec.message_id,
        payload=validate_payload(spec, obj["payload"]),
        system_id=header.get("system_id", 0),
        sequence_number=header.get("sequence_number"),
        roslink_version=header.get("roslink_version", ROSLINK_VERSION),
        ros_version=header.get("ros_version", ROS_VERSION),
        client_id=obj.get(CLIENT_ID_KEY),
    )


def _spec(message_id: int) -> MessageSpec:
    spec = SPECS_BY_ID.get(message_id)
    if spec is None:
        raise ProtocolError(f"message_id: unknown message_id {message_id}")
    return spec


def _check_header(obj: dict[str, Any]) -> dict[str, int]:
    header: dict[str, int] = {}
    for key, value in obj.items():
        if key == "payload":
            continue
        if key == CLIENT_ID_KEY:
            if not isinstance(value, str) or not 0 < len(value) <= MAX_CLIENT_ID:
                raise ProtocolError(f"{key}: expected a string of 1..{MAX_CLIENT_ID} characters, "
                                    f"got {describe(value)}")
            continue
        bounds = _HEADER_BOUNDS.get(key)
        if bounds is None:
            if key == "key":
                raise ProtocolError("field 'key' is not accepted: the ROSLink key lives in your broker "
                                    "credentials and grants, never in a message")
            raise ProtocolError(f"unknown field '{show_key(key)}' in envelope "
                                f"(fields: {', '.join(sorted(_ENVELOPE_KEYS))})")
        if isinstance(value, bool) or not isinstance(value, int):
            raise ProtocolError(f"{key}: expected integer, got {describe(value)}")
        if not bounds[0] <= value <= bounds[1]:
            raise ProtocolError(f"{key}: expected integer {bounds[0]}..{bounds[1]}, got {value}")
        header[key] = value
    return header


__all__ = ["Envelope", "MessageId", "ROSLINK_VERSION", "ROS_VERSION", "decode", "decode_object", "encode",
           "encode_message", "loads"]
