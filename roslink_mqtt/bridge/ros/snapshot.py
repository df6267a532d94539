"""The snapshot ring buffer's ROS side and where its chunks and failsafe files go (capabilities/snapshot.py).

Each ``snapshot.topics`` entry gets a raw subscription (``raw=True``: rclpy hands over the CDR bytes without
deserializing, the cheapest way to keep a topic) with the sensor-data QoS (best effort, so it matches reliable
and best-effort publishers alike). Every type's ``.msg`` definition is read once at start: a missing one stops the
bridge with the reason, not the first snapshot.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

from ...config import SnapshotSettings
from ...config.model import Priority
from ..core.msgdef import DefinitionNotFound, full_definition
from ..core.ros_types import UnknownTypeError, load_interface
from ..core.snapshot_buffer import SnapshotBuffer, SnapshotFile
from ..core.uplink_sender import Uplink
from .rules import RuleError

log = logging.getLogger("roslink_mqtt.bridge.snapshot")

STREAM = "snapshot"  # the uplink stream (and, when scheduled, the bulk lane) snapshot chunks leave on


class RosSnapshotBuffer(SnapshotBuffer):
    """:class:`SnapshotBuffer` fed by raw subscriptions on ``node``."""

    def __init__(self, node: Any, settings: SnapshotSettings) -> None:
        from rclpy.qos import qos_profile_sensor_data

        definitions: dict[str, str] = {}
        for i, topic in enumerate(settings.topics):
            try:
                load_interface(topic.ros_type)
                definitions[topic.ros_type] = full_definition(topic.ros_type)
            except (UnknownTypeError, DefinitionNotFound) as err:
                raise RuleError(f"snapshot.topics[{i}] ({topic.ros_topic}): {err}") from None
        super().__init__(settings, definitions.__getitem__)
        self.subscriptions = [
            node.create_subscription(load_interface(topic.ros_type), topic.ros_topic,
                                     lambda data, index=i: self.add(index, data), qos_profile_sensor_data, raw=True)
            for i, topic in enumerate(settings.topics)]
        log.info("snapshot ring buffer: %s, %g s, at most %d bytes", ", ".join(t.ros_topic for t in settings.topics),
                 settings.seconds, settings.max_bytes)


class UplinkChunks:
    """:class:`~roslink_mqtt.bridge.core.capabilities.snapshot.ChunkLink` on the uplink: a bulk stream of its own,
    ordered (chunks are never superseded), handed a chunk only when the one before has left the bridge."""

    def __init__(self, uplink: Uplink) -> None:
        self.uplink = uplink
        self.stream = uplink.stream(STREAM, Priority.BULK, latest_only=False, label=STREAM)
        self.lane = uplink.lane_of(self.stream)

    def room(self) -> bool:
        if not self.lane.link.connected.is_set():
            return False
        with self.uplink.lock:
            if self.stream.waiting:
                return False
        return self.uplink.unsent(self.lane) < self.uplink.meter.budget

    def send(self, topic: str, payload: bytes) -> None:
        self.uplink.offer(self.stream, topic, payload, 1, False)


def snapshot_dir(configured: str | None) -> Path:
    """Where the failsafe's snapshots go: ``snapshot.dir``, else systemd's $STATE_DIRECTORY/snapshots, else
    ~/.local/state/roslink-mqtt/snapshots."""
    if configured:
        return Path(configured).expanduser()
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    base = Path(state) if state else Path.home() / ".local" / "state" / "roslink-mqtt"
    return base / "snapshots"


class FailsafeFiles:
    """Writes the failsafe's snapshots to ``directory`` (``failsafe-<UTC time>.mcap``), keeping the newest ``keep``."""

    def __init__(self, directory: Path, robot: str, keep: int) -> None:
        self.directory, self.robot, self.keep = directory, robot, keep
        # a write cut short (power lost, the process killed mid-write) leaves a .part: never a snapshot, only disk
        for stale in directory.glob(f"{robot}-failsafe-*.part") if directory.is_dir() else ():
            try:
                stale.unlink()
                log.info("removed an unfinished failsafe snapshot: %s", stale)
            except OSError as err:
                log.warning("cannot remove the unfinished failsafe snapshot %s: %s", stale, err)

    def __call__(self, built: SnapshotFile, reason: str) -> None:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            path = self.directory / f"{self.robot}-failsafe-{stamp}-{time.time_ns() % 1_000_000_000:09d}.mcap"
            partial = path.with_suffix(".part")
            partial.write_bytes(built.data)
            partial.replace(path)
            for old in sorted(self.directory.glob(f"{self.robot}-failsafe-*.mcap"))[:-self.keep]:
                old.unlink(missing_ok=True)
        except OSError as err:
            log.error("failsafe snapshot not written to %s: %s", self.directory, err)
            return
        log.warning("failsafe snapshot: %s (%d messages, %d bytes; %s)", path, built.messages, len(built.data), reason)
