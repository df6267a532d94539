"""JSON Schema for what flows on a topic of the tree, from the protocol's own declarations (``roslink-mqtt record``).

Foxglove (and Lichtblick) show a JSON channel of an MCAP file field by field when the channel has a ``jsonschema``
schema. Every schema here is derived from a declaration the protocol already has, so it cannot drift from what
is sent:

* ROSLink messages (the heartbeat, preset state such as ``global_motion``, ``ack``): the envelope, with the payload
  from :data:`~roslink_mqtt.protocol.messages.SPECS`;
* control bodies (``state/description``, ``state/link``, ``state/control``, replies, errors, goal updates …): their
  ``FIELDS``;
* a generic rule's ROS message as JSON: the field layout the robot's description publishes (``types``);
* anything else: an object schema titled by its topic, so no channel is without one.

:func:`compressed_image_schema` is Foxglove's well-known ``foxglove.CompressedImage`` (JSON: ``data`` base64), which
raw image streams are recorded as; :func:`compressed_video_schema` its ``foxglove.CompressedVideo``, for video streams.
"""

from __future__ import annotations

from typing import Any

from ..topics import Kind, ParsedTopic, Verb, param_events_node
from .body import BodyField
from .control import AccessReport, CallReply, ErrorReport, Notice, ProviderRequest
from .description import RobotDescription
from .goals import GoalFeedback, GoalResult, GoalStatus
from .lease import CONTROL, ControlState
from .link import LINK, LinkReport
from .messages import SPECS_BY_NAME, FieldKind, MessageSpec
from .node_params import ParamSetRequest
from .params import ParamEvent, ParamReply
from .provided_actions import ActionRequest

DRAFT = "https://json-schema.org/draft/2020-12/schema"

# bodies the robot sends a user (to/<user>/<verb>/…) and its own state names
TO_USER_BODIES: dict[Verb, Any] = {
    Verb.REPLY: CallReply, Verb.REQUEST: ProviderRequest, Verb.ERROR: ErrorReport, Verb.NOTICE: Notice,
    Verb.ACCESS: AccessReport, Verb.GOAL_STATUS: GoalStatus, Verb.FEEDBACK: GoalFeedback, Verb.RESULT: GoalResult,
    Verb.PARAM_REPLY: ParamReply, Verb.PARAM_SET: ParamSetRequest, Verb.ACTION_REQUEST: ActionRequest,
}
STATE_BODIES: dict[str, Any] = {"description": RobotDescription, LINK: LinkReport, CONTROL: ControlState}

_FIELD_KINDS: dict[FieldKind, dict[str, Any]] = {
    FieldKind.INT: {"type": "integer"}, FieldKind.FLOAT: {"type": "number"}, FieldKind.STR: {"type": "string"},
    FieldKind.BOOL: {"type": "boolean"},
    FieldKind.FLOAT_LIST: {"type": "array", "items": {"type": "number"}},
    FieldKind.RANGE_LIST: {"type": "array", "items": {"type": ["number", "null"]}},
    FieldKind.INT_LIST: {"type": "array", "items": {"type": "integer"}},
    FieldKind.BASE64: {"type": "string", "contentEncoding": "base64"},
}
ENVELOPE = {"roslink_version": {"type": "integer"}, "ros_version": {"type": "integer"},
            "system_id": {"type": "integer"}, "message_id": {"type": "integer"},
            "sequence_number": {"type": "integer"}, "client_id": {"type": "string"}}
# a .msg primitive → JSON Schema (the bridge's ROS JSON: numbers, strings, booleans; bytes as integers)
_PRIMITIVES = {"bool": "boolean", "boolean": "boolean", "string": "string", "wstring": "string",
               "float32": "number", "float64": "number", "double": "number", "float": "number"}


def _doc(schema: dict[str, Any], title: str) -> dict[str, Any]:
    return {"$schema": DRAFT, "title": title, **schema}


def message_schema(spec: MessageSpec) -> dict[str, Any]:
    """A ROSLink message: its envelope, the payload's fields typed."""
    payload = {"type": "object", "properties": {f.name: {**_FIELD_KINDS[f.kind], **({"description": f.doc}
                                                                                   if f.doc else {})}
                                                for f in spec.fields},
               "required": [f.name for f in spec.fields if f.required]}
    return _doc({"type": "object", "properties": {**ENVELOPE, "payload": payload},
                 "required": ["message_id", "payload"]}, f"roslink.{spec.name}")


