"""Announce that an operator is alive: a retained heartbeat at ~1 Hz, cleared by the last-will.

Robots refuse commands from users without a live heartbeat and stop when the
operator who commanded motion goes away, so every commanding client runs one.
The heartbeat also says whether this client commands (ACTIVE) or only watches
(STANDBY): a robot stops when a commanding client of its driver goes away,
even if the same user is still logged in elsewhere, but not for a watcher.
"""

from __future__ import annotations

import threading

import paho.mqtt.client as mqtt

from ..presence import DEFAULT_OPERATOR_PERIOD, operator_heartbeat, operator_signoff
from ..topics import TopicTree


class OperatorPresence:
    def __init__(self, client: mqtt.Client, user: str, client_id: str, *, topics: TopicTree | None = None,
                 period: float = DEFAULT_OPERATOR_PERIOD, commanding: bool = True) -> None:
        """``commanding=False`` starts as a watcher; :meth:`start_commanding` before the first command."""
        self.client, self.user, self.client_id = client, user, client_id
        self.commanding = commanding
        self.topic = (topics or TopicTree()).operator(user, client_id)
        self.period = period
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sequence = 0
        # The last-will must be set before CONNECT: an empty retained message clears our heartbeat.
        client.will_set(self.topic, b"", qos=1, retain=True)

    def beat(self) -> None:
        """Publish one heartbeat now (also called on every (re)connect)."""
        self._sequence = (self._sequence + 1) & 0xFFFFFFFF
        self.client.publish(self.topic, operator_heartbeat(self.user, self.client_id, self._sequence,
                                                           commanding=self.commanding), qos=1, retain=True)

    def start_commanding(self) -> None:
        """Say ACTIVE before the first command goes out (same connection: the robot hears it first)."""
        if not self.commanding:
            self.commanding = True
            if self.client.is_connected():
                self.beat()

    def start(self) -> None:
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=f"presence-{self.client_id}", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.client.is_connected():
                self.beat()
            self._stop.wait(self.period)

    def stop(self) -> None:
        """Sign off cleanly: stop beating, say so (SIGNED_OFF), and clear the retained heartbeat."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
            self._thread = None
        if self.client.is_connected():
            # Say "leaving on purpose" first: the clear alone is what a crash's last-will looks like.
            self._sequence = (self._sequence + 1) & 0xFFFFFFFF
            self.client.publish(self.topic, operator_signoff(self.user, self.client_id, self._sequence), qos=1)
            self.client.publish(self.topic, b"", qos=1, retain=True).wait_for_publish(timeout=2)
