"""Topics this program publishes on, announced to the robot so its ROS side exists meanwhile.

An advertisement is a *retained* ``from/<user>/advertise/<name>`` naming the ROS
type and our presence client id. For a rule the robot's fleet file marks
``on_demand``, the bridge keeps the ROS publisher while an advertisement's
presence is live: withdrawing it (``destroy_publisher``), closing the client or
the process dying (last-will) removes the ROS side. For other rules the ROS
publisher always exists and the advertisement changes nothing. Advertisements
are re-published on every reconnect (a broker without persistence forgets them).
"""

from __future__ import annotations

import threading

from ..protocol.control import Advertisement
from ..ros_names import is_interface
from ..topics import TopicTree, check_path
from .connection import Connection
from .errors import InvalidArgument


class Advertisements:
    """The advertisements of one connection, keyed by (robot, name)."""

    def __init__(self, connection: Connection, topics: TopicTree, user: str) -> None:
        self.connection, self.topics, self.user = connection, topics, user
        self._lock = threading.Lock()
        self._types: dict[tuple[str, str], str] = {}
        self._counts: dict[tuple[str, str], int] = {}  # several publishers may share one topic
        connection.on_connected.append(self._republish)

    def advertise(self, robot: str, name: str, ros_type: str) -> None:
        check_path(name, "topic")
        if not isinstance(ros_type, str) or not is_interface(ros_type, "msg"):
            raise InvalidArgument(f"message type must look like 'std_msgs/msg/String', got {ros_type!r}")
        key = (robot, name)
        with self._lock:
            known = self._types.get(key)
            if known is not None and known != ros_type:
                raise InvalidArgument(f"'{name}' on {robot} is already advertised as {known}, not {ros_type}")
            self._types[key] = ros_type
            self._counts[key] = self._counts.get(key, 0) + 1
            first = self._counts[key] == 1
        if first:
            self._publish(robot, name, ros_type)

    def withdraw(self, robot: str, name: str, wait: float = 2.0) -> None:
        """One publisher fewer on ``name``; the last one withdraws the advertisement."""
        key = (robot, name)
        with self._lock:
            if key not in self._counts:
                return
            self._counts[key] -= 1
            if self._counts[key] > 0:
                return
            del self._counts[key], self._types[key]
        info = self.connection.publish(self.topics.advertise(robot, self.user, name), b"", qos=Advertisement.QOS,
                                       retain=Advertisement.RETAINED)
        if wait and not self.connection.on_network_thread() and self.connection.connected.is_set():
            info.wait_for_publish(wait)

    def withdraw_all(self) -> None:
        with self._lock:
            keys = list(self._counts)
            self._counts = {key: 1 for key in keys}
        for robot, name in keys:
            self.withdraw(robot, name)

    def _publish(self, robot: str, name: str, ros_type: str) -> None:
        body = Advertisement(ros_type, self.connection.client_id)
        self.connection.publish(self.topics.advertise(robot, self.user, name), body.to_json(),
                                qos=Advertisement.QOS, retain=Advertisement.RETAINED)

    def _republish(self) -> None:
        with self._lock:
            types = dict(self._types)
        for (robot, name), ros_type in types.items():
            self._publish(robot, name, ros_type)
