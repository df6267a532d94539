"""Per-message timestamps at the bridge's four doors, so a benchmark can split a path into hops.

Off unless the environment variable ``ROSLINK_BRIDGE_TRACE`` names a file when the bridge starts. Then
every message is stamped (``time.monotonic_ns()``, one clock for every process on the machine) where it
enters or leaves the bridge:

* ``mqtt_in``: paho handed it over (every subscribed topic; before authorization or parsing);
* ``ros_out``: a command rule published it to ROS;
* ``ros_in``: a ROS→MQTT rule's subscription callback got it;
* ``mqtt_out``: the bridge queued it to paho (every topic, state, replies and requests alike).

bench/hops.py takes the other timestamps in the sending and receiving processes and matches the bridge's
by topic and order. At most ``LIMIT`` events are kept (a forgotten trace cannot grow without bound);
they are written as JSON lines when the bridge exits. When tracing is off the cost is one ``None``
check per message.
"""

from __future__ import annotations

import atexit
import os
import threading
import time
from pathlib import Path

import orjson

ENV = "ROSLINK_BRIDGE_TRACE"
LIMIT = 1_000_000


class Trace:
    """An append-only list of (ns, stage, topic); appends are atomic under the GIL, the write takes a lock."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.events: list[tuple[int, str, str]] = []
        self._lock = threading.Lock()

    def mark(self, stage: str, topic: str) -> None:
        if len(self.events) < LIMIT:
            self.events.append((time.monotonic_ns(), stage, topic))

    def write(self) -> None:
        with self._lock:
            events, self.events = self.events, []
        with self.path.open("ab") as out:
            for ns, stage, topic in events:
                out.write(orjson.dumps({"ns": ns, "stage": stage, "topic": topic}) + b"\n")


def _from_environment() -> Trace | None:
    path = os.environ.get(ENV)
    if not path:
        return None
    trace = Trace(Path(path))
    atexit.register(trace.write)
    return trace


TRACE: Trace | None = _from_environment()
