"""The vehicle's side of VDA 5050 (roslink_mqtt/vda5050): orders accepted and refused the standard's way (§6.6),
progress node by node, cancelOrder and pause (§6.6.3, §6.8), and a ``state`` that the standard's own 2.1.0
schema (bundled unchanged by vda5050-sdk) accepts at every step."""

from __future__ import annotations

import copy
from typing import Any

import pytest
from vda5050.validation import SchemaValidator

from roslink_mqtt.vda5050.errors import VdaError
from roslink_mqtt.vda5050.order import Action, read_order
from roslink_mqtt.vda5050.vehicle import MAX_ENDED_ACTIONS, Vehicle
from roslink_mqtt.vda5050.wire import Headers

pytestmark = pytest.mark.unit
SCHEMAS = SchemaValidator()
MAP = "demo"


def node(node_id: str, seq: int, x: float, y: float, released: bool = True, **extra: Any) -> dict[str, Any]:
    return {"nodeId": node_id, "sequenceId": seq, "released": released, "actions": [],
            "nodePosition": {"x": x, "y": y, "mapId": MAP}, **extra}


def edge(start: dict[str, Any], end: dict[str, Any], released: bool = True, **extra: Any) -> dict[str, Any]:
    return {"edgeId": f"{start['nodeId']}-{end['nodeId']}", "sequenceId": start["sequenceId"] + 1,
            "released": released, "startNodeId": start["nodeId"], "endNodeId": end["nodeId"], "actions": [], **extra}


def order(order_id: str, update: int, nodes: list[dict[str, Any]], header: int = 0) -> dict[str, Any]:
    """An order as a master control sends it: edges between consecutive nodes, released when both ends are."""
    edges = [edge(a, b, released=a["released"] and b["released"]) for a, b in zip(nodes, nodes[1:], strict=False)]
    return {"headerId": header, "timestamp": "2026-11-29T08:00:00.00Z", "version": "2.1.0", "manufacturer": "Sim",
            "serialNumber": "turtle1", "orderId": order_id, "orderUpdateId": update, "nodes": nodes, "edges": edges}


A, B, C, D = node("A", 0, 0.0, 0.0), node("B", 2, 2.0, 0.0), node("C", 4, 2.0, 2.0), node("D", 6, 0.0, 2.0)


def vehicle_at(x: float = 0.0, y: float = 0.0) -> Vehicle:
    v = Vehicle(map_id=MAP)
    v.set_pose(x, y, 0.0)
    return v


def full_state(v: Vehicle, headers: Headers) -> dict[str, Any]:
    """The whole state message as the bridge sends it (the order's part from the vehicle, the rest measured)."""
    body = {**v.state(), "batteryState": {"batteryCharge": 87.5, "charging": False},
            "operatingMode": "AUTOMATIC", "safetyState": {"eStop": "NONE", "fieldViolation": False},
            "agvPosition": {"x": 0.0, "y": 0.0, "theta": 0.0, "mapId": MAP, "positionInitialized": True},
            "velocity": {"vx": 0.0, "vy": 0.0, "omega": 0.0}}
    return headers.stamp("state", body)


def valid(v: Vehicle, headers: Headers | None = None) -> dict[str, Any]:
    message = full_state(v, headers or Headers("Sim", "turtle1"))
    assert SCHEMAS.errors("state", message) == []
    return message


def refused(v: Vehicle, message: dict[str, Any], error_type: str) -> VdaError:
    before = copy.deepcopy(v.state())
    with pytest.raises(VdaError) as caught:
        v.receive_order(read_order(message))
    assert caught.value.error_type == error_type, caught.value
    after = v.state()
    assert after["errors"][-1]["errorType"] == error_type and after["errors"][-1]["errorLevel"] == "WARNING"
    after["errors"] = before["errors"]
    assert after == before  # a refused order changes nothing but the warning
    valid(v)
    return caught.value


def test_a_three_node_order_is_driven_node_by_node_to_its_end() -> None:
    v = vehicle_at()
    assert v.receive_order(read_order(order("o1", 0, [A, B, C]))) == "new"
    s = valid(v)
    # the first node is where the vehicle stands: traversed at once (§6.6.3.1)
    assert (s["lastNodeId"], s["lastNodeSequenceId"]) == ("A", 0)
    assert [n["nodeId"] for n in s["nodeStates"]] == ["B", "C"] and [e["edgeId"] for e in s["edgeStates"]] == [
        "A-B", "B-C"]
    assert v.target is not None and v.target.node_id == "B"
    v.set_driving(True)
    assert v.reached(v.target)
    s = valid(v)
    assert (s["lastNodeId"], s["lastNodeSequenceId"]) == ("B", 2) and s["edgeStates"] == [
        {"edgeId": "B-C", "sequenceId": 3, "released": True}]
    assert v.reached(v.target)
    v.set_driving(False)
    s = valid(v)
    assert s["nodeStates"] == [] and s["edgeStates"] == [] and s["lastNodeId"] == "C" and not s["driving"]
    assert v.target is None and not v.executing and s["orderId"] == "o1"