def _spec_schema(data: dict[str, Any]) -> dict[str, Any]:
    kind = data["kind"]
    if kind in ("string", "levels"):
        return {"type": "string"}
    if kind in ("integer", "number", "boolean", "object"):
        return {"type": kind}
    if kind == "strings":
        return {"type": "array", "items": {"type": "string"}}
    if kind == "text_map":
        return {"type": "object", "additionalProperties": {"type": "string"}}
    if kind == "objects":
        return {"type": "array", "items": {"type": "object"}}
    if kind == "choice":
        return {"type": "string", "enum": list(data["values"])}
    if kind == "id":
        return {"type": ["string", "integer"]}
    if kind == "nullable":
        return {"anyOf": [_spec_schema(data["inner"]), {"type": "null"}]}
    return {}


def body_schema(fields: tuple[BodyField, ...], title: str) -> dict[str, Any]:
    """A control body from its declared fields."""
    return _doc({"type": "object",
                 "properties": {f.name: {**_spec_schema(f.spec.as_data()), "description": f.doc} for f in fields},
                 "required": [f.name for f in fields if f.required]}, title)


def ros_schema(ros_type: str, types: dict[str, Any]) -> dict[str, Any] | None:
    """A ROS message as the bridge's JSON, from the description's field layouts; None when it has no layout."""
    layout = types.get(ros_type)
    if not isinstance(layout, dict):
        return None
    return _doc(_layout_schema(layout), ros_type)


def _layout_schema(fields: dict[str, Any]) -> dict[str, Any]:
    return {"type": "object", "properties": {name: _field_schema(kind) for name, kind in fields.items()}}


def _field_schema(kind: Any) -> dict[str, Any]:
    if isinstance(kind, dict):  # a nested message: {"type": "pkg/msg/T", "fields": {…}}
        return {**_layout_schema(kind.get("fields") or {}), "title": str(kind.get("type", ""))}
    text = str(kind)
    if text.endswith("]"):  # float64[36], int32[], string[<=5]
        item = text[:text.rindex("[")]
        return {"type": "array", "items": _field_schema(item)}
    base = text.split("<=")[0]
    if base in _PRIMITIVES:
        return {"type": _PRIMITIVES[base]}
    if base.startswith(("int", "uint", "byte", "char")):
        return {"type": "integer"}
    return {}


def compressed_image_schema() -> dict[str, Any]:
    """Foxglove's ``foxglove.CompressedImage`` (its JSON form: ``data`` base64): how raw image streams are kept."""
    time = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
    return _doc({"type": "object", "properties": {
        "timestamp": time, "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string", "description": "jpeg, png, webp or avif"}}}, "foxglove.CompressedImage")


def compressed_video_schema() -> dict[str, Any]:
    """Foxglove's ``foxglove.CompressedVideo`` (its JSON form: ``data`` base64, one frame, Annex B for H.264): how
    video streams are served and kept (Foxglove's Image panel decodes it)."""
    time = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
    return _doc({"type": "object", "properties": {
        "timestamp": time, "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string", "description": "h264, h265, vp9 or av1"}}}, "foxglove.CompressedVideo")


def fallback_schema(topic: str) -> dict[str, Any]:
    return _doc({"type": "object"}, topic)


def schema_for(parsed: ParsedTopic, topic: str, description: RobotDescription | None) -> dict[str, Any]:
    """The schema of ``topic`` (parsed), given what the robot's description says (None: not read yet)."""
    if parsed.kind is Kind.HEARTBEAT:
        return message_schema(SPECS_BY_NAME["heartbeat"])
    if parsed.kind is Kind.TO and parsed.verb in TO_USER_BODIES:
        body = TO_USER_BODIES[parsed.verb]
        return body_schema(body.FIELDS, body.__name__)
    if parsed.kind is Kind.STATE and parsed.name is not None:
        name = parsed.name
        if name in STATE_BODIES:
            return body_schema(STATE_BODIES[name].FIELDS, STATE_BODIES[name].__name__)
        if param_events_node(name) is not None:
            return body_schema(ParamEvent.FIELDS, "ParamEvent")
        if description is not None and any(v.name == name for v in description.video):
            return compressed_video_schema()
        entry = next((e for e in description.state if e.name == name), None) if description else None
        if entry is not None and entry.message and entry.message in SPECS_BY_NAME:
            return message_schema(SPECS_BY_NAME[entry.message])
        if entry is None and name in SPECS_BY_NAME:  # a preset's own name (state/ack) before any description
            return message_schema(SPECS_BY_NAME[name])
        if entry is not None and entry.encoding == "raw":
            return compressed_image_schema()
        if entry is not None and entry.ros_type and description is not None:
            found = ros_schema(entry.ros_type, description.types)
            if found is not None:
                return found
    return fallback_schema(topic)
