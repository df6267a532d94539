"""Every MQTT message the bridge receives, on any of its connections, routed in one place. ROS-free.

Before users' inputs reach the command endpoint, three kinds of message are the bridge's own business:

* the robot's own heartbeat and ``state/bridge`` announcements: another bridge for this robot shows itself there
  (bridge/core/claim.py, one bridge per robot);
* the robot's grants from the broker (bridge/core/fleet_follower.py);
* the second copy of an emergency stop: operators' stops arrive on the command link and on a link of their own
  (bridge/core/stops.py); the first is obeyed, the other dropped here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from .claim import ClaimWatch
from .stops import StopDedup

Deliver = Callable[[str, bytes, bool, "float | None"], None]  # topic, payload, retained, arrived (monotonic)


class Inbox:
    """``on_message`` of every link the bridge reads."""

    def __init__(self, robot: str, *, heartbeat_topic: str, announce_topic: str, grants_topic: str,
                 claims: ClaimWatch, on_grants: Callable[[bytes], None], stop_leaves: Sequence[str],
                 endpoint: Deliver, stops: StopDedup | None = None) -> None:
        """``stop_leaves``: the command leaves that are emergency stops (none: no stop link, nothing arrives twice);
        ``endpoint``: where users' inputs go (:meth:`CommandEndpoint.on_mqtt`)."""
        self.robot, self.claims, self.on_grants, self.endpoint = robot, claims, on_grants, endpoint
        self._own = {heartbeat_topic: claims.on_heartbeat, announce_topic: claims.on_announcement}
        self._grants_topic = grants_topic
        self._stop_leaves = tuple(stop_leaves)
        self.stops = stops or StopDedup()

    def on_message(self, topic: str, payload: bytes, retained: bool = False, arrived: float | None = None) -> None:
        own = self._own.get(topic)
        if own is not None:
            own(self.robot, payload, retained)
        elif topic == self._grants_topic:
            self.on_grants(payload)
        elif self._stop_leaves and topic.endswith(self._stop_leaves) and self.stops.seen(topic, payload):
            return  # the other copy of an emergency stop (stop link and command link both carry it)
        else:
            self.endpoint(topic, payload, retained, arrived)
