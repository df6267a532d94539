"""The robot's VDA 5050 side (docs/vda5050.md): a master control's orders driven through a ROS navigation action.

The order logic is :mod:`roslink_mqtt.vda5050` (ROS-free); this is its ROS adapter and its MQTT connection:

* **a connection of its own** to the broker, with the robot's login: its last will is the standard's
  ``connection`` CONNECTIONBROKEN (a connection has one will, and the bridge's command link carries the ROSLink
  heartbeat's). On connecting it says ONLINE and publishes the factsheet (both retained) and a state; a clean
  stop says OFFLINE first.
* **in**: ``order`` and ``instantActions`` (paho's thread: decoded, checked and applied to the
  :class:`~roslink_mqtt.vda5050.vehicle.Vehicle` under a lock); odometry and battery from ROS (the executor).
* **out**: ``state`` on every event and at least every ``state_interval``; ``visualization`` every
  ``visualization_interval``, as QoS 0 that a thin link drops rather than queues (a newer pose replaces one
  still waiting).
* **driving**: after every event, on the executor, :meth:`VdaRobot.reconcile` compares the vehicle's target
  node with the goal under way and sends or cancels navigation goals (``navigate``, an action of Nav2's
  NavigateToPose shape). The robot drives only while the master control holds the control lease and no
  emergency stop holds the robot: an order takes the free lease for the master (one driver, as for every
  operator) and gives it back when it ends; a supervisor who takes control over, or anyone's emergency stop,
  stands the robot until the lease is the master's again and an operator has re-armed. ``startPause`` stops
  the robot the way the failsafe does.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from functools import partial
from typing import Any

import orjson
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.action import ActionClient
from rclpy.node import Node
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Bool

from ...config import Fleet, Robot
from ...config.model import Priority, Vda5050Settings
from ...mqtt import BrokerUrl
from ...protocol import loads
from ...protocol.enums import AckResult
from ...vda5050 import wire
from ...vda5050.errors import VdaError, order_error, validation_error
from ...vda5050.lease import LeaseStep, OrderLease
from ...vda5050.messages import (
    CONNECTIONBROKEN,
    OFFLINE,
    ONLINE,
    Telemetry,
    connection_body,
    factsheet_body,
    state_body,
    visualization_body,
)
from ...vda5050.order import Action, Reader, read_actions, read_order
from ...vda5050.order import Node as OrderNode
from ...vda5050.vehicle import Vehicle
from ..core.endpoint import CommandEndpoint
from ..core.link import MqttLink, bridge_client_id
from ..core.on_executor import OnExecutor
from ..core.ros_types import UnknownTypeError, load_interface
from ..core.uplink_sender import Uplink

log = logging.getLogger("roslink_mqtt.bridge.vda5050")

TICK = 0.1  # s: visualization, the periodic state, the lease and e-stop checks
CALL_TIMEOUT = 30.0  # s a mapped instant action's ROS service has to answer
GOAL_WAIT = 2.0  # s without a navigation server before the state says the order waits for one


class VdaRobot:
    """A VDA 5050 vehicle over one robot's ROS graph."""

    def __init__(self, node: Node, fleet: Fleet, robot: Robot, settings: Vda5050Settings, *, password: str | None,
                 broker_url: BrokerUrl | list[BrokerUrl], ca_file: str | None, endpoint: CommandEndpoint,
                 on_executor: OnExecutor, uplink: Uplink) -> None:
        """``uplink``: the bridge's (bridge/core/uplink_sender.py): ``state`` leaves there as control (at once, never
        held back), ``visualization`` as motion, latest wins, so a thin link never queues old poses."""
        self.node, self.robot, self.settings = node, robot, settings
        self.endpoint, self.on_executor, self.uplink = endpoint, on_executor, uplink
        try:
            self.action_type: Any = load_interface(settings.navigate_type)
        except UnknownTypeError as err:
            raise UnknownTypeError(f"vda5050.navigate_type: {err}") from None
        self.headers = wire.Headers(settings.manufacturer, settings.serial_number)
        self.vehicle = Vehicle(settings.map_id, settings.tolerance,
                               mapped=frozenset(c.action_type for c in settings.actions))
        self.telemetry = Telemetry()
        self.lease = OrderLease(settings.master)  # tick() only (the executor)
        self.lock = threading.Lock()  # the vehicle and the telemetry: paho's thread and the executor both
        self._goal: _Goal | None = None  # the navigation goal under way (executor thread only)
        self._waiting_since: float | None = None  # monotonic: a goal waits for the navigation server since then
        self._state_at = 0.0  # monotonic: the last state went out
        self._visualized_at = 0.0
        self._stood_still = True  # the lease and e-stop as last seen by tick(), to notice changes
        self._out = threading.Lock()  # a header's number and its message leave together, in order (two threads send)
        self._streams = {
            wire.STATE: uplink.stream(self.headers.topic(wire.STATE), Priority.CONTROL, False, label="vda5050_state"),
            wire.VISUALIZATION: uplink.stream(self.headers.topic(wire.VISUALIZATION), Priority.MOTION, True,
                                              label="vda5050_visualization")}
        self._order_topic = self.headers.topic(wire.ORDER)
        self._actions_topic = self.headers.topic(wire.INSTANT_ACTIONS)
        will = self.headers.stamp(wire.CONNECTION, connection_body(CONNECTIONBROKEN))
        self.link = MqttLink(
            client_id=bridge_client_id(robot.name, "vda5050"), username=robot.name, password=password,
            url=broker_url, keepalive=robot.bridge.keepalive, will=None,
            subscriptions=lambda: [(self._order_topic, 0), (self._actions_topic, 0)],
            on_message=self._on_mqtt, on_up=self._on_up, ca_file=ca_file, max_payload=fleet.broker.max_payload)
        self.link.set_will(self.headers.topic(wire.CONNECTION), orjson.dumps(will))
        self.client = ActionClient(node, self.action_type, settings.navigate)
        node.create_subscription(Odometry, settings.odometry, self._on_odometry, 10)
        node.create_subscription(BatteryState, settings.battery, self._on_battery, 10)
        if settings.estop is not None:
            node.create_subscription(Bool, settings.estop, self._on_estop, 10)
        # the master's own instant actions robots.yaml maps to ROS services (startCharging → dock, …)
        self.services = {c.action_type: (c, node.create_client(load_interface(c.service_type), c.service))
                         for c in settings.actions}
        self._calls: dict[str, tuple[float, Any]] = {}  # actionId → (monotonic deadline, the call's future)
        node.create_timer(TICK, self.tick)

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> None:
        self.link.start()

    def stop(self) -> None:
        """OFFLINE first (retained: the master sees a clean stop, not a broken connection), then disconnect."""
        with self._out:
            offline = self.headers.stamp(wire.CONNECTION, connection_body(OFFLINE))
        self.link.stop([(self.headers.topic(wire.CONNECTION), orjson.dumps(offline), 1, True)])

    def _on_up(self) -> None:
        self._send(wire.CONNECTION, connection_body(ONLINE), qos=1, retain=True)
        self.publish_factsheet()
        self.publish_state()

    # -- from the master control (paho's thread) -------------------------------------------------------
    def _on_mqtt(self, topic: str, payload: bytes, retained: bool, _arrived: float) -> None:
        leaf = wire.ORDER if topic == self._order_topic else wire.INSTANT_ACTIONS
        if not payload:  # a retained message cleared: nothing was sent
            return
        if retained:  # the standard sends them unretained: a retained one would run again at every reconnect
            with self.lock:
                self.vehicle.refuse(validation_error(f"a retained {leaf} message is ignored (VDA 5050 sends them "
                                                     "unretained; remove it from the broker)", [("topic", leaf)]))
            self.publish_state()
            return
        try:
            message = loads(payload)
        except ValueError as err:
            with self.lock:
                self.vehicle.refuse(validation_error(f"not JSON: {err}", [("topic", leaf)]))
            self.publish_state()
            return
        if leaf == wire.ORDER:
            self._on_order(message)
        else:
            self._on_instant_actions(message)
        self.check_now()

    def check_now(self) -> None:
        """Send or cancel goals soon, on the executor (an order, an instant action, a stop of the bridge's)."""
        self.on_executor.run(self.reconcile)

    def _on_order(self, message: Any) -> None:
        master = self.settings.master
        try:
            order = read_order(message)
            with self.lock:
                fresh = order.order_id != self.vehicle.order_id or order.order_update_id > self.vehicle.order_update_id
                if fresh:  # not a repeat: the order needs the control lease for the master
                    why = self.endpoint.hold_for_order(master)
                    if why is not None:
                        raise order_error(f"{why}: the order is not taken", order.references())
                kind = self.vehicle.receive_order(order)
        except VdaError as error:
            with self.lock:
                self.vehicle.refuse(error)
                idle = not self.vehicle.executing
            if idle:
                self.endpoint.release_after_order(master, "its VDA 5050 order was refused")
            log.info("%s: VDA 5050 order refused: %s", self.robot.name, error)
        else:
            log.info("%s: VDA 5050 order %s (update %d): %s", self.robot.name, order.order_id,
                     order.order_update_id, kind)
        self.publish_state()

    def _on_instant_actions(self, message: Any) -> None:
        refs = [("topic", wire.INSTANT_ACTIONS)]
        try:
            body = Reader(refs).obj(message, "instantActions")
            if isinstance(body.get("headerId"), int):
                refs.insert(0, ("headerId", str(body["headerId"])))
            r = Reader(refs)
            actions = read_actions(r, r.array(body, "actions", ""), "actions")
        except VdaError as error:
            with self.lock:
                self.vehicle.refuse(error)
            self.publish_state()
            return
        with self.lock:
            publish, calls = self.vehicle.instant(actions, refs)
            pausing = any(a.action_type == "startPause" for a in actions)
        for action in calls:
            self.on_executor.run(partial(self._call, action))
        if pausing:  # the same stop the failsafe makes: zero velocity now, held a moment
            self.endpoint.trigger_stop("paused by the master control (VDA 5050 startPause)", logging.INFO,
                                       AckResult.ACCEPTED)
        if "factsheet" in publish:
            self.publish_factsheet()
        self.publish_state()

    # -- from ROS (the executor) ----------------------------------------------------------------------
    def _on_odometry(self, msg: Odometry) -> None:
        p, q, t = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        with self.lock:
            located = self.telemetry.pose is None  # the first pose: agvPosition appears in the state
            self.telemetry.pose = (p.x, p.y, yaw)
            self.telemetry.velocity = (t.linear.x, t.linear.y, t.angular.z)
            self.vehicle.set_pose(p.x, p.y, yaw)
            moving = self.telemetry.moving
            changed = moving != self.vehicle.driving
            if changed:
                self.vehicle.set_driving(moving)
        if changed or located:  # `driving` is part of the state: every change is an event (§6.10.6)
            self.publish_state()
        if changed:
            self.reconcile()

    def _on_estop(self, msg: Bool) -> None:
        with self.lock:
            changed = msg.data != self.telemetry.hardware_estop
            self.telemetry.hardware_estop = msg.data
        if changed:
            log.warning("%s: the robot's own e-stop is %s", self.robot.name, "pressed" if msg.data else "released")
            self.publish_state()
            self.reconcile()

    def _call(self, action: Action) -> None:
        """A mapped instant action: its ROS service is called (executor); the answer finishes it."""
        call, client = self.services[action.action_type]
        if not client.service_is_ready():
            self._called(action.action_id, False, f"no ROS service {self.node.resolve_service_name(call.service)}")
            return
        request_type: Any = client.srv_type.Request  # type: ignore[attr-defined]  # rclpy types it as a bare SrvType
        future = client.call_async(request_type())
        self._calls[action.action_id] = (time.monotonic() + CALL_TIMEOUT, future)
        future.add_done_callback(lambda f: self._answered(action.action_id, f))

    def _answered(self, action_id: str, future: Any) -> None:
        if self._calls.pop(action_id, None) is None:
            return  # timed out already
        response = future.result() if not future.cancelled() and future.exception() is None else None
        ok = response is not None and getattr(response, "success", True)
        text = getattr(response, "message", "") if response is not None else "the service call failed"
        self._called(action_id, bool(ok), text or ("done" if ok else "failed"))

    def _called(self, action_id: str, ok: bool, result: str) -> None:
        with self.lock:
            self.vehicle.finish_action(action_id, ok, result)
        self.publish_state()

    def _on_battery(self, msg: BatteryState) -> None:
        charge = msg.percentage * 100.0 if math.isfinite(msg.percentage) else 0.0
        charging = msg.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_CHARGING
        voltage = msg.voltage if math.isfinite(msg.voltage) and msg.voltage > 0 else None
        with self.lock:
            self.telemetry.battery = (max(0.0, min(100.0, charge)), charging, voltage)

    def tick(self) -> None:
        """Periodic: visualization, the state at least every state_interval, the lease and the e-stop."""
        now = time.monotonic()
        s = self.settings
        for action_id, (deadline, future) in list(self._calls.items()):
            if now > deadline:
                self._calls.pop(action_id, None)
                future.cancel()
                self._called(action_id, False, f"no answer within {CALL_TIMEOUT:g} s")
        if s.visualization_interval and now - self._visualized_at >= s.visualization_interval:
            self._visualized_at = now
            self.publish_visualization()
        still = self._standing_reason() is not None
        if still != self._stood_still:
            self._stood_still = still
            self.publish_state()
        self._sync_lease()
        self.reconcile()
        if now - self._state_at >= s.state_interval:
            self.publish_state()

    # -- driving (the executor) --------------------------------------------------------------------------
    def _standing_reason(self) -> str | None:
        """Why the robot may not drive the order now (None: it may)."""
        if self.endpoint.fenced:
            return self.endpoint.fenced  # another bridge has the robot: this one only stops it, then exits
        if self.telemetry.hardware_estop:
            return "the robot's own emergency stop is pressed"
        blocked = self.endpoint.motion_blocked
        if blocked:
            return f"emergency stop: {blocked}"
        holder = self.endpoint.holder()
        if holder not in (None, self.settings.master):
            return f"{self.robot.name} is driven by {holder}"
        return None

    def _sync_lease(self) -> None:
        """An order under way takes the free lease for the master; when it ends, it gives back only the lease it
        took (vda5050/lease.py)."""
        with self.lock:
            executing = self.vehicle.executing
        master = self.settings.master
        step = self.lease.step(executing, self.endpoint.holder())
        if step is LeaseStep.HOLD:
            self.lease.held(self.endpoint.hold_for_order(master) is None)
        elif step is LeaseStep.RELEASE:
            self.endpoint.release_after_order(master, "its VDA 5050 order ended")
            self.lease.released()

    def reconcile(self) -> None:
        """Send or cancel navigation goals so that the robot drives to the vehicle's target, or stands."""
        with self.lock:
            target = self.vehicle.target
        if target is not None and self._standing_reason() is not None:
            target = None
        goal = self._goal
        if goal is not None and (target is None or goal.node.key != target.key):
            goal.cancel()
            self._goal = None
        if target is not None and self._goal is None:
            if self.client.server_is_ready():
                self._waiting_since = None
                self._goal = _Goal(self, target)
            elif self._waiting_since is None:
                self._waiting_since = time.monotonic()

    def _goal_done(self, goal: _Goal, reached: bool, why: str) -> None:
        """A goal's result (executor): the node reached, or the navigation gave up on it."""
        if self._goal is goal:
            self._goal = None
        with self.lock:
            if reached:
                changed = self.vehicle.reached(goal.node)
            else:
                changed = self.vehicle.target is not None and self.vehicle.target.key == goal.node.key
                self.vehicle.failed(goal.node, why)
            executing = self.vehicle.executing
        if changed:
            if not executing:
                self.endpoint.release_after_order(self.settings.master, "its VDA 5050 order was driven to its end")
            self.publish_state()
        self.reconcile()

    def goal_message(self, node: OrderNode) -> Any:
        goal = self.action_type.Goal()
        pose = PoseStamped()
        pose.header.frame_id = self.settings.frame
        pose.header.stamp = self.node.get_clock().now().to_msg()
        assert node.position is not None  # the vehicle takes only nodes with positions
        pose.pose.position.x, pose.pose.position.y = node.position.x, node.position.y
        theta = node.position.theta
        if theta is None:  # no heading asked: arrive facing the way the robot drives there
            with self.lock:
                here = self.telemetry.pose
            theta = math.atan2(node.position.y - here[1], node.position.x - here[0]) if here else 0.0
        pose.pose.orientation.z, pose.pose.orientation.w = math.sin(theta / 2.0), math.cos(theta / 2.0)
        goal.pose = pose
        return goal

    # -- out ---------------------------------------------------------------------------------------------
    def publish_state(self) -> None:
        with self.lock:
            self.telemetry.emergency_stop = bool(self.endpoint.motion_blocked)  # a ROSLink stop: eStop REMOTE
            body = state_body(self.vehicle, self.telemetry, self.settings)
            executing = self.vehicle.executing
        reason = self._standing_reason()
        if reason is None and self._waiting_since is not None and time.monotonic() - self._waiting_since > GOAL_WAIT:
            reason = f"no navigation server on {self.node.resolve_topic_name(self.settings.navigate)}"
        if reason is not None and executing:
            body["errors"].append(VdaError("orderWaits", f"the order waits: {reason}").to_dict())
        self._send(wire.STATE, body)

    def publish_visualization(self) -> None:
        with self.lock:
            body = visualization_body(self.telemetry, self.settings)
        self._send(wire.VISUALIZATION, body)

    def publish_factsheet(self) -> None:
        self._send(wire.FACTSHEET, factsheet_body(self.settings, self.robot.bridge.limits), retain=True)

    def _send(self, leaf: str, body: dict[str, Any], qos: int = 0, retain: bool = False) -> None:
        """state and visualization through the uplink (their classes), connection and factsheet on this link."""
        with self._out:
            if leaf == wire.STATE:
                self._state_at = time.monotonic()
            topic, payload = self.headers.topic(leaf), orjson.dumps(self.headers.stamp(leaf, body))
            stream = self._streams.get(leaf)
            if stream is not None:
                self.uplink.offer(stream, topic, payload, qos, retain)
            else:
                self.link.publish(topic, payload, qos=qos, retain=retain)


