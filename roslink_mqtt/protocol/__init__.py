"""The ROSLink wire protocol: envelope, message ids, payload schemas, codec.

Pure Python plus orjson: importable on any client machine (no rclpy, no amqtt).
"""

from .codec import (
    DEFAULT_MAX_BYTES,
    ROS_VERSION,
    ROSLINK_VERSION,
    Envelope,
    decode,
    decode_object,
    encode,
    encode_message,
    loads,
)
from .control import AccessReport, ErrorReport, error_reply, sender_id
from .enums import AckResult, FlightMode, RobotType, SystemStatus
from .errors import ProtocolError
from .messages import SPECS, SPECS_BY_ID, SPECS_BY_NAME, Direction, Field, FieldKind, MessageId, MessageSpec, spec_for
from .sequence import SequenceTracker, Verdict
from .validate import validate_payload

__all__ = [
    "DEFAULT_MAX_BYTES", "ROSLINK_VERSION", "ROS_VERSION", "SPECS", "SPECS_BY_ID", "SPECS_BY_NAME",
    "AccessReport", "AckResult", "Direction", "Envelope", "ErrorReport", "Field", "FieldKind", "FlightMode",
    "MessageId", "MessageSpec",
    "ProtocolError", "RobotType", "SequenceTracker", "SystemStatus", "Verdict",
    "decode", "decode_object", "encode", "encode_message", "error_reply", "loads", "sender_id", "spec_for",
    "validate_payload",
]
