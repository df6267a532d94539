"""Bodies write what they declare (protocol/body.py, :func:`~roslink_mqtt.protocol.body.write`).

A body's ``to_json`` used to list its fields a third time, by hand; those that followed the common rule (declared
order, an optional field left out when None, ``client_id`` last) now write their declarations. Their bytes did not
change — the exact examples below are what the hand-written writers wrote — and every one still reads back as it
was written.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.protocol import description
from roslink_mqtt.protocol.body import BodyField, Integer, Nullable, Strings, Text, body_of, write
from roslink_mqtt.protocol.control import (
    AccessReport,
    Advertisement,
    ErrorReport,
    Notice,
    ProviderRequest,
    ServiceOffer,
)
from roslink_mqtt.protocol.goals import GoalCancel, GoalFeedback, GoalRequest, GoalResult, GoalStatus
from roslink_mqtt.protocol.lease import ControlState
from roslink_mqtt.protocol.link import LinkReport, PathReport, StreamReport
from roslink_mqtt.protocol.messages import MessageId
from roslink_mqtt.protocol.node_params import DeclaredParameter, ParamDeclaration, ParamSetRequest
from roslink_mqtt.protocol.params import ParamEvent
from roslink_mqtt.protocol.provided_actions import FEEDBACK, UPDATE_STATUSES, ActionOffer, ActionUpdate
from roslink_mqtt.protocol.snapshot import MAX_CHUNKS, SnapshotChunk

pytestmark = pytest.mark.unit

INTS = st.integers(-(2**53), 2**53)  # what JSON carries exactly
FLOATS = st.floats(allow_nan=False, allow_infinity=False)
json_scalars = st.none() | st.booleans() | INTS | st.text(max_size=20) | FLOATS
json_values = st.recursive(json_scalars, lambda inner: st.lists(inner, max_size=3)
                           | st.dictionaries(st.text(max_size=8), inner, max_size=3), max_leaves=8)


def objects(max_items: int = 4) -> st.SearchStrategy[dict[str, Any]]:
    return st.dictionaries(st.text(max_size=8), json_values, max_size=max_items)


def values(spec: dict[str, Any]) -> st.SearchStrategy[Any]:
    """Values a spec takes, from the spec as data (``Spec.as_data``, what the dashboard reads), as :func:`read`
    gives them back (arrays as tuples, numbers as floats)."""
    kind = spec["kind"]
    if kind == "nullable":
        return st.none() | values(spec["inner"])
    if kind == "string":
        longest = spec["min"] + 30 if spec["max"] is None else min(spec["max"], spec["min"] + 30)
        return st.text(min_size=spec["min"], max_size=longest)
    if kind == "integer":
        return st.integers(-(2**53) if spec["low"] is None else spec["low"],
                           2**53 if spec["high"] is None else spec["high"])
    if kind == "number":
        return st.floats(spec["low"], spec["high"], exclude_min=spec["low_open"] and spec["low"] is not None,
                         allow_nan=False, allow_infinity=False)
    if kind == "boolean":
        return st.booleans()
    if kind == "object":
        return objects(min(4, spec["max"] or 4))
    if kind == "strings":
        return st.lists(st.text(min_size=int(spec["non_empty"]), max_size=10), max_size=3).map(tuple)
    if kind == "text_map":
        return st.dictionaries(st.text(max_size=8), st.text(max_size=8), max_size=3)
    if kind == "objects":
        return st.lists(objects(3), max_size=3).map(tuple)
    if kind in ("choice", "levels"):
        return st.sampled_from(spec["values"])
    if kind == "id":
        text = st.text(min_size=spec["min"], max_size=spec["max"])
        return text if spec["strings_only"] else text | INTS
    assert kind == "any", spec
    return json_values


def field_values(field: BodyField) -> st.SearchStrategy[Any]:
    """A field's values; None too where None means "absent" (an optional field whose default is None)."""
    taken = values(field.spec.as_data())
    return st.none() | taken if field.default is None and field.spec.KIND not in ("nullable", "any") else taken