def test_a_late_result_for_a_node_the_order_no_longer_holds_changes_nothing() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B, C])))
    b = v.target
    assert b is not None and v.reached(b) and not v.reached(b)
    assert v.state()["lastNodeId"] == "B"


def test_malformed_orders_are_validation_errors_naming_the_field() -> None:
    good = order("o1", 0, [A, B])
    cases = {
        "orderUpdateId": ("orderUpdateId", -1, "orderUpdateId: must be a whole number"),
        "released": ("nodes", [dict(A, released="yes"), B], "nodes[0].released: must be true or false"),
        "x": ("nodes", [A, dict(B, nodePosition={"y": 0.0, "mapId": MAP})], "nodes[1].nodePosition.x: is required"),
        "theta": ("nodes", [A, node("B", 2, 1.0, 0.0, nodePosition={"x": 1.0, "y": 0.0, "mapId": MAP, "theta": 4.0})],
                  "theta: must be within"),
        "edges": ("edges", [], "edges: 2 nodes need 1 edges"),
        "join": ("edges", [dict(edge(A, B), endNodeId="C")], "edges[0] must join A to B"),
        "seq": ("edges", [dict(edge(A, B), sequenceId=7)], "edges[0].sequenceId 7 must lie between"),
        "blocking": ("nodes", [A, dict(B, actions=[{"actionType": "beep", "actionId": "1", "blockingType": "LOUD"}])],
                     "blockingType: must be one of NONE, SOFT, HARD"),
        "horizon first": ("nodes", [dict(A, released=False), dict(B, released=False)],
                          "first node is part of its base"),
    }
    for name, (key, value, said) in cases.items():
        bad = dict(good, **{key: value})
        with pytest.raises(VdaError) as caught:
            read_order(bad)
        assert caught.value.error_type == "validationError" and said in caught.value.description, (name, caught.value)
        refs = dict(caught.value.references)
        assert refs["topic"] == "order" and refs["headerId"] == "0", refs
    # released after unreleased, and a base that ends on an edge
    mixed = order("o1", 0, [A, dict(B, released=False), C])
    mixed["edges"][1]["released"] = True
    with pytest.raises(VdaError, match="comes before the horizon"):
        read_order(mixed)
    dangling = order("o1", 0, [A, dict(B, released=False)])
    dangling["edges"][0]["released"] = True
    with pytest.raises(VdaError, match="base ends on a node"):
        read_order(dangling)


def test_the_schema_and_the_reader_agree_on_what_is_malformed() -> None:
    """Every order the standard's schema rejects, the reader rejects too (a field removed or of the wrong type)."""
    good = order("o1", 3, [A, B, C])
    assert SCHEMAS.errors("order", good) == []
    read_order(good)
    broken = 0
    for path in _paths(good):
        for bad_value in (None, "x", 1.5, -1, True, [], {}):
            candidate = copy.deepcopy(good)
            _set(candidate, path, bad_value)
            if SCHEMAS.errors("order", candidate):
                broken += 1
                with pytest.raises(VdaError):
                    read_order(candidate)
        candidate = copy.deepcopy(good)
        _delete(candidate, path)
        if SCHEMAS.errors("order", candidate):
            broken += 1
            with pytest.raises(VdaError):
                read_order(candidate)
    assert broken > 100  # the comparison covered the order, not a corner of it


def _paths(value: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out: list[tuple[Any, ...]] = []
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, child in items:
        out.append(prefix + (key,))
        out.extend(_paths(child, prefix + (key,)))
    return out


def _set(root: Any, path: tuple[Any, ...], value: Any) -> None:
    for key in path[:-1]:
        root = root[key]
    root[path[-1]] = value


def _delete(root: Any, path: tuple[Any, ...]) -> None:
    for key in path[:-1]:
        root = root[key]
    del root[path[-1]]


def test_a_new_order_while_one_runs_and_one_out_of_reach_are_refused() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B])))
    error = refused(v, order("o2", 0, [A, C]), "orderError")
    assert "o1 is still being carried out" in error.description
    assert dict(error.references)["orderId"] == "o2"
    far = vehicle_at(5.0, 5.0)
    error = refused(far, order("o1", 0, [A, B]), "noRouteError")
    assert ("nodeId", "A") in error.references and "x 5.00, y 5.00" in error.description
    # within the node's own deviation range, it is reachable
    assert far.receive_order(read_order(order("o1", 0, [node("A", 0, 4.5, 5.0, nodePosition={
        "x": 4.5, "y": 5.0, "mapId": MAP, "allowedDeviationXY": 0.6}), B]))) == "new"


