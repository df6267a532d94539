"""Markdown reference of every ROSLink message, generated from the schema table.

docs/protocol.md embeds this output between markers (the messages, and the
control bodies of ``protocol.control``), and a test checks they agree, so the
document client writers read cannot drift from the code.
Run ``python -m roslink_mqtt.protocol.reference --write docs/protocol.md`` to regenerate in place.
"""

from __future__ import annotations

import base64
from typing import Any, Protocol

import orjson

from ..topics import TopicTree, Verb
from .body import BodyField
from .codec import _HEADER_BOUNDS, ROSLINK_VERSION, Envelope, encode
from .control import (
    CONTROL_BODIES,
    MAX_CALL_ID,
    AccessReport,
    Advertisement,
    CallReply,
    CallRequest,
    ErrorReport,
    Notice,
    ProviderRequest,
    ProviderResponse,
    ServiceOffer,
)
from .description import DESCRIPTION_BODIES, DESCRIPTION_ENTRIES, RobotDescription
from .description import EXAMPLE as DESCRIPTION_EXAMPLE
from .fleet_control import ControlRequest, ControlResponse
from .goals import GOAL_BODIES, GoalCancel, GoalFeedback, GoalRequest, GoalResult, GoalStatus
from .grants import GRANTS_BODIES, RobotGrants
from .lease import LEASE_BODIES, ControlState
from .link import LINK_BODIES, LinkReport, StreamReport
from .messages import SPECS, Direction, Field, FieldKind, MessageSpec
from .node_params import NODE_PARAM_BODIES, DeclaredParameter, ParamDeclaration, ParamSetRequest, ParamSetResult
from .params import PARAM_BODIES, ParamEvent, ParamReply, ParamRequest
from .provided_actions import PROVIDED_ACTION_BODIES, ActionOffer, ActionRequest, ActionUpdate
from .rosout import ROSOUT_BODIES, LogLine
from .snapshot import SNAPSHOT_BODIES, SnapshotChunk, SnapshotRequest
from .video import VIDEO_BODIES, VideoFrame, WatchRequest

BEGIN = "<!-- BEGIN GENERATED: message reference (python -m roslink_mqtt.protocol.reference) -->"
END = "<!-- END GENERATED: message reference -->"
BEGIN_CONTROL = "<!-- BEGIN GENERATED: control bodies (python -m roslink_mqtt.protocol.reference) -->"
END_CONTROL = "<!-- END GENERATED: control bodies -->"
BEGIN_VERBS = "<!-- BEGIN GENERATED: verbs (python -m roslink_mqtt.protocol.reference) -->"
END_VERBS = "<!-- END GENERATED: verbs -->"

# in the order docs/protocol.md shows them
DOCUMENTED_BODIES = (CONTROL_BODIES + GOAL_BODIES + PROVIDED_ACTION_BODIES + PARAM_BODIES + NODE_PARAM_BODIES +
                     ROSOUT_BODIES + DESCRIPTION_BODIES + LINK_BODIES + LEASE_BODIES + GRANTS_BODIES + SNAPSHOT_BODIES +
                     VIDEO_BODIES)



class _DocumentedBody(Protocol):
    """What the reference reads of a control body: its type's FIELDS, QOS and RETAINED, and its JSON."""

    @property
    def FIELDS(self) -> tuple[BodyField, ...]: ...
    @property
    def QOS(self) -> int: ...
    @property
    def RETAINED(self) -> bool: ...
    def to_json(self) -> bytes: ...


