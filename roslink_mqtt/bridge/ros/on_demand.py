"""ROS publishers that exist only while someone publishes through them (``on_demand`` rules), with rclpy.

The port of the ``advertise`` capability (:mod:`roslink_mqtt.bridge.core.capabilities.advertise`, which decides who
may advertise what). For a generic mqtt_to_ros rule marked ``on_demand``, the bridge's ROS publisher exists while
at least one live operator advertises it: explicitly (a retained advertisement naming the client, withdrawn by an
empty one or by that client's presence ending), or implicitly by publishing on the rule (the publisher then lives
while any client of that user is live).

Velocity and ROSLink command rules are never on demand: the failsafe must always
be able to publish on them. ROS entities are created and destroyed under one
lock, so a message never meets a half-destroyed publisher.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from ..core.routes import Inbound
from .rules import ros_qos

log = logging.getLogger("roslink_mqtt.bridge.ros.on_demand")

IMPLICIT = ""  # client_id of an implicit advertisement: any live client of the user keeps it


class OnDemandPublishers:
    """The advertisements per on-demand rule, and the ROS publishers they keep alive."""

    def __init__(self, node: Node, rules: dict[str, Inbound], is_live: Callable[[str, str | None], bool]) -> None:
        """``rules``: the on-demand rules by MQTT name; ``is_live``: whether a user's client is present."""
        self.node, self.rules, self.is_live = node, rules, is_live
        self._lock = threading.RLock()
        self._adverts: dict[str, dict[str, str]] = {name: {} for name in rules}  # name -> user -> client_id
        self._publishers: dict[str, Any] = {}

    # -- AdvertisePort (MQTT thread) ---------------------------------------------------------------
    def advertise(self, user: str, name: str, client_id: str | None) -> None:
        """``user`` advertises ``name`` from ``client_id`` (None: implicitly, from any of their live clients)."""
        with self._lock:
            self._adverts[name][user] = client_id if client_id is not None else IMPLICIT

    def withdraw(self, user: str, name: str) -> None:
        with self._lock:
            self._adverts[name].pop(user, None)

    def publisher(self, user: str, name: str) -> Any:
        """The ROS publisher for a message from ``user`` on ``name`` (MQTT thread), created if need be.

        Publishing is an implicit advertisement, so a plain MQTT client needs no extra step.
        """
        with self._lock:
            self._adverts[name].setdefault(user, IMPLICIT)
            return self._ensure(name)

    def publish(self, user: str, name: str, msg: Any) -> None:
        with self._lock:  # never on a publisher that refresh() is destroying
            self.publisher(user, name).publish(msg)

    def _ensure(self, name: str) -> Any:
        pub = self._publishers.get(name)
        if pub is None:
            rule = self.rules[name]
            pub = self._publishers[name] = self.node.create_publisher(rule.ros_cls, rule.rule.ros_topic,
                                                                      ros_qos(rule.rule.ros_qos))
            log.info("created ROS publisher %s for '%s' (advertised by %s)", pub.topic_name, name,
                     ", ".join(sorted(self._adverts[name])))
        return pub

    def withdraw_user(self, user: str, reason: str = "") -> None:
        """Forget ``user``'s advertisements (their operator grant was removed; nobody waits on one: ``reason`` is
        not told anyone)."""
        with self._lock:
            for adverts in self._adverts.values():
                adverts.pop(user, None)

    def refresh(self) -> None:
        """Create and destroy publishers to match the live advertisements (executor)."""
        with self._lock:
            for name, adverts in self._adverts.items():
                live = False
                for user, client_id in list(adverts.items()):
                    if self.is_live(user, client_id or None):
                        live = True
                    elif client_id == IMPLICIT:
                        del adverts[user]  # renewed by the user's next message
                    # an explicit advertisement stays until withdrawn: its client may not have said hello yet
                if live and name not in self._publishers:
                    self._ensure(name)
                elif not live and name in self._publishers:
                    pub = self._publishers.pop(name)
                    log.info("removed ROS publisher %s: nobody publishes on '%s' any more", pub.topic_name, name)
                    self.node.destroy_publisher(pub)