class _Goal:
    """One navigation goal to one node: sent when the server is there, cancelled when the order moves on."""

    def __init__(self, owner: VdaRobot, node: OrderNode) -> None:
        self.owner, self.node = owner, node
        self.handle: Any = None
        self.cancelled = False
        future = owner.client.send_goal_async(owner.goal_message(node))
        future.add_done_callback(self._accepted)
        log.info("%s: VDA 5050: driving to node %s (%.2f, %.2f)", owner.robot.name, node.node_id,
                 node.position.x if node.position else math.nan, node.position.y if node.position else math.nan)

    def _accepted(self, future: Any) -> None:
        handle = future.result()
        if handle is None or not handle.accepted:
            self.owner._goal_done(self, False, "the navigation refused the goal")
            return
        self.handle = handle
        if self.cancelled:
            handle.cancel_goal_async()
            return
        handle.get_result_async().add_done_callback(self._result)

    def _result(self, future: Any) -> None:
        if self.cancelled:
            return
        response = future.result()
        status = getattr(response, "status", None)
        succeeded = status == 4  # action_msgs/GoalStatus.STATUS_SUCCEEDED
        text = getattr(getattr(response, "result", None), "error_msg", "") or f"goal status {status}"
        self.owner._goal_done(self, succeeded, text)

    def cancel(self) -> None:
        self.cancelled = True
        if self.handle is not None:
            self.handle.cancel_goal_async()