def bodies(cls: Any, **overrides: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
    """Instances of ``cls`` whose every field takes what its declaration takes (``overrides``: what it does not
    say, e.g. a service type's form)."""
    return st.builds(cls, **{**{f.name: field_values(f) for f in cls.FIELDS}, **overrides})


def some(entry: type) -> st.SearchStrategy[tuple[Any, ...]]:
    return st.lists(bodies(entry), max_size=2).map(tuple)


PRESENT_TEXT = st.none() | st.text(min_size=1, max_size=20)  # an empty error reads back as none
PARAMETER_VALUES = {"bool": st.booleans(), "integer": INTS, "double": FLOATS, "string": st.text(max_size=10),
                    "not_set": st.none()}
declared_parameters = st.sampled_from(sorted(PARAMETER_VALUES)).flatmap(
    lambda kind: st.builds(DeclaredParameter, st.none() | PARAMETER_VALUES[kind], st.just(kind),
                           st.text(max_size=20), st.booleans()))
parameter_names = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}(\.[A-Za-z_][A-Za-z0-9_]{0,8})?", fullmatch=True)
snapshot_chunks = st.integers(1, MAX_CHUNKS).flatmap(
    lambda count: bodies(SnapshotChunk, index=st.integers(0, count - 1), count=st.just(count),
                         data=st.binary(max_size=8)))
action_updates = st.sampled_from(UPDATE_STATUSES).flatmap(  # feedback reads back only with status feedback
    lambda status: bodies(ActionUpdate, status=st.just(status),
                          feedback=objects() if status == FEEDBACK else st.none()))
description_entries = {key: some(entry) for key, entry in description.DESCRIPTION_ENTRIES}
description_entries["state"] = st.lists(  # an encoding "json" reads back as none
    bodies(description.StateEntry, encoding=PRESENT_TEXT.filter(lambda e: e != "json")), max_size=2).map(tuple)

# every body whose to_json is write(FIELDS, …): instances that read back as they are
INSTANCES: dict[type, st.SearchStrategy[Any]] = {
    ErrorReport: bodies(ErrorReport),
    Notice: bodies(Notice),
    AccessReport: bodies(AccessReport),
    ServiceOffer: bodies(ServiceOffer, type=st.from_regex(r"[a-z_]{1,8}/srv/[A-Z][a-zA-Z]{0,8}", fullmatch=True)),
    ProviderRequest: bodies(ProviderRequest),
    Advertisement: bodies(Advertisement),
    GoalRequest: bodies(GoalRequest),
    GoalCancel: bodies(GoalCancel),
    GoalStatus: bodies(GoalStatus, error=PRESENT_TEXT),
    GoalFeedback: bodies(GoalFeedback),
    GoalResult: bodies(GoalResult, error=PRESENT_TEXT),
    ControlState: bodies(ControlState),
    LinkReport: bodies(LinkReport, streams=st.dictionaries(st.text(max_size=8), bodies(StreamReport), max_size=3),
                       path=st.none() | bodies(PathReport)),
    ParamDeclaration: bodies(ParamDeclaration,
                             parameters=st.dictionaries(parameter_names, declared_parameters, max_size=3)),
    ParamSetRequest: bodies(ParamSetRequest),
    ParamEvent: bodies(ParamEvent),
    ActionOffer: bodies(ActionOffer,
                        type=st.from_regex(r"[a-z_]{1,8}/action/[A-Z][a-zA-Z]{0,8}", fullmatch=True)),
    ActionUpdate: action_updates,
    SnapshotChunk: snapshot_chunks,
    description.RobotDescription: bodies(
        description.RobotDescription, type=st.text(min_size=1, max_size=10),  # an empty type reads back as generic
        types=st.dictionaries(st.text(max_size=8), objects(), max_size=2), **description_entries),
}

