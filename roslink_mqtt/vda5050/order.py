"""An order as the master control sends it, read into typed values with the standard's checks.

Reading is strict where the schema is (required fields, types, ranges: a fault is a ``validationError`` naming
the field) and adds what the schema cannot say but the standard does: nodes and edges alternate by
``sequenceId``, each edge joins the nodes on either side of it, the base (``released``) comes before the horizon
and starts the order. What the order means for the vehicle (new order, update, stitching) is
:mod:`roslink_mqtt.vda5050.vehicle`'s.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

from .errors import VdaError, validation_error

BLOCKING_TYPES = ("NONE", "SOFT", "HARD")


@dataclass(frozen=True, slots=True)
class Action:
    action_type: str
    action_id: str
    blocking_type: str
    parameters: tuple[tuple[str, Any], ...] = ()
    description: str | None = None


@dataclass(frozen=True, slots=True)
class Position:
    x: float
    y: float
    map_id: str
    theta: float | None = None
    allowed_deviation_xy: float | None = None
    allowed_deviation_theta: float | None = None


@dataclass(frozen=True, slots=True)
class Node:
    node_id: str
    sequence_id: int
    released: bool
    actions: tuple[Action, ...]
    position: Position | None = None
    description: str | None = None

    @property
    def key(self) -> tuple[str, int]:
        return self.node_id, self.sequence_id


@dataclass(frozen=True, slots=True)
class Edge:
    edge_id: str
    sequence_id: int
    released: bool
    start_node_id: str
    end_node_id: str
    actions: tuple[Action, ...]
    max_speed: float | None = None
    description: str | None = None
    fields: frozenset[str] = frozenset()  # the keys the master sent: optional ones the vehicle cannot honour


@dataclass(frozen=True, slots=True)
class Order:
    header_id: int
    order_id: str
    order_update_id: int
    nodes: tuple[Node, ...]
    edges: tuple[Edge, ...]
    zone_set_id: str | None = None

    @property
    def base_nodes(self) -> tuple[Node, ...]:
        return tuple(n for n in self.nodes if n.released)

    @property
    def base_edges(self) -> tuple[Edge, ...]:
        return tuple(e for e in self.edges if e.released)

    @property
    def actions(self) -> tuple[Action, ...]:
        return tuple(a for n in self.nodes for a in n.actions) + tuple(a for e in self.edges for a in e.actions)

    def references(self) -> list[tuple[str, str]]:
        return [("headerId", str(self.header_id)), ("topic", "order"), ("orderId", self.order_id),
                ("orderUpdateId", str(self.order_update_id))]


class Reader:
    """Typed reads from a JSON object with the path of every field, for errors that say where."""

    def __init__(self, refs: list[tuple[str, str]]) -> None:
        self.refs = refs

    def fail(self, path: str, expected: str) -> VdaError:
        return validation_error(f"{path}: {expected}", self.refs)

    def obj(self, value: Any, path: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(path, "must be an object")
        return value

    def field(self, obj: dict[str, Any], key: str, path: str, required: bool = True) -> Any:
        if key not in obj:
            if required:
                raise self.fail(f"{path}.{key}" if path else key, "is required")
            return None
        return obj[key]

    def string(self, obj: dict[str, Any], key: str, path: str, required: bool = True) -> str | None:
        value = self.field(obj, key, path, required)
        if value is None and not required:
            return None
        if not isinstance(value, str):
            raise self.fail(_join(path, key), "must be a string")
        return value

    def integer(self, obj: dict[str, Any], key: str, path: str, minimum: int = 0) -> int:
        value = self.field(obj, key, path)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(_join(path, key), f"must be a whole number ≥ {minimum}")
        return value

    def boolean(self, obj: dict[str, Any], key: str, path: str) -> bool:
        value = self.field(obj, key, path)
        if not isinstance(value, bool):
            raise self.fail(_join(path, key), "must be true or false")
        return value

    def number(self, obj: dict[str, Any], key: str, path: str, required: bool = True, low: float | None = None,
               high: float | None = None) -> float | None:
        value = self.field(obj, key, path, required)
        if value is None and not required:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(_join(path, key), "must be a finite number")
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.fail(_join(path, key), f"must be within [{low}, {high}]" if high is not None
                            else f"must be ≥ {low}")
        return float(value)

    def array(self, obj: dict[str, Any], key: str, path: str) -> list[Any]:
        value = self.field(obj, key, path)
        if not isinstance(value, list):
            raise self.fail(_join(path, key), "must be an array")
        return value


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


THETA = math.pi + 1e-9  # the schema's bound is ±3.14159265359


def read_actions(r: Reader, items: list[Any], path: str) -> tuple[Action, ...]:
    actions = []
    for i, raw in enumerate(items):
        p = f"{path}[{i}]"
        a = r.obj(raw, p)
        blocking = r.string(a, "blockingType", p)
        if blocking not in BLOCKING_TYPES:
            raise r.fail(f"{p}.blockingType", f"must be one of {', '.join(BLOCKING_TYPES)}")
        params: list[tuple[str, Any]] = []
        if "actionParameters" in a:
            for j, raw_param in enumerate(r.array(a, "actionParameters", p)):
                pp = f"{p}.actionParameters[{j}]"
                param = r.obj(raw_param, pp)
                key = r.string(param, "key", pp)
                r.field(param, "value", pp)
                params.append((key or "", param["value"]))
        actions.append(Action(r.string(a, "actionType", p) or "", r.string(a, "actionId", p) or "", blocking,
                              tuple(params), r.string(a, "actionDescription", p, required=False)))
    return tuple(actions)


def _position(r: Reader, node: dict[str, Any], path: str) -> Position | None:
    if "nodePosition" not in node:
        return None
    p = f"{path}.nodePosition"
    pos = r.obj(node["nodePosition"], p)
    x, y = r.number(pos, "x", p), r.number(pos, "y", p)
    assert x is not None and y is not None
    return Position(x, y, r.string(pos, "mapId", p) or "",
                    r.number(pos, "theta", p, required=False, low=-THETA, high=THETA),
                    r.number(pos, "allowedDeviationXY", p, required=False, low=0.0),
                    r.number(pos, "allowedDeviationTheta", p, required=False, low=-THETA, high=THETA))


def read_order(message: Any) -> Order:
    """``message`` (the decoded JSON of an order) as an :class:`Order`; raises :class:`VdaError`
    (``validationError``) naming the first field that is wrong."""
    refs: list[tuple[str, str]] = [("topic", "order")]
    r = Reader(refs)
    m = r.obj(message, "order")
    if isinstance(m.get("headerId"), int):
        refs.insert(0, ("headerId", str(m["headerId"])))
    header_id = r.integer(m, "headerId", "")
    for key in ("timestamp", "version", "manufacturer", "serialNumber"):
        r.string(m, key, "")
    order_id = r.string(m, "orderId", "") or ""
    refs.append(("orderId", order_id))
    update = r.integer(m, "orderUpdateId", "")
    refs.append(("orderUpdateId", str(update)))
    zone = r.string(m, "zoneSetId", "", required=False)
    nodes = []
    for i, raw in enumerate(r.array(m, "nodes", "")):
        p = f"nodes[{i}]"
        n = r.obj(raw, p)
        nodes.append(Node(r.string(n, "nodeId", p) or "", r.integer(n, "sequenceId", p), r.boolean(n, "released", p),
                          read_actions(r, r.array(n, "actions", p), f"{p}.actions"), _position(r, n, p),
                          r.string(n, "nodeDescription", p, required=False)))
    edges = []
    for i, raw in enumerate(r.array(m, "edges", "")):
        p = f"edges[{i}]"
        e = r.obj(raw, p)
        edges.append(Edge(r.string(e, "edgeId", p) or "", r.integer(e, "sequenceId", p), r.boolean(e, "released", p),
                          r.string(e, "startNodeId", p) or "", r.string(e, "endNodeId", p) or "",
                          read_actions(r, r.array(e, "actions", p), f"{p}.actions"),
                          r.number(e, "maxSpeed", p, required=False, low=0.0),
                          r.string(e, "edgeDescription", p, required=False), frozenset(e)))
    order = Order(header_id, order_id, update, tuple(nodes), tuple(edges), zone)
    _check_shape(order)
    return order


def _check_shape(order: Order) -> None:
    """What the standard says of an order's graph beyond the schema (§6.6): a node, then edge and node in turn,
    sequence ids growing along it; every edge joins its neighbours; released nodes and edges first."""
    refs = order.references()
    nodes, edges = order.nodes, order.edges
    if not nodes:
        raise validation_error("nodes: an order has at least one node", refs)
    if len(edges) != len(nodes) - 1:
        raise validation_error(f"edges: {len(nodes)} nodes need {len(nodes) - 1} edges, not {len(edges)}", refs)
    for i, edge in enumerate(edges):
        before, after = nodes[i], nodes[i + 1]
        if not before.sequence_id < edge.sequence_id < after.sequence_id:
            raise validation_error(f"edges[{i}].sequenceId {edge.sequence_id} must lie between its nodes' "
                                   f"({before.sequence_id} and {after.sequence_id})", refs + [("edgeId", edge.edge_id)])
        if (edge.start_node_id, edge.end_node_id) != (before.node_id, after.node_id):
            raise validation_error(f"edges[{i}] must join {before.node_id} to {after.node_id}, not "
                                   f"{edge.start_node_id} to {edge.end_node_id}", refs + [("edgeId", edge.edge_id)])
    if not nodes[0].released:
        raise validation_error("nodes[0].released: the order's first node is part of its base", refs)
    sequence = [item.released for pair in zip(nodes, (*edges, None), strict=True) for item in pair if item is not None]
    if any(later and not earlier for earlier, later in itertools.pairwise(sequence)):
        raise validation_error("released: the base (released nodes and edges) comes before the horizon", refs)
    if sequence.count(True) % 2 == 0:  # node, edge, node, …: an even count ends on an edge
        raise validation_error("released: the base ends on a node (the end node of a released edge is released)",
                               refs)
    ids = [a.action_id for a in order.actions]
    if len(set(ids)) != len(ids):
        raise validation_error("actions: every actionId of an order is unique", refs)