def test_what_the_vehicle_cannot_do_is_refused_as_an_order_error() -> None:
    v = vehicle_at()
    with_action = order("o1", 0, [A, dict(B, actions=[{"actionType": "pick", "actionId": "p1",
                                                        "blockingType": "HARD"}])])
    error = refused(v, with_action, "orderError")
    assert ("actionId", "p1") in error.references
    other_map = order("o1", 0, [A, node("B", 2, 1.0, 0.0, nodePosition={"x": 1.0, "y": 0.0, "mapId": "hall2"})])
    assert ("mapId", "hall2") in refused(v, other_map, "orderError").references
    fast = order("o1", 0, [A, B])
    fast["edges"][0]["maxSpeed"] = 0.2
    assert ("field", "maxSpeed") in refused(v, fast, "orderError").references
    unplaced = order("o1", 0, [A, {k: val for k, val in B.items() if k != "nodePosition"}])
    assert "nodePosition is needed" in refused(v, unplaced, "orderError").description
    # the warnings stay until an order is accepted (§6.6.4)
    assert len(v.state()["errors"]) == 4
    v.receive_order(read_order(order("o1", 0, [A, B])))
    assert v.state()["errors"] == []


def test_updates_stitch_on_the_last_base_node_and_replace_the_horizon() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B, dict(C, released=False)])))
    s = valid(v)
    assert [(n["nodeId"], n["released"]) for n in s["nodeStates"]] == [("B", True), ("C", False)]
    assert [(e["edgeId"], e["released"]) for e in s["edgeStates"]] == [("A-B", True), ("B-C", False)]
    assert v.target is not None and v.target.node_id == "B"
    v.reached(v.target)
    assert v.target is None and v.new_base_request and valid(v)["newBaseRequest"]  # waiting at the decision point
    # the same message again is ignored; an older update and one that does not start at B are refused
    assert v.receive_order(read_order(order("o1", 0, [A, B, dict(C, released=False)]))) == "duplicate"
    refused(v, order("o1", 1, [C, D]), "orderUpdateError")
    assert v.receive_order(read_order(order("o1", 2, [B, C, D]))) == "update"
    s = valid(v)
    assert [(n["nodeId"], n["released"]) for n in s["nodeStates"]] == [("C", True), ("D", True)]
    assert [e["edgeId"] for e in s["edgeStates"]] == ["B-C", "C-D"] and s["orderUpdateId"] == 2
    assert "older than the vehicle's 2" in refused(v, order("o1", 1, [B, C]), "orderUpdateError").description
    # an update while the stitching node is still ahead keeps it once
    assert v.receive_order(read_order(order("o1", 3, [D, node("E", 8, 1.0, 1.0)]))) == "update"
    assert [n["nodeId"] for n in v.state()["nodeStates"]] == ["C", "D", "E"]
    for _ in range(3):
        assert v.target is not None and v.reached(v.target)
    # finished: an update continues from the last node
    assert not v.executing
    assert v.receive_order(read_order(order("o1", 4, [node("E", 8, 1.0, 1.0), node("F", 10, 0.0, 0.0)]))) == "update"
    assert v.target is not None and v.target.node_id == "F"


def test_cancel_order_stops_then_clears_the_order_and_keeps_its_ids() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B, C])))
    v.set_driving(True)
    v.instant([Action("cancelOrder", "c1", "HARD")], [])
    s = valid(v)
    assert s["actionStates"] == [{"actionId": "c1", "actionType": "cancelOrder", "actionStatus": "RUNNING"}]
    assert v.target is None and s["nodeStates"]  # stopping: the order is still there
    v.set_driving(False)
    s = valid(v)
    assert s["actionStates"][0]["actionStatus"] == "FINISHED"
    assert s["nodeStates"] == [] and s["edgeStates"] == [] and (s["orderId"], s["lastNodeId"]) == ("o1", "A")
    # nothing left to cancel: FAILED and noOrderToCancel naming the action
    v.instant([Action("cancelOrder", "c2", "HARD")], [])
    s = valid(v)
    assert s["actionStates"][-1] == {"actionId": "c2", "actionType": "cancelOrder", "actionStatus": "FAILED"}
    assert s["errors"][-1]["errorType"] == "noOrderToCancel" and s["errors"][-1]["errorReferences"] == [
        {"referenceKey": "actionId", "referenceValue": "c2"}]
    # the cancelled order takes no update; a new order is taken and clears the finished action states
    refused(v, order("o1", 1, [A, B]), "orderUpdateError")
    assert v.receive_order(read_order(order("o2", 0, [A, D]))) == "new"
    assert v.state()["actionStates"] == [] and v.target is not None and v.target.node_id == "D"