# what the hand-written writers wrote for these (the generic one must never write otherwise)
EXAMPLES: list[tuple[Any, bytes]] = [
    (ErrorReport("from/alice/cmd/twist", "payload.lx: expected number"),
     b'{"topic":"from/alice/cmd/twist","error":"payload.lx: expected number"}'),
    (ErrorReport("t", "e", MessageId.TWIST, 18, "alice-1", "goal-3"),
     b'{"topic":"t","error":"e","message_id":100,"sequence_number":18,"id":"goal-3","client_id":"alice-1"}'),
    (ErrorReport("t", "e", 0, None, None, 7),
     b'{"topic":"t","error":"e","message_id":0,"id":7}'),
    (Notice("from/alice/cmd/twist", "clamped"),
     b'{"topic":"from/alice/cmd/twist","notice":"clamped"}'),
    (Notice("t", "n", 100, 19, "alice-1"),
     b'{"topic":"t","notice":"n","message_id":100,"sequence_number":19,"client_id":"alice-1"}'),
    (AccessReport("viewer"),
     b'{"role":"viewer","services":[],"actions":[],"estop":false,"snapshot":false}'),
    (AccessReport("operator", ("reset", "status"), ("dock",), True, True),
     b'{"role":"operator","services":["reset","status"],"actions":["dock"],"estop":true,"snapshot":true}'),
    (ServiceOffer("std_srvs/srv/SetBool"),
     b'{"type":"std_srvs/srv/SetBool","timeout":5.0}'),
    (ServiceOffer("std_srvs/srv/SetBool", 2.5, "alice-1"),
     b'{"type":"std_srvs/srv/SetBool","timeout":2.5,"client_id":"alice-1"}'),
    (ProviderRequest(None),
     b'{"id":null,"args":{}}'),
    (ProviderRequest("turtle1-7", {"data": True}, "alice-1"),
     b'{"id":"turtle1-7","args":{"data":true},"client_id":"alice-1"}'),
    (Advertisement("std_msgs/msg/String"),
     b'{"type":"std_msgs/msg/String"}'),
    (Advertisement("std_msgs/msg/String", ""),
     b'{"type":"std_msgs/msg/String","client_id":""}'),
    (GoalRequest("dock-3"),
     b'{"id":"dock-3","goal":{}}'),
    (GoalRequest("dock-3", {"order": 5}, "alice-1"),
     b'{"id":"dock-3","goal":{"order":5},"client_id":"alice-1"}'),
    (GoalCancel("dock-3"),
     b'{"id":"dock-3"}'),
    (GoalCancel("dock-3", "alice-1"),
     b'{"id":"dock-3","client_id":"alice-1"}'),
    (GoalStatus("dock-3", "accepted"),
     b'{"id":"dock-3","status":"accepted"}'),
    (GoalStatus("dock-3", "rejected", "no server", "alice-1"),
     b'{"id":"dock-3","status":"rejected","error":"no server","client_id":"alice-1"}'),
    (GoalFeedback("dock-3", {}),
     b'{"id":"dock-3","feedback":{}}'),
    (GoalFeedback("dock-3", {"sequence": [0, 1]}, "alice-1"),
     b'{"id":"dock-3","feedback":{"sequence":[0,1]},"client_id":"alice-1"}'),
    (GoalResult("dock-3", "timeout"),
     b'{"id":"dock-3","status":"timeout"}'),
    (GoalResult("dock-3", "succeeded", {"sequence": [0, 1]}, "", "alice-1"),
     b'{"id":"dock-3","status":"succeeded","result":{"sequence":[0,1]},"error":"","client_id":"alice-1"}'),
    (ControlState(None, None),
     b'{"holder":null,"since":null,"supervisor":false,"mode":"auto","supervisors":[],"estop":"viewers","event":"",'
     b'"blocked":""}'),
    (ControlState("alice", 1764158585.2, True, "explicit", ("admin", "bob"), "operators", "claimed by alice",
                  "emergency stop by bob"),
     b'{"holder":"alice","since":1764158585.2,"supervisor":true,"mode":"explicit","supervisors":["admin","bob"],'
     b'"estop":"operators","event":"claimed by alice","blocked":"emergency stop by bob"}'),
    (LinkReport("fifo", 240.0, False, 3300, 81.2, 2.0),
     b'{"mode":"fifo","rate_kbit_s":240.0,"measured":false,"budget_bytes":3300,"rtt_ms":81.2,"period":2.0,'
     b'"streams":{}}'),
    (LinkReport("scheduled", 243.5, True, 3300, 81.2, 2.0,
                {"scan": StreamReport("state", True, 5.0, 3.9, 2, 0, 5.0, 20.1),
                 "pose": StreamReport("motion", False, 10.0, 10.0)}, PathReport(60.0, 62.0, 2.0, 900.0, 3, True)),
     b'{"mode":"scheduled","rate_kbit_s":243.5,"measured":true,"budget_bytes":3300,"rtt_ms":81.2,"period":2.0,'
     b'"streams":{"scan":{"priority":"state","latest_only":true,"offered_hz":5.0,"sent_hz":3.9,"superseded":2,'
     b'"dropped":0,"kbit_s":20.1,"max_rate":5.0},"pose":{"priority":"motion","latest_only":false,'
     b'"offered_hz":10.0,"sent_hz":10.0,"superseded":0,"dropped":0,"kbit_s":0.0}},"path":{"base_ms":60.0,'
     b'"rtt_ms":62.0,"queue_ms":2.0,"rate_kbit_s":900.0,"cuts":3,"steering":true}}'),
    (ParamDeclaration("alice-arm-1"),
     b'{"parameters":{},"client_id":"alice-arm-1"}'),
    (ParamDeclaration("alice-arm-1", {"max_force": DeclaredParameter(2.5, "double", "N"),
                                      "port": DeclaredParameter("/dev/x", "string", read_only=True),
                                      "any": DeclaredParameter(None, "not_set")}),
     b'{"parameters":{"max_force":{"value":2.5,"type":"double","description":"N"},"port":{"value":"/dev/x",'
     b'"type":"string","read_only":true},"any":{"value":null,"type":"not_set"}},"client_id":"alice-arm-1"}'),
    (ParamSetRequest(7, {}),
     b'{"id":7,"parameters":{}}'),
    (ParamSetRequest("turtle1-p3", {"max_force": 3.0}, "alice-arm-1"),
     b'{"id":"turtle1-p3","parameters":{"max_force":3.0},"client_id":"alice-arm-1"}'),
    (ParamEvent("/sim_robot"),
     b'{"node":"/sim_robot","new":{},"changed":{},"deleted":[]}'),
    (ParamEvent("/sim_robot", {"a": 1}, {"b": [1.5]}, ("c", "d")),
     b'{"node":"/sim_robot","new":{"a":1},"changed":{"b":[1.5]},"deleted":["c","d"]}'),
    (ActionOffer("test_msgs/action/Fibonacci"),
     b'{"type":"test_msgs/action/Fibonacci","accept_timeout":5.0,"result_timeout":600.0}'),
    (ActionOffer("test_msgs/action/Fibonacci", 1.5, 30.0, "alice-1"),
     b'{"type":"test_msgs/action/Fibonacci","accept_timeout":1.5,"result_timeout":30.0,"client_id":"alice-1"}'),
    (ActionUpdate("turtle1-g7", "accepted"),
     b'{"id":"turtle1-g7","status":"accepted"}'),
    (ActionUpdate("turtle1-g7", "feedback", {"sequence": [0]}, None, None, "alice-1"),
     b'{"id":"turtle1-g7","status":"feedback","feedback":{"sequence":[0]},"client_id":"alice-1"}'),
    (ActionUpdate("turtle1-g7", "aborted", None, {"sequence": []}, "stuck", "alice-1"),
     b'{"id":"turtle1-g7","status":"aborted","result":{"sequence":[]},"error":"stuck","client_id":"alice-1"}'),
    (SnapshotChunk(0, 1, 0, "0" * 64, b""),
     b'{"index":0,"count":1,"size":0,"sha256":"0000000000000000000000000000000000000000000000000000000000000000",'
     b'"start":0,"end":0,"messages":0}'),
    (SnapshotChunk(3, 12, 190734, "9f2c" * 16, b"\x00\n", 1, 2, 1204, "alice-1"),
     b'{"index":3,"count":12,"size":190734,'
     b'"sha256":"9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c9f2c","start":1,"end":2,'
     b'"messages":1204,"client_id":"alice-1"}'),
    (description.RobotDescription("r", 1),
     b'{"robot":"r","system_id":1,"type":"ground","protocol_version":2,"ros_version":24,"limits":{},"state":[],'
     b'"commands":[],"services":[],"actions":[],"parameters":[],"video":[],"types":{}}'),
    (description.RobotDescription(
        "turtle1", 1, "ground", 1, 2, {"linear": 0.5},
        (description.StateEntry("battery", None, "std_msgs/msg/Float32", max_rate=1.0),
         description.StateEntry("ack", "ack")),
        (description.CommandEntry("lights", None, "std_msgs/msg/Bool", on_demand=True),),
        (description.ServiceEntry("reset", "std_srvs/srv/Trigger", True, None, "viewers", "no server"),),
        (description.ActionEntry("fib", "t/action/F", False, 30.0),), {"std_msgs/msg/Bool": {"data": "bool"}},
        (description.ParameterEntry("sim", "sim"),)),
     b'{"robot":"turtle1","system_id":1,"type":"ground","protocol_version":1,"ros_version":2,'
     b'"limits":{"linear":0.5},"state":[{"name":"battery","ros_type":"std_msgs/msg/Float32","max_rate":1.0,'
     b'"who":"viewers"},{"name":"ack","message":"ack","who":"viewers"}],"commands":[{"name":"lights",'
     b'"ros_type":"std_msgs/msg/Bool","on_demand":true,"who":"operators"}],"services":[{"name":"reset",'
     b'"ros_type":"std_srvs/srv/Trigger","read_only":true,"timeout":null,"who":"viewers","warning":"no server"}],'
     b'"actions":[{"name":"fib","ros_type":"t/action/F","viewers":false,"timeout":30.0,"feedback_rate":null,'
     b'"who":"operators"}],"parameters":[{"name":"sim","node":"sim","set_by":"operators","timeout":null,'
     b'"who":"viewers"}],"video":[],"types":{"std_msgs/msg/Bool":{"data":"bool"}}}'),
]