_CONTROL_EXAMPLES: dict[type, _DocumentedBody] = {
    ParamDeclaration: ParamDeclaration("alice-legacy_arm-5f2c9e0a1b3d4c6e", {
        "max_force": DeclaredParameter(2.5, "double", "gripper force limit (N)"),
        "serial_port": DeclaredParameter("/dev/ttyUSB0", "string", read_only=True)}),
    ParamSetRequest: ParamSetRequest("turtle1-p3", {"max_force": 3.0}, "alice-legacy_arm-5f2c9e0a1b3d4c6e"),
    ParamSetResult: ParamSetResult("turtle1-p3", False, "max_force must be at most 5 N",
                                   "alice-legacy_arm-5f2c9e0a1b3d4c6e"),
    ActionOffer: ActionOffer("test_msgs/action/Fibonacci", client_id="alice-planner-5f2c9e0a1b3d4c6e"),
    ActionRequest: ActionRequest("turtle1-g7", "goal", {"order": 5}, "alice-planner-5f2c9e0a1b3d4c6e"),
    ActionUpdate: ActionUpdate("turtle1-g7", "succeeded", result={"sequence": [0, 1, 1, 2, 3, 5]}),
    LogLine: LogLine(20, "gripper closed", "legacy_arm.py", "close", 42, "alice-legacy_arm-5f2c9e0a1b3d4c6e"),
    ControlState: ControlState("alice", 1764158585.2, False, "auto", ("admin",), "viewers", "claimed by alice"),
    ControlRequest: ControlRequest(({"command": "getFleet", "correlationData": "apply-1-0"},), "apply-1"),
    ControlResponse: ControlResponse(({"command": "reload", "correlationData": "apply-2-0", "data": {
        "file": "/etc/roslink-mqtt/robots.yaml", "sha256": "9f2c…",
        "logins": {"alice": {"kind": "user", "password": "5e1d0c9a8b7f6e21"}},
        "grants": {"turtle1": {"alice": "operator"}}}},), "apply-2"),
    RobotGrants: RobotGrants("turtle1", {"admin": "operator", "alice": "operator", "bob": "viewer"}, 1764158585.2,
                             "admin"),
    LinkReport: LinkReport("scheduled", 243.5, True, 3300, 81.2, 2.0, {
        "global_motion": StreamReport("motion", True, 10.0, 10.0, 0, 0, 10.0, 39.2),
        "range_finder_data": StreamReport("state", True, 5.0, 3.5, 3, 0, 5.0, 196.1)}),
    RobotDescription: DESCRIPTION_EXAMPLE,
    ParamRequest: ParamRequest("p-1", "set", values={"max_speed": 0.3}, client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    SnapshotRequest: SnapshotRequest(30.0, client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    SnapshotChunk: SnapshotChunk(0, 12, 190_734, "9f2c" * 16, b"", 1_795_700_000_000_000_000,
                                 1_795_700_030_000_000_000, 1_204, client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    WatchRequest: WatchRequest("alice-web-5f2c9e0a", key=True),
    VideoFrame: VideoFrame("h264", True, 1_207, 1_795_700_000.125, 320, 240, "avc1.42c01f", b"",
                           encoded=1_795_700_000.141, kbit_s=180.0, fps=15.0),
    ParamReply: ParamReply("p-1", True, {"max_speed": {"successful": True, "reason": ""}},
                           client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    ParamEvent: ParamEvent("/sim_robot", changed={"max_speed": 0.3}),
    GoalRequest: GoalRequest("dock-3", {"order": 5}, "alice-sdk-5f2c9e0a1b3d4c6e"),
    GoalCancel: GoalCancel("dock-3", "alice-sdk-5f2c9e0a1b3d4c6e"),
    GoalStatus: GoalStatus("dock-3", "accepted", client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    GoalFeedback: GoalFeedback("dock-3", {"sequence": [0, 1, 1, 2]}, "alice-sdk-5f2c9e0a1b3d4c6e"),
    GoalResult: GoalResult("dock-3", "succeeded", {"sequence": [0, 1, 1, 2, 3, 5]},
                           client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    ErrorReport: ErrorReport(TopicTree().command("turtle1", "alice", "twist"),
                             'payload.lx: expected number, got "fast"', 100, 18, "alice-sdk-5f2c9e0a1b3d4c6e"),
    Notice: Notice(TopicTree().command("turtle1", "alice", "twist"),
                   "clamped to the robot's limits: linear speed 50 m/s cut to 0.5 m/s (limit 0.5 m/s)", 100, 19,
                   "alice-sdk-5f2c9e0a1b3d4c6e"),
    AccessReport: AccessReport("viewer", ("status",)),
    CallRequest: CallRequest("42", {}, "alice-sdk-5f2c9e0a1b3d4c6e"),
    CallReply: CallReply("42", True, {"success": True, "message": "pose reset to the room centre"},
                         client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    ServiceOffer: ServiceOffer("std_srvs/srv/SetBool", 5.0, "alice-sdk-5f2c9e0a1b3d4c6e"),
    ProviderRequest: ProviderRequest("turtle1-7", {"data": True}, "alice-sdk-5f2c9e0a1b3d4c6e"),
    ProviderResponse: ProviderResponse("turtle1-7", True, {"success": True, "message": "motors on"},
                                       client_id="alice-sdk-5f2c9e0a1b3d4c6e"),
    Advertisement: Advertisement("std_msgs/msg/String", "alice-sdk-5f2c9e0a1b3d4c6e"),
}

_EXAMPLES: dict[str, dict[str, Any]] = {
    "heartbeat": {"type": 1, "name": "turtle1", "system_status": 4, "owner_id": "alice", "mode": 0, "session": 3},
    "robot_status": {"voltage_battery": 12.1, "current_battery": -1.5, "battery_remaining": 87.0},
    "global_motion": {"time_boot_ms": 52100, "x": 1.2, "y": -0.4, "z": 0.0, "vx": 0.2, "vy": 0.0, "vz": 0.0,
                      "wx": 0.0, "wy": 0.0, "wz": 0.5, "roll": 0.0, "pitch": 0.0, "yaw": 1.57},
    "gps_raw_info": {"fix_type": 3, "lat": 24.7136, "lon": 46.6753, "alt": 612.0, "satellites_visible": 9},
    "range_finder_data": {"range_min": 0.12, "range_max": 10.0, "angle_min": -1.57, "angle_max": 1.57,
                          "angle_increment": 1.57, "ranges": [2.5, None, 0.8]},
    "image": {"width": 2, "height": 2, "format": "jpeg", "data": base64.b64encode(b"\xff\xd8\xff").decode()},
    "map": {"width": 2, "height": 2, "resolution": 0.05, "origin_x": -5.0, "origin_y": -5.0,
            "data": [0, 0, 100, -1]},
    "geo_tagged_image": {"lat": 24.7136, "lon": 46.6753, "alt": 612.0, "format": "jpeg",
                         "data": base64.b64encode(b"\xff\xd8\xff").decode()},
    "twist": {"lx": 0.2, "ly": 0.0, "lz": 0.0, "ax": 0.0, "ay": 0.0, "az": 0.5},
    "go_to_waypoint": {"frame_type": 0, "x": 2.0, "y": 1.0, "z": 0.0},
    "takeoff": {"altitude": 1.5},
    "set_mode": {"mode": "GUIDED"},
    "emergency_stop": {"reason": "person in the aisle"},
    "ack": {"command": 100, "command_sequence": 17, "result": 3, "text": "operator alice went away"},
}


def example(spec: MessageSpec) -> dict[str, Any]:
    return dict(_EXAMPLES.get(spec.name, {}))


def _field_row(f: Field) -> str:
    kind = f.kind.value
    if f.bounds and f.kind in (FieldKind.INT, FieldKind.INT_LIST):
        kind += f" {f.bounds[0]}..{f.bounds[1]}"
    default = "required" if f.required else f"default `{orjson.dumps(f.default).decode()}`"
    return f"| `{f.name}` | {kind} | {default} | {f.doc} |"


def _topic(spec: MessageSpec) -> str:
    doc = TopicTree()  # placeholders in angle brackets, as docs/protocol.md shows topics
    if spec.name == "heartbeat":
        return f"`{doc.heartbeat('<robot>')}` (retained)"
    if spec.direction is Direction.STATE:
        return f"`{doc.state('<robot>', spec.name)}`"
    return f"`{doc.command('<robot>', '<user>', spec.name)}`"


def render() -> str:
    out = [BEGIN, ""]
    for spec in SPECS:
        out.append(f"### {int(spec.message_id)} {spec.name}")
        out.append("")
        out.append(f"Topic: {_topic(spec)}." + (f" {spec.doc}" if spec.doc else ""))
        out.append("")
        if spec.fields:
            out += ["| field | type | | meaning |", "|---|---|---|---|", *(_field_row(f) for f in spec.fields), ""]
        else:
            out += ["No fields: send `{}`.", ""]
        wire = encode(Envelope(spec.message_id, example(spec), system_id=1, sequence_number=17), validate=True)
        out += ["```json", wire.decode(), "```", ""]
    out.append(END)
    return "\n".join(out)


_RULES = """\
Rules every control body follows (the sections below give each one's fields):

* A control body is a JSON object with the fields listed, and no `roslink_version`: it is versioned with the
  topic tree. Where the **bridge** reads a body (call request, service offer, provider response,
  advertisement) it refuses what does not match, with the reason on the reply topic (calls) or on
  `to/<user>/error` (the others); it refuses unknown fields, except in provider responses. Where a **client**
  reads one (call reply, provider request, error and access reports) it ignores fields it does not know, so
  the bridge may add some.
* Ids: a call's `id` is the caller's (string of at most {max_id} characters, or integer), echoed and never
  interpreted, so a caller picks ids unique among its own outstanding calls (the SDK: a random prefix per
  connection and a counter). A provider request's `id` is the bridge's, `<robot>-<n>`, and a response must carry
  it unchanged; a response whose `id` matches no waiting call is reported on `to/<user>/error`.
* `client_id` names one program of a user (all its programs read the user's topics); where a body gives a
  length it is checked, elsewhere any string is taken.
* `roslink_version` exists only in ROSLink envelopes (messages, not control bodies). Bridge and SDK accept
  any integer {low}..{high} there and read the message as version {version}: the number is not compared,
  so a peer sending another version is neither refused nor warned about; a value outside {low}..{high}, or
  not an integer, is refused like any malformed header field (`roslink_version: expected integer
  {low}..{high}, got …`)."""


def _field_rows(fields: tuple[BodyField, ...]) -> list[str]:
    return [f"| `{f.name}` | {f.type} | {'required' if f.required else 'optional'} | {f.doc} |" for f in fields]


def render_control() -> str:
    """The field tables of the control bodies (``protocol.control``), with one example each."""
    low, high = _HEADER_BOUNDS["roslink_version"]
    out = [BEGIN_CONTROL, "", *_RULES.format(version=ROSLINK_VERSION, low=low, high=high,
                                             max_id=MAX_CALL_ID).splitlines(), ""]
    for title, topic, cls in DOCUMENTED_BODIES:
        example = _CONTROL_EXAMPLES[cls]  # an instance of cls: its class constants and its JSON
        flags = f"QoS {example.QOS}, {'retained' if example.RETAINED else 'not retained'}"
        out += [f"#### {title}", "", f"Topic: {topic}. Published with {flags}.", "",
                "| field | type | | meaning |", "|---|---|---|---|"]
        out += _field_rows(example.FIELDS)
        if cls is RobotDescription:  # its entries
            out += ["", "In an entry a client ignores fields it does not know (a newer bridge may add some); a "
                        "known field with a wrong value makes the whole description unreadable."]
            for key, entry in DESCRIPTION_ENTRIES:
                out += ["", f"Each entry of `{key}`:", "", "| field | type | | meaning |", "|---|---|---|---|",
                        *_field_rows(entry.FIELDS)]
        out += ["", "```json", example.to_json().decode(), "```", ""]
    out.append(END_CONTROL)
    return "\n".join(out)


def render_verbs() -> str:
    """The verbs of the topic grammar (``roslink_mqtt.topics.Verb``): direction, name, retain flag, meaning."""
    doc = TopicTree()
    out = [BEGIN_VERBS, "", "| verb | topic | retained by its sender | meaning |", "|---|---|---|---|"]
    for verb in Verb:
        name = ("<service>" if verb in (Verb.CALL, Verb.REPLY, Verb.PROVIDE, Verb.REQUEST, Verb.RESPONSE) else
                "<action>" if verb in (Verb.GOAL, Verb.CANCEL, Verb.GOAL_STATUS, Verb.FEEDBACK, Verb.RESULT,
                                       Verb.PROVIDE_ACTION, Verb.ACTION_UPDATE, Verb.ACTION_REQUEST) else
                "<node>" if verb in (Verb.PARAM, Verb.PARAM_REPLY, Verb.LOG, Verb.DECLARE, Verb.PARAM_SET,
                                     Verb.PARAM_RESULT) else
                "<command>" if verb is Verb.CMD else "<id>" if verb in (Verb.SNAPSHOT, Verb.SNAPSHOT_DATA) else
                "<stream>" if verb is Verb.WATCH else "<rule>")
        topic = doc.user_topic("<robot>", "<user>", verb, name if verb.named else "")
        out.append(f"| `{verb.value}` | `{topic}` | {'yes' if verb.retained_by_sender else 'no'} | {verb.meaning} |")
    out += ["", "A topic under `from/<user>/` whose first level is none of the user's verbs is a generic rule's "
                "input (`from/<user>/lights`).", END_VERBS]
    return "\n".join(out)


def write(path: str) -> None:
    """Replace the generated sections of ``path`` (between their markers) with a fresh render."""
    from pathlib import Path

    doc = Path(path)
    text = doc.read_text()
    for begin, end_marker, fresh in ((BEGIN, END, render()), (BEGIN_CONTROL, END_CONTROL, render_control()),
                                     (BEGIN_VERBS, END_VERBS, render_verbs())):
        start, end = text.index(begin), text.index(end_marker) + len(end_marker)
        text = text[:start] + fresh + text[end:]
    doc.write_text(text)


if __name__ == "__main__":
    import sys

    if len(sys.argv) == 3 and sys.argv[1] == "--write":
        write(sys.argv[2])
    else:
        print(render())
        print()
        print(render_control())
        print()
        print(render_verbs())
