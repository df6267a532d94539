"""ROS publishers that exist only while someone publishes through them (``on_demand`` rules).

The legacy-ROSLink promise: ROS endpoints come and go with the programs behind
them. For a generic mqtt_to_ros rule marked ``on_demand``, the bridge's ROS
publisher exists while at least one live operator *advertises* it:

* explicitly, with a retained ``from/<user>/advertise/<name>``
  ``{"type": "pkg/msg/T", "client_id": "<presence id>"}`` (the SDK's
  ``create_publisher``); an empty retained message withdraws it
  (``destroy_publisher``), and the advertiser's presence ending (last-will,
  silence) withdraws it too;
* implicitly, by publishing on the rule: a plain MQTT client needs no extra step,
  and the publisher then lives while any client of that user is live.

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

from ..config import Role
from ..protocol import ProtocolError
from ..protocol.control import Advertisement
from ..topics import Verb
from .authorize import refusal
from .routes import Inbound
from .rules import ros_qos

log = logging.getLogger("roslink_mqtt.bridge.on_demand")

IMPLICIT = ""  # client_id of an implicit advertisement: any live client of the user keeps it


class OnDemandPublishers:
    """The advertisements per on-demand rule, and the ROS publishers they keep alive."""

    def __init__(self, node: Node, rules: dict[str, Inbound], always_there: set[str],
                 role_of: Callable[[str], Role | None], is_live: Callable[[str, str | None], bool],
                 error: Callable[..., None], *, robot: str) -> None:
        """``rules``: the on-demand rules by MQTT name; ``always_there``: the other mqtt_to_ros names;
        ``robot``: this robot's name, for refusals."""
        self.node, self.rules, self.always_there, self.robot = node, rules, always_there, robot
        self.role_of, self.is_live, self.error = role_of, is_live, error
        self._lock = threading.RLock()
        self._adverts: dict[str, dict[str, str]] = {name: {} for name in rules}  # name -> user -> client_id
        self._publishers: dict[str, Any] = {}

    def advertise(self, user: str, name: str, topic: str, payload: bytes) -> None:
        """A retained ``advertise/<name>`` from ``user`` (MQTT thread); empty = withdrawn."""
        rule = self.rules.get(name)
        if rule is None:
            if name not in self.always_there:  # advertising a rule whose publisher always exists is harmless
                known = ", ".join(sorted({*self.rules, *self.always_there})) or "none"
                self.error(user, topic, f"no mapping '{name}' on this robot (mqtt_to_ros rules: {known})",
                           payload=payload)
            return
        if not payload:
            with self._lock:
                self._adverts[name].pop(user, None)
            return
        why = refusal(user, self.role_of(user), Verb.ADVERTISE, name, robot=self.robot)
        if why:
            self.error(user, topic, why, payload=payload)
            return
        try:
            advert = Advertisement.from_json(payload)
            if advert.type != rule.rule.ros_type:
                raise ProtocolError(f"'{name}' carries {rule.rule.ros_type}, not {advert.type}")
        except ProtocolError as err:
            self.error(user, topic, str(err), payload=payload)
            return
        client_id = advert.client_id if advert.client_id is not None else IMPLICIT
        with self._lock:
            self._adverts[name][user] = client_id

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

    def withdraw_user(self, user: str) -> None:
        """Forget ``user``'s advertisements (e.g. their operator grant was removed)."""
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