@pytest.mark.parametrize(("body", "wire"), EXAMPLES,
                         ids=[f"{type(body).__name__}-{i}" for i, (body, _wire) in enumerate(EXAMPLES)])
def test_a_body_writes_exactly_what_its_hand_written_writer_wrote(body: Any, wire: bytes) -> None:
    assert body.to_json() == wire


def test_every_body_written_from_its_declaration_has_examples_and_instances() -> None:
    assert {type(body) for body, _wire in EXAMPLES} == set(INSTANCES)


@pytest.mark.parametrize("cls", list(INSTANCES), ids=lambda c: c.__name__)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_a_body_reads_back_what_it_writes(cls: Any, data: st.DataObject) -> None:
    body = data.draw(INSTANCES[cls])
    expected = replace(body, data=b"") if isinstance(body, SnapshotChunk) else body  # the header line alone
    assert cls.from_json(body.to_json()) == expected


@dataclass(frozen=True)
class _Body:
    client_id: str | None
    count: int | None
    note: str | None = None
    tags: tuple[str, ...] = ()

    FIELDS = (BodyField("client_id", Text(), False, "declared first, written last", None),
              BodyField("count", Nullable(Integer()), True, "required: null written"),
              BodyField("note", Text(), False, "optional: left out when None", None),
              BodyField("tags", Strings(), False, "a tuple, written as an array", ()))


