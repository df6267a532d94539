"""Who watches a video stream: leases renewed by watch requests, ended by ``leave`` or a client's presence ending.
ROS-free, I/O-free, thread-safe (requests arrive on the MQTT thread, the encoder thread asks).

Why leases: the robot's uplink is the scarcest thing it has, so a camera is encoded only while someone looks. A
watch that nobody renews lapses after :data:`~roslink_mqtt.protocol.video.WATCH_LEASE` seconds, so a browser tab
closed without a word, a crashed script or a lost phone stops costing the robot within seconds.

Why bounds: any granted user may watch, a viewer included; a viewer who sends watch requests from thousands of
made-up client ids must not grow the robot's memory, and one who asks for a keyframe a thousand times a second must
not turn the stream into keyframes (each several P-frames' worth of the link). So: at most
:data:`MAX_CLIENTS_PER_USER` watching clients per user, and at most one keyframe per :data:`KEY_MIN_GAP` seconds
whoever asks.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

from ..protocol.video import WATCH_LEASE

MAX_CLIENTS_PER_USER = 8
KEY_MIN_GAP = 1.0  # s between keyframes that viewers asked for
# why a watch is refused on a bridge whose uplink is `fifo` (robots.yaml bridge.uplink)
NEEDS_SCHEDULED_UPLINK = ("video needs bridge.uplink: scheduled (with fifo everything leaves in order on the "
                          "command connection, where frames would hold emergency stops back)")


@dataclass(slots=True)
class _Watch:
    until: float  # monotonic: the lease runs out
    had_presence: bool  # the client's presence was seen: its end ends the watch


class Watchers:
    """The watches of one stream, by (user, client id)."""

    def __init__(self, is_live: Callable[[str, str], bool], lease: float = WATCH_LEASE) -> None:
        self.is_live, self.lease = is_live, lease
        self._watches: dict[tuple[str, str], _Watch] = {}
        self._lock = threading.Lock()
        self._key_asked = False
        self._key_sent_at: float | None = None

    def watch(self, user: str, client_id: str, now: float, key: bool = False) -> str | None:
        """Start or renew ``client_id``'s watch; ``key``: it wants a keyframe. A refusal's reason, or None."""
        with self._lock:
            watch = self._watches.get((user, client_id))
            if watch is None:
                if sum(1 for u, _ in self._watches if u == user) >= MAX_CLIENTS_PER_USER:
                    return (f"user '{user}' already watches from {MAX_CLIENTS_PER_USER} clients: leave from one "
                            "first (or let its watch lapse)")
                watch = self._watches[(user, client_id)] = _Watch(now + self.lease, False)
                key = True  # a client that just joined needs a keyframe to start from
            watch.until = now + self.lease
            watch.had_presence = watch.had_presence or self.is_live(user, client_id)
            self._key_asked = self._key_asked or key
            return None

    def leave(self, user: str, client_id: str) -> None:
        with self._lock:
            self._watches.pop((user, client_id), None)

    def forget_user(self, user: str) -> None:
        """``user`` lost their grant: their watches end now."""
        with self._lock:
            for key in [k for k in self._watches if k[0] == user]:
                del self._watches[key]

    def expire(self, now: float) -> int:
        """End lapsed watches and those whose client's presence ended; how many remain."""
        with self._lock:
            for key, watch in list(self._watches.items()):
                if now >= watch.until:
                    del self._watches[key]
                elif self.is_live(*key):
                    watch.had_presence = True
                elif watch.had_presence:
                    del self._watches[key]
            return len(self._watches)

    def __len__(self) -> int:
        return len(self._watches)

    def take_key(self, now: float) -> bool:
        """Whether the next frame should be a keyframe a viewer asked for (at most one per KEY_MIN_GAP)."""
        with self._lock:
            if not self._key_asked or (self._key_sent_at is not None and now - self._key_sent_at < KEY_MIN_GAP):
                return False
            self._key_asked, self._key_sent_at = False, now
            return True