def test_pause_holds_the_order_and_resume_goes_on() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B])))
    v.set_driving(True)
    v.instant([Action("startPause", "p1", "HARD")], [])
    assert v.target is None and valid(v)["paused"] and v.actions["p1"].status == "RUNNING"
    v.set_driving(False)
    assert v.actions["p1"].status == "FINISHED" and v.state()["nodeStates"]
    v.instant([Action("stopPause", "p2", "HARD")], [])
    assert not v.paused and v.target is not None and v.target.node_id == "B" and v.actions["p2"].status == "FINISHED"
    valid(v)


def test_instant_actions_the_vehicle_does_not_know_fail_with_a_warning() -> None:
    v = vehicle_at()
    publish, calls = v.instant([Action("stateRequest", "s1", "NONE"), Action("factsheetRequest", "f1", "NONE"),
                                Action("pick", "x1", "HARD")], [("headerId", "7"), ("topic", "instantActions")])
    assert publish == {"factsheet"} and calls == []
    s = valid(v)
    assert [(a["actionId"], a["actionStatus"]) for a in s["actionStates"]] == [
        ("s1", "FINISHED"), ("f1", "FINISHED"), ("x1", "FAILED")]
    assert s["errors"][-1]["errorType"] == "instantActionError"
    assert {"referenceKey": "actionType", "referenceValue": "pick"} in s["errors"][-1]["errorReferences"]


def test_hours_of_instant_actions_keep_the_newest_ended_states_and_every_running_one() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B])))
    v.set_driving(True)
    v.instant([Action("startPause", "pause", "HARD")], [])  # running until the robot stands
    for i in range(500):
        v.instant([Action("stateRequest", f"s{i}", "NONE")], [])
    kept = [a["actionId"] for a in valid(v)["actionStates"]]
    assert kept[0] == "pause" and kept[1:] == [f"s{i}" for i in range(500 - MAX_ENDED_ACTIONS, 500)]


def test_a_node_the_navigation_cannot_reach_is_a_fatal_error_and_the_robot_stands() -> None:
    v = vehicle_at()
    v.receive_order(read_order(order("o1", 0, [A, B])))
    b = v.target
    assert b is not None
    v.failed(b, "the planner found no path")
    s = valid(v)
    assert v.target is None and s["errors"][-1]["errorLevel"] == "FATAL"
    v.instant([Action("cancelOrder", "c1", "HARD")], [])
    assert v.actions["c1"].status == "FINISHED" and not v.executing
    v.receive_order(read_order(order("o2", 0, [A, B])))
    assert v.target is not None and v.state()["errors"] == []


def test_headers_count_per_topic_and_stamp_utc_milliseconds() -> None:
    h = Headers("Sim", "turtle1", clock=lambda: 1_764_403_200.125)
    first, second, other = h.stamp("state", {}), h.stamp("state", {}), h.stamp("connection", {})
    assert (first["headerId"], second["headerId"], other["headerId"]) == (0, 1, 0)
    assert first["timestamp"] == "2025-11-29T08:00:00.125Z" and first["version"] == "2.1.0"
    assert h.topic("order") == "uagv/v2/Sim/turtle1/order"


def test_instant_actions_mapped_to_ros_calls_run_until_the_call_answers() -> None:
    v = Vehicle(map_id=MAP, mapped=frozenset({"startCharging"}))
    publish, calls = v.instant([Action("startCharging", "c1", "HARD"), Action("startCharging", "c2", "HARD")], [])
    assert publish == set() and [a.action_id for a in calls] == ["c1", "c2"]
    assert v.actions["c1"].status == "RUNNING"
    v.finish_action("c1", True, "docked")
    v.finish_action("c2", False, "no charger")
    v.finish_action("c1", False, "late")  # a finished action stays as it ended
    states = {a["actionId"]: a for a in valid(v)["actionStates"]}
    assert states["c1"] == {"actionId": "c1", "actionType": "startCharging", "actionStatus": "FINISHED",
                            "resultDescription": "docked"}
    assert states["c2"]["actionStatus"] == "FAILED" and states["c2"]["resultDescription"] == "no charger"