def test_the_writer_keeps_the_declared_order_leaves_out_none_and_puts_client_id_last() -> None:
    assert body_of(_Body.FIELDS, _Body("laptop", None, tags=("a",))) == {"count": None, "tags": ["a"]}
    assert write(_Body.FIELDS, _Body("laptop", None, tags=("a",))) == \
        b'{"count":null,"tags":["a"],"client_id":"laptop"}'
    assert write(_Body.FIELDS, _Body(None, 3, "n")) == b'{"count":3,"note":"n","tags":[]}'


# Bodies whose writers had their own rules (left out when empty, null written, a field only with another's value)
# and now declare them (BodyField.written, written_if): the bytes their hand-written writers wrote (stop 61; an
# action request with op goal and no goal is the one change: `{}`, was `null`).
def _shaped_examples() -> list[tuple[Any, bytes]]:
    from roslink_mqtt.protocol.control import CallReply, CallRequest, ProviderResponse
    from roslink_mqtt.protocol.fleet_control import ControlRequest, ControlResponse
    from roslink_mqtt.protocol.grants import RobotGrants
    from roslink_mqtt.protocol.node_params import ParamSetResult
    from roslink_mqtt.protocol.params import ParamReply, ParamRequest
    from roslink_mqtt.protocol.provided_actions import ActionRequest
    from roslink_mqtt.protocol.rosout import LogLine
    from roslink_mqtt.protocol.snapshot import SnapshotRequest

    return [
        (CallRequest(), b'{"id":null,"args":{}}'),
        (CallRequest(5, {"a": 1}, "c1"), b'{"id":5,"args":{"a":1},"client_id":"c1"}'),
        (CallReply(1, True), b'{"id":1,"result":true,"values":{}}'),
        (CallReply(None, False, None, "why"), b'{"id":null,"result":false,"error":"why"}'),
        (CallReply(2, False), b'{"id":2,"result":false,"error":null}'),
        (ProviderResponse(1), b'{"id":1,"result":true,"values":null}'),
        (ProviderResponse("z", False, None, "bad", "c"), b'{"id":"z","result":false,"error":"bad","client_id":"c"}'),
        (ParamRequest("1", "get"), b'{"id":"1","op":"get"}'),
        (ParamRequest("2", "set", (), {"a": 1}, "c"), b'{"id":"2","op":"set","values":{"a":1},"client_id":"c"}'),
        (ParamReply(1, True), b'{"id":1,"result":true,"values":{}}'),
        (ParamReply(1, False), b'{"id":1,"result":false,"error":null}'),
        (ActionRequest("g1", "goal", {"order": 3}), b'{"id":"g1","op":"goal","goal":{"order":3}}'),
        (ActionRequest("g1", "cancel"), b'{"id":"g1","op":"cancel"}'),
        (ActionRequest("g1", "goal", None, "c"), b'{"id":"g1","op":"goal","goal":{},"client_id":"c"}'),
        (LogLine(20, "hi"), b'{"level":20,"msg":"hi"}'),
        (LogLine(30, "w", "f.py", "fn", 3, "c"),
         b'{"level":30,"msg":"w","file":"f.py","function":"fn","line":3,"client_id":"c"}'),
        (LogLine(20, "x", "", "fn", 0), b'{"level":20,"msg":"x"}'),
        (ParamSetResult(1, True), b'{"id":1,"successful":true}'),
        (ParamSetResult(1, False, "no", "c"), b'{"id":1,"successful":false,"reason":"no","client_id":"c"}'),
        (SnapshotRequest(30), b'{"last":30}'),
        (SnapshotRequest(5.5, 1024, "c"), b'{"last":5.5,"resume_from":1024,"client_id":"c"}'),
        (ControlRequest(({"command": "getFleet"},)), b'{"commands":[{"command":"getFleet"}],"id":null}'),
        (ControlResponse((), 7), b'{"responses":[],"id":7}'),
        (RobotGrants("t1", {"bob": "viewer", "alice": "operator"}, 1.5),
         b'{"robot":"t1","users":{"alice":"operator","bob":"viewer"},"issued":1.5,"by":""}'),
    ]


@pytest.mark.parametrize(("body", "wire"), _shaped_examples(),
                         ids=[f"{type(body).__name__}-{i}" for i, (body, _wire) in enumerate(_shaped_examples())])
def test_a_body_with_its_own_writing_rules_writes_them_from_its_declaration(body: Any, wire: bytes) -> None:
    assert body.to_json() == wire


def test_a_nested_body_writes_its_own_dict_with_the_same_rules() -> None:
    assert DeclaredParameter(None, "not_set").to_body() == {"value": None, "type": "not_set"}
    assert DeclaredParameter(2.5, "double", "d", True).to_body() == \
        {"value": 2.5, "type": "double", "description": "d", "read_only": True}
