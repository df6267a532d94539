"""The vehicle's side of VDA 5050: what it does with orders and instant actions, and what its ``state`` says.

Pure logic, no clock, no I/O. The bridge's adapter feeds it the orders and instant actions the master control
sends, the navigation's results (a node reached, a goal that failed) and whether the robot moves; it reads back
:attr:`Vehicle.target` (the node to drive to now, or None: stand still) and :meth:`Vehicle.state` (the fields of
the ``state`` message that are the order's). Level-triggered on purpose: the adapter compares ``target`` with the
goal it has sent after every event, so a missed edge (a reconnect, a restarted action server) cannot leave the
robot driving to a node the order no longer holds.

The rules are VDA 5050 2.1.0 §6.6 (order acceptance, Figure 8 of the standard), §6.6.3 (cancelOrder), §6.8
(pause) and §6.10 (state). Where 2.1 leaves a case unnamed, the choice is written next to it (docs/vda5050.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from ..config.model import VDA_BUILT_IN_ACTIONS
from .errors import FATAL, VdaError, order_error, order_update_error
from .order import Action, Edge, Node, Order

WAITING, INITIALIZING, RUNNING, PAUSED, FINISHED, FAILED = (
    "WAITING", "INITIALIZING", "RUNNING", "PAUSED", "FINISHED", "FAILED")
TERMINAL = (FINISHED, FAILED)

INSTANT_ACTIONS = VDA_BUILT_IN_ACTIONS  # what every vehicle carries out (robots.yaml may map more to ROS calls)
# Optional edge fields this vehicle cannot carry out (it plans its own path to each node at its own limits): an
# order that asks for one is refused (§6.1.1) rather than driven without it.
UNSUPPORTED_EDGE_FIELDS = ("trajectory", "corridor", "orientation", "orientationType", "maxSpeed",
                           "maxRotationSpeed", "rotationAllowed")
MAX_ERRORS = 16  # warnings kept in state.errors (the newest): a flood of bad orders cannot grow the state
# Ended action states kept in state.actionStates between orders (the newest): a master that sends instant actions
# for hours without a new order cannot grow the state past what a thin uplink carries. Running ones always stay.
MAX_ENDED_ACTIONS = 32


@dataclass(slots=True)
class ActionState:
    action_id: str
    action_type: str
    status: str
    result: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"actionId": self.action_id, "actionType": self.action_type,
                               "actionStatus": self.status}
        if self.result is not None:
            out["resultDescription"] = self.result
        return out


class InstantResult(NamedTuple):
    """What :meth:`Vehicle.instant` leaves to the adapter: messages to publish besides the state (``"factsheet"``),
    and the actions robots.yaml maps to ROS calls (each finished later with :meth:`Vehicle.finish_action`)."""

    publish: set[str]
    calls: list[Action]


@dataclass(slots=True)
class Vehicle:
    """One vehicle's order, its progress and its warnings."""

    map_id: str
    tolerance: float = 0.25  # m: "on the node" when an order's node allows no deviation of its own
    mapped: frozenset[str] = frozenset()  # instant action types robots.yaml maps to ROS calls
    order_id: str = ""
    order_update_id: int = 0
    zone_set_id: str | None = None
    last_node_id: str = ""
    last_node_sequence_id: int = 0
    nodes: list[Node] = field(default_factory=list)  # still to traverse: the base, then the horizon
    edges: list[Edge] = field(default_factory=list)
    actions: dict[str, ActionState] = field(default_factory=dict)
    errors: list[VdaError] = field(default_factory=list)
    paused: bool = False
    driving: bool = False
    cancelled: bool = False  # the current orderId was cancelled: it takes no updates
    pose: tuple[float, float, float] | None = None
    stuck: bool = False  # the navigation gave up on the target: stand until the master sends or cancels
    _pending: list[str] = field(default_factory=list)  # startPause/cancelOrder ids waiting for the robot to stand

    # ------------------------------------------------------------------ what the vehicle should do
    @property
    def executing(self) -> bool:
        """§6.6 check 3: nodes or edges still to traverse, or an order's action not yet done."""
        return bool(self.nodes or self.edges)

    @property
    def target(self) -> Node | None:
        """The node to drive to now: the next released one, unless paused or a cancel is stopping the robot."""
        if self.paused or self.stuck or self._cancelling or not self.nodes or not self.nodes[0].released:
            return None
        return self.nodes[0]

    @property
    def new_base_request(self) -> bool:
        """Waiting at the decision point with a horizon left: the master should release more."""
        return bool(self.nodes) and not any(n.released for n in self.nodes)

    @property
    def _cancelling(self) -> bool:
        return any(self.actions[i].action_type == "cancelOrder" for i in self._pending)

    # ------------------------------------------------------------------ orders
    def receive_order(self, order: Order) -> str:
        """Take ``order`` or refuse it: ``"new"``, ``"update"`` or ``"duplicate"`` (ignored, §6.6.4.3); a refusal
        raises :class:`VdaError` and is kept in :attr:`errors` (until an order is accepted). A refused order
        changes nothing else."""
        try:
            self._check_supported(order)
            if order.order_id != self.order_id:
                kind = self._check_new(order)
            else:
                kind = self._check_update(order)
        except VdaError as error:
            self._warn(error)
            raise
        if kind == "duplicate":
            return kind
        self.errors, self.stuck = [], False  # warnings last until an order is accepted (§6.6.4)
        if kind == "new":
            self.order_id, self.cancelled = order.order_id, False
            # §6.10.6: action states are removed on a new order, except running instant actions
            self.actions = {k: a for k, a in self.actions.items() if a.status not in TERMINAL}
            self.nodes, self.edges = list(order.nodes[1:]), list(order.edges)
            first = order.nodes[0]  # trivially reachable: traversed at once (§6.6.3.1)
            self.last_node_id, self.last_node_sequence_id = first.node_id, first.sequence_id
        else:
            self.nodes = [n for n in self.nodes if n.released]  # the horizon is replaced
            self.edges = [e for e in self.edges if e.released]
            self.nodes.extend(order.nodes[1:])  # the stitching node stays where it is (kept, or already reached)
            self.edges.extend(order.edges)
        self.order_update_id, self.zone_set_id = order.order_update_id, order.zone_set_id
        return kind

    def _check_supported(self, order: Order) -> None:
        refs = order.references()
        for action in order.actions:
            raise order_error(f"action {action.action_type!r} ({action.action_id}): this vehicle carries out no "
                              f"node or edge actions", refs + [("actionId", action.action_id),
                                                               ("actionType", action.action_type)])
        for node in order.nodes:
            if node.position is None:
                raise order_error(f"node {node.node_id}: nodePosition is needed (this vehicle drives to positions)",
                                  refs + [("nodeId", node.node_id)])
            if node.position.allowed_deviation_theta is not None:
                raise order_error(f"node {node.node_id}: allowedDeviationTheta is not supported by this vehicle (its "
                                  f"navigation decides when the heading is reached)",
                                  refs + [("nodeId", node.node_id), ("field", "allowedDeviationTheta")])
            if node.position.map_id != self.map_id:
                raise order_error(f"node {node.node_id}: map {node.position.map_id!r} is not on this vehicle "
                                  f"(it has {self.map_id!r})", refs + [("nodeId", node.node_id),
                                                                       ("mapId", node.position.map_id)])
        for edge in order.edges:
            asked = [f for f in UNSUPPORTED_EDGE_FIELDS if f in edge.fields]
            if asked:
                raise order_error(f"edge {edge.edge_id}: {', '.join(asked)} not supported by this vehicle",
                                  refs + [("edgeId", edge.edge_id)] + [("field", f) for f in asked])

    def _check_new(self, order: Order) -> str:
        refs = order.references()
        if self.executing:
            raise order_error(f"order {self.order_id} is still being carried out: cancel it first, or update it",
                              refs)
        first = order.nodes[0]
        if not self._on_node(first):
            raise VdaError("noRouteError", f"the order's first node {first.node_id} is not where the vehicle "
                                           f"stands ({self._where()})", tuple(refs + [("nodeId", first.node_id)]))
        return "new"

    def _check_update(self, order: Order) -> str:
        refs = order.references()
        if order.order_update_id < self.order_update_id:
            raise order_update_error(f"orderUpdateId {order.order_update_id} is older than the vehicle's "
                                     f"{self.order_update_id}", refs)
        if order.order_update_id == self.order_update_id:
            return "duplicate"
        if self.cancelled:
            raise order_update_error(f"order {self.order_id} was cancelled: send a new orderId", refs)
        first = order.nodes[0]
        base = [n for n in self.nodes if n.released]
        stitch = base[-1].key if base else (self.last_node_id, self.last_node_sequence_id)
        if first.key != stitch:
            raise order_update_error(f"the update starts at {first.node_id} (sequenceId {first.sequence_id}), "
                                     f"not at the end of the base: {stitch[0]} (sequenceId {stitch[1]})",
                                     refs + [("nodeId", first.node_id)])
        return "update"

    def _on_node(self, node: Node) -> bool:
        """Trivially reachable (§6.6.1): within the node's deviation range of the robot's pose, or, while the pose
        is unknown, the node the vehicle last reached."""
        if node.position is None or self.pose is None:
            return bool(self.last_node_id) and node.node_id == self.last_node_id
        allowed = node.position.allowed_deviation_xy or self.tolerance
        return math.hypot(node.position.x - self.pose[0], node.position.y - self.pose[1]) <= allowed

    def _where(self) -> str:
        if self.pose is None:
            return f"last node {self.last_node_id or 'none'}, position unknown"
        return f"at x {self.pose[0]:.2f}, y {self.pose[1]:.2f}"

    # ------------------------------------------------------------------ progress
    def reached(self, node: Node) -> bool:
        """The robot arrived at ``node`` (the navigation's goal succeeded): traversed, with the edge before it
        (§6.10.2). False when ``node`` is not the target any more (a late result after an update or cancel)."""
        if self.target is None or self.target.key != node.key:
            return False
        self.nodes.pop(0)
        self.edges = [e for e in self.edges if e.sequence_id != node.sequence_id - 1]
        self.last_node_id, self.last_node_sequence_id = node.node_id, node.sequence_id
        return True

    def failed(self, node: Node, why: str) -> None:
        """The navigation gave up on ``node``: the robot stands; a FATAL error says so until the master cancels
        the order or sends a new one."""
        if self.target is None or self.target.key != node.key:
            return
        self.stuck = True
        self._warn(VdaError("navigationError", f"cannot reach node {node.node_id}: {why}",
                            (("nodeId", node.node_id), ("orderId", self.order_id)), FATAL))

    def set_driving(self, driving: bool) -> None:
        """Whether the robot moves (or turns); a pause or cancel completes once it stands."""
        self.driving = driving
        if not driving:
            self._settle()

    def set_pose(self, x: float, y: float, theta: float) -> None:
        self.pose = (x, y, theta)

    # ------------------------------------------------------------------ instant actions
    def instant(self, actions: Iterable[Action], references: list[tuple[str, str]]) -> InstantResult:
        """Carry out instant actions (each one gets an action state); returns what to publish besides ``state`` and
        the ROS calls to make."""
        publish: set[str] = set()
        calls: list[Action] = []
        for action in actions:
            state = self.actions[action.action_id] = ActionState(action.action_id, action.action_type, RUNNING)
            kind = action.action_type
            if kind == "startPause":
                self.paused = True
                self._pending.append(action.action_id)
            elif kind == "stopPause":
                self.paused = False
                for pause in [i for i in self._pending if self.actions[i].action_type == "startPause"]:
                    self.actions[pause].status = FINISHED  # a pause lifted before the robot stood still
                    self._pending.remove(pause)
                state.status = FINISHED
            elif kind == "cancelOrder":
                if not self.executing or self.cancelled:
                    state.status = FAILED
                    self._warn(VdaError("noOrderToCancel", "there is no order to cancel",
                                        (("actionId", action.action_id),)))
                else:
                    self._pending.append(action.action_id)
            elif kind == "stateRequest":
                state.status = FINISHED
            elif kind == "factsheetRequest":
                state.status = FINISHED
                publish.add("factsheet")
            elif kind in self.mapped:
                calls.append(action)  # RUNNING until the ROS call answers
            else:
                state.status = FAILED
                self._warn(VdaError("instantActionError", f"instant action {kind!r} is not supported by this "
                                    f"vehicle (its factsheet lists what is)", tuple(references + [
                                        ("actionId", action.action_id), ("actionType", kind)])))
        if not self.driving:
            self._settle()
        self._forget_old_actions()
        return InstantResult(publish, calls)

    def _forget_old_actions(self) -> None:
        ended = [k for k, a in self.actions.items() if a.status in TERMINAL]
        for action_id in ended[:-MAX_ENDED_ACTIONS]:
            del self.actions[action_id]

    def finish_action(self, action_id: str, ok: bool, result: str) -> None:
        """A mapped instant action's ROS call answered (or failed): FINISHED or FAILED, with what it said."""
        state = self.actions.get(action_id)
        if state is not None and state.status not in TERMINAL:
            state.status, state.result = (FINISHED if ok else FAILED), result

    def _settle(self) -> None:
        """The robot stands: pauses are in effect, cancels complete (§6.6.3: nodes and edges deleted; the order's
        ids and the last node stay)."""
        for action_id in self._pending:
            state = self.actions[action_id]
            if state.action_type == "cancelOrder":
                self.nodes, self.edges, self.cancelled = [], [], True
            state.status = FINISHED
        self._pending = []

    def refuse(self, error: VdaError) -> None:
        """A message the adapter refused before it reached the vehicle (not JSON, the lease held by another):
        a warning in ``state.errors`` like the vehicle's own refusals."""
        self._warn(error)

    def _warn(self, error: VdaError) -> None:
        self.errors = (self.errors + [error])[-MAX_ERRORS:]

    # ------------------------------------------------------------------ the state message
    def state(self) -> dict[str, Any]:
        """The order's part of ``state``: ids, node and edge states, actions, errors, driving, paused."""
        out: dict[str, Any] = {
            "orderId": self.order_id, "orderUpdateId": self.order_update_id,
            "lastNodeId": self.last_node_id, "lastNodeSequenceId": self.last_node_sequence_id,
            "nodeStates": [_node_state(n) for n in self.nodes],
            "edgeStates": [{"edgeId": e.edge_id, "sequenceId": e.sequence_id, "released": e.released}
                           for e in self.edges],
            "driving": self.driving, "paused": self.paused, "newBaseRequest": self.new_base_request,
            "actionStates": [a.to_dict() for a in self.actions.values()],
            "errors": [e.to_dict() for e in self.errors],
        }
        if self.zone_set_id is not None:
            out["zoneSetId"] = self.zone_set_id
        return out


def _node_state(node: Node) -> dict[str, Any]:
    out: dict[str, Any] = {"nodeId": node.node_id, "sequenceId": node.sequence_id, "released": node.released}
    if node.description is not None:
        out["nodeDescription"] = node.description
    if node.position is not None:
        p = node.position
        pos: dict[str, Any] = {"x": p.x, "y": p.y, "mapId": p.map_id}
        if p.theta is not None:
            pos["theta"] = p.theta
        if p.allowed_deviation_xy is not None:
            pos["allowedDeviationXY"] = p.allowed_deviation_xy
        out["nodePosition"] = pos
    return out
